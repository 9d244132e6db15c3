//! As few lights as the data needs: pruning lights whose removal costs (almost) nothing,
//! merging lights that sit together.

use super::Fitter;
use crate::model::Light;

/// How much pruning may raise the relative error in all, relative to the error before it.
pub const PRUNE_BUDGET: f64 = 0.01;

impl Fitter<'_> {
    /// Removes the weakest lights while their removal raises the relative error by less
    /// than `tol` (absolute), refitting the linear coefficients after each removal, and
    /// while the error stays within `tol` plus [`PRUNE_BUDGET`] of where it was before any
    /// (without that bound the small steps add up: on oacmpdm4, 29 of 32 lights went, each
    /// under 0.002, and the error rose from 0.28 to 0.32). Lights go in batches, weakest
    /// first: a quarter of the free lights, halved when a batch costs too much, down to
    /// single lights (of which the four weakest are tried), so that a start of a thousand
    /// source lights needs tens of refits, not a thousand. Returns how many.
    pub fn prune(&mut self, tol: f64) -> usize {
        let mut removed = 0;
        let start = self.fit_linear();
        let ceiling = start * (1.0 + PRUNE_BUDGET) + tol;
        let mut base = start;
        let mut batch = ((0..self.model.lights.len()).filter(|&j| !self.locked[j]).count() / 4).max(1);
        loop {
            if self.out_of_time() || self.model.lights.len() <= 1 {
                return removed;
            }
            let mut order: Vec<usize> = (0..self.model.lights.len()).filter(|&j| !self.locked[j]).collect();
            order.sort_by(|&a, &b| self.model.lights[a].rgb.iter().sum::<f32>().total_cmp(&self.model.lights[b].rgb.iter().sum::<f32>()));
            let b = batch.min(order.len()).min(self.model.lights.len() - 1);
            if b == 0 {
                return removed;
            }
            let saved = (self.model.clone(), self.locked.clone(), self.vis.clone());
            // The candidates: the `b` weakest together, or (single lights) each of the four
            // weakest in turn.
            let tries: Vec<Vec<usize>> = if b > 1 { vec![order[..b].to_vec()] } else { order.iter().take(4).map(|&j| vec![j]).collect() };
            let mut done = false;
            for mut take in tries {
                take.sort_unstable_by(|x, y| y.cmp(x));
                for &j in &take {
                    self.remove_light(j);
                }
                let e = self.fit_linear();
                if e <= base + tol && e <= ceiling {
                    removed += take.len();
                    base = e;
                    done = true;
                    break;
                }
                (self.model, self.locked, self.vis) = saved.clone();
            }
            if !done {
                if b == 1 {
                    return removed;
                }
                batch = b / 2;
            }
        }
    }

    /// Merges pairs of free point lights closer than `dist` m when that raises the
    /// relative error by less than `tol`, within the same budget as [`Fitter::prune`]; a
    /// pair that failed is not tried again. Returns how many merges were made.
    pub fn merge(&mut self, dist: f32, tol: f64) -> usize {
        let mut merged = 0;
        // Pairs that failed stay failed while neither light changes: keyed by positions, so
        // a success (which renumbers the lights) does not make the scan try them again.
        let key = |l: &Light| l.pos.to_array().map(f32::to_bits);
        let mut failed: std::collections::HashSet<([u32; 3], [u32; 3])> = std::collections::HashSet::new();
        let mut base = self.fit_linear();
        let ceiling = base * (1.0 + PRUNE_BUDGET) + tol;
        'outer: loop {
            if self.out_of_time() {
                return merged;
            }
            let k = self.model.lights.len();
            for a in 0..k {
                for b in a + 1..k {
                    let (la, lb) = (self.model.lights[a], self.model.lights[b]);
                    if self.locked[a] || self.locked[b] || la.spot.is_some() || lb.spot.is_some() || (la.pos - lb.pos).length() > dist || failed.contains(&(key(&la), key(&lb))) {
                        continue;
                    }
                    let saved = (self.model.clone(), self.locked.clone(), self.vis.clone());
                    let (wa, wb) = (la.rgb.iter().sum::<f32>(), lb.rgb.iter().sum::<f32>());
                    let pos = (la.pos * wa + lb.pos * wb) / (wa + wb).max(1e-30);
                    self.model.lights[a] = Light::point(pos, [0, 1, 2].map(|c| la.rgb[c] + lb.rgb[c]));
                    self.remove_light(b);
                    let e = self.fit_linear();
                    if e <= base + tol && e <= ceiling {
                        merged += 1;
                        base = e;
                        continue 'outer;
                    }
                    (self.model, self.locked, self.vis) = saved;
                    failed.insert((key(&la), key(&lb)));
                }
            }
            return merged;
        }
    }
}
