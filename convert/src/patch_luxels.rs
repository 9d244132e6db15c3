//! Where q3map2 sampled the luxels of a curved patch.
//!
//! A lightmap luxel is the light at one point, and for a brush face that point is where
//! the luxel's centre lands on the face. Not so on a curved Bezier patch. q3map2's light
//! stage (`MapRawLightmap`, case `MST_PATCH`) maps the patch's luxels on its own coarse
//! mesh of it ([`crate::lightmesh::light_mesh`]), and each luxel takes the first point of
//! that mesh's recursive subdivision that lands in it. So the point is on a chord of the
//! curve, anywhere in the luxel's square, and its side of the patch is not symmetric. A
//! light a few units from a column lights it where q3map2 put its samples, up to half a
//! luxel (8 units) from the luxel's centre on the drawn surface.
//!
//! The rules, read in q3map2's source (all in luxel units of the patch's raw lightmap,
//! `superSample` 1):
//! 1. **Layout** (`AddPatchToRawLightmap`): control point `(x, y)` of a `cw x ch` grid
//!    has lightmap coordinates `(sBasis x + 0.5, tBasis y + 0.5)` with
//!    `sBasis = (w - 1) / (cw - 1)` (f32) for a raw lightmap `w` luxels wide. The BSP
//!    stores them offset by the raw lightmap's place on its page; a patch whose stored
//!    coordinates do not have this shape (a flat patch, lit as a face) has no record.
//! 2. **Mesh**: the light mesh, lightmap coordinates interpolated with the positions.
//! 3. **Quads**, row by row: corners `pw = [(x, y), (x, y+1), (x+1, y+1), (x+1, y)]`
//!    taken from `r = (x + y) & 1` on (`pw[r..r + 4]`, wrapping).
//!    - `MapQuad`: when the first three corners make a plane (`PlaneFromPoints`) and the
//!      fourth lies within 0.5 unit of it, map the four corners, then `MapQuad_r`: split
//!      the pair of opposite edges holding the longest (in luxels) at their midpoints,
//!      map both midpoints, recurse into the two halves, until no edge is longer than
//!      one luxel.
//!    - Otherwise the triangles `(0, 1, 2)` and `(0, 2, 3)`, twice (`mapNonAxial` 0
//!      then 1), each through `MapTriangle`: its plane (a degenerate triangle maps
//!      nothing), its three corners, then with `mapNonAxial` the recursive split of its
//!      longest edge (`MapTriangle_r`), without it the same split of each edge that is
//!      axial in the lightmap (its two ends within 0.01 luxel in x or in y).
//! 4. **A point lands** (`MapSingleLuxel`) in luxel `(int x, int y)` (clamped into the
//!    raw lightmap). A luxel's first point sets its origin: the point pushed 1 unit
//!    along world x, towards the sign of the plane's x (q3map2 leaves the raw lightmap's
//!    projection axis at 0 for a curved patch; the shader's `q3map_lightmapSampleOffset`
//!    is not read here) and its normal; every later point adds its normal, and the sum
//!    is normalised at the end.
//!
//! 5. **A point in solid** (relight tests it with the map's solids): `MapSingleLuxel`
//!    tries it 0.5 unit away along two directions across the plane's normal, left,
//!    right, up, down, then the diagonals. On a curved patch these are the unit vectors
//!    of `MakeNormalVectors(plane normal)`, not the lightmap's axes as on a face (half a
//!    luxel there), so the record carries them per luxel.
//!
//! Not reproduced: a luxel whose first point stays in solid after every nudge takes a
//! later point of the mapping in q3map2 (relight leaves it out), and `-super` (the record
//! is only written at `superSample` 1: a recorded command line with `-super N`, N > 1,
//! writes none).
//!
//! The record convert writes into the scene's extras, `q3_patch_luxels`, has one entry
//! per drawn curved lightmapped patch: `shader`, `size`, `xyz`, `normal`, `area_m2` as
//! the light meshes' records (so relight matches it to the mesh the same way), and the
//! samples: `luxel_texel` (two whole numbers each: the luxel's texel in its atlas image),
//! `luxel_xyz` and `luxel_normal` (three each, glTF axes, metres), and `luxel_nudge`
//! (six each: the two unit directions of rule 5, glTF axes).

use crate::bsp::{Bsp, DrawVert, SurfaceType};
use crate::lightmesh::{self, LightMesh, Vert};
use crate::units;
use glam::{DVec2, DVec3};
use serde_json::{json, Value};
use std::collections::HashMap;

/// q3map2's `subdivideThreshold` (squared luxels: an edge no longer than one luxel stops).
const SUBDIVIDE_THRESHOLD: f64 = 1.0;
/// q3map2's `QUAD_PLANAR_EPSILON`, Quake units.
const QUAD_PLANAR_EPSILON: f64 = 0.5;
/// q3map2's `DEFAULT_LIGHTMAP_SAMPLE_OFFSET`, Quake units.
const SAMPLE_OFFSET: f64 = 1.0;
/// How far (luxels) the stored coordinates may be from the layout of rule 1.
const LAYOUT_TOLERANCE: f64 = 2e-3;
/// Recursion depth guard (a luxel edge halves each level; 2^40 luxels is no lightmap).
const MAX_DEPTH: u32 = 40;

/// One luxel's sample: its texel in the raw lightmap (`x`, `y` from 0) and q3map2's
/// origin (Quake units, the offset included) and normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LuxelSample {
    pub x: u32,
    pub y: u32,
    pub origin: DVec3,
    pub normal: DVec3,
    /// The directions of q3map2's nudges of this sample when it is in solid (rule 5).
    pub nudge: [DVec3; 2],
}

/// q3map2's `MakeNormalVectors`: two unit vectors across `forward` (a unit vector), from
/// a rotated copy of it.
fn make_normal_vectors(forward: DVec3) -> [DVec3; 2] {
    let r = DVec3::new(forward.z, -forward.x, forward.y);
    let right = (r - forward * r.dot(forward)).normalize_or_zero();
    [right, right.cross(forward)]
}

/// The raw lightmap of a curved patch as q3map2 laid it out (rule 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Layout {
    /// The raw lightmap's first texel on its page.
    pub offset: [i64; 2],
    /// Its size in luxels.
    pub size: [u32; 2],
}

/// Recognises rule 1's layout in the control points' stored coordinates (`page` texels
/// per unit of the page-normalised coordinates); `None` when they do not have it.
pub fn layout(ctrl: &[DrawVert], cw: usize, ch: usize, page: [usize; 2]) -> Option<Layout> {
    if cw < 3 || ch < 3 || ctrl.len() != cw * ch || page[0] == 0 || page[1] == 0 {
        return None;
    }
    let at = |x: usize, y: usize| DVec2::new(ctrl[y * cw + x].lightmap[0] as f64 * page[0] as f64, ctrl[y * cw + x].lightmap[1] as f64 * page[1] as f64);
    let first = at(0, 0);
    if !first.is_finite() {
        return None;
    }
    let offset = (first - DVec2::splat(0.5)).round();
    let span = (at(cw - 1, ch - 1) - first).round();
    if !(span.x >= (cw - 1) as f64 && span.y >= (ch - 1) as f64 && span.x < 1e6 && span.y < 1e6) {
        return None;
    }
    let size = [span.x as u32 + 1, span.y as u32 + 1];
    // The raw lightmap lies on its page (this also bounds the mapping's work by the
    // page's texels).
    if offset.x < 0.0 || offset.y < 0.0 || offset.x + f64::from(size[0]) > page[0] as f64 || offset.y + f64::from(size[1]) > page[1] as f64 {
        return None;
    }
    let (sb, tb) = basis(size, cw, ch);
    for y in 0..ch {
        for x in 0..cw {
            let want = offset + DVec2::new(f64::from(sb * x as f32 + 0.5), f64::from(tb * y as f32 + 0.5));
            if !((at(x, y) - want).abs().max_element() <= LAYOUT_TOLERANCE) {
                return None;
            }
        }
    }
    Some(Layout { offset: [offset.x as i64, offset.y as i64], size })
}

/// `sBasis`, `tBasis` (f32, as q3map2).
fn basis(size: [u32; 2], cw: usize, ch: usize) -> (f32, f32) {
    ((size[0] - 1) as f32 / (cw - 1) as f32, (size[1] - 1) as f32 / (ch - 1) as f32)
}

/// q3map2's `PlaneFromPoints`: the unit normal of `(p2 - p0) x (p1 - p0)` and its
/// distance, `None` for three points on a line.
fn plane(p0: DVec3, p1: DVec3, p2: DVec3) -> Option<(DVec3, f64)> {
    let n = (p2 - p0).cross(p1 - p0);
    let l = n.length();
    (l > 0.0).then(|| {
        let n = n / l;
        (n, n.dot(p0))
    })
}

/// The first longest edge `(i, i + 1)` of a polygon in the lightmap (luxels), when it is
/// longer than q3map2's `subdivideThreshold`; `None` stops the recursion.
fn longest_edge(dv: &[Vert]) -> Option<usize> {
    let mut max = None;
    let mut max_dist = 0.0;
    for i in 0..dv.len() {
        let d = (dv[i].lm - dv[(i + 1) % dv.len()].lm).length_squared();
        if d > max_dist {
            max_dist = d;
            max = Some(i);
        }
    }
    max.filter(|_| max_dist > SUBDIVIDE_THRESHOLD)
}

/// The luxels of one raw lightmap as the mapping fills them.
struct Luxels {
    size: [u32; 2],
    /// Per luxel: origin, normal sum, points landed, the first point's plane normal.
    cells: HashMap<(u32, u32), (DVec3, DVec3, u32, DVec3)>,
}

impl Luxels {
    /// `MapSingleLuxel` for a point `v` of a triangle or quad with plane normal `n`.
    fn land(&mut self, v: &Vert, n: DVec3) {
        let cell = |c: f64, size: u32| (c as i64).clamp(0, i64::from(size) - 1) as u32;
        let key = (cell(v.lm.x, self.size[0]), cell(v.lm.y, self.size[1]));
        self.cells
            .entry(key)
            .and_modify(|c| {
                c.1 += v.normal;
                c.2 += 1;
            })
            .or_insert_with(|| {
                let mut origin = v.xyz;
                origin.x += if n.x < 0.0 { -SAMPLE_OFFSET } else { SAMPLE_OFFSET };
                (origin, v.normal, 1, n)
            });
    }

    /// `MapTriangle_r`.
    fn triangle_r(&mut self, dv: [Vert; 3], n: DVec3, depth: u32) {
        let Some(max) = longest_edge(&dv).filter(|_| depth < MAX_DEPTH) else { return };
        let mid = lightmesh::lerp(&dv[max], &dv[(max + 1) % 3]);
        self.land(&mid, n);
        let mut a = dv;
        a[max] = mid;
        self.triangle_r(a, n, depth + 1);
        let mut b = dv;
        b[(max + 1) % 3] = mid;
        self.triangle_r(b, n, depth + 1);
    }

    /// `MapTriangle`; false for a degenerate triangle (nothing mapped).
    fn triangle(&mut self, dv: [Vert; 3], non_axial: bool) -> bool {
        let Some((n, _)) = plane(dv[0].xyz, dv[1].xyz, dv[2].xyz) else { return false };
        for v in &dv {
            self.land(v, n);
        }
        if non_axial {
            self.triangle_r(dv, n, 0);
            return true;
        }
        for i in 0..3 {
            let (a, b) = (dv[i].lm, dv[(i + 1) % 3].lm);
            if (a.x - b.x).abs() <= 0.01 || (a.y - b.y).abs() <= 0.01 {
                self.triangle_r([dv[i], dv[(i + 1) % 3], dv[(i + 1) % 3]], n, 0);
            }
        }
        true
    }

    /// `MapQuad_r`.
    fn quad_r(&mut self, dv: [Vert; 4], n: DVec3, depth: u32) {
        let Some(max) = longest_edge(&dv).filter(|_| depth < MAX_DEPTH) else { return };
        let max = max & 1;
        let m0 = lightmesh::lerp(&dv[max], &dv[(max + 1) % 4]);
        let m1 = lightmesh::lerp(&dv[max + 2], &dv[(max + 3) % 4]);
        self.land(&m0, n);
        self.land(&m1, n);
        if max == 0 {
            self.quad_r([dv[0], m0, m1, dv[3]], n, depth + 1);
            self.quad_r([m0, dv[1], dv[2], m1], n, depth + 1);
        } else {
            self.quad_r([dv[0], dv[1], m0, m1], n, depth + 1);
            self.quad_r([m1, m0, dv[2], dv[3]], n, depth + 1);
        }
    }

    /// `MapQuad`; false when the quad is not planar (the caller maps triangles).
    fn quad(&mut self, dv: [Vert; 4]) -> bool {
        let Some((n, d)) = plane(dv[0].xyz, dv[1].xyz, dv[2].xyz) else { return false };
        if (n.dot(dv[3].xyz) - d).abs() > QUAD_PLANAR_EPSILON {
            return false;
        }
        for v in &dv {
            self.land(v, n);
        }
        self.quad_r(dv, n, 0);
        true
    }
}

/// q3map2's luxel samples of a curved patch (rules 2-4): `mesh` is the light mesh of the
/// control points with their raw lightmap coordinates, `size` the raw lightmap's.
pub fn map_luxels(mesh: &LightMesh, size: [u32; 2]) -> Vec<LuxelSample> {
    let mut lx = Luxels { size, cells: HashMap::new() };
    let (w, h) = (mesh.width, mesh.height);
    for y in 0..h.saturating_sub(1) {
        for x in 0..w.saturating_sub(1) {
            let pw = [x + y * w, x + (y + 1) * w, x + 1 + (y + 1) * w, x + 1 + y * w];
            let r = (x + y) & 1;
            let dv = [0, 1, 2, 3].map(|k| mesh.verts[pw[(r + k) % 4]]);
            if lx.quad(dv) {
                continue;
            }
            for non_axial in [false, true] {
                lx.triangle([dv[0], dv[1], dv[2]], non_axial);
                lx.triangle([dv[0], dv[2], dv[3]], non_axial);
            }
        }
    }
    let mut out: Vec<LuxelSample> = lx
        .cells
        .into_iter()
        .filter_map(|((x, y), (origin, sum, _, plane))| {
            let l = sum.length();
            (l > 0.0 && origin.is_finite()).then(|| LuxelSample { x, y, origin, normal: sum / l, nudge: make_normal_vectors(plane) })
        })
        .collect();
    out.sort_by_key(|s| (s.y, s.x));
    out
}

/// The samples of one drawn patch surface, in its raw lightmap, with the layout and the
/// light mesh they were mapped on (its `lm` in raw luxels); `None` when it is not a curved
/// lightmapped patch as q3map2 lays them out.
pub fn patch_samples(ctrl: &[DrawVert], cw: usize, ch: usize, page: [usize; 2], iterations: u32) -> Option<(Layout, LightMesh, Vec<LuxelSample>)> {
    let layout = layout(ctrl, cw, ch, page)?;
    if !ctrl.iter().all(|v| v.xyz.iter().chain(&v.normal).all(|x| x.is_finite())) {
        return None;
    }
    let (sb, tb) = basis(layout.size, cw, ch);
    let raw: Vec<DrawVert> = (0..ch)
        .flat_map(|y| (0..cw).map(move |x| (x, y)))
        .map(|(x, y)| DrawVert { lightmap: [sb * x as f32 + 0.5, tb * y as f32 + 0.5], ..ctrl[y * cw + x] })
        .collect();
    let mesh = lightmesh::light_mesh(&raw, cw, ch, iterations)?;
    let samples = map_luxels(&mesh, layout.size);
    Some((layout, mesh, samples))
}

/// The `-super N` of a recorded command line's light stage (1 without one).
pub fn super_sample_of(cmdline: Option<&str>) -> u32 {
    cmdline.and_then(|c| lightmesh::light_stage_value(c, "-super")).and_then(|v| v.parse::<u32>().ok()).map_or(1, |n| n.max(1))
}

/// A drawn lightmapped patch: its surface, shader name, drawn area (m^2), and where its
/// page lies in its atlas image (texels of the page's first texel) with the page's size.
pub struct LitPatch {
    pub surface: usize,
    pub shader: String,
    pub area_m2: f64,
    pub page_origin: [usize; 2],
    pub page_size: [usize; 2],
}

/// The `q3_patch_luxels` record (see the module docs), or `None` when no listed patch is
/// curved. `scale` is metres per Quake unit.
pub fn q3map2_patch_luxels(bsp: &Bsp, patches: &[LitPatch], subdivisions: u32, scale: f64) -> Option<Value> {
    if patches.is_empty() {
        return None;
    }
    let longest = lightmesh::group_longest_curves(bsp);
    let mut list = Vec::new();
    for p in patches {
        let Some(s) = bsp.surfaces.get(p.surface).filter(|s| s.kind == SurfaceType::Patch) else { continue };
        let (cw, ch) = (s.patch_w as usize, s.patch_h as usize);
        let ctrl = bsp.surface_verts(s);
        let iterations = lightmesh::iterations_for_curve(longest.get(&p.surface).copied().unwrap_or(0.0), subdivisions);
        let Some((layout, mesh, samples)) = patch_samples(ctrl, cw, ch, p.page_size, iterations) else { continue };
        let mut texel = Vec::with_capacity(2 * samples.len());
        let mut xyz = Vec::with_capacity(3 * samples.len());
        let mut normal = Vec::with_capacity(3 * samples.len());
        let mut nudge = Vec::with_capacity(6 * samples.len());
        for q in &samples {
            let tx = layout.offset[0] + i64::from(q.x);
            let ty = layout.offset[1] + i64::from(q.y);
            // A luxel off its page (a broken layout) is left out.
            if tx < 0 || ty < 0 || tx >= p.page_size[0] as i64 || ty >= p.page_size[1] as i64 {
                continue;
            }
            texel.extend([p.page_origin[0] as i64 + tx, p.page_origin[1] as i64 + ty]);
            xyz.extend(units::direction(q.origin.to_array()).map(|x| x * scale));
            normal.extend(units::direction(q.normal.to_array()));
            for d in q.nudge {
                nudge.extend(units::direction(d.to_array()));
            }
        }
        if texel.is_empty() {
            continue;
        }
        let mxyz: Vec<f64> = mesh.verts.iter().flat_map(|v| units::direction(v.xyz.to_array()).map(|x| x * scale)).collect();
        let mnormal: Vec<f64> = mesh.verts.iter().flat_map(|v| units::direction(v.normal.to_array())).collect();
        list.push(json!({
            "shader": p.shader, "size": [mesh.width, mesh.height], "xyz": mxyz, "normal": mnormal, "area_m2": p.area_m2,
            "luxel_texel": texel, "luxel_xyz": xyz, "luxel_normal": normal, "luxel_nudge": nudge,
        }));
    }
    (!list.is_empty()).then_some(Value::Array(list))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A half column as the `column` fixture builds it: 3 rows of 5 control points
    /// (two quarter circles of radius 80 about the z axis), rows at z = 0, 96, 192,
    /// stored on a 128 x 128 page at `offset` with a raw lightmap `w x h`.
    fn column(w: u32, h: u32, offset: [f32; 2]) -> Vec<DrawVert> {
        let ring = [(-80.0, 0.0), (-80.0, 80.0), (0.0, 80.0), (80.0, 80.0), (80.0, 0.0)];
        let mut v = Vec::new();
        let (sb, tb) = ((w - 1) as f32 / 4.0, (h - 1) as f32 / 2.0);
        for (y, z) in [0.0f32, 96.0, 192.0].into_iter().enumerate() {
            for (x, (px, py)) in ring.into_iter().enumerate() {
                let n = DVec3::new(px, py, 0.0).normalize_or_zero();
                let lm = [(offset[0] + sb * x as f32 + 0.5) / 128.0, (offset[1] + tb * y as f32 + 0.5) / 128.0];
                v.push(DrawVert { xyz: [px as f32, py as f32, z], normal: [n.x as f32, n.y as f32, 0.0], lightmap: lm, ..Default::default() });
            }
        }
        v
    }

    #[test]
    fn the_layout_is_recognised_and_a_flat_projection_is_not() {
        let c = column(17, 13, [40.0, 7.0]);
        assert_eq!(layout(&c, 5, 3, [128, 128]), Some(Layout { offset: [40, 7], size: [17, 13] }));
        // A planar projection: lightmap coordinates from x and z.
        let flat: Vec<DrawVert> = c.iter().map(|v| DrawVert { lightmap: [v.xyz[0] / 2048.0 + 0.3, v.xyz[2] / 2048.0], ..*v }).collect();
        assert_eq!(layout(&flat, 5, 3, [128, 128]), None);
        // A raw lightmap that would run off its page: none (a hostile file's coordinates
        // cannot make the mapping walk millions of luxels).
        assert_eq!(layout(&column(17, 13, [120.0, 7.0]), 5, 3, [128, 128]), None);
        let huge: Vec<DrawVert> = c.iter().map(|v| DrawVert { lightmap: [v.lightmap[0] * 5000.0, v.lightmap[1]], ..*v }).collect();
        assert_eq!(layout(&huge, 5, 3, [128, 128]), None);
        assert_eq!(patch_samples(&huge, 5, 3, [128, 128], 2), None);
    }

    #[test]
    fn every_luxel_gets_one_sample_on_the_coarse_mesh() {
        let c = column(17, 13, [0.0, 0.0]);
        let (lay, _, s) = patch_samples(&c, 5, 3, [128, 128], 2).unwrap();
        assert_eq!(lay.size, [17, 13]);
        // Every luxel of the raw lightmap has a sample (edges of one luxel at most).
        assert_eq!(s.len(), 17 * 13);
        for q in &s {
            // Near the curve (a quadratic Bezier strays up to 3.6 units outside the
            // circle of radius 80; chords and the sample offset of 1 unit along x);
            // the normal unit and horizontal.
            let r = q.origin.x.hypot(q.origin.y);
            assert!(r <= 85.0 && r > 72.0, "{q:?}");
            assert!((q.normal.length() - 1.0).abs() < 1e-9 && q.normal.z.abs() < 1e-9);
            assert!(q.origin.y >= -1e-9 && (0.0..=192.0).contains(&q.origin.z));
        }
        // The first row of luxels: z = 0 (the bottom edge is mapped first), the last: 192.
        assert!(s.iter().filter(|q| q.y == 0).all(|q| q.origin.z == 0.0));
        assert!(s.iter().filter(|q| q.y == 12).all(|q| q.origin.z == 192.0));
    }

    #[test]
    fn a_luxel_takes_the_first_point_that_lands_in_it() {
        // A raw lightmap 7 wide over 4 spans: sBasis 1.5, so control points land at
        // x = 0.5, 2, 3.5, 5, 6.5: luxel 2 is first reached at its left edge (x = 2.0),
        // not at its centre.
        let c = column(7, 5, [0.0, 0.0]);
        let (_, _, s) = patch_samples(&c, 5, 3, [128, 128], 0).unwrap();
        let q = s.iter().find(|q| q.x == 2 && q.y == 0).unwrap();
        // Control point 1 of the bottom row is (-80, 80, 0), off the curve: the mesh
        // moved it onto the curve, to (-60, 60, 0) (the quarter circle's middle), and
        // the quad's plane faces +x: one unit that way.
        assert!((q.origin - DVec3::new(-59.0, 60.0, 0.0)).length() < 1e-9, "{q:?}");
    }

    /// Rule 5: the nudge directions are q3map2's `MakeNormalVectors` of the plane the
    /// luxel's first point was mapped with: unit, across the normal and each other.
    #[test]
    fn each_luxel_carries_q3map2s_nudge_directions() {
        // MakeNormalVectors((0, 0, 1)): right from the rotated (1, -0, 0), up = right x f.
        let [r, u] = make_normal_vectors(DVec3::Z);
        assert!((r - DVec3::X).length() < 1e-12 && (u - DVec3::new(0.0, -1.0, 0.0)).length() < 1e-12, "{r} {u}");
        let c = column(17, 13, [0.0, 0.0]);
        let (_, _, s) = patch_samples(&c, 5, 3, [128, 128], 2).unwrap();
        for q in &s {
            let [a, b] = q.nudge;
            assert!((a.length() - 1.0).abs() < 1e-9 && (b.length() - 1.0).abs() < 1e-9, "{q:?}");
            assert!(a.dot(b).abs() < 1e-9, "{q:?}");
            // Across a plane of the column: the normal is horizontal, so one of them is
            // nearly vertical and the other across the normal in the horizontal.
            assert!(a.dot(q.normal).abs() < 0.2 && b.dot(q.normal).abs() < 0.2, "{q:?}");
        }
    }

    #[test]
    fn super_sampling_is_read_from_the_light_stage() {
        assert_eq!(super_sample_of(None), 1);
        assert_eq!(super_sample_of(Some("-bsp -meta; -light -fast -super 2")), 2);
        assert_eq!(super_sample_of(Some("-bsp -super 4; -light -fast")), 1);
    }
}
