//! The bake's glTF editing on `.gltf` / `.glb` bytes held in memory: every surface that
//! relight reads is charted into a new atlas (xatlas) and the edited file is written.
//! Whatever relayout accepts, it writes a file that relight reads back with the same
//! triangles.
#![no_main]
use libfuzzer_sys::fuzz_target;
use q3gltf_relight::atlas;
use q3gltf_relight::io::baked_gltf::{relayout_bytes, Plan};
use q3gltf_relight::io::gltf_in::{read_slice, Limits};

#[global_allocator]
static ALLOC: q3gltf_fuzz::Guard = q3gltf_fuzz::Guard;

fuzz_target!(|data: &[u8]| {
    let limits = Limits { max_elements: 20_000, max_image_side: 512, max_image_bytes: 16 << 20 };
    let shown = std::path::Path::new("fuzz.glb");
    let Ok(scene) = read_slice(data, None, shown, &limits) else { return };
    // A small atlas: large or far-flung geometry is refused before xatlas runs.
    let plan = Plan { all: true, atlas: atlas::Options { texels_per_m: 4.0, padding: 1, max_size: 512 } };
    if let Ok(rl) = relayout_bytes(data, shown, &scene, &plan) {
        let glb = rl.to_glb().expect("a relayout that succeeded writes its file");
        let again = read_slice(&glb, None, shown, &Limits::default()).expect("relight reads what relayout wrote");
        assert_eq!(again.mesh.triangles.len(), scene.mesh.triangles.len());
    }
});
