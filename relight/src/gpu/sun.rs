//! The sun's visibility on the device (`shaders/sun.wgsl`; the CPU reference is
//! [`crate::trace::visibility::trace_sun`]): one invocation per row and direction walks
//! the mesh's tree to the ray's first hit and sets the row's bit where that is a sky
//! surface. The rows are the caller's (the sun search scores its own subsample), uploaded
//! with each call; the mesh's tree is the backend's, uploaded once. Directions go in
//! dispatches whose bits fit the adapter's storage binding limit.

use glam::Vec3;
use wgpu::util::DeviceExt;

use super::{bind_group, grid, output, storage, GpuBackend, MAX_GROUPS, WG};
use crate::error::{Error, Result};
use crate::rows::Rows;

/// `SunRow` of `shaders/sun.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SunRow {
    pos: [f32; 3],
    /// [`crate::rows::SolidAhead`]'s bits.
    ahead: u32,
    normal: [f32; 3],
    /// 1.0 for a two-sided row ([`Rows::facing`]), else 0.0.
    two_sided: f32,
}

/// `SunParams` of `shaders/sun.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SunParams {
    n: u32,
    dirs: u32,
    words: u32,
    open: u32,
    stride: u32,
    shadow_offset: f32,
    t_min: f32,
    reach: f32,
    on_epsilon: f32,
    pad: [u32; 3],
}

impl GpuBackend {
    /// The sun's visibility bits of `rows` towards each of `dirs` (unit vectors to the
    /// sun), `sky` flagging the mesh's sky triangles: what `trace_sun` gives for each.
    pub(super) fn try_sun_bits(&mut self, rows: &Rows, dirs: &[Vec3], sky: &[bool]) -> Result<Vec<Vec<u32>>> {
        let n = rows.len();
        let words = n.div_ceil(32).max(1);
        if n == 0 || dirs.is_empty() {
            return Ok(vec![vec![0u32; words]; dirs.len()]);
        }
        let max = self.ctx.max_binding();
        if n * std::mem::size_of::<SunRow>() > max || n.div_ceil(WG as usize) > (MAX_GROUPS as usize) * (MAX_GROUPS as usize) {
            return Err(Error::Gpu(format!("the sun's {n} rows exceed the adapter's storage binding limit of {max} bytes")));
        }
        let sun_rows: Vec<SunRow> = (0..n)
            .map(|i| SunRow { pos: rows.pos[i].to_array(), ahead: rows.solid_ahead[i].0 as u32, normal: rows.normal[i].to_array(), two_sided: if rows.two_sided[i] { 1.0 } else { 0.0 } })
            .collect();
        // The sky flags in the tree's triangle order (a triangle past `sky` is not sky,
        // as on the CPU); a scene without sky surfaces is open.
        let flags: Vec<u32> = self.mesh_tri_index.iter().map(|&t| sky.get(t as usize).copied().unwrap_or(false) as u32).collect();
        let open = !sky.iter().any(|&k| k);
        let d = &self.ctx.device;
        let rows_b = storage(d, "sun rows", bytemuck::cast_slice(&sun_rows));
        let sky_b = storage(d, "sun sky flags", bytemuck::cast_slice(&flags));
        let layout = self.ctx.pipes.sun.get_bind_group_layout(0);
        let per_dispatch = (max / (4 * words)).clamp(1, MAX_GROUPS as usize);
        let (gx, gy) = grid((n as u32).div_ceil(WG));
        let mut out = Vec::with_capacity(dirs.len());
        for batch in dirs.chunks(per_dispatch) {
            let dirs_v: Vec<[f32; 4]> = batch.iter().map(|w| w.extend(0.0).to_array()).collect();
            let dirs_b = storage(d, "sun directions", bytemuck::cast_slice(&dirs_v));
            let size = (batch.len() * words * 4) as u64;
            // wgpu zero-initialises new buffers: every bit starts cleared.
            let bits = output(d, "sun bits", size);
            let params = SunParams {
                n: n as u32,
                dirs: batch.len() as u32,
                words: words as u32,
                open: open as u32,
                stride: gx * WG,
                shadow_offset: rows.sampling.shadow_offset,
                t_min: rows.sampling.inhibit / self.mesh_reach,
                reach: self.mesh_reach,
                on_epsilon: rows.sampling.on_epsilon,
                pad: [0; 3],
            };
            let ub = d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("sun params"), contents: bytemuck::bytes_of(&params), usage: wgpu::BufferUsages::UNIFORM });
            let bg = bind_group(d, &layout, "sun", &[&ub, &rows_b, &self.mesh_nodes, &self.mesh_tris, &sky_b, &dirs_b, &bits]);
            let mut enc = d.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.ctx.pipes.sun);
                pass.set_bind_group(0, &bg, &[]);
                // One row of workgroups per direction: x (and y past 65535 groups) over
                // the rows, the direction in z.
                pass.dispatch_workgroups(gx, gy, batch.len() as u32);
            }
            let data = self.ctx.read_back(&bits, size, enc)?;
            out.extend(bytemuck::cast_slice::<u8, u32>(&data).chunks(words).map(<[u32]>::to_vec));
        }
        Ok(out)
    }
}
