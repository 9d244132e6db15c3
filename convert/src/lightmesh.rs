//! The mesh q3map2's light stage makes of a Bezier patch, which is what its area lights
//! emit from (and, with `-patchshadows`, what casts its shadows). It is coarser than the
//! surface the game draws (and than [`crate::patch`]'s tessellation), and its quads are
//! not always what they look like: where a patch has rows collapsed to one point (round
//! lamps built of quarter patches), every other quad's emitting half is a degenerate
//! triangle, and q3map2 then emits nothing from that quad (relight's `model::surface`
//! owns that rule). So relight needs this mesh, not the drawn one, to emit as q3map2 did.
//!
//! q3map2's steps (all in Quake units, as here):
//! 1. **How fine.** Per patch, the longest of its curves (`ExpandLongestCurve`, an
//!    8-segment length along each even control line; straight lines and lines with a
//!    segment under 1/8 unit count nothing). Patches of one entity that touch (any two
//!    control points within 1 unit on every axis) form a group that takes the group's
//!    longest curve (`PatchMapDrawSurfs`). The iterations are the first `k` in 0..3 with
//!    `subdivisions x 16 x 2^k >= length`, else 3 (`IterationsForCurve`; `subdivisions`
//!    is 8 for Quake III, the light stage's `-subdivisions` otherwise).
//! 2. **Subdivide** (`SubdivideMesh2`): each span's three control points become five by
//!    de Casteljau halving, `k` times, columns then rows (at most 128 per axis).
//! 3. **Onto the curve** (`PutMeshOnCurve`): every odd row, then every odd column, moves
//!    to the middle of its span's curve; the even ones already lie on it.
//! 4. **Drop straight lines** (`RemoveLinearMeshColumnsRows`): an inner column (then row)
//!    whose points all lie within 0.1 unit of the lines through their neighbours goes.
//!
//! Normals are halved and renormalised with the positions in step 2 (a zero result keeps
//! the first normal, as `LerpDrawVert`), and steps 3-4 leave them. Lightmap coordinates
//! follow the positions through steps 2-3 (q3map2 maps a curved patch's luxels on this
//! same mesh, [`crate::patch_luxels`]).
//!
//! The record convert writes into the scene's extras, `q3_patch_lights`, is a list with
//! one entry per drawn patch whose shader emits (glTF axes, metres):
//! - `shader`: the shader's name (the material's name up to any `#` suffix);
//! - `size`: `[width, height]` of the mesh, row-major;
//! - `xyz`, `normal`: three numbers per vertex;
//! - `area_m2`: the area of convert's own tessellation of the patch, by which relight
//!   tells whether the mesh it reads still has this patch (an edit may have moved or
//!   deleted it).
//!
//! **Vertex-lit patches.** q3map2 lights a patch without a lightmap at its control points
//! only (`IlluminateVertexes` walks the surface's vertices, which for a patch are its
//! control points, off the surface where it curves), and the game draws the colours
//! interpolated over its tessellation by the Bezier basis. A lamp or a glowing pad made
//! of patches with a light a few units above its centre is lit there at a handful of
//! points, and the colours between are their blend, much flatter than the light's
//! falloff. The record `q3_patch_vertices` holds, per drawn vertex-lit patch: `shader`,
//! `size` (the control grid), `xyz`, `normal`, `rgb` (q3map2's bytes, three per point),
//! `point_area_m2` (the drawn area each point's basis function covers,
//! [`crate::patch::Tessellated::control_point_areas`]) and `area_m2` as above.

use crate::bsp::{Bsp, DrawVert, SurfaceType};
use crate::units;
use glam::{DVec2, DVec3};
use serde_json::{json, Value};
use std::collections::HashMap;

/// q3map2's default `patchSubdivisions` for Quake III (`games.cpp`).
pub const DEFAULT_SUBDIVISIONS: u32 = 8;
/// q3map2's `MAX_EXPANDED_AXIS`: the most grid lines per axis of a subdivided patch.
const MAX_EXPANDED_AXIS: usize = 128;
/// Patches whose control points are this close (Quake units, per axis) share a group.
const BORDER_EPSILON: f64 = 1.0;
/// A grid line this close to straight (Quake units) is dropped.
const LINEAR_EPSILON: f64 = 0.1;

type P = DVec3;

fn mid(a: P, b: P) -> P {
    (a + b) * 0.5
}
/// `a / |a|`, and the zero vector for the zero vector (q3map2's `VectorNormalize`).
fn normalized(a: P) -> (P, f64) {
    let l = a.length();
    if l == 0.0 {
        (P::ZERO, 0.0)
    } else {
        (a * (1.0 / l), l)
    }
}

/// A vertex of the light mesh, Quake units and axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vert {
    pub xyz: P,
    pub normal: P,
    /// Lightmap coordinates, as the control points' (page-normalised in a BSP; the
    /// mesh interpolates them as q3map2 does, [`crate::patch_luxels`] maps luxels by them).
    pub lm: DVec2,
}

impl Vert {
    fn of(v: &DrawVert) -> Vert {
        Vert { xyz: DVec3::from(v.xyz.map(f64::from)), normal: DVec3::from(v.normal.map(f64::from)), lm: DVec2::from(v.lightmap.map(f64::from)) }
    }
}

/// q3map2's `LerpDrawVert` (position, lightmap coordinates and normal).
pub fn lerp(a: &Vert, b: &Vert) -> Vert {
    let (n, l) = normalized(mid(a.normal, b.normal));
    Vert { xyz: mid(a.xyz, b.xyz), normal: if l == 0.0 { a.normal } else { n }, lm: (a.lm + b.lm) * 0.5 }
}

/// The light mesh of one patch: `width x height` vertices, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct LightMesh {
    pub width: usize,
    pub height: usize,
    pub verts: Vec<Vert>,
}

/// `ExpandLongestCurve`: the length q3map2 measures along the control line `a b c` (none
/// for a straight line or one with a segment under 1/8 unit).
fn curve_length(a: P, b: P, c: P) -> Option<f64> {
    let (ab, lab) = normalized(b - a);
    let (bc, lbc) = normalized(c - b);
    let (ac, lac) = normalized(c - a);
    if lab < 0.125 || lbc < 0.125 || lac < 0.125 {
        return None;
    }
    if ab.dot(bc) > 0.99 && ab.dot(ac) > 0.99 {
        return None;
    }
    let (ab, bc) = (b - a, c - b);
    // q3map2's walk (eight steps from a, along ab then bending to bc; it never reaches c).
    let (mut last, mut len) = (a, 0.0);
    for i in 0..8 {
        let t = i as f64 / 8.0;
        let pt = a + (ab * (1.0 - t) + bc * t);
        len += (pt - last).length();
        last = pt;
    }
    Some(len)
}

/// The longest curve of one patch's control grid (row-major, `w x h`), as q3map2 measures
/// it: along the even rows and columns, except the last of each.
pub fn longest_curve(ctrl: &[DrawVert], w: usize, h: usize) -> f64 {
    let p = |i: usize, j: usize| DVec3::from(ctrl[i * w + j].xyz.map(f64::from));
    let mut longest = 0.0f64;
    for j in (0..w.saturating_sub(2)).step_by(2) {
        for i in (0..h.saturating_sub(2)).step_by(2) {
            for l in [curve_length(p(i, j), p(i, j + 1), p(i, j + 2)), curve_length(p(i, j), p(i + 1, j), p(i + 2, j))].into_iter().flatten() {
                longest = longest.max(l);
            }
        }
    }
    longest
}

/// `IterationsForCurve`.
pub fn iterations_for_curve(length: f64, subdivisions: u32) -> u32 {
    (0..3).find(|&k| (subdivisions as f64) * 16.0 * f64::from(1u32 << k) >= length).unwrap_or(3)
}

/// The longest curve of each patch surface's group (see the module docs), per surface
/// index (patch surfaces only). Groups never span two models (q3map2 groups per entity).
pub fn group_longest_curves(bsp: &Bsp) -> HashMap<usize, f64> {
    let mut out = HashMap::new();
    for m in &bsp.models {
        let first = m.first_surface as usize;
        let ids: Vec<usize> = (first..first.saturating_add(m.num_surfaces as usize))
            .filter(|&i| bsp.surfaces.get(i).is_some_and(|s| s.kind == SurfaceType::Patch))
            .collect();
        // Union-find over the model's patches; touching control points found through a
        // grid of cells one epsilon wide.
        let mut parent: Vec<usize> = (0..ids.len()).collect();
        fn root(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        let mut cells: HashMap<[i64; 3], Vec<(usize, P)>> = HashMap::new();
        for (k, &si) in ids.iter().enumerate() {
            for v in bsp.surface_verts(&bsp.surfaces[si]) {
                let p = DVec3::from(v.xyz.map(f64::from));
                if !p.is_finite() {
                    continue;
                }
                // `as` saturates, so a coordinate far outside any map lands in the outermost
                // cell and its neighbours are found with saturating steps.
                let c = p.to_array().map(|x| (x / BORDER_EPSILON).floor() as i64);
                for dx in -1..=1 {
                    for dy in -1..=1 {
                        for dz in -1..=1 {
                            let Some(list) = cells.get(&[c[0].saturating_add(dx), c[1].saturating_add(dy), c[2].saturating_add(dz)]) else { continue };
                            for &(other, q) in list {
                                if other != k && (p - q).abs().max_element() < BORDER_EPSILON {
                                    let (ra, rb) = (root(&mut parent, k), root(&mut parent, other));
                                    parent[ra] = rb;
                                }
                            }
                        }
                    }
                }
                cells.entry(c).or_default().push((k, p));
            }
        }
        let own: Vec<f64> = ids.iter().map(|&si| {
            let s = &bsp.surfaces[si];
            longest_curve(bsp.surface_verts(s), s.patch_w as usize, s.patch_h as usize)
        }).collect();
        let mut group: HashMap<usize, f64> = HashMap::new();
        for k in 0..ids.len() {
            let r = root(&mut parent, k);
            let g = group.entry(r).or_insert(0.0);
            *g = g.max(own[k]);
        }
        for (k, &si) in ids.iter().enumerate() {
            let r = root(&mut parent, k);
            out.insert(si, group[&r]);
        }
    }
    out
}

/// q3map2's light mesh of a control grid (row-major `w x h`, both odd and at least 3)
/// subdivided `iterations` times; `None` for a grid of another shape.
pub fn light_mesh(ctrl: &[DrawVert], w: usize, h: usize, iterations: u32) -> Option<LightMesh> {
    if w < 3 || h < 3 || w % 2 == 0 || h % 2 == 0 || w > MAX_EXPANDED_AXIS || h > MAX_EXPANDED_AXIS || ctrl.len() != w * h {
        return None;
    }
    // `SubdivideMesh2`.
    let mut rows: Vec<Vec<Vert>> = (0..h).map(|i| ctrl[i * w..(i + 1) * w].iter().map(Vert::of).collect()).collect();
    let (mut width, mut height) = (w, h);
    for _ in 0..iterations {
        let mut j = 0;
        while j + 2 < width {
            if width + 2 >= MAX_EXPANDED_AXIS {
                break;
            }
            width += 2;
            for row in &mut rows {
                let prev = lerp(&row[j], &row[j + 1]);
                let next = lerp(&row[j + 1], &row[j + 2]);
                let m = lerp(&prev, &next);
                row.splice(j + 1..j + 2, [prev, m, next]);
            }
            j += 4;
        }
        let mut j = 0;
        while j + 2 < height {
            if height + 2 >= MAX_EXPANDED_AXIS {
                break;
            }
            height += 2;
            let (a, b, c) = (&rows[j], &rows[j + 1], &rows[j + 2]);
            let prev: Vec<Vert> = a.iter().zip(b).map(|(a, b)| lerp(a, b)).collect();
            let next: Vec<Vert> = b.iter().zip(c).map(|(b, c)| lerp(b, c)).collect();
            let m: Vec<Vert> = prev.iter().zip(&next).map(|(p, n)| lerp(p, n)).collect();
            rows.splice(j + 1..j + 2, [prev, m, next]);
            j += 4;
        }
    }
    // `PutMeshOnCurve`: odd rows, then odd columns.
    let on_curve = |p: P, a: P, b: P| mid(mid(p, a), mid(p, b));
    let on_curve_lm = |p: DVec2, a: DVec2, b: DVec2| ((p + a) * 0.5 + (p + b) * 0.5) * 0.5;
    for i in 0..width {
        for j in (1..height.saturating_sub(1)).step_by(2) {
            rows[j][i].xyz = on_curve(rows[j][i].xyz, rows[j + 1][i].xyz, rows[j - 1][i].xyz);
            rows[j][i].lm = on_curve_lm(rows[j][i].lm, rows[j + 1][i].lm, rows[j - 1][i].lm);
        }
    }
    for row in &mut rows {
        for i in (1..width.saturating_sub(1)).step_by(2) {
            row[i].xyz = on_curve(row[i].xyz, row[i + 1].xyz, row[i - 1].xyz);
            row[i].lm = on_curve_lm(row[i].lm, row[i + 1].lm, row[i - 1].lm);
        }
    }
    // `RemoveLinearMeshColumnsRows`: columns, then rows.
    let off_line = |p: P, a: P, b: P| {
        let (dir, _) = normalized(b - a);
        (p - (a + dir * (p - a).dot(dir))).length()
    };
    let mut j = 1;
    while j + 1 < rows[0].len() {
        if rows.iter().all(|r| off_line(r[j].xyz, r[j - 1].xyz, r[j + 1].xyz) < LINEAR_EPSILON) {
            for r in &mut rows {
                r.remove(j);
            }
        } else {
            j += 1;
        }
    }
    let mut j = 1;
    while j + 1 < rows.len() {
        if (0..rows[j].len()).all(|i| off_line(rows[j][i].xyz, rows[j - 1][i].xyz, rows[j + 1][i].xyz) < LINEAR_EPSILON) {
            rows.remove(j);
        } else {
            j += 1;
        }
    }
    let (width, height) = (rows[0].len(), rows.len());
    Some(LightMesh { width, height, verts: rows.into_iter().flatten().collect() })
}

/// The word after `switch` in a recorded command line's light stage (its `;`-separated
/// part with `-light`): `-subdivisions N`, `-super N`, `-gamma G`.
pub fn light_stage_value<'a>(cmdline: &'a str, switch: &str) -> Option<&'a str> {
    let light = cmdline.split(';').find(|s| s.split_whitespace().any(|t| t.eq_ignore_ascii_case("-light")))?;
    let words: Vec<&str> = light.split_whitespace().collect();
    words.windows(2).find(|w| w[0].eq_ignore_ascii_case(switch)).map(|w| w[1])
}

/// The `-subdivisions N` of a recorded command line's light stage, else q3map2's default.
pub fn subdivisions_of(cmdline: Option<&str>) -> u32 {
    cmdline
        .and_then(|c| light_stage_value(c, "-subdivisions"))
        .and_then(|v| v.parse::<i64>().ok())
        .map_or(DEFAULT_SUBDIVISIONS, |n| n.clamp(1, 1 << 16) as u32)
}

/// The `q3_patch_lights` record (see the module docs) for the patch surfaces listed:
/// `(surface index, shader name, area of the drawn tessellation in m^2)`. `scale` is
/// metres per Quake unit. `None` when no listed patch has a mesh.
pub fn q3map2_patch_lights(bsp: &Bsp, emitting: &[(usize, String, f64)], subdivisions: u32, scale: f64) -> Option<Value> {
    if emitting.is_empty() {
        return None;
    }
    let longest = group_longest_curves(bsp);
    let mut list = Vec::new();
    for (si, shader, area_m2) in emitting {
        let Some(s) = bsp.surfaces.get(*si) else { continue };
        // A control point that is not a number makes no mesh (nor a drawn surface).
        if !bsp.surface_verts(s).iter().all(|v| v.xyz.iter().chain(&v.normal).all(|x| x.is_finite())) {
            continue;
        }
        let iterations = iterations_for_curve(longest.get(si).copied().unwrap_or(0.0), subdivisions);
        let Some(mesh) = light_mesh(bsp.surface_verts(s), s.patch_w as usize, s.patch_h as usize, iterations) else { continue };
        let mut xyz = Vec::with_capacity(3 * mesh.verts.len());
        let mut normal = Vec::with_capacity(3 * mesh.verts.len());
        for v in &mesh.verts {
            xyz.extend(units::direction(v.xyz.to_array()).map(|x| x * scale));
            normal.extend(units::direction(v.normal.to_array()));
        }
        list.push(json!({ "shader": shader, "size": [mesh.width, mesh.height], "xyz": xyz, "normal": normal, "area_m2": area_m2 }));
    }
    (!list.is_empty()).then_some(Value::Array(list))
}

/// The `q3_patch_vertices` record (see the module docs): per drawn vertex-lit patch
/// `(surface, shader name, drawn area m^2, drawn area per control point m^2)`, its
/// control points as q3map2 lit them, or `None` when there are none. `scale` is metres
/// per Quake unit.
pub fn q3map2_patch_vertices(bsp: &Bsp, vertex_lit: &[(usize, String, f64, Vec<f64>)], scale: f64) -> Option<Value> {
    let mut list = Vec::new();
    for (si, shader, area_m2, point_area_m2) in vertex_lit {
        let Some(s) = bsp.surfaces.get(*si) else { continue };
        let verts = bsp.surface_verts(s);
        let (w, h) = (s.patch_w as usize, s.patch_h as usize);
        if verts.len() != w * h || point_area_m2.len() != verts.len() || !verts.iter().all(|v| v.xyz.iter().chain(&v.normal).all(|x| x.is_finite())) {
            continue;
        }
        let xyz: Vec<f64> = verts.iter().flat_map(|v| units::direction(v.xyz.map(f64::from)).map(|x| x * scale)).collect();
        let normal: Vec<f64> = verts.iter().flat_map(|v| units::direction(v.normal.map(f64::from))).collect();
        let rgb: Vec<u8> = verts.iter().flat_map(|v| [v.color[0], v.color[1], v.color[2]]).collect();
        list.push(json!({ "shader": shader, "size": [w, h], "xyz": xyz, "normal": normal, "rgb": rgb, "point_area_m2": point_area_m2, "area_m2": area_m2 }));
    }
    (!list.is_empty()).then_some(Value::Array(list))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f32, y: f32, z: f32) -> DrawVert {
        DrawVert { xyz: [x, y, z], normal: [0.0, 0.0, -1.0], ..Default::default() }
    }

    /// A quarter of a round lamp as oacmpdm1 builds them: two control lines collapsed to
    /// the centre, the third the rim (radius 32).
    fn quarter() -> Vec<DrawVert> {
        let c = v(0.0, 0.0, 0.0);
        let rim = [v(0.0, 32.0, 0.0), v(32.0, 32.0, 0.0), v(32.0, 0.0, 0.0)];
        // The map lists columns: verts[i * 3 + j] is column j's i-th point.
        let mut g = vec![c; 9];
        for (i, r) in rim.into_iter().enumerate() {
            g[i * 3 + 2] = r;
        }
        g
    }

    #[test]
    fn a_flat_quarter_lamp_keeps_its_centre_twice_and_three_rim_points() {
        assert_eq!(longest_curve(&quarter(), 3, 3), 0.0, "its measured lines are collapsed");
        let m = light_mesh(&quarter(), 3, 3, 0).unwrap();
        // The middle column (all at the centre) is dropped; the rim's middle point is on
        // the arc now, 0.25 of the way from the corner's control point: (24, 24).
        assert_eq!((m.width, m.height), (2, 3));
        let xyz: Vec<[f64; 3]> = m.verts.iter().map(|v| v.xyz.to_array()).collect();
        assert_eq!(xyz, vec![[0.0; 3], [0.0, 32.0, 0.0], [0.0; 3], [24.0, 24.0, 0.0], [0.0; 3], [32.0, 0.0, 0.0]]);
    }

    #[test]
    fn subdividing_doubles_the_spans_and_puts_every_point_on_the_surface() {
        // A 3x3 arch (z = 64 at the middle control line, so 32 on the surface there).
        let mut g = Vec::new();
        for i in 0..3 {
            for (j, z) in [0.0, 64.0, 0.0].into_iter().enumerate() {
                g.push(v(64.0 * j as f32, 64.0 * i as f32, z));
            }
        }
        let m = light_mesh(&g, 3, 3, 1).unwrap();
        // Across the arch: 5 points at t = 0, 1/4, 1/2, 3/4, 1; along it, straight: 2.
        assert_eq!((m.width, m.height), (5, 2));
        for (k, v) in m.verts[..5].iter().enumerate() {
            let t = k as f64 / 4.0;
            assert!((v.xyz[0] - 128.0 * t).abs() < 1e-9 && (v.xyz[2] - 128.0 * t * (1.0 - t)).abs() < 1e-9, "{k}: {:?}", v.xyz);
        }
    }

    #[test]
    fn iterations_follow_the_curves_length() {
        assert_eq!(iterations_for_curve(0.0, 8), 0);
        assert_eq!(iterations_for_curve(128.0, 8), 0);
        assert_eq!(iterations_for_curve(129.0, 8), 1);
        assert_eq!(iterations_for_curve(300.0, 8), 2);
        assert_eq!(iterations_for_curve(1e6, 8), 3);
        assert_eq!(iterations_for_curve(129.0, 4), 2);
    }

    #[test]
    fn the_light_stages_own_subdivisions_count() {
        assert_eq!(subdivisions_of(None), 8);
        assert_eq!(subdivisions_of(Some("q3map2 -meta -subdivisions 2 x.map; q3map2 -light -fast x.bsp")), 8);
        assert_eq!(subdivisions_of(Some("-light -fast -subdivisions 4")), 4);
        assert_eq!(subdivisions_of(Some("-light -subdivisions -3")), 1);
    }

    /// A map of one model whose surfaces are the given 3x3 patches.
    fn map_of(patches: &[Vec<DrawVert>]) -> Bsp {
        use crate::bsp::{Format, Model, OtherCounts, ShaderRef, Surface};
        let mut verts = Vec::new();
        let mut surfaces = Vec::new();
        for p in patches {
            let mut s = Surface::new(0, SurfaceType::Patch);
            (s.first_vert, s.num_verts, s.patch_w, s.patch_h) = (verts.len() as u32, 9, 3, 3);
            verts.extend_from_slice(p);
            surfaces.push(s);
        }
        Bsp {
            format: Format::Ibsp(46),
            entities: String::new(),
            shaders: vec![ShaderRef { name: "lamp".into(), surface_flags: 0, content_flags: 0 }],
            models: vec![Model { mins: [0.0; 3], maxs: [1.0; 3], first_surface: 0, num_surfaces: surfaces.len() as u32, first_brush: 0, num_brushes: 0 }],
            verts,
            indices: vec![],
            surfaces,
            lightmaps: vec![],
            collision: Default::default(),
            other: OtherCounts::default(),
        }
    }

    #[test]
    fn a_patch_takes_its_groups_longest_curve_and_a_broken_one_has_no_record() {
        // The quarter lamp (no curve of its own) touching a wide arch.
        let mut arch = Vec::new();
        for i in 0..3 {
            for (j, z) in [0.0, 128.0, 0.0].into_iter().enumerate() {
                arch.push(v(32.0 + 128.0 * j as f32, 64.0 * i as f32, z));
            }
        }
        let b = map_of(&[quarter(), arch]);
        let longest = group_longest_curves(&b);
        assert!(longest[&0] > 128.0 && longest[&0] == longest[&1], "{longest:?}");
        let rec = q3map2_patch_lights(&b, &[(0, "lamp".into(), 1.0)], 8, 1.0).unwrap();
        // The lamp is subdivided as the arch asks: its rim in 2^(k+1) spans.
        let k = iterations_for_curve(longest[&0], 8);
        assert!(k >= 1);
        assert_eq!(rec[0]["size"], serde_json::json!([2, (2 << k) + 1]));
        let mut broken = quarter();
        broken[4].xyz[0] = f32::NAN;
        assert!(q3map2_patch_lights(&map_of(&[broken]), &[(0, "lamp".into(), 1.0)], 8, 1.0).is_none());
    }

    #[test]
    fn patches_at_the_ends_of_the_float_range_group_without_overflow() {
        // Found by the bsp fuzz target: a control point at 1e30 lands in the cell
        // i64::MAX, whose neighbour once overflowed.
        let far = |s: f32| quarter().into_iter().map(|mut d| { d.xyz = d.xyz.map(|x| x * 0.0 + s); d }).collect::<Vec<_>>();
        let b = map_of(&[far(1e30), far(1e30), far(-f32::MAX), quarter()]);
        let longest = group_longest_curves(&b);
        assert_eq!(longest.len(), 4);
        assert!(longest.values().all(|l| l.is_finite()), "{longest:?}");
    }

    #[test]
    fn grids_of_other_shapes_have_no_mesh() {
        assert!(light_mesh(&quarter(), 3, 2, 0).is_none());
        assert!(light_mesh(&quarter()[..8], 3, 3, 0).is_none());
        assert!(light_mesh(&[], 0, 0, 0).is_none());
    }
}
