//! Links between sessions: the candidates (by appearance, then by place once two sessions are
//! aligned), the alignment a verified link implies, and which verified links agree with each
//! other. Pure: poses and descriptors in, indices out.
//!
//! A link joins frame `frame_a` of session `a` and frame `frame_b` of session `b` with the
//! relative pose their registration measured, `a_from_b` (`p_a = a_from_b · p_b`, both in their
//! sensor frames). With each session's trajectory in its own world (its first frame), a link
//! implies the alignment of the two worlds, `world_a_from_world_b = T_a · a_from_b · T_b⁻¹`.
//! Two right links imply the same alignment up to the sessions' drift between them; a link to a
//! look-alike place implies another one. As PCM judges loops (Mangelson et al. 2018), the links
//! kept between two sessions are the largest set that agree pairwise ([`maximum_clique`]).

use nalgebra::{Isometry3, Matrix6};

use crate::loops::{Descriptor, maximum_clique};

/// How a link's candidate was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LinkSource {
    /// The two keyframes' descriptors were close, whatever the sessions' poses.
    Appearance,
    /// Once the sessions were aligned, the two keyframes were near each other.
    Place,
}

/// A verified link between two sessions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionLink {
    /// Session of the first end (the lower index).
    pub a: usize,
    /// Its frame (index into the session's trajectory).
    pub frame_a: usize,
    /// Session of the second end.
    pub b: usize,
    /// Its frame.
    pub frame_b: usize,
    /// `frame_b`'s sensor pose in `frame_a`'s sensor frame (`p_a = a_from_b · p_b`) \[m\].
    pub a_from_b: Isometry3<f64>,
    /// The registration's information on the right perturbation of `a_from_b` (rotation first,
    /// then translation; [`crate::odometry::uncertainty`]), `None` without a measured Hessian.
    pub information: Option<Matrix6<f64>>,
    /// RANSAC inliers of the registration.
    pub inliers: usize,
    /// How the candidate was found.
    pub found_by: LinkSource,
}

impl SessionLink {
    /// The alignment the link implies: `world_a_from_world_b = poses_a[frame_a] · a_from_b ·
    /// poses_b[frame_b]⁻¹`, with `poses_*` each session's `world_from_sensor`.
    #[must_use]
    pub fn alignment(
        &self,
        poses_a: &[Isometry3<f64>],
        poses_b: &[Isometry3<f64>],
    ) -> Isometry3<f64> {
        poses_a[self.frame_a] * self.a_from_b * poses_b[self.frame_b].inverse()
    }
}

/// When two links between the same sessions agree: link `j`'s relative pose, predicted from the
/// alignment link `i` implies, is within `tolerance_m + drift_fraction · path` and
/// `tolerance_deg + drift_deg_per_m · path` of what `j` measured, both ways, where `path` is the
/// path length between the two links' ends, summed over both sessions \[m\].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct AgreementConfig {
    /// Translation tolerance at no path between the links \[m\].
    pub tolerance_m: f64,
    /// Rotation tolerance at no path \[deg\].
    pub tolerance_deg: f64,
    /// Translation tolerance per metre of path (the odometry's relative drift).
    pub drift_fraction: f64,
    /// Rotation tolerance per metre of path \[deg/m\].
    pub drift_deg_per_m: f64,
}

impl AgreementConfig {
    /// The defaults for a voxel of `voxel_m` metres: 8 voxels and 3°, plus 2 % of the path and
    /// 1° per 50 voxels of path (the loop search's place radius and drift,
    /// [`crate::loops::LoopConfig::for_voxel`]).
    #[must_use]
    pub fn for_voxel(voxel_m: f64) -> Self {
        Self {
            tolerance_m: 8.0 * voxel_m,
            tolerance_deg: 3.0,
            drift_fraction: 0.02,
            drift_deg_per_m: 1.0 / (50.0 * voxel_m),
        }
    }
}

/// One session's trajectory as links see it: `world_from_sensor` per frame and the path length
/// to each frame \[m\] ([`crate::evaluate::path_distances`]).
#[derive(Debug, Clone, Copy)]
pub struct Track<'a> {
    /// Poses, one per frame.
    pub poses: &'a [Isometry3<f64>],
    /// Path length from the first frame to each \[m\].
    pub travelled_m: &'a [f64],
}

/// Whether links `i` and `j` (between the same two sessions, `tracks[i.a]` and `tracks[i.b]`)
/// agree by `config`.
#[must_use]
pub fn links_agree(
    i: &SessionLink,
    j: &SessionLink,
    tracks: &[Track<'_>],
    config: &AgreementConfig,
) -> bool {
    let (ta, tb) = (&tracks[i.a], &tracks[i.b]);
    let path = (ta.travelled_m[i.frame_a] - ta.travelled_m[j.frame_a]).abs()
        + (tb.travelled_m[i.frame_b] - tb.travelled_m[j.frame_b]).abs();
    let max_m = config.tolerance_m + config.drift_fraction * path;
    let max_deg = config.tolerance_deg + config.drift_deg_per_m * path;
    let predicts = |from: &SessionLink, to: &SessionLink| {
        let align = from.alignment(ta.poses, tb.poses);
        let predicted = ta.poses[to.frame_a].inverse() * align * tb.poses[to.frame_b];
        let e = to.a_from_b.inverse() * predicted;
        e.translation.vector.norm() <= max_m && e.rotation.angle().to_degrees() <= max_deg
    };
    predicts(i, j) && predicts(j, i)
}

/// The links between sessions `a` and `b` kept as agreeing: indices into `links` of the largest
/// set of links between them that agree pairwise ([`links_agree`]; ties broken towards more
/// inliers), in increasing order. Empty when there is no link between them.
#[must_use]
pub fn agreeing_links(
    links: &[SessionLink],
    (a, b): (usize, usize),
    tracks: &[Track<'_>],
    config: &AgreementConfig,
) -> Vec<usize> {
    let between: Vec<usize> = (0..links.len())
        .filter(|&k| links[k].a == a && links[k].b == b)
        .collect();
    let adjacent: Vec<Vec<bool>> = between
        .iter()
        .map(|&i| {
            between
                .iter()
                .map(|&j| i == j || links_agree(&links[i], &links[j], tracks, config))
                .collect()
        })
        .collect();
    // Lower rank first: more inliers.
    let rank: Vec<f64> = between
        .iter()
        .map(|&k| -(links[k].inliers as f64))
        .collect();
    maximum_clique(&adjacent, &rank)
        .into_iter()
        .map(|v| between[v])
        .collect()
}

/// Candidates by appearance between two sessions' keyframes: for each keyframe of `b` (index
/// into `descriptors_b`), the `per_query` keyframes of `a` with the closest descriptors; of
/// those, the `max_total` closest pairs overall. Returns `(keyframe_a, keyframe_b)` index pairs,
/// closest first (ties: lower indices first).
#[must_use]
pub fn appearance_candidates(
    descriptors_a: &[Descriptor],
    descriptors_b: &[Descriptor],
    per_query: usize,
    max_total: usize,
) -> Vec<(usize, usize)> {
    let mut all: Vec<(f64, usize, usize)> = Vec::new();
    for (kb, db) in descriptors_b.iter().enumerate() {
        let mut near: Vec<(f64, usize, usize)> = descriptors_a
            .iter()
            .enumerate()
            .map(|(ka, da)| (da.distance(db), ka, kb))
            .filter(|(d, _, _)| d.is_finite())
            .collect();
        near.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
        near.truncate(per_query);
        all.extend(near);
    }
    all.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.2.cmp(&y.2)).then(x.1.cmp(&y.1)));
    all.truncate(max_total);
    all.into_iter().map(|(_, ka, kb)| (ka, kb)).collect()
}

/// Candidates by place between two aligned sessions: pairs of keyframes (`positions_a`,
/// `positions_b`: their sensor origins in one world \[m\]) within `radius_m` of each other, for
/// each keyframe of `b` its `per_query` nearest, `(keyframe_a, keyframe_b)` in increasing `b`,
/// then distance. Brute force: sessions' keyframes number in the hundreds.
#[must_use]
pub fn place_candidates(
    positions_a: &[nalgebra::Point3<f64>],
    positions_b: &[nalgebra::Point3<f64>],
    radius_m: f64,
    per_query: usize,
) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    for (kb, pb) in positions_b.iter().enumerate() {
        let mut near: Vec<(f64, usize)> = positions_a
            .iter()
            .enumerate()
            .map(|(ka, pa)| ((pa - pb).norm(), ka))
            .filter(|(d, _)| *d <= radius_m)
            .collect();
        near.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
        out.extend(near.into_iter().take(per_query).map(|(_, ka)| (ka, kb)));
    }
    out
}
