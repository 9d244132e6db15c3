//! What the CPU's and the WGSL's walks share about the tree (`shaders/bvh.wgsl`): the
//! node and triangle layouts ([`crate::trace::tree`] builds them, [`crate::trace::wide`]
//! views them four-wide), the stack bound, and the shadow rays' slack.

/// A node of the flattened tree: an inner node's left child is the next node and
/// `right_or_first` its right child; a leaf (`count > 0`) holds triangles
/// `right_or_first .. right_or_first + count`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Node {
    pub min: [f32; 3],
    pub right_or_first: u32,
    pub max: [f32; 3],
    pub count: u32,
}

/// A triangle as `(v0, e1 = v1 - v0, e2 = v2 - v0)` for Moeller-Trumbore; the fourth
/// lanes are spare (q3map2's pieces keep their leaf, slack and coplanar threshold there,
/// [`crate::trace::pieces`]).
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Tri {
    pub v0: [f32; 4],
    pub e1: [f32; 4],
    pub e2: [f32; 4],
}

/// Stack depth of the traversals (CPU and WGSL); the build never goes deeper.
pub const MAX_DEPTH: usize = 48;

/// Barycentric slack of the shadow rays' hit test ([`crate::trace::tree::Tree::occluded`],
/// the WGSL shadow walk): in f32 a ray through the edge two triangles share can miss both
/// (fixture `arch`: a floor luxel's ray through a diagonal of the column's mesh, which
/// q3map2's 1% slack blocks). A slack this small closes the crack without q3map2's whole
/// 1% (see the module docs of [`crate::trace::tree`]). The first-hit walks (the sun's way
/// to the sky, bounces) stay exact: with the slack there, the synthetic sun's search
/// settled 0.4 degree off (error 0.0207 against 0.0007), a plateau of its pattern search,
/// not a worse model.
pub const EDGE_SLACK: f32 = 1e-5;
