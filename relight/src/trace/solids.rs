//! Where q3map2 found solid when it placed a lightmap's samples: the BSP tree and the
//! opaque brushes convert keeps in the scene's extras (`q3_solids`, written by
//! `q3gltf_convert::solids`), asked the question q3map2's `ClusterForPointExt` asked.
//!
//! A point is in solid when the tree puts it in a leaf of structural solid (a point within
//! [`PLANE_EPSILON_UNITS`] of a plane goes to the open side when that side is open:
//! `PointInLeafNum`), or when it lies within [`BRUSH_EPSILON_UNITS`] of the inside of an
//! opaque brush listed in its leaf, detail brushes included. The mesh alone cannot say the
//! second: a detail brush of caulk has no faces in the glTF.

use glam::{DVec3, Vec3};
use serde_json::Value;

/// q3map2's `PointInLeafNum`: within this distance of a node's plane (Quake units) a
/// point is tried on the front side first.
pub const PLANE_EPSILON_UNITS: f64 = 0.1;
/// q3map2's `LUXEL_EPSILON`: a point this far outside a brush's planes (Quake units)
/// still counts as inside it.
pub const BRUSH_EPSILON_UNITS: f64 = 0.125;
/// q3map2's `VERTEX_EPSILON`, for the vertices of vertex-lit surfaces: a vertex counts as
/// inside a brush only this far inside all its planes (Quake units; a vertex on a brush's
/// face is not in it).
pub const VERTEX_EPSILON_UNITS: f64 = -0.125;

/// The solid structure of a map, in the scene's stored frame (metres; see
/// [`crate::scene::Scene::origin`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Solids {
    /// Unit normal out of the solid and distance: `n . p = d` on the plane.
    planes: Vec<(DVec3, f64)>,
    /// Plane, front child, back child; a child `>= 0` is a later node, `< 0` the leaf
    /// `-(c + 1)`.
    nodes: Vec<(u32, [i32; 2])>,
    leafs: Vec<Leaf>,
    leaf_brushes: Vec<u32>,
    /// Range into `brush_planes`.
    brushes: Vec<(u32, u32)>,
    brush_planes: Vec<u32>,
    /// Epsilons in metres.
    plane_eps_m: f64,
    brush_eps_m: f64,
    /// Metres per Quake unit.
    units_m: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Leaf {
    /// In structural solid.
    solid: bool,
    /// Range into `leaf_brushes`.
    first: u32,
    count: u32,
}

pub(crate) fn numbers(v: &Value, key: &str, group: usize) -> Result<Vec<f64>, String> {
    let a = v.get(key).and_then(Value::as_array).ok_or_else(|| format!("`{key}` is missing or not a list"))?;
    if a.len() % group != 0 {
        return Err(format!("`{key}` has {} numbers, not a multiple of {group}", a.len()));
    }
    a.iter().map(|x| x.as_f64().filter(|x| x.is_finite()).ok_or_else(|| format!("`{key}` holds {x}, not a finite number"))).collect()
}

fn index(x: f64, len: usize, what: &str) -> Result<u32, String> {
    if x.fract() != 0.0 || x < 0.0 || x >= len as f64 {
        return Err(format!("{what} {x} is not an index below {len}"));
    }
    Ok(x as u32)
}

impl Solids {
    /// Reads the `q3_solids` record (see the module docs); `origin` is the scene's stored
    /// frame's origin (m) and `units_m` metres per Quake unit. Every index and range is
    /// checked, and the tree's children must come after their parents (no cycles).
    pub fn from_extras(v: &Value, origin: DVec3, units_m: f64) -> Result<Solids, String> {
        let p = numbers(v, "planes", 4)?;
        let planes: Vec<(DVec3, f64)> = p
            .chunks_exact(4)
            .map(|c| {
                let n = DVec3::new(c[0], c[1], c[2]);
                (n, c[3] - n.dot(origin))
            })
            .collect();
        if let Some(i) = planes.iter().position(|(n, _)| (n.length() - 1.0).abs() > 1e-3) {
            return Err(format!("plane {i} has no unit normal"));
        }
        let n = numbers(v, "nodes", 3)?;
        let l = numbers(v, "leafs", 3)?;
        let lb = numbers(v, "leaf_brushes", 1)?;
        let b = numbers(v, "brushes", 2)?;
        let bp = numbers(v, "brush_planes", 1)?;
        let (num_nodes, num_leafs) = (n.len() / 3, l.len() / 3);
        if num_nodes == 0 {
            return Err("the tree has no nodes".into());
        }
        let child = |c: f64, parent: usize| -> Result<i32, String> {
            let ok = c.fract() == 0.0 && if c >= 0.0 { c > parent as f64 && c < num_nodes as f64 } else { -c - 1.0 < num_leafs as f64 };
            if !ok {
                return Err(format!("node {parent}: child {c} is neither a later node nor one of the {num_leafs} leaves"));
            }
            Ok(c as i32)
        };
        let nodes = n
            .chunks_exact(3)
            .enumerate()
            .map(|(i, c)| Ok((index(c[0], planes.len(), "node plane")?, [child(c[1], i)?, child(c[2], i)?])))
            .collect::<Result<Vec<_>, String>>()?;
        let range = |first: f64, count: f64, len: usize, what: &str| -> Result<(u32, u32), String> {
            let first_ok = first.fract() == 0.0 && first >= 0.0;
            let count_ok = count.fract() == 0.0 && count >= 0.0;
            if !first_ok || !count_ok || first + count > len as f64 {
                return Err(format!("{what} {first}+{count} outside the {len} present"));
            }
            Ok((first as u32, count as u32))
        };
        let leafs = l
            .chunks_exact(3)
            .map(|c| {
                let (first, count) = range(c[1], c[2], lb.len(), "leaf brushes")?;
                Ok(Leaf { solid: c[0] != 0.0, first, count })
            })
            .collect::<Result<Vec<_>, String>>()?;
        let brushes = b.chunks_exact(2).map(|c| range(c[0], c[1], bp.len(), "brush planes")).collect::<Result<Vec<_>, String>>()?;
        let leaf_brushes = lb.iter().map(|&x| index(x, brushes.len(), "leaf brush")).collect::<Result<Vec<_>, String>>()?;
        let brush_planes = bp.iter().map(|&x| index(x, planes.len(), "brush plane")).collect::<Result<Vec<_>, String>>()?;
        let units_m = if units_m.is_finite() && units_m > 0.0 { units_m } else { q3gltf_convert::units::DEFAULT_SCALE };
        Ok(Solids {
            planes,
            nodes,
            leafs,
            leaf_brushes,
            brushes,
            brush_planes,
            plane_eps_m: PLANE_EPSILON_UNITS * units_m,
            brush_eps_m: BRUSH_EPSILON_UNITS * units_m,
            units_m,
        })
    }

    fn side(&self, plane: u32, p: DVec3) -> f64 {
        let (n, d) = self.planes[plane as usize];
        n.dot(p) - d
    }

    /// The leaf q3map2's `PointInLeafNum` finds: down the tree; a point on a plane (within
    /// the epsilon) tries the front first and takes the back only when the front's leaf is
    /// solid. Iterative, with the pending back sides on a stack.
    fn leaf(&self, p: DVec3) -> usize {
        let mut pending: Vec<i32> = Vec::new();
        let mut node = 0i32;
        loop {
            while node >= 0 {
                let (plane, [front, back]) = self.nodes[node as usize];
                let d = self.side(plane, p);
                node = if d > self.plane_eps_m {
                    front
                } else if d < -self.plane_eps_m {
                    back
                } else {
                    pending.push(back);
                    front
                };
            }
            let leaf = (-(node as i64) - 1) as usize;
            match pending.pop() {
                Some(back) if self.leafs[leaf].solid => node = back,
                _ => return leaf,
            }
        }
    }

    /// Whether q3map2 counted the point (stored frame, m) as in solid
    /// (`ClusterForPointExt`): in a leaf of structural solid, or inside an opaque brush of
    /// its leaf within the brush epsilon.
    pub fn contains(&self, p: Vec3) -> bool {
        self.contains_within(p, self.brush_eps_m)
    }

    /// Metres per Quake unit.
    pub fn units_m(&self) -> f64 {
        self.units_m
    }

    /// [`Solids::contains`] with the brush epsilon `brush_eps_m` (metres, positive
    /// outwards): q3map2 asks with [`VERTEX_EPSILON_UNITS`] for a vertex.
    pub fn contains_within(&self, p: Vec3, brush_eps_m: f64) -> bool {
        let p = p.as_dvec3();
        if !p.is_finite() {
            return false;
        }
        let leaf = self.leafs[self.leaf(p)];
        if leaf.solid {
            return true;
        }
        self.leaf_brushes[leaf.first as usize..(leaf.first + leaf.count) as usize].iter().any(|&b| {
            let (first, count) = self.brushes[b as usize];
            self.brush_planes[first as usize..(first + count) as usize].iter().all(|&pl| self.side(pl, p) <= brush_eps_m)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// The floor y = 0 splits the world (above open leaf 0, below solid leaf 1); a box
    /// 0..1 m of caulk stands in the open leaf. Scale 1 m per unit.
    fn world() -> Value {
        json!({
            "planes": [0, 1, 0, 0,  1, 0, 0, 1,  -1, 0, 0, 0,  0, 1, 0, 1,  0, 0, 1, 1,  0, 0, -1, 0,  0, -1, 0, 0],
            "nodes": [0, -1, -2],
            "leafs": [0, 0, 1,  1, 1, 0],
            "leaf_brushes": [0],
            "brushes": [0, 6],
            "brush_planes": [1, 2, 3, 6, 4, 5],
        })
    }

    #[test]
    fn below_the_floor_and_inside_the_caulk_box_is_solid() {
        let s = Solids::from_extras(&world(), DVec3::ZERO, 1.0).unwrap();
        assert!(s.contains(Vec3::new(5.0, -1.0, 0.0)));
        assert!(!s.contains(Vec3::new(5.0, 1.0, 0.0)));
        assert!(s.contains(Vec3::new(0.5, 0.5, 0.5)));
        // The brush counts a point up to 0.125 unit outside it as inside.
        assert!(s.contains(Vec3::new(1.1, 0.5, 0.5)));
        assert!(!s.contains(Vec3::new(1.2, 0.5, 0.5)));
        // On the floor's plane: the front (open) side is taken.
        assert!(!s.contains(Vec3::new(5.0, -0.05, 0.0)));
        assert!(s.contains(Vec3::new(5.0, -0.2, 0.0)));
    }

    /// q3map2's vertex samples: a vertex on a brush's face is not in it; one inside is
    /// nudged 4 units along the map's axes (Quake z, glTF y, first), to the first clear
    /// point; one deep in solid is left out.
    #[test]
    fn a_vertex_in_solid_is_nudged_along_the_maps_axes() {
        use crate::rows::luxel::vertex_sample_point;
        let s = Solids::from_extras(&world(), DVec3::ZERO, 1.0).unwrap();
        let clear = Vec3::new(5.0, 1.0, 0.0);
        assert_eq!(vertex_sample_point(&s, clear), Some(clear));
        // On the caulk box's face (and within the luxels' epsilon of it): clear.
        assert!(s.contains(Vec3::new(1.0, 0.5, 0.5)));
        assert_eq!(vertex_sample_point(&s, Vec3::new(1.0, 0.5, 0.5)), Some(Vec3::new(1.0, 0.5, 0.5)));
        // Inside the box: Quake z + 4 units first, glTF y + 4 m here.
        assert_eq!(vertex_sample_point(&s, Vec3::new(0.5, 0.5, 0.5)), Some(Vec3::new(0.5, 4.5, 0.5)));
        // Under the floor: up by 4 is still solid at -6, up by 8 is clear.
        assert_eq!(vertex_sample_point(&s, Vec3::new(5.0, -6.0, 0.0)), Some(Vec3::new(5.0, -6.0, 0.0) + Vec3::Y * 8.0));
        assert_eq!(vertex_sample_point(&s, Vec3::new(5.0, -1.0, 0.0)), Some(Vec3::new(5.0, 3.0, 0.0)));
        // Deeper than every nudge reaches: left out.
        assert_eq!(vertex_sample_point(&s, Vec3::new(5.0, -20.0, 0.0)), None);
    }

    #[test]
    fn the_stored_frame_moves_the_planes() {
        let s = Solids::from_extras(&world(), DVec3::new(0.0, 10.0, 0.0), 1.0).unwrap();
        // World y = 10.5 above the floor is stored y = 0.5.
        assert!(s.contains(Vec3::new(5.0, -10.5, 0.0)));
        assert!(!s.contains(Vec3::new(5.0, -9.5, 0.0)));
    }

    #[test]
    fn broken_records_are_refused_with_the_reason() {
        let cases: [(&str, Value, &str); 6] = [
            ("nodes", json!([0, 0, -2]), "child 0"),
            ("nodes", json!([0, -1, -3]), "child -3"),
            ("nodes", json!([9, -1, -2]), "node plane 9"),
            ("leafs", json!([0, 0, 2, 1, 1, 0]), "leaf brushes 0+2"),
            ("planes", json!([0, 2, 0, 0]), "unit normal"),
            ("brush_planes", json!([1, 2, 3, 6, 4, "x"]), "not a finite number"),
        ];
        for (key, value, said) in cases {
            let mut v = world();
            v[key] = value;
            let why = Solids::from_extras(&v, DVec3::ZERO, 1.0).unwrap_err();
            assert!(why.contains(said), "{key}: {why}");
        }
    }

    #[test]
    fn a_point_on_planes_all_the_way_down_takes_the_first_open_leaf() {
        // Two nested splits on the same plane y = 0: front of both is solid, the inner
        // back is open. q3map2 tries front first and falls back to the back side.
        let v = json!({
            "planes": [0, 1, 0, 0],
            "nodes": [0, 1, -3,  0, -1, -2],
            "leafs": [1, 0, 0,  0, 0, 0,  1, 0, 0],
            "leaf_brushes": [], "brushes": [], "brush_planes": [],
        });
        let s = Solids::from_extras(&v, DVec3::ZERO, 1.0).unwrap();
        assert!(!s.contains(Vec3::new(0.0, 0.0, 0.0)));
        assert!(s.contains(Vec3::new(0.0, 1.0, 0.0)));
    }
}
