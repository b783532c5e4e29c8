//! Putative correspondences: matching in feature space and ranking by how likely each is an inlier.

pub mod duplicates;
pub mod matching;
pub mod ranking;
