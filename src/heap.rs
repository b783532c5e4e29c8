//! Allocator settings for long streaming runs (`mireg register`).
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
//! (heaptrack). Keeping the threshold fixed at its default gives 55 → 57 MB, at the cost of
//! page faults on every frame's large buffers (system time 2.6–4.2 s instead of 0.7–1.0 s per 200
//! frames; see docs/BENCHMARKS.md).

/// The `mmap` threshold kept: glibc's default, made static \[bytes\].
pub const MMAP_THRESHOLD_BYTES: i32 = 128 * 1024;

/// Makes glibc's `mmap` threshold static at [`MMAP_THRESHOLD_BYTES`] (which also fixes the trim
/// threshold at its 128 KiB default), so memory a frame frees goes back to the system instead of
/// accumulating in per-thread arenas. Process-wide: for the binary, not the library. No effect
/// with other allocators or C libraries.
pub fn release_large_blocks_promptly() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets an allocator parameter; it is thread-safe (it takes each arena's
    // lock) and M_MMAP_THRESHOLD accepts any value up to 32 MiB.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES);
    }
}
