//! `dc_loc eval` on the datasets on disk, without a converter: `--nuscenes` (nuScenes tables and
//! sweeps) and `--vod` (View-of-Delft directories).
//!
//! `eval --nuscenes` ([`eval_nuscenes`]), the paper's nuScenes protocol: read the tables (with a
//! progress bar over the table bytes); describe every scene as a drive from its ego poses
//! ([`DriveInfo`]); check that the sweep files of the scenes to read are there; skip scenes that meet
//! no other scene; drive each remaining scene through the same [`Collector`] as `dc_loc eval --bag`
//! (its own extrinsics from calibrated_sensor, the radar flags filter, odometry from the ego poses with
//! optional drift); pair and evaluate keyframes across scenes as each scene finishes
//! ([`CrossDriveEval`]); print the same tables.
//!
//! `eval --vod` ([`eval_vod`]): every run of consecutive frames is a drive (all in VoD's one map
//! frame); keyframes of different runs are paired as nuScenes scenes are, and keyframes of one run
//! after `--min-pass-gap` metres of path as in `eval --bag`.

use std::io::Write;
use std::path::Path;

use super::eval::{EvalArgs, eval_config, methods, write_and_print};
use super::source::{open_nuscenes, select_scenes, vod_sequences};
use super::{CliError, progress};
use crate::eval::drives::{CrossDriveEval, DriveInfo, PairRecord};
use crate::eval::report;
use crate::eval::{Collector, EvalConfig};
use crate::input::{Input, InputIssue};
use crate::io::nuscenes::{
    NuscenesDb, NuscenesScene, OdometryDrift, RadarSweep, SceneInputs, nuscenes_config,
};
use crate::io::nuscenes_pcd::NuscenesRadarFilter;
use crate::io::vod_sequence::{VodInputs, vod_config};
use crate::math::iso2_from_iso3;
use crate::pipeline::{Config, PipelineStats};
use indicatif::ProgressBar;
use std::collections::BTreeMap;

/// Runs `dc_loc eval --nuscenes DIR --version V`.
pub fn eval_nuscenes(args: &EvalArgs) -> Result<(), CliError> {
    let src = &args.source;
    let Some(root) = &src.nuscenes else {
        return Err(CliError::Usage("--nuscenes DIR is required".into()));
    };
    let base = src.dataset_config(&nuscenes_config(&Config::default(), &[None; 5]))?;
    let filter = src.radar_filter()?;
    let drift = odometry_drift(args)?;
    let mut eval = eval_config(args);
    // Pairs are across scenes: no pass within one scene counts.
    eval.min_pass_gap = f64::MAX;
    eval.validate()
        .map_err(|e| CliError::Usage(e.to_string()))?;

    let db = open_nuscenes(root, &src.version)?;
    let scenes: Vec<&NuscenesScene> = select_scenes(&db, &src.scenes)?
        .into_iter()
        .map(|i| &db.scenes[i])
        .collect();
    let drives = scene_drives(&scenes);
    let sweeps: usize = scenes.iter().map(|s| s.sweeps.len()).sum();
    log::info!(
        "{} {}: {} scenes, {} radar sweeps",
        root.display(),
        src.version,
        scenes.len(),
        sweeps
    );
    let methods = methods(args);
    let mut cross = CrossDriveEval::new(
        drives,
        eval.clone(),
        methods.clone(),
        base.registration.clone(),
    );
    let progress = progress::bar(
        sweeps as u64,
        "{elapsed_precise} [{wide_bar}] {pos}/{len} sweeps, {msg} ({eta} left)",
    );
    let load = scenes_to_load(args, &db, &scenes, &cross)?;
    let run = SceneRun {
        db: &db,
        base: &base,
        eval: &eval,
        filter: &filter,
        drift,
    };
    let totals = run.read(&scenes, &load, &mut cross, &progress)?;
    progress::clear(&progress);
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
        "{} radar sweeps into the pipeline; dropped: {}",
        totals.scans,
        if totals.dropped.is_empty() {
            "none".to_string()
        } else {
            totals
                .dropped
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
        src.version,
        root.display(),
        scenes.len(),
        totals.loaded,
        totals.keyframes,
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

/// The odometry drift of `--odometry-scale-error` and `--odometry-yaw-bias-deg`, checked.
fn odometry_drift(args: &EvalArgs) -> Result<OdometryDrift, CliError> {
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
    Ok(drift)
}

/// Each scene as a drive: its name, location and the planar ego poses of its sweeps.
fn scene_drives(scenes: &[&NuscenesScene]) -> Vec<DriveInfo> {
    scenes
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
        .collect()
}

/// Which scenes to read: those that meet another scene. Every sweep file of those must be there (said
/// now, not hours into the run); with `--skip-incomplete-scenes` the scenes missing some are skipped
/// instead.
fn scenes_to_load(
    args: &EvalArgs,
    db: &NuscenesDb,
    scenes: &[&NuscenesScene],
    cross: &CrossDriveEval,
) -> Result<Vec<bool>, CliError> {
    let mut load: Vec<bool> = (0..scenes.len()).map(|d| cross.needs_loading(d)).collect();
    let mut missing: Vec<(usize, &RadarSweep)> = Vec::new();
    for (d, scene) in scenes.iter().enumerate().filter(|(d, _)| load[*d]) {
        missing.extend(
            scene
                .sweeps
                .iter()
                .filter(|w| !w.path_in(&db.dataroot).is_some_and(|p| p.is_file()))
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
                args.source.version
            )));
        }
        for &d in &incomplete {
            log::warn!("{}: sweep files missing, scene skipped", scenes[d].name);
            load[d] = false;
        }
    }
    Ok(load)
}

/// What every scene is read with.
struct SceneRun<'a> {
    db: &'a NuscenesDb,
    base: &'a Config,
    eval: &'a EvalConfig,
    filter: &'a NuscenesRadarFilter,
    drift: OdometryDrift,
}

/// What reading the scenes gave.
#[derive(Default)]
struct SceneTotals {
    keyframes: usize,
    loaded: usize,
    scans: u64,
    dropped: BTreeMap<&'static str, u64>,
}

impl SceneRun<'_> {
    /// Drives each scene to load through a [`Collector`] (its own extrinsics) and pairs its keyframes
    /// with the earlier scenes' as it finishes; the progress bar counts the sweeps, skipped scenes'
    /// included.
    fn read(
        &self,
        scenes: &[&NuscenesScene],
        load: &[bool],
        cross: &mut CrossDriveEval,
        progress: &ProgressBar,
    ) -> Result<SceneTotals, CliError> {
        let mut totals = SceneTotals::default();
        for (d, scene) in scenes.iter().enumerate() {
            if !load[d] {
                progress.inc(scene.sweeps.len() as u64);
                continue;
            }
            totals.loaded += 1;
            let cfg = nuscenes_config(self.base, &scene.extrinsics());
            let inputs =
                SceneInputs::new(&self.db.dataroot, scene, self.filter.clone(), self.drift);
            let (kfs, stats) = collect_drive(&cfg, self.eval, inputs, || progress.inc(1))?;
            totals.scans += stats.scans;
            for (reason, n) in &stats.dropped {
                *totals.dropped.entry(reason.name()).or_default() += n;
            }
            totals.keyframes += kfs.len();
            let n = cross.add_drive(d, kfs);
            progress.set_message(format!(
                "{}: {} pairs so far, {} keyframes held",
                scene.name,
                cross.records.len(),
                cross.retained()
            ));
            log::debug!("{}: {n} pairs", scene.name);
        }
        Ok(totals)
    }
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

/// Drives a fresh [`Collector`] for `cfg` over `inputs`; skipped messages are warned about, the first
/// of each topic and cause. `tick` is
/// called per radar message and per skipped message. Returns the keyframes and the pipeline's counts.
fn collect_drive(
    cfg: &Config,
    eval: &EvalConfig,
    inputs: impl Iterator<Item = Result<Input, InputIssue>>,
    mut tick: impl FnMut(),
) -> Result<(Vec<crate::eval::EvalKeyframe>, PipelineStats), CliError> {
    let mut collector = Collector::new(cfg, eval).map_err(|e| CliError::Usage(e.to_string()))?;
    let mut causes = crate::repeats::Repeats::default();
    for input in inputs {
        match input {
            Ok(input) => {
                if matches!(input, Input::Radar { .. }) {
                    tick();
                }
                collector.push(&input);
            }
            Err(issue) => {
                tick();
                issue.log_once(&mut causes);
            }
        }
    }
    Ok(collector.finish())
}

/// Runs `dc_loc eval --vod DIR`: every run of consecutive frames is a drive (all in VoD's one map
/// frame); keyframes of different runs are paired as nuScenes scenes are, and keyframes of one run
/// after `--min-pass-gap` metres of path as in `eval --bag`.
pub fn eval_vod(args: &EvalArgs) -> Result<(), CliError> {
    let src = &args.source;
    let Some(dir) = &src.vod else {
        return Err(CliError::Usage("--vod DIR is required".into()));
    };
    let cfg = vod_config(&src.dataset_config(&vod_config(&Config::default()))?);
    // Pairs across runs, and within a run after --min-pass-gap metres of path (a loop).
    let eval = eval_config(args);
    eval.validate()
        .map_err(|e| CliError::Usage(e.to_string()))?;
    let sequences = vod_sequences(dir, src.frame_rate)?;
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
    let methods = methods(args);
    let mut cross = CrossDriveEval::new(
        drives,
        eval.clone(),
        methods.clone(),
        cfg.registration.clone(),
    );
    let progress = progress::bar(
        frames as u64,
        "{elapsed_precise} [{wide_bar}] {pos}/{len} frames ({eta} left)",
    );
    let mut keyframes = 0;
    for (d, seq) in sequences.iter().enumerate() {
        let (kfs, _) = collect_drive(&cfg, &eval, VodInputs::new(seq, src.frame_rate), || {
            progress.inc(1)
        })?;
        keyframes += kfs.len();
        cross.add_drive(d, kfs);
    }
    progress::clear(&progress);
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
