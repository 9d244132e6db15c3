//! Hostile input and interrupted runs, end to end through the `q3gltf` binary: names from
//! the game data never place a file outside the output directory, a zip bomb fails fast,
//! a failed or interrupted conversion leaves no file behind (not even a temporary), and the
//! input is never overwritten. (Limits of each parser are unit-tested next to it, and the
//! parsers are fuzzed: see fuzz/ and docs/limits.md.)

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn exe() -> &'static str {
    env!("CARGO_BIN_EXE_q3gltf")
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("q3gltf-hostile-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Every file below `dir`, relative, sorted.
fn tree(dir: &Path) -> Vec<String> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<String>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                out.push(format!("{}/", p.strip_prefix(root).unwrap().display()));
                walk(root, &p, out);
            } else {
                out.push(p.strip_prefix(root).unwrap().display().to_string());
            }
        }
    }
    let mut out = Vec::new();
    if dir.exists() {
        walk(dir, dir, &mut out);
    }
    out.sort();
    out
}

fn tga(w: u32, h: u32, rgb: [u8; 3]) -> Vec<u8> {
    let mut out = Vec::new();
    image::RgbImage::from_pixel(w, h, image::Rgb(rgb)).write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Tga).unwrap();
    out
}

fn zip_with(entries: &[(&str, &[u8])]) -> Vec<u8> {
    let mut buf = std::io::Cursor::new(Vec::new());
    {
        let mut z = zip::ZipWriter::new(&mut buf);
        for (name, data) in entries {
            let o = zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated);
            z.start_file(*name, o).unwrap();
            z.write_all(data).unwrap();
        }
        z.finish().unwrap();
    }
    buf.into_inner()
}

/// The sample map with its surfaces spread over the given shader names.
fn sample_with_shaders(names: &[&str]) -> Vec<u8> {
    let mut bsp = q3gltf_samples::generate().bsp;
    bsp.shaders = names
        .iter()
        .map(|n| q3gltf_convert::bsp::ShaderRef { name: n.to_string(), surface_flags: 0, content_flags: 1 })
        .collect();
    for (i, s) in bsp.surfaces.iter_mut().enumerate() {
        s.shader = (i % names.len()) as u32;
    }
    bsp.to_bytes()
}

/// Texture names that are odd but legal inside an archive (spaces, case, a colon, a
/// Windows device name, non-ASCII, two names that sanitise alike) and names that are
/// hostile (`..`, absolute, drive letter, backslashes). No file may land outside the
/// output directory; every image gets its own sanitised, deterministic name.
#[test]
fn texture_names_never_leave_the_output_directory() {
    let d = tmp("names");
    let game = d.join("game");
    std::fs::create_dir_all(game.join("maps")).unwrap();
    let odd = ["textures/odd/A b", "textures/odd/a_b", "textures/odd/x:y", "textures/odd/con", "textures/odd/caf\u{e9}"];
    let hostile = ["../../../escape", "/tmp/abs_evil", "C:\\evil\\x", "textures\\..\\..\\..\\up", "textures/ok/../../../../up2"];
    let entries: Vec<(String, Vec<u8>)> =
        odd.iter().enumerate().map(|(i, n)| (format!("{n}.tga"), tga(4, 4, [i as u8 * 40, 7, 200]))).collect();
    let refs: Vec<(&str, &[u8])> = entries.iter().map(|(n, b)| (n.as_str(), b.as_slice())).collect();
    std::fs::write(game.join("odd.pk3"), zip_with(&refs)).unwrap();
    let names: Vec<&str> = odd.iter().chain(&hostile).copied().collect();
    let map = game.join("maps/m.bsp");
    std::fs::write(&map, sample_with_shaders(&names)).unwrap();
    let before_game = tree(&game);

    let out_dir = d.join("out");
    let run = || {
        let o = Command::new(exe()).arg("convert").arg(&map).arg("-q").arg("-o").arg(out_dir.join("m.gltf")).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(out_dir.join("m.gltf")).unwrap()
    };
    let first = run();
    // Nothing outside the output directory changed or appeared.
    assert_eq!(tree(&game), before_game);
    let mut top: Vec<String> = std::fs::read_dir(&d).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    top.sort();
    assert_eq!(top, ["game", "out"]);
    for p in ["/tmp/abs_evil", "/tmp/abs_evil.png"] {
        assert!(!Path::new(p).exists(), "{p} was created");
    }
    assert!(!d.join("escape.png").exists() && !std::env::temp_dir().join("escape.png").exists());

    // Every image URI is relative, inside m_textures/, distinct, and its file exists there.
    let doc: serde_json::Value = serde_json::from_slice(&first).unwrap();
    let uris: Vec<&str> = doc["images"].as_array().unwrap().iter().map(|i| i["uri"].as_str().unwrap()).collect();
    let distinct: std::collections::BTreeSet<&str> = uris.iter().copied().collect();
    assert_eq!(distinct.len(), uris.len(), "image URIs collide: {uris:?}");
    for u in &uris {
        assert!(u.starts_with("m_textures/") && !u.contains("..") && !u.contains('\\') && !u.contains(':'), "{u}");
        assert!(out_dir.join(u).is_file(), "{u} missing");
    }
    // The five odd textures were found (no placeholder for them), and the two names that
    // sanitise alike got two files, suffixed in a fixed order.
    assert!(uris.contains(&"m_textures/textures/odd/a_b.png") && uris.contains(&"m_textures/textures/odd/a_b_1.png"), "{uris:?}");
    assert!(uris.contains(&"m_textures/textures/odd/_con.png") && uris.contains(&"m_textures/textures/odd/x_y.png"), "{uris:?}");
    assert!(uris.contains(&"m_textures/missing_texture.png"), "hostile names get the placeholder: {uris:?}");
    // Deterministic: a second run writes the same document.
    assert_eq!(run(), first);
    std::fs::remove_dir_all(&d).unwrap();
}

/// Entries of 300 MiB of zeros (over the default 256 MiB limit for one file) that deflate
/// to about 300 KiB, once declared honestly and once with headers that claim 100 bytes:
/// both are refused with a size error, fast, and the map still converts without them.
#[test]
fn zip_bomb_fails_fast() {
    let d = tmp("bomb");
    let game = d.join("game");
    std::fs::create_dir_all(game.join("maps")).unwrap();
    let bomb = vec![0u8; 300 << 20];
    let pk3 = zip_with(&[("scripts/bomb.shader", &bomb), ("textures/sample/wall.tga", &bomb)]);
    drop(bomb);
    assert!(pk3.len() < 2 << 20);
    let map = game.join("maps/m.bsp");
    std::fs::write(&map, sample_with_shaders(&["textures/sample/wall"])).unwrap();
    for lying in [false, true] {
        let mut z = pk3.clone();
        if lying {
            // Uncompressed size: local headers at +22, central directory entries at +24.
            let mut at = 0;
            while let Some(p) = z[at..].windows(4).position(|w| w == b"PK\x03\x04" || w == b"PK\x01\x02") {
                let h = at + p;
                let off = if &z[h..h + 4] == b"PK\x03\x04" { 22 } else { 24 };
                z[h + off..h + off + 4].copy_from_slice(&100u32.to_le_bytes());
                at = h + 4;
            }
        }
        std::fs::write(game.join("bomb.pk3"), &z).unwrap();
        let t = Instant::now();
        let o = Command::new(exe()).arg("convert").arg(&map).args(["-q", "--json", "-o"]).arg(d.join("out.glb")).output().unwrap();
        let all = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
        assert!(t.elapsed() < Duration::from_secs(20), "took {:?}", t.elapsed());
        assert!(!all.contains("panicked"), "{all}");
        assert!(o.status.success(), "{all}");
        let summary: serde_json::Value = serde_json::from_str(&String::from_utf8_lossy(&o.stdout)).unwrap();
        let warnings = summary["warnings"].to_string();
        assert!(warnings.contains("bomb.shader") && warnings.contains("limit"), "lying={lying}: {warnings}");
        assert!(warnings.contains("textures/sample/wall.tga") && warnings.matches("limit").count() >= 2, "lying={lying}: {warnings}");
    }
    std::fs::remove_dir_all(&d).unwrap();
}

/// SIGINT while the output batch is half written (each staged file made slow by the test
/// hook): the process dies of the signal and leaves nothing, not the directories it
/// created, not a temporary, not a partial file.
#[cfg(unix)]
#[test]
fn interrupted_conversion_leaves_no_output() {
    use std::os::unix::process::ExitStatusExt;
    let d = tmp("interrupt");
    let map = d.join("m.bsp");
    std::fs::write(&map, q3gltf_samples::generate().bsp.to_bytes()).unwrap();
    let out_dir = d.join("new/deeper");
    for (container, signal) in [("gltf", "INT"), ("glb", "TERM")] {
        let mut child = Command::new(exe())
            .arg("convert")
            .arg(&map)
            .arg("-q")
            .arg("-o")
            .arg(out_dir.join(format!("m.{container}")))
            .env("Q3GLTF_TEST_WRITE_DELAY_MS", "3000")
            .spawn()
            .unwrap();
        // Wait for the first temporary file to appear, then interrupt.
        let t = Instant::now();
        let staged = |dir: &Path| tree(dir).iter().any(|p| p.rsplit('/').next().is_some_and(|n| n.starts_with('.') && n.contains(".tmp")));
        while !staged(&d) {
            assert!(t.elapsed() < Duration::from_secs(60), "no temporary file appeared");
            assert!(child.try_wait().unwrap().is_none(), "finished before it could be interrupted");
            std::thread::sleep(Duration::from_millis(5));
        }
        let k = Command::new("kill").arg(format!("-{signal}")).arg(child.id().to_string()).status().unwrap();
        assert!(k.success());
        let status = child.wait().unwrap();
        assert!(status.signal().is_some(), "{container}: should die of the signal, got {status:?}");
        assert_eq!(tree(&d), vec!["m.bsp".to_string()], "{container}: leftovers after SIGINT");
    }
    // Without the signal the same command completes (the hook only slows it down).
    let o = Command::new(exe())
        .arg("convert")
        .arg(&map)
        .args(["-q", "-o"])
        .arg(out_dir.join("m.glb"))
        .env("Q3GLTF_TEST_WRITE_DELAY_MS", "1")
        .output()
        .unwrap();
    assert!(o.status.success());
    assert_eq!(tree(&d), vec!["m.bsp", "new/", "new/deeper/", "new/deeper/m.glb"]);
    std::fs::remove_dir_all(&d).unwrap();
}

/// A write that fails half way (the textures directory name is taken by a file) leaves
/// no .gltf, no .bin, no image and no temporary; the input is never the output.
#[test]
fn failed_write_leaves_nothing_and_input_is_never_overwritten() {
    let d = tmp("failwrite");
    let map = d.join("m.bsp");
    let bsp = q3gltf_samples::generate().bsp.to_bytes();
    std::fs::write(&map, &bsp).unwrap();
    std::fs::write(d.join("out_textures"), b"not a directory").unwrap();
    let o = Command::new(exe()).arg("convert").arg(&map).args(["-q", "-o"]).arg(d.join("out.gltf")).output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(tree(&d), vec!["m.bsp", "out_textures"]);

    // The output named as the input (directly, or through `..`) is refused.
    std::fs::create_dir_all(d.join("x")).unwrap();
    let renamed = d.join("m.glb");
    std::fs::copy(&map, &renamed).unwrap();
    for out in [renamed.clone(), d.join("x/../m.glb")] {
        let o = Command::new(exe()).arg("convert").arg(&renamed).args(["-q", "-o"]).arg(&out).output().unwrap();
        assert_eq!(o.status.code(), Some(1));
        assert!(String::from_utf8_lossy(&o.stderr).contains("overwrite"), "{}", String::from_utf8_lossy(&o.stderr));
        assert_eq!(std::fs::read(&renamed).unwrap(), bsp);
    }
    assert_eq!(tree(&d), vec!["m.bsp", "m.glb", "out_textures", "x/"]);
    std::fs::remove_dir_all(&d).unwrap();
}

/// A map file over the 1 GiB limit is refused from its size, before anything is read (a
/// sparse file: no disk space used, and reading it would take seconds).
#[test]
fn oversized_map_is_refused_before_reading() {
    let d = tmp("huge");
    let p = d.join("huge.bsp");
    let f = std::fs::File::create(&p).unwrap();
    f.set_len((1 << 30) + 1).unwrap();
    drop(f);
    let t = Instant::now();
    let o = Command::new(exe()).arg("convert").arg(&p).args(["-q", "-o"]).arg(d.join("o.glb")).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("huge.bsp") && stderr.contains("limit"), "{stderr}");
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
    std::fs::remove_dir_all(&d).unwrap();
}
