//! A frame refined on the local map: point-to-plane ICP from each initial guess that makes sense,
//! coarse to fine, and the map brought up to date as the target of those refinements.

use nalgebra::{Isometry3, Point3};

use super::map_input::{add_to_map, add_to_map_and_target};
use super::retry::RetryInputs;
use super::{
    InitialGuess, MAP_FINE_FINISHES_MIN_STRIDE, MAP_FINE_MAX_ITERATIONS, MAP_FINE_MAX_POINTS,
    MAP_FINE_POINTS_PER_ICP_POINT, MAP_ICP_MAX_ITERATIONS_AFTER_COARSE, MAP_ICP_MIN_UPDATE,
    MAP_ICP_RELATIVE_CHANGE, MapFit, Odometry, Rival,
};
use crate::Result;
use crate::pipeline::refine::{FineInputs, fine_stage};
use crate::pipeline::{PairConfig, PairResult, PreparedFrame};
use crate::refine::icp::{IcpConfig, IcpResult, IcpTarget, registration_icp_point_to_plane};
use crate::refine::local_map::LocalMap;

impl Odometry {
    /// The global estimate (or, where it is doubtful, a second RANSAC stream's or the
    /// constant-velocity prediction) refined on the map, if it fits: the pose and fit to accept,
    /// with `pair` updated to it (the second stream's result where that won). `None`: refine
    /// frame to frame instead.
    pub(super) fn global_on_map(
        &self,
        (index, frame): (usize, &PreparedFrame),
        prev: &PreparedFrame,
        target: (&IcpTarget, f64),
        pair: &mut PairResult,
        world_from_prev: &Isometry3<f64>,
        predicted: &Isometry3<f64>,
    ) -> Result<Option<(Isometry3<f64>, MapFit)>> {
        let last_map_fitness = self.last_map_fitness;
        let max_hypotheses = self.config.pair.max_hypotheses;
        let found = pair.failure.is_none() && pair.num_inliers >= self.config.min_inliers;
        let mut first = None;
        if found {
            let global = world_from_prev * pair.target_from_source;
            first = self.refine_on_map(frame, target, Some(&global), predicted)?;
        }
        // NOTE: the retries also answer a global registration that found no model, or stopped
        // at its hypothesis budget unconverged, or whose estimate disagrees with the
        // prediction: one RANSAC stream either failing (its frame then tracked from the
        // prediction) or not decided whether a log registered right hinged on the seed (issue:
        // a real Livox log's hard frame slid 1.4 m for some seeds, registered for others), and
        // on a narrow view a model of no motion fitted the map at 0.53 while the car moved 2.4 m
        // (`retry.rs`).
        let capped = pair.hypotheses >= max_hypotheses && !pair.converged;
        let distance = map_icp_distance(&self.config.pair)?;
        let retry = match &first {
            None => !found,
            Some((pose, fit)) => {
                fit.guess == InitialGuess::Global
                    && (capped
                        || self.doubtful(fit.fitness)
                        || self.far_from_prediction(pose, predicted, distance))
            }
        };
        let mut seen = Vec::new();
        if let Some((pose, fit)) = &first {
            seen.push((*pose, *fit));
        }
        let inputs = RetryInputs {
            frame,
            prev,
            indices: (index, self.previous_index),
            target,
            world_from_prev,
            predicted,
        };
        let round = self.retry_rounds(retry, inputs, distance, pair, &mut first, &mut seen)?;
        // NOTE: where both global estimates fit the map doubtfully, the constant-velocity
        // prediction is tried too and wins if it fits better: after a frame whose own
        // features were poor (a floor alone), global registration against it went 3 m
        // wrong at a map fitness of 0.32 while the prediction fitted at 0.997
        // (`tests/suspect_steps.rs`).
        let mut tracked = false;
        if let Some((_, fit)) = &first
            && last_map_fitness.is_some()
            && self.doubtful(fit.fitness)
            && let Some((pose, refit)) = self.refine_on_map(frame, target, None, predicted)?
            && refit.used
            && refit.fitness > fit.fitness
        {
            seen.push((pose, refit));
            first = Some((pose, refit));
            tracked = true;
        }
        if let Some((pose, fit)) = first
            && fit.used
            && (tracked || fit.guess.is_global())
        {
            pair.target_from_source = world_from_prev.inverse() * pose;
            pair.fitness = fit.fitness;
            pair.inlier_rmse_m = fit.inlier_rmse_m;
            let fit = MapFit {
                retry_rounds: round as usize,
                rival: rival(&seen, &pose, distance),
                ..fit
            };
            return Ok(Some((pose, fit)));
        }
        Ok(None)
    }

    /// ICP of `frame` against the local map from the initial guesses that make sense: the global
    /// estimate when global registration succeeded, and the constant-velocity prediction
    /// `predicted` when there is no global estimate, or when the global start fitted the map
    /// poorly (fitness below `min_fitness`) and the prediction is not within the correspondence
    /// distance and 1° of it (both would converge alike). The best fit wins: highest fitness,
    /// then lowest RMSE, the global start on a tie.
    ///
    /// NOTE: the prediction is not tried when the global start already fits the map: on the
    /// KAIST03 keyframes trying both cost a third of the frame rate for no accuracy
    /// (docs/ODOMETRY.md); where the global estimate is wrong, its fit to the map is poor.
    ///
    /// `target` is the map as an ICP target and the seconds it took to build.
    pub(super) fn refine_on_map(
        &self,
        frame: &PreparedFrame,
        (target, target_s): (&IcpTarget, f64),
        global: Option<&Isometry3<f64>>,
        predicted: &Isometry3<f64>,
    ) -> Result<Option<(Isometry3<f64>, MapFit)>> {
        let t = std::time::Instant::now();
        let Some(plan) = self.map_icp_plan(frame, target, target_s)? else {
            return Ok(None);
        };
        let from_global = if let Some(global) = global {
            let f = plan.fit(InitialGuess::Global, global)?;
            let close = within(global, predicted, plan.distance);
            if f.1.used || close {
                let (pose, fit) = f;
                let icp_s = t.elapsed().as_secs_f64();
                return Ok(Some((pose, MapFit { icp_s, ..fit })));
            }
            Some(f)
        } else {
            None
        };
        let from_prediction = plan.fit(InitialGuess::ConstantVelocity, predicted)?;
        let icp_s = t.elapsed().as_secs_f64();
        let (pose, best) = match from_global {
            Some(g)
                if g.1.fitness > from_prediction.1.fitness
                    || (g.1.fitness == from_prediction.1.fitness
                        && g.1.inlier_rmse_m <= from_prediction.1.inlier_rmse_m) =>
            {
                g
            }
            _ => from_prediction,
        };
        Ok(Some((pose, MapFit { icp_s, ..best })))
    }

    /// How `frame` is refined on the map `target` (built in `target_s` seconds): its sources
    /// and ICP settings; `None` without a map or an ICP cloud.
    fn map_icp_plan<'a>(
        &self,
        frame: &'a PreparedFrame,
        target: &'a IcpTarget,
        target_s: f64,
    ) -> Result<Option<MapIcpPlan<'a>>> {
        let (Some(map), Some(icp_cloud)) = (&self.map, &frame.icp) else {
            return Ok(None);
        };
        let c = self.config.pair.resolved()?;
        let distance = map_icp_distance(&c)?;
        let icp = IcpConfig::new(distance)
            .max_iterations(c.icp_max_iterations)
            .relative_fitness(MAP_ICP_RELATIVE_CHANGE)
            .relative_rmse(MAP_ICP_RELATIVE_CHANGE * distance);
        let dense_icp = icp.min_update(
            MAP_ICP_MIN_UPDATE.0 * distance,
            MAP_ICP_MIN_UPDATE.1.to_radians(),
        );
        // Coarse to fine: where global registration ran on a coarser cloud than ICP
        // (`OdometryConfig::feature_points`), ICP against the map first converges with every
        // k-th ICP point as source, as many as that cloud has, and the ICP cloud then finishes.
        // NOTE: not the coarser cloud itself, whose centroids of large voxels are biased samples
        // of the surface: from their optimum the ICP cloud needed 5 updates on KAIST03, with a
        // 2-update cap ATE rose 2.46 → 2.91 cm (docs/ODOMETRY.md).
        let stride = icp_cloud.points().len().div_ceil(frame.points.len().max(1));
        let coarse: Option<Vec<Point3<f64>>> =
            (stride > 1).then(|| icp_cloud.points().iter().step_by(stride).copied().collect());
        let finish_icp = match coarse {
            Some(_) => dense_icp.max_iterations(
                c.icp_max_iterations
                    .min(MAP_ICP_MAX_ITERATIONS_AFTER_COARSE),
            ),
            None => dense_icp,
        };
        let fine: Option<Vec<Point3<f64>>> = (self.config.map_fine && !frame.fine.is_empty())
            .then(|| map_fine_points(frame).copied().collect());
        // A stage whose last pose the next stage measures skips the pass that would only
        // measure it: the coarse start always (the ICP cloud's first pass does), the ICP cloud
        // where the fine stage follows (it measures the final pose on that cloud at that
        // distance, the ICP cloud's own where it finds nothing). On the KITTI replay log, a
        // fifth of the map ICP's instructions (callgrind).
        let coarse_icp = dense_icp.measure_final_pose(false);
        let finish_icp = finish_icp.measure_final_pose(fine.is_none());
        let fine_finishes = fine.is_some() && stride >= MAP_FINE_FINISHES_MIN_STRIDE;
        Ok(Some(MapIcpPlan {
            target,
            target_s,
            map_points: map.len(),
            min_fitness: self.config.min_fitness,
            icp_points: icp_cloud.points(),
            coarse,
            fine,
            distance,
            coarse_icp,
            finish_icp,
            fine_finishes,
        }))
    }
}

/// A frame's refinement on the map ([`Odometry::map_icp_plan`]): ICP from a start on the coarse
/// source (every k-th ICP point, when global registration ran on a coarser cloud), then the ICP
/// cloud, then the fine stage on the input points drawn for it.
struct MapIcpPlan<'a> {
    target: &'a IcpTarget,
    /// Seconds the target took to build, and its points.
    target_s: f64,
    map_points: usize,
    /// [`super::OdometryConfig::min_fitness`].
    min_fitness: f64,
    icp_points: &'a [Point3<f64>],
    coarse: Option<Vec<Point3<f64>>>,
    fine: Option<Vec<Point3<f64>>>,
    /// The correspondence distance \[m\]; the fine stage uses half.
    distance: f64,
    coarse_icp: IcpConfig,
    finish_icp: IcpConfig,
    /// The fine stage follows a converged coarse stage directly, without the whole ICP cloud
    /// between them ([`MAP_FINE_FINISHES_MIN_STRIDE`]).
    fine_finishes: bool,
}

impl MapIcpPlan<'_> {
    /// The refinement from `start`, its result labelled `guess`.
    fn fit(&self, guess: InitialGuess, start: &Isometry3<f64>) -> Result<(Isometry3<f64>, MapFit)> {
        let target = self.target;
        let coarse = match self.coarse.as_deref() {
            Some(points) => Some(registration_icp_point_to_plane(
                points,
                target,
                start,
                &self.coarse_icp,
            )?),
            None => None,
        };
        let coarse_iterations = coarse.as_ref().map_or(0, |c| c.iterations);
        // The whole ICP cloud finishes the coarse stage unless the fine stage can: see
        // [`MAP_FINE_FINISHES_MIN_STRIDE`]. A coarse stage stopped by its iteration cap had not
        // converged (a frame after a gap: 30 updates), and the whole cloud finishes it.
        let mut r = match coarse {
            Some(c) if self.fine_finishes && c.iterations < self.coarse_icp.max_iterations => {
                IcpResult { iterations: 0, ..c }
            }
            _ => {
                let from = coarse.map_or(*start, |c| c.target_from_source);
                registration_icp_point_to_plane(self.icp_points, target, &from, &self.finish_icp)?
            }
        };
        let mut fine_iterations = 0;
        if let Some(points) = self.fine.as_deref() {
            let inputs = FineInputs {
                points,
                target,
                distance_m: 0.5 * self.distance,
                max_iterations: MAP_FINE_MAX_ITERATIONS,
            };
            let f = fine_stage(&inputs, self.icp_points, target, &r, self.distance)?;
            fine_iterations = f.iterations;
            r = IcpResult {
                iterations: r.iterations,
                ..f
            };
        }
        let fit = MapFit {
            guess,
            fitness: r.fitness,
            inlier_rmse_m: r.inlier_rmse_m,
            iterations: r.iterations,
            fine_iterations,
            coarse_iterations,
            map_points: self.map_points,
            used: r.fitness >= self.min_fitness,
            target_s: self.target_s,
            icp_s: 0.0,
            hessian: r.hessian,
            retry_rounds: 0,
            rival: None,
        };
        Ok((r.target_from_source, fit))
    }
}

/// The best-fitting start in `seen` (refined poses and their fits) that was used and does not
/// agree with the accepted `pose` ([`within`] `distance`): its fitness and its offset from `pose`.
fn rival(seen: &[(Isometry3<f64>, MapFit)], pose: &Isometry3<f64>, distance: f64) -> Option<Rival> {
    seen.iter()
        .filter(|(p, fit)| fit.used && !within(pose, p, distance))
        .max_by(|a, b| a.1.fitness.total_cmp(&b.1.fitness))
        .map(|(p, fit)| Rival {
            fitness: fit.fitness,
            offset: pose.inverse() * p,
        })
}

/// Whether poses `a` and `b` are within `distance` \[m\] and 1° of each other: ICP from either
/// would converge alike.
pub(super) fn within(a: &Isometry3<f64>, b: &Isometry3<f64>, distance: f64) -> bool {
    let apart = a.inverse() * b;
    apart.translation.vector.norm() <= distance && apart.rotation.angle() <= 1f64.to_radians()
}

/// The local map (with the previous frame `prev` added at `world_from_prev` if it is still
/// pending) built as an ICP target at `distance` \[m\] for `frame`: the seconds it took, or
/// `None` without a map or target.
pub(super) fn map_target(
    map: &mut Option<LocalMap>,
    map_pending: &mut bool,
    frame: &PreparedFrame,
    prev: &PreparedFrame,
    world_from_prev: &Isometry3<f64>,
    distance: f64,
) -> Result<Option<f64>> {
    let t = std::time::Instant::now();
    let Some(map) = map.as_mut() else {
        return Ok(None);
    };
    let pending = std::mem::take(map_pending);
    if frame.icp.is_none() {
        if pending {
            add_to_map(map, prev, world_from_prev);
        }
        return Ok(None);
    }
    let target = if pending {
        add_to_map_and_target(map, prev, world_from_prev, distance)?
    } else {
        map.target(distance)?
    };
    let Some(target) = target else {
        return Ok(None);
    };
    target.prepare_for_distance(distance)?;
    Ok(Some(t.elapsed().as_secs_f64()))
}

/// The correspondence distance of ICP against the map \[m\]: the ICP distance.
pub(super) fn map_icp_distance(pair: &PairConfig) -> Result<f64> {
    let c = pair.resolved()?;
    Ok(c.icp_max_distance_m.unwrap_or(c.voxel_size_m))
}

/// The input points of `frame` that the map ICP's fine stage uses
/// ([`OdometryConfig::map_fine`]): the frame carries [`MAP_FINE_DRAW_PER_ICP_POINT`] per
/// ICP point (a uniform draw in input order); every k-th of them is a
/// uniform draw of about [`MAP_FINE_POINTS_PER_ICP_POINT`] per ICP point, at most
/// [`MAP_FINE_MAX_POINTS`]. Keeping only these ([`keep_map_fine_points`]) leaves the same ones.
fn map_fine_points(frame: &PreparedFrame) -> impl Iterator<Item = &Point3<f64>> {
    let icp_points = frame.icp.as_ref().map_or(0, |icp| icp.points().len());
    let wanted = (MAP_FINE_POINTS_PER_ICP_POINT * icp_points).clamp(1, MAP_FINE_MAX_POINTS);
    let step = frame.fine.len().div_ceil(wanted).max(1);
    frame.fine.iter().step_by(step)
}

/// Drops the input points a prepared frame carries beyond those the map ICP's fine stage uses
/// ([`map_fine_points`]: the stage then picks the same ones), so that frames waiting between
/// the preparing and the registering thread hold a few thousand points, not eight per ICP point
/// (the KITTI replay log: 88k).
pub fn keep_map_fine_points(frame: &mut PreparedFrame) {
    let kept: Vec<Point3<f64>> = map_fine_points(frame).copied().collect();
    frame.keep_fine(kept);
}
