//! The one pipeline every front end drives: the ROS node, the offline bag runner, the demo and the tests.
//!
//! Steps, in order, as data arrives: decode a radar cloud -> wait until odometry covers its stamp ->
//! Doppler compensation, covariance, moving-object rejection ([`crate::submap::SubmapBuilder`]) ->
//! keyframe decision -> revisit search in the keyframe database -> registration -> gates -> closure.
//! Nothing calls back: [`Pipeline::push`] returns the [`Event`]s it produced, and counters live in
//! [`PipelineStats`].
//!
//! Entry points: [`Pipeline`], [`Event`], [`LoopClosure`], [`KeyframeConfig`], [`LoopConfig`],
//! [`MapConfig`], [`PipelineStats`]; the keyframe map is [`crate::keyframe_db`].

use crate::cloud::decode_detections;
use crate::config::Config;
use crate::input::Input;
use crate::keyframe_db::{CandidateQuery, KeyframeDb, KeyframeRecord, SearchSettings};
use crate::math::se2_log;
use crate::math::{Iso2, Iso3, Mat3, Mat6, Stamp, iso2_from_iso3, iso3_from_iso2};
use crate::msgs::sensor_msgs::PointCloud2;
use crate::radar::RadarScan;
use crate::radar::doppler::RadarModel;
use crate::registration::{
    PreparedSubmap, RegistrationError, RegistrationResult, common_view, overlap_near,
    register_prepared, slide_overlap,
};
use crate::submap::{OdometryBuffer, OdometryError, SpeedScale, Submap, SubmapBuilder};
use crate::validate::{ConfigError, Range, Validator};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;

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
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.positive("distance", self.distance);
        v.positive("angle", self.angle);
        v.at_least("min_points", self.min_points, 10);
    }
}

/// Revisit search and acceptance of loop closures. Every gate is a parameter; every rejection is counted
/// by reason ([`RejectReason`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoopConfig {
    /// Search for revisits at all (default true; off for pure submap collection).
    pub enabled: bool,
    /// Base search radius around the odometry position, m (default 15).
    pub search_radius: f64,
    /// Odometry drift model, translation: the search radius grows by this many metres per metre of path
    /// driven since the candidate keyframe, and the consistency check allows as much (default 0.05:
    /// 5 % of distance).
    pub drift_rate: f64,
    /// Odometry drift model, heading: rad per metre of path (default 5e-4, about 2.9 deg per 100 m).
    pub drift_yaw_rate: f64,
    /// Largest search radius, m (default 300).
    pub search_radius_max: f64,
    /// Fewest metres of odometry path between a same-session candidate and the current keyframe
    /// (default 100).
    pub minimum_path_gap: f64,
    /// Place-descriptor candidates retrieved per keyframe, whatever the odometry says (default 25;
    /// 0 disables retrieval by place).
    pub place_retrieve: usize,
    /// Largest place-descriptor distance (0..1) of a candidate found by place only (default 0.45).
    pub place_maximum_distance: f64,
    /// Candidates registered per keyframe, best place match first (default 4).
    pub maximum_candidates: usize,
    /// Fewest registration inliers to accept (default 15).
    pub minimum_inliers: usize,
    /// Smallest overlap (share of points with a partner at the result) to accept (default 0.3).
    pub minimum_overlap: f64,
    /// Largest translation standard deviation (largest eigenvalue of the x-y covariance), m
    /// (default 0.5).
    pub maximum_translation_std: f64,
    /// Largest yaw standard deviation, rad (default 0.02).
    pub maximum_rotation_std: f64,
    /// Largest ratio of the best *other* alignment's overlap to the result's (`runner_up_overlap /
    /// overlap`, 0..1): a street whose facades still fit when slid along itself gives two alignments of
    /// nearly equal support, and picking one of them is a guess (default 0.8; 1 disables the gate).
    /// A fresh accepted alignment of the session (`trusted_prior_std`) tells them apart when the
    /// result's translation standard deviation is at most half `maximum_translation_std`, it agrees
    /// with the alignment's prediction, every alternative that fits nearly as well contradicts it,
    /// and the dense stage started at the prediction ends at the result. A closure published alone
    /// because it agrees with a fresh alignment passes that last test too: the dense stage started
    /// at the prediction must end at the result, or where it ends must fit with at most this share
    /// of the result's overlap (with the Doppler speed scale on, one radar at 1 % drift published a
    /// closure slid 4.57 m along its street that agreed with a prediction from 60 m of path before;
    /// the full `dc_loc revisits` matrix had 4 such at 1-3 % drift, none with the test; measured
    /// while building, with no switch left in the code). Without the third condition
    /// one radar at 1 % drift published two closures slid 2.4 and 3.1 m along their street; without
    /// the first, tests/node.rs's drive published one 1.07 m off with a standard deviation of 0.27 m
    /// along the street (where the geometry is weak, the local optimum the prior picks is too).
    pub maximum_ambiguity: f64,
    /// A closure to a session without an accepted alignment (the first closures to it) is refused
    /// when the registration, slid along the query's heading by 3-24 m and refined there, fits with
    /// more than this share of its overlap ([`slide_overlap`]; default 0.7; 1 disables). Along a
    /// straight street a forward radar sees two facades that fit at any shift: one radar on the
    /// simulated city matched keyframes to others 130-500 m further along the same streets. Measured
    /// on `dc_loc revisits --radars carla --drift 3 --direction same -p loop.confirmations:=1 -p
    /// loop.maximum_slide_ratio:=1 --closures-out F` with `examples/closure_features.rs`: the 58
    /// false closures had a share of 0.64-1.44 (one at most 0.7), the 75 true ones 0.22-0.97, on
    /// the straight where lap 2 starts 0.49-0.97 and around the next corner mostly below 0.7. So the
    /// first closures come from distinctive places, and the ones after them are vouched for by the
    /// alignment they gave. Five radars see the street far both ways: on the Gamma drive the same
    /// way, the 436 true closures had 0.11-0.95 (median 0.79) and the 4 false ones 0.88-1.05; hence
    /// this bound is kept to a session's first closures. The other closures that wait for
    /// confirmation (no fresh alignment vouches for them) are refused when a slid alignment fits
    /// better than the result (share above 1): the result is then not the best alignment around,
    /// and closures further along the same street would confirm the same mistake. Five radars,
    /// Gamma, 5 % drift (beyond the drift model): 6 false closures 140 m off, of which 5 had a share
    /// of 1.00-1.10, without this; none with it.
    pub maximum_slide_ratio: f64,
    /// Smallest share of the two submaps' bearing histograms, turned by the result's yaw, that
    /// coincide ([`common_view`]; default 0.25; 0 disables). A forward radar driving a street the other
    /// way sees what lay behind it the first time, and a high overlap there is aliasing: one radar on
    /// the simulated reverse laps (`dc_loc revisits --radars carla --direction reverse`, 1 % drift)
    /// published 5 false closures and 7 true ones out of 404 opportunities, all with a common view of
    /// 0.05-0.14; the five radars' reverse closures had 0.40-0.77 and a forward radar's same-way ones
    /// 0.55-0.99 (`examples/closure_features.rs`).
    pub minimum_common_view: f64,
    /// Consistency gate: largest squared Mahalanobis distance (3 dof) between a closure and what odometry
    /// and the earlier accepted closures predict, under the closure's covariance plus the drift model's
    /// (default 16.27, the 99.9 % chi-square quantile; 0 disables the check).
    pub consistency_chi2: f64,
    /// Mutually consistent closures (from different query keyframes) needed before the first closure to
    /// a session is published: until then nothing but odometry (or, for a loaded map, nothing at all)
    /// vouches for them, and a single aliased match would misalign everything after it (default 2; 1
    /// publishes at once). Before a session has an accepted alignment, the candidate search also looks
    /// around the position the newest held closure predicts, so that the closures that would confirm
    /// it are registered (measured while building, with no switch left in the code: one radar, 3 %
    /// drift, recall 0 % without it and 83 % with it, once `maximum_slide_ratio` refused the slid
    /// first closures).
    pub confirmations: usize,
    /// The confirming closures' query keyframes must lie at least this many metres of path apart
    /// (default 30): one aliased place seen from two neighbouring keyframes agrees with itself, two
    /// places along the route rarely alias the same way.
    pub confirmation_span: f64,
    /// At least one of the closures that confirm each other must have this overlap (default 0.6;
    /// 0 disables): weak matches along an aliased street agree with each other as well as true
    /// ones do. Measured on `dc_loc revisits --radars nuscenes --noise gaussian,gamma,student-t
    /// --drift 1,3,5 -p loop.confirmation_overlap:=0` (debug log of the held closures' overlaps
    /// against `--closures-out`): the 4 false confirmations (at 5 %
    /// drift, beyond the drift model; streets 147 m and 520-630 m away) had a best overlap of
    /// 0.45-0.55, the true ones 0.62-0.97 but for one of 0.47 (two closures within the first
    /// lap, closed later by others).
    pub confirmation_overlap: f64,
    /// Held closures expire after this many metres of path without confirmation, before they may
    /// confirm a newer one (default 150): a true alignment is confirmed within a few keyframes, and over
    /// a long path the agreement test is too loose to tell a street slid by some metres from the right
    /// alignment (measured: a 19 m false closure confirmed by true ones 325 m of path earlier).
    pub confirmation_horizon: f64,
    /// A closure that agrees with the session's accepted alignment is published alone while that
    /// alignment's predicted translation standard deviation (0.5 m plus half the drift rate times the
    /// path since the last closure) is at most this, m (default 2.0: about 60 m of path at 5 % drift);
    /// after longer gaps closures wait for confirmation like the first ones.
    pub trusted_prior_std: f64,
    /// Keyframes searched again per new keyframe once closures to a session are confirmed (default
    /// 1; 0 disables, also at the end of a bag). The keyframes of the last `backfill_horizon` metres of path that got no
    /// closure while nothing vouched for their matches (a session's first closures wait for a
    /// distinctive place and for confirmation) are searched again, newest first, around the
    /// alignment the confirmation gave and then around each closure these searches publish; what
    /// agrees with it is published then, late. One at a time keeps the added latency to one more
    /// search per keyframe.
    pub backfill_per_keyframe: usize,
    /// Metres of path back that a confirmation's searches again reach (default 500; at least
    /// `confirmation_horizon`). They walk back along the route, newest first: each closure they
    /// publish gives the alignment the next older keyframe is searched around, so a confirmation
    /// that came late still closes the keyframes since the revisit began. The walk stops where no
    /// alignment is fresh enough to vouch (`trusted_prior_std`). Measured on `dc_loc
    /// revisits --radars nuscenes --noise student-t --drift 1 --direction same` with
    /// `submap.speed_scale_bound` 0.1, where the first closure was confirmed about 340 m into
    /// the revisit: recall 99.3 %, against 89.0 % with `-p loop.backfill_horizon:=150` (the only
    /// row of the full matrix that changes) and 83.6 % without searching again
    /// (`loop.backfill_per_keyframe` 0; `tests/revisits.rs`). Walking back from each closure found
    /// rather than searching around the confirmation's alignment alone (measured while building,
    /// with no switch left in the code) raised recall in 13 of the matrix's 36 scenarios and
    /// lowered it in none, with no false closure added.
    pub backfill_horizon: f64,
    /// Let the registration of revisit candidates run its correlative search
    /// (`registration.correlative`, default false). The search finds alignments the descriptors
    /// missed; here most of what it finds has fewer descriptor inliers than `minimum_inliers` and
    /// is refused anyway, and it runs on every candidate that does not fit (most of them).
    /// Measured with `dc_loc revisits` at 3 % drift, Gaussian noise, same direction: five radars,
    /// recall 97.9 -> 99.1 % and 3.7 times the run time; one radar, 92.3 -> 91.6 % and 1.6 times
    /// the run time; no false closure either way.
    pub correlative_search: bool,
}

impl Default for LoopConfig {
    fn default() -> Self {
        LoopConfig {
            enabled: true,
            search_radius: 15.0,
            drift_rate: 0.05,
            drift_yaw_rate: 5e-4,
            search_radius_max: 300.0,
            minimum_path_gap: 100.0,
            place_retrieve: 25,
            place_maximum_distance: 0.45,
            maximum_candidates: 4,
            minimum_inliers: 15,
            minimum_overlap: 0.3,
            maximum_translation_std: 0.5,
            maximum_rotation_std: 0.02,
            maximum_ambiguity: 0.8,
            maximum_slide_ratio: 0.7,
            minimum_common_view: 0.25,
            consistency_chi2: 16.27,
            confirmations: 2,
            confirmation_span: 30.0,
            confirmation_overlap: 0.6,
            confirmation_horizon: 150.0,
            trusted_prior_std: 2.0,
            backfill_per_keyframe: 1,
            backfill_horizon: 500.0,
            correlative_search: false,
        }
    }
}

impl LoopConfig {
    /// Declares each field's range; each horizon reaches at least as far as the one before it.
    pub fn check(&self, v: &mut Validator) {
        v.positive("search_radius", self.search_radius);
        v.positive("trusted_prior_std", self.trusted_prior_std);
        v.positive("maximum_translation_std", self.maximum_translation_std);
        v.positive("maximum_rotation_std", self.maximum_rotation_std);
        v.non_negative("drift_rate", self.drift_rate);
        v.non_negative("drift_yaw_rate", self.drift_yaw_rate);
        v.non_negative("minimum_path_gap", self.minimum_path_gap);
        v.non_negative("consistency_chi2", self.consistency_chi2);
        v.non_negative("confirmation_span", self.confirmation_span);
        v.at_least("confirmations", self.confirmations, 1);
        v.range(
            "confirmation_horizon",
            self.confirmation_horizon,
            Range::at_least(self.confirmation_span),
        );
        v.range(
            "backfill_horizon",
            self.backfill_horizon,
            Range::at_least(self.confirmation_horizon),
        );
        v.range(
            "search_radius_max",
            self.search_radius_max,
            Range::at_least(self.search_radius),
        );
        v.unit("place_maximum_distance", self.place_maximum_distance);
        v.unit("confirmation_overlap", self.confirmation_overlap);
        v.unit("minimum_common_view", self.minimum_common_view);
        v.unit("maximum_slide_ratio", self.maximum_slide_ratio);
        v.unit("maximum_ambiguity", self.maximum_ambiguity);
        v.unit("minimum_overlap", self.minimum_overlap);
        v.at_least("maximum_candidates", self.maximum_candidates, 1);
        v.at_least("minimum_inliers", self.minimum_inliers, 3);
    }

    /// The candidate-search view of these settings.
    pub fn search(&self) -> SearchSettings {
        SearchSettings {
            radius: self.search_radius,
            drift_rate: self.drift_rate,
            max_radius: self.search_radius_max,
            min_path_gap: self.minimum_path_gap,
            place_retrieve: self.place_retrieve,
            place_max_distance: self.place_maximum_distance,
            max_candidates: self.maximum_candidates,
        }
    }
}

/// The keyframe map: where it is kept and how it is loaded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    /// Most points kept per keyframe (default 4000: stored quantised at 7 bytes a point, under 32 KB per
    /// keyframe with its descriptor).
    pub max_points_per_keyframe: usize,
    /// Registration-ready keyframes kept in memory (default 64).
    pub prepared_cache: usize,
}

impl Default for MapConfig {
    fn default() -> Self {
        MapConfig {
            file: String::new(),
            start_empty_on_error: false,
            save_interval: 30.0,
            max_points_per_keyframe: 4000,
            prepared_cache: 64,
        }
    }
}

impl MapConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.positive("save_interval", self.save_interval);
        v.at_least("max_points_per_keyframe", self.max_points_per_keyframe, 10);
        v.at_least("prepared_cache", self.prepared_cache, 1);
    }
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
    /// Quality score: the registration's overlap (share of points with a partner, 0..1).
    pub score: f64,
    /// Session of the match keyframe (an earlier drive when it came from a loaded map).
    pub match_session: u32,
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
    /// The overlap is below `loop.minimum_overlap`.
    LowOverlap,
    /// The closure contradicts odometry and earlier closures (`loop.consistency_chi2`).
    Inconsistent,
    /// Another alignment fits nearly as well (`loop.maximum_ambiguity`, `loop.maximum_slide_ratio`).
    Ambiguous,
    /// The two submaps look in directions too different to have seen the same things
    /// (`loop.minimum_common_view`).
    NoCommonView,
}

impl RejectReason {
    /// Short snake_case name for logs and diagnostics.
    pub fn name(self) -> &'static str {
        match self {
            RejectReason::Registration => "registration_failed",
            RejectReason::FewInliers => "few_inliers",
            RejectReason::NotConverged => "not_converged",
            RejectReason::Uncertain => "covariance_too_large",
            RejectReason::LowOverlap => "low_overlap",
            RejectReason::Inconsistent => "inconsistent",
            RejectReason::Ambiguous => "ambiguous",
            RejectReason::NoCommonView => "no_common_view",
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
    /// A stamp more than 1 s older than the newest input, not (yet) taken as a restart (see
    /// [`Pipeline::set_restart_after`]).
    StampBackwards,
    /// A second scan of one radar with the same stamp (a re-sent or bogus message).
    DuplicateStamp,
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
            DropReason::StampBackwards => "stamp_backwards",
            DropReason::DuplicateStamp => "duplicate_stamp",
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
        /// The submap itself (shared; the database keeps a compact copy).
        submap: Arc<Submap>,
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
    /// Scans without a valid detection, counted before the duplicate check (fed on all the same: an
    /// empty scene is possible).
    pub empty_scans: u64,
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
    /// The newest keyframe's correction of the odometry's distances by the Doppler speeds
    /// (`submap.speed_scale_bound`; `None` before one was applied): about 1 / (1 + the odometry's
    /// scale error).
    pub speed_scale: Option<f64>,
    /// Keyframes whose Doppler and odometry distances disagreed beyond `submap.speed_scale_bound`
    /// (placed with the odometry as it is).
    pub speed_scale_refused: u64,
}

/// Gate on the agreement of two closures' alignments (the 99.9 % chi-square quantile, 3 dof).
const CONFIRM_CHI2: f64 = 16.27;
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
    db: KeyframeDb,
    session: u32,
    /// Per session of earlier keyframes: the latest accepted alignment of this session's odometry frame
    /// into that session's frame, and the path length at which it was found.
    alignments: BTreeMap<u32, (Iso2, f64)>,
    /// Per session without an alignment yet: closures waiting for confirmation, with the alignment each
    /// implies and the path length at which it was found.
    tentative: BTreeMap<u32, Vec<(LoopClosure, Iso2, f64)>>,
    /// This session's keyframes of the last `loop.backfill_horizon` metres without a published
    /// closure (id, path length), and the ones queued to be searched again
    /// (`loop.backfill_per_keyframe`), newest first.
    unclosed: VecDeque<(u64, f64)>,
    backfill: VecDeque<u64>,
    /// The alignment the keyframes queued to be searched again are searched around (session, alignment,
    /// path length): the confirmation's, then each closure those searches publish.
    backfill_alignment: Option<(u32, Iso2, f64)>,
    last_keyframe: Option<(Iso3, f64)>,
    path_distance: f64,
    last_odom: Option<Iso3>,
    newest_input: Option<Stamp>,
    /// Inputs in a row with stamps going backwards, and how many make a restart.
    backwards_run: usize,
    restart_after: usize,
    /// Newest scan stamp per radar (duplicates are dropped).
    last_scan_stamp: BTreeMap<usize, Stamp>,
    stats: PipelineStats,
}

impl Pipeline {
    /// A pipeline for a validated configuration, with an empty keyframe map.
    pub fn new(cfg: Config) -> Result<Self, ConfigError> {
        let db = KeyframeDb::new(cfg.place.clone(), cfg.map.prepared_cache);
        Self::with_map(cfg, db)
    }

    /// A pipeline that continues a keyframe map (e.g. loaded with [`KeyframeDb::load`]): its keyframes
    /// are revisit candidates, found by place descriptor (their odometry frame is another session's), and
    /// new keyframes get the next ids and a new session.
    pub fn with_map(cfg: Config, db: KeyframeDb) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let session = db.last_session().map_or(0, |s| s + 1);
        let radars: Vec<RadarModel> = cfg
            .radar_list()
            .into_iter()
            .map(|(_, r)| RadarModel::from(r))
            .collect();
        Ok(Pipeline {
            odom: OdometryBuffer::new(cfg.odometry.clone()),
            builder: SubmapBuilder::new(cfg.submap.clone(), cfg.ego_motion.clone(), radars),
            pending: VecDeque::new(),
            db,
            session,
            alignments: BTreeMap::new(),
            tentative: BTreeMap::new(),
            unclosed: VecDeque::new(),
            backfill: VecDeque::new(),
            backfill_alignment: None,
            last_keyframe: None,
            path_distance: 0.0,
            last_odom: None,
            newest_input: None,
            backwards_run: 0,
            restart_after: 1,
            last_scan_stamp: BTreeMap::new(),
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

    /// This session's number.
    pub fn session(&self) -> u32 {
        self.session
    }

    /// The current rolling submap (compensated, in the body frame at its newest scan).
    pub fn current_submap(&self) -> Option<Submap> {
        self.builder.build()
    }

    /// Index of the radar named `name` in `radar_names`.
    pub fn radar_index(&self, name: &str) -> Option<usize> {
        self.cfg.radar_names.iter().position(|n| n == name)
    }

    /// How many inputs in a row with stamps more than 1 s before the newest input mean a restart (a bag
    /// replayed again, a simulator reset) rather than stale messages (default 1: the first one, as in
    /// an offline bag; the node uses `node.restart_after`). The ones before are dropped as
    /// [`DropReason::StampBackwards`]. Values below 1 count as 1.
    pub fn set_restart_after(&mut self, n: usize) {
        self.restart_after = n.max(1);
    }

    /// True when an input at `stamp` may go on: its stamp is not too far back, or a run of them is
    /// taken as a restart (then everything but the keyframes is reset, [`Event::TimeReset`]).
    fn check_time(&mut self, stamp: Stamp, what: &str, out: &mut Vec<Event>) -> bool {
        if let Some(prev) = self.newest_input {
            if prev.secs_since(stamp) > BACKWARDS_TOLERANCE {
                self.backwards_run += 1;
                if self.backwards_run < self.restart_after {
                    self.drop(
                        DropReason::StampBackwards,
                        format!(
                            "{what} at {:.3} s, {:.3} s before the newest input",
                            stamp.as_secs_f64(),
                            prev.secs_since(stamp)
                        ),
                        out,
                    );
                    return false;
                }
                self.backwards_run = 0;
                log::warn!(
                    "time went backwards ({:.3} s -> {:.3} s): resetting odometry and the rolling submap, keeping {} keyframes",
                    prev.as_secs_f64(),
                    stamp.as_secs_f64(),
                    self.db.len()
                );
                self.odom.clear();
                self.builder.clear();
                self.pending.clear();
                self.last_keyframe = None;
                self.last_odom = None;
                self.last_scan_stamp.clear();
                self.newest_input = Some(stamp);
                self.stats.time_resets += 1;
                out.push(Event::TimeReset {
                    previous: prev,
                    got: stamp,
                });
                return true;
            }
        }
        self.backwards_run = 0;
        self.newest_input = Some(self.newest_input.map_or(stamp, |p| p.max(stamp)));
        true
    }

    fn drop(&mut self, reason: DropReason, detail: String, out: &mut Vec<Event>) {
        *self.stats.dropped.entry(reason).or_default() += 1;
        out.push(Event::Dropped { reason, detail });
    }

    /// Feeds one input: the one door through which every source's data enters the pipeline. Ground
    /// truth is not an input of the pipeline (it produces nothing).
    pub fn push(&mut self, input: &Input) -> Vec<Event> {
        match input {
            Input::Radar { radar, cloud } => self.push_cloud(*radar, cloud),
            Input::Scan(scan) => self.push_scan(scan.clone()),
            Input::Odometry { stamp, t_odom_body } => self.push_odometry(*stamp, *t_odom_body),
            Input::GroundTruth { .. } => Vec::new(),
        }
    }

    /// Feeds one odometry sample (`t_odom_body` at `stamp`); releases scans that were waiting for it.
    fn push_odometry(&mut self, stamp: Stamp, t_odom_body: Iso3) -> Vec<Event> {
        let mut out = Vec::new();
        if !self.check_time(stamp, "odometry", &mut out) {
            return out;
        }
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
    fn push_cloud(&mut self, radar: usize, cloud: &PointCloud2) -> Vec<Event> {
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
    fn push_scan(&mut self, scan: RadarScan) -> Vec<Event> {
        let mut out = Vec::new();
        if scan.radar >= self.cfg.radar_names.len() {
            self.drop(
                DropReason::UnknownRadar,
                format!("radar index {}", scan.radar),
                &mut out,
            );
            return out;
        }
        if !self.check_time(scan.stamp, "radar scan", &mut out) {
            return out;
        }
        if scan.detections.is_empty() {
            self.stats.empty_scans += 1;
            let name = &self.cfg.radar_names[scan.radar];
            out.push(Event::EmptyScan {
                detail: format!(
                    "radar `{name}` at {:.3} s: no valid point",
                    scan.stamp.as_secs_f64()
                ),
            });
        }
        // A second scan of one radar with the same stamp is a re-sent or bogus message.
        if self.last_scan_stamp.get(&scan.radar) == Some(&scan.stamp) {
            let name = &self.cfg.radar_names[scan.radar];
            let detail = format!(
                "radar `{name}`: a second scan stamped {:.3} s",
                scan.stamp.as_secs_f64()
            );
            self.drop(DropReason::DuplicateStamp, detail, &mut out);
            return out;
        }
        self.last_scan_stamp.insert(scan.radar, scan.stamp);
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

    /// End of input: searches the keyframes still queued to be searched again
    /// (`loop.backfill_per_keyframe`), drops the scans still waiting for odometry and counts them.
    pub fn finish(&mut self) -> Vec<Event> {
        let mut out = Vec::new();
        // The keyframes still queued to be searched again are searched now.
        self.run_backfill(self.backfill.len(), &mut out);
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
        let Some(submap) = self.builder.build() else {
            return;
        };
        if submap.len() < self.cfg.keyframe.min_points {
            return;
        }
        match submap.speed_scale {
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
        let id = self.db.next_id();
        let rec = KeyframeRecord::from_submap(
            id,
            self.session,
            &submap,
            self.path_distance,
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
        self.last_keyframe = Some((pose, self.path_distance));
        self.stats.keyframes += 1;
        log::debug!(
            "keyframe {id} at {:.3} s: {} points",
            rec.stamp.as_secs_f64(),
            submap.len()
        );
        let stamp = submap.anchor_stamp;
        let t_odom_body = submap.t_odom_anchor;
        out.push(Event::Keyframe {
            id,
            stamp,
            t_odom_body,
            points: submap.len(),
            submap: Arc::new(submap),
        });
        let path = rec.path_distance;
        if self.cfg.r#loop.enabled {
            let horizon = self.cfg.r#loop.backfill_horizon;
            self.unclosed.retain(|&(_, p)| path - p <= horizon);
            self.unclosed.push_back((id, path));
            self.search_revisits(&rec, &prepared, false, out);
        }
        if self.db.insert(rec) {
            self.db.put_prepared(id as usize, prepared);
        } else {
            log::warn!("keyframe {id} could not be added to the database");
        }
        self.run_backfill(self.cfg.r#loop.backfill_per_keyframe, out);
    }

    /// Searches up to `n` queued keyframes again (`loop.backfill_per_keyframe`).
    fn run_backfill(&mut self, n: usize, out: &mut Vec<Event>) {
        for _ in 0..n {
            let Some(id) = self.backfill.pop_front() else {
                return;
            };
            let Some(rec) = self.db.get(id).cloned() else {
                continue;
            };
            let prepared = match self.db.prepared(id as usize, &self.cfg.registration) {
                Ok(p) => p,
                Err(e) => {
                    log::debug!("keyframe {id} not searched again: {e}");
                    continue;
                }
            };
            // Searched around the chain's alignment instead of the newest one, which is put back
            // after.
            let newest = self
                .backfill_alignment
                .map(|(s, a, p)| (s, self.alignments.insert(s, (a, p))));
            // Only what agrees with a fresh alignment is published from here, and the keyframes
            // queued after this one lie further back along the path: once no alignment is fresh
            // enough to vouch (`loop.trusted_prior_std`), the rest are not searched.
            let lc = &self.cfg.r#loop;
            let fresh = self
                .alignments
                .values()
                .any(|&(_, path_a)| vouches(rec.path_distance - path_a, lc));
            let published = if fresh {
                self.search_revisits(&rec, &prepared, true, out)
            } else {
                None
            };
            if let Some((s, before)) = newest {
                match before {
                    Some(v) => self.alignments.insert(s, v),
                    None => self.alignments.remove(&s),
                };
            }
            if !fresh {
                log::debug!(
                    "keyframe {id} and {} older ones not searched again: no alignment is fresh enough there",
                    self.backfill.len()
                );
                self.backfill.clear();
                return;
            }
            if let Some(c) = published {
                if let Some((s, a)) = self.closure_alignment(&rec, &c) {
                    self.backfill_alignment = Some((s, a, rec.path_distance));
                }
            }
        }
    }

    fn search_revisits(
        &mut self,
        query: &KeyframeRecord,
        prepared: &PreparedSubmap,
        again: bool,
        out: &mut Vec<Event>,
    ) -> Option<LoopClosure> {
        // Around the accepted alignment's prediction too, or, before there is one, the newest held
        // closure's: the closures that would confirm it are then among the candidates.
        let alignment = self.alignments.get(&self.session).copied().or_else(|| {
            let held = self.tentative.get(&self.session)?.last()?;
            Some((held.1, held.2))
        });
        let candidates = self.db.candidates(
            &CandidateQuery { query, alignment },
            self.session,
            &self.cfg.r#loop.search(),
        );
        let mut best: Option<(LoopClosure, bool)> = None;
        let mut targets = Vec::with_capacity(candidates.len());
        for cand in candidates {
            match self.db.prepared(cand.index, &self.cfg.registration) {
                Ok(t) => targets.push((cand.index as u64, t)),
                Err(e) => {
                    let id = cand.index as u64;
                    self.reject(query.id, id, RejectReason::Registration, e.to_string(), out)
                }
            }
        }
        // The registrations are independent: they run in parallel (rayon) and are gated in candidate
        // order, so the outcome is the same as one after another, sooner.
        self.stats.registrations += targets.len() as u64;
        let mut cfg = self.cfg.registration.clone();
        cfg.correlative.enabled &= self.cfg.r#loop.correlative_search;
        let results: Vec<_> = targets
            .par_iter()
            .map(|(_, target)| register_prepared(prepared, target, &cfg))
            .collect();
        let mut passed = Vec::new();
        for ((id, target), res) in targets.into_iter().zip(results) {
            let Some(rec) = self.db.get(id) else { continue };
            match self.gate(query, rec, res, prepared, &target) {
                Ok(g) => passed.push((g, target)),
                Err((reason, detail)) => self.reject(query.id, id, reason, detail, out),
            }
        }
        // The best closure: those that agree with the accepted alignment first, then by score, the
        // earlier candidate among equals (a stable sort). The slide test, the costliest gate, runs
        // in that order until one passes: the same closure as testing every one, with less work
        // (the candidates after the winner are neither tested nor counted as rejected).
        passed.sort_by(|(a, _), (b, _)| {
            (b.agrees, b.closure.score)
                .partial_cmp(&(a.agrees, a.closure.score))
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        for (g, target) in passed {
            if let Some(p) = &g.prediction {
                if let Err((reason, detail)) =
                    self.prediction_test(p, &g.closure, prepared, &target)
                {
                    self.reject(query.id, g.closure.match_id, reason, detail, out);
                    continue;
                }
            }
            if let Some(s) = &g.slide {
                if let Err((reason, detail)) = self.slide_test(s, prepared, &target) {
                    self.reject(query.id, g.closure.match_id, reason, detail, out);
                    continue;
                }
            }
            best = Some((g.closure, g.agrees));
            break;
        }
        let (c, agrees) = best?;
        if !again {
            self.accept(query, c, agrees, out);
            None
        } else if agrees {
            // Searched again once an alignment vouches: only what agrees with it is published.
            self.publish(vec![c.clone()], out);
            Some(c)
        } else {
            None
        }
    }

    /// The session a closure goes to and the alignment of this session's odometry frame into that
    /// session's frame it implies.
    fn closure_alignment(&self, query: &KeyframeRecord, c: &LoopClosure) -> Option<(u32, Iso2)> {
        let m = self.db.get(c.match_id)?;
        let a = m.t_odom_body * iso2_from_iso3(&c.t_match_query) * query.t_odom_body.inverse();
        Some((m.session, a))
    }

    /// Publishes a closure that passed the gates, or holds it until confirmed (`loop.confirmations`):
    /// the first closures to a session, and closures that contradict the session's accepted alignment
    /// but not odometry (`agrees` false; confirmed, they replace the alignment, so one false closure
    /// that slipped through cannot block every true one after it).
    fn accept(
        &mut self,
        query: &KeyframeRecord,
        c: LoopClosure,
        agrees: bool,
        out: &mut Vec<Event>,
    ) {
        // The closure's alignment of this session's odometry into the match's session frame.
        let Some((session, a)) = self.closure_alignment(query, &c) else {
            return;
        };
        let mut publish = Vec::new();
        if (agrees && self.alignments.contains_key(&session)) || self.cfg.r#loop.confirmations <= 1
        {
            publish.push(c);
        } else {
            let pending = self.tentative.entry(session).or_default();
            let lc = &self.cfg.r#loop;
            // Old unconfirmed hypotheses expire before they may confirm anything
            // (`loop.confirmation_horizon`).
            pending.retain(|p| query.path_distance - p.2 <= lc.confirmation_horizon);
            let agree: Vec<usize> = (0..pending.len())
                .filter(|&k| {
                    let (old, a_old, path_old) = &pending[k];
                    old.query_id != c.query_id
                        && alignment_distance(
                            a_old,
                            &a,
                            &query.t_odom_body,
                            query.path_distance - path_old,
                            lc,
                        ) <= CONFIRM_CHI2
                })
                .collect();
            let span = agree
                .iter()
                .map(|&k| (query.path_distance - pending[k].2).abs())
                .fold(0.0, f64::max);
            let strong = c.score >= lc.confirmation_overlap
                || agree
                    .iter()
                    .any(|&k| pending[k].0.score >= lc.confirmation_overlap);
            if agree.len() + 1 >= lc.confirmations && span >= lc.confirmation_span && strong {
                let mut kept = std::mem::take(pending);
                for k in agree.into_iter().rev() {
                    publish.push(kept.swap_remove(k).0);
                }
                publish.sort_by_key(|p| p.query_id);
                publish.push(c);
                log::info!(
                    "closures to session {session} confirmed by {} agreeing matches",
                    publish.len()
                );
                // The keyframes before the confirmation that got nothing are searched again (not
                // even at the end of a bag when `backfill_per_keyframe` is 0).
                let unclosed = std::mem::take(&mut self.unclosed);
                self.backfill = if self.cfg.r#loop.backfill_per_keyframe > 0 {
                    let done = |id: u64| id == query.id || publish.iter().any(|p| p.query_id == id);
                    unclosed
                        .iter()
                        .rev()
                        .map(|&(id, _)| id)
                        .filter(|&id| !done(id))
                        .collect()
                } else {
                    VecDeque::new()
                };
                self.backfill_alignment = Some((session, a, query.path_distance));
            } else {
                log::debug!(
                    "closure {} -> {} held until another closure to session {session} confirms it ({} inliers, overlap {:.2}, alignment {:.2} {:.2} {:.3})",
                    c.query_id,
                    c.match_id,
                    c.inliers,
                    c.score,
                    a.translation.x,
                    a.translation.y,
                    a.rotation.angle()
                );
                pending.push((c, a, query.path_distance));
                return;
            }
        }
        self.alignments.insert(session, (a, query.path_distance));
        self.publish(publish, out);
    }

    /// Publishes closures that passed every gate.
    fn publish(&mut self, publish: Vec<LoopClosure>, out: &mut Vec<Event>) {
        for c in publish {
            self.unclosed.retain(|&(id, _)| id != c.query_id);
            self.stats.closures += 1;
            log::info!(
                "loop closure {} -> {} (session {}): {} inliers, overlap {:.2}",
                c.query_id,
                c.match_id,
                c.match_session,
                c.inliers,
                c.score
            );
            out.push(Event::Closure(Box::new(c)));
        }
    }

    fn reject(
        &mut self,
        query_id: u64,
        match_id: u64,
        reason: RejectReason,
        detail: String,
        out: &mut Vec<Event>,
    ) {
        *self.stats.rejected.entry(reason).or_default() += 1;
        log::debug!(
            "revisit {query_id} -> {match_id} rejected ({}): {detail}",
            reason.name()
        );
        out.push(Event::Rejected {
            query_id,
            match_id,
            reason,
            detail,
        });
    }

    /// The gates, in order: registration, inliers, convergence, overlap, common view, ambiguity,
    /// covariance, consistency, prediction (for closures that agree with a fresh alignment), slide.
    fn gate(
        &self,
        query: &KeyframeRecord,
        cand: &KeyframeRecord,
        res: Result<RegistrationResult, RegistrationError>,
        source: &PreparedSubmap,
        target: &PreparedSubmap,
    ) -> Result<Gated, (RejectReason, String)> {
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
        if r.overlap < lc.minimum_overlap {
            return Err((
                RejectReason::LowOverlap,
                format!("overlap {:.2}", r.overlap),
            ));
        }
        if lc.minimum_common_view > 0.0 {
            let view = common_view(source, target, &r.t_target_source);
            if view < lc.minimum_common_view {
                return Err((
                    RejectReason::NoCommonView,
                    format!(
                        "common view {view:.2} at a relative yaw of {:.2} rad",
                        r.t_target_source.rotation.angle()
                    ),
                ));
            }
        }
        // Only a fresh alignment vouches for a single closure: long after the last closure its
        // prediction is too loose to tell a slid or aliased match from the right one.
        let trusted = self
            .alignments
            .get(&cand.session)
            .is_some_and(|&(_, path_a)| vouches(query.path_distance - path_a, lc));
        if lc.maximum_ambiguity < 1.0 && r.runner_up_overlap > lc.maximum_ambiguity * r.overlap {
            // The submaps cannot tell the alignments apart; a fresh accepted alignment can, when the
            // result is well determined where it is (translation standard deviation at most half the
            // covariance gate's), agrees with the prediction, every alternative that fits nearly as
            // well contradicts it, and the dense stage started at the prediction ends at the result
            // (the prediction's own error may be metres, a street slid by as much would agree with it).
            let d2 = |t: &Iso2| self.inconsistency(query, cand, t, &r.covariance, true);
            let chi2 = lc.consistency_chi2;
            let resolved = trusted
                && chi2 > 0.0
                && translation_std(&r.covariance) <= 0.5 * lc.maximum_translation_std
                && d2(&r.t_target_source).is_some_and(|d| d <= chi2)
                && r.alternatives
                    .iter()
                    .filter(|a| a.1 > lc.maximum_ambiguity * r.overlap)
                    .all(|(t, _)| d2(t).is_some_and(|d| d > chi2))
                && self.alignments.get(&cand.session).is_some_and(|&(a, _)| {
                    let predicted = predict(&a, query, cand);
                    let rc = &self.cfg.registration;
                    overlap_near(source, target, &predicted, rc).is_ok_and(|near| {
                        near.is_some_and(|(t, _)| rc.same_alignment(&t, &r.t_target_source))
                    })
                });
            if !resolved {
                return Err((
                    RejectReason::Ambiguous,
                    format!(
                        "another alignment has overlap {:.2} against {:.2}",
                        r.runner_up_overlap, r.overlap
                    ),
                ));
            }
            log::debug!(
                "revisit {} -> {}: another alignment has overlap {:.2} against {:.2}, but only this one agrees with the accepted alignment",
                query.id,
                cand.id,
                r.runner_up_overlap,
                r.overlap
            );
        }
        let t_std = translation_std(&r.covariance);
        let r_std = r.covariance[(5, 5)].max(0.0).sqrt();
        if !(t_std <= lc.maximum_translation_std && r_std <= lc.maximum_rotation_std) {
            return Err((
                RejectReason::Uncertain,
                format!("std {t_std:.3} m, {r_std:.4} rad"),
            ));
        }
        // Consistency: with the session's accepted alignment when there is one; a closure that
        // contradicts it but agrees with odometry alone (or, for another session, has nothing to
        // contradict) may still be right, and waits for confirmation.
        let mut agrees = trusted;
        if lc.consistency_chi2 > 0.0 {
            let t = &r.t_target_source;
            let aligned = self.inconsistency(query, cand, t, &r.covariance, true);
            if aligned.is_some_and(|d2| d2 > lc.consistency_chi2) {
                agrees = false;
                // Does the accepted alignment's prediction fit the submaps nearly as well? Then the
                // scene aliases (a street sliding along itself) and the prior decides: reject.
                if let Some(&(a, _)) = self.alignments.get(&cand.session) {
                    let predicted = predict(&a, query, cand);
                    if let Ok(Some((_, o))) =
                        overlap_near(source, target, &predicted, &self.cfg.registration)
                    {
                        if lc.maximum_ambiguity < 1.0 && o > lc.maximum_ambiguity * r.overlap {
                            return Err((
                                RejectReason::Ambiguous,
                                format!(
                                    "the accepted alignment's prediction fits too (overlap {o:.2} against {:.2})",
                                    r.overlap
                                ),
                            ));
                        }
                    }
                }
                let odometry = self.inconsistency(query, cand, t, &r.covariance, false);
                if let Some(d2) = odometry.filter(|&d2| d2 > lc.consistency_chi2) {
                    return Err((
                        RejectReason::Inconsistent,
                        format!(
                            "squared Mahalanobis distance {d2:.1} to the odometry prediction, {:.1} to the accepted alignment's",
                            aligned.unwrap_or(f64::NAN)
                        ),
                    ));
                }
            }
        }
        // A closure published alone on the alignment's word: the prediction may be metres off, and
        // a street slid by as much agrees with it too (the prediction test, run by the caller on
        // the best closures only, see [`Pipeline::prediction_test`]).
        let prediction = (agrees && lc.maximum_ambiguity < 1.0)
            .then(|| self.alignments.get(&cand.session))
            .flatten()
            .map(|(a, _)| predict(a, query, cand));
        // The slide test (run by the caller on the best closures only, see [`Pipeline::slide_test`]):
        // for a session's first closures against `maximum_slide_ratio`; for the other closures that
        // wait for confirmation, a slid alignment must not fit better than the result (then the
        // result is not the best alignment around, and agreeing closures along the same street
        // cannot make it so).
        let first = !self.alignments.contains_key(&cand.session);
        let slide = (lc.maximum_slide_ratio < 1.0 && (first || !agrees)).then_some(Slide {
            t: r.t_target_source,
            overlap: r.overlap,
            ratio: if first { lc.maximum_slide_ratio } else { 1.0 },
            first,
        });
        let closure = LoopClosure {
            query_id: query.id,
            match_id: cand.id,
            query_stamp: query.stamp,
            match_stamp: cand.stamp,
            query_odom_pose: query.odom_pose_iso3(),
            match_odom_pose: cand.odom_pose_iso3(),
            t_match_query: iso3_from_iso2(&r.t_target_source),
            covariance: r.covariance,
            inliers: r.inliers as u32,
            score: r.overlap,
            match_session: cand.session,
        };
        Ok(Gated {
            closure,
            agrees,
            prediction,
            slide,
        })
    }

    /// The prediction test of a closure that agrees with a fresh alignment and passed the other
    /// gates: the dense stage started at the alignment's prediction must end at the result, or where
    /// it ends must fit with at most `loop.maximum_ambiguity` of the result's overlap.
    fn prediction_test(
        &self,
        predicted: &Iso2,
        c: &LoopClosure,
        source: &PreparedSubmap,
        target: &PreparedSubmap,
    ) -> Result<(), (RejectReason, String)> {
        let rc = &self.cfg.registration;
        let t = iso2_from_iso3(&c.t_match_query);
        if let Ok(Some((near, o))) = overlap_near(source, target, predicted, rc) {
            if !rc.same_alignment(&near, &t) && o > self.cfg.r#loop.maximum_ambiguity * c.score {
                let d = (near.translation.vector - t.translation.vector).norm();
                return Err((
                    RejectReason::Ambiguous,
                    format!(
                        "started at the accepted alignment's prediction it ends {d:.2} m away with overlap {o:.2} against {:.2}",
                        c.score
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The slide test of a closure that passed the other gates ([`slide_overlap`], stopping at the
    /// first shift above the limit).
    fn slide_test(
        &self,
        s: &Slide,
        source: &PreparedSubmap,
        target: &PreparedSubmap,
    ) -> Result<(), (RejectReason, String)> {
        let limit = s.ratio * s.overlap;
        let rc = &self.cfg.registration;
        let slid = slide_overlap(source, target, &s.t, rc, limit)
            .map_err(|e| (RejectReason::Registration, e.to_string()))?;
        if slid > limit {
            return Err((
                RejectReason::Ambiguous,
                format!(
                    "slid along the heading it fits {} (overlap {slid:.2} against {:.2}), and no fresh accepted alignment to its session vouches for it",
                    if s.first { "too" } else { "better" },
                    s.overlap
                ),
            ));
        }
        Ok(())
    }

    /// Squared Mahalanobis distance between a registered `T_match_query` (`t`, covariance `cov` in ROS
    /// order) and its prediction from
    /// the last accepted closure to the candidate's session (drift since that closure; only when
    /// `use_alignment`) or from odometry (same session: no correction, drift since the candidate);
    /// `None` when there is nothing to predict with (the first closure to a loaded map's session).
    fn inconsistency(
        &self,
        query: &KeyframeRecord,
        cand: &KeyframeRecord,
        t: &Iso2,
        cov6: &Mat6,
        use_alignment: bool,
    ) -> Option<f64> {
        let lc = &self.cfg.r#loop;
        let accepted = if use_alignment {
            self.alignments.get(&cand.session)
        } else {
            None
        };
        let (alignment, path_gap, from_alignment) = match accepted {
            Some(&(a, path_a)) => (a, (query.path_distance - path_a).abs(), true),
            None if cand.session == self.session => (
                Iso2::identity(),
                (query.path_distance - cand.path_distance).abs(),
                false,
            ),
            None => return None,
        };
        let predicted = predict(&alignment, query, cand);
        let e = se2_log(&(t.inverse() * predicted));
        let (sigma_t, sigma_r) = if from_alignment {
            alignment_sigmas(path_gap, lc)
        } else {
            drift_sigmas(path_gap, lc)
        };
        let mut cov = Mat3::zeros();
        for (i, j) in [
            (0usize, 0usize),
            (0, 1),
            (1, 0),
            (1, 1),
            (0, 5),
            (5, 0),
            (1, 5),
            (5, 1),
            (5, 5),
        ] {
            let (a, b) = (if i == 5 { 2 } else { i }, if j == 5 { 2 } else { j });
            cov[(a, b)] = cov6[(i, j)];
        }
        cov[(0, 0)] += sigma_t * sigma_t;
        cov[(1, 1)] += sigma_t * sigma_t;
        cov[(2, 2)] += sigma_r * sigma_r;
        let inv = cov.try_inverse()?;
        Some(e.dot(&(inv * e)))
    }
}

/// The `T_match_query` an alignment of the query's odometry frame into the match's session frame
/// predicts.
fn predict(alignment: &Iso2, query: &KeyframeRecord, cand: &KeyframeRecord) -> Iso2 {
    cand.t_odom_body.inverse() * alignment * query.t_odom_body
}

/// Whether an accepted alignment found `path_gap` metres of path away is fresh enough to vouch for
/// a closure alone (`loop.trusted_prior_std`).
fn vouches(path_gap: f64, lc: &LoopConfig) -> bool {
    alignment_sigmas(path_gap, lc).0 <= lc.trusted_prior_std
}

/// Largest translation standard deviation of a covariance in ROS order (largest eigenvalue of its x-y
/// block), m.
fn translation_std(cov: &Mat6) -> f64 {
    let xy = cov.fixed_view::<2, 2>(0, 0).into_owned();
    xy.symmetric_eigenvalues().max().max(0.0).sqrt()
}

/// A closure that passed the gates before the slide test.
struct Gated {
    closure: LoopClosure,
    /// It agrees with a fresh accepted alignment (published alone).
    agrees: bool,
    /// Where that alignment predicts the result, for the prediction test it still needs.
    prediction: Option<Iso2>,
    /// The slide test it still needs.
    slide: Option<Slide>,
}

/// A pending slide test: the result, its overlap, the largest share of it a slid alignment may
/// reach, and whether it is a session's first closure.
struct Slide {
    t: Iso2,
    overlap: f64,
    ratio: f64,
    first: bool,
}

/// Standard deviations (m, rad) of the odometry drift over `path_gap` metres: the drift model's bounds
/// (search radius plus `drift_rate` per metre, 0.05 rad plus `drift_yaw_rate` per metre) read as three
/// standard deviations, so that the default 3-dof chi-square gate accepts a closure whose translation
/// and heading errors both lie near their bounds (heading drift also moves the position). Read as four,
/// true closures at 85 % and 68 % of the two bounds were refused (chi-square 16.4-17.3), and the one-radar
/// drift at 3 % then confirmed a false alignment instead (`dc_loc revisits`, carla 3 % same).
fn drift_sigmas(path_gap: f64, lc: &LoopConfig) -> (f64, f64) {
    let gap = path_gap.abs();
    (
        (lc.search_radius + lc.drift_rate * gap).min(lc.search_radius_max) / 3.0,
        (0.05 + lc.drift_yaw_rate * gap).min(std::f64::consts::PI) / 3.0,
    )
}

/// Standard deviations (m, rad) of an accepted alignment's prediction `path_gap` metres of path after the
/// closure that gave it: the closure's own accuracy (0.5 m, 0.01 rad) plus the drift since, with the drift
/// model's rates read as two standard deviations. Tighter than [`drift_sigmas`]: right after a closure the
/// odometry is known to within decimetres, and a street that slides by a few metres is caught.
fn alignment_sigmas(path_gap: f64, lc: &LoopConfig) -> (f64, f64) {
    let gap = path_gap.abs();
    (
        (0.5 + 0.5 * lc.drift_rate * gap).min(lc.search_radius_max),
        (0.01 + 0.5 * lc.drift_yaw_rate * gap).min(std::f64::consts::PI),
    )
}

/// Squared Mahalanobis distance between two alignments of the same odometry frame found `path_gap`
/// metres of path apart, compared where they are used (the body pose `at`): two true closures agree to
/// registration accuracy (1 m, 0.02 rad standard deviation, generous) plus the drift between them (the
/// drift model's rates read as two standard deviations, as in [`alignment_sigmas`]).
fn alignment_distance(a: &Iso2, b: &Iso2, at: &Iso2, path_gap: f64, lc: &LoopConfig) -> f64 {
    let e = se2_log(&((a * at).inverse() * (b * at)));
    let gap = path_gap.abs();
    let st = 1.0 + 0.5 * lc.drift_rate * gap;
    let sr = 0.02 + 0.5 * lc.drift_yaw_rate * gap;
    (e.x * e.x + e.y * e.y) / (st * st) + e.z * e.z / (sr * sr)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Vec3;
    use crate::radar::Detection;

    fn scan(stamp: f64) -> RadarScan {
        RadarScan {
            radar: 0,
            stamp: Stamp::from_secs_f64(stamp),
            detections: vec![Detection {
                p_radar: Vec3::new(10.0, 1.0, 0.0),
                v_r: -1.0,
                rcs: None,
            }],
        }
    }

    fn dropped(events: &[Event], reason: DropReason) -> bool {
        events
            .iter()
            .any(|e| matches!(e, Event::Dropped { reason: r, .. } if *r == reason))
    }

    /// Each horizon must reach at least as far as the one before it, and the error names the
    /// parameter.
    #[test]
    fn loop_horizons_are_ordered() {
        let validate = |lc: &LoopConfig| {
            let mut v = Validator::at("loop");
            lc.check(&mut v);
            v.finish()
        };
        let lc = LoopConfig::default();
        assert!(validate(&lc).is_ok());
        let short = LoopConfig {
            backfill_horizon: lc.confirmation_horizon - 1.0,
            ..lc.clone()
        };
        let e = validate(&short).expect_err("shorter than confirmation_horizon");
        assert!(e.to_string().contains("loop.backfill_horizon"), "{e}");
        let short = LoopConfig {
            confirmation_horizon: lc.confirmation_span - 1.0,
            backfill_horizon: lc.confirmation_span - 1.0,
            ..lc
        };
        let e = validate(&short).expect_err("shorter than confirmation_span");
        assert!(e.to_string().contains("loop.confirmation_horizon"), "{e}");
    }

    #[test]
    fn backwards_stamps_are_dropped_until_a_run_makes_a_restart() {
        let mut p = Pipeline::new(Config::default()).expect("default config");
        p.set_restart_after(3);
        let odom =
            |p: &mut Pipeline, t: f64| p.push_odometry(Stamp::from_secs_f64(t), Iso3::identity());
        odom(&mut p, 100.0);
        p.push_scan(scan(100.0));
        // Two stale inputs: dropped, nothing reset.
        assert!(dropped(&odom(&mut p, 50.0), DropReason::StampBackwards));
        assert!(dropped(
            &p.push_scan(scan(50.1)),
            DropReason::StampBackwards
        ));
        assert_eq!(p.stats().time_resets, 0);
        // A fresh input ends the run; two more stale ones are dropped again.
        assert!(!dropped(&odom(&mut p, 100.1), DropReason::StampBackwards));
        odom(&mut p, 10.0);
        odom(&mut p, 10.1);
        assert_eq!(p.stats().dropped[&DropReason::StampBackwards], 4);
        // The third in a row is a restart.
        let ev = odom(&mut p, 10.2);
        assert!(ev.iter().any(|e| matches!(e, Event::TimeReset { .. })));
        assert_eq!(p.stats().time_resets, 1);
        // The default (as `dc_loc run`): the first stale input restarts.
        let mut q = Pipeline::new(Config::default()).expect("default config");
        odom(&mut q, 100.0);
        odom(&mut q, 10.0);
        assert_eq!(q.stats().time_resets, 1);
        assert!(!q.stats().dropped.contains_key(&DropReason::StampBackwards));
    }

    #[test]
    fn a_second_scan_with_the_same_stamp_is_dropped_and_empty_scans_are_counted() {
        let mut p = Pipeline::new(Config::default()).expect("default config");
        assert!(!dropped(
            &p.push_scan(scan(5.0)),
            DropReason::DuplicateStamp
        ));
        let mut empty = scan(5.0);
        empty.detections.clear();
        let ev = p.push_scan(empty);
        assert!(dropped(&ev, DropReason::DuplicateStamp));
        assert!(ev.iter().any(|e| matches!(e, Event::EmptyScan { .. })));
        assert_eq!(p.stats().empty_scans, 1);
        assert!(!dropped(
            &p.push_scan(scan(5.1)),
            DropReason::DuplicateStamp
        ));
        assert_eq!(p.stats().dropped[&DropReason::DuplicateStamp], 1);
    }
}
