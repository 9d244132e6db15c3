//! The pieces q3map2's light stage traced its shadow rays against, rebuilt from the
//! record convert keeps (`q3_casters`: the BSP's tree and the casting triangles, Quake
//! units; see `q3gltf_convert::casters`), and the hit test q3map2 applies to them.
//!
//! q3map2 (`SetupTraceNodes`, `TraceLine`, `TraceTriangle` in `light_trace.c`):
//! 1. **Tree.** A trace node per BSP node; each leaf of structural solid stops a ray.
//! 2. **Filter.** Each casting triangle goes down the tree. A triangle on a node's plane
//!    (normals within 0.999, distances within 0.001) goes to the side it faces; any other
//!    is clipped by the plane (`TW_ON_EPSILON` 0.25 unit: a vertex that close is on it,
//!    and a winding with nothing behind goes in front whole).
//! 3. **Subdivide.** A leaf with at least [`MIN_TRIANGLES`] triangles' worth of vertices,
//!    wider than [`MIN_NODE_SIZE`] along its widest axis and less than [`MAX_DEPTH`] deep
//!    is split on that axis at the floor of its vertices' mean (the box's middle when that
//!    falls outside), and its windings are clipped again.
//! 4. **Triangulate.** Each winding becomes a fan from its first vertex.
//! 5. **Test.** A ray collects the leaves it passes (stopping at solid) and tests their
//!    pieces by Moeller-Trumbore with every barycentric coordinate allowed 1% outside
//!    ([`BARY_SLACK`]); a ray nearly in a piece's plane (`|det| < 0.25` unit^2 for a unit
//!    direction, [`COPLANAR_UNITS2`]) misses it.
//!
//! The slack is what the mesh's exact test lacks: a ray that passes within 1% of a piece's
//! size beyond its edge is stopped, so a sky opening's or a doorway's rim casts a slightly
//! wider shadow, by an amount that depends on how the tree cut the face. relight tests
//! the same pieces with the same slack through a BVH ([`Shadow`]); a hit within the slack
//! band counts only when the ray passes through the piece's leaf (its half-spaces, each
//! grown by q3map2's `TRACE_ON_EPSILON`, 0.1 unit), as q3map2 tests only the pieces of
//! the leaves a ray visits. Not modelled: the 256 leaves a ray tests at most, the
//! self-shadow rule within half a unit of the sample, and the structural-solid stop (the
//! faces already bound it; exact modelling moved the recompiles by 0.0001).
//!
//! Measured (point lights only, q3map2 recompiles of the truth set, `--fit globals`):
//! the pieces dumped from q3map2 itself (a patched light stage) took oacmpdm3 0.0557 ->
//! 0.0283, oacmpdm2 0.0128 -> 0.0055, oacmpctf1 0.0159 -> 0.0111, oacmpdm1 0.0089 ->
//! 0.0066, oacmpdm4 0.1405 -> 0.1342 (without the leaf test); the pieces rebuilt here
//! are the same 1727 on the `skylight` fixtures, and the same figures. With the shadow
//! rays from the sample itself (`rows::Sampling::shadow_offset`): oacmpdm3 0.0156,
//! oacmpdm2 0.0053, oacmpctf1 0.0110, oacmpdm1 0.0063, oacmpdm4 0.1343.

use glam::{DVec3, Vec3};

use crate::casters::{Casters, SKY};
use crate::scene::Mesh;
use crate::trace::tree::{Occluder, Tree, Tri};
use crate::trace::wide::PACKET;

/// A vertex this close to a plane (Quake units) is on it when a winding is clipped.
const TW_ON_EPSILON: f64 = 0.25;
/// A ray within this distance of a node's plane (Quake units) is on its front side.
pub const TRACE_ON_EPSILON_UNITS: f64 = 0.1;
/// Subdivision stops at this depth (counted from the tree's root).
const MAX_DEPTH: u32 = 32;
/// A leaf with fewer triangles' worth of vertices (vertices less twice the windings) is
/// not subdivided.
const MIN_TRIANGLES: usize = 5;
/// A leaf no wider than this (Quake units) along its widest axis is not subdivided.
const MIN_NODE_SIZE: f64 = 32.0;
/// q3map2's barycentric slack (`BARY_EPSILON`).
pub const BARY_SLACK: f32 = 0.01;
/// q3map2's `COPLANAR_EPSILON`, Quake units^2 (for a unit direction).
const COPLANAR_UNITS2: f64 = 0.25;
/// No ancestor: the root's own bound.
pub const NO_PARENT: u32 = u32::MAX;

/// A winding being filtered: its vertices and the plane of the triangle it came from.
#[derive(Debug, Clone)]
struct Winding {
    v: Vec<DVec3>,
    plane: (DVec3, f64),
    sky: bool,
}

#[derive(Debug, Clone)]
enum Node {
    Split { normal: DVec3, dist: f64, children: [usize; 2] },
    Leaf { solid: bool, items: Vec<Winding> },
}

/// q3map2's pieces: fan triangles (Quake units), each with the trace node of its leaf, and
/// per trace node the half-space of its parent's plane on its side (`bound`: `n . p - d
/// >= 0` inside) and its parent ([`NO_PARENT`] at the root).
#[derive(Debug, Clone, Default)]
pub struct Pieces {
    pub triangles: Vec<[DVec3; 3]>,
    pub leaf: Vec<u32>,
    pub bound: Vec<(DVec3, f64)>,
    pub parent: Vec<u32>,
}

/// `ClipTraceWinding`: the parts of `w` in front of and behind `n . p = d`.
fn clip(w: &Winding, normal: DVec3, dist: f64) -> (Option<Winding>, Option<Winding>) {
    #[derive(Clone, Copy, PartialEq)]
    enum Side {
        Front,
        Back,
        On,
    }
    let d: Vec<f64> = w.v.iter().map(|p| normal.dot(*p) - dist).collect();
    let sides: Vec<Side> = d.iter().map(|&x| if x < -TW_ON_EPSILON { Side::Back } else if x > TW_ON_EPSILON { Side::Front } else { Side::On }).collect();
    let (front_n, back_n) = (sides.iter().filter(|s| **s == Side::Front).count(), sides.iter().filter(|s| **s == Side::Back).count());
    if back_n == 0 {
        return (Some(w.clone()), None);
    }
    if front_n == 0 {
        return (None, Some(w.clone()));
    }
    let (mut f, mut b) = (Vec::new(), Vec::new());
    let n = w.v.len();
    for i in 0..n {
        let j = (i + 1) % n;
        let (a, c) = (w.v[i], w.v[j]);
        match sides[i] {
            Side::Front => f.push(a),
            Side::Back => b.push(a),
            Side::On => {
                f.push(a);
                b.push(a);
                continue;
            }
        }
        if sides[j] == Side::On || sides[j] == sides[i] {
            continue;
        }
        let frac = d[i] / (d[i] - d[j]);
        let mid = DVec3::from_array(std::array::from_fn(|k| {
            if normal[k] == 1.0 {
                dist
            } else if normal[k] == -1.0 {
                -dist
            } else {
                a[k] + frac * (c[k] - a[k])
            }
        }));
        f.push(mid);
        b.push(mid);
    }
    let keep = |v: Vec<DVec3>| (v.len() >= 3).then(|| Winding { v, plane: w.plane, sky: w.sky });
    (keep(f), keep(b))
}

/// Builds q3map2's pieces from the record (the steps in the module docs).
pub fn build(c: &Casters) -> Pieces {
    // 1. The tree: trace node per BSP node, a fresh trace leaf per leaf child.
    let mut nodes: Vec<Node> = Vec::with_capacity(2 * c.nodes.len() + 1);
    let mut parent: Vec<(u32, usize)> = Vec::new();
    let mut map = vec![usize::MAX; c.nodes.len()];
    // Children come after parents, so one pass in order allocates each node once.
    nodes.push(Node::Leaf { solid: false, items: Vec::new() });
    parent.push((NO_PARENT, 0));
    map[0] = 0;
    for i in 0..c.nodes.len() {
        let Some(&me) = map.get(i).filter(|&&m| m != usize::MAX) else { continue };
        let (plane, kids) = c.nodes[i];
        let (normal, dist) = c.planes[plane as usize];
        let mut children = [0usize; 2];
        for (side, &k) in kids.iter().enumerate() {
            let id = nodes.len();
            if k >= 0 {
                map[k as usize] = id;
                nodes.push(Node::Leaf { solid: false, items: Vec::new() });
            } else {
                let solid = c.leaf_solid.get((-(k as i64) - 1) as usize).copied().unwrap_or(false);
                nodes.push(Node::Leaf { solid, items: Vec::new() });
            }
            parent.push((me as u32, side));
            children[side] = id;
        }
        nodes[me] = Node::Split { normal, dist, children };
    }
    // 2. Filter every triangle down the tree.
    for t in &c.triangles {
        let [p0, p1, p2] = [t[0], t[1], t[2]].map(|i| c.vertices[i as usize]);
        // `PlaneFromPoints`: the normal of (p2 - p0) x (p1 - p0); a degenerate one goes.
        let n = (p2 - p0).cross(p1 - p0);
        let len = n.length();
        if !(len > 0.0) {
            continue;
        }
        let n = n / len;
        let mut stack = vec![(Winding { v: vec![p0, p1, p2], plane: (n, p0.dot(n)), sky: t[3] & SKY != 0 }, 0usize)];
        while let Some((w, at)) = stack.pop() {
            match &mut nodes[at] {
                Node::Leaf { items, .. } => items.push(w),
                Node::Split { normal, dist, children } => {
                    let (normal, dist, children) = (*normal, *dist, *children);
                    let (wn, wd) = w.plane;
                    if normal.dot(wn) > 0.999 && (dist - wd).abs() < 0.001 {
                        stack.push((w, children[0]));
                    } else if normal.dot(-wn) > 0.999 && (dist + wd).abs() < 0.001 {
                        stack.push((w, children[1]));
                    } else {
                        let (f, b) = clip(&w, normal, dist);
                        if let Some(f) = f {
                            stack.push((f, children[0]));
                        }
                        if let Some(b) = b {
                            stack.push((b, children[1]));
                        }
                    }
                }
            }
        }
    }
    // 3. Subdivide the leaves along the axes.
    let mut stack = vec![(0usize, 0u32)];
    while let Some((at, depth)) = stack.pop() {
        if depth >= MAX_DEPTH {
            continue;
        }
        let depth = depth + 1;
        let items = match &mut nodes[at] {
            Node::Split { children, .. } => {
                stack.push((children[1], depth));
                stack.push((children[0], depth));
                continue;
            }
            Node::Leaf { items, .. } => items,
        };
        let (mut lo, mut hi, mut sum, mut count) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY), DVec3::ZERO, 0usize);
        for w in items.iter() {
            for p in &w.v {
                lo = lo.min(*p);
                hi = hi.max(*p);
                sum += *p;
                count += 1;
            }
        }
        if count < 2 * items.len() + MIN_TRIANGLES {
            continue;
        }
        let size = hi - lo;
        let axis = if size.x >= size.y && size.x >= size.z {
            0
        } else if size.y >= size.x && size.y >= size.z {
            1
        } else {
            2
        };
        if size[axis] <= MIN_NODE_SIZE {
            continue;
        }
        let mut dist = (sum[axis] / count as f64).floor();
        if dist <= lo[axis] || dist >= hi[axis] {
            dist = (0.5 * (lo[axis] + hi[axis])).floor();
        }
        let mut normal = DVec3::ZERO;
        normal[axis] = 1.0;
        let (mut front, mut back) = (Vec::new(), Vec::new());
        for w in std::mem::take(items) {
            let (f, b) = clip(&w, normal, dist);
            front.extend(f);
            back.extend(b);
        }
        let solid = matches!(nodes[at], Node::Leaf { solid: true, .. });
        let (fi, bi) = (nodes.len(), nodes.len() + 1);
        nodes.push(Node::Leaf { solid, items: front });
        nodes.push(Node::Leaf { solid, items: back });
        parent.push((at as u32, 0));
        parent.push((at as u32, 1));
        nodes[at] = Node::Split { normal, dist, children: [fi, bi] };
        stack.push((bi, depth));
        stack.push((fi, depth));
    }
    // 4. Fans, leaves of structural solid left out (a ray stops on entering them), and
    // the sky's (they stop nothing).
    let mut out = Pieces { triangles: Vec::new(), leaf: Vec::new(), bound: Vec::with_capacity(nodes.len()), parent: Vec::with_capacity(nodes.len()) };
    for (i, node) in nodes.iter().enumerate() {
        let (p, side) = parent[i];
        let b = match nodes.get(p as usize) {
            Some(Node::Split { normal, dist, .. }) if side == 0 => (*normal, *dist),
            Some(Node::Split { normal, dist, .. }) => (-*normal, -*dist),
            _ => (DVec3::ZERO, 0.0),
        };
        out.bound.push(b);
        out.parent.push(p);
        if let Node::Leaf { solid: false, items } = node {
            for w in items.iter().filter(|w| !w.sky) {
                for j in 1..w.v.len() - 1 {
                    out.triangles.push([w.v[0], w.v[j], w.v[j + 1]]);
                    out.leaf.push(i as u32);
                }
            }
        }
    }
    out
}

/// The pieces as relight traces them, in the scene's stored frame: a BVH over them (each
/// box grown to hold the piece's slack), each [`Tri`] carrying its leaf's trace node
/// (`v0[3]`, bits), its barycentric slack (`e1[3]`) and its coplanar threshold (`e2[3]`,
/// m^2 per metre of ray), and the leaves' half-spaces.
///
/// A first design grouped the pieces under their casting triangles (a tree of those, the
/// pieces tested where a ray crossed one): no faster on oa_dm1 (the shadow rays of 85
/// lights 0.95 s against 1.03 s), and not exact, since a ray grazing a triangle meets its
/// plane far from where it meets a piece that the cuts' rounding lifted off that plane
/// (1 ray in 200,000 on oacmpdm4).
#[derive(Debug, Clone)]
pub struct Shadow {
    pub tree: Tree,
    /// Per trace node: `[nx, ny, nz, d]` (inside: `n . x - d >= -leaf_epsilon_m`).
    pub bound: Vec<[f32; 4]>,
    pub parent: Vec<u32>,
    /// `TRACE_ON_EPSILON` in metres.
    pub leaf_epsilon_m: f32,
}

impl Shadow {
    /// The pieces of `c` in the frame of a scene whose stored positions are world minus
    /// `origin` (m), `units_m` metres per Quake unit.
    pub fn new(c: &Casters, origin: DVec3, units_m: f64) -> Shadow {
        let p = build(c);
        let to_gl = |q: DVec3| DVec3::new(q.x, q.z, -q.y);
        let mut mesh = Mesh::default();
        for t in &p.triangles {
            let base = mesh.positions.len() as u32;
            for v in t {
                mesh.positions.push((to_gl(*v) * units_m - origin).as_vec3());
            }
            mesh.triangles.push([base, base + 1, base + 2]);
        }
        // A slack s in every barycentric is the triangle scaled by 1 + 3 s about its
        // centroid: its box grows by at most 3 s of its largest side.
        let mut tree = Tree::build_grown(&mesh, 3.0 * BARY_SLACK);
        let coplanar = (COPLANAR_UNITS2 * units_m * units_m) as f32;
        for (k, tri) in tree.tris.iter_mut().enumerate() {
            let piece = tree.tri_index[k] as usize;
            tri.v0[3] = f32::from_bits(p.leaf[piece]);
            tri.e1[3] = BARY_SLACK;
            tri.e2[3] = coplanar;
        }
        let bound = p
            .bound
            .iter()
            .map(|(n, d)| {
                let g = to_gl(*n);
                [g.x as f32, g.y as f32, g.z as f32, (d * units_m - g.dot(origin)) as f32]
            })
            .collect();
        Shadow { tree, bound, parent: p.parent, leaf_epsilon_m: (TRACE_ON_EPSILON_UNITS * units_m) as f32 }
    }

    /// Whether the segment `o + s d`, `s` in `(t_min, t_max)`, passes through the leaf of
    /// trace node `leaf` (each of its half-spaces grown by the epsilon).
    pub fn passes_leaf(&self, mut leaf: u32, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> bool {
        let (mut lo, mut hi) = (t_min, t_max);
        let eps = self.leaf_epsilon_m;
        let mut guard = 0;
        while (leaf as usize) < self.parent.len() && self.parent[leaf as usize] != NO_PARENT && guard < 4096 {
            let [nx, ny, nz, dist] = self.bound[leaf as usize];
            let n = Vec3::new(nx, ny, nz);
            // n . (o + s d) - dist >= -eps.
            let (a, b) = (n.dot(o) - dist + eps, n.dot(d));
            if b > 0.0 {
                lo = lo.max(-a / b);
            } else if b < 0.0 {
                hi = hi.min(-a / b);
            } else if a < 0.0 {
                return false;
            }
            if !(lo <= hi) {
                return false;
            }
            leaf = self.parent[leaf as usize];
            guard += 1;
        }
        true
    }

    /// q3map2's test of one piece: the ray parameter of a hit, `None` for a miss (see the
    /// module docs). `len` is `|d|`.
    #[inline(always)]
    pub fn hit(&self, tri: &Tri, o: Vec3, d: Vec3, len: f32, t_min: f32, t_max: f32) -> Option<f32> {
        let (t, u, v) = crate::trace::tree::intersect_uv(tri, o, d, tri.e1[3], tri.e2[3] * len)?;
        if !(t > t_min && t < t_max) {
            return None;
        }
        if (u < 0.0 || v < 0.0 || u + v > 1.0) && !self.passes_leaf(tri.v0[3].to_bits(), o, d, t_min, t_max) {
            return None;
        }
        Some(t)
    }

    /// Whether a piece stops the segment `o + s d`, `s` in `(t_min, t_max)`.
    pub fn occluded(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32) -> bool {
        self.occluded_after(o, d, t_min, t_max, &mut Occluder::default())
    }

    /// [`Shadow::occluded`], trying first the piece that stopped the previous segment
    /// (`last`, updated): any piece that stops the segment answers, and the walk would
    /// have reached this one (its box holds its slack), so the answer is the walk's.
    pub fn occluded_after(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32, last: &mut Occluder) -> bool {
        self.occluded_hinted(o, d, t_min, t_max, &mut [last])
    }

    /// [`Shadow::occluded_after`] with several remembered pieces (`hints`, tried in
    /// order; a walk's piece is remembered in each): the same answer.
    pub fn occluded_hinted(&self, o: Vec3, d: Vec3, t_min: f32, t_max: f32, hints: &mut [&mut Occluder]) -> bool {
        let len = d.length();
        if hints.iter().any(|h| self.remembered_stops(h, o, d, len, t_min, t_max)) {
            return true;
        }
        match self.tree.find_leaf_tri(o, d, t_max, |_, tri| self.hit(tri, o, d, len, t_min, t_max).is_some()) {
            Some(hit) => {
                hints.iter_mut().for_each(|h| h.0 = Some(hit));
                true
            }
            None => false,
        }
    }

    /// Whether the remembered piece `h` stops the segment (`len = |d|`): any piece that
    /// does answers, and the walk would have reached it (its box holds its slack).
    #[inline]
    pub fn remembered_stops(&self, h: &Occluder, o: Vec3, d: Vec3, len: f32, t_min: f32, t_max: f32) -> bool {
        h.0.and_then(|(_, k)| self.tree.tris.get(k as usize)).is_some_and(|tri| self.hit(tri, o, d, len, t_min, t_max).is_some())
    }

    /// [`Shadow::occluded_hinted`]'s walk for up to [`PACKET`] segments at once, no
    /// hints (`o[r] + s d[r]`, `s` in `(t_min[r], t_max[r])`, for the rays `active`
    /// sets; `len[r] = |d[r]|`): each ray's piece that stops it, as the walk names
    /// pieces, `None` where none does; the same answers as one walk per ray
    /// ([`crate::trace::wide::Wide::find_packet`]).
    pub fn occluders_packet(&self, o: &[Vec3; PACKET], d: &[Vec3; PACKET], len: &[f32; PACKET], t_min: &[f32; PACKET], t_max: &[f32; PACKET], active: u32) -> [Option<(u32, u32)>; PACKET] {
        self.tree.wide.find_packet(&self.tree.nodes, &self.tree.tris, o, d, t_max, active, |r, _, tri| self.hit(tri, o[r], d[r], len[r], t_min[r], t_max[r]).is_some())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A one-node tree (plane x = 0) and the given triangles.
    fn casters(triangles: &[[[f64; 3]; 3]]) -> Casters {
        let mut c = Casters {
            planes: vec![(DVec3::X, 0.0)],
            nodes: vec![(0, [-1, -2])],
            leaf_solid: vec![false, false],
            ..Default::default()
        };
        for t in triangles {
            let base = c.vertices.len() as u32;
            c.vertices.extend(t.iter().map(|p| DVec3::from_array(*p)));
            c.triangles.push([base, base + 1, base + 2, 0]);
        }
        c
    }

    #[test]
    fn a_triangle_across_a_node_plane_is_cut_and_one_on_it_goes_to_the_side_it_faces() {
        // A floor triangle across x = 0, and one in the plane x = 0 facing +x.
        let p = build(&casters(&[[[-64.0, 0.0, 0.0], [64.0, 64.0, 0.0], [64.0, 0.0, 0.0]], [[0.0, 0.0, 0.0], [0.0, 0.0, 64.0], [0.0, 64.0, 0.0]]]));
        // Front leaf (node 1) holds the front half of the floor (a quad: two fans) and the
        // wall; the back leaf (node 2) the back triangle.
        let front = p.leaf.iter().filter(|&&l| l == 1).count();
        let back = p.leaf.iter().filter(|&&l| l == 2).count();
        assert_eq!((front, back), (3, 1), "{:?}", p.leaf);
        for (t, &l) in p.triangles.iter().zip(&p.leaf) {
            for v in t {
                assert!(if l == 1 { v.x >= -TW_ON_EPSILON } else { v.x <= TW_ON_EPSILON }, "{v} in leaf {l}");
            }
        }
        // The bounds: the front child inside x >= 0, the back one inside -x >= 0.
        assert_eq!(p.bound[1], (DVec3::X, 0.0));
        assert_eq!(p.bound[2], (-DVec3::X, -0.0));
    }

    #[test]
    fn a_crowded_leaf_is_split_at_the_floor_of_its_mean() {
        // Eight floor triangles over x in [8, 200] in the front leaf: split on x.
        let tris: Vec<[[f64; 3]; 3]> = (0..8).map(|i| {
            let x = 8.0 + 24.0 * i as f64;
            [[x, 0.0, 0.0], [x + 24.0, 10.0, 0.0], [x + 24.0, 0.0, 0.0]]
        }).collect();
        let p = build(&casters(&tris));
        // The mean x of the 24 vertices is 8 + 24 * 3.5 + 16 = 108, floored.
        let splits: Vec<f64> = p.bound.iter().filter(|(n, _)| *n == DVec3::X).map(|b| b.1).collect();
        assert!(splits.contains(&108.0), "{splits:?}");
        assert!(p.triangles.len() > 8);
    }

    #[test]
    fn the_slack_stops_a_ray_past_the_edge_only_through_the_pieces_leaf() {
        // A square floor at z = 0 over x in [0, 256], y in [8, 264]: in the front leaf of
        // the plane x = 0 (its vertices on the plane count as on it). Metres = units
        // (scale 1), origin 0; glTF (x, y, z) = Quake (x, z, -y).
        let c = casters(&[[[0.0, 8.0, 0.0], [256.0, 264.0, 0.0], [256.0, 8.0, 0.0]], [[0.0, 8.0, 0.0], [0.0, 264.0, 0.0], [256.0, 264.0, 0.0]]]);
        let s = Shadow::new(&c, DVec3::ZERO, 1.0);
        let down = |x: f32, y: f32| (Vec3::new(x, 10.0, -y), Vec3::new(0.0, -20.0, 0.0));
        // One unit past the edge x = 256 (the slack there is up to 2.56 units): stopped.
        let (o, d) = down(257.0, 100.0);
        assert!(s.occluded(o, d, 0.0, 1.0));
        // Five units past: not.
        let (o, d) = down(261.0, 100.0);
        assert!(!s.occluded(o, d, 0.0, 1.0));
        // One unit past the edge x = 0, straight down: the ray stays in the other leaf
        // (x < -0.1) and q3map2 never tests the piece.
        let (o, d) = down(-1.0, 100.0);
        assert!(!s.occluded(o, d, 0.0, 1.0));
        // The same point reached from inside the leaf (a slanted ray from x = 9): stopped.
        assert!(s.occluded(Vec3::new(9.0, 10.0, -100.0), Vec3::new(-20.0, -20.0, 0.0), 0.0, 1.0));
        // A ray in the floor's plane misses it (coplanar).
        assert!(!s.occluded(Vec3::new(100.0, 0.0, -100.0), Vec3::new(10.0, 0.0, 0.0), 0.0, 1.0));
        // Remembered pieces never change an answer, where the slack and the leaf decide
        // it too: rays down around the edge x = 0 and x = 256, slanted both ways, each
        // asked with the pieces of the rays before it.
        let (mut last, mut older) = (Occluder::default(), Occluder::default());
        let mut blocked = 0;
        for k in 0..4000u32 {
            let h = |q: u32| crate::model::bounce::hash01(k, q);
            let x = if k % 2 == 0 { -6.0 + 12.0 * h(1) } else { 250.0 + 12.0 * h(1) };
            let o = Vec3::new(x, 10.0, -(4.0 + 264.0 * h(2)));
            let d = Vec3::new(-10.0 + 20.0 * h(3), -20.0, -10.0 + 20.0 * h(4));
            let walk = s.occluded(o, d, 0.0, 1.0);
            let before = last;
            assert_eq!(s.occluded_hinted(o, d, 0.0, 1.0, &mut [&mut last, &mut older]), walk, "ray {k}");
            older = before;
            blocked += walk as u32;
        }
        assert!(blocked > 500 && blocked < 3500, "{blocked} of 4000 stopped");
    }
}
