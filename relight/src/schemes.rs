//! Named optimisation schemes: sequences of phases (algorithm, step size, parameter subset),
//! the thesis's schemes 1-5 of Table 5.1 and our default.
//!
//! Step sizes are in parameter units: positions in units of 5% of the scene diagonal,
//! intensity and colour as logarithms (a step of 0.1 is a 10% change).

use crate::fit::{Algorithm, ParamSet, Phase};

/// Adam's iteration limit per phase in the thesis.
pub const THESIS_ADAM_ITERATIONS: usize = 400;
/// L-BFGS's limit (the thesis's 10 000 is never reached).
pub const THESIS_LBFGS_ITERATIONS: usize = 10_000;

pub const NAMES: &[(&str, &str)] = &[
    ("default", "auto/grid start, then L-BFGS on every parameter (at most 50 iterations)"),
    ("fast", "L-BFGS on every parameter, at most 25 iterations"),
    ("thesis1", "Adam 0.1: intensity+color, then position, then all (3 x 400 iterations)"),
    ("thesis2", "Adam 0.1: position, then intensity+color, then all (3 x 400 iterations)"),
    ("thesis3", "L-BFGS 1.0 on all, then Adam 0.1 on all"),
    ("thesis4", "Adam 0.1 on all, three phases of 400 iterations"),
    ("thesis5", "L-BFGS 1.0 on all, three phases"),
];

pub fn phases(name: &str) -> Option<Vec<Phase>> {
    let adam = |params| Phase { algorithm: Algorithm::Adam { step: 0.1 }, params, max_iterations: THESIS_ADAM_ITERATIONS };
    let lbfgs = |params, n| Phase { algorithm: Algorithm::Lbfgs { step: 1.0 }, params, max_iterations: n };
    let all = ParamSet::ALL;
    Some(match name {
        // Measured on oa_dm1: the error stops improving after about 45 iterations.
        "default" => vec![lbfgs(all, 50)],
        "fast" => vec![lbfgs(all, 25)],
        "thesis1" => vec![adam(ParamSet::INTENSITY_COLOR), adam(ParamSet::POSITION), adam(all)],
        "thesis2" => vec![adam(ParamSet::POSITION), adam(ParamSet::INTENSITY_COLOR), adam(all)],
        "thesis3" => vec![lbfgs(all, THESIS_LBFGS_ITERATIONS), adam(all)],
        "thesis4" => vec![adam(all), adam(all), adam(all)],
        "thesis5" => vec![lbfgs(all, THESIS_LBFGS_ITERATIONS), lbfgs(all, THESIS_LBFGS_ITERATIONS), lbfgs(all, THESIS_LBFGS_ITERATIONS)],
        _ => return None,
    })
}
