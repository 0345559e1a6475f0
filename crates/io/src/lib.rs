//! dc_loc_io: files in and out of the [`dc_loc_core`] pipeline, with no ROS client or DDS.
//!
//! - [`bag`]: rosbag2 bags in MCAP storage (reader, writer, schemas, QoS metadata), ROS 1 bags
//!   (format 2.0, read by the same reader: [`bag::ros1`]) and foxglove MCAP.
//! - [`sources`]: recordings as streams of pipeline inputs (rosbag2 and ROS 1 bags, foxglove MCAP,
//!   nuScenes, View-of-Delft).
//! - [`params`]: the ROS 2 params YAML and `-p` overrides mapped onto the pipeline's configuration,
//!   the node's own settings, and the generated parameter reference.
#![warn(missing_docs)]
#![forbid(unsafe_code)]

pub mod bag;
pub mod params;
pub mod sources;
