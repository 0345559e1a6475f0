//! dc_loc: Doppler-compensated, uncertainty-aware loop closures from automotive radar (DC-Loc, ICRA 2022).
//!
//! This package is the `dc_loc` binary and its command line ([`cli`]). Its library gathers the
//! workspace's crates under one name, for the binary, the tests, the benches and the examples:
//! - `dc_loc_core`: the method ([`radar`], [`submap`], [`registration`], [`keyframe_db`],
//!   [`loop_closure`], [`pipeline`], ...), with no ROS client, DDS, CLI, plotting, file format or
//!   simulator;
//! - `dc_loc_io`: files in and out ([`bag`], [`io`], [`params`]);
//! - `dc_loc_node`: the ROS 2 node ([`ros`], cargo feature `ros`, on by default);
//! - `dc_loc_lab`: the simulator, the evaluation protocol and the baselines ([`sim`], [`eval`],
//!   [`baselines`]).
//!
//! docs/architecture.md says why each crate exists.
#![warn(missing_docs)]
#![forbid(unsafe_code)]

pub mod cli;

pub use dc_loc_core::{
    cdr, cloud, fleet, growing_index, input, keyframe_db, loop_closure, math, msgs, odometry,
    output, pipeline, place, radar, registration, repeats, runner, submap, validate,
};
pub use dc_loc_io::sources as io;
pub use dc_loc_io::{bag, params};
pub use dc_loc_lab::{baselines, eval, sim};
#[cfg(feature = "ros")]
pub use dc_loc_node as ros;
