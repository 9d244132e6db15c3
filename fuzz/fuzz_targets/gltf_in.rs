//! relight's glTF reader on `.gltf` / `.glb` bytes held in memory (no base directory:
//! external URIs must be refused, never read).
#![no_main]
use libfuzzer_sys::fuzz_target;
use q3gltf_relight::io::gltf_in::{read_slice, Limits};

#[global_allocator]
static ALLOC: q3gltf_fuzz::Guard = q3gltf_fuzz::Guard;

fuzz_target!(|data: &[u8]| {
    let limits = Limits { max_elements: 1_000_000, max_image_side: 2048, max_image_bytes: 64 << 20 };
    if let Ok(scene) = read_slice(data, None, std::path::Path::new("fuzz.glb"), &limits) {
        let m = &scene.mesh;
        assert!(m.positions.len() <= limits.max_elements);
        for t in &m.triangles {
            assert!(t.iter().all(|&i| (i as usize) < m.positions.len()));
        }
    }
});
