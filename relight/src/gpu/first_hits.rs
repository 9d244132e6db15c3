//! First hits on the mesh of rays set up on the CPU (`shaders/first_hits.wgsl`; the CPU
//! reference is [`crate::trace::tree::Tree::first_hit_of`]): the dirt's gathers and the
//! bounce's transport. One invocation per ray over the mesh's own tree (the backend's,
//! uploaded once); rays go in dispatches whose buffers fit the adapter's storage binding
//! limit.

use wgpu::util::DeviceExt;

use super::{bind_group, grid, output, storage, GpuBackend, WG};
use crate::error::{Error, Result};
use crate::trace::tree::PlaneRay;

/// `PlaneRay` of `shaders/first_hits.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuPlaneRay {
    o: [f32; 3],
    grace: f32,
    d: [f32; 3],
    pad: f32,
}

/// `FirstHitParams` of `shaders/first_hits.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FirstHitParams {
    n: u32,
    stride: u32,
    pad: [u32; 2],
}

/// Rays per dispatch at most (a GPU's watchdog stays away; 32 MiB of rays).
const RAYS_PER_DISPATCH: usize = 1 << 20;

impl GpuBackend {
    /// Each ray's walk: its parameter at the nearest hit it accepts and the mesh's
    /// triangle, or `None`.
    pub(super) fn try_first_hits(&mut self, rays: &[PlaneRay]) -> Result<Vec<crate::backend::FirstHit>> {
        let max = self.ctx.max_binding();
        let per = RAYS_PER_DISPATCH.min(max / std::mem::size_of::<GpuPlaneRay>()).max(1);
        let d = &self.ctx.device;
        let layout = self.ctx.pipes.first_hits.get_bind_group_layout(0);
        let mut out = Vec::with_capacity(rays.len());
        for chunk in rays.chunks(per) {
            let gr: Vec<GpuPlaneRay> = chunk.iter().map(|r| GpuPlaneRay { o: r.o.to_array(), grace: r.grace, d: r.d.to_array(), pad: 0.0 }).collect();
            let rays_b = storage(d, "plane rays", bytemuck::cast_slice(&gr));
            let size = (chunk.len() * 8) as u64;
            let hits_b = output(d, "first hits", size);
            let (gx, gy) = grid((chunk.len() as u32).div_ceil(WG));
            let params = FirstHitParams { n: chunk.len() as u32, stride: gx * WG, pad: [0; 2] };
            let ub = d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("first hit params"), contents: bytemuck::bytes_of(&params), usage: wgpu::BufferUsages::UNIFORM });
            let bg = bind_group(d, &layout, "first hits", &[&ub, &self.mesh_nodes, &self.mesh_tris, &rays_b, &hits_b]);
            let mut enc = d.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.ctx.pipes.first_hits);
                pass.set_bind_group(0, &bg, &[]);
                pass.dispatch_workgroups(gx, gy, 1);
            }
            let data = self.ctx.read_back(&hits_b, size, enc)?;
            for h in bytemuck::cast_slice::<u8, [u32; 2]>(&data[..chunk.len() * 8]) {
                out.push(match h[1] {
                    u32::MAX => None,
                    k => Some((f32::from_bits(h[0]), *self.mesh_tri_index.get(k as usize).ok_or_else(|| Error::Gpu(format!("a first hit on triangle {k} of a tree of {}", self.mesh_tri_index.len())))?)),
                });
            }
        }
        Ok(out)
    }
}
