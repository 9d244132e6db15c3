//! Writes the bundled sample (BSP, textures, shader script) into a game directory.
//!
//! Usage: make-sample [DIR]   (default: samples/sample)

fn main() -> std::process::ExitCode {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "samples/sample".into()));
    let sample = q3gltf_samples::generate();
    for (rel, bytes) in &sample.files {
        let path = dir.join(rel);
        if let Err(e) = path.parent().map(std::fs::create_dir_all).transpose().and_then(|_| q3gltf_convert::output::write_atomic(&path, bytes)) {
            eprintln!("make-sample: {}: {e}", path.display());
            return std::process::ExitCode::from(1);
        }
    }
    println!("sample map written to {} ({} files, {} lightmap pages)", dir.display(), sample.files.len(), sample.bsp.lightmaps.len());
    std::process::ExitCode::SUCCESS
}
