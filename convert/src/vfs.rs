//! Virtual file system: the engine's view of game directories and their `.pk3` archives.
//!
//! Mount order follows ioquake3: game directories in the order given, later ones
//! overriding earlier ones; inside a directory, `.pk3` files sorted by name with later
//! archives overriding earlier ones, and loose files overriding every archive of their
//! directory. Lookups are case-insensitive on normalised paths (`/` separators).
//!
//! Untrusted names: an archive with an entry whose path is absolute, has a drive letter,
//! a `..` component or a NUL byte is refused as a whole ([`is_hostile`]); other odd
//! names (empty or `.` components) are not mounted and are listed in [`Vfs::rejected`]. No name from an archive ever reaches the real
//! file system: reads go through the archive, and output names are made by the writer.
//!
//! Entry sizes are bounded: a read that would exceed [`Vfs::max_entry_bytes`] fails
//! before allocating (from the declared size) and while decompressing (a lying header
//! cannot inflate past the limit), so a zip bomb fails fast.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Default limit on the size of one file read through the VFS: 256 MiB.
pub const DEFAULT_MAX_ENTRY_BYTES: u64 = 256 << 20;

#[derive(Debug, thiserror::Error)]
pub enum VfsError {
    #[error("{path}: {source}")]
    Io { path: String, source: io::Error },
    #[error("{path}: corrupt pk3 archive: {msg}")]
    Archive { path: String, msg: String },
    #[error("{path}: {size} bytes exceeds the {limit}-byte limit for one file")]
    TooLarge { path: String, size: u64, limit: u64 },
    #[error("{0}: not found in the game directories")]
    NotFound(String),
}

/// A file handle that reads at an explicit position, so clones share one open file and
/// can read concurrently (each clone keeps its own cursor).
#[derive(Clone)]
struct SharedFile {
    file: Arc<File>,
    pos: u64,
    len: u64,
}

impl Read for SharedFile {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = read_at(&self.file, buf, self.pos)?;
        self.pos += n as u64;
        Ok(n)
    }
}

impl Seek for SharedFile {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        let target = match to {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::End(d) => self.len.checked_add_signed(d),
            SeekFrom::Current(d) => self.pos.checked_add_signed(d),
        };
        self.pos = target.ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "seek before start"))?;
        Ok(self.pos)
    }
}

#[cfg(unix)]
fn read_at(f: &File, buf: &mut [u8], pos: u64) -> io::Result<usize> {
    std::os::unix::fs::FileExt::read_at(f, buf, pos)
}
#[cfg(windows)]
fn read_at(f: &File, buf: &mut [u8], pos: u64) -> io::Result<usize> {
    std::os::windows::fs::FileExt::seek_read(f, buf, pos)
}

/// What an archive is read from: a file on disk, or bytes in memory (tests, fuzzing).
#[derive(Clone)]
enum ArchiveReader {
    File(SharedFile),
    Memory(io::Cursor<Arc<[u8]>>),
}

impl Read for ArchiveReader {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            ArchiveReader::File(f) => f.read(buf),
            ArchiveReader::Memory(c) => c.read(buf),
        }
    }
}

impl Seek for ArchiveReader {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        match self {
            ArchiveReader::File(f) => f.seek(to),
            ArchiveReader::Memory(c) => c.seek(to),
        }
    }
}

struct Archive {
    path: PathBuf,
    zip: zip::ZipArchive<ArchiveReader>,
}

#[derive(Clone)]
enum Source {
    Loose(PathBuf),
    Packed { archive: usize, index: usize, size: u64 },
}

/// Where a file of the VFS comes from, for messages.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Origin {
    Loose(PathBuf),
    Pk3 { archive: PathBuf, entry: String },
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Origin::Loose(p) => write!(f, "{}", p.display()),
            Origin::Pk3 { archive, entry } => write!(f, "{}:{}", archive.display(), entry),
        }
    }
}

/// The merged view of all mounted game directories.
pub struct Vfs {
    archives: Vec<Archive>,
    /// Normalised lower-case path -> the winning source.
    files: BTreeMap<String, Source>,
    /// Names refused as unsafe or malformed, with where they came from.
    pub rejected: Vec<String>,
    pub max_entry_bytes: u64,
}

/// Normalises a game path: backslashes to slashes, lower case, no leading `./` or `/`
/// duplicates. Returns `None` for names that must never be used (absolute, drive letter,
/// `..` or `.` components, NUL bytes, empty components, over 1024 bytes).
pub fn normalize(name: &str) -> Option<String> {
    if name.is_empty() || name.len() > 1024 || name.contains('\0') {
        return None;
    }
    let s = name.replace('\\', "/").to_ascii_lowercase();
    if s.starts_with('/') || s.as_bytes().get(1) == Some(&b':') {
        return None;
    }
    let s = s.strip_suffix('/').unwrap_or(&s);
    if s.split('/').any(|c| c.is_empty() || c == "." || c == "..") {
        return None;
    }
    Some(s.to_string())
}

/// Names that only a hostile archive contains: absolute paths, drive letters, `..`
/// components, NUL bytes. An archive with such an entry is refused as a whole.
pub fn is_hostile(name: &str) -> bool {
    let s = name.replace('\\', "/");
    s.contains('\0') || s.starts_with('/') || s.as_bytes().get(1) == Some(&b':') || s.split('/').any(|c| c == "..")
}

impl Vfs {
    pub fn new() -> Self {
        Vfs { archives: Vec::new(), files: BTreeMap::new(), rejected: Vec::new(), max_entry_bytes: DEFAULT_MAX_ENTRY_BYTES }
    }

    /// Mounts a game directory: its `.pk3` archives (sorted by name) and its loose files.
    pub fn mount_dir(&mut self, dir: &Path) -> Result<(), VfsError> {
        let io_err = |source| VfsError::Io { path: dir.display().to_string(), source };
        let mut pk3s: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(io_err)?
            .filter_map(|e| e.ok())
            .map(|e| e.path())
            .filter(|p| p.is_file() && p.extension().is_some_and(|e| e.eq_ignore_ascii_case("pk3")))
            .collect();
        pk3s.sort();
        for p in &pk3s {
            self.mount_pk3(p)?;
        }
        self.mount_loose(dir, dir, 0)
    }

    fn mount_loose(&mut self, root: &Path, dir: &Path, depth: usize) -> Result<(), VfsError> {
        // Only the directories the engine reads from: keeps `mount_dir` cheap on big trees.
        const TOP: [&str; 6] = ["maps", "textures", "scripts", "models", "gfx", "env"];
        if depth > 16 {
            return Ok(());
        }
        let Ok(rd) = std::fs::read_dir(dir) else { return Ok(()) };
        let mut entries: Vec<_> = rd.filter_map(|e| e.ok()).collect();
        entries.sort_by_key(|e| e.file_name());
        for e in entries {
            let path = e.path();
            let Ok(ft) = e.file_type() else { continue };
            let rel = path.strip_prefix(root).unwrap_or(&path);
            let rel_str = rel.to_string_lossy().replace('\\', "/");
            if ft.is_dir() {
                if depth == 0 && !TOP.iter().any(|t| rel_str.eq_ignore_ascii_case(t)) {
                    continue;
                }
                self.mount_loose(root, &path, depth + 1)?;
            } else if ft.is_file() && depth > 0 {
                match normalize(&rel_str) {
                    Some(n) => {
                        self.files.insert(n, Source::Loose(path));
                    }
                    None => self.rejected.push(path.display().to_string()),
                }
            }
        }
        Ok(())
    }

    /// Mounts one `.pk3` archive on top of everything mounted so far.
    pub fn mount_pk3(&mut self, path: &Path) -> Result<(), VfsError> {
        let shown = path.display().to_string();
        let file = File::open(path).map_err(|source| VfsError::Io { path: shown.clone(), source })?;
        let len = file.metadata().map_err(|source| VfsError::Io { path: shown.clone(), source })?.len();
        self.mount_archive(path, ArchiveReader::File(SharedFile { file: Arc::new(file), pos: 0, len }))
    }

    /// Mounts a `.pk3` archive held in memory, under the display name `name` (same rules
    /// as [`Vfs::mount_pk3`]; used by tests and the fuzz targets).
    pub fn mount_pk3_bytes(&mut self, name: &str, bytes: impl Into<Arc<[u8]>>) -> Result<(), VfsError> {
        self.mount_archive(Path::new(name), ArchiveReader::Memory(io::Cursor::new(bytes.into())))
    }

    fn mount_archive(&mut self, path: &Path, reader: ArchiveReader) -> Result<(), VfsError> {
        let shown = path.display().to_string();
        let mut zip = zip::ZipArchive::new(reader).map_err(|e| VfsError::Archive { path: shown.clone(), msg: e.to_string() })?;
        let archive = self.archives.len();
        // Entries in central-directory order; a later duplicate inside one archive wins.
        // Nothing is mounted until the whole directory has been checked, so a refused
        // archive leaves the file system as it was.
        let mut mounted = Vec::new();
        let mut rejected = Vec::new();
        for index in 0..zip.len() {
            let f = zip.by_index_raw(index).map_err(|e| VfsError::Archive { path: shown.clone(), msg: e.to_string() })?;
            let raw = String::from_utf8_lossy(f.name_raw()).into_owned();
            if is_hostile(&raw) {
                return Err(VfsError::Archive { path: shown, msg: format!("unsafe entry name {:?} (absolute, drive letter, '..' or NUL)", raw) });
            }
            if f.is_dir() {
                continue;
            }
            match normalize(&raw) {
                Some(n) => mounted.push((n, Source::Packed { archive, index, size: f.size() })),
                None => rejected.push(format!("{shown}:{}", raw.escape_debug())),
            }
        }
        self.files.extend(mounted);
        self.rejected.extend(rejected);
        self.archives.push(Archive { path: path.to_path_buf(), zip });
        Ok(())
    }

    pub fn contains(&self, name: &str) -> bool {
        normalize(name).is_some_and(|n| self.files.contains_key(&n))
    }

    /// Where a file would be read from.
    pub fn origin(&self, name: &str) -> Option<Origin> {
        let n = normalize(name)?;
        Some(match self.files.get(&n)? {
            Source::Loose(p) => Origin::Loose(p.clone()),
            Source::Packed { archive, index, .. } => {
                let a = &self.archives[*archive];
                Origin::Pk3 { archive: a.path.clone(), entry: a.zip.name_for_index(*index).unwrap_or("?").to_string() }
            }
        })
    }

    /// Every mounted path (normalised), sorted.
    pub fn names(&self) -> Vec<String> {
        self.files.keys().cloned().collect()
    }

    /// All mounted paths (normalised) under `dir` with the extension `ext` (lower case,
    /// without dot), sorted.
    pub fn list(&self, dir: &str, ext: &str) -> Vec<String> {
        let prefix = format!("{}/", dir.trim_end_matches('/').to_ascii_lowercase());
        self.files
            .range(prefix.clone()..)
            .take_while(|(k, _)| k.starts_with(&prefix))
            .filter(|(k, _)| k.rsplit_once('.').is_some_and(|(_, e)| e == ext))
            .map(|(k, _)| k.clone())
            .collect()
    }

    /// Reads a whole file. Safe to call from several threads at once.
    pub fn read(&self, name: &str) -> Result<Vec<u8>, VfsError> {
        let n = normalize(name).ok_or_else(|| VfsError::NotFound(name.to_string()))?;
        let src = self.files.get(&n).ok_or_else(|| VfsError::NotFound(name.to_string()))?;
        let limit = self.max_entry_bytes;
        match src {
            Source::Loose(p) => {
                let shown = p.display().to_string();
                let io = |source| VfsError::Io { path: shown.clone(), source };
                let f = File::open(p).map_err(io)?;
                let size = f.metadata().map_err(io)?.len();
                if size > limit {
                    return Err(VfsError::TooLarge { path: shown, size, limit });
                }
                let mut buf = Vec::with_capacity(size as usize);
                f.take(limit + 1).read_to_end(&mut buf).map_err(io)?;
                Ok(buf)
            }
            Source::Packed { archive, index, size } => {
                let a = &self.archives[*archive];
                let mut zip = a.zip.clone();
                let shown = format!("{}:{}", a.path.display(), n);
                if *size > limit {
                    return Err(VfsError::TooLarge { path: shown, size: *size, limit });
                }
                let f = zip.by_index(*index).map_err(|e| VfsError::Archive { path: shown.clone(), msg: e.to_string() })?;
                let mut buf = Vec::with_capacity(*size as usize);
                f.take(limit + 1)
                    .read_to_end(&mut buf)
                    .map_err(|e| VfsError::Archive { path: shown.clone(), msg: e.to_string() })?;
                if buf.len() as u64 > limit {
                    return Err(VfsError::TooLarge { path: shown, size: buf.len() as u64, limit });
                }
                Ok(buf)
            }
        }
    }
}

impl Default for Vfs {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalize_refuses_unsafe_names() {
        assert_eq!(normalize("Textures\\Base/Wall.TGA").as_deref(), Some("textures/base/wall.tga"));
        assert_eq!(normalize("maps/").as_deref(), Some("maps"));
        for bad in ["../x", "a/../b", "/etc/passwd", "C:/x", "c:x", "a//b", "./a", "a\0b", ""] {
            assert_eq!(normalize(bad), None, "{bad:?}");
        }
    }

    fn zip_with(entries: &[(&str, &[u8])]) -> Vec<u8> {
        use std::io::Write;
        let mut buf = io::Cursor::new(Vec::new());
        let mut z = zip::ZipWriter::new(&mut buf);
        for (name, data) in entries {
            let o = zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated);
            z.start_file(*name, o).unwrap();
            z.write_all(data).unwrap();
        }
        z.finish().unwrap();
        buf.into_inner()
    }

    /// Sets the uncompressed size of every entry (local and central headers) to `size`.
    fn lie_about_sizes(z: &mut [u8], size: u32) {
        let mut at = 0;
        while let Some(p) = z[at..].windows(4).position(|w| w == b"PK\x03\x04" || w == b"PK\x01\x02") {
            let h = at + p;
            let off = if &z[h..h + 4] == b"PK\x03\x04" { 22 } else { 24 };
            z[h + off..h + off + 4].copy_from_slice(&size.to_le_bytes());
            at = h + 4;
        }
    }

    #[test]
    fn zip_bomb_is_refused_before_and_while_inflating() {
        let bomb = vec![0u8; 32 << 20];
        let honest = zip_with(&[("textures/bomb.tga", &bomb), ("scripts/ok.shader", b"x { }")]);
        assert!(honest.len() < 64 << 10, "{}", honest.len());
        let mut lying = honest.clone();
        lie_about_sizes(&mut lying, 5);
        for (what, bytes) in [("declared", honest), ("lying", lying)] {
            let mut vfs = Vfs::new();
            vfs.max_entry_bytes = 1 << 20;
            vfs.mount_pk3_bytes("bomb.pk3", bytes).unwrap();
            let t = std::time::Instant::now();
            match vfs.read("textures/bomb.tga") {
                Err(VfsError::TooLarge { size, limit, .. }) => {
                    assert_eq!(limit, 1 << 20);
                    // Declared: refused from the header; lying: stopped one byte past the limit.
                    assert_eq!(size, if what == "declared" { 32 << 20 } else { (1 << 20) + 1 }, "{what}");
                }
                other => panic!("{what}: {:?}", other.map(|b| b.len())),
            }
            assert!(t.elapsed() < std::time::Duration::from_secs(2), "{what}: {:?}", t.elapsed());
        }
    }

    #[test]
    fn hostile_archive_is_refused_whole() {
        for bad in ["../x", "a/../../b", "/etc/passwd", "C:/win.ini", "c:\\x", "a\\..\\..\\b", "x\0y"] {
            let z = zip_with(&[("textures/ok.tga", b"ok"), (bad, b"evil")]);
            let mut vfs = Vfs::new();
            match vfs.mount_pk3_bytes("evil.pk3", z) {
                Err(VfsError::Archive { msg, .. }) => assert!(msg.contains("unsafe entry name"), "{bad:?}: {msg}"),
                other => panic!("{bad:?}: {:?}", other.is_ok()),
            }
            assert!(vfs.names().is_empty(), "{bad:?}: nothing mounted from a refused archive");
        }
        // Odd but harmless names are left out and listed.
        let z = zip_with(&[("textures/ok.tga", b"ok"), ("a//b", b"x"), ("./c", b"y")]);
        let mut vfs = Vfs::new();
        vfs.mount_pk3_bytes("odd.pk3", z).unwrap();
        assert_eq!(vfs.names(), ["textures/ok.tga"]);
        assert_eq!(vfs.rejected.len(), 2);
        assert_eq!(vfs.read("TEXTURES\\OK.TGA").unwrap(), b"ok");
    }
}
