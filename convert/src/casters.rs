//! What q3map2's light stage traces its shadow rays against, recorded for relight
//! (`q3_casters` in the scene's extras, with a binary buffer view).
//!
//! q3map2 does not trace the surfaces the game draws. Its light stage (`SetupTraceNodes`)
//! starts from the BSP's own tree, filters every shadow-casting triangle into it (clipped
//! by the node planes), subdivides each leaf along the axes, and tests a ray against the
//! fan triangles of those pieces with a barycentric slack of 1% of each piece. So a ray
//! that grazes an edge is stopped or not depending on the piece it passes, and that is
//! visible in the lightmaps wherever the 16-unit grid lines luxels, lights and brush
//! corners up. relight rebuilds those pieces (`trace::pieces`) from what this record
//! holds: the tree and the casting triangles, in Quake units exactly as the BSP has them
//! (the subdivision snaps to whole units, which a round trip through metres would move).
//!
//! The casting triangles, in q3map2's order (`PopulateTraceNodes`):
//! - the world model's surfaces whose shader blocks light ([`crate::material`]'s
//!   `casts_shadow`: a translucent shader only as an alpha shadow or a light filter), not
//!   fog, area portals or nodraw; polygons and triangle meshes by their indexes. Sky
//!   surfaces go in too, flagged: they stop no ray, but they are in the tree when q3map2
//!   decides where to subdivide;
//! - Bezier patches as q3map2's light mesh of them ([`crate::lightmesh`]), each quad cut
//!   along the diagonal q3map2 takes, when the recorded compile has `-patchshadows` (or
//!   records nothing: relight has always let patches cast);
//! - the surfaces of brush entities whose `_castShadows` / `_cs` key is positive, moved
//!   by their `origin` (q3map2's entities cast nothing by default).
//!
//! Layout of the buffer view (little-endian), counts in the JSON record:
//! `planes` x `[nx, ny, nz, dist]` f32; `nodes` x `[plane, front, back]` i32 (a child
//! `>= 0` is a node, `< 0` the leaf `-(c + 1)`, node 0 the root); `leafs` x i32 (1 where
//! the leaf is structural solid, cluster -1); `vertices` x `[x, y, z]` f32; `triangles`
//! x `[a, b, c, flags]` u32 (flags bit 0: sky). The record also holds `fnv1a64` (hex) of the view's bytes, by which
//! relight knows the view is still this record (an export that keeps the extras but not
//! the view renumbers the views), and `bufferView`, set by the writer.

use crate::bsp::{Bsp, SurfaceType};
use crate::entities::Entity;
use crate::lightmesh;
use crate::material::{ShaderInfo, Visibility};
use serde_json::{json, Value};

/// The record's name in the scene's extras.
pub const KEY: &str = "q3_casters";
/// A triangle's flag: a sky surface (in the tree, stops nothing).
pub const SKY: u32 = 1;

/// FNV-1a, 64 bits: the record's check of its bytes (relight computes the same).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3))
}

/// Whether the recorded compile let patches cast shadows (`-patchshadows` in its light
/// stage); `true` when nothing is recorded.
pub fn patch_shadows(cmdline: Option<&str>) -> bool {
    match cmdline {
        None => true,
        Some(c) => c.split_whitespace().any(|t| t.eq_ignore_ascii_case("-patchshadows")),
    }
}

/// The `q3_casters` record and its bytes, or `None` when the map has no tree or nothing
/// casts. `infos` is per BSP shader; `ents` the entity lump.
pub fn q3map2_casters(bsp: &Bsp, infos: &[ShaderInfo], ents: &[Entity], cmdline: Option<&str>) -> Option<(Value, Vec<u8>)> {
    let c = &bsp.collision;
    if c.error.is_some() || c.nodes.is_empty() || c.leafs.is_empty() || c.planes.is_empty() {
        return None;
    }
    // Per shader: None when q3map2 leaves its surfaces out of the tree, else the flags.
    let flags = |shader: u32| -> Option<u32> {
        let i = infos.get(shader as usize)?;
        match i.visibility {
            Visibility::Drawn => i.light.casts_shadow.then_some(0),
            Visibility::Hidden(why) => (!matches!(why, "nodraw" | "fog" | "areaportal" | "hint/skip" | "noshader") && i.light.casts_shadow).then_some(0),
            Visibility::Sky => Some(SKY),
        }
    };
    let patches = patch_shadows(cmdline);
    let subdivisions = lightmesh::subdivisions_of(cmdline);
    let longest = if patches { lightmesh::group_longest_curves(bsp) } else { Default::default() };
    // The models that cast, with their offset: the world, then the brush entities that ask.
    let mut models: Vec<(usize, [f64; 3])> = vec![(0, [0.0; 3])];
    for e in ents.iter().skip(1) {
        let Some(m) = e.get("model").and_then(|m| m.strip_prefix('*')).and_then(|m| m.parse::<usize>().ok()) else { continue };
        let cast = e.number("_castShadows").or_else(|| e.number("_cs")).unwrap_or(0.0);
        if m > 0 && m < bsp.models.len() && cast > 0.0 {
            models.push((m, e.vec3("origin").unwrap_or([0.0; 3])));
        }
    }
    let mut verts: Vec<[f32; 3]> = Vec::new();
    let mut tris: Vec<[u32; 4]> = Vec::new();
    for (m, off) in models {
        // A map may have no models at all (no world): then nothing casts.
        let Some(model) = bsp.models.get(m) else { continue };
        let first = model.first_surface as usize;
        let last = first.saturating_add(model.num_surfaces as usize).min(bsp.surfaces.len());
        for si in first..last {
            let s = &bsp.surfaces[si];
            let Some(flag) = flags(s.shader) else { continue };
            // Flares and unknown kinds cast nothing; `parse` checked only drawn ranges.
            if !matches!(s.kind, SurfaceType::Polygon | SurfaceType::Mesh | SurfaceType::Patch) {
                continue;
            }
            let sv = bsp.surface_verts(s);
            let at = |p: [f64; 3]| -> [f32; 3] { [0, 1, 2].map(|k| (p[k] + off[k]) as f32) };
            match s.kind {
                SurfaceType::Polygon | SurfaceType::Mesh => {
                    let base = verts.len() as u32;
                    verts.extend(sv.iter().map(|v| at(v.xyz.map(f64::from))));
                    for t in bsp.surface_indices(s).chunks_exact(3) {
                        if t.iter().all(|&i| (i as usize) < sv.len()) {
                            tris.push([base + t[0], base + t[1], base + t[2], flag]);
                        }
                    }
                }
                SurfaceType::Patch if patches => {
                    if !sv.iter().all(|v| v.xyz.iter().all(|x| x.is_finite())) {
                        continue;
                    }
                    let iterations = lightmesh::iterations_for_curve(longest.get(&si).copied().unwrap_or(0.0), subdivisions);
                    let Some(mesh) = lightmesh::light_mesh(sv, s.patch_w as usize, s.patch_h as usize, iterations) else { continue };
                    let base = verts.len() as u32;
                    verts.extend(mesh.verts.iter().map(|v| at(v.xyz.to_array())));
                    let w = mesh.width as u32;
                    for y in 0..mesh.height as u32 - 1 {
                        for x in 0..w - 1 {
                            // q3map2's quad: its corners in this order, cut from corner r.
                            let pw = [x + y * w, x + (y + 1) * w, x + 1 + (y + 1) * w, x + 1 + y * w, x + y * w];
                            let r = ((x + y) & 1) as usize;
                            tris.push([base + pw[r], base + pw[r + 1], base + pw[r + 2], flag]);
                            tris.push([base + pw[r], base + pw[r + 2], base + pw[r + 3], flag]);
                        }
                    }
                }
                _ => {}
            }
        }
    }
    if tris.iter().all(|t| t[3] & SKY != 0) {
        return None;
    }
    let mut bytes = Vec::new();
    for (n, d) in &c.planes {
        for x in n.iter().chain(std::iter::once(d)) {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    for node in &c.nodes {
        for x in [node.plane as i32, node.children[0], node.children[1]] {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    for leaf in &c.leafs {
        bytes.extend_from_slice(&i32::from(leaf.cluster == -1).to_le_bytes());
    }
    for v in &verts {
        for x in v {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    for t in &tris {
        for x in t {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    let record = json!({
        "planes": c.planes.len(),
        "nodes": c.nodes.len(),
        "leafs": c.leafs.len(),
        "vertices": verts.len(),
        "triangles": tris.len(),
        "patch_shadows": patches,
        "fnv1a64": format!("{:016x}", fnv1a64(&bytes)),
    });
    Some((record, bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patch_shadows_follow_the_recorded_compile() {
        assert!(patch_shadows(None));
        assert!(patch_shadows(Some("-bsp -meta; -light -fast -patchshadows")));
        assert!(!patch_shadows(Some("-bsp -meta; -light -fast -bounce 8")));
    }

    #[test]
    fn fnv1a64_is_the_reference_hash() {
        // FNV-1a 64 test vectors (the empty string and "a").
        assert_eq!(fnv1a64(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
    }
}
