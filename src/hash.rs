//! A fast, non-cryptographic hasher for the crate's internal lookup tables (voxel keys, local-map
//! voxels, bitwise-equal descriptors). Their keys are dense small integers or descriptor bits, not
//! attacker-chosen in any way that matters: a poor spread only costs time, never correctness, and
//! no table is ever iterated in hash order, so results do not depend on the hash.

use std::hash::{BuildHasherDefault, Hasher};

/// Multiplicative (Fibonacci) hashing, one 64-bit word at a time, rotated after the multiply so
/// that the product's well-mixed high bits reach the low bits a table indexes by.
#[derive(Debug, Default, Clone, Copy)]
pub(crate) struct FastHasher(u64);

/// `HashMap<K, V, FastHash>` hashes with [`FastHasher`].
pub(crate) type FastHash = BuildHasherDefault<FastHasher>;

impl Hasher for FastHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut word = [0u8; 8];
            word[..chunk.len()].copy_from_slice(chunk);
            self.write_u64(u64::from_le_bytes(word));
        }
    }

    fn write_u64(&mut self, k: u64) {
        self.0 = (self.0 ^ k)
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .rotate_left(29);
    }
}
