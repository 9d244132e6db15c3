//! The luxel-space target: one objective row per lightmap texel ("luxel"), at the point
//! of the surface the texel was baked for.
//!
//! q3map2 computed each luxel as the irradiance at one point of the surface (lightmap
//! coordinates put vertices on luxel centres, CONVENTIONS.md). The engine then filters
//! the luxels bilinearly. The thesis's target (the [`crate::target`] projection onto
//! vertices) compares the model *at a vertex* with that filtered image averaged over the
//! vertex's hat function: at a hard shadow edge the two cannot agree, whatever the lights
//! (the bundled sample's floor error is 7% for the true lights, almost all of it at shadow
//! edges). Here the model is instead evaluated where q3map2 evaluated it, so the true
//! lights reproduce the data up to its 8-bit quantisation.
//!
//! For every lightmapped triangle, the texel centres `c` inside its TEXCOORD_1 footprint
//! (in texel units, centres at half-integers, a tolerance of [`EDGE_TOLERANCE`] in
//! barycentric coordinates so that centres on an edge count) become rows:
//!
//! - position and normal: the triangle's barycentric interpolation at `c`;
//! - area `A` [m^2]: the world area of one texel, `area_world / area_texels`;
//! - albedo: the mean of 4x4 albedo samples spread over the texel's square (mapped to
//!   TEXCOORD_0 by the triangle's affine map), sRGB decoded, times the base colour factor;
//! - target `t_c = albedo_c * decode(byte_c)` of the texel itself (no filtering);
//! - censored texels (a channel at 255) are lower bounds on every channel, weight 0.
//!
//! A texel is claimed by the first triangle that contains its centre (triangles sharing a
//! lightmap block share its texels). Vertex-lit materials keep their per-vertex rows.
//!
//! Invariant: every row has `A > 0`, a unit normal and finite values.

use glam::{DVec2, Vec2, Vec3};

use crate::rows::{Row, Rows, Sampling, SolidAhead};
use crate::trace::bvh::Bvh;
use crate::trace::solids::Solids;
use crate::scene::{Lighting, Scene};
use crate::rows::projection::Target;
use crate::texel;

/// A texel centre counts as inside a triangle down to this barycentric coordinate.
pub const EDGE_TOLERANCE: f64 = 1e-4;
/// The footprint's bounding box is widened by this many texels (f32 rounding of texel
/// centres; the barycentric test with [`EDGE_TOLERANCE`] decides).
const BOX_TOLERANCE: f64 = 1e-3;
/// A triangle whose lightmap footprint (or its bounding box: a sliver can be thin but
/// long) spans more texels than this is refused (its UVs are not a lightmap's); the count
/// is reported.
pub const MAX_TEXELS_PER_TRIANGLE: f64 = 4.0 * 1024.0 * 1024.0;
/// Albedo samples per texel side.
const ALBEDO_SAMPLES: usize = 4;

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct LuxelStats {
    /// Luxel rows (texels claimed by a triangle).
    pub luxels: usize,
    /// Luxels with a channel at 255 (lower bounds).
    pub censored: usize,
    /// Rows from vertex-lit materials (per-vertex colours).
    pub vertex_rows: usize,
    /// Of those, rows at the control points of vertex-lit patches, where q3map2 lit them
    /// (scene extras `q3_patch_vertices`, [`patch_control_point_rows`]).
    pub patch_control_points: usize,
    /// Vertex-lit patches whose record no longer matches the mesh (their vertices are
    /// rows as any vertex-lit surface's).
    pub patch_records_unmatched: usize,
    /// Control points of vertex-lit patches in solid, sampled where q3map2's nudge found
    /// clear ([`vertex_sample_point`]), with the normal of the patch's last clear point
    /// before them (q3map2 never sets the normal of a point in solid).
    pub vertices_nudged: usize,
    /// Control points left out: in solid wherever q3map2's nudge tried (it gave them the
    /// surface's mean), or before any clear point of their patch (no normal: q3map2 left
    /// them unlit).
    pub vertices_in_solid: usize,
    /// Luxel rows of curved lightmapped patches at q3map2's own sample points (scene
    /// extras `q3_patch_luxels`, [`patch_luxel_samples`]).
    pub patch_luxels: usize,
    /// Curved lightmapped patches whose record no longer matches the mesh (their luxels
    /// are sampled on the mesh, at the texel centres).
    pub patch_luxel_records_unmatched: usize,
    /// Lightmapped triangles whose footprint holds no texel centre (slivers).
    pub triangles_without_luxel: usize,
    /// Lightmapped triangles refused: degenerate or absurd lightmap UVs.
    pub triangles_refused: usize,
    /// Luxels left out: occluded in the map's solids ([`place_in_solids`]; q3map2 filled
    /// them from their neighbours) or buried among the faces ([`drop_buried`]: enclosed,
    /// the game never shows them).
    pub buried: usize,
    /// Luxels whose sample point lay just behind a wall and was nudged out (see
    /// [`nudge_out_of_solid`]), as q3map2 does.
    pub nudged: usize,
    /// Luxels whose sample point lies on a wall's plane with the wall on Quake's positive
    /// side ([`mark_solid_ahead`]).
    pub on_solid_plane: usize,
    /// How solid was found: `"map"` (the BSP's own solids, [`place_in_solids`]) or
    /// `"faces"` (guessed from the mesh, [`nudge_out_of_solid`]).
    pub solids_from: &'static str,
}

/// The luxel rows and how they were made.
#[derive(Debug, Clone)]
pub struct Luxels {
    /// Luxel rows first (those with a texel), then the vertex-lit rows.
    pub rows: Rows,
    /// Per luxel row, the two steps its sample is nudged along when in solid (times
    /// `NUDGE_TEXELS`), m: for a face's luxel one texel along the lightmap's x and y (the
    /// triangle's lightmap mapping inverted), for a curved patch's recorded luxel its own
    /// two directions scaled so the nudge is `CURVED_NUDGE_UNITS`; zero for vertex-lit rows.
    pub texel_axes: Vec<[Vec3; 2]>,
    pub stats: LuxelStats,
}

/// Builds the rows: one per lightmap texel of the lightmapped triangles, and the rows of
/// `vertex_target` (a per-vertex projection of the same mesh) for vertex-lit materials;
/// with q3map2's sampling for the scene's units ([`Sampling::q3map2`]).
pub fn rows(scene: &Scene, vertex_target: &Target, scene_diagonal: f32) -> Luxels {
    let mesh = &scene.mesh;
    let lit = scene.materials.iter().find(|m| m.lighting == Lighting::Lightmap);
    let (ob, per_byte) = lit.map_or((2, 1.0), |m| (m.overbright_bits, m.stored_per_light_byte()));
    let mut pb = Rows::new(Sampling::q3map2(scene_diagonal, scene.units_m, ob, per_byte));
    let sample_offset = crate::scene::q3map2::SAMPLE_OFFSET_UNITS * scene.units_m;
    let mut st = LuxelStats::default();
    // Which texels are taken, per lightmap texture (allocated for lightmaps only).
    let mut claimed: Vec<Option<Vec<bool>>> = vec![None; scene.textures.len()];
    let mut texel_axes = Vec::new();
    let (record_of_tri, patch_samples) = patch_luxel_samples(scene, &mut st);
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let mat = &scene.materials[mesh.tri_material[t] as usize];
        if mat.lighting != Lighting::Lightmap {
            continue;
        }
        let Some(lm_index) = mat.lightmap else { continue };
        let lm = &scene.textures[lm_index];
        let (w, h) = (lm.width as usize, lm.height as usize);
        let taken = claimed[lm_index].get_or_insert_with(|| vec![false; w * h]);
        let tri = tri.map(|i| i as usize);
        let size = DVec2::new(w as f64, h as f64);
        let p = tri.map(|v| mesh.uv1[v].as_dvec2() * size);
        let e1 = p[1] - p[0];
        let e2 = p[2] - p[0];
        let det = e1.perp_dot(e2);
        let uv_area = 0.5 * det.abs();
        let world_area = mesh.triangle_area(t) as f64;
        if !(uv_area > crate::rows::projection::MIN_LIGHTMAP_TEXELS as f64) || !(uv_area <= MAX_TEXELS_PER_TRIANGLE) || !(world_area > 0.0) || !world_area.is_finite() {
            st.triangles_refused += 1;
            continue;
        }
        let texel_area = (world_area / uv_area) as f32;
        let lo = p[0].min(p[1]).min(p[2]);
        let hi = p[0].max(p[1]).max(p[2]);
        // Texel x has its centre at x + 0.5. The box is widened by BOX_TOLERANCE: q3map2
        // puts vertices on texel centres, and the f32 coordinate of a centre can fall a
        // hair outside it (1.50000003), which must not lose the face's edge row.
        let x0 = ((lo.x - 0.5 - BOX_TOLERANCE).ceil().max(0.0)) as usize;
        let y0 = ((lo.y - 0.5 - BOX_TOLERANCE).ceil().max(0.0)) as usize;
        let x1 = ((hi.x - 0.5 + BOX_TOLERANCE).floor().min(w as f64 - 1.0)).max(-1.0) as i64;
        let y1 = ((hi.y - 0.5 + BOX_TOLERANCE).floor().min(h as f64 - 1.0)).max(-1.0) as i64;
        let box_texels = (x1 - x0 as i64 + 1).max(0) as f64 * (y1 - y0 as i64 + 1).max(0) as f64;
        if box_texels > MAX_TEXELS_PER_TRIANGLE {
            st.triangles_refused += 1;
            continue;
        }
        let [pa, pb_, pc] = tri.map(|v| mesh.positions[v]);
        let [na, nb, nc] = tri.map(|v| mesh.normals[v]);
        let [ua, ub, uc] = tri.map(|v| mesh.uv0[v]);
        let face_normal = (pb_ - pa).cross(pc - pa).try_normalize().unwrap_or(Vec3::Z);
        // d(position)/d(texel x) and d/d(texel y): the inverse of the lightmap mapping.
        let axes = {
            let (w1, w2) = ((pb_ - pa).as_dvec3(), (pc - pa).as_dvec3());
            let ax = (w1 * e2.y - w2 * e1.y) / det;
            let ay = (w2 * e1.x - w1 * e2.x) / det;
            [ax.as_vec3(), ay.as_vec3()]
        };
        let bary = |c: DVec2| -> [f64; 3] {
            let d = c - p[0];
            let b1 = d.perp_dot(e2) / det;
            let b2 = e1.perp_dot(d) / det;
            [1.0 - b1 - b2, b1, b2]
        };
        let mut found = false;
        for y in y0 as i64..=y1 {
            for x in x0 as i64..=x1 {
                let (x, y) = (x as usize, y as usize);
                let c = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                let b = bary(c);
                if b.iter().any(|&v| v < -EDGE_TOLERANCE) {
                    continue;
                }
                found = true;
                if taken[y * w + x] {
                    continue;
                }
                taken[y * w + x] = true;
                let bf = b.map(|v| v as f32);
                let mut row_axes = axes;
                let (pos, normal) = match record_of_tri.get(t).copied().flatten().and_then(|k| patch_samples[k].get(&[x as u32, y as u32])) {
                    // Where q3map2 sampled a curved patch's luxel (its offset included),
                    // nudged out of solid half a unit along its own directions.
                    Some(&(pos, normal, nudge)) => {
                        st.patch_luxels += 1;
                        if let Some(d) = nudge {
                            row_axes = d.map(|v| v * crate::scene::q3map2::CURVED_NUDGE_UNITS / crate::scene::q3map2::NUDGE_TEXELS * scene.units_m);
                        }
                        (pos, normal)
                    }
                    None => {
                        let normal = (na * bf[0] + nb * bf[1] + nc * bf[2]).try_normalize().unwrap_or(face_normal);
                        // q3map2's sample origin: the surface point pushed off along the normal.
                        (pa * bf[0] + pb_ * bf[1] + pc * bf[2] + normal * sample_offset, normal)
                    }
                };
                // Albedo: mean over the texel's square, mapped affinely to TEXCOORD_0.
                let mut alb = [0.0f32; 3];
                let k = ALBEDO_SAMPLES;
                for sy in 0..k {
                    for sx in 0..k {
                        let s = DVec2::new(x as f64 + (sx as f64 + 0.5) / k as f64, y as f64 + (sy as f64 + 0.5) / k as f64);
                        let q = bary(s).map(|v| v as f32);
                        let uv: Vec2 = ua * q[0] + ub * q[1] + uc * q[2];
                        let a = match mat.albedo {
                            Some(i) => texel::bilinear(&scene.textures[i], uv.x, uv.y, texel::srgb_byte_to_linear),
                            None => [1.0; 3],
                        };
                        for ch in 0..3 {
                            alb[ch] += a[ch];
                        }
                    }
                }
                let f = mat.albedo_factor;
                let albedo = [0, 1, 2].map(|ch| alb[ch] / (k * k) as f32 * f[ch]);
                let o = (y * w + x) * 4;
                let bytes = [lm.rgba8[o], lm.rgba8[o + 1], lm.rgba8[o + 2]];
                let iv = bytes.map(|b| mat.interval(b));
                let lo = [0, 1, 2].map(|ch| albedo[ch] * iv[ch].0);
                let hi = [0, 1, 2].map(|ch| albedo[ch] * iv[ch].1);
                let censored = mat.censored(&bytes);
                if !pos.is_finite() || !hi.iter().all(|v| v.is_finite()) {
                    continue;
                }
                let base = Row { vertex: u32::MAX, material: mesh.tri_material[t], texel: [lm_index as u32, x as u32, y as u32], pos, normal, albedo, lo, hi, weight: [1.0; 3], lower: [0.0; 3], area: texel_area, solid_ahead: SolidAhead::NONE, two_sided: mat.double_sided };
                if censored {
                    // Every channel of a clamped texel is a lower bound (q3map2 kept its hue).
                    st.censored += 1;
                    pb.push(base.lower_bound());
                } else {
                    pb.push(base);
                }
                texel_axes.push(row_axes);
                st.luxels += 1;
            }
        }
        if !found {
            st.triangles_without_luxel += 1;
        }
    }
    let (control_points, by_patch) = patch_control_point_rows(scene, vertex_target, &mut st);
    for v in 0..mesh.positions.len() {
        let mat = &scene.materials[mesh.v_material[v] as usize];
        if mat.lighting != Lighting::Vertex || !(vertex_target.area[v] > 0.0) || by_patch[v] {
            continue;
        }
        let has = (0..3).any(|c| vertex_target.weight[v][c] > 0.0 || vertex_target.lower[v][c] > 0.0);
        if has {
            let t = vertex_target;
            pb.push(Row { vertex: v as u32, material: mesh.v_material[v], texel: [u32::MAX; 3], pos: mesh.positions[v], normal: mesh.normals[v], albedo: t.albedo[v], lo: t.value[v], hi: t.hi[v], weight: t.weight[v], lower: t.lower[v], area: t.area[v], solid_ahead: SolidAhead::NONE, two_sided: mat.double_sided });
            st.vertex_rows += 1;
            texel_axes.push([Vec3::ZERO; 2]);
        }
    }
    for r in control_points {
        pb.push(r);
        st.vertex_rows += 1;
        texel_axes.push([Vec3::ZERO; 2]);
    }
    pb.finish();
    Luxels { rows: pb, texel_axes, stats: st }
}

/// A curved patch's luxel samples by texel (`[x, y]` in its lightmap image): point, normal.
type LuxelSamples = std::collections::HashMap<[u32; 2], (Vec3, Vec3, Option<[Vec3; 2]>)>;

/// Where q3map2 sampled the luxels of the curved lightmapped patches that the scene's
/// `q3_patch_luxels` record still describes
/// ([`crate::model::patch_mesh::match_triangles_by_texel`]): per triangle, the record that
/// stands for it (an index into the second list). q3map2 mapped a curved patch's luxels on its own
/// coarse mesh of it, each at the first point of that mesh's subdivision that landed in
/// the luxel (convert's `patch_luxels`), up to half a luxel from the texel's centre on
/// the drawn surface.
fn patch_luxel_samples(scene: &Scene, st: &mut LuxelStats) -> (Vec<Option<usize>>, Vec<LuxelSamples>) {
    let (mut record_of_tri, mut samples) = (Vec::new(), Vec::new());
    if scene.patch_luxels.is_empty() {
        return (record_of_tri, samples);
    }
    let mesh = &scene.mesh;
    let shader_of_tri: Vec<Option<&str>> = mesh
        .tri_material
        .iter()
        .map(|&m| scene.materials.get(m as usize).filter(|m| m.lighting == Lighting::Lightmap).map(|m| m.name.split('#').next().unwrap_or_default()))
        .collect();
    // Each triangle's lightmap footprint's centre, texels of its lightmap image.
    let texel_of_tri: Vec<Vec2> = mesh
        .triangles
        .iter()
        .zip(&mesh.tri_material)
        .map(|(tri, &m)| {
            let size = scene.materials.get(m as usize).and_then(|m| m.lightmap).and_then(|i| scene.textures.get(i)).map_or(Vec2::ZERO, |t| Vec2::new(t.width as f32, t.height as f32));
            tri.iter().map(|&v| mesh.uv1[v as usize]).sum::<Vec2>() / 3.0 * size
        })
        .collect();
    let matched = crate::model::patch_mesh::match_triangles_by_texel(&scene.patch_luxels, &mesh.positions, &mesh.triangles, &shader_of_tri, &texel_of_tri, scene.units_m);
    record_of_tri = vec![None; mesh.triangles.len()];
    for (pm, tris) in scene.patch_luxels.iter().zip(matched) {
        let Some(tris) = tris else {
            st.patch_luxel_records_unmatched += 1;
            continue;
        };
        for t in tris {
            record_of_tri[t as usize] = Some(samples.len());
        }
        samples.push(pm.luxels.iter().filter(|l| l.pos.is_finite() && l.normal.is_finite()).map(|l| (l.texel, (l.pos, l.normal, l.nudge))).collect());
    }
    (record_of_tri, samples)
}

/// The rows of the vertex-lit patches that the scene's `q3_patch_vertices` record still
/// describes ([`crate::model::patch_mesh::match_triangles`]): one per control point, where
/// q3map2 lit it (`IlluminateVertexes` samples a patch at its control points; the game
/// draws their colours blended by the Bezier basis), with q3map2's own bytes and the drawn
/// area the point's basis covers (a point the drawn mesh never shows has none, and no
/// row). Albedo: that of the patch's mesh vertex nearest the point. Only where
/// `vertex_target` carries the patch's vertex colours, as the vertex rows. Returns the rows
/// and which mesh vertices they stand for (those get no row of their own).
pub fn patch_control_point_rows(scene: &Scene, vertex_target: &Target, st: &mut LuxelStats) -> (Vec<Row>, Vec<bool>) {
    let mesh = &scene.mesh;
    let mut by_patch = vec![false; mesh.positions.len()];
    let mut out = Vec::new();
    if scene.patch_vertices.is_empty() {
        return (out, by_patch);
    }
    let shader_of_tri: Vec<Option<&str>> = mesh
        .tri_material
        .iter()
        .map(|&m| scene.materials.get(m as usize).filter(|m| m.lighting == Lighting::Vertex).map(|m| m.name.split('#').next().unwrap_or_default()))
        .collect();
    let matched = crate::model::patch_mesh::match_triangles(&scene.patch_vertices, &mesh.positions, &mesh.triangles, &shader_of_tri, scene.units_m);
    for (pm, tris) in scene.patch_vertices.iter().zip(matched) {
        let Some(tris) = tris else {
            st.patch_records_unmatched += 1;
            continue;
        };
        let verts: Vec<usize> = {
            let mut v: Vec<usize> = tris.iter().flat_map(|&t| mesh.triangles[t as usize]).map(|i| i as usize).collect();
            v.sort_unstable();
            v.dedup();
            v
        };
        // As the vertex rows: only where the target carries the vertex colours (a render
        // of the model alone, `pipeline::render_on`, has luxel rows only).
        if !verts.iter().any(|&v| vertex_target.area.get(v).is_some_and(|&a| a > 0.0)) {
            continue;
        }
        let material = mesh.tri_material[tris[0] as usize];
        let mat = &scene.materials[material as usize];
        for &v in &verts {
            by_patch[v] = true;
        }
        // q3map2's normal for a point in solid: the last clear point's of the surface.
        let mut last_clear_normal: Option<Vec3> = None;
        for k in 0..pm.pos.len() {
            let (Some(&area), Some(&bytes)) = (pm.point_area_m2.get(k), pm.rgb.get(k)) else { continue };
            let own_normal = pm.normal[k].try_normalize();
            let (pos, normal) = match scene.solids.as_ref().map(|s| vertex_sample_point(s, pm.pos[k])) {
                Some(Some(p)) if p == pm.pos[k] => {
                    last_clear_normal = own_normal.or(last_clear_normal);
                    (p, own_normal)
                }
                Some(Some(p)) => {
                    if area > 0.0 {
                        st.vertices_nudged += usize::from(last_clear_normal.is_some());
                        st.vertices_in_solid += usize::from(last_clear_normal.is_none());
                    }
                    (p, last_clear_normal)
                }
                Some(None) => {
                    st.vertices_in_solid += usize::from(area > 0.0);
                    continue;
                }
                None => (pm.pos[k], own_normal),
            };
            // A point in solid before any clear one has no normal in q3map2 (nothing
            // lights it): left out.
            let Some(normal) = normal else { continue };
            if !(area > 0.0) || !pos.is_finite() {
                continue;
            }
            let Some(&near) = verts.iter().min_by(|&&a, &&b| (mesh.positions[a] - pm.pos[k]).length_squared().total_cmp(&(mesh.positions[b] - pm.pos[k]).length_squared())) else { continue };
            let Some(&albedo) = vertex_target.albedo.get(near) else { continue };
            let iv = bytes.map(|b| mat.interval(b));
            let lo = [0, 1, 2].map(|c| albedo[c] * iv[c].0);
            let hi = [0, 1, 2].map(|c| albedo[c] * iv[c].1);
            let base = Row { vertex: u32::MAX, material, texel: [u32::MAX; 3], pos, normal, albedo, lo, hi, weight: [1.0; 3], lower: [0.0; 3], area, solid_ahead: SolidAhead::NONE, two_sided: mat.double_sided };
            out.push(if mat.censored(&bytes) { base.lower_bound() } else { base });
            st.patch_control_points += 1;
        }
    }
    (out, by_patch)
}

/// Probe directions of [`buried`], in the frame of the row's normal `(t1, t2, n)`: the
/// normal itself, then 8 directions 60 degrees from it.
fn probe_directions() -> [[f32; 3]; 9] {
    let (s, c) = (60f32.to_radians().sin(), 60f32.to_radians().cos());
    let mut d = [[0.0, 0.0, 1.0]; 9];
    for (k, v) in d.iter_mut().enumerate().skip(1) {
        let a = std::f32::consts::TAU * (k - 1) as f32 / 8.0;
        *v = [s * a.cos(), s * a.sin(), c];
    }
    d
}

/// Whether a sample point at `x` (normal `n`) is buried in solid geometry: most rays into
/// its hemisphere meet the back of a surface first. q3map2 tests whether a luxel's sample
/// point lies in a solid leaf of the BSP ("luxels occluded", `MapSingleLuxel`) and fills
/// such luxels from elsewhere; the glTF has no solids, so the test is the geometry's
/// orientation: a point outside every solid sees front faces or open space. Faces of
/// double-sided materials count as front faces from either side.
pub fn buried(mesh: &crate::scene::Mesh, double_sided: &[bool], bvh: &Bvh, x: Vec3, n: Vec3, reach: f32) -> bool {
    let (t1, t2) = n.any_orthonormal_pair();
    let mut back = 0;
    let dirs = probe_directions();
    for (k, d) in dirs.iter().enumerate() {
        let dir = t1 * d[0] + t2 * d[1] + n * d[2];
        if let Some((_, t)) = bvh.first_hit(x, dir * reach, 1.0) {
            let t = t as usize;
            let [a, b, c] = mesh.triangles[t].map(|i| mesh.positions[i as usize]);
            let two_sided = double_sided.get(mesh.tri_material[t] as usize).copied().unwrap_or(false);
            if !two_sided && (b - a).cross(c - a).dot(dir) > 0.0 {
                back += 1;
            }
        }
        // Decided once the rest cannot change the majority.
        let left = dirs.len() - k - 1;
        if back * 2 > dirs.len() || (back + left) * 2 <= dirs.len() {
            break;
        }
    }
    back * 2 > dirs.len()
}

/// Whether a sample point lies in solid as q3map2 found it (`PointInLeafNum`, which
/// keeps a point within `PLANE_EPSILON` of a plane on its open side). The mesh keeps only
/// the brushes' visible faces, so: further than `epsilon` (m) behind the plane of the
/// nearest surface, a one-sided face seen from its back. A point on a wall's plane (a
/// face's edge row where it meets the wall) is not in solid; nor is one beside a convex
/// corner (its nearest point is on an edge, behind neither face's plane). A point deeper
/// in, whose nearest surface is its own face, is left to [`buried`] (measured on the
/// truth set: rescuing those by nudging too raised oacmpdm3's error from 0.25 to 0.41).
fn in_solid(mesh: &crate::scene::Mesh, double_sided: &[bool], bvh: &Bvh, x: Vec3, epsilon: f32) -> bool {
    let Some((d, c, t)) = bvh.nearest_triangle(x) else { return false };
    if d <= epsilon {
        return false;
    }
    let t = t as usize;
    let two_sided = double_sided.get(mesh.tri_material[t] as usize).copied().unwrap_or(false);
    let [a, b, cc] = mesh.triangles[t].map(|i| mesh.positions[i as usize]);
    !two_sided && (b - a).cross(cc - a).normalize_or_zero().dot(x - c) < -epsilon
}

/// q3map2's nudge (`MapSingleLuxel`): a luxel whose sample point is in solid (a face
/// that runs on under a wall, its texel centre a few units inside) is sampled instead
/// half a texel away along the lightmap's axes, the first of left, right, up, down and the four diagonals
/// that is clear; light, shadows and dirt are all evaluated there. Points no nudge frees
/// stay (then [`drop_buried`] decides). Returns how many moved.
pub fn nudge_out_of_solid(lx: &mut Luxels, scene: &Scene, bvh: &Bvh) -> usize {
    use crate::scene::q3map2::{NUDGE_TEXELS, PLANE_EPSILON_UNITS};
    use rayon::prelude::*;
    lx.stats.solids_from = "faces";
    let eps = PLANE_EPSILON_UNITS * scene.units_m;
    let double_sided: Vec<bool> = scene.materials.iter().map(|m| m.double_sided).collect();
    let pb = &lx.rows;
    let (lo, hi) = scene.mesh.bounds();
    let reach = 2.0 * (hi - lo).length().max(1e-3);
    let solid = |p: Vec3| in_solid(&scene.mesh, &double_sided, bvh, p, eps);
    // A place to move to must be clear by both tests: not just off the nearest face's back
    // (deeper in a brush, the nearest face can be the sample's own).
    let clear = |p: Vec3, n: Vec3| p.is_finite() && !solid(p) && !buried(&scene.mesh, &double_sided, bvh, p, n, reach);
    let moved: Vec<Option<Vec3>> = (0..pb.len())
        .into_par_iter()
        .map(|i| {
            let [ax, ay] = *lx.texel_axes.get(i)?;
            if pb.texel[i][0] == u32::MAX || ax == Vec3::ZERO || !solid(pb.pos[i]) {
                return None;
            }
            NUDGES.iter().map(|&(u, v)| pb.pos[i] + (ax * u + ay * v) * NUDGE_TEXELS).find(|&p| clear(p, pb.normal[i]))
        })
        .collect();
    let mut n = 0;
    for (i, m) in moved.into_iter().enumerate() {
        if let Some(p) = m {
            lx.rows.pos[i] = p;
            n += 1;
        }
    }
    lx.stats.nudged += n;
    n
}

/// The nudges of q3map2's `MapSingleLuxel`, in half texels along the lightmap's axes: left,
/// right, up, down, then the four diagonals.
const NUDGES: [(f32, f32); 8] = [(-1.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, -1.0)];

/// q3map2's placement of the samples with the map's own solids (`MapSingleLuxel`): a luxel
/// whose sample point is in solid ([`Solids::contains`]: a structural solid leaf, or
/// inside an opaque brush, detail or not) is sampled half a texel away along the
/// lightmap's axes, at the first of [`NUDGES`] that is clear; one that no nudge frees q3map2
/// marks occluded and fills from its neighbours, so it is left out here. If more than half
/// of the luxels are in solid, the solids do not describe this mesh (edited since convert):
/// nothing is changed and `false` returned, and the caller falls back to the faces.
/// Measured on the point-light recompiles against [`nudge_out_of_solid`] (both followed
/// by [`drop_buried`]): oacmpctf1 0.080 -> 0.021, oacmpdm3 0.204 -> 0.161.
pub fn place_in_solids(lx: &mut Luxels, solids: &Solids) -> bool {
    use crate::scene::q3map2::NUDGE_TEXELS;
    use rayon::prelude::*;
    let pb = &lx.rows;
    // Per luxel: None clear, Some(Some(p)) moved to p, Some(None) occluded.
    let placed: Vec<Option<Option<Vec3>>> = (0..pb.len())
        .into_par_iter()
        .map(|i| {
            if pb.texel[i][0] == u32::MAX || !solids.contains(pb.pos[i]) {
                return None;
            }
            let [ax, ay] = lx.texel_axes.get(i).copied().unwrap_or([Vec3::ZERO; 2]);
            Some(NUDGES.iter().map(|&(u, v)| pb.pos[i] + (ax * u + ay * v) * NUDGE_TEXELS).find(|&p| ax != Vec3::ZERO && !solids.contains(p)))
        })
        .collect();
    let in_solid = placed.iter().filter(|p| p.is_some()).count();
    if in_solid * 2 > lx.stats.luxels.max(1) {
        return false;
    }
    let mut keep = vec![true; placed.len()];
    for (i, p) in placed.into_iter().enumerate() {
        match p {
            Some(Some(to)) => {
                lx.rows.pos[i] = to;
                lx.stats.nudged += 1;
            }
            Some(None) => keep[i] = false,
            None => {}
        }
    }
    let dropped = keep.iter().filter(|k| !**k).count();
    if dropped > 0 {
        lx.rows.retain(&keep);
        lx.texel_axes = lx.texel_axes.iter().zip(&keep).filter(|(_, k)| **k).map(|(a, _)| *a).collect();
        lx.stats.luxels -= dropped;
        lx.stats.buried += dropped;
    }
    lx.stats.solids_from = "map";
    true
}

/// Where q3map2 lit a vertex of a vertex-lit surface (stored frame, m): the vertex itself
/// unless it is in solid ([`Solids::contains_within`] with q3map2's `VERTEX_EPSILON`: on
/// a brush's face is not in it); then the first point of `IlluminateVertexes`' nudge
/// ([`crate::scene::q3map2::VERTEX_NUDGE_UNITS`] steps along the map's axes) that is
/// clear. `None` when none is: q3map2 gave such a vertex the mean of the surface's lit
/// ones, which no row here can say, so it is left out. (q3map2 also nudges a clear
/// vertex that its lights leave black; that depends on the lights and is not done here.)
pub fn vertex_sample_point(solids: &Solids, p: Vec3) -> Option<Vec3> {
    let eps = crate::trace::solids::VERTEX_EPSILON_UNITS * solids.units_m();
    if !solids.contains_within(p, eps) {
        return Some(p);
    }
    // q3map2 means the order 0, 1, -1, 2, -2, but its formula gives 0, 0, 1, -1, 2.
    const STEPS: [f32; 4] = [0.0, 1.0, -1.0, 2.0];
    let step = crate::scene::q3map2::VERTEX_NUDGE_UNITS * solids.units_m() as f32;
    for x in STEPS {
        for y in STEPS {
            for z in STEPS {
                // Quake (x, y, z) is glTF (x, z, -y).
                let q = p + Vec3::new(x, z, -y) * step;
                if !solids.contains_within(q, eps) {
                    return Some(q);
                }
            }
        }
    }
    None
}

/// Marks each luxel row's [`SolidAhead`]: the axial faces of shadow-casting surfaces within
/// `TRACE_ON_EPSILON` of its sample point whose solid side is Quake's positive one (their
/// normal points down an axis). Returns how many rows touch one.
pub fn mark_solid_ahead(rows: &mut Rows, scene: &Scene, bvh: &Bvh) -> usize {
    use crate::scene::q3map2::PLANE_EPSILON_UNITS;
    use rayon::prelude::*;
    let eps = PLANE_EPSILON_UNITS * scene.units_m;
    let mesh = &scene.mesh;
    let marks: Vec<SolidAhead> = (0..rows.len())
        .into_par_iter()
        .map(|i| {
            if rows.texel[i][0] == u32::MAX {
                return SolidAhead::NONE;
            }
            let mut bits = 0u8;
            for t in bvh.within(rows.pos[i], eps) {
                let [a, b, c] = mesh.triangles[t as usize].map(|v| mesh.positions[v as usize]);
                let n = (b - a).cross(c - a).normalize_or_zero();
                for &(bit, axis) in &SolidAhead::DIRECTIONS {
                    // The face looks away from the solid, down the axis.
                    if n.dot(axis) < -0.9999 {
                        bits |= bit;
                    }
                }
            }
            SolidAhead(bits)
        })
        .collect();
    let n = marks.iter().filter(|m| m.0 != 0).count();
    rows.solid_ahead = marks;
    n
}

/// Removes the luxel rows whose sample point is [`buried`]; returns how many. Run after
/// either placement: with the map's solids too, a sample q3map2 counted as open can sit
/// in a pocket closed by faces (a gap between brushes, under a patch); the game never
/// shows it and its value there hangs on leaks, so the fit leaves it out (oacmpctf1's
/// recompile: 0.054 keeping them, 0.021 without).
pub fn drop_buried(lx: &mut Luxels, scene: &Scene, bvh: &Bvh) -> usize {
    use rayon::prelude::*;
    let (lo, hi) = scene.mesh.bounds();
    let reach = 2.0 * (hi - lo).length().max(1e-3);
    let double_sided: Vec<bool> = scene.materials.iter().map(|m| m.double_sided).collect();
    // A point on a plane is decided by the vote too. q3map2 keeps it on the open side of a
    // structural wall (`PointInLeafNum`) but inside a detail brush (`ClusterForPointExt`
    // counts a point within 0.125 unit of its faces as inside), and the mesh does not say
    // which a face is: keeping every such row raised oacmpdm3's point-light recompile from
    // 0.204 to 0.240, the vote's 0.204.
    let pb = &lx.rows;
    let keep: Vec<bool> = (0..pb.len()).into_par_iter().map(|i| pb.texel[i][0] == u32::MAX || !buried(&scene.mesh, &double_sided, bvh, pb.pos[i], pb.normal[i], reach)).collect();
    let dropped = keep.iter().filter(|k| !**k).count();
    if dropped > 0 {
        lx.rows.retain(&keep);
        lx.texel_axes = lx.texel_axes.iter().zip(&keep).filter(|(_, k)| **k).map(|(a, _)| *a).collect();
        lx.stats.luxels -= dropped;
        lx.stats.buried += dropped;
    }
    dropped
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Material, Mesh, Texture, Wrap};

    /// A 2 m x 1 m floor quad (y = 0, normal +y) whose lightmap coordinates put its corners
    /// on the centres of texels (1, 2) and (9, 6) of a 16 x 8 lightmap, as q3map2 does: 9 x 5
    /// luxels, 0.25 m apart.
    fn floor_scene() -> Scene {
        let (w, h) = (16u32, 8u32);
        let mut lm = vec![0u8; (w * h * 4) as usize];
        for y in 0..h {
            for x in 0..w {
                let o = ((y * w + x) * 4) as usize;
                lm[o..o + 4].copy_from_slice(&[(10 * x) as u8, (20 * y) as u8, 7, 255]);
            }
        }
        // One censored texel.
        let o = ((3 * w + 4) * 4) as usize;
        lm[o] = 255;
        let tex = Texture { width: w, height: h, rgba8: lm, wrap_s: Wrap::Clamp, wrap_t: Wrap::Clamp };
        let mut m = Mesh::default();
        let corners = [(0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (0.0, 1.0)];
        for (x, z) in corners {
            m.positions.push(Vec3::new(x, 0.0, z));
            m.normals.push(Vec3::Y);
            m.uv0.push(Vec2::ZERO);
            m.uv1.push(Vec2::new((1.5 + 4.0 * x) / w as f32, (2.5 + 4.0 * z) / h as f32));
            m.colors.push([1.0; 3]);
            m.v_material.push(0);
        }
        m.triangles = vec![[0, 1, 2], [0, 2, 3]];
        m.tri_material = vec![0, 0];
        m.tri_source = vec![0, 1];
        m.reweld();
        let mat = Material { name: "floor".into(), albedo: None, albedo_factor: [0.5, 0.25, 1.0, 1.0], lighting: Lighting::Lightmap, lightmap: Some(0), overbright_bits: 2, lightmap_gamma: 1.0, censor_byte: crate::scene::CENSOR_BYTE, sky: false, double_sided: false, casts_shadow: true, emitter: None, sky_lights: Vec::new(), emission: [0.0; 3] };
        Scene { mesh: m, materials: vec![mat], textures: vec![tex], lights: Vec::new(), suns: Vec::new(), origin: glam::DVec3::ZERO, skipped: Vec::new(), units_m: 0.0254, compile: Default::default(), relit: None, solids: None, patch_lights: Vec::new(), patch_vertices: Vec::new(), patch_luxels: Vec::new(), casters: None }
    }

    /// A vertex-lit 2 m x 1 m quad that q3map2 drew from a flat 3 x 3 patch: its rows are
    /// the patch's control points with q3map2's bytes (those the drawn quad shows, its
    /// corners), not the mesh's vertices; moved away from its record, the quad's vertices
    /// are its rows again.
    #[test]
    fn a_vertex_lit_patch_is_sampled_at_its_control_points_while_its_record_holds() {
        let mut scene = floor_scene();
        scene.materials[0].name = "pad#vertex".into();
        scene.materials[0].lighting = Lighting::Vertex;
        scene.materials[0].lightmap = None;
        let mut tg = Target::empty(4);
        for v in 0..4 {
            (tg.area[v], tg.albedo[v], tg.value[v], tg.hi[v], tg.weight[v]) = (0.5, [0.5; 3], [0.1; 3], [0.11; 3], [1.0; 3]);
        }
        let (mut pos, mut rgb, mut area) = (Vec::new(), Vec::new(), Vec::new());
        for j in 0..3 {
            for i in 0..3 {
                pos.push(Vec3::new(i as f32, 0.0, 0.5 * j as f32));
                rgb.push([(40 * i + 10 * j) as u8, 30, 20]);
                area.push(if i != 1 && j != 1 { 0.5 } else { 0.0 });
            }
        }
        let record = crate::model::patch_mesh::PatchMesh { shader: "pad".into(), width: 3, height: 3, pos, normal: vec![Vec3::Y; 9], area_m2: 2.0, rgb, point_area_m2: area, luxels: Vec::new() };
        scene.patch_vertices = vec![record];
        let lx = rows(&scene, &tg, 3.0);
        assert_eq!((lx.stats.patch_control_points, lx.stats.vertex_rows, lx.stats.patch_records_unmatched), (4, 4, 0));
        let pb = &lx.rows;
        assert!(pb.vertex.iter().all(|&v| v == u32::MAX), "no mesh vertex is a row");
        // The corner (2, 0, 1): bytes (100, 30, 20) -> [b, b + 1) / 255 x 4, times the albedo.
        let k = (0..pb.len()).find(|&i| pb.pos[i] == Vec3::new(2.0, 0.0, 1.0)).expect("the far corner is a row");
        assert!((pb.lo[k][0] - 0.5 * 100.0 / 255.0 * 4.0).abs() < 1e-5 && (pb.hi[k][0] - 0.5 * 101.0 / 255.0 * 4.0).abs() < 1e-5, "{:?} {:?}", pb.lo[k], pb.hi[k]);
        assert_eq!(pb.area[k], 0.5);
        // Without the vertex colours in the target (a render of the model alone), no
        // vertex-lit rows at all.
        let lx = rows(&scene, &Target::empty(4), 3.0);
        assert_eq!((lx.stats.patch_control_points, lx.rows.len()), (0, 0));
        // Moved by a metre: the record no longer describes the mesh.
        scene.mesh.positions.iter_mut().for_each(|p| p.x += 1.0);
        let lx = rows(&scene, &tg, 3.0);
        assert_eq!((lx.stats.patch_control_points, lx.stats.vertex_rows, lx.stats.patch_records_unmatched), (0, 4, 1));
        assert!(lx.rows.vertex.iter().all(|&v| v != u32::MAX));
    }

    /// A vertex-lit patch's control points in solid (the map's solids: below the plane
    /// y = 0, 1 m per unit) are sampled where q3map2's nudge first finds clear (4 units up
    /// first), with the normal of the patch's last clear point before them; those before
    /// any clear point have no normal in q3map2 and are left out.
    #[test]
    fn control_points_in_solid_are_nudged_with_the_last_clear_normal() {
        let floor = serde_json::json!({ "planes": [0, 1, 0, 0], "nodes": [0, -1, -2], "leafs": [0, 0, 0, 1, 0, 0], "leaf_brushes": [], "brushes": [], "brush_planes": [] });
        let record = |sunk_row: usize| {
            let (mut pos, mut normal, mut area) = (Vec::new(), Vec::new(), Vec::new());
            for j in 0..3 {
                for i in 0..3 {
                    pos.push(Vec3::new(i as f32, if j == sunk_row { -1.0 } else { 0.5 }, 0.5 * j as f32));
                    normal.push(if j * 3 + i == 5 { Vec3::Z } else { Vec3::Y });
                    area.push(if i != 1 && j != 1 { 0.5 } else { 0.0 });
                }
            }
            crate::model::patch_mesh::PatchMesh { shader: "pad".into(), width: 3, height: 3, pos, normal, area_m2: 2.0, rgb: vec![[50, 30, 20]; 9], point_area_m2: area, luxels: Vec::new() }
        };
        let mut scene = floor_scene();
        scene.materials[0].name = "pad#vertex".into();
        scene.materials[0].lighting = Lighting::Vertex;
        scene.materials[0].lightmap = None;
        scene.mesh.positions.iter_mut().for_each(|p| p.y = 0.5);
        scene.solids = Some(crate::trace::solids::Solids::from_extras(&floor, glam::DVec3::ZERO, 1.0).unwrap());
        let mut tg = Target::empty(4);
        for v in 0..4 {
            (tg.area[v], tg.albedo[v], tg.value[v], tg.hi[v], tg.weight[v]) = (0.5, [0.5; 3], [0.1; 3], [0.11; 3], [1.0; 3]);
        }
        // The last row sunk: its corners move 4 up and take point 5's normal (+z).
        scene.patch_vertices = vec![record(2)];
        let lx = rows(&scene, &tg, 3.0);
        assert_eq!((lx.stats.patch_control_points, lx.stats.vertices_nudged, lx.stats.vertices_in_solid), (4, 2, 0));
        let pb = &lx.rows;
        for (p, n) in [(Vec3::new(0.0, 0.5, 0.0), Vec3::Y), (Vec3::new(2.0, 0.5, 0.0), Vec3::Y), (Vec3::new(0.0, 3.0, 1.0), Vec3::Z), (Vec3::new(2.0, 3.0, 1.0), Vec3::Z)] {
            let k = (0..pb.len()).find(|&i| pb.pos[i] == p).unwrap_or_else(|| panic!("no row at {p}: {:?}", pb.pos));
            assert_eq!(pb.normal[k], n);
        }
        // The first row sunk: nothing clear before its corners, which are left out.
        scene.patch_vertices = vec![record(0)];
        let lx = rows(&scene, &tg, 3.0);
        assert_eq!((lx.stats.patch_control_points, lx.stats.vertices_nudged, lx.stats.vertices_in_solid), (2, 0, 2));
        // Without the map's solids, every point is where the record says.
        scene.solids = None;
        let lx = rows(&scene, &tg, 3.0);
        assert_eq!((lx.stats.patch_control_points, lx.stats.vertices_nudged), (4, 0));
    }

    /// The floor quad as a curved patch's luxels: two of its texels have q3map2's own
    /// sample points in the record, and their rows are there (with the record's normal);
    /// the other texels stay at their centres. Moved away from its record, every row is
    /// at its texel's centre again.
    #[test]
    fn a_curved_patch_is_sampled_where_q3map2_sampled_it_while_its_record_holds() {
        use crate::model::patch_mesh::{PatchLuxel, PatchMesh};
        let mut scene = floor_scene();
        let at_centre = rows(&scene, &Target::empty(4), 3.0);
        let tilted = Vec3::new(0.0, 1.0, 0.2).normalize();
        let luxels = vec![
            PatchLuxel { texel: [3, 4], pos: Vec3::new(0.3, 0.04, 0.45), normal: tilted, nudge: None },
            PatchLuxel { texel: [9, 6], pos: Vec3::new(1.9, 0.04, 0.95), normal: Vec3::Y, nudge: None },
        ];
        let pos = vec![Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 1.0), Vec3::new(2.0, 0.0, 1.0)];
        scene.patch_luxels = vec![PatchMesh { shader: "floor".into(), width: 2, height: 2, pos, normal: vec![Vec3::Y; 4], area_m2: 2.0, rgb: Vec::new(), point_area_m2: Vec::new(), luxels }];
        let lx = rows(&scene, &Target::empty(4), 3.0);
        assert_eq!((lx.stats.patch_luxels, lx.stats.patch_luxel_records_unmatched, lx.rows.len()), (2, 0, at_centre.rows.len()));
        let pb = &lx.rows;
        let row = |t: [u32; 2]| (0..pb.len()).find(|&i| pb.texel[i] == [0, t[0], t[1]]).unwrap();
        let k = row([3, 4]);
        assert_eq!((pb.pos[k], pb.normal[k]), (Vec3::new(0.3, 0.04, 0.45), tilted));
        assert_eq!(pb.pos[row([9, 6])], Vec3::new(1.9, 0.04, 0.95));
        // The data and the other rows are as without the record.
        let k0 = (0..at_centre.rows.len()).find(|&i| at_centre.rows.texel[i] == [0, 3, 4]).unwrap();
        assert_eq!((pb.lo[k], pb.hi[k], pb.area[k]), (at_centre.rows.lo[k0], at_centre.rows.hi[k0], at_centre.rows.area[k0]));
        let k = row([5, 4]);
        let k0 = (0..at_centre.rows.len()).find(|&i| at_centre.rows.texel[i] == [0, 5, 4]).unwrap();
        assert_eq!(pb.pos[k], at_centre.rows.pos[k0]);
        // Moved by a metre: the record no longer describes the mesh.
        scene.mesh.positions.iter_mut().for_each(|p| p.x += 1.0);
        let lx = rows(&scene, &Target::empty(4), 3.0);
        assert_eq!((lx.stats.patch_luxels, lx.stats.patch_luxel_records_unmatched), (0, 1));
    }

    #[test]
    fn every_covered_texel_is_one_row_at_its_sample_point() {
        let scene = floor_scene();
        let lx = rows(&scene, &Target::empty(4), 3.0);
        let pb = &lx.rows;
        assert_eq!(lx.stats.luxels, 45, "9 x 5 texel centres lie on the quad (edges included, the diagonal shared)");
        assert_eq!(pb.len(), 45);
        assert_eq!(lx.stats.censored, 1);
        let total: f32 = pb.area.iter().sum();
        // 45 luxels of 1/16 m^2 each: the quad's 2 m^2 plus its half-texel rim.
        assert!((total - 45.0 / 16.0).abs() < 1e-4, "area {total}");
        for (i, &[tex, x, y]) in pb.texel.iter().enumerate() {
            assert_eq!(tex, 0);
            // Texel (x, y) samples the point 0.25 m per texel from the corner at texel (1, 2),
            // one Quake unit off the surface (q3map2's sample origin).
            let want = Vec3::new((x as f32 - 1.0) * 0.25, 0.0254, (y as f32 - 2.0) * 0.25);
            assert!((pb.pos[i] - want).length() < 1e-5, "texel ({x}, {y}) at {:?}, expected {want:?}", pb.pos[i]);
            assert_eq!(pb.normal[i], Vec3::Y);
            assert_eq!(pb.albedo[i], [0.5, 0.25, 1.0]);
            // Byte b stands for [b, b + 1) / 255 * 4 (overbright 2), times the albedo.
            let e = [10.0 * x as f32, 20.0 * y as f32, 7.0].map(|b| b / 255.0 * 4.0);
            if (x, y) == (4, 3) {
                assert_eq!(pb.weight[i], [0.0; 3], "a texel with a channel at 255 is a lower bound");
                assert!((pb.lower[i][1] - 0.25 * e[1]).abs() < 1e-6);
            } else {
                assert_eq!(pb.weight[i], [1.0; 3]);
                for c in 0..3 {
                    assert!((pb.lo[i][c] - pb.albedo[i][c] * e[c]).abs() < 1e-6, "texel ({x}, {y}) channel {c}");
                    assert!((pb.hi[i][c] - pb.lo[i][c] - pb.albedo[i][c] * 4.0 / 255.0).abs() < 1e-6);
                }
            }
        }
        let mut seen = pb.texel.clone();
        seen.sort();
        seen.dedup();
        assert_eq!(seen.len(), 45, "no texel is claimed twice");
    }

    #[test]
    fn edge_texels_survive_the_f32_rounding_of_their_centres() {
        // q3map2's vertices sit on texel centres; in f32 a centre can land a hair outside
        // the face (1.50000003 for 1.5). The face's edge rows must stay.
        let mut scene = floor_scene();
        let (w, h) = (16.0f32, 8.0f32);
        for uv in scene.mesh.uv1.iter_mut() {
            let (tx, ty) = (uv.x * w, uv.y * h);
            // Push every corner outward by a few millionths of a texel.
            let out = |t: f32, mid: f32| t + if t < mid { -3e-6 } else { 3e-6 };
            *uv = Vec2::new(out(tx, 5.5) / w, out(ty, 4.5) / h);
        }
        let shrunk = {
            let mut s = floor_scene();
            for uv in s.mesh.uv1.iter_mut() {
                let (tx, ty) = (uv.x * w, uv.y * h);
                let inw = |t: f32, mid: f32| t + if t < mid { 3e-6 } else { -3e-6 };
                *uv = Vec2::new(inw(tx, 5.5) / w, inw(ty, 4.5) / h);
            }
            s
        };
        for s in [&scene, &shrunk] {
            let lx = rows(s, &Target::empty(4), 3.0);
            assert_eq!(lx.stats.luxels, 45, "the 9 x 5 centres, edges included: {:?}", lx.stats);
        }
    }

    /// `floor_scene` with a closed box (outward faces) standing on the floor over
    /// x in [-1, `x_max`] m: a detail brush the floor runs on under.
    fn floor_with_block(x_max: f32) -> Scene {
        let mut scene = floor_scene();
        let m = &mut scene.mesh;
        // Wound to face up (+y), as its normals say: the solid test reads the winding.
        m.triangles = vec![[0, 2, 1], [0, 3, 2]];
        let (lo, hi) = (Vec3::new(-1.0, -0.5, -1.0), Vec3::new(x_max, 1.0, 2.0));
        let c = |i: usize| Vec3::new(if i & 1 == 0 { lo.x } else { hi.x }, if i & 2 == 0 { lo.y } else { hi.y }, if i & 4 == 0 { lo.z } else { hi.z });
        // Faces as corner indices, counter-clockwise seen from outside.
        let faces = [[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [2, 6, 7, 3], [0, 2, 3, 1], [4, 5, 7, 6]];
        for f in faces {
            let base = m.positions.len() as u32;
            let n = (c(f[1]) - c(f[0])).cross(c(f[2]) - c(f[0])).normalize();
            for &k in &f {
                m.positions.push(c(k));
                m.normals.push(n);
                m.uv0.push(Vec2::ZERO);
                m.uv1.push(Vec2::ZERO);
                m.colors.push([1.0; 3]);
                m.v_material.push(1);
            }
            m.triangles.push([base, base + 1, base + 2]);
            m.triangles.push([base, base + 2, base + 3]);
            m.tri_material.extend([1, 1]);
            m.tri_source.extend([2, 2]);
        }
        m.reweld();
        let block = crate::scene::Material { name: "block".into(), lighting: Lighting::None, lightmap: None, ..scene.materials[0].clone() };
        scene.materials.push(block);
        scene
    }

    /// Open space above y = -10 m with one opaque (caulk) brush over x <= `x_max` m.
    fn solids_with_caulk(x_max: f64) -> Solids {
        let v = serde_json::json!({
            "planes": [0, 1, 0, -10,  1, 0, 0, x_max,  -1, 0, 0, 1,  0, 1, 0, 1,  0, -1, 0, 1,  0, 0, 1, 2,  0, 0, -1, 1],
            "nodes": [0, -1, -2],
            "leafs": [0, 0, 1,  1, 1, 0],
            "leaf_brushes": [0],
            "brushes": [0, 6],
            "brush_planes": [1, 2, 3, 4, 5, 6],
        });
        Solids::from_extras(&v, glam::DVec3::ZERO, 0.0254).unwrap()
    }

    #[test]
    fn the_maps_solids_nudge_or_drop_samples_as_q3map2_does() {
        // The caulk ends 0.26 m along x: texel column x = 2 (0.25 m) is inside, half a texel
        // right (0.375 m) is clear; column 1 (0 m) is inside wherever q3map2 nudges it
        // (0.125 m each way, all within the brush): occluded, left out.
        let scene = floor_scene();
        let mut lx = rows(&scene, &Target::empty(scene.mesh.positions.len()), 3.0);
        let before: Vec<([u32; 3], Vec3)> = (0..lx.rows.len()).map(|i| (lx.rows.texel[i], lx.rows.pos[i])).collect();
        assert!(place_in_solids(&mut lx, &solids_with_caulk(0.26)));
        assert_eq!((lx.stats.nudged, lx.stats.buried, lx.stats.solids_from), (5, 5, "map"));
        assert_eq!(lx.rows.len(), before.len() - 5);
        for i in 0..lx.rows.len() {
            let t = lx.rows.texel[i];
            let was = before.iter().find(|(bt, _)| *bt == t).unwrap().1;
            match t[1] {
                1 => panic!("an occluded texel was kept"),
                2 => assert!((lx.rows.pos[i] - (was + Vec3::new(0.125, 0.0, 0.0))).length() < 1e-5, "{t:?}"),
                _ => assert_eq!(lx.rows.pos[i], was),
            }
        }
        // Solids that bury more than half the luxels do not describe this mesh: nothing
        // changes and the caller falls back to the faces.
        let mut lx = rows(&scene, &Target::empty(scene.mesh.positions.len()), 3.0);
        let n = lx.rows.len();
        assert!(!place_in_solids(&mut lx, &solids_with_caulk(1.5)));
        assert_eq!((lx.rows.len(), lx.stats.nudged, lx.stats.buried), (n, 0, 0));
    }

    #[test]
    fn a_sample_inside_a_brush_is_nudged_half_a_texel_as_q3map2_does() {
        // The block ends 0.01 m (0.4 units) past texel x = 2's sample point (0.25 m): that
        // sample is in solid, just behind the block's face; half a texel left is deeper
        // in, half a texel right (0.375 m) is clear, and q3map2 samples there. Texels
        // further in (nearest to their own floor) stay, for `drop_buried`.
        let scene = floor_with_block(0.26);
        let bvh = Bvh::build(&scene.mesh);
        let mut lx = rows(&scene, &Target::empty(scene.mesh.positions.len()), 3.0);
        let before = lx.rows.pos.clone();
        let moved = nudge_out_of_solid(&mut lx, &scene, &bvh);
        assert!(moved > 0, "{:?}", lx.stats);
        for i in 0..lx.rows.len() {
            let [_, x, _] = lx.rows.texel[i];
            let p = lx.rows.pos[i];
            match x {
                2 => assert!((p - (before[i] + Vec3::new(0.125, 0.0, 0.0))).length() < 1e-5, "texel {x}: {p:?}"),
                _ => assert_eq!(p, before[i], "texel {x} is clear or deeper than half a texel"),
            }
        }
        assert_eq!(moved, 5, "one column of 5 texels");
        // A sample on the block's plane (within 0.1 unit) is not in solid: nothing moves.
        let on_plane = floor_with_block(0.25);
        let bvh = Bvh::build(&on_plane.mesh);
        let mut lx = rows(&on_plane, &Target::empty(on_plane.mesh.positions.len()), 3.0);
        assert_eq!(nudge_out_of_solid(&mut lx, &on_plane, &bvh), 0);
    }

    #[test]
    fn degenerate_or_absurd_lightmap_coordinates_are_refused() {
        let mut scene = floor_scene();
        // Triangle 0 collapses in lightmap space; triangle 1 spans 10^8 texels.
        let uv = scene.mesh.uv1[0];
        scene.mesh.uv1[1] = uv;
        scene.mesh.uv1[3] = Vec2::new(-1e5, 1e5);
        let lx = rows(&scene, &Target::empty(4), 3.0);
        assert_eq!(lx.stats.triangles_refused, 2);
        assert_eq!(lx.rows.len(), 0);
    }

    #[test]
    fn a_long_sliver_in_lightmap_space_is_refused_without_scanning_its_box() {
        let mut scene = floor_scene();
        scene.textures[0] = Texture { width: 4096, height: 1100, rgba8: vec![0; 4096 * 1100 * 4], wrap_s: Wrap::Clamp, wrap_t: Wrap::Clamp };
        // Triangle 0 becomes a sliver along the atlas's diagonal: an area of a few texels,
        // a box of 4096 x 1100 texels (over the limit).
        scene.mesh.uv1[0] = Vec2::new(0.0, 0.0);
        scene.mesh.uv1[1] = Vec2::new(1.0, 1.0);
        scene.mesh.uv1[2] = Vec2::new(1.0, 1.0 - 1e-5);
        let lx = rows(&scene, &Target::empty(4), 3.0);
        assert!(lx.stats.triangles_refused >= 1, "{:?}", lx.stats);
    }
}
