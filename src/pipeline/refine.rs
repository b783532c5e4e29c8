//! The refinement after RANSAC: point-to-plane ICP of the ICP clouds, then a fine stage on the
//! source's input points ([`PairConfig::icp_fine`]).

use nalgebra::Point3;
use rand::{RngExt, SeedableRng};

use super::{PairConfig, PairResult, PreparedFrame};
use crate::Result;
use crate::refine::icp::{
    IcpConfig, IcpResult, IcpTarget, evaluate_registration, registration_icp_point_to_plane,
};

/// Input points per ICP-cloud point in the fine stage's source: at most this many, drawn without
/// replacement from the finite input points.
///
/// NOTE: measured with `tools/compare_open3d.py` (docs/PAIRWISE.md, 20 poses × 2 seeds): 4, 6
/// and 8 per point all land closer to the reference than Open3D's ICP on the bunny, ICL-NUIM and
/// 3DMatch pairs; 8 did so in the 10-pose run too, where 4 and 6 left ICL-NUIM's rotation error
/// 0.002–0.005° above Open3D's. Every k-th point in input order instead of a random draw
/// aliased with the scanners' line order (bunny 000↔045: strides 7 and 8 gave 0.059° and 0.096°).
pub const FINE_POINTS_PER_ICP_POINT: usize = 8;

/// The fine stage stops when an update moves less than this fraction of its distance and
/// rotates less than this many radians (besides Open3D's fitness and RMSE criteria). It starts
/// from a converged pose, so its last updates are sub-micrometre jitter.
pub const FINE_MIN_UPDATE: (f64, f64) = (0.003, 3e-5);

/// The fine stage's source: `FINE_POINTS_PER_ICP_POINT · icp_points` of the finite `points`,
/// drawn uniformly without replacement (seeded by `seed`), in input order; all of them when
/// there are no more. Empty when `icp_points` is 0 or no point is finite.
pub(crate) fn fine_sample(
    points: &[Point3<f64>],
    icp_points: usize,
    seed: u64,
) -> Vec<Point3<f64>> {
    let finite = || {
        points
            .iter()
            .filter(|p| p.coords.iter().all(|x| x.is_finite()))
    };
    let n = finite().count();
    let wanted = FINE_POINTS_PER_ICP_POINT.saturating_mul(icp_points).min(n);
    // Selection sampling (Knuth's Algorithm S): each point is kept with probability
    // still wanted / still unseen, which draws exactly `wanted`, uniformly, in input order.
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let (mut left, mut unseen) = (wanted, n);
    let mut out = Vec::with_capacity(wanted);
    for p in finite() {
        if left == 0 {
            break;
        }
        if left == unseen || rng.random_range(0..unseen) < left {
            out.push(*p);
            left -= 1;
        }
        unseen -= 1;
    }
    out
}

/// The target feature cloud as a search target: its ICP cloud when that is the same cloud, else
/// built into `built` on first use.
pub(super) fn feature_tree<'a>(
    target: &'a PreparedFrame,
    built: &'a std::cell::OnceCell<IcpTarget>,
) -> Result<&'a IcpTarget> {
    if let Some(icp) = target.icp.as_ref().filter(|t| t.points() == target.points) {
        return Ok(icp);
    }
    if built.get().is_none() {
        let _ = built.set(IcpTarget::points_only(&target.points)?);
    }
    Ok(built.get().expect("just set"))
}

/// The fine stage after a converged ICP `coarse` of `icp_points` (at `distance`) against
/// `target`: point-to-plane ICP of `fine_points` from its pose at `fine_distance`, at most
/// `max_iterations` updates, stopping also on [`FINE_MIN_UPDATE`]. The result's fitness and RMSE
/// are measured as the coarse stage measures them (`icp_points` at `distance`), so acceptance
/// thresholds keep their meaning; its iterations are the fine stage's. `None` when `coarse` or
/// the fine stage found no correspondence (the coarse pose stands). Serves the pairwise
/// refinement and the odometry's map ICP.
pub(crate) fn fine_stage(
    fine_points: &[Point3<f64>],
    icp_points: &[Point3<f64>],
    target: &IcpTarget,
    coarse: &IcpResult,
    distance: f64,
    fine_distance: f64,
    max_iterations: usize,
) -> Result<Option<IcpResult>> {
    if coarse.fitness == 0.0 {
        return Ok(None);
    }
    let config = IcpConfig::new(fine_distance)
        .max_iterations(max_iterations)
        .min_update(FINE_MIN_UPDATE.0 * fine_distance, FINE_MIN_UPDATE.1)
        // The pose is measured below at the coarse stage's distance: a pass that would only
        // measure it at this one is skipped (a quarter of the stage's searches on the bunny).
        .evaluate_after_min_update(false);
    let f =
        registration_icp_point_to_plane(fine_points, target, &coarse.target_from_source, &config)?;
    if f.fitness == 0.0 {
        return Ok(None);
    }
    let e = evaluate_registration(icp_points, target, &f.target_from_source, distance)?;
    Ok(Some(IcpResult {
        fitness: e.fitness,
        inlier_rmse_m: e.inlier_rmse_m,
        ..f
    }))
}

/// ICP of `source` to `target` from `out.ransac_target_from_source`, then the fine stage when
/// the source has fine points (or, without ICP clouds, the fitness of that model on the feature
/// clouds, against `target_tree()`, only then consulted). `c` is resolved.
///
/// Fitness and RMSE are those of the final pose, measured as the first stage measures them (its
/// source and distance), so that acceptance thresholds keep their meaning.
pub(super) fn refine<'a>(
    out: &mut PairResult,
    source: &PreparedFrame,
    target: &PreparedFrame,
    c: &PairConfig,
    target_tree: impl FnOnce() -> Result<&'a IcpTarget>,
) -> Result<()> {
    let model = out.ransac_target_from_source;
    let (Some(src_icp), Some(tgt_icp)) = (&source.icp, &target.icp) else {
        let e = evaluate_registration(
            &source.points,
            target_tree()?,
            &model,
            c.inlier_threshold_m.unwrap(),
        )?;
        out.fitness = e.fitness;
        out.inlier_rmse_m = e.inlier_rmse_m;
        return Ok(());
    };
    let distance = c.icp_max_distance_m.unwrap();
    let icp_config = IcpConfig::new(distance).max_iterations(c.icp_max_iterations);
    let r = registration_icp_point_to_plane(src_icp.points(), tgt_icp, &model, &icp_config)?;
    out.target_from_source = r.target_from_source;
    out.fitness = r.fitness;
    out.inlier_rmse_m = r.inlier_rmse_m;
    out.icp_iterations = r.iterations;
    if !c.icp_fine || source.fine.is_empty() {
        return Ok(());
    }
    // NOTE: beyond Open3D's and the paper's single ICP. ICP on voxel centroids converges to an
    // optimum of those centroids, which moves with the voxel grid's phase (per posed source, the
    // bunny 000↔045 rotation error spreads over 0.04–0.125° for mireg and Open3D alike; on the
    // full input clouds it is 0.077° for every pose). The input points are samples of the
    // surface itself, and more of them average out the target's sampling; a closer distance
    // keeps only correspondences on the same surface. Measured in docs/PAIRWISE.md.
    let fine = fine_stage(
        &source.fine,
        src_icp.points(),
        tgt_icp,
        &r,
        distance,
        c.icp_fine_distance_m.unwrap(),
        c.icp_max_iterations,
    )?;
    let Some(f) = fine else {
        return Ok(());
    };
    out.target_from_source = f.target_from_source;
    out.fitness = f.fitness;
    out.inlier_rmse_m = f.inlier_rmse_m;
    out.icp_iterations += f.iterations;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selection_sampling_includes_every_point_with_the_same_probability() {
        // 40 points, 1 ICP point: 8 wanted, so each point is in a draw with probability 1/5.
        let points: Vec<Point3<f64>> = (0..40)
            .map(|i| Point3::new(f64::from(i), 0.0, 0.0))
            .collect();
        let runs = 4000;
        let mut hits = [0u32; 40];
        for seed in 0..runs {
            let draw = fine_sample(&points, 1, seed);
            assert_eq!(draw.len(), FINE_POINTS_PER_ICP_POINT);
            assert!(draw.windows(2).all(|w| w[0].x < w[1].x), "input order");
            for p in draw {
                hits[p.x as usize] += 1;
            }
        }
        // Binomial(4000, 0.2): σ = 25.3 hits; within 5σ of 800 everywhere.
        for (i, &h) in hits.iter().enumerate() {
            assert!((i64::from(h) - 800).abs() < 127, "point {i}: {h} of {runs}");
        }
    }
}
