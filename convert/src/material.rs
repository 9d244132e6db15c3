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
    /// How q3map2 lit the map with this shader.
    pub light: LightInfo,
}

/// What q3map2 does with a shader when it lights a map (its `light` stage).
#[derive(Debug, Clone, PartialEq)]
pub struct LightInfo {
    /// `q3map_surfacelight`: the surface emits.
    pub surface: Option<SurfaceLight>,
    /// `q3map_skyLight` value and iterations (sky shaders).
    pub sky_lights: Vec<(f64, u32)>,
    /// The colour q3map2 gives the sky light's suns: the shader's light colour (as a
    /// surface light's), largest channel 1.
    pub sky_color: [f64; 3],
    /// Blocks light: translucent shaders (`trans`, `water`, `slime`, `lava`) cast no
    /// shadow unless `alphashadow` or `lightfilter`. Translucent when the script says so
    /// or when the BSP's shader record does: the record keeps the flags the compile itself
    /// read, which can differ from the scripts at hand (oacmpdm4's blue flames were
    /// compiled translucent, and the scripts shipped today make them opaque).
    pub casts_shadow: bool,
}

impl Default for LightInfo {
    fn default() -> Self {
        LightInfo { surface: None, sky_lights: Vec::new(), sky_color: [1.0; 3], casts_shadow: true }
    }
}

/// A `q3map_surfacelight` shader, with q3map2's defaults filled in.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceLight {
    /// q3map2's value: a surface filling a sample's hemisphere adds `0.75 value` bytes
    /// (`formFactorValueScale 3 x areaScale 0.25`).
    pub value: f64,
    /// Linear RGB with its largest channel 1: `q3map_lightRGB`, else the average of the
    /// light image's bytes (`q3map_lightImage`, else the shader's own image), as q3map2.
    pub color: [f64; 3],
    /// Largest extent of one emitting patch, Quake units (q3map2's default 999).
    pub subdivide: f64,
    /// The backsplash light: a copy of each patch this far in front of it (Quake units),
    /// facing back, with this fraction of its value (times 7; default 5% at 23 units; sky
    /// shaders have none).
    pub backsplash_fraction: f64,
    pub backsplash_distance: f64,
}

/// q3map2's `defaultLightSubdivide`, `DEF_BACKSPLASH_FRACTION` and `DEF_BACKSPLASH_DISTANCE`.
pub const DEFAULT_LIGHT_SUBDIVIDE: f64 = 999.0;
pub const DEFAULT_BACKSPLASH: (f64, f64) = (0.05, 23.0);

/// Largest light image decoded to find a surface light's colour, bytes.
const LIGHT_IMAGE_LIMITS: crate::texture::Limits = crate::texture::Limits { max_side: 8192, max_alloc: 1 << 28 };

fn light_info(def: Option<&ShaderDef>, r: &ShaderRef, vfs: &Vfs) -> LightInfo {
    let name = r.name.as_str();
    let casts_shadow = casts_shadow(def, r);
    let Some(d) = def else { return LightInfo { casts_shadow, ..LightInfo::default() } };
    let emits = d.surface_light.is_some_and(|v| v > 0.0) || !d.sky_lights.is_empty();
    let color = if emits { d.light_rgb.map(normalized).unwrap_or_else(|| light_image_color(d, name, vfs)) } else { [1.0; 3] };
    let surface = d.surface_light.filter(|v| *v > 0.0).map(|value| {
        let sky = d.sky || d.has_parm("sky");
        let (backsplash_fraction, backsplash_distance) = if sky { (0.0, 0.0) } else { d.backsplash.unwrap_or(DEFAULT_BACKSPLASH) };
        SurfaceLight { value, color, subdivide: d.light_subdivide.unwrap_or(DEFAULT_LIGHT_SUBDIVIDE), backsplash_fraction, backsplash_distance }
    });
    LightInfo { surface, sky_lights: d.sky_lights.clone(), sky_color: color, casts_shadow }
}

/// q3map2's rule for the surfaces its light stage traces (`PopulateWithBSPModel`): a
/// translucent shader casts no shadow unless it is an alpha shadow or a light filter. The
/// script's surface parameters and the BSP record's flags (what the compile read) each
/// count.
fn casts_shadow(def: Option<&ShaderDef>, r: &ShaderRef) -> bool {
    let script = def.is_some_and(|d| ["trans", "water", "slime", "lava"].iter().any(|p| d.has_parm(p)));
    let record = r.content_flags & crate::solids::TRANSLUCENT_CONTENTS != 0;
    let filters = def.is_some_and(|d| d.has_parm("alphashadow") || d.has_parm("lightfilter")) || r.surface_flags & (surf::ALPHASHADOW | surf::LIGHTFILTER) != 0;
    !(script || record) || filters
}

/// Scales a colour so its largest channel is 1 (white when it has none).
fn normalized(c: [f64; 3]) -> [f64; 3] {
    let m = c.iter().copied().fold(0.0, f64::max);
    if m > 0.0 && m.is_finite() { c.map(|v| v.max(0.0) / m) } else { [1.0; 3] }
}

/// q3map2's surface-light colour: the average of the raw bytes of the light image, else of
/// the editor image, the shader's name or its first stage image, normalised.
fn light_image_color(d: &ShaderDef, name: &str, vfs: &Vfs) -> [f64; 3] {
    let mut names: Vec<&str> = Vec::new();
    names.extend(d.light_image.as_deref());
    names.extend(d.editor_image.as_deref());
    names.push(name);
    names.extend(d.albedo_stage().map(|(_, img)| img));
    for n in names {
        let Some(path) = find_image(vfs, n) else { continue };
        let Ok(bytes) = vfs.read(&path) else { continue };
        let ext = path.rsplit_once('.').map_or("", |(_, e)| e).to_ascii_lowercase();
        let Ok(img) = crate::texture::decode_rgba(&bytes, &ext, LIGHT_IMAGE_LIMITS) else { continue };
        let mut sum = [0.0f64; 3];
        for p in img.pixels() {
            for c in 0..3 {
                sum[c] += p[c] as f64;
            }
        }
        return normalized(sum);
    }
    [1.0; 3]
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
        light: LightInfo::default(),
    };
    info.light = light_info(def, r, vfs);
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

    #[test]
    fn translucent_shaders_cast_no_shadow_by_the_script_or_by_the_compiles_record() {
        let mut lib = ShaderLibrary::default();
        lib.add_script(
            "scripts/t.shader",
            "textures/t/flame\n{\n surfaceparm nolightmap\n}\ntextures/t/glass\n{\n surfaceparm trans\n}\ntextures/t/grate\n{\n surfaceparm trans\n surfaceparm alphashadow\n}\n",
        );
        let vfs = Vfs::new();
        let cast = |name: &str, sf: i32, cf: i32| resolve(&ShaderRef { name: name.into(), surface_flags: sf, content_flags: cf }, &lib, &vfs).light.casts_shadow;
        // Opaque in the script and in the record.
        assert!(cast("textures/t/flame", 0, 1));
        // Opaque in today's script, compiled translucent (oacmpdm4's blue flames).
        assert!(!cast("textures/t/flame", 0, 1 | contents::TRANSLUCENT));
        assert!(!cast("textures/t/unscripted", 0, contents::WATER));
        // Translucent in the script, whatever the record says.
        assert!(!cast("textures/t/glass", 0, 1));
        // Alpha shadows and light filters cast, from either source.
        assert!(cast("textures/t/grate", 0, 1 | contents::TRANSLUCENT));
        assert!(cast("textures/t/unscripted", surf::LIGHTFILTER, contents::TRANSLUCENT));
        assert!(cast("textures/t/unscripted", 0, 1));
    }
}
