//! The two places the light kernels run: the CPU (rayon; also the reference) and wgpu
//! ([`crate::gpu`]). Both hold the rows and the BVH, uploaded or borrowed once. A backend
//! traces shadow rays and evaluates the point and spot lights ([`crate::model::lights`]),
//! the one part of the model whose cost grows with lights x rows; the rest of the model
//! runs on the CPU in f64 ([`crate::model`]), except the surface lights' basis and the
//! sun's visibility, which a backend with kernels for them computes
//! ([`Backend::surface_sums`], [`Backend::sun_bits`]).

use glam::Vec3;

use crate::error::Result;
use crate::model::lights::{self, Light, LightGrad};
use crate::model::surface;
use crate::rows::Rows;
use crate::trace::bvh::Bvh;
use crate::trace::visibility::{self, Visibility};

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
}

impl<'a> Cpu<'a> {
    pub fn new(rows: &'a Rows, bvh: &'a Bvh) -> Cpu<'a> {
        Cpu { rows, bvh, recent: Default::default() }
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
        Ok(lights::irradiance(self.rows, vis, lights))
    }
    fn gradient(&mut self, vis: &Visibility, lights: &[Light], rho: &[[f32; 3]]) -> Result<Vec<LightGrad>> {
        Ok(lights::gradient(self.rows, vis, lights, rho))
    }
}
