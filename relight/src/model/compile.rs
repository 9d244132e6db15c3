//! What q3map2's compile does to the light after the emitters (`IlluminateRawLightmap`,
//! `StoreSurfaceLightmaps`), in its order:
//!
//! 1. **filter** (`-filter`): each light's luxels are blurred over the 3x3 luxels of the
//!    same raw lightmap, weights 1 at the centre, 1/2 on the sides and 1/4 at the corners
//!    (luxels that are not mapped count with weight 0), normalised;
//! 2. **ambient** (`_ambient`): a constant added to every luxel (not filtered);
//! 3. **dirt** (`-dirt`): the sum multiplied by an ambient-occlusion factor
//!    ([`dirt`]), computed once per luxel;
//! 4. bounces ([`super::bounce`]) go through 1 and 3 again, without the ambient;
//! 5. **minlight** (`_minlight`): every channel raised to at least this value when the
//!    lightmap is stored.
//!
//! Filter and dirt are linear: [`Sparse`] operators on the rows, with their transposes
//! for the gradient. The minlight floor is the model's one non-linearity in the light.
//! Gamma (`-gamma`) is applied to the data instead (the lightmap's decode), and the
//! clamp at 255 is the data's censoring.
//!
//! "Same raw lightmap" is not in the glTF: neighbours are the rows of the 8 adjacent
//! texels of the same lightmap texture whose material is the same and whose sample
//! points lie within 2.5 texel widths with normals within 25 degrees (packed neighbours
//! of another surface are far away in the world).

use std::collections::HashMap;

use glam::Vec3;
use rayon::prelude::*;

use crate::backend::Backend;
use crate::error::Result;
use crate::rows::{Rows, SolidAhead};
use crate::trace::bvh::Bvh;
use crate::trace::tree::PlaneRay;

/// A linear operator between rows (or rows and sources) that can skip the rows a sparse
/// input does not reach: the filter ([`Sparse`]) and the bounce's transport
/// ([`super::bounce::Transport`]).
pub trait Operator {
    /// `y = S x` per channel, with an optional per-column factor.
    fn apply(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>) -> Vec<[f64; 3]>;
    /// `apply` to an `x` that is zero outside `support`: the same bits on the rows it
    /// reaches, and those rows; `None` past `limit` of them.
    fn apply_supported(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>, support: &[u32], limit: usize) -> Option<(Vec<[f64; 3]>, Vec<u32>)>;
}

impl Operator for Sparse {
    fn apply(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>) -> Vec<[f64; 3]> {
        Sparse::apply(self, x, col)
    }
    fn apply_supported(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>, support: &[u32], limit: usize) -> Option<(Vec<[f64; 3]>, Vec<u32>)> {
        Sparse::apply_supported(self, x, col, support, limit)
    }
}

/// A sparse linear operator on the rows: `y_i = sum_k w_ik x_{j_ik}` (CSR).
///
/// The transpose (for the gradient's adjoint passes) is built on first use and kept, so
/// that `S^T x` is a gather per output row, in parallel, like `S x`.
#[derive(Debug, Clone, Default)]
pub struct Sparse {
    offsets: Vec<u32>,
    entries: Vec<(u32, f32)>,
    /// `S^T` in CSR over the same rows, entries of each row in increasing source row
    /// (the order a sequential scatter would add them in: the sums are the same bits).
    transposed: std::sync::OnceLock<Box<(Vec<u32>, Vec<(u32, f32)>)>>,
}

impl Sparse {
    /// An operator with no rows yet ([`Sparse::push_row`] adds them in order).
    pub fn empty() -> Sparse {
        Sparse { offsets: vec![0], entries: Vec::new(), transposed: std::sync::OnceLock::new() }
    }

    /// Appends the next row, `(source row, weight)` pairs.
    pub fn push_row(&mut self, row: impl IntoIterator<Item = (u32, f32)>) {
        self.entries.extend(row);
        self.offsets.push(self.entries.len() as u32);
        self.transposed = std::sync::OnceLock::new();
    }

    pub fn row(&self, i: usize) -> &[(u32, f32)] {
        &self.entries[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    pub fn rows(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// `y = S x` per channel, with an optional per-column factor `col[j]` (per channel).
    pub fn apply(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>) -> Vec<[f64; 3]> {
        gather(&self.offsets, &self.entries, x, col)
    }

    /// [`Sparse::apply`] to an `x` that is zero outside `support` (ascending rows): only
    /// the rows with an entry into the support are gathered, each as `apply` gathers it
    /// (the same bits); every other row of `y` is zero (`apply` sums zeros there).
    /// Returns `y` and its support (ascending), or `None` when it would reach more than
    /// `limit` rows (then the plain product costs about as much). The rows reached are
    /// found through `S^T` ([`Sparse::apply_transposed`]'s, built on first use).
    pub fn apply_supported(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>, support: &[u32], limit: usize) -> Option<(Vec<[f64; 3]>, Vec<u32>)> {
        let t = self.transposed.get_or_init(|| Box::new(self.transpose()));
        let (offsets, entries) = (&t.0, &t.1);
        let n = self.rows();
        let mut seen = vec![false; n];
        let mut reached: Vec<u32> = Vec::new();
        for &j in support {
            let j = j as usize;
            if j + 1 >= offsets.len() {
                continue;
            }
            for &(i, _) in &entries[offsets[j] as usize..offsets[j + 1] as usize] {
                let i = i as usize;
                if i < n && !seen[i] {
                    seen[i] = true;
                    reached.push(i as u32);
                    if reached.len() > limit {
                        return None;
                    }
                }
            }
        }
        reached.sort_unstable();
        let values: Vec<[f64; 3]> = reached.par_iter().with_min_len(1024).map(|&i| gather_row(self.row(i as usize), x, col)).collect();
        let mut y = vec![[0.0f64; 3]; n];
        for (&i, v) in reached.iter().zip(values) {
            y[i as usize] = v;
        }
        Some((y, reached))
    }

    /// `y = S^T x` (the same optional column factor applied on the output side), with
    /// `x.len()` rows (the operators here are square).
    pub fn apply_transposed(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>) -> Vec<[f64; 3]> {
        self.apply_transposed_len(x, col, x.len())
    }

    /// [`Sparse::apply_transposed`] of a rectangular operator: `x` over its rows, `y`
    /// over `len` columns (those past the largest column with an entry are zero).
    pub fn apply_transposed_len(&self, x: &[[f64; 3]], col: Option<&[[f32; 3]]>, len: usize) -> Vec<[f64; 3]> {
        let t = self.transposed.get_or_init(|| Box::new(self.transpose()));
        let (offsets, entries) = (&t.0, &t.1);
        let n = len.min(offsets.len().saturating_sub(1));
        let mut y = vec![[0.0f64; 3]; len];
        // Row j of S^T gathers x over the rows i that point at j; the column factor is
        // that of the output row j.
        y[..n].par_iter_mut().enumerate().for_each(|(j, yj)| {
            let f = col.map_or([1.0f32; 3], |a| a[j]);
            for &(i, w) in &entries[offsets[j] as usize..offsets[j + 1] as usize] {
                for c in 0..3 {
                    yj[c] += w as f64 * f[c] as f64 * x[i as usize][c];
                }
            }
        });
        y
    }

    /// `S^T` as CSR arrays over `max(rows, largest column + 1)` rows.
    fn transpose(&self) -> (Vec<u32>, Vec<(u32, f32)>) {
        let cols = self.entries.iter().map(|e| e.0 as usize + 1).max().unwrap_or(0).max(self.rows());
        let mut offsets = vec![0u32; cols + 1];
        for &(j, _) in &self.entries {
            offsets[j as usize + 1] += 1;
        }
        for j in 0..cols {
            offsets[j + 1] += offsets[j];
        }
        let mut fill: Vec<u32> = offsets[..cols].to_vec();
        let mut entries = vec![(0u32, 0.0f32); self.entries.len()];
        for i in 0..self.rows() {
            for &(j, w) in self.row(i) {
                let at = &mut fill[j as usize];
                entries[*at as usize] = (i as u32, w);
                *at += 1;
            }
        }
        (offsets, entries)
    }
}

/// The CSR product `y_i = sum_k w_ik col_{j_ik} x_{j_ik}` (rayon).
fn gather(offsets: &[u32], entries: &[(u32, f32)], x: &[[f64; 3]], col: Option<&[[f32; 3]]>) -> Vec<[f64; 3]> {
    (0..offsets.len().saturating_sub(1))
        .into_par_iter()
        .map(|i| gather_row(&entries[offsets[i] as usize..offsets[i + 1] as usize], x, col))
        .collect()
}

/// One row of [`gather`]: `sum_k w_k col_{j_k} x_{j_k}`, in the row's order.
#[inline]
fn gather_row(row: &[(u32, f32)], x: &[[f64; 3]], col: Option<&[[f32; 3]]>) -> [f64; 3] {
    let mut y = [0.0f64; 3];
    // The factor's presence decided once per row, not per entry (without one, `w x` is
    // `w 1 x` to the bit).
    match col {
        Some(a) => {
            for &(j, w) in row {
                let (f, xj) = (a[j as usize], x[j as usize]);
                for c in 0..3 {
                    y[c] += w as f64 * f[c] as f64 * xj[c];
                }
            }
        }
        None => {
            for &(j, w) in row {
                let (w, xj) = (w as f64, x[j as usize]);
                for c in 0..3 {
                    y[c] += w * xj[c];
                }
            }
        }
    }
    y
}

/// The 8 neighbours of every luxel row in its raw lightmap (see the module docs), as
/// `(row, dx, dy)`; the rows in parallel, each its own list (the same lists in any order).
pub fn neighbours(rows: &Rows) -> Vec<Vec<(u32, i8, i8)>> {
    let index: HashMap<[u32; 3], u32> = (0..rows.len()).filter(|&i| rows.texel[i][0] != u32::MAX).map(|i| (rows.texel[i], i as u32)).collect();
    (0..rows.len())
        .into_par_iter()
        .with_min_len(4096)
        .map(|i| {
            let [t, x, y] = rows.texel[i];
            if t == u32::MAX {
                return Vec::new();
            }
            let reach = 2.5 * rows.area[i].max(0.0).sqrt();
            let mut out = Vec::new();
            for dy in -1i32..=1 {
                for dx in -1i32..=1 {
                    if (dx, dy) == (0, 0) {
                        continue;
                    }
                    let (nx, ny) = (x as i64 + dx as i64, y as i64 + dy as i64);
                    if nx < 0 || ny < 0 {
                        continue;
                    }
                    let Some(&j) = index.get(&[t, nx as u32, ny as u32]) else { continue };
                    let j = j as usize;
                    if rows.material[j] == rows.material[i] && (rows.pos[j] - rows.pos[i]).length() <= reach && rows.normal[j].dot(rows.normal[i]) > 0.906 {
                        out.push((j as u32, dx as i8, dy as i8));
                    }
                }
            }
            out
        })
        .collect()
}

/// q3map2's `-filter` on every light: the normalised 3x3 tent (see the module docs).
pub fn filter(rows: &Rows, nb: &[Vec<(u32, i8, i8)>]) -> Sparse {
    let mut s = Sparse::empty();
    for i in 0..rows.len() {
        let mut row = vec![(i as u32, 1.0f32)];
        for &(j, dx, dy) in &nb[i] {
            let w = if dx != 0 { 0.5 } else { 1.0 } * if dy != 0 { 0.5 } else { 1.0 };
            row.push((j, w));
        }
        let sum: f32 = row.iter().map(|e| e.1).sum();
        s.push_row(row.into_iter().map(|(j, w)| (j, w / sum)));
    }
    s
}

pub use crate::scene::DirtSettings;

/// The factor of a luxel that gathered `g` (see [`dirt_gather`]) under `set`: 1 is no
/// darkening (q3map2's `DirtForSample`).
fn dirt_factor(set: &DirtSettings, g: f32) -> f32 {
    if g <= 0.0 {
        return 1.0;
    }
    1.0 - ((g / 49.0).powf(set.gain).min(1.0) * set.scale).min(1.0)
}

/// The depths (Quake units) the data chooses among where no compile recorded them: half
/// and a quarter of q3map2's default, and the default. Measured on oacmpdm1 with its
/// source lights (`--fit globals`, 2-core Xeon, 2026-11-28): depth 32, 48, 64, 96, 128:
/// 0.1480, 0.1478, 0.1481, 0.1563 (the dirt left out), 0.1541 (left out).
pub const DIRT_DEPTHS_UNITS: [f32; 3] = [32.0, 64.0, 128.0];

/// One dirt setting's factor per row.
#[derive(Debug, Clone, PartialEq)]
pub struct DirtBasis {
    pub settings: DirtSettings,
    pub factor: Vec<f32>,
}

/// The 48 ordered directions of q3map2's dirt (16 azimuths x 3 elevations within 88
/// degrees of the normal), in the normal's frame `(right, up, normal)`.
fn dirt_vectors() -> Vec<[f32; 3]> {
    let angle_step = (360.0f32 / 16.0).to_radians();
    let elevation_step = (88.0f32 / 3.0).to_radians();
    let mut v = Vec::with_capacity(48);
    for i in 0..16 {
        let angle = i as f32 * angle_step;
        for j in 0..3 {
            let elevation = elevation_step * (0.5 + j as f32);
            v.push([elevation.sin() * angle.cos(), elevation.sin() * angle.sin(), elevation.cos()]);
        }
    }
    v
}

/// The occlusion gathered at one sample: `sum (1 - hit distance / depth)` over the 48
/// directions and the normal, for hits within `depth`.
///
/// From a point on a wall's plane with the wall on Quake's positive side, the rays along
/// that wall stop at once too ([`SolidAhead`], `on_epsilon` m).
pub fn dirt_gather(bvh: &Bvh, x: Vec3, n: Vec3, depth: f32, ahead: SolidAhead, on_epsilon: f32) -> f32 {
    let mut g = [0.0];
    dirt_gathers(bvh, x, n, &[depth], ahead, on_epsilon, &mut g);
    g[0]
}

/// [`dirt_gather`] at several depths (m) from one trace per direction, as far as the
/// largest: a hit within a shorter depth is the first hit of that shorter ray too. At the
/// largest depth the same bits as [`dirt_gather`] at it alone.
pub fn dirt_gathers(bvh: &Bvh, x: Vec3, n: Vec3, depths: &[f32], ahead: SolidAhead, on_epsilon: f32, g: &mut [f32]) {
    let longest = depths.iter().copied().fold(0.0f32, f32::max);
    dirt_gathers_with(n, depths, ahead, on_epsilon, g, &mut |d| bvh.first_hit_from_plane(x, d, longest).map(|h| h.0));
}

/// [`dirt_gathers`] with its walks from `hit`: called for each direction that needs one,
/// in order, with the direction; it answers the hit's distance (m) within the largest
/// depth. The walks are the caller's, so a device can take them all at once
/// ([`dirt`]): one pass hands out the directions, a second sums their answers.
fn dirt_gathers_with(n: Vec3, depths: &[f32], ahead: SolidAhead, on_epsilon: f32, g: &mut [f32], hit: &mut dyn FnMut(Vec3) -> Option<f32>) {
    // q3map2's tangent frame: right = n x up (Quake's Z is glTF's Y), up = right x n.
    let world_up = Vec3::Y;
    let (right, up) = if n.x == 0.0 && n.z == 0.0 && n.y.abs() == 1.0 {
        // Quake: (1, 0, 0) and (0, 1, 0) for +Z, (-1, 0, 0) and (0, 1, 0) for -Z; glTF
        // maps Quake's +Y to -Z.
        (Vec3::X * n.y, Vec3::NEG_Z)
    } else {
        let r = n.cross(world_up).normalize();
        (r, r.cross(n).normalize())
    };
    g.iter_mut().for_each(|v| *v = 0.0);
    let longest = depths.iter().copied().fold(0.0f32, f32::max);
    for v in dirt_vectors().iter().chain(std::iter::once(&[0.0, 0.0, 1.0])) {
        let d = right * v[0] + up * v[1] + n * v[2];
        let mut traced = false;
        let mut found = None;
        for (gk, &depth) in g.iter_mut().zip(depths) {
            if on_epsilon > 0.0 && ahead.stops(d, depth, on_epsilon) {
                *gk += 1.0;
                continue;
            }
            // A sample on a wall's plane (the edge row of a face where it meets the wall)
            // is occluded at distance 0 in that wall's direction, as q3map2's BSP trace
            // finds it.
            if !traced {
                found = hit(d);
                traced = true;
            }
            if let Some(dist) = found.filter(|&t| t < depth || depth == longest) {
                *gk += 1.0 - dist / depth;
            }
        }
    }
}

/// The dirt factor of every row for each of `sets` (1 = no darkening), smoothed over each
/// luxel's mapped neighbours as q3map2 does: in place, row by row of each lightmap (later
/// luxels see their earlier neighbours already smoothed), over the neighbours with some
/// dirt. One trace per direction serves every depth. `units_m`: metres per Quake unit.
///
/// The walks run on `backend` where it has a kernel for them
/// ([`crate::backend::gather_rows`]), else row by row on the CPU (the reference).
pub fn dirt(rows: &Rows, bvh: &Bvh, nb: &[Vec<(u32, i8, i8)>], sets: &[DirtSettings], units_m: f32, backend: &mut dyn Backend) -> Result<Vec<DirtBasis>> {
    let depths: Vec<f32> = sets.iter().map(|s| s.depth_units * units_m).collect();
    let n = rows.len();
    let longest = depths.iter().copied().fold(0.0f32, f32::max);
    let gathered: Vec<Vec<f32>> = crate::backend::gather_rows(backend, bvh, n, DIRT_RAYS, |i, walk| {
        let mut g = vec![0.0f32; sets.len()];
        dirt_gathers_with(rows.normal[i], &depths, rows.solid_ahead[i], rows.sampling.on_epsilon, &mut g, &mut |d| walk(PlaneRay::new(rows.pos[i], d, longest)).map(|h| h.0));
        g
    })?;
    let mut order: Vec<usize> = (0..rows.len()).collect();
    order.sort_by_key(|&i| (rows.texel[i][0], rows.texel[i][2], rows.texel[i][1]));
    Ok(sets
        .iter()
        .enumerate()
        .map(|(k, set)| {
            let mut dirt: Vec<f32> = gathered.iter().map(|g| dirt_factor(set, g[k])).collect();
            for &i in &order {
                let (mut sum, mut n) = (dirt[i], 1.0f32);
                for &(j, _, _) in &nb[i] {
                    let d = dirt[j as usize];
                    if d > 0.0 {
                        sum += d;
                        n += 1.0;
                    }
                }
                dirt[i] = sum / n;
            }
            DirtBasis { settings: *set, factor: dirt }
        })
        .collect())
}

/// Rays of a row's dirt gather at most: q3map2's 48 directions and the normal.
const DIRT_RAYS: usize = 49;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sparse_transpose_is_the_adjoint() {
        let mut s = Sparse::empty();
        s.push_row([(0, 0.5), (2, 0.25)]);
        s.push_row([(1, 1.0)]);
        s.push_row([(0, 0.2), (2, 0.8)]);
        let x = vec![[1.0, 2.0, 3.0], [0.5, -1.0, 2.0], [4.0, 0.0, -2.0]];
        let y = vec![[0.3, 0.1, -0.7], [1.0, 2.0, 0.5], [-0.2, 0.4, 0.9]];
        let col = vec![[0.9, 0.8, 0.7], [0.5, 0.6, 0.4], [1.0, 0.2, 0.3]];
        let sx = s.apply(&x, Some(&col));
        let sty = s.apply_transposed(&y, Some(&col));
        for c in 0..3 {
            let a: f64 = (0..3).map(|i| y[i][c] * sx[i][c]).sum();
            let b: f64 = (0..3).map(|i| sty[i][c] * x[i][c]).sum();
            assert!((a - b).abs() < 1e-12, "<y, Sx> = <S^T y, x>: {a} vs {b}");
        }
    }

    /// The cached transpose's gather gives the bits a sequential scatter gives (the same
    /// terms in the same order), and a row pushed after a use is seen.
    #[test]
    fn sparse_transpose_gathers_what_a_scatter_adds() {
        let n = 2000;
        let mut s = Sparse::empty();
        for i in 0..n {
            let k = 1 + (crate::model::bounce::hash01(i as u32, 7) * 20.0) as usize;
            s.push_row((0..k).map(|m| (((crate::model::bounce::hash01(i as u32, m as u32) * n as f32) as u32).min(n as u32 - 1), 0.1 + crate::model::bounce::hash01(m as u32, i as u32))));
        }
        let x: Vec<[f64; 3]> = (0..n).map(|i| [i as f64 * 0.37, (i % 11) as f64 - 5.0, 1.0 / (1.0 + i as f64)]).collect();
        let col: Vec<[f32; 3]> = (0..n).map(|i| [0.3, 0.5 + (i % 3) as f32 * 0.1, 0.9]).collect();
        let scatter = |s: &Sparse, x: &[[f64; 3]], col: &[[f32; 3]]| {
            let mut y = vec![[0.0f64; 3]; x.len()];
            for i in 0..s.rows() {
                for &(j, w) in s.row(i) {
                    for c in 0..3 {
                        y[j as usize][c] += w as f64 * col[j as usize][c] as f64 * x[i][c];
                    }
                }
            }
            y
        };
        assert_eq!(s.apply_transposed(&x, Some(&col)), scatter(&s, &x, &col));
        // A further row (a square operator grown by one) after the transpose was cached.
        s.push_row([(0, 2.0), (n as u32, 1.0)]);
        let mut x2 = x.clone();
        x2.push([1.0, 2.0, 3.0]);
        let mut col2 = col.clone();
        col2.push([1.0; 3]);
        assert_eq!(s.apply_transposed(&x2, Some(&col2)), scatter(&s, &x2, &col2));
    }

    /// A 10 m square wall through the origin, facing `w`.
    fn wall(w: Vec3) -> crate::scene::Mesh {
        let mut m = crate::scene::Mesh::default();
        let t1 = Vec3::Y;
        let t2 = w.cross(t1).normalize();
        for (a, b) in [(-5.0, -5.0), (5.0, -5.0), (5.0, 5.0), (-5.0, 5.0)] {
            m.positions.push(t1 * a + t2 * b);
        }
        // (t1 x t2) = -w for this order; wind the other way so the face looks along w.
        let flip = t1.cross(t2).dot(w) < 0.0;
        m.triangles = if flip { vec![[0, 2, 1], [0, 3, 2]] } else { vec![[0, 1, 2], [0, 2, 3]] };
        m
    }

    #[test]
    fn a_sample_on_a_walls_plane_is_occluded_at_distance_zero_toward_it() {
        // q3map2's BSP trace stops a dirt ray from a point on a wall's plane at once when it
        // heads into the wall (its edge rows' raw dirt: 21 of the 49 rays on the oracle's
        // -dirtdebug lightmap), and lets the rays leaving the plane go. The wall is turned
        // 10 degrees so that no ray runs along it.
        let w = Vec3::new(10f32.to_radians().cos(), 0.0, 10f32.to_radians().sin());
        let bvh = Bvh::build(&wall(w));
        let n = Vec3::Y;
        let depth = 3.25;
        // Off the quad's diagonal (a ray through the shared edge of two triangles can slip
        // between them).
        let x = Vec3::new(0.0, 0.7, 0.0);
        let g = dirt_gather(&bvh, x, n, depth, SolidAhead::NONE, 0.0);
        // The directions as dirt_gather builds them for the normal +Y.
        let (right, up) = (Vec3::X, Vec3::NEG_Z);
        let into = dirt_vectors().iter().filter(|v| (right * v[0] + up * v[1] + n * v[2]).dot(w) < 0.0).count();
        assert!(into > 15, "{into}");
        assert!((g - into as f32).abs() < 1e-3, "gathered {g}, expected {into} rays at distance 0");
        // Moved off the plane into the open, the same rays hit at a distance.
        let g_off = dirt_gather(&bvh, x + w * 0.5, n, depth, SolidAhead::NONE, 0.0);
        assert!(g_off > 0.0 && g_off < g, "{g_off} vs {g}");
    }

    /// The rows moved off their faces and the walls around them, 1% of the way to the
    /// room's centre, and up to 5 mm off the seams between the walls' triangles (a ray
    /// along a seam slips between its two triangles or not by a hair).
    fn lift(rows: &mut Rows) {
        use crate::model::bounce::hash01;
        let centre = Vec3::new(2.0, 1.25, 1.5);
        for i in 0..rows.len() {
            let jitter = Vec3::new(hash01(i as u32, 1), hash01(i as u32, 2), hash01(i as u32, 3)) - 0.5;
            let off = (jitter - rows.normal[i] * jitter.dot(rows.normal[i])) * 0.01;
            rows.pos[i] = rows.pos[i].lerp(centre, 0.01) + off;
        }
    }

    #[test]
    fn one_trace_gathers_every_depth_as_its_own_trace_would() {
        // Samples across a room with quads scattered in it: the gathers at three depths
        // from one trace as far as the longest are the gathers each depth traces alone
        // (the same bits at the longest, f32 rounding of the hit distance below it). The
        // samples sit off their faces, as q3map2's sit off theirs: a ray from a room's
        // corner grazes the walls it starts on, hit or not by a hair either way.
        let (mut mesh, mut rows) = crate::testutil::room(6);
        lift(&mut rows);
        crate::testutil::scatter_quads(&mut mesh, 40);
        let bvh = Bvh::build(&mesh);
        let depths = [0.4f32, 1.1, 2.5];
        let mut some_differ = 0;
        for i in 0..rows.len() {
            let mut g = [0.0f32; 3];
            dirt_gathers(&bvh, rows.pos[i], rows.normal[i], &depths, SolidAhead::NONE, 0.0, &mut g);
            let alone = depths.map(|d| dirt_gather(&bvh, rows.pos[i], rows.normal[i], d, SolidAhead::NONE, 0.0));
            assert_eq!(g[2].to_bits(), alone[2].to_bits(), "row {i}: {g:?} vs {alone:?}");
            for k in 0..2 {
                assert!((g[k] - alone[k]).abs() <= 1e-4 * (1.0 + alone[k]), "row {i}, depth {}: {} vs {}", depths[k], g[k], alone[k]);
            }
            // A longer ray gathers at least what a shorter one does.
            assert!(g[0] <= g[1] + 1e-5 && g[1] <= g[2] + 1e-5, "row {i}: {g:?}");
            some_differ += (g[0] < g[2] - 0.5) as usize;
        }
        assert!(some_differ > rows.len() / 4, "the depths differ on {some_differ} of {} rows", rows.len());
    }

    #[test]
    fn the_dirt_of_each_setting_is_its_own_basis() {
        // The bases of three settings from one call: each the same as a call with it alone.
        let (mut mesh, mut rows) = crate::testutil::room(4);
        lift(&mut rows);
        crate::testutil::scatter_quads(&mut mesh, 20);
        let bvh = Bvh::build(&mesh);
        let nb = neighbours(&rows);
        let set = |depth_units: f32, scale: f32, gain: f32| DirtSettings { depth_units, scale, gain };
        let sets = [set(32.0, 1.0, 1.0), set(128.0, 1.5, 2.0), set(128.0, 1.0, 1.0)];
        let units_m = 0.02;
        let all = dirt(&rows, &bvh, &nb, &sets, units_m, &mut crate::backend::Cpu::new(&rows, &bvh)).unwrap();
        assert_eq!(all.len(), 3);
        for (k, b) in all.iter().enumerate() {
            assert_eq!(b.settings, sets[k]);
            let alone = dirt(&rows, &bvh, &nb, &sets[k..k + 1], units_m, &mut crate::backend::Cpu::new(&rows, &bvh)).unwrap().remove(0);
            if sets[k].depth_units == 128.0 {
                assert_eq!(b.factor, alone.factor, "setting {k}");
            } else {
                assert!(b.factor.iter().zip(&alone.factor).all(|(a, b)| (a - b).abs() < 1e-5), "setting {k}");
            }
            assert!(b.factor.iter().all(|f| f.is_finite() && (0.0..=1.0).contains(f)));
        }
        // Scale and gain darken where anything was gathered; a shorter ray darkens less.
        let mean = |f: &[f32]| f.iter().sum::<f32>() / f.len() as f32;
        let (short, strong, default) = (mean(&all[0].factor), mean(&all[1].factor), mean(&all[2].factor));
        assert!(short > default && default != strong, "{short} {strong} {default}");
    }

    #[test]
    fn dirt_directions_are_q3map2s() {
        let v = dirt_vectors();
        assert_eq!(v.len(), 48);
        assert!(v.iter().all(|d| d[2] > 0.0 && ((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 1.0).abs() < 1e-6));
        // The lowest ring is 88 * 5/6 degrees from the normal.
        let lowest = v.iter().map(|d| d[2]).fold(1.0f32, f32::min);
        assert!((lowest - (88.0f32 * 5.0 / 6.0).to_radians().cos()).abs() < 1e-6);
    }
}
