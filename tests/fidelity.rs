//! Fidelity of relight's forward model against q3map2 itself.
//!
//! - **Fixtures** (`tests/fixtures/q3map2`): small maps of our own, each isolating one
//!   thing q3map2 puts into a lightmap, compiled by q3map2 (the command is recorded beside
//!   each map and in the BSP). Converted with their own light entities (`--lights-from`),
//!   relit with only the global terms fitted (`--init input --fit globals`): the relative
//!   error is how far the model is from the real engine on that effect.
//! - **Truth set**: the OpenArena community pack's oacmpdm1-4 and oacmpctf1, whose `.map`
//!   sources ship with them, the same way.
//!
//! The bounds are the measured errors with a margin (the figures are in the README's
//! fidelity section, and every measurement in `docs/fidelity.md`); where a bound is above
//! the fidelity issue's goal, those say what is missing.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_q3gltf"))
}

fn run(args: &[&str]) {
    let out = Command::new(bin()).args(args).output().expect("run q3gltf");
    assert!(out.status.success(), "q3gltf {args:?} failed:\n{}", String::from_utf8_lossy(&out.stderr));
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("q3gltf-fidelity-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn fixtures() -> PathBuf {
    common::repo().join("tests/fixtures/q3map2")
}

/// Converts `bsp` (a path, or a map name in the game dirs) with the light entities of
/// `source`, relights it with only the global terms fitted, and returns the report.
fn globals_fit(dir: &Path, name: &str, bsp: &str, source: &Path, game_dirs: &[&Path]) -> Value {
    globals_fit_with(dir, name, bsp, source, game_dirs, &[])
}

/// Converts `bsp` with the light entities of `source` into `dir/NAME.glb`.
fn convert_with_source(dir: &Path, name: &str, bsp: &str, source: &Path, game_dirs: &[&Path]) -> PathBuf {
    let gltf = dir.join(format!("{name}.glb"));
    let mut args: Vec<String> = vec!["convert".into(), bsp.into()];
    for g in game_dirs {
        args.extend(["--game-dir".into(), g.to_str().unwrap().into()]);
    }
    args.extend(["--lights-from".into(), source.to_str().unwrap().into(), "-o".into(), gltf.to_str().unwrap().into(), "-q".into()]);
    run(&args.iter().map(String::as_str).collect::<Vec<_>>());
    gltf
}

fn globals_fit_with(dir: &Path, name: &str, bsp: &str, source: &Path, game_dirs: &[&Path], extra: &[&str]) -> Value {
    let gltf = convert_with_source(dir, name, bsp, source, game_dirs);
    let rep = dir.join(format!("{name}.json"));
    let out = dir.join(format!("{name}.relit.glb"));
    let mut args = vec!["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--init", "input", "--fit", "globals", "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"];
    args.extend_from_slice(extra);
    run(&args);
    serde_json::from_slice(&std::fs::read(&rep).unwrap()).unwrap()
}

/// (fixture, largest relative error, what the recorded compile must have switched on).
/// Measured on 2026-11-23: point 0.0000, pillar 0.0016, offgrid 0.0039, near_wall 0.0002,
/// spot 0.0000, surface 0.0031, sun 0.0000, skylight 0.0346, skylight_bright 0.0388,
/// bounce 0.0457, dirt 0.0049, filter 0.0028, gamma 0.0018, minlight 0.0013, combo 0.0216;
/// on 2026-11-24, detail 0.0113, and near_wall 0.0000 once `decide_terms` kept the phases' state;
/// on 2026-11-26, twosided 0.0140 (0.448 with the emitter lighting one side only; 0.0044 for
/// the same map lit without `-fast`: q3map2 cuts a patch's quads, relight its triangles);
/// then with q3map2's own patch mesh (convert's `lightmesh`): twosided 0.0040, lamp 0.0069
/// (0.149 emitting from the drawn patch's triangles); on 2026-11-26 (third), receiver 0.0112
/// (0.0960 receiving on the front face only: its lightmapped screen 0.096 -> 0.038, its
/// vertex-lit one 0.49 -> 0.0003), glass 0.0000 (0.28 one-sided); pad 0.0021 (0.587
/// sampling the vertex-lit pad at its drawn vertices instead of its control points); on
/// 2026-11-26 (fourth), column 0.0018 (0.1541 sampling the curved patch at its texel
/// centres on the drawn surface instead of q3map2's own sample points), sunk 0.0000 (0.2049
/// sampling the control points in the floor where they are); on 2026-11-26 (fifth), arch
/// 0.0000 (0.1278 nudging the curved patch's luxels in the pillar half a luxel along the
/// lightmap's axes instead of half a unit along q3map2's own directions; 0.0194 with a
/// floor luxel's shadow ray slipping through a diagonal of the column's mesh), column
/// 0.0018 -> 0.0000 (the same crack); on 2026-11-27 (second), bounce 0.0126 and combo 0.0160
/// with the bounce re-emitted from q3map2's pieces, each averaging its samples (0.0457 and
/// 0.0216 landing each ray on the row under it; bounce 0.0249 at 16 rays per row, 0.0146 at
/// 64, 196 now); surface 0.0008 with its panel cut along Quake's axes in q3map2's order and
/// with its clip epsilon (0.0029 along glTF's); on 2026-11-27 (third), skylight 0.0202 and
/// skylight_bright 0.0250 with the sky's suns traced as q3map2 traces them (through a sky
/// surface and past no opaque one on the whole way, a ray along an edge stopped: 0.0346
/// and 0.0388 to the first hit, ties passing), offgrid 0.0017 (0.0039), surface 0.0000,
/// receiver 0.0107, combo 0.0160 (the shadow walk's boxes grown by its slack); on
/// 2026-11-27 (seventh), with q3map2's own pieces stopping the shadow rays (convert's
/// `q3_casters`, relight's `trace::pieces`) and the rays starting at the sample itself:
/// skylight_bright 0.0250 -> 0.0000, receiver 0.0107 -> 0.0013, detail 0.0069 -> 0,
/// lamp 0.0069 -> 0, offgrid 0.0017 -> 0, pillar 0.0016 -> 0, twosided 0.0018 -> 0, gamma
/// 0.0018 -> 0, minlight 0.0013 -> 0, compensate 0.0010 -> 0, dirt 0.0049 -> 0.0046; skylight
/// 0.0202 -> 0.0231 (its bytes are 0-3: three wall luxels one byte lit where a sun passes
/// within the slack of a chimney piece's rim, a tie the bright fixture's compile of the
/// same geometry settles the other way); bounce, combo, filter, pad the same; on 2026-11-28,
/// dirt_depth 0.0050 and dirt_shaped 0.0142 (its dirt darker by its scale and gain, each
/// luxel's factor within 0.0037 of q3map2's on average: `dirt_factors_are_q3map2s_own`).
const FIXTURES: [(&str, f64, &[&str]); 27] = [
    ("point", 0.005, &[]),
    ("pillar", 0.005, &[]),
    ("offgrid", 0.004, &[]),
    ("near_wall", 0.005, &[]),
    ("spot", 0.005, &[]),
    ("surface", 0.005, &[]),
    ("twosided", 0.005, &[]),
    ("lamp", 0.005, &[]),
    ("receiver", 0.005, &[]),
    ("glass", 0.005, &[]),
    ("pad", 0.01, &[]),
    ("column", 0.005, &[]),
    ("arch", 0.005, &[]),
    ("sunk", 0.005, &[]),
    ("sun", 0.005, &[]),
    ("skylight", 0.026, &[]),
    ("skylight_bright", 0.005, &[]),
    ("bounce", 0.02, &["bounce"]),
    ("dirt", 0.01, &["dirt"]),
    ("dirt_depth", 0.01, &["dirt"]),
    ("dirt_shaped", 0.02, &["dirt"]),
    ("filter", 0.005, &["filter"]),
    ("gamma", 0.005, &[]),
    ("compensate", 0.01, &[]),
    ("minlight", 0.005, &[]),
    ("combo", 0.022, &["bounce", "dirt", "filter"]),
    ("detail", 0.005, &[]),
];

#[test]
fn q3map2_fixtures_are_reproduced_by_the_model() {
    let dir = tmp("fixtures");
    let mut failures = Vec::new();
    for (name, bound, switched) in FIXTURES {
        let bsp = fixtures().join(format!("maps/{name}.bsp"));
        let source = fixtures().join(format!("maps/{name}.map"));
        let r = globals_fit(&dir, name, bsp.to_str().unwrap(), &source, &[common::baseoa(), &fixtures()]);
        let err = r["rel_error_final"].as_f64().unwrap();
        eprintln!("{name:10} {err:.4} (bound {bound})");
        if !(err <= bound) {
            failures.push(format!("{name}: relative error {err:.4} > {bound}"));
        }
        // q3map2's shadow casters reach relight (convert's `q3_casters`): its pieces stop
        // the shadow rays.
        assert!(r["shadow_pieces"].as_u64().is_some_and(|n| n > 0), "{name}: {}", r["skipped_primitives"]);
        // The compile's recorded switches reach the model.
        let recorded = r["compile_cmdline"].as_str().unwrap_or_default();
        assert!(recorded.contains("-light"), "{name}: no recorded compile ({recorded:?})");
        for term in switched {
            let on = match *term {
                "bounce" => r["bounce"].is_array(),
                "dirt" => r["dirt"].is_object(),
                t => r[t] == true,
            };
            assert!(on, "{name}: the recorded compile switches {term} on, the model has it off: {}", r["terms"]);
        }
        // The dirt's settings are the recorded ones.
        if let Some(want) = recorded_dirt(name) {
            assert_eq!(dirt_settings(&r), Some(want), "{name}: {}", r["dirt"]);
        }
        // The lamp's quarters emit from q3map2's own mesh of them, which convert recorded.
        if name == "lamp" {
            assert_eq!(r["surfaces"][0]["q3map2_meshes"], 4, "{}", r["surfaces"]);
        }
        // The vertex-lit pad is sampled at its four quarters' control points, as q3map2 lit it.
        if name == "pad" {
            assert_eq!(r["luxel"]["patch_control_points"], 36, "{}", r["luxel"]);
        }
        // The half column's luxels are sampled where q3map2 sampled them, all of them.
        if name == "column" {
            assert_eq!(r["luxel"]["patch_luxels"], 234, "{}", r["luxel"]);
            assert_eq!(r["luxel"]["patch_luxel_records_unmatched"], 0, "{}", r["luxel"]);
        }
        // The arch's luxels in its pillar are nudged half a unit, as q3map2 nudged them:
        // a few come out, the rest are left out.
        if name == "arch" {
            assert_eq!(r["luxel"]["patch_luxels"], 182, "{}", r["luxel"]);
            assert!(r["luxel"]["nudged"].as_u64().is_some_and(|n| n < 10), "{}", r["luxel"]);
        }
        // The sunk patch's corner in the floor after a clear point is nudged out; the one
        // before any clear point (no normal in q3map2: black) is left out.
        if name == "sunk" {
            assert_eq!((r["luxel"]["vertices_nudged"].as_u64(), r["luxel"]["vertices_in_solid"].as_u64()), (Some(1), Some(1)), "{}", r["luxel"]);
        }
        // The bounce comes from q3map2's pieces of each lit surface, traced with more
        // rays per row than a big map gets (the fixture is small).
        if name == "bounce" {
            let t = &r["bounce_transport"];
            assert!(t["pieces"].as_u64().is_some_and(|p| p > 10) && t["rays_per_row"].as_u64().is_some_and(|m| m >= 64), "{t}");
        }
        if name == "gamma" {
            assert!(recorded.contains("-gamma 1.5"), "{recorded}");
        }
        // The clamp at 127 is found in the data (the record is not read for it), and
        // only where the compile put it.
        let clamp = r["data_clamp_byte"].as_u64();
        assert_eq!(clamp, (name == "compensate").then_some(127), "{name}: the data's clamp");
        // Emitters of their own kind: the surface light as a surface, the sky light and
        // the sun as themselves.
        match name {
            "surface" | "twosided" => assert!(r["surfaces"].as_array().is_some_and(|s| !s.is_empty()), "{name}: no surface light"),
            "sun" => assert!(r["sun"].is_object(), "{name}: no sun"),
            "skylight" | "skylight_bright" => assert!(r["sky"].is_array(), "{name}: no sky light"),
            "spot" => assert!(r["lights"].as_array().unwrap().iter().any(|l| l["kind"] == "spot"), "{name}: no spot: {}", r["lights"]),
            _ => {}
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The map's own solids (scene extras `q3_solids`, from the BSP) place the samples as
/// q3map2 did: in the `detail` fixture a faceless detail caulk block covers a crate's side
/// and a patch of floor, whose samples q3map2 counted as occluded. Without the record (as
/// after a Blender export without custom properties) relight guesses from the faces, cannot
/// see the caulk, and fits those texels as open floor.
#[test]
fn the_maps_own_solids_place_the_samples_as_q3map2_did() {
    let dir = tmp("solids");
    let bsp = fixtures().join("maps/detail.bsp");
    let gltf = dir.join("detail.gltf");
    let mut args: Vec<String> = vec!["convert".into(), bsp.to_str().unwrap().into()];
    for g in [common::baseoa(), &fixtures()] {
        args.extend(["--game-dir".into(), g.to_str().unwrap().into()]);
    }
    let source = fixtures().join("maps/detail.map");
    args.extend(["--lights-from".into(), source.to_str().unwrap().into(), "-o".into(), gltf.to_str().unwrap().into(), "-q".into()]);
    run(&args.iter().map(String::as_str).collect::<Vec<_>>());
    // The same scene without the record.
    let mut doc: Value = serde_json::from_slice(&std::fs::read(&gltf).unwrap()).unwrap();
    let extras = &mut doc["scenes"][0]["extras"];
    assert!(extras["q3_solids"]["nodes"].as_array().is_some_and(|n| !n.is_empty()), "convert wrote no solids");
    extras.as_object_mut().unwrap().remove("q3_solids");
    let faces = dir.join("faces.gltf");
    std::fs::write(&faces, serde_json::to_vec(&doc).unwrap()).unwrap();
    let fit = |input: &Path, name: &str| -> Value {
        let rep = dir.join(format!("{name}.json"));
        let out = dir.join(format!("{name}.relit.glb"));
        run(&["relight", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "--init", "input", "--fit", "globals", "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"]);
        serde_json::from_slice(&std::fs::read(&rep).unwrap()).unwrap()
    };
    let (with, without) = (fit(&gltf, "map"), fit(&faces, "faces"));
    assert_eq!(with["luxel"]["solids_from"], "map");
    assert_eq!(without["luxel"]["solids_from"], "faces");
    let (e_map, e_faces) = (with["rel_error_final"].as_f64().unwrap(), without["rel_error_final"].as_f64().unwrap());
    eprintln!("detail: {e_map:.4} with the map's solids, {e_faces:.4} from the faces");
    assert!(e_map <= 0.02, "{e_map}");
    // Measured 0.0113 against 0.0547.
    assert!(e_faces > 3.0 * e_map, "the solids bought nothing: {e_map} against {e_faces}");
    assert!(with["luxel"]["nudged"].as_u64().unwrap() > 0 && with["luxel"]["buried"].as_u64().unwrap() > 0, "{}", with["luxel"]);
}

/// The BSP's lightmap pages (lump 14: 128 x 128 RGB each).
fn bsp_lightmaps(path: &Path) -> Vec<u8> {
    let b = std::fs::read(path).unwrap();
    assert_eq!(&b[..4], b"IBSP", "{}", path.display());
    let at = 8 + 14 * 8;
    let off = u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize;
    let len = u32::from_le_bytes(b[at + 4..at + 8].try_into().unwrap()) as usize;
    b[off..off + len].to_vec()
}

/// The dirt settings a fixture's recorded compile gives: (depth in units, scale, gain).
fn recorded_dirt(name: &str) -> Option<(f32, f32, f32)> {
    match name {
        "dirt" | "combo" => Some((128.0, 1.0, 1.0)),
        "dirt_depth" => Some((64.0, 1.0, 1.0)),
        "dirt_shaped" => Some((48.0, 1.5, 0.8)),
        _ => None,
    }
}

/// A report's dirt settings: (depth in units, scale, gain; the f32 the model holds),
/// `None` without dirt.
fn dirt_settings(r: &Value) -> Option<(f32, f32, f32)> {
    let d = &r["dirt"];
    Some((d["depth_units"].as_f64()? as f32, d["scale"].as_f64()? as f32, d["gain"].as_f64()? as f32))
}

/// The dirt factor of every luxel, against q3map2's own: each `*_debug` fixture is its
/// dirt fixture compiled with `-dirtdebug` (q3map2 writes 255 x its factor as the
/// lightmap) and `-nocollapse` (the same pages); `dirt` at q3map2's default settings,
/// `dirt_shaped` with every setting away from its default (`-dirtdepth 48 -dirtscale 1.5
/// -dirtgain 0.8`). convert puts a one-texel border around a page, so texel (x, y) of ours
/// is (x - 1, y - 1) of the BSP's.
/// Measured on 2026-11-23 (`dirt`): mean difference 0.0026, 99.4% of the luxels within
/// 0.05. The edge rows where a face meets a wall sit on the wall's plane: they see it at
/// distance 0 (with the rays started at the sample instead, the mean was 0.038), and
/// q3map2's BSP trace also stops the rays along a wall whose solid is on its positive side
/// (`SolidAhead`; without that, 0.0129 and 87.6%: the corners). On 2026-11-28,
/// `dirt_shaped`: mean 0.0037, 98.9% within 0.05.
#[test]
fn dirt_factors_are_q3map2s_own() {
    for (lit, debug) in [("dirt", "dirt_debug"), ("dirt_shaped", "dirt_shaped_debug")] {
        let dir = tmp(debug);
        let bsp = fixtures().join(format!("maps/{lit}.bsp"));
        let source = fixtures().join(format!("maps/{lit}.map"));
        let dump = dir.join("rows.csv");
        globals_fit_with(&dir, lit, bsp.to_str().unwrap(), &source, &[common::baseoa(), &fixtures()], &["--dump-rows", dump.to_str().unwrap()]);
        let truth = bsp_lightmaps(&fixtures().join(format!("maps/{debug}.bsp")));
        assert_eq!(truth.len(), 128 * 128 * 3, "{debug}: one page");
        let rows = common::RowsDump::read(&dump);
        let (tx, ty, dirt) = (rows.column("tx"), rows.column("ty"), rows.column("dirt"));
        let mut diffs = Vec::new();
        for ((&x, &y), &ours) in tx.iter().zip(&ty).zip(&dirt) {
            assert!(ours.is_finite(), "{debug}: texel ({x}, {y}) has no dirt factor");
            let (x, y) = (x as usize, y as usize);
            assert!((1..=128).contains(&x) && (1..=128).contains(&y), "{debug}: texel ({x}, {y}) outside the page");
            let q3 = truth[((y - 1) * 128 + (x - 1)) * 3] as f64 / 255.0;
            assert!(q3 > 0.0, "{debug}: texel ({x}, {y}): q3map2 mapped no luxel there");
            diffs.push((ours - q3).abs());
        }
        let n = diffs.len() as f64;
        let mean = diffs.iter().sum::<f64>() / n;
        let within = diffs.iter().filter(|d| **d <= 0.05).count() as f64 / n;
        eprintln!("{debug}: dirt against q3map2's: {} luxels, mean difference {mean:.4}, {:.1}% within 0.05", diffs.len(), 100.0 * within);
        assert!(diffs.len() >= 4700, "{debug}: every luxel, the faces' edge rows included: {}", diffs.len());
        assert!(mean <= 0.006 && within >= 0.97, "{debug}: mean {mean:.4}, within 0.05: {within:.3}");
    }
}

/// A copy of a fixture's BSP in `dir` with its compile record hidden, as the OACMP maps
/// ship: the key `_q3map2_cmdline` renamed to one of the same length that nothing reads
/// (the entity lump keeps its size, so every offset stands).
fn without_record(dir: &Path, name: &str) -> PathBuf {
    let mut b = std::fs::read(fixtures().join(format!("maps/{name}.bsp"))).unwrap();
    let key = b"\"_q3map2_cmdline\"";
    let at = b.windows(key.len()).position(|w| w == key).unwrap_or_else(|| panic!("{name}: no compile record"));
    b[at + key.len() - 2] = b'X';
    assert!(!b.windows(key.len()).any(|w| w == key));
    let out = dir.join(format!("{name}_unrecorded.bsp"));
    std::fs::write(&out, b).unwrap();
    out
}

/// Where no compile is recorded, the data decides the dirt and its depth among
/// `DIRT_DEPTHS_UNITS`: the fixture lit at depth 64 is fitted at 64, the one at q3map2's
/// default at 128, and a map lit without dirt has none. Measured on 2026-11-28: 0.0050,
/// 0.0046 and 0.0000.
#[test]
fn the_dirt_and_its_depth_are_estimated_where_no_compile_is_recorded() {
    let dir = tmp("unrecorded");
    let mut failures = Vec::new();
    for (name, want, bound) in [("dirt_depth", Some(64.0), 0.01), ("dirt", Some(128.0), 0.01), ("pillar", None, 0.01)] {
        let bsp = without_record(&dir, name);
        let source = fixtures().join(format!("maps/{name}.map"));
        let r = globals_fit(&dir, name, bsp.to_str().unwrap(), &source, &[common::baseoa(), &fixtures()]);
        assert!(r["compile_cmdline"].is_null(), "{name}: the record is still read: {}", r["compile_cmdline"]);
        let err = r["rel_error_final"].as_f64().unwrap();
        let got = dirt_settings(&r);
        eprintln!("{name:10} {err:.4} (bound {bound}), dirt {got:?}");
        if got.map(|d| d.0) != want || got.is_some_and(|d| (d.1, d.2) != (1.0, 1.0)) {
            failures.push(format!("{name}: dirt {got:?}, want depth {want:?}: {}", r["terms"]));
        }
        if !(err <= bound) {
            failures.push(format!("{name}: relative error {err:.4} > {bound}"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// (map, largest relative error): the shipped BSPs of the truth set with their own source
/// lights, only the global terms fitted. Measured on 2026-11-23 (the README's table):
/// 0.2656, 0.1789, 0.2555, 0.1520, 0.1045; on 2026-11-25, with the data's clamp at 127 on
/// oacmpdm1-3 (`scene::find_clamp`): 0.2655, 0.0934, 0.1863, 0.1539, 0.1005; on
/// 2026-11-26, oacmpdm1 0.2274 with its torches' flames two-sided, 0.2033 with its lamps
/// emitting from q3map2's patch mesh; on 2026-11-26 (sixth), oacmpdm4 0.1053 with its blue
/// flames casting no shadow as the compile recorded, then with each kind of emitter run
/// through the filter and the bounce at any number of lights and the bounce tried at
/// q3map2's default factor: 0.1656, 0.0585, 0.1516, 0.1053, 0.0785; on 2026-11-27, with
/// the compile's gamma estimated (`rows::gamma`; the error against the stored bytes):
/// 0.1562 (gamma 1.25), 0.0585, 0.1516, 0.1053, 0.0705 (gamma 1.375); on 2026-11-27
/// (seventh), with q3map2's own pieces stopping the shadow rays: 0.1541 (gamma 1.25),
/// 0.0582, 0.1474, 0.1055, 0.0715 (gamma 1.375); on 2026-11-28, with the dirt's depth
/// estimated where no compile records it (`model::compile::DIRT_DEPTHS_UNITS`): 0.1484
/// (gamma 1.25, depth 32), 0.0582, 0.1474, 0.1055, 0.0662 (gamma 1.25, depth 128). The
/// third figure is the range of the estimated gamma.
const TRUTH_SET: [(&str, f64, (f64, f64)); 5] = [("oacmpdm1", 0.16, (1.125, 1.375)), ("oacmpdm2", 0.075, (1.0, 1.0)), ("oacmpdm3", 0.16, (1.0, 1.0)), ("oacmpdm4", 0.125, (1.0, 1.0)), ("oacmpctf1", 0.08, (1.25, 1.5))];

#[test]
fn truth_set_maps_with_their_source_lights() {
    let dir = tmp("truth");
    let pk3 = common::oacmp().join("z_oacmp-volume1-v3.pk3");
    let mut failures = Vec::new();
    for (map, bound, (g_lo, g_hi)) in TRUTH_SET {
        let source = dir.join(format!("{map}.map"));
        common::extract(&pk3, &format!("sources/maps/{map}.map"), &source);
        let r = globals_fit(&dir, map, map, &source, &[common::baseoa(), common::oacmp()]);
        let err = r["rel_error_final"].as_f64().unwrap();
        let g = r["gamma"]["gamma"].as_f64().unwrap();
        eprintln!("{map:10} {err:.4} (bound {bound}), gamma {g} ({})", r["gamma"]["how"]);
        if !(err <= bound) {
            failures.push(format!("{map}: relative error {err:.4} > {bound}"));
        }
        if !(g >= g_lo - 1e-9 && g <= g_hi + 1e-9) {
            failures.push(format!("{map}: gamma {g} outside [{g_lo}, {g_hi}]: {}", r["gamma"]));
        }
        assert!(!r["lights"].as_array().unwrap().is_empty(), "{map}: the source's lights were not read");
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The JSON chunk of a GLB file.
fn glb_json(path: &Path) -> Value {
    let b = std::fs::read(path).unwrap();
    let len = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
    serde_json::from_slice(&b[20..20 + len]).unwrap()
}

/// A glTF's point lights: (intensity, position in m), root nodes.
fn point_lights(doc: &Value) -> Vec<(f64, [f64; 3])> {
    let lights = doc["extensions"]["KHR_lights_punctual"]["lights"].as_array().cloned().unwrap_or_default();
    doc["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|n| {
            let l = &lights[n["extensions"]["KHR_lights_punctual"]["light"].as_u64()? as usize];
            (l["type"] == "point").then(|| {
                let t = n["translation"].as_array().map(|t| [0, 1, 2].map(|k| t[k].as_f64().unwrap())).unwrap_or([0.0; 3]);
                (l["intensity"].as_f64().unwrap_or(1.0), t)
            })
        })
        .collect()
}

/// (map, the error of the same map started from its source lights and fully refitted
/// (`--init input`), fewest of the source's 10 strongest point lights with a found point
/// light within 64 units). The default relight must end within the fidelity issue's
/// 1.15 x that refit. The refits measured on 2026-12-02 (2-core Xeon; the linear fit's
/// rounds through the chain), as the README's recovery table; the default then (the
/// placement and a thousand dense candidates beside it): 0.1238 (179 lights, 6/10),
/// 0.0530 (180, 5/10), 0.1386 (241, 9/10), 0.0869 (68, 10/10), 0.0827 (27, 0/10). The
/// counts' margins: the ten strongest are ten of a tie on oacmpdm1-4 (23 of oacmpdm2's
/// sources share `light 90`), so which of them a fit comes near varies between runs
/// (oacmpdm2 7/10 with 300 candidates, 5/10 with 1000); oacmpctf1 is skipped (its light is
/// its sky's: 0.89 of the direct light, 0.10 its point lights').
///
/// Before, the largest error of the default relight. Measured on 2026-11-24 (2 cores):
/// see the README's recovery table; the fidelity issue's goals (within 1.15 x the source
/// refit, 7 of 10 found) are met on oacmpdm4 only. On 2026-11-25, with the data's clamp
/// and the linear fit's active set of censored bounds: 0.2233 (3 lights), 0.1881 (33),
/// 0.2494 (63), 0.2115 (50), 0.0878 (16); on 2026-11-26, with q3map2's patch mesh:
/// 0.2123 (2), 0.1863 (34), 0.2567 (61), 0.2115 (50), 0.0878 (16); on 2026-11-26 (fourth),
/// with curved patches and sunk control points sampled as q3map2 did: 0.2015 (21), 0.2313
/// (12), 0.2607 (60), 0.2144 (50), 0.0876 (14); on 2026-11-26 (fifth), with curved
/// patches nudged along q3map2's own directions and no cracks in the shadow rays: 0.2105
/// (8), 0.1889 (28), 0.2563 (63), 0.2082 (50), 0.0897 (13); on 2026-11-26 (sixth), oacmpdm4
/// with its blue flames casting no shadow: 0.1462 (53); on 2026-11-27 (second), with q3map2's
/// bounce lights, the placement's bounce estimate through them and surface lights cut along
/// Quake's axes: 0.2112 (9), 0.1958 (24), 0.2549 (63), 0.1310 (55, 10/10), 0.0895 (15); on 2026-11-27 (third), with the shadow
/// walk's boxes grown by its slack and the sky's suns traced as q3map2 does: 0.2192 (1),
/// 0.1957 (24), 0.2563 (62), 0.1290 (56, 10/10), 0.0871 (16); on 2026-11-27 (fourth), with
/// the placement proposing down to a gain of 0.0003: 0.1922 (56, 4/10), 0.1678 (47, 1/10),
/// 0.2577 (61, 1/10), 0.1220 (57, 10/10), 0.0820 (20); on 2026-11-27 (fifth), with each
/// placement round past 8 lights refitting only the new light's neighbours and room for
/// 128 lights: 0.1692 (91, 5/10), 0.1669 (49, 1/10), 0.1894 (120, 1/10), 0.1286 (55,
/// 10/10), 0.0823 (19); then with ten failed rounds before the placement stops (three
/// before): 0.1646 (95, 5/10), 0.1534 (59, 1/10), the others the same; on 2026-11-27
/// (sixth), with up to four lights a placement try and ten failed tries in a row ending
/// it: 0.1676 (92, 6/10), 0.1500 (57, 1/10), 0.1889 (120, 1/10), 0.1286 (56, 10/10),
/// 0.0823 (19); on 2026-11-27 (seventh), with q3map2's own pieces stopping the shadow
/// rays: 0.1699 (85, 5/10), 0.1468 (59, 1/10), 0.1923 (117, 1/10), 0.1226 (57, 10/10),
/// 0.0830 (21, 1/10); on 2026-11-28 (tenth), with candidates a few decimetres off the
/// surfaces (`init::CANDIDATE_HEIGHTS`): 0.1623 (108, 6/10), 0.0676 (101, 1/10), 0.1940
/// (116, 1/10), 0.1012 (59, 10/10), 0.0830 (21, 1/10).
/// oacmpdm2's default is path dependent: its
/// placement subsample has three offsets (`--seed` 1, 2, 3: 0.2313 with 12 lights, 0.1907
/// with 28, 0.1966 with 24; on 2026-11-27 (fifth), refitted by overlap from the first
/// light, 0.1575 with 53, 0.1723 with 42, 0.2214 with 21; with ten failed rounds 0.1534
/// with 59, 0.1781 with 42, 0.1253 with 63; on 2026-11-27 (sixth), several lights a try:
/// 0.1500 with 57, 0.1814 with 40, 0.1404 with 62; on 2026-11-28 (tenth), with the low
/// candidates, converted without the source: 0.0700 with 90, 0.0730 with 87, 0.0630 with
/// 102), so its bound leaves room for a change of path.
///
/// The last field: the least fraction of the tie class ([`Found::tied_found`]) found,
/// measured on 2026-12-02 (second session, the default as above): oacmpdm1 174/248 (0.70),
/// oacmpdm2 10/23 (0.43), oacmpdm3 22/27 (0.81), oacmpdm4 53/53, oacmpctf1 0/10 (no tie;
/// skipped, as above). Where the tie is large this is the steadier count: oacmpdm1's 6/10
/// is ten of its 248 equal lights, most of them 56-96 units from the next.
const RECOVERY: [(&str, f64, usize, f64); 5] = [
    ("oacmpdm1", 0.1544, 5, 0.6),
    ("oacmpdm2", 0.0526, 4, 0.3),
    ("oacmpdm3", 0.1289, 7, 0.65),
    ("oacmpdm4", 0.0856, 8, 0.9),
    ("oacmpctf1", 0.0820, 0, 0.0),
];

/// The fidelity issue's recovery goal: the default within this factor of the source refit.
const RECOVERY_RATIO: f64 = 1.15;

/// How many of a map's strongest source point lights a relight came near (a fitted point
/// light within 64 units).
struct Found {
    /// Of the 10 strongest (ties in the file's order).
    first_ten: usize,
    /// Of every source at least as strong as the 10th: where hundreds share one intensity
    /// (all 248 of oacmpdm1's, 23 of oacmpdm2's at `light 90`), "the ten strongest" is
    /// the file's order, and this fraction says what a fit found of that whole class.
    tied_found: usize,
    tied: usize,
}

impl Found {
    fn tied_fraction(&self) -> f64 {
        self.tied_found as f64 / self.tied.max(1) as f64
    }
}

/// A relight of a truth-set map converted with its `.map` source, from no source light
/// (`relight` with `args` after the input): its report, its point lights, and what it
/// found of the source's strongest point lights.
fn recovery(dir: &Path, map: &str, tag: &str, args: &[&str]) -> (Value, usize, Found) {
    let pk3 = common::oacmp().join("z_oacmp-volume1-v3.pk3");
    let source = dir.join(format!("{map}.map"));
    if !source.exists() {
        common::extract(&pk3, &format!("sources/maps/{map}.map"), &source);
    }
    let gltf = dir.join(format!("{map}.glb"));
    if !gltf.exists() {
        convert_with_source(dir, map, map, &source, &[common::baseoa(), common::oacmp()]);
    }
    let rep = dir.join(format!("{map}.{tag}.json"));
    let out = dir.join(format!("{map}.{tag}.glb"));
    let mut all = vec!["relight", gltf.to_str().unwrap(), "-o", out.to_str().unwrap(), "--backend", "cpu", "--report", rep.to_str().unwrap(), "-q"];
    all.extend_from_slice(args);
    run(&all);
    let r: Value = serde_json::from_slice(&std::fs::read(&rep).unwrap()).unwrap();
    let mut sources = point_lights(&glb_json(&gltf));
    assert!(sources.len() >= 10, "{map}: {} source point lights", sources.len());
    sources.sort_by(|a, b| b.0.total_cmp(&a.0));
    // The fitted lights, as the report gives them (the written scene is checked elsewhere).
    let found: Vec<[f64; 3]> = r["lights"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|l| l["kind"] == "point")
        .map(|l| [0, 1, 2].map(|k| l["position_m"][k].as_f64().unwrap()))
        .collect();
    let reach = 64.0 * 0.0254;
    let near = |p: [f64; 3]| found.iter().any(|q| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt() <= reach);
    let first_ten = sources[..10].iter().filter(|(_, p)| near(*p)).count();
    let tenth = sources[9].0;
    let tied: Vec<&(f64, [f64; 3])> = sources.iter().filter(|(i, _)| *i >= tenth).collect();
    let tied_found = tied.iter().filter(|(_, p)| near(*p)).count();
    (r, found.len(), Found { first_ten, tied_found, tied: tied.len() })
}

/// Recovery: the default relight (`--init auto`, no source) on the truth-set maps.
#[test]
fn truth_set_recovery_by_the_default_relight() {
    let dir = tmp("recovery");
    let mut failures = Vec::new();
    for (map, refit, min_found, min_tied) in RECOVERY {
        let bound = RECOVERY_RATIO * refit;
        let (r, lights, found) = recovery(&dir, map, "auto", &[]);
        let hits = found.first_ten;
        assert!(r["dense_candidates"].as_u64().is_some_and(|c| c > 100), "{map}: the default placed no dense candidates: {}", r["dense_candidates"]);
        let err = r["rel_error_final"].as_f64().unwrap();
        common::assert_terms_within_allowance(map, &r);
        let tied = format!("{}/{} of the sources at least as strong as the 10th", found.tied_found, found.tied);
        eprintln!("{map:10} {err:.4} ({:.3} x the source refit's {refit}), {lights} lights, {hits}/10 of the strongest sources found (at least {min_found}), {tied} (at least {min_tied})", err / refit);
        if !(err <= bound) || hits < min_found || found.tied_fraction() < min_tied {
            failures.push(format!("{map}: error {err:.4} (bound {bound:.4}: {RECOVERY_RATIO} x {refit}), {hits}/10 found (at least {min_found}), {tied} (at least {min_tied})"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Recovery from the dense start (`--init dense`) on oacmpdm2, the truth-set map lit most
/// by point lights (83% of its direct light from its 1237 light entities, in the globals
/// fit of its own sources): measured 2026-12-01 (2-core Xeon), 0.0514 with 198 lights and
/// 4 of the 10 strongest found, against the default's 0.0702 (87 lights, 0/10) and the
/// source refit's 0.0523 (210); on 2026-12-02, with the linear fit's rounds through the
/// chain and the candidates it leaves dark dropped, 0.0513 (202, 5/10), the refit 0.0526.
/// The bound is the fidelity issue's goal, 1.15 x that
/// refit; the ten strongest are ten of 23 tied at `light 90`, so which of them a fit
/// comes near is close to a coin's toss (the sources within 64 units of a found light
/// hold 0.61-0.73 of the source intensity over the variants measured), hence the margin on
/// the count.
#[test]
fn truth_set_recovery_by_the_dense_start() {
    let dir = tmp("recovery-dense");
    let (r, lights, found) = recovery(&dir, "oacmpdm2", "dense", &["--init", "dense"]);
    let hits = found.first_ten;
    let err = r["rel_error_final"].as_f64().unwrap();
    common::assert_terms_within_allowance("oacmpdm2", &r);
    eprintln!("oacmpdm2 dense {err:.4}, {lights} lights, {hits}/10 of the strongest sources found, {}/{} of those at least as strong as the 10th", found.tied_found, found.tied);
    assert!(r["dense_candidates"].as_u64().is_some_and(|c| c > 500), "{}", r["dense_candidates"]);
    assert!(err <= RECOVERY_RATIO * 0.0526, "oacmpdm2 from the dense start: error {err:.4}, over 1.15 x the source refit's 0.0526");
    assert!(hits >= 3, "oacmpdm2 from the dense start: {hits}/10 of the strongest sources found");
}
