//! The sun: a directional light (q3map2's `q3map_sun`, written as a KHR directional
//! light in lux).
//!
//! Irradiance at normal incidence `S_c` [W/m^2] from the unit direction `w` towards the
//! sun: `E_ic = S_c V_i max(0, n_i . w)`, where `V_i` says whether a ray from the sample
//! towards the sun escapes the scene or first meets a sky surface
//! ([`crate::trace::visibility::trace_sun`]). q3map2 adds `intensity x cos` bytes, so a
//! `q3map_sun` of intensity `q` is `S = pi e_per_byte q`.
//!
//! A two-sided row's `n_i` is turned towards the sun ([`Rows::facing`]).
//!
//! Gradients: `dF/dS_c = sum_i rho_ic V_i cos_i` and `dF/dw = sum_i (sum_c rho_ic S_c)
//! V_i n_i` where `cos_i > 0`. The fit never moves `w` by its gradient (the shadows' edges,
//! which carry the information, are invisible to it): [`crate::init::sun_search`] does.

use glam::Vec3;

use crate::rows::Rows;
use crate::trace::visibility::Visibility;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sun {
    /// Unit direction towards the sun.
    pub to_sun: Vec3,
    /// Irradiance at normal incidence, W/m^2 per channel.
    pub rgb: [f32; 3],
}

impl Sun {
    /// `max(0, n . w)` at row `i` where the sun reaches it, else 0 (`n`: the row's normal
    /// turned towards the sun, [`Rows::facing`]).
    #[inline]
    pub fn cos_at(&self, rows: &Rows, vis: &Visibility, i: usize) -> f32 {
        if vis.sun_visible(i) {
            rows.facing(i, self.to_sun).dot(self.to_sun).max(0.0)
        } else {
            0.0
        }
    }

    /// Adds the sun's irradiance to `e`.
    pub fn add_irradiance(&self, rows: &Rows, vis: &Visibility, e: &mut [[f64; 3]]) {
        use rayon::prelude::*;
        e.par_iter_mut().enumerate().for_each(|(i, ei)| {
            let c = self.cos_at(rows, vis, i) as f64;
            if c > 0.0 {
                for k in 0..3 {
                    ei[k] += self.rgb[k] as f64 * c;
                }
            }
        });
    }

    /// `(dF/dw, dF/dS)` for `rho = dF/dE`.
    pub fn gradient(&self, rows: &Rows, vis: &Visibility, rho: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
        let (mut gw, mut gs) = ([0.0f64; 3], [0.0f64; 3]);
        for (i, r) in rho.iter().enumerate() {
            let c = self.cos_at(rows, vis, i) as f64;
            if c > 0.0 {
                let mut q = 0.0;
                for k in 0..3 {
                    gs[k] += r[k] * c;
                    q += r[k] * self.rgb[k] as f64;
                }
                let n = rows.facing(i, self.to_sun);
                gw[0] += q * n.x as f64;
                gw[1] += q * n.y as f64;
                gw[2] += q * n.z as f64;
            }
        }
        (gw, gs)
    }
}
