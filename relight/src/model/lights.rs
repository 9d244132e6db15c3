//! Point and spot lights: the model's per-light term and the CPU reference of
//! `shaders/light_irradiance.wgsl` and `shaders/light_gradient.wgsl`.
//!
//! A light `j` of radiant intensity `I_jc` [W/sr] at `p_j` [m] gives row `i` (sample
//! point `x_i`, unit normal `n_i`) the irradiance `E_ijc = I_jc V_ij g_ij`, where `V_ij`
//! is the cached shadow-ray visibility ([`crate::trace::visibility`]) and
//!
//! ```text
//! g_ij = max(0, n_i . d) / |d| / max(|d|, eps)^2 * cone_ij,     d = p_j - x_i
//! ```
//!
//! A two-sided row takes `n_i` turned towards the light ([`Rows::facing`]): q3map2's
//! `|n . d|` for a `cull none` surface; its gradient is the same expression with that
//! normal.
//!
//! `eps` is q3map2's 16-unit distance clamp ([`Sampling::eps`]); a point light has
//! `cone = 1`. A spot light (axis `a`, unit; `r = radius / distance` at its edge) follows
//! q3map2: with `u = x - p`, the distance along the axis `t = u . a`, the distance from
//! the axis `rho = |u - a t|` and the cone's radius there `R = r t`,
//!
//! ```text
//! cone = 0                   where t <= 0 or rho >= R
//!      = (R - rho) / ramp    where R - ramp < rho < R      (ramp: 32 units)
//!      = 1                   elsewhere
//! ```
//!
//! Where a light's brightest channel adds at most [`Sampling::falloff`] (q3map2's
//! one-byte tolerance for point lights), it adds nothing.
//!
//! Gradients, for `s = n . d > 0`, `r = |d|` outside `eps`: `grad_p G = n / r^3 -
//! 3 s d / r^5` (inside `eps`: `n / (r eps^2) - s d / (r^3 eps^2)`); on the ramp, with
//! `w = u - a t`: `grad_p cone = (w / rho - r a) / ramp`, `grad_a cone = (r u + t w /
//! rho) / ramp`, `d cone / d r = t / ramp`. Visibility and the falloff cut are piecewise
//! constant: their derivative is zero almost everywhere.

use std::sync::Arc;

use glam::Vec3;
use rayon::prelude::*;

use crate::rows::{Rows, Sampling};
use crate::trace::visibility::{UnitKey, UnitList, Visibility, WordBoxes, UNIT_STRETCH_WORDS};

/// A spot light's cone (q3map2's spot: a light entity with a `target`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spot {
    /// Unit axis, from the light towards its target.
    pub axis: Vec3,
    /// The cone's radius per unit of distance along the axis at its edge, `(radius + 16)
    /// / distance` for q3map2's `radius` key (default 64).
    pub radius_by_dist: f32,
}

/// A point light (or a spot, with `spot`): position [m] and radiant intensity per
/// channel [W/sr].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    pub pos: Vec3,
    pub rgb: [f32; 3],
    pub spot: Option<Spot>,
}

impl Light {
    pub fn point(pos: Vec3, rgb: [f32; 3]) -> Light {
        Light { pos, rgb, spot: None }
    }
    /// The brightest channel, W/sr.
    pub fn max_rgb(&self) -> f32 {
        self.rgb[0].max(self.rgb[1]).max(self.rgb[2])
    }
    /// A file's point or spot light: candela to radiant intensity (`I = cd / 683` W/sr,
    /// CONVENTIONS.md) per channel of its colour.
    pub fn from_input(l: &crate::scene::InputLight) -> Light {
        let i = l.intensity_cd as f64 / crate::io::lights_out::LM_PER_W;
        Light { pos: l.position, rgb: l.color.map(|c| (c as f64 * i) as f32), spot: l.spot.map(|(axis, radius_by_dist)| Spot { axis, radius_by_dist }) }
    }
    /// What the visibility cache needs of a light: position and brightest channel.
    pub fn source(&self) -> (Vec3, f32) {
        (self.pos, self.max_rgb())
    }
}

/// [`Light::source`] of each light.
pub fn sources(lights: &[Light]) -> Vec<(Vec3, f32)> {
    lights.iter().map(Light::source).collect()
}

/// `g` of one light at one row and its derivatives.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Term {
    pub g: f32,
    /// dg / d position.
    pub dp: Vec3,
    /// dg / d spot axis (zero for a point light).
    pub da: Vec3,
    /// dg / d radius_by_dist.
    pub dr: f32,
}

/// The geometry factor of a point light at `x` (normal `n`) and its gradient with respect
/// to the light position (see the module docs).
#[inline(always)]
pub fn geometry(x: Vec3, n: Vec3, p: Vec3, eps: f32) -> (f32, Vec3) {
    let d = p - x;
    let s = n.dot(d);
    let r2 = d.length_squared();
    if !(s > 0.0) || !(r2 > 0.0) {
        return (0.0, Vec3::ZERO);
    }
    let r = r2.sqrt();
    let e2 = eps * eps;
    if r2 > e2 {
        let r3 = r2 * r;
        (s / r3, n / r3 - d * (3.0 * s / (r3 * r2)))
    } else {
        (s / (r * e2), n / (r * e2) - d * (s / (r2 * r * e2)))
    }
}

/// q3map2's spot cone at `x` and its derivatives: `(cone, d/dp, d/daxis, d/dr)`.
#[inline(always)]
pub fn cone(x: Vec3, p: Vec3, spot: &Spot, ramp: f32) -> (f32, Vec3, Vec3, f32) {
    let u = x - p;
    let t = u.dot(spot.axis);
    if !(t > 0.0) {
        return (0.0, Vec3::ZERO, Vec3::ZERO, 0.0);
    }
    let w = u - spot.axis * t;
    let rho = w.length();
    let big_r = spot.radius_by_dist * t;
    if !(rho < big_r) {
        return (0.0, Vec3::ZERO, Vec3::ZERO, 0.0);
    }
    if rho <= big_r - ramp || !(ramp > 0.0) {
        return (1.0, Vec3::ZERO, Vec3::ZERO, 0.0);
    }
    let c = (big_r - rho) / ramp;
    let w_hat = if rho > 0.0 { w / rho } else { Vec3::ZERO };
    let dp = (w_hat - spot.axis * spot.radius_by_dist) / ramp;
    let da = (u * spot.radius_by_dist + w_hat * t) / ramp;
    (c, dp, da, t / ramp)
}

/// `g` of light `l` at row `i`, with its derivatives; zero below the falloff tolerance.
#[inline(always)]
pub fn term(rows: &Rows, i: usize, l: &Light) -> Term {
    term_at(rows.pos[i], rows.facing(i, l.pos - rows.pos[i]), l, &rows.sampling)
}

/// [`term`] at an arbitrary point (the probe, the bake).
#[inline(always)]
pub fn term_at(x: Vec3, n: Vec3, l: &Light, s: &Sampling) -> Term {
    let (g0, dg0) = geometry(x, n, l.pos, s.eps);
    if g0 == 0.0 {
        return Term::default();
    }
    let t = match &l.spot {
        None => Term { g: g0, dp: dg0, da: Vec3::ZERO, dr: 0.0 },
        Some(sp) => {
            let (c, dcp, dca, dcr) = cone(x, l.pos, sp, s.spot_ramp);
            if c == 0.0 {
                return Term::default();
            }
            Term { g: g0 * c, dp: dg0 * c + dcp * g0, da: dca * g0, dr: dcr * g0 }
        }
    };
    if s.falloff > 0.0 && l.max_rgb() * t.g <= s.falloff {
        return Term::default();
    }
    t
}

/// `g` of light `l` at row `i` without its derivatives (the irradiance, the linear
/// fit, the placement's scores): [`term`]'s `g` by the same arithmetic, to the bit.
///
/// This and the factors around it are always inlined: the loops over one light's rows
/// then keep the light's fields in registers (oa_dm1's default relight about 2% faster on
/// two cores, the same bits).
#[inline(always)]
pub fn g(rows: &Rows, i: usize, l: &Light) -> f32 {
    g_at(rows.pos[i], rows.facing(i, l.pos - rows.pos[i]), l, &rows.sampling)
}

/// [`g`] at an arbitrary point.
#[inline(always)]
pub fn g_at(x: Vec3, n: Vec3, l: &Light, s: &Sampling) -> f32 {
    cut(g_uncut_at(x, n, l, s), l, s)
}

/// [`g`] before the falloff cut (which depends on the light's intensity): what a light's
/// [`UnitList`] keeps.
#[inline(always)]
pub fn g_uncut(rows: &Rows, i: usize, l: &Light) -> f32 {
    g_uncut_at(rows.pos[i], rows.facing(i, l.pos - rows.pos[i]), l, &rows.sampling)
}

/// The falloff cut of [`g`]: nothing where the light's brightest channel adds at most
/// [`Sampling::falloff`].
#[inline(always)]
pub fn cut(g: f32, l: &Light, s: &Sampling) -> f32 {
    cut_by(g, l.max_rgb(), s)
}

/// [`cut`] given the light's brightest channel ([`Light::max_rgb`], W/sr): for a loop
/// over one light's rows, which takes it once.
#[inline(always)]
pub fn cut_by(g: f32, max_rgb: f32, s: &Sampling) -> f32 {
    if s.falloff > 0.0 && max_rgb * g <= s.falloff {
        return 0.0;
    }
    g
}

/// The squared distance, m^2, beyond which the falloff cut takes every term of a light
/// whose brightest channel is `max_rgb` W/sr: the light's reach
/// ([`crate::trace::visibility::reach`]), as `g <= 1 / r^2` everywhere (the cosine and a
/// spot's cone at most 1, the clamp inside `eps` lower still), with 0.5% to spare for the
/// rounding of `g` in f32; infinite without a cut, or for an intensity that is not a
/// finite non-negative number (where the cut would not take a NaN's terms).
#[inline]
pub fn cut_dist2(max_rgb: f32, s: &Sampling) -> f32 {
    if max_rgb >= 0.0 && max_rgb.is_finite() {
        crate::trace::visibility::reach(max_rgb, s, 1.005).powi(2)
    } else {
        f32::INFINITY
    }
}

/// [`g_at`] before the falloff cut.
#[inline(always)]
fn g_uncut_at(x: Vec3, n: Vec3, l: &Light, s: &Sampling) -> f32 {
    let d = l.pos - x;
    let sd = n.dot(d);
    let r2 = d.length_squared();
    if !(sd > 0.0) || !(r2 > 0.0) {
        return 0.0;
    }
    let r = r2.sqrt();
    let e2 = s.eps * s.eps;
    let g0 = if r2 > e2 { sd / (r2 * r) } else { sd / (r * e2) };
    let g = match &l.spot {
        None => g0,
        Some(sp) => {
            let u = x - l.pos;
            let t = u.dot(sp.axis);
            if !(t > 0.0) {
                return 0.0;
            }
            let rho = (u - sp.axis * t).length();
            let big_r = sp.radius_by_dist * t;
            if !(rho < big_r) {
                return 0.0;
            }
            let c = if rho <= big_r - s.spot_ramp || !(s.spot_ramp > 0.0) { 1.0 } else { (big_r - rho) / s.spot_ramp };
            g0 * c
        }
    };
    g
}

/// What light `j`'s [`UnitList`] depends on besides its bits.
fn unit_key(l: &Light, vis: &Visibility, j: usize) -> UnitKey {
    let (axis, r) = l.spot.map_or((Vec3::splat(f32::NAN), f32::NAN), |sp| (sp.axis, sp.radius_by_dist));
    let at = vis.traced_at[j];
    [l.pos.x, l.pos.y, l.pos.z, axis.x, axis.y, axis.z, r, at.x, at.y, at.z, vis.traced_reach[j], if l.spot.is_some() { 1.0 } else { 0.0 }].map(f32::to_bits)
}

/// Per light: its cached [`UnitList`] where its geometry has one; with `build`, built
/// here (all such lights at once, in parallel) for a geometry asked the second time in a
/// row ([`crate::trace::visibility::UnitSlot`]); `None` where the caller computes [`g`]
/// itself. The values are [`g_uncut`]'s, so a caller that applies [`cut`] to them gets
/// [`g`]'s to the bit.
///
/// The evaluations ask without `build` and the linear fit with it: a phase evaluates the
/// same lights twice in a row (a line search's value, then its gradient) and moves them
/// on, so a list built there is not read again; a linear fit comes back to its lights.
pub fn unit_lists(rows: &Rows, vis: &Visibility, lights: &[Light], build: bool) -> Vec<Option<Arc<UnitList>>> {
    let mut out: Vec<Option<Arc<UnitList>>> = vec![None; lights.len()];
    let mut todo: Vec<(usize, UnitKey)> = Vec::new();
    for (j, l) in lights.iter().enumerate().take(vis.bits.len()) {
        let Some(slot) = vis.unit_slot(j) else { continue };
        let key = unit_key(l, vis, j);
        match slot.lookup(&key) {
            Ok(list) => out[j] = Some(list),
            Err(true) if build => todo.push((j, key)),
            Err(_) => {}
        }
    }
    let n = rows.len();
    let built: Vec<(usize, UnitKey, Arc<UnitList>)> = todo
        .into_par_iter()
        .map(|(j, key)| {
            let l = &lights[j];
            let words = vis.bits[j].len();
            let mut list = UnitList { values: Vec::new(), stretch_start: Vec::with_capacity(words.div_ceil(UNIT_STRETCH_WORDS)) };
            for s in 0..words.div_ceil(UNIT_STRETCH_WORDS) {
                list.stretch_start.push(list.values.len() as u32);
                let stretch = (s * UNIT_STRETCH_WORDS * 32).min(n)..((s + 1) * UNIT_STRETCH_WORDS * 32).min(n);
                vis.for_each_visible(j, stretch, |i| list.values.push(g_uncut(rows, i, l)));
            }
            (j, key, Arc::new(list))
        })
        .collect();
    for (j, key, list) in built {
        if let Some(slot) = vis.unit_slot(j) {
            slot.store(key, list.clone());
        }
        out[j] = Some(list);
    }
    out
}

/// Irradiance of every light at every row, W/m^2 per channel (CPU backend). Each block
/// of rows runs light by light over the rows the light reaches
/// ([`Visibility::for_each_visible`]) within its falloff cut's distance ([`cut_dist2`],
/// `boxes` of `rows`), so a light that reaches few rows costs little; each row still
/// sums its lights in their order, in f64.
pub fn irradiance(rows: &Rows, boxes: &WordBoxes, vis: &Visibility, lights: &[Light]) -> Vec<[f32; 3]> {
    let units = unit_lists(rows, vis, lights, false);
    let mut out = vec![[0.0f32; 3]; rows.len()];
    let block_rows = crate::rows::block_rows(rows.len());
    out.par_chunks_mut(block_rows).enumerate().for_each(|(bi, block)| {
        let base = bi * block_rows;
        let range = base..base + block.len();
        let mut e = vec![[0.0f64; 3]; block.len()];
        for (j, l) in lights.iter().enumerate() {
            let top = l.max_rgb();
            let dist2 = cut_dist2(top, &rows.sampling);
            if !l.rgb.iter().all(|v| v.is_finite()) {
                // Not a number to add without its zeros' test (`inf * 0`).
                vis.for_each_visible(j, range.clone(), |i| {
                    let g = g(rows, i, l);
                    if g != 0.0 {
                        (0..3).for_each(|c| e[i - base][c] += l.rgb[c] as f64 * g as f64);
                    }
                });
                continue;
            }
            // A cut term adds `rgb * 0 = 0`, which leaves the sum as it was (it is never
            // -0): no branch on it.
            let rgb = l.rgb.map(f64::from);
            let mut add = |i: usize, g: f32| {
                let v = &mut e[i - base];
                (0..3).for_each(|c| v[c] += rgb[c] * g as f64);
            };
            match &units[j] {
                Some(list) => vis.for_each_visible_with_within(j, range.clone(), list, boxes, l.pos, dist2, |i, g| add(i, cut_by(g, top, &rows.sampling))),
                None => vis.for_each_visible_within(j, range.clone(), boxes, l.pos, dist2, |i| add(i, g(rows, i, l))),
            }
        }
        for (o, v) in block.iter_mut().zip(e) {
            *o = v.map(|x| x as f32);
        }
    });
    out
}

/// Derivatives of the objective with respect to one light's parameters.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LightGrad {
    /// dF / d position, per meter.
    pub pos: [f64; 3],
    /// dF / dI_c, per W/sr.
    pub rgb: [f64; 3],
    /// dF / d spot axis (unnormalised direction; zero for a point light).
    pub axis: [f64; 3],
    /// dF / d radius_by_dist.
    pub radius_by_dist: f64,
}

impl LightGrad {
    pub fn add(&mut self, o: &LightGrad) {
        for q in 0..3 {
            self.pos[q] += o.pos[q];
            self.rgb[q] += o.rgb[q];
            self.axis[q] += o.axis[q];
        }
        self.radius_by_dist += o.radius_by_dist;
    }
}

/// The lights' gradients for `rho_ic = dF/dE_ic` (CPU backend; rayon over row chunks,
/// f64 sums; each light over the rows within its falloff cut's distance, as
/// [`irradiance`]).
pub fn gradient(rows: &Rows, boxes: &WordBoxes, vis: &Visibility, lights: &[Light], rho: &[[f32; 3]]) -> Vec<LightGrad> {
    let k = lights.len();
    let chunk = crate::rows::block_rows(rows.len());
    (0..rows.len().div_ceil(chunk))
        .into_par_iter()
        .map(|ci| {
            let mut g = vec![LightGrad::default(); k];
            let block = ci * chunk..((ci + 1) * chunk).min(rows.len());
            // Light by light over the rows it reaches, each light's rows in order.
            for (j, l) in lights.iter().enumerate() {
                let gj = &mut g[j];
                vis.for_each_visible_within(j, block.clone(), boxes, l.pos, cut_dist2(l.max_rgb(), &rows.sampling), |i| {
                    let r = rho[i];
                    if r == [0.0; 3] {
                        return;
                    }
                    let t = term(rows, i, l);
                    if t.g == 0.0 {
                        return;
                    }
                    let mut s = 0.0f64;
                    for c in 0..3 {
                        gj.rgb[c] += r[c] as f64 * t.g as f64;
                        s += r[c] as f64 * l.rgb[c] as f64;
                    }
                    for q in 0..3 {
                        gj.pos[q] += s * t.dp[q] as f64;
                        gj.axis[q] += s * t.da[q] as f64;
                    }
                    gj.radius_by_dist += s * t.dr as f64;
                });
            }
            g
        })
        .collect::<Vec<_>>()
        .into_iter()
        // Added in block order: the sums do not depend on how rayon split the blocks.
        .fold(vec![LightGrad::default(); k], |mut a, b| {
            for (x, y) in a.iter_mut().zip(&b) {
                x.add(y);
            }
            a
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Visibility bits for `lights` over `n` rows: light `j` sees row `i` on a pattern
    /// with whole empty words, empty blocks and a partial last word.
    fn patterned_visibility(n: usize, k: usize) -> Visibility {
        let words = n.div_ceil(32);
        let mut vis = Visibility::default();
        for j in 0..k {
            let mut bits = vec![0u32; words];
            for i in 0..n {
                let seen = match j % 3 {
                    0 => (i * 7 + j) % 5 != 0,            // most rows
                    1 => (i / 32) % 9 == j % 9 && i % 3 != 1, // a few words
                    _ => (5000..5100).contains(&i) || i + 3 >= n, // one stretch and the end
                };
                if seen {
                    bits[i >> 5] |= 1 << (i & 31);
                }
            }
            vis.push_traced(bits, Vec3::ZERO, f32::INFINITY);
        }
        vis
    }

    /// The irradiance row by row, every light's `g` computed afresh.
    fn row_by_row(rows: &Rows, vis: &Visibility, lights: &[Light]) -> Vec<[f32; 3]> {
        (0..rows.len())
            .map(|i| {
                let mut e = [0.0f64; 3];
                for (j, l) in lights.iter().enumerate() {
                    let g = if vis.visible(j, i) { g(rows, i, l) } else { 0.0 };
                    if g != 0.0 {
                        for c in 0..3 {
                            e[c] += l.rgb[c] as f64 * g as f64;
                        }
                    }
                }
                e.map(|x| x as f32)
            })
            .collect()
    }

    /// The lights' cached unit factors give the irradiance to the bit: before the cache
    /// fills, once it has, with intensities the falloff cut turns on (the cut is taken at
    /// the current intensity), with a light moved, re-traced, removed, and through
    /// `select` and `put_back`; a spot light among them.
    #[test]
    fn cached_unit_factors_give_the_irradiance_to_the_bit() {
        let (_, mut rows) = crate::testutil::room(40);
        rows.sampling.falloff = 0.02;
        let n = rows.len();
        let mut lights: Vec<Light> = (0..7).map(|j| Light::point(Vec3::new(0.5 + 0.4 * j as f32, 1.2, 0.3 + 0.35 * j as f32), [0.05 + 0.3 * j as f32, 0.2, 0.1])).collect();
        lights[3].spot = Some(Spot { axis: Vec3::new(0.3, -1.0, 0.2).normalize(), radius_by_dist: 0.8 });
        let mut vis = patterned_visibility(n, lights.len());
        let boxes = WordBoxes::of(&rows);
        let check = |vis: &Visibility, lights: &[Light], what: &str| assert!(irradiance(&rows, &boxes, vis, lights) == row_by_row(&rows, vis, lights), "{what}");
        // The evaluation sees the geometry, the linear fit's call fills the cache, the next
        // evaluation reads it.
        check(&vis, &lights, "before");
        let filled = unit_lists(&rows, &vis, &lights, true);
        assert!(filled.iter().all(Option::is_some), "every light cached on the second sight");
        check(&vis, &lights, "cached");
        let again = unit_lists(&rows, &vis, &lights, false);
        assert!(again.iter().zip(&filled).all(|(a, b)| Arc::ptr_eq(a.as_ref().unwrap(), b.as_ref().unwrap())), "the same lists read back");
        let cut_before = (0..n).filter(|&i| vis.visible(0, i) && g(&rows, i, &lights[0]) == 0.0 && g_uncut(&rows, i, &lights[0]) > 0.0).count();
        lights[0].rgb = [0.01, 0.004, 0.002];
        let cut_after = (0..n).filter(|&i| vis.visible(0, i) && g(&rows, i, &lights[0]) == 0.0 && g_uncut(&rows, i, &lights[0]) > 0.0).count();
        assert!(cut_after > cut_before, "the dimmer light is cut on more rows ({cut_before} -> {cut_after})");
        check(&vis, &lights, "a light dimmed below the falloff");
        lights[2].pos.x += 0.01;
        check(&vis, &lights, "a light moved");
        let _ = unit_lists(&rows, &vis, &lights, true);
        check(&vis, &lights, "a light moved, cached again");
        let other = patterned_visibility(n, 2).bits[1].to_vec();
        vis.set_traced(4, other, Vec3::ONE, 3.0);
        check(&vis, &lights, "a light re-traced");
        let _ = unit_lists(&rows, &vis, &lights, true);
        check(&vis, &lights, "a light re-traced, cached again");
        let part = vis.select(&[1, 3, 5]);
        let part_lights = [lights[1], lights[3], lights[5]];
        check(&part, &part_lights, "selected");
        vis.put_back(&[1, 3, 5], part);
        check(&vis, &lights, "put back");
        vis.remove(2);
        lights.remove(2);
        check(&vis, &lights, "a light removed");
    }

    /// `for_each_visible_with` visits the rows `for_each_visible` does, each with its own
    /// entry of the list, over any range.
    #[test]
    fn for_each_visible_with_pairs_rows_with_their_entries() {
        let (_, rows) = crate::testutil::room(40);
        let n = rows.len();
        let lights: Vec<Light> = (0..3).map(|j| Light::point(Vec3::new(1.0 + j as f32, 1.2, 1.0), [1.0; 3])).collect();
        let vis = patterned_visibility(n, 3);
        let _ = unit_lists(&rows, &vis, &lights, false);
        let lists = unit_lists(&rows, &vis, &lights, true);
        for (j, l) in lights.iter().enumerate() {
            let list = lists[j].as_ref().expect("cached on the second call");
            for (a, b) in [(0, n), (5, 37), (31, 33), (64, 64), (1000, 2100), (n - 10, n), (1023, 1025)] {
                let mut seen = Vec::new();
                vis.for_each_visible_with(j, a..b, list, |i, g| seen.push((i, g)));
                let want: Vec<(usize, f32)> = (a..b).filter(|&i| vis.visible(j, i)).map(|i| (i, g_uncut(&rows, i, l))).collect();
                assert_eq!(seen, want, "light {j}, rows {a}..{b}");
            }
        }
    }

    /// The words a light's falloff cut leaves out ([`cut_dist2`], [`WordBoxes`]) hold only
    /// rows where its `g` is cut to zero, and the loops within that distance visit the
    /// other rows with their own entries; the gradient, like the irradiance, is the
    /// row-by-row sum. Lights dim, bright, dark and at a wall's row.
    #[test]
    fn words_beyond_the_falloff_cut_add_nothing() {
        let (_, mut rows) = crate::testutil::room(40);
        rows.sampling.falloff = 0.02;
        let n = rows.len();
        let boxes = WordBoxes::of(&rows);
        let mut lights: Vec<Light> = (0..5).map(|j| Light::point(Vec3::new(0.5 + 0.6 * j as f32, 1.2, 0.4 + 0.5 * j as f32), [0.03 + 0.5 * j as f32, 0.02, 0.01])).collect();
        lights[2].spot = Some(Spot { axis: Vec3::new(0.2, -1.0, 0.1).normalize(), radius_by_dist: 0.9 });
        lights[3].rgb = [0.0; 3];
        lights[4].pos = rows.pos[n / 2];
        let vis = patterned_visibility(n, lights.len());
        let _ = unit_lists(&rows, &vis, &lights, false);
        let lists = unit_lists(&rows, &vis, &lights, true);
        let mut left_out = 0;
        for (j, l) in lights.iter().enumerate() {
            let dist2 = cut_dist2(l.max_rgb(), &rows.sampling);
            for (a, b) in [(0, n), (5, 37), (1000, 2100), (n - 10, n)] {
                let mut near = Vec::new();
                vis.for_each_visible_within(j, a..b, &boxes, l.pos, dist2, |i| near.push(i));
                let all: Vec<usize> = (a..b).filter(|&i| vis.visible(j, i)).collect();
                for i in all.iter().filter(|i| !near.contains(i)) {
                    assert_eq!(g(&rows, *i, l), 0.0, "light {j}: row {i} left out but lit");
                    left_out += 1;
                }
                let mut with = Vec::new();
                vis.for_each_visible_with_within(j, a..b, lists[j].as_ref().expect("cached"), &boxes, l.pos, dist2, |i, g| with.push((i, g)));
                let want: Vec<(usize, f32)> = near.iter().map(|&i| (i, g_uncut(&rows, i, l))).collect();
                assert_eq!(with, want, "light {j}, rows {a}..{b}");
            }
        }
        assert!(left_out > n, "the cut leaves whole words out ({left_out} rows)");
        assert!(irradiance(&rows, &boxes, &vis, &lights) == row_by_row(&rows, &vis, &lights));
        let rho: Vec<[f32; 3]> = (0..n).map(|i| [0.3, -0.2, (i % 7) as f32 * 0.1]).collect();
        assert_eq!(gradient(&rows, &boxes, &vis, &lights, &rho), gradient(&rows, &WordBoxes::default(), &vis, &lights, &rho), "the same sums with no word left out");
        // No cut, no distance: every word is kept.
        assert_eq!(cut_dist2(1.0, &Sampling { falloff: 0.0, ..rows.sampling }), f32::INFINITY);
        assert_eq!(cut_dist2(f32::NAN, &rows.sampling), f32::INFINITY);
    }

    /// The light-by-light loops give, bit for bit, what a row-by-row loop over every
    /// light gives (each row sums its lights in the same order).
    #[test]
    fn light_by_light_loops_equal_the_row_by_row_reference() {
        let (_, rows) = crate::testutil::room(40);
        let n = rows.len();
        assert!(n > 2 * crate::rows::block_rows(n) && n % 32 != 0, "{n} rows: several blocks, a partial word");
        let lights: Vec<Light> = (0..7).map(|j| Light::point(Vec3::new(0.5 + 0.4 * j as f32, 1.2, 0.3 + 0.35 * j as f32), [1.0 + j as f32, 2.0, 0.5])).collect();
        let vis = patterned_visibility(n, lights.len());
        let reference = row_by_row(&rows, &vis, &lights);
        let boxes = WordBoxes::of(&rows);
        assert_eq!(irradiance(&rows, &boxes, &vis, &lights), reference);
        assert!(reference.iter().filter(|e| e[0] > 0.0).count() > n / 2);
        // The gradient against a row-by-row sum, per light and block as the loop sums.
        let rho: Vec<[f32; 3]> = (0..n).map(|i| if i % 11 == 0 { [0.0; 3] } else { [0.3, -0.2, (i % 7) as f32 * 0.1] }).collect();
        let got = gradient(&rows, &boxes, &vis, &lights, &rho);
        for (j, l) in lights.iter().enumerate() {
            // Sums and sums of magnitudes (the rounding scale of a reordered sum).
            let (mut want, mut size) = (LightGrad::default(), LightGrad::default());
            for i in 0..n {
                if !vis.visible(j, i) || rho[i] == [0.0; 3] {
                    continue;
                }
                let t = term(&rows, i, l);
                let mut s = 0.0f64;
                for c in 0..3 {
                    want.rgb[c] += rho[i][c] as f64 * t.g as f64;
                    size.rgb[c] += (rho[i][c] as f64 * t.g as f64).abs();
                    s += rho[i][c] as f64 * l.rgb[c] as f64;
                }
                for q in 0..3 {
                    want.pos[q] += s * t.dp[q] as f64;
                    size.pos[q] += (s * t.dp[q] as f64).abs();
                }
            }
            assert!(size.rgb[0] > 0.0, "light {j} reaches rows");
            for q in 0..3 {
                assert!((got[j].rgb[q] - want.rgb[q]).abs() <= 1e-12 * size.rgb[q], "light {j} rgb {q}: {:?} vs {want:?}", got[j]);
                assert!((got[j].pos[q] - want.pos[q]).abs() <= 1e-12 * size.pos[q], "light {j} pos {q}: {:?} vs {want:?}", got[j]);
            }
        }
    }

    /// The CPU kernels give the same bits on one thread as on several: each block's sums
    /// and the order the blocks are added in depend on the row count alone
    /// ([`crate::rows::block_rows`]), not on how rayon spread the blocks.
    #[test]
    fn the_kernels_do_not_depend_on_the_thread_count() {
        let (_, rows) = crate::testutil::room(40);
        let n = rows.len();
        let lights: Vec<Light> = (0..5).map(|j| Light::point(Vec3::new(0.6 + 0.5 * j as f32, 1.1, 0.4 + 0.3 * j as f32), [1.0, 2.0 + j as f32, 0.5])).collect();
        let vis = patterned_visibility(n, lights.len());
        let rho: Vec<[f32; 3]> = (0..n).map(|i| [0.3 + (i % 13) as f32 * 0.01, -0.2, (i % 7) as f32 * 0.1]).collect();
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
            let boxes = WordBoxes::of(&rows);
            pool.install(|| (irradiance(&rows, &boxes, &vis, &lights), gradient(&rows, &boxes, &vis, &lights, &rho)))
        };
        let one = on(1);
        for threads in [2, 3, 8] {
            assert_eq!(on(threads), one, "{threads} threads");
        }
    }

    /// `for_each_visible` visits exactly the set bits inside the range, in order.
    #[test]
    fn for_each_visible_visits_the_set_bits_of_the_range() {
        let vis = patterned_visibility(1000, 3);
        for j in 0..3 {
            for (a, b) in [(0, 1000), (5, 37), (31, 33), (64, 64), (990, 1000), (100, 997)] {
                let mut seen = Vec::new();
                vis.for_each_visible(j, a..b, |i| seen.push(i));
                let want: Vec<usize> = (a..b).filter(|&i| vis.visible(j, i)).collect();
                assert_eq!(seen, want, "light {j}, rows {a}..{b}");
            }
        }
    }

    /// The cone follows q3map2: full inside, a 32-unit linear ramp at the edge, nothing
    /// outside or behind; its derivatives match central differences.
    #[test]
    fn spot_cone_and_its_derivatives() {
        let spot = Spot { axis: Vec3::new(0.0, -1.0, 0.0), radius_by_dist: 0.5 };
        let p = Vec3::new(0.0, 4.0, 0.0);
        let ramp = 0.8;
        // 4 m below the light: R = 2 m; inside, on the ramp, outside, behind.
        assert_eq!(cone(Vec3::new(0.5, 0.0, 0.0), p, &spot, ramp).0, 1.0);
        let (c, ..) = cone(Vec3::new(1.6, 0.0, 0.0), p, &spot, ramp);
        assert!((c - 0.5).abs() < 1e-6, "{c}");
        assert_eq!(cone(Vec3::new(2.1, 0.0, 0.0), p, &spot, ramp).0, 0.0);
        assert_eq!(cone(Vec3::new(0.0, 5.0, 0.0), p, &spot, ramp).0, 0.0);
        let x = Vec3::new(1.3, 0.2, 0.7);
        let (_, dp, da, dr) = cone(x, p, &spot, ramp);
        let h = 1e-3;
        for q in 0..3 {
            let mut a = p;
            let mut b = p;
            a[q] += h;
            b[q] -= h;
            let fd = (cone(x, a, &spot, ramp).0 - cone(x, b, &spot, ramp).0) / (2.0 * h);
            assert!((fd - dp[q]).abs() < 1e-2, "d/dp{q}: {} vs {fd}", dp[q]);
            let (mut sa, mut sb) = (spot, spot);
            sa.axis[q] += h;
            sb.axis[q] -= h;
            let fd = (cone(x, p, &sa, ramp).0 - cone(x, p, &sb, ramp).0) / (2.0 * h);
            assert!((fd - da[q]).abs() < 1e-2, "d/da{q}: {} vs {fd}", da[q]);
        }
        let (mut sa, mut sb) = (spot, spot);
        sa.radius_by_dist += h;
        sb.radius_by_dist -= h;
        let fd = (cone(x, p, &sa, ramp).0 - cone(x, p, &sb, ramp).0) / (2.0 * h);
        assert!((fd - dr).abs() < 1e-2, "d/dr: {dr} vs {fd}");
    }

    /// [`g_at`] is [`term_at`]'s `g` to the bit: points and spots, inside and outside the
    /// distance clamp, on the cone's ramp and beyond it, at the falloff cut.
    #[test]
    fn g_alone_is_the_terms_g() {
        use crate::model::bounce::hash01;
        let s = Sampling { eps: 0.4, ray_offset: 0.0, shadow_offset: 0.0, inhibit: 0.0, falloff: 0.002, spot_ramp: 0.8, on_epsilon: 0.0 };
        let v = |k: u32, a: u32, r: f32| Vec3::new(r * (hash01(k, a) - 0.5), r * (hash01(k, a + 1) - 0.5), r * (hash01(k, a + 2) - 0.5));
        let (mut lit, mut ramp) = (0, 0);
        for k in 0..20_000u32 {
            let x = v(k, 0, 6.0);
            let n = v(k, 3, 2.0).try_normalize().unwrap_or(Vec3::Y);
            let mut l = Light::point(v(k, 6, 6.0), [hash01(k, 9), 0.5 * hash01(k, 10), 0.05]);
            if k % 2 == 0 {
                l.spot = Some(Spot { axis: (x - l.pos + v(k, 11, 2.0)).try_normalize().unwrap_or(Vec3::X), radius_by_dist: 0.1 + hash01(k, 14) });
            }
            let t = term_at(x, n, &l, &s);
            assert_eq!(g_at(x, n, &l, &s).to_bits(), t.g.to_bits(), "case {k}");
            lit += (t.g != 0.0) as usize;
            ramp += (l.spot.is_some() && t.dr != 0.0) as usize;
        }
        assert!(lit > 2000 && ramp > 100, "{lit} lit, {ramp} on a ramp");
    }

    /// Below the falloff tolerance a light adds nothing; above it, everything.
    #[test]
    fn falloff_cuts_weak_contributions() {
        let s = Sampling { eps: 0.4, ray_offset: 0.0, shadow_offset: 0.0, inhibit: 0.0, falloff: 0.05, spot_ramp: 0.8, on_epsilon: 0.0 };
        let x = Vec3::ZERO;
        let n = Vec3::Y;
        // g at 2 m straight above = 1/4: I = 0.21 gives 0.0525 > 0.05, I = 0.19 gives 0.0475.
        let l = |i: f32| Light::point(Vec3::new(0.0, 2.0, 0.0), [i, 0.01, 0.0]);
        assert!((term_at(x, n, &l(0.21), &s).g - 0.25).abs() < 1e-6);
        assert_eq!(term_at(x, n, &l(0.19), &s).g, 0.0);
        // Within eps the inverse square is clamped: cos / eps^2.
        let near = Light::point(Vec3::new(0.0, 0.1, 0.0), [1.0; 3]);
        assert!((term_at(x, n, &near, &s).g - 1.0 / 0.16).abs() < 1e-4);
    }
}
