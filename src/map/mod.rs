//! The world map of a registered log: every cloud put into the world by its pose and
//! voxel-downsampled to one point per occupied voxel (the centroid of the points that fell in
//! it, with their mean intensity).
//!
//! [`VoxelMap`] is the pure accumulator: clouds go in one at a time ([`VoxelMap::add_cloud`])
//! and nothing of a cloud is kept but its contribution to the voxel sums, so memory grows with
//! the occupied voxels of the map, never with the number of clouds or points added. Storage is
//! flat: one hash entry (12-byte integer key, 4-byte index) and one 40-byte [`Cell`] per
//! occupied voxel; no allocation per point.
//!
//! `build.rs` ([`build_map`]) drives it over a `mireg register` output (the trajectory chosen, clouds streamed
//! from the log), and writes the map ([`write_map`]).

use std::collections::HashMap;

use nalgebra::{Isometry3, Point3};

use crate::hash::FastHash;

mod build;
mod job;

pub use build::{
    MapOptions, MapSummary, TrajectoryChoice, build_map, build_map_of_runs, write_map,
};
pub use job::map_runs;

/// One occupied voxel's running sums.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Cell {
    /// Sum of the world coordinates of the points in the voxel \[m\].
    pub sum: [f64; 3],
    /// Sum of their intensities (0 for points without one).
    pub intensity_sum: f64,
    /// Number of points in the voxel.
    pub count: u32,
}

impl Cell {
    /// The centroid of the voxel's points \[m, world frame\].
    pub fn centroid(&self) -> Point3<f64> {
        let n = f64::from(self.count.max(1));
        Point3::new(self.sum[0] / n, self.sum[1] / n, self.sum[2] / n)
    }

    /// The mean intensity of the voxel's points (meaningful when every cloud had intensity).
    pub fn mean_intensity(&self) -> f64 {
        self.intensity_sum / f64::from(self.count.max(1))
    }
}

/// Per-voxel centroids and mean intensities of clouds placed in one world frame.
///
/// Voxel `(i, j, k)` holds the points with `⌊x/v⌋ = i`, `⌊y/v⌋ = j`, `⌊z/v⌋ = k` for the voxel
/// edge `v` (metres). Cells are kept in the order their voxels were first hit, so the output
/// order is deterministic.
#[derive(Debug, Clone)]
pub struct VoxelMap {
    voxel_m: f64,
    index: HashMap<[i32; 3], u32, FastHash>,
    cells: Vec<Cell>,
    points_added: u64,
    points_out_of_range: u64,
}

impl VoxelMap {
    /// An empty map with voxel edge `voxel_m` \[m\].
    ///
    /// # Errors
    /// [`crate::Error::InvalidInput`] unless `voxel_m` is finite and positive.
    pub fn new(voxel_m: f64) -> crate::Result<Self> {
        if !(voxel_m.is_finite() && voxel_m > 0.0) {
            return Err(crate::Error::InvalidInput(format!(
                "voxel size must be a positive number of metres, got {voxel_m}"
            )));
        }
        Ok(Self {
            voxel_m,
            index: HashMap::default(),
            cells: Vec::new(),
            points_added: 0,
            points_out_of_range: 0,
        })
    }

    /// The voxel edge \[m\].
    pub fn voxel_m(&self) -> f64 {
        self.voxel_m
    }

    /// The integer voxel coordinates of `p` \[m\], or `None` when one is beyond `i32` (more
    /// than 2³¹ voxels from the origin).
    pub fn voxel_of(&self, p: &Point3<f64>) -> Option<[i32; 3]> {
        let mut key = [0i32; 3];
        for (k, c) in key.iter_mut().zip(p.iter()) {
            let v = (c / self.voxel_m).floor();
            if !(v >= f64::from(i32::MIN) && v <= f64::from(i32::MAX)) {
                return None;
            }
            *k = v as i32;
        }
        Some(key)
    }

    /// Adds one cloud: `points` (metres, in the cloud's frame) moved into the world by
    /// `world_from_cloud`, with their `intensity` when given (parallel to `points`; a shorter
    /// slice gives 0 to the rest). Points that are not finite, or too far for a voxel key, are
    /// skipped and counted ([`Self::points_out_of_range`]).
    pub fn add_cloud(
        &mut self,
        world_from_cloud: &Isometry3<f64>,
        points: &[Point3<f64>],
        intensity: Option<&[f32]>,
    ) {
        for (n, p) in points.iter().enumerate() {
            let w = world_from_cloud * p;
            let Some(key) = self.voxel_of(&w) else {
                self.points_out_of_range += 1;
                continue;
            };
            let i = intensity
                .and_then(|v| v.get(n))
                .map_or(0.0, |&v| f64::from(v));
            let next = self.cells.len() as u32;
            let at = *self.index.entry(key).or_insert(next);
            if at == next {
                self.cells.push(Cell::default());
            }
            let c = &mut self.cells[at as usize];
            c.sum[0] += w.x;
            c.sum[1] += w.y;
            c.sum[2] += w.z;
            c.intensity_sum += i;
            c.count += 1;
            self.points_added += 1;
        }
    }

    /// The occupied voxels' cells, in first-hit order.
    pub fn cells(&self) -> &[Cell] {
        &self.cells
    }

    /// Number of occupied voxels (points of the map).
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// True when no point was added.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Points accumulated so far.
    pub fn points_added(&self) -> u64 {
        self.points_added
    }

    /// Points skipped because their voxel key would not fit in `i32` (or were not finite).
    pub fn points_out_of_range(&self) -> u64 {
        self.points_out_of_range
    }

    /// The map as flat `f32` rows: `x, y, z` (metres) and, with `with_intensity`, the mean
    /// intensity; one row per occupied voxel in [`Self::cells`] order.
    pub fn to_rows(&self, with_intensity: bool) -> Vec<f32> {
        let cols = if with_intensity { 4 } else { 3 };
        let mut out = Vec::with_capacity(self.cells.len() * cols);
        for c in &self.cells {
            let p = c.centroid();
            out.extend([p.x as f32, p.y as f32, p.z as f32]);
            if with_intensity {
                out.push(c.mean_intensity() as f32);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use rand::{RngExt, SeedableRng};
    use std::collections::BTreeMap;

    /// A cloud: its pose, points and intensities.
    type Cloud = (Isometry3<f64>, Vec<Point3<f64>>, Vec<f32>);

    /// Per-voxel mean by brute force: every point's voxel computed independently, sums in a
    /// sorted map.
    fn brute_force(voxel: f64, clouds: &[Cloud]) -> BTreeMap<[i64; 3], ([f64; 3], f64, u32)> {
        let mut m: BTreeMap<[i64; 3], ([f64; 3], f64, u32)> = BTreeMap::new();
        for (pose, pts, inten) in clouds {
            for (p, &i) in pts.iter().zip(inten) {
                let w = pose.transform_point(p);
                let key = [
                    (w.x / voxel).floor() as i64,
                    (w.y / voxel).floor() as i64,
                    (w.z / voxel).floor() as i64,
                ];
                let e = m.entry(key).or_default();
                e.0[0] += w.x;
                e.0[1] += w.y;
                e.0[2] += w.z;
                e.1 += f64::from(i);
                e.2 += 1;
            }
        }
        m
    }

    #[test]
    fn matches_brute_force_voxel_mean() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let voxel = 0.3;
        let clouds: Vec<_> = (0..5)
            .map(|k| {
                let pose = Isometry3::from_parts(
                    Translation3::new(0.4 * k as f64, -0.1 * k as f64, 0.2),
                    UnitQuaternion::from_euler_angles(0.1 * k as f64, -0.2, 0.3 * k as f64),
                );
                let pts: Vec<Point3<f64>> = (0..400)
                    .map(|_| {
                        Point3::new(
                            rng.random_range(-2.0..2.0),
                            rng.random_range(-2.0..2.0),
                            rng.random_range(-1.0..1.0),
                        )
                    })
                    .collect();
                let inten: Vec<f32> = (0..400).map(|_| rng.random_range(0.0..100.0)).collect();
                (pose, pts, inten)
            })
            .collect();
        let mut map = VoxelMap::new(voxel).unwrap();
        for (pose, pts, inten) in &clouds {
            map.add_cloud(pose, pts, Some(inten));
        }
        let truth = brute_force(voxel, &clouds);
        assert_eq!(map.len(), truth.len());
        assert_eq!(map.points_added(), 2000);
        let mut seen = std::collections::HashSet::new();
        for c in map.cells() {
            let p = c.centroid();
            // The centroid lies in its own voxel (a voxel is convex), so it names its truth.
            let key = [
                (p.x / voxel).floor() as i64,
                (p.y / voxel).floor() as i64,
                (p.z / voxel).floor() as i64,
            ];
            assert!(seen.insert(key), "two cells in voxel {key:?}");
            let (sum, isum, n) = truth[&key];
            assert_eq!(c.count, n);
            for d in 0..3 {
                assert!((p[d] - sum[d] / f64::from(n)).abs() < 1e-12);
            }
            assert!((c.mean_intensity() - isum / f64::from(n)).abs() < 1e-9);
        }
    }

    #[test]
    fn negative_coordinates_floor_not_truncate() {
        let mut map = VoxelMap::new(1.0).unwrap();
        let pts = [Point3::new(-0.5, 0.5, 0.5), Point3::new(0.5, 0.5, 0.5)];
        map.add_cloud(&Isometry3::identity(), &pts, None);
        assert_eq!(map.len(), 2);
        assert_eq!(map.voxel_of(&pts[0]), Some([-1, 0, 0]));
        assert_eq!(map.to_rows(false), vec![-0.5, 0.5, 0.5, 0.5, 0.5, 0.5]);
    }

    #[test]
    fn far_and_non_finite_points_are_counted_not_added() {
        let mut map = VoxelMap::new(0.01).unwrap();
        let pts = [
            Point3::new(1e9, 0.0, 0.0),
            Point3::new(f64::NAN, 0.0, 0.0),
            Point3::new(0.0, 0.0, 0.0),
        ];
        map.add_cloud(&Isometry3::identity(), &pts, Some(&[1.0, 2.0, 3.0]));
        assert_eq!((map.len(), map.points_out_of_range()), (1, 2));
        assert_eq!(map.to_rows(true), vec![0.0, 0.0, 0.0, 3.0]);
    }

    #[test]
    fn bad_voxel_is_an_error() {
        for v in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(VoxelMap::new(v).is_err(), "{v}");
        }
    }
}
