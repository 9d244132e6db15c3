//! `q3gltf`: Quake III maps to glTF 2.0, with their baked lightmaps.
//!
//! The command line only parses arguments, shows progress and prints reports; the work
//! is done by the library crates (`q3gltf-convert`, `q3gltf-relight`).

mod bake_cmd;
mod memory;
mod relight_cmd;

use clap::{Args, Parser, Subcommand};
use q3gltf_convert::{pipeline, MapSource, Options};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

#[derive(Parser)]
#[command(name = "q3gltf", version, about = "Quake III engine maps to glTF 2.0, with their baked lightmaps", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Convert a map (.bsp file, or a map name inside the game's .pk3 archives) to glTF.
    ///
    /// Geometry is written in meters, Y up, counter-clockwise fronts. Each material's
    /// base colour is its shader's albedo image; the lightmap atlas is its
    /// occlusionTexture on TEXCOORD_1 (bytes unchanged; decode with
    /// e = byte * 2^overbright / 255, recorded in the material extras). Vertex-lit
    /// surfaces carry COLOR_0. Point entities become empty nodes with their keys in extras.
    Convert(ConvertArgs),
    /// Print what a BSP file contains (format, lump counts), as text or JSON.
    Info(InfoArgs),
    /// List the maps (`maps/*.bsp`) of the game directories, one name per line.
    Maps(MapsArgs),
    /// Estimate point lights whose direct lighting reproduces a converted scene's baked
    /// lightmaps, and write the scene with them as KHR_lights_punctual lights.
    ///
    /// Target: albedo x lightmap (bytes decoded as e = byte * 2^overbright / 255) at
    /// every lightmap texel's surface point (`--target luxel`), or its mass-lumped L2
    /// projection onto the vertices (`--target vertex`, the thesis). Model: Lambertian
    /// albedo * E / pi from point lights of intensity I [W/sr] with shadow rays; written
    /// as candela (683 * I). Prints the error reached, the lights and the time of each stage.
    Relight(relight_cmd::RelightArgs),
    /// Print, as JSON, the irradiance that a scene's own point lights give at one surface
    /// point (relight's forward model, with shadow rays through the scene): for checking
    /// units against a renderer.
    Probe(relight_cmd::ProbeArgs),
    /// Render a scene's own light sources (a relit scene's lights, sun, emissive
    /// surfaces and recorded terms) with relight's forward model into its lightmap layout:
    /// HDR lightmaps (OpenEXR, linear e = E / pi), the original lightmaps decoded, and the
    /// signed residual, with PNG previews: where a fit matches the baked lighting.
    Bake(bake_cmd::BakeArgs),
}

#[derive(Args)]
struct MapsArgs {
    /// Game directory with .pk3 archives and loose files (repeatable).
    #[arg(long = "game-dir", value_name = "DIR", required = true)]
    game_dirs: Vec<PathBuf>,
}

#[derive(Args)]
struct MapArgs {
    /// A .bsp file, or a map name (`oa_dm1`, `maps/oa_dm1.bsp`) looked up in --game-dir.
    map: String,
    /// Game directory with .pk3 archives and loose files (repeatable; later ones override
    /// earlier ones). Default for a .bsp path: the directory above its `maps/` folder.
    #[arg(long = "game-dir", value_name = "DIR")]
    game_dirs: Vec<PathBuf>,
}

#[derive(Args)]
struct ConvertArgs {
    #[command(flatten)]
    map: MapArgs,
    /// Output file: .gltf (with a .bin and a <name>_textures/ folder beside it) or .glb.
    #[arg(short, long, value_name = "OUT")]
    output: PathBuf,
    /// Meters per Quake unit.
    #[arg(long, default_value_t = 0.0254)]
    scale: f64,
    /// Largest distance of tessellated patches from the true curved surface, in Quake
    /// units (the engine's r_subdivisions).
    #[arg(long = "patch-tolerance", default_value_t = 4.0, value_name = "UNITS")]
    patch_tolerance: f64,
    /// Write a binary .glb whatever the output's extension says.
    #[arg(long)]
    glb: bool,
    /// Leave out sky surfaces (otherwise they form their own "sky" node).
    #[arg(long = "no-sky")]
    no_sky: bool,
    /// Keep opaque faces that overlap on one plane as the BSP has them. By default the
    /// later face gives up the overlapping part (cut exactly, attributes interpolated):
    /// the game draws both alike, but a ray tracer such as Cycles shadows one with the
    /// other and renders the overlap black.
    #[arg(long = "keep-overlaps")]
    keep_overlaps: bool,
    /// Also write light entities (if the map kept them) and q3map_sun as
    /// KHR_lights_punctual lights, converted with q3map2's formula (candela, lux).
    #[arg(long = "entity-lights")]
    entity_lights: bool,
    /// The map's .map source (mappers keep it; q3map2 strips light entities from the
    /// BSP): its light entities become KHR_lights_punctual point and spot lights
    /// (q3map2's units: about 163 cd per unit of `light`), plus the sky shaders' suns.
    #[arg(long = "lights-from", value_name = "SRC.map")]
    lights_from: Option<PathBuf>,
    /// Also write the MOZ_lightmap material extension (in extensionsUsed only).
    #[arg(long = "moz-lightmap")]
    moz_lightmap: bool,
    /// The engine's r_mapOverBrightBits, recorded with the lightmaps.
    #[arg(long = "overbright-bits", default_value_t = 2, value_parser = clap::value_parser!(u32).range(0..=8))]
    overbright_bits: u32,
    /// Print the summary as JSON on stdout instead of text.
    #[arg(long)]
    json: bool,
    /// No progress display.
    #[arg(short, long)]
    quiet: bool,
}

#[derive(Args)]
struct InfoArgs {
    #[command(flatten)]
    map: MapArgs,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// An existing file is a map path; anything else is a map name for the game directories.
fn source_of(map: &str) -> MapSource {
    let p = PathBuf::from(map);
    if p.is_file() {
        MapSource::Path(p)
    } else {
        MapSource::Name(map.to_string())
    }
}

fn main() -> ExitCode {
    // An interrupted run removes its temporary files and leaves no partial output.
    q3gltf_convert::output::remove_temporaries_on_signal();
    memory::keep_freed_memory();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Convert(a) => run_convert(a),
        Command::Info(a) => run_info(a),
        Command::Maps(a) => run_maps(a),
        Command::Probe(a) => match relight_cmd::probe(a) {
            Ok(()) => return ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("q3gltf: error: {e}");
                return ExitCode::from(1);
            }
        },
        Command::Bake(a) => match bake_cmd::run(a) {
            Ok(()) => return ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("q3gltf: error: {e}");
                return ExitCode::from(1);
            }
        },
        Command::Relight(a) => match relight_cmd::run(a) {
            Ok(()) => return ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("q3gltf: error: {e}");
                return ExitCode::from(1);
            }
        },
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("q3gltf: error: {e}");
            ExitCode::from(1)
        }
    }
}

fn run_convert(a: ConvertArgs) -> Result<(), q3gltf_convert::Error> {
    let mut output = a.output.clone();
    if a.glb && !output.extension().is_some_and(|e| e.eq_ignore_ascii_case("glb")) {
        output.set_extension("glb");
    }
    let opts = Options {
        game_dirs: a.map.game_dirs.clone(),
        scale: a.scale,
        patch_tolerance: a.patch_tolerance,
        no_sky: a.no_sky,
        keep_overlaps: a.keep_overlaps,
        entity_lights: a.entity_lights,
        lights_from: a.lights_from.clone(),
        moz_lightmap: a.moz_lightmap,
        overbright_bits: a.overbright_bits,
        ..Options::default()
    };
    if !(opts.scale.is_finite() && opts.scale > 0.0) {
        return Err(q3gltf_convert::Error::Usage(format!("--scale must be a positive number, not {}", opts.scale)));
    }
    if !(opts.patch_tolerance.is_finite() && opts.patch_tolerance > 0.0) {
        return Err(q3gltf_convert::Error::Usage(format!("--patch-tolerance must be a positive number, not {}", opts.patch_tolerance)));
    }
    let bar = if a.quiet || a.json {
        indicatif::ProgressBar::hidden()
    } else {
        let b = indicatif::ProgressBar::new_spinner();
        b.set_style(indicatif::ProgressStyle::with_template("{spinner} {elapsed_precise} {msg}").unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()));
        b.enable_steady_tick(Duration::from_millis(100));
        b
    };
    let progress = |msg: &str| bar.set_message(format!("{}: {msg}", a.map.map));
    let result = pipeline::convert(&source_of(&a.map.map), &output, &opts, &progress);
    bar.finish_and_clear();
    let s = result?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&s).unwrap_or_default());
        return Ok(());
    }
    let c = &s.surfaces;
    println!("{} ({}) -> {}", s.map, s.format, output.display());
    println!(
        "  surfaces: {} polygons, {} patches, {} meshes, {} flares; {} hidden, {} sky, {} invalid",
        c.polygon, c.patch, c.mesh, c.flare, c.hidden, c.sky, c.invalid
    );
    if c.repaired_normals > 0 {
        println!("  normals: {} zero BSP normals replaced by their triangles' mean normal", c.repaired_normals);
    }
    let o = &c.overlaps;
    if o.triangles_cut + o.triangles_removed + o.triangles_left > 0 {
        println!(
            "  overlaps: {} triangles cut and {} removed where an earlier opaque face covers them on the same plane ({:.1} m2){}",
            o.triangles_cut,
            o.triangles_removed,
            o.area_removed_m2,
            if o.triangles_left > 0 { format!("; {} left whole (too many pieces, or past the work budget)", o.triangles_left) } else { String::new() }
        );
    }
    println!("  lighting: {} lightmapped, {} vertex-lit, {} unlit surfaces; {} lightmap pages in {} atlas image(s){}",
        c.lightmapped, c.vertex_lit, c.unlit, s.lightmap_pages, s.lightmap_atlases, if s.deluxe { " (deluxe map)" } else { "" });
    println!("  output: {} triangles, {} vertices, {} materials, {} images, {} entities, {} lights, {:.1} MB",
        s.triangles, s.vertices, s.materials, s.images, s.entities, s.lights, s.output_bytes as f64 / 1e6);
    if !s.missing_textures.is_empty() {
        eprintln!("q3gltf: warning: {} texture(s) not found, shown with a placeholder: {}", s.missing_textures.len(), s.missing_textures.join(", "));
    }
    for w in &s.warnings {
        eprintln!("q3gltf: warning: {w}");
    }
    let times: Vec<String> = s.timings.iter().map(|(k, v)| format!("{k} {:.0} ms", v * 1e3)).collect();
    println!("  time: {}", times.join(", "));
    Ok(())
}

fn run_maps(a: MapsArgs) -> Result<(), q3gltf_convert::Error> {
    let mut vfs = q3gltf_convert::vfs::Vfs::new();
    for d in &a.game_dirs {
        vfs.mount_dir(d)?;
    }
    for m in vfs.list("maps", "bsp") {
        let name = m.trim_start_matches("maps/").trim_end_matches(".bsp");
        if !name.contains('/') {
            println!("{name}");
        }
    }
    Ok(())
}

fn run_info(a: InfoArgs) -> Result<(), q3gltf_convert::Error> {
    let opts = Options { game_dirs: a.map.game_dirs.clone(), ..Options::default() };
    let map = q3gltf_convert::load(&source_of(&a.map.map), &opts)?;
    let b = &map.bsp;
    let count = |k: q3gltf_convert::bsp::SurfaceType| b.surfaces.iter().filter(|s| s.kind == k).count();
    use q3gltf_convert::bsp::SurfaceType as T;
    let other = b.surfaces.iter().filter(|s| matches!(s.kind, T::Other(_))).count();
    let v = serde_json::json!({
        "file": map.shown,
        "format": match b.format { q3gltf_convert::bsp::Format::Rbsp => "RBSP", _ => "IBSP" },
        "version": match b.format { q3gltf_convert::bsp::Format::Ibsp(v) => v, _ => 1 },
        "vertices": b.verts.len(),
        "indices": b.indices.len(),
        "surfaces": { "polygon": count(T::Polygon), "patch": count(T::Patch), "mesh": count(T::Mesh), "flare": count(T::Flare), "other": other },
        "lightmap_pages": b.lightmaps.len(),
        "shaders": b.shaders.len(),
        "models": b.models.len(),
        "entities": q3gltf_convert::entities::parse(&b.entities).map(|e| e.len()).unwrap_or(0),
        "planes": b.other.planes,
        "nodes": b.other.nodes,
        "leafs": b.other.leafs,
        "brushes": b.other.brushes,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&v).unwrap_or_default());
    } else {
        println!("{} ({})", map.shown, b.format);
        for (k, val) in v.as_object().into_iter().flatten().skip(3) {
            println!("  {k}: {val}");
        }
    }
    Ok(())
}
