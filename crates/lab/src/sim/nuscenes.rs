//! A simulated drive written as a nuScenes dataset (tables and radar PCD files), one scene per lap.
//!
//! Entry point: [`export_nuscenes`]. Used to test the nuScenes reader and `dc_loc eval --nuscenes`
//! against `dc_loc eval` on the same drive as a bag, and to try the nuScenes path without the real data.
//!
//! What is written under `<dataroot>/`: `<version>/{sensor,calibrated_sensor,log,scene,sample,
//! sample_data,ego_pose}.json` with the fields the devkit's schema gives them, and per scan
//! `samples/RADAR_*/…pcd` (2 Hz keyframes) or `sweeps/RADAR_*/…pcd` in the ARS408 PCD layout (18 fields,
//! 43-byte records, trailing zero padding as the real files have). Per detection: the measured position
//! (with its Doppler distortion), `vx, vy` = measured radial velocity along the ray, `dyn_prop` 0
//! (moving) for moving targets and 1 (stationary) otherwise, `invalid_state` 0, `ambig_state` 3,
//! `vx_comp, vy_comp` zero (not simulated). Ego poses are the true poses at each scan time.
//! The drive must use the `nuscenes` radar preset (radar index = channel of
//! [`dc_loc_io::sources::nuscenes::RADAR_CHANNELS`]).

use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use crate::sim::{RadarPreset, SimDrive};
use dc_loc_core::math::{Iso3, Stamp, iso3_from_iso2};
use dc_loc_io::sources::nuscenes::RADAR_CHANNELS;

/// Why a drive could not be written as a nuScenes dataset.
#[derive(Debug, thiserror::Error)]
pub enum NuscenesExportError {
    /// The drive does not use the nuScenes radars.
    #[error("the drive must use radar_preset `nuscenes` (five ARS408 radars)")]
    NotNuscenesRadars,
    /// A file could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
}

/// What [`export_nuscenes`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct NuscenesExport {
    /// Scene names, in order.
    pub scenes: Vec<String>,
    /// Radar sweeps (PCD files).
    pub sweeps: usize,
    /// Of which keyframes.
    pub keyframes: usize,
}

fn token(kind: u32, index: usize) -> String {
    format!("{kind:08x}{index:024x}")
}

fn pose_json(t: &Iso3) -> (Value, Value) {
    let q = t.rotation.quaternion();
    (
        json!([t.translation.x, t.translation.y, t.translation.z]),
        json!([q.w, q.i, q.j, q.k]),
    )
}

const PCD_HEADER: &str = "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n\
FIELDS x y z dyn_prop id rcs vx vy vx_comp vy_comp is_quality_valid ambig_state x_rms y_rms invalid_state pdh0 vx_rms vy_rms\n\
SIZE 4 4 4 1 2 4 4 4 4 4 1 1 1 1 1 1 1 1\nTYPE F F F I I F F F F F I I I I I I I I\n\
COUNT 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1\n";

/// The PCD bytes of one scan.
fn pcd_bytes(s: &crate::sim::SimScan) -> Vec<u8> {
    let n = s.scan.detections.len();
    let mut b = format!(
        "{PCD_HEADER}WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    )
    .into_bytes();
    for (i, d) in s.scan.detections.iter().enumerate() {
        let moving = s.truth.get(i).is_some_and(|t| t.kind.is_moving());
        let range = d.p_radar.norm().max(1e-9);
        let (ux, uy) = (d.p_radar.x / range, d.p_radar.y / range);
        let f = |b: &mut Vec<u8>, v: f64| b.extend_from_slice(&(v as f32).to_le_bytes());
        f(&mut b, d.p_radar.x);
        f(&mut b, d.p_radar.y);
        f(&mut b, 0.0);
        b.push(if moving { 0 } else { 1 }); // dyn_prop
        b.extend_from_slice(&(i as i16).to_le_bytes()); // id
        f(&mut b, d.rcs.unwrap_or(0.0));
        f(&mut b, d.v_r * ux);
        f(&mut b, d.v_r * uy);
        f(&mut b, 0.0);
        f(&mut b, 0.0);
        // is_quality_valid, ambig_state, x_rms, y_rms, invalid_state, pdh0, vx_rms, vy_rms
        b.extend_from_slice(&[1, 3, 0, 0, 0, 0, 0, 0]);
    }
    // The real files end with zero padding: 28 bytes here.
    b.extend_from_slice(&[0u8; 28]);
    b
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), NuscenesExportError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| NuscenesExportError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    std::fs::write(path, bytes).map_err(|source| NuscenesExportError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Token kinds: the first eight hex digits of a token name its table.
const SENSOR: u32 = 1;
const CALIB: u32 = 2;
const LOG: u32 = 3;
const SCENE: u32 = 4;
const SAMPLE: u32 = 5;
const DATA: u32 = 6;
const EGO: u32 = 7;

/// The one log all scenes belong to.
const LOGFILE: &str = "sim-2026-01-01-00-00-00+0000";

/// A stamp in microseconds, as the tables and file names have it.
fn us(s: Stamp) -> i64 {
    s.0.div_euclid(1000)
}

/// The rows of the seven tables.
#[derive(Default)]
struct Tables {
    sensors: Vec<Value>,
    calibs: Vec<Value>,
    logs: Vec<Value>,
    scenes: Vec<Value>,
    samples: Vec<Value>,
    data: Vec<Value>,
    egos: Vec<Value>,
}

/// The samples of one scene: every 0.5 s from its first scan, numbered from `first` in the sample table.
struct SceneSamples {
    first: usize,
    count: usize,
    t0_us: i64,
}

impl SceneSamples {
    /// Timestamp of the scene's sample `j`, microseconds.
    fn time(&self, j: usize) -> i64 {
        self.t0_us + (j as i64) * 500_000
    }
}

/// Writes `drive` as a nuScenes dataset under `dataroot` (tables in `dataroot/version`), one scene per
/// lap, all scenes in one log at `location`.
pub fn export_nuscenes(
    drive: &SimDrive,
    dataroot: &Path,
    version: &str,
    location: &str,
) -> Result<NuscenesExport, NuscenesExportError> {
    let radars = &drive.setup.radars;
    if drive.setup.config.radar_preset != RadarPreset::Nuscenes || radars.len() != 5 {
        return Err(NuscenesExportError::NotNuscenesRadars);
    }
    let mut tables = Tables::default();
    add_sensors(radars, &mut tables);
    tables.logs = vec![
        json!({"token": token(LOG, 0), "logfile": LOGFILE, "vehicle": "sim",
        "date_captured": "2026-01-01", "location": location}),
    ];
    // Scenes: one per lap, the scans of that lap.
    let mut names = Vec::new();
    let mut keyframes = 0;
    for (k, scans) in scans_by_lap(drive)
        .iter()
        .enumerate()
        .filter(|(_, v)| !v.is_empty())
    {
        let (name, samples) = add_scene(k, scans, &mut tables);
        names.push(name);
        keyframes += add_sweeps(drive, dataroot, scans, &samples, &mut tables)?;
    }
    let sweeps = tables.data.len();
    write_tables(&dataroot.join(version), tables)?;
    Ok(NuscenesExport {
        scenes: names,
        sweeps,
        keyframes,
    })
}

/// The sensor and calibrated_sensor rows of the five radars.
fn add_sensors(radars: &[crate::sim::SimRadarConfig], tables: &mut Tables) {
    for (i, r) in radars.iter().enumerate() {
        tables.sensors.push(
            json!({"token": token(SENSOR, i), "channel": RADAR_CHANNELS[i], "modality": "radar"}),
        );
        let [x, y, z, roll, pitch, yaw] = r.extrinsic;
        let (t, q) = pose_json(&dc_loc_core::math::iso3_from_xyz_rpy(
            x, y, z, roll, pitch, yaw,
        ));
        tables.calibs.push(
            json!({"token": token(CALIB, i), "sensor_token": token(SENSOR, i),
            "translation": t, "rotation": q, "camera_intrinsic": []}),
        );
    }
}

/// The drive's scans by lap (laps without scans left empty).
fn scans_by_lap(drive: &SimDrive) -> Vec<Vec<&crate::sim::SimScan>> {
    let mut lap_scans: Vec<Vec<&crate::sim::SimScan>> = Vec::new();
    for s in &drive.scans {
        let lap = s.lap.lap;
        while lap_scans.len() <= lap {
            lap_scans.push(Vec::new());
        }
        lap_scans[lap].push(s);
    }
    lap_scans
}

/// The scene row of lap `k` and its sample rows (every 0.5 s over its scans); returns the scene's name
/// and its samples.
fn add_scene(
    k: usize,
    scans: &[&crate::sim::SimScan],
    tables: &mut Tables,
) -> (String, SceneSamples) {
    let (t0, t1) = (scans[0].scan.stamp, scans[scans.len() - 1].scan.stamp);
    // Samples every 0.5 s; sample j is keyed by the first scan of each radar at or after its time.
    let n_samples = ((t1.secs_since(t0) / 0.5).floor() as usize) + 1;
    let first_sample = tables.samples.len();
    let samples = SceneSamples {
        first: first_sample,
        count: n_samples,
        t0_us: us(t0),
    };
    for j in 0..n_samples {
        let idx = first_sample + j;
        tables.samples.push(
            json!({"token": token(SAMPLE, idx), "timestamp": samples.time(j),
            "scene_token": token(SCENE, k),
            "prev": if j == 0 { String::new() } else { token(SAMPLE, idx - 1) },
            "next": if j + 1 == n_samples { String::new() } else { token(SAMPLE, idx + 1) }}),
        );
    }
    let name = format!("scene-{:04}", k + 1);
    tables
        .scenes
        .push(json!({"token": token(SCENE, k), "log_token": token(LOG, 0),
        "nbr_samples": n_samples, "first_sample_token": token(SAMPLE, first_sample),
        "last_sample_token": token(SAMPLE, first_sample + n_samples - 1),
        "name": name, "description": format!("simulated lap {}", k + 1)}));
    (name, samples)
}

/// Writes the PCD file of each scan of a scene and adds its sample_data and ego_pose rows: the first
/// scan of each radar at or after a sample's time is that sample's keyframe, the others are sweeps of
/// the next sample. Returns the number of keyframes.
fn add_sweeps(
    drive: &SimDrive,
    dataroot: &Path,
    scans: &[&crate::sim::SimScan],
    samples: &SceneSamples,
    tables: &mut Tables,
) -> Result<usize, NuscenesExportError> {
    let n_samples = samples.count;
    let mut keyframes = 0;
    let mut next_key = [0usize; 5];
    for s in scans {
        let r = s.scan.radar;
        let ts = us(s.scan.stamp);
        // The sample this sweep belongs to: the next one at or after it (the last one at the end).
        let j = (0..n_samples)
            .find(|&j| samples.time(j) >= ts)
            .unwrap_or(n_samples - 1);
        let is_key = next_key[r] < n_samples && ts >= samples.time(next_key[r]);
        let sample_j = if is_key { next_key[r] } else { j };
        if is_key {
            while next_key[r] < n_samples && samples.time(next_key[r]) <= ts {
                next_key[r] += 1;
            }
            keyframes += 1;
        }
        let channel = RADAR_CHANNELS[r];
        let folder = if is_key { "samples" } else { "sweeps" };
        let filename = format!("{folder}/{channel}/{LOGFILE}__{channel}__{ts}.pcd");
        write(&dataroot.join(&filename), &pcd_bytes(s))?;
        let i = tables.data.len();
        let t_map_body = iso3_from_iso2(&drive.state_at(s.scan.stamp).t_map_body);
        let (t, q) = pose_json(&t_map_body);
        tables.egos.push(
            json!({"token": token(EGO, i), "timestamp": ts, "rotation": q, "translation": t}),
        );
        tables.data.push(
            json!({"token": token(DATA, i), "sample_token": token(SAMPLE, samples.first + sample_j),
            "ego_pose_token": token(EGO, i), "calibrated_sensor_token": token(CALIB, r),
            "timestamp": ts, "fileformat": "pcd", "is_key_frame": is_key, "height": 0, "width": 0,
            "filename": filename, "prev": "", "next": ""}),
        );
    }
    Ok(keyframes)
}

/// Writes each table as `<dir>/<table>.json`.
fn write_tables(dir: &Path, tables: Tables) -> Result<(), NuscenesExportError> {
    for (name, rows) in [
        ("sensor", tables.sensors),
        ("calibrated_sensor", tables.calibs),
        ("log", tables.logs),
        ("scene", tables.scenes),
        ("sample", tables.samples),
        ("sample_data", tables.data),
        ("ego_pose", tables.egos),
    ] {
        let text = serde_json::to_string_pretty(&Value::Array(rows)).unwrap_or_default();
        write(&dir.join(format!("{name}.json")), text.as_bytes())?;
    }
    Ok(())
}
