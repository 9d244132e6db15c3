//! Lightmap atlas: packs lightmap pages into as few RGB images as possible.
//!
//! Pages keep their bytes unchanged (no gamma, overbright or filtering). Each page is
//! placed in a cell one texel larger on every side, and that border repeats the page's
//! edge texels, so bilinear sampling anywhere inside the page never reads another page
//! (it behaves like clamp-to-edge). Cells are laid out row by row on a grid; an atlas
//! holds at most [`MAX_ATLAS_SIDE`] texels per side, further pages start a new atlas.
//!
//! The layout is a pure function of the page sizes, so output is deterministic.

/// Largest side of one atlas image, in texels.
pub const MAX_ATLAS_SIDE: usize = 4096;
/// Border texels around each page.
pub const PAD: usize = 1;

/// One lightmap page as RGB8, row-major, top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct Page {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
}

/// One packed atlas image.
#[derive(Debug, Clone, PartialEq)]
pub struct AtlasImage {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
}

/// Where a page landed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    pub atlas: usize,
    /// Texel offset of the page's first texel (inside the border).
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

impl Placement {
    /// Maps page-normalised lightmap coordinates (0..1 across the page) to atlas UVs.
    pub fn map_uv(&self, uv: [f32; 2], atlas: &AtlasImage) -> [f32; 2] {
        let u = (self.x as f64 + uv[0] as f64 * self.width as f64) / atlas.width as f64;
        let v = (self.y as f64 + uv[1] as f64 * self.height as f64) / atlas.height as f64;
        [u as f32, v as f32]
    }
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct Atlas {
    pub images: Vec<AtlasImage>,
    /// One entry per input page, in input order.
    pub placements: Vec<Placement>,
}

/// Packs pages. All pages of one map have one size in practice; mixed sizes are packed
/// on a grid of the largest cell.
pub fn pack(pages: &[Page]) -> Atlas {
    let mut atlas = Atlas::default();
    if pages.is_empty() {
        return atlas;
    }
    let cw = pages.iter().map(|p| p.width).max().unwrap_or(1) + 2 * PAD;
    let ch = pages.iter().map(|p| p.height).max().unwrap_or(1) + 2 * PAD;
    let max_cols = (MAX_ATLAS_SIDE / cw).max(1);
    let max_rows = (MAX_ATLAS_SIDE / ch).max(1);
    let per_atlas = max_cols * max_rows;
    for (chunk_i, chunk) in pages.chunks(per_atlas).enumerate() {
        // Square-ish grid for this chunk.
        let n = chunk.len();
        let mut cols = (n as f64).sqrt().ceil() as usize;
        cols = cols.clamp(1, max_cols);
        let rows = n.div_ceil(cols);
        let (w, h) = (cols * cw, rows * ch);
        let mut img = AtlasImage { width: w, height: h, rgb: vec![0u8; w * h * 3] };
        for (k, page) in chunk.iter().enumerate() {
            let (cx, cy) = ((k % cols) * cw, (k / cols) * ch);
            blit_padded(&mut img, page, cx, cy);
            atlas.placements.push(Placement { atlas: chunk_i, x: cx + PAD, y: cy + PAD, width: page.width, height: page.height });
        }
        atlas.images.push(img);
    }
    atlas
}

/// Copies a page into the cell at (cx, cy), with its edge texels repeated into the border.
fn blit_padded(img: &mut AtlasImage, page: &Page, cx: usize, cy: usize) {
    let (pw, ph) = (page.width, page.height);
    if pw == 0 || ph == 0 {
        return;
    }
    for y in 0..ph + 2 * PAD {
        let sy = y.saturating_sub(PAD).min(ph - 1);
        for x in 0..pw + 2 * PAD {
            let sx = x.saturating_sub(PAD).min(pw - 1);
            let s = (sy * pw + sx) * 3;
            let d = ((cy + y) * img.width + cx + x) * 3;
            img.rgb[d..d + 3].copy_from_slice(&page.rgb[s..s + 3]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pages_are_copied_unchanged_with_clamped_border() {
        let pages: Vec<Page> = (0..5u8)
            .map(|i| Page { width: 4, height: 4, rgb: (0..48).map(|k| k as u8 ^ (i * 50)).collect() })
            .collect();
        let a = pack(&pages);
        assert_eq!(a.images.len(), 1);
        for (p, pl) in pages.iter().zip(&a.placements) {
            let img = &a.images[pl.atlas];
            for y in 0..4 {
                for x in 0..4 {
                    let d = ((pl.y + y) * img.width + pl.x + x) * 3;
                    assert_eq!(&img.rgb[d..d + 3], &p.rgb[(y * 4 + x) * 3..(y * 4 + x) * 3 + 3]);
                }
            }
            // Border texel left of (0, 0) repeats it.
            let d = (pl.y * img.width + pl.x - 1) * 3;
            assert_eq!(&img.rgb[d..d + 3], &p.rgb[0..3]);
            // UV (0.5/4, 0.5/4) is the centre of texel (0, 0).
            let uv = pl.map_uv([0.125, 0.125], img);
            assert!(((uv[0] * img.width as f32) - (pl.x as f32 + 0.5)).abs() < 1e-4);
        }
    }

    #[test]
    fn overflow_starts_a_new_atlas() {
        let per = (MAX_ATLAS_SIDE / 130).pow(2);
        let pages = vec![Page { width: 128, height: 128, rgb: vec![0; 128 * 128 * 3] }; per + 1];
        let a = pack(&pages);
        assert_eq!(a.images.len(), 2);
        assert_eq!(a.placements[per].atlas, 1);
    }
}
