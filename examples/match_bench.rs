//! Timing of FPFH matching: brute force vs kiddo kd-tree, on synthetic FPFH-like descriptors.
//!
//! `cargo run --release --example match_bench -- [sizes...]` (default sizes: 5000 20000; each
//! size N matches N source against N target descriptors).
//!
//! `cargo run --release --example match_bench -- --real SRC TGT VOXEL_M [REPEATS]` prepares two
//! real clouds with the default `PairConfig` at that voxel, then times brute-force matching
//! (nearest + second, as the pipeline's default ratio ranking uses) and prints a checksum of the
//! result, so kernel changes can be checked for bit-identical output.

use std::time::Instant;

use mireg::correspondence::matching::{
    FPFH_DIM, Fpfh, MatchConfig, MatchMethod, Matches, match_features_with,
};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// FPFH-like descriptors: each 11-bin block non-negative and summing to 200 (Open3D 0.20 scale,
/// 600 per descriptor), drawn around `clusters` peaky centres shared by source and target, with
/// a spread of noise levels so nearest-neighbour distances range from a few units to tens.
fn fpfh_like(rng: &mut Pcg64Mcg, centres: &[[[f32; 11]; 3]], n: usize) -> Vec<Fpfh> {
    (0..n)
        .map(|_| {
            let centre = &centres[rng.random_range(0..centres.len())];
            let noise_level: f32 = rng.random_range(0.02..0.5);
            let mut d = [0.0f32; FPFH_DIM];
            for (b, block) in centre.iter().enumerate() {
                let raw: [f32; 11] =
                    std::array::from_fn(|k| block[k] + noise_level * rng.random::<f32>().powi(3));
                let sum: f32 = raw.iter().sum();
                for k in 0..11 {
                    d[b * 11 + k] = 200.0 * raw[k] / sum;
                }
            }
            d
        })
        .collect()
}

fn time<F: FnMut() -> Matches>(mut f: F) -> (f64, Matches) {
    let mut best = f64::INFINITY;
    let mut out = Matches::default();
    for _ in 0..3 {
        let start = Instant::now();
        out = f();
        best = best.min(start.elapsed().as_secs_f64());
    }
    (best, out)
}

fn real(args: &[String]) {
    let [src, tgt, voxel, rest @ ..] = args else {
        panic!("usage: match_bench --real SRC TGT VOXEL_M [REPEATS]");
    };
    let repeats: usize = rest.first().map_or(10, |r| r.parse().expect("repeats"));
    let config = mireg::pipeline::PairConfig {
        voxel_size_m: voxel.parse().expect("voxel"),
        ..Default::default()
    }
    .resolved()
    .expect("config");
    let prepare = |p: &str| {
        let points = mireg::io::cloud_file::read_points(std::path::Path::new(p)).expect("cloud");
        mireg::pipeline::prepare_frame(&points, &config).expect("prepare")
    };
    let (s, t) = (prepare(src), prepare(tgt));
    let mut times = Vec::new();
    let mut out = Matches::default();
    for _ in 0..repeats {
        let start = Instant::now();
        out = match_features_with(s.features(), t.features(), &MatchConfig::default());
        times.push(start.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    let checksum = out
        .target_index
        .iter()
        .zip(&out.distance)
        .zip(&out.second_distance)
        .fold(0u64, |h, ((&j, &d), &e)| {
            let h = h.rotate_left(5) ^ u64::from(j);
            let h = h.rotate_left(5) ^ u64::from(d.to_bits());
            h.rotate_left(5) ^ u64::from(e.to_bits())
        });
    println!(
        "{} x {} real descriptors: min {:.1} ms, median {:.1} ms over {repeats}; checksum {checksum:016x}",
        s.features().len(),
        t.features().len(),
        times[0] * 1e3,
        times[repeats / 2] * 1e3
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("--real") {
        return real(&args[1..]);
    }
    let sizes: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("size"))
        .collect();
    let sizes = if sizes.is_empty() {
        vec![5000, 20000]
    } else {
        sizes
    };
    println!("threads: {}", rayon::current_num_threads());
    for n in sizes {
        let mut rng = Pcg64Mcg::seed_from_u64(42);
        let centres: Vec<[[f32; 11]; 3]> = (0..200)
            .map(|_| std::array::from_fn(|_| std::array::from_fn(|_| rng.random::<f32>().powi(3))))
            .collect();
        let source = fpfh_like(&mut rng, &centres, n);
        let target = fpfh_like(&mut rng, &centres, n);
        let mut brute_nn = Matches::default();
        for (name, method, mutual, count_radius) in [
            (
                "brute  nearest+second",
                MatchMethod::BruteForce,
                false,
                None,
            ),
            (
                "brute  + count(12)",
                MatchMethod::BruteForce,
                false,
                Some(12.0),
            ),
            ("brute  mutual", MatchMethod::BruteForce, true, None),
            ("kdtree nearest+second", MatchMethod::KdTree, false, None),
            ("kdtree + count(12)", MatchMethod::KdTree, false, Some(12.0)),
            ("kdtree mutual", MatchMethod::KdTree, true, None),
        ] {
            let config = MatchConfig {
                mutual,
                count_radius,
                method,
            };
            let (seconds, m) = time(|| match_features_with(&source, &target, &config));
            let mut sorted = m.distance.clone();
            sorted.sort_by(f32::total_cmp);
            let median = sorted.get(sorted.len() / 2).copied().unwrap_or(f32::NAN);
            let mean_count = if m.count_within.is_empty() {
                f64::NAN
            } else {
                m.count_within.iter().map(|&c| c as f64).sum::<f64>() / m.len() as f64
            };
            if method == MatchMethod::BruteForce && !mutual && count_radius.is_none() {
                brute_nn = m.clone();
            }
            let agree = if !mutual {
                let same = m
                    .target_index
                    .iter()
                    .zip(&brute_nn.target_index)
                    .filter(|(a, b)| a == b)
                    .count();
                format!("{same}/{n} agree with brute")
            } else {
                format!("{} mutual", m.len())
            };
            println!(
                "{n:>6} x {n:<6} {name:<22} {:>9.1} ms  median nn dist {median:6.2}  mean count {mean_count:7.1}  {agree}",
                seconds * 1e3
            );
        }
    }
}
