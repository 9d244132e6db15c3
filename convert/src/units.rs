//! Units, axes and the radiometric convention (see CONVENTIONS.md).
//!
//! * Quake units are inches; glTF uses meters: `meters = units * scale`, default
//!   [`DEFAULT_SCALE`] = 0.0254.
//! * Quake is Z up, glTF Y up (both right-handed): `(x, y, z)q3 -> (x, z, -y)gltf`.
//!   This is a rotation, so it keeps handedness; the winding flip from Quake's
//!   clockwise fronts to glTF's counter-clockwise fronts is done on the indices.
//! * Lightmap bytes are linear: `e = byte * 2^overbright / 255` is irradiance / pi.

use std::f64::consts::PI;

/// Meters per Quake unit.
pub const DEFAULT_SCALE: f64 = 0.0254;
/// The engine's default `r_mapOverBrightBits`.
pub const DEFAULT_OVERBRIGHT_BITS: u32 = 2;
/// Luminous efficacy used by KHR_lights_punctual conversions: lumens per watt.
pub const LM_PER_W: f64 = 683.0;
/// q3map2's point light constant: `byte = light * 7500 * cos / d^2`.
pub const Q3MAP2_POINT_SCALE: f64 = 7500.0;

/// Converts a Quake position (units) to glTF (meters, Y up).
pub fn position(p: [f32; 3], scale: f64) -> [f32; 3] {
    [(p[0] as f64 * scale) as f32, (p[2] as f64 * scale) as f32, (-(p[1] as f64) * scale) as f32]
}

/// Converts a Quake direction to glTF axes (no scaling).
pub fn direction(d: [f64; 3]) -> [f64; 3] {
    [d[0], d[2], -d[1]]
}

/// Irradiance over pi (`e`) per lightmap byte.
pub fn e_per_byte(overbright_bits: u32) -> f64 {
    (1u64 << overbright_bits.min(16)) as f64 / 255.0
}

/// Radiant intensity [W/sr] of a q3map2 inverse-square point light with key `light`.
///
/// `byte = light * 7500 * cos / d_units^2`, `E = pi * e_per_byte * byte` [W/m2] and
/// `E = I cos / d_m^2` with `d_m = d_units * scale` give
/// `I = pi * e_per_byte * 7500 * scale^2 * light`.
pub fn q3map2_point_intensity_w_per_sr(light: f64, scale: f64, overbright_bits: u32) -> f64 {
    PI * e_per_byte(overbright_bits) * Q3MAP2_POINT_SCALE * scale * scale * light
}

/// The same light in candela, as KHR_lights_punctual wants it.
pub fn q3map2_point_candela(light: f64, scale: f64, overbright_bits: u32) -> f64 {
    LM_PER_W * q3map2_point_intensity_w_per_sr(light, scale, overbright_bits)
}

/// Illuminance [lux] of a q3map2 sun at normal incidence: `byte = intensity * cos`.
pub fn q3map2_sun_lux(intensity: f64, overbright_bits: u32) -> f64 {
    LM_PER_W * PI * e_per_byte(overbright_bits) * intensity
}

/// q3map2's area-light scale for surface lights: `formFactorValueScale (3) x areaScale
/// (0.25)`: a surface light of value `V` filling a sample's hemisphere adds `0.75 V`
/// bytes.
pub const Q3MAP2_SURFACE_SCALE: f64 = 0.75;

/// Radiance [W/(m^2 sr)] of a q3map2 surface light of value `V`: a Lambertian emitter of
/// radiance `L` seen over a form factor `F` gives `E = pi L F`, i.e. `e = L F` and
/// `byte = L F / e_per_byte`; q3map2 adds `0.75 V F` bytes.
pub fn q3map2_surface_radiance(value: f64, overbright_bits: u32) -> f64 {
    Q3MAP2_SURFACE_SCALE * value * e_per_byte(overbright_bits)
}

/// q3map2's sky light (`q3map_skyLight value iterations`, horizon 0 to 90 degrees): a set
/// of suns, unit directions towards each in Quake axes; each adds `value / count` bytes
/// times its cosine where the sky is visible (q3map2's `CreateSkyLights`).
pub fn q3map2_sky_suns(iterations: u32) -> Vec<[f64; 3]> {
    let iterations = iterations.clamp(2, 1024);
    let angle_steps = (iterations - 1) * 4;
    let ele_step = 90.0 / iterations as f64;
    let ele_min = ele_step * 0.5;
    let ele_max = 90.0 - ele_step * 1.5;
    let elevation_steps = (1.0 + ((ele_max - ele_min) / ele_step).max(0.0)) as u32;
    let angle_step = (360.0 / angle_steps as f64).to_radians();
    let mut out = Vec::with_capacity((angle_steps * elevation_steps + 1) as usize);
    let mut elevation = ele_min.to_radians();
    let mut angle = 0.0f64;
    for _ in 0..elevation_steps {
        for _ in 0..angle_steps {
            out.push([angle.cos() * elevation.cos(), angle.sin() * elevation.cos(), elevation.sin()]);
            angle += angle_step;
        }
        elevation += ele_step.to_radians();
        angle += angle_step / elevation_steps as f64;
    }
    out.push([0.0, 0.0, 1.0]);
    out
}

/// Radiance [W/(m^2 sr)] of a uniform sky that gives an open, upward-facing surface the
/// irradiance of a q3map2 sky light (`value / count * sum of the suns' cosines` bytes).
pub fn q3map2_sky_radiance(value: f64, iterations: u32, overbright_bits: u32) -> f64 {
    let suns = q3map2_sky_suns(iterations);
    let mean_cos = suns.iter().map(|d| d[2]).sum::<f64>() / suns.len() as f64;
    value * mean_cos * e_per_byte(overbright_bits)
}

/// Unit quaternion (x, y, z, w) rotating -Z onto `dir` (glTF lights shine along -Z).
pub fn quat_from_neg_z(dir: [f64; 3]) -> [f32; 4] {
    let len = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
    if !(len > 1e-12) {
        return [0.0, 0.0, 0.0, 1.0];
    }
    let d = [dir[0] / len, dir[1] / len, dir[2] / len];
    let from = [0.0, 0.0, -1.0];
    let dot = -d[2];
    if dot < -1.0 + 1e-9 {
        // Opposite: half turn about X.
        return [1.0, 0.0, 0.0, 0.0];
    }
    // q = (from x to, 1 + from.to), normalised.
    let c = [from[1] * d[2] - from[2] * d[1], from[2] * d[0] - from[0] * d[2], from[0] * d[1] - from[1] * d[0]];
    let w = 1.0 + dot;
    let n = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2] + w * w).sqrt();
    [(c[0] / n) as f32, (c[1] / n) as f32, (c[2] / n) as f32, (w / n) as f32]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conventions_factor() {
        // CONVENTIONS.md: light = L corresponds to about I = 0.2385 L W/sr, 163 L cd.
        let i = q3map2_point_intensity_w_per_sr(1.0, DEFAULT_SCALE, 2);
        assert!((i - 0.2385).abs() < 5e-4, "{i}");
        assert!((q3map2_point_candela(1.0, DEFAULT_SCALE, 2) - 163.0).abs() < 0.5);
    }

    #[test]
    fn sky_suns_follow_q3map2() {
        // q3map_skyLight 180 8: 28 azimuths x 7 elevations + the zenith.
        let s = q3map2_sky_suns(8);
        assert_eq!(s.len(), 197);
        assert!(s.iter().all(|d| ((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 1.0).abs() < 1e-12 && d[2] > 0.0));
        assert!((s[0][2] - 5.625f64.to_radians().sin()).abs() < 1e-12);
        // A surface light filling the hemisphere: 0.75 V bytes, i.e. radiance 0.75 V e/byte.
        assert!((q3map2_surface_radiance(1000.0, 2) - 0.75 * 1000.0 * 4.0 / 255.0).abs() < 1e-9);
    }

    #[test]
    fn axes_are_a_rotation() {
        assert_eq!(position([1.0, 2.0, 3.0], 1.0), [1.0, 3.0, -2.0]);
        let q = quat_from_neg_z([0.0, -1.0, 0.0]);
        // Rotating (0, 0, -1) by q gives (0, -1, 0).
        let v = glam::Quat::from_array(q) * glam::Vec3::new(0.0, 0.0, -1.0);
        assert!((v - glam::Vec3::new(0.0, -1.0, 0.0)).length() < 1e-6);
    }
}
