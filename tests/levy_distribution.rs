//! The Lévy index sampler against the analytic truncated law: chi-square goodness of fit.
//!
//! The oracle integrates the Lévy pdf numerically over each rank's bin (no erf involved), so it is
//! independent of the sampler's inverse-CDF arithmetic.

use mireg::ransac::{Levy, TruncatedLevy, hypothesis_rng};
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// Untruncated Lévy pdf f(x; μ, c) (paper, Sec. III).
fn levy_pdf(x: f64, mu: f64, c: f64) -> f64 {
    let y = x - mu;
    (c / (2.0 * std::f64::consts::PI)).sqrt() * (-c / (2.0 * y)).exp() / y.powf(1.5)
}

/// ∫_a^b f by composite Simpson with `steps` panels.
fn integrate(a: f64, b: f64, steps: usize, f: impl Fn(f64) -> f64) -> f64 {
    let h = (b - a) / steps as f64;
    let mut s = f(a) + f(b);
    for i in 1..steps {
        s += f(a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    s * h / 3.0
}

fn bin_probabilities(mu: f64, c: f64, window: f64, n: usize) -> Vec<f64> {
    let w = window / n as f64;
    let raw: Vec<f64> = (0..n)
        .map(|i| {
            integrate(i as f64 * w, (i + 1) as f64 * w, 2000, |x| {
                levy_pdf(x, mu, c)
            })
        })
        .collect();
    let total: f64 = raw.iter().sum();
    raw.iter().map(|p| p / total).collect()
}

/// Chi-square statistic with bins of expected count < 5 merged into their neighbour.
fn chi_square(counts: &[u64], probs: &[f64], draws: u64) -> (f64, usize) {
    let (mut stat, mut bins) = (0.0, 0);
    let (mut obs, mut exp) = (0.0, 0.0);
    for (&c, &p) in counts.iter().zip(probs) {
        obs += c as f64;
        exp += p * draws as f64;
        if exp >= 5.0 {
            stat += (obs - exp).powi(2) / exp;
            bins += 1;
            obs = 0.0;
            exp = 0.0;
        }
    }
    if exp > 0.0 {
        stat += (obs - exp).powi(2) / exp.max(1e-300);
        bins += 1;
    }
    (stat, bins)
}

fn check(mu: f64, c: f64, n: usize, seed: u64) {
    let window = 100.0;
    let sampler = Levy::new(TruncatedLevy::new(mu, c, window).unwrap(), n).unwrap();
    let draws = 400_000u64;
    let mut counts = vec![0u64; n];
    let mut rng = hypothesis_rng(seed, 0);
    for _ in 0..draws {
        counts[sampler.draw_rank(&mut rng)] += 1;
    }
    let probs = bin_probabilities(mu, c, window, n);
    let (stat, bins) = chi_square(&counts, &probs, draws);
    let critical = ChiSquared::new((bins - 1) as f64)
        .unwrap()
        .inverse_cdf(0.999);
    assert!(
        stat < critical,
        "mu {mu} c {c}: chi-square {stat:.1} over {bins} bins exceeds the 0.1 % critical value {critical:.1}"
    );
    // The sampler's own bin probabilities agree with the quadrature oracle too.
    for (i, p) in probs.iter().enumerate() {
        let q = sampler.rank_probability(i);
        assert!(
            (q - p).abs() < 1e-6 * p.max(1e-3),
            "mu {mu} c {c} rank {i}: {q} vs {p}"
        );
    }
}

#[test]
fn chi_square_mu_minus_1() {
    check(-1.0, 1.0, 50, 11);
}

#[test]
fn chi_square_mu_minus_50() {
    check(-50.0, 1.0, 50, 12);
}

#[test]
fn chi_square_mu_minus_1e3() {
    check(-1e3, 1.0, 50, 13);
}

#[test]
fn chi_square_mu_minus_1e6() {
    check(-1e6, 1.0, 50, 14);
}

#[test]
fn chi_square_extreme_scales() {
    check(-1.0, 0.1, 40, 15);
    check(-1.0, 10.0, 40, 16);
    check(-1e6, 0.1, 40, 17);
    check(-1e6, 10.0, 40, 18);
}

#[test]
fn the_test_detects_a_wrong_law() {
    // Guard against a vacuous test: draws from μ = −50 must fail the fit for μ = −1.
    let n = 50;
    let sampler = Levy::new(TruncatedLevy::new(-50.0, 1.0, 100.0).unwrap(), n).unwrap();
    let mut counts = vec![0u64; n];
    let mut rng = hypothesis_rng(5, 0);
    for _ in 0..400_000 {
        counts[sampler.draw_rank(&mut rng)] += 1;
    }
    let (stat, bins) = chi_square(&counts, &bin_probabilities(-1.0, 1.0, 100.0, n), 400_000);
    assert!(
        stat > ChiSquared::new((bins - 1) as f64)
            .unwrap()
            .inverse_cdf(0.999)
    );
}

#[test]
fn flattens_to_uniform_for_very_negative_mu() {
    let s = Levy::new(TruncatedLevy::new(-1e6, 1.0, 100.0).unwrap(), 100).unwrap();
    for i in 0..100 {
        assert!(
            (s.rank_probability(i) - 0.01).abs() < 1e-5,
            "rank {i}: {}",
            s.rank_probability(i)
        );
    }
}
