//! `mireg merge`: several `register` outputs of one site (sessions that each start at their own
//! origin, with no prior between them) put into one frame.
//!
//! 1. Each session is read back: its best trajectory (loop-closed where `register` closed
//!    loops), its keyframes (the loop search's rule, [`crate::loops::KeyframeConfig`]) and their
//!    clouds, prepared for registration as loop verification prepares them.
//! 2. For every pair of sessions, candidates by appearance (the loop descriptors,
//!    [`links::appearance_candidates`]), each verified prior-free by MI-RANSAC + ICP with loop
//!    closure's acceptance test ([`crate::loops::verify`]).
//! 3. The verified links between two sessions that agree on one alignment are kept
//!    ([`links::agreeing_links`]); two sessions join when at least [`MergeConfig::min_links`]
//!    agreeing links at distinct keyframes hold them together. Once aligned, candidates by place
//!    ([`links::place_candidates`]) are verified too, against the alignment, and the agreeing
//!    set is found again.
//! 4. Sessions joined directly or through others form a group ([`group_sessions`]); each group
//!    is solved as one robust pose graph ([`graph::solve_group`]), its lowest session fixed.
//!
//! Sessions that join nothing stay apart, in their own frame, and the report says why.
//!
//! `mireg localize` ([`localize`]) is the same linking with the prior map as the first session,
//! held fixed.
//!
//! Pure parts: [`links`], [`graph`], [`group_sessions`]; `job.rs` reads and writes the files.

use nalgebra::Isometry3;

pub mod graph;
mod job;
pub mod links;
mod localize;
mod map_prior;
mod pair_links;
mod session;
mod write;

pub use job::{MergeOptions, MergeSummary, PairReport, SessionReport, merge};
pub use links::{AgreementConfig, LinkSource, SessionLink};
pub use localize::{
    FrameStatus, LOCALIZE_LINKS_PER_KEYFRAME, LocalizeOptions, LocalizeSummary, LocalizeTimings,
    LogLoops, localization_json_schema, localize,
};
pub use map_prior::{MAP_MIN_REVERSE_FITNESS, MAX_TILES, MIN_TILE_POINTS};
pub use pair_links::{PAIR_LINKS_FORMAT, link_pair_file, pair_links_path};

/// Default [`MergeConfig::min_links`]: 2.
pub const DEFAULT_MIN_LINKS: usize = 2;

/// How sessions are linked and joined.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MergeConfig {
    /// Agreeing links, at distinct keyframes of each session, that join two sessions. Default
    /// [`DEFAULT_MIN_LINKS`] (2): one verified link can be a look-alike place; two at different
    /// places that imply one alignment rarely are.
    pub min_links: usize,
    /// Appearance candidates per keyframe of the later session. Default 3.
    pub appearance_per_keyframe: usize,
    /// Appearance candidates per pair of sessions, the closest descriptors first. Default 300.
    pub max_appearance_candidates: usize,
    /// Keyframes of the later session, spread along it, whose appearance candidates are tried
    /// first; the others' only when those did not join the two sessions. Default 30.
    pub first_pass_keyframes: usize,
    /// Place candidates per keyframe once two sessions are aligned. Default 2.
    pub place_per_keyframe: usize,
    /// Place candidates per pair of sessions. Default 300.
    pub max_place_candidates: usize,
    /// Prepared keyframes kept in memory per session \[bytes\]
    /// ([`crate::pipeline::PreparedFrame::idle_bytes`]); the others are prepared again, for the
    /// candidates verified at once, when needed. Default
    /// [`crate::loops::closure::DEFAULT_LOOP_MEMORY_BYTES`] (128 MiB).
    pub keyframe_memory_bytes: usize,
}

impl Default for MergeConfig {
    fn default() -> Self {
        Self {
            min_links: DEFAULT_MIN_LINKS,
            appearance_per_keyframe: 3,
            max_appearance_candidates: 300,
            first_pass_keyframes: 30,
            place_per_keyframe: 2,
            max_place_candidates: 300,
            keyframe_memory_bytes: crate::loops::closure::DEFAULT_LOOP_MEMORY_BYTES,
        }
    }
}

/// A join between two sessions: `a < b`, the alignment `world_a_from_world_b`, and its
/// strength (agreeing links) by which the grouping prefers it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Join {
    /// The lower session.
    pub a: usize,
    /// The higher session.
    pub b: usize,
    /// `world_a_from_world_b`.
    pub a_from_b: Isometry3<f64>,
    /// Agreeing links behind it.
    pub links: usize,
}

/// Sessions joined into one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Group {
    /// Its sessions, the root (the lowest index, whose world is the group's) first, then in the
    /// order they joined.
    pub members: Vec<usize>,
    /// Per member, `world_group_from_world_session` (the root's the identity).
    pub alignments: Vec<Isometry3<f64>>,
}

/// The groups of `sessions` sessions given the `joins` between them: from the lowest session not
/// yet grouped, the strongest join from a member to a session outside is added until none is
/// left (a maximum spanning tree, ties to lower indices); each member's alignment composes the
/// joins on its way from the root. Every session is in exactly one group.
#[must_use]
pub fn group_sessions(sessions: usize, joins: &[Join]) -> Vec<Group> {
    let mut grouped = vec![false; sessions];
    let mut groups = Vec::new();
    for root in 0..sessions {
        if grouped[root] {
            continue;
        }
        grouped[root] = true;
        let mut group = Group {
            members: vec![root],
            alignments: vec![Isometry3::identity()],
        };
        loop {
            // (strength, member index in group, new session, member_from_new)
            let mut best: Option<(usize, usize, usize, Isometry3<f64>)> = None;
            for j in joins {
                let step = match (grouped[j.a], grouped[j.b]) {
                    (true, false) => group
                        .members
                        .iter()
                        .position(|&m| m == j.a)
                        .map(|m| (m, j.b, j.a_from_b)),
                    (false, true) => group
                        .members
                        .iter()
                        .position(|&m| m == j.b)
                        .map(|m| (m, j.a, j.a_from_b.inverse())),
                    _ => None,
                };
                let Some((m, new, member_from_new)) = step else {
                    continue;
                };
                let better = best
                    .as_ref()
                    .is_none_or(|b| j.links > b.0 || (j.links == b.0 && (new, m) < (b.2, b.1)));
                if better {
                    best = Some((j.links, m, new, member_from_new));
                }
            }
            let Some((_, m, new, member_from_new)) = best else {
                break;
            };
            grouped[new] = true;
            let alignment = group.alignments[m] * member_from_new;
            group.members.push(new);
            group.alignments.push(alignment);
        }
        groups.push(group);
    }
    groups
}
