//! `--start` / `--end`: register one segment of a log. A bound is a cloud index (`120`, counted
//! from 0 in log-time order over the cloud topic) or a log time (`1700000012.5s` in seconds,
//! `1700000012500000000ns` in nanoseconds). The window is resolved to a log-time range
//! `[start, end)` before the log is streamed, so that frames and (with `--copy-window`) copied
//! messages follow one rule.

use std::ops::ControlFlow;
use std::str::FromStr;

use crate::io::input_log::InputLog;
use crate::{Error, Result};

/// One end of a segment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum WindowBound {
    /// The `n`-th cloud of the topic (0-based, log-time order).
    Frame(u64),
    /// A log time in nanoseconds since the epoch.
    LogTimeNs(u64),
}

impl FromStr for WindowBound {
    type Err = String;

    /// `N` (a cloud index), `Ts` (log time in seconds, decimals allowed) or `Tns` (log time in
    /// nanoseconds).
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let s = s.trim();
        let bad = || {
            format!(
                "{s:?} is not a segment bound: a cloud index (120), or a log time in seconds (1700000012.5s) or nanoseconds (1700000012500000000ns)"
            )
        };
        if let Some(ns) = s.strip_suffix("ns") {
            return ns.parse().map(WindowBound::LogTimeNs).map_err(|_| bad());
        }
        if let Some(sec) = s.strip_suffix('s') {
            let v: f64 = sec.parse().map_err(|_| bad())?;
            if !(0.0..1.8e10).contains(&v) {
                return Err(bad());
            }
            // Whole seconds and the fraction apart, so that the nanoseconds are exact.
            let (whole, frac) = sec.split_once('.').unwrap_or((sec, ""));
            let whole: u64 = whole.parse().map_err(|_| bad())?;
            let digits: String = frac.chars().chain(std::iter::repeat('0')).take(9).collect();
            let nanos: u64 = digits.parse().map_err(|_| bad())?;
            return Ok(WindowBound::LogTimeNs(whole * 1_000_000_000 + nanos));
        }
        s.parse().map(WindowBound::Frame).map_err(|_| bad())
    }
}

/// A segment resolved to log times.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct LogWindow {
    /// First log time in the segment \[ns\].
    pub start_ns: u64,
    /// First log time after it \[ns\] (`u64::MAX`: to the end of the log).
    pub end_ns: u64,
    /// Clouds before the segment: the global index of the segment's first frame.
    pub first_frame: u64,
}

impl LogWindow {
    /// The whole log.
    pub const ALL: LogWindow = LogWindow {
        start_ns: 0,
        end_ns: u64::MAX,
        first_frame: 0,
    };

    /// Whether a message at `log_time` lies in the segment.
    pub fn contains(&self, log_time: u64) -> bool {
        (self.start_ns..self.end_ns).contains(&log_time)
    }

    /// Resolves `start`..`end` on the clouds of `cloud_channels` (one pass over the log when a
    /// bound is a frame index, none otherwise).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] when the window is empty or starts past the last cloud.
    pub fn resolve(
        input: &InputLog,
        cloud_channels: &[u16],
        start: Option<WindowBound>,
        end: Option<WindowBound>,
    ) -> Result<Self> {
        if start.is_none() && end.is_none() {
            return Ok(Self::ALL);
        }
        let mut times = Vec::new();
        input.for_each_message_until(|h, _| {
            if cloud_channels.contains(&h.channel_id) {
                times.push(h.log_time);
            }
            Ok(ControlFlow::Continue(()))
        })?;
        times.sort_unstable();
        let at = |b: Option<WindowBound>, open: u64| match b {
            None => open,
            Some(WindowBound::LogTimeNs(t)) => t,
            Some(WindowBound::Frame(k)) => times.get(k as usize).copied().unwrap_or(u64::MAX),
        };
        let w = LogWindow {
            start_ns: at(start, 0),
            end_ns: at(end, u64::MAX),
            first_frame: 0,
        };
        let first_frame = times.partition_point(|&t| t < w.start_ns) as u64;
        let inside = times.iter().filter(|&&t| w.contains(t)).count();
        if inside == 0 {
            return Err(Error::InvalidInput(format!(
                "--start {} --end {}: no cloud in the segment (the log has {} clouds{})",
                describe(start),
                describe(end),
                times.len(),
                match (times.first(), times.last()) {
                    (Some(a), Some(b)) => format!(", log times {a} to {b} ns"),
                    _ => String::new(),
                }
            )));
        }
        Ok(LogWindow { first_frame, ..w })
    }
}

fn describe(b: Option<WindowBound>) -> String {
    match b {
        None => "(open)".into(),
        Some(WindowBound::Frame(k)) => format!("frame {k}"),
        Some(WindowBound::LogTimeNs(t)) => format!("{t} ns"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_parse_as_frames_seconds_and_nanoseconds() {
        assert_eq!("120".parse(), Ok(WindowBound::Frame(120)));
        assert_eq!(
            "1700000012.5s".parse(),
            Ok(WindowBound::LogTimeNs(1_700_000_012_500_000_000))
        );
        assert_eq!("0.000000001s".parse(), Ok(WindowBound::LogTimeNs(1)));
        assert_eq!("17ns".parse(), Ok(WindowBound::LogTimeNs(17)));
        for bad in ["", "-1", "1.5", "x s", "1e3s", "-2s", "nan s"] {
            assert!(bad.parse::<WindowBound>().is_err(), "{bad:?}");
        }
    }
}
