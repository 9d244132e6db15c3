//! The crate's error type. Every variant names the file it is about, so the command-line
//! tool can print one line that says what is wrong and where.

use crate::bsp::BspError;
use crate::vfs::VfsError;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{path}: {source}")]
    Bsp { path: String, source: BspError },
    #[error(transparent)]
    Vfs(#[from] VfsError),
    #[error("{path}: {msg}")]
    Invalid { path: String, msg: String },
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{0}")]
    Usage(String),
}

impl Error {
    pub fn invalid(path: impl Into<String>, msg: impl Into<String>) -> Self {
        Error::Invalid { path: path.into(), msg: msg.into() }
    }
}
