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
//!
//! Times are checked against [`POINT_TIME_BOUND_S`], so that no time can move a point, or a pose,
//! to a non-finite or absurd place:
//! - a point whose time is not finite, or further than the bound from the median of its cloud's
//!   finite times, is a glitch: the decoders drop it and count it
//!   ([`crate::io::codec::PointCloud::num_dropped_time`]; [`glitches`]);
//! - a cloud is deskewed only when every time left is within the bound of its header stamp
//!   ([`PointTimes::deskewable`]): a time field without a finite value, or on another clock than
//!   the stamp, leaves the cloud as measured.

use super::scalar::Scalar;

/// Names of time fields, in the order they are looked for.
pub const TIME_FIELDS: [&str; 5] = ["t", "offset_time", "time", "timestamp", "time_stamp"];

/// Floating-point times whose median magnitude is above this are absolute \[s\] (1e6 s is 11 days:
/// no scan lasts that long, and every UNIX time since 1970 is above it).
pub const ABSOLUTE_TIME_MIN_S: f64 = 1e6;

/// The bound on per-point times \[s\] (default and only value: 2 s). No LiDAR sweep that is
/// deskewed lasts longer (spinning sensors turn at 5–20 Hz, a 0.5 Hz accumulation spans 2 s), so
/// a point's time further than this from its cloud's median point time is a glitch (dropped),
/// and a cloud whose times are further than this from its header stamp is on another clock (not
/// deskewed). Integer fields (nanoseconds, at most 4.3 s as `uint32`) are checked alike.
pub const POINT_TIME_BOUND_S: f64 = 2.0;

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

impl PointTimes {
    /// Whether the cloud can be deskewed by these times: every one finite and within
    /// [`POINT_TIME_BOUND_S`] of the header stamp (so that the deskew of a point, and the pose
    /// referred back to the stamp, stay finite and within a sweep's motion).
    pub fn deskewable(&self) -> bool {
        self.seconds.iter().all(|t| t.abs() <= POINT_TIME_BOUND_S)
    }

    /// Whether the times differ from point to point: a field that holds one value for every
    /// point (a Livox driver writing `offset_time` 0 throughout) measures no sweep, and the cloud
    /// is not deskewed by it.
    pub fn varies(&self) -> bool {
        self.seconds
            .first()
            .is_some_and(|first| self.seconds.iter().any(|t| t != first))
    }
}

/// Which of a cloud's point times `seconds` are glitches: not finite, or further than
/// [`POINT_TIME_BOUND_S`] from the median of the finite ones. `None` when none is (the common
/// case, found in one pass without allocating) and when none is finite (the field then carries
/// no time, and the cloud is not deskewed: [`PointTimes::deskewable`]).
pub(crate) fn glitches(seconds: &[f64]) -> Option<Vec<bool>> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut all_finite = true;
    for &t in seconds {
        all_finite &= t.is_finite();
        lo = lo.min(t);
        hi = hi.max(t);
    }
    // Every time within the bound of every other: within it of their median too.
    if all_finite && hi - lo <= POINT_TIME_BOUND_S {
        return None;
    }
    let mut finite: Vec<f64> = seconds.iter().copied().filter(|t| t.is_finite()).collect();
    if finite.is_empty() {
        return None;
    }
    let mid = finite.len() / 2;
    let median = *finite.select_nth_unstable_by(mid, f64::total_cmp).1;
    let glitch: Vec<bool> = seconds
        .iter()
        .map(|&t| !t.is_finite() || (t - median).abs() > POINT_TIME_BOUND_S)
        .collect();
    glitch.contains(&true).then_some(glitch)
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

    #[test]
    fn only_times_that_differ_vary() {
        let times = |seconds: Vec<f64>| PointTimes {
            field: "offset_time".into(),
            convention: TimeConvention::RelativeNs,
            seconds,
        };
        assert!(!times(vec![]).varies());
        assert!(!times(vec![0.0; 5]).varies());
        assert!(!times(vec![0.03; 3]).varies());
        assert!(times(vec![0.0, 0.0, 1e-9]).varies());
    }

    #[test]
    fn glitches_are_non_finite_or_far_from_the_median() {
        assert_eq!(glitches(&[]), None);
        assert_eq!(glitches(&[0.0, 0.05, 0.1]), None);
        // A sweep of exactly the bound, from before the stamp: no glitch.
        assert_eq!(glitches(&[-1.0, 0.0, 1.0]), None);
        assert_eq!(
            glitches(&[0.0, f64::NAN, 0.05, f64::INFINITY, 1e300, -1e300, 0.1, 2.5]),
            Some(vec![false, true, false, true, true, true, false, true])
        );
        // No finite time: nothing to tell glitches by.
        assert_eq!(glitches(&[f64::NAN, f64::NEG_INFINITY]), None);
        // All on another clock, but consistent: none is a glitch; the cloud is not deskewed.
        assert_eq!(glitches(&[1e300, 1e300]), None);
        let times = |seconds: Vec<f64>| PointTimes {
            field: "time".into(),
            convention: TimeConvention::RelativeS,
            seconds,
        };
        assert!(!times(vec![1e300, 1e300]).deskewable());
        assert!(!times(vec![0.0, f64::NAN]).deskewable());
        assert!(!times(vec![2.5, 2.6]).deskewable());
        assert!(times(vec![-0.1, 0.0, 2.0]).deskewable());
    }
}
