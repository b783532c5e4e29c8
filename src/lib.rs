//! mireg: point cloud registration for robotics logs with MI-RANSAC.
#![warn(missing_docs)]

pub mod error;
pub mod io;

pub use error::{Error, Result};
pub mod cli;
pub mod correspondence;
pub mod ransac;
pub mod simulate;
