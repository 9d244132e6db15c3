//! `q3gltf relight`: argument parsing, progress display and the final summary; the work is
//! `q3gltf_relight::pipeline::run`.

use std::path::PathBuf;
use std::time::Duration;

use clap::Args;
use q3gltf_relight::fit::IterRecord;
use q3gltf_relight::rows::look::Look;
use q3gltf_relight::pipeline::{self, BackendChoice, Estimator, FitMode, GammaChoice, Init, Optional, Options, Progress, Subdivide, TargetSpace};
use q3gltf_relight::report;

/// The most candidates `--init dense:N` takes (each is a light of the first fit).
const MAX_DENSE: usize = 8192;

#[derive(Args)]
pub struct RelightArgs {
    /// Input scene (.gltf or .glb): the output of `q3gltf convert`, or that scene after a
    /// Blender import/export. The lightmap must be the occlusionTexture on TEXCOORD_1.
    pub input: PathBuf,
    /// Output (.gltf or .glb): the input scene plus KHR_lights_punctual point lights.
    #[arg(short, long, value_name = "OUT", required_unless_present = "write_mesh")]
    pub output: Option<PathBuf>,
    /// Where the lightmap is compared with the model: `luxel` (one row per lightmap texel,
    /// at the surface point q3map2 baked it for: exact for hard shadows) or `vertex` (the
    /// thesis: the mass-lumped L2 projection of texture x lightmap onto the vertices).
    #[arg(long, default_value = "luxel", value_parser = ["luxel", "vertex"])]
    pub target: String,
    /// The picture to reproduce: `lightmap`, q3map2's baked light as stored (recovers the
    /// mapper's lights; the physics of the map), or `game`, what the game's screen shows
    /// (the engine multiplies the texture's sRGB bytes by the lightmap clamped at 1, and
    /// the screen's transfer function makes that light): a linear renderer such as
    /// Blender's Cycles, lit by the result, then looks like the game. See README, "The
    /// game as the reference", on which look relight fits.
    #[arg(long, default_value = "lightmap", value_parser = ["lightmap", "game"])]
    pub look: String,
    /// Refine the mesh before projecting the target: `lightmap` (no edge longer than one
    /// lightmap texel), `off`, or a largest edge length in meters. Default: `lightmap` with
    /// `--target vertex`, `off` with `--target luxel` (its lightmap rows do not depend on
    /// the vertices; only vertex-lit surfaces would gain rows).
    #[arg(long, value_name = "lightmap|off|METERS")]
    pub subdivide: Option<String>,
    /// Vertex budget of the subdivision.
    #[arg(long = "max-vertices", default_value_t = 1_500_000)]
    pub max_vertices: usize,
    /// Starting lights: `auto` (the greedy placement in free space, then a thousand dense
    /// candidates beside its lights, all fitted at once and pruned to as few as the data
    /// needs), `greedy` (the placement alone: fewer lights, faster, higher error on maps
    /// lit by many small light entities), `dense[:N]` (only the N candidates, default
    /// 1000, in free space over the brightest rows), `grid:N` (the thesis's N x N grid),
    /// `input` (the file's point lights; a light with extras `"locked": true` is kept
    /// fixed).
    #[arg(long, default_value = "auto", value_name = "auto|greedy|dense[:N]|grid:N|input")]
    pub init: String,
    /// Optimisation scheme: default, fast, thesis1..thesis5 (Table 5.1 of the thesis), or
    /// one phase of `adam:STEP` or `lbfgs:STEP` (the thesis's basic schemes, section 5.1).
    #[arg(long, default_value = "default")]
    pub scheme: String,
    /// What computes the lights' light: `model` (ours: a shadow ray from every row to
    /// every light under q3map2's rules, and the sun, sky, surface lights, dirt, filter and
    /// bounces where the map needs them) or `tracing` (the thesis's estimator, a baseline:
    /// `--rays` rays from each point light splatted onto the vertices they hit, with
    /// `--tracing-bounces` diffuse bounces, a fresh sample every evaluation; needs
    /// `--target vertex` and `--init grid:N` or `input`, and has nothing but point lights).
    #[arg(long, default_value = "model", value_parser = ["model", "tracing"])]
    pub estimator: String,
    /// Rays per light and evaluation of `--estimator tracing` (the thesis: 100,000).
    #[arg(long, default_value_t = q3gltf_relight::light_tracing::THESIS_RAYS)]
    pub rays: usize,
    /// Diffuse bounces of `--estimator tracing` (each lands on the vertices like the
    /// direct light, carrying the surface's albedo).
    #[arg(long = "tracing-bounces", default_value_t = 1)]
    pub tracing_bounces: usize,
    /// Most lights `auto` places (it stops earlier when a light no longer lowers the error
    /// by 0.0003 on its subsample; pruning then removes the lights not worth their cost).
    /// Measured (2-core machine): 64 was binding on oa_dm1 (0.28, 18 s; with 128: 77
    /// lights, 0.24, 20 s), oacmpdm1 and oacmpdm3 (0.26 -> 0.19 with 120 lights).
    #[arg(long = "max-lights", default_value_t = 128)]
    pub max_lights: usize,
    /// Caps every phase's iterations.
    #[arg(long = "max-iterations")]
    pub max_iterations: Option<usize>,
    /// Stop optimising after this many seconds (the result so far is written).
    #[arg(long = "time-limit", value_name = "SECONDS")]
    pub time_limit: Option<f64>,
    /// Where the forward model runs: `auto` (a hardware GPU if wgpu finds one, else the
    /// CPU), `wgpu` (any adapter, software Vulkan included), `cpu`.
    #[arg(long, default_value = "auto", value_parser = ["auto", "wgpu", "cpu"])]
    pub backend: String,
    /// Write the run's report (per-iteration time, objective, error; stages) as JSON.
    #[arg(long, value_name = "report.json")]
    pub report: Option<PathBuf>,
    /// Plot relative error against time as a PNG.
    #[arg(long, value_name = "curve.png")]
    pub plot: Option<PathBuf>,
    /// What the fit may change: `all`, or `globals` (the lights and the map's emitters
    /// stay as the file has them; only the compile's global terms are fitted: how well a
    /// map's own sources, e.g. from `convert --lights-from`, explain its lightmaps).
    #[arg(long, default_value = "all", value_parser = ["all", "globals"])]
    pub fit: String,
    /// Bounced light: the light of the model's own emitters reflected by the scene, as a
    /// renderer with global illumination computes it (each pass scaled by a fitted factor
    /// in (0, 4], 1 being q3map2's default `-bouncescale 0.25`). With it the written lights are the direct
    /// light only: render with global illumination. `auto`: as the map's recorded compile
    /// says (`-bounce N`), else where it lowers the error.
    #[arg(long, default_value = "auto", value_parser = ["auto", "on", "off"])]
    pub bounce: String,
    /// Rays per row for the bounce operator (rounded up to a square). Default: as many as
    /// a budget of 2^20 rays allows, 16 to 256 per row (16 on a map of 65k rows or more).
    #[arg(long = "bounce-rays")]
    pub bounce_rays: Option<usize>,
    /// A sun (directional light) for maps with sky: the sky shader's `q3map_sun` when the
    /// file has it as a directional light (convert `--entity-lights`), else searched;
    /// kept where it lowers the error; written as a KHR directional light in lux.
    #[arg(long, default_value = "auto", value_parser = ["auto", "on", "off"])]
    pub sun: String,
    /// The sky light of the map's sky shaders (`q3map_skyLight`), written as the sky
    /// surfaces' emission.
    #[arg(long, default_value = "auto", value_parser = ["auto", "on", "off"])]
    pub sky: String,
    /// The map's surface lights (`q3map_surfacelight` shaders), one radiance per shader,
    /// written as emissive materials.
    #[arg(long, default_value = "auto", value_parser = ["auto", "on", "off"])]
    pub surfaces: String,
    /// q3map2's dirt (`-dirty`: ambient occlusion multiplied in): `auto` as the recorded
    /// compile says (with its `-dirtdepth`, `-dirtscale`, `-dirtgain`), else where it
    /// lowers the error, its depth chosen by the data among 32, 64 and 128 units.
    #[arg(long, default_value = "auto", value_parser = ["auto", "on", "off"])]
    pub dirt: String,
    /// q3map2's lightmap filter (`-filter`: a 3x3 blur of each light): as `--dirt`.
    #[arg(long, default_value = "auto", value_parser = ["auto", "on", "off"])]
    pub filter: String,
    /// q3map2's `-gamma` (its lightmaps store light L as 255 (L/255)^(1/gamma)) where the
    /// file does not record it: `auto` estimates it when relight starts from the file's
    /// lights (`--init input`: the reading of the bytes whose fit, taken back to the stored
    /// bytes, is lowest; 1 unless another gains by the margin a term must; a placement from
    /// scratch would trade the lights' distance for it, so there it stays 1), `off` reads
    /// the bytes as they are, a number in [0.5, 4] reads them through that gamma from the
    /// start. The lights are then q3map2's linear light, the written file states the gamma
    /// on its lit materials, and the report's final error is against the stored bytes.
    #[arg(long, default_value = "auto", value_name = "auto|off|GAMMA")]
    pub gamma: String,
    /// Chooses which vertices `--init auto` samples (every k-th vertex from offset seed % k);
    /// the same seed gives the same result.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Only write the mesh relight would fit on (after --subdivide) to this PLY file and
    /// stop: positions in meters, lightmap UVs in texels as the texture coordinate. For
    /// inspecting the subdivision in MeshLab.
    #[arg(long = "write-mesh", value_name = "mesh.ply")]
    pub write_mesh: Option<PathBuf>,
    /// Also write every row's data and the final model's value there as CSV (material,
    /// texel, position, normal, albedo, the data's interval, the model, the area): where
    /// the model and the lightmap disagree.
    #[arg(long = "dump-rows", value_name = "rows.csv")]
    pub dump_rows: Option<PathBuf>,
    /// Also bake the output into this folder (as `q3gltf bake OUT -o DIR` with its
    /// defaults: relit, original and residual lightmaps as EXR and PNG, baked.glb); the
    /// report lists the files under `bake`.
    #[arg(long, value_name = "DIR")]
    pub bake: Option<PathBuf>,
    /// No progress display.
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Args)]
pub struct ProbeArgs {
    /// Scene (.gltf or .glb) with KHR_lights_punctual point lights.
    pub input: PathBuf,
    /// Surface point, world meters (glTF axes): X,Y,Z.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    pub at: String,
    /// Surface normal (any length): X,Y,Z.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    pub normal: String,
}

fn vec3(s: &str, what: &str) -> Result<glam::DVec3, String> {
    let v: Vec<f64> = s.split(',').map(|x| x.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|e| format!("{what} {s:?}: {e}"))?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(glam::DVec3::new(x, y, z)),
        _ => Err(format!("{what} {s:?}: expected three finite numbers X,Y,Z")),
    }
}

pub fn probe(a: ProbeArgs) -> Result<(), String> {
    let p = q3gltf_relight::probe::probe(&a.input, vec3(&a.at, "--at")?, vec3(&a.normal, "--normal")?).map_err(|e| e.to_string())?;
    println!("{}", serde_json::to_string_pretty(&p).map_err(|e| e.to_string())?);
    Ok(())
}

/// The command line's display: a spinner per stage, a bar per optimiser phase. Behind a
/// mutex because the relight reports from a thread of rayon's pool.
struct Bars {
    quiet: bool,
    bar: std::sync::Mutex<Option<indicatif::ProgressBar>>,
}

impl Bars {
    /// The current bar (a display that panicked once is still a display).
    fn bar(&self) -> std::sync::MutexGuard<'_, Option<indicatif::ProgressBar>> {
        self.bar.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

impl Progress for Bars {
    fn stage(&self, name: &str) {
        let mut bar = self.bar();
        if let Some(b) = bar.take() {
            b.finish_and_clear();
        }
        if !self.quiet {
            let b = indicatif::ProgressBar::new_spinner();
            b.set_message(name.to_string());
            b.enable_steady_tick(Duration::from_millis(120));
            *bar = Some(b);
        }
    }
    fn phase(&self, name: &str, max_iterations: usize) {
        self.stage(name);
        if let Some(b) = &*self.bar() {
            b.set_length(max_iterations as u64);
            b.set_style(indicatif::ProgressStyle::with_template("{msg:12} [{bar:30}] {pos}/{len} {elapsed}").unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()));
        }
    }
    fn iteration(&self, rec: &IterRecord) {
        if let Some(b) = &*self.bar() {
            b.set_position(rec.iteration as u64);
        }
    }
    fn phase_done(&self) {
        if let Some(b) = self.bar().take() {
            b.finish_and_clear();
        }
    }
}

fn parse(a: &RelightArgs) -> Result<Options, String> {
    let subdivide = match a.subdivide.as_deref() {
        None => None,
        Some("lightmap") => Some(Subdivide::Lightmap),
        Some("off") => Some(Subdivide::Off),
        Some(s) => match s.parse::<f32>() {
            Ok(m) if m.is_finite() && m > 0.0 => Some(Subdivide::Meters(m)),
            _ => return Err(format!("--subdivide {s:?}: expected lightmap, off or a positive length in meters")),
        },
    };
    let init = match a.init.as_str() {
        "auto" => Init::Auto,
        "greedy" => Init::Greedy,
        "input" => Init::Input,
        "dense" => Init::Dense(q3gltf_relight::init::DENSE_DEFAULT),
        s => match (s.strip_prefix("grid:").and_then(|n| n.parse::<usize>().ok()), s.strip_prefix("dense:").and_then(|n| n.parse::<usize>().ok())) {
            (Some(n), _) if (1..=64).contains(&n) => Init::Grid(n),
            (_, Some(n)) if (1..=MAX_DENSE).contains(&n) => Init::Dense(n),
            _ => return Err(format!("--init {s:?}: expected auto, greedy, input, dense[:N] with 1 <= N <= {MAX_DENSE}, or grid:N with 1 <= N <= 64")),
        },
    };
    let time_limit = match a.time_limit {
        Some(t) if t.is_finite() && t > 0.0 => Some(Duration::from_secs_f64(t)),
        Some(t) => return Err(format!("--time-limit {t}: expected a positive number of seconds")),
        None => None,
    };
    Ok(Options {
        input: a.input.clone(),
        output: a.output.clone().unwrap_or_default(),
        target: if a.target == "vertex" { TargetSpace::Vertex } else { TargetSpace::Luxel },
        look: if a.look == "game" { Look::Game } else { Look::Lightmap },
        subdivide,
        max_vertices: a.max_vertices.max(3),
        init,
        scheme: a.scheme.clone(),
        max_lights: a.max_lights.clamp(1, 256),
        max_iterations: a.max_iterations,
        time_limit,
        backend: match a.backend.as_str() {
            "wgpu" => BackendChoice::Wgpu,
            "cpu" => BackendChoice::Cpu,
            _ => BackendChoice::Auto,
        },
        seed: a.seed,
        fit: if a.fit == "globals" { FitMode::Globals } else { FitMode::All },
        bounce: optional(&a.bounce),
        bounce_rays: a.bounce_rays.map_or(0, |r| r.clamp(1, 1024)),
        sun: optional(&a.sun),
        sky: optional(&a.sky),
        surfaces: optional(&a.surfaces),
        dirt: optional(&a.dirt),
        filter: optional(&a.filter),
        gamma: match a.gamma.as_str() {
            "auto" => GammaChoice::Auto,
            "off" => GammaChoice::Off,
            g => match g.parse::<f32>() {
                Ok(v) if (0.5..=4.0).contains(&v) => GammaChoice::Fixed(v),
                _ => return Err(format!("--gamma {g}: expected auto, off or a gamma from 0.5 to 4")),
            },
        },
        dump_rows: a.dump_rows.clone(),
        estimator: match a.estimator.as_str() {
            "tracing" => {
                if !(1..=4_000_000).contains(&a.rays) {
                    return Err(format!("--rays {}: expected 1 to 4000000 rays per light", a.rays));
                }
                if a.tracing_bounces > 16 {
                    return Err(format!("--tracing-bounces {}: expected at most 16", a.tracing_bounces));
                }
                Estimator::Tracing { rays: a.rays, bounces: a.tracing_bounces }
            }
            _ => Estimator::Model,
        },
    })
}

fn optional(s: &str) -> Optional {
    match s {
        "on" => Optional::On,
        "off" => Optional::Off,
        _ => Optional::Auto,
    }
}

pub fn run(a: RelightArgs) -> Result<(), String> {
    let opts = parse(&a)?;
    if let Some(mesh) = &a.write_mesh {
        let stats = pipeline::write_mesh(&opts, mesh).map_err(|e| e.to_string())?;
        println!("mesh of {} -> {}", opts.input.display(), mesh.display());
        if let Some(s) = stats {
            println!("  subdivide {} -> {} vertices, {} -> {} triangles (longest edge {:.2}{})", s.vertices_before, s.vertices_after, s.triangles_before, s.triangles_after, s.longest_edge, if s.budget_reached { ", vertex budget reached" } else { "" });
        }
        return Ok(());
    }
    let bars = Bars { quiet: a.quiet, bar: Default::default() };
    let rep = pipeline::run(&opts, &bars).map_err(|e| e.to_string())?;
    bars.phase_done();
    let mut baked = None;
    if let Some(dir) = &a.bake {
        let b = q3gltf_relight::bake::Options {
            input: opts.output.clone(),
            out_dir: dir.clone(),
            bounces: None,
            bounce_rays: opts.bounce_rays,
            half: false,
            padding: 2,
            previews: true,
            backend: opts.backend,
            new_uvs: false,
            texel_m: None,
        };
        baked = Some(q3gltf_relight::bake::run(&b, &q3gltf_relight::bake::Quiet).map_err(|e| format!("bake: {e}"))?);
    }
    if let Some(p) = &a.report {
        report::write_json(&rep, baked.as_ref(), p).map_err(|e| e.to_string())?;
    }
    if let Some(p) = &a.plot {
        report::write_plot(&rep, p).map_err(|e| e.to_string())?;
    }
    println!("relit {} -> {}", rep.input, rep.output);
    println!("  backend   {} ({})", rep.backend, rep.backend_reason);
    if let Some(s) = &rep.subdivision {
        println!("  subdivide {} -> {} vertices in {} rounds (longest edge {:.2}{})", s.vertices_before, s.vertices_after, s.rounds, s.longest_edge, if s.budget_reached { ", vertex budget reached" } else { "" });
    }
    // The screen shows a clamped texel as stored (rows::look): not a lower bound there.
    let clamped_as = if rep.look == Look::Game { "intervals at what the screen shows" } else { "lower bounds" };
    if let Some(b) = rep.data_clamp_byte {
        println!("  data      clamped at byte {b}, not 255 (q3map2's -compensate): colours there are {clamped_as}");
    }
    match &rep.luxel {
        Some(l) => {
            println!(
                "  target    {} luxels ({} censored: {clamped_as}) and {} vertex-lit vertices; {} sliver triangles without a luxel",
                l.luxels, l.censored, l.vertex_rows, l.triangles_without_luxel
            );
            if l.patch_control_points + l.patch_records_unmatched > 0 {
                println!(
                    "  vertex    {} rows at the control points of vertex-lit patches, where q3map2 lit them{}",
                    l.patch_control_points,
                    if l.patch_records_unmatched > 0 { format!("; {} patches changed since convert sample their vertices", l.patch_records_unmatched) } else { String::new() }
                );
            }
            if l.patch_luxels + l.patch_luxel_records_unmatched > 0 {
                println!(
                    "  patches   {} luxels of curved patches where q3map2 sampled them{}",
                    l.patch_luxels,
                    if l.patch_luxel_records_unmatched > 0 { format!("; {} patches changed since convert sample their texel centres", l.patch_luxel_records_unmatched) } else { String::new() }
                );
            }
            if l.vertices_nudged + l.vertices_in_solid > 0 {
                println!("  vertex    {} control points in solid sampled where q3map2's nudge found clear, {} left out (in solid wherever it tried, or unlit by q3map2)", l.vertices_nudged, l.vertices_in_solid);
            }
            let from = if l.solids_from == "map" { "the map's own solids" } else { "the faces (the file carries no usable `q3_solids`)" };
            println!("  samples   {} nudged out of solid, {} left out (in solid or enclosed); solid as {from}", l.nudged, l.buried);
            match rep.shadow_pieces {
                Some(n) => println!("  shadows   q3map2's own {n} pieces of its casters stop the shadow rays"),
                None => println!("  shadows   the mesh's triangles stop the shadow rays (the file carries no usable `q3_casters`)"),
            }
        }
        None => println!(
            "  target    {} vertices with a target, {} censored (lower bounds), {} without baked lighting",
            rep.target.with_target, rep.target.censored, rep.target.no_coverage
        ),
    }
    let spots = rep.lights.iter().filter(|l| l.kind == "spot").count();
    match rep.dense_candidates {
        Some(c) => println!(
            "  lights    {} ({} spots; {}{c} dense candidates{}: pruned {}, merged {})",
            rep.lights.len(),
            spots,
            if rep.init == "auto" { "placed, then " } else { "from " },
            rep.dense_dark.map_or(String::new(), |d| format!(", {d} left dark by the first fit")),
            rep.pruned,
            rep.merged
        ),
        None => println!("  lights    {} ({} spots; pruned {}, merged {})", rep.lights.len(), spots, rep.pruned, rep.merged),
    }
    if let Some(s) = &rep.sun {
        println!("  sun       elevation {:.1} deg, azimuth {:.1} deg, {:.0} lux", s.elevation_deg, s.azimuth_deg, s.illuminance_lux);
    }
    let on: Vec<String> = rep.surfaces.iter().filter_map(|s| s.radiance.map(|r| format!("{} {:.3}", s.shader, r.iter().copied().fold(0.0f32, f32::max)))).collect();
    if !rep.surfaces.is_empty() {
        println!("  surfaces  {} of {} emitting shaders kept{}{}", on.len(), rep.surfaces.len(), if on.is_empty() { "" } else { ": " }, on.join(", "));
        let (meshes, unmatched) = rep.surfaces.iter().fold((0, 0), |(a, b), s| (a + s.q3map2_meshes, b + s.meshes_unmatched));
        if meshes + unmatched > 0 {
            println!("  patches   {meshes} emitting patches from q3map2's own mesh of them{}", if unmatched > 0 { format!("; {unmatched} changed since convert emit from their triangles") } else { String::new() });
        }
    }
    println!("  compile   {}", rep.compile_note);
    if let (Some(_), Some(t)) = (rep.bounce, &rep.bounce_transport) {
        println!("  bounce    {} passes from {} pieces of q3map2's bounce lights, {} rays per row ({:.0}% landed)", rep.bounces, t.pieces, t.rays_per_row, 100.0 * t.landed as f64 / (t.rays as f64).max(1.0));
    }
    println!("  gamma     {} ({})", rep.gamma.gamma, rep.gamma.how);
    for t in &rep.terms {
        println!("  term      {:<28} {} (error {:.4} without, {:.4} with)", t.term, if t.kept { "kept" } else { "off " }, t.rel_error_without, t.rel_error_with);
    }
    if let Some(m) = rep.residual_by_material.first() {
        println!("  residual  largest on {} ({:.0}% of it, its error {:.3})", m.material, 100.0 * m.residual_share, m.rel_error);
    }
    if rep.kept_input_state {
        println!("  kept      the input's own state: the refit ended worse than it");
    }
    println!("  error     {:.4} -> {:.4} (relative, area-weighted, against the stored bytes)", rep.rel_error_initial, rep.rel_error_final);
    let stages: Vec<String> = rep.stage_times_s.iter().map(|(n, t)| format!("{n} {t:.2}s")).collect();
    println!("  time      {:.2} s: {}", rep.total_time_s, stages.join(", "));
    let what = if matches!(rep.estimator, Estimator::Tracing { .. }) { "light paths traced" } else { "shadow rays" };
    let (phase_rays, phase_trace_s) = rep.phases.iter().fold((0u64, 0.0f64), |(r, t), p| (r + p.rays, t + p.trace_s));
    println!(
        "  rays      {} {what}, {} objective evaluations; the fit's phases re-traced {phase_rays} rays in {phase_trace_s:.2} s",
        rep.rays_traced, rep.evaluations
    );
    if let Some(b) = &baked {
        println!("  bake      {} files in {} (error {:.4}, {:.2} s)", b.files.len(), b.out_dir, b.rel_error.unwrap_or(f64::NAN), b.seconds);
    }
    Ok(())
}
