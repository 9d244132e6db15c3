//! Texture lookups shared by the CPU target projection and mirrored, operation for
//! operation, by `shaders/target.wgsl`: bilinear filtering with the glTF wrap modes (texel
//! centres at half-integers, UV origin top-left), sRGB decoding, and the censoring test of
//! lightmap texels (a channel stored as 255 is a lower bound, CONVENTIONS.md).

use crate::scene::{Texture, Wrap};

/// sRGB transfer function, decoded to linear [0, 1].
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// [`srgb_to_linear`] of every stored byte `b` (as `b / 255`), the same bits: a bilinear
/// lookup decodes each of its four taps, and the power function was most of its cost.
static SRGB_BYTE_TO_LINEAR: std::sync::LazyLock<[f32; 256]> = std::sync::LazyLock::new(|| std::array::from_fn(|b| srgb_to_linear(b as f32 / 255.0)));

/// [`srgb_to_linear`] of a stored byte (as `b / 255`), from a table.
pub fn srgb_byte_to_linear(b: u8) -> f32 {
    SRGB_BYTE_TO_LINEAR[b as usize]
}

fn wrap_index(i: i64, n: u32, mode: Wrap) -> u32 {
    let n = n.max(1) as i64;
    if (0..n).contains(&i) {
        // Inside the texture every mode is the identity.
        return i as u32;
    }
    let r = match mode {
        Wrap::Clamp => i.clamp(0, n - 1),
        Wrap::Repeat => i.rem_euclid(n),
        Wrap::Mirror => {
            let p = i.rem_euclid(2 * n);
            if p < n {
                p
            } else {
                2 * n - 1 - p
            }
        }
    };
    r as u32
}

/// Texel coordinates are clamped to +-2^24 before rounding, so that absurd UVs (finite but
/// huge) index the texture the same way here and on the GPU, whose integers are 32 bits.
pub const COORD_LIMIT: f32 = 16_777_216.0;

fn coord(u: f32, size: u32) -> f32 {
    (u * size as f32).clamp(-COORD_LIMIT, COORD_LIMIT)
}

/// The texel holding `uv` (nearest filtering), after wrapping.
pub fn nearest(tex: &Texture, u: f32, v: f32) -> [u8; 4] {
    let x = coord(u, tex.width).floor() as i64;
    let y = coord(v, tex.height).floor() as i64;
    texel(tex, x, y)
}

fn texel(tex: &Texture, x: i64, y: i64) -> [u8; 4] {
    let x = wrap_index(x, tex.width, tex.wrap_s);
    let y = wrap_index(y, tex.height, tex.wrap_t);
    let o = (y as usize * tex.width as usize + x as usize) * 4;
    [tex.rgba8[o], tex.rgba8[o + 1], tex.rgba8[o + 2], tex.rgba8[o + 3]]
}

/// Bilinear lookup of the stored values after `decode` is applied to every tap's byte
/// (decoding before filtering, as GPUs do for sRGB textures; a decoder of `b / 255` in
/// [0, 1] reads the stored value).
pub fn bilinear(tex: &Texture, u: f32, v: f32, decode: impl Fn(u8) -> f32) -> [f32; 3] {
    let fx = coord(u, tex.width) - 0.5;
    let fy = coord(v, tex.height) - 0.5;
    let x0 = fx.floor();
    let y0 = fy.floor();
    let (tx, ty) = (fx - x0, fy - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let mut out = [0.0f32; 3];
    for (dx, dy, w) in [(0, 0, (1.0 - tx) * (1.0 - ty)), (1, 0, tx * (1.0 - ty)), (0, 1, (1.0 - tx) * ty), (1, 1, tx * ty)] {
        let t = texel(tex, x0 + dx, y0 + dy);
        for c in 0..3 {
            out[c] += w * decode(t[c]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table is the transfer function, bit for bit, at every byte.
    #[test]
    fn the_srgb_table_is_the_transfer_function_at_every_byte() {
        for b in 0..=255u8 {
            assert_eq!(srgb_byte_to_linear(b).to_bits(), srgb_to_linear(b as f32 / 255.0).to_bits(), "byte {b}");
        }
    }

    /// Inside the texture every wrap mode is the identity; outside, each wraps as glTF says.
    #[test]
    fn wrapping_is_the_identity_inside_and_each_mode_outside() {
        for mode in [Wrap::Clamp, Wrap::Repeat, Wrap::Mirror] {
            for i in 0..5 {
                assert_eq!(wrap_index(i, 5, mode), i as u32);
            }
        }
        assert_eq!([wrap_index(-1, 5, Wrap::Clamp), wrap_index(7, 5, Wrap::Clamp)], [0, 4]);
        assert_eq!([wrap_index(-1, 5, Wrap::Repeat), wrap_index(7, 5, Wrap::Repeat)], [4, 2]);
        assert_eq!([wrap_index(-1, 5, Wrap::Mirror), wrap_index(7, 5, Wrap::Mirror)], [0, 2]);
        assert_eq!(wrap_index(3, 0, Wrap::Repeat), 0, "an empty texture reads its one placeholder texel");
    }
}
