//! Local point descriptors.

pub mod fpfh;

pub use fpfh::{
    FPFH_BINS, Fpfh, compute_fpfh, compute_fpfh_from_neighbourhoods, compute_fpfh_with_tree,
};
