//! The baked scene as glTF: the input with new lightmap coordinates where it needs them and
//! its lightmaps replaced by the bake, in the slot convention of `q3gltf convert` (the
//! lightmap is the material's `occlusionTexture` on TEXCOORD_1, clamped, linear filtering),
//! so relight, Blender and the tests read it like a converted map.
//!
//! Which primitives get new coordinates ([`Plan::all`] is `bake --new-uvs`):
//! - a lightmapped material's primitive: with `all`, or when it has no TEXCOORD_1 (a mesh
//!   added in Blender and given a map's material);
//! - a primitive whose material states no baked lighting but is not one of convert's unlit
//!   materials (`q3_lighting: "none"`, or the `#unlit` name suffix that survives Blender
//!   without extras), or that has no material: new geometry, which until now had no data;
//! - never sky, vertex-lit, skinned or compressed primitives (noted).
//!
//! Those primitives are charted together into one new atlas ([`crate::atlas`], texel size
//! in meters of world space, so an instanced mesh is copied per instance first). Their
//! vertices are split along chart seams: every attribute (and morph target) is gathered
//! through xatlas's `xref` into new accessors, TEXCOORD_1 is the atlas. A material they
//! share with primitives that keep their layout is copied (`NAME (baked)`); a missing
//! material becomes a plain white one.
//!
//! The JSON is edited as a tree, as [`crate::io::lights_out`] does, so what we do not
//! understand survives; accessors and buffer views that nothing refers to any more are
//! dropped when the file is written (unless an extension that may refer to them is used).
//! The output is one self-contained GLB: every external file of the input is embedded.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::Path;

use glam::{DMat3, DMat4, DVec3};
use serde_json::{json, Value};

use crate::atlas;
use crate::error::{Error, Result};
use crate::io::container::{abs_dir, embed_resources, external_uris, glb, parse_container, read_container, Container};
use crate::scene::{Lighting, Scene};

/// What to chart, and how finely.
#[derive(Debug, Clone, Copy)]
pub struct Plan {
    /// Chart every lightmapped primitive, not only those without lightmap coordinates.
    pub all: bool,
    pub atlas: atlas::Options,
}

/// The new atlas, when any primitive was charted.
#[derive(Debug, Clone, serde::Serialize)]
pub struct NewAtlas {
    pub width: u32,
    pub height: u32,
    pub charts: u32,
    pub utilization: f32,
    /// Texel size, meters.
    pub texel_m: f32,
    /// Primitive instances charted, and their triangles.
    pub primitives: usize,
    pub triangles: usize,
    /// Triangles xatlas left without texels (zero area, repeated indices).
    pub ignored_triangles: usize,
    /// glTF image holding the atlas (a black placeholder until [`Relayout::set_image`]).
    pub image: usize,
    /// glTF materials that now carry the atlas.
    pub materials: Vec<usize>,
}

/// The input as an editable tree with one binary buffer.
pub struct Relayout {
    json: Value,
    bin: Vec<u8>,
    pub atlas: Option<NewAtlas>,
    /// What was left as it was, and why.
    pub notes: Vec<String>,
}

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;

/// Reads `input` and charts the primitives [`Plan`] selects. `scene` is `input` as
/// [`crate::io::gltf_in`] read it (its materials say how each is lit).
pub fn relayout(input: &Path, scene: &Scene, plan: &Plan) -> Result<Relayout> {
    relayout_container(read_container(input)?, input, Some(&abs_dir(input)), scene, plan)
}

/// [`relayout`] of a `.gltf` or `.glb` held in memory (`shown` names it in errors):
/// external files are refused.
pub fn relayout_bytes(bytes: &[u8], shown: &Path, scene: &Scene, plan: &Plan) -> Result<Relayout> {
    relayout_container(parse_container(bytes, shown)?, shown, None, scene, plan)
}

fn relayout_container(c: Container, input: &Path, dir: Option<&Path>, scene: &Scene, plan: &Plan) -> Result<Relayout> {
    let Container { mut json, mut bin } = c;
    if !json.is_object() {
        return Err(Error::input(input, "top level is not an object"));
    }
    if json.get("buffers").and_then(Value::as_array).is_some_and(|b| b.len() > 1) {
        return Err(Error::unsupported(input, "more than one buffer"));
    }
    if let Some(uri) = json.pointer("/buffers/0/uri").and_then(Value::as_str).filter(|u| u.starts_with("data:")).map(str::to_string) {
        bin = Some(crate::io::gltf_in::read_uri(&uri, None, input, "buffer 0")?);
        json["buffers"][0].as_object_mut().map(|o| o.remove("uri"));
    }
    match dir {
        Some(dir) => embed_resources(&mut json, &mut bin, input, dir)?,
        None if !external_uris(&json).is_empty() => return Err(Error::input(input, "external files in a glTF held in memory")),
        None => {}
    }
    let mut rl = Relayout { json, bin: bin.unwrap_or_default(), atlas: None, notes: Vec::new() };

    let bad = |m: String| Error::input(input, m);
    let text = serde_json::to_vec(&rl.json).map_err(|e| bad(format!("JSON: {e}")))?;
    let (doc, _) = crate::io::gltf_in::document(&glb(&text, Some(&rl.bin))?, input)?;
    // Every accessor inside its view, before the gltf reader touches one.
    let buffers = [std::mem::take(&mut rl.bin)];
    let checked = doc.accessors().try_for_each(|a| crate::io::gltf_in::check_accessor(&a, &buffers, crate::io::gltf_in::MAX_ELEMENTS));
    let [b0] = buffers;
    rl.bin = b0;
    checked.map_err(bad)?;
    let buffer = |b: gltf::Buffer| (b.index() == 0).then_some(&rl.bin[..]);

    // Primitive instances, with their world matrix, in scene order.
    struct Job {
        node: usize,
        mesh: usize,
        prim: usize,
        world: DMat4,
    }
    let mut jobs: Vec<Job> = Vec::new();
    let mut kept_materials: HashSet<Option<usize>> = HashSet::new();
    let mut notes = Vec::new();
    let scene_root = doc.default_scene().or_else(|| doc.scenes().next());
    let mut stack: Vec<(gltf::Node, DMat4, bool, usize)> = scene_root.map(|s| s.nodes().map(|n| (n, DMat4::IDENTITY, false, 0)).collect()).unwrap_or_default();
    // A node reached twice (listed under two parents, which glTF forbids) is taken once.
    let mut visited = HashSet::new();
    while let Some((node, parent, under_sky, depth)) = stack.pop() {
        if depth > 256 {
            return Err(bad("node hierarchy deeper than 256 (a cycle?)".into()));
        }
        if !visited.insert(node.index()) {
            continue;
        }
        let world = parent * DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(f64::from)));
        let sky = under_sky || node.name().is_some_and(|n| n == "sky" || n.strip_prefix("sky.").is_some_and(|s| s.chars().all(|c| c.is_ascii_digit())));
        for child in node.children() {
            stack.push((child, world, sky, depth + 1));
        }
        let Some(mesh) = node.mesh() else { continue };
        for prim in mesh.primitives() {
            let mat = prim.material().index();
            let what = || format!("mesh {:?} primitive {}", mesh.name().unwrap_or(""), prim.index());
            let m = mat.and_then(|i| scene.materials.get(i));
            let raw_mat = mat.and_then(|i| rl.json.pointer(&format!("/materials/{i}")));
            let declared_unlit = raw_mat.and_then(|m| m.pointer("/extras/q3_lighting")).and_then(Value::as_str) == Some("none")
                || m.is_some_and(|m| m.name.contains("#unlit"));
            let has_uv1 = prim.get(&gltf::Semantic::TexCoords(1)).is_some();
            let lighting = m.map_or(Lighting::None, |m| m.lighting);
            let wanted = !sky
                && !m.is_some_and(|m| m.sky)
                && match lighting {
                    Lighting::Lightmap => plan.all || !has_uv1,
                    Lighting::None => !declared_unlit,
                    Lighting::Vertex => false,
                };
            let compressed = rl.json.pointer(&format!("/meshes/{}/primitives/{}/extensions", mesh.index(), prim.index())).and_then(Value::as_object).is_some_and(|o| !o.is_empty());
            let instanced = rl.json.pointer(&format!("/nodes/{}/extensions/EXT_mesh_gpu_instancing", node.index())).is_some();
            if wanted && prim.mode() != gltf::mesh::Mode::Triangles {
                notes.push(format!("{}: not triangles, left without lightmap", what()));
            } else if wanted && node.skin().is_some() {
                notes.push(format!("{}: skinned, left without lightmap", what()));
            } else if wanted && instanced {
                notes.push(format!("{}: GPU-instanced node, left without lightmap", what()));
            } else if wanted && compressed {
                notes.push(format!("{}: has primitive extensions (compression?), left without lightmap", what()));
            } else if let Some(why) = wanted.then(|| ungatherable(&rl.json, mesh.index(), prim.index())).flatten() {
                notes.push(format!("{}: {why}, left without lightmap", what()));
            } else if wanted && prim.get(&gltf::Semantic::Positions).is_some() {
                jobs.push(Job { node: node.index(), mesh: mesh.index(), prim: prim.index(), world });
                continue;
            }
            kept_materials.insert(mat);
        }
    }
    rl.notes = notes;
    if jobs.is_empty() {
        return Ok(rl);
    }

    // World positions (relative to the charted geometry's centre, for f32), normals, indices.
    let doc_meshes: Vec<gltf::Mesh> = doc.meshes().collect();
    let mut geo: Vec<(Vec<DVec3>, Vec<[f32; 3]>, Vec<u32>)> = Vec::with_capacity(jobs.len());
    for j in &jobs {
        let prim = doc_meshes[j.mesh].primitives().nth(j.prim).ok_or_else(|| bad(format!("mesh {} has no primitive {}", j.mesh, j.prim)))?;
        let reader = prim.reader(buffer);
        let pos: Vec<DVec3> = reader.read_positions().map(|it| it.map(|p| j.world.transform_point3(glam::Vec3::from(p).as_dvec3())).collect()).unwrap_or_default();
        let nm = DMat3::from_mat4(j.world).inverse().transpose();
        let normals: Vec<[f32; 3]> = match reader.read_normals() {
            Some(it) => it.map(|n| (nm * glam::Vec3::from(n).as_dvec3()).normalize_or_zero().as_vec3().to_array()).collect(),
            None => Vec::new(),
        };
        let idx: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..pos.len() as u32).collect(),
        };
        geo.push((pos, normals, idx));
    }
    let (lo, hi) = geo.iter().flat_map(|g| g.0.iter()).fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
    let centre = if lo.is_finite() && hi.is_finite() { (lo + hi) * 0.5 } else { DVec3::ZERO };
    let local: Vec<Vec<[f32; 3]>> = geo.iter().map(|g| g.0.iter().map(|p| (*p - centre).as_vec3().to_array()).collect()).collect();
    let inputs: Vec<atlas::Input> = geo
        .iter()
        .zip(&local)
        .map(|(g, p)| atlas::Input { positions: p, normals: (g.1.len() == p.len()).then_some(&g.1[..]), indices: &g.2 })
        .collect();
    let charted = atlas::chart(&inputs, &plan.atlas).map_err(|m| Error::unsupported(input, format!("lightmap atlas: {m}")))?;
    drop(inputs);

    // One mesh per instance: a mesh that any other node (charted or not, in any scene)
    // also uses is copied for each charted node.
    let mut users: HashMap<usize, usize> = HashMap::new();
    for n in rl.json.get("nodes").and_then(Value::as_array).into_iter().flatten() {
        if let Some(m) = n.get("mesh").and_then(Value::as_u64) {
            *users.entry(m as usize).or_default() += 1;
        }
    }
    let mut mesh_of: HashMap<(usize, usize), usize> = HashMap::new();
    for j in &jobs {
        if mesh_of.contains_key(&(j.node, j.mesh)) {
            continue;
        }
        let m = match users.get(&j.mesh).copied().unwrap_or(0) {
            0 | 1 => j.mesh,
            _ => {
                let copy = rl.json["meshes"][j.mesh].clone();
                let meshes = rl.json["meshes"].as_array_mut().ok_or_else(|| bad("meshes is not an array".into()))?;
                meshes.push(copy);
                let k = meshes.len() - 1;
                rl.json["nodes"][j.node]["mesh"] = json!(k);
                k
            }
        };
        mesh_of.insert((j.node, j.mesh), m);
    }

    // The atlas image (black until the bake fills it), its sampler and texture.
    let image = rl.push_image(black_png(charted.width.max(1), charted.height.max(1))?, "lightmap_atlas");
    let sampler = push(&mut rl.json, "samplers", json!({ "magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071, "name": "lightmap" }));
    let texture = push(&mut rl.json, "textures", json!({ "sampler": sampler, "source": image, "name": "lightmap_atlas" }));

    // Materials: charted primitives get one whose occlusion slot holds the atlas.
    let mut baked_material: BTreeMap<Option<usize>, usize> = BTreeMap::new();
    let (mut triangles, mut ignored) = (0usize, 0usize);
    for (k, j) in jobs.iter().enumerate() {
        let uv = &charted.meshes[k];
        let m = mesh_of[&(j.node, j.mesh)];
        let prim = rl.json["meshes"][m]["primitives"][j.prim].clone();
        let mut new_prim = prim.clone();
        let attrs = prim.get("attributes").and_then(Value::as_object).cloned().unwrap_or_default();
        let mut new_attrs = serde_json::Map::new();
        for (name, acc) in &attrs {
            if name == "TEXCOORD_1" {
                continue;
            }
            let a = acc.as_u64().ok_or_else(|| bad(format!("mesh {m}: attribute {name} is not an index")))? as usize;
            let g = rl.gather(a, &uv.xref, name == "POSITION").map_err(|e| bad(format!("mesh {m} primitive {} {name}: {e}", j.prim)))?;
            new_attrs.insert(name.clone(), json!(g));
        }
        let flat: Vec<f32> = uv.uv.iter().flatten().copied().collect();
        let view = rl.push_view(bytemuck::cast_slice(&flat), Some(ARRAY_BUFFER), None);
        let uv_acc = push(&mut rl.json, "accessors", json!({ "bufferView": view, "componentType": FLOAT, "count": uv.uv.len(), "type": "VEC2" }));
        new_attrs.insert("TEXCOORD_1".into(), json!(uv_acc));
        new_prim["attributes"] = Value::Object(new_attrs);
        if let Some(targets) = prim.get("targets").and_then(Value::as_array) {
            let mut new_targets = Vec::new();
            for t in targets {
                let mut nt = serde_json::Map::new();
                for (name, acc) in t.as_object().into_iter().flatten() {
                    let a = acc.as_u64().ok_or_else(|| bad(format!("mesh {m}: morph target {name} is not an index")))? as usize;
                    nt.insert(name.clone(), json!(rl.gather(a, &uv.xref, name == "POSITION").map_err(|e| bad(format!("mesh {m} morph target {name}: {e}")))?));
                }
                new_targets.push(Value::Object(nt));
            }
            new_prim["targets"] = Value::Array(new_targets);
        }
        let (view, ctype) = if uv.xref.len() <= u16::MAX as usize {
            let v: Vec<u16> = uv.indices.iter().map(|&i| i as u16).collect();
            (rl.push_view(bytemuck::cast_slice(&v), Some(ELEMENT_ARRAY_BUFFER), None), UNSIGNED_SHORT)
        } else {
            (rl.push_view(bytemuck::cast_slice(&uv.indices), Some(ELEMENT_ARRAY_BUFFER), None), UNSIGNED_INT)
        };
        new_prim["indices"] = json!(push(&mut rl.json, "accessors", json!({ "bufferView": view, "componentType": ctype, "count": uv.indices.len(), "type": "SCALAR" })));

        let mat = prim.get("material").and_then(Value::as_u64).map(|v| v as usize);
        let baked = match baked_material.get(&mat) {
            Some(&b) => b,
            None => {
                let b = match mat {
                    None => push(&mut rl.json, "materials", json!({
                        "name": "baked",
                        "pbrMetallicRoughness": { "metallicFactor": 0.0, "roughnessFactor": 1.0 },
                        "extensions": { "KHR_materials_specular": { "specularFactor": 0.0 } },
                    })),
                    Some(i) if kept_materials.contains(&Some(i)) => {
                        let mut copy = rl.json["materials"][i].clone();
                        let name = copy.get("name").and_then(Value::as_str).unwrap_or("material").to_string();
                        copy["name"] = json!(format!("{name} (baked)"));
                        push(&mut rl.json, "materials", copy)
                    }
                    Some(i) => i,
                };
                let m = &mut rl.json["materials"][b];
                m["occlusionTexture"] = json!({ "index": texture, "texCoord": 1 });
                if let Some(moz) = m.pointer_mut("/extensions/MOZ_lightmap").and_then(Value::as_object_mut) {
                    moz.insert("index".into(), json!(texture));
                }
                if !m.get("extras").is_some_and(Value::is_object) {
                    m["extras"] = json!({});
                }
                m["extras"]["q3_lighting"] = json!("lightmap");
                baked_material.insert(mat, b);
                b
            }
        };
        new_prim["material"] = json!(baked);
        rl.json["meshes"][m]["primitives"][j.prim] = new_prim;
        triangles += uv.indices.len() / 3;
        ignored += uv.ignored;
    }
    if rl.json.pointer("/materials").is_some_and(|m| m.as_array().is_some_and(|a| a.iter().any(|m| m.pointer("/extensions/KHR_materials_specular").is_some()))) {
        rl.use_extension("KHR_materials_specular");
    }
    rl.atlas = Some(NewAtlas {
        width: charted.width,
        height: charted.height,
        charts: charted.charts,
        utilization: charted.utilization,
        texel_m: 1.0 / plan.atlas.texels_per_m,
        primitives: jobs.len(),
        triangles,
        ignored_triangles: ignored,
        image,
        materials: baked_material.values().copied().collect(),
    });
    Ok(rl)
}

/// Why a primitive's vertices cannot be gathered into new accessors, if they cannot: a
/// sparse accessor, an attribute that is not SCALAR to VEC4, an index count that is not
/// a triangle list.
fn ungatherable(json: &Value, mesh: usize, prim: usize) -> Option<&'static str> {
    let p = json.pointer(&format!("/meshes/{mesh}/primitives/{prim}"))?;
    let mut accs: Vec<&Value> = p.get("attributes").and_then(Value::as_object).into_iter().flatten().map(|(_, a)| a).collect();
    for t in p.get("targets").and_then(Value::as_array).into_iter().flatten() {
        accs.extend(t.as_object().into_iter().flatten().map(|(_, a)| a));
    }
    let acc = |v: &Value| v.as_u64().and_then(|i| json.pointer(&format!("/accessors/{i}")));
    for a in accs.into_iter().filter_map(acc) {
        if a.get("sparse").is_some() {
            return Some("a sparse accessor");
        }
        if a.get("type").and_then(Value::as_str).and_then(component_count).is_none() {
            return Some("an attribute that is not SCALAR to VEC4");
        }
    }
    let count = match p.get("indices") {
        Some(i) => acc(i)?.get("count")?.as_u64()?,
        None => acc(p.pointer("/attributes/POSITION")?)?.get("count")?.as_u64()?,
    };
    (count % 3 != 0).then_some("an index count that is not a triangle list")
}

/// Appends `v` to the array `key` of the root (created if missing); its index.
fn push(json: &mut Value, key: &str, v: Value) -> usize {
    let arr = json.as_object_mut().expect("the root is an object (checked on reading)").entry(key).or_insert_with(|| json!([]));
    if !arr.is_array() {
        *arr = json!([]);
    }
    let a = arr.as_array_mut().unwrap();
    a.push(v);
    a.len() - 1
}

fn black_png(w: u32, h: u32) -> Result<Vec<u8>> {
    let img = image::RgbImage::new(w, h);
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).map_err(|e| Error::Usage(format!("encoding a {w} x {h} PNG: {e}")))?;
    Ok(out.into_inner())
}

/// Bytes per component of an accessor component type.
fn component_size(t: u64) -> Option<usize> {
    match t {
        5120 | 5121 => Some(1),
        5122 | 5123 => Some(2),
        5125 | 5126 => Some(4),
        _ => None,
    }
}

fn component_count(t: &str) -> Option<usize> {
    match t {
        "SCALAR" => Some(1),
        "VEC2" => Some(2),
        "VEC3" => Some(3),
        "VEC4" => Some(4),
        _ => None,
    }
}

impl Relayout {
    /// glTF image indices of every material's lightmap (occlusion texture on TEXCOORD_1),
    /// as `(material, image)`.
    pub fn lightmap_images(&self) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        for (i, m) in self.json.get("materials").and_then(Value::as_array).into_iter().flatten().enumerate() {
            let Some(occ) = m.get("occlusionTexture").filter(|o| o.get("texCoord").and_then(Value::as_u64) == Some(1)) else { continue };
            let Some(img) = occ.get("index").and_then(Value::as_u64).and_then(|t| self.json.pointer(&format!("/textures/{t}/source"))).and_then(Value::as_u64) else { continue };
            out.push((i, img as usize));
        }
        out
    }

    /// Replaces image `image` by a PNG, and marks the materials showing it as holding
    /// linear lightmap bytes (gamma 1, `overbright_bits`).
    pub fn set_image(&mut self, image: usize, png: &[u8], overbright_bits: u32) {
        let view = self.push_view(png, None, None);
        if let Some(img) = self.json.pointer_mut(&format!("/images/{image}")).and_then(Value::as_object_mut) {
            img.remove("uri");
            img.insert("bufferView".into(), json!(view));
            img.insert("mimeType".into(), json!("image/png"));
        }
        let users: Vec<usize> = self.lightmap_images().into_iter().filter(|&(_, i)| i == image).map(|(m, _)| m).collect();
        for m in users {
            let mat = &mut self.json["materials"][m];
            if !mat.get("extras").is_some_and(Value::is_object) {
                mat["extras"] = json!({});
            }
            if let Some(ex) = mat.get_mut("extras").and_then(Value::as_object_mut) {
                ex.remove("q3_lightmap_gamma");
                ex.insert("q3_overbright_bits".into(), json!(overbright_bits));
            }
        }
    }

    /// The file as GLB bytes, unreferenced accessors and views dropped.
    pub fn to_glb(&self) -> Result<Vec<u8>> {
        let mut json = self.json.clone();
        let bin = compact(&mut json, &self.bin);
        let text = serde_json::to_vec(&json).map_err(|e| Error::Usage(format!("JSON: {e}")))?;
        glb(&text, (!bin.is_empty()).then_some(&bin[..]))
    }

    fn use_extension(&mut self, name: &str) {
        let root = self.json.as_object_mut().unwrap();
        let used = root.entry("extensionsUsed").or_insert_with(|| json!([]));
        if let Some(u) = used.as_array_mut() {
            if !u.iter().any(|v| v == name) {
                u.push(json!(name));
            }
        }
    }

    /// Appends bytes (4-byte aligned) as a new buffer view of buffer 0.
    fn push_view(&mut self, bytes: &[u8], target: Option<u32>, stride: Option<usize>) -> usize {
        self.bin.resize(self.bin.len().next_multiple_of(4), 0);
        let mut v = json!({ "buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len() });
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        if let Some(s) = stride {
            v["byteStride"] = json!(s);
        }
        self.bin.extend_from_slice(bytes);
        let k = push(&mut self.json, "bufferViews", v);
        self.fix_buffer_length();
        k
    }

    fn push_image(&mut self, png: Vec<u8>, name: &str) -> usize {
        let view = self.push_view(&png, None, None);
        push(&mut self.json, "images", json!({ "bufferView": view, "mimeType": "image/png", "name": name }))
    }

    fn fix_buffer_length(&mut self) {
        let len = self.bin.len();
        let root = self.json.as_object_mut().unwrap();
        let buffers = root.entry("buffers").or_insert_with(|| json!([{}]));
        if let Some(b) = buffers.as_array_mut() {
            if b.is_empty() {
                b.push(json!({}));
            }
            b[0]["byteLength"] = json!(len);
        }
    }

    /// A new accessor holding element `xref[i]` of accessor `acc` at `i` (vertex
    /// attributes only: SCALAR to VEC4, no sparse storage). Elements are padded to a
    /// multiple of 4 bytes as glTF requires of vertex attributes. With `bounds`, `min` and
    /// `max` are computed (POSITION requires them).
    fn gather(&mut self, acc: usize, xref: &[u32], bounds: bool) -> std::result::Result<usize, String> {
        let a = self.json.pointer(&format!("/accessors/{acc}")).cloned().ok_or_else(|| format!("accessor {acc} does not exist"))?;
        if a.get("sparse").is_some() {
            return Err("sparse accessors are not supported".into());
        }
        let ctype = a.get("componentType").and_then(Value::as_u64).unwrap_or(0);
        let csize = component_size(ctype).ok_or_else(|| format!("component type {ctype}"))?;
        let ty = a.get("type").and_then(Value::as_str).unwrap_or("");
        let ncomp = component_count(ty).ok_or_else(|| format!("type {ty:?} is not a vertex attribute's"))?;
        let count = a.get("count").and_then(Value::as_u64).unwrap_or(0) as usize;
        let elem = csize * ncomp;
        let stride_out = elem.next_multiple_of(4);
        let mut out = vec![0u8; stride_out * xref.len()];
        if let Some(v) = a.get("bufferView").and_then(Value::as_u64) {
            let view = self.json.pointer(&format!("/bufferViews/{v}")).ok_or_else(|| format!("buffer view {v} does not exist"))?;
            let num = |k: &str| view.get(k).and_then(Value::as_u64).unwrap_or(0) as usize;
            let (voff, vlen) = (num("byteOffset"), num("byteLength"));
            let stride = view.get("byteStride").and_then(Value::as_u64).map_or(elem, |s| s as usize);
            let aoff = a.get("byteOffset").and_then(Value::as_u64).unwrap_or(0) as usize;
            let end = voff.checked_add(vlen).filter(|&e| e <= self.bin.len()).ok_or_else(|| format!("buffer view {v} lies outside the buffer"))?;
            if stride < elem || count > 0 && voff + aoff + (count - 1) * stride + elem > end {
                return Err(format!("accessor {acc} lies outside its buffer view"));
            }
            for (i, &x) in xref.iter().enumerate() {
                let x = x as usize;
                if x >= count {
                    return Err(format!("vertex {x} of {count}"));
                }
                let s = voff + aoff + x * stride;
                out[i * stride_out..i * stride_out + elem].copy_from_slice(&self.bin[s..s + elem]);
            }
        } else if xref.iter().any(|&x| x as usize >= count) {
            return Err(format!("a vertex beyond the accessor's {count}"));
        }
        let view = self.push_view(&out, Some(ARRAY_BUFFER), (stride_out != elem).then_some(stride_out));
        let mut na = json!({ "bufferView": view, "componentType": ctype, "count": xref.len(), "type": ty });
        if a.get("normalized").and_then(Value::as_bool) == Some(true) {
            na["normalized"] = json!(true);
        }
        if let Some(n) = a.get("name") {
            na["name"] = n.clone();
        }
        if bounds && ctype == FLOAT as u64 {
            let mut lo = vec![f32::INFINITY; ncomp];
            let mut hi = vec![f32::NEG_INFINITY; ncomp];
            for i in 0..xref.len() {
                for c in 0..ncomp {
                    let o = i * stride_out + c * 4;
                    let v = f32::from_le_bytes(out[o..o + 4].try_into().unwrap());
                    lo[c] = lo[c].min(v);
                    hi[c] = hi[c].max(v);
                }
            }
            if !xref.is_empty() {
                na["min"] = json!(lo);
                na["max"] = json!(hi);
            }
        }
        Ok(push(&mut self.json, "accessors", na))
    }
}

/// Extensions known not to refer to accessors or buffer views (materials, textures,
/// lights): with only these in the file, compaction sees every reference.
fn refers_to_no_data(name: &str) -> bool {
    name.starts_with("KHR_materials_")
        || matches!(name, "KHR_lights_punctual" | "KHR_texture_transform" | "KHR_mesh_quantization" | "KHR_texture_basisu" | "EXT_texture_webp" | "EXT_texture_avif" | "MOZ_lightmap")
}

/// Every extension named anywhere in the tree (`extensionsUsed` and the keys of every
/// `extensions` object, declared or not).
fn extension_names(v: &Value, out: &mut HashSet<String>) {
    match v {
        Value::Object(o) => {
            for (k, x) in o {
                if k == "extensions" {
                    if let Some(e) = x.as_object() {
                        out.extend(e.keys().cloned());
                    }
                }
                if k == "extensionsUsed" || k == "extensionsRequired" {
                    out.extend(x.as_array().into_iter().flatten().filter_map(Value::as_str).map(str::to_string));
                }
                extension_names(x, out);
            }
        }
        Value::Array(a) => a.iter().for_each(|x| extension_names(x, out)),
        _ => {}
    }
}

/// Drops accessors and buffer views nothing refers to, and packs the used views into a
/// new buffer (4-byte aligned). Left as it is when any extension in the file might refer
/// to them (only those of [`refers_to_no_data`] are known not to).
fn compact(json: &mut Value, bin: &[u8]) -> Vec<u8> {
    let mut names = HashSet::new();
    extension_names(json, &mut names);
    if !names.iter().all(|n| refers_to_no_data(n)) {
        return bin.to_vec();
    }
    let idx = |v: &Value| v.as_u64().map(|i| i as usize);
    // Accessors in use.
    let n_acc = json.get("accessors").and_then(Value::as_array).map_or(0, Vec::len);
    let mut used_acc = vec![false; n_acc];
    let mut mark = |v: Option<&Value>| {
        if let Some(i) = v.and_then(idx).filter(|&i| i < n_acc) {
            used_acc[i] = true;
        }
    };
    for m in json.get("meshes").and_then(Value::as_array).into_iter().flatten() {
        for p in m.get("primitives").and_then(Value::as_array).into_iter().flatten() {
            p.get("attributes").and_then(Value::as_object).into_iter().flatten().for_each(|(_, a)| mark(Some(a)));
            mark(p.get("indices"));
            for t in p.get("targets").and_then(Value::as_array).into_iter().flatten() {
                t.as_object().into_iter().flatten().for_each(|(_, a)| mark(Some(a)));
            }
        }
    }
    for s in json.get("skins").and_then(Value::as_array).into_iter().flatten() {
        mark(s.get("inverseBindMatrices"));
    }
    for a in json.get("animations").and_then(Value::as_array).into_iter().flatten() {
        for s in a.get("samplers").and_then(Value::as_array).into_iter().flatten() {
            mark(s.get("input"));
            mark(s.get("output"));
        }
    }
    let acc_map: Vec<Option<usize>> = {
        let mut k = 0;
        used_acc.iter().map(|&u| u.then(|| {
            k += 1;
            k - 1
        })).collect()
    };
    let remap_acc = |v: &mut Value| {
        if let Some(n) = idx(v).and_then(|i| acc_map.get(i).copied().flatten()) {
            *v = json!(n);
        }
    };
    for m in json.get_mut("meshes").and_then(Value::as_array_mut).into_iter().flatten() {
        for p in m.get_mut("primitives").and_then(Value::as_array_mut).into_iter().flatten() {
            p.get_mut("attributes").and_then(Value::as_object_mut).into_iter().flatten().for_each(|(_, a)| remap_acc(a));
            if let Some(i) = p.get_mut("indices") {
                remap_acc(i);
            }
            for t in p.get_mut("targets").and_then(Value::as_array_mut).into_iter().flatten() {
                t.as_object_mut().into_iter().flatten().for_each(|(_, a)| remap_acc(a));
            }
        }
    }
    for s in json.get_mut("skins").and_then(Value::as_array_mut).into_iter().flatten() {
        if let Some(i) = s.get_mut("inverseBindMatrices") {
            remap_acc(i);
        }
    }
    for a in json.get_mut("animations").and_then(Value::as_array_mut).into_iter().flatten() {
        for s in a.get_mut("samplers").and_then(Value::as_array_mut).into_iter().flatten() {
            for k in ["input", "output"] {
                if let Some(i) = s.get_mut(k) {
                    remap_acc(i);
                }
            }
        }
    }
    if let Some(accs) = json.get_mut("accessors").and_then(Value::as_array_mut) {
        let mut k = 0;
        accs.retain(|_| {
            k += 1;
            used_acc[k - 1]
        });
    }

    // Buffer views in use: by accessors (and their sparse parts) and images.
    let views: Vec<Value> = json.get("bufferViews").and_then(Value::as_array).cloned().unwrap_or_default();
    let mut used_view = vec![false; views.len()];
    let view_refs = |json: &mut Value, f: &mut dyn FnMut(&mut Value)| {
        for a in json.get_mut("accessors").and_then(Value::as_array_mut).into_iter().flatten() {
            if let Some(v) = a.get_mut("bufferView") {
                f(v);
            }
            for k in ["/sparse/indices/bufferView", "/sparse/values/bufferView"] {
                if let Some(v) = a.pointer_mut(k) {
                    f(v);
                }
            }
        }
        for im in json.get_mut("images").and_then(Value::as_array_mut).into_iter().flatten() {
            if let Some(v) = im.get_mut("bufferView") {
                f(v);
            }
        }
    };
    view_refs(json, &mut |v| {
        if let Some(i) = idx(v).filter(|&i| i < used_view.len()) {
            used_view[i] = true;
        }
    });
    let mut out = Vec::with_capacity(bin.len());
    let mut new_views = Vec::new();
    let mut view_map = vec![None; views.len()];
    for (i, v) in views.iter().enumerate() {
        let num = |k: &str| v.get(k).and_then(Value::as_u64).unwrap_or(0) as usize;
        let (off, len) = (num("byteOffset"), num("byteLength"));
        // Views of other buffers, or outside this one, stay as they are (the reader says why).
        if !used_view[i] || num("buffer") != 0 || off.checked_add(len).is_none_or(|e| e > bin.len()) {
            if used_view[i] {
                view_map[i] = Some(new_views.len());
                new_views.push(v.clone());
            }
            continue;
        }
        out.resize(out.len().next_multiple_of(4), 0);
        let mut nv = v.clone();
        nv["byteOffset"] = json!(out.len());
        out.extend_from_slice(&bin[off..off + len]);
        view_map[i] = Some(new_views.len());
        new_views.push(nv);
    }
    view_refs(json, &mut |v| {
        if let Some(n) = idx(v).and_then(|i| view_map.get(i).copied().flatten()) {
            *v = json!(n);
        }
    });
    let root = json.as_object_mut().expect("the root is an object (checked on reading)");
    // glTF forbids empty arrays and empty buffers.
    if new_views.is_empty() {
        root.remove("bufferViews");
    } else {
        root.insert("bufferViews".into(), Value::Array(new_views));
    }
    if root.get("accessors").and_then(Value::as_array).is_some_and(Vec::is_empty) {
        root.remove("accessors");
    }
    if out.is_empty() && !root.contains_key("bufferViews") {
        root.remove("buffers");
    } else if let Some(b) = root.get_mut("buffers").and_then(|b| b.get_mut(0)).and_then(Value::as_object_mut) {
        b.insert("byteLength".into(), json!(out.len()));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::gltf_in::{read_slice, Limits};

    /// A 2 m quad (positions, normals, u16 indices) in a GLB with `extra` applied to its
    /// JSON: mesh 0 has one primitive without material and without TEXCOORD_1.
    fn quad_glb(extra: impl FnOnce(&mut Value)) -> Vec<u8> {
        let pos: [[f32; 3]; 4] = [[-1.0, 0.0, -1.0], [-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, -1.0]];
        let nrm = [[0.0f32, 1.0, 0.0]; 4];
        let idx: [u16; 6] = [0, 1, 2, 0, 2, 3];
        let mut bin: Vec<u8> = Vec::new();
        bin.extend_from_slice(bytemuck::cast_slice(&pos));
        bin.extend_from_slice(bytemuck::cast_slice(&nrm));
        bin.extend_from_slice(bytemuck::cast_slice(&idx));
        bin.extend_from_slice(&[0, 0]);
        let mut json = json!({
            "asset": { "version": "2.0" },
            "buffers": [{ "byteLength": bin.len() }],
            "bufferViews": [
                { "buffer": 0, "byteOffset": 0, "byteLength": 48 },
                { "buffer": 0, "byteOffset": 48, "byteLength": 48 },
                { "buffer": 0, "byteOffset": 96, "byteLength": 12 },
            ],
            "accessors": [
                { "bufferView": 0, "componentType": FLOAT, "count": 4, "type": "VEC3", "min": [-1.0, 0.0, -1.0], "max": [1.0, 0.0, 1.0] },
                { "bufferView": 1, "componentType": FLOAT, "count": 4, "type": "VEC3" },
                { "bufferView": 2, "componentType": UNSIGNED_SHORT, "count": 6, "type": "SCALAR" },
            ],
            "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0, "NORMAL": 1 }, "indices": 2 }] }],
            "nodes": [{ "mesh": 0, "name": "a" }, { "mesh": 0, "name": "b", "translation": [5.0, 0.0, 0.0] }],
            "scenes": [{ "nodes": [0, 1] }],
            "scene": 0,
        });
        extra(&mut json);
        glb(&serde_json::to_vec(&json).unwrap(), Some(&bin)).unwrap()
    }

    fn plan() -> Plan {
        Plan { all: false, atlas: atlas::Options { texels_per_m: 8.0, padding: 1, max_size: 1024 } }
    }

    fn relaid(bytes: &[u8]) -> (Relayout, Vec<u8>, Scene) {
        let shown = Path::new("test.glb");
        let scene = read_slice(bytes, None, shown, &Limits::default()).unwrap();
        let rl = relayout_bytes(bytes, shown, &scene, &plan()).unwrap();
        let out = rl.to_glb().unwrap();
        let again = read_slice(&out, None, shown, &Limits::default()).unwrap();
        (rl, out, again)
    }

    #[test]
    fn an_instanced_mesh_gets_its_own_charts_per_node() {
        let (rl, out, scene) = relaid(&quad_glb(|_| {}));
        let a = rl.atlas.as_ref().expect("both quads charted");
        assert_eq!((a.primitives, a.triangles), (2, 4));
        let c = parse_container(&out, Path::new("out.glb")).unwrap();
        let (m0, m1) = (c.json["nodes"][0]["mesh"].as_u64().unwrap(), c.json["nodes"][1]["mesh"].as_u64().unwrap());
        assert_ne!(m0, m1, "the second node got a copy of the mesh");
        // Both quads lightmapped, on the same atlas, in different places: no texel is
        // shared (each quad's UV box is disjoint from the other's).
        assert_eq!(scene.mesh.triangles.len(), 4);
        let lm: Vec<_> = scene.mesh.tri_material.iter().map(|&m| scene.materials[m as usize].lightmap).collect();
        assert!(lm.iter().all(|l| l.is_some() && *l == lm[0]), "{lm:?}");
        let boxes: Vec<(glam::Vec2, glam::Vec2)> = [0usize, 2]
            .iter()
            .map(|&t| {
                let v: Vec<glam::Vec2> = scene.mesh.triangles[t..t + 2].iter().flatten().map(|&i| scene.mesh.uv1[i as usize]).collect();
                (v.iter().fold(glam::Vec2::MAX, |m, p| m.min(*p)), v.iter().fold(glam::Vec2::MIN, |m, p| m.max(*p)))
            })
            .collect();
        let overlap = (boxes[0].0.cmplt(boxes[1].1) & boxes[1].0.cmplt(boxes[0].1)).all();
        assert!(!overlap, "the two quads share atlas space: {boxes:?}");
        // Every accessor left is used, and no array is empty.
        let accs = c.json["accessors"].as_array().unwrap().len();
        let used: HashSet<u64> = c.json["meshes"].as_array().unwrap().iter().flat_map(|m| m["primitives"].as_array().unwrap()).flat_map(|p| p["attributes"].as_object().unwrap().values().chain(std::iter::once(&p["indices"]))).filter_map(Value::as_u64).collect();
        assert_eq!(used.len(), accs, "unreferenced accessors were kept");
    }

    #[test]
    fn primitives_that_cannot_be_gathered_are_left_alone_with_a_note() {
        // A sparse accessor on the second node's own mesh, and a malformed MOZ_lightmap.
        let bytes = quad_glb(|j| {
            j["meshes"].as_array_mut().unwrap().push(json!({ "primitives": [{ "attributes": { "POSITION": 3, "NORMAL": 1 }, "indices": 2, "material": 0 }] }));
            j["accessors"].as_array_mut().unwrap().push(json!({ "bufferView": 0, "componentType": FLOAT, "count": 4, "type": "VEC3", "min": [-1.0, 0.0, -1.0], "max": [1.0, 0.0, 1.0],
                "sparse": { "count": 1, "indices": { "bufferView": 2, "componentType": UNSIGNED_SHORT }, "values": { "bufferView": 1 } } }));
            j["nodes"][1]["mesh"] = json!(1);
            j["materials"] = json!([{ "name": "m", "extensions": { "MOZ_lightmap": 3 } }]);
            j["meshes"][0]["primitives"][0]["material"] = json!(0);
        });
        let (rl, out, scene) = relaid(&bytes);
        assert!(rl.notes.iter().any(|n| n.contains("sparse")), "{:?}", rl.notes);
        assert_eq!(rl.atlas.as_ref().unwrap().primitives, 1);
        assert_eq!(scene.mesh.triangles.len(), 4);
        // The material both primitives used is copied for the charted one; the kept one
        // still shows the original, without a lightmap.
        let c = parse_container(&out, Path::new("out.glb")).unwrap();
        let names: Vec<&str> = c.json["materials"].as_array().unwrap().iter().map(|m| m["name"].as_str().unwrap()).collect();
        assert_eq!(names, ["m", "m (baked)"]);
        assert!(c.json["materials"][0].get("occlusionTexture").is_none());
        assert_eq!(c.json["materials"][1]["occlusionTexture"]["texCoord"], 1);
    }
}
