//! Scan Context (G. Kim & A. Kim, "Scan Context: Egocentric Spatial Descriptor for Place
//! Recognition within 3D Point Cloud Map", IROS 2018), kept as the LiDAR baseline that
//! [`super::descriptor::Descriptor`] was measured against (`examples/loop_descriptors.rs`).
//!
//! The sensor-frame cloud is cut into [`SC_RINGS`] rings × [`SC_SECTORS`] sectors around the
//! z axis out to [`SC_MAX_RANGE_M`]; each cell keeps the highest `z + SC_HEIGHT_OFFSET_M` of its
//! points (0 when empty). Two descriptors are compared at every column shift (Eq. 5–6 of the
//! paper: the mean cosine distance of the columns), which makes the distance invariant to yaw up
//! to half a sector (3°). It needs an up axis: it is *not* invariant to roll or pitch, and an
//! RGB-D camera (z forward) has none. State: 1,200 `f32` + the 20-`f32` ring key = 4,880 bytes.
//!
//! NOTE: as SC-A-LOAM's `distDirectSC` (not the paper's plain mean), columns empty in either
//! descriptor are left out of the mean; the ring key is the mean height of each ring, as
//! SC-A-LOAM, not the paper's occupancy ratio.

use nalgebra::Point3;

/// Rings (radial bins), as the paper: 20.
pub const SC_RINGS: usize = 20;
/// Sectors (azimuth bins, 6° each), as the paper: 60.
pub const SC_SECTORS: usize = 60;
/// Radius of the descriptor \[m\], as the paper: 80.
pub const SC_MAX_RANGE_M: f64 = 80.0;
/// Added to z so that cell heights are positive for a car-mounted LiDAR \[m\] (SC-A-LOAM's
/// `LIDAR_HEIGHT`): 2.
pub const SC_HEIGHT_OFFSET_M: f64 = 2.0;

/// A Scan Context descriptor (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct ScanContext {
    /// Max height per cell, ring-major (`cells[ring * SC_SECTORS + sector]`).
    pub cells: Vec<f32>,
    /// Mean of each ring (rotation-invariant retrieval key).
    pub ring_key: [f32; SC_RINGS],
}

impl ScanContext {
    /// The descriptor of `points` (sensor frame, z up, metres); points beyond
    /// [`SC_MAX_RANGE_M`] in the xy plane are ignored.
    pub fn new(points: &[Point3<f64>]) -> Self {
        let mut cells = vec![f32::NEG_INFINITY; SC_RINGS * SC_SECTORS];
        let ring_m = SC_MAX_RANGE_M / SC_RINGS as f64;
        for p in points {
            let r = p.x.hypot(p.y);
            if !r.is_finite() || r >= SC_MAX_RANGE_M {
                continue;
            }
            let ring = ((r / ring_m) as usize).min(SC_RINGS - 1);
            let turn = (p.y.atan2(p.x) + std::f64::consts::PI) / std::f64::consts::TAU;
            let sector = ((turn * SC_SECTORS as f64) as usize).min(SC_SECTORS - 1);
            let c = &mut cells[ring * SC_SECTORS + sector];
            *c = c.max((p.z + SC_HEIGHT_OFFSET_M) as f32);
        }
        for c in &mut cells {
            if *c == f32::NEG_INFINITY {
                *c = 0.0;
            }
        }
        let mut ring_key = [0.0f32; SC_RINGS];
        for (ring, key) in ring_key.iter_mut().enumerate() {
            let row = &cells[ring * SC_SECTORS..(ring + 1) * SC_SECTORS];
            *key = row.iter().sum::<f32>() / SC_SECTORS as f32;
        }
        Self { cells, ring_key }
    }

    /// The smallest column-shift distance in `[0, 2]` (1 − mean column cosine) and the shift
    /// (sectors by which `other`'s columns are rotated) that gives it; ties go to the smaller
    /// shift. 1 when no shift has a column occupied in both.
    pub fn align(&self, other: &Self) -> (f64, usize) {
        let mut best = (f64::INFINITY, 0);
        for shift in 0..SC_SECTORS {
            let d = self.distance_at(other, shift);
            if d < best.0 {
                best = (d, shift);
            }
        }
        best
    }

    /// [`Self::align`]'s distance.
    pub fn distance(&self, other: &Self) -> f64 {
        self.align(other).0
    }

    fn column(&self, sector: usize) -> impl Iterator<Item = f64> + '_ {
        (0..SC_RINGS).map(move |ring| f64::from(self.cells[ring * SC_SECTORS + sector]))
    }

    fn distance_at(&self, other: &Self, shift: usize) -> f64 {
        let (mut sum, mut columns) = (0.0, 0usize);
        for s in 0..SC_SECTORS {
            let t = (s + shift) % SC_SECTORS;
            let (mut dot, mut na, mut nb) = (0.0, 0.0, 0.0);
            for (a, b) in self.column(s).zip(other.column(t)) {
                dot += a * b;
                na += a * a;
                nb += b * b;
            }
            if na > 0.0 && nb > 0.0 {
                sum += dot / (na.sqrt() * nb.sqrt());
                columns += 1;
            }
        }
        if columns == 0 {
            1.0
        } else {
            1.0 - sum / columns as f64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    #[test]
    fn yaw_by_whole_sectors_is_found_by_the_shift() {
        // A post per sector at different ranges and heights, well inside the cells.
        let points: Vec<Point3<f64>> = (0..60)
            .map(|i| {
                let a = (f64::from(i) * 6.0 + 3.0).to_radians(); // sector centres
                let r = 5.5 + f64::from(i * 37 % 70); // no period, off the 4 m ring edges
                Point3::new(r * a.cos(), r * a.sin(), f64::from(i % 5) * 0.5)
            })
            .collect();
        let sc = ScanContext::new(&points);
        let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), (6.0f64 * 10.0).to_radians());
        let rotated: Vec<_> = points.iter().map(|p| yaw * p).collect();
        let (d, shift) = sc.align(&ScanContext::new(&rotated));
        assert!(d < 1e-9, "distance {d}");
        assert_eq!(shift, 10);
        assert_eq!(sc.ring_key, ScanContext::new(&rotated).ring_key);
    }
}
