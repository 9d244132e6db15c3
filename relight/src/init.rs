//! Starting lights.
//!
//! - `grid:N`: the thesis's start, an N x N grid of lights in the horizontal mid-plane of
//!   the scene's box (intensities fitted exactly rather than all set to 1).
//! - `auto`: greedy, on a subsample of the vertices. Candidates are placed above the
//!   vertices with the largest unexplained target, along their normal at five heights
//!   ([`CANDIDATE_HEIGHTS`]: from a few decimetres off the surface to short of the
//!   opposite one), and only in free space (rays in 14 directions must all hit front
//!   faces: never inside a wall or outside the map). The candidate that removes most of
//!   the residual (exact one-light least squares) is added, it and the lights it shares
//!   rows with are refitted with a short L-BFGS on the rows they reach (every light while there are few,
//!   `neighbours`) and every intensity exactly; if that gains less than `min_gain`, the
//!   next-best candidates over other rows are tried (up to [`TRIES_PER_ROUND`] rows a
//!   round). Past the first lights a round first tries its best candidates whose light
//!   falls on different rows together (`batch`, up to [`BATCH_LIGHTS`]): one refit and two
//!   solves for several lights, kept when they gain `min_gain` each. Rows whose candidates
//!   failed are not picked again, so a round that adds nothing is followed by one that
//!   looks elsewhere; adding stops after [`FAILED_ROUNDS`] such rounds or
//!   [`FAILED_TRIES`] failed tries in a row, or at `max_lights`, or as soon as the error
//!   is below `min_gain` (a relative error is never negative, so no light could gain
//!   that much: the tries are not made, and the lights are those they would have left).
//! - `input`: the lights of the glTF (handled by the caller).

use glam::Vec3;

use crate::backend::Cpu;
use crate::fit::{Algorithm, Fitter, ParamSet, Phase};
use crate::model::{lights, Bases, Light, Model, Sun};
use crate::rows::Rows;
use crate::scene::Mesh;
use crate::trace::bvh::Bvh;
use crate::trace::visibility;

/// The 14 directions of the free-space test (6 axes, 8 diagonals).
fn directions() -> Vec<Vec3> {
    let mut d = vec![Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z];
    for x in [-1.0, 1.0] {
        for y in [-1.0, 1.0] {
            for z in [-1.0f32, 1.0] {
                d.push(Vec3::new(x, y, z).normalize());
            }
        }
    }
    d
}

/// True when `p` is inside the map's open space: every probe ray hits a front face.
pub fn free_space(mesh: &Mesh, bvh: &Bvh, p: Vec3, far: f32) -> bool {
    let mut bad = 0;
    for d in directions() {
        match bvh.first_hit(p, d * far, 1.0) {
            None => bad += 1,
            Some((_, t)) => {
                let [a, b, c] = mesh.triangles[t as usize].map(|i| mesh.positions[i as usize]);
                if (b - a).cross(c - a).dot(d) > 0.0 {
                    bad += 1;
                }
            }
        }
        if bad > 1 {
            return false;
        }
    }
    true
}

/// `p` moved off the surfaces it is closer than `min` to: pushed along the nearest
/// triangle's front normal until it is `clear` away from that plane, a few times (a corner
/// has three walls). A row at a polygon's corner (the vertex target without subdivision)
/// stepped along its normal lies in the plane of the wall beside it; this brings such a
/// candidate into the room. `None` if it is still too close after that.
fn clear_of_surfaces(mesh: &Mesh, bvh: &Bvh, mut p: Vec3, min: f32, clear: f32) -> Option<Vec3> {
    for _ in 0..4 {
        let (d, c, t) = bvh.nearest_triangle(p)?;
        if d >= min {
            return Some(p);
        }
        let [a, b, e] = mesh.triangles.get(t as usize)?.map(|i| mesh.positions[i as usize]);
        let nf = (b - a).cross(e - a).normalize_or_zero();
        if nf == Vec3::ZERO {
            return None;
        }
        p += nf * (clear - (p - c).dot(nf));
    }
    bvh.nearest(p).filter(|&(d, _)| d >= min).map(|_| p)
}

pub fn grid(n: usize, lo: Vec3, hi: Vec3) -> Vec<Light> {
    let n = n.max(1);
    let mut v = Vec::with_capacity(n * n);
    let y = 0.5 * (lo.y + hi.y);
    for i in 0..n {
        for k in 0..n {
            let fx = (i as f32 + 0.5) / n as f32;
            let fz = (k as f32 + 0.5) / n as f32;
            v.push(Light::point(Vec3::new(lo.x + fx * (hi.x - lo.x), y, lo.z + fz * (hi.z - lo.z)), [1.0; 3]));
        }
    }
    v
}

/// Heights of the dense start's candidates over a row along its normal, Quake units (a
/// small fixture's distance from its wall, and twice that), each at most half the free
/// distance to the opposite surface.
pub const DENSE_HEIGHTS_UNITS: [f32; 2] = [24.0, 48.0];

/// The dense start keeps one candidate per cell of this size, Quake units.
pub const DENSE_SPACING_UNITS: f32 = 64.0;

/// Candidates of the dense start when `--init dense` names no count.
pub const DENSE_DEFAULT: usize = 1000;

/// `dense:N`: an over-complete start for maps lit by many small sources. Up to `n` point
/// lights in free space over the rows with the most light (area times each channel's
/// data, a censored channel's lower bound), at [`DENSE_HEIGHTS_UNITS`] along each row's
/// normal, one per cell of [`DENSE_SPACING_UNITS`]. The caller fits them all at once (a
/// non-negative linear fit zeroes most), refits and prunes: where the greedy placement
/// adds one light for the largest shortfall at a time and stops when the next gains too
/// little, this start lets hundreds of small lights share the data from the first solve.
/// The candidates follow the data, not what the map's emitters leave of it: fitted alone,
/// the emitters stretch over light the lights will explain (oacmpdm2 0.0553 and oacmpdm3
/// 0.1597 over that residual, 0.0508 and 0.1486 over the data, before the second
/// pruning; docs/fidelity.md); the
/// first exact fit shares the data between the candidates and the emitters.
///
/// `units_m` is meters per Quake unit, `min_dist` the lights' least distance to a surface
/// (m), `diag` the light box's diagonal (m). Dark rows give no candidate; the result is
/// empty where every row is dark.
pub fn dense(mesh: &Mesh, rows: &Rows, bvh: &Bvh, n: usize, units_m: f32, min_dist: f32, diag: f32) -> Vec<Light> {
    let mut order: Vec<(f64, usize)> = (0..rows.len())
        .map(|i| ((0..3).map(|c| shortfall(rows, i, c, 0.0).0.max(0.0)).sum::<f64>() * rows.area[i] as f64, i))
        .filter(|(r, _)| *r > 0.0 && r.is_finite())
        .collect();
    order.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let cell = (DENSE_SPACING_UNITS * units_m).max(1e-4);
    let mut taken: std::collections::HashSet<[i64; 3]> = std::collections::HashSet::new();
    let mut out = Vec::new();
    let far = 0.3 * diag.max(1e-3);
    for &(_, i) in &order {
        if out.len() >= n {
            break;
        }
        let (x0, nrm) = (rows.pos[i], rows.normal[i]);
        if !x0.is_finite() || !nrm.is_finite() || nrm == Vec3::ZERO {
            continue;
        }
        // The free distance along the normal, to the opposite surface (or `far`).
        let free = bvh.first_hit(x0 + nrm * rows.sampling.ray_offset, nrm * far, 1.0).map_or(far, |(t, _)| t * far);
        for h in DENSE_HEIGHTS_UNITS {
            let step = (h * units_m).min(0.5 * free).max(2.0 * min_dist);
            let Some(p) = clear_of_surfaces(mesh, bvh, x0 + nrm * step, min_dist, step) else { continue };
            let key = [p.x, p.y, p.z].map(|v| (v / cell).floor() as i64);
            if taken.contains(&key) || !free_space(mesh, bvh, p, 2.0 * diag) {
                continue;
            }
            taken.insert(key);
            out.push(Light::point(p, [1.0; 3]));
            if out.len() >= n {
                break;
            }
        }
    }
    out
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct AutoStats {
    pub sample_vertices: usize,
    pub candidates_tried: usize,
    pub added: usize,
    /// Candidates refitted that gained less than `min_gain` (their rows are not picked again).
    pub failed_tries: usize,
    /// Tries that added several lights at once ([`batch`]), and those that gained too
    /// little (their round then tries the best candidates one at a time).
    pub batches: usize,
    pub failed_batches: usize,
    /// Relative error on the subsample after each try that added lights (a batch counts once).
    pub errors: Vec<f64>,
    /// Where the placement's wall time went, s (what does not scale with cores shows
    /// here, next to the work that does).
    pub time_s: AutoTimes,
    /// The placement's own iterations (on the subsample), for the report's curve.
    #[serde(skip)]
    pub history: Vec<crate::fit::IterRecord>,
}

/// The placement's wall time by step, s.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct AutoTimes {
    /// The model's radiance on the subsample and the rows' order by shortfall.
    pub residual: f64,
    /// Candidate positions, their shadow rays and their one-light scores.
    pub scoring: f64,
    /// The exact linear solves around each try, and their re-traces.
    pub linear: f64,
    /// The short refits of the new light and its neighbours (re-traces included).
    pub refit: f64,
    /// Of `linear` and `refit`: re-tracing lights that moved.
    pub trace: f64,
}

/// Heights of a row's candidates, as fractions of the free distance along its normal (to
/// the opposite surface, or 0.3 of the scene's diagonal), each at least twice the lights'
/// least distance to a surface. The two lowest stand where mappers put small fixtures, a
/// few decimetres off the wall: oacmpdm2 is lit by 1237 light entities of `light` 15-90
/// (663 at 15), whose pools the higher candidates drew as one wide blob each. Measured
/// (2-core Xeon, default relight, one run each; error (lights), s; 0.2/0.45/0.7 ->
/// 0.08/0.2/0.45/0.7 -> 0.03/0.08/0.2/0.45/0.7): oacmpdm2 0.1533 (58) 32.0 s -> 0.0713 (91)
/// 30.5 s -> **0.0700** (90) 30.0 s; oacmpdm4 0.1222 (57) -> 0.1014 (59) -> **0.1019**
/// (59); oa_dm1 0.2301 (87) -> 0.2227 (105) -> **0.2076** (106); oacmpdm1 0.1699 (85) ->
/// 0.1647 (109) -> **0.1623** (108); oacmpdm3 0.1935 (115) -> 0.1914 (123) -> **0.1926**
/// (117); oacmpctf1 0.0830 (21) either way. The placement finds good lights sooner and
/// reaches `max_lights` after fewer failed tries (oa_dm1: 56 -> 5), so oa_dm1's run took
/// 30.5-30.8 s against 42.5-43.9 s (two alternating pairs; the placement 22.6-23.6 ->
/// 11.7-12.2 s).
const CANDIDATE_HEIGHTS: [f32; 5] = [0.03, 0.08, 0.2, 0.45, 0.7];

/// Rows whose best-scored candidate a round refits (best score first) before it ends
/// without a light.
const TRIES_PER_ROUND: usize = 3;

/// Rounds in a row that add no light before the placement stops (each looks at other rows).
/// On maps lit by many small sources a light is often found after several rounds of rows
/// no point light explains: oacmpdm2 over `--seed` 1, 2, 3 at 3 / 6 / 10: 0.1669 (49
/// lights) / 0.1657 / 0.1534 (59); 0.1918 (30) / 0.1781 (42) / 0.1781; 0.1444 (53) /
/// 0.1253 (63) / 0.1253; oacmpdm1 0.1692 (91) / 0.1646 (95) / 0.1646; oa_dm1, oacmpdm3,
/// oacmpdm4, oacmpctf1 and the sample the same at all three (their placements end at the
/// cap or where no row is left to try). Each failed round costs three short refits.
const FAILED_ROUNDS: usize = 10;

/// Failed tries in a row (over rounds) before the placement stops. Near its end a
/// placement tried three rows a round for [`FAILED_ROUNDS`] rounds: on oa_dm1, 62 of its
/// 151 tries came after its last light but one, 40% of its time. Measured with batches
/// (2-core machine; error, lights, placement s; without the limit -> with it): oa_dm1
/// 0.2329 (87) 15.3 s -> 0.2346 (86) 10.9 s, oacmpdm2 0.1265 (72) 27.9 s -> 0.1500 (57)
/// 9.5 s, oacmpdm1 0.1676 (92) 20.5 -> 17.7 s, oacmpdm4 0.1312 (56) 4.6 s -> 0.1286 (56)
/// 2.3 s; oacmpdm3 and oacmpctf1 the same error.
const FAILED_TRIES: usize = 10;

/// Greedy placement on a subsample of the rows. `model` is the model the lights join:
/// its terms (sun, sky, surfaces, ambient, ...) and the lights kept from the input
/// (`locked` says which are the user's locked ones); new lights are placed for what it
/// leaves unexplained. `start_time` is the clock of the run, for the iteration records.
#[allow(clippy::too_many_arguments)]
pub fn auto(mesh: &Mesh, rows: &Rows, bases: &Bases, bvh: &Bvh, lo: Vec3, hi: Vec3, model: &Model, locked: &[bool], max_lights: usize, min_gain: f64, sample: usize, seed: u64, deadline: Option<std::time::Instant>, start_time: std::time::Instant) -> (Model, AutoStats) {
    let (sub, take) = rows.subsample(sample, seed);
    let sub_bases = bases.subset(&take);
    let diag = (hi - lo).length().max(1e-3);
    let mut backend = Cpu::new(&sub, bvh);
    let mut fit = Fitter::new(&sub, &sub_bases, bvh, &mut backend, lo, hi);
    fit.start = start_time;
    fit.deadline = deadline;
    fit.model = Model { lights: Vec::new(), ..model.clone() };
    for (l, &k) in model.lights.iter().zip(locked) {
        fit.add_light(*l, k);
    }
    let mut stats = AutoStats { sample_vertices: sub.len(), candidates_tried: 0, added: 0, failed_tries: 0, batches: 0, failed_batches: 0, errors: Vec::new(), time_s: AutoTimes::default(), history: Vec::new() };
    let clock = std::time::Instant::now;
    let trace0 = fit.trace_s;
    let mut err = fit.fit_linear();
    if !err.is_finite() {
        err = 1.0;
    }
    let spacing = 0.05 * diag;
    // Which subsample rows each candidate position sees (its shadow rays), by position.
    let key = |p: Vec3| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
    let mut visible: std::collections::HashMap<[u32; 3], Vec<u32>> = std::collections::HashMap::new();
    // Rows whose candidates were tried and failed: later rounds look elsewhere (the most
    // unexplained rows are often ones no point light explains, and would be picked again
    // every round).
    let mut failed: Vec<Vec3> = Vec::new();
    let mut strikes = 0;
    // Tries that failed since the last light was added, over rounds.
    let mut fails_in_row = 0;
    // A try stands where `err - e >= min_gain` (a batch of `n`: `n * min_gain`), and the
    // error after it, `e`, is never negative: below `min_gain` none can stand, and the
    // rounds would only fail until FAILED_TRIES ends them (on the q3map2 fixtures lit by
    // two point lights, 0.2 of their 0.3 s).
    while fit.model.lights.len() < max_lights && !fit.out_of_time() && err >= min_gain {
        let t = clock();
        let x = match crate::model::radiance(&fit.model, &sub, &sub_bases, &fit.vis, &mut Cpu::new(&sub, bvh)) {
            Ok(x) => x,
            Err(_) => break,
        };
        let mut order: Vec<(f64, usize)> = (0..sub.len())
            .map(|i| {
                let r: f64 = (0..3).map(|c| shortfall(&sub, i, c, x[i][c]).0.max(0.0)).sum();
                (r * sub.area[i] as f64, i)
            })
            .filter(|(r, _)| *r > 0.0)
            .collect();
        order.sort_by(|a, b| b.0.total_cmp(&a.0));
        stats.time_s.residual += t.elapsed().as_secs_f64();
        let t = clock();
        let mut picked: Vec<usize> = Vec::new();
        for &(_, i) in &order {
            if picked.len() >= 16 {
                break;
            }
            if picked.iter().all(|&j| (sub.pos[j] - sub.pos[i]).length() > spacing) && failed.iter().all(|&q| (q - sub.pos[i]).length() > spacing) {
                picked.push(i);
            }
        }
        // Each candidate with the row it stands over (`picked`'s index).
        let mut cands: Vec<(Vec3, usize)> = Vec::new();
        for (k, &i) in picked.iter().enumerate() {
            let (x0, n) = (sub.pos[i], sub.normal[i]);
            let h = bvh.first_hit(x0 + n * sub.sampling.ray_offset, n * (0.3 * diag), 1.0).map_or(0.3 * diag, |(t, _)| t * 0.3 * diag);
            for f in CANDIDATE_HEIGHTS {
                let step = (f * h).max(2.0 * fit.min_dist);
                if let Some(p) = clear_of_surfaces(mesh, bvh, x0 + n * step, fit.min_dist, step) {
                    if free_space(mesh, bvh, p, 2.0 * diag) {
                        cands.push((p, k));
                    }
                }
            }
        }
        if cands.is_empty() {
            stats.time_s.scoring += t.elapsed().as_secs_f64();
            break;
        }
        stats.candidates_tried += cands.len();
        // Score: error removed by the best non-negative intensity per channel (the
        // candidate's light through the dirt factor; filter and bounce are not on the
        // subsample).
        let dirt = sub_bases.dirt_of(&fit.model);
        let scored: Vec<Scored> = {
            use rayon::prelude::*;
            // The same rows stay the most unexplained for several rounds, so the same
            // candidates come back (on oa_dm1 307 distinct of 3025): their shadow rays are
            // traced once. The new ones over one row are traced one after the other, each
            // trying first what stopped the rays of the one below it (the heights over a
            // row mostly meet the same walls; the same bits): the rows in parallel.
            let mut over_row: Vec<Vec<Vec3>> = vec![Vec::new(); picked.len()];
            for &(p, k) in &cands {
                if !visible.contains_key(&key(p)) && !over_row[k].iter().any(|q| key(*q) == key(p)) {
                    over_row[k].push(p);
                }
            }
            let traced: Vec<Vec<(Vec3, Vec<u32>)>> = over_row
                .par_iter()
                .map(|ps| {
                    let mut prior: Option<Vec<u64>> = None;
                    ps.iter()
                        .map(|&p| {
                            let (bits, stopped) = visibility::trace_light_hinted(bvh, &sub, p, f32::INFINITY, prior.as_deref());
                            prior = Some(stopped);
                            (p, bits)
                        })
                        .collect()
                })
                .collect();
            visible.extend(traced.into_iter().flatten().map(|(p, bits)| (key(p), bits)));
            let visible = &visible;
            cands
                .par_iter()
                .map(|&(p, k)| {
                    let bits = &visible[&key(p)];
                    let (mut h, mut g2) = ([0.0f64; 3], [0.0f64; 3]);
                    let probe = Light::point(p, [1e30; 3]);
                    // The rows it reaches, in order (a word of rows it misses costs one test).
                    visibility::each_set_bit(bits, 0..sub.len(), |i| {
                        // The falloff cut is left out: the intensity is not known yet.
                        let g = lights::g(&sub, i, &probe) as f64 * dirt.map_or(1.0, |d| d[i] as f64);
                        for c in 0..3 {
                            let (r, w) = shortfall(&sub, i, c, x[i][c]);
                            let b = sub.albedo[i][c] as f64 * g / std::f64::consts::PI;
                            h[c] += sub.area[i] as f64 * b * r;
                            g2[c] += sub.area[i] as f64 * w * b * b;
                        }
                    });
                    let score: f64 = (0..3).map(|c| if g2[c] > 0.0 && h[c] > 0.0 { h[c] * h[c] / g2[c] } else { 0.0 }).sum();
                    let rgb = [0, 1, 2].map(|c| if g2[c] > 0.0 { (h[c] / g2[c]).max(0.0) as f32 } else { 0.0 });
                    (score, p, rgb, k)
                })
                .collect()
        };
        let mut scored = scored;
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        stats.time_s.scoring += t.elapsed().as_secs_f64();
        // Past the first lights, the best candidates whose light falls on different rows
        // (and that promise about as much) are tried together: one refit and two solves
        // for several lights ([`batch`]).
        let mut added = false;
        if fit.model.lights.len() >= REFIT_ALL_UP_TO && !fit.out_of_time() {
            let members = batch(&sub, dirt, &visible, &scored, key, (max_lights - fit.model.lights.len()).min(BATCH_LIGHTS));
            if members.len() > 1 && err >= min_gain * members.len() as f64 {
                let saved = (fit.model.clone(), fit.locked.clone(), fit.vis.clone());
                let news: Vec<Light> = members.iter().map(|&m| candidate_light(&scored[m])).collect();
                let e = try_lights(&mut fit, &sub, dirt, &news, &mut stats.time_s);
                if err - e >= min_gain * news.len() as f64 {
                    stats.errors.push(e);
                    stats.added += news.len();
                    stats.batches += 1;
                    err = e;
                    added = true;
                } else {
                    (fit.model, fit.locked, fit.vis) = saved;
                    stats.failed_batches += 1;
                }
            }
        }
        // The best-scored candidate can fail once refitted (its one-light score ignores how
        // the others move); the next ones are tried, each over a different row (the
        // heights over one row tend to fail together).
        let mut tried_rows: Vec<usize> = Vec::new();
        for best in scored.iter() {
            if added || tried_rows.len() >= TRIES_PER_ROUND || fails_in_row >= FAILED_TRIES {
                break;
            }
            if tried_rows.contains(&best.3) {
                continue;
            }
            tried_rows.push(best.3);
            if !(best.0 > 0.0) || fit.out_of_time() {
                break;
            }
            let saved = (fit.model.clone(), fit.locked.clone(), fit.vis.clone());
            let e = try_lights(&mut fit, &sub, dirt, &[candidate_light(best)], &mut stats.time_s);
            if err - e < min_gain {
                (fit.model, fit.locked, fit.vis) = saved;
                failed.push(sub.pos[picked[best.3]]);
                stats.failed_tries += 1;
                fails_in_row += 1;
                continue;
            }
            stats.errors.push(e);
            stats.added += 1;
            err = e;
            added = true;
        }
        if added {
            strikes = 0;
            fails_in_row = 0;
        } else {
            strikes += 1;
            if strikes >= FAILED_ROUNDS || fails_in_row >= FAILED_TRIES {
                break;
            }
        }
    }
    stats.time_s.trace = fit.trace_s - trace0;
    stats.history = std::mem::take(&mut fit.history);
    (fit.model.clone(), stats)
}

/// A scored candidate: (score, position, intensity per channel, index of its row in the
/// round's picks).
type Scored = (f64, Vec3, [f32; 3], usize);

/// A candidate's light: its scored intensity, each channel at least a thousandth of the
/// largest (a channel at zero would stay there under the multiplicative steps).
fn candidate_light(c: &Scored) -> Light {
    let floor = c.2.iter().copied().fold(0.0f32, f32::max) * 1e-3;
    Light::point(c.1, c.2.map(|v| v.max(floor).max(1e-9)))
}

/// Adds `news`, solves every intensity exactly, refits the new lights and their
/// neighbours briefly and solves again; keeps the refit only where it lowered the error.
/// Returns the error after (the caller decides whether the lights stay).
fn try_lights(fit: &mut Fitter, sub: &Rows, dirt: Option<&[f32]>, news: &[Light], times: &mut AutoTimes) -> f64 {
    let clock = std::time::Instant::now;
    for l in news {
        fit.add_light(*l, false);
    }
    // The solves without fit_linear's guard: the placement keeps the better state itself.
    let t = clock();
    fit.refresh_visibility();
    let e0 = fit.solve_linear();
    let placed = (fit.model.clone(), fit.vis.clone());
    times.linear += t.elapsed().as_secs_f64();
    let t = clock();
    // The short refinement moves the new lights and the lights they share rows with, on
    // the rows those reach; the others are held (a refit of every light cost each round
    // time in proportion to the lights placed so far, and one on every row cost each try
    // the whole subsample's time, on a map of many rooms as on one of few). Measured on
    // the refit on the reach against the refit on every row (2-core Xeon, default relight,
    // one run each, 2026-11-29; error (lights), placement s): oa_dm1 0.2075 (106) 22.6 s
    // -> 0.2078 (100) 16.8 s; oacmpdm1 0.1623 (108) 36.9 -> 0.1615 (110) 22.6; oacmpdm2
    // 0.0676 (101) 22.0 -> 0.0702 (87) 16.4; oacmpdm3 0.1940 (116) 23.7 -> 0.1967 (118)
    // 19.0; oacmpdm4 0.1012 (59) 10.0 -> 0.1011 (58) 5.1; oacmpctf1 0.0830 (21) 12.1 ->
    // 0.0842 (20) 4.2. The errors move within the greedy path's own spread (the same
    // change summed in another order gave oa_dm1 0.2103 with 108); the later stages
    // took some of the time back (the whole runs 547 -> 530 s). 30 iterations on the
    // reach: oa_dm1 0.2146, oacmpdm1 0.1659, oacmpdm2 0.0728, oacmpdm3 0.1933, slower.
    let n = fit.model.lights.len();
    let mut near: Vec<usize> = Vec::new();
    for new in n - news.len()..n {
        for j in neighbours(sub, dirt, &fit.vis, &fit.model.lights, new) {
            if !near.contains(&j) {
                near.push(j);
            }
        }
    }
    near.sort_unstable();
    // 15 iterations: 10 made oa_dm1's default 4.6 s shorter but 0.2076 -> 0.2214 (the
    // other maps of the truth set within +-0.004; 2026-11-28, 2-core Xeon, one run each).
    fit.run_phase_on_reach("auto", Phase { algorithm: Algorithm::Lbfgs { step: 0.5 }, params: ParamSet::ALL, max_iterations: 15 }, &near, e0);
    times.refit += t.elapsed().as_secs_f64();
    let t = clock();
    fit.refresh_visibility();
    let mut e = fit.solve_linear();
    times.linear += t.elapsed().as_secs_f64();
    if !(e <= e0) {
        // The short refinement made things worse (a light slid behind a wall): undo it.
        (fit.model, fit.vis) = placed;
        e = e0;
    }
    e
}

/// Most lights one placement try adds ([`batch`]). Measured (2-core machine, with
/// [`FAILED_TRIES`]; error, lights, placement s; one light a try -> 4 -> 8): oa_dm1 0.2363
/// (81) 12.1 s -> 0.2346 (86) 10.9 s -> 0.2397 (80) 17.2 s; oacmpdm3 0.1894 (120) 17.6 s
/// -> 0.1889 (120) 10.3 s -> 0.1931 (117) 9.4 s; oacmpdm1 0.1652 (93) 18.3 s -> 0.1676
/// (92) 17.7 s -> 0.1655 (102) 20.2 s; oacmpdm2 0.1657 (51) -> 0.1500 (57); oacmpdm4
/// 0.1286 either way. Where a batch fails, its round tries the candidates one at a time.
const BATCH_LIGHTS: usize = 4;

/// Least score, against the round's best, of a candidate that joins the best in a batch.
const BATCH_SCORE: f64 = 0.5;

/// Candidates (indices into `scored`, best first) that one try adds together: the best,
/// then each next candidate over another row whose score is at least [`BATCH_SCORE`] of
/// the best's and whose light overlaps none of those taken (the cosine of their radiance
/// on the rows, as [`neighbours`] measures it, under [`NEIGHBOUR_OVERLAP`]): lights that
/// share no row add their gains, so a batch costs one refit where it would cost one each.
fn batch(sub: &Rows, dirt: Option<&[f32]>, visible: &std::collections::HashMap<[u32; 3], Vec<u32>>, scored: &[Scored], key: impl Fn(Vec3) -> [u32; 3], most: usize) -> Vec<usize> {
    let Some(best) = scored.first().filter(|b| b.0 > 0.0) else {
        return Vec::new();
    };
    let radiance = |c: &Scored| -> (Vec<f64>, f64) {
        let bits = &visible[&key(c.1)];
        let l = candidate_light(c);
        let mut v = vec![0.0f64; sub.len()];
        visibility::each_set_bit(bits, 0..sub.len(), |i| v[i] = overlap_radiance(sub, dirt, &l, i));
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        (v, norm)
    };
    let mut taken: Vec<(usize, Vec<f64>, f64)> = Vec::new();
    let (v, norm) = radiance(best);
    taken.push((0, v, norm));
    for (m, c) in scored.iter().enumerate().skip(1) {
        if taken.len() >= most || c.0 < BATCH_SCORE * best.0 {
            break;
        }
        if taken.iter().any(|t| scored[t.0].3 == c.3) {
            continue;
        }
        let (v, norm) = radiance(c);
        let apart = taken.iter().all(|(_, w, wn)| {
            let cross: f64 = v.iter().zip(w).map(|(a, b)| a * b).sum();
            !(norm > 0.0 && *wn > 0.0) || cross / (norm * wn) < NEIGHBOUR_OVERLAP
        });
        if apart && norm > 0.0 {
            taken.push((m, v, norm));
        }
    }
    taken.into_iter().map(|t| t.0).collect()
}

/// Most lights a placement round refits beside the new one ([`neighbours`]).
const NEIGHBOURS: usize = 24;

/// While the model has at most this many lights, a placement round refits all of them
/// ([`neighbours`]). The first lights were each placed to explain what the lights not yet
/// placed left, and move back as those come: on the synthetic scenes refitted by overlap
/// from the start, the third light of three came out 2% and 1 cm off (every light
/// refitted: 0.01%), and on the bundled sample the placement ended with two lights more
/// (pruned again, 0.0565 -> 0.0572). Below it every light costs little to refit.
const REFIT_ALL_UP_TO: usize = 8;

/// Least overlap ([`neighbours`]) of a light with the new one for a placement round to
/// refit it.
const NEIGHBOUR_OVERLAP: f64 = 0.02;

/// The lights a placement round refits with the new light `new`: every light while
/// there are at most [`REFIT_ALL_UP_TO`]; then the new light and the lights whose
/// radiance overlaps its own on the rows: the cosine of the two radiance vectors
/// (area-weighted, channels summed) at least [`NEIGHBOUR_OVERLAP`], the [`NEIGHBOURS`]
/// largest. A light that shares no row with the new one has the same part of the
/// objective before and after it, and is left where it is.
///
/// Measured with `--max-lights 128` (2-core machine; error, lights, wall), against a
/// refit of every light each round: oa_dm1 0.2439 (79, 34.5 s) -> 0.2363 (81, 23.1 s),
/// oacmpdm3 0.2005 (109, 39 s) -> 0.1894 (120, 42 s), oacmpdm1 0.1815 (63) -> 0.1692
/// (91); oacmpdm4 0.1220 -> 0.1286 (55). The 12 largest at 0.05 and 32 at 0.01 did no
/// better; every light refitted up to 25 lights was 4.8 s slower on oa_dm1 and no better.
fn neighbours(sub: &Rows, dirt: Option<&[f32]>, vis: &visibility::Visibility, lights: &[Light], new: usize) -> Vec<usize> {
    use rayon::prelude::*;
    if lights.len() <= REFIT_ALL_UP_TO {
        return (0..lights.len()).collect();
    }
    let radiance = |j: usize, i: usize| overlap_radiance(sub, dirt, &lights[j], i);
    let mut mine = vec![0.0f64; sub.len()];
    vis.for_each_visible(new, 0..sub.len(), |i| mine[i] = radiance(new, i));
    let own: f64 = mine.iter().map(|v| v * v).sum();
    let mut overlap: Vec<(f64, usize)> = (0..lights.len())
        .into_par_iter()
        .filter(|&j| j != new)
        .map(|j| {
            let (mut norm, mut cross) = (0.0f64, 0.0f64);
            vis.for_each_visible(j, 0..sub.len(), |i| {
                let v = radiance(j, i);
                norm += v * v;
                cross += v * mine[i];
            });
            let cos = if norm > 0.0 && own > 0.0 { cross / (norm * own).sqrt() } else { 0.0 };
            (cos, j)
        })
        .filter(|&(cos, _)| cos >= NEIGHBOUR_OVERLAP)
        .collect();
    overlap.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut out: Vec<usize> = overlap.iter().take(NEIGHBOURS).map(|&(_, j)| j).collect();
    out.push(new);
    out
}

/// Light `l`'s radiance at row `i` as the overlaps between lights measure it
/// ([`neighbours`], [`batch`]): through the dirt, channels summed, weighted by the square
/// root of the row's area (so that a dot product of two is area-weighted). The caller
/// knows the row sees the light.
fn overlap_radiance(sub: &Rows, dirt: Option<&[f32]>, l: &Light, i: usize) -> f64 {
    let a: f64 = (0..3).map(|c| sub.albedo[i][c] as f64 * l.rgb[c] as f64).sum();
    lights::g(sub, i, l) as f64 * a * dirt.map_or(1.0, |d| d[i] as f64) * (sub.area[i] as f64).sqrt()
}

/// What the data asks of row `i`, channel `c` beyond the model's `x`, and the weight of
/// that ask: `w (mid - x)` for the interval, plus `(1 - w) (lower - x)` where a censored
/// texel's lower bound is not yet reached (a saturated lightmap asks for light too).
fn shortfall(sub: &Rows, i: usize, c: usize, x: f64) -> (f64, f64) {
    let w = sub.weight[i][c] as f64;
    let below = sub.lower[i][c] as f64 - x;
    if below > 0.0 {
        (w * (sub.mid(i, c) - x) + (1.0 - w) * below, 1.0)
    } else {
        (w * (sub.mid(i, c) - x), w)
    }
}

/// The fine grids [`sun_search`] scores around a known direction, one after the other:
/// (steps each way in elevation and azimuth, step in degrees). Measured on the synthetic
/// sun: the best direction's plateau of the score can be under 0.1 degree wide.
const REFINE_GRIDS: [(i32, f64); 2] = [(8, 0.25), (5, 0.1)];
const REFINE_STEP_DEG: f64 = 0.1;

/// The sun's visibility bits of the rows towards each of a batch of directions, one bit
/// vector per direction ([`crate::backend::sun_bits`]).
pub type SunTracer<'a> = dyn FnMut(&[Vec3]) -> crate::error::Result<Vec<Vec<u32>>> + 'a;

/// The sun direction (and irradiance) that best explains what the model `base` leaves of
/// the target on `sub`. Without `from`: a coarse search over the upper hemisphere (every
/// 10 degrees of elevation, 15 of azimuth, plus `extra` directions such as the input's
/// sun), then a local pattern search halving its step from 5 degrees down to 0.05; with
/// `from`, every direction of a 0.25-degree grid within 2 degrees of it and of a
/// 0.1-degree grid within 0.5 degree of the best, then the local search from 0.1 degree. Each direction is scored
/// by the error its best non-negative irradiance removes (per channel, exact). The
/// gradient cannot do this part: it sees the cosine, not the shadows' edges. `None` when
/// no direction lowers the error.
///
/// `trace` gives the sun's visibility bits of `sub` towards a batch of directions
/// ([`crate::backend::sun_bits`]: the device's kernel or the CPU's walks); each batch of
/// the search (the coarse grid, each fine grid, each step of the pattern search) is one
/// call, and the scores are summed on the CPU in f64 whatever traced the bits.
pub fn sun_search(sub: &Rows, base: &[[f64; 3]], extra: &[Vec3], from: Option<Vec3>, trace: &mut SunTracer<'_>) -> crate::error::Result<Option<(Sun, f64)>> {
    use crate::fit::{angles as sun_angles, direction as sun_direction};
    use rayon::prelude::*;
    let score_bits = |w: Vec3, bits: &[u32]| -> (f64, [f32; 3]) {
        let (mut h, mut g2) = ([0.0f64; 3], [0.0f64; 3]);
        visibility::each_set_bit(bits, 0..sub.len(), |i| {
            let cos = sub.normal[i].dot(w).max(0.0) as f64;
            for c in 0..3 {
                // Censored rows count too: a sunlit floor is often saturated.
                let (r, w) = shortfall(sub, i, c, base[i][c]);
                let b = sub.albedo[i][c] as f64 * cos / std::f64::consts::PI;
                h[c] += sub.area[i] as f64 * b * r;
                g2[c] += sub.area[i] as f64 * w * b * b;
            }
        });
        let s: f64 = (0..3).map(|c| if g2[c] > 0.0 && h[c] > 0.0 { h[c] * h[c] / g2[c] } else { 0.0 }).sum();
        (s, [0, 1, 2].map(|c| if g2[c] > 0.0 { (h[c] / g2[c]).max(0.0) as f32 } else { 0.0 }))
    };
    // Each of `at`'s directions (elevation, azimuth) and its score, in order.
    let mut scores = |at: &[(f64, f64)]| -> crate::error::Result<Vec<(f64, (f64, f64))>> {
        let dirs: Vec<Vec3> = at.iter().map(|&(t, p)| sun_direction(t, p).0).collect();
        let bits = trace(&dirs)?;
        if bits.len() != dirs.len() {
            return Err(crate::error::Error::Gpu(format!("the sun's trace gave {} bit vectors for {} directions", bits.len(), dirs.len())));
        }
        Ok(dirs.par_iter().zip(&bits).zip(at).map(|((&w, b), &at)| (score_bits(w, b).0, at)).collect())
    };
    let mut cands: Vec<(f64, f64)> = Vec::new();
    if from.is_none() {
        for e in 0..9 {
            for a in 0..24 {
                cands.push(((5.0 + 10.0 * e as f64).to_radians(), (15.0 * a as f64).to_radians()));
            }
        }
        cands.push((90f64.to_radians(), 0.0));
    }
    cands.extend(extra.iter().chain(from.as_ref()).map(|&w| sun_angles(w)));
    let scored = scores(&cands)?;
    let Some((mut best_s, (mut t, mut p))) = scored.into_iter().max_by(|a, b| a.0.total_cmp(&b.0)) else { return Ok(None) };
    // The score is piecewise constant where the lit rows share a normal (the cosine
    // cancels in the least-squares fit; only the set of sunlit rows changes), so a pattern
    // search stalls on plateaus. From a known direction: every direction of a fine grid
    // around it first.
    if from.is_some() {
        for (cells, step_deg) in REFINE_GRIDS {
            let fine: Vec<(f64, f64)> = (-cells..=cells)
                .flat_map(|a| (-cells..=cells).map(move |b| (a, b)))
                .map(|(a, b)| ((t + (a as f64 * step_deg).to_radians()).clamp(0.0, std::f64::consts::FRAC_PI_2), p + (b as f64 * step_deg).to_radians()))
                .collect();
            let local = scores(&fine)?;
            if let Some((s, at)) = local.into_iter().max_by(|a, b| a.0.total_cmp(&b.0)).filter(|x| x.0 > best_s) {
                (best_s, (t, p)) = (s, at);
            }
        }
    }
    let mut step = if from.is_some() { REFINE_STEP_DEG } else { 5.0 }.to_radians();
    while step > 0.05f64.to_radians() {
        let around: Vec<(f64, f64)> = [(-1.0, 0.0), (1.0, 0.0), (0.0, -1.0), (0.0, 1.0), (-1.0, -1.0), (1.0, 1.0), (-1.0, 1.0), (1.0, -1.0)]
            .iter()
            .map(|(a, b)| ((t + a * step).clamp(0.0, std::f64::consts::FRAC_PI_2), p + b * step))
            .collect();
        let local = scores(&around)?;
        match local.into_iter().max_by(|a, b| a.0.total_cmp(&b.0)) {
            Some((s, at)) if s > best_s => (best_s, (t, p)) = (s, at),
            _ => step *= 0.5,
        }
    }
    if !(best_s > 0.0) {
        return Ok(None);
    }
    let w = sun_direction(t, p).0;
    let bits = trace(&[w])?;
    let rgb = score_bits(w, bits.first().map_or(&[][..], Vec::as_slice)).1;
    Ok(Some((Sun { to_sun: w, rgb: rgb.map(|v| v.max(1e-6)) }, best_s)))
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::{auto, batch, dense, free_space, Scored, BATCH_LIGHTS, DENSE_SPACING_UNITS};
    use crate::model::{Bases, Light, Model};
    use crate::testutil::{data_from_model, room};
    use crate::trace::bvh::Bvh;

    /// Once the error is below the gain a light must bring, the placement stops: no round
    /// scores candidates that could not stand, and no try fails (without the stop, the
    /// rounds after the last light fail until `FAILED_TRIES` ends them).
    #[test]
    fn the_placement_stops_once_no_light_could_gain_enough() {
        let (mesh, mut rows) = room(8);
        let bvh = Bvh::build(&mesh);
        let bases = Bases::default();
        let truth = Model { lights: vec![Light::point(Vec3::new(1.3, 1.6, 1.1), [3.0, 2.5, 2.0])], ..Model::default() };
        data_from_model(&mut rows, &bases, &bvh, &truth, 0.02);
        let (lo, hi) = mesh.bounds();
        let min_gain = 3e-4;
        let t0 = std::time::Instant::now();
        let (placed, stats) = auto(&mesh, &rows, &bases, &bvh, lo, hi, &Model::default(), &[], 8, min_gain, rows.len(), 1, None, t0);
        let last = *stats.errors.last().expect("a light was placed");
        assert!(last < min_gain, "the placed lights leave {last}: the test needs a scene they explain");
        assert_eq!(placed.lights.len(), stats.added);
        assert!(stats.added < 8, "the cap, not the error, ended the placement");
        assert_eq!((stats.failed_tries, stats.failed_batches), (0, 0), "tries were made that could not gain {min_gain}");
        // A placement that starts below the gain tries nothing.
        let (none, stats) = auto(&mesh, &rows, &bases, &bvh, lo, hi, &placed, &vec![false; placed.lights.len()], 8, min_gain, rows.len(), 1, None, t0);
        assert_eq!((none.lights.len(), stats.candidates_tried, stats.failed_tries), (placed.lights.len(), 0, 0));
    }

    /// The dense start: candidates in free space, off the walls, one per cell, no more
    /// than asked, over the lit rows (the brightest first); none where every row is dark.
    #[test]
    fn the_dense_start_fills_the_room_over_the_lit_rows() {
        let (mesh, mut rows) = room(12);
        let bvh = Bvh::build(&mesh);
        let units_m = 0.0254;
        let (min_dist, diag) = (0.05, 5.7);
        // The data: bright only on the floor's rows under x < 1 m (every other row dark).
        for i in 0..rows.len() {
            let lit = rows.normal[i].y > 0.9 && rows.pos[i].x < 1.0;
            for c in 0..3 {
                (rows.lo[i][c], rows.hi[i][c], rows.lower[i][c]) = if lit { (1.0, 1.02, 0.0) } else { (0.0, 0.0, 0.0) };
                rows.weight[i][c] = 1.0;
            }
        }
        let got = dense(&mesh, &rows, &bvh, 1000, units_m, min_dist, diag);
        assert!(!got.is_empty());
        let cell = DENSE_SPACING_UNITS * units_m;
        for (k, l) in got.iter().enumerate() {
            assert!(free_space(&mesh, &bvh, l.pos, 2.0 * diag), "candidate {k} at {:?} is not in free space", l.pos);
            let (d, _) = bvh.nearest(l.pos).unwrap();
            assert!(d >= min_dist, "candidate {k} is {d} m from a wall");
            assert!(l.pos.x < 1.0 + 0.5 && l.pos.y < 1.3, "candidate {k} at {:?} is over no lit row", l.pos);
            for m in &got[..k] {
                assert_ne!((l.pos / cell).floor(), (m.pos / cell).floor(), "two candidates in one cell");
            }
        }
        // No more than asked, the first one the same.
        let two = dense(&mesh, &rows, &bvh, 2, units_m, min_dist, diag);
        assert_eq!(two.len(), 2);
        assert_eq!(two[0].pos, got[0].pos);
        // Dark rows give no candidate.
        for i in 0..rows.len() {
            (rows.lo[i], rows.hi[i]) = ([0.0; 3], [0.0; 3]);
        }
        assert!(dense(&mesh, &rows, &bvh, 1000, units_m, min_dist, diag).is_empty());
    }

    /// A batch takes the best candidate, then those over other rows that promise at least
    /// half as much and whose light falls on rows none taken reaches; no more than asked.
    #[test]
    fn a_batch_takes_strong_candidates_whose_light_falls_apart() {
        let (_, rows) = room(8);
        let n = rows.len();
        let words = n.div_ceil(32);
        // Which rows each candidate sees: the first half, the second half, or all.
        let sees = |range: std::ops::Range<usize>| {
            let mut bits = vec![0u32; words];
            range.for_each(|i| bits[i >> 5] |= 1 << (i & 31));
            bits
        };
        let at = |x: f32| Vec3::new(x, 1.2, 1.5);
        let key = |p: Vec3| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
        let visible: std::collections::HashMap<[u32; 3], Vec<u32>> = [(at(0.5), sees(0..n / 2)), (at(1.0), sees(0..n)), (at(1.5), sees(n / 2..n)), (at(2.0), sees(n / 2..n)), (at(2.5), sees(0..n / 2))].into_iter().map(|(p, b)| (key(p), b)).collect();
        let rgb = [1.0f32; 3];
        // (score, position, intensity, row), best first.
        let scored: Vec<Scored> = vec![
            (10.0, at(0.5), rgb, 0), // the best: the first half
            (9.0, at(1.0), rgb, 1),  // every row: overlaps the best
            (8.0, at(1.5), rgb, 0),  // the second half, but over the best's row
            (7.0, at(2.0), rgb, 2),  // the second half, another row: taken
            (6.0, at(2.5), rgb, 3),  // the first half again: overlaps the best
        ];
        assert_eq!(batch(&rows, None, &visible, &scored, key, BATCH_LIGHTS), vec![0, 3]);
        assert_eq!(batch(&rows, None, &visible, &scored, key, 1), vec![0], "no more than asked");
        // A candidate under half the best's score stays out.
        let weak: Vec<Scored> = scored.iter().map(|&c| if c.0 == 7.0 { (4.9, c.1, c.2, c.3) } else { c }).collect();
        assert_eq!(batch(&rows, None, &visible, &weak, key, BATCH_LIGHTS), vec![0]);
        // Nothing worth a light: no batch.
        let none: Vec<Scored> = scored.iter().map(|&c| (0.0, c.1, c.2, c.3)).collect();
        assert!(batch(&rows, None, &visible, &none, key, BATCH_LIGHTS).is_empty());
    }
}
