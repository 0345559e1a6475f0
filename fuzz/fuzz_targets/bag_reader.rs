//! Fuzz target `bag_reader`: the input as an MCAP file read by BagReader, every message decoded.
//! The body is `bodies::bag_reader` (fuzz/bodies.rs), which tests/fuzz_regressions.rs runs too.
#![no_main]

#[allow(dead_code)]
#[path = "../bodies.rs"]
mod bodies;

libfuzzer_sys::fuzz_target!(|data: &[u8]| bodies::bag_reader(data));
