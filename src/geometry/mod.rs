//! Point-cloud geometry: voxel-grid downsampling, kd-tree neighbourhoods and normal estimation,
//! matching Open3D's semantics (see each module for where and why we depart).

pub mod deskew;
pub mod grid;
pub mod kdtree;
pub mod normals;
pub mod radius_grid;
pub mod voxel;

pub use kdtree::{KdTree, Neighbour, Neighbourhoods};
pub use normals::{
    NO_PLANE, NormalEstimate, estimate_normals, estimate_normals_from_neighbourhoods,
    estimate_normals_with_grid, estimate_normals_with_tree,
};
pub use radius_grid::RadiusGrid;
pub use voxel::{voxel_downsample, voxel_downsample_indexed};

/// `x.floor() as i64`, exactly (also saturating the same way beyond ±2⁶³), without the libm
/// call that `f64::floor` costs on a target without SSE4.1: the voxel and grid keys of every
/// point of every frame go through it. NaN gives 0, as `NaN as i64` does.
#[inline]
pub(crate) fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    // Truncation rounds a negative non-integer up: step down once (saturating, where x is
    // below i64::MIN and `t` already is i64::MIN). NaN compares false.
    t.saturating_sub(i64::from((t as f64) > x))
}

#[cfg(test)]
mod tests {
    use super::floor_i64;

    /// Against `f64::floor` (the oracle) on integers, halves, values one ulp either side of
    /// integers, huge values that saturate, infinities and NaN.
    #[test]
    fn floor_i64_equals_libm_floor() {
        let mut xs = vec![
            0.0,
            -0.0,
            f64::INFINITY,
            f64::NEG_INFINITY,
            9.3e18,
            -9.3e18,
            1e300,
        ];
        for k in -1000i64..=1000 {
            let x = k as f64 * 0.37;
            xs.extend([x, k as f64, k as f64 + 0.5, x.next_up(), x.next_down()]);
            xs.extend([(k as f64).next_up(), (k as f64).next_down()]);
        }
        for x in xs {
            assert_eq!(floor_i64(x), x.floor() as i64, "x = {x:e}");
        }
        assert_eq!(floor_i64(f64::NAN), 0);
    }
}
