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

impl PackedLayout {
    /// The offset of `field` if it is a little-endian float32 (what LiDAR and depth drivers
    /// write), which [`extract`] reads directly instead of through `Scalar::read`'s per-field
    /// dispatch (the same values).
    fn le_f32_offset(&self, field: Option<PackedField>) -> Option<usize> {
        field
            .filter(|f| !self.big_endian && f.kind == Scalar::F32)
            .map(|f| f.offset)
    }
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
#[derive(Default)]
pub(crate) struct Extracted {
    pub(crate) points: Vec<Point3<f64>>,
    pub(crate) intensity: Option<Vec<f32>>,
    pub(crate) times: Option<Vec<f64>>,
    pub(crate) num_dropped_non_finite: usize,
    pub(crate) num_dropped_far: usize,
    pub(crate) num_dropped_zero: usize,
}

/// Reads `rows × cols` points starting at `row·row_step + col·point_step` in `data` into
/// `points` (cleared first: a buffer of an earlier cloud, whose capacity is reused). The caller
/// has checked that every point lies inside `data` and every field inside `point_step`.
///
/// Points with a non-finite coordinate are dropped and counted, and so are points with a
/// coordinate of magnitude [`super::MAX_COORDINATE_M`] or more; so are points exactly at
/// (0, 0, 0) when the cloud is organised (`rows > 1`), which is how organised LiDAR and depth
/// clouds mark a pixel without a return.
pub(crate) fn extract(
    data: &[u8],
    layout: &PackedLayout,
    rows: usize,
    cols: usize,
    row_step: usize,
    point_step: usize,
    points: Vec<Point3<f64>>,
) -> Extracted {
    // Little-endian float32 x, y, z: read directly.
    let f32_offsets = match layout.xyz.map(|f| layout.le_f32_offset(f)) {
        [Some(x), Some(y), Some(z)] => Some([x, y, z]),
        _ => None,
    };
    let cloud = Cloud {
        data,
        layout,
        rows,
        cols,
        row_step,
        point_step,
    };
    // One loop per coordinate reader, each compiled on its own.
    match f32_offsets {
        Some(o) => cloud.extract(points, |p| {
            let f = |o: usize| f64::from(le_f32(p, o));
            [f(o[0]), f(o[1]), f(o[2])]
        }),
        None => cloud.extract(points, |p| {
            let [x, y, z] = layout.xyz;
            [cloud.read(p, x), cloud.read(p, y), cloud.read(p, z)]
        }),
    }
}

/// The little-endian `f32` at byte `o` of `point` (one bounds check for its four bytes).
#[inline(always)]
fn le_f32(point: &[u8], o: usize) -> f32 {
    let bytes: [u8; 4] = point[o..o + 4].try_into().expect("four bytes");
    f32::from_le_bytes(bytes)
}

/// The arguments of [`extract`].
struct Cloud<'a> {
    data: &'a [u8],
    layout: &'a PackedLayout,
    rows: usize,
    cols: usize,
    row_step: usize,
    point_step: usize,
}

impl Cloud<'_> {
    /// Field `f` of `point` (0 when absent).
    #[inline(always)]
    fn read(&self, point: &[u8], f: Option<PackedField>) -> f64 {
        f.map_or(0.0, |f| {
            f.kind.read(&point[f.offset..], self.layout.big_endian)
        })
    }

    /// [`extract`] with `xyz` reading a point's coordinates.
    #[inline(always)]
    fn extract(&self, mut points: Vec<Point3<f64>>, xyz: impl Fn(&[u8]) -> [f64; 3]) -> Extracted {
        let Cloud {
            data,
            layout,
            rows,
            cols,
            row_step,
            point_step,
        } = *self;
        let n = rows * cols;
        points.clear();
        points.reserve(n);
        // Little-endian float32 intensity read directly too: the per-field dispatch of
        // `Scalar::read` was a third of a LiDAR frame's decoding.
        let intensity_f32_le = layout.le_f32_offset(layout.intensity);
        let mut intensity = layout.intensity.map(|_| Vec::with_capacity(n));
        let mut times = layout.time.map(|_| Vec::with_capacity(n));
        let (mut dropped, mut dropped_far, mut dropped_zero) = (0, 0, 0);
        let organised = rows > 1;
        for row in 0..rows {
            for col in 0..cols {
                let start = row * row_step + col * point_step;
                let point = &data[start..start + point_step];
                let [x, y, z] = xyz(point);
                if !super::within_bound(x, y, z) {
                    if x.is_finite() && y.is_finite() && z.is_finite() {
                        dropped_far += 1;
                    } else {
                        dropped += 1;
                    }
                    continue;
                }
                if organised && x == 0.0 && y == 0.0 && z == 0.0 {
                    dropped_zero += 1;
                    continue;
                }
                points.push(Point3::new(x, y, z));
                if let Some(out) = intensity.as_mut() {
                    out.push(match intensity_f32_le {
                        Some(o) => le_f32(point, o),
                        None => self.read(point, layout.intensity) as f32,
                    });
                }
                if let Some(out) = times.as_mut() {
                    out.push(self.read(point, layout.time));
                }
            }
        }
        Extracted {
            points,
            intensity,
            times,
            num_dropped_non_finite: dropped,
            num_dropped_far: dropped_far,
            num_dropped_zero: dropped_zero,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// sensor_msgs/msg/PointCloud2
// ---------------------------------------------------------------------------------------------

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// `extract` against a direct decoding of the same bytes, for little-endian float32
    /// coordinates and intensity (the direct paths) and for big-endian ones and float64
    /// coordinates with a uint8 intensity (the dispatching paths): finite points kept in order,
    /// non-finite and (organised) all-zero points counted; into a buffer that held more points
    /// before.
    #[test]
    fn extract_equals_direct_decoding() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        let (rows, cols, point_step) = (3usize, 50usize, 32usize);
        for (kind, big_endian) in [
            (Scalar::F32, false),
            (Scalar::F32, true),
            (Scalar::F64, false),
        ] {
            let size = if kind == Scalar::F32 { 4 } else { 8 };
            let offsets = [0, size, 2 * size];
            let field = |offset| Some(PackedField { offset, kind });
            let layout = PackedLayout {
                xyz: [field(offsets[0]), field(offsets[1]), field(offsets[2])],
                // float32 at 24 in the byte order of the coordinates, or uint8 at 28.
                intensity: Some(if kind == Scalar::F32 {
                    PackedField {
                        offset: 24,
                        kind: Scalar::F32,
                    }
                } else {
                    PackedField {
                        offset: 28,
                        kind: Scalar::U8,
                    }
                }),
                time: None,
                big_endian,
            };
            let mut data = vec![0u8; rows * cols * point_step];
            let mut want = Vec::new();
            let (mut non_finite, mut zero) = (0, 0);
            for (k, point) in data.chunks_exact_mut(point_step).enumerate() {
                let xyz: [f64; 3] = match k % 10 {
                    0 => [0.0; 3],
                    1 => [1.0, f64::NAN, 2.0],
                    2 => [f64::INFINITY, 0.0, 0.0],
                    _ => std::array::from_fn(|_| rng.random_range(-50.0..50.0)),
                };
                let mut stored = [0.0; 3];
                for ((o, v), s) in offsets.iter().zip(xyz).zip(&mut stored) {
                    let bytes: Vec<u8> = match (kind, big_endian) {
                        (Scalar::F32, false) => (v as f32).to_le_bytes().to_vec(),
                        (Scalar::F32, true) => (v as f32).to_be_bytes().to_vec(),
                        _ => v.to_le_bytes().to_vec(),
                    };
                    point[*o..*o + size].copy_from_slice(&bytes);
                    *s = if kind == Scalar::F32 {
                        f64::from(v as f32)
                    } else {
                        v
                    };
                }
                point[28] = k as u8;
                let value = rng.random_range(0.0f32..4096.0);
                let bytes = if big_endian {
                    value.to_be_bytes()
                } else {
                    value.to_le_bytes()
                };
                point[24..28].copy_from_slice(&bytes);
                let intensity = if kind == Scalar::F32 {
                    value
                } else {
                    f32::from(k as u8)
                };
                if !stored.iter().all(|c| c.is_finite()) {
                    non_finite += 1;
                } else if stored == [0.0; 3] {
                    zero += 1;
                } else {
                    want.push((Point3::from(stored), intensity));
                }
            }
            // Into a buffer that held another cloud: its points must not survive.
            let spare = vec![Point3::new(7.0, 8.0, 9.0); 2 * rows * cols];
            let got = extract(
                &data,
                &layout,
                rows,
                cols,
                cols * point_step,
                point_step,
                spare,
            );
            let got_pairs: Vec<(Point3<f64>, f32)> = got
                .points
                .iter()
                .copied()
                .zip(got.intensity.unwrap())
                .collect();
            assert_eq!(got_pairs, want, "{kind:?}, big endian {big_endian}");
            assert_eq!(got.num_dropped_non_finite, non_finite);
            assert_eq!(got.num_dropped_zero, zero);
        }
    }
}
