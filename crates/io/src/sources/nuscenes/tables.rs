//! Reading the tables: each JSON array streamed through a row filter (only radar rows of `sample_data`
//! and the ego poses they reference are kept, the tables are never held whole), then the radar sweeps
//! built from the rows and grouped into scenes.

use super::{LoadProgress, NuscenesError, NuscenesScene, RADAR_CHANNELS, RadarSweep, TABLES};
use dc_loc_core::math::{Iso3, Quat};
use serde::Deserialize;
use serde::de::{DeserializeOwned, DeserializeSeed, SeqAccess, Visitor};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::io::Read;
use std::path::{Path, PathBuf};

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

pub(super) struct Loader<'a> {
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

/// Radar calibrations by calibrated_sensor token: channel index and radar pose in the ego frame.
type Calibrations = HashMap<String, (usize, Iso3)>;

impl<'a> Loader<'a> {
    /// A loader of the tables in `dir`; `MissingTable` names the first table file that is not there.
    pub(super) fn new(
        dir: PathBuf,
        progress: &'a mut dyn FnMut(LoadProgress),
    ) -> Result<Self, NuscenesError> {
        let mut total = 0;
        for table in TABLES {
            let path = Self::path(&dir, table);
            match std::fs::metadata(&path) {
                Ok(m) if m.is_file() => total += m.len(),
                _ => return Err(NuscenesError::MissingTable { table, path }),
            }
        }
        Ok(Loader {
            dir,
            read: 0,
            total,
            progress,
        })
    }
}

impl Loader<'_> {
    /// Reads the tables in [`TABLES`] order and builds the scenes, in the order of `scene.json`, each
    /// with its radar sweeps by timestamp.
    pub(super) fn scenes(&mut self) -> Result<Vec<NuscenesScene>, NuscenesError> {
        let calibs = self.radar_calibrations()?;
        let logs: HashMap<String, LogRow> = self
            .table("log", |_: &LogRow| true)?
            .into_iter()
            .map(|l| (l.token.clone(), l))
            .collect();
        let scene_rows: Vec<SceneRow> = self.table("scene", |_: &SceneRow| true)?;
        let scene_of_sample: HashMap<String, String> = self
            .table("sample", |_: &SampleRow| true)?
            .into_iter()
            .map(|s| (s.token, s.scene_token))
            .collect();
        let data: Vec<SampleDataRow> = self.table("sample_data", |d: &SampleDataRow| {
            calibs.contains_key(&d.calibrated_sensor_token)
        })?;
        let ego = self.ego_poses(&data)?;
        let by_scene = sweeps_by_scene(data, &scene_of_sample, &calibs, ego)?;
        assemble_scenes(scene_rows, &logs, by_scene)
    }

    /// The radar sensors and their calibrations; `NoRadar` when the sensor table lists none.
    fn radar_calibrations(&mut self) -> Result<Calibrations, NuscenesError> {
        let sensors: Vec<SensorRow> = self.table("sensor", |s: &SensorRow| {
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
        Ok(self
            .table("calibrated_sensor", |c: &CalibRow| {
                channel_of.contains_key(&c.sensor_token)
            })?
            .into_iter()
            .filter_map(|c| {
                channel_of
                    .get(&c.sensor_token)
                    .map(|&ch| (c.token, (ch, pose_from_table(c.translation, c.rotation))))
            })
            .collect())
    }

    /// The ego poses the radar rows of `data` reference, by token.
    fn ego_poses(
        &mut self,
        data: &[SampleDataRow],
    ) -> Result<HashMap<String, Iso3>, NuscenesError> {
        let needed: HashSet<&str> = data.iter().map(|d| d.ego_pose_token.as_str()).collect();
        Ok(self
            .table("ego_pose", |e: &EgoPoseRow| {
                needed.contains(e.token.as_str())
            })?
            .into_iter()
            .map(|e| (e.token, pose_from_table(e.translation, e.rotation)))
            .collect())
    }
}

/// The radar sweeps by scene token. Rows are consumed (their strings moved, not copied) as the sweeps
/// are built; a row whose sample, calibration or ego pose is not in its table is a `DanglingToken`.
fn sweeps_by_scene<'s>(
    data: Vec<SampleDataRow>,
    scene_of_sample: &'s HashMap<String, String>,
    calibs: &Calibrations,
    ego: HashMap<String, Iso3>,
) -> Result<BTreeMap<&'s str, Vec<RadarSweep>>, NuscenesError> {
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
    Ok(by_scene)
}

/// The scenes in table order, each with its log's location and its sweeps by timestamp (the contiguous
/// part, [`contiguous_part`]).
fn assemble_scenes(
    scene_rows: Vec<SceneRow>,
    logs: &HashMap<String, LogRow>,
    mut by_scene: BTreeMap<&str, Vec<RadarSweep>>,
) -> Result<Vec<NuscenesScene>, NuscenesError> {
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
    Ok(scenes)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_from_table_reads_w_first() {
        // RADAR_BACK_LEFT of the nuScenes calibration: yaw +174.41 deg.
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
}
