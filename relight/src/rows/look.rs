//! Which picture the rows hold: q3map2's light as baked, or what the game's screen shows.
//!
//! The lightmap bytes are q3map2's linear light (`e = byte 2^overbright / 255`); fitting
//! them recovers the mapper's lights. The game does not show `albedo e`: ioquake3's
//! classic renderer multiplies 8-bit display values, the texture's sRGB byte `T` times the
//! lightmap shifted by the overbright bits and clamped keeping its hue,
//! `L = e / max(1, max_c e_c)`, and the screen turns `T L` into light through the sRGB
//! transfer function `D`. So a texel of linear albedo `a` (`T = D^-1(a)`) shows
//!
//! ```text
//! radiance = D(D^-1(a) L) = a g(a, L),   g(a, L) = D(D^-1(a) L) / a
//! ```
//!
//! and a linear renderer (Cycles) shows `a E / pi`. Fitting `E / pi` to `g` makes the
//! renderer's picture the game's: [`Look::Game`]. `g` is close to `L^2.2` (exactly `L^2.4`
//! in the curve's upper part, `L` in its linear toe), so the game is darker than the bytes'
//! light wherever `e < 1`, and cannot show more than `L = 1` (`e >= 1` saturates: those
//! rows stay intervals at what the screen shows, since the renderer clamps nothing).
//! Measured against the game's own frames in `make render`
//! (tools/game/compare.py).

use serde::Serialize;

use super::Rows;

/// The picture the fit reproduces.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Look {
    /// q3map2's baked light as stored (`albedo e`): the mapper's lights (the default).
    #[default]
    Lightmap,
    /// What the game's screen shows (`a g(a, L)`, see the module docs): a linear renderer
    /// lit by the result looks like the game.
    Game,
}

/// The sRGB transfer function (display value in [0, 1] -> light).
pub fn srgb_decode(v: f64) -> f64 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
}

/// Its inverse (light in [0, 1] -> display value).
pub fn srgb_encode(l: f64) -> f64 {
    let l = l.clamp(0.0, 1.0);
    if l <= 0.003_130_8 { 12.92 * l } else { 1.055 * l.powf(1.0 / 2.4) - 0.055 }
}

/// `g(a, L)`: the light the screen shows per unit of linear albedo `a` where the engine's
/// clamped lightmap value is `l` (in [0, 1]). For `a -> 0` it tends to `l` (the curve's
/// linear toe); it is 1 at `l = 1` and increasing in `l`.
pub fn screen_factor(albedo: f64, l: f64) -> f64 {
    let l = l.clamp(0.0, 1.0);
    if albedo <= 1e-9 {
        return l;
    }
    let a = albedo.min(1.0);
    srgb_decode(srgb_encode(a) * l) / a
}

/// Rewrites `rows` (built from the lightmaps, [`Look::Lightmap`]) into what the game's
/// screen shows ([`Look::Game`]): every interval `a e` becomes `a g(a, L(e))`, with one
/// hue clamp per row from the middle of its intervals (the engine clamps a texel's three
/// channels together). No row is a lower bound here, neither one the screen saturates
/// (`max_c e_c > 1`) nor one whose stored byte sat at the compile's clamp (taken at the
/// lower end it keeps): the screen shows the stored bytes through the engine's clamp,
/// whatever light was above them, and the renderer that draws the fitted lights clamps
/// nothing, so any light the fit put above the clamp would be drawn. As lower bounds they
/// let oa_dm1's screen fit put two lights 7 units from a dark wall whose lightmap is
/// saturated (the model 4 to 9 times the bound on its luxels), drawn by Cycles as bright dots
/// the game does not show. Rows without albedo carry no information either way and stay
/// as they are. Recomputes the error's denominator.
pub fn to_game_screen(rows: &mut Rows) {
    for i in 0..rows.len() {
        let a = rows.albedo[i].map(|v| v as f64);
        if a.iter().all(|&v| v <= 1e-9) {
            continue;
        }
        // e of each bound (radiance / albedo); channels without albedo have no light to show.
        let e = |v: f32, c: usize| if a[c] > 1e-9 { v as f64 / a[c] } else { 0.0 };
        // Each channel's stored light as an interval of e: the byte's, a censored
        // channel's lower end as a point, and a row projected from both (`--target
        // vertex`: weight `w` of the interval, the rest at the lower end) their blend;
        // `None`: no data in the channel.
        let w = rows.weight[i];
        let stored: [Option<(f64, f64)>; 3] = std::array::from_fn(|c| {
            let wc = w[c].clamp(0.0, 1.0) as f64;
            let l = e(rows.lower[i][c], c);
            match (wc > 0.0, rows.lower[i][c] > 0.0 && wc < 1.0) {
                (true, true) => Some((wc * e(rows.lo[i][c], c) + (1.0 - wc) * l, wc * e(rows.hi[i][c], c) + (1.0 - wc) * l)),
                (true, false) => Some((e(rows.lo[i][c], c), e(rows.hi[i][c], c))),
                (false, true) => Some((l, l)),
                (false, false) => None,
            }
        });
        let peak = stored.iter().flatten().map(|&(lo, hi)| 0.5 * (lo + hi)).fold(0.0, f64::max);
        let shown = |v: f64, c: usize| (a[c] * screen_factor(a[c], v / peak.max(1.0))) as f32;
        for (c, s) in stored.iter().enumerate() {
            let Some((lo, hi)) = *s else { continue };
            rows.lo[i][c] = shown(lo, c);
            rows.hi[i][c] = shown(hi, c).max(rows.lo[i][c]);
            rows.weight[i][c] = 1.0;
            rows.lower[i][c] = 0.0;
        }
    }
    rows.finish();
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rows::{Row, Sampling};
    use glam::Vec3;

    #[test]
    fn the_transfer_function_round_trips_and_the_factor_is_the_screens() {
        for k in 0..=100 {
            let v = k as f64 / 100.0;
            assert!((srgb_encode(srgb_decode(v)) - v).abs() < 1e-12);
        }
        // 8-bit check: display byte 128 is light 0.2158605 (the standard's table).
        assert!((srgb_decode(128.0 / 255.0) - 0.215_860_5).abs() < 1e-6);
        // g(a, 1) = 1; g(a, 0) = 0; increasing; ~ L^2.4 in the upper part of the curve.
        for a in [0.02, 0.2, 0.5, 1.0] {
            assert!((screen_factor(a, 1.0) - 1.0).abs() < 1e-12);
            assert_eq!(screen_factor(a, 0.0), 0.0);
            let mut prev = 0.0;
            for k in 1..=50 {
                let g = screen_factor(a, k as f64 / 50.0);
                assert!(g > prev);
                prev = g;
            }
        }
        let (a, l) = (0.5, 0.5);
        let t = srgb_encode(a);
        assert!((screen_factor(a, l) - ((t * l + 0.055) / 1.055f64).powf(2.4) / a).abs() < 1e-12);
        // Dark albedo: the linear toe, g -> L.
        assert!((screen_factor(1e-12, 0.3) - 0.3).abs() < 1e-12);
    }

    fn row(albedo: [f32; 3], e_lo: [f32; 3], e_hi: [f32; 3]) -> Row {
        Row { vertex: 0, material: 0, texel: [u32::MAX; 3], pos: Vec3::ZERO, normal: Vec3::Z, albedo, lo: [0, 1, 2].map(|c| albedo[c] * e_lo[c]), hi: [0, 1, 2].map(|c| albedo[c] * e_hi[c]), weight: [1.0; 3], lower: [0.0; 3], area: 1.0, solid_ahead: crate::rows::SolidAhead::NONE, two_sided: false }
    }

    #[test]
    fn rows_become_what_the_screen_shows() {
        let mut rows = Rows::new(Sampling::plain(1.0));
        rows.push(row([0.5, 0.25, 0.1], [0.5, 0.25, 0.75], [0.52, 0.27, 0.77])); // below saturation
        rows.push(row([0.5, 0.5, 0.5], [2.0, 1.0, 0.5], [2.1, 1.05, 0.55])); // the engine clamps: hue kept
        rows.push(Row { weight: [0.0; 3], lo: [0.0; 3], hi: [0.0; 3], lower: [2.0, 2.0, 1.0], ..row([0.5; 3], [0.0; 3], [0.0; 3]) }); // censored
        rows.push(row([0.0; 3], [1.0; 3], [1.1; 3])); // no albedo: untouched
        rows.push(Row { weight: [0.25; 3], lower: [0.4; 3], ..row([0.5; 3], [0.2; 3], [0.22; 3]) }); // projected from both
        rows.finish();
        let before = rows.clone();
        to_game_screen(&mut rows);
        for c in 0..3 {
            let a = before.albedo[0][c] as f64;
            let e = before.lo[0][c] as f64 / a;
            assert!((rows.lo[0][c] as f64 - a * screen_factor(a, e)).abs() < 1e-6);
            assert!(rows.hi[0][c] >= rows.lo[0][c] && rows.lo[0][c] < before.lo[0][c], "the screen is darker than the light below e = 1");
        }
        // Saturated: the brightest channel shows 1 (radiance = albedo), the others keep the
        // hue; an interval, not a lower bound (the renderer would draw any light above it).
        assert_eq!(rows.weight[1], [1.0; 3]);
        assert_eq!(rows.lower[1], [0.0; 3]);
        let mid = |c: usize| 0.5 * (before.lo[1][c] + before.hi[1][c]) as f64 / 0.5;
        let peak = mid(0);
        assert!((rows.lo[1][1] as f64 - 0.5 * screen_factor(0.5, before.lo[1][1] as f64 / 0.5 / peak)).abs() < 1e-6);
        assert!(rows.lo[1][0] as f64 > 0.5 * 0.9 && rows.hi[1][0] as f64 <= 0.5 + 1e-6);
        // Censored at the compile's clamp: its lower end through the same clamp, as a point.
        assert_eq!(rows.weight[2], [1.0; 3]);
        assert!((rows.lo[2][0] - 0.5).abs() < 1e-6 && (rows.lo[2][2] as f64 - 0.5 * screen_factor(0.5, 0.5)).abs() < 1e-6);
        assert_eq!(rows.lo[2], rows.hi[2]);
        // Projected from an interval (weight 0.25, e 0.2-0.22) and a clamped rest (e 0.8):
        // the blend, e 0.65-0.655, through the screen.
        assert_eq!(rows.weight[4], [1.0; 3]);
        assert!((rows.lo[4][0] as f64 - 0.5 * screen_factor(0.5, 0.65)).abs() < 1e-6 && (rows.hi[4][0] as f64 - 0.5 * screen_factor(0.5, 0.655)).abs() < 1e-6);
        assert!(!rows.any_censored(), "the screen's rows are all intervals");
        assert_eq!(rows.row(3).lo, before.row(3).lo);
        assert!(rows.norm2 > 0.0 && rows.norm2 < before.norm2);
    }
}
