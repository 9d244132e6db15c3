//! glTF 2.0 writing: [`Scene`] to a `.gltf` (with a `.bin` buffer and image files beside
//! it) or a binary `.glb`.
//!
//! Layout: one buffer; one buffer view per accessor (4-byte aligned, tightly packed);
//! vertex attributes as FLOAT, colours as normalised UNSIGNED_BYTE VEC4, indices as
//! UNSIGNED_INT. In `.glb` files images live in the buffer; in `.gltf` files they are
//! written to `<stem>_textures/` under sanitised names, so nothing lands outside the
//! output directory. Every file is written atomically; the `.gltf` is renamed into place
//! last, after the files it refers to. The JSON is a pure function of the scene.

use crate::output::{sanitize_relative, Staged};
use crate::scene::{AlphaMode, LightKind, Sampling, Scene};
use gltf_json as json;
use json::validation::Checked::Valid;
use json::validation::USize64;
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, Default)]
pub struct WriteOptions {
    /// Also write the `MOZ_lightmap` material extension (listed in extensionsUsed only).
    pub moz_lightmap: bool,
    /// The `asset.generator` string.
    pub generator: String,
}

/// What was written.
#[derive(Debug, Clone)]
pub struct Written {
    pub files: Vec<PathBuf>,
    pub bytes: u64,
}

/// Output container, chosen from the extension of the output path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Container {
    Gltf,
    Glb,
}

impl Container {
    pub fn from_path(p: &Path) -> Option<Container> {
        match p.extension()?.to_str()?.to_ascii_lowercase().as_str() {
            "gltf" => Some(Container::Gltf),
            "glb" => Some(Container::Glb),
            _ => None,
        }
    }
}

struct Builder {
    root: json::Root,
    bin: Vec<u8>,
}

impl Builder {
    fn view(&mut self, bytes: &[u8], target: Option<json::buffer::Target>) -> json::Index<json::buffer::View> {
        while self.bin.len() % 4 != 0 {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.root.push(json::buffer::View {
            buffer: json::Index::new(0),
            byte_length: USize64(bytes.len() as u64),
            byte_offset: Some(USize64(offset as u64)),
            byte_stride: None,
            name: None,
            target: target.map(Valid),
            extensions: None,
            extras: Default::default(),
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn accessor(
        &mut self,
        bytes: &[u8],
        count: usize,
        component: json::accessor::ComponentType,
        type_: json::accessor::Type,
        normalized: bool,
        minmax: Option<(Value, Value)>,
        target: json::buffer::Target,
    ) -> json::Index<json::Accessor> {
        let view = self.view(bytes, Some(target));
        let (min, max) = match minmax {
            Some((a, b)) => (Some(a), Some(b)),
            None => (None, None),
        };
        self.root.push(json::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64(count as u64),
            component_type: Valid(json::accessor::GenericComponentType(component)),
            extensions: None,
            extras: Default::default(),
            type_: Valid(type_),
            min,
            max,
            name: None,
            normalized,
            sparse: None,
        })
    }
}

fn f32_bytes<const N: usize>(v: &[[f32; N]]) -> Vec<u8> {
    v.iter().flatten().flat_map(|x| x.to_le_bytes()).collect()
}

fn raw(v: &Value) -> json::extras::Extras {
    serde_json::value::to_raw_value(v).ok()
}

fn json_f32(x: f32) -> Value {
    // Shortest representation of the f32 itself, so readers get back the exact value.
    serde_json::from_str(&format!("{x:?}")).unwrap_or(Value::from(0))
}

/// Builds the glTF document and its binary buffer. Images are embedded in the buffer
/// when `image_uris` is `None`, else referenced by those URIs (one per image).
fn build(scene: &Scene, opts: &WriteOptions, image_uris: Option<&[String]>, bin_uri: Option<String>) -> (json::Root, Vec<u8>) {
    use json::accessor::{ComponentType as C, Type as T};
    use json::buffer::Target;
    let mut b = Builder { root: json::Root::default(), bin: Vec::new() };
    b.root.asset = json::Asset {
        copyright: None,
        extensions: None,
        extras: Default::default(),
        generator: Some(opts.generator.clone()),
        min_version: None,
        version: "2.0".into(),
    };

    // Images and textures.
    for (i, img) in scene.images.iter().enumerate() {
        let (uri, view) = match image_uris {
            Some(uris) => (Some(uris[i].clone()), None),
            None => (None, Some(b.view(&img.bytes, None))),
        };
        b.root.push(json::Image {
            buffer_view: view,
            mime_type: view.map(|_| json::image::MimeType(img.mime.to_string())),
            name: Some(img.name.clone()),
            uri,
            extensions: None,
            extras: Default::default(),
        });
    }
    let samplings: BTreeSet<Sampling> = scene.textures.iter().map(|t| t.sampling).collect();
    let sampler_index = |s: Sampling| samplings.iter().position(|&x| x == s).unwrap() as u32;
    for s in &samplings {
        use json::texture::{MagFilter, MinFilter, WrappingMode};
        let (min, wrap, name) = match s {
            Sampling::Repeat => (MinFilter::LinearMipmapLinear, WrappingMode::Repeat, "albedo"),
            Sampling::ClampLinear => (MinFilter::Linear, WrappingMode::ClampToEdge, "lightmap"),
        };
        b.root.push(json::texture::Sampler {
            mag_filter: Some(Valid(MagFilter::Linear)),
            min_filter: Some(Valid(min)),
            name: Some(name.into()),
            wrap_s: Valid(wrap),
            wrap_t: Valid(wrap),
            extensions: None,
            extras: Default::default(),
        });
    }
    for t in &scene.textures {
        b.root.push(json::Texture {
            name: None,
            sampler: Some(json::Index::new(sampler_index(t.sampling))),
            source: json::Index::new(t.image as u32),
            extensions: None,
            extras: Default::default(),
        });
    }

    // Materials.
    let mut moz_used = false;
    let mut emissive_strength_used = false;
    for m in &scene.materials {
        let info = |t: usize, tex_coord: u32| json::texture::Info {
            index: json::Index::new(t as u32),
            tex_coord,
            extensions: None,
            extras: Default::default(),
        };
        let mut mat = json::Material {
            name: Some(m.name.clone()),
            double_sided: m.double_sided,
            extras: raw(&m.extras),
            ..Default::default()
        };
        mat.pbr_metallic_roughness.base_color_factor = json::material::PbrBaseColorFactor(m.base_color_factor);
        mat.pbr_metallic_roughness.base_color_texture = m.base_color_texture.map(|t| info(t, 0));
        mat.pbr_metallic_roughness.metallic_factor = json::material::StrengthFactor(0.0);
        mat.pbr_metallic_roughness.roughness_factor = json::material::StrengthFactor(1.0);
        match m.alpha_mode {
            AlphaMode::Opaque => {}
            AlphaMode::Mask(c) => {
                mat.alpha_mode = Valid(json::material::AlphaMode::Mask);
                mat.alpha_cutoff = Some(json::material::AlphaCutoff(c));
            }
            AlphaMode::Blend => mat.alpha_mode = Valid(json::material::AlphaMode::Blend),
        }
        if let Some(lm) = m.lightmap_texture {
            mat.occlusion_texture = Some(json::material::OcclusionTexture {
                index: json::Index::new(lm as u32),
                strength: json::material::StrengthFactor(1.0),
                tex_coord: 1,
                extensions: None,
                extras: Default::default(),
            });
            if opts.moz_lightmap {
                let mut ext = json::extensions::material::Material::default();
                ext.others.insert("MOZ_lightmap".into(), serde_json::json!({ "index": lm, "texCoord": 1, "intensity": 1.0 }));
                mat.extensions = Some(ext);
                moz_used = true;
            }
        }
        // The baked look is Lambertian: no specular lobe (Blender's Principled BSDF would
        // add its default 0.5 and wash grazing walls grey-white).
        mat.extensions.get_or_insert_with(Default::default).others.insert("KHR_materials_specular".into(), serde_json::json!({ "specularFactor": 0.0 }));
        if let Some((color, radiance)) = m.emissive {
            // glTF's emissiveFactor is in [0, 1]; the strength extension carries the rest.
            let strength = radiance.max(0.0);
            if strength <= 1.0 {
                mat.emissive_factor = json::material::EmissiveFactor(color.map(|c| c * strength));
            } else {
                mat.emissive_factor = json::material::EmissiveFactor(color);
                let ext = mat.extensions.get_or_insert_with(Default::default);
                ext.others.insert("KHR_materials_emissive_strength".into(), serde_json::json!({ "emissiveStrength": strength }));
                emissive_strength_used = true;
            }
        }
        b.root.push(mat);
    }

    // Meshes.
    for mesh in &scene.meshes {
        let mut prims = Vec::new();
        for p in &mesh.primitives {
            let n = p.positions.len();
            let mut mn = [f32::INFINITY; 3];
            let mut mx = [f32::NEG_INFINITY; 3];
            for v in &p.positions {
                for k in 0..3 {
                    mn[k] = mn[k].min(v[k]);
                    mx[k] = mx[k].max(v[k]);
                }
            }
            let mm = (Value::Array(mn.iter().map(|&x| json_f32(x)).collect()), Value::Array(mx.iter().map(|&x| json_f32(x)).collect()));
            let mut attributes = std::collections::BTreeMap::new();
            let pos = b.accessor(&f32_bytes(&p.positions), n, C::F32, T::Vec3, false, Some(mm), Target::ArrayBuffer);
            attributes.insert(Valid(json::mesh::Semantic::Positions), pos);
            let nrm = b.accessor(&f32_bytes(&p.normals), n, C::F32, T::Vec3, false, None, Target::ArrayBuffer);
            attributes.insert(Valid(json::mesh::Semantic::Normals), nrm);
            let uv0 = b.accessor(&f32_bytes(&p.uv0), n, C::F32, T::Vec2, false, None, Target::ArrayBuffer);
            attributes.insert(Valid(json::mesh::Semantic::TexCoords(0)), uv0);
            if let Some(uv1) = &p.uv1 {
                let a = b.accessor(&f32_bytes(uv1), n, C::F32, T::Vec2, false, None, Target::ArrayBuffer);
                attributes.insert(Valid(json::mesh::Semantic::TexCoords(1)), a);
            }
            if let Some(colors) = &p.colors {
                let bytes: Vec<u8> = colors.iter().flatten().copied().collect();
                let a = b.accessor(&bytes, n, C::U8, T::Vec4, true, None, Target::ArrayBuffer);
                attributes.insert(Valid(json::mesh::Semantic::Colors(0)), a);
            }
            let ib: Vec<u8> = p.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
            let idx = b.accessor(&ib, p.indices.len(), C::U32, T::Scalar, false, None, Target::ElementArrayBuffer);
            prims.push(json::mesh::Primitive {
                attributes,
                extensions: None,
                extras: Default::default(),
                indices: Some(idx),
                material: Some(json::Index::new(p.material as u32)),
                mode: Valid(json::mesh::Mode::Triangles),
                targets: None,
            });
        }
        b.root.push(json::Mesh { extensions: None, extras: Default::default(), name: Some(mesh.name.clone()), primitives: prims, weights: None });
    }

    // Lights.
    if !scene.lights.is_empty() {
        use json::extensions::scene::khr_lights_punctual as klp;
        let lights = scene
            .lights
            .iter()
            .map(|l| klp::Light {
                color: l.color,
                extensions: None,
                extras: l.extras.as_ref().and_then(raw),
                intensity: l.intensity,
                name: Some(l.name.clone()),
                range: l.range,
                spot: match l.kind {
                    LightKind::Spot { inner, outer } => Some(klp::Spot { inner_cone_angle: inner, outer_cone_angle: outer }),
                    _ => None,
                },
                type_: Valid(match l.kind {
                    LightKind::Point => klp::Type::Point,
                    LightKind::Spot { .. } => klp::Type::Spot,
                    LightKind::Directional => klp::Type::Directional,
                }),
            })
            .collect();
        b.root.extensions = Some(json::extensions::root::Root {
            khr_lights_punctual: Some(json::extensions::root::KhrLightsPunctual { lights }),
            ..Default::default()
        });
        b.root.extensions_used.push("KHR_lights_punctual".into());
    }
    if moz_used {
        b.root.extensions_used.push("MOZ_lightmap".into());
    }
    if emissive_strength_used {
        b.root.extensions_used.push("KHR_materials_emissive_strength".into());
    }
    if !scene.materials.is_empty() {
        b.root.extensions_used.push("KHR_materials_specular".into());
    }

    // Nodes and the scene.
    for n in &scene.nodes {
        let extensions = n.light.map(|l| json::extensions::scene::Node {
            khr_lights_punctual: Some(json::extensions::scene::khr_lights_punctual::KhrLightsPunctual { light: json::Index::new(l as u32) }),
            ..Default::default()
        });
        b.root.push(json::Node {
            camera: None,
            children: (!n.children.is_empty()).then(|| n.children.iter().map(|&c| json::Index::new(c as u32)).collect()),
            extensions,
            extras: n.extras.as_ref().and_then(raw),
            matrix: None,
            mesh: n.mesh.map(|m| json::Index::new(m as u32)),
            name: Some(n.name.clone()),
            rotation: n.rotation.map(json::scene::UnitQuaternion),
            scale: None,
            translation: n.translation,
            skin: None,
            weights: None,
        });
    }
    // The extras' binary records, each a buffer view its record names.
    let mut extras = scene.extras.clone();
    for (key, bytes) in &scene.blobs {
        let view = b.view(bytes, None);
        if let Some(record) = extras.as_mut().and_then(|e| e.get_mut(key)).and_then(Value::as_object_mut) {
            record.insert("bufferView".into(), Value::from(view.value()));
        }
    }
    let sc = b.root.push(json::Scene {
        extensions: None,
        extras: extras.as_ref().and_then(raw),
        name: Some(scene.name.clone()),
        nodes: scene.roots.iter().map(|&r| json::Index::new(r as u32)).collect(),
    });
    b.root.scene = Some(sc);

    while b.bin.len() % 4 != 0 {
        b.bin.push(0);
    }
    if !b.bin.is_empty() {
        b.root.push(json::Buffer { byte_length: USize64(b.bin.len() as u64), name: None, uri: bin_uri, extensions: None, extras: Default::default() });
    }
    (b.root, b.bin)
}

fn to_json_bytes(root: &json::Root) -> Vec<u8> {
    serde_json::to_vec(root).unwrap_or_default()
}

/// Encodes a scene as GLB bytes (JSON and BIN chunks).
pub fn to_glb(scene: &Scene, opts: &WriteOptions) -> Vec<u8> {
    let (root, bin) = build(scene, opts, None, None);
    let mut js = to_json_bytes(&root);
    while js.len() % 4 != 0 {
        js.push(b' ');
    }
    let total = 12 + 8 + js.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(js.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&js);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
    }
    out
}

/// Writes the scene to `path` (`.gltf` or `.glb`), atomically: every file is staged
/// under a temporary name first and the batch is renamed into place with the `.gltf`
/// last (see [`crate::output::Staged`]); on an error nothing is left behind.
pub fn write(scene: &Scene, path: &Path, opts: &WriteOptions) -> std::io::Result<Written> {
    let container = Container::from_path(path).ok_or_else(|| {
        std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("{}: output must end in .gltf or .glb", path.display()))
    })?;
    let mut staged = Staged::new();
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new(".")).to_path_buf();
    staged.create_dir_all(&dir)?;
    match container {
        Container::Glb => {
            let bytes = to_glb(scene, opts);
            staged.add(path, &bytes)?;
            staged.commit()?;
            Ok(Written { files: vec![path.to_path_buf()], bytes: bytes.len() as u64 })
        }
        Container::Gltf => {
            let stem = sanitize_relative(&path.file_stem().unwrap_or_default().to_string_lossy()).to_string_lossy().replace(['/', '\\'], "_");
            let tex_dir = format!("{stem}_textures");
            let uris = image_uris(scene, &tex_dir);
            let bin_name = format!("{stem}.bin");
            let (root, bin) = build(scene, opts, Some(&uris), Some(bin_name.clone()));
            let mut files = Vec::new();
            let mut bytes = 0u64;
            for (img, uri) in scene.images.iter().zip(&uris) {
                let p = dir.join(uri);
                if let Some(d) = p.parent() {
                    staged.create_dir_all(d)?;
                }
                staged.add(&p, &img.bytes)?;
                bytes += img.bytes.len() as u64;
                files.push(p);
            }
            if !bin.is_empty() {
                let p = dir.join(&bin_name);
                staged.add(&p, &bin)?;
                bytes += bin.len() as u64;
                files.push(p);
            }
            let js = to_json_bytes(&root);
            staged.add(path, &js)?;
            bytes += js.len() as u64;
            files.push(path.to_path_buf());
            staged.commit()?;
            Ok(Written { files, bytes })
        }
    }
}

/// Relative URIs of the images of a `.gltf` output: `<tex_dir>/<sanitised name>.<ext>`,
/// unique (a collision gets `_1`, `_2`, ... in image order), so deterministic.
pub fn image_uris(scene: &Scene, tex_dir: &str) -> Vec<String> {
    let mut taken = BTreeSet::new();
    scene
        .images
        .iter()
        .map(|img| {
            let base = sanitize_relative(&img.name).to_string_lossy().replace('\\', "/");
            let mut uri = format!("{tex_dir}/{base}.{}", img.extension());
            let mut k = 1;
            while !taken.insert(uri.clone()) {
                uri = format!("{tex_dir}/{base}_{k}.{}", img.extension());
                k += 1;
            }
            uri
        })
        .collect()
}
