//! Numerical hard cases of relight, end to end on the bundled sample: each asserts that
//! the run ends without a panic, with finite numbers and a sensible result, on both
//! backends where a kernel is involved (wgpu runs on lavapipe in CI). ARCHITECTURE.md says
//! which guard handles each case.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_q3gltf"))
}

fn q3gltf(args: &[&str]) -> Output {
    Command::new(bin()).args(args).output().expect("run q3gltf")
}

fn ok(args: &[&str]) {
    let out = q3gltf(args);
    assert!(out.status.success(), "q3gltf {args:?} failed:\n{}", String::from_utf8_lossy(&out.stderr));
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("q3gltf-hard-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn convert_sample(dir: &Path) -> PathBuf {
    let out = dir.join("sample.gltf");
    let bsp = common::repo().join("samples/sample/maps/sample.bsp");
    ok(&["convert", bsp.to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"]);
    out
}

fn read_json(p: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

/// Relights `input` on `backend` and returns the report, after checking that every number
/// in it that describes the result is finite and every light non-negative.
fn relight(input: &Path, backend: &str, extra: &[&str]) -> Value {
    let dir = input.parent().unwrap();
    let tag = format!("{}-{backend}", input.file_stem().unwrap().to_string_lossy());
    let rep = dir.join(format!("{tag}.json"));
    let out = dir.join(format!("{tag}.relit.gltf"));
    let mut args = vec!["relight", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", backend, "--report", rep.to_str().unwrap(), "-q"];
    args.extend_from_slice(extra);
    ok(&args);
    let r = read_json(&rep);
    let e = r["rel_error_final"].as_f64().unwrap_or(f64::NAN);
    assert!(e.is_finite() && e >= 0.0, "{tag}: relative error {e}");
    for l in r["lights"].as_array().unwrap() {
        let cd = l["intensity_cd"].as_f64().unwrap_or(f64::NAN);
        assert!(cd.is_finite() && cd >= 0.0, "{tag}: light intensity {cd}");
        for v in l["position_m"].as_array().unwrap().iter().chain(l["color"].as_array().unwrap()) {
            assert!(v.as_f64().is_some_and(f64::is_finite), "{tag}: {l}");
        }
    }
    for k in ["ambient", "bounce", "minlight"] {
        if let Some(a) = r[k].as_array() {
            assert!(a.iter().all(|v| v.as_f64().is_some_and(|x| x.is_finite() && x >= 0.0)), "{tag}: {k} {a:?}");
        }
    }
    // The written file parses.
    gltf::Gltf::open(&out).unwrap_or_else(|e| panic!("{tag}: output does not parse: {e}"));
    r
}

/// Every lightmap image of the converted scene rewritten by `f(x, y, rgba)`; the
/// vertex-lit surface (whose light is in its vertex colours) declared unlit, so that the
/// lightmaps are all the data.
fn rewrite_lightmaps(gltf: &Path, f: &dyn Fn(u32, u32, &mut image::Rgba<u8>)) {
    let mut json = read_json(gltf);
    for m in json["materials"].as_array_mut().unwrap() {
        if m["extras"]["q3_lighting"] == "vertex" {
            m["extras"]["q3_lighting"] = "none".into();
        }
    }
    std::fs::write(gltf, serde_json::to_vec(&json).unwrap()).unwrap();
    let dir = gltf.parent().unwrap();
    let mut done = std::collections::HashSet::new();
    for m in json["materials"].as_array().unwrap() {
        let Some(t) = m["occlusionTexture"]["index"].as_u64() else { continue };
        let img = json["textures"][t as usize]["source"].as_u64().unwrap() as usize;
        let uri = json["images"][img]["uri"].as_str().unwrap().to_string();
        if !done.insert(uri.clone()) {
            continue;
        }
        let path = dir.join(&uri);
        let mut im = image::open(&path).unwrap().to_rgba8();
        for (x, y, p) in im.enumerate_pixels_mut() {
            f(x, y, p);
        }
        im.save(&path).unwrap();
    }
}

/// Sets a texel's colour to grey `v` (alpha kept).
fn grey(p: &mut image::Rgba<u8>, v: u8) {
    p.0[..3].fill(v);
}

/// The converted sample with these point lights (world m, cd) in place of its own.
fn with_lights(gltf: &Path, name: &str, lights: &[([f64; 3], f64)]) -> PathBuf {
    let mut json = read_json(gltf);
    let defs = lights
        .iter()
        .enumerate()
        .map(|(k, (p, cd))| (serde_json::json!({ "type": "point", "color": [1.0, 0.9, 0.8], "intensity": cd }), serde_json::json!({ "name": format!("hard_{k}"), "translation": p })))
        .collect();
    common::set_lights(&mut json, defs);
    let out = gltf.with_file_name(format!("{name}.gltf"));
    std::fs::write(&out, serde_json::to_vec(&json).unwrap()).unwrap();
    out
}

/// The sample's first light entity in glTF meters, and the nearest surface point to it.
fn first_light_and_surface(gltf: &Path) -> ([f64; 3], [f64; 3]) {
    let l = &q3gltf_samples::LIGHTS[0];
    let p = [l.origin[0] * 0.0254, l.origin[2] * 0.0254, -l.origin[1] * 0.0254];
    let scene = q3gltf_relight::io::gltf_in::read(gltf).unwrap();
    let bvh = q3gltf_relight::trace::bvh::Bvh::build(&scene.mesh);
    let local = (glam::DVec3::from(p) - scene.origin).as_vec3();
    let (_, q) = bvh.nearest(local).unwrap();
    (p, (q.as_dvec3() + scene.origin).to_array())
}

/// An all-black lightmap: nothing to explain, so every intensity goes to zero (or no light
/// is placed), never negative or NaN. Guard: the NNLS fit's non-negativity and the
/// interval residual (a black texel is the interval [0, 1) byte, not a division by 0).
#[test]
fn all_black_lightmap() {
    let dir = tmp("black");
    let gltf = convert_sample(&dir);
    rewrite_lightmaps(&gltf, &|_, _, p| grey(p, 0));
    for backend in ["cpu", "wgpu"] {
        let r = relight(&gltf, backend, &["--scheme", "fast"]);
        let total: f64 = r["lights"].as_array().unwrap().iter().map(|l| l["intensity_cd"].as_f64().unwrap()).sum();
        // Measured: no light at all. (Light that adds less than a byte anywhere would
        // still be within the data: a black byte stands for [0, 1).)
        assert!(r["rel_error_final"].as_f64().unwrap() < 1e-9, "{backend}: {}", r["rel_error_final"]);
        assert!(total < 50.0, "{backend}: {total} cd of light for a black lightmap: {}", r["lights"]);
    }
}

/// A fully saturated lightmap: every texel is censored (a lower bound only), so the data
/// asks for at least that much light everywhere; the fit places lights that reach the
/// bounds (measured: two lights, error 0). Guards: censored rows as one-sided residuals in
/// the objective, the error and the placement (`init::shortfall`).
#[test]
fn saturated_lightmap() {
    let dir = tmp("saturated");
    let gltf = convert_sample(&dir);
    rewrite_lightmaps(&gltf, &|_, _, p| grey(p, 255));
    for backend in ["cpu", "wgpu"] {
        let r = relight(&gltf, backend, &["--scheme", "fast"]);
        assert!(r["rel_error_final"].as_f64().unwrap() < 0.01, "{backend}: {}", r["rel_error_final"]);
        assert!(!r["lights"].as_array().unwrap().is_empty());
    }
}

/// Every texel censored but one: finite, no panic; the one texel is matched.
#[test]
fn all_censored_but_one_texel() {
    let dir = tmp("one-texel");
    let gltf = convert_sample(&dir);
    rewrite_lightmaps(&gltf, &|x, y, p| grey(p, if (x, y) == (20, 20) { 80 } else { 255 }));
    for backend in ["cpu", "wgpu"] {
        let r = relight(&gltf, backend, &["--scheme", "fast"]);
        let (e0, e1) = (r["rel_error_initial"].as_f64().unwrap(), r["rel_error_final"].as_f64().unwrap());
        assert!(e1 < e0, "{backend}: {e0} -> {e1}");
    }
}

/// A light moved onto a surface (distance 0), a light far outside the map, two coincident
/// lights, and a single light, each as the start (`--init input`), on both backends.
/// Guards: the 16-unit distance clamp (`rows::Sampling::eps`) and the shadow rays' inhibit
/// radius keep `1/d^2` and its gradient finite; non-finite gradient entries are zeroed in
/// `optim`; a light that explains nothing is pruned; coincident lights are merged.
#[test]
fn lights_on_surfaces_outside_and_coincident() {
    let dir = tmp("lights");
    let gltf = convert_sample(&dir);
    let (p, on_surface) = first_light_and_surface(&gltf);
    let cases: [(&str, Vec<([f64; 3], f64)>); 4] = [
        ("on_surface", vec![(on_surface, 4000.0)]),
        ("outside", vec![(p, 4000.0), ([p[0] + 500.0, p[1] + 300.0, p[2] - 400.0], 4000.0)]),
        ("coincident", vec![(p, 2000.0), (p, 2000.0)]),
        ("single", vec![(p, 4000.0)]),
    ];
    for (name, lights) in cases {
        let input = with_lights(&gltf, name, &lights);
        for backend in ["cpu", "wgpu"] {
            let r = relight(&input, backend, &["--init", "input", "--scheme", "fast"]);
            let e0 = r["rel_error_initial"].as_f64().unwrap();
            let e1 = r["rel_error_final"].as_f64().unwrap();
            assert!(e1 <= e0 + 1e-9, "{name} on {backend}: the fit made it worse, {e0} -> {e1}");
            if name == "coincident" {
                assert_eq!(r["lights"].as_array().unwrap().len(), 1, "{name}: coincident lights are one light: {}", r["lights"]);
            }
        }
    }
}

/// NaN and infinite numbers in an input glTF: a clear error naming the file, no panic.
/// Guard: `io::gltf_in` checks every float it reads (positions, normals, UVs, light
/// parameters, transforms).
#[test]
fn non_finite_numbers_in_the_input_are_refused() {
    let dir = tmp("nan");
    let gltf = convert_sample(&dir);
    let json = read_json(&gltf);
    // A NaN position: the first float of the first POSITION accessor.
    let acc = json["meshes"][0]["primitives"][0]["attributes"]["POSITION"].as_u64().unwrap() as usize;
    let view = &json["bufferViews"][json["accessors"][acc]["bufferView"].as_u64().unwrap() as usize];
    let offset = view["byteOffset"].as_u64().unwrap_or(0) as usize + json["accessors"][acc]["byteOffset"].as_u64().unwrap_or(0) as usize;
    let bin = dir.join(json["buffers"][0]["uri"].as_str().unwrap());
    let mut bytes = std::fs::read(&bin).unwrap();
    bytes[offset..offset + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&bin, &bytes).unwrap();
    let out = q3gltf(&["relight", gltf.to_str().unwrap(), "-o", dir.join("o.gltf").to_str().unwrap(), "--backend", "cpu", "-q"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && !err.contains("panicked") && err.contains("sample.gltf"), "{err}");

    // A light with an infinite intensity and one with a NaN position.
    let dir = tmp("nan-light");
    let gltf = convert_sample(&dir);
    let (p, _) = first_light_and_surface(&gltf);
    for (name, light) in [("inf_intensity", (p, f64::INFINITY)), ("nan_position", ([f64::NAN, p[1], p[2]], 4000.0))] {
        let input = with_lights(&gltf, name, &[light]);
        // serde_json writes non-finite numbers as null: patch the text to the literal.
        let text = std::fs::read_to_string(&input).unwrap().replace("null", if name == "inf_intensity" { "1e999" } else { "NaN" });
        std::fs::write(&input, text).unwrap();
        let out = q3gltf(&["relight", input.to_str().unwrap(), "-o", dir.join("o.gltf").to_str().unwrap(), "--init", "input", "--backend", "cpu", "-q"]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && !err.contains("panicked") && err.contains(&format!("{name}.gltf")), "{name}: {err}");
    }
}
