//! A bounding volume hierarchy over triangles, built once on the CPU (binned SAH) and
//! flattened in depth-first order so the same arrays serve the CPU traversal here and the
//! WGSL traversal in `shaders/bvh.wgsl`. The scene's occluders ([`crate::trace::bvh::Bvh`])
//! are one over the mesh's casting triangles, and q3map2's pieces
//! ([`crate::trace::pieces::Shadow`]) are one over the pieces.
//!
//! Layout: an interior node's left child is the next node; `right_or_first` is its right
//! child; a leaf (`count > 0`) holds triangles `right_or_first .. right_or_first + count`
//! of [`Tree::tris`], each stored as `(v0, e1 = v1 - v0, e2 = v2 - v0)` for Moeller-Trumbore.
//! The shadow walks grow a node's box by twice [`EDGE_SLACK`] of its largest side, so
//! their slack holds where a triangle's edge is the box's face.
//!
//! The first-hit test is exact; shadow rays take [`EDGE_SLACK`], a hair. (q3map2 clips
//! every triangle into its BSP leaves and tests the pieces with a 1% barycentric slack;
//! taking that slack on whole triangles instead made the sun fixture worse, 0.0645
//! against 0.0000 relative error: a test of ours that matches q3map2's pieces is not
//! worth their reconstruction.)

use glam::Vec3;

use crate::scene::Mesh;
pub use crate::trace::layout::{Node, Tri, EDGE_SLACK, MAX_DEPTH};

#[derive(Debug, Clone)]
pub struct Tree {
    pub nodes: Vec<Node>,
    pub tris: Vec<Tri>,
    /// Original triangle index of each entry of `tris`.
    pub tri_index: Vec<u32>,
    /// The four-wide view of `nodes` the CPU's shadow walks take
    /// ([`crate::trace::wide`]; the same answers, faster).
    pub wide: crate::trace::wide::Wide,
    /// The four-wide view of `nodes` with their exact boxes, for the CPU's first-hit
    /// walks ([`crate::trace::wide::Wide::first_hit`]; the binary walk's hits, faster).
    pub wide_exact: crate::trace::wide::Wide,
}

const LEAF_SIZE: usize = 4;
const BINS: usize = 12;

#[derive(Clone, Copy)]
struct Aabb {
    lo: Vec3,
    hi: Vec3,
}
impl Aabb {
    const EMPTY: Aabb = Aabb { lo: Vec3::splat(f32::INFINITY), hi: Vec3::splat(f32::NEG_INFINITY) };
    fn grow(&mut self, p: Vec3) {
        self.lo = self.lo.min(p);
        self.hi = self.hi.max(p);
    }
    fn merge(&mut self, o: &Aabb) {
        self.lo = self.lo.min(o.lo);
        self.hi = self.hi.max(o.hi);
    }
    fn area(&self) -> f32 {
        let d = (self.hi - self.lo).max(Vec3::ZERO);
        d.x * d.y + d.y * d.z + d.z * d.x
    }
}

/// The occluder a shadow ray met last, for [`Tree::occluded_after`] (none at first).
#[derive(Debug, Clone, Copy, Default)]
pub struct Occluder(pub(crate) Option<(u32, u32)>);

impl Occluder {
    /// In eight bytes (`u64::MAX`: none), for the many kept per row
    /// ([`crate::trace::visibility::RecentOccluders`]).
    pub fn packed(self) -> u64 {
        self.0.map_or(u64::MAX, |(leaf, k)| (leaf as u64) << 32 | k as u64)
    }

    pub fn unpacked(bits: u64) -> Occluder {
        Occluder((bits != u64::MAX).then(|| ((bits >> 32) as u32, bits as u32)))
    }
}

/// How far behind its origin [`Tree::first_hit_from_plane`] starts a ray, m.
pub const START_BACK_M: f32 = 1e-4;

/// A ray of [`Tree::first_hit_from_plane`] as its walk takes it: from `o` (the caller's
/// origin pulled back by `back` m) along `d` (the direction times `reach`, the length plus
/// `back`), the parameter in `(0, 1)`; a face met from behind counts beyond `grace` only.
/// What a device's walk reads (`shaders/first_hits.wgsl`), set up once on the CPU.
#[derive(Debug, Clone, Copy)]
pub struct PlaneRay {
    pub o: Vec3,
    pub d: Vec3,
    pub grace: f32,
    pub reach: f32,
    pub back: f32,
}

impl PlaneRay {
    /// The ray from `o` along the unit `dir`, `length` m.
    pub fn new(o: Vec3, dir: Vec3, length: f32) -> PlaneRay {
        let back = START_BACK_M.max(o.abs().max_element() * 8.0 * f32::EPSILON);
        let reach = length + back;
        PlaneRay { o: o - dir * back, d: dir * reach, grace: 2.0 * back / reach, reach, back }
    }

    /// Whether the walk takes a hit on `tri` at parameter `t`.
    pub fn accepts(&self, tri: &Tri, t: f32) -> bool {
        t > self.grace || Vec3::from_slice(&tri.e1[..3]).cross(Vec3::from_slice(&tri.e2[..3])).dot(self.d) < 0.0
    }

    /// The distance from the caller's origin, m, of a hit at parameter `t`.
    pub fn distance(&self, t: f32) -> f32 {
        (t * self.reach - self.back).max(0.0)
    }
}

impl Tree {
    /// Builds over every non-degenerate triangle of the mesh, with exact hit tests.
    pub fn build(mesh: &Mesh) -> Tree {
        Tree::build_where(mesh, |_| true)
    }

    /// Builds over the non-degenerate triangles `t` with `keep(t)`.
    pub fn build_where(mesh: &Mesh, keep: impl Fn(usize) -> bool) -> Tree {
        Tree::build_padded(mesh, keep, 0.0, false)
    }

    /// Builds over every non-degenerate triangle, each one's box grown by `grow` times
    /// its largest side (room for a hit test with slack: q3map2's pieces,
    /// [`crate::trace::pieces::Shadow`]). Only shadow walks may use such a tree. Its
    /// splits weigh all three axes (the mesh's own tree keeps the longest axis: there a
    /// first hit's tie at a shared edge, and so the fit's path, depends on the tree; a
    /// shadow walk's any-hit answer does not).
    pub fn build_grown(mesh: &Mesh, grow: f32) -> Tree {
        Tree::build_padded(mesh, |_| true, grow, true)
    }

    fn build_padded(mesh: &Mesh, keep: impl Fn(usize) -> bool, grow: f32, three_axes: bool) -> Tree {
        let mut items: Vec<(u32, Aabb, Vec3)> = Vec::with_capacity(mesh.triangles.len());
        for (t, tri) in mesh.triangles.iter().enumerate() {
            if !keep(t) {
                continue;
            }
            let [a, b, c] = tri.map(|i| mesh.positions[i as usize]);
            if (b - a).cross(c - a).length_squared() <= 0.0 {
                continue;
            }
            let mut bb = Aabb::EMPTY;
            bb.grow(a);
            bb.grow(b);
            bb.grow(c);
            let pad = Vec3::splat(grow * (bb.hi - bb.lo).max_element());
            bb.lo -= pad;
            bb.hi += pad;
            items.push((t as u32, bb, (a + b + c) / 3.0));
        }
        let mut nodes = Vec::with_capacity(2 * items.len() / LEAF_SIZE + 1);
        let n = items.len();
        build_rec(&mut items[..], 0, &mut nodes, 0, three_axes);
        if n == 0 {
            nodes.clear();
            nodes.push(Node { min: [0.0; 3], right_or_first: 0, max: [0.0; 3], count: 0 });
        }
        let mut tris = Vec::with_capacity(n);
        let mut tri_index = Vec::with_capacity(n);
        for (t, _, _) in &items {
            let [a, b, c] = mesh.triangles[*t as usize].map(|i| mesh.positions[i as usize]);
            tris.push(Tri { v0: a.extend(0.0).to_array(), e1: (b - a).extend(0.0).to_array(), e2: (c - a).extend(0.0).to_array() });
            tri_index.push(*t);
        }
        let wide = crate::trace::wide::Wide::new(&nodes, tris.len());
        let wide_exact = crate::trace::wide::Wide::exact(&nodes, tris.len());
        Tree { nodes, tris, tri_index, wide, wide_exact }
    }

    /// True when the segment `o + s d`, `s` in `(t_min, t_max)` (`t_min >= 0`), hits a
    /// triangle.
    pub fn occluded(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> bool {
        self.occluder(o, d, t_min, t_max).is_some()
    }

    /// [`Tree::occluded`], trying first the occluder that stopped the previous segment
    /// (`last`, updated): neighbouring shadow rays towards one light are mostly stopped
    /// by the same wall. The answer is the walk's: the remembered triangle counts only
    /// where the segment hits it in range and crosses its leaf's box, and a box that
    /// passes the slab test has every enclosing box pass it too (the slab bounds are
    /// monotone in the box's corners), so the walk would have reached and hit it.
    pub fn occluded_after(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32, last: &mut Occluder) -> bool {
        self.occluded_hinted(o, d, t_min, t_max, &mut [last])
    }

    /// [`Tree::occluded_after`] with several remembered occluders (`hints`, tried in
    /// order; a walk's occluder is remembered in each): the same answer.
    pub fn occluded_hinted(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32, hints: &mut [&mut Occluder]) -> bool {
        self.hits_where_hinted(o, d, t_min, t_max, EDGE_SLACK, |_| true, hints)
    }

    /// The first occluder the walk finds on the segment (not the nearest): `(leaf node,
    /// index into tris)`.
    fn occluder(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> Option<(u32, u32)> {
        self.occluder_where(o, d, t_min, t_max, EDGE_SLACK, |_| true)
    }

    /// The shadow walk over the boxes the segment `o + s d`, `s` in `[0, t_max]`, crosses:
    /// the first triangle `hit` takes (the caller's own test, given the triangle's index
    /// into `tris`), as `(leaf node, index into tris)`, over the four-wide view
    /// ([`crate::trace::wide`]). Any hit answers, so the order does not change the answer.
    pub fn find_leaf_tri(&self, o: Vec3, d: Vec3, t_max: f32, hit: impl Fn(usize, &Tri) -> bool) -> Option<(u32, u32)> {
        self.wide.find(&self.nodes, &self.tris, o, d, t_max, hit)
    }

    /// True when the segment `o + s d`, `s` in `(t_min, t_max)`, hits a triangle that
    /// `accept` takes (by its index in the mesh), each triangle's barycentric range widened
    /// by `slack` (0 or at most [`EDGE_SLACK`], what the shadow walk's boxes are grown for).
    pub fn hits_where(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32, slack: f32, accept: impl Fn(u32) -> bool) -> bool {
        self.occluder_where(o, d, t_min, t_max, slack, accept).is_some()
    }

    /// [`Tree::hits_where`], trying first the triangles that answered earlier segments
    /// (`hints`, in order; a walk's answer is remembered in each): a remembered triangle
    /// counts only where the segment hits it in range, `accept` takes it and the segment
    /// crosses its leaf's box, so the walk would have found a hit too; the same answer.
    #[allow(clippy::too_many_arguments)]
    pub fn hits_where_hinted(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32, slack: f32, accept: impl Fn(u32) -> bool, hints: &mut [&mut Occluder]) -> bool {
        let inv = d.recip();
        for h in hints.iter() {
            if let Some((leaf, k)) = h.0 {
                if let (Some(node), Some(tri), Some(&t)) = (self.nodes.get(leaf as usize), self.tris.get(k as usize), self.tri_index.get(k as usize)) {
                    if intersect(tri, o, d, slack).is_some_and(|s| s > t_min && s < t_max) && accept(t) && slab_shadow(node, o, inv, t_max) {
                        return true;
                    }
                }
            }
        }
        match self.occluder_where(o, d, t_min, t_max, slack, accept) {
            Some(hit) => {
                hints.iter_mut().for_each(|h| h.0 = Some(hit));
                true
            }
            None => false,
        }
    }

    /// The shadow walk: the first hit it finds that `accept` takes (see [`Tree::hits_where`]).
    fn occluder_where(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32, slack: f32, accept: impl Fn(u32) -> bool) -> Option<(u32, u32)> {
        debug_assert!((0.0..=EDGE_SLACK).contains(&slack));
        self.find_leaf_tri(o, d, t_max, |k, tri| intersect(tri, o, d, slack).is_some_and(|t| t > t_min && t < t_max) && accept(self.tri_index[k]))
    }

    /// Nearest hit `(t, triangle index in the mesh)` along `o + s d`, `s` in `(0, t_max)`.
    pub fn first_hit(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, u32)> {
        self.first_hit_after(o, d, 0.0, t_max)
    }

    /// Nearest hit along `o + s d` with `s` in `(t_min, t_max)`.
    pub fn first_hit_after(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> Option<(f32, u32)> {
        self.first_hit_where(o, d, t_min, t_max, |_, _| true)
    }

    /// Nearest hit `(distance m, triangle index in the mesh)` within `length` (m) along the
    /// unit direction `dir` from `o`, counting a surface whose plane `o` lies on: the ray
    /// starts a hair ([`START_BACK_M`], more where f32 is coarser) behind `o`, so it enters
    /// a wall it starts on at distance 0, and a face met from behind (its winding normal
    /// along `dir`) counts only beyond twice that, so it does not stop at the plane it
    /// leaves. For a face's edge row, which lies on the plane of the wall it meets.
    pub fn first_hit_from_plane(&self, o: Vec3, dir: Vec3, length: f32) -> Option<(f32, u32)> {
        let r = PlaneRay::new(o, dir, length);
        self.first_hit_of(&r).map(|(t, tri)| (r.distance(t), tri))
    }

    /// The walk of a [`PlaneRay`]: its parameter in `(0, 1)` at the nearest hit it accepts
    /// and the mesh's triangle ([`PlaneRay::distance`] makes it a distance).
    pub fn first_hit_of(&self, r: &PlaneRay) -> Option<(f32, u32)> {
        self.first_hit_where(r.o, r.d, 0.0, 1.0, |tri, t| r.accepts(tri, t))
    }

    /// The first-hit walk: the exact four-wide view's ([`crate::trace::wide::Wide::first_hit`]),
    /// or the binary tree's where a component of `1 / d` is not finite. There the slab
    /// test meets `0 x inf` on a box's face (a ray along an axis, from the plane of a
    /// brush's box), and its NaN goes through glam's comparisons, which keep or drop it by
    /// position: a test that is no longer monotone in the box, so a walk that skips the
    /// binary tree's inner levels can take another path. (Without this fallback oa_dm1's
    /// default relight ended at 0.2288 instead of 0.2078.)
    fn first_hit_where(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32, accept: impl Fn(&Tri, f32) -> bool) -> Option<(f32, u32)> {
        if d.recip().is_finite() {
            let inv = d.recip();
            let leaf = |node: &Node, limit: f32| slab(node, o, inv, limit);
            let hit = |tri: &Tri, limit: f32| intersect(tri, o, d, 0.0).filter(|&t| t > t_min && t < limit && accept(tri, t));
            return self.wide_exact.first_hit(&self.nodes, &self.tris, o, d, t_max, leaf, hit).map(|(t, k)| (t, self.tri_index[k]));
        }
        let inv = d.recip();
        let mut best: Option<(f32, u32)> = None;
        let mut limit = t_max;
        let mut stack = Stack::root();
        while let Some(i) = stack.pop() {
            if self.tris.is_empty() {
                break;
            }
            let node = &self.nodes[i as usize];
            if !slab(node, o, inv, limit) {
                continue;
            }
            if node.count > 0 {
                let first = node.right_or_first as usize;
                for (k, tri) in self.tris[first..first + node.count as usize].iter().enumerate() {
                    if let Some(t) = intersect(tri, o, d, 0.0) {
                        if t > t_min && t < limit && accept(tri, t) {
                            limit = t;
                            best = Some((t, self.tri_index[first + k]));
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

    /// A length that crosses the whole scene from anywhere inside it (twice the root
    /// box's diagonal), m.
    pub fn reach(&self) -> f32 {
        self.nodes.first().map_or(1.0, |r| 2.0 * (Vec3::from(r.max) - Vec3::from(r.min)).length().max(0.5))
    }

    /// Distance from `p` to the nearest triangle and the nearest point (meters).
    pub fn nearest(&self, p: Vec3) -> Option<(f32, Vec3)> {
        self.nearest_triangle(p).map(|(d, c, _)| (d, c))
    }

    /// Every triangle within `r` of `p` (mesh index), in no particular order.
    pub fn within(&self, p: Vec3, r: f32) -> Vec<u32> {
        let mut out = Vec::new();
        let r2 = r * r;
        self.visit_near(p, r2, |t, _, d2| {
            if d2 <= r2 {
                out.push(t);
            }
            r2
        });
        out
    }

    /// [`Tree::nearest`] where the nearest triangle lies within `r` (m) of `p`; otherwise
    /// `None` or a triangle farther than `r`. The walk culls every box farther than `r`
    /// from the start (a light far from every wall costs a few boxes, not a descent to
    /// the nearest leaf), and visits the rest in `nearest`'s order with `nearest`'s test,
    /// so within `r` its answer is `nearest`'s to the bit.
    pub fn nearest_within(&self, p: Vec3, r: f32) -> Option<(f32, Vec3)> {
        self.nearest_bounded(p, r * r).map(|(d, c, _)| (d, c))
    }

    /// [`Tree::nearest`] with the nearest triangle's index in the mesh.
    pub fn nearest_triangle(&self, p: Vec3) -> Option<(f32, Vec3, u32)> {
        self.nearest_bounded(p, f32::INFINITY)
    }

    /// The nearest triangle, the walk culling boxes farther than `bound2` (m^2) from the
    /// start and, once a triangle is found, farther than it.
    fn nearest_bounded(&self, p: Vec3, bound2: f32) -> Option<(f32, Vec3, u32)> {
        let mut best: Option<(f32, Vec3, u32)> = None;
        let mut best_d2 = f32::INFINITY;
        self.visit_near(p, bound2, |t, c, d2| {
            if d2 < best_d2 {
                best_d2 = d2;
                best = Some((d2.sqrt(), c, t));
            }
            best_d2.min(bound2)
        });
        best
    }

    /// Visits the triangles in the leaves whose boxes lie within the bound (a squared
    /// distance, m^2) of `p`, with their mesh index, closest point and squared distance;
    /// `visit` returns the bound for the rest of the walk (a nearest search shrinks it).
    fn visit_near(&self, p: Vec3, bound2: f32, mut visit: impl FnMut(u32, Vec3, f32) -> f32) {
        let mut bound2 = bound2;
        let mut stack = Stack::root();
        while let Some(i) = stack.pop() {
            if self.tris.is_empty() {
                break;
            }
            let node = &self.nodes[i as usize];
            let q = p.clamp(Vec3::from(node.min), Vec3::from(node.max));
            if (q - p).length_squared() > bound2 {
                continue;
            }
            if node.count > 0 {
                let first = node.right_or_first as usize;
                for (k, tri) in self.tris[first..first + node.count as usize].iter().enumerate() {
                    let a = Vec3::from_slice(&tri.v0);
                    let c = closest_on_triangle(p, a, a + Vec3::from_slice(&tri.e1), a + Vec3::from_slice(&tri.e2));
                    bound2 = visit(self.tri_index[first + k], c, (c - p).length_squared());
                }
            } else {
                stack.push(node.right_or_first);
                stack.push(i + 1);
            }
        }
    }
}

/// The traversal stack of every walk: at most a node's two children are pushed when it is
/// visited, so it holds at most one entry per level plus one ([`MAX_DEPTH`] bounds the
/// build); no allocation per ray.
struct Stack {
    items: [u32; MAX_DEPTH + 1],
    len: usize,
}

impl Stack {
    fn root() -> Stack {
        Stack { items: [0; MAX_DEPTH + 1], len: 1 }
    }

    fn push(&mut self, node: u32) {
        if self.len < self.items.len() {
            self.items[self.len] = node;
            self.len += 1;
        }
    }

    fn pop(&mut self) -> Option<u32> {
        self.len = self.len.checked_sub(1)?;
        Some(self.items[self.len])
    }
}

/// [`slab`] on the node's box as the shadow walk's hit test sees its triangles: grown by
/// twice [`EDGE_SLACK`] of its largest side (a triangle's slack reaches at most that far
/// beyond it). The exact box would cull a ray through a triangle's edge where that edge
/// is the box's face, as the edges of Quake's axis-aligned brushes are (the floor under
/// `skylight_bright`'s opening). The same in WGSL (`shadow_box`, `slab_shadow_any`); the first-hit walks
/// keep the exact box (their hit test has no slack, and their ties stay as they were).
fn slab_shadow(node: &Node, o: Vec3, inv: Vec3, t_max: f32) -> bool {
    let (lo, hi) = crate::trace::wide::shadow_box(node);
    slab_box(lo, hi, o, inv, t_max)
}

fn slab(node: &Node, o: Vec3, inv: Vec3, t_max: f32) -> bool {
    slab_box(Vec3::from(node.min), Vec3::from(node.max), o, inv, t_max)
}

pub(crate) fn slab_box(min: Vec3, max: Vec3, o: Vec3, inv: Vec3, t_max: f32) -> bool {
    let t0 = (min - o) * inv;
    let t1 = (max - o) * inv;
    let near = t0.min(t1).max_element().max(0.0);
    let far = t0.max(t1).min_element().min(t_max);
    // NaN (0 * inf on a slab face) compares false: treated as a hit, which is conservative.
    !(near > far)
}

/// Moeller-Trumbore, two-sided, barycentric coordinates within `[-slack, 1 + slack]`.
/// Returns the ray parameter of the hit.
#[inline]
pub fn intersect(tri: &Tri, o: Vec3, d: Vec3, slack: f32) -> Option<f32> {
    intersect_uv(tri, o, d, slack, 0.0).map(|h| h.0)
}

/// [`intersect`], returning `(t, u, v)`, and missing where `|det| < min_det` (a ray that
/// close to the triangle's plane: q3map2's coplanar rule, [`crate::trace::pieces`]).
#[inline]
pub fn intersect_uv(tri: &Tri, o: Vec3, d: Vec3, slack: f32, min_det: f32) -> Option<(f32, f32, f32)> {
    let e1 = Vec3::from_slice(&tri.e1[..3]);
    let e2 = Vec3::from_slice(&tri.e2[..3]);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() || !(det.abs() >= min_det) {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - Vec3::from_slice(&tri.v0[..3]);
    let u = s.dot(p) * inv;
    if !(-slack..=1.0 + slack).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < -slack || u + v > 1.0 + slack {
        return None;
    }
    Some((e2.dot(q) * inv, u, v))
}

/// Closest point on triangle abc to p (Ericson, Real-Time Collision Detection 5.1.5).
pub fn closest_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return a + ab * v;
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return a + ac * w;
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return b + (c - b) * w;
    }
    let denom = va + vb + vc;
    if denom == 0.0 || !denom.is_finite() {
        return a;
    }
    let v = vb / denom;
    let w = vc / denom;
    a + ab * v + ac * w
}

/// Recursive binned-SAH build; returns the node index. Items are reordered in place and a
/// leaf's `first` is an offset into the whole item array (`base` is this slice's offset).
fn build_rec(items: &mut [(u32, Aabb, Vec3)], base: usize, nodes: &mut Vec<Node>, depth: usize, three_axes: bool) -> u32 {
    let mut bb = Aabb::EMPTY;
    let mut cb = Aabb::EMPTY;
    for (_, b, c) in items.iter() {
        bb.merge(b);
        cb.grow(*c);
    }
    let me = nodes.len();
    nodes.push(Node { min: bb.lo.to_array(), right_or_first: base as u32, max: bb.hi.to_array(), count: items.len() as u32 });
    // Deep enough that the stack of depth MAX_DEPTH always suffices (one slot per level + 1).
    if items.len() <= LEAF_SIZE || depth + 2 >= MAX_DEPTH {
        return me as u32;
    }
    let ext = cb.hi - cb.lo;
    let longest = if ext.x >= ext.y && ext.x >= ext.z { 0 } else if ext.y >= ext.z { 1 } else { 2 };
    // The axis and bin split of the lowest SAH cost: the longest axis, or all three.
    let mut best = (f32::INFINITY, 0usize, longest);
    for axis in 0..3 {
        if axis != longest && !three_axes {
            continue;
        }
        let (lo, span) = (cb.lo[axis], ext[axis]);
        if !(span > 0.0 && span.is_finite()) {
            continue;
        }
        let bin_of = |c: Vec3| (((c[axis] - lo) / span * BINS as f32) as usize).min(BINS - 1);
        let mut bins = [(Aabb::EMPTY, 0usize); BINS];
        for (_, b, c) in items.iter() {
            let k = bin_of(*c);
            bins[k].0.merge(b);
            bins[k].1 += 1;
        }
        for split in 1..BINS {
            let (mut l, mut r) = (Aabb::EMPTY, Aabb::EMPTY);
            let (mut nl, mut nr) = (0, 0);
            for (k, (b, n)) in bins.iter().enumerate() {
                if *n == 0 {
                    continue;
                }
                if k < split {
                    l.merge(b);
                    nl += n;
                } else {
                    r.merge(b);
                    nr += n;
                }
            }
            if nl == 0 || nr == 0 {
                continue;
            }
            let cost = l.area() * nl as f32 + r.area() * nr as f32;
            if cost < best.0 {
                best = (cost, split, axis);
            }
        }
    }
    let mut mid = if best.0.is_finite() {
        let (split, axis) = (best.1, best.2);
        let (lo, span) = (cb.lo[axis], ext[axis]);
        let bin_of = |c: Vec3| (((c[axis] - lo) / span * BINS as f32) as usize).min(BINS - 1);
        partition(items, |it| bin_of(it.2) < split)
    } else {
        items.len() / 2
    };
    if mid == 0 || mid == items.len() {
        mid = items.len() / 2;
    }
    let (left, right) = items.split_at_mut(mid);
    build_rec(left, base, nodes, depth + 1, three_axes);
    let r = build_rec(right, base + mid, nodes, depth + 1, three_axes);
    nodes[me].right_or_first = r;
    nodes[me].count = 0;
    me as u32
}

fn partition<T>(items: &mut [T], pred: impl Fn(&T) -> bool) -> usize {
    let mut i = 0;
    for j in 0..items.len() {
        if pred(&items[j]) {
            items.swap(i, j);
            i += 1;
        }
    }
    i
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::bounce::hash01;

    /// The BVH of one quad (two triangles), corners in order, facing `normal`.
    fn one_quad(corners: [[f32; 3]; 4], normal: Vec3) -> Tree {
        let mut mesh = crate::testutil::room(2).0;
        mesh.triangles.clear();
        mesh.tri_material.clear();
        mesh.tri_source.clear();
        crate::testutil::push_quad(&mut mesh, corners, normal);
        Tree::build(&mesh)
    }

    /// Within its radius the bounded nearest query is the unbounded one to the bit (the
    /// penalty that keeps lights off walls uses it); beyond, it finds nothing nearer.
    #[test]
    fn the_bounded_nearest_query_agrees_with_the_nearest_within_its_radius() {
        let bvh = Tree::build(&crate::testutil::room(6).0);
        let mut near = 0;
        for k in 0..2000u32 {
            // Points in and around the 4 x 2.5 x 3 m room.
            let p = Vec3::new(hash01(k, 0) * 5.0 - 0.5, hash01(k, 1) * 3.5 - 0.5, hash01(k, 2) * 4.0 - 0.5);
            let r = 0.02 + hash01(k, 3) * 0.6;
            let all = bvh.nearest(p).expect("a room has triangles");
            let within = bvh.nearest_within(p, r);
            if all.0 < r {
                near += 1;
                let w = within.expect("found within the radius");
                assert_eq!((w.0.to_bits(), w.1.to_array().map(f32::to_bits)), (all.0.to_bits(), all.1.to_array().map(f32::to_bits)), "at {p}");
            } else if let Some(w) = within {
                assert!(w.0 >= all.0 && w.0 >= r * (1.0 - 1e-6), "at {p}: {} within {r}", w.0);
            }
        }
        // Both sides of the radius were exercised.
        assert!(near > 100 && near < 1900, "{near} of 2000 within their radius");
    }

    /// A ray through the diagonal two triangles of a quad share hits the quad, wherever
    /// along the diagonal it passes (in f32 the exact test can miss both halves).
    #[test]
    fn a_ray_through_a_shared_edge_is_stopped() {
        // A quad at x = 0.3, in y, z from 0.1 to 2.7 (metres), cut along its diagonal.
        let bvh = one_quad([[0.3, 0.1, 0.1], [0.3, 2.7, 0.1], [0.3, 2.7, 2.7], [0.3, 0.1, 2.7]], Vec3::X);
        let mut missed = 0;
        for k in 0..2000u32 {
            // A point on the diagonal, and a ray through it from a random origin in front.
            let s = 0.02 + 0.96 * hash01(k, 7);
            let on = Vec3::new(0.3, 0.1 + 2.6 * s, 0.1 + 2.6 * s);
            let from = Vec3::new(-1.0 - hash01(k, 8), 3.0 * hash01(k, 9), 3.0 * hash01(k, 10));
            let d = (on - from) * 2.0;
            missed += !bvh.occluded(from, d, 0.0, 1.0) as u32;
        }
        assert_eq!(missed, 0);
    }

    #[test]
    fn a_ray_along_the_box_face_through_an_edge_is_stopped() {
        // A ceiling panel (y = 2, x from 0.5 to 2.5 m) and rays straight up a hair outside
        // its edge x = 0.5, which is also its box's face: the slack takes them, and the
        // box must not cull them first (the floor under `skylight_bright`'s opening).
        let bvh = one_quad([[0.5, 2.0, 0.5], [2.5, 2.0, 0.5], [2.5, 2.0, 2.5], [0.5, 2.0, 2.5]], Vec3::NEG_Y);
        for k in 0..200u32 {
            let z = 0.6 + 1.8 * hash01(k, 3);
            let outside = 0.5 - EDGE_SLACK * hash01(k, 5);
            let o = Vec3::new(outside, 0.0, z);
            assert!(bvh.occluded(o, Vec3::Y * 4.0, 1e-4, 1.0), "ray {k} at x = {outside}, z = {z}");
            assert!(bvh.hits_where(o, Vec3::Y * 4.0, 1e-4, 1.0, EDGE_SLACK, |_| true));
            // Clearly outside, nothing stops it.
            assert!(!bvh.occluded(Vec3::new(0.49, 0.0, z), Vec3::Y * 4.0, 1e-4, 1.0));
        }
    }

    /// The remembered occluder never changes an answer: segments in and around a room
    /// (walls that stop them, openings at grazing angles, segments ending on a wall),
    /// each asked with the occluder its predecessor left, with none, and with indices
    /// that are out of range.
    #[test]
    fn the_previous_occluder_gives_the_walks_answer() {
        let (mesh, _) = crate::testutil::room(4);
        let bvh = Tree::build(&mesh);
        let point = |k: u32| Vec3::new(-1.0 + 6.0 * hash01(k, 1), -1.0 + 4.5 * hash01(k, 2), -1.0 + 5.0 * hash01(k, 3));
        let mut last = Occluder::default();
        let mut older = Occluder::default();
        let mut crossed = Occluder::default();
        let (mut blocked, mut kept) = (0, 0);
        for k in 0..20_000u32 {
            let (a, b) = (point(2 * k), point(2 * k + 1));
            // Every fourth segment ends exactly on a wall plane (x = 0).
            let b = if k % 4 == 0 { Vec3::new(0.0, b.y, b.z) } else { b };
            let d = b - a;
            let (t_min, t_max) = (1e-3, 1.0 - 1e-3);
            let walk = bvh.occluded(a, d, t_min, t_max);
            let before = last;
            assert_eq!(bvh.occluded_after(a, d, t_min, t_max, &mut last), walk, "segment {k}");
            assert_eq!(bvh.occluded_after(a, d, t_min, t_max, &mut Occluder::default()), walk);
            assert_eq!(bvh.occluded_after(a, d, t_min, t_max, &mut Occluder(Some((u32::MAX, u32::MAX)))), walk);
            // Two hints: a bad one, then the occluder of the segment before the last.
            let mut bad = Occluder(Some((u32::MAX, 0)));
            assert_eq!(bvh.occluded_hinted(a, d, t_min, t_max, &mut [&mut bad, &mut older]), walk, "segment {k}, two hints");
            older = before;
            // Any hit among some triangles (the sky test), with the triangle that answered
            // an earlier segment tried first.
            let some = |t: u32| t % 3 != 0;
            assert_eq!(bvh.hits_where_hinted(a, d, t_min, t_max, 0.0, some, &mut [&mut crossed]), bvh.hits_where(a, d, t_min, t_max, 0.0, some), "segment {k}, a predicate");
            blocked += walk as usize;
            kept += (walk && before.0.is_some() && before.0 == last.0) as usize;
        }
        assert!(blocked > 1000 && kept > 100, "the test exercises both answers and a hint that stops the next segment too: {blocked} blocked, {kept} with the occluder kept");
    }
}
