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
    estimate_normals, estimate_normals_from_neighbourhoods, estimate_normals_with_tree,
};
pub use radius_grid::RadiusGrid;
pub use voxel::voxel_downsample;
