//! q3map2's light meshes of the emitting patches: the scene extras `q3_patch_lights`,
//! written by convert (`q3gltf_convert::lightmesh`, which says how q3map2 builds them);
//! and, in the same shape with q3map2's bytes and each point's drawn area, the control
//! points at which q3map2 lit the vertex-lit patches (`q3_patch_vertices`; their rows are
//! made in [`crate::rows::luxel`]).
//!
//! q3map2 made a patch's area lights from its own coarse mesh of the patch, not from the
//! surface the game draws: per quad `(x, y)` of the mesh, with `r = (x + y) & 1`, the
//! corners `pw = [(x, y), (x, y+1), (x+1, y+1), (x+1, y), (x, y)]` give the winding
//! `pw[r..r + 4]`; when its first three corners make no plane (two of them coincide, as
//! on the collapsed rows of a round lamp), q3map2 means to emit two triangles instead but
//! emits that degenerate first one twice, that is nothing (`RadLightForPatch`). Its
//! flatness test compares a corner with the plane through itself, so every other quad
//! emits whole, flat or not. The winding's normal is the mean of its corners' normals.
//!
//! The mesh as read may have been edited since convert wrote the record: a record stands
//! for the mesh's triangles of its shader that lie within its bounds (half a unit of
//! slack; a triangle within several records' bounds goes to the one nearest its centre), and only when
//! their area is the record's `area_m2` (0.5%). Otherwise relight emits from the
//! triangles themselves, as without a record.

use glam::{DVec3, Vec2, Vec3};
use serde_json::Value;

/// One emitting patch's light mesh, in the scene's stored frame (metres).
#[derive(Debug, Clone, PartialEq)]
pub struct PatchMesh {
    /// The shader's name (a material's name up to any `#` suffix).
    pub shader: String,
    pub width: usize,
    pub height: usize,
    /// Row-major `width x height`.
    pub pos: Vec<Vec3>,
    pub normal: Vec<Vec3>,
    /// Area of the drawn patch (convert's tessellation), m^2.
    pub area_m2: f64,
    /// q3map2's bytes at each point (`q3_patch_vertices` only; empty otherwise).
    pub rgb: Vec<[u8; 3]>,
    /// The drawn area each point's Bezier basis covers, m^2 (`q3_patch_vertices` only).
    pub point_area_m2: Vec<f32>,
    /// Where q3map2 sampled the patch's luxels (`q3_patch_luxels` only; empty otherwise).
    pub luxels: Vec<PatchLuxel>,
}

/// One luxel of a curved lightmapped patch as q3map2 sampled it (convert's
/// `patch_luxels` says how): its texel in the patch's lightmap atlas image, and the
/// sample's point (the stored frame, metres, q3map2's offset included) and unit normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatchLuxel {
    pub texel: [u32; 2],
    pub pos: Vec3,
    pub normal: Vec3,
    /// The unit directions of q3map2's nudges of the sample when it is in solid
    /// (`luxel_nudge`; `None` in a record written before convert wrote them).
    pub nudge: Option<[Vec3; 2]>,
}

/// Relative slack of the area test.
const AREA_TOLERANCE: f64 = 0.005;
/// Slack of the bounds test, Quake units.
const BOUNDS_SLACK_UNITS: f32 = 0.5;

/// `key`'s finite numbers, exactly `len` of them (`trace::solids`'s reader).
fn numbers(v: &Value, key: &str, len: usize) -> Result<Vec<f64>, String> {
    let x = crate::trace::solids::numbers(v, key, 3)?;
    if x.len() != len {
        return Err(format!("`{key}` has {} numbers, not {len}", x.len()));
    }
    Ok(x)
}

/// Reads the `q3_patch_lights` record; `origin` is the stored frame's origin (m). Every
/// size is checked before anything is allocated from it.
pub fn from_extras(v: &Value, origin: DVec3) -> Result<Vec<PatchMesh>, String> {
    let list = v.as_array().ok_or("not a list")?;
    let mut out = Vec::with_capacity(list.len().min(1 << 16));
    for (k, r) in list.iter().enumerate() {
        let at = |e: String| format!("patch {k}: {e}");
        let shader = r.get("shader").and_then(Value::as_str).ok_or_else(|| at("`shader` is missing".into()))?.to_string();
        let size = r.get("size").and_then(Value::as_array).filter(|s| s.len() == 2).ok_or_else(|| at("`size` is not two numbers".into()))?;
        let dim = |x: &Value| x.as_u64().filter(|&d| (2..=128).contains(&d)).map(|d| d as usize);
        let (Some(width), Some(height)) = (dim(&size[0]), dim(&size[1])) else {
            return Err(at("`size` is not two whole numbers in 2..=128".into()));
        };
        let n = width * height;
        let xyz = numbers(r, "xyz", 3 * n).map_err(at)?;
        let nrm = numbers(r, "normal", 3 * n).map_err(at)?;
        let area_m2 = r.get("area_m2").and_then(Value::as_f64).filter(|a| a.is_finite() && *a >= 0.0).ok_or_else(|| at("`area_m2` is not a size".into()))?;
        let pos = xyz.chunks_exact(3).map(|p| (DVec3::new(p[0], p[1], p[2]) - origin).as_vec3()).collect();
        let normal = nrm.chunks_exact(3).map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32)).collect();
        // The vertex-lit record's bytes and areas, both or neither.
        let (rgb, point_area_m2) = match (r.get("rgb"), r.get("point_area_m2")) {
            (None, None) => (Vec::new(), Vec::new()),
            (Some(_), Some(_)) => {
                let bytes = numbers(r, "rgb", 3 * n).map_err(at)?;
                if bytes.iter().any(|&b| b.fract() != 0.0 || !(0.0..=255.0).contains(&b)) {
                    return Err(at("`rgb` holds a number that is not a byte".into()));
                }
                let areas = crate::trace::solids::numbers(r, "point_area_m2", 1).map_err(at)?;
                if areas.len() != n || areas.iter().any(|&a| a < 0.0) {
                    return Err(at(format!("`point_area_m2` is not {n} sizes")));
                }
                (bytes.chunks_exact(3).map(|c| [c[0] as u8, c[1] as u8, c[2] as u8]).collect(), areas.iter().map(|&a| a as f32).collect())
            }
            _ => return Err(at("`rgb` and `point_area_m2` come together".into())),
        };
        // The luxel samples, all three lists or none.
        let luxels = match (r.get("luxel_texel"), r.get("luxel_xyz"), r.get("luxel_normal")) {
            (None, None, None) => Vec::new(),
            (Some(_), Some(_), Some(_)) => {
                let texel = crate::trace::solids::numbers(r, "luxel_texel", 2).map_err(at)?;
                let n = texel.len() / 2;
                let xyz = numbers(r, "luxel_xyz", 3 * n).map_err(at)?;
                let nrm = numbers(r, "luxel_normal", 3 * n).map_err(at)?;
                let nudge = r.get("luxel_nudge").map(|_| numbers(r, "luxel_nudge", 6 * n)).transpose().map_err(at)?;
                if texel.iter().any(|&t| t.fract() != 0.0 || !(0.0..=f64::from(u16::MAX)).contains(&t)) {
                    return Err(at("`luxel_texel` holds a number that is not a texel".into()));
                }
                let mut l = Vec::with_capacity(n);
                for k in 0..n {
                    let normal = Vec3::new(nrm[3 * k] as f32, nrm[3 * k + 1] as f32, nrm[3 * k + 2] as f32);
                    let Some(normal) = normal.try_normalize() else {
                        return Err(at(format!("luxel {k}'s normal is zero")));
                    };
                    let pos = (DVec3::new(xyz[3 * k], xyz[3 * k + 1], xyz[3 * k + 2]) - origin).as_vec3();
                    let v = |i: usize| nudge.as_ref().map(|d| Vec3::new(d[i] as f32, d[i + 1] as f32, d[i + 2] as f32));
                    let nudge = match (v(6 * k), v(6 * k + 3)) {
                        (Some(a), Some(b)) if a.is_normalized() && b.is_normalized() => Some([a, b]),
                        (None, None) => None,
                        _ => return Err(at(format!("luxel {k}'s nudge directions are not unit vectors"))),
                    };
                    l.push(PatchLuxel { texel: [texel[2 * k] as u32, texel[2 * k + 1] as u32], pos, normal, nudge });
                }
                l
            }
            _ => return Err(at("`luxel_texel`, `luxel_xyz` and `luxel_normal` come together".into())),
        };
        out.push(PatchMesh { shader, width, height, pos, normal, area_m2, rgb, point_area_m2, luxels });
    }
    Ok(out)
}

impl PatchMesh {
    /// The windings q3map2 emits from (see the module docs), each with its normal, in
    /// q3map2's winding order.
    pub fn windings(&self) -> Vec<(Vec<Vec3>, Vec3)> {
        let mut out = Vec::new();
        let w = self.width;
        for y in 0..self.height.saturating_sub(1) {
            for x in 0..w.saturating_sub(1) {
                let pw = [x + y * w, x + (y + 1) * w, x + 1 + (y + 1) * w, x + 1 + y * w, x + y * w];
                let r = (x + y) & 1;
                let corners = &pw[r..r + 4];
                let p: Vec<DVec3> = corners.iter().map(|&i| self.pos[i].as_dvec3()).collect();
                let (e1, e2) = (p[2] - p[0], p[1] - p[0]);
                // q3map2's `PlaneFromPoints` fails only on an exact zero; in metres and
                // f32 a zero in Quake units can come out a rounding's width from it.
                if e1.cross(e2).length() <= 1e-9 * e1.length() * e2.length() {
                    continue;
                }
                let normal = corners.iter().map(|&i| self.normal[i]).sum::<Vec3>().normalize_or_zero();
                if normal == Vec3::ZERO {
                    continue;
                }
                out.push((corners.iter().map(|&i| self.pos[i]).collect(), normal));
            }
        }
        out
    }

    /// Distance from `p` to the mesh (both triangles of every quad), m.
    fn distance(&self, p: Vec3) -> f32 {
        let w = self.width;
        let mut best = f32::INFINITY;
        for y in 0..self.height.saturating_sub(1) {
            for x in 0..w.saturating_sub(1) {
                let [a, b, c, d] = [x + y * w, x + (y + 1) * w, x + 1 + (y + 1) * w, x + 1 + y * w].map(|i| self.pos[i]);
                best = best.min(point_triangle_distance(p, a, b, c)).min(point_triangle_distance(p, a, c, d));
            }
        }
        best
    }

    fn bounds(&self, slack: f32) -> (Vec3, Vec3) {
        let (lo, hi) = self.pos.iter().fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
        (lo - Vec3::splat(slack), hi + Vec3::splat(slack))
    }
}

/// Distance from `p` to the triangle `abc` (a degenerate one: to its longest edge).
fn point_triangle_distance(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> f32 {
    let segment = |p: Vec3, a: Vec3, b: Vec3| {
        let ab = b - a;
        let t = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
        (a + ab * t - p).length()
    };
    let edges = segment(p, a, b).min(segment(p, b, c)).min(segment(p, c, a));
    let n = (b - a).cross(c - a);
    if n.length_squared() == 0.0 {
        return edges;
    }
    // Inside the triangle's prism: the distance to its plane.
    let inside = [(a, b), (b, c), (c, a)].iter().all(|&(u, v)| (v - u).cross(p - u).dot(n) >= 0.0);
    if inside {
        (p - a).dot(n).abs() / n.length()
    } else {
        edges
    }
}

/// Which triangles each record stands for: `Some(triangles)` when the record still
/// describes the mesh (see the module docs), else `None`. `group_of_tri[t]` is the
/// triangle's shader name when it emits; `units_m` metres per Quake unit.
pub fn match_triangles(meshes: &[PatchMesh], positions: &[Vec3], triangles: &[[u32; 3]], shader_of_tri: &[Option<&str>], units_m: f32) -> Vec<Option<Vec<u32>>> {
    let boxes: Vec<(Vec3, Vec3)> = meshes.iter().map(|m| m.bounds(BOUNDS_SLACK_UNITS * units_m)).collect();
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); meshes.len()];
    let mut area = vec![0.0f64; meshes.len()];
    for (t, tri) in triangles.iter().enumerate() {
        let Some(shader) = shader_of_tri.get(t).copied().flatten() else { continue };
        let p = tri.map(|i| positions[i as usize]);
        let inside = |(lo, hi): (Vec3, Vec3)| p.iter().all(|q| q.cmpge(lo).all() && q.cmple(hi).all());
        let centroid = (p[0] + p[1] + p[2]) / 3.0;
        let best = (0..meshes.len())
            .filter(|&k| meshes[k].shader == shader && inside(boxes[k]))
            .map(|k| (k, meshes[k].distance(centroid)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(k, _)| k);
        if let Some(k) = best {
            members[k].push(t as u32);
            let [a, b, c] = p.map(|q| q.as_dvec3());
            area[k] += 0.5 * (b - a).cross(c - a).length();
        }
    }
    holding(members, &area, meshes)
}

/// Each record's triangles while their area is the record's (0.5%), else `None`.
fn holding(members: Vec<Vec<u32>>, area: &[f64], meshes: &[PatchMesh]) -> Vec<Option<Vec<u32>>> {
    members
        .into_iter()
        .zip(area)
        .zip(meshes)
        .map(|((tris, a), m)| ((a - m.area_m2).abs() <= AREA_TOLERANCE * m.area_m2 + 1e-12 && !tris.is_empty()).then_some(tris))
        .collect()
}

/// Slack of the luxel records' bounds test, Quake units: the drawn curve strays outside
/// the light mesh's bounds by its chords' sag.
const LUXEL_BOUNDS_SLACK_UNITS: f32 = 16.0;

/// Which triangles each `q3_patch_luxels` record stands for: those of its shader within
/// its bounds (loosely) whose lightmap footprint's centre (`texel_of_tri`, texels of the
/// triangle's lightmap image) lies in the box of the record's texels, half a texel of
/// slack; `Some` only while their area is the record's (0.5%). A curved patch has its
/// lightmap block to itself, so neighbouring patches of one shader (a pipe's halves, a
/// trim's pieces), which the nearest-mesh rule of [`match_triangles`] confuses where the
/// mesh's chords sag, are told apart by their texels.
pub fn match_triangles_by_texel(meshes: &[PatchMesh], positions: &[Vec3], triangles: &[[u32; 3]], shader_of_tri: &[Option<&str>], texel_of_tri: &[Vec2], units_m: f32) -> Vec<Option<Vec<u32>>> {
    let boxes: Vec<(Vec3, Vec3)> = meshes.iter().map(|m| m.bounds(LUXEL_BOUNDS_SLACK_UNITS * units_m)).collect();
    let texel_boxes: Vec<(Vec2, Vec2)> = meshes
        .iter()
        .map(|m| {
            let (lo, hi) = m.luxels.iter().fold((Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)), |(lo, hi), l| {
                let t = Vec2::new(l.texel[0] as f32, l.texel[1] as f32);
                (lo.min(t), hi.max(t))
            });
            // Texel x covers [x, x + 1); half a texel of slack around the block.
            (lo - Vec2::splat(0.5), hi + Vec2::splat(1.5))
        })
        .collect();
    let mut by_shader: std::collections::HashMap<&str, Vec<usize>> = std::collections::HashMap::new();
    for (k, m) in meshes.iter().enumerate() {
        by_shader.entry(m.shader.as_str()).or_default().push(k);
    }
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); meshes.len()];
    let mut area = vec![0.0f64; meshes.len()];
    for (t, tri) in triangles.iter().enumerate() {
        let Some(shader) = shader_of_tri.get(t).copied().flatten() else { continue };
        let (Some(ks), Some(&c)) = (by_shader.get(shader), texel_of_tri.get(t)) else { continue };
        let p = tri.map(|i| positions[i as usize]);
        let inside = |(lo, hi): (Vec3, Vec3)| p.iter().all(|q| q.cmpge(lo).all() && q.cmple(hi).all());
        if let Some(&k) = ks.iter().find(|&&k| c.cmpge(texel_boxes[k].0).all() && c.cmple(texel_boxes[k].1).all() && inside(boxes[k])) {
            members[k].push(t as u32);
            let [a, b, c] = p.map(|q| q.as_dvec3());
            area[k] += 0.5 * (b - a).cross(c - a).length();
        }
    }
    holding(members, &area, meshes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A quarter lamp's mesh as convert writes it for oacmpdm1 (2 x 3, the first column
    /// collapsed to the centre), facing down, in Quake units as metres.
    fn quarter() -> PatchMesh {
        let c = Vec3::ZERO;
        let pos = vec![c, Vec3::new(0.0, 0.0, -32.0), c, Vec3::new(24.0, 0.0, -24.0), c, Vec3::new(32.0, 0.0, 0.0)];
        PatchMesh { shader: "lamp".into(), width: 2, height: 3, normal: vec![Vec3::NEG_Y; 6], pos, area_m2: 0.0, rgb: Vec::new(), point_area_m2: Vec::new(), luxels: Vec::new() }
    }

    #[test]
    fn a_collapsed_row_leaves_every_other_quad_dark() {
        let w = quarter().windings();
        // Quad (0, 0) starts centre, centre: nothing. Quad (0, 1) starts at its second
        // row: centre, rim 2, rim 1, centre.
        assert_eq!(w.len(), 1);
        assert_eq!(w[0].0, vec![Vec3::ZERO, Vec3::new(32.0, 0.0, 0.0), Vec3::new(24.0, 0.0, -24.0), Vec3::ZERO]);
        assert_eq!(w[0].1, Vec3::NEG_Y);
    }

    #[test]
    fn a_record_stands_for_its_triangles_only_while_their_area_is_its_own() {
        let mut m = quarter();
        // Two triangles on the quarter disc's fan, area 2 x 384 = 768.
        let positions = vec![Vec3::ZERO, Vec3::new(0.0, 0.0, -32.0), Vec3::new(24.0, 0.0, -24.0), Vec3::new(32.0, 0.0, 0.0), Vec3::new(300.0, 0.0, 0.0)];
        let tris = vec![[0, 1, 2], [0, 2, 3], [0, 3, 4]];
        let shaders = vec![Some("lamp"), Some("lamp"), Some("lamp")];
        m.area_m2 = 768.0;
        assert_eq!(match_triangles(&[m.clone()], &positions, &tris, &shaders, 1.0), vec![Some(vec![0, 1])]);
        // Another shader's triangles are not the lamp's.
        assert_eq!(match_triangles(&[m.clone()], &positions, &tris, &[Some("lamp"), Some("other"), None], 1.0), vec![None]);
        // Moved (the mesh no longer has it where the record says): none.
        let moved: Vec<Vec3> = positions.iter().map(|p| *p + Vec3::X * 5.0).collect();
        assert_eq!(match_triangles(&[m.clone()], &moved, &tris, &shaders, 1.0), vec![None]);
        m.area_m2 = 800.0;
        assert_eq!(match_triangles(&[m], &positions, &tris, &shaders, 1.0), vec![None]);
    }

    #[test]
    fn a_triangle_within_two_records_bounds_goes_to_the_nearer() {
        // A 10 x 10 square drawn as 200 triangles, and a small square hovering 0.3 above
        // its middle (within the bounds' slack): the big one's middle triangles lie within
        // both bounds but on the big one.
        let square = |lo: f32, hi: f32, y: f32, area: f64| PatchMesh {
            luxels: Vec::new(),
            shader: "s".into(),
            width: 2,
            height: 2,
            pos: vec![Vec3::new(lo, y, lo), Vec3::new(lo, y, hi), Vec3::new(hi, y, lo), Vec3::new(hi, y, hi)],
            normal: vec![Vec3::Y; 4],
            area_m2: area,
            rgb: Vec::new(),
            point_area_m2: Vec::new(),
        };
        let records = [square(0.0, 10.0, 0.0, 100.0), square(4.0, 6.0, 0.3, 4.0)];
        let mut positions = Vec::new();
        let mut tris = Vec::new();
        for (lo, hi, y, n) in [(0.0f32, 10.0f32, 0.0f32, 10usize), (4.0, 6.0, 0.3, 1)] {
            let base = positions.len() as u32;
            for i in 0..=n {
                for j in 0..=n {
                    positions.push(Vec3::new(lo + (hi - lo) * i as f32 / n as f32, y, lo + (hi - lo) * j as f32 / n as f32));
                }
            }
            let at = |i: usize, j: usize| base + (i * (n + 1) + j) as u32;
            for i in 0..n {
                for j in 0..n {
                    tris.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                    tris.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
                }
            }
        }
        let shaders = vec![Some("s"); tris.len()];
        let m = match_triangles(&records, &positions, &tris, &shaders, 1.0);
        assert_eq!(m[0].as_ref().map(Vec::len), Some(200));
        assert_eq!(m[1], Some(vec![200, 201]));
    }

    #[test]
    fn the_record_is_checked_before_it_is_read() {
        let ok = serde_json::json!([{ "shader": "s", "size": [2, 2], "xyz": [0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0], "normal": [0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1], "area_m2": 1.0 }]);
        let m = from_extras(&ok, DVec3::new(1.0, 0.0, 0.0)).unwrap();
        assert_eq!(m[0].pos[1], Vec3::ZERO, "positions go to the stored frame");
        assert!(m[0].rgb.is_empty() && m[0].point_area_m2.is_empty());
        let mut lit = ok.clone();
        lit[0]["rgb"] = serde_json::json!([1, 2, 3, 4, 5, 6, 7, 8, 9, 255, 0, 0]);
        lit[0]["point_area_m2"] = serde_json::json!([0.25, 0.25, 0.25, 0.25]);
        let m = from_extras(&lit, DVec3::ZERO).unwrap();
        assert_eq!((m[0].rgb[3], m[0].point_area_m2[2]), ([255, 0, 0], 0.25));
        for (key, bad) in [("rgb", serde_json::json!([1, 2, 3, 4, 5, 6, 7, 8, 9, 256, 0, 0])), ("rgb", serde_json::json!([1.5, 2, 3, 4, 5, 6, 7, 8, 9, 1, 0, 0])), ("point_area_m2", serde_json::json!([0.25, 0.25, -0.25, 0.25])), ("point_area_m2", serde_json::json!([0.25]))] {
            let mut b = lit.clone();
            b[0][key] = bad;
            assert!(from_extras(&b, DVec3::ZERO).is_err(), "{b}");
        }
        let mut half = lit.clone();
        half[0].as_object_mut().unwrap().remove("rgb");
        assert!(from_extras(&half, DVec3::ZERO).is_err(), "bytes without areas");
        // The luxel samples: texels, points (to the stored frame) and unit normals.
        let mut lux = ok.clone();
        lux[0]["luxel_texel"] = serde_json::json!([3, 4, 9, 6]);
        lux[0]["luxel_xyz"] = serde_json::json!([1, 2, 3, 4, 5, 6]);
        lux[0]["luxel_normal"] = serde_json::json!([0, 2, 0, 0, 0, 1]);
        let m = from_extras(&lux, DVec3::new(1.0, 0.0, 0.0)).unwrap();
        assert_eq!(m[0].luxels, vec![PatchLuxel { texel: [3, 4], pos: Vec3::new(0.0, 2.0, 3.0), normal: Vec3::Y, nudge: None }, PatchLuxel { texel: [9, 6], pos: Vec3::new(3.0, 5.0, 6.0), normal: Vec3::Z, nudge: None }]);
        for (key, bad) in [
            ("luxel_texel", serde_json::json!([3, 4, 9])),
            ("luxel_texel", serde_json::json!([3, 4.5, 9, 6])),
            ("luxel_texel", serde_json::json!([3, -4, 9, 6])),
            ("luxel_xyz", serde_json::json!([1, 2, 3])),
            ("luxel_normal", serde_json::json!([0, 0, 0, 0, 0, 1])),
            ("luxel_nudge", serde_json::json!([1, 0, 0, 0, 1, 0])),
            ("luxel_nudge", serde_json::json!([1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 2])),
        ] {
            let mut b = lux.clone();
            b[0][key] = bad;
            assert!(from_extras(&b, DVec3::ZERO).is_err(), "{b}");
        }
        // The nudge directions, when the record has them: two unit vectors per luxel.
        let mut nudged = lux.clone();
        nudged[0]["luxel_nudge"] = serde_json::json!([1, 0, 0, 0, 1, 0, 0, 0, 1, 0, -1, 0]);
        let m = from_extras(&nudged, DVec3::ZERO).unwrap();
        assert_eq!(m[0].luxels[0].nudge, Some([Vec3::X, Vec3::Y]));
        assert_eq!(m[0].luxels[1].nudge, Some([Vec3::Z, Vec3::NEG_Y]));
        let mut half = lux.clone();
        half[0].as_object_mut().unwrap().remove("luxel_normal");
        assert!(from_extras(&half, DVec3::ZERO).is_err(), "points without normals");
        for bad in [
            serde_json::json!({}),
            serde_json::json!([{ "shader": "s", "size": [2, 2], "xyz": [0], "normal": [], "area_m2": 1.0 }]),
            serde_json::json!([{ "shader": "s", "size": [100000, 100000], "xyz": [], "normal": [], "area_m2": 1.0 }]),
            serde_json::json!([{ "shader": "s", "size": [2, 2], "xyz": [0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, "x"], "normal": [0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1], "area_m2": 1.0 }]),
            serde_json::json!([{ "shader": "s", "size": [2, 2], "xyz": [0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0], "normal": [0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1], "area_m2": -1.0 }]),
        ] {
            assert!(from_extras(&bad, DVec3::ZERO).is_err(), "{bad}");
        }
    }
}
