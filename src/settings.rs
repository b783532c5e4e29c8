//! Registration settings as the command line and the Python package name them: flat, each one
//! optional (unset keeps the value from the configuration file or the documented default), and
//! how they resolve into a [`PairConfig`]. `mireg pair`, `mireg register` and the Python
//! `register_log` all go through [`PairSettings::config`], so the same settings give the same
//! configuration whichever way they came in.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::correspondence::ranking::{CountOrder, PAPER_DESCRIPTOR_RADIUS};
use crate::pipeline::{PairConfig, RankingConfig, SamplerConfig, Verification};
use crate::{Error, Result};

/// Which hypothesis sampler ([`SamplerConfig`]) to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SamplerChoice {
    /// MI-RANSAC's truncated Lévy law over the ranks.
    Levy,
    /// Plain RANSAC.
    Uniform,
    /// PROSAC.
    Prosac,
}

/// Which correspondence ranking ([`RankingConfig`]) to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RankingChoice {
    /// Lowe ratio d1/d2, ascending.
    Ratio,
    /// Descriptor distance, ascending.
    Distance,
    /// Paper's neighbour count, largest first (authors' order).
    #[serde(alias = "count-most")]
    CountMost,
    /// Paper's neighbour count, smallest first.
    #[serde(alias = "count-fewest")]
    CountFewest,
}

/// The pairwise registration settings shared by `pair` and `register`: a configuration file,
/// then each set field over it. Every field defaults to unset (`None` or `false`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PairSettings {
    /// TOML file with any fields of [`PairConfig`] (docs/CONFIG.md).
    pub config: Option<PathBuf>,
    /// Voxel size \[m\]; normal, feature, inlier and ICP radii derive from it. Unset: the
    /// configuration's (0.05 m by default).
    pub voxel: Option<f64>,
    /// Hypothesis sampler. Unset: the configuration's (Lévy by default).
    pub sampler: Option<SamplerChoice>,
    /// Lévy location μ (< 0). Unset: the configuration's (−50 by default).
    pub mu: Option<f64>,
    /// Lévy scale c. Unset: the configuration's (1 by default).
    pub levy_c: Option<f64>,
    /// Lévy draws with replacement (the authors' behaviour).
    pub with_replacement: bool,
    /// Correspondence ranking. Unset: the configuration's (ratio by default).
    pub ranking: Option<RankingChoice>,
    /// Descriptor radius τ_d for the count rankings, in FPFH units. Unset: the configuration's
    /// (12 by default).
    pub descriptor_radius: Option<f32>,
    /// Keep only mutual nearest neighbours in feature space.
    pub mutual: bool,
    /// Cap on RANSAC hypotheses. Unset: the configuration's (200 000 by default).
    pub max_hypotheses: Option<u64>,
    /// What RANSAC hypotheses are scored against. Unset: the configuration's (dense by default).
    pub verification: Option<Verification>,
    /// Skip ICP refinement.
    pub no_icp: bool,
    /// Seed of all randomness. Unset: the configuration's (0 by default).
    pub seed: Option<u64>,
}

/// The text of the configuration file: a regular file of at most
/// [`crate::io::input_file::MAX_CONFIG_BYTES`].
fn read_config(path: &Path) -> Result<String> {
    crate::io::input_file::read_limited_text(
        path,
        crate::io::input_file::MAX_CONFIG_BYTES,
        "a configuration file",
    )
}

/// `path`'s text parsed as TOML of `T`; an error names the file.
fn parse_config<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    toml::from_str(&read_config(path)?).map_err(|e| Error::Format {
        path: path.to_path_buf(),
        detail: format!("invalid configuration: {e}"),
    })
}

impl PairSettings {
    /// Whether the voxel was given, by [`PairSettings::voxel`] or as `voxel_size_m` in the
    /// configuration file.
    ///
    /// # Errors
    /// A configuration file that cannot be read or is not TOML.
    pub fn voxel_configured(&self) -> Result<bool> {
        if self.voxel.is_some() {
            return Ok(true);
        }
        let Some(path) = &self.config else {
            return Ok(false);
        };
        let table: toml::Table = parse_config(path)?;
        Ok(table.contains_key("voxel_size_m"))
    }

    /// The configuration, checked ([`PairConfig::resolved`]): defaults, then the configuration
    /// file, then the set fields.
    ///
    /// # Errors
    /// A configuration file that cannot be read or parsed, or values out of range.
    pub fn config(&self) -> Result<PairConfig> {
        let c = self.unchecked_config()?;
        c.resolved()?;
        Ok(c)
    }

    /// As [`PairSettings::config`], without the range checks (for callers that report them in
    /// words of their own).
    ///
    /// # Errors
    /// A configuration file that cannot be read or parsed.
    pub fn unchecked_config(&self) -> Result<PairConfig> {
        let mut c = match &self.config {
            Some(path) => parse_config::<PairConfig>(path)?,
            None => PairConfig::default(),
        };
        if let Some(v) = self.voxel {
            c.voxel_size_m = v;
        }
        if self.mutual {
            c.mutual_filter = true;
        }
        self.apply_ranking(&mut c);
        self.apply_sampler(&mut c);
        if let Some(m) = self.max_hypotheses {
            c.max_hypotheses = m;
        }
        if let Some(v) = self.verification {
            c.verification = v;
        }
        if self.no_icp {
            c.icp = false;
        }
        if let Some(seed) = self.seed {
            c.seed = seed;
        }
        Ok(c)
    }

    /// [`PairSettings::ranking`] and [`PairSettings::descriptor_radius`] over `c`'s ranking.
    fn apply_ranking(&self, c: &mut PairConfig) {
        if let Some(r) = self.ranking {
            let radius = self.descriptor_radius.unwrap_or(match c.ranking {
                RankingConfig::NeighbourCount { radius, .. } => radius,
                _ => PAPER_DESCRIPTOR_RADIUS as f32,
            });
            c.ranking = match r {
                RankingChoice::Ratio => RankingConfig::Ratio,
                RankingChoice::Distance => RankingConfig::Distance,
                RankingChoice::CountMost => RankingConfig::NeighbourCount {
                    radius,
                    order: CountOrder::MostFirst,
                },
                RankingChoice::CountFewest => RankingConfig::NeighbourCount {
                    radius,
                    order: CountOrder::FewestFirst,
                },
            };
        } else if let (Some(d), RankingConfig::NeighbourCount { radius, .. }) =
            (self.descriptor_radius, &mut c.ranking)
        {
            *radius = d;
        }
    }

    /// [`PairSettings::sampler`] and the Lévy law's fields over `c`'s sampler.
    fn apply_sampler(&self, c: &mut PairConfig) {
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
            Some(SamplerChoice::Uniform) => SamplerConfig::Uniform,
            Some(SamplerChoice::Prosac) => SamplerConfig::Prosac {
                growth_max_samples: crate::ransac::prosac::DEFAULT_GROWTH_MAX_SAMPLES,
            },
            Some(SamplerChoice::Levy) => levy,
            None if matches!(c.sampler, SamplerConfig::Levy { .. }) => levy,
            None => c.sampler,
        };
    }
}
