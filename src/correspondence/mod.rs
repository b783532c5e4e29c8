//! Putative correspondences between source and target features.

pub mod matching;
