//! The command line on the bundled sample and on broken input: every bad file gives a
//! one-line error naming the file and the problem, exit code 1, no panic and no output.

mod common;

use q3gltf_convert::bsp::{lump, Bsp, Format};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

fn exe() -> &'static str {
    env!("CARGO_BIN_EXE_q3gltf")
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("q3gltf-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn sample_bsp() -> Vec<u8> {
    q3gltf_samples::generate().bsp.to_bytes()
}

/// Runs `q3gltf convert` and checks the failure contract.
fn expect_failure(input: &Path, extra: &[&str], must_mention: &[&str]) {
    let dir = input.parent().unwrap();
    let out = dir.join("out.glb");
    let o = Command::new(exe()).arg("convert").arg(input).args(extra).arg("-o").arg(&out).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "exit code for {}: {stderr}", input.display());
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "one line: {stderr}");
    for m in must_mention {
        assert!(stderr.contains(m), "error should mention {m:?}: {stderr}");
    }
    assert!(!out.exists(), "no output file on failure");
    let leftovers: Vec<_> = std::fs::read_dir(dir).unwrap().filter_map(|e| e.ok()).map(|e| e.file_name()).filter(|n| n.to_string_lossy().starts_with("out.") || n.to_string_lossy().starts_with(".out.")).collect();
    assert!(leftovers.is_empty(), "no partial files: {leftovers:?}");
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn set_lump(bytes: &mut [u8], l: usize, offset: i32, length: i32) {
    let at = 8 + l * 8;
    bytes[at..at + 4].copy_from_slice(&offset.to_le_bytes());
    bytes[at + 4..at + 8].copy_from_slice(&length.to_le_bytes());
}

#[test]
fn truncated_file() {
    let d = tmp("trunc");
    let good = sample_bsp();
    let p = write(&d, "trunc.bsp", &good[..good.len() / 2]);
    expect_failure(&p, &[], &["trunc.bsp", "outside"]);
    let p = write(&d, "tiny.bsp", &good[..6]);
    expect_failure(&p, &[], &["tiny.bsp", "too short"]);
}

#[test]
fn wrong_magic_and_unknown_version() {
    let d = tmp("magic");
    let mut b = sample_bsp();
    b[..4].copy_from_slice(b"PK\x03\x04");
    let p = write(&d, "magic.bsp", &b);
    expect_failure(&p, &[], &["magic.bsp", "not a Quake III BSP"]);
    let mut b = sample_bsp();
    b[4..8].copy_from_slice(&38i32.to_le_bytes());
    let p = write(&d, "version.bsp", &b);
    expect_failure(&p, &[], &["version.bsp", "version 38"]);
}

#[test]
fn lump_outside_file_negative_and_huge_counts() {
    let d = tmp("lumps");
    let mut b = sample_bsp();
    let len = b.len() as i32;
    set_lump(&mut b, lump::DRAW_VERTS, len - 4, 4400);
    let p = write(&d, "outside.bsp", &b);
    expect_failure(&p, &[], &["outside.bsp", "draw vertices", "outside"]);
    let mut b = sample_bsp();
    set_lump(&mut b, lump::SURFACES, 100, -104);
    let p = write(&d, "negative.bsp", &b);
    expect_failure(&p, &[], &["negative.bsp", "surfaces"]);
    let mut b = sample_bsp();
    set_lump(&mut b, lump::DRAW_INDEXES, 8, i32::MAX);
    let p = write(&d, "huge.bsp", &b);
    expect_failure(&p, &[], &["huge.bsp", "draw indexes"]);
    // A lump length that is not a whole number of records.
    let mut b = sample_bsp();
    let at = 8 + lump::MODELS * 8;
    let (off, l) = (i32::from_le_bytes(b[at..at + 4].try_into().unwrap()), i32::from_le_bytes(b[at + 4..at + 8].try_into().unwrap()));
    set_lump(&mut b, lump::MODELS, off, l - 3);
    let p = write(&d, "partial.bsp", &b);
    expect_failure(&p, &[], &["partial.bsp", "multiple"]);
}

#[test]
fn indices_and_references_out_of_range() {
    let d = tmp("refs");
    let s = q3gltf_samples::generate().bsp;
    let mut b = s.clone();
    b.indices[4] = 999;
    let p = write(&d, "index.bsp", &b.to_bytes());
    expect_failure(&p, &[], &["index.bsp", "surface 0", "index 999"]);
    let mut b = s.clone();
    b.surfaces[3].shader = 77;
    let p = write(&d, "shader.bsp", &b.to_bytes());
    expect_failure(&p, &[], &["shader.bsp", "surface 3", "shader index 77"]);
    let mut b = s.clone();
    b.models[0].num_surfaces = 100_000;
    let p = write(&d, "model.bsp", &b.to_bytes());
    expect_failure(&p, &[], &["model.bsp", "model 0"]);
    let mut b = s.clone();
    let patch = b.surfaces.iter().position(|x| x.patch_w > 0).unwrap();
    b.surfaces[patch].patch_w = 4;
    let p = write(&d, "patch.bsp", &b.to_bytes());
    expect_failure(&p, &[], &["patch.bsp", "patch control grid 4x3"]);
    let mut b = s;
    b.entities = "{ \"classname\" \"worldspawn\" ".into();
    let p = write(&d, "entities.bsp", &b.to_bytes());
    expect_failure(&p, &[], &["entities.bsp", "entity lump"]);
}

fn zip_with(entries: &[(&str, &[u8])]) -> Vec<u8> {
    let mut buf = std::io::Cursor::new(Vec::new());
    {
        let mut z = zip::ZipWriter::new(&mut buf);
        for (name, data) in entries {
            z.start_file(*name, zip::write::SimpleFileOptions::default()).unwrap();
            z.write_all(data).unwrap();
        }
        z.finish().unwrap();
    }
    buf.into_inner()
}

#[test]
fn hostile_and_corrupt_pk3() {
    let d = tmp("pk3");
    let game = d.join("game");
    std::fs::create_dir_all(&game).unwrap();
    let bsp = sample_bsp();
    let pk3 = zip_with(&[("maps/evil.bsp", &bsp), ("../x", b"escape")]);
    std::fs::write(game.join("evil.pk3"), &pk3).unwrap();
    let out = d.join("out.glb");
    let o = Command::new(exe()).args(["convert", "evil", "--game-dir"]).arg(&game).arg("-o").arg(&out).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("evil.pk3") && stderr.contains("unsafe entry name") && stderr.contains("../x"), "{stderr}");
    assert_eq!(stderr.lines().count(), 1);
    assert!(!out.exists());
    assert!(!d.join("x").exists() && !game.join("x").exists());

    // A corrupt archive: the central directory is garbage.
    std::fs::remove_file(game.join("evil.pk3")).unwrap();
    let mut broken = zip_with(&[("maps/evil.bsp", &bsp)]);
    let n = broken.len();
    for b in &mut broken[n - 30..n - 10] {
        *b = 0xAB;
    }
    std::fs::write(game.join("broken.pk3"), &broken).unwrap();
    let o = Command::new(exe()).args(["convert", "evil", "--game-dir"]).arg(&game).arg("-o").arg(&out).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("broken.pk3") && stderr.contains("corrupt pk3"), "{stderr}");
    assert!(!out.exists());
}

#[test]
fn missing_map_and_bad_output_name() {
    let d = tmp("usage");
    let game = d.join("game");
    std::fs::create_dir_all(&game).unwrap();
    let o = Command::new(exe()).args(["convert", "nosuchmap", "--game-dir"]).arg(&game).arg("-o").arg(d.join("o.glb")).output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("maps/nosuchmap.bsp: not found"));
    let p = write(&d, "m.bsp", &sample_bsp());
    let o = Command::new(exe()).arg("convert").arg(&p).arg("-o").arg(d.join("o.obj")).output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains(".gltf or .glb"));
}

/// The committed sample is exactly what the generator makes (deterministic, up to date).
#[test]
fn committed_sample_is_current() {
    let sample = q3gltf_samples::generate();
    for (rel, bytes) in &sample.files {
        let path = common::repo().join("samples/sample").join(rel);
        let on_disk = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e} (run `make sample`)", path.display()));
        assert!(on_disk == *bytes, "{} is out of date: run `make sample`", path.display());
    }
}

/// The sample converts (as the default `make` does) with its lights as KHR lights of the
/// intensity CONVENTIONS.md gives, its patch, and its vertex-lit panel.
#[test]
fn sample_converts_with_entity_lights() {
    let d = tmp("sample");
    let out = d.join("sample.gltf");
    let o = Command::new(exe())
        .arg("convert")
        .arg(common::repo().join("samples/sample/maps/sample.bsp"))
        .args(["--entity-lights", "--json", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["surfaces"]["patch"], 1);
    assert_eq!(summary["surfaces"]["vertex_lit"], 1);
    assert_eq!(summary["missing_textures"].as_array().unwrap().len(), 0, "{summary}");
    let (doc, _, images) = gltf::import(&out).unwrap();
    assert_eq!(images.len(), 6, "5 textures and one lightmap atlas");
    let lights: Vec<_> = doc.lights().unwrap().collect();
    assert_eq!(lights.len(), q3gltf_samples::LIGHTS.len());
    for (l, s) in lights.iter().zip(q3gltf_samples::LIGHTS.iter()) {
        let cd = q3gltf_convert::units::q3map2_point_candela(s.light, 0.0254, 2);
        assert!((l.intensity() as f64 - cd).abs() < 1e-3 * cd);
        assert!((cd / s.light - 163.0).abs() < 0.5, "about 163 cd per unit of `light`");
    }
    let node = doc.nodes().find(|n| n.light().is_some()).unwrap();
    let t = node.transform().decomposed().0;
    let q = q3gltf_samples::LIGHTS[0].origin;
    let want = [q[0] * 0.0254, q[2] * 0.0254, -q[1] * 0.0254];
    for k in 0..3 {
        assert!((t[k] as f64 - want[k]).abs() < 1e-5, "light position in glTF axes: {t:?} vs {want:?}");
    }
}

/// RBSP 1 and IBSP 47 files convert like IBSP 46 (written by our writer from the sample).
#[test]
fn other_formats_convert() {
    let d = tmp("formats");
    let base: Bsp = q3gltf_samples::generate().bsp;
    for (format, name) in [(Format::Ibsp(47), "v47.bsp"), (Format::Rbsp, "rbsp.bsp")] {
        let mut b = base.clone();
        b.format = format;
        let p = write(&d, name, &b.to_bytes());
        let out = d.join(format!("{name}.glb"));
        let o = Command::new(exe()).arg("convert").arg(&p).arg("-o").arg(&out).output().unwrap();
        assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
        let (doc, _, _) = gltf::import(&out).unwrap();
        let tris: usize = doc.meshes().flat_map(|m| m.primitives()).map(|p| p.indices().unwrap().count() / 3).sum();
        assert!(tris > 90, "{name}: {tris} triangles");
    }
}

/// External lightmaps (`maps/<map>/lm_0000.tga`, empty lump) are found through the VFS
/// and packed unchanged; `--moz-lightmap` adds the extension to extensionsUsed only.
#[test]
fn external_lightmaps_and_moz_lightmap() {
    let d = tmp("external");
    let game = d.join("game");
    std::fs::create_dir_all(game.join("maps/ext")).unwrap();
    let mut bsp = q3gltf_samples::generate().bsp;
    let page = bsp.lightmaps.remove(0);
    assert!(bsp.lightmaps.is_empty());
    let img = image::RgbImage::from_raw(128, 128, page.clone()).unwrap();
    img.save_with_format(game.join("maps/ext/lm_0000.tga"), image::ImageFormat::Tga).unwrap();
    std::fs::write(game.join("maps/ext.bsp"), bsp.to_bytes()).unwrap();
    let out = d.join("ext.gltf");
    let o = Command::new(exe()).arg("convert").arg(game.join("maps/ext.bsp")).args(["--moz-lightmap", "--json", "-o"]).arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["lightmap_pages"], 1, "{summary}");
    assert_eq!(summary["surfaces"]["lightmapped"], 33, "{summary}");
    let doc: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    assert!(doc["extensionsUsed"].as_array().unwrap().iter().any(|e| e == "MOZ_lightmap"));
    assert!(doc.get("extensionsRequired").is_none_or(|r| !r.as_array().unwrap().iter().any(|e| e == "MOZ_lightmap")));
    let mat = doc["materials"].as_array().unwrap().iter().find(|m| m.get("occlusionTexture").is_some()).unwrap();
    assert_eq!(mat["extensions"]["MOZ_lightmap"]["texCoord"], 1);
    // The atlas holds the page unchanged, one texel in from its cell's corner.
    let (gdoc, _, images) = gltf::import(&out).unwrap();
    let tex = gdoc.materials().find_map(|m| m.occlusion_texture()).unwrap().texture().source().index();
    let atlas = &images[tex];
    assert_eq!(atlas.format, gltf::image::Format::R8G8B8);
    for y in 0..128 {
        for x in 0..128 {
            let a = ((y + 1) * atlas.width as usize + x + 1) * 3;
            let p = (y * 128 + x) * 3;
            assert_eq!(&atlas.pixels[a..a + 3], &page[p..p + 3], "texel ({x}, {y})");
        }
    }
}
