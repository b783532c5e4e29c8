//! The *prepare* stage of `mireg register`, on its own thread: decode each cloud message, deskew
//! it by an earlier frame's motion, and prepare it for registration (downsampling, normals,
//! features: [`prepare_frame_with`]). A cloud that cannot be used becomes an empty, flagged frame.

use std::path::Path;
use std::sync::mpsc::{Receiver, Sender, SyncSender};
use std::time::Instant;

use nalgebra::{Isometry3, Point3};

use crate::io::codec;
use crate::io::codec::MAX_COORDINATE_M;
use crate::io::point_time::POINT_TIME_BOUND_S;
use crate::odometry::stream::{self, Deskewed, deskew_cloud, deskew_for};
use crate::pipeline::{FailureReason, PrepareScratch, prepare_frame};
use crate::{Error, Result};

use super::frames::{CloudInfo, CloudMsg, Dropped, PreparedMsg};
use super::motions::Motions;
use super::options::DeskewMode;
use super::plan::Plan;

/// The prepare stage's settings.
pub(super) struct Prepare<'a> {
    pub(super) plan: &'a Plan,
    /// The input, named in errors.
    pub(super) input: &'a Path,
    /// [`super::options::RegisterOptions::max_points_per_cloud`].
    pub(super) max_points: usize,
    pub(super) deskew_mode: DeskewMode,
}

/// The clouds whose per-point times were unusable, or that had points beyond
/// [`MAX_COORDINATE_M`], for the run's warnings ([`Self::warn`]).
#[derive(Debug, Default)]
pub(super) struct TimeTally {
    /// The time field of the first such cloud.
    field: String,
    /// Points dropped as time glitches, the clouds they were in, the first one's log time \[ns\].
    dropped_points: usize,
    dropped_clouds: usize,
    first_dropped: Option<u64>,
    /// Clouds not deskewed although a motion was known, because a time was not finite or more
    /// than [`POINT_TIME_BOUND_S`] from the stamp, and the first one's log time \[ns\].
    undeskewed_clouds: usize,
    first_undeskewed: Option<u64>,
    /// Points dropped beyond [`MAX_COORDINATE_M`], the clouds they were in, the first one's log
    /// time \[ns\].
    far_points: usize,
    far_clouds: usize,
    first_far: Option<u64>,
}

impl TimeTally {
    fn field(&mut self, field: &str) {
        if self.field.is_empty() {
            self.field = field.to_string();
        }
    }

    /// Counts the points the decoder dropped from one cloud (`decoded`, logged at `log_time`):
    /// far ones, and time glitches with the cloud's time field.
    fn count_dropped(&mut self, dropped: &Dropped, decoded: &Decoded, log_time: u64) {
        if dropped.far > 0 {
            self.far_points += dropped.far;
            self.far_clouds += 1;
            self.first_far.get_or_insert(log_time);
        }
        if dropped.time > 0 {
            if let Ok(Ok(c)) = decoded
                && let Some(times) = &c.times
            {
                self.field(&times.field);
            }
            self.dropped_points += dropped.time;
            self.dropped_clouds += 1;
            self.first_dropped.get_or_insert(log_time);
        }
    }

    /// Warns on stderr of what was dropped or left skewed, naming `input` and `topic`; nothing
    /// when nothing was.
    pub(super) fn warn(&self, input: &Path, topic: &str) {
        let (input, field) = (input.display(), &self.field);
        if let Some(t) = self.first_dropped {
            eprintln!(
                "mireg: warning: {input}: {} points of {} clouds on {topic} dropped: their time \
                 (field {field}) is not finite or more than {POINT_TIME_BOUND_S} s from their \
                 cloud's median point time (the first such cloud at log time {t} ns)",
                self.dropped_points, self.dropped_clouds
            );
        }
        if let Some(t) = self.first_far {
            eprintln!(
                "mireg: warning: {input}: {} points of {} clouds on {topic} dropped: a coordinate \
                 is {MAX_COORDINATE_M} m or more from the sensor (a glitch, or a wrong \
                 is_bigendian or point_step; the first such cloud at log time {t} ns; counted \
                 per frame as num_dropped_far in /mireg/stats)",
                self.far_points, self.far_clouds
            );
        }
        if let Some(t) = self.first_undeskewed {
            eprintln!(
                "mireg: warning: {input}: {} clouds on {topic} not deskewed: their point times \
                 (field {field}) are not all finite and within {POINT_TIME_BOUND_S} s of the \
                 header stamp (a field without times, or on another clock than the stamp; the \
                 first such cloud at log time {t} ns)",
                self.undeskewed_clouds
            );
        }
    }
}

/// What the prepare stage carries from one cloud to the next.
#[derive(Default)]
struct Carry {
    scratch: PrepareScratch,
    /// The frame id of a cloud that cannot be decoded: the previous cloud's.
    last_frame_id: String,
    /// The previous cloud's points, once prepared: their buffer takes the next cloud's (a LiDAR
    /// frame's few megabytes are allocated and faulted in once, not per cloud).
    spare_points: Vec<Point3<f64>>,
    /// The clouds whose times were unusable so far.
    times: TimeTally,
}

impl Prepare<'_> {
    /// Prepares the clouds of `clouds` in order into `prepared`, until the clouds end, the
    /// receiver hangs up or a fatal error (sent on) stops the run. Each message buffer goes back
    /// on `recycle` once decoded; frame motions for deskewing come on `motions`. Returns the
    /// clouds whose per-point times were unusable, for the run's warnings.
    pub(super) fn run(
        &self,
        clouds: Receiver<CloudMsg>,
        prepared: SyncSender<Result<PreparedMsg>>,
        motions: Receiver<(usize, Isometry3<f64>, f64)>,
        recycle: Sender<Vec<u8>>,
    ) -> TimeTally {
        let mut carry = Carry::default();
        let mut motions = Motions::new(motions);
        for (frame_index, msg) in clouds.into_iter().enumerate() {
            let r = self.prepare(frame_index, msg, &mut carry, &mut motions, &recycle);
            let failed = r.is_err();
            if prepared.send(r).is_err() || failed {
                break;
            }
        }
        carry.times
    }

    /// Decodes, deskews and prepares one cloud. `Err` only for what stops the run (`--deskew
    /// on` without a time field); a bad cloud is a flagged frame.
    fn prepare(
        &self,
        frame_index: usize,
        msg: CloudMsg,
        carry: &mut Carry,
        motions: &mut Motions,
        recycle: &Sender<Vec<u8>>,
    ) -> Result<PreparedMsg> {
        let config = &self.plan.config;
        let t = Instant::now();
        let decoded = self.decode(&msg.data, &mut carry.spare_points);
        let dropped = dropped_of(&decoded);
        carry.times.count_dropped(&dropped, &decoded, msg.log_time);
        // The message bytes are not needed past decoding: don't hold them through prepare.
        let _ = recycle.send(msg.data);
        let decode_s = t.elapsed().as_secs_f64();
        let mut times = CloudTimes::default();
        let (header, prepared) = match self.usable(decoded, msg.log_time, &carry.last_frame_id) {
            Err((header, invalid)) => (header, Err(invalid)),
            Ok(mut cloud) => {
                times = self.deskew(
                    frame_index,
                    &mut cloud,
                    motions,
                    &mut carry.times,
                    msg.log_time,
                );
                let prepared = stream::prepare(&cloud.points, config, &mut carry.scratch)?;
                carry.spare_points = cloud.points;
                (cloud.header, Ok(prepared))
            }
        };
        if let Some(e) = times.fatal {
            return Err(e);
        }
        carry.last_frame_id.clone_from(&header.frame_id);
        match prepared {
            Ok(prepared) => Ok(prepared),
            Err(invalid) => prepare_frame(&[], &config.pair).map(|f| (f, Some(invalid))),
        }
        .map(|(frame, invalid)| PreparedMsg {
            cloud: CloudInfo {
                // The keyframes' descriptors are computed as the frames are registered
                // (`registrar.rs`): only they need the features.
                descriptor: None,
                invalid,
                time_field: times.field,
                deskewed: times.deskewed,
                dropped,
                log_time: msg.log_time,
                publish_time: msg.publish_time,
                header,
                decode_s,
            },
            frame,
        })
    }

    /// Decodes one cloud message into `spare_points`' buffer. A PointCloud2 declaring more
    /// points than --max-points is not decoded (`Err`: its header and declared count): a cloud
    /// of hostile size (a decompression bomb of zeros) is never held twice.
    fn decode(&self, data: &[u8], spare_points: &mut Vec<Point3<f64>>) -> Decoded {
        let kind = self.plan.kind;
        let declared = kind
            .declared_points(data)
            .filter(|&(_, n)| n > self.max_points as u64);
        match declared {
            Some((header, n)) => Err((header, n)),
            None => Ok(kind.decode_reusing(data, std::mem::take(spare_points))),
        }
    }

    /// The decoded cloud, if it can be registered; else the flagged frame's header and why not.
    /// A cloud that cannot be decoded, is too large, or that the pipeline cannot take (e.g. a
    /// glitch at 1e38 m) is one bad frame: flag it, keep going. A cloud that cannot be decoded
    /// is stamped with its log time and takes the previous cloud's `last_frame_id`.
    fn usable(
        &self,
        decoded: Decoded,
        log_time: u64,
        last_frame_id: &str,
    ) -> std::result::Result<codec::PointCloud, (codec::Header, Invalid)> {
        let (topic, max_points) = (self.plan.topic.as_str(), self.max_points);
        match decoded {
            Err((header, n)) => {
                let detail = format!(
                    "declares {n} points, more than the bound of {max_points} (--max-points)"
                );
                Err((header, (FailureReason::TooManyPoints, detail)))
            }
            Ok(Err(e)) => {
                let detail = decode_detail(topic, log_time, &e);
                let header = codec::Header {
                    stamp: stamp_of_log_time(log_time),
                    frame_id: last_frame_id.to_string(),
                };
                Err((header, (FailureReason::InvalidCloud, detail)))
            }
            Ok(Ok(cloud)) if cloud.points.len() > max_points => {
                let detail = format!(
                    "{} points, more than the bound of {max_points} (--max-points)",
                    cloud.points.len()
                );
                Err((cloud.header, (FailureReason::TooManyPoints, detail)))
            }
            Ok(Ok(cloud)) => Ok(cloud),
        }
    }

    /// Deskews `cloud` by the motion of the frame [`deskew_for`] names, when `--deskew` allows,
    /// the cloud has per-point times that vary, and that motion is known; a cloud whose times
    /// are out of bounds is left as it is and counted in `tally`.
    fn deskew(
        &self,
        frame_index: usize,
        cloud: &mut codec::PointCloud,
        motions: &mut Motions,
        tally: &mut TimeTally,
        log_time: u64,
    ) -> CloudTimes {
        let mut out = CloudTimes::default();
        if let Some(times) = &cloud.times {
            out.field = Some(times.field.clone());
            if self.deskew_mode != DeskewMode::Off
                && let Some((motion, dt)) = motions.of(deskew_for(frame_index))
            {
                // Times within the bound of the stamp and a finite motion: every point moves by
                // a finite fraction of a finite motion, and so does the pose referred back to
                // the stamp. One time for every point (a Livox `offset_time` of 0 throughout)
                // measures no sweep: nothing to deskew, and the statistics must not say
                // `deskewed`.
                if times.deskewable() {
                    if times.varies() {
                        out.deskewed =
                            Some(deskew_cloud(&mut cloud.points, &times.seconds, motion, dt));
                    }
                } else {
                    tally.field(&times.field);
                    tally.undeskewed_clouds += 1;
                    tally.first_undeskewed.get_or_insert(log_time);
                }
            }
        } else if self.deskew_mode == DeskewMode::On {
            let detail = format!(
                "--deskew on: no per-point time field (one of {})",
                crate::io::point_time::TIME_FIELDS.join(", ")
            );
            out.fatal = Some(Error::InvalidInput(format!(
                "{}: cloud on {} at log time {log_time} ns: {detail}",
                self.input.display(),
                self.plan.topic
            )));
        }
        out
    }
}

/// A cloud message decoded (or why not), or the header and declared point count of a
/// PointCloud2 over `--max-points`, never decoded ([`Prepare::decode`]).
type Decoded = std::result::Result<
    std::result::Result<codec::PointCloud, codec::DecodeError>,
    (codec::Header, u64),
>;

/// Why a frame is flagged invalid, and the detail.
type Invalid = (FailureReason, String);

/// What the per-point times of one cloud gave ([`Prepare::deskew`]).
#[derive(Default)]
struct CloudTimes {
    /// The cloud's time field.
    field: Option<String>,
    /// The motion it was deskewed by ([`CloudInfo::deskewed`]).
    deskewed: Deskewed,
    /// `--deskew on` and no time field: stops the run, once the cloud is prepared.
    fatal: Option<Error>,
}

/// The points the decoder dropped from `decoded` (none if it was not decoded).
fn dropped_of(decoded: &Decoded) -> Dropped {
    decoded
        .as_ref()
        .ok()
        .and_then(|d| d.as_ref().ok())
        .map_or(Dropped::default(), |c| Dropped {
            non_finite: c.num_dropped_non_finite,
            far: c.num_dropped_far,
            zero: c.num_dropped_zero,
            tag: c.num_dropped_tag,
            time: c.num_dropped_time,
        })
}

/// Why a cloud message could not be decoded, naming topic, log time and field.
fn decode_detail(topic: &str, log_time: u64, e: &codec::DecodeError) -> String {
    format!(
        "message on {topic} at log time {log_time} ns: field {}: {}",
        e.field, e.detail
    )
}

/// The header stamp given to a cloud that could not be decoded: its log time.
fn stamp_of_log_time(log_time: u64) -> codec::Time {
    i64::try_from(log_time)
        .ok()
        .and_then(codec::Time::from_ns)
        .unwrap_or_default()
}
