//! Texture images for glTF: JPEG and PNG files are kept byte for byte (after a header
//! check), every other format (TGA in practice) is decoded and re-encoded as PNG.
//! Decoding is bounded by [`Limits`] before any pixel buffer is allocated.

use std::io::Cursor;

/// Bounds on images read from game data.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Largest accepted width or height, in pixels.
    pub max_side: u32,
    /// Largest decoded size, in bytes.
    pub max_alloc: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits { max_side: 8192, max_alloc: 512 << 20 }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum TextureError {
    #[error("cannot decode image: {0}")]
    Decode(String),
    #[error("image is {w}x{h}, over the {max}-pixel limit per side")]
    TooLarge { w: u32, h: u32, max: u32 },
}

/// An image ready for glTF.
#[derive(Debug, Clone)]
pub struct Encoded {
    pub mime: &'static str,
    pub bytes: Vec<u8>,
    pub width: u32,
    pub height: u32,
}

fn reader(bytes: &[u8], limits: Limits) -> Result<image::ImageReader<Cursor<&[u8]>>, TextureError> {
    let mut r = image::ImageReader::new(Cursor::new(bytes));
    let mut l = image::Limits::default();
    l.max_image_width = Some(limits.max_side);
    l.max_image_height = Some(limits.max_side);
    l.max_alloc = Some(limits.max_alloc);
    r.limits(l);
    Ok(r)
}

fn check_dims(w: u32, h: u32, limits: Limits) -> Result<(), TextureError> {
    if w == 0 || h == 0 || w > limits.max_side || h > limits.max_side {
        return Err(TextureError::TooLarge { w, h, max: limits.max_side });
    }
    Ok(())
}

/// Prepares an image file's bytes for glTF. `ext` is the file's extension (lower case);
/// the content's magic bytes decide, so a JPEG named `.tga` is still copied.
pub fn encode_for_gltf(bytes: &[u8], ext: &str, limits: Limits) -> Result<Encoded, TextureError> {
    let is_jpeg = bytes.starts_with(&[0xFF, 0xD8, 0xFF]);
    let is_png = bytes.starts_with(b"\x89PNG\r\n\x1a\n");
    if is_jpeg || is_png {
        let format = if is_jpeg { image::ImageFormat::Jpeg } else { image::ImageFormat::Png };
        let mut r = reader(bytes, limits)?;
        r.set_format(format);
        let (w, h) = r.into_dimensions().map_err(|e| TextureError::Decode(e.to_string()))?;
        check_dims(w, h, limits)?;
        let mime = if is_jpeg { "image/jpeg" } else { "image/png" };
        return Ok(Encoded { mime, bytes: bytes.to_vec(), width: w, height: h });
    }
    let mut r = reader(bytes, limits)?;
    match image::ImageFormat::from_extension(ext) {
        Some(f) => r.set_format(f),
        None => {
            r = r.with_guessed_format().map_err(|e| TextureError::Decode(e.to_string()))?;
        }
    }
    let img = r.decode().map_err(|e| TextureError::Decode(e.to_string()))?;
    check_dims(img.width(), img.height(), limits)?;
    let (w, h) = (img.width(), img.height());
    let bytes = if img.color().has_alpha() {
        png_bytes(img.to_rgba8().as_raw(), w, h, image::ExtendedColorType::Rgba8)?
    } else {
        png_bytes(img.to_rgb8().as_raw(), w, h, image::ExtendedColorType::Rgb8)?
    };
    Ok(Encoded { mime: "image/png", bytes, width: w, height: h })
}

/// Encodes raw 8-bit pixels as PNG (fast deflate: conversion speed matters more than the
/// last percent of size).
pub fn png_bytes(pixels: &[u8], w: u32, h: u32, color: image::ExtendedColorType) -> Result<Vec<u8>, TextureError> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    let enc = image::codecs::png::PngEncoder::new_with_quality(
        &mut out,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Adaptive,
    );
    enc.write_image(pixels, w, h, color).map_err(|e| TextureError::Decode(e.to_string()))?;
    Ok(out)
}

/// The image used for textures that cannot be found: an 8x8 magenta and black checker,
/// impossible to mistake for a real texture.
pub fn placeholder() -> Encoded {
    let mut px = Vec::with_capacity(8 * 8 * 3);
    for y in 0..8 {
        for x in 0..8 {
            px.extend_from_slice(if (x / 2 + y / 2) % 2 == 0 { &[255, 0, 255] } else { &[0, 0, 0] });
        }
    }
    Encoded { mime: "image/png", bytes: png_bytes(&px, 8, 8, image::ExtendedColorType::Rgb8).unwrap_or_default(), width: 8, height: 8 }
}

/// Decodes an image to RGBA8. `ext` (the file's extension) names the format when the
/// content has no magic bytes (TGA); content with magic bytes wins.
pub fn decode_rgba(bytes: &[u8], ext: &str, limits: Limits) -> Result<image::RgbaImage, TextureError> {
    let mut r = reader(bytes, limits)?.with_guessed_format().map_err(|e| TextureError::Decode(e.to_string()))?;
    if r.format().is_none() {
        if let Some(f) = image::ImageFormat::from_extension(ext) {
            r.set_format(f);
        }
    }
    let img = r.decode().map_err(|e| TextureError::Decode(e.to_string()))?;
    Ok(img.to_rgba8())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tga_becomes_png_and_png_is_copied() {
        let mut tga = Vec::new();
        let img = image::RgbImage::from_fn(3, 2, |x, y| image::Rgb([x as u8 * 80, y as u8 * 100, 7]));
        img.write_to(&mut Cursor::new(&mut tga), image::ImageFormat::Tga).unwrap();
        let e = encode_for_gltf(&tga, "tga", Limits::default()).unwrap();
        assert_eq!(e.mime, "image/png");
        let back = decode_rgba(&e.bytes, "png", Limits::default()).unwrap();
        assert_eq!(back.get_pixel(2, 1).0, [160, 100, 7, 255]);
        let again = encode_for_gltf(&e.bytes, "png", Limits::default()).unwrap();
        assert_eq!(again.bytes, e.bytes);
    }

    #[test]
    fn limits_and_garbage() {
        let big = image::RgbImage::new(64, 2);
        let mut tga = Vec::new();
        big.write_to(&mut Cursor::new(&mut tga), image::ImageFormat::Tga).unwrap();
        assert!(encode_for_gltf(&tga, "tga", Limits { max_side: 32, max_alloc: 1 << 20 }).is_err());
        assert!(encode_for_gltf(b"not an image at all", "tga", Limits::default()).is_err());
        assert!(encode_for_gltf(&[0xFF, 0xD8, 0xFF, 0x00], "jpg", Limits::default()).is_err());
    }
}
