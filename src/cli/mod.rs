//! Command-line front ends: the offline subcommands and the node's entry point.
//!
//! Entry points: [`main`] (subcommands `sim`, `run`, `eval`, `demo`), [`node_main`] (the ROS 2 node).

/// Runs an offline subcommand; returns the process exit code.
pub fn main(args: &[String]) -> i32 {
    eprintln!("dc_loc: subcommands are being written (args: {args:?})");
    2
}

/// Runs the ROS 2 node; returns the process exit code.
pub fn node_main(args: &[String]) -> i32 {
    eprintln!("dc_loc: the ROS 2 node is being written (args: {args:?})");
    2
}
