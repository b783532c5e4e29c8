//! mireg: point cloud registration for robotics logs with MI-RANSAC.
#![warn(missing_docs)]

pub mod correspondence;
pub mod error;
pub mod refine;

pub use error::{Error, Result};
