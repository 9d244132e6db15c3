//! Safe output files: every file is written to a temporary name in its destination
//! directory and renamed into place, so an interrupted run never leaves a partial file,
//! and an output path that names an input is refused.
//!
//! Several files that belong together (a `.gltf`, its `.bin` and its images) go through
//! one [`Staged`] batch: all are written and synced under temporary names first, then
//! renamed in order (the `.gltf` last) by [`Staged::commit`]. A batch dropped before its
//! commit (an error) removes its temporaries and the directories it created. With
//! [`remove_temporaries_on_signal`] installed, SIGINT, SIGTERM and SIGHUP do the same
//! before the process dies, and a signal that arrives during the renames is held until
//! they are done, so the outputs are either all there or none is. (SIGKILL cannot be
//! caught: it may leave `.NAME.tmp*` files, never a partial file under a real name.)

use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

static TMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// For the interruption tests only: `Q3GLTF_TEST_WRITE_DELAY_MS` makes every staged file
/// take that long, so a test can signal the process while a batch is half written.
fn test_delay() {
    static DELAY: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    let ms = *DELAY.get_or_init(|| std::env::var("Q3GLTF_TEST_WRITE_DELAY_MS").ok().and_then(|v| v.parse().ok()).unwrap_or(0));
    if ms > 0 {
        std::thread::sleep(std::time::Duration::from_millis(ms));
    }
}

/// Files written under temporary names, renamed into place together by [`Staged::commit`].
#[derive(Default)]
pub struct Staged {
    /// (temporary, destination, cleanup slot), in the order they are renamed.
    files: Vec<(PathBuf, PathBuf, Option<usize>)>,
    /// Directories this batch created (removed again, if empty, when not committed).
    dirs: Vec<(PathBuf, Option<usize>)>,
}

impl Staged {
    pub fn new() -> Self {
        Staged::default()
    }

    /// Creates `dir` and its missing parents, remembering the ones this batch created.
    pub fn create_dir_all(&mut self, dir: &Path) -> io::Result<()> {
        if dir.as_os_str().is_empty() || dir.is_dir() {
            return Ok(());
        }
        if let Some(parent) = dir.parent() {
            self.create_dir_all(parent)?;
        }
        match std::fs::create_dir(dir) {
            Ok(()) => {
                self.dirs.push((dir.to_path_buf(), cleanup::register(dir)));
                Ok(())
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists && dir.is_dir() => Ok(()),
            Err(e) => Err(e),
        }
    }

    /// Writes `bytes` to a temporary file beside `path` (synced to disk); `path` itself is
    /// only touched by [`Staged::commit`].
    pub fn add(&mut self, path: &Path, bytes: &[u8]) -> io::Result<()> {
        let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let name = path.file_name().ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "output path has no file name"))?;
        // A fresh name (a stale temporary of an earlier process with the same id is
        // left alone); never follows an existing file or link.
        // Registered for the signal handler before it exists, so no moment is uncovered.
        let mut f = loop {
            let n = TMP_COUNTER.fetch_add(1, Ordering::Relaxed);
            let tmp = dir.join(format!(".{}.tmp{}-{n}", name.to_string_lossy(), std::process::id()));
            let slot = cleanup::register(&tmp);
            match std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp) {
                Ok(f) => {
                    self.files.push((tmp, path.to_path_buf(), slot));
                    break f;
                }
                Err(e) => {
                    cleanup::unregister(slot);
                    if e.kind() != io::ErrorKind::AlreadyExists || n % 1000 == 999 {
                        return Err(e);
                    }
                }
            }
        };
        f.write_all(bytes)?;
        f.sync_all()?;
        test_delay();
        Ok(())
    }

    /// Renames every file into place, in the order added. A signal that arrives meanwhile
    /// takes effect when the renames are done.
    pub fn commit(mut self) -> io::Result<()> {
        let _hold = cleanup::HoldSignals::new();
        let files = std::mem::take(&mut self.files);
        let mut result = Ok(());
        for (tmp, dest, slot) in files {
            if result.is_ok() {
                result = std::fs::rename(&tmp, &dest);
            }
            if result.is_err() {
                let _ = std::fs::remove_file(&tmp);
            }
            cleanup::unregister(slot);
        }
        for (_, slot) in std::mem::take(&mut self.dirs) {
            cleanup::unregister(slot);
        }
        result
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        for (tmp, _, slot) in self.files.drain(..) {
            let _ = std::fs::remove_file(&tmp);
            cleanup::unregister(slot);
        }
        for (dir, slot) in self.dirs.drain(..).rev() {
            let _ = std::fs::remove_dir(&dir);
            cleanup::unregister(slot);
        }
    }
}

/// Writes `bytes` to `path` atomically (temporary file in the same directory, then
/// rename). The temporary file is removed if anything fails.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut s = Staged::new();
    s.add(path, bytes)?;
    s.commit()
}

/// Installs handlers for SIGINT, SIGTERM and SIGHUP that remove every pending temporary
/// file (and directory created for it) of the [`Staged`] batches, then let the signal
/// end the process as it would have. Call once at start-up (the command line does).
/// No-op on other platforms than Unix.
pub fn remove_temporaries_on_signal() {
    cleanup::install();
}

#[cfg(unix)]
mod cleanup {
    //! Paths of pending temporaries in a fixed table of C strings, so that a signal
    //! handler can unlink them with async-signal-safe calls only.
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    use std::path::Path;
    use std::sync::atomic::{AtomicBool, AtomicI32, AtomicPtr, AtomicUsize, Ordering::SeqCst};

    const SLOTS: usize = 4096;
    static PENDING: [AtomicPtr<libc::c_char>; SLOTS] = [const { AtomicPtr::new(std::ptr::null_mut()) }; SLOTS];
    static INSTALLED: AtomicBool = AtomicBool::new(false);
    static HOLDING: AtomicUsize = AtomicUsize::new(0);
    static HELD: AtomicI32 = AtomicI32::new(0);

    pub fn register(p: &Path) -> Option<usize> {
        if !INSTALLED.load(SeqCst) {
            return None;
        }
        let c = CString::new(p.as_os_str().as_bytes()).ok()?.into_raw();
        for (i, s) in PENDING.iter().enumerate() {
            if s.compare_exchange(std::ptr::null_mut(), c, SeqCst, SeqCst).is_ok() {
                return Some(i);
            }
        }
        // Table full: this temporary is still removed on errors, only not on a signal.
        drop(unsafe { CString::from_raw(c) });
        None
    }

    pub fn unregister(slot: Option<usize>) {
        if let Some(i) = slot {
            // The string is leaked on purpose: a handler on another thread may be reading it.
            PENDING[i].swap(std::ptr::null_mut(), SeqCst);
        }
    }

    /// While alive, signals are held (recorded, acted on when the last hold ends).
    pub struct HoldSignals;

    impl HoldSignals {
        pub fn new() -> Self {
            HOLDING.fetch_add(1, SeqCst);
            HoldSignals
        }
    }

    impl Drop for HoldSignals {
        fn drop(&mut self) {
            if HOLDING.fetch_sub(1, SeqCst) == 1 {
                let sig = HELD.swap(0, SeqCst);
                if sig != 0 {
                    handler(sig);
                }
            }
        }
    }

    extern "C" fn handler(sig: libc::c_int) {
        if HOLDING.load(SeqCst) > 0 {
            HELD.store(sig, SeqCst);
            return;
        }
        // Files first, then the directories made for them (empty by then).
        for s in PENDING.iter() {
            let c = s.load(SeqCst);
            if !c.is_null() {
                unsafe { libc::unlink(c) };
            }
        }
        // Directories get slots in creation order, parents first: remove in reverse.
        for s in PENDING.iter().rev() {
            let c = s.load(SeqCst);
            if !c.is_null() {
                unsafe { libc::rmdir(c) };
            }
        }
        unsafe {
            libc::signal(sig, libc::SIG_DFL);
            libc::raise(sig);
        }
    }

    pub fn install() {
        if INSTALLED.swap(true, SeqCst) {
            return;
        }
        let h = handler as extern "C" fn(libc::c_int);
        for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
            unsafe { libc::signal(sig, h as libc::sighandler_t) };
        }
    }
}

#[cfg(not(unix))]
mod cleanup {
    use std::path::Path;
    pub fn register(_: &Path) -> Option<usize> {
        None
    }
    pub fn unregister(_: Option<usize>) {}
    pub struct HoldSignals;
    impl HoldSignals {
        pub fn new() -> Self {
            HoldSignals
        }
    }
    pub fn install() {}
}

/// True when `out` and `input` are the same file (also through links or `..`).
pub fn same_file(out: &Path, input: &Path) -> bool {
    match (out.canonicalize(), input.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

/// Most directory levels kept by [`sanitize_relative`]; deeper names are folded into the
/// last component.
pub const MAX_NAME_DEPTH: usize = 8;
/// Longest component kept by [`sanitize_relative`], in bytes.
pub const MAX_COMPONENT: usize = 96;

/// Makes a relative path safe and portable for an output file name: each component keeps
/// only `[a-z0-9_-.]` (others, NUL and non-ASCII included, become `_`), loses leading and
/// trailing dots, is at most [`MAX_COMPONENT`] bytes and never a Windows device name
/// (`con`, `nul`, `com1`, ... get a leading `_`); empty, `.` and `..` components are
/// dropped, so the result is never absolute and never climbs out (backslashes and drive
/// letters are separators and characters like any other). At most [`MAX_NAME_DEPTH`]
/// components. Deterministic; distinct names may collide, which the caller resolves.
pub fn sanitize_relative(name: &str) -> PathBuf {
    let mut comps: Vec<String> = Vec::new();
    for comp in name.split(['/', '\\']) {
        let c: String = comp
            .chars()
            .map(|ch| {
                let ch = ch.to_ascii_lowercase();
                if ch.is_ascii_alphanumeric() || ch == '_' || ch == '-' || ch == '.' {
                    ch
                } else {
                    '_'
                }
            })
            .collect();
        let c = c.trim_matches('.');
        if !c.is_empty() {
            comps.push(c.to_string());
        }
    }
    if comps.len() > MAX_NAME_DEPTH {
        let tail = comps.split_off(MAX_NAME_DEPTH - 1).join("_");
        comps.push(tail);
    }
    let mut out = PathBuf::new();
    for mut c in comps {
        c.truncate(MAX_COMPONENT);
        let c = c.trim_end_matches('.');
        let stem = c.split('.').next().unwrap_or("");
        let device = matches!(stem, "con" | "prn" | "aux" | "nul")
            || (stem.len() == 4 && (stem.starts_with("com") || stem.starts_with("lpt")) && stem.as_bytes()[3].is_ascii_digit());
        out.push(if device { format!("_{c}") } else { c.to_string() });
    }
    if out.as_os_str().is_empty() {
        out.push("unnamed");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sanitized_names_stay_inside() {
        for bad in ["../../etc/passwd", "/abs/x", "C:\\win\\x", "a/./b", "a\0b", "..", ""] {
            let p = sanitize_relative(bad);
            assert!(p.is_relative(), "{bad:?}");
            assert!(p.components().all(|c| matches!(c, std::path::Component::Normal(_))), "{bad:?} -> {p:?}");
        }
        assert_eq!(sanitize_relative("textures/Base Wall/x.tga"), PathBuf::from("textures/base_wall/x.tga"));
        assert_eq!(sanitize_relative("..\\..\\C:\\Windows\\evil"), PathBuf::from("c_/windows/evil"));
        assert_eq!(sanitize_relative("/etc/passwd\0.tga"), PathBuf::from("etc/passwd_.tga"));
        assert_eq!(sanitize_relative("textures/CON/nul.tga"), PathBuf::from("textures/_con/_nul.tga"));
        assert_eq!(sanitize_relative("a/com1/lpt9.x/console"), PathBuf::from("a/_com1/_lpt9.x/console"));
        assert_eq!(sanitize_relative("\u{e9}t\u{e9}"), PathBuf::from("_t_"));
        let deep = sanitize_relative(&"d/".repeat(40));
        assert_eq!(deep.components().count(), MAX_NAME_DEPTH);
        let long = sanitize_relative(&"x".repeat(500));
        assert_eq!(long.as_os_str().len(), MAX_COMPONENT);
        // Deterministic.
        assert_eq!(sanitize_relative("A/B c"), sanitize_relative("A/B c"));
    }

    #[test]
    fn staged_batch_is_all_or_nothing() {
        let dir = std::env::temp_dir().join(format!("q3gltf-staged-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        // Dropped before commit: no file, no temporary, no directory it created.
        {
            let mut s = Staged::new();
            s.create_dir_all(&dir.join("tex/sub")).unwrap();
            s.add(&dir.join("tex/sub/a.png"), b"a").unwrap();
            s.add(&dir.join("m.gltf"), b"{}").unwrap();
            assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 2, "temporaries exist before the commit");
        }
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0, "nothing left after a dropped batch");
        // A failing add (the destination directory is a file) leaves nothing either.
        std::fs::write(dir.join("blocker"), b"x").unwrap();
        {
            let mut s = Staged::new();
            s.add(&dir.join("m.bin"), b"bin").unwrap();
            assert!(s.add(&dir.join("blocker/a.png"), b"a").is_err());
        }
        let names: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, vec![std::ffi::OsString::from("blocker")]);
        // Committed: all files under their names, in place.
        let mut s = Staged::new();
        s.create_dir_all(&dir.join("tex")).unwrap();
        s.add(&dir.join("tex/a.png"), b"a").unwrap();
        s.add(&dir.join("m.gltf"), b"{}").unwrap();
        s.commit().unwrap();
        assert_eq!(std::fs::read(dir.join("tex/a.png")).unwrap(), b"a");
        assert_eq!(std::fs::read(dir.join("m.gltf")).unwrap(), b"{}");
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 3);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn atomic_write_replaces_whole_file() {
        let dir = std::env::temp_dir().join(format!("q3gltf-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("f.bin");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two!").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two!");
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1, "no temporary file left");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
