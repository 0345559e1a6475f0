//! What the pipeline reports: the [`Event`]s of each input, why an input was dropped
//! ([`DropReason`]), and the counters over its life ([`PipelineStats`]).

use std::collections::BTreeMap;
use std::sync::Arc;

use crate::fleet::FleetState;
use crate::keyframe_db::KeyframeRecord;
use crate::loop_closure::{LoopClosure, RejectReason};
use crate::math::{Iso3, Stamp};
use crate::odometry::{OdometryEstimate, RadarOdometryStats};
use crate::repeats::Repeats;
use crate::submap::Submap;

/// Why an input was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum DropReason {
    /// A cloud that could not be decoded (missing/mistyped field, truncated, bad layout).
    BadCloud,
    /// A cloud larger than the input limits (`node.max_cloud_points`, `node.max_cloud_bytes`).
    CloudTooLarge,
    /// A cloud from a radar index that is not configured.
    UnknownRadar,
    /// A non-finite odometry pose.
    BadOdometry,
    /// A scan older than odometry history, or inside an odometry gap.
    NoOdometry,
    /// The pending-scan queue was full (odometry far behind).
    QueueFull,
    /// A stamp more than 1 s older than the newest input, not (yet) taken as a restart (see
    /// [`super::Pipeline::set_restart_after`]).
    StampBackwards,
    /// A stamp more than 10 s after the newest input, not (yet) taken as a jump (see
    /// [`super::Pipeline::set_restart_after`]).
    StampAhead,
    /// A second scan of one radar with the same stamp (a re-sent or bogus message).
    DuplicateStamp,
    /// Another robot's keyframe that is malformed (see [`crate::fleet::wire::decode`]).
    BadKeyframe,
    /// Another robot's keyframe beyond `map.max_keyframes_per_robot` of that robot.
    KeyframeOverBudget,
    /// Another robot's keyframe while the map holds `map.max_keyframes`.
    KeyframeMapFull,
    /// Another robot's keyframe that cannot be indexed.
    KeyframeInvalid,
    /// A keyframe of another node with this node's `node.robot_id` (two robots configured alike).
    KeyframeSameRobotId,
}

impl DropReason {
    /// Short snake_case name for logs and diagnostics.
    pub fn name(self) -> &'static str {
        match self {
            DropReason::BadCloud => "bad_cloud",
            DropReason::CloudTooLarge => "cloud_too_large",
            DropReason::UnknownRadar => "unknown_radar",
            DropReason::BadOdometry => "bad_odometry",
            DropReason::NoOdometry => "no_odometry",
            DropReason::QueueFull => "queue_full",
            DropReason::StampBackwards => "stamp_backwards",
            DropReason::StampAhead => "stamp_ahead",
            DropReason::DuplicateStamp => "duplicate_stamp",
            DropReason::BadKeyframe => "bad_keyframe",
            DropReason::KeyframeOverBudget => "keyframe_over_budget",
            DropReason::KeyframeMapFull => "keyframe_map_full",
            DropReason::KeyframeInvalid => "keyframe_invalid",
            DropReason::KeyframeSameRobotId => "keyframe_same_robot_id",
        }
    }
}

/// What [`super::Pipeline::push`] produced.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// A keyframe was added.
    Keyframe {
        /// Its id in this robot's own sequence (other robots' keyframes do not count).
        id: u64,
        /// Its stamp.
        stamp: Stamp,
        /// Its odometry pose.
        t_odom_body: Iso3,
        /// Points in its submap.
        points: usize,
        /// The submap itself (shared; the database keeps a compact copy).
        submap: Arc<Submap>,
        /// The compact copy, as the map keeps it and the fleet receives it (with `id` above).
        record: Arc<KeyframeRecord>,
        /// What was known of the fleet when it was made, sent with it.
        fleet: FleetState,
    },
    /// A loop closure passed every gate.
    Closure(Box<LoopClosure>),
    /// An odometry sample of the radar odometry (`odometry.source: radar | radar_imu`), emitted
    /// before it enters the pipeline as a topic's sample would.
    Odometry(Box<OdometryEstimate>),
    /// A candidate revisit was rejected.
    Rejected {
        /// Query keyframe, in this robot's sequence.
        query_id: u64,
        /// Candidate keyframe, in its robot's sequence.
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
    /// A scan without a valid detection: counted (`empty_scans`) and fed on all the same (an empty
    /// scene is possible).
    EmptyScan {
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
    /// Detections outside `submap.height_band` (road surface, overhead).
    pub detections_out_of_band: u64,
    /// Scans without a valid detection, counted before the duplicate check (fed on all the same: an
    /// empty scene is possible).
    pub empty_scans: u64,
    /// Scans whose Doppler ego-motion fit failed, or ended farther from the odometry's velocity and
    /// the radar's previous fit than the body can change speed (`ego_motion.prior_tolerance`).
    pub doppler_fit_failures: u64,
    /// Per radar index: scans whose Doppler velocity disagreed with the odometry's.
    pub doppler_disagreements: BTreeMap<usize, u64>,
    /// Per radar index: the likely misconfiguration, once its Doppler persistently disagrees with the
    /// odometry, and the stamp of the scan that showed it.
    pub doppler_warnings: BTreeMap<usize, (Stamp, String)>,
    /// Inputs dropped, by reason.
    pub dropped: BTreeMap<DropReason, u64>,
    /// Inputs dropped, by cause (`reason: what it concerns`, e.g. `bad_cloud: radar `front`: field
    /// `v_r` (velocity) is not in the cloud; ...`): the first of each cause is logged in full.
    pub drop_causes: Repeats,
    /// Candidates rejected, by reason.
    pub rejected: BTreeMap<RejectReason, u64>,
    /// Time resets (stamps going backwards).
    pub time_resets: u64,
    /// New odometry tracks (the odometry jumped and stayed there).
    pub odometry_resets: u64,
    /// Keyframes taken.
    pub keyframes: u64,
    /// Keyframes not added because the map was full (`map.max_keyframes`).
    pub map_full: u64,
    /// Registrations run.
    pub registrations: u64,
    /// Closures accepted.
    pub closures: u64,
    /// Scans waiting for odometry now.
    pub pending_scans: usize,
    /// The newest keyframe's correction of the odometry's distances by the Doppler speeds
    /// (`submap.speed_scale_bound`; `None` before one was applied): about 1 / (1 + the odometry's
    /// scale error).
    pub speed_scale: Option<f64>,
    /// Keyframes whose Doppler and odometry distances disagreed beyond `submap.speed_scale_bound`
    /// (placed with the odometry as it is).
    pub speed_scale_refused: u64,
    /// Per other robot (`node.robot_id`): its keyframes received and what became of them.
    pub robots: BTreeMap<i32, RobotCounts>,
    /// The radar odometry's counters (`odometry.source: radar | radar_imu`).
    pub radar_odometry: Option<RadarOdometryStats>,
    /// Revisit search left out because its deadline had passed ([`super::Pipeline::set_deadline`]).
    pub trimmed: crate::loop_closure::deadline::Trimmed,
}

/// Another robot's keyframes received, and what became of them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RobotCounts {
    /// Received.
    pub received: u64,
    /// Added to the map.
    pub added: u64,
    /// Already in the map (a transient-local history delivered again).
    pub duplicates: u64,
    /// Refused (over budget, map full, invalid, this robot's id): counted as dropped inputs too.
    pub refused: u64,
}

/// Counts a dropped input, logs it in full the first time of its cause (`reason` and `cause`: what it
/// concerns, without stamps or counts, e.g. the radar) and at debug level after, and reports it.
pub(crate) fn dropped(
    stats: &mut PipelineStats,
    out: &mut Vec<Event>,
    reason: DropReason,
    cause: &str,
    detail: String,
) {
    *stats.dropped.entry(reason).or_default() += 1;
    let key = format!("{}: {cause}", reason.name());
    let message = format!("dropped input ({}): {detail}", reason.name());
    stats.drop_causes.warn_first(module_path!(), &key, &message);
    out.push(Event::Dropped { reason, detail });
}
