//! Diagnosis of one registration against its ground truth: is the correct model never sampled, or
//! sampled but out-scored? (Used for the bunny 0°↔90° failures; see `ransac::dense`.)
//!
//! `cargo run --release --example pair_diag -- SRC TGT GT_4x4.txt VOXEL SEED`
//! (`DIAG_BENCH=1` also times one dense score.)
//!
//! Runs the default pipeline up to RANSAC (no ICP), then replays every hypothesis the consensus
//! loop could draw (same per-hypothesis RNG streams, up to the hypothesis cap) for the default Lévy
//! sampler (μ = −50, c = 1, window 100) and the uniform one. Printed for the ground truth, the
//! chosen model and the hypotheses: correspondence inliers (residual < 1.5·voxel) and dense fitness
//! (Open3D's `evaluate_registration` on the feature clouds at 1.5·voxel). A hypothesis is "near
//! GT" when it moves the source feature points by less than 2·voxel RMS from where the ground truth
//! puts them.

use std::path::Path;

use mireg::correspondence::matching::{MatchConfig, match_features_with};
use mireg::correspondence::ranking::rank_by_ratio;
use mireg::io::{cloud_file::read_points, pose_file::read_matrix4};
use mireg::pipeline::{PairConfig, pose_error, prepare_frame, run_sampler};
use mireg::ransac::{
    ConsensusConfig, Estimator, Levy, RigidEstimator, Sampler, TruncatedLevy, Uniform,
    hypothesis_rng,
};
use mireg::refine::icp::{IcpTarget, evaluate_registration};
use nalgebra::{Isometry3, Point3};

fn rms_motion(a: &Isometry3<f64>, b: &Isometry3<f64>, pts: &[Point3<f64>]) -> f64 {
    (pts.iter()
        .map(|p| (a * p - b * p).norm_squared())
        .sum::<f64>()
        / pts.len() as f64)
        .sqrt()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    let (src, tgt) = (
        read_points(Path::new(&a[1]))?,
        read_points(Path::new(&a[2]))?,
    );
    let gt = read_matrix4(Path::new(&a[3]))?;
    let voxel: f64 = a[4].parse()?;
    let seed: u64 = a[5].parse()?;
    let near: f64 = 2.0 * voxel;
    let config = PairConfig {
        voxel_size_m: voxel,
        icp: false,
        seed,
        ..Default::default()
    }
    .resolved()?;
    let (s, t) = (prepare_frame(&src, &config)?, prepare_frame(&tgt, &config)?);
    let m = match_features_with(s.features(), t.features(), &MatchConfig::default());
    let ranking = rank_by_ratio(&m.distance, &m.second_distance);
    let sp = ranking.gather(&m.source_index, &s.points);
    let tp = ranking.gather(&m.target_index, &t.points);
    let thr = 1.5 * voxel;
    let est = RigidEstimator::new(&sp, &tp);
    let dense_t = IcpTarget::points_only(&t.points)?;
    let dense = |model: &Isometry3<f64>| {
        let e = evaluate_registration(&s.points, &dense_t, model, thr).unwrap();
        (e.fitness, e.inlier_rmse_m)
    };
    let corr = |model: &Isometry3<f64>| est.score(model, thr * thr).inliers;
    let gt_inl: Vec<usize> = (0..sp.len())
        .filter(|&i| est.residual_sq(&gt, i) < thr * thr)
        .collect();
    let gt_ranks: Vec<usize> = gt_inl.iter().copied().take(12).collect();
    println!(
        "points {} / {}, correspondences {}, GT: corr inliers {} (first ranks {:?}), dense {:.4}/{:.4} mm",
        s.points.len(),
        t.points.len(),
        sp.len(),
        gt_inl.len(),
        gt_ranks,
        dense(&gt).0,
        dense(&gt).1 * 1e3
    );
    if let Some(refit) = est.refit(&gt_inl) {
        println!(
            "GT refit on its inliers: corr {}, dense {:.4}, RE {:.2}°",
            corr(&refit),
            dense(&refit).0,
            pose_error(&gt, &refit).0
        );
    }
    if std::env::var("DIAG_BENCH").is_ok() {
        bench_dense(&est, (&s.points, &t.points), &dense_t, thr, &gt)?;
    }
    let cc = ConsensusConfig {
        inlier_threshold: thr,
        seed,
        max_hypotheses: config.max_hypotheses,
        ..Default::default()
    };
    let r = run_sampler(config.sampler, &est, &cc)?;
    if let Some(model) = r.model {
        let (re, te) = pose_error(&gt, &model);
        println!(
            "chosen: corr {}, dense {:.4}/{:.2} mm, RE {re:.1}° TE {:.1} mm, hyp {} found at {:?}",
            r.num_inliers,
            dense(&model).0,
            dense(&model).1 * 1e3,
            te * 1e3,
            r.hypotheses,
            r.best_found_at
        );
    }
    let levy = Levy::new(TruncatedLevy::new(-50.0, 1.0, 100.0)?, sp.len())?;
    let uni = Uniform::new(sp.len());
    for (name, sampler) in [("levy", &levy as &dyn DynSampler), ("uniform", &uni)] {
        let scores: Scores = (&corr, &dense);
        replay(
            name,
            sampler,
            &est,
            scores,
            (&gt, &s.points),
            (config.max_hypotheses, seed, near),
        );
    }
    Ok(())
}

/// Times 200 dense scores of the ground truth against the grid and the kd-tree target.
fn bench_dense(
    est: &RigidEstimator,
    (source, target_points): (&[Point3<f64>], &[Point3<f64>]),
    dense_t: &IcpTarget,
    thr: f64,
    gt: &Isometry3<f64>,
) -> Result<(), Box<dyn std::error::Error>> {
    let grid = mireg::ransac::OverlapTarget::new(target_points, thr, || Ok(dense_t))?;
    let tree = mireg::ransac::OverlapTarget::Tree(dense_t);
    for (name, target) in [("grid", &grid), ("kd-tree", &tree)] {
        let dense_est = mireg::ransac::DenseRigidEstimator::new(*est, source, target);
        let t0 = std::time::Instant::now();
        let mut acc = 0u32;
        for _ in 0..200 {
            acc += dense_est.score(gt, thr * thr).inliers;
        }
        let dt = t0.elapsed().as_secs_f64();
        println!(
            "dense score ({name}): {:.1} µs per call, {:.0} ns per point ({acc})",
            dt / 200.0 * 1e6,
            dt / 200.0 / source.len() as f64 * 1e9
        );
    }
    Ok(())
}

/// Correspondence inliers and dense (fitness, RMSE \[m\]) of a model.
type Scores<'a> = (
    &'a dyn Fn(&Isometry3<f64>) -> u32,
    &'a dyn Fn(&Isometry3<f64>) -> (f64, f64),
);

/// Replays every hypothesis `sampler` draws (up to the cap, on the consensus loop's RNG streams)
/// and prints how many were verified, how many landed near the ground truth `gt` (source points
/// moved less than `near` \[m\] RMS from where it puts them) and the best of each score.
fn replay(
    name: &str,
    sampler: &dyn DynSampler,
    est: &RigidEstimator,
    (corr, dense): Scores,
    (gt, source): (&Isometry3<f64>, &[Point3<f64>]),
    (max_hypotheses, seed, near): (u64, u64, f64),
) {
    let mut buf = [0usize; 3];
    let (mut verified, mut near_n, mut first_near) = (0u64, 0u64, None);
    let mut best_near_corr = 0u32;
    let mut best_near_dense = 0.0f64;
    let mut best_corr: (u32, f64, f64) = (0, 0.0, 0.0); // corr, dense, rms
    let mut best_dense: (f64, u32, f64) = (0.0, 0, 0.0);
    for h in 0..max_hypotheses {
        sampler.draw_dyn(h, seed, &mut buf);
        if !est.accept_sample(&buf) {
            continue;
        }
        let Some(model) = est.estimate(&buf) else {
            continue;
        };
        verified += 1;
        let c = corr(&model);
        let d = dense(&model).0;
        let rms = rms_motion(&model, gt, source);
        if rms < near {
            near_n += 1;
            first_near.get_or_insert(h);
            best_near_corr = best_near_corr.max(c);
            best_near_dense = best_near_dense.max(d);
        }
        if c > best_corr.0 {
            best_corr = (c, d, rms);
        }
        if d > best_dense.0 {
            best_dense = (d, c, rms);
        }
    }
    println!(
        "{name:>8}: verified {verified}, near-GT (rms<{:.0} mm) {near_n} first at {first_near:?}, best near corr {best_near_corr} dense {best_near_dense:.4}; \
         best-by-corr {} (dense {:.4}, rms {:.1} mm); best-by-dense {:.4} (corr {}, rms {:.1} mm)",
        near * 1e3,
        best_corr.0,
        best_corr.1,
        best_corr.2 * 1e3,
        best_dense.0,
        best_dense.1,
        best_dense.2 * 1e3
    );
}

trait DynSampler {
    fn draw_dyn(&self, h: u64, seed: u64, out: &mut [usize]);
}
impl<S: Sampler> DynSampler for S {
    fn draw_dyn(&self, h: u64, seed: u64, out: &mut [usize]) {
        self.draw(h, &mut hypothesis_rng(seed, h), out);
    }
}
