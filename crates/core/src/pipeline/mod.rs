//! The one pipeline every front end drives: the ROS node, the offline runner, the demo and the tests.
//!
//! [`Pipeline::push`] takes one [`Input`] and returns the [`Event`]s it produced; nothing calls back.
//! Steps, in order, as data arrives:
//! 1. the input's stamp is checked, a cloud decoded, odometry buffered ([`ingest`]);
//! 2. each scan waits until odometry covers its stamp, then is Doppler-compensated (paper eq. 4),
//!    given per-point covariances (eq. 6-8), cleared of moving objects and stacked into the rolling
//!    submap ([`crate::submap::SubmapBuilder`], eq. 5);
//! 3. after enough motion a keyframe is taken: the submap in compact form
//!    ([`crate::keyframe_db::KeyframeRecord`]) and ready for registration;
//! 4. its revisits are searched, registered and gated ([`crate::loop_closure::LoopCloser`]);
//! 5. it joins the keyframe map, and keyframes queued to be searched again are searched.
//!
//! Entry points: [`Pipeline`], [`Config`], [`Event`], [`PipelineStats`].

mod config;
mod events;
pub mod ingest;

pub use config::{Config, KeyframeConfig};
pub use events::{DropReason, Event, PipelineStats, RobotCounts};

use std::sync::Arc;

use crate::fleet::{FleetState, SharedAlignment, SharedKeyframe, wire};
use crate::input::{Input, InputLimits};
use crate::keyframe_db::{ForeignRefusal, KeyframeDb, KeyframeRecord};
use crate::loop_closure::{Decision, Decisions, LoopCloser};
use crate::math::{Iso3, Stamp, iso2_from_iso3};
use crate::msgs::dc_loc::Keyframe as KeyframeMsg;
use crate::odometry::OdometryEstimate;
use crate::pose_noise::PoseNoise;
use crate::radar::RadarScan;
use crate::registration::PreparedSubmap;
use crate::submap::{SpeedScale, Submap};
use crate::validate::ConfigError;
use events::dropped;
use ingest::{Ingest, OdometryCheck, TimeCheck};

/// The DC-Loc pipeline state.
pub struct Pipeline {
    cfg: Config,
    ingest: Ingest,
    db: KeyframeDb,
    loops: LoopCloser,
    session: u32,
    /// This robot's `node.robot_id` (0 unless set).
    robot: i32,
    /// The next keyframe's id (positions in the map while it is not full).
    next_id: u64,
    /// Odometry pose of the last keyframe.
    last_keyframe: Option<Iso3>,
    stats: PipelineStats,
}

impl Pipeline {
    /// A pipeline for a validated configuration, with an empty keyframe map.
    pub fn new(cfg: Config) -> Result<Self, ConfigError> {
        let db = KeyframeDb::new(cfg.place.clone(), cfg.map.prepared_cache);
        Self::with_map(cfg, db)
    }

    /// Takes the run-time parameters of `cfg` (`loop.*`, `keyframe.*`, see `dc_loc_io::params::live`);
    /// they apply from the next keyframe. Everything else of `cfg` is ignored.
    pub fn update_live(&mut self, cfg: &Config) {
        self.cfg.r#loop = cfg.r#loop.clone();
        self.cfg.keyframe = cfg.keyframe.clone();
        self.loops.set_config(cfg.r#loop.clone());
    }

    /// A pipeline that continues a keyframe map (e.g. loaded with [`KeyframeDb::load`]): its keyframes
    /// are revisit candidates, found by place descriptor (their odometry frame is another session's)
    /// and, from the first closure onto them on, near the position its alignment predicts; new
    /// keyframes get the next ids and a new session.
    pub fn with_map(cfg: Config, mut db: KeyframeDb) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let session = db.last_session().map_or(0, |s| s + 1);
        db.set_owner(0, session);
        Ok(Pipeline {
            ingest: Ingest::new(&cfg),
            loops: LoopCloser::new(cfg.r#loop.clone(), cfg.registration.clone(), session),
            next_id: db.next_id(),
            db,
            session,
            robot: 0,
            last_keyframe: None,
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

    /// The keyframe database (loaded map and this session's keyframes).
    pub fn db(&self) -> &KeyframeDb {
        &self.db
    }

    /// Ends the run and hands over its keyframe map (e.g. to the next session's [`Pipeline::with_map`]).
    pub fn into_db(self) -> KeyframeDb {
        self.db
    }

    /// This session's number.
    pub fn session(&self) -> u32 {
        self.session
    }

    /// Sets this robot's `node.robot_id`: its closures carry it, and other robots' keyframes are told
    /// from its own by it.
    pub fn set_robot(&mut self, robot: i32) {
        self.robot = robot;
        self.db.set_owner(robot, self.session);
    }

    /// This robot's id.
    pub fn robot(&self) -> i32 {
        self.robot
    }

    /// The current rolling submap (compensated, in the body frame at its newest scan).
    pub fn current_submap(&self) -> Option<Submap> {
        self.ingest.submap()
    }

    /// Index of the radar named `name` in `radar_names`.
    pub fn radar_index(&self, name: &str) -> Option<usize> {
        self.cfg.radar_names.iter().position(|n| n == name)
    }

    /// How many inputs in a row with stamps out of line with the newest input (more than 1 s before it:
    /// a bag replayed again, a simulator reset; more than 10 s after it: a jump after an outage) are
    /// taken as the new time rather than bad stamps (default 1: the first one; the node and `dc_loc
    /// run` use `node.restart_after`, default 20). The ones before are dropped as
    /// [`DropReason::StampBackwards`] or [`DropReason::StampAhead`]. Values below 1 count as 1.
    pub fn set_restart_after(&mut self, n: usize) {
        self.ingest.set_restart_after(n);
    }

    /// The largest cloud the pipeline decodes, and the largest scan it takes decoded (default
    /// [`InputLimits::default`]); larger ones are dropped as [`DropReason::CloudTooLarge`].
    pub fn set_input_limits(&mut self, limits: InputLimits) {
        self.ingest.set_input_limits(limits);
    }

    /// The time by which the revisit searches the next inputs set off should end (`None`, the default:
    /// no limit); past it the loop closer leaves work out in a fixed order and counts it
    /// ([`crate::loop_closure::deadline`], [`PipelineStats::trimmed`]). The node sets one per input
    /// (`node.keyframe_budget`); the offline runs set none.
    pub fn set_deadline(&mut self, at: Option<std::time::Instant>) {
        self.loops.set_deadline(at);
    }

    /// Feeds one input: the one door through which every source's data enters the pipeline. Ground
    /// truth is not an input of the pipeline (it produces nothing).
    pub fn push(&mut self, input: &Input) -> Vec<Event> {
        let mut out = Vec::new();
        match input {
            Input::Radar { radar, cloud } => {
                let decoded =
                    self.ingest
                        .decode(&self.cfg, *radar, cloud, &mut self.stats, &mut out);
                if let Some(scan) = decoded {
                    self.scan(scan, &mut out);
                }
            }
            Input::Scan(scan) => {
                if self
                    .ingest
                    .scan_fits(&self.cfg, scan, &mut self.stats, &mut out)
                {
                    self.scan(scan.clone(), &mut out);
                }
            }
            Input::Odometry { stamp, t_odom_body } => match self.ingest.radar_odometry() {
                Some(r) => r.ignore_topic(),
                None => self.odometry(*stamp, *t_odom_body, None, &mut out),
            },
            Input::Imu {
                stamp,
                angular_velocity,
            } => {
                if let Some(r) = self.ingest.radar_odometry() {
                    r.push_imu(*stamp, *angular_velocity);
                }
            }
            Input::Keyframe(k) => self.foreign(k, &mut out),
            Input::GroundTruth { .. } => {}
        }
        out
    }

    /// End of input: searches the keyframes still queued to be searched again
    /// (`loop.backfill_per_keyframe`), drops the scans still waiting for odometry and counts them.
    pub fn finish(&mut self) -> Vec<Event> {
        let mut out = Vec::new();
        if let Some(r) = self.ingest.radar_odometry() {
            let estimates = r.finish();
            self.radar_odometry(estimates, &mut out);
        }
        let mut decisions = Decisions::default();
        self.loops.set_deadline(None);
        self.loops
            .backfill(&mut self.db, usize::MAX, &mut decisions);
        self.report(decisions, &mut out);
        self.ingest.finish(&mut self.stats, &mut out);
        self.stats.pending_scans = 0;
        out
    }

    fn time(&mut self, stamp: Stamp, what: &str, out: &mut Vec<Event>) -> bool {
        match self.ingest.check_time(stamp, what, &mut self.stats, out) {
            TimeCheck::Go => true,
            TimeCheck::Dropped => false,
            TimeCheck::Restarted => {
                self.last_keyframe = None;
                true
            }
        }
    }

    fn odometry(
        &mut self,
        stamp: Stamp,
        t_odom_body: Iso3,
        noise: Option<PoseNoise>,
        out: &mut Vec<Event>,
    ) {
        if !self.time(stamp, "odometry", out) {
            return;
        }
        let odometry = &self.cfg.odometry;
        match self
            .ingest
            .odometry(odometry, stamp, t_odom_body, noise, &mut self.stats, out)
        {
            OdometryCheck::Dropped => return,
            OdometryCheck::Reset => self.last_keyframe = None,
            OdometryCheck::Accepted => {}
        }
        self.process_pending(out);
    }

    fn scan(&mut self, scan: RadarScan, out: &mut Vec<Event>) {
        if scan.radar >= self.cfg.radar_names.len() {
            let detail = format!("radar index {}", scan.radar);
            let cause = detail.clone();
            dropped(
                &mut self.stats,
                out,
                DropReason::UnknownRadar,
                &cause,
                detail,
            );
            return;
        }
        if !self.time(scan.stamp, "radar scan", out) {
            return;
        }
        let estimates = self.ingest.radar_odometry().map(|r| r.push_scan(&scan));
        self.ingest
            .queue_scan(&self.cfg, scan, &mut self.stats, out);
        self.process_pending(out);
        if let Some(estimates) = estimates {
            self.radar_odometry(estimates, out);
        }
    }

    /// The radar odometry's samples: each reported, then taken as a topic's sample is.
    fn radar_odometry(&mut self, estimates: Vec<OdometryEstimate>, out: &mut Vec<Event>) {
        for e in estimates {
            out.push(Event::Odometry(Box::new(e)));
            self.odometry(e.stamp, e.t_odom_body, Some(e.noise), out);
        }
        self.stats.radar_odometry = self.ingest.radar_odometry().map(|r| r.stats());
    }

    /// Stacks every waiting scan that odometry can place now, taking keyframes as the body moves.
    fn process_pending(&mut self, out: &mut Vec<Event>) {
        while let Some(pose) = self.ingest.next_scan(&self.cfg, &mut self.stats, out) {
            self.maybe_keyframe(pose, out);
        }
        self.stats.pending_scans = self.ingest.pending();
    }

    /// A keyframe when the body moved `keyframe.distance` or turned `keyframe.angle` since the last
    /// one and the submap holds `keyframe.min_points`: into the map, its revisits searched.
    fn maybe_keyframe(&mut self, pose: Iso3, out: &mut Vec<Event>) {
        if let Some(last) = &self.last_keyframe {
            let rel = last.inverse() * pose;
            let moved = rel.translation.vector.xy().norm();
            let turned = iso2_from_iso3(&rel).rotation.angle().abs();
            if moved < self.cfg.keyframe.distance && turned < self.cfg.keyframe.angle {
                return;
            }
        }
        let Some(submap) = self.ingest.submap() else {
            return;
        };
        if submap.len() < self.cfg.keyframe.min_points {
            return;
        }
        self.note_speed_scale(submap.speed_scale);
        if let (Some(first), Some(last)) = (submap.scans.first(), submap.scans.last()) {
            self.loops
                .note_submap_span(last.stamp.secs_since(first.stamp));
        }
        self.loops.note_submap_motion(submap.motion);
        let id = self.next_id;
        let path = self.ingest.path_distance();
        let rec = KeyframeRecord::from_submap(
            id,
            self.session,
            &submap,
            path,
            self.cfg.map.max_points_per_keyframe,
            &self.cfg.place,
        );
        let prepared = match PreparedSubmap::new(rec.point_set(), &self.cfg.registration) {
            Ok(p) => Arc::new(p),
            Err(e) => {
                log::warn!("keyframe skipped: {e}");
                return;
            }
        };
        self.last_keyframe = Some(pose);
        self.next_id += 1;
        self.stats.keyframes += 1;
        let public = KeyframeRecord {
            id: self.db.public_id(id).1,
            ..rec.clone()
        };
        log::debug!(
            "keyframe {} at {:.3} s: {} points",
            public.id,
            rec.stamp.as_secs_f64(),
            submap.len()
        );
        out.push(Event::Keyframe {
            id: public.id,
            stamp: submap.anchor_stamp,
            t_odom_body: submap.t_odom_anchor,
            points: submap.len(),
            submap: Arc::new(submap),
            record: Arc::new(public),
            fleet: self.fleet_state(),
        });
        let mut decisions = Decisions::default();
        if self.cfg.r#loop.enabled {
            self.loops
                .search(&mut self.db, &rec, &prepared, &mut decisions);
        }
        self.store(rec, prepared);
        let n = self.cfg.r#loop.backfill_per_keyframe;
        self.loops.backfill(&mut self.db, n, &mut decisions);
        self.report(decisions, out);
    }

    /// What this node knows of the fleet: the newest keyframe of each other robot it holds and its
    /// accepted alignments to other robots' sessions.
    fn fleet_state(&self) -> FleetState {
        let foreign = self.db.foreign();
        let alignments = self.loops.state().alignments().iter();
        FleetState {
            heard: foreign.newest(),
            alignments: alignments
                .filter_map(|(&local, a)| {
                    let (robot, session) = foreign.session_origin(local)?;
                    Some(SharedAlignment {
                        robot,
                        session,
                        alignment: *a,
                    })
                })
                .collect(),
        }
    }

    /// Another robot's keyframe: decoded (its place descriptor made with `place.*`; a malformed one
    /// dropped as [`DropReason::BadKeyframe`]), into the map as a session of that robot's (within
    /// `map.max_keyframes_per_robot` and `map.max_keyframes`), then this session's keyframes that may
    /// revisit it and are newer are registered against it. This node's own keyframes, echoed by the
    /// fleet topic, are ignored.
    fn foreign(&mut self, msg: &KeyframeMsg, out: &mut Vec<Event>) {
        let k = match wire::decode(msg, &self.cfg.place) {
            Ok(k) => k,
            Err(e) => {
                let detail = format!("keyframe {} of robot {}: {e}", msg.id, msg.robot_id);
                let cause = format!("robot {}", msg.robot_id);
                dropped(
                    &mut self.stats,
                    out,
                    DropReason::BadKeyframe,
                    &cause,
                    detail,
                );
                return;
            }
        };
        let counts = self.stats.robots.entry(k.robot).or_default();
        counts.received += 1;
        if k.robot == self.robot {
            if k.record.session != self.session {
                counts.refused += 1;
                let detail = format!(
                    "keyframe {} of session {} carries this node's robot id {}: give every robot its own node.robot_id",
                    k.record.id, k.record.session, k.robot
                );
                let cause = format!("robot {}", k.robot);
                dropped(
                    &mut self.stats,
                    out,
                    DropReason::KeyframeSameRobotId,
                    &cause,
                    detail,
                );
            }
            return;
        }
        let (max_robot, max_all) = (
            self.cfg.map.max_keyframes_per_robot,
            self.cfg.map.max_keyframes,
        );
        let added = self.db.insert_foreign(
            k.record.clone(),
            k.origin(),
            k.fleet.heard.clone(),
            max_robot,
            max_all,
        );
        take_shared_alignment(&mut self.loops, &self.db, (self.robot, self.session), &k);
        match added {
            Ok(id) => {
                counts.added += 1;
                self.next_id = self.next_id.max(self.db.next_id());
                if self.cfg.r#loop.enabled {
                    let mut decisions = Decisions::default();
                    self.loops.search_arrival(&mut self.db, id, &mut decisions);
                    self.report(decisions, out);
                }
            }
            Err(ForeignRefusal::Duplicate) => counts.duplicates += 1,
            Err(why) => {
                counts.refused += 1;
                let reason = match why {
                    ForeignRefusal::OverBudget => DropReason::KeyframeOverBudget,
                    ForeignRefusal::MapFull => DropReason::KeyframeMapFull,
                    _ => DropReason::KeyframeInvalid,
                };
                let detail = format!(
                    "keyframe {} of robot {} not added ({} of its keyframes held, map.max_keyframes_per_robot {max_robot}; {} in the map, map.max_keyframes {max_all})",
                    k.record.id,
                    k.robot,
                    self.db.foreign().count(k.robot),
                    self.db.len()
                );
                let cause = format!("robot {}", k.robot);
                dropped(&mut self.stats, out, reason, &cause, detail);
            }
        }
    }

    /// Adds a keyframe to the map, unless the map is full (`map.max_keyframes`).
    fn store(&mut self, rec: KeyframeRecord, prepared: Arc<PreparedSubmap>) {
        let id = rec.id;
        if self.db.len() >= self.cfg.map.max_keyframes {
            self.stats.map_full += 1;
            if self.stats.map_full == 1 {
                log::warn!(
                    "the keyframe map holds map.max_keyframes ({}): new keyframes close loops against it but are not added",
                    self.cfg.map.max_keyframes
                );
            }
            return;
        }
        if self.db.insert(rec) {
            self.db.put_prepared(id as usize, prepared);
        } else {
            log::warn!("keyframe {id} could not be added to the database");
        }
    }

    /// Counts the submap's correction of the odometry's distances by the radars' Doppler speeds.
    fn note_speed_scale(&mut self, scale: SpeedScale) {
        match scale {
            SpeedScale::Applied(k) => self.stats.speed_scale = Some(k),
            SpeedScale::Refused(k) => {
                self.stats.speed_scale_refused += 1;
                // The first and every hundredth: a misconfigured radar would refuse every keyframe.
                let level = if self.stats.speed_scale_refused % 100 == 1 {
                    log::Level::Warn
                } else {
                    log::Level::Debug
                };
                log::log!(
                    level,
                    "the radars' Doppler speeds say the body covered {k:.3} times the distance the odometry says, beyond submap.speed_scale_bound {}: keyframe placed with the odometry as it is (check the odometry's speed and the radars' radial velocity fields; {} keyframes so far)",
                    self.cfg.submap.speed_scale_bound,
                    self.stats.speed_scale_refused
                );
            }
            SpeedScale::Unavailable => {}
        }
    }

    /// The loop closer's decisions as events, counted.
    fn report(&mut self, decisions: Decisions, out: &mut Vec<Event>) {
        self.stats.registrations += decisions.registrations;
        self.stats.trimmed.add(decisions.trimmed);
        for d in decisions.decisions {
            match d {
                Decision::Published(mut c) => {
                    self.stats.closures += 1;
                    c.query_robot = self.robot;
                    c.match_origin = self.db.foreign().origin(c.match_id).copied();
                    c.query_id = self.db.public_id(c.query_id).1;
                    c.match_id = self.db.public_id(c.match_id).1;
                    out.push(Event::Closure(c));
                }
                Decision::Rejected {
                    query_id,
                    match_id,
                    reason,
                    detail,
                } => {
                    *self.stats.rejected.entry(reason).or_default() += 1;
                    out.push(Event::Rejected {
                        query_id: self.db.public_id(query_id).1,
                        match_id: self.db.public_id(match_id).1,
                        reason,
                        detail,
                    });
                }
            }
        }
    }
}

/// The sender's accepted alignment to this node's robot and session (`own`), if `k` carries one:
/// inverted, it is this session's odometry frame in the sender's session's frame, the prior the gates
/// test closures to that session against until this node accepts an alignment of its own.
fn take_shared_alignment(
    loops: &mut LoopCloser,
    db: &KeyframeDb,
    own: (i32, u32),
    k: &SharedKeyframe,
) {
    let Some(local) = db.foreign().session(&k.origin()) else {
        return;
    };
    let mine = |a: &&SharedAlignment| (a.robot, a.session) == own;
    if let Some(a) = k.fleet.alignments.iter().find(mine) {
        loops.take_shared(local, a.alignment.inverse());
    }
}

#[cfg(test)]
mod tests;
