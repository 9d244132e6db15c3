//! The scene relight works on: one flat triangle mesh in world space (meters, glTF axes),
//! its materials and textures, and the point lights the input already had.
//!
//! Positions are stored relative to `Scene::origin` (the centre of the mesh's bounding
//! box, computed in f64): a map placed kilometres from the origin keeps f32 precision in
//! every kernel, and lights go back to world space only when they are written.
//!
//! Invariants (established by `gltf_in`, kept by `subdivide`):
//! - every array indexed by vertex has `positions.len()` entries; every triangle index is
//!   in range; `tri_material[t]` indexes `materials`; `tri_source` has one entry per
//!   triangle;
//! - normals are unit length (a vertex without a usable normal gets its face normal);
//! - `weld[v]` is the same for vertices whose positions are bit-identical, so edges can be
//!   matched across primitives.

use glam::{Vec2, Vec3};

/// How a material's baked lighting is stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Lighting {
    /// A lightmap atlas on TEXCOORD_1 (the material's `occlusionTexture`).
    Lightmap,
    /// q3map2's per-vertex lighting in COLOR_0.
    Vertex,
    /// No baked lighting: the surface blocks and reflects light but carries no target.
    None,
}

/// How a texture repeats outside [0, 1].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Wrap {
    Repeat,
    Clamp,
    Mirror,
}

/// An 8-bit RGBA image as stored in the file (no colour decoding applied).
#[derive(Debug, Clone)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    /// `width * height` texels, row-major, top row first (glTF's UV origin is top-left).
    pub rgba8: Vec<u8>,
    pub wrap_s: Wrap,
    pub wrap_t: Wrap,
}

#[derive(Debug, Clone)]
pub struct Material {
    pub name: String,
    /// Base colour texture (sRGB encoded) on TEXCOORD_0.
    pub albedo: Option<usize>,
    /// Base colour factor, linear.
    pub albedo_factor: [f32; 4],
    pub lighting: Lighting,
    /// The lightmap atlas on TEXCOORD_1 (linear bytes, see `overbright_bits`).
    pub lightmap: Option<usize>,
    /// Lightmap and vertex-colour decoding: `e = (byte/255)^gamma * 2^overbright_bits`.
    pub overbright_bits: u32,
    pub lightmap_gamma: f32,
    /// A sky surface: sunlight passes it (the sun is behind it), it carries no target.
    pub sky: bool,
    /// Both sides face outward (glTF `doubleSided`, q3 `cull none`).
    pub double_sided: bool,
    /// Blocks light (q3map2: translucent surfaces without `alphashadow`/`lightfilter`
    /// cast no shadow). From extras `q3_casts_shadow`; without them, `BLEND` materials
    /// are taken as translucent.
    pub casts_shadow: bool,
    /// q3map2 surface light of this material's shader.
    pub emitter: Option<Emitter>,
    /// `q3map_skyLight` value, iterations and colour (largest channel 1; sky materials).
    pub sky_lights: Vec<(f32, u32, [f32; 3])>,
    /// The file's own emission: `emissiveFactor x emissiveStrength`, W/(m^2 sr) (what a
    /// renderer shows; the probe uses it).
    pub emission: [f32; 3],
}

impl Material {
    /// Linear value `e` (irradiance / pi, 1 = texture at full brightness) of a stored
    /// value `v = byte / 255` read back from filtered data (bilinear lookups, the gather):
    /// the middle of the byte's interval (see [`Material::interval`]).
    pub fn decode(&self, v: f32) -> f32 {
        self.decode_exact((v.clamp(0.0, 1.0) + HALF_BYTE).min(1.0))
    }

    /// `e` of the exact stored fraction `v` (`(v)^gamma 2^overbright`).
    pub fn decode_exact(&self, v: f32) -> f32 {
        let v = v.clamp(0.0, 1.0);
        let v = if self.lightmap_gamma == 1.0 { v } else { v.powf(self.lightmap_gamma) };
        v * (1u32 << self.overbright_bits.min(8)) as f32
    }

    /// The interval of `e` a stored byte stands for: q3map2 truncates a luxel's float
    /// value to a byte (a C conversion), so byte `b` is any value in `[b, b + 1)`.
    /// Without this every texel would read half a byte low: 5% at a byte of 10, which
    /// real maps' dark areas are full of.
    pub fn interval(&self, byte: u8) -> (f32, f32) {
        let b = byte as f32;
        (self.decode_exact(b / 255.0), self.decode_exact(((b + 1.0) / 255.0).min(256.0 / 255.0)))
    }
}

/// A material that emits light in q3map2's compile: `q3map_surfacelight` (from the
/// material extras `q3_surfacelight` that convert writes).
#[derive(Debug, Clone, PartialEq)]
pub struct Emitter {
    /// q3map2's value (a surface filling a sample's hemisphere adds `0.75 value` bytes).
    pub value: f32,
    /// Linear colour, largest channel 1.
    pub color: [f32; 3],
    /// Largest extent of one emitting patch, Quake units.
    pub subdivide: f32,
    /// Backsplash: fraction (of 7 x the value) and distance (Quake units).
    pub backsplash: (f32, f32),
}

/// What the compile of the map recorded (worldspawn keys that convert keeps in the world
/// node's extras): q3map2's settings where the map says them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Compile {
    /// `_q3map2_cmdline`, when recorded.
    pub cmdline: Option<String>,
    /// `_minlight` times `_color`, bytes per channel.
    pub minlight: Option<[f32; 3]>,
    /// `_ambient` (or `ambient`) times `_color`, bytes per channel.
    pub ambient: Option<[f32; 3]>,
}

impl Compile {
    /// The value of a `-switch VALUE` of the light stage of the command line.
    pub fn switch(&self, name: &str) -> Option<&str> {
        let light = self.light_stage()?;
        let mut it = light.split_whitespace();
        while let Some(t) = it.next() {
            if t.eq_ignore_ascii_case(name) {
                return Some(it.next().unwrap_or(""));
            }
        }
        None
    }

    /// Whether the light stage had `-switch`.
    pub fn has(&self, name: &str) -> bool {
        self.light_stage().is_some_and(|l| l.split_whitespace().any(|t| t.eq_ignore_ascii_case(name)))
    }

    /// The `-light ...` part of the recorded command line (stages are separated by `;`).
    fn light_stage(&self) -> Option<&str> {
        self.cmdline.as_deref()?.split(';').find(|s| s.split_whitespace().any(|t| t.eq_ignore_ascii_case("-light")))
    }
}

/// Half of one byte step, `0.5 / 255`: the offset [`Material::decode`] adds (mirrored in
/// `shaders/target.wgsl`).
pub const HALF_BYTE: f32 = 0.5 / 255.0;

/// A point light found in the input (KHR_lights_punctual on a node).
#[derive(Debug, Clone)]
pub struct InputLight {
    /// Index of the glTF node carrying the light.
    pub node: usize,
    pub name: String,
    /// Position relative to `Scene::origin`, meters.
    pub position: Vec3,
    /// World position, meters (f64).
    pub world_position: glam::DVec3,
    /// Linear colour, as in the file.
    pub color: [f32; 3],
    /// Luminous intensity, candela.
    pub intensity_cd: f32,
    /// `extras.locked == true`: the optimiser must not change this light.
    pub locked: bool,
    /// World matrix of the node's parent (identity for a root node), in f64.
    pub parent_world: glam::DMat4,
    /// A spot light: unit axis (world) and q3map2's cone, `radius / distance` at the
    /// edge (extras `q3_radius_by_dist`, else `tan(outerConeAngle)`).
    pub spot: Option<(Vec3, f32)>,
    /// A spot's glTF cone half-angles (inner, outer), radians.
    pub cone: Option<(f32, f32)>,
}

/// A directional light found in the input (KHR_lights_punctual `directional`).
#[derive(Debug, Clone)]
pub struct InputSun {
    pub node: usize,
    pub name: String,
    /// Unit vector from the surface towards the sun, world axes.
    pub to_sun: Vec3,
    pub color: [f32; 3],
    /// Illuminance at normal incidence, lux.
    pub intensity_lux: f32,
    /// World matrix of the node's parent (identity for a root node), in f64.
    pub parent_world: glam::DMat4,
}

#[derive(Debug, Clone, Default)]
pub struct Mesh {
    /// Positions relative to `Scene::origin`, meters.
    pub positions: Vec<Vec3>,
    /// Unit world normals.
    pub normals: Vec<Vec3>,
    /// Albedo texture coordinates.
    pub uv0: Vec<Vec2>,
    /// Lightmap atlas coordinates (zero where the material has no lightmap).
    pub uv1: Vec<Vec2>,
    /// COLOR_0 as stored, RGB in [0, 1] (white where absent).
    pub colors: Vec<[f32; 3]>,
    /// Vertex ids equal for bit-identical positions.
    pub weld: Vec<u32>,
    /// Material of each vertex (a vertex belongs to one primitive, hence one material).
    pub v_material: Vec<u32>,
    pub triangles: Vec<[u32; 3]>,
    pub tri_material: Vec<u32>,
    /// The input triangle each triangle was cut from (its own index before subdivision).
    pub tri_source: Vec<u32>,
}

impl Mesh {
    pub fn triangle_area(&self, t: usize) -> f32 {
        let [a, b, c] = self.triangles[t].map(|i| self.positions[i as usize]);
        0.5 * (b - a).cross(c - a).length()
    }

    /// Recomputes `weld` from the positions' bits.
    pub fn reweld(&mut self) {
        let mut ids = std::collections::HashMap::with_capacity(self.positions.len());
        self.weld = self
            .positions
            .iter()
            .map(|p| {
                let key = p.to_array().map(f32::to_bits);
                let n = ids.len() as u32;
                *ids.entry(key).or_insert(n)
            })
            .collect();
    }

    /// Bounding box of the vertices the triangles use (a vertex no triangle uses is not
    /// geometry: an isolated vertex far away must not stretch the scene).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for p in self.triangles.iter().flatten().map(|&i| self.positions[i as usize]) {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        (lo, hi)
    }
}

#[derive(Debug, Clone)]
pub struct Scene {
    pub mesh: Mesh,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub lights: Vec<InputLight>,
    /// Directional lights of the input.
    pub suns: Vec<InputSun>,
    /// World position of the mesh's local origin: world = origin + stored position.
    pub origin: glam::DVec3,
    /// Primitives skipped (not triangles, no positions), with why.
    pub skipped: Vec<String>,
    /// Meters per Quake unit (scene extras `q3_scale`, convert's `--scale`; 0.0254 when
    /// the file does not say): q3map2's sampling rules are in Quake units.
    pub units_m: f32,
    /// The compile's recorded settings.
    pub compile: Compile,
    /// The terms of relight's model that a relit file records only in its scene extras.
    pub relit: Option<Relit>,
    /// Where q3map2 found solid (scene extras `q3_solids`, written by convert from the
    /// BSP); `None` when the file does not carry it (then the faces decide).
    pub solids: Option<crate::trace::solids::Solids>,
}

/// What relight recorded of its fitted model in the scene's extras (`q3_relight`): the
/// terms that are not lights or emission, which the file carries itself. Blender keeps
/// them only when "Custom Properties" is ticked on export.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Relit {
    /// Ambient irradiance added before dirt, W/m^2 per channel.
    pub ambient: Option<[f32; 3]>,
    /// Floor of the total irradiance, W/m^2 per channel.
    pub minlight: Option<[f32; 3]>,
    /// Scale of each pass of bounced light, per channel.
    pub bounce_scale: Option<[f32; 3]>,
    /// Passes of bounced light the fit used.
    pub bounces: usize,
    /// q3map2's `-dirt` and `-filter` were part of the model.
    pub dirt: bool,
    pub filter: bool,
}

/// How q3map2 sampled the lightmap, in Quake units (its source: `MapSingleLuxel`,
/// `LightContributionToSample`, `DEFAULT_INHIBIT_RADIUS`).
pub mod q3map2 {
    /// A luxel's sample origin lies this far off the surface, along its normal.
    pub const SAMPLE_OFFSET_UNITS: f32 = 1.0;
    /// A point this close to a plane of the BSP counts as on its open side
    /// (`PointInLeafNum`); a sample origin further behind a wall is in solid and is nudged
    /// ([`NUDGE_TEXELS`]).
    pub const PLANE_EPSILON_UNITS: f32 = 0.1;
    /// A sample origin in solid is moved this many texels along the lightmap's axes, trying
    /// in order left, right, up, down, then the four diagonals (`MapSingleLuxel`).
    pub const NUDGE_TEXELS: f32 = 0.5;
    /// A shadow ray ignores geometry this close to the sample origin.
    pub const INHIBIT_RADIUS_UNITS: f32 = 1.5;
    /// Point and spot lights: the distance in the inverse square is at least this.
    pub const MIN_DISTANCE_UNITS: f32 = 16.0;
    /// Point and spot lights ("fast" by default): a contribution of at most this many
    /// bytes (in the brightest channel) is left out.
    pub const FALLOFF_TOLERANCE_BYTES: f32 = 1.0;
    /// A spot light's edge fades over this distance from its cone.
    pub const SPOT_RAMP_UNITS: f32 = 32.0;
    /// A spot's cone radius at its target: `radius` (default 64) plus this.
    pub const SPOT_RADIUS_EXTRA_UNITS: f32 = 16.0;
    /// Area lights (surface lights): each patch's light origin lies this far in front of
    /// it; a sample closer to its plane than [`AREA_PUSH_UNITS`] is pushed forward to it
    /// for the form factor.
    pub const AREA_ORIGIN_OFFSET_UNITS: f32 = 1.0;
    pub const AREA_PUSH_UNITS: f32 = 8.0;
    /// Dirt (ambient occlusion, `-dirt`): ray length, scale and gain defaults.
    pub const DIRT_DEPTH_UNITS: f32 = 128.0;
}

