//! The forward model: what light reaches each row, from every kind of emitter a q3map2
//! map uses, through the compile's own effects; the objective and its gradient.
//!
//! One module per term, each with its CPU evaluation and gradient:
//!
//! | term | module | parameters |
//! |---|---|---|
//! | point and spot lights | [`lights`] (WGSL: `light_*.wgsl`) | position, intensity, colour; a spot's axis and cone |
//! | sun | [`sun`] | irradiance, colour (its direction by search) |
//! | sky light | [`sky`] | irradiance |
//! | surface lights | [`surface`] (patches from [`patch_mesh`], q3map2's mesh of them) | radiance per emitting shader |
//! | ambient, minlight, filter, dirt | [`compile`] | ambient, minlight; filter on or off; dirt on or off, its depth among [`compile::DIRT_DEPTHS_UNITS`] where no compile recorded it |
//! | bounced light | [`bounce`] | scale per channel |
//!
//! Per row `i` and channel `c`, in q3map2's order (see [`compile`]):
//!
//! ```text
//! D   = sum_lights + sun + sky + sum_surfaces            irradiance of the emitters, W/m^2
//! T_0 = dirt (ambient + Filter D)
//! T_n = dirt Filter (k K rho T_{n-1})                     n = 1 .. bounces
//! x   = albedo / pi max(sum_n T_n (+ H), minlight)  (+ k_g o)    radiance
//! ```
//!
//! (`o` is the data's own gathered bounce, [`crate::gather`], used only where the
//! operator `K` is not available: the placement's subsample. `H`, [`Bases::held`], is the
//! light of emitters held out of a fit of some lights.) The objective is
//! [`crate::rows::residual`] summed over rows and channels. Its gradient runs the chain
//! backwards: `rho_x -> rho_T` (zero where the floor holds) `-> rho_0 = sum_n (G^T)^n
//! rho_T` with `G = dirt Filter k K rho` (`rho`: the bounce reflectance), `-> rho_D = Filter^T (dirt rho_0)`, and
//! each term turns `rho_D` into its parameters' gradient. Everything but the lights runs
//! here in f64; the lights run on a [`crate::backend::Backend`] (the CPU or wgpu).

pub mod area;
pub mod bounce;
pub mod compile;
pub mod lights;
pub mod patch_mesh;
pub mod sky;
pub mod stated;
pub mod sun;
pub mod surface;

use std::f64::consts::PI;

use rayon::prelude::*;

use crate::backend::Backend;
use crate::error::Result;
use crate::rows::{residual, Rows};
use crate::trace::visibility::Visibility;
pub use compile::Sparse;
pub use lights::{Light, LightGrad, Spot};
pub use sun::Sun;

/// Every parameter of the model; an absent term is `None` (or off).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Model {
    pub lights: Vec<Light>,
    pub sun: Option<Sun>,
    /// Sky-light irradiance scale, W/m^2 per channel ([`sky`]).
    pub sky: Option<[f32; 3]>,
    /// Radiance of each emitting shader of [`Bases::surfaces`], W/(m^2 sr); `None`: off.
    pub surfaces: Vec<Option<[f32; 3]>>,
    /// Ambient irradiance added before dirt, W/m^2.
    pub ambient: Option<[f32; 3]>,
    /// Scale of each bounce per channel, in (0, 1] ([`bounce`]).
    pub bounce: Option<[f32; 3]>,
    /// Floor of the total irradiance, W/m^2 (q3map2's `_minlight`).
    pub minlight: Option<[f32; 3]>,
    /// Scale of the data's own gathered bounce (placement only).
    pub gathered: Option<[f32; 3]>,
    /// q3map2's dirt (`-dirty`) and its settings (the factor is [`Bases::dirt_of`]).
    pub dirt: Option<compile::DirtSettings>,
    /// q3map2's `-filter`.
    pub filter: bool,
}

impl Model {
    /// Total irradiance `t` of channel `c` (W/m^2) after the minlight floor.
    #[inline]
    pub fn floored(&self, t: f64, c: usize) -> f64 {
        match self.minlight {
            Some(m) => t.max(m[c] as f64),
            None => t,
        }
    }

    /// The model's chain (bounce, dirt, filter) with no emitter, ambient, minlight or
    /// gathered term: what one term's or one kind's radiance is run through.
    pub fn chain_only(&self) -> Model {
        Model { lights: Vec::new(), sun: None, sky: None, surfaces: vec![None; self.surfaces.len()], ambient: None, gathered: None, minlight: None, ..self.clone() }
    }
}

/// What the model needs of the geometry, computed once per set of rows.
#[derive(Debug, Clone, Default)]
pub struct Bases {
    pub sky: Option<sky::SkyBasis>,
    pub surfaces: surface::SurfaceBasis,
    /// Dirt factor per row, one basis per setting the run considers.
    pub dirt: Vec<compile::DirtBasis>,
    pub filter: Option<Sparse>,
    /// The bounce's transport `K` ([`bounce::Transport`]).
    pub bounce: Option<bounce::Transport>,
    /// The reflectance each row bounces light with ([`bounce::reflectance`]).
    pub bounce_reflectance: Vec<[f32; 3]>,
    /// How the bounce's transport was traced (rays, pieces).
    pub bounce_stats: Option<bounce::GatherStats>,
    /// Passes of bounced light (q3map2's `-bounce N`).
    pub bounces: usize,
    /// The data's own bounced radiance per row ([`crate::gather`]).
    pub gathered: Option<Vec<[f32; 3]>>,
    /// Sky flag of every mesh triangle (sunlight passes sky).
    pub sky_triangles: Vec<bool>,
    /// Light of emitters held out of the model, per row and channel, in the units of the
    /// chain's total `T` (W/m^2, after dirt and filter): added to `T` before the minlight
    /// floor. A fit of some lights with the rest held
    /// ([`crate::fit::Fitter::run_phase_on_reach`]) carries the rest here.
    pub held: Option<Vec<[f64; 3]>>,
}

impl Bases {
    /// The dirt factor per row of the model's dirt settings: `None` where the model has
    /// no dirt, or these bases no basis for its settings.
    pub fn dirt_of(&self, model: &Model) -> Option<&[f32]> {
        let set = model.dirt?;
        self.dirt.iter().find(|b| b.settings == set).map(|b| b.factor.as_slice())
    }

    /// The bases of a subset of the rows (`take`: their indices in these rows). The
    /// filter and the bounce operator link rows to rows and are not carried over: the
    /// subset uses the gathered bounce instead.
    pub fn subset(&self, take: &[usize]) -> Bases {
        let mut surfaces = surface::SurfaceBasis { groups: self.surfaces.groups.clone(), offsets: vec![0], entries: Vec::new(), rays: 0 };
        if self.surfaces.offsets.len() > 1 {
            for &i in take {
                surfaces.entries.extend_from_slice(self.surfaces.row(i));
                surfaces.offsets.push(surfaces.entries.len() as u32);
            }
        } else {
            surfaces.offsets = vec![0; take.len() + 1];
        }
        Bases {
            sky: self.sky.as_ref().map(|b| sky::SkyBasis { d: take.iter().map(|&i| b.d[i]).collect(), directions: b.directions.clone(), mean_cos_up: b.mean_cos_up }),
            surfaces,
            dirt: self.dirt.iter().map(|b| compile::DirtBasis { settings: b.settings, factor: take.iter().map(|&i| b.factor[i]).collect() }).collect(),
            filter: None,
            bounce: None,
            bounce_reflectance: Vec::new(),
            bounce_stats: None,
            bounces: 0,
            gathered: self.gathered.as_ref().map(|o| take.iter().map(|&i| o[i]).collect()),
            sky_triangles: self.sky_triangles.clone(),
            held: self.held.as_ref().map(|h| take.iter().map(|&i| h[i]).collect()),
        }
    }
}

/// Value and gradient of the objective.
#[derive(Debug, Clone, Default)]
pub struct Eval {
    /// Objective F (without penalties).
    pub f: f64,
    /// `sqrt(sum A w (x - clamp(x, lo, hi))^2 / sum A w mid^2)`.
    pub rel_error: f64,
    pub lights: Vec<LightGrad>,
    /// dF/dw (unnormalised direction) and dF/dS of the sun.
    pub sun: ([f64; 3], [f64; 3]),
    pub sky: [f64; 3],
    pub surfaces: Vec<[f64; 3]>,
    pub ambient: [f64; 3],
    pub bounce: [f64; 3],
    pub minlight: [f64; 3],
    pub gathered: [f64; 3],
}

impl Eval {
    /// An evaluation that failed (a backend error): NaN everywhere, so every loop stops.
    pub fn failed(model: &Model) -> Eval {
        Eval { f: f64::NAN, rel_error: f64::NAN, lights: vec![LightGrad::default(); model.lights.len()], surfaces: vec![[0.0; 3]; model.surfaces.len()], ..Default::default() }
    }
}

/// The forward chain's intermediate values (kept for the gradient).
#[derive(Debug, Clone, Default)]
pub struct Forward {
    /// D: the emitters' irradiance.
    pub direct: Vec<[f64; 3]>,
    /// T_0, T_1, ...: the passes.
    pub passes: Vec<Vec<[f64; 3]>>,
    /// sum_n T_n.
    pub total: Vec<[f64; 3]>,
    /// The model's radiance per row.
    pub x: Vec<[f64; 3]>,
}

/// Irradiance of the emitters that are not lights (sun, sky, surfaces), added to `e`.
fn add_other_emitters(model: &Model, rows: &Rows, bases: &Bases, vis: &Visibility, e: &mut [[f64; 3]]) {
    if let Some(s) = &model.sun {
        s.add_irradiance(rows, vis, e);
    }
    if let (Some(k), Some(b)) = (model.sky, &bases.sky) {
        b.add_irradiance(k, e);
    }
    if model.surfaces.iter().any(Option::is_some) {
        bases.surfaces.add_irradiance(&model.surfaces, e);
    }
}

fn filter_of<'a>(model: &Model, bases: &'a Bases) -> Option<&'a Sparse> {
    if model.filter {
        bases.filter.as_ref()
    } else {
        None
    }
}

/// `dirt Filter v`.
fn dirt_filter(model: &Model, bases: &Bases, v: Vec<[f64; 3]>) -> Vec<[f64; 3]> {
    let mut v = match filter_of(model, bases) {
        Some(f) => f.apply(&v, None),
        None => v,
    };
    if let Some(d) = bases.dirt_of(model) {
        v.par_iter_mut().zip(d).for_each(|(x, &d)| x.iter_mut().for_each(|c| *c *= d as f64));
    }
    v
}

/// `Filter^T dirt v` (the adjoint of [`dirt_filter`]).
fn dirt_filter_adjoint(model: &Model, bases: &Bases, mut v: Vec<[f64; 3]>) -> Vec<[f64; 3]> {
    if let Some(d) = bases.dirt_of(model) {
        v.par_iter_mut().zip(d).for_each(|(x, &d)| x.iter_mut().for_each(|c| *c *= d as f64));
    }
    match filter_of(model, bases) {
        Some(f) => f.apply_transposed(&v, None),
        None => v,
    }
}

/// The bounce operator of one pass without dirt and filter: `k K rho v`.
fn bounce_step(k: [f32; 3], op: &bounce::Transport, rho: &[[f32; 3]], v: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut out = op.apply(v, Some(rho));
    out.par_iter_mut().for_each(|x| (0..3).for_each(|c| x[c] *= k[c] as f64));
    out
}

/// Runs the forward chain from the lights' irradiance `e_lights` (see the module docs).
pub fn forward(model: &Model, rows: &Rows, bases: &Bases, vis: &Visibility, e_lights: &[[f32; 3]]) -> Forward {
    // Every step is row by row, so the loops run on all cores with each row's sums as in
    // one loop (the same bits on any number of threads). On one core they were half of
    // what oa_dm1's placement, which evaluates its subsample a thousand times, did on its
    // main thread alone; on 16 cores that serial part set the pace.
    let n = rows.len();
    let mut direct: Vec<[f64; 3]> = if e_lights.len() == n { e_lights.par_iter().map(|e| e.map(|v| v as f64)).collect() } else { vec![[0.0; 3]; n] };
    add_other_emitters(model, rows, bases, vis, &mut direct);
    if chain_is_local(model, bases) {
        forward_local(model, rows, bases, direct)
    } else {
        forward_chain(model, rows, bases, direct)
    }
}

/// Whether the model's chain is local: no filter and no bounce, each row's radiance its
/// own irradiance's ([`forward_local`]).
fn chain_is_local(model: &Model, bases: &Bases) -> bool {
    filter_of(model, bases).is_none() && !(model.bounce.is_some() && bases.bounce.is_some() && bases.bounces > 0)
}

/// [`forward`] from the emitters' irradiance `direct`, step by step: any chain.
fn forward_chain(model: &Model, rows: &Rows, bases: &Bases, direct: Vec<[f64; 3]>) -> Forward {
    let n = rows.len();
    // T_0 = dirt (ambient + Filter D).
    let mut f = match filter_of(model, bases) {
        Some(op) => op.apply(&direct, None),
        None => direct.clone(),
    };
    if let Some(a) = model.ambient {
        f.par_iter_mut().for_each(|x| (0..3).for_each(|c| x[c] += a[c] as f64));
    }
    if let Some(d) = bases.dirt_of(model) {
        f.par_iter_mut().zip(d).for_each(|(x, &d)| x.iter_mut().for_each(|c| *c *= d as f64));
    }
    let mut passes = vec![f];
    if let (Some(k), Some(op)) = (model.bounce, &bases.bounce) {
        for _ in 0..bases.bounces {
            let prev = passes.last().expect("T_0 is there");
            let next = dirt_filter(model, bases, bounce_step(k, op, &bases.bounce_reflectance, prev));
            passes.push(next);
        }
    }
    let mut total = passes[0].clone();
    for p in passes[1..].iter().chain(&bases.held) {
        total.par_iter_mut().zip(p).for_each(|(t, v)| (0..3).for_each(|c| t[c] += v[c]));
    }
    let x = (0..n)
        .into_par_iter()
        .map(|i| {
            [0, 1, 2].map(|c| {
                let t = model.floored(total[i][c], c);
                let mut v = rows.albedo[i][c] as f64 / PI * t;
                if let (Some(k), Some(o)) = (model.gathered, &bases.gathered) {
                    v += k[c] as f64 * o[i][c] as f64;
                }
                v
            })
        })
        .collect();
    Forward { direct, passes, total, x }
}

/// [`forward_chain`] where the chain is local ([`chain_is_local`]):
/// `T_0 = dirt (ambient + D)`, the total `T_0 + H` and the radiance, row by row in one
/// parallel pass. There the steps' loops and copies, one after the other, were a
/// parallel loop each (an evaluation on a light's reach in the placement is short, and
/// each loop's start and end cost about as much as its rows); here each row's values are
/// the same operations in the same order: the same bits (a test).
fn forward_local(model: &Model, rows: &Rows, bases: &Bases, direct: Vec<[f64; 3]>) -> Forward {
    let n = rows.len();
    let dirt = bases.dirt_of(model);
    let held = bases.held.as_deref();
    let gathered = model.gathered.zip(bases.gathered.as_deref());
    // Collected, not zeroed and then written: the three vectors are megabytes each.
    type PerRow = Vec<[f64; 3]>;
    let (t0, (total, x)): (PerRow, (PerRow, PerRow)) = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut v = direct[i];
            if let Some(a) = model.ambient {
                (0..3).for_each(|c| v[c] += a[c] as f64);
            }
            if let Some(d) = dirt {
                (0..3).for_each(|c| v[c] *= d[i] as f64);
            }
            let t0 = v;
            if let Some(h) = held.and_then(|h| h.get(i)) {
                (0..3).for_each(|c| v[c] += h[c]);
            }
            let x = [0, 1, 2].map(|c| {
                let mut r = rows.albedo[i][c] as f64 / PI * model.floored(v[c], c);
                if let Some((k, o)) = gathered {
                    r += k[c] as f64 * o[i][c] as f64;
                }
                r
            });
            (t0, (v, x))
        })
        .unzip();
    Forward { direct, passes: vec![t0], total, x }
}

/// A vector over the rows and the rows where it can be nonzero (ascending; `None`: any).
#[derive(Clone)]
struct Spread {
    v: Vec<[f64; 3]>,
    support: Option<Vec<u32>>,
}

/// A [`Spread`] that would reach more than this fraction of the rows is run dense.
const SPREAD_DENSE_FRACTION: usize = 4;

impl Spread {
    /// `S v` ([`Operator::apply`]'s values), over the rows the support reaches while they
    /// are few.
    fn apply(&self, op: &impl compile::Operator, col: Option<&[[f32; 3]]>) -> Spread {
        if let Some(s) = &self.support {
            if let Some((v, support)) = op.apply_supported(&self.v, col, s, self.v.len() / SPREAD_DENSE_FRACTION) {
                return Spread { v, support: Some(support) };
            }
        }
        Spread { v: op.apply(&self.v, col), support: None }
    }

    /// `f(row, value)` on every row of the support.
    fn each(&mut self, f: impl Fn(usize, &mut [f64; 3]) + Sync) {
        match &self.support {
            Some(s) => s.iter().for_each(|&i| f(i as usize, &mut self.v[i as usize])),
            None => self.v.par_iter_mut().enumerate().for_each(|(i, x)| f(i, x)),
        }
    }

    /// `self += other`, row by row; the support becomes the union.
    fn add(&mut self, other: &Spread) {
        match (&mut self.support, &other.support) {
            (Some(a), Some(b)) => {
                b.iter().for_each(|&i| (0..3).for_each(|c| self.v[i as usize][c] += other.v[i as usize][c]));
                let mut union = Vec::with_capacity(a.len() + b.len());
                let (mut p, mut q) = (0, 0);
                while p < a.len() || q < b.len() {
                    let next = match (a.get(p), b.get(q)) {
                        (Some(&x), Some(&y)) if x == y => {
                            (p, q) = (p + 1, q + 1);
                            x
                        }
                        (Some(&x), Some(&y)) if x < y => {
                            p += 1;
                            x
                        }
                        (Some(&x), None) => {
                            p += 1;
                            x
                        }
                        (_, Some(&y)) => {
                            q += 1;
                            y
                        }
                        (None, None) => unreachable!("the loop's condition"),
                    };
                    union.push(next);
                }
                *a = union;
            }
            _ => {
                self.v.par_iter_mut().zip(&other.v).for_each(|(t, v)| (0..3).for_each(|c| t[c] += v[c]));
                self.support = None;
            }
        }
    }
}

/// The radiance of one light's column of the linear fit ([`crate::fit`]): [`forward`]'s
/// `x` for a model whose only emitter is the per-unit irradiance `direct` (ascending
/// `(row, W/m^2)`, the same in every channel; every other row dark), through `chain`'s
/// filter, dirt and bounce (its emitters, ambient, minlight and gathered term are not
/// read). Every row's value is [`forward`]'s to the bit (a zero may differ in sign);
/// each step works on the rows the light's reach has spread to, while they are few (a
/// light of a big map reaches a few percent of its rows, and each bounce pass spreads
/// that to the rows that see them), and on all rows after.
pub fn light_column(chain: &Model, rows: &Rows, bases: &Bases, direct: &[(u32, f32)]) -> Vec<[f64; 3]> {
    let n = rows.len();
    let mut d = vec![[0.0f64; 3]; n];
    let mut support = Vec::with_capacity(direct.len());
    for &(i, g) in direct {
        if let Some(x) = d.get_mut(i as usize) {
            *x = [g as f64; 3];
            support.push(i);
        }
    }
    let dirt_filter = |t: Spread| {
        let mut t = match filter_of(chain, bases) {
            Some(f) => t.apply(f, None),
            None => t,
        };
        if let Some(d) = bases.dirt_of(chain) {
            t.each(|i, x| x.iter_mut().for_each(|c| *c *= d[i] as f64));
        }
        t
    };
    // T_0 = dirt Filter D (no ambient in a column).
    let mut pass = dirt_filter(Spread { v: d, support: Some(support) });
    let mut total = pass.clone();
    if let (Some(k), Some(op)) = (chain.bounce, &bases.bounce) {
        for _ in 0..bases.bounces {
            let mut next = pass.apply(op, Some(&bases.bounce_reflectance));
            next.each(|_, x| (0..3).for_each(|c| x[c] *= k[c] as f64));
            pass = dirt_filter(next);
            total.add(&pass);
        }
    }
    let mut x = vec![[0.0f64; 3]; n];
    let radiance = |i: usize| [0, 1, 2].map(|c| rows.albedo[i][c] as f64 / PI * total.v[i][c]);
    match &total.support {
        Some(s) => s.iter().for_each(|&i| x[i as usize] = radiance(i as usize)),
        None => x.par_iter_mut().enumerate().for_each(|(i, v)| *v = radiance(i)),
    }
    x
}

/// The model's radiance per row (no gradient).
pub fn radiance(model: &Model, rows: &Rows, bases: &Bases, vis: &Visibility, backend: &mut dyn Backend) -> Result<Vec<[f64; 3]>> {
    let e = if model.lights.is_empty() { Vec::new() } else { backend.irradiance(vis, &model.lights)? };
    Ok(forward(model, rows, bases, vis, &e).x)
}

/// [`evaluate`] without the gradient (its fields stay empty): the objective and the
/// relative error only, for a line search's trials. The adjoint chain and the lights'
/// gradient kernels are about half of an evaluation.
pub fn value(model: &Model, rows: &Rows, bases: &Bases, vis: &Visibility, backend: &mut dyn Backend) -> Result<Eval> {
    value_and_forward(model, rows, bases, vis, backend).map(|(ev, _)| ev)
}

/// [`value`] and the forward chain it ran: a caller that next needs the same model's
/// radiance (the linear fit's next round) takes it from here.
pub fn value_and_forward(model: &Model, rows: &Rows, bases: &Bases, vis: &Visibility, backend: &mut dyn Backend) -> Result<(Eval, Forward)> {
    let e = if model.lights.is_empty() { Vec::new() } else { backend.irradiance(vis, &model.lights)? };
    let fw = forward(model, rows, bases, vis, &e);
    let (f, num, _) = residuals(rows, &fw, None);
    Ok((eval_of(model, rows, f, num), fw))
}

/// An evaluation of `model` with the objective `f` and the error's numerator `num` from
/// [`residuals`], its gradients still zero.
fn eval_of(model: &Model, rows: &Rows, f: f64, num: f64) -> Eval {
    let rel_error = if rows.norm2 > 0.0 { (num / rows.norm2).sqrt() } else { 0.0 };
    Eval { f, rel_error, surfaces: vec![[0.0; 3]; model.surfaces.len()], ..Default::default() }
}

/// The objective, the error's numerator (`sum A w (x - clamp)^2`) and, with `keep`,
/// `keep(i, rho_x_i)` per row for `rho_x = dF/dx` (the caller's first steps back along
/// the chain, in the same pass): per block of rows summed in row order, the blocks in
/// order (the same bits on any number of threads, with or without `keep`).
fn residuals(rows: &Rows, fw: &Forward, keep: Option<&(dyn Fn(usize, [f64; 3]) -> [f64; 3] + Sync)>) -> (f64, f64, Vec<[f64; 3]>) {
    let n = rows.len();
    let chunk = crate::rows::block_rows(n);
    let parts: Vec<(f64, f64, Vec<[f64; 3]>)> = (0..n.div_ceil(chunk))
        .into_par_iter()
        .map(|ci| {
            let (mut f, mut num) = (0.0, 0.0);
            let mut rho: Vec<[f64; 3]> = Vec::with_capacity(if keep.is_some() { chunk } else { 0 });
            for i in ci * chunk..((ci + 1) * chunk).min(n) {
                let r = [0, 1, 2].map(|c| {
                    let (fi, r, ni) = residual(fw.x[i][c], rows.lo[i][c] as f64, rows.hi[i][c] as f64, rows.weight[i][c] as f64, rows.lower[i][c] as f64, rows.area[i] as f64);
                    f += fi;
                    num += ni;
                    r
                });
                if let Some(k) = keep {
                    rho.push(k(i, r));
                }
            }
            (f, num, rho)
        })
        .collect();
    let (mut f, mut num) = (0.0, 0.0);
    let mut rho_x: Vec<[f64; 3]> = Vec::with_capacity(if keep.is_some() { n } else { 0 });
    for (pf, pn, r) in parts {
        f += pf;
        num += pn;
        rho_x.extend(r);
    }
    (f, num, rho_x)
}

/// Objective, relative error and gradient of every parameter.
pub fn evaluate(model: &Model, rows: &Rows, bases: &Bases, vis: &Visibility, backend: &mut dyn Backend) -> Result<Eval> {
    let e = if model.lights.is_empty() { Vec::new() } else { backend.irradiance(vis, &model.lights)? };
    let fw = forward(model, rows, bases, vis, &e);
    evaluate_from(model, rows, bases, vis, backend, fw)
}

/// [`evaluate`] given the model's forward chain `fw` under the same visibility (what
/// [`value_and_forward`] returned for it): the same [`Eval`] to the bit, without the
/// irradiance and the chain computed again (a line search's accepted trial, evaluated
/// afresh where no light was re-traced).
pub fn evaluate_from(model: &Model, rows: &Rows, bases: &Bases, vis: &Visibility, backend: &mut dyn Backend, fw: Forward) -> Result<Eval> {
    if model.minlight.is_none() && bases.gathered.is_none() && chain_is_local(model, bases) {
        evaluate_local(model, rows, bases, vis, backend, fw)
    } else {
        evaluate_chain(model, rows, bases, vis, backend, fw)
    }
}

/// [`evaluate_chain`] where the chain is local and has no floor or gathered term:
/// `rho_D = dirt albedo / pi rho_x` row by row, in the residuals' pass. There each step
/// back is a loop over the rows and a copy; here each row's values are the same
/// operations in the same order: the same bits (a test).
fn evaluate_local(model: &Model, rows: &Rows, bases: &Bases, vis: &Visibility, backend: &mut dyn Backend, fw: Forward) -> Result<Eval> {
    let dirt = bases.dirt_of(model);
    let back = |i: usize, r: [f64; 3]| {
        let mut v = [0, 1, 2].map(|c| rows.albedo[i][c] as f64 / PI * r[c]);
        if let Some(d) = dirt {
            v.iter_mut().for_each(|c| *c *= d[i] as f64);
        }
        v
    };
    let (f, num, rho_d) = residuals(rows, &fw, Some(&back));
    let mut ev = eval_of(model, rows, f, num);
    // The ambient's, before dirt: `dirt rho_0` is rho_D itself (the same product).
    if model.ambient.is_some() {
        for r in &rho_d {
            (0..3).for_each(|c| ev.ambient[c] += r[c]);
        }
    }
    evaluate_rest(model, rows, bases, vis, backend, ev, rho_d)
}

/// [`evaluate_from`] step by step back along any chain.
fn evaluate_chain(model: &Model, rows: &Rows, bases: &Bases, vis: &Visibility, backend: &mut dyn Backend, fw: Forward) -> Result<Eval> {
    let n = rows.len();
    // Residuals: rho_x and the objective.
    let (f, num, rho_x) = residuals(rows, &fw, Some(&|_, r| r));
    let mut ev = eval_of(model, rows, f, num);
    // rho_T: through the albedo and the minlight floor. The sums (minlight, gathered) in
    // row order, on one thread; without them, a map over the rows.
    let mut rho_t = vec![[0.0f64; 3]; n];
    if model.minlight.is_none() && bases.gathered.is_none() {
        rho_t.par_iter_mut().enumerate().for_each(|(i, r)| *r = [0, 1, 2].map(|c| rows.albedo[i][c] as f64 / PI * rho_x[i][c]));
    } else {
        for i in 0..n {
            for c in 0..3 {
                let a = rows.albedo[i][c] as f64 / PI * rho_x[i][c];
                match model.minlight {
                    Some(m) if fw.total[i][c] <= m[c] as f64 => ev.minlight[c] += a,
                    _ => rho_t[i][c] = a,
                }
                if let Some(o) = &bases.gathered {
                    ev.gathered[c] += rho_x[i][c] * o[i][c] as f64;
                }
            }
        }
    }
    // rho_0 = sum_n (G^T)^n rho_T, and dF/dk = sum_n n/k <rho_T, T_n>.
    let mut rho_0 = rho_t.clone();
    if let (Some(k), Some(op)) = (model.bounce, &bases.bounce) {
        for (p, t_n) in fw.passes.iter().enumerate().skip(1) {
            for c in 0..3 {
                let s: f64 = (0..n).map(|i| rho_t[i][c] * t_n[i][c]).sum();
                ev.bounce[c] += p as f64 * s / (k[c] as f64).max(1e-12);
            }
        }
        let mut a = rho_t;
        for _ in 1..fw.passes.len() {
            // G^T a = albedo K^T k Filter^T dirt a ... applied right to left.
            let mut v = dirt_filter_adjoint(model, bases, a);
            v.par_iter_mut().for_each(|x| (0..3).for_each(|c| x[c] *= k[c] as f64));
            a = op.apply_transposed(&v, Some(&bases.bounce_reflectance));
            rho_0.par_iter_mut().zip(&a).for_each(|(r, v)| (0..3).for_each(|c| r[c] += v[c]));
        }
    }
    // Ambient (before dirt, after the filter), then rho_D = Filter^T (dirt rho_0).
    if model.ambient.is_some() {
        let d = bases.dirt_of(model);
        for i in 0..n {
            let w = d.map_or(1.0, |d| d[i] as f64);
            for c in 0..3 {
                ev.ambient[c] += w * rho_0[i][c];
            }
        }
    }
    let rho_d = dirt_filter_adjoint(model, bases, rho_0);
    evaluate_rest(model, rows, bases, vis, backend, ev, rho_d)
}

/// [`evaluate_from`]'s gradients of the emitters from `rho_D = dF/dD` (the sun's, the
/// sky's, the surfaces', the lights') into `ev`.
fn evaluate_rest(model: &Model, rows: &Rows, bases: &Bases, vis: &Visibility, backend: &mut dyn Backend, mut ev: Eval, rho_d: Vec<[f64; 3]>) -> Result<Eval> {
    if let Some(s) = &model.sun {
        ev.sun = s.gradient(rows, vis, &rho_d);
    }
    if let Some(b) = &bases.sky {
        ev.sky = b.gradient(&rho_d);
    }
    if !model.surfaces.is_empty() {
        ev.surfaces = bases.surfaces.gradient(&rho_d);
        ev.surfaces.resize(model.surfaces.len(), [0.0; 3]);
    }
    ev.lights = if model.lights.is_empty() {
        Vec::new()
    } else {
        let rho32: Vec<[f32; 3]> = rho_d.par_iter().map(|r| r.map(|v| v as f32)).collect();
        backend.gradient(vis, &model.lights, &rho32)?
    };
    Ok(ev)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::Cpu;
    use crate::testutil::room;
    use crate::trace::bvh::Bvh;
    use glam::Vec3;

    /// A light's column over the rows it reaches is the whole chain's, row by row: for
    /// reaches of one row (spread a little per pass), a few, and half the rows (dense at
    /// once), with each of the chain's steps on and off.
    #[test]
    fn a_light_column_over_its_reach_is_the_forward_chains() {
        let (_, rows) = room(6);
        let n = rows.len();
        let bases = crate::testutil::chain_bases(n, 8);
        let reaches: [Vec<u32>; 3] = [vec![5], vec![0, 17, 40, (n - 1) as u32], (0..n as u32).step_by(2).collect()];
        for reach in &reaches {
            let direct: Vec<(u32, f32)> = reach.iter().map(|&i| (i, 0.25 + 0.01 * i as f32)).collect();
            let mut e = vec![[0.0f32; 3]; n];
            direct.iter().for_each(|&(i, g)| e[i as usize] = [g; 3]);
            for bits in 0..8 {
                let chain = Model { bounce: (bits & 1 != 0).then_some([0.8, 0.6, 0.7]), dirt: (bits & 2 != 0).then_some(crate::scene::DirtSettings::Q3MAP2), filter: bits & 4 != 0, ..Model::default() };
                let want = forward(&chain, &rows, &bases, &Visibility::default(), &e).x;
                let got = light_column(&chain, &rows, &bases, &direct);
                assert_eq!(got.len(), n);
                for i in 0..n {
                    for c in 0..3 {
                        // The same value; a zero may differ in sign only.
                        assert!(got[i][c].to_bits() == want[i][c].to_bits() || (got[i][c] == 0.0 && want[i][c] == 0.0), "reach {} chain {bits} row {i}: {} vs {}", reach.len(), got[i][c], want[i][c]);
                    }
                }
                assert!(got.iter().any(|x| x[0] != 0.0));
            }
        }
    }

    /// The local chain in one pass ([`forward_local`]) is the chain step by step
    /// ([`forward_chain`]) to the bit: with its ambient, dirt, minlight floor and gathered
    /// term each on and off, a held part, on one thread and on three.
    #[test]
    fn the_local_chain_in_one_pass_is_the_chain_step_by_step() {
        let (_, rows) = room(6);
        let n = rows.len();
        let mut bases = crate::testutil::chain_bases(n, 0);
        bases.filter = None;
        bases.bounce = None;
        bases.held = Some((0..n).map(|i| [0.01 * (i % 5) as f64, 0.02, 0.003 * (i % 11) as f64]).collect());
        bases.gathered = Some((0..n).map(|i| [0.1, 0.05 * (i % 3) as f32, 0.2]).collect());
        let direct: Vec<[f64; 3]> = (0..n).map(|i| [0.5 + 0.01 * (i % 17) as f64, 0.3 + 1e-3 * i as f64, 0.1 * (i % 7) as f64]).collect();
        let bits = |v: &[[f64; 3]]| v.iter().flat_map(|x| x.map(f64::to_bits)).collect::<Vec<u64>>();
        for terms in 0..16 {
            let model = Model {
                ambient: (terms & 1 != 0).then_some([0.01, 0.02, 0.03]),
                dirt: (terms & 2 != 0).then_some(crate::scene::DirtSettings::Q3MAP2),
                minlight: (terms & 4 != 0).then_some([0.4; 3]),
                gathered: (terms & 8 != 0).then_some([0.5, 0.4, 0.3]),
                ..Model::default()
            };
            assert!(chain_is_local(&model, &bases));
            let want = forward_chain(&model, &rows, &bases, direct.clone());
            assert_eq!(want.passes.len(), 1);
            if terms & 4 != 0 {
                assert!(want.total.iter().any(|t| t[1] < 0.4) && want.total.iter().any(|t| t[1] > 0.4), "the floor binds on some rows only");
            }
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
                let got = pool.install(|| forward_local(&model, &rows, &bases, direct.clone()));
                let what = format!("terms {terms:04b}, {threads} threads");
                assert_eq!(bits(&got.direct), bits(&want.direct), "{what}: direct");
                assert_eq!(got.passes.len(), 1, "{what}");
                assert_eq!(bits(&got.passes[0]), bits(&want.passes[0]), "{what}: T_0");
                assert_eq!(bits(&got.total), bits(&want.total), "{what}: total");
                assert_eq!(bits(&got.x), bits(&want.x), "{what}: radiance");
            }
        }
    }

    /// The local chain's evaluation in the residuals' pass ([`evaluate_local`]) is the
    /// step-by-step one's ([`evaluate_chain`]) to the bit, every gradient with it: with
    /// the ambient and dirt each on and off, a sun, a sky and surfaces, on one thread and
    /// on three.
    #[test]
    fn the_local_evaluation_is_the_chains() {
        let (mesh, rows) = room(6);
        let n = rows.len();
        let bvh = Bvh::build(&mesh);
        let mut bases = crate::testutil::chain_bases(n, 0);
        bases.filter = None;
        bases.bounce = None;
        bases.sky = Some(crate::model::sky::SkyBasis { d: (0..n).map(|i| 0.1 + 0.01 * (i % 9) as f32).collect(), ..Default::default() });
        let lights = vec![Light::point(Vec3::new(1.1, 1.7, 0.9), [2.0, 1.5, 1.0]), Light::point(Vec3::new(2.6, 2.4, 2.2), [0.7, 1.2, 1.9])];
        let mut vis = Visibility::default();
        vis.update(&lights::sources(&lights), 0.0, &rows.sampling, n, &mut |p| Ok(p.iter().map(|&(q, r)| crate::trace::visibility::trace_light(&bvh, &rows, q, r)).collect())).unwrap();
        let sun = Sun { to_sun: Vec3::new(0.3, 0.9, -0.2).normalize(), rgb: [1.5, 1.2, 0.9] };
        let sky_tri = vec![true; mesh.triangles.len()];
        vis.update_sun(Some(sun.to_sun), 0.0, n, &mut |d| Ok(crate::trace::visibility::trace_sun(&bvh, &rows, d, &sky_tri))).unwrap();
        for terms in 0..4 {
            let model = Model {
                lights: lights.clone(),
                sun: Some(sun),
                sky: Some([0.3, 0.4, 0.5]),
                ambient: (terms & 1 != 0).then_some([0.01, 0.02, 0.015]),
                dirt: (terms & 2 != 0).then_some(crate::scene::DirtSettings::Q3MAP2),
                ..Model::default()
            };
            assert!(chain_is_local(&model, &bases));
            let mut cpu = Cpu::new(&rows, &bvh);
            let (_, fw) = value_and_forward(&model, &rows, &bases, &vis, &mut cpu).unwrap();
            let want = format!("{:?}", evaluate_chain(&model, &rows, &bases, &vis, &mut cpu, fw.clone()).unwrap());
            assert!(want.contains("lights: [LightGrad"), "the lights' gradients are there: {want}");
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
                let got = pool.install(|| format!("{:?}", evaluate_local(&model, &rows, &bases, &vis, &mut Cpu::new(&rows, &bvh), fw.clone()).unwrap()));
                assert_eq!(got, want, "terms {terms:02b}, {threads} threads");
            }
        }
    }

    /// Every parameter's analytic gradient against central differences, with every term
    /// in the model at once (lights and a spot, sun, sky, surfaces, ambient, filter, dirt,
    /// bounce, minlight), and a quarter of the rows two-sided (a light outside the room
    /// reaches those of the wall it stands behind).
    #[test]
    fn gradient_matches_central_differences() {
        let (mesh, mut rows) = room(6);
        rows.two_sided = (0..rows.len()).map(|i| i % 4 == 0).collect();
        let bvh = Bvh::build(&mesh);
        let n = rows.len();
        // Synthetic bases: any fixed numbers exercise the chain.
        let sky = sky::SkyBasis { d: (0..n).map(|i| 0.2 + 0.1 * (i % 5) as f32).collect(), directions: vec![Vec3::Y], mean_cos_up: 1.0 };
        let group = |name: &str| surface::Group { name: name.into(), materials: Vec::new(), source_rgb: [1.0; 3], patches: 1, area_m2: 1.0, q3map2_meshes: 0, meshes_unmatched: 0 };
        let mut surfaces = surface::SurfaceBasis { groups: vec![group("a"), group("b")], offsets: vec![0], ..Default::default() };
        for i in 0..n {
            surfaces.entries.push((0, 0.5 + 0.05 * (i % 7) as f32));
            if i % 3 == 0 {
                surfaces.entries.push((1, 0.3));
            }
            surfaces.offsets.push(surfaces.entries.len() as u32);
        }
        let ring = |w: f32| {
            let mut s = Sparse::empty();
            for i in 0..n {
                s.push_row([(i as u32, 1.0 - 2.0 * w), (((i + 1) % n) as u32, w), (((i + 7) % n) as u32, w)]);
            }
            s
        };
        let bases = Bases {
            sky: Some(sky),
            surfaces,
            dirt: vec![crate::model::compile::DirtBasis { settings: crate::scene::DirtSettings::Q3MAP2, factor: (0..n).map(|i| 0.6 + 0.05 * (i % 8) as f32).collect() }],
            filter: Some(ring(0.2)),
            bounce: Some(crate::testutil::factored_transport(n, n / 4 + 1)),
            bounce_reflectance: (0..n).map(|i| [0.5, 0.4 + 0.01 * (i % 9) as f32, 0.3]).collect(),
            bounce_stats: None,
            bounces: 3,
            gathered: Some((0..n).map(|i| [0.01 * (i % 4) as f32, 0.02, 0.015]).collect()),
            sky_triangles: vec![true; mesh.triangles.len()],
            held: None,
        };
        let model = Model {
            lights: vec![
                Light::point(Vec3::new(1.1, 1.7, 0.9), [2.0, 1.5, 1.0]),
                Light { pos: Vec3::new(2.6, 2.4, 2.2), rgb: [0.7, 1.2, 1.9], spot: Some(Spot { axis: Vec3::new(-0.2, -1.0, -0.1).normalize(), radius_by_dist: 0.9 }) },
                Light::point(Vec3::new(-0.7, 0.9, 2.1), [1.2, 1.0, 0.8]),
            ],
            sun: Some(Sun { to_sun: Vec3::new(0.3, 0.9, -0.2).normalize(), rgb: [1.5, 1.2, 0.9] }),
            sky: Some([0.3, 0.4, 0.5]),
            surfaces: vec![Some([0.2, 0.1, 0.15]), Some([0.05, 0.06, 0.07])],
            ambient: Some([0.01, 0.02, 0.015]),
            bounce: Some([0.8, 0.6, 0.7]),
            minlight: Some([0.05, 0.05, 0.05]),
            gathered: Some([0.5, 0.4, 0.3]),
            dirt: Some(crate::scene::DirtSettings::Q3MAP2),
            filter: true,
        };
        let mut vis = Visibility::default();
        vis.update(&lights::sources(&model.lights), 0.0, &rows.sampling, n, &mut |p| Ok(p.iter().map(|&(q, r)| crate::trace::visibility::trace_light(&bvh, &rows, q, r)).collect())).unwrap();
        let sky_tri = vec![true; mesh.triangles.len()];
        vis.update_sun(model.sun.map(|s| s.to_sun), 0.0, n, &mut |d| Ok(crate::trace::visibility::trace_sun(&bvh, &rows, d, &sky_tri))).unwrap();
        let mut cpu = Cpu::new(&rows, &bvh);
        // The floor in the widest gap between the lowest third of the rows' total
        // irradiance: it binds on some rows, and no row sits on its kink.
        let mut model = model;
        let e = cpu.irradiance(&vis, &model.lights).unwrap();
        let mut totals: Vec<f64> = forward(&Model { minlight: None, ..model.clone() }, &rows, &bases, &vis, &e).total.iter().map(|t| t[1]).collect();
        totals.sort_by(f64::total_cmp);
        let k = (1..n / 3).max_by(|&a, &b| (totals[a] - totals[a - 1]).total_cmp(&(totals[b] - totals[b - 1]))).unwrap();
        model.minlight = Some([(0.5 * (totals[k] + totals[k - 1])) as f32; 3]);
        let ev = evaluate(&model, &rows, &bases, &vis, &mut cpu).unwrap();
        assert!(ev.f > 0.0);
        // The forward chain's loops run on all cores: every term's evaluation and gradient
        // are the same bits on any number of threads.
        let e_lights = cpu.irradiance(&vis, &model.lights).unwrap();
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
            pool.install(|| {
                let fw = forward(&model, &rows, &bases, &vis, &e_lights);
                let ev = evaluate(&model, &rows, &bases, &vis, &mut Cpu::new(&rows, &bvh)).unwrap();
                (fw.x, fw.total, format!("{ev:?}"))
            })
        };
        let one = on(1);
        assert_eq!(one.2, format!("{ev:?}"));
        // Given the forward chain a frozen evaluation ran (a line search's accepted
        // trial), the evaluation is the same to the bit (`{:?}` prints every f64 exactly).
        let (_, fw) = value_and_forward(&model, &rows, &bases, &vis, &mut cpu).unwrap();
        assert_eq!(format!("{:?}", evaluate_from(&model, &rows, &bases, &vis, &mut cpu, fw).unwrap()), format!("{ev:?}"));
        for threads in [2, 3, 8] {
            assert!(on(threads) == one, "{threads} threads");
        }
        let f = |m: &Model| {
            let mut cpu = Cpu::new(&rows, &bvh);
            evaluate(m, &rows, &bases, &vis, &mut cpu).unwrap().f
        };
        let check = |name: &str, an: f64, plus: Model, minus: Model, h: f64| {
            let fd = (f(&plus) - f(&minus)) / (2.0 * h);
            let scale = an.abs().max(fd.abs()).max(1e-9 * ev.f);
            assert!((fd - an).abs() <= 3e-3 * scale, "{name}: analytic {an} vs central difference {fd}");
        };
        let behind = (0..rows.len()).filter(|&i| vis.visible(2, i) && rows.normal[i].dot(model.lights[2].pos - rows.pos[i]) < 0.0 && crate::model::lights::g(&rows, i, &model.lights[2]) > 0.0).count();
        assert!(behind > 0, "the light outside lights two-sided rows from behind");
        let h = 1e-3f32;
        for j in 0..3 {
            for q in 0..3 {
                let (mut a, mut b) = (model.clone(), model.clone());
                a.lights[j].pos[q] += h;
                b.lights[j].pos[q] -= h;
                check(&format!("light {j} pos {q}"), ev.lights[j].pos[q], a, b, h as f64);
                let (mut a, mut b) = (model.clone(), model.clone());
                a.lights[j].rgb[q] += h;
                b.lights[j].rgb[q] -= h;
                check(&format!("light {j} rgb {q}"), ev.lights[j].rgb[q], a, b, h as f64);
            }
        }
        for q in 0..3 {
            let (mut a, mut b) = (model.clone(), model.clone());
            a.lights[1].spot.as_mut().unwrap().axis[q] += h;
            b.lights[1].spot.as_mut().unwrap().axis[q] -= h;
            check(&format!("spot axis {q}"), ev.lights[1].axis[q], a, b, h as f64);
        }
        let (mut a, mut b) = (model.clone(), model.clone());
        a.lights[1].spot.as_mut().unwrap().radius_by_dist += h;
        b.lights[1].spot.as_mut().unwrap().radius_by_dist -= h;
        check("spot radius", ev.lights[1].radius_by_dist, a, b, h as f64);
        let h = 1e-4f32;
        for c in 0..3 {
            let per = |set: &dyn Fn(&mut Model, f32)| {
                let (mut a, mut b) = (model.clone(), model.clone());
                set(&mut a, h);
                set(&mut b, -h);
                (a, b)
            };
            let (a, b) = per(&|m, d| m.sun.as_mut().unwrap().rgb[c] += d);
            check("sun irradiance", ev.sun.1[c], a, b, h as f64);
            let (a, b) = per(&|m, d| m.sun.as_mut().unwrap().to_sun[c] += d);
            check("sun direction", ev.sun.0[c], a, b, h as f64);
            let (a, b) = per(&|m, d| m.sky.as_mut().unwrap()[c] += d);
            check("sky", ev.sky[c], a, b, h as f64);
            for s in 0..2 {
                let (a, b) = per(&|m, d| m.surfaces[s].as_mut().unwrap()[c] += d);
                check(&format!("surface {s}"), ev.surfaces[s][c], a, b, h as f64);
            }
            let (a, b) = per(&|m, d| m.ambient.as_mut().unwrap()[c] += d);
            check("ambient", ev.ambient[c], a, b, h as f64);
            let (a, b) = per(&|m, d| m.bounce.as_mut().unwrap()[c] += d);
            check("bounce", ev.bounce[c], a, b, h as f64);
            let (a, b) = per(&|m, d| m.minlight.as_mut().unwrap()[c] += d);
            check("minlight", ev.minlight[c], a, b, h as f64);
            let (a, b) = per(&|m, d| m.gathered.as_mut().unwrap()[c] += d);
            check("gathered", ev.gathered[c], a, b, h as f64);
        }
        assert!(ev.minlight.iter().any(|&g| g != 0.0), "the floor holds somewhere");
    }
}
