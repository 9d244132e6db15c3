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
//! - The packet walk ([`Wide::find_packet`]) takes up to [`PACKET`] segments of the
//!   shadow view at once: rows next to each other towards one light cross mostly the same
//!   boxes, so one walk loads each node once for all of them. Each ray is still tested
//!   against each box on its own, as [`Wide::find`] tests it, so its answer is its own
//!   walk's. Its test is the same slab test with SSE's plain minimum and maximum where no
//!   NaN can arise ([`Node4::crossed_finite`]); `f32::min` and `f32::max` step over NaNs
//!   at the cost of a few instructions each, which, for one ray at a time, measured no
//!   faster (its walk waits on memory), but shared over a packet's rays paid.
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

    /// [`Node4::crossed`] as a mask (bit `l`: lane `l`), where [`slab_numbers_finite`]
    /// holds: the same answer with plain comparisons for the minima and maxima, one
    /// vector instruction each where `f32::min`/`f32::max` take several to pass over a
    /// NaN. With `o` finite and `inv` finite and not zero, no slab product is a NaN: a
    /// box's corner is finite, or infinite in an empty slot, and `(corner - o) * inv` is
    /// then a number or an infinity. `near` starts at 0 and `far` at `t_max` (a NaN there
    /// is dropped by the first minimum either way: `a < b` is false, and `f32::min`
    /// passes over it). Without NaNs the two kinds of minimum and maximum differ at most
    /// in the sign of a zero, which no comparison after them sees.
    #[inline(always)]
    fn crossed_finite(&self, o: [f32; 3], inv: [f32; 3], t_max: f32) -> u32 {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::*;
            // SAFETY: SSE is part of x86_64's baseline; the loads read the node's own
            // arrays of four.
            let outside = unsafe {
                let mut near = _mm_setzero_ps();
                let mut far = _mm_set1_ps(t_max);
                for a in 0..3 {
                    let (oa, ia) = (_mm_set1_ps(o[a]), _mm_set1_ps(inv[a]));
                    let t0 = _mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(self.lo[a].as_ptr()), oa), ia);
                    let t1 = _mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(self.hi[a].as_ptr()), oa), ia);
                    // `_mm_max_ps(x, y)` is `x > y ? x : y`, `_mm_min_ps` `x < y ? x : y`.
                    near = _mm_max_ps(near, _mm_min_ps(t0, t1));
                    far = _mm_min_ps(far, _mm_max_ps(t0, t1));
                }
                _mm_movemask_ps(_mm_cmpgt_ps(near, far)) as u32
            };
            self.live() & !outside
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            lane_mask(self.crossed(o, inv, t_max))
        }
    }

    /// The lanes that hold a child, as a mask.
    #[inline(always)]
    fn live(&self) -> u32 {
        lane_mask(self.child.map(|c| c != EMPTY))
    }
}

/// Four lanes' answers as a mask (bit `l`: lane `l`).
#[inline(always)]
fn lane_mask(lanes: [bool; 4]) -> u32 {
    (0..4).filter(|&l| lanes[l]).fold(0, |m, l| m | 1 << l)
}

/// The first triangle of binary leaf `leaf` that `hit` takes (given its index into
/// `tris`), as `(leaf, index into tris)`.
#[inline(always)]
fn leaf_hit(nodes: &[Node], tris: &[Tri], leaf: u32, hit: impl Fn(usize, &Tri) -> bool) -> Option<(u32, u32)> {
    let node = &nodes[leaf as usize];
    let first = node.right_or_first as usize;
    (first..first + node.count as usize).find(|&k| hit(k, &tris[k])).map(|k| (leaf, k as u32))
}

/// Whether a segment's slab products can be taken without NaNs
/// ([`Node4::crossed_finite`]): `o` finite, each `1 / d` finite and not zero.
#[inline]
fn slab_numbers_finite(o: [f32; 3], inv: [f32; 3]) -> bool {
    o.iter().all(|v| v.is_finite()) && inv.iter().all(|v| v.is_finite() && *v != 0.0)
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
                    if let Some(found) = leaf_hit(nodes, tris, c & !LEAF, |k, tri| hit(k, tri)) {
                        return Some(found);
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

/// Most segments [`Wide::find_packet`] walks together.
pub const PACKET: usize = 8;
const _: () = assert!(PACKET <= 32, "a packet's rays are the bits of a u32");

impl Wide {
    /// [`Wide::find`] for up to [`PACKET`] segments at once (`o[r] + s d[r]`, `s` in
    /// `[0, t_max[r]]`, for the rays `r` whose bit `active` sets): one walk over the
    /// nodes any of them crosses, each node loaded once for all of them, each ray tested
    /// against each box as [`Wide::find`] tests it, so each ray reaches exactly the leaves
    /// its own walk reaches and gets its answer (a ray leaves the packet at its first
    /// hit). `hit(r, k, tri)`: ray `r`'s own test of triangle `k`. Returns each ray's
    /// `(binary leaf, index into tris)`, `None` for a ray nothing stopped (or not active).
    #[inline]
    pub fn find_packet(&self, nodes: &[Node], tris: &[Tri], o: &[Vec3; PACKET], d: &[Vec3; PACKET], t_max: &[f32; PACKET], mut active: u32, hit: impl Fn(usize, usize, &Tri) -> bool) -> [Option<(u32, u32)>; PACKET] {
        let mut out = [None; PACKET];
        active &= (1 << PACKET) - 1;
        if tris.is_empty() || self.nodes.is_empty() {
            return out;
        }
        let o = o.map(|v| v.to_array());
        let inv = d.map(|d| d.recip().to_array());
        let finite = (0..PACKET).filter(|&r| slab_numbers_finite(o[r], inv[r])).fold(0u32, |m, r| m | 1 << r);
        // Per node visited: the rays that crossed its box, as a mask.
        let mut stack = [(0u32, 0u32); STACK];
        stack[0] = (0, active);
        let mut len = 1;
        while len > 0 && active != 0 {
            len -= 1;
            let (c, mask) = stack[len];
            let n = &self.nodes[c as usize];
            // Per lane, the rays that cross its box.
            let mut lanes = [0u32; 4];
            let mut rays = mask & active;
            while rays != 0 {
                let r = rays.trailing_zeros() as usize;
                rays &= rays - 1;
                let crossed = if finite >> r & 1 == 1 {
                    n.crossed_finite(o[r], inv[r], t_max[r])
                } else {
                    lane_mask(n.crossed(o[r], inv[r], t_max[r]))
                };
                for l in 0..4 {
                    lanes[l] |= (crossed >> l & 1) << r;
                }
            }
            for l in 0..4 {
                if lanes[l] == 0 {
                    continue;
                }
                let c = n.child[l];
                if c & LEAF != 0 {
                    let mut rays = lanes[l] & active;
                    while rays != 0 {
                        let r = rays.trailing_zeros() as usize;
                        rays &= rays - 1;
                        if let Some(found) = leaf_hit(nodes, tris, c & !LEAF, |k, tri| hit(r, k, tri)) {
                            out[r] = Some(found);
                            active &= !(1 << r);
                        }
                    }
                } else {
                    debug_assert!(len < STACK);
                    if len < STACK {
                        stack[len] = (c, lanes[l]);
                        len += 1;
                    }
                }
            }
        }
        out
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

    /// Segments walked together answer each as its own walk does: packets of the room's
    /// segments with some rays left out, rays along the axes (`1 / d` infinite) and from a
    /// wall's plane among them, on the plain and the grown tree; each ray's occluder is in
    /// the leaf it names and takes the ray.
    #[test]
    fn a_packet_walk_answers_as_one_walk_per_segment() {
        let (mut mesh, _) = crate::testutil::room(4);
        crate::testutil::scatter_quads(&mut mesh, 300);
        let at = |k: u32, s: u32| -0.5 + 5.0 * hash01(k, s);
        let (bvh, grown) = (Tree::build(&mesh), Tree::build_grown(&mesh, 0.03));
        let (mut blocked, mut open, mut left_out) = (0, 0, 0);
        for k in 0..4_000u32 {
            let mut o = [Vec3::ZERO; PACKET];
            let mut d = [Vec3::ZERO; PACKET];
            let mut t_max = [0.0f32; PACKET];
            // Segments from a small patch towards one point, as a light's rows are, or
            // scattered.
            let target = Vec3::new(at(k, 1), at(k, 2), at(k, 3));
            for r in 0..PACKET {
                let j = k * PACKET as u32 + r as u32;
                o[r] = if k % 2 == 0 { Vec3::new(at(k, 4), at(k, 5), at(k, 6)) + 0.05 * Vec3::new(hash01(j, 7), hash01(j, 8), hash01(j, 9)) } else { Vec3::new(at(j, 11), at(j, 12), at(j, 13)) };
                d[r] = if k % 2 == 0 { target - o[r] } else { Vec3::new(at(j, 14), at(j, 15), at(j, 16)) - o[r] };
                match j % 11 {
                    0 => d[r].x = 0.0,
                    1 => d[r] = Vec3::new(0.0, d[r].y, 0.0),
                    2 => o[r].x = 0.0,
                    _ => {}
                }
                t_max[r] = if j % 3 == 0 { 1.0 } else { 1.0 - 1e-4 };
            }
            let active = (hash01(k, 20) * (1u32 << PACKET) as f32) as u32 | 1;
            for tree in [&bvh, &grown] {
                let hit = |r: usize, tri: &Tri| intersect(tri, o[r], d[r], EDGE_SLACK).is_some_and(|t| t > 1e-4 && t < t_max[r]);
                let found = tree.wide.find_packet(&tree.nodes, &tree.tris, &o, &d, &t_max, active, |r, _, tri| hit(r, tri));
                for r in 0..PACKET {
                    if active >> r & 1 == 0 {
                        assert!(found[r].is_none(), "packet {k}, ray {r} left out");
                        left_out += 1;
                        continue;
                    }
                    let one = tree.find_leaf_tri(o[r], d[r], t_max[r], |_, tri| hit(r, tri));
                    assert_eq!(found[r].is_some(), one.is_some(), "packet {k}, ray {r}");
                    if let Some((leaf, t)) = found[r] {
                        let n = &tree.nodes[leaf as usize];
                        assert!(n.count > 0 && (n.right_or_first..n.right_or_first + n.count).contains(&t) && hit(r, &tree.tris[t as usize]));
                    }
                    blocked += one.is_some() as usize;
                    open += one.is_none() as usize;
                }
            }
        }
        assert!(blocked > 5000 && open > 5000 && left_out > 5000, "{blocked} blocked, {open} open, {left_out} left out");
    }

    /// The slab test without NaN guards answers as the guarded one wherever it is taken:
    /// boxes with empty slots, origins on their faces and corners, directions from tiny to
    /// huge (`1 / d` near the ends of f32's range), bounds from 0 to infinity and NaN.
    #[test]
    fn the_unguarded_slab_test_answers_as_the_guarded_one() {
        let (mut same, mut crossed) = (0usize, 0usize);
        let pick = |k: u32, s: u32, lo: f32, hi: f32| lo + (hi - lo) * hash01(k, s);
        for k in 0..200_000u32 {
            let mut node = Node4 { lo: [[f32::INFINITY; 4]; 3], hi: [[f32::NEG_INFINITY; 4]; 3], child: [EMPTY; 4] };
            for l in 0..4 {
                if hash01(k, 40 + l as u32) < 0.2 {
                    continue;
                }
                for a in 0..3 {
                    let (p, q) = (pick(k, 50 + 3 * l as u32 + a as u32, -2.0, 2.0), pick(k, 70 + 3 * l as u32 + a as u32, -2.0, 2.0));
                    (node.lo[a][l], node.hi[a][l]) = (p.min(q), p.max(q));
                }
                node.child[l] = l as u32;
            }
            let mut o = [0, 1, 2].map(|a| pick(k, 90 + a as u32, -3.0, 3.0));
            // On a face or a corner of a lane's box.
            if k % 3 == 0 {
                let l = (k / 3 % 4) as usize;
                for a in 0..3 {
                    if hash01(k, 95 + a as u32) < 0.5 {
                        o[a] = if hash01(k, 98 + a as u32) < 0.5 { node.lo[a][l] } else { node.hi[a][l] };
                    }
                }
            }
            let d = [0, 1, 2].map(|a| {
                let scale = [1e-30f32, 1e-6, 1.0, 1e6, 1e30][(hash01(k, 100 + a as u32) * 5.0) as usize % 5];
                pick(k, 110 + a as u32, -1.0, 1.0) * scale
            });
            let inv = d.map(f32::recip);
            if !slab_numbers_finite(o, inv) {
                continue;
            }
            let t_max = [0.0, 0.5, 1.0, 1e30, f32::INFINITY, f32::NAN][k as usize % 6];
            let fast = node.crossed_finite(o, inv, t_max);
            let guarded = node.crossed(o, inv, t_max);
            assert_eq!(fast, lane_mask(guarded), "segment {k}");
            same += 1;
            crossed += fast.count_ones() as usize;
        }
        assert!(same > 100_000 && crossed > 20_000 && crossed < 4 * same - 20_000, "{same} segments, {crossed} lanes crossed");
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
