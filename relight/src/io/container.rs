//! glTF containers as JSON trees: reading a `.gltf` or `.glb` into its JSON and BIN chunk,
//! resolving the external files its URIs name (relative paths inside the file's folder
//! only), embedding them into one BIN buffer, copying them beside an output elsewhere, and
//! writing a GLB. Shared by the writers that edit an input rather than rebuild it
//! ([`crate::io::lights_out`], [`crate::io::baked_gltf`]).

use std::path::{Path, PathBuf};

use serde_json::{json, Value};

use q3gltf_convert::output::Staged;

use crate::error::{Error, Result};

pub struct Container {
    pub json: Value,
    pub bin: Option<Vec<u8>>,
}

/// Reads a `.gltf` or `.glb` file into its JSON tree and BIN chunk.
pub fn read_container(path: &Path) -> Result<Container> {
    let bytes = std::fs::read(path).map_err(|e| Error::Io { path: path.display().to_string(), source: e })?;
    parse_container(&bytes, path)
}

/// [`read_container`] of bytes in memory; `path` names them in errors.
pub fn parse_container(bytes: &[u8], path: &Path) -> Result<Container> {
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
        let json = serde_json::from_slice(bytes).map_err(|e| Error::input(path, format!("JSON: {e}")))?;
        Ok(Container { json, bin: None })
    }
}

pub fn is_glb(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("glb"))
}

pub fn abs_dir(p: &Path) -> PathBuf {
    let dir = p.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf())
}

/// External (non-data) URIs of buffers and images: `(key, index, uri)`.
pub fn external_uris(json: &Value) -> Vec<(&'static str, usize, String)> {
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
pub fn read_resource(input: &Path, in_dir: &Path, uri: &str) -> Result<(PathBuf, Vec<u8>)> {
    let rel = PathBuf::from(crate::io::gltf_in::relative_uri(uri).map_err(|why| Error::input(input, format!("refused URI {:?} ({why})", uri.escape_debug().to_string())))?);
    let p = in_dir.join(&rel);
    let bytes = std::fs::read(&p).map_err(|e| Error::Io { path: p.display().to_string(), source: e })?;
    Ok((rel, bytes))
}

/// GLB output: buffer 0 and every external image go into the BIN chunk.
pub fn embed_resources(json: &mut Value, bin: &mut Option<Vec<u8>>, input: &Path, in_dir: &Path) -> Result<()> {
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
    let Some(b0) = buffers[0].as_object_mut() else { return Err(Error::input(input, "buffer 0 is not an object")) };
    b0.insert("byteLength".into(), json!(data.len()));
    *bin = Some(data);
    Ok(())
}

/// `.gltf` output in another folder: the input's external files are copied beside it,
/// at the same relative paths (staged with the rest of the output).
pub fn copy_resources(json: &Value, input: &Path, in_dir: &Path, out_dir: &Path, staged: &mut Staged) -> Result<()> {
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

/// A GLB of a JSON chunk and an optional BIN chunk; an error past GLB's 4 GiB.
pub fn glb(json: &[u8], bin: Option<&[u8]>) -> Result<Vec<u8>> {
    let pad = |n: usize| (4 - n % 4) % 4;
    let jl = json.len() + pad(json.len());
    let bl = bin.map_or(0, |b| b.len() + pad(b.len()));
    let total = 12 + 8 + jl + if bin.is_some() { 8 + bl } else { 0 };
    if total > u32::MAX as usize {
        return Err(Error::Usage(format!("a GLB of {total} bytes is over the format's 4 GiB")));
    }
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
    Ok(out)
}
