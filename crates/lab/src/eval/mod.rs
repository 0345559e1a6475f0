//! The paper's evaluation protocol (its section IV) on any drive with ground truth.
//!
//! Steps, in order: drive the same [`Pipeline`] as the node over the input (revisit search off) and keep
//! its keyframes ([`Collector`]); pair keyframes of different passes over one place by ground truth
//! ([`make_pairs`]); register every pair with every method and ablation row ([`Method`], [`evaluate`]);
//! summarise over the inliers and by ego-velocity difference ([`report`]). docs/algorithm.md, "The
//! evaluation", has the pairing rule, the inlier threshold and what each method row runs.

pub mod drives;
pub mod export;
pub mod fleet;
pub mod judge;
pub mod odometry;
pub mod report;
pub mod revisits;

use crate::baselines::{BaselinesConfig, ForwardSpeedEstimator, register_icp, register_ndt};
use dc_loc_core::cloud::decode_detections;
use dc_loc_core::input::Input;
use dc_loc_core::math::se2_log;
use dc_loc_core::math::{Iso2, Iso3, Mat3, Stamp, Vec2, Vec3, iso2_from_iso3, wrap_angle};
use dc_loc_core::pipeline::Config;
use dc_loc_core::pipeline::{Event, Pipeline};
use dc_loc_core::radar::Detection;
use dc_loc_core::radar::doppler::RadarModel;
use dc_loc_core::registration::{
    PointSet2, PreparedSubmap, RegistrationConfig, RegistrationResult, register_detailed,
};
use dc_loc_core::submap::{OdometryBuffer, OdometryConfig, Submap};
use dc_loc_core::validate::{ConfigError, Validator};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Evaluation settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvalConfig {
    /// Pairs: ground-truth distance of the two keyframes at most this, m (default 5.0, the paper's).
    pub pair_radius: f64,
    /// Pairs: ground-truth path driven between the two keyframes at least this, m (default 200): another
    /// pass over the place, not the same pass.
    pub min_pass_gap: f64,
    /// Pairs: heading difference at most this, rad (default pi/2: same direction of travel, as the paper's
    /// pairs; raise to pi to include reverse passes).
    pub max_heading_difference: f64,
    /// Translation error above this counts as an outlier, m (default 2.0, the paper's).
    pub outlier_threshold: f64,
    /// Width of the ego-velocity-difference bins, m/s (default 2.0).
    pub velocity_bin_width: f64,
    /// Evaluate every n-th pair only (default 1: all).
    pub pair_stride: usize,
    /// A result whose runner-up alignment fits with more than this share of its overlap is
    /// ambiguous (default 0.8, the node's `loop.maximum_ambiguity`); the mean NEES is also given
    /// over the inliers that are not, the ones the node could publish.
    pub ambiguity_ratio: f64,
    /// Baseline settings.
    pub baselines: BaselinesConfig,
}

impl Default for EvalConfig {
    fn default() -> Self {
        EvalConfig {
            pair_radius: 5.0,
            min_pass_gap: 200.0,
            max_heading_difference: std::f64::consts::FRAC_PI_2,
            outlier_threshold: 2.0,
            velocity_bin_width: 2.0,
            pair_stride: 1,
            ambiguity_ratio: 0.8,
            baselines: BaselinesConfig::default(),
        }
    }
}

impl EvalConfig {
    /// Rejects unusable values, naming them `eval.*` (and `baselines.*`).
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut v = Validator::at("eval");
        v.positive("pair_radius", self.pair_radius);
        v.positive("outlier_threshold", self.outlier_threshold);
        v.positive("velocity_bin_width", self.velocity_bin_width);
        v.positive("max_heading_difference", self.max_heading_difference);
        v.positive("ambiguity_ratio", self.ambiguity_ratio);
        v.non_negative("min_pass_gap", self.min_pass_gap);
        v.at_least("pair_stride", self.pair_stride, 1);
        v.finish()?;
        self.baselines.validate()
    }
}

/// A method (or ablation row) of the evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum Method {
    /// Point-to-point ICP from the identity, uncorrected points.
    Icp,
    /// 2D NDT from the identity, uncorrected points.
    Ndt,
    /// MC-RANSAC-style Doppler correction with self-estimated speed, no uncertainty.
    McRansac,
    /// DC-Loc association and eq. 10 with per-point uncertainty (`ue`) and Doppler compensation (`dc`)
    /// switchable; `dense` adds the dense refinement.
    DcLoc {
        /// Uncertainty estimation (U.E.).
        ue: bool,
        /// Doppler compensation (D.C.).
        dc: bool,
        /// Dense refinement (beyond the paper).
        dense: bool,
    },
}

impl Method {
    /// Full DC-Loc as dc_loc runs it.
    pub const DCLOC: Method = Method::DcLoc {
        ue: true,
        dc: true,
        dense: true,
    };

    /// Every method and row, in table order.
    pub fn all() -> Vec<Method> {
        let mut v = vec![Method::Icp, Method::Ndt, Method::McRansac];
        for (ue, dc) in [(false, false), (true, false), (false, true), (true, true)] {
            v.push(Method::DcLoc {
                ue,
                dc,
                dense: true,
            });
        }
        v.push(Method::DcLoc {
            ue: true,
            dc: true,
            dense: false,
        });
        v
    }

    /// Name for tables.
    pub fn name(&self) -> String {
        match *self {
            Method::Icp => "ICP".into(),
            Method::Ndt => "NDT".into(),
            Method::McRansac => "MC-RANSAC-style".into(),
            Method::DcLoc {
                ue: true,
                dc: true,
                dense: true,
            } => "DC-Loc".into(),
            Method::DcLoc {
                ue: true,
                dc: true,
                dense: false,
            } => "DC-Loc (paper: no dense stage)".into(),
            Method::DcLoc { ue, dc, dense } => format!(
                "DC-Loc U.E. {} D.C. {}{}",
                if ue { "on" } else { "off" },
                if dc { "on" } else { "off" },
                if dense { "" } else { " (no dense)" }
            ),
        }
    }
}

/// A keyframe with what the evaluation needs.
#[derive(Debug, Clone)]
pub struct EvalKeyframe {
    /// Keyframe id in the pipeline.
    pub id: u64,
    /// Anchor stamp.
    pub stamp: Stamp,
    /// Ground-truth body pose at the anchor (map frame).
    pub t_map_body: Iso2,
    /// Ground-truth speed at the anchor, m/s.
    pub speed: f64,
    /// Ground-truth path length driven up to the anchor, m.
    pub path: f64,
    /// The submap.
    pub submap: std::sync::Arc<Submap>,
    /// Forward speed the MC-RANSAC-style estimator found for each of the submap's scans (`None` when it
    /// had none: the first scans of a drive).
    pub estimated_speeds: Vec<Option<f64>>,
}

/// Drives the pipeline over a drive's inputs and keeps keyframes with ground truth.
pub struct Collector {
    pipeline: Pipeline,
    radars: Vec<RadarModel>,
    fields: Vec<dc_loc_core::radar::FieldsConfig>,
    gt: OdometryBuffer,
    gt_speed: Vec<(Stamp, f64)>,
    gt_path: Vec<(Stamp, f64)>,
    estimators: Vec<ForwardSpeedEstimator>,
    speeds: BTreeMap<(usize, Stamp), f64>,
    keyframes: Vec<(u64, std::sync::Arc<Submap>)>,
    /// Ground-truth samples refused (not finite, time going backwards).
    pub bad_ground_truth: u64,
}

impl Collector {
    /// A collector for `cfg` (revisit search is switched off: only keyframes are needed).
    pub fn new(cfg: &Config, eval: &EvalConfig) -> Result<Self, ConfigError> {
        eval.validate()?;
        let mut cfg = cfg.clone();
        cfg.r#loop.enabled = false;
        let radars: Vec<RadarModel> = cfg
            .radar_list()
            .into_iter()
            .map(|(_, r)| RadarModel::from(r))
            .collect();
        let fields = cfg
            .radar_list()
            .into_iter()
            .map(|(_, r)| r.fields.clone())
            .collect();
        let estimators = (0..radars.len())
            .map(|_| ForwardSpeedEstimator::new(eval.baselines.mc_ransac.clone()))
            .collect::<Result<Vec<_>, _>>()?;
        let gt_cfg = OdometryConfig {
            buffer_duration: 1e9,
            max_gap: 1.0,
            ..OdometryConfig::default()
        };
        Ok(Collector {
            pipeline: Pipeline::new(cfg)?,
            radars,
            fields,
            gt: OdometryBuffer::new(gt_cfg),
            gt_speed: Vec::new(),
            gt_path: Vec::new(),
            estimators,
            speeds: BTreeMap::new(),
            keyframes: Vec::new(),
            bad_ground_truth: 0,
        })
    }

    /// Feeds one input of a stream: to the pipeline (ground truth to the evaluation only), and a radar
    /// scan's uncorrected points to the MC-RANSAC-style speed estimator of that radar.
    pub fn push(&mut self, input: &Input) -> Vec<Event> {
        match input {
            Input::Radar { radar, cloud } => {
                let fields = self.fields.get(*radar);
                if let Some(decoded) = fields.and_then(|f| decode_detections(cloud, f).ok()) {
                    self.estimate_speed(*radar, cloud.header.stamp.into(), &decoded.detections);
                }
            }
            Input::Scan(scan) => self.estimate_speed(scan.radar, scan.stamp, &scan.detections),
            Input::GroundTruth {
                stamp,
                t_map_body,
                speed,
            } => self.push_ground_truth(*stamp, *t_map_body, *speed),
            Input::Odometry { .. } | Input::Imu { .. } | Input::Keyframe(_) => {}
        }
        let events = self.pipeline.push(input);
        for e in &events {
            if let Event::Keyframe { id, submap, .. } = e {
                self.keyframes.push((*id, submap.clone()));
            }
        }
        events
    }

    /// The MC-RANSAC-style forward speed of radar `radar` at `stamp`, from its uncorrected points.
    fn estimate_speed(&mut self, radar: usize, stamp: Stamp, detections: &[Detection]) {
        let (Some(model), Some(est)) = (self.radars.get(radar), self.estimators.get_mut(radar))
        else {
            return;
        };
        let pts: Vec<Vec2> = detections
            .iter()
            .map(|d| {
                (model.t_body_radar * nalgebra::Point3::from(d.p_radar))
                    .coords
                    .xy()
            })
            .collect();
        if let Ok(Some(e)) = est.push(stamp, pts) {
            self.speeds.insert((radar, stamp), e.forward_speed);
        }
    }

    /// Feeds a ground-truth pose (map frame) and speed.
    fn push_ground_truth(&mut self, stamp: Stamp, t_map_body: Iso3, speed: f64) {
        let prev = self.gt.newest();
        if self.gt.push(stamp, t_map_body, None).is_err() || !speed.is_finite() {
            self.bad_ground_truth += 1;
            return;
        }
        let path = match (prev, self.gt_path.last()) {
            (Some((_, p)), Some(&(_, d))) => {
                d + (t_map_body.translation.vector - p.translation.vector)
                    .xy()
                    .norm()
            }
            _ => 0.0,
        };
        self.gt_path.push((stamp, path));
        self.gt_speed.push((stamp, speed));
    }

    /// Ends the input; returns the keyframes that have ground truth, with their per-scan speed estimates.
    pub fn finish(mut self) -> (Vec<EvalKeyframe>, dc_loc_core::pipeline::PipelineStats) {
        self.pipeline.finish();
        let mut out = Vec::new();
        for (id, submap) in &self.keyframes {
            let stamp = submap.anchor_stamp;
            let Ok(t) = self.gt.pose_at(stamp) else {
                continue;
            };
            let estimated_speeds = submap
                .scans
                .iter()
                .map(|s| self.speeds.get(&(s.radar, s.stamp)).copied())
                .collect();
            out.push(EvalKeyframe {
                id: *id,
                stamp,
                t_map_body: iso2_from_iso3(&t),
                speed: interpolate(&self.gt_speed, stamp),
                path: interpolate(&self.gt_path, stamp),
                submap: submap.clone(),
                estimated_speeds,
            });
        }
        (out, self.pipeline.stats().clone())
    }
}

fn interpolate(series: &[(Stamp, f64)], at: Stamp) -> f64 {
    let i = series.partition_point(|s| s.0 <= at);
    match (i.checked_sub(1).and_then(|k| series.get(k)), series.get(i)) {
        (Some(a), Some(b)) if b.0 > a.0 => {
            a.1 + (b.1 - a.1) * at.secs_since(a.0) / b.0.secs_since(a.0)
        }
        (Some(a), _) => a.1,
        (None, Some(b)) => b.1,
        (None, None) => f64::NAN,
    }
}

/// A pair: `query` (later pass) registered against `target` (earlier pass), indices into the keyframes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pair {
    /// Later keyframe (source).
    pub query: usize,
    /// Earlier keyframe (target).
    pub target: usize,
    /// Ground-truth distance, m.
    pub distance: f64,
}

/// Pairs every keyframe with the nearest earlier keyframe of another pass (see [`EvalConfig`]).
pub fn make_pairs(kfs: &[EvalKeyframe], cfg: &EvalConfig) -> Vec<Pair> {
    let mut pairs = Vec::new();
    for (q, kq) in kfs.iter().enumerate() {
        let best = kfs[..q]
            .iter()
            .enumerate()
            .filter(|(_, k)| kq.path - k.path >= cfg.min_pass_gap)
            .filter(|(_, k)| {
                wrap_angle(kq.t_map_body.rotation.angle() - k.t_map_body.rotation.angle()).abs()
                    <= cfg.max_heading_difference
            })
            .map(|(i, k)| {
                (
                    i,
                    (kq.t_map_body.translation.vector - k.t_map_body.translation.vector).norm(),
                )
            })
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((t, d)) = best
            && d <= cfg.pair_radius
        {
            pairs.push(Pair {
                query: q,
                target: t,
                distance: d,
            });
        }
    }
    pairs.into_iter().step_by(cfg.pair_stride).collect()
}

/// The outcome of one method on one pair.
#[derive(Debug, Clone, PartialEq)]
pub struct PairResult {
    /// The pair.
    pub pair: Pair,
    /// The method.
    pub method: Method,
    /// |speed_query - speed_target| from ground truth, m/s.
    pub velocity_difference: f64,
    /// The method's `T_target_query`, when it gave one.
    pub estimate: Option<Iso2>,
    /// Translation error, m (infinite when the method gave no result).
    pub translation_error: f64,
    /// Rotation error, rad (infinite when the method gave no result).
    pub rotation_error: f64,
    /// NEES of the error under the reported covariance (x, y, yaw), when there was a result.
    pub nees: Option<f64>,
    /// Why there was no result.
    pub failure: Option<String>,
    /// The method's overlap at its result (see `RegistrationResult::overlap`), 0 without a result.
    pub overlap: f64,
    /// Descriptor-stage (RANSAC) inliers, 0 without a result.
    pub inliers: usize,
    /// Overlap of the best other alignment (see `RegistrationResult::runner_up_overlap`), 0 without
    /// a result.
    pub runner_up_overlap: f64,
}

/// Points of a submap in the form a method registers: compensated, raw, or raw with the
/// MC-RANSAC-style correction (yeti `dopplerCorrection` with the self-estimated forward speed of each
/// point's scan; a scan without an estimate takes the nearest estimate of the submap, else none).
fn mc_ransac_points(kf: &EvalKeyframe) -> PointSet2 {
    let mut set = kf.submap.point_set(false);
    let fallback: Vec<Option<f64>> = (0..kf.estimated_speeds.len())
        .map(|k| {
            kf.estimated_speeds[k].or_else(|| {
                (1..kf.estimated_speeds.len()).find_map(|d| {
                    kf.estimated_speeds
                        .get(k + d)
                        .copied()
                        .flatten()
                        .or_else(|| {
                            k.checked_sub(d)
                                .and_then(|j| kf.estimated_speeds.get(j).copied().flatten())
                        })
                })
            })
        })
        .collect();
    for (p, q) in set.points.iter_mut().zip(&kf.submap.points) {
        let scan = q.scan as usize;
        let (Some(s), Some(Some(v))) = (kf.submap.scans.get(scan), fallback.get(scan)) else {
            continue;
        };
        // yeti: p += beta * v * cos(theta) * [cos theta, sin theta] in the radar frame, theta the angle
        // between the ray and the direction of travel; in the anchor frame with the scan's heading.
        let forward: Vec3 = s.t_anchor_body.rotation * Vec3::x();
        let d = q.ray;
        *p += (d * (s.beta * v * d.dot(&forward))).xy();
    }
    set
}

fn ground_truth(kfs: &[EvalKeyframe], pair: &Pair) -> Iso2 {
    kfs[pair.target].t_map_body.inverse() * kfs[pair.query].t_map_body
}

fn score(
    pair: &Pair,
    method: Method,
    kfs: &[EvalKeyframe],
    res: Result<(RegistrationResult, Option<Mat3>), String>,
) -> PairResult {
    let truth = ground_truth(kfs, pair);
    let velocity_difference = (kfs[pair.query].speed - kfs[pair.target].speed).abs();
    match res {
        Ok((r, cov)) => {
            let est = r.t_target_source;
            let err = est.inverse() * truth;
            let e = se2_log(&err);
            let nees = cov.and_then(|c| c.try_inverse()).map(|ci| e.dot(&(ci * e)));
            PairResult {
                pair: *pair,
                method,
                velocity_difference,
                estimate: Some(est),
                translation_error: (truth.translation.vector - est.translation.vector).norm(),
                rotation_error: wrap_angle(truth.rotation.angle() - est.rotation.angle()).abs(),
                nees,
                failure: None,
                overlap: r.overlap,
                inliers: r.inliers,
                runner_up_overlap: r.runner_up_overlap,
            }
        }
        Err(f) => PairResult {
            pair: *pair,
            method,
            velocity_difference,
            estimate: None,
            translation_error: f64::INFINITY,
            rotation_error: f64::INFINITY,
            nees: None,
            failure: Some(f),
            overlap: 0.0,
            inliers: 0,
            runner_up_overlap: 0.0,
        },
    }
}

/// Runs every method on every pair (in parallel over pairs; deterministic).
pub fn evaluate(
    kfs: &[EvalKeyframe],
    pairs: &[Pair],
    methods: &[Method],
    registration: &RegistrationConfig,
    eval: &EvalConfig,
) -> Vec<PairResult> {
    let per_pair: Vec<Vec<PairResult>> = pairs
        .par_iter()
        .map(|pair| {
            let (q, t) = (&kfs[pair.query], &kfs[pair.target]);
            let raw = (q.submap.point_set(false), t.submap.point_set(false));
            let comp = (q.submap.point_set(true), t.submap.point_set(true));
            let mut out = Vec::with_capacity(methods.len());
            for &m in methods {
                let res: Result<(RegistrationResult, Option<Mat3>), String> = match m {
                    Method::Icp => {
                        register_icp(&raw.0, &raw.1, &Iso2::identity(), &eval.baselines.icp)
                            .map(|r| (r, None))
                            .map_err(|e| e.to_string())
                    }
                    Method::Ndt => {
                        register_ndt(&raw.0, &raw.1, &Iso2::identity(), &eval.baselines.ndt)
                            .map(|r| (r, None))
                            .map_err(|e| e.to_string())
                    }
                    Method::McRansac => {
                        let mut cfg = registration.clone();
                        cfg.lm.use_uncertainty = false;
                        dcloc(&mc_ransac_points(q), &mc_ransac_points(t), &cfg)
                    }
                    Method::DcLoc { ue, dc, dense } => {
                        let mut cfg = registration.clone();
                        cfg.lm.use_uncertainty = ue;
                        cfg.dense.enabled = dense;
                        let (s, g) = if dc { &comp } else { &raw };
                        dcloc(s, g, &cfg)
                    }
                };
                out.push(score(pair, m, kfs, res));
            }
            out
        })
        .collect();
    per_pair.into_iter().flatten().collect()
}

fn dcloc(
    source: &PointSet2,
    target: &PointSet2,
    cfg: &RegistrationConfig,
) -> Result<(RegistrationResult, Option<Mat3>), String> {
    timed_stages(source, target, cfg).0
}

/// DC-Loc on one pair as [`dcloc`], with the wall time of its two stages on the calling thread:
/// preparing both submaps (descriptors, neighbour grids; the node does this once a keyframe) and
/// registering the prepared pair, s.
fn timed_stages(
    source: &PointSet2,
    target: &PointSet2,
    cfg: &RegistrationConfig,
) -> (
    Result<(RegistrationResult, Option<Mat3>), String>,
    StageSeconds,
) {
    let t0 = std::time::Instant::now();
    let prepared = PreparedSubmap::new(source.clone(), cfg)
        .and_then(|s| Ok((s, PreparedSubmap::new(target.clone(), cfg)?)));
    let prepare = t0.elapsed().as_secs_f64();
    let t1 = std::time::Instant::now();
    let res = prepared
        .and_then(|(s, t)| register_detailed(&s, &t, cfg))
        .map(|d| (d.result, Some(d.covariance_se2)))
        .map_err(|e| e.to_string());
    let register = t1.elapsed().as_secs_f64();
    (res, StageSeconds { prepare, register })
}

/// Wall time of DC-Loc's two stages on one pair, s.
#[derive(Debug, Clone, Copy)]
pub struct StageSeconds {
    /// Preparing both submaps.
    pub prepare: f64,
    /// Registering the prepared pair.
    pub register: f64,
}
