//! Where q3map2 found solid: the part of the BSP's solid structure ([`bsp::Collision`]) that
//! its light stage consulted to decide whether a lightmap's sample point lay in solid
//! (`ClusterForPointExt`), written into the scene's extras as `q3_solids` so that relight
//! can place its samples as q3map2 did.
//!
//! q3map2's rule: a point is in solid when it falls in a leaf of structural solid (the tree
//! keeps a point within 0.1 unit of a plane on the open side when it can), or within
//! 0.125 unit inside any opaque world brush listed in its leaf, detail brushes included.
//! A brush is opaque when none of its sides' shaders is translucent to light (`trans`,
//! liquids, clips, triggers, portals, alpha shadows and light filters all are:
//! `SetupBrushes`). The glTF keeps only visible faces, and a detail brush of caulk has
//! none, so without this the samples buried in such brushes cannot be told apart.
//!
//! The record (glTF axes, metres; relight's `trace::solids` reads it):
//! - `planes`: `[nx, ny, nz, d]` per plane, `n . p = d` on it, `n` out of the solid;
//! - `nodes`: `[plane, front, back]` per node, node 0 the root; a child `>= 0` is a later
//!   node, `< 0` the leaf `-(c + 1)`;
//! - `leafs`: `[solid, first, count]` per leaf: 1 in structural solid, and its range of
//!   `leaf_brushes`;
//! - `leaf_brushes`: indexes into `brushes` (only the opaque brushes of open leaves);
//! - `brushes`: `[first, count]` per brush into `brush_planes`;
//! - `brush_planes`: indexes into `planes`.

use crate::bsp::{self, Bsp};
use crate::units;
use serde_json::{json, Value};
use std::collections::HashMap;

/// Content flags of shaders that q3map2 counts as translucent to light (its
/// `C_TRANSLUCENT`, given by these surface parameters).
pub(crate) const TRANSLUCENT_CONTENTS: i32 = bsp::contents::TRANSLUCENT
    | bsp::contents::WATER
    | bsp::contents::SLIME
    | bsp::contents::LAVA
    | bsp::contents::PLAYERCLIP
    | bsp::contents::MONSTERCLIP
    | bsp::contents::BOTCLIP
    | bsp::contents::TRIGGER
    | bsp::contents::NODROP
    | bsp::contents::CLUSTERPORTAL
    | bsp::contents::DONOTENTER
    | bsp::contents::ORIGIN
    | bsp::contents::AREAPORTAL;
/// Surface flags with the same effect (`alphashadow`, `lightfilter`).
const TRANSLUCENT_SURFACE: i32 = bsp::surf::ALPHASHADOW | bsp::surf::LIGHTFILTER;

/// Whether a shader record lets light through, as q3map2 reads its surface parameters.
pub fn translucent(s: &bsp::ShaderRef) -> bool {
    s.content_flags & TRANSLUCENT_CONTENTS != 0 || s.surface_flags & TRANSLUCENT_SURFACE != 0
}

/// The world brushes that q3map2 treats as opaque: none of their sides translucent.
pub fn opaque_brushes(b: &Bsp) -> Vec<bool> {
    let c = &b.collision;
    let mut opaque = vec![false; c.brushes.len()];
    let Some(world) = b.models.first() else { return opaque };
    let (first, n) = (world.first_brush.max(0) as usize, world.num_brushes.max(0) as usize);
    for i in first..first.saturating_add(n).min(c.brushes.len()) {
        let br = &c.brushes[i];
        let sides = &c.brush_sides[br.first_side as usize..(br.first_side + br.num_sides) as usize];
        opaque[i] = !sides.iter().any(|s| b.shaders.get(s.shader as usize).is_some_and(translucent));
    }
    opaque
}

/// The `q3_solids` record (see the module docs), or `None` when the map has no tree.
/// `scale` is metres per Quake unit.
pub fn q3map2_solids(b: &Bsp, scale: f64) -> Option<Value> {
    let c = &b.collision;
    if c.nodes.is_empty() || c.leafs.is_empty() {
        return None;
    }
    let opaque = opaque_brushes(b);
    // Planes and brushes are renumbered to the ones kept.
    let mut plane_of: HashMap<u32, usize> = HashMap::new();
    let mut planes: Vec<f64> = Vec::new();
    let mut plane = |p: u32| -> usize {
        *plane_of.entry(p).or_insert_with(|| {
            let (n, d) = c.planes[p as usize];
            let n = units::direction(n.map(|x| x as f64));
            planes.extend_from_slice(&[n[0], n[1], n[2], d as f64 * scale]);
            planes.len() / 4 - 1
        })
    };
    let mut nodes = Vec::with_capacity(c.nodes.len() * 3);
    for n in &c.nodes {
        nodes.extend_from_slice(&[plane(n.plane) as i64, n.children[0] as i64, n.children[1] as i64]);
    }
    let mut brush_of: HashMap<u32, usize> = HashMap::new();
    let (mut brushes, mut brush_planes, mut leaf_brushes, mut leafs) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for l in &c.leafs {
        let solid = l.cluster < 0;
        let first = leaf_brushes.len();
        if !solid {
            for &bi in &c.leaf_brushes[l.first_brush as usize..(l.first_brush + l.num_brushes) as usize] {
                if !opaque[bi as usize] {
                    continue;
                }
                let k = *brush_of.entry(bi).or_insert_with(|| {
                    let br = &c.brushes[bi as usize];
                    brushes.extend_from_slice(&[brush_planes.len(), br.num_sides as usize]);
                    for s in &c.brush_sides[br.first_side as usize..(br.first_side + br.num_sides) as usize] {
                        brush_planes.push(plane(s.plane));
                    }
                    brushes.len() / 2 - 1
                });
                leaf_brushes.push(k);
            }
        }
        leafs.extend_from_slice(&[solid as usize, first, leaf_brushes.len() - first]);
    }
    Some(json!({
        "planes": planes,
        "nodes": nodes,
        "leafs": leafs,
        "leaf_brushes": leaf_brushes,
        "brushes": brushes,
        "brush_planes": brush_planes,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsp::{Brush, BrushSide, Collision, Format, Leaf, Model, Node, OtherCounts, ShaderRef};

    /// A world split by the plane z = 0 (up: open leaf 0, down: solid leaf 1), with a
    /// caulk box and a clip box in the open leaf.
    fn world() -> Bsp {
        let shader = |name: &str, content_flags| ShaderRef { name: name.into(), surface_flags: 0, content_flags };
        let mut planes = vec![([0.0, 0.0, 1.0], 0.0)];
        let mut sides = Vec::new();
        let mut brushes = Vec::new();
        for (k, shader) in [0u32, 1].into_iter().enumerate() {
            // Box 0..8 in x, y and z + 16 k.
            let first = sides.len() as u32;
            let lo = 16.0 * k as f32;
            for (n, d) in [([1.0, 0.0, 0.0], 8.0), ([-1.0, 0.0, 0.0], 0.0), ([0.0, 1.0, 0.0], 8.0), ([0.0, -1.0, 0.0], 0.0), ([0.0, 0.0, 1.0], lo + 8.0), ([0.0, 0.0, -1.0], -lo)] {
                planes.push((n, d));
                sides.push(BrushSide { plane: planes.len() as u32 - 1, shader });
            }
            brushes.push(Brush { first_side: first, num_sides: 6, shader });
        }
        Bsp {
            format: Format::Ibsp(46),
            entities: String::new(),
            shaders: vec![shader("textures/common/caulk", 1), shader("textures/common/clip", bsp::contents::PLAYERCLIP)],
            models: vec![Model { mins: [0.0; 3], maxs: [1.0; 3], first_surface: 0, num_surfaces: 0, first_brush: 0, num_brushes: 2 }],
            verts: vec![],
            indices: vec![],
            surfaces: vec![],
            lightmaps: vec![],
            collision: Collision {
                planes,
                nodes: vec![Node { plane: 0, children: [-1, -2] }],
                leafs: vec![Leaf { cluster: 0, first_brush: 0, num_brushes: 2 }, Leaf { cluster: -1, first_brush: 0, num_brushes: 0 }],
                leaf_brushes: vec![0, 1],
                brushes,
                brush_sides: sides,
                error: None,
            },
            other: OtherCounts::default(),
        }
    }

    #[test]
    fn clips_are_not_opaque_caulk_is() {
        assert_eq!(opaque_brushes(&world()), vec![true, false]);
    }

    #[test]
    fn the_record_keeps_the_tree_and_the_open_leaves_opaque_brushes_in_gltf_axes() {
        let v = q3map2_solids(&world(), 0.5).unwrap();
        let nums = |k: &str| v[k].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect::<Vec<_>>();
        // The root plane z = 0 is glTF's y = 0.
        assert_eq!(&nums("planes")[..4], &[0.0, 1.0, 0.0, 0.0]);
        assert_eq!(nums("nodes"), vec![0.0, -1.0, -2.0]);
        assert_eq!(nums("leafs"), vec![0.0, 0.0, 1.0, 1.0, 1.0, 0.0]);
        assert_eq!(nums("leaf_brushes"), vec![0.0]);
        assert_eq!(nums("brushes"), vec![0.0, 6.0]);
        // The caulk box's x = 8 side: glTF x = 4 m at scale 0.5; its y = 8 side is glTF's
        // z = -4 m (normal -z).
        let planes = nums("planes");
        let side = |k: usize| planes[4 * nums("brush_planes")[k] as usize..][..4].to_vec();
        assert_eq!(side(0), vec![1.0, 0.0, 0.0, 4.0]);
        assert_eq!(side(2), vec![0.0, 0.0, -1.0, 4.0]);
    }

    #[test]
    fn no_tree_no_record() {
        let mut b = world();
        b.collision = Collision::default();
        assert!(q3map2_solids(&b, 1.0).is_none());
    }
}
