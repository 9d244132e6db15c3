//! q3map2's shadow casters as the file records them (scene extras `q3_casters` and one
//! buffer view, written by `q3gltf_convert::casters`): the BSP's tree and the casting
//! triangles, Quake units. Read and checked here ([`Casters::from_record`]); what
//! q3map2's light stage made of them, and its hit test, is [`crate::trace::pieces`].

use glam::DVec3;
use serde_json::Value;

/// The record as read: the BSP's tree and the casting triangles, Quake units.
#[derive(Debug, Clone, Default)]
pub struct Casters {
    pub planes: Vec<(DVec3, f64)>,
    /// `(plane, [front, back])`; a child `>= 0` is a node, `< 0` the leaf `-(c + 1)`.
    pub nodes: Vec<(u32, [i32; 2])>,
    pub leaf_solid: Vec<bool>,
    pub vertices: Vec<DVec3>,
    /// `[a, b, c, flags]`; flags bit 0 ([`SKY`]): a sky surface, in the tree but
    /// stopping nothing.
    pub triangles: Vec<[u32; 4]>,
}

/// A caster's flag: a sky surface.
pub const SKY: u32 = 1;

impl Casters {
    /// Reads the record `v` and its buffer view's `bytes`: the counts must give the view's
    /// length exactly, its hash must match, every index must be in range, and the tree's
    /// children must come after their parents.
    pub fn from_record(v: &Value, bytes: &[u8]) -> Result<Casters, String> {
        let count = |k: &str| -> Result<usize, String> { v.get(k).and_then(Value::as_u64).map(|n| n as usize).ok_or_else(|| format!("`{k}` is not a count")) };
        let (np, nn, nl, nv, nt) = (count("planes")?, count("nodes")?, count("leafs")?, count("vertices")?, count("triangles")?);
        let want = [(np, 16usize), (nn, 12), (nl, 4), (nv, 12), (nt, 16)].iter().try_fold(0usize, |acc, &(n, size)| n.checked_mul(size).and_then(|b| acc.checked_add(b)));
        if want != Some(bytes.len()) {
            return Err(format!("its counts do not fit its {} bytes", bytes.len()));
        }
        let hash = v.get("fnv1a64").and_then(Value::as_str).and_then(|h| u64::from_str_radix(h, 16).ok());
        if hash != Some(q3gltf_convert::casters::fnv1a64(bytes)) {
            return Err("its bytes are not the ones it was written with (the file was re-exported?)".into());
        }
        if nn == 0 || nl == 0 {
            return Err("the tree is empty".into());
        }
        let mut at = 0usize;
        let mut word = || {
            let w = [bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]];
            at += 4;
            w
        };
        let mut planes = Vec::with_capacity(np);
        for i in 0..np {
            let f: [f64; 4] = std::array::from_fn(|_| f32::from_le_bytes(word()) as f64);
            let n = DVec3::new(f[0], f[1], f[2]);
            if !(f.iter().all(|x| x.is_finite()) && (n.length() - 1.0).abs() < 1e-3) {
                return Err(format!("plane {i} is not a plane"));
            }
            planes.push((n, f[3]));
        }
        let mut nodes = Vec::with_capacity(nn);
        for i in 0..nn {
            let f: [i32; 3] = std::array::from_fn(|_| i32::from_le_bytes(word()));
            if f[0] < 0 || f[0] as usize >= np {
                return Err(format!("node {i} has no plane {}", f[0]));
            }
            for &c in &f[1..] {
                let ok = if c >= 0 { c as usize > i && (c as usize) < nn } else { ((-(c as i64) - 1) as usize) < nl };
                if !ok {
                    return Err(format!("node {i}: child {c} is neither a later node nor a leaf"));
                }
            }
            nodes.push((f[0] as u32, [f[1], f[2]]));
        }
        let leaf_solid = (0..nl).map(|_| i32::from_le_bytes(word()) != 0).collect();
        let mut vertices = Vec::with_capacity(nv);
        for i in 0..nv {
            let p = DVec3::from_array(std::array::from_fn(|_| f32::from_le_bytes(word()) as f64));
            if !p.is_finite() {
                return Err(format!("vertex {i} is not a number"));
            }
            vertices.push(p);
        }
        let mut triangles = Vec::with_capacity(nt);
        for i in 0..nt {
            let t: [u32; 4] = std::array::from_fn(|_| u32::from_le_bytes(word()));
            if t[..3].iter().any(|&k| k as usize >= nv) {
                return Err(format!("triangle {i} refers to a vertex past the {nv}"));
            }
            triangles.push(t);
        }
        Ok(Casters { planes, nodes, leaf_solid, vertices, triangles })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A record's bytes: one plane (x = 0), the nodes given over two leaves (the second
    /// solid), three vertices and the triangles given.
    fn record(nodes: &[[i32; 3]], triangles: &[[u32; 4]]) -> (Value, Vec<u8>) {
        let mut b = Vec::new();
        for x in [1.0f32, 0.0, 0.0, 0.0] {
            b.extend_from_slice(&x.to_le_bytes());
        }
        for n in nodes {
            for x in n {
                b.extend_from_slice(&x.to_le_bytes());
            }
        }
        for x in [0i32, 1] {
            b.extend_from_slice(&x.to_le_bytes());
        }
        for x in [0.0f32, 0.0, 0.0, 64.0, 0.0, 0.0, 0.0, 64.0, 0.0] {
            b.extend_from_slice(&x.to_le_bytes());
        }
        for t in triangles {
            for x in t {
                b.extend_from_slice(&x.to_le_bytes());
            }
        }
        let v = serde_json::json!({ "planes": 1, "nodes": nodes.len(), "leafs": 2, "vertices": 3, "triangles": triangles.len(), "fnv1a64": format!("{:016x}", q3gltf_convert::casters::fnv1a64(&b)) });
        (v, b)
    }


    #[test]
    fn a_record_is_read_only_when_every_count_index_and_byte_checks() {
        let (v, b) = record(&[[0, -1, -2]], &[[0, 1, 2, 0]]);
        let c = Casters::from_record(&v, &b).unwrap();
        assert_eq!((c.planes.len(), c.nodes.len(), c.leaf_solid, c.triangles.len()), (1, 1, vec![false, true], 1));
        // Bytes changed after writing (a re-export that renumbered the views).
        let mut other = b.clone();
        other[0] ^= 1;
        assert!(Casters::from_record(&v, &other).unwrap_err().contains("not the ones"));
        // Counts that do not fit the bytes, or overflow.
        let mut big = v.clone();
        big["triangles"] = serde_json::json!(u64::MAX / 2);
        assert!(Casters::from_record(&big, &b).unwrap_err().contains("do not fit"));
        // A child that is not a later node; a triangle past the vertices.
        let (v, b) = record(&[[0, 0, -2]], &[[0, 1, 2, 0]]);
        assert!(Casters::from_record(&v, &b).unwrap_err().contains("child"));
        let (v, b) = record(&[[0, -1, -3]], &[[0, 1, 2, 0]]);
        assert!(Casters::from_record(&v, &b).unwrap_err().contains("child"));
        let (v, b) = record(&[[0, -1, -2]], &[[0, 1, 3, 0]]);
        assert!(Casters::from_record(&v, &b).unwrap_err().contains("vertex"));
        // A count that is not a count.
        let (mut v, b) = record(&[[0, -1, -2]], &[[0, 1, 2, 0]]);
        v["planes"] = serde_json::json!(-1);
        assert!(Casters::from_record(&v, &b).is_err());
    }

}
