//! The pk3 virtual file system: mount an archive from memory, then list and read every
//! entry with a small per-file limit (a zip bomb must fail, not allocate).
#![no_main]
use libfuzzer_sys::fuzz_target;
use q3gltf_convert::vfs::{normalize, Vfs};

#[global_allocator]
static ALLOC: q3gltf_fuzz::Guard = q3gltf_fuzz::Guard;

const LIMIT: u64 = 1 << 20;

fuzz_target!(|data: &[u8]| {
    let mut vfs = Vfs::new();
    vfs.max_entry_bytes = LIMIT;
    if vfs.mount_pk3_bytes("fuzz.pk3", data.to_vec()).is_err() {
        return;
    }
    for name in vfs.names().into_iter().take(256) {
        // Every mounted name is already normal: relative, no '..', no NUL, no drive.
        assert_eq!(normalize(&name).as_deref(), Some(name.as_str()));
        if let Ok(bytes) = vfs.read(&name) {
            assert!(bytes.len() as u64 <= LIMIT);
        }
    }
});
