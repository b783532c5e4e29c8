//! A local map in the world frame, for refining each frame's pose against recent frames instead
//! of the previous one alone: frame-to-map registration, as in KISS-ICP (Vizzo et al., "KISS-ICP:
//! In Defense of Point-to-Point ICP", RA-L 2023, Sec. IV-D: a voxel hash of at most N points per
//! voxel, voxels beyond the sensor's range of the current pose removed).
//!
//! NOTE: KISS-ICP registers point-to-point; we keep point-to-plane (our ICP), so each map point
//! carries the normal estimated in the frame it came from, rotated into the world.
//!
//! Storage: each voxel owns a slot of `max_points_per_voxel` points (and normals) in one flat
//! slab, found through a hash index of voxel keys; freed slots are reused. The map's points come
//! out in the order of its correspondence grid (else in slot order), which depends only on the
//! frames inserted, never on the hash or the thread count: the same seed gives the same poses.
//!
//! NOTE: a [`BTreeMap`](std::collections::BTreeMap) of per-voxel vectors, the first layout, cost
//! 15–19 ms a frame on the KAIST03 keyframes (80–87k voxels, mostly of 1–2 points): the tree
//! search for every inserted point, a pointer chase per voxel for dropping far ones and again for
//! flattening the map into the ICP target (docs/ODOMETRY.md).

use std::collections::HashMap;

use nalgebra::{Isometry3, Point3, Vector3};

use super::icp::IcpTarget;
use crate::geometry::floor_i64;
use crate::geometry::radius_grid::{GridStorage, RadiusGrid, cell_edge, default_max_columns};
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

/// The map's points in a target's storage, with their grid, before the normals
/// ([`LocalMap::target`]).
struct BuiltPoints {
    points: Vec<Point3<f64>>,
    /// Storage for the normals.
    normals: Vec<Vector3<f64>>,
    /// Storage for the next grid.
    spare: GridStorage,
    grid: Option<RadiusGrid>,
}

/// One voxel's slot in a [`LocalMap`].
#[derive(Debug, Clone, Copy)]
struct Slot {
    key: [i64; 3],
    held: usize,
    first: Point3<f64>,
}

impl Default for Slot {
    fn default() -> Self {
        Self {
            key: [0; 3],
            held: 0,
            first: Point3::origin(),
        }
    }
}

/// Each occupied voxel's key and its points' range in the slabs (`cap` entries per slot), in slot
/// order (the order of the map as a target when its voxels are no correspondence grid).
fn occupied(
    slots: &[Slot],
    cap: usize,
) -> impl Iterator<Item = ([i64; 3], std::ops::Range<usize>)> + '_ {
    (slots.iter().enumerate())
        .filter(|(_, s)| s.held > 0)
        .map(move |(slot, s)| (s.key, slot * cap..slot * cap + s.held))
}

/// Points (with normals) of recent frames in the world frame.
#[derive(Debug)]
pub struct LocalMap {
    config: LocalMapConfig,
    /// Slot of each occupied voxel.
    index: HashMap<[i64; 3], u32, FastHash>,
    /// Per slot: its voxel's key, how many points it holds (0: free) and its first point
    /// (a copy, so that dropping far voxels reads one flat array, not the slab at every slot).
    slots: Vec<Slot>,
    /// `max_points_per_voxel` entries per slot.
    points_slab: Vec<Point3<f64>>,
    normals_slab: Vec<Vector3<f64>>,
    /// Slots to reuse, last freed first.
    free: Vec<u32>,
    points: usize,
    /// The map as an ICP target, rebuilt in place by [`LocalMap::target`] (`None` when that
    /// found the map empty or failed).
    target: Option<IcpTarget>,
    /// Scratch of [`LocalMap::target`]: each occupied voxel's key and its points' range in the
    /// slabs, in slot order.
    cells: Vec<([i64; 3], std::ops::Range<usize>)>,
    /// Scratch of [`LocalMap::insert_with`]: each kept point's index and place in the slabs.
    kept: Vec<(u32, usize)>,
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
            slots: Vec::new(),
            points_slab: Vec::new(),
            normals_slab: Vec::new(),
            free: Vec::new(),
            points: 0,
            target: None,
            cells: Vec::new(),
            kept: Vec::new(),
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
        let v = self.config.voxel_size_m;
        [p.x / v, p.y / v, p.z / v].map(floor_i64)
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
        let at = self.place_points(world_from_frame, points, max_distance_m);
        let (normals, built) =
            rayon::join(|| normals_at(&at), || self.target_points(target_distance_m));
        self.write_normals(world_from_frame, &normals);
        self.finish_target(built?, target_distance_m)
    }

    /// The first part of an insertion: each point goes to its voxel unless that is full, then
    /// voxels farther than `max_distance_m` from the frame's origin are dropped. Returns the kept
    /// points' indices into `points` (increasing); [`LocalMap::write_normals`] then gives them
    /// their normals.
    fn place_points(
        &mut self,
        world_from_frame: &Isometry3<f64>,
        points: &[Point3<f64>],
        max_distance_m: f64,
    ) -> Vec<u32> {
        let cap = self.config.max_points_per_voxel;
        // The points kept: their index in `points` and their place in the slabs.
        self.kept.clear();
        for (i, p) in points.iter().enumerate() {
            let w = world_from_frame * p;
            if !w.coords.iter().all(|c| c.is_finite()) {
                continue;
            }
            let key = self.key(&w);
            let slot = match self.index.get(&key) {
                Some(&slot) => slot as usize,
                None => {
                    let slot = match self.free.pop() {
                        Some(slot) => slot as usize,
                        None => {
                            self.slots.push(Slot::default());
                            let len = self.slots.len() * cap;
                            self.points_slab.resize(len, Point3::origin());
                            self.normals_slab.resize(len, Vector3::zeros());
                            self.slots.len() - 1
                        }
                    };
                    self.slots[slot] = Slot {
                        key,
                        held: 0,
                        first: w,
                    };
                    // Slots beyond u32 would need 4 G voxels: more than any cloud we accept.
                    self.index.insert(key, slot as u32);
                    slot
                }
            };
            let held = &mut self.slots[slot].held;
            if *held < cap {
                let at = slot * cap + *held;
                self.points_slab[at] = w;
                self.kept.push((i as u32, at));
                *held += 1;
                self.points += 1;
            }
        }
        let origin = Point3::from(world_from_frame.translation.vector);
        let max_sq = max_distance_m * max_distance_m;
        for (slot, s) in self.slots.iter_mut().enumerate() {
            if s.held > 0 && (s.first - origin).norm_squared() > max_sq {
                self.points -= s.held;
                s.held = 0;
                self.index.remove(&s.key);
                self.free.push(slot as u32);
            }
        }
        self.kept.iter().map(|&(i, _)| i).collect()
    }

    /// The normals (the frame's sensor frame) of the points the last
    /// [`LocalMap::place_points`] kept, one per kept point, rotated into the world; missing ones
    /// stay zero. (A kept point whose voxel was then dropped writes into a free slot: harmless.)
    fn write_normals(&mut self, world_from_frame: &Isometry3<f64>, normals: &[Vector3<f64>]) {
        for (k, &(_, slab)) in self.kept.iter().enumerate() {
            self.normals_slab[slab] = normals
                .get(k)
                .map_or_else(Vector3::zeros, |n| world_from_frame.rotation * n);
        }
    }

    /// The map as an ICP target; `None` while empty. Its points and normals are in the order of
    /// its correspondence grid where the voxels serve as one (see below), else in slot order. Built
    /// into the storage of the previous call's target (the map's tens of megabytes are
    /// allocated and faulted in once, not every frame); [`LocalMap::built_target`] returns it
    /// until the next call. When the voxel is at least the cell edge of `max_distance_m` \[m\]
    /// ([`cell_edge`]), the voxels also serve as the target's correspondence grid at that
    /// distance ([`RadiusGrid::from_lattice`]).
    pub fn target(&mut self, max_distance_m: f64) -> Result<Option<&IcpTarget>> {
        let built = self.target_points(max_distance_m);
        self.finish_target(built?, max_distance_m)
    }

    /// The first part of [`LocalMap::target`]: the map's correspondence grid where the voxels
    /// serve as its cells (the grid needs no normals), and the map's points in its order (else in
    /// slot order), in the storage of the previous target; `None` for an empty map.
    fn target_points(&mut self, max_distance_m: f64) -> Result<Option<BuiltPoints>> {
        let (mut points, normals, mut spare) = match self.target.take() {
            Some(previous) => previous.into_storage(),
            None => Default::default(),
        };
        if self.is_empty() {
            return Ok(None);
        }
        let cap = self.config.max_points_per_voxel;
        // Occupied voxels in slot order, with their points' range in the slab.
        self.cells.clear();
        self.cells.extend(occupied(&self.slots, cap));
        // The voxels are the correspondence grid's cells where they are large enough: no point
        // is bucketed again.
        let v = self.config.voxel_size_m;
        let grid = if v >= cell_edge(max_distance_m) {
            RadiusGrid::from_lattice(
                &self.points_slab,
                &self.cells,
                v,
                max_distance_m,
                default_max_columns(self.points),
                std::mem::take(&mut spare),
            )?
        } else {
            None
        };
        // The target's points in the grid's order where there is a grid: the points near a query
        // (ICP reads their normals) then lie near each other in memory.
        points.clear();
        points.reserve(self.points);
        match &grid {
            Some(grid) => points.extend(grid.points_in_storage_order()),
            None => {
                for (_, at) in &self.cells {
                    points.extend_from_slice(&self.points_slab[at.clone()]);
                }
            }
        }
        Ok(Some(BuiltPoints {
            points,
            normals,
            spare,
            grid,
        }))
    }

    /// The second part of [`LocalMap::target`]: the normals, in the points' order, and the
    /// target made.
    fn finish_target(
        &mut self,
        built: Option<BuiltPoints>,
        max_distance_m: f64,
    ) -> Result<Option<&IcpTarget>> {
        let Some(BuiltPoints {
            points,
            mut normals,
            spare,
            mut grid,
        }) = built
        else {
            self.target = None;
            return Ok(None);
        };
        normals.clear();
        normals.reserve(points.len());
        match &mut grid {
            Some(grid) => {
                let slab = &self.normals_slab;
                normals.extend(grid.storage_index().iter().map(|&i| slab[i as usize]));
                grid.index_by_storage_order();
            }
            None => {
                for (_, at) in &self.cells {
                    normals.extend_from_slice(&self.normals_slab[at.clone()]);
                }
            }
        }
        let mut target = IcpTarget::from_storage(points, normals, spare)?;
        if let Some(grid) = grid {
            target.set_grid(max_distance_m, grid)?;
        }
        self.target = Some(target);
        Ok(self.target.as_ref())
    }

    /// The target of the last [`LocalMap::target`] call (`None` before it, or if the map was
    /// empty then or the call failed); the map may have changed since.
    pub fn built_target(&self) -> Option<&IcpTarget> {
        self.target.as_ref()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn map(voxel: f64, cap: usize) -> LocalMap {
        LocalMap::new(LocalMapConfig {
            voxel_size_m: voxel,
            max_points_per_voxel: cap,
        })
        .unwrap()
    }

    #[test]
    fn voxels_hold_at_most_their_cap_and_far_voxels_go() {
        let mut m = map(1.0, 2);
        let pts: Vec<Point3<f64>> = (0..5)
            .map(|k| Point3::new(0.1 * k as f64, 0.5, 0.5))
            .collect();
        let normals = vec![Vector3::z(); pts.len()];
        m.insert(&Isometry3::identity(), &pts, &normals, 100.0);
        assert_eq!(m.len(), 2, "one voxel, capped at two");
        // The same points seen from 10 m further along x land in another voxel.
        let moved = Isometry3::from_parts(
            Translation3::new(10.0, 0.0, 0.0),
            UnitQuaternion::identity(),
        );
        m.insert(&moved, &pts, &normals, 100.0);
        assert_eq!(m.len(), 4);
        // From 20 m on, with a 5 m range, the first voxel (10+ m away) is dropped.
        let far = Isometry3::from_parts(
            Translation3::new(12.0, 0.0, 0.0),
            UnitQuaternion::identity(),
        );
        m.insert(&far, &[], &[], 5.0);
        assert_eq!(m.len(), 2);
        let t = m.target(0.5).unwrap().unwrap();
        assert!(t.points().iter().all(|p| p.x >= 10.0));
    }

    /// Against a direct model of the map's rule (per voxel, the first `cap` points in arrival
    /// order; voxels whose first point is beyond the range dropped after each frame), over
    /// frames that move away so that slots are freed and reused.
    #[test]
    fn the_slab_holds_what_the_rule_says() {
        use rand::{RngExt, SeedableRng};
        use std::collections::BTreeMap;
        let (voxel, cap, range) = (0.5, 3, 4.0);
        let mut m = map(voxel, cap);
        let mut model: BTreeMap<[i64; 3], Vec<Point3<f64>>> = BTreeMap::new();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let mut created = 0;
        for frame in 0..12 {
            let pose = Isometry3::from_parts(
                Translation3::new(0.7 * frame as f64, 0.1 * frame as f64, 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.2 * frame as f64),
            );
            let pts: Vec<Point3<f64>> = (0..300)
                .map(|_| {
                    Point3::new(
                        rng.random_range(-3.0..3.0),
                        rng.random_range(-3.0..3.0),
                        rng.random_range(-0.5..0.5),
                    )
                })
                .collect();
            let normals = vec![Vector3::z(); pts.len()];
            m.insert(&pose, &pts, &normals, range);
            for p in &pts {
                let w = pose * p;
                let key = [0, 1, 2].map(|k| (w[k] / voxel).floor() as i64);
                created += usize::from(!model.contains_key(&key));
                let v = model.entry(key).or_default();
                if v.len() < cap {
                    v.push(w);
                }
            }
            let origin = Point3::from(pose.translation.vector);
            model.retain(|_, v| (v[0] - origin).norm() <= range);
            let expected: usize = model.values().map(Vec::len).sum();
            assert_eq!(m.len(), expected, "frame {frame}");
            let mut got: Vec<[f64; 3]> = m
                .target(0.2)
                .unwrap()
                .unwrap()
                .points()
                .iter()
                .map(|p| [p.x, p.y, p.z])
                .collect();
            let mut want: Vec<[f64; 3]> =
                model.values().flatten().map(|p| [p.x, p.y, p.z]).collect();
            got.sort_by(|a, b| a.partial_cmp(b).unwrap());
            want.sort_by(|a, b| a.partial_cmp(b).unwrap());
            assert!(
                got == want,
                "frame {frame}: the map's points differ from the model's"
            );
        }
        // Voxels were dropped and their slots reused.
        assert!(
            m.slots.len() < created,
            "{} slots for {created} voxels",
            m.slots.len()
        );
    }

    #[test]
    fn points_and_normals_go_to_the_world_frame() {
        let mut m = map(0.5, 20);
        let pose = Isometry3::from_parts(
            Translation3::new(1.0, 2.0, 3.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
        );
        m.insert(&pose, &[Point3::new(1.0, 0.0, 0.0)], &[Vector3::x()], 100.0);
        let t = m.target(0.5).unwrap().unwrap();
        assert!((t.points()[0] - Point3::new(1.0, 3.0, 3.0)).norm() < 1e-12);
        assert!((t.normals().unwrap()[0] - Vector3::y()).norm() < 1e-12);
        assert!(map(0.5, 20).target(0.2).unwrap().is_none());
        assert!(
            LocalMap::new(LocalMapConfig {
                voxel_size_m: f64::NAN,
                max_points_per_voxel: 1
            })
            .is_err()
        );
    }

    #[test]
    fn normals_asked_for_the_kept_points_only_give_the_same_map() {
        // Two overlapping frames of a noisy slab: the second lands mostly in voxels the first
        // filled up.
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
        let frame: Vec<Point3<f64>> = (0..4000)
            .map(|_| {
                Point3::new(
                    rng.random_range(0.0..4.0),
                    rng.random_range(0.0..4.0),
                    rng.random_range(0.0..0.3),
                )
            })
            .collect();
        let normals: Vec<Vector3<f64>> = frame
            .iter()
            .map(|p| Vector3::new(p.x, 1.0, p.y).normalize())
            .collect();
        let poses = [
            Isometry3::identity(),
            Isometry3::from_parts(
                Translation3::new(0.3, 0.1, 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.05),
            ),
        ];
        let (mut all, mut lazy) = (map(0.5, 3), map(0.5, 3));
        let mut asked = Vec::new();
        for pose in &poses {
            all.insert(pose, &frame, &normals, 100.0);
            lazy.insert_with(
                pose,
                &frame,
                |at| {
                    asked.push(at.to_vec());
                    at.iter().map(|&i| normals[i as usize]).collect()
                },
                100.0,
            );
        }
        assert_eq!(all.len(), lazy.len());
        let (a, b) = (
            all.target(0.5).unwrap().unwrap(),
            lazy.target(0.5).unwrap().unwrap(),
        );
        assert_eq!(a.points(), b.points());
        assert_eq!(a.normals(), b.normals());
        // Inserting and building the target in one call (normals estimated beside the grid)
        // gives the same target, frame after frame, with its grid at the distance asked.
        let mut fused = map(0.5, 3);
        for pose in &poses {
            let gather = |at: &[u32]| at.iter().map(|&i| normals[i as usize]).collect();
            let t = fused
                .insert_and_target(pose, &frame, gather, 100.0, 0.4)
                .unwrap()
                .unwrap();
            assert_eq!(t.points().len(), fused.len());
        }
        // At 0.4 m the voxels are its grid and the target comes in the grid's order; at 0.5 m
        // (just above the voxel) in slot order: the same points with the same normals.
        let f = fused.built_target().unwrap();
        let pairs = |t: &IcpTarget| {
            let mut v: Vec<[f64; 6]> = (t.points().iter().zip(t.normals().unwrap()))
                .map(|(p, n)| [p.x, p.y, p.z, n.x, n.y, n.z])
                .collect();
            v.sort_by(|a, b| a.partial_cmp(b).unwrap());
            v
        };
        assert_eq!(pairs(f), pairs(a));
        let probes = [Point3::new(1.0, 1.0, 0.1), Point3::new(3.3, 0.2, 0.25)];
        let id = Isometry3::identity();
        assert_eq!(
            crate::refine::icp::evaluate_registration(&probes, f, &id, 0.4).unwrap(),
            crate::refine::icp::evaluate_registration(&probes, a, &id, 0.4).unwrap()
        );
        // Asked once per frame, in increasing order, for exactly the points kept.
        assert_eq!(asked.len(), 2);
        assert!(asked.iter().all(|at| at.windows(2).all(|w| w[0] < w[1])));
        assert_eq!(asked.iter().map(Vec::len).sum::<usize>(), all.len());
        assert!(asked[1].len() < frame.len() / 2, "{}", asked[1].len());
    }
}
