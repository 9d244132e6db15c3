//! Baking: the lighting a scene's own light sources give, rendered with relight's forward
//! model into the scene's lightmap layout, next to the original lightmaps and their
//! difference. What a user looks at to see where a fit matches the baked lighting and
//! where not, and HDR lightmaps for engines that still use them.
//!
//! Data flow: [`crate::io::gltf_in`] reads the scene; [`crate::model::stated`] turns what
//! the file states (its lights, sun, emission and relight's recorded terms) into a
//! [`Model`](crate::model::Model); [`crate::pipeline::render_on`] evaluates it on the luxel
//! rows (every term: shadows, surfaces, sky, dirt, filter, bounces); [`page`] lays the
//! rows' values out on their lightmap pages; [`encode`] writes them. Every file is staged
//! and renamed into `OUTDIR` together ([`q3gltf_convert::output::Staged`]).
//!
//! Values are the lightmap's linear units: `e = E / pi` (the radiance of a white
//! Lambertian surface, W/(m^2 sr); CONVENTIONS.md), the same `e` the original decodes to
//! (each byte at the middle of the interval it stands for). Per page `NAME`:
//!
//! - `NAME.relit.exr`: the model's `e`, padded by [`Options::padding`] texels around the
//!   charts; alpha 1 where a texel has a row;
//! - `NAME.original.exr`: the original lightmap decoded, padded alike;
//! - `NAME.residual.exr`: how far the relit `e` lies outside the interval the original
//!   byte stands for (`[b, b + 1)`, [`crate::scene::Material::interval`]): 0 where the
//!   byte agrees, signed; where the original has a channel at 255 (a lower bound) only a
//!   shortfall counts; 0 on texels without a row;
//! - with previews, `NAME.{relit,original,residual}.png` ([`encode`]);
//! - `baked.glb`: the scene with the relit pages in place of its lightmaps, in the
//!   lightmaps' own 8-bit encoding ([`crate::io::baked_gltf`]);
//! - `bake.json`: the [`Report`].
//!
//! New lightmap coordinates: geometry without them (a mesh added in Blender), or all of it
//! with [`Options::new_uvs`], is charted into one new atlas (`lightmap_atlas`, [`crate::atlas`])
//! at [`Options::texel_m`] before the render, and the scene rendered is the one written to
//! `baked.glb`. The atlas page has no original, so no `original`/`residual` files; the
//! relative error counts only the pages that have one.
//!
//! The relative error reported is relight's own ([`crate::rows`]: the byte intervals,
//! censored texels as lower bounds) over the lightmap texels, so it matches the error a
//! relight run reports for the model it wrote (which also counts vertex-lit surfaces).

pub mod encode;
pub mod page;

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use crate::error::{Error, Result};
use crate::io::{baked_gltf, gltf_in};
use crate::model::stated;
use crate::pipeline::{render_on, BackendChoice};
use page::Page;

#[derive(Debug, Clone)]
pub struct Options {
    pub input: PathBuf,
    pub out_dir: PathBuf,
    /// Passes of bounced light; `None`: as the file records (`q3_relight.bounces`, 0 if absent).
    pub bounces: Option<usize>,
    /// Rays per row of the bounce operator (0: as relight chooses,
    /// [`crate::model::bounce::rays_for`]).
    pub bounce_rays: usize,
    /// EXR samples as 16-bit floats (else 32-bit).
    pub half: bool,
    /// Texels of padding around the charts of the relit and original pages.
    pub padding: u32,
    /// Write PNG previews.
    pub previews: bool,
    pub backend: BackendChoice,
    /// Chart every lightmapped surface into a new atlas, not only those without lightmap
    /// coordinates.
    pub new_uvs: bool,
    /// Texel size of a new atlas, meters; `None`: the scene's own lightmap density
    /// ([`lightmap_texel_m`]), else q3map2's default sample size, 16 Quake units
    /// ([`DEFAULT_SAMPLE_UNITS`]) at the scene's scale.
    pub texel_m: Option<f32>,
}

/// q3map2's default lightmap sample size (`-samplesize`), Quake units per luxel.
pub const DEFAULT_SAMPLE_UNITS: f32 = 16.0;
/// Largest side of a new atlas, texels.
pub const MAX_ATLAS_SIDE: u32 = 8192;

/// One lightmap page of the bake.
#[derive(Debug, Clone, Serialize)]
pub struct PageReport {
    pub name: String,
    /// Index of the lightmap among the scene's textures (relight's reading order).
    pub texture: usize,
    pub width: u32,
    pub height: u32,
    /// Texels with a row (the rest is padding or unused).
    pub texels: usize,
    /// Texels whose original has a channel at 255 (the data is only a lower bound).
    pub censored: usize,
    /// Mean `e` over the covered texels, per channel.
    pub relit_mean: [f64; 3],
    /// The page of a new atlas: no original, no residual (the fields below are `None`).
    pub new: bool,
    pub original_mean: Option<[f64; 3]>,
    /// Root mean square and largest magnitude of the residual's channels over covered
    /// texels, in `e`.
    pub residual_rms: Option<f64>,
    pub residual_max_abs: Option<f64>,
}

/// What a bake made (also written as `OUTDIR/bake.json`).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub input: String,
    pub out_dir: String,
    pub backend: String,
    /// Terms of the stated model.
    pub lights: usize,
    pub sun: bool,
    pub sky: bool,
    pub surface_lights: usize,
    pub ambient: Option<[f32; 3]>,
    pub minlight: Option<[f32; 3]>,
    pub bounces: usize,
    /// q3map2's dirt and its settings, where the stated model has it.
    pub dirt: Option<crate::model::compile::DirtSettings>,
    pub filter: bool,
    pub notes: Vec<String>,
    /// Luxel rows rendered (vertex-lit surfaces have no lightmap and are not baked).
    pub luxels: usize,
    /// Relight's relative error of the stated model against the original lightmaps (pages
    /// that have one; `None` when every page is new).
    pub rel_error: Option<f64>,
    /// The new atlas, when one was made.
    pub atlas: Option<crate::io::baked_gltf::NewAtlas>,
    /// The residual previews' colour map spans `[-residual_range, residual_range]` in
    /// luminance of `e`.
    pub residual_range: f64,
    pub pages: Vec<PageReport>,
    /// Files written, relative to `out_dir`.
    pub files: Vec<String>,
    /// Seconds per stage.
    pub stages: Vec<(String, f64)>,
    pub seconds: f64,
}

/// Progress of a bake, for the command line.
pub trait Progress {
    fn stage(&self, name: &str);
}

/// No display.
pub struct Quiet;
impl Progress for Quiet {
    fn stage(&self, _: &str) {}
}

/// The texel size of a scene's lightmaps, meters: `sqrt(world area / texel area)` over
/// its lightmapped triangles (q3map2's `-samplesize`, or a map's `_lightmapscale`, times
/// the scale). `None` without lightmapped area.
pub fn lightmap_texel_m(scene: &crate::scene::Scene) -> Option<f32> {
    let m = &scene.mesh;
    let (mut world, mut texels) = (0.0f64, 0.0f64);
    for t in 0..m.triangles.len() {
        let Some(area_t) = crate::rows::projection::lightmap_texels(m, &scene.materials, &scene.textures, t).filter(|a| a.is_finite()) else { continue };
        world += m.triangle_area(t) as f64;
        texels += area_t as f64;
    }
    let s = (world / texels).sqrt();
    (texels > 0.0 && s.is_finite() && s > 0.0).then_some(s as f32)
}

pub fn run(opts: &Options, progress: &dyn Progress) -> Result<Report> {
    let t0 = Instant::now();
    let mut stages: Vec<(String, f64)> = Vec::new();
    let mut t = Instant::now();
    let mut done = |name: &str, t: &mut Instant| {
        stages.push((name.to_string(), t.elapsed().as_secs_f64()));
        *t = Instant::now();
    };
    progress.stage("read");
    let scene0 = gltf_in::read(&opts.input)?;
    done("read", &mut t);
    let texel_m = opts.texel_m.or_else(|| lightmap_texel_m(&scene0)).unwrap_or(DEFAULT_SAMPLE_UNITS * scene0.units_m);
    if !(texel_m.is_finite() && texel_m > 0.0) {
        return Err(Error::Usage(format!("texel size {texel_m} m is not positive")));
    }
    let plan = baked_gltf::Plan { all: opts.new_uvs, atlas: crate::atlas::Options { texels_per_m: 1.0 / texel_m, padding: opts.padding.max(1), max_size: MAX_ATLAS_SIDE } };
    progress.stage("atlas");
    let mut baked = baked_gltf::relayout(&opts.input, &scene0, &plan)?;
    let mut scene = match &baked.atlas {
        Some(_) => gltf_in::read_slice(&baked.to_glb()?, None, &opts.input, &gltf_in::Limits::default())?,
        None => scene0,
    };
    let mut notes = std::mem::take(&mut baked.notes);
    // Scene textures of the new atlas (no original).
    let new_textures: Vec<usize> = baked.atlas.as_ref().map_or(Vec::new(), |a| a.materials.iter().filter_map(|&m| scene.materials.get(m).and_then(|m| m.lightmap)).collect());
    done("atlas", &mut t);
    let st = stated::stated(&mut scene, opts.bounces);
    notes.extend(st.notes.iter().cloned());

    progress.stage("render");
    let r = render_on(&scene, &st.model, st.bounces, opts.bounce_rays, opts.backend)?;
    done("render", &mut t);
    // Luxel rows only: `render_on` makes no rows for vertex-lit surfaces.
    let rows = &r.rows;
    let luxels = rows.len();
    if luxels == 0 {
        return Err(Error::unsupported(&opts.input, "no lightmapped surface (no lightmap on TEXCOORD_1): nothing to bake"));
    }

    // e per row: the model's, and the original byte's (the middle of its interval).
    let pi = std::f64::consts::PI;
    let relit: Vec<[f64; 3]> = r.irradiance.iter().map(|e| e.map(|v| v / pi)).collect();
    let mut censored_row = vec![false; rows.len()];
    // Per row and channel: the byte's interval of e.
    let mut interval = vec![[(0.0f64, 0.0f64); 3]; rows.len()];
    let original: Vec<[f64; 3]> = (0..rows.len())
        .map(|i| {
            let [tex, x, y] = rows.texel[i];
            let (Some(t), Some(m)) = (scene.textures.get(tex as usize), scene.materials.get(rows.material[i] as usize)) else { return [0.0; 3] };
            let o = (y as usize * t.width as usize + x as usize) * 4;
            let b = [t.rgba8[o], t.rgba8[o + 1], t.rgba8[o + 2]];
            censored_row[i] = m.censored(&b);
            interval[i] = b.map(|v| {
                let (lo, hi) = m.interval(v);
                (lo as f64, hi as f64)
            });
            b.map(|v| m.decode(v as f32 / 255.0) as f64)
        })
        .collect();
    // Distance outside the byte's interval; a censored texel is a lower bound, so only
    // falling short of it counts.
    let residual: Vec<[f64; 3]> = (0..rows.len())
        .map(|i| {
            [0, 1, 2].map(|c| {
                let (v, (lo, hi)) = (relit[i][c], interval[i][c]);
                if censored_row[i] {
                    (v - lo).min(0.0)
                } else {
                    v - v.clamp(lo, hi.max(lo))
                }
            })
        })
        .collect();
    let mut censored_on = vec![0usize; scene.textures.len()];
    for (i, &c) in censored_row.iter().enumerate() {
        censored_on[rows.texel[i][0] as usize] += c as usize;
    }

    let mut relit_pages = page::splat(rows, &relit, &scene.textures);
    let mut original_pages = page::splat(rows, &original, &scene.textures);
    let residual_pages = page::splat(rows, &residual, &scene.textures);
    let is_new = |tex: usize| new_textures.contains(&tex);
    let rel_error = if new_textures.is_empty() {
        Some(rows.rel_error(&r.radiance))
    } else {
        let keep: Vec<usize> = (0..rows.len()).filter(|&i| !is_new(rows.texel[i][0] as usize)).collect();
        let radiance: Vec<[f64; 3]> = keep.iter().map(|&i| r.radiance[i]).collect();
        (!keep.is_empty()).then(|| rows.subset(&keep).rel_error(&radiance))
    };

    // One colour scale for every residual preview: the 99th percentile of |luminance|,
    // at least one byte of the default encoding.
    let mut mags: Vec<f32> = residual_pages.iter().filter(|p| !is_new(p.texture)).flat_map(|p| p.rgb.iter().zip(&p.covered).filter(|(_, c)| **c).map(|(v, _)| encode::luminance(*v).abs())).collect();
    mags.sort_by(f32::total_cmp);
    let p99 = mags.get(((mags.len() as f64 * 0.99) as usize).min(mags.len().saturating_sub(1))).copied().unwrap_or(0.0);
    let residual_range = (p99 as f64).max(4.0 / 255.0);

    let mut pages = Vec::new();
    for ((rp, op), dp) in relit_pages.iter().zip(&original_pages).zip(&residual_pages) {
        let name = format!("lightmap_{:03}", rp.texture);
        let mean = |p: &Page| -> [f64; 3] {
            let mut s = [0.0f64; 3];
            let mut n = 0usize;
            for (v, c) in p.rgb.iter().zip(&p.covered) {
                if *c {
                    (0..3).for_each(|k| s[k] += v[k] as f64);
                    n += 1;
                }
            }
            s.map(|v| v / n.max(1) as f64)
        };
        let (mut sq, mut n, mut mx) = (0.0f64, 0usize, 0.0f64);
        for (v, c) in dp.rgb.iter().zip(&dp.covered) {
            if *c {
                for k in 0..3 {
                    sq += (v[k] as f64).powi(2);
                    mx = mx.max((v[k] as f64).abs());
                }
                n += 3;
            }
        }
        let new = is_new(rp.texture);
        pages.push(PageReport {
            name: if new { "lightmap_atlas".into() } else { name },
            texture: rp.texture,
            width: rp.width,
            height: rp.height,
            texels: rp.texels_covered(),
            censored: if new { 0 } else { censored_on[rp.texture] },
            relit_mean: mean(rp),
            new,
            original_mean: (!new).then(|| mean(op)),
            residual_rms: (!new).then(|| (sq / n.max(1) as f64).sqrt()),
            residual_max_abs: (!new).then_some(mx),
        });
    }
    for p in relit_pages.iter_mut().chain(original_pages.iter_mut()) {
        page::pad(p, opts.padding);
    }
    done("pages", &mut t);

    progress.stage("write");
    let mut staged = q3gltf_convert::output::Staged::new();
    let io = |source: std::io::Error, p: &Path| Error::Io { path: p.display().to_string(), source };
    staged.create_dir_all(&opts.out_dir).map_err(|e| io(e, &opts.out_dir))?;
    let mut files = Vec::new();
    let mut add = |staged: &mut q3gltf_convert::output::Staged, name: String, bytes: Vec<u8>| -> Result<()> {
        let path = opts.out_dir.join(&name);
        staged.add(&path, &bytes).map_err(|e| io(e, &path))?;
        files.push(name);
        Ok(())
    };
    // The lightmap images of the baked glTF: each page in its material's encoding.
    // A page is encoded once, with the overbright bits of the first material that shows
    // it; every material showing it is told those bits.
    let mut page_png: Vec<Option<(Vec<u8>, u32)>> = vec![None; pages.len()];
    for (material, image) in baked.lightmap_images() {
        let Some(m) = scene.materials.get(material) else { continue };
        let Some(k) = m.lightmap.and_then(|t| pages.iter().position(|p| p.texture == t)) else { continue };
        if page_png[k].is_none() {
            page_png[k] = Some((encode::preview(&relit_pages[k], m.overbright_bits, 255.0 * m.stored_per_light_byte())?, m.overbright_bits));
        }
        let (png, ob) = page_png[k].as_ref().unwrap();
        baked.set_image(image, png, *ob);
    }
    for (k, p) in pages.iter().enumerate() {
        let (ob, top) = scene.materials.iter().find(|m| m.lightmap == Some(p.texture)).map_or((2, 255.0), |m| (m.overbright_bits, 255.0 * m.stored_per_light_byte()));
        let kinds: &[(&str, &Page)] = if p.new { &[("relit", &relit_pages[k])] } else { &[("relit", &relit_pages[k]), ("original", &original_pages[k]), ("residual", &residual_pages[k])] };
        for &(kind, pg) in kinds {
            add(&mut staged, format!("{}.{kind}.exr", p.name), encode::exr(pg, opts.half)?)?;
            if opts.previews {
                let png = match (kind, &page_png[k]) {
                    ("residual", _) => encode::residual_preview(pg, residual_range as f32)?,
                    ("relit", Some((png, _))) => png.clone(),
                    _ => encode::preview(pg, ob, top)?,
                };
                add(&mut staged, format!("{}.{kind}.png", p.name), png)?;
            }
        }
    }
    add(&mut staged, "baked.glb".into(), baked.to_glb()?)?;
    let m = &st.model;
    let mut report = Report {
        input: opts.input.display().to_string(),
        out_dir: opts.out_dir.display().to_string(),
        backend: r.backend.clone(),
        lights: m.lights.len(),
        sun: m.sun.is_some(),
        sky: m.sky.is_some(),
        surface_lights: m.surfaces.iter().filter(|s| s.is_some()).count(),
        ambient: m.ambient,
        minlight: m.minlight,
        bounces: if m.bounce.is_some() { st.bounces } else { 0 },
        dirt: m.dirt,
        filter: m.filter,
        notes,
        luxels,
        rel_error,
        atlas: baked.atlas.clone(),
        residual_range,
        pages,
        files,
        stages,
        seconds: 0.0,
    };
    report.files.push("bake.json".into());
    report.seconds = t0.elapsed().as_secs_f64();
    let json = serde_json::to_vec_pretty(&report).map_err(|e| Error::Usage(format!("bake report: {e}")))?;
    let path = opts.out_dir.join("bake.json");
    staged.add(&path, &json).map_err(|e| io(e, &path))?;
    staged.commit().map_err(|e| io(e, &opts.out_dir))?;
    Ok(report)
}
