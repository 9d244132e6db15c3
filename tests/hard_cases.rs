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

/// Degenerate geometry in a lightmapped primitive added to the sample: a triangle with a
/// repeated index, one whose corners are distinct vertices at the same position
/// (duplicates), a collinear sliver, a triangle 10 um on a side, a vertex no triangle
/// uses, and a ground triangle 2 km on a side 100 m below the map (its bounding box moves
/// the scene's origin far from the map and is 80 times the map's). Their lightmap coordinates have no area. The fit must
/// end finite with the error of the plain sample (the degenerate triangles carry no data
/// and block no light), on both backends, on the luxel target and on the vertex target
/// with and without subdivision. Guards: `rows::luxel` refuses triangles without lightmap
/// area (counted), `subdivide` never splits a zero-length edge and stops at its vertex
/// budget, positions relative to `Scene::origin` in f64, `Mesh::bounds` over the vertices
/// triangles use, and lights searched around the rows (`pipeline::light_box`), not over
/// the whole geometry: before these two, an isolated vertex or the ground triangle made
/// the placement search a 2 km box and find nothing (error 0.71 instead of 0.025).
#[test]
fn degenerate_tiny_huge_and_duplicate_geometry() {
    let dir = tmp("degenerate");
    let gltf = convert_sample(&dir);
    let plain = dir.join("plain.gltf");
    std::fs::copy(&gltf, &plain).unwrap();
    let mut json = read_json(&gltf);
    let floor = json["materials"].as_array().unwrap().iter().position(|m| m["name"] == "textures/sample/floor").unwrap();
    let up = [0.0f32, 1.0, 0.0];
    let v: Vec<([f32; 3], [f32; 3])> = vec![
        ([13.0, 0.5, -5.5], up),
        ([13.5, 0.5, -5.5], up),
        ([13.0, 0.5, -5.5], up), // a duplicate of 0
        ([13.25, 0.5, -5.5], up), // collinear with 0 and 1
        ([10.0, 1.0, -3.0], up), // no triangle uses it
        ([13.0, 0.8, -5.5], up),
        ([13.00001, 0.8, -5.5], up),
        ([13.0, 0.8, -5.50001], up),
        ([-1000.0, -100.0, -1000.0], up),
        ([1000.0, -100.0, -1000.0], up),
        ([0.0, -100.0, 1000.0], up),
    ];
    let idx: [u32; 15] = [0, 0, 1, 0, 2, 1, 0, 1, 3, 5, 7, 6, 8, 10, 9];
    let bin_path = dir.join(json["buffers"][0]["uri"].as_str().unwrap());
    let mut bin = std::fs::read(&bin_path).unwrap();
    let mut push = |bytes: &[u8], target: u32, json: &mut Value| -> usize {
        bin.resize(bin.len().next_multiple_of(4), 0);
        let views = json["bufferViews"].as_array_mut().unwrap();
        views.push(serde_json::json!({ "buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len(), "target": target }));
        bin.extend_from_slice(bytes);
        views.len() - 1
    };
    let f32s = |it: &mut dyn Iterator<Item = f32>| -> Vec<u8> { it.flat_map(f32::to_le_bytes).collect() };
    let pos = push(&f32s(&mut v.iter().flat_map(|p| p.0)), 34962, &mut json);
    let nrm = push(&f32s(&mut v.iter().flat_map(|p| p.1)), 34962, &mut json);
    // Every lightmap coordinate on one texel centre: no lightmap area anywhere.
    let uv = push(&f32s(&mut v.iter().flat_map(|_| [0.25f32, 0.25])), 34962, &mut json);
    let ind = push(&idx.iter().flat_map(|i| i.to_le_bytes()).collect::<Vec<u8>>(), 34963, &mut json);
    let (lo, hi) = v.iter().fold(([f32::MAX; 3], [f32::MIN; 3]), |(lo, hi), (p, _)| ([0, 1, 2].map(|k| lo[k].min(p[k])), [0, 1, 2].map(|k| hi[k].max(p[k]))));
    let accs = json["accessors"].as_array_mut().unwrap();
    let base = accs.len();
    accs.push(serde_json::json!({ "bufferView": pos, "componentType": 5126, "count": v.len(), "type": "VEC3", "min": lo, "max": hi }));
    accs.push(serde_json::json!({ "bufferView": nrm, "componentType": 5126, "count": v.len(), "type": "VEC3" }));
    accs.push(serde_json::json!({ "bufferView": uv, "componentType": 5126, "count": v.len(), "type": "VEC2" }));
    accs.push(serde_json::json!({ "bufferView": ind, "componentType": 5125, "count": idx.len(), "type": "SCALAR" }));
    json["meshes"][0]["primitives"].as_array_mut().unwrap().push(serde_json::json!({
        "attributes": { "POSITION": base, "NORMAL": base + 1, "TEXCOORD_0": base + 2, "TEXCOORD_1": base + 2 },
        "indices": base + 3, "material": floor,
    }));
    json["buffers"][0]["byteLength"] = bin.len().into();
    std::fs::write(&bin_path, &bin).unwrap();
    std::fs::write(&gltf, serde_json::to_vec(&json).unwrap()).unwrap();

    let runs: [(&str, &[&str]); 4] = [
        ("cpu", &["--scheme", "fast"]),
        ("wgpu", &["--scheme", "fast"]),
        ("cpu", &["--scheme", "fast", "--target", "vertex", "--subdivide", "off"]),
        ("cpu", &["--scheme", "fast", "--target", "vertex", "--subdivide", "1.0", "--max-vertices", "60000"]),
    ];
    for (backend, extra) in runs {
        let r = relight(&gltf, backend, extra);
        let p = relight(&plain, backend, extra);
        assert_eq!(r["triangles_input"].as_u64().unwrap(), p["triangles_input"].as_u64().unwrap() + 5, "{backend} {extra:?}: every triangle read");
        let (e, e0) = (r["rel_error_final"].as_f64().unwrap(), p["rel_error_final"].as_f64().unwrap());
        assert!(e <= e0 * 1.1 + 1e-3, "{backend} {extra:?}: error {e} with the degenerate geometry, {e0} without");
        if extra.contains(&"luxel") || !extra.contains(&"vertex") {
            let l = &r["luxel"];
            // The same luxels, up to the faces' edge rows: their sample points sit on the
            // planes of the walls they meet, where whether a point is buried is a vote of
            // rays that start on the plane, which f32 rounding flips when the origin moves
            // (measured: 72 of 7651; 1 of 6737 before the edge rows were kept).
            let (n, n0) = (l["luxels"].as_i64().unwrap(), p["luxel"]["luxels"].as_i64().unwrap());
            assert!((n - n0).abs() * 1000 <= 15 * n0, "{backend}: {n} luxels with the degenerate geometry, {n0} without");
            assert!(l["triangles_refused"].as_u64().unwrap() + l["triangles_without_luxel"].as_u64().unwrap() >= 5, "{backend}: {l}");
        }
    }
}

/// OpenArena's `suspended`, where the default run once ended worse than it started
/// (0.584 -> 0.602 in a survey of all maps on 2026-11-22). At 5dc1c61 the phases went
/// 0.407 -> 0.361 -> 0.324 and the final exact refit of the linear coefficients, which
/// leaves censored channels out, undid the polish (0.360). Now every phase and the run end
/// no worse than they began (measured on 2026-11-23: 0.413 -> 0.354 -> 0.320). The phases
/// re-trace a light only once it moved `retrace_tol`, so the last phase's error is of
/// slightly stale shadows: the final refit starts from every light traced where it stands
/// (the report's `rel_error_retraced`) and must not end above that; the retrace itself
/// moves the error by little (2026-12-02, with the dense candidates' 174 lights: 0.2218 in
/// the last polish, 0.2238 traced exactly, 0.2233 after the refit).
#[test]
fn suspended_ends_no_worse_than_it_starts() {
    let dir = tmp("suspended");
    let gltf = dir.join("suspended.glb");
    ok(&["convert", "suspended", "--game-dir", common::baseoa().to_str().unwrap(), "-o", gltf.to_str().unwrap(), "-q"]);
    let r = relight(&gltf, "cpu", &[]);
    let (e0, e1) = (r["rel_error_initial"].as_f64().unwrap(), r["rel_error_final"].as_f64().unwrap());
    assert!(e1 < e0, "the run: {e0} -> {e1}");
    let phases = r["phases"].as_array().unwrap();
    assert!(!phases.is_empty());
    let mut last = e0;
    for p in phases {
        let (b, a) = (p["rel_error_before"].as_f64().unwrap(), p["rel_error_after"].as_f64().unwrap());
        assert!(a <= b * 1.001, "{}: {b} -> {a}", p["name"]);
        last = a;
    }
    let retraced = r["rel_error_retraced"].as_f64().expect("the report gives the retraced error");
    assert!(retraced <= last * 1.02, "the exact retrace: {last} -> {retraced}");
    assert!(e1 <= retraced * 1.001, "the final refit: {retraced} -> {e1}");
}
