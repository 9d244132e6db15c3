//! Material resolution: from a BSP shader record and the shader scripts to what a glTF
//! material needs (albedo image file, alpha mode, sidedness) and whether the surface is
//! drawn at all.
//!
//! Albedo rule (as the issue and the engine's texture lookup): the first stage image
//! that is not `$lightmap` / `$whiteimage` (an `animMap` gives its first frame), else
//! `qer_editorimage`, else the shader name itself. Each candidate name is looked up as
//! given, then with `.tga`, `.jpg` and `.png` (the engine swaps extensions the same way).

use crate::bsp::{contents, surf, ShaderRef};
use crate::scene::AlphaMode;
use crate::shader::{AlphaFunc, Cull, ShaderDef, ShaderLibrary, Sun};
use crate::vfs::Vfs;

/// Whether and where a surface is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Visibility {
    Drawn,
    /// Goes to the sky node (or is dropped with `--no-sky`).
    Sky,
    /// Not drawn; the reason names the rule.
    Hidden(&'static str),
}

/// What the converter needs to know about one shader.
#[derive(Debug, Clone, PartialEq)]
pub struct ShaderInfo {
    pub name: String,
    pub visibility: Visibility,
    /// VFS path of the albedo image, if found.
    pub image: Option<String>,
    /// The first name that was looked for, when nothing was found.
    pub missing: Option<String>,
    pub alpha: AlphaMode,
    pub double_sided: bool,
    /// `q3map_sun` of a sky shader.
    pub sun: Option<Sun>,
    /// Whether a shader script defines this shader.
    pub scripted: bool,
}

/// Tool textures that are never drawn, by last path component under `textures/common/`.
const TOOL_NAMES: [&str; 14] = [
    "caulk", "nodraw", "nodrawnonsolid", "clip", "full_clip", "weapclip", "botclip", "hint", "skip",
    "areaportal", "trigger", "fog", "nodrop", "donotenter",
];

fn strip_ext(name: &str) -> &str {
    match name.rsplit_once('.') {
        Some((stem, ext)) if !ext.contains('/') && ext.len() <= 4 => stem,
        _ => name,
    }
}

/// Looks an image up by name, trying the engine's alternative extensions.
pub fn find_image(vfs: &Vfs, name: &str) -> Option<String> {
    let name = name.trim().replace('\\', "/");
    if name.is_empty() {
        return None;
    }
    if vfs.contains(&name) && name.rsplit_once('.').is_some_and(|(_, e)| matches!(e.to_ascii_lowercase().as_str(), "tga" | "jpg" | "jpeg" | "png")) {
        return crate::vfs::normalize(&name);
    }
    let stem = strip_ext(&name);
    ["tga", "jpg", "png", "jpeg"].iter().map(|e| format!("{stem}.{e}")).find(|c| vfs.contains(c)).and_then(|c| crate::vfs::normalize(&c))
}

/// Resolves one BSP shader record.
pub fn resolve(r: &ShaderRef, lib: &ShaderLibrary, vfs: &Vfs) -> ShaderInfo {
    let def = lib.get(&r.name);
    let lower = r.name.to_ascii_lowercase();
    let visibility = visibility(r, def, &lower);
    let mut info = ShaderInfo {
        name: r.name.clone(),
        visibility,
        image: None,
        missing: None,
        alpha: AlphaMode::Opaque,
        double_sided: false,
        sun: def.and_then(|d| d.sun),
        scripted: def.is_some(),
    };
    if visibility != Visibility::Drawn && visibility != Visibility::Sky {
        return info;
    }
    let mut candidates: Vec<&str> = Vec::new();
    if let Some(d) = def {
        info.double_sided = d.cull == Cull::None;
        if let Some((stage, img)) = d.albedo_stage() {
            candidates.push(img);
            info.alpha = match stage.alpha_func {
                Some(AlphaFunc::Gt0) => AlphaMode::Mask(0.001),
                Some(AlphaFunc::Lt128) | Some(AlphaFunc::Ge128) => AlphaMode::Mask(0.5),
                None => AlphaMode::Opaque,
            };
            // The shader is translucent when its first stage blends over the scene.
            if d.stages.first().is_some_and(|s| s.is_blended()) {
                info.alpha = AlphaMode::Blend;
            }
        }
        if let Some(e) = &d.editor_image {
            candidates.push(e);
        }
    }
    candidates.push(&r.name);
    for c in &candidates {
        if let Some(found) = find_image(vfs, c) {
            info.image = Some(found);
            return info;
        }
    }
    info.missing = candidates.first().map(|c| c.to_string());
    info
}

fn visibility(r: &ShaderRef, def: Option<&ShaderDef>, lower: &str) -> Visibility {
    if r.surface_flags & surf::NODRAW != 0 {
        return Visibility::Hidden("nodraw");
    }
    if r.surface_flags & (surf::SKIP | surf::HINT) != 0 {
        return Visibility::Hidden("hint/skip");
    }
    if r.content_flags & contents::FOG != 0 || def.is_some_and(|d| d.fog) {
        return Visibility::Hidden("fog");
    }
    if r.content_flags & contents::AREAPORTAL != 0 {
        return Visibility::Hidden("areaportal");
    }
    if let Some(d) = def {
        if d.has_parm("nodraw") {
            return Visibility::Hidden("nodraw");
        }
    }
    if let Some(rest) = lower.strip_prefix("textures/common/") {
        if TOOL_NAMES.iter().any(|t| rest == *t) {
            return Visibility::Hidden("tool texture");
        }
    }
    if lower == "noshader" {
        return Visibility::Hidden("noshader");
    }
    if r.surface_flags & surf::SKY != 0 || def.is_some_and(|d| d.sky) {
        return Visibility::Sky;
    }
    Visibility::Drawn
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tool_and_flagged_shaders_are_hidden() {
        let lib = ShaderLibrary::default();
        let vfs = Vfs::new();
        let r = |name: &str, sf: i32, cf: i32| ShaderRef { name: name.into(), surface_flags: sf, content_flags: cf };
        assert_eq!(resolve(&r("textures/common/caulk", 0, 1), &lib, &vfs).visibility, Visibility::Hidden("tool texture"));
        assert_eq!(resolve(&r("textures/x/y", surf::NODRAW, 1), &lib, &vfs).visibility, Visibility::Hidden("nodraw"));
        assert_eq!(resolve(&r("textures/x/fogwater", 0, contents::FOG), &lib, &vfs).visibility, Visibility::Hidden("fog"));
        assert_eq!(resolve(&r("textures/skies/x", surf::SKY, 0), &lib, &vfs).visibility, Visibility::Sky);
        let wall = resolve(&r("textures/x/wall", 0, 1), &lib, &vfs);
        assert_eq!(wall.visibility, Visibility::Drawn);
        assert_eq!(wall.missing.as_deref(), Some("textures/x/wall"));
    }
}
