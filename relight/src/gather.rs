//! The data's own bounced light, gathered once: for the light placement only.
//!
//! The model's bounce ([`crate::model::bounce`]) is the light of the model's own
//! emitters reflected by the scene, through an operator `K` between rows. The placement
//! ([`crate::init::auto`]) works on a subsample of the rows, where `K` cannot be formed
//! (a ray's landing row is rarely in the subsample); there the bounce is estimated from
//! the data instead, once, independent of the lights:
//!
//! ```text
//! o_i = albedo_i / pi * E_ind(x_i) ~= albedo_i * mean_m L(hit_m)      (M cosine-weighted rays)
//! ```
//!
//! where `L(hit)` is the data's radiance where the ray lands: `albedo x decode(lightmap)`
//! (or the decoded vertex colour on vertex-lit surfaces). Because the data holds every
//! bounce, `o` stands for all orders; the model scales it by a fitted `k_g` per channel
//! ([`crate::model::Model::gathered`]) so that lights are placed for the light it leaves
//! unexplained. Rays that escape, land on the back of a surface, or on a surface without
//! baked lighting, bring nothing.

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::trace::bvh::Bvh;
use crate::model::bounce::{barycentric, cosine_direction};
use crate::rows::Rows;
use crate::scene::{Lighting, Scene};
use crate::texel;

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct GatherStats {
    pub rows: usize,
    pub rays_per_row: usize,
    pub rays: u64,
    /// Rays that landed on the front of a surface with baked lighting.
    pub hits_with_data: u64,
}

/// The data's outgoing radiance at a point of triangle `t` with barycentrics `b`, seen
/// along `dir`: zero from behind or without baked lighting.
pub fn data_radiance(scene: &Scene, t: usize, b: [f32; 3], dir: Vec3) -> Option<[f32; 3]> {
    let mesh = &scene.mesh;
    let tri = mesh.triangles[t].map(|i| i as usize);
    let n = mesh.normals[tri[0]] * b[0] + mesh.normals[tri[1]] * b[1] + mesh.normals[tri[2]] * b[2];
    if !(n.dot(dir) < 0.0) {
        return None;
    }
    let mat = &scene.materials[mesh.tri_material[t] as usize];
    let lerp2 = |v: &[Vec2]| v[tri[0]] * b[0] + v[tri[1]] * b[1] + v[tri[2]] * b[2];
    let e = match (mat.lighting, mat.lightmap) {
        (Lighting::Lightmap, Some(lm)) => {
            let uv = lerp2(&mesh.uv1);
            texel::bilinear(&scene.textures[lm], uv.x, uv.y, |v| mat.decode(v))
        }
        (Lighting::Vertex, _) => {
            let c = [0, 1, 2].map(|k| mesh.colors[tri[0]][k] * b[0] + mesh.colors[tri[1]][k] * b[1] + mesh.colors[tri[2]][k] * b[2]);
            c.map(|v| mat.decode(v))
        }
        _ => return None,
    };
    let albedo = match mat.albedo {
        Some(i) => {
            let uv = lerp2(&mesh.uv0);
            texel::bilinear(&scene.textures[i], uv.x, uv.y, texel::srgb_to_linear)
        }
        None => [1.0; 3],
    };
    let f = mat.albedo_factor;
    Some([0, 1, 2].map(|c| albedo[c] * f[c] * e[c]))
}

/// `o_i` of every row (see the module docs) using `rays_per_row` rays per row (rounded up
/// to a square).
pub fn gather(scene: &Scene, bvh: &Bvh, pb: &Rows, rays_per_row: usize) -> (Vec<[f32; 3]>, GatherStats) {
    let s = (rays_per_row.max(1) as f64).sqrt().ceil() as usize;
    let m = s * s;
    let (lo, hi) = scene.mesh.bounds();
    let reach = 2.0 * (hi - lo).length().max(1e-3);
    let offset = pb.sampling.ray_offset;
    let rows: Vec<([f32; 3], u64)> = (0..pb.len())
        .into_par_iter()
        .map(|i| {
            let n = pb.normal[i];
            let o = pb.pos[i] + n * offset;
            let mut sum = [0.0f64; 3];
            let mut hits = 0u64;
            for cell in 0..m {
                let d = cosine_direction(n, i as u32, cell, s);
                let Some((t, tri)) = bvh.first_hit(o, d * reach, 1.0) else { continue };
                let p = o + d * (reach * t);
                let [a, b, c] = scene.mesh.triangles[tri as usize].map(|v| scene.mesh.positions[v as usize]);
                if let Some(l) = data_radiance(scene, tri as usize, barycentric(p, a, b, c), d) {
                    hits += 1;
                    for k in 0..3 {
                        sum[k] += l[k] as f64;
                    }
                }
            }
            let a = pb.albedo[i];
            ([0, 1, 2].map(|k| (a[k] as f64 * sum[k] / m as f64) as f32), hits)
        })
        .collect();
    let mut st = GatherStats { rows: pb.len(), rays_per_row: m, rays: (pb.len() * m) as u64, hits_with_data: 0 };
    let mut out = Vec::with_capacity(rows.len());
    for (o, h) in rows {
        out.push(o);
        st.hits_with_data += h;
    }
    (out, st)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rows::{Row, Sampling};
    use crate::scene::{Material, Mesh, Texture, Wrap};

    /// A row at the centre of the floor of a closed box whose other five walls all show the
    /// same baked radiance `L` (vertex-lit, white): every ray lands on a wall, so
    /// `o = albedo * L` exactly, whatever the directions.
    #[test]
    fn inside_a_uniformly_lit_box_the_gather_is_exact() {
        let mut m = Mesh::default();
        let quad = |m: &mut Mesh, o: Vec3, u: Vec3, v: Vec3, mat: u32| {
            let n = u.cross(v).normalize();
            let base = m.positions.len() as u32;
            for p in [o, o + u, o + u + v, o + v] {
                m.positions.push(p);
                m.normals.push(n);
                m.uv0.push(Vec2::ZERO);
                m.uv1.push(Vec2::ZERO);
                m.colors.push([0.25, 0.5, 0.125]);
                m.v_material.push(mat);
            }
            m.triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
            m.tri_material.extend([mat, mat]);
        };
        // Unit box, normals inward; the floor (y = 0) has material 1 (no baked lighting).
        quad(&mut m, Vec3::ZERO, Vec3::Z, Vec3::X, 1);
        quad(&mut m, Vec3::Y, Vec3::X, Vec3::Z, 0);
        quad(&mut m, Vec3::ZERO, Vec3::X, Vec3::Y, 0);
        quad(&mut m, Vec3::Z, Vec3::Y, Vec3::X, 0);
        quad(&mut m, Vec3::ZERO, Vec3::Y, Vec3::Z, 0);
        quad(&mut m, Vec3::X, Vec3::Z, Vec3::Y, 0);
        m.tri_source = (0..m.triangles.len() as u32).collect();
        m.reweld();
        let lit = Material { name: "wall".into(), albedo: None, albedo_factor: [1.0; 4], lighting: Lighting::Vertex, lightmap: None, overbright_bits: 2, lightmap_gamma: 1.0, censor_byte: crate::scene::CENSOR_BYTE, sky: false, double_sided: false, casts_shadow: true, emitter: None, sky_lights: Vec::new(), emission: [0.0; 3] };
        let dark = Material { name: "floor".into(), lighting: Lighting::None, ..lit.clone() };
        let tex = Texture { width: 1, height: 1, rgba8: vec![255; 4], wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat };
        let scene = Scene { mesh: m, materials: vec![lit, dark], textures: vec![tex], lights: Vec::new(), suns: Vec::new(), origin: glam::DVec3::ZERO, skipped: Vec::new(), units_m: 0.0254, compile: Default::default(), relit: None, solids: None, patch_lights: Vec::new(), patch_vertices: Vec::new(), patch_luxels: Vec::new() };
        let bvh = Bvh::build(&scene.mesh);
        let rows = |pos: Vec3, n: Vec3, albedo: [f32; 3]| {
            let mut r = Rows::new(Sampling::plain(2.0));
            r.push(Row { vertex: u32::MAX, material: 1, texel: [u32::MAX; 3], pos, normal: n, albedo, lo: [0.0; 3], hi: [0.0; 3], weight: [1.0; 3], lower: [0.0; 3], area: 1.0, solid_ahead: crate::rows::SolidAhead::NONE, two_sided: false });
            r.finish();
            r
        };
        let (o, st) = gather(&scene, &bvh, &rows(Vec3::new(0.5, 0.0, 0.5), Vec3::Y, [0.5, 0.8, 1.0]), 16);
        assert_eq!(st.hits_with_data, 16);
        // decode(v) = (v + 1/2 byte) * 4 (overbright 2): L = (1, 2, 0.5) + 2/255.
        let half = 2.0 / 255.0;
        let want = [0.5 * (1.0 + half), 0.8 * (2.0 + half), 1.0 * (0.5 + half)];
        for c in 0..3 {
            assert!((o[0][c] - want[c]).abs() < 1e-5, "{:?} vs {want:?}", o[0]);
        }
        // Seen from outside (the back of the walls), nothing comes in.
        let (o, _) = gather(&scene, &bvh, &rows(Vec3::new(0.5, 2.0, 0.5), -Vec3::Y, [1.0; 3]), 16);
        assert_eq!(o[0], [0.0; 3]);
    }

    /// Half of a row's hemisphere sees a lit wall: the cosine-weighted estimate tends to
    /// the exact form factor. A vertical wall at x = 0 spanning the whole half-space x < 0
    /// seen from a floor point: exactly half the cosine-weighted hemisphere.
    #[test]
    fn the_cosine_weighting_is_right() {
        let mut m = Mesh::default();
        let big = 1e3f32;
        // Wall x = 0, normal +x, huge; floor not modelled (rays below the horizon never occur).
        for p in [Vec3::new(0.0, 0.0, -big), Vec3::new(0.0, 0.0, big), Vec3::new(0.0, big, big), Vec3::new(0.0, big, -big)] {
            m.positions.push(p);
            m.normals.push(Vec3::X);
            m.uv0.push(Vec2::ZERO);
            m.uv1.push(Vec2::ZERO);
            m.colors.push([0.25; 3]);
            m.v_material.push(0);
        }
        m.triangles = vec![[0, 1, 2], [0, 2, 3]];
        m.tri_material = vec![0, 0];
        m.tri_source = vec![0, 1];
        m.reweld();
        let lit = Material { name: "wall".into(), albedo: None, albedo_factor: [1.0; 4], lighting: Lighting::Vertex, lightmap: None, overbright_bits: 2, lightmap_gamma: 1.0, censor_byte: crate::scene::CENSOR_BYTE, sky: false, double_sided: false, casts_shadow: true, emitter: None, sky_lights: Vec::new(), emission: [0.0; 3] };
        let scene = Scene { mesh: m, materials: vec![lit], textures: Vec::new(), lights: Vec::new(), suns: Vec::new(), origin: glam::DVec3::ZERO, skipped: Vec::new(), units_m: 0.0254, compile: Default::default(), relit: None, solids: None, patch_lights: Vec::new(), patch_vertices: Vec::new(), patch_luxels: Vec::new() };
        let bvh = Bvh::build(&scene.mesh);
        let mut pb = Rows::new(Sampling::plain(10.0));
        for k in 0..200 {
            pb.push(Row { vertex: u32::MAX, material: 0, texel: [u32::MAX; 3], pos: Vec3::new(0.5, 0.0, k as f32 * 0.01), normal: Vec3::Y, albedo: [1.0; 3], lo: [0.0; 3], hi: [0.0; 3], weight: [1.0; 3], lower: [0.0; 3], area: 1.0, solid_ahead: crate::rows::SolidAhead::NONE, two_sided: false });
        }
        pb.finish();
        let (o, _) = gather(&scene, &bvh, &pb, 64);
        // L = 1 on the wall (a quarter byte-value times 4, plus the half byte); the row 0.5 m
        // away sees it under nearly the full half-space.
        let mean: f32 = o.iter().map(|o| o[0]).sum::<f32>() / pb.len() as f32;
        let l = 1.0 + 2.0 / 255.0;
        assert!((mean - 0.5 * l).abs() < 0.01, "mean gathered {mean}, expected {}", 0.5 * l);
    }
}
