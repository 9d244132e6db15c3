//! The data read through a compile gamma the file does not record.
//!
//! q3map2's `-gamma g` stores each luxel's light `L` (its bytes, before the clamp) as
//! `255 (L / 255)^(1/g)` (`ColorToBytes`), so the stored fraction `v` reads back as
//! `e = 2^overbright v^g`. Where the compile recorded its command line convert puts `g`
//! on the materials and the rows are built with it; where it did not (the OACMP maps
//! keep no `_q3map2_cmdline`), relight estimates it from the data (`pipeline`'s gamma
//! stage). Both directions live here:
//!
//! - [`regraded`]: rows built with gamma 1 (the stored bytes read linearly) read through
//!   `g`: every bound `albedo e` becomes `albedo 2^ob (e / 2^ob)^g`, intervals map to
//!   intervals (the map is increasing), and the error's denominator is recomputed;
//! - [`to_stored`]: a model's radiance fitted to such rows, taken back to the stored
//!   reading, where candidates of different `g` are compared (each candidate's own
//!   reading would change the yardstick with the candidate).
//!
//! The map is exact for luxel and vertex-colour rows (one byte each); for the thesis's
//! projected rows (averages of bytes) it is the map of the average, an approximation.

use super::Rows;

/// `albedo s (r / (albedo s))^p` per channel: radiance `r` of a row with albedo
/// `albedo`, re-read with exponent `p` around full scale `s = 2^overbright` (`e` of a
/// stored fraction of 1). Zero (or negative) albedo or radiance gives zero.
#[inline]
fn power_about(r: f64, albedo: f64, e_full: f64, p: f64) -> f64 {
    let s = albedo * e_full;
    if !(s > 0.0) || !(r > 0.0) {
        return 0.0;
    }
    s * (r / s).powf(p)
}

/// The rows' data read through compile gamma `gamma` instead of 1 (see the module
/// docs). `e_full`: `e` of a stored fraction of 1 (`2^overbright`).
///
/// The sampling rules stay as they are. q3map2's falloff tolerance is one byte of its
/// light, which through a gamma `g` after `-compensate c` reads `c^(1 - g)` of the
/// stored reading's (0.84 for 1.25 after `-compensate 2`); kept at the stored reading's,
/// so that a candidate needs no shadow ray beyond those already traced (a light's traced
/// reach grows as its cut falls).
pub fn regraded(rows: &Rows, gamma: f64, e_full: f64) -> Rows {
    let mut r = rows.clone();
    for i in 0..r.len() {
        for c in 0..3 {
            let a = rows.albedo[i][c] as f64;
            r.lo[i][c] = power_about(rows.lo[i][c] as f64, a, e_full, gamma) as f32;
            r.hi[i][c] = power_about(rows.hi[i][c] as f64, a, e_full, gamma) as f32;
            r.lower[i][c] = power_about(rows.lower[i][c] as f64, a, e_full, gamma) as f32;
        }
    }
    r.finish();
    r
}

/// Radiance `x` fitted to rows regraded by `gamma`, in the stored reading (gamma 1) of
/// the same rows: the inverse of [`regraded`]'s map, row by row.
pub fn to_stored(rows: &Rows, x: &[[f64; 3]], gamma: f64, e_full: f64) -> Vec<[f64; 3]> {
    x.iter().enumerate().map(|(i, xi)| [0, 1, 2].map(|c| power_about(xi[c], rows.albedo[i][c] as f64, e_full, 1.0 / gamma))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rows::{Row, Sampling, SolidAhead};
    use glam::Vec3;

    fn row(albedo: [f32; 3], lo: [f32; 3], hi: [f32; 3]) -> Row {
        Row { vertex: 0, material: 0, texel: [u32::MAX; 3], pos: Vec3::ZERO, normal: Vec3::Y, albedo, lo, hi, weight: [1.0; 3], lower: [0.0; 3], area: 1.0, solid_ahead: SolidAhead::NONE, two_sided: false }
    }

    /// A q3map2 byte written under `-gamma g` and read as rows with gamma 1, then
    /// regraded by `g`, is the light q3map2 had; `to_stored` takes it back.
    #[test]
    fn regrading_undoes_the_compiles_gamma_and_to_stored_undoes_the_regrading() {
        let e_full = 4.0;
        let g = 1.5;
        let albedo = [0.5, 0.25, 0.0];
        // q3map2's light as e (irradiance over pi): 0.3 of full scale.
        let light = 0.3 * e_full;
        let stored_fraction = (light / e_full as f64).powf(1.0 / g);
        let e_read = e_full as f64 * stored_fraction;
        let r = |a: f32| (a as f64 * e_read) as f32;
        let mut rows = Rows::new(Sampling { falloff: 0.1, ..Sampling::default() });
        rows.push(row(albedo, [r(albedo[0]), r(albedo[1]), 0.0], [r(albedo[0]), r(albedo[1]), 0.0]));
        rows.finish();
        let back = regraded(&rows, g, e_full as f64);
        for c in 0..2 {
            let want = albedo[c] as f64 * light;
            assert!((back.lo[0][c] as f64 - want).abs() < 1e-5 * want, "channel {c}: {} against {want}", back.lo[0][c]);
        }
        assert_eq!(back.lo[0][2], 0.0, "no albedo, no data");
        assert!(back.norm2 < rows.norm2, "darker through a gamma above 1");
        assert_eq!(back.sampling, rows.sampling);
        let x = [[back.lo[0][0] as f64, back.lo[0][1] as f64, 0.0]];
        let stored = to_stored(&rows, &x, g, e_full as f64);
        for c in 0..2 {
            assert!((stored[0][c] - rows.lo[0][c] as f64).abs() < 1e-5, "channel {c}");
        }
        // Gamma 1 changes nothing.
        let same = regraded(&rows, 1.0, e_full as f64);
        assert_eq!(same.lo, rows.lo);
        assert!((same.norm2 - rows.norm2).abs() < 1e-12);
    }

    /// The map is increasing: an interval stays an interval, censored bounds included.
    #[test]
    fn intervals_stay_ordered() {
        let mut rows = Rows::new(Sampling::default());
        let mut r = row([0.8; 3], [0.1, 0.5, 2.0], [0.2, 0.6, 3.1]);
        r.weight = [1.0, 1.0, 0.0];
        r.lower = [0.0, 0.0, 3.1];
        rows.push(r);
        rows.finish();
        for g in [0.8, 1.25, 2.0] {
            let b = regraded(&rows, g, 4.0);
            for c in 0..3 {
                assert!(b.lo[0][c] <= b.hi[0][c] && b.lo[0][c] >= 0.0, "gamma {g} channel {c}");
            }
            assert!(b.lower[0][2] > 0.0);
        }
    }
}
