//! The loop stage's verification of its candidates, pass by pass over the input ([`verify_all`]):
//! each pass streams the frames the remaining candidates need, holds what fits, and verifies a
//! candidate as soon as both of its frames are in memory.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::ops::ControlFlow;

use rayon::prelude::*;

use super::super::frames::Estimate;
use super::super::options::RegisterOptions;
use super::super::plan::Plan;
use super::{Verified, Verifier, VerifyOutcome};
use crate::Result;
use crate::geometry::deskew::deskew;
use crate::loops::{Candidate, Source};
use crate::pipeline::{PairConfig, PreparedFrame, prepare_frame};

/// Verifies every candidate, reading the input again as often as needed (the passes, returned):
/// in each pass the frames stream by in file order; a frame some candidate still needs is
/// prepared (or taken from `cached`), its candidates whose other frame is held are verified at
/// once (in parallel), and it is held while it has candidates left and there is room
/// ([`crate::loops::LoopConfig::frames_in_memory`]); a frame is released when its last
/// candidate is done. Candidates whose two frames were never held together wait for the next
/// pass. Each pass verifies at least the candidates of the first frame it holds, so the passes
/// end; a log that revisits a few places often needs few. A pass whose frames are all in
/// `cached` visits them in index order without reading the input, and is not counted. Loops in
/// `accepted_before` (an earlier round's) make candidates redundant as the ones accepted here
/// do.
pub(super) fn verify_all(
    plan: &Plan,
    opts: &RegisterOptions,
    estimates: &[Estimate],
    candidates: &[Candidate],
    verifier: &Verifier,
    mut cached: BTreeMap<usize, PreparedFrame>,
    accepted_before: &[(usize, usize)],
) -> Result<VerifyOutcome> {
    let mut progress = Progress {
        verified: Verified::new(),
        accepted: accepted_before.to_vec(),
        skipped: BTreeSet::new(),
        capacity: None,
    };
    // Candidates that could not be read (a frame that no longer decodes) are left out.
    let mut remaining: Vec<Candidate> = candidates.to_vec();
    let mut passes = 0;
    while !remaining.is_empty() {
        let mut pass = Pass::new(&remaining, verifier);
        let needed: BTreeSet<usize> = pass.uses.keys().copied().collect();
        cached.retain(|k, _| needed.contains(k));
        let all_cached = needed.iter().all(|k| cached.contains_key(k));
        let mut visit = |k: usize, prepare: &mut dyn FnMut() -> Option<PreparedFrame>| {
            pass.visit(k, prepare, &mut cached, &mut progress)
        };
        let seen = if all_cached {
            let mut seen = BTreeSet::new();
            for &k in &needed {
                if visit(k, &mut || None)? {
                    seen.insert(k);
                }
            }
            seen
        } else {
            passes += 1;
            for_each_needed_frame(plan, opts, estimates, &needed, verifier.pair, visit)?
        };
        let Pass { done, .. } = pass;
        let before = remaining.len();
        // Candidates with a frame that could not be read again: no verification, rejected.
        remaining.retain(|c| {
            !done.contains(&(c.query, c.matched))
                && seen.contains(&c.query)
                && seen.contains(&c.matched)
        });
        if remaining.len() == before {
            break; // nothing could be verified: the frames are gone
        }
    }
    Ok((progress.verified, progress.skipped, passes))
}

/// What the passes of [`verify_all`] have found so far.
struct Progress {
    verified: Verified,
    /// The loops accepted, those of earlier rounds first (seam pairs are no loops).
    accepted: Vec<(usize, usize)>,
    /// The candidates skipped as redundant.
    skipped: BTreeSet<(usize, usize)>,
    /// How many frames may be in memory at once: sized by the first frame prepared (frames of
    /// one log are of a size).
    capacity: Option<usize>,
}

/// One pass over the frames the remaining candidates need.
struct Pass<'r> {
    remaining: &'r [Candidate],
    verifier: &'r Verifier<'r>,
    /// Each frame's candidates (indices into `remaining`, in its order).
    of_frame: HashMap<usize, Vec<usize>>,
    /// How many of each frame's candidates are left.
    uses: HashMap<usize, usize>,
    /// The frames held for their candidates left.
    held: BTreeMap<usize, PreparedFrame>,
    /// The candidates verified or skipped on this pass.
    done: BTreeSet<(usize, usize)>,
}

impl<'r> Pass<'r> {
    fn new(remaining: &'r [Candidate], verifier: &'r Verifier<'r>) -> Self {
        let mut of_frame: HashMap<usize, Vec<usize>> = HashMap::new();
        for (i, c) in remaining.iter().enumerate() {
            of_frame.entry(c.query).or_default().push(i);
            of_frame.entry(c.matched).or_default().push(i);
        }
        let uses = of_frame.iter().map(|(&f, cs)| (f, cs.len())).collect();
        Pass {
            remaining,
            verifier,
            of_frame,
            uses,
            held: BTreeMap::new(),
            done: BTreeSet::new(),
        }
    }

    /// Frame `k` streams by: its redundant candidates skipped, the frame taken from `cached` or
    /// prepared (`prepare`), its candidates whose other frame is held verified, and the frame
    /// held if it has candidates left and there is room. Whether the frame was prepared.
    fn visit(
        &mut self,
        k: usize,
        prepare: &mut dyn FnMut() -> Option<PreparedFrame>,
        cached: &mut BTreeMap<usize, PreparedFrame>,
        progress: &mut Progress,
    ) -> Result<bool> {
        self.skip_redundant(k, progress);
        let from_cache = cached.remove(&k);
        if self.uses[&k] == 0 {
            return Ok(false);
        }
        let was_cached = from_cache.is_some();
        let Some(mut frame) = from_cache.or_else(prepare) else {
            return Ok(false);
        };
        let ready = self.ready(k);
        let config = self.verifier.config;
        let cap = *progress.capacity.get_or_insert_with(|| {
            let fit = config.memory_budget_bytes / frame.idle_bytes().max(1);
            fit.clamp(2, config.frames_in_memory.max(2))
        });
        self.verify_ready(k, &mut frame, ready, cached, progress)?;
        // A kept frame was in memory already; a new one needs room beside the kept ones.
        if self.uses[&k] > 0 && (was_cached || self.held.len() + cached.len() < cap) {
            self.held.insert(k, frame);
        }
        Ok(true)
    }

    /// Frame `k`'s candidates, in their order.
    fn mine(&self, k: usize) -> impl Iterator<Item = &'r Candidate> + '_ {
        let remaining = self.remaining;
        self.of_frame[&k].iter().map(move |&i| &remaining[i])
    }

    /// Skips frame `k`'s candidates that an accepted loop makes redundant: not tried.
    fn skip_redundant(&mut self, k: usize, progress: &mut Progress) {
        let redundant: Vec<(usize, usize)> = self
            .mine(k)
            .filter(|c| !self.done.contains(&(c.query, c.matched)))
            .filter(|c| self.verifier.redundant(c, &progress.accepted))
            .map(|c| (c.query, c.matched))
            .collect();
        for key in redundant {
            progress.skipped.insert(key);
            self.release(key);
        }
    }

    /// Frame `k`'s candidates left whose other frame is held.
    fn ready(&self, k: usize) -> Vec<&'r Candidate> {
        self.mine(k)
            .filter(|c| !self.done.contains(&(c.query, c.matched)))
            .filter(|c| {
                (c.query == k && self.held.contains_key(&c.matched))
                    || (c.matched == k && self.held.contains_key(&c.query))
            })
            .collect()
    }

    /// Verifies `ready` (frame `k`'s candidates whose other frame is held), leaders first
    /// ([`Verifier::leaders_first`]), as many at once as there are threads: each builds search
    /// structures on its target (a matching target and an ICP grid, for a LiDAR scan twenty
    /// times the idle frame), kept for the frame's next candidates while the frames in memory
    /// fit the budget, dropped when they do not.
    fn verify_ready(
        &mut self,
        k: usize,
        frame: &mut PreparedFrame,
        ready: Vec<&'r Candidate>,
        cached: &BTreeMap<usize, PreparedFrame>,
        progress: &mut Progress,
    ) -> Result<()> {
        let verifier = self.verifier;
        let budget = verifier.config.memory_budget_bytes;
        for (round, batch) in verifier.leaders_first(ready).into_iter().enumerate() {
            let batch = if round == 0 {
                batch
            } else {
                // Followers of an accepted leader would join the same places again.
                let (skip, keep): (Vec<&Candidate>, Vec<&Candidate>) = batch
                    .into_iter()
                    .partition(|c| verifier.redundant(c, &progress.accepted));
                for c in skip {
                    progress.skipped.insert((c.query, c.matched));
                    self.release((c.query, c.matched));
                }
                keep
            };
            let mut results = Vec::new();
            for chunk in batch.chunks(rayon::current_num_threads().max(1)) {
                let held = &self.held;
                let query_frame = &*frame;
                let verified_chunk: Vec<_> = chunk
                    .par_iter()
                    .map(|c| {
                        let (q, m) = if c.query == k {
                            (query_frame, &held[&c.matched])
                        } else {
                            (&held[&c.query], query_frame)
                        };
                        verifier.verify(c, q, m).map(|v| (*c, v))
                    })
                    .collect::<Result<_>>()?;
                results.extend(verified_chunk);
                fit_budget(budget, frame, &mut self.held, cached);
            }
            for (c, v) in results {
                let key = (c.query, c.matched);
                // Seam pairs are no loops: an accepted one makes no candidate redundant.
                if v.0.accepted && c.by != Source::Seam {
                    progress.accepted.push(key);
                }
                progress.verified.insert(key, v);
                self.release(key);
            }
        }
        Ok(())
    }

    /// Marks candidate `key` done and releases its frames whose last candidate it was.
    fn release(&mut self, key: (usize, usize)) {
        self.done.insert(key);
        for f in [key.0, key.1] {
            let u = self.uses.get_mut(&f).expect("counted");
            *u -= 1;
            if *u == 0 {
                self.held.remove(&f);
            }
        }
    }
}

/// Drops the search structures of the `held` frames, then of `frame`, while the frames in
/// memory (those and the `cached` ones, which are idle) hold more than `budget` bytes.
fn fit_budget(
    budget: usize,
    frame: &mut PreparedFrame,
    held: &mut BTreeMap<usize, PreparedFrame>,
    cached: &BTreeMap<usize, PreparedFrame>,
) {
    let idle: usize = cached.values().map(PreparedFrame::heap_bytes).sum();
    let mut total =
        idle + frame.heap_bytes() + held.values().map(PreparedFrame::heap_bytes).sum::<usize>();
    for f in held.values_mut().chain(std::iter::once(frame)) {
        if total <= budget {
            return;
        }
        let before = f.heap_bytes();
        f.drop_search_structures();
        total -= before - f.heap_bytes();
    }
}

/// Streams the input's clouds once, calling `f(k, prepare)` for each frame `k` in `needed`;
/// `prepare()` decodes the cloud and prepares it for verification (deskewed as the odometry
/// deskewed it), `None` for a cloud that no longer decodes or is over the point bound, and `f`
/// says whether it was prepared. Returns the frames that were: frames registered in log-time order
/// are found by their log time (the n-th cloud of a log time is the n-th frame of it).
pub(super) fn for_each_needed_frame(
    plan: &Plan,
    opts: &RegisterOptions,
    estimates: &[Estimate],
    needed: &BTreeSet<usize>,
    pair: &PairConfig,
    mut f: impl FnMut(usize, &mut dyn FnMut() -> Option<PreparedFrame>) -> Result<bool>,
) -> Result<BTreeSet<usize>> {
    let times: BTreeSet<u64> = needed.iter().map(|&k| estimates[k].log_time).collect();
    let mut by_time: HashMap<u64, (Vec<usize>, usize)> = HashMap::new();
    for (k, e) in estimates.iter().enumerate() {
        if times.contains(&e.log_time) {
            by_time.entry(e.log_time).or_default().0.push(k);
        }
    }
    let mut seen = BTreeSet::new();
    plan.input_log.for_each_message_until(|header, data| {
        if !plan.cloud_channels.contains(&header.channel_id)
            || !plan.segment.contains(header.log_time)
        {
            return Ok(ControlFlow::Continue(()));
        }
        let Some((indices, count)) = by_time.get_mut(&header.log_time) else {
            return Ok(ControlFlow::Continue(()));
        };
        let k = indices.get(*count).copied();
        *count += 1;
        if let Some(k) = k.filter(|k| needed.contains(k)) {
            let mut prepare = || {
                let mut cloud = plan.kind.decode(data).ok()?;
                if cloud.points.len() > opts.max_points_per_cloud {
                    return None;
                }
                if let (Some((motion, dt)), Some(times)) =
                    (&estimates[k].deskew_motion, &cloud.times)
                {
                    deskew(&mut cloud.points, &times.seconds, motion, *dt);
                }
                prepare_frame(&cloud.points, pair).ok()
            };
            if f(k, &mut prepare)? {
                seen.insert(k);
            }
        }
        Ok(ControlFlow::Continue(()))
    })?;
    Ok(seen)
}
