//! The BSP reader, then the whole scene build on what it accepts (shaders, entities,
//! lightmap pages and atlas, patch tessellation), with an empty file system.
#![no_main]
use libfuzzer_sys::fuzz_target;
use q3gltf_convert::bsp::Bsp;
use q3gltf_convert::pipeline::{build_scene, LoadedMap, Options};
use q3gltf_convert::vfs::Vfs;

#[global_allocator]
static ALLOC: q3gltf_fuzz::Guard = q3gltf_fuzz::Guard;

fuzz_target!(|data: &[u8]| {
    let Ok(bsp) = Bsp::parse(data) else { return };
    // The writer must accept whatever the reader accepted, and read back what it wrote.
    let again = Bsp::parse(&bsp.to_bytes()).expect("re-reading our own output");
    assert_eq!(again.surfaces.len(), bsp.surfaces.len());
    // Lower work limits than a conversion's defaults: every input must finish well inside
    // libFuzzer's 20 s under AddressSanitizer and coverage (about 20 times slower than
    // release); the code paths are the same, only the counts are smaller.
    let opts = Options {
        max_patch_vertices: 50_000,
        overlap_work_budget: 1_000_000,
        texture_limits: q3gltf_fuzz::texture_limits(),
        ..Options::default()
    };
    let map = LoadedMap { vfs: Vfs::new(), bsp, name: "fuzz".into(), shown: "fuzz.bsp".into(), path: None };
    let _ = build_scene(&map, &opts, &|_| {});
});
