//! Stage two of q3gltf: estimate a small set of point lights whose direct lighting
//! reproduces the baked lightmaps of a glTF written by `q3gltf convert` (or by Blender
//! from it), and write the scene back with `KHR_lights_punctual`.
//!
//! Data flow: [`gltf_in`] reads the scene into world space ([`scene`]); [`subdivide`]
//! refines it to lightmap resolution; [`target`] projects `albedo x lightmap` onto the
//! vertices; [`bvh`] is built once; [`fit`] drives the optimisers ([`optim`]) over the
//! forward model ([`model`], visibility cached in [`visibility`]) on a [`backend`];
//! [`init`] chooses the starting lights; [`lights_out`] writes the result and [`report`]
//! the numbers; [`ply`] writes the fitted mesh for inspection.

pub mod backend;
pub mod bvh;
pub mod error;
pub mod fit;
pub mod gltf_in;
pub mod gpu;
pub mod indirect;
pub mod init;
pub mod lights_out;
pub mod luxel;
pub mod model;
pub mod optim;
pub mod pipeline;
pub mod ply;
pub mod probe;
pub mod report;
pub mod scene;
pub mod schemes;
pub mod subdivide;
pub mod target;
#[cfg(test)]
pub(crate) mod testutil;
pub mod texel;
pub mod visibility;
