//! Rays through the scene: the BVH ([`bvh`], layout shared with `shaders/bvh.wgsl`) and
//! the cached shadow-ray visibility of lights and the sun ([`visibility`]).

pub mod bvh;
pub mod visibility;
