//! The gates a registered revisit must pass before it is published or held, each a function of the
//! registration result, the session's accepted alignments and the configuration, returning the
//! verdict with its reason.
//!
//! In order ([`gate`]): registration, inliers, convergence, overlap, common view, ambiguity,
//! covariance, consistency, and for a later candidate round's closure [`later_round`]; then, on the
//! best candidates only and in order until one passes, the prediction test ([`prediction_test`], for
//! closures published on a fresh alignment's word) and the slide test ([`slide_test`], for a
//! session's first closures and those that wait for confirmation).

use std::collections::BTreeMap;

use super::calibration::{
    add_planar, calibration_covariance, clock_covariance, submap_motion_covariance,
};
use super::decision::vouching;
use super::drift::{
    Prior, heading_drift_covariance, inconsistency, predict, reach_chi2, translation_std,
    within_reach,
};
use super::{Alignment, LoopClosure, LoopConfig, RejectReason, Standing};
use crate::keyframe_db::KeyframeRecord;
use crate::math::{Iso2, Mat3, iso3_from_iso2, se2_log};
use crate::registration::{
    PreparedSubmap, RegistrationConfig, RegistrationError, RegistrationResult, common_view,
    overlap_near, slide_overlap,
};

/// Why a candidate was refused, for the log and the counters.
pub type Refusal = (RejectReason, String);

/// What the gates know: the settings and the session's accepted alignments.
#[derive(Clone, Copy)]
pub struct Gates<'a> {
    /// `loop.*`.
    pub lc: &'a LoopConfig,
    /// `registration.*` (the dense stage the ambiguity probes run).
    pub rc: &'a RegistrationConfig,
    /// This session's number.
    pub session: u32,
    /// Per earlier session, the accepted alignment of this session's odometry into it.
    pub alignments: &'a BTreeMap<u32, Alignment>,
    /// Per other robot's session, that robot's accepted alignment to this session, inverted.
    pub shared: &'a BTreeMap<u32, Alignment>,
}

/// The two submaps of a candidate pair.
#[derive(Clone, Copy)]
pub struct Pair<'a> {
    /// The query keyframe (newer).
    pub query: &'a KeyframeRecord,
    /// The candidate keyframe (older).
    pub cand: &'a KeyframeRecord,
    /// The query's prepared submap (the registration's source).
    pub source: &'a PreparedSubmap,
    /// The candidate's prepared submap (the registration's target).
    pub target: &'a PreparedSubmap,
    /// The odometry's speeds at the query and the candidate, m/s (0 where unknown).
    pub speeds: [f64; 2],
    /// Mean path length of each submap's scans behind its keyframe, query and candidate, m.
    pub arms: [f64; 2],
    /// Covariance of each submap's frame from the odometry's motion between its scans
    /// ([`crate::submap::Submap::motion`]), taken for both.
    pub motion: Mat3,
}

/// A closure that passed the gates before the prediction and slide tests.
#[derive(Debug, Clone)]
pub struct Gated {
    /// The closure.
    pub closure: LoopClosure,
    /// What it needs before it is published.
    pub standing: Standing,
    /// Where that alignment predicts the result, for the prediction test it still needs.
    pub prediction: Option<Iso2>,
    /// The slide test it still needs.
    pub slide: Option<Slide>,
}

/// A pending slide test: the result, its overlap, the largest share of it a slid alignment may
/// reach, and whether it is a session's first closure.
#[derive(Debug, Clone, Copy)]
pub struct Slide {
    /// The result.
    pub t: Iso2,
    /// Its overlap.
    pub overlap: f64,
    /// The largest share of `overlap` a slid alignment may reach.
    pub ratio: f64,
    /// The candidate's session has no accepted alignment yet.
    pub first: bool,
}

impl Gates<'_> {
    /// The accepted alignment to `session`.
    fn alignment(&self, session: u32) -> Option<&Alignment> {
        self.alignments.get(&session)
    }

    /// What a closure to `cand` is tested against: the accepted alignment to its session (when
    /// `use_alignment`), else odometry for a candidate of this session; `None` for another
    /// session without an alignment.
    fn prior(&self, cand: &KeyframeRecord, use_alignment: bool) -> Option<Prior<'_>> {
        match self.alignment(cand.session) {
            Some(a) if use_alignment => Some(Prior::Alignment(a)),
            _ if cand.session == self.session => Some(Prior::Odometry),
            _ => None,
        }
    }

    /// Squared Mahalanobis distance of `t` (with the result's covariance) to its prediction.
    fn distance(
        &self,
        p: &Pair<'_>,
        r: &RegistrationResult,
        t: &Iso2,
        aligned: bool,
    ) -> Option<f64> {
        let prior = self.prior(p.cand, aligned)?;
        inconsistency(prior, p.query, p.cand, t, &r.covariance, self.lc)
    }

    /// The accepted alignment to the candidate's session is fresh enough to vouch for a closure.
    fn trusted(&self, p: &Pair<'_>) -> bool {
        self.alignment(p.cand.session)
            .is_some_and(|a| vouching(a, p.query.path_distance, self.lc))
    }

    /// The pose the accepted alignment to the candidate's session predicts.
    fn predicted(&self, p: &Pair<'_>) -> Option<Iso2> {
        self.alignment(p.cand.session)
            .map(|a| predict(&a.t, p.query, p.cand))
    }
}

/// Every gate in order; the closure with the tests it still needs, or why it is refused.
pub fn gate(
    g: &Gates<'_>,
    p: &Pair<'_>,
    res: Result<RegistrationResult, RegistrationError>,
) -> Result<Gated, Refusal> {
    let r = res.map_err(|e| (RejectReason::Registration, e.to_string()))?;
    let judged = judged(&r);
    quality(g.lc, &judged)?;
    common_view_gate(g.lc, p, &judged)?;
    ambiguity(g, p, &judged)?;
    covariance(g.lc, &judged)?;
    let standing = consistency(g, p, &judged)?;
    let agrees = standing == Standing::Vouched;
    let lc = g.lc;
    // A closure published alone on the alignment's word: the prediction may be metres off, and a
    // street slid by as much agrees with it too.
    let prediction = (agrees && lc.maximum_ambiguity < 1.0)
        .then(|| g.predicted(p))
        .flatten();
    // A session's first closures against `maximum_slide_ratio`; the other closures that wait for
    // confirmation must not have a slid alignment that fits better than the result (then the result
    // is not the best alignment around, and agreeing closures along the same street cannot make it
    // so).
    let first = g.alignment(p.cand.session).is_none();
    let slide = (lc.maximum_slide_ratio < 1.0 && (first || !agrees)).then_some(Slide {
        t: r.t_target_source,
        overlap: r.overlap,
        ratio: if first { lc.maximum_slide_ratio } else { 1.0 },
        first,
    });
    Ok(Gated {
        closure: closure(p, &r, lc),
        standing,
        prediction,
        slide,
    })
}

/// The result as the gates judge it: without the score probe's share of its covariance
/// ([`RegistrationResult::score_share`]). The gates' chi-square tests tell the result from
/// alternatives a metre and more away; the share widens the covariance along the street by the pull
/// of the facades and parked cars within the alignment, and in those tests it would make a street
/// slid by a car length look as likely as the result. The published closure carries it, as it
/// carries the calibration's share.
fn judged(r: &RegistrationResult) -> RegistrationResult {
    RegistrationResult {
        covariance: add_planar(&r.covariance, &-r.score_share),
        alternatives: r.alternatives.clone(),
        ..*r
    }
}

/// The closure a result gives: its covariance with the calibration's share (`loop.extrinsic_std`,
/// `loop.clock_std`), the heading drift's within its two submaps (`loop.drift_yaw_rate`) and the
/// odometry's motion noise within them ([`Pair::motion`]).
fn closure(p: &Pair<'_>, r: &RegistrationResult, lc: &LoopConfig) -> LoopClosure {
    let shares = calibration_covariance(&r.t_target_source, lc.extrinsic_std)
        + clock_covariance(&r.t_target_source, p.speeds, lc.clock_std)
        + heading_drift_covariance(&r.t_target_source, p.arms, lc)
        + submap_motion_covariance(&r.t_target_source, &p.motion);
    LoopClosure {
        query_id: p.query.id,
        match_id: p.cand.id,
        query_stamp: p.query.stamp,
        match_stamp: p.cand.stamp,
        query_odom_pose: p.query.odom_pose_iso3(),
        match_odom_pose: p.cand.odom_pose_iso3(),
        t_match_query: iso3_from_iso2(&r.t_target_source),
        covariance: add_planar(&r.covariance, &shares),
        inliers: r.inliers as u32,
        score: r.overlap,
        match_session: p.cand.session,
        query_robot: 0,
        match_origin: None,
    }
}

/// Enough inliers, a converged optimiser and enough overlap.
pub fn quality(lc: &LoopConfig, r: &RegistrationResult) -> Result<(), Refusal> {
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
    Ok(())
}

/// A closure of a later candidate round ([`crate::keyframe_db::KeyframeDb::candidate_rounds`]): its
/// keyframe lies farther from the predicted position than those of the first round, which did not
/// close, so it stands on less shared view and needs the overlap a confirmation asks of its strongest
/// closure (`loop.confirmation_overlap`).
pub fn later_round(lc: &LoopConfig, gated: Gated) -> Result<Gated, Refusal> {
    if gated.closure.score < lc.confirmation_overlap {
        return Err((
            RejectReason::LowOverlap,
            format!(
                "overlap {:.2} in a later round, below loop.confirmation_overlap",
                gated.closure.score
            ),
        ));
    }
    Ok(gated)
}

/// The two submaps looked in directions that can have seen the same things (`loop.minimum_common_view`).
pub fn common_view_gate(
    lc: &LoopConfig,
    p: &Pair<'_>,
    r: &RegistrationResult,
) -> Result<(), Refusal> {
    if lc.minimum_common_view <= 0.0 {
        return Ok(());
    }
    let view = common_view(p.source, p.target, &r.t_target_source);
    if view < lc.minimum_common_view {
        return Err((
            RejectReason::NoCommonView,
            format!(
                "common view {view:.2} at a relative yaw of {:.2} rad",
                r.t_target_source.rotation.angle()
            ),
        ));
    }
    Ok(())
}

/// No other alignment fits nearly as well (`loop.maximum_ambiguity`), unless a fresh accepted
/// alignment tells them apart: the result is well determined where it is (translation standard
/// deviation at most half the covariance gate's), agrees with the prediction, every alternative that
/// fits nearly as well contradicts it, and the dense stage started at the prediction ends at the
/// result (the prediction's own error may be metres; a street slid by as much would agree with it).
pub fn ambiguity(g: &Gates<'_>, p: &Pair<'_>, r: &RegistrationResult) -> Result<(), Refusal> {
    let lc = g.lc;
    if !(lc.maximum_ambiguity < 1.0 && r.runner_up_overlap > lc.maximum_ambiguity * r.overlap) {
        return Ok(());
    }
    let chi2 = lc.consistency_chi2;
    let d2 = |t: &Iso2| g.distance(p, r, t, true);
    let resolved = g.trusted(p)
        && chi2 > 0.0
        && translation_std(&r.covariance) <= 0.5 * lc.maximum_translation_std
        && d2(&r.t_target_source).is_some_and(|d| d <= chi2)
        && r.alternatives
            .iter()
            .filter(|a| a.1 > lc.maximum_ambiguity * r.overlap)
            .all(|(t, _)| d2(t).is_some_and(|d| d > chi2))
        && g.predicted(p).is_some_and(|predicted| {
            overlap_near(p.source, p.target, &predicted, g.rc).is_ok_and(|near| {
                near.is_some_and(|(t, _)| g.rc.same_alignment(&t, &r.t_target_source))
            })
        });
    if !resolved {
        return Err((
            RejectReason::Ambiguous,
            format!(
                "another alignment has overlap {:.2} against {:.2}{}",
                r.runner_up_overlap,
                r.overlap,
                strongest_alternative(r)
            ),
        ));
    }
    log::debug!(
        "revisit {} -> {}: another alignment has overlap {:.2} against {:.2}, but only this one agrees with the accepted alignment",
        p.query.id,
        p.cand.id,
        r.runner_up_overlap,
        r.overlap
    );
    Ok(())
}

/// Where the alternative with the most overlap lies from the result, in the result's query frame
/// (empty when the registration kept none).
fn strongest_alternative(r: &RegistrationResult) -> String {
    r.alternatives
        .iter()
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(t, overlap)| {
            let d = r.t_target_source.inverse() * t;
            format!(
                " (the strongest alternative, overlap {overlap:.2}, lies {:.2} m, {:.2} m, {:.3} rad from it)",
                d.translation.x,
                d.translation.y,
                d.rotation.angle()
            )
        })
        .unwrap_or_default()
}

/// The covariance is within `loop.maximum_translation_std` and `loop.maximum_rotation_std`.
pub fn covariance(lc: &LoopConfig, r: &RegistrationResult) -> Result<(), Refusal> {
    let t_std = translation_std(&r.covariance);
    let r_std = r.covariance[(5, 5)].max(0.0).sqrt();
    if !(t_std <= lc.maximum_translation_std && r_std <= lc.maximum_rotation_std) {
        return Err((
            RejectReason::Uncertain,
            format!("std {t_std:.3} m, {r_std:.4} rad"),
        ));
    }
    Ok(())
}

/// Consistency (`loop.consistency_chi2`) with the session's accepted alignment when there is one;
/// what the closure needs before it is published ([`Standing`]). A closure that contradicts the
/// alignment but agrees with odometry alone (or, for another session, has nothing to contradict) may
/// still be right and waits for confirmation, unless the alignment's prediction fits the submaps
/// nearly as well: then the scene aliases (a street sliding along itself) and the prior decides. A
/// closure to this session that contradicts odometry is refused while the session's accepted
/// alignment to itself is fresh enough to vouch (`loop.trusted_prior_std`). Before there is one,
/// odometry has drifted beyond its model and no longer tells where the session is; once it is stale,
/// a drift beyond the model (a yaw-rate bias turns the alignment as the robot drives) has moved it
/// as far. Either way the closure waits for as many confirmations as one to another session, across
/// a turn. A closure to another session is first tested against every alignment to it known here
/// ([`beyond_every_alignment`]).
pub fn consistency(
    g: &Gates<'_>,
    p: &Pair<'_>,
    r: &RegistrationResult,
) -> Result<Standing, Refusal> {
    let lc = g.lc;
    // What a closure that passes needs: nothing more when a fresh alignment vouches for it.
    let consistent = if g.trusted(p) {
        Standing::Vouched
    } else {
        Standing::Unconfirmed
    };
    if lc.consistency_chi2 <= 0.0 {
        return Ok(consistent);
    }
    beyond_every_alignment(g, p, r)?;
    let t = &r.t_target_source;
    let aligned = g.distance(p, r, t, true);
    if !aligned.is_some_and(|d2| d2 > lc.consistency_chi2) {
        return Ok(consistent);
    }
    if let Some(predicted) = g.predicted(p)
        && let Ok(Some((_, o))) = overlap_near(p.source, p.target, &predicted, g.rc)
        && lc.maximum_ambiguity < 1.0
        && o > lc.maximum_ambiguity * r.overlap
    {
        return Err((
            RejectReason::Ambiguous,
            format!(
                "the accepted alignment's prediction fits too (overlap {o:.2} against {:.2})",
                r.overlap
            ),
        ));
    }
    let Some(d2) = g
        .distance(p, r, t, false)
        .filter(|&d2| d2 > lc.consistency_chi2)
    else {
        return Ok(Standing::Unconfirmed);
    };
    if lc.confirm_beyond_drift && within_reach(d2, lc) && !g.trusted(p) {
        return Ok(Standing::BeyondDrift);
    }
    Err(contradicts_odometry(p, t, d2, aligned))
}

/// A closure to another session, tested against every alignment to it this node knows (its own
/// accepted one, stale or fresh, and the one the other session's robot accepted to this session,
/// inverted) as odometry carries them ([`Prior::Anchored`]): refused when it lies beyond
/// [`within_reach`] of each. Between sessions nothing else ties the two odometry frames; without it,
/// closures onto a look-alike street far away that agree with each other would replace a stale
/// alignment or become the first one.
fn beyond_every_alignment(
    g: &Gates<'_>,
    p: &Pair<'_>,
    r: &RegistrationResult,
) -> Result<(), Refusal> {
    let s = p.cand.session;
    if s == g.session {
        return Ok(());
    }
    let t = &r.t_target_source;
    let d2 =
        |a: &Alignment| inconsistency(Prior::Anchored(a), p.query, p.cand, t, &r.covariance, g.lc);
    let d2s: Vec<Option<f64>> = [g.alignment(s), g.shared.get(&s)]
        .into_iter()
        .flatten()
        .map(d2)
        .collect();
    if d2s.is_empty() || d2s.iter().any(|d| d.is_none_or(|d| within_reach(d, g.lc))) {
        return Ok(());
    }
    let nearest = d2s.into_iter().flatten().fold(f64::INFINITY, f64::min);
    Err((
        RejectReason::Inconsistent,
        format!(
            "squared Mahalanobis distance {nearest:.1} to the nearest prediction of the alignments to session {s} known here (the drift along both paths since each was found allows {:.1})",
            reach_chi2(g.lc)
        ),
    ))
}

/// The refusal of `t`, a closure within its own session at squared Mahalanobis distance `d2` from
/// the odometry prediction (and `aligned` from the accepted alignment's): how far off it lies.
fn contradicts_odometry(p: &Pair<'_>, t: &Iso2, d2: f64, aligned: Option<f64>) -> Refusal {
    let e = se2_log(&(t.inverse() * predict(&Iso2::identity(), p.query, p.cand)));
    (
        RejectReason::Inconsistent,
        format!(
            "squared Mahalanobis distance {d2:.1} to the odometry prediction ({:.1} m, {:.1} deg from it), {:.1} to the accepted alignment's",
            e.xy().norm(),
            e.z.to_degrees(),
            aligned.unwrap_or(f64::NAN)
        ),
    )
}

/// The prediction test of a closure that agrees with a fresh alignment and passed the other gates:
/// the dense stage started at the alignment's prediction must end at the result, or where it ends
/// must fit with at most `loop.maximum_ambiguity` of the result's overlap.
pub fn prediction_test(
    g: &Gates<'_>,
    predicted: &Iso2,
    c: &LoopClosure,
    source: &PreparedSubmap,
    target: &PreparedSubmap,
) -> Result<(), Refusal> {
    let t = crate::math::iso2_from_iso3(&c.t_match_query);
    if let Ok(Some((near, o))) = overlap_near(source, target, predicted, g.rc)
        && !g.rc.same_alignment(&near, &t)
        && o > g.lc.maximum_ambiguity * c.score
    {
        let d = (near.translation.vector - t.translation.vector).norm();
        return Err((
            RejectReason::Ambiguous,
            format!(
                "started at the accepted alignment's prediction it ends {d:.2} m away with overlap {o:.2} against {:.2}",
                c.score
            ),
        ));
    }
    Ok(())
}

/// The slide test of a closure that passed the other gates ([`slide_overlap`], stopping at the first
/// shift above the limit).
pub fn slide_test(
    rc: &RegistrationConfig,
    s: &Slide,
    source: &PreparedSubmap,
    target: &PreparedSubmap,
) -> Result<(), Refusal> {
    let limit = s.ratio * s.overlap;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Mat3, Stamp, Vec2};
    use crate::place::{PlaceConfig, PlaceDescriptor};
    use crate::registration::{PointSet2, covariance_ros_from_se2};
    use rand::{RngExt, SeedableRng};

    fn record(id: u64, session: u32, pose: Iso2, path: f64) -> KeyframeRecord {
        let q = nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, pose.rotation.angle());
        KeyframeRecord {
            id,
            session,
            stamp: Stamp(1_000_000_000 * (id as i64 + 1)),
            t_odom_body: pose,
            odom_pose: [
                pose.translation.x,
                pose.translation.y,
                0.0,
                q.i,
                q.j,
                q.k,
                q.w,
            ],
            path_distance: path,
            points: Vec::new(),
            covs: Vec::new(),
            rays: Vec::new(),
            place: PlaceDescriptor::from_points(&[], &PlaceConfig::default()),
        }
    }

    /// A result at `t` with `sigma` m and 0.002 rad standard deviations.
    fn result(t: Iso2, sigma: f64) -> RegistrationResult {
        let cov = Mat3::from_diagonal(&crate::math::Vec3::new(sigma * sigma, sigma * sigma, 4e-6));
        RegistrationResult {
            t_target_source: t,
            covariance: covariance_ros_from_se2(&cov),
            converged: true,
            iterations: 5,
            inliers: 80,
            candidates: 200,
            cost: 1.0,
            overlap: 0.8,
            runner_up_overlap: 0.0,
            alternatives: Vec::new(),
            score_share: Mat3::zeros(),
        }
    }

    /// Points all round the anchor (a crossing with buildings on every side).
    fn surroundings(seed: u64) -> PreparedSubmap {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let pts: Vec<Vec2> = (0..400)
            .map(|_| {
                let (r, a) = (
                    rng.random_range(5.0..60.0),
                    rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
                );
                Vec2::new(r * a.cos(), r * a.sin())
            })
            .collect();
        PreparedSubmap::new(
            PointSet2::isotropic(pts, 0.15),
            &RegistrationConfig::default(),
        )
        .expect("prepared")
    }

    struct Fixture {
        lc: LoopConfig,
        rc: RegistrationConfig,
        alignments: BTreeMap<u32, Alignment>,
        shared: BTreeMap<u32, Alignment>,
        query: KeyframeRecord,
        cand: KeyframeRecord,
        map: PreparedSubmap,
    }

    /// The query keyframe 300 m of path after a candidate of the same session 2 m away.
    fn fixture() -> Fixture {
        Fixture {
            lc: LoopConfig::default(),
            rc: RegistrationConfig::default(),
            alignments: BTreeMap::new(),
            shared: BTreeMap::new(),
            query: record(60, 0, Iso2::new(Vec2::new(2.0, 0.0), 0.0), 300.0),
            cand: record(0, 0, Iso2::identity(), 0.0),
            map: surroundings(3),
        }
    }

    impl Fixture {
        fn gates(&self) -> Gates<'_> {
            Gates {
                lc: &self.lc,
                rc: &self.rc,
                session: 0,
                alignments: &self.alignments,
                shared: &self.shared,
            }
        }
        fn pair(&self) -> Pair<'_> {
            Pair {
                query: &self.query,
                cand: &self.cand,
                source: &self.map,
                target: &self.map,
                speeds: [0.0, 0.0],
                arms: [0.0, 0.0],
                motion: Mat3::zeros(),
            }
        }
        fn gate(&self, r: RegistrationResult) -> Result<Gated, Refusal> {
            gate(&self.gates(), &self.pair(), Ok(r))
        }
    }

    fn reason(r: Result<Gated, Refusal>) -> RejectReason {
        r.expect_err("refused").0
    }

    #[test]
    fn quality_gates_name_their_reasons() {
        let f = fixture();
        let t = Iso2::new(Vec2::new(2.0, 0.0), 0.0);
        let e = gate(
            &f.gates(),
            &f.pair(),
            Err(RegistrationError::TooFewPoints { have: 1, need: 10 }),
        );
        assert_eq!(reason(e), RejectReason::Registration);
        let few = RegistrationResult {
            inliers: 10,
            ..result(t, 0.05)
        };
        assert_eq!(reason(f.gate(few)), RejectReason::FewInliers);
        let stuck = RegistrationResult {
            converged: false,
            ..result(t, 0.05)
        };
        assert_eq!(reason(f.gate(stuck)), RejectReason::NotConverged);
        let thin = RegistrationResult {
            overlap: 0.2,
            ..result(t, 0.05)
        };
        assert_eq!(reason(f.gate(thin)), RejectReason::LowOverlap);
        assert_eq!(reason(f.gate(result(t, 0.8))), RejectReason::Uncertain);
    }

    /// The gates judge a result without the score probe's share: 0.8 m along x on top of 5 cm passes
    /// the covariance gate (0.5 m), which the same 0.8 m in the registration's own covariance does
    /// not; the closure carries the share.
    #[test]
    fn the_gates_judge_without_the_score_probe_s_share() {
        let f = fixture();
        let t = Iso2::identity();
        let share = Mat3::from_diagonal(&crate::math::Vec3::new(0.64, 0.0, 0.0));
        let mut pulled = result(t, 0.05);
        pulled.covariance = add_planar(&pulled.covariance, &share);
        pulled.score_share = share;
        let gated = f.gate(pulled.clone()).expect("passes");
        assert!((gated.closure.covariance[(0, 0)] - (0.0025 + 0.64)).abs() < 1e-12);
        assert_eq!(gated.closure.covariance, pulled.covariance);
        pulled.score_share = Mat3::zeros();
        assert_eq!(reason(f.gate(pulled)), RejectReason::Uncertain);
    }

    /// An overlap the first round takes (0.3 and above) is refused in a later round below
    /// `loop.confirmation_overlap` (0.6), and taken at or above it.
    #[test]
    fn a_later_round_asks_the_overlap_of_a_confirmation() {
        let f = fixture();
        let t = Iso2::new(Vec2::new(2.0, 0.0), 0.0);
        let at = |overlap: f64| RegistrationResult {
            overlap,
            ..result(t, 0.05)
        };
        let thin = f.gate(at(0.45)).expect("the first round takes it");
        assert_eq!(reason(later_round(&f.lc, thin)), RejectReason::LowOverlap);
        let thick = f.gate(at(f.lc.confirmation_overlap)).expect("passes");
        assert!(later_round(&f.lc, thick).is_ok());
    }

    #[test]
    fn a_first_closure_needs_the_slide_test_and_does_not_vouch_for_itself() {
        let f = fixture();
        let g = f
            .gate(result(Iso2::new(Vec2::new(2.0, 0.0), 0.0), 0.05))
            .expect("passes");
        assert!(g.standing != Standing::Vouched && g.prediction.is_none());
        let slide = g.slide.expect("first closures are slide-tested");
        assert!(slide.first && slide.ratio == f.lc.maximum_slide_ratio);
        assert_eq!(g.closure.query_id, 60);
        assert_eq!(g.closure.match_id, 0);
        assert_eq!(g.closure.score, 0.8);
    }

    /// A closure to another robot's session is refused beyond the drift from every alignment to it
    /// known here (this node's, stale or fresh, and the one that robot's node accepted to this
    /// session), and waits for confirmation within reach of any of them; with none, nothing refuses
    /// it.
    #[test]
    fn a_closure_to_another_robot_beyond_every_known_alignment_is_refused() {
        let mut f = fixture();
        f.cand.session = 1;
        // The other robot's frame: the query's origin lies at (500, -200) there, turned by 2 rad;
        // the candidate keyframe sits there, so the true closure is the query's own pose (2, 0, 0).
        let truth = Iso2::new(Vec2::new(500.0, -200.0), 2.0);
        f.cand.t_odom_body = truth;
        let at = |x: f64, yaw: f64| result(Iso2::new(Vec2::new(x, 0.0), yaw), 0.05);
        let standing = |f: &Fixture, x: f64, yaw: f64| f.gate(at(x, yaw)).map(|g| g.standing);
        assert_eq!(
            standing(&f, 200.0, 0.0),
            Ok(Standing::Unconfirmed),
            "no prior"
        );
        // Shared at this session's 300 m and the candidate's 0 m: no drift between, 5 m and 0.017
        // rad standard deviation, twelve of them within reach.
        let shared = Alignment {
            t: truth,
            path: 300.0,
            match_path: 0.0,
        };
        f.shared.insert(1, shared);
        assert_eq!(standing(&f, 2.0, 0.0), Ok(Standing::Unconfirmed));
        assert_eq!(
            standing(&f, 40.0, 0.0),
            Ok(Standing::Unconfirmed),
            "within reach"
        );
        assert_eq!(reason(f.gate(at(200.0, 0.0))), RejectReason::Inconsistent);
        assert_eq!(reason(f.gate(at(2.0, 0.5))), RejectReason::Inconsistent);
        // This node's own alignment 200 m away: the slid closure agrees with it, and may wait for
        // confirmation that replaces the shared one's word.
        let slid = truth * Iso2::new(Vec2::new(198.0, 0.0), 0.0);
        f.alignments.insert(1, Alignment { t: slid, ..shared });
        assert!(f.gate(at(200.0, 0.0)).is_ok());
        // Far from both: refused.
        assert_eq!(reason(f.gate(at(600.0, 0.0))), RejectReason::Inconsistent);
        // A closure to this session's own earlier keyframes is not tested against them.
        f.cand.session = 0;
        f.cand.t_odom_body = Iso2::identity();
        f.cand.path_distance = 290.0;
        assert!(f.gate(at(2.0, 0.0)).is_ok());
    }

    #[test]
    fn beyond_the_drift_model_a_closure_waits_unless_an_alignment_vouches() {
        let mut f = fixture();
        f.lc.confirm_beyond_drift = true;
        // 300 m of path: the drift model allows (15 + 15) / 3 = 10 m standard deviation.
        let far = || result(Iso2::new(Vec2::new(80.0, 0.0), 0.0), 0.05);
        let near = || result(Iso2::new(Vec2::new(12.0, 0.0), 0.0), 0.05);
        assert_eq!(
            f.gate(near()).expect("passes").standing,
            Standing::Unconfirmed
        );
        assert_eq!(f.gate(far()).expect("held").standing, Standing::BeyondDrift);
        // Beyond three times the drift model's bounds it is refused: 198 m is 19.8 standard deviations.
        let twin = result(Iso2::new(Vec2::new(200.0, 0.0), 0.0), 0.05);
        assert_eq!(reason(f.gate(twin)), RejectReason::Inconsistent);
        // Once the session has an accepted alignment to itself fresh enough to vouch (here one whose
        // prediction does not fit the submaps), odometry and the alignment refuse it.
        let a = Iso2::new(Vec2::new(40.0, 0.0), 0.0);
        f.alignments.insert(0, Alignment::along_one_pass(a, 300.0));
        assert_eq!(reason(f.gate(far())), RejectReason::Inconsistent);
        // An alignment 200 m of path back vouches for nothing: the closure waits again.
        f.alignments.insert(0, Alignment::along_one_pass(a, 100.0));
        assert_eq!(f.gate(far()).expect("held").standing, Standing::BeyondDrift);
        f.alignments.clear();
        f.lc.confirm_beyond_drift = false;
        assert_eq!(reason(f.gate(far())), RejectReason::Inconsistent);
    }

    #[test]
    fn a_fresh_alignment_vouches_for_what_agrees_with_it() {
        let mut f = fixture();
        // An accepted alignment found 20 m of path ago: the odometry is off by 1 m along x.
        let a = Iso2::new(Vec2::new(1.0, 0.0), 0.0);
        f.alignments.insert(0, Alignment::along_one_pass(a, 280.0));
        let at = Iso2::new(Vec2::new(3.0, 0.0), 0.0);
        let g = f.gate(result(at, 0.05)).expect("agrees");
        assert!(g.standing == Standing::Vouched && g.slide.is_none());
        assert_eq!(g.prediction, Some(at), "the prediction test remains");
        // 5 m from the prediction: contradicts the alignment but not odometry, so it waits.
        let off = f
            .gate(result(Iso2::new(Vec2::new(8.0, 0.0), 0.0), 0.05))
            .expect("held");
        assert_ne!(off.standing, Standing::Vouched);
        let slide = off
            .slide
            .expect("not the first closure, still slide-tested");
        assert!(!slide.first && slide.ratio == 1.0);
        // An alignment too old to vouch (200 m of path back) vouches for nothing.
        f.alignments.insert(0, Alignment::along_one_pass(a, 100.0));
        assert_ne!(
            f.gate(result(at, 0.05)).expect("passes").standing,
            Standing::Vouched
        );
    }

    #[test]
    fn an_ambiguous_result_is_refused_unless_a_fresh_alignment_resolves_it() {
        let mut f = fixture();
        let at = Iso2::new(Vec2::new(2.0, 0.0), 0.0);
        let slid = Iso2::new(Vec2::new(12.0, 0.0), 0.0);
        let ambiguous = RegistrationResult {
            runner_up_overlap: 0.75,
            alternatives: vec![(slid, 0.75)],
            ..result(at, 0.05)
        };
        assert_eq!(reason(f.gate(ambiguous.clone())), RejectReason::Ambiguous);
        // The session's fresh alignment predicts `at`, contradicts the alternative, and the dense
        // stage started at the prediction ends at the result (the submap fits itself there).
        f.query = record(60, 0, at, 300.0);
        let at_identity = RegistrationResult {
            t_target_source: Iso2::identity(),
            alternatives: vec![(Iso2::new(Vec2::new(10.0, 0.0), 0.0), 0.75)],
            ..ambiguous
        };
        f.alignments
            .insert(0, Alignment::along_one_pass(at.inverse(), 290.0));
        let g = f.gate(at_identity).expect("resolved by the alignment");
        assert_eq!(g.standing, Standing::Vouched);
    }

    #[test]
    fn looking_the_other_way_has_no_common_view() {
        let mut f = fixture();
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let cone: Vec<Vec2> = (0..400)
            .map(|_| {
                let (r, a) = (rng.random_range(5.0..60.0), rng.random_range(-1.3..1.3f64));
                Vec2::new(r * a.cos(), r * a.sin())
            })
            .collect();
        f.map = PreparedSubmap::new(PointSet2::isotropic(cone, 0.15), &f.rc).expect("prepared");
        let turned = Iso2::new(Vec2::new(2.0, 0.0), std::f64::consts::PI);
        assert_eq!(
            reason(f.gate(result(turned, 0.05))),
            RejectReason::NoCommonView
        );
        f.lc.minimum_common_view = 0.0;
        assert_ne!(
            f.gate(result(turned, 0.05)).err().map(|e| e.0),
            Some(RejectReason::NoCommonView)
        );
    }

    #[test]
    fn the_prediction_test_refuses_a_result_the_prediction_does_not_lead_to() {
        let f = fixture();
        let g = f.gates();
        let c = |t: Iso2| LoopClosure {
            t_match_query: iso3_from_iso2(&t),
            ..closure(&f.pair(), &result(t, 0.05), &LoopConfig::default())
        };
        // The submap fits itself at the identity: a prediction near it ends there.
        let near = Iso2::new(Vec2::new(0.3, -0.2), 0.01);
        assert!(prediction_test(&g, &near, &c(Iso2::identity()), &f.map, &f.map).is_ok());
        // A result 6 m off that the prediction does not lead to is refused.
        let off = Iso2::new(Vec2::new(6.0, 0.0), 0.0);
        let e = prediction_test(&g, &near, &c(off), &f.map, &f.map).expect_err("refused");
        assert_eq!(e.0, RejectReason::Ambiguous);
    }

    #[test]
    fn the_slide_test_refuses_a_street_that_fits_when_slid() {
        let rc = RegistrationConfig::default();
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        // Bare facades 8 m either side of a 120 m street: any slide fits.
        let street: Vec<Vec2> = (0..300)
            .map(|k| {
                let side = if k % 2 == 0 { -8.0 } else { 8.0 };
                Vec2::new(
                    rng.random_range(-60.0..60.0),
                    side + rng.random_range(-0.1..0.1),
                )
            })
            .collect();
        let bare = PreparedSubmap::new(PointSet2::isotropic(street, 0.15), &rc).expect("bare");
        let s = |ratio: f64| Slide {
            t: Iso2::identity(),
            overlap: 0.9,
            ratio,
            first: true,
        };
        let e = slide_test(&rc, &s(0.7), &bare, &bare).expect_err("slides");
        assert_eq!(e.0, RejectReason::Ambiguous);
        // All round, nothing fits slid along the heading.
        let round = surroundings(4);
        assert!(slide_test(&rc, &s(0.7), &round, &round).is_ok());
    }
}
