//! Local refinement of a coarse alignment (after RANSAC): point-to-plane ICP.

pub mod icp;

pub use icp::{
    IcpConfig, IcpResult, IcpTarget, RegistrationEvaluation, RobustKernel, evaluate_registration,
    registration_icp_point_to_plane,
};
