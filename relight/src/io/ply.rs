//! The mesh relight fits on, written as binary little-endian PLY for inspection in MeshLab
//! and for the tests' independent checks (pymeshlab): world positions in meters (glTF
//! axes) and, as the per-vertex texture coordinate, the lightmap UV (TEXCOORD_1) measured
//! in texels of its atlas (0 on surfaces without a lightmap), and the vertex's material
//! index as the vertex `quality` (so checks can work per surface kind); each face's
//! `quality` is the input triangle it was cut from (`Mesh::tri_source`). Vertices are written as the
//! mesh stores them, one per primitive corner (not merged across primitives or seams).

use std::path::Path;

use crate::error::{Error, Result};
use crate::scene::{Lighting, Scene};

/// Writes `scene`'s mesh to `path` (atomically).
pub fn write(scene: &Scene, path: &Path) -> Result<()> {
    let mesh = &scene.mesh;
    let nv = mesh.positions.len();
    let nt = mesh.triangles.len();
    // Atlas size per vertex, from its material.
    let texel_uv = |v: usize| -> [f32; 2] {
        let m = &scene.materials[mesh.v_material[v] as usize];
        match (m.lighting, m.lightmap) {
            (Lighting::Lightmap, Some(lm)) => {
                let t = &scene.textures[lm];
                [mesh.uv1[v].x * t.width as f32, mesh.uv1[v].y * t.height as f32]
            }
            _ => [0.0; 2],
        }
    };
    let o = scene.origin;
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment q3gltf relight mesh: meters, glTF axes, relative to origin; texture_u/v = lightmap texels\ncomment origin {} {} {}\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\nproperty float texture_u\nproperty float texture_v\nproperty float quality\nelement face {nt}\nproperty list uchar int vertex_indices\nproperty float quality\nend_header\n",
        o.x, o.y, o.z
    );
    let mut out = Vec::with_capacity(header.len() + nv * 24 + nt * 17);
    out.extend_from_slice(header.as_bytes());
    for v in 0..nv {
        let p = mesh.positions[v];
        for x in [p.x, p.y, p.z].into_iter().chain(texel_uv(v)).chain([mesh.v_material[v] as f32]) {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    for (tri, &src) in mesh.triangles.iter().zip(&mesh.tri_source) {
        out.push(3);
        for &i in tri {
            out.extend_from_slice(&(i as i32).to_le_bytes());
        }
        out.extend_from_slice(&(src as f32).to_le_bytes());
    }
    q3gltf_convert::output::write_atomic(path, &out).map_err(|source| Error::Io { path: path.display().to_string(), source })
}
