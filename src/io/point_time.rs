//! Per-point acquisition times in point clouds, as real LiDAR drivers write them, for deskewing
//! (`crate::geometry::deskew`). The field is found by name and its unit and reference by its
//! datatype and values:
//!
//! | driver | field | datatype | meaning |
//! |---|---|---|---|
//! | Ouster | `t` | UINT32 | ns since the scan start (the header stamp) |
//! | Livox | `offset_time` | UINT32 | ns since the header stamp |
//! | Velodyne | `time` | FLOAT32 | s relative to the header stamp (may be negative) |
//! | Hesai | `timestamp` | FLOAT64 | absolute UNIX time, s |
//! | RoboSense and others | `time_stamp` | FLOAT64 | absolute UNIX time, s |
//!
//! Integer fields are nanoseconds; floating-point ones seconds, absolute when their median
//! magnitude exceeds [`ABSOLUTE_TIME_MIN_S`] (then the header stamp is subtracted).

use super::scalar::Scalar;

/// Names of time fields, in the order they are looked for.
pub const TIME_FIELDS: [&str; 5] = ["t", "offset_time", "time", "timestamp", "time_stamp"];

/// Floating-point times whose median magnitude is above this are absolute \[s\] (1e6 s is 11 days:
/// no scan lasts that long, and every UNIX time since 1970 is above it).
pub const ABSOLUTE_TIME_MIN_S: f64 = 1e6;

/// How a cloud's time field was read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TimeConvention {
    /// Integer nanoseconds relative to the header stamp (Ouster `t`, Livox `offset_time`).
    RelativeNs,
    /// Seconds relative to the header stamp (Velodyne `time`).
    RelativeS,
    /// Absolute seconds (Hesai `timestamp`, `time_stamp`).
    AbsoluteS,
}

/// A cloud's per-point times.
#[derive(Debug, Clone, PartialEq)]
pub struct PointTimes {
    /// The field they came from.
    pub field: String,
    /// How its values were read.
    pub convention: TimeConvention,
    /// Seconds after the header stamp, one per point of the cloud.
    pub seconds: Vec<f64>,
}

/// `raw` values of time field `field` (read as `f64` from its datatype `kind`) as seconds after
/// `stamp_s` (the header stamp, seconds).
pub(crate) fn point_times(field: &str, kind: Scalar, raw: Vec<f64>, stamp_s: f64) -> PointTimes {
    let (convention, seconds) = if !kind.is_float() {
        (
            TimeConvention::RelativeNs,
            raw.iter().map(|t| t * 1e-9).collect(),
        )
    } else {
        let mut mags: Vec<f64> = raw.iter().map(|t| t.abs()).collect();
        let mid = mags.len() / 2;
        let median = if mags.is_empty() {
            0.0
        } else {
            *mags.select_nth_unstable_by(mid, f64::total_cmp).1
        };
        if median > ABSOLUTE_TIME_MIN_S {
            (
                TimeConvention::AbsoluteS,
                raw.iter().map(|t| t - stamp_s).collect(),
            )
        } else {
            (TimeConvention::RelativeS, raw)
        }
    };
    PointTimes {
        field: field.to_string(),
        convention,
        seconds,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_driver_convention_is_read_as_seconds_after_the_stamp() {
        let stamp = 1_700_000_000.25;
        // Ouster t / Livox offset_time: uint32 ns.
        let t = point_times("t", Scalar::U32, vec![0.0, 50_000_000.0], stamp);
        assert_eq!(
            (t.convention, t.seconds.clone()),
            (TimeConvention::RelativeNs, vec![0.0, 0.05])
        );
        let t = point_times("offset_time", Scalar::U32, vec![1e8], stamp);
        assert_eq!(t.seconds, [0.1]);
        // Velodyne time: float32 s, relative (here before the stamp).
        let t = point_times("time", Scalar::F32, vec![-0.1, -0.05, 0.0], stamp);
        assert_eq!(
            (t.convention, t.seconds.clone()),
            (TimeConvention::RelativeS, vec![-0.1, -0.05, 0.0])
        );
        // Hesai timestamp / time_stamp: float64 absolute s.
        let t = point_times("timestamp", Scalar::F64, vec![stamp, stamp + 0.08], stamp);
        assert_eq!(t.convention, TimeConvention::AbsoluteS);
        assert!((t.seconds[1] - 0.08).abs() < 1e-6 && t.seconds[0] == 0.0);
    }
}
