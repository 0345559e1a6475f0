//! The datasets on disk, without a converter: `dc_loc eval --nuscenes` / `run --nuscenes` (nuScenes
//! tables and sweeps), `eval --vod` / `run --vod` (View-of-Delft directories), and the foxglove-MCAP
//! helpers of `run --bag` ([`nuscenes_mcap_config`], [`apply_bag_extrinsics`]).
//!
//! `eval --nuscenes` ([`eval_nuscenes`]), the paper's nuScenes protocol: read the tables
//! ([`NuscenesDb::open`], with a progress bar over the table bytes); describe every scene as a drive from
//! its ego poses ([`DriveInfo`]); check that the sweep files of the scenes to read are there; skip scenes
//! that meet no other scene; drive each remaining scene through the same [`Collector`] as
//! `dc_loc eval --bag` (its own extrinsics from calibrated_sensor, the radar flags filter, odometry from
//! the ego poses with optional drift); pair and evaluate keyframes across scenes as each scene finishes
//! ([`CrossDriveEval`]); print the same tables.
//!
//! Parameters: the defaults with the dataset's radars ([`nuscenes_config`], `vod_config`), then the
//! params file (optional), then `-p` overrides ([`dataset_config`]); extrinsics come from the dataset.

use std::io::Write;
use std::path::Path;

use super::eval::{EvalArgs, eval_config, write_and_print};
use super::{CliError, set_progress};
use crate::config::Config;
use crate::eval::drives::{CrossDriveEval, DriveInfo, PairRecord};
use crate::eval::report;
use crate::eval::{Collector, Method};
use crate::io::nuscenes::{NuscenesDb, OdometryDrift, SceneInputs, nuscenes_config};
use crate::io::nuscenes_pcd::NuscenesRadarFilter;
use crate::math::iso2_from_iso3;
use crate::params::{ParamSet, apply, flatten_config};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A flag's list of kept states: comma-separated integers, or `all` (no filtering on that flag).
pub fn parse_states(flag: &str, value: &str) -> Result<Option<Vec<i8>>, CliError> {
    if value.trim() == "all" {
        return Ok(None);
    }
    value
        .split(',')
        .map(|v| {
            v.trim().parse::<i8>().map_err(|_| {
                CliError::Usage(format!(
                    "--{flag}: `{v}` is not a state number (give e.g. 0,1,2 or all)"
                ))
            })
        })
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

/// The configuration for a dataset whose radars `template` describes: `template`'s parameters, then the
/// params file's, then the overrides.
pub fn dataset_config(
    template: &Config,
    params: Option<&Path>,
    node_name: &str,
    overrides: &[String],
) -> Result<Config, CliError> {
    let mut set = ParamSet::default();
    for (name, value) in flatten_config(template) {
        set.set(name, value);
    }
    if let Some(p) = params {
        let text = std::fs::read_to_string(p)
            .map_err(|e| CliError::Usage(format!("--params {}: {e}", p.display())))?;
        let file = ParamSet::from_yaml(&text, "/", node_name)
            .map_err(|e| CliError::Usage(format!("--params {}: {e}", p.display())))?;
        for (name, value) in file.entries() {
            set.set(name.clone(), value.clone());
        }
    }
    for o in overrides {
        set.set_override(o)
            .map_err(|e| CliError::Usage(format!("-p: {e}")))?;
    }
    apply(&set).map_err(|e| CliError::Usage(format!("parameters: {e}")))
}

fn bar(len: u64, template: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style.progress_chars("=> "));
    }
    set_progress(Some(bar.clone()));
    bar
}

/// The tables of `root/version`, with a progress bar over their bytes.
fn open_nuscenes(root: &Path, version: &str) -> Result<NuscenesDb, CliError> {
    let progress = bar(
        0,
        "{elapsed_precise} [{wide_bar}] {bytes}/{total_bytes} tables ({msg})",
    );
    let db = NuscenesDb::open(root, version, &mut |p| {
        progress.set_length(p.total);
        progress.set_position(p.read);
        progress.set_message(p.table);
    });
    progress.finish_and_clear();
    set_progress(None);
    db.map_err(|e| match e {
        crate::io::nuscenes::NuscenesError::Table { .. } => CliError::Runtime(e.to_string()),
        e => CliError::Usage(e.to_string()),
    })
}

/// The scenes named in `names` (all when empty); an unknown name is a usage error.
fn select_scenes<'a>(
    db: &'a NuscenesDb,
    names: &[String],
) -> Result<Vec<&'a crate::io::nuscenes::NuscenesScene>, CliError> {
    for name in names {
        if !db.scenes.iter().any(|s| &s.name == name) {
            return Err(CliError::Usage(format!(
                "--scenes: no scene `{name}` in {} {}",
                db.dataroot.display(),
                db.version
            )));
        }
    }
    Ok(db
        .scenes
        .iter()
        .filter(|s| names.is_empty() || names.contains(&s.name))
        .collect())
}

/// Runs `dc_loc eval --nuscenes DIR --version V`.
pub fn eval_nuscenes(args: &EvalArgs) -> Result<(), CliError> {
    let Some(root) = &args.nuscenes else {
        return Err(CliError::Usage("--nuscenes DIR is required".into()));
    };
    let base = dataset_config(
        &nuscenes_config(&Config::default(), &[None; 5]),
        args.params.as_deref(),
        &args.node_name,
        &args.overrides,
    )?;
    let filter = NuscenesRadarFilter {
        invalid_states: parse_states("radar-invalid-states", &args.radar_invalid_states)?,
        dynprop_states: parse_states("radar-dynprop-states", &args.radar_dynprop_states)?,
        ambig_states: parse_states("radar-ambig-states", &args.radar_ambig_states)?,
    };
    let drift = OdometryDrift {
        scale_error: args.odometry_scale_error,
        yaw_rate_bias: args.odometry_yaw_bias_deg.to_radians(),
    };
    if !(drift.scale_error.is_finite() && drift.scale_error.abs() < 0.5) {
        return Err(CliError::Usage(
            "--odometry-scale-error must be in (-0.5, 0.5)".into(),
        ));
    }
    if !drift.yaw_rate_bias.is_finite() {
        return Err(CliError::Usage(
            "--odometry-yaw-bias-deg must be finite".into(),
        ));
    }
    let mut eval = eval_config(args);
    // Pairs are across scenes: no pass within one scene counts.
    eval.min_pass_gap = f64::MAX;
    eval.validate()
        .map_err(|e| CliError::Usage(e.to_string()))?;

    let db = open_nuscenes(root, &args.version)?;
    let scenes = select_scenes(&db, &args.scenes)?;
    let drives: Vec<DriveInfo> = scenes
        .iter()
        .map(|s| DriveInfo {
            name: s.name.clone(),
            location: s.location.clone(),
            trajectory: s
                .sweeps
                .iter()
                .map(|w| {
                    let t = iso2_from_iso3(&w.t_global_ego);
                    (t.translation.vector, t.rotation.angle())
                })
                .collect(),
        })
        .collect();
    let sweeps: usize = scenes.iter().map(|s| s.sweeps.len()).sum();
    log::info!(
        "{} {}: {} scenes, {} radar sweeps",
        root.display(),
        args.version,
        scenes.len(),
        sweeps
    );
    let methods = if args.dcloc_only {
        vec![Method::DCLOC]
    } else {
        Method::all()
    };
    let mut cross = CrossDriveEval::new(
        drives,
        eval.clone(),
        methods.clone(),
        base.registration.clone(),
    );
    let progress = bar(
        sweeps as u64,
        "{elapsed_precise} [{wide_bar}] {pos}/{len} sweeps, {msg} ({eta} left)",
    );
    // Every sweep file of the scenes to be read must be there: say so now, not hours into the run.
    let mut load: Vec<bool> = (0..scenes.len()).map(|d| cross.needs_loading(d)).collect();
    let mut missing: Vec<(usize, &crate::io::nuscenes::RadarSweep)> = Vec::new();
    for (d, scene) in scenes.iter().enumerate().filter(|(d, _)| load[*d]) {
        missing.extend(
            scene
                .sweeps
                .iter()
                .filter(|w| !db.dataroot.join(&w.filename).is_file())
                .map(|w| (d, w)),
        );
    }
    if let Some(&(d, first)) = missing.first() {
        let mut incomplete: Vec<usize> = missing.iter().map(|m| m.0).collect();
        incomplete.dedup();
        if !args.skip_incomplete_scenes {
            return Err(CliError::Runtime(format!(
                "{} sweep files of {} scenes are missing, e.g. {} (sample_data {}, {}): extract the \
                 radar files of those scenes' blobs into {}, check that --version {} matches the files, \
                 or pass --skip-incomplete-scenes",
                missing.len(),
                incomplete.len(),
                db.dataroot.join(&first.filename).display(),
                first.token,
                scenes[d].name,
                db.dataroot.display(),
                args.version
            )));
        }
        for &d in &incomplete {
            log::warn!("{}: sweep files missing, scene skipped", scenes[d].name);
            load[d] = false;
        }
    }
    let (mut keyframes, mut loaded, mut scans) = (0usize, 0usize, 0u64);
    let mut dropped: std::collections::BTreeMap<&str, u64> = Default::default();
    for (d, scene) in scenes.iter().enumerate() {
        if !load[d] {
            progress.inc(scene.sweeps.len() as u64);
            continue;
        }
        loaded += 1;
        let cfg = nuscenes_config(&base, &scene.extrinsics());
        let mut collector =
            Collector::new(&cfg, &eval).map_err(|e| CliError::Usage(e.to_string()))?;
        for input in SceneInputs::new(&db.dataroot, scene, filter.clone(), drift) {
            let input = input.map_err(|e| CliError::Runtime(e.to_string()))?;
            if matches!(input, crate::runner::Input::Radar { .. }) {
                progress.inc(1);
            }
            collector.push(&input);
        }
        let (kfs, stats) = collector.finish();
        scans += stats.scans;
        for (reason, n) in &stats.dropped {
            *dropped.entry(reason.name()).or_default() += n;
        }
        keyframes += kfs.len();
        let n = cross.add_drive(d, kfs);
        progress.set_message(format!(
            "{}: {} pairs so far, {} keyframes held",
            scene.name,
            cross.records.len(),
            cross.retained()
        ));
        log::debug!("{}: {n} pairs", scene.name);
    }
    progress.finish_and_clear();
    set_progress(None);
    if cross.records.is_empty() {
        return Err(CliError::Usage(format!(
            "no keyframe pairs: no two of the {} scenes pass within {} m of each other{}",
            scenes.len(),
            eval.pair_radius,
            if args.any_heading {
                ""
            } else {
                " in the same direction (try --any-heading)"
            }
        )));
    }
    log::info!(
        "{scans} radar sweeps into the pipeline; dropped: {}",
        if dropped.is_empty() {
            "none".to_string()
        } else {
            dropped
                .iter()
                .map(|(k, v)| format!("{k} {v}"))
                .collect::<Vec<_>>()
                .join(", ")
        }
    );
    let summaries = report::summarize(&cross.results, &methods, &eval);
    let intro = format!(
        "nuScenes {} in {}: {} scenes ({} meet another scene and were read), {} keyframes, {} pairs \
         across scenes (ground truth within {} m), at most {} keyframes ({:.1} MB of submap points) held \
         at once, outlier threshold {} m\n",
        args.version,
        root.display(),
        scenes.len(),
        loaded,
        keyframes,
        cross.records.len(),
        eval.pair_radius,
        cross.max_retained,
        (cross.max_points * std::mem::size_of::<crate::submap::SubmapPoint>()) as f64 / 1e6,
        eval.outlier_threshold
    );
    write_and_print(
        &summaries,
        &eval,
        &methods,
        &args.out_dir,
        |path| write_records(path, cross.drives(), &cross.records),
        &intro,
    )?;
    Ok(())
}

/// The per-pair JSON lines of a cross-drive evaluation (one line per pair and method).
pub fn write_records(
    path: &Path,
    drives: &[DriveInfo],
    records: &[PairRecord],
) -> std::io::Result<()> {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    let name = |d: usize| drives.get(d).map_or("", |x| x.name.as_str());
    for rec in records {
        for r in &rec.results {
            let v = serde_json::json!({
                "method": r.method.name(),
                "query_scene": name(rec.query_drive),
                "target_scene": name(rec.target_drive),
                "query_stamp": rec.query_stamp,
                "target_stamp": rec.target_stamp,
                "distance": r.pair.distance,
                "velocity_difference": r.velocity_difference,
                "translation_error": if r.translation_error.is_finite() { Some(r.translation_error) } else { None },
                "rotation_error": if r.rotation_error.is_finite() { Some(r.rotation_error) } else { None },
                "nees": r.nees,
                "overlap": r.overlap,
                "inliers": r.inliers,
                "failure": r.failure,
            });
            writeln!(out, "{v}")?;
        }
    }
    out.flush()
}

/// Drives a fresh [`Collector`] for `cfg` over `inputs`; the first input error stops with a runtime
/// error. `tick` is called per radar input.
fn collect_drive<E: std::fmt::Display>(
    cfg: &Config,
    eval: &crate::eval::EvalConfig,
    inputs: impl Iterator<Item = Result<crate::runner::Input, E>>,
    mut tick: impl FnMut(),
) -> Result<Vec<crate::eval::EvalKeyframe>, CliError> {
    let mut collector = Collector::new(cfg, eval).map_err(|e| CliError::Usage(e.to_string()))?;
    for input in inputs {
        let input = input.map_err(|e| CliError::Runtime(e.to_string()))?;
        if matches!(input, crate::runner::Input::Radar { .. }) {
            tick();
        }
        collector.push(&input);
    }
    Ok(collector.finish().0)
}

fn vod_sequences(
    dir: &Path,
    frame_rate: f64,
) -> Result<Vec<crate::io::vod_sequence::VodSequence>, CliError> {
    if !(frame_rate.is_finite() && frame_rate > 0.0) {
        return Err(CliError::Usage(format!(
            "--frame-rate {frame_rate}: must be > 0 Hz"
        )));
    }
    crate::io::vod_sequence::open_sequences(dir).map_err(|e| match e {
        crate::io::vod_sequence::VodSequenceError::Frame { .. } => CliError::Runtime(e.to_string()),
        e => CliError::Usage(e.to_string()),
    })
}

/// Runs `dc_loc eval --vod DIR`: every run of consecutive frames is a drive (all in VoD's one map
/// frame); keyframes of different runs are paired as nuScenes scenes are, and keyframes of one run
/// after `--min-pass-gap` metres of path as in `eval --bag`.
pub fn eval_vod(args: &EvalArgs) -> Result<(), CliError> {
    use crate::io::vod_sequence::{VodInputs, vod_config};
    let Some(dir) = &args.vod else {
        return Err(CliError::Usage("--vod DIR is required".into()));
    };
    let cfg = dataset_config(
        &vod_config(&Config::default()),
        args.params.as_deref(),
        &args.node_name,
        &args.overrides,
    )?;
    let cfg = vod_config(&cfg);
    // Pairs across runs, and within a run after --min-pass-gap metres of path (a loop).
    let eval = eval_config(args);
    eval.validate()
        .map_err(|e| CliError::Usage(e.to_string()))?;
    let sequences = vod_sequences(dir, args.frame_rate)?;
    let frames: usize = sequences.iter().map(|s| s.frames.len()).sum();
    let drives: Vec<DriveInfo> = sequences
        .iter()
        .map(|s| DriveInfo {
            name: s.name(),
            location: "delft".into(),
            trajectory: s
                .frames
                .iter()
                .map(|f| {
                    let t = iso2_from_iso3(&f.t_map_radar);
                    (t.translation.vector, t.rotation.angle())
                })
                .collect(),
        })
        .collect();
    let methods = if args.dcloc_only {
        vec![Method::DCLOC]
    } else {
        Method::all()
    };
    let mut cross = CrossDriveEval::new(
        drives,
        eval.clone(),
        methods.clone(),
        cfg.registration.clone(),
    );
    let progress = bar(
        frames as u64,
        "{elapsed_precise} [{wide_bar}] {pos}/{len} frames ({eta} left)",
    );
    let mut keyframes = 0;
    for (d, seq) in sequences.iter().enumerate() {
        let kfs = collect_drive(&cfg, &eval, VodInputs::new(seq, args.frame_rate), || {
            progress.inc(1)
        })?;
        keyframes += kfs.len();
        cross.add_drive(d, kfs);
    }
    progress.finish_and_clear();
    set_progress(None);
    if cross.records.is_empty() {
        return Err(CliError::Usage(format!(
            "no keyframe pairs: {} has {} runs of consecutive frames ({frames} frames) and no two \
             keyframes of different runs (or {} m of path apart) within {} m of each other",
            dir.display(),
            sequences.len(),
            eval.min_pass_gap,
            eval.pair_radius
        )));
    }
    let summaries = report::summarize(&cross.results, &methods, &eval);
    let intro = format!(
        "View-of-Delft {}: {} runs of consecutive frames, {frames} frames, {keyframes} keyframes, {} \
         pairs (another run, or the same run after {} m of path; ground truth within {} m), outlier threshold {} m\n",
        dir.display(),
        sequences.len(),
        cross.records.len(),
        eval.min_pass_gap,
        eval.pair_radius,
        eval.outlier_threshold
    );
    write_and_print(
        &summaries,
        &eval,
        &methods,
        &args.out_dir,
        |path| write_records(path, cross.drives(), &cross.records),
        &intro,
    )?;
    Ok(())
}

/// Runs `dc_loc run --vod DIR`: the pipeline over every frame in frame order (runs of consecutive
/// frames one after another), loop closures to `--out` as JSON lines.
pub fn run_vod(args: &super::run::RunArgs) -> Result<(), CliError> {
    use crate::io::vod_sequence::{VodInputs, vod_config};
    use crate::pipeline::{Event, Pipeline};
    use crate::runner::drive_pipeline;
    let Some(dir) = &args.vod else {
        return Err(CliError::Usage("--vod DIR is required".into()));
    };
    let cfg = dataset_config(
        &vod_config(&Config::default()),
        args.params.as_deref(),
        &args.node_name,
        &args.overrides,
    )?;
    let cfg = vod_config(&cfg);
    let body_frame = cfg.body_frame.clone();
    let mut pipeline = Pipeline::new(cfg).map_err(|e| CliError::Usage(e.to_string()))?;
    let sequences = vod_sequences(dir, args.frame_rate)?;
    let frames: usize = sequences.iter().map(|s| s.frames.len()).sum();
    let out_path = args.out.display().to_string();
    let file = std::fs::File::create(&args.out)
        .map_err(|e| CliError::Runtime(format!("--out {out_path}: {e}")))?;
    let mut out = std::io::BufWriter::new(file);
    let progress = bar(
        frames as u64,
        "{elapsed_precise} [{wide_bar}] {pos}/{len} frames, {msg} ({eta} left)",
    );
    let mut closures = 0u64;
    let mut write = |events: Vec<Event>, closures: &mut u64| {
        write_closures(&mut out, &out_path, &body_frame, events, closures)
    };
    for seq in &sequences {
        for input in VodInputs::new(seq, args.frame_rate) {
            let input = input.map_err(|e| CliError::Runtime(e.to_string()))?;
            if matches!(input, crate::runner::Input::Radar { .. }) {
                progress.inc(1);
            }
            write(drive_pipeline(&mut pipeline, &input), &mut closures)?;
        }
    }
    write(pipeline.finish(), &mut closures)?;
    progress.finish_and_clear();
    set_progress(None);
    out.flush()
        .map_err(|e| CliError::Runtime(format!("--out {out_path}: {e}")))?;
    let s = pipeline.stats();
    println!(
        "View-of-Delft {}: {} runs of consecutive frames, {frames} frames",
        dir.display(),
        sequences.len()
    );
    println!(
        "scans {}, detections kept {}, keyframes {}, registrations {}",
        s.scans, s.detections_kept, s.keyframes, s.registrations
    );
    println!("closures {closures} -> {}", args.out.display());
    Ok(())
}

/// The five-radar nuScenes configuration for a bag written by nuscenes2mcap (or nuscenes2bag): each
/// channel whose topic is in the bag (`/radar_front` with frame `radar_front`, or the 2022 layout's
/// `/RADAR_FRONT` with frame `RADAR_FRONT`) as `foxglove.PointCloud`. `None` when the bag has none of
/// them (a ROS bag needs its params file: its odometry topic is not implied).
pub fn nuscenes_mcap_config(reader: &crate::bag::BagReader) -> Option<Config> {
    use crate::io::nuscenes::RADAR_CHANNELS;
    let mut cfg = nuscenes_config(&Config::default(), &[None; 5]);
    let mut names = Vec::new();
    for (i, channel) in RADAR_CHANNELS.iter().enumerate() {
        let name = cfg.radar_names.get(i)?.clone();
        let lower = channel.to_ascii_lowercase();
        let found = [lower.as_str(), *channel]
            .into_iter()
            .find(|frame| crate::bag::foxglove::is_foxglove_cloud(reader, &format!("/{frame}")));
        match (found, cfg.radars.get_mut(&name)) {
            (Some(frame), Some(r)) => {
                r.topic = format!("/{frame}");
                r.frame_id = frame.to_string();
                names.push(name);
            }
            _ => {
                cfg.radars.remove(&name);
            }
        }
    }
    if names.is_empty() {
        return None;
    }
    cfg.radar_names = names;
    cfg.odometry.topic = "/tf".into();
    Some(cfg)
}

/// Replaces each radar's extrinsic by the bag's `body_frame -> frame_id` transform from `/tf_static` or
/// `/tf`, when the bag has one (logged).
pub fn apply_bag_extrinsics(
    reader: &crate::bag::BagReader,
    cfg: &mut Config,
) -> Result<(), CliError> {
    let frames: Vec<String> = cfg
        .radar_list()
        .iter()
        .map(|(_, r)| r.frame_id.clone())
        .filter(|f| !f.is_empty())
        .collect();
    let found = crate::bag::foxglove::bag_extrinsics(reader, &cfg.body_frame, &frames)
        .map_err(|e| CliError::Runtime(e.to_string()))?;
    for (name, r) in cfg.radars.iter_mut() {
        if let Some(t) = found.get(&r.frame_id) {
            let (roll, pitch, yaw) = t.rotation.euler_angles();
            r.extrinsic = [
                t.translation.x,
                t.translation.y,
                t.translation.z,
                roll,
                pitch,
                yaw,
            ];
            log::info!(
                "radar {name}: extrinsic from the bag's transforms ({} -> {})",
                cfg.body_frame,
                r.frame_id
            );
        }
    }
    Ok(())
}

/// Runs `dc_loc run --nuscenes DIR`: per location, its scenes in time order through one pipeline
/// (odometry = ego poses in the location's global frame, so revisits across scenes are found), loop
/// closures to `--out`. The extrinsics are those of the location's first scene (a warning names a scene
/// whose calibration differs).
pub fn run_nuscenes(args: &super::run::RunArgs) -> Result<(), CliError> {
    use crate::pipeline::{Event, Pipeline};
    use crate::runner::drive_pipeline;
    let Some(root) = &args.nuscenes else {
        return Err(CliError::Usage("--nuscenes DIR is required".into()));
    };
    let base = dataset_config(
        &nuscenes_config(&Config::default(), &[None; 5]),
        args.params.as_deref(),
        &args.node_name,
        &args.overrides,
    )?;
    let filter = NuscenesRadarFilter {
        invalid_states: parse_states("radar-invalid-states", &args.radar_invalid_states)?,
        dynprop_states: parse_states("radar-dynprop-states", &args.radar_dynprop_states)?,
        ambig_states: parse_states("radar-ambig-states", &args.radar_ambig_states)?,
    };
    let db = open_nuscenes(root, &args.version)?;
    let mut scenes = select_scenes(&db, &args.scenes)?;
    scenes.retain(|s| !s.sweeps.is_empty());
    scenes.sort_by_key(|s| s.sweeps.first().map_or(0, |w| w.timestamp_us));
    let mut locations: Vec<&str> = scenes.iter().map(|s| s.location.as_str()).collect();
    locations.sort_unstable();
    locations.dedup();
    let sweeps: usize = scenes.iter().map(|s| s.sweeps.len()).sum();
    let out_path = args.out.display().to_string();
    let file = std::fs::File::create(&args.out)
        .map_err(|e| CliError::Runtime(format!("--out {out_path}: {e}")))?;
    let mut out = std::io::BufWriter::new(file);
    let progress = bar(
        sweeps as u64,
        "{elapsed_precise} [{wide_bar}] {pos}/{len} sweeps, {msg} ({eta} left)",
    );
    let mut closures = 0u64;
    let mut keyframes = 0u64;
    for location in &locations {
        let here: Vec<_> = scenes.iter().filter(|s| s.location == *location).collect();
        let Some(first) = here.first() else { continue };
        let extrinsics = first.extrinsics();
        let cfg = nuscenes_config(&base, &extrinsics);
        let body_frame = cfg.body_frame.clone();
        let mut pipeline = Pipeline::new(cfg).map_err(|e| CliError::Usage(e.to_string()))?;
        let mut write = |events: Vec<Event>, closures: &mut u64| {
            write_closures(&mut out, &out_path, &body_frame, events, closures)
        };
        for scene in &here {
            for (a, b) in scene.extrinsics().iter().zip(&extrinsics) {
                if let (Some(a), Some(b)) = (a, b) {
                    if (a.translation.vector - b.translation.vector).norm() > 0.01
                        || a.rotation.angle_to(&b.rotation) > 0.1f64.to_radians()
                    {
                        log::warn!(
                            "{}: radar calibration differs from {}'s, which this run uses",
                            scene.name,
                            first.name
                        );
                        break;
                    }
                }
            }
            progress.set_message(format!("{} ({location}), {closures} closures", scene.name));
            for input in SceneInputs::new(&db.dataroot, scene, filter.clone(), Default::default()) {
                let input = input.map_err(|e| CliError::Runtime(e.to_string()))?;
                if matches!(input, crate::runner::Input::Radar { .. }) {
                    progress.inc(1);
                }
                write(drive_pipeline(&mut pipeline, &input), &mut closures)?;
            }
        }
        write(pipeline.finish(), &mut closures)?;
        keyframes += pipeline.stats().keyframes;
    }
    progress.finish_and_clear();
    set_progress(None);
    out.flush()
        .map_err(|e| CliError::Runtime(format!("--out {out_path}: {e}")))?;
    println!(
        "nuScenes {} in {}: {} scenes at {} locations, {sweeps} radar sweeps, {keyframes} keyframes",
        args.version,
        root.display(),
        scenes.len(),
        locations.len()
    );
    println!("closures {closures} -> {}", args.out.display());
    Ok(())
}

/// Writes the closures among `events` to `out` as JSON lines (`path` names it in errors), counting them.
fn write_closures(
    out: &mut impl Write,
    path: &str,
    body_frame: &str,
    events: Vec<crate::pipeline::Event>,
    closures: &mut u64,
) -> Result<(), CliError> {
    for e in events {
        if let crate::pipeline::Event::Closure(c) = e {
            *closures += 1;
            writeln!(
                out,
                "{}",
                crate::runner::ClosureRecord::new(&c, body_frame).to_json_line()
            )
            .map_err(|e| CliError::Runtime(format!("--out {path}: {e}")))?;
        }
    }
    Ok(())
}
