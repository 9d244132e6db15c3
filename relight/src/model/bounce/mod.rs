//! Bounced light: the light of the model's own emitters, reflected by the scene, the
//! way q3map2's radiosity (`-bounce N`) re-emits it, pass after pass.
//!
//! A Lambertian row `j` lit by `E_j` sends radiance `albedo_j E_j / pi`. q3map2 does not
//! send it from where it is: between passes it cuts every lit surface into pieces and
//! each piece emits, as an area light, the average of its samples' reflected light
//! ([`pieces`]). The irradiance a pass brings to row `i` is estimated with `M`
//! cosine-weighted rays per hemisphere:
//!
//! ```text
//! E_bounce_i = sum_w G_iw sum_j P_wj rho_j T_j,   G_iw = (rays from i landing on piece w) / M
//! ```
//!
//! `P` (pieces x rows) is the pieces' averaging and `G` (rows x pieces) the gather; both
//! are traced once (the geometry does not change during a fit) and kept apart
//! ([`Transport`]: their product would hold thousands of entries per row). A ray lands
//! on the piece under the point it hits; rays that escape, hit the back of a one-sided
//! surface, a surface that bounces nothing (sky, unlit) or, under `-fast`, a piece whose
//! envelope does not reach the row, bring nothing. A two-sided row (a `cull none`
//! surface, [`Rows::facing`]) gathers over both of its hemispheres, `M` rays each, and
//! the back of a two-sided surface sends light as its front does (q3map2's bounce lights
//! of such a shader are two-sided). Landing on the row under the hit point instead (a
//! physical gather, what Cycles computes) left the corners of q3map2's `-bounce 2` box
//! 20% dark and the fixture at 0.046; with the pieces, 0.025 at 16 rays per row, 0.013 at
//! the 196 a scene that small gets ([`rays_for`]).
//!
//! q3map2's pieces emit the texture's raw byte (its sRGB encoding, read as linear) times
//! the luxel, with a fixed strength (`RADIOSITY_VALUE 500 x 0.375 x formFactorValueScale
//! 3 x -bouncescale 0.25 / 255`): a bounce with the reflectance
//!
//! ```text
//! rho_q3 = 0.5515 srgb(albedo)           ([`reflectance`])
//! ```
//!
//! about 1.3 times a mid-grey texture's linear albedo. The model bounces with `rho_q3`,
//! scaled per channel by a fitted `k_c` in (0, [`MAX_SCALE`]] (1: q3map2's default
//! `-bouncescale`), and applies the compile's filter and dirt to every pass
//! ([`super::Model`]). Cycles bounces with the linear albedo from where the light lands:
//! the report gives the ratio ([`physical_ratio`]), what the render will lack in indirect
//! light.
//!
//! The directions are stratified (`s x s` cells of the unit square, Malley's method)
//! with a jitter hashed from the row and the cell: deterministic.

pub mod pieces;

use glam::Vec3;

use super::compile::Sparse;
use crate::backend::Backend;
use crate::error::Result;
use crate::rows::Rows;
use crate::scene::Scene;
use crate::trace::bvh::Bvh;
use crate::trace::tree::PlaneRay;

/// A uniform number in [0, 1) from two integers (a 32-bit integer hash).
pub fn hash01(a: u32, b: u32) -> f32 {
    let mut x = a.wrapping_mul(0x9E37_79B9) ^ b.wrapping_mul(0x85EB_CA6B).rotate_left(13);
    x ^= x >> 16;
    x = x.wrapping_mul(0x7FEB_352D);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846C_A68B);
    x ^= x >> 16;
    (x >> 8) as f32 / (1u32 << 24) as f32
}

/// Direction `cell` of `s x s` stratified cosine-weighted directions around `n` for row
/// `i` (Malley: uniform on the disc, lifted to the hemisphere).
pub fn cosine_direction(n: Vec3, i: u32, cell: usize, s: usize) -> Vec3 {
    let (t1, t2) = n.any_orthonormal_pair();
    let u1 = ((cell / s) as f32 + hash01(i, 2 * cell as u32)) / s as f32;
    let u2 = ((cell % s) as f32 + hash01(i, 2 * cell as u32 + 1)) / s as f32;
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    (t1 * (r * phi.cos()) + t2 * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()).normalize_or_zero()
}

/// q3map2's bounce strength per unit of raw texture colour (see the module docs):
/// `500 x 0.375 x 3 x 0.25 / 255`.
pub const Q3MAP2_BOUNCE: f32 = 500.0 * 0.375 * 3.0 * 0.25 / 255.0;

/// Largest fitted scale of q3map2's bounce (`-bouncescale 1`, four times the default).
pub const MAX_SCALE: f32 = 4.0;

/// Rays the bounce's transport traces in all, when not asked for a number per row.
pub const RAY_BUDGET: usize = 1 << 20;
/// Fewest and most rays per row within [`RAY_BUDGET`].
pub const MIN_RAYS: usize = 16;
pub const MAX_RAYS: usize = 256;

/// Rays per row for `rows` rows when not asked: as many as [`RAY_BUDGET`] allows, from
/// [`MIN_RAYS`] to [`MAX_RAYS`], a square. The estimate's noise is what a small scene's
/// error is made of (q3map2's `-bounce 2` fixture: 0.025 with 16 rays, 0.015 with 64,
/// 0.012 with 256), and a small scene's rays are cheap; a map of 65k rows or more gets 16.
pub fn rays_for(rows: usize) -> usize {
    let r = (RAY_BUDGET / rows.max(1)).clamp(MIN_RAYS, MAX_RAYS);
    let s = (r as f64).sqrt().floor() as usize;
    s * s
}

/// The sRGB encoding of a linear value in [0, 1].
pub fn srgb_encode(c: f32) -> f32 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// The reflectance q3map2 bounces light with, per row ([`Q3MAP2_BOUNCE`] times the
/// albedo's sRGB encoding).
pub fn reflectance(rows: &Rows) -> Vec<[f32; 3]> {
    rows.albedo.iter().map(|a| a.map(|c| Q3MAP2_BOUNCE * srgb_encode(c))).collect()
}

/// How much weaker a physical bounce (the linear albedo, Cycles) is than q3map2's, on
/// these rows (area-weighted mean of `albedo / rho_q3`).
pub fn physical_ratio(rows: &Rows, rho: &[[f32; 3]]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for i in 0..rows.len().min(rho.len()) {
        for c in 0..3 {
            num += rows.area[i] as f64 * rows.albedo[i][c] as f64;
            den += rows.area[i] as f64 * rho[i][c] as f64;
        }
    }
    if den > 0.0 { num / den } else { 1.0 }
}

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct GatherStats {
    pub rows: usize,
    pub rays_per_row: usize,
    pub rays: u64,
    /// Rays that landed on a source.
    pub landed: u64,
    /// q3map2's bounce lights that emit ([`pieces`]; 0 when the sources are the rows).
    pub pieces: usize,
}

/// The transport of one bounce pass, `E = gather (emit (rho T))`: each row's
/// cosine-weighted rays land on sources, and each source's light is an average of rows.
#[derive(Debug, Clone, Default)]
pub struct Transport {
    /// Rows x sources: the share of a row's rays (per hemisphere) landing on each source.
    pub gather: Sparse,
    /// Sources x rows: q3map2's bounce lights, each piece's average of its samples
    /// ([`pieces`]); `None`: a ray's source is the row under the point it lands on.
    pub emit: Option<Sparse>,
}

impl Transport {
    /// `gather emit (col x)` ([`Sparse::apply`]'s column factor on the rows).
    pub fn apply(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>) -> Vec<[f64; 3]> {
        match &self.emit {
            None => self.gather.apply(x, col),
            Some(e) => self.gather.apply(&e.apply(x, col), None),
        }
    }

    /// The transpose, `col (emit^T gather^T y)`, over `y.len()` rows.
    pub fn apply_transposed(&self, y: &[[f64; 3]], col: Option<&[[f32; 3]]>) -> Vec<[f64; 3]> {
        match &self.emit {
            None => self.gather.apply_transposed(y, col),
            Some(e) => e.apply_transposed_len(&self.gather.apply_transposed_len(y, None, e.rows()), col, y.len()),
        }
    }

    /// [`Transport::apply`] to an `x` that is zero outside `support`, over the rows it
    /// reaches ([`Sparse::apply_supported`]: the same bits as `apply` there), or `None`
    /// past `limit` rows.
    pub fn apply_supported(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>, support: &[u32], limit: usize) -> Option<(Vec<[f64; 3]>, Vec<u32>)> {
        match &self.emit {
            None => self.gather.apply_supported(x, col, support, limit),
            Some(e) => {
                let (w, sources) = e.apply_supported(x, col, support, usize::MAX)?;
                self.gather.apply_supported(&w, None, &sources, limit)
            }
        }
    }
}

impl super::compile::Operator for Transport {
    fn apply(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>) -> Vec<[f64; 3]> {
        Transport::apply(self, x, col)
    }
    fn apply_supported(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>, support: &[u32], limit: usize) -> Option<(Vec<[f64; 3]>, Vec<u32>)> {
        Transport::apply_supported(self, x, col, support, limit)
    }
}

/// Traces the bounce's transport for `rows` with `rays_per_row` rays (rounded up to a
/// square) per hemisphere: the rays land on q3map2's bounce lights ([`pieces`]).
/// `fast`: the compile's `-fast`, under which a piece reaches no row beyond its
/// envelope.
/// The rays are walked on `backend` where it has a kernel for first hits
/// ([`Backend::first_hits`]), else row by row on the CPU (the reference).
pub fn operator(scene: &Scene, rows: &Rows, bvh: &Bvh, rays_per_row: usize, fast: bool, backend: &mut dyn Backend) -> Result<(Transport, GatherStats)> {
    let pieces = pieces::Pieces::build(scene, rows, fast);
    let (gather, mut st) = trace(scene, rows, bvh, rays_per_row, backend, |i, tri, p, add| {
        match pieces.locate(tri, p) {
            Some(w) if (rows.pos[i] - pieces.origin[w as usize]).length() < pieces.envelope[w as usize] => {
                add(w, 1.0);
                true
            }
            _ => false,
        }
    })?;
    st.pieces = pieces.len();
    Ok((Transport { gather, emit: Some(pieces.emit) }, st))
}

/// The rays of the bounce's transport: `rays_per_row` cosine-weighted rays (rounded up
/// to a square) from each row, per hemisphere of a two-sided row; a ray from row `i`
/// that meets the front of a surface (either face of a two-sided one) at point `p` of
/// triangle `tri` is handed to `land`, which adds its sources with their weights
/// (each scaled by `1 / rays`) and says whether it found any.
/// The walks are `backend`'s where it has a kernel for first hits
/// ([`crate::backend::gather_rows`]): the same sums as the CPU's walks where the walks
/// agree.
fn trace<L>(scene: &Scene, rows: &Rows, bvh: &Bvh, rays_per_row: usize, backend: &mut dyn Backend, land: L) -> Result<(Sparse, GatherStats)>
where
    L: Fn(usize, usize, Vec3, &mut dyn FnMut(u32, f32)) -> bool + Sync,
{
    let s = (rays_per_row.max(1) as f64).sqrt().ceil() as usize;
    let m = s * s;
    let (lo, hi) = scene.mesh.bounds();
    let reach = 2.0 * (hi - lo).length().max(1e-3);
    let n = rows.len();
    let max_rays = if rows.two_sided.iter().any(|&t| t) { 2 * m } else { m };
    let per_row = crate::backend::gather_rows(backend, bvh, n, max_rays, |i, walk| gather_row(scene, rows, i, s, &land, &mut |o, d| walk(PlaneRay::new(o, d, reach))))?;
    let mut k = Sparse::empty();
    let mut st = GatherStats { rows: n, rays_per_row: m, rays: (n * m) as u64, landed: 0, pieces: 0 };
    for (acc, landed) in per_row {
        k.push_row(acc);
        st.landed += landed;
    }
    Ok((k, st))
}

/// Row `i`'s gather: its `s x s` cosine-weighted rays per hemisphere, each walked by
/// `hit(origin, unit direction)` (the distance and the mesh's triangle of the first hit
/// within the scene's reach, [`crate::trace::tree::Tree::first_hit_from_plane`]), those
/// that meet the front of a surface landed by `land`; returns the row's sources with
/// their weights and the rays that landed.
fn gather_row<L>(scene: &Scene, rows: &Rows, i: usize, s: usize, land: &L, hit: &mut dyn FnMut(Vec3, Vec3) -> Option<(f32, u32)>) -> (Vec<(u32, f32)>, u64)
where
    L: Fn(usize, usize, Vec3, &mut dyn FnMut(u32, f32)) -> bool + Sync,
{
    let m = s * s;
    let mesh = &scene.mesh;
    let mut acc: Vec<(u32, f32)> = Vec::new();
    let mut landed = 0u64;
    // A two-sided row gathers over both hemispheres, each from its own side.
    let sides = if rows.two_sided[i] { 2 } else { 1 };
    for (side, cell) in (0..sides).flat_map(|side| (0..m).map(move |cell| (side, cell))) {
        let n = if side == 0 { rows.normal[i] } else { -rows.normal[i] };
        let o = rows.pos[i] + n * rows.sampling.ray_offset;
        let d = cosine_direction(n, i as u32, cell, s);
        // A row on another surface's plane (the edge row of a wall under a ceiling) sees
        // that surface over half its hemisphere, from distance 0.
        let Some((dist, tri)) = hit(o, d) else { continue };
        let tri = tri as usize;
        let Some(&[ia, ib, ic]) = mesh.triangles.get(tri).map(|t| t.map(|v| v as usize)).as_ref() else { continue };
        let (a, b, c) = (mesh.positions[ia], mesh.positions[ib], mesh.positions[ic]);
        let mat = &scene.materials[mesh.tri_material[tri] as usize];
        if (b - a).cross(c - a).dot(d) >= 0.0 && !mat.double_sided {
            continue; // the back of a one-sided surface (q3map2's bounce lights of a
                      // two-sided shader emit from both faces)
        }
        let p = o + d * dist;
        let mut add = |j: u32, w: f32| {
            let w = w / m as f32;
            match acc.iter_mut().find(|e| e.0 == j) {
                Some(e) => e.1 += w,
                None => acc.push((j, w)),
            }
        };
        landed += land(i, tri, p, &mut add) as u64;
    }
    (acc, landed)
}
