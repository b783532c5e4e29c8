//! Hypotheses to the first all-inlier sample on real FPFH correspondences, per ranking and sampler
//! (docs/PAIRWISE.md, "Ranking and sampler on real correspondences").
//!
//! `cargo run --release --example first_clean_sample -- SRC TGT GT_4x4.txt VOXEL [SEEDS]`
//!
//! Correspondences come from the real pipeline (voxel grid, normals, FPFH, nearest neighbour); a
//! correspondence is an inlier when the ground truth maps its source point within 1.5·voxel of its
//! target point. Samples are drawn exactly as the consensus loop draws them (per-hypothesis RNG).

use std::path::Path;

use mireg::correspondence::matching::{MatchConfig, match_features_with};
use mireg::correspondence::ranking::{
    CountOrder, PAPER_DESCRIPTOR_RADIUS, Ranking, rank_by_distance, rank_by_neighbour_count,
    rank_by_ratio,
};
use mireg::io::{cloud_file::read_points, pose_file::read_matrix4};
use mireg::pipeline::{PairConfig, prepare_frame};
use mireg::ransac::{Levy, Prosac, Sampler, TruncatedLevy, Uniform, hypothesis_rng};

fn first_clean(sampler: &impl Sampler, inlier: &[bool], seed: u64, cap: u64) -> u64 {
    let mut s = [0usize; 3];
    for h in 0..cap {
        sampler.draw(h, &mut hypothesis_rng(seed, h), &mut s);
        if s.iter().all(|&i| inlier[i]) {
            return h + 1;
        }
    }
    cap
}

fn median(mut v: Vec<u64>) -> u64 {
    v.sort_unstable();
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 5 {
        eprintln!("usage: first_clean_sample SRC TGT GT_4x4.txt VOXEL [SEEDS]");
        std::process::exit(2);
    }
    let (src, tgt) = (
        read_points(Path::new(&a[1]))?,
        read_points(Path::new(&a[2]))?,
    );
    let gt = read_matrix4(Path::new(&a[3]))?;
    let voxel: f64 = a[4].parse()?;
    let seeds: u64 = a.get(5).map(|s| s.parse()).transpose()?.unwrap_or(101);
    let config = PairConfig {
        voxel_size_m: voxel,
        icp: false,
        ..Default::default()
    };
    let (s, t) = (prepare_frame(&src, &config)?, prepare_frame(&tgt, &config)?);
    let m = match_features_with(
        s.features(),
        t.features(),
        &MatchConfig {
            count_radius: Some(PAPER_DESCRIPTOR_RADIUS as f32),
            ..Default::default()
        },
    );
    let n = m.len();
    let thr = 1.5 * voxel;
    let inlier_by_corr: Vec<bool> = (0..n)
        .map(|k| {
            (gt * s.points[m.source_index[k] as usize] - t.points[m.target_index[k] as usize])
                .norm()
                < thr
        })
        .collect();
    println!(
        "{n} correspondences, {} inliers ({:.1} %), cap 1e6 hypotheses, median over {seeds} seeds",
        inlier_by_corr.iter().filter(|&&b| b).count(),
        100.0 * inlier_by_corr.iter().filter(|&&b| b).count() as f64 / n as f64
    );
    let rankings: Vec<(&str, Ranking)> = vec![
        ("ratio", rank_by_ratio(&m.distance, &m.second_distance)),
        ("distance", rank_by_distance(&m.distance)),
        (
            "count-most (authors)",
            rank_by_neighbour_count(&m.count_within, t.points.len(), CountOrder::MostFirst),
        ),
        (
            "count-fewest",
            rank_by_neighbour_count(&m.count_within, t.points.len(), CountOrder::FewestFirst),
        ),
    ];
    println!(
        "| ranking | inliers in top 10 % | uniform | PROSAC | Lévy μ=−1 | Lévy μ=−50 | Lévy μ=−1e3 |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for (name, r) in &rankings {
        let inlier: Vec<bool> = r
            .order
            .iter()
            .map(|&k| inlier_by_corr[k as usize])
            .collect();
        let top = inlier[..n / 10].iter().filter(|&&b| b).count();
        let run = |sampler: &dyn Fn(u64) -> u64| median((0..seeds).map(sampler).collect());
        let u = Uniform::new(n);
        let p = Prosac::new(n, 3, 200_000)?;
        let levy = |mu: f64| Levy::new(TruncatedLevy::new(mu, 1.0, 100.0).unwrap(), n).unwrap();
        let (l1, l50, l1k) = (levy(-1.0), levy(-50.0), levy(-1e3));
        println!(
            "| {name} | {:.1} % | {} | {} | {} | {} | {} |",
            100.0 * top as f64 / (n / 10).max(1) as f64,
            run(&|sd| first_clean(&u, &inlier, sd, 1_000_000)),
            run(&|sd| first_clean(&p, &inlier, sd, 1_000_000)),
            run(&|sd| first_clean(&l1, &inlier, sd, 1_000_000)),
            run(&|sd| first_clean(&l50, &inlier, sd, 1_000_000)),
            run(&|sd| first_clean(&l1k, &inlier, sd, 1_000_000)),
        );
    }
    Ok(())
}
