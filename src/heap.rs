//! Allocator settings: for long streaming runs (`mireg register`) and for one-shot commands
//! (`mireg pair`).
//!
//! glibc's malloc serves blocks of at least `M_MMAP_THRESHOLD` (128 KiB) with their own `mmap`,
//! returned to the system on free. But by default the threshold is *dynamic*: freeing such a block
//! raises it to the block's size (up to 32 MiB), and the trim threshold to twice that. After the
//! first frame, a frame's multi-megabyte buffers (the cloud, its neighbourhoods, FPFH histograms)
//! therefore come from the per-thread arenas (one per worker thread), and each arena keeps up to
//! twice the largest such buffer free but resident. Measured on a KITTI-size log (124k points a
//! frame, 0.5 m voxel): at the end of 200 frames the arenas held 94 MB for 17.5 MB in use, two
//! rayon workers' arenas 12.5 and 13.1 MB for under 40 kB in use (`malloc_stats`), and the peak
//! RSS grew from 79 MB over 20 frames to 90 MB over 200 while the live heap stayed flat
//! (heaptrack). A fixed threshold stops that growth, at the cost of page faults on every frame's
//! large buffers. Measured (docs/BENCHMARKS_ARCHIVE.md, idle, 20 → 200 KITTI-size frames, two runs each):
//! at glibc's 128 KiB default, 48.6–49.2 → 51.3–51.7 MB peak RSS at 9.5–10.2 frames/s (system
//! time 3.8–4.5 s per 200 frames); at 1 MiB, which leaves the sub-megabyte per-frame buffers in
//! the arenas, 53.1–53.2 → 57.2–57.8 MB at 10.2–10.5 frames/s (3.3–3.5 s). 1 MiB is used: both
//! stay within 10 % between a log and one 10× longer, and only 1 MiB keeps 10 frames/s.
//!
//! The trim threshold: at glibc's 128 KiB each arena gave the top of its heap back to the system
//! whenever that much lay free there, and faulted it in again for the next frame's buffers: a
//! frame's sub-megabyte blocks (neighbourhoods, sort buffers, the map's growing vectors) were
//! faulted in once per frame. `mireg register` already returns every arena's free memory
//! every few frames ([`trim`]), which is what bounds the RSS of a long log; between two such
//! returns the arenas now keep what they freed ([`TRIM_THRESHOLD_BYTES`]). Measured with the
//! cloud buffers reused (docs/BENCHMARKS_ARCHIVE.md): on the KITTI replay log (100 frames, 0.5 m voxel)
//! 157k → 28k page faults and 0.50 → 0.20 s of system time; peak RSS 20 → 200 frames
//! 45.5–47.1 → 48.1–48.9 MB (+3.8–5.7 % per round, against +3.9–10 % before).

/// The static `mmap` threshold \[bytes\] (glibc's default is 128 KiB, dynamic).
pub const MMAP_THRESHOLD_BYTES: i32 = 1024 * 1024;

/// The trim threshold \[bytes\] of [`release_large_blocks_promptly`]: free memory at the top of
/// an arena's heap that glibc keeps rather than returning it on each free (default 128 KiB).
/// Large enough that the arenas never trim themselves between two [`trim`] calls.
pub const TRIM_THRESHOLD_BYTES: i32 = 256 * 1024 * 1024;

/// Makes glibc's `mmap` threshold static at [`MMAP_THRESHOLD_BYTES`], so the large blocks a frame
/// frees go back to the system instead of accumulating in per-thread arenas, and lets the arenas
/// keep their smaller freed blocks ([`TRIM_THRESHOLD_BYTES`]) until the caller returns them with
/// [`trim`], as `mireg register` does every few frames. Process-wide: for the binary, not the
/// library. No effect with other allocators or C libraries.
pub fn release_large_blocks_promptly() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters; it is thread-safe (it takes each arena's
    // lock), M_MMAP_THRESHOLD accepts any value up to 32 MiB and M_TRIM_THRESHOLD any value.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES);
        libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES);
    }
}

/// Returns the free memory of every malloc arena to the system (`malloc_trim(0)`: trims each
/// heap's top and releases whole free pages inside it). For long streaming runs, every few frames:
/// frames of varying size leave free gaps in the per-thread arenas that nothing else would give back.
pub fn trim() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only walks the allocator's own arenas under their locks.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Largest `mmap` threshold glibc accepts on 64-bit targets (its `DEFAULT_MMAP_THRESHOLD_MAX`).
const ONE_SHOT_MMAP_THRESHOLD_BYTES: i32 = 32 * 1024 * 1024;
/// Trim threshold and top padding \[bytes\] of [`keep_freed_memory`].
const ONE_SHOT_TRIM_BYTES: i32 = 1 << 30;
const ONE_SHOT_TOP_PAD_BYTES: i32 = 64 * 1024 * 1024;

/// For one-shot commands (`mireg pair`): keeps freed memory in the heap for reuse instead of
/// returning it (blocks up to 32 MiB come from the heap, which is grown 64 MiB at a time and never
/// trimmed). A registration allocates and frees the same multi-megabyte buffers stage after
/// stage; with glibc's defaults each of them is a fresh `mmap`, faulted in page by page, and an
/// `munmap` that interrupts the other core to flush its TLB. Measured on the KITTI pair at 0.5 m
/// (posed source, `/usr/bin/time`, 3–4 runs each, docs/PAIRWISE.md): 13.0k → 9.5–10.1k minor
/// faults, 0.05–0.07 → 0.01–0.03 s system time, 39–40 → 43–45 MB peak RSS. Not for `register`, whose
/// memory must stay flat over long logs ([`release_large_blocks_promptly`]).
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters; it is thread-safe, and the values are
    // within the ranges glibc accepts.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, ONE_SHOT_MMAP_THRESHOLD_BYTES);
        libc::mallopt(libc::M_TRIM_THRESHOLD, ONE_SHOT_TRIM_BYTES);
        libc::mallopt(libc::M_TOP_PAD, ONE_SHOT_TOP_PAD_BYTES);
    }
}
