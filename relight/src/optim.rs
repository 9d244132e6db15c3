//! Adam and L-BFGS over a flat parameter vector with a mask of the free parameters.
//!
//! Both call an objective `f(x) -> (value, gradient)` and a per-iteration observer that
//! may stop them (time limit, progress bar). L-BFGS keeps 8 pairs, skips pairs that break
//! the curvature condition, restarts from steepest descent when its direction is not a
//! descent direction, and uses a backtracking Armijo line search; when even steepest
//! descent finds no decrease it reports convergence instead of wandering (the noisy
//! behaviour the thesis observed came from stochastic gradients with a strong Wolfe search).

/// Why a run stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stop {
    Converged,
    MaxIterations,
    Observer,
    LineSearchFailed,
}

/// The result of one run.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub x: Vec<f64>,
    pub f: f64,
    pub iterations: usize,
    pub evaluations: usize,
    pub stop: Stop,
}

/// `f(x, fresh)`: `fresh = false` for line-search trials, which must see the same
/// (cached) visibility as the current iterate so the search is over a smooth function,
/// and need only the value (the gradient may come back empty: the accepted point is
/// evaluated again, fresh); `fresh = true` at accepted iterates, where moved lights are
/// re-traced, value and gradient.
pub type Objective<'a> = dyn FnMut(&[f64], bool) -> (f64, Vec<f64>) + 'a;
/// Called after each iteration with (iteration, objective); returns false to stop.
pub type Observer<'a> = dyn FnMut(usize, f64) -> bool + 'a;

fn masked(g: &mut [f64], mask: &[bool]) {
    for (x, &m) in g.iter_mut().zip(mask) {
        if !m || !x.is_finite() {
            *x = 0.0;
        }
    }
}

/// A `rel_tol` that never stops a run: it goes to its iteration limit.
pub const NEVER: f64 = f64::NEG_INFINITY;

/// Adam (Kingma and Ba) with step size `lr`; stops when the objective changed by less
/// than `rel_tol` (relative) over 20 iterations ([`NEVER`]: runs to `max_iter`).
pub fn adam(x0: &[f64], mask: &[bool], lr: f64, max_iter: usize, rel_tol: f64, f: &mut Objective, observe: &mut Observer) -> Outcome {
    let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-8f64);
    let mut x = x0.to_vec();
    let mut m = vec![0.0; x.len()];
    let mut v = vec![0.0; x.len()];
    let mut best = (f64::INFINITY, x.clone());
    let mut history = Vec::new();
    let mut evals = 0;
    for it in 1..=max_iter {
        let (fx, mut g) = f(&x, true);
        evals += 1;
        masked(&mut g, mask);
        if fx < best.0 {
            best = (fx, x.clone());
        }
        history.push(fx);
        if !observe(it, fx) {
            return Outcome { x: best.1, f: best.0, iterations: it, evaluations: evals, stop: Stop::Observer };
        }
        if history.len() > 20 {
            let old = history[history.len() - 21];
            if (old - fx).abs() <= rel_tol * old.abs().max(1e-300) {
                return Outcome { x: best.1, f: best.0, iterations: it, evaluations: evals, stop: Stop::Converged };
            }
        }
        let (c1, c2) = (1.0 - b1.powi(it as i32), 1.0 - b2.powi(it as i32));
        for k in 0..x.len() {
            if !mask[k] {
                continue;
            }
            m[k] = b1 * m[k] + (1.0 - b1) * g[k];
            v[k] = b2 * v[k] + (1.0 - b2) * g[k] * g[k];
            x[k] -= lr * (m[k] / c1) / ((v[k] / c2).sqrt() + eps);
        }
    }
    let (fx, _) = f(&x, true);
    evals += 1;
    if fx < best.0 {
        best = (fx, x);
    }
    Outcome { x: best.1, f: best.0, iterations: max_iter, evaluations: evals, stop: Stop::MaxIterations }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// L-BFGS with `m = 8`; `step0` is the length of the first step (in parameter units).
pub fn lbfgs(x0: &[f64], mask: &[bool], step0: f64, max_iter: usize, rel_tol: f64, f: &mut Objective, observe: &mut Observer) -> Outcome {
    const M: usize = 8;
    let n = x0.len();
    let mut x = x0.to_vec();
    let (mut fx, mut g) = f(&x, true);
    masked(&mut g, mask);
    let mut evals = 1;
    let mut s_hist: Vec<Vec<f64>> = Vec::new();
    let mut y_hist: Vec<Vec<f64>> = Vec::new();
    let mut stop = Stop::MaxIterations;
    let mut it = 0;
    let mut small = 0;
    // The best point a fresh evaluation has seen: a step the trials accepted can turn out
    // worse once its own shadows are traced, and the walk goes on from there, but the
    // phase ends where it was best.
    let mut best = (x.clone(), fx);
    while it < max_iter {
        it += 1;
        let gnorm = dot(&g, &g).sqrt();
        if gnorm == 0.0 || !gnorm.is_finite() {
            stop = Stop::Converged;
            break;
        }
        // Two-loop recursion.
        let mut d: Vec<f64> = g.iter().map(|v| -v).collect();
        let mut alpha = vec![0.0; s_hist.len()];
        for k in (0..s_hist.len()).rev() {
            let rho = 1.0 / dot(&y_hist[k], &s_hist[k]);
            alpha[k] = rho * dot(&s_hist[k], &d);
            for q in 0..n {
                d[q] -= alpha[k] * y_hist[k][q];
            }
        }
        if let (Some(s), Some(y)) = (s_hist.last(), y_hist.last()) {
            let gamma = dot(s, y) / dot(y, y);
            for v in d.iter_mut() {
                *v *= gamma;
            }
        } else {
            let scale = step0 / gnorm;
            for v in d.iter_mut() {
                *v *= scale;
            }
        }
        for k in 0..s_hist.len() {
            let rho = 1.0 / dot(&y_hist[k], &s_hist[k]);
            let beta = rho * dot(&y_hist[k], &d);
            for q in 0..n {
                d[q] += s_hist[k][q] * (alpha[k] - beta);
            }
        }
        masked(&mut d, mask);
        let mut slope = dot(&g, &d);
        if !(slope < 0.0) {
            // Not a descent direction (noise, a bad pair): restart from steepest descent.
            s_hist.clear();
            y_hist.clear();
            let scale = step0 / gnorm;
            d = g.iter().map(|v| -v * scale).collect();
            slope = dot(&g, &d);
        }
        // Backtracking Armijo line search.
        let mut t = 1.0;
        let mut accepted = None;
        for _ in 0..30 {
            let xn: Vec<f64> = x.iter().zip(&d).map(|(a, b)| a + t * b).collect();
            let (fnew, _) = f(&xn, false);
            evals += 1;
            if fnew.is_finite() && fnew <= fx + 1e-4 * t * slope {
                accepted = Some(xn);
                break;
            }
            t *= 0.5;
        }
        let Some(xn) = accepted else {
            if s_hist.is_empty() {
                stop = Stop::LineSearchFailed;
                break;
            }
            s_hist.clear();
            y_hist.clear();
            continue;
        };
        // Re-evaluate at the accepted point with visibility re-traced there.
        let (fnew, mut gnew) = f(&xn, true);
        evals += 1;
        masked(&mut gnew, mask);
        let s: Vec<f64> = xn.iter().zip(&x).map(|(a, b)| a - b).collect();
        let y: Vec<f64> = gnew.iter().zip(&g).map(|(a, b)| a - b).collect();
        if dot(&s, &y) > 1e-12 * dot(&y, &y).max(1e-300) {
            if s_hist.len() == M {
                s_hist.remove(0);
                y_hist.remove(0);
            }
            s_hist.push(s);
            y_hist.push(y);
        }
        let decrease = fx - fnew; // may be negative after a re-trace: then stop as converged
        x = xn;
        g = gnew;
        let old = fx;
        fx = fnew;
        if fx < best.1 {
            best = (x.clone(), fx);
        }
        if !observe(it, fx) {
            stop = Stop::Observer;
            break;
        }
        // A re-trace can raise f a little; stop after three iterations without real progress.
        small = if decrease <= rel_tol * old.abs().max(1e-300) { small + 1 } else { 0 };
        if small >= 3 {
            stop = Stop::Converged;
            break;
        }
    }
    let (x, fx) = if best.1 < fx { best } else { (x, fx) };
    Outcome { x, f: fx, iterations: it, evaluations: evals, stop }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn never_stop() -> impl FnMut(usize, f64) -> bool {
        |_, _| true
    }

    #[test]
    fn lbfgs_minimises_rosenbrock() {
        let mut f = |x: &[f64], _: bool| {
            let (a, b) = (x[0], x[1]);
            ((1.0 - a).powi(2) + 100.0 * (b - a * a).powi(2), vec![-2.0 * (1.0 - a) - 400.0 * a * (b - a * a), 200.0 * (b - a * a)])
        };
        let o = lbfgs(&[-1.2, 1.0], &[true, true], 0.1, 500, 1e-12, &mut f, &mut never_stop());
        assert!((o.x[0] - 1.0).abs() < 1e-3 && (o.x[1] - 1.0).abs() < 1e-3, "{:?}", o);
    }

    /// Trials that see a stale objective (the shadows of the last re-trace) can accept a
    /// step whose own evaluation is worse: L-BFGS walks on, but ends at the best point a
    /// full evaluation saw, never above its start.
    #[test]
    fn lbfgs_ends_at_its_best_fresh_point() {
        // The trials see (x - 2)^2; a full evaluation adds 10 beyond x = 1.5 (a wall).
        let mut f = |x: &[f64], fresh: bool| {
            let wall = if fresh && x[0] > 1.5 { 10.0 } else { 0.0 };
            ((x[0] - 2.0).powi(2) + wall, vec![2.0 * (x[0] - 2.0)])
        };
        let o = lbfgs(&[0.0], &[true], 1.0, 20, 1e-12, &mut f, &mut never_stop());
        assert!(o.f <= 4.0, "{o:?}");
        assert_eq!(o.f, f(&o.x, true).0, "the value returned is the point's own: {o:?}");
        assert!(o.x[0] <= 1.5, "{o:?}");
    }

    /// A flat objective (zero gradient): both stop at once where they started, finite.
    #[test]
    fn flat_objective_stays_put() {
        let mut f = |_: &[f64], _: bool| (3.0, vec![0.0, 0.0]);
        let o = lbfgs(&[0.5, -2.0], &[true, true], 1.0, 100, 1e-6, &mut f, &mut never_stop());
        assert_eq!(o.x, vec![0.5, -2.0]);
        assert_eq!(o.stop, Stop::Converged);
        let o = adam(&[0.5, -2.0], &[true, true], 0.1, 100, 1e-6, &mut f, &mut never_stop());
        assert_eq!(o.x, vec![0.5, -2.0], "Adam with zero gradients moves nothing");
        assert!(o.f == 3.0);
    }

    /// A noisy objective whose values repeat by chance 20 iterations apart stops Adam as
    /// converged; with [`NEVER`] (the sampled estimator) it runs to its limit.
    #[test]
    fn adam_runs_to_its_limit_on_a_sampled_objective() {
        let noise = [0.0, 0.3, -0.2, 0.1];
        let mut k = 0usize;
        let mut f = |x: &[f64], _: bool| {
            k += 1;
            (x[0] * x[0] + 1.0 + noise[k % 4], vec![2.0 * x[0]])
        };
        let o = adam(&[1.0], &[true], 0.1, 100, 1e-5, &mut f, &mut never_stop());
        assert_eq!(o.stop, Stop::Converged);
        assert!(o.iterations < 100);
        let o = adam(&[1.0], &[true], 0.1, 100, NEVER, &mut f, &mut never_stop());
        assert_eq!((o.stop, o.iterations), (Stop::MaxIterations, 100));
        assert!(o.f.is_finite());
    }

    /// An objective that no step lowers (a kink at the start, as at a shadow edge): L-BFGS's
    /// line search fails, and it stops at the start with its value, not somewhere worse.
    #[test]
    fn failed_line_search_keeps_the_start() {
        let mut f = |x: &[f64], _: bool| (x[0].abs() * 10.0 + 1.0, vec![1.0]);
        let o = lbfgs(&[0.0], &[true], 1.0, 50, 1e-6, &mut f, &mut never_stop());
        assert_eq!(o.x, vec![0.0]);
        assert_eq!(o.f, 1.0);
        assert!(matches!(o.stop, Stop::LineSearchFailed | Stop::Converged), "{:?}", o.stop);
    }

    /// Non-finite gradient entries (a light on a surface) are treated as zero: the other
    /// parameters still move and nothing becomes NaN.
    #[test]
    fn non_finite_gradients_are_ignored() {
        let mut f = |x: &[f64], _: bool| ((x[0] - 2.0).powi(2), vec![2.0 * (x[0] - 2.0), f64::NAN]);
        let o = lbfgs(&[0.0, 1.0], &[true, true], 0.5, 100, 1e-12, &mut f, &mut never_stop());
        assert!((o.x[0] - 2.0).abs() < 1e-6 && o.x[1] == 1.0, "{:?}", o.x);
        let o = adam(&[0.0, 1.0], &[true, true], 0.1, 2000, 1e-12, &mut f, &mut never_stop());
        assert!((o.x[0] - 2.0).abs() < 1e-2 && o.x[1] == 1.0, "{:?}", o.x);
    }
}
