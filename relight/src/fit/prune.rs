//! As few lights as the data needs: pruning lights whose removal costs (almost) nothing,
//! merging lights that sit together; both by one batched search (`Fitter::in_batches`).

use rayon::prelude::*;

use super::Fitter;
use crate::model::{lights, Light};
use crate::rows::Rows;

/// How much pruning may raise the relative error in all, relative to the error before it.
pub const PRUNE_BUDGET: f64 = 0.01;

impl Fitter<'_> {
    /// Removes the weakest lights while their removal raises the relative error by less
    /// than `tol` (absolute), refitting the linear coefficients after each removal, and
    /// while the error stays within `tol` plus [`PRUNE_BUDGET`] of where it was before any
    /// (without that bound the small steps add up: on oacmpdm4, 29 of 32 lights went, each
    /// under 0.002, and the error rose from 0.28 to 0.32). Lights go in batches, weakest
    /// first: a quarter of the free lights, halved when a batch costs too much, down to
    /// single lights (of which the [`SINGLES`] weakest are tried), so that a start of a thousand
    /// source lights needs tens of refits, not a thousand. Returns how many.
    ///
    /// A light whose removal alone failed is not refitted without it again while that
    /// refit's error stays above the bound: the best fit over a subset of the lights is
    /// no better than over the set, so once other lights have gone, the fit without it
    /// can only lie at or above the error it reached, and it fails again until the bound
    /// has risen past that error (it is still counted among the [`SINGLES`] tried, so the
    /// search makes the decisions it made when each was refitted). On oa_dm1 the same
    /// weakest lights failed in round after round, each a refit of 0.09 s.
    pub fn prune(&mut self, tol: f64) -> usize {
        let free = (0..self.model.lights.len()).filter(|&j| !self.locked[j]).count();
        let weakest_first = |f: &Self| {
            let lights = &f.model.lights;
            let mut order: Vec<usize> = (0..lights.len()).filter(|&j| !f.locked[j]).collect();
            order.sort_by(|&a, &b| lights[a].rgb.iter().sum::<f32>().total_cmp(&lights[b].rgb.iter().sum::<f32>()));
            order
        };
        let remove = |f: &mut Self, take: &[usize]| {
            let mut take = take.to_vec();
            take.sort_unstable_by(|x, y| y.cmp(x));
            for j in take {
                f.remove_light(j);
            }
        };
        // One light stays.
        let most = |f: &Self| f.model.lights.len().saturating_sub(1);
        // The error each light's removal alone reached, keyed by what the light is (two
        // lights with the same key are the same column, so the same refit).
        let failed = std::cell::RefCell::new(std::collections::HashMap::<LightKey, f64>::new());
        let failed_alone = |f: &Self, j: usize, e: f64| {
            failed.borrow_mut().insert(light_key(&f.model.lights[j]), e);
        };
        let known_to_fail = |f: &Self, j: usize, bound: f64| f.remember_failed_singles && failed.borrow().get(&light_key(&f.model.lights[j])).is_some_and(|&e| e > bound);
        self.in_batches(tol, Some((free / 4).max(1)), weakest_first, most, remove, failed_alone, known_to_fail)
    }

    /// Merges pairs of free point lights closer than `dist` m when that raises the
    /// relative error by less than `tol`, within the same budget as [`Fitter::prune`].
    ///
    /// Pairs go in batches, as lights do in pruning: the candidates are paired off (each
    /// light in one pair at most) in the order of [`merge_cost`], the pair whose
    /// one light best stands for both first; then a quarter of the pairs are merged at
    /// once, halved when a batch costs too much, down to single pairs, of which the
    /// [`SINGLES`] cheapest are tried (a single pair that failed is not tried again
    /// while neither light changes). The scan it replaces tried every pair within `dist`
    /// with a refit each, hundreds of refits once the error had reached the budget:
    /// 0.8 s each on oacmpdm3's 450 lights. Returns how many merges were made.
    pub fn merge(&mut self, dist: f32, tol: f64) -> usize {
        // Pairs that failed alone stay failed while neither light changes: keyed by
        // positions, so a success (which renumbers the lights) keeps them.
        let key = |l: &Light| l.pos.to_array().map(f32::to_bits);
        let failed = std::cell::RefCell::new(std::collections::HashSet::<([u32; 3], [u32; 3])>::new());
        let candidates = |f: &Self| f.merge_candidates(dist).into_iter().filter(|&(a, b)| !failed.borrow().contains(&(key(&f.model.lights[a]), key(&f.model.lights[b])))).collect();
        let failed_alone = |f: &Self, (a, b): (usize, usize), _e: f64| {
            failed.borrow_mut().insert((key(&f.model.lights[a]), key(&f.model.lights[b])));
        };
        self.in_batches(tol, None, candidates, |_| usize::MAX, Self::merge_pairs, failed_alone, |_, _, _| false)
    }

    /// The search pruning and merging share. Each round `candidates` lists the changes
    /// (best first); the first `b` of them are applied together (`apply`, at most `most`
    /// at once) and the linear coefficients refitted; the batch stands when the error
    /// rose by at most `tol` and stays within `tol` plus [`PRUNE_BUDGET`] of where it was
    /// before any, else it is undone and `b` halves. `b` starts at `first` (default: a
    /// quarter of the first list). At `b = 1` each of the [`SINGLES`] best candidates is
    /// tried alone (`failed_alone` hears of each that failed, with the error its refit
    /// reached), except those `known_to_fail` says cannot come within the bound (the
    /// error a change may reach to stand, passed to it), which count as tried and failed
    /// without a refit; when none stands, the search ends. Returns how many changes stood.
    #[allow(clippy::too_many_arguments)]
    fn in_batches<C: Copy>(
        &mut self,
        tol: f64,
        first: Option<usize>,
        candidates: impl Fn(&Self) -> Vec<C>,
        most: impl Fn(&Self) -> usize,
        apply: impl Fn(&mut Self, &[C]),
        failed_alone: impl Fn(&Self, C, f64),
        known_to_fail: impl Fn(&Self, C, f64) -> bool,
    ) -> usize {
        let mut done_count = 0;
        let mut base = self.fit_linear();
        let ceiling = base * (1.0 + PRUNE_BUDGET) + tol;
        let mut batch = first;
        loop {
            if self.out_of_time() {
                return done_count;
            }
            let list = candidates(self);
            let b = (*batch.get_or_insert((list.len() / 4).max(1))).min(list.len()).min(most(self));
            if b == 0 {
                return done_count;
            }
            let tries: Vec<&[C]> = if b > 1 { vec![&list[..b]] } else { list.chunks(1).take(SINGLES).collect() };
            let saved = (self.model.clone(), self.locked.clone(), self.vis.clone());
            let mut done = false;
            for take in tries {
                if let [c] = take {
                    if known_to_fail(self, *c, (base + tol).min(ceiling)) {
                        self.singles_skipped += 1;
                        continue;
                    }
                }
                apply(self, take);
                let e = self.fit_linear();
                if e <= base + tol && e <= ceiling {
                    done_count += take.len();
                    base = e;
                    done = true;
                    break;
                }
                (self.model, self.locked, self.vis) = saved.clone();
                if let [c] = take {
                    failed_alone(self, *c, e);
                }
            }
            if !done {
                if b == 1 {
                    return done_count;
                }
                batch = Some(b / 2);
            }
        }
    }

    /// Each pair `(a, b)` (disjoint, `a < b`) becomes one light at their intensity-weighted
    /// position with their summed intensity, in `a`'s place.
    fn merge_pairs(&mut self, pairs: &[(usize, usize)]) {
        for &(a, b) in pairs {
            self.model.lights[a] = merged_light(&self.model.lights[a], &self.model.lights[b]);
        }
        let mut gone: Vec<usize> = pairs.iter().map(|p| p.1).collect();
        gone.sort_unstable_by(|x, y| y.cmp(x));
        for j in gone {
            self.remove_light(j);
        }
    }

    /// The pairs of free point lights closer than `dist` m, paired off greedily (each
    /// light in one pair at most), cheapest [`merge_cost`] first.
    fn merge_candidates(&self, dist: f32) -> Vec<(usize, usize)> {
        let lights = &self.model.lights;
        // A light without traced bits (the cache behind after a backend failure) is no candidate.
        let free = |j: usize| !self.locked[j] && lights[j].spot.is_none() && j < self.vis.bits.len();
        let near: Vec<(usize, usize)> = (0..lights.len())
            .filter(|&a| free(a))
            .flat_map(|a| (a + 1..lights.len()).filter(move |&b| free(b) && (lights[a].pos - lights[b].pos).length() <= dist).map(move |b| (a, b)))
            .collect();
        let (rows, vis) = (self.rows, &self.vis);
        let dirt = self.bases.dirt_of(&self.model);
        let mut scored: Vec<(f64, (usize, usize))> = near.par_iter().map(|&(a, b)| (merge_cost(rows, dirt, (&lights[a], &vis.bits[a]), (&lights[b], &vis.bits[b])), (a, b))).collect();
        scored.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
        let mut used = vec![false; lights.len()];
        let mut pairs = Vec::new();
        for (_, (a, b)) in scored {
            if !used[a] && !used[b] {
                used[a] = true;
                used[b] = true;
                pairs.push((a, b));
            }
        }
        pairs
    }
}

/// What a light is, to the search's memory of failed removals: its position and spot
/// bits (intensities change with every refit; position and spot do not while pruning).
type LightKey = ([u32; 3], Option<[u32; 4]>);

fn light_key(l: &Light) -> LightKey {
    (l.pos.to_array().map(f32::to_bits), l.spot.map(|s| [s.axis.x.to_bits(), s.axis.y.to_bits(), s.axis.z.to_bits(), s.radius_by_dist.to_bits()]))
}

/// Single candidates (lights to prune, pairs to merge) tried, best first, once batches
/// have failed; when none of them stands, the search stops.
pub const SINGLES: usize = 4;

/// Lights `a` and `b` as one point light: their intensity-weighted position, their
/// summed intensity.
fn merged_light(a: &Light, b: &Light) -> Light {
    let (wa, wb) = (a.rgb.iter().sum::<f32>(), b.rgb.iter().sum::<f32>());
    let pos = (a.pos * wa + b.pos * wb) / (wa + wb).max(1e-30);
    Light::point(pos, [0, 1, 2].map(|c| a.rgb[c] + b.rgb[c]))
}

/// What merging lights `a` and `b` costs, before any refit: the weighted squared
/// radiance by which one light at their merged position, at its best intensity per
/// channel, misses the pair's own light, over the rows either reaches (with their
/// albedo, area, weight and dirt; the merged light taken to see what either saw). `ba`
/// and `bb` are the lights' visibility bits. An estimate for ordering the candidates:
/// the refit decides.
pub fn merge_cost(rows: &Rows, dirt: Option<&[f32]>, (la, ba): (&Light, &[u32]), (lb, bb): (&Light, &[u32])) -> f64 {
    let lm = merged_light(la, lb);
    // Per channel: sum W v^2, sum W u v, sum W u^2 (v: the pair's light, u: the merged one's per unit).
    let mut s = [[0.0f64; 3]; 3];
    for (w, (&wa, &wb)) in ba.iter().zip(bb).enumerate() {
        let mut word = wa | wb;
        while word != 0 {
            let bit = word.trailing_zeros();
            word &= word - 1;
            let i = (w << 5) | bit as usize;
            let ga = if wa >> bit & 1 == 1 { lights::g(rows, i, la) as f64 } else { 0.0 };
            let gb = if wb >> bit & 1 == 1 { lights::g(rows, i, lb) as f64 } else { 0.0 };
            let u = lights::g(rows, i, &lm) as f64;
            let d = dirt.map_or(1.0, |d| d[i] as f64);
            for (c, [vv, uv, uu]) in s.iter_mut().enumerate() {
                let alb = rows.albedo[i][c] as f64 / std::f64::consts::PI * d;
                let wt = rows.area[i] as f64 * rows.weight[i][c] as f64 * alb * alb;
                let v = la.rgb[c] as f64 * ga + lb.rgb[c] as f64 * gb;
                *vv += wt * v * v;
                *uv += wt * u * v;
                *uu += wt * u * u;
            }
        }
    }
    s.iter().map(|&[vv, uv, uu]| if uv > 0.0 && uu > 0.0 { (vv - uv * uv / uu).max(0.0) } else { vv }).sum()
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::merge_cost;
    use crate::backend::Cpu;
    use crate::fit::Fitter;
    use crate::model::{Bases, Light, Model};
    use crate::testutil::room;
    use crate::trace::bvh::Bvh;

    /// Eight lights over the room, each given to the fit as two half lights 6 cm apart:
    /// every pair merges (a batch of pairs at a time), back to eight lights where the
    /// data's are, within the budget; the lights a metre apart are left alone.
    #[test]
    fn split_lights_merge_back_in_batches() {
        let (mesh, mut rows) = room(12);
        let bvh = Bvh::build(&mesh);
        let bases = Bases::default();
        let (lo, hi) = mesh.bounds();
        let truth: Vec<Light> = [1.0f32, 3.0]
            .into_iter()
            .flat_map(|x| [0.8f32, 1.7].into_iter().flat_map(move |y| [0.8f32, 2.2].into_iter().map(move |z| Light::point(Vec3::new(x, y, z), [0.4, 0.35, 0.3]))))
            .collect();
        // The data: the truth's radiance, intervals 0.01 wide, nothing censored.
        let x = {
            let mut cpu = Cpu::new(&rows, &bvh);
            let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
            fit.model = Model { lights: truth.clone(), ..Model::default() };
            fit.refresh_visibility();
            crate::model::radiance(&fit.model, &rows, &bases, &fit.vis, &mut Cpu::new(&rows, &bvh)).unwrap()
        };
        for (i, xi) in x.iter().enumerate() {
            rows.lo[i] = xi.map(|v| v as f32 - 0.005);
            rows.hi[i] = xi.map(|v| v as f32 + 0.005);
            rows.weight[i] = [1.0; 3];
            rows.lower[i] = [0.0; 3];
        }
        rows.finish();
        let mut cpu = Cpu::new(&rows, &bvh);
        let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
        let half = Vec3::new(0.03, 0.0, 0.0);
        for l in &truth {
            fit.add_light(Light::point(l.pos - half, l.rgb.map(|c| c / 2.0)), false);
            fit.add_light(Light::point(l.pos + half, l.rgb.map(|c| c / 2.0)), false);
        }
        let e0 = fit.fit_linear();
        assert!(e0 < 0.01, "the split lights explain the data: {e0}");
        // A split pair costs little to merge, a pair a metre apart much more.
        fit.refresh_visibility();
        let cost = |a: usize, b: usize| merge_cost(&rows, None, (&fit.model.lights[a], &fit.vis.bits[a]), (&fit.model.lights[b], &fit.vis.bits[b]));
        let (split, apart) = (cost(0, 1), cost(0, 2));
        assert!(split * 100.0 < apart, "merge costs: split pair {split}, lights a metre apart {apart}");
        let merged = fit.merge(0.3, 0.002);
        assert_eq!(merged, 8, "every split pair merges");
        assert_eq!(fit.model.lights.len(), 8);
        for l in &truth {
            let near = fit.model.lights.iter().map(|m| (m.pos - l.pos).length()).fold(f32::INFINITY, f32::min);
            assert!(near < 1e-3, "a merged light stands where its pair's centre is: {near} m off");
        }
        let e1 = fit.eval().rel_error;
        assert!(e1 <= e0 + 0.002, "merging cost more than its tolerance: {e0} -> {e1}");
    }

    /// Two dim lights the data needs and one bright light given to the fit as four
    /// copies 5 cm from its place: the dim lights, weakest, fail alone (0.07), a copy goes
    /// (0.017, within the tolerance of 0.02), and in the next round the dim lights, still
    /// the weakest, are the first two tries again. Remembering their failures makes the
    /// same decisions (the same lights left, the same error) without those two refits.
    #[test]
    fn a_light_that_failed_alone_is_not_refitted_again_while_its_error_is_above_the_bound() {
        let (mesh, mut rows) = room(12);
        let bvh = Bvh::build(&mesh);
        let bases = Bases::default();
        let (lo, hi) = mesh.bounds();
        let dim = [Light::point(Vec3::new(0.6, 1.2, 0.6), [0.05, 0.045, 0.04]), Light::point(Vec3::new(3.4, 1.2, 2.4), [0.04, 0.05, 0.045])];
        let bright = Light::point(Vec3::new(2.0, 1.6, 1.5), [0.8, 0.75, 0.7]);
        let x = {
            let mut cpu = Cpu::new(&rows, &bvh);
            let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
            fit.model = Model { lights: vec![dim[0], dim[1], bright], ..Model::default() };
            fit.refresh_visibility();
            crate::model::radiance(&fit.model, &rows, &bases, &fit.vis, &mut Cpu::new(&rows, &bvh)).unwrap()
        };
        for (i, xi) in x.iter().enumerate() {
            rows.lo[i] = xi.map(|v| v as f32 * 0.995);
            rows.hi[i] = xi.map(|v| v as f32 * 1.005);
            rows.weight[i] = [1.0; 3];
            rows.lower[i] = [0.0; 3];
        }
        rows.finish();
        let run = |remember: bool| {
            let mut cpu = Cpu::new(&rows, &bvh);
            let mut fit = Fitter::new(&rows, &bases, &bvh, &mut cpu, lo, hi);
            fit.remember_failed_singles = remember;
            for l in dim {
                fit.add_light(l, false);
            }
            for k in 0..4 {
                let off = [Vec3::new(1.0, 1.0, 1.0), Vec3::new(1.0, -1.0, -1.0), Vec3::new(-1.0, 1.0, -1.0), Vec3::new(-1.0, -1.0, 1.0)][k] * 0.05;
                fit.add_light(Light::point(bright.pos + off, bright.rgb.map(|c| c / 4.0)), false);
            }
            let pruned = fit.prune(0.02);
            let e = fit.eval().rel_error;
            let left: Vec<[u32; 3]> = fit.model.lights.iter().map(|l| l.pos.to_array().map(f32::to_bits)).collect();
            (pruned, e, left, fit.linear_fits, fit.singles_skipped)
        };
        let (pruned_ref, e_ref, left_ref, fits_ref, skipped_ref) = run(false);
        let (pruned, e, left, fits, skipped) = run(true);
        assert_eq!(skipped_ref, 0);
        assert_eq!(pruned_ref, 1, "one copy goes: {left_ref:?}");
        assert!(dim.iter().all(|l| left_ref.contains(&l.pos.to_array().map(f32::to_bits))), "the dim lights stay: {left_ref:?}");
        assert_eq!((pruned, &left), (pruned_ref, &left_ref), "the same lights left");
        assert!((e - e_ref).abs() < 1e-6, "the same error: {e} against {e_ref}");
        assert_eq!(skipped, 2, "the dim lights' failures were remembered in the second round");
        assert_eq!(fits + skipped, fits_ref, "each skipped try is one refit fewer: {fits} + {skipped} against {fits_ref}");
    }
}
