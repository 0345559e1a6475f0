//! Any PCD file's header (format v0.7; v0.6 too), its packed binary records, and the records wrapped
//! into a `sensor_msgs/PointCloud2`.

use dc_loc_core::cloud::ScalarType;
use dc_loc_core::msgs::sensor_msgs::{PointCloud2, PointField};
use dc_loc_core::msgs::std_msgs::Header;
use std::path::PathBuf;

/// Why a PCD file could not be read. Variants name the header key, field or file at fault.
#[derive(Debug, thiserror::Error)]
pub enum PcdError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A reader error, with the file it came from.
    #[error("{path}: {source}")]
    InFile {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: Box<PcdError>,
    },
    /// No `DATA` line was found: the header is incomplete.
    #[error("PCD header has no DATA line")]
    NoDataLine,
    /// A header line is not UTF-8 text.
    #[error("PCD header line {line} is not text")]
    NotText {
        /// 1-based line number.
        line: usize,
    },
    /// A required header key is missing.
    #[error("PCD header has no {key} line")]
    MissingKey {
        /// The key (`FIELDS`, `SIZE`, `TYPE`, `WIDTH`, `HEIGHT`).
        key: &'static str,
    },
    /// A header value cannot be parsed.
    #[error("PCD header {key}: cannot parse `{value}`")]
    BadValue {
        /// The key.
        key: String,
        /// The offending value.
        value: String,
    },
    /// A per-field header line has the wrong number of entries.
    #[error("PCD header {key} has {found} entries, FIELDS has {expected}")]
    FieldCountMismatch {
        /// The key (`SIZE`, `TYPE`, `COUNT`).
        key: &'static str,
        /// Entries in FIELDS.
        expected: usize,
        /// Entries found.
        found: usize,
    },
    /// `POINTS` disagrees with `WIDTH * HEIGHT`.
    #[error("PCD header POINTS {points} != WIDTH {width} * HEIGHT {height}")]
    PointsMismatch {
        /// POINTS.
        points: usize,
        /// WIDTH.
        width: usize,
        /// HEIGHT.
        height: usize,
    },
    /// A header size does not fit in memory addresses.
    #[error("PCD header sizes overflow")]
    SizeOverflow,
    /// Only `DATA binary` is read.
    #[error("PCD DATA `{0}` is not supported (only `binary`)")]
    UnsupportedData(String),
    /// A field type/size pair that has no PointField datatype (e.g. `F 2`, `I 8`).
    #[error("PCD field `{name}` has unsupported TYPE {kind} SIZE {size}")]
    UnsupportedType {
        /// Field name.
        name: String,
        /// TYPE letter.
        kind: char,
        /// SIZE, bytes.
        size: usize,
    },
    /// A field the nuScenes reader needs is missing.
    #[error("PCD has no field `{0}`")]
    MissingField(&'static str),
    /// A nuScenes field has another type than the standard one.
    #[error(
        "PCD field `{name}` is TYPE {kind} SIZE {size}, expected TYPE {expected_kind} SIZE {expected_size}"
    )]
    WrongFieldType {
        /// Field name.
        name: &'static str,
        /// TYPE found.
        kind: char,
        /// SIZE found.
        size: usize,
        /// TYPE expected.
        expected_kind: char,
        /// SIZE expected.
        expected_size: usize,
    },
    /// The data part is shorter than `POINTS` records.
    #[error("PCD data has {len} bytes, {points} points of {point_size} bytes need {needed}")]
    Truncated {
        /// Bytes present after the header.
        len: usize,
        /// POINTS.
        points: usize,
        /// Bytes per point.
        point_size: usize,
        /// Bytes needed.
        needed: usize,
    },
}

/// One field of a PCD header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PcdField {
    /// Name (FIELDS).
    pub name: String,
    /// Element size, bytes (SIZE).
    pub size: usize,
    /// Element type letter (TYPE): `F` float, `I` signed, `U` unsigned.
    pub kind: char,
    /// Elements (COUNT; 1 when the header has no COUNT line).
    pub count: usize,
    /// Byte offset within a packed binary record.
    pub offset: usize,
}

impl PcdField {
    /// The matching PointField scalar type, when there is one.
    pub fn scalar_type(&self) -> Option<ScalarType> {
        Some(match (self.kind, self.size) {
            ('F', 4) => ScalarType::F32,
            ('F', 8) => ScalarType::F64,
            ('I', 1) => ScalarType::I8,
            ('I', 2) => ScalarType::I16,
            ('I', 4) => ScalarType::I32,
            ('U', 1) => ScalarType::U8,
            ('U', 2) => ScalarType::U16,
            ('U', 4) => ScalarType::U32,
            _ => return None,
        })
    }
}

/// A parsed PCD header (format v0.7; v0.6 files without VIEWPOINT/POINTS are accepted too).
#[derive(Debug, Clone, PartialEq)]
pub struct PcdHeader {
    /// VERSION (empty when absent).
    pub version: String,
    /// Fields in record order, with their packed offsets.
    pub fields: Vec<PcdField>,
    /// WIDTH.
    pub width: usize,
    /// HEIGHT.
    pub height: usize,
    /// VIEWPOINT: tx ty tz qw qx qy qz (default 0 0 0 1 0 0 0).
    pub viewpoint: [f64; 7],
    /// POINTS (default WIDTH * HEIGHT).
    pub points: usize,
    /// DATA kind as written (`binary`, `ascii`, `binary_compressed`).
    pub data: String,
    /// Bytes per packed record (sum of SIZE * COUNT).
    pub point_size: usize,
    /// Byte offset of the data part in the file (just after the DATA line).
    pub data_offset: usize,
}

impl PcdHeader {
    /// Parses the header at the start of `bytes` (lines up to and including `DATA`). Comment lines
    /// (`#`) and unknown keys are skipped; keys may come in any order.
    pub fn parse(bytes: &[u8]) -> Result<PcdHeader, PcdError> {
        let mut pos = 0;
        let mut line_no = 0;
        let mut version = String::new();
        let mut names: Option<Vec<String>> = None;
        let mut sizes: Option<Vec<usize>> = None;
        let mut kinds: Option<Vec<char>> = None;
        let mut counts: Option<Vec<usize>> = None;
        let (mut width, mut height, mut points): (Option<usize>, Option<usize>, Option<usize>) =
            (None, None, None);
        let mut viewpoint = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        let data;
        loop {
            let rest = bytes.get(pos..).unwrap_or_default();
            if rest.is_empty() {
                return Err(PcdError::NoDataLine);
            }
            line_no += 1;
            let raw = rest.split(|&b| b == b'\n').next().unwrap_or_default();
            // Past the end after the last line; `get` above then yields an empty rest.
            pos += raw.len() + 1;
            let line = std::str::from_utf8(raw)
                .map_err(|_| PcdError::NotText { line: line_no })?
                .trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let (key, value) = line.split_once(char::is_whitespace).unwrap_or((line, ""));
            let value = value.trim();
            let words = || value.split_whitespace();
            match key {
                "VERSION" => version = value.to_string(),
                "FIELDS" | "COLUMNS" => names = Some(words().map(str::to_string).collect()),
                "SIZE" => sizes = Some(parse_list(key, words())?),
                "COUNT" => counts = Some(parse_list(key, words())?),
                "TYPE" => {
                    let k = words()
                        .map(|w| match w {
                            "F" | "I" | "U" => Ok(w.chars().next().unwrap_or('?')),
                            _ => Err(bad(key, w)),
                        })
                        .collect::<Result<Vec<char>, _>>()?;
                    kinds = Some(k);
                }
                "WIDTH" => width = Some(parse_one(key, value)?),
                "HEIGHT" => height = Some(parse_one(key, value)?),
                "POINTS" => points = Some(parse_one(key, value)?),
                "VIEWPOINT" => {
                    let v: Vec<f64> = parse_list(key, words())?;
                    viewpoint = v.try_into().map_err(|_| bad(key, value))?;
                }
                "DATA" => {
                    data = value.to_string();
                    break;
                }
                _ => {}
            }
        }
        let names = names.ok_or(PcdError::MissingKey { key: "FIELDS" })?;
        let sizes = sizes.ok_or(PcdError::MissingKey { key: "SIZE" })?;
        let kinds = kinds.ok_or(PcdError::MissingKey { key: "TYPE" })?;
        let counts = counts.unwrap_or_else(|| vec![1; names.len()]);
        for (key, found) in [
            ("SIZE", sizes.len()),
            ("TYPE", kinds.len()),
            ("COUNT", counts.len()),
        ] {
            if found != names.len() {
                return Err(PcdError::FieldCountMismatch {
                    key,
                    expected: names.len(),
                    found,
                });
            }
        }
        let width = width.ok_or(PcdError::MissingKey { key: "WIDTH" })?;
        let height = height.ok_or(PcdError::MissingKey { key: "HEIGHT" })?;
        let wh = width.checked_mul(height).ok_or(PcdError::SizeOverflow)?;
        let points = points.unwrap_or(wh);
        if points != wh {
            return Err(PcdError::PointsMismatch {
                points,
                width,
                height,
            });
        }
        let mut fields = Vec::with_capacity(names.len());
        let mut offset = 0usize;
        for (((name, size), kind), count) in names.into_iter().zip(sizes).zip(kinds).zip(counts) {
            fields.push(PcdField {
                name,
                size,
                kind,
                count,
                offset,
            });
            let bytes = size.checked_mul(count).ok_or(PcdError::SizeOverflow)?;
            offset = offset.checked_add(bytes).ok_or(PcdError::SizeOverflow)?;
        }
        Ok(PcdHeader {
            version,
            fields,
            width,
            height,
            viewpoint,
            points,
            data,
            point_size: offset,
            data_offset: pos,
        })
    }

    /// The field called `name`, if any (the first, should names repeat).
    pub fn field(&self, name: &str) -> Option<&PcdField> {
        self.fields.iter().find(|f| f.name == name)
    }

    /// The `POINTS` packed binary records of `bytes` (the whole file), trailing bytes ignored.
    pub fn binary_records<'a>(&self, bytes: &'a [u8]) -> Result<&'a [u8], PcdError> {
        if self.data != "binary" {
            return Err(PcdError::UnsupportedData(self.data.clone()));
        }
        let body = bytes.get(self.data_offset..).unwrap_or_default();
        let needed = self
            .points
            .checked_mul(self.point_size)
            .ok_or(PcdError::SizeOverflow)?;
        body.get(..needed).ok_or(PcdError::Truncated {
            len: body.len(),
            points: self.points,
            point_size: self.point_size,
            needed,
        })
    }
}

fn bad(key: &str, value: &str) -> PcdError {
    PcdError::BadValue {
        key: key.to_string(),
        value: value.to_string(),
    }
}

fn parse_one<T: std::str::FromStr>(key: &str, value: &str) -> Result<T, PcdError> {
    value.parse().map_err(|_| bad(key, value))
}

fn parse_list<'a, T: std::str::FromStr>(
    key: &str,
    words: impl Iterator<Item = &'a str>,
) -> Result<Vec<T>, PcdError> {
    words.map(|w| parse_one(key, w)).collect()
}

/// Wraps a binary PCD file's records into a `sensor_msgs/PointCloud2`, as the ROS1 nuscenes2bag variant
/// (pypcd `array_to_pointcloud2`) and nuscenes2mcap did: the header's fields in order with packed
/// offsets, TYPE/SIZE mapped to INT8/INT16/FLOAT32/..., `count` = COUNT, little-endian,
/// `point_step` = record size (43 for nuScenes radar), `row_step = width * point_step`, exactly `POINTS`
/// records of data. `is_dense` is false (not checked).
pub fn pcd_to_pointcloud2(bytes: &[u8], header: Header) -> Result<PointCloud2, PcdError> {
    let pcd = PcdHeader::parse(bytes)?;
    let records = pcd.binary_records(bytes)?;
    let mut fields = Vec::with_capacity(pcd.fields.len());
    for f in &pcd.fields {
        let kind = f.scalar_type().ok_or_else(|| PcdError::UnsupportedType {
            name: f.name.clone(),
            kind: f.kind,
            size: f.size,
        })?;
        fields.push(PointField {
            name: f.name.clone(),
            offset: u32::try_from(f.offset).map_err(|_| PcdError::SizeOverflow)?,
            datatype: kind.datatype(),
            count: u32::try_from(f.count).map_err(|_| PcdError::SizeOverflow)?,
        });
    }
    let to_u32 = |v: usize| u32::try_from(v).map_err(|_| PcdError::SizeOverflow);
    let point_step = to_u32(pcd.point_size)?;
    let width = to_u32(pcd.width)?;
    Ok(PointCloud2 {
        header,
        height: to_u32(pcd.height)?,
        width,
        fields,
        is_bigendian: false,
        point_step,
        row_step: width
            .checked_mul(point_step)
            .ok_or(PcdError::SizeOverflow)?,
        data: records.to_vec(),
        is_dense: false,
    })
}
