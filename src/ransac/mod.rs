//! MI-RANSAC: ranked correspondences, a Lévy sampler over the ranks, and a generic consensus loop.
//!
//! Sampler ([`Sampler`]: [`Uniform`], [`Levy`], [`Prosac`]), estimator ([`Estimator`]:
//! [`RigidEstimator`], [`DenseRigidEstimator`]) and the loop ([`run_consensus`]) are separate, swappable parts.

pub mod consensus;
pub mod dense;
pub mod estimator;
pub mod levy;
pub mod prosac;
pub mod sampler;

pub use consensus::{Consensus, ConsensusConfig, Scoring, Termination, run_consensus};
pub use dense::{DenseRigidEstimator, OverlapTarget};
pub use estimator::{Estimator, RigidEstimator, Score, kabsch, kabsch_indexed};
pub use levy::{Levy, TruncatedLevy};
pub use prosac::{Prosac, ProsacTermination};
pub use sampler::{Sampler, Uniform, hypothesis_rng};
