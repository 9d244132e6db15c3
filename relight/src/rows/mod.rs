//! The rows of the objective: the surface points where the model is compared with the
//! baked lighting, and what the data says there.
//!
//! A row is a lightmap texel's sample point ([`luxel`], the default) or a (subdivided) mesh
//! vertex carrying the thesis's mass-lumped projection ([`projection`]); the model, the
//! kernels and the fit treat both alike. Each row holds its position and normal (m,
//! relative to `Scene::origin`), its area `A` (m^2), its linear albedo, and the data as
//! an interval of radiance per channel:
//!
//! - weight `w` of a two-sided target `[lo, hi]`: a lightmap byte `b` stands for any
//!   value in `[b, b + 1)` (q3map2 truncates), so the data is consistent with every model
//!   value in that interval (`lo == hi` for the projection, whose values are averages);
//! - weight `1 - w` of a lower bound `lower` where the data was clamped (censored).
//!
//! The objective's term of one row and channel is
//!
//! ```text
//! f = 1/2 A [ w (x - clamp(x, lo, hi))^2 + (1 - w) min(0, x - lower)^2 ]
//! ```
//!
//! and the relative error `sqrt(sum 2 f / sum A [w mid^2 + (1 - w) lower^2])` with
//! `mid = (lo + hi) / 2`: zero for a model that every byte agrees with, and 1 for no light
//! at all, censored texels included (a fully saturated lightmap is not a perfect fit of
//! darkness).
//!
//! [`Sampling`] holds how the data was sampled (q3map2's rules for its lightmaps);
//! [`look`] turns the rows into what the game's screen shows instead of the baked light.

pub mod gamma;
pub mod look;
pub mod luxel;
pub mod projection;

use glam::Vec3;

/// Rows per block of the CPU's parallel loops over rows (the lights' kernels, the
/// residuals, the linear fit's Gram blocks): a multiple of 32 (whole visibility words),
/// about 64 blocks (a placement's 20 000-row subsample was 3 to 5 blocks of 4096 or
/// 8192, so 16 cores ran it on 3 to 5 threads), between 512 and 4096 rows. A function of
/// the row count alone: a block's sums, and the order blocks are added in, do not depend
/// on the number of threads.
pub fn block_rows(n: usize) -> usize {
    (n / 64).next_multiple_of(32).clamp(512, 4096)
}

/// How the baked data was sampled: the rules the model and the shadow rays follow to
/// compare like with like (see [`crate::scene::q3map2`] for q3map2's values).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Sampling {
    /// A point or spot light's inverse square never comes closer than this, m.
    pub eps: f32,
    /// Rays that look for the surface they meet (bounce gathers, the placement's
    /// clearance) start this far along the normal, m.
    pub ray_offset: f32,
    /// Shadow rays towards a light or a sun start this far along the normal, m.
    pub shadow_offset: f32,
    /// Shadow rays ignore geometry closer than this to their start, m.
    pub inhibit: f32,
    /// A point or spot light adds nothing where its brightest channel's irradiance would
    /// be at most this, W/m^2 (0: no cut).
    pub falloff: f32,
    /// Width of a spot light's soft edge, m (q3map2: 32 units).
    pub spot_ramp: f32,
    /// A segment starting on a plane that ends no further than this on its open side
    /// counts as running along it, m (q3map2's `TRACE_ON_EPSILON`, 0.1 unit; see
    /// [`SolidAhead`]).
    pub on_epsilon: f32,
}

impl Sampling {
    /// Plain physical sampling for a scene of this diagonal (m): no cut, tiny offsets.
    pub fn plain(scene_diagonal: f32) -> Sampling {
        let offset = (1e-5 * scene_diagonal).max(1e-3);
        Sampling { eps: (1e-3 * scene_diagonal).max(0.01), ray_offset: offset, shadow_offset: offset, inhibit: 0.0, falloff: 0.0, spot_ramp: 32.0 * 0.0254, on_epsilon: 0.0 }
    }

    /// q3map2's sampling for a scene of `units_m` meters per Quake unit whose lightmaps
    /// decode with `overbright_bits` and store `stored_per_light_byte` bytes per byte of
    /// q3map2's light ([`crate::scene::Material::stored_per_light_byte`]): the inverse
    /// square never closer than 16 units, shadow rays from the sample origin itself (no
    /// offset: q3map2's start there, and where a ray grazes an edge within its 1% slack
    /// the offset decides it; the recompiled oacmpdm3, point lights only: 0.0283 with a
    /// millimetre's offset, 0.0156 without) and blind within 1.5 units of it, never
    /// stopped within the plain offset of the light (a light on a face: q3map2's f32
    /// depth decides those ray by ray; the shipped oacmpdm1's lights on its walls, with
    /// its source lights and the global terms fitted: 0.1743 stopped there, 0.1541 not),
    /// the rays that look for a surface (bounce gathers) from the plain offset too, and
    /// a light's contribution of at most 1 byte of q3map2's light left out
    /// (half a stored byte after `-compensate 2`).
    pub fn q3map2(scene_diagonal: f32, units_m: f32, overbright_bits: u32, stored_per_light_byte: f32) -> Sampling {
        use crate::scene::q3map2::*;
        let stored = FALLOFF_TOLERANCE_BYTES as f64 * stored_per_light_byte as f64;
        let falloff = (stored * std::f64::consts::PI * q3gltf_convert::units::e_per_byte(overbright_bits)) as f32;
        Sampling { eps: MIN_DISTANCE_UNITS * units_m, shadow_offset: 0.0, inhibit: INHIBIT_RADIUS_UNITS * units_m, falloff, spot_ramp: SPOT_RAMP_UNITS * units_m, on_epsilon: PLANE_EPSILON_UNITS * units_m, ..Sampling::plain(scene_diagonal) }
    }
}

/// The rows of the objective (see the module docs).
#[derive(Debug, Clone, Default)]
pub struct Rows {
    /// Mesh vertex of each row (`u32::MAX` for a luxel row).
    pub vertex: Vec<u32>,
    /// Material of each row (the report's breakdown by material).
    pub material: Vec<u32>,
    /// Lightmap texture and texel `(x, y)` of a luxel row (`u32::MAX` for a vertex row).
    pub texel: Vec<[u32; 3]>,
    pub pos: Vec<Vec3>,
    pub normal: Vec<Vec3>,
    pub albedo: Vec<[f32; 3]>,
    /// Lower end of the data's interval, radiance.
    pub lo: Vec<[f32; 3]>,
    /// Upper end of the data's interval, radiance (`>= lo`).
    pub hi: Vec<[f32; 3]>,
    /// Weight of the interval, in [0, 1]; the rest is the lower bound's.
    pub weight: Vec<[f32; 3]>,
    /// Lower bound where the data was censored.
    pub lower: Vec<[f32; 3]>,
    /// Row area A_i, m^2.
    pub area: Vec<f32>,
    /// Directions along which the row's sample point touches solid ([`SolidAhead`]).
    pub solid_ahead: Vec<SolidAhead>,
    /// Whether the row receives light on both faces (see [`Rows::facing`]).
    pub two_sided: Vec<bool>,
    pub sampling: Sampling,
    /// `sum A w mid^2`, the error's denominator (0 only without data).
    pub norm2: f64,
}

/// One row as pushed by the builders.
#[derive(Debug, Clone, Copy)]
pub struct Row {
    pub vertex: u32,
    pub material: u32,
    pub texel: [u32; 3],
    pub pos: Vec3,
    pub normal: Vec3,
    pub albedo: [f32; 3],
    pub lo: [f32; 3],
    pub hi: [f32; 3],
    pub weight: [f32; 3],
    pub lower: [f32; 3],
    pub area: f32,
    pub solid_ahead: SolidAhead,
    pub two_sided: bool,
}

impl Row {
    /// The row with its data a lower bound in every channel, at its interval's lower end
    /// (a clamped byte: q3map2 kept its hue, so every channel is at least what it says).
    pub fn lower_bound(self) -> Row {
        Row { lo: [0.0; 3], hi: [0.0; 3], weight: [0.0; 3], lower: self.lo, ..self }
    }
}

/// The axial planes of solid a sample point lies on (within q3map2's `TRACE_ON_EPSILON`)
/// whose solid side is their positive side in Quake's axes, as bits: 1 `+x`, 2 `+y`,
/// 4 `-z` (glTF axes: Quake's `+x`, `+z`, `+y`). q3map2's BSP puts a segment that starts
/// on such a plane and does not end more than 0.1 unit on its open side into the solid
/// child: a ray running along a wall whose brush lies on the positive side is stopped at
/// once (a face's edge row where it meets that wall: its dirt, its sky). The BSP keeps
/// only the positive plane of each axial pair, so a wall on the negative side lets the
/// same ray go.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SolidAhead(pub u8);

impl SolidAhead {
    pub const NONE: SolidAhead = SolidAhead(0);

    /// The unit directions (glTF axes) towards the solid of each bit.
    pub const DIRECTIONS: [(u8, Vec3); 3] = [(1, Vec3::X), (2, Vec3::Y), (4, Vec3::NEG_Z)];

    /// Whether `d` runs exactly along one of the planes (within f32 rounding): what q3map2's
    /// sun trace stops on such a plane (measured: the sky-light fixture 0.054 -> 0.047;
    /// stopping the suns that enter the solid as well broke the sun fixture, 0 -> 0.065:
    /// with `testAll` the sun's trace is stopped by triangles there, not by the BSP).
    pub fn along(self, d: Vec3) -> bool {
        self.0 != 0 && Self::DIRECTIONS.iter().any(|&(bit, axis)| self.0 & bit != 0 && d.dot(axis).abs() < 1e-6)
    }

    /// Whether the segment `d * length` from the point goes into that solid at once:
    /// it ends on no plane's open side by more than `on_epsilon` (same units as `length`).
    pub fn stops(self, d: Vec3, length: f32, on_epsilon: f32) -> bool {
        self.0 != 0 && Self::DIRECTIONS.iter().any(|&(bit, axis)| self.0 & bit != 0 && d.dot(axis) * length >= -on_epsilon)
    }
}

impl Rows {
    /// No rows yet, with these sampling rules.
    pub fn new(sampling: Sampling) -> Rows {
        Rows { sampling, ..Default::default() }
    }

    /// The relative error of radiance `x` (one value per row and channel; see the module
    /// docs), what [`crate::model::evaluate`] reports.
    pub fn rel_error(&self, x: &[[f64; 3]]) -> f64 {
        let mut num = 0.0;
        for (i, xi) in x.iter().enumerate().take(self.len()) {
            for c in 0..3 {
                num += residual(xi[c], self.lo[i][c] as f64, self.hi[i][c] as f64, self.weight[i][c] as f64, self.lower[i][c] as f64, self.area[i] as f64).2;
            }
        }
        if self.norm2 > 0.0 { (num / self.norm2).sqrt() } else { 0.0 }
    }

    pub fn push(&mut self, r: Row) {
        self.vertex.push(r.vertex);
        self.material.push(r.material);
        self.texel.push(r.texel);
        self.pos.push(r.pos);
        self.normal.push(r.normal);
        self.albedo.push(r.albedo);
        self.lo.push(r.lo);
        self.hi.push(r.hi);
        self.weight.push(r.weight);
        self.lower.push(r.lower);
        self.area.push(r.area);
        self.solid_ahead.push(r.solid_ahead);
        self.two_sided.push(r.two_sided);
    }

    pub fn row(&self, i: usize) -> Row {
        Row {
            vertex: self.vertex[i],
            material: self.material[i],
            texel: self.texel[i],
            pos: self.pos[i],
            normal: self.normal[i],
            albedo: self.albedo[i],
            lo: self.lo[i],
            hi: self.hi[i],
            weight: self.weight[i],
            lower: self.lower[i],
            area: self.area[i],
            solid_ahead: self.solid_ahead[i],
            two_sided: self.two_sided[i],
        }
    }

    /// The normal row `i` receives light from direction `d` (towards the emitter) with:
    /// its own, or, on a two-sided row (q3map2's `twoSided` trace for a `cull none`
    /// shader) with `d` behind it, its negation. Every emitter's cosine, its culling and
    /// the side its shadow ray starts on follow this normal, so a two-sided row receives
    /// `E(x, n) + E(x, -n)`: q3map2's `|cos|` with no behind-culling. Along the plane
    /// (`n . d == 0`) the row's own normal.
    #[inline]
    pub fn facing(&self, i: usize, d: Vec3) -> Vec3 {
        let n = self.normal[i];
        if self.two_sided[i] && n.dot(d) < 0.0 {
            -n
        } else {
            n
        }
    }

    /// The rows `keep` (in that order), with their own error denominator.
    pub fn subset(&self, keep: &[usize]) -> Rows {
        let mut r = Rows { sampling: self.sampling, ..Rows::default() };
        for &i in keep {
            r.push(self.row(i));
        }
        r.finish();
        r
    }

    /// Completes rows pushed one by one (computes the error's denominator).
    pub fn finish(&mut self) {
        self.norm2 = (0..self.len())
            .map(|i| {
                (0..3)
                    .map(|c| {
                        let w = self.weight[i][c] as f64;
                        self.area[i] as f64 * (w * self.mid(i, c).powi(2) + (1.0 - w) * (self.lower[i][c] as f64).powi(2))
                    })
                    .sum::<f64>()
            })
            .sum();
    }

    /// The middle of row `i`'s interval in channel `c`.
    #[inline]
    /// Whether some channel of some row is censored (a lower bound with weight below 1).
    pub fn any_censored(&self) -> bool {
        self.lower.iter().zip(&self.weight).any(|(l, w)| (0..3).any(|c| w[c] < 1.0 && l[c] > 0.0))
    }

    pub fn mid(&self, i: usize, c: usize) -> f64 {
        0.5 * (self.lo[i][c] as f64 + self.hi[i][c] as f64)
    }

    pub fn len(&self) -> usize {
        self.pos.len()
    }
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }

    /// Whether any row carries data (an interval or a lower bound).
    pub fn has_data(&self) -> bool {
        (0..self.len()).any(|i| (0..3).any(|c| self.weight[i][c] > 0.0 || self.lower[i][c] > 0.0))
    }

    /// Keeps the rows whose flag is true.
    pub fn retain(&mut self, keep: &[bool]) {
        let old = std::mem::replace(self, Rows::new(self.sampling));
        for (i, &k) in keep.iter().enumerate().take(old.len()) {
            if k {
                self.push(old.row(i));
            }
        }
        self.finish();
    }

    /// A subset of at most about `max` rows: every `stride`-th one, starting at
    /// `seed % stride` (areas scaled so sums stay comparable). Returns the subset and the
    /// indices it took.
    /// The rows with a known part `x` of the model's radiance taken out of the data: what
    /// is left for the rest of the model to explain. Every row's interval and lower bound
    /// move down by `x`; the error's denominator stays the whole data's. So the objective,
    /// its gradient and the relative error of a partial model on these rows are the whole
    /// model's, as long as the model's radiance is the sum of the parts (no minlight
    /// floor across them).
    pub fn less(&self, x: &[[f64; 3]]) -> Rows {
        debug_assert_eq!(x.len(), self.len());
        let shift = |v: &[[f32; 3]]| -> Vec<[f32; 3]> { v.iter().zip(x).map(|(v, x)| [0, 1, 2].map(|c| (v[c] as f64 - x[c]) as f32)).collect() };
        Rows { lo: shift(&self.lo), hi: shift(&self.hi), lower: shift(&self.lower), ..self.clone() }
    }

    pub fn subsample(&self, max: usize, seed: u64) -> (Rows, Vec<usize>) {
        let stride = self.len().div_ceil(max.max(1)).max(1);
        let take: Vec<usize> = if stride == 1 { (0..self.len()).collect() } else { ((seed % stride as u64) as usize..self.len()).step_by(stride).collect() };
        let mut p = Rows::new(self.sampling);
        for &i in &take {
            let mut r = self.row(i);
            r.area *= stride as f32;
            p.push(r);
        }
        p.finish();
        (p, take)
    }
}

/// One row-channel's objective term: `(f, dF/dx, 2 f)`, the last the relative error's
/// numerator (see the module docs).
#[inline]
pub fn residual(x: f64, lo: f64, hi: f64, w: f64, lower: f64, area: f64) -> (f64, f64, f64) {
    let two = x - x.clamp(lo, hi.max(lo));
    let one = (x - lower).min(0.0);
    let f = 0.5 * area * (w * two * two + (1.0 - w) * one * one);
    let rho = area * (w * two + (1.0 - w) * one);
    (f, rho, 2.0 * f)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Blocks are whole visibility words, a placement's subsample splits into tens of
    /// them, and a map's rows into blocks of at most 4096.
    #[test]
    fn blocks_are_whole_words_and_enough_for_many_cores() {
        for n in [0, 1, 31, 700, 20_000, 143_339, 600_000, 5_000_000] {
            let b = block_rows(n);
            assert!(b % 32 == 0 && (512..=4096).contains(&b), "{n} rows: blocks of {b}");
        }
        assert!(20_000usize.div_ceil(block_rows(20_000)) >= 32, "a placement subsample in {} blocks", 20_000usize.div_ceil(block_rows(20_000)));
    }

    #[test]
    fn residual_is_zero_inside_the_interval_and_quadratic_outside() {
        assert_eq!(residual(1.5, 1.0, 2.0, 1.0, 0.0, 2.0), (0.0, 0.0, 0.0));
        let (f, rho, n) = residual(3.0, 1.0, 2.0, 1.0, 0.0, 2.0);
        assert_eq!((f, rho, n), (1.0, 2.0, 2.0));
        let (f, rho, _) = residual(0.5, 1.0, 2.0, 1.0, 0.0, 2.0);
        assert_eq!((f, rho), (0.25, -1.0));
        // A censored channel (w = 0): only below the bound costs.
        assert_eq!(residual(5.0, 0.0, 0.0, 0.0, 4.0, 1.0).0, 0.0);
        assert_eq!(residual(3.0, 0.0, 0.0, 0.0, 4.0, 1.0), (0.5, -1.0, 1.0));
    }

    #[test]
    fn a_ray_along_a_positive_wall_stops_and_along_a_negative_one_goes() {
        // On the plane of a wall whose solid is at +x (glTF and Quake): rays that do not
        // leave it by more than 0.1 unit towards -x stop, as q3map2's BSP sends them into
        // the solid child; a wall at -x (bit not set) stops nothing.
        let plus_x = SolidAhead(1);
        let (len, eps) = (128.0, 0.1);
        assert!(plus_x.stops(Vec3::X, len, eps), "into the wall");
        assert!(plus_x.stops(Vec3::Y, len, eps), "along it");
        assert!(plus_x.stops(Vec3::new(-4e-8, 1.0, 0.0).normalize(), len, eps), "along it, within float");
        assert!(!plus_x.stops(Vec3::new(-0.01, 1.0, 0.0).normalize(), len, eps), "1.28 units off it into the open");
        assert!(!SolidAhead::NONE.stops(Vec3::X, len, eps));
        // Quake's +y is glTF's -z.
        assert!(SolidAhead(4).stops(Vec3::new(1.0, 0.0, 0.0), len, eps) && !SolidAhead(4).stops(Vec3::Z, len, eps));
    }

    #[test]
    fn retain_and_subsample_keep_rows_whole() {
        let mut rows = Rows::new(Sampling::plain(1.0));
        for k in 0..10 {
            let v = k as f32;
            rows.push(Row { vertex: k, material: 0, texel: [u32::MAX; 3], pos: Vec3::splat(v), normal: Vec3::Y, albedo: [v; 3], lo: [v; 3], hi: [v + 1.0; 3], weight: [1.0; 3], lower: [0.0; 3], area: 1.0, solid_ahead: SolidAhead::NONE, two_sided: false });
        }
        rows.finish();
        let (sub, take) = rows.subsample(5, 1);
        assert_eq!(take, vec![1, 3, 5, 7, 9]);
        assert_eq!(sub.area[0], 2.0);
        assert_eq!(sub.lo[2], [5.0; 3]);
        rows.retain(&(0..10).map(|k| k % 3 == 0).collect::<Vec<_>>());
        assert_eq!(rows.vertex, vec![0, 3, 6, 9]);
        assert!((rows.norm2 - 3.0 * (0.25 + 12.25 + 42.25 + 90.25)).abs() < 1e-9);
    }
}
