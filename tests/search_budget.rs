//! A deadline on the revisit search each input sets off (`Pipeline::set_deadline`, which the node sets
//! from `node.keyframe_budget`), on the short simulated drive of tests/common with the five radars of
//! the nuScenes car: a deadline far ahead changes no event; one already passed at every input leaves
//! work out in the documented order (the searches again of older keyframes put off, the rounds after
//! the first not registered, each new keyframe registered against its best-ranked candidate alone),
//! counts all of it, and every closure it still publishes is within 2 m of the simulator's truth.

mod common;
use common::SHORT_DRIVE;
use std::time::{Duration, Instant};

use dc_loc::math::iso2_from_iso3;
use dc_loc::pipeline::{Event, Pipeline, PipelineStats};
use dc_loc::sim::inputs::{ScanEncoding, SimInputs};
use dc_loc::sim::{SimConfig, SimDrive, simulate};

/// The drive through a pipeline whose deadline for each input is `deadline()`: its events and stats.
fn run(drive: &SimDrive, deadline: impl Fn() -> Option<Instant>) -> (Vec<Event>, PipelineStats) {
    let mut p = Pipeline::new(drive.to_config()).expect("valid");
    let mut events = Vec::new();
    for input in SimInputs::new(drive, ScanEncoding::Detections).flatten() {
        p.set_deadline(deadline());
        events.extend(p.push(&input));
    }
    events.extend(p.finish());
    (events, p.stats().clone())
}

fn closures(events: &[Event]) -> Vec<&dc_loc::loop_closure::LoopClosure> {
    events
        .iter()
        .filter_map(|e| match e {
            Event::Closure(c) => Some(c.as_ref()),
            _ => None,
        })
        .collect()
}

#[test]
fn a_passed_deadline_trims_the_search_in_order_and_counts_it() {
    let cfg: SimConfig =
        yaml_serde::from_str(&format!("{SHORT_DRIVE}radar_preset: nuscenes\n")).expect("drive");
    let drive = simulate(&cfg).expect("valid");
    let (free, free_stats) = run(&drive, || None);
    let (ahead, ahead_stats) = run(&drive, || Some(Instant::now() + Duration::from_secs(3600)));
    assert_eq!(free, ahead, "a deadline that never passes changes nothing");
    assert!(!free_stats.trimmed.any() && !ahead_stats.trimmed.any());

    let (late, late_stats) = run(&drive, || Some(Instant::now()));
    let t = late_stats.trimmed;
    println!(
        "no deadline: {} registrations, {} closures; deadline passed at every input: {} registrations, {} closures, trimmed {t:?}",
        free_stats.registrations,
        closures(&free).len(),
        late_stats.registrations,
        closures(&late).len()
    );
    assert!(t.candidates > 0 && t.backfill > 0, "{t:?}");
    assert!(late_stats.registrations < free_stats.registrations);
    assert_eq!(
        late_stats.keyframes, free_stats.keyframes,
        "every keyframe is made"
    );
    // Every keyframe's search registered one candidate at most (arrivals of other robots' keyframes:
    // none here; the searches again at the end of the input run without a deadline).
    let end_searches = free_stats.registrations.min(late_stats.registrations);
    assert!(late_stats.registrations <= late_stats.keyframes + end_searches);
    for c in closures(&late) {
        let truth = drive.state_at(c.match_stamp).t_map_body.inverse()
            * drive.state_at(c.query_stamp).t_map_body;
        let got = iso2_from_iso3(&c.t_match_query);
        let error = (truth.translation.vector - got.translation.vector).norm();
        assert!(
            error <= 2.0,
            "closure {} -> {}: {error:.2} m from the truth",
            c.query_id,
            c.match_id
        );
    }
    assert!(
        !closures(&late).is_empty(),
        "no closure with the trimmed search"
    );
}
