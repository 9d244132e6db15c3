//! The forward model at one point, for the lights a file already has: what relight
//! predicts a renderer should show there. Used to pin the chain of units against other
//! renderers (Cycles in the Blender tests) and to inspect a relit scene.
//!
//! For a surface point `x` [m, world] with unit normal `n`, every point light of the file
//! (KHR_lights_punctual, candela -> `I = cd / 683` W/sr per channel) contributes
//! `E = I max(0, n.d) / |d|^3` [W/m^2] where a shadow ray through the file's own geometry
//! reaches it (the same `model::geometry_term` and `visibility::visible_from` as the fit).
//! A white Lambertian surface there has radiance `E / pi` [W/(m^2 sr)].

use glam::{DVec3, Vec3};

use crate::bvh::Bvh;
use crate::error::{Error, Result};
use crate::gltf_in;
use crate::lights_out::LM_PER_W;
use crate::model::{geometry_term, Problem};
use crate::visibility::visible_from;

#[derive(Debug, Clone, serde::Serialize)]
pub struct Probe {
    /// World position, m.
    pub point: [f64; 3],
    pub normal: [f64; 3],
    /// Irradiance per channel, W/m^2.
    pub irradiance: [f64; 3],
    /// Radiance of a white Lambertian surface, `irradiance / pi`, W/(m^2 sr).
    pub radiance_white: [f64; 3],
    /// Point lights in the file.
    pub lights: usize,
    /// Of those, how many reach the point (in front of it and not shadowed).
    pub lights_visible: usize,
}

/// Evaluates the model at `point` (world, m) facing `normal` for the point lights of `input`.
pub fn probe(input: &std::path::Path, point: DVec3, normal: DVec3) -> Result<Probe> {
    let n = normal.try_normalize().ok_or_else(|| Error::Usage("--normal must be a non-zero vector".into()))?.as_vec3();
    if !point.is_finite() {
        return Err(Error::Usage("--at must be finite".into()));
    }
    let scene = gltf_in::read(input)?;
    let x: Vec3 = (point - scene.origin).as_vec3();
    let (lo, hi) = scene.mesh.bounds();
    let diag = if scene.mesh.positions.is_empty() { 1.0 } else { (hi - lo).length() };
    // The fit's eps and ray offset for this scene.
    let pb = Problem::empty(diag);
    let bvh = Bvh::build(&scene.mesh);
    let mut e = [0.0f64; 3];
    let mut visible = 0;
    for l in &scene.lights {
        if !visible_from(&bvh, x, n, l.position, pb.ray_offset) {
            continue;
        }
        let (g, _) = geometry_term(x, n, l.position, pb.eps);
        if g > 0.0 {
            visible += 1;
        }
        let i = l.intensity_cd as f64 / LM_PER_W;
        for c in 0..3 {
            e[c] += l.color[c] as f64 * i * g as f64;
        }
    }
    Ok(Probe {
        point: point.to_array(),
        normal: n.as_dvec3().to_array(),
        irradiance: e,
        radiance_white: e.map(|v| v / std::f64::consts::PI),
        lights: scene.lights.len(),
        lights_visible: visible,
    })
}
