//! Files in and out: the glTF reader ([`gltf_in`]), the writer of the fitted lights and
//! emissive materials ([`lights_out`]), and the mesh as PLY for inspection ([`ply`]).

pub mod gltf_in;
pub mod lights_out;
pub mod ply;
