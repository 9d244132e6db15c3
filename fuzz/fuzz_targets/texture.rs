//! The texture path: the glTF encoder (JPEG/PNG header check or TGA decode and PNG
//! re-encode) and the RGBA decoder used for external lightmaps. The first byte picks the
//! extension the file would have had.
#![no_main]
use libfuzzer_sys::fuzz_target;
use q3gltf_convert::texture::{decode_rgba, encode_for_gltf};

#[global_allocator]
static ALLOC: q3gltf_fuzz::Guard = q3gltf_fuzz::Guard;

fuzz_target!(|data: &[u8]| {
    let Some((&pick, bytes)) = data.split_first() else { return };
    let ext = ["tga", "jpg", "png", "bmp"][pick as usize % 4];
    let limits = q3gltf_fuzz::texture_limits();
    if let Ok(e) = encode_for_gltf(bytes, ext, limits) {
        assert!(e.width >= 1 && e.height >= 1 && e.width <= limits.max_side && e.height <= limits.max_side);
    }
    if let Ok(img) = decode_rgba(bytes, ext, limits) {
        assert!(img.width() <= limits.max_side && img.height() <= limits.max_side);
    }
});
