//! How the process keeps the memory it frees.
//!
//! relight's objective allocates its per-row buffers afresh at every evaluation (a few
//! `[f64; 3]` per row: about 10 MB each at 400k rows). glibc gives freed memory above its
//! trim threshold back to the system and serves large blocks with fresh `mmap`s, so every
//! evaluation faulted the same pages back in, zeroed: on oa_dm1's vertex target at 402k
//! rows the kernel's page handling took about a seventh of the run and an evaluation
//! cost 0.167 us per row against 0.08 at 121k (`benches/scaling.py`, 2-core machine). With
//! the memory kept, 0.066 at 402k (README, "Speed"): the cost is linear in the rows again.

/// Keeps freed memory in the process: blocks up to 32 MB (glibc's largest mmap threshold
/// on 64-bit) come from the heap, and the heap is never trimmed during the run. A no-op
/// where the allocator is not glibc's.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets the allocator's parameters; it is called before any
    // thread starts, and an out-of-range value is refused (returns 0), not undefined.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}
