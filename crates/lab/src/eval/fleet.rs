//! Inter-robot loop closures measured on a simulated fleet ([`crate::sim::fleet`]), as the robots' nodes
//! find them over DDS: each robot has its own pipeline and keyframe map, and every keyframe a robot
//! makes goes through the wire format ([`dc_loc_core::fleet::wire`]) into every other robot's pipeline at once
//! ([`Input::Keyframe`]) half a second later. The robots drive at the same time (their inputs
//! interleaved by the time since each one's start), except the last of three or more, which starts once
//! the others have finished and takes their keyframes first, as a late joiner gets them from the
//! topic's history.
//!
//! Judged as [`super::judge`] judges laps, with robots for laps: an opportunity is a keyframe of a
//! robot with an earlier robot's keyframe within 5 m in the same direction (or across the street in the
//! other direction); a closure is correct within 2 m of the ground truth, both robots' poses in the
//! world's one map frame. Keyframes are named across the fleet by robot and id ([`fleet_key`]).

use std::collections::BTreeMap;

use super::judge::{
    Collected, RevisitReport, judge, keyframe_truth, measured_drift, reverse_radius,
};
use crate::sim::inputs::{ScanEncoding, SimInputs};
use crate::sim::{SimConfig, SimDrive, simulate};
use dc_loc_core::fleet::wire::{self, DEFAULT_WIRE_POINTS};
use dc_loc_core::input::Input;
use dc_loc_core::math::Stamp;
use dc_loc_core::pipeline::{Config, Event, Pipeline, PipelineStats};
use dc_loc_core::validate::ConfigError;

/// One id for keyframe `id` of robot `robot` across the fleet.
pub fn fleet_key(robot: i32, id: u64) -> u64 {
    robot as u64 * 1_000_000 + id
}

/// One robot of the fleet: its drive's inputs, its pipeline and what it reported.
struct Robot<'a> {
    id: i32,
    inputs: std::iter::Peekable<SimInputs<'a>>,
    start: Option<Stamp>,
    pipeline: Pipeline,
    seen: Collected,
}

impl Robot<'_> {
    /// Seconds since this robot's first input of its next input (`None`: its drive is over).
    fn clock(&mut self) -> Option<f64> {
        let stamp = match self.inputs.peek()? {
            Ok(input) => input.stamp(),
            Err(_) => return Some(0.0),
        };
        let start = *self.start.get_or_insert(stamp);
        Some(stamp.as_secs_f64() - start.as_secs_f64())
    }

    /// Keeps `events`, the closures named by fleet keys; the keyframes made, as the others receive
    /// them.
    fn take(&mut self, events: Vec<Event>) -> Vec<Input> {
        let mut shared = Vec::new();
        for e in &events {
            if let Event::Keyframe { record, fleet, .. } = e {
                let msg = wire::encode(self.id, record, fleet, DEFAULT_WIRE_POINTS, "base_link");
                shared.push(Input::Keyframe(Box::new(msg)));
            }
        }
        let mut mine = Collected::default();
        mine.take(events);
        for (id, stamp) in mine.keyframes {
            self.seen.keyframes.push((fleet_key(self.id, id), stamp));
        }
        for mut c in mine.closures {
            let (robot, id) = c.match_key();
            c.query_id = fleet_key(self.id, c.query_id);
            c.match_id = fleet_key(robot, id);
            self.seen.closures.push(c);
        }
        self.seen.rejections.extend(
            mine.rejections
                .into_iter()
                .map(|(q, why)| (fleet_key(self.id, q), why)),
        );
        shared
    }
}

/// Drives the fleet `configs` (robot `k` = `configs[k]`), each robot through its own pipeline
/// configured from robot 0's drive and `tweak`, sharing keyframes as described in the module
/// documentation, and judges the closures between robots.
pub fn evaluate_fleet(
    configs: &[SimConfig],
    tweak: impl FnOnce(&mut Config),
) -> Result<RevisitReport, ConfigError> {
    let Some(first) = configs.first() else {
        return Err(ConfigError::new("fleet", "no robot"));
    };
    let mut cfg = first.to_config();
    tweak(&mut cfg);
    cfg.r#loop.enabled = true;
    let drives = configs
        .iter()
        .map(simulate)
        .collect::<Result<Vec<SimDrive>, _>>()?;
    let mut robots = Vec::with_capacity(drives.len());
    for (k, drive) in drives.iter().enumerate() {
        let mut pipeline = Pipeline::new(cfg.clone())?;
        pipeline.set_robot(k as i32);
        robots.push(Robot {
            id: k as i32,
            inputs: SimInputs::new(drive, ScanEncoding::Detections).peekable(),
            start: None,
            pipeline,
            seen: Collected::default(),
        });
    }
    let late = if robots.len() >= 3 {
        robots.len() - 1
    } else {
        robots.len()
    };
    let n = robots.len();
    drive_together(&mut robots, 0..late);
    drive_together(&mut robots, late..n);
    let mut seen = Collected::default();
    let mut truth = BTreeMap::new();
    let mut stats = PipelineStats::default();
    for (r, drive) in robots.iter_mut().zip(&drives) {
        let events = r.pipeline.finish();
        r.take(events);
        let robot = r.id as usize;
        truth.append(&mut keyframe_truth(drive, &r.seen.keyframes, |_| robot));
        stats.keyframes += r.pipeline.stats().keyframes;
        for (reason, n) in &r.pipeline.stats().rejected {
            *stats.rejected.entry(*reason).or_default() += n;
        }
        seen.keyframes.append(&mut r.seen.keyframes);
        seen.closures.append(&mut r.seen.closures);
        seen.rejections.append(&mut r.seen.rejections);
    }
    let drift = drives.iter().map(measured_drift).fold(0.0, f64::max);
    let radius = drives.iter().map(reverse_radius).fold(0.0, f64::max);
    Ok(judge(truth, radius, drift, &seen, &stats))
}

/// How long a keyframe takes from the robot that made it to the others, s of drive time: the DDS
/// transit and the receiving node's queue. Keyframes made meanwhile by two robots at one place are
/// registered on arrival ([`dc_loc_core::loop_closure::LoopCloser::search_arrival`]).
const DELIVERY_DELAY: f64 = 0.5;

/// A keyframe on its way: when it arrives (s since the robots' start), from which robot, as an input.
type InFlight = (f64, usize, Input);

/// Feeds the robots `active` their inputs in the order of the time since each one's start, until their
/// drives are over; each keyframe a robot makes reaches every other robot of the fleet
/// [`DELIVERY_DELAY`] later, the ones that have not started yet included (they receive it before their
/// first input).
fn drive_together(robots: &mut [Robot<'_>], active: std::ops::Range<usize>) {
    let mut in_flight: Vec<InFlight> = Vec::new();
    loop {
        let next = active
            .clone()
            .filter_map(|i| robots[i].clock().map(|t| (t, i)))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        let now = next.map_or(f64::INFINITY, |(t, _)| t);
        let (due, later): (Vec<_>, Vec<_>) = in_flight.into_iter().partition(|k| k.0 <= now);
        in_flight = later;
        for (_, from, input) in due {
            broadcast(robots, from, &input);
        }
        let Some((_, i)) = next else { return };
        let Some(Ok(input)) = robots[i].inputs.next() else {
            continue;
        };
        let events = robots[i].pipeline.push(&input);
        for k in robots[i].take(events) {
            in_flight.push((now + DELIVERY_DELAY, i, k));
        }
    }
}

/// Pushes a keyframe robot `from` made into every other robot's pipeline.
fn broadcast(robots: &mut [Robot<'_>], from: usize, input: &Input) {
    for j in (0..robots.len()).filter(|&j| j != from) {
        let events = robots[j].pipeline.push(input);
        robots[j].take(events);
    }
}
