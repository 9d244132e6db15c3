//! The conversion pipeline: locate and parse the map, resolve shaders and textures, pack
//! lightmaps, tessellate patches, assemble meshes per material, convert entities, and
//! write the glTF.
//!
//! Data flow: `MapSource` -> ([`Vfs`], [`Bsp`]) -> per-shader [`ShaderInfo`] ->
//! [`Pages`] -> atlas -> geometry per (model, material) -> [`Scene`] -> file.
//! Nothing is written before the whole scene has been built, so a bad input leaves no
//! output at all.

use crate::atlas;
use crate::bsp::{Bsp, DrawVert, SurfaceType};
use crate::entities::{self, Entity};
use crate::error::Error;
use crate::gltf_out;
use crate::lightmaps::{self, Pages};
use crate::material::{self, ShaderInfo, Visibility};
use crate::patch::{self, PatchInput};
use crate::scene::{self, LightKind, Sampling, Scene};
use crate::shader::ShaderLibrary;
use crate::texture::{self, Limits};
use crate::units;
use crate::vfs::Vfs;
use rayon::prelude::*;
use serde_json::{json, Map, Value};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Which map to convert.
#[derive(Debug, Clone)]
pub enum MapSource {
    /// A `.bsp` file on disk.
    Path(PathBuf),
    /// A map name (`oa_dm1` or `maps/oa_dm1.bsp`) looked up in the game directories.
    Name(String),
}

/// Conversion settings. `Options::default()` matches the command line's defaults.
#[derive(Debug, Clone)]
pub struct Options {
    /// Game directories (`baseoa`, a mod directory), later ones overriding earlier ones.
    pub game_dirs: Vec<PathBuf>,
    /// Meters per Quake unit.
    pub scale: f64,
    /// Largest distance between a patch's true surface and its triangles, Quake units.
    pub patch_tolerance: f64,
    pub no_sky: bool,
    /// Write `light` entities and `q3map_sun` as KHR_lights_punctual lights.
    pub entity_lights: bool,
    /// The map's `.map` source: its light entities (which q3map2 strips from the BSP)
    /// become the scene's lights, as with `entity_lights`.
    pub lights_from: Option<PathBuf>,
    /// Also write the MOZ_lightmap material extension.
    pub moz_lightmap: bool,
    /// The engine's r_mapOverBrightBits, recorded with the lightmaps and used for lights.
    pub overbright_bits: u32,
    pub texture_limits: Limits,
    /// Largest BSP file accepted, in bytes.
    pub max_bsp_bytes: u64,
    /// Largest file read from the game data, in bytes.
    pub max_entry_bytes: u64,
    /// Most vertices that patch tessellation may create.
    pub max_patch_vertices: usize,
    /// Most work the coplanar-overlap cut may spend, in the units of
    /// [`crate::overlap::WORK_BUDGET`] (its default); past it, triangles stay whole.
    pub overlap_work_budget: u64,
    /// Keep opaque faces that overlap on one plane as the BSP has them (by default the
    /// later one gives up the overlap: see [`crate::overlap`]).
    pub keep_overlaps: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            game_dirs: Vec::new(),
            scale: units::DEFAULT_SCALE,
            patch_tolerance: 4.0,
            no_sky: false,
            entity_lights: false,
            lights_from: None,
            moz_lightmap: false,
            overbright_bits: units::DEFAULT_OVERBRIGHT_BITS,
            texture_limits: Limits::default(),
            max_bsp_bytes: 1 << 30,
            max_entry_bytes: crate::vfs::DEFAULT_MAX_ENTRY_BYTES,
            max_patch_vertices: 20_000_000,
            overlap_work_budget: crate::overlap::WORK_BUDGET,
            keep_overlaps: false,
        }
    }
}

/// Counts of BSP surfaces by what happened to them.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct SurfaceCounts {
    pub polygon: usize,
    pub patch: usize,
    pub mesh: usize,
    pub flare: usize,
    pub other: usize,
    /// Drawable surfaces left out (tool textures, fog, nodraw).
    pub hidden: usize,
    pub sky: usize,
    /// Lightmapped / vertex-lit / unlit among the converted ones.
    pub lightmapped: usize,
    pub vertex_lit: usize,
    pub unlit: usize,
    /// Surfaces skipped because of non-finite vertex positions.
    pub invalid: usize,
    /// Vertices whose BSP normal was zero, given the mean normal of their triangles.
    pub repaired_normals: usize,
    /// Opaque triangles cut or removed where an earlier face covers them on one plane.
    pub overlaps: crate::overlap::OverlapCounts,
}

/// What a conversion did, for the report at the end.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Summary {
    pub map: String,
    pub format: String,
    pub surfaces: SurfaceCounts,
    pub triangles: usize,
    pub vertices: usize,
    pub materials: usize,
    pub images: usize,
    pub lightmap_pages: usize,
    pub lightmap_atlases: usize,
    pub deluxe: bool,
    pub entities: usize,
    pub lights: usize,
    /// Texture names that were not found (a placeholder was used).
    pub missing_textures: Vec<String>,
    pub warnings: Vec<String>,
    /// Seconds per stage, in order.
    pub timings: Vec<(String, f64)>,
    pub output_files: Vec<PathBuf>,
    pub output_bytes: u64,
}

/// A loaded map: its file system and parsed BSP.
pub struct LoadedMap {
    pub vfs: Vfs,
    pub bsp: Bsp,
    /// The map's file stem (`oa_dm1`).
    pub name: String,
    /// How to name the map file in messages.
    pub shown: String,
    /// The file on disk, when the map was given as a path.
    pub path: Option<PathBuf>,
}

/// Mounts the game directories and reads and parses the map.
pub fn load(source: &MapSource, opts: &Options) -> Result<LoadedMap, Error> {
    let mut vfs = Vfs::new();
    vfs.max_entry_bytes = opts.max_entry_bytes;
    let mut dirs = opts.game_dirs.clone();
    if dirs.is_empty() {
        if let MapSource::Path(p) = source {
            // Default game dir: the directory above `maps/`.
            let parent = p.parent().filter(|d| d.file_name().is_some_and(|n| n.eq_ignore_ascii_case("maps")));
            if let Some(game) = parent.and_then(|d| d.parent()) {
                dirs.push(if game.as_os_str().is_empty() { PathBuf::from(".") } else { game.to_path_buf() });
            }
        }
    }
    for d in &dirs {
        if !d.is_dir() {
            return Err(Error::Usage(format!("{}: game directory not found", d.display())));
        }
        vfs.mount_dir(d)?;
    }
    let (bytes, shown, name, path) = match source {
        MapSource::Path(p) => {
            let shown = p.display().to_string();
            let meta = std::fs::metadata(p).map_err(|source| Error::Io { path: shown.clone(), source })?;
            if meta.len() > opts.max_bsp_bytes {
                return Err(Error::invalid(shown, format!("{} bytes is over the {}-byte limit for a map", meta.len(), opts.max_bsp_bytes)));
            }
            let bytes = std::fs::read(p).map_err(|source| Error::Io { path: shown.clone(), source })?;
            let name = p.file_stem().unwrap_or_default().to_string_lossy().into_owned();
            (bytes, shown, name, Some(p.clone()))
        }
        MapSource::Name(n) => {
            let n = n.replace('\\', "/");
            let mut vpath = if n.contains('/') { n.clone() } else { format!("maps/{n}") };
            if !vpath.to_ascii_lowercase().ends_with(".bsp") {
                vpath.push_str(".bsp");
            }
            if dirs.is_empty() {
                return Err(Error::Usage(format!("map name '{n}' needs --game-dir (or give a .bsp path)")));
            }
            let shown = vfs.origin(&vpath).map(|o| o.to_string()).unwrap_or_else(|| vpath.clone());
            let bytes = vfs.read(&vpath)?;
            let name = Path::new(&vpath).file_stem().unwrap_or_default().to_string_lossy().into_owned();
            (bytes, shown, name, None)
        }
    };
    let bsp = Bsp::parse(&bytes).map_err(|source| Error::Bsp { path: shown.clone(), source })?;
    Ok(LoadedMap { vfs, bsp, name, shown, path })
}

/// Converts a map and writes it to `out` (`.gltf` or `.glb`).
pub fn convert(source: &MapSource, out: &Path, opts: &Options, progress: &dyn Fn(&str)) -> Result<Summary, Error> {
    if gltf_out::Container::from_path(out).is_none() {
        return Err(Error::Usage(format!("{}: output must end in .gltf or .glb", out.display())));
    }
    let t0 = Instant::now();
    progress("reading map");
    let map = load(source, opts)?;
    if let Some(p) = &map.path {
        if crate::output::same_file(out, p) {
            return Err(Error::Usage(format!("{}: output would overwrite the input", out.display())));
        }
    }
    let load_s = t0.elapsed().as_secs_f64();
    let (scene, mut summary) = build_scene(&map, opts, progress)?;
    summary.timings.insert(0, ("read".into(), load_s));
    progress("writing glTF");
    let t = Instant::now();
    let wopts = gltf_out::WriteOptions { moz_lightmap: opts.moz_lightmap, generator: format!("q3gltf {}", env!("CARGO_PKG_VERSION")) };
    let written = gltf_out::write(&scene, out, &wopts).map_err(|source| Error::Io { path: out.display().to_string(), source })?;
    summary.timings.push(("write".into(), t.elapsed().as_secs_f64()));
    summary.timings.push(("total".into(), t0.elapsed().as_secs_f64()));
    summary.output_files = written.files;
    summary.output_bytes = written.bytes;
    Ok(summary)
}

/// Reads every shader script of the VFS (in parallel; later files override earlier
/// ones) and resolves each BSP shader record. Also returns the scripts that could not be
/// read, as warnings.
pub fn resolve_shaders(map: &LoadedMap) -> (Vec<ShaderInfo>, Vec<String>) {
    let scripts = map.vfs.list("scripts", "shader");
    let texts: Vec<(String, Result<Vec<u8>, String>)> =
        scripts.par_iter().map(|s| (s.clone(), map.vfs.read(s).map_err(|e| e.to_string()))).collect();
    let mut lib = ShaderLibrary::default();
    let mut warnings = Vec::new();
    for (name, text) in &texts {
        match text {
            Ok(bytes) => lib.add_script(name, &String::from_utf8_lossy(bytes)),
            Err(e) => warnings.push(e.clone()),
        }
    }
    let infos = map.bsp.shaders.iter().map(|s| material::resolve(s, &lib, &map.vfs)).collect();
    (infos, warnings)
}

/// Lighting of a converted surface.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Lighting {
    /// Lightmapped, in the given atlas image.
    Lightmap(usize),
    /// q3map2 vertex lighting in the vertex colours (lightmap index -3).
    Vertex,
    /// No baked lighting (lightmap index -1, or a page that is missing).
    None,
}

/// Key of one glTF material: shader index and lighting.
type MaterialKey = (u32, Lighting);

/// Vertices and Quake-order triangles of one surface, before conversion to glTF space.
struct SurfaceGeometry<'a> {
    verts: std::borrow::Cow<'a, [DrawVert]>,
    /// Engine order (clockwise from the front), relative to `verts`.
    indices: std::borrow::Cow<'a, [u32]>,
}

/// Builds the scene without writing anything.
pub fn build_scene(map: &LoadedMap, opts: &Options, progress: &dyn Fn(&str)) -> Result<(Scene, Summary), Error> {
    let bsp = &map.bsp;
    let mut summary = Summary { map: map.shown.clone(), format: bsp.format.to_string(), ..Default::default() };
    if !map.vfs.rejected.is_empty() {
        let shown: Vec<&str> = map.vfs.rejected.iter().take(5).map(String::as_str).collect();
        summary.warnings.push(format!("{} file(s) with unusable names ignored: {}", map.vfs.rejected.len(), shown.join(", ")));
    }
    let mut t = Instant::now();
    let mut lap = |summary: &mut Summary, name: &str| {
        summary.timings.push((name.to_string(), t.elapsed().as_secs_f64()));
        t = Instant::now();
    };

    // Shaders.
    progress("reading shader scripts");
    let (infos, unreadable_scripts) = resolve_shaders(map);
    summary.warnings.extend(unreadable_scripts);
    lap(&mut summary, "shaders");

    // Entities.
    let ents = entities::parse(&bsp.entities).map_err(|m| Error::invalid(&map.shown, format!("entity lump: {m}")))?;
    // q3map2 `-gamma G` stores `255 (v / 255)^(1/G)`: the lightmaps decode with G.
    let lightmap_gamma = ents.iter().find(|e| e.classname() == "worldspawn").and_then(|w| w.get("_q3map2_cmdline")).and_then(light_gamma).unwrap_or(1.0);
    summary.entities = ents.len();

    // Lightmaps.
    progress("packing lightmaps");
    let pages: Pages = lightmaps::gather(bsp, &map.vfs, &map.name, opts.texture_limits);
    summary.warnings.extend(pages.warnings.iter().cloned());
    summary.deluxe = pages.deluxe;
    summary.lightmap_pages = pages.pages.len();
    let atlas = atlas::pack(&pages.pages);
    summary.lightmap_atlases = atlas.images.len();
    lap(&mut summary, "lightmaps");

    // Which surfaces are drawn, and where.
    let mut model_of = vec![None; bsp.surfaces.len()];
    for (mi, m) in bsp.models.iter().enumerate() {
        for si in m.first_surface..m.first_surface + m.num_surfaces {
            model_of[si as usize].get_or_insert(mi);
        }
    }
    let c = &mut summary.surfaces;
    for s in &bsp.surfaces {
        match s.kind {
            SurfaceType::Polygon => c.polygon += 1,
            SurfaceType::Patch => c.patch += 1,
            SurfaceType::Mesh => c.mesh += 1,
            SurfaceType::Flare => c.flare += 1,
            SurfaceType::Other(_) => c.other += 1,
        }
    }
    let drawable = |si: usize| -> bool {
        let s = &bsp.surfaces[si];
        let vis = infos[s.shader as usize].visibility;
        matches!(s.kind, SurfaceType::Polygon | SurfaceType::Patch | SurfaceType::Mesh)
            && model_of[si].is_some()
            && (vis == Visibility::Drawn || (vis == Visibility::Sky && !opts.no_sky))
    };

    // Patches: all together, so that shared edges are stitched.
    progress("tessellating patches");
    let patch_ids: Vec<usize> = (0..bsp.surfaces.len()).filter(|&i| bsp.surfaces[i].kind == SurfaceType::Patch && drawable(i)).collect();
    let inputs: Vec<PatchInput> = patch_ids
        .iter()
        .map(|&i| PatchInput::of(bsp, &bsp.surfaces[i]))
        .collect();
    let tess = patch::tessellate_all(&inputs, opts.patch_tolerance, opts.max_patch_vertices)
        .map_err(|e| Error::invalid(&map.shown, e.to_string()))?;
    let mut tess_of: BTreeMap<usize, patch::Tessellated> = patch_ids.into_iter().zip(tess).collect();
    // The emitting patches, with the area of their drawn tessellation (m^2): q3map2 emitted
    // from its own coarser mesh of them, which the scene carries for relight.
    let emitting_patches: Vec<(usize, String, f64)> = tess_of
        .iter()
        .filter(|(si, _)| infos[bsp.surfaces[**si].shader as usize].light.surface.is_some())
        .map(|(si, t)| (*si, infos[bsp.surfaces[*si].shader as usize].name.clone(), t.area() * opts.scale * opts.scale))
        .collect();
    // The lightmapped patches, with their drawn area and their page's place: q3map2
    // sampled a curved one's luxels on its own mesh of it, which the scene carries too.
    let lit_patches: Vec<crate::patch_luxels::LitPatch> = tess_of
        .iter()
        .filter_map(|(si, t)| {
            let s = &bsp.surfaces[*si];
            let pl = &atlas.placements[pages.page_of(s.lightmap)?];
            Some(crate::patch_luxels::LitPatch {
                surface: *si,
                shader: infos[s.shader as usize].name.clone(),
                area_m2: t.area() * opts.scale * opts.scale,
                page_origin: [pl.x, pl.y],
                page_size: [pl.width, pl.height],
            })
        })
        .collect();
    // The vertex-lit patches, with their drawn area and each control point's share of it
    // (m^2): q3map2 lit them at their control points only, which the scene carries too.
    let vertex_lit_patches: Vec<(usize, String, f64, Vec<f64>)> = tess_of
        .iter()
        .filter(|(si, _)| bsp.surfaces[**si].lightmap == -3)
        .map(|(si, t)| {
            let s = &bsp.surfaces[*si];
            let m2 = opts.scale * opts.scale;
            let points = t.control_point_areas(s.patch_w as usize, s.patch_h as usize).into_iter().map(|a| a * m2).collect();
            (*si, infos[s.shader as usize].name.clone(), t.area() * m2, points)
        })
        .collect();
    lap(&mut summary, "patches");

    // Geometry per (model, sky, material).
    progress("building meshes");
    let mut prims: BTreeMap<(usize, bool, MaterialKey), scene::Primitive> = BTreeMap::new();
    // Per primitive, which of its triangles are the world's own surfaces (brush faces and
    // patches, not models' triangle soups).
    let mut world_surface: BTreeMap<(usize, bool, MaterialKey), Vec<bool>> = BTreeMap::new();
    for si in 0..bsp.surfaces.len() {
        let s = &bsp.surfaces[si];
        if !matches!(s.kind, SurfaceType::Polygon | SurfaceType::Patch | SurfaceType::Mesh) || model_of[si].is_none() {
            continue;
        }
        let info = &infos[s.shader as usize];
        match info.visibility {
            Visibility::Hidden(_) => {
                summary.surfaces.hidden += 1;
                continue;
            }
            Visibility::Sky if opts.no_sky => {
                summary.surfaces.hidden += 1;
                continue;
            }
            _ => {}
        }
        let geom = match s.kind {
            SurfaceType::Patch => {
                let t = tess_of.remove(&si).expect("every drawable patch was tessellated");
                SurfaceGeometry { verts: t.verts.into(), indices: t.indices.into() }
            }
            _ => SurfaceGeometry { verts: bsp.surface_verts(s).into(), indices: bsp.surface_indices(s).into() },
        };
        // A non-finite position cannot be drawn; other attributes are repaired below.
        if !geom.verts.iter().all(|v| v.xyz.iter().all(|x| x.is_finite())) {
            summary.surfaces.invalid += 1;
            continue;
        }
        let sky = info.visibility == Visibility::Sky;
        if sky {
            summary.surfaces.sky += 1;
        }
        let page = pages.page_of(s.lightmap);
        let lighting = match (page, s.lightmap) {
            (Some(p), _) => Lighting::Lightmap(atlas.placements[p].atlas),
            (None, -3) => Lighting::Vertex,
            _ => Lighting::None,
        };
        match lighting {
            Lighting::Lightmap(_) => summary.surfaces.lightmapped += 1,
            Lighting::Vertex => summary.surfaces.vertex_lit += 1,
            Lighting::None => summary.surfaces.unlit += 1,
        }
        let key = (model_of[si].unwrap(), sky, (s.shader, lighting));
        let prim = prims.entry(key).or_insert_with(|| scene::Primitive {
            uv1: matches!(lighting, Lighting::Lightmap(_)).then(Vec::new),
            colors: (!matches!(lighting, Lighting::Lightmap(_))).then(Vec::new),
            ..Default::default()
        });
        let before = prim.indices.len() / 3;
        summary.surfaces.repaired_normals += append_surface(prim, &geom, opts.scale, page.map(|p| (&atlas.placements[p], &atlas.images[atlas.placements[p].atlas])));
        let faces = world_surface.entry(key).or_default();
        faces.resize(before, false);
        faces.resize(prim.indices.len() / 3, matches!(s.kind, SurfaceType::Polygon | SurfaceType::Patch));
    }
    if !opts.keep_overlaps {
        // Brush faces and patches only (models keep the triangles their author made), per
        // model, the opaque primitives in key order: earlier faces keep their area.
        let mut by_model: BTreeMap<usize, (Vec<&mut scene::Primitive>, Vec<&[bool]>)> = BTreeMap::new();
        for (key, prim) in prims.iter_mut() {
            let (model, sky, (shader, _)) = *key;
            if !sky && infos[shader as usize].alpha == scene::AlphaMode::Opaque {
                let e = by_model.entry(model).or_default();
                e.0.push(prim);
                e.1.push(world_surface.get(key).map_or(&[][..], Vec::as_slice));
            }
        }
        let mut budget = opts.overlap_work_budget;
        for (_, (mut list, faces)) in by_model {
            summary.surfaces.overlaps += crate::overlap::cut_coplanar_overlaps(&mut list, &faces, &mut budget);
        }
    }
    lap(&mut summary, "meshes");

    // Materials, images and textures.
    progress("encoding textures");
    let mut scene = Scene { name: map.name.clone(), ..Default::default() };
    let used_keys: std::collections::BTreeSet<MaterialKey> = prims.keys().map(|k| k.2).collect();
    let albedo_paths: std::collections::BTreeSet<&str> =
        used_keys.iter().filter_map(|(sh, _)| infos[*sh as usize].image.as_deref()).collect();
    let albedo_paths: Vec<&str> = albedo_paths.into_iter().collect();
    let encoded: Vec<Result<texture::Encoded, String>> = albedo_paths
        .par_iter()
        .map(|p| {
            let bytes = map.vfs.read(p).map_err(|e| e.to_string())?;
            let ext = p.rsplit_once('.').map(|(_, e)| e).unwrap_or("");
            texture::encode_for_gltf(&bytes, ext, opts.texture_limits).map_err(|e| format!("{p}: {e}"))
        })
        .collect();
    let mut texture_of_path: BTreeMap<&str, usize> = BTreeMap::new();
    let mut placeholder: Option<usize> = None;
    let add_texture = |scene: &mut Scene, img: scene::Image, sampling: Sampling| -> usize {
        scene.images.push(img);
        scene.textures.push(scene::Texture { image: scene.images.len() - 1, sampling });
        scene.textures.len() - 1
    };
    let mut unreadable = Vec::new();
    for (p, e) in albedo_paths.iter().zip(encoded) {
        match e {
            Ok(enc) => {
                let stem = p.rsplit_once('.').map(|(s, _)| s).unwrap_or(p);
                let t = add_texture(&mut scene, scene::Image { name: stem.to_string(), mime: enc.mime, bytes: enc.bytes }, Sampling::Repeat);
                texture_of_path.insert(p, t);
            }
            Err(msg) => unreadable.push(msg),
        }
    }
    let mut lightmap_textures = Vec::new();
    for (k, img) in atlas.images.iter().enumerate() {
        let png = texture::png_bytes(&img.rgb, img.width as u32, img.height as u32, image::ExtendedColorType::Rgb8)
            .map_err(|e| Error::invalid(&map.shown, format!("lightmap atlas: {e}")))?;
        let name = format!("lightmaps/{}_lightmap_{k}", map.name);
        lightmap_textures.push(add_texture(&mut scene, scene::Image { name, mime: "image/png", bytes: png }, Sampling::ClampLinear));
    }
    let mut missing: std::collections::BTreeSet<String> = std::collections::BTreeSet::new();
    let mut material_of: BTreeMap<MaterialKey, usize> = BTreeMap::new();
    for key in &used_keys {
        let (sh, lighting) = *key;
        let info = &infos[sh as usize];
        let tex = info.image.as_deref().and_then(|p| texture_of_path.get(p).copied());
        let tex = match tex {
            Some(t) => t,
            None => {
                missing.insert(info.missing.clone().or(info.image.clone()).unwrap_or_else(|| info.name.clone()));
                *placeholder.get_or_insert_with(|| {
                    let p = texture::placeholder();
                    add_texture(&mut scene, scene::Image { name: "missing_texture".into(), mime: p.mime, bytes: p.bytes }, Sampling::Repeat)
                })
            }
        };
        let mut extras = Map::new();
        extras.insert("q3_shader".into(), json!(info.name));
        let (suffix, lighting_name) = match lighting {
            Lighting::Lightmap(0) => (String::new(), "lightmap"),
            Lighting::Lightmap(k) => (format!("#lm{k}"), "lightmap"),
            Lighting::Vertex => ("#vertex".into(), "vertex"),
            Lighting::None => ("#unlit".into(), "none"),
        };
        extras.insert("q3_lighting".into(), json!(lighting_name));
        if lighting != Lighting::None {
            extras.insert("q3_encoding".into(), json!("rgb8_linear"));
            extras.insert("q3_overbright_bits".into(), json!(opts.overbright_bits));
            extras.insert("q3_lightmap_gamma".into(), json!(lightmap_gamma));
        }
        if info.image.is_none() || Some(tex) == placeholder {
            extras.insert("q3_missing_texture".into(), json!(true));
        }
        // How q3map2 lit with this shader: relight models it, and with the map's lights
        // requested the surface light is also written as emission.
        extras.insert("q3_casts_shadow".into(), json!(info.light.casts_shadow));
        if let Some(s) = &info.light.surface {
            extras.insert(
                "q3_surfacelight".into(),
                json!({ "value": s.value, "color": s.color, "subdivide": s.subdivide, "backsplash": [s.backsplash_fraction, s.backsplash_distance] }),
            );
        }
        if !info.light.sky_lights.is_empty() {
            let list: Vec<Value> = info.light.sky_lights.iter().map(|&(v, it)| json!({ "value": v, "iterations": it, "color": info.light.sky_color })).collect();
            extras.insert("q3_skylight".into(), Value::Array(list));
        }
        let emissive = if opts.entity_lights || opts.lights_from.is_some() {
            let surface = info.light.surface.as_ref().map(|s| (s.color, units::q3map2_surface_radiance(s.value, opts.overbright_bits)));
            let sky = info.light.sky_lights.iter().map(|&(v, it)| units::q3map2_sky_radiance(v, it, opts.overbright_bits)).sum::<f64>();
            match (surface, sky > 0.0) {
                (Some((c, l)), _) => Some((c.map(|x| x as f32), (l + sky) as f32)),
                (None, true) => Some((info.light.sky_color.map(|x| x as f32), sky as f32)),
                (None, false) => None,
            }
        } else {
            None
        };
        scene.materials.push(scene::Material {
            name: format!("{}{}", info.name, suffix),
            base_color_texture: Some(tex),
            base_color_factor: [1.0; 4],
            alpha_mode: info.alpha,
            double_sided: info.double_sided,
            lightmap_texture: match lighting {
                Lighting::Lightmap(k) => Some(lightmap_textures[k]),
                _ => None,
            },
            emissive,
            extras: Value::Object(extras),
        });
        material_of.insert(*key, scene.materials.len() - 1);
    }
    summary.missing_textures = missing.into_iter().collect();
    summary.warnings.extend(unreadable);
    lap(&mut summary, "textures");

    // Meshes and nodes.
    let mut per_mesh: BTreeMap<(usize, bool), Vec<scene::Primitive>> = BTreeMap::new();
    for ((model, sky, key), mut p) in prims {
        p.material = material_of[&key];
        summary.triangles += p.indices.len() / 3;
        summary.vertices += p.positions.len();
        per_mesh.entry((model, sky)).or_default().push(p);
    }
    let brush_entity: BTreeMap<usize, (usize, &Entity)> = ents
        .iter()
        .enumerate()
        .filter_map(|(i, e)| e.get("model").and_then(|m| m.strip_prefix('*')).and_then(|m| m.parse().ok()).map(|m| (m, (i, e))))
        .collect();
    for ((model, sky), primitives) in per_mesh {
        let (name, extras) = if sky {
            ("sky".to_string(), None)
        } else if model == 0 {
            ("world".to_string(), ents.iter().find(|e| e.classname() == "worldspawn").map(entity_extras))
        } else {
            match brush_entity.get(&model) {
                Some((_, e)) => (format!("*{model} {}", e.classname()), Some(entity_extras(e))),
                None => (format!("*{model}"), None),
            }
        };
        scene.meshes.push(scene::Mesh { name: name.clone(), primitives });
        let n = scene.add_node(scene::Node { name, mesh: Some(scene.meshes.len() - 1), extras, ..Default::default() });
        scene.roots.push(n);
    }
    let source_lights = match &opts.lights_from {
        Some(path) => Some(read_map_source(path, opts.max_entry_bytes)?),
        None => None,
    };
    add_entities(&mut scene, &ents, source_lights.as_deref(), &infos, opts, &mut summary);
    summary.materials = scene.materials.len();
    summary.images = scene.images.len();
    summary.lights = scene.lights.len();
    let mut extras = json!({
        "q3_map": map.name,
        "q3_format": bsp.format.to_string(),
        "q3_scale": opts.scale,
        "q3_overbright_bits": opts.overbright_bits,
    });
    if let Some(why) = &bsp.collision.error {
        summary.warnings.push(format!("the map's solid structure is left out ({why}); relight will guess where solid is from the faces"));
    }
    if let Some(solids) = crate::solids::q3map2_solids(&bsp, opts.scale) {
        extras["q3_solids"] = solids;
    }
    let cmdline = ents.iter().find(|e| e.classname() == "worldspawn").and_then(|w| w.get("_q3map2_cmdline"));
    if let Some((record, bytes)) = crate::casters::q3map2_casters(bsp, &infos, &ents, cmdline) {
        extras[crate::casters::KEY] = record;
        scene.blobs.push((crate::casters::KEY.to_string(), bytes));
    }
    let subdivisions = crate::lightmesh::subdivisions_of(cmdline);
    if let Some(meshes) = crate::lightmesh::q3map2_patch_lights(bsp, &emitting_patches, subdivisions, opts.scale) {
        extras["q3_patch_lights"] = meshes;
    }
    if let Some(points) = crate::lightmesh::q3map2_patch_vertices(bsp, &vertex_lit_patches, opts.scale) {
        extras["q3_patch_vertices"] = points;
    }
    if crate::patch_luxels::super_sample_of(cmdline) == 1 {
        if let Some(luxels) = crate::patch_luxels::q3map2_patch_luxels(bsp, &lit_patches, subdivisions, opts.scale) {
            extras["q3_patch_luxels"] = luxels;
        }
    }
    scene.extras = Some(extras);
    lap(&mut summary, "entities");
    Ok((scene, summary))
}

/// Appends one surface to a primitive: glTF axes and meters, reversed winding, atlas UVs,
/// unit normals (a zero normal takes the mean of its triangles' normals). Returns the
/// number of normals repaired so.
fn append_surface(prim: &mut scene::Primitive, g: &SurfaceGeometry, scale: f64, lm: Option<(&atlas::Placement, &atlas::AtlasImage)>) -> usize {
    let base = prim.positions.len() as u32;
    let start = prim.positions.len();
    for v in g.verts.iter() {
        prim.positions.push(units::position(v.xyz, scale));
        let n = units::direction([v.normal[0] as f64, v.normal[1] as f64, v.normal[2] as f64]);
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        // Zero or non-finite normals are repaired from the geometry below.
        prim.normals.push(if len > 1e-6 && len.is_finite() { [(n[0] / len) as f32, (n[1] / len) as f32, (n[2] / len) as f32] } else { [0.0; 3] });
        let finite2 = |t: [f32; 2]| if t.iter().all(|x| x.is_finite()) { t } else { [0.0; 2] };
        prim.uv0.push(finite2(v.st));
        if let (Some(uv1), Some((pl, img))) = (prim.uv1.as_mut(), lm) {
            uv1.push(pl.map_uv(finite2(v.lightmap), img));
        } else if let Some(uv1) = prim.uv1.as_mut() {
            uv1.push([0.0, 0.0]);
        }
        if let Some(c) = prim.colors.as_mut() {
            c.push(v.color);
        }
    }
    for t in g.indices.chunks_exact(3) {
        // Quake fronts are clockwise, glTF's counter-clockwise.
        prim.indices.extend_from_slice(&[base + t[0], base + t[2], base + t[1]]);
    }
    // Repair zero normals from the geometry.
    let repaired = prim.normals[start..].iter().filter(|n| **n == [0.0; 3]).count();
    if repaired > 0 {
        let mut acc = vec![[0.0f64; 3]; g.verts.len()];
        for t in g.indices.chunks_exact(3) {
            let p = [t[0], t[2], t[1]].map(|i| prim.positions[start + i as usize].map(|x| x as f64));
            let e1 = [p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]];
            let e2 = [p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]];
            let n = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]];
            for &i in t {
                for k in 0..3 {
                    acc[i as usize][k] += n[k];
                }
            }
        }
        for (i, a) in acc.iter().enumerate() {
            if prim.normals[start + i] == [0.0; 3] {
                let len = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
                prim.normals[start + i] = if len > 0.0 { a.map(|x| (x / len) as f32) } else { [0.0, 1.0, 0.0] };
            }
        }
    }
    repaired
}

fn entity_extras(e: &Entity) -> Value {
    Value::Object(e.pairs.iter().map(|(k, v)| (k.clone(), Value::String(v.clone()))).collect())
}

/// Yaw (and pitch, roll) of an entity as a glTF rotation.
fn entity_rotation(e: &Entity) -> Option<[f32; 4]> {
    let (pitch, yaw, roll) = match (e.vec3("angles"), e.number("angle")) {
        (Some(a), _) => (a[0], a[1], a[2]),
        (None, Some(y)) => (0.0, y, 0.0),
        _ => return None,
    };
    if pitch == 0.0 && yaw == 0.0 && roll == 0.0 {
        return None;
    }
    // Quake: yaw about +Z, pitch about +Y (positive looks down), roll about +X; in glTF
    // axes +Z(q3) = +Y, +Y(q3) = -Z, +X = +X.
    let q = glam::DQuat::from_axis_angle(glam::DVec3::Y, yaw.to_radians())
        * glam::DQuat::from_axis_angle(glam::DVec3::NEG_Z, pitch.to_radians())
        * glam::DQuat::from_axis_angle(glam::DVec3::X, roll.to_radians());
    let q = q.normalize();
    Some([q.x as f32, q.y as f32, q.z as f32, q.w as f32])
}

/// The `-gamma G` of the light stage of a recorded q3map2 command line (stages are
/// separated by `;`), when it is a sane positive number.
pub fn light_gamma(cmdline: &str) -> Option<f64> {
    crate::lightmesh::light_stage_value(cmdline, "-gamma")?.parse::<f64>().ok().filter(|g| g.is_finite() && (0.1..=10.0).contains(g))
}

/// The entities of a `.map` source ([`crate::mapfile`]), read with a size bound.
fn read_map_source(path: &Path, max_bytes: u64) -> Result<Vec<Entity>, Error> {
    let shown = path.display().to_string();
    let meta = std::fs::metadata(path).map_err(|source| Error::Io { path: shown.clone(), source })?;
    if meta.len() > max_bytes {
        return Err(Error::invalid(&shown, format!("{} bytes, more than the {max_bytes} accepted for a .map source", meta.len())));
    }
    let bytes = std::fs::read(path).map_err(|source| Error::Io { path: shown.clone(), source })?;
    crate::mapfile::parse(&String::from_utf8_lossy(&bytes)).map_err(|m| Error::invalid(&shown, m))
}

/// Point entities as empty nodes (key/values in extras); with `entity_lights`, light
/// entities and sky-shader suns as KHR_lights_punctual lights. With `source` (the
/// entities of the map's `.map` source), the lights are the source's light entities
/// (spot targets resolved among the source's entities) and the BSP's own light entities,
/// if it kept any, are not converted twice.
fn add_entities(scene: &mut Scene, ents: &[Entity], source: Option<&[Entity]>, infos: &[ShaderInfo], opts: &Options, summary: &mut Summary) {
    let mut children = Vec::new();
    let entity_lights = opts.entity_lights || source.is_some();
    for (i, e) in ents.iter().enumerate() {
        let class = e.classname();
        if class == "worldspawn" || e.get("model").is_some_and(|m| m.starts_with('*')) {
            continue;
        }
        if source.is_some() && class == "light" {
            continue;
        }
        let origin = e.vec3("origin").unwrap_or([0.0; 3]);
        let translation = units::position([origin[0] as f32, origin[1] as f32, origin[2] as f32], opts.scale);
        let mut node = scene::Node {
            name: format!("{}_{i}", if class.is_empty() { "entity" } else { class }),
            translation: Some(translation),
            rotation: entity_rotation(e),
            extras: Some(entity_extras(e)),
            ..Default::default()
        };
        if entity_lights && class == "light" {
            match entity_light(e, ents, opts, i) {
                Ok((light, rotation)) => {
                    scene.lights.push(light);
                    node.light = Some(scene.lights.len() - 1);
                    if rotation.is_some() {
                        node.rotation = rotation;
                    }
                }
                Err(w) => summary.warnings.push(w),
            }
        }
        children.push(scene.add_node(node));
    }
    for (i, e) in source.unwrap_or(&[]).iter().enumerate().filter(|(_, e)| e.classname() == "light") {
        let origin = e.vec3("origin").unwrap_or([0.0; 3]);
        let mut node = scene::Node {
            name: format!("light_{i}"),
            translation: Some(units::position([origin[0] as f32, origin[1] as f32, origin[2] as f32], opts.scale)),
            extras: Some(entity_extras(e)),
            ..Default::default()
        };
        match entity_light(e, source.unwrap_or(&[]), opts, i) {
            Ok((light, rotation)) => {
                scene.lights.push(light);
                node.light = Some(scene.lights.len() - 1);
                node.rotation = rotation;
                children.push(scene.add_node(node));
            }
            Err(w) => summary.warnings.push(format!("{} (in the .map source)", w)),
        }
    }
    if entity_lights {
        let mut suns: Vec<crate::shader::Sun> = Vec::new();
        for s in infos.iter().filter_map(|i| i.sun) {
            if !suns.contains(&s) {
                suns.push(s);
            }
        }
        for (k, s) in suns.iter().enumerate() {
            let (a, b) = (s.degrees.to_radians(), s.elevation.to_radians());
            let to_sun = [a.cos() * b.cos(), a.sin() * b.cos(), b.sin()];
            let travel = units::direction([-to_sun[0], -to_sun[1], -to_sun[2]]);
            let max = s.color.iter().copied().fold(0.0, f64::max);
            let color = if max > 0.0 { s.color.map(|c| (c / max) as f32) } else { [1.0; 3] };
            scene.lights.push(scene::Light {
                name: format!("sun_{k}"),
                kind: LightKind::Directional,
                color,
                intensity: units::q3map2_sun_lux(s.intensity, opts.overbright_bits) as f32,
                range: None,
                extras: Some(json!({ "q3_sun": [s.color[0], s.color[1], s.color[2], s.intensity, s.degrees, s.elevation] })),
            });
            let n = scene.add_node(scene::Node {
                name: format!("sun_{k}"),
                light: Some(scene.lights.len() - 1),
                rotation: Some(units::quat_from_neg_z(travel)),
                ..Default::default()
            });
            children.push(n);
        }
    }
    if !children.is_empty() {
        let n = scene.add_node(scene::Node { name: "entities".into(), children, ..Default::default() });
        scene.roots.push(n);
    }
}

/// A q3map2 light entity as a KHR light (and the node rotation of a spot light).
fn entity_light(e: &Entity, ents: &[Entity], opts: &Options, index: usize) -> Result<(scene::Light, Option<[f32; 4]>), String> {
    let light = e.number("light").or_else(|| e.number("_light")).unwrap_or(300.0);
    if light <= 0.0 {
        return Err(format!("light entity {index}: intensity {light} is not positive; not converted to a light"));
    }
    let color = e.vec3("_color").filter(|c| c.iter().all(|x| *x >= 0.0) && c.iter().any(|x| *x > 0.0)).unwrap_or([1.0; 3]);
    let max = color.iter().copied().fold(0.0, f64::max);
    let color = color.map(|c| (c / max) as f32);
    let spawnflags = e.number("spawnflags").unwrap_or(0.0) as i64;
    let intensity = units::q3map2_point_candela(light, opts.scale, opts.overbright_bits) as f32;
    let mut extras = json!({ "q3_light": light, "q3_entity": index });
    if spawnflags & 1 != 0 {
        extras["q3_falloff"] = json!("linear");
    }
    let origin = e.vec3("origin").unwrap_or([0.0; 3]);
    let target = e.get("target").and_then(|t| ents.iter().find(|o| o.get("targetname") == Some(t)));
    let (kind, rotation) = match target.and_then(|t| t.vec3("origin")) {
        Some(to) => {
            // q3map2's cone: radius (default 64) plus 16 units at the target's distance
            // (64 when the target sits on the light), softened over its last 32 units.
            let d = [to[0] - origin[0], to[1] - origin[1], to[2] - origin[2]];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let (d, dist) = if len > 0.0 { (d, len) } else { ([0.0, 0.0, -1.0], 64.0) };
            let radius = e.number("radius").filter(|r| *r != 0.0).unwrap_or(64.0);
            let radius_by_dist = ((radius + 16.0) / dist).max(1e-6);
            let outer = radius_by_dist.atan().clamp(1e-3, std::f64::consts::FRAC_PI_2 - 1e-3);
            let inner = (((radius + 16.0 - 32.0).max(0.0)) / dist).atan().min(outer * 0.999);
            extras["q3_radius_by_dist"] = json!(radius_by_dist);
            (LightKind::Spot { inner: inner as f32, outer: outer as f32 }, Some(units::quat_from_neg_z(units::direction(d))))
        }
        None => (LightKind::Point, None),
    };
    let name = format!("light_{index}");
    Ok((scene::Light { name, kind, color, intensity, range: None, extras: Some(extras) }, rotation))
}


#[cfg(test)]
mod tests {
    use super::light_gamma;

    #[test]
    fn gamma_comes_from_the_light_stage_only() {
        assert_eq!(light_gamma("-meta -patchmeta; -vis; -light -fast -gamma 1.5 -samples 3"), Some(1.5));
        assert_eq!(light_gamma("-meta; -vis; -light -fast"), None);
        assert_eq!(light_gamma("-gamma 2; -light -fast"), None, "another stage's switch");
        assert_eq!(light_gamma("-light -gamma x"), None);
        assert_eq!(light_gamma("-light -gamma 1e9"), None);
    }
}
