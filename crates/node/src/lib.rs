//! dc_loc_node: the ROS 2 node on ros2-client/rustdds, no rclcpp or rclrs.
//!
//! The node is a thin layer: messages in, [`dc_loc_core::pipeline::Pipeline`] on a worker thread, messages
//! out. Entry points: [`node::main`] (the `dc_loc` binary without a subcommand), [`args`] (the ROS 2
//! command line and environment, which ros2-client does not parse), [`dc_loc_io::params::node`] (the node's own
//! parameters), [`inputs`] (one reception task per subscription), [`worker`] (the pipeline's thread and
//! the publishers), [`diagnostics`], [`rosout`] (the log on `/rosout`), [`services`] (`~/save_map`, `~/relocalized`), [`map_store`] (the map on disk), [`convert`] (the node's message
//! types and conversions to them), [`tf`] (extrinsics from `/tf_static`), [`backends`] (the optional `pose_graph_tools_msgs/PoseGraph` and
//! LIO-SAM outputs), [`merge`] (inputs back in stamp order), [`odometry`] (the radar odometry as `~/odometry`
//! and `/tf`). Topics and parameters: README_NODE.md.

#![warn(missing_docs)]
#![forbid(unsafe_code)]

pub mod args;
pub mod backends;
pub mod convert;
pub mod diagnostics;
pub mod endpoints;
pub mod error;
pub mod fleet_identity;
pub mod inputs;
pub mod map_store;
pub mod merge;
pub mod node;
pub mod odometry;
pub mod rosout;
pub mod security;
pub mod services;
pub mod shared;
pub mod tf;
pub mod worker;
