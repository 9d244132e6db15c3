//! Writing the relit scene: the input glTF unchanged (lightmap still in its slot, so
//! relight can run again on its output) plus `KHR_lights_punctual` point and spot lights
//! and the emission of the fitted surface lights and sky.
//!
//! The input's JSON is edited as a tree, never rebuilt, so whatever we do not understand
//! survives. Point and spot lights of the input are replaced: with `--init input` each
//! fitted light updates its own node and light entry (the node's local translation and
//! rotation are solved from its parent's world matrix); other input lights lose their
//! light (the node stays, as an empty). New lights get new root nodes `light_000`, ...
//!
//! A spot is written with q3map2's cone as `extras.q3_radius_by_dist` (read back exactly)
//! and, for renderers, `outerConeAngle = atan(radius_by_dist)` with the inner angle where
//! q3map2's soft edge (a fixed width, 32 units) begins at the distance the axis meets the
//! scene. Emission: `emissiveFactor` (colour, largest channel 1) and
//! `KHR_materials_emissive_strength` (radiance, W/(m^2 sr); only above 1).
//!
//! Containers. The output is always self-contained in its own folder, so that relight
//! (which reads only relative URIs inside the glTF's folder) and Blender can open it
//! again: a `.glb` output embeds the first buffer and every external image in its BIN
//! chunk; a `.gltf` output next to its input keeps the input's URIs; a `.gltf` output
//! in another folder gets copies of the input's external files at the same relative
//! paths (a `.glb` input's BIN chunk becomes `<output>.bin`). Data URIs stay as they are.
//! Every file of an output is staged under a temporary name and all are renamed together,
//! the glTF last ([`q3gltf_convert::output::Staged`]): an error or an interruption leaves
//! nothing. The input is never overwritten.

use std::path::{Path, PathBuf};

use glam::{DMat4, DVec3};
use serde_json::{json, Map, Value};

use q3gltf_convert::output::Staged;

use crate::error::{Error, Result};

/// A fitted light to write.
#[derive(Debug, Clone)]
pub struct OutLight {
    /// World position, meters.
    pub position: DVec3,
    /// Radiant intensity per channel, W/sr.
    pub rgb: [f64; 3],
    /// A spot's cone.
    pub spot: Option<OutSpot>,
    /// The input light (node index, parent world matrix) this one continues, if any.
    pub source_node: Option<(usize, DMat4)>,
    pub name: String,
    /// Statistics and flags for `extras` (merged into the light's extras).
    pub extras: Value,
    pub locked: bool,
}

/// A spot's cone (q3map2's: see [`crate::model::lights`]).
#[derive(Debug, Clone)]
pub struct OutSpot {
    /// Unit axis, world.
    pub axis: DVec3,
    pub radius_by_dist: f64,
    /// Width of the soft edge, m.
    pub ramp_m: f64,
    /// Where the axis meets the scene, m (where the inner angle is taken).
    pub typical_distance_m: f64,
}

impl OutSpot {
    /// glTF's (inner, outer) cone half-angles, radians.
    pub fn cone_angles(&self) -> (f64, f64) {
        let outer = self.radius_by_dist.max(1e-6).atan().clamp(1e-3, std::f64::consts::FRAC_PI_2 - 1e-3);
        let d = self.typical_distance_m.max(1e-3);
        let inner = ((self.radius_by_dist * d - self.ramp_m).max(0.0) / d).atan().min(outer * 0.999);
        (inner, outer)
    }
}

/// Everything `write` adds to the input.
pub struct Output<'a> {
    pub lights: &'a [OutLight],
    pub sun: Option<&'a OutSun>,
    /// Replace the input's directional lights by `sun` (the fit decided about the sun);
    /// otherwise they are kept as they are.
    pub replace_suns: bool,
    /// Material index (as in the input's `materials`) and its emitted radiance per
    /// channel, W/(m^2 sr).
    pub emissive: &'a [(usize, [f64; 3])],
    pub scene_extras: Value,
}

/// A fitted sun to write as a KHR_lights_punctual directional light.
#[derive(Debug, Clone)]
pub struct OutSun {
    /// Unit direction towards the sun, world axes.
    pub to_sun: DVec3,
    /// Irradiance at normal incidence per channel, W/m^2 (written as lux = 683 W/m^2).
    pub rgb: [f64; 3],
    pub name: String,
    pub extras: Value,
}

/// Luminous efficacy used by KHR_lights_punctual and Blender: candela = 683 * W/sr.
pub const LM_PER_W: f64 = 683.0;

/// The light's `range`: where its irradiance/pi at normal incidence falls to 1/256 of
/// "full brightness" (e = 1), `sqrt(256 I / pi)` meters.
pub fn range_m(intensity_w_sr: f64) -> f64 {
    (256.0 * intensity_w_sr.max(0.0) / std::f64::consts::PI).sqrt()
}

struct Container {
    json: Value,
    bin: Option<Vec<u8>>,
}

fn read_container(path: &Path) -> Result<Container> {
    let bytes = std::fs::read(path).map_err(|e| Error::Io { path: path.display().to_string(), source: e })?;
    if bytes.starts_with(b"glTF") {
        let bad = |m: &str| Error::input(path, format!("GLB: {m}"));
        let u32_at = |o: usize| -> Result<u32> { bytes.get(o..o + 4).map(|b| u32::from_le_bytes(b.try_into().unwrap())).ok_or_else(|| bad("truncated header")) };
        let total = (u32_at(8)? as usize).min(bytes.len());
        let mut off = 12;
        let mut json = None;
        let mut bin = None;
        while off + 8 <= total {
            let len = u32_at(off)? as usize;
            let kind = u32_at(off + 4)?;
            let body = bytes.get(off + 8..off + 8 + len).ok_or_else(|| bad("chunk runs past the end"))?;
            match kind {
                0x4E4F_534A => json = Some(serde_json::from_slice(body).map_err(|e| bad(&format!("JSON chunk: {e}")))?),
                0x004E_4942 => bin = Some(body.to_vec()),
                _ => {}
            }
            off += 8 + len;
        }
        Ok(Container { json: json.ok_or_else(|| bad("no JSON chunk"))?, bin })
    } else {
        let json = serde_json::from_slice(&bytes).map_err(|e| Error::input(path, format!("JSON: {e}")))?;
        Ok(Container { json, bin: None })
    }
}

fn is_glb(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("glb"))
}

fn abs_dir(p: &Path) -> PathBuf {
    let dir = p.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf())
}

/// External (non-data) URIs of buffers and images: `(key, index, uri)`.
fn external_uris(json: &Value) -> Vec<(&'static str, usize, String)> {
    let mut out = Vec::new();
    for key in ["buffers", "images"] {
        let Some(arr) = json.get(key).and_then(Value::as_array) else { continue };
        for (i, item) in arr.iter().enumerate() {
            if let Some(uri) = item.get("uri").and_then(Value::as_str).filter(|u| !u.starts_with("data:")) {
                out.push((key, i, uri.to_string()));
            }
        }
    }
    out
}

/// Reads the file an external URI of the input names.
fn read_resource(input: &Path, in_dir: &Path, uri: &str) -> Result<(PathBuf, Vec<u8>)> {
    let rel = PathBuf::from(crate::io::gltf_in::relative_uri(uri).map_err(|why| Error::input(input, format!("refused URI {:?} ({why})", uri.escape_debug().to_string())))?);
    let p = in_dir.join(&rel);
    let bytes = std::fs::read(&p).map_err(|e| Error::Io { path: p.display().to_string(), source: e })?;
    Ok((rel, bytes))
}

/// GLB output: buffer 0 and every external image go into the BIN chunk.
fn embed_resources(json: &mut Value, bin: &mut Option<Vec<u8>>, input: &Path, in_dir: &Path) -> Result<()> {
    let mut data = bin.take().unwrap_or_default();
    if let Some(uri) = json.pointer("/buffers/0/uri").and_then(Value::as_str).filter(|u| !u.starts_with("data:")).map(str::to_string) {
        data = read_resource(input, in_dir, &uri)?.1;
        json["buffers"][0].as_object_mut().map(|o| o.remove("uri"));
    }
    let images: Vec<(usize, String)> = external_uris(json).into_iter().filter(|e| e.0 == "images").map(|e| (e.1, e.2)).collect();
    if images.is_empty() && data.is_empty() {
        return Ok(());
    }
    for (i, uri) in images {
        let (rel, bytes) = read_resource(input, in_dir, &uri)?;
        let ext = rel.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
        let mime = json["images"][i].get("mimeType").and_then(Value::as_str).map(str::to_string).or_else(|| match ext.as_str() {
            "png" => Some("image/png".into()),
            "jpg" | "jpeg" => Some("image/jpeg".into()),
            _ => None,
        });
        // glTF allows only PNG and JPEG in buffer views; anything else stays beside the file.
        let Some(mime) = mime else { continue };
        data.resize(data.len().next_multiple_of(4), 0);
        let views = json.as_object_mut().unwrap().entry("bufferViews").or_insert_with(|| json!([]));
        let Some(views) = views.as_array_mut() else { return Err(Error::input(input, "bufferViews is not an array")) };
        views.push(json!({ "buffer": 0, "byteOffset": data.len(), "byteLength": bytes.len() }));
        let view = views.len() - 1;
        data.extend_from_slice(&bytes);
        let img = json["images"][i].as_object_mut().unwrap();
        img.remove("uri");
        img.insert("bufferView".into(), json!(view));
        img.insert("mimeType".into(), json!(mime));
    }
    let buffers = json.as_object_mut().unwrap().entry("buffers").or_insert_with(|| json!([]));
    let Some(buffers) = buffers.as_array_mut() else { return Err(Error::input(input, "buffers is not an array")) };
    if buffers.is_empty() {
        buffers.push(json!({}));
    }
    buffers[0]["byteLength"] = json!(data.len());
    *bin = Some(data);
    Ok(())
}

/// `.gltf` output in another folder: the input's external files are copied beside it,
/// at the same relative paths (staged with the rest of the output).
fn copy_resources(json: &Value, input: &Path, in_dir: &Path, out_dir: &Path, staged: &mut Staged) -> Result<()> {
    for (_, _, uri) in external_uris(json) {
        let (rel, bytes) = read_resource(input, in_dir, &uri)?;
        let dest = out_dir.join(&rel);
        if q3gltf_convert::output::same_file(&dest, input) {
            return Err(Error::Usage(format!("{}: copying {uri:?} there would overwrite the input", dest.display())));
        }
        if let Some(parent) = dest.parent() {
            staged.create_dir_all(parent).map_err(|e| Error::Io { path: parent.display().to_string(), source: e })?;
        }
        staged.add(&dest, &bytes).map_err(|e| Error::Io { path: dest.display().to_string(), source: e })?;
    }
    Ok(())
}

fn light_json(l: &OutLight) -> Value {
    let m = l.rgb.iter().copied().fold(0.0f64, f64::max);
    let color = if m > 0.0 { l.rgb.map(|c| c / m) } else { [1.0; 3] };
    let mut extras = match &l.extras {
        Value::Object(o) => o.clone(),
        _ => Map::new(),
    };
    if l.locked {
        extras.insert("locked".into(), Value::Bool(true));
    }
    let mut v = json!({
        "name": l.name,
        "type": "point",
        "color": color,
        "intensity": m * LM_PER_W,
        "range": range_m(m),
    });
    if let Some(s) = &l.spot {
        let (inner, outer) = s.cone_angles();
        v["type"] = json!("spot");
        v["spot"] = json!({ "innerConeAngle": inner, "outerConeAngle": outer });
        extras.insert("q3_radius_by_dist".into(), json!(s.radius_by_dist));
    }
    v["extras"] = Value::Object(extras);
    v
}

/// The rotation that turns a node's -Z (where glTF lights shine) onto `axis`.
fn rotation_to(axis: DVec3) -> glam::DQuat {
    glam::DQuat::from_rotation_arc(DVec3::NEG_Z, axis.normalize_or(DVec3::NEG_Y))
}

/// Sets material `m`'s emission to `radiance` (per channel).
fn set_emission(m: &mut Value, radiance: [f64; 3]) {
    let peak = radiance.iter().copied().fold(0.0f64, f64::max);
    let Some(o) = m.as_object_mut() else { return };
    if !(peak > 0.0) {
        o.remove("emissiveFactor");
        return;
    }
    let ext = o.entry("extensions").or_insert_with(|| json!({}));
    if peak <= 1.0 {
        o.insert("emissiveFactor".into(), json!(radiance));
        if let Some(e) = o.get_mut("extensions").and_then(Value::as_object_mut) {
            e.remove("KHR_materials_emissive_strength");
        }
    } else {
        ext["KHR_materials_emissive_strength"] = json!({ "emissiveStrength": peak });
        o.insert("emissiveFactor".into(), json!(radiance.map(|c| c / peak)));
    }
    if o.get("extensions").and_then(Value::as_object).is_some_and(|e| e.is_empty()) {
        o.remove("extensions");
    }
}

/// Writes `input` plus `out` to `output`.
pub fn write(input: &Path, output: &Path, out: &Output) -> Result<()> {
    let (lights, sun, replace_suns, scene_extras) = (out.lights, out.sun, out.replace_suns, out.scene_extras.clone());
    if q3gltf_convert::output::same_file(output, input) {
        return Err(Error::Usage(format!("{}: the output would overwrite the input", output.display())));
    }
    let Container { mut json, bin } = read_container(input)?;
    let root = json.as_object_mut().ok_or_else(|| Error::input(input, "top level is not an object"))?;

    // The lights array: drop the input's point lights, keep the others, re-index nodes.
    let old_lights: Vec<Value> = root
        .get("extensions")
        .and_then(|e| e.get("KHR_lights_punctual"))
        .and_then(|k| k.get("lights"))
        .and_then(Value::as_array)
        .cloned()
        .unwrap_or_default();
    let mut remap = vec![None; old_lights.len()];
    let mut new_lights = Vec::new();
    for (i, l) in old_lights.iter().enumerate() {
        let kind = l.get("type").and_then(Value::as_str);
        if kind != Some("point") && kind != Some("spot") && !(replace_suns && kind == Some("directional")) {
            remap[i] = Some(new_lights.len());
            new_lights.push(l.clone());
        }
    }
    let nodes = root.entry("nodes").or_insert_with(|| json!([]));
    let nodes = nodes.as_array_mut().ok_or_else(|| Error::input(input, "nodes is not an array"))?;
    for node in nodes.iter_mut() {
        let Some(ext) = node.get_mut("extensions").and_then(Value::as_object_mut) else { continue };
        let Some(idx) = ext.get("KHR_lights_punctual").and_then(|k| k.get("light")).and_then(Value::as_u64) else { continue };
        match remap.get(idx as usize).copied().flatten() {
            Some(n) => ext["KHR_lights_punctual"]["light"] = json!(n),
            None => {
                ext.remove("KHR_lights_punctual");
            }
        }
        if ext.is_empty() {
            node.as_object_mut().map(|o| o.remove("extensions"));
        }
    }
    let mut new_roots = Vec::new();
    for l in lights {
        let index = new_lights.len();
        new_lights.push(light_json(l));
        let attach = json!({ "KHR_lights_punctual": { "light": index } });
        match l.source_node {
            Some((node, parent)) if node < nodes.len() => {
                let local = parent.inverse().transform_point3(l.position);
                let n = &mut nodes[node];
                if let Some(m) = n.get_mut("matrix").and_then(Value::as_array_mut) {
                    if m.len() == 16 {
                        m[12] = json!(local.x);
                        m[13] = json!(local.y);
                        m[14] = json!(local.z);
                    }
                } else {
                    n["translation"] = json!([local.x, local.y, local.z]);
                    if let Some(s) = &l.spot {
                        let (_, parent_rot, _) = parent.to_scale_rotation_translation();
                        let q = parent_rot.inverse() * rotation_to(s.axis);
                        n["rotation"] = json!([q.x, q.y, q.z, q.w]);
                    }
                }
                n["name"] = json!(l.name);
                let ext = n.as_object_mut().unwrap().entry("extensions").or_insert_with(|| json!({}));
                ext["KHR_lights_punctual"] = attach["KHR_lights_punctual"].clone();
                if l.locked {
                    n["extras"]["locked"] = Value::Bool(true);
                }
            }
            _ => {
                new_roots.push(nodes.len());
                let mut node = json!({
                    "name": l.name,
                    "translation": [l.position.x, l.position.y, l.position.z],
                    "extensions": attach,
                });
                if let Some(s) = &l.spot {
                    let q = rotation_to(s.axis);
                    node["rotation"] = json!([q.x, q.y, q.z, q.w]);
                }
                nodes.push(node);
            }
        }
    }
    if let Some(sun) = sun {
        let index = new_lights.len();
        let m = sun.rgb.iter().copied().fold(0.0f64, f64::max);
        let mut light = json!({
            "type": "directional",
            "name": sun.name,
            "color": if m > 0.0 { sun.rgb.map(|c| c / m) } else { [1.0; 3] },
            "intensity": m * LM_PER_W,
        });
        if !sun.extras.is_null() {
            light["extras"] = sun.extras.clone();
        }
        new_lights.push(light);
        // The light shines along the node's -Z: rotate +Z onto the direction to the sun.
        let q = glam::DQuat::from_rotation_arc(DVec3::Z, sun.to_sun.normalize_or(DVec3::Y));
        new_roots.push(nodes.len());
        nodes.push(json!({ "name": sun.name, "rotation": [q.x, q.y, q.z, q.w], "extensions": { "KHR_lights_punctual": { "light": index } } }));
    }
    if !out.emissive.is_empty() {
        let materials = root.get_mut("materials").and_then(Value::as_array_mut);
        if let Some(materials) = materials {
            for &(mi, radiance) in out.emissive {
                if let Some(m) = materials.get_mut(mi) {
                    set_emission(m, radiance);
                }
            }
        }
        let used_strength = root.get("materials").and_then(Value::as_array).is_some_and(|ms| ms.iter().any(|m| m.get("extensions").and_then(|e| e.get("KHR_materials_emissive_strength")).is_some()));
        let used = root.entry("extensionsUsed").or_insert_with(|| json!([]));
        if let Some(u) = used.as_array_mut() {
            if used_strength && !u.iter().any(|v| v == "KHR_materials_emissive_strength") {
                u.push(json!("KHR_materials_emissive_strength"));
            }
        }
    }
    let scene_index = root.get("scene").and_then(Value::as_u64).unwrap_or(0) as usize;
    let scenes = root.entry("scenes").or_insert_with(|| json!([{ "nodes": [] }]));
    if let Some(scene) = scenes.as_array_mut().and_then(|s| s.get_mut(scene_index)) {
        let list = scene.as_object_mut().unwrap().entry("nodes").or_insert_with(|| json!([]));
        if let Some(list) = list.as_array_mut() {
            list.extend(new_roots.into_iter().map(|n| json!(n)));
        }
        if !scene_extras.is_null() {
            scene["extras"]["q3_relight"] = scene_extras;
        }
    }
    let exts = root.entry("extensions").or_insert_with(|| json!({}));
    if new_lights.is_empty() {
        exts.as_object_mut().map(|o| o.remove("KHR_lights_punctual"));
    } else {
        exts["KHR_lights_punctual"] = json!({ "lights": new_lights });
    }
    if exts.as_object().is_some_and(|o| o.is_empty()) {
        root.remove("extensions");
    }
    let used = root.entry("extensionsUsed").or_insert_with(|| json!([]));
    if let Some(u) = used.as_array_mut() {
        if !new_lights.is_empty() && !u.iter().any(|v| v == "KHR_lights_punctual") {
            u.push(json!("KHR_lights_punctual"));
        }
    }
    if root.get("extensionsUsed").and_then(Value::as_array).is_some_and(|u| u.is_empty()) {
        root.remove("extensionsUsed");
    }

    let (in_dir, out_dir) = (abs_dir(input), abs_dir(output));
    let io_err = |p: &Path, e: std::io::Error| Error::Io { path: p.display().to_string(), source: e };
    let mut bin = bin;
    let mut staged = Staged::new();
    if is_glb(output) {
        embed_resources(&mut json, &mut bin, input, &in_dir)?;
    } else {
        if in_dir != out_dir {
            copy_resources(&json, input, &in_dir, &out_dir, &mut staged)?;
        }
        if let Some(b) = bin.take() {
            let bin_path = output.with_extension("bin");
            if q3gltf_convert::output::same_file(&bin_path, input) {
                return Err(Error::Usage(format!("{}: the buffer would overwrite the input", bin_path.display())));
            }
            staged.add(&bin_path, &b).map_err(|e| io_err(&bin_path, e))?;
            let name = bin_path.file_name().unwrap().to_string_lossy().replace('%', "%25").replace(' ', "%20");
            if let Some(b0) = json.get_mut("buffers").and_then(|b| b.get_mut(0)) {
                b0["uri"] = json!(name);
            }
        }
    }
    let text = serde_json::to_vec(&json).map_err(|e| Error::Usage(format!("JSON: {e}")))?;
    let bytes = if is_glb(output) { glb(&text, bin.as_deref()) } else { text };
    staged.add(output, &bytes).map_err(|e| io_err(output, e))?;
    staged.commit().map_err(|e| io_err(output, e))
}

fn glb(json: &[u8], bin: Option<&[u8]>) -> Vec<u8> {
    let pad = |n: usize| (4 - n % 4) % 4;
    let jl = json.len() + pad(json.len());
    let bl = bin.map_or(0, |b| b.len() + pad(b.len()));
    let total = 12 + 8 + jl + if bin.is_some() { 8 + bl } else { 0 };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(jl as u32).to_le_bytes());
    out.extend_from_slice(&0x4E4F_534Au32.to_le_bytes());
    out.extend_from_slice(json);
    out.resize(out.len() + pad(json.len()), b' ');
    if let Some(b) = bin {
        out.extend_from_slice(&(bl as u32).to_le_bytes());
        out.extend_from_slice(&0x004E_4942u32.to_le_bytes());
        out.extend_from_slice(b);
        out.resize(out.len() + pad(b.len()), 0);
    }
    out
}
