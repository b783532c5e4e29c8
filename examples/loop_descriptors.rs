//! Measures loop-closure descriptors on real frames: for each "return" frame (odd index), are
//! the earlier-visited "out" frames (even index) that truly overlap it (reference poses within a
//! distance and, for RGB-D, a viewing angle) the nearest by descriptor? Reports recall@1/@5, the
//! distances of true and false pairs, the fraction of (true, false) pairs ranked right (AUC), and
//! the invariance of each descriptor to rotating a scan about z and about other axes.
//!
//! ```text
//! cargo run --example loop_descriptors [-- <data dir, default /work/shared/data>]
//! MIREG_FEATURE_POINTS=8000 cargo run --example loop_descriptors   # a finer feature cloud
//! ```
//!
//! Data: `<data>/mulran_kaist03_keyframes` (21 Ouster scans, PCD + KITTI poses; skipped with a
//! message when absent) and `fixtures/icl_livingroom1.mcap` (71 ICL-NUIM depth clouds with
//! `/ground_truth/pose`).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use mireg::io::cloud_file::read_points;
use mireg::loops::{CandidateConfig, Descriptor, ScanContext};
use mireg::pipeline::{
    DEFAULT_FEATURE_POINTS, PairConfig, feature_voxel_for_cloud, prepare_frame, voxel_for_cloud,
    with_feature_voxel,
};
use nalgebra::{Isometry3, Point3, Rotation3, Unit, Vector3};

/// What one frame gives each descriptor.
struct Frame {
    ours: Descriptor,
    sc_feature: ScanContext,
    sc_raw: ScanContext,
}

type Metric = (&'static str, fn(&Frame, &Frame) -> f64);

fn chi2(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| {
            let (x, y) = (f64::from(x), f64::from(y));
            if x + y > 0.0 {
                (x - y).powi(2) / (x + y)
            } else {
                0.0
            }
        })
        .sum::<f64>()
        * 0.5
}

fn cosine(a: &[f32], b: &[f32]) -> f64 {
    let dot: f64 = a
        .iter()
        .zip(b)
        .map(|(&x, &y)| f64::from(x) * f64::from(y))
        .sum();
    let n = |v: &[f32]| v.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>().sqrt();
    1.0 - dot / (n(a) * n(b)).max(1e-300)
}

const METRICS: &[Metric] = &[
    ("fpfh L1", |a, b| a.ours.fpfh_distance(&b.ours)),
    ("fpfh chi2", |a, b| chi2(&a.ours.fpfh, &b.ours.fpfh)),
    ("fpfh cosine", |a, b| cosine(&a.ours.fpfh, &b.ours.fpfh)),
    ("shape L1", |a, b| a.ours.shape_distance(&b.ours)),
    ("range L1", |a, b| a.ours.range_distance(&b.ours)),
    ("fpfh+shape", |a, b| {
        a.ours.weighted_distance(&b.ours, [0.5, 0.5, 0.0])
    }),
    ("fpfh+range", |a, b| {
        a.ours.weighted_distance(&b.ours, [0.5, 0.0, 0.5])
    }),
    ("shape+range", |a, b| {
        a.ours.weighted_distance(&b.ours, [0.0, 0.5, 0.5])
    }),
    ("fpfh+shape+range (Descriptor)", |a, b| {
        a.ours.distance(&b.ours)
    }),
    ("scan context (feature cloud)", |a, b| {
        a.sc_feature.distance(&b.sc_feature)
    }),
    ("scan context (raw scan)", |a, b| {
        a.sc_raw.distance(&b.sc_raw)
    }),
];

struct Prepared {
    config: PairConfig,
}

impl Prepared {
    fn new(first: &[Point3<f64>]) -> Result<Self> {
        let voxel = voxel_for_cloud(first).context("first cloud too small")?;
        let pair = PairConfig {
            voxel_size_m: voxel,
            icp: false,
            icp_fine: false,
            ..PairConfig::default()
        };
        // `MIREG_FEATURE_POINTS` overrides the feature-cloud size of `mireg register`.
        let max_points = std::env::var("MIREG_FEATURE_POINTS")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(DEFAULT_FEATURE_POINTS);
        let fv = feature_voxel_for_cloud(first, voxel, max_points)?;
        println!("  voxel {voxel:.3} m, feature voxel {fv:.3} m");
        Ok(Self {
            config: with_feature_voxel(&pair, fv),
        })
    }

    fn frame(&self, points: &[Point3<f64>]) -> Result<Frame> {
        let p = prepare_frame(points, &self.config)?;
        Ok(Frame {
            ours: Descriptor::from_prepared(&p),
            sc_feature: ScanContext::new(&p.points),
            sc_raw: ScanContext::new(points),
        })
    }
}

/// Ground-truth overlap between two reference poses.
struct Truth {
    max_distance_m: f64,
    max_angle_deg: f64,
}

impl Truth {
    fn overlaps(&self, a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
        let d = (a.translation.vector - b.translation.vector).norm();
        let angle = (a.rotation.inverse() * b.rotation).angle().to_degrees();
        d <= self.max_distance_m && angle <= self.max_angle_deg
    }
}

/// Odd frames query the even ones; prints one line per metric.
fn retrieval(name: &str, frames: &[Frame], poses: &[Isometry3<f64>], truth: &Truth) {
    let queries: Vec<usize> = (1..frames.len()).step_by(2).collect();
    let database: Vec<usize> = (0..frames.len()).step_by(2).collect();
    let with_truth: Vec<usize> = queries
        .iter()
        .copied()
        .filter(|&q| {
            database
                .iter()
                .any(|&m| truth.overlaps(&poses[q], &poses[m]))
        })
        .collect();
    let pairs_true: usize = with_truth
        .iter()
        .map(|&q| {
            database
                .iter()
                .filter(|&&m| truth.overlaps(&poses[q], &poses[m]))
                .count()
        })
        .sum();
    println!(
        "\n{name}: {} queries (odd frames) with a true match among {} even frames \
         (within {} m and {}°; {pairs_true} true pairs)",
        with_truth.len(),
        database.len(),
        truth.max_distance_m,
        truth.max_angle_deg
    );
    println!(
        "  {:<30} {:>6} {:>6} {:>10} {:>10} {:>10} {:>6}",
        "descriptor", "R@1", "R@5", "true mean", "false mean", "false min", "AUC"
    );
    for (label, metric) in METRICS {
        let (mut r1, mut r5) = (0, 0);
        let (mut t, mut f) = (Vec::new(), Vec::new());
        let (mut right, mut total) = (0usize, 0usize);
        for &q in &with_truth {
            let mut ranked: Vec<(f64, usize)> = database
                .iter()
                .map(|&m| (metric(&frames[q], &frames[m]), m))
                .collect();
            ranked.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let is_true = |m: usize| truth.overlaps(&poses[q], &poses[m]);
            r1 += usize::from(is_true(ranked[0].1));
            r5 += usize::from(ranked.iter().take(5).any(|&(_, m)| is_true(m)));
            let (tq, fq): (Vec<_>, Vec<_>) = ranked.iter().partition(|&&(_, m)| is_true(m));
            for &(dt, _) in &tq {
                for &(df, _) in &fq {
                    right += usize::from(dt < df);
                    total += 1;
                }
            }
            t.extend(tq.iter().map(|x| x.0));
            f.extend(fq.iter().map(|x| x.0));
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let n = with_truth.len() as f64;
        println!(
            "  {label:<30} {:>6.2} {:>6.2} {:>10.4} {:>10.4} {:>10.4} {:>6.3}",
            r1 as f64 / n,
            r5 as f64 / n,
            mean(&t),
            mean(&f),
            f.iter().copied().fold(f64::INFINITY, f64::min),
            right as f64 / total.max(1) as f64
        );
    }
    appearance_gate(frames, poses, truth, &with_truth, &database);
}

/// The appearance gate of `find_candidates` on the `queries` (odd frames with a true match)
/// against the `database` (even frames): a pair passes when its distance is at most
/// `max_descriptor_distance` and `appearance_ratio` × the median distance from the query to the
/// database; printed at the default and at 0.5.
fn appearance_gate(
    frames: &[Frame],
    poses: &[Isometry3<f64>],
    truth: &Truth,
    with_truth: &[usize],
    database: &[usize],
) {
    let default = CandidateConfig::default();
    let mut ratios = Vec::new();
    let mut gates = Vec::new();
    for &q in with_truth {
        let d: Vec<(f64, usize)> = database
            .iter()
            .map(|&m| (frames[q].ours.distance(&frames[m].ours), m))
            .collect();
        let mut sorted: Vec<f64> = d.iter().map(|x| x.0).collect();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        let best_true = d
            .iter()
            .filter(|x| truth.overlaps(&poses[q], &poses[x.1]))
            .map(|x| x.0)
            .fold(f64::INFINITY, f64::min);
        ratios.push(best_true / median);
        gates.push((d, median, best_true, q));
    }
    ratios.sort_by(f64::total_cmp);
    println!(
        "  Descriptor, best true / median distance over the queries: median {:.3}, max {:.3}",
        ratios[ratios.len() / 2],
        ratios[ratios.len() - 1]
    );
    for ratio in [default.appearance_ratio, 0.5] {
        let (mut queries_passing, mut false_passing, mut false_total) = (0, 0, 0);
        for (d, median, best_true, q) in &gates {
            let gate = default.max_descriptor_distance.min(ratio * median);
            queries_passing += usize::from(*best_true <= gate);
            for &(x, m) in d {
                if !truth.overlaps(&poses[*q], &poses[m]) {
                    false_total += 1;
                    false_passing += usize::from(x <= gate);
                }
            }
        }
        println!(
            "  gate <= {} and <= {ratio} x median: passes the best true pair of \
             {queries_passing}/{} queries and {false_passing}/{false_total} false pairs",
            default.max_descriptor_distance,
            with_truth.len()
        );
    }
}

fn rotation(axis: Vector3<f64>, deg: f64) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Unit::new_normalize(axis), deg.to_radians())
}

/// Distance of each descriptor between a cloud and its rotated copies, next to the distance
/// between neighbouring frames (the scale of a "same place" distance).
fn invariance(prep: &Prepared, points: &[Point3<f64>], neighbour: &Frame) -> Result<()> {
    let base = prep.frame(points)?;
    let cases = [
        ("yaw 10°", rotation(Vector3::z(), 10.0)),
        ("yaw 45°", rotation(Vector3::z(), 45.0)),
        ("yaw 90°", rotation(Vector3::z(), 90.0)),
        ("yaw 180°", rotation(Vector3::z(), 180.0)),
        ("yaw 233°", rotation(Vector3::z(), 233.0)),
        ("roll 30°", rotation(Vector3::x(), 30.0)),
        ("pitch 90°", rotation(Vector3::y(), 90.0)),
        ("(1,2,3) 120°", rotation(Vector3::new(1.0, 2.0, 3.0), 120.0)),
    ];
    print!(
        "\n  invariance: distance to the unrotated scan\n  {:<30}",
        "descriptor"
    );
    for (name, _) in &cases {
        print!(" {name:>12}");
    }
    println!(" {:>12}", "next frame");
    let rotated: Vec<Frame> = cases
        .iter()
        .map(|(_, r)| prep.frame(&points.iter().map(|p| r * p).collect::<Vec<_>>()))
        .collect::<Result<_>>()?;
    for (label, metric) in METRICS {
        print!("  {label:<30}");
        for f in &rotated {
            print!(" {:>12.4}", metric(&base, f));
        }
        println!(" {:>12.4}", metric(&base, neighbour));
    }
    Ok(())
}

fn kaist03(dir: &Path) -> Result<()> {
    println!("KAIST03 ({})", dir.display());
    let poses = mireg::io::poses::read_kitti(&dir.join("poses_kitti.txt"))?.poses;
    let clouds: Vec<Vec<Point3<f64>>> = (0..poses.len())
        .map(|k| read_points(&dir.join(format!("Scans/{k:06}.pcd"))))
        .collect::<mireg::Result<_>>()?;
    let prep = Prepared::new(&clouds[0])?;
    let frames: Vec<Frame> = clouds
        .iter()
        .map(|c| prep.frame(c))
        .collect::<Result<_>>()?;
    let truth = Truth {
        max_distance_m: 2.0,
        max_angle_deg: 180.0,
    };
    retrieval("KAIST03", &frames, &poses, &truth);
    // The same queries seen with another heading: each odd scan turned about z (yaw) by
    // 37° · k, and about x (roll) by 90°, as a revisit in another direction or a tilted sensor.
    for (label, axis) in [("yaw 37°·k", Vector3::z()), ("roll 90°", Vector3::x())] {
        let turned: Vec<Frame> = clouds
            .iter()
            .enumerate()
            .map(|(k, c)| {
                if k % 2 == 0 {
                    return prep.frame(c);
                }
                let deg = if label.starts_with("yaw") {
                    37.0 * k as f64
                } else {
                    90.0
                };
                let r = rotation(axis, deg);
                prep.frame(&c.iter().map(|p| r * p).collect::<Vec<_>>())
            })
            .collect::<Result<_>>()?;
        retrieval(
            &format!("KAIST03, queries rotated {label}"),
            &turned,
            &poses,
            &truth,
        );
    }
    invariance(&prep, &clouds[0], &frames[1])
}

fn icl(path: &Path) -> Result<()> {
    println!("\nICL-NUIM livingroom1 ({})", path.display());
    let reference = mireg::io::poses::read_mcap_pose_topic(path, "/ground_truth/pose")?;
    let by_stamp: HashMap<i64, Isometry3<f64>> = reference
        .stamps_ns
        .iter()
        .copied()
        .zip(reference.poses.iter().copied())
        .collect();
    let mut clouds = Vec::new();
    let mut poses = Vec::new();
    mireg::register::for_each_cloud(path, Some("/camera/depth/points"), |_, cloud| {
        if let Some(p) = by_stamp.get(&cloud.header.stamp.to_ns()) {
            poses.push(*p);
            clouds.push(cloud.points);
        }
        Ok(std::ops::ControlFlow::Continue(()))
    })?;
    println!("  {} clouds with a reference pose", clouds.len());
    let prep = Prepared::new(&clouds[0])?;
    let frames: Vec<Frame> = clouds
        .iter()
        .map(|c| prep.frame(c))
        .collect::<Result<_>>()?;
    for truth in [
        Truth {
            max_distance_m: 0.3,
            max_angle_deg: 30.0,
        },
        Truth {
            max_distance_m: 0.15,
            max_angle_deg: 15.0,
        },
    ] {
        retrieval("ICL-NUIM livingroom1", &frames, &poses, &truth);
    }
    invariance(&prep, &clouds[0], &frames[1])
}

fn main() -> Result<()> {
    let data = std::env::args()
        .nth(1)
        .map_or_else(|| PathBuf::from("/work/shared/data"), PathBuf::from);
    let kaist = data.join("mulran_kaist03_keyframes");
    if kaist.is_dir() {
        kaist03(&kaist)?;
    } else {
        println!("skipping KAIST03: {} is absent", kaist.display());
    }
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/icl_livingroom1.mcap");
    if fixture.is_file() {
        icl(&fixture)?;
    } else {
        println!("skipping ICL-NUIM: {} is absent", fixture.display());
    }
    Ok(())
}
