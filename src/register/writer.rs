//! The *writer* stage of `mireg register`, on the calling thread: each registered frame's pose,
//! transform and statistics into the output, then the run's metadata and its summary.

use std::collections::BTreeMap;
use std::sync::mpsc::Receiver;
use std::time::Instant;

use nalgebra::Isometry3;

use crate::Result;
use crate::io::mcap::log::{ChannelInfo, OutputLog};
use crate::loops::LoopConfig;
use crate::odometry::InitialGuess;
use crate::trajectory::{FrameErrors, Trajectory, evaluate};

use super::closure::LoopOutcome;
use super::clouds::CloudKind;
use super::frames::Estimate;
use super::frames::FrameOut;
use super::options::{OnFrame, RegisterOptions};
use super::output::{
    Outputs, StampedPose, Topics, write_frame, write_loop, write_optimized_pose, write_pose,
};
use super::plan::Plan;
use super::summary::{
    DOMINANT_MIN_STEPS, DOMINANT_SHARE, DominantStep, FLAGGED_FRAMES_LISTED, Flag, FlaggedFrame,
    ReferenceErrors, RegisterSummary, StepError,
};
use super::window::LogWindow;

/// Writes the frames as they come and keeps what the summary needs.
pub(super) struct Writer<'a> {
    outputs: Outputs,
    world_frame: &'a str,
    progress: Option<indicatif::ProgressBar>,
    /// [`RegisterOptions::on_frame`], and the clouds the log holds (0: unknown).
    pub(super) on_frame: Option<OnFrame>,
    total_frames: u64,
    pub(super) estimates: Vec<Estimate>,
    /// The reference poses read (stamp \[ns\], pose).
    reference: Vec<(i64, Isometry3<f64>)>,
    /// The first [`FLAGGED_FRAMES_LISTED`] failed or suspect frames.
    flagged: Vec<FlaggedFrame>,
    /// Registered frames flagged suspect.
    suspect_frames: usize,
    /// Frames accepted by tracking ([`crate::odometry::InitialGuess::Tracked`]).
    tracked_frames: usize,
}

impl<'a> Writer<'a> {
    /// A writer of `outputs`' channels; draws a progress bar of `total_frames` when `progress`
    /// and stderr is a terminal.
    pub(super) fn new(
        outputs: Outputs,
        world_frame: &'a str,
        progress: bool,
        total_frames: u64,
    ) -> Self {
        let progress =
            (progress && std::io::IsTerminal::is_terminal(&std::io::stderr())).then(|| {
                let bar = indicatif::ProgressBar::new(total_frames);
                bar.set_style(
                    indicatif::ProgressStyle::with_template(
                        "{bar:40} {pos}/{len} frames  {per_sec}  ETA {eta}",
                    )
                    .expect("valid template"),
                );
                bar
            });
        Self {
            outputs,
            world_frame,
            progress,
            on_frame: None,
            total_frames,
            estimates: Vec::new(),
            reference: Vec::new(),
            flagged: Vec::new(),
            suspect_frames: 0,
            tracked_frames: 0,
        }
    }

    /// Writes one registered frame (or passes on the error that stopped the run).
    pub(super) fn frame(&mut self, log: &mut OutputLog, r: Result<FrameOut>) -> Result<()> {
        let out = r?;
        write_frame(log, &self.outputs, self.world_frame, &out)?;
        let e = &out.est;
        let flag = if !e.success {
            Some((Flag::Failed, e.failure.map_or("failed", |f| f.as_str())))
        } else {
            e.suspect.map(|s| (Flag::Suspect, s.as_str()))
        };
        if let Some((flag, reason)) = flag {
            self.suspect_frames += usize::from(flag == Flag::Suspect);
            if self.flagged.len() < FLAGGED_FRAMES_LISTED {
                self.flagged.push(FlaggedFrame {
                    frame: e.index,
                    stamp_ns: out.cloud.header.stamp.to_ns(),
                    flag,
                    reason,
                });
            }
        }
        let deskew_motion = out.cloud.deskew_motion();
        let tracked = out
            .est
            .map
            .is_some_and(|m| m.guess == InitialGuess::Tracked);
        self.tracked_frames += usize::from(tracked);
        self.estimates.push(Estimate {
            world_from_frame: out.est.world_from_frame,
            success: out.est.success,
            inliers: out.est.pair.as_ref().map(|p| p.num_inliers),
            header: out.cloud.header,
            log_time: out.cloud.log_time,
            publish_time: out.cloud.publish_time,
            deskew_motion,
            descriptor: out.cloud.descriptor,
            information: out.est.information,
            map_range_m: out.est.map_range_m,
        });
        if let Some(bar) = &self.progress {
            bar.inc(1);
        }
        if let Some(f) = &self.on_frame {
            (f.0)(self.estimates.len() as u64, self.total_frames);
        }
        Ok(())
    }

    /// Keeps a reference pose for the summary's errors.
    pub(super) fn reference_pose(&mut self, stamp_ns: i64, pose: Isometry3<f64>) {
        self.reference.push((stamp_ns, pose));
    }

    /// Writes the frames still to come on `registered` once the reader is done (`read`: its
    /// outcome). A worker's error is the root cause of any later failure to hand it work:
    /// reported first.
    pub(super) fn drain(
        &mut self,
        log: &mut OutputLog,
        registered: Receiver<Result<FrameOut>>,
        read: Result<u64>,
    ) -> Result<u64> {
        let mut result = read;
        let mut worker_error = None;
        for r in registered.iter() {
            match r {
                Err(e) => worker_error = worker_error.or(Some(e)),
                Ok(out) if result.is_ok() => {
                    if let Err(e) = self.frame(log, Ok(out)) {
                        result = Err(e);
                    }
                }
                Ok(_) => {}
            }
        }
        match worker_error {
            Some(e) => Err(e),
            None => result,
        }
    }

    /// Writes the run's metadata, closes the output and sums the run up.
    pub(super) fn finish(
        mut self,
        mut log: OutputLog,
        plan: Plan,
        opts: &RegisterOptions,
        copied: u64,
        start: Instant,
        loops: Option<(LoopOutcome, LoopConfig)>,
    ) -> Result<RegisterSummary> {
        if let Some(bar) = &self.progress {
            bar.finish_and_clear();
        }
        let mut meta = metadata(&plan, opts);
        if let Some((outcome, config)) = &loops {
            write_loop_outcome(
                &mut log,
                &self.outputs,
                self.world_frame,
                &self.estimates,
                outcome,
            )?;
            loop_metadata(&mut meta, &plan.topics, outcome, config);
        }
        log.write_metadata("mireg", meta)?;
        log.finish()?;

        let estimates = &self.estimates;
        let frames = estimates.len();
        let failed_frames = estimates.iter().filter(|e| !e.success).count();
        // Over the frames registered globally: a tracked frame has no RANSAC inliers.
        let registered: Vec<usize> = estimates
            .iter()
            .skip(1)
            .filter(|e| e.success)
            .filter_map(|e| e.inliers)
            .collect();
        let mean_inliers = if registered.is_empty() {
            0.0
        } else {
            registered.iter().sum::<usize>() as f64 / registered.len() as f64
        };
        let reference_poses = std::mem::take(&mut self.reference);
        let odometry: Vec<(i64, Isometry3<f64>)> = estimates
            .iter()
            .map(|e| (e.stamp_ns(), e.world_from_frame))
            .collect();
        let reference = plan
            .reference
            .as_ref()
            .and_then(|(t, _)| reference_errors(t, &odometry, reference_poses.clone()));
        let reference_optimized = match (&plan.reference, &loops) {
            (Some((t, _)), Some((outcome, _))) => {
                let optimized: Vec<(i64, Isometry3<f64>)> = estimates
                    .iter()
                    .zip(&outcome.optimized)
                    .map(|(e, p)| (e.stamp_ns(), *p))
                    .collect();
                reference_errors(t, &optimized, reference_poses)
            }
            _ => None,
        };
        let elapsed_s = start.elapsed().as_secs_f64();
        Ok(RegisterSummary {
            output: opts.output.clone(),
            topic: plan.topic,
            tf_topic: plan.topics.tf,
            pose_topic: plan.topics.pose,
            frames,
            failed_frames,
            suspect_frames: self.suspect_frames,
            tracked_frames: self.tracked_frames,
            flagged: std::mem::take(&mut self.flagged),
            mean_inliers,
            messages_copied: copied,
            voxel_m: plan.voxel_m,
            voxel_source: plan.voxel_source,
            feature_voxel_m: plan.config.pair.voxel_size_m,
            feature_points: plan.config.feature_points,
            elapsed_s,
            frames_per_s: frames as f64 / elapsed_s.max(1e-9),
            reference,
            pose_optimized_topic: loops.is_some().then(|| plan.topics.pose_optimized.clone()),
            loops: loops.map(|(outcome, _)| outcome.summary),
            reference_optimized,
            input_damage: plan.input_log.damage().cloned(),
        })
    }
}

/// This run's channels in an output log, for a job that writes poses it did not register itself
/// (`mireg stitch`) as `register` writes them: each frame's `/tf`, pose and statistics
/// ([`Self::write_pose`]), loop closure's outcome ([`Self::write_loop_outcome`]) and metadata
/// keys ([`Self::loop_metadata`]). No pose-with-covariance channel: such a job has no per-frame
/// information.
pub(super) struct PoseWriter {
    /// The topics of this run (the next free `/mireg_N/…` namespace of the input).
    pub(super) topics: Topics,
    outputs: Outputs,
    /// The frame the poses are in.
    world_frame: String,
}

impl PoseWriter {
    /// Adds this run's channels to `log`, whose input has `channels`: poses in `kind`'s message
    /// family, in `world_frame`; loop closure's channels too when `loops`.
    pub(super) fn create(
        log: &mut OutputLog,
        channels: &[ChannelInfo],
        kind: CloudKind,
        loops: bool,
        world_frame: &str,
    ) -> Result<Self> {
        let topics = Topics::for_input(channels);
        let outputs = Outputs::create(log, kind, &topics, loops, None)?;
        Ok(Self {
            topics,
            outputs,
            world_frame: world_frame.to_string(),
        })
    }

    /// Writes one frame's `/tf`, pose and statistics (`stats`, JSON) messages.
    pub(super) fn write_pose(
        &self,
        log: &mut OutputLog,
        pose: &StampedPose<'_>,
        stats: &[u8],
    ) -> Result<()> {
        write_pose(log, &self.outputs, &self.world_frame, pose, stats)
    }

    /// Writes loop closure's outcome for `estimates` ([`write_loop_outcome`]).
    pub(super) fn write_loop_outcome(
        &self,
        log: &mut OutputLog,
        estimates: &[Estimate],
        outcome: &LoopOutcome,
    ) -> Result<()> {
        write_loop_outcome(log, &self.outputs, &self.world_frame, estimates, outcome)
    }

    /// Adds loop closure's keys to a `mireg` metadata record ([`loop_metadata`]).
    pub(super) fn loop_metadata(
        &self,
        meta: &mut BTreeMap<String, String>,
        outcome: &LoopOutcome,
        config: &LoopConfig,
    ) {
        loop_metadata(meta, &self.topics, outcome, config);
    }
}

/// Writes loop closure's outcome for `estimates` (one per frame) on `outputs`' loop channels (none
/// without them): each candidate tried at its query frame's log time, then every frame's
/// optimised pose and transform at the frame's own log time.
fn write_loop_outcome(
    log: &mut OutputLog,
    outputs: &Outputs,
    world_frame: &str,
    estimates: &[Estimate],
    outcome: &LoopOutcome,
) -> Result<()> {
    let Some(channels) = &outputs.loops else {
        return Ok(());
    };
    for r in &outcome.records {
        let e = &estimates[r.query_frame];
        let json = serde_json::to_vec(r).expect("JSON of plain values");
        write_loop(log, channels, e.log_time, e.publish_time, &json)?;
    }
    for (e, pose) in estimates.iter().zip(&outcome.optimized) {
        let p = StampedPose {
            stamp: e.header.stamp,
            child_frame: &e.header.frame_id,
            world_from_frame: *pose,
            log_time: e.log_time,
            publish_time: e.publish_time,
        };
        write_optimized_pose(log, outputs, channels, world_frame, &p)?;
    }
    Ok(())
}

/// The loop-closure keys of a run's `mireg` metadata: the topics, the settings, the counts.
fn loop_metadata(
    meta: &mut BTreeMap<String, String>,
    topics: &Topics,
    outcome: &LoopOutcome,
    config: &LoopConfig,
) {
    meta.insert(
        "pose_optimized_topic".to_string(),
        topics.pose_optimized.clone(),
    );
    meta.insert(
        "tf_optimized_topic".to_string(),
        topics.tf_optimized.clone(),
    );
    meta.insert("loops_topic".to_string(), topics.loops.clone());
    meta.insert(
        "loop_config".to_string(),
        serde_json::to_string(config).expect("loop config JSON"),
    );
    meta.insert(
        "loops".to_string(),
        serde_json::to_string(&outcome.summary).expect("loop summary JSON"),
    );
}

/// The output's `mireg` metadata record: version, settings, input and topics.
fn metadata(plan: &Plan, opts: &RegisterOptions) -> BTreeMap<String, String> {
    let config = &plan.config;
    let mut meta = BTreeMap::new();
    meta.insert("version".to_string(), env!("CARGO_PKG_VERSION").to_string());
    meta.insert(
        "config".to_string(),
        serde_json::to_string(config).expect("config JSON"),
    );
    meta.insert("voxel_source".to_string(), plan.voxel_source.to_string());
    meta.insert("voxel_m".to_string(), plan.voxel_m.to_string());
    meta.insert(
        "feature_voxel_m".to_string(),
        config.pair.voxel_size_m.to_string(),
    );
    meta.insert("seed".to_string(), config.pair.seed.to_string());
    meta.insert("command_line".to_string(), opts.command_line.clone());
    meta.insert("input".to_string(), opts.input.display().to_string());
    // What `stitch` checks a segment's log by; a log it cannot read again has none.
    if let Ok(f) = crate::io::fingerprint::content_fingerprint(&opts.input) {
        meta.insert("input_fingerprint".to_string(), f);
    }
    meta.insert("topic".to_string(), plan.topic.clone());
    meta.insert("pose_topic".to_string(), plan.topics.pose.clone());
    meta.insert("stats_topic".to_string(), plan.topics.stats.clone());
    meta.insert("tf_topic".to_string(), plan.topics.tf.clone());
    if let Some(d) = plan.input_log.damage() {
        meta.insert(
            "input_damage".to_string(),
            serde_json::to_string(d).expect("damage JSON"),
        );
    }
    if plan.segment != LogWindow::ALL {
        meta.insert(
            "segment".to_string(),
            serde_json::to_string(&plan.segment).expect("segment JSON"),
        );
    }
    meta
}

/// The run's trajectory against the reference poses at the same stamps
/// ([`crate::trajectory::evaluate`] with exact stamp association); `None` with fewer than 2 pairs.
fn reference_errors(
    topic: &str,
    estimate: &[(i64, Isometry3<f64>)],
    reference: Vec<(i64, Isometry3<f64>)>,
) -> Option<ReferenceErrors> {
    let estimate = Trajectory::stamped(
        estimate.iter().map(|e| e.0).collect(),
        estimate.iter().map(|e| e.1).collect(),
    );
    let (stamps, poses) = reference.into_iter().unzip();
    let e = evaluate(&estimate, &Trajectory::stamped(stamps, poses), None, 0).ok()?;
    Some(ReferenceErrors {
        topic: topic.to_string(),
        frames: e.rows.len(),
        ate_rmse_m: e.ate_rmse_m,
        rpe_trans_mean_m: e.rpe_trans_mean_m,
        rpe_rot_mean_deg: e.rpe_rot_mean_deg,
        dominant_step: dominant_step(&e.rows),
    })
}

/// The step that carries more than [`DOMINANT_SHARE`] of the summed RPE translation, or else of
/// the summed rotation, over at least [`DOMINANT_MIN_STEPS`] steps; `None` when none does (or
/// every step is exact).
fn dominant_step(rows: &[FrameErrors]) -> Option<DominantStep> {
    let part = |error: StepError| {
        let steps: Vec<(&FrameErrors, f64)> = rows
            .iter()
            .filter_map(|r| {
                match error {
                    StepError::Translation => r.rpe_trans_m,
                    StepError::Rotation => r.rpe_rot_deg,
                }
                .filter(|v| v.is_finite())
                .map(|v| (r, v))
            })
            .collect();
        let total: f64 = steps.iter().map(|s| s.1).sum();
        let (row, value) = steps.iter().copied().max_by(|a, b| a.1.total_cmp(&b.1))?;
        let share = value / total;
        (steps.len() >= DOMINANT_MIN_STEPS && total > 0.0 && share > DOMINANT_SHARE).then_some(
            DominantStep {
                frame: row.frame,
                stamp_ns: row.stamp_ns,
                error,
                value,
                total,
                share,
                steps: steps.len(),
            },
        )
    };
    part(StepError::Translation).or_else(|| part(StepError::Rotation))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(frame: u64, trans: Option<f64>, rot: Option<f64>) -> FrameErrors {
        FrameErrors {
            frame,
            stamp_ns: Some(frame as i64 * 100),
            success: None,
            failure_reason: None,
            rpe_trans_m: trans,
            rpe_rot_deg: rot,
            ate_err_m: 0.0,
        }
    }

    #[test]
    fn a_step_dominates_when_it_carries_most_of_the_error() {
        let even: Vec<FrameErrors> = (0..5)
            .map(|k| row(k, (k > 0).then_some(0.01), (k > 0).then_some(0.1)))
            .collect();
        assert_eq!(dominant_step(&even), None);
        let mut broken = even.clone();
        broken[3].rpe_trans_m = Some(0.5);
        let d = dominant_step(&broken).unwrap();
        assert_eq!(
            (d.frame, d.stamp_ns, d.error, d.steps),
            (3, Some(300), StepError::Translation, 4)
        );
        assert!((d.share - 0.5 / 0.53).abs() < 1e-12 && (d.total - 0.53).abs() < 1e-12);
        // Rotation alone.
        let mut turned = even.clone();
        turned[2].rpe_rot_deg = Some(3.0);
        let d = dominant_step(&turned).unwrap();
        assert_eq!((d.frame, d.error), (2, StepError::Rotation));
        // Two steps are too few to say one dominates; exact steps have no error to carry.
        assert_eq!(dominant_step(&broken[2..4]), None);
        let exact: Vec<FrameErrors> = (0..5).map(|k| row(k, Some(0.0), Some(0.0))).collect();
        assert_eq!(dominant_step(&exact), None);
    }
}
