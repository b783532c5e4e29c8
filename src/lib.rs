//! mireg: point cloud registration for robotics logs with MI-RANSAC (More Informed RANSAC,
//! Zhang & Chen).
//!
//! The core is pure: [`ransac`] (samplers, estimators, the consensus loop) and
//! [`correspondence`] (ranking metrics) and [`graph`] (robust pose-graph optimisation for loop
//! closure) take slices and nalgebra types; [`io`] reads files;
//! [`cli`] maps the command line onto them.
#![recursion_limit = "256"]
#![warn(missing_docs)]

pub mod cli;
pub mod correspondence;
pub mod error;
pub mod features;
pub mod fuzzing;
pub mod geometry;
pub mod graph;
mod hash;
pub mod heap;
pub mod io;
pub mod loops;
pub mod map;
pub mod merge;
pub mod pair;
pub mod ransac;
pub mod refine;
pub mod settings;
pub mod simulate;
pub mod sweep;

pub use error::{Error, Result};
pub mod evaluate;
pub mod odometry;
pub mod pipeline;
pub mod register;
pub mod trajectory;
