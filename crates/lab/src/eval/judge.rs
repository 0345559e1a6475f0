//! Published closures judged against the simulator's ground truth: each closure's error, its NEES
//! under the published covariance, the revisit opportunities closed and missed, and the table of
//! [`RevisitReport`]s. One robot's laps ([`super::revisits`]) and a fleet's robots ([`super::fleet`])
//! are judged alike, passes for laps. docs/algorithm.md, "The evaluation", defines the opportunities,
//! the correct closures ([`FALSE_CLOSURE_THRESHOLD`], [`SAME_RADIUS`]), precision, recall and the
//! measured drift.

use crate::sim::{EgoState, SimDrive};
use dc_loc_core::loop_closure::LoopClosure;
use dc_loc_core::math::{Iso2, Mat3, Mat6, Stamp, Vec2, Vec3, iso2_from_iso3, se2_log, wrap_angle};
use dc_loc_core::pipeline::{Event, PipelineStats};
use dc_loc_core::registration::covariance_se2_from_ros;
use serde::Serialize;
use std::collections::BTreeMap;

/// Translation error above which a closure is false, m (the paper's outlier threshold).
pub const FALSE_CLOSURE_THRESHOLD: f64 = 2.0;
/// Same-direction revisit radius, m (the paper's pairing radius).
pub const SAME_RADIUS: f64 = 5.0;

/// A published closure judged against the ground truth.
#[derive(Debug, Clone, Serialize)]
pub struct JudgedClosure {
    /// Query keyframe id.
    pub query_id: u64,
    /// Match keyframe id.
    pub match_id: u64,
    /// The two keyframes were driven in opposite directions.
    pub reverse: bool,
    /// Translation error, m.
    pub translation_error: f64,
    /// Rotation error, rad.
    pub rotation_error: f64,
    /// Ground-truth distance between the two keyframes, m.
    pub distance: f64,
    /// The true pose of the query keyframe in the match keyframe's frame, `(x m, y m, yaw rad)`.
    pub truth: [f64; 3],
    /// The estimated position of the query keyframe minus its true one (match keyframe's frame), m:
    /// along the line from the match keyframe to the query keyframe (positive: estimated farther
    /// apart) and across it (positive: to the left of that line).
    pub along_across: [f64; 2],
    /// Registration inliers.
    pub inliers: u32,
    /// Overlap score.
    pub score: f64,
    /// Normalised estimation error squared of `(x, y, yaw)` under the closure's covariance (chi-square
    /// with 3 degrees of freedom when the covariance is right; `inf` when it is singular).
    pub nees: f64,
    /// The error `delta = Log(T_est^-1 T_true)` over `(x m, y m, yaw rad)`, in the query keyframe's
    /// frame (the published covariance's convention).
    pub error: [f64; 3],
    /// The published standard deviations of `(x m, y m, yaw rad)`.
    pub sigma: [f64; 3],
}

/// Counts for one direction of travel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct DirectionCounts {
    /// Revisit opportunities.
    pub opportunities: usize,
    /// Opportunities closed by a correct closure.
    pub closed: usize,
    /// Published closures.
    pub published: usize,
    /// Published closures more than 2 m off.
    pub false_closures: usize,
    /// Correct closures also within 1.0 m and 0.02 rad (the node issue's accuracy bar).
    pub within_accuracy_bar: usize,
}

impl DirectionCounts {
    /// Share of published closures within 2 m (1 when nothing was published).
    pub fn precision(&self) -> f64 {
        if self.published == 0 {
            1.0
        } else {
            (self.published - self.false_closures) as f64 / self.published as f64
        }
    }

    /// Share of opportunities closed (`NaN` when there were none).
    pub fn recall(&self) -> f64 {
        self.closed as f64 / self.opportunities as f64
    }
}

/// What one scenario gave.
#[derive(Debug, Clone, Serialize)]
pub struct RevisitReport {
    /// Scenario label.
    pub scenario: String,
    /// Keyframes taken.
    pub keyframes: u64,
    /// Measured odometry drift at the end of lap 1, share of distance.
    pub measured_drift: f64,
    /// Same-direction revisits.
    pub same: DirectionCounts,
    /// Opposite-direction revisits.
    pub reverse: DirectionCounts,
    /// Largest translation / rotation error of a correct closure, m / rad.
    pub max_error: (f64, f64),
    /// Largest translation error of a correct closure whose covariance does not cover it (NEES above
    /// the chi-square(3) 99 % bound), m: the error a pose graph would take at its word.
    pub max_error_uncovered: f64,
    /// Candidate rejections by reason.
    pub rejected: BTreeMap<String, u64>,
    /// Every published closure, judged.
    pub closures: Vec<JudgedClosure>,
    /// NEES of the published closures: mean, and the share above the chi-square(3) 99 % bound.
    pub nees: NeesSummary,
    /// Missed opportunities by what happened to their candidates: the reasons their candidates were
    /// rejected for, `no_candidate` when none was registered, `held` when a closure passed every gate
    /// but waited for confirmation, `false_only` when only false closures were published.
    pub missed: BTreeMap<String, usize>,
    /// Ids of the missed opportunities (query keyframes).
    pub missed_ids: Vec<u64>,
    /// The odometry's drift and the honesty of its covariance ([`super::odometry`]).
    pub odometry: super::odometry::OdometryDrift,
}

/// The radius of a reverse revisit: [`SAME_RADIUS`] plus twice the ego lane's offset (the other
/// carriageway).
pub(crate) fn reverse_radius(drive: &SimDrive) -> f64 {
    SAME_RADIUS + 2.0 * drive.setup.config.world.street.ego_lane_offset()
}

/// What a run of the pipeline published: keyframes, closures and the rejected candidates' reasons.
#[derive(Default)]
pub(crate) struct Collected {
    pub keyframes: Vec<(u64, Stamp)>,
    pub closures: Vec<LoopClosure>,
    pub rejections: Vec<(u64, String)>,
    /// The radar odometry's samples (none with odometry from a topic).
    pub odometry: Vec<super::odometry::OdometryTrackSample>,
}

impl Collected {
    /// Keeps what `events` tell.
    pub fn take(&mut self, events: Vec<Event>) {
        for e in events {
            match e {
                Event::Keyframe { id, stamp, .. } => self.keyframes.push((id, stamp)),
                Event::Closure(c) => self.closures.push(*c),
                Event::Rejected {
                    query_id, reason, ..
                } => self.rejections.push((query_id, reason.name().to_string())),
                Event::Odometry(o) => {
                    self.odometry
                        .push((o.stamp, iso2_from_iso3(&o.t_odom_body), o.covariance()))
                }
                _ => {}
            }
        }
    }
}

/// The ground truth of one keyframe.
pub(crate) struct KfTruth {
    pose: Iso2,
    heading: f64,
    /// Its pass: the lap of a drive, or the robot of a fleet (opportunities pair later passes with
    /// earlier ones).
    pass: usize,
    turning: bool,
}

/// Judges the published closures against the ground truth of their keyframes and counts the revisit
/// opportunities closed and missed (see the module documentation).
pub(crate) fn judge(
    truth: BTreeMap<u64, KfTruth>,
    reverse_radius: f64,
    measured_drift: f64,
    seen: &Collected,
    stats: &PipelineStats,
) -> RevisitReport {
    let opportunity = opportunities(&truth, reverse_radius);
    let mut report = RevisitReport {
        scenario: String::new(),
        keyframes: stats.keyframes,
        measured_drift,
        same: DirectionCounts::default(),
        reverse: DirectionCounts::default(),
        max_error: (0.0, 0.0),
        max_error_uncovered: 0.0,
        rejected: stats
            .rejected
            .iter()
            .map(|(r, n)| (r.name().to_string(), *n))
            .collect(),
        closures: Vec::new(),
        nees: NeesSummary::default(),
        missed: BTreeMap::new(),
        missed_ids: Vec::new(),
        odometry: Default::default(),
    };
    let closed = judge_closures(&mut report, &truth, &seen.closures);
    report.nees = NeesSummary::of(report.closures.iter().map(|c| c.nees));
    count_opportunities(&mut report, &opportunity, &closed, &seen.rejections);
    report
}

/// The ground truth of each keyframe of `drive`, by id; `pass` names the pass a state belongs to.
pub(crate) fn keyframe_truth(
    drive: &SimDrive,
    keyframes: &[(u64, Stamp)],
    pass: impl Fn(&EgoState) -> usize,
) -> BTreeMap<u64, KfTruth> {
    keyframes
        .iter()
        .map(|&(id, stamp)| {
            let s = drive.state_at(stamp);
            (
                id,
                KfTruth {
                    pose: s.t_map_body,
                    heading: s.heading,
                    pass: pass(&s),
                    turning: s.lap.turning,
                },
            )
        })
        .collect()
}

/// The two keyframes were driven in opposite directions.
fn is_reverse(a: &KfTruth, b: &KfTruth) -> bool {
    wrap_angle(a.heading - b.heading).abs() > 0.5 * std::f64::consts::PI
}

/// Opportunities: keyframes on a later lap (not turning) with an earlier-lap keyframe within
/// [`SAME_RADIUS`] in the same direction (value `false`) or else within `reverse_radius` in the opposite
/// direction (value `true`).
fn opportunities(truth: &BTreeMap<u64, KfTruth>, reverse_radius: f64) -> BTreeMap<u64, bool> {
    let mut opportunity: BTreeMap<u64, bool> = BTreeMap::new();
    for (&q, tq) in truth {
        if tq.pass == 0 || tq.turning {
            continue;
        }
        let (mut same, mut rev) = (false, false);
        for tm in truth.values() {
            if tm.pass >= tq.pass || tm.turning {
                continue;
            }
            let d = (tq.pose.translation.vector - tm.pose.translation.vector).norm();
            if is_reverse(tq, tm) {
                rev |= d <= reverse_radius;
            } else {
                same |= d <= SAME_RADIUS;
            }
        }
        if same {
            opportunity.insert(q, false);
        } else if rev {
            opportunity.insert(q, true);
        }
    }
    opportunity
}

/// Judges each closure between known keyframes into the report's counts, errors and closure list;
/// returns the keyframes of the later pass closed by a correct closure.
fn judge_closures(
    report: &mut RevisitReport,
    truth: &BTreeMap<u64, KfTruth>,
    closures: &[LoopClosure],
) -> BTreeMap<u64, bool> {
    let mut closed: BTreeMap<u64, bool> = BTreeMap::new();
    for c in closures {
        let (Some(tq), Some(tm)) = (truth.get(&c.query_id), truth.get(&c.match_id)) else {
            continue;
        };
        let t = tm.pose.inverse() * tq.pose;
        let est = iso2_from_iso3(&c.t_match_query);
        let et = (t.translation.vector - est.translation.vector).norm();
        let er = wrap_angle(t.rotation.angle() - est.rotation.angle()).abs();
        let reverse = is_reverse(tq, tm);
        let error = se2_log(&(est.inverse() * t));
        let cov = covariance_se2_from_ros(&c.covariance);
        let nees = nees(&error, &cov);
        let counts = if reverse {
            &mut report.reverse
        } else {
            &mut report.same
        };
        counts.published += 1;
        if et > FALSE_CLOSURE_THRESHOLD {
            counts.false_closures += 1;
        } else {
            if et <= 1.0 && er <= 0.02 {
                counts.within_accuracy_bar += 1;
            }
            report.max_error.0 = report.max_error.0.max(et);
            report.max_error.1 = report.max_error.1.max(er);
            if outside_bound(nees) {
                report.max_error_uncovered = report.max_error_uncovered.max(et);
            }
            // The keyframe of the later pass is the opportunity (in a fleet, the node that registered
            // the pair may be the earlier robot's).
            let later = if tq.pass >= tm.pass {
                c.query_id
            } else {
                c.match_id
            };
            closed.insert(later, true);
        }
        report.closures.push(JudgedClosure {
            query_id: c.query_id,
            match_id: c.match_id,
            reverse,
            translation_error: et,
            rotation_error: er,
            distance: t.translation.vector.norm(),
            truth: [t.translation.x, t.translation.y, t.rotation.angle()],
            along_across: along_across(&t, &est),
            inliers: c.inliers,
            score: c.score,
            nees,
            error: error.into(),
            sigma: cov.diagonal().map(|v| v.max(0.0).sqrt()).into(),
        });
    }
    closed
}

/// `est`'s translation minus `truth`'s, along and across the direction of `truth`'s translation, m
/// (zero when the two keyframes coincide).
fn along_across(truth: &Iso2, est: &Iso2) -> [f64; 2] {
    let t = truth.translation.vector;
    let d = est.translation.vector - t;
    let u = t.try_normalize(1e-9).unwrap_or_else(Vec2::zeros);
    [d.dot(&u), u.perp(&d)]
}

/// The chi-square(3) 99 % quantile: a correct 3-DOF covariance leaves 1 % of NEES values above it.
pub const CHI2_3_99: f64 = 11.345;

/// NEES of a set of closures against their truth.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct NeesSummary {
    /// Closures counted.
    pub count: usize,
    /// Mean NEES (3 when the covariances are right; `NaN` without closures).
    pub mean: f64,
    /// Closures with NEES above [`CHI2_3_99`].
    pub above_99: usize,
}

impl NeesSummary {
    /// Summarises NEES values (a singular covariance counts as infinite).
    pub fn of(values: impl Iterator<Item = f64>) -> Self {
        let mut s = NeesSummary::default();
        let mut sum = 0.0;
        for v in values {
            s.count += 1;
            sum += v;
            if outside_bound(v) {
                s.above_99 += 1;
            }
        }
        s.mean = sum / s.count as f64;
        s
    }

    /// Share of closures above the 99 % bound (0 without closures).
    pub fn share_above_99(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.above_99 as f64 / self.count as f64
        }
    }
}

/// The covariance does not cover the error: NEES above [`CHI2_3_99`] (or undefined).
fn outside_bound(nees: f64) -> bool {
    nees.is_nan() || nees > CHI2_3_99
}

/// NEES of an estimated `T_match_query` against the truth, with `covariance` (ROS order, over the
/// right perturbation `T_true = T_est * Exp(delta)`) reduced to its `(x, y, yaw)` block.
pub fn closure_nees(est: &Iso2, truth: &Iso2, covariance: &Mat6) -> f64 {
    nees(
        &se2_log(&(est.inverse() * truth)),
        &covariance_se2_from_ros(covariance),
    )
}

/// NEES of the error `e` over `(x, y, yaw)` under the covariance `c`; `inf` when `c` is singular.
fn nees(e: &Vec3, c: &Mat3) -> f64 {
    c.try_inverse()
        .map_or(f64::INFINITY, |ci| e.dot(&(ci * e)).max(0.0))
}

/// Counts the opportunities and those closed per direction; each missed one is counted under the
/// reasons its candidates were rejected for (see [`RevisitReport::missed`]).
fn count_opportunities(
    report: &mut RevisitReport,
    opportunity: &BTreeMap<u64, bool>,
    closed: &BTreeMap<u64, bool>,
    rejections: &[(u64, String)],
) {
    for (q, rev) in opportunity {
        let counts = if *rev {
            &mut report.reverse
        } else {
            &mut report.same
        };
        counts.opportunities += 1;
        if closed.contains_key(q) {
            counts.closed += 1;
            continue;
        }
        report.missed_ids.push(*q);
        let mut why: Vec<&str> = rejections
            .iter()
            .filter(|r| r.0 == *q)
            .map(|r| r.1.as_str())
            .collect();
        if why.is_empty() {
            why.push(if report.closures.iter().any(|c| c.query_id == *q) {
                "false_only"
            } else {
                "no_candidate_or_held"
            });
        }
        why.sort_unstable();
        why.dedup();
        for w in why {
            *report.missed.entry(w.to_string()).or_default() += 1;
        }
    }
}

/// Odometry position error at the end of the first lap over the ground-truth path driven.
pub(crate) fn measured_drift(drive: &SimDrive) -> f64 {
    let Some(end) = drive.ground_truth.iter().rfind(|g| g.lap.lap == 0) else {
        return f64::NAN;
    };
    let Some(o) = drive
        .odometry
        .iter()
        .min_by_key(|o| (o.stamp.0 - end.stamp.0).abs())
    else {
        return f64::NAN;
    };
    let first = drive.ground_truth.first().map_or(0.0, |g| g.distance);
    let err =
        (drive.t_map_odom() * o.t_odom_body).translation.vector - end.t_map_body.translation.vector;
    err.norm() / (end.distance - first).max(1.0)
}

/// The README table: one row per scenario. The odometry's own columns (its heading drift and the NEES
/// of its covariance over 10 m windows) appear when a row's odometry carries a covariance (a radar
/// source); a wheel odometry's rows show `-` there.
pub fn format_revisit_table(reports: &[RevisitReport]) -> String {
    let estimated = reports.iter().any(|r| r.odometry.windows > 0);
    let mut s = String::new();
    if estimated {
        s.push_str("| scenario | drift (measured) | heading drift (deg/100 m) | odometry NEES (10 m) mean / above 99 % | keyframes | same: published / false / precision / recall | reverse: published / false / precision / recall | max error (m, rad) / outside the bound (m) | NEES mean / above 99 % |\n");
        s.push_str("|---|---|---|---|---|---|---|---|---|\n");
    } else {
        s.push_str("| scenario | drift (measured) | keyframes | same: published / false / precision / recall | reverse: published / false / precision / recall | max error (m, rad) / outside the bound (m) | NEES mean / above 99 % |\n");
        s.push_str("|---|---|---|---|---|---|---|\n");
    }
    let dir = |c: &DirectionCounts| {
        if c.opportunities == 0 && c.published == 0 {
            "-".to_string()
        } else {
            format!(
                "{} / {} / {:.1} % / {:.1} % ({}/{})",
                c.published,
                c.false_closures,
                100.0 * c.precision(),
                100.0 * c.recall(),
                c.closed,
                c.opportunities
            )
        }
    };
    for r in reports {
        let odometry = if !estimated {
            String::new()
        } else if r.odometry.windows > 0 {
            format!(
                " {:.2} | {:.1} / {:.1} % |",
                r.odometry.heading_deg_per_100m,
                r.odometry.nees_mean,
                100.0 * r.odometry.nees_above_99
            )
        } else {
            format!(" {:.2} | - |", r.odometry.heading_deg_per_100m)
        };
        s.push_str(&format!(
            "| {} | {:.2} % |{odometry} {} | {} | {} | {:.2}, {:.4} / {:.2} | {:.1} / {:.1} % |\n",
            r.scenario,
            100.0 * r.measured_drift,
            r.keyframes,
            dir(&r.same),
            dir(&r.reverse),
            r.max_error.0,
            r.max_error.1,
            r.max_error_uncovered,
            r.nees.mean,
            100.0 * r.nees.share_above_99()
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use dc_loc_core::math::{iso3_from_iso2, se2_exp};
    use dc_loc_core::registration::covariance_ros_from_se2;

    /// An estimate 0.5 m farther from the match keyframe and 0.3 m to the right of the line between
    /// the two keyframes is split into those two figures.
    #[test]
    fn the_error_is_split_along_and_across_the_line_between_the_keyframes() {
        let truth = Iso2::new(Vec2::new(0.0, 4.0), 0.3);
        let est = Iso2::new(Vec2::new(0.3, 4.5), 0.0);
        let [along, across] = along_across(&truth, &est);
        assert!((along - 0.5).abs() < 1e-12, "0.5 m farther apart: {along}");
        assert!((across + 0.3).abs() < 1e-12, "0.3 m to the right: {across}");
        assert_eq!(along_across(&Iso2::identity(), &est), [0.0, 0.0]);
    }

    /// A closure off its truth by a known `delta` (`T_est = T_true Exp(-delta)`) is judged with that
    /// error, its published standard deviations and the NEES they give.
    #[test]
    fn a_closure_is_judged_with_its_error_and_sigmas() {
        let kf = |x: f64, pass: usize| KfTruth {
            pose: Iso2::new(Vec2::new(x, 0.0), 0.0),
            heading: 0.0,
            pass,
            turning: false,
        };
        let truth = || BTreeMap::from([(1, kf(0.0, 0)), (10, kf(3.0, 1))]);
        let delta = Vec3::new(0.3, -0.1, 0.02);
        let (m, q) = (truth()[&1].pose, truth()[&10].pose);
        let t_true = m.inverse() * q;
        let est = t_true * se2_exp(&(-delta));
        let sigma = Vec3::new(0.2, 0.1, 0.01);
        let closure = LoopClosure {
            query_id: 10,
            match_id: 1,
            query_stamp: Stamp(0),
            match_stamp: Stamp(0),
            query_odom_pose: iso3_from_iso2(&q),
            match_odom_pose: iso3_from_iso2(&m),
            t_match_query: iso3_from_iso2(&est),
            covariance: covariance_ros_from_se2(&Mat3::from_diagonal(&sigma.component_mul(&sigma))),
            inliers: 40,
            score: 0.7,
            match_session: 0,
            query_robot: 0,
            match_origin: None,
        };
        let mut report = judge(
            truth(),
            10.0,
            0.01,
            &Collected::default(),
            &PipelineStats::default(),
        );
        judge_closures(
            &mut report,
            &BTreeMap::new(),
            std::slice::from_ref(&closure),
        );
        assert!(
            report.closures.is_empty(),
            "unknown keyframes are not judged"
        );
        judge_closures(&mut report, &truth(), std::slice::from_ref(&closure));
        let c = &report.closures[0];
        for k in 0..3 {
            assert!((c.error[k] - delta[k]).abs() < 1e-9, "{:?}", c.error);
            assert!((c.sigma[k] - sigma[k]).abs() < 1e-9, "{:?}", c.sigma);
        }
        assert_eq!(c.truth, [3.0, 0.0, 0.0]);
        let off = est.translation.vector - Vec2::new(3.0, 0.0);
        assert!(
            (c.along_across[0] - off.x).abs() < 1e-12 && (c.along_across[1] - off.y).abs() < 1e-12
        );
        let want_nees = (0..3).map(|k| (delta[k] / sigma[k]).powi(2)).sum::<f64>();
        assert!(
            (c.nees - want_nees).abs() < 1e-6,
            "{} vs {want_nees}",
            c.nees
        );
        // NEES 7.25 lies within the 99 % bound; with half the sigmas, 29, it does not.
        assert_eq!(report.max_error_uncovered, 0.0);
        let half = sigma / 2.0;
        let tight = LoopClosure {
            covariance: covariance_ros_from_se2(&Mat3::from_diagonal(&half.component_mul(&half))),
            ..closure
        };
        judge_closures(&mut report, &truth(), &[tight]);
        assert!(report.closures[1].nees > CHI2_3_99);
        assert_eq!(
            report.max_error_uncovered,
            report.closures[1].translation_error
        );
    }
}
