//! The wgpu backend: the problem and the BVH are uploaded once; `trace` runs
//! `shaders/trace.wgsl` for a batch of light positions and reads the bits back (they are
//! small: one bit per vertex and light); `evaluate` uploads only the visibility of lights
//! re-traced since the last call and runs `shaders/forward.wgsl`, whose per-workgroup
//! partial sums are added on the CPU in f64. Pipelines are built in one place, [`Pipelines`].

use glam::Vec3;
use wgpu::util::DeviceExt;

use crate::backend::Backend;
use crate::bvh::Bvh;
use crate::error::{Error, Result};
use crate::model::{Eval, Light, Problem, Terms};
use crate::scene::{Lighting, Scene, Wrap};
use crate::target::{self, CORNER_FLOATS};
use crate::visibility::Visibility;

const WG: u32 = 64;
const MAX_GROUPS: u32 = 65_535;

/// What `probe` found.
#[derive(Debug, Clone)]
pub struct AdapterInfo {
    pub name: String,
    pub backend: String,
    /// A CPU implementation (lavapipe, llvmpipe, WARP).
    pub software: bool,
}

/// A wgpu device with every relight pipeline built on it: made once per run and used
/// first by the target projection ([`Context::target_sums`]), then by [`GpuBackend`].
pub struct Context {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: AdapterInfo,
    pipes: Pipelines,
}

fn adapter() -> Result<wgpu::Adapter> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions { power_preference: wgpu::PowerPreference::HighPerformance, ..Default::default() }))
        .map_err(|e| Error::Gpu(format!("no adapter: {e}")))
}

fn info_of(a: &wgpu::Adapter) -> AdapterInfo {
    let i = a.get_info();
    AdapterInfo { name: i.name.clone(), backend: format!("{:?}", i.backend), software: i.device_type == wgpu::DeviceType::Cpu }
}

impl Context {
    /// The adapter wgpu would use, without creating a device.
    pub fn probe() -> Result<AdapterInfo> {
        Ok(info_of(&adapter()?))
    }

    pub fn new() -> Result<Context> {
        let a = adapter()?;
        let info = info_of(&a);
        let limits = a.limits();
        let (device, queue) = pollster::block_on(a.request_device(&wgpu::DeviceDescriptor {
            label: Some("relight"),
            required_features: wgpu::Features::empty(),
            required_limits: limits,
            ..Default::default()
        }))
        .map_err(|e| Error::Gpu(format!("request_device: {e}")))?;
        let pipes = Pipelines::new(&device);
        Ok(Context { device, queue, info, pipes })
    }

    /// The largest storage buffer binding the device accepts, bytes.
    pub fn max_binding(&self) -> usize {
        self.device.limits().max_storage_buffer_binding_size as usize
    }

    /// Copies `size` bytes of `src` to the CPU after submitting `encoder`.
    fn read_back(&self, src: &wgpu::Buffer, size: u64, mut encoder: wgpu::CommandEncoder) -> Result<Vec<u8>> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor { label: Some("readback"), size, usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST, mapped_at_creation: false });
        encoder.copy_buffer_to_buffer(src, 0, &staging, 0, size);
        self.queue.submit([encoder.finish()]);
        let slice = staging.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device.poll(wgpu::PollType::Wait { submission_index: None, timeout: None }).map_err(|e| Error::Gpu(format!("poll: {e}")))?;
        rx.recv().map_err(|e| Error::Gpu(e.to_string()))?.map_err(|e| Error::Gpu(format!("map: {e}")))?;
        let data = slice.get_mapped_range().map_err(|e| Error::Gpu(format!("mapped range: {e}")))?.to_vec();
        staging.unmap();
        Ok(data)
    }

    /// The per-triangle corner sums of the target projection (`shaders/target.wgsl`; CPU
    /// reference [`crate::target::all_triangle_sums_cpu`], same layout and sample count).
    /// Textures are uploaded once as packed RGBA8 words; triangles go in chunks that fit
    /// the adapter's storage binding limit.
    pub fn target_sums(&self, scene: &Scene) -> Result<(Vec<f32>, u64)> {
        let mesh = &scene.mesh;
        let max = self.max_binding();
        let mut infos = Vec::with_capacity(scene.textures.len());
        let mut words: Vec<u32> = Vec::new();
        for t in &scene.textures {
            let wrap = |w: Wrap| match w {
                Wrap::Repeat => 0u32,
                Wrap::Clamp => 1,
                Wrap::Mirror => 2,
            };
            infos.push(GpuTexInfo { offset: words.len() as u32, width: t.width, height: t.height, wrap: wrap(t.wrap_s) | wrap(t.wrap_t) << 8 });
            if (words.len() + t.rgba8.len() / 4) * 4 > max {
                return Err(Error::Gpu(format!("the textures exceed the adapter's storage binding limit of {max} bytes")));
            }
            words.extend(t.rgba8.chunks_exact(4).map(|p| u32::from_le_bytes([p[0], p[1], p[2], p[3]])));
        }
        let mats: Vec<GpuMaterial> = scene
            .materials
            .iter()
            .map(|m| GpuMaterial {
                albedo_factor: m.albedo_factor,
                albedo_tex: m.albedo.map_or(-1, |i| i as i32),
                lightmap_tex: if m.lighting == Lighting::Lightmap { m.lightmap.map_or(-1, |i| i as i32) } else { -1 },
                scale: m.decode(1.0),
                gamma: m.lightmap_gamma,
            })
            .collect();
        let d = &self.device;
        let mats_b = storage(d, "materials", bytemuck::cast_slice(&mats));
        let infos_b = storage(d, "textures", bytemuck::cast_slice(&infos));
        let texels_b = storage(d, "texels", bytemuck::cast_slice(&words));
        let nt = mesh.triangles.len();
        let per_tri = 3 * CORNER_FLOATS * 4;
        let chunk = (max / per_tri).min(max / std::mem::size_of::<GpuTriangle>()).clamp(1, 1 << 20);
        let mut sums = Vec::with_capacity(nt * 3 * CORNER_FLOATS);
        let mut samples = 0u64;
        for start in (0..nt).step_by(chunk) {
            let end = (start + chunk).min(nt);
            let tris: Vec<GpuTriangle> = (start..end)
                .map(|t| {
                    let tri = mesh.triangles[t].map(|i| i as usize);
                    let area = mesh.triangle_area(t);
                    let order = if area > 0.0 && area.is_finite() { target::order(scene, t) } else { 0 };
                    samples += (order * order) as u64;
                    GpuTriangle {
                        uv0: tri.map(|v| mesh.uv0[v].to_array()),
                        uv1: tri.map(|v| mesh.uv1[v].to_array()),
                        area,
                        order,
                        material: mesh.tri_material[t],
                        pad: 0,
                    }
                })
                .collect();
            let n = (end - start) as u32;
            let size = (n as usize * per_tri) as u64;
            let out = d.create_buffer(&wgpu::BufferDescriptor { label: Some("target sums"), size, usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC, mapped_at_creation: false });
            let tris_b = storage(d, "target triangles", bytemuck::cast_slice(&tris));
            let groups = n.div_ceil(WG).max(1);
            let gx = groups.min(MAX_GROUPS);
            let gy = groups.div_ceil(gx);
            let params = TargetParams { triangles: n, row: gx * WG, pad: [0; 2] };
            let ub = d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("target params"), contents: bytemuck::bytes_of(&params), usage: wgpu::BufferUsages::UNIFORM });
            let layout = self.pipes.target.get_bind_group_layout(0);
            let bg = d.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("target"),
                layout: &layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: ub.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: tris_b.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: mats_b.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: infos_b.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 4, resource: texels_b.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 5, resource: out.as_entire_binding() },
                ],
            });
            let mut enc = d.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.pipes.target);
                pass.set_bind_group(0, &bg, &[]);
                pass.dispatch_workgroups(gx, gy, 1);
            }
            let data = self.read_back(&out, size, enc)?;
            sums.extend_from_slice(bytemuck::cast_slice::<u8, f32>(&data));
        }
        Ok((sums, samples))
    }
}

/// Bytes the textures take on the device (see [`Context::target_sums`]).
pub fn texture_bytes(scene: &Scene) -> usize {
    scene.textures.iter().map(|t| t.rgba8.len()).sum()
}

/// `TriIn` of `shaders/target.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuTriangle {
    uv0: [[f32; 2]; 3],
    uv1: [[f32; 2]; 3],
    area: f32,
    order: u32,
    material: u32,
    pad: u32,
}

/// `TexInfo` of `shaders/target.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuTexInfo {
    offset: u32,
    width: u32,
    height: u32,
    wrap: u32,
}

/// `MaterialIn` of `shaders/target.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuMaterial {
    albedo_factor: [f32; 4],
    albedo_tex: i32,
    lightmap_tex: i32,
    scale: f32,
    gamma: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TargetParams {
    triangles: u32,
    row: u32,
    pad: [u32; 2],
}

/// The layout of `Vertex` in `shaders/problem.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuVertex {
    pos: [f32; 3],
    area: f32,
    normal: [f32; 3],
    pad: f32,
    albedo: [f32; 4],
    target: [f32; 4],
    weight: [f32; 4],
    lower: [f32; 4],
    indirect: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TraceParams {
    n: u32,
    lights: u32,
    words: u32,
    ray_offset: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ForwardParams {
    n: u32,
    k: u32,
    words: u32,
    stride: u32,
    ambient: [f32; 4],
    indirect: [f32; 4],
    sun_dir: [f32; 4],
    sun_rgb: [f32; 4],
    eps: f32,
    pad: [f32; 3],
}

struct Pipelines {
    target: wgpu::ComputePipeline,
    trace: wgpu::ComputePipeline,
    forward: wgpu::ComputePipeline,
}

impl Pipelines {
    fn new(device: &wgpu::Device) -> Pipelines {
        let problem = include_str!("../../shaders/problem.wgsl");
        let bvh = include_str!("../../shaders/bvh.wgsl");
        let make = |label: &str, src: String| {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor { label: Some(label), source: wgpu::ShaderSource::Wgsl(src.into()) });
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: None,
                module: &module,
                entry_point: Some("main"),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        Pipelines {
            target: make("target", include_str!("../../shaders/target.wgsl").to_string()),
            trace: make("trace", format!("{problem}\n{bvh}\n{}", include_str!("../../shaders/trace.wgsl"))),
            forward: make("forward", format!("{problem}\n{}", include_str!("../../shaders/forward.wgsl"))),
        }
    }
}

pub struct GpuBackend {
    ctx: Context,
    n: u32,
    words: u32,
    eps: f32,
    ray_offset: f32,
    norm2: f64,
    verts: wgpu::Buffer,
    nodes: wgpu::Buffer,
    tris: wgpu::Buffer,
    /// Visibility uploaded per light slot, and the light position it was traced at.
    vis: Option<wgpu::Buffer>,
    vis_capacity: usize,
    uploaded: Vec<Option<Vec3>>,
}

fn storage(device: &wgpu::Device, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    // wgpu refuses zero-sized bindings: pad empty arrays to one element.
    let pad = [0u8; 16];
    let contents = if bytes.is_empty() { &pad[..] } else { bytes };
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST })
}

impl GpuBackend {
    /// Uploads the problem and the BVH to `ctx`'s device.
    pub fn new(ctx: Context, pb: &Problem, bvh: &Bvh) -> Result<GpuBackend> {
        let verts: Vec<GpuVertex> = (0..pb.len())
            .map(|i| GpuVertex {
                pos: pb.pos[i].to_array(),
                area: pb.area[i],
                normal: pb.normal[i].to_array(),
                pad: 0.0,
                albedo: [pb.albedo[i][0], pb.albedo[i][1], pb.albedo[i][2], 0.0],
                target: [pb.target[i][0], pb.target[i][1], pb.target[i][2], 0.0],
                weight: [pb.weight[i][0], pb.weight[i][1], pb.weight[i][2], 0.0],
                lower: [pb.lower[i][0], pb.lower[i][1], pb.lower[i][2], 0.0],
                indirect: [pb.indirect[i][0], pb.indirect[i][1], pb.indirect[i][2], 0.0],
            })
            .collect();
        let max = ctx.max_binding();
        let vb: &[u8] = bytemuck::cast_slice(&verts);
        if vb.len() > max || bvh.tris.len() * 48 > max {
            return Err(Error::Gpu(format!("the problem ({} vertices, {} triangles) exceeds the adapter's storage binding limit of {max} bytes", pb.len(), bvh.tris.len())));
        }
        if pb.len().div_ceil(WG as usize) > MAX_GROUPS as usize {
            return Err(Error::Gpu(format!("{} vertices exceed one dispatch ({} workgroups of {WG})", pb.len(), MAX_GROUPS)));
        }
        let d = &ctx.device;
        Ok(GpuBackend {
            verts: storage(d, "verts", vb),
            nodes: storage(d, "nodes", bytemuck::cast_slice(&bvh.nodes)),
            tris: storage(d, "tris", bytemuck::cast_slice(&bvh.tris)),
            n: pb.len() as u32,
            words: pb.len().div_ceil(32).max(1) as u32,
            eps: pb.eps,
            ray_offset: pb.ray_offset,
            norm2: pb.norm2,
            vis: None,
            vis_capacity: 0,
            uploaded: Vec::new(),
            ctx,
        })
    }

    fn try_trace(&mut self, lights: &[Vec3]) -> Result<Vec<Vec<u32>>> {
        let d = &self.ctx.device;
        let mut out = Vec::with_capacity(lights.len());
        // Batches bounded by the second dispatch dimension.
        for batch in lights.chunks(MAX_GROUPS as usize) {
            let pos: Vec<[f32; 4]> = batch.iter().map(|p| p.extend(0.0).to_array()).collect();
            let lb = storage(d, "light_pos", bytemuck::cast_slice(&pos));
            let size = (batch.len() * self.words as usize * 4) as u64;
            let bits = d.create_buffer(&wgpu::BufferDescriptor { label: Some("bits"), size, usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC, mapped_at_creation: false });
            // wgpu zero-initialises new buffers: every bit starts cleared.
            let params = TraceParams { n: self.n, lights: batch.len() as u32, words: self.words, ray_offset: self.ray_offset };
            let ub = d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("trace params"), contents: bytemuck::bytes_of(&params), usage: wgpu::BufferUsages::UNIFORM });
            let layout = self.ctx.pipes.trace.get_bind_group_layout(0);
            let bg = d.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("trace"),
                layout: &layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: ub.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: self.verts.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: self.nodes.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: self.tris.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 4, resource: lb.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 5, resource: bits.as_entire_binding() },
                ],
            });
            let mut enc = d.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.ctx.pipes.trace);
                pass.set_bind_group(0, &bg, &[]);
                pass.dispatch_workgroups(self.n.div_ceil(WG).max(1), batch.len() as u32, 1);
            }
            let data = self.ctx.read_back(&bits, size, enc)?;
            let words: &[u32] = bytemuck::cast_slice(&data);
            out.extend(words.chunks(self.words as usize).map(|w| w.to_vec()));
        }
        Ok(out)
    }

    fn try_evaluate(&mut self, vis: &Visibility, lights: &[Light], terms: Terms) -> Result<Eval> {
        let d = &self.ctx.device;
        let k = lights.len();
        let wbytes = self.words as usize * 4;
        if self.vis.is_none() || self.vis_capacity < k.max(1) {
            let cap = k.max(1).next_power_of_two();
            self.vis = Some(d.create_buffer(&wgpu::BufferDescriptor { label: Some("vis"), size: (cap * wbytes) as u64, usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST, mapped_at_creation: false }));
            self.vis_capacity = cap;
            self.uploaded.clear();
        }
        self.uploaded.resize(k, None);
        let vbuf = self.vis.as_ref().expect("allocated above");
        for j in 0..k {
            if self.uploaded[j] != Some(vis.traced_at[j]) {
                self.ctx.queue.write_buffer(vbuf, (j * wbytes) as u64, bytemuck::cast_slice(&vis.bits[j]));
                self.uploaded[j] = Some(vis.traced_at[j]);
            }
        }
        let mut lb: Vec<[f32; 4]> = Vec::with_capacity(2 * k);
        for l in lights {
            lb.push(l.pos.extend(0.0).to_array());
            lb.push([l.rgb[0], l.rgb[1], l.rgb[2], 0.0]);
        }
        let lbuf = storage(d, "lights", bytemuck::cast_slice(&lb));
        let groups = self.n.div_ceil(WG).max(1);
        let stride = 8 * (k as u32 + 2);
        let size = groups as u64 * stride as u64 * 4;
        let partial = d.create_buffer(&wgpu::BufferDescriptor { label: Some("partial"), size, usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC, mapped_at_creation: false });
        let params = ForwardParams { n: self.n, k: k as u32, words: self.words, stride, ambient: [terms.ambient[0], terms.ambient[1], terms.ambient[2], 0.0], indirect: [terms.indirect[0], terms.indirect[1], terms.indirect[2], 0.0],
            sun_dir: terms.sun.map_or([0.0; 4], |s| s.to_sun.extend(1.0).to_array()),
            sun_rgb: terms.sun.map_or([0.0; 4], |s| [s.rgb[0], s.rgb[1], s.rgb[2], 0.0]),
            eps: self.eps,
            pad: [0.0; 3],
        };
        // The sun's bits (a single word when there is none, never read then).
        let sun_words: Vec<u32> = match (&vis.sun, terms.sun) {
            (Some((_, b)), Some(_)) => b.clone(),
            _ => vec![0],
        };
        let sbuf = storage(d, "sun_vis", bytemuck::cast_slice(&sun_words));
        let ub = d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("forward params"), contents: bytemuck::bytes_of(&params), usage: wgpu::BufferUsages::UNIFORM });
        let layout = self.ctx.pipes.forward.get_bind_group_layout(0);
        let bg = d.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("forward"),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: ub.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: self.verts.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: lbuf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: vbuf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 4, resource: partial.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 5, resource: sbuf.as_entire_binding() },
            ],
        });
        let mut enc = d.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.ctx.pipes.forward);
            pass.set_bind_group(0, &bg, &[]);
            pass.dispatch_workgroups(groups, 1, 1);
        }
        let data = self.ctx.read_back(&partial, size, enc)?;
        let p: &[f32] = bytemuck::cast_slice(&data);
        let mut ev = Eval { grad: vec![[0.0; 6]; k], ..Default::default() };
        let mut num = 0.0f64;
        for g in 0..groups as usize {
            let b = &p[g * stride as usize..(g + 1) * stride as usize];
            for j in 0..k {
                for q in 0..6 {
                    ev.grad[j][q] += b[8 * j + q] as f64;
                }
            }
            for q in 0..6 {
                ev.grad_sun[q] += b[8 * k + q] as f64;
            }
            let t = &b[8 * (k + 1)..];
            ev.f += t[0] as f64;
            num += t[1] as f64;
            for c in 0..3 {
                ev.grad_ambient[c] += t[2 + c] as f64;
                ev.grad_indirect[c] += t[5 + c] as f64;
            }
        }
        Ok(ev_with_error(ev, num, self.norm2))
    }
}

fn ev_with_error(mut ev: Eval, num: f64, norm2: f64) -> Eval {
    ev.rel_error = if norm2 > 0.0 { (num / norm2).sqrt() } else { 0.0 };
    ev
}

impl Backend for GpuBackend {
    fn name(&self) -> String {
        format!("wgpu ({}, {})", self.ctx.info.name, self.ctx.info.backend)
    }
    fn trace(&mut self, lights: &[Vec3]) -> Result<Vec<Vec<u32>>> {
        self.try_trace(lights)
    }
    fn evaluate(&mut self, vis: &Visibility, lights: &[Light], terms: Terms) -> Result<Eval> {
        self.try_evaluate(vis, lights, terms)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::room;

    /// The wgpu kernels agree with the CPU reference (visibility bits exactly; objective and
    /// gradient within 1e-4 relative). Needs a wgpu adapter: CI has Mesa's lavapipe.
    #[test]
    fn wgpu_agrees_with_cpu() {
        let (mut mesh, mut tg) = room(8);
        // A pillar in the middle so that some shadow rays are blocked.
        let base = mesh.positions.len() as u32;
        for p in [[1.8, 0.0, 1.3], [2.2, 0.0, 1.3], [2.2, 2.5, 1.3], [1.8, 2.5, 1.3]] {
            mesh.positions.push(Vec3::from(p));
            mesh.normals.push(Vec3::Z);
            mesh.uv0.push(glam::Vec2::ZERO);
            mesh.uv1.push(glam::Vec2::ZERO);
            mesh.colors.push([1.0; 3]);
            mesh.v_material.push(0);
            tg.area.push(0.0);
            tg.albedo.push([0.0; 3]);
            tg.value.push([0.0; 3]);
            tg.weight.push([0.0; 3]);
            tg.lower.push([0.0; 3]);
        }
        mesh.reweld();
        mesh.triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
        mesh.tri_material.extend([0, 0]);
        mesh.tri_source.extend([mesh.triangles.len() as u32 - 2, mesh.triangles.len() as u32 - 1]);
        let (lo, hi) = mesh.bounds();
        let mut pb = Problem::new(&mesh, &tg, (hi - lo).length());
        for (i, o) in pb.indirect.iter_mut().enumerate() {
            *o = [0.02 * (i % 4) as f32, 0.05, 0.01 * (i % 7) as f32];
        }
        let bvh = Bvh::build(&mesh);
        let lights = vec![
            Light { pos: Vec3::new(2.0, 1.2, 0.5), rgb: [2.0, 1.5, 1.0] },
            Light { pos: Vec3::new(3.1, 2.0, 2.4), rgb: [0.7, 1.2, 1.9] },
            Light { pos: Vec3::new(0.6, 0.4, 2.7), rgb: [1.0, 1.0, 1.0] },
        ];
        let mut gpu = GpuBackend::new(Context::new().expect("a wgpu adapter (install mesa-vulkan-drivers)"), &pb, &bvh).expect("a wgpu adapter (install mesa-vulkan-drivers)");
        let positions: Vec<Vec3> = lights.iter().map(|l| l.pos).collect();
        let g_bits = gpu.trace(&positions).unwrap();
        let c_bits: Vec<Vec<u32>> = positions.iter().map(|&p| crate::visibility::trace_light(&bvh, &pb, p)).collect();
        assert_eq!(g_bits, c_bits, "visibility bits differ");
        let blocked = c_bits[0].iter().map(|w| w.count_zeros()).sum::<u32>();
        assert!(blocked > 0, "the pillar casts a shadow");
        let mut vis = Visibility::default();
        vis.update(&lights, 0.0, pb.len(), &mut |p| Ok(p.iter().map(|&q| crate::visibility::trace_light(&bvh, &pb, q)).collect())).unwrap();
        let terms = Terms { ambient: [0.01, 0.02, 0.03], indirect: [0.7, 1.0, 1.3], sun: Some(crate::model::Sun { to_sun: Vec3::new(-0.4, 0.8, 0.3).normalize(), rgb: [2.0, 1.0, 0.5] }) };
        // Every triangle counts as sky here: the sun reaches every row that faces it.
        let sky = vec![true; mesh.triangles.len()];
        vis.update_sun(terms.sun.map(|s| s.to_sun), 0.0, pb.len(), &mut |dir| crate::visibility::trace_sun(&bvh, &pb, dir, &sky));
        let c = crate::model::evaluate(&pb, &vis, &lights, terms);
        let g = gpu.evaluate(&vis, &lights, terms).unwrap();
        let rel = |a: f64, b: f64, scale: f64| (a - b).abs() / scale.max(1e-30);
        assert!(rel(c.f, g.f, c.f) < 1e-4, "objective {} vs {}", c.f, g.f);
        assert!(rel(c.rel_error, g.rel_error, c.rel_error) < 1e-4);
        for j in 0..lights.len() {
            let scale = c.grad[j].iter().map(|v| v.abs()).fold(0.0, f64::max);
            for q in 0..6 {
                assert!(rel(c.grad[j][q], g.grad[j][q], scale) < 1e-4, "light {j} gradient {q}: cpu {} wgpu {}", c.grad[j][q], g.grad[j][q]);
            }
        }
        for k in 0..3 {
            assert!(rel(c.grad_ambient[k], g.grad_ambient[k], c.grad_ambient[k].abs()) < 1e-4);
            assert!(rel(c.grad_indirect[k], g.grad_indirect[k], c.grad_indirect[k].abs()) < 1e-4, "indirect {k}: cpu {} wgpu {}", c.grad_indirect[k], g.grad_indirect[k]);
        }
        let scale = c.grad_sun.iter().map(|v| v.abs()).fold(0.0, f64::max);
        assert!(scale > 0.0);
        for q in 0..6 {
            assert!(rel(c.grad_sun[q], g.grad_sun[q], scale) < 1e-4, "sun gradient {q}: cpu {} wgpu {}", c.grad_sun[q], g.grad_sun[q]);
        }
    }
}
