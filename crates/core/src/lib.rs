//! dc_loc_core: the DC-Loc method (Doppler-compensated, uncertainty-aware radar loop closures, ICRA
//! 2022) with no ROS client, DDS, async runtime, command line, plotting, file format or simulator.
//!
//! Data flows one way through one [`pipeline::Pipeline`]: [`input::Input`]s (radar clouds decoded by
//! [`cloud`], odometry, other robots' keyframes) -> radar scans ([`radar`]: Doppler compensation,
//! per-point covariance, ego-motion and moving-object rejection) -> submaps ([`submap`]) -> keyframes in
//! a map ([`keyframe_db`], place search in [`place`]) -> registration ([`registration`]) -> the closure
//! decision ([`loop_closure`]) -> [`pipeline::Event`]s, rendered as ROS messages by [`output`]. The
//! node, the offline runner ([`runner`]), the demo and the tests all drive this pipeline.
#![warn(missing_docs)]
#![forbid(unsafe_code)]

pub mod cdr;
pub mod cloud;
pub mod fleet;
pub mod growing_index;
pub mod input;
pub mod keyframe_db;
pub mod loop_closure;
pub mod math;
pub mod msgs;
pub mod odometry;
pub mod output;
pub mod pipeline;
pub mod place;
pub mod pose_noise;
pub mod radar;
pub mod registration;
pub mod repeats;
pub mod runner;
pub mod submap;
pub mod validate;
