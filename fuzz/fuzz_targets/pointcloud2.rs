//! Fuzz target `pointcloud2`: a PointCloud2 built field by field from the input (layout, sizes, byte order, field names, limits, data), decoded as the pipeline decodes radar clouds.
//! The body is `bodies::pointcloud2` (fuzz/bodies.rs), which tests/fuzz_regressions.rs runs too.
#![no_main]

#[allow(dead_code)]
#[path = "../bodies.rs"]
mod bodies;

libfuzzer_sys::fuzz_target!(|data: &[u8]| bodies::pointcloud2(data));
