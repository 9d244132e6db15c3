//! The optimisation state: the model being fitted, its parameterisation ([`params`]),
//! penalties, phases of optimisers ([`crate::optim`]), the exact linear fit of every
//! linear coefficient ([`linear`]), and the pruning and merging of lights ([`prune`]).
//!
//! Penalties (scaled to the objective of an unlit scene `F0`): a light closer than
//! `min_dist` to a surface pays `F0 (1 - dist/min_dist)^2`; a light outside the scene's
//! box pays `F0 (outside/unit)^2` per axis.
//!
//! Invariants: a phase never ends worse than it began (visibility changes can make an
//! optimiser's last accepted step worse once re-traced: the phase is then undone);
//! line-search trials see the visibility of the current iterate (a smooth function),
//! re-tracing happens only at accepted iterates; locked lights are masked out of every
//! optimiser and of the linear fit.

pub mod linear;
pub mod params;
pub mod prune;

use std::time::Instant;

use glam::Vec3;

use crate::backend::Backend;
use crate::model::{self, Bases, Eval, Light, Model};
use crate::optim::{self, Stop};
use crate::rows::Rows;
use crate::trace::bvh::Bvh;
use crate::trace::visibility::{self, Visibility};
pub use params::{angles, direction, Codec, ParamSet};

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(tag = "algorithm", rename_all = "lowercase")]
pub enum Algorithm {
    Adam { step: f64 },
    Lbfgs { step: f64 },
}

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Phase {
    #[serde(flatten)]
    pub algorithm: Algorithm,
    pub params: ParamSet,
    pub max_iterations: usize,
}

/// One objective evaluation that ended an iteration.
#[derive(Debug, Clone, serde::Serialize)]
pub struct IterRecord {
    /// Seconds since the fitter's `start` (the run's start in the report).
    pub time_s: f64,
    pub phase: usize,
    pub iteration: usize,
    pub objective: f64,
    pub rel_error: f64,
    pub lights: usize,
    /// An iteration of the greedy placement's fits (on its subsample, before the main
    /// fit; `phase` then counts the placement's own phases).
    pub placement: bool,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct PhaseSummary {
    pub name: String,
    #[serde(flatten)]
    pub phase: Phase,
    pub iterations: usize,
    pub evaluations: usize,
    pub stop: Stop,
    pub time_s: f64,
    /// Of `time_s`, the seconds spent re-tracing shadows of lights that moved (and the sun).
    pub trace_s: f64,
    /// Shadow rays re-traced in the phase, counted as the report's `rays_traced` (rows times
    /// lights re-traced; 0 for the sampled estimator, which does not use the cache).
    pub rays: u64,
    pub rel_error_before: f64,
    pub rel_error_after: f64,
}

/// L-BFGS stops after three iterations that each lower the objective by less than this
/// fraction (1e-4 stopped the placement's fits early on oa_dm1: 0.44 instead of 0.39).
pub const LBFGS_REL_TOL: f64 = 1e-6;

/// A fitter's parameterisation, tolerances, clock and switches: what a fitter working for
/// another on other rows takes from it ([`Fitter::on_rows`], [`Fitter::run_phase_on_reach`]).
#[derive(Clone, Copy)]
struct Settings {
    codec: Codec,
    min_dist: f32,
    retrace_tol: f32,
    sun_retrace_tol: f32,
    start: Instant,
    deadline: Option<Instant>,
    frozen_emitters: bool,
    frozen_minlight: bool,
    kind_scales: bool,
}

pub struct Fitter<'a> {
    pub rows: &'a Rows,
    pub bases: &'a Bases,
    pub bvh: &'a Bvh,
    pub backend: &'a mut dyn Backend,
    pub vis: Visibility,
    pub model: Model,
    /// Per light: the user's lock (never changed by the fit).
    pub locked: Vec<bool>,
    pub codec: Codec,
    pub lo: Vec3,
    pub hi: Vec3,
    /// Lights keep at least this distance from surfaces, m.
    pub min_dist: f32,
    /// A light is re-traced when it moved more than this, m.
    pub retrace_tol: f32,
    /// The sun is re-traced when its direction turned more than this, radians.
    pub sun_retrace_tol: f32,
    pub history: Vec<IterRecord>,
    pub phases: Vec<PhaseSummary>,
    pub start: Instant,
    pub deadline: Option<Instant>,
    pub evaluations: usize,
    /// Seconds spent re-tracing visibility (`retrace`), over the fitter's life.
    pub trace_s: f64,
    pub phase_index: usize,
    /// Called after every iteration (progress display).
    pub on_iter: Option<Box<dyn FnMut(&IterRecord) + 'a>>,
    /// The first backend error; once set, evaluations return NaN and every loop stops.
    pub failure: Option<crate::error::Error>,
    /// The map's emitters (sun, sky, surface lights) keep their values.
    pub frozen_emitters: bool,
    /// The minlight keeps its value (the map recorded it).
    pub frozen_minlight: bool,
    /// The linear fit scales each kind of emitter as a whole ([`linear`]).
    pub kind_scales: bool,
    /// Most solves of a linear fit that takes the chain as local
    /// ([`linear::CHAIN_ROUNDS`]; 1: the one local solve).
    pub chain_rounds: usize,
    /// The terms' decisions (`pipeline::decide_terms`) take a term the model has on out
    /// without a refit where the error as it stands already decides (a refit can only
    /// lower it). Off: every decision refitted (the tests' reference).
    pub screen_decisions: bool,
    /// How many times [`Fitter::fit_linear`] ran.
    pub linear_fits: usize,
    /// Pruning does not refit a light's removal alone again while the error that removal
    /// reached when it failed lies above the bound ([`Fitter::prune`]). Off: every
    /// single try refitted (the tests' reference).
    pub remember_failed_singles: bool,
    /// How many single tries pruning decided from a failure it remembered, without a refit.
    pub singles_skipped: usize,
    /// The linear fit's recent light columns through the non-local chain, by their
    /// whole input ([`linear::ColumnCache`]).
    columns: linear::ColumnCache,
    /// The rows' word boxes: the linear fit's light columns leave out the words beyond a
    /// light's falloff cut (the same columns).
    boxes: visibility::WordBoxes,
}

/// What an evaluation of a model on a visibility ([`visibility::Snapshot`]) found: its
/// forward chain (a frozen evaluation) or the whole evaluation.
enum Known {
    Forward(visibility::Snapshot, model::Forward),
    Eval(visibility::Snapshot, Eval),
}

/// The least distance lights keep from surfaces in a light box from `lo` to `hi`, m: a
/// 500th of its diagonal, at least 5 cm.
pub fn min_dist(lo: Vec3, hi: Vec3) -> f32 {
    (0.002 * (hi - lo).length().max(1e-3)).max(0.05)
}

impl<'a> Fitter<'a> {
    pub fn new(rows: &'a Rows, bases: &'a Bases, bvh: &'a Bvh, backend: &'a mut dyn Backend, lo: Vec3, hi: Vec3) -> Fitter<'a> {
        let diag = (hi - lo).length().max(1e-3);
        Fitter {
            rows,
            bases,
            bvh,
            backend,
            vis: Visibility::default(),
            model: Model::default(),
            locked: Vec::new(),
            codec: Codec { center: (lo + hi) * 0.5, unit: 0.05 * diag },
            lo,
            hi,
            min_dist: min_dist(lo, hi),
            retrace_tol: (0.002 * diag).max(0.01),
            sun_retrace_tol: 1e-3,
            history: Vec::new(),
            phases: Vec::new(),
            start: Instant::now(),
            deadline: None,
            evaluations: 0,
            trace_s: 0.0,
            phase_index: 0,
            on_iter: None,
            failure: None,
            frozen_emitters: false,
            frozen_minlight: false,
            chain_rounds: linear::CHAIN_ROUNDS,
            screen_decisions: true,
            linear_fits: 0,
            remember_failed_singles: true,
            singles_skipped: 0,
            kind_scales: false,
            columns: linear::ColumnCache::default(),
            boxes: visibility::WordBoxes::of(rows),
        }
    }

    /// Runs `f` on a fitter over other rows at the same points (another reading of the
    /// same data: [`crate::rows::gamma`]) that starts where this one stands: its model,
    /// visibility (the rows' geometry is the same, so no ray is traced again), clock and
    /// switches. What `f` does there leaves this fitter as it was, bar the evaluations
    /// counted and a backend failure.
    pub fn on_rows<R>(&mut self, rows: &Rows, f: impl FnOnce(&mut Fitter) -> R) -> R {
        debug_assert_eq!(rows.len(), self.rows.len());
        let settings = self.settings();
        let mut t = Fitter::new(rows, self.bases, self.bvh, &mut *self.backend, self.lo, self.hi);
        t.vis = self.vis.clone();
        t.model = self.model.clone();
        t.locked = self.locked.clone();
        t.take_settings(settings);
        let r = f(&mut t);
        let (evaluations, failure) = (t.evaluations, t.failure.take());
        self.evaluations += evaluations;
        if self.failure.is_none() {
            self.failure = failure;
        }
        r
    }

    /// What a fitter working for this one on other rows takes from it
    /// ([`Fitter::take_settings`]).
    fn settings(&self) -> Settings {
        Settings { codec: self.codec, min_dist: self.min_dist, retrace_tol: self.retrace_tol, sun_retrace_tol: self.sun_retrace_tol, start: self.start, deadline: self.deadline, frozen_emitters: self.frozen_emitters, frozen_minlight: self.frozen_minlight, kind_scales: self.kind_scales }
    }

    /// Takes another fitter's parameterisation, tolerances, clock and switches.
    fn take_settings(&mut self, s: Settings) {
        (self.codec, self.min_dist, self.retrace_tol, self.sun_retrace_tol) = (s.codec, s.min_dist, s.retrace_tol, s.sun_retrace_tol);
        (self.start, self.deadline) = (s.start, s.deadline);
        (self.frozen_emitters, self.frozen_minlight, self.kind_scales) = (s.frozen_emitters, s.frozen_minlight, s.kind_scales);
    }

    /// True when the time limit passed or the backend failed: every loop stops.
    pub fn out_of_time(&self) -> bool {
        self.failure.is_some() || self.deadline.is_some_and(|d| Instant::now() >= d)
    }

    pub fn add_light(&mut self, l: Light, locked: bool) {
        self.model.lights.push(l);
        self.locked.push(locked);
    }

    /// Removes light `j` (keeps the visibility cache aligned).
    pub fn remove_light(&mut self, j: usize) {
        self.model.lights.remove(j);
        self.locked.remove(j);
        if j < self.vis.bits.len() {
            self.vis.remove(j);
        }
    }

    /// Brings the visibility up to date with `m` (lights that moved, the sun if it turned).
    fn retrace(&mut self, m: &Model) -> crate::error::Result<()> {
        let t0 = Instant::now();
        let r = self.retrace_untimed(m);
        self.trace_s += t0.elapsed().as_secs_f64();
        r
    }

    fn retrace_untimed(&mut self, m: &Model) -> crate::error::Result<()> {
        let n = self.rows.len();
        let (bvh, rows, sky) = (self.bvh, self.rows, &self.bases.sky_triangles);
        let backend = &mut *self.backend;
        self.vis.update_sun(m.sun.map(|s| s.to_sun), self.sun_retrace_tol, n, &mut |d| Ok(crate::backend::sun_bits(&mut *backend, bvh, rows, &[d], sky)?.into_iter().next().unwrap_or_default()))?;
        self.vis.update(&crate::model::lights::sources(&m.lights), self.retrace_tol, &self.rows.sampling, n, &mut |p| backend.trace(p)).map(|_| ())
    }

    /// Re-traces what moved, without evaluating the objective.
    pub fn refresh_visibility(&mut self) {
        if self.failure.is_some() {
            return;
        }
        let m = self.model.clone();
        if let Err(e) = self.retrace(&m) {
            self.failure = Some(e);
        }
    }

    /// Objective without penalties for the current model (re-traces what moved).
    pub fn eval(&mut self) -> Eval {
        let m = self.model.clone();
        self.eval_model(&m)
    }

    pub fn eval_model(&mut self, m: &Model) -> Eval {
        self.eval_model_knowing(m, None)
    }

    /// [`Fitter::eval_model`] where part of the answer may be known already (`known`, for
    /// `m` on the visibility it names): taken where the re-trace leaves that visibility as
    /// it was, for the same result without computing it again.
    fn eval_model_knowing(&mut self, m: &Model, known: Option<Known>) -> Eval {
        if self.failure.is_some() {
            return Eval::failed(m);
        }
        let r = self.retrace(m).and_then(|_| {
            self.evaluations += 1;
            match known {
                Some(Known::Forward(at, fw)) if self.vis.is(&at) => model::evaluate_from(m, self.rows, self.bases, &self.vis, self.backend, fw),
                Some(Known::Eval(at, ev)) if self.vis.is(&at) => Ok(ev),
                _ => model::evaluate(m, self.rows, self.bases, &self.vis, self.backend),
            }
        });
        match r {
            Ok(ev) => ev,
            Err(e) => {
                self.failure = Some(e);
                Eval::failed(m)
            }
        }
    }

    /// The objective and error of the current model without the gradient (re-traces what
    /// moved): what a linear refit needs to know where it landed.
    pub fn value(&mut self) -> Eval {
        self.value_and_forward().0
    }

    /// [`Fitter::value`] and the forward chain it ran (`None` after a failure): the
    /// linear fit's next round needs the same model's radiance.
    fn value_and_forward(&mut self) -> (Eval, Option<model::Forward>) {
        let m = self.model.clone();
        if self.failure.is_some() {
            return (Eval::failed(&m), None);
        }
        let r = self.retrace(&m).and_then(|_| {
            self.evaluations += 1;
            model::value_and_forward(&m, self.rows, self.bases, &self.vis, self.backend)
        });
        match r {
            Ok((ev, fw)) => (ev, Some(fw)),
            Err(e) => {
                self.failure = Some(e);
                (Eval::failed(&m), None)
            }
        }
    }

    /// The objective and error of `m` (no gradient) with the visibility cache as it is (no
    /// re-trace): a line-search trial.
    pub fn value_frozen(&mut self, m: &Model) -> Eval {
        self.value_frozen_and_forward(m).0
    }

    /// [`Fitter::value_frozen`] and the forward chain it ran (`None` where it re-traced
    /// or failed): the linear fit's first round needs the entry's radiance.
    fn value_frozen_and_forward(&mut self, m: &Model) -> (Eval, Option<model::Forward>) {
        if self.failure.is_some() || self.vis.bits.len() != m.lights.len() || self.vis.sun.is_some() != m.sun.is_some() {
            return (self.eval_model(m), None);
        }
        self.evaluations += 1;
        match model::value_and_forward(m, self.rows, self.bases, &self.vis, self.backend) {
            Ok((ev, fw)) => (ev, Some(fw)),
            Err(e) => {
                self.failure = Some(e);
                (Eval::failed(m), None)
            }
        }
    }

    /// Penalty value and its gradient with respect to each light position (per meter).
    pub fn penalty(&self, lights: &[Light]) -> (f64, Vec<Vec3>) {
        let f0 = 0.5 * self.rows.norm2.max(1e-30);
        let mut total = 0.0;
        let mut grads = vec![Vec3::ZERO; lights.len()];
        let unit = self.codec.unit;
        // The nearest surface of each light on all cores (a BVH query each: a fifth of what
        // oa_dm1's placement did on its main thread alone, once the forward chain's loops
        // ran on all cores); summed in order, the same bits. Only a surface nearer than
        // `min_dist` counts, so the query looks no farther (9% of oacmpdm3's run with 256
        // lights went to the unbounded one).
        let nearest: Vec<Option<(f32, Vec3)>> = {
            use rayon::prelude::*;
            let (bvh, min_dist) = (self.bvh, self.min_dist);
            lights.par_iter().map(|l| bvh.nearest_within(l.pos, min_dist)).collect()
        };
        for (j, l) in lights.iter().enumerate() {
            if let Some((dist, near)) = nearest[j] {
                if dist < self.min_dist {
                    let u = 1.0 - dist / self.min_dist;
                    total += f0 * (u * u) as f64;
                    let dir = (l.pos - near).try_normalize().unwrap_or(Vec3::ZERO);
                    grads[j] += dir * (-2.0 * u / self.min_dist * f0 as f32);
                }
            }
            for a in 0..3 {
                let below = self.lo[a] - l.pos[a];
                let above = l.pos[a] - self.hi[a];
                if below > 0.0 {
                    total += f0 * ((below / unit) as f64).powi(2);
                    grads[j][a] -= 2.0 * below / (unit * unit) * f0 as f32;
                }
                if above > 0.0 {
                    total += f0 * ((above / unit) as f64).powi(2);
                    grads[j][a] += 2.0 * above / (unit * unit) * f0 as f32;
                }
            }
        }
        (total, grads)
    }

    /// [`Fitter::run_phase`] moving only the lights `js` (position, intensity, colour), on
    /// the rows they reach where the phase starts; every other light and term is held
    /// ([`Bases::held`]). An evaluation then costs what those lights light, not the whole
    /// map: the greedy placement refits one new light at a time on a map of a hundred
    /// rooms. The objective leaves out the rows outside that reach (they are held
    /// constant: a light that moves into sight of them is neither paid nor charged for it
    /// there), so the caller judges the result on all rows (the placement solves every
    /// intensity after it and undoes a refit that made things worse).
    ///
    /// `rel_error_now` is the whole model's relative error as the phase finds it (the
    /// caller's last solve): the records and the summary add the rows outside the reach to
    /// the errors they report, so that they read as the whole model's. Where the model's
    /// chain spreads light between rows (a filter or a bounce on these rows), this is
    /// [`Fitter::run_phase_moving`]. The phase runs on the CPU (the placement's backend),
    /// whatever this fitter's backend.
    pub fn run_phase_on_reach(&mut self, name: &str, phase: Phase, js: &[usize], rel_error_now: f64) -> PhaseSummary {
        let spreads = self.bases.filter.is_some() || self.bases.bounce.is_some();
        if spreads || self.failure.is_some() {
            return self.run_phase_moving(name, phase, js);
        }
        self.refresh_visibility();
        let n = self.model.lights.len();
        let js: Vec<usize> = (0..n).filter(|j| js.contains(j)).collect();
        let held: Vec<usize> = (0..n).filter(|j| !js.contains(j)).collect();
        let reach = self.vis.reached_rows(&js);
        let rows = self.rows.subset(&reach);
        let mut bases = self.bases.subset(&reach);
        let mut cpu = crate::backend::Cpu::new(&rows, self.bvh);
        // What the held lights and the other emitters give the reach, through the chain
        // and before the floor; the gathered term comes after the floor, out of the data.
        let held_vis = self.vis.select_rows(&held, &reach);
        let held_model = Model { lights: held.iter().map(|&j| self.model.lights[j]).collect(), minlight: None, gathered: None, ..self.model.clone() };
        let e = if held.is_empty() {
            vec![[0.0f32; 3]; rows.len()]
        } else {
            match cpu.irradiance(&held_vis, &held_model.lights) {
                Ok(e) => e,
                Err(err) => {
                    self.failure = Some(err);
                    return self.run_phase_moving(name, phase, &js);
                }
            }
        };
        bases.held = Some(model::forward(&held_model, &rows, &bases, &held_vis, &e).total);
        let gathered: Vec<[f64; 3]> = match (self.model.gathered, &bases.gathered) {
            (Some(k), Some(o)) => o.iter().map(|o| [0, 1, 2].map(|c| k[c] as f64 * o[c] as f64)).collect(),
            _ => vec![[0.0; 3]; rows.len()],
        };
        let mut left = rows.less(&gathered);
        // The penalties keep the whole data's scale (they are relative to its unlit objective).
        left.norm2 = self.rows.norm2;
        let part = Model { lights: js.iter().map(|&j| self.model.lights[j]).collect(), minlight: self.model.minlight, ..self.model.chain_only() };
        let mut t = Fitter::new(&left, &bases, self.bvh, &mut cpu, self.lo, self.hi);
        t.take_settings(self.settings());
        // The floor is the whole model's, not the part's to move.
        t.frozen_minlight = true;
        t.model = part;
        t.locked = js.iter().map(|&j| self.locked[j]).collect();
        t.vis = self.vis.select_rows(&js, &reach);
        t.phase_index = self.phase_index;
        let mut summary = t.run_phase(name, phase);
        let (part, part_vis, history, trace_s, phase_index, evaluations) = (std::mem::take(&mut t.model), std::mem::take(&mut t.vis), std::mem::take(&mut t.history), t.trace_s, t.phase_index, t.evaluations);
        if let Some(err) = t.failure.take() {
            self.failure.get_or_insert(err);
        }
        drop(t);
        // The rows outside the reach, in the error's units (squared, relative): what the
        // whole model's error adds to the part's at the start.
        let outside = (rel_error_now.powi(2) - summary.rel_error_before.powi(2)).max(0.0);
        let whole = |e: f64| (e * e + outside).sqrt();
        let f_outside = 0.5 * outside * self.rows.norm2;
        summary.rel_error_before = whole(summary.rel_error_before);
        summary.rel_error_after = whole(summary.rel_error_after);
        for (&j, l) in js.iter().zip(&part.lights) {
            self.model.lights[j] = *l;
        }
        // A light re-traced on the reach has no bits for the other rows: traced again when
        // the caller next refreshes. The others keep their whole bits.
        for (k, &j) in js.iter().enumerate() {
            if part_vis.traced_at[k] != self.vis.traced_at[j] || part_vis.traced_reach[k] != self.vis.traced_reach[j] {
                self.vis.traced_at[j] = Vec3::INFINITY;
            }
        }
        self.vis.rays += part_vis.rays;
        self.evaluations += evaluations;
        self.history.extend(history.into_iter().map(|r| IterRecord { lights: n, rel_error: whole(r.rel_error), objective: r.objective + f_outside, ..r }));
        self.trace_s += trace_s;
        self.phase_index = phase_index;
        self.phases.push(summary.clone());
        summary
    }

    /// [`Fitter::run_phase`] moving only the lights `js` (with the model's terms), the other
    /// lights held as they are. Where the model's radiance is the sum of its lights' (no
    /// minlight floor across them, no bounce whose scale the phase moves), the held
    /// lights' radiance is taken out of the data ([`Rows::less`]) and the phase runs on
    /// the lights `js` alone, so that an evaluation, its gradient and its re-traces cost
    /// those lights only; the objective and the error are the whole model's all the same.
    /// Otherwise the held lights are locked for the phase (the same fit, at the whole
    /// model's cost).
    pub fn run_phase_moving(&mut self, name: &str, phase: Phase, js: &[usize]) -> PhaseSummary {
        let n = self.model.lights.len();
        let moving: Vec<bool> = (0..n).map(|j| js.contains(&j)).collect();
        // The chain (filter, dirt) is linear in the lights' irradiance; the bounce too, but
        // its scale may move in the phase, and the held lights' bounced light with it.
        let chain_is_linear = self.model.minlight.is_none() && (self.model.bounce.is_none() || self.bases.bounce.is_none());
        self.refresh_visibility();
        if !chain_is_linear || self.failure.is_some() {
            let (keep, before) = (self.locked.clone(), self.model.lights.clone());
            self.locked.iter_mut().zip(&moving).for_each(|(l, &m)| *l = *l || !m);
            let s = self.run_phase(name, phase);
            self.locked = keep;
            // Masked out, the held lights moved by the parameters' rounding only: as they were.
            for (j, l) in before.into_iter().enumerate().filter(|&(j, _)| !moving[j]) {
                self.model.lights[j] = l;
            }
            return s;
        }
        let js: Vec<usize> = (0..n).filter(|&j| moving[j]).collect();
        let held: Vec<usize> = (0..n).filter(|&j| !moving[j]).collect();
        let held_lights: Vec<Light> = held.iter().map(|&j| self.model.lights[j]).collect();
        let e = if held.is_empty() {
            vec![[0.0f32; 3]; self.rows.len()]
        } else {
            match self.backend.irradiance(&self.vis.select(&held), &held_lights) {
                Ok(e) => e,
                Err(err) => {
                    self.failure = Some(err);
                    return self.run_phase(name, phase);
                }
            }
        };
        // The held lights' radiance: their irradiance through the model's chain alone.
        let x_held = model::forward(&self.model.chain_only(), self.rows, self.bases, &self.vis, &e).x;
        let left = self.rows.less(&x_held);
        let part = Model { lights: js.iter().map(|&j| self.model.lights[j]).collect(), ..self.model.clone() };
        let part_locked: Vec<bool> = js.iter().map(|&j| self.locked[j]).collect();
        let part_vis = self.vis.select(&js);
        let phase_index = self.phase_index;
        let (model, vis, history, summary, trace_s, phase_index) = self.on_rows(&left, |t| {
            t.model = part;
            t.locked = part_locked;
            t.vis = part_vis;
            t.phase_index = phase_index;
            let s = t.run_phase(name, phase);
            (std::mem::take(&mut t.model), std::mem::take(&mut t.vis), std::mem::take(&mut t.history), s, t.trace_s, t.phase_index)
        });
        let mut lights = std::mem::take(&mut self.model.lights);
        for (&j, l) in js.iter().zip(&model.lights) {
            lights[j] = *l;
        }
        self.model = Model { lights, ..model };
        self.vis.put_back(&js, vis);
        // The records count the whole model's lights, not the part's.
        self.history.extend(history.into_iter().map(|r| IterRecord { lights: n, ..r }));
        self.trace_s += trace_s;
        self.phase_index = phase_index;
        self.phases.push(summary.clone());
        summary
    }

    /// Runs one phase; returns its summary (also appended to `phases`).
    pub fn run_phase(&mut self, name: &str, phase: Phase) -> PhaseSummary {
        let t0 = Instant::now();
        let (trace0, rays0) = (self.trace_s, self.vis.rays);
        let start_eval = self.eval();
        let start_vis = self.vis.clone();
        let before = start_eval.rel_error;
        let start = (self.model.clone(), start_eval.f + self.penalty(&self.model.lights).0);
        let x0 = self.codec.encode(&self.model);
        let mask = self.codec.mask(&self.model, &self.locked, phase.params, self.frozen_emitters, self.frozen_minlight);
        let layout = self.model.clone();
        let phase_no = self.phase_index;
        let sampled = self.backend.rays_traced().is_some();
        self.phase_index += 1;
        let last_err = std::cell::Cell::new(before);
        // The last evaluation's point and what it knew there: a trial's forward chain (the
        // accepted trial is evaluated afresh next, and where no light is re-traced there
        // its irradiance and chain are the trial's), or a fresh evaluation (the phase ends
        // at its best point, mostly its last, and evaluates it again). Not on a sampled
        // objective (the light-tracing estimator): there each evaluation draws its own
        // light paths, and the fresh one must not take the trial's.
        let last = std::cell::RefCell::new(None::<(Vec<f64>, Known)>);
        let remember = |x: &[f64], k: Option<Known>| *last.borrow_mut() = k.map(|k| (x.to_vec(), k));
        let at = |x: &[f64]| last.borrow_mut().take().filter(|(p, _)| p.len() == x.len() && p.iter().zip(x).all(|(a, b)| a.to_bits() == b.to_bits())).map(|(_, k)| k);
        let outcome = {
            let this = std::cell::RefCell::new(&mut *self);
            let mut objective = |x: &[f64], fresh: bool| -> (f64, Vec<f64>) {
                let mut me = this.borrow_mut();
                let m = me.codec.decode(&layout, x);
                // A line-search trial needs the value only.
                let ev = if fresh {
                    let ev = me.eval_model_knowing(&m, at(x));
                    remember(x, (!sampled).then(|| Known::Eval(me.vis.snapshot(), ev.clone())));
                    ev
                } else {
                    let (ev, fw) = me.value_frozen_and_forward(&m);
                    remember(x, fw.filter(|_| !sampled).map(|fw| Known::Forward(me.vis.snapshot(), fw)));
                    ev
                };
                let (pen, pgrad) = me.penalty(&m.lights);
                last_err.set(ev.rel_error);
                let g = if !fresh {
                    Vec::new()
                } else if ev.f.is_finite() {
                    me.codec.gradient(&m, x, &ev, &pgrad)
                } else {
                    vec![0.0; x.len()]
                };
                (ev.f + pen, g)
            };
            let mut observe = |it: usize, f: f64| -> bool {
                let mut me = this.borrow_mut();
                let rec = IterRecord { time_s: me.start.elapsed().as_secs_f64(), phase: phase_no, iteration: it, objective: f, rel_error: last_err.get(), lights: me.model.lights.len(), placement: false };
                if let Some(cb) = me.on_iter.as_mut() {
                    cb(&rec);
                }
                me.history.push(rec);
                !me.out_of_time()
            };
            match phase.algorithm {
                // On a sampled objective (the light-tracing estimator) two evaluations 20
                // iterations apart can agree by chance: there Adam runs to its limit, as
                // in the thesis ("it never terminates").
                Algorithm::Adam { step } => optim::adam(&x0, &mask, step, phase.max_iterations, if sampled { optim::NEVER } else { 1e-5 }, &mut objective, &mut observe),
                Algorithm::Lbfgs { step } => optim::lbfgs(&x0, &mask, step, phase.max_iterations, LBFGS_REL_TOL, &mut objective, &mut observe),
            }
        };
        self.model = self.codec.decode(&layout, &outcome.x);
        let mut end_eval = {
            let m = self.model.clone();
            self.eval_model_knowing(&m, at(&outcome.x))
        };
        if !(end_eval.f + self.penalty(&self.model.lights).0 <= start.1) {
            // Undone: the start's model with the shadows it was evaluated with. Re-tracing
            // would not give them back: a light is re-traced only beyond the tolerance, so
            // the cache may hold another position's shadows within it (on `suspended` the
            // start re-evaluated 1.3% above itself, and the phase seemed to end worse).
            let rays = self.vis.rays;
            self.model = start.0;
            self.vis = start_vis;
            self.vis.rays = rays;
            end_eval = start_eval;
        }
        let s = PhaseSummary {
            name: name.to_string(),
            phase,
            iterations: outcome.iterations,
            evaluations: outcome.evaluations,
            stop: outcome.stop,
            time_s: t0.elapsed().as_secs_f64(),
            trace_s: self.trace_s - trace0,
            rays: self.vis.rays.saturating_sub(rays0),
            rel_error_before: before,
            rel_error_after: end_eval.rel_error,
        };
        self.phases.push(s.clone());
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::Cpu;
    use crate::model::Bases;
    use crate::testutil::{data_from_model, room};

    /// A room lit by four lights and an ambient through dirt and a filter, its data another
    /// four lights' radiance with some channels censored, and a fitter over it.
    fn four_lights() -> (crate::scene::Mesh, Rows, Bases, Model) {
        let (mesh, mut rows) = room(8);
        let n = rows.len();
        let bases = Bases { dirt: vec![crate::model::compile::DirtBasis { settings: crate::scene::DirtSettings::Q3MAP2, factor: (0..n).map(|i| 0.7 + 0.03 * (i % 10) as f32).collect() }], filter: crate::testutil::chain_bases(n, 0).filter, ..Bases::default() };
        let at = |x: f32, y: f32, z: f32, i: f32| Light::point(Vec3::new(x, y, z), [i, 0.8 * i, 0.6 * i]);
        let truth = Model { lights: vec![at(0.7, 1.9, 0.6, 4.0), at(3.2, 1.7, 0.8, 3.0), at(1.1, 0.6, 2.4, 2.0), at(3.3, 2.0, 2.5, 5.0)], dirt: Some(crate::scene::DirtSettings::Q3MAP2), filter: true, ambient: Some([0.05; 3]), ..Model::default() };
        let bvh = Bvh::build(&mesh);
        data_from_model(&mut rows, &bases, &bvh, &truth, 0.01);
        for i in (0..n).step_by(7) {
            rows.lower[i] = rows.lo[i];
            rows.weight[i] = [0.0; 3];
        }
        rows.finish();
        let start = Model { lights: vec![at(0.9, 1.8, 0.7, 3.0), at(3.0, 1.6, 1.0, 3.0), at(1.3, 0.8, 2.2, 3.0), at(3.0, 1.8, 2.3, 3.0)], ambient: Some([0.08; 3]), ..truth };
        (mesh, rows, bases, start)
    }

    /// A phase that moves two of four lights sees the whole model's objective (its start
    /// is the whole model's error, to rounding), leaves the other two exactly as they
    /// were, ends no worse than it began, and leaves the visibility cache as a re-trace
    /// would (the state's error afterwards is the phase's last).
    #[test]
    fn a_phase_moving_some_lights_fits_the_whole_objective_and_holds_the_rest() {
        let (mesh, rows, bases, start) = four_lights();
        let bvh = Bvh::build(&mesh);
        let (lo, hi) = mesh.bounds();
        let mut cpu = Cpu::new(&rows, &bvh);
        let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
        fit.model = start.clone();
        fit.locked = vec![false; 4];
        let whole = fit.eval().rel_error;
        let lbfgs = |its| Phase { algorithm: Algorithm::Lbfgs { step: 0.5 }, params: ParamSet::ALL, max_iterations: its };
        let s0 = fit.run_phase_moving("none", lbfgs(0), &[1, 3]);
        assert!((s0.rel_error_before - whole).abs() <= 1e-6 * whole, "the part's start {} is not the whole model's {whole}", s0.rel_error_before);
        let s = fit.run_phase_moving("two", lbfgs(20), &[1, 3]);
        assert!(s.rel_error_after < whole - 1e-3, "the phase did not fit: {whole} -> {}", s.rel_error_after);
        for j in [0, 2] {
            assert_eq!(fit.model.lights[j], start.lights[j], "held light {j} changed");
        }
        for j in [1, 3] {
            assert!(fit.model.lights[j].pos.distance(start.lights[j].pos) > 1e-3, "light {j} did not move");
        }
        let after = fit.eval().rel_error;
        assert!((after - s.rel_error_after).abs() <= 1e-6 * after, "the state's error {after} is not the phase's last {}", s.rel_error_after);
        assert_eq!(fit.vis.bits.len(), 4);
        assert!(!fit.history.is_empty() && fit.history.iter().all(|r| r.lights == 4), "the history counts the whole model's lights");
        drop(fit);

        // With a minlight floor the radiance is not a sum of parts: the held lights are
        // locked instead, with the same promises.
        let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
        fit.model = Model { minlight: Some([0.02; 3]), ..start.clone() };
        fit.locked = vec![false; 4];
        let whole = fit.eval().rel_error;
        let s = fit.run_phase_moving("locked", lbfgs(20), &[1, 3]);
        assert!(s.rel_error_before == whole && s.rel_error_after < whole - 1e-3, "{whole}: {} -> {}", s.rel_error_before, s.rel_error_after);
        for j in [0, 2] {
            assert_eq!(fit.model.lights[j], start.lights[j], "held light {j} changed (locked)");
        }
        assert_eq!(fit.locked, vec![false; 4], "the locks are given back");
    }

    /// The room split by a wall at x = 2 (floor to ceiling, front to back), two lights on
    /// each side, through dirt and an ambient (no filter: its light would cross the
    /// wall's rows); the data another four lights' radiance.
    fn two_rooms() -> (crate::scene::Mesh, Rows, Bases, Model) {
        let (mut mesh, mut rows) = room(8);
        crate::testutil::push_quad(&mut mesh, [[2.0, 0.0, 0.0], [2.0, 2.5, 0.0], [2.0, 2.5, 3.0], [2.0, 0.0, 3.0]], Vec3::X);
        let n = rows.len();
        let bases = Bases { dirt: vec![crate::model::compile::DirtBasis { settings: crate::scene::DirtSettings::Q3MAP2, factor: (0..n).map(|i| 0.7 + 0.03 * (i % 10) as f32).collect() }], ..Bases::default() };
        let at = |x: f32, y: f32, z: f32, i: f32| Light::point(Vec3::new(x, y, z), [i, 0.8 * i, 0.6 * i]);
        let truth = Model { lights: vec![at(0.7, 1.9, 0.6, 4.0), at(1.2, 1.2, 2.2, 3.0), at(3.1, 0.6, 2.4, 2.0), at(3.3, 2.0, 0.9, 5.0)], dirt: Some(crate::scene::DirtSettings::Q3MAP2), ambient: Some([0.05; 3]), ..Model::default() };
        let bvh = Bvh::build(&mesh);
        data_from_model(&mut rows, &bases, &bvh, &truth, 0.01);
        let start = Model { lights: vec![at(0.8, 1.8, 0.7, 3.0), at(1.5, 1.0, 1.8, 2.0), at(3.0, 0.8, 2.2, 3.0), at(3.0, 1.8, 1.1, 3.0)], ambient: Some([0.08; 3]), ..truth };
        (mesh, rows, bases, start)
    }

    /// A phase on the moving lights' reach sees the whole model there (its start is the
    /// whole model's error once the rows outside are added back, to rounding, with and
    /// without a minlight floor across the lights), fits, moves only its lights, runs on
    /// fewer rows than the map has, and hands back a cache that the next refresh re-traces
    /// where it must (the state's error is then the phase's last: the light stayed on its
    /// side of the wall).
    #[test]
    fn a_phase_on_the_reach_fits_the_whole_model_there() {
        let (mesh, rows, bases, start) = two_rooms();
        let bvh = Bvh::build(&mesh);
        let (lo, hi) = mesh.bounds();
        let lbfgs = |its| Phase { algorithm: Algorithm::Lbfgs { step: 0.5 }, params: ParamSet::ALL, max_iterations: its };
        for minlight in [None, Some([0.12f32; 3])] {
            let mut cpu = Cpu::new(&rows, &bvh);
            let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
            fit.model = Model { minlight, ..start.clone() };
            fit.locked = vec![false; 4];
            let whole = fit.eval().rel_error;
            let reach = fit.vis.reached_rows(&[1]);
            assert!(reach.len() > rows.len() / 4 && reach.len() < rows.len() * 3 / 4, "light 1 reaches {} of {} rows", reach.len(), rows.len());
            let s0 = fit.run_phase_on_reach("none", lbfgs(0), &[1], whole);
            assert!((s0.rel_error_before - whole).abs() <= 1e-6 * whole, "{minlight:?}: the part's start {} is not the whole model's {whole}", s0.rel_error_before);
            let s = fit.run_phase_on_reach("one", lbfgs(20), &[1], whole);
            assert!(s.rel_error_after < whole - 1e-3, "{minlight:?}: the phase did not fit: {whole} -> {}", s.rel_error_after);
            for j in [0, 2, 3] {
                assert_eq!(fit.model.lights[j], start.lights[j], "held light {j} changed");
            }
            assert_eq!(fit.model.minlight, minlight, "the floor is held");
            assert_eq!(fit.model.ambient, start.ambient, "the ambient is held");
            assert!(fit.model.lights[1].pos.distance(start.lights[1].pos) > 1e-3, "light 1 did not move");
            assert!(fit.model.lights[1].pos.x < 2.0, "light 1 crossed the wall");
            fit.refresh_visibility();
            assert_eq!(fit.vis.traced_at[1], fit.model.lights[1].pos, "the moved light was traced again over all rows");
            let after = fit.eval().rel_error;
            assert!((after - s.rel_error_after).abs() <= 1e-3 * after, "{minlight:?}: the state's error {after} is not the phase's last {}", s.rel_error_after);
            assert!(fit.history.iter().all(|r| r.lights == 4 && r.rel_error >= s.rel_error_after - 1e-9), "the records are the whole model's");
        }
        // A light outside the rooms (its cache cleared: the rows on the walls' edges see
        // past them) reaches no row: a phase on no rows ends where it began.
        let mut cpu = Cpu::new(&rows, &bvh);
        let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
        fit.model = start.clone();
        fit.model.lights.push(Light::point(Vec3::new(-1.0, 1.0, 1.0), [1.0; 3]));
        fit.locked = vec![false; 5];
        fit.refresh_visibility();
        std::sync::Arc::make_mut(&mut fit.vis.bits[4]).iter_mut().for_each(|w| *w = 0);
        let whole = fit.eval().rel_error;
        assert!(fit.vis.reached_rows(&[4]).is_empty());
        let s = fit.run_phase_on_reach("none reached", lbfgs(20), &[4], whole);
        assert!(s.rel_error_before.is_finite() && s.rel_error_after.is_finite() && (s.rel_error_before - whole).abs() <= 1e-9, "{whole}: {} -> {}", s.rel_error_before, s.rel_error_after);
        assert_eq!(&fit.model.lights[..4], &start.lights[..], "the held lights stay");
    }
}
