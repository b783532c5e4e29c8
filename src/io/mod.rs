//! File readers: point clouds (PLY, PCD, NumPy `.npy`, KITTI `.bin`) and poses (4×4 text
//! matrices, Redwood/3DMatch `.log`, Stanford `bun.conf`).
//!
//! Readers parse from byte slices or strings with a path used only for error messages, so
//! they can be tested without files; the `read_*` functions add the file system on top.

pub mod cloud_file;
pub mod foxglove_msgs;
pub mod mcap_log;
pub mod pose_file;
pub mod ros2;
