//! Gathering a map's lightmap pages: from lump 14, or from external `lm_NNNN.tga`
//! images (q3map2 `-external` or a `-lightmapsize` other than 128), without the direction
//! pages of deluxe maps. The pages are then packed by [`crate::atlas`].

use crate::atlas::Page;
use crate::bsp::{Bsp, LIGHTMAP_SIZE};
use crate::texture::Limits;
use crate::vfs::Vfs;

/// Where the lighting pages came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PageSource {
    None,
    Lump,
    External,
}

/// The lighting pages of a map and how surface lightmap indices map onto them.
#[derive(Debug, Clone)]
pub struct Pages {
    pub pages: Vec<Page>,
    pub source: PageSource,
    /// Deluxe map: every lighting page is followed by a direction page.
    pub deluxe: bool,
    /// Problems that were worked around (missing or unreadable external pages).
    pub warnings: Vec<String>,
    /// Per raw surface lightmap index: the page in `pages`, if available.
    index: Vec<Option<usize>>,
}

impl Pages {
    /// The page of a surface's lightmap index, if the index names an available page.
    pub fn page_of(&self, lightmap: i32) -> Option<usize> {
        usize::try_from(lightmap).ok().and_then(|i| self.index.get(i).copied().flatten())
    }
}

/// Most external pages looked for (indices come from the file).
pub const MAX_EXTERNAL_PAGES: usize = 4096;
/// Most texels of external pages held at once (64 Mi texels, 192 MiB of RGB): pages past
/// the budget are left out with a warning (their surfaces use vertex colours).
pub const MAX_LIGHTMAP_TEXELS: u64 = 64 << 20;

/// Finds the pages of `bsp`. `map_name` is the map's file stem (for external pages).
pub fn gather(bsp: &Bsp, vfs: &Vfs, map_name: &str, limits: Limits) -> Pages {
    gather_within(bsp, vfs, map_name, limits, MAX_LIGHTMAP_TEXELS)
}

/// [`gather`] with an explicit texel budget for external pages.
pub fn gather_within(bsp: &Bsp, vfs: &Vfs, map_name: &str, limits: Limits, max_texels: u64) -> Pages {
    let used: Vec<i32> = bsp.surfaces.iter().map(|s| s.lightmap).filter(|&l| l >= 0).collect();
    let max_used = used.iter().copied().max();
    let mut out = Pages { pages: Vec::new(), source: PageSource::None, deluxe: false, warnings: Vec::new(), index: Vec::new() };
    let Some(max_used) = max_used else {
        return out;
    };
    let available = if !bsp.lightmaps.is_empty() {
        out.source = PageSource::Lump;
        bsp.lightmaps
            .iter()
            .map(|rgb| Some(Page { width: LIGHTMAP_SIZE, height: LIGHTMAP_SIZE, rgb: rgb.clone() }))
            .collect::<Vec<_>>()
    } else {
        out.source = PageSource::External;
        // Indices come from the file: bound the number of pages we try, and their texels.
        let n = (max_used as usize + 1).min(MAX_EXTERNAL_PAGES);
        let mut texels = 0u64;
        let mut missing = Vec::new();
        let mut over_budget = 0usize;
        let pages = (0..n)
            .map(|i| {
                let name = format!("maps/{map_name}/lm_{i:04}.tga");
                if !vfs.contains(&name) {
                    missing.push(name);
                    return None;
                }
                if texels >= max_texels {
                    over_budget += 1;
                    return None;
                }
                match vfs.read(&name) {
                    Ok(bytes) => match crate::texture::decode_rgba(&bytes, "tga", limits) {
                        Ok(img) => {
                            let (w, h) = (img.width() as usize, img.height() as usize);
                            if texels + (w * h) as u64 > max_texels {
                                over_budget += 1;
                                texels = max_texels;
                                return None;
                            }
                            texels += (w * h) as u64;
                            let rgb = img.pixels().flat_map(|p| [p.0[0], p.0[1], p.0[2]]).collect();
                            Some(Page { width: w, height: h, rgb })
                        }
                        Err(e) => {
                            out.warnings.push(format!("{name}: {e}"));
                            None
                        }
                    },
                    Err(e) => {
                        out.warnings.push(format!("external lightmap {e}"));
                        None
                    }
                }
            })
            .collect();
        if !missing.is_empty() {
            let shown: Vec<&str> = missing.iter().take(4).map(String::as_str).collect();
            let more = if missing.len() > 4 { format!(" and {} more", missing.len() - 4) } else { String::new() };
            out.warnings.push(format!("external lightmap pages not found: {}{more}", shown.join(", ")));
        }
        if over_budget > 0 {
            out.warnings.push(format!("{over_budget} external lightmap page(s) left out: over the budget of {max_texels} texels in all"));
        }
        pages
    };
    // Deluxe maps interleave direction pages: every used index is even and the page
    // count is even (q3map2 -deluxe).
    // With a single used page the pattern says nothing; keeping the pages is harmless.
    let distinct: std::collections::BTreeSet<i32> = used.iter().copied().collect();
    out.deluxe = distinct.len() >= 2 && available.len() % 2 == 0 && used.iter().all(|l| l % 2 == 0);
    let step = if out.deluxe { 2 } else { 1 };
    out.index = vec![None; available.len()];
    for (i, page) in available.into_iter().enumerate() {
        if i % step != 0 {
            continue;
        }
        if let Some(p) = page {
            out.index[i] = Some(out.pages.len());
            out.pages.push(p);
        }
    }
    if max_used as usize >= out.index.len() {
        out.warnings.push(format!("surfaces use lightmap {max_used} but the map has {} pages; those surfaces use vertex colours", out.index.len()));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsp::{Format, OtherCounts, Surface, SurfaceType};

    fn tga(w: u32, h: u32) -> Vec<u8> {
        let mut out = Vec::new();
        image::RgbImage::from_pixel(w, h, image::Rgb([9, 8, 7])).write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Tga).unwrap();
        out
    }

    fn bsp_using(indices: &[i32]) -> Bsp {
        Bsp {
            format: Format::Ibsp(46),
            entities: String::new(),
            shaders: Vec::new(),
            models: Vec::new(),
            verts: Vec::new(),
            indices: Vec::new(),
            surfaces: indices.iter().map(|&l| Surface { lightmap: l, ..Surface::new(0, SurfaceType::Flare) }).collect(),
            lightmaps: Vec::new(),
            collision: Default::default(),
            other: OtherCounts::default(),
        }
    }

    #[test]
    fn external_pages_are_bounded_in_count_and_texels() {
        use std::io::Write;
        let mut buf = std::io::Cursor::new(Vec::new());
        {
            let mut z = zip::ZipWriter::new(&mut buf);
            for i in 0..3 {
                z.start_file(format!("maps/t/lm_{i:04}.tga"), zip::write::SimpleFileOptions::default()).unwrap();
                z.write_all(&tga(64, 64)).unwrap();
            }
            z.finish().unwrap();
        }
        let mut vfs = Vfs::new();
        vfs.mount_pk3_bytes("t.pk3", buf.into_inner()).unwrap();
        // Budget for two of the three pages; page 3 does not exist; an absurd index is
        // looked for only up to MAX_EXTERNAL_PAGES.
        let bsp = bsp_using(&[0, 1, 2, 3, i32::MAX]);
        let p = gather_within(&bsp, &vfs, "t", Limits::default(), 2 * 64 * 64);
        assert_eq!(p.source, PageSource::External);
        assert_eq!(p.pages.len(), 2);
        assert_eq!((p.page_of(0), p.page_of(1), p.page_of(2), p.page_of(3)), (Some(0), Some(1), None, None));
        let w = p.warnings.join("\n");
        assert!(w.contains("1 external lightmap page(s) left out"), "{w}");
        assert!(w.contains("not found: maps/t/lm_0003.tga") && w.contains(&format!("and {} more", MAX_EXTERNAL_PAGES - 4 - 4 + 1)), "{w}");
        assert!(p.warnings.len() <= 4, "one line per kind of problem, not per page: {w}");
        // The default budget takes all three.
        assert_eq!(gather(&bsp, &vfs, "t", Limits::default()).pages.len(), 3);
    }
}
