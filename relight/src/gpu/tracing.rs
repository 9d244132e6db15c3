//! The light-tracing estimator on wgpu (`shaders/light_tracing.wgsl`): the same sample as
//! [`crate::light_tracing`] (its CPU reference), the BVH and the splat tables uploaded
//! once; each evaluation uploads the lights, dispatches one invocation per (ray, light)
//! and reads back the 64-bit fixed-point deposits (irradiance) or one partial gradient per
//! workgroup (added on the CPU in f64, in order).

use glam::Vec3;
use wgpu::util::DeviceExt;

use super::{output, storage, Context, MAX_GROUPS, WG};
use crate::backend::Backend;
use crate::error::{Error, Result};
use crate::light_tracing::{self, Splat};
use crate::model::lights::{Light, LightGrad};
use crate::rows::Rows;
use crate::scene::Mesh;
use crate::trace::bvh::Bvh;
use crate::trace::visibility::Visibility;

/// `TracingParams` of the shader.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TracingParams {
    rays: u32,
    lights: u32,
    bounces: u32,
    seed: u32,
    sample: u32,
    groups_x: u32,
    unit: f32,
    reach: f32,
    offset: f32,
    per_intensity: f32,
    pad: [f32; 2],
}

/// `SplatTri` of the shader.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuSplatTri {
    v: [u32; 4],
    a: [f32; 4],
    n: [f32; 4],
    gu: [f32; 4],
    gv: [f32; 4],
}

/// `SplatVertex` of the shader.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuSplatVertex {
    albedo: [f32; 3],
    row: u32,
    inv_area: f32,
    pad: [f32; 3],
}

/// The most rays per light one dispatch covers (the x dimension's group limit).
pub const MAX_RAYS: usize = (MAX_GROUPS * WG) as usize;

pub struct TracingGpu {
    ctx: Context,
    nodes: wgpu::Buffer,
    tris: wgpu::Buffer,
    tri_index: wgpu::Buffer,
    splat_tris: wgpu::Buffer,
    splat_verts: wgpu::Buffer,
    /// What the flux-to-irradiance step needs on the CPU.
    splat: Splat,
    reach: f32,
    n_rows: usize,
    rays_per_light: usize,
    bounces: usize,
    seed: u32,
    sample: u32,
    rays: u64,
}

impl TracingGpu {
    pub fn new(ctx: Context, mesh: &Mesh, rows: &Rows, bvh: &Bvh, rays_per_light: usize, bounces: usize, seed: u64) -> Result<TracingGpu> {
        if rays_per_light > MAX_RAYS {
            return Err(Error::Usage(format!("--rays {rays_per_light}: the wgpu estimator covers at most {MAX_RAYS} rays per light")));
        }
        let splat = Splat::new(mesh, rows)?;
        let d = &ctx.device;
        let st: Vec<GpuSplatTri> = (0..splat.triangles.len())
            .map(|t| {
                let v = splat.triangles[t];
                GpuSplatTri {
                    v: [v[0], v[1], v[2], 0],
                    a: splat.positions[v[0] as usize].extend(0.0).to_array(),
                    n: splat.normal[t].extend(0.0).to_array(),
                    gu: splat.grad_uv[t][0].extend(0.0).to_array(),
                    gv: splat.grad_uv[t][1].extend(0.0).to_array(),
                }
            })
            .collect();
        let sv: Vec<GpuSplatVertex> = (0..splat.row.len()).map(|v| GpuSplatVertex { albedo: splat.albedo[v], row: splat.row[v], inv_area: splat.inv_area[v] as f32, pad: [0.0; 3] }).collect();
        let max = ctx.max_binding();
        if st.len() * std::mem::size_of::<GpuSplatTri>() > max || 6 * 4 * rows.len() > max || bvh.tris.len() * std::mem::size_of::<crate::trace::bvh::Tri>() > max {
            return Err(Error::Gpu(format!("the mesh or the rows exceed the adapter's storage binding limit of {max} bytes")));
        }
        let seed32 = (seed ^ (seed >> 32)) as u32;
        Ok(TracingGpu {
            nodes: storage(d, "nodes", bytemuck::cast_slice(&bvh.nodes)),
            tris: storage(d, "tris", bytemuck::cast_slice(&bvh.tris)),
            tri_index: storage(d, "tri_index", bytemuck::cast_slice(&bvh.tri_index)),
            splat_tris: storage(d, "splat triangles", bytemuck::cast_slice(&st)),
            splat_verts: storage(d, "splat vertices", bytemuck::cast_slice(&sv)),
            splat,
            reach: bvh.reach().max(1.0),
            n_rows: rows.len(),
            rays_per_light: rays_per_light.max(1),
            bounces,
            seed: seed32,
            sample: u32::MAX,
            rays: 0,
            ctx,
        })
    }

    fn params(&self, lights: usize, unit: f64) -> TracingParams {
        TracingParams {
            rays: self.rays_per_light as u32,
            lights: lights as u32,
            bounces: self.bounces as u32,
            seed: self.seed,
            sample: self.sample,
            groups_x: (self.rays_per_light as u32).div_ceil(WG),
            unit: unit as f32,
            reach: self.reach,
            offset: self.splat.offset,
            per_intensity: 4.0 * std::f32::consts::PI / self.rays_per_light as f32,
            pad: [0.0; 2],
        }
    }

    /// Runs one entry point over every (ray, light) of a batch of at most 65535 lights.
    fn dispatch(&self, pipe: &wgpu::ComputePipeline, params: &TracingParams, lights: &[Light], acc: &wgpu::Buffer, rho: &wgpu::Buffer, partial: &wgpu::Buffer) -> wgpu::CommandEncoder {
        let d = &self.ctx.device;
        let per_ray = 4.0 * std::f32::consts::PI / self.rays_per_light as f32;
        // The flux per ray as the CPU reference computes it (f32, same expression).
        let lb: Vec<[f32; 4]> = lights.iter().flat_map(|l| [l.pos.extend(0.0).to_array(), [l.rgb[0].max(0.0) * per_ray, l.rgb[1].max(0.0) * per_ray, l.rgb[2].max(0.0) * per_ray, 0.0]]).collect();
        let lbuf = storage(d, "tracing lights", bytemuck::cast_slice(&lb));
        let ub = d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("tracing params"), contents: bytemuck::bytes_of(params), usage: wgpu::BufferUsages::UNIFORM });
        let layout = pipe.get_bind_group_layout(0);
        let bufs = [&ub, &self.nodes, &self.tris, &self.tri_index, &self.splat_tris, &self.splat_verts, &lbuf, acc, rho, partial];
        let bg = super::bind_group(d, &layout, "light tracing", &bufs);
        let mut enc = d.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(pipe);
            pass.set_bind_group(0, &bg, &[]);
            pass.dispatch_workgroups(params.groups_x.max(1), lights.len() as u32, 1);
        }
        enc
    }

    fn try_irradiance(&mut self, lights: &[Light]) -> Result<Vec<[f32; 3]>> {
        self.sample = self.sample.wrapping_add(1);
        let unit = light_tracing::fixed_unit(lights, self.rays_per_light);
        let d = &self.ctx.device;
        let size = (6 * self.n_rows.max(1) * 4) as u64;
        let acc = output(d, "deposits", size);
        let dummy = storage(d, "unused", &[]);
        let dummy_out = output(d, "unused", 16);
        // Every batch adds into the same deposits; one read at the end.
        let batches: Vec<&[Light]> = lights.chunks(MAX_GROUPS as usize).collect();
        let mut last = None;
        for (k, batch) in batches.iter().enumerate() {
            let params = self.params(batch.len(), unit);
            let enc = self.dispatch(&self.ctx.pipes.tracing_irradiance, &params, batch, &acc, &dummy, &dummy_out);
            if k + 1 < batches.len() {
                self.ctx.queue.submit([enc.finish()]);
            } else {
                last = Some(enc);
            }
        }
        let data = self.ctx.read_back(&acc, size, last.expect("at least one light"))?;
        let words: &[u32] = bytemuck::cast_slice(&data);
        self.rays += (lights.len() * self.rays_per_light) as u64;
        let mut out = vec![[0.0f32; 3]; self.n_rows];
        for (v, &r) in self.splat.row.iter().enumerate() {
            if r != u32::MAX {
                let r = r as usize;
                out[r] = [0, 1, 2].map(|c| ((words[2 * (3 * r + c)] as u64 | (words[2 * (3 * r + c) + 1] as u64) << 32) as f64 * unit * self.splat.inv_area[v]) as f32);
            }
        }
        Ok(out)
    }

    fn try_gradient(&mut self, lights: &[Light], rho: &[[f32; 3]]) -> Result<Vec<LightGrad>> {
        let d = &self.ctx.device;
        let rho4: Vec<[f32; 4]> = rho.iter().map(|r| [r[0], r[1], r[2], 0.0]).collect();
        let rbuf = storage(d, "rho", bytemuck::cast_slice(&rho4));
        let acc = output(d, "unused", 16);
        let gx = (self.rays_per_light as u32).div_ceil(WG) as usize;
        let mut out = vec![LightGrad::default(); lights.len()];
        for (b, batch) in lights.chunks(MAX_GROUPS as usize).enumerate() {
            let psize = (6 * gx * batch.len() * 4) as u64;
            if psize > self.ctx.max_binding() as u64 {
                return Err(Error::Gpu(format!("the gradient's partial sums ({} MB) exceed the adapter's storage binding limit", psize >> 20)));
            }
            let partial = output(d, "tracing partial", psize);
            let params = self.params(batch.len(), 1.0);
            let enc = self.dispatch(&self.ctx.pipes.tracing_gradient, &params, batch, &acc, &rbuf, &partial);
            let data = self.ctx.read_back(&partial, psize, enc)?;
            let p: &[f32] = bytemuck::cast_slice(&data);
            for (jj, g) in out[b * MAX_GROUPS as usize..][..batch.len()].iter_mut().enumerate() {
                for grp in 0..gx {
                    let o = 6 * (jj * gx + grp);
                    let v = |q: usize| p[o + q] as f64;
                    g.add(&LightGrad { pos: [v(0), v(1), v(2)], rgb: [v(3), v(4), v(5)], ..Default::default() });
                }
            }
        }
        Ok(out)
    }
}

impl Backend for TracingGpu {
    fn name(&self) -> String {
        format!("wgpu ({}, {}), light tracing {} rays/light, {} bounces", self.ctx.info.name, self.ctx.info.backend, self.rays_per_light, self.bounces)
    }
    fn trace(&mut self, lights: &[(Vec3, f32)]) -> Result<Vec<Vec<u32>>> {
        Ok(lights.iter().map(|_| vec![0u32; self.n_rows.div_ceil(32)]).collect())
    }
    fn irradiance(&mut self, _vis: &Visibility, lights: &[Light]) -> Result<Vec<[f32; 3]>> {
        light_tracing::check_points(lights)?;
        if lights.iter().all(|l| l.max_rgb() <= 0.0) {
            self.sample = self.sample.wrapping_add(1);
            return Ok(vec![[0.0; 3]; self.n_rows]);
        }
        self.try_irradiance(lights)
    }
    fn gradient(&mut self, _vis: &Visibility, lights: &[Light], rho: &[[f32; 3]]) -> Result<Vec<LightGrad>> {
        light_tracing::check_points(lights)?;
        self.try_gradient(lights, rho)
    }
    fn rays_traced(&self) -> Option<u64> {
        Some(self.rays)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::light_tracing::tests::{check_expectation, EXPECTATION_LIGHT};
    use crate::light_tracing::Tracing;
    use crate::testutil::room;

    fn context() -> Context {
        Context::new().expect("a wgpu adapter (install mesa-vulkan-drivers)")
    }

    /// The same sample on both backends: the same random numbers and paths give the same
    /// deposits (f32 trigonometry may move a hit by an ulp: within 1e-4 of the largest
    /// irradiance), and the same gradient; with bounces and several lights.
    #[test]
    fn wgpu_traces_the_cpus_sample() {
        let (mesh, mut rows) = room(6);
        rows.albedo.iter_mut().enumerate().for_each(|(i, a)| *a = [0.4 + 0.001 * (i % 100) as f32, 0.5, 0.3]);
        let bvh = Bvh::build(&mesh);
        let lights = [Light::point(Vec3::new(1.0, 1.2, 0.8), [2.0, 1.5, 1.0]), Light::point(Vec3::new(3.1, 2.0, 2.4), [0.7, 1.2, 1.9])];
        let (rays, bounces) = (30_000, 2);
        let mut cpu = Tracing::new(&mesh, &rows, &bvh, rays, bounces, 5).unwrap();
        let mut gpu = TracingGpu::new(context(), &mesh, &rows, &bvh, rays, bounces, 5).unwrap();
        let vis = Visibility::default();
        for _ in 0..2 {
            let (ce, ge) = (cpu.irradiance(&vis, &lights).unwrap(), gpu.irradiance(&vis, &lights).unwrap());
            let scale = ce.iter().flat_map(|e| e.iter()).copied().fold(0.0f32, f32::max);
            assert!(scale > 0.0);
            let (mut num, mut den) = (0.0f64, 0.0f64);
            for (a, b) in ce.iter().zip(&ge) {
                for c in 0..3 {
                    assert!((a[c] - b[c]).abs() <= 1e-4 * scale.max(1e-30) + 0.02 * a[c].abs(), "irradiance {a:?} vs {b:?}");
                    num += ((a[c] - b[c]) as f64).powi(2);
                    den += (a[c] as f64).powi(2);
                }
            }
            assert!((num / den).sqrt() < 1e-3, "relative difference {}", (num / den).sqrt());
            let rho: Vec<[f32; 3]> = (0..rows.len()).map(|i| [0.3 - 0.01 * (i % 50) as f32, 0.2, -0.1 + 0.005 * (i % 40) as f32]).collect();
            let (cg, gg) = (cpu.gradient(&vis, &lights, &rho).unwrap(), gpu.gradient(&vis, &lights, &rho).unwrap());
            for j in 0..lights.len() {
                let (a, b) = ([cg[j].pos, cg[j].rgb].concat(), [gg[j].pos, gg[j].rgb].concat());
                let scale = a.iter().map(|v| v.abs()).fold(0.0, f64::max);
                assert!(scale > 0.0);
                for q in 0..6 {
                    assert!((a[q] - b[q]).abs() <= 2e-3 * scale, "light {j} gradient {q}: cpu {} wgpu {}", a[q], b[q]);
                }
            }
        }
    }

    /// The wgpu estimator's expected value is the projected deterministic model too.
    #[test]
    fn wgpu_expectation_is_the_projected_deterministic_model() {
        let (mesh, rows) = room(4);
        let bvh = Bvh::build(&mesh);
        let mut gpu = TracingGpu::new(context(), &mesh, &rows, &bvh, 40_000, 0, 7).unwrap();
        let vis = Visibility::default();
        check_expectation(16, |_| gpu.irradiance(&vis, &[EXPECTATION_LIGHT]).unwrap());
    }
}
