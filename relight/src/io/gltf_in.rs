//! Reading a glTF (`.gltf` or `.glb`) into the flat world-space [`Scene`].
//!
//! Accepts what `q3gltf convert` writes and what Blender exports from it: the lightmap is
//! the material's `occlusionTexture` on TEXCOORD_1; `extras` may be missing (then the
//! defaults of CONVENTIONS.md apply: overbright 2, gamma 1); `KHR_lights_punctual` may be
//! in `extensionsRequired`; node order, transforms and vertex order may have changed. Every
//! node transform of the default scene is applied.

use std::path::Path;

use glam::{DMat3, DMat4, DVec3, Vec2, Vec3};
use serde_json::Value;

use crate::error::{Error, Result};
use crate::scene::{find_clamp, InputLight, InputSun, Lighting, Material, Mesh, Scene, Texture, Wrap, CENSOR_BYTE};

/// Default `2^overbright` exponent of q3map2 lightmaps (CONVENTIONS.md).
pub const DEFAULT_OVERBRIGHT_BITS: u32 = 2;
/// Refuse meshes larger than this many vertices or triangles (a corrupt or hostile count).
pub const MAX_ELEMENTS: usize = 50_000_000;
/// Largest world coordinate accepted, meters (f64 still resolves 0.1 mm there).
pub const MAX_COORDINATE: f64 = 1e12;

fn extras_of(raw: &Option<Box<serde_json::value::RawValue>>) -> Value {
    raw.as_ref().and_then(|r| serde_json::from_str(r.get()).ok()).unwrap_or(Value::Null)
}

fn wrap(m: gltf::texture::WrappingMode) -> Wrap {
    match m {
        gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
        gltf::texture::WrappingMode::ClampToEdge => Wrap::Clamp,
        gltf::texture::WrappingMode::MirroredRepeat => Wrap::Mirror,
    }
}

/// Most node instances visited while flattening the scene graph.
pub const MAX_NODE_VISITS: usize = 1_000_000;
/// Largest input file (and largest external buffer) read, in bytes.
pub const MAX_FILE_BYTES: u64 = 4 << 30;
/// Largest image side accepted, in pixels (convert writes at most 8192).
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// Largest decoded image, in bytes (the decoder refuses before allocating more).
pub const MAX_IMAGE_BYTES: u64 = 1 << 30;

/// Bounds on what reading a glTF may allocate. `Default` gives the constants above; the
/// fuzz targets use smaller ones.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Most vertices (in all) and most items of one accessor.
    pub max_elements: usize,
    pub max_image_side: u32,
    pub max_image_bytes: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits { max_elements: MAX_ELEMENTS, max_image_side: MAX_IMAGE_SIDE, max_image_bytes: MAX_IMAGE_BYTES }
    }
}

/// Decodes standard base64 (padding optional, no whitespace), as data URIs carry it.
fn base64_decode(s: &str) -> Option<Vec<u8>> {
    let val = |c: u8| -> Option<u32> {
        Some(match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            _ => return None,
        } as u32)
    };
    let b = s.trim_end_matches('=').as_bytes();
    if b.len() % 4 == 1 {
        return None;
    }
    let mut out = Vec::with_capacity(b.len() / 4 * 3 + 2);
    for chunk in b.chunks(4) {
        let mut acc = 0u32;
        for (k, &c) in chunk.iter().enumerate() {
            acc |= val(c)? << (18 - 6 * k);
        }
        let bytes = acc.to_be_bytes();
        out.extend_from_slice(&bytes[1..chunk.len()]);
    }
    Some(out)
}

/// Decodes `%XX` escapes of a relative URI; `None` for malformed escapes or non-UTF-8.
fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = std::str::from_utf8(b.get(i + 1..i + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// The path a relative (non-`data:`) URI names inside the glTF's directory: `%XX`
/// decoded, `\` read as `/`; refused (with why) when it could leave the directory: `..`,
/// an absolute path, a drive letter or other scheme, NUL, or a malformed escape. The
/// writer ([`crate::lights_out`]) resolves the URIs it copies with the same rule.
pub fn relative_uri(uri: &str) -> std::result::Result<String, &'static str> {
    let rel = percent_decode(uri).ok_or("malformed percent escape")?;
    let slashed = rel.replace('\\', "/");
    if slashed.contains('\0') || slashed.contains(':') {
        return Err("a scheme, drive letter or NUL");
    }
    if slashed.is_empty() || slashed.starts_with('/') || slashed.split('/').any(|c| c == "..") {
        return Err("must be a relative path inside the glTF's directory");
    }
    Ok(slashed)
}

/// Where a URI points, after the safety rules: data URIs are decoded; relative paths must
/// stay inside the glTF's directory (no `..`, no absolute path, no drive letter, no NUL,
/// no other scheme), and are only read when the input came from a directory.
pub(crate) fn read_uri(uri: &str, base: Option<&Path>, shown: &Path, what: &str) -> Result<Vec<u8>> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, data) = rest.split_once(";base64,").ok_or_else(|| Error::input(shown, format!("{what}: data URI is not base64")))?;
        return base64_decode(data).ok_or_else(|| Error::input(shown, format!("{what}: invalid base64 in data URI")));
    }
    let bad = |why: &str| Error::input(shown, format!("{what}: refused URI {:?} ({why})", uri.escape_debug().to_string()));
    let slashed = relative_uri(uri).map_err(bad)?;
    let base = base.ok_or_else(|| bad("external file in an in-memory glTF"))?;
    let p = base.join(&slashed);
    let io = |e: std::io::Error| Error::input(shown, format!("{what}: {}: {e}", p.display()));
    let size = std::fs::metadata(&p).map_err(io)?.len();
    if size > MAX_FILE_BYTES {
        return Err(Error::input(shown, format!("{what}: {} is {size} bytes, over the {MAX_FILE_BYTES}-byte limit", p.display())));
    }
    std::fs::read(&p).map_err(io)
}

/// `[start, start + len)` of a buffer view inside its buffer, checked.
fn view_range(view: &gltf::buffer::View, buffers: &[Vec<u8>]) -> Option<std::ops::Range<usize>> {
    let data = buffers.get(view.buffer().index())?;
    let end = view.offset().checked_add(view.length())?;
    (end <= data.len()).then_some(view.offset()..end)
}

/// Checks that an accessor's items lie inside its buffer view, and that its count is
/// sane, so the `gltf` reader neither overflows nor allocates from a hostile count.
pub(crate) fn check_accessor(a: &gltf::Accessor, buffers: &[Vec<u8>], max_elements: usize) -> std::result::Result<(), String> {
    let count = a.count();
    if count == 0 || count > max_elements {
        return Err(format!("accessor {}: count {count} (must be 1..={max_elements})", a.index()));
    }
    let span = |view: &gltf::buffer::View, offset: usize, n: usize, size: usize| -> bool {
        let Some(r) = view_range(view, buffers) else { return false };
        let stride = view.stride().unwrap_or(size).max(size);
        stride.checked_mul(n - 1).and_then(|x| x.checked_add(size)).and_then(|x| x.checked_add(offset)).is_some_and(|end| end <= r.len())
    };
    // Without a buffer view the items are zeros (plus sparse values): bound them by the
    // input's size, as a dense accessor would be.
    let total: usize = buffers.iter().map(Vec::len).sum();
    if a.view().is_none() && count > total.max(1024) {
        return Err(format!("accessor {}: {count} items without a buffer view, more than the {total} buffer bytes", a.index()));
    }
    if let Some(view) = a.view() {
        if !span(&view, a.offset(), count, a.size()) {
            return Err(format!("accessor {}: {count} items at offset {} run past buffer view {}", a.index(), a.offset(), view.index()));
        }
    }
    if let Some(sp) = a.sparse() {
        let n = sp.count();
        if n == 0 || n > count {
            return Err(format!("accessor {}: sparse count {n} outside 1..={count}", a.index()));
        }
        let (iv, vv) = (sp.indices(), sp.values());
        if !span(&iv.view(), iv.offset(), n, iv.index_type().size()) || !span(&vv.view(), vv.offset(), n, a.size()) {
            return Err(format!("accessor {}: sparse data runs past its buffer view", a.index()));
        }
    }
    Ok(())
}

/// Checks the component type and dimensions of the attributes and indices that are read,
/// as the glTF spec allows them: the `gltf` reader assumes them (and hits `unreachable!`
/// or reads the wrong element size otherwise).
fn check_attribute_types(prim: &gltf::Primitive) -> std::result::Result<(), String> {
    use gltf::accessor::{DataType as D, Dimensions as N};
    use gltf::mesh::Semantic as S;
    let ok = |a: &gltf::Accessor, types: &[D], dims: &[N]| types.contains(&a.data_type()) && dims.contains(&a.dimensions());
    for (sem, a) in prim.attributes() {
        let (fine, want) = match sem {
            S::Positions | S::Normals => (ok(&a, &[D::F32], &[N::Vec3]), "FLOAT VEC3"),
            S::TexCoords(_) => (ok(&a, &[D::F32, D::U8, D::U16], &[N::Vec2]), "VEC2 of FLOAT, UNSIGNED_BYTE or UNSIGNED_SHORT"),
            S::Colors(_) => (ok(&a, &[D::F32, D::U8, D::U16], &[N::Vec3, N::Vec4]), "VEC3 or VEC4 of FLOAT, UNSIGNED_BYTE or UNSIGNED_SHORT"),
            _ => (true, ""),
        };
        if !fine {
            return Err(format!("attribute {sem:?} (accessor {}) is {:?} {:?}, not {want}", a.index(), a.data_type(), a.dimensions()));
        }
    }
    if let Some(a) = prim.indices() {
        if !ok(&a, &[D::U8, D::U16, D::U32], &[N::Scalar]) {
            return Err(format!("indices (accessor {}) are {:?} {:?}, not an unsigned SCALAR", a.index(), a.data_type(), a.dimensions()));
        }
    }
    Ok(())
}

/// Decodes one image with bounded dimensions and allocation, to RGBA8.
fn decode_image(bytes: &[u8], mime: Option<&str>, uri: Option<&str>, limits: &Limits) -> std::result::Result<(u32, u32, Vec<u8>), String> {
    let mut r = image::ImageReader::new(std::io::Cursor::new(bytes));
    let mut lim = image::Limits::default();
    lim.max_image_width = Some(limits.max_image_side);
    lim.max_image_height = Some(limits.max_image_side);
    lim.max_alloc = Some(limits.max_image_bytes);
    r.limits(lim);
    let by_name = |n: &str| {
        let n = n.to_ascii_lowercase();
        if n.ends_with(".png") || n.contains("image/png") {
            Some(image::ImageFormat::Png)
        } else if n.ends_with(".jpg") || n.ends_with(".jpeg") || n.contains("image/jpeg") {
            Some(image::ImageFormat::Jpeg)
        } else {
            None
        }
    };
    let declared = mime.and_then(by_name).or_else(|| uri.filter(|u| !u.starts_with("data:")).and_then(by_name));
    let format = declared.or_else(|| match image::guess_format(bytes) {
        Ok(f @ (image::ImageFormat::Png | image::ImageFormat::Jpeg)) => Some(f),
        _ => None,
    });
    let Some(format) = format else { return Err("unsupported image encoding (PNG and JPEG only)".into()) };
    r.set_format(format);
    let img = r.decode().map_err(|e| e.to_string())?;
    let (w, h) = (img.width(), img.height());
    if w == 0 || h == 0 {
        return Err(format!("image of {w}x{h}"));
    }
    if w as u64 * h as u64 * 4 > limits.max_image_bytes {
        return Err(format!("image of {w}x{h} is over the {}-byte limit as RGBA8", limits.max_image_bytes));
    }
    Ok((w, h, img.to_rgba8().into_raw()))
}

/// Reads the file and flattens the default scene.
pub fn read(path: &Path) -> Result<Scene> {
    let io = |e| Error::Io { path: path.display().to_string(), source: e };
    let size = std::fs::metadata(path).map_err(io)?.len();
    if size > MAX_FILE_BYTES {
        return Err(Error::input(path, format!("{size} bytes is over the {MAX_FILE_BYTES}-byte limit")));
    }
    let bytes = std::fs::read(path).map_err(io)?;
    let base = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    read_slice(&bytes, Some(base), path, &Limits::default())
}

/// The typed glTF of `bytes` and its GLB binary chunk, validated, without the panics gltf
/// 1.4.1 has on hostile input.
pub(crate) fn document(bytes: &[u8], path: &Path) -> Result<(gltf::Document, Option<Vec<u8>>)> {
    // gltf 1.4.1 subtracts the 12-byte header from the declared GLB length unchecked
    // (an overflow panic with overflow checks on: found by the gltf_in fuzz target).
    if let Some(h) = bytes.strip_prefix(b"glTF").and_then(|r| r.get(4..8)) {
        let declared = u32::from_le_bytes(h.try_into().unwrap());
        if declared < 12 {
            return Err(Error::input(path, format!("GLB header declares {declared} bytes, less than the header itself")));
        }
    }
    let gltf::Gltf { document: doc, blob } = gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| Error::input(path, e.to_string()))?;
    // gltf-json 1.4.1's validation indexes the POSITION accessor before checking that it
    // exists (a panic, found by the gltf_in fuzz target): check that first, then validate.
    let root = doc.into_json();
    for (mi, m) in root.meshes.iter().enumerate() {
        for (pi, p) in m.primitives.iter().enumerate() {
            if let Some(a) = p.attributes.values().find(|a| a.value() >= root.accessors.len()) {
                return Err(Error::input(path, format!("mesh {mi} primitive {pi}: accessor {} does not exist", a.value())));
            }
        }
    }
    let doc = gltf::Document::from_json(root).map_err(|e| Error::input(path, e.to_string()))?;
    Ok((doc, blob))
}

/// Reads a `.gltf` or `.glb` held in memory and flattens the default scene. External
/// buffers and images are read from `base` (the file's directory); with `None` only data
/// URIs and the GLB chunk are accepted. `shown` names the input in errors. Hostile input
/// gives an error, never a panic or an unbounded allocation: URIs may not leave `base`,
/// every accessor is checked against its buffer view, counts and images are bounded by
/// `limits`.
pub fn read_slice(bytes: &[u8], base: Option<&Path>, shown: &Path, limits: &Limits) -> Result<Scene> {
    let path = shown;
    let (doc, mut blob) = document(bytes, path)?;
    let mut buffers: Vec<Vec<u8>> = Vec::new();
    for b in doc.buffers() {
        let what = format!("buffer {}", b.index());
        let data = match b.source() {
            gltf::buffer::Source::Bin => blob.take().ok_or_else(|| Error::input(path, format!("{what}: refers to a missing GLB binary chunk")))?,
            gltf::buffer::Source::Uri(uri) => read_uri(uri, base, path, &what)?,
        };
        if data.len() < b.length() {
            return Err(Error::input(path, format!("{what}: {} bytes, shorter than its byteLength {}", data.len(), b.length())));
        }
        buffers.push(data);
    }
    for a in doc.accessors() {
        check_accessor(&a, &buffers, limits.max_elements).map_err(|m| Error::input(path, m))?;
    }
    let mut images = Vec::new();
    for img in doc.images() {
        let what = format!("image {}", img.index());
        // `Image::source` unwraps: a buffer view without a mimeType, or neither a view nor
        // a URI, panics in gltf 1.4.1 (found by the gltf_in fuzz target).
        let raw = &doc.as_json().images[img.index()];
        if raw.buffer_view.is_some() && raw.mime_type.is_none() || raw.buffer_view.is_none() && raw.uri.is_none() {
            return Err(Error::input(path, format!("{what}: needs a uri, or a bufferView with a mimeType")));
        }
        let (encoded, mime, uri): (std::borrow::Cow<[u8]>, Option<&str>, Option<&str>) = match img.source() {
            gltf::image::Source::View { view, mime_type } => {
                let r = view_range(&view, &buffers).ok_or_else(|| Error::input(path, format!("{what}: buffer view {} lies outside its buffer", view.index())))?;
                (std::borrow::Cow::Borrowed(&buffers[view.buffer().index()][r]), Some(mime_type), None)
            }
            gltf::image::Source::Uri { uri, mime_type } => (std::borrow::Cow::Owned(read_uri(uri, base, path, &what)?), mime_type, Some(uri)),
        };
        images.push(decode_image(&encoded, mime, uri, limits).map_err(|m| Error::input(path, format!("{what}: {m}")))?);
    }

    let mut textures = Vec::new();
    let mut tex_of_image = Vec::new();
    for (width, height, rgba8) in images {
        tex_of_image.push(textures.len());
        textures.push(Texture {
            width,
            height,
            rgba8,
            wrap_s: Wrap::Repeat,
            wrap_t: Wrap::Repeat,
        });
    }
    // A glTF texture is an image plus a sampler; give each (image, sampler) pair its own entry.
    let mut texture_index = std::collections::HashMap::new();
    let mut tex_ref = |t: gltf::texture::Texture| -> usize {
        let s = t.sampler();
        let key = (t.source().index(), wrap(s.wrap_s()), wrap(s.wrap_t()));
        *texture_index.entry(key).or_insert_with(|| {
            let base = &textures[tex_of_image[key.0]];
            if base.wrap_s == key.1 && base.wrap_t == key.2 {
                tex_of_image[key.0]
            } else {
                let mut copy = base.clone();
                copy.wrap_s = key.1;
                copy.wrap_t = key.2;
                textures.push(copy);
                textures.len() - 1
            }
        })
    };

    let scene_extras = doc.default_scene().or_else(|| doc.scenes().next()).map(|s| extras_of(s.extras())).unwrap_or(Value::Null);
    let scene_ob = scene_extras.get("q3_overbright_bits").and_then(Value::as_u64).map(|v| v.min(8) as u32);

    let mut materials: Vec<Material> = Vec::new();
    for m in doc.materials() {
        let ex = extras_of(m.extras());
        let name = m.name().unwrap_or("").to_string();
        let pbr = m.pbr_metallic_roughness();
        let albedo = pbr.base_color_texture().filter(|i| i.tex_coord() == 0).map(|i| tex_ref(i.texture()));
        let lightmap = m.occlusion_texture().filter(|o| o.tex_coord() == 1).map(|o| tex_ref(o.texture()));
        let declared = ex.get("q3_lighting").and_then(Value::as_str);
        // Sky surfaces (convert puts them under the "sky" node; see below) carry no target.
        let sky = ex.get("q3_sky").and_then(Value::as_bool).unwrap_or(false);
        let lighting = match declared {
            _ if sky => Lighting::None,
            Some("lightmap") if lightmap.is_some() => Lighting::Lightmap,
            Some("vertex") => Lighting::Vertex,
            Some("none") => Lighting::None,
            _ if lightmap.is_some() => Lighting::Lightmap,
            // Blender drops extras unless asked; the material name keeps convert's suffix.
            _ if name.contains("#vertex") => Lighting::Vertex,
            _ => Lighting::None,
        };
        materials.push(Material {
            name,
            albedo,
            albedo_factor: pbr.base_color_factor(),
            lighting,
            lightmap,
            overbright_bits: ex.get("q3_overbright_bits").and_then(Value::as_u64).map(|v| v.min(8) as u32).or(scene_ob).unwrap_or(DEFAULT_OVERBRIGHT_BITS),
            lightmap_gamma: ex.get("q3_lightmap_gamma").and_then(Value::as_f64).filter(|g| g.is_finite() && *g > 0.0).unwrap_or(1.0) as f32,
            censor_byte: CENSOR_BYTE,
            sky,
            double_sided: m.double_sided(),
            casts_shadow: ex.get("q3_casts_shadow").and_then(Value::as_bool).unwrap_or(m.alpha_mode() != gltf::material::AlphaMode::Blend),
            emitter: emitter_of(&ex),
            emission: {
                let s = m.emissive_strength().filter(|s| s.is_finite() && *s >= 0.0).unwrap_or(1.0);
                m.emissive_factor().map(|c| if c.is_finite() { (c * s).max(0.0) } else { 0.0 })
            },
            sky_lights: ex
                .get("q3_skylight")
                .and_then(Value::as_array)
                .map(|a| {
                    a.iter()
                        .filter_map(|p| {
                            let c = p.get("color").and_then(Value::as_array).filter(|c| c.len() == 3).map(|c| [0, 1, 2].map(|k| c[k].as_f64().unwrap_or(1.0).clamp(0.0, 1.0) as f32)).unwrap_or([1.0; 3]);
                            Some((p.get("value")?.as_f64()? as f32, p.get("iterations")?.as_u64()?.min(1024) as u32, c))
                        })
                        .filter(|(v, it, _)| v.is_finite() && *v > 0.0 && *it >= 2)
                        .collect()
                })
                .unwrap_or_default(),
        });
    }
    let default_material = materials.len();
    materials.push(Material::plain("(default)", Lighting::None, scene_ob.unwrap_or(DEFAULT_OVERBRIGHT_BITS)));

    let mut mesh = Mesh::default();
    let mut lights = Vec::new();
    let mut suns = Vec::new();
    let mut skipped = Vec::new();
    let mut compile = crate::scene::Compile::default();
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => doc.nodes().collect(),
    };
    // World positions in f64 until the origin is known (see `Scene::origin`).
    let mut world_pos: Vec<DVec3> = Vec::new();
    let mut stack: Vec<(gltf::Node, DMat4, usize)> = roots.into_iter().map(|n| (n, DMat4::IDENTITY, 0)).collect();
    let mut visits = 0usize;
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > 256 {
            return Err(Error::input(path, "node hierarchy deeper than 256 (a cycle?)"));
        }
        // A node listed as the child of several parents is visited once per path: bound
        // the walk so a hostile DAG cannot multiply it without end.
        visits += 1;
        if visits > MAX_NODE_VISITS {
            return Err(Error::input(path, format!("more than {MAX_NODE_VISITS} node instances in the scene")));
        }
        let world = parent * DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(f64::from)));
        for c in node.children() {
            stack.push((c, world, depth + 1));
        }
        if let Some(light) = node.light() {
            if let gltf::khr_lights_punctual::Kind::Directional = light.kind() {
                // The light shines along the node's -Z: the sun lies along +Z.
                let to_sun = world.transform_vector3(DVec3::Z).normalize_or_zero().as_vec3();
                if to_sun != Vec3::ZERO && to_sun.is_finite() {
                    suns.push(InputSun { node: node.index(), name: node.name().or(light.name()).unwrap_or("").to_string(), to_sun, color: light.color(), intensity_lux: light.intensity(), parent_world: parent });
                }
            }
            let spot = match light.kind() {
                gltf::khr_lights_punctual::Kind::Spot { outer_cone_angle, .. } => {
                    let axis = world.transform_vector3(-DVec3::Z).normalize_or_zero().as_vec3();
                    let rbd = extras_of(light.extras()).get("q3_radius_by_dist").and_then(Value::as_f64).map(|v| v as f32).unwrap_or(outer_cone_angle.clamp(1e-3, 1.5).tan());
                    (axis != Vec3::ZERO && axis.is_finite() && rbd.is_finite() && rbd > 0.0).then_some((axis, rbd))
                }
                _ => None,
            };
            let cone = match light.kind() {
                gltf::khr_lights_punctual::Kind::Spot { inner_cone_angle, outer_cone_angle } if spot.is_some() => Some((inner_cone_angle.clamp(0.0, outer_cone_angle), outer_cone_angle)),
                _ => None,
            };
            let point_like = matches!(light.kind(), gltf::khr_lights_punctual::Kind::Point) || spot.is_some();
            if point_like {
                let ex = extras_of(node.extras());
                let lex = extras_of(light.extras());
                let locked = ex.get("locked").and_then(Value::as_bool).or_else(|| lex.get("locked").and_then(Value::as_bool)).unwrap_or(false);
                lights.push(InputLight {
                    node: node.index(),
                    name: node.name().or(light.name()).unwrap_or("").to_string(),
                    position: Vec3::ZERO, // made relative to the origin below
                    world_position: world.transform_point3(DVec3::ZERO),
                    color: light.color(),
                    intensity_cd: light.intensity(),
                    locked,
                    parent_world: parent,
                    spot,
                    cone,
                });
            }
        }
        let ex = extras_of(node.extras());
        if ex.get("classname").and_then(Value::as_str) == Some("worldspawn") {
            compile = compile_of(&ex);
        }
        let Some(m) = node.mesh() else { continue };
        // convert's "sky" node (Blender keeps the name, adding ".001" on a clash).
        let sky_node = node.name().is_some_and(|n| n == "sky" || n.strip_prefix("sky.").is_some_and(|s| s.chars().all(|c| c.is_ascii_digit())));
        let normal_matrix = DMat3::from_mat4(world).inverse().transpose();
        let flip = DMat3::from_mat4(world).determinant() < 0.0;
        for prim in m.primitives() {
            let what = || format!("mesh {:?} primitive {}", m.name().unwrap_or(""), prim.index());
            if prim.mode() != gltf::mesh::Mode::Triangles {
                skipped.push(format!("{}: mode {:?} is not triangles", what(), prim.mode()));
                continue;
            }
            check_attribute_types(&prim).map_err(|m| Error::input(path, format!("{}: {m}", what())))?;
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d[..]));
            let Some(pos) = reader.read_positions() else {
                skipped.push(format!("{}: no POSITION", what()));
                continue;
            };
            let pos: Vec<Vec3> = pos.map(Vec3::from).collect();
            let n = pos.len();
            if world_pos.len() + n > limits.max_elements {
                return Err(Error::unsupported(path, format!("more than {} vertices", limits.max_elements)));
            }
            let normals: Option<Vec<Vec3>> = reader.read_normals().map(|it| it.map(Vec3::from).collect());
            let uv0: Option<Vec<Vec2>> = reader.read_tex_coords(0).map(|it| it.into_f32().map(Vec2::from).collect());
            let uv1: Option<Vec<Vec2>> = reader.read_tex_coords(1).map(|it| it.into_f32().map(Vec2::from).collect());
            let colors: Option<Vec<[f32; 3]>> = reader.read_colors(0).map(|it| it.into_rgb_f32().collect());
            let indices: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..n as u32).collect(),
            };
            let len_ok = |k: usize| k == n;
            if !normals.as_ref().is_none_or(|v| len_ok(v.len()))
                || !uv0.as_ref().is_none_or(|v| len_ok(v.len()))
                || !uv1.as_ref().is_none_or(|v| len_ok(v.len()))
                || !colors.as_ref().is_none_or(|v| len_ok(v.len()))
            {
                return Err(Error::input(path, format!("{}: attribute counts differ from POSITION's {n}", what())));
            }
            if mesh.triangles.len() + indices.len() / 3 > limits.max_elements {
                return Err(Error::unsupported(path, format!("more than {} triangles", limits.max_elements)));
            }
            if let Some(bad) = indices.iter().find(|&&i| i as usize >= n) {
                return Err(Error::input(path, format!("{}: index {bad} out of range (vertex count {n})", what())));
            }
            let mut mat = prim.material().index().unwrap_or(default_material);
            if sky_node && mat != default_material {
                materials[mat].sky = true;
                materials[mat].lighting = Lighting::None;
            }
            if materials[mat].lighting == Lighting::Lightmap && uv1.is_none() {
                skipped.push(format!("{}: lightmapped material without TEXCOORD_1: no target", what()));
                mat = default_material;
            }
            if materials[mat].lighting == Lighting::Vertex && colors.is_none() {
                skipped.push(format!("{}: vertex-lit material without COLOR_0: no target", what()));
                mat = default_material;
            }
            let base = world_pos.len() as u32;
            for (k, p) in pos.iter().enumerate() {
                let wp = world.transform_point3(p.as_dvec3());
                if !wp.is_finite() || wp.abs().max_element() > MAX_COORDINATE {
                    return Err(Error::input(path, format!("{}: vertex {k} has a non-finite or absurd position ({wp})", what())));
                }
                world_pos.push(wp);
                let nw = normals.as_ref().map(|v| (normal_matrix * v[k].as_dvec3()).normalize_or_zero().as_vec3()).unwrap_or(Vec3::ZERO);
                mesh.normals.push(if nw.is_finite() { nw } else { Vec3::ZERO });
                mesh.uv0.push(uv0.as_ref().map(|v| v[k]).filter(|u| u.is_finite()).unwrap_or(Vec2::ZERO));
                mesh.uv1.push(uv1.as_ref().map(|v| v[k]).filter(|u| u.is_finite()).unwrap_or(Vec2::ZERO));
                mesh.colors.push(colors.as_ref().map(|v| v[k]).unwrap_or([1.0; 3]));
                mesh.v_material.push(mat as u32);
            }
            for t in indices.chunks_exact(3) {
                let tri = if flip { [t[0], t[2], t[1]] } else { [t[0], t[1], t[2]] };
                mesh.tri_source.push(mesh.triangles.len() as u32);
                mesh.triangles.push(tri.map(|i| base + i));
                mesh.tri_material.push(mat as u32);
            }
        }
    }
    if mesh.triangles.is_empty() {
        return Err(Error::unsupported(path, "the scene has no triangles"));
    }
    // The origin from the vertices triangles use (an isolated vertex is not geometry).
    let (lo, hi) = mesh.triangles.iter().flatten().map(|&i| world_pos[i as usize]).fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(lo, hi), p| (lo.min(p), hi.max(p)));
    let origin = ((lo + hi) * 0.5).round();
    mesh.positions = world_pos.iter().map(|p| (*p - origin).as_vec3()).collect();
    for l in &mut lights {
        l.position = (l.world_position - origin).as_vec3();
    }
    repair_normals(&mut mesh);
    mesh.reweld();
    // The data's own clamp, where the compile put it below 255 (`-compensate`).
    if let Some(c) = find_clamp(&mesh, &materials, &textures) {
        for m in &mut materials {
            m.censor_byte = c.byte;
        }
    }
    lights.sort_by_key(|l| l.node);
    suns.sort_by_key(|s| s.node);
    let units_m = scene_extras.get("q3_scale").and_then(Value::as_f64).filter(|s| s.is_finite() && *s > 1e-6 && *s < 1e3).unwrap_or(q3gltf_convert::units::DEFAULT_SCALE) as f32;
    let relit = scene_extras.get("q3_relight").and_then(relit_of);
    // q3map2's casters: the record names its buffer view, whose bytes it checks.
    let casters = match scene_extras.get("q3_casters") {
        Some(v) => {
            let view = v.get("bufferView").and_then(Value::as_u64).and_then(|i| doc.views().nth(i as usize));
            let bytes = view.as_ref().and_then(|view| view_range(view, &buffers).map(|r| &buffers[view.buffer().index()][r]));
            match bytes.ok_or_else(|| "its buffer view is missing".to_string()).and_then(|b| crate::casters::Casters::from_record(v, b)) {
                Ok(c) => Some(c),
                Err(why) => {
                    skipped.push(format!("scene extras `q3_casters` left out (the mesh's triangles cast the shadows): {why}"));
                    None
                }
            }
        }
        None => None,
    };
    let solids = match scene_extras.get("q3_solids") {
        Some(v) => match crate::trace::solids::Solids::from_extras(v, origin, units_m as f64) {
            Ok(s) => Some(s),
            Err(why) => {
                skipped.push(format!("scene extras `q3_solids` left out: {why}"));
                None
            }
        },
        None => None,
    };
    let patch_lights = match scene_extras.get("q3_patch_lights") {
        Some(v) => crate::model::patch_mesh::from_extras(v, origin).unwrap_or_else(|why| {
            skipped.push(format!("scene extras `q3_patch_lights` left out: {why}"));
            Vec::new()
        }),
        None => Vec::new(),
    };
    let patch_vertices = match scene_extras.get("q3_patch_vertices") {
        Some(v) => crate::model::patch_mesh::from_extras(v, origin)
            .and_then(|m| if m.iter().all(|p| !p.rgb.is_empty()) { Ok(m) } else { Err("a patch without `rgb`".into()) })
            .unwrap_or_else(|why| {
                skipped.push(format!("scene extras `q3_patch_vertices` left out: {why}"));
                Vec::new()
            }),
        None => Vec::new(),
    };
    let patch_luxels = match scene_extras.get("q3_patch_luxels") {
        Some(v) => crate::model::patch_mesh::from_extras(v, origin)
            .and_then(|m| if m.iter().all(|p| !p.luxels.is_empty()) { Ok(m) } else { Err("a patch without luxels".into()) })
            .unwrap_or_else(|why| {
                skipped.push(format!("scene extras `q3_patch_luxels` left out: {why}"));
                Vec::new()
            }),
        None => Vec::new(),
    };
    Ok(Scene { mesh, materials, textures, lights, suns, origin, skipped, units_m, compile, relit, solids, patch_lights, patch_vertices, patch_luxels, casters })
}

/// A material's q3map2 surface light (extras `q3_surfacelight`, written by convert).
fn emitter_of(ex: &Value) -> Option<crate::scene::Emitter> {
    let s = ex.get("q3_surfacelight")?;
    let f = |v: &Value| v.as_f64().filter(|x| x.is_finite()).map(|x| x as f32);
    let value = f(s.get("value")?)?.max(0.0);
    let color = s.get("color").and_then(Value::as_array).filter(|a| a.len() == 3).map(|a| [0, 1, 2].map(|k| f(&a[k]).unwrap_or(1.0).clamp(0.0, 1.0))).unwrap_or([1.0; 3]);
    let subdivide = s.get("subdivide").and_then(f).filter(|v| *v > 0.0).unwrap_or(999.0);
    let backsplash = s.get("backsplash").and_then(Value::as_array).filter(|a| a.len() == 2).map(|a| (f(&a[0]).unwrap_or(0.0).clamp(0.0, 1.0), f(&a[1]).unwrap_or(0.0).clamp(0.0, 1e4))).unwrap_or((0.05, 23.0));
    (value > 0.0).then_some(crate::scene::Emitter { value, color, subdivide: subdivide.min(1e6), backsplash })
}

/// The compile settings recorded in worldspawn's keys (convert copies them into the world
/// node's extras): q3map2 reads `_minlight`, `_ambient` (or `ambient`) and `_color` so.
fn compile_of(ex: &Value) -> crate::scene::Compile {
    let s = |k: &str| ex.get(k).and_then(Value::as_str);
    let num = |k: &str| s(k).and_then(|v| v.trim().parse::<f32>().ok()).filter(|v| v.is_finite());
    let mut color = s("_color")
        .and_then(|c| {
            let v: Vec<f32> = c.split_whitespace().filter_map(|t| t.parse().ok()).collect();
            (v.len() == 3 && v.iter().all(|x| x.is_finite())).then(|| [v[0], v[1], v[2]])
        })
        .unwrap_or([1.0; 3]);
    if color.iter().map(|c| c * c).sum::<f32>() == 0.0 {
        color = [1.0; 3];
    }
    crate::scene::Compile {
        cmdline: s("_q3map2_cmdline").map(str::to_string),
        minlight: num("_minlight").filter(|v| *v > 0.0).map(|v| color.map(|c| c * v)),
        ambient: num("_ambient").or_else(|| num("ambient")).filter(|v| *v > 0.0).map(|v| color.map(|c| c * v)),
    }
}

/// The model terms a relit file records in its scene extras (`q3_relight`, written by
/// [`crate::io::lights_out`]); values that are not finite and non-negative are dropped.
fn relit_of(ex: &Value) -> Option<crate::scene::Relit> {
    let rgb = |k: &str| -> Option<[f32; 3]> {
        let a = ex.get(k)?.as_array().filter(|a| a.len() == 3)?;
        let v = [0, 1, 2].map(|c| a[c].as_f64().unwrap_or(f64::NAN) as f32);
        v.iter().all(|x| x.is_finite() && *x >= 0.0).then_some(v)
    };
    ex.is_object().then(|| crate::scene::Relit {
        ambient: rgb("ambient"),
        minlight: rgb("minlight"),
        bounce_scale: rgb("bounce_scale"),
        bounces: ex.get("bounces").and_then(Value::as_u64).unwrap_or(0).min(64) as usize,
        // Files written before the settings were recorded used q3map2's defaults.
        dirt: ex.get("dirt").and_then(Value::as_bool).unwrap_or(false).then(|| {
            ex.get("dirt_settings").and_then(|v| serde_json::from_value::<crate::scene::DirtSettings>(v.clone()).ok()).and_then(|s| s.checked()).unwrap_or(crate::scene::DirtSettings::Q3MAP2)
        }),
        filter: ex.get("filter").and_then(Value::as_bool).unwrap_or(false),
    })
}

/// Vertices without a usable normal get the area-weighted normal of their triangles.
fn repair_normals(mesh: &mut Mesh) {
    let mut acc = vec![Vec3::ZERO; mesh.positions.len()];
    let mut need = false;
    for tri in &mesh.triangles {
        let [a, b, c] = tri.map(|i| mesh.positions[i as usize]);
        let n = (b - a).cross(c - a);
        for &v in tri {
            if mesh.normals[v as usize] == Vec3::ZERO {
                acc[v as usize] += n;
                need = true;
            }
        }
    }
    if need {
        for (n, a) in mesh.normals.iter_mut().zip(acc) {
            if *n == Vec3::ZERO {
                *n = a.normalize_or(Vec3::Y);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn a_relit_files_dirt_is_read_with_its_settings() {
        use crate::scene::DirtSettings;
        let read = |v: serde_json::Value| relit_of(&v).unwrap().dirt;
        assert_eq!(read(serde_json::json!({ "dirt": false })), None);
        // Written before the settings were recorded: q3map2's defaults.
        assert_eq!(read(serde_json::json!({ "dirt": true })), Some(DirtSettings::Q3MAP2));
        let s = DirtSettings { depth_units: 32.0, scale: 1.5, gain: 0.8 };
        assert_eq!(read(serde_json::json!({ "dirt": true, "dirt_settings": s })), Some(s));
        // Settings that are not finite and positive, or not settings: the defaults.
        for bad in [serde_json::json!({ "depth_units": -1.0, "scale": 1.0, "gain": 1.0 }), serde_json::json!({ "depth_units": 64.0 }), serde_json::json!("deep")] {
            assert_eq!(read(serde_json::json!({ "dirt": true, "dirt_settings": bad })), Some(DirtSettings::Q3MAP2));
        }
    }

    fn b64(data: &[u8]) -> String {
        const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut s = String::new();
        for c in data.chunks(3) {
            let n = (c[0] as u32) << 16 | (*c.get(1).unwrap_or(&0) as u32) << 8 | *c.get(2).unwrap_or(&0) as u32;
            for k in 0..4 {
                s.push(if k <= c.len() { A[(n >> (18 - 6 * k) & 63) as usize] as char } else { '=' });
            }
        }
        s
    }

    fn data_uri(bytes: &[u8]) -> String {
        format!("data:application/octet-stream;base64,{}", b64(bytes))
    }

    fn crc32(data: &[u8]) -> u32 {
        let mut c = !0u32;
        for &b in data {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
            }
        }
        !c
    }

    /// A PNG whose header claims `w` x `h` (valid CRCs; empty image data).
    fn png_header(w: u32, h: u32) -> Vec<u8> {
        let mut ihdr = b"IHDR".to_vec();
        ihdr.extend_from_slice(&w.to_be_bytes());
        ihdr.extend_from_slice(&h.to_be_bytes());
        ihdr.extend_from_slice(&[8, 6, 0, 0, 0]);
        let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
        png.extend_from_slice(&13u32.to_be_bytes());
        png.extend_from_slice(&ihdr);
        png.extend_from_slice(&crc32(&ihdr).to_be_bytes());
        for kind in [b"IDAT", b"IEND"] {
            png.extend_from_slice(&0u32.to_be_bytes());
            png.extend_from_slice(kind);
            png.extend_from_slice(&crc32(kind).to_be_bytes());
        }
        png
    }

    /// One triangle (3 float positions in a 36-byte buffer), plus whatever `edit` changes.
    fn triangle(edit: impl FnOnce(&mut Value)) -> Vec<u8> {
        let pos: Vec<u8> = [0f32, 0., 0., 1., 0., 0., 0., 1., 0.].iter().flat_map(|x| x.to_le_bytes()).collect();
        let mut doc = json!({
            "asset": { "version": "2.0" },
            "buffers": [{ "byteLength": 36, "uri": data_uri(&pos) }],
            "bufferViews": [{ "buffer": 0, "byteLength": 36 }],
            "accessors": [{ "bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                            "min": [0, 0, 0], "max": [1, 1, 0] }],
            "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0 } }] }],
            "nodes": [{ "mesh": 0 }],
            "scenes": [{ "nodes": [0] }],
            "scene": 0
        });
        edit(&mut doc);
        serde_json::to_vec(&doc).unwrap()
    }

    fn read_mem(bytes: &[u8]) -> Result<Scene> {
        read_slice(bytes, None, Path::new("t.gltf"), &Limits::default())
    }

    fn err_of(r: Result<Scene>) -> String {
        match r {
            Ok(_) => panic!("accepted"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn reads_a_minimal_triangle() {
        let s = read_mem(&triangle(|_| {})).unwrap();
        assert_eq!(s.mesh.positions.len(), 3);
        assert_eq!(s.mesh.triangles.len(), 1);
    }

    /// Found by fuzzing the `gltf` crate's importer path: an image in a buffer view that
    /// lies past its buffer made it slice out of range (a panic). Now an error.
    #[test]
    fn image_view_outside_its_buffer_is_an_error() {
        let bytes = triangle(|d| {
            d["bufferViews"].as_array_mut().unwrap().push(json!({ "buffer": 0, "byteOffset": 30, "byteLength": 100 }));
            d["images"] = json!([{ "bufferView": 1, "mimeType": "image/png" }]);
        });
        let e = err_of(read_mem(&bytes));
        assert!(e.contains("image 0") && e.contains("outside its buffer"), "{e}");
    }

    /// The `gltf` importer unwrapped the percent-decoding of relative URIs: `%FF` (not
    /// UTF-8) panicked. Now an error naming the URI.
    #[test]
    fn malformed_percent_escape_is_an_error() {
        let dir = std::env::temp_dir();
        let bytes = triangle(|d| d["images"] = json!([{ "uri": "%FF%FE.png" }]));
        let e = err_of(read_slice(&bytes, Some(&dir), Path::new("t.gltf"), &Limits::default()));
        assert!(e.contains("percent"), "{e}");
    }

    #[test]
    fn uris_may_not_leave_the_gltf_directory() {
        let d = std::env::temp_dir().join(format!("q3gltf-uri-{}", std::process::id()));
        let sub = d.join("sub");
        std::fs::create_dir_all(&sub).unwrap();
        let pos: Vec<u8> = [0f32, 0., 0., 1., 0., 0., 0., 1., 0.].iter().flat_map(|x| x.to_le_bytes()).collect();
        std::fs::write(d.join("secret.bin"), &pos).unwrap();
        std::fs::write(sub.join("ok.bin"), &pos).unwrap();
        let abs = d.join("secret.bin").display().to_string();
        for uri in ["../secret.bin", "..%2Fsecret.bin", "sub/../../secret.bin", "..\\secret.bin", abs.as_str(), &format!("file://{abs}"), "C:/secret.bin", "ok.bin%00"] {
            let bytes = triangle(|doc| doc["buffers"][0]["uri"] = json!(uri));
            let e = err_of(read_slice(&bytes, Some(&sub), Path::new("t.gltf"), &Limits::default()));
            assert!(e.contains("refused URI"), "{uri}: {e}");
        }
        let bytes = triangle(|doc| doc["buffers"][0]["uri"] = json!("ok.bin"));
        assert_eq!(read_slice(&bytes, Some(&sub), Path::new("t.gltf"), &Limits::default()).unwrap().mesh.positions.len(), 3);
        // In memory (no base directory) even a harmless relative URI is not read.
        assert!(err_of(read_mem(&bytes)).contains("in-memory"));
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn accessors_are_checked_against_their_views() {
        for (edit, want) in [
            (json!({ "count": 1000 }), "run past"),
            (json!({ "count": 0 }), "count 0"),
            (json!({ "byteOffset": 4 }), "run past"),
            (json!({ "count": 3_000_000_000u64 }), "count"),
        ] {
            let bytes = triangle(|d| {
                for (k, v) in edit.as_object().unwrap() {
                    d["accessors"][0][k] = v.clone();
                }
            });
            let e = err_of(read_mem(&bytes));
            assert!(e.contains(want), "{edit}: {e}");
        }
        // A sparse accessor without a view: its count is bounded by the input's size.
        let bytes = triangle(|d| {
            d["bufferViews"].as_array_mut().unwrap().push(json!({ "buffer": 0, "byteLength": 4 }));
            d["accessors"][0] = json!({ "componentType": 5126, "count": 40_000_000, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0],
                "sparse": { "count": 1, "indices": { "bufferView": 1, "componentType": 5125 }, "values": { "bufferView": 0 } } });
        });
        let e = err_of(read_mem(&bytes));
        assert!(e.contains("without a buffer view"), "{e}");
    }

    /// Found by the `gltf_in` fuzz target: COLOR_0 on a VEC2 accessor hit
    /// `unreachable!()` inside the `gltf` reader (a panic); so would FLOAT indices.
    #[test]
    fn attribute_types_are_checked_before_reading() {
        let color_vec2 = triangle(|d| {
            d["accessors"].as_array_mut().unwrap().push(json!({ "bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC2" }));
            d["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"] = json!(1);
        });
        let e = err_of(read_mem(&color_vec2));
        assert!(e.contains("Colors(0)") && e.contains("not VEC3 or VEC4"), "{e}");
        let float_indices = triangle(|d| {
            d["accessors"].as_array_mut().unwrap().push(json!({ "bufferView": 0, "componentType": 5126, "count": 3, "type": "SCALAR" }));
            d["meshes"][0]["primitives"][0]["indices"] = json!(1);
        });
        let e = err_of(read_mem(&float_indices));
        assert!(e.contains("indices") && e.contains("unsigned SCALAR"), "{e}");
        let u8_positions = triangle(|d| d["accessors"][0]["componentType"] = json!(5121));
        let e = err_of(read_mem(&u8_positions));
        assert!(e.contains("Positions") && e.contains("FLOAT VEC3"), "{e}");
    }

    /// Found by the `gltf_in` fuzz target: a GLB header declaring fewer than 12 bytes
    /// made `gltf::Gltf::from_slice` subtract with overflow (a panic with overflow
    /// checks, a wrapped length without).
    #[test]
    fn glb_length_shorter_than_its_header_is_an_error() {
        for declared in [0u32, 11] {
            let mut glb = b"glTF".to_vec();
            glb.extend_from_slice(&2u32.to_le_bytes());
            glb.extend_from_slice(&declared.to_le_bytes());
            glb.extend_from_slice(&[0u8; 16]);
            let e = err_of(read_mem(&glb));
            assert!(e.contains("GLB header declares"), "{e}");
        }
    }

    /// Found by the `gltf_in` fuzz target: an image with a buffer view but no mimeType
    /// (or with neither a view nor a URI) made `gltf::Image::source` unwrap `None`.
    #[test]
    fn image_without_mime_type_or_source_is_an_error() {
        for image in [json!({ "bufferView": 0 }), json!({ "name": "nothing" })] {
            let bytes = triangle(|d| d["images"] = json!([image]));
            let e = err_of(read_mem(&bytes));
            assert!(e.contains("image 0: needs a uri"), "{e}");
        }
    }

    /// Found by the `gltf_in` fuzz target: a POSITION attribute naming an accessor that
    /// does not exist made gltf-json's own validation index out of bounds.
    #[test]
    fn missing_position_accessor_is_an_error() {
        let bytes = triangle(|d| d["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(7));
        let e = err_of(read_mem(&bytes));
        assert!(e.contains("accessor 7 does not exist"), "{e}");
        let bytes = triangle(|d| d["accessors"] = json!([]));
        let e = err_of(read_mem(&bytes));
        assert!(e.contains("accessor 0 does not exist"), "{e}");
    }

    #[test]
    fn image_dimensions_are_bounded_before_decoding() {
        let png = png_header(100_000, 100_000);
        let bytes = triangle(|d| d["images"] = json!([{ "uri": format!("data:image/png;base64,{}", b64(&png)) }]));
        let t = std::time::Instant::now();
        let e = err_of(read_mem(&bytes));
        assert!(e.contains("image 0") && e.to_lowercase().contains("limit"), "{e}");
        assert!(t.elapsed() < std::time::Duration::from_secs(1));
        // Within the side limit but over the byte budget given.
        let png = png_header(4000, 4000);
        let bytes = triangle(|d| d["images"] = json!([{ "uri": format!("data:image/png;base64,{}", b64(&png)) }]));
        let small = Limits { max_image_bytes: 1 << 20, ..Limits::default() };
        let e = err_of(read_slice(&bytes, None, Path::new("t.gltf"), &small));
        assert!(e.to_lowercase().contains("limit"), "{e}");
    }

    /// Nodes shared by two parents on each of 40 levels make 2^40 paths: the walk stops
    /// at MAX_NODE_VISITS with an error instead of running for ever.
    #[test]
    fn shared_nodes_cannot_multiply_the_walk() {
        let levels = 40;
        let bytes = triangle(|d| {
            let mut nodes = Vec::new();
            for l in 0..levels {
                let children = if l + 1 < levels { json!([2 * l + 2, 2 * l + 3]) } else { json!([]) };
                nodes.push(json!({ "children": children, "mesh": 0 }));
                nodes.push(json!({ "children": children }));
            }
            d["nodes"] = json!(nodes);
            d["scenes"] = json!([{ "nodes": [0, 1] }]);
        });
        let t = std::time::Instant::now();
        let r = read_slice(&bytes, None, Path::new("t.gltf"), &Limits { max_elements: 1 << 30, ..Limits::default() });
        assert!(t.elapsed() < std::time::Duration::from_secs(30));
        match r {
            Ok(_) => panic!("accepted"),
            Err(e) => {
                let e = e.to_string();
                assert!(e.contains("node instances") || e.contains("triangles") || e.contains("vertices"), "{e}");
            }
        }
    }

    #[test]
    fn base64_round_trip() {
        for n in 0..10 {
            let data: Vec<u8> = (0..n).map(|i| (i * 37 + 5) as u8).collect();
            assert_eq!(base64_decode(&b64(&data)).unwrap(), data);
        }
        assert!(base64_decode("a").is_none() && base64_decode("ab!d").is_none());
    }
}
