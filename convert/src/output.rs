//! Safe output files: every file is written to a temporary name in its destination
//! directory and renamed into place, so an interrupted run never leaves a partial file,
//! and an output path that names an input is refused.

use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` atomically (temporary file in the same directory, then
/// rename). The temporary file is removed if anything fails.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "output path has no file name"))?;
    let tmp = dir.join(format!(".{}.tmp{}", name.to_string_lossy(), std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// True when `out` and `input` are the same file (also through links or `..`).
pub fn same_file(out: &Path, input: &Path) -> bool {
    match (out.canonicalize(), input.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

/// Makes a relative path safe and portable for an output file name: each component keeps
/// only `[a-z0-9_-.]` (others become `_`), no component is empty, `.` or `..`, and the
/// result is never absolute. Deterministic.
pub fn sanitize_relative(name: &str) -> PathBuf {
    let mut out = PathBuf::new();
    for comp in name.split(['/', '\\']) {
        let mut c: String = comp
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
        c = c.trim_matches('.').to_string();
        if c.is_empty() {
            continue;
        }
        c.truncate(96);
        out.push(c);
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
