//! KITTI velodyne scan reader (`.bin`): a flat array of little-endian f32 records
//! `x, y, z, intensity` in metres, 16 bytes per point, no header.

use std::path::Path;

use nalgebra::Point3;

use super::{format_err, push_finite};
use crate::Result;

/// Bytes per KITTI point: four little-endian f32 (x, y, z, intensity).
const KITTI_POINT_BYTES: usize = 16;

/// Parses a KITTI velodyne scan held in memory; `path` is used only in error messages.
///
/// Returns the finite x, y, z in metres (sensor frame), dropping intensity.
///
/// # Errors
/// [`crate::Error::Format`] if the length is not a multiple of 16 bytes.
pub fn parse_kitti_bin(bytes: &[u8], path: &Path) -> Result<Vec<Point3<f64>>> {
    if !bytes.len().is_multiple_of(KITTI_POINT_BYTES) {
        return Err(format_err(
            path,
            format!(
                "KITTI .bin length {} is not a multiple of {KITTI_POINT_BYTES} bytes (x, y, z, intensity as f32)",
                bytes.len()
            ),
        ));
    }
    let f = |b: &[u8]| f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    let mut points = Vec::with_capacity(bytes.len() / KITTI_POINT_BYTES);
    for rec in bytes.chunks_exact(KITTI_POINT_BYTES) {
        push_finite(&mut points, f(&rec[0..4]), f(&rec[4..8]), f(&rec[8..12]));
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Error;

    #[test]
    fn reads_xyz_and_drops_intensity_and_non_finite() {
        let mut b = Vec::new();
        for v in [
            1.5f32,
            -2.0,
            0.25,
            0.9,
            f32::INFINITY,
            0.0,
            0.0,
            0.1,
            10.0,
            20.0,
            -30.0,
            0.0,
        ] {
            b.extend(v.to_le_bytes());
        }
        let pts = parse_kitti_bin(&b, Path::new("scan.bin")).unwrap();
        assert_eq!(
            pts,
            vec![Point3::new(1.5, -2.0, 0.25), Point3::new(10.0, 20.0, -30.0)]
        );
        assert!(
            parse_kitti_bin(&[], Path::new("empty.bin"))
                .unwrap()
                .is_empty()
        );
    }

    #[test]
    fn length_not_multiple_of_16_is_an_error() {
        let err = parse_kitti_bin(&[0u8; 20], Path::new("scan.bin")).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, Error::Format { .. }));
        assert!(
            msg.contains("scan.bin") && msg.contains("multiple of 16"),
            "{msg}"
        );
    }
}
