//! The keyframe database: compact keyframes, revisit candidates, and the map file.
//!
//! Entry points: [`KeyframeRecord`] (what is kept of a keyframe: planar pose, path length, the
//! compensated submap as planar points with 2x2 covariances, its place descriptor), [`KeyframeDb`]
//! ([`KeyframeDb::insert`], [`KeyframeDb::candidates`], [`KeyframeDb::prepared`] with a bounded cache of
//! registration-ready submaps), [`KeyframeDb::save`] / [`KeyframeDb::load`] (the map file), [`MapError`].
//!
//! Candidates come from two sources (see [`crate::pipeline::LoopConfig`]): keyframes of the current
//! session near the odometry position, within a radius that grows with the path driven since each
//! (a drift model), and keyframes of any session whose place descriptor is close, whatever the odometry
//! says. Ids are positions in the database, so a loaded map keeps its ids and new keyframes continue
//! after them.
//!
//! Map file: `DCLOCMAP` magic, a format version, a postcard payload ([`MapFile`]), and a CRC-32 of
//! everything before it. Written to a temporary file, synced, renamed over the old one and the directory
//! synced: a kill at any moment leaves the previous or the new map, never a partial one. A file that is
//! truncated, damaged, of another version or not a map at all is refused with a message saying which.

use crate::growing_index::GrowingIndex;
use crate::math::{Iso2, Mat2, Stamp, Vec2};
use crate::place::{PlaceConfig, PlaceDescriptor, PlaceIndex, column_distance};
use crate::registration::{PointSet2, PreparedSubmap, RegistrationConfig, RegistrationError};
use crate::submap::Submap;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::io::Write;
use std::path::Path;
use std::sync::Arc;

/// Map file magic.
const MAGIC: &[u8; 8] = b"DCLOCMAP";
/// Map file format version.
pub const MAP_FORMAT_VERSION: u32 = 2;

/// Stored point resolution, m (points are kept as `i16` multiples of it: +-327 m).
pub const POINT_QUANTUM: f64 = 0.01;
/// Smallest stored standard deviation, m (covariance axes are kept as 8-bit log2 codes from here).
const SIGMA_MIN: f64 = 0.001;
/// Codes per octave of a stored standard deviation (16: 4.4% steps, up to 62 m).
const SIGMA_STEPS_PER_OCTAVE: f64 = 16.0;

/// A point as stored (1 cm steps); `None` beyond +-327 m or when not finite.
pub fn quantise_point(p: Vec2) -> Option<[i16; 2]> {
    let q = |v: f64| {
        let k = (v / POINT_QUANTUM).round();
        (k.is_finite() && k.abs() <= f64::from(i16::MAX)).then_some(k as i16)
    };
    Some([q(p.x)?, q(p.y)?])
}

/// The point a stored code stands for.
pub fn dequantise_point(q: [i16; 2]) -> Vec2 {
    Vec2::new(
        f64::from(q[0]) * POINT_QUANTUM,
        f64::from(q[1]) * POINT_QUANTUM,
    )
}

/// A 2x2 covariance as stored: major and minor standard deviations as log2 codes (1 mm .. 62 m, 4.4%
/// steps, to the nearest step; smaller axes are stored as 1 mm) and the major axis
/// angle in steps of pi/256.
pub fn quantise_cov(c: &Mat2) -> [u8; 3] {
    let (a, b, d) = (c[(0, 0)], 0.5 * (c[(0, 1)] + c[(1, 0)]), c[(1, 1)]);
    let mean = 0.5 * (a + d);
    let half_diff = (0.25 * (a - d) * (a - d) + b * b).sqrt();
    let (l1, l2) = (mean + half_diff, (mean - half_diff).max(0.0));
    let theta = if half_diff > 0.0 {
        0.5 * (2.0 * b).atan2(a - d)
    } else {
        0.0
    };
    let code = |var: f64| {
        let sigma = var.max(0.0).sqrt().max(SIGMA_MIN);
        let k = (SIGMA_STEPS_PER_OCTAVE * (sigma / SIGMA_MIN).log2()).round();
        if k.is_finite() {
            k.clamp(0.0, 255.0) as u8
        } else {
            255
        }
    };
    let t = (theta.rem_euclid(std::f64::consts::PI) / (std::f64::consts::PI / 256.0)).round();
    [code(l1), code(l2), (t as u32 % 256) as u8]
}

/// The covariance a stored code stands for.
pub fn dequantise_cov(q: [u8; 3]) -> Mat2 {
    let sigma = |k: u8| SIGMA_MIN * (f64::from(k) / SIGMA_STEPS_PER_OCTAVE).exp2();
    let (s1, s2) = (sigma(q[0]), sigma(q[1]));
    let theta = f64::from(q[2]) * std::f64::consts::PI / 256.0;
    let (sn, cs) = theta.sin_cos();
    let r = Mat2::new(cs, -sn, sn, cs);
    r * Mat2::new(s1 * s1, 0.0, 0.0, s2 * s2) * r.transpose()
}

/// A keyframe as the database keeps it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KeyframeRecord {
    /// Id (position in the database).
    pub id: u64,
    /// Recording session (0 for the first drive of a map; each start of the node adds one).
    pub session: u32,
    /// Anchor stamp of its submap.
    pub stamp: Stamp,
    /// Odometry pose of the body at `stamp`, planar, in its session's odometry frame.
    pub t_odom_body: Iso2,
    /// Full 3D odometry pose (x, y, z, qx, qy, qz, qw), as published in closures.
    pub odom_pose: [f64; 7],
    /// Odometry path length of its session up to this keyframe, m.
    pub path_distance: f64,
    /// Compensated submap points (body frame at `stamp`), quantised ([`quantise_point`]).
    pub points: Vec<[i16; 2]>,
    /// Their covariances, quantised ([`quantise_cov`]).
    pub covs: Vec<[u8; 3]>,
    /// Place descriptor of the points.
    pub place: PlaceDescriptor,
}

impl KeyframeRecord {
    /// The compact form of a submap: compensated points and covariances, at most `max_points` of them
    /// (an even deterministic subsample when there are more).
    #[allow(clippy::too_many_arguments)]
    pub fn from_submap(
        id: u64,
        session: u32,
        submap: &Submap,
        path_distance: f64,
        max_points: usize,
        place: &PlaceConfig,
    ) -> Self {
        let set = submap.point_set(true);
        let n = set.len();
        let keep: Vec<usize> = if n <= max_points || max_points == 0 {
            (0..n).collect()
        } else {
            (0..max_points).map(|k| k * n / max_points).collect()
        };
        let mut points: Vec<[i16; 2]> = Vec::with_capacity(keep.len());
        let mut covs: Vec<[u8; 3]> = Vec::with_capacity(keep.len());
        for &i in &keep {
            if let Some(q) = quantise_point(set.points[i]) {
                points.push(q);
                covs.push(quantise_cov(&set.covs[i]));
            }
        }
        let planar: Vec<Vec2> = points.iter().map(|&q| dequantise_point(q)).collect();
        let t = submap.t_odom_anchor;
        let q = t.rotation.quaternion();
        KeyframeRecord {
            id,
            session,
            stamp: submap.anchor_stamp,
            t_odom_body: crate::math::iso2_from_iso3(&t),
            odom_pose: [
                t.translation.x,
                t.translation.y,
                t.translation.z,
                q.i,
                q.j,
                q.k,
                q.w,
            ],
            path_distance,
            points,
            covs,
            place: PlaceDescriptor::from_points(&planar, place),
        }
    }

    /// The points as registration input.
    pub fn point_set(&self) -> PointSet2 {
        PointSet2 {
            points: self.planar_points(),
            covs: self.covs.iter().map(|&c| dequantise_cov(c)).collect(),
        }
    }

    /// The points, m (body frame at `stamp`).
    pub fn planar_points(&self) -> Vec<Vec2> {
        self.points.iter().map(|&q| dequantise_point(q)).collect()
    }

    /// The 3D odometry pose.
    pub fn odom_pose_iso3(&self) -> crate::math::Iso3 {
        let [x, y, z, qx, qy, qz, qw] = self.odom_pose;
        crate::math::Iso3::from_parts(
            nalgebra::Translation3::new(x, y, z),
            crate::math::Quat::new_normalize(nalgebra::Quaternion::new(qw, qx, qy, qz)),
        )
    }

    /// Approximate bytes held (for the memory benchmark).
    pub fn heap_bytes(&self) -> usize {
        self.points.capacity() * 4
            + self.covs.capacity() * 3
            + self.place.grid.len()
            + std::mem::size_of::<Self>()
    }
}

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

/// Where a candidate came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CandidateSource {
    /// Near the (drift-tolerant) odometry position.
    Odometry,
    /// Close place descriptor.
    Place,
    /// Both.
    Both,
}

/// A revisit candidate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    /// Index (= id) in the database.
    pub index: usize,
    /// Where it came from.
    pub source: CandidateSource,
    /// Place-descriptor distance (0..1).
    pub place_distance: f64,
}

/// What a candidate search is given about the query.
#[derive(Debug, Clone, Copy)]
pub struct CandidateQuery<'a> {
    /// The query keyframe (not yet inserted).
    pub query: &'a KeyframeRecord,
    /// The current session's odometry-to-corrected alignment, if a closure gave one, and the path length
    /// at which it was found.
    pub alignment: Option<(Iso2, f64)>,
}

/// Candidate-search settings (a view of [`crate::pipeline::LoopConfig`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchSettings {
    /// Base radius, m.
    pub radius: f64,
    /// Radius growth per metre of path, m/m.
    pub drift_rate: f64,
    /// Largest radius, m.
    pub max_radius: f64,
    /// Fewest metres of path between the query and a same-session candidate.
    pub min_path_gap: f64,
    /// Place candidates retrieved by ring key.
    pub place_retrieve: usize,
    /// Largest place distance of a place candidate.
    pub place_max_distance: f64,
    /// Candidates returned at most.
    pub max_candidates: usize,
}

/// The keyframe database.
pub struct KeyframeDb {
    records: Vec<Arc<KeyframeRecord>>,
    /// Planar odometry positions by id.
    positions: GrowingIndex<2>,
    /// Place-descriptor columns by id ([`PlaceDescriptor::columns`]), for fast ranking.
    place_columns: Vec<Vec<u32>>,
    place: PlaceIndex,
    place_cfg: PlaceConfig,
    cache: VecDeque<(usize, Arc<PreparedSubmap>)>,
    cache_size: usize,
}

impl KeyframeDb {
    /// An empty database.
    pub fn new(place_cfg: PlaceConfig, cache_size: usize) -> Self {
        KeyframeDb {
            records: Vec::new(),
            positions: GrowingIndex::default(),
            place_columns: Vec::new(),
            place: PlaceIndex::default(),
            place_cfg,
            cache: VecDeque::new(),
            cache_size: cache_size.max(1),
        }
    }

    /// Number of keyframes.
    pub fn len(&self) -> usize {
        self.records.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.records.is_empty()
    }

    /// The keyframe with this id.
    pub fn get(&self, id: u64) -> Option<&KeyframeRecord> {
        self.records
            .get(usize::try_from(id).ok()?)
            .map(|r| r.as_ref())
    }

    /// All records, by id.
    pub fn records(&self) -> impl Iterator<Item = &KeyframeRecord> {
        self.records.iter().map(|r| r.as_ref())
    }

    /// The id the next keyframe gets.
    pub fn next_id(&self) -> u64 {
        self.records.len() as u64
    }

    /// Highest session in the database (`None` when empty).
    pub fn last_session(&self) -> Option<u32> {
        self.records.iter().map(|r| r.session).max()
    }

    /// Adds a record; its id must be [`KeyframeDb::next_id`] (else it is refused and `false` returned).
    pub fn insert(&mut self, rec: KeyframeRecord) -> bool {
        if rec.id != self.next_id() {
            return false;
        }
        let Ok(item) = u32::try_from(rec.id) else {
            return false;
        };
        let p = rec.t_odom_body.translation.vector;
        if !(p.x.is_finite() && p.y.is_finite()) {
            return false;
        }
        if self.positions.push([p.x, p.y]) != Some(self.records.len()) {
            return false;
        }
        self.place.insert(item, &rec.place);
        self.place_columns.push(rec.place.columns());
        self.records.push(Arc::new(rec));
        true
    }

    /// Revisit candidates for `q`, at most `max_candidates`: alternately the next nearest to the predicted
    /// position and the next closest place descriptor.
    pub fn candidates(
        &self,
        q: &CandidateQuery<'_>,
        session: u32,
        s: &SearchSettings,
    ) -> Vec<Candidate> {
        let query = q.query;
        let mut found: Vec<(usize, CandidateSource)> = Vec::new();
        let eligible = |r: &KeyframeRecord| {
            r.session != session || query.path_distance - r.path_distance >= s.min_path_gap
        };
        // 1. Odometry, drift-tolerant: |p_q - p_i| <= radius + drift_rate * (path_q - path_i), and, once a
        //    closure aligned this session, the same around the corrected position with the drift since then.
        let p = query.t_odom_body.translation.vector;
        let outer = (s.radius + s.drift_rate * query.path_distance.max(0.0)).min(s.max_radius);
        let corrected = q.alignment.map(|(a, path_a)| {
            let c = (a * nalgebra::Point2::from(p)).coords;
            (
                c,
                (s.radius + s.drift_rate * (query.path_distance - path_a).abs()).min(s.max_radius),
            )
        });
        let around = |centre: Vec2,
                      r: f64,
                      found: &mut Vec<(usize, CandidateSource)>,
                      drift_radius: bool| {
            let mut visit = |i: usize, d2: f64| {
                let Some(rec) = self.records.get(i) else {
                    return;
                };
                if rec.session != session || !eligible(rec) {
                    return;
                }
                if drift_radius {
                    let allowed = (s.radius
                        + s.drift_rate * (query.path_distance - rec.path_distance))
                        .min(s.max_radius);
                    if d2.sqrt() > allowed {
                        return;
                    }
                }
                found.push((i, CandidateSource::Odometry));
            };
            self.positions.within(&[centre.x, centre.y], r, &mut visit);
        };
        around(p, outer, &mut found, true);
        if let Some((c, r)) = corrected {
            around(c, r, &mut found, false);
        }
        // Only the odometry hits nearest the (corrected) predicted position are ranked further: a long
        // drive makes the drift radius hold hundreds of keyframes, and comparing place descriptors with
        // all of them would dominate the query (the place retrieval below still sees every keyframe).
        let keep = (4 * s.max_candidates).max(16);
        if found.len() > keep {
            let centre = corrected.map_or(p, |(c, _)| c);
            let d2 =
                |i: usize| (self.records[i].t_odom_body.translation.vector - centre).norm_squared();
            found.sort_by(|a, b| d2(a.0).total_cmp(&d2(b.0)).then(a.0.cmp(&b.0)));
            found.dedup_by_key(|f| f.0);
            found.truncate(keep);
        }
        // 2. Place descriptors, any session.
        for (item, _) in self.place.nearest(&query.place, s.place_retrieve) {
            let i = item as usize;
            if self.records.get(i).is_some_and(|r| eligible(r)) {
                found.push((i, CandidateSource::Place));
            }
        }
        found.sort_by_key(|f| f.0);
        let mut merged: Vec<(usize, CandidateSource)> = Vec::with_capacity(found.len());
        for (i, src) in found {
            match merged.last_mut() {
                Some(last) if last.0 == i => {
                    if last.1 != src {
                        last.1 = CandidateSource::Both;
                    }
                }
                _ => merged.push((i, src)),
            }
        }
        let query_columns = query.place.columns();
        let all: Vec<Candidate> = merged
            .into_iter()
            .filter_map(|(index, source)| {
                let place_distance = if query.place.sectors == self.records[index].place.sectors {
                    column_distance(&query_columns, &self.place_columns[index]).0
                } else {
                    1.0
                };
                let keep =
                    source != CandidateSource::Place || place_distance <= s.place_max_distance;
                keep.then_some(Candidate {
                    index,
                    source,
                    place_distance,
                })
            })
            .collect();
        // Two rankings, interleaved: odometry candidates nearest to the (corrected) predicted position
        // first (right when drift is small), and every candidate by place distance (right when the
        // odometry has drifted or the keyframe is another session's).
        let centre = corrected.map_or(p, |(c, _)| c);
        let metric = |i: usize| (self.records[i].t_odom_body.translation.vector - centre).norm();
        let mut by_position: Vec<&Candidate> = all
            .iter()
            .filter(|c| c.source != CandidateSource::Place)
            .collect();
        by_position.sort_by(|a, b| {
            metric(a.index)
                .total_cmp(&metric(b.index))
                .then(a.index.cmp(&b.index))
        });
        let mut by_place: Vec<&Candidate> = all.iter().collect();
        by_place.sort_by(|a, b| {
            a.place_distance
                .total_cmp(&b.place_distance)
                .then(a.index.cmp(&b.index))
        });
        let mut out: Vec<Candidate> = Vec::with_capacity(s.max_candidates);
        let (mut a, mut b) = (by_position.into_iter(), by_place.into_iter());
        while out.len() < s.max_candidates {
            let next = [a.next(), b.next()];
            if next.iter().all(Option::is_none) {
                break;
            }
            for c in next.into_iter().flatten() {
                if out.len() < s.max_candidates && !out.iter().any(|o| o.index == c.index) {
                    out.push(*c);
                }
            }
        }
        out
    }

    /// The registration-ready form of keyframe `index`, from a small cache (built on a miss, or when the
    /// cached one was prepared under other settings than `cfg`).
    pub fn prepared(
        &mut self,
        index: usize,
        cfg: &RegistrationConfig,
    ) -> Result<Arc<PreparedSubmap>, RegistrationError> {
        // A cached submap prepared under other settings is prepared again.
        if let Some(pos) = self
            .cache
            .iter()
            .position(|(i, p)| *i == index && p.fits(cfg))
        {
            if let Some(entry) = self.cache.remove(pos) {
                let p = entry.1.clone();
                self.cache.push_back(entry);
                return Ok(p);
            }
        }
        let rec = self
            .records
            .get(index)
            .ok_or_else(|| RegistrationError::Numerical(format!("no keyframe {index}")))?;
        let p = Arc::new(PreparedSubmap::new(rec.point_set(), cfg)?);
        self.put_prepared(index, p.clone());
        Ok(p)
    }

    /// Puts an already prepared submap into the cache (the pipeline prepares each new keyframe anyway).
    pub fn put_prepared(&mut self, index: usize, p: Arc<PreparedSubmap>) {
        self.cache.retain(|(i, _)| *i != index);
        self.cache.push_back((index, p));
        while self.cache.len() > self.cache_size {
            self.cache.pop_front();
        }
    }

    /// A snapshot of the records for saving elsewhere (cheap: shared pointers).
    pub fn snapshot(&self) -> Vec<Arc<KeyframeRecord>> {
        self.records.clone()
    }

    /// Writes the map file crash-safely (temporary file, sync, rename, directory sync).
    pub fn save(&self, path: &Path) -> Result<(), MapError> {
        save_records(&self.snapshot(), &self.place_cfg, path)
    }

    /// Reads a map file. Place descriptors made with other settings than `place_cfg` are recomputed.
    pub fn load(path: &Path, place_cfg: PlaceConfig, cache_size: usize) -> Result<Self, MapError> {
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
        let file: MapFile =
            postcard::from_bytes(&body[12..]).map_err(|e| corrupt(e.to_string()))?;
        let mut db = KeyframeDb::new(place_cfg.clone(), cache_size);
        let recompute = file.place != place_cfg;
        for (k, mut rec) in file.keyframes.into_iter().enumerate() {
            if rec.id != k as u64 || rec.points.len() != rec.covs.len() {
                return Err(corrupt(format!("keyframe {k} is inconsistent")));
            }
            if recompute {
                rec.place = PlaceDescriptor::from_points(&rec.planar_points(), &place_cfg);
            }
            if !db.insert(rec) {
                return Err(corrupt(format!("keyframe {k} could not be indexed")));
            }
        }
        Ok(db)
    }
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

impl std::fmt::Debug for KeyframeDb {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KeyframeDb")
            .field("keyframes", &self.records.len())
            .field("sessions", &self.last_session().map_or(0, |s| s + 1))
            .field("cached", &self.cache.len())
            .finish()
    }
}

/// Borrowing twin of [`MapFile`] for writing without copying the records.
#[derive(Serialize)]
struct MapFileRef<'a> {
    written_by: &'a str,
    place: &'a PlaceConfig,
    keyframes: Vec<&'a KeyframeRecord>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    fn record(id: u64, session: u32, x: f64, rng: &mut StdRng) -> KeyframeRecord {
        let pts: Vec<Vec2> = (0..300)
            .map(|_| Vec2::new(rng.random_range(-60.0..60.0), rng.random_range(-60.0..60.0)))
            .collect();
        let t = Iso2::new(Vec2::new(x, 0.5 * x), 0.1 * id as f64);
        KeyframeRecord {
            id,
            session,
            stamp: Stamp(1_000_000_000 * (id as i64 + 1)),
            t_odom_body: t,
            odom_pose: [
                x,
                0.5 * x,
                0.0,
                0.0,
                0.0,
                (0.05 * id as f64).sin(),
                (0.05 * id as f64).cos(),
            ],
            path_distance: 2.0 * id as f64,
            points: pts.iter().filter_map(|&p| quantise_point(p)).collect(),
            covs: pts
                .iter()
                .map(|_| quantise_cov(&Mat2::new(0.04, 0.001, 0.001, 0.09)))
                .collect(),
            place: PlaceDescriptor::from_points(&pts, &PlaceConfig::default()),
        }
    }

    fn db_with(n: u64) -> KeyframeDb {
        let mut rng = StdRng::seed_from_u64(7);
        let mut db = KeyframeDb::new(PlaceConfig::default(), 4);
        for id in 0..n {
            assert!(db.insert(record(id, (id / 5) as u32, 3.0 * id as f64, &mut rng)));
        }
        db
    }

    fn scratch(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("dc_loc_kfdb_{name}_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d.join("map.dcloc")
    }

    #[test]
    fn quantised_points_and_covariances_keep_the_mahalanobis_geometry() {
        let mut rng = StdRng::seed_from_u64(3);
        for _ in 0..2000 {
            let p = Vec2::new(
                rng.random_range(-300.0..300.0),
                rng.random_range(-300.0..300.0),
            );
            let back = dequantise_point(quantise_point(p).unwrap());
            assert!((back - p).abs().max() <= 0.5 * POINT_QUANTUM + 1e-12);
            // A random covariance with sigmas from 1 mm to 20 m and any orientation.
            let s1 = 0.02 * 1000f64.powf(rng.random_range(0.0..1.0));
            let s2 = s1 * rng.random_range(0.05..1.0);
            let th: f64 = rng.random_range(-3.2..3.2);
            let r = Mat2::new(th.cos(), -th.sin(), th.sin(), th.cos());
            let c = r * Mat2::new(s1 * s1, 0.0, 0.0, s2 * s2) * r.transpose();
            let cq = dequantise_cov(quantise_cov(&c));
            // Squared Mahalanobis lengths of random residuals agree within the step sizes (4.4% per
            // sigma, pi/256 in angle: the angle matters little for round ellipses, more for flat ones).
            let (ci, cqi) = (c.try_inverse().unwrap(), cq.try_inverse().unwrap());
            for _ in 0..4 {
                let e = Vec2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
                let (m, mq) = ((e.transpose() * ci * e)[0], (e.transpose() * cqi * e)[0]);
                let tol = 0.1 + 0.02 * s1 / s2;
                assert!((mq / m - 1.0).abs() < tol, "{m} vs {mq} for {c} / {cq}");
            }
        }
        assert_eq!(quantise_point(Vec2::new(400.0, 0.0)), None);
        assert_eq!(quantise_point(Vec2::new(f64::NAN, 0.0)), None);
        // Degenerate input stays usable: a zero covariance becomes the smallest stored circle.
        let z = dequantise_cov(quantise_cov(&Mat2::zeros()));
        assert!(z.try_inverse().is_some());
    }

    /// The cache hands out a prepared submap only for the settings it was prepared with.
    #[test]
    fn the_prepared_cache_follows_the_registration_settings() {
        let mut db = db_with(3);
        let cfg = RegistrationConfig::default();
        let a = db.prepared(1, &cfg).expect("prepared");
        let again = db.prepared(1, &cfg).expect("cached");
        assert!(Arc::ptr_eq(&a, &again), "same settings: the cached one");
        let mut other = cfg.clone();
        other.dense.surface_radius = 3.0;
        let b = db.prepared(1, &other).expect("prepared anew");
        assert!(!Arc::ptr_eq(&a, &b));
        assert!(b.fits(&other) && !b.fits(&cfg));
    }

    #[test]
    fn ids_must_follow_on() {
        let mut rng = StdRng::seed_from_u64(1);
        let mut db = KeyframeDb::new(PlaceConfig::default(), 4);
        assert!(!db.insert(record(1, 0, 0.0, &mut rng)));
        assert!(db.insert(record(0, 0, 0.0, &mut rng)));
        assert!(!db.insert(record(0, 0, 0.0, &mut rng)));
        assert_eq!(db.len(), 1);
    }

    #[test]
    fn save_load_round_trip_keeps_every_record_and_the_search() {
        let db = db_with(12);
        let path = scratch("roundtrip");
        db.save(&path).unwrap();
        let back = KeyframeDb::load(&path, PlaceConfig::default(), 4).unwrap();
        assert_eq!(back.len(), 12);
        for (a, b) in db.records().zip(back.records()) {
            assert_eq!(a, b);
        }
        assert_eq!(back.last_session(), Some(2));
        // The position index was rebuilt: a query near keyframe 7 finds it (another session).
        let mut rng = StdRng::seed_from_u64(99);
        let mut q = record(12, 3, 21.0, &mut rng);
        q.place = back.get(7).unwrap().place.clone();
        let s = SearchSettings {
            radius: 15.0,
            drift_rate: 0.0,
            max_radius: 15.0,
            min_path_gap: 0.0,
            place_retrieve: 3,
            place_max_distance: 1.0,
            max_candidates: 3,
        };
        let c = back.candidates(
            &CandidateQuery {
                query: &q,
                alignment: None,
            },
            3,
            &s,
        );
        assert_eq!(c.first().map(|c| c.index), Some(7), "{c:?}");
    }

    #[test]
    fn truncated_damaged_foreign_and_newer_files_are_refused() {
        let db = db_with(5);
        let path = scratch("refuse");
        db.save(&path).unwrap();
        let good = std::fs::read(&path).unwrap();
        for cut in [good.len() - 1, good.len() / 2, 13, 9] {
            std::fs::write(&path, &good[..cut]).unwrap();
            let e = KeyframeDb::load(&path, PlaceConfig::default(), 4).unwrap_err();
            assert!(matches!(e, MapError::Corrupt { .. }), "cut {cut}: {e}");
        }
        let mut flipped = good.clone();
        flipped[good.len() / 3] ^= 0x40;
        std::fs::write(&path, &flipped).unwrap();
        assert!(matches!(
            KeyframeDb::load(&path, PlaceConfig::default(), 4),
            Err(MapError::Corrupt { .. })
        ));
        std::fs::write(&path, b"PK\x03\x04 a zip file, not a map").unwrap();
        assert!(matches!(
            KeyframeDb::load(&path, PlaceConfig::default(), 4),
            Err(MapError::NotAMap(_))
        ));
        let mut newer = good.clone();
        newer[8..12].copy_from_slice(&(MAP_FORMAT_VERSION + 1).to_le_bytes());
        std::fs::write(&path, &newer).unwrap();
        let e = KeyframeDb::load(&path, PlaceConfig::default(), 4).unwrap_err();
        assert!(
            e.to_string()
                .contains(&format!("format version {}", MAP_FORMAT_VERSION + 1)),
            "{e}"
        );
        let missing = KeyframeDb::load(&path.with_extension("none"), PlaceConfig::default(), 4);
        assert!(matches!(missing, Err(MapError::Io { .. })));
    }

    #[test]
    fn a_save_replaces_the_old_map_whole_and_leaves_no_temporary_file() {
        let path = scratch("replace");
        db_with(3).save(&path).unwrap();
        db_with(9).save(&path).unwrap();
        let back = KeyframeDb::load(&path, PlaceConfig::default(), 4).unwrap();
        assert_eq!(back.len(), 9);
        let dir = path.parent().unwrap();
        let names: Vec<_> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
    }

    #[test]
    fn other_place_settings_are_recomputed_on_load() {
        let db = db_with(4);
        let path = scratch("place");
        db.save(&path).unwrap();
        let other = PlaceConfig {
            sectors: 30,
            ..PlaceConfig::default()
        };
        let back = KeyframeDb::load(&path, other.clone(), 4).unwrap();
        let r = back.get(2).unwrap();
        assert_eq!(
            r.place,
            PlaceDescriptor::from_points(&r.planar_points(), &other)
        );
        assert_ne!(r.place, db.get(2).unwrap().place);
    }

    #[test]
    fn drift_radius_grows_with_path_and_min_gap_holds() {
        let mut rng = StdRng::seed_from_u64(3);
        let mut db = KeyframeDb::new(PlaceConfig::default(), 4);
        // Keyframes along x every 5 m of path, all session 0, all with y = 0 (enough to build the tree).
        for id in 0..200u64 {
            let mut r = record(id, 0, 5.0 * id as f64, &mut rng);
            r.t_odom_body = Iso2::new(Vec2::new(5.0 * id as f64, 0.0), 0.0);
            r.path_distance = 5.0 * id as f64;
            assert!(db.insert(r));
        }
        // Query 60 m to the side of keyframe 0 after 1000 m of path: outside a fixed 15 m radius,
        // inside 15 m + 5 % of 1000 m.
        let mut q = record(200, 0, 0.0, &mut rng);
        q.t_odom_body = Iso2::new(Vec2::new(0.0, 60.0), 0.0);
        q.path_distance = 1000.0;
        let mut s = SearchSettings {
            radius: 15.0,
            drift_rate: 0.0,
            max_radius: 300.0,
            min_path_gap: 100.0,
            place_retrieve: 0,
            place_max_distance: 0.0,
            max_candidates: 100,
        };
        let cq = CandidateQuery {
            query: &q,
            alignment: None,
        };
        assert!(db.candidates(&cq, 0, &s).is_empty());
        s.drift_rate = 0.05;
        let ids: Vec<usize> = db.candidates(&cq, 0, &s).iter().map(|c| c.index).collect();
        // Keyframe k is at distance hypot(5k, 60) and allowed 15 + 0.05 (1000 - 5k).
        let expect: Vec<usize> = (0..200)
            .filter(|&k| {
                let d = (25.0 * (k * k) as f64 + 3600.0).sqrt();
                d <= 15.0 + 0.05 * (1000.0 - 5.0 * k as f64) && 1000.0 - 5.0 * k as f64 >= 100.0
            })
            .collect();
        assert!(expect.len() >= 3, "{expect:?}");
        let mut sorted = ids.clone();
        sorted.sort();
        assert_eq!(sorted, expect);
        assert_eq!(
            ids.first(),
            Some(&0),
            "nearest to the predicted position first"
        );
    }
}
