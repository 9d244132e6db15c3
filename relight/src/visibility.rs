//! Shadow-ray visibility of every light from every problem vertex, one bit per pair,
//! cached between iterations: a light is re-traced only when it moved more than a
//! tolerance since its last trace (colour and intensity phases never re-trace).
//!
//! A bit is set when the light is in front of the vertex (`n . d > 0`) and the segment
//! from `x + n * ray_offset` to the light hits no triangle.

use glam::Vec3;
use rayon::prelude::*;

use crate::bvh::Bvh;
use crate::model::{Light, Problem};


#[derive(Debug, Clone, Default)]
pub struct Visibility {
    /// Bits per light, `words_per_light` u32 words each.
    pub bits: Vec<Vec<u32>>,
    /// Light position at its last trace.
    pub traced_at: Vec<Vec3>,
    /// The sun's bits and the direction they were traced for (see [`sun_visible_from`]).
    pub sun: Option<(Vec3, Vec<u32>)>,
    /// Rays traced so far (all lights, all updates).
    pub rays: u64,
}

impl Visibility {
    #[inline]
    pub fn visible(&self, light: usize, vertex: usize) -> bool {
        self.bits[light][vertex >> 5] >> (vertex & 31) & 1 == 1
    }

    /// Whether the sun (as last traced) reaches `vertex`.
    #[inline]
    pub fn sun_visible(&self, vertex: usize) -> bool {
        self.sun.as_ref().is_some_and(|(_, b)| b[vertex >> 5] >> (vertex & 31) & 1 == 1)
    }

    /// Brings the sun's bits up to date: re-traced (with `trace`) when the direction turned
    /// by more than `tolerance` radians since the last trace; dropped without a sun.
    pub fn update_sun(&mut self, to_sun: Option<Vec3>, tolerance: f32, n_vertices: usize, trace: &mut dyn FnMut(Vec3) -> Vec<u32>) {
        let Some(dir) = to_sun else {
            self.sun = None;
            return;
        };
        let fresh = self.sun.as_ref().is_some_and(|(d, _)| d.dot(dir).clamp(-1.0, 1.0).acos() <= tolerance);
        if !fresh {
            self.sun = Some((dir, trace(dir)));
            self.rays += n_vertices as u64;
        }
    }

    /// Brings the cache up to date with `lights`: traces (with `trace`, a batch of light
    /// positions to bit vectors) new lights and lights that moved more than `tolerance`
    /// meters; drops lights beyond `lights.len()`. Returns how many lights were traced.
    pub fn update(&mut self, lights: &[Light], tolerance: f32, n_vertices: usize, trace: &mut dyn FnMut(&[Vec3]) -> crate::error::Result<Vec<Vec<u32>>>) -> crate::error::Result<usize> {
        self.bits.truncate(lights.len());
        self.traced_at.truncate(lights.len());
        let stale: Vec<usize> = (0..lights.len()).filter(|&j| j >= self.bits.len() || (self.traced_at[j] - lights[j].pos).length() > tolerance).collect();
        if stale.is_empty() {
            return Ok(0);
        }
        let positions: Vec<Vec3> = stale.iter().map(|&j| lights[j].pos).collect();
        let traced = trace(&positions)?;
        self.rays += (n_vertices * stale.len()) as u64;
        for (&j, words) in stale.iter().zip(traced) {
            if j < self.bits.len() {
                self.bits[j] = words;
                self.traced_at[j] = lights[j].pos;
            } else {
                self.bits.push(words);
                self.traced_at.push(lights[j].pos);
            }
        }
        Ok(stale.len())
    }

    /// Replaces the cache of light `j` (used when lights are reordered or removed).
    pub fn remove(&mut self, j: usize) {
        self.bits.remove(j);
        self.traced_at.remove(j);
    }
}

/// Sun visibility: the sun (direction `to_sun`, unit) is in front of the vertex and the
/// ray from `x + n * offset` towards it escapes the scene or first meets a sky surface
/// (`sky[t]` for mesh triangle `t`).
pub fn sun_visible_from(bvh: &Bvh, x: Vec3, n: Vec3, to_sun: Vec3, offset: f32, sky: &[bool]) -> bool {
    if !(n.dot(to_sun) > 0.0) {
        return false;
    }
    match bvh.first_hit(x + n * offset, to_sun * bvh.reach(), 1.0) {
        None => true,
        Some((_, t)) => sky.get(t as usize).copied().unwrap_or(false),
    }
}

/// Sun visibility bits of every problem row (rayon, 32 per task).
pub fn trace_sun(bvh: &Bvh, pb: &Problem, to_sun: Vec3, sky: &[bool]) -> Vec<u32> {
    let n = pb.len();
    (0..n.div_ceil(32))
        .into_par_iter()
        .map(|w| {
            let mut word = 0u32;
            for b in 0..32.min(n - w * 32) {
                let i = w * 32 + b;
                if sun_visible_from(bvh, pb.pos[i], pb.normal[i], to_sun, pb.ray_offset, sky) {
                    word |= 1 << b;
                }
            }
            word
        })
        .collect()
}

/// Visibility bits of one light position from every problem vertex (rayon, 32 per task).
pub fn trace_light(bvh: &Bvh, pb: &Problem, light: Vec3) -> Vec<u32> {
    let n = pb.len();
    (0..n.div_ceil(32))
        .into_par_iter()
        .map(|w| {
            let mut word = 0u32;
            for b in 0..32 {
                let i = w * 32 + b;
                if i >= n {
                    break;
                }
                if visible_from(bvh, pb.pos[i], pb.normal[i], light, pb.ray_offset) {
                    word |= 1 << b;
                }
            }
            word
        })
        .collect()
}

/// One shadow ray (the CPU reference of the WGSL `visible_from`).
pub fn visible_from(bvh: &Bvh, x: Vec3, n: Vec3, light: Vec3, offset: f32) -> bool {
    if n.dot(light - x) <= 0.0 {
        return false;
    }
    let o = x + n * offset;
    let d = light - o;
    let len = d.length();
    if !(len > offset) {
        // The light touches the surface: lit, nothing can be in between.
        return len.is_finite();
    }
    !bvh.occluded(o, d, 1.0 - offset / len)
}
