//! `dc_loc run`: the pipeline over any recorded source (a rosbag2, ROS 1 or foxglove MCAP bag, a
//! nuScenes or View-of-Delft directory), loop closures to a JSON-lines file.
//!
//! One loop for every source: each [`Segment`] of the data through a fresh [`Pipeline`]
//! ([`run_inputs`]), one progress bar, one closure writer. The run is deterministic: the same data and
//! parameters give a byte-identical output file.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;

use super::params::node_settings;
use super::source::{Dataset, Segment, SourceArgs};
use super::{CliError, progress};
use crate::input::IssueReason;
use crate::io::tum::tum_line;
use crate::output::ClosureRecord;
use crate::params::node::{NodeSettings, describe};
use crate::pipeline::{Event, Pipeline};
use crate::runner::{RunItem, RunReport, run_inputs};

/// Arguments of `dc_loc run`.
#[derive(Debug, Clone, clap::Args)]
pub struct RunArgs {
    /// The data and its parameters.
    #[command(flatten)]
    pub source: SourceArgs,
    /// Foxglove MCAP: the frame whose `map -> <body frame>` transforms on `/tf` are the odometry.
    #[arg(long, default_value = "map")]
    pub map_frame: String,
    /// Output: one JSON object per loop closure and line.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Writes the radar odometry (`odometry.source: radar | radar_imu`) here as a TUM trajectory, one
    /// `stamp x y z qx qy qz qw` line a sample (s, m, quaternion of `t_odom_body`).
    #[arg(long, value_name = "FILE")]
    pub odometry_out: Option<PathBuf>,
    /// Node namespace (for `/<ns>/<node>:` sections of the params file).
    #[arg(long, default_value = "/")]
    pub namespace: String,
    /// Do not log the effective configuration (every parameter's value) at start.
    #[arg(long)]
    pub quiet_config: bool,
}

/// Runs `dc_loc run`.
pub fn main(args: &RunArgs) -> Result<(), CliError> {
    let data = Dataset::open(&args.source, &args.namespace, &args.map_frame)?;
    let src = &args.source;
    let node = node_settings(
        src.params.as_deref(),
        &args.namespace,
        &src.node_name,
        &src.overrides,
    )?;
    let segments = data.segments()?;
    let out_path = args.out.display().to_string();
    let file =
        File::create(&args.out).map_err(|e| CliError::Runtime(format!("--out {out_path}: {e}")))?;
    let mut out = BufWriter::new(file);
    let total = segments.iter().map(|s| s.radar_messages).sum();
    let bar = progress::bar(
        total,
        "{elapsed_precise} [{wide_bar}] {pos}/{len} radar messages, {msg} ({eta} left)",
    );
    let odometry = match &args.odometry_out {
        Some(p) => Some(BufWriter::new(File::create(p).map_err(|e| {
            CliError::Runtime(format!("--odometry-out {}: {e}", p.display()))
        })?)),
        None => None,
    };
    let mut sink = ClosureSink {
        out: &mut out,
        closures: 0,
        error: None,
        damaged: Vec::new(),
        odometry,
        odometry_samples: 0,
    };
    let mut reports = Vec::new();
    let mut radar_names = Vec::new();
    let mut described = None;
    for segment in segments {
        radar_names.push(segment.config.radar_names.clone());
        if !args.quiet_config {
            log_config(&segment, &node, &mut described);
        }
        reports.push(run_segment(segment, &node, &mut sink, &bar)?);
    }
    progress::clear(&bar);
    if let Some(f) = &mut sink.odometry
        && let Err(e) = f.flush()
    {
        sink.error.get_or_insert(e);
    }
    let odometry_samples = sink.odometry_samples;
    let (closures, error, damaged) = (sink.closures, sink.error, sink.damaged);
    if let Some(e) = error {
        return Err(CliError::Runtime(format!("--out {out_path}: {e}")));
    }
    out.flush()
        .map_err(|e| CliError::Runtime(format!("--out {out_path}: {e}")))?;
    println!("{}", data.describe());
    print_summary(&reports);
    print_doppler(&reports, &radar_names);
    print_radar_odometry(&reports);
    println!("closures {closures} -> {}", args.out.display());
    if let Some(p) = &args.odometry_out {
        println!("odometry samples {odometry_samples} -> {}", p.display());
    }
    if let Some(mb) = peak_memory_mb() {
        println!("peak memory: {mb} MB");
    }
    if !damaged.is_empty() {
        return Err(CliError::Runtime(format!(
            "the bag is damaged, closures up to the damage were written: {}",
            damaged.join("; ")
        )));
    }
    Ok(())
}

/// Where the closures go, and what went wrong on the way.
struct ClosureSink<'a> {
    out: &'a mut BufWriter<File>,
    closures: u64,
    error: Option<std::io::Error>,
    damaged: Vec<String>,
    /// The radar odometry's TUM trajectory, when asked for.
    odometry: Option<BufWriter<File>>,
    odometry_samples: u64,
}

/// Logs the effective configuration of `segment` (every parameter, as the node logs it at start), unless
/// it is the one logged last (`described`): the segments of a dataset mostly share one.
fn log_config(segment: &Segment<'_>, node: &NodeSettings, described: &mut Option<String>) {
    let text = describe(&segment.config, node);
    if described.as_ref() != Some(&text) {
        log::info!(
            "{}: effective configuration (--quiet-config hides it):\n{text}",
            segment.label
        );
        *described = Some(text);
    }
}

/// One segment through a fresh pipeline, its closures into `sink`.
fn run_segment(
    segment: Segment<'_>,
    node: &NodeSettings,
    sink: &mut ClosureSink<'_>,
    bar: &indicatif::ProgressBar,
) -> Result<RunReport, CliError> {
    let cfg = segment.config;
    let radars: Vec<String> = cfg
        .radar_list()
        .iter()
        .map(|(n, r)| format!("{n} on {}", r.topic))
        .collect();
    log::info!(
        "{}: radars {}; {}",
        segment.label,
        radars.join(", "),
        cfg.pose_input()
    );
    let body_frame = cfg.body_frame.clone();
    let mut pipeline = Pipeline::new(cfg).map_err(|e| CliError::Usage(e.to_string()))?;
    pipeline.set_input_limits(node.limits);
    pipeline.set_restart_after(node.restart_after);
    Ok(run_inputs(
        &mut pipeline,
        segment.inputs,
        |item| match item {
            RunItem::Input(crate::input::Input::Radar { .. } | crate::input::Input::Scan(_)) => {
                bar.inc(1)
            }
            RunItem::Input(_) => {}
            RunItem::Issue(issue) => {
                if matches!(issue.reason, IssueReason::Damaged(_)) {
                    sink.damaged.push(issue.reason.to_string());
                }
            }
            RunItem::Event(Event::Closure(c)) => {
                sink.closures += 1;
                bar.set_message(format!("{} closures", sink.closures));
                if sink.error.is_none() {
                    let line = ClosureRecord::new(c, &body_frame).to_json_line();
                    if let Err(e) = writeln!(sink.out, "{line}") {
                        sink.error = Some(e);
                    }
                }
            }
            RunItem::Event(Event::Odometry(o)) => {
                sink.odometry_samples += 1;
                if let Some(f) = &mut sink.odometry
                    && let Err(e) = writeln!(f, "{}", tum_line(o.stamp, &o.t_odom_body))
                {
                    sink.error.get_or_insert(e);
                }
            }
            RunItem::Event(_) => {}
        },
    ))
}

fn counts<K: std::fmt::Display>(m: &BTreeMap<K, u64>) -> String {
    if m.is_empty() {
        return "none".into();
    }
    m.iter()
        .map(|(k, v)| format!("{k} {v}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The counts of every segment's run, summed.
fn print_summary(reports: &[RunReport]) {
    let sum = |f: &dyn Fn(&RunReport) -> u64| reports.iter().map(f).sum::<u64>();
    let mut issues: BTreeMap<&str, u64> = BTreeMap::new();
    let mut dropped: BTreeMap<&str, u64> = BTreeMap::new();
    let mut rejected: BTreeMap<&str, u64> = BTreeMap::new();
    for r in reports {
        for (k, v) in &r.issues {
            *issues.entry(k).or_default() += v;
        }
        for (k, v) in &r.stats.dropped {
            *dropped.entry(k.name()).or_default() += v;
        }
        for (k, v) in &r.stats.rejected {
            *rejected.entry(k.name()).or_default() += v;
        }
    }
    println!(
        "inputs: {} radar clouds, {} odometry; skipped messages: {}",
        sum(&|r| r.radar_inputs),
        sum(&|r| r.odometry_inputs),
        counts(&issues)
    );
    println!(
        "scans {}, detections kept {} / moving {} / invalid {} / outside the height band {}, doppler fit failures {}",
        sum(&|r| r.stats.scans),
        sum(&|r| r.stats.detections_kept),
        sum(&|r| r.stats.detections_dynamic),
        sum(&|r| r.stats.detections_invalid),
        sum(&|r| r.stats.detections_out_of_band),
        sum(&|r| r.stats.doppler_fit_failures)
    );
    println!("dropped inputs: {}", counts(&dropped));
    println!(
        "keyframes {}, registrations {}, rejected: {}",
        sum(&|r| r.stats.keyframes),
        sum(&|r| r.stats.registrations),
        counts(&rejected)
    );
    let resets = sum(&|r| r.stats.time_resets);
    if resets > 0 {
        println!("time resets: {resets}");
    }
    if let Some(k) = reports.iter().rev().find_map(|r| r.stats.speed_scale) {
        println!("odometry distances times {k:.4} by the radars' Doppler (newest keyframe)");
    }
    let refused = sum(&|r| r.stats.speed_scale_refused);
    if refused > 0 {
        println!(
            "keyframes whose Doppler and odometry distances disagreed beyond submap.speed_scale_bound: {refused}"
        );
    }
}

/// The radars' Doppler against the odometry, per segment: the scans that disagreed, and each radar
/// flagged as misconfigured with the stamp of the scan that showed it and the likely cause.
/// The radar odometry's counters of each segment that made its odometry from the radars.
fn print_radar_odometry(reports: &[RunReport]) {
    for s in reports
        .iter()
        .filter_map(|r| r.stats.radar_odometry.as_ref())
    {
        let refused: BTreeMap<&str, u64> = s.scans_refused.clone();
        let coasted: BTreeMap<&str, u64> = s.coasted.clone();
        println!(
            "radar odometry: {} steps, coasted {}; scans fitted {}, refused {}; late scans {}; odometry topic samples ignored {}",
            s.steps,
            counts(&coasted),
            s.scans_fitted,
            counts(&refused),
            s.late_scans,
            s.topic_ignored
        );
        if let Some((bias, sigma)) = s.gyro_bias {
            let g = s.gyro;
            println!(
                "gyro: {} samples, {} saturated, {} out of order, {} not finite; {} steps without gyro coverage; bias {:.5} +- {:.5} rad/s ({} updates, {} refused){}",
                g.samples,
                g.saturated,
                g.out_of_order,
                g.non_finite,
                s.gyro_gaps,
                bias,
                sigma,
                s.bias_updates.0,
                s.bias_updates.1,
                s.gyro_wrong_frame
                    .map_or(String::new(), |k| format!("; wrong frame (slope {k:.2})"))
            );
        }
    }
}

fn print_doppler(reports: &[RunReport], radar_names: &[Vec<String>]) {
    for (r, names) in reports.iter().zip(radar_names) {
        let name = |i: &usize| names.get(*i).map_or("?", String::as_str);
        let disagreed: BTreeMap<&str, u64> = r
            .stats
            .doppler_disagreements
            .iter()
            .map(|(i, n)| (name(i), *n))
            .collect();
        if r.stats.doppler_warnings.is_empty() {
            if !disagreed.is_empty() {
                println!(
                    "doppler: no radar flagged; scans disagreeing with the odometry: {}",
                    counts(&disagreed)
                );
            }
            continue;
        }
        for (i, (stamp, cause)) in &r.stats.doppler_warnings {
            let into = r.first_stamp.map_or(0.0, |s| stamp.secs_since(s));
            println!(
                "doppler: radar `{}` flagged at {:.3} s ({into:.1} s into the drive; {} scans \
                 disagreed in all): {cause}",
                name(i),
                stamp.as_secs_f64(),
                disagreed.get(name(i)).copied().unwrap_or(0),
            );
        }
    }
}

/// Peak resident memory of this process (`VmHWM` of /proc/self/status), MB; `None` without /proc.
fn peak_memory_mb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let kb: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))?
        .trim()
        .strip_suffix("kB")?
        .trim()
        .parse()
        .ok()?;
    Some(kb.div_ceil(1024))
}
