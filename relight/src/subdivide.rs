//! Subdivision of the mesh until no edge spans more than a bound: one lightmap texel
//! (measured through TEXCOORD_1 and the atlas size) or a length in meters.
//!
//! The decision to split is a property of the *edge*, keyed by the welded ids of its two
//! end points, so every triangle that shares the edge, in any primitive, splits it, and
//! the midpoint is computed from commutative operations (`(a + b) * 0.5`), so both sides
//! get bit-identical positions: no T-junctions are introduced. Each round splits only the
//! edges longer than half the longest remaining one, so when the vertex budget stops the
//! refinement the mesh is as uniform as the rounds made it. Triangles with one, two or
//! three split edges become two, three or four triangles with the original winding.

use std::collections::{HashMap, HashSet};

use glam::Vec2;

use crate::scene::{Lighting, Material, Mesh, Texture};

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Bound {
    /// At most this many lightmap texels per edge (edges of lightmapped triangles only).
    Texels(f32),
    /// At most this many meters per edge (every triangle).
    Meters(f32),
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct Stats {
    pub vertices_before: usize,
    pub vertices_after: usize,
    pub triangles_before: usize,
    pub triangles_after: usize,
    pub rounds: usize,
    /// Longest remaining edge in the bound's unit (texels or meters).
    pub longest_edge: f32,
    /// The vertex budget stopped the refinement before the bound was met.
    pub budget_reached: bool,
}

/// Edge length in the bound's unit, or 0 where the bound does not apply to this triangle
/// (a lightmapped triangle without lightmap area carries no data: splitting it, a ground
/// plane a kilometre wide, would spend the vertex budget where there is nothing to fit).
fn edge_measure(mesh: &Mesh, mats: &[Material], texs: &[Texture], t: usize, a: u32, b: u32, bound: Bound) -> f32 {
    match bound {
        Bound::Meters(_) => {
            use crate::rows::projection::{lightmap_texels, MIN_LIGHTMAP_TEXELS};
            if lightmap_texels(mesh, mats, texs, t).is_some_and(|a| !(a > MIN_LIGHTMAP_TEXELS)) {
                0.0
            } else {
                (mesh.positions[a as usize] - mesh.positions[b as usize]).length()
            }
        }
        Bound::Texels(_) => {
            let m = &mats[mesh.tri_material[t] as usize];
            match (m.lighting, m.lightmap) {
                (Lighting::Lightmap, Some(lm)) => {
                    let size = Vec2::new(texs[lm].width as f32, texs[lm].height as f32);
                    ((mesh.uv1[a as usize] - mesh.uv1[b as usize]) * size).length()
                }
                _ => 0.0,
            }
        }
    }
}

fn edge_key(mesh: &Mesh, a: u32, b: u32) -> (u32, u32) {
    let (wa, wb) = (mesh.weld[a as usize], mesh.weld[b as usize]);
    (wa.min(wb), wa.max(wb))
}

/// Subdivides in place. `max_vertices` bounds the result (the budget).
pub fn subdivide(mesh: &mut Mesh, mats: &[Material], texs: &[Texture], bound: Bound, max_vertices: usize) -> Stats {
    let limit = match bound {
        Bound::Texels(x) | Bound::Meters(x) => x.max(1e-6),
    };
    let mut stats = Stats {
        vertices_before: mesh.positions.len(),
        vertices_after: 0,
        triangles_before: mesh.triangles.len(),
        triangles_after: 0,
        rounds: 0,
        longest_edge: 0.0,
        budget_reached: false,
    };
    loop {
        // Longest edge per welded key, over every triangle that uses it.
        let mut longest: HashMap<(u32, u32), f32> = HashMap::new();
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let len = edge_measure(mesh, mats, texs, t, a, b, bound);
                let e = longest.entry(edge_key(mesh, a, b)).or_insert(0.0);
                if len.is_finite() && len > *e {
                    *e = len;
                }
            }
        }
        let max_len = longest.values().copied().fold(0.0f32, f32::max);
        stats.longest_edge = max_len;
        if max_len <= limit {
            break;
        }
        let threshold = limit.max(0.5 * max_len);
        let split: HashSet<(u32, u32)> = longest.iter().filter(|(_, &l)| l > threshold).map(|(&k, _)| k).collect();
        // Vertices this round adds: one per distinct (vertex pair) edge that is split.
        let mut added = HashSet::new();
        for tri in &mesh.triangles {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                if split.contains(&edge_key(mesh, a, b)) {
                    added.insert((a.min(b), a.max(b)));
                }
            }
        }
        if mesh.positions.len() + added.len() > max_vertices {
            stats.budget_reached = true;
            break;
        }
        split_round(mesh, &split);
        stats.rounds += 1;
    }
    stats.vertices_after = mesh.positions.len();
    stats.triangles_after = mesh.triangles.len();
    stats
}

fn split_round(mesh: &mut Mesh, split: &HashSet<(u32, u32)>) {
    let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
    let old_tris = std::mem::take(&mut mesh.triangles);
    let old_mats = std::mem::take(&mut mesh.tri_material);
    let old_src = std::mem::take(&mut mesh.tri_source);
    let mut tris = Vec::with_capacity(old_tris.len() * 2);
    let mut mats = Vec::with_capacity(old_tris.len() * 2);
    let mut srcs = Vec::with_capacity(old_tris.len() * 2);
    for ((tri, mat), src) in old_tris.into_iter().zip(old_mats).zip(old_src) {
        let mut m = [None; 3];
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            if split.contains(&edge_key(mesh, a, b)) {
                let key = (a.min(b), a.max(b));
                let v = *mid.entry(key).or_insert_with(|| midpoint(mesh, a, b));
                m[k] = Some(v);
            }
        }
        let mut push = |t: [u32; 3]| {
            tris.push(t);
            mats.push(mat);
            srcs.push(src);
        };
        let [v0, v1, v2] = tri;
        match m {
            [None, None, None] => push(tri),
            [Some(a), Some(b), Some(c)] => {
                push([v0, a, c]);
                push([a, v1, b]);
                push([c, b, v2]);
                push([a, b, c]);
            }
            _ => {
                // Rotate so that the split edges come first: (p0, p1) is split.
                let count = m.iter().filter(|x| x.is_some()).count();
                let r = (0..3).find(|&r| m[r].is_some() && (count == 1 || m[(r + 1) % 3].is_some())).unwrap_or(0);
                let p = [tri[r], tri[(r + 1) % 3], tri[(r + 2) % 3]];
                let ma = m[r].unwrap_or(p[0]);
                if count == 1 {
                    push([p[0], ma, p[2]]);
                    push([ma, p[1], p[2]]);
                } else {
                    // Edges (p0,p1) and (p1,p2) split; quad p0, ma, mb, p2 gets its shorter diagonal.
                    let mb = m[(r + 1) % 3].unwrap_or(p[1]);
                    push([ma, p[1], mb]);
                    let d1 = (mesh.positions[p[0] as usize] - mesh.positions[mb as usize]).length_squared();
                    let d2 = (mesh.positions[ma as usize] - mesh.positions[p[2] as usize]).length_squared();
                    if d1 <= d2 {
                        push([p[0], ma, mb]);
                        push([p[0], mb, p[2]]);
                    } else {
                        push([p[0], ma, p[2]]);
                        push([ma, mb, p[2]]);
                    }
                }
            }
        }
    }
    mesh.triangles = tris;
    mesh.tri_material = mats;
    mesh.tri_source = srcs;
    mesh.reweld();
}

/// A new vertex halfway along (a, b), every attribute interpolated with commutative
/// arithmetic so that the same edge seen from another primitive gets the same position.
fn midpoint(mesh: &mut Mesh, a: u32, b: u32) -> u32 {
    let (a, b) = (a as usize, b as usize);
    let v = mesh.positions.len() as u32;
    mesh.positions.push((mesh.positions[a] + mesh.positions[b]) * 0.5);
    let n = mesh.normals[a] + mesh.normals[b];
    mesh.normals.push(n.try_normalize().unwrap_or(mesh.normals[a]));
    mesh.uv0.push((mesh.uv0[a] + mesh.uv0[b]) * 0.5);
    mesh.uv1.push((mesh.uv1[a] + mesh.uv1[b]) * 0.5);
    let (ca, cb) = (mesh.colors[a], mesh.colors[b]);
    mesh.colors.push([0, 1, 2].map(|k| (ca[k] + cb[k]) * 0.5));
    mesh.v_material.push(mesh.v_material[a]);
    mesh.weld.push(u32::MAX); // recomputed at the end of the round
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::room;
    use std::collections::HashMap;

    fn area(m: &Mesh) -> f64 {
        (0..m.triangles.len()).map(|t| m.triangle_area(t) as f64).sum()
    }

    /// Every edge (by welded ids) is used by exactly two triangles in a closed room: no
    /// T-junction, no hole, no non-manifold edge; area is preserved; the bound holds.
    #[test]
    fn meters_bound_keeps_the_room_closed() {
        let (mut m, _) = room(2);
        let a0 = area(&m);
        let mats = vec![];
        let st = subdivide(&mut m, &mats, &[], Bound::Meters(0.3), 1_000_000);
        assert!(!st.budget_reached && st.longest_edge <= 0.3, "{st:?}");
        assert!((area(&m) - a0).abs() < 1e-4 * a0);
        let mut uses: HashMap<(u32, u32), usize> = HashMap::new();
        for tri in &m.triangles {
            for k in 0..3 {
                let (a, b) = (m.weld[tri[k] as usize], m.weld[tri[(k + 1) % 3] as usize]);
                *uses.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        assert!(uses.values().all(|&n| n == 2), "open or non-manifold edges after subdivision");
    }

    #[test]
    fn budget_stops_refinement() {
        let (mut m, _) = room(2);
        let st = subdivide(&mut m, &[], &[], Bound::Meters(0.01), 2_000);
        assert!(st.budget_reached && m.positions.len() <= 2_000);
    }
}
