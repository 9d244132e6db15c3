//! Four-wide views of a [`Tree`](crate::trace::tree::Tree) for the CPU's walks: the binary
//! tree collapsed so that one node holds the boxes of up to four subtrees, laid out lane
//! by lane, and one visit tests all four against the segment (the compiler turns the lane
//! loop into vector instructions). The binary tree stays what the WGSL walks use; these
//! views only change how fast the CPU finds an occluder or a first hit.
//!
//! - The shadow view ([`Wide::new`]) holds the boxes grown as the shadow walks grow them
//!   ([`shadow_box`]). Its answer is the binary walk's, bit for bit. Both reach exactly
//!   the triangles whose leaf box the segment crosses: a box that passes the slab test
//!   has every box around it pass too (the slab bounds are monotone in the corners, in
//!   f32 as in the reals, and a parent's grown box holds its children's), so skipping
//!   the inner levels of the binary tree culls nothing more or less. The boxes here are
//!   the binary tree's own, grown once when the view is built, with the same f32
//!   operations the binary walk does per visit.
//! - The exact view ([`Wide::exact`]) holds the binary tree's boxes as they are, each
//!   node's lanes in the binary tree's depth-first order, for the first-hit walk
//!   ([`Wide::first_hit`]). It visits the leaves in the binary walk's order and tests each
//!   leaf's own box again, with the binary slab test, at the distance found so far, before
//!   its triangles: so it tests the same triangles against the same bound as the binary
//!   walk, and names the same hit (a tie at a shared edge included), bit for bit. A lane
//!   tested earlier, at a larger bound, only skips what the binary walk would skip (the
//!   bound only falls, and the slab bounds are monotone in it as in the corners). That
//!   holds where `1 / d` is finite; elsewhere `0 x inf` on a box's face gives a NaN that
//!   the binary test's glam comparisons keep or drop by position, and
//!   [`Tree`](crate::trace::tree::Tree) walks the binary tree instead.
//!
//! Measured on oa_dm1's relit lights (87 lights, 326k shadow rays, one thread, 2-core
//! Xeon): q3map2's 65,666 pieces 1.32 -> 2.34 M rays/s, the same 239,827 rays stopped.

use glam::Vec3;

use crate::trace::layout::{Node, Tri, EDGE_SLACK, MAX_DEPTH};

/// A child slot that is a leaf of the binary tree: the low bits are that leaf's index
/// in [`crate::trace::tree::Tree::nodes`] (so a walk's answer names the same leaf).
const LEAF: u32 = 1 << 31;
/// An empty child slot (its box is empty, so no segment crosses it).
const EMPTY: u32 = u32::MAX;
/// Deepest stack a walk needs: a visit pops one node and pushes at most four, and the
/// view is no deeper than the binary tree ([`MAX_DEPTH`]).
const STACK: usize = 3 * MAX_DEPTH + 1;

#[derive(Debug, Clone, Copy)]
struct Node4 {
    /// Per axis, per lane: the child's grown box.
    lo: [[f32; 4]; 3],
    hi: [[f32; 4]; 3],
    /// Per lane: a node of this view, `LEAF | binary leaf`, or `EMPTY`.
    child: [u32; 4],
}

impl Node4 {
    /// Per lane: whether the segment from `o` (`inv`: `1 / d`), `s` in `[0, t_max]`,
    /// crosses the lane's box, an empty slot never. The slab test of `slab_box` in
    /// `tree.rs`, four lanes at once; NaN (0 * inf on a slab face) compares false: crossed.
    #[inline]
    fn crossed(&self, o: [f32; 3], inv: [f32; 3], t_max: f32) -> [bool; 4] {
        let mut near = [0.0f32; 4];
        let mut far = [t_max; 4];
        for a in 0..3 {
            for l in 0..4 {
                let t0 = (self.lo[a][l] - o[a]) * inv[a];
                let t1 = (self.hi[a][l] - o[a]) * inv[a];
                near[l] = near[l].max(t0.min(t1));
                far[l] = far[l].min(t0.max(t1));
            }
        }
        [0, 1, 2, 3].map(|l| self.child[l] != EMPTY && !(near[l] > far[l]))
    }
}

#[derive(Debug, Clone, Default)]
pub struct Wide {
    nodes: Vec<Node4>,
}

/// A node's box as the shadow walks test it: grown by twice [`EDGE_SLACK`] of its
/// largest side (why: [`crate::trace::tree`]'s module docs and [`EDGE_SLACK`]).
pub fn shadow_box(node: &Node) -> (Vec3, Vec3) {
    let (lo, hi) = (Vec3::from(node.min), Vec3::from(node.max));
    let pad = Vec3::splat(2.0 * EDGE_SLACK * (hi - lo).max_element().max(0.0));
    (lo - pad, hi + pad)
}

/// Surface area of a node's box, half of it (what the collapse compares).
fn half_area(n: &Node) -> f32 {
    let e = Vec3::from(n.max) - Vec3::from(n.min);
    e.x * e.y + e.y * e.z + e.z * e.x
}

impl Wide {
    /// The view of the binary tree `nodes` (depth-first, left child next, as
    /// [`crate::trace::tree`] lays it out). Each node of the view takes its binary node's
    /// children and opens the largest inner one among them until it holds four. A tree
    /// over no triangles (`triangles == 0`: one empty placeholder node) has an empty view.
    pub fn new(nodes: &[Node], triangles: usize) -> Wide {
        Wide::collapsed(nodes, triangles, false)
    }

    /// The exact view: the binary tree's boxes as they are, each node's lanes in the
    /// binary tree's depth-first order (its nodes' order), for [`Wide::first_hit`].
    pub fn exact(nodes: &[Node], triangles: usize) -> Wide {
        Wide::collapsed(nodes, triangles, true)
    }

    fn collapsed(nodes: &[Node], triangles: usize, exact: bool) -> Wide {
        let mut w = Wide { nodes: Vec::with_capacity(nodes.len() / 3 + 1) };
        if !nodes.is_empty() && triangles > 0 {
            w.collapse(nodes, 0, exact);
        }
        w
    }

    fn collapse(&mut self, nodes: &[Node], root: u32, exact: bool) -> u32 {
        let me = self.nodes.len();
        self.nodes.push(Node4 { lo: [[f32::INFINITY; 4]; 3], hi: [[f32::NEG_INFINITY; 4]; 3], child: [EMPTY; 4] });
        let inner = |k: u32| nodes[k as usize].count == 0;
        let mut kids: Vec<u32> = if inner(root) { vec![root + 1, nodes[root as usize].right_or_first] } else { vec![root] };
        while kids.len() < 4 {
            let widest = kids.iter().enumerate().filter(|(_, &k)| inner(k)).max_by(|a, b| half_area(&nodes[*a.1 as usize]).total_cmp(&half_area(&nodes[*b.1 as usize])));
            let Some((i, &k)) = widest else { break };
            kids.swap_remove(i);
            kids.push(k + 1);
            kids.push(nodes[k as usize].right_or_first);
        }
        if exact {
            // The binary tree is laid out depth first: its nodes' order is its walk's.
            kids.sort_unstable();
        }
        for (lane, &k) in kids.iter().enumerate() {
            let node = &nodes[k as usize];
            let (lo, hi) = if exact { (Vec3::from(node.min), Vec3::from(node.max)) } else { shadow_box(node) };
            for a in 0..3 {
                self.nodes[me].lo[a][lane] = lo[a];
                self.nodes[me].hi[a][lane] = hi[a];
            }
            self.nodes[me].child[lane] = if inner(k) { self.collapse(nodes, k, exact) } else { LEAF | k };
        }
        me as u32
    }

    /// The nearest hit along `o + s d` with `s` in `(0, t_max)`: `hit` gives a triangle's
    /// `s` where it counts below the bound it is given (the caller's hit test, its `t_min`
    /// and its filter), `leaf`
    /// says whether a binary leaf's box is crossed up to a bound. Returns `(s, index into
    /// tris)`. On the exact view ([`Wide::exact`]), with `leaf` the binary walk's slab
    /// test and a `d` whose `1 / d` is finite, the binary walk's answer to the bit (module
    /// docs). Among hits at the same `s`, the first in the tree's order.
    #[inline]
    pub fn first_hit(&self, nodes: &[Node], tris: &[Tri], o: Vec3, d: Vec3, t_max: f32, leaf: impl Fn(&Node, f32) -> bool, hit: impl Fn(&Tri, f32) -> Option<f32>) -> Option<(f32, usize)> {
        if tris.is_empty() || self.nodes.is_empty() {
            return None;
        }
        let (o, inv) = (o.to_array(), d.recip().to_array());
        let mut best: Option<(f32, usize)> = None;
        let mut limit = t_max;
        // Wide nodes and binary leaves (`LEAF | leaf`), the next to visit on top.
        let mut stack = [0u32; STACK];
        let mut len = 1;
        while len > 0 {
            len -= 1;
            let c = stack[len];
            if c & LEAF != 0 {
                let node = &nodes[(c & !LEAF) as usize];
                // The binary walk's own test of this leaf, at the bound it would have here.
                if !leaf(node, limit) {
                    continue;
                }
                let first = node.right_or_first as usize;
                for (k, tri) in tris[first..first + node.count as usize].iter().enumerate() {
                    if let Some(t) = hit(tri, limit) {
                        limit = t;
                        best = Some((t, first + k));
                    }
                }
                continue;
            }
            let n = &self.nodes[c as usize];
            let crossed = n.crossed(o, inv, limit);
            // Pushed last lane first, so that the first lane is walked first.
            for l in (0..4).rev() {
                if !crossed[l] {
                    continue;
                }
                debug_assert!(len < STACK);
                if len < STACK {
                    stack[len] = n.child[l];
                    len += 1;
                }
            }
        }
        best
    }

    /// The shadow walk over the boxes the segment `o + s d`, `s` in `[0, t_max]`, crosses:
    /// the first triangle `hit` takes (given its index into `tris`), as `(binary leaf,
    /// index into tris)`. Any hit answers, so the order of the walk does not change the
    /// answer, only which occluder it names.
    #[inline]
    pub fn find(&self, nodes: &[Node], tris: &[Tri], o: Vec3, d: Vec3, t_max: f32, hit: impl Fn(usize, &Tri) -> bool) -> Option<(u32, u32)> {
        if tris.is_empty() || self.nodes.is_empty() {
            return None;
        }
        let (o, inv) = (o.to_array(), d.recip().to_array());
        let mut stack = [0u32; STACK];
        let mut len = 1;
        while len > 0 {
            len -= 1;
            let n = &self.nodes[stack[len] as usize];
            let crossed = n.crossed(o, inv, t_max);
            for l in 0..4 {
                if !crossed[l] {
                    continue;
                }
                let c = n.child[l];
                if c & LEAF != 0 {
                    let leaf = c & !LEAF;
                    let node = &nodes[leaf as usize];
                    let first = node.right_or_first as usize;
                    if let Some(k) = (first..first + node.count as usize).find(|&k| hit(k, &tris[k])) {
                        return Some((leaf, k as u32));
                    }
                } else {
                    debug_assert!(len < STACK);
                    if len < STACK {
                        stack[len] = c;
                        len += 1;
                    }
                }
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::bounce::hash01;
    use crate::trace::tree::{intersect, slab_box, Tree};

    /// The binary walk, written as the reference: recursion over the binary tree, each
    /// box tested as the shadow walks grow it.
    fn binary(bvh: &Tree, node: u32, o: Vec3, d: Vec3, t_max: f32, hit: &dyn Fn(&Tri) -> bool) -> bool {
        let n = &bvh.nodes[node as usize];
        let (lo, hi) = shadow_box(n);
        if !slab_box(lo, hi, o, d.recip(), t_max) {
            return false;
        }
        if n.count > 0 {
            let first = n.right_or_first as usize;
            return bvh.tris[first..first + n.count as usize].iter().any(hit);
        }
        binary(bvh, node + 1, o, d, t_max, hit) || binary(bvh, n.right_or_first, o, d, t_max, hit)
    }

    /// The four-wide walk answers as the binary one, segment by segment: a room and 300
    /// quads in it, axis-aligned ones among them (their edges are their boxes' faces),
    /// segments in every direction and along the axes (slab products 0 * inf), segments
    /// that end on a wall and that start on one.
    #[test]
    fn the_wide_walk_answers_as_the_binary_walk() {
        let (mut mesh, _) = crate::testutil::room(4);
        crate::testutil::scatter_quads(&mut mesh, 300);
        let at = |k: u32, s: u32| -0.5 + 5.0 * hash01(k, s);
        let bvh = Tree::build(&mesh);
        assert!(bvh.nodes.len() > 100, "a tree of some depth");
        let grown = Tree::build_grown(&mesh, 0.03);
        let (mut blocked, mut open) = (0, 0);
        for k in 0..20_000u32 {
            let o = Vec3::new(at(k, 11), at(k, 12), at(k, 13));
            let mut d = Vec3::new(at(k, 14), at(k, 15), at(k, 16)) - o;
            match k % 5 {
                0 => d.x = 0.0,
                1 => d = Vec3::new(0.0, d.y, 0.0),
                _ => {}
            }
            let o = if k % 7 == 0 { Vec3::new(0.0, o.y, o.z) } else { o };
            let (t_min, t_max) = (1e-4, if k % 3 == 0 { 1.0 } else { 1.0 - 1e-4 });
            for tree in [&bvh, &grown] {
                let hit = |tri: &Tri| intersect(tri, o, d, EDGE_SLACK).is_some_and(|t| t > t_min && t < t_max);
                let wide = tree.find_leaf_tri(o, d, t_max, |_, tri| hit(tri));
                let reference = binary(tree, 0, o, d, t_max, &hit);
                assert_eq!(wide.is_some(), reference, "segment {k}");
                // The occluder it names is one the walk reaches, in the leaf it names.
                if let Some((leaf, t)) = wide {
                    let n = &tree.nodes[leaf as usize];
                    assert!(n.count > 0 && (n.right_or_first..n.right_or_first + n.count).contains(&t));
                }
                blocked += reference as usize;
                open += !reference as usize;
            }
        }
        assert!(blocked > 5000 && open > 5000, "both answers exercised: {blocked} blocked, {open} open");
    }

    /// The binary first-hit walk, written as the reference: the stack walk
    /// `first_hit_where` did before the exact view, left child first, each node's exact
    /// box tested at the distance found so far.
    fn binary_first(bvh: &Tree, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> Option<(f32, usize)> {
        let inv = d.recip();
        let (mut best, mut limit) = (None, t_max);
        let mut stack = vec![0u32];
        while let Some(i) = stack.pop() {
            let node = &bvh.nodes[i as usize];
            if !slab_box(Vec3::from(node.min), Vec3::from(node.max), o, inv, limit) {
                continue;
            }
            if node.count > 0 {
                let first = node.right_or_first as usize;
                for (k, tri) in bvh.tris[first..first + node.count as usize].iter().enumerate() {
                    if let Some(t) = intersect(tri, o, d, 0.0) {
                        if t > t_min && t < limit {
                            limit = t;
                            best = Some((t, first + k));
                        }
                    }
                }
            } else {
                stack.push(node.right_or_first);
                stack.push(i + 1);
            }
        }
        best
    }

    /// The exact view's first hit is the binary walk's, distance and triangle, bit for bit:
    /// the room and its 300 quads, every triangle six times (a map's doubled faces: exact
    /// ties, more than a leaf holds, which the tree's order settles), rays from inside in every direction and along the
    /// axes, rays from a wall's plane, rays that end short of everything.
    #[test]
    fn the_wide_first_hit_is_the_binary_walks() {
        let (mut mesh, _) = crate::testutil::room(4);
        crate::testutil::scatter_quads(&mut mesh, 300);
        let once = mesh.triangles.len();
        for _ in 0..5 {
            for t in 0..once {
                mesh.triangles.push(mesh.triangles[t]);
                mesh.tri_material.push(mesh.tri_material[t]);
                mesh.tri_source.push(mesh.tri_source[t]);
            }
        }
        let at = |k: u32, s: u32| -0.5 + 5.0 * hash01(k, s);
        let bvh = Tree::build(&mesh);
        let (mut hits, mut misses) = (0, 0);
        for k in 0..20_000u32 {
            let o = Vec3::new(at(k, 21), at(k, 22), at(k, 23));
            let mut d = Vec3::new(at(k, 24), at(k, 25), at(k, 26)) - o;
            match k % 5 {
                0 => d.x = 0.0,
                1 => d = Vec3::new(0.0, 0.0, d.z),
                _ => {}
            }
            let o = if k % 7 == 0 { Vec3::new(0.0, o.y, o.z) } else { o };
            let (t_min, t_max) = (if k % 2 == 0 { 0.0 } else { 1e-4 }, if k % 3 == 0 { 0.5 } else { 4.0 });
            let wide = if d.recip().is_finite() { bvh.wide_exact.first_hit(&bvh.nodes, &bvh.tris, o, d, t_max, |n, limit| slab_box(Vec3::from(n.min), Vec3::from(n.max), o, d.recip(), limit), |tri, limit| intersect(tri, o, d, 0.0).filter(|&t| t > t_min && t < limit)) } else { bvh.first_hit_after(o, d, t_min, t_max).map(|h| (h.0, bvh.tri_index.iter().position(|&t| t == h.1).unwrap())) };
            let reference = binary_first(&bvh, o, d, t_min, t_max);
            assert_eq!(wide.map(|h| (h.0.to_bits(), h.1)), reference.map(|h| (h.0.to_bits(), h.1)), "ray {k}");
            hits += reference.is_some() as usize;
            misses += reference.is_none() as usize;
        }
        assert!(hits > 5000 && misses > 2000, "both answers exercised: {hits} hits, {misses} misses");
    }

    /// A tree that is one leaf (a single quad) and an empty one.
    #[test]
    fn a_leaf_alone_and_no_tree_at_all() {
        let mut mesh = crate::testutil::room(2).0;
        mesh.triangles.clear();
        mesh.tri_material.clear();
        mesh.tri_source.clear();
        let empty = Tree::build(&mesh);
        assert!(empty.find_leaf_tri(Vec3::ZERO, Vec3::ONE, 1.0, |_, _| true).is_none());
        crate::testutil::push_quad(&mut mesh, [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.0, 1.0, 1.0]], Vec3::NEG_Z);
        let one = Tree::build(&mesh);
        assert_eq!(one.nodes.len(), 1);
        assert_eq!(one.find_leaf_tri(Vec3::new(0.5, 0.3, 0.0), Vec3::Z * 2.0, 1.0, |_, _| true).map(|h| h.0), Some(0));
        assert!(one.find_leaf_tri(Vec3::new(1.5, 0.3, 0.0), Vec3::Z * 2.0, 1.0, |_, _| true).is_none());
    }
}
