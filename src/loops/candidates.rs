//! Loop candidates over a whole log (offline: every keyframe is known): pairs of keyframes that
//! may see the same place, found by odometry position ([`Source::Place`]) and by appearance
//! ([`Source::Appearance`]). They are only candidates: registration and a robust back-end decide.
//!
//! Cost for n keyframes: place search builds a kd-tree over the positions (O(n log n)) and
//! queries one ball per keyframe, of radius at most [`CandidateConfig::max_place_radius_m`];
//! appearance search compares each keyframe with every earlier one, O(n²) distances of 65
//! floats (10⁴ keyframes: 5 · 10⁷ distances). Measured on 10⁴ synthetic keyframes 0.5 m apart
//! on 16 laps of a 50 m circle (dev profile, this repository's 2-core machine): 3.0 s on one
//! thread, 1.6 s on two (parallel over queries). Beyond ~10⁴ keyframes the appearance scan wants
//! an index (a kd-tree over the 65-float descriptors, as Scan Context's ring keys).

use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

use super::descriptor::Descriptor;
use crate::geometry::KdTree;
use crate::{Error, Result};

/// One keyframe of the log.
#[derive(Debug, Clone, PartialEq)]
pub struct Keyframe {
    /// Index of the frame in the log.
    pub frame: usize,
    /// Stamp \[ns since the epoch\].
    pub stamp_ns: u64,
    /// Odometry `world_from_sensor` (translation in metres).
    pub pose: Isometry3<f64>,
    /// Path length from the log's start \[m\] (non-decreasing along the log).
    pub travelled_m: f64,
    /// Appearance of the keyframe.
    pub descriptor: Descriptor,
}

/// Which search found a candidate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Source {
    /// Odometry positions close, allowing for drift.
    Place,
    /// Descriptors close.
    Appearance,
    /// Both searches.
    Both,
    /// Not searched: a stitched segment's first output frame against the frame just before the
    /// segment's window, which its young local map never held (`mireg stitch`).
    Seam,
}

/// A loop candidate: keyframe `query` may see what the earlier keyframe `matched` saw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    /// Index of the later keyframe in the slice given to [`find_candidates`].
    pub query: usize,
    /// Index of the earlier keyframe (`matched < query`).
    pub matched: usize,
    /// The search(es) that found it.
    pub by: Source,
    /// Distance between the two odometry positions \[m\].
    pub odometry_distance_m: f64,
    /// [`Descriptor::distance`] of the two keyframes.
    pub descriptor_distance: f64,
}

/// Knobs of [`find_candidates`]. The defaults fit a vehicle LiDAR log with keyframes about a
/// metre apart; a room-scale RGB-D log wants radii and separations about ten times smaller.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CandidateConfig {
    /// Place radius at zero path between the two keyframes \[m\]. Default 3.
    pub place_radius_m: f64,
    /// Growth of the place radius per metre of path between the two keyframes \[m/m\]: the
    /// odometry drift allowed for. Default 0.02 (2 % of the path).
    pub drift_fraction: f64,
    /// The place radius stops growing here \[m\]: beyond it, only appearance can find the
    /// revisit (and the ball queries stay small on long logs). Default 30.
    pub max_place_radius_m: f64,
    /// Candidates, by place and by appearance, need at least this much path between them \[m\],
    /// so that a keyframe is not matched with its neighbours along the path (a LiDAR scan shares
    /// most of what it sees with the scans a few metres back: registering them is the odometry's
    /// work, not a loop's). Default 20.
    pub min_path_separation_m: f64,
    /// Both searches need the two keyframes' odometry positions at most this fraction of the
    /// path between them apart \[m/m\]: the sensor came back towards the place instead of going
    /// on along a line from it. Keyframes of a straight drive 20 m apart see each other's far
    /// field, which the odometry related already; an edge between them closes nothing and only
    /// moves a trajectory that has no loop. 1 turns the test off. Default 0.8.
    ///
    /// Measured (`register` on the four loop logs and the fixture, 2026-12-05): every accepted
    /// revisit had a ratio of at most 0.64 (an appearance match of micro211 out-and-back), most
    /// under 0.1; the three loops found on KAIST03, a straight drive, had 1.00 (8–9.6 m apart
    /// after 8–9.6 m of path).
    pub max_distance_per_path: f64,
    /// Both searches need the two keyframes at least this many log frames apart
    /// ([`Keyframe::frame`]). Default 50.
    pub min_frame_separation: usize,
    /// Place candidates kept per query, nearest in odometry first. Default 3.
    pub max_place_per_query: usize,
    /// Appearance candidates kept per query, nearest in descriptor distance first (the k of
    /// k-nearest). Default 3.
    pub appearance_k: usize,
    /// Appearance candidates need a descriptor distance at most this. Default
    /// [`DEFAULT_MAX_DESCRIPTOR_DISTANCE`] (0.1).
    pub max_descriptor_distance: f64,
    /// Appearance candidates need a descriptor distance at most this fraction of the median
    /// distance from the query to all eligible earlier keyframes: a match must stand out from
    /// the log's typical keyframe. 1 turns the test off. Default 0.7.
    ///
    /// Measured (`examples/loop_descriptors.rs`, odd frames against even ones): the best true
    /// match of a query lies at a median 0.52 × (max 0.60) the median distance on KAIST03 (max
    /// 0.68 and 0.76 with the queries turned by yaw or roll), and at 0.20 × (max 0.49) on
    /// ICL-NUIM. With the 0.1 cap, 0.7 passes the best true match of 10/10, 10/10 and 8/10
    /// KAIST03 queries (and 5/90, 6/90, 4/90 false pairs) and of 35/35 ICL queries (75/1011
    /// false pairs); 0.5 passes 4/10, 3/10, 2/10 and 35/35 (1/90, 0/90, 0/90, 21/1011).
    ///
    /// NOTE: Lowe's ratio test compares the best with the second best; a place seen several
    /// times has several good matches, so the reference here is the median instead.
    pub appearance_ratio: f64,
    /// Candidates kept per query after merging both searches. Default 5.
    pub max_per_query: usize,
}

/// Default [`CandidateConfig::max_descriptor_distance`]: 0.1. Measured with
/// `examples/loop_descriptors.rs`: true pairs average 0.036 on KAIST03 and 0.064 on ICL-NUIM,
/// false ones 0.071 and 0.144; the cap only bites where the median test is loose.
pub const DEFAULT_MAX_DESCRIPTOR_DISTANCE: f64 = 0.1;

impl Default for CandidateConfig {
    fn default() -> Self {
        Self {
            place_radius_m: 3.0,
            drift_fraction: 0.02,
            max_place_radius_m: 30.0,
            min_path_separation_m: 20.0,
            max_distance_per_path: 0.8,
            min_frame_separation: 50,
            max_place_per_query: 3,
            appearance_k: 3,
            max_descriptor_distance: DEFAULT_MAX_DESCRIPTOR_DISTANCE,
            appearance_ratio: 0.7,
            max_per_query: 5,
        }
    }
}

impl CandidateConfig {
    fn check(&self) -> Result<()> {
        for (name, x) in [
            ("place_radius_m", self.place_radius_m),
            ("drift_fraction", self.drift_fraction),
            ("max_place_radius_m", self.max_place_radius_m),
            ("min_path_separation_m", self.min_path_separation_m),
            ("max_distance_per_path", self.max_distance_per_path),
            ("max_descriptor_distance", self.max_descriptor_distance),
            ("appearance_ratio", self.appearance_ratio),
        ] {
            if !(x.is_finite() && x >= 0.0) {
                return Err(Error::InvalidInput(format!(
                    "{name} must be finite and >= 0, got {x}"
                )));
            }
        }
        Ok(())
    }

    /// Whether two keyframes `distance_m` apart in the odometry after `path_m` of path between
    /// them may be a revisit: `distance_m ≤ max_distance_per_path · path_m`.
    pub fn revisits(&self, distance_m: f64, path_m: f64) -> bool {
        distance_m <= self.max_distance_per_path * path_m
    }

    /// The place radius \[m\] for two keyframes `path_m` of path apart:
    /// `min(place_radius_m + drift_fraction · path_m, max(place_radius_m, max_place_radius_m))`.
    pub fn place_radius_for(&self, path_m: f64) -> f64 {
        (self.place_radius_m + self.drift_fraction * path_m.max(0.0))
            .min(self.max_place_radius_m.max(self.place_radius_m))
    }
}

/// Loop candidates of a whole log. `keyframes` are in log order (`frame` increasing,
/// `travelled_m` non-decreasing). For each query keyframe q, against earlier keyframes m with
/// `frame_q − frame_m ≥ min_frame_separation`:
/// - by place: `‖t_q − t_m‖ ≤` [`CandidateConfig::place_radius_for`]`(travelled_q − travelled_m)`
///   and `travelled_q − travelled_m ≥ min_path_separation_m`; the `max_place_per_query` nearest;
/// - by appearance, among the m with `travelled_q − travelled_m ≥ min_path_separation_m` too:
///   descriptor distance `≤ max_descriptor_distance` and `≤ appearance_ratio` × the median over
///   those m; the `appearance_k` nearest, however far the odometry puts them;
/// - both: only pairs that may be revisits ([`CandidateConfig::revisits`]).
///
/// A pair found by both is one [`Source::Both`] candidate. Per query the merged list is ranked
/// `Both` first, then by descriptor distance, then by the earlier `matched`, and cut to
/// `max_per_query`. The result is ordered by `query`, then by that rank; it does not depend on the
/// thread count. Ties in distance go to the smaller index.
///
/// # Errors
/// [`Error::InvalidInput`] for a negative or non-finite knob, keyframes out of log order, or a
/// non-finite position or path length.
pub fn find_candidates(keyframes: &[Keyframe], config: &CandidateConfig) -> Result<Vec<Candidate>> {
    config.check()?;
    if keyframes.iter().any(|k| !k.travelled_m.is_finite()) {
        return Err(Error::InvalidInput("non-finite travelled_m".into()));
    }
    for (k, w) in keyframes.windows(2).enumerate() {
        if w[1].frame <= w[0].frame || w[1].travelled_m < w[0].travelled_m {
            return Err(Error::InvalidInput(format!(
                "keyframes {k} and {} are out of log order (frames {} → {}, path {} → {} m)",
                k + 1,
                w[0].frame,
                w[1].frame,
                w[0].travelled_m,
                w[1].travelled_m
            )));
        }
    }
    let positions: Vec<Point3<f64>> = keyframes
        .iter()
        .map(|k| Point3::from(k.pose.translation.vector))
        .collect();
    let tree = KdTree::new(&positions)?;
    let per_query: Vec<Vec<Candidate>> = (0..keyframes.len())
        .into_par_iter()
        .map(|q| {
            let eligible = eligible_count(keyframes, q, config.min_frame_separation);
            let place = by_place(keyframes, &positions, &tree, q, eligible, config);
            let far = far_count(keyframes, q, config.min_path_separation_m);
            let appearance = by_appearance(keyframes, q, eligible.min(far), config);
            merge(keyframes, q, &place, &appearance, config.max_per_query)
        })
        .collect();
    Ok(per_query.into_iter().flatten().collect())
}

/// Number of keyframes before `q` at least `min_frames` log frames earlier (a prefix, since
/// frames increase).
fn eligible_count(keyframes: &[Keyframe], q: usize, min_frames: usize) -> usize {
    let frame_q = keyframes[q].frame;
    keyframes[..q].partition_point(|k| frame_q - k.frame >= min_frames)
}

/// Number of keyframes before `q` at least `min_path_m` of path earlier (a prefix, since the
/// path grows).
fn far_count(keyframes: &[Keyframe], q: usize, min_path_m: f64) -> usize {
    let travelled_q = keyframes[q].travelled_m;
    keyframes[..q].partition_point(|k| travelled_q - k.travelled_m >= min_path_m)
}

/// `(matched, odometry distance)` of the place candidates of `q`, nearest first.
fn by_place(
    keyframes: &[Keyframe],
    positions: &[Point3<f64>],
    tree: &KdTree,
    q: usize,
    eligible: usize,
    config: &CandidateConfig,
) -> Vec<(usize, f64)> {
    if eligible == 0 || config.max_place_per_query == 0 {
        return Vec::new();
    }
    let travelled_q = keyframes[q].travelled_m;
    let radius = config.place_radius_for(travelled_q - keyframes[0].travelled_m);
    // `within_radius` is strict; the test below is inclusive.
    let ball = tree.within_radius(
        &positions[q],
        radius * (1.0 + 1e-12) + 1e-12,
        positions.len(),
    );
    let mut out: Vec<(usize, f64)> = ball
        .into_iter()
        .filter(|n| n.index < eligible)
        .filter_map(|n| {
            let path = travelled_q - keyframes[n.index].travelled_m;
            let d = n.distance_sq.sqrt();
            (path >= config.min_path_separation_m
                && d <= config.place_radius_for(path)
                && config.revisits(d, path))
            .then_some((n.index, d))
        })
        .collect();
    // The tree sorts by distance with ties by index; keep that order.
    out.truncate(config.max_place_per_query);
    out
}

/// `(matched, descriptor distance)` of the appearance candidates of `q`, nearest first.
fn by_appearance(
    keyframes: &[Keyframe],
    q: usize,
    eligible: usize,
    config: &CandidateConfig,
) -> Vec<(usize, f64)> {
    if eligible == 0 || config.appearance_k == 0 {
        return Vec::new();
    }
    let dq = &keyframes[q].descriptor;
    let mut all: Vec<(usize, f64)> = keyframes[..eligible]
        .iter()
        .enumerate()
        .map(|(m, k)| (m, dq.distance(&k.descriptor)))
        .collect();
    let mut distances: Vec<f64> = all.iter().map(|&(_, d)| d).collect();
    let mid = distances.len() / 2;
    let median = *distances.select_nth_unstable_by(mid, f64::total_cmp).1;
    let limit = config
        .max_descriptor_distance
        .min(config.appearance_ratio * median);
    let kq = &keyframes[q];
    all.retain(|&(m, d)| {
        let km = &keyframes[m];
        let apart = (kq.pose.translation.vector - km.pose.translation.vector).norm();
        d <= limit && config.revisits(apart, kq.travelled_m - km.travelled_m)
    });
    all.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
    all.truncate(config.appearance_k);
    all
}

fn merge(
    keyframes: &[Keyframe],
    q: usize,
    place: &[(usize, f64)],
    appearance: &[(usize, f64)],
    max_per_query: usize,
) -> Vec<Candidate> {
    let kq = &keyframes[q];
    let make = |m: usize, by: Source| {
        let km = &keyframes[m];
        Candidate {
            query: q,
            matched: m,
            by,
            odometry_distance_m: (kq.pose.translation.vector - km.pose.translation.vector).norm(),
            descriptor_distance: kq.descriptor.distance(&km.descriptor),
        }
    };
    let mut out: Vec<Candidate> = place
        .iter()
        .map(|&(m, _)| {
            let both = appearance.iter().any(|&(a, _)| a == m);
            make(m, if both { Source::Both } else { Source::Place })
        })
        .collect();
    for &(m, _) in appearance {
        if !place.iter().any(|&(p, _)| p == m) {
            out.push(make(m, Source::Appearance));
        }
    }
    out.sort_by(|a, b| {
        (b.by == Source::Both)
            .cmp(&(a.by == Source::Both))
            .then(a.descriptor_distance.total_cmp(&b.descriptor_distance))
            .then(a.matched.cmp(&b.matched))
    });
    out.truncate(max_per_query);
    out
}
