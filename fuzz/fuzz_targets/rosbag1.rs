//! Fuzz target `rosbag1`: the input as a ROS 1 bag read by BagReader, every message decoded.
//! The body is `bodies::rosbag1` (fuzz/bodies.rs), which tests/fuzz_regressions.rs runs too.
#![no_main]

#[allow(dead_code)]
#[path = "../bodies.rs"]
mod bodies;

libfuzzer_sys::fuzz_target!(|data: &[u8]| bodies::rosbag1(data));
