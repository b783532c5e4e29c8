//! The truncated Lévy distribution over correspondence ranks: MI-RANSAC's sampler.
//!
//! Zhang & Chen, "More Informed Random Sample Consensus", Sec. III: hypotheses draw their indices from a
//! Lévy distribution with location μ < 0 and scale c,
//!
//! ```text
//! f(x; μ, c) = sqrt(c / 2π) · exp(−c / (2(x − μ))) / (x − μ)^{3/2},   x > μ,
//! F(x; μ, c) = erfc( sqrt(c / (2(x − μ))) ),
//! ```
//!
//! truncated to the window `[0, m]` (the paper and the authors' code use m = 100) and scaled to the
//! `n` ranks. With μ = −1 the mass sits on the first ranks; as μ → −∞ the law flattens to uniform, so
//! plain RANSAC is the limit case.
//!
//! # Numerics
//! Write z(x) = sqrt(c / (2(x − μ))), a = z(0), b = z(m). The truncated CDF is
//! `G(x) = (erf(a) − erf(z(x))) / (erf(a) − erf(b))`, and its exact inverse is
//! `x = μ + c / (2 z²)` with `z = erf⁻¹(erf(a) − u·(erf(a) − erf(b)))`. Working with `erf` of the
//! small arguments (rather than `erfc` ≈ 1) keeps full relative precision even for μ = −10⁶, where the
//! window holds only ~4·10⁻⁸ of the untruncated mass and rejection sampling would be hopeless.
//!
//! # Index mapping
//! Rank `i` (0-based) receives the mass of `x ∈ (i·m/n, (i+1)·m/n]`, i.e. `i = ceil(x·n/m) − 1` clamped
//! to `[0, n)`. This is the authors' 1-based `ceil(x·N/100)` shifted to 0-based. The sampler inverts
//! the CDF of this discrete law exactly (a table of `G` at the `n + 1` bin edges plus a guide table,
//! Chen & Asau 1974), which gives the same index as inverting `G` and binning, at table-lookup speed.

use rand::{Rng, RngExt};
use statrs::function::erf::{erf, erf_inv};

use super::sampler::{Sampler, check_sample_len, fill_distinct};
use crate::{Error, Result};

/// Default truncation window `m` (paper, Sec. III, and the authors' code).
pub const DEFAULT_WINDOW: f64 = 100.0;
/// Default Lévy scale `c` (fixed to 1 in the paper and the authors' code).
pub const DEFAULT_SCALE: f64 = 1.0;

/// A Lévy(μ, c) distribution truncated to `[0, window]`, sampled by exact inverse CDF.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruncatedLevy {
    mu: f64,
    c: f64,
    window: f64,
    erf_a: f64,
    /// `erf(a) − erf(b)`: the truncated mass (in units of the untruncated total).
    mass: f64,
}

impl TruncatedLevy {
    /// Location `mu` (< 0), scale `c` (> 0), window `[0, window]` (> 0). Numerically validated for
    /// μ ∈ [−10⁶, −1] and c ∈ [0.1, 10].
    pub fn new(mu: f64, c: f64, window: f64) -> Result<Self> {
        if !(mu.is_finite() && mu < 0.0) {
            return Err(Error::InvalidInput(format!(
                "Lévy location mu must be finite and < 0, got {mu}"
            )));
        }
        if !(c.is_finite() && c > 0.0) {
            return Err(Error::InvalidInput(format!(
                "Lévy scale c must be finite and > 0, got {c}"
            )));
        }
        if !(window.is_finite() && window > 0.0) {
            return Err(Error::InvalidInput(format!(
                "Lévy window must be finite and > 0, got {window}"
            )));
        }
        let erf_a = erf(Self::z_of(mu, c, 0.0));
        let mass = erf_a - erf(Self::z_of(mu, c, window));
        if mass.is_nan() || mass <= 0.0 {
            return Err(Error::InvalidInput(format!(
                "Lévy(mu = {mu}, c = {c}) has no representable mass on [0, {window}]"
            )));
        }
        Ok(Self {
            mu,
            c,
            window,
            erf_a,
            mass,
        })
    }

    #[inline]
    fn z_of(mu: f64, c: f64, x: f64) -> f64 {
        (c / (2.0 * (x - mu))).sqrt()
    }

    /// Location μ.
    pub fn mu(&self) -> f64 {
        self.mu
    }

    /// Scale c.
    pub fn c(&self) -> f64 {
        self.c
    }

    /// Upper end of the window `m`.
    pub fn window(&self) -> f64 {
        self.window
    }

    /// Truncated CDF `G(x)`: 0 below 0, 1 above the window.
    pub fn cdf(&self, x: f64) -> f64 {
        if x <= 0.0 {
            0.0
        } else if x >= self.window {
            1.0
        } else {
            ((self.erf_a - erf(Self::z_of(self.mu, self.c, x))) / self.mass).clamp(0.0, 1.0)
        }
    }

    /// Exact inverse of [`cdf`](Self::cdf) for `u ∈ [0, 1]`; the result lies in `[0, window]`.
    pub fn inverse_cdf(&self, u: f64) -> f64 {
        let z = erf_inv(self.erf_a - u * self.mass);
        (self.mu + self.c / (2.0 * z * z)).clamp(0.0, self.window)
    }

    /// One draw by inverse transform of a uniform `[0, 1)` variate.
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        self.inverse_cdf(rng.random::<f64>())
    }
}

/// MI-RANSAC's index sampler: ranks drawn from a [`TruncatedLevy`] scaled to `[0, n)`.
#[derive(Debug, Clone)]
pub struct Levy {
    dist: TruncatedLevy,
    n: usize,
    with_replacement: bool,
    /// `edges[i] = G(i·m/n)` for `i = 0..=n`, `edges[n] = 1`.
    edges: Vec<f64>,
    /// `guide[k]` = the smallest rank `i` with `edges[i + 1] > k / n`.
    guide: Vec<u32>,
}

impl Levy {
    /// A sampler over `n` ranks (`1 ≤ n ≤ u32::MAX`) with the given distribution. Samples hold distinct
    /// indices (see [`with_replacement`](Self::with_replacement)).
    pub fn new(dist: TruncatedLevy, n: usize) -> Result<Self> {
        if n == 0 || n > u32::MAX as usize {
            return Err(Error::InvalidInput(format!("Lévy sampler over {n} ranks")));
        }
        let step = dist.window() / n as f64;
        let mut edges: Vec<f64> = (0..=n).map(|i| dist.cdf(i as f64 * step)).collect();
        edges[0] = 0.0;
        edges[n] = 1.0;
        // `cdf` is monotone mathematically; enforce it against last-ulp wobble of `erf`.
        for i in 1..=n {
            edges[i] = edges[i].max(edges[i - 1]);
        }
        let mut guide = Vec::with_capacity(n);
        let mut i = 0usize;
        for k in 0..n {
            let u = k as f64 / n as f64;
            while i + 1 < n && edges[i + 1] <= u {
                i += 1;
            }
            guide.push(i as u32);
        }
        Ok(Self {
            dist,
            n,
            with_replacement: false,
            edges,
            guide,
        })
    }

    /// Draw every slot independently, so a sample may repeat an index — what the authors' code does
    /// (reproduces their behaviour; such samples are degenerate for rigid estimation). Default: `false`.
    #[must_use]
    pub fn with_replacement(mut self, yes: bool) -> Self {
        self.with_replacement = yes;
        self
    }

    /// The underlying continuous distribution.
    pub fn distribution(&self) -> &TruncatedLevy {
        &self.dist
    }

    /// Probability of rank `i` for a single draw: `G((i+1)·m/n) − G(i·m/n)`.
    pub fn rank_probability(&self, i: usize) -> f64 {
        self.edges[i + 1] - self.edges[i]
    }

    /// The rank for a uniform variate `u ∈ [0, 1)`: the smallest `i` with `G((i+1)·m/n) > u`.
    #[inline]
    pub fn rank_for(&self, u: f64) -> usize {
        let slot = ((u * self.n as f64) as usize).min(self.n - 1);
        let mut i = self.guide[slot] as usize;
        while i + 1 < self.n && self.edges[i + 1] <= u {
            i += 1;
        }
        i
    }

    /// One rank drawn from the discretised truncated Lévy law.
    #[inline]
    pub fn draw_rank<R: Rng + ?Sized>(&self, rng: &mut R) -> usize {
        self.rank_for(rng.random::<f64>())
    }
}

impl Sampler for Levy {
    fn num_items(&self) -> usize {
        self.n
    }

    fn draw<R: Rng + ?Sized>(&self, _hypothesis: u64, rng: &mut R, sample: &mut [usize]) {
        if self.with_replacement {
            assert!(sample.len() <= super::sampler::MAX_SAMPLE_SIZE);
            for slot in sample.iter_mut() {
                *slot = self.draw_rank(rng);
            }
        } else {
            check_sample_len(sample.len(), self.n);
            fill_distinct(sample, || self.draw_rank(rng));
        }
    }

    fn draw_probability(&self, i: usize) -> Option<f64> {
        Some(self.rank_probability(i))
    }
}

/// Samples with any RNG the ecosystem's way (`rand_distr` builds on this trait):
/// `dist.sample(&mut rng)` or `rng.sample(dist)`, the same draw as [`TruncatedLevy::sample`].
impl rand::distr::Distribution<f64> for TruncatedLevy {
    fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        TruncatedLevy::sample(self, rng)
    }
}

/// One rank of the discrete law over `[0, n)`, the same draw as [`Levy::draw_rank`].
impl rand::distr::Distribution<usize> for Levy {
    fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> usize {
        self.draw_rank(rng)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_distribution_trait_draws_the_analytic_law() {
        use rand::SeedableRng;
        use rand_distr::Distribution;
        // Through the trait, with an RNG of the rand ecosystem: the empirical CDF of 20 000 draws
        // against the analytic one (Kolmogorov–Smirnov bound at α = 0.001: 1.95 / sqrt(n)).
        let d = TruncatedLevy::new(-50.0, 1.0, 100.0).unwrap();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        let mut xs: Vec<f64> = (0..20_000)
            .map(|_| Distribution::sample(&d, &mut rng))
            .collect();
        xs.sort_by(f64::total_cmp);
        let n = xs.len() as f64;
        let ks = xs
            .iter()
            .enumerate()
            .map(|(i, &x)| {
                let g = d.cdf(x);
                (g - i as f64 / n).abs().max((g - (i + 1) as f64 / n).abs())
            })
            .fold(0.0, f64::max);
        assert!(ks < 1.95 / n.sqrt(), "KS statistic {ks}");
        // The same draw as the inherent sampler, for the same RNG state.
        let (mut a, mut b) = (
            rand_pcg::Pcg64::seed_from_u64(3),
            rand_pcg::Pcg64::seed_from_u64(3),
        );
        assert_eq!(Distribution::sample(&d, &mut a), d.sample(&mut b));
        // Ranks through the trait follow rank_probability.
        let levy = Levy::new(TruncatedLevy::new(-1.0, 1.0, 100.0).unwrap(), 10).unwrap();
        let mut counts = [0usize; 10];
        for _ in 0..50_000 {
            counts[Distribution::<usize>::sample(&levy, &mut rng)] += 1;
        }
        for (i, &c) in counts.iter().enumerate() {
            let p = levy.rank_probability(i);
            let sd = (50_000.0 * p * (1.0 - p)).sqrt();
            assert!(
                (c as f64 - 50_000.0 * p).abs() < 5.0 * sd + 1.0,
                "rank {i}: {c} vs p {p}"
            );
        }
    }

    #[test]
    fn rejects_bad_parameters() {
        assert!(TruncatedLevy::new(0.0, 1.0, 100.0).is_err());
        assert!(TruncatedLevy::new(-1.0, 0.0, 100.0).is_err());
        assert!(TruncatedLevy::new(-1.0, 1.0, f64::NAN).is_err());
        let d = TruncatedLevy::new(-1.0, 1.0, 100.0).unwrap();
        assert!(Levy::new(d, 0).is_err());
    }

    #[test]
    fn inverse_cdf_inverts_cdf() {
        for &mu in &[-1.0, -50.0, -1e3, -1e6] {
            for &c in &[0.1, 1.0, 10.0] {
                let d = TruncatedLevy::new(mu, c, 100.0).unwrap();
                for k in 1..100 {
                    let x = k as f64;
                    let back = d.inverse_cdf(d.cdf(x));
                    assert!((back - x).abs() < 1e-6, "mu {mu} c {c}: x {x} -> {back}");
                }
            }
        }
    }

    #[test]
    fn with_replacement_repeats_indices_like_the_authors_code() {
        // Over 10 ranks with μ = −1 the top rank has ~30 % mass: triples repeat often when each
        // slot is independent, never when samples are distinct.
        let d = TruncatedLevy::new(-1.0, 1.0, 100.0).unwrap();
        let distinct = Levy::new(d, 10).unwrap();
        let authors = distinct.clone().with_replacement(true);
        let mut rng = super::super::sampler::hypothesis_rng(1, 0);
        let (mut s, mut repeats) = ([0usize; 3], [0u32; 2]);
        for (k, sampler) in [&distinct, &authors].into_iter().enumerate() {
            for h in 0..2000 {
                sampler.draw(h, &mut rng, &mut s);
                repeats[k] += (s[0] == s[1] || s[0] == s[2] || s[1] == s[2]) as u32;
            }
        }
        assert_eq!(repeats[0], 0);
        // P(some pair equal) = 1 − P(all distinct) ≥ 1 − (1 − p0)… with p0 ≈ 0.3: well above 20 %.
        assert!(repeats[1] > 400, "{} repeats in 2000 triples", repeats[1]);
    }

    #[test]
    fn table_rank_matches_direct_inversion() {
        let n = 997;
        for &mu in &[-1.0, -50.0, -1e6] {
            let d = TruncatedLevy::new(mu, 1.0, 100.0).unwrap();
            let s = Levy::new(d, n).unwrap();
            for k in 0..10_000 {
                let u = (k as f64 + 0.5) / 10_000.0;
                let x = d.inverse_cdf(u) * n as f64 / 100.0;
                // Away from bin edges the two must agree exactly.
                if (x - x.round()).abs() > 1e-6 {
                    let direct = (x.ceil() as usize).clamp(1, n) - 1;
                    assert_eq!(s.rank_for(u), direct, "mu {mu} u {u}");
                }
            }
        }
    }
}
