//! The paper's sampling simulation (Zhang & Chen, Sec. IV-A, Fig. 5).
//!
//! A boolean vector of `num_items` entries holds `num_inliers` `true` entries whose positions are
//! drawn from the truncated Lévy(μ = −10, c = 1) law scaled to the vector (so inliers concentrate at
//! the top ranks, as a good ranking would make them). Each sampling strategy draws hypotheses of
//! `s` indices; the score is the number of **unique** hypotheses (as index sets) whose indices are all
//! `true`. We also report the median number of hypotheses until the first outlier-free one.
//!
//! Every budget of a (strategy, s, run) cell is a prefix of one stream of hypotheses, so a run of the
//! largest budget yields all smaller ones. Run `r` uses the same boolean vector for every strategy
//! (a paired comparison). Results are identical for a seed on any thread count.

use std::collections::HashSet;

use rand::SeedableRng;
use rayon::prelude::*;

use crate::ransac::levy::{DEFAULT_SCALE, DEFAULT_WINDOW};
use crate::ransac::prosac::DEFAULT_GROWTH_MAX_SAMPLES;
use crate::ransac::sampler::{Sampler, splitmix64};
use crate::ransac::{Levy, Prosac, TruncatedLevy, Uniform};
use crate::{Error, Result};

/// A sampling strategy under test.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Strategy {
    /// Plain RANSAC.
    Uniform,
    /// PROSAC with `T_N` = [`DEFAULT_GROWTH_MAX_SAMPLES`].
    Prosac,
    /// MI-RANSAC's truncated Lévy sampler (window [`DEFAULT_WINDOW`]).
    Levy {
        /// Location μ (< 0).
        mu: f64,
        /// Scale c (> 0).
        c: f64,
    },
}

impl Strategy {
    /// `uniform`, `prosac` or `levy`.
    pub fn name(&self) -> &'static str {
        match self {
            Strategy::Uniform => "uniform",
            Strategy::Prosac => "prosac",
            Strategy::Levy { .. } => "levy",
        }
    }
}

/// The simulation's parameters; [`Default`] is the paper's full experiment.
#[derive(Debug, Clone, PartialEq)]
pub struct SimulationConfig {
    /// Length of the boolean vector. Default 3000.
    pub num_items: usize,
    /// Number of `true` entries. Default 300.
    pub num_inliers: usize,
    /// Lévy location of the inlier positions. Default −10.
    pub inlier_mu: f64,
    /// Lévy scale of the inlier positions. Default 1.
    pub inlier_c: f64,
    /// Default: uniform, PROSAC, Lévy c = 1 with μ ∈ {−1, −50, −1e2, −1e3, −1e4, −1e5, −1e6}.
    pub strategies: Vec<Strategy>,
    /// Default {2, 3, 4}; at most 4.
    pub sample_sizes: Vec<usize>,
    /// Hypothesis budgets. Default {1e2, 1e3, 1e4, 1e5, 1e6}.
    pub budgets: Vec<u64>,
    /// Monte Carlo runs per cell. Default 20.
    pub runs: usize,
    /// Seed of all randomness. Default 0.
    pub seed: u64,
}

impl Default for SimulationConfig {
    fn default() -> Self {
        let mut strategies = vec![Strategy::Uniform, Strategy::Prosac];
        for mu in [-1.0, -50.0, -1e2, -1e3, -1e4, -1e5, -1e6] {
            strategies.push(Strategy::Levy {
                mu,
                c: DEFAULT_SCALE,
            });
        }
        Self {
            num_items: 3000,
            num_inliers: 300,
            inlier_mu: -10.0,
            inlier_c: 1.0,
            strategies,
            sample_sizes: vec![2, 3, 4],
            budgets: vec![100, 1_000, 10_000, 100_000, 1_000_000],
            runs: 20,
            seed: 0,
        }
    }
}

impl SimulationConfig {
    /// The `--quick` variant: budgets ≤ 1e4 and 5 runs.
    pub fn quick() -> Self {
        Self {
            budgets: vec![100, 1_000, 10_000],
            runs: 5,
            ..Self::default()
        }
    }
}

/// One line of the result table.
#[derive(Debug, Clone, PartialEq)]
pub struct SimulationRow {
    /// The strategy.
    pub strategy: Strategy,
    /// Sample size `s`.
    pub sample_size: usize,
    /// Budget of hypotheses.
    pub hypotheses: u64,
    /// Runs averaged.
    pub runs: usize,
    /// Mean number of unique outlier-free hypotheses.
    pub unique_outlier_free_mean: f64,
    /// Sample standard deviation of the same (0 for a single run).
    pub unique_outlier_free_std: f64,
    /// Median (over runs) number of hypotheses up to and including the first outlier-free one;
    /// `None` when at least half the runs found none within the budget.
    pub first_success_median: Option<f64>,
}

/// Draws the boolean inlier vector of one run.
pub fn inlier_vector<R: rand::Rng + ?Sized>(
    config: &SimulationConfig,
    rng: &mut R,
) -> Result<Vec<bool>> {
    let dist = TruncatedLevy::new(config.inlier_mu, config.inlier_c, DEFAULT_WINDOW)?;
    let levy = Levy::new(dist, config.num_items)?;
    let mut flags = vec![false; config.num_items];
    let mut placed = 0;
    while placed < config.num_inliers {
        let i = levy.draw_rank(rng);
        if !flags[i] {
            flags[i] = true;
            placed += 1;
        }
    }
    Ok(flags)
}

struct CellRun {
    unique_at_budget: Vec<u64>,
    first_success: Option<u64>,
}

fn run_cell(
    config: &SimulationConfig,
    strategy: Strategy,
    s: usize,
    run: usize,
) -> Result<CellRun> {
    let n = config.num_items;
    // The data depend on (seed, run) only, so every strategy sees the same vector in a run.
    let data_seed = splitmix64(config.seed ^ splitmix64(run as u64 + 1));
    let flags = inlier_vector(config, &mut rand_pcg::Pcg64Mcg::seed_from_u64(data_seed))?;
    let stream = splitmix64(data_seed ^ splitmix64(s as u64 ^ strategy_tag(&strategy)));
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(stream);
    let max_budget = config.budgets.iter().copied().max().unwrap_or(0);
    enum Any {
        U(Uniform),
        P(Prosac),
        L(Levy),
    }
    let sampler = match strategy {
        Strategy::Uniform => Any::U(Uniform::new(n)),
        Strategy::Prosac => Any::P(Prosac::new(n, s, DEFAULT_GROWTH_MAX_SAMPLES)?),
        Strategy::Levy { mu, c } => {
            Any::L(Levy::new(TruncatedLevy::new(mu, c, DEFAULT_WINDOW)?, n)?)
        }
    };
    let mut seen: HashSet<u64> = HashSet::new();
    let mut first_success = None;
    let mut unique_at_budget = vec![0; config.budgets.len()];
    let mut buf = [0usize; 4];
    for h in 0..max_budget {
        let sample = &mut buf[..s];
        match &sampler {
            Any::U(x) => x.draw(h, &mut rng, sample),
            Any::P(x) => x.draw(h, &mut rng, sample),
            Any::L(x) => x.draw(h, &mut rng, sample),
        }
        if sample.iter().all(|&i| flags[i]) {
            first_success.get_or_insert(h + 1);
            sample.sort_unstable();
            let key = sample.iter().fold(0u64, |k, &i| (k << 16) | i as u64);
            seen.insert(key);
        }
        for (slot, &b) in unique_at_budget.iter_mut().zip(&config.budgets) {
            if h + 1 == b {
                *slot = seen.len() as u64;
            }
        }
    }
    Ok(CellRun {
        unique_at_budget,
        first_success,
    })
}

fn strategy_tag(s: &Strategy) -> u64 {
    match *s {
        Strategy::Uniform => 1,
        Strategy::Prosac => 2,
        Strategy::Levy { mu, c } => splitmix64(mu.to_bits()) ^ c.to_bits().rotate_left(17),
    }
}

/// Runs the simulation; rows are ordered by strategy, sample size, then budget.
pub fn simulate(config: &SimulationConfig) -> Result<Vec<SimulationRow>> {
    if config.num_items > u16::MAX as usize || config.num_inliers > config.num_items {
        return Err(Error::InvalidInput(format!(
            "simulation needs num_inliers ≤ num_items ≤ {}, got {} / {}",
            u16::MAX,
            config.num_inliers,
            config.num_items
        )));
    }
    if config.runs == 0 || config.budgets.is_empty() {
        return Err(Error::InvalidInput(
            "simulation needs at least one run and one budget".into(),
        ));
    }
    for &s in &config.sample_sizes {
        if !(1..=4).contains(&s) || s > config.num_inliers {
            return Err(Error::InvalidInput(format!(
                "sample size {s} not in 1..=4 (or above the inlier count)"
            )));
        }
    }
    let mut cells = Vec::new();
    for &strategy in &config.strategies {
        for &s in &config.sample_sizes {
            for run in 0..config.runs {
                cells.push((strategy, s, run));
            }
        }
    }
    let results: Vec<CellRun> = cells
        .par_iter()
        .map(|&(strategy, s, run)| run_cell(config, strategy, s, run))
        .collect::<Result<_>>()?;

    let mut rows = Vec::new();
    for (chunk, cell) in results.chunks(config.runs).zip(cells.chunks(config.runs)) {
        let (strategy, s, _) = cell[0];
        for (b, &budget) in config.budgets.iter().enumerate() {
            let values: Vec<f64> = chunk.iter().map(|r| r.unique_at_budget[b] as f64).collect();
            let mean = values.iter().sum::<f64>() / values.len() as f64;
            let std = if values.len() > 1 {
                (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (values.len() - 1) as f64)
                    .sqrt()
            } else {
                0.0
            };
            let mut firsts: Vec<f64> = chunk
                .iter()
                .map(|r| {
                    r.first_success
                        .filter(|&f| f <= budget)
                        .map_or(f64::INFINITY, |f| f as f64)
                })
                .collect();
            rows.push(SimulationRow {
                strategy,
                sample_size: s,
                hypotheses: budget,
                runs: config.runs,
                unique_outlier_free_mean: mean,
                unique_outlier_free_std: std,
                first_success_median: median(&mut firsts).filter(|m| m.is_finite()),
            });
        }
    }
    Ok(rows)
}

fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let k = values.len() / 2;
    Some(if values.len() % 2 == 1 {
        values[k]
    } else {
        0.5 * (values[k - 1] + values[k])
    })
}

/// The CSV header `--csv` prints.
pub const CSV_HEADER: &str = "strategy,mu,c,sample_size,hypotheses,runs,unique_outlier_free_mean,unique_outlier_free_std,first_success_median";

impl SimulationRow {
    /// The row as a CSV line matching [`CSV_HEADER`] (`mu` and `c` empty unless Lévy, median empty when
    /// undefined).
    pub fn to_csv(&self) -> String {
        let (mu, c) = match self.strategy {
            Strategy::Levy { mu, c } => (format!("{mu}"), format!("{c}")),
            _ => (String::new(), String::new()),
        };
        format!(
            "{},{},{},{},{},{},{:.3},{:.3},{}",
            self.strategy.name(),
            mu,
            c,
            self.sample_size,
            self.hypotheses,
            self.runs,
            self.unique_outlier_free_mean,
            self.unique_outlier_free_std,
            self.first_success_median
                .map_or(String::new(), |m| format!("{m}"))
        )
    }
}
