//! q3map2's bounce lights: the pieces each pass of its radiosity re-emits from
//! (`-bounce N`; `RadCreateDiffuseLights`, `RadSubdivideDiffuseLight`, `RadSample` in its
//! `light_bounce.cpp`).
//!
//! Between passes q3map2 turns every drawn triangle of a lit, opaque, non-sky surface
//! into area lights. A triangle is cut in two at the middle of its bounds, along the first
//! of Quake's x, y, z on which it spans more than [`SUBDIVIDE_UNITS`], and each half again,
//! until no extent passes it (a vertex within [`area::CLIP_EPSILON_UNITS`] of a cut goes to both
//! halves). A piece under [`MIN_AREA_UNITS2`] emits nothing. Every other piece emits one
//! colour over its whole area: the average of the pass's reflected light at its sample
//! points,
//!
//! ```text
//! colour(piece) = 1/S sum_s rho(s) T(s)
//! ```
//!
//! where the samples of a lightmapped piece are the luxels under the points
//! `(i a + j b + k c) / (i + j + k)`, `i, j, k` in `1..GRANULARITY`, of each triangle
//! `(a, b, c)` of the piece's fan (duplicates counted, unlit luxels skipped, at most
//! [`MAX_SAMPLES`] in all, so a quad's second triangle adds 25 to its first's 125), and
//! those of a vertex-lit piece its corners (their colours interpolated along the cuts).
//!
//! So a ray that lands on a wall brings that piece's average, not the light where it
//! landed: a floor's corner row sees the wall's bright middle as much as its dim foot.
//! Against q3map2 `-bounce 2` in a box (fixture `bounce`), bouncing the light where each
//! ray lands left the corners 20% dark.
//!
//! [`Pieces::locate`] finds the piece under a point of a triangle (the cuts as a tree),
//! and [`Pieces::emit`] is the averaging, a [`Sparse`] operator from rows to pieces.

use std::collections::HashMap;

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};

use crate::model::area::{self, bounds, clip, split, Corner};
use crate::model::compile::Sparse;
use crate::rows::Rows;
use crate::scene::{Lighting, Scene};

/// Pieces are cut until no extent along Quake's axes passes this (`diffuseSubdivide`;
/// a shader's `q3map_lightSubdivide` is not read).
pub const SUBDIVIDE_UNITS: f32 = 256.0;
/// A piece with less area emits nothing, units^2.
pub const MIN_AREA_UNITS2: f32 = 1.0;
/// The barycentric sample weights of a fan triangle run over `1..GRANULARITY`.
pub const GRANULARITY: u32 = 6;
/// Most lit samples a piece averages.
pub const MAX_SAMPLES: usize = 150;
/// A bounce light's strength per unit of form factor in q3map2's light (`light.add`:
/// `RADIOSITY_VALUE 500 x 0.375 x formFactorValueScale 3 x -bouncescale 0.25`), which
/// `-fast` compares with its falloff tolerance (the piece's colour is not counted).
pub const ADD_PER_FORM_FACTOR: f32 = 500.0 * 0.375 * 3.0 * 0.25;
/// Cuts deeper than this (a triangle of non-finite or absurd size) stop.
const MAX_DEPTH: usize = area::MAX_DEPTH;
const NONE: u32 = u32::MAX;
/// Cuts in all, every triangle's together. A real map's lit surfaces make a few tens of
/// thousands (oacmpdm1: 23 370 pieces); past this budget (a hostile file's huge
/// triangles) the windings left stay whole, so the pieces' memory stays bounded (which
/// ones then depends on the threads' order; no real map comes near it).
pub const CUT_BUDGET: usize = 1 << 22;

#[derive(Debug, Clone, Copy)]
enum Node {
    /// A cut: points with `p[axis] > dist` lie in `front`.
    Cut { axis: u8, dist: f32, front: u32, back: u32 },
    /// A piece (`NONE`: one that emits nothing).
    Piece(u32),
}

/// Every triangle's pieces and what each emits.
#[derive(Debug, Clone, Default)]
pub struct Pieces {
    /// Each mesh triangle's first node (`NONE`: the triangle emits nothing).
    root: Vec<u32>,
    nodes: Vec<Node>,
    /// Pieces x rows: each piece's colour as the average of its samples' rows (the
    /// reflectance is the caller's column factor).
    pub emit: Sparse,
    /// Each piece's light origin (its corners' mean, 1 unit along its normal), m.
    pub origin: Vec<Vec3>,
    /// Each piece's reach from its origin, m: with `-fast` the first distance along its
    /// normal (100 units, then steps of 10) where its on-axis form factor gives at most
    /// the falloff tolerance (`SetupEnvelopes`), else unbounded.
    pub envelope: Vec<f32>,
}

/// What one triangle contributes: its nodes (indices local to it) and its pieces' rows.
struct Local {
    nodes: Vec<Node>,
    pieces: Vec<Vec<(u32, f32)>>,
    /// Each piece's origin and envelope.
    reach: Vec<(Vec3, f32)>,
}

impl Pieces {
    /// Cuts every triangle of `scene` that bounces light into q3map2's pieces and finds
    /// each piece's samples among `rows` (luxel rows by texel, vertex rows by vertex).
    /// `fast`: the compile's `-fast` (or `-fastbounce`), which bounds each piece's reach.
    pub fn build(scene: &Scene, rows: &Rows, fast: bool) -> Pieces {
        let mesh = &scene.mesh;
        let u = scene.units_m.max(f32::MIN_POSITIVE);
        let luxel: HashMap<[u32; 3], u32> = (0..rows.len()).filter(|&i| rows.texel[i][0] != u32::MAX).map(|i| (rows.texel[i], i as u32)).collect();
        let vertex_row: HashMap<u32, u32> = (0..rows.len()).filter(|&i| rows.vertex[i] != u32::MAX).map(|i| (rows.vertex[i], i as u32)).collect();
        let cuts_left = AtomicUsize::new(CUT_BUDGET);
        let ctx = Ctx { scene, rows, luxel: &luxel, vertex_row: &vertex_row, subdivide: SUBDIVIDE_UNITS * u, epsilon: area::CLIP_EPSILON_UNITS * u, min_area: MIN_AREA_UNITS2 * u * u, units_m: u, fast, cuts_left: &cuts_left };
        let locals: Vec<Option<Local>> = (0..mesh.triangles.len()).into_par_iter().map(|t| ctx.triangle(t)).collect();
        let mut out = Pieces { root: Vec::with_capacity(locals.len()), nodes: Vec::new(), emit: Sparse::empty(), origin: Vec::new(), envelope: Vec::new() };
        let mut pieces = 0u32;
        for local in locals {
            let Some(local) = local else {
                out.root.push(NONE);
                continue;
            };
            let base = out.nodes.len() as u32;
            out.root.push(base);
            out.nodes.extend(local.nodes.iter().map(|n| match *n {
                Node::Cut { axis, dist, front, back } => Node::Cut { axis, dist, front: front + base, back: back + base },
                Node::Piece(NONE) => Node::Piece(NONE),
                Node::Piece(p) => Node::Piece(p + pieces),
            }));
            pieces += local.pieces.len() as u32;
            for row in local.pieces {
                out.emit.push_row(row);
            }
            for (o, e) in local.reach {
                out.origin.push(o);
                out.envelope.push(e);
            }
        }
        out
    }

    /// The number of pieces that emit.
    pub fn len(&self) -> usize {
        self.emit.rows()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The emitting piece of triangle `tri` under `p` (a point on it), if any.
    pub fn locate(&self, tri: usize, p: Vec3) -> Option<u32> {
        let mut node = *self.root.get(tri)?;
        for _ in 0..=MAX_DEPTH {
            match *self.nodes.get(node as usize)? {
                Node::Cut { axis, dist, front, back } => node = if p[axis as usize] > dist { front } else { back },
                Node::Piece(NONE) => return None,
                Node::Piece(piece) => return Some(piece),
            }
        }
        None
    }
}

struct Ctx<'a> {
    scene: &'a Scene,
    rows: &'a Rows,
    luxel: &'a HashMap<[u32; 3], u32>,
    vertex_row: &'a HashMap<u32, u32>,
    /// [`SUBDIVIDE_UNITS`], [`area::CLIP_EPSILON_UNITS`] and [`MIN_AREA_UNITS2`] in meters.
    subdivide: f32,
    epsilon: f32,
    min_area: f32,
    units_m: f32,
    fast: bool,
    /// Cuts left in all ([`CUT_BUDGET`]).
    cuts_left: &'a AtomicUsize,
}

impl Ctx<'_> {
    /// Triangle `t`'s pieces, or `None` where it bounces nothing (sky, unlit, no rows).
    fn triangle(&self, t: usize) -> Option<Local> {
        let mesh = &self.scene.mesh;
        let mat = self.scene.materials.get(*mesh.tri_material.get(t)? as usize)?;
        let lit = match mat.lighting {
            Lighting::Lightmap => mat.lightmap.is_some(),
            Lighting::Vertex => true,
            _ => false,
        };
        if mat.sky || !lit {
            return None;
        }
        let v = mesh.triangles[t].map(|i| mesh.positions[i as usize]);
        let corners = [Corner { p: v[0], bary: [1.0, 0.0, 0.0] }, Corner { p: v[1], bary: [0.0, 1.0, 0.0] }, Corner { p: v[2], bary: [0.0, 0.0, 1.0] }];
        let mut local = Local { nodes: Vec::new(), pieces: Vec::new(), reach: Vec::new() };
        self.subdivide(t, &corners, 0, &mut local);
        Some(local)
    }

    /// Cuts `w` (`RadSubdivideDiffuseLight`) and returns its node's index in `local`.
    fn subdivide(&self, t: usize, w: &[Corner], depth: usize, local: &mut Local) -> u32 {
        let at = local.nodes.len() as u32;
        local.nodes.push(Node::Piece(NONE));
        if w.len() < 3 {
            return at;
        }
        let cut = split(w, self.subdivide).filter(|_| depth < MAX_DEPTH && self.cuts_left.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| n.checked_sub(1)).is_ok());
        if let Some((axis, dist)) = cut {
            let (front, back) = clip(w, axis, dist, self.epsilon);
            let front = self.subdivide(t, &front, depth + 1, local);
            let back = self.subdivide(t, &back, depth + 1, local);
            local.nodes[at as usize] = Node::Cut { axis: axis as u8, dist, front, back };
            return at;
        }
        let (lo, hi) = bounds(w);
        let area: f32 = (2..w.len()).map(|i| 0.5 * (w[i - 1].p - w[0].p).cross(w[i].p - w[0].p).length()).sum();
        if !(area >= self.min_area) || !lo.is_finite() || !hi.is_finite() {
            return at;
        }
        // The mean of the corners' normals (q3map2's vertex normals; the mesh's here).
        let mesh = &self.scene.mesh;
        let normal: Vec3 = w.iter().map(|c| (0..3).map(|k| mesh.normals[mesh.triangles[t][k] as usize] * c.bary[k]).sum::<Vec3>()).sum::<Vec3>().normalize_or_zero();
        if normal == Vec3::ZERO {
            return at;
        }
        let samples = self.samples(t, w);
        if !samples.is_empty() {
            let u = self.units_m;
            let origin = w.iter().map(|c| c.p).sum::<Vec3>() / w.len() as f32 + normal * (crate::scene::q3map2::AREA_ORIGIN_OFFSET_UNITS * u);
            let envelope = if self.fast { envelope(w, origin, normal, u) } else { f32::INFINITY };
            local.pieces.push(samples);
            local.reach.push((origin, envelope));
            local.nodes[at as usize] = Node::Piece(local.pieces.len() as u32 - 1);
        }
        at
    }

    /// The rows piece `w` of triangle `t` averages, with their weights (`RadSample`).
    fn samples(&self, t: usize, w: &[Corner]) -> Vec<(u32, f32)> {
        let mesh = &self.scene.mesh;
        let tri = mesh.triangles[t];
        let mat_index = mesh.tri_material[t];
        let mat = &self.scene.materials[mat_index as usize];
        let mut acc: Vec<(u32, f32)> = Vec::new();
        let mut add = |j: u32, wt: f32| match acc.iter_mut().find(|e| e.0 == j) {
            Some(e) => e.1 += wt,
            None => acc.push((j, wt)),
        };
        let mut total = 0.0f32;
        match (mat.lighting, mat.lightmap) {
            (Lighting::Lightmap, Some(lm)) => {
                let Some(tx) = self.scene.textures.get(lm) else { return Vec::new() };
                let uv_at = |b: [f32; 3]| -> Vec2 { (0..3).map(|k| mesh.uv1[tri[k] as usize] * b[k]).sum() };
                let mut count = 0usize;
                'fan: for v in 1..w.len() - 1 {
                    let fan = [w[0].bary, w[v].bary, w[v + 1].bary];
                    for i in 1..GRANULARITY {
                        for j in 1..GRANULARITY {
                            for k in 1..GRANULARITY {
                                if count >= MAX_SAMPLES {
                                    break 'fan;
                                }
                                let s = (i + j + k) as f32;
                                let blend = [i as f32 / s, j as f32 / s, k as f32 / s];
                                let b = [0, 1, 2].map(|c| blend[0] * fan[0][c] + blend[1] * fan[1][c] + blend[2] * fan[2][c]);
                                let uv = uv_at(b);
                                let x = ((uv.x * tx.width as f32).floor() as i64).clamp(0, tx.width.max(1) as i64 - 1) as u32;
                                let y = ((uv.y * tx.height as f32).floor() as i64).clamp(0, tx.height.max(1) as i64 - 1) as u32;
                                // An unlit luxel (none of this surface's rows) is skipped.
                                let Some(&row) = self.luxel.get(&[lm as u32, x, y]) else { continue };
                                if self.rows.material[row as usize] != mat_index {
                                    continue;
                                }
                                count += 1;
                                add(row, 1.0);
                            }
                        }
                    }
                }
                total = count as f32;
            }
            (Lighting::Vertex, _) => {
                // Each corner's colour, interpolated from the triangle's vertices.
                for c in w {
                    let present: f32 = (0..3).filter(|&k| self.vertex_row.contains_key(&tri[k])).map(|k| c.bary[k]).sum();
                    if !(present > 0.0) {
                        continue;
                    }
                    for k in 0..3 {
                        if let Some(&row) = self.vertex_row.get(&tri[k]) {
                            if c.bary[k] > 0.0 {
                                add(row, c.bary[k] / present);
                            }
                        }
                    }
                    total += 1.0;
                }
            }
            _ => {}
        }
        if !(total > 0.0) {
            return Vec::new();
        }
        acc.iter_mut().for_each(|e| e.1 /= total);
        acc.sort_by_key(|e| e.0);
        acc
    }
}

/// q3map2's reach of an area light under `-fast` (`SetupEnvelopes`): from 100 units out
/// along its normal, in steps of 10, the first distance from `origin` where the form
/// factor of the piece, facing it, times [`ADD_PER_FORM_FACTOR`] is at most the falloff
/// tolerance; m.
fn envelope(w: &[Corner], origin: Vec3, normal: Vec3, units_m: f32) -> f32 {
    const FIRST_UNITS: f32 = 100.0;
    const STEP_UNITS: f32 = 10.0;
    const LAST_UNITS: f32 = 65536.0 * 8.0;
    let verts: Vec<Vec3> = w.iter().map(|c| c.p).collect();
    let mut radius = FIRST_UNITS;
    while radius < LAST_UNITS {
        let at = origin + normal * (radius * units_m);
        let ff = area::form_factor(at, -normal, &verts).abs();
        if ff * ADD_PER_FORM_FACTOR <= crate::scene::q3map2::FALLOFF_TOLERANCE_BYTES {
            return radius * units_m;
        }
        radius += STEP_UNITS;
    }
    LAST_UNITS * units_m
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lightmapped wall 600 x 300 units (luxels of 15 units) and a small vertex-lit
    /// triangle: the wall's two triangles are cut into pieces no wider than 256 units,
    /// each averaging the luxels under it; the triangle is one piece, its corners' mean.
    /// Triangles far bigger than Quake's world stop being cut once the budget is spent:
    /// the tree stays bounded however many there are.
    #[test]
    fn hostile_triangles_spend_a_bounded_budget() {
        let mut mesh = crate::scene::Mesh::default();
        // 80 triangles, each of which the depth cap alone would let make 2^16 - 1 cuts.
        for k in 0..40 {
            let z = k as f32;
            crate::testutil::push_quad(&mut mesh, [[0.0, 0.0, z], [1e6, 0.0, z], [1e6, 1e6, z], [0.0, 1e6, z]], Vec3::Z);
        }
        let scene = crate::testutil::scene(mesh, vec![crate::testutil::material("wall")]);
        let mut rows = Rows::new(crate::rows::Sampling::plain(1.0));
        rows.finish();
        let pieces = Pieces::build(&scene, &rows, false);
        // Each cut adds two nodes to the one it replaces.
        assert!(pieces.nodes.len() <= 2 * CUT_BUDGET + scene.mesh.triangles.len(), "{} nodes", pieces.nodes.len());
        assert!(pieces.nodes.len() > CUT_BUDGET, "the budget was spent: {} nodes", pieces.nodes.len());
    }

    #[test]
    fn pieces_average_the_rows_under_them() {
        use crate::rows::{Row, Sampling, SolidAhead};
        let u = 0.0254f32;
        let mut mesh = crate::scene::Mesh::default();
        let (w, h) = (600.0 * u, 300.0 * u);
        crate::testutil::push_quad(&mut mesh, [[0.0, 0.0, 0.0], [w, 0.0, 0.0], [w, h, 0.0], [0.0, h, 0.0]], Vec3::Z);
        mesh.uv1 = vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)];
        // The vertex-lit triangle, 10 units on a side, in front of the wall.
        let base = mesh.positions.len() as u32;
        for p in [[0.0, 0.0, 40.0 * u], [10.0 * u, 0.0, 40.0 * u], [0.0, 10.0 * u, 40.0 * u]] {
            mesh.positions.push(Vec3::from(p));
            mesh.normals.push(Vec3::Z);
            mesh.uv0.push(Vec2::ZERO);
            mesh.uv1.push(Vec2::ZERO);
            mesh.colors.push([1.0; 3]);
            mesh.v_material.push(1);
        }
        mesh.triangles.push([base, base + 1, base + 2]);
        mesh.tri_material.push(1);
        mesh.tri_source.push(2);
        mesh.reweld();
        let vertex_lit = crate::scene::Material::plain("model", Lighting::Vertex, 2);
        let mut scene = crate::testutil::scene(mesh, vec![crate::testutil::material("wall"), vertex_lit]);
        let (tw, th) = (40u32, 20u32);
        scene.textures.push(crate::scene::Texture { width: tw, height: th, rgba8: vec![0; (tw * th * 4) as usize], wrap_s: crate::scene::Wrap::Clamp, wrap_t: crate::scene::Wrap::Clamp });
        let mut rows = Rows::new(Sampling::plain(1.0));
        let row = |vertex: u32, material: u32, texel: [u32; 3], pos: Vec3| Row { vertex, material, texel, pos, normal: Vec3::Z, albedo: [0.5; 3], lo: [0.1; 3], hi: [0.2; 3], weight: [1.0; 3], lower: [0.0; 3], area: 1.0, solid_ahead: SolidAhead::NONE, two_sided: false };
        for y in 0..th {
            for x in 0..tw {
                rows.push(row(u32::MAX, 0, [0, x, y], Vec3::new((x as f32 + 0.5) * 15.0 * u, (y as f32 + 0.5) * 15.0 * u, 0.0)));
            }
        }
        for v in 0..3 {
            rows.push(row(base + v, 1, [u32::MAX; 3], scene.mesh.positions[(base + v) as usize]));
        }
        rows.finish();
        let pieces = Pieces::build(&scene, &rows, false);
        // Each 600 x 300 triangle: x cut at 300, then each half at 150; y at 150.
        assert!(pieces.len() > 2 + 1, "{} pieces", pieces.len());
        for p in 0..pieces.len() {
            let sum: f32 = pieces.emit.row(p).iter().map(|e| e.1).sum();
            assert!((sum - 1.0).abs() < 1e-5, "piece {p} weighs {sum}");
        }
        // A point's piece averages luxels around it, never further than a piece's size.
        for (tri, p) in [(0usize, Vec3::new(500.0, 60.0, 0.0) * u), (1, Vec3::new(100.0, 250.0, 0.0) * u), (0, Vec3::new(290.0, 10.0, 0.0) * u)] {
            let piece = pieces.locate(tri, p).expect("the wall emits");
            for &(j, _) in pieces.emit.row(piece as usize) {
                let d = (rows.pos[j as usize] - p).abs() / u;
                assert!(d.x <= 256.0 + 15.0 && d.y <= 256.0 + 15.0, "row {j} is {d} units from {p}");
            }
            let o = pieces.origin[piece as usize];
            assert!((o.z / u - 1.0).abs() < 1e-3, "the origin lies 1 unit in front: {o}");
        }
        // The vertex-lit triangle is one piece: its three corners' mean.
        let piece = pieces.locate(2, Vec3::new(2.0, 2.0, 40.0) * u).expect("the model emits");
        let mut got: Vec<(u32, f32)> = pieces.emit.row(piece as usize).to_vec();
        got.sort_by_key(|e| e.0);
        let first = (tw * th) as u32;
        assert_eq!(got.iter().map(|e| e.0).collect::<Vec<_>>(), vec![first, first + 1, first + 2]);
        assert!(got.iter().all(|e| (e.1 - 1.0 / 3.0).abs() < 1e-5), "{got:?}");
        // Without -fast a piece reaches everywhere; with it, a small piece's reach is
        // q3map2's first step, 100 units.
        assert!(pieces.envelope.iter().all(|e| e.is_infinite()));
        let fast = Pieces::build(&scene, &rows, true);
        let e = fast.envelope[piece as usize] / u;
        assert!((e - 100.0).abs() < 1e-2, "the small triangle reaches {e} units");
        assert!(fast.envelope.iter().any(|&e| e / u > 500.0), "a 150-unit piece reaches further");
    }


}
