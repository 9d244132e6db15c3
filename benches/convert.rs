//! Conversion speed on the OpenArena maps of pak1-maps.pk3: median of several runs per
//! map (release build, warm file cache), with the time per stage, printed and saved as
//! a Markdown table to `out/bench/convert.md`. Run with `make bench`.
//!
//! Environment: `BENCH_RUNS` (default 3), `BENCH_MAPS` (comma-separated subset).

use q3gltf_convert::pipeline::{convert, MapSource, Options};
use std::fmt::Write as _;
use std::path::PathBuf;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let out = std::process::Command::new("bash").arg(repo.join("samples/fetch-openarena.sh")).output().expect("fetch script");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let baseoa = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim());
    let runs: usize = std::env::var("BENCH_RUNS").ok().and_then(|s| s.parse().ok()).unwrap_or(3).max(1);
    let mut vfs = q3gltf_convert::vfs::Vfs::new();
    vfs.mount_pk3(&baseoa.join("pak1-maps.pk3")).unwrap();
    let mut maps: Vec<String> = vfs.list("maps", "bsp").iter().map(|m| m.trim_start_matches("maps/").trim_end_matches(".bsp").to_string()).collect();
    if let Ok(sel) = std::env::var("BENCH_MAPS") {
        let sel: Vec<&str> = sel.split(',').collect();
        maps.retain(|m| sel.contains(&m.as_str()));
    }
    let tmp = std::env::temp_dir().join(format!("q3gltf-bench-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let opts = Options { game_dirs: vec![baseoa.clone()], ..Options::default() };
    let stages = ["read", "shaders", "lightmaps", "patches", "meshes", "textures", "entities", "write"];
    let mut table = String::new();
    let _ = writeln!(table, "| map | triangles | total ms | {} |", stages.join(" ms | ") + " ms");
    let _ = writeln!(table, "|---|---:|---:|{}", "---:|".repeat(stages.len()));
    print!("{table}");
    let mut sum = 0.0;
    for m in &maps {
        let mut totals = Vec::new();
        let mut per_stage: Vec<Vec<f64>> = vec![Vec::new(); stages.len()];
        let mut tris = 0;
        // One warm-up run fills the file cache; it is not counted.
        for run in 0..=runs {
            let s = convert(&MapSource::Name(m.clone()), &tmp.join("m.glb"), &opts, &|_| {}).unwrap();
            if run == 0 {
                continue;
            }
            tris = s.triangles;
            let get = |k: &str| s.timings.iter().find(|(n, _)| n == k).map(|(_, v)| *v).unwrap_or(0.0);
            totals.push(get("total"));
            for (i, st) in stages.iter().enumerate() {
                per_stage[i].push(get(st));
            }
        }
        let total = median(totals);
        sum += total;
        let cols: Vec<String> = per_stage.into_iter().map(|v| format!("{:.1}", median(v) * 1e3)).collect();
        let line = format!("| {m} | {tris} | {:.1} | {} |\n", total * 1e3, cols.join(" | "));
        print!("{line}");
        table.push_str(&line);
    }
    let foot = format!("\n{} maps, sum of medians {:.2} s ({} runs each, release build, one thread per conversion plus rayon for textures)\n", maps.len(), sum, runs);
    print!("{foot}");
    table.push_str(&foot);
    let dir = repo.join("out/bench");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("convert.md"), table).unwrap();
    println!("saved {}", dir.join("convert.md").display());
    let _ = std::fs::remove_dir_all(&tmp);
}
