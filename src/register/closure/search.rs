//! The loop stage's search: the keyframes and the first candidates of a trajectory, and the
//! accepted loops among verified candidates.

use nalgebra::Isometry3;

use super::super::frames::Estimate;
use super::Verified;
use super::record::loop_information;
use crate::Result;
use crate::loops::{
    Candidate, Keyframe, LoopConfig, LoopEdge, Source, find_candidates, select_keyframes,
};

/// The keyframes of the odometry's trajectory (those with a descriptor).
pub(super) fn keyframes_of(
    estimates: &[Estimate],
    poses: &[Isometry3<f64>],
    travelled: &[f64],
    config: &LoopConfig,
) -> Result<Vec<Keyframe>> {
    Ok(select_keyframes(poses, travelled, &config.keyframes)?
        .into_iter()
        .filter_map(|k| {
            let e = &estimates[k];
            Some(Keyframe {
                frame: k,
                stamp_ns: u64::try_from(e.stamp_ns()).unwrap_or(0),
                pose: e.world_from_frame,
                travelled_m: travelled[k],
                descriptor: e.descriptor?,
            })
        })
        .collect())
}

/// The first search's candidates, in frames (the search's indices are keyframes'), the seams'
/// first.
pub(super) fn first_candidates(
    estimates: &[Estimate],
    poses: &[Isometry3<f64>],
    keyframes: &[Keyframe],
    seams: &[(usize, usize)],
    config: &LoopConfig,
) -> Result<Vec<Candidate>> {
    let mut candidates: Vec<Candidate> = seams
        .iter()
        .filter(|&&(q, m)| m < q && q < estimates.len())
        .map(|&(q, m)| Candidate {
            query: q,
            matched: m,
            by: Source::Seam,
            odometry_distance_m: (poses[q].translation.vector - poses[m].translation.vector).norm(),
            descriptor_distance: match (&estimates[q].descriptor, &estimates[m].descriptor) {
                (Some(a), Some(b)) => a.distance(b),
                // A frame without features has no descriptor: null on `/mireg/loops`.
                _ => f64::NAN,
            },
        })
        .collect();
    let searched = find_candidates(keyframes, &config.candidates)?
        .into_iter()
        .map(|c| Candidate {
            query: keyframes[c.query].frame,
            matched: keyframes[c.matched].frame,
            ..c
        })
        .filter(|c| !seams.contains(&(c.query, c.matched)))
        .collect::<Vec<_>>();
    candidates.extend(searched);
    Ok(candidates)
}

/// The accepted loops among `candidates`, in their order.
pub(super) fn accepted_loops<'c>(
    candidates: impl Iterator<Item = &'c Candidate>,
    verified: &Verified,
) -> Vec<LoopEdge> {
    candidates
        .filter_map(|c| {
            let (v, _) = verified.get(&(c.query, c.matched))?;
            v.accepted.then(|| LoopEdge {
                query: c.query,
                matched: c.matched,
                match_from_query: v.match_from_query.expect("accepted loops have a pose"),
                information: loop_information(v),
            })
        })
        .collect()
}
