//! The ROS 2 node (cargo feature `ros`, on by default): ros2-client/rustdds, no rclcpp or rclrs.
//!
//! Entry points: [`node::main`] (the `dc_loc` binary without a subcommand), [`args`] (the ROS 2 command
//! line and environment, which ros2-client does not parse), [`convert`] (the node's message types and
//! conversions to them). The node is a thin layer: messages in, [`crate::pipeline::Pipeline`] on a worker
//! thread, messages out; see README_NODE.md for topics and parameters.

pub mod args;
pub mod convert;
pub mod merge;
#[cfg(feature = "ros")]
pub mod node;
