//! `dc_loc run`: the pipeline over a rosbag2 bag, loop closures to a JSON-lines file.
//!
//! Parameters: the node's section of the params file (`<node-name>:` or a wildcard, under
//! `ros__parameters:`), then each `-p name:=value`, onto the defaults ([`crate::params::apply`]).
//! The run is deterministic: the same bag and parameters give a byte-identical output file.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::{CliError, set_progress};
use crate::bag::BagReader;
use crate::config::Config;
use crate::params::{ParamSet, apply, flatten_config};
use crate::pipeline::{Event, Pipeline};
use crate::runner::{BagInputs, ClosureRecord, RunItem, RunReport, RunnerError, run_bag};

/// Arguments of `dc_loc run`.
#[derive(Debug, Clone, clap::Args)]
pub struct RunArgs {
    /// rosbag2 bag: directory or single .mcap file.
    #[arg(
        long,
        value_name = "BAG",
        required_unless_present_any = ["vod", "nuscenes"],
        conflicts_with_all = ["vod", "nuscenes"]
    )]
    pub bag: Option<PathBuf>,
    /// ROS 2 params YAML (e.g. the `dc_loc.yaml` that `dc_loc sim` writes into its bag directory).
    /// Required with `--bag`; optional with `--vod`.
    #[arg(long, value_name = "FILE")]
    pub params: Option<PathBuf>,
    /// View-of-Delft radar directory (`velodyne/`, `pose/`, `calib/`, or a folder holding
    /// `radar/training/`) instead of a bag.
    #[arg(long, value_name = "DIR")]
    pub vod: Option<PathBuf>,
    /// VoD frame rate, Hz (the `.bin` files carry no time).
    #[arg(long, default_value_t = 10.0)]
    pub frame_rate: f64,
    /// nuScenes data root instead of a bag: the scenes of each location run through one pipeline, in
    /// time order (odometry from the ego poses).
    #[arg(long, value_name = "DIR", conflicts_with = "vod")]
    pub nuscenes: Option<PathBuf>,
    /// nuScenes version folder.
    #[arg(long, default_value = "v1.0-mini")]
    pub version: String,
    /// nuScenes: only these scenes (comma-separated names).
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<String>,
    /// nuScenes radar filter: kept `invalid_state` values (comma-separated, or `all`).
    #[arg(long, default_value = "0")]
    pub radar_invalid_states: String,
    /// nuScenes radar filter: kept `dyn_prop` values (comma-separated, or `all`).
    #[arg(long, default_value = "0,1,2,3,4,5,6")]
    pub radar_dynprop_states: String,
    /// nuScenes radar filter: kept `ambig_state` values (comma-separated, or `all`).
    #[arg(long, default_value = "3")]
    pub radar_ambig_states: String,
    /// Foxglove MCAP: the frame whose `map -> <body frame>` transforms on `/tf` are the odometry.
    #[arg(long, default_value = "map")]
    pub map_frame: String,
    /// Output: one JSON object per loop closure and line.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Node name whose section of the params file applies.
    #[arg(long, default_value = "dc_loc")]
    pub node_name: String,
    /// Node namespace (for `/<ns>/<node>:` sections).
    #[arg(long, default_value = "/")]
    pub namespace: String,
    /// Parameter override, applied after the file (repeatable).
    #[arg(short = 'p', long = "param", value_name = "NAME:=VALUE")]
    pub overrides: Vec<String>,
}

/// The configuration from the params file and the overrides.
pub fn load_config(args: &RunArgs) -> Result<Config, CliError> {
    let Some(params) = &args.params else {
        return Err(CliError::Usage(
            "--bag needs --params (the params file of the bag's radars and topics)".into(),
        ));
    };
    load_params(params, &args.namespace, &args.node_name, &args.overrides)
}

/// The configuration from a params file (the section of node `/namespace/node_name`) and `-p`
/// overrides, validated.
pub fn load_params(
    params: &std::path::Path,
    namespace: &str,
    node_name: &str,
    overrides: &[String],
) -> Result<Config, CliError> {
    let file = params.display();
    let text = std::fs::read_to_string(params)
        .map_err(|e| CliError::Usage(format!("--params {file}: {e}")))?;
    let mut set = ParamSet::from_yaml(&text, namespace, node_name)
        .map_err(|e| CliError::Usage(format!("--params {file}: {e}")))?;
    if set.entries().is_empty() {
        log::warn!(
            "{file} has no parameters for node {node_name} (namespace {namespace}): running with the defaults"
        );
    }
    for o in overrides {
        set.set_override(o)
            .map_err(|e| CliError::Usage(format!("-p: {e}")))?;
    }
    apply(&set).map_err(|e| CliError::Usage(format!("parameters ({file} and -p): {e}")))
}

/// Runs `dc_loc run`.
pub fn main(args: &RunArgs) -> Result<(), CliError> {
    if args.vod.is_some() {
        return super::realdata::run_vod(args);
    }
    if args.nuscenes.is_some() {
        return super::realdata::run_nuscenes(args);
    }
    let Some(bag) = &args.bag else {
        return Err(CliError::Usage("--bag or --vod is required".into()));
    };
    let reader = BagReader::open(bag).map_err(|e| CliError::Runtime(e.to_string()))?;
    // A foxglove nuscenes2mcap file runs without a params file: its radar topics say the layout.
    let mut cfg = match (&args.params, super::realdata::nuscenes_mcap_config(&reader)) {
        (None, Some(template)) => {
            super::realdata::dataset_config(&template, None, &args.node_name, &args.overrides)?
        }
        _ => load_config(args)?,
    };
    super::realdata::apply_bag_extrinsics(&reader, &mut cfg)?;
    let radars: Vec<String> = cfg
        .radar_list()
        .iter()
        .map(|(n, r)| format!("{n} on {}", r.topic))
        .collect();
    log::info!(
        "radars: {}; odometry on {}",
        radars.join(", "),
        cfg.odometry.topic
    );
    for (name, value) in flatten_config(&cfg) {
        log::debug!("parameter {name} = {value}");
    }
    let body_frame = cfg.body_frame.clone();
    let radar_topics: Vec<String> = cfg
        .radar_list()
        .iter()
        .map(|(_, r)| r.topic.clone())
        .collect();
    let mut pipeline = Pipeline::new(cfg).map_err(|e| CliError::Usage(e.to_string()))?;

    let inputs: Box<dyn Iterator<Item = Result<crate::runner::Input, crate::runner::InputIssue>>>;
    let total;
    if radar_topics
        .iter()
        .any(|t| crate::bag::foxglove::is_foxglove_cloud(&reader, t))
    {
        let f = crate::bag::foxglove::FoxgloveInputs::new(
            &reader,
            &radar_topics,
            &args.map_frame,
            &body_frame,
        )
        .map_err(|e| CliError::Runtime(e.to_string()))?;
        total = f.total_messages();
        inputs = Box::new(f);
    } else {
        let b = BagInputs::new(&reader, pipeline.config(), None).map_err(|e| match e {
            RunnerError::Bag(e) => CliError::Runtime(e.to_string()),
            e => CliError::Usage(e.to_string()),
        })?;
        total = b.total_messages();
        inputs = Box::new(b);
    }
    let out_path = args.out.display().to_string();
    let file =
        File::create(&args.out).map_err(|e| CliError::Runtime(format!("--out {out_path}: {e}")))?;
    let mut out = BufWriter::new(file);

    let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template(
        "{elapsed_precise} [{wide_bar}] {pos}/{len} messages, {msg} ({eta} left)",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    set_progress(Some(bar.clone()));

    let mut closures = 0u64;
    let mut write_error: Option<std::io::Error> = None;
    let mut damaged: Vec<String> = Vec::new();
    let report = run_bag(&mut pipeline, inputs, |item| match item {
        RunItem::Input(_) => bar.inc(1),
        RunItem::Issue(issue) => {
            bar.inc(1);
            if matches!(issue.reason, crate::runner::IssueReason::Damaged(_)) {
                damaged.push(issue.reason.to_string());
            }
        }
        RunItem::Event(Event::Closure(c)) => {
            closures += 1;
            bar.set_message(format!("{closures} closures"));
            if write_error.is_none() {
                let line = ClosureRecord::new(c, &body_frame).to_json_line();
                if let Err(e) = writeln!(out, "{line}") {
                    write_error = Some(e);
                }
            }
        }
        RunItem::Event(_) => {}
    });
    bar.finish_and_clear();
    set_progress(None);
    if let Some(e) = write_error {
        return Err(CliError::Runtime(format!("--out {out_path}: {e}")));
    }
    out.flush()
        .map_err(|e| CliError::Runtime(format!("--out {out_path}: {e}")))?;

    print_summary(args, bag, &reader, &report, closures);
    if !damaged.is_empty() {
        return Err(CliError::Runtime(format!(
            "the bag is damaged, closures up to the damage were written: {}",
            damaged.join("; ")
        )));
    }
    Ok(())
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

fn print_summary(
    args: &RunArgs,
    bag: &std::path::Path,
    reader: &BagReader,
    r: &RunReport,
    closures: u64,
) {
    let span = reader.time_range().map_or(0.0, |(a, b)| b.secs_since(a));
    let s = &r.stats;
    println!(
        "bag: {} ({} messages, {span:.1} s)",
        bag.display(),
        reader.message_count()
    );
    println!(
        "inputs: {} radar clouds, {} odometry; skipped messages: {}",
        r.radar_inputs,
        r.odometry_inputs,
        counts(&r.issues)
    );
    println!(
        "scans {}, detections kept {} / moving {} / invalid {}, doppler fit failures {}",
        s.scans,
        s.detections_kept,
        s.detections_dynamic,
        s.detections_invalid,
        s.doppler_fit_failures
    );
    let dropped: BTreeMap<&str, u64> = s.dropped.iter().map(|(k, v)| (k.name(), *v)).collect();
    let rejected: BTreeMap<&str, u64> = s.rejected.iter().map(|(k, v)| (k.name(), *v)).collect();
    println!("dropped inputs: {}", counts(&dropped));
    println!(
        "keyframes {}, registrations {}, rejected: {}",
        s.keyframes,
        s.registrations,
        counts(&rejected)
    );
    if s.time_resets > 0 {
        println!("time resets: {}", s.time_resets);
    }
    if let Some(k) = s.speed_scale {
        println!("odometry distances times {k:.4} by the radars' Doppler (newest keyframe)");
    }
    if s.speed_scale_refused > 0 {
        println!(
            "keyframes whose Doppler and odometry distances disagreed beyond submap.speed_scale_bound: {}",
            s.speed_scale_refused
        );
    }
    println!("closures {closures} -> {}", args.out.display());
}
