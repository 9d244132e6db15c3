//! Stage two of q3gltf: estimate the light sources whose lighting reproduces the baked
//! lightmaps of a glTF written by `q3gltf convert` (or by Blender from it), with a forward
//! model of how q3map2 made them, and write the scene back with `KHR_lights_punctual`
//! lights and emissive materials.
//!
//! Data flow (ARCHITECTURE.md has the codemap): [`io::gltf_in`] reads the scene into world
//! space ([`scene`]); [`subdivide`] refines it for the vertex target; [`rows`] builds the
//! objective's rows ([`rows::luxel`] or the thesis's [`rows::projection`]); [`trace`]
//! builds the BVH and caches visibility; [`model`] is the forward model, one module per
//! term, with its gradient; [`fit`] drives the optimisers ([`optim`]) in phases on a
//! [`backend`] (the CPU or [`gpu`]), or on the thesis's estimator [`light_tracing`] as a
//! baseline; [`init`] places the starting lights and searches the
//! sun; [`pipeline`] runs the stages; [`io::lights_out`] writes the result and [`report`]
//! the numbers; [`probe`] evaluates the model at one point; [`bake`] renders a file's own
//! lights into its lightmap layout (EXR) beside the original and the residual.

pub mod atlas;
pub mod backend;
pub mod bake;
pub mod casters;
pub mod error;
pub mod fit;
pub mod gather;
pub mod gpu;
pub mod init;
pub mod io;
pub mod light_tracing;
pub mod model;
pub mod optim;
pub mod pipeline;
pub mod probe;
pub mod report;
pub mod rows;
pub mod scene;
pub mod schemes;
pub mod subdivide;
#[cfg(test)]
pub(crate) mod testutil;
pub mod texel;
pub mod trace;
