//! Fuzz target `keyframe_map`: the input as a keyframe map file (framed with a valid CRC-32, or raw), loaded.
//! The body is `bodies::keyframe_map` (fuzz/bodies.rs), which tests/fuzz_regressions.rs runs too.
#![no_main]

#[allow(dead_code)]
#[path = "../bodies.rs"]
mod bodies;

libfuzzer_sys::fuzz_target!(|data: &[u8]| bodies::keyframe_map(data));
