//! `q3gltf bake`: argument parsing, progress display and the summary; the work is
//! `q3gltf_relight::bake::run`.

use std::path::PathBuf;
use std::time::Duration;

use clap::Args;
use q3gltf_relight::bake::{self, Options, Progress};
use q3gltf_relight::pipeline::BackendChoice;

#[derive(Args)]
pub struct BakeArgs {
    /// Input scene (.gltf or .glb) with lightmaps on TEXCOORD_1: typically the output of
    /// `q3gltf relight`, or a converted scene (then its own emitters and, with
    /// `convert --lights-from`, the map's light entities are rendered).
    pub input: PathBuf,
    /// Output folder: per lightmap page `lightmap_NNN.{relit,original,residual}.exr`
    /// (linear e = E / pi, alpha = texel covered), PNG previews, baked.glb (the scene with
    /// the relit lightmaps in place of its own) and bake.json.
    #[arg(short, long, value_name = "OUTDIR")]
    pub output: PathBuf,
    /// Passes of bounced light (default: as relight recorded in the file, else none).
    #[arg(long)]
    pub bounces: Option<usize>,
    /// Rays per texel for the bounce operator. Default: as relight chooses (a budget of 2^20
    /// rays, 16 to 256 per texel).
    #[arg(long = "bounce-rays")]
    pub bounce_rays: Option<usize>,
    /// Write 16-bit float EXR samples (default 32-bit).
    #[arg(long)]
    pub half: bool,
    /// Texels of padding around each chart: rings filled around the charts of every page
    /// written, and the empty space kept between charts of a new atlas.
    #[arg(long, default_value_t = 2)]
    pub padding: u32,
    /// Chart every lightmapped surface into one new atlas (xatlas) at --texel-size, instead
    /// of keeping the map's lightmap layout. Surfaces without lightmap coordinates (meshes
    /// added in Blender) are charted in any case.
    #[arg(long = "new-uvs")]
    pub new_uvs: bool,
    /// Texel size of a new atlas, meters of surface per texel (default: that of the scene's
    /// own lightmaps; without any, q3map2's default 16 Quake units, 0.41 m at convert's
    /// scale). A quarter of it is four times as fine.
    #[arg(long = "texel-size", value_name = "METERS")]
    pub texel_size: Option<f32>,
    /// Skip the PNG previews.
    #[arg(long = "no-previews")]
    pub no_previews: bool,
    /// Where shadow rays and point lights run: `auto`, `wgpu`, `cpu`.
    #[arg(long, default_value = "auto", value_parser = ["auto", "wgpu", "cpu"])]
    pub backend: String,
    /// Also write the report (bake.json) here.
    #[arg(long, value_name = "report.json")]
    pub report: Option<PathBuf>,
    /// No progress display.
    #[arg(short, long)]
    pub quiet: bool,
}

struct Spinner {
    quiet: bool,
    bar: std::cell::RefCell<Option<indicatif::ProgressBar>>,
}

impl Progress for Spinner {
    fn stage(&self, name: &str) {
        if let Some(b) = self.bar.borrow_mut().take() {
            b.finish_and_clear();
        }
        if !self.quiet {
            let b = indicatif::ProgressBar::new_spinner();
            b.set_message(format!("bake: {name}"));
            b.enable_steady_tick(Duration::from_millis(120));
            *self.bar.borrow_mut() = Some(b);
        }
    }
}

pub fn run(a: BakeArgs) -> Result<(), String> {
    let opts = Options {
        input: a.input,
        out_dir: a.output,
        bounces: a.bounces,
        bounce_rays: a.bounce_rays.map_or(0, |r| r.clamp(1, 1024)),
        half: a.half,
        padding: a.padding.min(64),
        previews: !a.no_previews,
        new_uvs: a.new_uvs,
        texel_m: a.texel_size,
        backend: match a.backend.as_str() {
            "wgpu" => BackendChoice::Wgpu,
            "cpu" => BackendChoice::Cpu,
            _ => BackendChoice::Auto,
        },
    };
    let sp = Spinner { quiet: a.quiet, bar: Default::default() };
    let r = bake::run(&opts, &sp).map_err(|e| e.to_string())?;
    if let Some(b) = sp.bar.borrow_mut().take() {
        b.finish_and_clear();
    }
    if let Some(p) = &a.report {
        let json = serde_json::to_vec_pretty(&r).map_err(|e| e.to_string())?;
        q3gltf_convert::output::write_atomic(p, &json).map_err(|e| format!("{}: {e}", p.display()))?;
    }
    if !a.quiet {
        eprintln!(
            "baked {} lightmap pages ({} texels) of {}: {} lights{}{}{}, {} bounces, on {}",
            r.pages.len(),
            r.luxels,
            r.input,
            r.lights,
            if r.sun { ", sun" } else { "" },
            if r.sky { ", sky" } else { "" },
            if r.surface_lights > 0 { format!(", {} surface lights", r.surface_lights) } else { String::new() },
            r.bounces,
            r.backend
        );
        for n in &r.notes {
            eprintln!("  note: {n}");
        }
        match r.rel_error {
            Some(e) => eprintln!("relative error against the original lightmaps {e:.4}; residual previews span +-{:.4} (e, luminance)", r.residual_range),
            None => eprintln!("no original lightmap to compare with (every page is new)"),
        }
        if let Some(a) = &r.atlas {
            eprintln!(
                "new atlas {}x{} at {:.3} m per texel: {} charts, {} primitives, {} triangles ({} degenerate, without texels), {:.0}% used",
                a.width,
                a.height,
                a.texel_m,
                a.charts,
                a.primitives,
                a.triangles,
                a.ignored_triangles,
                100.0 * a.utilization
            );
        }
        for p in &r.pages {
            match (p.residual_rms, p.residual_max_abs) {
                (Some(rms), Some(mx)) => eprintln!("  {} {}x{}: {} texels, residual rms {:.4} max {:.4}", p.name, p.width, p.height, p.texels, rms, mx),
                _ => eprintln!("  {} {}x{}: {} texels (new, no original)", p.name, p.width, p.height, p.texels),
            }
        }
        let st: Vec<String> = r.stages.iter().map(|(n, s)| format!("{n} {s:.2}s")).collect();
        eprintln!("{} files in {} ({:.2} s: {})", r.files.len(), r.out_dir, r.seconds, st.join(", "));
    }
    Ok(())
}
