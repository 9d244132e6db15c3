//! Lightmap pages of a bake: per-texel values of the luxel rows laid out on the lightmap
//! texture each row came from, and the padding that keeps bilinear filtering at a chart's
//! edge from reading the empty texels around it.
//!
//! Invariant: `rgb.len() == covered.len() == width * height`; a texel is covered when a
//! row wrote it; padding writes only texels that were not covered.

use crate::rows::Rows;
use crate::scene::Texture;

/// One lightmap page: linear values per texel (row-major, y down as in the image).
#[derive(Debug, Clone)]
pub struct Page {
    /// Index of the lightmap in [`crate::scene::Scene::textures`].
    pub texture: usize,
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<[f32; 3]>,
    /// A row wrote this texel (the EXR's alpha).
    pub covered: Vec<bool>,
}

impl Page {
    pub fn blank(texture: usize, width: u32, height: u32) -> Page {
        let n = width as usize * height as usize;
        Page { texture, width, height, rgb: vec![[0.0; 3]; n], covered: vec![false; n] }
    }

    pub fn texels_covered(&self) -> usize {
        self.covered.iter().filter(|c| **c).count()
    }
}

/// The pages of every lightmap a luxel row refers to (ascending texture index), each
/// covered texel holding `values[i]` of its row; vertex rows are skipped.
pub fn splat(rows: &Rows, values: &[[f64; 3]], textures: &[Texture]) -> Vec<Page> {
    let mut pages: Vec<Option<Page>> = vec![None; textures.len()];
    for (i, &[tex, x, y]) in rows.texel.iter().enumerate() {
        let Some(t) = textures.get(tex as usize) else { continue };
        if x >= t.width || y >= t.height {
            continue;
        }
        let p = pages[tex as usize].get_or_insert_with(|| Page::blank(tex as usize, t.width, t.height));
        let o = y as usize * t.width as usize + x as usize;
        p.rgb[o] = values[i].map(|v| v as f32);
        p.covered[o] = true;
    }
    pages.into_iter().flatten().collect()
}

/// Fills up to `rings` texels around the covered ones, each with the mean of its already
/// filled 8-neighbours, ring by ring (what q3map2 does to its lightmaps' unused texels, so
/// that filtering at a chart's edge reads the chart, not black).
pub fn pad(page: &mut Page, rings: u32) {
    let (w, h) = (page.width as i64, page.height as i64);
    let mut filled = page.covered.clone();
    for _ in 0..rings {
        let mut next: Vec<(usize, [f32; 3])> = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let o = (y * w + x) as usize;
                if filled[o] {
                    continue;
                }
                let (mut sum, mut n) = ([0.0f32; 3], 0);
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let (nx, ny) = (x + dx, y + dy);
                        if (dx, dy) == (0, 0) || nx < 0 || ny < 0 || nx >= w || ny >= h {
                            continue;
                        }
                        let q = (ny * w + nx) as usize;
                        if filled[q] {
                            (0..3).for_each(|c| sum[c] += page.rgb[q][c]);
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    next.push((o, sum.map(|s| s / n as f32)));
                }
            }
        }
        if next.is_empty() {
            break;
        }
        for (o, v) in next {
            page.rgb[o] = v;
            filled[o] = true;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn padding_fills_rings_around_the_chart_and_never_overwrites_it() {
        let mut p = Page::blank(0, 6, 5);
        p.rgb[2 * 6 + 2] = [4.0, 2.0, 1.0];
        p.covered[2 * 6 + 2] = true;
        pad(&mut p, 1);
        assert_eq!(p.rgb[2 * 6 + 2], [4.0, 2.0, 1.0]);
        for (x, y) in [(1, 1), (3, 3), (2, 1), (1, 3)] {
            assert_eq!(p.rgb[y * 6 + x], [4.0, 2.0, 1.0], "({x}, {y}) is in the first ring");
        }
        assert_eq!(p.rgb[2 * 6 + 4], [0.0; 3], "the second ring is not filled with one ring of padding");
        assert_eq!(p.texels_covered(), 1, "padding is not coverage");
        pad(&mut p, 3);
        assert!(p.rgb.iter().all(|v| *v == [4.0, 2.0, 1.0]));
    }
}
