//! Ranking metrics for putative correspondences (MI-RANSAC's "more informed" step).
//!
//! Each function takes per-correspondence scores computed from the descriptors and returns a
//! [`Ranking`]: the permutation that puts the most promising correspondence first, plus the scores.
//! Ties keep the original order (lowest correspondence index first), so rankings are deterministic.

/// A ranking of `n` correspondences.
#[derive(Debug, Clone, PartialEq)]
pub struct Ranking {
    /// `order[k]` is the index of the correspondence at rank `k` (rank 0 = most likely inlier).
    pub order: Vec<u32>,
    /// `scores[i]` is correspondence `i`'s score (indexed by correspondence, not by rank).
    pub scores: Vec<f64>,
}

impl Ranking {
    /// Reorders per-correspondence data into rank order: `out[k] = items[order[k]]`.
    pub fn apply<T: Copy>(&self, items: &[T]) -> Vec<T> {
        assert_eq!(
            items.len(),
            self.order.len(),
            "ranking and data differ in length"
        );
        self.order.iter().map(|&i| items[i as usize]).collect()
    }

    /// Looks up per-correspondence indices into `items`, in rank order:
    /// `out[k] = items[index[order[k]]]` (e.g. the source points of the ranked correspondences,
    /// with `index` = the matches' source indices).
    pub fn gather<T: Copy>(&self, index: &[u32], items: &[T]) -> Vec<T> {
        self.apply(index)
            .iter()
            .map(|&i| items[i as usize])
            .collect()
    }
}

/// Sort direction for the paper's neighbour-count metric.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CountOrder {
    /// Largest count first: what the authors' code does (ascending sort, then reversed).
    #[default]
    MostFirst,
    /// Smallest count first: a distinctive descriptor (few look-alikes) ranks high.
    FewestFirst,
}

/// The authors' default descriptor radius τ_d for the neighbour-count metric, on Open3D/PCL-scale
/// FPFH (33 bins, each 11-bin block summing to 100) \[descriptor units\].
pub const PAPER_DESCRIPTOR_RADIUS: f64 = 12.0;

fn rank(scores: Vec<f64>, higher_first: bool) -> Ranking {
    assert!(
        scores.len() <= u32::MAX as usize,
        "too many correspondences to rank"
    );
    let mut order: Vec<u32> = (0..scores.len() as u32).collect();
    // Stable sort: equal scores keep ascending index order. NaN scores sort last either way.
    order.sort_by(|&a, &b| {
        let (x, y) = (scores[a as usize], scores[b as usize]);
        match (x.is_nan(), y.is_nan()) {
            (true, true) => std::cmp::Ordering::Equal,
            (true, false) => std::cmp::Ordering::Greater,
            (false, true) => std::cmp::Ordering::Less,
            _ if higher_first => y.total_cmp(&x),
            _ => x.total_cmp(&y),
        }
    });
    Ranking { order, scores }
}

/// (a) The paper's metric (Zhang & Chen, Sec. III-B; authors' code): `counts[i]` is the number of
/// target descriptors within τ_d ([`PAPER_DESCRIPTOR_RADIUS`]) of correspondence `i`'s source
/// descriptor; a count of 0 is replaced by `num_target` (as the authors do), then sorted by `order`.
pub fn rank_by_neighbour_count(counts: &[u32], num_target: usize, order: CountOrder) -> Ranking {
    let scores = counts
        .iter()
        .map(|&c| if c == 0 { num_target as f64 } else { c as f64 })
        .collect();
    rank(scores, order == CountOrder::MostFirst)
}

/// (b) Ascending descriptor distance between the matched source and target descriptors.
pub fn rank_by_distance(distances: &[f32]) -> Ranking {
    rank(distances.iter().map(|&d| d as f64).collect(), false)
}

/// (c) Ascending Lowe ratio `d1 / d2` (Lowe 2004): nearest over second-nearest descriptor distance.
/// A zero second distance gives ratio 1 (the match is not distinctive).
pub fn rank_by_ratio(nearest: &[f32], second: &[f32]) -> Ranking {
    assert_eq!(
        nearest.len(),
        second.len(),
        "distance slices differ in length"
    );
    let scores = nearest
        .iter()
        .zip(second)
        .map(|(&d1, &d2)| if d2 > 0.0 { d1 as f64 / d2 as f64 } else { 1.0 })
        .collect();
    rank(scores, false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neighbour_count_orders_and_zero_rule() {
        let counts = [3, 0, 7, 3, 1];
        let r = rank_by_neighbour_count(&counts, 10, CountOrder::MostFirst);
        // 0 becomes 10, so index 1 ranks first; ties (3, 3) keep index order.
        assert_eq!(r.order, vec![1, 2, 0, 3, 4]);
        assert_eq!(r.scores[1], 10.0);
        let r = rank_by_neighbour_count(&counts, 10, CountOrder::FewestFirst);
        assert_eq!(r.order, vec![4, 0, 3, 2, 1]);
    }

    #[test]
    fn distance_and_ratio() {
        let r = rank_by_distance(&[0.5, 0.1, f32::NAN, 0.3]);
        assert_eq!(r.order, vec![1, 3, 0, 2]);
        let r = rank_by_ratio(&[1.0, 1.0, 2.0], &[2.0, 0.0, 10.0]);
        assert_eq!(r.order, vec![2, 0, 1]);
        assert_eq!(r.apply(&['a', 'b', 'c']), vec!['c', 'a', 'b']);
        // Correspondence k points at items[index[k]]; rank order is 2, 0, 1.
        assert_eq!(
            r.gather(&[4, 0, 2], &['p', 'q', 'r', 's', 't']),
            vec!['r', 't', 'p']
        );
    }
}
