//! Shared pieces of the fuzz targets.
//!
//! [`Guard`] is the global allocator of every target: it aborts (a crash that libFuzzer
//! records, with the input) on any single allocation over [`MAX_ALLOC`]. The parsers are
//! run with limits far below it, so an allocation that large means a count or size from
//! the input reached an allocation without a check. This works with or without a
//! sanitizer (libFuzzer's own `-malloc_limit_mb` needs one).

use std::alloc::{GlobalAlloc, Layout, System};

/// Largest single allocation a target may make: 256 MiB.
pub const MAX_ALLOC: usize = 256 << 20;

pub struct Guard;

unsafe impl GlobalAlloc for Guard {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        System.alloc(layout)
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        System.alloc_zeroed(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        check(new_size);
        System.realloc(ptr, layout, new_size)
    }
}

fn check(size: usize) {
    if size > MAX_ALLOC {
        // No formatting: this runs inside the allocator.
        let msg = b"\n==q3gltf-fuzz== single allocation over MAX_ALLOC (256 MiB): an unchecked size from the input\n";
        use std::io::Write;
        let _ = std::io::stderr().write_all(msg);
        std::process::abort();
    }
}

/// Texture limits for the targets: small, so each run stays fast; the guard sits above.
pub fn texture_limits() -> q3gltf_convert::texture::Limits {
    q3gltf_convert::texture::Limits { max_side: 2048, max_alloc: 64 << 20 }
}
