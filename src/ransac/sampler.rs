//! The sampler abstraction: how a hypothesis picks its minimal sample of correspondence indices.
//!
//! Index 0 is the best-ranked correspondence. A sample is `s` indices in `[0, n)`, distinct unless a
//! sampler documents otherwise. Samplers hold no mutable state: the hypothesis number and an injected
//! RNG fully determine a sample, which is what lets the consensus loop draw hypotheses in parallel and
//! still be bit-identical on any thread count.

use rand::{Rng, RngExt};

/// Largest minimal sample the samplers support (rigid registration needs 3; the paper's simulation
/// uses up to 4).
pub const MAX_SAMPLE_SIZE: usize = 8;

/// Draws minimal samples of correspondence indices.
pub trait Sampler: Sync {
    /// Number of correspondences `n` the indices range over.
    fn num_items(&self) -> usize;

    /// Fills `sample` with indices in `[0, n)` for hypothesis number `hypothesis` (0-based, in the
    /// order the consensus loop draws them), using `rng` for all randomness.
    ///
    /// Panics if `sample.len()` exceeds `n` or [`MAX_SAMPLE_SIZE`] (a programming error).
    fn draw<R: Rng + ?Sized>(&self, hypothesis: u64, rng: &mut R, sample: &mut [usize]);

    /// Probability that a single draw picks item `i`, when the sampler's law does not change with the
    /// hypothesis number; `None` otherwise (e.g. PROSAC). The consensus loop uses it for adaptive
    /// termination. Default: `None`.
    fn draw_probability(&self, _i: usize) -> Option<f64> {
        None
    }
}

/// Fills `sample` with distinct values produced by `draw_one`, redrawing a slot whenever it repeats
/// an earlier one (rejection keeps each slot's marginal distribution conditioned on distinctness,
/// the usual way to draw a sample without replacement from a non-uniform law).
pub(crate) fn fill_distinct(sample: &mut [usize], mut draw_one: impl FnMut() -> usize) {
    for i in 0..sample.len() {
        sample[i] = loop {
            let candidate = draw_one();
            if !sample[..i].contains(&candidate) {
                break candidate;
            }
        };
    }
}

/// Checks the sample size against `n` and [`MAX_SAMPLE_SIZE`].
pub(crate) fn check_sample_len(sample_len: usize, n: usize) {
    assert!(
        sample_len <= n && sample_len <= MAX_SAMPLE_SIZE,
        "sample of {sample_len} distinct indices requested from {n} items (max {MAX_SAMPLE_SIZE})"
    );
}

/// Uniform index in `[0, n)`; `n` must fit in `u32` so the draw is the same on every platform.
#[inline]
pub(crate) fn uniform_index<R: Rng + ?Sized>(rng: &mut R, n: usize) -> usize {
    rng.random_range(0..n as u32) as usize
}

/// Plain RANSAC: every `s`-subset of `[0, n)` is equally likely (Fischler & Bolles 1981).
#[derive(Debug, Clone)]
pub struct Uniform {
    n: usize,
}

impl Uniform {
    /// A uniform sampler over `n` items. Panics if `n` is 0 or exceeds `u32::MAX`.
    pub fn new(n: usize) -> Self {
        assert!(
            n > 0 && n <= u32::MAX as usize,
            "uniform sampler over {n} items"
        );
        Self { n }
    }
}

impl Sampler for Uniform {
    fn num_items(&self) -> usize {
        self.n
    }

    fn draw<R: Rng + ?Sized>(&self, _hypothesis: u64, rng: &mut R, sample: &mut [usize]) {
        check_sample_len(sample.len(), self.n);
        fill_distinct(sample, || uniform_index(rng, self.n));
    }

    fn draw_probability(&self, _i: usize) -> Option<f64> {
        Some(1.0 / self.n as f64)
    }
}

/// The RNG of hypothesis number `hypothesis` under run seed `seed`: an independent PCG stream per
/// hypothesis, so hypotheses can be drawn in any order or on any thread with identical results.
pub fn hypothesis_rng(seed: u64, hypothesis: u64) -> rand_pcg::Pcg64Mcg {
    let hi = splitmix64(seed ^ 0x6d69_7265_6721_0001);
    let lo = splitmix64(hi ^ hypothesis.wrapping_mul(0x9e37_79b9_7f4a_7c15));
    let state = ((splitmix64(hi.wrapping_add(hypothesis)) as u128) << 64) | lo as u128;
    // NOTE: an MCG state must be odd.
    rand_pcg::Pcg64Mcg::new(state | 1)
}

/// SplitMix64 finaliser (Steele, Lea & Flood 2014): a bijective 64-bit mixer.
pub(crate) fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_samples_are_distinct_and_in_range() {
        let sampler = Uniform::new(5);
        let mut rng = hypothesis_rng(7, 0);
        let mut s = [0usize; 5];
        for h in 0..1000 {
            sampler.draw(h, &mut rng, &mut s);
            let mut sorted = s;
            sorted.sort_unstable();
            assert_eq!(sorted, [0, 1, 2, 3, 4]);
        }
    }

    #[test]
    fn hypothesis_streams_differ() {
        let a: u64 = hypothesis_rng(1, 0).random();
        let b: u64 = hypothesis_rng(1, 1).random();
        let c: u64 = hypothesis_rng(2, 0).random();
        assert!(a != b && a != c && b != c);
        assert_eq!(a, hypothesis_rng(1, 0).random::<u64>());
    }
}
