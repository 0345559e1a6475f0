//! dc_loc_lab: where the method is measured, with no ROS client or DDS.
//!
//! - [`sim`]: the radar scenario simulator (worlds, routes, radars with the FMCW Doppler range
//!   distortion, drifting odometry, fleets) and its export as rosbag2 bags.
//! - [`eval`]: the paper's evaluation protocol and the precision and recall of closures on drives with
//!   ground truth; tables and plots.
//! - [`baselines`]: ICP, NDT and MC-RANSAC, the methods the paper compares against.
#![warn(missing_docs)]
#![forbid(unsafe_code)]

pub mod baselines;
pub mod eval;
pub mod sim;
