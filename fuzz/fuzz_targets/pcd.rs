//! Fuzz target `pcd`: the input as a PCD file (header, records, nuScenes radar points, PointCloud2).
//! The body is `bodies::pcd` (fuzz/bodies.rs), which tests/fuzz_regressions.rs runs too.
#![no_main]

#[allow(dead_code)]
#[path = "../bodies.rs"]
mod bodies;

libfuzzer_sys::fuzz_target!(|data: &[u8]| bodies::pcd(data));
