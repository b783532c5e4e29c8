//! The multi-session pose graph: the sessions of one group, each its trajectory as a chain of
//! relative poses, joined by the links kept between them, solved jointly.
//!
//! Anchor nodes (Kim, Kaess et al., ICRA 2010; `../shared/docs/DESIGN.md` §9) give each session
//! one extra pose, `world_from_session`, that links constrain. Here each session's poses are put
//! into the group's world by the alignment the links found and become the graph's nodes
//! directly; that is the same graph with each anchor folded into its session's poses. The gauge
//! is the root session's first pose, held fixed by the solver (node 0).
//!
//! Edges: each session's consecutive frames, with the relative pose of its own best trajectory
//! (loop-closed where `register` closed loops) and [`crate::loops::LoopConfig::odometry_sigma_m`]
//! / `odometry_sigma_deg`; each link, with its registration's information scaled as a loop's
//! ([`LOOP_INFORMATION_SCALE`]) on top of the prior [`edge_prior`]. Every edge is robust (the
//! Cauchy kernel, annealed as [`solve_annealed`] does).
//!
//! NOTE: a session's steps get one deviation each, not the per-frame covariance `register`
//! measured: its best trajectory is loop-closed already, and its steps after the solve no longer
//! have the odometry's uncertainty.

use nalgebra::Isometry3;

use super::links::SessionLink;
use crate::graph::{Edge, PoseGraph};
use crate::loops::{LOOP_INFORMATION_SCALE, LoopConfig, edge_prior, solve_annealed};
use crate::odometry::uncertainty::diagonal_information;
use crate::{Error, Result};

/// The solved group.
#[derive(Debug, Clone)]
pub struct GroupSolution {
    /// Per member session (in the order given), its `world_from_sensor` per frame in the group's
    /// world.
    pub poses: Vec<Vec<Isometry3<f64>>>,
    /// Robust weight of each link at the optimum, in the order given.
    pub link_weights: Vec<f64>,
    /// Solver iterations, summed over the annealing.
    pub iterations: usize,
}

/// Solves the group `members` (session indices, root first) of `tracks` (each session's
/// `world_from_sensor` per frame, in its own world), each member put into the group's world by
/// `alignments[m]` (`world_group_from_world_session`; the root's is the identity), with `links`
/// between members. `config` gives the steps' deviations and the kernel scale.
///
/// # Errors
/// [`Error::InvalidInput`] when a link names a session outside the group or a frame outside its
/// trajectory, or the lengths differ; the solver's errors.
pub fn solve_group(
    tracks: &[&[Isometry3<f64>]],
    members: &[usize],
    alignments: &[Isometry3<f64>],
    links: &[SessionLink],
    config: &LoopConfig,
) -> Result<GroupSolution> {
    if members.len() != alignments.len() {
        return Err(Error::InvalidInput(format!(
            "solve_group: {} members but {} alignments",
            members.len(),
            alignments.len()
        )));
    }
    let mut offset = vec![usize::MAX; tracks.len()];
    let mut poses = Vec::new();
    for (m, &s) in members.iter().enumerate() {
        offset[s] = poses.len();
        poses.extend(tracks[s].iter().map(|p| alignments[m] * p));
    }
    let step = diagonal_information(config.odometry_sigma_m, config.odometry_sigma_deg);
    let prior = edge_prior(config);
    let fallback = diagonal_information(config.loop_sigma_m, config.loop_sigma_deg);
    let mut edges = Vec::new();
    for &s in members {
        for k in 1..tracks[s].len() {
            edges.push(Edge {
                from: offset[s] + k - 1,
                to: offset[s] + k,
                measurement: tracks[s][k - 1].inverse() * tracks[s][k],
                information: step,
                robust: true,
            });
        }
    }
    for l in links {
        let node = |s: usize, f: usize| {
            (offset.get(s).is_some_and(|&o| o != usize::MAX) && f < tracks[s].len())
                .then(|| offset[s] + f)
        };
        let (Some(from), Some(to)) = (node(l.a, l.frame_a), node(l.b, l.frame_b)) else {
            return Err(Error::InvalidInput(format!(
                "solve_group: link {}:{} – {}:{} outside the group",
                l.a, l.frame_a, l.b, l.frame_b
            )));
        };
        let information = match l.information {
            Some(omega) if omega.iter().all(|v| v.is_finite()) => {
                omega * LOOP_INFORMATION_SCALE + prior
            }
            _ => fallback,
        };
        edges.push(Edge {
            from,
            to,
            measurement: l.a_from_b,
            information,
            robust: true,
        });
    }
    let steps = edges.len() - links.len();
    let solution = if links.is_empty() {
        None
    } else {
        Some(solve_annealed(
            PoseGraph { poses, edges },
            config.kernel_scale,
        )?)
    };
    let (all, link_weights, iterations) = match solution {
        Some(s) => (s.poses, s.edge_weights[steps..].to_vec(), s.iterations),
        None => (
            members
                .iter()
                .zip(alignments)
                .flat_map(|(&s, a)| tracks[s].iter().map(move |p| a * p))
                .collect(),
            Vec::new(),
            0,
        ),
    };
    let per_member = members
        .iter()
        .map(|&s| all[offset[s]..offset[s] + tracks[s].len()].to_vec())
        .collect();
    Ok(GroupSolution {
        poses: per_member,
        link_weights,
        iterations,
    })
}

/// A frame of a log measured in a prior map's world (a link to the prior, whose poses are held):
/// `world_from_sensor` of frame `frame`, with the information of the registration on its right
/// perturbation (`None`: a loop's default deviations).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fix {
    /// The log's frame.
    pub frame: usize,
    /// Its sensor pose in the prior's world.
    pub world_from_sensor: Isometry3<f64>,
    /// See [`Fix`].
    pub information: Option<nalgebra::Matrix6<f64>>,
}

/// A log's trajectory `track` (its own world) solved into a prior's world that stays fixed: the
/// log's frames start at `alignment · track` and are joined by its steps (as in
/// [`solve_group`]); each fix ties its frame to the prior's world (an edge from a fixed node at
/// the prior's origin, so the right perturbation and its information carry over). Returns the
/// poses in the prior's world and each fix's robust weight.
///
/// # Errors
/// [`Error::InvalidInput`] for a fix outside the track; the solver's errors.
pub fn solve_in_prior(
    track: &[Isometry3<f64>],
    alignment: &Isometry3<f64>,
    fixes: &[Fix],
    config: &LoopConfig,
) -> Result<GroupSolution> {
    if let Some(f) = fixes.iter().find(|f| f.frame >= track.len()) {
        return Err(Error::InvalidInput(format!(
            "solve_in_prior: fix of frame {} outside a track of {} frames",
            f.frame,
            track.len()
        )));
    }
    let mut poses = vec![Isometry3::identity()];
    poses.extend(track.iter().map(|p| alignment * p));
    let step = diagonal_information(config.odometry_sigma_m, config.odometry_sigma_deg);
    let prior = edge_prior(config);
    let fallback = diagonal_information(config.loop_sigma_m, config.loop_sigma_deg);
    let mut edges: Vec<Edge> = (1..track.len())
        .map(|k| Edge {
            from: k,
            to: k + 1,
            measurement: track[k - 1].inverse() * track[k],
            information: step,
            robust: true,
        })
        .collect();
    let steps = edges.len();
    edges.extend(fixes.iter().map(|f| Edge {
        from: 0,
        to: f.frame + 1,
        measurement: f.world_from_sensor,
        information: match f.information {
            Some(omega) if omega.iter().all(|v| v.is_finite()) => {
                omega * LOOP_INFORMATION_SCALE + prior
            }
            _ => fallback,
        },
        robust: true,
    }));
    if fixes.is_empty() {
        return Err(Error::InvalidInput(
            "solve_in_prior: no fix ties the log to the prior".into(),
        ));
    }
    let s = solve_annealed(PoseGraph { poses, edges }, config.kernel_scale)?;
    Ok(GroupSolution {
        poses: vec![s.poses[1..].to_vec()],
        link_weights: s.edge_weights[steps..].to_vec(),
        iterations: s.iterations,
    })
}
