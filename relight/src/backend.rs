//! The two places the heavy kernels run: the CPU (rayon; also the reference) and wgpu
//! (`gpu` module). Both hold the problem and the BVH, uploaded or borrowed once.

use glam::Vec3;

use crate::error::Result;

use crate::bvh::Bvh;
use crate::model::{self, Eval, Light, Problem, Terms};
use crate::visibility::{self, Visibility};

pub trait Backend {
    /// "cpu" or "wgpu (adapter name, backend)".
    fn name(&self) -> String;
    /// Visibility bits of each light position from every problem vertex.
    fn trace(&mut self, lights: &[Vec3]) -> Result<Vec<Vec<u32>>>;
    /// Objective, error and gradient.
    fn evaluate(&mut self, vis: &Visibility, lights: &[Light], terms: Terms) -> Result<Eval>;
}

pub struct Cpu<'a> {
    pub pb: &'a Problem,
    pub bvh: &'a Bvh,
}

impl Backend for Cpu<'_> {
    fn name(&self) -> String {
        format!("cpu ({} threads)", rayon::current_num_threads())
    }
    fn trace(&mut self, lights: &[Vec3]) -> Result<Vec<Vec<u32>>> {
        Ok(lights.iter().map(|&p| visibility::trace_light(self.bvh, self.pb, p)).collect())
    }
    fn evaluate(&mut self, vis: &Visibility, lights: &[Light], terms: Terms) -> Result<Eval> {
        Ok(model::evaluate(self.pb, vis, lights, terms))
    }
}
