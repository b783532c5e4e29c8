//! Local refinement of a coarse alignment (after RANSAC): point-to-plane ICP, against the previous
//! frame or a local map of recent frames.

pub mod icp;
pub mod local_map;

pub use icp::{
    IcpConfig, IcpResult, IcpTarget, RegistrationEvaluation, RobustKernel, evaluate_registration,
    registration_icp_point_to_plane,
};
