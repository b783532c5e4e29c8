//! A local map in the world frame, for refining each frame's pose against recent frames instead
//! of the previous one alone: frame-to-map registration, as in KISS-ICP (Vizzo et al., "KISS-ICP:
//! In Defense of Point-to-Point ICP", RA-L 2023, Sec. IV-D: a voxel hash of at most N points per
//! voxel, voxels beyond the sensor's range of the current pose removed).
//!
//! NOTE: KISS-ICP registers point-to-point; we keep point-to-plane (our ICP), so each map point
//! carries the normal estimated in the frame it came from, rotated into the world.
//!
//! Storage: the map's points and normals are kept voxel after voxel in lattice order (the order
//! of a radius grid's storage, [`lattice_order`]), each voxel's in arrival order, and they are
//! the arrays of the map's ICP target itself. A hash index finds each voxel's record (its key,
//! how many points it holds, its first point). Points added by a frame wait beside the stored
//! ones; building the target merges them in: the surviving voxels are already in order, only
//! the frame's new voxels are sorted, and the stored points are read in order, not gathered.
//! The voxels also serve as the target's correspondence grid, built from that order in one pass
//! ([`RadiusGrid::from_sorted_lattice`]). The order depends only on the frames inserted, never on
//! the hash or the thread count: the same seed gives the same poses.
//!
//! NOTE: two earlier layouts, measured on the KAIST03 keyframes (docs/ODOMETRY.md,
//! docs/BENCHMARKS_ARCHIVE.md): a [`BTreeMap`](std::collections::BTreeMap) of per-voxel vectors cost
//! 15–19 ms a frame (a tree search per inserted point, a pointer chase per voxel); a slab of
//! `max_points_per_voxel` slots per voxel (at 5 per voxel, 21 MB of points and normals for 87k
//! voxels of 2.5 points on average), bucketed into a grid by a counting sort every frame, spent
//! its time gathering points and normals from random slots.

use std::collections::HashMap;

use nalgebra::{Isometry3, Point3, Vector3};

use super::icp::IcpTarget;
use crate::geometry::floor_i64;
use crate::geometry::radius_grid::{
    GridStorage, RadiusGrid, cell_edge, check_radius, default_max_columns, key_bounds,
    lattice_axes, lattice_order,
};
use crate::hash::FastHash;
use crate::{Error, Result};

/// Settings of a [`LocalMap`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalMapConfig {
    /// Edge of a map voxel \[m\]; `mireg register` uses the ICP voxel.
    pub voxel_size_m: f64,
    /// Points kept per voxel (the first ones to arrive). KISS-ICP's default: 20.
    pub max_points_per_voxel: usize,
}

/// The bit of a [`LocalMap`] index entry that marks its voxel full.
const FULL: u32 = 1 << 31;

/// One voxel of a [`LocalMap`].
#[derive(Debug, Clone, Copy)]
struct Voxel {
    /// Points it holds, stored and waiting (0: free, or dropped since the last rebuild).
    held: u32,
    /// Its first point (dropping far voxels reads these, one flat array); its key is this
    /// point's.
    first: Point3<f64>,
}

impl Default for Voxel {
    fn default() -> Self {
        Self {
            held: 0,
            first: Point3::origin(),
        }
    }
}

/// A voxel of the last rebuild, in the map's order: its key, and its points stored then,
/// `start .. start + stored` of the target's arrays.
///
/// NOTE: these live in the order, not in the voxel's record, so that a rebuild reads them in
/// sequence: read through the voxels' ids, in lattice order, every one was a cache miss (a
/// third of the rebuild's time on the KAIST03 keyframes, 126k map points).
#[derive(Debug, Clone, Copy)]
struct Stored {
    key: [i64; 3],
    id: u32,
    start: u32,
    stored: u32,
}

/// The first part of a rebuild ([`LocalMap::target_points`]): the new points in order, with
/// their grid, before the normals.
struct BuiltPoints {
    points: Vec<Point3<f64>>,
    /// The previous target's normals (read by the normals' merge) and points (to recycle).
    old_normals: Vec<Vector3<f64>>,
    old_points: Vec<Point3<f64>>,
    /// Storage for the next grid.
    spare: GridStorage,
    grid: Option<RadiusGrid>,
}

/// Scratch of a rebuild, kept between frames.
#[derive(Debug, Default)]
struct Rebuild {
    /// Voxels created since the last rebuild that are still held.
    fresh: Vec<Stored>,
    /// The voxels dropped since the last rebuild, one bit per id.
    dropped: Vec<u64>,
    /// Per voxel of the new order: its waiting points.
    counts: Vec<u32>,
    /// Per voxel of the new order: its stored points' start and count in the previous arrays,
    /// and its waiting points' start and count in `grouped`.
    plan: Vec<[u32; 4]>,
    /// Indices of the waiting points, grouped by voxel in the new order (arrival order within).
    grouped: Vec<u32>,
    /// Per voxel id: its waiting points' count, then their end in `grouped`.
    waiting: Vec<u32>,
    /// Each voxel's key and point count in the new order, for the grid.
    cells: Vec<([i64; 3], u32)>,
    /// Arrays for the next target.
    points: Vec<Point3<f64>>,
    normals: Vec<Vector3<f64>>,
}

/// Points (with normals) of recent frames in the world frame.
#[derive(Debug)]
pub struct LocalMap {
    config: LocalMapConfig,
    /// Id of each held voxel, with [`FULL`] set once it holds `max_points_per_voxel` points.
    index: HashMap<[i64; 3], u32, FastHash>,
    /// Per id: the voxel's record.
    voxels: Vec<Voxel>,
    /// Ids to reuse, last freed first.
    free: Vec<u32>,
    /// Voxels dropped since the last rebuild: their ids are reused only after it, when no
    /// waiting point refers to them any more.
    dropped: Vec<u32>,
    /// Voxels created since the last rebuild.
    created: Vec<u32>,
    /// The voxels of the last rebuild in lattice order under `axes`.
    order: Vec<Stored>,
    axes: [usize; 3],
    /// Points added since the last rebuild, in arrival order, with their voxel (world frame),
    /// and their normals (world frame) once given.
    waiting: Vec<(u32, Point3<f64>)>,
    waiting_normals: Vec<Vector3<f64>>,
    points: usize,
    /// The map as an ICP target (`None` when the last [`LocalMap::target`] found the map empty
    /// or failed); its arrays are the map's stored points and normals.
    target: Option<IcpTarget>,
    rebuild: Rebuild,
}

impl LocalMap {
    /// An empty map; fails unless the voxel is finite and positive and voxels hold a point.
    pub fn new(config: LocalMapConfig) -> Result<Self> {
        let v = config.voxel_size_m;
        if !(v.is_finite() && v > 0.0) || config.max_points_per_voxel == 0 {
            return Err(Error::InvalidInput(format!(
                "local map: voxel_size_m must be finite and > 0 and max_points_per_voxel > 0, got {v} and {}",
                config.max_points_per_voxel
            )));
        }
        Ok(Self {
            config,
            index: HashMap::default(),
            voxels: Vec::new(),
            free: Vec::new(),
            dropped: Vec::new(),
            created: Vec::new(),
            order: Vec::new(),
            axes: [0, 1, 2],
            waiting: Vec::new(),
            waiting_normals: Vec::new(),
            points: 0,
            target: None,
            rebuild: Rebuild::default(),
        })
    }

    /// Points in the map.
    pub fn len(&self) -> usize {
        self.points
    }

    /// `true` before the first [`insert`](Self::insert).
    pub fn is_empty(&self) -> bool {
        self.points == 0
    }

    fn key(&self, p: &Point3<f64>) -> [i64; 3] {
        voxel_key(p, self.config.voxel_size_m)
    }

    /// Adds a frame's `points` and `normals` (sensor frame) at `world_from_frame`, into voxels not
    /// yet full, then drops every voxel whose first point is farther than `max_distance_m` from the
    /// frame's origin.
    ///
    /// # Panics
    /// If `points` and `normals` differ in length.
    pub fn insert(
        &mut self,
        world_from_frame: &Isometry3<f64>,
        points: &[Point3<f64>],
        normals: &[Vector3<f64>],
        max_distance_m: f64,
    ) {
        assert_eq!(points.len(), normals.len(), "one normal per point");
        self.insert_with(
            world_from_frame,
            points,
            |at| at.iter().map(|&i| normals[i as usize]).collect(),
            max_distance_m,
        );
    }

    /// [`LocalMap::insert`] asking `normals_at` for the normals (sensor frame) of only the points
    /// kept, by index into `points` in increasing order, so that normals can be estimated for
    /// those alone ([`crate::refine::icp::IcpTarget::normals_at`]): on a 10 Hz log most points
    /// land in voxels already full. The map is the same as with all normals given. Normals
    /// missing from its answer (it must return one per index) stay zero.
    pub fn insert_with(
        &mut self,
        world_from_frame: &Isometry3<f64>,
        points: &[Point3<f64>],
        normals_at: impl FnOnce(&[u32]) -> Vec<Vector3<f64>>,
        max_distance_m: f64,
    ) {
        let at = self.place_points(world_from_frame, points, max_distance_m);
        let normals = normals_at(&at);
        self.write_normals(world_from_frame, &normals);
    }

    /// [`LocalMap::insert_with`] followed by [`LocalMap::target`]`(target_distance_m)`, with the
    /// normals of the kept points estimated while the target's points and grid are built (the
    /// grid needs the points only): the same map and target, sooner where estimating the
    /// normals takes long (most points of the KAIST03 keyframes, 1 m apart, are kept).
    pub fn insert_and_target(
        &mut self,
        world_from_frame: &Isometry3<f64>,
        points: &[Point3<f64>],
        normals_at: impl FnOnce(&[u32]) -> Vec<Vector3<f64>> + Send,
        max_distance_m: f64,
        target_distance_m: f64,
    ) -> Result<Option<&IcpTarget>> {
        check_radius(target_distance_m)?;
        let at = self.place_points(world_from_frame, points, max_distance_m);
        let (normals, built) =
            rayon::join(|| normals_at(&at), || self.target_points(target_distance_m));
        self.write_normals(world_from_frame, &normals);
        self.finish_target(built, target_distance_m)
    }

    /// The first part of an insertion: each point joins its voxel's waiting points unless the
    /// voxel is full, then voxels farther than `max_distance_m` from the frame's origin are
    /// dropped. Returns the kept points' indices into `points` (increasing);
    /// [`LocalMap::write_normals`] then gives them their normals.
    fn place_points(
        &mut self,
        world_from_frame: &Isometry3<f64>,
        points: &[Point3<f64>],
        max_distance_m: f64,
    ) -> Vec<u32> {
        let cap = self.config.max_points_per_voxel.min(u32::MAX as usize) as u32;
        let mut kept = Vec::new();
        for (i, p) in points.iter().enumerate() {
            let w = world_from_frame * p;
            if !w.coords.iter().all(|c| c.is_finite()) {
                continue;
            }
            let key = self.key(&w);
            // NOTE: most points of a 10 Hz frame land in a full voxel (94 % on the KITTI replay
            // log); the flag in the index answers them without reading the voxel's record, a
            // second random access into a table the size of the map.
            let id = match self.index.get_mut(&key) {
                Some(entry) if *entry & FULL != 0 => continue,
                Some(entry) => {
                    let id = *entry;
                    if self.voxels[id as usize].held + 1 >= cap {
                        *entry |= FULL;
                    }
                    id
                }
                None => {
                    let id = self.free.pop().unwrap_or_else(|| {
                        self.voxels.push(Voxel::default());
                        // Ids reach FULL only with 2 G voxels: more than any cloud we accept.
                        (self.voxels.len() - 1) as u32
                    });
                    self.voxels[id as usize] = Voxel {
                        first: w,
                        ..Voxel::default()
                    };
                    self.index
                        .insert(key, if cap <= 1 { id | FULL } else { id });
                    self.created.push(id);
                    id
                }
            };
            // Not full: an entry without FULL holds fewer than `cap` points.
            self.voxels[id as usize].held += 1;
            self.waiting.push((id, w));
            kept.push(i as u32);
            self.points += 1;
        }
        let origin = Point3::from(world_from_frame.translation.vector);
        let max_sq = max_distance_m * max_distance_m;
        let voxel = self.config.voxel_size_m;
        for (id, v) in self.voxels.iter_mut().enumerate() {
            if v.held > 0 && (v.first - origin).norm_squared() > max_sq {
                self.points -= v.held as usize;
                v.held = 0;
                self.index.remove(&voxel_key(&v.first, voxel));
                self.dropped.push(id as u32);
            }
        }
        kept
    }

    /// The normals (the frame's sensor frame) of the points the last
    /// [`LocalMap::place_points`] kept, one per kept point, rotated into the world; missing ones
    /// stay zero.
    fn write_normals(&mut self, world_from_frame: &Isometry3<f64>, normals: &[Vector3<f64>]) {
        let new = self.waiting.len() - self.waiting_normals.len();
        self.waiting_normals.extend((0..new).map(|k| {
            normals
                .get(k)
                .map_or_else(Vector3::zeros, |n| world_from_frame.rotation * n)
        }));
    }

    /// The map as an ICP target; `None` while empty. Its points and normals are voxel after
    /// voxel in lattice order ([`lattice_order`] under [`lattice_axes`] of the voxels' bounds),
    /// each voxel's in arrival order. Built into the storage of the previous call's target (the
    /// map's megabytes are allocated and faulted in once, not every frame);
    /// [`LocalMap::built_target`] returns it until the next call. When the voxel is at least the
    /// cell edge of `max_distance_m` \[m\] ([`cell_edge`]), the voxels also serve as the
    /// target's correspondence grid at that distance ([`RadiusGrid::from_sorted_lattice`]).
    ///
    /// On an error (a non-finite normal given to an insertion) the map is emptied.
    pub fn target(&mut self, max_distance_m: f64) -> Result<Option<&IcpTarget>> {
        // Checked before the map changes: a rebuild that fails empties it.
        check_radius(max_distance_m)?;
        let built = self.target_points(max_distance_m);
        self.finish_target(built, max_distance_m)
    }

    /// The first part of [`LocalMap::target`]: the voxels' new order (the surviving ones keep
    /// theirs, the new ones are sorted and merged in), the points in it, and the grid (it needs
    /// no normals); `None` for an empty map.
    fn target_points(&mut self, max_distance_m: f64) -> Result<Option<BuiltPoints>> {
        let (old_points, old_normals, spare) = match self.target.take() {
            Some(previous) => previous.into_storage(),
            None => Default::default(),
        };
        let voxel = self.config.voxel_size_m;
        let Self {
            voxels,
            order,
            created,
            dropped,
            waiting,
            rebuild: r,
            ..
        } = self;
        // A voxel is held unless dropped since the last rebuild: ids are not reused before it.
        r.dropped.clear();
        r.dropped.resize(voxels.len().div_ceil(64), 0);
        for &id in dropped.iter() {
            r.dropped[id as usize / 64] |= 1 << (id % 64);
        }
        let gone = &r.dropped;
        let held = |id: u32| gone[id as usize / 64] >> (id % 64) & 1 == 0;
        // The voxels in order: the survivors keep theirs, the new ones are sorted and merged in
        // (all are sorted again when the grid's axes change).
        order.retain(|s| held(s.id));
        r.fresh.clear();
        r.fresh
            .extend(created.drain(..).filter(|&id| held(id)).map(|id| Stored {
                key: voxel_key(&voxels[id as usize].first, voxel),
                id,
                start: 0,
                stored: 0,
            }));
        let Some((lo, hi)) = key_bounds(order.iter().chain(&r.fresh).map(|s| &s.key)) else {
            self.after_rebuild();
            return Ok(None);
        };
        let axes = lattice_axes(lo, hi);
        let rank = |s: &Stored| lattice_order(&s.key, axes);
        if axes == self.axes {
            r.fresh.sort_unstable_by_key(rank);
            merge_into(order, &r.fresh, rank);
        } else {
            order.extend_from_slice(&r.fresh);
            order.sort_unstable_by_key(rank);
            self.axes = axes;
        }
        // The waiting points grouped by voxel in the new order (a counting sort; those of
        // dropped voxels are left out).
        r.waiting.clear();
        r.waiting.resize(voxels.len(), 0);
        for &(id, _) in waiting.iter() {
            if held(id) {
                r.waiting[id as usize] += 1;
            }
        }
        r.counts.clear();
        let mut end = 0u32;
        for s in order.iter() {
            let count = r.waiting[s.id as usize];
            r.counts.push(count);
            end += count;
            r.waiting[s.id as usize] = end;
        }
        r.grouped.clear();
        r.grouped.resize(end as usize, 0);
        for (k, &(id, _)) in waiting.iter().enumerate().rev() {
            if held(id) {
                let at = &mut r.waiting[id as usize];
                *at -= 1;
                r.grouped[*at as usize] = k as u32;
            }
        }
        // The points: each voxel's stored ones, read in order from the previous arrays, then its
        // waiting ones (each voxel's group follows the previous one's in `grouped`).
        let mut points = std::mem::take(&mut r.points);
        points.clear();
        points.reserve(self.points);
        r.plan.clear();
        r.cells.clear();
        let mut from = 0u32;
        for (s, &waits) in order.iter_mut().zip(&r.counts) {
            r.plan.push([s.start, s.stored, from, waits]);
            let holds = s.stored + waits;
            r.cells.push((s.key, holds));
            let new_start = points.len() as u32;
            points.extend_from_slice(&old_points[s.start as usize..(s.start + s.stored) as usize]);
            let group = &r.grouped[from as usize..(from + waits) as usize];
            points.extend(group.iter().map(|&k| waiting[k as usize].1));
            (s.start, s.stored) = (new_start, holds);
            from += waits;
        }
        let (grid, spare) = if voxel >= cell_edge(max_distance_m) {
            let max_columns = default_max_columns(points.len());
            let grid = RadiusGrid::from_sorted_lattice(
                &points,
                &r.cells,
                voxel,
                max_distance_m,
                max_columns,
                spare,
            )?;
            (grid, GridStorage::default())
        } else {
            (None, spare)
        };
        Ok(Some(BuiltPoints {
            points,
            old_normals,
            old_points,
            spare,
            grid,
        }))
    }

    /// The second part of [`LocalMap::target`]: the normals merged as the points were (the
    /// stored ones in order, then each voxel's waiting ones), and the target made. On an error
    /// the map is emptied: its stored points went with the failed target.
    fn finish_target(
        &mut self,
        built: Result<Option<BuiltPoints>>,
        max_distance_m: f64,
    ) -> Result<Option<&IcpTarget>> {
        let target = match built {
            Ok(Some(built)) => self.merge_normals(built, max_distance_m),
            Ok(None) => Ok(None),
            Err(e) => Err(e),
        };
        self.after_rebuild();
        match target {
            Ok(target) => {
                self.target = target;
                Ok(self.target.as_ref())
            }
            Err(e) => {
                self.clear();
                Err(e)
            }
        }
    }

    /// The normals in the order of `built`'s points, and the target.
    fn merge_normals(
        &mut self,
        built: BuiltPoints,
        max_distance_m: f64,
    ) -> Result<Option<IcpTarget>> {
        let BuiltPoints {
            points,
            old_normals,
            old_points,
            spare,
            grid,
        } = built;
        let r = &mut self.rebuild;
        let mut normals = std::mem::take(&mut r.normals);
        normals.clear();
        normals.reserve(points.len());
        for &[start, stored, from, waits] in &r.plan {
            normals.extend_from_slice(&old_normals[start as usize..(start + stored) as usize]);
            let group = &r.grouped[from as usize..(from + waits) as usize];
            normals.extend(group.iter().map(|&k| self.waiting_normals[k as usize]));
        }
        // The previous arrays serve the next rebuild.
        (r.points, r.normals) = (old_points, old_normals);
        let mut target = IcpTarget::from_storage(points, normals, spare)?;
        if let Some(grid) = grid {
            target.set_grid(max_distance_m, grid)?;
        }
        Ok(Some(target))
    }

    /// After a rebuild: no point waits, and the dropped voxels' ids can be reused.
    fn after_rebuild(&mut self) {
        self.free.append(&mut self.dropped);
        self.waiting.clear();
        self.waiting_normals.clear();
    }

    /// Empties the map.
    fn clear(&mut self) {
        self.index.clear();
        self.voxels.clear();
        self.free.clear();
        self.dropped.clear();
        self.created.clear();
        self.order.clear();
        self.points = 0;
        self.target = None;
    }

    /// The target of the last [`LocalMap::target`] call (`None` before it, or if the map was
    /// empty then or the call failed); the map may have changed since.
    pub fn built_target(&self) -> Option<&IcpTarget> {
        self.target.as_ref()
    }
}

/// The key of the voxel of edge `voxel` \[m\] that holds `p`.
fn voxel_key(p: &Point3<f64>, voxel: f64) -> [i64; 3] {
    [p.x / voxel, p.y / voxel, p.z / voxel].map(floor_i64)
}

/// Merges `fresh` into `order`, both in increasing `rank`, in place: from the back, so each
/// element of `order` moves once, to where it ends (ties keep `order`'s first).
fn merge_into<T: Copy, K: Ord>(order: &mut Vec<T>, fresh: &[T], rank: impl Fn(&T) -> K) {
    let (mut i, mut j) = (order.len(), fresh.len());
    order.extend_from_slice(fresh);
    let mut k = order.len();
    while j > 0 {
        k -= 1;
        if i > 0 && rank(&fresh[j - 1]) < rank(&order[i - 1]) {
            order[k] = order[i - 1];
            i -= 1;
        } else {
            order[k] = fresh[j - 1];
            j -= 1;
        }
    }
}

#[cfg(test)]
mod tests;
