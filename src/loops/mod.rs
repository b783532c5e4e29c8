//! Loop-closure candidates (the first stage of globally consistent trajectories): a compact
//! appearance [`Descriptor`] per keyframe, a keyframe selector and the candidate search over a
//! whole log. Pure: slices and nalgebra types in, candidates out; no I/O.
//!
//! Anchors (../shared/docs/DESIGN.md §6): Scan Context (Kim & Kim 2018) searches by appearance with a
//! yaw-invariant polar descriptor ([`scan_context`], kept as the measured baseline); KISS-SLAM
//! queries MapClosures with each local map. Here a keyframe is a candidate for an earlier one
//! when their odometry positions are close allowing for drift ([`Source::Place`]) or when their
//! descriptors are close whatever the odometry says ([`Source::Appearance`]).
//!
//! ```
//! use mireg::loops::{CandidateConfig, Descriptor, Keyframe, find_candidates};
//! use nalgebra::{Isometry3, Point3};
//!
//! let points = [Point3::new(1.0, 0.0, 0.0), Point3::new(0.0, 2.0, 0.0)];
//! let features = [[1.0f32; 33]; 2];
//! let descriptor = Descriptor::new(&points, &features);
//! let keyframes: Vec<Keyframe> = (0..3)
//!     .map(|k| Keyframe {
//!         frame: 100 * k,
//!         stamp_ns: 0,
//!         pose: Isometry3::translation(0.1 * k as f64, 0.0, 0.0),
//!         travelled_m: 40.0 * k as f64,
//!         descriptor,
//!     })
//!     .collect();
//! let candidates = find_candidates(&keyframes, &CandidateConfig::default()).unwrap();
//! assert_eq!((candidates[0].query, candidates[0].matched), (1, 0));
//! ```

pub mod candidates;
pub mod closure;
pub mod consistency;
pub mod descriptor;
pub mod joint;
pub mod keyframes;
pub mod scan_context;
pub mod verify;

pub use candidates::{Candidate, CandidateConfig, Keyframe, Source, find_candidates};
pub use closure::{
    LOOP_INFORMATION_SCALE, LoopConfig, LoopEdge, Step, edge_prior, held_by_map, map_agreement,
    optimize_trajectory, pose_graph, solve_annealed,
};
pub use consistency::{PairwiseConsistency, maximum_clique};
pub use descriptor::Descriptor;
pub use joint::{Judged, LoopDecision, Rounds, close_in_rounds, judge_loops, search_again};
pub use keyframes::{KeyframeConfig, KeyframeSelector, select_keyframes};
pub use scan_context::ScanContext;
pub use verify::{Verification, VerifyConfig, verify};
