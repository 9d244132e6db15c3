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
    /// Stored bytes at or above this value are clamped (censored: lower bounds). q3map2
    /// clamps a luxel at 255 keeping its hue ([`CENSOR_BYTE`] allows for the truncation
    /// to 254), then divides by `-compensate`, so a compile with `-compensate 2` clamps
    /// at 127 ([`find_clamp`] finds it in the data).
    pub censor_byte: u8,
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
    /// A white, one-sided material lit as `lighting`, without lightmap or emission, casting
    /// shadows: what the other fields are where nothing says otherwise.
    pub fn plain(name: &str, lighting: Lighting, overbright_bits: u32) -> Self {
        Material {
            name: name.into(),
            albedo: None,
            albedo_factor: [1.0; 4],
            lighting,
            lightmap: None,
            overbright_bits,
            lightmap_gamma: 1.0,
            censor_byte: CENSOR_BYTE,
            sky: false,
            double_sided: false,
            casts_shadow: true,
            emitter: None,
            sky_lights: Vec::new(),
            emission: [0.0; 3],
        }
    }

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

    /// Stored bytes per byte of q3map2's light, after the clamp: `1 / -compensate`,
    /// read from the data's clamp (`255 / (clamp + 1/2)`: 2 for a clamp at 127), 1 where
    /// the data shows q3map2's own. The compile's tolerances are in q3map2's bytes.
    pub fn stored_per_light_byte(&self) -> f32 {
        if self.censor_byte >= CENSOR_BYTE {
            1.0
        } else {
            (self.censor_byte as f32 + 0.5) / 255.0
        }
    }

    /// Whether a stored colour was clamped: one channel at the clamp (q3map2 scaled the
    /// whole colour down, so every channel of it is a lower bound).
    pub fn censored(&self, bytes: &[u8]) -> bool {
        bytes.iter().any(|&b| b >= self.censor_byte)
    }
}

/// A stored channel at or above this byte is censored where the data shows no lower
/// clamp (q3map2's default): q3map2 scales an overflowing luxel so its largest channel is
/// 255.0, and the float-to-byte truncation of that product often stores 254: both are
/// clamped values.
pub const CENSOR_BYTE: u8 = 254;

/// The lowest clamp [`find_clamp`] believes: below it a pile-up at the top byte is a dark
/// map's shape, not a clamp (`-compensate 8` clamps at 31).
const LOWEST_CLAMP: u8 = 24;

/// A clamp below 255 found in the data ([`find_clamp`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataClamp {
    /// Stored bytes at or above this are clamped.
    pub byte: u8,
    /// Lightmap texels and vertex colours whose largest channel is at the clamp.
    pub at_clamp: usize,
}

/// The byte at which the compile clamped the data, when it is below q3map2's 255.
///
/// q3map2 (`ColorToBytes`) clamps a luxel at 255 keeping its hue and then divides it by
/// `-compensate`, so a compile with `-compensate 2` never stores more than 127, and every
/// luxel that overflowed lands exactly there: the histogram of each stored colour's largest
/// channel ends in a spike, far above the bytes just below it (oacmpdm2: 3830 texels at
/// 127, at most 118 on each of 123-126). A lightmap whose light simply stops below 255 ends
/// in a tail instead. Counted over the lightmap texels of lightmapped materials and the
/// vertex colours of vertex-lit ones. `None` where the data's top is q3map2's own clamp,
/// or shows none.
pub fn find_clamp(mesh: &Mesh, materials: &[Material], textures: &[Texture]) -> Option<DataClamp> {
    let mut hist = [0usize; 256];
    let mut pages: Vec<usize> = materials.iter().filter(|m| m.lighting == Lighting::Lightmap).filter_map(|m| m.lightmap).filter(|&i| i < textures.len()).collect();
    pages.sort_unstable();
    pages.dedup();
    for t in pages.iter().map(|&i| &textures[i]) {
        for px in t.rgba8.chunks_exact(4) {
            hist[px[0].max(px[1]).max(px[2]) as usize] += 1;
        }
    }
    for (v, c) in mesh.colors.iter().enumerate() {
        let vertex_lit = mesh.v_material.get(v).and_then(|&m| materials.get(m as usize)).is_some_and(|m| m.lighting == Lighting::Vertex);
        if vertex_lit {
            let top = c.iter().fold(0.0f32, |a, &x| a.max(x));
            hist[(top.clamp(0.0, 1.0) * 255.0).round() as usize] += 1;
        }
    }
    let top = (1..256).rev().find(|&b| hist[b] > 0)? as u8;
    let lit: usize = hist[1..].iter().sum();
    // A spike: many colours at `b` and above, at least four times as many as on any of
    // the four bytes below, and not most of the lit data (a uniformly lit test scene is
    // no clamp). The truncation can split the clamped value over two bytes (as 255 and
    // 254), hence the second try.
    let spike = |b: usize| {
        let n: usize = hist[b..=top as usize].iter().sum();
        let below = hist[b.saturating_sub(4)..b].iter().copied().max().unwrap_or(0);
        n >= 16 && n >= 4 * below.max(1) && 4 * n <= lit
    };
    if top >= CENSOR_BYTE || top < LOWEST_CLAMP {
        return None;
    }
    let byte = [top, top - 1].into_iter().find(|&b| spike(b as usize))?;
    Some(DataClamp { byte, at_clamp: hist[byte as usize..].iter().sum() })
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

    /// The dirt settings of the recorded light stage (q3map2 takes a value that is not
    /// positive, or not a number, as its default).
    pub fn dirt_settings(&self) -> DirtSettings {
        let value = |name: &str, default: f32| self.switch(name).and_then(|v| v.parse::<f32>().ok()).filter(|v| v.is_finite() && *v > 0.0).unwrap_or(default);
        let d = DirtSettings::Q3MAP2;
        DirtSettings { depth_units: value("-dirtdepth", d.depth_units), scale: value("-dirtscale", d.scale), gain: value("-dirtgain", d.gain) }
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
    /// q3map2's light meshes of the emitting patches (scene extras `q3_patch_lights`,
    /// written by convert); empty when the file does not carry them.
    pub patch_lights: Vec<crate::model::patch_mesh::PatchMesh>,
    /// The control points at which q3map2 lit the vertex-lit patches, with its bytes
    /// (scene extras `q3_patch_vertices`; [`crate::rows::luxel`] samples there).
    pub patch_vertices: Vec<crate::model::patch_mesh::PatchMesh>,
    /// Where q3map2 sampled the luxels of the curved lightmapped patches (scene extras
    /// `q3_patch_luxels`; [`crate::rows::luxel`] moves those rows there).
    pub patch_luxels: Vec<crate::model::patch_mesh::PatchMesh>,
    /// The BSP's tree and the triangles q3map2 cast shadows with (scene extras
    /// `q3_casters` and its buffer view, written by convert): relight's shadow rays test
    /// q3map2's pieces of them ([`crate::trace::pieces`]). `None` when the file does not
    /// carry them (a Blender export drops the view): then the mesh's triangles cast.
    pub casters: Option<crate::casters::Casters>,
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
    /// q3map2's dirt, with its settings, was part of the model.
    pub dirt: Option<DirtSettings>,
    /// q3map2's `-filter` was part of the model.
    pub filter: bool,
}

/// q3map2's dirt settings: `-dirtdepth` (Quake units), `-dirtscale`, `-dirtgain`. Its
/// `-dirtmode 1` (random directions) is taken as mode 0, the ordered directions: the
/// same directions on average.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DirtSettings {
    /// Ray length, Quake units.
    pub depth_units: f32,
    pub scale: f32,
    pub gain: f32,
}

impl DirtSettings {
    /// q3map2's defaults.
    pub const Q3MAP2: DirtSettings = DirtSettings { depth_units: q3map2::DIRT_DEPTH_UNITS, scale: 1.0, gain: 1.0 };

    /// Settings as read from a file: each finite and positive, or `None`.
    pub fn checked(self) -> Option<DirtSettings> {
        [self.depth_units, self.scale, self.gain].iter().all(|v| v.is_finite() && *v > 0.0).then_some(self)
    }
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
    /// On a curved patch the same nudges go this far (Quake units) along two unit vectors
    /// across the plane its point was mapped with (`MakeNormalVectors`), not along the lightmap's
    /// axes: the record of each luxel carries them (convert's `patch_luxels`).
    pub const CURVED_NUDGE_UNITS: f32 = 0.5;
    /// A vertex-lit surface's vertex in solid is sampled instead this far away along the
    /// map's axes, at steps `(x, y, z)` with each in 0, 1, -1, 2 (x outermost), the first
    /// clear (`IlluminateVertexes`: its "two's complement" formula never reaches -2).
    pub const VERTEX_NUDGE_UNITS: f32 = 4.0;
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
    /// Dirt (ambient occlusion, `-dirty`): the default ray length (`-dirtdepth`).
    pub const DIRT_DEPTH_UNITS: f32 = 128.0;
}


#[cfg(test)]
mod tests {
    use super::*;

    /// A lightmapped material over one lightmap page whose texels' largest channels are
    /// `bytes` (as grey), and a vertex-lit one with no vertices.
    fn page(bytes: &[u8]) -> (Mesh, Vec<Material>, Vec<Texture>) {
        let rgba8 = bytes.iter().flat_map(|&b| [b, b / 2, b / 4, 255]).collect();
        let tex = Texture { width: bytes.len() as u32, height: 1, rgba8, wrap_s: Wrap::Clamp, wrap_t: Wrap::Clamp };
        let mat = Material { name: "wall".into(), albedo: None, albedo_factor: [1.0; 4], lighting: Lighting::Lightmap, lightmap: Some(0), overbright_bits: 2, lightmap_gamma: 1.0, censor_byte: CENSOR_BYTE, sky: false, double_sided: false, casts_shadow: true, emitter: None, sky_lights: Vec::new(), emission: [0.0; 3] };
        (Mesh::default(), vec![mat], vec![tex])
    }

    /// A smooth falling tail of lit bytes from 1 to `top` (more dark texels than bright).
    fn tail(top: u8) -> Vec<u8> {
        (1..=top).flat_map(|b| std::iter::repeat(b).take(1 + (top - b) as usize / 8)).collect()
    }

    #[test]
    fn the_dirt_settings_are_read_from_the_recorded_light_stage() {
        let c = |l: &str| Compile { cmdline: Some(l.into()), ..Default::default() };
        let d = DirtSettings::Q3MAP2;
        assert_eq!(c("-meta; -vis; -light -fast -dirty").dirt_settings(), d);
        assert_eq!(c("-meta; -light -dirty -dirtdepth 48 -dirtscale 1.5 -dirtgain 0.8").dirt_settings(), DirtSettings { depth_units: 48.0, scale: 1.5, gain: 0.8 });
        // q3map2 takes what is not positive as its default; what is not a number too.
        assert_eq!(c("-light -dirty -dirtdepth 0 -dirtscale -2 -dirtgain x").dirt_settings(), d);
        // Only the light stage counts.
        assert_eq!(c("-bsp -dirtdepth 16; -light -dirty").dirt_settings(), d);
        assert_eq!(DirtSettings { depth_units: f32::NAN, ..d }.checked(), None);
        assert_eq!(d.checked(), Some(d));
    }

    #[test]
    fn a_compensated_compile_is_found_clamped_at_its_spike() {
        // -compensate 2: everything that overflowed stored at 127, the rest a tail below.
        let mut bytes = tail(126);
        bytes.extend(std::iter::repeat(127).take(40));
        let (mesh, mats, tex) = page(&bytes);
        let c = find_clamp(&mesh, &mats, &tex).expect("a spike at 127");
        assert_eq!((c.byte, c.at_clamp), (127, 40));
        // The truncation split the clamped value over two bytes (as 255 and 254).
        let mut bytes = tail(83);
        bytes.extend(std::iter::repeat(84).take(30));
        bytes.extend(std::iter::repeat(85).take(25));
        let (mesh, mats, tex) = page(&bytes);
        assert_eq!(find_clamp(&mesh, &mats, &tex).map(|c| (c.byte, c.at_clamp)), Some((84, 55)));
    }

    #[test]
    fn a_tail_a_uniform_page_a_dark_page_and_q3map2s_own_clamp_are_no_clamp() {
        for (what, bytes) in [
            ("a tail ending below 255", tail(140)),
            ("a uniformly lit page", [tail(60), vec![61; 400]].concat()),
            ("a dark page", [tail(12), vec![13; 40]].concat()),
            ("q3map2's own clamp", [tail(253), vec![255; 40]].concat()),
            ("a few texels at the top", [tail(126), vec![127; 3]].concat()),
        ] {
            let (mesh, mats, tex) = page(&bytes);
            assert_eq!(find_clamp(&mesh, &mats, &tex), None, "{what}");
        }
    }

    #[test]
    fn the_clamp_makes_a_colour_a_lower_bound() {
        let (_, mut mats, _) = page(&[1]);
        let m = &mut mats[0];
        assert!(m.censored(&[255, 10, 0]) && m.censored(&[254, 10, 0]) && !m.censored(&[253, 10, 0]));
        assert_eq!(m.stored_per_light_byte(), 1.0);
        m.censor_byte = 127;
        assert!(m.censored(&[10, 127, 0]) && !m.censored(&[126, 126, 126]));
        assert_eq!(m.stored_per_light_byte(), 0.5);
    }
}
