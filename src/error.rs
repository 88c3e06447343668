//! One error type for the library. Every variant names the file (or scan) it is about, so the
//! binary can print a single line that tells the user what to fix.

use std::path::PathBuf;

/// Errors returned by the mvao library.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The operating system refused a read or write.
    #[error("{}: {err}", path.display())]
    Io {
        /// The file or directory the operation was on.
        path: PathBuf,
        /// What the operating system said.
        err: std::io::Error,
    },
    /// A scan file is not what its format says it is.
    #[error("{}: {msg}", path.display())]
    Format {
        /// The offending file.
        path: PathBuf,
        /// What is wrong, lowercase, with the offending value.
        msg: String,
    },
    /// An alignment file is unreadable, inconsistent with the scans, or not rigid.
    #[error("{}: {msg}", path.display())]
    Align {
        /// The alignment file.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// A scan cannot be processed (no points, no sensor model fits, …).
    #[error("{scan}: {msg}")]
    Scan {
        /// The scan's name (file stem or path).
        scan: String,
        /// What is wrong.
        msg: String,
    },
    /// A parameter or combination of parameters is invalid.
    #[error("{0}")]
    Param(String),
}

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, err: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            err,
        }
    }

    /// A format error in `path`.
    pub fn format(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            msg: msg.into(),
        }
    }

    /// An alignment error in `path`.
    pub fn align(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        Error::Align {
            path: path.into(),
            msg: msg.into(),
        }
    }

    /// A per-scan processing error.
    pub fn scan(scan: impl Into<String>, msg: impl Into<String>) -> Self {
        Error::Scan {
            scan: scan.into(),
            msg: msg.into(),
        }
    }
}

/// Result with the library's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
