//! The optimisers' parameter vector: every model parameter in a form the optimisers can
//! move freely.
//!
//! Per light: position `q` in units of `unit` meters around the scene centre, log
//! intensity `s`, log colour `g_c` (`I_c = exp(s + g_c)`, positive by construction); a
//! spot adds its axis as elevation and azimuth (radians, glTF's Y up) and its log cone
//! `ln(radius / distance)`. Then, for the terms in the model: the sun (elevation, azimuth,
//! log irradiance, log colour), the sky, each surface group and the ambient as
//! logarithms per channel, the bounce and the gathered bounce as logits of a value in
//! (0, 1], the minlight as a logarithm.

use glam::{DVec3, Vec3};

use crate::model::{Eval, Light, Model, Spot, Sun};

/// `(theta, phi)` of a unit direction: elevation above the horizontal and azimuth from +X
/// towards +Z (glTF axes).
pub fn angles(w: Vec3) -> (f64, f64) {
    let w = w.as_dvec3().normalize_or(DVec3::Y);
    (w.y.clamp(-1.0, 1.0).asin(), w.z.atan2(w.x))
}

/// The direction of `(theta, phi)` and its derivatives by theta and by phi.
pub fn direction(theta: f64, phi: f64) -> (Vec3, DVec3, DVec3) {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    (DVec3::new(ct * cp, st, ct * sp).as_vec3(), DVec3::new(-st * cp, ct, -st * sp), DVec3::new(-ct * sp, 0.0, ct * cp))
}

/// Which parameters a phase moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct ParamSet {
    pub position: bool,
    pub intensity: bool,
    pub color: bool,
}

impl ParamSet {
    pub const ALL: ParamSet = ParamSet { position: true, intensity: true, color: true };
    pub const POSITION: ParamSet = ParamSet { position: true, intensity: false, color: false };
    pub const INTENSITY_COLOR: ParamSet = ParamSet { position: false, intensity: true, color: true };
    pub fn label(&self) -> String {
        let mut v = Vec::new();
        if self.position {
            v.push("position");
        }
        if self.intensity {
            v.push("intensity");
        }
        if self.color {
            v.push("color");
        }
        v.join("+")
    }
}

/// Encoding of a model with a given layout (lights and their kinds, terms present).
#[derive(Debug, Clone, Copy)]
pub struct Codec {
    pub center: Vec3,
    /// Position unit, m.
    pub unit: f32,
}

fn ln_rgb(rgb: [f32; 3]) -> [f64; 4] {
    let m = rgb.iter().copied().fold(0.0f32, f32::max).max(1e-12);
    let c = rgb.map(|v| ((v / m).max(1e-9) as f64).ln());
    [(m as f64).ln(), c[0], c[1], c[2]]
}

fn exp_rgb(p: &[f64]) -> [f32; 3] {
    [0, 1, 2].map(|c| (p[0] + p[1 + c]).clamp(-80.0, 80.0).exp() as f32)
}

/// Upper bound of the bounce scale ([`crate::model::bounce::MAX_SCALE`]).
const BOUNCE_MAX: f64 = crate::model::bounce::MAX_SCALE as f64;

fn logit(k: f64) -> f64 {
    let p = k.clamp(1e-6, 1.0 - 1e-6);
    (p / (1.0 - p)).ln()
}

fn logistic(v: f64) -> f64 {
    1.0 / (1.0 + (-v.clamp(-80.0, 80.0)).exp())
}

/// Reads a parameter vector front to back.
struct Reader<'a> {
    x: &'a [f64],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> &'a [f64] {
        let s = &self.x[self.at..self.at + n];
        self.at += n;
        s
    }
    fn exp3(&mut self) -> [f32; 3] {
        let p = self.take(3);
        [0, 1, 2].map(|c| p[c].clamp(-80.0, 80.0).exp() as f32)
    }
    fn logistic3(&mut self) -> [f32; 3] {
        let p = self.take(3);
        [0, 1, 2].map(|c| logistic(p[c]) as f32)
    }
}

impl Codec {
    pub fn encode(&self, m: &Model) -> Vec<f64> {
        let mut x = Vec::new();
        for l in &m.lights {
            let q = (l.pos - self.center) / self.unit;
            x.extend([q.x as f64, q.y as f64, q.z as f64]);
            x.extend(ln_rgb(l.rgb));
            if let Some(s) = &l.spot {
                let (t, p) = angles(s.axis);
                x.extend([t, p, (s.radius_by_dist.max(1e-6) as f64).ln()]);
            }
        }
        if let Some(s) = &m.sun {
            let (t, p) = angles(s.to_sun);
            x.extend([t, p]);
            x.extend(ln_rgb(s.rgb));
        }
        for v in [m.sky].iter().flatten().chain(m.surfaces.iter().flatten()).chain(m.ambient.iter()) {
            x.extend(v.map(|c| (c.max(1e-12) as f64).ln()));
        }
        for v in m.bounce.iter() {
            x.extend(v.map(|c| logit(c as f64 / BOUNCE_MAX)));
        }
        for v in m.minlight.iter() {
            x.extend(v.map(|c| (c.max(1e-12) as f64).ln()));
        }
        for v in m.gathered.iter() {
            x.extend(v.map(|c| logit(c as f64)));
        }
        x
    }

    /// The model of `x`, with `like`'s layout (and its switches: dirt, filter).
    pub fn decode(&self, like: &Model, x: &[f64]) -> Model {
        let mut r = Reader { x, at: 0 };
        let mut lights = Vec::with_capacity(like.lights.len());
        for l in &like.lights {
            let p = r.take(7);
            let pos = self.center + Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) * self.unit;
            let rgb = exp_rgb(&p[3..7]);
            let spot = l.spot.map(|_| {
                let s = r.take(3);
                Spot { axis: direction(s[0], s[1]).0, radius_by_dist: s[2].clamp(-20.0, 20.0).exp() as f32 }
            });
            lights.push(Light { pos, rgb, spot });
        }
        let sun = like.sun.map(|_| {
            let p = r.take(6);
            Sun { to_sun: direction(p[0], p[1]).0, rgb: exp_rgb(&p[2..6]) }
        });
        let sky = like.sky.map(|_| r.exp3());
        let surfaces: Vec<Option<[f32; 3]>> = like.surfaces.iter().map(|s| s.map(|_| r.exp3())).collect();
        let ambient = like.ambient.map(|_| r.exp3());
        let bounce = like.bounce.map(|_| r.logistic3().map(|k| k * BOUNCE_MAX as f32));
        let minlight = like.minlight.map(|_| r.exp3());
        let gathered = like.gathered.map(|_| r.logistic3());
        Model { lights, sun, sky, surfaces, ambient, bounce, minlight, gathered, dirt: like.dirt, filter: like.filter }
    }

    /// The gradient with respect to `x` from the model's gradient `ev` at `m` (the model
    /// of `x`), plus the lights' penalty gradients (per meter).
    pub fn gradient(&self, m: &Model, x: &[f64], ev: &Eval, penalty: &[Vec3]) -> Vec<f64> {
        let mut g = Vec::with_capacity(x.len());
        for (j, l) in m.lights.iter().enumerate() {
            let lg = &ev.lights[j];
            for a in 0..3 {
                g.push((lg.pos[a] + penalty.get(j).map_or(0.0, |p| p[a] as f64)) * self.unit as f64);
            }
            let mut gs = 0.0;
            let start = g.len();
            g.push(0.0);
            for c in 0..3 {
                let d = lg.rgb[c] * l.rgb[c] as f64;
                gs += d;
                g.push(d);
            }
            g[start] = gs;
            if let Some(s) = &l.spot {
                let o = g.len();
                let (_, dt, dp) = direction(x[o], x[o + 1]);
                let ga = DVec3::from_array(lg.axis);
                g.extend([ga.dot(dt), ga.dot(dp), lg.radius_by_dist * s.radius_by_dist as f64]);
            }
        }
        if let Some(s) = &m.sun {
            let o = g.len();
            let (_, dt, dp) = direction(x[o], x[o + 1]);
            let gw = DVec3::from_array(ev.sun.0);
            g.extend([gw.dot(dt), gw.dot(dp)]);
            let mut gs = 0.0;
            let start = g.len();
            g.push(0.0);
            for c in 0..3 {
                let d = ev.sun.1[c] * s.rgb[c] as f64;
                gs += d;
                g.push(d);
            }
            g[start] = gs;
        }
        let mut log3 = |v: &[f32; 3], d: &[f64; 3]| g.extend((0..3).map(|c| d[c] * v[c] as f64));
        if let Some(v) = &m.sky {
            log3(v, &ev.sky);
        }
        for (s, v) in m.surfaces.iter().enumerate() {
            if let Some(v) = v {
                log3(v, &ev.surfaces[s]);
            }
        }
        if let Some(v) = &m.ambient {
            log3(v, &ev.ambient);
        }
        if let Some(k) = &m.bounce {
            g.extend((0..3).map(|c| ev.bounce[c] * k[c] as f64 * (1.0 - k[c] as f64 / BOUNCE_MAX)));
        }
        if let Some(v) = &m.minlight {
            g.extend((0..3).map(|c| ev.minlight[c] * v[c] as f64));
        }
        if let Some(k) = &m.gathered {
            g.extend((0..3).map(|c| ev.gathered[c] * k[c] as f64 * (1.0 - k[c] as f64)));
        }
        debug_assert_eq!(g.len(), x.len());
        g
    }

    /// Which entries of `x` a phase moves: lights' by `set` (none for locked ones), the
    /// spot's axis and cone with positions, the global terms' with intensities; never the
    /// sun's direction (its search moves it).
    /// `frozen_emitters` keeps the sun, the sky and the surface lights, `frozen_minlight`
    /// the minlight.
    pub fn mask(&self, m: &Model, locked: &[bool], set: ParamSet, frozen_emitters: bool, frozen_minlight: bool) -> Vec<bool> {
        let mut k = Vec::new();
        for (j, l) in m.lights.iter().enumerate() {
            let free = !locked.get(j).copied().unwrap_or(false);
            k.extend([set.position && free; 3]);
            k.push(set.intensity && free);
            k.extend([set.color && free; 3]);
            if l.spot.is_some() {
                k.extend([set.position && free; 3]);
            }
        }
        let emit = set.intensity && !frozen_emitters;
        if m.sun.is_some() {
            k.extend([false; 2]);
            k.push(emit);
            k.extend([set.color && !frozen_emitters; 3]);
        }
        let emitters = m.sky.is_some() as usize + m.surfaces.iter().flatten().count();
        k.extend(std::iter::repeat_n(emit, 3 * emitters));
        k.extend(std::iter::repeat_n(set.intensity, 3 * (m.ambient.is_some() as usize + m.bounce.is_some() as usize)));
        k.extend(std::iter::repeat_n(set.intensity && !frozen_minlight, 3 * m.minlight.is_some() as usize));
        k.extend(std::iter::repeat_n(set.intensity, 3 * m.gathered.is_some() as usize));
        k
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encode_then_decode_is_the_identity() {
        let c = Codec { center: Vec3::new(1.0, 2.0, 3.0), unit: 0.5 };
        let m = Model {
            lights: vec![
                Light::point(Vec3::new(0.5, 1.0, -2.0), [2.0, 1.0, 0.5]),
                Light { pos: Vec3::new(3.0, 1.0, 0.0), rgb: [0.1, 0.2, 0.3], spot: Some(Spot { axis: Vec3::new(0.0, -1.0, 0.2).normalize(), radius_by_dist: 0.7 }) },
            ],
            sun: Some(Sun { to_sun: Vec3::new(0.2, 0.9, 0.1).normalize(), rgb: [3.0, 2.0, 1.0] }),
            sky: Some([0.5, 0.6, 0.7]),
            surfaces: vec![Some([1.0, 2.0, 3.0]), None, Some([0.1, 0.1, 0.2])],
            ambient: Some([0.01, 0.02, 0.03]),
            bounce: Some([0.9, 0.5, 0.25]),
            minlight: Some([0.2, 0.2, 0.3]),
            gathered: Some([0.3, 0.4, 0.5]),
            dirt: Some(crate::scene::DirtSettings::Q3MAP2),
            filter: false,
        };
        let x = c.encode(&m);
        let back = c.decode(&m, &x);
        assert_eq!(c.mask(&m, &[false, true], ParamSet::ALL, false, false).len(), x.len());
        let close = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(p, q)| (p - q).abs() <= 1e-5 * p.abs().max(1.0));
        for (a, b) in m.lights.iter().zip(&back.lights) {
            assert!(close(&a.pos.to_array(), &b.pos.to_array()) && close(&a.rgb, &b.rgb));
            assert_eq!(a.spot.is_some(), b.spot.is_some());
            if let (Some(s), Some(t)) = (a.spot, b.spot) {
                assert!(close(&s.axis.to_array(), &t.axis.to_array()) && (s.radius_by_dist - t.radius_by_dist).abs() < 1e-5);
            }
        }
        assert!(close(&m.sun.unwrap().to_sun.to_array(), &back.sun.unwrap().to_sun.to_array()));
        assert_eq!(back.surfaces[1], None);
        assert!(close(&m.surfaces[2].unwrap(), &back.surfaces[2].unwrap()));
        assert!(close(&m.bounce.unwrap(), &back.bounce.unwrap()));
        assert!(close(&m.minlight.unwrap(), &back.minlight.unwrap()));
        assert!(back.dirt.is_some() && !back.filter);
    }
}
