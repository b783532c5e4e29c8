//! The paper's registration experiment (Zhang & Chen, Fig. 6) as a tool: for pairs of clouds with
//! a ground-truth relative pose, run every sampler (uniform, PROSAC, Lévy with several μ) for each
//! ranking, M seeded runs each, and report recall and precision per cell.
//!
//! Protocol (../shared/docs/DESIGN.md §2, after Choi et al.): a registration is **reported** when
//! it passes the acceptance test `mireg register` uses to flag failures ([`Acceptance`]: no
//! failure, at least `min_inliers` RANSAC inliers, ICP fitness at least `min_fitness`), and
//! **correct** when it is reported and its error against the ground truth is within
//! [`Thresholds`] (Choi's information-matrix error when the pair has a `gt.info` record, else
//! rotation and translation). Over the `pairs × runs` attempts of a cell, recall = correct /
//! attempts and precision = correct / reported.
//!
//! Pure: frames come in prepared ([`crate::pipeline::prepare_frame`], once per frame, shared by
//! every cell), pairs as indices with their ground truth. Every registration is seeded by its run
//! index, so the table is the same on any thread count (timings aside). The job that reads the
//! frames and pairs from a log or a `gt.log` and settles the defaults is `job.rs`.

mod job;

pub use job::{PreparedSweep, SweepOptions, prepare_sweep};

use nalgebra::{Isometry3, Matrix6, Vector6};
use rayon::prelude::*;
use serde::Serialize;

use crate::Result;
use crate::correspondence::ranking::{CountOrder, PAPER_DESCRIPTOR_RADIUS};
use crate::pipeline::{
    PairConfig, PairResult, PreparedFrame, RankingConfig, SamplerConfig, pose_error,
    register_prepared,
};

/// A pair to register: `source` onto `target` (indices into the frames), with the ground truth
/// `target_from_source`.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepPair {
    /// Source frame index.
    pub source: usize,
    /// Target frame index.
    pub target: usize,
    /// Ground-truth pose of the source in the target frame.
    pub target_from_source: Isometry3<f64>,
    /// Choi et al.'s information matrix of the pair (a `gt.info` record), if known: correctness
    /// is then judged by [`choi_error`] instead of the RE/TE thresholds.
    pub information: Option<Matrix6<f64>>,
}

/// Choi et al.'s registration error (Robust Reconstruction of Indoor Scenes, CVPR 2015; their
/// `mrEvaluateRegistration.m`, reused by 3DMatch): with `Δ = gt⁻¹ · est`, `e = [t_Δ; q_Δ]`
/// (translation \[m\], then the vector part of Δ's unit quaternion) and `Λ` the pair's information
/// matrix, `p = eᵀ Λ e / Λ₁₁` \[m²\]. Λ is `Σ JᵢᵀJᵢ` over Λ₁₁ point correspondences with
/// `Jᵢ = [I | −2[pᵢ]×]`, so p is, to first order, the mean squared displacement of those points
/// under Δ. A registration counts as correct at `p ≤ 0.04` ([`CHOI_MAX_ERROR`], 0.2 m RMSE).
///
/// NOTE: the MATLAB code writes `e = [t; −q_xyz]` with `dcm2quat`, whose quaternion is the
/// conjugate (passive convention) of nalgebra's active one, so the two vectors are equal. The
/// sign matters through Λ's translation–rotation block; `tests/sweep.rs` checks p against the
/// displacement computed directly.
pub fn choi_error(gt: &Isometry3<f64>, est: &Isometry3<f64>, information: &Matrix6<f64>) -> f64 {
    let delta = gt.inverse() * est;
    let mut q = delta.rotation.into_inner().coords;
    // q and −q are the same rotation; take the one with w ≥ 0, the small-angle branch.
    if q.w < 0.0 {
        q = -q;
    }
    let t = delta.translation.vector;
    let e = Vector6::new(t.x, t.y, t.z, q.x, q.y, q.z);
    (e.transpose() * information * e)[(0, 0)] / information[(0, 0)]
}

/// Choi et al.'s threshold on [`choi_error`] \[m²\]: 0.04, i.e. 0.2 m RMSE.
pub const CHOI_MAX_ERROR: f64 = 0.04;

/// The pairs `(i, i + k)` of a trajectory for each gap `k` in `gaps`: source `i + k` onto target
/// `i`, ground truth `world_from_i⁻¹ · world_from_{i+k}`.
pub fn pairs_from_trajectory(
    world_from_frame: &[Isometry3<f64>],
    gaps: &[usize],
) -> Vec<SweepPair> {
    let mut out = Vec::new();
    for &k in gaps {
        for i in 0..world_from_frame.len().saturating_sub(k) {
            if k == 0 {
                continue;
            }
            out.push(SweepPair {
                source: i + k,
                target: i,
                target_from_source: world_from_frame[i].inverse() * world_from_frame[i + k],
                information: None,
            });
        }
    }
    out
}

/// When a registration counts as reported: `register`'s acceptance test.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Acceptance {
    /// Fewest RANSAC inliers. Default 12, as [`crate::odometry::OdometryConfig`].
    pub min_inliers: usize,
    /// Lowest ICP fitness, in \[0, 1\]. Default 0.3.
    pub min_fitness: f64,
}

impl Default for Acceptance {
    fn default() -> Self {
        let o = crate::odometry::OdometryConfig::default();
        Self {
            min_inliers: o.min_inliers,
            min_fitness: o.min_fitness,
        }
    }
}

impl Acceptance {
    /// Whether `r` passes.
    pub fn accepts(&self, r: &PairResult) -> bool {
        r.failure.is_none() && r.num_inliers >= self.min_inliers && r.fitness >= self.min_fitness
    }
}

/// When a reported registration counts as correct: within [`choi_error`] `max_info_error` for a
/// pair with an information matrix, else within both `max_re_deg` and `max_te_m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thresholds {
    /// Largest rotation error \[deg\].
    pub max_re_deg: f64,
    /// Largest translation error \[m\].
    pub max_te_m: f64,
    /// Largest [`choi_error`] \[m²\]; Choi's is [`CHOI_MAX_ERROR`].
    pub max_info_error: f64,
}

impl Thresholds {
    /// Whether `est` is a correct registration of `pair`.
    pub fn correct(&self, pair: &SweepPair, est: &Isometry3<f64>) -> bool {
        match &pair.information {
            Some(info) => choi_error(&pair.target_from_source, est, info) <= self.max_info_error,
            None => {
                let (re, te) = pose_error(&pair.target_from_source, est);
                re <= self.max_re_deg && te <= self.max_te_m
            }
        }
    }
}

/// One sampler of the sweep, named as the CSV names it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SamplerCell {
    /// `uniform`, `prosac` or `levy`.
    pub name: &'static str,
    /// μ for Lévy, else `None`.
    pub mu: Option<f64>,
    /// The configuration it runs.
    pub config: SamplerConfig,
}

/// The paper's μ values for registration (Fig. 6): −1, −50, −1e2 … −1e6.
pub const PAPER_MUS: [f64; 7] = [-1.0, -50.0, -1e2, -1e3, -1e4, -1e5, -1e6];

/// Uniform, PROSAC (`T_N` as the default PROSAC), and Lévy (c = 1, window 100) at each μ.
pub fn samplers(mus: &[f64]) -> Vec<SamplerCell> {
    let prosac = SamplerConfig::Prosac {
        growth_max_samples: 200_000,
    };
    let mut v = vec![
        SamplerCell {
            name: "uniform",
            mu: None,
            config: SamplerConfig::Uniform,
        },
        SamplerCell {
            name: "prosac",
            mu: None,
            config: prosac,
        },
    ];
    for &mu in mus {
        v.push(SamplerCell {
            name: "levy",
            mu: Some(mu),
            config: SamplerConfig::Levy {
                mu,
                c: 1.0,
                window: 100.0,
                with_replacement: false,
            },
        });
    }
    v
}

/// The rankings by their CSV names: `ratio`, `distance`, `count_most` (the authors'), `count_fewest`.
pub fn ranking(name: &str) -> Option<RankingConfig> {
    let radius = PAPER_DESCRIPTOR_RADIUS as f32;
    Some(match name {
        "ratio" => RankingConfig::Ratio,
        "distance" => RankingConfig::Distance,
        "count_most" => RankingConfig::NeighbourCount {
            radius,
            order: CountOrder::MostFirst,
        },
        "count_fewest" => RankingConfig::NeighbourCount {
            radius,
            order: CountOrder::FewestFirst,
        },
        _ => return None,
    })
}

/// One attempt's outcome.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outcome {
    /// Passed the acceptance test.
    pub reported: bool,
    /// Reported and within the thresholds.
    pub correct: bool,
    /// Hypotheses drawn.
    pub hypotheses: u64,
    /// Wall time of the registration \[s\].
    pub time_s: f64,
}

/// Recall (correct / attempts) and precision (correct / reported; 0 when nothing was reported).
pub fn recall_precision(outcomes: &[Outcome]) -> (f64, f64) {
    let correct = outcomes.iter().filter(|o| o.correct).count() as f64;
    let reported = outcomes.iter().filter(|o| o.reported).count() as f64;
    let recall = if outcomes.is_empty() {
        0.0
    } else {
        correct / outcomes.len() as f64
    };
    let precision = if reported > 0.0 {
        correct / reported
    } else {
        0.0
    };
    (recall, precision)
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// One row of the table.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CellResult {
    /// Dataset name.
    pub dataset: String,
    /// Ranking name.
    pub ranking: String,
    /// Sampler name.
    pub sampler: &'static str,
    /// μ (Lévy only).
    pub mu: Option<f64>,
    /// Runs per pair.
    pub runs: usize,
    /// Pairs.
    pub pairs: usize,
    /// Correct / attempts.
    pub recall: f64,
    /// Correct / reported.
    pub precision: f64,
    /// Median hypotheses drawn per attempt.
    pub hypotheses_median: f64,
    /// Median seconds per attempt.
    pub time_s_median: f64,
}

/// The CSV header of [`CellResult::csv_row`].
pub const CSV_HEADER: &str =
    "dataset,ranking,sampler,mu,runs,pairs,recall,precision,hypotheses_median,time_s_median";

impl CellResult {
    /// The row in [`CSV_HEADER`]'s columns (mu empty unless Lévy).
    pub fn csv_row(&self) -> String {
        format!(
            "{},{},{},{},{},{},{:.4},{:.4},{},{:.6}",
            self.dataset,
            self.ranking,
            self.sampler,
            self.mu.map(|m| m.to_string()).unwrap_or_default(),
            self.runs,
            self.pairs,
            self.recall,
            self.precision,
            self.hypotheses_median,
            self.time_s_median
        )
    }
}

/// What to sweep.
#[derive(Debug, Clone)]
pub struct SweepConfig {
    /// Dataset name for the table.
    pub dataset: String,
    /// Rankings by name ([`ranking`]).
    pub rankings: Vec<String>,
    /// Samplers ([`samplers`]).
    pub samplers: Vec<SamplerCell>,
    /// Seeded runs per pair and cell; run r uses seed `seed + r`. Default 20 (the paper's M).
    pub runs: usize,
    /// First seed. Default 0.
    pub seed: u64,
    /// Everything else of the registration (its ranking, sampler and seed are replaced).
    pub pair: PairConfig,
    /// Reported or not.
    pub acceptance: Acceptance,
    /// Correct or not.
    pub thresholds: Thresholds,
}

/// Runs the sweep: every (ranking, sampler) cell over every pair and run, in parallel; rows in
/// ranking-major, then sampler order.
///
/// # Errors
/// An unknown ranking name, or an invalid configuration.
pub fn sweep(
    frames: &[PreparedFrame],
    pairs: &[SweepPair],
    config: &SweepConfig,
) -> Result<Vec<CellResult>> {
    let mut cells = Vec::new();
    for name in &config.rankings {
        let r = ranking(name).ok_or_else(|| {
            crate::Error::InvalidInput(format!(
                "unknown ranking {name:?} (ratio, distance, count_most, count_fewest)"
            ))
        })?;
        for s in &config.samplers {
            cells.push((name.clone(), r, *s));
        }
    }
    let jobs: Vec<(usize, usize, usize)> = (0..cells.len())
        .flat_map(|c| (0..pairs.len()).flat_map(move |p| (0..config.runs).map(move |r| (c, p, r))))
        .collect();
    let outcomes: Vec<Outcome> = jobs
        .par_iter()
        .map(|&(c, p, r)| {
            let (_, ranking, sampler) = &cells[c];
            let pair = &pairs[p];
            let pc = PairConfig {
                ranking: *ranking,
                sampler: sampler.config,
                seed: config.seed + r as u64,
                ..config.pair.clone()
            };
            let t = std::time::Instant::now();
            let res = register_prepared(&frames[pair.source], &frames[pair.target], &pc)?;
            let time_s = t.elapsed().as_secs_f64();
            let reported = config.acceptance.accepts(&res);
            let correct = reported && config.thresholds.correct(pair, &res.target_from_source);
            Ok(Outcome {
                reported,
                correct,
                hypotheses: res.hypotheses,
                time_s,
            })
        })
        .collect::<Result<_>>()?;
    let per_cell = pairs.len() * config.runs;
    Ok(cells
        .iter()
        .enumerate()
        .map(|(c, (name, _, s))| {
            let o = &outcomes[c * per_cell..(c + 1) * per_cell];
            let (recall, precision) = recall_precision(o);
            CellResult {
                dataset: config.dataset.clone(),
                ranking: name.clone(),
                sampler: s.name,
                mu: s.mu,
                runs: config.runs,
                pairs: pairs.len(),
                recall,
                precision,
                hypotheses_median: median(o.iter().map(|o| o.hypotheses as f64).collect()),
                time_s_median: median(o.iter().map(|o| o.time_s).collect()),
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn o(reported: bool, correct: bool) -> Outcome {
        Outcome {
            reported,
            correct,
            hypotheses: 1,
            time_s: 0.0,
        }
    }

    #[test]
    fn recall_and_precision_of_known_counts() {
        // 10 attempts: 6 reported, 4 of them correct.
        let mut v = vec![o(true, true); 4];
        v.extend([o(true, false), o(true, false)]);
        v.extend([o(false, false); 4]);
        assert_eq!(recall_precision(&v), (0.4, 4.0 / 6.0));
        assert_eq!(recall_precision(&[o(false, false)]), (0.0, 0.0));
        assert_eq!(recall_precision(&[]), (0.0, 0.0));
    }

    #[test]
    fn pairs_from_a_trajectory_carry_the_relative_ground_truth() {
        let poses: Vec<Isometry3<f64>> = (0..6)
            .map(|k| {
                Isometry3::from_parts(
                    Translation3::new(k as f64, 0.5 * k as f64, 0.0),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, 0.1 * k as f64),
                )
            })
            .collect();
        let pairs = pairs_from_trajectory(&poses, &[1, 3]);
        assert_eq!(pairs.len(), 5 + 3);
        for p in &pairs {
            // The ground truth maps the source frame into the target frame: through the world.
            let x = nalgebra::Point3::new(0.3, -0.2, 1.0);
            let via_world = poses[p.target].inverse() * (poses[p.source] * x);
            assert!((p.target_from_source * x - via_world).norm() < 1e-12);
            assert!(p.source > p.target);
        }
        assert_eq!((pairs[5].target, pairs[5].source), (0, 3));
    }

    #[test]
    fn csv_rows_have_the_header_columns() {
        let r = CellResult {
            dataset: "d".into(),
            ranking: "ratio".into(),
            sampler: "levy",
            mu: Some(-50.0),
            runs: 2,
            pairs: 3,
            recall: 0.5,
            precision: 1.0,
            hypotheses_median: 10.0,
            time_s_median: 0.01,
        };
        assert_eq!(
            r.csv_row().split(',').count(),
            CSV_HEADER.split(',').count()
        );
        assert_eq!(
            r.csv_row(),
            "d,ratio,levy,-50,2,3,0.5000,1.0000,10,0.010000"
        );
        let u = CellResult {
            sampler: "uniform",
            mu: None,
            ..r
        };
        assert!(u.csv_row().starts_with("d,ratio,uniform,,2,"));
    }
}
