//! The keyframe map: compact keyframes, revisit candidates, and the map file.
//!
//! Entry points: [`KeyframeRecord`] ([`record`]), [`KeyframeDb`] ([`KeyframeDb::insert`],
//! [`KeyframeDb::candidates`], [`KeyframeDb::prepared`] with a bounded cache of registration-ready
//! submaps), [`KeyframeDb::save`] / [`KeyframeDb::load`] (the map file, [`file`], written crash-safely
//! by [`storage`], one writer at a time by [`lock`]), [`MapConfig`]. Ids are positions in the
//! database (local ids), so a loaded map keeps its ids and new keyframes continue after them; outside
//! the pipeline a keyframe is named by its robot and its id in that robot's own sequence
//! ([`KeyframeDb::public_id`]).

mod candidates;
pub mod file;
pub mod foreign;
pub mod lock;
pub mod record;
pub mod storage;

pub use candidates::{Candidate, CandidateQuery, CandidateSource, SearchSettings, SessionPrior};
pub use file::{
    MAP_FORMAT_VERSION, MapError, MapFile, MapShape, MapSnapshot, RadarMount, RecordV4,
    save_records, save_records_with, save_snapshot,
};
pub use foreign::{ForeignRefusal, Foreigners, Origin};
pub use record::{
    KeyframeRecord, POINT_QUANTUM, dequantise_cov, dequantise_point, dequantise_ray, quantise_cov,
    quantise_point, quantise_ray,
};

use crate::growing_index::GrowingIndex;
use crate::place::{PlaceConfig, PlaceDescriptor, PlaceIndex};
use crate::registration::{PreparedSubmap, RegistrationConfig, RegistrationError};
use crate::validate::Validator;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::path::Path;
use std::sync::Arc;

/// The keyframe map: where it is kept and how it is loaded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct MapConfig {
    /// Map file to load at start and save to (default empty: no persistence).
    pub file: String,
    /// Start with an empty map when the file exists but cannot be used (corrupt, other version); the
    /// file is then left untouched until the first save would replace it... which is refused: the new
    /// map goes to `<file>.new` instead (default false: refuse to start).
    pub start_empty_on_error: bool,
    /// Seconds between saves while keyframes are added (default 30; the node also saves at shutdown).
    pub save_interval: f64,
    /// Most points kept per keyframe (default 4000: stored quantised at 8 bytes a point, about 33 KB per
    /// keyframe with its descriptor).
    pub max_points_per_keyframe: usize,
    /// Registration-ready keyframes kept in memory (default 64).
    pub prepared_cache: usize,
    /// Most keyframes in the map, loaded ones included (default 10000: about 330 MB at 4000 points
    /// a keyframe). Once full, new keyframes still close loops against the map but are not added to
    /// it (counted as `map_full`): a robot that keeps driving known streets localises in the map it
    /// has, and its memory stays bounded.
    pub max_keyframes: usize,
    /// Most keyframes of one other robot in the map (default 2000: about 30 MB as they arrive over
    /// the wire); more from that robot are refused and counted as `over_budget` under its id.
    pub max_keyframes_per_robot: usize,
}

impl Default for MapConfig {
    fn default() -> Self {
        MapConfig {
            file: String::new(),
            start_empty_on_error: false,
            save_interval: 30.0,
            max_points_per_keyframe: 4000,
            prepared_cache: 64,
            max_keyframes: 10_000,
            max_keyframes_per_robot: 2000,
        }
    }
}

impl MapConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.positive("save_interval", self.save_interval);
        v.count(
            "max_points_per_keyframe",
            self.max_points_per_keyframe,
            10,
            100_000,
        );
        v.count("prepared_cache", self.prepared_cache, 1, 100_000);
        v.count("max_keyframes", self.max_keyframes, 1, 10_000_000);
        v.count(
            "max_keyframes_per_robot",
            self.max_keyframes_per_robot,
            0,
            10_000_000,
        );
    }
}

/// Records [`KeyframeDb::speed_at`] looks back over for the keyframe before (other robots' keyframes
/// interleave with a session's).
pub const SPEED_LOOKBACK: usize = 64;
/// Longest time between two keyframes over which [`KeyframeDb::speed_at`] gives their mean speed, s.
pub const SPEED_MAX_GAP: f64 = 10.0;

/// The keyframe database.
pub struct KeyframeDb {
    records: Vec<Arc<KeyframeRecord>>,
    /// Planar odometry positions by id.
    positions: GrowingIndex<2>,
    /// Place-descriptor columns by id ([`PlaceDescriptor::columns`]), for fast ranking.
    place_columns: Vec<Vec<u32>>,
    place: PlaceIndex,
    /// The settings that shaped the keyframes (stored with the map).
    shape: MapShape,
    cache: VecDeque<(usize, Arc<PreparedSubmap>)>,
    cache_size: usize,
    /// Other robots' keyframes: their origins and budgets.
    foreign: Foreigners,
    /// This robot's id and session (other robots' sessions get local numbers after it).
    owner: (i32, u32),
}

impl KeyframeDb {
    /// An empty database.
    pub fn new(place_cfg: PlaceConfig, cache_size: usize) -> Self {
        KeyframeDb {
            records: Vec::new(),
            positions: GrowingIndex::default(),
            place_columns: Vec::new(),
            place: PlaceIndex::default(),
            shape: MapShape {
                body_frame: String::new(),
                radars: Vec::new(),
                max_points_per_keyframe: 0,
                place: place_cfg,
            },
            cache: VecDeque::new(),
            cache_size: cache_size.max(1),
            foreign: Foreigners::default(),
            owner: (0, 0),
        }
    }

    /// Sets this robot's id and session: other robots' keyframes get sessions after it, and pairs with
    /// them are told apart from this robot's ([`KeyframeDb::registers_on_arrival`]).
    pub fn set_owner(&mut self, robot: i32, session: u32) {
        self.owner = (robot, session);
    }

    /// Other robots' keyframes held here.
    pub fn foreign(&self) -> &Foreigners {
        &self.foreign
    }

    /// Keyframe `id` as the fleet and the outputs name it: its robot and its id in that robot's own
    /// sequence. Another robot's keyframe keeps the id its robot gave it; this robot's keyframes
    /// (and those of its loaded map) are numbered in the order they were made, so the keyframes that
    /// arrived from other robots between them leave no gaps. A keyframe not in the map (the map was
    /// full) takes the id it would have had.
    pub fn public_id(&self, id: u64) -> (i32, u64) {
        match self.foreign.origin(id) {
            Some(o) => (o.robot, o.id),
            None => (self.owner.0, id - self.foreign.before(id)),
        }
    }

    /// Whether this node registers its keyframe `own` against another robot's keyframe `index`, which
    /// arrived after `own` was made: not when the other node held `own` when it made `index` (it
    /// registered the pair then); else, neither node having had the other's keyframe, when `own` is
    /// the newer of the two (by stamp, then robot id), so that exactly one of the two nodes does.
    pub fn registers_on_arrival(&self, own: &KeyframeRecord, index: usize) -> bool {
        let (Some(o), Some(r)) = (self.foreign.origin(index as u64), self.records.get(index))
        else {
            return false;
        };
        if self
            .foreign
            .heard(index as u64, self.owner.0)
            .is_some_and(|h| h >= self.public_id(own.id).1)
        {
            return false;
        }
        (own.stamp, self.owner.0) > (r.stamp, o.robot)
    }

    /// Whether this node registers its keyframe `own` against keyframe `index` of another session:
    /// always when `index` was in the map before `own` was made (ids follow the order of insertion;
    /// the other node never held `own` when it made `index`), else as
    /// [`KeyframeDb::registers_on_arrival`] decides. A search again of an older keyframe
    /// ([`crate::loop_closure::LoopCloser::backfill`]) thus leaves alone the pairs the other node
    /// registered.
    pub fn registers_pair(&self, own: &KeyframeRecord, index: usize) -> bool {
        (index as u64) < own.id || self.registers_on_arrival(own, index)
    }

    /// Adds another robot's keyframe (`rec.id` and `rec.session` are overwritten with the next id and
    /// the local session of its robot's session) within `max_per_robot` of that robot and
    /// `max_keyframes` in all, with what its node had `heard` of the others' keyframes then; its local
    /// id.
    pub fn insert_foreign(
        &mut self,
        mut rec: KeyframeRecord,
        origin: Origin,
        heard: Vec<(i32, u64)>,
        max_per_robot: usize,
        max_keyframes: usize,
    ) -> Result<u64, ForeignRefusal> {
        if self.foreign.holds(&origin, rec.stamp) {
            return Err(ForeignRefusal::Duplicate);
        }
        if self.foreign.count(origin.robot) >= max_per_robot {
            return Err(ForeignRefusal::OverBudget);
        }
        if self.len() >= max_keyframes {
            return Err(ForeignRefusal::MapFull);
        }
        let session = self.foreign.session(&origin).unwrap_or_else(|| {
            let last = self.last_session().unwrap_or(0);
            last.max(self.owner.1) + 1
        });
        rec.id = self.next_id();
        rec.session = session;
        let (id, stamp) = (rec.id, rec.stamp);
        if !self.insert(rec) {
            return Err(ForeignRefusal::Invalid);
        }
        self.foreign.record(id, session, stamp, origin);
        self.foreign.set_heard(id, heard);
        Ok(id)
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

    /// The odometry's mean speed on the way to `rec` from the keyframe of its session before it, m/s:
    /// path over time, looking back at most [`SPEED_LOOKBACK`] records; `None` for a session's first
    /// keyframe or after a gap of more than [`SPEED_MAX_GAP`] seconds.
    pub fn speed_at(&self, rec: &KeyframeRecord) -> Option<f64> {
        let end = usize::try_from(rec.id).map_or(self.records.len(), |i| i.min(self.records.len()));
        let before = self.records[..end]
            .iter()
            .rev()
            .take(SPEED_LOOKBACK)
            .find(|r| r.session == rec.session)?;
        let dt = rec.stamp.secs_since(before.stamp);
        (dt > 0.0 && dt <= SPEED_MAX_GAP).then(|| (rec.path_distance - before.path_distance) / dt)
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
            && let Some(entry) = self.cache.remove(pos)
        {
            let p = entry.1.clone();
            self.cache.push_back(entry);
            return Ok(p);
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

    /// A snapshot of the map for saving elsewhere (cheap: shared pointers).
    pub fn snapshot(&self) -> MapSnapshot {
        MapSnapshot {
            records: self.records.clone(),
            origins: self.foreign.origins().map(|(k, o)| (k, *o)).collect(),
        }
    }

    /// The settings that shaped the keyframes: as loaded from a map file, or as set.
    pub fn shape(&self) -> &MapShape {
        &self.shape
    }

    /// Records the settings that shape the keyframes added from now on (saved with the map).
    pub fn set_shape(&mut self, shape: MapShape) {
        self.shape = shape;
    }

    /// Writes the map file crash-safely (temporary file, sync, rename, directory sync).
    pub fn save(&self, path: &Path) -> Result<(), MapError> {
        save_snapshot(&self.snapshot(), &self.shape, path)
    }

    /// Reads and checks a map file. Place descriptors made with other settings than `place_cfg` are
    /// recomputed; [`KeyframeDb::shape`] is the file's.
    pub fn load(path: &Path, place_cfg: PlaceConfig, cache_size: usize) -> Result<Self, MapError> {
        let file = file::read_map(path)?;
        let origins: std::collections::BTreeMap<u64, Origin> = file.origins.into_iter().collect();
        let mut db = KeyframeDb::new(place_cfg.clone(), cache_size);
        let recompute = file.shape.place != place_cfg;
        if recompute {
            log::info!(
                "map file {}: place descriptors made with other `place.*` settings are recomputed",
                path.display()
            );
        }
        db.shape = MapShape {
            place: place_cfg.clone(),
            ..file.shape
        };
        for (k, mut rec) in file.keyframes.into_iter().enumerate() {
            if recompute {
                rec.place = PlaceDescriptor::from_points(&rec.planar_points(), &place_cfg);
            }
            let (session, stamp) = (rec.session, rec.stamp);
            if !db.insert(rec) {
                return Err(MapError::Corrupt {
                    path: path.display().to_string(),
                    reason: format!("keyframe {k} could not be indexed"),
                });
            }
            if let Some(o) = origins.get(&(k as u64)) {
                db.foreign.record(k as u64, session, stamp, *o);
            }
        }
        Ok(db)
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Iso2, Mat2, Stamp, Vec2};
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
            rays: pts.iter().map(|p| quantise_ray(&p.normalize())).collect(),
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

    /// A stored ray is within half a step (0.7 degrees) of the direction it stands for, across the
    /// wrap at 180 degrees too.
    #[test]
    fn quantised_rays_keep_their_direction() {
        let mut rng = StdRng::seed_from_u64(4);
        for k in 0..2000 {
            let a: f64 = if k < 2 {
                [std::f64::consts::PI, -std::f64::consts::PI + 1e-12][k]
            } else {
                rng.random_range(-4.0..4.0)
            };
            let u = Vec2::new(a.cos(), a.sin());
            let back = dequantise_ray(quantise_ray(&u));
            assert!((back.norm() - 1.0).abs() < 1e-12);
            let angle = u.x * back.y - u.y * back.x;
            assert!(
                angle.abs() <= (std::f64::consts::PI / 256.0).sin() + 1e-12 && u.dot(&back) > 0.0,
                "{u:?} came back as {back:?}"
            );
        }
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

    /// Another robot's keyframes: each taken once, within its budget, in a session of its own after
    /// this robot's, kept with their origin by a save and a load; a pair is registered on arrival
    /// only by the node whose keyframe is newer and when the other node did not hold it.
    #[test]
    fn other_robots_keyframes_are_kept_once_within_budget() {
        let mut rng = StdRng::seed_from_u64(3);
        let mut db = KeyframeDb::new(PlaceConfig::default(), 4);
        db.set_owner(1, 0);
        let mut own = record(0, 0, 0.0, &mut rng);
        own.stamp = Stamp::from_secs_f64(100.0);
        assert!(db.insert(own.clone()));
        let origin = |id| Origin {
            robot: 7,
            session: 4,
            id,
        };
        let theirs = |id: u64, t: f64, rng: &mut StdRng| {
            let mut r = record(0, 0, 3.0, rng);
            r.stamp = Stamp::from_secs_f64(t);
            (r, origin(id))
        };
        let (r, o) = theirs(30, 90.0, &mut rng);
        assert_eq!(db.insert_foreign(r.clone(), o, vec![], 2, 100), Ok(1));
        assert_eq!(
            db.get(1).unwrap().session,
            1,
            "a session after this robot's"
        );
        assert_eq!(
            db.insert_foreign(r, o, vec![], 2, 100),
            Err(ForeignRefusal::Duplicate)
        );
        assert!(db.registers_on_arrival(&own, 1), "own keyframe is newer");
        let (r, o) = theirs(31, 110.0, &mut rng);
        assert_eq!(db.insert_foreign(r, o, vec![], 2, 100), Ok(2));
        assert!(!db.registers_on_arrival(&own, 2), "theirs is newer");
        let (r, o) = theirs(32, 95.0, &mut rng);
        assert_eq!(
            db.insert_foreign(r.clone(), o, vec![(1, 0)], 2, 100),
            Err(ForeignRefusal::OverBudget)
        );
        assert_eq!(db.insert_foreign(r, o, vec![(1, 0)], 3, 100), Ok(3));
        assert!(!db.registers_on_arrival(&own, 3), "their node held ours");
        // The same pairs, searched again later from `own`: only the first is this node's; a
        // keyframe of theirs that was here before a newer own keyframe was made is that one's.
        let pairs: Vec<bool> = (1..4).map(|i| db.registers_pair(&own, i)).collect();
        assert_eq!(pairs, [true, false, false]);
        let mut newer = record(4, 0, 0.0, &mut rng);
        newer.stamp = Stamp::from_secs_f64(80.0);
        assert!((1..4).all(|i| db.registers_pair(&newer, i)));
        assert_eq!(db.foreign().newest(), vec![(7, 32)]);
        // Outside, each keyframe is named in its robot's own sequence: this robot's second keyframe
        // is its 1 though three of robot 7's came between; what robot 7's node heard of this robot
        // is in those names too.
        let mut second = record(4, 0, 0.0, &mut rng);
        second.stamp = Stamp::from_secs_f64(120.0);
        assert!(db.insert(second.clone()));
        let names: Vec<(i32, u64)> = (0..6).map(|i| db.public_id(i)).collect();
        assert_eq!(names, [(1, 0), (7, 30), (7, 31), (7, 32), (1, 1), (1, 2)]);
        let (r, o) = theirs(33, 115.0, &mut rng);
        assert_eq!(db.insert_foreign(r, o, vec![(1, 1)], 10, 100), Ok(5));
        assert!(
            !db.registers_on_arrival(&second, 5),
            "their node held our keyframe 1"
        );
        let path = scratch("foreign");
        db.save(&path).unwrap();
        let back = KeyframeDb::load(&path, PlaceConfig::default(), 4).unwrap();
        assert_eq!(back.len(), 6);
        assert_eq!(back.foreign().origin(2), Some(&origin(31)));
        assert_eq!(back.foreign().origin(0), None);
        assert_eq!(back.foreign().count(7), 4);
        assert_eq!(back.public_id(4).1, 1, "a loaded map keeps the names");
        let _ = std::fs::remove_file(&path);
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
                vouched: false,
                others: &[],
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

    /// `n` keyframes of session 0 along x every 5 m of path, all with y = 0.
    fn straight_pass(n: u64, rng: &mut StdRng) -> KeyframeDb {
        let mut db = KeyframeDb::new(PlaceConfig::default(), 4);
        for id in 0..n {
            let mut r = record(id, 0, 5.0 * id as f64, rng);
            r.t_odom_body = Iso2::new(Vec2::new(5.0 * id as f64, 0.0), 0.0);
            r.path_distance = 5.0 * id as f64;
            assert!(db.insert(r));
        }
        db
    }

    #[test]
    fn drift_radius_grows_with_path_and_min_gap_holds() {
        let mut rng = StdRng::seed_from_u64(3);
        let db = straight_pass(200, &mut rng);
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
            vouched: false,
            others: &[],
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

    /// The way back on the other carriageway's outer lane of a six-lane road whose first pass
    /// ([`straight_pass`]) drove the outer lane at y = 0: 2 x 2.5 lanes x 3.75 m = 18.75 m to the side of
    /// keyframe 50, just after a closure aligned the session (odometry far off, the alignment exact).
    fn way_back_beside_keyframe_50(rng: &mut StdRng) -> (KeyframeRecord, Iso2) {
        let mut q = record(100, 0, 0.0, rng);
        q.t_odom_body = Iso2::new(
            Vec2::new(250.0 + 300.0, 18.75 + 200.0),
            std::f64::consts::PI,
        );
        q.path_distance = 1000.0;
        (q, Iso2::new(Vec2::new(-300.0, -200.0), 0.0))
    }

    /// The keyframe indices of each candidate round for `q` under `alignment` (accepted at the
    /// query's own path length), checking that the first round is what [`KeyframeDb::candidates`]
    /// returns.
    fn rounds_of_ids(
        db: &KeyframeDb,
        q: &KeyframeRecord,
        alignment: Iso2,
        s: &SearchSettings,
        vouched: bool,
    ) -> Vec<Vec<usize>> {
        let cq = CandidateQuery {
            query: q,
            alignment: Some((alignment, q.path_distance)),
            vouched,
            others: &[],
        };
        let ids = |r: &[Candidate]| -> Vec<usize> { r.iter().map(|c| c.index).collect() };
        let rounds: Vec<Vec<usize>> = db
            .candidate_rounds(&cq, 0, s)
            .iter()
            .map(|r| ids(r))
            .collect();
        assert_eq!(rounds[0], ids(&db.candidates(&cq, 0, s)));
        rounds
    }

    #[test]
    fn right_after_a_closure_the_default_search_reaches_the_other_carriageway() {
        let mut rng = StdRng::seed_from_u64(5);
        let db = straight_pass(100, &mut rng);
        let (q, alignment) = way_back_beside_keyframe_50(&mut rng);
        let mut s = crate::loop_closure::LoopConfig::default().search();
        s.place_retrieve = 0;
        let found = rounds_of_ids(&db, &q, alignment, &s, true).remove(0);
        assert_eq!(found.first(), Some(&50), "{found:?}");
    }

    #[test]
    fn while_the_alignment_vouches_the_nearest_keyframes_take_all_slots_but_one() {
        let mut rng = StdRng::seed_from_u64(5);
        let db = straight_pass(100, &mut rng);
        let (mut q, alignment) = way_back_beside_keyframe_50(&mut rng);
        // It looks like keyframe 10, 200 m away.
        q.place = db.get(10).unwrap().place.clone();
        let s = crate::loop_closure::LoopConfig::default().search();
        assert_eq!(s.max_candidates, 4);
        let search = |vouched: bool| rounds_of_ids(&db, &q, alignment, &s, vouched).remove(0);
        // Not vouched: the nearest to the predicted position and the closest place descriptors
        // alternate.
        let free = search(false);
        assert_eq!(free[..3], [50, 10, 49], "{free:?}");
        // Vouched: the three nearest (49 and 51 equally near, the lower index first), then the
        // closest place descriptor.
        assert_eq!(search(true), [50, 49, 51, 10]);
    }

    #[test]
    fn while_the_alignment_vouches_later_rounds_hold_the_next_nearest_keyframes() {
        let mut rng = StdRng::seed_from_u64(5);
        let db = straight_pass(100, &mut rng);
        let (mut q, alignment) = way_back_beside_keyframe_50(&mut rng);
        q.place = db.get(10).unwrap().place.clone();
        let mut s = crate::loop_closure::LoopConfig::default().search();
        let rounds = |q: &KeyframeRecord, s: &SearchSettings, vouched: bool| {
            rounds_of_ids(&db, q, alignment, s, vouched)
        };
        // Not vouched: one round, the candidates of `candidates`.
        assert_eq!(rounds(&q, &s, false).len(), 1);
        // Vouched: the first round, then the next nearest to the predicted position, the place
        // candidate of the first round not repeated, as far as the search radius reaches (25 m:
        // keyframes 47 to 53 at 18.75 m beside the pass).
        assert_eq!(
            rounds(&q, &s, true),
            [vec![50, 49, 51, 10], vec![48, 52, 47, 53]]
        );
        // With a 40 m radius, keyframes 43 to 57 lie within it: three rounds at most.
        s.radius = 40.0;
        assert_eq!(
            rounds(&q, &s, true),
            [
                vec![50, 49, 51, 10],
                vec![48, 52, 47, 53],
                vec![46, 54, 45, 55]
            ]
        );
    }
    #[test]
    fn another_sessions_keyframes_near_where_an_alignment_to_it_puts_the_query_are_candidates() {
        let mut rng = StdRng::seed_from_u64(5);
        // Another robot's pass (session 1) along y = 0 of its own frame.
        let mut db = KeyframeDb::new(PlaceConfig::default(), 4);
        for id in 0..100 {
            let mut r = record(id, 1, 0.0, &mut rng);
            r.t_odom_body = Iso2::new(Vec2::new(5.0 * id as f64, 0.0), 0.0);
            r.path_distance = 5.0 * id as f64;
            assert!(db.insert(r));
        }
        // This robot (session 0) drives the other way 18.75 m beside that robot's keyframe 50; its
        // odometry frame lies 300 m and 200 m off the other's.
        let (q, alignment) = way_back_beside_keyframe_50(&mut rng);
        let mut s = crate::loop_closure::LoopConfig::default().search();
        s.place_retrieve = 0;
        let rounds = |others: &[SessionPrior]| -> Vec<Vec<usize>> {
            let cq = CandidateQuery {
                query: &q,
                alignment: None,
                vouched: false,
                others,
            };
            db.candidate_rounds(&cq, 0, &s)
                .iter()
                .map(|r| r.iter().map(|c| c.index).collect())
                .collect()
        };
        // Without an alignment to session 1, nothing but place descriptors finds its keyframes.
        assert_eq!(rounds(&[]), [Vec::<usize>::new()]);
        // With an accepted one found at the query's own path length, the nearest to the position it
        // predicts, round by round, as this session's own keyframes are under a vouching alignment.
        let prior = SessionPrior {
            session: 1,
            t: alignment,
            path: q.path_distance,
            vouched: true,
        };
        assert_eq!(rounds(&[prior]), [vec![50, 49, 51, 48], vec![52, 47, 53]]);
        // A held closure's alignment, which vouches for nothing: one round, the nearest first (the
        // place ranking, here among the same keyframes, takes every other slot).
        let held = SessionPrior {
            vouched: false,
            ..prior
        };
        let r = rounds(&[held]);
        assert_eq!((r.len(), r[0].len(), r[0][0]), (1, 4, 50), "{r:?}");
        // Found 400 m of path back, the search radius has grown by the drift over that path.
        let old = SessionPrior {
            path: q.path_distance - 400.0,
            ..prior
        };
        let reach = rounds(&[old]).concat().len();
        assert!(reach > 7, "{:?}", rounds(&[old]));
    }
}
