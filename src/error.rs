//! The library's one error type.

use std::path::PathBuf;

/// Everything that can go wrong in `mireg` outside of programming errors (which are `assert!`s).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Reading or writing `path` failed at the operating-system level.
    #[error("{path}: {source}")]
    Io {
        /// The file involved.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// `path` was read but its content is not what its format promises.
    #[error("{path}: {detail}")]
    Format {
        /// The offending file.
        path: PathBuf,
        /// What is wrong, naming the record/field where possible.
        detail: String,
    },
    /// A caller-supplied value is out of its documented range.
    #[error("invalid input: {0}")]
    InvalidInput(String),
}

/// `Result` with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
