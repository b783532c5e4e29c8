//! [`merge`]: the job, from the `register` outputs to the merged outputs and the report.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

use super::links::{
    AgreementConfig, LinkSource, SessionLink, Track, agreeing_links, appearance_candidates,
    place_candidates,
};
use super::pair_links::{Inputs, read_pair_links, write_pair_links};
use super::session::{Session, prepare_sessions};
use super::write::{LinkRecord, Verdict, write_report, write_session};
use super::{Join, MergeConfig, graph::solve_group, group_sessions};
use crate::io::atomic_file::{check_not_an_input, check_target};
use crate::loops::{LoopConfig, verify};
use crate::odometry::uncertainty::registration_information;
use crate::pipeline::{PairConfig, PreparedFrame};
use crate::{Error, Result};

/// What [`merge`] needs.
#[derive(Debug, Clone)]
pub struct MergeOptions {
    /// The sessions: `mireg register` outputs, at least two. The first is the merged frame's
    /// reference (its group's root); the registration settings are its.
    pub runs: Vec<PathBuf>,
    /// Folder of the merged outputs (`NAME.mcap` per session, by the run's file name) and of
    /// `merge_report.json`; created when missing (its parent must exist).
    pub output_dir: PathBuf,
    /// Replace existing outputs.
    pub force: bool,
    /// Seed of the registrations' randomness. Default 0.
    pub seed: u64,
    /// How sessions are linked and joined.
    pub config: MergeConfig,
    /// Recorded in each output's metadata.
    pub command_line: String,
    /// Folder of each pair's links (`pair_A_B.json`, [`crate::merge::link_pair_file`]): read
    /// where present instead of linking that pair, written for the pairs linked. `None`: every
    /// pair is linked, no file written.
    pub links_dir: Option<PathBuf>,
}

/// One session in the report.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SessionReport {
    /// The file stem of its run.
    pub name: String,
    /// The run read.
    pub input: PathBuf,
    /// Its merged output.
    pub output: PathBuf,
    /// The trajectory used (`…/pose_optimized` when the run closed loops).
    pub pose_topic: String,
    /// Frames (poses) and keyframes prepared.
    pub frames: usize,
    /// See [`SessionReport::frames`].
    pub keyframes: usize,
    /// Its group (index into the groups; the group of the first run is 0).
    pub group: usize,
    /// The group's frame id in `/mireg/tf_merged`.
    pub merged_frame: String,
    /// `world_group_from_world_session` at the optimum, as x y z \[m\], qx qy qz qw.
    pub alignment: [f64; 7],
}

/// One pair of sessions in the report.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct PairReport {
    /// The earlier session's name.
    pub a: String,
    /// The later session's name.
    pub b: String,
    /// Candidates tried, by appearance and by place.
    pub appearance_candidates: usize,
    /// See [`PairReport::appearance_candidates`].
    pub place_candidates: usize,
    /// Candidates that passed verification.
    pub verified: usize,
    /// Verified links in the largest agreeing set.
    pub agreeing: usize,
    /// Whether the two sessions joined.
    pub joined: bool,
    /// Why they did or did not.
    pub reason: String,
}

/// What [`merge`] did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct MergeSummary {
    /// The output folder.
    pub output_dir: PathBuf,
    /// Per session.
    pub sessions: Vec<SessionReport>,
    /// Per pair of sessions.
    pub pairs: Vec<PairReport>,
    /// Groups of sessions in one frame (1 when every session joined).
    pub groups: usize,
    /// Links accepted into the graphs.
    pub links_accepted: usize,
    /// Pose-graph iterations, summed over the groups.
    pub graph_iterations: usize,
    /// Wall-clock seconds.
    pub elapsed_s: f64,
}

/// A candidate tried and what became of it.
pub(super) struct Attempt {
    pub(super) link: SessionLink,
    /// Whether verification accepted it, and its text when not.
    pub(super) verified: bool,
    pub(super) reason: String,
    pub(super) fitness: f64,
    pub(super) registered: bool,
}

/// Merges the sessions `opts.runs` into `opts.output_dir`; see the module doc of
/// [`crate::merge`].
///
/// # Errors
/// [`Error::InvalidInput`] for fewer than two runs, two runs with one file name, an output that
/// is an input or exists without `force`, a run that is not a `register` output (naming the
/// file); the readers' and writers' errors. Outputs already committed stay when a later one
/// fails.
pub fn merge(opts: &MergeOptions) -> Result<MergeSummary> {
    let t0 = Instant::now();
    let targets = check_outputs(opts)?;
    let mut sessions = opts
        .runs
        .iter()
        .map(|p| Session::read(p))
        .collect::<Result<Vec<_>>>()?;
    let (loops, pair) =
        prepare_sessions(&mut sessions, opts.config.keyframe_memory_bytes, opts.seed)?;
    let tracks: Vec<Track<'_>> = sessions.iter().map(Session::track).collect();
    let mut attempts: Vec<Attempt> = Vec::new();
    let mut joins = Vec::new();
    let mut pairs = Vec::new();
    let mut kept: BTreeSet<usize> = BTreeSet::new();
    let linker = Linker::new(&sessions, &tracks, &pair, &loops, &opts.config);
    if let Some(dir) = &opts.links_dir
        && !dir.is_dir()
    {
        std::fs::create_dir(dir).map_err(|e| crate::io::io_err(dir, e))?;
    }
    for b in 1..sessions.len() {
        for a in 0..b {
            let outcome = link_or_read(&linker, opts, (a, b), &mut attempts)?;
            if let Some((join, agreeing)) = outcome.join {
                joins.push(join);
                kept.extend(agreeing);
            }
            pairs.push(outcome.report);
        }
    }
    let groups = group_sessions(sessions.len(), &joins);
    let solved = solve_groups(&sessions, &groups, &attempts, &kept, &loops)?;
    let records = link_records(
        &sessions,
        &attempts,
        &kept,
        &joins,
        &solved.weights,
        &opts.config,
    );
    let reports = write_outputs(&sessions, &targets, opts, &solved, &records)?;
    let summary = MergeSummary {
        output_dir: opts.output_dir.clone(),
        sessions: reports,
        pairs,
        groups: groups.len(),
        links_accepted: kept.len(),
        graph_iterations: solved.iterations,
        elapsed_s: t0.elapsed().as_secs_f64(),
    };
    write_report(
        &opts.output_dir.join("merge_report.json"),
        &summary,
        opts.force,
    )?;
    Ok(summary)
}

/// Sessions `a` and `b` linked, or their links read from `opts.links_dir` where that holds
/// their file; linked ones are written there.
fn link_or_read(
    linker: &Linker<'_>,
    opts: &MergeOptions,
    (a, b): (usize, usize),
    attempts: &mut Vec<Attempt>,
) -> Result<PairOutcome> {
    let Some(dir) = &opts.links_dir else {
        return linker.link_pair((a, b), attempts);
    };
    let s = linker.sessions;
    let inputs = Inputs::new(&s[0], [(a, &s[a]), (b, &s[b])], opts.seed, &opts.config);
    if let Some(outcome) = read_pair_links(dir, &inputs, attempts, opts.force)? {
        return Ok(outcome);
    }
    let first = attempts.len();
    let outcome = linker.link_pair((a, b), attempts)?;
    write_pair_links(
        dir,
        &inputs,
        &attempts[first..],
        first,
        &outcome,
        opts.force,
    )?;
    Ok(outcome)
}

/// Writes each session's merged output; returns the sessions' reports.
fn write_outputs(
    sessions: &[Session],
    targets: &[PathBuf],
    opts: &MergeOptions,
    solved: &Solved,
    records: &[LinkRecord],
) -> Result<Vec<SessionReport>> {
    let frame_of = |g: usize| {
        if g == 0 {
            "mireg_merged".to_string()
        } else {
            format!("mireg_merged_{g}")
        }
    };
    let mut reports = Vec::new();
    for (s, session) in sessions.iter().enumerate() {
        let frame = frame_of(solved.group_of[s]);
        write_session(
            session,
            &targets[s],
            opts,
            &solved.merged[s],
            &frame,
            records,
            s,
        )?;
        let a = solved.alignment[s];
        let (t, q) = (a.translation.vector, a.rotation.coords);
        reports.push(SessionReport {
            name: session.name.clone(),
            input: session.output.path.clone(),
            output: targets[s].clone(),
            pose_topic: session.pose_topic.clone(),
            frames: session.poses.len(),
            keyframes: session.keyframes.len(),
            group: solved.group_of[s],
            merged_frame: frame,
            alignment: [t.x, t.y, t.z, q.x, q.y, q.z, q.w],
        });
    }
    Ok(reports)
}

/// Every group solved: per session its merged poses, its world's placement in its group's, and
/// its group; per attempt its weight in the graph (0 outside).
struct Solved {
    merged: Vec<Vec<Isometry3<f64>>>,
    alignment: Vec<Isometry3<f64>>,
    group_of: Vec<usize>,
    weights: Vec<f64>,
    iterations: usize,
}

/// Solves each of `groups` with the `kept` attempts between its members ([`solve_group`]).
fn solve_groups(
    sessions: &[Session],
    groups: &[super::Group],
    attempts: &[Attempt],
    kept: &BTreeSet<usize>,
    loops: &LoopConfig,
) -> Result<Solved> {
    let n = sessions.len();
    let mut solved = Solved {
        merged: vec![Vec::new(); n],
        alignment: vec![Isometry3::identity(); n],
        group_of: vec![0; n],
        weights: vec![0.0; attempts.len()],
        iterations: 0,
    };
    let all_poses: Vec<&[Isometry3<f64>]> = sessions.iter().map(|s| s.poses.as_slice()).collect();
    for (g, group) in groups.iter().enumerate() {
        let in_group: Vec<usize> = kept
            .iter()
            .copied()
            .filter(|&k| {
                let l = &attempts[k].link;
                group.members.contains(&l.a) && group.members.contains(&l.b)
            })
            .collect();
        let links: Vec<SessionLink> = in_group.iter().map(|&k| attempts[k].link).collect();
        let solution = solve_group(&all_poses, &group.members, &group.alignments, &links, loops)?;
        solved.iterations += solution.iterations;
        for (&k, w) in in_group.iter().zip(&solution.link_weights) {
            solved.weights[k] = *w;
        }
        for (&m, poses) in group.members.iter().zip(solution.poses) {
            // The session's world in the group's: where its first pose went.
            solved.alignment[m] = poses[0] * sessions[m].poses[0].inverse();
            solved.merged[m] = poses;
            solved.group_of[m] = g;
        }
    }
    Ok(solved)
}

/// The output paths, checked before anything is read: `DIR/NAME.mcap` per run, `DIR` created
/// when missing.
fn check_outputs(opts: &MergeOptions) -> Result<Vec<PathBuf>> {
    if opts.runs.len() < 2 {
        return Err(Error::InvalidInput(format!(
            "merge needs at least two `mireg register` outputs, got {}",
            opts.runs.len()
        )));
    }
    let dir = &opts.output_dir;
    if dir.exists() && !dir.is_dir() {
        return Err(Error::InvalidInput(format!(
            "{}: not a folder; mireg merge writes one output per session into a folder",
            dir.display()
        )));
    }
    let mut targets: Vec<PathBuf> = Vec::new();
    for run in &opts.runs {
        let name = run
            .file_name()
            .ok_or_else(|| Error::InvalidInput(format!("{}: not a file", run.display())))?;
        let target = dir.join(Path::new(name).with_extension("mcap"));
        if targets.contains(&target) {
            return Err(Error::InvalidInput(format!(
                "two runs are named {}: their merged outputs would be one file; rename one",
                target.display()
            )));
        }
        targets.push(target);
    }
    for t in &targets {
        check_not_an_input(t, opts.runs.iter().map(PathBuf::as_path), "one of the runs")?;
    }
    if !dir.exists() {
        std::fs::create_dir(dir).map_err(|e| crate::io::io_err(dir, e))?;
    }
    for t in targets
        .iter()
        .chain(std::iter::once(&dir.join("merge_report.json")))
    {
        check_target(t, opts.force)?;
    }
    Ok(targets)
}

/// What linking needs of a merge, shared by every pair of sessions.
pub(super) struct Linker<'s> {
    pub(super) sessions: &'s [Session],
    pub(super) tracks: &'s [Track<'s>],
    pub(super) pair: &'s PairConfig,
    pub(super) loops: &'s LoopConfig,
    pub(super) agreement: AgreementConfig,
    pub(super) config: &'s MergeConfig,
    /// Verified appearance links after which a keyframe of the later session stops
    /// ([`Linker::links_per_keyframe`]); `None`: all its candidates are verified.
    pub(super) links_per_keyframe: Option<usize>,
}

/// One pair of sessions linked: its report and, when they join, the join and the agreeing links
/// (indices into the attempts).
pub(super) struct PairOutcome {
    pub(super) report: PairReport,
    pub(super) join: Option<(Join, Vec<usize>)>,
}

impl<'s> Linker<'s> {
    /// Linking by `config` with `loops`' search and acceptance settings and `pair`'s
    /// registration; links agree by the first session's voxel ([`AgreementConfig::for_voxel`]).
    pub(super) fn new(
        sessions: &'s [Session],
        tracks: &'s [Track<'s>],
        pair: &'s PairConfig,
        loops: &'s LoopConfig,
        config: &'s MergeConfig,
    ) -> Self {
        Self {
            sessions,
            tracks,
            pair,
            loops,
            agreement: AgreementConfig::for_voxel(sessions[0].voxel_m),
            config,
            links_per_keyframe: None,
        }
    }

    /// Each keyframe of the later session verifies its appearance candidates best first, a
    /// round at a time, until `links` of them have passed; once aligned, only the keyframes
    /// without an agreeing link get place candidates. For `mireg localize`, where each keyframe
    /// of the log needs a fix in the map, not every one it could have.
    ///
    /// NOTE: a merge verifies every candidate: its joint trajectory is scored against one log
    /// registered whole, and each extra link is a constraint. Localising KAIST03 in its second
    /// half verified 64 candidates, 3 per keyframe, all accepted (docs/SESSIONS.md).
    pub(super) fn links_per_keyframe(self, links: usize) -> Self {
        Self {
            links_per_keyframe: Some(links),
            ..self
        }
    }

    /// Verifies candidates between sessions `a` and `b` (by appearance; then, once aligned, by
    /// place), appending every attempt to `attempts`.
    pub(super) fn link_pair(
        &self,
        (a, b): (usize, usize),
        attempts: &mut Vec<Attempt>,
    ) -> Result<PairOutcome> {
        let (sa, sb) = (&self.sessions[a], &self.sessions[b]);
        let first = attempts.len();
        // NOTE: appearance in two passes: a spread of at most `first_pass_keyframes` of b's
        // keyframes first, the rest only when those did not join the sessions; once joined,
        // place candidates (with the alignment to check against) cover the rest for less.
        let nb = sb.descriptors.len();
        let stride = nb.div_ceil(self.config.first_pass_keyframes.max(1)).max(1);
        let passes: [Vec<usize>; 2] = [
            (0..nb).step_by(stride).collect(),
            (0..nb).filter(|k| k % stride != 0).collect(),
        ];
        let mut by_look: Vec<(usize, usize)> = Vec::new();
        let mut agreeing = Vec::new();
        for subset in passes {
            let budget = self.config.max_appearance_candidates - by_look.len();
            if subset.is_empty()
                || budget == 0
                || joining_alignment(attempts, &agreeing, self.tracks, self.config).is_some()
            {
                break;
            }
            let descriptors: Vec<_> = subset.iter().map(|&k| sb.descriptors[k]).collect();
            let found: Vec<(usize, usize)> = appearance_candidates(
                &sa.descriptors,
                &descriptors,
                self.config.appearance_per_keyframe,
                budget,
            )
            .into_iter()
            .map(|(ka, i)| (ka, subset[i]))
            .collect();
            by_look.extend(self.verify_appearance((a, b), &found, attempts)?);
            agreeing = self.agreeing(attempts, first, (a, b));
        }
        let mut place = 0;
        if let Some(align) = joining_alignment(attempts, &agreeing, self.tracks, self.config) {
            let mut tried = self.place_candidates((a, b), &align, &by_look);
            if self.links_per_keyframe.is_some() {
                let linked: BTreeSet<usize> =
                    agreeing.iter().map(|&k| attempts[k].link.frame_b).collect();
                tried.retain(|&(_, kb, _)| !linked.contains(&sb.keyframes[kb]));
            }
            place = tried.len();
            attempts.extend(self.verify_candidates((a, b), &tried, LinkSource::Place)?);
            agreeing = self.agreeing(attempts, first, (a, b));
        }
        Ok(self.outcome((a, b), attempts, first, agreeing, [by_look.len(), place]))
    }

    /// Verifies place candidates for the keyframes of `b` at the frames `frames_b` (at most
    /// [`MergeConfig::place_per_keyframe`] each, none tried before), once `b` is aligned to `a`
    /// by `align`, appending the attempts; then the outcome of every attempt from `first` on,
    /// as [`Linker::link_pair`] gives it, its report counting the candidates of `previous` (that
    /// link's) and these. For `mireg localize`, whose solve holds some frames of the log by no
    /// link: they get another fix in the map, where verifying a second one for every keyframe
    /// up front cost twice as much.
    pub(super) fn link_again(
        &self,
        (a, b): (usize, usize),
        attempts: &mut Vec<Attempt>,
        first: usize,
        previous: &PairReport,
        frames_b: &BTreeSet<usize>,
        align: &Isometry3<f64>,
    ) -> Result<PairOutcome> {
        let (sa, sb) = (&self.sessions[a], &self.sessions[b]);
        let keyframe = |s: &Session, frame: usize| s.keyframes.binary_search(&frame).ok();
        let done: Vec<(usize, usize)> = attempts[first..]
            .iter()
            .filter_map(|t| Some((keyframe(sa, t.link.frame_a)?, keyframe(sb, t.link.frame_b)?)))
            .collect();
        let mut tried = self.place_candidates((a, b), align, &done);
        tried.retain(|&(_, kb, _)| frames_b.contains(&sb.keyframes[kb]));
        attempts.extend(self.verify_candidates((a, b), &tried, LinkSource::Place)?);
        let agreeing = self.agreeing(attempts, first, (a, b));
        Ok(self.outcome(
            (a, b),
            attempts,
            first,
            agreeing,
            [
                previous.appearance_candidates,
                previous.place_candidates + tried.len(),
            ],
        ))
    }

    /// The outcome of linking `a` and `b` by the attempts from `first` on, of which `agreeing`
    /// agree, after `[appearance, place]` candidates.
    fn outcome(
        &self,
        (a, b): (usize, usize),
        attempts: &[Attempt],
        first: usize,
        agreeing: Vec<usize>,
        [appearance, place]: [usize; 2],
    ) -> PairOutcome {
        let (sa, sb) = (&self.sessions[a], &self.sessions[b]);
        let verified = attempts[first..].iter().filter(|t| t.verified).count();
        let join = joining_alignment(attempts, &agreeing, self.tracks, self.config);
        let (frames_a, frames_b) = distinct_ends(attempts, &agreeing);
        let reason = if join.is_some() {
            format!(
                "{} agreeing links at {frames_a} and {frames_b} keyframes",
                agreeing.len()
            )
        } else if verified == 0 {
            "no candidate passed verification: the sessions share no place that registers"
                .to_string()
        } else {
            format!(
                "{} of {verified} verified links agree, at {frames_a} and {frames_b} keyframes: \
                 fewer than the {} that join two sessions",
                agreeing.len(),
                self.config.min_links
            )
        };
        let report = PairReport {
            a: sa.name.clone(),
            b: sb.name.clone(),
            appearance_candidates: appearance,
            place_candidates: place,
            verified,
            agreeing: agreeing.len(),
            joined: join.is_some(),
            reason,
        };
        let join = join.map(|a_from_b| {
            let links = agreeing.len();
            (
                Join {
                    a,
                    b,
                    a_from_b,
                    links,
                },
                agreeing,
            )
        });
        PairOutcome { report, join }
    }

    /// Verifies the appearance candidates `found` (`(keyframe_a, keyframe_b)`, best first)
    /// between sessions `a` and `b`, appending the attempts; returns the pairs tried. All at
    /// once, or with [`Linker::links_per_keyframe`] in rounds: the k-th candidate of each
    /// keyframe of `b` that has fewer verified links than wanted.
    fn verify_appearance(
        &self,
        (a, b): (usize, usize),
        found: &[(usize, usize)],
        attempts: &mut Vec<Attempt>,
    ) -> Result<Vec<(usize, usize)>> {
        let Some(wanted) = self.links_per_keyframe else {
            let tried: Vec<Candidate> = found.iter().map(|&(ka, kb)| (ka, kb, None)).collect();
            attempts.extend(self.verify_candidates((a, b), &tried, LinkSource::Appearance)?);
            return Ok(found.to_vec());
        };
        // Each keyframe's candidates in the order found, the keyframes in order of their best.
        let mut queues: Vec<(usize, Vec<usize>)> = Vec::new();
        for &(ka, kb) in found {
            match queues.iter_mut().find(|(k, _)| *k == kb) {
                Some((_, q)) => q.push(ka),
                None => queues.push((kb, vec![ka])),
            }
        }
        // Verified links per frame of `b`.
        let keyframes = &self.sessions[b].keyframes;
        let mut linked: BTreeMap<usize, usize> = BTreeMap::new();
        let mut done = Vec::new();
        for round in 0.. {
            let tried: Vec<Candidate> = queues
                .iter()
                .filter(|(kb, q)| {
                    round < q.len() && linked.get(&keyframes[*kb]).is_none_or(|&n| n < wanted)
                })
                .map(|(kb, q)| (q[round], *kb, None))
                .collect();
            if tried.is_empty() {
                break;
            }
            let verified = self.verify_candidates((a, b), &tried, LinkSource::Appearance)?;
            for t in verified.iter().filter(|t| t.verified) {
                *linked.entry(t.link.frame_b).or_default() += 1;
            }
            attempts.extend(verified);
            done.extend(tried.iter().map(|&(ka, kb, _)| (ka, kb)));
        }
        Ok(done)
    }

    /// The agreeing links among the verified attempts from `first` on (indices into
    /// `attempts`).
    fn agreeing(&self, attempts: &[Attempt], first: usize, ends: (usize, usize)) -> Vec<usize> {
        let index: Vec<usize> = (first..attempts.len())
            .filter(|&k| attempts[k].verified)
            .collect();
        let links: Vec<SessionLink> = index.iter().map(|&k| attempts[k].link).collect();
        agreeing_links(&links, ends, self.tracks, &self.agreement)
            .into_iter()
            .map(|i| index[i])
            .collect()
    }

    /// Candidates by place once `b` is aligned to `a` by `align` (`world_a_from_world_b`), not
    /// among those `done`, each with the relative pose the alignment predicts.
    fn place_candidates(
        &self,
        (a, b): (usize, usize),
        align: &Isometry3<f64>,
        done: &[(usize, usize)],
    ) -> Vec<Candidate> {
        let (sa, sb) = (&self.sessions[a], &self.sessions[b]);
        let positions = |s: &Session, to: &Isometry3<f64>| -> Vec<Point3<f64>> {
            s.keyframes
                .iter()
                .map(|&k| to * s.poses[k] * Point3::origin())
                .collect()
        };
        let done: BTreeSet<(usize, usize)> = done.iter().copied().collect();
        // NOTE: a map file's tiles stand at the mean of their grid cell's points, up to a cell
        // from the log's path and below the sensor: at the loop place radius (3 m) a keyframe
        // of the log rarely had a tile to try (KAIST03's gap log in the PLY map of its second
        // half: frame 7 none after its one link was down-weighted). Within a cell's edge, the
        // tiles whose points surround it (a tile reaches twice as far).
        let radius = self.loops.candidates.place_radius_m;
        let radius = sa
            .tiles
            .as_ref()
            .map_or(radius, |t| radius.max(t.spacing_m()));
        let mut near = place_candidates(
            &positions(sa, &Isometry3::identity()),
            &positions(sb, align),
            radius,
            self.config.place_per_keyframe,
        );
        near.retain(|c| !done.contains(c));
        near.truncate(self.config.max_place_candidates);
        near.iter()
            .map(|&(ka, kb)| {
                let (pa, pb) = (sa.poses[sa.keyframes[ka]], sb.poses[sb.keyframes[kb]]);
                (ka, kb, Some(pa.inverse() * align * pb))
            })
            .collect()
    }

    /// Verifies `candidates` between sessions `a` and `b`, in parallel; with a prior, the
    /// agreement test applies at the place radius.
    fn verify_candidates(
        &self,
        (a, b): (usize, usize),
        candidates: &[Candidate],
        found_by: LinkSource,
    ) -> Result<Vec<Attempt>> {
        let (sa, sb) = (&self.sessions[a], &self.sessions[b]);
        // The frames not kept in memory, prepared again for this batch only.
        let wanted = |side: usize| -> BTreeSet<usize> {
            candidates
                .iter()
                .map(|c| if side == 0 { c.0 } else { c.1 })
                .collect()
        };
        let (loaded_a, loaded_b) = (
            sa.load(&wanted(0), self.pair)?,
            sb.load(&wanted(1), self.pair)?,
        );
        candidates
            .par_iter()
            .filter_map(|&(ka, kb, prior)| {
                Some((
                    ka,
                    kb,
                    prior,
                    frame(sa, &loaded_a, ka)?,
                    frame(sb, &loaded_b, kb)?,
                ))
            })
            .map(|(ka, kb, prior, fa, fb)| {
                let v = verify(
                    fb,
                    fa,
                    &prior.unwrap_or_else(Isometry3::identity),
                    prior.map(|_| self.loops.candidates.place_radius_m),
                    self.pair,
                    &self.loops.verify,
                )?;
                let a_from_b = v.match_from_query.unwrap_or_else(Isometry3::identity);
                let information = v
                    .pair
                    .icp_hessian
                    .and_then(|h| registration_information(&h, &a_from_b));
                Ok(Attempt {
                    link: SessionLink {
                        a,
                        frame_a: sa.keyframes[ka],
                        b,
                        frame_b: sb.keyframes[kb],
                        a_from_b,
                        information,
                        inliers: v.pair.num_inliers,
                        found_by,
                    },
                    verified: v.accepted,
                    reason: v.reason,
                    fitness: v.pair.fitness,
                    registered: v.match_from_query.is_some(),
                })
            })
            .collect()
    }
}

/// Keyframe `k`'s prepared cloud: kept by the session, or prepared again into `loaded`.
fn frame<'f>(
    s: &'f Session,
    loaded: &'f BTreeMap<usize, PreparedFrame>,
    k: usize,
) -> Option<&'f PreparedFrame> {
    s.frames[k].as_ref().or_else(|| loaded.get(&k))
}

/// A candidate: a keyframe of session `a`, one of `b` (indices into their keyframes), and the
/// relative pose `a_from_b` expected, when the sessions are aligned.
type Candidate = (usize, usize, Option<Isometry3<f64>>);

/// Distinct keyframes of each session among `agreeing` attempts.
fn distinct_ends(attempts: &[Attempt], agreeing: &[usize]) -> (usize, usize) {
    let fa: BTreeSet<usize> = agreeing.iter().map(|&k| attempts[k].link.frame_a).collect();
    let fb: BTreeSet<usize> = agreeing.iter().map(|&k| attempts[k].link.frame_b).collect();
    (fa.len(), fb.len())
}

/// The alignment `world_a_from_world_b` when the agreeing links join the two sessions (at
/// least [`MergeConfig::min_links`] distinct keyframes at each end): the one the link with the
/// most inliers implies.
fn joining_alignment(
    attempts: &[Attempt],
    agreeing: &[usize],
    tracks: &[Track<'_>],
    config: &MergeConfig,
) -> Option<Isometry3<f64>> {
    let (fa, fb) = distinct_ends(attempts, agreeing);
    if fa.min(fb) < config.min_links.max(1) {
        return None;
    }
    let best = agreeing
        .iter()
        .map(|&k| &attempts[k].link)
        .max_by(|x, y| x.inliers.cmp(&y.inliers).then(y.frame_b.cmp(&x.frame_b)))?;
    Some(best.alignment(tracks[best.a].poses, tracks[best.b].poses))
}

/// Every attempt as `/mireg/session_links` records it.
pub(super) fn link_records(
    sessions: &[Session],
    attempts: &[Attempt],
    kept: &BTreeSet<usize>,
    joins: &[Join],
    weights: &[f64],
    config: &MergeConfig,
) -> Vec<LinkRecord> {
    attempts
        .iter()
        .enumerate()
        .map(|(k, t)| {
            let l = &t.link;
            let joined = joins.iter().any(|j| j.a == l.a && j.b == l.b);
            let (verdict, reason) = if kept.contains(&k) {
                (Verdict::Accepted, String::new())
            } else if !t.verified {
                (Verdict::Rejected, t.reason.clone())
            } else if joined {
                (
                    Verdict::Rejected,
                    "disagrees with the links that joined the two sessions".to_string(),
                )
            } else {
                (
                    Verdict::Rejected,
                    format!(
                        "the sessions did not join: fewer than {} agreeing links",
                        config.min_links
                    ),
                )
            };
            LinkRecord::new(sessions, t, verdict, reason, weights[k])
        })
        .collect()
}
