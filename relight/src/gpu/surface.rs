//! The surface lights' basis on the device (`shaders/surface_lights.wgsl`; the CPU
//! reference is [`crate::model::surface::basis_from`]): one invocation per row walks the
//! patches in order, as the CPU does, and keeps one sum per emitting group. Rows go in
//! chunks whose sums fit the adapter's storage binding limit, patches in dispatches of
//! [`PATCH_CHUNK`] (the sums carry over from one to the next), all of a row chunk's
//! dispatches in one submit.

use wgpu::util::DeviceExt;

use super::{bind_group, grid, output, storage, GpuBackend, WG};
use crate::error::{Error, Result};
use crate::model::surface::{Request, Sums};

/// Patches per dispatch: each invocation walks at most this many shadow rays. Longer
/// dispatches came back wrong on lavapipe (Mesa's software Vulkan, CI's adapter): with
/// 256 or more patches a dispatch, rows of oacmpctf1 (3188 patches) stopped their loop
/// early, at the same patch for rows of one dispatch, and kept partial sums (39.7 M of
/// the CPU's 41.4 M rays; the bake's wgpu pages then differed from the CPU's on 0.6% of
/// the texels). Nothing in the kernel explains it (every walk of a row agrees with the
/// CPU in dispatches of one patch; loop bounding off, no early returns: the same); at 32
/// a dispatch every row runs every patch and the basis is the CPU's
/// (`tests/bake.rs`, `a_relit_real_map_bakes_to_relights_own_error_on_both_backends`).
/// Short dispatches also keep a GPU's watchdog away.
pub const PATCH_CHUNK: usize = 32;

/// `Patch` of `shaders/surface_lights.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuPatch {
    origin: [f32; 3],
    dist: f32,
    normal: [f32; 3],
    weight: f32,
    area: f32,
    bytes_per_ff: f32,
    group: u32,
    two_sided: u32,
    first_vert: u32,
    verts: u32,
    pad: [u32; 2],
}

/// `SurfaceParams` of `shaders/surface_lights.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SurfaceParams {
    n: u32,
    row0: u32,
    first: u32,
    count: u32,
    groups: u32,
    stride: u32,
    fast: u32,
    pieces: u32,
    units: f32,
    push: f32,
    behind: f32,
    skip_bytes: f32,
    tolerance_bytes: f32,
    shadow_offset: f32,
    inhibit: f32,
    end_margin: f32,
    leaf_eps: f32,
    pad: [f32; 3],
}

impl GpuBackend {
    /// The basis's sums of every row (see the module docs).
    pub(super) fn try_surface_sums(&mut self, req: &Request) -> Result<Sums> {
        let ng = req.groups;
        let n = self.n as usize;
        if req.patches.is_empty() || ng == 0 || n == 0 {
            return Ok(Sums { per_row: vec![0.0; n * ng], rays: 0 });
        }
        let mut corners: Vec<[f32; 4]> = Vec::new();
        let mut patches = Vec::with_capacity(req.patches.len());
        for (p, &bpf) in req.patches.iter().zip(req.bytes_per_ff) {
            patches.push(GpuPatch {
                origin: p.origin.to_array(),
                dist: p.dist,
                normal: p.normal.to_array(),
                weight: p.weight,
                area: p.area,
                bytes_per_ff: bpf,
                group: p.group,
                two_sided: p.two_sided as u32,
                first_vert: corners.len() as u32,
                verts: p.verts.len() as u32,
                pad: [0; 2],
            });
            corners.extend(p.verts.iter().map(|v| v.extend(0.0).to_array()));
        }
        let max = self.ctx.max_binding();
        if patches.len() * std::mem::size_of::<GpuPatch>() > max || corners.len() * 16 > max {
            return Err(Error::Gpu(format!("the surface lights' {} patches exceed the adapter's storage binding limit of {max} bytes", patches.len())));
        }
        let d = &self.ctx.device;
        let patches_b = storage(d, "surface patches", bytemuck::cast_slice(&patches));
        let corners_b = storage(d, "surface corners", bytemuck::cast_slice(&corners));
        let layout = self.ctx.pipes.surface.get_bind_group_layout(0);
        let rows_per = (max / (4 * ng)).clamp(1, n);
        let mut per_row = Vec::with_capacity(n * ng);
        let mut rays = 0u64;
        for row0 in (0..n).step_by(rows_per) {
            let rows = rows_per.min(n - row0);
            let sums_size = (rows * ng * 4) as u64;
            let rays_size = (rows * 4) as u64;
            // wgpu zero-initialises new buffers: every sum starts at 0.
            let sums_b = output(d, "surface sums", sums_size);
            let rays_b = output(d, "surface rays", rays_size);
            let (gx, gy) = grid((rows as u32).div_ceil(WG));
            let mut enc = d.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.ctx.pipes.surface);
                for first in (0..patches.len()).step_by(PATCH_CHUNK) {
                    let params = SurfaceParams {
                        n: rows as u32,
                        row0: row0 as u32,
                        first: first as u32,
                        count: PATCH_CHUNK.min(patches.len() - first) as u32,
                        groups: ng as u32,
                        stride: gx * WG,
                        fast: req.fast as u32,
                        pieces: self.pieces.is_some() as u32,
                        units: req.units_m,
                        push: req.push_m(),
                        behind: req.behind_m(),
                        skip_bytes: crate::model::surface::SKIP_BYTES,
                        tolerance_bytes: crate::scene::q3map2::FALLOFF_TOLERANCE_BYTES,
                        shadow_offset: self.sampling.shadow_offset,
                        inhibit: self.sampling.inhibit,
                        end_margin: self.sampling.ray_offset,
                        leaf_eps: self.pieces.unwrap_or(0.0),
                        pad: [0.0; 3],
                    };
                    let ub = d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("surface params"), contents: bytemuck::bytes_of(&params), usage: wgpu::BufferUsages::UNIFORM });
                    let bg = bind_group(d, &layout, "surface lights", &[&ub, &self.rows, &self.nodes, &self.tris, &self.bounds, &patches_b, &corners_b, &sums_b, &rays_b]);
                    pass.set_bind_group(0, &bg, &[]);
                    pass.dispatch_workgroups(gx, gy, 1);
                }
            }
            let data = self.ctx.read_back(&sums_b, sums_size, enc)?;
            per_row.extend_from_slice(&bytemuck::cast_slice::<u8, f32>(&data)[..rows * ng]);
            let data = self.ctx.read_back(&rays_b, rays_size, d.create_command_encoder(&Default::default()))?;
            rays += bytemuck::cast_slice::<u8, u32>(&data)[..rows].iter().map(|&r| r as u64).sum::<u64>();
        }
        Ok(Sums { per_row, rays })
    }
}
