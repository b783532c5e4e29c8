//! The *reader* stage of `mireg register`, on the calling thread: stream the input's records,
//! copy each into the output, and hand the cloud messages on in log-time order (restoring it
//! within a window where the file's chunk index does not prove it).

use std::sync::mpsc::{Receiver, SyncSender};

use crate::io::log_order::Reorder;
use crate::io::mcap::log::OutputLog;
use crate::{Error, Result};

use super::frames::{CloudMsg, FrameOut};
use super::options::{QUEUE_CAPACITY, REORDER_WINDOW_BYTES, RegisterOptions};
use super::plan::Plan;
use super::writer::Writer;

/// Cloud message buffers outside the reorder window: the queue to the preparing thread, and the
/// one it decodes.
const MESSAGE_BUFFERS: usize = QUEUE_CAPACITY + 1;

/// Message buffers back from the preparing thread once decoded, for the next clouds' bytes: the
/// few buffers in flight are allocated (and faulted in) once, instead of a multi-megabyte map and
/// unmap per cloud whose timing across threads decided the peak RSS. At most
/// [`MESSAGE_BUFFERS`] of them live outside the reorder window.
struct Buffers {
    recycled: Receiver<Vec<u8>>,
    /// Allocated so far (each is recycled or, when outsized, freed).
    allocated: usize,
}

impl Buffers {
    /// A buffer holding a copy of `data`, `pending` clouds being held in the reorder window.
    fn copy(&mut self, data: &[u8], pending: usize) -> Vec<u8> {
        // A buffer more than twice this cloud's size (after an outsized cloud) is freed rather
        // than kept for the rest of the log. At most MESSAGE_BUFFERS outside the reorder window:
        // the preparing thread returns each one once decoded, so waiting for it cannot deadlock,
        // and the peak memory does not hang on how far the reader ran ahead.
        let recycled = if self.allocated - pending >= MESSAGE_BUFFERS {
            self.recycled.recv().ok()
        } else {
            self.recycled.try_recv().ok()
        };
        if recycled.is_none() {
            self.allocated += 1;
        }
        let mut buf = recycled
            .filter(|b| b.capacity() <= 2 * data.len())
            .unwrap_or_default();
        buf.clear();
        // Exact: amortised doubling would let a recycled buffer one byte short of the next cloud
        // grow to twice its size.
        buf.reserve_exact(data.len());
        buf.extend_from_slice(data);
        buf
    }
}

/// Copies the input into `log` and sends its clouds on `clouds` in log-time order, writing the
/// frames registered meanwhile (`registered`) through `writer`; returns the messages copied.
/// Closes `clouds` when done, whatever the outcome.
pub(super) fn read(
    plan: &Plan,
    opts: &RegisterOptions,
    log: &mut OutputLog,
    writer: &mut Writer,
    clouds: SyncSender<CloudMsg>,
    recycled: Receiver<Vec<u8>>,
    registered: &Receiver<Result<FrameOut>>,
) -> Result<u64> {
    let (input, topic, segment) = (&opts.input, &plan.topic, plan.segment);
    // Clouds are handed on in log-time order: at once where the chunk index proves nothing
    // earlier follows, else after a window of REORDER_WINDOW clouds.
    let reorder_window = opts.reorder_window;
    let mut pending = Reorder::new(reorder_window, plan.chunk_times.clone())
        .with_byte_limit(REORDER_WINDOW_BYTES);
    let mut buffers = Buffers {
        recycled,
        allocated: 0,
    };
    // Input chunks are copied byte for byte; only messages on the cloud and reference channels
    // come here, in file order.
    let copy_only = opts
        .copy_window_only
        .then_some(segment.start_ns..segment.end_ns);
    let wanted = plan.wanted_channels();
    let read = plan
        .input_log
        .pass_through(log, &wanted, copy_only, |log, header, data| {
            if !segment.contains(header.log_time) {
                // Outside the segment: copied (unless --copy-window), not registered.
            } else if plan.cloud_channels.contains(&header.channel_id) {
                if let Some(handed) = pending.too_late(header.log_time) {
                    return Err(Error::Format {
                        path: input.to_path_buf(),
                        detail: format!(
                            "cloud on {topic} at log time {} ns comes after the cloud at log time {handed} ns was registered: the log is out of log-time order by more than the reorder window of {reorder_window} clouds (and at most {} MiB); rerun with a larger --reorder-window (each holds one cloud in memory)",
                            header.log_time,
                            REORDER_WINDOW_BYTES >> 20
                        ),
                    });
                }
                let data = buffers.copy(data, pending.len());
                pending.push_sized(
                    header.log_time,
                    data.len(),
                    CloudMsg {
                        log_time: header.log_time,
                        publish_time: header.publish_time,
                        data,
                    },
                );
                while let Some(msg) = pending.pop_ready() {
                    if clouds.send(msg).is_err() {
                        return Err(Error::InvalidInput("registration stopped early".into()));
                    }
                }
            } else if plan.reference_channels.contains(&header.channel_id)
                && let Some((_, decode)) = plan.reference
                && let Ok((h, pose)) = decode(data)
            {
                writer.reference_pose(h.stamp.to_ns(), pose);
            }
            while let Ok(r) = registered.try_recv() {
                writer.frame(log, r)?;
            }
            Ok(())
        });
    if read.is_ok() {
        for msg in pending.into_remaining() {
            if clouds.send(msg).is_err() {
                break;
            }
        }
    }
    read
}
