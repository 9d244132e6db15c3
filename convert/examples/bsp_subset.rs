//! Writes a small BSP made of a few surfaces of a real one: fuzzing seeds that keep the
//! real data's structure (records, shaders, patches, lightmap page, entities) at a size
//! the fuzzer can mutate quickly.
//!
//! `bsp_subset IN.bsp OUT.bsp [PER_TYPE [rbsp]]` keeps up to PER_TYPE (default 6)
//! surfaces of each type from the world model, their vertices and indexes, every shader,
//! the first lightmap page they use (other pages' surfaces become vertex lit) and the
//! entity lump; `rbsp` writes Raven's RBSP 1 layout instead of IBSP.

use q3gltf_convert::bsp::{Bsp, Format, Model, SurfaceType};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err("usage: bsp_subset IN.bsp OUT.bsp [PER_TYPE [rbsp]]".into());
    }
    let per_type: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(6);
    let src = Bsp::parse(&std::fs::read(&args[1])?)?;
    let world = src.models.first().ok_or("no models")?;
    let range = world.first_surface as usize..(world.first_surface + world.num_surfaces) as usize;
    let mut taken: std::collections::BTreeMap<SurfaceType, usize> = Default::default();
    let mut out = Bsp { models: Vec::new(), verts: Vec::new(), indices: Vec::new(), surfaces: Vec::new(), lightmaps: Vec::new(), ..src.clone() };
    let page = src.surfaces[range.clone()].iter().map(|s| s.lightmap).find(|&l| l >= 0 && (l as usize) < src.lightmaps.len());
    if let Some(p) = page {
        out.lightmaps.push(src.lightmaps[p as usize].clone());
    }
    for s in &src.surfaces[range] {
        let n = taken.entry(s.kind).or_default();
        if *n >= per_type {
            continue;
        }
        *n += 1;
        let mut t = s.clone();
        t.first_vert = out.verts.len() as u32;
        t.first_index = out.indices.len() as u32;
        if matches!(s.kind, SurfaceType::Polygon | SurfaceType::Mesh | SurfaceType::Patch) {
            out.verts.extend_from_slice(src.surface_verts(s));
        } else {
            t.num_verts = 0;
        }
        if matches!(s.kind, SurfaceType::Polygon | SurfaceType::Mesh) {
            out.indices.extend_from_slice(src.surface_indices(s));
        } else {
            t.num_indexes = 0;
        }
        if s.lightmap >= 0 {
            t.lightmap = if Some(s.lightmap) == page { 0 } else { -3 };
        }
        out.surfaces.push(t);
    }
    if args.get(4).is_some_and(|a| a == "rbsp") {
        out.format = Format::Rbsp;
    }
    out.models.push(Model { first_surface: 0, num_surfaces: out.surfaces.len() as u32, ..world.clone() });
    let bytes = out.to_bytes();
    Bsp::parse(&bytes)?;
    std::fs::write(&args[2], &bytes)?;
    println!("{}: {} surfaces, {} bytes", args[2], out.surfaces.len(), bytes.len());
    Ok(())
}
