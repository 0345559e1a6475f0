//! The node's keyframe map on disk: loaded at start ([`load_map`]: one writer at a time, temporary
//! files of a killed writer removed, the content checked and the settings that shaped it compared),
//! saved every `map.save_interval` by a thread of its own and at shutdown ([`MapSaver`], whose last
//! result `/diagnostics` reports).

use std::path::{Path, PathBuf};
use std::sync::mpsc::SyncSender;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use dc_loc_core::keyframe_db::lock::MapLock;
use dc_loc_core::keyframe_db::storage::clean_temp_files;
use dc_loc_core::keyframe_db::{KeyframeDb, MapShape, MapSnapshot, save_snapshot};
use dc_loc_core::pipeline::Config;

/// The map a node starts with, and where it goes.
pub struct LoadedMap {
    /// The loaded (or empty) map, shaped by the current settings from now on.
    pub db: KeyframeDb,
    /// Where the map is saved (`None` without persistence).
    pub save_to: Option<PathBuf>,
    /// The lock on `save_to`, held while the node runs.
    pub lock: Option<MapLock>,
}

/// The map `map.file` holds (or an empty one), and where it is saved: `map.file`, or, when the file
/// was refused and `map.start_empty_on_error` allowed an empty start, the first of `<file>.new`,
/// `<file>.new.1`, ... that does not exist yet (a fallback session never replaces an earlier one).
/// A map file that cannot be used, or that another process holds, stops the start (the error says
/// why).
pub fn load_map(cfg: &Config) -> Result<LoadedMap, String> {
    let empty = || {
        let mut db = KeyframeDb::new(cfg.place.clone(), cfg.map.prepared_cache);
        db.set_shape(cfg.map_shape());
        db
    };
    if cfg.map.file.is_empty() {
        return Ok(LoadedMap {
            db: empty(),
            save_to: None,
            lock: None,
        });
    }
    let path = PathBuf::from(&cfg.map.file);
    let lock = lock(&path)?;
    if !path.exists() {
        log::info!(
            "map file {} does not exist yet: starting an empty map",
            path.display()
        );
        return Ok(LoadedMap {
            db: empty(),
            save_to: Some(path),
            lock: Some(lock),
        });
    }
    match KeyframeDb::load(&path, cfg.place.clone(), cfg.map.prepared_cache) {
        Ok(mut db) => {
            log::info!(
                "map file {}: {} keyframes loaded (sessions up to {:?})",
                path.display(),
                db.len(),
                db.last_session()
            );
            for note in db.shape().differences(&cfg.map_shape()) {
                log::warn!("map file {}: {note}", path.display());
            }
            db.set_shape(cfg.map_shape());
            Ok(LoadedMap {
                db,
                save_to: Some(path),
                lock: Some(lock),
            })
        }
        Err(e) if cfg.map.start_empty_on_error => {
            drop(lock);
            let new = fallback_path(&path);
            let lock = self::lock(&new)?;
            log::warn!(
                "{e}; starting with an empty map (map.start_empty_on_error), saving to {} and leaving the file untouched",
                new.display()
            );
            Ok(LoadedMap {
                db: empty(),
                save_to: Some(new),
                lock: Some(lock),
            })
        }
        Err(e) => Err(format!(
            "parameter `map.file`: {e}; refusing to start (set map.start_empty_on_error:=true to start with an empty map)"
        )),
    }
}

/// Takes the map's lock, then removes the temporary files a killed writer left behind.
fn lock(path: &Path) -> Result<MapLock, String> {
    let lock = MapLock::acquire(path).map_err(|e| format!("parameter `map.file`: {e}"))?;
    for tmp in clean_temp_files(path) {
        log::info!(
            "removed {}, left by a writer that did not finish",
            tmp.display()
        );
    }
    Ok(lock)
}

/// The first of `<file>.new`, `<file>.new.1`, `<file>.new.2`, ... that does not exist.
pub fn fallback_path(path: &Path) -> PathBuf {
    let base = format!("{}.new", path.display());
    std::iter::once(PathBuf::from(&base))
        .chain((1u32..).map(|k| PathBuf::from(format!("{base}.{k}"))))
        .find(|p| !p.exists())
        .unwrap_or_else(|| PathBuf::from(base))
}

/// The result of the newest map save.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SaveStatus {
    /// Saves attempted.
    pub saves: u64,
    /// The newest save's error, if it failed.
    pub last_error: Option<String>,
}

/// Saves the map periodically on a thread of its own (the worker only hands it a snapshot), and at
/// the end.
pub struct MapSaver {
    path: PathBuf,
    shape: MapShape,
    interval: f64,
    last_save: Instant,
    saved_keyframes: usize,
    tx: SyncSender<MapSnapshot>,
    thread: JoinHandle<()>,
    status: Arc<Mutex<SaveStatus>>,
}

impl MapSaver {
    /// A saver of the map to `path`, every `interval` seconds while keyframes are added; `db` is the
    /// map as loaded.
    pub fn new(path: PathBuf, shape: MapShape, interval: f64, db: &KeyframeDb) -> Self {
        let (tx, rx) = std::sync::mpsc::sync_channel::<MapSnapshot>(1);
        let status = Arc::new(Mutex::new(SaveStatus::default()));
        let (p, sh, st) = (path.clone(), shape.clone(), status.clone());
        let thread = std::thread::spawn(move || {
            for map in rx {
                save_map(&map, &sh, &p, &st);
            }
        });
        MapSaver {
            path,
            shape,
            interval,
            last_save: Instant::now(),
            saved_keyframes: db.len(),
            tx,
            thread,
            status,
        }
    }

    /// Where the map is saved.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The result of the newest save.
    pub fn status(&self) -> SaveStatus {
        super::shared::lock(&self.status).clone()
    }

    /// Hands a snapshot to the saver thread when the interval has passed and keyframes were added; a
    /// save still running lets the next interval take the newer map.
    pub fn maybe_save(&mut self, db: &KeyframeDb) {
        if self.last_save.elapsed().as_secs_f64() < self.interval {
            return;
        }
        self.last_save = Instant::now();
        if db.len() != self.saved_keyframes && self.tx.try_send(db.snapshot()).is_ok() {
            self.saved_keyframes = db.len();
        }
    }

    /// Saves now, on this thread (the first step of a shutdown); the error, if it failed.
    pub fn save_now(&mut self, db: &KeyframeDb) -> Option<String> {
        self.saved_keyframes = db.len();
        save_map(&db.snapshot(), &self.shape, &self.path, &self.status)
    }

    /// The final save, after any periodic save in flight; the error, if it failed.
    pub fn finish(self, db: &KeyframeDb) -> Option<String> {
        drop(self.tx);
        let _ = self.thread.join();
        save_map(&db.snapshot(), &self.shape, &self.path, &self.status)
    }
}

/// Saves `records`, records the result in `status`, and returns the error if it failed.
fn save_map(
    map: &MapSnapshot,
    shape: &MapShape,
    path: &Path,
    status: &Mutex<SaveStatus>,
) -> Option<String> {
    let t0 = Instant::now();
    let error = match save_snapshot(map, shape, path) {
        Ok(()) => {
            log::info!(
                "map saved: {} keyframes to {} in {:.0} ms",
                map.records.len(),
                path.display(),
                t0.elapsed().as_secs_f64() * 1e3
            );
            None
        }
        Err(e) => {
            log::error!("map not saved: {e}");
            Some(e.to_string())
        }
    };
    let mut s = super::shared::lock(status);
    s.saves += 1;
    s.last_error = error.clone();
    error
}
