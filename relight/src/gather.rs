//! The data's own bounced light: for the light placement only.
//!
//! The model's bounce ([`crate::model::bounce`]) is the light of the model's own
//! emitters reflected by the scene. The placement ([`crate::init::auto`]) places lights
//! for the light the data shows before the model has any, on a subsample of the rows;
//! there the bounce is estimated from the data instead, once, independent of the lights:
//! the data's own light at every row, sent through the bounce's transport as one pass of
//! the model's bounce sends the model's,
//!
//! ```text
//! o_i = albedo_i / pi * sum_w G_iw sum_j P_wj rho_j T_j,      T_j = pi x_j / albedo_j
//! ```
//!
//! (`x_j`: the row's data, the middle of its interval, a censored channel at its bound;
//! `G`, `P`, `rho`: [`crate::model::bounce::Transport`] and the reflectance). Because the
//! data holds every pass, `o` stands for all of them; the model scales it by a fitted
//! `k_g` per channel ([`crate::model::Model::gathered`]) so that lights are placed for
//! the light it leaves unexplained. Gathering the data where each ray lands instead (a
//! physical gather) is not the light q3map2 bounced: on a synthetic scene whose data is
//! the model's own bounce from q3map2's pieces, the lights placed that way started the
//! fit at 0.024 and it stopped at 0.022 (0.0037 in the end, a light 2% off); through the
//! transport, see the synthetic test.

use rayon::prelude::*;

use crate::model::bounce::Transport;
use crate::rows::Rows;

/// `o_i` of every row (see the module docs), through `transport` with reflectance `rho`.
pub fn through(rows: &Rows, transport: &Transport, rho: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let t: Vec<[f64; 3]> = (0..rows.len())
        .into_par_iter()
        .map(|j| {
            [0, 1, 2].map(|c| {
                let (w, a) = (rows.weight[j][c] as f64, rows.albedo[j][c] as f64);
                let x = w * 0.5 * (rows.lo[j][c] as f64 + rows.hi[j][c] as f64) + (1.0 - w) * rows.lower[j][c] as f64;
                if a > 1e-6 { std::f64::consts::PI * x / a } else { 0.0 }
            })
        })
        .collect();
    let e = transport.apply(&t, Some(rho));
    (0..rows.len()).map(|i| [0, 1, 2].map(|c| (rows.albedo[i][c] as f64 / std::f64::consts::PI * e[i][c]) as f32)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Sparse;
    use crate::rows::{Row, Sampling, SolidAhead};

    /// Three rows: row 0's rays all land on one piece that averages rows 1 and 2; row 1's
    /// half on a piece of row 0, half nowhere. `o` is the data's light through that.
    #[test]
    fn the_data_bounces_through_the_transport() {
        let mut rows = Rows::new(Sampling::plain(1.0));
        let row = |albedo: [f32; 3], lo: f32, hi: f32| Row { vertex: u32::MAX, material: 0, texel: [u32::MAX; 3], pos: glam::Vec3::ZERO, normal: glam::Vec3::Y, albedo, lo: [lo; 3], hi: [hi; 3], weight: [1.0; 3], lower: [0.0; 3], area: 1.0, solid_ahead: SolidAhead::NONE, two_sided: false };
        rows.push(row([0.5; 3], 0.1, 0.3));
        rows.push(row([0.25; 3], 0.2, 0.2));
        rows.push(row([1.0; 3], 0.6, 0.8));
        rows.finish();
        let mut gather = Sparse::empty();
        gather.push_row([(0, 1.0)]);
        gather.push_row([(1, 0.5)]);
        gather.push_row([]);
        let mut emit = Sparse::empty();
        emit.push_row([(1, 0.5), (2, 0.5)]);
        emit.push_row([(0, 1.0)]);
        let t = Transport { gather, emit: Some(emit) };
        let rho = vec![[0.4; 3], [0.5; 3], [0.6; 3]];
        let o = through(&rows, &t, &rho);
        let pi = std::f32::consts::PI;
        // T = pi x / albedo: 0.2 pi / 0.5, 0.2 pi / 0.25, 0.7 pi / 1.
        let tt = [0.4 * pi, 0.8 * pi, 0.7 * pi];
        let want = [0.5 / pi * (0.5 * 0.5 * tt[1] + 0.5 * 0.6 * tt[2]), 0.25 / pi * (0.5 * 0.4 * tt[0]), 0.0];
        for i in 0..3 {
            assert!((o[i][0] - want[i]).abs() < 1e-6, "row {i}: {:?} against {}", o[i], want[i]);
        }
    }
}
