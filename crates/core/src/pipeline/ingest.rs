//! Inputs into the rolling submap ([`Ingest`]): stamps checked (going backwards, duplicates), clouds
//! decoded, odometry buffered, and each scan held until odometry covers its stamp, then compensated
//! and stacked ([`SubmapBuilder`]).

use std::collections::{BTreeMap, VecDeque};

use super::Config;
use super::events::{DropReason, Event, PipelineStats, dropped};
use crate::cloud::decode_detections;
use crate::input::InputLimits;
use crate::math::{Iso3, Stamp};
use crate::msgs::sensor_msgs::PointCloud2;
use crate::odometry::RadarOdometry;
use crate::pose_noise::PoseNoise;
use crate::radar::RadarScan;
use crate::radar::consistency::{DopplerMonitor, Verdict};
use crate::radar::doppler::RadarModel;
use crate::submap::{
    OdometryBuffer, OdometryConfig, OdometryError, Submap, SubmapBuilder, add_motion_noise,
};

/// Most scans held while waiting for odometry to cover their stamps.
const MAX_PENDING: usize = 256;
/// A stamp this much older than the newest input counts as time going backwards, s.
const BACKWARDS_TOLERANCE: f64 = 1.0;
/// A stamp this much newer than the newest input counts as a jump ahead, s.
const AHEAD_TOLERANCE: f64 = 10.0;

/// Consecutive implausible odometry samples, plausible among themselves, that are the odometry's own
/// reset (a new track) rather than outliers: 10, a fraction of a second at odometry rates.
const ODOMETRY_RESET_AFTER: usize = 10;
/// Slack on the plausible motion between two odometry samples, m and rad.
const JUMP_SLACK: (f64, f64) = (1.0, 0.2);

/// Why the body cannot have moved from `a` to `b` (`odometry.max_speed`, `max_yaw_rate`).
fn implausible(a: &(Stamp, Iso3), b: &(Stamp, Iso3), cfg: &OdometryConfig) -> Result<(), String> {
    let dt = b.0.secs_since(a.0).abs();
    let moved = (b.1.translation.vector - a.1.translation.vector).norm();
    let turned = a.1.rotation.angle_to(&b.1.rotation);
    if moved <= cfg.max_speed * dt + JUMP_SLACK.0 && turned <= cfg.max_yaw_rate * dt + JUMP_SLACK.1
    {
        return Ok(());
    }
    Err(format!(
        "odometry moved {moved:.3e} m and turned {turned:.2} rad in {dt:.3} s (odometry.max_speed {}, max_yaw_rate {})",
        cfg.max_speed, cfg.max_yaw_rate
    ))
}

/// What [`Ingest::odometry`] did with a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OdometryCheck {
    /// Buffered.
    Accepted,
    /// Dropped (implausible, out of order).
    Dropped,
    /// Buffered as the first sample of a new track (the odometry jumped for good).
    Reset,
}

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
    /// The last accepted odometry sample.
    last_odom: Option<(Stamp, Iso3)>,
    /// The newest implausible odometry sample and how many in a row agreed with it.
    jump: Option<((Stamp, Iso3), usize)>,
    newest_input: Option<Stamp>,
    /// Inputs in a row with stamps out of line (ahead or not, how many), and how many make a restart.
    out_of_line: Option<(bool, usize)>,
    restart_after: usize,
    /// Newest scan stamp per radar (duplicates are dropped).
    last_scan_stamp: BTreeMap<usize, Stamp>,
    limits: InputLimits,
    /// The radars' Doppler against the odometry.
    doppler: DopplerMonitor,
    /// The odometry made from the radars, unless it comes from a topic.
    radar_odometry: Option<RadarOdometry>,
}

impl Ingest {
    /// The input side for a validated configuration.
    pub fn new(cfg: &Config) -> Self {
        let radars: Vec<RadarModel> = cfg
            .radar_list()
            .into_iter()
            .map(|(_, r)| RadarModel::from(r))
            .collect();
        let radar_odometry = RadarOdometry::new(
            &cfg.odometry,
            &cfg.imu,
            radars.clone(),
            cfg.ego_motion.clone(),
        );
        Ingest {
            odom: OdometryBuffer::new(cfg.odometry.clone()),
            builder: SubmapBuilder::new(cfg.submap.clone(), cfg.ego_motion.clone(), radars),
            pending: VecDeque::new(),
            path_distance: 0.0,
            last_odom: None,
            jump: None,
            newest_input: None,
            out_of_line: None,
            restart_after: 1,
            last_scan_stamp: BTreeMap::new(),
            limits: InputLimits::default(),
            doppler: DopplerMonitor::default(),
            radar_odometry,
        }
    }

    /// The radar odometry, when `odometry.source` is not `topic`.
    pub fn radar_odometry(&mut self) -> Option<&mut RadarOdometry> {
        self.radar_odometry.as_mut()
    }

    /// See [`super::Pipeline::set_input_limits`].
    pub fn set_input_limits(&mut self, limits: InputLimits) {
        self.limits = limits;
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

    /// The current rolling submap, its points' covariances grown by the odometry's motion between
    /// the scans where the odometry gives its uncertainty (the radar odometry does).
    pub fn submap(&self) -> Option<Submap> {
        let mut sub = self.builder.build()?;
        let stamps: Vec<Stamp> = sub.scans.iter().map(|s| s.stamp).collect();
        if let Some(motion) = self.odom.motion_to(&stamps, sub.anchor_stamp) {
            add_motion_noise(&mut sub, &motion);
        }
        Some(sub)
    }

    /// Whether an input at `stamp` may go on. A stamp out of line with the newest input (more than
    /// 1 s before it, or 10 s after it) is dropped and counted, and the newest stamp stays: one bad
    /// stamp costs no other input. A run of `restart_after` of them in one direction is taken as the
    /// truth: going back, a restart (odometry, the waiting scans and the rolling submap are reset,
    /// [`Event::TimeReset`]); going ahead, a jump after an outage.
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
        let ahead = stamp.secs_since(prev) > AHEAD_TOLERANCE;
        if prev.secs_since(stamp) <= BACKWARDS_TOLERANCE && !ahead {
            self.out_of_line = None;
            self.newest_input = Some(prev.max(stamp));
            return TimeCheck::Go;
        }
        let run = match self.out_of_line {
            Some((dir, n)) if dir == ahead => n + 1,
            _ => 1,
        };
        self.out_of_line = Some((ahead, run));
        if run < self.restart_after {
            let (reason, detail) = if ahead {
                let d = stamp.secs_since(prev);
                (
                    DropReason::StampAhead,
                    format!("{d:.3} s after the newest input"),
                )
            } else {
                let d = prev.secs_since(stamp);
                (
                    DropReason::StampBackwards,
                    format!("{d:.3} s before the newest input"),
                )
            };
            let detail = format!("{what} at {:.3} s, {detail}", stamp.as_secs_f64());
            dropped(stats, out, reason, what, detail);
            return TimeCheck::Dropped;
        }
        self.out_of_line = None;
        self.newest_input = Some(stamp);
        if ahead {
            log::info!(
                "time jumped ahead ({:.3} s -> {:.3} s)",
                prev.as_secs_f64(),
                stamp.as_secs_f64()
            );
            return TimeCheck::Go;
        }
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
        if let Some(r) = &mut self.radar_odometry {
            r.reset();
        }
        stats.time_resets += 1;
        out.push(Event::TimeReset {
            previous: prev,
            got: stamp,
        });
        TimeCheck::Restarted
    }

    /// Buffers one odometry sample unless it is implausible: a pose the last one could not have
    /// moved to (`odometry.max_speed`, `odometry.max_yaw_rate`) is an outlier, dropped and counted,
    /// unless it starts a run of plausible samples long enough to be the odometry's own reset (then
    /// a new track starts, with the rolling submap reset and the path length kept).
    pub fn odometry(
        &mut self,
        cfg: &OdometryConfig,
        stamp: Stamp,
        t_odom_body: Iso3,
        noise: Option<PoseNoise>,
        stats: &mut PipelineStats,
        out: &mut Vec<Event>,
    ) -> OdometryCheck {
        let sample = (stamp, t_odom_body);
        let mut reset = false;
        if let Some(last) = self.last_odom.filter(|l| stamp > l.0)
            && let Err(why) = implausible(&last, &sample, cfg)
        {
            let run = match self.jump {
                Some((prev, n)) if implausible(&prev, &sample, cfg).is_ok() => n + 1,
                _ => 1,
            };
            if run < ODOMETRY_RESET_AFTER {
                self.jump = Some((sample, run));
                dropped(
                    stats,
                    out,
                    DropReason::BadOdometry,
                    "implausible motion",
                    why,
                );
                return OdometryCheck::Dropped;
            }
            log::warn!(
                "odometry jumped and stayed there for {run} samples ({why}): a new odometry track, the rolling submap reset"
            );
            self.odom.clear();
            self.builder.clear();
            self.last_odom = None;
            stats.odometry_resets += 1;
            reset = true;
        }
        self.jump = None;
        match self.odom.push(stamp, t_odom_body, noise) {
            Ok(()) => {}
            Err(OdometryError::TimeWentBackwards { newest, got }) => {
                // Within the tolerance: an out-of-order sample, not a restart.
                let detail = format!("odometry out of order: {got:?} after {newest:?}");
                dropped(stats, out, DropReason::BadOdometry, "out of order", detail);
                return OdometryCheck::Dropped;
            }
            Err(e) => {
                dropped(
                    stats,
                    out,
                    DropReason::BadOdometry,
                    "refused",
                    e.to_string(),
                );
                return OdometryCheck::Dropped;
            }
        }
        stats.odometry += 1;
        if let Some((_, prev)) = self.last_odom {
            self.path_distance += (t_odom_body.translation.vector - prev.translation.vector).norm();
        }
        self.last_odom = Some(sample);
        if reset {
            OdometryCheck::Reset
        } else {
            OdometryCheck::Accepted
        }
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
            let detail = format!("radar index {radar}");
            dropped(
                stats,
                out,
                DropReason::UnknownRadar,
                &detail,
                detail.clone(),
            );
            return None;
        };
        let Some(rc) = cfg.radars.get(name) else {
            let detail = format!("radar `{name}`");
            dropped(
                stats,
                out,
                DropReason::UnknownRadar,
                &detail,
                detail.clone(),
            );
            return None;
        };
        if let Err(e) = self.limits.check(cloud) {
            let detail = format!("radar `{name}`: {e}");
            dropped(stats, out, DropReason::CloudTooLarge, name, detail);
            return None;
        }
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
                // The error names the layout, not the message: it is the cause itself.
                let detail = format!("radar `{name}`: {e}");
                dropped(stats, out, DropReason::BadCloud, &detail, detail.clone());
                None
            }
        }
    }

    /// Whether a scan that came decoded (a `radar_msgs/RadarScan`, five float32 fields a return) fits
    /// the input limits; a larger one is dropped as [`DropReason::CloudTooLarge`], as a cloud is.
    pub fn scan_fits(
        &self,
        cfg: &Config,
        scan: &RadarScan,
        stats: &mut PipelineStats,
        out: &mut Vec<Event>,
    ) -> bool {
        let n = scan.detections.len();
        let Err(e) = self.limits.check_size(n as u64, n.saturating_mul(20)) else {
            return true;
        };
        let name = cfg.radar_names.get(scan.radar).map_or("?", String::as_str);
        let detail = format!("radar `{name}`: {e}");
        dropped(stats, out, DropReason::CloudTooLarge, name, detail);
        false
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
            dropped(stats, out, DropReason::DuplicateStamp, name, detail);
            return;
        }
        self.last_scan_stamp.insert(scan.radar, scan.stamp);
        if self.pending.len() >= MAX_PENDING
            && let Some(old) = self.pending.pop_front()
        {
            let detail = format!(
                "no odometry up to {:.3} s; dropped the oldest waiting scan",
                old.stamp.as_secs_f64()
            );
            dropped(stats, out, DropReason::QueueFull, "", detail);
        }
        let at = self.pending.partition_point(|s| s.stamp <= scan.stamp);
        self.pending.insert(at, scan);
    }

    /// Stacks the oldest waiting scan that odometry can place now into the rolling submap, and returns
    /// the body pose at its stamp; `None` when no waiting scan can be placed yet. Scans odometry cannot
    /// place at all (older than its history, inside a gap) are dropped on the way.
    pub fn next_scan(
        &mut self,
        cfg: &Config,
        stats: &mut PipelineStats,
        out: &mut Vec<Event>,
    ) -> Option<Iso3> {
        while let Some(scan) = self.pending.front() {
            let pose = match self.odom.pose_at(scan.stamp) {
                Ok(p) => p,
                Err(OdometryError::NotYet { .. }) => return None,
                Err(e) => {
                    let name = cfg.radar_names.get(scan.radar).map_or("?", String::as_str);
                    self.pending.pop_front();
                    let detail = format!("radar `{name}`: {e}");
                    dropped(stats, out, DropReason::NoOdometry, name, detail);
                    continue;
                }
            };
            let scan = self.pending.pop_front()?;
            let prior = self.odom.velocity_at(scan.stamp, 0.05);
            let Some(rep) = self.builder.add_scan(&scan, pose, prior) else {
                let detail = format!("radar index {}", scan.radar);
                dropped(
                    stats,
                    out,
                    DropReason::UnknownRadar,
                    &detail,
                    detail.clone(),
                );
                continue;
            };
            stats.scans += 1;
            stats.detections_kept += rep.kept as u64;
            stats.detections_dynamic += rep.dynamic as u64;
            stats.detections_invalid += rep.invalid as u64;
            stats.detections_out_of_band += rep.out_of_band as u64;
            if !rep.doppler_fit {
                stats.doppler_fit_failures += 1;
            }
            self.check_doppler(cfg, &scan, rep.doppler_check, stats);
            log::debug!(
                "scan radar {} at {:.3} s: {} kept, {} moving, {} invalid, {} outside the height band",
                scan.radar,
                scan.stamp.as_secs_f64(),
                rep.kept,
                rep.dynamic,
                rep.invalid,
                rep.out_of_band
            );
            return Some(pose);
        }
        None
    }

    /// Counts a scan's Doppler disagreeing with the odometry, and warns once per radar whose Doppler
    /// disagrees persistently, with the likely cause.
    fn check_doppler(
        &mut self,
        cfg: &Config,
        scan: &RadarScan,
        verdict: Option<Verdict>,
        stats: &mut PipelineStats,
    ) {
        let Some(verdict) = verdict else { return };
        if verdict != Verdict::Agrees {
            *stats.doppler_disagreements.entry(scan.radar).or_default() += 1;
        }
        if let Some(cause) = self.doppler.observe(scan.radar, verdict) {
            let name = cfg.radar_names.get(scan.radar).map_or("?", String::as_str);
            log::warn!("radar `{name}`: {cause}");
            stats
                .doppler_warnings
                .insert(scan.radar, (scan.stamp, cause));
        }
    }

    /// End of input: the scans still waiting for odometry are dropped and counted.
    pub fn finish(&mut self, stats: &mut PipelineStats, out: &mut Vec<Event>) {
        while let Some(s) = self.pending.pop_front() {
            let detail = format!(
                "input ended before odometry reached {:.3} s",
                s.stamp.as_secs_f64()
            );
            dropped(stats, out, DropReason::NoOdometry, "input ended", detail);
        }
    }
}
