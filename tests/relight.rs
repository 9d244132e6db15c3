//! End-to-end tests of `q3gltf relight` on real inputs: the bundled sample (convert, then
//! relight, compared with the sample's known light entities), re-runs on its own output
//! (`--init input`, locked lights), and a real OpenArena map.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_q3gltf"))
}

fn run(args: &[&str]) -> String {
    let out = Command::new(bin()).args(args).output().expect("run q3gltf");
    assert!(out.status.success(), "q3gltf {args:?} failed:\n{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("q3gltf-relight-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn report(p: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

fn convert_sample(dir: &Path) -> PathBuf {
    let out = dir.join("sample.gltf");
    let bsp = common::repo().join("samples/sample/maps/sample.bsp");
    run(&["convert", bsp.to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"]);
    out
}

/// The sample's light entities in glTF meters: (x, y, z)q3 -> (x, z, -y) * 0.0254, and
/// q3map2's `light` key as candela (163 * light at the default scale and overbright).
fn sample_truth() -> Vec<([f64; 3], f64)> {
    q3gltf_samples::LIGHTS.iter().map(|l| ([l.origin[0] * 0.0254, l.origin[2] * 0.0254, -l.origin[1] * 0.0254], 163.0 * l.light)).collect()
}

fn lights_of(r: &Value) -> Vec<([f64; 3], f64, String)> {
    r["lights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| {
            let p: Vec<f64> = l["position_m"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
            ([p[0], p[1], p[2]], l["intensity_cd"].as_f64().unwrap(), l["name"].as_str().unwrap().to_string())
        })
        .collect()
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Every true light `(position + offset, cd)` has a found light within `tol_m` meters
/// whose intensity is within `tol_rel`.
fn assert_recovered(found: &[([f64; 3], f64, String)], truth: &[([f64; 3], f64)], offset: [f64; 3], tol_m: f64, tol_rel: f64) {
    for &(p, cd) in truth {
        let p = [p[0] + offset[0], p[1] + offset[1], p[2] + offset[2]];
        let best = found.iter().min_by(|a, b| dist(a.0, p).total_cmp(&dist(b.0, p))).expect("some light was found");
        assert!(dist(best.0, p) < tol_m, "light at {p:?} recovered at {:?} ({} m away)", best.0, dist(best.0, p));
        assert!((best.1 / cd - 1.0).abs() < tol_rel, "light at {p:?}: {} cd recovered, {cd} cd expected", best.1);
    }
}

#[test]
fn sample_convert_then_relight_recovers_the_light_entities() {
    let dir = tmp("sample");
    let gltf = convert_sample(&dir);
    let out = dir.join("sample.relit.gltf");
    let rep = dir.join("report.json");
    let plot = dir.join("curve.png");
    let baked = dir.join("bake");
    run(&["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", "cpu", "--report", rep.to_str().unwrap(), "--plot", plot.to_str().unwrap(), "--bake", baked.to_str().unwrap(), "-q"]);
    let r = report(&rep);
    let found = lights_of(&r);
    // `--bake`: the report names the bake's files, and the bake of the written file has the
    // error relight reported for it.
    let files = r["bake"]["files"].as_array().expect("the report lists the bake's files");
    assert!(files.len() >= 8 && files.iter().any(|f| f == "baked.glb"), "{files:?}");
    for f in files {
        assert!(baked.join(f.as_str().unwrap()).is_file(), "{f} listed, not written");
    }
    let (eb, er) = (r["bake"]["rel_error"].as_f64().unwrap(), r["rel_error_final"].as_f64().unwrap());
    assert!((eb / er - 1.0).abs() < 0.05, "bake error {eb}, relight's {er}");
    // Scene diagonal of the sample, for the tolerance.
    let doc = gltf::Gltf::open(&out).expect("output parses as glTF");
    let lights: Vec<_> = doc.lights().map(|l| l.collect::<Vec<_>>()).unwrap_or_default();
    assert_eq!(lights.len(), found.len(), "every reported light is in the file");
    assert_eq!(found.len(), 3, "as few lights as the scene needs: {found:?}");
    // Measured: every light within 1 cm and 1% (the luxel target compares the model with
    // the lightmap where q3map2 computed it).
    assert_recovered(&found, &sample_truth(), [0.0; 3], 0.05, 0.02);
    let err = r["rel_error_final"].as_f64().unwrap();
    // Measured about 0.044 (0.035 with the true lights: a handful of luxels whose shadow rays
    // graze an occluder's edge exactly, where q3map2's test and ours disagree); 0.058 since
    // relight samples a curved patch's luxels where q3map2 does (2026-11-26): the sample's
    // generator baked its arch at the luxels' centres on the surface, so those rows now sit
    // up to half a luxel from where their bytes were computed. (Baking the arch at q3map2's
    // points needs relight to cast the arch's shadows from q3map2's coarse mesh too, as
    // `-patchshadows` does: with the drawn arch as occluder it was 0.056.)
    assert!(err < 0.065, "relative error {err}");
    // The fit starts where the placement ended (on the sample its subsample is every
    // row): the undecided bounce joins the phases only where it lowers the error (it took
    // the placed lights from 0.020 to 0.136 when it started on).
    let rows = r["luxel"]["luxels"].as_u64().unwrap() + r["luxel"]["vertex_rows"].as_u64().unwrap();
    assert_eq!(r["auto"]["sample_vertices"].as_u64(), Some(rows), "the placement saw every row");
    let placed = r["auto"]["errors"].as_array().unwrap().last().unwrap().as_f64().unwrap();
    let start = r["rel_error_initial"].as_f64().unwrap();
    assert!(start <= placed * 1.1, "the fit starts at {start}, the placement ended at {placed}");
    assert!(r["iterations"].as_array().unwrap().len() > 3, "iterations are reported");
    let png = image::open(&plot).expect("the plot is a PNG").to_rgb8();
    assert!(png.width() >= 600);
    // A title (dark text across the top) and a legend: one solid swatch per phase that has
    // iterations, in that phase's colour.
    let dark_on_top = (0..png.width()).flat_map(|x| (0..40).map(move |y| (x, y))).filter(|&(x, y)| png.get_pixel(x, y).0[0] < 128).count();
    assert!(dark_on_top > 500, "no title ({dark_on_top} dark pixels on top)");
    use q3gltf_relight::report::{PHASE_COLORS, PLACEMENT_COLOR};
    let mut series: Vec<Option<u64>> = r["iterations"].as_array().unwrap().iter().map(|i| (!i["placement"].as_bool().unwrap()).then(|| i["phase"].as_u64().unwrap())).collect();
    series.dedup();
    assert!(series.contains(&None) && series.contains(&Some(0)), "placement and fit iterations: {series:?}");
    for k in series {
        let c = k.map_or(PLACEMENT_COLOR, |k| PHASE_COLORS[k as usize % PHASE_COLORS.len()]);
        let swatch = (0..png.width() - 20).any(|x| (60..png.height() - 4).any(|y| (0..20).all(|dx| (0..4).all(|dy| *png.get_pixel(x + dx, y + dy) == c))));
        assert!(swatch, "no legend swatch for {k:?}");
    }

    // The thesis's vertex target (lightmap resolution subdivision, mass-lumped projection):
    // hard shadow edges are blurred into the vertices, so its floor is higher (about 0.07).
    let rep_v = dir.join("report-vertex.json");
    run(&["relight", gltf.to_str().unwrap(), "-o", dir.join("v.glb").to_str().unwrap(), "--target", "vertex", "--backend", "cpu", "--report", rep_v.to_str().unwrap(), "-q"]);
    let rv = report(&rep_v);
    assert_eq!(rv["target_space"], "vertex");
    assert!(rv["subdivision"]["vertices_after"].as_u64().unwrap() > rv["subdivision"]["vertices_before"].as_u64().unwrap());
    assert_recovered(&lights_of(&rv), &sample_truth(), [0.0; 3], 0.12, 0.03);
    let err_v = rv["rel_error_final"].as_f64().unwrap();
    assert!(err_v < 0.08, "vertex target: relative error {err_v}");
    // Without subdivision every vertex is a polygon's corner, in the plane of the wall beside
    // it: the placement's candidates must still come into the room (they once never did,
    // leaving the ambient alone at 0.62; measured 0.49 with 10 lights).
    let rep_c = dir.join("report-corners.json");
    run(&["relight", gltf.to_str().unwrap(), "-o", dir.join("c.glb").to_str().unwrap(), "--target", "vertex", "--subdivide", "off", "--backend", "cpu", "--report", rep_c.to_str().unwrap(), "-q"]);
    let rc = report(&rep_c);
    assert!(rc["auto"]["added"].as_u64().unwrap() >= 2, "corner vertices: {}", rc["auto"]);
    let err_c = rc["rel_error_final"].as_f64().unwrap();
    assert!(err_c < 0.55, "corner vertices: relative error {err_c}");

    // Re-run on its own output with the lights as the start: not worse.
    let out2 = dir.join("sample.relit2.glb");
    let rep2 = dir.join("report2.json");
    run(&["relight", out.to_str().unwrap(), "-o", out2.to_str().unwrap(), "--init", "input", "--backend", "cpu", "--report", rep2.to_str().unwrap(), "-q"]);
    let r2 = report(&rep2);
    let err2 = r2["rel_error_final"].as_f64().unwrap();
    assert!(err2 <= err + 1e-3, "re-run made the error worse: {err} -> {err2}");
    assert_eq!(lights_of(&r2).len(), 3);
}

#[test]
fn locked_light_does_not_move_and_input_is_never_overwritten() {
    let dir = tmp("locked");
    let gltf = convert_sample(&dir);
    let out = dir.join("a.gltf");
    run(&["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", "cpu", "--scheme", "fast", "-q"]);
    // Lock light_000 and displace it by 0.5 m, as a user would in Blender.
    let mut json: Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let nodes = json["nodes"].as_array_mut().unwrap();
    let node = nodes.iter_mut().find(|n| n["name"] == "light_000").expect("light_000 node");
    let mut t: Vec<f64> = node["translation"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    t[1] -= 0.5;
    node["translation"] = serde_json::json!(t);
    node["extras"] = serde_json::json!({ "locked": true });
    let edited = dir.join("edited.gltf");
    std::fs::write(&edited, serde_json::to_vec(&json).unwrap()).unwrap();
    let out2 = dir.join("b.gltf");
    let rep = dir.join("r.json");
    run(&["relight", edited.to_str().unwrap(), "-o", out2.to_str().unwrap(), "--init", "input", "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"]);
    let r = report(&rep);
    let locked: Vec<_> = r["lights"].as_array().unwrap().iter().filter(|l| l["locked"] == true).collect();
    assert_eq!(locked.len(), 1);
    let p: Vec<f64> = locked[0]["position_m"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!(dist([p[0], p[1], p[2]], [t[0], t[1], t[2]]) < 1e-5, "locked light moved: {p:?} vs {t:?}");

    // Refuses to overwrite its input.
    let st = Command::new(bin()).args(["relight", edited.to_str().unwrap(), "-o", edited.to_str().unwrap(), "-q"]).output().unwrap();
    assert!(!st.status.success());
    assert!(String::from_utf8_lossy(&st.stderr).contains("overwrite"));
}

#[test]
fn invalid_inputs_give_clear_errors() {
    let dir = tmp("bad");
    let junk = dir.join("junk.gltf");
    std::fs::write(&junk, b"{ not json").unwrap();
    let st = Command::new(bin()).args(["relight", junk.to_str().unwrap(), "-o", dir.join("o.gltf").to_str().unwrap(), "-q"]).output().unwrap();
    assert!(!st.status.success());
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("junk.gltf") && !err.contains("panicked"), "{err}");
    // A scene without baked lighting: nothing to fit.
    let gltf = convert_sample(&dir);
    let mut json: Value = serde_json::from_slice(&std::fs::read(&gltf).unwrap()).unwrap();
    for m in json["materials"].as_array_mut().unwrap() {
        m.as_object_mut().unwrap().remove("occlusionTexture");
        m["extras"]["q3_lighting"] = "none".into();
    }
    let unlit = dir.join("unlit.gltf");
    std::fs::write(&unlit, serde_json::to_vec(&json).unwrap()).unwrap();
    let st = Command::new(bin()).args(["relight", unlit.to_str().unwrap(), "-o", dir.join("o.gltf").to_str().unwrap(), "-q"]).output().unwrap();
    assert!(!st.status.success());
    assert!(String::from_utf8_lossy(&st.stderr).contains("no surface carries baked lighting"));
}

#[test]
fn real_map_end_to_end_on_the_wgpu_backend() {
    let dir = tmp("oa_dm1");
    let out = dir.join("oa_dm1.glb");
    run(&["convert", "oa_dm1", "--game-dir", common::baseoa().to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"]);
    let relit = dir.join("oa_dm1.relit.glb");
    let rep = dir.join("r.json");
    // CI has no GPU: this runs on Mesa's software Vulkan. Small budget: a 3x3 grid start.
    run(&[
        "relight", out.to_str().unwrap(), "-o", relit.to_str().unwrap(), "--backend", "wgpu", "--subdivide", "off", "--init", "grid:3",
        "--scheme", "fast", "--max-iterations", "8", "--report", rep.to_str().unwrap(), "-q",
    ]);
    let r = report(&rep);
    assert!(r["backend"].as_str().unwrap().starts_with("wgpu"), "{}", r["backend"]);
    let (e0, e1) = (r["rel_error_initial"].as_f64().unwrap(), r["rel_error_final"].as_f64().unwrap());
    assert!(e1 < e0, "the error did not go down: {e0} -> {e1}");
    assert!(gltf::Gltf::open(&relit).is_ok());
}

/// The default fit does not hang on which rows the placement samples: `--seed` picks the
/// offset of its every-8th-row subsample. Before the placement looked past the rows whose
/// candidates had failed, three of these offsets ended at 0.35, 0.34 and 0.39 on oa_dm1
/// (it stopped at 49, 45 and 41 lights); now 0.28, 0.27 and 0.28.
#[test]
fn the_default_fit_holds_across_placement_subsamples() {
    let dir = tmp("seeds");
    let out = dir.join("oa_dm1.glb");
    run(&["convert", "oa_dm1", "--game-dir", common::baseoa().to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"]);
    let mut errors = Vec::new();
    for seed in ["1", "2", "4"] {
        let rep = dir.join(format!("{seed}.json"));
        run(&["relight", out.to_str().unwrap(), "-o", dir.join("relit.glb").to_str().unwrap(), "--backend", "cpu", "--seed", seed, "--report", rep.to_str().unwrap(), "-q"]);
        let r = report(&rep);
        // Each phase's re-traces are part of its time and of the run's rays.
        let phases = r["phases"].as_array().unwrap();
        for p in phases {
            let (t, tr) = (p["time_s"].as_f64().unwrap(), p["trace_s"].as_f64().unwrap());
            assert!((0.0..=t).contains(&tr), "--seed {seed} {}: {tr} s re-tracing of {t} s", p["name"]);
        }
        let phase_rays: u64 = phases.iter().map(|p| p["rays"].as_u64().unwrap()).sum();
        assert!(phase_rays <= r["rays_traced"].as_u64().unwrap(), "--seed {seed}: the phases re-traced {phase_rays} rays of {}", r["rays_traced"]);
        common::assert_terms_within_allowance(&format!("oa_dm1 --seed {seed}"), &r);
        errors.push((seed, r["rel_error_final"].as_f64().unwrap(), r["lights"].as_array().unwrap().len()));
    }
    for &(seed, e, n) in &errors {
        assert!(e < 0.31, "--seed {seed}: the default fit ended at {e:.4} with {n} lights ({errors:?})");
    }
}

/// The Blender loop's second step on a real map: relight run again on its own output with
/// `--init input` starts where the first fit ended (the file states the model it fitted:
/// surface lights it switched off are written dark, the rest from `q3_relight`) and ends
/// no worse. Once the re-run started at 0.35 from 0.27: the switched-off lamps kept their
/// source emission.
#[test]
fn a_relit_real_map_reruns_from_its_own_state() {
    let dir = tmp("rerun");
    let out = dir.join("oa_dm1.glb");
    run(&["convert", "oa_dm1", "--game-dir", common::baseoa().to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"]);
    let relit = dir.join("oa_dm1.relit.glb");
    let rep = dir.join("first.json");
    run(&["relight", out.to_str().unwrap(), "-o", relit.to_str().unwrap(), "--backend", "cpu", "--scheme", "fast", "--report", rep.to_str().unwrap(), "-q"]);
    let r = report(&rep);
    let first = r["rel_error_final"].as_f64().unwrap();
    // Every surface-light shader the fit switched off is dark in the file, every one it
    // kept emits.
    let json = gltf::Gltf::open(&relit).unwrap();
    let surfaces = r["surfaces"].as_array().unwrap();
    assert!(!surfaces.is_empty(), "oa_dm1 has surface-light shaders");
    for s in surfaces {
        let shader = s["shader"].as_str().unwrap();
        let on = !s["radiance"].is_null();
        for m in json.materials().filter(|m| m.name().is_some_and(|n| n.split('#').next() == Some(shader))) {
            let e = m.emissive_factor();
            assert_eq!(e.iter().any(|c| *c > 0.0), on, "{shader}: emission {e:?}, fitted {}", s["radiance"]);
        }
    }
    let rep2 = dir.join("second.json");
    run(&["relight", relit.to_str().unwrap(), "-o", dir.join("again.glb").to_str().unwrap(), "--init", "input", "--backend", "cpu", "--scheme", "fast", "--report", rep2.to_str().unwrap(), "-q"]);
    let r2 = report(&rep2);
    let (start, end) = (r2["rel_error_initial"].as_f64().unwrap(), r2["rel_error_final"].as_f64().unwrap());
    assert!((start - first).abs() < 1e-3, "the re-run starts at {start}, the first fit ended at {first}");
    assert!(end <= first + 1e-3, "the re-run ended worse: {first} -> {end}");
}

/// The thesis's estimator (`--estimator tracing`) end to end on a real map, on both
/// backends: the error goes down from the grid's start, the report names the estimator and
/// counts its light paths, and a luxel target is refused with a clear error.
#[test]
fn thesis_estimator_end_to_end_on_a_real_map() {
    let dir = tmp("tracing");
    let out = dir.join("oa_dm1.glb");
    run(&["convert", "oa_dm1", "--game-dir", common::baseoa().to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"]);
    let relit = dir.join("oa_dm1.relit.glb");
    for backend in ["cpu", "wgpu"] {
        let rep = dir.join(format!("{backend}.json"));
        // L-BFGS (thesis5) moves a dim grid much further in a few iterations than Adam's 0.1 steps.
        run(&[
            "relight", out.to_str().unwrap(), "-o", relit.to_str().unwrap(), "--backend", backend, "--target", "vertex", "--subdivide", "off", "--init", "grid:3",
            "--scheme", "thesis5", "--estimator", "tracing", "--rays", "5000", "--max-iterations", "4", "--report", rep.to_str().unwrap(), "-q",
        ]);
        let r = report(&rep);
        assert!(r["backend"].as_str().unwrap().contains("light tracing 5000 rays/light"), "{}", r["backend"]);
        assert_eq!(r["estimator"]["kind"], "tracing");
        let (e0, e1) = (r["rel_error_initial"].as_f64().unwrap(), r["rel_error_final"].as_f64().unwrap());
        assert!(e1.is_finite() && e1 < e0 - 0.05, "{backend}: the error did not go down: {e0} -> {e1}");
        let (evals, rays) = (r["evaluations"].as_u64().unwrap(), r["rays_traced"].as_u64().unwrap());
        assert!(rays >= evals * 9 * 5000, "{backend}: {rays} light paths for {evals} evaluations of 9 lights");
        assert_eq!(r["lights"].as_array().unwrap().len(), 9, "the thesis's method keeps its grid");
        assert!(gltf::Gltf::open(&relit).is_ok());
    }
    let err = Command::new(bin()).args(["relight", out.to_str().unwrap(), "-o", relit.to_str().unwrap(), "--estimator", "tracing", "--init", "grid:3"]).output().unwrap();
    assert!(!err.status.success());
    assert!(String::from_utf8_lossy(&err.stderr).contains("needs --target vertex"), "{}", String::from_utf8_lossy(&err.stderr));
}

/// The target projection on wgpu (`shaders/target.wgsl`) against the CPU reference, on real
/// inputs: the converted sample at lightmap resolution and oa_dm1 as converted. Per vertex
/// and channel, value, weight, lower bound, albedo and area agree within 1e-4 relative to
/// the channel's largest value in the scene; a quadrature point that lands exactly on a
/// texel edge may round to the other texel on the GPU (fused multiply-adds), so a few
/// vertices in a million are allowed up to 1e-2.
#[test]
fn target_projection_wgpu_agrees_with_cpu_on_real_maps() {
    use q3gltf_relight::io::gltf_in;
    use q3gltf_relight::rows::projection as target;
    use q3gltf_relight::{gpu, subdivide};
    let dir = tmp("target-gpu");
    let sample = convert_sample(&dir);
    let map = dir.join("oa_dm1.glb");
    run(&["convert", "oa_dm1", "--game-dir", common::baseoa().to_str().unwrap(), "-o", map.to_str().unwrap(), "-q"]);
    let ctx = gpu::Context::new().expect("a wgpu adapter (install mesa-vulkan-drivers)");
    for (path, subdivide) in [(&sample, true), (&map, false)] {
        let mut scene = gltf_in::read(path).unwrap();
        if subdivide {
            subdivide::subdivide(&mut scene.mesh, &scene.materials, &scene.textures, subdivide::Bound::Texels(1.0), 2_000_000);
        }
        let (c, cs) = target::project_cpu(&scene);
        let (sums, samples) = ctx.target_sums(&scene).unwrap();
        let (g, gs) = target::gather(&scene, &sums, samples);
        assert_eq!(cs.samples, gs.samples, "{}: sample counts", path.display());
        assert_eq!(cs.with_target, gs.with_target, "{}: vertices with a target", path.display());
        let fields: [(&str, &Vec<[f32; 3]>, &Vec<[f32; 3]>); 4] = [("value", &c.value, &g.value), ("weight", &c.weight, &g.weight), ("lower", &c.lower, &g.lower), ("albedo", &c.albedo, &g.albedo)];
        for (name, a, b) in fields {
            let scale = a.iter().flat_map(|v| v.iter()).fold(0.0f32, |m, &x| m.max(x.abs())).max(1e-12);
            let diffs: Vec<f32> = a.iter().zip(b).map(|(x, y)| (0..3).map(|k| (x[k] - y[k]).abs() / scale).fold(0.0, f32::max)).collect();
            let over = diffs.iter().filter(|&&d| d > 1e-4).count();
            let worst = diffs.iter().copied().fold(0.0, f32::max);
            assert!(over * 100_000 <= diffs.len() && worst < 1e-2, "{} {name}: {over} of {} vertices differ by more than 1e-4 (worst {worst:e})", path.display(), diffs.len());
        }
        let area_diff = c.area.iter().zip(&g.area).map(|(x, y)| (x - y).abs() / x.abs().max(1e-12)).fold(0.0f32, f32::max);
        assert!(area_diff < 1e-4, "{}: vertex areas differ by {area_diff:e}", path.display());
    }
}

/// The surface lights' basis on wgpu (`shaders/surface_lights.wgsl`) against the CPU
/// reference, on a real map: oa_dm1 as converted (its flames, two-sided `cull disable`
/// emitters, and its other surface lights, shadowed by q3map2's pieces), rendered with
/// every emitting shader at its declared radiance and nothing else. Per row and channel
/// the irradiance agrees within 1e-4 of the brightest row's; a shadow ray that grazes a
/// piece's edge may decide otherwise in the GPU's fused arithmetic, so one row in a
/// thousand may differ by up to 1% (on lavapipe none differs by 1e-4: worst 7.5e-5).
#[test]
fn surface_lights_wgpu_agree_with_cpu_on_a_real_map() {
    use q3gltf_relight::io::gltf_in;
    use q3gltf_relight::model::{surface, Model};
    use q3gltf_relight::pipeline::{render_on, BackendChoice};
    let dir = tmp("surface-gpu");
    let map = dir.join("oa_dm1.glb");
    run(&["convert", "oa_dm1", "--game-dir", common::baseoa().to_str().unwrap(), "-o", map.to_str().unwrap(), "-q"]);
    let scene = gltf_in::read(&map).unwrap();
    let (groups, patches) = surface::patches(&scene);
    assert!(groups.len() >= 2 && patches.len() >= 50, "{} groups, {} patches", groups.len(), patches.len());
    assert!(patches.iter().any(|p| p.two_sided), "oa_dm1's flames emit from both faces");
    let model = Model { surfaces: groups.iter().map(|g| Some(g.source_rgb)).collect(), ..Model::default() };
    let cpu = render_on(&scene, &model, 0, 0, BackendChoice::Cpu).unwrap();
    let gpu = render_on(&scene, &model, 0, 0, BackendChoice::Wgpu).expect("a wgpu adapter (install mesa-vulkan-drivers)");
    assert!(gpu.backend.starts_with("wgpu"), "{}", gpu.backend);
    assert_eq!(cpu.irradiance.len(), gpu.irradiance.len());
    let top = cpu.irradiance.iter().flat_map(|e| e.iter()).copied().fold(0.0f64, f64::max);
    let lit = cpu.irradiance.iter().filter(|e| e[0] > 1e-3 * top).count();
    assert!(top > 0.0 && lit > 5_000, "the surface lights reach {lit} rows");
    let diffs: Vec<f64> = cpu.irradiance.iter().zip(&gpu.irradiance).map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs() / top).fold(0.0, f64::max)).collect();
    let over = diffs.iter().filter(|&&d| d > 1e-4).count();
    let worst = diffs.iter().copied().fold(0.0, f64::max);

    assert!(over * 1000 <= diffs.len() && worst < 1e-2, "{over} of {} rows differ by more than 1e-4 of the brightest (worst {worst:e})", diffs.len());
}

/// The sun's visibility on wgpu (`shaders/sun.wgsl`) against the CPU reference, on a real
/// map with sky: oacmpdm4 as converted, rendered with a sun alone from the direction of
/// the pack's skies' `q3map_sun`, from one along an axis (azimuth 0, where the ray's zero
/// component sends the CPU's walk through its NaN-keeping slab test, which the kernel
/// spells out) and from a low one. Each direction lights thousands of rows, and all but
/// one row in a thousand have the CPU's irradiance to the bit: a ray that grazes an edge
/// may decide otherwise in a device's arithmetic (on lavapipe 0, 2 and 0 of the 154,808
/// rows differ, of 40,842, 33,574 and 32,670 lit).
#[test]
fn the_sun_on_wgpu_lights_a_real_map_as_the_cpu_does() {
    use q3gltf_relight::io::gltf_in;
    use q3gltf_relight::model::{Model, Sun};
    use q3gltf_relight::pipeline::{render_on, BackendChoice};
    let dir = tmp("sun-gpu");
    let map = dir.join("oacmpdm4.glb");
    run(&["convert", "oacmpdm4", "--game-dir", common::baseoa().to_str().unwrap(), "--game-dir", common::oacmp().to_str().unwrap(), "-o", map.to_str().unwrap(), "-q"]);
    let scene = gltf_in::read(&map).unwrap();
    assert!(scene.materials.iter().any(|m| m.sky), "oacmpdm4 has sky surfaces");
    // The pack's `q3map_sun .9 .9 1 70 65 78` (azimuth 65, elevation 78 degrees, Quake
    // axes: z up) in glTF axes (y up, z = -Quake y).
    let (az, el) = (65f32.to_radians(), 78f32.to_radians());
    let pack = glam::Vec3::new(el.cos() * az.cos(), el.sin(), -el.cos() * az.sin());
    let dirs = [pack, glam::Vec3::new(0.6, 0.8, 0.0), glam::Vec3::new(-0.35, 0.25, 0.9).normalize()];
    for to_sun in dirs {
        let model = Model { sun: Some(Sun { to_sun, rgb: [1.0, 0.9, 0.8] }), ..Model::default() };
        let cpu = render_on(&scene, &model, 0, 0, BackendChoice::Cpu).unwrap();
        let gpu = render_on(&scene, &model, 0, 0, BackendChoice::Wgpu).expect("a wgpu adapter (install mesa-vulkan-drivers)");
        assert!(gpu.backend.starts_with("wgpu"), "{}", gpu.backend);
        assert_eq!(cpu.irradiance.len(), gpu.irradiance.len());
        let lit = cpu.irradiance.iter().filter(|e| e[0] > 0.0).count();
        assert!(lit > 2_000, "the sun towards {to_sun} lights {lit} rows");
        let differ = cpu.irradiance.iter().zip(&gpu.irradiance).filter(|(a, b)| a != b).count();
        assert!(differ * 1000 <= cpu.irradiance.len(), "towards {to_sun}: {differ} of {} rows differ ({lit} lit)", cpu.irradiance.len());
    }
}

/// The sky light's rays on wgpu (`shaders/sky.wgsl`) against the CPU reference
/// (`sky_visible_from`), on a real map: oacmpctf1 as converted, whose shaders carry
/// q3map2's `q3map_skyLight`, lit by a sky of irradiance 1 alone, so that each row's
/// irradiance is its sky basis `D_i`, a mean over the sky's suns. A ray that grazes an
/// edge may be decided otherwise by a device's rounding, changing a row's mean by one
/// sun's cosine over their count (on lavapipe 1 of the 244,795 rows differs, by 0.005:
/// one of the 197 suns; 217,578 rows see the sky).
#[test]
fn the_sky_on_wgpu_lights_a_real_map_as_the_cpu_does() {
    use q3gltf_relight::io::gltf_in;
    use q3gltf_relight::model::Model;
    use q3gltf_relight::pipeline::{render_on, BackendChoice};
    let dir = tmp("sky-gpu");
    let map = dir.join("oacmpctf1.glb");
    run(&["convert", "oacmpctf1", "--game-dir", common::baseoa().to_str().unwrap(), "--game-dir", common::oacmp().to_str().unwrap(), "-o", map.to_str().unwrap(), "-q"]);
    let scene = gltf_in::read(&map).unwrap();
    assert!(scene.materials.iter().any(|m| !m.sky_lights.is_empty()), "oacmpctf1 has a sky light");
    let model = Model { sky: Some([1.0; 3]), ..Model::default() };
    let cpu = render_on(&scene, &model, 0, 0, BackendChoice::Cpu).unwrap();
    let gpu = render_on(&scene, &model, 0, 0, BackendChoice::Wgpu).expect("a wgpu adapter (install mesa-vulkan-drivers)");
    assert!(gpu.backend.starts_with("wgpu"), "{}", gpu.backend);
    assert_eq!(cpu.irradiance.len(), gpu.irradiance.len());
    let n = cpu.irradiance.len();
    let lit = cpu.irradiance.iter().filter(|e| e[0] > 0.0).count();
    assert!(lit > 2_000, "the sky lights {lit} of {n} rows");
    let differ = cpu.irradiance.iter().zip(&gpu.irradiance).filter(|(a, b)| a != b).count();
    let worst = cpu.irradiance.iter().zip(&gpu.irradiance).map(|(a, b)| (a[0] - b[0]).abs()).fold(0.0, f64::max);
    assert!(differ * 1000 <= n && worst < 0.05, "{differ} of {n} rows differ ({lit} lit), by up to {worst}");
}

/// The dirt's walks on wgpu (`shaders/first_hits.wgsl`) against the CPU reference, on a
/// real map: oa_dm1 as converted, lit by an ambient of 1 alone, so that each row's
/// irradiance is its dirt factor at q3map2's default depth. A ray that grazes a shared
/// edge may be decided otherwise by a device's rounding (its division need not be exact),
/// and q3map2's smoothing carries a row's difference on to the luxels after it: on
/// lavapipe 11,272 of oa_dm1's 143,339 rows differ at all, 525 by more than 1e-3, by
/// 1.4e-5 on average and 0.019 at most (the dirt darkens 101,718 of them).
#[test]
fn the_dirt_on_wgpu_darkens_a_real_map_as_the_cpu_does() {
    use q3gltf_relight::io::gltf_in;
    use q3gltf_relight::model::Model;
    use q3gltf_relight::pipeline::{render_on, BackendChoice};
    use q3gltf_relight::scene::DirtSettings;
    let dir = tmp("dirt-gpu");
    let map = dir.join("oa_dm1.glb");
    run(&["convert", "oa_dm1", "--game-dir", common::baseoa().to_str().unwrap(), "-o", map.to_str().unwrap(), "-q"]);
    let scene = gltf_in::read(&map).unwrap();
    let model = Model { ambient: Some([1.0; 3]), dirt: Some(DirtSettings::Q3MAP2), ..Model::default() };
    let cpu = render_on(&scene, &model, 0, 0, BackendChoice::Cpu).unwrap();
    let gpu = render_on(&scene, &model, 0, 0, BackendChoice::Wgpu).expect("a wgpu adapter (install mesa-vulkan-drivers)");
    assert!(gpu.backend.starts_with("wgpu"), "{}", gpu.backend);
    assert_eq!(cpu.irradiance.len(), gpu.irradiance.len());
    let n = cpu.irradiance.len();
    let dark = cpu.irradiance.iter().filter(|e| e[0] < 0.9).count();
    assert!(dark * 20 > n, "{dark} of {n} rows darkened by the dirt");
    let differ = cpu.irradiance.iter().zip(&gpu.irradiance).filter(|(a, b)| a != b).count();
    let worst = cpu.irradiance.iter().zip(&gpu.irradiance).map(|(a, b)| (a[0] - b[0]).abs()).fold(0.0, f64::max);
    let over = cpu.irradiance.iter().zip(&gpu.irradiance).filter(|(a, b)| (a[0] - b[0]).abs() > 1e-3).count();
    let mean = cpu.irradiance.iter().zip(&gpu.irradiance).map(|(a, b)| (a[0] - b[0]).abs()).sum::<f64>() / n as f64;
    assert!(over * 100 <= n && mean < 1e-4 && worst < 0.05, "{differ} of {n} rows differ, {over} by more than 1e-3, by {mean:e} on average and up to {worst}");
}

/// The bounce's walks on wgpu (`shaders/first_hits.wgsl`) against the CPU reference, on a
/// real map: oa_dm1 as converted, lit by an ambient of 1 and two passes of q3map2's
/// bounce, 16 rays a row. A ray that grazes a shared edge may land on another piece by a
/// device's rounding, so a few rows' gathers differ, and little: on lavapipe 268 of the
/// 143,339 rows differ at all, 8 by more than 1e-3 relative, 0.7% at most.
#[test]
fn the_bounce_on_wgpu_lights_a_real_map_as_the_cpu_does() {
    use q3gltf_relight::io::gltf_in;
    use q3gltf_relight::model::Model;
    use q3gltf_relight::pipeline::{render_on, BackendChoice};
    let dir = tmp("bounce-gpu");
    let map = dir.join("oa_dm1.glb");
    run(&["convert", "oa_dm1", "--game-dir", common::baseoa().to_str().unwrap(), "-o", map.to_str().unwrap(), "-q"]);
    let scene = gltf_in::read(&map).unwrap();
    let model = Model { ambient: Some([1.0; 3]), bounce: Some([1.0; 3]), ..Model::default() };
    let cpu = render_on(&scene, &model, 2, 16, BackendChoice::Cpu).unwrap();
    let gpu = render_on(&scene, &model, 2, 16, BackendChoice::Wgpu).expect("a wgpu adapter (install mesa-vulkan-drivers)");
    assert!(gpu.backend.starts_with("wgpu"), "{}", gpu.backend);
    assert_eq!(cpu.irradiance.len(), gpu.irradiance.len());
    let n = cpu.irradiance.len();
    // What the bounce adds to the ambient's 1.
    let bounced = cpu.irradiance.iter().filter(|e| e[0] > 1.05).count();
    assert!(bounced * 2 > n, "the bounce brightens {bounced} of {n} rows");
    let rel = |a: &[f64; 3], b: &[f64; 3]| (a[0] - b[0]).abs() / a[0].max(1e-9);
    let differ = cpu.irradiance.iter().zip(&gpu.irradiance).filter(|(a, b)| a != b).count();
    let over = cpu.irradiance.iter().zip(&gpu.irradiance).filter(|(a, b)| rel(a, b) > 1e-3).count();
    let mean = cpu.irradiance.iter().zip(&gpu.irradiance).map(|(a, b)| rel(a, b)).sum::<f64>() / n as f64;
    let worst = cpu.irradiance.iter().zip(&gpu.irradiance).map(|(a, b)| rel(a, b)).fold(0.0, f64::max);
    assert!(over * 100 <= n && mean < 1e-3 && worst < 0.1, "{differ} of {n} rows differ, {over} by more than 1e-3, by {mean:e} on average and up to {worst}");
}

/// Huge coordinates: the converted sample moved 1000 km away (a parent node with a large
/// translation, as a georeferenced scene would have). Positions are recentred in f64 on
/// reading, so the fit is as good as at the origin and the lights come back in world space.
#[test]
fn far_from_the_origin_the_fit_is_unchanged() {
    let dir = tmp("far");
    let gltf = convert_sample(&dir);
    let offset = [1.0e6, 250.0, -2.0e6];
    let mut json: Value = serde_json::from_slice(&std::fs::read(&gltf).unwrap()).unwrap();
    let scene = json["scene"].as_u64().unwrap_or(0) as usize;
    let roots = json["scenes"][scene]["nodes"].clone();
    let nodes = json["nodes"].as_array_mut().unwrap();
    nodes.push(serde_json::json!({ "name": "far away", "translation": offset, "children": roots }));
    let root = nodes.len() - 1;
    json["scenes"][scene]["nodes"] = serde_json::json!([root]);
    let far = dir.join("far.gltf");
    std::fs::write(&far, serde_json::to_vec(&json).unwrap()).unwrap();
    let out = dir.join("far.relit.gltf");
    let rep = dir.join("r.json");
    run(&["relight", far.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"]);
    let r = report(&rep);
    let err = r["rel_error_final"].as_f64().unwrap();
    assert!(err < 0.05, "relative error {err}");
    let found = lights_of(&r);
    assert_eq!(found.len(), 3, "{found:?}");
    assert_recovered(&found, &sample_truth(), offset, 0.05, 0.02);
}

/// World positions (m) and radiant intensities (W/sr) of the synthetic truth: three lights
/// in the sample's rooms, at other places and in other colours than its entities.
const SYNTHETIC_TRUTH: [([f64; 3], [f32; 3]); 3] = [([6.2, 4.6, -4.5], [70.0, 55.0, 40.0]), ([19.9, 3.7, -3.6], [25.0, 40.0, 60.0]), ([21.5, 2.6, -7.8], [30.0, 20.0, 12.0])];

/// The converted sample with its lightmap re-rendered by relight's CPU reference
/// ([`q3gltf_relight::pipeline::render`]) from [`SYNTHETIC_TRUTH`], stored as 8-bit
/// lightmap texels as q3map2 would (overbright 2, truncated to a byte, scaled down keeping
/// hue above 255). With `bounces`, the data also holds [`SYNTHETIC_BOUNCES`] passes of the
/// lights' own bounced light (the model's bounce at scale 1, what q3map2 `-bounce` adds).
/// With `sun`, the sample's walls become sky (extras `q3_sky`: no target, sunlight passes
/// them) and [`SYNTHETIC_SUN`] shines in. Returns the glTF and the scene diagonal (m).
fn synthetic_scene(dir: &Path, bounces: bool, sun: bool) -> (PathBuf, f64) {
    synthetic_scene_with(dir, bounces, sun, Emitter::None, None, 1.0)
}

/// A surface light in the synthetic scene: none, declared by the material (extras
/// `q3_surfacelight`, as convert writes from `q3map_surfacelight`) but absent from the
/// data, or declared and lit with [`SYNTHETIC_SURFACE`].
#[derive(Debug, Clone, Copy, PartialEq)]
enum Emitter {
    None,
    Declared,
    Lit,
}

/// The emitting material of the synthetic surface light and its radiance, W/(m^2 sr).
const SYNTHETIC_SURFACE: (&str, [f32; 3]) = ("textures/sample/pillar", [8.0, 6.4, 4.8]);

/// [`synthetic_scene`] with a surface light, and `spot`: the first truth light made a spot
/// of this axis (world, normalised on use) and `radius_by_dist`; its bytes stored through
/// q3map2's `-gamma gamma` (`255 (L / 255)^(1 / gamma)`), not recorded in the file.
fn synthetic_scene_with(dir: &Path, bounces: bool, sun: bool, emitter: Emitter, spot: Option<([f32; 3], f32)>, gamma: f64) -> (PathBuf, f64) {
    use q3gltf_relight::io::gltf_in;
    use q3gltf_relight::model::{Light, Model, Sun};
    use q3gltf_relight::trace::bvh::Bvh;
    let gltf = convert_sample(dir);
    // The sample's vertex-lit surface keeps q3map2's colours, which the truth did not make:
    // declare it unlit (it still casts shadows).
    let mut json: Value = serde_json::from_slice(&std::fs::read(&gltf).unwrap()).unwrap();
    for m in json["materials"].as_array_mut().unwrap() {
        if m["extras"]["q3_lighting"] == "vertex" {
            m["extras"]["q3_lighting"] = "none".into();
        }
        if sun && m["name"] == "textures/sample/wall" {
            m["extras"]["q3_sky"] = true.into();
        }
        if emitter != Emitter::None && m["name"] == SYNTHETIC_SURFACE.0 {
            m["extras"]["q3_surfacelight"] = serde_json::json!({ "value": 1000.0, "color": [1.0, 0.8, 0.6] });
        }
    }
    std::fs::write(&gltf, serde_json::to_vec(&json).unwrap()).unwrap();
    let mut scene = gltf_in::read(&gltf).unwrap();
    assert_eq!(scene.materials.iter().any(|m| m.sky), sun, "the wall material is sky exactly when asked");
    let (lo, hi) = scene.mesh.bounds();
    let diag = (hi - lo).length() as f64;
    let bvh = Bvh::build(&scene.mesh);
    let mut lights: Vec<Light> = SYNTHETIC_TRUTH.iter().map(|(p, rgb)| Light::point((glam::DVec3::from_array(*p) - scene.origin).as_vec3(), *rgb)).collect();
    if let Some((axis, radius_by_dist)) = spot {
        lights[0].spot = Some(q3gltf_relight::model::Spot { axis: glam::Vec3::from(axis).normalize(), radius_by_dist });
    }
    for l in &lights {
        let (d, _) = bvh.nearest(l.pos).unwrap();
        assert!(d > 0.5, "a truth light is {d} m from a surface: move it into free space");
    }
    let model = Model {
        lights,
        sun: sun.then(|| Sun { to_sun: glam::Vec3::from(SYNTHETIC_SUN.0).normalize(), rgb: SYNTHETIC_SUN.1 }),
        bounce: bounces.then_some([1.0; 3]),
        surfaces: if emitter == Emitter::Lit { vec![Some(SYNTHETIC_SURFACE.1)] } else { Vec::new() },
        ..Model::default()
    };
    let passes = if bounces { SYNTHETIC_BOUNCES } else { 0 };
    // The bounce traced as relight traces it by default.
    let r = q3gltf_relight::pipeline::render(&scene, &model, passes, 0).unwrap();
    let ob = 2;
    for (i, &[tex, x, y]) in r.rows.texel.iter().enumerate() {
        let t = &mut scene.textures[tex as usize];
        // e = byte / 255 * 2^2 (CONVENTIONS.md), truncated; above 255 scaled down keeping hue.
        let b = [0, 1, 2].map(|c| (r.radiance[i][c] / (r.rows.albedo[i][c] as f64).max(1e-6) / (1u32 << ob) as f64).max(0.0).powf(1.0 / gamma) * 255.0);
        let m = b.iter().copied().fold(255.0, f64::max);
        let o = ((y * t.width + x) * 4) as usize;
        for c in 0..3 {
            t.rgba8[o + c] = (b[c] * 255.0 / m).floor() as u8;
        }
    }
    // Write the lightmaps back to the converted scene's files.
    let mut written = 0;
    for (m, mat) in scene.materials.iter().enumerate() {
        let Some(t) = mat.lightmap else { continue };
        let jm = json["materials"].as_array().unwrap().iter().find(|j| j["name"] == mat.name.as_str()).unwrap_or(&json["materials"][m]);
        let tex = jm["occlusionTexture"]["index"].as_u64().unwrap() as usize;
        let img = json["textures"][tex]["source"].as_u64().unwrap() as usize;
        let uri = json["images"][img]["uri"].as_str().unwrap();
        let tx = &scene.textures[t];
        image::RgbaImage::from_raw(tx.width, tx.height, tx.rgba8.clone()).unwrap().save(dir.join(uri)).unwrap();
        written += 1;
    }
    assert!(written > 0);
    (gltf, diag)
}

/// Passes of bounced light in the synthetic data: relight's own default when the compile
/// is not recorded, so a bounce scale of 1 reproduces it.
const SYNTHETIC_BOUNCES: usize = q3gltf_relight::pipeline::DEFAULT_BOUNCES;

/// Direction towards the sun (normalised on use) and its irradiance, W/m^2.
const SYNTHETIC_SUN: ([f32; 3], [f32; 3]) = ([0.5, 0.8, 0.3], [6.0, 5.5, 4.5]);

fn synthetic_truth_cd() -> Vec<([f64; 3], f64)> {
    SYNTHETIC_TRUTH.iter().map(|(p, rgb)| (*p, rgb.iter().copied().fold(0.0f32, f32::max) as f64 * 683.0)).collect()
}

/// Synthetic ground truth (direct light only), relit from scratch (`--init auto`): every
/// light within 1% of the scene diagonal and 2% in intensity, the relative error below 1%,
/// no light more than the scene needs, and no indirect term (the data has none).
#[test]
fn synthetic_ground_truth_is_recovered() {
    let dir = tmp("synthetic");
    let (gltf, diag) = synthetic_scene(&dir, false, false);
    let out = dir.join("synthetic.relit.gltf");
    let rep = dir.join("r.json");
    run(&["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"]);
    let r = report(&rep);
    let found = lights_of(&r);
    assert_eq!(found.len(), SYNTHETIC_TRUTH.len(), "as many lights as the truth: {found:?}");
    // Measured: within 1 mm and 0.1%; error 0.0071, the floor of 8-bit quantisation.
    assert_recovered(&found, &synthetic_truth_cd(), [0.0; 3], 0.01 * diag, 0.02);
    let err = r["rel_error_final"].as_f64().unwrap();
    assert!(err < 0.01, "relative error {err}");
    assert!(r["bounce"].is_null(), "no bounce in the data, yet the bounce term was kept: {}", r["terms"]);
    assert!(r["ambient"].is_null() && r["sun"].is_null(), "terms the data has not: {}", r["terms"]);
    // From the truth's lights, where a gamma is estimated: none in the data, none read.
    let start = with_truth_lights(&dir, &gltf);
    run(&["relight", start.to_str().unwrap(), "-o", out.to_str().unwrap(), "--init", "input", "--fit", "globals", "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"]);
    let r = report(&rep);
    assert_eq!(r["gamma"]["gamma"].as_f64(), Some(1.0), "no gamma in the data, yet one was read: {}", r["gamma"]);
    assert!(r["gamma"]["how"].as_str().unwrap().starts_with("estimated: 1"), "{}", r["gamma"]);
}

/// `--init auto` is the greedy placement and the dense candidates beside it; `--init
/// greedy` the placement alone. On the sample both end with its three light entities.
#[test]
fn the_default_start_tops_the_placement_up_with_dense_candidates() {
    let dir = tmp("greedy");
    let gltf = convert_sample(&dir);
    let out = dir.join("sample.relit.gltf");
    let rep = dir.join("report.json");
    for init in ["auto", "greedy"] {
        run(&["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--init", init, "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"]);
        let r = report(&rep);
        assert_eq!(r["init"], init);
        assert!(r["auto"]["added"].as_u64().is_some_and(|a| a >= 3), "{init}: the placement placed {}", r["auto"]["added"]);
        match init {
            "auto" => {
                let c = r["dense_candidates"].as_u64().expect("auto reports its dense candidates");
                let dark = r["dense_dark"].as_u64().expect("auto reports the candidates left dark");
                assert!(c > 50 && dark > 0 && dark <= c + 3, "{c} candidates, {dark} dark");
            }
            _ => assert!(r["dense_candidates"].is_null() && r["dense_dark"].is_null(), "greedy: {} {}", r["dense_candidates"], r["dense_dark"]),
        }
        let found = lights_of(&r);
        assert_eq!(found.len(), 3, "{init}: as few lights as the scene needs: {found:?}");
        assert_recovered(&found, &sample_truth(), [0.0; 3], 0.05, 0.02);
        let err = r["rel_error_final"].as_f64().unwrap();
        assert!(err < 0.065, "{init}: relative error {err}");
    }
}

/// Synthetic ground truth relit from the dense start (`--init dense`): a thousand
/// candidates, fitted at once, pruned and merged down to the truth's lights, each found
/// where it is; the CLI refuses a count of 0 and `--fit globals` with it.
#[test]
fn synthetic_ground_truth_from_the_dense_start() {
    let dir = tmp("synthetic-dense");
    let (gltf, diag) = synthetic_scene(&dir, false, false);
    let out = dir.join("dense.relit.gltf");
    let rep = dir.join("r.json");
    run(&["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--init", "dense", "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"]);
    let r = report(&rep);
    assert!(r["dense_candidates"].as_u64().is_some_and(|c| c > SYNTHETIC_TRUTH.len() as u64), "{}", r["dense_candidates"]);
    assert_eq!(r["init"], "dense:1000");
    let found = lights_of(&r);
    let err = r["rel_error_final"].as_f64().unwrap();
    eprintln!("dense start: {} lights, error {err:.4}", found.len());
    assert!(err < 0.01, "relative error {err}");
    assert!(found.len() <= 2 * SYNTHETIC_TRUTH.len(), "{} lights for the truth's {}: {found:?}", found.len(), SYNTHETIC_TRUTH.len());
    for (p, _) in synthetic_truth_cd() {
        assert!(found.iter().any(|f| dist(f.0, p) < 0.01 * diag), "no light found near {p:?}: {found:?}");
    }
    for bad in [&["--init", "dense:0"][..], &["--init", "dense", "--fit", "globals"]] {
        let mut args = vec!["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "-q"];
        args.extend_from_slice(bad);
        let st = Command::new(bin()).args(&args).output().unwrap();
        let msg = String::from_utf8_lossy(&st.stderr);
        assert!(!st.status.success() && msg.contains("dense") && !msg.contains("panicked"), "{bad:?}: {msg}");
    }
}

/// The synthetic scene `gltf` with [`SYNTHETIC_TRUTH`]'s lights in it as point lights
/// (`start.gltf` in `dir`): the start of an `--init input` run.
fn with_truth_lights(dir: &Path, gltf: &Path) -> PathBuf {
    let mut json: Value = serde_json::from_slice(&std::fs::read(gltf).unwrap()).unwrap();
    let lights = SYNTHETIC_TRUTH
        .iter()
        .enumerate()
        .map(|(k, (p, rgb))| {
            let m = rgb.iter().copied().fold(0.0f32, f32::max);
            (serde_json::json!({ "type": "point", "color": rgb.map(|c| c / m), "intensity": m * 683.0 }), serde_json::json!({ "name": format!("truth_{k}"), "translation": p }))
        })
        .collect();
    common::set_lights(&mut json, lights);
    let start = dir.join("start.gltf");
    std::fs::write(&start, serde_json::to_vec(&json).unwrap()).unwrap();
    start
}

/// Synthetic ground truth stored through q3map2's `-gamma 1.5`, not recorded in the file
/// (as the OACMP maps keep no command line).
/// - Asked for (`--gamma 1.5`), the rows are read through it from the start: relit from
///   scratch, the lights come back as q3map2's linear light (1% of the diagonal, 2% in
///   intensity), three for three, at the quantisation floor against the stored bytes.
/// - From the truth's own lights (`--init input --fit globals`, the truth set's run), the
///   gamma is estimated within the search's step and the error is near the floor; read as
///   stored (`--gamma off`) the same start fits far worse: what the estimate is for.
/// - Relit from scratch without the gamma, the placement trades the lights' distance for
///   it, and the gamma is not estimated there (the report says why).
#[test]
fn synthetic_ground_truth_through_a_compile_gamma_is_recovered() {
    let dir = tmp("synthetic-gamma");
    let (gltf, diag) = synthetic_scene_with(&dir, false, false, Emitter::None, None, 1.5);
    let fit = |input: &Path, extra: &[&str], name: &str| {
        let out = dir.join(format!("{name}.gltf"));
        let rep = dir.join(format!("{name}.json"));
        let mut args = vec!["relight", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"];
        args.extend_from_slice(extra);
        run(&args);
        report(&rep)
    };
    // Asked.
    let asked = fit(&gltf, &["--gamma", "1.5"], "asked");
    assert_eq!(asked["gamma"]["gamma"].as_f64(), Some(1.5));
    let found = lights_of(&asked);
    assert_eq!(found.len(), SYNTHETIC_TRUTH.len(), "as many lights as the truth: {found:?}");
    assert_recovered(&found, &synthetic_truth_cd(), [0.0; 3], 0.01 * diag, 0.02);
    let err = asked["rel_error_final"].as_f64().unwrap();
    assert!(err < 0.01, "relative error against the stored bytes {err}");
    // Estimated from the truth's lights.
    let start = with_truth_lights(&dir, &gltf);
    let est = fit(&start, &["--init", "input", "--fit", "globals"], "estimated");
    let g = est["gamma"]["gamma"].as_f64().unwrap();
    assert!((g - 1.5).abs() <= 0.125 + 1e-9, "estimated gamma {g}: {}", est["gamma"]);
    let err = est["rel_error_final"].as_f64().unwrap();
    let plain = fit(&start, &["--init", "input", "--fit", "globals", "--gamma", "off"], "off");
    assert_eq!(plain["gamma"]["gamma"].as_f64(), Some(1.0));
    let err_plain = plain["rel_error_final"].as_f64().unwrap();
    assert!(err < 0.03 && err < 0.5 * err_plain, "error against the stored bytes {err}, read as stored {err_plain}");
    // The written file states the gamma on its lit materials: a re-run from it (the Blender
    // loop) reads the bytes through it and starts where this fit ended.
    let written: Value = serde_json::from_slice(&std::fs::read(dir.join("estimated.gltf")).unwrap()).unwrap();
    let lit: Vec<&Value> = written["materials"].as_array().unwrap().iter().filter(|m| m["extras"]["q3_lighting"] == "lightmap").collect();
    assert!(!lit.is_empty() && lit.iter().all(|m| m["extras"]["q3_lightmap_gamma"].as_f64() == Some(g)), "the lit materials state the gamma read");
    let again = fit(&dir.join("estimated.gltf"), &["--init", "input", "--fit", "globals"], "again");
    assert_eq!(again["gamma"]["gamma"].as_f64(), Some(1.0), "read as the file states it, no further gamma: {}", again["gamma"]);
    assert!(again["gamma"]["how"].as_str().unwrap().starts_with("stated by the file"), "{}", again["gamma"]);
    let e_again = again["rel_error_final"].as_f64().unwrap();
    assert!(e_again <= err + 0.002, "the re-run ends at {e_again}, the fit it starts from at {err}");
    // The bake reads the bytes as the file states them: at the floor too.
    let baked = dir.join("bake");
    run(&["bake", dir.join("estimated.gltf").to_str().unwrap(), "-o", baked.to_str().unwrap(), "--backend", "cpu", "-q"]);
    let b: Value = serde_json::from_slice(&std::fs::read(baked.join("bake.json")).unwrap()).unwrap();
    let e_bake = b["rel_error"].as_f64().unwrap();
    assert!(e_bake <= err + 0.002, "the bake of the written file: {e_bake}, relight {err}");
    // From scratch without it: not estimated, and said so.
    let scratch = fit(&gltf, &[], "scratch");
    assert_eq!(scratch["gamma"]["gamma"].as_f64(), Some(1.0));
    assert!(scratch["gamma"]["how"].as_str().unwrap().contains("--init input"), "{}", scratch["gamma"]);
}

/// Synthetic ground truth with bounced light in the data: the bounce term is kept with a
/// scale near 1, and the lights come back as the direct light alone (1% / 2%). Without
/// the term (`--bounce off`) the lights must absorb the bounced light and the fit is
/// measurably worse: that is what the term is for.
#[test]
fn synthetic_ground_truth_with_bounces_is_recovered() {
    let dir = tmp("synthetic-bounce");
    let (gltf, diag) = synthetic_scene(&dir, true, false);
    let run_with = |bounce: &str| -> Value {
        let rep = dir.join(format!("r-{bounce}.json"));
        let out = dir.join(format!("relit-{bounce}.glb"));
        run(&["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", "cpu", "--bounce", bounce, "--report", rep.to_str().unwrap(), "-q"]);
        report(&rep)
    };
    let r = run_with("auto");
    let k: Vec<f64> = r["bounce"].as_array().unwrap_or_else(|| panic!("bounce term not kept: {}", r["terms"])).iter().map(|v| v.as_f64().unwrap()).collect();
    for c in &k {
        assert!((c - 1.0).abs() < 0.1, "bounce scale {k:?}, expected about 1");
    }
    assert_eq!(r["bounces"], SYNTHETIC_BOUNCES);
    let found = lights_of(&r);
    assert_eq!(found.len(), SYNTHETIC_TRUTH.len(), "{found:?}");
    assert_recovered(&found, &synthetic_truth_cd(), [0.0; 3], 0.01 * diag, 0.02);
    let err = r["rel_error_final"].as_f64().unwrap();
    assert!(err < 0.015, "relative error {err}");
    let off = run_with("off");
    let err_off = off["rel_error_final"].as_f64().unwrap();
    assert!(err_off > err + 0.005, "without the indirect term: {err_off}, with it: {err}");
}

/// The output is self-contained wherever it is written: a `.gltf` in another folder gets
/// copies of the textures and buffer (no `../` URI, which relight's reader refuses), a `.glb`
/// embeds everything; both can be relit again from there, and the copies are the input's
/// bytes.
#[test]
fn outputs_in_another_folder_are_self_contained() {
    let dir = tmp("elsewhere");
    let gltf = convert_sample(&dir);
    let away = dir.join("away/deeper");
    std::fs::create_dir_all(&away).unwrap();
    let input_json: Value = serde_json::from_slice(&std::fs::read(&gltf).unwrap()).unwrap();
    for ext in ["gltf", "glb"] {
        let out = away.join(format!("relit.{ext}"));
        run(&["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", "cpu", "--scheme", "fast", "-q"]);
        let doc = gltf::Gltf::open(&out).expect("the output parses");
        let uris: Vec<String> = doc.images().filter_map(|i| match i.source() {
            gltf::image::Source::Uri { uri, .. } => Some(uri.to_string()),
            _ => None,
        }).chain(doc.buffers().filter_map(|b| match b.source() {
            gltf::buffer::Source::Uri(u) => Some(u.to_string()),
            _ => None,
        })).collect();
        if ext == "glb" {
            assert!(uris.is_empty(), "the .glb still references files: {uris:?}");
        } else {
            assert!(!uris.is_empty());
            for u in &uris {
                assert!(!u.contains(".."), "{u}");
                assert!(away.join(u).is_file(), "{u} was not copied beside the output");
            }
            // Each image copy holds the input's bytes.
            for (k, img) in input_json["images"].as_array().unwrap().iter().enumerate() {
                let u = img["uri"].as_str().unwrap();
                assert_eq!(std::fs::read(dir.join(u)).unwrap(), std::fs::read(away.join(u)).unwrap(), "image {k}");
            }
        }
        // Relight reads its own output from there.
        let again = away.join(format!("again.{ext}"));
        run(&["relight", out.to_str().unwrap(), "-o", again.to_str().unwrap(), "--init", "input", "--backend", "cpu", "--scheme", "fast", "-q"]);
    }
}

/// `q3gltf probe`: the model's irradiance for a file's own lights at one point, in the
/// units of CONVENTIONS.md (cd / 683 = W/sr; E = I cos / d^2 where visible).
#[test]
fn probe_reports_the_irradiance_of_the_files_lights() {
    let dir = tmp("probe");
    let gltf = convert_sample(&dir);
    // One white light of 10 W/sr (6830 cd) at the first entity light's place.
    let mut json: Value = serde_json::from_slice(&std::fs::read(&gltf).unwrap()).unwrap();
    let p = sample_truth()[0].0;
    json["extensions"]["KHR_lights_punctual"] = serde_json::json!({ "lights": [{ "type": "point", "color": [1.0, 1.0, 1.0], "intensity": 6830.0 }] });
    let nodes = json["nodes"].as_array_mut().unwrap();
    for n in nodes.iter_mut() {
        n.as_object_mut().unwrap().remove("extensions");
    }
    nodes.push(serde_json::json!({ "name": "lamp", "translation": p, "extensions": { "KHR_lights_punctual": { "light": 0 } } }));
    let k = nodes.len() - 1;
    json["scenes"][0]["nodes"].as_array_mut().unwrap().push(k.into());
    let one = dir.join("one.gltf");
    std::fs::write(&one, serde_json::to_vec(&json).unwrap()).unwrap();
    let probe = |at: [f64; 3], n: &str| -> Value {
        let at = format!("{},{},{}", at[0], at[1], at[2]);
        serde_json::from_str(&run(&["probe", one.to_str().unwrap(), "--at", &at, "--normal", n])).unwrap()
    };
    // 1 m below, facing up: E = I = 10 W/m^2; radiance of white = 10 / pi.
    let r = probe([p[0], p[1] - 1.0, p[2]], "0,1,0");
    for c in 0..3 {
        assert!((r["irradiance"][c].as_f64().unwrap() - 10.0).abs() < 1e-4, "{r}");
        assert!((r["radiance_white"][c].as_f64().unwrap() - 10.0 / std::f64::consts::PI).abs() < 1e-4, "{r}");
    }
    // 2 m below and 2 m aside, tilted normal: E = I cos / d^2 with cos = 2 / sqrt(8).
    let r = probe([p[0] + 2.0, p[1] - 2.0, p[2]], "0,1,0");
    let want = 10.0 * (2.0 / 8f64.sqrt()) / 8.0;
    assert!((r["irradiance"][0].as_f64().unwrap() - want).abs() < 1e-4, "{r} vs {want}");
    // Facing away: nothing.
    let r = probe([p[0], p[1] - 1.0, p[2]], "0,-1,0");
    assert_eq!(r["irradiance"][0].as_f64().unwrap(), 0.0);
    assert_eq!(r["lights"], 1);
    // Bad arguments: a clear error, no panic.
    let st = Command::new(bin()).args(["probe", one.to_str().unwrap(), "--at", "1,2", "--normal", "0,1,0"]).output().unwrap();
    assert!(!st.status.success());
    assert!(String::from_utf8_lossy(&st.stderr).contains("--at"));
}

/// `q3gltf probe` on an emissive square (1 m, radiance 2 W/(m^2 sr), 1 m above the point):
/// `E = pi L F` with the analytic form factor of the square; seen from behind (1 m above
/// it, facing it) a one-sided material adds nothing and a double-sided one the same as in
/// front, as relight's surface lights and Cycles do.
#[test]
fn probe_sees_a_double_sided_emitter_from_behind() {
    let dir = tmp("probe_emitter");
    let pos: [[f32; 3]; 4] = [[-0.5, 1.0, -0.5], [0.5, 1.0, -0.5], [0.5, 1.0, 0.5], [-0.5, 1.0, 0.5]];
    let mut buf: Vec<u8> = pos.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
    let npos = buf.len();
    buf.extend([0u16, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()));
    std::fs::write(dir.join("panel.bin"), &buf).unwrap();
    // Analytic form factor of a rectangle seen from below its corner, summed over four.
    let corner = |a: f64, b: f64, h: f64| {
        let (x, y) = (a / h, b / h);
        let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
        (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / (2.0 * std::f64::consts::PI)
    };
    let want = std::f64::consts::PI * 2.0 * 4.0 * corner(0.5, 0.5, 1.0);
    for double_sided in [false, true] {
        let doc = serde_json::json!({
            "asset": { "version": "2.0" },
            "extensionsUsed": ["KHR_materials_emissive_strength"],
            "buffers": [{ "byteLength": buf.len(), "uri": "panel.bin" }],
            "bufferViews": [{ "buffer": 0, "byteOffset": 0, "byteLength": npos }, { "buffer": 0, "byteOffset": npos, "byteLength": 12 }],
            "accessors": [
                { "bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-0.5, 1.0, -0.5], "max": [0.5, 1.0, 0.5] },
                { "bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR" }
            ],
            "materials": [{ "name": "panel", "emissiveFactor": [1.0, 1.0, 1.0], "doubleSided": double_sided, "extensions": { "KHR_materials_emissive_strength": { "emissiveStrength": 2.0 } } }],
            "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0 }, "indices": 1, "material": 0 }] }],
            "nodes": [{ "mesh": 0 }],
            "scenes": [{ "nodes": [0] }],
            "scene": 0
        });
        let file = dir.join(format!("panel_{double_sided}.gltf"));
        std::fs::write(&file, serde_json::to_vec(&doc).unwrap()).unwrap();
        let probe = |at: &str, n: &str| -> f64 {
            let r: Value = serde_json::from_str(&run(&["probe", file.to_str().unwrap(), "--at", at, "--normal", n])).unwrap();
            r["irradiance"][1].as_f64().unwrap()
        };
        let front = probe("0,0,0", "0,1,0");
        assert!((front - want).abs() < 1e-3 * want, "in front: {front} vs {want}");
        let behind = probe("0,2,0", "0,-1,0");
        let expected = if double_sided { want } else { 0.0 };
        assert!((behind - expected).abs() < 1e-3 * want, "double-sided {double_sided}, behind: {behind} vs {expected}");
    }
}

/// Synthetic ground truth with a sun shining through sky walls: the sun comes back (its
/// direction within 1 degree, its illuminance within 2%), written as a KHR directional
/// light, with the three point lights (1% / 2%) and the error below 1%. Without a sun in
/// the model (`--sun off`) the fit is measurably worse.
#[test]
fn synthetic_ground_truth_with_a_sun_is_recovered() {
    let dir = tmp("synthetic-sun");
    let (gltf, diag) = synthetic_scene(&dir, false, true);
    let rep = dir.join("r.json");
    let out = dir.join("relit.gltf");
    run(&["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"]);
    let r = report(&rep);
    let sun = &r["sun"];
    assert!(sun.is_object(), "no sun: {}", r["terms"]);
    let w: Vec<f64> = sun["to_sun"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let t = glam::DVec3::from(SYNTHETIC_SUN.0.map(f64::from)).normalize();
    let angle = glam::DVec3::new(w[0], w[1], w[2]).angle_between(t).to_degrees();
    assert!(angle < 1.0, "sun direction off by {angle} degrees");
    let lux = SYNTHETIC_SUN.1.iter().copied().fold(0.0f32, f32::max) as f64 * 683.0;
    let got = sun["illuminance_lux"].as_f64().unwrap();
    assert!((got / lux - 1.0).abs() < 0.02, "sun {got} lux, expected {lux}");
    let found = lights_of(&r);
    assert_eq!(found.len(), SYNTHETIC_TRUTH.len(), "{found:?}");
    assert_recovered(&found, &synthetic_truth_cd(), [0.0; 3], 0.01 * diag, 0.02);
    let err = r["rel_error_final"].as_f64().unwrap();
    assert!(err < 0.01, "relative error {err}");
    // The file has it as a directional light pointing from the sun (node -Z = -to_sun).
    let doc = gltf::Gltf::open(&out).unwrap();
    let node = doc.nodes().find(|n| n.light().is_some_and(|l| matches!(l.kind(), gltf::khr_lights_punctual::Kind::Directional))).expect("a directional light node");
    let q = glam::Quat::from_array(node.transform().decomposed().1);
    let shines = q * glam::Vec3::NEG_Z;
    assert!(shines.as_dvec3().angle_between(-t).to_degrees() < 1.0, "the light shines along {shines}");
    // Without the sun the lights cannot make up for it.
    let rep_off = dir.join("off.json");
    run(&["relight", gltf.to_str().unwrap(), "-o", dir.join("off.glb").to_str().unwrap(), "--backend", "cpu", "--sun", "off", "--report", rep_off.to_str().unwrap(), "-q"]);
    let err_off = report(&rep_off)["rel_error_final"].as_f64().unwrap();
    assert!(err_off > err + 0.02, "without the sun: {err_off}, with it: {err}");
}

/// Synthetic ground truth with a surface light (the pillar's material declared emitting):
/// its radiance comes back within 3% as an emissive material, with the three point lights
/// (1% / 2%); declared but absent from the data, the term is switched off.
#[test]
fn synthetic_ground_truth_with_a_surface_light_is_recovered() {
    for emitter in [Emitter::Lit, Emitter::Declared] {
        let dir = tmp(if emitter == Emitter::Lit { "synthetic-surface" } else { "synthetic-surface-off" });
        let (gltf, diag) = synthetic_scene_with(&dir, false, false, emitter, None, 1.0);
        let rep = dir.join("r.json");
        let out = dir.join("relit.gltf");
        run(&["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"]);
        let r = report(&rep);
        let s = &r["surfaces"][0];
        assert_eq!(s["shader"], SYNTHETIC_SURFACE.0, "{}", r["surfaces"]);
        let err = r["rel_error_final"].as_f64().unwrap();
        assert!(err < 0.01, "{emitter:?}: relative error {err}");
        let found = lights_of(&r);
        assert_eq!(found.len(), SYNTHETIC_TRUTH.len(), "{emitter:?}: {found:?}");
        assert_recovered(&found, &synthetic_truth_cd(), [0.0; 3], 0.01 * diag, 0.02);
        let doc: Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
        let mat = doc["materials"].as_array().unwrap().iter().find(|m| m["name"] == SYNTHETIC_SURFACE.0).unwrap();
        if emitter == Emitter::Lit {
            let got: Vec<f64> = s["radiance"].as_array().unwrap_or_else(|| panic!("surface light off: {}", r["terms"])).iter().map(|v| v.as_f64().unwrap()).collect();
            for c in 0..3 {
                assert!((got[c] / SYNTHETIC_SURFACE.1[c] as f64 - 1.0).abs() < 0.03, "radiance {got:?}, expected {:?}", SYNTHETIC_SURFACE.1);
            }
            // Written as emission: factor x strength is the radiance.
            let strength = mat["extensions"]["KHR_materials_emissive_strength"]["emissiveStrength"].as_f64().unwrap_or(1.0);
            let factor = mat["emissiveFactor"][0].as_f64().unwrap();
            assert!((factor * strength / got[0] - 1.0).abs() < 1e-3, "{mat}");
        } else {
            assert!(s["radiance"].is_null(), "no surface light in the data, yet kept: {}", r["terms"]);
            assert!(mat.get("emissiveFactor").is_none_or(|f| f.as_array().unwrap().iter().all(|v| v.as_f64() == Some(0.0))), "{mat}");
        }
    }
}

/// Synthetic ground truth with a spot: started from the truth moved by 0.3 m, its axis
/// turned by about 10 degrees and its cone 20% wider (`--init input`), the fit brings
/// position (1% of the diagonal), axis (2 degrees), cone (5%) and intensity (5%) back.
/// Distance, cone and intensity of a spot trade off along a shallow valley (measured: the
/// default's 50 iterations end 0.3 m away at 0.0077, converged L-BFGS 0.08 m and 3% in
/// intensity at 0.0076, the 8-bit floor being 0.0071), so this runs L-BFGS to convergence
/// (`thesis5`).
#[test]
fn synthetic_ground_truth_with_a_spot_is_recovered() {
    let dir = tmp("synthetic-spot");
    let axis = glam::Vec3::new(0.2, -1.0, 0.1).normalize();
    let radius_by_dist = 0.6f32;
    let (gltf, diag) = synthetic_scene_with(&dir, false, false, Emitter::None, Some((axis.to_array(), radius_by_dist)), 1.0);
    // The start: the truth's lights in the file, the spot perturbed.
    let mut json: Value = serde_json::from_slice(&std::fs::read(&gltf).unwrap()).unwrap();
    let mut lights = Vec::new();
    for (k, (p, rgb)) in SYNTHETIC_TRUTH.iter().enumerate() {
        let m = rgb.iter().copied().fold(0.0f32, f32::max);
        let color = rgb.map(|c| c / m);
        let mut node = serde_json::json!({ "name": format!("truth_{k}"), "translation": p });
        let light = if k == 0 {
            node["translation"] = serde_json::json!([p[0] + 0.2, p[1] - 0.15, p[2] + 0.15]);
            let turned = (axis + glam::Vec3::new(0.15, 0.0, -0.1)).normalize();
            node["rotation"] = serde_json::json!(glam::Quat::from_rotation_arc(glam::Vec3::NEG_Z, turned).to_array());
            let outer = (1.2 * radius_by_dist).atan();
            serde_json::json!({ "type": "spot", "color": color, "intensity": m * 683.0, "spot": { "innerConeAngle": 0.8 * outer, "outerConeAngle": outer } })
        } else {
            serde_json::json!({ "type": "point", "color": color, "intensity": m * 683.0 })
        };
        lights.push((light, node));
    }
    common::set_lights(&mut json, lights);
    let start = dir.join("start.gltf");
    std::fs::write(&start, serde_json::to_vec(&json).unwrap()).unwrap();
    let rep = dir.join("r.json");
    let out = dir.join("relit.gltf");
    run(&["relight", start.to_str().unwrap(), "-o", out.to_str().unwrap(), "--init", "input", "--scheme", "thesis5", "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"]);
    let r = report(&rep);
    let err = r["rel_error_final"].as_f64().unwrap();
    assert!(err < 0.01, "relative error {err}");
    let found = lights_of(&r);
    assert_recovered(&found, &synthetic_truth_cd(), [0.0; 3], 0.01 * diag, 0.05);
    let spot = r["lights"].as_array().unwrap().iter().find(|l| l["kind"] == "spot").expect("the spot stays a spot");
    let got = glam::DVec3::from_slice(&spot["spot_axis"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect::<Vec<_>>());
    let angle = got.angle_between(axis.as_dvec3()).to_degrees();
    assert!(angle < 2.0, "spot axis off by {angle} degrees");
    let cone = spot["spot_angle_deg"].as_f64().unwrap().to_radians().tan();
    assert!((cone / radius_by_dist as f64 - 1.0).abs() < 0.05, "spot cone tan {cone}, expected {radius_by_dist}");
}

/// The synthetic ground truth baked with the very lights that made its lightmap: the
/// residual is at the quantisation floor everywhere (every relit texel inside the
/// interval its byte stands for, up to the rounding of candela in the file), and the
/// relative error is zero to that floor.
#[test]
fn bake_of_the_synthetic_ground_truth_is_at_the_quantisation_floor() {
    let dir = tmp("synthetic-bake");
    let (gltf, _) = synthetic_scene(&dir, false, false);
    let mut json: Value = serde_json::from_slice(&std::fs::read(&gltf).unwrap()).unwrap();
    let lights = SYNTHETIC_TRUTH
        .iter()
        .enumerate()
        .map(|(k, (p, rgb))| {
            let m = rgb.iter().copied().fold(0.0f32, f32::max);
            (serde_json::json!({ "type": "point", "color": rgb.map(|c| c / m), "intensity": m as f64 * 683.0 }), serde_json::json!({ "name": format!("truth_{k}"), "translation": p }))
        })
        .collect();
    common::set_lights(&mut json, lights);
    let truth = dir.join("truth.gltf");
    std::fs::write(&truth, serde_json::to_vec(&json).unwrap()).unwrap();
    let out = dir.join("bake");
    run(&["bake", truth.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", "cpu", "-q"]);
    let b = report(&out.join("bake.json"));
    assert_eq!(b["lights"], 3);
    let err = b["rel_error"].as_f64().unwrap();
    assert!(err < 1e-3, "relative error {err}");
    let pages = b["pages"].as_array().unwrap();
    assert!(!pages.is_empty());
    for p in pages {
        // One byte of e is 4 / 255 = 0.0157.
        let worst = p["residual_max_abs"].as_f64().unwrap();
        assert!(worst < 1e-4, "{}: residual up to {worst} (e)", p["name"]);
        assert!(p["texels"].as_u64().unwrap() > 0);
    }
}

/// The surface lights are the map's own surfaces cut as q3map2 cut them: subdividing the
/// mesh for the vertex target leaves their patches (count and area) as they are, so the
/// basis costs rows times the map's patches, not rows times the subdivided triangles.
#[test]
fn surface_light_patches_do_not_follow_the_subdivision() {
    let dir = tmp("patches");
    let gltf = dir.join("oa_dm1.glb");
    run(&["convert", "oa_dm1", "--game-dir", common::baseoa().to_str().unwrap(), "-o", gltf.to_str().unwrap(), "-q"]);
    let surfaces = |extra: &[&str]| -> Vec<(String, u64, f64)> {
        let (rep, out) = (dir.join("r.json"), dir.join("o.glb"));
        let mut args = vec!["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--init", "grid:1", "--max-iterations", "0", "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"];
        args.extend_from_slice(extra);
        run(&args);
        report(&rep)["surfaces"].as_array().unwrap().iter().map(|s| (s["shader"].as_str().unwrap().to_string(), s["patches"].as_u64().unwrap(), s["area_m2"].as_f64().unwrap())).collect()
    };
    let luxel = surfaces(&[]);
    let vertex = surfaces(&["--target", "vertex", "--subdivide", "0.5"]);
    assert!(luxel.len() >= 4 && luxel.iter().all(|s| s.1 > 0), "{luxel:?}");
    assert_eq!(luxel.len(), vertex.len());
    for (a, b) in luxel.iter().zip(&vertex) {
        assert_eq!((&a.0, a.1), (&b.0, b.1), "patches of {} changed with the subdivision", a.0);
        assert!((a.2 - b.2).abs() <= 1e-6 * a.2.max(1.0), "{}: area {} then {}", a.0, a.2, b.2);
    }
}

/// `--look game`: the rows hold what the game's screen shows instead of the baked light
/// (rows::look). The fit must then reproduce that picture better than the lights fitted
/// to the baked light do, judged in the same space, and say which look it fitted.
#[test]
fn the_game_look_fits_what_the_screen_shows() {
    let dir = tmp("look");
    let gltf = convert_sample(&dir);
    let (lm, game) = (dir.join("lightmap.gltf"), dir.join("game.gltf"));
    let (rl, rg, rx) = (dir.join("lightmap.json"), dir.join("game.json"), dir.join("cross.json"));
    let g = gltf.to_str().unwrap();
    let (dl, dg) = (dir.join("lightmap.csv"), dir.join("game.csv"));
    run(&["relight", g, "-o", lm.to_str().unwrap(), "--backend", "cpu", "--report", rl.to_str().unwrap(), "--dump-rows", dl.to_str().unwrap(), "-q"]);
    run(&["relight", g, "-o", game.to_str().unwrap(), "--backend", "cpu", "--look", "game", "--report", rg.to_str().unwrap(), "--dump-rows", dg.to_str().unwrap(), "-q"]);
    // The lightmap look's lights, judged by the game look's objective as they are.
    run(&["relight", lm.to_str().unwrap(), "-o", dir.join("cross.gltf").to_str().unwrap(), "--backend", "cpu", "--look", "game", "--init", "input", "--max-iterations", "0", "--fit", "globals", "--report", rx.to_str().unwrap(), "-q"]);
    let (l, gm, x) = (report(&rl), report(&rg), report(&rx));
    assert_eq!(l["look"], "lightmap");
    assert_eq!(gm["look"], "game");
    let extras: Value = serde_json::from_str(&std::fs::read_to_string(&game).unwrap()).unwrap();
    assert_eq!(extras["scenes"][0]["extras"]["q3_relight"]["look"], "game", "the file says which picture its lights reproduce");
    let (el, eg, ex) = (l["rel_error_final"].as_f64().unwrap(), gm["rel_error_final"].as_f64().unwrap(), x["rel_error_initial"].as_f64().unwrap());
    eprintln!("sample: lightmap look {el:.4}; game look {eg:.4}; the lightmap look's lights in the game look {ex:.4}");
    assert!(eg.is_finite() && eg < 0.5, "game look error {eg}");
    assert!(ex > 1.5 * eg, "the baked light's fit is not what the screen shows: {ex} against {eg}");
    // The texels the compile clamped are lower bounds of the baked light, but the screen
    // shows them as stored, and a renderer draws whatever light the fit puts above them:
    // in the game look they are intervals, and the fit stays near them (1.14 times their
    // screen value at the 90th percentile; as lower bounds the model was 5.5 times it, 12
    // times at most, on the sample's 109).
    let (rows_l, rows_g) = (common::RowsDump::read(&dl), common::RowsDump::read(&dg));
    let rgb = |d: &common::RowsDump, what: &str| -> Vec<[f64; 3]> {
        let [r, g, b] = ["r", "g", "b"].map(|c| d.column(&format!("{what}_{c}")));
        (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect()
    };
    let (hi_l, hi_g, x_g) = (rgb(&rows_l, "hi"), rgb(&rows_g, "hi"), rgb(&rows_g, "x"));
    assert_eq!(hi_l.len(), hi_g.len(), "the two looks' rows are the same rows");
    let clamped: Vec<usize> = (0..hi_l.len()).filter(|&i| hi_l[i].iter().any(|h| h.is_nan())).collect();
    assert!(!clamped.is_empty(), "the sample has clamped texels");
    assert!(hi_g.iter().all(|h| h.iter().all(|h| !h.is_nan())), "a lower bound in the game look");
    let mut over: Vec<f64> = clamped.iter().map(|&i| x_g[i].iter().copied().fold(0.0, f64::max) / hi_g[i].iter().copied().fold(1e-12, f64::max)).collect();
    over.sort_by(f64::total_cmp);
    let p90 = over[over.len() * 9 / 10];
    eprintln!("sample: {} clamped texels, the game look's model over their screen value: 90th percentile {p90:.2}", clamped.len());
    assert!(p90 < 1.5, "the game look's fit overshoots the clamped texels: {p90} at the 90th percentile");
}
