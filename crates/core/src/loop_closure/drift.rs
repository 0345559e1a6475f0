//! The odometry drift model the gates test closures against: how far a prediction from odometry, or
//! from an accepted alignment, may be off after some metres of path.

use super::calibration::moved_frames_covariance;
use super::{Alignment, LoopClosure, LoopConfig};
use crate::keyframe_db::KeyframeRecord;
use crate::math::{Iso2, Mat3, Mat6, Vec3, iso2_from_iso3, se2_adjoint, se2_log};
use crate::registration::covariance_se2_from_ros;

/// The `T_match_query` an alignment of the query's odometry frame into the match's session frame
/// predicts.
pub fn predict(alignment: &Iso2, query: &KeyframeRecord, cand: &KeyframeRecord) -> Iso2 {
    cand.t_odom_body.inverse() * alignment * query.t_odom_body
}

/// Whether an accepted alignment found `path_gap` metres of path away is fresh enough to vouch for
/// a closure alone (`loop.trusted_prior_std`).
pub fn vouches(path_gap: f64, lc: &LoopConfig) -> bool {
    alignment_sigmas(path_gap, lc).0 <= lc.trusted_prior_std
}

/// Largest translation standard deviation of a covariance in ROS order (largest eigenvalue of its x-y
/// block), m.
pub fn translation_std(cov: &Mat6) -> f64 {
    let xy = cov.fixed_view::<2, 2>(0, 0).into_owned();
    xy.symmetric_eigenvalues().max().max(0.0).sqrt()
}

/// The drift model's translation bound before any path is driven, m: odometry error that does not
/// grow with the distance (wheel slip at a standstill, the error of the pose it started from). The
/// search radius is wider: it also spans the distance between two passes of one place (the other
/// carriageway), which is no error.
const DRIFT_BOUND_BASE: f64 = 15.0;

/// How far beyond the drift model a closure may lie from a prior that odometry drift alone separates
/// it from and still wait for confirmation: this many times the model's bounds, i.e. the bounds read
/// as one standard deviation instead of three. A yaw-rate bias integrated over a lap lies within it; a
/// street matched to its point-symmetric twin across a block (half a turn and a block's width off)
/// does not, and such twins agree with each other from every keyframe along the street.
const BEYOND_DRIFT_REACH: f64 = 3.0;

/// Whether a closure at squared Mahalanobis distance `d2` from a prediction under the drift model
/// ([`drift_sigmas`]) lies within [`BEYOND_DRIFT_REACH`] times the bounds `loop.consistency_chi2`
/// sets.
pub fn within_reach(d2: f64, lc: &LoopConfig) -> bool {
    d2 <= reach_chi2(lc)
}

/// The largest squared Mahalanobis distance [`within_reach`] allows.
pub fn reach_chi2(lc: &LoopConfig) -> f64 {
    BEYOND_DRIFT_REACH * BEYOND_DRIFT_REACH * lc.consistency_chi2
}

/// Standard deviations (m, rad) of the odometry drift over `path_gap` metres: the drift model's bounds
/// ([`DRIFT_BOUND_BASE`] plus `drift_rate` per metre, 0.05 rad plus `drift_yaw_rate` per metre) read as
/// three standard deviations, so that the default 3-dof chi-square gate accepts a closure whose
/// translation and heading errors both lie near their bounds (heading drift also moves the position).
pub fn drift_sigmas(path_gap: f64, lc: &LoopConfig) -> (f64, f64) {
    let gap = path_gap.abs();
    (
        (DRIFT_BOUND_BASE + lc.drift_rate * gap).min(lc.search_radius_max) / 3.0,
        (0.05 + lc.drift_yaw_rate * gap).min(std::f64::consts::PI) / 3.0,
    )
}

/// Covariance over `(x, y, yaw)` that the odometry's heading drift within the two submaps adds to the
/// closure `t_match_query`, with `arms` = `[query, match]` the mean path length, m, of each submap's
/// scans behind its keyframe.
///
/// A submap places its scans with the odometry: a heading drift of `k` rad per metre turns a scan
/// `l` metres behind the keyframe by `k l`, and its returns with it, about the keyframe when they lie
/// far away. To first order the submap is turned by `k` times its arm. Both submaps drift at the same
/// rate, so the registration finds `T' = Exp(k l_m e_yaw) T Exp(-k l_q e_yaw)`, and as for a clock
/// offset ([`super::calibration::clock_covariance`]) `delta = k (l_q e_yaw - l_m Ad_{T^-1} e_yaw)`:
/// nothing between keyframes at one pose with equal arms, and across the line between two keyframes
/// `D` metres apart the match's turn times `D`. The rate's standard deviation is `drift_yaw_rate` read
/// as [`drift_sigmas`] reads it, a third of the bound.
pub fn heading_drift_covariance(t_match_query: &Iso2, arms: [f64; 2], lc: &LoopConfig) -> Mat3 {
    moved_frames_covariance(t_match_query, Vec3::z(), arms, lc.drift_yaw_rate / 3.0)
}

/// Standard deviations (m, rad) of an accepted alignment's prediction `path_gap` metres of path after the
/// closure that gave it: the closure's own accuracy (0.5 m, 0.01 rad) plus the drift since, with the drift
/// model's rates read as two standard deviations. Tighter than [`drift_sigmas`]: right after a closure the
/// odometry is known to within decimetres, and a street that slides by a few metres is caught.
pub fn alignment_sigmas(path_gap: f64, lc: &LoopConfig) -> (f64, f64) {
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
pub fn alignment_distance(a: &Iso2, b: &Iso2, at: &Iso2, path_gap: f64, lc: &LoopConfig) -> f64 {
    let e = se2_log(&((a * at).inverse() * (b * at)));
    let gap = path_gap.abs();
    let st = 1.0 + 0.5 * lc.drift_rate * gap;
    let sr = 0.02 + 0.5 * lc.drift_yaw_rate * gap;
    (e.x * e.x + e.y * e.y) / (st * st) + e.z * e.z / (sr * sr)
}

/// Squared Mahalanobis distance between closure `a` and its prediction from closure `b`, two
/// closures of this session's keyframes to one other pass: `b` carried to `a`'s keyframes through the
/// odometry between their query keyframes (`path_gap` metres of path) and between their match
/// keyframes, under both closures' covariances plus the drift over those two stretches; `None` when
/// that sum is singular.
///
/// With `T_true = T Exp(delta)` for each closure and each stretch of odometry, the prediction
/// `P = M_ab T_b Q_ba` (`M_ab` from `a`'s match keyframe to `b`'s, `Q_ba` from `b`'s query keyframe to
/// `a`'s) moves by `Ad((T_b Q_ba)^-1) e_M + Ad(Q_ba^-1) delta_b + e_Q`, in `a`'s query frame as
/// `delta_a`. The drift over `g` metres is the drift model's rates read as [`drift_sigmas`] reads
/// them, a third of the bound, without its base: two keyframes a few metres apart on one odometry are
/// known relative to each other to the drift over that stretch, not to the drift since the start.
/// The closure does not carry its match keyframe's path length: the match stretch is the longer of
/// `path_gap` and the straight line between the two match keyframes.
pub fn closure_disagreement(
    a: &LoopClosure,
    b: &LoopClosure,
    path_gap: f64,
    lc: &LoopConfig,
) -> Option<f64> {
    let (ta, tb) = (
        iso2_from_iso3(&a.t_match_query),
        iso2_from_iso3(&b.t_match_query),
    );
    let q_ba = iso2_from_iso3(&b.query_odom_pose).inverse() * iso2_from_iso3(&a.query_odom_pose);
    let m_ab = iso2_from_iso3(&a.match_odom_pose).inverse() * iso2_from_iso3(&b.match_odom_pose);
    let predicted = m_ab * tb * q_ba;
    let e = se2_log(&(predicted.inverse() * ta));
    let match_gap = path_gap.abs().max(m_ab.translation.vector.norm());
    let carry_b = se2_adjoint(&q_ba.inverse());
    let carry_m = se2_adjoint(&(tb * q_ba).inverse());
    let cov = covariance_se2_from_ros(&a.covariance)
        + carry_b * covariance_se2_from_ros(&b.covariance) * carry_b.transpose()
        + stretch_drift(path_gap, lc)
        + carry_m * stretch_drift(match_gap, lc) * carry_m.transpose();
    let inv = cov.try_inverse()?;
    Some(e.dot(&(inv * e)))
}

/// Covariance over `(x, y, yaw)` of the odometry's relative pose over `gap` metres of path: the drift
/// model's rates read as three standard deviations, the heading's drift turning the path behind it
/// (half the rate times the squared distance) added to the translation's.
fn stretch_drift(gap: f64, lc: &LoopConfig) -> Mat3 {
    let g = gap.abs();
    let st = (lc.drift_rate * g + 0.5 * lc.drift_yaw_rate * g * g) / 3.0;
    let sr = lc.drift_yaw_rate * g / 3.0;
    Mat3::from_diagonal(&Vec3::new(st * st, st * st, sr * sr))
}

/// What a closure is tested against: the session's accepted alignment, or (for a candidate of this
/// session) odometry itself, or an alignment to another session under the drift along both paths.
#[derive(Debug, Clone, Copy)]
pub enum Prior<'a> {
    /// The accepted alignment to the candidate's session.
    Alignment(&'a Alignment),
    /// Odometry: the candidate belongs to this session.
    Odometry,
    /// An alignment of this session's frame into the candidate's session's (this session's
    /// accepted one, or the one the candidate's robot accepted to this session, inverted), as odometry
    /// carries it: the drift along both sessions' paths since the closure that gave it separates its
    /// prediction from the truth, under the drift model's bounds ([`drift_sigmas`]).
    Anchored(&'a Alignment),
}

/// The drift model's standard deviations (m, rad) of `prior`'s prediction of a closure from `query`
/// onto `cand`, and the alignment it predicts with.
fn prior_sigmas(
    prior: Prior<'_>,
    query: &KeyframeRecord,
    cand: &KeyframeRecord,
    lc: &LoopConfig,
) -> (Iso2, (f64, f64)) {
    match prior {
        Prior::Alignment(a) => (a.t, alignment_sigmas(query.path_distance - a.path, lc)),
        Prior::Odometry => (
            Iso2::identity(),
            drift_sigmas(query.path_distance - cand.path_distance, lc),
        ),
        Prior::Anchored(a) => (
            a.t,
            anchored_sigmas(a, query.path_distance, cand.path_distance, lc),
        ),
    }
}

/// The drift model's standard deviations (m, rad) of alignment `a`'s prediction of a closure from
/// this session's keyframe at `query_path` onto the other session's at `match_path`: the drift over
/// both sessions' paths since the closure that gave it ([`Prior::Anchored`]).
fn anchored_sigmas(a: &Alignment, query_path: f64, match_path: f64, lc: &LoopConfig) -> (f64, f64) {
    let gap = (query_path - a.path).abs() + (match_path - a.match_path).abs();
    drift_sigmas(gap, lc)
}

/// Squared Mahalanobis distance between a held closure `c` (its keyframes at `paths`, query then
/// match, m) and alignment `a`'s prediction ([`Prior::Anchored`]); `None` when the covariance is
/// singular.
pub fn anchored_inconsistency(
    a: &Alignment,
    c: &LoopClosure,
    paths: [f64; 2],
    lc: &LoopConfig,
) -> Option<f64> {
    let predicted =
        iso2_from_iso3(&c.match_odom_pose).inverse() * a.t * iso2_from_iso3(&c.query_odom_pose);
    let t = iso2_from_iso3(&c.t_match_query);
    let sigmas = anchored_sigmas(a, paths[0], paths[1], lc);
    distance_to(&t, &predicted, &c.covariance, sigmas)
}

/// Squared Mahalanobis distance between a registered `T_match_query` (`t`, covariance `cov6` in ROS
/// order) and its prediction by `prior` under the closure's covariance plus the drift since the prior
/// was found; `None` when the covariance is singular.
pub fn inconsistency(
    prior: Prior<'_>,
    query: &KeyframeRecord,
    cand: &KeyframeRecord,
    t: &Iso2,
    cov6: &Mat6,
    lc: &LoopConfig,
) -> Option<f64> {
    let (alignment, sigmas) = prior_sigmas(prior, query, cand, lc);
    distance_to(t, &predict(&alignment, query, cand), cov6, sigmas)
}

/// Squared Mahalanobis distance between `t` and `predicted` under `cov6` (ROS order) plus the
/// prediction's standard deviations `(sigma_t, sigma_r)` (m, rad); `None` when that is singular.
fn distance_to(
    t: &Iso2,
    predicted: &Iso2,
    cov6: &Mat6,
    (sigma_t, sigma_r): (f64, f64),
) -> Option<f64> {
    let e = se2_log(&(t.inverse() * predicted));
    let mut cov = covariance_se2_from_ros(cov6);
    cov[(0, 0)] += sigma_t * sigma_t;
    cov[(1, 1)] += sigma_t * sigma_t;
    cov[(2, 2)] += sigma_r * sigma_r;
    let inv = cov.try_inverse()?;
    Some(e.dot(&(inv * e)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Stamp, Vec2, iso3_from_iso2, se2_exp};
    use crate::registration::covariance_ros_from_se2;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};

    /// A closure from the query odometry pose `q`, the match odometry pose `m` and the registration's
    /// `t`, with the planar covariance `cov`.
    fn closure(q: &Iso2, m: &Iso2, t: &Iso2, cov: &Mat3) -> LoopClosure {
        LoopClosure {
            query_id: 1,
            match_id: 0,
            query_stamp: Stamp(0),
            match_stamp: Stamp(0),
            query_odom_pose: iso3_from_iso2(q),
            match_odom_pose: iso3_from_iso2(m),
            t_match_query: iso3_from_iso2(t),
            covariance: covariance_ros_from_se2(cov),
            inliers: 50,
            score: 0.9,
            match_session: 0,
            query_robot: 0,
            match_origin: None,
        }
    }

    /// A draw of `N(0, diag(s^2))`.
    fn draw(rng: &mut rand::rngs::StdRng, s: [f64; 3]) -> Vec3 {
        Vec3::from_fn(|i, _| {
            let z: f64 = StandardNormal.sample(rng);
            s[i] * z
        })
    }

    /// Two closures of one street, 12 m apart along the query's path, to a pass driven the other
    /// way with a drifted odometry frame. Each closure's registration and each stretch of odometry
    /// between the two is perturbed by a draw of its stated covariance: the squared distance
    /// averages 3 (chi-square with 3 degrees of freedom), so the propagation through the adjoints is
    /// what the draws make. A closure slid by 2 m along the street with 5 cm sigmas is far outside;
    /// one off by 5 cm is not.
    #[test]
    fn closure_disagreement_is_chi_square_for_draws_of_the_stated_covariances() {
        let lc = LoopConfig::default();
        let alignment = Iso2::new(Vec2::new(40.0, -15.0), 2.9);
        let qa = Iso2::new(Vec2::new(212.0, 31.0), 0.4);
        let qb = qa * Iso2::new(Vec2::new(-12.0, 0.3), -0.02);
        // The match keyframes: on the other carriageway of the same street, the other way.
        let ma = alignment * qa * Iso2::new(Vec2::new(3.0, 7.5), std::f64::consts::PI - 0.03);
        let mb = alignment * qb * Iso2::new(Vec2::new(-2.0, 7.0), std::f64::consts::PI + 0.02);
        let truth = |q: &Iso2, m: &Iso2| m.inverse() * alignment * q;
        let (sa, sb) = ([0.05, 0.08, 0.002], [0.12, 0.04, 0.003]);
        let cov =
            |s: [f64; 3]| Mat3::from_diagonal(&Vec3::new(s[0] * s[0], s[1] * s[1], s[2] * s[2]));
        let drift = |g: f64| {
            let d = stretch_drift(g, &lc);
            [d[(0, 0)].sqrt(), d[(1, 1)].sqrt(), d[(2, 2)].sqrt()]
        };
        // The match stretch as the closure sees it: the straight line between the match keyframes.
        let match_gap = (ma.inverse() * mb).translation.vector.norm();
        assert!(match_gap > 12.0);
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let n = 4000;
        let mut sum = 0.0;
        for _ in 0..n {
            // The odometry between the query keyframes and between the match keyframes drifts.
            let qa_seen = qa * se2_exp(&draw(&mut rng, drift(12.0)));
            let mb_seen = mb * se2_exp(&draw(&mut rng, drift(match_gap)));
            let ta = truth(&qa, &ma) * se2_exp(&draw(&mut rng, sa));
            let tb = truth(&qb, &mb) * se2_exp(&draw(&mut rng, sb));
            let a = closure(&qa_seen, &ma, &ta, &cov(sa));
            let b = closure(&qb, &mb_seen, &tb, &cov(sb));
            sum += closure_disagreement(&a, &b, 12.0, &lc).expect("regular");
        }
        let mean = sum / n as f64;
        assert!((mean - 3.0).abs() < 0.25, "mean squared distance {mean}");
        let tight = [0.05, 0.05, 0.001];
        let b = closure(&qb, &mb, &truth(&qb, &mb), &cov(tight));
        for (off, inside) in [(2.0, false), (0.05, true)] {
            let slid = truth(&qa, &ma) * Iso2::new(Vec2::new(off, 0.0), 0.0);
            let a = closure(&qa, &ma, &slid, &cov(tight));
            let d = closure_disagreement(&a, &b, 12.0, &lc).expect("regular");
            assert_eq!(d <= 16.27, inside, "{off} m off: {d}");
        }
    }

    /// The first-order error against the exact one: each submap turned by the drift rate times its
    /// arm, the registration's answer `Exp(k l_m e_yaw) T Exp(-k l_q e_yaw)`, its error
    /// `Log(T'^-1 T)`; the covariance is that error's outer product at the rate's standard deviation.
    #[test]
    fn heading_drift_error_is_the_turned_submaps_error() {
        let lc = LoopConfig::default();
        let k = lc.drift_yaw_rate / 3.0;
        let arms = [7.0, 4.0];
        for t in [
            Iso2::new(Vec2::new(150.0, 2.0), 0.05),
            Iso2::new(Vec2::new(-3.0, 12.0), std::f64::consts::PI - 0.1),
            Iso2::new(Vec2::new(0.5, 0.0), 0.0),
        ] {
            let turn = |l: f64| se2_exp(&Vec3::new(0.0, 0.0, k * l));
            let seen = turn(arms[1]) * t * turn(arms[0]).inverse();
            let exact = se2_log(&(seen.inverse() * t));
            let c = heading_drift_covariance(&t, arms, &lc);
            let expected = exact * exact.transpose();
            assert!(
                (c - expected).norm() < 1e-3 * expected.norm(),
                "{c} vs {expected}"
            );
        }
    }

    /// Keyframes at one pose with equal arms take nothing; 150 m apart along the street, the match's
    /// turn moves the query across the street by its arm times the rate times the distance, and not
    /// along it.
    #[test]
    fn heading_drift_widens_across_the_line_between_the_keyframes() {
        let lc = LoopConfig::default();
        let k = lc.drift_yaw_rate / 3.0;
        let at_one_pose = heading_drift_covariance(&Iso2::identity(), [6.0, 6.0], &lc);
        assert!(at_one_pose.norm() < 1e-15);
        let far = heading_drift_covariance(&Iso2::new(Vec2::new(150.0, 0.0), 0.0), [6.0, 6.0], &lc);
        assert!((far[(1, 1)].sqrt() - k * 6.0 * 150.0).abs() < 1e-9, "{far}");
        assert!(
            far[(0, 0)].abs() < 1e-12 && far[(2, 2)].abs() < 1e-12,
            "{far}"
        );
    }

    /// The alignment's prediction tightens the drift model near the closure that gave it, and both
    /// grow with the path.
    #[test]
    fn sigmas_grow_with_the_path_and_alignments_are_tighter() {
        let lc = LoopConfig::default();
        let (t0, r0) = alignment_sigmas(0.0, &lc);
        assert_eq!((t0, r0), (0.5, 0.01));
        let (t100, _) = alignment_sigmas(100.0, &lc);
        assert!((t100 - 3.0).abs() < 1e-12);
        let (d100, _) = drift_sigmas(100.0, &lc);
        assert!((d100 - 20.0 / 3.0).abs() < 1e-12);
        assert!(vouches(60.0, &lc) && !vouches(61.0, &lc));
        let far = drift_sigmas(1e9, &lc);
        assert_eq!(far.0, lc.search_radius_max / 3.0);
    }

    #[test]
    fn alignments_agree_within_their_drift() {
        let lc = LoopConfig::default();
        let a = Iso2::new(crate::math::Vec2::new(10.0, 0.0), 0.1);
        let at = Iso2::new(crate::math::Vec2::new(50.0, 20.0), 0.3);
        assert_eq!(alignment_distance(&a, &a, &at, 0.0, &lc), 0.0);
        let b = Iso2::new(crate::math::Vec2::new(12.0, 0.0), 0.1);
        // 2 m apart: 4 sigma^2 right after the closure, under 1 after 100 m of path.
        assert!((alignment_distance(&a, &b, &at, 0.0, &lc) - 4.0).abs() < 1e-9);
        assert!(alignment_distance(&a, &b, &at, 100.0, &lc) < 1.0);
    }
}
