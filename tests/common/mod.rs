//! Shared helpers for the integration tests: the OpenArena data (fetched and cached by
//! `samples/fetch-openarena.sh`) and the maps of one pk3.
#![allow(dead_code)]

use q3gltf_convert::bsp::Bsp;
use q3gltf_convert::pipeline::LoadedMap;
use q3gltf_convert::vfs::Vfs;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs `samples/fetch-openarena.sh` with `args` (it caches what it fetches) and returns
/// the folder it prints, checked to hold `expect`.
fn fetched(args: &[&str], expect: &str) -> PathBuf {
    let out = std::process::Command::new("bash")
        .arg(repo().join("samples/fetch-openarena.sh"))
        .args(args)
        .output()
        .expect("run samples/fetch-openarena.sh");
    assert!(out.status.success(), "fetching OpenArena data ({args:?}) failed: {}", String::from_utf8_lossy(&out.stderr));
    let dir = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim().to_string());
    assert!(dir.join(expect).is_file(), "no {expect} in {}", dir.display());
    dir
}

/// The `baseoa` game directory, fetched on first use (the script caches it).
pub fn baseoa() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| fetched(&[], "pak1-maps.pk3"))
}

/// The folder of the OpenArena community map pack vol. 1 (`z_oacmp-volume1-v3.pk3`, with
/// the maps' `.map` sources), fetched on first use; a second game dir after baseoa.
pub fn oacmp() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| fetched(&["--oacmp"], "z_oacmp-volume1-v3.pk3"))
}

/// One file of a pk3 (a zip), written to `out`.
pub fn extract(pk3: &Path, name: &str, out: &Path) {
    let mut vfs = Vfs::new();
    vfs.mount_pk3(pk3).unwrap();
    let bytes = vfs.read(name).unwrap_or_else(|e| panic!("{}:{name}: {e}", pk3.display()));
    std::fs::write(out, bytes).unwrap();
}

/// Names (`maps/x.bsp`) of the maps inside one pk3 of baseoa.
pub fn maps_in(pk3: &str) -> Vec<String> {
    let mut vfs = Vfs::new();
    vfs.mount_pk3(&baseoa().join(pk3)).unwrap();
    vfs.list("maps", "bsp")
}

/// A map from a specific pk3 (not the overriding newer version), with the whole of
/// baseoa mounted for textures and shaders.
pub fn load_from(pk3: &str, map: &str) -> LoadedMap {
    let mut only = Vfs::new();
    only.mount_pk3(&baseoa().join(pk3)).unwrap();
    let bytes = only.read(map).unwrap();
    let bsp = Bsp::parse(&bytes).unwrap_or_else(|e| panic!("{pk3}:{map}: {e}"));
    let mut vfs = Vfs::new();
    vfs.mount_dir(baseoa()).unwrap();
    let name = Path::new(map).file_stem().unwrap().to_string_lossy().into_owned();
    LoadedMap { vfs, bsp, name, shown: format!("{pk3}:{map}"), path: None }
}

/// Every map of pak1-maps.pk3 and pak6-patch088.pk3, as (pk3, map name).
pub fn all_test_maps() -> Vec<(&'static str, String)> {
    let mut v: Vec<(&'static str, String)> = maps_in("pak1-maps.pk3").into_iter().map(|m| ("pak1-maps.pk3", m)).collect();
    v.extend(maps_in("pak6-patch088.pk3").into_iter().map(|m| ("pak6-patch088.pk3", m)));
    v
}

/// Replaces a glTF document's KHR_lights_punctual lights with `lights`, each a (light
/// definition, node) pair; the node's `light` index is set here. Nodes keep everything
/// but their old light extensions; the new nodes become scene roots.
pub fn set_lights(json: &mut serde_json::Value, lights: Vec<(serde_json::Value, serde_json::Value)>) {
    use serde_json::Value;
    let mut nodes: Vec<Value> = json["nodes"].as_array().cloned().unwrap_or_default();
    for n in nodes.iter_mut() {
        if let Some(o) = n.as_object_mut() {
            o.remove("extensions");
        }
    }
    let mut roots: Vec<Value> = json["scenes"][0]["nodes"].as_array().cloned().unwrap_or_default();
    let mut defs = Vec::new();
    for (k, (light, mut node)) in lights.into_iter().enumerate() {
        defs.push(light);
        node["extensions"] = serde_json::json!({ "KHR_lights_punctual": { "light": k } });
        nodes.push(node);
        roots.push((nodes.len() - 1).into());
    }
    json["nodes"] = Value::Array(nodes);
    json["scenes"][0]["nodes"] = Value::Array(roots);
    json["extensions"]["KHR_lights_punctual"] = serde_json::json!({ "lights": defs });
    let used = json["extensionsUsed"].as_array().cloned().unwrap_or_default();
    if !used.iter().any(|u| u == "KHR_lights_punctual") {
        json["extensionsUsed"] = Value::Array(used.into_iter().chain([Value::from("KHR_lights_punctual")]).collect());
    }
}

/// The optional terms' decisions in a relight report (`terms`, in the order decided):
/// a term left out with `auto` never takes the error more than `TERM_GAIN` above the
/// lowest error any decision reached (each small loss counts against one allowance).
pub fn assert_terms_within_allowance(name: &str, report: &serde_json::Value) {
    let gain = q3gltf_relight::pipeline::TERM_GAIN;
    let mut lowest = f64::INFINITY;
    for t in report["terms"].as_array().expect("the report lists the terms") {
        let with = t["rel_error_with"].as_f64().unwrap_or(f64::INFINITY);
        let without = t["rel_error_without"].as_f64().unwrap_or(f64::INFINITY);
        lowest = lowest.min(with).min(without);
        let note = t["note"].as_str().unwrap_or_default();
        if note.starts_with("not used") {
            assert!(without <= lowest + gain + 1e-12, "{name}: leaving out {} took the error to {without:.4}, more than {gain} above the lowest reached, {lowest:.4}: {}", t["term"], report["terms"]);
        }
    }
}

/// The CSV `relight --dump-rows` writes, by column name.
pub struct RowsDump {
    head: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl RowsDump {
    pub fn read(path: &Path) -> RowsDump {
        let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let mut lines = text.lines();
        let head = lines.next().unwrap_or_default().split(',').map(str::to_string).collect();
        // The material name is the first field and has no commas (shader paths).
        let rows = lines.map(|l| l.split(',').map(str::to_string).collect()).collect();
        RowsDump { head, rows }
    }

    /// A column's values, NaN where the field is empty (a lower bound's missing upper end).
    pub fn column(&self, name: &str) -> Vec<f64> {
        let k = self.head.iter().position(|h| h == name).unwrap_or_else(|| panic!("no column {name}"));
        self.rows.iter().map(|r| r.get(k).and_then(|v| v.parse().ok()).unwrap_or(f64::NAN)).collect()
    }
}
