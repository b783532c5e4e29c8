//! The body of `sensor_msgs/PointCloud2` (everything after the header), shared by the ROS 1 and
//! ROS 2 codecs: the fields are the same, only the wire primitives differ.

use nalgebra::Point3;

use super::packed::{PackedField, PackedLayout, check_field_fits, extract};
use super::{DecodeError, Header, PointCloud, WireRead, WireWrite, datatype};
use crate::io::scalar::Scalar;

/// Smallest serialized `PointField`: empty name (4) + offset (4) + datatype (1) + count (4) in
/// ROS 1; CDR adds 3 bytes of padding, so this bounds both.
const MIN_POINT_FIELD_BYTES: usize = 13;

struct RawField {
    name: String,
    offset: u32,
    datatype: u8,
    count: u32,
}

/// Decodes the body of a `sensor_msgs/PointCloud2` after its header (the same fields in ROS 1 and
/// ROS 2), from `r`.
///
/// - Coordinates come from the fields named `x`, `y`, `z` and the optional `intensity`, each of
///   any `PointField` datatype (INT8 … FLOAT64), converted to `f64` (`f32` for intensity). If
///   several fields share a name, the first is used.
/// - A field with `count > 1` contributes its element 0; `count == 0` is read like 1.
/// - The point data's byte order is `is_bigendian`, independent of the CDR byte order.
/// - Point `(row, col)` starts at `row·row_step + col·point_step` in `data`; `row_step` is
///   only used (and must be ≥ `width·point_step`) when `height > 1`. Padding inside a point and
///   after each row is skipped; extra bytes after the last point are ignored.
/// - Points with a NaN or ±Inf coordinate are dropped and counted in
///   [`PointCloud::num_dropped_non_finite`]; points of an organised cloud (`height > 1`) exactly
///   at (0, 0, 0), the drivers' "no return", in [`PointCloud::num_dropped_zero`].
/// - Points whose per-point time is a glitch (not finite, or more than
///   [`crate::io::point_time::POINT_TIME_BOUND_S`] from the cloud's median point time) are
///   dropped and counted in [`PointCloud::num_dropped_time`].
/// - An empty cloud (`width·height == 0`) decodes without requiring `x`, `y`, `z` fields.
/// - Fields other than x, y, z, intensity are not validated.
/// - The points are written into `points` (cleared first), so that a stream of clouds can reuse
///   one buffer.
///
/// # Errors
/// [`DecodeError`] naming the field for a truncated message, a
/// missing `x`/`y`/`z`, an unknown datatype (`fields[i].datatype`), a field that does not fit in
/// `point_step` (`fields[i]`), `row_step < width·point_step` with `height > 1` (`row_step`), or
/// `data` shorter than `(height−1)·row_step + width·point_step` (`data`).
pub(crate) fn decode_body<'a>(
    r: &mut impl WireRead<'a>,
    header: Header,
    points: Vec<Point3<f64>>,
) -> Result<PointCloud, DecodeError> {
    let body = read_body(r)?;
    let (width, height) = (body.width, body.height);
    let empty = PointCloud {
        header,
        points: Vec::new(),
        intensity: None,
        times: None,
        width,
        height,
        num_dropped_non_finite: 0,
        num_dropped_far: 0,
        num_dropped_zero: 0,
        num_dropped_tag: 0,
        num_dropped_time: 0,
    };
    if width == 0 || height == 0 {
        return Ok(empty);
    }
    let (layout, time_name) = layout_of(&body)?;
    check_extent(&body)?;
    // All of these are ≤ data.len(), so they fit usize.
    let ex = extract(
        body.data,
        &layout,
        height as usize,
        width as usize,
        if height > 1 {
            body.row_step as usize
        } else {
            0
        },
        body.point_step as usize,
        points,
    );
    let stamp_s = empty.header.stamp.to_ns() as f64 * 1e-9;
    let times = time_name
        .zip(layout.time)
        .zip(ex.times)
        .map(|((name, f), raw)| crate::io::point_time::point_times(name, f.kind, raw, stamp_s));
    let mut cloud = PointCloud {
        points: ex.points,
        intensity: ex.intensity,
        times,
        num_dropped_non_finite: ex.num_dropped_non_finite,
        num_dropped_far: ex.num_dropped_far,
        num_dropped_zero: ex.num_dropped_zero,
        num_dropped_tag: 0,
        ..empty
    };
    cloud.drop_time_glitches();
    Ok(cloud)
}

/// The fields of a PointCloud2 body as the wire has them, `data` borrowed from the message.
struct RawBody<'a> {
    height: u32,
    width: u32,
    fields: Vec<RawField>,
    is_bigendian: bool,
    point_step: u32,
    row_step: u32,
    data: &'a [u8],
}

/// Reads the body's fields from `r` (every length checked against what remains).
fn read_body<'a>(r: &mut impl WireRead<'a>) -> Result<RawBody<'a>, DecodeError> {
    let height = r.u32("height")?;
    let width = r.u32("width")?;
    let n_fields = r.sequence_len("fields", MIN_POINT_FIELD_BYTES)?;
    let mut fields = Vec::with_capacity(n_fields);
    for i in 0..n_fields {
        let name = r.string(&format!("fields[{i}].name"))?;
        let offset = r.u32(&format!("fields[{i}].offset"))?;
        let datatype = r.u8(&format!("fields[{i}].datatype"))?;
        let count = r.u32(&format!("fields[{i}].count"))?;
        fields.push(RawField {
            name,
            offset,
            datatype,
            count,
        });
    }
    let is_bigendian = r.bool("is_bigendian")?;
    let point_step = r.u32("point_step")?;
    let row_step = r.u32("row_step")?;
    let data_len = r.sequence_len("data", 1)?;
    let data = r.bytes(data_len, "data")?;
    let _is_dense = r.bool("is_dense")?;
    Ok(RawBody {
        height,
        width,
        fields,
        is_bigendian,
        point_step,
        row_step,
        data,
    })
}

/// The packed layout of `body`'s points: `x`, `y`, `z` (required), `intensity`, and the first
/// time field found ([`crate::io::point_time::TIME_FIELDS`], returned by name), each checked to
/// fit in `point_step`.
fn layout_of(body: &RawBody<'_>) -> Result<(PackedLayout, Option<&'static str>), DecodeError> {
    let fields = &body.fields;
    let find = |name: &str, required: bool| -> Result<Option<PackedField>, DecodeError> {
        let Some(i) = fields.iter().position(|f| f.name == name) else {
            return if required {
                let names: Vec<&str> = fields.iter().map(|f| f.name.as_str()).collect();
                Err(DecodeError::new(
                    "fields",
                    format!("no field named '{name}' (fields: {names:?})"),
                ))
            } else {
                Ok(None)
            };
        };
        let f = &fields[i];
        let kind = Scalar::from_ros(f.datatype).ok_or_else(|| {
            DecodeError::new(
                format!("fields[{i}].datatype"),
                format!(
                    "unknown datatype {} for field '{name}' (expected 1..=8, INT8..FLOAT64)",
                    f.datatype
                ),
            )
        })?;
        check_field_fits(
            &format!("fields[{i}]"),
            u64::from(f.offset),
            kind,
            u64::from(f.count),
            u64::from(body.point_step),
        )
        .map(Some)
    };
    let mut time_field = None;
    for name in crate::io::point_time::TIME_FIELDS {
        if let Some(f) = find(name, false)? {
            time_field = Some((name, f));
            break;
        }
    }
    let layout = PackedLayout {
        xyz: [find("x", true)?, find("y", true)?, find("z", true)?],
        intensity: find("intensity", false)?,
        time: time_field.map(|(_, f)| f),
        big_endian: body.is_bigendian,
    };
    Ok((layout, time_field.map(|(name, _)| name)))
}

/// Checks that `body`'s rows do not overlap and that its data holds every point:
/// `row_step ≥ width·point_step` when `height > 1`, and
/// `(height−1)·row_step + width·point_step ≤ data.len()`.
fn check_extent(body: &RawBody<'_>) -> Result<(), DecodeError> {
    let (w, h, ps, rs) = (
        u64::from(body.width),
        u64::from(body.height),
        u64::from(body.point_step),
        u64::from(body.row_step),
    );
    let row_bytes = w * ps; // < 2^64
    if h > 1 && rs < row_bytes {
        return Err(DecodeError::new(
            "row_step",
            format!(
                "row step {rs} is smaller than width {w} × point step {ps} = {row_bytes}, so \
                 rows would overlap"
            ),
        ));
    }
    let need = (h - 1)
        .checked_mul(rs)
        .and_then(|v| v.checked_add(row_bytes));
    match need {
        Some(need) if need <= body.data.len() as u64 => Ok(()),
        _ => Err(DecodeError::new(
            "data",
            format!(
                "{} bytes, but height {h}, width {w}, point step {ps} and row step {rs} \
                 need (height−1)·row_step + width·point_step = {} bytes",
                body.data.len(),
                need.map_or_else(|| "more than 2^64".to_string(), |n| n.to_string())
            ),
        )),
    }
}

/// Writes the body of a little-endian `sensor_msgs/PointCloud2` (after its header) with FLOAT32 fields `x`, `y`, `z`
/// (offsets 0, 4, 8) and, if `intensity` is given, `intensity` (offset 12): `point_step` 12 or
/// 16, `height` 1, `width` = number of points, `row_step` = `width·point_step`,
/// `is_bigendian` false, `is_dense` true unless a coordinate is non-finite. Coordinates are in
/// metres and rounded to `f32`.
///
/// # Panics
/// If `intensity` has a different length from `points`, or the data would exceed 4 GiB.
pub(crate) fn encode_body<T>(
    w: &mut impl WireWrite,
    points: &[Point3<T>],
    intensity: Option<&[f32]>,
) where
    T: nalgebra::Scalar + Copy + Into<f64>,
{
    if let Some(i) = intensity {
        assert_eq!(
            i.len(),
            points.len(),
            "intensity must have one value per point"
        );
    }
    let names: &[&str] = if intensity.is_some() {
        &["x", "y", "z", "intensity"]
    } else {
        &["x", "y", "z"]
    };
    let point_step = 4 * names.len();
    let data_len = points.len() * point_step;
    let width = u32::try_from(points.len()).expect("fewer than 2^32 points");
    let data_len_u32 = u32::try_from(data_len).expect("point data shorter than 4 GiB");

    w.u32(1); // height
    w.u32(width);
    w.sequence_len(names.len());
    for (i, name) in names.iter().enumerate() {
        w.string(name);
        w.u32(4 * i as u32);
        w.u8(datatype::FLOAT32);
        w.u32(1);
    }
    w.bool(false); // is_bigendian
    w.u32(point_step as u32);
    w.u32(data_len_u32); // row_step
    w.u32(data_len_u32);
    let mut dense = true;
    for (k, p) in points.iter().enumerate() {
        for c in [p.x, p.y, p.z] {
            let c: f64 = c.into();
            dense &= c.is_finite();
            w.raw(&(c as f32).to_le_bytes());
        }
        if let Some(i) = intensity {
            w.raw(&i[k].to_le_bytes());
        }
    }
    w.bool(dense);
}

/// Bytes of point data [`encode_body`] writes for `n` points.
pub(crate) fn data_len(n: usize, with_intensity: bool) -> usize {
    n * if with_intensity { 16 } else { 12 }
}
