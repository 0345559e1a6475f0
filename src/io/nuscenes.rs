//! nuScenes tables and radar sweeps as drives: one scene = one drive with ground truth.
//!
//! Entry points: [`NuscenesDb::open`] (reads the tables `log`, `scene`, `sample`, `sample_data`,
//! `ego_pose`, `calibrated_sensor`, `sensor` of `<dataroot>/<version>/`), [`NuscenesScene`] (every radar
//! sweep of the five ARS408 radars of one scene, keyframes and the ~13 Hz sweeps in between, with its
//! calibration and ego pose), [`SceneInputs`] (a scene as the runner's [`Input`] stream: ground truth and
//! odometry from the ego poses, radar clouds from the PCD files), [`nuscenes_config`] (the pipeline
//! configuration of the five radars), [`RADAR_CHANNELS`].
//!
//! Memory: only radar rows of `sample_data` and the ego poses they reference are kept (the tables are
//! streamed through a filter, never held whole); PCD files are read one sweep at a time while a scene is
//! driven.
//!
//! Frames: nuScenes' ego frame (rear-axle midpoint, x forward, y left, z up) is the body frame; the
//! global frame of a log's location is the map frame. Quaternions in the tables are w, x, y, z.
//! Timestamps are microseconds since the epoch.

use crate::input::{Input, InputIssue, IssueReason};
use crate::io::nuscenes_pcd::{
    NuscenesRadarFilter, PcdError, filtered_pointcloud2, nuscenes_fields_config,
};
use crate::math::{Iso3, Quat, Stamp};
use crate::msgs::std_msgs::Header;
use crate::pipeline::Config;
use crate::radar::RadarConfig;
use serde::Deserialize;
use serde::de::{DeserializeOwned, DeserializeSeed, SeqAccess, Visitor};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::io::Read;
use std::path::{Path, PathBuf};

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
    /// A sweep's PCD file does not parse.
    #[error("sweep file {path}: {source}")]
    Pcd {
        /// The file.
        path: PathBuf,
        /// The reader's error.
        source: PcdError,
    },
}

#[derive(Deserialize)]
struct SensorRow {
    token: String,
    channel: String,
}

#[derive(Deserialize)]
struct CalibRow {
    token: String,
    sensor_token: String,
    translation: [f64; 3],
    rotation: [f64; 4],
}

#[derive(Deserialize)]
struct LogRow {
    token: String,
    #[serde(default)]
    location: String,
    #[serde(default)]
    logfile: String,
}

#[derive(Deserialize)]
struct SceneRow {
    token: String,
    name: String,
    log_token: String,
    #[serde(default)]
    description: String,
}

#[derive(Deserialize)]
struct SampleRow {
    token: String,
    scene_token: String,
}

#[derive(Deserialize)]
struct SampleDataRow {
    token: String,
    sample_token: String,
    ego_pose_token: String,
    calibrated_sensor_token: String,
    timestamp: i64,
    is_key_frame: bool,
    filename: String,
}

#[derive(Deserialize)]
struct EgoPoseRow {
    token: String,
    translation: [f64; 3],
    rotation: [f64; 4],
}

/// A pose from a nuScenes translation and w, x, y, z quaternion (normalised).
pub fn pose_from_table(translation: [f64; 3], rotation: [f64; 4]) -> Iso3 {
    let [w, x, y, z] = rotation;
    Iso3::from_parts(
        nalgebra::Translation3::new(translation[0], translation[1], translation[2]),
        Quat::new_normalize(nalgebra::Quaternion::new(w, x, y, z)),
    )
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

/// Counts bytes read and reports them.
struct Counting<'a, R> {
    inner: R,
    read: &'a mut u64,
    total: u64,
    table: &'static str,
    progress: &'a mut dyn FnMut(LoadProgress),
}

impl<R: Read> Read for Counting<'_, R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        *self.read += n as u64;
        (self.progress)(LoadProgress {
            table: self.table,
            read: *self.read,
            total: self.total,
        });
        Ok(n)
    }
}

/// A JSON array streamed through `keep`: rows that fail it are dropped as they are parsed.
struct Filter<'f, T, F> {
    keep: &'f mut F,
    _row: std::marker::PhantomData<T>,
}

impl<'de, T: DeserializeOwned, F: FnMut(&T) -> bool> Visitor<'de> for Filter<'_, T, F> {
    type Value = Vec<T>;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a JSON array of table rows")
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<T>, A::Error> {
        let mut out = Vec::new();
        while let Some(row) = seq.next_element::<T>()? {
            if (self.keep)(&row) {
                out.push(row);
            }
        }
        Ok(out)
    }
}

impl<'de, T: DeserializeOwned, F: FnMut(&T) -> bool> DeserializeSeed<'de> for Filter<'_, T, F> {
    type Value = Vec<T>;
    fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<Vec<T>, D::Error> {
        d.deserialize_seq(self)
    }
}

struct Loader<'a> {
    dir: PathBuf,
    read: u64,
    total: u64,
    progress: &'a mut dyn FnMut(LoadProgress),
}

impl Loader<'_> {
    fn path(dir: &Path, table: &str) -> PathBuf {
        dir.join(format!("{table}.json"))
    }

    fn table<T: DeserializeOwned>(
        &mut self,
        table: &'static str,
        mut keep: impl FnMut(&T) -> bool,
    ) -> Result<Vec<T>, NuscenesError> {
        let path = Self::path(&self.dir, table);
        let err = |message: String| NuscenesError::Table {
            table,
            path: path.clone(),
            message,
        };
        let file = std::fs::File::open(&path).map_err(|e| err(e.to_string()))?;
        let reader = std::io::BufReader::with_capacity(
            1 << 20,
            Counting {
                inner: file,
                read: &mut self.read,
                total: self.total,
                table,
                progress: &mut *self.progress,
            },
        );
        let mut de = serde_json::Deserializer::from_reader(reader);
        let rows = Filter {
            keep: &mut keep,
            _row: std::marker::PhantomData,
        }
        .deserialize(&mut de)
        .map_err(|e| err(e.to_string()))?;
        de.end().map_err(|e| err(e.to_string()))?;
        Ok(rows)
    }
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
            return Err(NuscenesError::VersionNotFound {
                dataroot: dataroot.to_path_buf(),
                version: version.to_string(),
                available: if available.is_empty() {
                    "none".into()
                } else {
                    available.join(", ")
                },
                hint,
            });
        }
        let mut total = 0;
        for table in TABLES {
            let path = Loader::path(&dir, table);
            match std::fs::metadata(&path) {
                Ok(m) if m.is_file() => total += m.len(),
                _ => return Err(NuscenesError::MissingTable { table, path }),
            }
        }
        let mut ld = Loader {
            dir,
            read: 0,
            total,
            progress,
        };

        // Radar sensors and their calibrations.
        let sensors: Vec<SensorRow> = ld.table("sensor", |s: &SensorRow| {
            RADAR_CHANNELS.contains(&s.channel.as_str())
        })?;
        if sensors.is_empty() {
            return Err(NuscenesError::NoRadar);
        }
        let channel_of: HashMap<String, usize> = sensors
            .iter()
            .filter_map(|s| {
                RADAR_CHANNELS
                    .iter()
                    .position(|c| *c == s.channel)
                    .map(|i| (s.token.clone(), i))
            })
            .collect();
        let calibs: HashMap<String, (usize, Iso3)> = ld
            .table("calibrated_sensor", |c: &CalibRow| {
                channel_of.contains_key(&c.sensor_token)
            })?
            .into_iter()
            .filter_map(|c| {
                channel_of
                    .get(&c.sensor_token)
                    .map(|&ch| (c.token, (ch, pose_from_table(c.translation, c.rotation))))
            })
            .collect();

        let logs: HashMap<String, LogRow> = ld
            .table("log", |_: &LogRow| true)?
            .into_iter()
            .map(|l| (l.token.clone(), l))
            .collect();
        let scene_rows: Vec<SceneRow> = ld.table("scene", |_: &SceneRow| true)?;
        let scene_of_sample: HashMap<String, String> = ld
            .table("sample", |_: &SampleRow| true)?
            .into_iter()
            .map(|s| (s.token, s.scene_token))
            .collect();
        let data: Vec<SampleDataRow> = ld.table("sample_data", |d: &SampleDataRow| {
            calibs.contains_key(&d.calibrated_sensor_token)
        })?;
        let needed: HashSet<&str> = data.iter().map(|d| d.ego_pose_token.as_str()).collect();
        let ego: HashMap<String, Iso3> = ld
            .table("ego_pose", |e: &EgoPoseRow| {
                needed.contains(e.token.as_str())
            })?
            .into_iter()
            .map(|e| (e.token, pose_from_table(e.translation, e.rotation)))
            .collect();
        drop(needed);

        // Rows are consumed (their strings moved, not copied) as the sweeps are built.
        let mut by_scene: BTreeMap<&str, Vec<RadarSweep>> = BTreeMap::new();
        for d in data {
            let dangling = |field, token: &str| NuscenesError::DanglingToken {
                table: "sample_data",
                row: d.token.clone(),
                field,
                token: token.to_string(),
            };
            let scene = scene_of_sample
                .get(&d.sample_token)
                .ok_or_else(|| dangling("sample_token", &d.sample_token))?;
            let &(channel, t_ego_radar) = calibs
                .get(&d.calibrated_sensor_token)
                .ok_or_else(|| dangling("calibrated_sensor_token", &d.calibrated_sensor_token))?;
            let t_global_ego = *ego
                .get(&d.ego_pose_token)
                .ok_or_else(|| dangling("ego_pose_token", &d.ego_pose_token))?;
            by_scene
                .entry(scene.as_str())
                .or_default()
                .push(RadarSweep {
                    channel,
                    timestamp_us: d.timestamp,
                    is_key_frame: d.is_key_frame,
                    filename: d.filename,
                    token: d.token,
                    t_ego_radar,
                    t_global_ego,
                });
        }
        drop(ego);
        let mut scenes = Vec::with_capacity(scene_rows.len());
        for s in scene_rows {
            let log = logs
                .get(&s.log_token)
                .ok_or_else(|| NuscenesError::DanglingToken {
                    table: "scene",
                    row: s.token.clone(),
                    field: "log_token",
                    token: s.log_token.clone(),
                })?;
            let mut sweeps = by_scene.remove(s.token.as_str()).unwrap_or_default();
            sweeps.sort_by_key(|w| (w.timestamp_us, w.channel));
            let sweeps = contiguous_part(&s.name, sweeps);
            scenes.push(NuscenesScene {
                token: s.token,
                name: s.name,
                description: s.description,
                location: log.location.clone(),
                logfile: log.logfile.clone(),
                sweeps,
            });
        }
        Ok(NuscenesDb {
            dataroot: dataroot.to_path_buf(),
            version: version.to_string(),
            scenes,
        })
    }
}

/// Longest gap between two sweeps of one scene, microseconds (a radar sweeps at ~13 Hz).
const MAX_SWEEP_GAP_US: i64 = 1_000_000;

/// The sweeps of a scene without a detached part: a non-keyframe sweep belongs to the sample that
/// follows it (schema.md), so sweeps recorded before a scene starts, after a gap in the log, can land in
/// it. The sweeps are split at gaps over [`MAX_SWEEP_GAP_US`] and the part with the most keyframes kept.
fn contiguous_part(scene: &str, sweeps: Vec<RadarSweep>) -> Vec<RadarSweep> {
    let mut parts: Vec<Vec<RadarSweep>> = Vec::new();
    for w in sweeps {
        match parts.last_mut() {
            Some(p)
                if p.last()
                    .is_some_and(|l| w.timestamp_us - l.timestamp_us <= MAX_SWEEP_GAP_US) =>
            {
                p.push(w)
            }
            _ => parts.push(vec![w]),
        }
    }
    if parts.len() > 1 {
        log::warn!(
            "{scene}: the radar sweeps fall into {} parts separated by more than {} s; the part with the most \
             keyframes is used",
            parts.len(),
            MAX_SWEEP_GAP_US as f64 * 1e-6
        );
    }
    parts
        .into_iter()
        .max_by_key(|p| (p.iter().filter(|w| w.is_key_frame).count(), p.len()))
        .unwrap_or_default()
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

/// Odometry error injected into the ego poses (all zero: perfect odometry).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OdometryDrift {
    /// Relative scale error of the distance driven (0.01: the odometry overestimates by 1 %).
    pub scale_error: f64,
    /// Yaw-rate bias, rad/s.
    pub yaw_rate_bias: f64,
}

/// A scene as an input stream: per sweep, in time order, the ground truth (ego pose, speed
/// from the neighbouring ego poses), the odometry (the ego poses with [`OdometryDrift`] integrated in)
/// and the radar cloud (the PCD records that pass the filter, as a PointCloud2 stamped with the sweep
/// time, frame id `radar_<channel>`). A missing or damaged PCD file is reported as an
/// [`InputIssue`] and skipped; the scene goes on.
pub struct SceneInputs<'a> {
    dataroot: &'a Path,
    scene: &'a NuscenesScene,
    filter: NuscenesRadarFilter,
    drift: OdometryDrift,
    next: usize,
    queue: std::collections::VecDeque<Result<Input, InputIssue>>,
    odom: Option<(Stamp, Iso3, Iso3)>,
    speeds: Vec<f64>,
}

impl<'a> SceneInputs<'a> {
    /// The inputs of `scene` with PCD files under `dataroot`.
    pub fn new(
        dataroot: &'a Path,
        scene: &'a NuscenesScene,
        filter: NuscenesRadarFilter,
        drift: OdometryDrift,
    ) -> Self {
        SceneInputs {
            dataroot,
            scene,
            filter,
            drift,
            next: 0,
            queue: Default::default(),
            odom: None,
            speeds: ego_speeds(&scene.sweeps),
        }
    }

    fn odometry(&mut self, stamp: Stamp, gt: Iso3) -> Option<Iso3> {
        let out = match self.odom {
            None => gt,
            Some((t0, _, _)) if stamp <= t0 => return None,
            Some((t0, gt0, od0)) => {
                let mut d = gt0.inverse() * gt;
                let dt = stamp.secs_since(t0);
                d.translation.vector *= 1.0 + self.drift.scale_error;
                d.rotation =
                    Quat::from_euler_angles(0.0, 0.0, self.drift.yaw_rate_bias * dt) * d.rotation;
                od0 * d
            }
        };
        self.odom = Some((stamp, gt, out));
        Some(out)
    }
}

/// Speed at each sweep from the ego poses about +-0.25 s around it (the ego poses of one instant come
/// from five radars within milliseconds, too close for a difference), m/s.
fn ego_speeds(sweeps: &[RadarSweep]) -> Vec<f64> {
    let n = sweeps.len();
    (0..n)
        .map(|i| {
            let t = sweeps[i].timestamp_us;
            let a = sweeps[..i]
                .iter()
                .rposition(|s| t - s.timestamp_us >= 250_000)
                .unwrap_or(0);
            let b = sweeps[i..]
                .iter()
                .position(|s| s.timestamp_us - t >= 250_000)
                .map_or(n - 1, |k| i + k);
            let (sa, sb) = (&sweeps[a], &sweeps[b]);
            let dt = (sb.timestamp_us - sa.timestamp_us) as f64 * 1e-6;
            if dt <= 0.0 {
                return 0.0;
            }
            (sb.t_global_ego.translation.vector - sa.t_global_ego.translation.vector).norm() / dt
        })
        .collect()
}

impl Iterator for SceneInputs<'_> {
    type Item = Result<Input, InputIssue>;

    fn next(&mut self) -> Option<Self::Item> {
        if let Some(i) = self.queue.pop_front() {
            return Some(i);
        }
        let sweep = self.scene.sweeps.get(self.next)?;
        let speed = self.speeds.get(self.next).copied().unwrap_or(0.0);
        self.next += 1;
        let channel = RADAR_CHANNELS
            .get(sweep.channel)
            .copied()
            .unwrap_or("RADAR");
        let stamp = sweep.stamp();
        if let Some(t_odom_body) = self.odometry(stamp, sweep.t_global_ego) {
            self.queue.push_back(Ok(Input::GroundTruth {
                stamp,
                t_map_body: sweep.t_global_ego,
                speed,
            }));
            self.queue
                .push_back(Ok(Input::Odometry { stamp, t_odom_body }));
        }
        let header = Header {
            stamp: stamp.into(),
            frame_id: channel.to_ascii_lowercase(),
        };
        let path = self.dataroot.join(&sweep.filename);
        let cloud = match std::fs::read(&path) {
            Err(source) => Err(NuscenesError::MissingSweep {
                path,
                token: sweep.token.clone(),
                source,
            }),
            Ok(bytes) => filtered_pointcloud2(&bytes, &self.filter, header)
                .map_err(|source| NuscenesError::Pcd { path, source }),
        };
        // A sweep that cannot be read is skipped and reported; the scene goes on.
        self.queue.push_back(match cloud {
            Ok(cloud) => Ok(Input::Radar {
                radar: sweep.channel,
                cloud,
            }),
            Err(e) => Err(InputIssue {
                topic: channel.to_string(),
                stamp,
                reason: IssueReason::Unreadable(e.to_string()),
            }),
        });
        self.queue.pop_front()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_from_table_reads_w_first() {
        // RADAR_BACK_LEFT of FORMATS.md: yaw +174.41 deg.
        let t = pose_from_table(
            [-0.562, 0.628, 0.53],
            [0.04876260733128922, 0.0, 0.0, 0.9988103964848657],
        );
        assert!((t.rotation.euler_angles().2.to_degrees() - 174.41).abs() < 0.01);
        assert_eq!(t.translation.x, -0.562);
    }

    #[test]
    fn sweeps_detached_from_the_scene_are_dropped() {
        let sweep = |t: i64, key: bool| RadarSweep {
            channel: 0,
            timestamp_us: t,
            is_key_frame: key,
            filename: String::new(),
            token: t.to_string(),
            t_ego_radar: Iso3::identity(),
            t_global_ego: Iso3::identity(),
        };
        // Two stray sweeps 60 s before the scene, then the scene with its keyframes.
        let mut v = vec![sweep(0, false), sweep(77_000, false)];
        v.extend((0..30).map(|k| sweep(60_000_000 + 77_000 * k, k % 7 == 0)));
        let kept = contiguous_part("scene-x", v);
        assert_eq!(kept.len(), 30);
        assert_eq!(kept[0].timestamp_us, 60_000_000);
    }

    #[test]
    fn drift_free_odometry_is_the_ego_pose_and_drift_grows() {
        let scene = NuscenesScene {
            token: "s".into(),
            name: "scene-x".into(),
            description: String::new(),
            location: "here".into(),
            logfile: "log".into(),
            sweeps: Vec::new(),
        };
        let root = Path::new(".");
        let mut inputs = SceneInputs::new(
            root,
            &scene,
            NuscenesRadarFilter::default(),
            OdometryDrift {
                scale_error: 0.1,
                yaw_rate_bias: 0.0,
            },
        );
        let p = |x: f64| crate::math::iso3_from_xyz_rpy(x, 0.0, 0.0, 0.0, 0.0, 0.0);
        assert_eq!(inputs.odometry(Stamp(0), p(5.0)), Some(p(5.0)));
        let o = inputs.odometry(Stamp(1_000_000_000), p(15.0)).unwrap();
        assert!((o.translation.x - 16.0).abs() < 1e-12);
        assert_eq!(inputs.odometry(Stamp(1_000_000_000), p(15.0)), None);
    }
}
