//! The two places the light kernels run: the CPU (rayon; also the reference) and wgpu
//! ([`crate::gpu`]). Both hold the rows and the BVH, uploaded or borrowed once. A backend
//! traces shadow rays and evaluates the point and spot lights ([`crate::model::lights`]),
//! the one part of the model whose cost grows with lights x rows; the rest of the model
//! runs on the CPU in f64 ([`crate::model`]), except the surface lights' basis, the sun's
//! visibility and the first hits of the dirt's and the bounce's rays, which a backend with
//! kernels for them computes
//! ([`Backend::surface_sums`], [`Backend::sun_bits`], [`Backend::first_hits`]).

use glam::Vec3;

use crate::error::Result;
use crate::model::lights::{self, Light, LightGrad};
use crate::model::surface;
use crate::rows::Rows;
use crate::trace::bvh::Bvh;
use crate::trace::tree::PlaneRay;
use crate::trace::visibility::{self, Visibility};

/// A ray's first hit on the mesh: the walk's parameter and the mesh's triangle, or none.
pub type FirstHit = Option<(f32, u32)>;

pub trait Backend {
    /// "cpu (N threads)" or "wgpu (adapter name, backend)".
    fn name(&self) -> String;
    /// Visibility bits of each light position from every row within its reach (m).
    fn trace(&mut self, lights: &[(Vec3, f32)]) -> Result<Vec<Vec<u32>>>;
    /// The lights' irradiance at every row, W/m^2 per channel.
    fn irradiance(&mut self, vis: &Visibility, lights: &[Light]) -> Result<Vec<[f32; 3]>>;
    /// The lights' gradients for `rho_ic = dF/dE_ic`.
    fn gradient(&mut self, vis: &Visibility, lights: &[Light], rho: &[[f32; 3]]) -> Result<Vec<LightGrad>>;
    /// Rays the backend traced itself, where it does not use the visibility cache (the
    /// light-tracing estimator, [`crate::light_tracing`]).
    fn rays_traced(&self) -> Option<u64> {
        None
    }
    /// The surface lights' basis sums where the backend has a kernel for them (wgpu:
    /// `shaders/surface_lights.wgsl`); `None`: the CPU reference,
    /// [`crate::model::surface::basis_from`], builds the basis.
    fn surface_sums(&mut self, _request: &surface::Request) -> Option<Result<surface::Sums>> {
        None
    }
    /// The sun's visibility bits of `rows` (any rows: the sun search scores a subsample)
    /// towards each of `dirs` (unit, to the sun), `sky` flagging the mesh's sky
    /// triangles, where the backend has a kernel for them (wgpu: `shaders/sun.wgsl`);
    /// `None`: the CPU reference runs ([`sun_bits`]).
    fn sun_bits(&mut self, _rows: &Rows, _dirs: &[Vec3], _sky: &[bool]) -> Option<Result<Vec<Vec<u32>>>> {
        None
    }
    /// The sky light's visibility bits of `rows` towards each of `dirs` (its suns, unit),
    /// `sky` flagging the mesh's sky triangles
    /// ([`crate::trace::visibility::sky_visible_from`]'s answers), where the backend has a
    /// kernel for them (wgpu: `shaders/sky.wgsl`); `None`: the CPU reference runs
    /// ([`crate::model::sky::basis`]).
    fn sky_bits(&mut self, _rows: &Rows, _dirs: &[Vec3], _sky: &[bool]) -> Option<Result<Vec<Vec<u32>>>> {
        None
    }
    /// Each ray's first hit on the mesh ([`crate::trace::tree::Tree::first_hit_of`]: the walk's parameter and
    /// the mesh's triangle) where the backend has a kernel for them (wgpu:
    /// `shaders/first_hits.wgsl`); `None`: the CPU walks them ([`first_hits`]).
    fn first_hits(&mut self, _rays: &[PlaneRay]) -> Option<Result<Vec<FirstHit>>> {
        None
    }
}

/// Rays of [`gather_rows`] that go to a device at once.
pub const DEVICE_RAYS: usize = 1 << 22;

/// The walk a row's gather asks for: a ray set up by [`PlaneRay::new`] in, the distance
/// (m, from the ray's own origin) and the mesh's triangle of its first hit out.
pub type Walk<'a> = dyn FnMut(PlaneRay) -> Option<(f32, u32)> + 'a;

/// Every row's gather, `gather(i, walk)` for `i < n`, its rays walked on `backend` where
/// it has a kernel for first hits, else on the CPU row by row
/// ([`crate::trace::tree::Tree::first_hit_from_plane`]'s walk: the CPU reference). On the
/// device each row's gather runs twice: first with a walk that keeps the rays it is
/// handed (and answers none), then, once the device has walked the rays of
/// `DEVICE_RAYS / max_rays` rows at once, with one that answers them in the same order.
/// So a gather must ask for the same rays whatever the answers (the dirt's and the
/// bounce's do).
pub fn gather_rows<T: Send>(backend: &mut dyn Backend, bvh: &Bvh, n: usize, max_rays: usize, gather: impl Fn(usize, &mut Walk<'_>) -> T + Sync) -> Result<Vec<T>> {
    use rayon::prelude::*;
    let cpu = |r: PlaneRay| bvh.first_hit_of(&r).map(|(t, tri)| (r.distance(t), tri));
    // Whether the backend walks first hits (an empty batch answers at no cost).
    if backend.first_hits(&[]).is_none() {
        return Ok((0..n).into_par_iter().map(|i| gather(i, &mut |r| cpu(r))).collect());
    }
    let chunk_rows = (DEVICE_RAYS / max_rays.max(1)).max(1);
    let mut out = Vec::with_capacity(n);
    for start in (0..n).step_by(chunk_rows) {
        let chunk = start..(start + chunk_rows).min(n);
        let handed: Vec<Vec<PlaneRay>> = chunk
            .clone()
            .into_par_iter()
            .map(|i| {
                let mut rays = Vec::new();
                gather(i, &mut |r| {
                    rays.push(r);
                    None
                });
                rays
            })
            .collect();
        let mut first = Vec::with_capacity(handed.len() + 1);
        first.push(0usize);
        handed.iter().for_each(|r| first.push(first.last().copied().unwrap_or(0) + r.len()));
        let rays: Vec<PlaneRay> = handed.into_iter().flatten().collect();
        let hits = first_hits(backend, bvh, &rays)?;
        if hits.len() != rays.len() {
            return Err(crate::error::Error::Gpu(format!("the device gave {} first hits for {} rays", hits.len(), rays.len())));
        }
        out.par_extend(chunk.into_par_iter().enumerate().map(|(k, i)| {
            let mut next = first[k];
            gather(i, &mut |_| {
                let r = next;
                next += 1;
                hits.get(r).copied().flatten().map(|(t, tri)| (rays[r].distance(t), tri))
            })
        }));
    }
    Ok(out)
}

/// Each ray's first hit on the mesh: the backend's kernel where it has one, else
/// [`crate::trace::tree::Tree::first_hit_of`] on the CPU, the rays in parallel.
pub fn first_hits(backend: &mut dyn Backend, bvh: &Bvh, rays: &[PlaneRay]) -> Result<Vec<FirstHit>> {
    use rayon::prelude::*;
    match backend.first_hits(rays) {
        Some(hits) => hits,
        None => Ok(rays.par_iter().map(|r| bvh.first_hit_of(r)).collect()),
    }
}

/// The sun's visibility bits of `rows` towards each of `dirs`: the backend's kernel where
/// it has one, else [`visibility::trace_sun`] on the CPU, the directions in parallel (the
/// same bits in any order).
pub fn sun_bits(backend: &mut dyn Backend, bvh: &Bvh, rows: &Rows, dirs: &[Vec3], sky: &[bool]) -> Result<Vec<Vec<u32>>> {
    use rayon::prelude::*;
    match backend.sun_bits(rows, dirs, sky) {
        Some(bits) => bits,
        None => Ok(dirs.par_iter().map(|&d| visibility::trace_sun(bvh, rows, d, sky)).collect()),
    }
}

pub struct Cpu<'a> {
    pub rows: &'a Rows,
    pub bvh: &'a Bvh,
    /// What stopped the rows' rays in recent traces: tried first when a light is traced
    /// near one of them (the same bits).
    recent: visibility::RecentOccluders,
    /// The rows' word boxes: the kernels leave out the words beyond a light's falloff
    /// cut (the same sums; `rows` is borrowed, so they stay the rows' boxes).
    boxes: visibility::WordBoxes,
}

impl<'a> Cpu<'a> {
    pub fn new(rows: &'a Rows, bvh: &'a Bvh) -> Cpu<'a> {
        Cpu { rows, bvh, recent: Default::default(), boxes: visibility::WordBoxes::of(rows) }
    }
}

impl Backend for Cpu<'_> {
    fn name(&self) -> String {
        format!("cpu ({} threads)", rayon::current_num_threads())
    }
    fn trace(&mut self, lights: &[(Vec3, f32)]) -> Result<Vec<Vec<u32>>> {
        Ok(lights
            .iter()
            .map(|&(p, r)| {
                let (bits, stopped) = visibility::trace_light_hinted(self.bvh, self.rows, p, r, self.recent.near(p));
                self.recent.put(p, stopped);
                bits
            })
            .collect())
    }
    fn irradiance(&mut self, vis: &Visibility, lights: &[Light]) -> Result<Vec<[f32; 3]>> {
        Ok(lights::irradiance(self.rows, &self.boxes, vis, lights))
    }
    fn gradient(&mut self, vis: &Visibility, lights: &[Light], rho: &[[f32; 3]]) -> Result<Vec<LightGrad>> {
        Ok(lights::gradient(self.rows, &self.boxes, vis, lights, rho))
    }
}
