//! The first stage of `mireg register`: open the input, choose the cloud topic, size the voxels
//! and settle everything the later stages share, before any output exists.

use std::collections::BTreeSet;

use crate::Result;
use crate::io::codec::{PoseStampedDecoder, pose_stamped_decoder};
use crate::io::input_log::InputLog;
use crate::io::log_order::ChunkTimes;
use crate::io::mcap::log::InputCatalog;
use crate::odometry::OdometryConfig;
use crate::odometry::stream::resolve_config;
use crate::pipeline::voxel_for_cloud;

use super::clouds::{CloudKind, choose_topic};
use super::options::{DEFAULT_REFERENCE_TOPIC, RegisterOptions};
use super::output::Topics;
use super::window::LogWindow;

/// What a run reads and how it registers it, settled from the input and the options.
pub(super) struct Plan {
    pub(super) input_log: InputLog,
    pub(super) catalog: InputCatalog,
    /// The cloud topic and its message family.
    pub(super) topic: String,
    pub(super) kind: CloudKind,
    /// The registration settings with the voxels sized.
    pub(super) config: OdometryConfig,
    /// `"configured"` or `"first_cloud"` ([`super::summary::RegisterSummary::voxel_source`]).
    pub(super) voxel_source: &'static str,
    /// The ICP voxel \[m\] (before the feature voxel replaced it in `config.pair`).
    pub(super) voxel_m: f64,
    /// This run's output topics.
    pub(super) topics: Topics,
    /// The reference pose topic and its decoder, when the log has one.
    pub(super) reference: Option<(String, PoseStampedDecoder)>,
    /// The chunks' time ranges, for the reader's order ([`crate::io::log_order::Reorder`]).
    pub(super) chunk_times: Option<ChunkTimes>,
    /// Clouds on the topic, from the summary (0 when the log has none): the progress bar's length.
    pub(super) total_frames: u64,
    pub(super) cloud_channels: Vec<u16>,
    pub(super) reference_channels: Vec<u16>,
    /// The clouds registered (`--start`/`--end`).
    pub(super) segment: LogWindow,
}

impl Plan {
    pub(super) fn new(opts: &RegisterOptions) -> Result<Self> {
        let input = &opts.input;
        let (input_log, catalog) = InputLog::open_with(input, opts.read_policy)?;
        let channels = catalog.channel_infos();
        let (topic, kind) = choose_topic(input, &channels, opts.topic.as_deref()).map_err(|e| {
            // A log cut before its first cloud: say so, not only that no cloud is there.
            match (e, input_log.damage()) {
                (crate::Error::InvalidInput(m), Some(d)) => {
                    crate::Error::InvalidInput(format!("{m}; the log is damaged: {}", d.describe()))
                }
                (e, _) => e,
            }
        })?;
        let kind = kind.with_livox_tags(opts.livox_tags);
        let ids_of = |t: Option<&str>| -> Vec<u16> {
            channels
                .iter()
                .filter(|c| Some(c.topic.as_str()) == t)
                .map(|c| c.id)
                .collect()
        };
        let cloud_channels = ids_of(Some(&topic));
        // The first cloud sizes the voxel (unless configured) and the feature voxel (unless
        // --feature-points 0); without either, it is not read twice.
        let first = if opts.derive_voxel || opts.config.feature_points > 0 {
            first_usable_cloud(&input_log, &cloud_channels, kind)?
        } else {
            None
        };
        let resolved = resolve_config(
            &opts.config,
            first.as_ref().map(|(_, points)| points.as_slice()),
            opts.derive_voxel,
        )
        .map_err(|e| match &first {
            // What the first cloud could not be sized for (a voxel too small for its extent):
            // name the cloud.
            Some((log_time, _)) => crate::Error::InvalidInput(format!(
                "{}: first cloud on {topic} at log time {log_time} ns: sizing the voxels: {e}",
                input.display()
            )),
            None => e,
        })?;
        drop(first);
        let voxel_source = if resolved.voxel_derived {
            "first_cloud"
        } else {
            "configured"
        };
        let (config, voxel_m) = (resolved.config, resolved.voxel_m);
        // A log registered before keeps its mireg topics; this run's go to the next namespace
        // (`/mireg_2/…`), so that no topic mixes two runs.
        let topics = Topics::for_input(&channels);
        let reference = channels
            .iter()
            .filter(|c| c.topic == DEFAULT_REFERENCE_TOPIC)
            .find_map(|c| pose_stamped_decoder(&c.schema_name, &c.message_encoding))
            .map(|decode| (DEFAULT_REFERENCE_TOPIC.to_string(), decode));
        let chunk_times = input_log.chunk_times()?;
        let total_frames = channels
            .iter()
            .filter(|c| c.topic == topic)
            .filter_map(|c| c.message_count)
            .sum::<u64>();
        let reference_channels = ids_of(reference.as_ref().map(|r| r.0.as_str()));
        let segment = LogWindow::resolve(&input_log, &cloud_channels, opts.start, opts.end)?;
        Ok(Self {
            input_log,
            catalog,
            topic,
            kind,
            config,
            voxel_source,
            voxel_m,
            topics,
            reference,
            chunk_times,
            total_frames,
            cloud_channels,
            reference_channels,
            segment,
        })
    }

    /// The channels whose messages the reader hands on: clouds and reference poses.
    pub(super) fn wanted_channels(&self) -> BTreeSet<u16> {
        self.cloud_channels
            .iter()
            .chain(&self.reference_channels)
            .copied()
            .collect()
    }
}

/// The first cloud on the channels `ids` that decodes to at least 3 finite, non-zero points (one that
/// [`voxel_for_cloud`] can size), with its log time \[ns\]; `None` when none does.
fn first_usable_cloud(
    input: &InputLog,
    ids: &[u16],
    kind: CloudKind,
) -> Result<Option<(u64, Vec<nalgebra::Point3<f64>>)>> {
    use std::ops::ControlFlow::{Break, Continue};
    let mut first = None;
    input.for_each_message_until(|header, data| {
        if ids.contains(&header.channel_id)
            && let Ok(cloud) = kind.decode(data)
            && voxel_for_cloud(&cloud.points).is_some()
        {
            first = Some((header.log_time, cloud.points));
        }
        Ok(if first.is_some() {
            Break(())
        } else {
            Continue(())
        })
    })?;
    Ok(first)
}
