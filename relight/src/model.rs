//! The forward model, the objective and its analytic gradient (CPU reference; the WGSL
//! version is `shaders/forward.wgsl`).
//!
//! View-independent Lambertian radiance at row `i` (a vertex or a luxel), channel `c`, from
//! point lights `j` of radiant intensity `I_jc` [W/sr] at `p_j` [m], plus optional global
//! terms: a sun (irradiance `S_c` [W/m^2] at normal incidence from direction `w`, unit,
//! towards the sun; `V_i` its visibility), an ambient irradiance `a_c` and a scale `k_c`
//! of the indirect radiance `o_ic` gathered once from the data ([`crate::indirect`]):
//!
//! ```text
//! x_ic = albedo_ic / pi * (sum_j I_jc V_ij g_ij + S_c V_i max(0, n_i . w))
//!        + albedo_ic * a_c  +  k_c * o_ic
//! g_ij = max(0, n_i . d) / (|d| max(|d|^2, eps^2)),    d = p_j - x_i
//! ```
//!
//! `V_ij` is the shadow-ray visibility (cached, see [`crate::visibility`]); `eps` keeps the
//! inverse square finite when a light touches a surface. The objective is
//!
//! ```text
//! F = 1/2 sum_i A_i sum_c [ w_ic (x_ic - t_ic)^2 + (1 - w_ic) min(0, x_ic - lb_ic)^2 ]
//! ```
//!
//! (censored data is a lower bound), and the reported error is
//! `sqrt(sum A w |x - t|^2 / sum A w |t|^2)`. Gradients: with `rho_ic = dF/dx_ic`,
//! `dF/dI_jc = sum_i rho_ic albedo_ic / pi V_ij g_ij` and
//! `dF/dp_j = sum_i (sum_c rho_ic albedo_ic I_jc / pi) V_ij grad_p g_ij`, where for
//! `s = n.d > 0`, `r = |d|`: `grad g = n/r^3 - 3 s d / r^5` (or `n/(r eps^2) - s d/(r^3 eps^2)`
//! inside `eps`). Visibility is piecewise constant, so its derivative is zero almost everywhere.
//! The global terms: `dF/da_c = sum_i rho_ic albedo_ic`, `dF/dk_c = sum_i rho_ic o_ic`,
//! `dF/dS_c = sum_i rho_ic albedo_ic / pi V_i max(0, n_i . w)` and
//! `dF/dw = sum_i (sum_c rho_ic albedo_ic S_c / pi) V_i n_i` (where `n_i . w > 0`).

use std::f64::consts::PI;

use glam::Vec3;
use rayon::prelude::*;

use crate::scene::Mesh;
use crate::target::Target;
use crate::visibility::Visibility;

/// The rows of the objective: surface points that carry a target (the only ones the
/// objective sees). A row is a mesh vertex (the thesis's projection, [`crate::target`]) or
/// a lightmap texel's sample point ([`crate::luxel`]); the model treats both alike.
#[derive(Debug, Clone, Default)]
pub struct Problem {
    /// Mesh vertex of each row (`u32::MAX` for a luxel row).
    pub vertex: Vec<u32>,
    pub pos: Vec<Vec3>,
    pub normal: Vec<Vec3>,
    pub albedo: Vec<[f32; 3]>,
    pub target: Vec<[f32; 3]>,
    pub weight: Vec<[f32; 3]>,
    pub lower: Vec<[f32; 3]>,
    /// Vertex area A_i, m^2.
    pub area: Vec<f32>,
    /// Indirect radiance `o_i` per row (zero unless [`crate::indirect`] filled it in).
    pub indirect: Vec<[f32; 3]>,
    /// `eps` of the inverse square, m.
    pub eps: f32,
    /// Shadow rays start this far along the normal, m.
    pub ray_offset: f32,
    /// `sum A w |t|^2`, the error's denominator (never 0: guarded at construction).
    pub norm2: f64,
}

impl Problem {
    /// A problem without rows, with `eps` and the ray offset scaled to the scene.
    pub fn empty(scene_diagonal: f32) -> Problem {
        Problem { eps: (1e-3 * scene_diagonal).max(0.01), ray_offset: (1e-5 * scene_diagonal).max(1e-3), ..Default::default() }
    }

    /// One row per mesh vertex that carries a target.
    pub fn new(mesh: &Mesh, tg: &Target, scene_diagonal: f32) -> Problem {
        let mut p = Problem::empty(scene_diagonal);
        for v in 0..mesh.positions.len() {
            let has = (0..3).any(|c| tg.weight[v][c] > 0.0 || tg.lower[v][c] > 0.0);
            if has && tg.area[v] > 0.0 {
                p.push(v as u32, mesh.positions[v], mesh.normals[v], tg.albedo[v], tg.value[v], tg.weight[v], tg.lower[v], tg.area[v]);
            }
        }
        p.set_norm2();
        p
    }

    #[allow(clippy::too_many_arguments)]
    pub(crate) fn push(&mut self, v: u32, pos: Vec3, normal: Vec3, albedo: [f32; 3], target: [f32; 3], weight: [f32; 3], lower: [f32; 3], area: f32) {
        self.vertex.push(v);
        self.pos.push(pos);
        self.normal.push(normal);
        self.albedo.push(albedo);
        self.target.push(target);
        self.weight.push(weight);
        self.lower.push(lower);
        self.area.push(area);
        self.indirect.push([0.0; 3]);
    }

    /// Completes a problem built row by row (computes the error's denominator).
    pub(crate) fn finish(&mut self) {
        self.set_norm2();
    }

    fn set_norm2(&mut self) {
        self.norm2 = (0..self.len()).map(|i| (0..3).map(|c| self.area[i] as f64 * self.weight[i][c] as f64 * (self.target[i][c] as f64).powi(2)).sum::<f64>()).sum();
    }

    pub fn len(&self) -> usize {
        self.pos.len()
    }
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }

    /// A sub-problem of at most about `max` vertices: every `stride`-th one, starting at
    /// `seed % stride` (areas scaled so sums stay comparable).
    pub fn subsample(&self, max: usize, seed: u64) -> Problem {
        let stride = self.len().div_ceil(max.max(1)).max(1);
        if stride == 1 {
            return self.clone();
        }
        let mut p = Problem { eps: self.eps, ray_offset: self.ray_offset, ..Default::default() };
        for i in ((seed % stride as u64) as usize..self.len()).step_by(stride) {
            p.push(self.vertex[i], self.pos[i], self.normal[i], self.albedo[i], self.target[i], self.weight[i], self.lower[i], self.area[i] * stride as f32);
            *p.indirect.last_mut().expect("just pushed") = self.indirect[i];
        }
        p.set_norm2();
        p
    }
}

/// A point light: position [m] and radiant intensity per channel [W/sr].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    pub pos: Vec3,
    pub rgb: [f32; 3],
}

/// A directional light: unit direction towards it and irradiance at normal incidence per
/// channel [W/m^2].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sun {
    pub to_sun: Vec3,
    pub rgb: [f32; 3],
}

/// The model's global terms (see the module docs), held fixed by the kernels and fitted
/// like the lights' intensities.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Terms {
    /// Ambient irradiance / pi per channel, `a_c`.
    pub ambient: [f32; 3],
    /// Scale of the gathered indirect radiance per channel, `k_c`.
    pub indirect: [f32; 3],
    /// The sun, whose visibility is [`Visibility::sun`].
    pub sun: Option<Sun>,
}

impl Terms {
    /// The sun's irradiance (before `1/pi`) at row `i` per channel, and `max(0, n.w)`.
    #[inline]
    pub fn sun_at(&self, pb: &Problem, vis: &Visibility, i: usize) -> ([f32; 3], f32) {
        match self.sun {
            Some(s) if vis.sun_visible(i) => {
                let c = pb.normal[i].dot(s.to_sun).max(0.0);
                (s.rgb.map(|v| v * c), c)
            }
            _ => ([0.0; 3], 0.0),
        }
    }
}

/// Value and gradient of the objective.
#[derive(Debug, Clone, Default)]
pub struct Eval {
    /// Objective F (without penalties).
    pub f: f64,
    /// `sqrt(sum A w |x - t|^2 / sum A w |t|^2)`.
    pub rel_error: f64,
    /// Per light: dF/dp (3, per meter) then dF/dI (3, per W/sr).
    pub grad: Vec<[f64; 6]>,
    /// dF/da_c of the ambient term.
    pub grad_ambient: [f64; 3],
    /// dF/dk_c of the indirect term.
    pub grad_indirect: [f64; 3],
    /// dF/dw (3, per unit of direction) then dF/dS (3, per W/m^2) of the sun.
    pub grad_sun: [f64; 6],
}

/// `g` of the module docs and its gradient with respect to the light position.
#[inline]
pub fn geometry_term(x: Vec3, n: Vec3, p: Vec3, eps: f32) -> (f32, Vec3) {
    let d = p - x;
    let s = n.dot(d);
    let r2 = d.length_squared();
    if !(s > 0.0) || !(r2 > 0.0) {
        return (0.0, Vec3::ZERO);
    }
    let r = r2.sqrt();
    let e2 = eps * eps;
    if r2 > e2 {
        let r3 = r2 * r;
        let g = s / r3;
        (g, n / r3 - d * (3.0 * s / (r3 * r2)))
    } else {
        let g = s / (r * e2);
        (g, n / (r * e2) - d * (s / (r2 * r * e2)))
    }
}

/// `dF/dx` and the objective contribution of one vertex-channel.
#[inline]
pub fn residual(x: f64, t: f64, w: f64, lb: f64, area: f64) -> (f64, f64, f64) {
    let two = x - t;
    let one = (x - lb).min(0.0);
    let f = 0.5 * area * (w * two * two + (1.0 - w) * one * one);
    let rho = area * (w * two + (1.0 - w) * one);
    (f, rho, area * w * two * two)
}

/// Radiance of every problem vertex (no gradient).
pub fn radiance(pb: &Problem, vis: &Visibility, lights: &[Light], terms: Terms) -> Vec<[f32; 3]> {
    (0..pb.len())
        .into_par_iter()
        .map(|i| {
            let (s, _) = terms.sun_at(pb, vis, i);
            let mut e = s.map(|v| v as f64);
            for (j, l) in lights.iter().enumerate() {
                if !vis.visible(j, i) {
                    continue;
                }
                let (g, _) = geometry_term(pb.pos[i], pb.normal[i], l.pos, pb.eps);
                for c in 0..3 {
                    e[c] += l.rgb[c] as f64 * g as f64;
                }
            }
            [0, 1, 2].map(|c| (pb.albedo[i][c] as f64 * (e[c] / PI + terms.ambient[c] as f64) + terms.indirect[c] as f64 * pb.indirect[i][c] as f64) as f32)
        })
        .collect()
}

/// Objective, relative error and gradient on the CPU (rayon over vertex chunks, f64 sums).
pub fn evaluate(pb: &Problem, vis: &Visibility, lights: &[Light], terms: Terms) -> Eval {
    let k = lights.len();
    let chunk = 4096;
    #[allow(clippy::type_complexity)]
    let parts: Vec<(f64, f64, Vec<[f64; 6]>, [f64; 3], [f64; 3], [f64; 6])> = (0..pb.len().div_ceil(chunk))
        .into_par_iter()
        .map(|ci| {
            let mut f = 0.0;
            let mut num = 0.0;
            let mut grad = vec![[0.0f64; 6]; k];
            let mut ga = [0.0f64; 3];
            let mut gk = [0.0f64; 3];
            let mut gsun = [0.0f64; 6];
            let mut gs = vec![(0.0f32, Vec3::ZERO); k];
            for i in ci * chunk..((ci + 1) * chunk).min(pb.len()) {
                let (x, n) = (pb.pos[i], pb.normal[i]);
                let (s, cos_sun) = terms.sun_at(pb, vis, i);
                let mut e = s.map(|v| v as f64);
                for (j, l) in lights.iter().enumerate() {
                    gs[j] = if vis.visible(j, i) { geometry_term(x, n, l.pos, pb.eps) } else { (0.0, Vec3::ZERO) };
                    for c in 0..3 {
                        e[c] += l.rgb[c] as f64 * gs[j].0 as f64;
                    }
                }
                let mut rho_a = [0.0f64; 3]; // rho_ic * albedo_ic / pi
                for c in 0..3 {
                    let a = pb.albedo[i][c] as f64;
                    let o = pb.indirect[i][c] as f64;
                    let xc = a * (e[c] / PI + terms.ambient[c] as f64) + terms.indirect[c] as f64 * o;
                    let (fi, rho, ni) = residual(xc, pb.target[i][c] as f64, pb.weight[i][c] as f64, pb.lower[i][c] as f64, pb.area[i] as f64);
                    f += fi;
                    num += ni;
                    rho_a[c] = rho * a / PI;
                    ga[c] += rho * a;
                    gk[c] += rho * o;
                }
                if rho_a == [0.0; 3] {
                    continue;
                }
                if let Some(sun) = terms.sun.filter(|_| cos_sun > 0.0) {
                    let mut q = 0.0;
                    for c in 0..3 {
                        gsun[3 + c] += rho_a[c] * cos_sun as f64;
                        q += rho_a[c] * sun.rgb[c] as f64;
                    }
                    gsun[0] += q * n.x as f64;
                    gsun[1] += q * n.y as f64;
                    gsun[2] += q * n.z as f64;
                }
                for (j, l) in lights.iter().enumerate() {
                    let (g, dg) = gs[j];
                    if g == 0.0 {
                        continue;
                    }
                    let gr = &mut grad[j];
                    let mut s = 0.0;
                    for c in 0..3 {
                        gr[3 + c] += rho_a[c] * g as f64;
                        s += rho_a[c] * l.rgb[c] as f64;
                    }
                    let dg = dg.as_dvec3() * s;
                    gr[0] += dg.x;
                    gr[1] += dg.y;
                    gr[2] += dg.z;
                }
            }
            (f, num, grad, ga, gk, gsun)
        })
        .collect();
    let mut out = Eval { grad: vec![[0.0; 6]; k], ..Default::default() };
    let mut num = 0.0;
    for (f, nm, g, ga, gk, gsun) in parts {
        for q in 0..6 {
            out.grad_sun[q] += gsun[q];
        }
        out.f += f;
        num += nm;
        for (a, b) in out.grad.iter_mut().zip(g) {
            for q in 0..6 {
                a[q] += b[q];
            }
        }
        for c in 0..3 {
            out.grad_ambient[c] += ga[c];
            out.grad_indirect[c] += gk[c];
        }
    }
    out.rel_error = if pb.norm2 > 0.0 { (num / pb.norm2).sqrt() } else { 0.0 };
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::Bvh;
    use crate::testutil::room;

    /// Central finite differences of the objective against the analytic gradient.
    #[test]
    fn gradient_matches_central_differences() {
        let (mesh, tg) = room(6);
        let (lo, hi) = mesh.bounds();
        let mut pb = Problem::new(&mesh, &tg, (hi - lo).length());
        for (i, o) in pb.indirect.iter_mut().enumerate() {
            *o = [0.05 + 0.01 * (i % 5) as f32, 0.04, 0.03 + 0.02 * (i % 3) as f32];
        }
        let bvh = Bvh::build(&mesh);
        let lights = vec![
            Light { pos: Vec3::new(1.1, 1.7, 0.9), rgb: [2.0, 1.5, 1.0] },
            Light { pos: Vec3::new(2.6, 0.8, 2.2), rgb: [0.7, 1.2, 1.9] },
        ];
        let sun = Sun { to_sun: Vec3::new(0.3, 0.9, -0.2).normalize(), rgb: [1.5, 1.2, 0.9] };
        let terms = Terms { ambient: [0.01, 0.02, 0.015], indirect: [0.8, 1.1, 0.6], sun: Some(sun) };
        let vis_of = |ls: &[Light]| {
            let mut v = Visibility::default();
            v.update(ls, 0.0, pb.len(), &mut |p| Ok(p.iter().map(|&q| crate::visibility::trace_light(&bvh, &pb, q)).collect())).unwrap();
            v
        };
        let mut vis = vis_of(&lights);
        // The room is closed: let the sun reach the rows facing it through a "sky" ceiling,
        // i.e. with every triangle marked sky.
        let sky = vec![true; mesh.triangles.len()];
        vis.update_sun(Some(sun.to_sun), 0.0, pb.len(), &mut |d| crate::visibility::trace_sun(&bvh, &pb, d, &sky));
        assert!(vis.sun.as_ref().unwrap().1.iter().any(|&w| w != 0), "the sun reaches some rows");
        let ev = evaluate(&pb, &vis, &lights, terms);
        assert!(ev.f > 0.0);
        for j in 0..lights.len() {
            for q in 0..6 {
                let h = if q < 3 { 1e-3 } else { 1e-3 };
                let mut a = lights.clone();
                let mut b = lights.clone();
                if q < 3 {
                    a[j].pos[q] += h;
                    b[j].pos[q] -= h;
                } else {
                    a[j].rgb[q - 3] += h;
                    b[j].rgb[q - 3] -= h;
                }
                // Same visibility (no shadow boundary crossing for these small steps).
                let fd = (evaluate(&pb, &vis, &a, terms).f - evaluate(&pb, &vis, &b, terms).f) / (2.0 * h as f64);
                let an = ev.grad[j][q];
                let scale = an.abs().max(fd.abs()).max(1e-9 * ev.f);
                assert!((fd - an).abs() <= 2e-3 * scale, "light {j} param {q}: analytic {an} vs central difference {fd}");
            }
        }
        for c in 0..3 {
            let h = 1e-4f32;
            let (mut a, mut b) = (terms, terms);
            a.ambient[c] += h;
            b.ambient[c] -= h;
            let fd = (evaluate(&pb, &vis, &lights, a).f - evaluate(&pb, &vis, &lights, b).f) / (2.0 * h as f64);
            assert!((fd - ev.grad_ambient[c]).abs() <= 2e-3 * fd.abs().max(ev.grad_ambient[c].abs()), "ambient {c}: {} vs {fd}", ev.grad_ambient[c]);
            let (mut a, mut b) = (terms, terms);
            a.indirect[c] += h;
            b.indirect[c] -= h;
            let fd = (evaluate(&pb, &vis, &lights, a).f - evaluate(&pb, &vis, &lights, b).f) / (2.0 * h as f64);
            assert!((fd - ev.grad_indirect[c]).abs() <= 2e-3 * fd.abs().max(ev.grad_indirect[c].abs()), "indirect {c}: {} vs {fd}", ev.grad_indirect[c]);
        }
        // The sun: direction (unnormalised perturbation, same visibility) and irradiance.
        for q in 0..6 {
            let h = 1e-3f32;
            let (mut a, mut b) = (sun, sun);
            if q < 3 {
                a.to_sun[q] += h;
                b.to_sun[q] -= h;
            } else {
                a.rgb[q - 3] += h;
                b.rgb[q - 3] -= h;
            }
            let with = |s: Sun| Terms { sun: Some(s), ..terms };
            let fd = (evaluate(&pb, &vis, &lights, with(a)).f - evaluate(&pb, &vis, &lights, with(b)).f) / (2.0 * h as f64);
            let an = ev.grad_sun[q];
            assert!((fd - an).abs() <= 2e-3 * fd.abs().max(an.abs()).max(1e-9 * ev.f), "sun param {q}: analytic {an} vs central difference {fd}");
        }
    }
}
