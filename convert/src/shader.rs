//! Shader scripts (`scripts/*.shader`): the parts that decide how a surface looks in glTF.
//!
//! A script is a sequence of `name { directives { stage } ... }` blocks. We keep the
//! directives that matter for materials (cull, surfaceparms, sky, fog, editor image, sun,
//! surface light) and, per stage, its image, blend function and alpha test. Everything
//! else is skipped. Keywords are case-insensitive; `//` and `/* */` comments are ignored.
//! Malformed text never panics: the parser recovers at the next top-level block and
//! reports what it skipped.

use std::collections::BTreeMap;

/// What a stage samples.
#[derive(Debug, Clone, PartialEq)]
pub enum StageMap {
    /// An image path (from `map`, `clampMap`, or the first frame of `animMap`).
    Image(String),
    /// `$lightmap`: the baked lightmap.
    Lightmap,
    /// `$whiteimage` / `*white`.
    White,
    /// `videoMap`: a cinematic, not an image.
    Video,
}

/// `alphaFunc` of a stage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AlphaFunc {
    Gt0,
    Lt128,
    Ge128,
}

/// One `{ ... }` stage of a shader.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Stage {
    pub map: Option<StageMap>,
    /// `blendFunc` as (source, destination) GL factor names in upper case; the shorthands
    /// `add`, `filter` and `blend` are expanded.
    pub blend: Option<(String, String)>,
    pub alpha_func: Option<AlphaFunc>,
}

impl Stage {
    /// True when this stage is drawn over what is below it (anything but `GL_ONE GL_ZERO`).
    pub fn is_blended(&self) -> bool {
        self.blend.as_ref().is_some_and(|(s, d)| !(s == "GL_ONE" && d == "GL_ZERO"))
    }
}

/// `q3map_sun` / `q3map_sunExt`: colour, intensity (q3map2 units), azimuth and elevation
/// in degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sun {
    pub color: [f64; 3],
    pub intensity: f64,
    pub degrees: f64,
    pub elevation: f64,
}

/// Face culling of a shader.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Cull {
    #[default]
    Front,
    Back,
    None,
}

/// The material-relevant content of one shader.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ShaderDef {
    pub name: String,
    pub stages: Vec<Stage>,
    pub cull: Cull,
    /// `surfaceparm` values, lower case.
    pub surfaceparms: Vec<String>,
    pub editor_image: Option<String>,
    pub sky: bool,
    pub fog: bool,
    pub sun: Option<Sun>,
    /// `q3map_surfacelight`: q3map2's emission value.
    pub surface_light: Option<f64>,
    /// `q3map_lightImage`: the image whose average colour tints the surface light.
    pub light_image: Option<String>,
    /// `q3map_lightRGB`: an explicit surface-light colour.
    pub light_rgb: Option<[f64; 3]>,
    /// `q3map_lightSubdivide`: largest extent of one emitting patch, Quake units.
    pub light_subdivide: Option<f64>,
    /// `q3map_backsplash <percent> <distance>`: as a fraction and Quake units.
    pub backsplash: Option<(f64, f64)>,
    /// `q3map_skyLight <value> <iterations>` (a shader may carry several).
    pub sky_lights: Vec<(f64, u32)>,
}

impl ShaderDef {
    pub fn has_parm(&self, p: &str) -> bool {
        self.surfaceparms.iter().any(|s| s == p)
    }

    /// The albedo image: the first stage image that is neither `$lightmap` nor white.
    pub fn albedo_stage(&self) -> Option<(&Stage, &str)> {
        self.stages.iter().find_map(|s| match &s.map {
            Some(StageMap::Image(p)) => Some((s, p.as_str())),
            _ => None,
        })
    }
}

/// Splits script text into tokens: words, quoted strings, `{` and `}`; each with the
/// number of line breaks before it (so directives can be read line by line).
fn tokenize(text: &str) -> Vec<(bool, String)> {
    let mut out = Vec::new();
    let b = text.as_bytes();
    let mut i = 0;
    let mut newline = true;
    while i < b.len() {
        let c = b[i];
        if c == b'\n' {
            newline = true;
            i += 1;
        } else if c.is_ascii_whitespace() || c == 0 {
            i += 1;
        } else if c == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if c == b'/' && b.get(i + 1) == Some(&b'*') {
            i += 2;
            while i < b.len() && !(b[i] == b'*' && b.get(i + 1) == Some(&b'/')) {
                if b[i] == b'\n' {
                    newline = true;
                }
                i += 1;
            }
            i += 2;
        } else if c == b'{' || c == b'}' {
            out.push((newline, (c as char).to_string()));
            newline = false;
            i += 1;
        } else if c == b'"' {
            let start = i + 1;
            i += 1;
            while i < b.len() && b[i] != b'"' && b[i] != b'\n' {
                i += 1;
            }
            out.push((newline, String::from_utf8_lossy(&b[start..i.min(b.len())]).into_owned()));
            newline = false;
            i += 1;
        } else {
            let start = i;
            while i < b.len() && !b[i].is_ascii_whitespace() && b[i] != b'{' && b[i] != b'}' && b[i] != 0 {
                if b[i] == b'/' && matches!(b.get(i + 1), Some(b'/') | Some(b'*')) {
                    break;
                }
                i += 1;
            }
            out.push((newline, String::from_utf8_lossy(&b[start..i]).into_owned()));
            newline = false;
        }
    }
    out
}

fn expand_blend(args: &[String]) -> Option<(String, String)> {
    let up = |s: &String| s.to_ascii_uppercase();
    match args {
        [one] => match one.to_ascii_lowercase().as_str() {
            "add" => Some(("GL_ONE".into(), "GL_ONE".into())),
            "filter" => Some(("GL_DST_COLOR".into(), "GL_ZERO".into())),
            "blend" => Some(("GL_SRC_ALPHA".into(), "GL_ONE_MINUS_SRC_ALPHA".into())),
            _ => None,
        },
        [s, d, ..] => Some((up(s), up(d))),
        [] => None,
    }
}

fn image_or_special(name: &str) -> StageMap {
    match name.to_ascii_lowercase().as_str() {
        "$lightmap" => StageMap::Lightmap,
        "$whiteimage" | "*white" | "$white" => StageMap::White,
        _ => StageMap::Image(name.to_string()),
    }
}

/// Result of parsing one script file.
#[derive(Debug, Default)]
pub struct Parsed {
    pub shaders: Vec<ShaderDef>,
    /// Problems found (the parser recovered from each).
    pub problems: Vec<String>,
}

/// Parses one shader script.
pub fn parse(text: &str) -> Parsed {
    let toks = tokenize(text);
    let mut out = Parsed::default();
    let mut i = 0;
    while i < toks.len() {
        let name = &toks[i].1;
        if name == "{" || name == "}" {
            out.problems.push(format!("unexpected '{name}' where a shader name was expected"));
            i = skip_block(&toks, i);
            continue;
        }
        if toks.get(i + 1).map(|t| t.1.as_str()) != Some("{") {
            out.problems.push(format!("shader name {name:?} not followed by '{{'"));
            i += 1;
            continue;
        }
        let mut def = ShaderDef { name: name.replace('\\', "/"), ..Default::default() };
        i += 2;
        let mut depth = 1;
        let mut stage: Option<Stage> = None;
        while i < toks.len() && depth > 0 {
            let tok = &toks[i].1;
            if tok == "{" {
                depth += 1;
                if depth == 2 {
                    stage = Some(Stage::default());
                }
                i += 1;
                continue;
            }
            if tok == "}" {
                if depth == 2 {
                    def.stages.extend(stage.take());
                }
                depth -= 1;
                i += 1;
                continue;
            }
            // A directive: the keyword and its arguments up to the end of the line.
            let mut j = i + 1;
            while j < toks.len() && !toks[j].0 && toks[j].1 != "{" && toks[j].1 != "}" {
                j += 1;
            }
            let key = tok.to_ascii_lowercase();
            // Known stage keywords take a fixed number of arguments (the engine reads them
            // token by token, so several may share a line); others run to the line's end.
            let line_args = j - i - 1;
            let arity = match (depth, key.as_str()) {
                (2, "map" | "clampmap" | "alphafunc") => Some(1),
                (2, "blendfunc") => Some(match toks.get(i + 1).map(|t| t.1.to_ascii_lowercase()).as_deref() {
                    Some("add" | "filter" | "blend") => 1,
                    _ => 2,
                }),
                _ => None,
            };
            if let Some(a) = arity {
                j = i + 1 + a.min(line_args);
            }
            let args: Vec<String> = toks[i + 1..j].iter().map(|t| t.1.clone()).collect();
            let num = |k: usize| args.get(k).and_then(|a| a.parse::<f64>().ok()).filter(|x| x.is_finite());
            if let (2, Some(st)) = (depth, stage.as_mut()) {
                match key.as_str() {
                    "map" | "clampmap" => st.map = args.first().map(|a| image_or_special(a)),
                    "animmap" => st.map = args.get(1).map(|a| image_or_special(a)),
                    "videomap" => st.map = Some(StageMap::Video),
                    "blendfunc" => st.blend = expand_blend(&args),
                    "alphafunc" => {
                        st.alpha_func = match args.first().map(|a| a.to_ascii_uppercase()).as_deref() {
                            Some("GT0") => Some(AlphaFunc::Gt0),
                            Some("LT128") => Some(AlphaFunc::Lt128),
                            Some("GE128") => Some(AlphaFunc::Ge128),
                            _ => None,
                        }
                    }
                    _ => {}
                }
            } else if depth == 1 {
                match key.as_str() {
                    "cull" => {
                        def.cull = match args.first().map(|a| a.to_ascii_lowercase()).as_deref() {
                            Some("none") | Some("twosided") | Some("disable") => Cull::None,
                            Some("back") | Some("backside") | Some("backsided") => Cull::Back,
                            _ => Cull::Front,
                        }
                    }
                    "surfaceparm" => def.surfaceparms.extend(args.first().map(|a| a.to_ascii_lowercase())),
                    "qer_editorimage" => def.editor_image = args.first().cloned(),
                    "skyparms" => def.sky = true,
                    "fogparms" => def.fog = true,
                    "q3map_surfacelight" => def.surface_light = num(0),
                    "q3map_lightimage" => def.light_image = args.first().cloned(),
                    "q3map_lightrgb" => {
                        if let (Some(r), Some(g), Some(b)) = (num(0), num(1), num(2)) {
                            def.light_rgb = Some([r, g, b]);
                        }
                    }
                    "q3map_lightsubdivide" => def.light_subdivide = num(0).filter(|v| *v > 0.0),
                    "q3map_backsplash" => {
                        if let (Some(p), Some(d)) = (num(0), num(1)) {
                            def.backsplash = Some((p * 0.01, d));
                        }
                    }
                    "q3map_skylight" => {
                        if let (Some(v), Some(it)) = (num(0), num(1)) {
                            if v > 0.0 && it >= 2.0 && it <= 1024.0 {
                                def.sky_lights.push((v, it as u32));
                            }
                        }
                    }
                    "q3map_sun" | "q3map_sunext" => {
                        if let (Some(r), Some(g), Some(b), Some(intensity), Some(degrees), Some(elevation)) =
                            (num(0), num(1), num(2), num(3), num(4), num(5))
                        {
                            def.sun = Some(Sun { color: [r, g, b], intensity, degrees, elevation });
                        }
                    }
                    _ => {}
                }
            }
            i = j;
        }
        if depth > 0 {
            out.problems.push(format!("shader {:?} not closed at end of file", def.name));
        }
        if def.has_parm("sky") {
            def.sky = true;
        }
        out.shaders.push(def);
    }
    out
}

fn skip_block(toks: &[(bool, String)], mut i: usize) -> usize {
    let mut depth = 0i32;
    while i < toks.len() {
        match toks[i].1.as_str() {
            "{" => depth += 1,
            "}" => {
                depth -= 1;
                if depth <= 0 {
                    return i + 1;
                }
            }
            _ => {}
        }
        i += 1;
    }
    i
}

/// All shaders of a game, by lower-case name. Files are applied in the order given, so a
/// later file's definition replaces an earlier one (ioquake3 loads scripts so that later
/// pk3s override earlier ones).
#[derive(Debug, Default)]
pub struct ShaderLibrary {
    pub shaders: BTreeMap<String, ShaderDef>,
    /// "file: problem" lines from parsing.
    pub problems: Vec<String>,
}

impl ShaderLibrary {
    pub fn add_script(&mut self, file: &str, text: &str) {
        let parsed = parse(text);
        for p in parsed.problems {
            self.problems.push(format!("{file}: {p}"));
        }
        for s in parsed.shaders {
            self.shaders.insert(s.name.to_ascii_lowercase(), s);
        }
    }

    pub fn get(&self, name: &str) -> Option<&ShaderDef> {
        self.shaders.get(&name.replace('\\', "/").to_ascii_lowercase())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCRIPT: &str = r#"
// comment
textures/base_wall/glass { qer_editorimage textures/base_wall/glass_ed.tga
    surfaceparm trans
    cull none
    { map textures/effects/tinfx.tga
      blendFunc add }
    { map $lightmap blendfunc filter }
}
/* block
   comment */
textures/sfx/fence
{
    { map textures/sfx/fence.tga
      alphaFunc GE128
      depthWrite }
    { map $lightmap
      blendFunc GL_DST_COLOR GL_ZERO }
}
textures/skies/sky
{
    q3map_sun 1 0.9 0.8 100 30 60
    surfaceparm noimpact
    surfaceparm sky
    skyparms env/sky - -
}
textures/anim/x { { animMap 5 textures/a1.tga textures/a2.tga } }
"#;

    #[test]
    fn reads_lighting_directives() {
        let p = parse(
            "textures/l/panel { q3map_surfacelight 1000\n q3map_lightimage textures/l/glow.tga\n q3map_lightSubdivide 32\n q3map_backsplash 0 0\n }\n\
             textures/l/rgb { q3map_lightRGB 1 0.5 0\n q3map_surfacelight 50 }\n\
             textures/s/sky { surfaceparm sky\n q3map_skyLight 180 8\n q3map_skylight 10 1\n q3map_sun 1 1 1 32 90 90 }",
        );
        assert!(p.problems.is_empty(), "{:?}", p.problems);
        let panel = &p.shaders[0];
        assert_eq!(panel.surface_light, Some(1000.0));
        assert_eq!(panel.light_image.as_deref(), Some("textures/l/glow.tga"));
        assert_eq!(panel.light_subdivide, Some(32.0));
        assert_eq!(panel.backsplash, Some((0.0, 0.0)));
        assert_eq!(p.shaders[1].light_rgb, Some([1.0, 0.5, 0.0]));
        let sky = &p.shaders[2];
        assert_eq!(sky.sky_lights, vec![(180.0, 8)], "one iteration is no sky light (q3map2 needs two)");
        assert_eq!(sky.sun.unwrap().elevation, 90.0);
    }

    #[test]
    fn reads_material_directives() {
        let p = parse(SCRIPT);
        assert!(p.problems.is_empty(), "{:?}", p.problems);
        assert_eq!(p.shaders.len(), 4);
        let glass = &p.shaders[0];
        assert_eq!(glass.cull, Cull::None);
        assert_eq!(glass.editor_image.as_deref(), Some("textures/base_wall/glass_ed.tga"));
        let (st, img) = glass.albedo_stage().unwrap();
        assert_eq!(img, "textures/effects/tinfx.tga");
        assert!(st.is_blended());
        assert_eq!(glass.stages[1].map, Some(StageMap::Lightmap));
        assert_eq!(glass.stages[1].blend, Some(("GL_DST_COLOR".into(), "GL_ZERO".into())));
        let fence = &p.shaders[1];
        assert_eq!(fence.stages[0].alpha_func, Some(AlphaFunc::Ge128));
        assert!(!fence.stages[0].is_blended());
        let sky = &p.shaders[2];
        assert!(sky.sky);
        assert_eq!(sky.sun.unwrap().elevation, 60.0);
        assert_eq!(p.shaders[3].albedo_stage().unwrap().1, "textures/a1.tga");
    }

    #[test]
    fn recovers_from_garbage() {
        let p = parse("} foo { { map x.tga } bar { \"unterminated");
        assert!(!p.problems.is_empty());
        assert_eq!(p.shaders[0].name, "foo");
        let p = parse("{{{{");
        assert!(!p.problems.is_empty());
    }
}
