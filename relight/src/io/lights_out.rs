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

use std::path::Path;

use glam::{DMat4, DVec3};
use serde_json::{json, Map, Value};

use q3gltf_convert::output::Staged;

use crate::error::{Error, Result};
use crate::io::container::{abs_dir, copy_resources, embed_resources, glb, is_glb, read_container, Container};

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
    /// The gamma the fit read the lightmap bytes through, where relight estimated it or
    /// was asked for it (`rows::gamma`): written as `q3_lightmap_gamma` on every lit
    /// material, so that bake, probe and a re-run read the bytes as this fit did.
    pub lightmap_gamma: Option<f64>,
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
        if let Some(e) = o.get_mut("extensions").and_then(Value::as_object_mut) {
            e.remove("KHR_materials_emissive_strength");
            if e.is_empty() {
                o.remove("extensions");
            }
        }
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
    if let Some(g) = out.lightmap_gamma {
        for m in root.get_mut("materials").and_then(Value::as_array_mut).into_iter().flatten() {
            if let Some(ex) = m.get_mut("extras").and_then(Value::as_object_mut) {
                if ex.get("q3_lighting").and_then(Value::as_str).is_some_and(|l| l != "none") {
                    ex.insert("q3_lightmap_gamma".into(), json!(g));
                }
            }
        }
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
        // Listed exactly when a material uses it (emission written dark can leave none).
        let used = root.entry("extensionsUsed").or_insert_with(|| json!([]));
        if let Some(u) = used.as_array_mut() {
            let listed = u.iter().any(|v| v == "KHR_materials_emissive_strength");
            if used_strength && !listed {
                u.push(json!("KHR_materials_emissive_strength"));
            } else if !used_strength && listed {
                u.retain(|v| v != "KHR_materials_emissive_strength");
            }
        }
        if let Some(r) = root.get_mut("extensionsRequired").and_then(Value::as_array_mut) {
            if !used_strength {
                r.retain(|v| v != "KHR_materials_emissive_strength");
            }
        }
        if root.get("extensionsRequired").and_then(Value::as_array).is_some_and(|r| r.is_empty()) {
            root.remove("extensionsRequired");
        }
        if root.get("extensionsUsed").and_then(Value::as_array).is_some_and(|u| u.is_empty()) {
            root.remove("extensionsUsed");
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
    let bytes = if is_glb(output) { glb(&text, bin.as_deref())? } else { text };
    staged.add(output, &bytes).map_err(|e| io_err(output, e))?;
    staged.commit().map_err(|e| io_err(output, e))
}

