//! The node's `/diagnostics` (diagnostic_msgs/DiagnosticArray): what was received and at what rate,
//! what was not used and why, and how processing goes (queues, counts, latencies).

use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::Ordering;
use std::time::Instant;

use super::convert::{DiagnosticArray, DiagnosticStatus, KeyValue};
use super::map_store::SaveStatus;
use super::shared::{Shared, lock};
use dc_loc_core::msgs::builtin_interfaces::Time;
use dc_loc_core::msgs::std_msgs::Header;
use dc_loc_core::odometry::RadarOdometryStats;
use dc_loc_core::pipeline::PipelineStats;

/// Rolling latency samples, seconds.
#[derive(Default)]
pub struct Latencies {
    samples: VecDeque<f64>,
}

impl Latencies {
    const KEEP: usize = 2000;

    /// One more sample, s.
    pub fn push(&mut self, s: f64) {
        if self.samples.len() == Self::KEEP {
            self.samples.pop_front();
        }
        self.samples.push_back(s);
    }

    /// (p50, p99, max) in ms, or None.
    pub fn summary(&self) -> Option<(f64, f64, f64)> {
        if self.samples.is_empty() {
            return None;
        }
        let mut v: Vec<f64> = self.samples.iter().copied().collect();
        v.sort_by(f64::total_cmp);
        let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize] * 1e3;
        Some((q(0.5), q(0.99), q(1.0)))
    }
}

/// What the worker measures: latencies (arrival to processed for every input, arrival to published
/// closure, keyframe processing time) and the closures published.
#[derive(Default)]
pub struct Measures {
    /// Arrival to processed, every input.
    pub input_latency: Latencies,
    /// Arrival to published closure.
    pub closure_latency: Latencies,
    /// Processing of an input that made a keyframe.
    pub keyframe_time: Latencies,
    /// Keyframes whose processing ended after `node.keyframe_budget` all the same.
    pub late_keyframes: u64,
    /// Closures published.
    pub closures_published: u64,
    /// Radar odometry samples published on `~/odometry` (`odometry.source: radar | radar_imu`).
    pub odometry_published: u64,
    /// Points in the newest `~/markers` message (keyframes plus two per closure).
    pub markers_points: usize,
}

/// What a diagnostics message reports besides the shared counters.
pub struct Report<'a> {
    /// The message stamp.
    pub now: Time,
    /// The pipeline's counters.
    pub stats: &'a PipelineStats,
    /// Keyframes in the map (loaded and new).
    pub map_keyframes: usize,
    /// `node.queue_size`.
    pub queue_size: usize,
    /// The worker's measures.
    pub measures: &'a Measures,
    /// The newest map save's result (`None` without a map file).
    pub map_save: Option<SaveStatus>,
    /// The radars' names, by index.
    pub radar_names: &'a [String],
}

/// Builds the diagnostics messages; keeps what the rates are taken against.
pub struct Diagnostics {
    hardware_id: String,
    last: Instant,
    last_received: BTreeMap<String, u64>,
}

fn kv(key: &str, value: String) -> KeyValue {
    KeyValue {
        key: key.to_string(),
        value,
    }
}

impl Diagnostics {
    /// Diagnostics of the node named `hardware_id`.
    pub fn new(hardware_id: String) -> Self {
        Diagnostics {
            hardware_id,
            last: Instant::now(),
            last_received: BTreeMap::new(),
        }
    }

    /// Seconds since the last message.
    pub fn since_last(&self) -> f64 {
        self.last.elapsed().as_secs_f64()
    }

    /// The message now: input, dropped and processing status.
    pub fn message(&mut self, shared: &Shared, r: &Report<'_>) -> DiagnosticArray {
        let dt = self.last.elapsed().as_secs_f64().max(1e-6);
        self.last = Instant::now();
        let input = self.input(shared, dt);
        let (dropped, total_dropped) = dropped(shared, r.stats);
        let status =
            |name: &str, level: u8, message: String, values: Vec<KeyValue>| DiagnosticStatus {
                level,
                name: format!("dc_loc: {name}"),
                message,
                hardware_id: self.hardware_id.clone(),
                values,
            };
        let misconfigured = !r.stats.doppler_warnings.is_empty();
        let drop_level = if total_dropped > 0 {
            DiagnosticStatus::WARN
        } else {
            DiagnosticStatus::OK
        };
        let closures = r.measures.closures_published;
        let mut statuses = vec![
            status(
                "input",
                DiagnosticStatus::OK,
                "messages received".into(),
                input,
            ),
            status(
                "dropped",
                drop_level,
                format!("{total_dropped} messages not used"),
                dropped,
            ),
            status(
                "processing",
                if misconfigured {
                    DiagnosticStatus::WARN
                } else {
                    DiagnosticStatus::OK
                },
                format!("{} keyframes, {closures} closures", r.stats.keyframes),
                processing(shared, r),
            ),
        ];
        if let Some(save) = &r.map_save {
            let (level, message) = match &save.last_error {
                None => (DiagnosticStatus::OK, "last save succeeded".to_string()),
                Some(e) => (DiagnosticStatus::ERROR, format!("last save failed: {e}")),
            };
            let values = vec![
                kv("map.saves", save.saves.to_string()),
                kv("map.last_save_ok", (save.last_error.is_none()).to_string()),
                kv(
                    "map.last_save_error",
                    save.last_error.clone().unwrap_or_default(),
                ),
            ];
            statuses.push(status("map", level, message, values));
        }
        DiagnosticArray {
            header: Header {
                stamp: r.now,
                frame_id: String::new(),
            },
            status: statuses,
        }
    }

    /// Messages received per input, their rate since the last message, matched publishers.
    fn input(&mut self, shared: &Shared, dt: f64) -> Vec<KeyValue> {
        let received = lock(&shared.received).clone();
        let mut input = Vec::new();
        for (name, n) in &received {
            let before = self.last_received.get(name).copied().unwrap_or(0);
            input.push(kv(
                &format!("{name}.rate_hz"),
                format!("{:.2}", (n - before) as f64 / dt),
            ));
            input.push(kv(&format!("{name}.received"), n.to_string()));
        }
        self.last_received = received;
        for (name, n) in lock(&shared.publishers).iter() {
            input.push(kv(&format!("{name}.publishers"), n.to_string()));
        }
        input
    }
}

/// Messages not used, by reason (the reception's and the pipeline's), and their total.
fn dropped(shared: &Shared, stats: &PipelineStats) -> (Vec<KeyValue>, u64) {
    let mut dropped: BTreeMap<String, u64> = lock(&shared.dropped).clone();
    for (r, n) in &stats.dropped {
        *dropped.entry(r.name().to_string()).or_default() += n;
    }
    let total: u64 = dropped.values().sum();
    let mut values: Vec<KeyValue> = dropped.iter().map(|(k, v)| kv(k, v.to_string())).collect();
    values.push(kv("nan_points", stats.detections_invalid.to_string()));
    values.push(kv(
        "points_outside_height_band",
        stats.detections_out_of_band.to_string(),
    ));
    values.push(kv("empty_clouds", stats.empty_scans.to_string()));
    values.push(kv("time_resets", stats.time_resets.to_string()));
    values.push(kv("odometry_resets", stats.odometry_resets.to_string()));
    (values, total)
}

/// The radar odometry's counters (`odometry.source: radar | radar_imu`): steps, the steps that
/// coasted and the scans refused by reason, and with a gyro its samples, gaps and bias.
fn radar_odometry(o: &RadarOdometryStats) -> Vec<KeyValue> {
    let mut values = vec![
        kv("radar_odometry.steps", o.steps.to_string()),
        kv("radar_odometry.scans_fitted", o.scans_fitted.to_string()),
        kv("radar_odometry.late_scans", o.late_scans.to_string()),
        kv("radar_odometry.topic_ignored", o.topic_ignored.to_string()),
    ];
    for (reason, n) in &o.coasted {
        values.push(kv(
            &format!("radar_odometry.coasted.{reason}"),
            n.to_string(),
        ));
    }
    for (reason, n) in &o.scans_refused {
        values.push(kv(
            &format!("radar_odometry.refused.{reason}"),
            n.to_string(),
        ));
    }
    let Some((bias, sigma)) = o.gyro_bias else {
        return values;
    };
    let g = o.gyro;
    values.extend([
        kv("gyro.samples", g.samples.to_string()),
        kv("gyro.saturated", g.saturated.to_string()),
        kv("gyro.out_of_order", g.out_of_order.to_string()),
        kv("gyro.non_finite", g.non_finite.to_string()),
        kv("gyro.steps_uncovered", o.gyro_gaps.to_string()),
        kv("gyro.bias", format!("{bias:.6}")),
        kv("gyro.bias_sigma", format!("{sigma:.6}")),
        kv("gyro.bias_updates", o.bias_updates.0.to_string()),
        kv("gyro.bias_refused", o.bias_updates.1.to_string()),
    ]);
    if let Some(slope) = o.gyro_wrong_frame {
        values.push(kv("gyro.wrong_frame_slope", format!("{slope:.3}")));
    }
    values
}

/// Queues, counts, rejections by reason and latencies.
fn processing(shared: &Shared, r: &Report<'_>) -> Vec<KeyValue> {
    let stats = r.stats;
    let load = |a: &std::sync::atomic::AtomicUsize| a.load(Ordering::SeqCst).to_string();
    let mut proc = vec![
        kv("queue_depth", load(&shared.queued)),
        kv("queue_depth_max", load(&shared.queued_max)),
        kv("queue_size", r.queue_size.to_string()),
        kv("held_for_order", load(&shared.held)),
        kv("pending_scans", stats.pending_scans.to_string()),
        kv("scans", stats.scans.to_string()),
        kv("keyframes", stats.keyframes.to_string()),
        kv("map_keyframes", r.map_keyframes.to_string()),
        kv("map_full", stats.map_full.to_string()),
        kv("registrations", stats.registrations.to_string()),
        kv("closures", r.measures.closures_published.to_string()),
        kv(
            "odometry_published",
            r.measures.odometry_published.to_string(),
        ),
        kv("markers_points", r.measures.markers_points.to_string()),
        kv(
            "odometry_speed_scale",
            stats
                .speed_scale
                .map_or_else(|| "-".to_string(), |k| format!("{k:.4}")),
        ),
        kv(
            "odometry_speed_scale_refused",
            stats.speed_scale_refused.to_string(),
        ),
    ];
    for (reason, n) in &stats.rejected {
        proc.push(kv(&format!("rejected.{}", reason.name()), n.to_string()));
    }
    // Other robots' keyframes (`node.fleet`), per robot: received, added, already held, refused, and
    // dropped at reception beyond `node.fleet_rate`.
    let flood = lock(&shared.fleet_flood).clone();
    let robots: std::collections::BTreeSet<i32> =
        stats.robots.keys().chain(flood.keys()).copied().collect();
    for robot in robots {
        let c = stats.robots.get(&robot).copied().unwrap_or_default();
        let f = flood.get(&robot).copied().unwrap_or(0);
        proc.push(kv(
            &format!("fleet.robot_{robot}"),
            format!(
                "received {}, added {}, duplicates {}, refused {}, over rate {f}",
                c.received, c.added, c.duplicates, c.refused
            ),
        ));
    }
    // The radars' Doppler against the odometry: scans that disagreed, and the likely cause once a
    // radar disagrees persistently.
    for (i, name) in r.radar_names.iter().enumerate() {
        let n = stats.doppler_disagreements.get(&i).copied().unwrap_or(0);
        proc.push(kv(
            &format!("{name}.doppler_odometry_disagree"),
            n.to_string(),
        ));
        if let Some((_, cause)) = stats.doppler_warnings.get(&i) {
            proc.push(kv(&format!("{name}.misconfigured"), cause.clone()));
        }
    }
    if let Some(o) = &stats.radar_odometry {
        proc.extend(radar_odometry(o));
    }
    let m = r.measures;
    // The search left out to keep `node.keyframe_budget`, and keyframes late all the same.
    let t = &stats.trimmed;
    if t.any() || m.late_keyframes > 0 {
        proc.push(kv("budget.backfill_put_off", t.backfill.to_string()));
        proc.push(kv("budget.rounds_skipped", t.rounds.to_string()));
        proc.push(kv("budget.candidates_skipped", t.candidates.to_string()));
        proc.push(kv("budget.late_keyframes", m.late_keyframes.to_string()));
    }
    for (name, l) in [
        ("latency_ms", &m.input_latency),
        ("closure_latency_ms", &m.closure_latency),
        ("keyframe_processing_ms", &m.keyframe_time),
    ] {
        if let Some((p50, p99, max)) = l.summary() {
            proc.push(kv(&format!("{name}.p50"), format!("{p50:.3}")));
            proc.push(kv(&format!("{name}.p99"), format!("{p99:.3}")));
            proc.push(kv(&format!("{name}.max"), format!("{max:.3}")));
        }
    }
    proc
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The radar odometry's counters appear under `radar_odometry.*`, each coasting and refusal
    /// reason with its count, and the gyro's under `gyro.*` only when there is a gyro.
    #[test]
    fn radar_odometry_counters_are_reported_by_reason() {
        let mut o = RadarOdometryStats {
            steps: 12,
            scans_fitted: 20,
            ..Default::default()
        };
        o.coasted.insert("no_radar", 2);
        o.scans_refused.insert("dominated_by_movers", 3);
        let text = |values: Vec<KeyValue>| -> Vec<String> {
            values
                .iter()
                .map(|v| format!("{}={}", v.key, v.value))
                .collect()
        };
        let got = text(radar_odometry(&o));
        for want in [
            "radar_odometry.steps=12",
            "radar_odometry.scans_fitted=20",
            "radar_odometry.coasted.no_radar=2",
            "radar_odometry.refused.dominated_by_movers=3",
        ] {
            assert!(got.contains(&want.to_string()), "{want} not in {got:?}");
        }
        assert!(!got.iter().any(|k| k.starts_with("gyro.")), "{got:?}");
        o.gyro_bias = Some((0.007, 0.001));
        o.gyro.saturated = 4;
        let got = text(radar_odometry(&o));
        for want in [
            "gyro.saturated=4",
            "gyro.bias=0.007000",
            "gyro.bias_sigma=0.001000",
        ] {
            assert!(got.contains(&want.to_string()), "{want} not in {got:?}");
        }
    }
}
