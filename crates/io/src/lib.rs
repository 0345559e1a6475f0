//! dc_loc_io: files in and out of the [`dc_loc_core`] pipeline, with no ROS client or DDS.
//!
//! - [`bag`]: rosbag2 bags in MCAP storage (reader, writer, schemas, QoS metadata) and foxglove MCAP.
//! - [`sources`]: recordings as streams of pipeline inputs (rosbag2, foxglove MCAP, nuScenes,
//!   View-of-Delft).
//! - [`params`]: the ROS 2 params YAML and `-p` overrides mapped onto the pipeline's configuration,
//!   the node's own settings, and the generated parameter reference.
#![warn(missing_docs)]
#![forbid(unsafe_code)]

pub mod bag;
pub mod params;
pub mod sources;
