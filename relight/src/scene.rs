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
}

impl Material {
    /// Linear value `e` (irradiance / pi, 1 = texture at full brightness) of a stored byte
    /// value `v = byte / 255`.
    pub fn decode(&self, v: f32) -> f32 {
        let v = v.clamp(0.0, 1.0);
        let v = if self.lightmap_gamma == 1.0 { v } else { v.powf(self.lightmap_gamma) };
        v * (1u32 << self.overbright_bits.min(8)) as f32
    }
}

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

    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for p in &self.positions {
            lo = lo.min(*p);
            hi = hi.max(*p);
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
}

