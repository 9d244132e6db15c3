//! The radiance target per vertex: the mass-lumped L2 projection of `albedo x lightmap`
//! (thesis eq. 3.7 and Algorithm 4.1) with CONVENTIONS.md's decoding
//! `e = (byte/255)^gamma * 2^overbright`, `r = albedo_linear * e`.
//!
//! Per triangle `k` with area `A_k`, `n = m^2` quadrature points at the centroids of the
//! `m x m` equal sub-triangles (so the quadrature weight is `A_k / n` each and every
//! corner's shape function integrates to exactly `A_k / 3`); `m` follows the texel
//! footprint: about four samples per lightmap texel, more (up to 16) where the albedo
//! texture is finer. Each corner gets
//!
//! - `num_c  = sum A_k/n phi_i r_c`     over samples that are not censored (no channel of
//!   the nearest texel at 255: q3map2 scales such texels down keeping their hue),
//! - `wsum_c = sum A_k/n phi_i`         over the same samples,
//! - `lb_c   = sum A_k/n phi_i r_c`     over the censored ones (a lower bound),
//! - `alb_c  = sum A_k/n phi_i albedo_c` and `den = sum A_k/n phi_i` (= A_k/3).
//!
//! Summed over a vertex's triangles: `t_c = num_c / wsum_c`, the two-sided weight
//! `w_c = wsum_c / den` (the uncensored fraction), the lower bound `lb_c / (den - wsum_c)`
//! on the rest, and the vertex area `A_i = den`. Vertex-lit materials take the target from
//! the vertex colour (decoded like a lightmap) times the projected albedo.
//!
//! The per-triangle sums are what the GPU kernel (`shaders/target.wgsl`) computes; both
//! backends share [`gather`], which runs in f64.

use glam::Vec2;
use rayon::prelude::*;

use crate::rows::{Row, Rows, Sampling};
use crate::scene::{Lighting, Material, Mesh, Scene, Texture};
use crate::texel;

/// Floats per triangle corner in the per-triangle sums (see the module docs).
pub const CORNER_FLOATS: usize = 13;
/// Largest quadrature order per triangle edge (`m`): at most `m^2 = 1024` samples.
pub const MAX_ORDER: u32 = 32;

/// Per-vertex data the forward model and the objective need.
#[derive(Debug, Clone, Default)]
pub struct Target {
    /// Vertex-associated area `A_i`, m^2.
    pub area: Vec<f32>,
    /// Projected linear albedo.
    pub albedo: Vec<[f32; 3]>,
    /// Target radiance (same unit as the model's `albedo * E / pi`): the lower end of
    /// the data's interval ([`crate::rows`]).
    pub value: Vec<[f32; 3]>,
    /// Upper end of the interval: `value` itself for a projected lightmap (an average),
    /// the byte's upper end for a vertex colour.
    pub hi: Vec<[f32; 3]>,
    /// Two-sided weight per channel, in [0, 1].
    pub weight: Vec<[f32; 3]>,
    /// Lower bound per channel where the data was censored (weight `1 - w`).
    pub lower: Vec<[f32; 3]>,
}

impl Target {
    /// A target of `n` vertices, none of which carries data.
    pub fn empty(n: usize) -> Target {
        Target { area: vec![0.0; n], albedo: vec![[0.0; 3]; n], value: vec![[0.0; 3]; n], hi: vec![[0.0; 3]; n], weight: vec![[0.0; 3]; n], lower: vec![[0.0; 3]; n] }
    }
}

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct TargetStats {
    pub vertices: usize,
    /// Vertices with a two-sided target in at least one channel.
    pub with_target: usize,
    /// Vertices with some channel (partly) censored: treated as a lower bound there.
    pub censored: usize,
    /// Vertices without any baked lighting (weight 0).
    pub no_coverage: usize,
    pub lightmap_vertices: usize,
    pub vertex_lit_vertices: usize,
    pub samples: u64,
}

/// A lightmapped triangle's footprint below this (texels^2) holds no data: its corners
/// would all read one point of the lightmap, with the weight of the triangle's world area
/// (the luxel target refuses the same triangles, [`crate::rows::luxel`]).
pub const MIN_LIGHTMAP_TEXELS: f32 = 1e-12;

/// The lightmap footprint of triangle `t`, texels^2 (TEXCOORD_1 area times the lightmap's
/// size); `None` unless its material is lightmapped.
pub fn lightmap_texels(mesh: &Mesh, mats: &[Material], texs: &[Texture], t: usize) -> Option<f32> {
    let mat = mats.get(mesh.tri_material[t] as usize)?;
    let tex = mat.lightmap.and_then(|l| texs.get(l)).filter(|_| mat.lighting == Lighting::Lightmap)?;
    let [a, b, c] = mesh.triangles[t].map(|v| mesh.uv1[v as usize]);
    Some(0.5 * (b - a).perp_dot(c - a).abs() * tex.width as f32 * tex.height as f32)
}

/// Quadrature order of triangle `t` (see the module docs); 0 for a lightmapped triangle
/// without lightmap area (no samples: it carries no data).
pub fn order(scene: &Scene, t: usize) -> u32 {
    let mesh = &scene.mesh;
    let [a, b, c] = mesh.triangles[t].map(|i| i as usize);
    let mat = &scene.materials[mesh.tri_material[t] as usize];
    let texel_area = |uv: &[Vec2], tex: Option<usize>| -> f32 {
        let Some(tex) = tex else { return 0.0 };
        let tx = &scene.textures[tex];
        let (p, q) = (uv[b] - uv[a], uv[c] - uv[a]);
        0.5 * (p.x * q.y - p.y * q.x).abs() * tx.width as f32 * tx.height as f32
    };
    let lm = match lightmap_texels(mesh, &scene.materials, &scene.textures, t) {
        Some(lm) if !(lm > MIN_LIGHTMAP_TEXELS) => return 0,
        lm => lm.unwrap_or(0.0),
    };
    // Albedo detail adds samples, but at most 16 per triangle beyond the lightmap's need.
    let al = (texel_area(&mesh.uv0, mat.albedo) / 16.0).min(16.0);
    let want = (4.0 * lm).max(al).max(1.0);
    let m = want.sqrt().ceil();
    if m.is_finite() { (m as u32).clamp(1, MAX_ORDER) } else { MAX_ORDER }
}

/// Barycentric coordinates of sample `s` of order `m` (0 <= s < m^2): the centroids of the
/// upright sub-triangles first, then of the inverted ones, row by row.
pub fn lattice_point(m: u32, s: u32) -> [f32; 3] {
    let mf = m as f32;
    let upright = m * (m + 1) / 2;
    let (s, off) = if s < upright { (s, 1.0 / 3.0) } else { (s - upright, 2.0 / 3.0) };
    let rows = if off < 0.5 { m } else { m - 1 };
    // Row i has (rows - i) entries.
    let mut i = 0;
    let mut s = s;
    while i < rows && s >= rows - i {
        s -= rows - i;
        i += 1;
    }
    let j = s;
    let u = (i as f32 + off) / mf;
    let v = (j as f32 + off) / mf;
    [1.0 - u - v, u, v]
}

/// The per-triangle corner sums of one triangle (CPU reference of `target.wgsl`).
pub fn triangle_sums(scene: &Scene, t: usize, out: &mut [f32; 3 * CORNER_FLOATS]) -> u32 {
    out.fill(0.0);
    let mesh = &scene.mesh;
    let tri = mesh.triangles[t].map(|i| i as usize);
    let mat = &scene.materials[mesh.tri_material[t] as usize];
    let area = mesh.triangle_area(t);
    if !(area > 0.0) || !area.is_finite() {
        return 0;
    }
    let m = order(scene, t);
    if m == 0 {
        return 0;
    }
    let n = m * m;
    let wq = area / n as f32;
    let lm = if mat.lighting == Lighting::Lightmap { mat.lightmap.map(|i| &scene.textures[i]) } else { None };
    let alb_tex = mat.albedo.map(|i| &scene.textures[i]);
    let f = mat.albedo_factor;
    for s in 0..n {
        let w = lattice_point(m, s);
        let uv0 = mesh.uv0[tri[0]] * w[0] + mesh.uv0[tri[1]] * w[1] + mesh.uv0[tri[2]] * w[2];
        let uv1 = mesh.uv1[tri[0]] * w[0] + mesh.uv1[tri[1]] * w[1] + mesh.uv1[tri[2]] * w[2];
        let albedo = match alb_tex {
            Some(tx) => texel::bilinear(tx, uv0.x, uv0.y, texel::srgb_byte_to_linear),
            None => [1.0; 3],
        };
        let albedo = [albedo[0] * f[0], albedo[1] * f[1], albedo[2] * f[2]];
        let (e, cens) = match lm {
            Some(tx) => {
                let e = texel::bilinear(tx, uv1.x, uv1.y, |b| mat.decode(b as f32 / 255.0));
                // q3map2 scales an overflowing texel down keeping its hue: when one channel
                // is at 255, every channel of the texel is a lower bound.
                let near = texel::nearest(tx, uv1.x, uv1.y);
                let censored = mat.censored(&near[..3]);
                (e, [censored; 3])
            }
            None => ([0.0; 3], [false; 3]),
        };
        for k in 0..3 {
            let o = &mut out[k * CORNER_FLOATS..(k + 1) * CORNER_FLOATS];
            let phi = wq * w[k];
            for c in 0..3 {
                let r = albedo[c] * e[c];
                if cens[c] {
                    o[6 + c] += phi * r;
                } else {
                    o[c] += phi * r;
                    o[3 + c] += phi;
                }
                o[9 + c] += phi * albedo[c];
            }
            o[12] += phi;
        }
    }
    n
}

/// All per-triangle corner sums on the CPU (rayon over triangles).
pub fn all_triangle_sums_cpu(scene: &Scene) -> (Vec<f32>, u64) {
    let nt = scene.mesh.triangles.len();
    let mut sums = vec![0.0f32; nt * 3 * CORNER_FLOATS];
    let samples: u64 = sums
        .par_chunks_mut(3 * CORNER_FLOATS)
        .enumerate()
        .map(|(t, chunk)| {
            let out: &mut [f32; 3 * CORNER_FLOATS] = chunk.try_into().expect("chunk size");
            triangle_sums(scene, t, out) as u64
        })
        .sum();
    (sums, samples)
}

/// Sums the corners of each vertex (f64) and turns them into the [`Target`].
pub fn gather(scene: &Scene, sums: &[f32], samples: u64) -> (Target, TargetStats) {
    let mesh = &scene.mesh;
    let nv = mesh.positions.len();
    let mut acc = vec![[0.0f64; CORNER_FLOATS]; nv];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            let o = &sums[(t * 3 + k) * CORNER_FLOATS..(t * 3 + k + 1) * CORNER_FLOATS];
            let a = &mut acc[tri[k] as usize];
            for (x, y) in a.iter_mut().zip(o) {
                *x += *y as f64;
            }
        }
    }
    let mut tg = Target {
        area: vec![0.0; nv],
        albedo: vec![[0.0; 3]; nv],
        value: vec![[0.0; 3]; nv],
        hi: vec![[0.0; 3]; nv],
        weight: vec![[0.0; 3]; nv],
        lower: vec![[0.0; 3]; nv],
    };
    let mut st = TargetStats { vertices: nv, samples, ..Default::default() };
    for v in 0..nv {
        let a = &acc[v];
        let den = a[12];
        tg.area[v] = den as f32;
        if !(den > 0.0) {
            st.no_coverage += 1;
            continue;
        }
        let albedo = [0, 1, 2].map(|c| a[9 + c] / den);
        tg.albedo[v] = albedo.map(|x| x as f32);
        let mat = &scene.materials[mesh.v_material[v] as usize];
        let mut censored = false;
        match mat.lighting {
            Lighting::Lightmap => {
                st.lightmap_vertices += 1;
                for c in 0..3 {
                    let ws = a[3 + c];
                    if ws > 0.0 {
                        tg.value[v][c] = (a[c] / ws) as f32;
                        tg.hi[v][c] = tg.value[v][c];
                    }
                    tg.weight[v][c] = (ws / den).clamp(0.0, 1.0) as f32;
                    let rest = den - ws;
                    if rest > 1e-12 * den {
                        tg.lower[v][c] = (a[6 + c] / rest) as f32;
                        censored = true;
                    }
                }
            }
            Lighting::Vertex => {
                st.vertex_lit_vertices += 1;
                let col = mesh.colors[v];
                let clamped = mat.censored(&col.map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8));
                for c in 0..3 {
                    // The colour's byte stands for an interval, as a lightmap texel does.
                    let (lo, hi) = mat.interval((col[c].clamp(0.0, 1.0) * 255.0).round() as u8);
                    let (lo, hi) = ((albedo[c] * lo as f64) as f32, (albedo[c] * hi as f64) as f32);
                    if clamped {
                        tg.lower[v][c] = lo;
                        censored = true;
                    } else {
                        tg.value[v][c] = lo;
                        tg.hi[v][c] = hi;
                        tg.weight[v][c] = 1.0;
                    }
                }
            }
            Lighting::None => {
                st.no_coverage += 1;
                continue;
            }
        }
        if censored {
            st.censored += 1;
        }
        if tg.weight[v].iter().any(|&w| w > 0.0) {
            st.with_target += 1;
        }
    }
    (tg, st)
}

/// The whole projection on the CPU.
pub fn project_cpu(scene: &Scene) -> (Target, TargetStats) {
    let (sums, samples) = all_triangle_sums_cpu(scene);
    gather(scene, &sums, samples)
}

/// One row per mesh vertex of `scene` that carries data (the thesis's target), with
/// `sampling`.
pub fn rows(scene: &Scene, tg: &Target, sampling: Sampling) -> Rows {
    let mesh = &scene.mesh;
    let mut p = Rows::new(sampling);
    for v in 0..mesh.positions.len() {
        let has = (0..3).any(|c| tg.weight[v][c] > 0.0 || tg.lower[v][c] > 0.0);
        if has && tg.area[v] > 0.0 {
            p.push(Row {
                vertex: v as u32,
                material: mesh.v_material[v],
                texel: [u32::MAX; 3],
                pos: mesh.positions[v],
                normal: mesh.normals[v],
                albedo: tg.albedo[v],
                lo: tg.value[v],
                hi: tg.hi[v],
                weight: tg.weight[v],
                lower: tg.lower[v],
                area: tg.area[v],
                solid_ahead: crate::rows::SolidAhead::NONE,
                two_sided: scene.materials.get(mesh.v_material[v] as usize).is_some_and(|m| m.double_sided),
            });
        }
    }
    p.finish();
    p
}
