//! A `register` run's settings by the names of `mireg register`'s flags (`voxel`, `no_loops`,
//! `loop_memory`, …): flat, each with its default, and serde, so that the command line and the
//! Python package's `register_log(path, **settings)` fill the same struct and
//! [`RegisterSettings::options`] turns it into the [`RegisterOptions`] the job runs with.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::io::codec::livox::LivoxTags;
use crate::io::damage::ReadPolicy;
use crate::odometry::OdometryConfig;
use crate::settings::PairSettings;
use crate::{Error, Result};

use super::options::{
    DEFAULT_MAX_POINTS_PER_CLOUD, DeskewMode, OutputMessages, REORDER_WINDOW, RegisterOptions,
    default_output,
};
use super::window::WindowBound;

/// The settings of a `register` run, as `mireg register`'s flags name them (`--no-loops` is
/// `no_loops`). [`Default`] is the command's defaults; unknown keys are refused by
/// [`RegisterSettings::from_json`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RegisterSettings {
    /// Pairwise registration settings (`voxel`, `sampler`, `seed`, …; flattened).
    #[serde(flatten)]
    pub pair: PairSettings,
    /// Point cloud topic; `None` (default): the only point cloud topic.
    pub topic: Option<String>,
    /// A registration with fewer RANSAC inliers is flagged as failed. Default
    /// [`OdometryConfig::min_inliers`]'s.
    pub min_inliers: usize,
    /// A registration with lower ICP fitness (a fraction in \[0, 1\]) is flagged as failed.
    /// Default [`OdometryConfig::min_fitness`]'s.
    pub min_fitness: f64,
    /// Register each frame to the previous one only, without the local map. Default `false`.
    pub no_local_map: bool,
    /// Skip the map ICP's last stage on each frame's own points. Default `false`.
    pub no_map_fine: bool,
    /// The map ICP's last stage on each frame's own points: the default, kept for old callers;
    /// no effect. Default `false`.
    pub map_fine: bool,
    /// Register every frame globally (features, matching, MI-RANSAC) instead of refining it on
    /// the local map from the constant-velocity prediction first and registering globally only
    /// where that fit is doubtful ([`OdometryConfig::track_first`]). Default `false`.
    pub global_every_frame: bool,
    /// Tracking first: the default, kept for old callers; no effect. Default `false`.
    pub track_first: bool,
    /// Motion compensation of clouds with per-point times. Default [`DeskewMode::Auto`].
    pub deskew: DeskewMode,
    /// Message family of our `/tf` and pose channels. Default [`OutputMessages::Auto`].
    pub output_messages: OutputMessages,
    /// First cloud of the segment: a cloud index (`120`) or a log time (`"1700000012.5s"`,
    /// `"…ns"`). Default `None`: the log's first.
    #[serde(deserialize_with = "bound")]
    pub start: Option<WindowBound>,
    /// First cloud after the segment (exclusive), as `start`. Default `None`: to the end.
    #[serde(deserialize_with = "bound")]
    pub end: Option<WindowBound>,
    /// Copy only the input messages whose log time lies in the segment. Default `false`.
    pub copy_window: bool,
    /// Points kept per voxel of the local map. Default
    /// [`OdometryConfig::map_max_points_per_voxel`]'s.
    pub map_points_per_voxel: usize,
    /// Most points of the cloud global registration runs on (0: the voxel cloud). Default
    /// [`OdometryConfig::feature_points`]'s.
    pub feature_points: usize,
    /// Name of the world frame in `/tf` and `/mireg/pose`. Default `"world"`.
    pub world_frame: String,
    /// A cloud with more points is flagged instead of registered. Default
    /// [`DEFAULT_MAX_POINTS_PER_CLOUD`].
    pub max_points: usize,
    /// Clouds held at most to restore log-time order. Default [`REORDER_WINDOW`].
    pub reorder_window: usize,
    /// Skip loop closure. Default `false`.
    pub no_loops: bool,
    /// Memory for loop verification's prepared frames \[MiB\]. Default
    /// [`crate::loops::closure::DEFAULT_LOOP_MEMORY_BYTES`] in MiB.
    pub loop_memory: usize,
    /// Refuse a log that was cut off. Default `false`.
    pub strict: bool,
    /// Skip corrupt chunks instead of failing. Default `false`.
    pub skip_corrupt: bool,
    /// Which Livox `CustomMsg` points are kept. Default [`LivoxTags::DropNoise`].
    pub livox_tags: LivoxTags,
    /// Replace an existing output. Default `false`.
    pub force: bool,
    /// No progress bar. Default `false`.
    pub quiet: bool,
}

impl Default for RegisterSettings {
    fn default() -> Self {
        let odometry = OdometryConfig::default();
        Self {
            pair: PairSettings::default(),
            topic: None,
            min_inliers: odometry.min_inliers,
            min_fitness: odometry.min_fitness,
            no_local_map: false,
            no_map_fine: false,
            map_fine: false,
            global_every_frame: false,
            track_first: false,
            deskew: DeskewMode::Auto,
            output_messages: OutputMessages::Auto,
            start: None,
            end: None,
            copy_window: false,
            map_points_per_voxel: odometry.map_max_points_per_voxel,
            feature_points: odometry.feature_points,
            world_frame: "world".into(),
            max_points: DEFAULT_MAX_POINTS_PER_CLOUD,
            reorder_window: REORDER_WINDOW,
            no_loops: false,
            loop_memory: crate::loops::closure::DEFAULT_LOOP_MEMORY_BYTES >> 20,
            strict: false,
            skip_corrupt: false,
            livox_tags: LivoxTags::DropNoise,
            force: false,
            quiet: false,
        }
    }
}

/// A segment bound given as a cloud index (a number) or as [`WindowBound`]'s text.
fn bound<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<WindowBound>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Given {
        Index(u64),
        Text(String),
    }
    match Option::<Given>::deserialize(d)? {
        None => Ok(None),
        Some(Given::Index(i)) => Ok(Some(WindowBound::Frame(i))),
        Some(Given::Text(s)) => s.parse().map(Some).map_err(serde::de::Error::custom),
    }
}

impl RegisterSettings {
    /// The keys a settings object may have: the fields' names (the pair settings' included).
    pub fn keys() -> Vec<String> {
        match serde_json::to_value(Self::default()) {
            Ok(serde_json::Value::Object(map)) => map.keys().cloned().collect(),
            _ => Vec::new(),
        }
    }

    /// Settings from a JSON object of some of the fields (the others at their defaults).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] naming an unknown key (and the known ones), or a value of the
    /// wrong type.
    pub fn from_json(json: &str) -> Result<Self> {
        let value: serde_json::Value = serde_json::from_str(json)
            .map_err(|e| Error::InvalidInput(format!("settings: {e}")))?;
        let Some(map) = value.as_object() else {
            return Err(Error::InvalidInput("settings: not a JSON object".into()));
        };
        let keys = Self::keys();
        if let Some(unknown) = map.keys().find(|k| !keys.contains(k)) {
            return Err(Error::InvalidInput(format!(
                "unknown setting {unknown:?} (known: {})",
                keys.join(", ")
            )));
        }
        serde_json::from_value(value).map_err(|e| Error::InvalidInput(format!("settings: {e}")))
    }

    /// The options of a run registering `input` into `output` (default
    /// [`default_output`]), with these settings; no command line recorded, a progress bar unless
    /// `quiet`.
    ///
    /// # Errors
    /// A configuration file that cannot be read or parsed, or `copy_window` without a segment.
    pub fn options(&self, input: &Path, output: Option<&Path>) -> Result<RegisterOptions> {
        let config = OdometryConfig {
            pair: self.pair.config()?,
            min_inliers: self.min_inliers,
            min_fitness: self.min_fitness,
            local_map: !self.no_local_map,
            map_fine: !self.no_map_fine,
            map_max_points_per_voxel: self.map_points_per_voxel,
            feature_points: self.feature_points,
            track_first: !self.global_every_frame,
        };
        let opts = RegisterOptions {
            input: input.to_path_buf(),
            output: output.map_or_else(|| default_output(input), Path::to_path_buf),
            topic: self.topic.clone(),
            config,
            force: self.force,
            world_frame: self.world_frame.clone(),
            command_line: String::new(),
            progress: !self.quiet,
            max_points_per_cloud: self.max_points,
            reorder_window: self.reorder_window,
            derive_voxel: !self.pair.voxel_configured()?,
            deskew: self.deskew,
            output_messages: self.output_messages,
            start: self.start,
            end: self.end,
            copy_window_only: self.copy_window,
            loops: !self.no_loops,
            loop_config: None,
            loop_memory_bytes: Some(self.loop_memory.saturating_mul(1 << 20)),
            read_policy: ReadPolicy {
                strict: self.strict,
                skip_corrupt: self.skip_corrupt,
            },
            livox_tags: self.livox_tags,
            on_frame: None,
        };
        if opts.copy_window_only && opts.start.is_none() && opts.end.is_none() {
            return Err(Error::InvalidInput(
                "--copy-window needs a segment: --start and/or --end".into(),
            ));
        }
        Ok(opts)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_settings_by_flag_name() {
        let s = RegisterSettings::from_json(
            r#"{"voxel": 0.5, "no_loops": true, "start": 3, "end": "12.5s",
                "livox_tags": "keep-all", "sampler": "uniform", "ranking": "count-most"}"#,
        )
        .unwrap();
        assert_eq!(s.pair.voxel, Some(0.5));
        assert!(s.no_loops);
        assert_eq!(s.start, Some(WindowBound::Frame(3)));
        assert_eq!(s.end, Some(WindowBound::LogTimeNs(12_500_000_000)));
        assert_eq!(s.livox_tags, LivoxTags::KeepAll);
        assert_eq!(
            RegisterSettings::from_json("{}").unwrap(),
            Default::default()
        );
        let e = RegisterSettings::from_json(r#"{"no_such_flag": 1}"#).unwrap_err();
        assert!(
            e.to_string().contains("unknown setting \"no_such_flag\""),
            "{e}"
        );
        assert!(RegisterSettings::from_json(r#"{"voxel": "big"}"#).is_err());
    }
}
