//! The ROS 2 node (cargo feature `ros`, on by default): ros2-client/rustdds, no rclcpp or rclrs.
//!
//! The node is a thin layer: messages in, [`crate::pipeline::Pipeline`] on a worker thread, messages
//! out. Entry points: [`node::main`] (the `dc_loc` binary without a subcommand), [`args`] (the ROS 2
//! command line and environment, which ros2-client does not parse), [`crate::params::node`] (the node's own
//! parameters), [`inputs`] (one reception task per subscription), [`worker`] (the pipeline's thread and
//! the publishers), [`diagnostics`], [`rosout`] (the log on `/rosout`), [`services`] (`~/save_map`, `~/relocalized`), [`map_store`] (the map on disk), [`convert`] (the node's message
//! types and conversions to them), [`tf`] (extrinsics from `/tf_static`), [`backends`] (the optional `pose_graph_tools_msgs/PoseGraph` and
//! LIO-SAM outputs), [`merge`] (inputs back in stamp order). Topics and parameters: README_NODE.md.

pub mod args;
#[cfg(feature = "ros")]
pub mod backends;
pub mod convert;
pub mod diagnostics;
#[cfg(feature = "ros")]
pub mod endpoints;
#[cfg(feature = "ros")]
pub mod error;
#[cfg(feature = "ros")]
pub mod inputs;
pub mod map_store;
pub mod merge;
#[cfg(feature = "ros")]
pub mod node;
#[cfg(feature = "ros")]
pub mod rosout;
#[cfg(feature = "ros")]
pub mod services;
pub mod shared;
#[cfg(feature = "ros")]
pub mod tf;
#[cfg(feature = "ros")]
pub mod worker;
