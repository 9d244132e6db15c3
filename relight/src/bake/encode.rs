//! Encoding a bake's pages: OpenEXR (the `exr` crate; linear RGB with the coverage as
//! alpha, half or float) and PNG previews for people who do not open EXR files.
//!
//! Previews: a lightmap value `e` in the lightmap's own 8-bit encoding (`e 255 /
//! 2^overbright`, scaled down keeping hue above 255: what q3map2 would store), so the
//! original's preview is the original lightmap; a signed residual in a diverging colour
//! map (blue below, white at zero, red above), `range` at the ends, its luminance
//! (Rec. 709 weights) per texel; texels no row covers are dark grey.

use exr::prelude::*;

use crate::bake::page::Page;
use crate::error::{Error, Result};

/// The page as an EXR file in memory: channels R, G, B (linear, the page's units) and A
/// (1 where a row covered the texel, 0 in padding and empty space).
pub fn exr(page: &Page, half: bool) -> Result<Vec<u8>> {
    let (w, h) = (page.width as usize, page.height as usize);
    let mut out = std::io::Cursor::new(Vec::new());
    let px = |x: usize, y: usize| -> ([f32; 3], f32) {
        let o = y * w + x;
        (page.rgb[o], if page.covered[o] { 1.0 } else { 0.0 })
    };
    let written = if half {
        let channels = SpecificChannels::rgba(|Vec2(x, y)| {
            let (c, a) = px(x, y);
            (f16::from_f32(c[0]), f16::from_f32(c[1]), f16::from_f32(c[2]), f16::from_f32(a))
        });
        Image::from_channels((w, h), channels).write().to_buffered(&mut out)
    } else {
        let channels = SpecificChannels::rgba(|Vec2(x, y)| {
            let (c, a) = px(x, y);
            (c[0], c[1], c[2], a)
        });
        Image::from_channels((w, h), channels).write().to_buffered(&mut out)
    };
    written.map_err(|e| Error::Usage(format!("encoding an EXR page ({w} x {h}): {e}")))?;
    Ok(out.into_inner())
}

/// `e` in the lightmap's 8-bit encoding for `overbright_bits`, its largest channel
/// clamped at `top` keeping the hue: 255 as q3map2 stores it, or the data's own clamp
/// (127.5 after `-compensate 2`: [`crate::scene::Material::stored_per_light_byte`]).
pub fn lightmap_bytes(e: [f32; 3], overbright_bits: u32, top: f32) -> [u8; 3] {
    let top = if top.is_finite() { top.clamp(1.0, 255.0) } else { 255.0 };
    let scale = 255.0 / (1u32 << overbright_bits.min(8)) as f32;
    let b = e.map(|v| if v.is_finite() { v.max(0.0) * scale } else { 0.0 });
    let m = b.iter().copied().fold(top, f32::max);
    b.map(|v| (v * top / m).floor().clamp(0.0, 255.0) as u8)
}

fn png(w: u32, h: u32, rgb: Vec<u8>) -> Result<Vec<u8>> {
    let img = image::RgbImage::from_raw(w, h, rgb).ok_or_else(|| Error::Usage(format!("a {w} x {h} preview of the wrong size")))?;
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).map_err(|e| Error::Usage(format!("encoding a PNG preview: {e}")))?;
    Ok(out.into_inner())
}

/// Grey for texels no row covers.
const EMPTY: [u8; 3] = [40, 40, 40];

/// Preview of a lightmap page in its 8-bit encoding, clamped at `top` (padding shown as
/// stored).
pub fn preview(page: &Page, overbright_bits: u32, top: f32) -> Result<Vec<u8>> {
    let rgb = page.rgb.iter().flat_map(|&e| lightmap_bytes(e, overbright_bits, top)).collect();
    png(page.width, page.height, rgb)
}

/// The diverging colour map at `t` in [-1, 1].
pub fn diverging(t: f32) -> [u8; 3] {
    // Anchors from dark blue through white to dark red.
    const A: [(f32, [f32; 3]); 5] = [(-1.0, [5.0, 48.0, 97.0]), (-0.5, [67.0, 147.0, 195.0]), (0.0, [247.0, 247.0, 247.0]), (0.5, [214.0, 96.0, 77.0]), (1.0, [103.0, 0.0, 31.0])];
    let t = if t.is_finite() { t.clamp(-1.0, 1.0) } else { 0.0 };
    let k = A.iter().position(|a| t <= a.0).unwrap_or(A.len() - 1).max(1);
    let (t0, c0) = A[k - 1];
    let (t1, c1) = A[k];
    let s = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
    [0, 1, 2].map(|c| (c0[c] + (c1[c] - c0[c]) * s).round() as u8)
}

/// Rec. 709 luminance of a signed RGB value.
pub fn luminance(v: [f32; 3]) -> f32 {
    0.2126 * v[0] + 0.7152 * v[1] + 0.0722 * v[2]
}

/// Preview of a signed residual page: [`diverging`] of its luminance over `range`.
pub fn residual_preview(page: &Page, range: f32) -> Result<Vec<u8>> {
    let r = if range > 0.0 && range.is_finite() { range } else { 1.0 };
    let rgb = page.rgb.iter().zip(&page.covered).flat_map(|(&v, &c)| if c { diverging(luminance(v) / r) } else { EMPTY }).collect();
    png(page.width, page.height, rgb)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_diverging_map_is_white_at_zero_and_saturates_at_the_ends() {
        assert_eq!(diverging(0.0), [247, 247, 247]);
        assert_eq!(diverging(-1.0), [5, 48, 97]);
        assert_eq!(diverging(5.0), [103, 0, 31]);
        assert_eq!(diverging(f32::NAN), [247, 247, 247]);
        let warm = diverging(0.25);
        assert!(warm[0] > warm[2], "above zero is red: {warm:?}");
    }

    #[test]
    fn lightmap_bytes_invert_the_decode_and_keep_hue_above_full() {
        // e = byte 2^2 / 255.
        assert_eq!(lightmap_bytes([100.0 * 4.0 / 255.0, 0.0, 4.0], 2, 255.0), [100, 0, 255]);
        assert_eq!(lightmap_bytes([8.0, 4.0, -1.0], 2, 255.0), [255, 127, 0]);
        // A compile that halved every byte after the clamp (`-compensate 2`) stops at 127.
        assert_eq!(lightmap_bytes([100.0 * 4.0 / 255.0, 0.0, 1.0], 2, 127.5), [100, 0, 63]);
        assert_eq!(lightmap_bytes([8.0, 4.0, -1.0], 2, 127.5), [127, 63, 0]);
        assert_eq!(lightmap_bytes([f32::NAN, f32::INFINITY, 1.0], 2, 255.0), [0, 0, 63]);
    }

    #[test]
    fn an_exr_page_reads_back_with_its_values_and_coverage() {
        let mut p = Page::blank(0, 3, 2);
        p.rgb[4] = [0.25, 1.5, 3.0];
        p.covered[4] = true;
        for half in [false, true] {
            let bytes = exr(&p, half).unwrap();
            let img = read_first_rgba_layer_from_file_bytes(&bytes);
            assert_eq!(img.len(), 6);
            assert_eq!(img[4], [0.25, 1.5, 3.0, 1.0], "half {half}");
            assert_eq!(img[0], [0.0; 4]);
        }
    }

    fn read_first_rgba_layer_from_file_bytes(bytes: &[u8]) -> Vec<[f32; 4]> {
        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .rgba_channels(|res, _| vec![[0.0f32; 4]; res.width() * res.height()], |v: &mut Vec<[f32; 4]>, p: Vec2<usize>, (r, g, b, a): (f32, f32, f32, f32)| v[p.y() * 3 + p.x()] = [r, g, b, a])
            .first_valid_layer()
            .all_attributes()
            .from_buffered(std::io::Cursor::new(bytes))
            .unwrap();
        image.layer_data.channel_data.pixels
    }
}
