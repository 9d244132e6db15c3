//! The exact fit of every linear coefficient of the model for fixed positions,
//! directions and switches: the lights' intensities per channel, the sun's, the sky's,
//! each surface group's radiance, the ambient and the gathered bounce's scale.
//!
//! Each coefficient is a column: its radiance per unit at every row, through the
//! model's linear chain (filter, dirt and the bounces at their current scale, see
//! [`crate::model`]). Per channel, `min sum_i A_i w_i (sum_k x_ik b_k - mid_i)^2` over
//! `0 <= b <= upper` (the intervals' middles; rows held at the minlight floor are left
//! out, and a censored channel counts with its lower bound as the target where the
//! current model falls short of it, an active set refitted in rounds) is solved on the
//! Gram matrix by projected coordinate descent, with a Newton step on the coordinates
//! inside their bounds every few sweeps (`Subspace::step`). Columns through a non-local chain (filter, bounce) are run through it one
//! by one when there are few of them (at most [`DENSE_COLUMNS`]); with more, the chain is
//! taken as local (dirt only) and the gradient phases finish the fit.
//!
//! With [`Fitter::kind_scales`] the coefficients are not free one by one: each kind of
//! emitter keeps its members' proportions and gets one multiplier per channel (q3map2's
//! `-pointscale`, `-skyscale` for the sun and the sky light, `-areascale` for the surface
//! lights), so a map's own sources are scaled as a compile could have, never moved apart.
//! Then each kind is one column, the chain run once over the kind's emitters as they stand
//! (`kind_columns`): exact through a non-local chain at any number of lights.

use rayon::prelude::*;

use super::Fitter;
use crate::model::{lights, Model};
use crate::trace::visibility::{UnitList, Visibility, WordBoxes};

std::thread_local! {
    /// Per worker thread: the per-row lists of nonzero columns of the linear fit's last
    /// block ([`Fitter::fit_linear_once`]), kept for the next block to reuse.
    static BLOCK_NZ: std::cell::Cell<Vec<Vec<(usize, f64)>>> = const { std::cell::Cell::new(Vec::new()) };
}

/// Most refits of the linear coefficients while the rows at the minlight floor change.
pub const MINLIGHT_ROUNDS: usize = 8;
/// Most solves while only the censored channels' active set changes (each round one
/// evaluation of the model): on oa_dm1 the set settles in two or three.
pub const CENSORED_ROUNDS: usize = 3;

/// Most columns pushed through a non-local chain exactly.
pub const DENSE_COLUMNS: usize = 64;

/// Most solves of a fit whose chain is taken as local ([`DENSE_COLUMNS`]), each with the
/// previous one's non-local remainder off the targets. The remainder is the bounce and the
/// filter's spread, a fraction of the light, so each round shrinks the previous round's
/// error in it by about that fraction.
pub const CHAIN_ROUNDS: usize = 6;
/// The chain's rounds stop once one lowers the relative error by less than this fraction
/// of it.
pub const CHAIN_TOL: f64 = 1e-3;

/// What the chain gives beyond its local part (dirt times the direct light and the
/// ambient, the columns' values where the solve takes the chain as local), as radiance per
/// row and channel: `albedo / pi * (T - dirt (D + a))` with `T` the sum of the passes
/// before the minlight floor (the held light's with them). Linear in the coefficients, so
/// the previous solve's remainder taken off the targets is a fixed-point step towards the
/// solve through the whole chain.
fn chain_remainder(m: &Model, rows: &crate::rows::Rows, bases: &crate::model::Bases, fw: &crate::model::Forward) -> Vec<[f64; 3]> {
    let dirt = bases.dirt_of(m);
    let amb = m.ambient.map_or([0.0; 3], |a| a.map(f64::from));
    (0..rows.len())
        .into_par_iter()
        .map(|i| {
            let d = dirt.map_or(1.0, |d| d[i] as f64);
            [0, 1, 2].map(|c| rows.albedo[i][c] as f64 / std::f64::consts::PI * (fw.total[i][c] - d * (fw.direct[i][c] + amb[c])))
        })
        .collect()
}

/// What a column is.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Col {
    Light(usize),
    Sun,
    Sky,
    Surface(usize),
    Ambient,
    Gathered,
}

/// Light `j`'s per-unit direct irradiance ([`lights::g`], W/m^2 per W/sr) at each row of
/// `range` it reaches, in row order: from its cached unit list where there is one. Rows
/// of the words beyond its falloff cut (`boxes` of `rows`, [`lights::cut_dist2`]) are
/// left out: their values are all zero.
#[inline]
fn unit_g(rows: &crate::rows::Rows, boxes: &WordBoxes, vis: &Visibility, units: &[Option<std::sync::Arc<UnitList>>], all: &[crate::model::Light], j: usize, range: std::ops::Range<usize>, mut f: impl FnMut(usize, f32)) {
    let l = &all[j];
    let top = l.max_rgb();
    let dist2 = lights::cut_dist2(top, &rows.sampling);
    match units.get(j).and_then(Option::as_ref) {
        Some(list) => vis.for_each_visible_with_within(j, range, list, boxes, l.pos, dist2, |i, g| f(i, lights::cut_by(g, top, &rows.sampling))),
        None => vis.for_each_visible_within(j, range, boxes, l.pos, dist2, |i| f(i, lights::g(rows, i, l))),
    }
}

/// One block of rows' share of the normal equations, over the unknowns the block has.
struct BlockGram {
    /// The block's unknowns, ascending.
    unknowns: Vec<usize>,
    /// Per channel, `m x m` over `unknowns` (the dense and the kinds' columns; empty on
    /// the sparse path).
    gram: [Vec<f64>; 3],
    rhs: [Vec<f64>; 3],
    /// The sparse path's: `m x m` entries of the three channels side by side ([`Lanes`]).
    lanes: Option<(Vec<Lanes>, Vec<Lanes>)>,
}

/// The three channels of one Gram (or right-hand side) entry side by side, and a fourth
/// lane that stays zero: a row's pair adds to all three with one vector multiply-add's
/// worth of instructions ([`add_row3`]) where three matrices took three scattered ones.
type Lanes = [f64; 4];

/// One channel's normal equations over every unknown: the Gram matrix's nonzero entries
/// ([`SparseRows`], both triangles), its diagonal, the right-hand side.
struct Normal {
    rows: SparseRows,
    diag: Vec<f64>,
    rhs: Vec<f64>,
}

/// Rows of the whole Gram matrix one task of [`sum_blocks`] sums.
const SUM_ROWS: usize = 16;

/// The blocks' shares summed into each channel's normal equations over the `k` unknowns:
/// every entry the blocks' values added in block order from zero (as one loop over the
/// blocks adds them: the sums do not depend on the threads), the upper triangle mirrored,
/// zeros left out (what [`SparseRows::of_dense`] keeps of the dense matrix). The rows of
/// the whole matrix are summed in parallel, [`SUM_ROWS`] a task, and no dense `k x k` is
/// made: at oacmpdm3's 1388 source lights that sum, on one thread, was 3 s of its 89.
fn sum_blocks(parts: &[BlockGram], k: usize) -> [Normal; 3] {
    // Per channel: the rows' upper entries, the diagonal, the right-hand side.
    type Rows3 = [Vec<Vec<(u32, f64)>>; 3];
    type Task = (Rows3, [Vec<f64>; 3], [Vec<f64>; 3]);
    let tasks: Vec<Task> = (0..k.div_ceil(SUM_ROWS))
        .into_par_iter()
        .map(|t| {
            let (p0, p1) = (t * SUM_ROWS, ((t + 1) * SUM_ROWS).min(k));
            let h = p1 - p0;
            // Rows p0..p1, dense over the columns (only q >= p is ever touched).
            let mut g: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; h * k]);
            let mut r: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; h]);
            for part in parts {
                let u = &part.unknowns;
                let m = u.len();
                let (a0, a1) = (u.partition_point(|&p| p < p0), u.partition_point(|&p| p < p1));
                for a in a0..a1 {
                    let at = (u[a] - p0) * k;
                    match &part.lanes {
                        Some((gl, rl)) => {
                            (0..3).for_each(|c| r[c][u[a] - p0] += rl[a][c]);
                            for b in a..m {
                                let e = gl[a * m + b];
                                (0..3).for_each(|c| g[c][at + u[b]] += e[c]);
                            }
                        }
                        None => {
                            for c in 0..3 {
                                r[c][u[a] - p0] += part.rhs[c][a];
                                let gr = &part.gram[c][a * m..(a + 1) * m];
                                for b in a..m {
                                    g[c][at + u[b]] += gr[b];
                                }
                            }
                        }
                    }
                }
            }
            let upper: Rows3 = std::array::from_fn(|c| (p0..p1).map(|p| (p..k).filter_map(|q| Some((q as u32, g[c][(p - p0) * k + q])).filter(|e| e.1 != 0.0)).collect()).collect());
            let diag: [Vec<f64>; 3] = std::array::from_fn(|c| (p0..p1).map(|p| g[c][(p - p0) * k + p]).collect());
            (upper, diag, r)
        })
        .collect();
    let mut upper: Rows3 = Default::default();
    let mut diag: [Vec<f64>; 3] = Default::default();
    let mut rhs: [Vec<f64>; 3] = Default::default();
    for (u, d, r) in tasks {
        for (c, ((u, d), r)) in u.into_iter().zip(d).zip(r).enumerate() {
            upper[c].extend(u);
            diag[c].extend(d);
            rhs[c].extend(r);
        }
    }
    let [(u0, d0, r0), (u1, d1, r1), (u2, d2, r2)] = [0, 1, 2].map(|c| (std::mem::take(&mut upper[c]), std::mem::take(&mut diag[c]), std::mem::take(&mut rhs[c])));
    let ((n0, n1), n2) = rayon::join(|| rayon::join(|| SparseRows::of_upper(&u0), || SparseRows::of_upper(&u1)), || SparseRows::of_upper(&u2));
    [Normal { rows: n0, diag: d0, rhs: r0 }, Normal { rows: n1, diag: d1, rhs: r1 }, Normal { rows: n2, diag: d2, rhs: r2 }]
}

/// The chain a column runs through, to the bit: the bounce's scale, dirt and filter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct ChainKey {
    bounce: Option<[u32; 3]>,
    dirt: Option<[u32; 3]>,
    filter: bool,
}

impl ChainKey {
    fn of(m: &Model) -> ChainKey {
        ChainKey { bounce: m.bounce.map(|k| k.map(f32::to_bits)), dirt: m.dirt.map(|d| [d.depth_units, d.scale, d.gain].map(f32::to_bits)), filter: m.filter }
    }
}

/// What a column of the dense path is computed from, besides the chain, the rows and
/// the bases.
#[derive(Debug)]
enum ColumnInput {
    /// A light's per-unit direct irradiance over the rows it reaches, ascending rows.
    Light(Vec<(u32, f32)>),
    /// A term whose column is the chain's alone (sky, a surface group, ambient, gathered).
    Term(Col),
}

impl PartialEq for ColumnInput {
    /// To the bit.
    fn eq(&self, other: &ColumnInput) -> bool {
        match (self, other) {
            (ColumnInput::Light(a), ColumnInput::Light(b)) => a.len() == b.len() && a.iter().zip(b).all(|(e, f)| e.0 == f.0 && e.1.to_bits() == f.1.to_bits()),
            (ColumnInput::Term(a), ColumnInput::Term(b)) => a == b,
            _ => false,
        }
    }
}

/// Most bytes of columns [`ColumnCache`] keeps.
pub const COLUMN_CACHE_BYTES: usize = 256 << 20;

/// The dense path's recent columns, each under its whole input: the chain
/// ([`ChainKey`]) and, for a light ([`crate::model::light_column`]), its per-unit direct
/// irradiance over the rows it reaches, compared entry by entry (no hash stands for it);
/// for the sky, a surface group, the ambient and the gathered term, which one. The rows
/// and bases are the fitter's, fixed for its life (checked: another pair empties it).
///
/// Why: the fits that decide the terms, prune and merge start again and again from one
/// state (a term's fits with and without it; each try of a batch from the state before
/// it), and a light whose intensity the solve leaves as it was keeps its column. On
/// the 32-light scaling start of oa_dm1, 59% of the light columns the dense fits asked
/// for were the same as one of the last 64. Least recently used first out; at most
/// [`DENSE_COLUMNS`] columns and [`COLUMN_CACHE_BYTES`].
pub struct ColumnCache {
    /// Most bytes kept ([`COLUMN_CACHE_BYTES`]; 0: none).
    budget_bytes: usize,
    /// Columns found here so far.
    hits: usize,
    owner: (usize, usize),
    entries: std::collections::VecDeque<(ChainKey, ColumnInput, std::sync::Arc<Vec<[f64; 3]>>)>,
}

impl Default for ColumnCache {
    fn default() -> ColumnCache {
        ColumnCache { budget_bytes: COLUMN_CACHE_BYTES, hits: 0, owner: (0, 0), entries: Default::default() }
    }
}

impl ColumnCache {
    /// Empties the cache when the rows or bases are not those it was filled for.
    fn check_owner(&mut self, rows: &crate::rows::Rows, bases: &crate::model::Bases) {
        let owner = (rows as *const _ as usize, bases as *const _ as usize);
        if self.owner != owner {
            self.entries.clear();
            self.owner = owner;
        }
    }

    /// The column of this input, if kept (it becomes the most recent).
    fn get(&mut self, chain: ChainKey, input: &ColumnInput) -> Option<std::sync::Arc<Vec<[f64; 3]>>> {
        let k = self.entries.iter().position(|(c, d, _)| *c == chain && d == input)?;
        let e = self.entries.remove(k)?;
        self.hits += 1;
        let x = e.2.clone();
        self.entries.push_back(e);
        Some(x)
    }

    fn put(&mut self, chain: ChainKey, input: ColumnInput, x: std::sync::Arc<Vec<[f64; 3]>>) {
        let bytes = (x.len() * std::mem::size_of::<[f64; 3]>()).max(1);
        let most = (self.budget_bytes / bytes).min(DENSE_COLUMNS);
        if most == 0 {
            return;
        }
        while self.entries.len() >= most {
            self.entries.pop_front();
        }
        self.entries.push_back((chain, input, x));
    }
}

/// One row's share of the normal equations: `rhs_p += w b_p mid`, `gram_pq += w b_p b_q`
/// over the row's nonzero values `(unknown, b)`, ascending unknowns, into the upper
/// triangle of an `m x m` matrix (`q >= p`; [`mirror_upper`] fills the rest once every
/// row is in). The matrix is symmetric, so the lower half was the same products again:
/// half of the fit's multiply-adds, and the solve now gets a matrix symmetric to the bit.
fn add_row(gram: &mut [f64], rhs: &mut [f64], m: usize, w: f64, mid: f64, basis: &[(usize, f64)]) {
    debug_assert!(basis.windows(2).all(|e| e[0].0 < e[1].0), "ascending unknowns");
    for (a, &(p, bp)) in basis.iter().enumerate() {
        rhs[p] += w * bp * mid;
        for &(q, bq) in &basis[a..] {
            gram[p * m + q] += w * bp * bq;
        }
    }
}

/// [`add_row`] for the three channels at once, `(weight, target)` per channel and each
/// unknown's three values (a fourth lane of zeros), into the channels side by side
/// ([`Lanes`]): per channel the same products (`(w b_p) b_q`, `(w b_p) mid`), summed in
/// the same order, so each lane holds `add_row`'s sums to the bit.
fn add_row3(gram: &mut [Lanes], rhs: &mut [Lanes], m: usize, wm: [(f64, f64); 3], basis: &[(usize, Lanes)]) {
    debug_assert!(basis.windows(2).all(|e| e[0].0 < e[1].0), "ascending unknowns");
    let w: Lanes = [wm[0].0, wm[1].0, wm[2].0, 0.0];
    let mid: Lanes = [wm[0].1, wm[1].1, wm[2].1, 0.0];
    for (a, &(p, bp)) in basis.iter().enumerate() {
        let s: Lanes = std::array::from_fn(|c| w[c] * bp[c]);
        let r = &mut rhs[p];
        (0..4).for_each(|c| r[c] += s[c] * mid[c]);
        let h = &mut gram[p * m..(p + 1) * m];
        for &(q, bq) in &basis[a..] {
            let g = &mut h[q];
            (0..4).for_each(|c| g[c] += s[c] * bq[c]);
        }
    }
}

/// [`add_row`] into lane `c` of the channels side by side ([`add_row3`]'s layout), for a
/// row with only some channels in; `basis` holds all three.
fn add_row_lane(gram: &mut [Lanes], rhs: &mut [Lanes], m: usize, c: usize, w: f64, mid: f64, basis: &[(usize, Lanes)]) {
    debug_assert!(basis.windows(2).all(|e| e[0].0 < e[1].0), "ascending unknowns");
    for (a, &(p, bp)) in basis.iter().enumerate() {
        rhs[p][c] += w * bp[c] * mid;
        for &(q, bq) in &basis[a..] {
            gram[p * m + q][c] += w * bp[c] * bq[c];
        }
    }
}

/// [`add_row`] for a row with a value for every unknown in order (`b.len() x b.len()`
/// matrix, its upper triangle), zeros included: each Gram row is one contiguous product
/// (vectorised). The zeros [`add_row`] never sees add `+0` here, which leaves every sum as
/// it was (sums that start at `+0` and add nonnegative products never become `-0`), so the
/// two agree to the bit. Returns false, adding nothing, where a value is not finite
/// (`0 x inf`) or negative (left to [`add_row`]).
fn add_dense_row(gram: &mut [f64], rhs: &mut [f64], w: f64, mid: f64, b: &[f64]) -> bool {
    let m = b.len();
    if !b.iter().all(|v| v.is_finite() && *v >= 0.0) || !w.is_finite() {
        return false;
    }
    for (p, &bp) in b.iter().enumerate() {
        if bp == 0.0 {
            continue;
        }
        rhs[p] += w * bp * mid;
        let wbp = w * bp;
        for (g, &bq) in gram[p * m + p..(p + 1) * m].iter_mut().zip(&b[p..]) {
            *g += wbp * bq;
        }
    }
    true
}

/// Sums neighbouring entries of the same unknown into one (a row's basis whose columns
/// share unknowns, in order).
fn coalesce(basis: &mut Vec<(usize, Lanes)>) {
    basis.dedup_by(|next, kept| {
        let same = next.0 == kept.0;
        if same {
            (0..4).for_each(|c| kept.1[c] += next.1[c]);
        }
        same
    });
}

/// Copies the upper triangle of an `n x n` matrix onto its lower one (what [`add_row`]
/// and its kin leave out; the fit's own sums go to [`sum_blocks`], which never makes the
/// dense matrix).
#[cfg(test)]
fn mirror_upper(g: &mut [f64], n: usize) {
    for p in 0..n {
        for q in p + 1..n {
            g[q * n + p] = g[p * n + q];
        }
    }
}

/// The work one [`nnls_cd`] solve may take, multiply-adds.
pub const NNLS_WORK: f64 = 2e9;

/// Projected coordinate descent for `min 1/2 x'Gx - r'x, 0 <= x <= upper` (free entries
/// only; fixed ones keep their value; `g` symmetric, dense `n x n`). The gradient `r - Gx`
/// is kept up to date over each row's nonzero entries only: lights whose reaches do not
/// overlap have `G_jl = 0`, so at a thousand small source lights a row holds tens of
/// entries, not a thousand. A coordinate that stays put (a light held at zero) costs O(1)
/// per sweep. Skipping a zero entry skips an update by `0 * delta`, so the iterates are
/// those of the dense sweep to the bit.
pub fn nnls_cd(g: &[f64], r: &[f64], n: usize, x: &mut [f64], free: &[bool], upper: &[f64], sweeps: usize) {
    let rows = SparseRows::of_dense(g, n);
    let diag: Vec<f64> = (0..n).map(|j| g[j * n + j]).collect();
    nnls_cd_rows_with(&rows, &diag, r, x, free, upper, sweeps, 0);
}

/// [`nnls_cd`] on the matrix's nonzero entries (both triangles, each row's in ascending
/// column) and its diagonal, with a [`subspace step`](Subspace::step) every
/// [`SUBSPACE_EVERY`] sweeps.
///
/// Coordinate descent alone crawls where columns are nearly parallel (a thousand source
/// lights, each overlapping tens of neighbours): on oacmpdm3 from its 1388 source lights a
/// solve took 900-1900 sweeps. It finds which coordinates sit at their bounds quickly;
/// what is slow is the interior, where the subspace step is a Newton step. The sweeps
/// still decide the active set and the stop, so the solve ends where the sweeps alone
/// would, at the same minimum (the objective the same to about 1e-15 relative on those
/// solves, the coefficients to about 1e-8), in about a tenth of the sweeps.
fn nnls_cd_rows(rows: &SparseRows, diag: &[f64], r: &[f64], x: &mut [f64], free: &[bool], upper: &[f64], sweeps: usize) {
    nnls_cd_rows_with(rows, diag, r, x, free, upper, sweeps, SUBSPACE_EVERY);
}

/// Sweeps between subspace steps of [`nnls_cd_rows`]. On oacmpdm3's 1388 source lights
/// (the first 300 solves of a run, 2-core machine; thread seconds against the sweeps
/// alone): every 5 sweeps 8.6 s, 10: 7.3 s, 20: 6.6 s, 40: 6.3 s, against 15.5 s.
const SUBSPACE_EVERY: usize = 20;

/// Most conjugate-gradient iterations of a subspace step (at 20 sweeps apart, on the
/// same solves as [`SUBSPACE_EVERY`]'s figures: 30: 6.4 s, 60: 6.6 s, 120: 8.0 s).
const CG_ITERATIONS: usize = 60;

/// A subspace step's conjugate gradients stop once the residual is this fraction of its
/// start.
const CG_TOL: f64 = 1e-6;

/// [`nnls_cd_rows`] with a subspace step every `subspace_every` sweeps (0: none, the
/// plain sweeps of [`nnls_cd`]: the dense sweep's iterates, to the bit). Returns the
/// sweeps made.
#[allow(clippy::too_many_arguments)]
fn nnls_cd_rows_with(rows: &SparseRows, diag: &[f64], r: &[f64], x: &mut [f64], free: &[bool], upper: &[f64], sweeps: usize, subspace_every: usize) -> usize {
    let n = diag.len();
    // At most about NNLS_WORK multiply-adds, counted as a sweep that moves every
    // coordinate (the solution starts from the current values, so repeated solves go on
    // converging), a subspace step as the passes over the matrix it makes; below that the
    // sweep limit is the caller's.
    let sweep_work = (rows.nnz() + n).max(1) as f64;
    let passes = sweeps.min((NNLS_WORK / sweep_work) as usize).max(50);
    let mut grad: Vec<f64> = (0..n).map(|j| r[j] - rows.row(j).map(|(l, gjl)| gjl * x[l]).sum::<f64>()).collect();
    let mut subspace = Subspace::default();
    let (mut spent, mut sweep) = (0, 0);
    while spent < passes {
        if subspace_every > 0 && sweep > 0 && sweep % subspace_every == 0 {
            spent += subspace.step(rows, diag, &mut grad, x, free, upper);
        }
        sweep += 1;
        spent += 1;
        let mut change = 0.0f64;
        let mut scale = 0.0f64;
        for j in 0..n {
            let gjj = diag[j];
            if !free[j] || !(gjj > 0.0) {
                continue;
            }
            // r_j - sum_{l != j} g_jl x_l
            let s = grad[j] + gjj * x[j];
            let new = (s / gjj).max(0.0).min(upper[j]);
            let delta = new - x[j];
            scale = scale.max(new.abs());
            if delta != 0.0 {
                change = change.max(delta.abs());
                for (l, gjl) in rows.row(j) {
                    grad[l] -= gjl * delta;
                }
                x[j] = new;
            }
        }
        if change <= 1e-10 * scale.max(1e-300) {
            break;
        }
    }
    sweep
}

/// The subspace step's working vectors (full length, zero off the subspace).
#[derive(Default)]
struct Subspace {
    /// The coordinates strictly inside their bounds.
    inside: Vec<usize>,
    /// The step.
    d: Vec<f64>,
    /// Conjugate gradients' residual, preconditioned residual, direction and `G p`.
    res: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
}

impl Subspace {
    /// One Newton step on the free coordinates strictly inside their bounds, the others
    /// held: `G_FF d = grad_F` (`grad = r - Gx`, the objective's descent direction) by
    /// Jacobi-preconditioned conjugate gradients, then `x += t d` with `t` the line's
    /// minimum `d'grad / d'Gd`, cut at the first bound it would cross (that coordinate
    /// lands on its bound). Conjugate gradients from zero on a convex quadratic give
    /// `d'grad > 0`, so the objective never rises: where it could (a singular subspace, a
    /// non-positive curvature from rounding) no step is taken. Keeps `grad` up to date.
    /// Returns the passes over the matrix it made.
    fn step(&mut self, rows: &SparseRows, diag: &[f64], grad: &mut [f64], x: &mut [f64], free: &[bool], upper: &[f64]) -> usize {
        let n = diag.len();
        self.inside.clear();
        self.inside.extend((0..n).filter(|&j| free[j] && diag[j] > 0.0 && x[j] > 0.0 && x[j] < upper[j]));
        let f = &self.inside;
        if f.is_empty() {
            return 0;
        }
        for v in [&mut self.d, &mut self.res, &mut self.z, &mut self.p, &mut self.q] {
            v.clear();
            v.resize(n, 0.0);
        }
        for &j in f {
            self.res[j] = grad[j];
            self.z[j] = grad[j] / diag[j];
            self.p[j] = self.z[j];
        }
        let r0: f64 = f.iter().map(|&j| self.res[j] * self.res[j]).sum();
        if !(r0 > 0.0 && r0.is_finite()) {
            return 0;
        }
        let mut rz: f64 = f.iter().map(|&j| self.res[j] * self.z[j]).sum();
        let mut passes = 1;
        for _ in 0..CG_ITERATIONS {
            // `p` is zero off the subspace: whole rows give `G_FF p`.
            let mut pq = 0.0;
            for &j in f {
                let qj: f64 = rows.row(j).map(|(l, g)| g * self.p[l]).sum();
                self.q[j] = qj;
                pq += self.p[j] * qj;
            }
            passes += 1;
            if !(pq > 0.0) {
                break;
            }
            let alpha = rz / pq;
            let (mut rr, mut rz_next) = (0.0, 0.0);
            for &j in f {
                self.d[j] += alpha * self.p[j];
                self.res[j] -= alpha * self.q[j];
                self.z[j] = self.res[j] / diag[j];
                rr += self.res[j] * self.res[j];
                rz_next += self.res[j] * self.z[j];
            }
            // `rz_next` is the next step's denominator (positive while the residual is).
            if rr <= CG_TOL * CG_TOL * r0 || !(rz_next > 0.0) {
                break;
            }
            let beta = rz_next / rz;
            rz = rz_next;
            for &j in f {
                self.p[j] = self.z[j] + beta * self.p[j];
            }
        }
        // `G d` on every row (`grad` moves by it), the line's minimum, the first bound.
        self.q.iter_mut().for_each(|v| *v = 0.0);
        for &j in f {
            let dj = self.d[j];
            if dj != 0.0 {
                for (l, g) in rows.row(j) {
                    self.q[l] += g * dj;
                }
            }
        }
        let slope: f64 = f.iter().map(|&j| self.d[j] * grad[j]).sum();
        let curvature: f64 = f.iter().map(|&j| self.d[j] * self.q[j]).sum();
        if !(slope > 0.0 && curvature > 0.0) {
            return passes;
        }
        let mut t = slope / curvature;
        let mut first_bound = None;
        for &j in f {
            let dj = self.d[j];
            let room = if dj < 0.0 { x[j] / -dj } else if dj > 0.0 { (upper[j] - x[j]) / dj } else { f64::INFINITY };
            if room < t {
                t = room;
                first_bound = Some((j, if dj < 0.0 { 0.0 } else { upper[j] }));
            }
        }
        if !(t > 0.0 && t.is_finite()) {
            return passes;
        }
        for &j in f {
            x[j] = (x[j] + t * self.d[j]).max(0.0).min(upper[j]);
        }
        if let Some((j, bound)) = first_bound {
            x[j] = bound;
        }
        for (g, q) in grad.iter_mut().zip(&self.q) {
            *g -= t * q;
        }
        passes + 1
    }
}

/// The nonzero entries of a dense square matrix, row by row (compressed sparse rows).
struct SparseRows {
    start: Vec<usize>,
    col: Vec<u32>,
    val: Vec<f64>,
}

impl SparseRows {
    fn of_dense(g: &[f64], n: usize) -> SparseRows {
        let mut s = SparseRows { start: Vec::with_capacity(n + 1), col: Vec::new(), val: Vec::new() };
        s.start.push(0);
        for row in g.chunks_exact(n.max(1)).take(n) {
            for (l, &v) in row.iter().enumerate() {
                if v != 0.0 {
                    s.col.push(l as u32);
                    s.val.push(v);
                }
            }
            s.start.push(s.col.len());
        }
        s
    }

    fn nnz(&self) -> usize {
        self.col.len()
    }

    /// The symmetric matrix whose upper triangle's nonzero entries are `upper[p]` (row `p`'s,
    /// columns `>= p` ascending): every row with both triangles, ascending (what
    /// [`SparseRows::of_dense`] gives of the mirrored dense matrix).
    fn of_upper(upper: &[Vec<(u32, f64)>]) -> SparseRows {
        let n = upper.len();
        // The strictly lower part, row by row: row `q` holds `(p, G_pq)` for `p < q`, in
        // ascending `p` (rows `p` visited in order).
        let mut count = vec![0usize; n + 1];
        for (p, row) in upper.iter().enumerate() {
            row.iter().filter(|e| e.0 as usize > p).for_each(|e| count[e.0 as usize + 1] += 1);
        }
        for q in 0..n {
            count[q + 1] += count[q];
        }
        let mut lower = vec![(0u32, 0.0f64); count[n]];
        let mut fill = count.clone();
        for (p, row) in upper.iter().enumerate() {
            for &(q, v) in row.iter().filter(|e| e.0 as usize > p) {
                lower[fill[q as usize]] = (p as u32, v);
                fill[q as usize] += 1;
            }
        }
        let mut s = SparseRows { start: Vec::with_capacity(n + 1), col: Vec::with_capacity(2 * count[n] + n), val: Vec::with_capacity(2 * count[n] + n) };
        s.start.push(0);
        for (q, row) in upper.iter().enumerate() {
            for &(p, v) in lower[count[q]..count[q + 1]].iter().chain(row) {
                s.col.push(p);
                s.val.push(v);
            }
            s.start.push(s.col.len());
        }
        s
    }

    #[inline]
    fn row(&self, j: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        let r = self.start[j]..self.start[j + 1];
        self.col[r.clone()].iter().map(|&l| l as usize).zip(self.val[r].iter().copied())
    }
}

impl Col {
    /// The kind of emitter a column belongs to, for [`Fitter::kind_scales`].
    fn kind(self) -> usize {
        match self {
            Col::Light(_) => 0,
            Col::Sun | Col::Sky => 1,
            Col::Surface(_) => 2,
            Col::Ambient => 3,
            Col::Gathered => 4,
        }
    }
}

impl Fitter<'_> {
    /// The columns of the current model and their current values per channel.
    fn columns(&self) -> (Vec<Col>, Vec<[f64; 3]>) {
        let m = &self.model;
        let mut cols = Vec::new();
        let mut val = Vec::new();
        for (j, l) in m.lights.iter().enumerate() {
            cols.push(Col::Light(j));
            val.push(l.rgb.map(|v| v as f64));
        }
        if let Some(s) = &m.sun {
            cols.push(Col::Sun);
            val.push(s.rgb.map(|v| v as f64));
        }
        if let Some(k) = m.sky {
            cols.push(Col::Sky);
            val.push(k.map(|v| v as f64));
        }
        for (s, l) in m.surfaces.iter().enumerate() {
            if let Some(l) = l {
                cols.push(Col::Surface(s));
                val.push(l.map(|v| v as f64));
            }
        }
        if let Some(a) = m.ambient {
            cols.push(Col::Ambient);
            val.push(a.map(|v| v as f64));
        }
        if let Some(k) = m.gathered {
            cols.push(Col::Gathered);
            val.push(k.map(|v| v as f64));
        }
        (cols, val)
    }

    /// For [`Fitter::kind_scales`]: each kind's column ([`Col::kind`]), its emitters at their
    /// current values run once through the model's chain (an empty column for a kind the
    /// model lacks). The chain is linear, so this is the sum of the kind's columns.
    fn kind_columns(&mut self, m: &Model, cols: &[Col]) -> crate::error::Result<Vec<Vec<[f64; 3]>>> {
        let (rows, bases) = (self.rows, self.bases);
        let bare = m.chain_only();
        let mut out = vec![Vec::new(); 5];
        for (p, x) in out.iter_mut().enumerate() {
            // The model with only this kind's terms, as `Col::kind` sorts them.
            let mut one = bare.clone();
            let mut any = false;
            for col in cols.iter().filter(|c| c.kind() == p) {
                any = true;
                match *col {
                    Col::Light(_) => one.lights = m.lights.clone(),
                    Col::Sun => one.sun = m.sun,
                    Col::Sky => one.sky = m.sky,
                    Col::Surface(s) => one.surfaces[s] = m.surfaces[s],
                    Col::Ambient => one.ambient = m.ambient,
                    Col::Gathered => one.gathered = m.gathered,
                }
            }
            if !any {
                continue;
            }
            let e = if one.lights.is_empty() { Vec::new() } else { self.backend.irradiance(&self.vis, &one.lights)? };
            *x = crate::model::forward(&one, rows, bases, &self.vis, &e).x;
        }
        Ok(out)
    }

    /// Fits every linear coefficient exactly (see the module docs); returns the new
    /// relative error. Never ends above where it started: the solve fits the intervals'
    /// middles and the lower bounds the entry falls short of, not the one-sided objective
    /// itself (and, with more than
    /// [`DENSE_COLUMNS`] columns, the non-local chain), so it can land above the entry
    /// state under the full objective; then the entry state is kept.
    pub fn fit_linear(&mut self) -> f64 {
        self.linear_fits += 1;
        self.refresh_visibility();
        if self.failure.is_some() {
            return f64::NAN;
        }
        let entry = self.model.clone();
        // The entry's forward chain is the solve's first round's (the same model and
        // visibility): evaluated once.
        let (ev, landed) = self.value_frozen_and_forward(&entry);
        let e_entry = ev.rel_error;
        let e = self.solve_linear_from(landed);
        if e_entry < e || (e.is_nan() && self.failure.is_none()) {
            self.model = entry;
            self.refresh_visibility();
            return e_entry;
        }
        e
    }

    /// The solve without [`Fitter::fit_linear`]'s guard (visibility as it is), refitted
    /// while the rows at the minlight floor change; for a caller that compares the states
    /// itself and cannot afford the entry's evaluation (the placement's tries).
    pub fn solve_linear(&mut self) -> f64 {
        self.solve_linear_from(None)
    }

    /// [`Fitter::solve_linear`] given the current model's forward chain where the caller
    /// has it (the same visibility).
    fn solve_linear_from(&mut self, mut landed: Option<crate::model::Forward>) -> f64 {
        let censored = self.rows.any_censored();
        let local = self.chain_rounds > 1 && self.chain_taken_as_local();
        if self.model.minlight.is_none() && !censored && !local {
            self.fit_linear_once(censored, None, None);
            return if self.failure.is_some() { f64::NAN } else { self.value().rel_error };
        }
        // The rows held at the minlight floor, and the censored channels below their
        // bounds, depend on the coefficients: refitted until the error stops falling (a
        // fixed point of both sets), the best kept. So does the chain's non-local part
        // where the solve takes it as local: each round subtracts from the targets what
        // the previous round's coefficients give through it.
        let mut best: Option<(f64, crate::model::Model)> = None;
        let rounds = match (self.model.minlight.is_some(), censored) {
            (true, _) => MINLIGHT_ROUNDS,
            (false, true) => CENSORED_ROUNDS,
            (false, false) => 1,
        };
        let rounds = if local { rounds.max(self.chain_rounds) } else { rounds };
        // The first round solves as before (nothing subtracted): the rounds after it can
        // only keep a lower error.
        let mut offset: Option<Vec<[f64; 3]>> = None;
        // Each round's sets come from the model the previous round left, whose radiance
        // that round's evaluation computed: taken from there, not computed twice.
        for _ in 0..rounds {
            self.fit_linear_once(censored, landed.take(), offset.as_deref());
            if self.failure.is_some() {
                return f64::NAN;
            }
            let (ev, fw) = self.value_and_forward();
            let e = ev.rel_error;
            if local {
                offset = fw.as_ref().map(|fw| chain_remainder(&self.model, self.rows, self.bases, fw));
            }
            landed = fw;
            let gain = best.as_ref().map_or(f64::INFINITY, |(b, _)| *b - e);
            if gain > 1e-6 {
                best = Some((e, self.model.clone()));
            }
            // The chain's rounds shrink the remainder's error geometrically: once a round
            // gains less than `CHAIN_TOL` of the error, the next gains less still.
            if !(gain > 1e-6) || (local && !(gain > CHAIN_TOL * e)) {
                break;
            }
        }
        let (e, m) = best.expect("one round at least");
        self.model = m;
        e
    }

    /// Whether [`Fitter::fit_linear_once`] takes the chain as local: a filter or bounce in
    /// the model and more than [`DENSE_COLUMNS`] free columns, one by one.
    fn chain_taken_as_local(&self) -> bool {
        let m = &self.model;
        let nonlocal = (m.filter && self.bases.filter.is_some()) || (m.bounce.is_some() && self.bases.bounce.is_some());
        nonlocal && !self.kind_scales && self.columns().0.len() > DENSE_COLUMNS
    }

    /// One solve; `censored`: whether the rows have censored channels (their active set
    /// is taken from the current model); `landed`: the current model's forward chain where
    /// the caller has it (the same visibility); `offset`: radiance per row and channel
    /// taken off the targets where the chain is taken as local (see
    /// [`chain_remainder`]), ignored where the solve runs the chain itself.
    fn fit_linear_once(&mut self, censored: bool, landed: Option<crate::model::Forward>, offset: Option<&[[f64; 3]]>) {
        let (cols, mut values) = self.columns();
        if cols.is_empty() {
            return;
        }
        // The unknowns: one per column, or one per kind of emitter (multiplying the
        // columns' current values).
        let kinds = self.kind_scales;
        let unknown: Vec<usize> = if kinds { cols.iter().map(|c| c.kind()).collect() } else { (0..cols.len()).collect() };
        let k = if kinds { 5 } else { cols.len() };
        let unit: Vec<[f64; 3]> = if kinds { values.clone() } else { vec![[1.0; 3]; cols.len()] };
        let rows = self.rows;
        let bases = self.bases;
        let n = rows.len();
        let m = self.model.clone();
        // Rows at the minlight floor (for the current model) are left out, and a censored
        // channel the current model leaves below its lower bound is fitted to that bound
        // (its one-sided residual is then a plain one: an active set, refitted in
        // `solve_linear`'s rounds). Without it a clamped light fixture counted for nothing,
        // and a new light took intensity from the emitter that had reached the clamp.
        let (floor, below): (Vec<[bool; 3]>, Vec<[bool; 3]>) = match (m.minlight, censored) {
            (None, false) => (vec![[false; 3]; n], vec![[false; 3]; n]),
            (ml, _) => {
                let fw = match landed {
                    Some(fw) => fw,
                    None => {
                        let e = if m.lights.is_empty() {
                            Vec::new()
                        } else {
                            match self.backend.irradiance(&self.vis, &m.lights) {
                                Ok(e) => e,
                                Err(err) => {
                                    self.failure = Some(err);
                                    return;
                                }
                            }
                        };
                        crate::model::forward(&m, rows, bases, &self.vis, &e)
                    }
                };
                let floor = fw.total.iter().map(|t| [0, 1, 2].map(|c| ml.is_some_and(|ml| t[c] <= ml[c] as f64))).collect();
                let below = (0..n).map(|i| [0, 1, 2].map(|c| rows.weight[i][c] < 1.0 && fw.x[i][c] < rows.lower[i][c] as f64)).collect();
                (floor, below)
            }
        };
        let dirt = bases.dirt_of(&m);
        let nonlocal = (m.filter && bases.filter.is_some()) || (m.bounce.is_some() && bases.bounce.is_some());
        // With one multiplier per kind, the chain is linear and the kind's members keep
        // their values: each kind's column is the chain run once over the kind's emitters
        // as they are (the sum of its members' columns), whatever their number. Exact for
        // a map's thousand source lights, where column by column stopped at `DENSE_COLUMNS`
        // and took the chain as local (the filter and the bounce left out of the solve).
        let kind_cols: Option<Vec<Vec<[f64; 3]>>> = if kinds && nonlocal {
            match self.kind_columns(&m, &cols) {
                Ok(x) => Some(x),
                Err(err) => {
                    self.failure = Some(err);
                    return;
                }
            }
        } else {
            None
        };
        let dense = nonlocal && kind_cols.is_none() && cols.len() <= DENSE_COLUMNS;
        let offset = offset.filter(|o| nonlocal && !dense && kind_cols.is_none() && o.len() == n);
        // Each surface group's column (usize::MAX: off), and the first of those columns
        // (they are consecutive, in group order).
        let mut surface_col = vec![usize::MAX; m.surfaces.len()];
        cols.iter().enumerate().for_each(|(c, col)| {
            if let Col::Surface(s) = *col {
                surface_col[s] = c;
            }
        });
        let first_surface_col = cols.iter().position(|col| matches!(col, Col::Surface(_)));
        // The lights' cached unit factors (the linear fits of pruning, merging and the
        // terms' decisions see the same lights again and again).
        let units = if kind_cols.is_none() { lights::unit_lists(rows, &self.vis, &m.lights, true) } else { Vec::new() };
        // Per row of a block: (column, per-unit direct irradiance) for the sparse path, in
        // column order; the gathered column is in radiance already. Light columns run
        // over the rows their light reaches (`for_each_visible`), the rest row by row.
        let unit_direct = |block: std::ops::Range<usize>, out: &mut Vec<Vec<(usize, f64)>>| {
            out.resize_with(block.len(), Vec::new);
            out.iter_mut().for_each(Vec::clear);
            let base = block.start;
            for (c, col) in cols.iter().enumerate() {
                let mut put = |i: usize, v: f64| {
                    if v != 0.0 {
                        out[i - base].push((c, v));
                    }
                };
                match *col {
                    // The falloff cut depends on the intensity: taken at the current one.
                    // `unit_g` is generic, not a `&mut dyn` call per entry: with that and
                    // the brightest channel taken once per light, this loop's thread time
                    // on oa_dm1 halved.
                    Col::Light(j) => unit_g(rows, &self.boxes, &self.vis, &units, &m.lights, j, block.clone(), |i, g| put(i, g as f64)),
                    Col::Sun => {
                        if let Some(s) = m.sun {
                            block.clone().for_each(|i| put(i, s.cos_at(rows, &self.vis, i) as f64));
                        }
                    }
                    Col::Sky => {
                        if let Some(b) = bases.sky.as_ref() {
                            block.clone().for_each(|i| put(i, b.d[i] as f64));
                        }
                    }
                    // Every surface column at its first one: one pass over each row's
                    // entries (one per emitting patch that reaches the row; a pass per
                    // group over all of them was the largest item of oacmpdm3's source
                    // refit in a perf profile), each group's entries summed in the row's
                    // order, pushed in column order.
                    Col::Surface(_) if Some(c) == first_surface_col => {
                        for i in block.clone() {
                            let v = &mut out[i - base];
                            let start = v.len();
                            for &(g, b) in bases.surfaces.row(i) {
                                let q = surface_col.get(g as usize).copied().unwrap_or(usize::MAX);
                                if q == usize::MAX {
                                    continue;
                                }
                                match v[start..].iter_mut().find(|e| e.0 == q) {
                                    Some(e) => e.1 += b as f64,
                                    None => v.push((q, b as f64)),
                                }
                            }
                            v[start..].sort_unstable_by_key(|e| e.0);
                            let mut keep = start;
                            for r in start..v.len() {
                                if v[r].1 != 0.0 {
                                    v[keep] = v[r];
                                    keep += 1;
                                }
                            }
                            v.truncate(keep);
                        }
                    }
                    Col::Surface(_) | Col::Ambient | Col::Gathered => {}
                }
            }
        };
        // Dense columns through the chain: x_col per row and channel. A light's column is
        // a function of its per-unit direct irradiance over the rows it reaches (its
        // position, cone, visibility and falloff cut all show there) and of the chain: a
        // column with both as a recent fit's is that fit's (`ColumnCache`).
        let dense_cols: Option<Vec<std::sync::Arc<Vec<[f64; 3]>>>> = dense.then(|| {
            let chain = ChainKey::of(&m);
            let inputs: Vec<Option<ColumnInput>> = cols
                .par_iter()
                .map(|col| match *col {
                    Col::Light(j) => {
                        let mut d = Vec::new();
                        unit_g(rows, &self.boxes, &self.vis, &units, &m.lights, j, 0..n, |i, g| {
                            if g != 0.0 {
                                d.push((i as u32, g));
                            }
                        });
                        Some(ColumnInput::Light(d))
                    }
                    // The sun's column depends on its shadows as last traced: not kept.
                    Col::Sun => None,
                    Col::Sky | Col::Surface(_) | Col::Ambient | Col::Gathered => Some(ColumnInput::Term(*col)),
                })
                .collect();
            self.columns.check_owner(rows, bases);
            let cached: Vec<Option<std::sync::Arc<Vec<[f64; 3]>>>> = inputs.iter().map(|d| d.as_ref().and_then(|d| self.columns.get(chain, d))).collect();
            let out: Vec<std::sync::Arc<Vec<[f64; 3]>>> = (0..cols.len())
                .into_par_iter()
                .map(|c| {
                    if let Some(x) = &cached[c] {
                        return x.clone();
                    }
                    let mut one = m.chain_only();
                    match cols[c] {
                        // A light's column over the rows it reaches (the same values).
                        Col::Light(_) => {
                            let direct = match &inputs[c] {
                                Some(ColumnInput::Light(d)) => d.as_slice(),
                                _ => &[],
                            };
                            return std::sync::Arc::new(crate::model::light_column(&one, rows, bases, direct));
                        }
                        Col::Sun => one.sun = m.sun.map(|s| crate::model::Sun { rgb: [1.0; 3], ..s }),
                        Col::Sky => one.sky = Some([1.0; 3]),
                        Col::Surface(s) => one.surfaces[s] = Some([1.0; 3]),
                        Col::Ambient => one.ambient = Some([1.0; 3]),
                        Col::Gathered => one.gathered = Some([1.0; 3]),
                    }
                    std::sync::Arc::new(crate::model::forward(&one, rows, bases, &self.vis, &[]).x)
                })
                .collect();
            for (c, d) in inputs.into_iter().enumerate() {
                if let (Some(d), None) = (d, &cached[c]) {
                    self.columns.put(chain, d, out[c].clone());
                }
            }
            out
        });
        // The columns that are not in `unit_direct`'s lists (every row has them), in order.
        let row_wide: Vec<usize> = (0..cols.len()).filter(|&q| matches!(cols[q], Col::Ambient | Col::Gathered)).collect();
        // Each block of rows sums into a Gram matrix of only the unknowns it has (a block
        // of a map's luxels sees tens of its thousand lights; a dense k x k per block was
        // tens of MB to clear and add, and worker threads mapped and unmapped it at every
        // fit); the blocks are then added into the whole matrix in block order, so the
        // sums do not depend on how the blocks were spread over threads.
        let chunk = crate::rows::block_rows(n);
        let parts: Vec<BlockGram> = (0..n.div_ceil(chunk))
            .into_par_iter()
            .map(|ci| {
                // The rows' lists from the thread's last block (of this fit or an earlier
                // one): cleared, not freed, so a placement's hundreds of solves do not
                // allocate a list per row each time.
                let mut block_nz: Vec<Vec<(usize, f64)>> = BLOCK_NZ.take();
                let mut basis: Vec<(usize, f64)> = Vec::new();
                let mut row_b: Vec<f64> = Vec::new();
                let block = ci * chunk..((ci + 1) * chunk).min(n);
                if dense_cols.is_none() && kind_cols.is_none() {
                    unit_direct(block.clone(), &mut block_nz);
                }
                // The block's unknowns, ascending, and each one's place among them.
                let mut local = vec![u32::MAX; k];
                let mut has = vec![false; k];
                match (&dense_cols, &kind_cols) {
                    (Some(_), _) => has.iter_mut().for_each(|h| *h = true),
                    (None, Some(_)) => cols.iter().for_each(|col| has[col.kind()] = true),
                    (None, None) => {
                        block_nz.iter().flatten().for_each(|&(q, _)| has[unknown[q]] = true);
                        row_wide.iter().for_each(|&q| has[unknown[q]] = true);
                    }
                }
                let unknowns: Vec<usize> = (0..k).filter(|&p| has[p]).collect();
                unknowns.iter().enumerate().for_each(|(l, &p)| local[p] = l as u32);
                let m = unknowns.len();
                let sparse = dense_cols.is_none() && kind_cols.is_none();
                let mut part = if sparse {
                    BlockGram { gram: Default::default(), rhs: Default::default(), lanes: Some((vec![[0.0; 4]; m * m], vec![[0.0; 4]; m])), unknowns }
                } else {
                    BlockGram { gram: [vec![0.0; m * m], vec![0.0; m * m], vec![0.0; m * m]], rhs: [vec![0.0; m], vec![0.0; m], vec![0.0; m]], lanes: None, unknowns }
                };
                let mut basis3: Vec<(usize, Lanes)> = Vec::new();
                for i in block.clone() {
                    let nz: &[(usize, f64)] = block_nz.get(i - block.start).map_or(&[], Vec::as_slice);
                    // Per channel: the interval's weight, plus the rest at the lower bound
                    // where it is active (`w (mid - x)^2 + (1 - w) (lower - x)^2`), and
                    // the target; `None`: the channel is left out.
                    let wm = [0, 1, 2].map(|c| {
                        let wi = rows.weight[i][c] as f64;
                        let wl = if below[i][c] { 1.0 - wi } else { 0.0 };
                        let w = rows.area[i] as f64 * (wi + wl);
                        let off = offset.map_or(0.0, |o| o[i][c]);
                        (w != 0.0 && !floor[i][c]).then(|| (w, (wi * rows.mid(i, c) + wl * rows.lower[i][c] as f64) / (wi + wl) - off))
                    });
                    // The sparse path: the row's values for the three channels (side by
                    // side); with all three in, one pass over its pairs (`add_row3`, each
                    // channel's sums as `add_row`'s), else the channels in one by one.
                    if let Some((g4, r4)) = &mut part.lanes {
                        let a = [0, 1, 2].map(|c| rows.albedo[i][c] as f64 / std::f64::consts::PI * dirt.map_or(1.0, |d| d[i] as f64));
                        basis3.clear();
                        basis3.extend(nz.iter().map(|&(q, v)| (local[unknown[q]] as usize, [a[0] * v * unit[q][0], a[1] * v * unit[q][1], a[2] * v * unit[q][2], 0.0])));
                        for &q in &row_wide {
                            match cols[q] {
                                Col::Ambient => basis3.push((local[unknown[q]] as usize, [a[0] * unit[q][0], a[1] * unit[q][1], a[2] * unit[q][2], 0.0])),
                                Col::Gathered => basis3.push((local[unknown[q]] as usize, std::array::from_fn(|c| if c < 3 { bases.gathered.as_ref().map_or(0.0, |o| o[i][c] as f64) * unit[q][c] } else { 0.0 }))),
                                _ => {}
                            }
                        }
                        // With one unknown per kind, a kind's columns (in column order, so
                        // side by side) share their unknown: one entry, their sum (the
                        // upper-triangle sums take each unknown once).
                        if kinds {
                            coalesce(&mut basis3);
                        }
                        if let [Some(w0), Some(w1), Some(w2)] = wm {
                            add_row3(g4, r4, m, [w0, w1, w2], &basis3);
                        } else {
                            for (c, wm) in wm.iter().enumerate() {
                                if let Some((w, mid)) = *wm {
                                    add_row_lane(g4, r4, m, c, w, mid, &basis3);
                                }
                            }
                        }
                        continue;
                    }
                    for c in 0..3 {
                        let Some((w, mid)) = wm[c] else { continue };
                        // Dense columns, one unknown each (never with kinds: those have
                        // `kind_cols`): the row's values in column order (`add_dense_row`,
                        // the same sums as `add_row`'s).
                        if let Some(d) = &dense_cols {
                            row_b.clear();
                            row_b.extend((0..cols.len()).map(|q| d[q][i][c]));
                            if add_dense_row(&mut part.gram[c], &mut part.rhs[c], w, mid, &row_b) {
                                continue;
                            }
                        }
                        basis.clear();
                        match (&dense_cols, &kind_cols) {
                            (Some(d), _) => basis.extend((0..cols.len()).map(|q| (local[unknown[q]] as usize, d[q][i][c] * unit[q][c])).filter(|b| b.1 != 0.0)),
                            (None, Some(x)) => basis.extend((0..k).filter(|&p| has[p]).map(|p| (local[p] as usize, x[p][i][c])).filter(|b| b.1 != 0.0)),
                            (None, None) => unreachable!("the sparse path adds its rows above"),
                        }
                        add_row(&mut part.gram[c], &mut part.rhs[c], m, w, mid, &basis);
                    }
                }
                BLOCK_NZ.set(block_nz);
                part
            })
            .collect();
        let normal = sum_blocks(&parts, k);
        drop(parts);
        let (frozen, locked) = (self.frozen_emitters, &self.locked);
        // The three channels are independent solves: one per thread.
        let solved: Vec<Vec<f64>> = (0..3)
            .into_par_iter()
            .map(|c| {
                if kinds {
                    // Multipliers of the kinds (1: as they are); a kind without columns stays 1.
                    let mut x = vec![1.0f64; k];
                    let free = vec![true; k];
                    let upper = vec![f64::INFINITY, f64::INFINITY, f64::INFINITY, f64::INFINITY, 1.0];
                    let nc = &normal[c];
                    nnls_cd_rows(&nc.rows, &nc.diag, &nc.rhs, &mut x, &free, &upper, 20_000);
                    x
                } else {
                    let free: Vec<bool> = cols
                        .iter()
                        .map(|col| match col {
                            Col::Light(j) => !locked[*j],
                            Col::Sun | Col::Sky | Col::Surface(_) => !frozen,
                            Col::Ambient | Col::Gathered => true,
                        })
                        .collect();
                    let upper: Vec<f64> = cols.iter().map(|col| if *col == Col::Gathered { 1.0 } else { f64::INFINITY }).collect();
                    let mut x: Vec<f64> = values.iter().map(|v| v[c]).collect();
                    let nc = &normal[c];
                    nnls_cd_rows(&nc.rows, &nc.diag, &nc.rhs, &mut x, &free, &upper, 20_000);
                    x
                }
            })
            .collect();
        for (c, x) in solved.iter().enumerate() {
            for q in 0..cols.len() {
                values[q][c] = if kinds { values[q][c] * x[unknown[q]] } else { x[q] };
            }
        }
        // Keep every coefficient just above zero so its logarithm stays finite.
        let top = values.iter().flat_map(|v| v.iter()).copied().fold(1e-9, f64::max);
        let floor_v = |v: f64| v.max(1e-6 * top) as f32;
        let mm = &mut self.model;
        for (q, col) in cols.iter().enumerate() {
            let v = values[q];
            match *col {
                Col::Light(j) => {
                    if !self.locked[j] || kinds {
                        mm.lights[j].rgb = v.map(floor_v);
                    }
                }
                Col::Sun => mm.sun.as_mut().expect("a column per term").rgb = v.map(floor_v),
                Col::Sky => mm.sky = Some(v.map(floor_v)),
                Col::Surface(s) => mm.surfaces[s] = Some(v.map(floor_v)),
                Col::Ambient => mm.ambient = Some(v.map(|x| x.max(1e-9) as f32)),
                Col::Gathered => mm.gathered = Some(v.map(|x| x.clamp(1e-6, 1.0 - 1e-6) as f32)),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::backend::Cpu;
    use crate::fit::Fitter;
    use crate::model::{Bases, Light, Model};
    use crate::testutil::room;
    use crate::trace::bvh::Bvh;
    use glam::Vec3;

    /// The dense sweep `nnls_cd` replaced, kept as its reference: every entry of `G`
    /// updates the gradient.
    fn nnls_dense_reference(g: &[f64], r: &[f64], n: usize, x: &mut [f64], free: &[bool], upper: &[f64], sweeps: usize) {
        let mut grad: Vec<f64> = (0..n).map(|j| r[j] - (0..n).map(|l| g[j * n + l] * x[l]).sum::<f64>()).collect();
        for _ in 0..sweeps {
            let (mut change, mut scale) = (0.0f64, 0.0f64);
            for j in 0..n {
                let gjj = g[j * n + j];
                if !free[j] || !(gjj > 0.0) {
                    continue;
                }
                let new = ((grad[j] + gjj * x[j]) / gjj).max(0.0).min(upper[j]);
                let delta = new - x[j];
                scale = scale.max(new.abs());
                if delta != 0.0 {
                    change = change.max(delta.abs());
                    for (gl, &gjl) in grad.iter_mut().zip(&g[j * n..(j + 1) * n]) {
                        *gl -= gjl * delta;
                    }
                    x[j] = new;
                }
            }
            if change <= 1e-10 * scale.max(1e-300) {
                break;
            }
        }
    }

    /// Uniform numbers in [0, 1) from a xorshift generator (`seed` nonzero).
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut rng = seed;
        move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// Lights along a corridor, each overlapping its neighbours only: a banded Gram
    /// matrix (most entries zero), some lights held, some bounded, some pushed below zero.
    /// The sparse sweep gives the dense sweep's solution to the bit.
    #[test]
    fn the_sparse_sweep_is_the_dense_one_to_the_bit() {
        let n = 300;
        let mut next = uniform(0x2545_f491_4f6c_dd1d);
        // G = A'A with A's columns supported on a window of rows around each light.
        let m = 2 * n;
        let mut a = vec![0.0f64; m * n];
        for j in 0..n {
            for i in (2 * j).saturating_sub(6)..(2 * j + 7).min(m) {
                a[i * n + j] = next();
            }
        }
        let mut g = vec![0.0f64; n * n];
        for p in 0..n {
            for q in 0..n {
                g[p * n + q] = (0..m).map(|i| a[i * n + p] * a[i * n + q]).sum();
            }
        }
        let r: Vec<f64> = (0..n).map(|_| next() - 0.3).collect();
        let free: Vec<bool> = (0..n).map(|j| j % 17 != 0).collect();
        let upper: Vec<f64> = (0..n).map(|j| if j % 29 == 0 { 0.05 } else { f64::INFINITY }).collect();
        let x0: Vec<f64> = (0..n).map(|_| next()).collect();
        assert!(g.iter().filter(|v| **v == 0.0).count() > n * n * 9 / 10, "the case is not sparse");
        for sweeps in [3, 50, 2000] {
            let (mut xs, mut xd) = (x0.clone(), x0.clone());
            super::nnls_cd(&g, &r, n, &mut xs, &free, &upper, sweeps);
            nnls_dense_reference(&g, &r, n, &mut xd, &free, &upper, sweeps.max(50));
            assert_eq!(xs.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), xd.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "{sweeps} sweeps");
            assert!(xs.iter().zip(&upper).zip(&free).all(|((x, u), f)| !f || (*x >= 0.0 && x <= u)), "a free entry out of its bounds");
            assert!(xs.iter().zip(&x0).zip(&free).any(|((x, x0), f)| *f && x != x0), "nothing moved");
        }
    }

    /// `G = A'A` for `n` lights along a corridor of `2n` rows, light `j`'s column on the
    /// rows within `half` of row `2j`: random entries, or (`smooth`) a bump shared by all,
    /// so that neighbouring columns are nearly parallel, as a thousand overlapping source
    /// lights are. Returns `G` dense and a right-hand side pushing some entries below zero.
    fn corridor(n: usize, half: usize, smooth: bool, seed: u64) -> (Vec<f64>, Vec<f64>) {
        let mut next = uniform(seed);
        let m = 2 * n;
        let mut a = vec![0.0f64; m * n];
        for j in 0..n {
            for i in (2 * j).saturating_sub(half)..(2 * j + half + 1).min(m) {
                let u = (i as f64 - 2.0 * j as f64) / half as f64;
                a[i * n + j] = if smooth { (1.0 - u * u) * (1.0 + 0.01 * next()) } else { next() };
            }
        }
        let mut g = vec![0.0f64; n * n];
        for p in 0..n {
            for q in 0..n {
                g[p * n + q] = (0..m).map(|i| a[i * n + p] * a[i * n + q]).sum();
            }
        }
        // The right-hand side of a mostly positive solution, some of it below zero.
        let truth: Vec<f64> = (0..n).map(|_| next() - 0.2).collect();
        let r = (0..n).map(|p| (0..n).map(|q| g[p * n + q] * truth[q]).sum()).collect();
        (g, r)
    }

    fn objective(g: &[f64], r: &[f64], x: &[f64]) -> f64 {
        let n = x.len();
        (0..n).map(|j| 0.5 * x[j] * (0..n).map(|l| g[j * n + l] * x[l]).sum::<f64>() - r[j] * x[j]).sum()
    }

    /// Nearly parallel columns, some held, some bounded: with the subspace steps the solve
    /// lands on the minimum the sweeps alone reach (the same objective; the optimality
    /// conditions hold) in a fifth of their sweeps or less. Fails without the steps (the
    /// sweep count) or with a step that lands elsewhere.
    #[test]
    fn subspace_steps_reach_the_sweeps_minimum_in_a_fraction_of_the_sweeps() {
        let n = 200;
        let (g, r) = corridor(n, 24, true, 0x9e37_79b9_7f4a_7c15);
        let rows = super::SparseRows::of_dense(&g, n);
        let diag: Vec<f64> = (0..n).map(|j| g[j * n + j]).collect();
        let free: Vec<bool> = (0..n).map(|j| j % 23 != 0).collect();
        let upper: Vec<f64> = (0..n).map(|j| if j % 31 == 0 { 0.01 } else { f64::INFINITY }).collect();
        let x0 = vec![0.1f64; n];
        let (mut plain, mut fast) = (x0.clone(), x0.clone());
        let sweeps_plain = super::nnls_cd_rows_with(&rows, &diag, &r, &mut plain, &free, &upper, 1_000_000, 0);
        let sweeps_fast = super::nnls_cd_rows_with(&rows, &diag, &r, &mut fast, &free, &upper, 1_000_000, super::SUBSPACE_EVERY);
        let (fp, ff) = (objective(&g, &r, &plain), objective(&g, &r, &fast));
        assert!(sweeps_plain > 1000, "the case is not hard: {sweeps_plain} sweeps");
        assert!(sweeps_fast * 5 <= sweeps_plain, "{sweeps_fast} sweeps with the subspace steps against {sweeps_plain} without");
        assert!((ff - fp).abs() <= 1e-10 * fp.abs(), "objective {ff} against the sweeps' {fp}");
        // Optimality: a free coordinate inside its bounds has no gradient; one at a bound
        // one that points out.
        let scale = (0..n).map(|j| r[j].abs()).fold(0.0, f64::max);
        for j in (0..n).filter(|&j| free[j]) {
            let gj = r[j] - (0..n).map(|l| g[j * n + l] * fast[l]).sum::<f64>();
            let x = fast[j];
            assert!(x >= 0.0 && x <= upper[j], "{j}: {x} outside its bounds");
            let ok = if x == 0.0 { gj <= 1e-7 * scale } else if x == upper[j] { gj >= -1e-7 * scale } else { gj.abs() <= 1e-7 * scale };
            assert!(ok, "{j}: x {x}, descent {gj}");
        }
        assert!(fast.iter().zip(&free).zip(&x0).all(|((x, f), x0)| *f || x == x0), "a held coordinate moved");
    }

    /// A subspace step from any point inside the bounds never raises the objective, stays
    /// inside the bounds, and leaves the kept gradient equal to `r - Gx` computed afresh.
    #[test]
    fn a_subspace_step_never_raises_the_objective() {
        let n = 120;
        for (k, (half, smooth)) in [(6, false), (20, true), (40, true)].into_iter().enumerate() {
            let (g, r) = corridor(n, half, smooth, 0x2545_f491_4f6c_dd1d + k as u64);
            let rows = super::SparseRows::of_dense(&g, n);
            let diag: Vec<f64> = (0..n).map(|j| g[j * n + j]).collect();
            let free: Vec<bool> = (0..n).map(|j| j % 11 != 0).collect();
            let upper: Vec<f64> = (0..n).map(|j| if j % 7 == 0 { 0.3 } else { f64::INFINITY }).collect();
            let mut x: Vec<f64> = (0..n).map(|j| if j % 5 == 0 { 0.0 } else { 0.05 + 0.2 * ((j * 37 % 17) as f64 / 17.0) }).collect();
            let mut step = super::Subspace::default();
            for round in 0..5 {
                let mut grad: Vec<f64> = (0..n).map(|j| r[j] - (0..n).map(|l| g[j * n + l] * x[l]).sum::<f64>()).collect();
                let before = objective(&g, &r, &x);
                step.step(&rows, &diag, &mut grad, &mut x, &free, &upper);
                let after = objective(&g, &r, &x);
                assert!(after <= before, "case {k}, round {round}: {before} -> {after}");
                assert!(x.iter().zip(&upper).all(|(x, u)| *x >= 0.0 && x <= u), "case {k}: out of the bounds");
                for j in 0..n {
                    let fresh = r[j] - (0..n).map(|l| g[j * n + l] * x[l]).sum::<f64>();
                    assert!((fresh - grad[j]).abs() <= 1e-9 * (1.0 + fresh.abs()), "case {k}, {j}: kept {} against {fresh}", grad[j]);
                }
                if round == 0 {
                    assert!(after < before, "case {k}: the first step did not move");
                }
            }
        }
    }

    /// Most rows censored far above what the two-sided rows ask: whatever the solve lands
    /// on, `fit_linear` never ends above a bright entry state.
    #[test]
    fn the_linear_fit_never_ends_above_its_entry() {
        let (mesh, mut rows) = room(6);
        for i in 0..rows.len() {
            let censored = i % 4 != 0;
            rows.weight[i] = if censored { [0.0; 3] } else { [1.0; 3] };
            rows.lower[i] = if censored { [2.0; 3] } else { [0.0; 3] };
            rows.lo[i] = [0.1; 3];
            rows.hi[i] = [0.12; 3];
        }
        rows.finish();
        let bvh = Bvh::build(&mesh);
        let bases = Bases::default();
        let (lo, hi) = mesh.bounds();
        let mut cpu = Cpu::new(&rows, &bvh);
        let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
        // The entry: the light's best intensity under the full objective, on a coarse scan.
        fit.locked = vec![false];
        let at = |i: f32| Model { lights: vec![Light::point(Vec3::new(2.0, 1.25, 1.5), [i; 3])], ..Model::default() };
        let (e_entry, entry) = [1.0f32, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0]
            .into_iter()
            .map(|i| {
                fit.model = at(i);
                (fit.eval().rel_error, at(i))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap();
        // The solve alone does land above the entry here (else this test tests nothing).
        fit.fit_linear_once(true, None, None);
        let e_solve = fit.eval().rel_error;
        assert!(e_solve > e_entry + 0.05, "the case is not hard: entry {e_entry}, solve {e_solve}");
        fit.model = entry.clone();
        let e = fit.fit_linear();
        assert!(e <= e_entry + 1e-12, "fit_linear ended above its entry: {e_entry} -> {e}");
        assert_eq!(e, fit.eval().rel_error, "the error returned is the state's");
        // From a state the solve improves on, the solve is taken.
        let dim = Model { lights: vec![Light::point(Vec3::new(2.0, 1.25, 1.5), [1e-3; 3])], ..Model::default() };
        fit.model = dim.clone();
        let e_dim = fit.eval().rel_error;
        let e2 = fit.fit_linear();
        assert!(e2 < e_dim - 0.02, "the solve was not taken: {e_dim} -> {e2}");
        assert!(e2.is_finite());
        // `fit_linear` hands the entry's forward chain to the solve's first round: the
        // solve that runs its own lands on the same bits.
        let landed = fit.model.clone();
        fit.model = dim;
        fit.refresh_visibility();
        let e3 = fit.solve_linear();
        assert_eq!((e3.to_bits(), &fit.model), (e2.to_bits(), &landed), "the entry's chain is not the first round's");
    }

    /// `room(6)` with the bases of a bounce and a filter (`testutil::chain_bases`), its
    /// tree and bounds, and 70 point lights spread through it (more than
    /// `DENSE_COLUMNS`).
    fn seventy_lights_room() -> (crate::rows::Rows, Bases, Bvh, (Vec3, Vec3), Vec<Light>) {
        let (mesh, rows) = room(6);
        let bases = crate::testutil::chain_bases(rows.len(), 3);
        let bvh = Bvh::build(&mesh);
        let bounds = mesh.bounds();
        (rows, bases, bvh, bounds, seventy_lights())
    }

    fn seventy_lights() -> Vec<Light> {
        (0..70)
            .map(|j| {
                let t = j as f32 / 70.0;
                let p = Vec3::new(0.5 + 3.0 * t, 0.5 + 2.0 * ((j * 7 % 10) as f32 / 10.0), 0.5 + 2.0 * ((j * 3 % 10) as f32 / 10.0));
                Light::point(p, [0.05 + 0.02 * (j % 5) as f32, 0.06, 0.04 + 0.01 * (j % 3) as f32])
            })
            .collect()
    }

    /// Past `DENSE_COLUMNS` free columns the solve takes the chain as local; its rounds
    /// then take the previous round's bounce and filter spread off the targets. The data
    /// is a bounced, filtered model of 70 lights plus an ambient; the fit from every light
    /// at one value reaches it, where the one local solve of before left several percent.
    #[test]
    fn many_free_columns_see_the_chain_through_rounds() {
        let (mut rows, bases, bvh, (lo, hi), lights) = seventy_lights_room();
        let truth = Model { lights: lights.clone(), ambient: Some([0.03, 0.02, 0.025]), bounce: Some([0.8, 0.6, 0.7]), dirt: Some(crate::scene::DirtSettings::Q3MAP2), filter: true, ..Model::default() };
        crate::testutil::data_from_model(&mut rows, &bases, &bvh, &truth, 5e-4);
        let start = Model { lights: lights.iter().map(|l| Light { rgb: [0.1; 3], ..*l }).collect(), ambient: Some([0.01; 3]), ..truth.clone() };
        let mut cpu = Cpu::new(&rows, &bvh);
        let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
        fit.locked = vec![false; lights.len()];
        fit.model = start.clone();
        assert!(fit.chain_taken_as_local(), "the case does not take the chain as local");
        // One local solve, as before the rounds.
        fit.refresh_visibility();
        fit.fit_linear_once(false, None, None);
        let e_once = fit.eval().rel_error;
        fit.model = start;
        let e = fit.fit_linear();
        assert!(e_once > 0.02, "one local solve is not off here (the test tests nothing): {e_once}");
        assert!(e < 0.2 * e_once && e < 5e-3, "the rounds through the chain: {e_once} -> {e}");
    }

    /// With one multiplier per kind (the globals fit), the filter and the bounce are in the
    /// solve at any number of lights: the data is a bounced, filtered model of 70 lights
    /// (more than `DENSE_COLUMNS`) at half their stated values plus an ambient, and the
    /// fit from the stated values finds the half and the ambient. Taking the chain as local
    /// past `DENSE_COLUMNS` columns, as before, left an error of several percent.
    #[test]
    fn kind_scales_see_the_chain_at_any_number_of_lights() {
        let (mut rows, bases, bvh, (lo, hi), lights) = seventy_lights_room();
        let stated = Model { lights: lights.clone(), ambient: Some([0.01; 3]), bounce: Some([0.8, 0.6, 0.7]), dirt: Some(crate::scene::DirtSettings::Q3MAP2), filter: true, ..Model::default() };
        assert!(lights.len() > super::DENSE_COLUMNS);
        let truth = Model { lights: lights.iter().map(|l| Light { rgb: l.rgb.map(|c| c * 0.5), ..*l }).collect(), ambient: Some([0.03, 0.02, 0.025]), ..stated.clone() };
        crate::testutil::data_from_model(&mut rows, &bases, &bvh, &truth, 5e-4);
        let mut cpu = Cpu::new(&rows, &bvh);
        let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
        fit.kind_scales = true;
        fit.frozen_emitters = true;
        fit.locked = vec![true; lights.len()];
        fit.model = stated;
        let e = fit.fit_linear();
        assert!(e < 1e-3, "the kinds' fit through the chain: relative error {e}");
        for (l, t) in fit.model.lights.iter().zip(&truth.lights) {
            for c in 0..3 {
                assert!((l.rgb[c] / t.rgb[c] - 1.0).abs() < 1e-3, "a light's scale: {:?} against {:?}", l.rgb, t.rgb);
            }
        }
        let a = fit.model.ambient.unwrap();
        assert!(a.iter().zip(truth.ambient.unwrap()).all(|(a, t)| (a / t - 1.0).abs() < 1e-2), "ambient {a:?}");
    }

    /// The dense path's kept columns are the ones it would compute: fits from one state
    /// agree to the bit with no cache, and with one that starts empty, holds that
    /// state's columns, or holds other states' (a bounce, dirt and filter chain, three
    /// lights and the ambient).
    #[test]
    fn kept_columns_change_no_bit_of_the_fit() {
        let (mesh, rows) = room(6);
        let n = rows.len();
        let bases = crate::testutil::chain_bases(n, 3);
        let bvh = Bvh::build(&mesh);
        let (lo, hi) = mesh.bounds();
        // Light 0 `dx` m off and `scale` times as bright.
        let start = |(scale, dx): (f32, f32)| Model {
            lights: vec![Light::point(Vec3::new(1.1 + dx, 1.7, 0.9), [2.0 * scale; 3]), Light::point(Vec3::new(2.6, 2.4, 2.2), [0.7 * scale, 1.2, 1.9]), Light::point(Vec3::new(0.7, 0.9, 2.1), [1.2; 3])],
            ambient: Some([0.01; 3]),
            bounce: Some([0.8, 0.6, 0.7]),
            dirt: Some(crate::scene::DirtSettings::Q3MAP2),
            filter: true,
            ..Model::default()
        };
        let fitted = |warm: &[(f32, f32)], keep: bool| {
            let mut cpu = Cpu::new(&rows, &bvh);
            let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
            fit.locked = vec![false; 3];
            if !keep {
                fit.columns.budget_bytes = 0;
            }
            for &s in warm {
                fit.model = start(s);
                fit.fit_linear();
            }
            fit.model = start((1.0, 0.0));
            let e = fit.fit_linear();
            (e, fit.model.clone(), fit.columns.hits)
        };
        let (e0, m0, hits0) = fitted(&[], false);
        assert_eq!(hits0, 0);
        assert!(m0.lights.iter().any(|l| l.rgb != [2.0; 3]) && e0.is_finite());
        // A state whose light 0 lights the same rows a little differently (its input
        // differs in values only), the state itself, and others.
        for warm in [&[][..], &[(1.0f32, 0.01f32)], &[(1.0, 0.0)], &[(3.0, 0.0)], &[(3.0, 0.2), (1.0, 0.0), (0.5, 0.0)]] {
            let (e, m, hits) = fitted(warm, true);
            assert_eq!(e.to_bits(), e0.to_bits(), "warmed by {warm:?}");
            assert_eq!(m, m0, "warmed by {warm:?}");
            assert!(hits > 0, "warmed by {warm:?}: no column was kept");
        }
    }

    /// A dense row's share of the normal equations is the sparse one's to the bit, with
    /// zeros among its values; a value that is not finite, or negative, is left to the
    /// sparse form.
    #[test]
    fn a_dense_row_adds_what_its_nonzero_entries_add() {
        let m = 7;
        let (mut g1, mut r1) = (vec![0.0f64; m * m], vec![0.0f64; m]);
        let (mut g2, mut r2) = (g1.clone(), r1.clone());
        for row in 0..50u32 {
            let b: Vec<f64> = (0..m as u32).map(|q| if (row + q) % 3 == 0 { 0.0 } else { crate::model::bounce::hash01(row, q) as f64 * 1e3f64.powi((q % 4) as i32 - 2) }).collect();
            let (w, mid) = (0.3 + 0.01 * row as f64, 1.0 / (1.0 + row as f64));
            let basis: Vec<(usize, f64)> = b.iter().copied().enumerate().filter(|e| e.1 != 0.0).collect();
            super::add_row(&mut g1, &mut r1, m, w, mid, &basis);
            assert!(super::add_dense_row(&mut g2, &mut r2, w, mid, &b));
        }
        assert!(g1.iter().zip(&g2).all(|(a, b)| a.to_bits() == b.to_bits()));
        assert!(r1.iter().zip(&r2).all(|(a, b)| a.to_bits() == b.to_bits()));
        assert!(g1.iter().filter(|v| **v != 0.0).count() > m);
        for bad in [f64::INFINITY, f64::NAN, -1.0] {
            let before = g2.clone();
            assert!(!super::add_dense_row(&mut g2, &mut r2, 1.0, 1.0, &[1.0, bad, 0.0, 1.0, 1.0, 1.0, 1.0]));
            assert_eq!(g2, before);
        }
    }

    /// Columns that share an unknown (one scale per kind, `--fit globals`) summed into one
    /// entry, then the upper triangle mirrored: the matrix every pair of the columns' own
    /// entries adds up to (the sum over all ordered pairs, as the full loop summed it).
    #[test]
    fn shared_unknowns_add_every_pair_of_their_columns() {
        let m = 4;
        let h = |a: u32, b: u32| crate::model::bounce::hash01(a, b) as f64;
        let (mut g, mut r) = (vec![[0.0f64; 4]; m * m], vec![[0.0f64; 4]; m]);
        let mut full: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; m * m]);
        for row in 0..100u32 {
            // Three columns of unknown 0, one of 1, two of 3 (2 absent), in order.
            let cols: Vec<(usize, [f64; 4])> = [0usize, 0, 0, 1, 3, 3].iter().enumerate().map(|(j, &p)| (p, std::array::from_fn(|c| if c < 3 { h(row, 10 * j as u32 + c as u32) } else { 0.0 }))).collect();
            let wm = [0, 1, 2].map(|c| (0.5 + h(row, 100 + c), h(row, 200 + c)));
            for c in 0..3 {
                for &(p, bp) in &cols {
                    for &(q, bq) in &cols {
                        full[c][p * m + q] += wm[c as usize].0 * bp[c] * bq[c];
                    }
                }
            }
            let mut basis = cols.clone();
            super::coalesce(&mut basis);
            assert_eq!(basis.iter().map(|e| e.0).collect::<Vec<_>>(), [0, 1, 3]);
            super::add_row3(&mut g, &mut r, m, wm, &basis);
        }
        for c in 0..3 {
            let mut gc: Vec<f64> = g.iter().map(|e| e[c]).collect();
            super::mirror_upper(&mut gc, m);
            for (a, b) in full[c].iter().zip(&gc) {
                assert!((a - b).abs() <= 1e-12 * a.abs().max(1.0), "channel {c}: {a} against {b}");
            }
            assert!(gc[0] > 0.0 && gc[3] > 0.0 && gc[2 * m + 2] == 0.0);
        }
        assert!(g.iter().chain(&r).all(|e| e[3] == 0.0), "the fourth lane stays zero");
    }

    /// The blocks' shares summed row-parallel into sparse rows (`sum_blocks`) are what one
    /// loop over the blocks into a dense matrix, mirrored and scanned for its nonzeros,
    /// gives, to the bit: block parts of both layouts (lanes, per channel), unknowns
    /// shared and not, entries that cancel to zero, any number of unknowns around
    /// `SUM_ROWS`.
    #[test]
    fn summed_blocks_are_the_dense_sums_to_the_bit() {
        let h = |a: u32, b: u32| crate::model::bounce::hash01(a, b) as f64;
        for k in [1usize, 5, super::SUM_ROWS, super::SUM_ROWS + 1, 3 * super::SUM_ROWS + 7] {
            let parts: Vec<super::BlockGram> = (0..9u32)
                .map(|b| {
                    let unknowns: Vec<usize> = (0..k).filter(|&p| h(b, p as u32) < 0.6).collect();
                    let m = unknowns.len();
                    let v = |c: usize, a: usize, e: usize| {
                        let x = h(b * 1000 + c as u32, (a * m + e) as u32);
                        // Some entries cancel across blocks: +-0.25 in blocks 0 and 1.
                        if x < 0.1 && b < 2 { if b == 0 { 0.25 } else { -0.25 } } else { x - 0.3 }
                    };
                    if b % 2 == 0 {
                        let g = (0..m * m).map(|i| [v(0, i / m, i % m), v(1, i / m, i % m), v(2, i / m, i % m), 0.0]).collect();
                        let r = (0..m).map(|a| [v(3, a, 0), v(4, a, 0), v(5, a, 0), 0.0]).collect();
                        super::BlockGram { unknowns, gram: Default::default(), rhs: Default::default(), lanes: Some((g, r)) }
                    } else {
                        let gram = std::array::from_fn(|c| (0..m * m).map(|i| v(c, i / m, i % m)).collect());
                        let rhs = std::array::from_fn(|c| (0..m).map(|a| v(c + 3, a, 0)).collect());
                        super::BlockGram { unknowns, gram, rhs, lanes: None }
                    }
                })
                .collect();
            let normal = super::sum_blocks(&parts, k);
            for c in 0..3 {
                // The reference: one loop over the blocks, the upper triangle, mirrored.
                let (mut g, mut r) = (vec![0.0f64; k * k], vec![0.0f64; k]);
                for part in &parts {
                    let m = part.unknowns.len();
                    for (a, &p) in part.unknowns.iter().enumerate() {
                        r[p] += match &part.lanes { Some((_, rl)) => rl[a][c], None => part.rhs[c][a] };
                        for (b, &q) in part.unknowns.iter().enumerate().skip(a) {
                            g[p * k + q] += match &part.lanes { Some((gl, _)) => gl[a * m + b][c], None => part.gram[c][a * m + b] };
                        }
                    }
                }
                super::mirror_upper(&mut g, k);
                let dense = super::SparseRows::of_dense(&g, k);
                let n = &normal[c];
                assert_eq!((&n.rows.start, &n.rows.col), (&dense.start, &dense.col), "k {k}, channel {c}: the nonzero pattern");
                assert!(n.rows.val.iter().zip(&dense.val).all(|(a, b)| a.to_bits() == b.to_bits()), "k {k}, channel {c}: values");
                assert!(n.diag.iter().enumerate().all(|(j, d)| d.to_bits() == g[j * k + j].to_bits()), "k {k}, channel {c}: diagonal");
                assert!(n.rhs.iter().zip(&r).all(|(a, b)| a.to_bits() == b.to_bits()), "k {k}, channel {c}: rhs");
                if k > 5 {
                    assert!(dense.nnz() < k * k, "k {k}: some entries cancel or are never met");
                }
            }
        }
    }

    /// The three channels in one pass add, channel by channel, what three `add_row`s add,
    /// to the bit (weights, targets of both signs and values over eight decades).
    #[test]
    fn three_channels_at_once_add_what_one_at_a_time_adds() {
        let m = 9;
        let h = |a: u32, b: u32| crate::model::bounce::hash01(a, b) as f64;
        let mut one: [(Vec<f64>, Vec<f64>); 3] = std::array::from_fn(|_| (vec![0.0; m * m], vec![0.0; m]));
        let (mut g3, mut r3) = (vec![[0.0f64; 4]; m * m], vec![[0.0f64; 4]; m]);
        // Rows with a channel left out go lane by lane (`add_row_lane`), into the same sums.
        let (mut gl, mut rl) = (vec![[0.0f64; 4]; m * m], vec![[0.0f64; 4]; m]);
        for row in 0..200u32 {
            let basis: Vec<(usize, [f64; 4])> = (0..m as u32).filter(|q| (row * 7 + q) % 3 != 0).map(|q| (q as usize, std::array::from_fn(|c| if c < 3 { h(row, 10 * q + c as u32) * 1e2f64.powi((q % 5) as i32 - 2) } else { 0.0 }))).collect();
            let wm = [0, 1, 2].map(|c| (0.1 + h(row, 100 + c), h(row, 200 + c) - 0.4));
            for c in 0..3 {
                let b: Vec<(usize, f64)> = basis.iter().map(|&(q, v)| (q, v[c])).collect();
                super::add_row(&mut one[c].0, &mut one[c].1, m, wm[c].0, wm[c].1, &b);
                super::add_row_lane(&mut gl, &mut rl, m, c, wm[c].0, wm[c].1, &basis);
            }
            super::add_row3(&mut g3, &mut r3, m, wm, &basis);
        }
        for c in 0..3 {
            for (lanes, what) in [((&g3, &r3), "three at once"), ((&gl, &rl), "lane by lane")] {
                assert!(one[c].0.iter().zip(lanes.0).all(|(a, b)| a.to_bits() == b[c].to_bits()), "gram, channel {c}, {what}");
                assert!(one[c].1.iter().zip(lanes.1).all(|(a, b)| a.to_bits() == b[c].to_bits()), "rhs, channel {c}, {what}");
            }
            assert!((0..m).all(|p| (p..m).all(|q| g3[p * m + q][c] > 0.0)), "every pair met");
            assert!((0..m).all(|p| (0..p).all(|q| g3[p * m + q][c] == 0.0)), "the lower triangle left to `mirror_upper`");
        }
        assert!(g3.iter().chain(&r3).all(|e| e[3] == 0.0), "the fourth lane stays zero");
    }
}
