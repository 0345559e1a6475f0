//! Inputs into the rolling submap ([`Ingest`]): stamps checked (going backwards, duplicates), clouds
//! decoded, odometry buffered, and each scan held until odometry covers its stamp, then compensated
//! and stacked ([`SubmapBuilder`]).

use std::collections::{BTreeMap, VecDeque};

use super::Config;
use super::events::{DropReason, Event, PipelineStats, dropped};
use crate::cloud::decode_detections;
use crate::math::{Iso3, Stamp};
use crate::msgs::sensor_msgs::PointCloud2;
use crate::radar::RadarScan;
use crate::radar::doppler::RadarModel;
use crate::submap::{OdometryBuffer, OdometryError, Submap, SubmapBuilder};

/// Most scans held while waiting for odometry to cover their stamps.
const MAX_PENDING: usize = 256;
/// A stamp this much older than the newest input counts as time going backwards, s.
const BACKWARDS_TOLERANCE: f64 = 1.0;

/// What [`Ingest::check_time`] decided about an input's stamp.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeCheck {
    /// The input goes on.
    Go,
    /// The input was dropped (a stale stamp).
    Dropped,
    /// A run of stamps going backwards is a restart: the input side was reset and the input goes on.
    Restarted,
}

/// The pipeline's input side: odometry, the scans waiting for it, and the rolling submap.
pub struct Ingest {
    odom: OdometryBuffer,
    builder: SubmapBuilder,
    pending: VecDeque<RadarScan>,
    /// Odometry path length so far, m.
    path_distance: f64,
    last_odom: Option<Iso3>,
    newest_input: Option<Stamp>,
    /// Inputs in a row with stamps going backwards, and how many make a restart.
    backwards_run: usize,
    restart_after: usize,
    /// Newest scan stamp per radar (duplicates are dropped).
    last_scan_stamp: BTreeMap<usize, Stamp>,
}

impl Ingest {
    /// The input side for a validated configuration.
    pub fn new(cfg: &Config) -> Self {
        let radars: Vec<RadarModel> = cfg
            .radar_list()
            .into_iter()
            .map(|(_, r)| RadarModel::from(r))
            .collect();
        Ingest {
            odom: OdometryBuffer::new(cfg.odometry.clone()),
            builder: SubmapBuilder::new(cfg.submap.clone(), cfg.ego_motion.clone(), radars),
            pending: VecDeque::new(),
            path_distance: 0.0,
            last_odom: None,
            newest_input: None,
            backwards_run: 0,
            restart_after: 1,
            last_scan_stamp: BTreeMap::new(),
        }
    }

    /// See [`super::Pipeline::set_restart_after`].
    pub fn set_restart_after(&mut self, n: usize) {
        self.restart_after = n.max(1);
    }

    /// Odometry path length so far, m.
    pub fn path_distance(&self) -> f64 {
        self.path_distance
    }

    /// Scans waiting for odometry.
    pub fn pending(&self) -> usize {
        self.pending.len()
    }

    /// The current rolling submap.
    pub fn submap(&self) -> Option<Submap> {
        self.builder.build()
    }

    /// Whether an input at `stamp` may go on: its stamp is not too far back, or a run of them is
    /// taken as a restart (then odometry, the waiting scans and the rolling submap are reset,
    /// [`Event::TimeReset`]).
    pub fn check_time(
        &mut self,
        stamp: Stamp,
        what: &str,
        stats: &mut PipelineStats,
        out: &mut Vec<Event>,
    ) -> TimeCheck {
        let Some(prev) = self.newest_input else {
            self.newest_input = Some(stamp);
            return TimeCheck::Go;
        };
        if prev.secs_since(stamp) <= BACKWARDS_TOLERANCE {
            self.backwards_run = 0;
            self.newest_input = Some(prev.max(stamp));
            return TimeCheck::Go;
        }
        self.backwards_run += 1;
        if self.backwards_run < self.restart_after {
            let detail = format!(
                "{what} at {:.3} s, {:.3} s before the newest input",
                stamp.as_secs_f64(),
                prev.secs_since(stamp)
            );
            dropped(stats, out, DropReason::StampBackwards, detail);
            return TimeCheck::Dropped;
        }
        self.backwards_run = 0;
        log::warn!(
            "time went backwards ({:.3} s -> {:.3} s): resetting odometry and the rolling submap, keeping the keyframes",
            prev.as_secs_f64(),
            stamp.as_secs_f64(),
        );
        self.odom.clear();
        self.builder.clear();
        self.pending.clear();
        self.last_odom = None;
        self.last_scan_stamp.clear();
        self.newest_input = Some(stamp);
        stats.time_resets += 1;
        out.push(Event::TimeReset {
            previous: prev,
            got: stamp,
        });
        TimeCheck::Restarted
    }

    /// Buffers one odometry sample; false when it was dropped.
    pub fn odometry(
        &mut self,
        stamp: Stamp,
        t_odom_body: Iso3,
        stats: &mut PipelineStats,
        out: &mut Vec<Event>,
    ) -> bool {
        match self.odom.push(stamp, t_odom_body) {
            Ok(()) => {}
            Err(OdometryError::TimeWentBackwards { newest, got }) => {
                // Within the tolerance: an out-of-order sample, not a restart.
                let detail = format!("odometry out of order: {got:?} after {newest:?}");
                dropped(stats, out, DropReason::BadOdometry, detail);
                return false;
            }
            Err(e) => {
                dropped(stats, out, DropReason::BadOdometry, e.to_string());
                return false;
            }
        }
        stats.odometry += 1;
        if let Some(prev) = self.last_odom {
            self.path_distance += (t_odom_body.translation.vector - prev.translation.vector).norm();
        }
        self.last_odom = Some(t_odom_body);
        true
    }

    /// Decodes a cloud of radar `radar` (index in `radar_names`) with its configured fields.
    pub fn decode(
        &self,
        cfg: &Config,
        radar: usize,
        cloud: &PointCloud2,
        stats: &mut PipelineStats,
        out: &mut Vec<Event>,
    ) -> Option<RadarScan> {
        let Some(name) = cfg.radar_names.get(radar) else {
            dropped(
                stats,
                out,
                DropReason::UnknownRadar,
                format!("radar index {radar}"),
            );
            return None;
        };
        let Some(rc) = cfg.radars.get(name) else {
            dropped(
                stats,
                out,
                DropReason::UnknownRadar,
                format!("radar `{name}`"),
            );
            return None;
        };
        match decode_detections(cloud, &rc.fields) {
            Ok(decoded) => {
                stats.detections_invalid +=
                    (decoded.skipped_nonfinite + decoded.skipped_zero_range) as u64;
                Some(RadarScan {
                    radar,
                    stamp: cloud.header.stamp.into(),
                    detections: decoded.detections,
                })
            }
            Err(e) => {
                let detail = format!("radar `{name}`: {e}");
                dropped(stats, out, DropReason::BadCloud, detail);
                None
            }
        }
    }

    /// Queues a decoded scan (of a configured radar whose stamp passed [`Ingest::check_time`]) until
    /// odometry covers it; empty scans are counted, a second scan of one radar with the same stamp
    /// (a re-sent or bogus message) and the oldest scan of a full queue are dropped.
    pub fn queue_scan(
        &mut self,
        cfg: &Config,
        scan: RadarScan,
        stats: &mut PipelineStats,
        out: &mut Vec<Event>,
    ) {
        let name = &cfg.radar_names[scan.radar];
        if scan.detections.is_empty() {
            stats.empty_scans += 1;
            out.push(Event::EmptyScan {
                detail: format!(
                    "radar `{name}` at {:.3} s: no valid point",
                    scan.stamp.as_secs_f64()
                ),
            });
        }
        if self.last_scan_stamp.get(&scan.radar) == Some(&scan.stamp) {
            let detail = format!(
                "radar `{name}`: a second scan stamped {:.3} s",
                scan.stamp.as_secs_f64()
            );
            dropped(stats, out, DropReason::DuplicateStamp, detail);
            return;
        }
        self.last_scan_stamp.insert(scan.radar, scan.stamp);
        if self.pending.len() >= MAX_PENDING {
            if let Some(old) = self.pending.pop_front() {
                let detail = format!(
                    "no odometry up to {:.3} s; dropped the oldest waiting scan",
                    old.stamp.as_secs_f64()
                );
                dropped(stats, out, DropReason::QueueFull, detail);
            }
        }
        let at = self.pending.partition_point(|s| s.stamp <= scan.stamp);
        self.pending.insert(at, scan);
    }

    /// Stacks the oldest waiting scan that odometry can place now into the rolling submap, and returns
    /// the body pose at its stamp; `None` when no waiting scan can be placed yet. Scans odometry cannot
    /// place at all (older than its history, inside a gap) are dropped on the way.
    pub fn next_scan(&mut self, stats: &mut PipelineStats, out: &mut Vec<Event>) -> Option<Iso3> {
        while let Some(scan) = self.pending.front() {
            let pose = match self.odom.pose_at(scan.stamp) {
                Ok(p) => p,
                Err(OdometryError::NotYet { .. }) => return None,
                Err(e) => {
                    self.pending.pop_front();
                    dropped(stats, out, DropReason::NoOdometry, e.to_string());
                    continue;
                }
            };
            let scan = self.pending.pop_front()?;
            let prior = self.odom.velocity_at(scan.stamp, 0.05);
            let Some(rep) = self.builder.add_scan(&scan, pose, prior) else {
                let detail = format!("radar index {}", scan.radar);
                dropped(stats, out, DropReason::UnknownRadar, detail);
                continue;
            };
            stats.scans += 1;
            stats.detections_kept += rep.kept as u64;
            stats.detections_dynamic += rep.dynamic as u64;
            stats.detections_invalid += rep.invalid as u64;
            if !rep.doppler_fit {
                stats.doppler_fit_failures += 1;
            }
            log::debug!(
                "scan radar {} at {:.3} s: {} kept, {} moving, {} invalid",
                scan.radar,
                scan.stamp.as_secs_f64(),
                rep.kept,
                rep.dynamic,
                rep.invalid
            );
            return Some(pose);
        }
        None
    }

    /// End of input: the scans still waiting for odometry are dropped and counted.
    pub fn finish(&mut self, stats: &mut PipelineStats, out: &mut Vec<Event>) {
        while let Some(s) = self.pending.pop_front() {
            let detail = format!(
                "input ended before odometry reached {:.3} s",
                s.stamp.as_secs_f64()
            );
            dropped(stats, out, DropReason::NoOdometry, detail);
        }
    }
}
