//! The one pipeline every front end drives: the ROS node, the offline bag runner, the demo and the tests.
//!
//! Steps, in order, as data arrives: decode a radar cloud -> wait until odometry covers its stamp ->
//! Doppler compensation, covariance, moving-object rejection ([`crate::submap::SubmapBuilder`]) ->
//! keyframe decision -> revisit search in the keyframe database -> registration -> gates -> closure.
//! Nothing calls back: every `push_*` returns the [`Event`]s it produced, and counters live in
//! [`PipelineStats`].
//!
//! Entry points: [`Pipeline`], [`Event`], [`LoopClosure`], [`Keyframe`], [`KeyframeConfig`],
//! [`LoopConfig`], [`PipelineStats`].

use crate::cloud::decode_detections;
use crate::config::{Config, ConfigError};
use crate::math::{Iso3, Mat6, Stamp, iso2_from_iso3, iso3_from_iso2};
use crate::msgs::sensor_msgs::PointCloud2;
use crate::radar::RadarScan;
use crate::radar::doppler::RadarModel;
use crate::registration::{
    PreparedSubmap, RegistrationError, RegistrationResult, register_prepared,
};
use crate::submap::{OdometryBuffer, OdometryError, Submap, SubmapBuilder};
use kiddo::SquaredEuclidean;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, VecDeque};

/// When a new keyframe is taken.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KeyframeConfig {
    /// Odometry distance travelled since the last keyframe, m (default 5.0).
    pub distance: f64,
    /// Odometry heading change since the last keyframe, rad (default 0.5).
    pub angle: f64,
    /// Fewest submap points for a keyframe (default 50).
    pub min_points: usize,
}

impl Default for KeyframeConfig {
    fn default() -> Self {
        KeyframeConfig {
            distance: 5.0,
            angle: 0.5,
            min_points: 50,
        }
    }
}

impl KeyframeConfig {
    /// Rejects unusable values, naming the parameter under `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        if !(self.distance.is_finite() && self.distance > 0.0) {
            return Err(ConfigError::new(
                format!("{prefix}.distance"),
                "must be > 0 m",
            ));
        }
        if !(self.angle.is_finite() && self.angle > 0.0) {
            return Err(ConfigError::new(
                format!("{prefix}.angle"),
                "must be > 0 rad",
            ));
        }
        if self.min_points < 10 {
            return Err(ConfigError::new(
                format!("{prefix}.min_points"),
                "must be at least 10",
            ));
        }
        Ok(())
    }
}

/// Revisit search and acceptance of loop closures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoopConfig {
    /// Search for revisits at all (default true; off for pure submap collection).
    pub enabled: bool,
    /// Keyframes within this odometry distance of the current one are candidates, m (default 15).
    pub search_radius: f64,
    /// Fewest metres of odometry path between a candidate and the current keyframe (default 100).
    pub minimum_path_gap: f64,
    /// Candidates registered per keyframe, nearest first (default 3).
    pub maximum_candidates: usize,
    /// Fewest registration inliers to accept (default 15).
    pub minimum_inliers: usize,
    /// Largest translation standard deviation (largest eigenvalue of the x-y covariance), m
    /// (default 0.5).
    pub maximum_translation_std: f64,
    /// Largest yaw standard deviation, rad (default 0.02).
    pub maximum_rotation_std: f64,
}

impl Default for LoopConfig {
    fn default() -> Self {
        LoopConfig {
            enabled: true,
            search_radius: 15.0,
            minimum_path_gap: 100.0,
            maximum_candidates: 3,
            minimum_inliers: 15,
            maximum_translation_std: 0.5,
            maximum_rotation_std: 0.02,
        }
    }
}

impl LoopConfig {
    /// Rejects unusable values, naming the parameter under `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        let pos = |f: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(ConfigError::new(
                    format!("{prefix}.{f}"),
                    format!("{v} must be > 0"),
                ))
            }
        };
        pos("search_radius", self.search_radius)?;
        pos("maximum_translation_std", self.maximum_translation_std)?;
        pos("maximum_rotation_std", self.maximum_rotation_std)?;
        if !(self.minimum_path_gap.is_finite() && self.minimum_path_gap >= 0.0) {
            return Err(ConfigError::new(
                format!("{prefix}.minimum_path_gap"),
                "must be >= 0 m",
            ));
        }
        if self.maximum_candidates == 0 {
            return Err(ConfigError::new(
                format!("{prefix}.maximum_candidates"),
                "must be at least 1",
            ));
        }
        if self.minimum_inliers < 3 {
            return Err(ConfigError::new(
                format!("{prefix}.minimum_inliers"),
                "must be at least 3",
            ));
        }
        Ok(())
    }
}

/// A keyframe: a submap at a place, with what is needed to match it later.
#[derive(Debug)]
pub struct Keyframe {
    /// Sequential id, from 0.
    pub id: u64,
    /// Anchor stamp of its submap.
    pub stamp: Stamp,
    /// Odometry pose of the body at `stamp`.
    pub t_odom_body: Iso3,
    /// Odometry path length driven up to this keyframe, m.
    pub path_distance: f64,
    /// The submap (compensated and raw points, covariances).
    pub submap: Submap,
    /// Descriptors and trees of the points registration uses.
    pub prepared: PreparedSubmap,
}

/// A verified loop closure: the query keyframe's body frame in the match keyframe's body frame.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopClosure {
    /// Newer keyframe.
    pub query_id: u64,
    /// Older, revisited keyframe.
    pub match_id: u64,
    /// Query keyframe stamp.
    pub query_stamp: Stamp,
    /// Match keyframe stamp.
    pub match_stamp: Stamp,
    /// Odometry pose of the query keyframe.
    pub query_odom_pose: Iso3,
    /// Odometry pose of the match keyframe.
    pub match_odom_pose: Iso3,
    /// Query body frame in the match body frame.
    pub t_match_query: Iso3,
    /// Covariance of `t_match_query`, ROS order (x, y, z, rot x, rot y, rot z), right perturbation.
    pub covariance: Mat6,
    /// Registration inliers.
    pub inliers: u32,
    /// Quality score: inlier share of the candidate matches (0..1).
    pub score: f64,
}

/// Why a candidate revisit was not published.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum RejectReason {
    /// Registration failed (too few points or inliers, numerical failure).
    Registration,
    /// Fewer inliers than `loop.minimum_inliers`.
    FewInliers,
    /// The optimiser did not converge.
    NotConverged,
    /// The covariance exceeds `loop.maximum_*_std`.
    Uncertain,
}

impl RejectReason {
    /// Short snake_case name for logs and diagnostics.
    pub fn name(self) -> &'static str {
        match self {
            RejectReason::Registration => "registration_failed",
            RejectReason::FewInliers => "few_inliers",
            RejectReason::NotConverged => "not_converged",
            RejectReason::Uncertain => "covariance_too_large",
        }
    }
}

/// Why an input was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum DropReason {
    /// A cloud that could not be decoded (missing/mistyped field, truncated, bad layout).
    BadCloud,
    /// A cloud from a radar index that is not configured.
    UnknownRadar,
    /// A non-finite odometry pose.
    BadOdometry,
    /// A scan older than odometry history, or inside an odometry gap.
    NoOdometry,
    /// The pending-scan queue was full (odometry far behind).
    QueueFull,
}

impl DropReason {
    /// Short snake_case name for logs and diagnostics.
    pub fn name(self) -> &'static str {
        match self {
            DropReason::BadCloud => "bad_cloud",
            DropReason::UnknownRadar => "unknown_radar",
            DropReason::BadOdometry => "bad_odometry",
            DropReason::NoOdometry => "no_odometry",
            DropReason::QueueFull => "queue_full",
        }
    }
}

/// What a `push_*` call produced.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// A keyframe was added.
    Keyframe {
        /// Its id.
        id: u64,
        /// Its stamp.
        stamp: Stamp,
        /// Its odometry pose.
        t_odom_body: Iso3,
        /// Points in its submap.
        points: usize,
    },
    /// A loop closure passed every gate.
    Closure(Box<LoopClosure>),
    /// A candidate revisit was rejected.
    Rejected {
        /// Query keyframe.
        query_id: u64,
        /// Candidate keyframe.
        match_id: u64,
        /// Why.
        reason: RejectReason,
        /// Details for the log.
        detail: String,
    },
    /// An input was dropped.
    Dropped {
        /// Why.
        reason: DropReason,
        /// Details for the log.
        detail: String,
    },
    /// Time went backwards: odometry, scans and the rolling submap were reset; keyframes are kept.
    TimeReset {
        /// Newest stamp seen before.
        previous: Stamp,
        /// The stamp that went backwards.
        got: Stamp,
    },
}

/// Counters over the pipeline's life.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PipelineStats {
    /// Radar scans processed into the submap window.
    pub scans: u64,
    /// Odometry samples accepted.
    pub odometry: u64,
    /// Detections kept / dropped as moving / invalid.
    pub detections_kept: u64,
    /// Detections rejected as moving objects.
    pub detections_dynamic: u64,
    /// Non-finite or zero-range detections skipped while decoding or compensating.
    pub detections_invalid: u64,
    /// Scans whose Doppler ego-motion fit failed.
    pub doppler_fit_failures: u64,
    /// Inputs dropped, by reason.
    pub dropped: BTreeMap<DropReason, u64>,
    /// Candidates rejected, by reason.
    pub rejected: BTreeMap<RejectReason, u64>,
    /// Time resets (stamps going backwards).
    pub time_resets: u64,
    /// Keyframes taken.
    pub keyframes: u64,
    /// Registrations run.
    pub registrations: u64,
    /// Closures accepted.
    pub closures: u64,
    /// Scans waiting for odometry now.
    pub pending_scans: usize,
}

/// Most scans held while waiting for odometry to cover their stamps.
const MAX_PENDING: usize = 256;
/// A stamp this much older than the newest input counts as time going backwards, s.
const BACKWARDS_TOLERANCE: f64 = 1.0;

/// The DC-Loc pipeline state.
pub struct Pipeline {
    cfg: Config,
    odom: OdometryBuffer,
    builder: SubmapBuilder,
    pending: VecDeque<RadarScan>,
    keyframes: Vec<Keyframe>,
    tree: kiddo::MutableKdTree<f64, 2>,
    last_keyframe: Option<(Iso3, f64)>,
    path_distance: f64,
    last_odom: Option<Iso3>,
    newest_input: Option<Stamp>,
    stats: PipelineStats,
}

impl Pipeline {
    /// A pipeline for a validated configuration.
    pub fn new(cfg: Config) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let radars: Vec<RadarModel> = cfg
            .radar_list()
            .into_iter()
            .map(|(_, r)| RadarModel::from(r))
            .collect();
        Ok(Pipeline {
            odom: OdometryBuffer::new(cfg.odometry.clone()),
            builder: SubmapBuilder::new(cfg.submap.clone(), cfg.ego_motion.clone(), radars),
            pending: VecDeque::new(),
            keyframes: Vec::new(),
            tree: kiddo::MutableKdTree::default(),
            last_keyframe: None,
            path_distance: 0.0,
            last_odom: None,
            newest_input: None,
            stats: PipelineStats::default(),
            cfg,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// Counters.
    pub fn stats(&self) -> &PipelineStats {
        &self.stats
    }

    /// Keyframes so far, oldest first (index = id).
    pub fn keyframes(&self) -> &[Keyframe] {
        &self.keyframes
    }

    /// The current rolling submap (compensated, in the body frame at its newest scan).
    pub fn current_submap(&self) -> Option<Submap> {
        self.builder.build()
    }

    /// Index of the radar named `name` in `radar_names`.
    pub fn radar_index(&self, name: &str) -> Option<usize> {
        self.cfg.radar_names.iter().position(|n| n == name)
    }

    fn check_time(&mut self, stamp: Stamp, out: &mut Vec<Event>) {
        if let Some(prev) = self.newest_input {
            if prev.secs_since(stamp) > BACKWARDS_TOLERANCE {
                log::warn!(
                    "time went backwards ({:.3} s -> {:.3} s): resetting odometry and the rolling submap, keeping {} keyframes",
                    prev.as_secs_f64(),
                    stamp.as_secs_f64(),
                    self.keyframes.len()
                );
                self.odom.clear();
                self.builder.clear();
                self.pending.clear();
                self.last_keyframe = None;
                self.last_odom = None;
                self.newest_input = Some(stamp);
                self.stats.time_resets += 1;
                out.push(Event::TimeReset {
                    previous: prev,
                    got: stamp,
                });
                return;
            }
        }
        self.newest_input = Some(self.newest_input.map_or(stamp, |p| p.max(stamp)));
    }

    fn drop(&mut self, reason: DropReason, detail: String, out: &mut Vec<Event>) {
        *self.stats.dropped.entry(reason).or_default() += 1;
        out.push(Event::Dropped { reason, detail });
    }

    /// Feeds one odometry sample (`t_odom_body` at `stamp`); releases scans that were waiting for it.
    pub fn push_odometry(&mut self, stamp: Stamp, t_odom_body: Iso3) -> Vec<Event> {
        let mut out = Vec::new();
        self.check_time(stamp, &mut out);
        match self.odom.push(stamp, t_odom_body) {
            Ok(()) => {}
            Err(OdometryError::TimeWentBackwards { newest, got }) => {
                // Within the tolerance: an out-of-order sample, not a restart.
                self.drop(
                    DropReason::BadOdometry,
                    format!("odometry out of order: {got:?} after {newest:?}"),
                    &mut out,
                );
                return out;
            }
            Err(e) => {
                self.drop(DropReason::BadOdometry, e.to_string(), &mut out);
                return out;
            }
        }
        self.stats.odometry += 1;
        if let Some(prev) = self.last_odom {
            self.path_distance += (t_odom_body.translation.vector - prev.translation.vector).norm();
        }
        self.last_odom = Some(t_odom_body);
        self.process_pending(&mut out);
        out
    }

    /// Decodes and feeds one radar cloud from radar `radar` (index in `radar_names`).
    pub fn push_cloud(&mut self, radar: usize, cloud: &PointCloud2) -> Vec<Event> {
        let mut out = Vec::new();
        let Some(name) = self.cfg.radar_names.get(radar) else {
            self.drop(
                DropReason::UnknownRadar,
                format!("radar index {radar}"),
                &mut out,
            );
            return out;
        };
        let Some(rc) = self.cfg.radars.get(name) else {
            self.drop(
                DropReason::UnknownRadar,
                format!("radar `{name}`"),
                &mut out,
            );
            return out;
        };
        match decode_detections(cloud, &rc.fields) {
            Ok(decoded) => {
                self.stats.detections_invalid +=
                    (decoded.skipped_nonfinite + decoded.skipped_zero_range) as u64;
                let scan = RadarScan {
                    radar,
                    stamp: cloud.header.stamp.into(),
                    detections: decoded.detections,
                };
                out.extend(self.push_scan(scan));
            }
            Err(e) => self.drop(
                DropReason::BadCloud,
                format!("radar `{name}`: {e}"),
                &mut out,
            ),
        }
        out
    }

    /// Feeds one decoded scan.
    pub fn push_scan(&mut self, scan: RadarScan) -> Vec<Event> {
        let mut out = Vec::new();
        if scan.radar >= self.cfg.radar_names.len() {
            self.drop(
                DropReason::UnknownRadar,
                format!("radar index {}", scan.radar),
                &mut out,
            );
            return out;
        }
        self.check_time(scan.stamp, &mut out);
        if self.pending.len() >= MAX_PENDING {
            if let Some(old) = self.pending.pop_front() {
                self.drop(
                    DropReason::QueueFull,
                    format!(
                        "no odometry up to {:.3} s; dropped the oldest waiting scan",
                        old.stamp.as_secs_f64()
                    ),
                    &mut out,
                );
            }
        }
        let at = self.pending.partition_point(|s| s.stamp <= scan.stamp);
        self.pending.insert(at, scan);
        self.process_pending(&mut out);
        out
    }

    /// Processes every waiting scan that odometry can place now; at the end of a bag, call
    /// [`Pipeline::finish`] to drop the rest with a count.
    fn process_pending(&mut self, out: &mut Vec<Event>) {
        while let Some(scan) = self.pending.front() {
            let pose = match self.odom.pose_at(scan.stamp) {
                Ok(p) => p,
                Err(OdometryError::NotYet { .. }) => break,
                Err(e) => {
                    let e = e.to_string();
                    self.pending.pop_front();
                    self.drop(DropReason::NoOdometry, e, out);
                    continue;
                }
            };
            let Some(scan) = self.pending.pop_front() else {
                break;
            };
            let prior = self.odom.velocity_at(scan.stamp, 0.05);
            let Some(rep) = self.builder.add_scan(&scan, pose, prior) else {
                self.drop(
                    DropReason::UnknownRadar,
                    format!("radar index {}", scan.radar),
                    out,
                );
                continue;
            };
            self.stats.scans += 1;
            self.stats.detections_kept += rep.kept as u64;
            self.stats.detections_dynamic += rep.dynamic as u64;
            self.stats.detections_invalid += rep.invalid as u64;
            if !rep.doppler_fit {
                self.stats.doppler_fit_failures += 1;
            }
            log::debug!(
                "scan radar {} at {:.3} s: {} kept, {} moving, {} invalid",
                scan.radar,
                scan.stamp.as_secs_f64(),
                rep.kept,
                rep.dynamic,
                rep.invalid
            );
            self.maybe_keyframe(pose, out);
        }
        self.stats.pending_scans = self.pending.len();
    }

    /// Drops the scans still waiting for odometry (end of input) and counts them.
    pub fn finish(&mut self) -> Vec<Event> {
        let mut out = Vec::new();
        while let Some(s) = self.pending.pop_front() {
            self.drop(
                DropReason::NoOdometry,
                format!(
                    "input ended before odometry reached {:.3} s",
                    s.stamp.as_secs_f64()
                ),
                &mut out,
            );
        }
        self.stats.pending_scans = 0;
        out
    }

    fn maybe_keyframe(&mut self, pose: Iso3, out: &mut Vec<Event>) {
        if let Some((last, _)) = &self.last_keyframe {
            let rel = last.inverse() * pose;
            let moved = rel.translation.vector.xy().norm();
            let turned = iso2_from_iso3(&rel).rotation.angle().abs();
            if moved < self.cfg.keyframe.distance && turned < self.cfg.keyframe.angle {
                return;
            }
        }
        // Only with a full window: every radar has its N scans (or the window spans max_span).
        let Some(submap) = self.builder.build() else {
            return;
        };
        if submap.len() < self.cfg.keyframe.min_points {
            return;
        }
        let prepared = match PreparedSubmap::new(submap.point_set(true), &self.cfg.registration) {
            Ok(p) => p,
            Err(e) => {
                log::warn!("keyframe skipped: {e}");
                return;
            }
        };
        let id = self.keyframes.len() as u64;
        let kf = Keyframe {
            id,
            stamp: submap.anchor_stamp,
            t_odom_body: submap.t_odom_anchor,
            path_distance: self.path_distance,
            submap,
            prepared,
        };
        self.last_keyframe = Some((pose, self.path_distance));
        self.stats.keyframes += 1;
        log::debug!(
            "keyframe {id} at {:.3} s: {} points",
            kf.stamp.as_secs_f64(),
            kf.submap.len()
        );
        out.push(Event::Keyframe {
            id,
            stamp: kf.stamp,
            t_odom_body: kf.t_odom_body,
            points: kf.submap.len(),
        });
        if self.cfg.r#loop.enabled {
            self.search_revisits(&kf, out);
        }
        let p = kf.t_odom_body.translation.vector;
        // Ids fit u32 (kiddo's item type) for four billion keyframes; beyond, the search ignores them.
        if let Ok(item) = u32::try_from(id) {
            if let Err(e) = self.tree.add(&[p.x, p.y], item) {
                log::warn!("keyframe {id} not indexed for revisit search: {e:?}");
            }
        }
        self.keyframes.push(kf);
    }

    fn search_revisits(&mut self, query: &Keyframe, out: &mut Vec<Event>) {
        let lc = &self.cfg.r#loop;
        let p = query.t_odom_body.translation.vector;
        let r2 = lc.search_radius * lc.search_radius;
        let mut candidates: Vec<(f64, u64)> = Vec::new();
        self.tree
            .query(&[p.x, p.y])
            .within::<SquaredEuclidean<f64>>(r2)
            .unsorted()
            .visit(|n| candidates.push((n.distance, u64::from(n.item))));
        candidates.retain(|&(_, id)| {
            self.keyframes
                .get(id as usize)
                .is_some_and(|k| query.path_distance - k.path_distance >= lc.minimum_path_gap)
        });
        candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        candidates.truncate(lc.maximum_candidates);
        let mut best: Option<LoopClosure> = None;
        for (_, id) in candidates {
            let Some(cand) = self.keyframes.get(id as usize) else {
                continue;
            };
            self.stats.registrations += 1;
            let res = register_prepared(&query.prepared, &cand.prepared, &self.cfg.registration);
            match self.gate(query, cand, res) {
                Ok(c) => {
                    if best.as_ref().is_none_or(|b| c.score > b.score) {
                        best = Some(c);
                    }
                }
                Err((reason, detail)) => {
                    *self.stats.rejected.entry(reason).or_default() += 1;
                    log::debug!(
                        "revisit {} -> {} rejected ({}): {detail}",
                        query.id,
                        id,
                        reason.name()
                    );
                    out.push(Event::Rejected {
                        query_id: query.id,
                        match_id: id,
                        reason,
                        detail,
                    });
                }
            }
        }
        if let Some(c) = best {
            self.stats.closures += 1;
            log::info!(
                "loop closure {} -> {}: {} inliers, score {:.2}",
                c.query_id,
                c.match_id,
                c.inliers,
                c.score
            );
            out.push(Event::Closure(Box::new(c)));
        }
    }

    fn gate(
        &self,
        query: &Keyframe,
        cand: &Keyframe,
        res: Result<RegistrationResult, RegistrationError>,
    ) -> Result<LoopClosure, (RejectReason, String)> {
        let lc = &self.cfg.r#loop;
        let r = res.map_err(|e| (RejectReason::Registration, e.to_string()))?;
        if r.inliers < lc.minimum_inliers {
            return Err((RejectReason::FewInliers, format!("{} inliers", r.inliers)));
        }
        if !r.converged {
            return Err((
                RejectReason::NotConverged,
                format!("{} iterations", r.iterations),
            ));
        }
        let xy = r.covariance.fixed_view::<2, 2>(0, 0).into_owned();
        let t_std = xy.symmetric_eigenvalues().max().max(0.0).sqrt();
        let r_std = r.covariance[(5, 5)].max(0.0).sqrt();
        if !(t_std <= lc.maximum_translation_std && r_std <= lc.maximum_rotation_std) {
            return Err((
                RejectReason::Uncertain,
                format!("std {t_std:.3} m, {r_std:.4} rad"),
            ));
        }
        Ok(LoopClosure {
            query_id: query.id,
            match_id: cand.id,
            query_stamp: query.stamp,
            match_stamp: cand.stamp,
            query_odom_pose: query.t_odom_body,
            match_odom_pose: cand.t_odom_body,
            t_match_query: iso3_from_iso2(&r.t_target_source),
            covariance: r.covariance,
            inliers: r.inliers as u32,
            score: if r.candidates > 0 {
                r.inliers as f64 / r.candidates as f64
            } else {
                0.0
            },
        })
    }
}
