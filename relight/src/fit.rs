//! The optimisation state: lights, their parameterisation, penalties, phases, the exact
//! intensity fit, and the pruning and merging of lights.
//!
//! Parameters per light (7): position `q` in units of `unit` meters around the scene
//! centre, log intensity `s`, log colour `g_c`; `I_c = exp(s + g_c)` is positive by
//! construction. The optional global terms ([`Globals`]) add 3 parameters each: the
//! ambient `a_c` as a logarithm, the indirect scale `k_c` in (0, 1) as a logit (the data's
//! bounced light can be present in full, `k = 1`, or scaled down, as q3map2's
//! `-bouncescale` does, but never more: above 1 the term would only imitate the target's
//! shape); the sun adds 6: elevation `theta` and
//! azimuth `phi` of its direction `w = (cos theta cos phi, sin theta, cos theta sin phi)`
//! (radians, glTF's Y up), then log intensity and log colour like a light.
//! Penalties (scaled to the objective of an unlit scene `F0`): a light closer than
//! `min_dist` to a surface pays `F0 (1 - dist/min_dist)^2`; a light outside the scene's box
//! pays `F0 (outside/unit)^2` per axis.

use std::time::Instant;

use glam::Vec3;

use crate::backend::Backend;
use crate::bvh::Bvh;
use crate::model::{Eval, Light, Problem, Sun, Terms};
use crate::optim::{self, Stop};
use crate::visibility::Visibility;

const PER_LIGHT: usize = 7;

/// The model's optional global terms: `None` where the model leaves a term out.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Globals {
    /// Ambient irradiance / pi per channel.
    pub ambient: Option<[f32; 3]>,
    /// Scale of the gathered indirect radiance per channel.
    pub indirect: Option<[f32; 3]>,
    /// A directional light.
    pub sun: Option<Sun>,
}

impl Globals {
    pub fn terms(&self) -> Terms {
        Terms { ambient: self.ambient.unwrap_or([0.0; 3]), indirect: self.indirect.unwrap_or([0.0; 3]), sun: self.sun }
    }
}

/// `(theta, phi)` of a unit direction (see the module docs).
pub fn sun_angles(w: Vec3) -> (f64, f64) {
    let w = w.as_dvec3().normalize_or(glam::DVec3::Y);
    (w.y.clamp(-1.0, 1.0).asin(), w.z.atan2(w.x))
}

/// The direction of `(theta, phi)` and its derivatives by theta and by phi.
pub fn sun_direction(theta: f64, phi: f64) -> (Vec3, glam::DVec3, glam::DVec3) {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    (glam::DVec3::new(ct * cp, st, ct * sp).as_vec3(), glam::DVec3::new(-st * cp, ct, -st * sp), glam::DVec3::new(-ct * sp, 0.0, ct * cp))
}

/// Which light parameters a phase changes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct ParamSet {
    pub position: bool,
    pub intensity: bool,
    pub color: bool,
}

impl ParamSet {
    pub const ALL: ParamSet = ParamSet { position: true, intensity: true, color: true };
    pub const POSITION: ParamSet = ParamSet { position: true, intensity: false, color: false };
    pub const INTENSITY_COLOR: ParamSet = ParamSet { position: false, intensity: true, color: true };
    pub fn label(&self) -> String {
        let mut v = Vec::new();
        if self.position {
            v.push("position");
        }
        if self.intensity {
            v.push("intensity");
        }
        if self.color {
            v.push("color");
        }
        v.join("+")
    }
}

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
    pub rel_error_before: f64,
    pub rel_error_after: f64,
}

pub struct Fitter<'a> {
    pub pb: &'a Problem,
    pub bvh: &'a Bvh,
    pub backend: &'a mut dyn Backend,
    pub vis: Visibility,
    pub lights: Vec<Light>,
    pub locked: Vec<bool>,
    pub globals: Globals,
    /// Position parameter unit, m.
    pub unit: f32,
    pub center: Vec3,
    pub lo: Vec3,
    pub hi: Vec3,
    /// Lights keep at least this distance from surfaces, m.
    pub min_dist: f32,
    /// A light is re-traced when it moved more than this, m.
    pub retrace_tol: f32,
    pub history: Vec<IterRecord>,
    pub phases: Vec<PhaseSummary>,
    pub start: Instant,
    pub deadline: Option<Instant>,
    pub evaluations: usize,
    pub phase_index: usize,
    /// Called after every iteration (progress display).
    pub on_iter: Option<Box<dyn FnMut(&IterRecord) + 'a>>,
    /// The first backend error; once set, evaluations return NaN and every loop stops.
    pub failure: Option<crate::error::Error>,
    /// Sky flag of every mesh triangle: sunlight passes sky surfaces.
    pub sky: Vec<bool>,
    /// The sun is re-traced when its direction turned more than this, radians.
    pub sun_retrace_tol: f32,
}

impl<'a> Fitter<'a> {
    pub fn new(pb: &'a Problem, bvh: &'a Bvh, backend: &'a mut dyn Backend, lo: Vec3, hi: Vec3) -> Fitter<'a> {
        let diag = (hi - lo).length().max(1e-3);
        Fitter {
            pb,
            bvh,
            backend,
            vis: Visibility::default(),
            lights: Vec::new(),
            locked: Vec::new(),
            globals: Globals::default(),
            unit: 0.05 * diag,
            center: (lo + hi) * 0.5,
            lo,
            hi,
            min_dist: (0.002 * diag).max(0.05),
            retrace_tol: (0.002 * diag).max(0.01),
            history: Vec::new(),
            phases: Vec::new(),
            start: Instant::now(),
            deadline: None,
            evaluations: 0,
            phase_index: 0,
            on_iter: None,
            failure: None,
            sky: Vec::new(),
            sun_retrace_tol: 1e-3,
        }
    }

    /// True when the time limit passed or the backend failed: every loop stops.
    pub fn out_of_time(&self) -> bool {
        self.failure.is_some() || self.deadline.is_some_and(|d| Instant::now() >= d)
    }

    /// Objective without penalties, at the current lights (re-traces what moved).
    pub fn eval(&mut self) -> Eval {
        self.eval_lights(&self.lights.clone(), self.globals)
    }

    pub fn eval_lights(&mut self, lights: &[Light], globals: Globals) -> Eval {
        let n = self.pb.len();
        let failed = Eval { f: f64::NAN, rel_error: f64::NAN, grad: vec![[0.0; 6]; lights.len()], ..Default::default() };
        if self.failure.is_some() {
            return failed;
        }
        let backend = &mut *self.backend;
        let (bvh, pb, sky) = (self.bvh, self.pb, &self.sky);
        self.vis.update_sun(globals.sun.map(|s| s.to_sun), self.sun_retrace_tol, n, &mut |d| crate::visibility::trace_sun(bvh, pb, d, sky));
        let r = self.vis.update(lights, self.retrace_tol, n, &mut |p| backend.trace(p)).and_then(|_| {
            self.evaluations += 1;
            self.backend.evaluate(&self.vis, lights, globals.terms())
        });
        match r {
            Ok(ev) => ev,
            Err(e) => {
                self.failure = Some(e);
                failed
            }
        }
    }

    /// Re-traces the lights that moved, without evaluating the objective.
    pub fn refresh_visibility(&mut self) {
        if self.failure.is_some() {
            return;
        }
        let n = self.pb.len();
        let backend = &mut *self.backend;
        let (bvh, pb, sky) = (self.bvh, self.pb, &self.sky);
        self.vis.update_sun(self.globals.sun.map(|s| s.to_sun), self.sun_retrace_tol, n, &mut |d| crate::visibility::trace_sun(bvh, pb, d, sky));
        if let Err(e) = self.vis.update(&self.lights, self.retrace_tol, n, &mut |p| backend.trace(p)) {
            self.failure = Some(e);
        }
    }

    /// Like `eval_lights` but with the visibility cache as it is (no re-trace).
    pub fn eval_frozen(&mut self, lights: &[Light], globals: Globals) -> Eval {
        if self.failure.is_some() || self.vis.bits.len() != lights.len() || self.vis.sun.is_some() != globals.sun.is_some() {
            return self.eval_lights(lights, globals);
        }
        self.evaluations += 1;
        match self.backend.evaluate(&self.vis, lights, globals.terms()) {
            Ok(ev) => ev,
            Err(e) => {
                self.failure = Some(e);
                Eval { f: f64::NAN, rel_error: f64::NAN, grad: vec![[0.0; 6]; lights.len()], ..Default::default() }
            }
        }
    }

    fn encode(&self) -> Vec<f64> {
        let mut x = Vec::with_capacity(self.lights.len() * PER_LIGHT + 3);
        for l in &self.lights {
            let q = (l.pos - self.center) / self.unit;
            let m = l.rgb.iter().copied().fold(0.0f32, f32::max).max(1e-12);
            x.extend([q.x as f64, q.y as f64, q.z as f64, (m as f64).ln()]);
            for c in 0..3 {
                x.push(((l.rgb[c] / m).max(1e-9) as f64).ln());
            }
        }
        if let Some(a) = self.globals.ambient {
            x.extend(a.map(|v| (v.max(1e-12) as f64).ln()));
        }
        if let Some(k) = self.globals.indirect {
            x.extend(k.map(|v| logit(v as f64)));
        }
        if let Some(s) = self.globals.sun {
            let (theta, phi) = sun_angles(s.to_sun);
            let m = s.rgb.iter().copied().fold(0.0f32, f32::max).max(1e-12);
            x.extend([theta, phi, (m as f64).ln()]);
            x.extend(s.rgb.map(|v| ((v / m).max(1e-9) as f64).ln()));
        }
        x
    }

    fn decode(&self, x: &[f64]) -> (Vec<Light>, Globals) {
        let k = self.lights.len();
        let lights = (0..k)
            .map(|j| {
                let p = &x[j * PER_LIGHT..(j + 1) * PER_LIGHT];
                let pos = self.center + Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) * self.unit;
                let rgb = [0, 1, 2].map(|c| (p[3] + p[4 + c]).clamp(-80.0, 80.0).exp() as f32);
                Light { pos, rgb }
            })
            .collect();
        let mut o = k * PER_LIGHT;
        let mut next = |used: bool, f: fn(f64) -> f64| {
            used.then(|| {
                let v = [0, 1, 2].map(|c| f(x[o + c]) as f32);
                o += 3;
                v
            })
        };
        let ambient = next(self.globals.ambient.is_some(), |v| v.clamp(-80.0, 80.0).exp());
        let indirect = next(self.globals.indirect.is_some(), logistic);
        let sun = self.globals.sun.map(|_| {
            let p = &x[o..o + 6];
            Sun { to_sun: sun_direction(p[0], p[1]).0, rgb: [0, 1, 2].map(|c| (p[2] + p[3 + c]).clamp(-80.0, 80.0).exp() as f32) }
        });
        (lights, Globals { ambient, indirect, sun })
    }

    /// Penalty value and its gradient with respect to each light position (per meter).
    pub fn penalty(&self, lights: &[Light]) -> (f64, Vec<Vec3>) {
        let f0 = 0.5 * self.pb.norm2.max(1e-30);
        let mut total = 0.0;
        let mut grads = vec![Vec3::ZERO; lights.len()];
        for (j, l) in lights.iter().enumerate() {
            if let Some((dist, near)) = self.bvh.nearest(l.pos) {
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
                    total += f0 * ((below / self.unit) as f64).powi(2);
                    grads[j][a] -= 2.0 * below / (self.unit * self.unit) * f0 as f32;
                }
                if above > 0.0 {
                    total += f0 * ((above / self.unit) as f64).powi(2);
                    grads[j][a] += 2.0 * above / (self.unit * self.unit) * f0 as f32;
                }
            }
        }
        (total, grads)
    }

    fn mask(&self, set: ParamSet, with_ambient: bool) -> Vec<bool> {
        let mut m = Vec::new();
        for j in 0..self.lights.len() {
            let free = !self.locked[j];
            m.extend([set.position && free; 3]);
            m.push(set.intensity && free);
            m.extend([set.color && free; 3]);
        }
        let globals = self.globals.ambient.is_some() as usize + self.globals.indirect.is_some() as usize;
        m.extend(std::iter::repeat_n(with_ambient, 3 * globals));
        if self.globals.sun.is_some() {
            // The sun's direction is left to the search (`init::sun_search`): its shadows'
            // edges, which carry the information, are invisible to the gradient.
            m.extend([false; 2]);
            m.push(set.intensity);
            m.extend([set.color; 3]);
        }
        m
    }

    /// Runs one phase; returns its summary (also appended to `phases`).
    pub fn run_phase(&mut self, name: &str, phase: Phase) -> PhaseSummary {
        let t0 = Instant::now();
        let start_eval = self.eval();
        let before = start_eval.rel_error;
        let start = (self.lights.clone(), self.globals, start_eval.f + self.penalty(&self.lights).0);
        let x0 = self.encode();
        let mask = self.mask(phase.params, phase.params.intensity);
        let phase_no = self.phase_index;
        self.phase_index += 1;
        let last_err = std::cell::Cell::new(before);
        let outcome = {
            let this = std::cell::RefCell::new(&mut *self);
            let mut objective = |x: &[f64], fresh: bool| -> (f64, Vec<f64>) {
                let mut me = this.borrow_mut();
                let (lights, globals) = me.decode(x);
                let ev = if fresh { me.eval_lights(&lights, globals) } else { me.eval_frozen(&lights, globals) };
                let (pen, pgrad) = me.penalty(&lights);
                last_err.set(ev.rel_error);
                let mut g = vec![0.0; x.len()];
                for (j, l) in lights.iter().enumerate() {
                    let o = j * PER_LIGHT;
                    let gp = [ev.grad[j][0] + pgrad[j].x as f64, ev.grad[j][1] + pgrad[j].y as f64, ev.grad[j][2] + pgrad[j].z as f64];
                    for a in 0..3 {
                        g[o + a] = gp[a] * me.unit as f64;
                    }
                    let mut gs = 0.0;
                    for c in 0..3 {
                        let d = ev.grad[j][3 + c] * l.rgb[c] as f64;
                        gs += d;
                        g[o + 4 + c] = d;
                    }
                    g[o + 3] = gs;
                }
                let mut o = lights.len() * PER_LIGHT;
                if let Some(a) = globals.ambient {
                    for c in 0..3 {
                        g[o + c] = ev.grad_ambient[c] * a[c] as f64;
                    }
                    o += 3;
                }
                if let Some(k) = globals.indirect {
                    for c in 0..3 {
                        let k = k[c] as f64;
                        g[o + c] = ev.grad_indirect[c] * k * (1.0 - k / INDIRECT_MAX);
                    }
                    o += 3;
                }
                if let Some(s) = globals.sun {
                    let (_, d_theta, d_phi) = sun_direction(x[o], x[o + 1]);
                    let gw = glam::DVec3::new(ev.grad_sun[0], ev.grad_sun[1], ev.grad_sun[2]);
                    g[o] = gw.dot(d_theta);
                    g[o + 1] = gw.dot(d_phi);
                    let mut gs = 0.0;
                    for c in 0..3 {
                        let d = ev.grad_sun[3 + c] * s.rgb[c] as f64;
                        gs += d;
                        g[o + 3 + c] = d;
                    }
                    g[o + 2] = gs;
                }
                (ev.f + pen, g)
            };
            let mut observe = |it: usize, f: f64| -> bool {
                let mut me = this.borrow_mut();
                let rec = IterRecord { time_s: me.start.elapsed().as_secs_f64(), phase: phase_no, iteration: it, objective: f, rel_error: last_err.get(), lights: me.lights.len() };
                if let Some(cb) = me.on_iter.as_mut() {
                    cb(&rec);
                }
                me.history.push(rec);
                !me.out_of_time()
            };
            match phase.algorithm {
                Algorithm::Adam { step } => optim::adam(&x0, &mask, step, phase.max_iterations, 1e-5, &mut objective, &mut observe),
                Algorithm::Lbfgs { step } => optim::lbfgs(&x0, &mask, step, phase.max_iterations, 1e-6, &mut objective, &mut observe),
            }
        };
        let (lights, globals) = self.decode(&outcome.x);
        self.lights = lights;
        self.globals = globals;
        let mut end_eval = self.eval();
        // A phase never leaves things worse than it found them (visibility changes can make
        // an optimiser's last accepted step worse once re-traced).
        if end_eval.f + self.penalty(&self.lights).0 > start.2 {
            (self.lights, self.globals) = (start.0, start.1);
            end_eval = self.eval();
        }
        let after = end_eval.rel_error;
        let s = PhaseSummary {
            name: name.to_string(),
            phase,
            iterations: outcome.iterations,
            evaluations: outcome.evaluations,
            stop: outcome.stop,
            time_s: t0.elapsed().as_secs_f64(),
            rel_error_before: before,
            rel_error_after: after,
        };
        self.phases.push(s.clone());
        s
    }

    /// Exact non-negative least-squares fit of every free light's intensity per channel (and
    /// of the ambient term when enabled) for the current positions, on the CPU. Locked lights
    /// keep their values. Returns the new relative error.
    pub fn fit_intensities(&mut self) -> f64 {
        self.refresh_visibility();
        if self.failure.is_some() {
            return f64::NAN;
        }
        let k = self.lights.len();
        // Columns: the lights, then the ambient and indirect terms in use.
        let amb = self.globals.ambient.map(|_| k);
        let ind = self.globals.indirect.map(|_| k + amb.is_some() as usize);
        let sun_col = self.globals.sun.map(|_| k + amb.is_some() as usize + ind.is_some() as usize);
        let cols = k + amb.is_some() as usize + ind.is_some() as usize + sun_col.is_some() as usize;
        // The sun's direction is fixed here; its colour is fitted per channel.
        let sun_dir = self.globals.sun.map(|s| Terms { sun: Some(Sun { to_sun: s.to_sun, rgb: [1.0; 3] }), ..Terms::default() });
        let pb = self.pb;
        let lights = self.lights.clone();
        let vis = &self.vis;
        use rayon::prelude::*;
        let chunk = 8192;
        // Per channel: Gram matrix and right-hand side.
        let (gram, rhs) = (0..pb.len().div_ceil(chunk))
            .into_par_iter()
            .map(|ci| {
                let mut gram = vec![vec![0.0f64; cols * cols]; 3];
                let mut rhs = vec![vec![0.0f64; cols]; 3];
                let mut nz: Vec<(usize, f64)> = Vec::new();
                let mut basis: Vec<(usize, f64)> = Vec::new();
                for i in ci * chunk..((ci + 1) * chunk).min(pb.len()) {
                    nz.clear();
                    for (j, l) in lights.iter().enumerate() {
                        if vis.visible(j, i) {
                            let (g, _) = crate::model::geometry_term(pb.pos[i], pb.normal[i], l.pos, pb.eps);
                            if g > 0.0 {
                                nz.push((j, g as f64 / std::f64::consts::PI));
                            }
                        }
                    }
                    for c in 0..3 {
                        let w = pb.area[i] as f64 * pb.weight[i][c] as f64;
                        if w == 0.0 {
                            continue;
                        }
                        // Each column's radiance per unit of its parameter, at this row.
                        let a = pb.albedo[i][c] as f64;
                        basis.clear();
                        basis.extend(nz.iter().map(|&(j, g)| (j, a * g)));
                        basis.extend(amb.map(|col| (col, a)));
                        basis.extend(ind.map(|col| (col, pb.indirect[i][c] as f64)));
                        if let (Some(col), Some(t)) = (sun_col, sun_dir) {
                            let (_, cos) = t.sun_at(pb, vis, i);
                            if cos > 0.0 {
                                basis.push((col, a * cos as f64 / std::f64::consts::PI));
                            }
                        }
                        for &(j, bj) in &basis {
                            rhs[c][j] += w * bj * pb.target[i][c] as f64;
                            for &(l, bl) in &basis {
                                gram[c][j * cols + l] += w * bj * bl;
                            }
                        }
                    }
                }
                (gram, rhs)
            })
            .reduce(
                || (vec![vec![0.0; cols * cols]; 3], vec![vec![0.0; cols]; 3]),
                |(mut g1, mut r1), (g2, r2)| {
                    for c in 0..3 {
                        for (a, b) in g1[c].iter_mut().zip(&g2[c]) {
                            *a += b;
                        }
                        for (a, b) in r1[c].iter_mut().zip(&r2[c]) {
                            *a += b;
                        }
                    }
                    (g1, r1)
                },
            );
        for c in 0..3 {
            let mut x: Vec<f64> = self.lights.iter().map(|l| l.rgb[c] as f64).collect();
            x.extend([self.globals.ambient, self.globals.indirect].into_iter().flatten().map(|a| a[c] as f64));
            x.extend(self.globals.sun.map(|s| s.rgb[c] as f64));
            let free: Vec<bool> = (0..cols).map(|j| j >= k || !self.locked[j]).collect();
            let upper: Vec<f64> = (0..cols).map(|j| if Some(j) == ind { INDIRECT_MAX } else { f64::INFINITY }).collect();
            nnls_cd(&gram[c], &rhs[c], cols, &mut x, &free, &upper, 20_000);
            for j in 0..k {
                // Keep a light's channel just above zero so its log parameterisation stays finite.
                self.lights[j].rgb[c] = (x[j] as f32).max(1e-6 * x.iter().copied().fold(1e-9, f64::max) as f32);
            }
            if let (Some(a), Some(col)) = (self.globals.ambient.as_mut(), amb) {
                a[c] = (x[col] as f32).max(1e-9);
            }
            if let (Some(s), Some(col)) = (self.globals.indirect.as_mut(), ind) {
                s[c] = (x[col] as f32).clamp(1e-6, INDIRECT_MAX as f32 - 1e-6);
            }
            if let (Some(s), Some(col)) = (self.globals.sun.as_mut(), sun_col) {
                s.rgb[c] = (x[col] as f32).max(1e-6 * x.iter().copied().fold(1e-9, f64::max) as f32);
            }
        }
        self.eval().rel_error
    }

    /// Removes light `j` (keeps the visibility cache aligned).
    pub fn remove_light(&mut self, j: usize) {
        self.lights.remove(j);
        self.locked.remove(j);
        if j < self.vis.bits.len() {
            self.vis.remove(j);
        }
    }

    pub fn add_light(&mut self, l: Light, locked: bool) {
        self.lights.push(l);
        self.locked.push(locked);
    }

    /// Removes lights whose removal raises the relative error by less than `tol`
    /// (absolute), one at a time, refitting intensities after each. Returns how many.
    pub fn prune(&mut self, tol: f64) -> usize {
        let mut removed = 0;
        loop {
            if self.out_of_time() || self.lights.len() <= 1 {
                return removed;
            }
            let base = self.fit_intensities();
            let saved = (self.lights.clone(), self.locked.clone(), self.vis.clone(), self.globals);
            // Try the weakest lights first (least energy reaching the target).
            let mut order: Vec<usize> = (0..self.lights.len()).filter(|&j| !self.locked[j]).collect();
            order.sort_by(|&a, &b| self.lights[a].rgb.iter().sum::<f32>().total_cmp(&self.lights[b].rgb.iter().sum::<f32>()));
            let mut done = false;
            for &j in order.iter().take(4) {
                self.remove_light(j);
                let e = self.fit_intensities();
                if e <= base + tol {
                    removed += 1;
                    done = true;
                    break;
                }
                (self.lights, self.locked, self.vis, self.globals) = saved.clone();
            }
            if !done {
                (self.lights, self.locked, self.vis, self.globals) = saved;
                return removed;
            }
        }
    }

    /// Merges pairs of free lights closer than `dist` m when that raises the relative error
    /// by less than `tol`. Returns how many merges were made.
    pub fn merge(&mut self, dist: f32, tol: f64) -> usize {
        let mut merged = 0;
        'outer: loop {
            if self.out_of_time() {
                return merged;
            }
            let base = self.fit_intensities();
            let k = self.lights.len();
            for a in 0..k {
                for b in a + 1..k {
                    if self.locked[a] || self.locked[b] || (self.lights[a].pos - self.lights[b].pos).length() > dist {
                        continue;
                    }
                    let saved = (self.lights.clone(), self.locked.clone(), self.vis.clone(), self.globals);
                    let (la, lb) = (self.lights[a], self.lights[b]);
                    let (wa, wb) = (la.rgb.iter().sum::<f32>(), lb.rgb.iter().sum::<f32>());
                    let pos = (la.pos * wa + lb.pos * wb) / (wa + wb).max(1e-30);
                    self.lights[a] = Light { pos, rgb: [0, 1, 2].map(|c| la.rgb[c] + lb.rgb[c]) };
                    self.remove_light(b);
                    let e = self.fit_intensities();
                    if e <= base + tol {
                        merged += 1;
                        continue 'outer;
                    }
                    (self.lights, self.locked, self.vis, self.globals) = saved;
                }
            }
            return merged;
        }
    }
}

/// Projected coordinate descent for `min 1/2 x'Gx - r'x, 0 <= x <= upper` (free entries only).
/// Largest indirect scale `k` (see the module docs).
pub const INDIRECT_MAX: f64 = 1.0;

fn logistic(v: f64) -> f64 {
    INDIRECT_MAX / (1.0 + (-v.clamp(-80.0, 80.0)).exp())
}

fn logit(k: f64) -> f64 {
    let p = (k / INDIRECT_MAX).clamp(1e-6, 1.0 - 1e-6);
    (p / (1.0 - p)).ln()
}

pub fn nnls_cd(g: &[f64], r: &[f64], n: usize, x: &mut [f64], free: &[bool], upper: &[f64], sweeps: usize) {
    for _ in 0..sweeps {
        let mut change = 0.0f64;
        let mut scale = 0.0f64;
        for j in 0..n {
            if !free[j] || !(g[j * n + j] > 0.0) {
                continue;
            }
            let mut s = r[j];
            for l in 0..n {
                if l != j {
                    s -= g[j * n + l] * x[l];
                }
            }
            let new = (s / g[j * n + j]).max(0.0).min(upper[j]);
            change = change.max((new - x[j]).abs());
            scale = scale.max(new.abs());
            x[j] = new;
        }
        if change <= 1e-10 * scale.max(1e-300) {
            break;
        }
    }
}
