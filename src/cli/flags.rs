//! Registration flags shared by `pair` and `register`, and the value enums of the command line:
//! clap arguments → [`PairSettings`] → [`PairConfig`], each clap enum mapped onto the library's
//! own.

use anyhow::{Context, Result};
use clap::Args;

use std::path::PathBuf;

use clap::ValueEnum;

use crate::io::codec::livox::LivoxTags;
use crate::pipeline::{PairConfig, Verification};
use crate::register::{DeskewMode, OutputMessages};
use crate::settings::{PairSettings, RankingChoice, SamplerChoice};

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
    #[arg(long, value_name = "METRES")]
    pub voxel: Option<f64>,
    /// Hypothesis sampler [default: levy].
    #[arg(long, value_enum)]
    pub sampler: Option<SamplerArg>,
    /// Lévy location μ (< 0) [default: -50].
    #[arg(long, allow_hyphen_values = true)]
    pub mu: Option<f64>,
    /// Lévy scale c [default: 1].
    #[arg(long, value_name = "C")]
    pub levy_c: Option<f64>,
    /// Lévy draws with replacement (the authors' behaviour).
    #[arg(long)]
    pub with_replacement: bool,
    /// Correspondence ranking [default: ratio].
    #[arg(long, value_enum)]
    pub ranking: Option<RankingArg>,
    /// Descriptor radius τ_d for the count rankings, in FPFH units [default: 12].
    #[arg(long, value_name = "RADIUS")]
    pub descriptor_radius: Option<f32>,
    /// Keep only mutual nearest neighbours in feature space.
    #[arg(long)]
    pub mutual: bool,
    /// Cap on RANSAC hypotheses [default: 200000; Open3D's is 100000].
    #[arg(long, value_name = "N")]
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

impl From<SamplerArg> for SamplerChoice {
    fn from(a: SamplerArg) -> Self {
        match a {
            SamplerArg::Levy => SamplerChoice::Levy,
            SamplerArg::Uniform => SamplerChoice::Uniform,
            SamplerArg::Prosac => SamplerChoice::Prosac,
        }
    }
}

impl From<RankingArg> for RankingChoice {
    fn from(a: RankingArg) -> Self {
        match a {
            RankingArg::Ratio => RankingChoice::Ratio,
            RankingArg::Distance => RankingChoice::Distance,
            RankingArg::CountMost => RankingChoice::CountMost,
            RankingArg::CountFewest => RankingChoice::CountFewest,
        }
    }
}

impl From<VerificationArg> for Verification {
    fn from(a: VerificationArg) -> Self {
        match a {
            VerificationArg::Dense => Verification::Dense,
            VerificationArg::Correspondences => Verification::Correspondences,
        }
    }
}

/// `--deskew` ([`DeskewMode`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum)]
pub enum DeskewArg {
    /// Deskew every cloud that has a time field.
    #[default]
    Auto,
    /// As `auto`, and a cloud without a time field is an error.
    On,
    /// Never deskew.
    Off,
}

impl From<DeskewArg> for DeskewMode {
    fn from(a: DeskewArg) -> Self {
        match a {
            DeskewArg::Auto => DeskewMode::Auto,
            DeskewArg::On => DeskewMode::On,
            DeskewArg::Off => DeskewMode::Off,
        }
    }
}

/// `--output-messages` ([`OutputMessages`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum)]
pub enum OutputMessagesArg {
    /// The clouds' family: ROS 2 for ROS 2 clouds, ROS 1 for ROS 1 clouds, foxglove for
    /// foxglove clouds.
    #[default]
    Auto,
    /// `tf2_msgs/msg/TFMessage` and `geometry_msgs/msg/PoseStamped` in cdr.
    Ros2,
    /// `tf2_msgs/TFMessage` and `geometry_msgs/PoseStamped` in ros1.
    Ros1,
    /// `foxglove.FrameTransforms` and `foxglove.PoseInFrame` in protobuf.
    Foxglove,
}

impl From<OutputMessagesArg> for OutputMessages {
    fn from(a: OutputMessagesArg) -> Self {
        match a {
            OutputMessagesArg::Auto => OutputMessages::Auto,
            OutputMessagesArg::Ros2 => OutputMessages::Ros2,
            OutputMessagesArg::Ros1 => OutputMessages::Ros1,
            OutputMessagesArg::Foxglove => OutputMessages::Foxglove,
        }
    }
}

/// `--livox-tags` ([`LivoxTags`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum)]
pub enum LivoxTagsArg {
    /// Drop the points tagged as noise with high or moderate confidence by their spatial position
    /// (bits 0–1 = 01 or 10) or as noise by their intensity (bits 2–3 = 01): rain, dust, fog
    /// and the stray returns at object edges. Low-confidence noise (11) is kept.
    #[default]
    DropNoise,
    /// Keep every point whatever its tag.
    KeepAll,
    /// Keep returns 0 and 1 only (bits 4–5 = 00 or 01), whatever the noise bits, as FAST-LIO's
    /// Livox front end does.
    FirstReturns,
}

impl From<LivoxTagsArg> for LivoxTags {
    fn from(a: LivoxTagsArg) -> Self {
        match a {
            LivoxTagsArg::DropNoise => LivoxTags::DropNoise,
            LivoxTagsArg::KeepAll => LivoxTags::KeepAll,
            LivoxTagsArg::FirstReturns => LivoxTags::FirstReturns,
        }
    }
}

impl RegistrationFlags {
    /// The flags as library settings.
    pub fn settings(&self) -> PairSettings {
        PairSettings {
            config: self.config.clone(),
            voxel: self.voxel,
            sampler: self.sampler.map(Into::into),
            mu: self.mu,
            levy_c: self.levy_c,
            with_replacement: self.with_replacement,
            ranking: self.ranking.map(Into::into),
            descriptor_radius: self.descriptor_radius,
            mutual: self.mutual,
            max_hypotheses: self.max_hypotheses,
            verification: self.verification.map(Into::into),
            no_icp: self.no_icp,
            seed: self.seed,
        }
    }

    /// Whether the voxel was given, by `--voxel` or as `voxel_size_m` in the `--config` file.
    pub fn voxel_configured(&self) -> Result<bool> {
        Ok(self.settings().voxel_configured()?)
    }

    /// The configuration: defaults, then `--config`, then explicit flags.
    pub fn config(&self) -> Result<PairConfig> {
        let c = self.settings().unchecked_config()?;
        c.resolved().context("invalid configuration")?;
        Ok(c)
    }
}
