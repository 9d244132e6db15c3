//! Files in and out: the glTF reader ([`gltf_in`]), the writer of the fitted lights and
//! emissive materials ([`lights_out`]), the baked scene with new lightmap coordinates and
//! lightmaps ([`baked_gltf`]), the container handling both writers share ([`container`]),
//! and the mesh as PLY for inspection ([`ply`]).

pub mod baked_gltf;
pub mod container;
pub mod gltf_in;
pub mod lights_out;
pub mod ply;
