//! The shader script parser, and material resolution over what it produced.
#![no_main]
use libfuzzer_sys::fuzz_target;
use q3gltf_convert::shader::{parse, ShaderLibrary};

#[global_allocator]
static ALLOC: q3gltf_fuzz::Guard = q3gltf_fuzz::Guard;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let parsed = parse(&text);
    let mut lib = ShaderLibrary::default();
    lib.add_script("scripts/fuzz.shader", &text);
    assert!(lib.shaders.len() <= parsed.shaders.len());
    let vfs = q3gltf_convert::vfs::Vfs::new();
    for def in parsed.shaders.iter().take(64) {
        let r = q3gltf_convert::bsp::ShaderRef { name: def.name.clone(), surface_flags: 0, content_flags: 0 };
        let _ = q3gltf_convert::material::resolve(&r, &lib, &vfs);
    }
});
