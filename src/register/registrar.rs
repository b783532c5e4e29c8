//! The *register* stage of `mireg register`, on its own thread: each prepared frame in turn
//! against the local map ([`Odometry::push`]: MI-RANSAC, ICP, then the map update).

use std::sync::mpsc::{Receiver, Sender};
use std::time::Instant;

use nalgebra::Isometry3;

use crate::Result;
use crate::geometry::deskew::{exp_twist, log_isometry};
use crate::odometry::Odometry;

use super::frames::{CloudInfo, FrameOut, PreparedMsg};

/// Frames between two returns of the allocator's free memory to the system
/// ([`crate::heap::trim`]), which keeps the peak RSS of a long log within a few percent of a short
/// one's (docs/BENCHMARKS.md).
const TRIM_EVERY_FRAMES: usize = 8;

/// Runs `f` on a worker of rayon's global pool, the calling thread waiting (`rayon::scope` from
/// outside the pool). Registering a frame is many short parallel loops (an ICP iteration each);
/// called from the registering thread, each loop was injected into the pool and woke the caller
/// when done, where from a worker the loops split among the workers directly. On the KAIST03
/// keyframes: 1 800–2 100 → 940–1 150 context switches per run (docs/BENCHMARKS.md).
///
/// NOTE: not for preparing frames: on the workers, that stage's buffers shared their malloc
/// arenas with registration's, and the peak RSS of 200 KITTI-size frames rose to 1.11–1.12 × that
/// of 20 (issue 11's bound: 1.10); preparing on its own thread, 1.067.
fn on_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| f())
}

/// Registers the frames of `prepared` in order, sending each result on `out` and each frame's
/// motion (`prev_from_curr` and its seconds) on `motions` for deskewing a later frame. Stops at
/// the first error (sent on) or when the writer hangs up.
pub(super) fn run(
    odometry: &mut Odometry,
    prepared: Receiver<Result<PreparedMsg>>,
    out: Sender<Result<FrameOut>>,
    motions: Sender<(usize, Isometry3<f64>, f64)>,
) {
    let mut previous_stamp: Option<i64> = None;
    // The previous frame's `stamp_from_mean` ([`stamp_from_mean`]).
    let mut previous_from_mean = Isometry3::identity();
    for (k, msg) in prepared.into_iter().enumerate() {
        if k % TRIM_EVERY_FRAMES == TRIM_EVERY_FRAMES - 1 {
            crate::heap::trim();
        }
        let r = msg.and_then(|m| {
            let prep = m.frame.timings;
            let t = Instant::now();
            let mut est = on_pool(|| odometry.push(m.frame))?;
            if let Some((reason, _)) = &m.cloud.invalid {
                est.failure = Some(*reason);
            }
            // The motion and its duration, for deskewing a later frame.
            let stamp = m.cloud.header.stamp.to_ns();
            let dt = previous_stamp.map_or(f64::NAN, |p| (stamp - p) as f64 * 1e-9);
            previous_stamp = Some(stamp);
            // NOTE: the motion for deskewing is taken between the frames' mean point times, not
            // their stamps. A cloud deskewed to its stamp by a motion that is off by δ is
            // shifted by about δ·(mean time / dt) as a whole, which registration takes into the
            // stamp's pose; motions between stamp poses would then carry that error into the
            // next deskew, and on Livox's 100 ms sweeps the loop oscillates (period 2, ±12 cm
            // per frame at 3 m/s). Between mean-time poses the shift cancels to first order.
            let from_mean = stamp_from_mean(&m.cloud);
            let motion = if m.cloud.deskewed() || previous_from_mean != Isometry3::identity() {
                previous_from_mean.inverse() * est.prev_from_curr * from_mean
            } else {
                est.prev_from_curr
            };
            previous_from_mean = from_mean;
            if m.cloud.deskewed() && dt.is_finite() && dt > 0.0 {
                let (omega, v) = log_isometry(&motion);
                let s = -m.cloud.deskew_mean_s / dt;
                est.world_from_frame =
                    est.world_from_frame * from_mean * exp_twist(&(omega * s), &(v * s));
            }
            let _ = motions.send((k, motion, dt));
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
}

/// The pose of the sensor at a deskewed cloud's mean point time in the frame at its stamp,
/// under the constant velocity it was deskewed by: `exp(mean/dt · log(motion))`; the identity
/// when the cloud was not deskewed.
fn stamp_from_mean(cloud: &CloudInfo) -> Isometry3<f64> {
    match cloud.deskew_motion {
        Some((motion, dt)) if cloud.deskew_mean_s != 0.0 => {
            let (omega, v) = log_isometry(&motion);
            let s = cloud.deskew_mean_s / dt;
            exp_twist(&(omega * s), &(v * s))
        }
        _ => Isometry3::identity(),
    }
}
