//! dc_loc: Doppler-compensated, uncertainty-aware loop closures from automotive radar (DC-Loc, ICRA 2022).
//!
//! The library is the algorithm core: no DDS, no async, no wall clock. Data flows one way:
//! bytes ([`cloud`], [`io`]) -> radar scans ([`radar`]: Doppler compensation, per-point covariance,
//! ego-motion and moving-object rejection) -> submaps ([`submap`]) -> registration ([`registration`],
//! [`baselines`]) -> results. The node, the offline runner, the demo and the tests drive the same code.
#![warn(missing_docs)]
#![forbid(unsafe_code)]

pub mod bag;
pub mod baselines;
pub mod cli;
pub mod cloud;
pub mod eval;
pub mod fleet;
pub mod growing_index;
pub mod input;
pub mod io;
pub mod keyframe_db;
pub mod loop_closure;
pub mod math;
pub mod msgs;
pub mod output;
pub mod params;
pub mod pipeline;
pub mod place;
pub mod radar;
pub mod registration;
pub mod ros;
pub mod runner;
pub mod sim;
pub mod submap;
pub mod validate;
