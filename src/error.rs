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
    /// Text input (e.g. a g2o pose graph) is malformed at `line` (1-based), in `field`.
    #[error("line {line}, field {field}: {detail}")]
    Parse {
        /// 1-based line number.
        line: usize,
        /// The record field that could not be read (e.g. `qw`, `info[3]`).
        field: String,
        /// What is wrong.
        detail: String,
    },
}

/// `Result` with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
