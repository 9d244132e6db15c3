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

/// Finds the pages of `bsp`. `map_name` is the map's file stem (for external pages).
pub fn gather(bsp: &Bsp, vfs: &Vfs, map_name: &str, limits: Limits) -> Pages {
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
        // Indices come from the file: bound the number of pages we try.
        let n = (max_used as usize + 1).min(4096);
        (0..n)
            .map(|i| {
                let name = format!("maps/{map_name}/lm_{i:04}.tga");
                match vfs.read(&name) {
                    Ok(bytes) => match crate::texture::decode_rgba(&bytes, "tga", limits) {
                        Ok(img) => {
                            let (w, h) = (img.width() as usize, img.height() as usize);
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
            .collect()
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
