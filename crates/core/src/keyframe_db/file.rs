//! The map file: `DCLOCMAP` magic, a format version, a postcard payload ([`MapFile`]: the keyframes, the
//! settings that shaped them, [`MapShape`], and which keyframes other robots made, [`Origin`]), and a
//! CRC-32 of everything before it. It is written
//! crash-safely ([`super::storage`]). A file that is truncated, damaged, of another version or not a
//! map at all is refused with a message saying which; one that is intact but holds nonsense (a
//! non-finite pose, a session number out of range, a descriptor of another shape) is refused by
//! [`check_records`].

use std::path::Path;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::KeyframeRecord;
use super::foreign::Origin;
use super::storage::{Disk, write_atomically};
use crate::place::{PlaceConfig, RING_KEY_DIM};

/// Map file magic.
const MAGIC: &[u8; 8] = b"DCLOCMAP";
/// Map file format version written (versions 2, without [`MapShape`], 3, without origins, and 4,
/// without the points' rays, are still read).
pub const MAP_FORMAT_VERSION: u32 = 5;
/// Highest session number a map may hold (a node start adds one).
pub const MAX_SESSION: u32 = 1_000_000;

/// Why a map file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// Reading or writing failed.
    #[error("map file {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The error.
        source: std::io::Error,
    },
    /// Not a dc_loc map (wrong magic).
    #[error("map file {0}: not a dc_loc keyframe map")]
    NotAMap(String),
    /// Written by another, incompatible format version.
    #[error("map file {path}: format version {found}, this dc_loc reads versions 2 to {expected}")]
    Version {
        /// The file.
        path: String,
        /// Version in the file.
        found: u32,
        /// Version written.
        expected: u32,
    },
    /// Truncated, damaged, or intact but holding nonsense.
    #[error("map file {path}: corrupt ({reason})")]
    Corrupt {
        /// The file.
        path: String,
        /// What was found.
        reason: String,
    },
    /// Another process holds the map.
    #[error("map file {path}: {reason}")]
    Locked {
        /// The file.
        path: String,
        /// Who holds it.
        reason: String,
    },
}

/// Where a radar sat when the map's keyframes were made.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RadarMount {
    /// The radar's name.
    pub name: String,
    /// `radars.<name>.extrinsic`.
    pub extrinsic: [f64; 6],
    /// `radars.<name>.beta`, s.
    pub beta: f64,
}

/// The settings that shaped a map's keyframes, stored with them and compared on load.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapShape {
    /// `body_frame`: the frame of every keyframe's points.
    pub body_frame: String,
    /// The radars and their mounts.
    pub radars: Vec<RadarMount>,
    /// `map.max_points_per_keyframe` (0: not recorded).
    pub max_points_per_keyframe: usize,
    /// The place-descriptor settings the records are described with.
    #[serde(with = "stored_place")]
    pub place: PlaceConfig,
}

/// The place settings as every map file version stores them: `max_range`, `sectors` and a
/// candidate count that retrieval no longer reads, written as its old default so that files stay
/// readable both ways.
mod stored_place {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    use crate::place::PlaceConfig;

    /// The stored layout.
    #[derive(Serialize, Deserialize)]
    struct Stored {
        max_range: f64,
        sectors: usize,
        retrieve: usize,
    }

    /// The count written in the retired field.
    const RETRIEVE: usize = 25;

    pub fn serialize<S: Serializer>(place: &PlaceConfig, s: S) -> Result<S::Ok, S::Error> {
        Stored {
            max_range: place.max_range,
            sectors: place.sectors,
            retrieve: RETRIEVE,
        }
        .serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<PlaceConfig, D::Error> {
        let stored = Stored::deserialize(d)?;
        Ok(PlaceConfig {
            max_range: stored.max_range,
            sectors: stored.sectors,
        })
    }
}

impl MapShape {
    /// What a map made with other settings than `self` means, one note per difference; empty when
    /// the settings are the same.
    pub fn differences(&self, current: &MapShape) -> Vec<String> {
        let mut notes = Vec::new();
        if self.body_frame != current.body_frame && !self.body_frame.is_empty() {
            notes.push(format!(
                "its keyframes are in body frame `{}`, the configuration says `{}`",
                self.body_frame, current.body_frame
            ));
        }
        for old in &self.radars {
            match current.radars.iter().find(|r| r.name == old.name) {
                Some(new) if new == old => {}
                Some(new) => notes.push(format!(
                    "radar `{}` was mounted at {:?} (beta {}), now {:?} (beta {}): the stored points are in the body frame and are used as they are",
                    old.name, old.extrinsic, old.beta, new.extrinsic, new.beta
                )),
                None => notes.push(format!("radar `{}` is no longer configured", old.name)),
            }
        }
        if self.max_points_per_keyframe != 0
            && self.max_points_per_keyframe != current.max_points_per_keyframe
        {
            notes.push(format!(
                "keyframes were kept with at most {} points, now {}",
                self.max_points_per_keyframe, current.max_points_per_keyframe
            ));
        }
        notes
    }
}

/// The map file's payload.
#[derive(Debug, Serialize, Deserialize)]
pub struct MapFile {
    /// Program and version that wrote it.
    pub written_by: String,
    /// The settings that shaped the keyframes.
    pub shape: MapShape,
    /// The keyframes, by id.
    pub keyframes: Vec<KeyframeRecord>,
    /// The keyframes other robots made (by id), and where they came from.
    pub origins: Vec<(u64, Origin)>,
}

/// What a map file holds, shared with the map for saving on another thread.
#[derive(Debug, Clone, Default)]
pub struct MapSnapshot {
    /// The keyframes, by id.
    pub records: Vec<Arc<KeyframeRecord>>,
    /// The keyframes other robots made (by id), and where they came from.
    pub origins: Vec<(u64, Origin)>,
}

/// The payload of format version 4.
#[derive(Deserialize)]
struct MapFileV4 {
    written_by: String,
    shape: MapShape,
    keyframes: Vec<RecordV4>,
    origins: Vec<(u64, Origin)>,
}

/// The payload of format version 3.
#[derive(Deserialize)]
struct MapFileV3 {
    written_by: String,
    shape: MapShape,
    keyframes: Vec<RecordV4>,
}

/// The payload of format version 2.
#[derive(Deserialize)]
struct MapFileV2 {
    written_by: String,
    #[serde(with = "stored_place")]
    place: PlaceConfig,
    keyframes: Vec<RecordV4>,
}

/// A keyframe as format versions 2 to 4 stored it: no rays.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RecordV4 {
    id: u64,
    session: u32,
    stamp: crate::math::Stamp,
    t_odom_body: crate::math::Iso2,
    odom_pose: [f64; 7],
    path_distance: f64,
    points: Vec<[i16; 2]>,
    covs: Vec<[u8; 3]>,
    place: crate::place::PlaceDescriptor,
}

/// A keyframe in the older form, its rays left out (for writing maps of versions 2 to 4 in tests).
impl From<&KeyframeRecord> for RecordV4 {
    fn from(r: &KeyframeRecord) -> Self {
        RecordV4 {
            id: r.id,
            session: r.session,
            stamp: r.stamp,
            t_odom_body: r.t_odom_body,
            odom_pose: r.odom_pose,
            path_distance: r.path_distance,
            points: r.points.clone(),
            covs: r.covs.clone(),
            place: r.place.clone(),
        }
    }
}

impl From<RecordV4> for KeyframeRecord {
    fn from(r: RecordV4) -> Self {
        KeyframeRecord {
            id: r.id,
            session: r.session,
            stamp: r.stamp,
            t_odom_body: r.t_odom_body,
            odom_pose: r.odom_pose,
            path_distance: r.path_distance,
            points: r.points,
            covs: r.covs,
            rays: Vec::new(),
            place: r.place,
        }
    }
}

fn records(old: Vec<RecordV4>) -> Vec<KeyframeRecord> {
    old.into_iter().map(KeyframeRecord::from).collect()
}

/// Reads and checks a map file: magic, version, checksum, payload, content.
pub fn read_map(path: &Path) -> Result<MapFile, MapError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| MapError::Io {
        path: name.clone(),
        source,
    })?;
    let corrupt = |reason: String| MapError::Corrupt {
        path: name.clone(),
        reason,
    };
    if bytes.len() < 8 || &bytes[..8] != MAGIC {
        return Err(MapError::NotAMap(name));
    }
    if bytes.len() < 16 {
        return Err(corrupt(format!(
            "{} bytes, shorter than the header",
            bytes.len()
        )));
    }
    let version = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
    if !(2..=MAP_FORMAT_VERSION).contains(&version) {
        return Err(MapError::Version {
            path: name,
            found: version,
            expected: MAP_FORMAT_VERSION,
        });
    }
    let (body, crc) = bytes.split_at(bytes.len() - 4);
    let stored = u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]);
    if crc32fast::hash(body) != stored {
        return Err(corrupt(
            "checksum mismatch: the file is truncated or damaged".into(),
        ));
    }
    let payload = &body[12..];
    let file = if version == 2 {
        let v2: MapFileV2 = postcard::from_bytes(payload).map_err(|e| corrupt(e.to_string()))?;
        MapFile {
            written_by: v2.written_by,
            shape: MapShape {
                body_frame: String::new(),
                radars: Vec::new(),
                max_points_per_keyframe: 0,
                place: v2.place,
            },
            keyframes: records(v2.keyframes),
            origins: Vec::new(),
        }
    } else if version == 3 {
        let v3: MapFileV3 = postcard::from_bytes(payload).map_err(|e| corrupt(e.to_string()))?;
        MapFile {
            written_by: v3.written_by,
            shape: v3.shape,
            keyframes: records(v3.keyframes),
            origins: Vec::new(),
        }
    } else if version == 4 {
        let v4: MapFileV4 = postcard::from_bytes(payload).map_err(|e| corrupt(e.to_string()))?;
        MapFile {
            written_by: v4.written_by,
            shape: v4.shape,
            keyframes: records(v4.keyframes),
            origins: v4.origins,
        }
    } else {
        postcard::from_bytes(payload).map_err(|e| corrupt(e.to_string()))?
    };
    check_records(&file).map_err(corrupt)?;
    Ok(file)
}

/// The content of a map is usable: ids in order, finite poses with unit rotations, sessions and path
/// lengths in range, points with one covariance each, place descriptors of the stored shape.
pub fn check_records(file: &MapFile) -> Result<(), String> {
    let place = &file.shape.place;
    if !(8..=360).contains(&place.sectors) {
        return Err(format!("place descriptors of {} sectors", place.sectors));
    }
    for (k, r) in file.keyframes.iter().enumerate() {
        let bad = |what: &str| Err(format!("keyframe {k}: {what}"));
        if r.id != k as u64 {
            return bad(&format!("id {} out of order", r.id));
        }
        if r.session > MAX_SESSION {
            return bad(&format!("session {} beyond {MAX_SESSION}", r.session));
        }
        let t = r.t_odom_body;
        let pose_ok = t.translation.vector.iter().all(|v| v.is_finite())
            && t.rotation.angle().is_finite()
            && r.odom_pose.iter().all(|v| v.is_finite());
        let q = &r.odom_pose[3..];
        let q_norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !pose_ok || (q_norm - 1.0).abs() > 1e-3 {
            return bad("pose not finite or rotation not a unit quaternion");
        }
        if !(r.path_distance.is_finite() && r.path_distance >= 0.0) {
            return bad(&format!("path length {}", r.path_distance));
        }
        if r.points.len() != r.covs.len() {
            return bad("points and covariances differ in number");
        }
        if !(r.rays.is_empty() || r.rays.len() == r.points.len()) {
            return bad("points and rays differ in number");
        }
        if r.session == 0 && file.origins.iter().any(|(i, _)| *i == r.id) {
            return bad("another robot's keyframe in session 0, which is always this robot's");
        }
        let d = &r.place;
        if usize::from(d.sectors) != place.sectors
            || d.grid.len() != RING_KEY_DIM * place.sectors
            || !d.ring_key.iter().all(|v| v.is_finite())
        {
            return bad("place descriptor of another shape than the map's settings");
        }
    }
    let n = file.keyframes.len() as u64;
    if let Some((i, _)) = file.origins.iter().find(|(i, _)| *i >= n) {
        return Err(format!("origin of keyframe {i}, beyond the {n} keyframes"));
    }
    Ok(())
}

/// The bytes of a map file.
fn encode(map: &MapSnapshot, shape: &MapShape) -> Result<Vec<u8>, String> {
    let file = MapFileRef {
        written_by: concat!("dc_loc ", env!("CARGO_PKG_VERSION")),
        shape,
        keyframes: map.records.iter().map(|r| r.as_ref()).collect(),
        origins: &map.origins,
    };
    let payload = postcard::to_stdvec(&file).map_err(|e| e.to_string())?;
    let mut bytes = Vec::with_capacity(payload.len() + 16);
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&MAP_FORMAT_VERSION.to_le_bytes());
    bytes.extend_from_slice(&payload);
    let crc = crc32fast::hash(&bytes);
    bytes.extend_from_slice(&crc.to_le_bytes());
    Ok(bytes)
}

/// Writes a map crash-safely; usable from another thread with [`super::KeyframeDb::snapshot`].
pub fn save_snapshot(map: &MapSnapshot, shape: &MapShape, path: &Path) -> Result<(), MapError> {
    save_snapshot_with(&mut Disk, map, shape, path)
}

/// Writes this robot's records as a map file crash-safely.
pub fn save_records(
    records: &[Arc<KeyframeRecord>],
    shape: &MapShape,
    path: &Path,
) -> Result<(), MapError> {
    save_records_with(&mut Disk, records, shape, path)
}

/// [`save_records`] through the file-system steps of `storage`.
pub fn save_records_with(
    storage: &mut dyn super::storage::Storage,
    records: &[Arc<KeyframeRecord>],
    shape: &MapShape,
    path: &Path,
) -> Result<(), MapError> {
    let map = MapSnapshot {
        records: records.to_vec(),
        origins: Vec::new(),
    };
    save_snapshot_with(storage, &map, shape, path)
}

/// [`save_snapshot`] through the file-system steps of `storage`.
fn save_snapshot_with(
    storage: &mut dyn super::storage::Storage,
    map: &MapSnapshot,
    shape: &MapShape,
    path: &Path,
) -> Result<(), MapError> {
    let name = path.display().to_string();
    let bytes = encode(map, shape).map_err(|reason| MapError::Corrupt {
        path: name.clone(),
        reason,
    })?;
    write_atomically(storage, path, &bytes).map_err(|source| MapError::Io { path: name, source })
}

/// Borrowing twin of [`MapFile`] for writing without copying the records.
#[derive(Serialize)]
struct MapFileRef<'a> {
    written_by: &'a str,
    shape: &'a MapShape,
    keyframes: Vec<&'a KeyframeRecord>,
    origins: &'a [(u64, Origin)],
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The place settings keep their stored layout: three fields, the third read and ignored.
    #[test]
    fn place_settings_keep_their_stored_layout() {
        let shape = MapShape {
            body_frame: "base_link".into(),
            radars: Vec::new(),
            max_points_per_keyframe: 7,
            place: PlaceConfig {
                max_range: 50.0,
                sectors: 40,
            },
        };
        let bytes = postcard::to_stdvec(&shape).unwrap();
        #[derive(Deserialize)]
        struct Stored {
            body_frame: String,
            radars: Vec<RadarMount>,
            max_points_per_keyframe: usize,
            place: (f64, usize, usize),
        }
        let stored: Stored = postcard::from_bytes(&bytes).unwrap();
        assert_eq!(stored.body_frame, "base_link");
        assert!(stored.radars.is_empty());
        assert_eq!(stored.max_points_per_keyframe, 7);
        assert_eq!(stored.place, (50.0, 40, 25));
        let back: MapShape = postcard::from_bytes(&bytes).unwrap();
        assert_eq!(back, shape);
    }
}
