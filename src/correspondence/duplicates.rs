//! Bitwise-equal descriptors, found once so that the matching scan sees each only once.
//!
//! A cloud of isolated points (a sparse far field, a glitch that scatters returns, a hostile
//! input) gives many equal FPFH descriptors — all zero when a point has no neighbour within the
//! feature radius. Equal descriptors are equally near every query, so no lower bound can prune
//! them and the exact scan becomes quadratic: 100 000 isolated points took 35.6 s to match
//! (docs/HARDENING.md). Scanning one representative per group gives the same answers: the
//! representative is the group's lowest index, which is what the scan's tie-break picks anyway.

use std::collections::HashMap;

use crate::features::fpfh::{FPFH_BINS as FPFH_DIM, Fpfh};
use crate::hash::FastHash;

/// Fewest duplicates for which [`Unique::of`] groups the descriptors; below, grouping costs more
/// than it saves.
pub const MIN_DUPLICATES: usize = 256;

/// The distinct descriptors of a set, in order of first appearance.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Unique {
    /// Index of the first occurrence of each distinct descriptor (increasing).
    pub first: Vec<u32>,
    /// For each descriptor, the position of its group in `first`.
    pub group: Vec<u32>,
    /// Members of each group.
    pub size: Vec<u32>,
}

impl Unique {
    /// The groups of `descriptors`; `None` when fewer than [`MIN_DUPLICATES`] descriptors repeat
    /// an earlier one. Descriptors are compared bit for bit (`0.0` and `-0.0` differ: only
    /// bitwise-equal descriptors are guaranteed to have equal distances to every query).
    pub fn of(descriptors: &[Fpfh]) -> Option<Self> {
        if descriptors.len() <= MIN_DUPLICATES {
            return None;
        }
        let mut slot: HashMap<[u32; FPFH_DIM], u32, FastHash> =
            HashMap::with_capacity_and_hasher(descriptors.len(), Default::default());
        let mut u = Self {
            first: Vec::new(),
            group: Vec::with_capacity(descriptors.len()),
            size: Vec::new(),
        };
        for (i, d) in descriptors.iter().enumerate() {
            let key = d.map(f32::to_bits);
            let next = u.first.len() as u32;
            let g = *slot.entry(key).or_insert(next);
            if g == next {
                u.first.push(i as u32);
                u.size.push(0);
            }
            u.size[g as usize] += 1;
            u.group.push(g);
        }
        (descriptors.len() - u.first.len() >= MIN_DUPLICATES).then_some(u)
    }

    /// The distinct descriptors, in group order.
    pub fn descriptors(&self, all: &[Fpfh]) -> Vec<Fpfh> {
        self.first.iter().map(|&i| all[i as usize]).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::correspondence::matching::match_features;
    use rand::{RngExt, SeedableRng};

    /// Squared distance as the scan defines it: dimensions in order, `mul_add`.
    fn squared(a: &Fpfh, b: &Fpfh) -> f32 {
        a.iter().zip(b).fold(0.0f32, |acc, (&x, &y)| {
            let d = x - y;
            d.mul_add(d, acc)
        })
    }

    /// (nearest index, lowest on ties; nearest²; second nearest²) by a naive scan.
    fn naive(q: &Fpfh, set: &[Fpfh]) -> (u32, f32, f32) {
        let (mut best, mut second, mut j_best) = (f32::INFINITY, f32::INFINITY, 0u32);
        for (j, t) in set.iter().enumerate() {
            let d = squared(q, t);
            if d < best {
                (second, best, j_best) = (best, d, j as u32);
            } else if d < second {
                second = d;
            }
        }
        (j_best, best, second)
    }

    /// Clouds of mostly isolated points: hundreds of all-zero descriptors on both sides, some
    /// repeated non-zero ones, the rest distinct. Matching (plain and mutual) equals a naive
    /// scan, bit for bit, ties to the lowest index.
    #[test]
    fn matching_with_many_equal_descriptors_equals_a_naive_scan() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
        let mut random = |n: usize| -> Vec<Fpfh> {
            (0..n)
                .map(|_| std::array::from_fn(|_| rng.random_range(0..4u8) as f32 * 10.0))
                .collect()
        };
        let mut target = random(300);
        let repeated = target[5];
        for k in 0..700 {
            target.insert(
                (k * 7) % target.len(),
                if k % 5 == 0 {
                    repeated
                } else {
                    [0.0; FPFH_DIM]
                },
            );
        }
        let mut source = random(200);
        for k in 0..500 {
            source.insert(
                (k * 3) % source.len(),
                if k % 4 == 0 {
                    repeated
                } else {
                    [0.0; FPFH_DIM]
                },
            );
        }
        assert!(Unique::of(&target).is_some() && Unique::of(&source).is_some());
        let m = match_features(&source, &target, false);
        for (i, q) in source.iter().enumerate() {
            let (j, best, second) = naive(q, &target);
            assert_eq!(m.target_index[i], j, "source {i}");
            assert_eq!(m.distance[i].to_bits(), best.sqrt().to_bits(), "source {i}");
            assert_eq!(
                m.second_distance[i].to_bits(),
                second.sqrt().to_bits(),
                "source {i}"
            );
        }
        let mutual = match_features(&source, &target, true);
        let expected: Vec<(u32, u32)> = (0..source.len() as u32)
            .filter_map(|i| {
                let (j, _, _) = naive(&source[i as usize], &target);
                let (back, _, _) = naive(&target[j as usize], &source);
                (back == i).then_some((i, j))
            })
            .collect();
        let got: Vec<(u32, u32)> = mutual
            .source_index
            .iter()
            .copied()
            .zip(mutual.target_index.iter().copied())
            .collect();
        assert_eq!(got, expected);
    }

    #[test]
    fn groups_equal_descriptors_by_first_occurrence() {
        let mut d = vec![[0.0f32; FPFH_DIM]; MIN_DUPLICATES + 3];
        d[1][0] = 1.0;
        d[4][0] = 1.0;
        d[5][3] = -0.0; // bitwise different from 0.0
        let u = Unique::of(&d).expect("enough duplicates");
        assert_eq!(u.first, [0, 1, 5]);
        assert_eq!(u.size, [d.len() as u32 - 3, 2, 1]);
        for (i, &g) in u.group.iter().enumerate() {
            let rep = u.first[g as usize] as usize;
            assert!(rep <= i);
            assert_eq!(d[rep].map(f32::to_bits), d[i].map(f32::to_bits));
        }
        // Few duplicates: not worth grouping.
        let distinct: Vec<Fpfh> = (0..MIN_DUPLICATES + 10)
            .map(|k| {
                let mut f = [0.0; FPFH_DIM];
                f[0] = k as f32;
                f
            })
            .collect();
        assert!(Unique::of(&distinct).is_none());
    }
}
