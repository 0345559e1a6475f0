//! Odometry from the radars themselves, with or without a gyro (`odometry.source: radar | radar_imu`).
//!
//! The radars measure the body's motion on every scan: each static detection's radial velocity is
//! the projection of its radar's velocity on the ray. Fitted jointly over every radar of a time step,
//! with the extrinsics, they give the planar twist `(v_x, v_y, yaw rate)`; integrated, the pose the
//! submaps and the revisit search use, as a `nav_msgs/Odometry` topic would give it.
//! docs/algorithm.md, "Radar odometry", has the model.
//!
//! Entry points: [`RadarOdometry`] (the stage the pipeline runs: scans and gyro samples in,
//! [`OdometryEstimate`]s out), [`OdometrySource`], [`ImuConfig`]. Parts, one job each: [`fit`] (the
//! joint fit of one time step), [`gyro`] (yaw rate, bias, frame check), [`integrate`] (pose and
//! covariance), [`estimator`] (the stage).

pub mod config;
pub mod estimator;
pub mod fit;
pub mod gyro;
pub mod integrate;

pub use config::{ImuConfig, OdometrySource};
pub use estimator::{OdometryEstimate, RadarOdometry, RadarOdometryStats};
