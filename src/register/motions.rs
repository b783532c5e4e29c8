//! Deskewing inside the streaming pipeline: the motions of registered frames handed back from
//! the registering thread to the preparing one.

use std::collections::BTreeMap;
use std::sync::mpsc::Receiver;

use nalgebra::Isometry3;

/// The motions of registered frames as the registering thread reports them, for deskewing:
/// frame `k` is deskewed with frame `k − 2`'s motion, the latest one that is surely known when
/// `k` is prepared (frame `k − 1` is being registered meanwhile), so the result does not depend
/// on thread timing.
pub(super) struct Motions {
    rx: Receiver<(usize, Isometry3<f64>, f64)>,
    known: BTreeMap<usize, (Isometry3<f64>, f64)>,
}

impl Motions {
    pub(super) fn new(rx: Receiver<(usize, Isometry3<f64>, f64)>) -> Self {
        Self {
            rx,
            known: BTreeMap::new(),
        }
    }

    /// Frame `k`'s motion (`prev_from_curr`, and the seconds it took), waiting for it; `None`
    /// for the first two frames (no motion yet), once registration has stopped, or when the
    /// motion or its seconds are not finite (nothing is deskewed by them).
    pub(super) fn of(&mut self, k: Option<usize>) -> Option<(Isometry3<f64>, f64)> {
        let k = k.filter(|&k| k >= 1)?;
        while !self.known.contains_key(&k) {
            let (i, m, dt) = self.rx.recv().ok()?;
            self.known.insert(i, (m, dt));
        }
        self.known = self.known.split_off(&k);
        self.known.get(&k).copied().filter(|(motion, dt)| {
            dt.is_finite() && *dt > 0.0 && motion.to_homogeneous().iter().all(|v| v.is_finite())
        })
    }
}
