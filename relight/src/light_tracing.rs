//! The thesis's forward model, as a baseline: light tracing from every point light, the
//! hits splatted onto the vertices of the hit triangle (chapters 3.2 and 5 of the thesis).
//! CPU reference here; `shaders/light_tracing.wgsl` runs the same sample on wgpu
//! ([`crate::gpu::TracingGpu`]).
//!
//! A point light `j` of radiant intensity `I_jc` [W/sr] sends `N` rays in directions
//! uniform on the sphere, each carrying the flux `Phi_jc / N = 4 pi I_jc / N` [W]. Where a
//! ray meets the front of a triangle at `x` with barycentric weights `b_k` it deposits
//! `b_k Phi / N` on vertex `k`; the vertex's irradiance is its deposits over its vertex
//! area `A_k = 1/3 sum_{triangles at k} A_t` [m^2]:
//!
//! ```text
//! E_kc = 1/A_k sum_{rays} b_k(x) W_c,       E[E_kc] = 1/A_k int E_c(x) phi_k(x) dx
//! ```
//!
//! the mass-lumped L2 projection of the irradiance (thesis eq. 3.6), which is what the
//! vertex target holds of the data. Bounces: the ray leaves the hit point in a
//! cosine-weighted direction with `W_c *= albedo_c(x)` (the vertices' linear albedo,
//! interpolated), deposits again where it lands, `bounces` times at most: the expected
//! deposit of each pass is a Lambertian bounce's irradiance. A ray that meets the back of
//! a face, or a face whose vertices carry no row, stops there.
//!
//! Every evaluation draws a fresh sample (as the thesis's renderer did): sample `s` of
//! light `j`, ray `r` uses the numbers `rand(seed, s, j, r, dim)` of a counter-based
//! hash, the same on both backends. The gradient is that of the last evaluation's own
//! estimate (the same rays):
//!
//! - intensity and colour: exact (every deposit is linear in `I_jc`);
//! - position: pathwise, the direct hits moving with the light along their fixed
//!   directions (`dx/dp = Id - d n^T / (n . d)`, `n` the hit face's normal), through the
//!   barycentric weights' gradients. The moves of bounced paths and the jumps where a ray
//!   changes face across an unwelded edge or a silhouette are left out: the estimate is
//!   a step function there, as the thesis's renderer's was.
//!
//! Deposits are summed in 64-bit fixed point (a unit of `2^-24` of the largest flux a ray
//! carries), so the sum is the same whatever the order the threads add in.

use std::f32::consts::PI;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::Vec3;
use rayon::prelude::*;

use crate::backend::Backend;
use crate::error::{Error, Result};
use crate::model::lights::{Light, LightGrad};
use crate::rows::Rows;
use crate::scene::Mesh;
use crate::trace::bvh::Bvh;
use crate::trace::visibility::Visibility;

/// The thesis's rays per light and evaluation.
pub const THESIS_RAYS: usize = 100_000;
/// Fixed-point resolution: the largest flux one ray carries is this many units.
pub const FIXED_ONE: f64 = (1u64 << 24) as f64;
/// Rays per parallel work item.
const CHUNK: usize = 4096;

/// A uniform integer from a 32-bit state (PCG's output permutation, as in Jarzynski and
/// Olano's "Hash functions for GPU rendering"); `shaders/light_tracing.wgsl` has the same.
#[inline]
pub fn pcg(v: u32) -> u32 {
    let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// A uniform number in [0, 1) for ray `ray` of light `light` in sample `sample`,
/// dimension `dim` (2 per bounce).
#[inline]
pub fn rand(seed: u32, sample: u32, light: u32, ray: u32, dim: u32) -> f32 {
    let h = pcg(seed ^ pcg(sample ^ pcg(light ^ pcg(ray ^ pcg(dim)))));
    (h >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// A direction uniform on the unit sphere from two uniform numbers.
#[inline]
pub fn sphere(u1: f32, u2: f32) -> Vec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u2;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Two unit tangents completing the unit normal `n` to an orthonormal basis (Duff et
/// al. 2017; the WGSL has the same arithmetic).
#[inline]
pub fn tangents(n: Vec3) -> (Vec3, Vec3) {
    let sign = if n.z >= 0.0 { 1.0f32 } else { -1.0 };
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x), Vec3::new(b, sign + n.y * n.y * a, -n.y))
}

/// A cosine-weighted direction around the unit normal `n` (Malley's method).
#[inline]
pub fn cosine(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let (t1, t2) = tangents(n);
    let r = u1.sqrt();
    let phi = 2.0 * PI * u2;
    let (x, y) = (r * phi.cos(), r * phi.sin());
    (t1 * x + t2 * y + n * (1.0 - u1).max(0.0).sqrt()).normalize()
}

/// What the splat needs of the mesh: per triangle its vertices, its unit normal (turned
/// to the side its vertex normals face) and its barycentric gradients; per vertex its row,
/// `1 / A_k` and its albedo.
#[derive(Debug, Clone)]
pub struct Splat {
    pub triangles: Vec<[u32; 3]>,
    pub positions: Vec<Vec3>,
    /// Unit normal of each triangle's front (zero for a degenerate triangle).
    pub normal: Vec<Vec3>,
    /// Gradients (1/m) of the barycentric weights of the 2nd and 3rd vertex.
    pub grad_uv: Vec<[Vec3; 2]>,
    /// Row of each vertex (`u32::MAX`: none, its deposits are not kept).
    pub row: Vec<u32>,
    /// `1 / A_k`, 1/m^2 (0 where the vertex has no area).
    pub inv_area: Vec<f64>,
    /// Linear albedo a bounce leaves with (0 where the vertex has no row).
    pub albedo: Vec<[f32; 3]>,
    /// Bounce rays start this far off the surface, m.
    pub offset: f32,
}

impl Splat {
    /// From the mesh and the rows (vertex rows; luxel rows have no vertex to splat on).
    pub fn new(mesh: &Mesh, rows: &Rows) -> Result<Splat> {
        let nv = mesh.positions.len();
        let mut row = vec![u32::MAX; nv];
        for (i, &v) in rows.vertex.iter().enumerate() {
            if (v as usize) < nv {
                row[v as usize] = i as u32;
            }
        }
        if row.iter().all(|&r| r == u32::MAX) {
            return Err(Error::Usage("the light-tracing estimator splats onto mesh vertices: it needs the vertex target (--target vertex)".into()));
        }
        let mut area = vec![0.0f64; nv];
        let mut normal = Vec::with_capacity(mesh.triangles.len());
        let mut grad_uv = Vec::with_capacity(mesh.triangles.len());
        for tri in &mesh.triangles {
            let [a, b, c] = tri.map(|i| mesh.positions[i as usize]);
            let (e1, e2) = (b - a, c - a);
            let nn = e1.cross(e2);
            let len2 = nn.length_squared();
            let a_t = 0.5 * (len2 as f64).sqrt();
            for &v in tri {
                area[v as usize] += a_t / 3.0;
            }
            if !(len2 > 0.0 && len2.is_finite()) {
                normal.push(Vec3::ZERO);
                grad_uv.push([Vec3::ZERO; 2]);
                continue;
            }
            // u = ((x - a) x e2) . N / |N|^2, v = (e1 x (x - a)) . N / |N|^2.
            grad_uv.push([e2.cross(nn) / len2, nn.cross(e1) / len2]);
            let unit = nn / len2.sqrt();
            let vn = tri.iter().map(|&i| mesh.normals.get(i as usize).copied().unwrap_or(Vec3::ZERO)).sum::<Vec3>();
            normal.push(if unit.dot(vn) < 0.0 { -unit } else { unit });
        }
        let inv_area = area.iter().map(|&a| if a > 0.0 { 1.0 / a } else { 0.0 }).collect();
        let albedo = row.iter().map(|&r| if r == u32::MAX { [0.0; 3] } else { rows.albedo[r as usize] }).collect();
        Ok(Splat { triangles: mesh.triangles.clone(), positions: mesh.positions.clone(), normal, grad_uv, row, inv_area, albedo, offset: rows.sampling.ray_offset.max(1e-4) })
    }

    /// Barycentric weights of `x` in triangle `t`.
    #[inline]
    pub fn weights(&self, t: usize, x: Vec3) -> [f32; 3] {
        let a = self.positions[self.triangles[t][0] as usize];
        let [gu, gv] = self.grad_uv[t];
        let (u, v) = (gu.dot(x - a), gv.dot(x - a));
        let (u, v) = (u.clamp(0.0, 1.0), v.clamp(0.0, 1.0));
        [(1.0 - u - v).max(0.0), u, v]
    }
}

/// One deposit: where it landed and what it carries.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    /// Mesh triangle.
    pub tri: u32,
    pub weights: [f32; 3],
    /// Flux per channel, W (for the gradient: per W/sr of the light's intensity).
    pub flux: [f32; 3],
    /// The ray's direction and pass (0: direct).
    pub dir: Vec3,
    pub pass: u32,
}

/// Traces ray `r` of light `j` (sample `s`) and calls `hit` at every deposit. `flux`: the
/// ray's starting flux per channel. Returns the segments traced.
#[allow(clippy::too_many_arguments)]
pub fn trace_ray(sp: &Splat, bvh: &Bvh, seed: u32, s: u32, j: u32, r: u32, pos: Vec3, flux: [f32; 3], bounces: usize, mut hit: impl FnMut(Hit)) -> u64 {
    let mut o = pos;
    let mut d = sphere(rand(seed, s, j, r, 0), rand(seed, s, j, r, 1));
    let mut w = flux;
    let reach = bvh.reach().max(1.0);
    for pass in 0..=bounces as u32 {
        let segments = pass as u64 + 1;
        let Some((t, tri)) = bvh.first_hit(o, d * reach, 1.0) else { return segments };
        let n = sp.normal[tri as usize];
        if !(n.dot(d) < 0.0) {
            return segments;
        }
        let x = o + d * (t * reach);
        let weights = sp.weights(tri as usize, x);
        if sp.triangles[tri as usize].iter().all(|&v| sp.row[v as usize] == u32::MAX) {
            return segments;
        }
        hit(Hit { tri, weights, flux: w, dir: d, pass });
        if pass as usize == bounces {
            return segments;
        }
        let vs = sp.triangles[tri as usize];
        for c in 0..3 {
            w[c] *= (0..3).map(|k| weights[k] * sp.albedo[vs[k] as usize][c]).sum::<f32>();
        }
        if w == [0.0; 3] {
            return segments;
        }
        o = x + n * sp.offset;
        d = cosine(n, rand(seed, s, j, r, 2 + 2 * pass), rand(seed, s, j, r, 3 + 2 * pass));
    }
    bounces as u64 + 1
}

/// The estimator: the thesis's forward model of the point lights, a [`Backend`].
pub struct Tracing<'a> {
    pub splat: Splat,
    pub bvh: &'a Bvh,
    pub rays_per_light: usize,
    pub bounces: usize,
    pub seed: u32,
    /// The sample the last irradiance drew (the gradient uses it again).
    sample: u32,
    /// Light paths traced so far (rays leaving a light, their bounces not counted).
    pub rays: u64,
    n_rows: usize,
}

impl<'a> Tracing<'a> {
    pub fn new(mesh: &Mesh, rows: &Rows, bvh: &'a Bvh, rays_per_light: usize, bounces: usize, seed: u64) -> Result<Tracing<'a>> {
        Ok(Tracing { splat: Splat::new(mesh, rows)?, bvh, rays_per_light: rays_per_light.max(1), bounces, seed: (seed ^ (seed >> 32)) as u32, sample: u32::MAX, rays: 0, n_rows: rows.len() })
    }

    /// The sample an irradiance evaluation uses: a new one each time.
    fn next_sample(&mut self) -> u32 {
        self.sample = self.sample.wrapping_add(1);
        self.sample
    }
}

pub fn check_points(lights: &[Light]) -> Result<()> {
    if lights.iter().any(|l| l.spot.is_some()) {
        return Err(Error::Usage("the light-tracing estimator (the thesis's model) has point lights only; this model has a spot".into()));
    }
    Ok(())
}

/// The fixed-point unit (W per count) for these lights: the largest flux a ray carries
/// over [`FIXED_ONE`].
pub fn fixed_unit(lights: &[Light], rays_per_light: usize) -> f64 {
    let m = lights.iter().map(|l| l.max_rgb().max(0.0) as f64).fold(0.0, f64::max);
    (4.0 * std::f64::consts::PI * m / rays_per_light as f64 / FIXED_ONE).max(f64::MIN_POSITIVE)
}

/// The estimate of sample `s`: irradiance per row, W/m^2 (CPU reference).
#[allow(clippy::too_many_arguments)]
pub fn irradiance_cpu(sp: &Splat, bvh: &Bvh, lights: &[Light], rays_per_light: usize, bounces: usize, seed: u32, s: u32, n_rows: usize) -> (Vec<[f32; 3]>, u64) {
    let unit = fixed_unit(lights, rays_per_light);
    let acc: Vec<AtomicU64> = (0..3 * n_rows).map(|_| AtomicU64::new(0)).collect();
    let chunks = rays_per_light.div_ceil(CHUNK);
    let rays: u64 = (0..lights.len() * chunks)
        .into_par_iter()
        .map(|job| {
            let (j, ch) = (job / chunks, job % chunks);
            let l = &lights[j];
            let flux = l.rgb.map(|c| 4.0 * PI * c.max(0.0) / rays_per_light as f32);
            let mut n = 0u64;
            for r in ch * CHUNK..((ch + 1) * CHUNK).min(rays_per_light) {
                n += trace_ray(sp, bvh, seed, s, j as u32, r as u32, l.pos, flux, bounces, |h| deposit(sp, &acc, unit, &h));
            }
            n
        })
        .sum();
    // Flux to irradiance: each row's deposits over its vertex area.
    let mut out = vec![[0.0f32; 3]; n_rows];
    for (v, &r) in sp.row.iter().enumerate() {
        if r != u32::MAX {
            let r = r as usize;
            out[r] = [0, 1, 2].map(|c| (acc[3 * r + c].load(Ordering::Relaxed) as f64 * unit * sp.inv_area[v]) as f32);
        }
    }
    (out, rays)
}

#[inline]
fn deposit(sp: &Splat, acc: &[AtomicU64], unit: f64, h: &Hit) {
    for (k, &v) in sp.triangles[h.tri as usize].iter().enumerate() {
        let r = sp.row[v as usize];
        if r == u32::MAX || h.weights[k] <= 0.0 {
            continue;
        }
        for c in 0..3 {
            let q = (h.flux[c] as f64 * h.weights[k] as f64 / unit).round();
            if q > 0.0 {
                acc[3 * r as usize + c].fetch_add(q as u64, Ordering::Relaxed);
            }
        }
    }
}

/// The gradient of sample `s`'s objective for `rho_ic = dF/dE_ic` (CPU reference).
#[allow(clippy::too_many_arguments)]
pub fn gradient_cpu(sp: &Splat, bvh: &Bvh, lights: &[Light], rho: &[[f32; 3]], rays_per_light: usize, bounces: usize, seed: u32, s: u32) -> Vec<LightGrad> {
    let chunks = rays_per_light.div_ceil(CHUNK);
    let parts: Vec<LightGrad> = (0..lights.len() * chunks)
        .into_par_iter()
        .map(|job| {
            let (j, ch) = (job / chunks, job % chunks);
            let l = &lights[j];
            // Per unit intensity: the deposits' derivative with respect to I_c.
            let per_i = 4.0 * PI / rays_per_light as f32;
            let mut g = LightGrad::default();
            for r in ch * CHUNK..((ch + 1) * CHUNK).min(rays_per_light) {
                trace_ray(sp, bvh, seed, s, j as u32, r as u32, l.pos, [per_i; 3], bounces, |h| {
                    let vs = sp.triangles[h.tri as usize];
                    // s_k = sum_c rho_kc W_c / A_k (W: the deposit's flux at the light's intensity).
                    let mut gx = Vec3::ZERO;
                    for k in 0..3 {
                        let row = sp.row[vs[k] as usize];
                        if row == u32::MAX {
                            continue;
                        }
                        let ia = sp.inv_area[vs[k] as usize];
                        let rr = rho[row as usize];
                        let mut sk = 0.0f64;
                        for c in 0..3 {
                            let dep = h.flux[c] as f64 * ia;
                            g.rgb[c] += rr[c] as f64 * dep * h.weights[k] as f64;
                            sk += rr[c] as f64 * dep * l.rgb[c] as f64;
                        }
                        if h.pass == 0 && k > 0 {
                            gx += sp.grad_uv[h.tri as usize][k - 1] * sk as f32;
                        } else if h.pass == 0 {
                            gx -= (sp.grad_uv[h.tri as usize][0] + sp.grad_uv[h.tri as usize][1]) * sk as f32;
                        }
                    }
                    if h.pass == 0 {
                        // dF/dp = (Id - n d^T / (n . d)) g ... transposed: g - n (d . g) / (n . d).
                        let n = sp.normal[h.tri as usize];
                        let nd = n.dot(h.dir);
                        if nd.abs() > 1e-6 {
                            let dp = gx - n * (h.dir.dot(gx) / nd);
                            for q in 0..3 {
                                g.pos[q] += dp[q] as f64;
                            }
                        }
                    }
                });
            }
            g
        })
        .collect();
    let mut out = vec![LightGrad::default(); lights.len()];
    for (job, g) in parts.iter().enumerate() {
        out[job / chunks].add(g);
    }
    out
}

impl Backend for Tracing<'_> {
    fn name(&self) -> String {
        format!("cpu ({} threads), light tracing {} rays/light, {} bounces", rayon::current_num_threads(), self.rays_per_light, self.bounces)
    }
    /// The estimator has no shadow-ray cache: every bit clear.
    fn trace(&mut self, lights: &[(Vec3, f32)]) -> Result<Vec<Vec<u32>>> {
        Ok(lights.iter().map(|_| vec![0u32; self.n_rows.div_ceil(32)]).collect())
    }
    fn irradiance(&mut self, _vis: &Visibility, lights: &[Light]) -> Result<Vec<[f32; 3]>> {
        check_points(lights)?;
        let s = self.next_sample();
        let (e, _segments) = irradiance_cpu(&self.splat, self.bvh, lights, self.rays_per_light, self.bounces, self.seed, s, self.n_rows);
        self.rays += (lights.len() * self.rays_per_light) as u64;
        Ok(e)
    }
    fn gradient(&mut self, _vis: &Visibility, lights: &[Light], rho: &[[f32; 3]]) -> Result<Vec<LightGrad>> {
        check_points(lights)?;
        Ok(gradient_cpu(&self.splat, self.bvh, lights, rho, self.rays_per_light, self.bounces, self.seed, self.sample))
    }
    fn rays_traced(&self) -> Option<u64> {
        Some(self.rays)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::model::lights::g_at;
    use crate::rows::Sampling;
    use crate::scene::Mesh;
    use crate::testutil::room;
    use glam::Vec2;

    /// The mass-lumped projection of our deterministic model's irradiance (a light in a
    /// convex room: nothing occludes), by a dense quadrature of every triangle.
    pub(crate) fn projected_reference(mesh: &Mesh, rows: &Rows, l: &Light) -> Vec<[f64; 3]> {
        let s = Sampling::plain(10.0);
        let m = 24usize;
        let nv = mesh.positions.len();
        let mut num = vec![[0.0f64; 3]; nv];
        let mut area = vec![0.0f64; nv];
        for tri in &mesh.triangles {
            let [a, b, c] = tri.map(|i| mesh.positions[i as usize]);
            let at = 0.5 * (b - a).cross(c - a).length() as f64;
            let n = mesh.normals[tri[0] as usize];
            let mut pts = 0usize;
            let mut acc = [[0.0f64; 3]; 3];
            // Barycentric lattice midpoints: m^2 equal sub-triangles' centroids.
            for i in 0..m {
                for k in 0..m - i {
                    for (du, dv) in [(1.0 / 3.0, 1.0 / 3.0), (2.0 / 3.0, 2.0 / 3.0)] {
                        if (du > 0.5) && i + k + 1 >= m {
                            continue;
                        }
                        let (u, v) = ((i as f64 + du) / m as f64, (k as f64 + dv) / m as f64);
                        let w = [1.0 - u - v, u, v];
                        let x = a + (b - a) * u as f32 + (c - a) * v as f32;
                        let g = g_at(x, n, l, &s) as f64;
                        for q in 0..3 {
                            for ch in 0..3 {
                                acc[q][ch] += w[q] * g * l.rgb[ch] as f64;
                            }
                        }
                        pts += 1;
                    }
                }
            }
            for q in 0..3 {
                let v = tri[q] as usize;
                area[v] += at / 3.0;
                for ch in 0..3 {
                    num[v][ch] += acc[q][ch] * at / pts as f64;
                }
            }
        }
        rows.vertex.iter().map(|&v| num[v as usize].map(|x| x / area[v as usize])).collect()
    }

    /// The light of [`check_expectation`].
    pub(crate) const EXPECTATION_LIGHT: Light = Light { pos: Vec3::new(1.3, 1.7, 1.1), rgb: [2.0, 1.0, 0.5], spot: None };

    /// Asserts that `k` samples of [`EXPECTATION_LIGHT`]'s irradiance on the rows of
    /// `room(4)` (`sample(s)`: sample `s`) average to the projected deterministic model,
    /// every vertex and channel within its standard error.
    pub(crate) fn check_expectation(k: usize, mut sample: impl FnMut(u32) -> Vec<[f32; 3]>) {
        let (mesh, rows) = room(4);
        let reference = projected_reference(&mesh, &rows, &EXPECTATION_LIGHT);
        let samples: Vec<Vec<[f32; 3]>> = (0..k as u32).map(&mut sample).collect();
        let (mut z2, mut zmax, mut count) = (0.0f64, 0.0f64, 0usize);
        for i in 0..rows.len() {
            for c in 0..3 {
                let xs: Vec<f64> = samples.iter().map(|e| e[i][c] as f64).collect();
                let mean = xs.iter().sum::<f64>() / k as f64;
                let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (k - 1) as f64;
                let se = (var / k as f64).sqrt();
                assert!(se > 0.0 && mean.is_finite(), "row {i}: no hits");
                let z = (mean - reference[i][c]) / se;
                z2 += z * z;
                zmax = zmax.max(z.abs());
                count += 1;
            }
        }
        let mean_z2 = z2 / count as f64;
        assert!(zmax < 5.5 && (0.5..1.6).contains(&mean_z2), "max |z| {zmax:.2}, mean z^2 {mean_z2:.3} over {count}");
    }

    /// The estimator's expected value is our deterministic model's irradiance projected
    /// onto the vertices (thesis eq. 3.6): 16 independent samples of 40,000 rays.
    #[test]
    fn expectation_is_the_projected_deterministic_model() {
        let (mesh, rows) = room(4);
        let bvh = Bvh::build(&mesh);
        let sp = Splat::new(&mesh, &rows).unwrap();
        check_expectation(16, |s| irradiance_cpu(&sp, &bvh, &[EXPECTATION_LIGHT], 40_000, 0, 7, s, rows.len()).0);
    }

    /// In a closed room of uniform albedo every ray ends on a front face: the deposits of
    /// `b` bounces add up to the light's flux times `1 + rho + ... + rho^b`.
    #[test]
    fn bounces_conserve_energy_in_a_closed_room() {
        let (mesh, mut rows) = room(3);
        let rho = [0.5f32, 0.25, 0.8];
        rows.albedo.iter_mut().for_each(|a| *a = rho);
        let bvh = Bvh::build(&mesh);
        let sp = Splat::new(&mesh, &rows).unwrap();
        let l = Light::point(Vec3::new(2.5, 1.2, 0.7), [1.0, 2.0, 3.0]);
        let n = 20_000;
        for bounces in [0usize, 1, 3] {
            let (e, rays) = irradiance_cpu(&sp, &bvh, &[l], n, bounces, 3, 0, rows.len());
            assert_eq!(rays, (n * (bounces + 1)) as u64);
            for c in 0..3 {
                let total: f64 = rows.vertex.iter().enumerate().map(|(i, &v)| e[i][c] as f64 / sp.inv_area[v as usize]).sum();
                let want = 4.0 * std::f64::consts::PI * l.rgb[c] as f64 * (0..=bounces).map(|p| (rho[c] as f64).powi(p as i32)).sum::<f64>();
                assert!(((total - want) / want).abs() < 1e-4, "bounces {bounces}, channel {c}: {total} vs {want}");
            }
        }
    }

    /// A welded floor lit from above: the gradient of one sample's objective `sum rho E`
    /// against central differences of the same sample (its rays fixed), `rho` zero on the
    /// border where rays fall off the edge.
    #[test]
    fn gradient_is_the_samples_own_derivative() {
        let n = 12usize;
        let size = 6.0f32;
        let mut mesh = Mesh::default();
        for i in 0..=n {
            for k in 0..=n {
                mesh.positions.push(Vec3::new(size * i as f32 / n as f32, 0.0, size * k as f32 / n as f32));
                mesh.normals.push(Vec3::Y);
                mesh.uv0.push(Vec2::ZERO);
                mesh.uv1.push(Vec2::ZERO);
                mesh.colors.push([1.0; 3]);
                mesh.v_material.push(0);
            }
        }
        let id = |i: usize, k: usize| (i * (n + 1) + k) as u32;
        for i in 0..n {
            for k in 0..n {
                mesh.triangles.push([id(i, k), id(i, k + 1), id(i + 1, k + 1)]);
                mesh.triangles.push([id(i, k), id(i + 1, k + 1), id(i + 1, k)]);
                mesh.tri_material.extend([0, 0]);
                mesh.tri_source.extend([0, 0]);
            }
        }
        mesh.reweld();
        let mut rows = Rows::new(Sampling::plain(10.0));
        for v in 0..mesh.positions.len() {
            rows.push(crate::rows::Row {
                vertex: v as u32,
                material: 0,
                texel: [u32::MAX; 3],
                pos: mesh.positions[v],
                normal: Vec3::Y,
                albedo: [0.5; 3],
                lo: [0.1; 3],
                hi: [0.1; 3],
                weight: [1.0; 3],
                lower: [0.0; 3],
                area: 1.0,
                solid_ahead: crate::rows::SolidAhead::NONE,
                two_sided: false,
            });
        }
        rows.finish();
        let bvh = Bvh::build(&mesh);
        let sp = Splat::new(&mesh, &rows).unwrap();
        let rho: Vec<[f32; 3]> = (0..rows.len())
            .map(|v| {
                let (i, k) = (v / (n + 1), v % (n + 1));
                if i == 0 || k == 0 || i == n || k == n {
                    [0.0; 3]
                } else {
                    let p = mesh.positions[v];
                    [0.3 + 0.1 * p.x, 0.2 * p.z - 0.4, 0.5]
                }
            })
            .collect();
        let rays = 20_000;
        let obj = |l: Light| -> f64 {
            let (e, _) = irradiance_cpu(&sp, &bvh, &[l], rays, 0, 11, 5, rows.len());
            e.iter().zip(&rho).map(|(e, r)| (0..3).map(|c| e[c] as f64 * r[c] as f64).sum::<f64>()).sum()
        };
        let l = Light::point(Vec3::new(2.7, 1.4, 3.2), [1.5, 0.7, 1.1]);
        let g = gradient_cpu(&sp, &bvh, &[l], &rho, rays, 0, 11, 5)[0];
        let h = 2e-3f32;
        for q in 0..3 {
            let mut dp = Vec3::ZERO;
            dp[q] = h;
            let fd = (obj(Light { pos: l.pos + dp, ..l }) - obj(Light { pos: l.pos - dp, ..l })) / (2.0 * h as f64);
            let scale = g.pos.iter().map(|x| x.abs()).fold(0.0, f64::max);
            assert!((fd - g.pos[q]).abs() < 0.02 * scale, "d/dp{q}: finite differences {fd}, gradient {}", g.pos[q]);
        }
        let f0 = obj(l);
        let lin: f64 = (0..3).map(|c| g.rgb[c] * l.rgb[c] as f64).sum();
        assert!(((lin - f0) / f0).abs() < 1e-4, "the objective is linear in the intensities: {lin} vs {f0}");
    }
}
