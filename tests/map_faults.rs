//! The map file under faults: ENOSPC, EIO and a kill at each step of a save (write, fsync, rename,
//! directory fsync), injected through the storage layer the node saves with. After every trial the map
//! loads as the old or the new version, no temporary file survives the next start, and a failed save
//! is reported. One writer at a time: a second one is refused, naming the first.

use std::io;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use dc_loc::keyframe_db::lock::MapLock;
use dc_loc::keyframe_db::storage::{Disk, Storage, clean_temp_files, temp_path};
use dc_loc::keyframe_db::{
    KeyframeDb, KeyframeRecord, MapError, MapShape, quantise_cov, quantise_point, quantise_ray,
    save_records, save_records_with,
};
use dc_loc::math::{Iso2, Mat2, Stamp, Vec2};
use dc_loc::place::{PlaceConfig, PlaceDescriptor};
mod common;

fn record(id: u64, x: f64) -> KeyframeRecord {
    let pts: Vec<Vec2> = (0..200)
        .map(|k| {
            Vec2::new(
                (k as f64 * 0.7).sin() * 40.0,
                (k as f64 * 1.3).cos() * 30.0 + x,
            )
        })
        .collect();
    KeyframeRecord {
        id,
        session: 0,
        stamp: Stamp(1_000_000_000 * (id as i64 + 1)),
        t_odom_body: Iso2::new(Vec2::new(x, 0.0), 0.0),
        odom_pose: [x, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        path_distance: x,
        points: pts.iter().filter_map(|&p| quantise_point(p)).collect(),
        covs: pts
            .iter()
            .map(|_| quantise_cov(&Mat2::new(0.04, 0.0, 0.0, 0.09)))
            .collect(),
        rays: pts.iter().map(|p| quantise_ray(&p.normalize())).collect(),
        place: PlaceDescriptor::from_points(&pts, &PlaceConfig::default()),
    }
}

fn records(n: u64) -> Vec<Arc<KeyframeRecord>> {
    (0..n)
        .map(|i| Arc::new(record(i, 5.0 * i as f64)))
        .collect()
}

fn shape() -> MapShape {
    MapShape {
        body_frame: "base_link".into(),
        radars: Vec::new(),
        max_points_per_keyframe: 4000,
        place: PlaceConfig::default(),
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Fault {
    NoSpace,
    Io,
    Kill,
}

/// The real disk with one fault at step `at` (0 write, 1 fsync, 2 rename, 3 directory fsync); a
/// write that fails leaves `partial` bytes behind, as a full disk or a killed process would.
struct Faulty {
    step: usize,
    at: usize,
    fault: Fault,
    partial: usize,
    dead: bool,
}

impl Faulty {
    fn error(&mut self) -> io::Error {
        match self.fault {
            Fault::NoSpace => io::Error::from_raw_os_error(28),
            Fault::Io => io::Error::from_raw_os_error(5),
            Fault::Kill => {
                self.dead = true;
                io::Error::other("killed")
            }
        }
    }

    /// Whether this step fails.
    fn fails(&mut self) -> bool {
        let now = self.step;
        self.step += 1;
        now == self.at
    }
}

impl Storage for Faulty {
    fn write_file(&mut self, path: &Path, bytes: &[u8]) -> io::Result<()> {
        if self.fails() {
            std::fs::write(path, &bytes[..self.partial.min(bytes.len())])?;
            return Err(self.error());
        }
        Disk.write_file(path, bytes)
    }
    fn sync_file(&mut self, path: &Path) -> io::Result<()> {
        if self.fails() {
            return Err(self.error());
        }
        Disk.sync_file(path)
    }
    fn rename(&mut self, from: &Path, to: &Path) -> io::Result<()> {
        if self.fails() {
            return Err(self.error());
        }
        Disk.rename(from, to)
    }
    fn sync_dir(&mut self, dir: &Path) -> io::Result<()> {
        if self.fails() {
            return Err(self.error());
        }
        Disk.sync_dir(dir)
    }
    fn remove(&mut self, path: &Path) -> io::Result<()> {
        Disk.remove(path)
    }
    fn alive(&self) -> bool {
        !self.dead
    }
}

fn temp_files(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().contains(".tmp-"))
        .collect()
}

#[test]
fn every_fault_at_every_step_leaves_the_old_or_the_new_map() {
    let dir = common::scratch("map_faults", "steps");
    let path = dir.join("map.dcloc");
    let (old, new) = (records(6), records(11));
    let mut trials = 0;
    for at in 0..4 {
        for fault in [Fault::NoSpace, Fault::Io, Fault::Kill] {
            for partial in [0, 17, 4096, usize::MAX] {
                save_records(&old, &shape(), &path).expect("the old map");
                let mut storage = Faulty {
                    step: 0,
                    at,
                    fault,
                    partial,
                    dead: false,
                };
                let saved = save_records_with(&mut storage, &new, &shape(), &path);
                // A fault before the rename is a failed save; at the directory fsync the new map is
                // in place but the save is still reported as failed.
                assert!(saved.is_err(), "{fault:?} at step {at}: not reported");
                // The next start cleans up what a killed writer left.
                clean_temp_files(&path);
                assert!(
                    temp_files(&dir).is_empty(),
                    "{fault:?} at step {at}: temporary files left: {:?}",
                    temp_files(&dir)
                );
                let back = KeyframeDb::load(&path, PlaceConfig::default(), 4)
                    .unwrap_or_else(|e| panic!("{fault:?} at step {at}: {e}"));
                let expected = if at >= 3 { new.len() } else { old.len() };
                assert_eq!(
                    back.len(),
                    expected,
                    "{fault:?} at step {at}, partial {partial}"
                );
                trials += 1;
            }
        }
    }
    assert_eq!(trials, 48);
}

#[test]
fn a_failed_write_removes_its_temporary_file_at_once() {
    let dir = common::scratch("map_faults", "cleanup");
    let path = dir.join("map.dcloc");
    let mut storage = Faulty {
        step: 0,
        at: 0,
        fault: Fault::NoSpace,
        partial: 100,
        dead: false,
    };
    let e = save_records_with(&mut storage, &records(3), &shape(), &path).unwrap_err();
    assert!(e.to_string().contains("No space left"), "{e}");
    assert!(!temp_path(&path).exists());
    assert!(!path.exists());
}

#[test]
fn a_second_writer_is_refused_naming_the_first() {
    let dir = common::scratch("map_faults", "lock");
    let path = dir.join("map.dcloc");
    let first = MapLock::acquire(&path).expect("first writer");
    let e = MapLock::acquire(&path).unwrap_err();
    assert!(matches!(e, MapError::Locked { .. }), "{e}");
    let pid = std::process::id().to_string();
    assert!(e.to_string().contains(&pid), "{e}");
    drop(first);
    MapLock::acquire(&path).expect("free again once the first is gone");
}

#[test]
fn intact_nonsense_is_refused() {
    let dir = common::scratch("map_faults", "nonsense");
    let path = dir.join("map.dcloc");
    type Damage = fn(&mut KeyframeRecord);
    let bad: [(&str, Damage); 5] = [
        ("rays", |r| {
            r.rays.pop();
        }),
        ("not finite", |r| {
            r.t_odom_body = Iso2::new(Vec2::new(f64::NAN, 0.0), 0.0)
        }),
        ("unit quaternion", |r| r.odom_pose[6] = 3.0),
        ("session", |r| r.session = u32::MAX),
        ("another shape", |r| {
            r.place = PlaceDescriptor::from_points(
                &[],
                &PlaceConfig {
                    sectors: 24,
                    ..PlaceConfig::default()
                },
            )
        }),
    ];
    for (what, spoil) in bad {
        let mut rs: Vec<KeyframeRecord> = (0..4).map(|i| record(i, 5.0 * i as f64)).collect();
        spoil(&mut rs[2]);
        let rs: Vec<Arc<KeyframeRecord>> = rs.into_iter().map(Arc::new).collect();
        save_records(&rs, &shape(), &path).unwrap();
        let e = KeyframeDb::load(&path, PlaceConfig::default(), 4).unwrap_err();
        assert!(matches!(e, MapError::Corrupt { .. }), "{what}: {e}");
        assert!(e.to_string().contains("keyframe 2"), "{what}: {e}");
    }
}
