//! Revisit detection measured on simulated drives: precision and recall of the published loop closures
//! under odometry drift, same-direction and reverse laps, the three noise models, one and five radars.
//!
//! Steps, in order: simulate the scenario ([`RevisitScenario::sim_config`]); drive the [`Pipeline`] with
//! revisit search on, exactly as the node does ([`evaluate_revisits`]); compare every published closure
//! with the ground truth of its two keyframes; count the revisit opportunities (keyframes of a later lap
//! with an earlier lap's keyframe nearby) and which of them were closed ([`RevisitReport`]).
//!
//! Definitions.
//! - *Opportunity*: a keyframe on lap >= 2 (not in a U-turn) whose ground-truth nearest keyframe on an
//!   earlier lap lies within `same_radius` (5 m, the paper's pairing radius) when driven in the same
//!   direction, or within `reverse_radius` when driven in the opposite direction (5 m plus twice the ego
//!   lane's offset from the centre line: a reverse lap drives the other carriageway).
//! - *Correct closure*: translation error of `T_match_query` against the ground truth at most 2.0 m (the
//!   paper's outlier threshold). Precision = correct / published; recall = opportunities whose keyframe
//!   published at least one correct closure / opportunities.
//! - *Drift* (measured): the odometry's position error at the end of the first lap over the path driven.

use crate::loop_closure::LoopClosure;
use crate::math::{Iso2, Mat3, Mat6, Stamp, Vec2, Vec3, iso2_from_iso3, se2_log, wrap_angle};
use crate::pipeline::Config;
use crate::pipeline::{Event, Pipeline, PipelineStats};
use crate::registration::covariance_se2_from_ros;
use crate::sim::inputs::{ScanEncoding, SimInputs};
use crate::sim::{
    EgoState, NoiseModel, RadarPreset, SimConfig, SimDrive, WorldFamily, config::LapConfig,
    simulate,
};
use serde::Serialize;
use std::collections::BTreeMap;

/// Translation error above which a closure is false, m (the paper's outlier threshold).
pub const FALSE_CLOSURE_THRESHOLD: f64 = 2.0;
/// Same-direction revisit radius, m (the paper's pairing radius).
pub const SAME_RADIUS: f64 = 5.0;
/// The simulator's Gamma noise shape, which the scenarios use unless told otherwise.
pub const DEFAULT_GAMMA_SHAPE: f64 = 1.0;

/// One simulated scenario.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RevisitScenario {
    /// Radar set.
    pub radars: RadarPreset,
    /// Measurement noise model.
    pub noise: NoiseModel,
    /// Odometry drift as a share of distance (0.01 = 1 %): the speed scale error; the yaw-rate bias is
    /// `drift * 10` deg/s (0.1 deg/s at 1 %, the simulator's default).
    pub drift: f64,
    /// Second lap driven in the opposite direction (after a U-turn).
    pub reverse: bool,
    /// Simulator seed.
    pub seed: u64,
    /// Kind of street ([`WorldFamily::City`] is the simulator's default world).
    pub world: WorldFamily,
    /// Extrinsic calibration error of the radars the pipeline is given (zero: the true extrinsics).
    pub calibration: CalibrationError,
    /// Radar clock offset, s: radar `i`'s stamps run this far ahead of the time it measured (`i` even)
    /// or behind it (`i` odd); 0: synchronised clocks.
    pub time_offset: f64,
    /// Robots of a fleet on this world, each driving one lap ([`crate::sim::fleet`]; `reverse` then
    /// unused); 0 or 1: one robot driving the two laps.
    pub fleet: u32,
    /// Multipath ghost probability of every radar (`SimRadarConfig::multipath_probability`); 0: none.
    pub multipath: f64,
    /// Wheel slip episodes per km (`OdometrySimConfig::slip_rate`); 0: none.
    pub wheel_slip: f64,
    /// Shape of the Gamma noise (`NoiseConfig::gamma_shape`; the simulator's default 1 is the most
    /// skewed it models); used with [`NoiseModel::Gamma`] only.
    pub gamma_shape: f64,
    /// Factors on the noise model's range, azimuth and radial-velocity scales (1: the model's own).
    pub noise_factors: [f64; 3],
}

/// An extrinsic calibration error: each radar's extrinsic as the pipeline is told it is off from the
/// simulated mount by `yaw_deg` of yaw (sign alternating from radar to radar) and `offset` metres in
/// the horizontal plane (in a direction turning by 72 degrees from radar to radar), so that five radars
/// carry five different errors. Deterministic, so runs compare.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct CalibrationError {
    /// Yaw error, degrees.
    pub yaw_deg: f64,
    /// Position error, m.
    pub offset: f64,
}

impl CalibrationError {
    /// True when the pipeline is given the true extrinsics.
    pub fn is_zero(&self) -> bool {
        self.yaw_deg == 0.0 && self.offset == 0.0
    }

    /// Applies the error to the radars of `cfg` (in name order).
    pub fn apply(&self, cfg: &mut Config) {
        for (i, radar) in cfg.radars.values_mut().enumerate() {
            let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
            let dir = (72.0 * i as f64).to_radians();
            let e = &mut radar.extrinsic;
            e[0] += self.offset * dir.cos();
            e[1] += self.offset * dir.sin();
            e[5] = wrap_angle(e[5] + sign * self.yaw_deg.to_radians());
        }
    }
}

impl RevisitScenario {
    /// A scenario on the default city with seed 1, the true extrinsics, synchronised clocks, no
    /// ghosts, no wheel slip, one robot and the simulator's Gamma shape.
    pub fn new(radars: RadarPreset, noise: NoiseModel, drift: f64, reverse: bool) -> Self {
        RevisitScenario {
            radars,
            noise,
            drift,
            reverse,
            seed: 1,
            world: WorldFamily::City,
            calibration: CalibrationError::default(),
            time_offset: 0.0,
            fleet: 0,
            multipath: 0.0,
            wheel_slip: 0.0,
            gamma_shape: DEFAULT_GAMMA_SHAPE,
            noise_factors: [1.0; 3],
        }
    }

    /// The simulator configuration: the default city, a 72 km/h lap then a 40 km/h lap.
    pub fn sim_config(&self) -> SimConfig {
        let mut c = SimConfig::with_preset(self.radars);
        c.seed = self.seed;
        c.world = self.world.world();
        c.noise.model = self.noise;
        c.noise.gamma_shape = self.gamma_shape;
        let [fr, fa, fv] = self.noise_factors;
        for scales in [
            &mut c.noise.gaussian,
            &mut c.noise.gamma,
            &mut c.noise.student_t,
        ] {
            scales.range *= fr;
            scales.azimuth *= fa;
            scales.velocity *= fv;
        }
        c.odometry.scale_error = self.drift;
        c.odometry.yaw_rate_bias = (self.drift * 10.0).to_radians();
        c.odometry.slip_rate = self.wheel_slip;
        if self.time_offset != 0.0 || self.multipath != 0.0 {
            c.radars = c.radar_list();
            c.radar_preset = RadarPreset::Custom;
            for (i, r) in c.radars.iter_mut().enumerate() {
                let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
                r.stamp_offset = sign * self.time_offset;
                r.multipath_probability = self.multipath;
            }
        }
        c.laps = vec![
            LapConfig {
                speed: 72.0 / 3.6,
                reverse: false,
            },
            LapConfig {
                speed: 40.0 / 3.6,
                reverse: self.reverse,
            },
        ];
        c
    }

    /// A short label, e.g. `nuscenes gaussian 3% reverse`, prefixed by the family and seed outside the
    /// default city with seed 1 (`suburb/101 nuscenes gaussian 3% reverse`).
    pub fn label(&self) -> String {
        let world = if self.world == WorldFamily::City && self.seed == 1 {
            String::new()
        } else {
            format!("{}/{} ", self.world.name(), self.seed)
        };
        let calibration = if self.calibration.is_zero() {
            String::new()
        } else {
            format!(
                " calibration {}deg/{}m",
                self.calibration.yaw_deg, self.calibration.offset
            )
        };
        let clock = if self.time_offset == 0.0 {
            String::new()
        } else {
            format!(" clock +-{}ms", (self.time_offset * 1e3).round())
        };
        let multipath = if self.multipath == 0.0 {
            String::new()
        } else {
            format!(" multipath {}", self.multipath)
        };
        let slip = if self.wheel_slip == 0.0 {
            String::new()
        } else {
            format!(" slip {}/km", self.wheel_slip)
        };
        let shape = if self.noise == NoiseModel::Gamma && self.gamma_shape != DEFAULT_GAMMA_SHAPE {
            format!(" shape {}", self.gamma_shape)
        } else {
            String::new()
        };
        let factors = if self.noise_factors == [1.0; 3] {
            String::new()
        } else {
            let [r, a, v] = self.noise_factors;
            format!(" x{r},{a},{v}")
        };
        let passes = match (self.fleet, self.reverse) {
            (0 | 1, false) => "same".to_string(),
            (0 | 1, true) => "reverse".to_string(),
            (n, _) => format!("fleet of {n}"),
        };
        format!(
            "{world}{} {}{shape}{factors} {}% {passes}{calibration}{clock}{multipath}{slip}",
            self.radars.name(),
            self.noise.name(),
            fmt_pct(self.drift),
        )
    }
}

fn fmt_pct(v: f64) -> String {
    let p = v * 100.0;
    if (p - p.round()).abs() < 1e-9 {
        format!("{p:.0}")
    } else {
        format!("{p:.1}")
    }
}

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
}

/// Simulates `scenario` and evaluates it with the pipeline configured by `tweak` applied to the
/// drive's own configuration.
pub fn evaluate_scenario(
    scenario: &RevisitScenario,
    tweak: impl FnOnce(&mut Config),
) -> Result<RevisitReport, crate::validate::ConfigError> {
    if scenario.fleet >= 2 {
        let robots = crate::sim::fleet::fleet(&scenario.sim_config(), scenario.fleet)?;
        let mut r = super::fleet::evaluate_fleet(&robots, |cfg| {
            scenario.calibration.apply(cfg);
            tweak(cfg);
        })?;
        r.scenario = scenario.label();
        return Ok(r);
    }
    let drive = simulate(&scenario.sim_config())?;
    let mut cfg = drive.to_config();
    scenario.calibration.apply(&mut cfg);
    tweak(&mut cfg);
    let mut r = evaluate_revisits(&drive, cfg)?;
    r.scenario = scenario.label();
    Ok(r)
}

/// Drives the pipeline (revisit search on) over `drive` and judges its closures.
pub fn evaluate_revisits(
    drive: &SimDrive,
    mut cfg: Config,
) -> Result<RevisitReport, crate::validate::ConfigError> {
    cfg.r#loop.enabled = true;
    let mut p = Pipeline::new(cfg)?;
    let mut seen = Collected::default();
    feed(drive, &mut p, |events| seen.take(events));
    seen.take(p.finish());
    let truth = keyframe_truth(drive, &seen.keyframes, |s| s.lap.lap);
    Ok(judge(
        truth,
        reverse_radius(drive),
        measured_drift(drive),
        &seen,
        p.stats(),
    ))
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
                _ => {}
            }
        }
    }
}

/// Pushes a simulated drive's inputs through `p` in time order (its scans as decoded detections),
/// handing each input's events to `sink`.
pub fn feed(drive: &SimDrive, p: &mut Pipeline, mut sink: impl FnMut(Vec<Event>)) {
    for input in SimInputs::new(drive, ScanEncoding::Detections).flatten() {
        sink(p.push(&input));
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

/// The README table: one row per scenario.
pub fn format_revisit_table(reports: &[RevisitReport]) -> String {
    let mut s = String::new();
    s.push_str("| scenario | drift (measured) | keyframes | same: published / false / precision / recall | reverse: published / false / precision / recall | max error (m, rad) / outside the bound (m) | NEES mean / above 99 % |\n");
    s.push_str("|---|---|---|---|---|---|---|\n");
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
        s.push_str(&format!(
            "| {} | {:.2} % | {} | {} | {} | {:.2}, {:.4} / {:.2} | {:.1} / {:.1} % |\n",
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
    use crate::math::{iso3_from_iso2, se2_exp};
    use crate::registration::covariance_ros_from_se2;
    use crate::sim::noise::NoiseConfig;

    /// `--gamma-shape` and `--noise-factors` reach the simulated noise (skewness 2 / sqrt(shape), the
    /// scales times the factors) and the scenario's label; the defaults leave the label as it was.
    #[test]
    fn a_gamma_shape_and_noise_factors_reach_the_simulated_noise_and_the_label() {
        use rand::SeedableRng;
        let mut scenario = RevisitScenario::new(RadarPreset::Carla, NoiseModel::Gamma, 0.01, false);
        assert_eq!(scenario.label(), "carla gamma 1% same");
        scenario.gamma_shape = 100.0;
        assert_eq!(scenario.label(), "carla gamma shape 100 1% same");
        scenario.noise_factors = [1.0, 0.5, 2.0];
        assert_eq!(scenario.label(), "carla gamma shape 100 x1,0.5,2 1% same");
        let scaled = scenario.sim_config().noise.std_devs();
        let own = NoiseConfig::default().gamma;
        assert_eq!(scaled.range, own.range);
        assert_eq!(scaled.azimuth, 0.5 * own.azimuth);
        assert_eq!(scaled.velocity, 2.0 * own.velocity);
        scenario.noise_factors = [1.0; 3];
        let noise = scenario.sim_config().noise;
        let sampler = crate::sim::noise::NoiseSampler::new(&noise).expect("valid");
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let n = 100_000;
        let range: Vec<f64> = (0..n).map(|_| sampler.sample(&mut rng)[0]).collect();
        let m = range.iter().sum::<f64>() / n as f64;
        let sd = (range.iter().map(|r| (r - m).powi(2)).sum::<f64>() / n as f64).sqrt();
        let skew = range.iter().map(|r| ((r - m) / sd).powi(3)).sum::<f64>() / n as f64;
        assert!((skew - 0.2).abs() < 0.05, "skewness {skew}");
        assert!(
            (sd / noise.std_devs().range - 1.0).abs() < 0.02,
            "scale {sd}"
        );
    }

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
