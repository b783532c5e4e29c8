//! PROSAC: progressive sampling over a ranked set (Chum & Matas, "Matching with PROSAC — Progressive
//! Sample Consensus", CVPR 2005), the closest prior art to MI-RANSAC.
//!
//! Hypothesis `t` (1-based) draws from the top `n(t)` ranks, where `n` grows on the schedule of
//! Sec. 2.2: `T_n = T_N · C(n, m) / C(N, m)` is the expected number of samples drawn from the top `n`
//! among `T_N` uniform ones, and `T'_{n+1} = T'_n + ceil(T_{n+1} − T_n)`, `T'_m = 1` (Eq. 3).

use rand::Rng;
use statrs::function::beta::beta_reg;

use super::sampler::{Sampler, check_sample_len, fill_distinct, uniform_index};
use crate::{Error, Result};

/// Default `T_N`: the number of hypotheses after which PROSAC has become plain RANSAC (the value
/// Chum & Matas used).
pub const DEFAULT_GROWTH_MAX_SAMPLES: u64 = 200_000;

/// The PROSAC sampler for a fixed sample size `m`.
#[derive(Debug, Clone)]
pub struct Prosac {
    n: usize,
    m: usize,
    /// `t_prime[k] = T'_{m+k}` for `k = 0..=N−m`: strictly increasing.
    t_prime: Vec<u64>,
}

impl Prosac {
    /// A sampler over `n` ranked items with sample size `m` and `T_N = growth_max_samples`
    /// (default [`DEFAULT_GROWTH_MAX_SAMPLES`]).
    pub fn new(n: usize, m: usize, growth_max_samples: u64) -> Result<Self> {
        if m == 0 || m > n || m > super::sampler::MAX_SAMPLE_SIZE || n > u32::MAX as usize {
            return Err(Error::InvalidInput(format!(
                "PROSAC with sample size {m} over {n} items"
            )));
        }
        if growth_max_samples == 0 {
            return Err(Error::InvalidInput(
                "PROSAC growth_max_samples must be > 0".into(),
            ));
        }
        // T_m = T_N · Π_{i<m} (m − i) / (N − i).
        let mut t_n = growth_max_samples as f64;
        for i in 0..m {
            t_n *= (m - i) as f64 / (n - i) as f64;
        }
        let mut t_prime = Vec::with_capacity(n - m + 1);
        let mut tp = 1u64;
        t_prime.push(tp);
        for size in m..n {
            // T_{n+1} = T_n · (n + 1) / (n + 1 − m).
            let next = t_n * (size + 1) as f64 / (size + 1 - m) as f64;
            tp += (next - t_n).ceil().max(1.0) as u64;
            t_prime.push(tp);
            t_n = next;
        }
        Ok(Self { n, m, t_prime })
    }

    /// Sample size `m`.
    pub fn sample_size(&self) -> usize {
        self.m
    }

    /// `T'_n` for `n ∈ [m, N]`.
    pub fn t_prime(&self, n: usize) -> u64 {
        self.t_prime[n - self.m]
    }

    /// The size `n(t)` of the progressive set for hypothesis number `t` (1-based): the smallest `n` with
    /// `T'_n ≥ t`, or `None` once the schedule is exhausted (`t > T'_N`: plain RANSAC over all items).
    pub fn set_size(&self, t: u64) -> Option<usize> {
        let k = self.t_prime.partition_point(|&tp| tp < t);
        (k < self.t_prime.len()).then_some(self.m + k)
    }
}

impl Sampler for Prosac {
    fn num_items(&self) -> usize {
        self.n
    }

    /// Hypothesis `h` (0-based) is PROSAC's iteration `t = h + 1`.
    // NOTE: the paper's Algorithm 1 prints the test as `T'_n < t`; its own definition of T'_n (the
    // samples that contain u_n) makes the sample hold u_n while `t ≤ T'_n`, which is what we and the
    // common implementations do. Past T'_N we sample uniformly from all N, as RANSAC.
    fn draw<R: Rng + ?Sized>(&self, hypothesis: u64, rng: &mut R, sample: &mut [usize]) {
        assert_eq!(
            sample.len(),
            self.m,
            "PROSAC was built for sample size {}",
            self.m
        );
        check_sample_len(sample.len(), self.n);
        match self.set_size(hypothesis + 1) {
            Some(n) => {
                sample[0] = n - 1;
                if self.m > 1 {
                    let (_, rest) = sample.split_at_mut(1);
                    fill_distinct(rest, || uniform_index(rng, n - 1));
                }
            }
            None => fill_distinct(sample, || uniform_index(rng, self.n)),
        }
    }
}

/// PROSAC's stopping rule (Chum & Matas 2005, Sec. 2.3): among the prefixes `n` whose inlier count is
/// non-random (Eq. 7–9), pick `n*` minimising the number of samples `k_n(η₀)` (Eq. 10) needed to miss
/// a better model with probability below `η₀`.
#[derive(Debug, Clone)]
pub struct ProsacTermination {
    m: usize,
    eta0: f64,
    /// `min_inliers[n]`: the non-randomness threshold `I_n^min` for the prefix of size `n`.
    min_inliers: Vec<usize>,
}

impl ProsacTermination {
    /// `n` items, sample size `m`, `beta` = probability that a random wrong model is supported by a
    /// given outlier (paper: 0.05 is "pessimistic"; default used by callers 0.05), `psi` = allowed
    /// probability that an inlier set is random (paper 0.05), `eta0` = 1 − confidence.
    pub fn new(n: usize, m: usize, beta: f64, psi: f64, eta0: f64) -> Self {
        assert!(m >= 1 && m <= n, "PROSAC termination with m = {m}, n = {n}");
        assert!((0.0..1.0).contains(&beta) && beta > 0.0);
        let min_inliers = (0..=n)
            .map(|size| {
                if size < m {
                    return usize::MAX;
                }
                // Support among the `size − m` points outside the sample is Binomial(size − m, β);
                // I_min = m + smallest j with P(X ≥ j) < ψ, with P(X ≥ j) = I_β(j, size − m − j + 1).
                let trials = size - m;
                let tail = |j: usize| {
                    if j == 0 {
                        1.0
                    } else if j > trials {
                        0.0
                    } else {
                        beta_reg(j as f64, (trials - j + 1) as f64, beta)
                    }
                };
                let (mut lo, mut hi) = (0usize, trials + 1);
                while lo < hi {
                    let mid = (lo + hi) / 2;
                    if tail(mid) < psi {
                        hi = mid
                    } else {
                        lo = mid + 1
                    }
                }
                m + lo
            })
            .collect();
        Self {
            m,
            eta0,
            min_inliers,
        }
    }

    /// Number of hypotheses after which PROSAC may stop, given the best model's inlier flags in rank
    /// order (`is_inlier[i]` for rank `i`); `None` when no prefix is non-random yet.
    pub fn required_hypotheses(&self, is_inlier: &[bool]) -> Option<f64> {
        let mut best: Option<f64> = None;
        let mut count = 0usize;
        for (i, &inl) in is_inlier.iter().enumerate() {
            count += inl as usize;
            let size = i + 1;
            if size < self.m || count < self.min_inliers[size] {
                continue;
            }
            let mut p_good = 1.0;
            for j in 0..self.m {
                p_good *= (count - j) as f64 / (size - j) as f64;
            }
            let k = if p_good >= 1.0 {
                1.0
            } else {
                self.eta0.ln() / (1.0 - p_good).ln()
            };
            best = Some(best.map_or(k, |b: f64| b.min(k)));
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_sample_is_the_top_m() {
        let p = Prosac::new(100, 3, DEFAULT_GROWTH_MAX_SAMPLES).unwrap();
        let mut rng = super::super::sampler::hypothesis_rng(3, 0);
        let mut s = [0; 3];
        p.draw(0, &mut rng, &mut s);
        s.sort_unstable();
        assert_eq!(s, [0, 1, 2]);
    }

    #[test]
    fn non_randomness_threshold_grows_with_n() {
        let t = ProsacTermination::new(500, 3, 0.05, 0.05, 0.01);
        // Expected random support is β·(n − m); the threshold must exceed it.
        for n in [10, 100, 500] {
            assert!(t.min_inliers[n] as f64 > 3.0 + 0.05 * (n - 3) as f64);
        }
        assert!(t.min_inliers[100] < t.min_inliers[500]);
    }
}
