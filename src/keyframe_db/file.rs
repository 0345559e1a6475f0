//! The map file: `DCLOCMAP` magic, a format version, a postcard payload ([`MapFile`]), and a CRC-32 of
//! everything before it. Written to a temporary file, synced, renamed over the old one and the
//! directory synced: a kill at any moment leaves the previous or the new map, never a partial one. A
//! file that is truncated, damaged, of another version or not a map at all is refused with a message
//! saying which.

use std::io::Write;
use std::path::Path;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::KeyframeRecord;
use crate::place::PlaceConfig;

/// Map file magic.
const MAGIC: &[u8; 8] = b"DCLOCMAP";
/// Map file format version.
pub const MAP_FORMAT_VERSION: u32 = 2;

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
    #[error("map file {path}: format version {found}, this dc_loc reads version {expected}")]
    Version {
        /// The file.
        path: String,
        /// Version in the file.
        found: u32,
        /// Version supported.
        expected: u32,
    },
    /// Truncated or damaged (checksum or decoding failed).
    #[error("map file {path}: corrupt ({reason})")]
    Corrupt {
        /// The file.
        path: String,
        /// What was found.
        reason: String,
    },
}

/// The map file's payload.
#[derive(Debug, Serialize, Deserialize)]
pub struct MapFile {
    /// Program and version that wrote it.
    pub written_by: String,
    /// The place-descriptor settings the records were described with.
    pub place: PlaceConfig,
    /// The keyframes, by id.
    pub keyframes: Vec<KeyframeRecord>,
}

/// Reads and checks a map file: magic, version, checksum, payload.
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
    if version != MAP_FORMAT_VERSION {
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
    postcard::from_bytes(&body[12..]).map_err(|e| corrupt(e.to_string()))
}

/// Writes records as a map file crash-safely; usable from another thread with [`KeyframeDb::snapshot`].
pub fn save_records(
    records: &[Arc<KeyframeRecord>],
    place: &PlaceConfig,
    path: &Path,
) -> Result<(), MapError> {
    let name = path.display().to_string();
    let io = |source: std::io::Error| MapError::Io {
        path: name.clone(),
        source,
    };
    let file = MapFileRef {
        written_by: concat!("dc_loc ", env!("CARGO_PKG_VERSION")),
        place,
        keyframes: records.iter().map(|r| r.as_ref()).collect(),
    };
    let payload = postcard::to_stdvec(&file).map_err(|e| MapError::Corrupt {
        path: name.clone(),
        reason: e.to_string(),
    })?;
    let mut bytes = Vec::with_capacity(payload.len() + 16);
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&MAP_FORMAT_VERSION.to_le_bytes());
    bytes.extend_from_slice(&payload);
    let crc = crc32fast::hash(&bytes);
    bytes.extend_from_slice(&crc.to_le_bytes());
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(io)?;
    let file_name = path
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_else(|| "map".into());
    let tmp = dir.join(format!(".{file_name}.tmp-{}", std::process::id()));
    {
        let mut f = std::fs::File::create(&tmp).map_err(io)?;
        f.write_all(&bytes).map_err(io)?;
        f.sync_all().map_err(io)?;
    }
    std::fs::rename(&tmp, path).map_err(io)?;
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Borrowing twin of [`MapFile`] for writing without copying the records.
#[derive(Serialize)]
struct MapFileRef<'a> {
    written_by: &'a str,
    place: &'a PlaceConfig,
    keyframes: Vec<&'a KeyframeRecord>,
}
