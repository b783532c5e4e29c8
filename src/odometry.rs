//! Consecutive-frame registration: a stream of prepared frames → a trajectory. Pure; no file I/O.
//!
//! Frame `k` is registered globally (MI-RANSAC + ICP, no motion prior) to the last frame that had
//! usable data, giving `prev_from_curr`; the trajectory is `world_from_k = world_from_prev ·
//! prev_from_curr` with world = the first frame's sensor frame (DESIGN §5). A frame that fails is
//! flagged with its reason and the trajectory continues on a constant-velocity prediction, refined by
//! ICP when that fits; one bad frame never stops the run.

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::Result;
use crate::pipeline::{FailureReason, PairConfig, PairResult, PreparedFrame, register_prepared};
use crate::refine::icp::{IcpConfig, registration_icp_point_to_plane};

/// Acceptance thresholds on top of the pairwise configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryConfig {
    /// Pairwise registration settings.
    pub pair: PairConfig,
    /// A registration with fewer RANSAC inliers is a failure. Default 12.
    pub min_inliers: usize,
    /// A registration whose ICP fitness is lower is a failure. Default 0.3.
    pub min_fitness: f64,
}

impl Default for OdometryConfig {
    fn default() -> Self {
        Self {
            pair: PairConfig::default(),
            min_inliers: 12,
            min_fitness: 0.3,
        }
    }
}

/// How a failed frame's pose was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fallback {
    /// The previous relative motion, refined by ICP (fitness above the minimum).
    ConstantVelocityIcp,
    /// The previous relative motion, unrefined.
    ConstantVelocity,
}

/// The estimate for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameEstimate {
    /// 0-based frame number.
    pub index: usize,
    /// Pose of this frame in the world (the first frame's sensor frame).
    pub world_from_frame: Isometry3<f64>,
    /// Motion from this frame into the previous one used.
    pub prev_from_curr: Isometry3<f64>,
    /// `true` when global registration met the thresholds (always true for the first frame).
    pub success: bool,
    /// Why it failed, if it did.
    pub failure: Option<FailureReason>,
    /// How the pose was obtained after a failure.
    pub fallback: Option<Fallback>,
    /// Pairwise statistics (`None` for the first frame and frames without usable data).
    pub pair: Option<PairResult>,
    /// ICP iterations of the fallback refinement, if any.
    pub fallback_icp_iterations: usize,
    /// Input points.
    pub num_points: usize,
    /// Points after downsampling.
    pub num_points_downsampled: usize,
}

/// The running state of consecutive-frame registration.
#[derive(Debug)]
pub struct Odometry {
    config: OdometryConfig,
    previous: Option<(PreparedFrame, Isometry3<f64>)>,
    velocity: Isometry3<f64>,
    frames: usize,
}

impl Odometry {
    /// A new trajectory; fails if the pairwise configuration is invalid.
    pub fn new(config: OdometryConfig) -> Result<Self> {
        config.pair.resolved()?;
        if !(0.0..=1.0).contains(&config.min_fitness) {
            return Err(crate::Error::InvalidInput(format!(
                "min_fitness must be a fraction in [0, 1], got {}",
                config.min_fitness
            )));
        }
        Ok(Self {
            config,
            previous: None,
            velocity: Isometry3::identity(),
            frames: 0,
        })
    }

    /// The configuration in force.
    pub fn config(&self) -> &OdometryConfig {
        &self.config
    }

    /// Registers the next frame and returns its estimate.
    pub fn push(&mut self, frame: PreparedFrame) -> Result<FrameEstimate> {
        let index = self.frames;
        self.frames += 1;
        let mut est = FrameEstimate {
            index,
            world_from_frame: Isometry3::identity(),
            prev_from_curr: Isometry3::identity(),
            success: true,
            failure: None,
            fallback: None,
            pair: None,
            fallback_icp_iterations: 0,
            num_points: frame.num_points,
            num_points_downsampled: frame.points.len(),
        };
        let usable = frame.points.len() >= 3 && frame.icp.is_some();
        let Some((prev, world_from_prev)) = &self.previous else {
            // The first frame defines the world.
            if usable {
                self.previous = Some((frame, Isometry3::identity()));
            } else {
                est.success = false;
                est.failure = Some(FailureReason::TooFewPoints);
                est.fallback = Some(Fallback::ConstantVelocity);
            }
            return Ok(est);
        };
        let world_from_prev = *world_from_prev;
        if !usable {
            est.success = false;
            est.failure = Some(FailureReason::TooFewPoints);
            est.fallback = Some(Fallback::ConstantVelocity);
            est.prev_from_curr = self.velocity;
            est.world_from_frame = world_from_prev * self.velocity;
            // The previous frame stays the reference; the prediction advances one more step.
            self.previous = self.previous.take().map(|(f, _)| (f, est.world_from_frame));
            return Ok(est);
        }

        let pair = register_prepared(&frame, prev, &self.config.pair)?;
        let failure = pair
            .failure
            .or(if pair.num_inliers < self.config.min_inliers {
                Some(FailureReason::TooFewInliers)
            } else if pair.fitness < self.config.min_fitness {
                Some(FailureReason::LowFitness)
            } else {
                None
            });
        if failure.is_none() {
            est.prev_from_curr = pair.target_from_source;
            self.velocity = pair.target_from_source;
        } else {
            est.success = false;
            est.failure = failure;
            let (pose, fallback, iterations) = self.constant_velocity(&frame, prev)?;
            est.prev_from_curr = pose;
            est.fallback = Some(fallback);
            est.fallback_icp_iterations = iterations;
        }
        est.pair = Some(pair);
        est.world_from_frame = world_from_prev * est.prev_from_curr;
        self.previous = Some((frame, est.world_from_frame));
        Ok(est)
    }

    fn constant_velocity(
        &self,
        frame: &PreparedFrame,
        prev: &PreparedFrame,
    ) -> Result<(Isometry3<f64>, Fallback, usize)> {
        let c = self.config.pair.resolved()?;
        if let (Some(src), Some(tgt)) = (&frame.icp, &prev.icp) {
            let icp = IcpConfig::new(c.icp_max_distance_m.unwrap_or(c.voxel_size_m))
                .max_iterations(c.icp_max_iterations);
            let r = registration_icp_point_to_plane(src.points(), tgt, &self.velocity, &icp)?;
            if r.fitness >= self.config.min_fitness {
                return Ok((
                    r.target_from_source,
                    Fallback::ConstantVelocityIcp,
                    r.iterations,
                ));
            }
        }
        Ok((self.velocity, Fallback::ConstantVelocity, 0))
    }
}
