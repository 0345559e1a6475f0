//! nuScenes tables and radar sweeps as drives: one scene = one drive with ground truth.
//!
//! Entry points: [`NuscenesDb::open`] (reads the tables `log`, `scene`, `sample`, `sample_data`,
//! `ego_pose`, `calibrated_sensor`, `sensor` of `<dataroot>/<version>/`, streamed through a filter that
//! keeps only the radar rows of `sample_data` and the ego poses they reference), [`NuscenesScene`]
//! (every sweep of the five ARS408 radars of one scene, keyframes and the ~13 Hz sweeps between, with
//! its calibration and ego pose), [`SceneInputs`] (a scene as the runner's
//! [`Input`](dc_loc_core::input::Input) stream: ground truth and odometry from the ego poses, radar
//! clouds from the PCD files, read one sweep at a time), [`nuscenes_config`] (the pipeline configuration
//! of the five radars), [`RADAR_CHANNELS`]. Parts: `tables` (the tables into scenes), `inputs`.
//!
//! Frames: nuScenes' ego frame (rear-axle midpoint, x forward, y left, z up) is the body frame, the
//! global frame of a log's location the map frame. Quaternions are w, x, y, z; timestamps microseconds.

mod inputs;
mod tables;

pub use inputs::{OdometryDrift, SceneInputs};
pub use tables::pose_from_table;

use crate::sources::nuscenes_pcd::{PcdError, nuscenes_fields_config};
use dc_loc_core::math::{Iso3, Stamp};
use dc_loc_core::pipeline::Config;
use dc_loc_core::radar::RadarConfig;
use std::path::{Component, Path, PathBuf};
use tables::Loader;

/// The five radar channels, in the radar-index order of [`nuscenes_config`].
pub const RADAR_CHANNELS: [&str; 5] = [
    "RADAR_FRONT",
    "RADAR_FRONT_LEFT",
    "RADAR_FRONT_RIGHT",
    "RADAR_BACK_LEFT",
    "RADAR_BACK_RIGHT",
];

/// The tables read, in reading order.
pub const TABLES: [&str; 7] = [
    "sensor",
    "calibrated_sensor",
    "log",
    "scene",
    "sample",
    "sample_data",
    "ego_pose",
];

/// Why a nuScenes dataset could not be read. Every variant names the path, table or token at fault.
#[derive(Debug, thiserror::Error)]
pub enum NuscenesError {
    /// The data root is not a directory.
    #[error(
        "{0} is not a directory (give the nuScenes dataroot, the folder holding v1.0-*/, samples/, sweeps/)"
    )]
    NotADirectory(PathBuf),
    /// `<dataroot>/<version>` does not exist.
    #[error("no {version}/ in {dataroot} (versions found there: {available}){hint}")]
    VersionNotFound {
        /// The data root.
        dataroot: PathBuf,
        /// The version asked for.
        version: String,
        /// Version folders present, comma-separated (or `none`).
        available: String,
        /// A hint when the path looks like the version folder itself.
        hint: String,
    },
    /// A table file is missing.
    #[error("table `{table}` is missing: {path} does not exist")]
    MissingTable {
        /// Table name.
        table: &'static str,
        /// Expected file.
        path: PathBuf,
    },
    /// A table file could not be read or parsed.
    #[error("table `{table}` ({path}): {message}")]
    Table {
        /// Table name.
        table: &'static str,
        /// The file.
        path: PathBuf,
        /// The parser's or OS message.
        message: String,
    },
    /// A row refers to a token that is not in the referenced table.
    #[error("table `{table}` row {row}: `{field}` {token} is not in the referenced table")]
    DanglingToken {
        /// Table of the row.
        table: &'static str,
        /// The row's own token.
        row: String,
        /// The field holding the reference.
        field: &'static str,
        /// The missing token.
        token: String,
    },
    /// The tables list no radar sensor.
    #[error("table `sensor` lists none of the radar channels {RADAR_CHANNELS:?}")]
    NoRadar,
    /// A sweep's PCD file is missing or unreadable.
    #[error(
        "sweep file {path} (sample_data {token}) cannot be read: {source}. Is this part of the dataset \
         downloaded and extracted into the dataroot, and does --version match the files?"
    )]
    MissingSweep {
        /// The file.
        path: PathBuf,
        /// The sample_data token.
        token: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// A sweep's file name leaves the data root (an absolute path, a `..`): the file is not opened.
    #[error(
        "sweep file name {filename:?} (sample_data {token}) leaves the dataroot (absolute or with \
         `..`): not opened"
    )]
    OutsideDataroot {
        /// The file name as the table gives it.
        filename: String,
        /// The sample_data token.
        token: String,
    },
    /// A sweep's PCD file does not parse.
    #[error("sweep file {path}: {source}")]
    Pcd {
        /// The file.
        path: PathBuf,
        /// The reader's error.
        source: PcdError,
    },
}

/// One radar sweep (one `sample_data` row of a radar channel).
#[derive(Debug, Clone, PartialEq)]
pub struct RadarSweep {
    /// Index into [`RADAR_CHANNELS`].
    pub channel: usize,
    /// Timestamp, microseconds since the epoch.
    pub timestamp_us: i64,
    /// A 2 Hz keyframe (`samples/`) rather than an intermediate sweep (`sweeps/`).
    pub is_key_frame: bool,
    /// File relative to the data root.
    pub filename: String,
    /// The `sample_data` token (for error messages).
    pub token: String,
    /// Radar pose in the ego frame (calibrated_sensor).
    pub t_ego_radar: Iso3,
    /// Ego pose in the global frame at the sweep time (ego_pose).
    pub t_global_ego: Iso3,
}

impl RadarSweep {
    /// The stamp (nanoseconds).
    pub fn stamp(&self) -> Stamp {
        Stamp(self.timestamp_us.saturating_mul(1000))
    }

    /// The sweep's file under `dataroot`; `None` when its name is empty, absolute or climbs out with
    /// `..` (a table's file name is data, never a way out of the dataset).
    pub fn path_in(&self, dataroot: &Path) -> Option<PathBuf> {
        let name = Path::new(&self.filename);
        let inside = name
            .components()
            .all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
        (inside && !self.filename.is_empty()).then(|| dataroot.join(name))
    }
}

/// One scene: its radar sweeps in time order.
#[derive(Debug, Clone, PartialEq)]
pub struct NuscenesScene {
    /// Scene token.
    pub token: String,
    /// Scene name (`scene-0061`).
    pub name: String,
    /// Scene description.
    pub description: String,
    /// The log's location (`singapore-onenorth`, `boston-seaport`, ...): poses of scenes at one location
    /// share one global frame.
    pub location: String,
    /// The log file name.
    pub logfile: String,
    /// Every radar sweep of the five channels, by timestamp.
    pub sweeps: Vec<RadarSweep>,
}

impl NuscenesScene {
    /// The radar extrinsics of the scene (first sweep of each channel), by channel index.
    pub fn extrinsics(&self) -> [Option<Iso3>; 5] {
        let mut out = [None; 5];
        for s in &self.sweeps {
            if let Some(slot) = out.get_mut(s.channel) {
                slot.get_or_insert(s.t_ego_radar);
            }
        }
        out
    }
}

/// Progress of [`NuscenesDb::open`]: bytes of the tables read so far and in all.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoadProgress {
    /// The table being read.
    pub table: &'static str,
    /// Bytes read over all tables.
    pub read: u64,
    /// Bytes of all tables.
    pub total: u64,
}

/// A nuScenes dataset's radar part: scenes with their sweeps.
#[derive(Debug, Clone)]
pub struct NuscenesDb {
    /// The data root.
    pub dataroot: PathBuf,
    /// The version folder (`v1.0-mini`, `v1.0-trainval`, ...).
    pub version: String,
    /// Scenes in the order of `scene.json`.
    pub scenes: Vec<NuscenesScene>,
}

impl NuscenesDb {
    /// Reads the tables of `<dataroot>/<version>/` (see the module documentation); `progress` is called as
    /// table bytes are read. PCD files are not opened here (see [`SceneInputs`]).
    pub fn open(
        dataroot: &Path,
        version: &str,
        progress: &mut dyn FnMut(LoadProgress),
    ) -> Result<NuscenesDb, NuscenesError> {
        if !dataroot.is_dir() {
            return Err(NuscenesError::NotADirectory(dataroot.to_path_buf()));
        }
        let dir = dataroot.join(version);
        if !dir.is_dir() {
            return Err(version_not_found(dataroot, version));
        }
        let scenes = Loader::new(dir, progress)?.scenes()?;
        Ok(NuscenesDb {
            dataroot: dataroot.to_path_buf(),
            version: version.to_string(),
            scenes,
        })
    }
}

/// The error for a missing version folder: the versions there are, and a hint when `dataroot` looks
/// like a version folder itself.
fn version_not_found(dataroot: &Path, version: &str) -> NuscenesError {
    let mut available: Vec<String> = std::fs::read_dir(dataroot)
        .map(|rd| {
            rd.filter_map(Result::ok)
                .filter(|e| e.path().is_dir())
                .filter_map(|e| e.file_name().to_str().map(str::to_string))
                .filter(|n| n.starts_with("v1.0") || n.starts_with("v0."))
                .collect()
        })
        .unwrap_or_default();
    available.sort();
    let hint = if dataroot.join("scene.json").is_file() {
        format!(
            " (hint: {} holds the tables itself: pass its parent as the dataroot)",
            dataroot.display()
        )
    } else {
        String::new()
    };
    NuscenesError::VersionNotFound {
        dataroot: dataroot.to_path_buf(),
        version: version.to_string(),
        available: if available.is_empty() {
            "none".into()
        } else {
            available.join(", ")
        },
        hint,
    }
}

/// The pipeline configuration of the five nuScenes radars on top of `base` (its non-radar sections
/// kept): radars `front`, `front_left`, `front_right`, `back_left`, `back_right` (radar index = position
/// in [`RADAR_CHANNELS`]), topic `/radar_<name>`, frame id `radar_<name>` (nuscenes2mcap's), radial
/// velocity from the raw `vx, vy` ([`nuscenes_fields_config`]), `beta` and noise from the base's first
/// radar (0.04 s, the paper's ARS408 value, by default). Extrinsics are those of `extrinsics` when given
/// (per scene, from calibrated_sensor), else the base radar of the same name's, else zero.
pub fn nuscenes_config(base: &Config, extrinsics: &[Option<Iso3>; 5]) -> Config {
    let template = base
        .radar_list()
        .first()
        .map(|(_, r)| (*r).clone())
        .unwrap_or_default();
    let mut cfg = base.clone();
    cfg.radar_names.clear();
    cfg.radars.clear();
    for (i, channel) in RADAR_CHANNELS.iter().enumerate() {
        let name = channel.trim_start_matches("RADAR_").to_ascii_lowercase();
        let old = base.radars.get(&name);
        let extrinsic = match extrinsics.get(i).copied().flatten() {
            Some(t) => {
                let (roll, pitch, yaw) = t.rotation.euler_angles();
                [
                    t.translation.x,
                    t.translation.y,
                    t.translation.z,
                    roll,
                    pitch,
                    yaw,
                ]
            }
            None => old.map_or([0.0; 6], |r| r.extrinsic),
        };
        let src = old.unwrap_or(&template);
        cfg.radars.insert(
            name.clone(),
            RadarConfig {
                topic: format!("/radar_{name}"),
                frame_id: format!("radar_{name}"),
                extrinsic,
                fields: nuscenes_fields_config(),
                ..src.clone()
            },
        );
        cfg.radar_names.push(name);
    }
    cfg
}
