//! mireg: point cloud registration for robotics logs with MI-RANSAC.
#![warn(missing_docs)]

pub mod error;
pub mod features;
pub mod geometry;

pub use error::{Error, Result};
