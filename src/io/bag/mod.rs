//! Bag containers: ROS 1 bags (format 2.0) and ROS 2 bag directories (`metadata.yaml` over
//! MCAP or SQLite storage, maybe zstd-compressed). Both feed the same catalog and message stream as an MCAP input
//! ([`crate::io::mcap::log::InputCatalog`]).

pub mod compression;
pub mod ros1;
pub mod rosbag2;
pub mod temp;
