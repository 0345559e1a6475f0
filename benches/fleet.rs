//! Fleet benchmark (a bench binary, not a timed test): bytes of a keyframe on the wire, and the CPU a
//! node spends on another robot's keyframe, beside what it spends on one of its own.
//!
//! Run: `cargo bench --bench fleet`. Two robots drive the simulated city (five radars, 1 % drift) the
//! same way, a third of the loop apart. Robot 1 receives the first half of robot 0's keyframes, then
//! drives its lap through its pipeline, timing each input that makes a keyframe (its closures to robot 0
//! give it an alignment to robot 0's session); then the other half of robot 0's keyframes are encoded,
//! decoded and pushed into robot 1's pipeline: the worst case, where each one is registered against
//! robot 1's keyframes of the same place on arrival (robot 1's are newer and robot 0's node had not
//! heard of them). Last, all of them again: a flood of duplicates (a history delivered twice). Times
//! are per keyframe (`RAYON_NUM_THREADS=1` for a strict single core).

use std::time::Instant;

use dc_loc::eval::revisits::RevisitScenario;
use dc_loc::fleet::FleetState;
use dc_loc::fleet::wire::{self, DEFAULT_WIRE_POINTS};
use dc_loc::input::Input;
use dc_loc::keyframe_db::KeyframeRecord;
use dc_loc::msgs::dc_loc::Keyframe;
use dc_loc::pipeline::{Event, Pipeline};
use dc_loc::sim::inputs::{ScanEncoding, SimInputs};
use dc_loc::sim::{NoiseModel, RadarPreset, simulate};

fn summary(name: &str, mut ms: Vec<f64>) {
    ms.sort_by(f64::total_cmp);
    let q = |p: f64| ms[((ms.len() - 1) as f64 * p) as usize];
    let mean = ms.iter().sum::<f64>() / ms.len() as f64;
    println!(
        "{name:<40} n {:>4}  mean {mean:>7.2} ms  p50 {:>7.2}  p99 {:>7.2}  max {:>7.2}",
        ms.len(),
        q(0.5),
        q(0.99),
        ms[ms.len() - 1]
    );
}

/// A keyframe a robot made, and what its node knew of the fleet then.
type Made = (KeyframeRecord, FleetState);

/// Drives `drive` through a pipeline of robot `robot` that first receives the keyframes `history`;
/// its keyframes and the time of each input that made one, ms.
fn drive(
    robot: i32,
    cfg: &dc_loc::sim::SimConfig,
    history: &[Keyframe],
) -> (Pipeline, Vec<Made>, Vec<f64>) {
    let d = simulate(cfg).expect("simulates");
    let mut p = Pipeline::new(d.to_config()).expect("config");
    p.set_robot(robot);
    for m in history {
        p.push(&Input::Keyframe(Box::new(m.clone())));
    }
    let (mut kfs, mut ms) = (Vec::new(), Vec::new());
    for input in SimInputs::new(&d, ScanEncoding::Detections).flatten() {
        let t0 = Instant::now();
        let events = p.push(&input);
        let dt = t0.elapsed().as_secs_f64() * 1e3;
        for e in events {
            if let Event::Keyframe { record, fleet, .. } = e {
                kfs.push((record.as_ref().clone(), fleet));
                ms.push(dt);
            }
        }
    }
    (p, kfs, ms)
}

fn main() {
    let base =
        RevisitScenario::new(RadarPreset::Nuscenes, NoiseModel::Gaussian, 0.01, false).sim_config();
    let mut robots = dc_loc::sim::fleet::fleet(&base, 2).expect("fleet");
    robots[1].laps[0].reverse = false;
    let (_, theirs, _) = drive(0, &robots[0], &[]);
    let all: Vec<_> = theirs
        .iter()
        .map(|(r, fleet)| wire::encode(0, r, fleet, DEFAULT_WIRE_POINTS, "base_link"))
        .collect();
    let (history, msgs) = all.split_at(all.len() / 2);
    let (mut p, _, own_ms) = drive(1, &robots[1], history);
    let bytes: Vec<f64> = all.iter().map(|m| wire::wire_bytes(m) as f64).collect();
    let stored: Vec<f64> = theirs.iter().map(|(r, _)| r.heap_bytes() as f64).collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
    println!(
        "wire bytes per keyframe: mean {:.0}, max {:.0} (stored in the map: mean {:.0}); {} keyframes",
        mean(&bytes),
        max(&bytes),
        mean(&stored),
        all.len()
    );
    let registrations = p.stats().registrations;
    let mut received = Vec::new();
    let closures = p.stats().closures;
    for m in msgs {
        let t0 = Instant::now();
        p.push(&Input::Keyframe(Box::new(m.clone())));
        received.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    let arrival_registrations = p.stats().registrations - registrations;
    let arrival_closures = p.stats().closures - closures;
    let mut duplicates = Vec::new();
    for m in &all {
        let t0 = Instant::now();
        p.push(&Input::Keyframe(Box::new(m.clone())));
        duplicates.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    summary("own keyframe (the input that made it)", own_ms.clone());
    summary("another robot's keyframe, on arrival", received.clone());
    summary("the same again (duplicates)", duplicates);
    println!(
        "on arrival: {arrival_registrations} registrations and {arrival_closures} closures for {} keyframes ({closures} closures while driving)",
        msgs.len()
    );
    println!(
        "ratio, mean time of a received keyframe to an own one: {:.2}",
        mean(&received) / mean(&own_ms)
    );
}
