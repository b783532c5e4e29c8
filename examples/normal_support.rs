//! How well a log's first cloud supports normals at the voxel `mireg register` derives for it:
//! per point of the voxel cloud, how many neighbours lie within the normal radius (2 voxels,
//! capped at 30 as the pipeline's), how far its k-th nearest neighbour is (in voxels), and the
//! share of neighbourhoods that are lines rather than surfaces (middle over largest eigenvalue
//! of the covariance below 0.05). Prints medians per log.
//!
//! ```sh
//! cargo run --release --example normal_support -- LOG.mcap [LOG.mcap ...]
//! ```

use std::ops::ControlFlow;
use std::path::Path;

use mireg::geometry::{KdTree, voxel_downsample};
use mireg::pipeline::voxel_for_cloud;
use nalgebra::{Matrix3, SymmetricEigen};

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

fn main() -> mireg::Result<()> {
    for arg in std::env::args().skip(1) {
        let mut first = None;
        mireg::register::for_each_cloud(Path::new(&arg), None, |_, cloud| {
            first = Some(cloud.points);
            Ok(ControlFlow::Break(()))
        })?;
        let Some(points) = first else {
            println!("{arg}: no cloud");
            continue;
        };
        let voxel = voxel_for_cloud(&points).expect("a cloud with points");
        let down = voxel_downsample(&points, voxel)?;
        let tree = KdTree::new(&down)?;
        let mut count = Vec::new();
        let mut kth = [5usize, 10, 20].map(|_| Vec::new());
        let mut lines = 0usize;
        for p in &down {
            let near = tree.within_radius(p, 2.0 * voxel, 30);
            count.push(near.len() as f64);
            let knn = tree.nearest_k(p, 21);
            for (slot, k) in kth.iter_mut().zip([5usize, 10, 20]) {
                if let Some(n) = knn.get(k) {
                    slot.push(n.distance_sq.sqrt() / voxel);
                }
            }
            let ids: Vec<usize> = near.iter().map(|n| n.index).collect();
            let line = ids.len() < 3 || {
                let mean = ids
                    .iter()
                    .map(|&i| down[i].coords)
                    .sum::<nalgebra::Vector3<f64>>()
                    / ids.len() as f64;
                let cov = ids.iter().fold(Matrix3::zeros(), |acc, &i| {
                    let d = down[i].coords - mean;
                    acc + d * d.transpose()
                });
                let mut ev: Vec<f64> = SymmetricEigen::new(cov)
                    .eigenvalues
                    .iter()
                    .copied()
                    .collect();
                ev.sort_by(f64::total_cmp);
                ev[1] < 0.05 * ev[2]
            };
            lines += usize::from(line);
        }
        println!(
            "{arg}: voxel {voxel:.3} m, {} points; within 2 voxels: median {:.0}; k-th neighbour \
             (voxels) k=5 {:.2} k=10 {:.2} k=20 {:.2}; lines {:.1} %",
            down.len(),
            median(count),
            median(std::mem::take(&mut kth[0])),
            median(std::mem::take(&mut kth[1])),
            median(std::mem::take(&mut kth[2])),
            100.0 * lines as f64 / down.len() as f64
        );
    }
    Ok(())
}
