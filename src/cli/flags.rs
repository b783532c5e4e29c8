//! Registration flags shared by `pair`, `register` and `sweep`: clap arguments → [`PairConfig`].

use anyhow::{Context, Result};
use clap::Args;

use std::path::PathBuf;

use clap::ValueEnum;

use crate::correspondence::ranking::{CountOrder, PAPER_DESCRIPTOR_RADIUS};
use crate::pipeline::{PairConfig, RankingConfig, SamplerConfig, Verification};

/// Sampler choice on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SamplerArg {
    /// MI-RANSAC's truncated Lévy law over the ranks.
    Levy,
    /// Plain RANSAC.
    Uniform,
    /// PROSAC.
    Prosac,
}

/// Ranking choice on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum RankingArg {
    /// Lowe ratio d1/d2, ascending.
    Ratio,
    /// Descriptor distance, ascending.
    Distance,
    /// Paper's neighbour count, largest first (authors' order).
    CountMost,
    /// Paper's neighbour count, smallest first.
    CountFewest,
}

/// Hypothesis verification on the command line ([`crate::pipeline::Verification`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum VerificationArg {
    /// Overlap of the whole feature clouds (Open3D's fitness).
    Dense,
    /// Correspondence inliers (the paper's count).
    Correspondences,
}

/// Registration flags shared by `pair` and `register`. Unset flags keep the value from
/// `--config` (TOML of [`PairConfig`]) or the documented default.
#[derive(Debug, Args, Default)]
pub struct RegistrationFlags {
    /// TOML file with any fields of the pairwise configuration (see docs/CONFIG.md).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Voxel size in metres; normal, feature, inlier and ICP radii derive from it [default: 0.05].
    #[arg(long)]
    pub voxel: Option<f64>,
    /// Hypothesis sampler [default: levy].
    #[arg(long, value_enum)]
    pub sampler: Option<SamplerArg>,
    /// Lévy location μ (< 0) [default: -50].
    #[arg(long, allow_hyphen_values = true)]
    pub mu: Option<f64>,
    /// Lévy scale c [default: 1].
    #[arg(long)]
    pub levy_c: Option<f64>,
    /// Lévy draws with replacement (the authors' behaviour).
    #[arg(long)]
    pub with_replacement: bool,
    /// Correspondence ranking [default: ratio].
    #[arg(long, value_enum)]
    pub ranking: Option<RankingArg>,
    /// Descriptor radius τ_d for the count rankings, in FPFH units [default: 12].
    #[arg(long)]
    pub descriptor_radius: Option<f32>,
    /// Keep only mutual nearest neighbours in feature space.
    #[arg(long)]
    pub mutual: bool,
    /// Cap on RANSAC hypotheses [default: 200000; Open3D's is 100000].
    #[arg(long)]
    pub max_hypotheses: Option<u64>,
    /// What RANSAC hypotheses are scored against [default: dense].
    #[arg(long, value_enum)]
    pub verification: Option<VerificationArg>,
    /// Skip ICP refinement.
    #[arg(long)]
    pub no_icp: bool,
    /// Seed of all randomness [default: 0].
    #[arg(long)]
    pub seed: Option<u64>,
}

/// The text of the `--config` file: a regular file of at most
/// [`crate::io::input_file::MAX_CONFIG_BYTES`].
fn read_config(path: &std::path::Path) -> Result<String> {
    Ok(crate::io::input_file::read_limited_text(
        path,
        crate::io::input_file::MAX_CONFIG_BYTES,
        "a configuration file",
    )?)
}

impl RegistrationFlags {
    /// Whether the voxel was given, by `--voxel` or as `voxel_size_m` in the `--config` file.
    pub fn voxel_configured(&self) -> Result<bool> {
        if self.voxel.is_some() {
            return Ok(true);
        }
        let Some(path) = &self.config else {
            return Ok(false);
        };
        let text = read_config(path)?;
        let table: toml::Table = toml::from_str(&text)
            .with_context(|| format!("{}: invalid configuration", path.display()))?;
        Ok(table.contains_key("voxel_size_m"))
    }

    /// The configuration: defaults, then `--config`, then explicit flags.
    pub fn config(&self) -> Result<PairConfig> {
        let mut c = match &self.config {
            Some(path) => {
                let text = read_config(path)?;
                toml::from_str::<PairConfig>(&text)
                    .with_context(|| format!("{}: invalid configuration", path.display()))?
            }
            None => PairConfig::default(),
        };
        if let Some(v) = self.voxel {
            c.voxel_size_m = v;
        }
        if self.mutual {
            c.mutual_filter = true;
        }
        if let Some(r) = self.ranking {
            let radius = self.descriptor_radius.unwrap_or(match c.ranking {
                RankingConfig::NeighbourCount { radius, .. } => radius,
                _ => PAPER_DESCRIPTOR_RADIUS as f32,
            });
            c.ranking = match r {
                RankingArg::Ratio => RankingConfig::Ratio,
                RankingArg::Distance => RankingConfig::Distance,
                RankingArg::CountMost => RankingConfig::NeighbourCount {
                    radius,
                    order: CountOrder::MostFirst,
                },
                RankingArg::CountFewest => RankingConfig::NeighbourCount {
                    radius,
                    order: CountOrder::FewestFirst,
                },
            };
        } else if let (Some(d), RankingConfig::NeighbourCount { radius, .. }) =
            (self.descriptor_radius, &mut c.ranking)
        {
            *radius = d;
        }
        let (mut mu, mut levy_c, window, mut repl) = match c.sampler {
            SamplerConfig::Levy {
                mu,
                c,
                window,
                with_replacement,
            } => (mu, c, window, with_replacement),
            _ => (-50.0, 1.0, crate::ransac::levy::DEFAULT_WINDOW, false),
        };
        mu = self.mu.unwrap_or(mu);
        levy_c = self.levy_c.unwrap_or(levy_c);
        repl |= self.with_replacement;
        let levy = SamplerConfig::Levy {
            mu,
            c: levy_c,
            window,
            with_replacement: repl,
        };
        c.sampler = match self.sampler {
            Some(SamplerArg::Uniform) => SamplerConfig::Uniform,
            Some(SamplerArg::Prosac) => SamplerConfig::Prosac {
                growth_max_samples: crate::ransac::prosac::DEFAULT_GROWTH_MAX_SAMPLES,
            },
            Some(SamplerArg::Levy) => levy,
            None if matches!(c.sampler, SamplerConfig::Levy { .. }) => levy,
            None => c.sampler,
        };
        if let Some(m) = self.max_hypotheses {
            c.max_hypotheses = m;
        }
        if let Some(v) = self.verification {
            c.verification = match v {
                VerificationArg::Dense => Verification::Dense,
                VerificationArg::Correspondences => Verification::Correspondences,
            };
        }
        if self.no_icp {
            c.icp = false;
        }
        if let Some(seed) = self.seed {
            c.seed = seed;
        }
        c.resolved().context("invalid configuration")?;
        Ok(c)
    }
}
