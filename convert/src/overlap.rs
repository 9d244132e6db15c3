//! Coplanar overlaps: where two opaque surfaces lie on one plane, facing the same way.
//!
//! Quake III maps have them wherever brushes overlap without being clipped against each
//! other (detail brushes, a trim laid over a floor): q3map2 keeps both faces, and the
//! game draws both with the same texture and nearly the same lightmap, so nobody sees
//! it. A ray tracer does: Cycles starts a shadow ray on one face and hits the other at
//! distance zero, and the overlap renders black under every light (oa_dm1's floor by the
//! pillar, issue 12). So the later face gives up the part the earlier ones cover.
//!
//! The cut is exact where it happens: each triangle that loses area is replaced by
//! triangles of what is left (convex pieces, fanned), whose new vertices take every
//! attribute (position, normal, texture and lightmap coordinates, colour) by linear
//! interpolation over the original triangle, so the picture on what is left does not
//! change. A triangle that loses nothing keeps its bits. "The same plane" is a normal
//! within [`NORMAL_TOLERANCE`] and a distance within [`DISTANCE_TOLERANCE_M`]: only
//! faces a ray tracer cannot tell apart; surfaces a fraction of a unit apart are left
//! as they are.

use crate::scene::Primitive;
use std::collections::HashMap;

/// Normals of one plane differ by at most this much per component (unit vectors).
pub const NORMAL_TOLERANCE: f64 = 1e-4;
/// Planes of one group are at most this far apart, metres (0.0008 Quake units at the
/// default scale: far below what a map places on purpose, above f32 rounding).
pub const DISTANCE_TOLERANCE_M: f64 = 2e-5;
/// Overlaps smaller than this (square metres, about 0.0016 square Quake units) are
/// rounding, not overlaps: the triangle is left whole.
pub const MIN_OVERLAP_M2: f64 = 1e-6;
/// Pieces smaller than this (square metres) are dropped rather than written.
const MIN_PIECE_M2: f64 = 1e-10;
/// Most pieces one triangle may be cut into; beyond it the triangle stays whole (a
/// bound on the work a hostile file can ask for).
const MAX_PIECES: usize = 256;
/// Most work one conversion may spend on cutting overlaps, in units of one grid cell
/// visited or one piece-against-cover test (the budget [`cut_coplanar_overlaps`] draws
/// on; the whole budget took 0.38 s on one core of the 2-core EPYC, in the test
/// `a_hostile_stack_stops_at_the_work_budget` at 30 000 triangles). The 85 maps of
/// OpenArena and oacmp1 spend at most 1.2 million (oacmpdm8); a file that asks for more
/// (thousands of triangles on one plane, each cutting the next) keeps the rest of its
/// triangles whole instead of taking minutes (the fuzzer found one that took over 20 s).
pub const WORK_BUDGET: u64 = 10_000_000;

/// What [`cut_coplanar_overlaps`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct OverlapCounts {
    /// Triangles replaced by what an earlier coplanar face leaves of them.
    pub triangles_cut: usize,
    /// Triangles wholly covered by earlier coplanar faces, removed.
    pub triangles_removed: usize,
    /// Triangles left whole because cutting them would take more than `MAX_PIECES`,
    /// or more than what was left of the work budget.
    pub triangles_left: usize,
    /// Work spent, in the units of [`WORK_BUDGET`].
    pub work: u64,
    /// The area removed, square metres.
    pub area_removed_m2: f64,
}

impl std::ops::AddAssign for OverlapCounts {
    fn add_assign(&mut self, o: OverlapCounts) {
        self.triangles_cut += o.triangles_cut;
        self.triangles_removed += o.triangles_removed;
        self.triangles_left += o.triangles_left;
        self.work += o.work;
        self.area_removed_m2 += o.area_removed_m2;
    }
}

type P2 = [f64; 2];

/// Removes, from each triangle of `prims`, the part that an earlier triangle of `prims`
/// covers on the same plane facing the same way. "Earlier" is the order of `prims`, then
/// of their triangles. Every primitive given must be opaque and belong to one model.
/// Only the triangles that `eligible[prim][triangle]` marks take part (missing entries
/// count as eligible): they are neither cut nor cut others.
///
/// `budget` is the work still allowed (start from [`WORK_BUDGET`] and pass the same
/// counter to every call of one conversion); the work done is taken from it. When it
/// runs out, the triangle being cut and every later one are left whole (counted in
/// [`OverlapCounts::triangles_left`]).
pub fn cut_coplanar_overlaps(prims: &mut [&mut Primitive], eligible: &[&[bool]], budget: &mut u64) -> OverlapCounts {
    let mut counts = OverlapCounts::default();
    // Every non-degenerate triangle, with its plane.
    struct Tri {
        prim: usize,
        tri: usize,
        normal: [f64; 3],
        dist: f64,
    }
    let mut tris = Vec::new();
    for (pi, p) in prims.iter().enumerate() {
        let mask = eligible.get(pi).copied().unwrap_or(&[]);
        for t in 0..p.indices.len() / 3 {
            if !mask.get(t).copied().unwrap_or(true) {
                continue;
            }
            let [a, b, c] = corners(p, t);
            let n = cross(sub(b, a), sub(c, a));
            let len = dot(n, n).sqrt();
            if !(len > 1e-12) {
                continue;
            }
            let normal = [n[0] / len, n[1] / len, n[2] / len];
            tris.push(Tri { prim: pi, tri: t, normal, dist: dot(normal, a) });
        }
    }
    // Groups: the same quantised normal, then runs of distances within the tolerance.
    let quant = |x: f64| (x / NORMAL_TOLERANCE).round() as i64;
    let mut by_normal: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, t) in tris.iter().enumerate() {
        by_normal.entry(t.normal.map(quant)).or_default().push(i);
    }
    let mut keys: Vec<[i64; 3]> = by_normal.keys().copied().collect();
    keys.sort_unstable();
    // Cut pieces per (prim, triangle), in the primitives' own 2D projection.
    let mut cuts: Vec<HashMap<usize, (usize, Vec<Vec<P2>>)>> = (0..prims.len()).map(|_| HashMap::new()).collect();
    for key in keys {
        let mut ids = by_normal.remove(&key).unwrap_or_default();
        if ids.len() < 2 {
            continue;
        }
        ids.sort_by(|&a, &b| tris[a].dist.total_cmp(&tris[b].dist).then(a.cmp(&b)));
        let mut start = 0;
        while start < ids.len() {
            let mut end = start + 1;
            while end < ids.len() && tris[ids[end]].dist - tris[ids[end - 1]].dist <= DISTANCE_TOLERANCE_M {
                end += 1;
            }
            if end - start >= 2 {
                let mut group: Vec<usize> = ids[start..end].to_vec();
                group.sort_unstable(); // the triangles' own order: earlier ones win
                let n = tris[group[0]].normal;
                let axis = (0..3).max_by(|&i, &j| n[i].abs().total_cmp(&n[j].abs())).unwrap_or(2);
                let flat: Vec<[P2; 3]> = group.iter().map(|&g| corners(prims[tris[g].prim], tris[g].tri).map(|p| project(p, axis))).collect();
                // The sign of a front-facing triangle's area in this projection.
                let sign = if n[axis] >= 0.0 { 1.0 } else { -1.0 };
                // Areas in this projection are |n[axis]| times the plane's own.
                for (gi, pieces) in cut_group(&flat, sign, 1.0 / n[axis].abs(), budget, &mut counts) {
                    let t = &tris[group[gi]];
                    cuts[t.prim].insert(t.tri, (axis, pieces));
                }
            }
            start = end;
        }
    }
    for (pi, p) in prims.iter_mut().enumerate() {
        if !cuts[pi].is_empty() {
            rebuild(p, &cuts[pi]);
        }
    }
    counts
}

/// The pieces each cut triangle of one plane keeps (group index -> pieces; none when
/// it is wholly covered). Triangles that lose nothing are not listed. Takes its tests
/// from `budget` (see [`cut_coplanar_overlaps`]).
fn cut_group(flat: &[[P2; 3]], sign: f64, to_plane: f64, budget: &mut u64, counts: &mut OverlapCounts) -> Vec<(usize, Vec<Vec<P2>>)> {
    let area_total: f64 = flat.iter().map(|t| (signed_area(t) * sign).max(0.0)).sum();
    let boxes: Vec<(P2, P2)> = flat.iter().map(|t| bounds(t)).collect();
    let mut grid = Grid::new((area_total / flat.len() as f64).sqrt().max(1e-3) * 2.0, &boxes);
    let mut out = Vec::new();
    for (i, tri) in flat.iter().enumerate() {
        let (lo, hi) = boxes[i];
        let Some(candidates) = grid.query(lo, hi, budget, &mut counts.work) else {
            counts.triangles_left += 1;
            continue;
        };
        let mut pieces: Vec<Vec<P2>> = vec![tri.to_vec()];
        let mut cut = false;
        let mut too_many = false;
        for k in candidates {
            let cover = &flat[k];
            let (clo, chi) = boxes[k];
            if clo[0] > hi[0] || clo[1] > hi[1] || chi[0] < lo[0] || chi[1] < lo[1] {
                continue; // a neighbour in the grid, not over this triangle
            }
            if pieces.is_empty() {
                break; // wholly covered already
            }
            if !spend(budget, &mut counts.work, pieces.len()) {
                too_many = true;
                break;
            }
            let mut next = Vec::with_capacity(pieces.len());
            for piece in pieces {
                let inside = clip_to_triangle(&piece, cover, sign);
                if polygon_area(&inside) <= MIN_OVERLAP_M2 {
                    next.push(piece);
                    continue;
                }
                cut = true;
                next.extend(subtract_triangle(piece, cover, sign));
            }
            pieces = next;
            if pieces.len() > MAX_PIECES {
                too_many = true;
                break;
            }
        }
        if too_many {
            counts.triangles_left += 1;
        } else if cut {
            let before = polygon_area(&tri[..]);
            pieces.retain(|p| substantial(p, to_plane));
            let after: f64 = pieces.iter().map(|p| polygon_area(p)).sum();
            counts.area_removed_m2 += (before - after).max(0.0) * to_plane;
            let covered = pieces.is_empty();
            if covered {
                counts.triangles_removed += 1;
            } else {
                counts.triangles_cut += 1;
            }
            out.push((i, pieces));
            if covered {
                continue; // what it covers, earlier triangles cover: later ones test those
            }
        }
        grid.insert(i, lo, hi, budget, &mut counts.work);
    }
    out
}

/// Takes `units` of work from `budget` and adds them to `spent`; false (and the
/// budget emptied) when fewer are left.
fn spend(budget: &mut u64, spent: &mut u64, units: usize) -> bool {
    let units = units as u64;
    if *budget < units {
        *budget = 0;
        return false;
    }
    *budget -= units;
    *spent += units;
    true
}

/// The bounding box (lowest, highest corner) of a triangle in the projection.
fn bounds(t: &[P2; 3]) -> (P2, P2) {
    (
        [t[0][0].min(t[1][0]).min(t[2][0]), t[0][1].min(t[1][1]).min(t[2][1])],
        [t[0][0].max(t[1][0]).max(t[2][0]), t[0][1].max(t[1][1]).max(t[2][1])],
    )
}

/// A uniform grid over one plane's triangles, for the covering candidates of a box.
///
/// Dense over the bounds of the group, at most [`Grid::MAX_GRID_CELLS`] cells; each
/// cell's triangles are a list threaded through one array (`head` -> `entries`), so
/// registering a triangle allocates nothing per cell and hashes nothing: a unit of work
/// costs the same few instructions whatever the input (the budget bounds time, not just
/// steps).
struct Grid {
    /// Lowest corner of the grid, projection metres.
    origin: P2,
    /// Side of one cell, projection metres.
    cell: f64,
    /// Cells along each axis.
    n: [i64; 2],
    /// First entry of each cell's list, `NONE` when empty.
    head: Vec<u32>,
    /// (triangle, next entry of the same cell).
    entries: Vec<(u32, u32)>,
    /// Triangles spanning too many cells to register: always candidates.
    big: Vec<usize>,
}

impl Grid {
    /// Most cells one triangle is registered in; a larger one goes to `big`.
    const MAX_CELLS: i64 = 1024;
    /// Most cells of one grid (4 MB of list heads).
    const MAX_GRID_CELLS: f64 = (1u64 << 20) as f64;
    const NONE: u32 = u32::MAX;

    /// A grid over `boxes` whose cells are about `cell` wide, coarser where that would
    /// take more than `MAX_GRID_CELLS` (or four per triangle) cells.
    fn new(cell: f64, boxes: &[(P2, P2)]) -> Grid {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for (l, h) in boxes {
            for k in 0..2 {
                lo[k] = lo[k].min(l[k]);
                hi[k] = hi[k].max(h[k]);
            }
        }
        if !(lo[0] <= hi[0] && lo[1] <= hi[1]) {
            lo = [0.0; 2];
            hi = [0.0; 2];
        }
        let most = Self::MAX_GRID_CELLS.min(4.0 * boxes.len() as f64).max(1.0);
        let (w, h) = (hi[0] - lo[0], hi[1] - lo[1]);
        // Cells of `cell` would number (w / cell + 1) (h / cell + 1); widen until `most`.
        let mut cell = if cell.is_finite() && cell > 0.0 { cell } else { 1.0 };
        let fits = |c: f64| (w / c + 1.0) * (h / c + 1.0) <= most;
        if !fits(cell) {
            cell = ((w / most).sqrt() * h.sqrt()).max(w / most).max(h / most).max(cell);
            while !fits(cell) && cell.is_finite() {
                cell *= 1.5;
            }
        }
        let count = |x: f64| if cell.is_finite() { ((x / cell).floor() + 1.0).clamp(1.0, most) as i64 } else { 1 };
        let n = [count(w), count(h)];
        let cells = (n[0] * n[1]).max(1) as usize;
        Grid { origin: lo, cell, n, head: vec![Self::NONE; cells], entries: Vec::new(), big: Vec::new() }
    }

    fn range(&self, lo: P2, hi: P2) -> ((i64, i64), (i64, i64)) {
        let c = |x: f64, k: usize| {
            let v = ((x - self.origin[k]) / self.cell).floor();
            if v.is_nan() { 0 } else { v.clamp(0.0, (self.n[k] - 1) as f64) as i64 }
        };
        ((c(lo[0], 0), c(hi[0], 0)), (c(lo[1], 1), c(hi[1], 1)))
    }

    /// Registers triangle `id` over the cells of its box, one unit of work each (a
    /// triangle the budget cannot pay for is not registered: every later one is left
    /// whole anyway).
    fn insert(&mut self, id: usize, lo: P2, hi: P2, budget: &mut u64, spent: &mut u64) {
        let ((x0, x1), (y0, y1)) = self.range(lo, hi);
        let cells = (x1 - x0 + 1).saturating_mul(y1 - y0 + 1);
        if cells > Self::MAX_CELLS || self.entries.len() + cells as usize >= Self::NONE as usize {
            if spend(budget, spent, 1) {
                self.big.push(id);
            }
            return;
        }
        if !spend(budget, spent, cells as usize) {
            return;
        }
        for y in y0..=y1 {
            for x in x0..=x1 {
                let c = (y * self.n[0] + x) as usize;
                self.entries.push((id as u32, self.head[c]));
                self.head[c] = (self.entries.len() - 1) as u32;
            }
        }
    }

    /// Registered triangles whose cells meet the box, each once, in insertion order;
    /// one unit of work per cell and per entry visited. None when the budget cannot pay.
    fn query(&self, lo: P2, hi: P2, budget: &mut u64, spent: &mut u64) -> Option<Vec<usize>> {
        let ((x0, x1), (y0, y1)) = self.range(lo, hi);
        let cells = (x1 - x0 + 1).saturating_mul(y1 - y0 + 1);
        let mut found: Vec<usize> = self.big.clone();
        if cells > Self::MAX_CELLS {
            if !spend(budget, spent, self.big.len() + self.entries.len()) {
                return None;
            }
            found.extend(self.entries.iter().map(|&(id, _)| id as usize));
        } else {
            if !spend(budget, spent, self.big.len() + cells as usize) {
                return None;
            }
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let mut e = self.head[(y * self.n[0] + x) as usize];
                    while e != Self::NONE {
                        if !spend(budget, spent, 1) {
                            return None;
                        }
                        let (id, next) = self.entries[e as usize];
                        found.push(id as usize);
                        e = next;
                    }
                }
            }
        }
        found.sort_unstable();
        found.dedup();
        Some(found)
    }
}

/// `poly` minus the triangle `cover`: up to three convex pieces, each with `poly`'s
/// orientation. `sign` is the sign of the triangles' area in this projection.
fn subtract_triangle(poly: Vec<P2>, cover: &[P2; 3], sign: f64) -> Vec<Vec<P2>> {
    let mut out = Vec::new();
    let mut rest = poly;
    for e in 0..3 {
        let (a, b) = (cover[e], cover[(e + 1) % 3]);
        let (outside, inside) = split(&rest, a, b, sign);
        if polygon_area(&outside) > MIN_PIECE_M2 {
            out.push(outside);
        }
        rest = inside;
        if rest.len() < 3 {
            break;
        }
    }
    out
}

/// `poly` clipped to the triangle `cover`.
fn clip_to_triangle(poly: &[P2], cover: &[P2; 3], sign: f64) -> Vec<P2> {
    let mut rest = poly.to_vec();
    for e in 0..3 {
        rest = split(&rest, cover[e], cover[(e + 1) % 3], sign).1;
        if rest.len() < 3 {
            return Vec::new();
        }
    }
    rest
}

/// A convex polygon split by the line `a -> b`: (the part outside, the part inside),
/// inside being the side where a front-facing triangle with edge `a -> b` lies.
fn split(poly: &[P2], a: P2, b: P2, sign: f64) -> (Vec<P2>, Vec<P2>) {
    let side = |p: P2| sign * ((b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]));
    let (mut outside, mut inside) = (Vec::new(), Vec::new());
    for i in 0..poly.len() {
        let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
        let (sp, sq) = (side(p), side(q));
        if sp >= 0.0 {
            inside.push(p);
        }
        if sp <= 0.0 {
            outside.push(p);
        }
        if (sp > 0.0 && sq < 0.0) || (sp < 0.0 && sq > 0.0) {
            let t = sp / (sp - sq);
            let x = [p[0] + (q[0] - p[0]) * t, p[1] + (q[1] - p[1]) * t];
            inside.push(x);
            outside.push(x);
        }
    }
    (outside, inside)
}

/// A piece worth writing: area above `MIN_PIECE_M2` and wider than `MIN_WIDTH_M` (a
/// sliver thinner than that is f32 rounding, not surface; `to_plane` undoes the
/// projection's foreshortening of the area).
fn substantial(p: &[P2], to_plane: f64) -> bool {
    let area = polygon_area(p) * to_plane;
    let longest = (0..p.len()).map(|i| {
        let (a, b) = (p[i], p[(i + 1) % p.len()]);
        ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt()
    }).fold(0.0f64, f64::max) * to_plane;
    area > MIN_PIECE_M2 && area > MIN_WIDTH_M * longest
}

/// Pieces thinner than this (metres: area over longest edge) are dropped.
const MIN_WIDTH_M: f64 = 1e-4;

fn signed_area(p: &[P2]) -> f64 {
    let mut s = 0.0;
    for i in 0..p.len() {
        let (a, b) = (p[i], p[(i + 1) % p.len()]);
        s += a[0] * b[1] - b[0] * a[1];
    }
    0.5 * s
}

/// Area of a polygon in the projection, square metres of the projection (within a
/// factor `1 / |n[axis]|` >= 1 of the plane's own: the thresholds are conservative).
fn polygon_area(p: &[P2]) -> f64 {
    if p.len() < 3 {
        0.0
    } else {
        signed_area(p).abs()
    }
}

/// Replaces the cut triangles of `p` by their pieces (see the module docs).
fn rebuild(p: &mut Primitive, cuts: &HashMap<usize, (usize, Vec<Vec<P2>>)>) {
    let old = std::mem::take(&mut p.indices);
    let mut indices = Vec::with_capacity(old.len());
    for (t, tri) in old.chunks_exact(3).enumerate() {
        let Some((axis, pieces)) = cuts.get(&t) else {
            indices.extend_from_slice(tri);
            continue;
        };
        let idx = [tri[0] as usize, tri[1] as usize, tri[2] as usize];
        let pos = idx.map(|i| p.positions[i].map(f64::from));
        let flat = pos.map(|q| project(q, *axis));
        let whole = signed_area(&flat);
        if whole == 0.0 {
            continue; // unreachable: degenerate triangles are never cut
        }
        for piece in pieces {
            let verts: Vec<u32> = piece.iter().map(|&q| vertex_at(p, idx, &flat, whole, q)).collect();
            for k in 1..verts.len() - 1 {
                let (a, b, c) = (piece[0], piece[k], piece[k + 1]);
                if substantial(&[a, b, c], 1.0) {
                    indices.extend_from_slice(&[verts[0], verts[k], verts[k + 1]]);
                }
            }
        }
    }
    p.indices = indices;
}

/// The vertex at projected point `q` of the triangle `idx`: an existing corner when `q`
/// is one, otherwise a new vertex with every attribute interpolated.
fn vertex_at(p: &mut Primitive, idx: [usize; 3], flat: &[P2; 3], whole: f64, q: P2) -> u32 {
    let w = [
        signed_area(&[q, flat[1], flat[2]]) / whole,
        signed_area(&[flat[0], q, flat[2]]) / whole,
        signed_area(&[flat[0], flat[1], q]) / whole,
    ];
    for k in 0..3 {
        if q == flat[k] {
            return idx[k] as u32;
        }
    }
    let mix3 = |a: &[[f32; 3]]| -> [f64; 3] {
        let mut s = [0.0; 3];
        for k in 0..3 {
            for c in 0..3 {
                s[c] += w[k] * f64::from(a[idx[k]][c]);
            }
        }
        s
    };
    let mix2 = |a: &[[f32; 2]]| -> [f32; 2] {
        let mut s = [0.0f64; 2];
        for k in 0..3 {
            for c in 0..2 {
                s[c] += w[k] * f64::from(a[idx[k]][c]);
            }
        }
        s.map(|x| x as f32)
    };
    let position = mix3(&p.positions).map(|x| x as f32);
    let n = mix3(&p.normals);
    let len = dot(n, n).sqrt();
    let normal = if len > 1e-9 {
        n.map(|x| (x / len) as f32)
    } else {
        p.normals[idx[0]]
    };
    let uv0 = mix2(&p.uv0);
    let uv1 = p.uv1.as_ref().map(|uv| mix2(uv));
    let color = p.colors.as_ref().map(|col| {
        let mut s = [0.0f64; 4];
        for k in 0..3 {
            for c in 0..4 {
                s[c] += w[k] * f64::from(col[idx[k]][c]);
            }
        }
        s.map(|x| x.round().clamp(0.0, 255.0) as u8)
    });
    p.positions.push(position);
    p.normals.push(normal);
    p.uv0.push(uv0);
    if let (Some(v), Some(x)) = (p.uv1.as_mut(), uv1) {
        v.push(x);
    }
    if let (Some(v), Some(x)) = (p.colors.as_mut(), color) {
        v.push(x);
    }
    (p.positions.len() - 1) as u32
}

fn corners(p: &Primitive, t: usize) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|k| p.positions[p.indices[3 * t + k] as usize].map(f64::from))
}

/// The point in the plane of the two axes other than `axis`, in cyclic order (so a
/// triangle's projected area has the sign of its normal's `axis` component).
fn project(p: [f64; 3], axis: usize) -> P2 {
    [p[(axis + 1) % 3], p[(axis + 2) % 3]]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A quad on the plane y = `y` (glTF axes, facing +y), from (x0, z0) to (x1, z1),
    /// with uv0 = (x, z) and uv1 = (x, z) / 10.
    fn quad(p: &mut Primitive, x0: f32, z0: f32, x1: f32, z1: f32, y: f32) {
        let base = p.positions.len() as u32;
        for (x, z) in [(x0, z0), (x1, z0), (x1, z1), (x0, z1)] {
            p.positions.push([x, y, z]);
            p.normals.push([0.0, 1.0, 0.0]);
            p.uv0.push([x, z]);
            p.uv1.get_or_insert_with(Vec::new).push([x / 10.0, z / 10.0]);
        }
        // Facing +y: (x0,z0) -> (x0,z1) -> (x1,z1) is counter-clockwise seen from above.
        p.indices.extend_from_slice(&[base, base + 3, base + 2, base, base + 2, base + 1]);
    }

    fn area_and_normals(p: &Primitive) -> (f64, bool) {
        let mut area = 0.0;
        let mut up = true;
        for t in 0..p.indices.len() / 3 {
            let [a, b, c] = corners(p, t);
            let n = cross(sub(b, a), sub(c, a));
            area += 0.5 * dot(n, n).sqrt();
            up &= n[1] > 0.0;
        }
        (area, up)
    }

    #[test]
    fn the_later_face_gives_up_what_the_earlier_covers() {
        let mut floor = Primitive::default();
        quad(&mut floor, 0.0, 0.0, 2.0, 2.0, 1.0);
        let mut trim = Primitive::default();
        quad(&mut trim, 1.0, 0.5, 3.0, 1.5, 1.0); // half of it on the floor
        let before = area_and_normals(&trim).0;
        let counts = cut_coplanar_overlaps(&mut [&mut floor, &mut trim], &[], &mut WORK_BUDGET.clone());
        assert_eq!(counts.triangles_removed, 0);
        assert!(counts.triangles_cut >= 1, "{counts:?}");
        assert!((counts.area_removed_m2 - 1.0).abs() < 1e-9, "{counts:?}");
        let (after, up) = area_and_normals(&trim);
        assert!((before - after - 1.0).abs() < 1e-9, "trim {before} -> {after}");
        assert!(up, "the pieces keep the winding");
        assert_eq!(area_and_normals(&floor).0, 4.0, "the earlier face is untouched");
        // Every vertex used kept its attributes' linear relation to its position.
        for &i in &trim.indices {
            let (i, q) = (i as usize, trim.positions[i as usize]);
            assert!(q[0] >= 2.0 - 1e-6, "no piece of the trim is left on the floor: {q:?}");
            assert!((trim.uv0[i][0] - q[0]).abs() < 1e-6 && (trim.uv0[i][1] - q[2]).abs() < 1e-6);
            let uv1 = trim.uv1.as_ref().unwrap()[i];
            assert!((uv1[0] - q[0] / 10.0).abs() < 1e-6 && (uv1[1] - q[2] / 10.0).abs() < 1e-6);
            assert_eq!(trim.normals[i], [0.0, 1.0, 0.0]);
        }
    }

    #[test]
    fn a_face_wholly_covered_is_removed_and_neighbours_are_untouched() {
        let mut floor = Primitive::default();
        quad(&mut floor, 0.0, 0.0, 2.0, 2.0, 1.0);
        quad(&mut floor, 2.0, 0.0, 4.0, 2.0, 1.0); // shares an edge: no overlap
        let mut patch = Primitive::default();
        quad(&mut patch, 0.5, 0.5, 1.5, 1.5, 1.0);
        let floor_before = floor.clone();
        let counts = cut_coplanar_overlaps(&mut [&mut floor, &mut patch], &[], &mut WORK_BUDGET.clone());
        assert_eq!(counts.triangles_removed, 2, "{counts:?}");
        assert!(patch.indices.is_empty());
        assert_eq!(floor.indices, floor_before.indices);
        assert_eq!(floor.positions, floor_before.positions);
    }

    #[test]
    fn planes_apart_or_facing_away_are_not_cut() {
        let mut floor = Primitive::default();
        quad(&mut floor, 0.0, 0.0, 2.0, 2.0, 1.0);
        let mut above = Primitive::default();
        quad(&mut above, 0.0, 0.0, 2.0, 2.0, 1.001); // a millimetre above
        let mut under = Primitive::default();
        quad(&mut under, 0.0, 0.0, 2.0, 2.0, 1.0);
        for t in under.indices.chunks_exact_mut(3) {
            t.swap(1, 2); // facing down
        }
        let counts = cut_coplanar_overlaps(&mut [&mut floor, &mut above, &mut under], &[], &mut WORK_BUDGET.clone());
        assert_eq!(OverlapCounts { work: 0, ..counts }, OverlapCounts::default());
    }

    #[test]
    fn triangles_not_eligible_neither_cut_nor_are_cut() {
        let mut floor = Primitive::default();
        quad(&mut floor, 0.0, 0.0, 2.0, 2.0, 1.0);
        let mut model = Primitive::default();
        quad(&mut model, 0.5, 0.5, 1.5, 1.5, 1.0);
        let counts = cut_coplanar_overlaps(&mut [&mut floor, &mut model], &[&[true, true], &[false, false]], &mut WORK_BUDGET.clone());
        assert_eq!(OverlapCounts { work: 0, ..counts }, OverlapCounts::default());
        assert_eq!(model.indices.len(), 6);
    }

    #[test]
    fn many_overlapping_faces_leave_the_union() {
        // 40 strips over one floor, each overlapping the next: the union is what is left.
        let mut prims: Vec<Primitive> = (0..40)
            .map(|i| {
                let mut p = Primitive::default();
                quad(&mut p, i as f32 * 0.25, 0.0, i as f32 * 0.25 + 1.0, 1.0, 0.0);
                p
            })
            .collect();
        let mut refs: Vec<&mut Primitive> = prims.iter_mut().collect();
        let counts = cut_coplanar_overlaps(&mut refs, &[], &mut WORK_BUDGET.clone());
        let total: f64 = prims.iter().map(|p| area_and_normals(p).0).sum();
        let union = 39.0 * 0.25 + 1.0;
        assert!((total - union).abs() < 1e-6, "{total} vs {union}, {counts:?}");
        assert!((counts.area_removed_m2 - (40.0 - union)).abs() < 1e-6);
    }

    /// Triangles turning about one point on one plane: each cuts every later one into
    /// pieces, so without a budget the work grows as the square of their number.
    fn fan_of_turned_triangles(n: usize) -> Primitive {
        let mut p = Primitive::default();
        for i in 0..n {
            let a = i as f64 * 0.7;
            let base = p.positions.len() as u32;
            for k in 0..3 {
                let t = a + k as f64 * std::f64::consts::TAU / 3.0;
                let (x, z) = ((2.0 * t.cos()) as f32, (2.0 * t.sin()) as f32);
                p.positions.push([x, 0.0, z]);
                p.normals.push([0.0, 1.0, 0.0]);
                p.uv0.push([x, z]);
            }
            // Counter-clockwise seen from +y is (x, z) turning from z towards x: reversed.
            p.indices.extend_from_slice(&[base, base + 2, base + 1]);
        }
        p
    }

    #[test]
    fn a_hostile_stack_stops_at_the_work_budget() {
        let mut p = fan_of_turned_triangles(3000);
        let before = area_and_normals(&p);
        assert!(before.1, "the fan faces +y");
        let mut budget = 100_000;
        let counts = cut_coplanar_overlaps(&mut [&mut p], &[], &mut budget);
        assert_eq!(budget, 0, "{counts:?}");
        assert!(counts.work <= 100_000, "{counts:?}");
        assert!(counts.triangles_left > 1000, "the triangles past the budget stay whole: {counts:?}");
        assert!(counts.triangles_cut + counts.triangles_removed > 10, "{counts:?}");
        // What was cut is still on the plane, facing the same way.
        assert!(area_and_normals(&p).1);
    }

    #[test]
    fn a_stack_of_one_triangle_costs_work_linear_in_its_copies() {
        // Copies wholly covered are not registered as covers: 1000 copies of one
        // triangle take a few units of work each (one cell, one entry, one test), not
        // the half a million tests of each copy against every earlier one.
        let mut p = Primitive::default();
        quad(&mut p, 0.0, 0.0, 1.0, 1.0, 0.0);
        p.indices.truncate(3);
        let tri = p.indices.clone();
        for _ in 1..1000 {
            p.indices.extend_from_slice(&tri);
        }
        let counts = cut_coplanar_overlaps(&mut [&mut p], &[], &mut WORK_BUDGET.clone());
        assert_eq!(counts.triangles_removed, 999, "{counts:?}");
        assert!(counts.work <= 4 * 1000, "{counts:?}");
        assert_eq!(p.indices, tri);
    }
}
