//! Bezier patch tessellation, adaptive like the engine and crack-free across patches.
//!
//! A patch surface is a `w x h` grid of control points (both odd) forming
//! `(w-1)/2 x (h-1)/2` biquadratic Bezier patches. Per direction and per span (one patch
//! wide) we choose breakpoints t in (0, 1):
//!
//! 1. **Adaptive**, like ioquake3's `R_SubdividePatchToGrid`: a segment [a, b] of a span
//!    is split at its middle while, on any line of the grid, the curve point at the
//!    segment's middle, `(q0 + 2 q1 + q2) / 4` of the segment's own control points, lies
//!    farther than the tolerance from the chord's middle (the engine measures from the
//!    chord line instead; see [`segment_error`]). The worst segment is split first, up
//!    to [`MAX_GRID`] grid lines per direction.
//! 2. **Stitched**: a boundary span whose three control points equal a boundary span of
//!    another patch (in either direction and orientation) gets the union of both sets of
//!    breakpoints, repeated until nothing changes. Neighbouring patches therefore place
//!    the same vertices along shared edges.
//! 3. **Exact shared vertices**: breakpoints are dyadic (k / 2^16, exact in f64), and
//!    vertices on a boundary are evaluated from that boundary's three control points
//!    in a canonical order, so both neighbours compute bitwise identical positions.
//! 4. **No T-junctions**: where boundaries touch without sharing control points (a
//!    straight edge with a shifted middle point, an edge covering part of a longer one),
//!    a boundary vertex lying on another patch's boundary edge is inserted into that
//!    edge, bit for bit, and the edge's triangle becomes a fan (repeated until no
//!    vertex is inserted, since an inserted vertex can lie on a third patch's edge).
//!
//! Vertices are evaluated on the true surface (the tensor-product Bezier), with every
//! attribute (normal, texture and lightmap coordinates, colour) interpolated by the same
//! weights. Triangles are emitted in the engine's order (clockwise from the front), like
//! the BSP's own polygons; the caller reverses them for glTF.

use crate::bsp::DrawVert;
use std::collections::{BTreeMap, BTreeSet, HashMap};

/// Breakpoints are integers over this denominator (2^16): exact in f64, and reversal
/// `t -> 1 - t` is exact too.
const DENOM: u32 = 1 << 16;
/// Most grid lines per direction from adaptive subdivision (the engine's MAX_GRID_SIZE
/// is 65; we allow more so that large curved patches still meet the tolerance).
pub const MAX_GRID: usize = 257;

/// Input: one patch surface's control grid (row-major, `width` points per row).
#[derive(Debug, Clone, Copy)]
pub struct PatchInput<'a> {
    pub width: usize,
    pub height: usize,
    pub ctrl: &'a [DrawVert],
}

impl<'a> PatchInput<'a> {
    /// The control grid of a BSP patch surface (sizes and ranges checked by `Bsp::parse`).
    pub fn of(bsp: &'a crate::bsp::Bsp, s: &crate::bsp::Surface) -> Self {
        PatchInput { width: s.patch_w as usize, height: s.patch_h as usize, ctrl: bsp.surface_verts(s) }
    }
}

/// Output: the tessellated grid of one patch surface.
#[derive(Debug, Clone)]
pub struct Tessellated {
    pub width: usize,
    pub height: usize,
    /// Row-major `width x height` grid vertices on the true surface, followed by any
    /// vertices inserted on boundary edges to close T-junctions with neighbours.
    pub verts: Vec<DrawVert>,
    /// Triangles in engine order (clockwise from the front); triangles with two
    /// coincident corners are left out.
    pub indices: Vec<u32>,
    /// Parameter of each grid column: `span + t`, in [0, (control width - 1) / 2].
    pub u_params: Vec<f64>,
    /// Parameter of each grid row, likewise.
    pub v_params: Vec<f64>,
}

impl Tessellated {
    /// Area of the triangles, square Quake units.
    pub fn area(&self) -> f64 {
        self.indices
            .chunks_exact(3)
            .filter_map(|t| {
                let [a, b, c] = [t[0], t[1], t[2]].map(|i| self.verts.get(i as usize).map(pos));
                Some(0.5 * dot_self(cross(sub(b?, a?), sub(c?, a?))).sqrt())
            })
            .sum()
    }
}

impl Tessellated {
    /// The drawn area each control point's Bezier basis function covers, square Quake
    /// units, row-major over the `ctrl_width x ctrl_height` control points: each
    /// triangle's area in thirds to its corners, and a corner's third split over the
    /// control points by their basis weights at its grid parameters (the mass-lumped area
    /// of the interpolation the game draws vertex colours with). A corner inserted on a
    /// boundary edge (past the grid) gives its third to the triangle's first grid corner.
    /// The areas add up to [`Tessellated::area`].
    pub fn control_point_areas(&self, ctrl_width: usize, ctrl_height: usize) -> Vec<f64> {
        let mut out = vec![0.0; ctrl_width * ctrl_height];
        let (nu, nv) = ((ctrl_width.max(3) - 1) / 2, (ctrl_height.max(3) - 1) / 2);
        let grid = self.width * self.height;
        let weights = |i: usize| -> Option<[(usize, f64); 9]> {
            let (u, v) = (*self.u_params.get(i % self.width)?, *self.v_params.get(i / self.width)?);
            let su = (u.floor().max(0.0) as usize).min(nu - 1);
            let sv = (v.floor().max(0.0) as usize).min(nv - 1);
            let (wu, wv) = (bernstein(u - su as f64), bernstein(v - sv as f64));
            Some(std::array::from_fn(|k| ((2 * sv + k / 3) * ctrl_width + 2 * su + k % 3, wv[k / 3] * wu[k % 3])))
        };
        for t in self.indices.chunks_exact(3) {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| self.verts.get(i as usize).map(pos));
            let (Some(a), Some(b), Some(c)) = (a, b, c) else { continue };
            let third = dot_self(cross(sub(b, a), sub(c, a))).sqrt() / 6.0;
            let Some(first) = t.iter().map(|&i| i as usize).find(|&i| i < grid) else { continue };
            for &i in t {
                let i = if (i as usize) < grid { i as usize } else { first };
                for (k, w) in weights(i).into_iter().flatten() {
                    if let Some(o) = out.get_mut(k) {
                        *o += third * w;
                    }
                }
            }
        }
        out
    }
}

fn dot_self(a: Pos) -> f64 {
    dot(a, a)
}

#[derive(Debug, thiserror::Error)]
pub enum PatchError {
    #[error("patch tessellation needs {needed} vertices, over the budget of {budget}")]
    OverBudget { needed: usize, budget: usize },
}

type Pos = [f64; 3];

fn pos(v: &DrawVert) -> Pos {
    [v.xyz[0] as f64, v.xyz[1] as f64, v.xyz[2] as f64]
}

fn sub(a: Pos, b: Pos) -> Pos {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: Pos, b: Pos) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: Pos, b: Pos) -> Pos {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Quadratic Bernstein weights at t.
fn bernstein(t: f64) -> [f64; 3] {
    let s = 1.0 - t;
    [s * s, 2.0 * s * t, t * t]
}

/// Blossom of the quadratic at (a, b): the middle control point of the sub-curve [a, b].
fn blossom(p: [Pos; 3], a: f64, b: f64) -> Pos {
    let w = [(1.0 - a) * (1.0 - b), (1.0 - a) * b + a * (1.0 - b), a * b];
    std::array::from_fn(|k| w[0] * p[0][k] + w[1] * p[1][k] + w[2] * p[2][k])
}

fn eval_curve(p: [Pos; 3], t: f64) -> Pos {
    let w = bernstein(t);
    std::array::from_fn(|k| w[0] * p[0][k] + w[1] * p[1][k] + w[2] * p[2][k])
}

/// Deviation of the sub-curve [a, b] from its chord: the distance between the curve's
/// middle point `(q0 + 2 q1 + q2) / 4` and the chord's middle point. For a quadratic this
/// is the largest distance between the curve and the chord at equal parameters. (The
/// engine measures the middle point's distance from the chord *line*, which misses
/// curves that run along the line unevenly; textures and lightmaps follow the
/// parameterisation, so we bound that too.)
fn segment_error(p: [Pos; 3], a: f64, b: f64) -> f64 {
    let q0 = eval_curve(p, a);
    let q2 = eval_curve(p, b);
    let q1 = blossom(p, a, b);
    let d: Pos = std::array::from_fn(|k| (q0[k] - 2.0 * q1[k] + q2[k]) * 0.25);
    dot(d, d).sqrt()
}

/// Control point of line `line`, position `k` along direction `dir` (0: along a row,
/// i.e. across columns; 1: along a column, across rows).
fn ctrl_at<'a>(p: &PatchInput<'a>, dir: usize, line: usize, k: usize) -> &'a DrawVert {
    if dir == 0 {
        &p.ctrl[line * p.width + k]
    } else {
        &p.ctrl[k * p.width + line]
    }
}

fn lines(p: &PatchInput, dir: usize) -> usize {
    if dir == 0 {
        p.height
    } else {
        p.width
    }
}

fn spans(p: &PatchInput, dir: usize) -> usize {
    (if dir == 0 { p.width } else { p.height } - 1) / 2
}

fn span_curve(p: &PatchInput, dir: usize, line: usize, span: usize) -> [Pos; 3] {
    std::array::from_fn(|k| pos(ctrl_at(p, dir, line, 2 * span + k)))
}

/// Breakpoints of one direction of one patch: per span, interior numerators in (0, DENOM).
type Breaks = Vec<BTreeSet<u32>>;

/// Step 1: adaptive breakpoints for one direction.
fn adaptive(p: &PatchInput, dir: usize, tolerance: f64) -> Breaks {
    let nspans = spans(p, dir);
    let nlines = lines(p, dir);
    let curves: Vec<Vec<[Pos; 3]>> =
        (0..nspans).map(|s| (0..nlines).map(|l| span_curve(p, dir, l, s)).collect()).collect();
    let err = |s: usize, a: u32, b: u32| -> f64 {
        let (a, b) = (a as f64 / DENOM as f64, b as f64 / DENOM as f64);
        curves[s].iter().map(|c| segment_error(*c, a, b)).fold(0.0, f64::max)
    };
    // Segments as (span, a, b, error).
    let mut segs: Vec<(usize, u32, u32, f64)> = (0..nspans).map(|s| (s, 0, DENOM, err(s, 0, DENOM))).collect();
    while segs.len() < MAX_GRID - 1 {
        // Worst segment; ties broken by position, for determinism.
        let Some((i, _)) = segs
            .iter()
            .enumerate()
            .filter(|(_, s)| s.3 > tolerance && s.2 - s.1 >= 2)
            .max_by(|x, y| x.1 .3.total_cmp(&y.1 .3).then(y.0.cmp(&x.0)))
        else {
            break;
        };
        let (s, a, b, _) = segs[i];
        let m = (a + b) / 2;
        segs[i] = (s, a, m, err(s, a, m));
        segs.insert(i + 1, (s, m, b, err(s, m, b)));
    }
    let mut breaks: Breaks = vec![BTreeSet::new(); nspans];
    for (s, a, _, _) in segs {
        if a > 0 {
            breaks[s].insert(a);
        }
    }
    breaks
}

/// Global parameters (span + t) of one direction's grid lines.
fn line_params(b: &Breaks) -> Vec<f64> {
    params(b).iter().map(|&(s, t)| s as f64 + t).collect()
}

/// Largest distance, on a 5x5 lattice of the cell [u0, u1] x [v0, v1], between the true
/// surface and the cell's two triangles at equal parameters, and the same measured on
/// the cell's u edges and v edges alone.
fn cell_error(p: &PatchInput, u0: f64, u1: f64, v0: f64, v1: f64) -> (f64, f64, f64) {
    let c00 = surface_point(p, u0, v0);
    let c01 = surface_point(p, u1, v0);
    let c10 = surface_point(p, u0, v1);
    let c11 = surface_point(p, u1, v1);
    let (mut all, mut eu, mut ev) = (0.0f64, 0.0f64, 0.0f64);
    for i in 0..=4 {
        for j in 0..=4 {
            let (a, b) = (i as f64 / 4.0, j as f64 / 4.0);
            if (i == 0 || i == 4) && (j == 0 || j == 4) {
                continue;
            }
            let truth = surface_point(p, u0 + a * (u1 - u0), v0 + b * (v1 - v0));
            // Triangles (c00, c01, c10) and (c01, c11, c10): the diagonal c01-c10.
            let lin: Pos = if a + b <= 1.0 {
                std::array::from_fn(|k| c00[k] + a * (c01[k] - c00[k]) + b * (c10[k] - c00[k]))
            } else {
                std::array::from_fn(|k| c11[k] + (1.0 - a) * (c10[k] - c11[k]) + (1.0 - b) * (c01[k] - c11[k]))
            };
            let d = sub(truth, lin);
            let e = dot(d, d).sqrt();
            all = all.max(e);
            if j == 0 || j == 4 {
                eu = eu.max(e);
            }
            if i == 0 || i == 4 {
                ev = ev.max(e);
            }
        }
    }
    (all, eu, ev)
}

/// 2D pass: the per-direction criterion bounds the edges of each grid cell, not its
/// inside (a twisted cell deviates in the middle). While a cell's triangles are farther
/// than the tolerance from the surface, split its u or v segment (whichever edge error
/// is larger, both when the twist dominates), all offending cells of a round at once.
fn refine_cells(p: &PatchInput, b: &mut [Breaks; 2], tolerance: f64) {
    for _round in 0..8 {
        let us = line_params(&b[0]);
        let vs = line_params(&b[1]);
        let mut split_u = BTreeSet::new();
        let mut split_v = BTreeSet::new();
        for c in 0..us.len() - 1 {
            for r in 0..vs.len() - 1 {
                let (all, eu, ev) = cell_error(p, us[c], us[c + 1], vs[r], vs[r + 1]);
                if all <= tolerance {
                    continue;
                }
                if eu > 0.5 * tolerance || ev > 0.5 * tolerance {
                    if eu >= ev {
                        split_u.insert(c);
                    } else {
                        split_v.insert(r);
                    }
                } else {
                    split_u.insert(c);
                    split_v.insert(r);
                }
            }
        }
        if split_u.is_empty() && split_v.is_empty() {
            return;
        }
        let mut changed = false;
        for (dir, set, lines) in [(0, split_u, &us), (1, split_v, &vs)] {
            for seg in set {
                if lines.len() + 1 > MAX_GRID {
                    break;
                }
                let (a, c) = (lines[seg], lines[seg + 1]);
                let span = (a.floor() as usize).min(b[dir].len() - 1);
                let (ta, tc) = ((a - span as f64) * DENOM as f64, (c - span as f64) * DENOM as f64);
                let (ta, tc) = (ta.round() as u32, tc.round() as u32);
                if tc - ta >= 2 {
                    b[dir][span].insert((ta + tc) / 2);
                    changed = true;
                }
            }
        }
        if !changed {
            return;
        }
    }
}

/// Exact key of a boundary span: its three control positions as bits, in canonical
/// order, plus whether the canonical order reverses the span.
fn span_key(c: [&DrawVert; 3]) -> ([[u32; 3]; 3], bool) {
    let bits = |v: &DrawVert| v.xyz.map(|x| (x + 0.0).to_bits()); // + 0.0 folds -0 into 0
    let (a, b, c2) = (bits(c[0]), bits(c[1]), bits(c[2]));
    if a <= c2 {
        ([a, b, c2], false)
    } else {
        ([c2, b, a], true)
    }
}

/// Tessellates a set of patch surfaces together, stitching shared edges.
///
/// `tolerance` is in the units of the control points (Quake units for BSP data);
/// `vertex_budget` bounds the total number of output vertices.
pub fn tessellate_all(patches: &[PatchInput], tolerance: f64, vertex_budget: usize) -> Result<Vec<Tessellated>, PatchError> {
    let tolerance = if tolerance.is_finite() && tolerance > 0.0 { tolerance } else { 4.0 };
    let mut breaks: Vec<[Breaks; 2]> = patches
        .iter()
        .map(|p| {
            let mut b = [adaptive(p, 0, tolerance), adaptive(p, 1, tolerance)];
            refine_cells(p, &mut b, tolerance);
            b
        })
        .collect();

    // Step 2: group boundary spans by their exact control points.
    type Member = (usize, usize, usize, bool); // patch, dir, span, reversed
    let mut groups: HashMap<[[u32; 3]; 3], Vec<Member>> = HashMap::new();
    for (pi, p) in patches.iter().enumerate() {
        for dir in 0..2 {
            let last = lines(p, dir) - 1;
            for line in [0, last] {
                for s in 0..spans(p, dir) {
                    let c = [ctrl_at(p, dir, line, 2 * s), ctrl_at(p, dir, line, 2 * s + 1), ctrl_at(p, dir, line, 2 * s + 2)];
                    let (key, rev) = span_key(c);
                    let m = (pi, dir, s, rev);
                    let g = groups.entry(key).or_default();
                    if !g.contains(&m) {
                        g.push(m);
                    }
                }
            }
        }
    }
    let mut shared: Vec<Vec<Member>> = groups.into_values().filter(|g| g.len() > 1).collect();
    shared.sort(); // determinism: HashMap order must not matter
    let flip = |t: u32, rev: bool| if rev { DENOM - t } else { t };
    loop {
        let mut changed = false;
        for g in &shared {
            let union: BTreeSet<u32> =
                g.iter().flat_map(|&(pi, d, s, rev)| breaks[pi][d][s].iter().map(move |&t| flip(t, rev))).collect();
            for &(pi, d, s, rev) in g {
                let mine: BTreeSet<u32> = union.iter().map(|&t| flip(t, rev)).collect();
                if mine != breaks[pi][d][s] {
                    breaks[pi][d][s] = mine;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
    }

    // Budget check before allocating any output.
    let grid_len = |b: &Breaks| 1 + b.iter().map(|s| s.len() + 1).sum::<usize>();
    let needed: usize = breaks.iter().map(|b| grid_len(&b[0]) * grid_len(&b[1])).sum();
    if needed > vertex_budget {
        return Err(PatchError::OverBudget { needed, budget: vertex_budget });
    }

    let mut out: Vec<Tessellated> = patches.iter().zip(&breaks).map(|(p, b)| build_grid(p, b)).collect();
    // An inserted vertex can itself lie on a third patch's edge: repeat until none is
    // inserted (bounded; each pass only adds vertices that already exist elsewhere). The
    // passes share one work budget.
    let mut work_left: u64 = T_JUNCTION_WORK;
    for _ in 0..8 {
        if fix_t_junctions(&mut out, &mut work_left) == 0 {
            break;
        }
    }
    Ok(out)
}

/// Most spatial-hash cells the T-junction passes of one conversion may visit together.
pub const T_JUNCTION_WORK: u64 = 1 << 26;

/// Largest distance (in the units of the positions) at which a boundary vertex of one
/// patch counts as lying on another patch's boundary edge.
const WELD_EPS: f64 = 1e-3;

/// Step 4: boundaries that touch without sharing control points (straight edges whose
/// middle control points differ, or an edge that covers part of a longer one) can still
/// meet with a vertex of one patch inside an edge of the other: a T-junction. Such a
/// vertex is inserted, bit for bit, into the other patch's edge, and the triangle on
/// that edge becomes a fan. Returns the number of vertices inserted.
fn fix_t_junctions(ts: &mut [Tessellated], work_left: &mut u64) -> usize {
    // Boundary edges (used by one triangle) and their triangle, per patch.
    struct Edge {
        patch: usize,
        a: u32,
        b: u32,
    }
    let mut edges = Vec::new();
    let mut boundary_verts: Vec<(usize, [f32; 3])> = Vec::new();
    for (pi, t) in ts.iter().enumerate() {
        let mut count: HashMap<(u32, u32), (usize, usize, u32, u32)> = HashMap::new();
        for (ti, tri) in t.indices.chunks_exact(3).enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let e = count.entry((a.min(b), a.max(b))).or_insert((0, ti, a, b));
                e.0 += 1;
            }
        }
        let mut bset = BTreeSet::new();
        let mut local: Vec<_> = count.into_values().filter(|e| e.0 == 1).collect();
        local.sort_by_key(|e| (e.1, e.2, e.3));
        for (_, _, a, b) in local {
            bset.insert(a);
            bset.insert(b);
            edges.push(Edge { patch: pi, a, b });
        }
        boundary_verts.extend(bset.into_iter().map(|v| (pi, t.verts[v as usize].xyz)));
    }
    if edges.is_empty() {
        return 0;
    }
    let mut inserted = 0;
    // Spatial hash of boundary vertices.
    let cell_size = 32.0;
    let cell = |p: Pos| p.map(|x| (x / cell_size).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, (_, p)) in boundary_verts.iter().enumerate() {
        grid.entry(cell(p.map(|x| x as f64))).or_default().push(i);
    }
    // `work_left`: cells still to visit, at most: hostile geometry leaves T-junctions in
    // place rather than taking unbounded time (real maps use a tiny fraction of this).
    // Per (patch, a, b) boundary edge: vertices to insert, with their fraction along it.
    let mut inserts: BTreeMap<(usize, u32, u32), Vec<(f64, [f32; 3])>> = BTreeMap::new();
    for e in &edges {
        let t = &ts[e.patch];
        let (pa, pb) = (t.verts[e.a as usize].xyz, t.verts[e.b as usize].xyz);
        let (a, b) = (pa.map(|x| x as f64), pb.map(|x| x as f64));
        let ab = sub(b, a);
        let len2 = dot(ab, ab);
        if len2 < 1e-12 {
            continue;
        }
        let (ca, cb) = (cell(a), cell(b));
        let lo: [i64; 3] = std::array::from_fn(|k| ca[k].min(cb[k]).saturating_sub(1));
        let hi: [i64; 3] = std::array::from_fn(|k| ca[k].max(cb[k]).saturating_add(1));
        // The cells of the edge's box, or, when the box holds more cells than there are
        // occupied ones (a long edge: hostile coordinates can make it astronomically
        // long), the occupied cells inside the box. Either way the work per edge is at
        // most the number of occupied cells, and the passes have a budget.
        let box_cells = (0..3).fold(1u64, |n, k| n.saturating_mul(hi[k].abs_diff(lo[k]).saturating_add(1)));
        let cost = box_cells.min(grid.len() as u64);
        if cost > *work_left {
            *work_left = 0;
            break;
        }
        *work_left -= cost;
        let cells: Vec<&Vec<usize>> = if box_cells <= grid.len() as u64 {
            let mut v = Vec::new();
            for x in lo[0]..=hi[0] {
                for y in lo[1]..=hi[1] {
                    for z in lo[2]..=hi[2] {
                        v.extend(grid.get(&[x, y, z]));
                    }
                }
            }
            v
        } else {
            grid.iter().filter(|(c, _)| (0..3).all(|k| (lo[k]..=hi[k]).contains(&c[k]))).map(|(_, v)| v).collect()
        };
        let mut found: Vec<(f64, [f32; 3])> = Vec::new();
        for &vi in cells.into_iter().flatten() {
            let (vp, v) = boundary_verts[vi];
            if vp == e.patch || v == pa || v == pb {
                continue;
            }
            let p = v.map(|x| x as f64);
            let s = dot(sub(p, a), ab) / len2;
            if s <= 1e-6 || s >= 1.0 - 1e-6 {
                continue;
            }
            let q = [a[0] + ab[0] * s, a[1] + ab[1] * s, a[2] + ab[2] * s];
            let d = sub(p, q);
            if dot(d, d) <= WELD_EPS * WELD_EPS && !found.iter().any(|f| f.1 == v) {
                found.push((s, v));
            }
        }
        if !found.is_empty() {
            found.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.map(f32::to_bits).cmp(&y.1.map(f32::to_bits))));
            inserts.insert((e.patch, e.a, e.b), found);
        }
    }
    for ((pi, a, b), found) in inserts {
        let t = &mut ts[pi];
        // The triangle holding the directed edge a -> b now (an earlier split of another
        // edge of the same triangle may have moved it), read as (a, b, c).
        let Some((ti, c)) = t.indices.chunks_exact(3).enumerate().find_map(|(ti, tri)| {
            (0..3).find(|&k| tri[k] == a && tri[(k + 1) % 3] == b).map(|k| (ti, tri[(k + 2) % 3]))
        }) else {
            continue;
        };
        let (va, vb) = (t.verts[a as usize], t.verts[b as usize]);
        let mut chain = vec![a];
        for (s, pos) in found {
            let mut v = lerp_vert(&va, &vb, s);
            v.xyz = pos;
            t.verts.push(v);
            chain.push(t.verts.len() as u32 - 1);
        }
        chain.push(b);
        inserted += chain.len() - 2;
        t.indices[ti * 3..ti * 3 + 3].copy_from_slice(&[chain[0], chain[1], c]);
        for w in chain[1..].windows(2) {
            t.indices.extend_from_slice(&[w[0], w[1], c]);
        }
    }
    inserted
}

fn lerp_vert(a: &DrawVert, b: &DrawVert, s: f64) -> DrawVert {
    let l = |x: f32, y: f32| (x as f64 + (y as f64 - x as f64) * s) as f32;
    let n = [l(a.normal[0], b.normal[0]), l(a.normal[1], b.normal[1]), l(a.normal[2], b.normal[2])];
    let len = (n.iter().map(|x| (*x as f64).powi(2)).sum::<f64>()).sqrt();
    DrawVert {
        xyz: [l(a.xyz[0], b.xyz[0]), l(a.xyz[1], b.xyz[1]), l(a.xyz[2], b.xyz[2])],
        normal: if len > 1e-12 { n.map(|x| (x as f64 / len) as f32) } else { a.normal },
        st: [l(a.st[0], b.st[0]), l(a.st[1], b.st[1])],
        lightmap: [l(a.lightmap[0], b.lightmap[0]), l(a.lightmap[1], b.lightmap[1])],
        color: std::array::from_fn(|k| l(a.color[k] as f32, b.color[k] as f32).round().clamp(0.0, 255.0) as u8),
    }
}

/// (span, t) for each grid line of one direction.
fn params(b: &Breaks) -> Vec<(usize, f64)> {
    let mut out = vec![(0, 0.0)];
    for (s, set) in b.iter().enumerate() {
        out.extend(set.iter().map(|&t| (s, t as f64 / DENOM as f64)));
        out.push((s, 1.0));
    }
    out
}

/// Number of f64 attributes carried per vertex: xyz, normal, st, lightmap, rgba.
const NA: usize = 14;

fn attrs(v: &DrawVert) -> [f64; NA] {
    let mut a = [0.0; NA];
    for k in 0..3 {
        a[k] = v.xyz[k] as f64;
        a[3 + k] = v.normal[k] as f64;
    }
    a[6] = v.st[0] as f64;
    a[7] = v.st[1] as f64;
    a[8] = v.lightmap[0] as f64;
    a[9] = v.lightmap[1] as f64;
    for k in 0..4 {
        a[10 + k] = v.color[k] as f64;
    }
    a
}

/// Weighted sum of three attribute vectors, always in the given order.
fn combine(w: [f64; 3], a: [&[f64; NA]; 3]) -> [f64; NA] {
    std::array::from_fn(|k| w[0] * a[0][k] + w[1] * a[1][k] + w[2] * a[2][k])
}

/// Point on a boundary curve in canonical control order, so that every patch sharing the
/// curve computes the same bits.
fn eval_boundary(c: [&DrawVert; 3], t: f64) -> [f64; NA] {
    let (_, rev) = span_key(c);
    let (c, t) = if rev { ([c[2], c[1], c[0]], 1.0 - t) } else { (c, t) };
    let a = [attrs(c[0]), attrs(c[1]), attrs(c[2])];
    combine(bernstein(t), [&a[0], &a[1], &a[2]])
}

fn build_grid(p: &PatchInput, b: &[Breaks; 2]) -> Tessellated {
    let cols = params(&b[0]);
    let rows = params(&b[1]);
    let (w, h) = (cols.len(), rows.len());
    let ctrl_attrs: Vec<[f64; NA]> = p.ctrl.iter().map(attrs).collect();
    let mut verts = Vec::with_capacity(w * h);
    for (ri, &(sv, tv)) in rows.iter().enumerate() {
        for (ci, &(su, tu)) in cols.iter().enumerate() {
            let a = if ri == 0 || ri == h - 1 {
                let line = if ri == 0 { 0 } else { p.height - 1 };
                eval_boundary(std::array::from_fn(|k| ctrl_at(p, 0, line, 2 * su + k)), tu)
            } else if ci == 0 || ci == w - 1 {
                let line = if ci == 0 { 0 } else { p.width - 1 };
                eval_boundary(std::array::from_fn(|k| ctrl_at(p, 1, line, 2 * sv + k)), tv)
            } else {
                let wu = bernstein(tu);
                let rowv: [[f64; NA]; 3] = std::array::from_fn(|m| {
                    let r = (2 * sv + m) * p.width + 2 * su;
                    combine(wu, [&ctrl_attrs[r], &ctrl_attrs[r + 1], &ctrl_attrs[r + 2]])
                });
                combine(bernstein(tv), [&rowv[0], &rowv[1], &rowv[2]])
            };
            let mut normal = [a[3], a[4], a[5]];
            let len = dot(normal, normal).sqrt();
            if len > 1e-12 {
                normal = normal.map(|x| x / len);
            } else {
                normal = surface_normal(p, su, tu, sv, tv);
            }
            verts.push(DrawVert {
                xyz: [a[0] as f32, a[1] as f32, a[2] as f32],
                normal: normal.map(|x| x as f32),
                st: [a[6] as f32, a[7] as f32],
                lightmap: [a[8] as f32, a[9] as f32],
                color: std::array::from_fn(|k| a[10 + k].round().clamp(0.0, 255.0) as u8),
            });
        }
    }
    let mut indices = Vec::with_capacity((w - 1) * (h - 1) * 6);
    for i in 0..h - 1 {
        for j in 0..w - 1 {
            let v2 = (i * w + j) as u32;
            let v1 = v2 + 1;
            let v3 = v2 + w as u32;
            let v4 = v3 + 1;
            for tri in [[v2, v3, v1], [v1, v3, v4]] {
                let [a, b, c] = tri.map(|k| verts[k as usize].xyz);
                if a != b && b != c && a != c {
                    indices.extend_from_slice(&tri);
                }
            }
        }
    }
    Tessellated {
        width: w,
        height: h,
        verts,
        indices,
        u_params: cols.iter().map(|&(s, t)| s as f64 + t).collect(),
        v_params: rows.iter().map(|&(s, t)| s as f64 + t).collect(),
    }
}

/// Geometric normal from the surface derivatives, oriented like the engine's winding
/// (its front is where the clockwise triangles face), for points where the interpolated
/// vertex normals cancel out.
fn surface_normal(p: &PatchInput, su: usize, tu: f64, sv: usize, tv: f64) -> Pos {
    let du = derivative(p, su, tu, sv, tv, 0);
    let dv = derivative(p, su, tu, sv, tv, 1);
    // Engine triangles (v2, v3, v1): edge to the next row, then to the next column:
    // front normal = dv x du for clockwise-front winding.
    let n = cross(dv, du);
    let len = dot(n, n).sqrt();
    if len > 1e-12 {
        n.map(|x| x / len)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// Partial derivative of the position at (span su + tu, span sv + tv).
pub fn derivative(p: &PatchInput, su: usize, tu: f64, sv: usize, tv: f64, dir: usize) -> Pos {
    let d = |t: f64| [2.0 * (t - 1.0), 2.0 - 4.0 * t, 2.0 * t];
    let (wu, wv) = if dir == 0 { (d(tu), bernstein(tv)) } else { (bernstein(tu), d(tv)) };
    let mut out = [0.0; 3];
    for (m, &wvm) in wv.iter().enumerate() {
        for (n, &wun) in wu.iter().enumerate() {
            let c = pos(&p.ctrl[(2 * sv + m) * p.width + 2 * su + n]);
            for k in 0..3 {
                out[k] += wvm * wun * c[k];
            }
        }
    }
    out
}

/// Position on the true surface at grid parameters (u, v) in span units.
pub fn surface_point(p: &PatchInput, u: f64, v: f64) -> Pos {
    let nu = spans(p, 0);
    let nv = spans(p, 1);
    let su = (u.floor().max(0.0) as usize).min(nu - 1);
    let sv = (v.floor().max(0.0) as usize).min(nv - 1);
    let (wu, wv) = (bernstein(u - su as f64), bernstein(v - sv as f64));
    let mut out = [0.0; 3];
    for (m, &wvm) in wv.iter().enumerate() {
        for (n, &wun) in wu.iter().enumerate() {
            let c = pos(&p.ctrl[(2 * sv + m) * p.width + 2 * su + n]);
            for k in 0..3 {
                out[k] += wvm * wun * c[k];
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f32, y: f32, z: f32) -> DrawVert {
        DrawVert { xyz: [x, y, z], normal: [0.0, 0.0, 1.0], ..Default::default() }
    }

    /// A 3x3 arch: flat in x, curved in y-z.
    fn arch(x0: f32, x1: f32, height: f32) -> Vec<DrawVert> {
        let mut c = Vec::new();
        for (y, z) in [(0.0, 0.0), (64.0, height), (128.0, 0.0)] {
            for x in [x0, (x0 + x1) / 2.0, x1] {
                c.push(v(x, y, z));
            }
        }
        c
    }

    #[test]
    fn flat_patch_is_two_triangles_and_curved_is_subdivided() {
        let flat = arch(0.0, 64.0, 0.0);
        let t = tessellate_all(&[PatchInput { width: 3, height: 3, ctrl: &flat }], 4.0, 1 << 20).unwrap();
        assert_eq!((t[0].width, t[0].height), (2, 2));
        assert_eq!(t[0].indices.len(), 6);
        let curved = arch(0.0, 64.0, 128.0);
        let t = tessellate_all(&[PatchInput { width: 3, height: 3, ctrl: &curved }], 4.0, 1 << 20).unwrap();
        assert_eq!(t[0].width, 2, "straight direction stays at its ends");
        assert!(t[0].height > 4, "curved direction is subdivided: {}", t[0].height);
    }

    /// A flat patch is drawn as two triangles whose corners carry the colours of the four
    /// corner control points: they share the whole area, the others none. A curved one
    /// gives its middle control line a share; the shares always add up to the area.
    #[test]
    fn control_point_areas_add_up_to_the_drawn_area() {
        let flat = arch(0.0, 64.0, 0.0);
        let t = tessellate_all(&[PatchInput { width: 3, height: 3, ctrl: &flat }], 4.0, 1 << 20).unwrap();
        let a = t[0].control_point_areas(3, 3);
        assert!((t[0].area() - 8192.0).abs() < 1e-9);
        // Thirds of each triangle: a corner on both triangles gets a third of the area,
        // one on a single triangle a sixth.
        for (k, &x) in a.iter().enumerate() {
            let ok = if [0, 2, 6, 8].contains(&k) { [8192.0 / 6.0, 8192.0 / 3.0].iter().any(|e| (x - e).abs() < 1e-9) } else { x == 0.0 };
            assert!(ok, "control point {k}: {x}");
        }
        assert!((a.iter().sum::<f64>() - 8192.0).abs() < 1e-9);
        let curved = arch(0.0, 64.0, 128.0);
        let t = tessellate_all(&[PatchInput { width: 3, height: 3, ctrl: &curved }], 1.0, 1 << 20).unwrap();
        let a = t[0].control_point_areas(3, 3);
        assert!((a.iter().sum::<f64>() - t[0].area()).abs() < 1e-6 * t[0].area());
        assert!(a.iter().all(|&x| x >= 0.0) && a[3] > 0.1 * a[0], "{a:?}");
    }

    #[test]
    fn neighbours_with_different_curvature_share_edge_vertices() {
        // Patch A is flat across x; patch B (sharing A's x=64 edge) bends in x, which makes
        // it subdivide more along y than A alone would.
        let a = arch(0.0, 64.0, 32.0);
        let mut b = arch(64.0, 128.0, 32.0);
        for r in 0..3 {
            b[r * 3 + 1].xyz[2] += 200.0; // bulge B's middle column
        }
        let t = tessellate_all(&[PatchInput { width: 3, height: 3, ctrl: &a }, PatchInput { width: 3, height: 3, ctrl: &b }], 1.0, 1 << 20)
            .unwrap();
        let edge_a: Vec<[f32; 3]> = (0..t[0].height).map(|r| t[0].verts[r * t[0].width + t[0].width - 1].xyz).collect();
        let edge_b: Vec<[f32; 3]> = (0..t[1].height).map(|r| t[1].verts[r * t[1].width].xyz).collect();
        assert_eq!(edge_a, edge_b);
    }

    /// Found by fuzzing (a mutated control point of a real map): a patch stretched over
    /// millions of units made the T-junction search enumerate every spatial-hash cell of
    /// each long boundary edge's box (billions per edge): the conversion never finished.
    /// Now the work per edge is bounded by the occupied cells, and the pass by a budget.
    #[test]
    fn huge_patch_is_tessellated_in_bounded_time() {
        let a = arch(0.0, 64.0, 0.0);
        let mut b = arch(64.0, 128.0, 16.0);
        b[8].xyz = [1.0e7, 1.0e7, 1.0e7];
        let t0 = std::time::Instant::now();
        let t = tessellate_all(&[PatchInput { width: 3, height: 3, ctrl: &a }, PatchInput { width: 3, height: 3, ctrl: &b }], 4.0, 1 << 20).unwrap();
        assert!(t0.elapsed() < std::time::Duration::from_secs(5), "{:?}", t0.elapsed());
        assert!(t[1].verts.len() > 100, "the stretched patch is still subdivided");
    }

    #[test]
    fn budget_is_enforced() {
        let curved = arch(0.0, 64.0, 128.0);
        assert!(tessellate_all(&[PatchInput { width: 3, height: 3, ctrl: &curved }], 0.001, 10).is_err());
    }
}
