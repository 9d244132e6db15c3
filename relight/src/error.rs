//! The crate's error type. Every variant says which file or which stage it is about, so the
//! command-line tool prints one line that says what is wrong and where.

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The glTF could not be read (syntax, missing buffer, undecodable image, ...).
    #[error("{path}: {msg}")]
    Input { path: String, msg: String },
    /// The glTF was read but cannot be relit as it is (no geometry, no baked lighting, ...).
    #[error("{path}: {msg}")]
    Unsupported { path: String, msg: String },
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    /// The GPU backend failed (no adapter, device lost, shader rejected).
    #[error("wgpu: {0}")]
    Gpu(String),
    #[error("{0}")]
    Usage(String),
}

impl Error {
    pub fn input(path: impl AsRef<std::path::Path>, msg: impl Into<String>) -> Self {
        Error::Input { path: path.as_ref().display().to_string(), msg: msg.into() }
    }
    pub fn unsupported(path: impl AsRef<std::path::Path>, msg: impl Into<String>) -> Self {
        Error::Unsupported { path: path.as_ref().display().to_string(), msg: msg.into() }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
