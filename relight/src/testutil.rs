//! Small synthetic scenes for unit tests: a closed box room seen from inside.

use glam::{Vec2, Vec3};

use crate::rows::{Row, Rows, Sampling};
use crate::scene::Mesh;

/// A 4 x 2.5 x 3 m box room (normals inward), each wall an `n x n` grid, with one row per
/// vertex whose data is a smooth made-up field (tests of the gradient do not need it to
/// be realisable): intervals of width 0.02, a few censored channels.
pub fn room(n: usize) -> (Mesh, Rows) {
    let size = Vec3::new(4.0, 2.5, 3.0);
    let mut m = Mesh::default();
    // (origin, u, v) with u x v pointing into the room.
    let faces = [
        (Vec3::ZERO, Vec3::new(size.x, 0.0, 0.0), Vec3::new(0.0, 0.0, size.z)), // floor, normal +y? (x cross z = -y) fixed below
        (Vec3::new(0.0, size.y, 0.0), Vec3::new(0.0, 0.0, size.z), Vec3::new(size.x, 0.0, 0.0)),
        (Vec3::ZERO, Vec3::new(0.0, size.y, 0.0), Vec3::new(size.x, 0.0, 0.0)),
        (Vec3::new(0.0, 0.0, size.z), Vec3::new(size.x, 0.0, 0.0), Vec3::new(0.0, size.y, 0.0)),
        (Vec3::ZERO, Vec3::new(0.0, 0.0, size.z), Vec3::new(0.0, size.y, 0.0)),
        (Vec3::new(size.x, 0.0, 0.0), Vec3::new(0.0, size.y, 0.0), Vec3::new(0.0, 0.0, size.z)),
    ];
    let center = size * 0.5;
    for (o, u, v) in faces {
        let mut normal = u.cross(v).normalize();
        let (u, v) = if normal.dot(center - (o + (u + v) * 0.5)) < 0.0 {
            normal = -normal;
            (v, u)
        } else {
            (u, v)
        };
        let base = m.positions.len() as u32;
        for i in 0..=n {
            for k in 0..=n {
                let (a, b) = (i as f32 / n as f32, k as f32 / n as f32);
                m.positions.push(o + u * a + v * b);
                m.normals.push(normal);
                m.uv0.push(Vec2::new(a, b));
                m.uv1.push(Vec2::new(a, b));
                m.colors.push([1.0; 3]);
                m.v_material.push(0);
            }
        }
        let idx = |i: usize, k: usize| base + (i * (n + 1) + k) as u32;
        for i in 0..n {
            for k in 0..n {
                m.triangles.push([idx(i, k), idx(i + 1, k), idx(i + 1, k + 1)]);
                m.triangles.push([idx(i, k), idx(i + 1, k + 1), idx(i, k + 1)]);
                m.tri_source.extend([m.triangles.len() as u32 - 2, m.triangles.len() as u32 - 1]);
                m.tri_material.extend([0, 0]);
            }
        }
    }
    m.reweld();
    let nv = m.positions.len();
    let mut area = vec![0.0f32; nv];
    for t in 0..m.triangles.len() {
        let a = m.triangle_area(t);
        for &v in &m.triangles[t] {
            area[v as usize] += a / 3.0;
        }
    }
    let (lo, hi) = m.bounds();
    let mut rows = Rows::new(Sampling::plain((hi - lo).length()));
    for (i, p) in m.positions.iter().enumerate() {
        let t = [0.2 + 0.05 * p.x, 0.3 + 0.04 * p.y, 0.25 + 0.03 * p.z];
        let censored = i % 7 == 0;
        rows.push(Row {
            vertex: i as u32,
            material: 0,
            texel: [u32::MAX; 3],
            pos: *p,
            normal: m.normals[i],
            albedo: [0.5 + 0.05 * p.x, 0.6, 0.7 - 0.05 * p.z],
            lo: t,
            hi: t.map(|v| v + 0.02),
            weight: if censored { [0.0, 1.0, 0.5] } else { [1.0; 3] },
            lower: if censored { [0.4, 0.0, 0.3] } else { [0.0; 3] },
            area: area[i],
            solid_ahead: crate::rows::SolidAhead::NONE,
            two_sided: false,
        });
    }
    rows.finish();
    (m, rows)
}

/// Appends the quad `corners` (in order, material 0, normal `normal`) to `mesh` as two
/// triangles split along its diagonal from the first corner.
pub fn push_quad(mesh: &mut Mesh, corners: [[f32; 3]; 4], normal: glam::Vec3) {
    let base = mesh.positions.len() as u32;
    for p in corners {
        mesh.positions.push(glam::Vec3::from(p));
        mesh.normals.push(normal);
        mesh.uv0.push(glam::Vec2::ZERO);
        mesh.uv1.push(glam::Vec2::ZERO);
        mesh.colors.push([1.0; 3]);
        mesh.v_material.push(0);
    }
    mesh.reweld();
    mesh.triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
    mesh.tri_material.extend([0, 0]);
    mesh.tri_source.extend([mesh.triangles.len() as u32 - 2, mesh.triangles.len() as u32 - 1]);
}

/// `count` small quads scattered in and around [`room`]'s box (the shadow walks' tests):
/// a third parallel to the floor's axes x and z, a third to y and z (their edges are
/// their boxes' faces), a third slanted.
pub fn scatter_quads(mesh: &mut Mesh, count: u32) {
    use crate::model::bounce::hash01;
    let at = |k: u32, s: u32| -0.5 + 5.0 * hash01(k, s);
    for k in 0..count {
        let (x, y, z) = (at(k, 1), at(k, 2), at(k, 3));
        let (a, b) = (0.05 + 0.4 * hash01(k, 4), 0.05 + 0.4 * hash01(k, 5));
        let corners = match k % 3 {
            0 => [[x, y, z], [x + a, y, z], [x + a, y, z + b], [x, y, z + b]],
            1 => [[x, y, z], [x, y + a, z], [x, y + a, z + b], [x, y, z + b]],
            _ => [[x, y, z], [x + a, y + 0.3 * b, z], [x + a, y + b, z + a], [x - 0.2 * a, y + b, z + b]],
        };
        push_quad(mesh, corners, glam::Vec3::Y);
    }
}

/// A lightmapped material (no texture, overbright 2) for tests of the model's terms.
pub fn material(name: &str) -> crate::scene::Material {
    crate::scene::Material { lightmap: Some(0), ..crate::scene::Material::plain(name, crate::scene::Lighting::Lightmap, 2) }
}

/// A scene of `mesh` and `materials` in Quake units (0.0254 m), at the origin, with nothing
/// else.
pub fn scene(mesh: Mesh, materials: Vec<crate::scene::Material>) -> crate::scene::Scene {
    crate::scene::Scene {
        mesh,
        materials,
        textures: Vec::new(),
        lights: Vec::new(),
        suns: Vec::new(),
        origin: glam::DVec3::ZERO,
        skipped: Vec::new(),
        units_m: 0.0254,
        compile: Default::default(),
        relit: None,
        solids: None,
        patch_lights: Vec::new(),
        patch_vertices: Vec::new(),
        patch_luxels: Vec::new(),
        casters: None,
    }
}

/// Synthetic chain bases over `n` rows for tests of the non-local chain: dirt, a filter
/// and a bounce operator that each gather a row from itself and two others (rings of
/// steps 1 and 3, and 1 and 7), a reflectance, and `bounces` passes.
pub fn chain_bases(n: usize, bounces: usize) -> crate::model::Bases {
    let ring = |w: f32, step: usize| {
        let mut s = crate::model::Sparse::empty();
        for i in 0..n {
            s.push_row([(i as u32, 1.0 - 2.0 * w), (((i + 1) % n) as u32, w), (((i + step) % n) as u32, w)]);
        }
        s
    };
    crate::model::Bases {
        dirt: vec![crate::model::compile::DirtBasis { settings: crate::scene::DirtSettings::Q3MAP2, factor: (0..n).map(|i| 0.6 + 0.05 * (i % 8) as f32).collect() }],
        filter: Some(ring(0.2, 3)),
        bounce: Some(factored_transport(n, n / 3 + 1)),
        bounce_reflectance: (0..n).map(|i| [0.5, 0.4 + 0.01 * (i % 9) as f32, 0.3]).collect(),
        bounces,
        ..crate::model::Bases::default()
    }
}

/// A bounce transport through `s` sources, as q3map2's pieces make it
/// ([`crate::model::bounce::Transport`]): row `i`'s rays land on sources `i mod s` (0.2)
/// and `(i + 5) mod s` (0.1); source `p` averages rows `p, p + s, p + 2s, ...`.
pub fn factored_transport(n: usize, s: usize) -> crate::model::bounce::Transport {
    let s = s.max(1);
    let mut gather = crate::model::Sparse::empty();
    for i in 0..n {
        gather.push_row([((i % s) as u32, 0.2), (((i + 5) % s) as u32, 0.1)]);
    }
    let mut emit = crate::model::Sparse::empty();
    for p in 0..s {
        let members: Vec<u32> = (p..n).step_by(s).map(|i| i as u32).collect();
        let w = 1.0 / members.len().max(1) as f32;
        emit.push_row(members.into_iter().map(|i| (i, w)));
    }
    crate::model::bounce::Transport { gather, emit: Some(emit) }
}

/// Makes `rows`' data the radiance of `truth` (its visibility traced on the CPU): each value
/// the middle of an interval `rel` of it wide on each side, nothing censored.
pub fn data_from_model(rows: &mut crate::rows::Rows, bases: &crate::model::Bases, bvh: &crate::trace::bvh::Bvh, truth: &crate::model::Model, rel: f32) {
    let (lo, hi) = (Vec3::splat(-1e3), Vec3::splat(1e3));
    let x = {
        let mut cpu = crate::backend::Cpu::new(rows, bvh);
        let mut fit = crate::fit::Fitter::new(rows, bases, bvh, &mut cpu, lo, hi);
        fit.model = truth.clone();
        fit.refresh_visibility();
        crate::model::radiance(&fit.model, rows, bases, &fit.vis, &mut crate::backend::Cpu::new(rows, bvh)).expect("the CPU backend does not fail")
    };
    for (i, xi) in x.iter().enumerate() {
        rows.lo[i] = xi.map(|v| v as f32 * (1.0 - rel));
        rows.hi[i] = xi.map(|v| v as f32 * (1.0 + rel));
        rows.weight[i] = [1.0; 3];
        rows.lower[i] = [0.0; 3];
    }
    rows.finish();
}

/// q3map2's casters of `mesh`'s triangles in Quake units (glTF (x, y, z) = Quake (x, z, -y)
/// * [`DEFAULT_SCALE`](q3gltf_convert::units::DEFAULT_SCALE)), over a tree of two planes
/// through the room: `x = a`, then `z = b` on its front side (Quake units).
pub fn casters_of(mesh: &Mesh, a: f64, b: f64) -> crate::casters::Casters {
    let s = q3gltf_convert::units::DEFAULT_SCALE;
    let mut c = crate::casters::Casters {
        planes: vec![(glam::DVec3::X, a), (glam::DVec3::Z, b)],
        nodes: vec![(0, [1, -1]), (1, [-2, -3])],
        leaf_solid: vec![false; 3],
        ..Default::default()
    };
    c.vertices = mesh.positions.iter().map(|p| glam::DVec3::new(p.x as f64, -p.z as f64, p.y as f64) / s).collect();
    c.triangles = mesh.triangles.iter().map(|t| [t[0], t[1], t[2], 0]).collect();
    c
}
