//! Log-time order for messages read in file order.
//!
//! `mireg register` streams a log front to back but registers its clouds in log-time order, and
//! an MCAP file need not be time-ordered. A message therefore waits in a [`Reorder`] buffer until
//! no earlier one can follow. Knowing nothing about the file, that takes a fixed window of the
//! latest messages (whole clouds: ~2 MB each at HDL-64 size). The summary's chunk indexes usually
//! prove much more: when the chunks' time ranges follow file order without overlapping (what
//! recorders write), a message read from chunk `j` shows that nothing read later is earlier than
//! chunk `j`'s first message, so everything pending up to that time can be handed on at once
//! ([`ChunkTimes`]). The order handed on is the same either way: log time, then file order.

use std::collections::BTreeMap;
use std::path::Path;

use mcap::records::ChunkIndex;

use crate::Result;

/// The time ranges of a log's chunks, in file order, when they are ordered and disjoint:
/// `start ≤ end` for every chunk and `end ≤ next start` (log times in ns).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChunkTimes {
    ranges: Vec<(u64, u64)>,
}

impl ChunkTimes {
    /// From `(message_start_time, message_end_time)` per chunk in file order; `None` when two
    /// ranges overlap or go back in time (the index then proves nothing about order).
    pub fn new(ranges: Vec<(u64, u64)>) -> Option<Self> {
        let ordered =
            ranges.iter().all(|&(s, e)| s <= e) && ranges.windows(2).all(|w| w[0].1 <= w[1].0);
        (ordered && !ranges.is_empty()).then_some(Self { ranges })
    }

    /// From a summary's chunk indexes (any order; sorted by file offset here). Chunks without
    /// messages (no message index, times 0) are skipped; see [`ChunkTimes::new`] for `None`.
    pub fn from_chunk_indexes(indexes: &[ChunkIndex]) -> Option<Self> {
        let mut chunks: Vec<&ChunkIndex> = indexes
            .iter()
            .filter(|c| {
                !(c.message_index_offsets.is_empty()
                    && c.message_start_time == 0
                    && c.message_end_time == 0)
            })
            .collect();
        chunks.sort_by_key(|c| c.chunk_start_offset);
        Self::new(
            chunks
                .iter()
                .map(|c| (c.message_start_time, c.message_end_time))
                .collect(),
        )
    }

    /// The chunk times of the MCAP at `path`; `None` without a readable summary, without chunk
    /// indexes, or when they are not ordered and disjoint.
    pub fn read(path: &Path) -> Result<Option<Self>> {
        Ok(read_chunk_indexes(path)?.and_then(|c| Self::from_chunk_indexes(&c)))
    }

    /// The earliest log time of any message read after one at `log_time`: the start of the first
    /// chunk that can hold `log_time` (every later message is in that chunk or a later one).
    /// `None` when no chunk's range holds `log_time`, i.e. the index does not describe the file.
    pub fn bound_after(&self, log_time: u64) -> Option<u64> {
        // Ends are non-decreasing, so the chunks ending before `log_time` form a prefix.
        let j = self.ranges.partition_point(|&(_, end)| end < log_time);
        let &(start, _) = self.ranges.get(j)?;
        (start <= log_time).then_some(start)
    }
}

/// The chunk indexes of the summary section of `path`; `None` when the file has no readable
/// summary (e.g. a log cut short while recording).
fn read_chunk_indexes(path: &Path) -> Result<Option<Vec<ChunkIndex>>> {
    Ok(super::mcap::read::read_summary(path)?.map(|s| s.chunk_indexes))
}

/// Items keyed by log time, handed on in (log time, arrival) order once no earlier item can
/// arrive: when more than `window` are pending or they hold more than the byte limit (the
/// earliest goes), or when the chunk index proves it ([`Reorder::observe`]).
#[derive(Debug)]
pub struct Reorder<T> {
    window: usize,
    /// Bytes the pending items may hold ([`Reorder::with_byte_limit`]); `usize::MAX` by default.
    max_bytes: usize,
    /// Bytes the pending items hold, as given to [`Reorder::push_sized`].
    bytes: usize,
    chunks: Option<ChunkTimes>,
    /// Every message still to be read has a log time ≥ this, by the chunk index.
    bound: Option<u64>,
    pending: BTreeMap<(u64, u64), (T, usize)>,
    arrivals: u64,
    /// Log time of the last item handed on.
    handed: Option<u64>,
}

impl<T> Reorder<T> {
    /// At most `window` items wait for a possibly earlier one; `chunks` (from the same file) lets
    /// items go as soon as the index proves nothing earlier follows.
    pub fn new(window: usize, chunks: Option<ChunkTimes>) -> Self {
        Self {
            window,
            max_bytes: usize::MAX,
            bytes: 0,
            chunks,
            bound: None,
            pending: BTreeMap::new(),
            arrivals: 0,
            handed: None,
        }
    }

    /// The same, holding at most `max_bytes` \[bytes\] of pending items (counted as given to
    /// [`Reorder::push_sized`]): past it the earliest goes, as past the window.
    pub fn with_byte_limit(mut self, max_bytes: usize) -> Self {
        self.max_bytes = max_bytes;
        self
    }

    /// The log time of the last item handed on, when it is later than `log_time`: an item read
    /// now at `log_time` could no longer go in order (the file is out of order by more than the
    /// window). `None` when it still can.
    pub fn too_late(&self, log_time: u64) -> Option<u64> {
        self.handed.filter(|&h| log_time < h)
    }

    /// Notes a message read at `log_time`. Call it in file order for every message read, or for
    /// any subset of them (e.g. only those pushed): each one proves a bound on all later ones. A
    /// message earlier than the index allowed means the index does not describe the file: from
    /// then on only the window applies.
    pub fn observe(&mut self, log_time: u64) {
        let Some(chunks) = &self.chunks else { return };
        match chunks.bound_after(log_time) {
            Some(b) if self.bound.is_none_or(|bound| log_time >= bound) => {
                self.bound = Some(self.bound.map_or(b, |bound| bound.max(b)));
            }
            _ => {
                self.chunks = None;
                self.bound = None;
            }
        }
    }

    /// Adds an item read at `log_time`, [observing](Reorder::observe) its message.
    pub fn push(&mut self, log_time: u64, item: T) {
        self.push_sized(log_time, 0, item);
    }

    /// [`Reorder::push`] of an item holding `bytes` \[bytes\].
    pub fn push_sized(&mut self, log_time: u64, bytes: usize, item: T) {
        self.observe(log_time);
        self.pending
            .insert((log_time, self.arrivals), (item, bytes));
        self.bytes = self.bytes.saturating_add(bytes);
        self.arrivals += 1;
    }

    /// The earliest pending item if it may go now: more than `window` are pending, or nothing
    /// earlier can follow. Call until `None` after each [`Reorder::push`].
    pub fn pop_ready(&mut self) -> Option<T> {
        let &(log_time, _) = self.pending.keys().next()?;
        let proven = self.bound.is_some_and(|bound| log_time <= bound);
        if proven || self.pending.len() > self.window || self.bytes > self.max_bytes {
            self.handed = Some(log_time);
            self.pending.pop_first().map(|(_, (item, bytes))| {
                self.bytes -= bytes;
                item
            })
        } else {
            None
        }
    }

    /// Items waiting.
    pub fn len(&self) -> usize {
        self.pending.len()
    }

    /// `true` when no item waits.
    pub fn is_empty(&self) -> bool {
        self.pending.is_empty()
    }

    /// Everything still pending, in order (at the end of the file).
    pub fn into_remaining(self) -> impl Iterator<Item = T> {
        self.pending.into_values().map(|(item, _)| item)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Feeds messages with log times `times` in file order, each pushed; returns the order they are
    /// handed on in and the most items that ever waited.
    fn run(window: usize, chunks: Option<ChunkTimes>, times: &[u64]) -> (Vec<u64>, usize) {
        let mut r = Reorder::new(window, chunks);
        let (mut out, mut most) = (Vec::new(), 0);
        for &t in times {
            r.push(t, t);
            most = most.max(r.len());
            while let Some(t) = r.pop_ready() {
                out.push(t);
            }
        }
        out.extend(r.into_remaining());
        (out, most)
    }

    #[test]
    fn the_byte_limit_hands_the_earliest_on_before_the_window_fills() {
        let mut r = Reorder::new(16, None).with_byte_limit(100);
        r.push_sized(30, 60, 30);
        assert_eq!(r.pop_ready(), None);
        r.push_sized(20, 60, 20);
        assert_eq!(r.pop_ready(), Some(20), "120 bytes held, over 100");
        assert_eq!(r.pop_ready(), None);
        assert_eq!(r.too_late(10), Some(20));
    }

    #[test]
    fn an_item_behind_what_was_handed_on_is_too_late() {
        let mut r = Reorder::new(2, None);
        assert_eq!(r.too_late(0), None);
        for t in [50, 40, 30] {
            r.push(t, t);
        }
        assert_eq!(r.pop_ready(), Some(30)); // three pending, window two
        assert_eq!(r.pop_ready(), None);
        assert_eq!(r.too_late(20), Some(30));
        assert_eq!(r.too_late(30), None, "equal times keep arrival order");
        assert_eq!(r.too_late(45), None);
    }

    #[test]
    fn chunk_times_need_ordered_disjoint_ranges() {
        assert!(ChunkTimes::new(vec![(0, 5), (5, 9), (10, 10)]).is_some());
        assert!(ChunkTimes::new(vec![(0, 5), (4, 9)]).is_none(), "overlap");
        assert!(
            ChunkTimes::new(vec![(6, 9), (0, 5)]).is_none(),
            "back in time"
        );
        assert!(ChunkTimes::new(vec![(3, 2)]).is_none());
        assert!(ChunkTimes::new(vec![]).is_none());
    }

    #[test]
    fn bound_is_the_start_of_the_first_chunk_that_can_hold_the_time() {
        let c = ChunkTimes::new(vec![(10, 20), (20, 30), (40, 50)]).unwrap();
        assert_eq!(c.bound_after(10), Some(10));
        assert_eq!(c.bound_after(15), Some(10));
        // 20 may be the end of chunk 0 or the start of chunk 1: the earlier start is safe.
        assert_eq!(c.bound_after(20), Some(10));
        assert_eq!(c.bound_after(25), Some(20));
        assert_eq!(c.bound_after(50), Some(40));
        assert_eq!(c.bound_after(35), None, "in a gap");
        assert_eq!(c.bound_after(5), None, "before every chunk");
        assert_eq!(c.bound_after(51), None, "after every chunk");
    }

    #[test]
    fn a_proven_order_hands_items_on_at_once_and_keeps_the_window_order() {
        // Three chunks, out of order inside each: [3, 1, 2] [5, 4] [9, 6].
        let times = [3, 1, 2, 5, 4, 9, 6];
        let chunks = ChunkTimes::new(vec![(1, 3), (4, 5), (6, 9)]);
        let (sorted, _) = run(16, None, &times);
        assert_eq!(sorted, [1, 2, 3, 4, 5, 6, 9]);
        let (out, most) = run(16, chunks, &times);
        assert_eq!(out, sorted);
        assert!(most <= 3, "waited for {most}");
    }

    #[test]
    fn in_order_chunks_of_one_message_wait_for_nothing() {
        let times: Vec<u64> = (0..100).map(|k| 10 * k).collect();
        let chunks = ChunkTimes::new(times.iter().map(|&t| (t, t)).collect());
        let (out, most) = run(16, chunks, &times);
        assert_eq!(out, times);
        assert_eq!(most, 1);
        // Without the index the window fills.
        assert_eq!(run(16, None, &times).1, 17);
    }

    #[test]
    fn equal_times_keep_file_order() {
        let mut r = Reorder::new(16, ChunkTimes::new(vec![(5, 5), (5, 7)]));
        let mut out = Vec::new();
        for (t, name) in [(5, "a"), (5, "b"), (7, "c"), (5, "d")] {
            r.push(t, name);
            while let Some(x) = r.pop_ready() {
                out.push(x);
            }
        }
        out.extend(r.into_remaining());
        assert_eq!(out, ["a", "b", "d", "c"]);
    }

    #[test]
    fn an_index_that_does_not_describe_the_file_falls_back_to_the_window() {
        // The index claims chunks [0, 10] then [20, 30], but 5 comes after 25.
        let times = [0, 25, 5, 30];
        let chunks = ChunkTimes::new(vec![(0, 10), (20, 30)]);
        let mut r = Reorder::new(16, chunks);
        for &t in &times[..2] {
            r.push(t, t);
        }
        assert_eq!(r.pop_ready(), Some(0));
        assert_eq!(r.pop_ready(), None);
        r.push(5, 5);
        r.push(30, 30);
        assert_eq!(r.pop_ready(), None, "only the window applies now");
        assert_eq!(r.into_remaining().collect::<Vec<_>>(), [5, 25, 30]);
    }
}
