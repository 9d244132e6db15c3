//! The whole relight, as a list of stages: read, subdivide, choose the backend, build the
//! BVH and the rows, read the compile's settings, trace the model's bases, upload, start
//! (the map's own emitters, then the lights: the file's, a grid, or placed), fit the
//! phases, decide which terms the data needs, prune and merge, refine the sun, polish,
//! write the glTF, gather the report.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use glam::Vec3;
use serde::Serialize;
use serde_json::json;

use crate::backend::{Backend, Cpu};
use crate::error::{Error, Result};
use crate::fit::{Fitter, IterRecord, PhaseSummary};
use crate::init;
use crate::io::gltf_in;
use crate::io::lights_out::{self, OutLight, OutSpot, LM_PER_W};
use crate::model::{self, Bases, Light, Model, Sun};
use crate::rows::projection::{self, TargetStats};
use crate::rows::look::{self, Look};
use crate::rows::{luxel, Rows};
use crate::scene::{Lighting, Scene};
use crate::schemes;
use crate::subdivide::{self, Bound};
use crate::trace::bvh::Bvh;

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Subdivide {
    Off,
    /// About one lightmap texel per edge.
    Lightmap,
    /// At most this many meters per edge.
    Meters(f32),
}

/// Where the objective's rows are: see [`crate::rows`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TargetSpace {
    /// One row per lightmap texel, at the point q3map2 baked it for (the default).
    Luxel,
    /// One row per (subdivided) vertex: the thesis's mass-lumped L2 projection.
    Vertex,
}

/// What computes the point lights' light: see [`crate::light_tracing`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase", tag = "kind")]
pub enum Estimator {
    /// Ours: every row's shadow ray to every light under q3map2's rules, and the model's
    /// other terms ([`crate::model`]).
    Model,
    /// The thesis's: `rays` per light and evaluation traced from the lights and splatted
    /// onto the vertices, `bounces` diffuse bounces; point lights only, nothing else in
    /// the model (a baseline for `make bench`).
    Tracing { rays: usize, bounces: usize },
}

#[derive(Debug, Clone, PartialEq)]
pub enum Init {
    /// The greedy placement ([`init::auto`]), then the dense start's candidates beside its
    /// lights ([`AUTO_DENSE_CANDIDATES`] of them, [`init::dense`]), all fitted at once and
    /// pruned: the placement's emitters and strong lights, and hundreds of small lights
    /// to share what it left.
    Auto,
    /// The greedy placement alone ([`init::auto`]).
    Greedy,
    /// The thesis's N x N grid.
    Grid(usize),
    /// The file's lights.
    Input,
    /// Up to N lights over the brightest rows, fitted at once and pruned
    /// ([`init::dense`]): for maps lit by many small sources.
    Dense(usize),
}

/// What the fit may change.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FitMode {
    /// Everything (the default).
    All,
    /// Only the compile's global terms: one scale per kind of emitter per channel (as
    /// q3map2's `-pointscale`, `-skyscale`, `-areascale`), ambient, minlight, bounce scale,
    /// dirt and filter on or off; the lights and the map's emitters otherwise stay as the
    /// file has them (positions, directions, proportions). The truth harness: how well a
    /// map's own sources explain its lightmaps.
    Globals,
}

/// Whether the model has an optional term.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Optional {
    /// As the recorded compile says; else only where it lowers the relative error by at
    /// least [`TERM_GAIN`].
    Auto,
    Off,
    On,
}

/// Rows of the subsample on which `--init auto` places lights (every k-th row).
pub const AUTO_SAMPLE_ROWS: usize = 20_000;
/// Dense candidates `--init auto` adds beside the placement's lights.
pub const AUTO_DENSE_CANDIDATES: usize = init::DENSE_DEFAULT;
/// No dense candidate within this many Quake units of a placed light (the placement
/// already explains its light there).
pub const AUTO_DENSE_CLEARANCE_UNITS: f32 = 32.0;
/// A light whose every channel is at most this fraction of the brightest light's
/// brightest channel is dark: the exact fit keeps its zeros at `1e-6` of its largest
/// coefficient, so that their logarithms stay finite.
pub const DARK_FRACTION: f32 = 1e-5;

/// The least a light must lower the placement's error (relative, on its subsample) to
/// be added. The placement proposes and pruning decides (over all rows it removes the
/// lights whose removal raises the error by less than 0.002, [`crate::fit`]'s `prune`),
/// so it proposes below that: at 0.001 it
/// stopped on maps whose light comes from many small sources, where each further light
/// gained 0.0003-0.001 on the subsample. Measured on 2026-11-27 (fourth session, 2-core
/// machine, default relights) at 0.001 / 0.0003 / 0.0001: oacmpdm1 0.2192 (1 light) /
/// 0.1922 (56) / 0.1947 (54); oacmpdm2 0.1957 (24) / 0.1678 (47) / 0.1563 (61);
/// oacmpdm3 0.2563 (62) / 0.2577 (61) / 0.2577 (61); oacmpdm4 0.1290 (56) / 0.1220 (57)
/// / 0.1220 (57); oacmpctf1 0.0871 (16) / 0.0820 (20) / 0.0790 (34); oa_dm1 0.2763 (59)
/// / 0.2818 (56) / 0.2818 (56), where the placement reaches `--max-lights` either way
/// and only its last lights differ.
pub const PLACEMENT_MIN_GAIN: f64 = 0.0003;

/// An optional term stays in the model with `auto` only when it lowers the relative error
/// by at least this much (absolute).
pub const TERM_GAIN: f64 = 0.005;

/// Passes of bounced light when the compile's `-bounce N` is not recorded.
pub const DEFAULT_BOUNCES: usize = 8;

/// L-BFGS iterations of the polish after pruning and the terms' decisions (measured on
/// oa_dm1: 40 bought 0.001 of error over 20 for 8 s more).
const POLISH_ITERATIONS: usize = 20;

/// Rounds of sun search and polish at the end of a fit with a sun, at most (they stop
/// when the search no longer turns the sun, see [`sun_turned`]).
const SUN_ROUNDS: usize = 4;

/// The smallest turn of the sun's direction, degrees, that counts as a turn for
/// [`SUN_ROUNDS`]: the search returns the same direction to within float rounding (the
/// vectors differ in their last bits) once it has settled, and oacmpdm4 spent two more
/// rounds (3.4 s of 45) on turns of 0.00000 degrees.
const SUN_TURN_MIN_DEG: f32 = 0.01;

/// Whether the sun's direction moved from `before` to `after` (unit vectors) by at least
/// [`SUN_TURN_MIN_DEG`].
fn sun_turned(before: Vec3, after: Vec3) -> bool {
    before.angle_between(after).to_degrees() >= SUN_TURN_MIN_DEG
}

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
    /// The picture the fit reproduces: the baked light or the game's screen.
    pub look: Look,
    /// `None`: `Lightmap` for the vertex target, `Off` for the luxel target.
    pub subdivide: Option<Subdivide>,
    pub max_vertices: usize,
    pub init: Init,
    pub fit: FitMode,
    pub scheme: String,
    pub max_lights: usize,
    /// Caps every phase's iterations.
    pub max_iterations: Option<usize>,
    pub time_limit: Option<Duration>,
    pub backend: BackendChoice,
    pub seed: u64,
    /// Bounced light of the model's own emitters ([`model::bounce`]).
    pub bounce: Optional,
    /// Rays per row for the bounce operator (0: [`model::bounce::rays_for`] the rows).
    pub bounce_rays: usize,
    /// A sun (directional light).
    pub sun: Optional,
    /// The sky light of the map's sky shaders.
    pub sky: Optional,
    /// The map's surface lights (emitting shaders).
    pub surfaces: Optional,
    /// q3map2's `-dirt` and `-filter`.
    pub dirt: Optional,
    pub filter: Optional,
    /// The compile's `-gamma` where the file does not record it ([`crate::rows::gamma`]).
    pub gamma: GammaChoice,
    /// Write every row's data and the final model there as CSV.
    pub dump_rows: Option<PathBuf>,
    pub estimator: Estimator,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            input: PathBuf::new(),
            output: PathBuf::new(),
            target: TargetSpace::Luxel,
            look: Look::Lightmap,
            subdivide: None,
            max_vertices: 1_500_000,
            init: Init::Auto,
            fit: FitMode::All,
            scheme: "default".into(),
            max_lights: 32,
            max_iterations: None,
            time_limit: None,
            backend: BackendChoice::Auto,
            seed: 1,
            bounce: Optional::Auto,
            bounce_rays: 0,
            sun: Optional::Auto,
            sky: Optional::Auto,
            surfaces: Optional::Auto,
            dirt: Optional::Auto,
            filter: Optional::Auto,
            gamma: GammaChoice::Auto,
            dump_rows: None,
            estimator: Estimator::Model,
        }
    }
}

/// What the command line shows while the work goes on. Methods take `&self` so the
/// optimiser's per-iteration callback can hold the display while stages are reported;
/// `Sync` because [`run`] does its work on a thread of rayon's pool, not the caller's.
pub trait Progress: Sync {
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
    pub kind: &'static str,
    pub position_m: [f64; 3],
    pub intensity_cd: f64,
    pub color: [f64; 3],
    /// A spot's unit axis and cone half-angle, degrees.
    pub spot_axis: Option<[f64; 3]>,
    pub spot_angle_deg: Option<f64>,
    pub range_m: f64,
    /// Share of the model's area-weighted radiance that comes from this light.
    pub energy_share: f64,
    pub locked: bool,
}

/// A surface-light group as fitted.
#[derive(Debug, Clone, Serialize)]
pub struct SurfaceReport {
    pub shader: String,
    pub rows_reached: usize,
    pub patches: usize,
    pub area_m2: f64,
    /// Patch surfaces emitting from q3map2's own mesh of them, and those whose recorded
    /// mesh no longer matches the scene (they emit from their triangles).
    pub q3map2_meshes: usize,
    pub meshes_unmatched: usize,
    /// The radiance the shader's own value stands for, and the fitted one, W/(m^2 sr).
    pub source_radiance: [f32; 3],
    pub radiance: Option<[f32; 3]>,
}

/// How the compile's `-gamma` is read where the file does not record it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GammaChoice {
    /// Estimated from the data: the reading whose fit, taken back to the stored bytes,
    /// is lowest (1 unless another lowers the error by [`TERM_GAIN`]).
    Auto,
    /// The stored bytes as they are (gamma 1).
    Off,
    /// This gamma, as if the compile had recorded it.
    Fixed(f32),
}

/// The compile gamma the data was read through, and how it was chosen.
#[derive(Debug, Clone, Serialize)]
pub struct GammaReport {
    /// The gamma the fit read the data through (1: the stored bytes as they are).
    pub gamma: f64,
    /// "recorded", "asked", "estimated" or why it was not.
    pub how: String,
    /// Each gamma tried and its fit's relative error against the stored bytes.
    pub tried: Vec<(f64, f64)>,
    /// The final relative error in the fit's own reading (the phases' and the per
    /// material breakdown's); `rel_error_final` is against the stored bytes.
    pub rel_error_fit_reading: f64,
}

/// One term's decision: whether it stayed, and the error with and without it.
#[derive(Debug, Clone, Serialize)]
pub struct TermReport {
    pub term: String,
    pub kept: bool,
    pub rel_error_without: f64,
    pub rel_error_with: f64,
    pub note: String,
}

/// The residual of one material: where the model does not explain the data.
#[derive(Debug, Clone, Serialize)]
pub struct MaterialResidual {
    pub material: String,
    pub rows: usize,
    /// Share of the total squared residual.
    pub residual_share: f64,
    /// The material's own relative error.
    pub rel_error: f64,
    /// Mean data and model radiance (area-weighted), per channel.
    pub mean_data: [f64; 3],
    pub mean_model: [f64; 3],
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
    pub estimator: Estimator,
    pub init: String,
    pub fit: FitMode,
    pub vertices_input: usize,
    pub triangles_input: usize,
    pub subdivision: Option<subdivide::Stats>,
    pub target_space: TargetSpace,
    pub look: Look,
    pub target: TargetStats,
    pub luxel: Option<luxel::LuxelStats>,
    /// The byte at which the data was clamped, where it is below q3map2's 255 (the
    /// compile's `-compensate`, found in the data: [`crate::scene::find_clamp`]); the
    /// texels there are lower bounds.
    pub data_clamp_byte: Option<u8>,
    pub problem_rows: usize,
    /// The compile's recorded command line, when the map has one.
    pub compile_cmdline: Option<String>,
    /// How the compile's settings were chosen.
    pub compile_note: String,
    /// In the reading the fit starts in: the stored bytes, or through `--gamma G`.
    pub rel_error_initial: f64,
    /// Against the data as stored (the file's own reading of its bytes), whatever gamma
    /// the fit read it through (`gamma`).
    pub rel_error_final: f64,
    /// The phases' last state with every light traced exactly where it stands (the phases
    /// re-trace a light only once it moved `retrace_tol`), before the final exact refit of
    /// the linear coefficients; in the fit's reading of the data. `None` where that step
    /// did not run (out of time, the thesis's estimator).
    pub rel_error_retraced: Option<f64>,
    pub gamma: GammaReport,
    pub lights: Vec<LightReport>,
    pub sun: Option<SunReport>,
    pub sky: Option<[f32; 3]>,
    pub surfaces: Vec<SurfaceReport>,
    pub ambient: Option<[f32; 3]>,
    pub minlight: Option<[f32; 3]>,
    /// Scale of each pass of bounced light, and the passes.
    pub bounce: Option<[f32; 3]>,
    pub bounces: usize,
    /// How the bounce's transport was traced: rows, rays per row, rays that landed on one
    /// of q3map2's bounce lights, and those pieces ([`model::bounce::pieces`]).
    pub bounce_transport: Option<model::bounce::GatherStats>,
    /// q3map2's dirt and its settings, where the model has it.
    pub dirt: Option<model::compile::DirtSettings>,
    pub filter: bool,
    /// The decision on every optional term.
    pub terms: Vec<TermReport>,
    /// Where the residual is, by material (largest first).
    pub residual_by_material: Vec<MaterialResidual>,
    pub pruned: usize,
    pub merged: usize,
    /// With `--init input`: the refit ended worse than the file's own state, which is
    /// what was written (the lights and terms as the file stated them).
    pub kept_input_state: bool,
    pub auto: Option<init::AutoStats>,
    /// With `--init dense` and `auto`: the dense candidates the first fit started from
    /// (with `auto`, beside the placement's lights).
    pub dense_candidates: Option<usize>,
    /// Of the lights the first fit started from (with dense candidates), those it left
    /// dark (every channel at its floor): removed before the phases.
    pub dense_dark: Option<usize>,
    pub phases: Vec<PhaseSummary>,
    pub iterations: Vec<IterRecord>,
    /// Shadow rays traced (`--estimator model`) or light paths started (`tracing`).
    pub rays_traced: u64,
    pub evaluations: usize,
    /// Exact linear refits run (`Fitter::fit_linear`: the terms' decisions, pruning's and
    /// merging's tries, the final state).
    pub linear_fits: usize,
    /// Pruning's single tries decided from a failure it remembered, without a refit
    /// (`Fitter::prune`).
    pub prune_singles_skipped: usize,
    /// Seconds per stage, in order.
    pub stage_times_s: Vec<(String, f64)>,
    pub total_time_s: f64,
    pub skipped_primitives: Vec<String>,
    /// How many of q3map2's pieces the shadow rays test (`trace::pieces`, from the
    /// file's `q3_casters`); `None`: the mesh's own triangles stop them.
    pub shadow_pieces: Option<usize>,
}

struct Stages {
    t: Instant,
    list: Vec<(String, f64)>,
}
impl Stages {
    /// Ends a stage: its time since the last one, added to the entry of the same name
    /// if the stage ran before (a stage that alternates with another keeps one total).
    fn done(&mut self, name: &str) {
        let s = self.t.elapsed().as_secs_f64();
        match self.list.iter_mut().find(|e| e.0 == name) {
            Some(e) => e.1 += s,
            None => self.list.push((name.to_string(), s)),
        }
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
fn project(plan: &Plan, scene: &Scene) -> Result<(projection::Target, TargetStats, String)> {
    if let Plan::Wgpu(ctx) = plan {
        let bytes = crate::gpu::texture_bytes(scene);
        if bytes <= ctx.max_binding() {
            let (sums, samples) = ctx.target_sums(scene)?;
            let (tg, st) = projection::gather(scene, &sums, samples);
            return Ok((tg, st, "wgpu".into()));
        }
        let (tg, st) = projection::project_cpu(scene);
        return Ok((tg, st, format!("cpu (the textures, {} MB, exceed the adapter's storage binding limit)", bytes >> 20)));
    }
    let (tg, st) = projection::project_cpu(scene);
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
/// ([`crate::io::ply`]); nothing is fitted. Returns the subdivision's statistics.
pub fn write_mesh(opts: &Options, path: &std::path::Path) -> Result<Option<subdivide::Stats>> {
    if q3gltf_convert::output::same_file(path, &opts.input) {
        return Err(Error::Usage(format!("{}: the mesh would overwrite the input", path.display())));
    }
    let mut scene = gltf_in::read(&opts.input)?;
    let stats = bound_of(opts).map(|b| subdivide::subdivide(&mut scene.mesh, &scene.materials, &scene.textures, b, opts.max_vertices));
    crate::io::ply::write(&scene, path)?;
    Ok(stats)
}

/// The box lights are searched and kept in: the rows' bounding box grown by 10% of its
/// diagonal on every side, within the mesh's bounds.
fn light_box(mesh: &crate::scene::Mesh, rows: &Rows) -> (glam::Vec3, glam::Vec3) {
    let (mlo, mhi) = mesh.bounds();
    let (rlo, rhi) = rows.pos.iter().fold((glam::Vec3::splat(f32::INFINITY), glam::Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
    if !(rlo.is_finite() && rhi.is_finite()) {
        return (mlo, mhi);
    }
    let pad = 0.1 * (rhi - rlo).length();
    ((rlo - pad).max(mlo), (rhi + pad).min(mhi))
}

/// The luxel rows of `scene` (and the vertex-lit rows of `tg`), buried texels left out.
fn luxel_rows(scene: &Scene, tg: &projection::Target, bvh: &Bvh) -> luxel::Luxels {
    let (lo, hi) = scene.mesh.bounds();
    let mut lx = luxel::rows(scene, tg, (hi - lo).length());
    // The map's own solids when the file carries them, else the faces' guess.
    if !scene.solids.as_ref().is_some_and(|s| luxel::place_in_solids(&mut lx, s)) {
        luxel::nudge_out_of_solid(&mut lx, scene, bvh);
    }
    luxel::drop_buried(&mut lx, scene, bvh);
    lx.stats.on_solid_plane = luxel::mark_solid_ahead(&mut lx.rows, scene, bvh);
    lx
}

/// The rows of the objective and their statistics.
fn build_rows(opts: &Options, plan: &Plan, scene: &Scene, bvh: &Bvh) -> Result<(Rows, TargetStats, Option<luxel::LuxelStats>, String)> {
    let (lo, hi) = scene.mesh.bounds();
    let diag = (hi - lo).length();
    let lit = scene.materials.iter().find(|m| m.lighting != Lighting::None);
    let (ob, per_byte) = lit.map_or((2, 1.0), |m| (m.overbright_bits, m.stored_per_light_byte()));
    let (mut rows, tstats, luxel_stats, backend) = match opts.target {
        TargetSpace::Vertex => {
            let (tg, tstats, target_backend) = project(plan, scene)?;
            (projection::rows(scene, &tg, crate::rows::Sampling::q3map2(diag, scene.units_m, ob, per_byte)), tstats, None, target_backend)
        }
        TargetSpace::Luxel => {
            // The per-vertex projection is still needed for vertex-lit materials' rows.
            let vertex_lit = scene.materials.iter().any(|m| m.lighting == Lighting::Vertex);
            let (tg, tstats, backend) = if vertex_lit { project(plan, scene)? } else { (projection::Target::empty(scene.mesh.positions.len()), TargetStats::default(), "none needed".into()) };
            let lx = luxel_rows(scene, &tg, bvh);
            (lx.rows, tstats, Some(lx.stats), format!("luxel rows on the cpu; vertex-lit projection: {backend}"))
        }
    };
    if opts.look == Look::Game {
        look::to_game_screen(&mut rows);
    }
    Ok((rows, tstats, luxel_stats, backend))
}

/// Which optional terms the model considers, and with which fixed settings.
#[derive(Debug, Clone)]
struct TermPlan {
    sun: Optional,
    sky: Optional,
    surfaces: Optional,
    bounce: Optional,
    bounces: usize,
    dirt: Optional,
    /// The dirt settings the data chooses among (the recorded compile's alone).
    dirt_sets: Vec<model::compile::DirtSettings>,
    filter: Optional,
    /// q3map2's `-fast` for area lights.
    fast_area: bool,
    /// q3map2's `-fast` (or `-fastbounce`) for its bounce lights ([`model::bounce::pieces`]).
    fast_bounce: bool,
}

/// The dirt settings a run considers: the recorded compile's, or else q3map2's scale and
/// gain at each of [`model::compile::DIRT_DEPTHS_UNITS`] (the data chooses the depth),
/// with the settings a relit file states where they are not among those.
fn dirt_sets(scene: &Scene) -> Vec<model::compile::DirtSettings> {
    use model::compile::{DirtSettings, DIRT_DEPTHS_UNITS};
    if scene.compile.cmdline.is_some() {
        return vec![scene.compile.dirt_settings()];
    }
    let mut sets: Vec<DirtSettings> = DIRT_DEPTHS_UNITS.iter().map(|&d| DirtSettings { depth_units: d, ..DirtSettings::Q3MAP2 }).collect();
    if let Some(s) = scene.relit.as_ref().and_then(|r| r.dirt) {
        if !sets.contains(&s) {
            sets.push(s);
        }
    }
    sets
}

/// The dirt settings a model starts with when its dirt is on from the start: q3map2's
/// defaults where they are among `sets`, else the first.
fn first_dirt(sets: &[model::compile::DirtSettings]) -> Option<model::compile::DirtSettings> {
    let d = model::compile::DirtSettings::Q3MAP2;
    sets.iter().copied().find(|s| *s == d).or(sets.first().copied())
}

/// The compile's settings where recorded (`_q3map2_cmdline`), the options otherwise.
fn plan_terms(opts: &Options, scene: &Scene) -> (TermPlan, String) {
    let c = &scene.compile;
    let recorded = c.cmdline.is_some();
    let from_record = |opt: Optional, on: bool| match opt {
        Optional::Auto if recorded => {
            if on {
                Optional::On
            } else {
                Optional::Off
            }
        }
        o => o,
    };
    let bounces = c.switch("-bounce").and_then(|v| v.parse::<usize>().ok()).unwrap_or(DEFAULT_BOUNCES).min(64);
    let sky_surfaces = scene.materials.iter().any(|m| m.sky);
    // A kind of emitter the recorded compile scaled to nothing (`-skyscale 0`,
    // `-areascale 0`) lit nothing in the data.
    let zero = |long: &str, short: &str| [long, short].iter().any(|s| c.switch(s).and_then(|v| v.parse::<f32>().ok()) == Some(0.0));
    let (no_sky, no_area) = (zero("-skyscale", "-sky"), zero("-areascale", "-area"));
    let p = TermPlan {
        sun: if (!sky_surfaces && scene.suns.is_empty() || no_sky) && opts.sun == Optional::Auto { Optional::Off } else { opts.sun },
        sky: if (!scene.materials.iter().any(|m| !m.sky_lights.is_empty()) || no_sky) && opts.sky == Optional::Auto { Optional::Off } else { opts.sky },
        surfaces: if !scene.materials.iter().any(|m| m.emitter.is_some()) || (no_area && opts.surfaces == Optional::Auto) { Optional::Off } else { opts.surfaces },
        bounce: from_record(opts.bounce, c.has("-bounce")),
        bounces,
        // q3map2's switch is `-dirty`; `-dirt`, which many OpenArena maps record, is not one
        // (q3map2 warns "Unknown argument" and lights without dirt).
        dirt: from_record(opts.dirt, c.has("-dirty")),
        dirt_sets: dirt_sets(scene),
        filter: from_record(opts.filter, c.has("-filter")),
        // q3map2's `-faster` switches `-fast` on too.
        fast_area: c.has("-fast") || c.has("-faster"),
        fast_bounce: ["-fast", "-faster", "-fastbounce"].iter().any(|s| c.has(s)),
    };
    let mut note = match &c.cmdline {
        Some(l) => format!("recorded compile: {l}"),
        None => "no recorded compile: dirt, filter and bounce decided by the data".into(),
    };
    let mut p = p;
    if opts.look == Look::Game {
        // The game look is fitted for a renderer to draw: it has no dirt or filter, and its
        // bounces carry the scene's own albedo at scale 1, not a fitted scale. Those terms
        // stay off unless asked for.
        let off = |o: Optional, asked: Optional| if asked == Optional::Auto { Optional::Off } else { o };
        p.dirt = off(p.dirt, opts.dirt);
        p.filter = off(p.filter, opts.filter);
        p.bounce = off(p.bounce, opts.bounce);
        note.push_str("; look game: dirt, filter and bounce off unless asked for (a renderer draws none of them as fitted)");
    }
    (p, note)
}

/// Traces what the model needs of the geometry for the terms `plan` considers; `st`
/// records each one's time.
/// `emitters`: the surface lights' patches, made before any subdivision. `backend`: the
/// run's, which traces the sky's and the surface lights' bases, the dirt's and the
/// bounce's rays where it has kernels for them.
#[allow(clippy::too_many_arguments)]
fn build_bases(scene: &Scene, emitters: (Vec<model::surface::Group>, Vec<model::surface::Patch>), rows: &Rows, bvh: &Bvh, plan: &TermPlan, bounce_rays: usize, with_gathered: bool, backend: &mut dyn Backend, st: &mut Stages) -> Result<Bases> {
    let sky_triangles: Vec<bool> = scene.mesh.tri_material.iter().map(|&m| scene.materials[m as usize].sky).collect();
    let sky = if plan.sky != Optional::Off {
        let it = scene.materials.iter().flat_map(|m| m.sky_lights.iter()).map(|s| s.1).max().unwrap_or(8);
        Some(model::sky::basis_on(backend, rows, bvh, &sky_triangles, &model::sky::directions(it))?)
    } else {
        None
    };
    st.done("bases: sky");
    let surfaces = if plan.surfaces != Optional::Off { surface_basis(backend, emitters, scene, rows, bvh, plan.fast_area)? } else { model::surface::SurfaceBasis { offsets: vec![0; rows.len() + 1], ..Default::default() } };
    st.done("bases: surfaces");
    let luxels = rows.texel.iter().any(|t| t[0] != u32::MAX);
    let nb = if luxels && (plan.dirt != Optional::Off || plan.filter != Optional::Off) { model::compile::neighbours(rows) } else { vec![Vec::new(); rows.len()] };
    let dirt = if plan.dirt != Optional::Off { model::compile::dirt(rows, bvh, &nb, &plan.dirt_sets, scene.units_m as f32, backend)? } else { Vec::new() };
    let filter = (plan.filter != Optional::Off && luxels).then(|| model::compile::filter(rows, &nb));
    st.done("bases: dirt, filter");
    let bounce_rays = if bounce_rays == 0 { model::bounce::rays_for(rows.len()) } else { bounce_rays };
    let (bounce, bounce_stats) = match plan.bounce {
        Optional::Off => (None, None),
        _ => {
            let (t, s) = model::bounce::operator(scene, rows, bvh, bounce_rays, plan.fast_bounce, backend)?;
            (Some(t), Some(s))
        }
    };
    st.done("bases: bounce");
    let bounce_reflectance = if bounce.is_some() { model::bounce::reflectance(rows) } else { Vec::new() };
    let gathered = bounce.as_ref().filter(|_| with_gathered).map(|t| crate::gather::through(rows, t, &bounce_reflectance));
    st.done("bases: gathered");
    Ok(Bases { sky, surfaces, dirt, filter, bounce, bounce_reflectance, bounce_stats, bounces: plan.bounces, gathered, sky_triangles, held: None })
}

/// The surface lights' basis on `backend` where it has a kernel for it, else the CPU's.
fn surface_basis(backend: &mut dyn Backend, emitters: (Vec<model::surface::Group>, Vec<model::surface::Patch>), scene: &Scene, rows: &Rows, bvh: &Bvh, fast: bool) -> Result<model::surface::SurfaceBasis> {
    let bytes_per_ff = model::surface::bytes_per_form_factor(scene, &emitters.0, &emitters.1);
    let request = model::surface::Request { patches: &emitters.1, bytes_per_ff: &bytes_per_ff, groups: emitters.0.len(), units_m: scene.units_m, fast };
    match backend.surface_sums(&request) {
        Some(sums) => {
            let sums = sums?;
            Ok(model::surface::basis_from_sums(emitters, &sums, rows.len()))
        }
        None => Ok(model::surface::basis_from(emitters, scene, rows, bvh, fast)),
    }
}

/// The map's own emitters as the file declares them: the sun (from its directional
/// light), the sky light and the surface lights (from the shaders' values), the
/// worldspawn's minlight and ambient.
fn declared_model(scene: &Scene, bases: &Bases, plan: &TermPlan) -> Model {
    let e_per_byte = q3gltf_convert::units::e_per_byte(scene.materials.iter().find(|m| m.lighting != Lighting::None).map_or(2, |m| m.overbright_bits)) as f32;
    let e_irr = std::f32::consts::PI * e_per_byte;
    let sun = (plan.sun != Optional::Off).then(|| scene.suns.first().map(|s| Sun { to_sun: s.to_sun, rgb: s.color.map(|c| c * s.intensity_lux / LM_PER_W as f32) })).flatten();
    let sky = bases.sky.as_ref().map(|_| {
        let (v, c) = scene.materials.iter().flat_map(|m| m.sky_lights.iter()).map(|s| (s.0, s.2)).fold((0.0f32, [1.0f32; 3]), |a, b| if b.0 > a.0 { b } else { a });
        c.map(|k| k * v * e_irr)
    });
    let surfaces = bases.surfaces.groups.iter().map(|g| Some(g.source_rgb)).collect();
    let minlight = scene.compile.minlight.map(|m| m.map(|v| v * e_irr));
    let ambient = scene.compile.ambient.map(|a| a.map(|v| v * e_irr));
    Model { lights: Vec::new(), sun, sky: sky.filter(|k| k[0] > 0.0), surfaces, ambient, bounce: None, minlight, gathered: None, dirt: None, filter: false }
}

/// The model's lightmap of a scene: one luxel row per lightmap texel, as relight fits
/// them, and the model's radiance and irradiance at each. The lightmap byte q3map2 would
/// store for a row is `x / albedo` in the units of [`crate::scene::Material::decode`].
/// Used to make synthetic ground truth and to bake ([`crate::bake`]).
pub struct Rendered {
    pub rows: Rows,
    /// Radiance toward the viewer, W/(m^2 sr) per channel: `albedo E / pi`.
    pub radiance: Vec<[f64; 3]>,
    /// Irradiance `E`, W/m^2 per channel: every term, dirt, filter and bounces included,
    /// floored at the minlight (the lightmap's `e` is `E / pi`).
    pub irradiance: Vec<[f64; 3]>,
    /// The backend that traced and lit it ([`Backend::name`]).
    pub backend: String,
}

/// Renders `model` (its lights, sun, sky, surfaces, ambient, minlight, dirt, filter and
/// `bounces` passes of bounced light traced with `bounce_rays` rays per row, 0: as
/// relight chooses) on the luxel
/// rows of `scene`, on the CPU.
pub fn render(scene: &Scene, model: &Model, bounces: usize, bounce_rays: usize) -> Result<Rendered> {
    render_on(scene, model, bounces, bounce_rays, BackendChoice::Cpu)
}

/// [`render`] with the shadow rays, the point and spot lights and the surface lights' basis
/// on the chosen backend (the rest of the model runs on the CPU in f64 either way).
pub fn render_on(scene: &Scene, model: &Model, bounces: usize, bounce_rays: usize, choice: BackendChoice) -> Result<Rendered> {
    let bvh = Bvh::occluders(scene);
    let rows = luxel_rows(scene, &projection::Target::empty(scene.mesh.positions.len()), &bvh).rows;
    let plan = TermPlan {
        sun: if model.sun.is_some() { Optional::On } else { Optional::Off },
        sky: if model.sky.is_some() { Optional::On } else { Optional::Off },
        surfaces: if model.surfaces.iter().any(Option::is_some) { Optional::On } else { Optional::Off },
        bounce: if model.bounce.is_some() && bounces > 0 { Optional::On } else { Optional::Off },
        bounces,
        dirt: if model.dirt.is_some() { Optional::On } else { Optional::Off },
        dirt_sets: model.dirt.into_iter().collect(),
        filter: if model.filter { Optional::On } else { Optional::Off },
        fast_area: false,
        fast_bounce: false,
    };
    let mut st = Stages { t: Instant::now(), list: Vec::new() };
    let (device, _) = choose_backend(choice)?;
    let mut backend: Box<dyn Backend + '_> = match device {
        Plan::Cpu => Box::new(Cpu::new(&rows, &bvh)),
        Plan::Wgpu(ctx) => Box::new(crate::gpu::GpuBackend::new(ctx, &rows, &bvh)?),
    };
    let bases = build_bases(scene, model::surface::patches(scene), &rows, &bvh, &plan, bounce_rays, false, backend.as_mut(), &mut st)?;
    let mut vis = crate::trace::visibility::Visibility::default();
    vis.update_sun(model.sun.map(|s| s.to_sun), 0.0, rows.len(), &mut |d| Ok(crate::backend::sun_bits(backend.as_mut(), &bvh, &rows, &[d], &bases.sky_triangles)?.into_iter().next().unwrap_or_default()))?;
    vis.update(&model::lights::sources(&model.lights), 0.0, &rows.sampling, rows.len(), &mut |p| backend.trace(p))?;
    let e = if model.lights.is_empty() { Vec::new() } else { backend.irradiance(&vis, &model.lights)? };
    let fw = model::forward(model, &rows, &bases, &vis, &e);
    let irradiance = fw.total.iter().map(|t| [0, 1, 2].map(|c| model.floored(t[c], c))).collect();
    let name = backend.name();
    drop(backend);
    Ok(Rendered { rows, radiance: fw.x, irradiance, backend: name })
}

/// Removes the free lights the exact fit left dark ([`DARK_FRACTION`] of the brightest
/// light) and their entries in `sources`; returns how many. The emitters stay as they
/// are, and so does the brightest light (unless every light is black, when none goes).
fn drop_dark(fit: &mut Fitter, sources: &mut Vec<Option<usize>>) -> usize {
    let top = fit.model.lights.iter().flat_map(|l| l.rgb).fold(0.0f32, f32::max);
    if !(top > 0.0) {
        return 0;
    }
    let dark: Vec<usize> = (0..fit.model.lights.len()).filter(|&j| !fit.locked[j] && fit.model.lights[j].rgb.iter().all(|&c| c <= DARK_FRACTION * top)).collect();
    for &j in dark.iter().rev() {
        fit.remove_light(j);
        if j < sources.len() {
            sources.remove(j);
        }
    }
    dark.len()
}

/// Relights `opts.input` into `opts.output` (see the crate docs), on a thread of rayon's
/// pool: the caller's thread waits. A parallel loop started outside the pool is handed to
/// it as a job and its caller sleeps until the job ends, a hand-off and two wake-ups per
/// loop; started on a worker, the loop splits by work stealing and the worker takes a
/// share. A relight runs tens of thousands of short loops (every evaluation of the
/// objective is several), so the hand-offs were about 3% of oa_dm1's default run on two
/// cores (docs/speed.md). The result is the same to the bit: every parallel sum in the
/// crate is ordered by blocks of rows, not by threads.
pub fn run(opts: &Options, progress: &dyn Progress) -> Result<Report> {
    rayon::scope(|_| run_on_worker(opts, progress))
}

fn run_on_worker(opts: &Options, progress: &dyn Progress) -> Result<Report> {
    let t_all = Instant::now();
    let deadline = opts.time_limit.map(|d| t_all + d);
    let mut st = Stages { t: Instant::now(), list: Vec::new() };
    if q3gltf_convert::output::same_file(&opts.output, &opts.input) {
        return Err(Error::Usage(format!("{}: the output would overwrite the input", opts.output.display())));
    }
    let phases = schemes::phases(&opts.scheme).ok_or_else(|| {
        Error::Usage(format!("unknown scheme {:?}; known: {}", opts.scheme, schemes::NAMES.iter().map(|n| n.0).collect::<Vec<_>>().join(", ")))
    })?;
    let tracing = match opts.estimator {
        Estimator::Tracing { rays, bounces } => {
            if opts.target != TargetSpace::Vertex {
                return Err(Error::Usage("--estimator tracing splats onto the vertices: it needs --target vertex".into()));
            }
            if matches!(opts.init, Init::Auto | Init::Greedy | Init::Dense(_)) {
                return Err(Error::Usage("--estimator tracing starts as the thesis did, from --init grid:N (or the file's lights, --init input)".into()));
            }
            Some((rays, bounces))
        }
        Estimator::Model => None,
    };
    if matches!(opts.init, Init::Dense(_)) && opts.fit == FitMode::Globals {
        return Err(Error::Usage("--init dense places lights to be fitted; --fit globals keeps the file's lights as they are (use --init input)".into()));
    }

    progress.stage("read");
    let mut scene = gltf_in::read(&opts.input)?;
    let (vertices_input, triangles_input) = (scene.mesh.positions.len(), scene.mesh.triangles.len());
    st.done("read");

    progress.stage("subdivide");
    // The surface lights are the map's own surfaces, cut as q3map2 cut them, whatever
    // the subdivision does to the mesh.
    let emitters = model::surface::patches(&scene);
    let subdivision = bound_of(opts).map(|b| subdivide::subdivide(&mut scene.mesh, &scene.materials, &scene.textures, b, opts.max_vertices));
    st.done("subdivide");

    let (plan, reason) = choose_backend(opts.backend)?;
    st.done("backend");

    progress.stage("bvh");
    let bvh = Bvh::occluders(&scene);
    let shadow_pieces = bvh.shadow.as_ref().map(|s| s.tree.tris.len());
    st.done("bvh");

    progress.stage("rows");
    let (stored_rows, tstats, luxel_stats, target_backend) = build_rows(opts, &plan, &scene, &bvh)?;
    // The compile's gamma: asked for, the rows read through it from the start (the
    // placement too); estimated at the end where the lights' places are given.
    let e_full = scene.materials.iter().find(|m| m.lighting != Lighting::None).map_or(4.0, |m| m.decode_exact(1.0) as f64);
    let gamma_plan = plan_gamma(opts, &scene, &stored_rows, tracing.is_some());
    let read_through = match gamma_plan {
        GammaPlan::Asked(g) => Some(crate::rows::gamma::regraded(&stored_rows, g, e_full)),
        _ => None,
    };
    let rows: &Rows = read_through.as_ref().unwrap_or(&stored_rows);
    st.done("rows");
    if rows.is_empty() || !rows.has_data() {
        return Err(Error::unsupported(&opts.input, "no surface carries baked lighting (no lightmap on TEXCOORD_1, no vertex-lit material): nothing to fit"));
    }
    let diag = {
        let (lo, hi) = scene.mesh.bounds();
        (hi - lo).length()
    };
    // Where lights may go: around the surfaces that carry data, within the geometry (a
    // huge ground plane far below the map must not spread the search over kilometres).
    let (lo, hi) = light_box(&scene.mesh, &rows);

    progress.stage("bases");
    let (mut terms, mut compile_note) = plan_terms(opts, &scene);
    if tracing.is_some() {
        // The thesis's model: point lights and their traced bounces, nothing else.
        terms = TermPlan { sun: Optional::Off, sky: Optional::Off, surfaces: Optional::Off, bounce: Optional::Off, bounces: 0, dirt: Optional::Off, dirt_sets: Vec::new(), filter: Optional::Off, fast_area: false, fast_bounce: false };
        compile_note = "--estimator tracing: point lights and their traced bounces only (the thesis's model)".into();
    }
    let mut backend: Box<dyn Backend + '_> = match (plan, tracing) {
        (Plan::Cpu, None) => Box::new(Cpu::new(&rows, &bvh)),
        (Plan::Wgpu(ctx), None) => Box::new(crate::gpu::GpuBackend::new(ctx, &rows, &bvh)?),
        (Plan::Cpu, Some((n, b))) => Box::new(crate::light_tracing::Tracing::new(&scene.mesh, &rows, &bvh, n, b, opts.seed)?),
        (Plan::Wgpu(ctx), Some((n, b))) => Box::new(crate::gpu::TracingGpu::new(ctx, &scene.mesh, &rows, &bvh, n, b, opts.seed)?),
    };
    let backend_name = backend.name();
    st.done("upload");
    let bases = build_bases(&scene, emitters, &rows, &bvh, &terms, opts.bounce_rays, matches!(opts.init, Init::Auto | Init::Greedy), backend.as_mut(), &mut st)?;

    // The map's own emitters, then the switches the recorded compile fixes.
    progress.stage("init");
    let mut start = if tracing.is_some() { Model::default() } else { declared_model(&scene, &bases, &terms) };
    start.dirt = if terms.dirt == Optional::On { first_dirt(&terms.dirt_sets) } else { None };
    start.filter = terms.filter == Optional::On;
    if terms.bounce != Optional::Off && bases.bounce.is_some() {
        start.bounce = Some([1.0; 3]);
    }
    // A file relight wrote, started from its lights: the rest of the model as it states it.
    if matches!(opts.init, Init::Input) && tracing.is_none() {
        if let Some(m) = model::stated::resumed(&start, &scene, &bases) {
            start = m;
        }
    }
    let input_lights: Vec<(Light, bool, usize)> = scene
        .lights
        .iter()
        .enumerate()
        .map(|(k, l)| (Light::from_input(l), l.locked || opts.fit == FitMode::Globals, k))
        .collect();
    // Without a declared sun: searched where sky surfaces could let one in.
    if terms.sun != Optional::Off && start.sun.is_none() && opts.fit == FitMode::All {
        let (sub, take) = rows.subsample(10_000, opts.seed);
        let sub_bases = bases.subset(&take);
        let base_model = Model { lights: Vec::new(), sun: None, gathered: sub_bases.gathered.as_ref().map(|_| [0.5; 3]), ..start.clone() };
        let vis = crate::trace::visibility::Visibility::default();
        let base = model::radiance(&base_model, &sub, &sub_bases, &vis, &mut Cpu::new(&sub, &bvh))?;
        let extra: Vec<Vec3> = scene.suns.iter().map(|s| s.to_sun).collect();
        let sky = &bases.sky_triangles;
        start.sun = init::sun_search(&sub, &base, &extra, None, &mut |dirs| crate::backend::sun_bits(backend.as_mut(), &bvh, &sub, dirs, sky))?.map(|(s, _)| s);
    }
    st.done("sun");
    let mut auto_stats: Option<init::AutoStats> = None;
    let mut dense_candidates: Option<usize> = None;
    let (lights, locked, sources): (Vec<Light>, Vec<bool>, Vec<Option<usize>>) = match &opts.init {
        Init::Input => {
            if input_lights.is_empty() && opts.fit == FitMode::All && start == Model::default() {
                return Err(Error::Usage(format!("{}: --init input, but the file has no point or spot lights", opts.input.display())));
            }
            (input_lights.iter().map(|x| x.0).collect(), input_lights.iter().map(|x| x.1).collect(), input_lights.iter().map(|x| Some(x.2)).collect())
        }
        Init::Grid(n) => {
            let g = init::grid(*n, lo, hi);
            let k = g.len();
            (g, vec![false; k], vec![None; k])
        }
        Init::Dense(n) => {
            // Locked input lights stay; the candidates join them.
            let keep: Vec<&(Light, bool, usize)> = input_lights.iter().filter(|x| x.1).collect();
            let cands = init::dense(&scene.mesh, rows, &bvh, *n, scene.units_m, crate::fit::min_dist(lo, hi), (hi - lo).length());
            dense_candidates = Some(cands.len());
            let mut lights: Vec<Light> = keep.iter().map(|x| x.0).collect();
            let mut locked = vec![true; lights.len()];
            let mut src: Vec<Option<usize>> = keep.iter().map(|x| Some(x.2)).collect();
            locked.resize(lights.len() + cands.len(), false);
            src.resize(lights.len() + cands.len(), None);
            lights.extend(cands);
            (lights, locked, src)
        }
        Init::Auto | Init::Greedy => {
            // Locked input lights stay (the user's decision); the rest is placed anew.
            let keep: Vec<&(Light, bool, usize)> = input_lights.iter().filter(|x| x.1).collect();
            let with = Model { lights: keep.iter().map(|x| x.0).collect(), gathered: bases.gathered.as_ref().map(|_| [0.5; 3]), bounce: None, filter: false, ..start.clone() };
            let (placed, stats) = init::auto(&scene.mesh, &rows, &bases, &bvh, lo, hi, &with, &vec![true; keep.len()], opts.max_lights, PLACEMENT_MIN_GAIN, AUTO_SAMPLE_ROWS, opts.seed, deadline, t_all);
            auto_stats = Some(stats);
            st.done("init: placement");
            // The placement's fit of the declared emitters is a better start than their
            // declared values.
            start.sun = placed.sun.or(start.sun);
            start.sky = placed.sky.or(start.sky);
            start.surfaces = placed.surfaces.clone();
            start.ambient = placed.ambient.or(start.ambient);
            let mut lights = placed.lights;
            if opts.init == Init::Auto {
                // The dense start's candidates, but where the placement put a light.
                let cands = init::dense(&scene.mesh, rows, &bvh, AUTO_DENSE_CANDIDATES, scene.units_m, crate::fit::min_dist(lo, hi), (hi - lo).length());
                let near = AUTO_DENSE_CLEARANCE_UNITS * scene.units_m;
                let placed_at: Vec<Vec3> = lights.iter().map(|l| l.pos).collect();
                let fresh: Vec<Light> = cands.into_iter().filter(|c| placed_at.iter().all(|p| (*p - c.pos).length() > near)).collect();
                dense_candidates = Some(fresh.len());
                lights.extend(fresh);
            }
            let n = lights.len();
            let mut src: Vec<Option<usize>> = keep.iter().map(|x| Some(x.2)).collect();
            src.resize(n, None);
            (lights, (0..n).map(|j| j < keep.len()).collect(), src)
        }
    };
    st.done("init");

    // The rows read through an estimated compile gamma, if one is adopted (they must
    // outlive the fitter that reads them).
    let regraded = std::cell::OnceCell::new();
    let mut fit = Fitter::new(&rows, &bases, &bvh, backend.as_mut(), lo, hi);
    fit.deadline = deadline;
    // One clock for the whole run: the report's curve shows placement and fit together.
    fit.start = t_all;
    fit.model = Model { lights: Vec::new(), ..start };
    fit.frozen_emitters = opts.fit == FitMode::Globals;
    fit.kind_scales = opts.fit == FitMode::Globals;
    fit.frozen_minlight = scene.compile.minlight.is_some();
    // The dense start alone keeps the one local solve: with the chain's rounds its
    // synthetic ground truth ended at 0.028 with 8 lights instead of 0.0082 with 5 (the
    // path through the terms' decisions and pruning moved; oacmpdm2 0.0512 against 0.0514).
    if matches!(opts.init, Init::Dense(_)) {
        fit.chain_rounds = 1;
    }
    let mut sources = sources;
    for (l, k) in lights.iter().zip(&locked) {
        fit.add_light(*l, *k);
    }
    // With --init input the start is the file as it is; otherwise the linear fit first.
    // The thesis's estimator starts from its grid as it is (dim white lights).
    let mut rel_error_initial = if matches!(opts.init, Init::Input) || tracing.is_some() { fit.eval().rel_error } else { fit.fit_linear() };
    // The placement fits without the bounce (it is not on its subsample); an undecided
    // bounce joins the phases only where the exact fit of the placed lights says it
    // lowers the error (decide_terms asks again at the end). Started on, it cannot go
    // below its smallest factor: on the sample it took the placed lights from 0.020 to
    // 0.136, and the first phase spent its 50 iterations coming back.
    if matches!(opts.init, Init::Auto | Init::Greedy) && terms.bounce == Optional::Auto && fit.model.bounce.is_some() && tracing.is_none() {
        let with = (fit.model.clone(), fit.vis.clone(), rel_error_initial);
        fit.model.bounce = None;
        let without = fit.fit_linear();
        if !(without < with.2) {
            (fit.model, fit.vis, rel_error_initial) = with;
        } else {
            rel_error_initial = without;
        }
    }
    // Beside the placement's lights, the candidates the first fit left dark take no part
    // in what follows: the phases would carry them, and pruning would try each. (The dense
    // start alone keeps them, as measured before: dropping them there was only measured
    // together with the chain's rounds, which it does without.)
    let dense_dark = (opts.init == Init::Auto && dense_candidates.is_some()).then(|| drop_dark(&mut fit, &mut sources));
    // The Blender loop's re-run starts from the file's own state: it must not end worse.
    let entry = (matches!(opts.init, Init::Input) && tracing.is_none()).then(|| (fit.model.clone(), fit.locked.clone(), sources.clone(), rel_error_initial));
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

    // Every optional term only where it lowers the error; then as few lights as the data
    // needs.
    progress.stage("prune");
    let mut term_reports = Vec::new();
    // The thesis's method ends with its phases: no terms, pruning, polish or exact refit
    // (those run on our model).
    if tracing.is_none() {
        decide_terms(&mut fit, &terms, opts, TERM_GAIN, &mut term_reports);
    }
    st.done("prune: terms");
    let mut pruned = 0;
    let mut merged = 0;
    let may_prune = opts.fit == FitMode::All && (!matches!(opts.init, Init::Grid(_)) || opts.scheme == "default") && tracing.is_none();
    // Re-associates input sources by position, after pruning and merging removed entries.
    let reassociate = |lights: &[Light], before: &[Vec3], sources: &[Option<usize>]| -> Vec<Option<usize>> { lights.iter().map(|l| before.iter().position(|p| *p == l.pos).and_then(|k| sources.get(k).copied().flatten())).collect() };
    if may_prune {
        let before: Vec<Vec3> = fit.model.lights.iter().map(|l| l.pos).collect();
        pruned = fit.prune(0.002);
        st.done("prune: lights");
        merged = fit.merge((0.03 * diag).max(2.0 * fit.min_dist), 0.002);
        st.done("prune: merge");
        sources = reassociate(&fit.model.lights, &before, &sources);
    }
    // The sun's direction by search, now that the rest explains its part, and the rest
    // polished for it; again while the search turns it (the lights had bent to the
    // previous direction).
    let polish = crate::fit::Phase { algorithm: crate::fit::Algorithm::Lbfgs { step: 0.5 }, params: crate::fit::ParamSet::ALL, max_iterations: opts.max_iterations.unwrap_or(POLISH_ITERATIONS).min(POLISH_ITERATIONS) };
    let sun_rounds = if fit.model.sun.is_some() && opts.fit == FitMode::All { SUN_ROUNDS } else { 0 };
    for round in 0..sun_rounds {
        if let Some(s) = fit.model.sun.filter(|_| !fit.out_of_time()) {
            refine_sun(&mut fit, s, opts.seed);
            st.done("prune: sun search");
            let turned = fit.model.sun.is_some_and(|n| sun_turned(s.to_sun, n.to_sun));
            if round > 0 && !turned {
                break;
            }
            fit.run_phase("polish", polish);
            st.done("prune: polish");
        }
    }
    if sun_rounds == 0 && (pruned + merged > 0 || !term_reports.is_empty()) && !fit.out_of_time() {
        fit.run_phase("polish", polish);
        st.done("prune: polish");
    }
    // Lights placed while the sun still shone from the placement's coarse direction may have
    // drawn its patches' edges (the placement's low candidates stand a few decimetres over
    // a floor); once the search has turned the sun, they explain nothing: pruned again. So
    // are the dense start's helpers: small lights that made up for the larger ones' places
    // until the polish put those where they belong.
    if (sun_rounds > 0 || dense_candidates.is_some()) && may_prune && !fit.out_of_time() {
        let before: Vec<Vec3> = fit.model.lights.iter().map(|l| l.pos).collect();
        let again = fit.prune(0.002);
        st.done("prune: lights again");
        if again > 0 {
            pruned += again;
            sources = reassociate(&fit.model.lights, &before, &sources);
            fit.run_phase("polish", polish);
            st.done("prune: polish");
        }
    }
    // The final state exactly: the fit re-traces a light only once it has moved more than
    // `retrace_tol` (5 cm on oa_dm1), which leaves shadow edges up to that far off; trace
    // every light where it is and refit the linear coefficients for it.
    // The exact linear fit holds censored channels only through an active set of their
    // bounds, so where most of the data is censored it can be worse than what the phases
    // reached: then the traced state is kept
    // with the phases' coefficients (a step never ends worse than it began).
    let mut rel_error_retraced = None;
    if !fit.out_of_time() && tracing.is_none() {
        fit.retrace_tol = 0.0;
        let kept = fit.model.clone();
        fit.refresh_visibility();
        let entry = fit.eval();
        let before = entry.f;
        rel_error_retraced = Some(entry.rel_error);
        fit.fit_linear();
        if !(fit.eval().f <= before) {
            fit.model = kept;
        }
    }
    // With `--init input`, a refit that ends worse than the file's own state (pruning
    // trades a little error for a light, the terms' decisions and polish are each
    // guarded only against their own entry) gives the file's state back.
    let mut kept_input_state = false;
    if let Some((model, locked, entry_sources, e0)) = entry {
        if fit.failure.is_none() && !(fit.eval().rel_error <= e0) {
            fit.model = model;
            fit.locked = locked;
            sources = entry_sources;
            fit.vis = crate::trace::visibility::Visibility::default();
            fit.retrace_tol = 0.0;
            fit.refresh_visibility();
            kept_input_state = true;
        }
    }
    // The compile's gamma, where the file does not record it.
    let (mut gamma_report, gamma_terms) = estimate_gamma(&mut fit, &regraded, &gamma_plan, &terms, opts, polish, e_full);
    if let Some(t) = gamma_terms {
        term_reports = t;
    }
    st.done("gamma");
    let final_eval = fit.eval();
    if let Some(e) = fit.failure.take() {
        return Err(e);
    }
    // The headline error is against the stored bytes, whatever reading the fit used.
    gamma_report.rel_error_fit_reading = final_eval.rel_error;
    let rel_error_final = if gamma_report.gamma == 1.0 {
        final_eval.rel_error
    } else {
        let m = fit.model.clone();
        let x = model::radiance(&m, fit.rows, &bases, &fit.vis, &mut *fit.backend)?;
        stored_rows.rel_error(&crate::rows::gamma::to_stored(&stored_rows, &x, gamma_report.gamma, e_full))
    };
    st.done("prune: final");
    // What follows describes the fit: in its own reading of the data.
    let rows = fit.rows;

    let shares = if tracing.is_some() { traced_energy_shares(rows, &mut fit)? } else { energy_shares(rows, &fit) };
    let residual_by_material = residual_by_material(&scene, rows, &bases, &mut fit)?;
    if let Some(path) = &opts.dump_rows {
        dump_rows(path, &scene, rows, &bases, &mut fit)?;
    }
    let m = fit.model.clone();
    let locked = fit.locked.clone();
    let names = light_names(&sources.iter().map(|s| s.map(|k| scene.lights[k].name.as_str())).collect::<Vec<_>>(), m.lights.len());
    let out_lights: Vec<OutLight> = m
        .lights
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
                spot: l.spot.map(|s| OutSpot { axis: s.axis.as_dvec3(), radius_by_dist: s.radius_by_dist as f64, ramp_m: rows.sampling.spot_ramp as f64, typical_distance_m: spot_distance(&bvh, l) }),
                source_node: src.map(|s| (s.node, s.parent_world)),
                name: names[j].clone(),
                extras: json!({ "q3_relight": { "energy_share": shares[j], "rel_error": rel_error_final, "scheme": opts.scheme } }),
                locked: locked[j],
            }
        })
        .collect();
    let phases_done = fit.phases.clone();
    // The placement's iterations (on its subsample) first, then the fit's.
    let mut history: Vec<IterRecord> = auto_stats.as_mut().map(|a| std::mem::take(&mut a.history)).unwrap_or_default();
    history.iter_mut().for_each(|r| r.placement = true);
    history.extend(fit.history.iter().cloned());
    let evaluations = fit.evaluations;
    let (linear_fits, prune_singles_skipped) = (fit.linear_fits, fit.singles_skipped);
    let rays = fit.backend.rays_traced().unwrap_or(fit.vis.rays);
    drop(fit);
    progress.stage("write");
    // Emission: each surface group's fitted radiance on its materials; the sky light as
    // the sky materials' uniform radiance. A group or sky the fit switched off is written
    // dark: the file states the light the fit used, no more (a renderer would add the
    // source's emission to lights that already explain it, and a re-run would start
    // from it).
    let mut emissive: Vec<(usize, [f64; 3])> = Vec::new();
    for (g, l) in bases.surfaces.groups.iter().zip(&m.surfaces) {
        let radiance = l.unwrap_or([0.0; 3]).map(|v| v as f64);
        emissive.extend(g.materials.iter().map(|&mi| (mi as usize, radiance)));
    }
    if let Some(b) = &bases.sky {
        let radiance = m.sky.map_or([0.0; 3], |k| k.map(|v| (v * b.mean_cos_up) as f64 / std::f64::consts::PI));
        for (mi, mat) in scene.materials.iter().enumerate() {
            if mat.sky && !emissive.iter().any(|e| e.0 == mi) {
                emissive.push((mi, radiance));
            }
        }
    }
    let scene_extras = json!({
        "rel_error": rel_error_final,
        "lights": out_lights.len(),
        "ambient": m.ambient,
        "minlight": m.minlight,
        "bounce_scale": m.bounce,
        "bounces": bases.bounces,
        "dirt": m.dirt.is_some(),
        "dirt_settings": m.dirt,
        "filter": m.filter,
        "lights_are": if m.bounce.is_some() { "direct light only: render with global illumination" } else { "direct and bounced light together" },
        // The picture the lights reproduce: "lightmap" (show it like the game through
        // tools/blender/game_display.py) or "game" (render it as it is).
        "look": opts.look,
    });
    let out_sun = m.sun.map(|s| lights_out::OutSun {
        to_sun: s.to_sun.as_dvec3(),
        rgb: s.rgb.map(|c| c as f64),
        name: scene.suns.first().map(|s| s.name.clone()).filter(|n| !n.is_empty()).unwrap_or_else(|| "sun".into()),
        extras: json!({ "q3_relight": { "rel_error": rel_error_final, "scheme": opts.scheme } }),
    });
    lights_out::write(&opts.input, &opts.output, &lights_out::Output { lights: &out_lights, sun: out_sun.as_ref(), replace_suns: terms.sun != Optional::Off, emissive: &emissive, scene_extras, lightmap_gamma: (gamma_report.gamma != 1.0).then_some(gamma_report.gamma) })?;
    st.done("write");

    let light_reports = out_lights
        .iter()
        .zip(&shares)
        .map(|(l, s)| {
            let mx = l.rgb.iter().copied().fold(0.0f64, f64::max);
            LightReport {
                name: l.name.clone(),
                kind: if l.spot.is_some() { "spot" } else { "point" },
                position_m: l.position.to_array(),
                intensity_cd: mx * LM_PER_W,
                color: if mx > 0.0 { l.rgb.map(|c| c / mx) } else { [1.0; 3] },
                spot_axis: l.spot.as_ref().map(|s| s.axis.to_array()),
                spot_angle_deg: l.spot.as_ref().map(|s| s.radius_by_dist.atan().to_degrees()),
                range_m: lights_out::range_m(mx),
                energy_share: *s,
                locked: l.locked,
            }
        })
        .collect();
    let surfaces = bases.surfaces.groups.iter().enumerate().map(|(s, g)| SurfaceReport { shader: g.name.clone(), rows_reached: bases.surfaces.reach(s), patches: g.patches, area_m2: g.area_m2, q3map2_meshes: g.q3map2_meshes, meshes_unmatched: g.meshes_unmatched, source_radiance: g.source_rgb, radiance: m.surfaces.get(s).copied().flatten() }).collect();
    Ok(Report {
        input: opts.input.display().to_string(),
        output: opts.output.display().to_string(),
        backend: backend_name,
        backend_reason: reason,
        target_backend,
        scheme: opts.scheme.clone(),
        estimator: opts.estimator,
        init: match &opts.init {
            Init::Auto => "auto".into(),
            Init::Greedy => "greedy".into(),
            Init::Grid(n) => format!("grid:{n}"),
            Init::Input => "input".into(),
            Init::Dense(n) => format!("dense:{n}"),
        },
        fit: opts.fit,
        vertices_input,
        triangles_input,
        subdivision,
        target_space: opts.target,
        look: opts.look,
        target: tstats,
        luxel: luxel_stats,
        data_clamp_byte: scene.materials.iter().map(|m| m.censor_byte).min().filter(|&b| b < crate::scene::CENSOR_BYTE),
        problem_rows: rows.len(),
        compile_cmdline: scene.compile.cmdline.clone(),
        compile_note,
        rel_error_initial,
        rel_error_final,
        rel_error_retraced,
        gamma: gamma_report,
        lights: light_reports,
        sun: out_sun.as_ref().map(|s| {
            let mx = s.rgb.iter().copied().fold(0.0f64, f64::max);
            let (t, p) = crate::fit::angles(s.to_sun.as_vec3());
            SunReport { name: s.name.clone(), to_sun: s.to_sun.to_array(), elevation_deg: t.to_degrees(), azimuth_deg: p.to_degrees(), illuminance_lux: mx * LM_PER_W, color: if mx > 0.0 { s.rgb.map(|c| c / mx) } else { [1.0; 3] } }
        }),
        sky: m.sky,
        surfaces,
        ambient: m.ambient,
        minlight: m.minlight,
        bounce: m.bounce,
        bounces: bases.bounces,
        bounce_transport: bases.bounce_stats.clone(),
        dirt: m.dirt,
        filter: m.filter,
        terms: term_reports,
        residual_by_material,
        pruned,
        kept_input_state,
        merged,
        auto: auto_stats,
        dense_candidates,
        dense_dark,
        phases: phases_done,
        iterations: history,
        rays_traced: rays,
        evaluations,
        linear_fits,
        prune_singles_skipped,
        stage_times_s: st.list,
        total_time_s: t_all.elapsed().as_secs_f64(),
        skipped_primitives: scene.skipped,
        shadow_pieces,
    })
}

/// How far a spot's axis runs before it meets the scene (for its cone in glTF angles).
fn spot_distance(bvh: &Bvh, l: &Light) -> f64 {
    let Some(s) = l.spot else { return 0.0 };
    let reach = bvh.reach();
    bvh.first_hit(l.pos, s.axis * reach, 1.0).map_or(1.0, |(t, _)| (t * reach) as f64)
}

/// How [`decide_terms`] switches a term on or off from the model it starts from (the
/// entry): `fn(model, entry, on)`.
type Set = Box<dyn Fn(&mut Model, &Model, bool)>;

/// One optional term as [`decide_terms`] weighs it.
struct TermCase {
    name: String,
    /// The plan's choice.
    choice: Optional,
    /// Switches it on or off from the entry.
    set: Set,
    /// Other ways to switch it on, each tried too where it differs from `set`'s (the
    /// best is the term's case).
    others: Vec<Set>,
    /// What another way must lower the error by to replace the first.
    other_gain: f64,
    /// What the term kept is, for the report's note (the dirt's settings).
    describe: fn(&Model) -> Option<String>,
}

impl TermCase {
    /// A term with one way to switch it on.
    fn new(name: &str, choice: Optional, set: Set) -> TermCase {
        TermCase { name: name.into(), choice, set, others: Vec::new(), other_gain: 0.0, describe: |_| None }
    }
}

/// Decides each optional term (see [`Optional`]): with `auto` a term stays when the linear
/// fit with it lowers the relative error by at least [`TERM_GAIN`] against the same fit
/// without it, or when it lowers it at all and leaving it out would take the error more
/// than [`TERM_GAIN`] above the lowest the decisions have reached: terms are left out one
/// by one, and each small loss counts against one allowance for them all (five surface
/// lights of oacmpctf1, each under the gain, had added up to 0.0066). Every term is
/// weighed without the ambient and the ambient last (see the ambient's entry below).
/// Appends one report per term considered.
fn decide_terms(fit: &mut Fitter, terms: &TermPlan, opts: &Options, gain: f64, out: &mut Vec<TermReport>) {
    let mut list: Vec<TermCase> = Vec::new();
    if fit.bases.bounce.is_some() {
        // The bounce's factor is not a linear coefficient: the phases may have taken it
        // near zero (the ambient standing in for it) before the exact fits could weigh it.
        // It is also tried at q3map2's default strength, factor 1 (its `-bouncescale
        // 0.25`): oacmpdm1 with its source lights, 0.2879 with the phases' 4e-6, 0.2411
        // at 1.
        list.push(TermCase {
            others: vec![Box::new(|m, _, on| m.bounce = on.then_some([1.0; 3]))],
            ..TermCase::new("bounce", terms.bounce, Box::new(|m, e, on| m.bounce = if on { e.bounce.or(Some([1.0; 3])) } else { None }))
        });
    }
    if let Some(first) = first_dirt(&terms.dirt_sets).filter(|_| !fit.bases.dirt.is_empty()) {
        // Each depth the data chooses among is another way to switch it on. Another depth
        // than the entry's (q3map2's default where the entry has no dirt) is one more
        // fitted number, and must earn its place as a term does, whatever the gain asked
        // of the terms: oacmpctf1 with its source lights, free to take any depth, took 64
        // at the stored reading, which then stood in for its gamma (0.0741, gamma 1;
        // 0.0715 with depth 128 and gamma 1.375).
        // Every setting (the one the first way gives is skipped where it is tried).
        let others: Vec<Set> = terms.dirt_sets.iter().map(|&s| Box::new(move |m: &mut Model, _: &Model, on: bool| m.dirt = on.then_some(s)) as Set).collect();
        list.push(TermCase {
            others,
            other_gain: TERM_GAIN,
            describe: |m| m.dirt.map(|d| format!("depth {} units, scale {}, gain {}", d.depth_units, d.scale, d.gain)),
            ..TermCase::new("dirt", terms.dirt, Box::new(move |m, e, on| m.dirt = if on { e.dirt.or(Some(first)) } else { None }))
        });
    }
    if fit.bases.filter.is_some() {
        list.push(TermCase::new("filter", terms.filter, Box::new(|m, _, on| m.filter = on)));
    }
    if opts.fit == FitMode::All {
        if fit.model.sun.is_some() {
            list.push(TermCase::new("sun", terms.sun, Box::new(|m, e, on| m.sun = if on { e.sun } else { None })));
        }
        if fit.bases.sky.is_some() {
            list.push(TermCase::new("sky", terms.sky, Box::new(|m, e, on| m.sky = if on { e.sky.or(Some([0.1; 3])) } else { None })));
        }
        for (s, g) in fit.bases.surfaces.groups.clone().iter().enumerate() {
            list.push(TermCase::new(&format!("surface light {}", g.name), terms.surfaces, Box::new(move |m, e, on| m.surfaces[s] = if on { e.surfaces[s].or(Some([1e-3; 3])) } else { None })));
        }
    }
    // The ambient is the catch-all: a constant that stands in, in part, for any term that
    // brightens broadly (the bounce above all). Every other term is weighed without it, and
    // the ambient last, on what they leave. Weighed beside it, oacmpdm1's bounce (its
    // source lights, read through gamma 1.25) gained 0.0042, stayed out, and the ambient
    // was kept: 0.1581; weighed without it, the bounce is kept and the ambient not
    // needed: 0.1543.
    let entry_ambient = fit.model.ambient;
    list.push(TermCase::new("ambient", Optional::Auto, Box::new(move |m, _, on| m.ambient = if on { entry_ambient.or(Some([1e-6; 3])) } else { None })));
    // Which terms a model has on (the lights aside).
    let terms_of = |m: &Model| (m.bounce.is_some(), m.dirt, m.filter, m.sun.is_some(), m.sky.is_some(), m.surfaces.iter().map(Option::is_some).collect::<Vec<_>>(), m.ambient.is_some());
    // The entry's error as the phases saw it (their visibility; the value only).
    let entry_error = {
        let m = fit.model.clone();
        fit.value_frozen(&m).rel_error
    };
    let entry = (fit.model.clone(), fit.vis.clone(), entry_error);
    fit.model.ambient = None;
    // The error of the model as it stands (the ambient aside); a variant equal to it is
    // not fitted again.
    let mut current = fit.fit_linear();
    // The lowest error the decisions have reached (what the allowance is counted from).
    let mut lowest = current;
    // Whether the model stands as screened decisions left it: terms taken out, the rest's
    // coefficients not refitted since (`current` is then its error as it stands, above
    // what the refit would reach).
    let mut stale = false;
    for TermCase { name, choice, set, others, other_gain, describe } in list {
        if fit.out_of_time() {
            break;
        }
        // A term the model has on, with one way to be on, decided by the data: screened.
        // Taken out, the rest's coefficients as they stand, its error bounds the refit's
        // from above (`fit_linear` never ends above its entry); the fit with it, whose
        // terms are among those of the last refitted model, lies at or above `lowest`.
        // So where taking it out stays within `lowest + gain` as it stands, the fits would
        // have left it out too (neither lower by the gain, nor past the allowance), and
        // it goes without them; the refit waits for the next decision that needs one.
        let mut off = fit.model.clone();
        set(&mut off, &fit.model, false);
        let mut fitted_off = None;
        if fit.screen_decisions && choice == Optional::Auto && others.is_empty() && off != fit.model {
            let vis = fit.vis.clone();
            let as_it_stands = fit.value_frozen(&off).rel_error;
            if as_it_stands <= lowest + gain {
                out.push(TermReport { term: name, kept: false, rel_error_without: as_it_stands, rel_error_with: current, note: "not used: leaving it out, before any refit, keeps the error within the allowance".into() });
                (current, fit.model, stale) = (as_it_stands, off, true);
                continue;
            }
            fit.vis = vis;
            if stale {
                // The fit without it, from the state as it stands; the same bound decides
                // where it can, else the state with it is refitted to compare.
                let with = (fit.model.clone(), fit.vis.clone());
                fit.model = off;
                let e = fit.fit_linear();
                if e <= lowest + gain {
                    out.push(TermReport { term: name, kept: false, rel_error_without: e, rel_error_with: current, note: "not used: leaving it out, refitted, keeps the error within the allowance (with it: as it stands, before a refit)".into() });
                    (current, lowest, stale) = (e, lowest.min(e), false);
                    continue;
                }
                fitted_off = Some((e, fit.model.clone(), fit.vis.clone()));
                (fit.model, fit.vis) = with;
            }
        }
        if stale {
            current = fit.fit_linear();
            lowest = lowest.min(current);
            stale = false;
        }
        let entry = fit.model.clone();
        let variant = |set: &Set, on: bool, fit: &mut Fitter| {
            let mut m = entry.clone();
            set(&mut m, &entry, on);
            if m == entry {
                return (current, entry.clone(), fit.vis.clone());
            }
            fit.model = m;
            let e = fit.fit_linear();
            (e, fit.model.clone(), fit.vis.clone())
        };
        if choice == Optional::Off {
            let (e, m, v) = variant(&set, false, fit);
            (current, fit.model, fit.vis) = (e, m, v);
            out.push(TermReport { term: name, kept: false, rel_error_without: e, rel_error_with: f64::NAN, note: "off".into() });
            continue;
        }
        let without = match fitted_off.take() {
            Some(w) => w,
            None => variant(&set, false, fit),
        };
        let mut with = variant(&set, true, fit);
        // The best other way, which replaces the first where it is lower by the gain asked.
        let mut first_on = entry.clone();
        set(&mut first_on, &entry, true);
        let mut best_other: Option<(f64, Model, crate::trace::visibility::Visibility)> = None;
        for also in &others {
            let mut b = entry.clone();
            also(&mut b, &entry, true);
            if b != first_on {
                let other = variant(also, true, fit);
                if best_other.as_ref().is_none_or(|o| other.0 < o.0) {
                    best_other = Some(other);
                }
            }
        }
        if let Some(other) = best_other.filter(|o| o.0 < with.0 - other_gain) {
            with = other;
        }
        lowest = lowest.min(with.0).min(without.0);
        let gains = with.0 < without.0 - gain;
        let allowance_spent = with.0 < without.0 && without.0 > lowest + gain;
        let keep = choice == Optional::On || gains || allowance_spent;
        let mut note = match (choice, keep) {
            (Optional::On, _) => "on (asked, or the recorded compile)".to_string(),
            (_, true) if gains => "kept: lowers the error".into(),
            (_, true) => "kept: leaving it out too would take the error past the allowance for the terms left out".into(),
            (_, false) => "not used: does not lower the error enough".into(),
        };
        if let Some(what) = describe(&with.1).filter(|_| keep) {
            note.push_str(&format!(" ({what})"));
        }
        out.push(TermReport { term: name, kept: keep, rel_error_without: without.0, rel_error_with: with.0, note });
        let chosen = if keep { with } else { without };
        (current, fit.model, fit.vis) = chosen;
    }
    if stale {
        current = fit.fit_linear();
    }
    // The variants are compared after exact linear fits, which hold censored channels
    // only through an active set and can be worse than what the phases reached: where the decision kept every
    // term as it was, the entry stands unless the fits improved on it (a re-run from a
    // relit file's own state starts and stays there).
    if terms_of(&fit.model) == terms_of(&entry.0) && !(current < entry.2) {
        (fit.model, fit.vis) = (entry.0, entry.1);
    }
}

/// What the run does about the compile's gamma ([`crate::rows::gamma`]).
#[derive(Debug, Clone, PartialEq)]
enum GammaPlan {
    /// Read the data through this gamma from the start (`--gamma G`).
    Asked(f64),
    /// Estimate it at the end, the lights' places being given (`--init input`).
    Estimate,
    /// Neither, and why.
    Not(String),
}

/// Whether the gamma is asked for, estimated, or neither. Only where the file does not
/// record one (convert reads `-gamma` from `_q3map2_cmdline` onto the materials), and
/// only for the baked light as stored (`--look lightmap`, the model's estimator). The
/// estimate needs the lights' places: a light further away falls off more slowly, as a
/// gamma above 1 makes it seem to, so the placement (`--init auto`) would trade one for
/// the other (a synthetic scene stored through `-gamma 1.5` and placed from its bytes as
/// they are came back with nine lights for its three, 0.033 even through the right gamma).
fn plan_gamma(opts: &Options, scene: &Scene, rows: &Rows, tracing: bool) -> GammaPlan {
    // A recorded command line states the gamma, 1 where it has no `-gamma`.
    let recorded = scene.materials.iter().filter(|m| m.lighting != Lighting::None).any(|m| m.lightmap_gamma != 1.0) || scene.compile.cmdline.is_some();
    let not = |s: &str| GammaPlan::Not(s.to_string());
    match opts.gamma {
        GammaChoice::Off => not("off (asked)"),
        _ if recorded => not("stated by the file (a recorded compile's, or the gamma a previous relight read it through); --gamma applies only where none is"),
        _ if tracing => not("not read: --estimator tracing"),
        _ if opts.look == Look::Game => not("not read: --look game reads the screen, not the compile's light"),
        _ if !rows.has_data() => not("not read: no data"),
        GammaChoice::Fixed(g) => GammaPlan::Asked(g as f64),
        GammaChoice::Auto if matches!(opts.init, Init::Input) => GammaPlan::Estimate,
        GammaChoice::Auto => not("not estimated: only from the file's lights (--init input), as the placement would trade their distance for it; ask with --gamma G"),
    }
}

/// Gammas the estimate may choose: q3map2's `-gamma` as mappers set it (1, 1.5, 2.2 in
/// recorded command lines), searched on this range.
const GAMMA_RANGE: (f64, f64) = (1.0, 2.5);
/// The search's first step and the smallest it halves to.
const GAMMA_STEP: (f64, f64) = (0.25, 0.125);

/// The compile's gamma where the file does not record it ([`crate::rows::gamma`]): each
/// candidate reading of the data gets the exact linear fit of the model as it stands,
/// each kind of emitter scaled as a whole, with every term that lowers the error at all
/// (a bounce and an ambient stand in for a gamma differently), and is measured against
/// the stored bytes; the best reading is adopted where it lowers that error by
/// [`TERM_GAIN`] (the rule every term follows) and, polished and its terms decided under
/// that gain, still ends below the run's own result; the fitter then reads the data
/// through it (`regraded` holds those rows). Returns the report and, when a reading was
/// adopted, its terms' decisions.
#[allow(clippy::too_many_arguments)]
fn estimate_gamma<'a>(fit: &mut Fitter<'a>, regraded: &'a std::cell::OnceCell<Rows>, plan: &GammaPlan, terms: &TermPlan, opts: &Options, polish: crate::fit::Phase, e_full: f64) -> (GammaReport, Option<Vec<TermReport>>) {
    let stored = fit.rows;
    let mut report = GammaReport { gamma: 1.0, how: String::new(), tried: Vec::new(), rel_error_fit_reading: f64::NAN };
    match plan {
        GammaPlan::Estimate => {}
        GammaPlan::Asked(g) => {
            report.gamma = *g;
            report.how = format!("asked: {g} (the rows read through it from the start)");
            return (report, None);
        }
        GammaPlan::Not(why) => {
            report.how = why.clone();
            return (report, None);
        }
    }
    // The run's own result in the stored reading, what an adopted reading must end below.
    let main = (fit.model.clone(), fit.vis.clone(), fit.value().rel_error);
    // The adopted reading's model: the nonlinear parameters polished (the bounce's factor
    // above all; kept where it lowers the error), then every term decided under the
    // usual gain, as the stored reading's were.
    let settle = |fit: &mut Fitter| {
        if !fit.out_of_time() {
            let before = (fit.model.clone(), fit.vis.clone(), fit.value().f);
            fit.run_phase("polish (gamma)", polish);
            fit.fit_linear();
            if !(fit.value().f <= before.2) {
                (fit.model, fit.vis) = (before.0, before.1);
            }
        }
        let mut reports = Vec::new();
        decide_terms(fit, terms, opts, TERM_GAIN, &mut reports);
        reports
    };
    // The readings are compared with the dirt at one depth, the entry's where no other was
    // estimated (q3map2's default): a shorter dirt and a gamma both lift the dim luxels,
    // and a depth chosen at the stored reading stood in for the gamma there (oacmpctf1
    // with its source lights: depth 64 and gamma 1, 0.0741, where depth 128 and gamma
    // 1.375 reach 0.0715). The adopted reading chooses its depth when it settles.
    let first = first_dirt(&terms.dirt_sets);
    let compared = TermPlan { dirt_sets: first.into_iter().collect(), ..terms.clone() };
    // One candidate: its rows, the fit on them, the error against the stored bytes.
    let try_gamma = |g: f64, fit: &mut Fitter<'a>| -> Option<(f64, Rows, Model, crate::trace::visibility::Visibility)> {
        let rows_g = crate::rows::gamma::regraded(stored, g, e_full);
        // The model as it stands with its coefficients refitted, with an ambient, and
        // with its bounce as it is, at q3map2's factor 1, or none (its factor is not a
        // linear coefficient; a bounce and an ambient stand in for a gamma differently),
        // the best of those: readings compared at their best, not through decisions at
        // the margin.
        let bounce_allowed = fit.bases.bounce.is_some() && terms.bounce != Optional::Off;
        let (model, vis) = fit.on_rows(&rows_g, |t| {
            // Each kind of emitter scaled as a whole, its members' proportions as fitted
            // (a column per kind through the chain, not per light: on oa_dm1's 59 lights
            // the per-light columns took 18 s over three readings, for no gain).
            t.kind_scales = true;
            let entry = Model { ambient: t.model.ambient.or(Some([1e-6; 3])), dirt: t.model.dirt.and(first), ..t.model.clone() };
            let mut variants = vec![entry.clone()];
            if bounce_allowed {
                for b in [Some([1.0f32; 3]), None] {
                    if entry.bounce != b && (b.is_some() || terms.bounce != Optional::On) {
                        variants.push(Model { bounce: b, ..entry.clone() });
                    }
                }
            }
            let mut best: Option<(f64, Model, crate::trace::visibility::Visibility)> = None;
            for v in variants {
                t.model = v;
                let e = t.fit_linear();
                if best.as_ref().is_none_or(|b| e < b.0) {
                    best = Some((e, t.model.clone(), t.vis.clone()));
                }
            }
            let Some((_, m, v)) = best else { return (t.model.clone(), t.vis.clone()) };
            // Then every term that lowers the error at all (dirt, say, may pay in one
            // reading and not in another).
            (t.model, t.vis) = (m, v);
            decide_terms(t, &compared, opts, 0.0, &mut Vec::new());
            (t.model.clone(), t.vis.clone())
        });
        let x = model::radiance(&model, &rows_g, fit.bases, &vis, &mut *fit.backend).ok()?;
        let e = stored.rel_error(&crate::rows::gamma::to_stored(stored, &x, g, e_full));
        e.is_finite().then_some((e, rows_g, model, vis))
    };
    // The stored reading itself, fitted as the candidates are (every term that lowers the
    // error): the yardstick they must beat by the gain.
    let e1 = match try_gamma(1.0, fit) {
        Some((e, ..)) => e.min(main.2),
        None => main.2,
    };
    report.tried = vec![(1.0, e1)];
    let mut best: (f64, f64, Option<(Rows, Model, crate::trace::visibility::Visibility)>) = (1.0, e1, None);
    let mut step = GAMMA_STEP.0;
    while step >= GAMMA_STEP.1 - 1e-9 && !fit.out_of_time() {
        let mut moved = false;
        for g in [best.0 + step, best.0 - step] {
            let g = (g * 1e4).round() / 1e4;
            if g < GAMMA_RANGE.0 - 1e-9 || g > GAMMA_RANGE.1 + 1e-9 || report.tried.iter().any(|t| (t.0 - g).abs() < 1e-6) || fit.out_of_time() {
                continue;
            }
            let Some((e, rows_g, m, vis)) = try_gamma(g, fit) else { continue };
            report.tried.push((g, e));
            if e < best.1 {
                best = (g, e, Some((rows_g, m, vis)));
                moved = true;
                break;
            }
        }
        if !moved {
            step *= 0.5;
        }
    }
    report.tried.sort_by(|a, b| a.0.total_cmp(&b.0));
    match best {
        (g, e, Some((rows_g, m, vis))) if e < e1 - TERM_GAIN => {
            let _ = regraded.set(rows_g);
            if let Some(r) = regraded.get() {
                fit.rows = r;
                fit.model = m;
                fit.vis = vis;
                let reports = settle(fit);
                // Settled (its terms decided under the gain), it must still end below the
                // run's own result against the stored bytes; otherwise that stands.
                let m = fit.model.clone();
                let settled = model::radiance(&m, r, fit.bases, &fit.vis, &mut *fit.backend).ok().map(|x| stored.rel_error(&crate::rows::gamma::to_stored(stored, &x, g, e_full)));
                if let Some(e_settled) = settled.filter(|e| *e < main.2) {
                    report.gamma = g;
                    report.how = format!("estimated: the stored bytes read through gamma {g} fit them {e1:.4} -> {e:.4} ({e_settled:.4} with its terms decided)");
                    return (report, Some(reports));
                }
                fit.rows = stored;
                (fit.model, fit.vis) = (main.0, main.1);
                report.how = format!("estimated: 1 (gamma {g} fitted the stored bytes {e1:.4} -> {e:.4}, but not below the run's own {:.4} with its terms decided)", main.2);
                return (report, None);
            }
            report.how = "not estimated: internal".into();
            (report, None)
        }
        (g, e, _) => {
            report.how = if g == 1.0 { "estimated: 1 (no other reading fits the stored bytes better)".into() } else { format!("estimated: 1 (gamma {g} fits the stored bytes {e1:.4} -> {e:.4}, less than the gain a term must bring)") };
            (report, None)
        }
    }
}

/// The sun's direction by search with the rest of the model fixed (its shadows' edges,
/// which carry the information, are invisible to the gradient).
fn refine_sun(fit: &mut Fitter, s: Sun, seed: u64) {
    let (sub, take) = fit.rows.subsample(40_000, seed);
    let sub_bases = fit.bases.subset(&take);
    let others = Model { sun: None, bounce: None, filter: false, ..fit.model.clone() };
    let mut vis = crate::trace::visibility::Visibility::default();
    let bvh = fit.bvh;
    if vis.update(&model::lights::sources(&others.lights), 0.0, &sub.sampling, sub.len(), &mut |p| Ok(p.iter().map(|&(q, r)| crate::trace::visibility::trace_light(bvh, &sub, q, r)).collect())).is_err() {
        return;
    }
    let Ok(base) = model::radiance(&others, &sub, &sub_bases, &vis, &mut Cpu::new(&sub, bvh)) else { return };
    let sky = &fit.bases.sky_triangles;
    let backend = &mut *fit.backend;
    let found = match init::sun_search(&sub, &base, &[], Some(s.to_sun), &mut |dirs| crate::backend::sun_bits(&mut *backend, bvh, &sub, dirs, sky)) {
        Ok(found) => found,
        Err(err) => {
            fit.failure = Some(err);
            return;
        }
    };
    if let Some((better, _)) = found {
        let before = fit.eval().f;
        let saved = (fit.model.clone(), fit.vis.clone());
        fit.model.sun = Some(Sun { rgb: s.rgb, ..better });
        fit.fit_linear();
        if !(fit.eval().f <= before) {
            (fit.model, fit.vis) = saved;
        }
    }
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

/// [`energy_shares`] by the light-tracing estimator: each light traced alone once.
fn traced_energy_shares(rows: &Rows, fit: &mut Fitter) -> Result<Vec<f64>> {
    let lights = fit.model.lights.clone();
    let mut e = Vec::with_capacity(lights.len());
    for l in &lights {
        let irr = fit.backend.irradiance(&fit.vis, std::slice::from_ref(l))?;
        e.push(irr.iter().enumerate().map(|(i, x)| rows.area[i] as f64 * (0..3).map(|c| rows.albedo[i][c] as f64 * x[c] as f64).sum::<f64>()).sum::<f64>());
    }
    let total: f64 = e.iter().sum();
    Ok(e.iter().map(|v| if total > 0.0 { v / total } else { 0.0 }).collect())
}

/// Each light's share of the area-weighted direct radiance it sends to the rows.
fn energy_shares(rows: &Rows, fit: &Fitter) -> Vec<f64> {
    let m = &fit.model;
    let mut e = vec![0.0f64; m.lights.len()];
    for (j, l) in m.lights.iter().enumerate() {
        if j >= fit.vis.bits.len() {
            continue;
        }
        fit.vis.for_each_visible(j, 0..rows.len(), |i| {
            let g = model::lights::g(rows, i, l) as f64;
            e[j] += rows.area[i] as f64 * (0..3).map(|c| rows.albedo[i][c] as f64 * l.rgb[c] as f64).sum::<f64>() * g;
        });
    }
    let total: f64 = e.iter().sum();
    e.iter().map(|v| if total > 0.0 { v / total } else { 0.0 }).collect()
}

/// Every row as CSV: material, texel, position and normal (world, m), albedo, the data's
/// interval (lo, hi; a censored channel's lower bound in lo with hi empty), the model,
/// the area, and the model's green channel from each kind of emitter alone (the lights,
/// the sun and sky, the surface lights; through the same chain).
fn dump_rows(path: &std::path::Path, scene: &Scene, rows: &Rows, bases: &Bases, fit: &mut Fitter) -> Result<()> {
    use std::fmt::Write;
    let m = fit.model.clone();
    let x = model::radiance(&m, rows, bases, &fit.vis, &mut *fit.backend)?;
    let bare = m.chain_only();
    let only_lights = model::radiance(&Model { lights: m.lights.clone(), ..bare.clone() }, rows, bases, &fit.vis, &mut *fit.backend)?;
    let only_sky = model::radiance(&Model { sun: m.sun, sky: m.sky, ..bare.clone() }, rows, bases, &fit.vis, &mut *fit.backend)?;
    let only_surfaces = model::radiance(&Model { surfaces: m.surfaces.clone(), ..bare }, rows, bases, &fit.vis, &mut *fit.backend)?;
    // The model's dirt factor, or the first the run traced where the model has none.
    let dirt = bases.dirt_of(&m).or(bases.dirt.first().map(|b| b.factor.as_slice()));
    let mut s = String::from("material,tex,tx,ty,px,py,pz,nx,ny,nz,ar,ag,ab,lo_r,lo_g,lo_b,hi_r,hi_g,hi_b,x_r,x_g,x_b,area,g_lights,g_sky,g_surfaces,dirt\n");
    for i in 0..rows.len() {
        let p = scene.origin + rows.pos[i].as_dvec3();
        let n = rows.normal[i];
        let name = scene.materials.get(rows.material[i] as usize).map_or("", |m| m.name.as_str()).replace(',', ";");
        let t = rows.texel[i].map(|v| if v == u32::MAX { -1 } else { v as i64 });
        let (lo, hi): ([f32; 3], [Option<f32>; 3]) = ([0, 1, 2].map(|c| if rows.weight[i][c] > 0.0 { rows.lo[i][c] } else { rows.lower[i][c] }), [0, 1, 2].map(|c| (rows.weight[i][c] > 0.0).then_some(rows.hi[i][c])));
        let hs = hi.map(|h| h.map_or(String::new(), |v| v.to_string()));
        let a = rows.albedo[i];
        let _ = writeln!(
            s,
            "{name},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            t[0], t[1], t[2], p.x, p.y, p.z, n.x, n.y, n.z, a[0], a[1], a[2], lo[0], lo[1], lo[2], hs[0], hs[1], hs[2], x[i][0], x[i][1], x[i][2], rows.area[i], only_lights[i][1], only_sky[i][1], only_surfaces[i][1],
            dirt.map_or(1.0, |d| d[i])
        );
    }
    q3gltf_convert::output::write_atomic(path, s.as_bytes()).map_err(|e| Error::Io { path: path.display().to_string(), source: e })
}

/// The residual per material, largest share first.
fn residual_by_material(scene: &Scene, rows: &Rows, bases: &Bases, fit: &mut Fitter) -> Result<Vec<MaterialResidual>> {
    let m = fit.model.clone();
    let x = model::radiance(&m, rows, bases, &fit.vis, &mut *fit.backend)?;
    let k = scene.materials.len();
    let mut acc = vec![(0usize, 0.0f64, 0.0f64, [0.0f64; 3], [0.0f64; 3], 0.0f64); k];
    let mut total = 0.0;
    for i in 0..rows.len() {
        let mi = (rows.material[i] as usize).min(k.saturating_sub(1));
        let a = &mut acc[mi];
        a.0 += 1;
        for c in 0..3 {
            let w = rows.area[i] as f64 * rows.weight[i][c] as f64;
            let (_, _, num) = crate::rows::residual(x[i][c], rows.lo[i][c] as f64, rows.hi[i][c] as f64, rows.weight[i][c] as f64, rows.lower[i][c] as f64, rows.area[i] as f64);
            a.1 += num;
            a.2 += w * rows.mid(i, c).powi(2);
            a.3[c] += w * rows.mid(i, c);
            a.4[c] += w * x[i][c];
            total += num;
        }
        a.5 += rows.area[i] as f64;
    }
    let mut out: Vec<MaterialResidual> = acc
        .into_iter()
        .enumerate()
        .filter(|(_, a)| a.0 > 0)
        .map(|(mi, a)| MaterialResidual {
            material: scene.materials[mi].name.clone(),
            rows: a.0,
            residual_share: if total > 0.0 { a.1 / total } else { 0.0 },
            rel_error: if a.2 > 0.0 { (a.1 / a.2).sqrt() } else { 0.0 },
            mean_data: a.3.map(|v| if a.5 > 0.0 { v / a.5 } else { 0.0 }),
            mean_model: a.4.map(|v| if a.5 > 0.0 { v / a.5 } else { 0.0 }),
        })
        .collect();
    out.sort_by(|a, b| b.residual_share.total_cmp(&a.residual_share));
    Ok(out)
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_sun_turned_by_float_rounding_has_not_turned() {
        use glam::Vec3;
        let a = Vec3::new(0.000_218_166_7, 1.0, -6.068_547e-7).normalize();
        let nudged = Vec3::new(a.x + 1e-7, a.y, a.z).normalize();
        assert_ne!(a, nudged, "the nudge changes the bits");
        assert!(!super::sun_turned(a, nudged), "{}", a.angle_between(nudged).to_degrees());
        assert!(!super::sun_turned(a, a));
        let turned = glam::Quat::from_rotation_x(0.2f32.to_radians()) * a;
        assert!(super::sun_turned(a, turned));
    }

    /// A recorded `-areascale 0` / `-skyscale 0` (as in a point-lights-only compile) keeps the
    /// surface lights, the sky light and the sun out of the model; asked for, they stay in.
    #[test]
    fn emitters_the_compile_scaled_to_nothing_stay_out() {
        use super::{plan_terms, Optional, Options};
        use crate::scene::{Compile, Emitter, Material};
        let panel = Material { emitter: Some(Emitter { value: 1000.0, color: [1.0; 3], subdivide: 999.0, backsplash: (0.05, 23.0) }), ..crate::testutil::material("panel") };
        let sky = Material { sky: true, sky_lights: vec![(60.0, 4, [1.0; 3])], ..crate::testutil::material("sky") };
        let scene = |cmdline: Option<&str>| {
            let mut s = crate::testutil::scene(Default::default(), vec![panel.clone(), sky.clone()]);
            s.compile = Compile { cmdline: cmdline.map(String::from), ..Default::default() };
            s
        };
        let opts = Options::default();
        let (p, _) = plan_terms(&opts, &scene(Some("-bsp -meta; -light -fast -patchshadows -areascale 0 -skyscale 0")));
        assert_eq!((p.surfaces, p.sky, p.sun), (Optional::Off, Optional::Off, Optional::Off));
        let (p, _) = plan_terms(&opts, &scene(Some("-bsp -meta; -light -fast -area 0.5 -sky 0")));
        assert_eq!((p.surfaces, p.sky), (Optional::Auto, Optional::Off));
        let (p, _) = plan_terms(&opts, &scene(None));
        assert_eq!((p.surfaces, p.sky, p.sun), (Optional::Auto, Optional::Auto, Optional::Auto));
        let asked = Options { surfaces: Optional::On, sky: Optional::On, ..Options::default() };
        let (p, _) = plan_terms(&asked, &scene(Some("-light -areascale 0 -skyscale 0")));
        assert_eq!((p.surfaces, p.sky), (Optional::On, Optional::On));
    }

    /// A room whose data is two point lights and three passes of their bounce (the
    /// bases' chain), 8-bit: the scene of the term decisions' tests.
    struct BouncedRoom {
        rows: crate::rows::Rows,
        bases: crate::model::Bases,
        bvh: crate::trace::bvh::Bvh,
        lo: glam::Vec3,
        hi: glam::Vec3,
        truth: crate::model::Model,
    }

    fn bounced_room() -> BouncedRoom {
        use crate::model::{Light, Model};
        use glam::Vec3;
        let (mesh, mut rows) = crate::testutil::room(6);
        let bases = crate::testutil::chain_bases(rows.len(), 3);
        let bvh = crate::trace::bvh::Bvh::build(&mesh);
        let (lo, hi) = mesh.bounds();
        let lights = vec![Light::point(Vec3::new(1.1, 1.7, 0.9), [2.0; 3]), Light::point(Vec3::new(2.6, 2.4, 2.2), [0.7, 1.2, 1.9])];
        let truth = Model { lights, bounce: Some([1.0; 3]), ..Model::default() };
        crate::testutil::data_from_model(&mut rows, &bases, &bvh, &truth, 1e-3);
        BouncedRoom { rows, bases, bvh, lo, hi, truth }
    }

    /// Only the bounce (and the ambient) undecided, three passes.
    fn bounce_plan() -> super::TermPlan {
        use super::Optional;
        super::TermPlan { sun: Optional::Off, sky: Optional::Off, surfaces: Optional::Off, bounce: Optional::Auto, bounces: 3, dirt: Optional::Off, dirt_sets: Vec::new(), filter: Optional::Off, fast_area: false, fast_bounce: false }
    }

    /// The phases can leave the bounce's factor near zero (the ambient standing in for it);
    /// the decision then tries it at q3map2's default factor too, and keeps it where the data was
    /// bounced. Tried only at the entry's factor, the bounce was left out.
    #[test]
    fn a_bounce_the_phases_turned_down_is_decided_at_full_strength_too() {
        use super::{decide_terms, Options};
        use crate::backend::Cpu;
        use crate::fit::Fitter;
        use crate::model::Model;
        let r = bounced_room();
        let truth = &r.truth;
        let mut cpu = Cpu::new(&r.rows, &r.bvh);
        let mut fit = Fitter::new(&r.rows, &r.bases, &r.bvh, &mut cpu, r.lo, r.hi);
        fit.locked = vec![false; 2];
        fit.model = Model { bounce: Some([4e-6; 3]), ..truth.clone() };
        let plan = bounce_plan();
        let mut reports = Vec::new();
        decide_terms(&mut fit, &plan, &Options::default(), super::TERM_GAIN, &mut reports);
        let b = &reports[0];
        assert_eq!(b.term, "bounce");
        assert!(b.kept, "the bounce left out: {} without, {} with", b.rel_error_without, b.rel_error_with);
        assert!(b.rel_error_with < 0.01, "the bounce at full strength explains the data: {}", b.rel_error_with);
        assert_eq!(fit.model.bounce, Some([1.0; 3]));
    }

    /// The ambient, a constant, stands in for part of any broad term (the bounce above
    /// all), so every other term is weighed without it and the ambient last: the entry
    /// here has the ambient the phases fitted in place of the bounce. The bounce's "without"
    /// is the lights alone, not the lights and that ambient; the bounce is kept, the ambient
    /// then left out.
    #[test]
    fn terms_are_weighed_without_the_ambient_and_the_ambient_last() {
        use super::{decide_terms, Options};
        use crate::backend::Cpu;
        use crate::fit::Fitter;
        use crate::model::Model;
        let r = bounced_room();
        let lights = r.truth.lights.clone();
        let mut cpu = Cpu::new(&r.rows, &r.bvh);
        let mut fit = Fitter::new(&r.rows, &r.bases, &r.bvh, &mut cpu, r.lo, r.hi);
        fit.locked = vec![false; 2];
        fit.model = Model { lights: lights.clone(), ..Model::default() };
        let alone = fit.fit_linear();
        fit.model = Model { lights: lights.clone(), ambient: Some([0.05; 3]), ..Model::default() };
        let with_ambient = fit.fit_linear();
        assert!(with_ambient < alone - 1e-3, "the ambient stands in for part of the bounce: {alone} alone, {with_ambient} with it");
        let plan = bounce_plan();
        let mut reports = Vec::new();
        decide_terms(&mut fit, &plan, &Options::default(), super::TERM_GAIN, &mut reports);
        let (b, a) = (&reports[0], reports.last().unwrap());
        assert_eq!((b.term.as_str(), a.term.as_str()), ("bounce", "ambient"));
        assert!((b.rel_error_without - alone).abs() < 1e-9, "the bounce weighed against {} (the lights alone: {alone}; with the ambient: {with_ambient})", b.rel_error_without);
        assert!(b.kept && !a.kept, "bounce kept {}, ambient kept {}", b.kept, a.kept);
        assert_eq!((fit.model.bounce.is_some(), fit.model.ambient), (true, None));
        assert!(fit.eval().rel_error < 0.01, "{}", fit.eval().rel_error);
    }

    /// Five surface lights over the room (synthetic bases, each a different pattern over
    /// the rows); the data has only the second. The model has all five on, its
    /// coefficients fitted, as the phases leave it. The terms the model has on and the data
    /// lacks are taken out as they stand (the first before any refit, the last three after
    /// the second's exact decision), the second is kept, the ambient fitted last: the same
    /// decisions as with every term refitted, the same error, and fewer linear fits.
    #[test]
    fn terms_taken_out_as_they_stand_are_decided_as_the_refits_decide_them() {
        use super::{decide_terms, Optional, Options, TermPlan};
        use crate::backend::Cpu;
        use crate::fit::Fitter;
        use crate::model::{surface, Light, Model};
        use glam::Vec3;
        let (mesh, mut rows) = crate::testutil::room(6);
        let n = rows.len();
        let bvh = crate::trace::bvh::Bvh::build(&mesh);
        let (lo, hi) = mesh.bounds();
        let groups = 5;
        let mut bases = crate::model::Bases::default();
        bases.surfaces.groups = (0..groups)
            .map(|g| surface::Group { name: format!("g{g}"), materials: Vec::new(), source_rgb: [1.0; 3], patches: 1, area_m2: 1.0, q3map2_meshes: 0, meshes_unmatched: 0 })
            .collect();
        bases.surfaces.offsets.push(0);
        for i in 0..n {
            for g in 0..groups {
                // Group g reaches every (g + 2)th row, more or less brightly.
                if (i + g) % (g + 2) == 0 {
                    bases.surfaces.entries.push((g as u32, 0.2 + 0.1 * ((i * (g + 3)) % 7) as f32));
                }
            }
            bases.surfaces.offsets.push(bases.surfaces.entries.len() as u32);
        }
        let lights = vec![Light::point(Vec3::new(1.1, 1.7, 0.9), [2.0; 3]), Light::point(Vec3::new(2.6, 2.4, 2.2), [0.7, 1.2, 1.9])];
        let mut present = vec![None; groups];
        present[1] = Some([0.9, 0.8, 0.7]);
        let truth = Model { lights, surfaces: present, ..Model::default() };
        crate::testutil::data_from_model(&mut rows, &bases, &bvh, &truth, 1e-3);
        let plan = TermPlan { sun: Optional::Off, sky: Optional::Off, surfaces: Optional::Auto, bounce: Optional::Off, bounces: 0, dirt: Optional::Off, dirt_sets: Vec::new(), filter: Optional::Off, fast_area: false, fast_bounce: false };
        let decide = |screen: bool| {
            let mut cpu = Cpu::new(&rows, &bvh);
            let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
            fit.locked = vec![false; 2];
            fit.screen_decisions = screen;
            // The lights a little off where the data's are, as a fit leaves them: the
            // error is not zero, and the surface lights the data lacks make up a little.
            let lights = truth.lights.iter().map(|l| Light { pos: l.pos + Vec3::new(0.03, -0.02, 0.025), ..*l }).collect();
            fit.model = Model { lights, surfaces: vec![Some([0.3; 3]); groups], ..truth.clone() };
            fit.fit_linear();
            let before = fit.linear_fits;
            let mut reports = Vec::new();
            decide_terms(&mut fit, &plan, &Options::default(), super::TERM_GAIN, &mut reports);
            let kept: Vec<(String, bool)> = reports.iter().map(|r| (r.term.clone(), r.kept)).collect();
            let on: Vec<bool> = fit.model.surfaces.iter().map(Option::is_some).collect();
            let notes: Vec<String> = reports.iter().map(|r| r.note.clone()).collect();
            (kept, on, fit.eval().rel_error, fit.linear_fits - before, notes)
        };
        let (kept_ref, on_ref, e_ref, fits_ref, _) = decide(false);
        let (kept, on, e, fits, notes) = decide(true);
        assert_eq!(on_ref, [false, true, false, false, false], "the reference keeps the data's surface light only: {kept_ref:?}");
        assert_eq!(kept, kept_ref, "the screened decisions differ from the refitted ones");
        assert_eq!(on, on_ref);
        assert!(e.is_finite() && (e - e_ref).abs() <= 1e-6 * e_ref, "the screened decisions end at {e}, the refitted at {e_ref}");
        let screened = notes.iter().filter(|n| n.contains("before any refit")).count();
        assert_eq!(screened, 4, "the four surface lights the data lacks are taken out as they stand: {notes:?}");
        assert!(fits < fits_ref, "screening saves fits: {fits} against {fits_ref}");
    }

    use super::light_names;

    #[test]
    fn light_names_keep_the_users_and_stay_distinct() {
        let n = light_names(&[Some("lamp"), None, Some("light_001"), Some("lamp"), Some("")], 6);
        assert_eq!(n, ["lamp", "light_000", "light_001", "light_002", "light_003", "light_004"]);
    }
}
