//! Fuzz target `cdr`: the input as ROS 2 CDR bytes, decoded as PointCloud2, Odometry and TFMessage.
//! The body is `bodies::cdr` (fuzz/bodies.rs), which tests/fuzz_regressions.rs runs too.
#![no_main]

#[allow(dead_code)]
#[path = "../bodies.rs"]
mod bodies;

libfuzzer_sys::fuzz_target!(|data: &[u8]| bodies::cdr(data));
