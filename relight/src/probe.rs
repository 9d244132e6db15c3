//! The lights a file already has, at one point: what a physically based renderer should
//! show there. Pins the chain of units against other renderers (Cycles, in the Blender
//! tests) and helps inspect a relit scene.
//!
//! For a surface point `x` [m, world] with unit normal `n`, with physical sampling (no
//! q3map2 clamp or cut) and shadow rays through the file's own geometry:
//!
//! - a point light (candela -> `I = cd / 683` W/sr per channel) adds `I max(0, n.d) /
//!   |d|^3`;
//! - a spot light adds the same times its cone: 1 inside `innerConeAngle`, 0 outside
//!   `outerConeAngle`, linear in the angle between (inside the inner cone, as the units
//!   checks use it, every renderer agrees);
//! - a directional light (lux -> `S = lux / 683` W/m^2) adds `S max(0, n.w)` where a ray
//!   towards it escapes;
//! - an emissive material of radiance `L` (`emissiveFactor x emissiveStrength`) adds
//!   `pi L F` per triangle, `F` its form factor seen from `x` (unoccluded; seen from
//!   behind, only a double-sided material's triangle adds, `pi L |F|`).
//!
//! A white Lambertian surface there has radiance `E / pi` [W/(m^2 sr)].

use glam::{DVec3, Vec3};

use crate::error::{Error, Result};
use crate::io::gltf_in;
use crate::io::lights_out::LM_PER_W;
use crate::model::lights::{geometry, Light};
use crate::rows::Sampling;
use crate::trace::bvh::Bvh;
use crate::trace::visibility::{sun_visible_from, visible_from};

#[derive(Debug, Clone, serde::Serialize)]
pub struct Probe {
    /// World position, m.
    pub point: [f64; 3],
    pub normal: [f64; 3],
    /// Irradiance per channel, W/m^2.
    pub irradiance: [f64; 3],
    /// Of which from emissive materials.
    pub irradiance_emissive: [f64; 3],
    /// Radiance of a white Lambertian surface, `irradiance / pi`, W/(m^2 sr).
    pub radiance_white: [f64; 3],
    /// Point and spot lights in the file.
    pub lights: usize,
    /// Of those, how many reach the point (in front of it and not shadowed).
    pub lights_visible: usize,
    pub suns: usize,
    pub emissive_triangles: usize,
}

/// The cone factor of a glTF spot with half-angles `inner`, `outer` (radians).
fn gltf_cone(x: Vec3, l: &Light, inner: f32, outer: f32) -> f32 {
    let Some(s) = l.spot else { return 1.0 };
    let d = (x - l.pos).normalize_or_zero();
    let angle = d.dot(s.axis).clamp(-1.0, 1.0).acos();
    if angle <= inner {
        1.0
    } else if angle >= outer {
        0.0
    } else {
        (outer - angle) / (outer - inner).max(1e-6)
    }
}

/// Evaluates the file's lights at `point` (world, m) facing `normal`.
pub fn probe(input: &std::path::Path, point: DVec3, normal: DVec3) -> Result<Probe> {
    let n = normal.try_normalize().ok_or_else(|| Error::Usage("--normal must be a non-zero vector".into()))?.as_vec3();
    if !point.is_finite() {
        return Err(Error::Usage("--at must be finite".into()));
    }
    let scene = gltf_in::read(input)?;
    let x: Vec3 = (point - scene.origin).as_vec3();
    let (lo, hi) = scene.mesh.bounds();
    let diag = if scene.mesh.positions.is_empty() { 1.0 } else { (hi - lo).length() };
    let s = Sampling::plain(diag);
    let bvh = Bvh::occluders(&scene);
    let mut e = [0.0f64; 3];
    let mut visible = 0;
    for l in &scene.lights {
        if !visible_from(&bvh, x, n, l.position, &s) {
            continue;
        }
        let light = Light { pos: l.position, rgb: [1.0; 3], spot: l.spot.map(|(axis, radius_by_dist)| crate::model::Spot { axis, radius_by_dist }) };
        let (inner, outer) = l.cone.unwrap_or((std::f32::consts::PI, std::f32::consts::PI));
        let g = geometry(x, n, l.position, s.eps).0 * gltf_cone(x, &light, inner, outer);
        if g > 0.0 {
            visible += 1;
        }
        let i = l.intensity_cd as f64 / LM_PER_W;
        for c in 0..3 {
            e[c] += l.color[c] as f64 * i * g as f64;
        }
    }
    let sky: Vec<bool> = scene.mesh.tri_material.iter().map(|&m| scene.materials[m as usize].sky).collect();
    for sun in &scene.suns {
        if sun_visible_from(&bvh, x, n, sun.to_sun, &s, &sky, crate::rows::SolidAhead::NONE) {
            let c = n.dot(sun.to_sun).max(0.0) as f64;
            for k in 0..3 {
                e[k] += sun.color[k] as f64 * sun.intensity_lux as f64 / LM_PER_W * c;
            }
        }
    }
    let mut em = [0.0f64; 3];
    let mut tris = 0;
    for (t, tri) in scene.mesh.triangles.iter().enumerate() {
        let mat = &scene.materials[scene.mesh.tri_material[t] as usize];
        let l = mat.emission;
        if l == [0.0; 3] {
            continue;
        }
        tris += 1;
        // Quake winding (the form factor's convention): each glTF triangle reversed. A
        // double-sided material emits from its back as well (as relight's surface lights).
        let w = [tri[2], tri[1], tri[0]].map(|v| scene.mesh.positions[v as usize]);
        let f = crate::model::area::form_factor(x, n, &w);
        let f = if mat.double_sided { f.abs() } else { f.max(0.0) } as f64;
        for c in 0..3 {
            em[c] += std::f64::consts::PI * l[c] as f64 * f;
        }
    }
    for c in 0..3 {
        e[c] += em[c];
    }
    Ok(Probe {
        point: point.to_array(),
        normal: n.as_dvec3().to_array(),
        irradiance: e,
        irradiance_emissive: em,
        radiance_white: e.map(|v| v / std::f64::consts::PI),
        lights: scene.lights.len(),
        lights_visible: visible,
        suns: scene.suns.len(),
        emissive_triangles: tris,
    })
}
