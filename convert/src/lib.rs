//! # q3gltf-convert
//!
//! Converts Quake III engine maps (IBSP 46 / 47, RBSP 1) into glTF 2.0 scenes: geometry
//! (polygons, triangle meshes, tessellated Bezier patches), materials resolved through
//! shader scripts with their textures, and the baked lightmaps as a second UV set
//! (TEXCOORD_1) with the lightmap atlas images.
//!
//! Module map (see ARCHITECTURE.md for the data flow and invariants):
//!
//! * [`bsp`]: the file format, typed and bounds-checked (reader and writer).
//! * [`vfs`]: game directories and `.pk3` archives as one file system.
//! * [`shader`]: shader script parsing.
//! * [`material`]: shader + scripts -> visibility, albedo image, alpha, sidedness.
//! * [`texture`]: image files -> glTF-ready PNG/JPEG bytes, with limits.
//! * [`solids`]: where q3map2 found solid, for relight's samples; [`casters`]: what
//!   q3map2's light stage traced its shadow rays against, for relight's shadows.
//! * [`entities`]: the entity lump; [`mapfile`]: the entities of a `.map` source.
//! * [`patch`]: adaptive, stitched Bezier patch tessellation; [`lightmesh`]: the coarser
//!   mesh q3map2's light stage made of a patch (what its surface lights emit from);
//!   [`patch_luxels`]: where q3map2 sampled a curved patch's luxels on that mesh.
//! * [`overlap`]: opaque faces overlapping on one plane, cut so a ray tracer sees one.
//! * [`lightmaps`], [`atlas`]: lightmap pages and their packing.
//! * [`units`]: axes, scale and the radiometric conversions.
//! * [`scene`]: the converted scene; [`gltf_out`]: writing it as `.gltf`/`.glb`.
//! * [`output`]: atomic files and safe names.
//! * [`pipeline`]: the whole conversion.

pub mod atlas;
pub mod bsp;
pub mod casters;
pub mod entities;
pub mod error;
pub mod gltf_out;
pub mod lightmaps;
pub mod lightmesh;
pub mod mapfile;
pub mod material;
pub mod output;
pub mod overlap;
pub mod patch;
pub mod patch_luxels;
pub mod pipeline;
pub mod scene;
pub mod shader;
pub mod solids;
pub mod texture;
pub mod units;
pub mod vfs;

pub use error::Error;
pub use pipeline::{convert, load, MapSource, Options, Summary};
