//! Rays through the scene: the BVH ([`bvh`], layout shared with `shaders/bvh.wgsl`) and
//! the cached shadow-ray visibility of lights and the sun ([`visibility`]), and where
//! q3map2 found solid ([`solids`]), and the pieces q3map2 traced its shadows against
//! ([`pieces`]). The CPU's shadow walks run over a four-wide view of the tree ([`wide`]); what
//! the walks on both sides share is [`layout`].

pub mod bvh;
pub mod layout;
pub mod pieces;
pub mod solids;
pub mod visibility;
pub mod wide;
