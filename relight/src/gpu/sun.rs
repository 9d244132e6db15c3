//! Rays towards suns on the device: the sun's visibility (`shaders/sun.wgsl`; the CPU
//! reference is [`crate::trace::visibility::trace_sun`]) and the sky light's
//! (`shaders/sky.wgsl`; the CPU reference is
//! [`crate::trace::visibility::sky_visible_from`], through [`crate::model::sky::basis`]).
//! One invocation per row and direction. The sun's walks the mesh's tree to the ray's
//! first hit and sets the row's bit where that is a sky surface; the sky's first finds
//! the rays that cross a sky surface (the mesh's tree), then those of them that nothing
//! opaque stops (the shadow rays' tree: q3map2's pieces where the scene has them). The
//! rows are the caller's (the sun search scores its own subsample), uploaded with each
//! call; the trees are the backend's, uploaded once. Directions go in dispatches whose
//! bits fit the adapter's storage binding limit.

use glam::Vec3;
use wgpu::util::DeviceExt;

use super::{bind_group, grid, output, storage, GpuBackend, MAX_GROUPS, WG};
use crate::error::{Error, Result};
use crate::rows::Rows;

/// `SunRow` of `shaders/sun_rays.wgsl`.
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

/// `SkyParams` of `shaders/sky.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SkyParams {
    n: u32,
    dirs: u32,
    words: u32,
    open: u32,
    stride: u32,
    pass: u32,
    pieces: u32,
    shadow_offset: f32,
    t_min: f32,
    reach: f32,
    on_epsilon: f32,
    leaf_eps: f32,
}

/// The rows as the rays towards a sun need them (`SunRow` of `shaders/sun_rays.wgsl`).
fn sun_rows(rows: &Rows) -> Vec<SunRow> {
    (0..rows.len()).map(|i| SunRow { pos: rows.pos[i].to_array(), ahead: rows.solid_ahead[i].0 as u32, normal: rows.normal[i].to_array(), two_sided: if rows.two_sided[i] { 1.0 } else { 0.0 } }).collect()
}

impl GpuBackend {
    /// Whether `n` rows fit the kernels over rows and directions: their buffer within the
    /// adapter's storage binding limit, their workgroups within a dispatch's grid.
    fn check_sun_rows(&self, n: usize, what: &str) -> Result<()> {
        let max = self.ctx.max_binding();
        if n * std::mem::size_of::<SunRow>() > max || n.div_ceil(WG as usize) > (MAX_GROUPS as usize) * (MAX_GROUPS as usize) {
            return Err(Error::Gpu(format!("the {what}'s {n} rows exceed the adapter's storage binding limit of {max} bytes")));
        }
        Ok(())
    }

    /// The mesh's sky flags in its tree's triangle order (a triangle past `sky` is not
    /// sky, as on the CPU).
    fn tree_sky_flags(&self, sky: &[bool]) -> Vec<u32> {
        self.mesh_tri_index.iter().map(|&t| sky.get(t as usize).copied().unwrap_or(false) as u32).collect()
    }

    /// The sky light's visibility bits of `rows` towards each of `dirs` (the sky suns,
    /// unit vectors), `sky` flagging the mesh's sky triangles: bit `i` of direction `k`
    /// is [`crate::trace::visibility::sky_visible_from`]'s answer for row `i` (its normal
    /// as [`Rows::facing`] turns it) and sun `k`.
    pub(super) fn try_sky_bits(&mut self, rows: &Rows, dirs: &[Vec3], sky: &[bool]) -> Result<Vec<Vec<u32>>> {
        let n = rows.len();
        let words = n.div_ceil(32).max(1);
        if n == 0 || dirs.is_empty() {
            return Ok(vec![vec![0u32; words]; dirs.len()]);
        }
        self.check_sun_rows(n, "sky light")?;
        let open = !sky.iter().any(|&k| k);
        let d = &self.ctx.device;
        let rows_b = storage(d, "sky rows", bytemuck::cast_slice(&sun_rows(rows)));
        let sky_b = storage(d, "sky flags", bytemuck::cast_slice(&self.tree_sky_flags(sky)));
        let layout = self.ctx.pipes.sky.get_bind_group_layout(0);
        let per_dispatch = (self.ctx.max_binding() / (4 * words)).clamp(1, MAX_GROUPS as usize);
        let (gx, gy) = grid((n as u32).div_ceil(WG));
        let mut out = Vec::with_capacity(dirs.len());
        for batch in dirs.chunks(per_dispatch) {
            let dirs_v: Vec<[f32; 4]> = batch.iter().map(|w| w.extend(0.0).to_array()).collect();
            let dirs_b = storage(d, "sky directions", bytemuck::cast_slice(&dirs_v));
            let size = (batch.len() * words * 4) as u64;
            // wgpu zero-initialises new buffers: every bit starts cleared.
            let crossed = output(d, "sky crossings", size);
            let bits = output(d, "sky bits", size);
            let params = |pass: u32| SkyParams {
                n: n as u32,
                dirs: batch.len() as u32,
                words: words as u32,
                open: open as u32,
                stride: gx * WG,
                pass,
                pieces: self.pieces.is_some() as u32,
                shadow_offset: rows.sampling.shadow_offset,
                t_min: rows.sampling.inhibit / self.mesh_reach,
                reach: self.mesh_reach,
                on_epsilon: rows.sampling.on_epsilon,
                leaf_eps: self.pieces.unwrap_or(0.0),
            };
            let uniform = |p: SkyParams| d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("sky params"), contents: bytemuck::bytes_of(&p), usage: wgpu::BufferUsages::UNIFORM });
            let (u0, u1) = (uniform(params(0)), uniform(params(1)));
            // Pass 0 reads no crossings (it writes them): a small buffer fills that
            // binding, since `crossed` cannot be bound twice in one bind group.
            let scratch = output(d, "sky no crossings", 16);
            let crossing = bind_group(d, &layout, "sky crossing", &[&u0, &rows_b, &self.mesh_nodes, &self.mesh_tris, &self.bounds, &sky_b, &dirs_b, &scratch, &crossed]);
            let blocking = bind_group(d, &layout, "sky blocking", &[&u1, &rows_b, &self.nodes, &self.tris, &self.bounds, &sky_b, &dirs_b, &crossed, &bits]);
            let mut enc = d.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.ctx.pipes.sky);
                // One row of workgroups per direction: x (and y past 65535 groups) over
                // the rows, the direction in z. A scene without sky surfaces crosses
                // everywhere: no pass 0.
                if !open {
                    pass.set_bind_group(0, &crossing, &[]);
                    pass.dispatch_workgroups(gx, gy, batch.len() as u32);
                }
                pass.set_bind_group(0, &blocking, &[]);
                pass.dispatch_workgroups(gx, gy, batch.len() as u32);
            }
            let data = self.ctx.read_back(&bits, size, enc)?;
            out.extend(bytemuck::cast_slice::<u8, u32>(&data).chunks(words).map(<[u32]>::to_vec));
        }
        Ok(out)
    }

    /// The sun's visibility bits of `rows` towards each of `dirs` (unit vectors to the
    /// sun), `sky` flagging the mesh's sky triangles: what `trace_sun` gives for each.
    pub(super) fn try_sun_bits(&mut self, rows: &Rows, dirs: &[Vec3], sky: &[bool]) -> Result<Vec<Vec<u32>>> {
        let n = rows.len();
        let words = n.div_ceil(32).max(1);
        if n == 0 || dirs.is_empty() {
            return Ok(vec![vec![0u32; words]; dirs.len()]);
        }
        self.check_sun_rows(n, "sun")?;
        // A scene without sky surfaces is open.
        let open = !sky.iter().any(|&k| k);
        let max = self.ctx.max_binding();
        let d = &self.ctx.device;
        let rows_b = storage(d, "sun rows", bytemuck::cast_slice(&sun_rows(rows)));
        let sky_b = storage(d, "sun sky flags", bytemuck::cast_slice(&self.tree_sky_flags(sky)));
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
