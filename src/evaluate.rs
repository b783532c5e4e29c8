//! Trajectory error metrics (Sturm et al. 2012, "A Benchmark for the Evaluation of RGB-D SLAM
//! Systems"): absolute trajectory error after alignment and relative pose error. Pure functions;
//! the `evaluate` job that reads a `register` output and its reference is `job.rs`, the `export`
//! job that writes its trajectory as text `export.rs`, the check of their input `inputs.rs`.

mod export;
mod inputs;
mod job;

pub use export::{
    ExportFormat, ExportOptions, export_to_file, read_export, write_export, write_trajectory,
};
pub use inputs::registered_log;
pub use job::{
    EvaluateOptions, EvaluateSummary, LogEvaluation, TrajectoryFormat, evaluate_log, evaluate_run,
    evaluation_json, run_topics,
};

use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};

/// Relative pose error between consecutive frames: for each `k ≥ 1`,
/// `E_k = (gt_{k−1}⁻¹ gt_k)⁻¹ (est_{k−1}⁻¹ est_k)`; returns per-frame (translation \[m\],
/// rotation \[deg\]) of `E_k` (Sturm et al., Eq. 1 with Δ = 1).
pub fn relative_pose_errors(
    estimate: &[Isometry3<f64>],
    truth: &[Isometry3<f64>],
) -> Vec<(f64, f64)> {
    assert_eq!(estimate.len(), truth.len(), "trajectories differ in length");
    (1..estimate.len())
        .map(|k| {
            let d_est = estimate[k - 1].inverse() * estimate[k];
            let d_gt = truth[k - 1].inverse() * truth[k];
            let e = d_gt.inverse() * d_est;
            (e.translation.vector.norm(), e.rotation.angle().to_degrees())
        })
        .collect()
}

/// Rigid alignment `truth_from_estimate` minimising `Σ ‖truth_k.t − T·estimate_k.t‖²` over the
/// positions (Umeyama 1991 without scale); identity for fewer than 3 non-collinear positions.
pub fn align_positions(estimate: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> Isometry3<f64> {
    assert_eq!(estimate.len(), truth.len(), "trajectories differ in length");
    let n = estimate.len();
    if n < 3 {
        return Isometry3::identity();
    }
    let p: Vec<Point3<f64>> = estimate
        .iter()
        .map(|e| Point3::from(e.translation.vector))
        .collect();
    let q: Vec<Point3<f64>> = truth
        .iter()
        .map(|e| Point3::from(e.translation.vector))
        .collect();
    let cp = p.iter().fold(Vector3::zeros(), |a, x| a + x.coords) / n as f64;
    let cq = q.iter().fold(Vector3::zeros(), |a, x| a + x.coords) / n as f64;
    let mut h = Matrix3::zeros();
    for (a, b) in p.iter().zip(&q) {
        h += (a.coords - cp) * (b.coords - cq).transpose();
    }
    let svd = h.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Isometry3::identity();
    };
    let v = v_t.transpose();
    let mut d = Matrix3::identity();
    if (v * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = nalgebra::Rotation3::from_matrix_unchecked(v * d * u.transpose());
    let rotation = UnitQuaternion::from_rotation_matrix(&r);
    Isometry3::from_parts(Translation3::from(cq - rotation * cp), rotation)
}

/// Absolute trajectory error: RMSE of position differences \[m\] after [`align_positions`].
pub fn ate_rmse(estimate: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> f64 {
    if estimate.is_empty() {
        return 0.0;
    }
    let t = align_positions(estimate, truth);
    let sum: f64 = estimate
        .iter()
        .zip(truth)
        .map(|(e, g)| ((t * e).translation.vector - g.translation.vector).norm_squared())
        .sum();
    (sum / estimate.len() as f64).sqrt()
}

/// Per-frame position error \[m\] after [`align_positions`]: `‖truth_k.t − T·estimate_k.t‖`; the
/// root mean square of these is [`ate_rmse`].
pub fn aligned_position_errors(estimate: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> Vec<f64> {
    assert_eq!(estimate.len(), truth.len(), "trajectories differ in length");
    let t = align_positions(estimate, truth);
    estimate
        .iter()
        .zip(truth)
        .map(|(e, g)| ((t * e).translation.vector - g.translation.vector).norm())
        .collect()
}

/// Cumulative distance travelled \[m\]: `d_0 = 0`, `d_k = d_{k−1} + ‖t_k − t_{k−1}‖` (KITTI devkit
/// `trajectoryDistances`).
pub fn path_distances(poses: &[Isometry3<f64>]) -> Vec<f64> {
    let mut d = Vec::with_capacity(poses.len());
    let mut acc = 0.0;
    for (k, p) in poses.iter().enumerate() {
        if k > 0 {
            acc += (p.translation.vector - poses[k - 1].translation.vector).norm();
        }
        d.push(acc);
    }
    d
}

/// Segment lengths of the KITTI odometry benchmark \[m\] (Geiger et al. 2012, devkit `lengths`).
pub const KITTI_SEGMENT_LENGTHS_M: [f64; 8] =
    [100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0];
/// Frames between segment start points in the KITTI devkit (`step_size`, 1 s at 10 Hz).
pub const KITTI_STEP_FRAMES: usize = 10;
/// Segment lengths for paths shorter than the first KITTI length, as fractions of the path
/// length (10 %, 20 %, …, 80 %: eight lengths like KITTI's).
pub const SHORT_PATH_SEGMENT_FRACTIONS: [f64; 8] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8];
/// Frames between segment start points for short paths: every frame (indoor logs are short).
pub const SHORT_PATH_STEP_FRAMES: usize = 1;

/// Segment lengths \[m\] and start-point step \[frames\] for a ground-truth path of
/// `path_length_m` metres: the KITTI lengths shorter than the path (step
/// [`KITTI_STEP_FRAMES`]) when the path is longer than 100 m, else
/// [`SHORT_PATH_SEGMENT_FRACTIONS`] of the path (step [`SHORT_PATH_STEP_FRAMES`]). Empty for a
/// path of zero (or non-finite) length.
pub fn drift_segment_lengths(path_length_m: f64) -> (Vec<f64>, usize) {
    if !(path_length_m.is_finite() && path_length_m > 0.0) {
        return (Vec::new(), SHORT_PATH_STEP_FRAMES);
    }
    if path_length_m > KITTI_SEGMENT_LENGTHS_M[0] {
        let lengths = KITTI_SEGMENT_LENGTHS_M
            .iter()
            .copied()
            .filter(|&l| l < path_length_m)
            .collect();
        (lengths, KITTI_STEP_FRAMES)
    } else {
        let lengths = SHORT_PATH_SEGMENT_FRACTIONS
            .iter()
            .map(|f| f * path_length_m)
            .collect();
        (lengths, SHORT_PATH_STEP_FRAMES)
    }
}

/// Drift over the segments of one length.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SegmentDrift {
    /// Nominal segment length \[m\].
    pub length_m: f64,
    /// Segments of this length that fit in the path.
    pub segments: usize,
    /// Mean translational error per nominal length [%].
    pub trans_drift_pct: f64,
    /// Mean rotational error per nominal length \[deg/m\].
    pub rot_drift_deg_per_m: f64,
}

/// KITTI-style drift over all segment lengths.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Drift {
    /// Per length, only lengths with at least one segment.
    pub per_length: Vec<SegmentDrift>,
    /// Segments over all lengths.
    pub segments: usize,
    /// Mean over all segments of translational error per nominal length [%].
    pub trans_drift_pct: f64,
    /// Mean over all segments of rotational error per nominal length \[deg/m\].
    pub rot_drift_deg_per_m: f64,
}

/// KITTI odometry drift (devkit `calcSequenceErrors`): for every start frame `f` (every
/// `step_frames`-th) and length `L`, the end frame `l` is the first with
/// `d_l > d_f + L` (`d` = [`path_distances`] of `truth`); the error
/// `E = (est_f⁻¹ est_l)⁻¹ (gt_f⁻¹ gt_l)` contributes `‖t_E‖ / L` and `angle(R_E) / L`.
/// Returns `None` when no segment fits.
///
/// NOTE: like the devkit, errors are divided by the nominal length `L`, not by the distance
/// `d_l − d_f` actually travelled (which exceeds `L` by up to one frame's motion).
pub fn segment_drift(
    estimate: &[Isometry3<f64>],
    truth: &[Isometry3<f64>],
    lengths_m: &[f64],
    step_frames: usize,
) -> Option<Drift> {
    assert_eq!(estimate.len(), truth.len(), "trajectories differ in length");
    assert!(step_frames > 0, "step_frames must be positive");
    let dist = path_distances(truth);
    let mut per_length = Vec::new();
    let (mut all_t, mut all_r, mut all_n) = (0.0, 0.0, 0usize);
    for &len in lengths_m {
        let (mut sum_t, mut sum_r, mut n) = (0.0, 0.0, 0usize);
        for first in (0..truth.len()).step_by(step_frames) {
            let Some(last) = (first..truth.len()).find(|&i| dist[i] > dist[first] + len) else {
                continue;
            };
            let d_gt = truth[first].inverse() * truth[last];
            let d_est = estimate[first].inverse() * estimate[last];
            let e = d_est.inverse() * d_gt;
            sum_t += e.translation.vector.norm() / len;
            sum_r += e.rotation.angle().to_degrees() / len;
            n += 1;
        }
        if n > 0 {
            per_length.push(SegmentDrift {
                length_m: len,
                segments: n,
                trans_drift_pct: 100.0 * sum_t / n as f64,
                rot_drift_deg_per_m: sum_r / n as f64,
            });
            all_t += sum_t;
            all_r += sum_r;
            all_n += n;
        }
    }
    (all_n > 0).then(|| Drift {
        per_length,
        segments: all_n,
        trans_drift_pct: 100.0 * all_t / all_n as f64,
        rot_drift_deg_per_m: all_r / all_n as f64,
    })
}

/// [`segment_drift`] with the lengths and step of [`drift_segment_lengths`] for the length of
/// `truth`'s path.
pub fn path_drift(estimate: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> Option<Drift> {
    let total = path_distances(truth).last().copied().unwrap_or(0.0);
    let (lengths, step) = drift_segment_lengths(total);
    segment_drift(estimate, truth, &lengths, step)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path(n: usize) -> Vec<Isometry3<f64>> {
        (0..n)
            .map(|k| {
                let a = k as f64 * 0.1;
                Isometry3::from_parts(
                    Translation3::new(a.cos() * 3.0, a.sin() * 2.0, 0.1 * k as f64),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, a),
                )
            })
            .collect()
    }

    #[test]
    fn identical_trajectories_have_zero_error() {
        let p = path(20);
        assert!(ate_rmse(&p, &p) < 1e-12);
        assert!(
            relative_pose_errors(&p, &p)
                .iter()
                .all(|&(t, r)| t < 1e-12 && r < 1e-9)
        );
    }

    #[test]
    fn fixed_offset_vanishes_after_alignment() {
        let gt = path(30);
        let offset = Isometry3::from_parts(
            Translation3::new(5.0, -1.0, 2.0),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0),
        );
        let est: Vec<_> = gt.iter().map(|g| offset * g).collect();
        assert!(ate_rmse(&est, &gt) < 1e-9);
        // RPE is invariant to a global offset.
        assert!(
            relative_pose_errors(&est, &gt)
                .iter()
                .all(|&(t, r)| t < 1e-9 && r < 1e-7)
        );
    }

    #[test]
    fn pure_translation_drift() {
        // Each step overshoots by 1 cm along x in the frame's own axes (no rotation).
        let gt: Vec<_> = (0..10)
            .map(|k| Isometry3::translation(0.1 * k as f64, 0.0, 0.0))
            .collect();
        let est: Vec<_> = (0..10)
            .map(|k| Isometry3::translation(0.11 * k as f64, 0.0, 0.0))
            .collect();
        for (t, r) in relative_pose_errors(&est, &gt) {
            assert!((t - 0.01).abs() < 1e-12 && r.abs() < 1e-12);
        }
    }

    /// Straight path along x with `n + 1` poses 1 m apart.
    fn straight(n: usize, scale: f64) -> Vec<Isometry3<f64>> {
        (0..=n)
            .map(|k| Isometry3::translation(scale * k as f64, 0.0, 0.0))
            .collect()
    }

    #[test]
    fn per_step_rotation_offset_gives_that_rpe() {
        // est_k = est_{k−1} · (gt_{k−1}⁻¹ gt_k) · R_z(δ) ⇒ E_k = R_z(δ): RPE (0 m, δ).
        let gt = path(15);
        let delta_deg = 0.7_f64;
        let r = Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_euler_angles(0.0, 0.0, delta_deg.to_radians()),
        );
        let mut est = vec![gt[0]];
        for k in 1..gt.len() {
            let step = gt[k - 1].inverse() * gt[k];
            est.push(est[k - 1] * step * r);
        }
        let rpe = relative_pose_errors(&est, &gt);
        assert_eq!(rpe.len(), 14);
        for (t, rot) in rpe {
            assert!(t < 1e-9, "translation {t}");
            assert!((rot - delta_deg).abs() < 1e-9, "rotation {rot}");
        }
    }

    #[test]
    fn aligned_errors_of_a_scaled_line_are_deviations_from_the_centroid() {
        // est = 1.1 · gt along x, k = 0..9: the best rigid fit matches the centroids, leaving
        // errors 0.01·|k − 4.5| m; RMSE = 0.01·sqrt((10² − 1)/12).
        let gt: Vec<_> = (0..10)
            .map(|k| Isometry3::translation(0.1 * k as f64, 0.0, 0.0))
            .collect();
        let est: Vec<_> = (0..10)
            .map(|k| Isometry3::translation(0.11 * k as f64, 0.0, 0.0))
            .collect();
        let errs = aligned_position_errors(&est, &gt);
        for (k, e) in errs.iter().enumerate() {
            assert!(
                (e - 0.01 * (k as f64 - 4.5).abs()).abs() < 1e-9,
                "frame {k}: {e}"
            );
        }
        assert!((ate_rmse(&est, &gt) - 0.01 * (99.0_f64 / 12.0).sqrt()).abs() < 1e-9);
    }

    #[test]
    fn composed_with_fixed_se3_has_zero_aligned_errors() {
        let gt = path(25);
        let x = Isometry3::from_parts(
            Translation3::new(-2.0, 0.5, 7.0),
            UnitQuaternion::from_euler_angles(1.2, 0.4, -2.5),
        );
        let est: Vec<_> = gt.iter().map(|g| x * g).collect();
        assert!(aligned_position_errors(&est, &gt).iter().all(|&e| e < 1e-9));
    }

    #[test]
    fn path_distances_accumulate_step_lengths() {
        let p = [
            Isometry3::translation(0.0, 0.0, 0.0),
            Isometry3::translation(3.0, 4.0, 0.0),
            Isometry3::translation(3.0, 4.0, 2.0),
        ];
        assert_eq!(path_distances(&p), vec![0.0, 5.0, 7.0]);
        assert!(path_distances(&[]).is_empty());
    }

    #[test]
    fn kitti_drift_of_a_scale_error_on_a_straight_path() {
        // 300 m straight, 1 m per frame, estimate 1 % too long. Lengths < 300 m: 100 and 200.
        // L = 100: ends at first + 101 (first d > d_f + 100), starts 0, 10, …, 190 → 20
        // segments, error 0.01·101 m / 100 m = 1.01 %. L = 200: ends at first + 201, starts
        // 0, …, 90 → 10 segments, 2.01 / 200 = 1.005 %. Overall (20·1.01 + 10·1.005) / 30.
        let gt = straight(300, 1.0);
        let est = straight(300, 1.01);
        let d = path_drift(&est, &gt).expect("segments fit");
        assert_eq!(d.per_length.len(), 2);
        let (a, b) = (d.per_length[0], d.per_length[1]);
        assert_eq!((a.length_m, a.segments), (100.0, 20));
        assert_eq!((b.length_m, b.segments), (200.0, 10));
        assert!((a.trans_drift_pct - 1.01).abs() < 1e-9, "{a:?}");
        assert!((b.trans_drift_pct - 1.005).abs() < 1e-9, "{b:?}");
        assert_eq!(d.segments, 30);
        assert!((d.trans_drift_pct - (20.0 * 1.01 + 10.0 * 1.005) / 30.0).abs() < 1e-9);
        assert!(d.rot_drift_deg_per_m.abs() < 1e-12);
    }

    #[test]
    fn kitti_drift_of_a_roll_about_the_direction_of_travel() {
        // est_k = (R_x(kδ), (k, 0, 0)): positions exact, rotation drifts δ per metre. Segment
        // of L = 100 spans 101 frames → 101·δ / 100 per metre.
        let delta = 1e-3_f64;
        let gt = straight(300, 1.0);
        let est: Vec<_> = (0..=300)
            .map(|k| {
                Isometry3::from_parts(
                    Translation3::new(k as f64, 0.0, 0.0),
                    UnitQuaternion::from_euler_angles(k as f64 * delta, 0.0, 0.0),
                )
            })
            .collect();
        let d = segment_drift(&est, &gt, &[100.0], KITTI_STEP_FRAMES).expect("fits");
        let s = d.per_length[0];
        assert!(s.trans_drift_pct < 1e-9, "{s:?}");
        assert!(
            (s.rot_drift_deg_per_m - (101.0 * delta).to_degrees() / 100.0).abs() < 1e-9,
            "{s:?}"
        );
    }

    #[test]
    fn short_paths_use_fractions_of_their_length() {
        let (lengths, step) = drift_segment_lengths(10.0);
        assert_eq!(step, SHORT_PATH_STEP_FRAMES);
        let want = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0];
        assert_eq!(lengths.len(), 8);
        for (l, w) in lengths.iter().zip(want) {
            assert!((l - w).abs() < 1e-12);
        }
        let (lengths, step) = drift_segment_lengths(350.0);
        assert_eq!(
            (lengths, step),
            (vec![100.0, 200.0, 300.0], KITTI_STEP_FRAMES)
        );
        assert!(drift_segment_lengths(0.0).0.is_empty());
        // A path that never moves has no segment.
        let still = vec![Isometry3::identity(); 5];
        assert!(path_drift(&still, &still).is_none());
    }
}
