//! Rays through the scene: a triangle BVH ([`tree`], layout shared with
//! `shaders/bvh.wgsl`), the pieces q3map2 traced its shadows against ([`pieces`], a tree
//! of their own), the scene's occluders that pair the two ([`bvh`]), the cached
//! shadow-ray visibility of lights and the sun ([`visibility`]), and where q3map2 found
//! solid ([`solids`]). The CPU's shadow walks run over a four-wide view of a tree
//! ([`wide`]); what the walks on both sides share is [`layout`].

pub mod bvh;
pub mod layout;
pub mod pieces;
pub mod solids;
pub mod tree;
pub mod visibility;
pub mod wide;
