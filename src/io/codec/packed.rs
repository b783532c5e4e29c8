//! Packed point extraction, shared by the `sensor_msgs/PointCloud2` decoders (ROS 1 and ROS 2)
//! and the `foxglove.PointCloud` decoder: a validated field layout, then one pass over the point
//! records.

use nalgebra::Point3;

use super::{DecodeError, datatype};
use crate::io::scalar::Scalar;

impl Scalar {
    /// From a `sensor_msgs/PointField` datatype constant.
    pub(crate) fn from_ros(datatype: u8) -> Option<Self> {
        Some(match datatype {
            datatype::INT8 => Self::I8,
            datatype::UINT8 => Self::U8,
            datatype::INT16 => Self::I16,
            datatype::UINT16 => Self::U16,
            datatype::INT32 => Self::I32,
            datatype::UINT32 => Self::U32,
            datatype::FLOAT32 => Self::F32,
            datatype::FLOAT64 => Self::F64,
            _ => return None,
        })
    }
}

/// A validated field: `offset + kind.size() <= point_step`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PackedField {
    pub(crate) offset: usize,
    pub(crate) kind: Scalar,
}

/// Validated layout of a packed cloud. Coordinates that are `None` read as 0 (foxglove allows
/// 2-D clouds; the PointCloud2 decoder requires all three).
#[derive(Debug, Clone, Copy)]
pub(crate) struct PackedLayout {
    pub(crate) xyz: [Option<PackedField>; 3],
    pub(crate) intensity: Option<PackedField>,
    /// A per-point time field (read as `f64`).
    pub(crate) time: Option<PackedField>,
    pub(crate) big_endian: bool,
}

/// Checks that `kind` at `offset` fits in `point_step`, naming `field` otherwise.
pub(crate) fn check_field_fits(
    field: &str,
    offset: u64,
    kind: Scalar,
    count: u64,
    point_step: u64,
) -> Result<PackedField, DecodeError> {
    let end = offset + kind.size() as u64 * count.max(1);
    if end > point_step {
        return Err(DecodeError::new(
            field,
            format!(
                "offset {offset} + {} element(s) of {} bytes ends at byte {end}, beyond point \
                 step {point_step}",
                count.max(1),
                kind.size()
            ),
        ));
    }
    // offset < point_step <= u32::MAX fits usize on every supported target.
    Ok(PackedField {
        offset: offset as usize,
        kind,
    })
}

/// Points and intensities extracted from packed data.
pub(crate) struct Extracted {
    pub(crate) points: Vec<Point3<f64>>,
    pub(crate) intensity: Option<Vec<f32>>,
    pub(crate) times: Option<Vec<f64>>,
    pub(crate) num_dropped_non_finite: usize,
    pub(crate) num_dropped_zero: usize,
}

/// Reads `rows × cols` points starting at `row·row_step + col·point_step` in `data`. The caller
/// has checked that every point lies inside `data` and every field inside `point_step`.
///
/// Points with a non-finite coordinate are dropped and counted; so are points exactly at
/// (0, 0, 0) when the cloud is organised (`rows > 1`), which is how organised LiDAR and depth
/// clouds mark a pixel without a return.
pub(crate) fn extract(
    data: &[u8],
    layout: &PackedLayout,
    rows: usize,
    cols: usize,
    row_step: usize,
    point_step: usize,
) -> Extracted {
    let n = rows * cols;
    let mut points = Vec::with_capacity(n);
    let mut intensity = layout.intensity.map(|_| Vec::with_capacity(n));
    let mut times = layout.time.map(|_| Vec::with_capacity(n));
    let mut dropped = 0;
    let mut dropped_zero = 0;
    let organised = rows > 1;
    let read = |point: &[u8], f: Option<PackedField>| {
        f.map_or(0.0, |f| f.kind.read(&point[f.offset..], layout.big_endian))
    };
    for row in 0..rows {
        for col in 0..cols {
            let start = row * row_step + col * point_step;
            let point = &data[start..start + point_step];
            let (x, y, z) = (
                read(point, layout.xyz[0]),
                read(point, layout.xyz[1]),
                read(point, layout.xyz[2]),
            );
            if !(x.is_finite() && y.is_finite() && z.is_finite()) {
                dropped += 1;
                continue;
            }
            if organised && x == 0.0 && y == 0.0 && z == 0.0 {
                dropped_zero += 1;
                continue;
            }
            points.push(Point3::new(x, y, z));
            if let Some(out) = intensity.as_mut() {
                out.push(read(point, layout.intensity) as f32);
            }
            if let Some(out) = times.as_mut() {
                out.push(read(point, layout.time));
            }
        }
    }
    Extracted {
        points,
        intensity,
        times,
        num_dropped_non_finite: dropped,
        num_dropped_zero: dropped_zero,
    }
}

// ---------------------------------------------------------------------------------------------
// sensor_msgs/msg/PointCloud2
// ---------------------------------------------------------------------------------------------
