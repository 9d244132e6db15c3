//! The whole relight: read, subdivide, build the target (luxel rows or the vertex
//! projection), build the BVH, gather the indirect light, choose the starting lights, run
//! the scheme's phases, prune and merge, decide on the indirect and ambient terms, write
//! the glTF, and gather the report.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use glam::Vec3;
use serde::Serialize;
use serde_json::json;

use crate::backend::{Backend, Cpu};
use crate::bvh::Bvh;
use crate::error::{Error, Result};
use crate::fit::{Fitter, IterRecord, PhaseSummary};
use crate::gltf_in;
use crate::init;
use crate::lights_out::{self, OutLight, LM_PER_W};
use crate::model::{Light, Problem, Sun};
use crate::schemes;
use crate::subdivide::{self, Bound};
use crate::target::{self, TargetStats};

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Subdivide {
    Off,
    /// About one lightmap texel per edge.
    Lightmap,
    /// At most this many meters per edge.
    Meters(f32),
}

/// Where the objective's rows are: see [`crate::luxel`] and [`crate::target`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TargetSpace {
    /// One row per lightmap texel, at the point q3map2 baked it for (the default).
    Luxel,
    /// One row per (subdivided) vertex: the thesis's mass-lumped L2 projection.
    Vertex,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Init {
    Auto,
    Grid(usize),
    Input,
}

/// Whether the model has the indirect term ([`crate::indirect`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Optional {
    /// Only when it lowers the relative error by at least [`TERM_GAIN`].
    Auto,
    Off,
    On,
}

/// Rows of the subsample on which `--init auto` places lights (every k-th row).
pub const AUTO_SAMPLE_ROWS: usize = 20_000;

/// A global term (indirect, ambient) stays in the model with `auto` only when it lowers
/// the relative error by at least this much (absolute).
pub const TERM_GAIN: f64 = 0.005;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BackendChoice {
    Auto,
    Wgpu,
    Cpu,
}

#[derive(Debug, Clone)]
pub struct Options {
    pub input: PathBuf,
    pub output: PathBuf,
    pub target: TargetSpace,
    /// `None`: `Lightmap` for the vertex target, `Off` for the luxel target (whose
    /// lightmapped rows do not depend on the mesh's vertices).
    pub subdivide: Option<Subdivide>,
    pub max_vertices: usize,
    pub init: Init,
    pub scheme: String,
    pub max_lights: usize,
    /// Caps every phase's iterations.
    pub max_iterations: Option<usize>,
    pub time_limit: Option<Duration>,
    pub backend: BackendChoice,
    pub seed: u64,
    pub indirect: Optional,
    /// Gather rays per row for the indirect term.
    pub indirect_rays: usize,
    /// Whether the model has a sun (`auto`: searched when the scene has sky surfaces or a
    /// directional light, kept where it lowers the error).
    pub sun: Optional,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            input: PathBuf::new(),
            output: PathBuf::new(),
            target: TargetSpace::Luxel,
            subdivide: None,
            max_vertices: 1_500_000,
            init: Init::Auto,
            scheme: "default".into(),
            max_lights: 32,
            max_iterations: None,
            time_limit: None,
            backend: BackendChoice::Auto,
            seed: 1,
            indirect: Optional::Auto,
            indirect_rays: 16,
            sun: Optional::Auto,
        }
    }
}

/// What the command line shows while the work goes on. Methods take `&self` so the
/// optimiser's per-iteration callback can hold the display while stages are reported.
pub trait Progress {
    fn stage(&self, _name: &str) {}
    fn phase(&self, _name: &str, _max_iterations: usize) {}
    fn iteration(&self, _rec: &IterRecord) {}
    fn phase_done(&self) {}
}
pub struct Silent;
impl Progress for Silent {}

#[derive(Debug, Clone, Serialize)]
pub struct SunReport {
    pub name: String,
    /// Unit vector towards the sun, world axes.
    pub to_sun: [f64; 3],
    /// Above the horizontal plane, degrees.
    pub elevation_deg: f64,
    /// From +X towards +Z (glTF axes), degrees.
    pub azimuth_deg: f64,
    /// Illuminance at normal incidence of the brightest channel, lux (683 lm/W).
    pub illuminance_lux: f64,
    pub color: [f64; 3],
}

#[derive(Debug, Clone, Serialize)]
pub struct LightReport {
    pub name: String,
    pub position_m: [f64; 3],
    pub intensity_cd: f64,
    pub color: [f64; 3],
    pub range_m: f64,
    /// Share of the model's area-weighted radiance that comes from this light.
    pub energy_share: f64,
    pub locked: bool,
}

#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub input: String,
    pub output: String,
    pub backend: String,
    pub backend_reason: String,
    /// Where the target projection ran ("wgpu", "cpu", or "cpu (why not wgpu)").
    pub target_backend: String,
    pub scheme: String,
    pub init: String,
    pub vertices_input: usize,
    pub triangles_input: usize,
    pub subdivision: Option<subdivide::Stats>,
    pub target_space: TargetSpace,
    /// The per-vertex projection (with the luxel target: of the vertex-lit materials only).
    pub target: TargetStats,
    /// The luxel rows, with the luxel target.
    pub luxel: Option<crate::luxel::LuxelStats>,
    /// Rows of the objective (vertices or luxels).
    pub problem_rows: usize,
    pub rel_error_initial: f64,
    pub rel_error_final: f64,
    pub lights: Vec<LightReport>,
    pub ambient: Option<[f32; 3]>,
    pub ambient_note: String,
    /// Fitted scale `k_c` of the gathered indirect radiance, when the model kept it.
    pub indirect: Option<[f32; 3]>,
    pub indirect_note: String,
    pub indirect_gather: Option<crate::indirect::GatherStats>,
    pub sun: Option<SunReport>,
    pub sun_note: String,
    pub pruned: usize,
    pub merged: usize,
    pub auto: Option<init::AutoStats>,
    pub phases: Vec<PhaseSummary>,
    pub iterations: Vec<IterRecord>,
    pub rays_traced: u64,
    pub evaluations: usize,
    /// Seconds per stage, in order.
    pub stage_times_s: Vec<(String, f64)>,
    pub total_time_s: f64,
    pub skipped_primitives: Vec<String>,
}

struct Stages {
    t: Instant,
    list: Vec<(String, f64)>,
}
impl Stages {
    fn done(&mut self, name: &str) {
        self.list.push((name.to_string(), self.t.elapsed().as_secs_f64()));
        self.t = Instant::now();
    }
}

/// Where the heavy kernels will run, decided before the target projection (which runs
/// on the same device).
pub enum Plan {
    Cpu,
    Wgpu(crate::gpu::Context),
}

/// Picks the backend. `auto` takes a hardware GPU when wgpu finds one; a software adapter
/// (lavapipe, llvmpipe) is slower than the CPU path, so `auto` then uses the CPU.
pub fn choose_backend(choice: BackendChoice) -> Result<(Plan, String)> {
    use crate::gpu::Context;
    match choice {
        BackendChoice::Cpu => Ok((Plan::Cpu, "--backend cpu".into())),
        BackendChoice::Wgpu => Ok((Plan::Wgpu(Context::new()?), "--backend wgpu".into())),
        BackendChoice::Auto => match Context::probe() {
            Ok(info) if !info.software => Ok((Plan::Wgpu(Context::new()?), format!("auto: hardware adapter {}", info.name))),
            Ok(info) => Ok((Plan::Cpu, format!("auto: only a software adapter ({}), the CPU path is faster", info.name))),
            Err(e) => Ok((Plan::Cpu, format!("auto: no wgpu adapter ({e})"))),
        },
    }
}

/// The target projection on the chosen device; the CPU when the textures do not fit the
/// adapter's limits (the note says so).
fn project(plan: &Plan, scene: &crate::scene::Scene) -> Result<(target::Target, TargetStats, String)> {
    if let Plan::Wgpu(ctx) = plan {
        let bytes = crate::gpu::texture_bytes(scene);
        if bytes <= ctx.max_binding() {
            let (sums, samples) = ctx.target_sums(scene)?;
            let (tg, st) = target::gather(scene, &sums, samples);
            return Ok((tg, st, "wgpu".into()));
        }
        let (tg, st) = target::project_cpu(scene);
        return Ok((tg, st, format!("cpu (the textures, {} MB, exceed the adapter's storage binding limit)", bytes >> 20)));
    }
    let (tg, st) = target::project_cpu(scene);
    Ok((tg, st, "cpu".into()))
}

fn bound_of(opts: &Options) -> Option<Bound> {
    let s = opts.subdivide.unwrap_or(match opts.target {
        TargetSpace::Vertex => Subdivide::Lightmap,
        TargetSpace::Luxel => Subdivide::Off,
    });
    match s {
        Subdivide::Off => None,
        Subdivide::Lightmap => Some(Bound::Texels(1.0)),
        Subdivide::Meters(m) => Some(Bound::Meters(m)),
    }
}

/// Reads `opts.input`, subdivides it as `run` would, and writes the mesh to `path` as PLY
/// ([`crate::ply`]); nothing is fitted. Returns the subdivision's statistics.
pub fn write_mesh(opts: &Options, path: &std::path::Path) -> Result<Option<subdivide::Stats>> {
    if q3gltf_convert::output::same_file(path, &opts.input) {
        return Err(Error::Usage(format!("{}: the mesh would overwrite the input", path.display())));
    }
    let mut scene = gltf_in::read(&opts.input)?;
    let stats = bound_of(opts).map(|b| subdivide::subdivide(&mut scene.mesh, &scene.materials, &scene.textures, b, opts.max_vertices));
    crate::ply::write(&scene, path)?;
    Ok(stats)
}

pub fn run(opts: &Options, progress: &dyn Progress) -> Result<Report> {
    let t_all = Instant::now();
    let deadline = opts.time_limit.map(|d| t_all + d);
    let mut st = Stages { t: Instant::now(), list: Vec::new() };
    if q3gltf_convert::output::same_file(&opts.output, &opts.input) {
        return Err(Error::Usage(format!("{}: the output would overwrite the input", opts.output.display())));
    }
    let phases = schemes::phases(&opts.scheme).ok_or_else(|| {
        Error::Usage(format!("unknown scheme {:?}; known: {}", opts.scheme, schemes::NAMES.iter().map(|n| n.0).collect::<Vec<_>>().join(", ")))
    })?;

    progress.stage("read");
    let mut scene = gltf_in::read(&opts.input)?;
    let (vertices_input, triangles_input) = (scene.mesh.positions.len(), scene.mesh.triangles.len());
    st.done("read");

    progress.stage("subdivide");
    let subdivision = bound_of(opts).map(|b| subdivide::subdivide(&mut scene.mesh, &scene.materials, &scene.textures, b, opts.max_vertices));
    st.done("subdivide");

    let (plan, reason) = choose_backend(opts.backend)?;
    st.done("backend");

    progress.stage("target");
    let (lo, hi) = scene.mesh.bounds();
    let diag = (hi - lo).length();
    let (mut pb, tstats, luxel_stats, target_backend) = match opts.target {
        TargetSpace::Vertex => {
            let (tg, tstats, target_backend) = project(&plan, &scene)?;
            (Problem::new(&scene.mesh, &tg, diag), tstats, None, target_backend)
        }
        TargetSpace::Luxel => {
            // The per-vertex projection is still needed for vertex-lit materials' rows.
            let vertex_lit = scene.materials.iter().any(|m| m.lighting == crate::scene::Lighting::Vertex);
            let (tg, tstats, backend) = if vertex_lit { project(&plan, &scene)? } else { (target::Target::empty(scene.mesh.positions.len()), TargetStats::default(), "none needed".into()) };
            let lx = crate::luxel::problem(&scene, &tg, diag);
            (lx.problem, tstats, Some(lx.stats), format!("luxel rows on the cpu; vertex-lit projection: {backend}"))
        }
    };
    st.done("target");
    if pb.is_empty() || pb.weight.iter().all(|w| w.iter().all(|&x| x == 0.0)) {
        return Err(Error::unsupported(&opts.input, "no surface carries baked lighting (no lightmap on TEXCOORD_1, no vertex-lit material): nothing to fit"));
    }

    progress.stage("bvh");
    let bvh = Bvh::build(&scene.mesh);
    st.done("bvh");

    progress.stage("indirect");
    let indirect_gather = (opts.indirect != Optional::Off).then(|| crate::indirect::gather(&scene, &bvh, &mut pb, opts.indirect_rays));
    st.done("indirect");
    let pb = pb;

    let mut backend: Box<dyn Backend + '_> = match plan {
        Plan::Cpu => Box::new(Cpu { pb: &pb, bvh: &bvh }),
        Plan::Wgpu(ctx) => Box::new(crate::gpu::GpuBackend::new(ctx, &pb, &bvh)?),
    };
    let backend_name = backend.name();
    st.done("upload");

    // Starting lights.
    progress.stage("init");
    let input_lights: Vec<(Light, bool, usize)> = scene
        .lights
        .iter()
        .enumerate()
        .map(|(k, l)| {
            let i = l.intensity_cd as f64 / LM_PER_W;
            (Light { pos: l.position, rgb: l.color.map(|c| (c as f64 * i) as f32) }, l.locked, k)
        })
        .collect();
    // The indirect term is part of the model from the start (lights are placed for what it
    // leaves unexplained); `auto` removes it after the optimisation if it does not help.
    let mut globals0 = crate::fit::Globals { indirect: (opts.indirect != Optional::Off).then_some([0.5; 3]), ..Default::default() };
    // The sun: the input's (with --init input), else searched, when the scene could have one.
    let sky: Vec<bool> = scene.mesh.tri_material.iter().map(|&m| scene.materials[m as usize].sky).collect();
    let consider_sun = match opts.sun {
        Optional::Off => false,
        Optional::On => true,
        Optional::Auto => sky.iter().any(|&s| s) || !scene.suns.is_empty(),
    };
    let mut sun_note = if consider_sun { String::new() } else { format!("off ({})", if opts.sun == Optional::Off { "--sun off" } else { "no sky surface, no directional light" }) };
    if consider_sun {
        let input_sun = scene.suns.first().map(|s| crate::model::Sun { to_sun: s.to_sun, rgb: s.color.map(|c| (c as f64 * s.intensity_lux as f64 / LM_PER_W) as f32) });
        globals0.sun = match (&opts.init, input_sun) {
            (Init::Input, Some(s)) => Some(s),
            _ => {
                let sub = pb.subsample(10_000, opts.seed);
                let base: Vec<[f32; 3]> = sub.indirect.iter().map(|o| if globals0.indirect.is_some() { *o } else { [0.0; 3] }).collect();
                let extra: Vec<Vec3> = scene.suns.iter().map(|s| s.to_sun).collect();
                init::sun_search(&sub, &bvh, &sky, &base, &extra, None).map(|(s, _)| s)
            }
        };
        if globals0.sun.is_none() {
            sun_note = "no direction lowers the error".into();
        }
    }
    st.done("sun");
    let mut auto_stats: Option<init::AutoStats> = None;
    let (start, sources): (Vec<(Light, bool)>, Vec<Option<usize>>) = match &opts.init {
        Init::Input => {
            if input_lights.is_empty() {
                return Err(Error::Usage(format!("{}: --init input, but the file has no point lights", opts.input.display())));
            }
            (input_lights.iter().map(|(l, k, _)| (*l, *k)).collect(), input_lights.iter().map(|x| Some(x.2)).collect())
        }
        Init::Grid(n) => {
            let g = init::grid(*n, lo, hi);
            let s = vec![None; g.len()];
            (g.into_iter().map(|l| (l, false)).collect(), s)
        }
        Init::Auto => {
            // Locked input lights stay (the user's decision); the rest is placed anew.
            let keep: Vec<(Light, bool)> = input_lights.iter().filter(|x| x.1).map(|x| (x.0, true)).collect();
            let mut src: Vec<Option<usize>> = input_lights.iter().filter(|x| x.1).map(|x| Some(x.2)).collect();
            let (lights, stats) = init::auto(&scene.mesh, &pb, &bvh, &sky, lo, hi, &keep, globals0, opts.max_lights, 0.001, AUTO_SAMPLE_ROWS, opts.seed, deadline, t_all);
            auto_stats = Some(stats);
            src.resize(lights.len(), None);
            let locked: Vec<bool> = (0..lights.len()).map(|j| j < keep.len()).collect();
            (lights.into_iter().zip(locked).collect(), src)
        }
    };
    st.done("init");

    let mut fit = Fitter::new(&pb, &bvh, backend.as_mut(), lo, hi);
    fit.deadline = deadline;
    // One clock for the whole run: the report's curve shows placement and fit together.
    fit.start = t_all;
    fit.globals = globals0;
    fit.sky = sky.clone();
    let mut sources = sources;
    for (l, locked) in &start {
        fit.add_light(*l, *locked);
    }
    // Keep `sources` aligned with the lights through pruning and merging: tag by position.
    // With --init input the start is the file as it is: its lights and sun, nothing else.
    let rel_error_initial = if matches!(opts.init, Init::Input) {
        fit.globals = crate::fit::Globals { sun: globals0.sun.filter(|_| !scene.suns.is_empty()), ..Default::default() };
        let e = fit.eval().rel_error;
        fit.globals = globals0;
        e
    } else {
        fit.fit_intensities()
    };
    st.done("start");

    fit.on_iter = Some(Box::new(|r: &IterRecord| progress.iteration(r)));
    for (k, mut phase) in phases.into_iter().enumerate() {
        if fit.out_of_time() {
            break;
        }
        if let Some(m) = opts.max_iterations {
            phase.max_iterations = phase.max_iterations.min(m);
        }
        progress.phase(&format!("phase {}", k + 1), phase.max_iterations);
        fit.run_phase(&format!("{} phase {}", opts.scheme, k + 1), phase);
        progress.phase_done();
    }
    st.done("optimise");

    // The indirect term only where it lowers the error; then as few lights as the scene
    // needs; then the ambient term, again only where it lowers the error.
    progress.stage("prune");
    let indirect_note = decide(&mut fit, |g, on| g.indirect = on.then_some([0.5; 3]), opts.indirect);
    if let Some(fitted) = fit.globals.sun {
        sun_note = decide(&mut fit, |g, on| g.sun = on.then_some(fitted), opts.sun);
    }
    let mut pruned = 0;
    let mut merged = 0;
    if !matches!(opts.init, Init::Grid(_)) || opts.scheme == "default" {
        let before: Vec<Vec3> = fit.lights.iter().map(|l| l.pos).collect();
        pruned = fit.prune(0.002);
        merged = fit.merge((0.03 * diag).max(2.0 * fit.min_dist), 0.002);
        // Re-associate input sources by position (pruning and merging removed entries).
        sources = fit.lights.iter().map(|l| before.iter().position(|p| *p == l.pos).and_then(|k| sources.get(k).copied().flatten())).collect();
    }
    let ambient_note = decide(&mut fit, |g, on| g.ambient = on.then_some([1e-6; 3]), Optional::Auto);
    // The sun's direction by search, now that the final lights explain their part (shadow
    // edges move with it; the gradient sees only the cosine); the polish below follows.
    if let Some(s) = fit.globals.sun.filter(|_| !fit.out_of_time()) {
        let sub = pb.subsample(40_000, opts.seed);
        let mut vis = crate::visibility::Visibility::default();
        let others = crate::fit::Globals { sun: None, ..fit.globals };
        let _ = vis.update(&fit.lights, 0.0, sub.len(), &mut |p| Ok(p.iter().map(|&q| crate::visibility::trace_light(&bvh, &sub, q)).collect()));
        let base = crate::model::radiance(&sub, &vis, &fit.lights, others.terms());
        if let Some((better, _)) = init::sun_search(&sub, &bvh, &sky, &base, &[], Some(s.to_sun)) {
            let before = fit.eval().f;
            let saved = (fit.lights.clone(), fit.globals);
            fit.globals.sun = Some(Sun { rgb: s.rgb, ..better });
            fit.fit_intensities();
            if !(fit.eval().f <= before) {
                (fit.lights, fit.globals) = saved;
            }
        }
    }
    if (pruned + merged > 0 || fit.globals != crate::fit::Globals::default()) && !fit.out_of_time() {
        let polish = crate::fit::Phase { algorithm: crate::fit::Algorithm::Lbfgs { step: 0.5 }, params: crate::fit::ParamSet::ALL, max_iterations: opts.max_iterations.unwrap_or(40).min(40) };
        fit.run_phase("polish", polish);
    }
    let final_eval = fit.eval();
    if let Some(e) = fit.failure.take() {
        return Err(e);
    }
    st.done("prune");

    // Energy share of each light (area-weighted model radiance).
    let shares = energy_shares(&pb, &fit);
    let lights: Vec<Light> = fit.lights.clone();
    let locked = fit.locked.clone();
    let names = light_names(&sources.iter().map(|s| s.map(|k| scene.lights[k].name.as_str())).collect::<Vec<_>>(), lights.len());
    let out_lights: Vec<OutLight> = lights
        .iter()
        .enumerate()
        .map(|(j, l)| {
            let src = sources.get(j).copied().flatten().map(|k| &scene.lights[k]);
            // Back to world space; a locked light keeps its input position exactly.
            let position = match src {
                Some(s) if locked[j] => s.world_position,
                _ => scene.origin + l.pos.as_dvec3(),
            };
            OutLight {
                position,
                rgb: l.rgb.map(|c| c as f64),
                source_node: src.map(|s| (s.node, s.parent_world)),
                // An input light keeps its name (the user's); new ones are numbered.
                name: names[j].clone(),
                extras: json!({ "q3_relight": { "energy_share": shares[j], "rel_error": final_eval.rel_error, "scheme": opts.scheme } }),
                locked: locked[j],
            }
        })
        .collect();
    let phases_done = fit.phases.clone();
    // The placement's iterations (on its subsample) first, then the fit's.
    let mut history: Vec<IterRecord> = auto_stats.as_mut().map(|a| std::mem::take(&mut a.history)).unwrap_or_default();
    history.extend(fit.history.iter().cloned());
    let evaluations = fit.evaluations;
    let rays = fit.vis.rays;
    let ambient = fit.globals.ambient;
    let indirect = fit.globals.indirect;
    let fit_sun = fit.globals.sun;
    drop(fit);
    progress.stage("write");
    // With the indirect term, the lights reproduce the data only together with the bounced
    // light that a renderer with global illumination adds: say so for the user.
    let scene_extras = json!({ "rel_error": final_eval.rel_error, "lights": out_lights.len(), "ambient": ambient, "indirect_scale": indirect, "lights_are": if indirect.is_some() { "direct light only: render with global illumination" } else { "direct and bounced light together" } });
    let out_sun = fit_sun.map(|s| lights_out::OutSun {
        to_sun: s.to_sun.as_dvec3(),
        rgb: s.rgb.map(|c| c as f64),
        name: scene.suns.first().map(|s| s.name.clone()).filter(|n| !n.is_empty()).unwrap_or_else(|| "sun".into()),
        extras: json!({ "q3_relight": { "rel_error": final_eval.rel_error, "scheme": opts.scheme } }),
    });
    lights_out::write(&opts.input, &opts.output, &out_lights, out_sun.as_ref(), opts.sun != Optional::Off, scene_extras)?;
    st.done("write");

    let light_reports = out_lights
        .iter()
        .zip(&shares)
        .map(|(l, s)| {
            let m = l.rgb.iter().copied().fold(0.0f64, f64::max);
            LightReport {
                name: l.name.clone(),
                position_m: l.position.to_array(),
                intensity_cd: m * LM_PER_W,
                color: if m > 0.0 { l.rgb.map(|c| c / m) } else { [1.0; 3] },
                range_m: lights_out::range_m(m),
                energy_share: *s,
                locked: l.locked,
            }
        })
        .collect();
    Ok(Report {
        input: opts.input.display().to_string(),
        output: opts.output.display().to_string(),
        backend: backend_name,
        backend_reason: reason,
        target_backend,
        scheme: opts.scheme.clone(),
        init: match &opts.init {
            Init::Auto => "auto".into(),
            Init::Grid(n) => format!("grid:{n}"),
            Init::Input => "input".into(),
        },
        vertices_input,
        triangles_input,
        subdivision,
        target_space: opts.target,
        target: tstats,
        luxel: luxel_stats,
        problem_rows: pb.len(),
        rel_error_initial,
        rel_error_final: final_eval.rel_error,
        lights: light_reports,
        ambient,
        ambient_note,
        indirect,
        indirect_note,
        indirect_gather,
        sun: out_sun.as_ref().map(|s| {
            let m = s.rgb.iter().copied().fold(0.0f64, f64::max);
            let (t, p) = crate::fit::sun_angles(s.to_sun.as_vec3());
            SunReport {
                name: s.name.clone(),
                to_sun: s.to_sun.to_array(),
                elevation_deg: t.to_degrees(),
                azimuth_deg: p.to_degrees(),
                illuminance_lux: m * LM_PER_W,
                color: if m > 0.0 { s.rgb.map(|c| c / m) } else { [1.0; 3] },
            }
        }),
        sun_note,
        pruned,
        merged,
        auto: auto_stats,
        phases: phases_done,
        iterations: history,
        rays_traced: rays,
        evaluations,
        stage_times_s: st.list,
        total_time_s: t_all.elapsed().as_secs_f64(),
        skipped_primitives: scene.skipped,
    })
}

/// Output light names: a light continuing an input light keeps its (non-empty, first
/// seen) name, the user's; the others are `light_NNN`, numbered in order, skipping names
/// already taken. All distinct.
fn light_names(source_names: &[Option<&str>], count: usize) -> Vec<String> {
    let mut used = std::collections::HashSet::new();
    let mut names: Vec<Option<String>> = (0..count)
        .map(|j| source_names.get(j).copied().flatten().filter(|n| !n.is_empty() && used.insert(n.to_string())).map(str::to_string))
        .collect();
    let mut k = 0;
    for n in names.iter_mut().filter(|n| n.is_none()) {
        while used.contains(&format!("light_{k:03}")) {
            k += 1;
        }
        let name = format!("light_{k:03}");
        used.insert(name.clone());
        *n = Some(name);
    }
    names.into_iter().map(|n| n.expect("every light named above")).collect()
}

/// Decides whether a global term stays in the model: with `auto`, when the exact
/// intensity fit with it lowers the relative error by at least [`TERM_GAIN`] against the
/// same fit without it (whether or not the term is in the model on entry). Returns the
/// note for the report.
fn decide(fit: &mut Fitter, set: impl Fn(&mut crate::fit::Globals, bool), choice: Optional) -> String {
    if choice == Optional::Off {
        set(&mut fit.globals, false);
        return "off".into();
    }
    let entry = fit.globals;
    let variant = |on: bool, fit: &mut Fitter| {
        let mut g = entry;
        set(&mut g, on);
        // Keep a fitted value when the term is already in the model.
        if g.ambient.is_some() && entry.ambient.is_some() {
            g.ambient = entry.ambient;
        }
        if g.indirect.is_some() && entry.indirect.is_some() {
            g.indirect = entry.indirect;
        }
        fit.globals = g;
        let e = fit.fit_intensities();
        (e, fit.lights.clone(), fit.vis.clone(), fit.globals)
    };
    let without = variant(false, fit);
    let with = variant(true, fit);
    let (e0, e1) = (without.0, with.0);
    let keep = choice == Optional::On || e1 < e0 - TERM_GAIN;
    let chosen = if keep { with } else { without };
    (_, fit.lights, fit.vis, fit.globals) = chosen;
    match (choice, keep) {
        (Optional::On, _) => format!("on: relative error {e0:.4} without, {e1:.4} with it"),
        (_, true) => format!("kept: relative error {e0:.4} -> {e1:.4}"),
        (_, false) => format!("not used: relative error {e0:.4} -> {e1:.4} with it"),
    }
}

fn energy_shares(pb: &Problem, fit: &Fitter) -> Vec<f64> {
    let mut e = vec![0.0f64; fit.lights.len()];
    for (j, l) in fit.lights.iter().enumerate() {
        for i in 0..pb.len() {
            if !fit.vis.visible(j, i) {
                continue;
            }
            let (g, _) = crate::model::geometry_term(pb.pos[i], pb.normal[i], l.pos, pb.eps);
            e[j] += pb.area[i] as f64 * (0..3).map(|c| pb.albedo[i][c] as f64 * l.rgb[c] as f64).sum::<f64>() * g as f64;
        }
    }
    let total: f64 = e.iter().sum();
    e.iter().map(|v| if total > 0.0 { v / total } else { 0.0 }).collect()
}

#[cfg(test)]
mod tests {
    use super::light_names;

    #[test]
    fn light_names_keep_the_users_and_stay_distinct() {
        let n = light_names(&[Some("lamp"), None, Some("light_001"), Some("lamp"), Some("")], 6);
        assert_eq!(n, ["lamp", "light_000", "light_001", "light_002", "light_003", "light_004"]);
    }
}
