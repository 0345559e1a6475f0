//! The paper's protocol over many separate drives (nuScenes scenes): keyframes of different drives at
//! the same location paired by ground truth, with memory bounded by what the pairs need.
//!
//! Entry points: [`DriveInfo`] (a drive's name, location and ground-truth trajectory, known before its
//! radar data is read), [`CrossDriveEval`] (`new`, then [`CrossDriveEval::needs_loading`] and
//! [`CrossDriveEval::add_drive`] per drive in order, then `results` / `records`).
//!
//! Pairs (as the paper's nuScenes pairs): a keyframe of drive `d` is paired with the nearest keyframe of
//! an earlier drive at the same location (or of the same drive at least `min_pass_gap` metres of path
//! before; set it out of reach for across-drive pairs only) within `pair_radius`, headings within
//! `max_heading_difference`. A keyframe is kept after its drive only when a later drive's ground-truth
//! trajectory passes within `pair_radius` of it with a compatible heading, so memory holds only the
//! keyframes some later pair can use, whatever the number of drives.

use std::collections::HashMap;

use super::{EvalConfig, EvalKeyframe, Method, Pair, PairResult, evaluate};
use dc_loc_core::math::{Vec2, wrap_angle};
use dc_loc_core::registration::RegistrationConfig;

/// A drive as known before its radar data is read.
#[derive(Debug, Clone, PartialEq)]
pub struct DriveInfo {
    /// Name (scene name).
    pub name: String,
    /// Location: positions of drives at one location share a frame; drives at different locations are
    /// never paired.
    pub location: String,
    /// Ground-truth positions (map frame, m) and headings (rad) along the drive.
    pub trajectory: Vec<(Vec2, f64)>,
}

/// Trajectory points by (location, cell x, cell y): (drive, position, heading).
type Grid = HashMap<(usize, i64, i64), Vec<(usize, Vec2, f64)>>;

/// One evaluated pair with its drives (for the per-pair output).
#[derive(Debug, Clone, PartialEq)]
pub struct PairRecord {
    /// Drive of the query keyframe (index into the drives).
    pub query_drive: usize,
    /// Drive of the target keyframe.
    pub target_drive: usize,
    /// Query keyframe anchor time, s.
    pub query_stamp: f64,
    /// Target keyframe anchor time, s.
    pub target_stamp: f64,
    /// Results, one per method.
    pub results: Vec<PairResult>,
}

/// Incremental cross-drive evaluation (see the module documentation).
pub struct CrossDriveEval {
    drives: Vec<DriveInfo>,
    eval: EvalConfig,
    methods: Vec<Method>,
    registration: RegistrationConfig,
    /// (location, cell x, cell y) -> (drive, position, heading) of trajectory points.
    grid: Grid,
    location_of: Vec<usize>,
    retained: Vec<(usize, EvalKeyframe)>,
    pairs_seen: usize,
    /// Every result so far.
    pub results: Vec<PairResult>,
    /// Every pair so far with its results.
    pub records: Vec<PairRecord>,
    /// Most keyframes held at once (for the memory claim).
    pub max_retained: usize,
    /// Most submap points held at once (with the keyframes of the drive being added).
    pub max_points: usize,
}

impl CrossDriveEval {
    /// Prepares the evaluation of `drives` (in processing order).
    pub fn new(
        drives: Vec<DriveInfo>,
        eval: EvalConfig,
        methods: Vec<Method>,
        registration: RegistrationConfig,
    ) -> Self {
        let mut locations: Vec<String> = Vec::new();
        let mut location_of = Vec::with_capacity(drives.len());
        for d in &drives {
            let l = match locations.iter().position(|l| *l == d.location) {
                Some(l) => l,
                None => {
                    locations.push(d.location.clone());
                    locations.len() - 1
                }
            };
            location_of.push(l);
        }
        let mut grid: Grid = HashMap::new();
        let cell = eval.pair_radius;
        for (i, d) in drives.iter().enumerate() {
            let mut last: Option<Vec2> = None;
            for &(p, h) in &d.trajectory {
                // Points 0.5 m apart at most are enough against a radius of metres.
                if last.is_some_and(|q| (p - q).norm() < 0.5) {
                    continue;
                }
                last = Some(p);
                let key = (
                    location_of[i],
                    (p.x / cell).floor() as i64,
                    (p.y / cell).floor() as i64,
                );
                grid.entry(key).or_default().push((i, p, h));
            }
        }
        CrossDriveEval {
            drives,
            eval,
            methods,
            registration,
            grid,
            location_of,
            retained: Vec::new(),
            pairs_seen: 0,
            results: Vec::new(),
            records: Vec::new(),
            max_retained: 0,
            max_points: 0,
        }
    }

    /// The drives.
    pub fn drives(&self) -> &[DriveInfo] {
        &self.drives
    }

    /// Whether some trajectory point of a drive other than `drive` at its location passes within the
    /// pair radius of `p` with a compatible heading.
    fn near_other(&self, drive: usize, p: Vec2, heading: f64) -> bool {
        let cell = self.eval.pair_radius;
        let (cx, cy) = ((p.x / cell).floor() as i64, (p.y / cell).floor() as i64);
        let loc = self.location_of[drive];
        for dx in -1..=1 {
            for dy in -1..=1 {
                let Some(v) = self.grid.get(&(loc, cx + dx, cy + dy)) else {
                    continue;
                };
                if v.iter().any(|&(d, q, h)| {
                    d != drive
                        && (q - p).norm() <= self.eval.pair_radius
                        && wrap_angle(h - heading).abs() <= self.eval.max_heading_difference
                }) {
                    return true;
                }
            }
        }
        false
    }

    /// Whether drive `d` can take part in any pair (its trajectory meets another drive's): drives that
    /// cannot need not be read at all.
    pub fn needs_loading(&self, d: usize) -> bool {
        self.drives.get(d).is_some_and(|info| {
            info.trajectory
                .iter()
                .any(|&(p, h)| self.near_other(d, p, h))
        })
    }

    /// Adds the keyframes of drive `d` (drives must come in index order): pairs them with the kept
    /// keyframes of earlier drives, evaluates those pairs, then keeps of all keyframes only those a later
    /// drive may pair with. Returns the number of pairs evaluated.
    pub fn add_drive(&mut self, d: usize, kfs: Vec<EvalKeyframe>) -> usize {
        let loc = self.location_of.get(d).copied();
        // Targets: kept keyframes of earlier drives at this location.
        let mut combined: Vec<EvalKeyframe> = Vec::new();
        let mut drive_of: Vec<usize> = Vec::new();
        for (kd, kf) in &self.retained {
            if *kd < d && self.location_of.get(*kd).copied() == loc {
                combined.push(kf.clone());
                drive_of.push(*kd);
            }
        }
        let n_targets = combined.len();
        let mut pairs = Vec::new();
        for (qi, q) in kfs.iter().enumerate() {
            // Candidates: kept keyframes of earlier drives, and earlier keyframes of this drive at least
            // `min_pass_gap` of path before (another pass within one drive).
            let earlier = combined[..n_targets].iter().enumerate().chain(
                kfs[..qi]
                    .iter()
                    .enumerate()
                    .filter(|(_, k)| q.path - k.path >= self.eval.min_pass_gap)
                    .map(|(i, k)| (n_targets + i, k)),
            );
            let best = earlier
                .filter(|(_, t)| {
                    wrap_angle(q.t_map_body.rotation.angle() - t.t_map_body.rotation.angle()).abs()
                        <= self.eval.max_heading_difference
                })
                .map(|(i, t)| {
                    (
                        i,
                        (q.t_map_body.translation.vector - t.t_map_body.translation.vector).norm(),
                    )
                })
                .min_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((t, dist)) = best.filter(|b| b.1 <= self.eval.pair_radius) {
                self.pairs_seen += 1;
                if (self.pairs_seen - 1).is_multiple_of(self.eval.pair_stride) {
                    pairs.push(Pair {
                        query: n_targets + qi,
                        target: t,
                        distance: dist,
                    });
                }
            }
        }
        combined.extend(kfs.iter().cloned());
        let held: usize = self
            .retained
            .iter()
            .map(|(_, k)| k.submap.points.len())
            .sum::<usize>()
            + kfs.iter().map(|k| k.submap.points.len()).sum::<usize>();
        self.max_points = self.max_points.max(held);
        drive_of.extend(std::iter::repeat_n(d, kfs.len()));
        let results = evaluate(
            &combined,
            &pairs,
            &self.methods,
            &self.registration,
            &self.eval,
        );
        for (p, chunk) in pairs.iter().zip(results.chunks(self.methods.len().max(1))) {
            self.records.push(PairRecord {
                query_drive: d,
                target_drive: drive_of[p.target],
                query_stamp: combined[p.query].stamp.as_secs_f64(),
                target_stamp: combined[p.target].stamp.as_secs_f64(),
                results: chunk.to_vec(),
            });
        }
        self.results.extend(results);
        // Keep only what a later drive can pair with.
        let retained = std::mem::take(&mut self.retained);
        let mut next: Vec<(usize, EvalKeyframe)> = Vec::new();
        for (kd, kf) in retained.into_iter().chain(kfs.into_iter().map(|k| (d, k))) {
            // A kept keyframe of drive kd stays while a drive after d may still pair with it.
            if self.near_later_than(kd, d, &kf) {
                next.push((kd, kf));
            }
        }
        self.retained = next;
        self.max_retained = self.max_retained.max(self.retained.len());
        pairs.len()
    }

    /// Whether a drive after `after` passes near keyframe `kf` of drive `drive`.
    fn near_later_than(&self, drive: usize, after: usize, kf: &EvalKeyframe) -> bool {
        let p = kf.t_map_body.translation.vector;
        let heading = kf.t_map_body.rotation.angle();
        let cell = self.eval.pair_radius;
        let (cx, cy) = ((p.x / cell).floor() as i64, (p.y / cell).floor() as i64);
        let loc = self.location_of[drive];
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                self.grid.get(&(loc, cx + dx, cy + dy)).is_some_and(|v| {
                    v.iter().any(|&(e, q, h)| {
                        e > after
                            && e != drive
                            && (q - p).norm() <= self.eval.pair_radius
                            && wrap_angle(h - heading).abs() <= self.eval.max_heading_difference
                    })
                })
            })
        })
    }

    /// Keyframes held now.
    pub fn retained(&self) -> usize {
        self.retained.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dc_loc_core::math::{Iso2, Iso3, Stamp};
    use dc_loc_core::submap::Submap;
    use std::sync::Arc;

    fn kf(x: f64, y: f64, t: i64) -> EvalKeyframe {
        EvalKeyframe {
            id: t as u64,
            stamp: Stamp(t),
            t_map_body: Iso2::new(Vec2::new(x, y), 0.0),
            speed: 10.0,
            path: x,
            submap: Arc::new(Submap {
                anchor_stamp: Stamp(t),
                t_odom_anchor: Iso3::identity(),
                points: Vec::new(),
                scans: Vec::new(),
                speed_scale: dc_loc_core::submap::SpeedScale::Unavailable,
                motion: dc_loc_core::math::Mat3::zeros(),
            }),
            estimated_speeds: Vec::new(),
        }
    }

    fn drive(name: &str, location: &str, y: f64) -> DriveInfo {
        DriveInfo {
            name: name.into(),
            location: location.into(),
            trajectory: (0..=200)
                .map(|i| (Vec2::new(i as f64 * 0.5, y), 0.0))
                .collect(),
        }
    }

    /// Pairs only across drives at one location; kept keyframes are those a later drive passes, so
    /// unrelated drives in between do not add to what is held.
    #[test]
    fn pairs_across_drives_and_holds_only_what_later_pairs_need() {
        let mut drives = vec![drive("a", "one", 0.0), drive("b", "one", 1.0)];
        // Unrelated drives: another location (the first at the same coordinates), and far away at this one.
        for i in 0..20 {
            drives.push(drive(&format!("x{i}"), "two", 50.0 * i as f64));
            drives.push(drive(&format!("y{i}"), "one", 500.0 + 50.0 * i as f64));
        }
        drives.push(drive("e", "one", -1.0));
        let n = drives.len();
        let eval = EvalConfig {
            min_pass_gap: f64::MAX,
            ..EvalConfig::default()
        };
        let mut cross = CrossDriveEval::new(
            drives,
            eval,
            vec![Method::Icp],
            RegistrationConfig::default(),
        );
        let kfs = |y: f64, t0: i64| -> Vec<EvalKeyframe> {
            (0..=10).map(|i| kf(10.0 * i as f64, y, t0 + i)).collect()
        };
        assert!(cross.needs_loading(0) && cross.needs_loading(1) && cross.needs_loading(n - 1));
        assert!(!cross.needs_loading(2) && !cross.needs_loading(3));
        assert_eq!(cross.add_drive(0, kfs(0.0, 0)), 0);
        assert_eq!(cross.retained(), 11);
        assert_eq!(cross.add_drive(1, kfs(1.0, 100)), 11);
        assert_eq!(cross.retained(), 22);
        for d in 2..n - 1 {
            let y = cross.drives()[d].trajectory[0].0.y;
            assert_eq!(cross.add_drive(d, kfs(y, 1000 * d as i64)), 0, "drive {d}");
        }
        assert_eq!(cross.max_retained, 22);
        // The last drive pairs with the nearest of a (1 m) and b (2 m): a.
        assert_eq!(cross.add_drive(n - 1, kfs(-1.0, 99_000)), 11);
        assert_eq!(cross.retained(), 0);
        assert_eq!(cross.records.len(), 22);
        let last = &cross.records[11..];
        assert!(
            last.iter()
                .all(|r| r.query_drive == n - 1 && r.target_drive == 0)
        );
        assert!(
            last.iter()
                .all(|r| (r.results[0].pair.distance - 1.0).abs() < 1e-9)
        );
    }
}
