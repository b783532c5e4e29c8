//! The target of ICP: points, their normals (given, or estimated when first needed) and the
//! search structures built over them once.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};

use super::{IcpConfig, correspondence_grid};
use crate::geometry::radius_grid::GridStorage;
use crate::geometry::{NormalEstimate, RadiusGrid};
use crate::{Error, Result};

/// The share of a target's points, asked for their deferred normals at once, from which
/// [`IcpTarget::normals_at`] estimates them all: 0.5.
///
/// NOTE: a keyframe log's frame (KAIST03, 1 m apart) adds most of its points to the local map,
/// and loop closure then estimated the normals of the same cloud again, for all its points, when
/// it verified a loop against it (a third of the loop stage's CPU on KAIST03). Estimating them
/// all at the map's request costs little more and serves both; on a 10 Hz log, where a frame
/// adds a few per cent of its points, only those are estimated.
pub const ESTIMATE_ALL_FRACTION: f64 = 0.5;

/// All the normals of a target with deferred ones, once estimated (`None` if that failed).
type DeferredNormals = std::sync::OnceLock<Option<Vec<Vector3<f64>>>>;

/// Target points with a kd-tree built once, plus (for ICP) their normals.
pub struct IcpTarget {
    pub(super) points: Vec<Point3<f64>>,
    normals: Option<Vec<Vector3<f64>>>,
    /// Without given normals: how to estimate them, and all of them once asked for
    /// ([`IcpTarget::with_deferred_normals`]; `None` inside if that failed).
    deferred: Option<(NormalEstimate, DeferredNormals)>,
    /// Built on first use: ICP answers from a radius grid where it can, so a target that only
    /// serves ICP (a local map rebuilt every frame) never pays for the tree.
    tree: std::sync::OnceLock<ImmutableKdTree<f64, 3>>,
    /// The correspondence grid of the first search radius asked for, kept: a target that serves
    /// several ICP runs at one distance (a local map, refined from two starts and at two
    /// resolutions) buckets its points once.
    pub(super) grid: std::sync::OnceLock<(f64, Option<RadiusGrid>)>,
    /// Storage for the next grid ([`IcpTarget::from_storage`]), used once by the first.
    pub(super) spare: std::sync::Mutex<GridStorage>,
}

impl std::fmt::Debug for IcpTarget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("IcpTarget")
            .field("points", &self.points.len())
            .field("has_normals", &self.has_normals())
            .finish()
    }
}

/// One normal per point, all finite (unit, or zero for a point with no plane).
fn check_normals(points: &[Point3<f64>], normals: &[Vector3<f64>]) -> Result<()> {
    if normals.len() != points.len() {
        return Err(Error::InvalidInput(format!(
            "target has {} points but {} normals",
            points.len(),
            normals.len()
        )));
    }
    if let Some(i) = normals
        .iter()
        .position(|n| !n.iter().all(|c| c.is_finite()))
    {
        return Err(Error::InvalidInput(format!(
            "target normal {i} is not finite"
        )));
    }
    Ok(())
}

/// A target cloud is non-empty, finite and indexable by `u32`.
fn check_target_points(points: &[Point3<f64>]) -> Result<()> {
    if points.is_empty() {
        return Err(Error::InvalidInput("target cloud is empty".into()));
    }
    if points.len() > u32::MAX as usize {
        return Err(Error::InvalidInput(format!(
            "target cloud has {} points, more than u32::MAX",
            points.len()
        )));
    }
    if let Some(i) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(Error::InvalidInput(format!(
            "target point {i} is not finite"
        )));
    }
    Ok(())
}

impl IcpTarget {
    /// Builds the kd-tree over `points` and keeps unit `normals` (one per point; a zero one marks a
    /// point with no plane, matched point to point: see [`super`]) for
    /// point-to-plane ICP. Fails on an empty cloud, a length mismatch or non-finite values.
    pub fn new(points: &[Point3<f64>], normals: &[Vector3<f64>]) -> Result<Self> {
        check_normals(points, normals)?;
        let mut target = Self::points_only(points)?;
        target.normals = Some(normals.to_vec());
        Ok(target)
    }

    /// [`IcpTarget::new`] reusing `tree`, which must have been built over exactly `points` (e.g.
    /// for normal estimation): saves rebuilding the same tree.
    pub fn with_tree(
        points: &[Point3<f64>],
        normals: &[Vector3<f64>],
        tree: crate::geometry::KdTree,
    ) -> Result<Self> {
        if tree.len() != points.len() {
            return Err(Error::InvalidInput(format!(
                "kd-tree holds {} points but {} were given",
                tree.len(),
                points.len()
            )));
        }
        check_normals(points, normals)?;
        // KdTree::new has checked the points (finite, at most u32::MAX).
        let Some(tree) = tree.into_inner() else {
            return Err(Error::InvalidInput("target cloud is empty".into()));
        };
        Ok(Self {
            points: points.to_vec(),
            normals: Some(normals.to_vec()),
            deferred: None,
            tree: std::sync::OnceLock::from(tree),
            grid: std::sync::OnceLock::new(),
            spare: Default::default(),
        })
    }

    /// Builds the kd-tree over `points` without normals: enough for
    /// [`evaluate_registration`](super::evaluate_registration), not for ICP. Fails on an empty
    /// cloud or non-finite coordinates.
    pub fn points_only(points: &[Point3<f64>]) -> Result<Self> {
        check_target_points(points)?;
        Ok(Self {
            points: points.to_vec(),
            normals: None,
            deferred: None,
            tree: std::sync::OnceLock::new(),
            grid: std::sync::OnceLock::new(),
            spare: Default::default(),
        })
    }

    /// Builds now, instead of at the first ICP call, the search structure that ICP and
    /// [`evaluate_registration`](super::evaluate_registration) at `max_distance_m` \[m\] use
    /// (kept in the target), so that a caller can overlap its construction with other work.
    pub fn prepare_for_distance(&self, max_distance_m: f64) -> Result<()> {
        IcpConfig::new(max_distance_m).validate()?;
        correspondence_grid(self, max_distance_m).map(|_| ())
    }

    /// Takes the target apart for a rebuild in place ([`IcpTarget::from_storage`]): a target
    /// rebuilt every frame (a local map) allocates and faults in its megabytes once. Returns its
    /// points, given normals (empty without) and the storage of its correspondence grid (or the
    /// spare storage it was made with, if it built none).
    pub(crate) fn into_storage(mut self) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>, GridStorage) {
        let grid = match self.grid.take() {
            Some((_, Some(grid))) => grid.into_storage(),
            _ => self.spare.into_inner().unwrap_or_else(|e| e.into_inner()),
        };
        (self.points, self.normals.unwrap_or_default(), grid)
    }

    /// [`IcpTarget::new`] taking the vectors as they are (no copy), with `spare` as the storage
    /// of the next correspondence grid.
    pub(crate) fn from_storage(
        points: Vec<Point3<f64>>,
        normals: Vec<Vector3<f64>>,
        spare: GridStorage,
    ) -> Result<Self> {
        check_normals(&points, &normals)?;
        check_target_points(&points)?;
        Ok(Self {
            points,
            normals: Some(normals),
            deferred: None,
            tree: std::sync::OnceLock::new(),
            grid: std::sync::OnceLock::new(),
            spare: std::sync::Mutex::new(spare),
        })
    }

    /// Makes `grid`, over exactly this target's points at radius `max_distance_m`, the
    /// correspondence grid (as if [`IcpTarget::prepare_for_distance`] had built it). Fails if
    /// one is already set or the grid holds another number of points.
    pub(crate) fn set_grid(&mut self, max_distance_m: f64, grid: RadiusGrid) -> Result<()> {
        if grid.len() != self.points.len() {
            return Err(Error::InvalidInput(format!(
                "grid holds {} points, the target {}",
                grid.len(),
                self.points.len()
            )));
        }
        self.grid
            .set((max_distance_m, Some(grid)))
            .map_err(|_| Error::InvalidInput("target already has a correspondence grid".into()))
    }

    /// The heap this target holds now \[bytes\]: its points and normals (given, or estimated
    /// once asked for), and the kd-tree and correspondence grid where they have been built (the
    /// tree counted at 32 B a point: its leaves' coordinates and indices and its stems).
    pub fn heap_bytes(&self) -> usize {
        let point = std::mem::size_of::<Point3<f64>>();
        let normals = match (&self.normals, &self.deferred) {
            (Some(n), _) => n.capacity(),
            (None, Some((_, all))) => all.get().and_then(|n| n.as_ref()).map_or(0, Vec::capacity),
            (None, None) => 0,
        };
        let tree = self.tree.get().map_or(0, |_| self.points.len() * 32);
        (self.points.capacity() + normals) * point + tree + self.grid_bytes()
    }

    /// The heap of the correspondence grid \[bytes\], 0 until one is built.
    pub fn grid_bytes(&self) -> usize {
        match self.grid.get() {
            Some((_, Some(grid))) => grid.heap_bytes(),
            _ => 0,
        }
    }

    /// The heap of normals not estimated yet \[bytes\]: what the first point-to-plane ICP against
    /// this target adds for good (0 with normals given or already estimated).
    pub fn pending_normal_bytes(&self) -> usize {
        match &self.deferred {
            Some((_, all)) if self.normals.is_none() && all.get().is_none() => {
                self.points.len() * std::mem::size_of::<Vector3<f64>>()
            }
            _ => 0,
        }
    }

    /// Drops the correspondence grid, if one was built, so that the target holds only its
    /// points, normals and tree until its next ICP builds it again (the same grid: answers do
    /// not change). For a target kept idle between uses, whose grid is the largest part.
    pub fn drop_grid(&mut self) {
        self.grid = std::sync::OnceLock::new();
    }

    /// The target points.
    pub fn points(&self) -> &[Point3<f64>] {
        &self.points
    }

    /// The target normals: those given ([`IcpTarget::new`]) or, for
    /// [`IcpTarget::with_deferred_normals`], all of them estimated at the first call.
    pub fn normals(&self) -> Option<&[Vector3<f64>]> {
        match (&self.normals, &self.deferred) {
            (Some(normals), _) => Some(normals),
            (None, Some((estimate, all))) => all
                .get_or_init(|| estimate.estimate(&self.points, None).ok())
                .as_deref(),
            (None, None) => None,
        }
    }

    /// The normals of the points at the indices `at`, in that order: picked from the known
    /// normals, or estimated for those points only while the deferred ones have not been (the
    /// same values, bit for bit). When `at` holds at least [`ESTIMATE_ALL_FRACTION`] of the
    /// points, all the deferred normals are estimated (and kept) instead. `None` without normals
    /// or for an index outside the points.
    pub fn normals_at(&self, at: &[u32]) -> Option<Vec<Vector3<f64>>> {
        let known = match (&self.normals, &self.deferred) {
            (Some(normals), _) => Some(normals.as_slice()),
            (None, Some(_))
                if at.len() as f64 >= ESTIMATE_ALL_FRACTION * self.points.len() as f64 =>
            {
                self.normals()
            }
            (None, Some((_, all))) => all.get().and_then(|n| n.as_deref()),
            (None, None) => return None,
        };
        match (known, &self.deferred) {
            (Some(normals), _) => at
                .iter()
                .map(|&i| normals.get(i as usize).copied())
                .collect(),
            (None, Some((estimate, _))) => estimate.estimate(&self.points, Some(at)).ok(),
            (None, None) => None,
        }
    }

    /// Whether the target has normals (given or deferred): point-to-plane ICP needs them.
    pub fn has_normals(&self) -> bool {
        self.normals.is_some() || self.deferred.is_some()
    }

    /// A target over `points` (taken as they are) whose normals are estimated with `estimate`
    /// only when asked for: all of them at the first point-to-plane ICP against it, or a few
    /// ([`IcpTarget::normals_at`]). A frame of `mireg register` is a target only when its
    /// registration falls back to frame-to-frame ICP, and adds to the local map only the points
    /// that land in a voxel not yet full. Fails on an empty cloud or non-finite coordinates.
    pub fn with_deferred_normals(
        points: Vec<Point3<f64>>,
        estimate: NormalEstimate,
    ) -> Result<Self> {
        check_target_points(&points)?;
        Ok(Self {
            points,
            normals: None,
            deferred: Some((estimate, std::sync::OnceLock::new())),
            tree: std::sync::OnceLock::new(),
            grid: std::sync::OnceLock::new(),
            spare: Default::default(),
        })
    }

    /// The kd-tree over the points (built on first use).
    fn tree(&self) -> &ImmutableKdTree<f64, 3> {
        self.tree.get_or_init(|| {
            let coords: Vec<[f64; 3]> = self.points.iter().map(|p| [p.x, p.y, p.z]).collect();
            // The points were checked (non-empty, finite, at most u32::MAX) when the target was made.
            ImmutableKdTree::new_from_slice(&coords).expect("kd-tree over checked points")
        })
    }

    /// Squared distance \[m²\] from `p` to the nearest target point.
    pub fn nearest_distance_squared(&self, p: &Point3<f64>) -> f64 {
        self.tree()
            .query(&[p.x, p.y, p.z])
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute()
            .distance
    }

    /// Index of and squared distance \[m²\] to the nearest target point if it is within
    /// `max_squared` \[m²\] (inclusive; the caller applies Open3D's strict bound). Which of several
    /// equidistant points is returned is kiddo's choice.
    pub(super) fn nearest(&self, p: &Point3<f64>, max_squared: f64) -> Option<(usize, f64)> {
        let nn = self
            .tree()
            .query(&[p.x, p.y, p.z])
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute();
        (nn.distance <= max_squared).then_some((nn.item as usize, nn.distance))
    }
}
