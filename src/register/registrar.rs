//! The *register* stage of `mireg register`, on its own thread: each prepared frame in turn
//! against the local map ([`Odometry::push`]: MI-RANSAC, ICP, then the map update).

use std::sync::mpsc::{Receiver, Sender};
use std::time::Instant;

use nalgebra::Isometry3;

use crate::Result;
use crate::odometry::Odometry;
use crate::odometry::stream::MeanTimeMotions;

use super::closure::KeyframeCache;
use super::frames::{FrameOut, PreparedMsg};
use crate::loops::Descriptor;

/// Frames between two returns of the allocator's free memory to the system
/// ([`crate::heap::trim`]), which keeps the peak RSS of a long log within a few percent of a short
/// one's (docs/BENCHMARKS_ARCHIVE.md).
const TRIM_EVERY_FRAMES: usize = 8;

/// Runs `f` on a worker of rayon's global pool, the calling thread waiting (`rayon::scope` from
/// outside the pool). Registering a frame is many short parallel loops (an ICP iteration each);
/// called from the registering thread, each loop was injected into the pool and woke the caller
/// when done, where from a worker the loops split among the workers directly. On the KAIST03
/// keyframes: 1 800–2 100 → 940–1 150 context switches per run (docs/BENCHMARKS_ARCHIVE.md).
///
/// NOTE: not for preparing frames: on the workers, that stage's buffers shared their malloc
/// arenas with registration's, and the peak RSS of 200 KITTI-size frames rose to 1.11–1.12 × that
/// of 20 (issue 11's bound: 1.10); preparing on its own thread, 1.067.
fn on_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| f())
}

/// The registering thread's channels: the prepared frames in, the results out, each frame's
/// motion back to the preparing thread.
pub(super) type Channels = (
    Receiver<Result<PreparedMsg>>,
    Sender<Result<FrameOut>>,
    Sender<(usize, Isometry3<f64>, f64)>,
);

/// Registers the frames of `prepared` in order, sending each result on `out` and each frame's
/// motion (`prev_from_curr` and its seconds) on `motions` for deskewing a later frame. Stops at
/// the first error (sent on) or when the writer hangs up. With a `cache`, each frame's pose
/// tells it the keyframes; with `describe` too, each keyframe's loop-closure descriptor is
/// computed as it is registered (the features it needs are computed then, where the odometry
/// deferred them); where the cache keeps frames, the keyframes' are offered to it as the
/// odometry retires them, the last one at the end (returned).
pub(super) fn run(
    odometry: &mut Odometry,
    (prepared, out, motions): Channels,
    mut cache: Option<KeyframeCache>,
    describe: bool,
) -> Option<KeyframeCache> {
    odometry.keep_retired(cache.as_ref().is_some_and(KeyframeCache::keeps_frames));
    // The motions for deskewing, between mean point times ([`MeanTimeMotions`]).
    let mut mean_time = MeanTimeMotions::default();
    for (k, msg) in prepared.into_iter().enumerate() {
        if k % TRIM_EVERY_FRAMES == TRIM_EVERY_FRAMES - 1 {
            crate::heap::trim();
        }
        let r = msg.and_then(|mut m| {
            let prep = m.frame.timings;
            let t = Instant::now();
            let mut est = on_pool(|| odometry.push(m.frame))?;
            if let Some((reason, _)) = &m.cloud.invalid {
                est.failure = Some(*reason);
            }
            // The motion and its duration, for deskewing a later frame; a deskewed frame's pose
            // referred to its stamp by its own motion.
            let (motion, dt) =
                mean_time.push(&mut est, m.cloud.header.stamp.to_ns(), m.cloud.deskewed);
            let _ = motions.send((k, motion, dt));
            if let Some(cache) = cache.as_mut() {
                let keyframe = cache.push_pose(&est.world_from_frame);
                if keyframe && describe && m.cloud.invalid.is_none() {
                    // A frame whose deferred features come out empty (none known) has no
                    // descriptor, as one too small to have features.
                    m.cloud.descriptor = odometry
                        .previous_frame()
                        .filter(|(j, frame)| *j == k && frame.has_features())
                        .and_then(|(_, frame)| {
                            on_pool(|| {
                                (!frame.features().is_empty())
                                    .then(|| Descriptor::from_prepared(frame))
                            })
                        });
                }
                if let Some((j, frame)) = odometry.take_retired() {
                    cache.offer(j, frame);
                }
            }
            Ok(FrameOut {
                cloud: m.cloud,
                prep,
                register_s: t.elapsed().as_secs_f64(),
                est,
            })
        });
        let failed = r.is_err();
        if out.send(r).is_err() || failed {
            break;
        }
    }
    if let Some(cache) = cache.as_mut()
        && let Some((j, frame)) = odometry.take_previous()
    {
        cache.offer(j, frame);
    }
    cache
}
