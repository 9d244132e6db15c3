//! Bounced light: the light of the model's own emitters, reflected by the scene, as a
//! renderer with global illumination (Cycles) computes it from the written scene.
//!
//! A Lambertian row `j` lit by `E_j` sends radiance `albedo_j E_j / pi`; the irradiance
//! it brings to row `i` over the cosine-weighted hemisphere is estimated with `M` rays:
//!
//! ```text
//! E_bounce_i = pi / M sum_m L(hit_im) = sum_j K_ij albedo_j E_j,   K_ij = (rays from i landing on j) / M
//! ```
//!
//! The operator `K` is traced once (the geometry does not change during a fit). A ray
//! lands on the row that represents the hit point: the luxel row of the lightmap texel
//! under it (or the nearest row of the 3x3 texels around, on the same material), or the
//! vertex rows of a vertex-lit triangle by barycentric weight; rays that escape, hit the
//! back of a one-sided surface or a surface without rows bring nothing. A two-sided row
//! (a `cull none` surface, [`Rows::facing`]) gathers over both of its hemispheres, `M`
//! rays each, and the back of a two-sided surface sends light as its front does (q3map2's
//! bounce lights of such a shader are two-sided).
//!
//! q3map2 (`-bounce N`) re-emits each pass's light `N` times as area lights whose colour
//! is the texture's raw byte (its sRGB encoding, read as linear) times the luxel, with a
//! fixed strength (`RADIOSITY_VALUE 500 x 0.375 x formFactorValueScale 3 x -bouncescale
//! 0.25 / 255`): a physical bounce with the reflectance
//!
//! ```text
//! rho_q3 = 0.5515 srgb(albedo)           ([`reflectance`])
//! ```
//!
//! about 1.3 times a mid-grey texture's linear albedo. The model bounces with `rho_q3`,
//! scaled per channel by a fitted `k_c` in (0, [`MAX_SCALE`]] (1: q3map2's default
//! `-bouncescale`), and applies the compile's filter and dirt to every pass
//! ([`super::Model`]). Cycles bounces with the linear albedo: the report gives the ratio
//! ([`physical_ratio`]), what the render will lack in indirect light.
//!
//! The directions are stratified (`s x s` cells of the unit square, Malley's method)
//! with a jitter hashed from the row and the cell: deterministic.

use std::collections::HashMap;

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::compile::Sparse;
use crate::rows::Rows;
use crate::scene::{Lighting, Scene};
use crate::trace::bvh::Bvh;

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

/// Barycentric coordinates of `p` (on or near the triangle's plane), clamped into it.
pub fn barycentric(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> [f32; 3] {
    let (v0, v1, v2) = (b - a, c - a, p - a);
    let (d00, d01, d11) = (v0.dot(v0), v0.dot(v1), v1.dot(v1));
    let (d20, d21) = (v2.dot(v0), v2.dot(v1));
    let den = d00 * d11 - d01 * d01;
    if !(den.abs() > 0.0) {
        return [1.0 / 3.0; 3];
    }
    let v = ((d11 * d20 - d01 * d21) / den).clamp(0.0, 1.0);
    let w = ((d00 * d21 - d01 * d20) / den).clamp(0.0, 1.0 - v);
    [1.0 - v - w, v, w]
}

/// q3map2's bounce strength per unit of raw texture colour (see the module docs):
/// `500 x 0.375 x 3 x 0.25 / 255`.
pub const Q3MAP2_BOUNCE: f32 = 500.0 * 0.375 * 3.0 * 0.25 / 255.0;

/// Largest fitted scale of q3map2's bounce (`-bouncescale 1`, four times the default).
pub const MAX_SCALE: f32 = 4.0;

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
    /// Rays that landed on a row.
    pub landed: u64,
}

/// Traces the transport operator `K` for `rows` with `rays_per_row` rays (rounded up to a
/// square).
pub fn operator(scene: &Scene, rows: &Rows, bvh: &Bvh, rays_per_row: usize) -> (Sparse, GatherStats) {
    let s = (rays_per_row.max(1) as f64).sqrt().ceil() as usize;
    let m = s * s;
    let (lo, hi) = scene.mesh.bounds();
    let reach = 2.0 * (hi - lo).length().max(1e-3);
    let luxel: HashMap<[u32; 3], u32> = (0..rows.len()).filter(|&i| rows.texel[i][0] != u32::MAX).map(|i| (rows.texel[i], i as u32)).collect();
    let vertex_row: HashMap<u32, u32> = (0..rows.len()).filter(|&i| rows.vertex[i] != u32::MAX).map(|i| (rows.vertex[i], i as u32)).collect();
    let mesh = &scene.mesh;
    let per_row: Vec<(Vec<(u32, f32)>, u64)> = (0..rows.len())
        .into_par_iter()
        .map(|i| {
            let mut acc: Vec<(u32, f32)> = Vec::new();
            let mut landed = 0u64;
            let add = |j: u32, w: f32, acc: &mut Vec<(u32, f32)>| match acc.iter_mut().find(|e| e.0 == j) {
                Some(e) => e.1 += w,
                None => acc.push((j, w)),
            };
            // A two-sided row gathers over both hemispheres, each from its own side.
            let sides = if rows.two_sided[i] { 2 } else { 1 };
            for (side, cell) in (0..sides).flat_map(|side| (0..m).map(move |cell| (side, cell))) {
                let n = if side == 0 { rows.normal[i] } else { -rows.normal[i] };
                let o = rows.pos[i] + n * rows.sampling.ray_offset;
                let d = cosine_direction(n, i as u32, cell, s);
                // A row on another surface's plane (the edge row of a wall under a
                // ceiling) sees that surface over half its hemisphere, from distance 0.
                let Some((dist, tri)) = bvh.first_hit_from_plane(o, d, reach) else { continue };
                let tri = tri as usize;
                let [ia, ib, ic] = mesh.triangles[tri].map(|v| v as usize);
                let (a, b, c) = (mesh.positions[ia], mesh.positions[ib], mesh.positions[ic]);
                let mat = &scene.materials[mesh.tri_material[tri] as usize];
                if (b - a).cross(c - a).dot(d) >= 0.0 && !mat.double_sided {
                    continue; // the back of a one-sided surface (q3map2's bounce lights of a
                              // two-sided shader emit from both faces)
                }
                let bc = barycentric(o + d * dist, a, b, c);
                match (mat.lighting, mat.lightmap) {
                    (Lighting::Lightmap, Some(lm)) => {
                        let uv: Vec2 = mesh.uv1[ia] * bc[0] + mesh.uv1[ib] * bc[1] + mesh.uv1[ic] * bc[2];
                        let tx = &scene.textures[lm];
                        let (fx, fy) = (uv.x * tx.width as f32, uv.y * tx.height as f32);
                        let (x, y) = (fx.floor() as i64, fy.floor() as i64);
                        let mut best: Option<(f32, u32)> = None;
                        for dy in -1..=1 {
                            for dx in -1..=1 {
                                let (nx, ny) = (x + dx, y + dy);
                                if nx < 0 || ny < 0 {
                                    continue;
                                }
                                if let Some(&j) = luxel.get(&[lm as u32, nx as u32, ny as u32]) {
                                    if rows.material[j as usize] != mesh.tri_material[tri] {
                                        continue;
                                    }
                                    let dist = (nx as f32 + 0.5 - fx).powi(2) + (ny as f32 + 0.5 - fy).powi(2);
                                    if best.is_none_or(|b| dist < b.0) {
                                        best = Some((dist, j));
                                    }
                                }
                            }
                        }
                        if let Some((_, j)) = best {
                            add(j, 1.0 / m as f32, &mut acc);
                            landed += 1;
                        }
                    }
                    (Lighting::Vertex, _) => {
                        let mut any = false;
                        for (k, v) in [ia, ib, ic].into_iter().enumerate() {
                            if let Some(&j) = vertex_row.get(&(v as u32)) {
                                add(j, bc[k] / m as f32, &mut acc);
                                any = true;
                            }
                        }
                        landed += any as u64;
                    }
                    _ => {}
                }
            }
            (acc, landed)
        })
        .collect();
    let mut k = Sparse::empty();
    let mut st = GatherStats { rows: rows.len(), rays_per_row: m, rays: (rows.len() * m) as u64, landed: 0 };
    for (acc, landed) in per_row {
        k.push_row(acc);
        st.landed += landed;
    }
    (k, st)
}
