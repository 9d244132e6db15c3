//! The scene's occluders, as every ray of relight sees them: the tree over the mesh's
//! casting triangles ([`Tree`]: first hits, nearest-surface queries, and shadow rays where
//! the file carries nothing better) and, where the file carries q3map2's casters, the
//! pieces its light stage traced its shadows against ([`Shadow`]), which every shadow ray
//! then asks instead ([`crate::trace::visibility`] chooses; first hits stay on the mesh).
//!
//! A [`Bvh`] derefs to its mesh tree, so a walk over the mesh reads `bvh.first_hit(..)`;
//! the pieces are `bvh.shadow`. The tree and the pieces know nothing of this pairing
//! ([`crate::trace::tree`], [`crate::trace::pieces`]).

use crate::scene::{Mesh, Scene};
use crate::trace::pieces::Shadow;
pub use crate::trace::tree::{Occluder, Tree, Tri, EDGE_SLACK};

#[derive(Debug, Clone)]
pub struct Bvh {
    /// The mesh's triangles (those that cast, for [`Bvh::occluders`]).
    pub tree: Tree,
    /// q3map2's own pieces for the shadow rays, where the scene carries them
    /// ([`crate::trace::pieces`]); the shadow tests use them instead of the triangles.
    pub shadow: Option<Box<Shadow>>,
}

impl std::ops::Deref for Bvh {
    type Target = Tree;

    fn deref(&self) -> &Tree {
        &self.tree
    }
}

impl Bvh {
    /// Over every non-degenerate triangle of the mesh, with exact hit tests; no pieces.
    pub fn build(mesh: &Mesh) -> Bvh {
        Bvh { tree: Tree::build(mesh), shadow: None }
    }

    /// Over the triangles whose material blocks light
    /// ([`crate::scene::Material::casts_shadow`]): the occluders of every shadow ray.
    /// With q3map2's casters in the scene, its pieces of them stop the shadow rays
    /// instead ([`Bvh::shadow`]).
    pub fn occluders(scene: &Scene) -> Bvh {
        let casts: Vec<bool> = scene.materials.iter().map(|m| m.casts_shadow).collect();
        let tree = Tree::build_where(&scene.mesh, |t| casts.get(scene.mesh.tri_material[t] as usize).copied().unwrap_or(true));
        let shadow = scene.casters.as_ref().map(|c| Box::new(Shadow::new(c, scene.origin, scene.units_m as f64)));
        Bvh { tree, shadow }
    }
}
