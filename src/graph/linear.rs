//! The sparse normal equations `H δ = −g` of the pose graph: 6×6 blocks over the free nodes
//! (all but node 0), a block-level minimum-degree ordering, and one `CscCholesky` whose symbolic
//! factorisation is computed once and reused (`refactor`) for every linearisation and damping.

use std::collections::BTreeSet;

use nalgebra::{DMatrix, DVector, Matrix6, Vector6};
use nalgebra_sparse::CscMatrix;
use nalgebra_sparse::factorization::CscCholesky;
use nalgebra_sparse::pattern::SparsityPattern;

/// Where a 6×6 block lives in the CSC value array: entry `(6r+i, 6c+j)` is at
/// `base + j·stride + i` (every scalar column of a block column has the same row list).
#[derive(Debug, Clone, Copy)]
struct BlockSlot {
    base: usize,
    stride: usize,
}

/// The slots an edge writes into; `None` where an end is the fixed node 0.
#[derive(Debug, Clone, Copy)]
struct EdgeSlots {
    from: Option<(usize, BlockSlot)>,
    to: Option<(usize, BlockSlot)>,
    /// Block (row = position of `to`, column = position of `from`) and its transpose.
    cross: Option<(BlockSlot, BlockSlot)>,
}

/// Block-sparse Hessian over the free nodes with a fixed pattern.
#[derive(Debug)]
pub(crate) struct NormalEquations {
    /// Free node `k` (graph node `k + 1`) sits at block position `position[k]`.
    position: Vec<usize>,
    matrix: CscMatrix<f64>,
    /// Indices of the scalar diagonal entries in `matrix.values()`.
    diagonal: Vec<usize>,
    edge_slots: Vec<EdgeSlots>,
    /// The undamped assembly (kept so that damping can change without re-linearising).
    undamped: Vec<f64>,
    pub(crate) gradient: DVector<f64>,
    cholesky: Option<CscCholesky<f64>>,
}

/// Greedy minimum-degree elimination order of the free-node graph (Markowitz / Tinney scheme 2 on
/// blocks). `CscCholesky` does no fill-reducing ordering of its own.
fn minimum_degree_order(adjacency: &[BTreeSet<usize>]) -> Vec<usize> {
    let n = adjacency.len();
    let mut adj = adjacency.to_vec();
    let mut eliminated = vec![false; n];
    let mut position = vec![0; n];
    for step in 0..n {
        let v = (0..n)
            .filter(|&u| !eliminated[u])
            .min_by_key(|&u| adj[u].len())
            .expect("a node is left");
        eliminated[v] = true;
        position[v] = step;
        let neighbours: Vec<usize> = std::mem::take(&mut adj[v]).into_iter().collect();
        for &a in &neighbours {
            adj[a].remove(&v);
            for &b in &neighbours {
                if a != b {
                    adj[a].insert(b);
                }
            }
        }
    }
    position
}

impl NormalEquations {
    /// Builds the pattern for `node_count` nodes (node 0 fixed) and the edges' `(from, to)`.
    pub(crate) fn new(node_count: usize, edges: &[(usize, usize)]) -> Self {
        let free = node_count - 1;
        let mut adjacency = vec![BTreeSet::new(); free];
        for &(a, b) in edges {
            if a > 0 && b > 0 && a != b {
                adjacency[a - 1].insert(b - 1);
                adjacency[b - 1].insert(a - 1);
            }
        }
        let position = minimum_degree_order(&adjacency);
        // Block rows of each block column (in positions), sorted: diagonal + neighbours.
        let mut rows: Vec<Vec<usize>> = vec![Vec::new(); free];
        for k in 0..free {
            let c = position[k];
            rows[c].push(c);
            rows[c].extend(adjacency[k].iter().map(|&m| position[m]));
            rows[c].sort_unstable();
        }
        let mut col_offsets = Vec::with_capacity(6 * free + 1);
        let mut row_indices = Vec::new();
        let mut block_base = vec![0; free];
        for (c, block_rows) in rows.iter().enumerate() {
            block_base[c] = row_indices.len();
            for _ in 0..6 {
                col_offsets.push(row_indices.len());
                for &r in block_rows {
                    row_indices.extend(6 * r..6 * r + 6);
                }
            }
        }
        col_offsets.push(row_indices.len());
        let nnz = row_indices.len();
        let pattern = SparsityPattern::try_from_offsets_and_indices(
            6 * free,
            6 * free,
            col_offsets,
            row_indices,
        )
        .expect("pattern is built sorted and in range");
        let matrix = CscMatrix::try_from_pattern_and_values(pattern, vec![0.0; nnz])
            .expect("values match the pattern");
        let slot = |r: usize, c: usize| {
            let rank = rows[c].binary_search(&r).expect("block is in the pattern");
            BlockSlot {
                base: block_base[c] + 6 * rank,
                stride: 6 * rows[c].len(),
            }
        };
        let mut diagonal = Vec::with_capacity(6 * free);
        for c in 0..free {
            let s = slot(c, c);
            diagonal.extend((0..6).map(|i| s.base + i * s.stride + i));
        }
        let edge_slots = edges
            .iter()
            .map(|&(a, b)| {
                let pa = (a > 0).then(|| position[a - 1]);
                let pb = (b > 0).then(|| position[b - 1]);
                EdgeSlots {
                    from: pa.map(|p| (p, slot(p, p))),
                    to: pb.map(|p| (p, slot(p, p))),
                    cross: match (pa, pb) {
                        (Some(p), Some(q)) if p != q => Some((slot(q, p), slot(p, q))),
                        _ => None,
                    },
                }
            })
            .collect();
        Self {
            position,
            matrix,
            diagonal,
            edge_slots,
            undamped: vec![0.0; nnz],
            gradient: DVector::zeros(6 * free),
            cholesky: None,
        }
    }

    /// Zeroes the Hessian and the gradient before an assembly.
    pub(crate) fn clear(&mut self) {
        self.undamped.fill(0.0);
        self.gradient.fill(0.0);
    }

    fn add_block(values: &mut [f64], slot: BlockSlot, block: &Matrix6<f64>) {
        for j in 0..6 {
            let col = slot.base + j * slot.stride;
            for i in 0..6 {
                values[col + i] += block[(i, j)];
            }
        }
    }

    /// Adds edge `index`'s weighted terms: `H += JᵀWJ`, `g += JᵀWe` with `W = w Ω`.
    pub(crate) fn add_edge(
        &mut self,
        index: usize,
        j_from: &Matrix6<f64>,
        j_to: &Matrix6<f64>,
        weighted_information: &Matrix6<f64>,
        error: &Vector6<f64>,
    ) {
        let slots = self.edge_slots[index];
        let wf = j_from.transpose() * weighted_information;
        let wt = j_to.transpose() * weighted_information;
        let we = weighted_information * error;
        if let Some((p, s)) = slots.from {
            Self::add_block(&mut self.undamped, s, &(wf * j_from));
            let mut g = self.gradient.fixed_rows_mut::<6>(6 * p);
            g += j_from.transpose() * we;
        }
        if let Some((p, s)) = slots.to {
            Self::add_block(&mut self.undamped, s, &(wt * j_to));
            let mut g = self.gradient.fixed_rows_mut::<6>(6 * p);
            g += j_to.transpose() * we;
        }
        if let Some((to_from, from_to)) = slots.cross {
            let block = wt * j_from; // rows: `to`, columns: `from`
            Self::add_block(&mut self.undamped, to_from, &block);
            Self::add_block(&mut self.undamped, from_to, &block.transpose());
        }
    }

    /// `½ δᵀ H δ + gᵀ δ` of the undamped model (δ in block positions).
    pub(crate) fn model_change(&self, delta: &DVector<f64>) -> f64 {
        let (offsets, indices, _) = self.matrix.csc_data();
        let mut quad = 0.0;
        for col in 0..delta.len() {
            let dc = delta[col];
            for p in offsets[col]..offsets[col + 1] {
                quad += delta[indices[p]] * self.undamped[p] * dc;
            }
        }
        0.5 * quad + self.gradient.dot(delta)
    }

    /// Solves `(H + λ I) δ = −g`; `None` when the damped matrix is not positive definite.
    pub(crate) fn solve(&mut self, lambda: f64) -> Option<DVector<f64>> {
        let values = self.matrix.values_mut();
        values.copy_from_slice(&self.undamped);
        for &d in &self.diagonal {
            values[d] += lambda;
        }
        match &mut self.cholesky {
            Some(chol) => chol.refactor(self.matrix.values()).ok()?,
            None => self.cholesky = Some(CscCholesky::factor(&self.matrix).ok()?),
        }
        let chol = self.cholesky.as_ref().expect("factorised above");
        let rhs = DMatrix::from_column_slice(self.gradient.len(), 1, (-&self.gradient).as_slice());
        let x = chol.solve(&rhs);
        let x = DVector::from_column_slice(x.as_slice());
        x.iter().all(|v| v.is_finite()).then_some(x)
    }

    /// Block position of free node `k` (graph node `k + 1`).
    pub(crate) fn position(&self, free_node: usize) -> usize {
        self.position[free_node]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sparse_solve_matches_dense() {
        // A loop 0-1-2-3-0 plus a chord 1-3, random SPD blocks.
        let edges = [(0, 1), (1, 2), (2, 3), (3, 0), (1, 3)];
        let mut ne = NormalEquations::new(4, &edges);
        let mut dense = DMatrix::<f64>::zeros(18, 18);
        let mut gdense = DVector::<f64>::zeros(18);
        ne.clear();
        for (k, &(a, b)) in edges.iter().enumerate() {
            let s = k as f64;
            let jf = Matrix6::from_fn(|i, j| ((i * 7 + j * 3) as f64 + s).sin());
            let jt = Matrix6::from_fn(|i, j| ((i * 5 + j * 11) as f64 - s).cos());
            let w = Matrix6::from_diagonal(&Vector6::from_fn(|i, _| 1.0 + i as f64 + s));
            let e = Vector6::from_fn(|i, _| (i as f64 + s).sin());
            ne.add_edge(k, &jf, &jt, &w, &e);
            // Dense reference: stacked Jacobian over the free nodes 1..3 (identity positions).
            let mut j = DMatrix::<f64>::zeros(6, 18);
            if a > 0 {
                j.view_mut((0, 6 * (a - 1)), (6, 6)).copy_from(&jf);
            }
            if b > 0 {
                j.view_mut((0, 6 * (b - 1)), (6, 6)).copy_from(&jt);
            }
            let wd = DMatrix::from_column_slice(6, 6, w.as_slice());
            let ed = DVector::from_column_slice(e.as_slice());
            dense += j.transpose() * &wd * &j;
            gdense += j.transpose() * &wd * ed;
        }
        let lambda = 1e-3;
        let delta = ne.solve(lambda).expect("SPD");
        let reference = (dense + DMatrix::identity(18, 18) * lambda)
            .cholesky()
            .expect("SPD")
            .solve(&(-gdense));
        for free in 0..3 {
            let p = ne.position(free);
            let got = delta.rows(6 * p, 6);
            let want = reference.rows(6 * free, 6);
            assert!((got - want).norm() < 1e-9 * (1.0 + want.norm()));
        }
    }
}
