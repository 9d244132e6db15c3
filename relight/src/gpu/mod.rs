//! The wgpu backend: the rows and the BVH are uploaded once; `trace` runs
//! `shaders/trace.wgsl` for a batch of light positions and reads the bits back (they are
//! small: one bit per row and light); `irradiance` and `gradient` upload only the
//! visibility of lights re-traced since the last call and run
//! `shaders/light_irradiance.wgsl` and `shaders/light_gradient.wgsl` (whose per-workgroup
//! partial sums are reduced by blocks on the device and the blocks added on the CPU in
//! f64; both take the lights in tiles of 64 and pass over those that reach no row of a
//! workgroup, by its two visibility words, with the sums of visiting them all). The surface lights' basis is `shaders/surface_lights.wgsl` ([`surface`]), the
//! sun's visibility `shaders/sun.wgsl` and the sky light's `shaders/sky.wgsl` ([`sun`]),
//! the first hits of the dirt's and the
//! bounce's rays `shaders/first_hits.wgsl` ([`first_hits`]); every shadow ray walks
//! `shaders/shadow.wgsl`. The target projection's kernel is
//! `shaders/target.wgsl`; the light-tracing estimator's is `shaders/light_tracing.wgsl`
//! ([`TracingGpu`]). Pipelines are built in one place, [`Pipelines`].

use glam::Vec3;
use wgpu::util::DeviceExt;

use crate::backend::Backend;
use crate::trace::bvh::Bvh;
use crate::error::{Error, Result};
use crate::model::lights::{Light, LightGrad};
use crate::scene::{Lighting, Scene, Wrap};
use crate::rows::projection::{self as target, CORNER_FLOATS};
use crate::rows::Rows;
use crate::trace::visibility::Visibility;

mod first_hits;
mod sun;
mod surface;
mod tracing;
pub use tracing::TracingGpu;

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
            let bg = bind_group(d, &layout, "target", &[&ub, &tris_b, &mats_b, &infos_b, &texels_b, &out]);
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

/// The layout of `Row` in `shaders/rows.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuRow {
    pos: [f32; 3],
    pad0: f32,
    normal: [f32; 3],
    /// 1.0 for a two-sided row ([`Rows::facing`]), else 0.0.
    two_sided: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TraceParams {
    n: u32,
    lights: u32,
    words: u32,
    ray_offset: f32,
    inhibit: f32,
    /// 1 when `nodes`/`tris` hold q3map2's pieces ([`crate::trace::pieces`]).
    pieces: u32,
    /// q3map2's `TRACE_ON_EPSILON`, m.
    leaf_eps: f32,
    /// Geometry this close to the light does not shadow it, m.
    end_margin: f32,
}

/// `Bound` of `shaders/shadow.wgsl`: a trace node's half-space and parent.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuBound {
    plane: [f32; 4],
    parent: u32,
    pad: [u32; 3],
}

/// `LightParams` of `shaders/lights.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct LightParams {
    n: u32,
    k: u32,
    words: u32,
    block: u32,
    eps: f32,
    falloff: f32,
    ramp: f32,
    pad: f32,
}

/// Workgroups per block of the gradient's second reduction stage.
const BLOCK: u32 = 256;

struct Pipelines {
    target: wgpu::ComputePipeline,
    trace: wgpu::ComputePipeline,
    irradiance: wgpu::ComputePipeline,
    gradient: wgpu::ComputePipeline,
    reduce: wgpu::ComputePipeline,
    /// The light-tracing estimator's two entry points ([`tracing`]), one layout.
    tracing_irradiance: wgpu::ComputePipeline,
    tracing_gradient: wgpu::ComputePipeline,
    /// The surface lights' basis ([`surface`]).
    surface: wgpu::ComputePipeline,
    /// The sun's visibility ([`sun`]).
    sun: wgpu::ComputePipeline,
    /// The sky light's visibility, both passes ([`sun`]).
    sky: wgpu::ComputePipeline,
    /// First hits of rays set up on the CPU ([`first_hits`]).
    first_hits: wgpu::ComputePipeline,
}

impl Pipelines {
    fn new(device: &wgpu::Device) -> Pipelines {
        let rows = include_str!("../../../shaders/rows.wgsl");
        let bvh = include_str!("../../../shaders/bvh.wgsl");
        let shadow = include_str!("../../../shaders/shadow.wgsl");
        let lights = include_str!("../../../shaders/lights.wgsl");
        let sun_rays = include_str!("../../../shaders/sun_rays.wgsl");
        let make = |label: &str, src: String, entry: &str, layout: Option<&wgpu::PipelineLayout>| {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor { label: Some(label), source: wgpu::ShaderSource::Wgsl(src.into()) });
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout,
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        // The gradient's two entry points share one bind group (each uses only part of
        // it, so the automatic layouts would differ): bindings 0-4 read, 5-6 written.
        let entry = |binding: u32, ty: wgpu::BindingType| wgpu::BindGroupLayoutEntry { binding, visibility: wgpu::ShaderStages::COMPUTE, ty, count: None };
        let storage = |read_only: bool| wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Storage { read_only }, has_dynamic_offset: false, min_binding_size: None };
        let mut gradient_entries = vec![entry(0, wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Uniform, has_dynamic_offset: false, min_binding_size: None })];
        gradient_entries.extend((1..=4).map(|b| entry(b, storage(true))));
        gradient_entries.extend((5..=6).map(|b| entry(b, storage(false))));
        let gradient_group = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("light gradient"), entries: &gradient_entries });
        let gradient_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor { label: Some("light gradient"), bind_group_layouts: &[Some(&gradient_group)], immediate_size: 0 });
        let gradient_src = format!("{rows}\n{}\n{lights}", include_str!("../../../shaders/light_gradient.wgsl"));
        // The estimator: bindings 0 uniform, 1-6 read, 7 written, 8 read, 9 written.
        let mut tracing_entries = vec![entry(0, wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Uniform, has_dynamic_offset: false, min_binding_size: None })];
        tracing_entries.extend((1..=9).map(|b| entry(b, storage(b != 7 && b != 9))));
        let tracing_group = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("light tracing"), entries: &tracing_entries });
        let tracing_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor { label: Some("light tracing"), bind_group_layouts: &[Some(&tracing_group)], immediate_size: 0 });
        let tracing_src = format!("{bvh}\n{}", include_str!("../../../shaders/light_tracing.wgsl"));
        Pipelines {
            tracing_irradiance: make("light tracing irradiance", tracing_src.clone(), "irradiance", Some(&tracing_layout)),
            tracing_gradient: make("light tracing gradient", tracing_src, "gradient", Some(&tracing_layout)),
            target: make("target", include_str!("../../../shaders/target.wgsl").to_string(), "main", None),
            trace: make("trace", format!("{rows}\n{bvh}\n{shadow}\n{}", include_str!("../../../shaders/trace.wgsl")), "main", None),
            surface: make("surface lights", format!("{rows}\n{bvh}\n{shadow}\n{}", include_str!("../../../shaders/surface_lights.wgsl")), "main", None),
            sun: make("sun", format!("{bvh}\n{sun_rays}\n{}", include_str!("../../../shaders/sun.wgsl")), "main", None),
            sky: make("sky", format!("{bvh}\n{shadow}\n{sun_rays}\n{}", include_str!("../../../shaders/sky.wgsl")), "main", None),
            first_hits: make("first hits", format!("{bvh}\n{}", include_str!("../../../shaders/first_hits.wgsl")), "main", None),
            irradiance: make("light irradiance", format!("{rows}\n{}\n{lights}", include_str!("../../../shaders/light_irradiance.wgsl")), "main", None),
            gradient: make("light gradient", gradient_src.clone(), "main", Some(&gradient_layout)),
            reduce: make("light gradient blocks", gradient_src, "reduce_blocks", Some(&gradient_layout)),
        }
    }
}

pub struct GpuBackend {
    ctx: Context,
    n: u32,
    words: u32,
    sampling: crate::rows::Sampling,
    rows: wgpu::Buffer,
    /// The shadow rays' tree: q3map2's pieces where the scene has them, else the mesh's.
    nodes: wgpu::Buffer,
    tris: wgpu::Buffer,
    /// The pieces' leaves (one dummy entry for the mesh's tree).
    bounds: wgpu::Buffer,
    /// The mesh's own tree, whose first hits the sun's rays look for (the same buffers
    /// as `nodes` and `tris` where the scene has no pieces), each of its triangles' index
    /// in the mesh, and its rays' length (`Tree::reach`, m).
    mesh_nodes: wgpu::Buffer,
    mesh_tris: wgpu::Buffer,
    mesh_tri_index: Vec<u32>,
    mesh_reach: f32,
    pieces: Option<f32>,
    /// The device's visibility buffer: `vis_capacity` slots of `words` words each.
    vis: Option<wgpu::Buffer>,
    vis_capacity: usize,
    /// Which slot holds the bits traced from a position to a reach (`vis_key`). The bits
    /// are a function of the two (the rows and the BVH are this backend's), so a light
    /// finds its bits wherever its index went: a pruning try removes lights, renumbering
    /// those after them, and undoes it, and neither uploads anything again.
    slots: std::collections::HashMap<[u32; 4], u32>,
}

/// The key of a light's visibility bits: the position and reach they were traced for.
fn vis_key(at: Vec3, reach: f32) -> [u32; 4] {
    [at.x.to_bits(), at.y.to_bits(), at.z.to_bits(), reach.to_bits()]
}

/// A bind group of whole buffers, bound in order: binding `i` is `buffers[i]`.
pub(crate) fn bind_group(device: &wgpu::Device, layout: &wgpu::BindGroupLayout, label: &str, buffers: &[&wgpu::Buffer]) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers.iter().enumerate().map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() }).collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some(label), layout, entries: &entries })
}

pub(crate) fn storage(device: &wgpu::Device, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    // wgpu refuses zero-sized bindings: pad empty arrays to one element.
    let pad = [0u8; 16];
    let contents = if bytes.is_empty() { &pad[..] } else { bytes };
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST })
}

pub(crate) fn output(device: &wgpu::Device, label: &str, size: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size: size.max(16), usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC, mapped_at_creation: false })
}

/// A dispatch of `groups` workgroups as (x, y) within the 65535 limit per dimension.
fn grid(groups: u32) -> (u32, u32) {
    let gx = groups.clamp(1, MAX_GROUPS);
    (gx, groups.div_ceil(gx).max(1))
}

impl GpuBackend {
    pub fn new(ctx: Context, rows: &Rows, bvh: &Bvh) -> Result<GpuBackend> {
        let d = &ctx.device;
        let gr: Vec<GpuRow> = (0..rows.len()).map(|i| GpuRow { pos: rows.pos[i].to_array(), pad0: 0.0, normal: rows.normal[i].to_array(), two_sided: if rows.two_sided[i] { 1.0 } else { 0.0 } }).collect();
        let max = ctx.max_binding();
        // The shadow rays' tree: q3map2's pieces where the scene carries them.
        let (shadow, bounds): (&crate::trace::tree::Tree, Vec<GpuBound>) = match &bvh.shadow {
            Some(s) => (&s.tree, s.bound.iter().zip(&s.parent).map(|(b, &parent)| GpuBound { plane: *b, parent, pad: [0; 3] }).collect()),
            None => (&bvh.tree, vec![GpuBound { plane: [0.0; 4], parent: crate::trace::pieces::NO_PARENT, pad: [0; 3] }]),
        };
        let tri_bytes = shadow.tris.len().max(bvh.tree.tris.len()) * std::mem::size_of::<crate::trace::bvh::Tri>();
        if gr.len() * std::mem::size_of::<GpuRow>() > max || tri_bytes > max || bounds.len() * std::mem::size_of::<GpuBound>() > max {
            return Err(Error::Gpu(format!("the rows or the BVH exceed the adapter's storage binding limit of {max} bytes")));
        }
        let nodes = storage(d, "nodes", bytemuck::cast_slice(&shadow.nodes));
        let tris = storage(d, "tris", bytemuck::cast_slice(&shadow.tris));
        let (mesh_nodes, mesh_tris) = match &bvh.shadow {
            Some(_) => (storage(d, "mesh nodes", bytemuck::cast_slice(&bvh.tree.nodes)), storage(d, "mesh tris", bytemuck::cast_slice(&bvh.tree.tris))),
            None => (nodes.clone(), tris.clone()),
        };
        Ok(GpuBackend {
            rows: storage(d, "rows", bytemuck::cast_slice(&gr)),
            nodes,
            tris,
            mesh_nodes,
            mesh_tris,
            mesh_tri_index: bvh.tree.tri_index.clone(),
            mesh_reach: bvh.tree.reach(),
            bounds: storage(d, "bounds", bytemuck::cast_slice(&bounds)),
            pieces: bvh.shadow.as_ref().map(|s| s.leaf_epsilon_m),
            n: rows.len() as u32,
            words: rows.len().div_ceil(32).max(1) as u32,
            sampling: rows.sampling,
            vis: None,
            vis_capacity: 0,
            slots: std::collections::HashMap::new(),
            ctx,
        })
    }

    fn try_trace(&mut self, lights: &[(Vec3, f32)]) -> Result<Vec<Vec<u32>>> {
        let d = &self.ctx.device;
        let mut out = Vec::with_capacity(lights.len());
        // Batches bounded by the second dispatch dimension.
        for batch in lights.chunks(MAX_GROUPS as usize) {
            // xyz: the position; w: the reach (a finite stand-in for no limit).
            let pos: Vec<[f32; 4]> = batch.iter().map(|(p, r)| p.extend(r.min(f32::MAX)).to_array()).collect();
            let lb = storage(d, "light_pos", bytemuck::cast_slice(&pos));
            let size = (batch.len() * self.words as usize * 4) as u64;
            // wgpu zero-initialises new buffers: every bit starts cleared.
            let bits = output(d, "bits", size);
            let params = TraceParams { n: self.n, lights: batch.len() as u32, words: self.words, ray_offset: self.sampling.shadow_offset, inhibit: self.sampling.inhibit, pieces: self.pieces.is_some() as u32, leaf_eps: self.pieces.unwrap_or(0.0), end_margin: self.sampling.ray_offset };
            let ub = d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("trace params"), contents: bytemuck::bytes_of(&params), usage: wgpu::BufferUsages::UNIFORM });
            let layout = self.ctx.pipes.trace.get_bind_group_layout(0);
            let bg = bind_group(d, &layout, "trace", &[&ub, &self.rows, &self.nodes, &self.tris, &lb, &bits, &self.bounds]);
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

    /// Brings the visibility of the `k` lights onto the device: each light's bits in a
    /// slot of their own, uploaded when no slot holds them yet. Returns each light's slot.
    /// Slots no light needs now are reused when the buffer is full; it grows (to twice the
    /// lights, within the adapter's binding limit) when the lights alone fill it.
    fn upload_visibility(&mut self, vis: &Visibility, k: usize) -> Result<Vec<u32>> {
        let d = &self.ctx.device;
        let wbytes = self.words as usize * 4;
        let keys: Vec<[u32; 4]> = (0..k).map(|j| vis_key(vis.traced_at[j], vis.traced_reach[j])).collect();
        let needed: std::collections::HashSet<[u32; 4]> = keys.iter().copied().collect();
        let missing = needed.iter().filter(|key| !self.slots.contains_key(*key)).count();
        if self.vis.is_none() || self.slots.len() + missing > self.vis_capacity {
            self.slots.retain(|key, _| needed.contains(key));
        }
        if self.vis.is_none() || needed.len() > self.vis_capacity {
            let max = self.ctx.max_binding() / wbytes.max(1);
            if needed.len().max(1) > max {
                return Err(Error::Gpu(format!("the visibility of {k} lights exceeds the adapter's storage binding limit")));
            }
            let cap = (2 * needed.len()).max(1).next_power_of_two().min(max);
            self.vis = Some(d.create_buffer(&wgpu::BufferDescriptor { label: Some("vis"), size: (cap * wbytes) as u64, usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST, mapped_at_creation: false }));
            self.vis_capacity = cap;
            self.slots.clear();
        }
        let vbuf = self.vis.as_ref().expect("allocated above");
        let mut used = vec![false; self.vis_capacity];
        self.slots.values().for_each(|&s| used[s as usize] = true);
        let mut free = (0..self.vis_capacity as u32).filter(|&s| !used[s as usize]);
        let mut out = Vec::with_capacity(k);
        for (j, key) in keys.iter().enumerate() {
            let slot = match self.slots.get(key) {
                Some(&s) => s,
                None => {
                    let s = free.next().ok_or_else(|| Error::Gpu("the visibility buffer has no free slot".into()))?;
                    self.ctx.queue.write_buffer(vbuf, (s as usize * wbytes) as u64, bytemuck::cast_slice(&vis.bits[j]));
                    self.slots.insert(*key, s);
                    s
                }
            };
            out.push(slot);
        }
        Ok(out)
    }

    fn params(&self, k: usize) -> LightParams {
        LightParams { n: self.n, k: k as u32, words: self.words, block: BLOCK, eps: self.sampling.eps, falloff: self.sampling.falloff, ramp: self.sampling.spot_ramp, pad: 0.0 }
    }

    /// The lights as the kernels read them (`shaders/lights.wgsl`), each with the slot of
    /// its visibility bits.
    fn light_buffer(&self, lights: &[Light], slots: &[u32]) -> wgpu::Buffer {
        let mut lb: Vec<[f32; 4]> = Vec::with_capacity(3 * lights.len());
        for (l, &slot) in lights.iter().zip(slots) {
            let (flag, axis, rbd) = match &l.spot {
                Some(s) => (1.0, s.axis, s.radius_by_dist),
                None => (0.0, Vec3::ZERO, 0.0),
            };
            lb.push(l.pos.extend(flag).to_array());
            lb.push([l.rgb[0], l.rgb[1], l.rgb[2], rbd]);
            // The slot as a float: exact below 2^24 slots, far beyond any binding limit.
            lb.push(axis.extend(slot as f32).to_array());
        }
        storage(&self.ctx.device, "lights", bytemuck::cast_slice(&lb))
    }

    fn try_irradiance(&mut self, vis: &Visibility, lights: &[Light]) -> Result<Vec<[f32; 3]>> {
        let k = lights.len();
        let slots = self.upload_visibility(vis, k)?;
        let d = &self.ctx.device;
        let lbuf = self.light_buffer(lights, &slots);
        let size = self.n as u64 * 16;
        let out = output(d, "irradiance", size);
        let ub = d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("light params"), contents: bytemuck::bytes_of(&self.params(k)), usage: wgpu::BufferUsages::UNIFORM });
        let layout = self.ctx.pipes.irradiance.get_bind_group_layout(0);
        let bg = bind_group(d, &layout, "light irradiance", &[&ub, &self.rows, &lbuf, self.vis.as_ref().expect("uploaded"), &out]);
        let mut enc = d.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.ctx.pipes.irradiance);
            pass.set_bind_group(0, &bg, &[]);
            let (gx, gy) = grid(self.n.div_ceil(WG));
            pass.dispatch_workgroups(gx, gy, 1);
        }
        let data = self.ctx.read_back(&out, size, enc)?;
        let v: &[[f32; 4]] = bytemuck::cast_slice(&data);
        Ok(v.iter().take(self.n as usize).map(|e| [e[0], e[1], e[2]]).collect())
    }

    fn try_gradient(&mut self, vis: &Visibility, lights: &[Light], rho: &[[f32; 3]]) -> Result<Vec<LightGrad>> {
        let k = lights.len();
        let slots = self.upload_visibility(vis, k)?;
        let d = &self.ctx.device;
        let lbuf = self.light_buffer(lights, &slots);
        let rho4: Vec<[f32; 4]> = rho.iter().map(|r| [r[0], r[1], r[2], 0.0]).collect();
        let rbuf = storage(d, "rho", bytemuck::cast_slice(&rho4));
        let groups = self.n.div_ceil(WG).max(1);
        let per = k as u64 * 12;
        let psize = groups as u64 * per * 4;
        let nblocks = groups.div_ceil(BLOCK) as u64;
        let bsize = nblocks * per * 4;
        if psize > self.ctx.max_binding() as u64 {
            return Err(Error::Gpu(format!("the gradient's partial sums ({} MB) exceed the adapter's storage binding limit", psize >> 20)));
        }
        let partial = output(d, "partial", psize);
        let blocks = output(d, "blocks", bsize);
        let ub = d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("light params"), contents: bytemuck::bytes_of(&self.params(k)), usage: wgpu::BufferUsages::UNIFORM });
        // Both entry points share one layout (`Pipelines::new`), so one bind group.
        let bg = bind_group(d, &self.ctx.pipes.gradient.get_bind_group_layout(0), "light gradient", &[&ub, &self.rows, &lbuf, self.vis.as_ref().expect("uploaded"), &rbuf, &partial, &blocks]);
        let mut enc = d.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.ctx.pipes.gradient);
            pass.set_bind_group(0, &bg, &[]);
            let (gx, gy) = grid(groups);
            pass.dispatch_workgroups(gx, gy, 1);
            pass.set_pipeline(&self.ctx.pipes.reduce);
            pass.set_bind_group(0, &bg, &[]);
            let (gx, gy) = grid((nblocks * per).div_ceil(WG as u64) as u32);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        let data = self.ctx.read_back(&blocks, bsize, enc)?;
        let b: &[f32] = bytemuck::cast_slice(&data);
        let mut out = vec![LightGrad::default(); k];
        for blk in 0..nblocks as usize {
            for (j, g) in out.iter_mut().enumerate() {
                let o = blk * per as usize + j * 12;
                let v = |q: usize| b[o + q] as f64;
                g.add(&LightGrad { pos: [v(0), v(1), v(2)], rgb: [v(3), v(4), v(5)], axis: [v(6), v(7), v(8)], radius_by_dist: v(9) });
            }
        }
        Ok(out)
    }
}

impl Backend for GpuBackend {
    fn name(&self) -> String {
        format!("wgpu ({}, {})", self.ctx.info.name, self.ctx.info.backend)
    }
    fn trace(&mut self, lights: &[(Vec3, f32)]) -> Result<Vec<Vec<u32>>> {
        self.try_trace(lights)
    }
    fn irradiance(&mut self, vis: &Visibility, lights: &[Light]) -> Result<Vec<[f32; 3]>> {
        self.try_irradiance(vis, lights)
    }
    fn gradient(&mut self, vis: &Visibility, lights: &[Light], rho: &[[f32; 3]]) -> Result<Vec<LightGrad>> {
        self.try_gradient(vis, lights, rho)
    }
    fn surface_sums(&mut self, request: &crate::model::surface::Request) -> Option<Result<crate::model::surface::Sums>> {
        Some(self.try_surface_sums(request))
    }
    fn sun_bits(&mut self, rows: &Rows, dirs: &[Vec3], sky: &[bool]) -> Option<Result<Vec<Vec<u32>>>> {
        Some(self.try_sun_bits(rows, dirs, sky))
    }
    fn sky_bits(&mut self, rows: &Rows, dirs: &[Vec3], sky: &[bool]) -> Option<Result<Vec<Vec<u32>>>> {
        Some(self.try_sky_bits(rows, dirs, sky))
    }
    fn first_hits(&mut self, rays: &[crate::trace::tree::PlaneRay]) -> Option<Result<Vec<crate::backend::FirstHit>>> {
        Some(self.try_first_hits(rays))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Spot;
    use crate::testutil::room;

    /// The wgpu kernels agree with the CPU reference: visibility bits exactly; the
    /// lights' irradiance and gradients (points and a spot, with the falloff cut) within
    /// 1e-4 relative. Needs a wgpu adapter: CI has Mesa's lavapipe.
    #[test]
    fn wgpu_agrees_with_cpu() {
        let (mut mesh, mut rows) = room(8);
        // A pillar in the middle so that some shadow rays are blocked.
        crate::testutil::push_quad(&mut mesh, [[1.8, 0.0, 1.3], [2.2, 0.0, 1.3], [2.2, 2.5, 1.3], [1.8, 2.5, 1.3]], Vec3::Z);
        rows.sampling.falloff = 0.02;
        rows.sampling.inhibit = 0.01;
        // A third of the rows two-sided: the fourth light, outside the room, reaches those
        // of the wall it stands behind.
        rows.two_sided = (0..rows.len()).map(|i| i % 3 == 0).collect();
        let bvh = Bvh::build(&mesh);
        let lights = vec![
            Light::point(Vec3::new(2.0, 1.2, 0.5), [2.0, 1.5, 1.0]),
            Light::point(Vec3::new(3.1, 2.0, 2.4), [0.7, 1.2, 1.9]),
            Light { pos: Vec3::new(0.6, 2.2, 2.7), rgb: [1.0, 1.0, 1.0], spot: Some(Spot { axis: Vec3::new(0.3, -1.0, -0.2).normalize(), radius_by_dist: 0.8 }) },
            Light::point(Vec3::new(-0.6, 1.3, 1.4), [1.2, 1.0, 0.8]),
        ];
        let mut gpu = GpuBackend::new(Context::new().expect("a wgpu adapter (install mesa-vulkan-drivers)"), &rows, &bvh).expect("a wgpu adapter (install mesa-vulkan-drivers)");
        // The third light traced only to 2.5 m: farther rows have no bit.
        let positions: Vec<(Vec3, f32)> = lights.iter().enumerate().map(|(j, l)| (l.pos, if j == 2 { 2.5 } else { f32::INFINITY })).collect();
        let g_bits = gpu.trace(&positions).unwrap();
        let c_bits: Vec<Vec<u32>> = positions.iter().map(|&(p, r)| crate::trace::visibility::trace_light(&bvh, &rows, p, r)).collect();
        assert_eq!(g_bits, c_bits, "visibility bits differ");
        let blocked = c_bits[0].iter().map(|w| w.count_zeros()).sum::<u32>();
        assert!(blocked > 0, "the pillar casts a shadow");
        assert!(c_bits[3].iter().any(|w| *w != 0), "the light outside reaches the two-sided rows behind it");
        let mut vis = Visibility::default();
        vis.update(&crate::model::lights::sources(&lights), 0.0, &rows.sampling, rows.len(), &mut |p| Ok(p.iter().map(|&(q, r)| crate::trace::visibility::trace_light(&bvh, &rows, q, r)).collect())).unwrap();
        let mut cpu = crate::backend::Cpu::new(&rows, &bvh);
        let (ce, ge) = (cpu.irradiance(&vis, &lights).unwrap(), gpu.irradiance(&vis, &lights).unwrap());
        let scale = ce.iter().flat_map(|e| e.iter()).copied().fold(0.0f32, f32::max);
        assert!(scale > 0.0);
        for (a, b) in ce.iter().zip(&ge) {
            for c in 0..3 {
                assert!((a[c] - b[c]).abs() <= 1e-4 * scale, "irradiance {a:?} vs {b:?}");
            }
        }
        let rho: Vec<[f32; 3]> = (0..rows.len()).map(|i| [0.3 - 0.01 * (i % 50) as f32, 0.2, -0.1 + 0.005 * (i % 40) as f32]).collect();
        let (cg, gg) = (cpu.gradient(&vis, &lights, &rho).unwrap(), gpu.gradient(&vis, &lights, &rho).unwrap());
        for j in 0..lights.len() {
            let flat = |g: &LightGrad| [g.pos, g.rgb, g.axis].concat().into_iter().chain([g.radius_by_dist]).collect::<Vec<f64>>();
            let (a, b) = (flat(&cg[j]), flat(&gg[j]));
            let scale = a.iter().map(|v| v.abs()).fold(0.0, f64::max);
            assert!(scale > 0.0);
            for q in 0..a.len() {
                assert!((a[q] - b[q]).abs() <= 1e-4 * scale, "light {j} gradient {q}: cpu {} wgpu {}", a[q], b[q]);
            }
        }
        assert!(cg[2].axis.iter().any(|v| *v != 0.0) && cg[2].radius_by_dist != 0.0, "the spot's cone has a gradient");
    }

    /// The device's visibility follows the lights as a fit changes them: a light removed
    /// (the later ones renumbered) and put back, as a pruning try does and undoes, and a
    /// light traced again at the same position to a longer reach (it brightened). The
    /// irradiance agrees with the CPU's after each. Before the slots were keyed by
    /// position and reach, the last step kept the short reach's bits on the device.
    /// With q3map2's pieces (a scene's `q3_casters`), the device tests the pieces as the
    /// CPU does: the slack, the coplanar rule and the leaf test give the same bits.
    #[test]
    fn wgpu_traces_q3map2_pieces_as_the_cpu_does() {
        let (mut mesh, rows) = room(8);
        crate::testutil::push_quad(&mut mesh, [[1.8, 0.0, 1.3], [2.2, 0.0, 1.3], [2.2, 2.5, 1.3], [1.8, 2.5, 1.3]], Vec3::Z);
        let mut rows = rows;
        rows.sampling.inhibit = 0.01;
        rows.sampling.shadow_offset = 0.0;
        // The casters in Quake units, a tree of two planes through the room (x = 40, then
        // z = 30 on its front side).
        let c = crate::testutil::casters_of(&mesh, 40.0, 30.0);
        let mut bvh = Bvh::build(&mesh);
        bvh.shadow = Some(Box::new(crate::trace::pieces::Shadow::new(&c, glam::DVec3::ZERO, q3gltf_convert::units::DEFAULT_SCALE)));
        let positions: Vec<(Vec3, f32)> = vec![(Vec3::new(2.0, 1.2, 0.5), f32::INFINITY), (Vec3::new(3.1, 2.0, 2.4), f32::INFINITY), (Vec3::new(0.6, 2.2, 2.7), 2.5)];
        let mut gpu = GpuBackend::new(Context::new().expect("a wgpu adapter (install mesa-vulkan-drivers)"), &rows, &bvh).expect("a wgpu adapter");
        let g_bits = gpu.trace(&positions).unwrap();
        let c_bits: Vec<Vec<u32>> = positions.iter().map(|&(p, r)| crate::trace::visibility::trace_light(&bvh, &rows, p, r)).collect();
        assert_eq!(g_bits, c_bits, "visibility bits differ");
        assert!(c_bits[0].iter().map(|w| w.count_zeros()).sum::<u32>() > 0, "the pillar casts a shadow");
    }

    /// The dirt's walks on the device (`first_hits.wgsl`) are the CPU's: a room with a
    /// pillar, at each of the three depths the data chooses from (in metres a room this
    /// size has them all within reach), rows on walls' planes with their solid ahead:
    /// all but a few rows' factors the CPU's to the bit, and dirt where walls meet.
    #[test]
    fn wgpu_walks_the_dirt_as_the_cpu_does() {
        use crate::model::compile::{dirt, neighbours, DIRT_DEPTHS_UNITS};
        let (mut mesh, mut rows) = room(10);
        crate::testutil::push_quad(&mut mesh, [[1.8, 0.0, 1.3], [2.2, 0.0, 1.3], [2.2, 2.5, 1.3], [1.8, 2.5, 1.3]], Vec3::Z);
        rows.sampling.on_epsilon = 0.001;
        rows.solid_ahead = (0..rows.len()).map(|i| crate::rows::SolidAhead((i % 8) as u8)).collect();
        let bvh = Bvh::build(&mesh);
        let nb = neighbours(&rows);
        // Quake units of 2 cm: depths of 0.64, 1.28 and 2.56 m.
        let sets: Vec<crate::scene::DirtSettings> = DIRT_DEPTHS_UNITS.iter().map(|&d| crate::scene::DirtSettings { depth_units: d, ..crate::scene::DirtSettings::Q3MAP2 }).collect();
        let cpu = dirt(&rows, &bvh, &nb, &sets, 0.02, &mut crate::backend::Cpu::new(&rows, &bvh)).unwrap();
        let mut gpu_backend = GpuBackend::new(Context::new().expect("a wgpu adapter (install mesa-vulkan-drivers)"), &rows, &bvh).expect("a wgpu adapter (install mesa-vulkan-drivers)");
        let gpu = dirt(&rows, &bvh, &nb, &sets, 0.02, &mut gpu_backend).unwrap();
        assert_eq!(cpu.len(), 3);
        for (c, g) in cpu.iter().zip(&gpu) {
            assert_eq!(c.settings, g.settings);
            let differ = (0..rows.len()).filter(|&i| c.factor[i].to_bits() != g.factor[i].to_bits()).count();
            // The rows here are the mesh's vertices, so many of their rays run along a
            // wall's plane through its triangles' shared edges, where a device's rounding
            // (division, fused products) may take a hit the CPU's misses: 8 of the 726
            // rows differ at the shortest depth on lavapipe, 18 at the middle one, by up to
            // 0.02.
            let worst = (0..rows.len()).map(|i| (c.factor[i] - g.factor[i]).abs()).fold(0.0f32, f32::max);
            assert!(differ * 20 <= rows.len() && worst < 0.05, "depth {} units: {differ} of {} rows differ, by up to {worst}", c.settings.depth_units, rows.len());
            let dark = c.factor.iter().filter(|&&f| f < 0.99).count();
            assert!(dark > 10, "depth {} units: {dark} of {} rows darkened", c.settings.depth_units, rows.len());
        }
    }

    /// The device's first hits (`first_hits.wgsl`) are the CPU's walks (`Tree::first_hit_of`):
    /// the bounce's cosine-weighted rays from every row of a room with a pillar, both
    /// hemispheres, 64 a hemisphere, starting on the rows' planes. The rows are the mesh's
    /// vertices, on the triangles' shared edges, where a device's rounding may decide a
    /// grazing ray otherwise: nearly every ray hits the same triangle at the same distance.
    #[test]
    fn wgpu_walks_first_hits_as_the_cpu_does() {
        use crate::trace::tree::PlaneRay;
        let (mut mesh, rows) = room(8);
        crate::testutil::push_quad(&mut mesh, [[1.8, 0.0, 1.3], [2.2, 0.0, 1.3], [2.2, 2.5, 1.3], [1.8, 2.5, 1.3]], Vec3::Z);
        let bvh = Bvh::build(&mesh);
        let rays: Vec<PlaneRay> = (0..rows.len())
            .flat_map(|i| [1.0f32, -1.0].into_iter().flat_map(move |side| (0..64).map(move |cell| (i, side, cell))))
            .map(|(i, side, cell)| {
                let n = rows.normal[i] * side;
                PlaneRay::new(rows.pos[i] + n * rows.sampling.ray_offset, crate::model::bounce::cosine_direction(n, i as u32, cell, 8), 10.0)
            })
            .collect();
        let mut gpu = GpuBackend::new(Context::new().expect("a wgpu adapter (install mesa-vulkan-drivers)"), &rows, &bvh).expect("a wgpu adapter (install mesa-vulkan-drivers)");
        let got = gpu.first_hits(&rays).expect("wgpu has a kernel").unwrap();
        assert_eq!(got.len(), rays.len());
        let want: Vec<Option<(f32, u32)>> = rays.iter().map(|r| bvh.first_hit_of(r)).collect();
        let hits = want.iter().filter(|h| h.is_some()).count();
        // The back hemispheres of the walls look out of the room: about half the rays.
        assert!(hits * 3 > rays.len(), "{hits} of {} rays hit", rays.len());
        let differ = got.iter().zip(&want).filter(|(g, w)| g != w).count();
        assert!(differ * 100 <= rays.len(), "{differ} of {} rays differ", rays.len());
        // The CPU's fallback is the CPU's walks.
        let cpu = crate::backend::first_hits(&mut crate::backend::Cpu::new(&rows, &bvh), &bvh, &rays).unwrap();
        assert_eq!(cpu, want);
    }

    /// The sun's visibility on the device is the CPU's (`trace_sun`) bit for bit: a room
    /// whose ceiling is sky, a pillar that shadows the floor, a third of the rows
    /// two-sided, rows standing on planes with their solid ahead; suns straight overhead
    /// (the ray along two axes), along a wall, low, below the horizon; rows other than the
    /// backend's (a subsample, as the sun search scores); and the open scene, without sky.
    #[test]
    fn wgpu_traces_the_sun_as_the_cpu_does() {
        let (mut mesh, mut rows) = room(8);
        crate::testutil::push_quad(&mut mesh, [[1.8, 0.0, 1.3], [2.2, 0.0, 1.3], [2.2, 2.5, 1.3], [1.8, 2.5, 1.3]], Vec3::Z);
        rows.sampling.inhibit = 0.01;
        rows.sampling.on_epsilon = 0.001;
        rows.two_sided = (0..rows.len()).map(|i| i % 3 == 0).collect();
        rows.solid_ahead = (0..rows.len()).map(|i| crate::rows::SolidAhead((i % 8) as u8)).collect();
        let bvh = Bvh::build(&mesh);
        let sky: Vec<bool> = mesh.triangles.iter().map(|t| t.iter().all(|&v| mesh.positions[v as usize].y == 2.5)).collect();
        assert!(sky.iter().any(|&k| k) && !sky.iter().all(|&k| k));
        let dirs = [
            Vec3::Y,
            Vec3::new(0.0, 0.8, 0.6),
            Vec3::new(0.3, 0.9, -0.2).normalize(),
            Vec3::new(-0.5, 0.7, 0.4).normalize(),
            Vec3::new(0.9, 0.1, 0.3).normalize(),
            Vec3::new(0.2, -0.9, 0.1).normalize(),
        ];
        let mut gpu = GpuBackend::new(Context::new().expect("a wgpu adapter (install mesa-vulkan-drivers)"), &rows, &bvh).expect("a wgpu adapter (install mesa-vulkan-drivers)");
        let (sub, _) = rows.subsample(200, 3);
        for (what, r) in [("rows", &rows), ("subsample", &sub)] {
            for open in [false, true] {
                let sky = if open { vec![false; sky.len()] } else { sky.clone() };
                let got = gpu.sun_bits(r, &dirs, &sky).expect("wgpu has a kernel").unwrap();
                assert_eq!(got.len(), dirs.len());
                let mut seen = 0;
                for (k, &w) in dirs.iter().enumerate() {
                    let want = crate::trace::visibility::trace_sun(&bvh, r, w, &sky);
                    assert_eq!(got[k], want, "{what}, open {open}, sun {w}");
                    seen += want.iter().map(|b| b.count_ones()).sum::<u32>();
                }
                // Some rows see the sun, and (with the sky) the pillar and the walls stop some.
                assert!(seen > 0, "{what}, open {open}: no row sees any sun");
            }
        }
        // The overhead sun's shadow of the pillar is there.
        let up = gpu.sun_bits(&rows, &[Vec3::Y], &sky).unwrap().unwrap();
        let floor_lit = (0..rows.len()).filter(|&i| rows.normal[i].y > 0.9 && rows.pos[i].y < 0.01).filter(|&i| up[0][i / 32] >> (i % 32) & 1 == 1).count();
        let floor = (0..rows.len()).filter(|&i| rows.normal[i].y > 0.9 && rows.pos[i].y < 0.01).count();
        assert!(floor_lit > 0 && floor_lit < floor, "{floor_lit} of {floor} floor rows lit by the overhead sun");
    }

    /// The sky light's visibility on the device is the CPU's (`sky_visible_from`) bit for
    /// bit, and so the basis: a room whose ceiling is sky over half its width, a pillar
    /// that shadows the floor, an opaque slab above the sky (a ray that crosses the sky
    /// and then meets it is stopped, as q3map2 traces the whole way), a third of the rows
    /// two-sided, rows standing on planes with their solid ahead; q3map2's sky suns (the
    /// first of each ring and the last, straight up, along axes) and a sun along a wall;
    /// through the mesh's tree and through q3map2's pieces; and the open scene.
    #[test]
    fn wgpu_traces_the_sky_as_the_cpu_does() {
        use crate::trace::bvh::Occluder;
        let (mut mesh, mut rows) = room(8);
        crate::testutil::push_quad(&mut mesh, [[1.8, 0.0, 1.3], [2.2, 0.0, 1.3], [2.2, 2.5, 1.3], [1.8, 2.5, 1.3]], Vec3::Z);
        crate::testutil::push_quad(&mut mesh, [[0.5, 3.0, 0.5], [1.5, 3.0, 0.5], [1.5, 3.0, 2.5], [0.5, 3.0, 2.5]], -Vec3::Y);
        rows.sampling.inhibit = 0.01;
        rows.sampling.on_epsilon = 0.001;
        rows.two_sided = (0..rows.len()).map(|i| i % 3 == 0).collect();
        rows.solid_ahead = (0..rows.len()).map(|i| crate::rows::SolidAhead((i % 8) as u8)).collect();
        let sky: Vec<bool> = mesh.triangles.iter().map(|t| t.iter().all(|&v| mesh.positions[v as usize].y == 2.5 && mesh.positions[v as usize].x <= 2.0)).collect();
        assert!(sky.iter().any(|&k| k) && !sky.iter().all(|&k| k));
        let mut dirs = crate::model::sky::directions(4);
        assert!(dirs.iter().any(|w| w.x == 0.0 && w.z == 0.0), "q3map2's sky suns end straight up");
        dirs.push(Vec3::new(0.0, 0.8, 0.6));
        for pieces in [false, true] {
            let mut bvh = Bvh::build(&mesh);
            if pieces {
                // q3map2's pieces of the opaque surfaces (the sky is not one).
                let mut opaque = mesh.clone();
                opaque.triangles = mesh.triangles.iter().zip(&sky).filter(|(_, &k)| !k).map(|(t, _)| *t).collect();
                let c = crate::testutil::casters_of(&opaque, 40.0, 30.0);
                bvh.shadow = Some(Box::new(crate::trace::pieces::Shadow::new(&c, glam::DVec3::ZERO, q3gltf_convert::units::DEFAULT_SCALE)));
            }
            let mut gpu = GpuBackend::new(Context::new().expect("a wgpu adapter (install mesa-vulkan-drivers)"), &rows, &bvh).expect("a wgpu adapter (install mesa-vulkan-drivers)");
            for open in [false, true] {
                let what = format!("pieces {pieces}, open {open}");
                let sky = if open { vec![false; sky.len()] } else { sky.clone() };
                let got = gpu.sky_bits(&rows, &dirs, &sky).expect("wgpu has a kernel").unwrap();
                assert_eq!(got.len(), dirs.len());
                let (mut seen, mut stopped) = (0, 0);
                for (k, &w) in dirs.iter().enumerate() {
                    for i in 0..rows.len() {
                        let n = rows.facing(i, w);
                        let want = crate::trace::visibility::sky_visible_from(&bvh, rows.pos[i], n, w, &rows.sampling, &sky, open, rows.solid_ahead[i], &mut [&mut Occluder::default()], &mut Occluder::default());
                        assert_eq!(got[k][i / 32] >> (i % 32) & 1 == 1, want, "{what}, sun {w}, row {i} at {}", rows.pos[i]);
                        seen += want as usize;
                        stopped += (!want && n.dot(w) > 0.0) as usize;
                    }
                }
                assert!(seen > 0 && stopped > 0, "{what}: {seen} rays see the sky, {stopped} do not");
                let cpu = crate::model::sky::basis(&rows, &bvh, &sky, &dirs);
                let dev = crate::model::sky::basis_on(&mut gpu, &rows, &bvh, &sky, &dirs).unwrap();
                assert_eq!(cpu.d, dev.d, "{what}");
                assert_eq!(cpu.mean_cos_up, dev.mean_cos_up);
            }
        }
    }

    /// The device builds the surface lights' basis as the CPU does: the same rays (but at
    /// `-fast`'s cut), and every row's sum per group within 1e-4 of the largest, the
    /// patches in several dispatches, through the mesh's tree and
    /// q3map2's pieces, with and without `-fast`. The room holds a two-sided emitter (a
    /// flame, lighting both sides), a one-sided ceiling panel with its backsplash, and a
    /// pillar that shadows both; a third of the rows are two-sided.
    #[test]
    fn wgpu_builds_the_surface_lights_basis_as_the_cpu_does() {
        use crate::model::surface as model;
        use crate::scene::{Emitter, Material};
        let (mut mesh, mut rows) = room(10);
        crate::testutil::push_quad(&mut mesh, [[1.8, 0.0, 1.3], [2.2, 0.0, 1.3], [2.2, 2.0, 1.3], [1.8, 2.0, 1.3]], Vec3::Z);
        let emitting = |mesh: &mut crate::scene::Mesh, corners: [[f32; 3]; 4], normal: Vec3, m: u32| {
            crate::testutil::push_quad(mesh, corners, normal);
            let t = mesh.tri_material.len();
            mesh.tri_material[t - 2..].iter_mut().for_each(|x| *x = m);
        };
        emitting(&mut mesh, [[2.0, 0.75, 0.4], [2.0, 1.75, 0.4], [2.0, 1.75, 1.0], [2.0, 0.75, 1.0]], Vec3::X, 1);
        emitting(&mut mesh, [[1.0, 2.45, 1.6], [3.0, 2.45, 1.6], [3.0, 2.45, 2.6], [1.0, 2.45, 2.6]], -Vec3::Y, 2);
        rows.two_sided = (0..rows.len()).map(|i| i % 3 == 0).collect();
        rows.sampling.inhibit = 0.01;
        let flame = Emitter { value: 2000.0, color: [1.0, 0.6, 0.3], subdivide: 8.0, backsplash: (0.0, 23.0) };
        let panel = Emitter { value: 500.0, color: [0.8, 0.9, 1.0], subdivide: 16.0, backsplash: (0.05, 23.0) };
        let materials = vec![crate::testutil::material("wall"), Material { emitter: Some(flame), double_sided: true, ..crate::testutil::material("flame") }, Material { emitter: Some(panel), ..crate::testutil::material("panel") }];
        let scene = crate::testutil::scene(mesh, materials);
        for pieces in [false, true] {
            let mut bvh = Bvh::build(&scene.mesh);
            if pieces {
                let c = crate::testutil::casters_of(&scene.mesh, 40.0, 30.0);
                bvh.shadow = Some(Box::new(crate::trace::pieces::Shadow::new(&c, glam::DVec3::ZERO, q3gltf_convert::units::DEFAULT_SCALE)));
            }
            let mut gpu = GpuBackend::new(Context::new().expect("a wgpu adapter (install mesa-vulkan-drivers)"), &rows, &bvh).expect("a wgpu adapter");
            for fast in [false, true] {
                let what = format!("pieces {pieces}, fast {fast}");
                let emitters = model::patches(&scene);
                assert_eq!(emitters.0.len(), 2);
                assert!(emitters.1.len() > 2 * surface::PATCH_CHUNK, "{} patches: several dispatches add to the sums", emitters.1.len());
                let cpu = model::basis_from(emitters.clone(), &scene, &rows, &bvh, fast);
                let bytes_per_ff = model::bytes_per_form_factor(&scene, &emitters.0, &emitters.1);
                let request = model::Request { patches: &emitters.1, bytes_per_ff: &bytes_per_ff, groups: 2, units_m: scene.units_m, fast };
                let sums = gpu.surface_sums(&request).expect("wgpu has the kernel").unwrap();
                let emitters_cut = |r: &model::Request| r.patches.iter().zip(r.bytes_per_ff).map(|(p, b)| std::f32::consts::PI * p.weight * crate::scene::q3map2::FALLOFF_TOLERANCE_BYTES / b).fold(0.0f32, f32::max);
                let dev = model::basis_from_sums(emitters.clone(), &sums, rows.len());
                // The f32 form factor decides `-fast`'s cut; at the cut a patch adds at most
                // a byte, and a few rays in ten thousand may fall on the other side.
                assert!(dev.rays.abs_diff(cpu.rays) * 1000 <= cpu.rays, "{what}: rays {} on the device, {} on the CPU", dev.rays, cpu.rays);
                if !fast {
                    assert_eq!(dev.rays, cpu.rays, "{what}: rays");
                }
                let dense = |b: &model::SurfaceBasis| (0..rows.len()).map(|i| (0..2).map(|g| b.row(i).iter().filter(|e| e.0 == g).map(|e| e.1).sum::<f32>()).collect::<Vec<f32>>()).collect::<Vec<_>>();
                let (c, d) = (dense(&cpu), dense(&dev));
                let top = c.iter().flatten().copied().fold(0.0f32, f32::max);
                assert!(top > 0.0, "{what}: the emitters light the room");
                for g in 0..2 {
                    assert!((0..rows.len()).filter(|&i| c[i][g] > 1e-3 * top).count() > 50, "{what}: group {g} lights rows");
                }
                // With `-fast`, a patch whose f32 form factor lands on the other side of the
                // cut adds or misses at most the cut's value, in a few rows.
                let at_cut = emitters_cut(&request);
                let mut off = 0;
                for i in 0..rows.len() {
                    for g in 0..2 {
                        let diff = (c[i][g] - d[i][g]).abs();
                        if diff > 1e-4 * top {
                            off += 1;
                            assert!(fast && diff <= 2.0 * at_cut, "{what}: row {i} group {g}: cpu {} wgpu {}", c[i][g], d[i][g]);
                        }
                    }
                }
                assert!(off * 100 <= rows.len(), "{what}: {off} sums differ at the cut");
            }
        }
    }

    #[test]
    fn wgpu_visibility_follows_removals_undos_and_longer_reaches() {
        let (mut mesh, mut rows) = room(8);
        crate::testutil::push_quad(&mut mesh, [[1.8, 0.0, 1.3], [2.2, 0.0, 1.3], [2.2, 2.5, 1.3], [1.8, 2.5, 1.3]], Vec3::Z);
        rows.sampling.falloff = 0.02;
        let bvh = Bvh::build(&mesh);
        let mut lights: Vec<Light> = [(2.0, 1.2, 0.5), (3.1, 2.0, 2.4), (0.6, 2.2, 2.7), (1.0, 0.8, 1.0), (3.3, 0.7, 0.6)].iter().map(|&(x, y, z)| Light::point(Vec3::new(x, y, z), [1.5, 1.2, 1.0])).collect();
        let trace = |p: &[(Vec3, f32)]| -> crate::error::Result<Vec<Vec<u32>>> { Ok(p.iter().map(|&(q, r)| crate::trace::visibility::trace_light(&bvh, &rows, q, r)).collect()) };
        let mut vis = Visibility::default();
        vis.update(&crate::model::lights::sources(&lights), 0.0, &rows.sampling, rows.len(), &mut |p| trace(p)).unwrap();
        let mut gpu = GpuBackend::new(Context::new().expect("a wgpu adapter (install mesa-vulkan-drivers)"), &rows, &bvh).expect("a wgpu adapter (install mesa-vulkan-drivers)");
        let agree = |gpu: &mut GpuBackend, vis: &Visibility, lights: &[Light], what: &str| {
            let mut cpu = crate::backend::Cpu::new(&rows, &bvh);
            let (ce, ge) = (cpu.irradiance(vis, lights).unwrap(), gpu.irradiance(vis, lights).unwrap());
            let scale = ce.iter().flat_map(|e| e.iter()).copied().fold(0.0f32, f32::max);
            assert!(scale > 0.0);
            for (i, (a, b)) in ce.iter().zip(&ge).enumerate() {
                for c in 0..3 {
                    assert!((a[c] - b[c]).abs() <= 1e-4 * scale, "{what}: row {i}, cpu {a:?}, wgpu {b:?}");
                }
            }
        };
        agree(&mut gpu, &vis, &lights, "as traced");
        let saved = (lights.clone(), vis.clone());
        lights.remove(1);
        vis.remove(1);
        agree(&mut gpu, &vis, &lights, "the second light removed");
        (lights, vis) = saved;
        agree(&mut gpu, &vis, &lights, "put back");
        // The first light traced again where it stands, to 0.8 m and then to no limit.
        for reach in [0.8f32, f32::INFINITY] {
            vis.set_traced(0, crate::trace::visibility::trace_light(&bvh, &rows, lights[0].pos, reach), lights[0].pos, reach);
            agree(&mut gpu, &vis, &lights, &format!("the first light traced to {reach} m"));
        }
    }
}
