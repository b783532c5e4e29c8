//! The refinement after RANSAC: point-to-plane ICP of the ICP clouds, then a fine stage on the
//! source's input points ([`PairConfig::icp_fine`]).

use nalgebra::{Matrix3, Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;

use super::{PairConfig, PairResult, PreparedFrame};
use crate::Result;
use crate::geometry::normals::smallest_eigenvector;
use crate::refine::icp::{
    IcpConfig, IcpHessian, IcpResult, IcpTarget, evaluate_registration, evaluate_with_hessian,
    registration_icp_point_to_plane,
};

/// Input points per ICP-cloud point drawn for the fine stage: its source, and its target's
/// points and planes ([`fine_target`]). Default of [`super::PairConfig::icp_fine_points_per_icp_point`].
///
/// NOTE: measured with `tools/compare_open3d.py` (docs/PAIRWISE.md, 10 poses × seeds 0 and 1),
/// together with the input-point target: 6 per point lands closer to the reference than Open3D's
/// ICP in rotation and translation on all five pairs and both seeds; 4 left the KITTI rotation
/// above Open3D's (0.0115° vs 0.0087°), 8 the bunny 000↔045 translation (0.090 vs 0.086 mm).
/// With the ICP-cloud target alone (before), 8 was the choice. Every k-th point in input order
/// instead of a random draw aliased with the scanners' line order (bunny 000↔045: strides 7 and
/// 8 gave 0.059° and 0.096°).
pub const FINE_POINTS_PER_ICP_POINT: usize = 6;

/// Input points per ICP-cloud point in the fine stage's source: a uniform draw from the
/// frame's [`FINE_POINTS_PER_ICP_POINT`], of which the target keeps all.
///
/// NOTE: measured with `tools/compare_open3d.py` (docs/PAIRWISE.md): with 4 instead of all 6,
/// RE and TE stay below Open3D's on every pair for seeds 0 and 1, and the fine stage's searches
/// drop by a third.
pub const FINE_SOURCE_POINTS_PER_ICP_POINT: usize = 4;

/// A fine-stage target point takes the normal of the plane through the drawn points that share
/// its nearest ICP-cloud point when there are at least this many of them; else that point's own
/// normal.
pub const FINE_PLANE_MIN_POINTS: u32 = 5;

/// The fine stage stops when an update moves less than this fraction of its distance and
/// rotates less than this many radians (besides Open3D's fitness and RMSE criteria). It starts
/// from a converged pose, so its last updates are sub-micrometre jitter.
pub const FINE_MIN_UPDATE: (f64, f64) = (0.003, 3e-5);

/// The fine stage's draw: `per_icp_point · icp_points` of the finite `points`, drawn uniformly
/// without replacement (seeded by `seed`), in input order; all of them when there are no more.
/// With `voxel_of` (one entry per point), also the entry of each drawn point. Empty when
/// `icp_points` is 0 or no point is finite.
pub(crate) fn fine_sample(
    points: &[Point3<f64>],
    voxel_of: Option<&[u32]>,
    icp_points: usize,
    per_icp_point: usize,
    seed: u64,
) -> (Vec<Point3<f64>>, Vec<u32>) {
    let finite = || {
        points
            .iter()
            .enumerate()
            .filter(|(_, p)| p.coords.iter().all(|x| x.is_finite()))
    };
    let n = finite().count();
    let wanted = per_icp_point.saturating_mul(icp_points).min(n);
    // Selection sampling (Knuth's Algorithm S): each point is kept with probability
    // still wanted / still unseen, which draws exactly `wanted`, uniformly, in input order.
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let (mut left, mut unseen) = (wanted, n);
    let mut out = Vec::with_capacity(wanted);
    let mut voxels = Vec::with_capacity(if voxel_of.is_some() { wanted } else { 0 });
    for (i, p) in finite() {
        if left == 0 {
            break;
        }
        if left == unseen || rng.random_range(0..unseen) < left {
            out.push(*p);
            if let Some(v) = voxel_of {
                voxels.push(v[i]);
            }
            left -= 1;
        }
        unseen -= 1;
    }
    (out, voxels)
}

/// The fine stage's target: the target frame's `drawn` input points, each with the normal of
/// the plane fitted to the drawn points of its voxel of the ICP cloud `icp` (`voxel_of`: the
/// index of each drawn point's voxel, whose centroid is that ICP point) when there are at least
/// [`FINE_PLANE_MIN_POINTS`], else that ICP point's own normal. `None` when `icp` has no normals
/// or nothing was drawn.
///
/// NOTE: beyond Open3D's and the paper's ICP. Input points lie on the surface, where voxel
/// centroids average across it: against the centroids, the fine stage left the KITTI pair 0.0155°
/// and 5.4 mm from the dense-ICP reference; against these points, 0.0058° and 0.96 mm (Open3D +
/// ICP: 0.0087°, 10.7 mm). A plane per voxel from the points drawn there costs one pass, where
/// a normal from each point's own neighbours would cost a neighbourhood search and an
/// eigen-solve per point (docs/PAIRWISE.md).
pub(crate) fn fine_target(
    drawn: &[Point3<f64>],
    voxel_of: &[u32],
    icp: &IcpTarget,
) -> Result<Option<IcpTarget>> {
    let Some(normals) = icp.normals() else {
        return Ok(None);
    };
    if drawn.is_empty() {
        return Ok(None);
    }
    let centres = icp.points();
    if voxel_of.len() != drawn.len() || voxel_of.iter().any(|&v| v as usize >= centres.len()) {
        return Err(crate::Error::InvalidInput(format!(
            "{} drawn points with {} voxel indices into {} ICP points",
            drawn.len(),
            voxel_of.len(),
            centres.len()
        )));
    }
    // Per voxel, in draw order: the count, and the sums of the offsets from its centroid and of
    // their outer products (offsets keep the sums small where the coordinates are large).
    let mut cells = vec![(0u32, Vector3::<f64>::zeros(), Matrix3::<f64>::zeros()); centres.len()];
    for (p, &v) in drawn.iter().zip(voxel_of) {
        let d = p - centres[v as usize];
        let cell = &mut cells[v as usize];
        cell.0 += 1;
        cell.1 += d;
        cell.2 += d * d.transpose();
    }
    let planes: Vec<Vector3<f64>> = cells
        .par_iter()
        .zip(normals)
        .map(|((n, sum, outer), own)| {
            if *n < FINE_PLANE_MIN_POINTS {
                return *own;
            }
            let n = f64::from(*n);
            let mean = sum / n;
            smallest_eigenvector(&(outer / n - mean * mean.transpose())).unwrap_or(*own)
        })
        .collect();
    let point_normals = voxel_of.iter().map(|&v| planes[v as usize]).collect();
    IcpTarget::from_storage(drawn.to_vec(), point_normals, Default::default()).map(Some)
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

/// What the fine stage aligns: input points of the source against a target (the pair's
/// [`fine_target`], or the coarse stage's target itself), within a distance.
pub(crate) struct FineInputs<'a> {
    /// Input points of the source.
    pub points: &'a [Point3<f64>],
    /// Their target.
    pub target: &'a IcpTarget,
    /// Max correspondence distance \[m\].
    pub distance_m: f64,
    /// At most this many updates.
    pub max_iterations: usize,
}

/// The fine stage after a converged ICP `coarse` of `icp_points` (at `distance`) against
/// `target`: point-to-plane ICP of `fine.points` against `fine.target` from its pose, stopping
/// also on [`FINE_MIN_UPDATE`]. Its pose, or `coarse`'s where `coarse` or the fine stage found no
/// correspondence, measured as the coarse stage measures it (`icp_points` against `target` at
/// `distance`: fitness, RMSE and Hessian), so acceptance thresholds keep their meaning and
/// `coarse` need not measure its own last pose ([`IcpConfig::measure_final_pose`]); the
/// iterations are the fine stage's (0 where its pose did not stand). Serves the pairwise
/// refinement and the odometry's map ICP.
pub(crate) fn fine_stage(
    fine: &FineInputs<'_>,
    icp_points: &[Point3<f64>],
    target: &IcpTarget,
    coarse: &IcpResult,
    distance: f64,
) -> Result<IcpResult> {
    let measured = |result: IcpResult| -> Result<IcpResult> {
        let (e, hessian) = if target.has_normals() {
            evaluate_with_hessian(icp_points, target, &result.target_from_source, distance)?
        } else {
            let e =
                evaluate_registration(icp_points, target, &result.target_from_source, distance)?;
            (e, IcpHessian::ZERO)
        };
        Ok(IcpResult {
            fitness: e.fitness,
            inlier_rmse_m: e.inlier_rmse_m,
            hessian,
            ..result
        })
    };
    let coarse_stands = IcpResult {
        iterations: 0,
        ..*coarse
    };
    if coarse.fitness == 0.0 {
        return measured(coarse_stands);
    }
    let config = IcpConfig::new(fine.distance_m)
        .max_iterations(fine.max_iterations)
        .min_update(FINE_MIN_UPDATE.0 * fine.distance_m, FINE_MIN_UPDATE.1)
        // The pose is measured below at the coarse stage's distance: a pass that would only
        // measure it at this one is skipped (a quarter of the stage's searches on the bunny).
        .measure_final_pose(false);
    let f = registration_icp_point_to_plane(
        fine.points,
        fine.target,
        &coarse.target_from_source,
        &config,
    )?;
    measured(if f.fitness == 0.0 { coarse_stands } else { f })
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
    let fine_runs = c.icp_fine && !source.fine.is_empty();
    // The fine stage measures the final pose on this stage's cloud and distance: the pass
    // that would only measure this stage's last pose is skipped.
    let icp_config = IcpConfig::new(distance)
        .max_iterations(c.icp_max_iterations)
        .measure_final_pose(!fine_runs);
    let thinned = c
        .icp_max_source_points
        .and_then(|max| thin(src_icp.points(), max));
    let src_points = thinned.as_deref().unwrap_or(src_icp.points());
    let r = registration_icp_point_to_plane(src_points, tgt_icp, &model, &icp_config)?;
    out.target_from_source = r.target_from_source;
    out.fitness = r.fitness;
    out.inlier_rmse_m = r.inlier_rmse_m;
    out.icp_iterations = r.iterations;
    out.icp_hessian = Some(r.hessian);
    if !fine_runs {
        return Ok(());
    }
    // NOTE: beyond Open3D's and the paper's single ICP. ICP on voxel centroids converges to an
    // optimum of those centroids, which moves with the voxel grid's phase (per posed source, the
    // bunny 000↔045 rotation error spreads over 0.04–0.125° for mireg and Open3D alike; on the
    // full input clouds it is 0.077° for every pose). The input points are samples of the
    // surface itself, and more of them average out the target's sampling; a closer distance
    // keeps only correspondences on the same surface. Measured in docs/PAIRWISE.md.
    let fine_target = target.fine_target()?.unwrap_or(tgt_icp);
    let inputs = FineInputs {
        points: source.fine_source(),
        target: fine_target,
        distance_m: c.icp_fine_distance_m.unwrap(),
        max_iterations: c.icp_max_iterations,
    };
    let f = fine_stage(&inputs, src_points, tgt_icp, &r, distance)?;
    out.target_from_source = f.target_from_source;
    out.fitness = f.fitness;
    out.inlier_rmse_m = f.inlier_rmse_m;
    out.icp_iterations += f.iterations;
    out.icp_hessian = Some(f.hessian);
    Ok(())
}

/// Every `ceil(n / max)`-th of `points`, when there are more than `max` (at least 1); `None`
/// when all are kept. An even stride over the ICP cloud's voxel order spreads the kept points
/// over the whole cloud.
fn thin(points: &[Point3<f64>], max: usize) -> Option<Vec<Point3<f64>>> {
    let max = max.max(1);
    (points.len() > max).then(|| {
        points
            .iter()
            .step_by(points.len().div_ceil(max))
            .copied()
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thinning_keeps_at_most_max_points_spread_over_the_cloud() {
        let points: Vec<Point3<f64>> = (0..10)
            .map(|i| Point3::new(f64::from(i), 0.0, 0.0))
            .collect();
        assert_eq!(thin(&points, 10), None);
        assert_eq!(thin(&points, 0).unwrap().len(), 1);
        let kept: Vec<f64> = thin(&points, 4).unwrap().iter().map(|p| p.x).collect();
        assert_eq!(kept, vec![0.0, 3.0, 6.0, 9.0]);
        let kept: Vec<f64> = thin(&points, 3).unwrap().iter().map(|p| p.x).collect();
        assert_eq!(kept, vec![0.0, 4.0, 8.0]);
    }

    #[test]
    fn selection_sampling_includes_every_point_with_the_same_probability() {
        // 40 points, 1 ICP point, 8 per ICP point: each point is in a draw with probability 1/5.
        let points: Vec<Point3<f64>> = (0..40)
            .map(|i| Point3::new(f64::from(i), 0.0, 0.0))
            .collect();
        let runs = 4000;
        let mut hits = [0u32; 40];
        for seed in 0..runs {
            let (draw, _) = fine_sample(&points, None, 1, 8, seed);
            assert_eq!(draw.len(), 8);
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

    #[test]
    fn the_draw_keeps_each_drawn_points_voxel_and_skips_non_finite_points() {
        let mut points: Vec<Point3<f64>> = (0..50)
            .map(|i| Point3::new(f64::from(i), 0.0, 0.0))
            .collect();
        points[3].y = f64::NAN;
        points[30].z = f64::INFINITY;
        let voxel_of: Vec<u32> = (0..50).map(|i| (i * 7 % 11) as u32).collect();
        for seed in 0..20 {
            let (plain, _) = fine_sample(&points, None, 4, 3, seed);
            let (draw, voxels) = fine_sample(&points, Some(&voxel_of), 4, 3, seed);
            assert_eq!(draw, plain, "the voxels do not change the draw");
            assert_eq!(draw.len(), 12);
            assert_eq!(voxels.len(), draw.len());
            for (p, v) in draw.iter().zip(&voxels) {
                assert!(p.coords.iter().all(|c| c.is_finite()));
                assert_eq!(*v, voxel_of[p.x as usize]);
            }
        }
        // More wanted than finite points: all 48 of them.
        assert_eq!(fine_sample(&points, None, 100, 6, 1).0.len(), 48);
    }

    #[test]
    fn the_fine_target_takes_each_voxels_plane_or_its_centroids_normal() {
        use rand::RngExt;
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        // Three ICP points with deliberately wrong normals: +z everywhere.
        let centres = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(10.0, 0.0, 0.0),
            Point3::new(20.0, 0.0, 0.0),
        ];
        let icp = IcpTarget::new(&centres, &[Vector3::z(); 3]).unwrap();
        // Voxel 0: 20 points on the plane x + y + z = 0; voxel 1: 6 on x = 10; voxel 2: 4 points
        // (below FINE_PLANE_MIN_POINTS) on y = 0. Interleaved, as a draw in input order is.
        let planes = [
            Vector3::new(1.0, 1.0, 1.0).normalize(),
            Vector3::x(),
            Vector3::y(),
        ];
        let counts = [20, 6, 4];
        let mut drawn = Vec::new();
        let mut voxel_of = Vec::new();
        for round in 0..20 {
            for v in 0..3 {
                if round >= counts[v] {
                    continue;
                }
                // A random point of the plane through the centre.
                let r = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0));
                let n = planes[v];
                drawn.push(centres[v] + (r - n * n.dot(&r)));
                voxel_of.push(v as u32);
            }
        }
        let target = fine_target(&drawn, &voxel_of, &icp).unwrap().unwrap();
        assert_eq!(target.points(), &drawn[..], "the drawn points, in order");
        for ((n, &v), p) in target.normals().unwrap().iter().zip(&voxel_of).zip(&drawn) {
            let expected = if v == 2 {
                Vector3::z()
            } else {
                planes[v as usize]
            };
            assert!(n.dot(&expected).abs() > 1.0 - 1e-9, "voxel {v} at {p}: {n}");
        }
        // Indices that do not fit the ICP cloud are refused; nothing drawn gives no target.
        assert!(fine_target(&drawn, &voxel_of[1..], &icp).is_err());
        let mut wrong = voxel_of.clone();
        wrong[0] = 3;
        assert!(fine_target(&drawn, &wrong, &icp).is_err());
        assert!(fine_target(&[], &[], &icp).unwrap().is_none());
    }

    #[test]
    fn a_draw_of_no_points_per_icp_point_is_refused() {
        let config = super::super::PairConfig {
            icp_fine_points_per_icp_point: 0,
            ..Default::default()
        };
        assert!(config.resolved().is_err());
    }

    #[test]
    fn the_fine_source_is_a_seeded_sub_draw_of_the_frames_draw() {
        use rand::RngExt;
        let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
        // A noisy box surface of 20 000 points: ~1 000 ICP points at 0.1 m.
        let points: Vec<Point3<f64>> = (0..20_000)
            .map(|_| {
                let mut p: [f64; 3] = std::array::from_fn(|_| rng.random_range(0.0..2.0));
                p[rng.random_range(0..3)] = if rng.random::<bool>() { 0.0 } else { 2.0 };
                Point3::from(p)
            })
            .collect();
        let config = super::super::PairConfig {
            voxel_size_m: 0.1,
            ..Default::default()
        };
        let frame = super::super::prepare_frame(&points, &config).unwrap();
        let icp_points = frame.icp.as_ref().unwrap().points().len();
        assert_eq!(frame.fine.len(), FINE_POINTS_PER_ICP_POINT * icp_points);
        let source = frame.fine_source();
        assert_eq!(source.len(), FINE_SOURCE_POINTS_PER_ICP_POINT * icp_points);
        // A subset of the draw, in its order: each source point is found after the previous one.
        let mut at = 0;
        for p in source {
            at += frame.fine[at..]
                .iter()
                .position(|q| q == p)
                .expect("in the draw")
                + 1;
        }
        // Spread over the whole draw, not a prefix of it.
        let last = frame
            .fine
            .iter()
            .position(|q| q == source.last().unwrap())
            .unwrap();
        assert!(
            last > frame.fine.len() * 9 / 10,
            "{last} of {}",
            frame.fine.len()
        );
        // Seeded by the frame: the same for the same frame, another for another seed.
        let again = super::super::prepare_frame(&points, &config).unwrap();
        assert_eq!(again.fine_source(), source);
        let reseeded = super::super::PairConfig { seed: 1, ..config };
        let other = super::super::prepare_frame(&points, &reseeded).unwrap();
        assert_ne!(other.fine_source(), source);
    }
}
