//! The settings of revisit search and closure acceptance (`loop.*`).

use crate::keyframe_db::SearchSettings;
use crate::validate::{Range, Validator};
use serde::{Deserialize, Serialize};

/// Revisit search and acceptance of loop closures. Every gate is a parameter; every rejection is
/// counted by reason ([`super::RejectReason`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct LoopConfig {
    /// Search for revisits at all (default true; off for pure submap collection).
    pub enabled: bool,
    /// Base search radius around the odometry position and the position an alignment predicts, m
    /// (default 25): the farthest apart two passes of one place may lie, e.g. the two carriageways of
    /// a six-lane road (18.75 m between the outer lanes' centres), plus the odometry's error right
    /// after a closure.
    pub search_radius: f64,
    /// Odometry drift model, translation: the search radius grows by this many metres per metre of path
    /// driven since the candidate keyframe, and the consistency check allows as much (default 0.05:
    /// 5 % of distance).
    pub drift_rate: f64,
    /// Odometry drift model, heading: rad per metre of path (default 5e-4, about 2.9 deg per 100 m).
    /// A third of it is the heading drift a published closure's covariance allows within each of its
    /// two submaps (docs/algorithm.md, "The covariance reported").
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
    /// Candidates registered per keyframe (default 4): the nearest to the predicted position and the
    /// closest place descriptors in turn; while an accepted alignment vouches, the nearest take every
    /// slot but one, and where none of them closes, up to two more rounds of as many of the next
    /// nearest are registered.
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
    /// Standard deviations of the radars' extrinsic calibration, `[translation m (each axis), yaw
    /// rad]` (default `[0.0, 0.0]`: exact). Set them to how well the mounts are known (e.g. `[0.05,
    /// 0.026]` for 5 cm and 1.5 degrees): the published covariance then adds what such an error does to
    /// a closure, nothing between keyframes at the same pose, most to closures across the street in the
    /// other direction (docs/algorithm.md, "The covariance reported"). The gates judge the registration
    /// without it.
    pub extrinsic_std: [f64; 2],
    /// Standard deviation of a radar clock's offset from the odometry's, s (default 0.0:
    /// synchronised). A scan stamped off by `dt` is placed where the body was at the stamped time, so
    /// a submap lies `speed x dt` along the heading from where its keyframe says; the published
    /// covariance then adds what that does to a closure, which grows with the two keyframes' speed
    /// difference (docs/algorithm.md, "The covariance reported"). The gates judge the registration
    /// without it.
    pub clock_std: f64,
    /// Largest ratio of the best *other* alignment's overlap to the result's (`runner_up_overlap /
    /// overlap`, 0..1; default 0.8; 1 disables): a street whose facades still fit when slid along
    /// itself gives two alignments of nearly equal support, and picking one of them is a guess. A
    /// fresh accepted alignment of the session tells them apart when the result is well determined,
    /// agrees with the alignment's prediction, every alternative that fits nearly as well contradicts
    /// it, and the dense stage started at the prediction ends at the result. The same share bounds
    /// the prediction test of a closure published on a fresh alignment's word.
    pub maximum_ambiguity: f64,
    /// A closure to a session without an accepted alignment (its first closures) is refused when the
    /// registration, slid along the query's heading by 3-24 m and refined there, fits with more than
    /// this share of its overlap (default 0.7; 1 disables): along a straight street a forward radar
    /// sees two facades that fit at any shift, so a session's first closures must come from
    /// distinctive places. Other closures that wait for confirmation are refused when a slid
    /// alignment fits better than the result.
    pub maximum_slide_ratio: f64,
    /// Smallest share of the two submaps' bearing histograms, turned by the result's yaw, that
    /// coincide (default 0.25; 0 disables): a forward radar driving a street the other way sees what
    /// lay behind it the first time, and a high overlap there is aliasing.
    pub minimum_common_view: f64,
    /// Consistency gate: largest squared Mahalanobis distance (3 dof) between a closure and what
    /// odometry and the earlier accepted closures predict, under the closure's covariance plus the
    /// drift model's (default 16.27, the 99.9 % chi-square quantile; 0 disables the check).
    pub consistency_chi2: f64,
    /// Mutually consistent closures (from different query keyframes) needed before the first closure
    /// to the robot's own earlier keyframes is published (default 2; 1 publishes at once): until then
    /// nothing but odometry vouches for them, and a single aliased match would misalign everything
    /// after it (another session's: `foreign_confirmations`). Until a session has an accepted
    /// alignment, the candidate search also looks around the position the newest held closure
    /// predicts, so that the closures that would confirm it are registered.
    pub confirmations: usize,
    /// The same for the first closures to another session, a loaded map or another robot (default 4):
    /// no odometry links the two sessions; two streets far apart in a grid of look-alike blocks can
    /// alias consistently from two keyframes, and a street symmetric about a point from three, seen by
    /// two robots driving it towards each other. Closures to the
    /// robot's own keyframes that contradict its accepted alignment to itself by more than the drift
    /// between them, while that alignment is fresh enough to vouch (`trusted_prior_std`), need as
    /// many: two keyframes onto a street slid along itself by a block agree with each other, and
    /// would replace an alignment that closures a little way back bore out.
    pub foreign_confirmations: usize,
    /// A session's closures to itself that lie beyond the drift model, but within three times its
    /// bounds, while no accepted alignment to itself vouches for them (none yet, or one too far back
    /// along the path, `trusted_prior_std`), are held for `foreign_confirmations` agreeing closures
    /// from keyframes on both sides of a turn instead of refused (default true): odometry that
    /// drifted that far (a yaw-rate bias, a long drive) no longer tells where the session is, as
    /// between two sessions, nor does an alignment it has carried since, and closures that agree with
    /// each other around a corner still do. Along one street they do not: a
    /// parallel street a block away agrees with itself from every keyframe (docs/experiments.md,
    /// "Drift beyond the model").
    /// Further out lie a street's look-alikes, such as its point-symmetric twin across a block. Off,
    /// such closures are refused, and odometry beyond its model closes no lap.
    pub confirm_beyond_drift: bool,
    /// The confirming closures' query keyframes must lie at least this many metres of path apart
    /// (default 30): one aliased place seen from two neighbouring keyframes agrees with itself, two
    /// places along the route rarely alias the same way.
    pub confirmation_span: f64,
    /// At least one of the closures that confirm each other must have this overlap (default 0.6;
    /// 0 disables): weak matches along an aliased street agree with each other as well as true
    /// ones do. A closure from a later round of nearest keyframes (`maximum_candidates`) needs it too.
    pub confirmation_overlap: f64,
    /// Held closures expire after this many metres of path without confirmation, before they may
    /// confirm a newer one (default 150): a true alignment is confirmed within a few keyframes, and
    /// over a long path the agreement test is too loose to tell a street slid by some metres from the
    /// right alignment.
    pub confirmation_horizon: f64,
    /// A closure that agrees with the session's accepted alignment is published alone while that
    /// alignment's predicted translation standard deviation (0.5 m plus half the drift rate times the
    /// path since the last closure) is at most this, m (default 2.0: about 60 m of path at 5 % drift);
    /// after longer gaps closures wait for confirmation like the first ones.
    pub trusted_prior_std: f64,
    /// Keyframes searched again per new keyframe once closures to a session are confirmed (default
    /// 1; 0 disables, also at the end of a bag): the keyframes of the last `backfill_horizon` metres
    /// of path that got no closure while nothing vouched for their matches are searched again,
    /// walking away from the confirming keyframe, and what agrees with the confirmed alignment is
    /// published, late. In a fleet the same budget also searches this robot's keyframes without a
    /// closure around another robot's alignment (shared before this node has one, or its own beyond
    /// where the walk went stale), holding what they find for confirmation. One at a time keeps the
    /// added latency to one more search per keyframe.
    pub backfill_per_keyframe: usize,
    /// Metres of path back that a confirmation's searches again reach (default 2000; at least
    /// `confirmation_horizon`). They walk back along the route: each closure they publish gives the
    /// alignment the next older keyframe is searched around, so a confirmation that came late still
    /// closes the keyframes since the revisit began. The walk stops where no alignment is fresh
    /// enough to vouch (`trusted_prior_std`), before the revisit began (on a walk to another robot's
    /// keyframes, those beyond are then searched as new keyframes are); the horizon bounds the
    /// keyframes a confirmation may search again, and should not cut the walk short: a confirmation
    /// can come hundreds of metres into a revisit where places repeat.
    pub backfill_horizon: f64,
    /// Let the registration of revisit candidates run its correlative search
    /// (`registration.correlative`, default false): it finds alignments the descriptors missed, but
    /// most of them have fewer descriptor inliers than `minimum_inliers`, and it runs on every
    /// candidate that does not fit, which is most of them.
    pub correlative_search: bool,
}

impl Default for LoopConfig {
    fn default() -> Self {
        LoopConfig {
            enabled: true,
            search_radius: 25.0,
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
            extrinsic_std: [0.0, 0.0],
            clock_std: 0.0,
            maximum_ambiguity: 0.8,
            maximum_slide_ratio: 0.7,
            minimum_common_view: 0.25,
            consistency_chi2: 16.27,
            confirmations: 2,
            foreign_confirmations: 4,
            confirm_beyond_drift: true,
            confirmation_span: 30.0,
            confirmation_overlap: 0.6,
            confirmation_horizon: 150.0,
            trusted_prior_std: 2.0,
            backfill_per_keyframe: 1,
            backfill_horizon: 2000.0,
            correlative_search: false,
        }
    }
}

impl LoopConfig {
    /// Declares each field's range; each horizon reaches at least as far as the one before it.
    pub fn check(&self, v: &mut Validator) {
        v.count("place_retrieve", self.place_retrieve, 0, 10_000);
        v.count("backfill_per_keyframe", self.backfill_per_keyframe, 0, 1000);
        v.positive("search_radius", self.search_radius);
        v.positive("trusted_prior_std", self.trusted_prior_std);
        v.positive("maximum_translation_std", self.maximum_translation_std);
        v.positive("maximum_rotation_std", self.maximum_rotation_std);
        let std_ok = self
            .extrinsic_std
            .iter()
            .all(|x| x.is_finite() && (0.0..=10.0).contains(x));
        v.require("extrinsic_std", std_ok, || {
            format!(
                "{:?} must be two values in [0, 10] (m, rad)",
                self.extrinsic_std
            )
        });
        v.range("clock_std", self.clock_std, Range::closed(0.0, 1.0));
        v.non_negative("drift_rate", self.drift_rate);
        v.non_negative("drift_yaw_rate", self.drift_yaw_rate);
        v.non_negative("minimum_path_gap", self.minimum_path_gap);
        v.non_negative("consistency_chi2", self.consistency_chi2);
        v.non_negative("confirmation_span", self.confirmation_span);
        v.at_least("confirmations", self.confirmations, 1);
        v.at_least("foreign_confirmations", self.foreign_confirmations, 1);
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

#[cfg(test)]
mod tests {
    use super::*;

    fn validate(lc: &LoopConfig) -> Result<(), crate::validate::ConfigError> {
        let mut v = Validator::at("loop");
        lc.check(&mut v);
        v.finish()
    }

    /// Each horizon must reach at least as far as the one before it, and the error names the
    /// parameter.
    #[test]
    fn loop_horizons_are_ordered() {
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
}
