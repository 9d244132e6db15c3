//! The converted scene, independent of glTF's encoding: meshes with their vertex arrays
//! (already in glTF space: meters, Y up, counter-clockwise fronts), materials, encoded
//! images, nodes and lights. [`crate::gltf_out`] turns it into a file.

use serde_json::Value;

/// An encoded image, ready to be stored (PNG or JPEG bytes).
#[derive(Debug, Clone)]
pub struct Image {
    /// File-name stem (sanitised relative path, no extension) for `.gltf` output.
    pub name: String,
    pub mime: &'static str,
    pub bytes: Vec<u8>,
}

impl Image {
    pub fn extension(&self) -> &'static str {
        if self.mime == "image/jpeg" {
            "jpg"
        } else {
            "png"
        }
    }
}

/// How a texture is sampled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Sampling {
    /// Albedo: repeat, trilinear.
    Repeat,
    /// Lightmap atlas: clamp to edge, bilinear, no mipmaps.
    ClampLinear,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub image: usize,
    pub sampling: Sampling,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AlphaMode {
    Opaque,
    Mask(f32),
    Blend,
}

#[derive(Debug, Clone)]
pub struct Material {
    pub name: String,
    pub base_color_texture: Option<usize>,
    pub base_color_factor: [f32; 4],
    pub alpha_mode: AlphaMode,
    pub double_sided: bool,
    /// Lightmap atlas texture, referenced as occlusion on TEXCOORD_1.
    pub lightmap_texture: Option<usize>,
    /// Emission: linear colour (largest channel 1) and radiance, W/(m^2 sr) in the
    /// radiometric convention of CONVENTIONS.md (written as `emissiveFactor` and
    /// `KHR_materials_emissive_strength`).
    pub emissive: Option<([f32; 3], f32)>,
    /// JSON object stored as the material's extras.
    pub extras: Value,
}

/// One primitive: triangles sharing a material. Arrays are parallel.
#[derive(Debug, Clone, Default)]
pub struct Primitive {
    pub material: usize,
    /// Meters, glTF axes.
    pub positions: Vec<[f32; 3]>,
    /// Unit length.
    pub normals: Vec<[f32; 3]>,
    pub uv0: Vec<[f32; 2]>,
    /// Lightmap atlas coordinates (lightmapped primitives only).
    pub uv1: Option<Vec<[f32; 2]>>,
    /// Vertex colours (vertex-lit and unlit primitives only), RGBA bytes.
    pub colors: Option<Vec<[u8; 4]>>,
    /// Counter-clockwise triangles.
    pub indices: Vec<u32>,
}

#[derive(Debug, Clone)]
pub struct Mesh {
    pub name: String,
    pub primitives: Vec<Primitive>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LightKind {
    /// Intensity in candela.
    Point,
    /// Intensity in candela; cone half-angles in radians.
    Spot { inner: f32, outer: f32 },
    /// Intensity in lux.
    Directional,
}

#[derive(Debug, Clone)]
pub struct Light {
    pub name: String,
    pub kind: LightKind,
    /// Linear RGB, max channel 1.
    pub color: [f32; 3],
    pub intensity: f32,
    /// Meters, where the light's contribution becomes negligible; None = infinite.
    pub range: Option<f32>,
    pub extras: Option<Value>,
}

#[derive(Debug, Clone, Default)]
pub struct Node {
    pub name: String,
    pub mesh: Option<usize>,
    pub light: Option<usize>,
    pub translation: Option<[f32; 3]>,
    /// Unit quaternion (x, y, z, w).
    pub rotation: Option<[f32; 4]>,
    pub children: Vec<usize>,
    pub extras: Option<Value>,
}

#[derive(Debug, Clone, Default)]
pub struct Scene {
    pub name: String,
    pub nodes: Vec<Node>,
    /// Top-level nodes.
    pub roots: Vec<usize>,
    pub meshes: Vec<Mesh>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub images: Vec<Image>,
    pub lights: Vec<Light>,
    /// Scene-level extras (source map, converter settings).
    pub extras: Option<Value>,
    /// Binary records of the scene's extras, `(key, bytes)`: each is written as a buffer
    /// view, and `extras[key]["bufferView"]` is set to its index (`q3_casters`).
    pub blobs: Vec<(String, Vec<u8>)>,
}

impl Scene {
    pub fn add_node(&mut self, node: Node) -> usize {
        self.nodes.push(node);
        self.nodes.len() - 1
    }
}
