//! [`localize`]: a log placed in a prior map, the map held fixed. `mireg localize LOG --map
//! PRIOR`.
//!
//! The log is registered first (`mireg register`'s odometry, into a temporary file beside the
//! output), so that its own trajectory bridges the frames that see nothing of the map; its own
//! loops are closed where it leaves the map ([`LogLoops`]). Then, as [`super::merge`] links two
//! sessions, with the prior as the first: its keyframes against the log's by appearance
//! (prior-free: the log may start anywhere in the map, at any heading — the kidnapped robot),
//! each verified by MI-RANSAC + ICP; the links that agree on one placement kept, at least
//! [`super::MergeConfig::min_links`] at distinct keyframes to localise at all; then by place once
//! placed. The log's trajectory is solved into the prior's world with the prior's poses fixed
//! ([`super::graph::solve_in_prior`]).
//!
//! Each frame's status on `…/localization`: `localized` (a link to the map holds it), `tracking`
//! (placed by its own trajectory between fixes, within reach of the map), `outside_map` (placed
//! by its trajectory, but farther than the place search's largest radius from every keyframe of
//! the prior: the map does not cover it), or `lost` (the log never localised: no pose is written,
//! none is guessed).
//!
//! The prior is a `register` (or `merge`) output, read whole, or a map file (PLY, PCD, npy) cut
//! into tiles that play its keyframes ([`super::map_prior`]); the output's transforms then have
//! the parent `map`.
//!
//! NOTE: offline, not a tracker at the sensor's rate: the whole log is registered, then placed.
//! Every keyframe (or tile) of the prior is prepared up front for its descriptor, but only those
//! within [`super::MergeConfig::keyframe_memory_bytes`] are held; a map file's points are held
//! whole.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;
use serde_json::json;

use super::MergeConfig;
use super::graph::{Fix, solve_in_prior};
use super::job::{Attempt, Linker, link_records};
use super::links::Track;
use super::map_prior::{MAP_MIN_REVERSE_FITNESS, is_map_file, map_session, read_map, tiling_for};
use super::session::{Session, merge_settings, prepare_sessions};
use super::write::{LinkRecord, session_links_json_schema, write_links};
use crate::io::atomic_file::{check_not_an_input, check_target};
use crate::io::codec::Time;
use crate::io::input_log::InputLog;
use crate::io::mcap::log::OutputLog;
use crate::loops::LoopConfig;
use crate::odometry::OdometryConfig;
use crate::pipeline::PairConfig;
use crate::register::{
    CloudKind, KeptKeyframes, RegisterOptions, StampedPose, encode_pose, pose_channels,
    register_log, register_log_keeping_keyframes,
};
use crate::{Error, Result};

/// Verified appearance links after which a keyframe of the log stops trying its candidates: 1.
/// A keyframe that the solve then holds by no link (its link down-weighted, or none verified)
/// gets place candidates (`Linker::link_again`), in up to [`LOCALIZE_PLACE_ROUNDS`] rounds.
///
/// NOTE: with one link a keyframe and no second try, where the robust solve down-weighted that
/// link its frame fell back to `tracking` (KAIST03 in its second half: 18 of 21 localised); two
/// a keyframe up front localised all 21, for 42 verifications. One, and a place candidate for
/// the frames not held, localised as many frames on the sessions bench (21, 40, 25, 21 of the
/// four logs) for 24, 68, 32 and 22 verifications instead of 42, 80, 51 and 42, at the same
/// errors (docs/SESSIONS.md).
pub const LOCALIZE_LINKS_PER_KEYFRAME: usize = 1;

/// Rounds of place candidates for the log's keyframes that the solve holds by no link: 3. Each
/// round's new links move the solution, and may let go of a keyframe the previous solve held
/// (KAIST03 after c0d3738: frame 19's one link down-weighted to 0.41 only once frames 17 and 20
/// had their place links, and it ended `tracking`). A round that tries nothing new ends them.
pub const LOCALIZE_PLACE_ROUNDS: usize = 3;

/// When [`localize`] closes the log's own loops (`mireg register`'s loop closure on the log).
///
/// NOTE: inside the map, the links to the map are the loop closures: each holds its frame in the
/// map's world, and the frames between two of them ride on the odometry between fixed ends. The
/// log's own loop closure (0.2 s of KAIST03's 1.1 s registration) moved no placement there: on
/// the five logs of the sessions bench the frames placed and localised and the unaligned error
/// were the same without it (docs/SESSIONS.md). Where a frame ends `outside_map`, nothing of the
/// map holds the log there and its own loops may: the log is registered again with them, and
/// placed again by the same links.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LogLoops {
    /// Only where a frame ends `outside_map` (a second registration of the log, with loop
    /// closure). The default.
    #[default]
    Auto,
    /// Always: the log registered once, with loop closure.
    Always,
}

/// What [`localize`] needs.
#[derive(Debug, Clone)]
pub struct LocalizeOptions {
    /// The log to localise (MCAP, ROS 1 bag or ROS 2 bag directory, as `register` reads).
    pub log: PathBuf,
    /// The prior: a `mireg register` (or `merge`) output (its clouds and best trajectory), or a
    /// map file (`.ply`, `.pcd`, `.npy`, as `mireg map` writes them; told by extension), cut
    /// into tiles (the module `merge::map_prior`).
    pub prior: PathBuf,
    /// The output MCAP: the log's messages, its poses in the prior's world, the status per frame.
    pub output: PathBuf,
    /// Replace an existing output.
    pub force: bool,
    /// Seed of the registrations' randomness. Default 0.
    pub seed: u64,
    /// How the log is linked to the prior.
    pub config: MergeConfig,
    /// The log's point cloud topic (`None`: as `register` chooses).
    pub topic: Option<String>,
    /// When the log's own loops are closed. Default [`LogLoops::Auto`].
    pub log_loops: LogLoops,
    /// How far from the prior's nearest keyframe (or tile) a frame placed by its own trajectory
    /// is still `tracking` \[m\]; farther it is `outside_map`. `None` (the default): loop
    /// closure's largest place radius at the log's voxel (80 voxels: 29.6 m on KAIST03's 0.37 m,
    /// 3.9 m indoors at 0.049 m).
    pub map_reach_m: Option<f64>,
    /// Recorded in the output's metadata.
    pub command_line: String,
}

/// A frame's status on `…/localization`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FrameStatus {
    /// A link to the map holds it.
    Localized,
    /// Placed by the log's own trajectory, within reach of the map.
    Tracking,
    /// Placed by the log's trajectory, beyond the map.
    OutsideMap,
    /// Not placed: the log never localised.
    Lost,
}

/// What [`localize`] did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct LocalizeSummary {
    /// The output file.
    pub output: PathBuf,
    /// The prior's frame id, the parent of the output's transforms.
    pub map_frame: String,
    /// Frames of the log.
    pub frames: usize,
    /// Frames per status.
    pub localized: usize,
    /// See [`LocalizeSummary::localized`].
    pub tracking: usize,
    /// See [`LocalizeSummary::localized`].
    pub outside_map: usize,
    /// See [`LocalizeSummary::localized`].
    pub lost: usize,
    /// Candidates tried against the map, and links kept.
    pub candidates: usize,
    /// See [`LocalizeSummary::candidates`].
    pub links: usize,
    /// Why the log localised or not.
    pub reason: String,
    /// Whether the log's own loops were closed ([`LogLoops`]).
    pub log_loops_closed: bool,
    /// The output's topics: poses, transforms, statuses.
    pub pose_topic: String,
    /// See [`LocalizeSummary::pose_topic`].
    pub tf_topic: String,
    /// See [`LocalizeSummary::pose_topic`].
    pub localization_topic: String,
    /// Every candidate link to the map tried, its verdict and reason (`mireg.SessionLink`, as
    /// `mireg merge` writes them; the prior is session a).
    pub session_links_topic: String,
    /// Wall-clock seconds, the log's registration included.
    pub elapsed_s: f64,
    /// Where they went.
    pub timings_s: LocalizeTimings,
}

/// One frame's placement.
struct Placed {
    status: FrameStatus,
    pose: Option<Isometry3<f64>>,
    /// The link holding it: inliers, fitness, robust weight.
    fix: Option<(usize, f64, f64)>,
    distance_to_map_m: Option<f64>,
}

/// Localises `opts.log` in `opts.prior`; see the module doc.
///
/// # Errors
/// [`crate::Error::InvalidInput`] when the output is an input or exists without `force`, the
/// prior is not a `register` output (naming it); `register`'s errors on the log; the writers'
/// errors. A log that does not localise is not an error: its frames are `lost`.
pub fn localize(opts: &LocalizeOptions) -> Result<LocalizeSummary> {
    let t0 = Instant::now();
    if let Some(r) = opts.map_reach_m
        && !(r.is_finite() && r > 0.0)
    {
        return Err(Error::InvalidInput(format!(
            "localize: map_reach_m (--map-reach) must be finite and > 0 metres, got {r}"
        )));
    }
    let inputs = [opts.log.as_path(), opts.prior.as_path()];
    check_not_an_input(&opts.output, inputs, "one of the inputs")?;
    check_target(&opts.output, opts.force)?;
    // The prior first, so that a bad one fails before the log is registered.
    let prior = if is_map_file(&opts.prior) {
        Prior::Map(read_map(&opts.prior)?)
    } else {
        Prior::Run(Box::new(Session::read(&opts.prior)?))
    };
    // The log's own trajectory, in a temporary folder beside the output (removed on return).
    let dir = opts.output.parent().filter(|p| !p.as_os_str().is_empty());
    let tmp = tempfile::Builder::new()
        .prefix(".mireg-localize-")
        .tempdir_in(dir.unwrap_or(Path::new(".")))
        .map_err(|e| crate::io::io_err(dir.unwrap_or(Path::new(".")), e))?;
    let registered = tmp.path().join("log.mcap");
    let mut ropts = RegisterOptions::new(&opts.log, &registered, OdometryConfig::default());
    ropts.derive_voxel = true;
    ropts.topic.clone_from(&opts.topic);
    ropts.config.pair.seed = opts.seed;
    ropts.loops = opts.log_loops == LogLoops::Always;
    // A run prior's keyframes are prepared at its own settings, while the log registers: the
    // registration leaves part of two cores idle (it waits on its preparing thread, and that
    // one on it).
    // Without its loop closure the registration keeps the keyframes its odometry prepared.
    let (registration, prior) = std::thread::scope(|scope| {
        let prior = scope.spawn(|| prior.prepared(opts));
        let registration = register_log_keeping_keyframes(&ropts, !ropts.loops);
        let prior = prior
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        (registration, prior)
    });
    let (_, kept) = registration?;
    let prior = prior?;
    let mut timings = LocalizeTimings::default();
    let mut lap = Instant::now();
    let mut clock = |phase: &mut f64| {
        *phase = lap.elapsed().as_secs_f64();
        lap = Instant::now();
    };
    timings.register = t0.elapsed().as_secs_f64();
    let mut log = Session::read(&registered)?;
    // Links name the log by its own file, not the temporary one.
    log.name = opts
        .log
        .file_stem()
        .map_or_else(|| "log".to_string(), |s| s.to_string_lossy().into_owned());
    let (mut sessions, loops, pair) = prior.with_log(log, kept, opts)?;
    clock(&mut timings.prepare);
    let reach = opts
        .map_reach_m
        .unwrap_or(loops.candidates.max_place_radius_m);
    let tracks: Vec<Track<'_>> = sessions.iter().map(Session::track).collect();
    let linker = Linker::new(&sessions, &tracks, &pair, &loops, &opts.config)
        .links_per_keyframe(LOCALIZE_LINKS_PER_KEYFRAME);
    let mut attempts = Vec::new();
    let mut outcome = linker.link_pair((0, 1), &mut attempts)?;
    let (mut placed, mut weights) =
        place(&sessions, &attempts, outcome.join.as_ref(), (&loops, reach))?;
    // The log's keyframes that no link holds after the solve get place candidates; again after
    // a solve that lets go of others (the new links move the solution), a few times at most.
    for _ in 0..LOCALIZE_PLACE_ROUNDS {
        let unheld: BTreeSet<usize> = sessions[1]
            .keyframes
            .iter()
            .copied()
            .filter(|&k| placed[k].status != FrameStatus::Localized)
            .collect();
        let Some(align) = outcome.join.as_ref().map(|(join, _)| join.a_from_b) else {
            break;
        };
        if unheld.is_empty() {
            break;
        }
        let tried = attempts.len();
        let again =
            linker.link_again((0, 1), &mut attempts, 0, &outcome.report, &unheld, &align)?;
        if attempts.len() == tried {
            break;
        }
        outcome = again;
        (placed, weights) = place(&sessions, &attempts, outcome.join.as_ref(), (&loops, reach))?;
    }
    clock(&mut timings.link);
    let mut log_loops_closed = ropts.loops;
    if !log_loops_closed && placed.iter().any(|p| p.status == FrameStatus::OutsideMap) {
        // The log leaves the map: registered again with its own loops, and placed again by the
        // same links (the same seed gives the same odometry, the frames they join).
        ropts.loops = true;
        ropts.output = tmp.path().join("log_loops.mcap");
        register_log(&ropts)?;
        let closed = Session::read(&ropts.output)?;
        let log = &mut sessions[1];
        (log.poses, log.travelled_m) = (closed.poses, closed.travelled_m);
        log.pose_topic = closed.pose_topic;
        (placed, weights) = place(&sessions, &attempts, outcome.join.as_ref(), (&loops, reach))?;
        log_loops_closed = true;
        clock(&mut timings.log_loops);
    }
    let kept: BTreeSet<usize> = outcome
        .join
        .iter()
        .flat_map(|(_, kept)| kept.iter().copied())
        .collect();
    let joins: Vec<_> = outcome.join.iter().map(|(j, _)| *j).collect();
    let records = link_records(&sessions, &attempts, &kept, &joins, &weights, &opts.config);
    let [prior, log] = &sessions;
    let map_frame = prior.output.world_frame.clone();
    let topics = write_output(opts, log, &map_frame, &placed, &records)?;
    clock(&mut timings.write);
    let count = |s: FrameStatus| placed.iter().filter(|p| p.status == s).count();
    Ok(LocalizeSummary {
        output: opts.output.clone(),
        map_frame,
        frames: placed.len(),
        localized: count(FrameStatus::Localized),
        log_loops_closed,
        tracking: count(FrameStatus::Tracking),
        outside_map: count(FrameStatus::OutsideMap),
        lost: count(FrameStatus::Lost),
        candidates: attempts.len(),
        links: outcome.join.as_ref().map_or(0, |(_, kept)| kept.len()),
        reason: outcome.report.reason,
        pose_topic: topics[0].clone(),
        tf_topic: topics[1].clone(),
        localization_topic: topics[2].clone(),
        session_links_topic: topics[3].clone(),
        elapsed_s: t0.elapsed().as_secs_f64(),
        timings_s: timings,
    })
}

/// Where [`localize`]'s wall-clock time went \[s\].
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct LocalizeTimings {
    /// The log registered (its odometry; loop closure too with [`LogLoops::Always`]), and
    /// beside it a run prior's keyframes prepared.
    pub register: f64,
    /// The log's output read back and its keyframes prepared (a map file prior: also cut into
    /// tiles and prepared).
    pub prepare: f64,
    /// Candidates verified against the prior, and the log placed in it.
    pub link: f64,
    /// The log registered again with its own loops, and placed again, where it left the map
    /// (0 otherwise: [`LogLoops`]).
    pub log_loops: f64,
    /// The output written.
    pub write: f64,
}

/// What `--map` named, read.
enum Prior {
    /// A `register` (or `merge`) output.
    Run(Box<Session>),
    /// A run with its keyframes prepared, and the loop and registration settings they were
    /// prepared with.
    PreparedRun(Box<(Session, LoopConfig, PairConfig)>),
    /// The points of a map file.
    Map(Vec<Point3<f64>>),
}

impl Prior {
    /// A run's keyframes prepared as a merge prepares its first session (its voxel sets the
    /// settings); a map file as it is (tiled to the log's reach, it waits for the log).
    fn prepared(self, opts: &LocalizeOptions) -> Result<Self> {
        let Prior::Run(run) = self else {
            return Ok(self);
        };
        let mut sessions = [*run];
        let budget = opts.config.keyframe_memory_bytes;
        let (loops, pair) = prepare_sessions(&mut sessions, budget, opts.seed)?;
        let [run] = sessions;
        // The normals of the kept keyframes' ICP clouds, which their first verification
        // estimates (and keeps) otherwise: here they fill the registration's idle cores.
        run.frames.par_iter().flatten().for_each(|frame| {
            if let Some(icp) = &frame.icp {
                icp.normals();
            }
        });
        Ok(Prior::PreparedRun(Box::new((run, loops, pair))))
    }

    /// The prior and the log as the two sessions to link, prepared, with the loop and
    /// registration settings: a run's voxel sets them as in a merge; a map file is tiled to the
    /// log's reach and prepared at the log's voxel ([`super::map_prior`]).
    fn with_log(
        self,
        mut log: Session,
        kept: Option<KeptKeyframes>,
        opts: &LocalizeOptions,
    ) -> Result<([Session; 2], LoopConfig, PairConfig)> {
        let budget = opts.config.keyframe_memory_bytes;
        match self {
            Prior::Run(_) => self.prepared(opts)?.with_log(log, kept, opts),
            Prior::PreparedRun(prepared) => {
                let (prior, loops, pair) = *prepared;
                log.prepare_keyframes_from(&loops, &pair, kept)?;
                Ok(([prior, log], loops, pair))
            }
            Prior::Map(points) => {
                let (mut loops, pair) = merge_settings(&log, budget, opts.seed);
                log.prepare_keyframes_from(&loops, &pair, kept)?;
                loops.verify.min_reverse_fitness = MAP_MIN_REVERSE_FITNESS;
                let voxels = (log.voxel_m, log.feature_voxel_m);
                let tiling = tiling_for(&log)?;
                let map = map_session(&opts.prior, points, tiling, voxels, (&pair, budget))?;
                Ok(([map, log], loops, pair))
            }
        }
    }
}

/// Each frame of the log (`sessions[1]`) placed in the prior's world (`sessions[0]`) by the
/// agreeing links of `join`, or lost without one (`outside_map` farther than `reach` \[m\] from
/// every keyframe of the prior; `loops` solves the log's own loops with the links); and each
/// attempt's robust weight at the optimum (0 outside the graph).
fn place(
    sessions: &[Session; 2],
    attempts: &[Attempt],
    join: Option<&(super::Join, Vec<usize>)>,
    (loops, reach): (&LoopConfig, f64),
) -> Result<(Vec<Placed>, Vec<f64>)> {
    let [prior, log] = sessions;
    let mut weights = vec![0.0; attempts.len()];
    let Some((join, kept)) = join else {
        let lost = log
            .poses
            .iter()
            .map(|_| Placed {
                status: FrameStatus::Lost,
                pose: None,
                fix: None,
                distance_to_map_m: None,
            })
            .collect();
        return Ok((lost, weights));
    };
    let fixes: Vec<Fix> = kept
        .iter()
        .map(|&k| {
            let l = &attempts[k].link;
            Fix {
                frame: l.frame_b,
                world_from_sensor: prior.poses[l.frame_a] * l.a_from_b,
                information: l.information,
            }
        })
        .collect();
    let solution = solve_in_prior(&log.poses, &join.a_from_b, &fixes, loops)?;
    let mut held: BTreeMap<usize, (usize, f64, f64)> = BTreeMap::new();
    for ((&k, f), w) in kept.iter().zip(&fixes).zip(&solution.link_weights) {
        weights[k] = *w;
        let t = &attempts[k];
        if *w >= 0.5 && held.get(&f.frame).is_none_or(|h| t.link.inliers > h.0) {
            held.insert(f.frame, (t.link.inliers, t.fitness, *w));
        }
    }
    let keyframes: Vec<Point3<f64>> = prior
        .keyframes
        .iter()
        .map(|&k| prior.poses[k] * Point3::origin())
        .collect();
    let placed = solution.poses[0]
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let at = p * Point3::origin();
            let d = keyframes
                .iter()
                .map(|q| (q - at).norm())
                .fold(f64::INFINITY, f64::min);
            let status = if held.contains_key(&k) {
                FrameStatus::Localized
            } else if d <= reach {
                FrameStatus::Tracking
            } else {
                FrameStatus::OutsideMap
            };
            Placed {
                status,
                pose: Some(*p),
                fix: held.get(&k).copied(),
                distance_to_map_m: d.is_finite().then_some(d),
            }
        })
        .collect();
    Ok((placed, weights))
}

/// The JSON schema of `…/localization`.
#[must_use]
pub fn localization_json_schema() -> serde_json::Value {
    let num = json!({"type": "number"});
    let nullable = json!({"type": ["number", "null"]});
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "mireg.Localization",
        "description": "A frame of a log localised by mireg localize in a prior map: its status, the link to the map holding it (inliers, ICP fitness, robust weight) when there is one, and its distance to the nearest keyframe of the map",
        "type": "object",
        "properties": {
            "frame": {"type": "integer"}, "stamp_ns": {"type": "integer"},
            "status": {"type": "string", "enum": ["localized", "tracking", "outside_map", "lost"]},
            "inliers": {"type": ["integer", "null"]}, "fitness": nullable, "weight": nullable,
            "distance_to_map_m": nullable, "reason": {"type": "string"}
        },
        "required": ["frame", "stamp_ns", "status", "distance_to_map_m", "reason"],
        "additionalProperties": num
    })
}

/// Writes the output: the log's messages copied whole, then per placed frame its pose and
/// transform (parent `map_frame`), and every frame's status. Returns the topics (pose, tf,
/// localization).
fn write_output(
    opts: &LocalizeOptions,
    log: &Session,
    map_frame: &str,
    placed: &[Placed],
    records: &[LinkRecord],
) -> Result<[String; 4]> {
    let (input, catalog) = InputLog::open(&opts.log)?;
    let channels = catalog.channel_infos();
    let ns = crate::trajectory::free_mireg_namespace(channels.iter().map(|c| c.topic.as_str()));
    let tf_topic = if channels.iter().any(|c| c.topic == "/tf") {
        format!("{ns}/tf")
    } else {
        "/tf".to_string()
    };
    let topics = [
        format!("{ns}/pose"),
        tf_topic,
        format!("{ns}/localization"),
        format!("{ns}/session_links"),
    ];
    let kind = log.output.kind;
    let profile = match kind {
        CloudKind::Ros1 | CloudKind::LivoxRos1(_) => "ros1",
        _ => "ros2",
    };
    let mut out = OutputLog::create(&opts.output, opts.force, profile)?;
    out.declare_input(&opts.log, &catalog)?;
    let (tf, pose) = pose_channels(&mut out, kind, &topics[1], &topics[0])?;
    let status = out.add_json_channel(
        &topics[2],
        "mireg.Localization",
        &localization_json_schema(),
    )?;
    let links = out.add_json_channel(
        &topics[3],
        "mireg.SessionLink",
        &session_links_json_schema(),
    )?;
    input.pass_through(&mut out, &BTreeSet::new(), None, |_, _, _| Ok(()))?;
    write_links(&mut out, links, records, |r| {
        log.output.frames[r.frame_b()].log_time
    })?;
    for (k, (f, p)) in log.output.frames.iter().zip(placed).enumerate() {
        if let Some(world_from_sensor) = p.pose {
            let stamped = StampedPose {
                stamp: Time::from_ns(f.stamp_ns).unwrap_or_default(),
                child_frame: &f.child_frame,
                world_from_frame: world_from_sensor,
                log_time: f.log_time,
                publish_time: f.publish_time,
            };
            let (pose_msg, tf_msg) = encode_pose(kind, map_frame, &stamped);
            out.write(tf, f.log_time, f.publish_time, &tf_msg)?;
            out.write(pose, f.log_time, f.publish_time, &pose_msg)?;
        }
        let reason = match p.status {
            FrameStatus::Localized => "registered against the map",
            FrameStatus::Tracking => "placed by the log's own trajectory between links to the map",
            FrameStatus::OutsideMap => "beyond the map: placed by the log's own trajectory",
            FrameStatus::Lost => "the log did not localise in the map: no pose",
        };
        let record = json!({
            "frame": k, "stamp_ns": f.stamp_ns, "status": p.status,
            "inliers": p.fix.map(|x| x.0), "fitness": p.fix.map(|x| x.1),
            "weight": p.fix.map(|x| x.2), "distance_to_map_m": p.distance_to_map_m,
            "reason": reason,
        });
        out.write(
            status,
            f.log_time,
            f.publish_time,
            &serde_json::to_vec(&record).expect("JSON"),
        )?;
    }
    let meta = BTreeMap::from([
        ("version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
        ("command_line".to_string(), opts.command_line.clone()),
        ("input".to_string(), opts.log.display().to_string()),
        ("prior".to_string(), opts.prior.display().to_string()),
        ("map_frame".to_string(), map_frame.to_string()),
        ("pose_topic".to_string(), topics[0].clone()),
        ("tf_topic".to_string(), topics[1].clone()),
        ("localization_topic".to_string(), topics[2].clone()),
        ("session_links_topic".to_string(), topics[3].clone()),
        ("voxel_m".to_string(), log.voxel_m.to_string()),
    ]);
    out.write_metadata("mireg_localize", meta)?;
    out.finish()?;
    Ok(topics)
}
