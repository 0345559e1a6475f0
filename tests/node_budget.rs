//! The keyframe budget on the live node (`-p node.keyframe_budget:=S`): the five-radar drive of
//! examples/support/replay.rs replayed over DDS into a running `dc_loc` node whose budget, 0.1 ms from an
//! input's arrival, is spent before each revisit search begins. The node must still register each new
//! keyframe against its best-ranked candidate (closures published), leave out the rest in the documented
//! order and count it in `/diagnostics` (`budget.candidates_skipped`, `budget.backfill_put_off`,
//! `budget.rounds_skipped`), count the keyframes finished late all the same (`budget.late_keyframes`,
//! never more than the keyframes), and exit 0 on SIGINT. tests/search_budget.rs checks the same trimming
//! in the pipeline against the simulator's truth.
//!
//! DDS stays on loopback in domain 74; the drive is replayed at five times real time (about 25 s).

mod common;
#[path = "../examples/support/replay.rs"]
mod replay;

use std::collections::BTreeMap;
use std::time::Instant;

use replay::{Drive, start_node, stop_node};

const DOMAIN: u16 = 74;
const RATE: f64 = 5.0;

fn count(values: &BTreeMap<String, String>, key: &str) -> u64 {
    values.get(key).map_or(0, |v| v.parse().unwrap_or(0))
}

#[test]
fn a_spent_keyframe_budget_trims_the_live_search_and_counts_it() {
    let dir = common::scratch("node_budget", "replay");
    let drive = Drive::simulate(&dir.join("drive"));
    let log_path = dir.join("node.log");
    let log = std::fs::File::create(&log_path).unwrap();
    let node = start_node(
        env!("CARGO_BIN_EXE_dc_loc"),
        &drive.summary.params_file,
        &[
            "-p".into(),
            "node.diagnostics_period:=0.5".into(),
            "-p".into(),
            "node.keyframe_budget:=0.0001".into(),
        ],
        DOMAIN,
        None,
        log.into(),
    );
    let t0 = Instant::now();
    let values = replay::replay_drive(DOMAIN, &drive, RATE, None);
    let code = stop_node(node);
    let log = std::fs::read_to_string(&log_path).unwrap();
    let tail: Vec<&str> = log.lines().rev().take(20).collect();
    assert_eq!(
        code,
        Some(0),
        "the node's exit; its log ends with {tail:#?}"
    );

    let budget: BTreeMap<&str, u64> = [
        "budget.backfill_put_off",
        "budget.rounds_skipped",
        "budget.candidates_skipped",
        "budget.late_keyframes",
    ]
    .into_iter()
    .map(|k| (k, count(&values, k)))
    .collect();
    let (keyframes, closures) = (count(&values, "keyframes"), count(&values, "closures"));
    println!(
        "replayed in {:.0} s at {RATE}x: {keyframes} keyframes, {closures} closures, {budget:?}",
        t0.elapsed().as_secs_f64()
    );
    for key in budget.keys() {
        assert!(values.contains_key(*key), "{key} missing from /diagnostics");
    }
    assert!(
        budget["budget.candidates_skipped"] > 0,
        "a budget spent before each search leaves every candidate but the best-ranked out: {budget:?}"
    );
    assert!(
        budget["budget.late_keyframes"] > 0 && budget["budget.late_keyframes"] <= keyframes,
        "every keyframe finishes after 0.1 ms, and each is counted once: {budget:?}, {keyframes} keyframes"
    );
    assert!(
        closures > 0,
        "each new keyframe is still registered against its best-ranked candidate"
    );
}
