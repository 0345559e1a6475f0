//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The real-data folder: `$DC_LOC_REAL_DATA` if set, else `<manifest>/../shared/data/real` (the main
/// checkout), else `<manifest>/../../shared/data/real` (a worktree under `/work/wt/`). `None` (after
/// printing why) only when none exists: that is the only case in which real-data tests skip.
pub fn real_data() -> Option<PathBuf> {
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut candidates = Vec::new();
    if let Some(dir) = std::env::var_os("DC_LOC_REAL_DATA") {
        candidates.push(PathBuf::from(dir));
    }
    candidates.push(manifest.join("../shared/data/real"));
    candidates.push(manifest.join("../../shared/data/real"));
    let found = candidates.iter().find(|p| p.is_dir()).cloned();
    if found.is_none() {
        eprintln!(
            "SKIPPED: real data folder not found (tried {candidates:?}); set DC_LOC_REAL_DATA to run"
        );
    }
    found
}
