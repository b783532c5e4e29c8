use super::brute_force::*;
use super::*;
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Descriptors with small integer entries: every squared distance is an exact integer in f32
/// whatever the summation order, and ties are frequent, so index equality is exact.
fn integer_descriptors(rng: &mut Pcg64Mcg, n: usize, max: u32) -> Vec<Fpfh> {
    (0..n)
        .map(|_| std::array::from_fn(|_| rng.random_range(0..=max) as f32))
        .collect()
}

/// FPFH-like: each 11-bin block is non-negative and sums to 100; descriptors cluster around
/// a few peaky centres.
fn fpfh_like(rng: &mut Pcg64Mcg, n: usize, clusters: usize) -> Vec<Fpfh> {
    let peaky_block =
        |rng: &mut Pcg64Mcg| -> [f32; 11] { std::array::from_fn(|_| rng.random::<f32>().powi(4)) };
    let centres: Vec<[[f32; 11]; 3]> = (0..clusters)
        .map(|_| std::array::from_fn(|_| peaky_block(rng)))
        .collect();
    (0..n)
        .map(|_| {
            let centre = centres[rng.random_range(0..clusters)];
            let mut d = [0.0f32; FPFH_DIM];
            for (b, block) in centre.iter().enumerate() {
                let noise = peaky_block(rng);
                let raw: [f32; 11] = std::array::from_fn(|k| block[k] + 0.05 * noise[k]);
                let sum: f32 = raw.iter().sum();
                for k in 0..11 {
                    d[b * 11 + k] = 100.0 * raw[k] / sum;
                }
            }
            d
        })
        .collect()
}

fn oracle_squared(a: &Fpfh, b: &Fpfh) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
        .sum()
}

/// Naive O(N·M): (nearest index with lowest index on ties, nearest², second nearest²).
fn oracle_nearest(query: &Fpfh, set: &[Fpfh]) -> (u32, f64, f64) {
    let mut d: Vec<(f64, u32)> = set
        .iter()
        .enumerate()
        .map(|(j, t)| (oracle_squared(query, t), j as u32))
        .collect();
    d.sort_by(|a, b| a.partial_cmp(b).unwrap());
    (d[0].1, d[0].0, d.get(1).map_or(f64::INFINITY, |x| x.0))
}

fn oracle_count(query: &Fpfh, set: &[Fpfh], radius: f64) -> u32 {
    set.iter()
        .filter(|t| oracle_squared(query, t) <= radius * radius)
        .count() as u32
}

#[test]
fn brute_force_equals_naive_oracle_with_ties() {
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    // Sizes not multiples of TILE or WORK_ROWS; entries 0..=3 make many exact ties.
    let source = integer_descriptors(&mut rng, 301, 3);
    let target = integer_descriptors(&mut rng, 257, 3);
    let config = MatchConfig {
        count_radius: Some(8.0),
        ..MatchConfig::default()
    };
    let m = match_features_with(&source, &target, &config);
    assert_eq!(m.len(), source.len());
    let mut ties = 0;
    for (i, q) in source.iter().enumerate() {
        let (j, best, second) = oracle_nearest(q, &target);
        ties += (best == second) as usize;
        assert_eq!(m.source_index[i], i as u32);
        assert_eq!(m.target_index[i], j, "source {i}");
        assert_eq!(m.distance[i] as f64, (best as f32).sqrt() as f64);
        assert_eq!(m.second_distance[i] as f64, (second as f32).sqrt() as f64);
        assert_eq!(m.count_within[i], oracle_count(q, &target, 8.0));
    }
    assert!(
        ties > 10,
        "the data should exercise tie-breaking, got {ties} ties"
    );
}

/// The documented definition of a squared distance: dimensions 0..33 in order, `mul_add`.
fn in_order_squared(a: &Fpfh, b: &Fpfh) -> f32 {
    a.iter().zip(b).fold(0.0f32, |acc, (&x, &y)| {
        let d = x - y;
        d.mul_add(d, acc)
    })
}

/// The lower-bound filter must never drop a pair that matters: on FPFH-like floats (with
/// exact and one-ulp duplicates, and outliers far from the bulk that stretch the projected
/// coordinates), nearest index, both distances and the count are bit-identical to a naive
/// scan under the same distance definition.
#[test]
fn pruned_search_is_bit_identical_to_naive_scan_on_floats() {
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let mut target = fpfh_like(&mut rng, 1500, 12);
    for j in (0..300).step_by(3) {
        let mut d = target[j];
        if j % 2 == 0 {
            d[rng.random_range(0..FPFH_DIM)] = f32::from_bits(d[0].to_bits() + 1);
        }
        target.push(d);
    }
    target.extend((0..20).map(|_| std::array::from_fn(|_| rng.random_range(0.0..5e4f32))));
    let mut source = fpfh_like(&mut rng, 700, 12);
    source.extend(target.iter().step_by(7).take(100).copied());
    source.extend((0..10).map(|_| std::array::from_fn(|_| rng.random_range(0.0..5e4f32))));
    let radius = 12.0f32;
    let config = MatchConfig {
        count_radius: Some(radius),
        ..MatchConfig::default()
    };
    let m = match_features_with(&source, &target, &config);
    for (i, q) in source.iter().enumerate() {
        let d: Vec<f32> = target.iter().map(|t| in_order_squared(q, t)).collect();
        let (mut best, mut j_best) = (f32::INFINITY, 0u32);
        for (j, &x) in d.iter().enumerate() {
            if x < best {
                (best, j_best) = (x, j as u32);
            }
        }
        let mut rest = d.clone();
        rest.remove(j_best as usize);
        let second = rest.iter().copied().fold(f32::INFINITY, f32::min);
        let count = d.iter().filter(|&&x| x <= radius * radius).count() as u32;
        assert_eq!(m.target_index[i], j_best, "source {i}");
        assert_eq!(m.distance[i].to_bits(), best.sqrt().to_bits(), "source {i}");
        assert_eq!(
            m.second_distance[i].to_bits(),
            second.sqrt().to_bits(),
            "source {i}"
        );
        assert_eq!(m.count_within[i], count, "source {i}");
    }
    assert!(m.distance.iter().filter(|&&d| d == 0.0).count() >= 100);
}

#[test]
fn mutual_filter_equals_oracle() {
    let mut rng = Pcg64Mcg::seed_from_u64(2);
    let source = integer_descriptors(&mut rng, 203, 4);
    let target = integer_descriptors(&mut rng, 150, 4);
    let m = match_features(&source, &target, true);
    let expected: Vec<(u32, u32)> = (0..source.len())
        .filter_map(|i| {
            let (j, _, _) = oracle_nearest(&source[i], &target);
            let (back, _, _) = oracle_nearest(&target[j as usize], &source);
            (back == i as u32).then_some((i as u32, j))
        })
        .collect();
    let got: Vec<(u32, u32)> = m
        .source_index
        .iter()
        .copied()
        .zip(m.target_index.iter().copied())
        .collect();
    assert!(!expected.is_empty() && expected.len() < source.len());
    assert_eq!(got, expected);
    assert!(m.count_within.is_empty());
}

#[test]
fn count_within_equals_oracle() {
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let source = integer_descriptors(&mut rng, 97, 2);
    let target = integer_descriptors(&mut rng, 611, 2);
    for radius in [0.0f32, 4.0, 6.0, 7.5] {
        let counts = count_within(&source, &target, radius);
        let expected: Vec<u32> = source
            .iter()
            .map(|q| oracle_count(q, &target, radius as f64))
            .collect();
        assert_eq!(counts, expected, "radius {radius}");
    }
    // FPFH-like floats at the paper's τ_d = 12: exact except for distances within rounding
    // of the radius.
    let mut source = fpfh_like(&mut rng, 1100, 20);
    let target = source.split_off(200);
    let counts = count_within(&source, &target, 12.0);
    assert!(counts.iter().any(|&c| c > 0) && counts.iter().any(|&c| c < 900));
    for (q, &c) in source.iter().zip(&counts) {
        let low = oracle_count(q, &target, 12.0 - 1e-3);
        let high = oracle_count(q, &target, 12.0 + 1e-3);
        assert!(low <= c && c <= high, "{low} <= {c} <= {high}");
    }
}

#[test]
fn kd_tree_agrees_with_brute_force() {
    let mut rng = Pcg64Mcg::seed_from_u64(4);
    let mut source = fpfh_like(&mut rng, 2200, 30);
    let target = source.split_off(700);
    for mutual in [false, true] {
        let brute = MatchConfig {
            mutual,
            count_radius: Some(12.0),
            method: MatchMethod::BruteForce,
        };
        let kd = MatchConfig {
            method: MatchMethod::KdTree,
            ..brute
        };
        let a = match_features_with(&source, &target, &brute);
        let b = match_features_with(&source, &target, &kd);
        assert_eq!(a.source_index, b.source_index, "mutual {mutual}");
        assert_eq!(a.target_index, b.target_index);
        for i in 0..a.len() {
            assert!((a.distance[i] - b.distance[i]).abs() <= 1e-4 * a.distance[i].max(1.0));
            assert!(
                (a.second_distance[i] - b.second_distance[i]).abs()
                    <= 1e-4 * a.second_distance[i].max(1.0)
            );
            assert!(a.count_within[i].abs_diff(b.count_within[i]) <= 1);
        }
    }
}

#[test]
fn same_result_on_one_and_two_threads() {
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let mut source = fpfh_like(&mut rng, 1500, 25);
    let target = source.split_off(500);
    let config = MatchConfig {
        mutual: true,
        count_radius: Some(12.0),
        method: MatchMethod::BruteForce,
    };
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| match_features_with(&source, &target, &config))
    };
    assert_eq!(run(1), run(2));
}

/// The quantised bound's invariant, pair by pair: a pair whose computed full squared distance
/// is ≤ some bound has a quantised squared distance ≤ the threshold for that bound. Pairs are
/// near-duplicates and ordinary neighbours (where the √PCA_DIMS-step margin matters: without
/// it, this fails), and the database holds an outlier that coarsens the quantisation.
#[test]
fn quantised_bound_never_exceeds_the_full_distance() {
    let mut rng = Pcg64Mcg::seed_from_u64(23);
    let mut base = fpfh_like(&mut rng, 400, 5);
    base[7] = [0.0; FPFH_DIM];
    base[7][0] = 600.0;
    let db = Database::new(&base);
    let queries: Vec<Fpfh> = base
        .iter()
        .map(|d| {
            let scale = [0.0, 1e-3, 0.05, 1.0][rng.random_range(0..4)];
            std::array::from_fn(|k| (d[k] + scale * rng.random::<f32>()).max(0.0))
        })
        .collect();
    let projected: Vec<[f64; PCA_DIMS]> = queries
        .iter()
        .map(|q| project(q, &db.mean, &db.axes_t))
        .collect();
    let quantiser = Quantiser::new(&db, &projected);
    let blocks = quantiser.blocks(&db);
    let mut order: Vec<usize> = (0..base.len()).collect();
    order.sort_by(|&a, &b| {
        let (x, y) = (
            project(&base[a], &db.mean, &db.axes_t),
            project(&base[b], &db.mean, &db.axes_t),
        );
        x[0].total_cmp(&y[0]).then(a.cmp(&b))
    });
    let mut tight = 0;
    for (q, c) in queries.iter().zip(&projected) {
        let pattern = pattern(&quantiser.coordinates(c));
        for (k, &j) in order.iter().enumerate() {
            let full = in_order_squared(q, &base[j]);
            let (b, l) = (k / LANES, k % LANES);
            let quantised: i32 = (0..PCA_DIMS)
                .map(|dim| {
                    let d = i32::from(pattern[dim / 2][2 * l + dim % 2])
                        - i32::from(blocks[b][dim / 2][2 * l + dim % 2]);
                    d * d
                })
                .sum();
            let threshold = quantiser.threshold(full);
            assert!(
                quantised <= threshold,
                "{quantised} > {threshold} (full {full})"
            );
            tight += usize::from(threshold - quantised < 4 * PCA_DIMS as i32);
        }
    }
    assert!(
        tight > 100,
        "only {tight} pairs near the margin: the test is too easy"
    );
}

/// The AVX2 kernel decides exactly as the portable one, at the extremes of the quantised range
/// and at thresholds on, just below and just above a lane's distance.
#[test]
fn bound_kernels_agree() {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        let mut rng = Pcg64Mcg::seed_from_u64(29);
        let max = QUANT_MAX as i16;
        for trial in 0..2000 {
            let mut value = || match rng.random_range(0..4) {
                0 => max,
                1 => -max,
                _ => rng.random_range(-max..=max),
            };
            let pattern: QuantBlock = std::array::from_fn(|_| std::array::from_fn(|_| value()));
            let block: QuantBlock = std::array::from_fn(|_| std::array::from_fn(|_| value()));
            let lanes: Vec<i64> = (0..LANES)
                .map(|l| {
                    (0..PCA_DIMS)
                        .map(|dim| {
                            let d = i64::from(pattern[dim / 2][2 * l + dim % 2])
                                - i64::from(block[dim / 2][2 * l + dim % 2]);
                            d * d
                        })
                        .sum()
                })
                .collect();
            let min = *lanes.iter().min().unwrap();
            for threshold in [min - 1, min, min + 1, i64::from(i32::MAX), 0] {
                let threshold = threshold.clamp(0, i64::from(i32::MAX)) as i32;
                let expected = min <= i64::from(threshold);
                assert_eq!(
                    PortableBound.any_within(&pattern, &block, threshold),
                    expected
                );
                assert_eq!(
                    Avx2Bound(()).any_within(&pattern, &block, threshold),
                    expected,
                    "trial {trial}, threshold {threshold}"
                );
            }
        }
    }
}

#[test]
fn degenerate_sizes() {
    let one = [[1.0f32; FPFH_DIM]];
    let m = match_features(&one, &one, false);
    assert_eq!((m.target_index[0], m.distance[0]), (0, 0.0));
    assert_eq!(m.second_distance[0], f32::INFINITY);
    assert!(match_features(&one, &[], true).is_empty());
    assert!(match_features(&[], &one, false).is_empty());
    assert_eq!(count_within(&one, &[], 12.0), vec![0]);
}

#[test]
fn a_prepared_target_gives_the_oracles_matches_for_every_source() {
    let mut rng = Pcg64Mcg::seed_from_u64(31);
    // Repeated descriptors on both sides exercise the distinct-descriptor groups.
    let mut target = integer_descriptors(&mut rng, 300, 3);
    target.extend(target[..40].to_vec());
    let prepared = MatchTarget::new(&target).unwrap();
    for n in [1, 57, 400] {
        let source = integer_descriptors(&mut rng, n, 3);
        for mutual in [false, true] {
            let config = MatchConfig {
                mutual,
                ..Default::default()
            };
            let got = match_features_against(&source, &target, &prepared, &config);
            assert_eq!(got, match_features_with(&source, &target, &config));
            if !mutual {
                // Oracle: every source's nearest target, ties to the lowest index.
                assert_eq!(got.len(), n);
                for (k, q) in source.iter().enumerate() {
                    let (best, best_sq, second_sq) = oracle_nearest(q, &target);
                    assert_eq!(got.target_index[k], best);
                    assert_eq!(got.distance[k], (best_sq as f32).sqrt());
                    assert_eq!(got.second_distance[k], (second_sq as f32).sqrt());
                }
            }
        }
        // A count radius is not what the structures serve: the search builds its own.
        let counting = MatchConfig {
            count_radius: Some(4.0),
            ..Default::default()
        };
        assert_eq!(
            match_features_against(&source, &target, &prepared, &counting),
            match_features_with(&source, &target, &counting)
        );
    }
    assert!(MatchTarget::new(&[]).is_none());
}
