//! Sky light: the light of an overcast sky through the map's sky surfaces (q3map2's
//! `q3map_skyLight value iterations`).
//!
//! q3map2 simulates it with a set of suns spread over the upper hemisphere
//! ([`q3gltf_convert::units::q3map2_sky_suns`]), each adding `value / count x cos` bytes
//! where the sky is visible. The model keeps their geometry once, per row,
//!
//! ```text
//! D_i = 1/N sum_k max(0, n_i . s_k) V_ik          (V_ik: the ray towards s_k crosses sky)
//! ```
//!
//! (`n_i` turned towards `s_k` on a two-sided row, [`Rows::facing`]; `V_ik` as q3map2
//! decides it for its suns, [`crate::trace::visibility::sky_visible_from`]: a sky surface
//! crossed and no opaque one on the whole way, a ray along an edge stopped) and scales it by a
//! fitted irradiance `K_c` [W/m^2]: `E_ic = K_c D_i`. A q3map2 sky
//! light of value `v` is `K = pi e_per_byte v`; written for Blender as emission of the
//! sky surfaces with radiance `K mean_k(cos s_k) / pi` (the same irradiance on an open,
//! upward-facing surface). Gradient: `dF/dK_c = sum_i rho_ic D_i`.

use glam::Vec3;

use crate::backend::Backend;
use crate::error::Result;
use crate::rows::Rows;
use crate::trace::bvh::Bvh;

/// The sky basis `D_i` and the directions it was traced for.
#[derive(Debug, Clone, Default)]
pub struct SkyBasis {
    pub d: Vec<f32>,
    /// Unit directions towards the sky suns, glTF axes.
    pub directions: Vec<Vec3>,
    /// Mean upward cosine of the directions (the open-sky value of `D`).
    pub mean_cos_up: f32,
}

/// q3map2's sky-sun directions for `iterations`, in glTF axes (`(x, y, z)q3 -> (x, z, -y)`).
pub fn directions(iterations: u32) -> Vec<Vec3> {
    q3gltf_convert::units::q3map2_sky_suns(iterations).into_iter().map(|d| Vec3::new(d[0] as f32, d[2] as f32, -d[1] as f32)).collect()
}

/// Traces the basis for `dirs` (rayon over blocks of rows). `sky[t]` marks sky triangles.
pub fn basis(rows: &Rows, bvh: &Bvh, sky: &[bool], dirs: &[Vec3]) -> SkyBasis {
    let n = dirs.len().max(1) as f32;
    let open = !sky.iter().any(|&k| k);
    use crate::trace::bvh::Occluder;
    // Rows in blocks of neighbours, sun by sun: per sun, the piece that stopped the
    // previous row's ray and the sky triangle it crossed are tried first, and per row the
    // piece that stopped its previous sun (the same answers). A row's state: its sum and
    // that piece.
    let per_row = crate::trace::visibility::by_neighbour_blocks(
        rows.len(),
        dirs.len(),
        |_| (0.0f32, Occluder::default()),
        || (Occluder::default(), Occluder::default()),
        |i, k, (s, last), (stopped, crossed)| {
            let w = dirs[k];
            let n = rows.facing(i, w);
            let c = n.dot(w);
            if c > 0.0 && crate::trace::visibility::sky_visible_from(bvh, rows.pos[i], n, w, &rows.sampling, sky, open, rows.solid_ahead[i], &mut [last, stopped], crossed) {
                *s += c;
            }
        },
    );
    let d = per_row.into_iter().map(|(s, _)| s / n).collect();
    SkyBasis { d, directions: dirs.to_vec(), mean_cos_up: mean_cos_up(dirs) }
}

/// The basis for `dirs` on `backend` where it has a kernel for the sky's rays
/// ([`Backend::sky_bits`]), else [`basis`] on the CPU (the reference): the same sums of
/// the same cosines, so the same bits where the device's rays agree.
pub fn basis_on(backend: &mut dyn Backend, rows: &Rows, bvh: &Bvh, sky: &[bool], dirs: &[Vec3]) -> Result<SkyBasis> {
    match backend.sky_bits(rows, dirs, sky) {
        None => Ok(basis(rows, bvh, sky, dirs)),
        Some(bits) => {
            let bits = bits?;
            if bits.len() != dirs.len() || bits.iter().any(|b| b.len() < rows.len().div_ceil(32)) {
                return Err(crate::error::Error::Gpu(format!("the device gave the sky's bits of {} directions for {}", bits.len(), dirs.len())));
            }
            Ok(basis_from_bits(rows, dirs, &bits))
        }
    }
}

/// The basis from each sun's visibility bits (`bits[k]`, bit `i` for row `i`): each
/// row's cosines summed sun by sun, as [`basis`] sums them.
pub fn basis_from_bits(rows: &Rows, dirs: &[Vec3], bits: &[Vec<u32>]) -> SkyBasis {
    use rayon::prelude::*;
    let n = dirs.len().max(1) as f32;
    let d = (0..rows.len())
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| {
            let mut s = 0.0f32;
            for (k, &w) in dirs.iter().enumerate() {
                if bits[k][i / 32] >> (i % 32) & 1 == 1 {
                    let c = rows.facing(i, w).dot(w);
                    if c > 0.0 {
                        s += c;
                    }
                }
            }
            s / n
        })
        .collect();
    SkyBasis { d, directions: dirs.to_vec(), mean_cos_up: mean_cos_up(dirs) }
}

/// Mean upward cosine of `dirs` (the open-sky value of `D`).
fn mean_cos_up(dirs: &[Vec3]) -> f32 {
    dirs.iter().map(|w| w.y.max(0.0)).sum::<f32>() / dirs.len().max(1) as f32
}

impl SkyBasis {
    pub fn add_irradiance(&self, k: [f32; 3], e: &mut [[f64; 3]]) {
        for (ei, &d) in e.iter_mut().zip(&self.d) {
            for c in 0..3 {
                ei[c] += k[c] as f64 * d as f64;
            }
        }
    }

    pub fn gradient(&self, rho: &[[f64; 3]]) -> [f64; 3] {
        let mut g = [0.0; 3];
        for (r, &d) in rho.iter().zip(&self.d) {
            for c in 0..3 {
                g[c] += r[c] * d as f64;
            }
        }
        g
    }
}
