//! Odometry interpolation and submaps: the last N sweeps stacked in the body frame of the newest scan.
//!
//! Entry points: [`OdometryBuffer`] (stamped odometry poses, interpolated at scan stamps),
//! [`SubmapBuilder`] (per radar, the last `size` scans after Doppler compensation, covariance and
//! moving-object rejection), [`Submap`] and [`Submap::point_set`] (what registration consumes).
//!
//! A *sweep* with several radars: each radar keeps its own last `size` scans, so a submap holds the last
//! `size` scans of every radar whatever their phase or rate (the DC-Loc authors likewise stack 10 sweeps per
//! radar). Each scan is placed with the odometry pose interpolated at its own stamp, and the submap is
//! expressed in the body frame at the newest scan's stamp (its *anchor*).

use crate::math::{Iso3, Mat3, Stamp, Vec2, Vec3, interpolate_iso3};
use crate::odometry::OdometrySource;
use crate::pose_noise::{PoseNoise, shear};
use crate::radar::RadarScan;
use crate::radar::consistency::{self, Verdict};
use crate::radar::doppler::{BodyPoint, RadarModel};
use crate::radar::ego_motion::{EgoMotionConfig, FitDims, fit_radar_velocity, static_mask};
use crate::registration::PointSet2;
use crate::validate::{Range, Validator};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// Why odometry could not give a pose.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OdometryError {
    /// A sample older than the newest one arrived (a bag restarted, clocks jumped).
    #[error("odometry stamp went backwards: {got:?} after {newest:?}")]
    TimeWentBackwards {
        /// Newest stamp held.
        newest: Stamp,
        /// Stamp received.
        got: Stamp,
    },
    /// The pose is not finite.
    #[error("odometry pose is not finite")]
    NotFinite,
    /// No odometry yet, or the request lies beyond the newest sample (wait for more).
    #[error("no odometry at {at:?} yet (newest {newest:?})")]
    NotYet {
        /// Requested stamp.
        at: Stamp,
        /// Newest stamp held, if any.
        newest: Option<Stamp>,
    },
    /// The request lies before the oldest sample held.
    #[error("odometry at {at:?} is older than the buffer (oldest {oldest:?})")]
    TooOld {
        /// Requested stamp.
        at: Stamp,
        /// Oldest stamp held.
        oldest: Stamp,
    },
    /// The two samples around the request are too far apart to interpolate between.
    #[error("odometry gap of {gap:.3} s around {at:?}")]
    Gap {
        /// Requested stamp.
        at: Stamp,
        /// Gap between the bracketing samples, s.
        gap: f64,
    },
}

/// Odometry settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryConfig {
    /// Where the odometry comes from: `topic` (default: `nav_msgs/Odometry` on `topic`), `radar` (the
    /// radars' Doppler, two or more radars mounted apart) or `radar_imu` (the radars' Doppler and the
    /// gyro on `imu.topic`).
    pub source: OdometrySource,
    /// nav_msgs/Odometry topic (default `/odom`).
    pub topic: String,
    /// With `radar` or `radar_imu`: standard deviation of the body's sideways velocity at the body
    /// origin, m/s (default 0: not assumed). A car with its body frame on the rear axle does not
    /// slide sideways (about 0.1 m/s); then one radar mounted ahead of the axle sees the yaw rate.
    pub lateral_velocity_sigma: f64,
    /// How much odometry history to keep, s (default 30).
    pub buffer_duration: f64,
    /// Largest gap between two odometry samples that is still interpolated across, s (default 0.5).
    pub max_gap: f64,
    /// How far past the newest sample a pose may be extrapolated, s (default 0.05).
    pub max_extrapolation: f64,
    /// Fastest motion between two odometry samples that is plausible, m/s (default 100, 360 km/h):
    /// a sample farther from the last one is dropped as an outlier (`bad_odometry`), unless a run of
    /// samples agrees on the new place (the odometry itself was reset).
    pub max_speed: f64,
    /// Fastest turn between two odometry samples that is plausible, rad/s (default 5).
    pub max_yaw_rate: f64,
}

impl Default for OdometryConfig {
    fn default() -> Self {
        OdometryConfig {
            source: OdometrySource::Topic,
            topic: "/odom".into(),
            lateral_velocity_sigma: 0.0,
            buffer_duration: 30.0,
            max_gap: 0.5,
            max_extrapolation: 0.05,
            max_speed: 100.0,
            max_yaw_rate: 5.0,
        }
    }
}

impl OdometryConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.require("topic", !self.topic.is_empty(), || {
            "must not be empty".into()
        });
        v.non_negative("lateral_velocity_sigma", self.lateral_velocity_sigma);
        v.positive("buffer_duration", self.buffer_duration);
        v.positive("max_gap", self.max_gap);
        v.non_negative("max_extrapolation", self.max_extrapolation);
        v.positive("max_speed", self.max_speed);
        v.positive("max_yaw_rate", self.max_yaw_rate);
    }
}

/// Stamped odometry poses `t_odom_body`, interpolated at arbitrary stamps, with their uncertainty
/// when the odometry gives it in the form [`PoseNoise`] (the radar odometry does).
#[derive(Debug, Clone)]
pub struct OdometryBuffer {
    cfg: OdometryConfig,
    samples: VecDeque<(Stamp, Iso3)>,
    /// Per sample, in step with `samples`.
    noise: VecDeque<Option<PoseNoise>>,
}

impl OdometryBuffer {
    /// An empty buffer.
    pub fn new(cfg: OdometryConfig) -> Self {
        OdometryBuffer {
            cfg,
            samples: VecDeque::new(),
            noise: VecDeque::new(),
        }
    }

    /// Appends a sample. Stamps must not go backwards (the caller decides whether to [`Self::clear`]);
    /// a repeated stamp replaces the previous sample.
    pub fn push(
        &mut self,
        stamp: Stamp,
        t_odom_body: Iso3,
        noise: Option<PoseNoise>,
    ) -> Result<(), OdometryError> {
        let finite = t_odom_body.translation.vector.iter().all(|v| v.is_finite())
            && t_odom_body.rotation.coords.iter().all(|v| v.is_finite());
        if !finite {
            return Err(OdometryError::NotFinite);
        }
        if let Some(&(newest, _)) = self.samples.back() {
            if stamp < newest {
                return Err(OdometryError::TimeWentBackwards { newest, got: stamp });
            }
            if stamp == newest {
                self.samples.pop_back();
                self.noise.pop_back();
            }
        }
        self.samples.push_back((stamp, t_odom_body));
        self.noise.push_back(noise);
        while let (Some(&(old, _)), true) = (self.samples.front(), self.samples.len() > 2) {
            if stamp.secs_since(old) > self.cfg.buffer_duration {
                self.samples.pop_front();
                self.noise.pop_front();
            } else {
                break;
            }
        }
        Ok(())
    }

    /// Forgets every sample (after time went backwards).
    pub fn clear(&mut self) {
        self.samples.clear();
        self.noise.clear();
    }

    /// The newest sample.
    pub fn newest(&self) -> Option<(Stamp, Iso3)> {
        self.samples.back().copied()
    }

    /// Number of samples held.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// True when no sample is held.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The body pose at `at`, interpolated between the bracketing samples (linear translation, geodesic
    /// rotation), or extrapolated up to `max_extrapolation` past the newest one.
    pub fn pose_at(&self, at: Stamp) -> Result<Iso3, OdometryError> {
        let (i, j, t) = self.bracket(at)?;
        let (a, b) = (self.samples[i].1, self.samples[j].1);
        Ok(if i == j {
            b
        } else {
            interpolate_iso3(&a, &b, t)
        })
    }

    /// Covariance of `(x, y, yaw)` (odometry frame) of the pose at `to` given the pose at each of
    /// `stamps` (each at or before `to`): the errors the odometry's steps between them add, each step's
    /// own ([`PoseNoise::since`] of its two samples) turned to `to` by the heading error it carries, a
    /// step cut by a stamp taking its share in time. `None` when the odometry gives no uncertainty or
    /// cannot place `to`. The steps' bias parts add as if independent: over a submap's second they are
    /// small beside the white errors.
    pub fn motion_to(&self, stamps: &[Stamp], to: Stamp) -> Option<Vec<Mat3>> {
        let end = self.pose_at(to).ok()?.translation.vector.xy();
        let position = |j: usize| self.samples[j].1.translation.vector.xy();
        let mut steps = Vec::with_capacity(self.samples.len());
        for j in 1..self.samples.len() {
            let own = self.noise[j]?.since(&self.noise[j - 1]?, position(j) - position(j - 1));
            let turn = shear(end - position(j));
            steps.push(turn * own * turn.transpose());
        }
        let share = |j: usize, from: Stamp| {
            let (t0, t1) = (self.samples[j - 1].0, self.samples[j].0);
            // The newest step also stands for the motion extrapolated past it.
            let t1_cut = if j + 1 == self.samples.len() {
                to
            } else {
                t1.min(to)
            };
            let overlap = t1_cut.secs_since(t0.max(from));
            (overlap / t1.secs_since(t0).max(1e-9)).max(0.0)
        };
        Some(
            stamps
                .iter()
                .map(|&from| {
                    (1..self.samples.len())
                        .map(|j| steps[j - 1] * share(j, from))
                        .sum()
                })
                .collect(),
        )
    }

    /// The samples `(i, j)` a stamp lies between and the fraction of the way from `i` to `j` (past 1
    /// when extrapolating; `i == j` with one sample or a stamp on the newest).
    fn bracket(&self, at: Stamp) -> Result<(usize, usize, f64), OdometryError> {
        let newest = self.samples.back().map(|s| s.0);
        let (Some(&(t0, _)), Some(&(tn, _))) = (self.samples.front(), self.samples.back()) else {
            return Err(OdometryError::NotYet { at, newest });
        };
        if at < t0 {
            return Err(OdometryError::TooOld { at, oldest: t0 });
        }
        let last = self.samples.len() - 1;
        if at >= tn {
            if at.secs_since(tn) > self.cfg.max_extrapolation {
                return Err(OdometryError::NotYet { at, newest });
            }
            if at == tn || last == 0 {
                return Ok((last, last, 1.0));
            }
            return self.between(last - 1, last, at);
        }
        // First sample strictly after `at`.
        let j = self.samples.partition_point(|s| s.0 <= at);
        self.between(j - 1, j, at)
    }

    fn between(&self, i: usize, j: usize, at: Stamp) -> Result<(usize, usize, f64), OdometryError> {
        let (a, b) = (self.samples[i].0, self.samples[j].0);
        let gap = b.secs_since(a);
        if gap > self.cfg.max_gap {
            return Err(OdometryError::Gap { at, gap });
        }
        if gap <= 0.0 {
            return Ok((j, j, 1.0));
        }
        Ok((i, j, at.secs_since(a) / gap))
    }

    /// Body velocity (body frame, m/s) and yaw rate (rad/s) at `at`, by differences of the interpolated
    /// poses over `at +- half_window` (the window is cut at the newest sample).
    pub fn velocity_at(&self, at: Stamp, half_window: f64) -> Option<(Vec3, f64)> {
        let h = Stamp::from_secs_f64(half_window).0;
        let t0 = Stamp(at.0 - h);
        let t1 = Stamp(at.0 + h).min(self.newest()?.0.max(at));
        let span = t1.secs_since(t0);
        if span <= 0.0 {
            return None;
        }
        let (a, b, mid) = (
            self.pose_at(t0).ok()?,
            self.pose_at(t1).ok()?,
            self.pose_at(at).ok()?,
        );
        let v_body = mid.rotation.inverse() * (b.translation.vector - a.translation.vector) / span;
        let (_, _, dyaw) = (a.inverse() * b).rotation.euler_angles();
        Some((v_body, dyaw / span))
    }
}

/// Submap settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct SubmapConfig {
    /// Scans per radar stacked into a submap (default 10, the paper's N).
    pub size: usize,
    /// Scans older than the newest one by more than this are dropped, s (default 3.0): a submap never
    /// spans a long stop in the data.
    pub max_span: f64,
    /// Largest correction of the odometry's distances by the radars' Doppler, as a share (default
    /// 0.5; 0 = off). Each scan's Doppler fit gives the body's speed over the ground, independent of
    /// wheel radius or tyre wear; the submap's scans are placed along the odometry's path with each
    /// step between consecutive scans scaled to the distance the body's Doppler speed (a line fitted
    /// through the scans' speeds) integrates to over the step's time ([`SpeedScale`]). A wheel
    /// odometry 1 % long (the simulator's default drift) stretches a 72 km/h submap by 15 cm from
    /// end to end, and two laps at different speeds are
    /// stretched differently: on the demo drive the correction brings DC-Loc's median error from
    /// 0.065 to 0.058 m (docs/experiments.md, "Submaps and odometry"). Wheels that spin or slide read 5-30 % more distance for a
    /// second or two, which the correction also takes out where the slip covers only part of the
    /// submap. A submap whose ratio is off 1 by more than the bound is refused (the odometry is
    /// then used as it is, and the node counts it in its diagnostics): wheels do not over-read by
    /// half, but a radial velocity of the wrong sign (a ratio near -1) or in km/h (3.6) does.
    pub speed_scale_bound: f64,
    /// Heights kept in a submap, `[lowest, highest]` in the body frame, m (default `[-100.0, 100.0]`:
    /// all). The registration is planar: a radar that measures elevation sees the road surface and
    /// what passes overhead (signs, bridges, tree crowns), which land in the plane as clutter. Set the
    /// band to what stands on the ground at the radars' heights: the road lies at `-H` for a body
    /// frame `H` above it, so `[0.3 - H, 5.0 - H]` (`[0.3, 5.0]` for a body frame on the road); a
    /// planar radar's points all lie at its mounting height. The Doppler ego-motion
    /// fit still uses every detection.
    pub height_band: [f64; 2],
}

impl Default for SubmapConfig {
    fn default() -> Self {
        SubmapConfig {
            size: 10,
            max_span: 3.0,
            speed_scale_bound: 0.5,
            height_band: [-100.0, 100.0],
        }
    }
}

impl SubmapConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.count("size", self.size, 1, 1000);
        v.positive("max_span", self.max_span);
        v.range(
            "speed_scale_bound",
            self.speed_scale_bound,
            Range::NON_NEGATIVE.below(1.0),
        );
        let [lo, hi] = self.height_band;
        v.require(
            "height_band",
            lo.is_finite() && hi.is_finite() && lo < hi,
            || format!("[{lo}, {hi}]: needs two finite heights, the lower first"),
        );
    }

    /// `z` (body frame) lies within `height_band`.
    pub fn in_band(&self, z: f64) -> bool {
        let [lo, hi] = self.height_band;
        (lo..=hi).contains(&z)
    }
}

/// How a submap's odometry distances were corrected by the radars' Doppler speeds
/// (`submap.speed_scale_bound`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SpeedScale {
    /// The scans were placed along the odometry's path with each step's length taken from the
    /// Doppler speeds; the factor is the distance the Doppler speeds integrate to over the distance
    /// the odometry moved, over the whole submap.
    Applied(f64),
    /// Not corrected: the correction is off, fewer than three scans have a Doppler fit, or the
    /// odometry moved less than 1 m between them.
    Unavailable,
    /// Not corrected: the ratio (given) is off 1 by more than the bound.
    Refused(f64),
}

/// A submap point, in the submap (anchor body) frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SubmapPoint {
    /// Doppler-compensated position, m (eq. 4-5).
    pub p: Vec3,
    /// Covariance of `p`, m^2 (eq. 7-8).
    pub cov: Mat3,
    /// Measured (distorted) position, m.
    pub p_raw: Vec3,
    /// Covariance of `p_raw` (range and azimuth noise only), m^2.
    pub cov_raw: Mat3,
    /// Unit ray from the radar to the point.
    pub ray: Vec3,
    /// Measured radial velocity, m/s.
    pub v_r: f64,
    /// Index into [`Submap::scans`].
    pub scan: u32,
}

/// One scan that went into a submap.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SubmapScan {
    /// Measurement time.
    pub stamp: Stamp,
    /// Radar index.
    pub radar: usize,
    /// Body pose at the scan's stamp in the anchor frame.
    pub t_anchor_body: Iso3,
    /// The radar's `beta`, s.
    pub beta: f64,
    /// Radar velocity fitted from this scan's Doppler (radar frame, m/s), when the fit succeeded.
    pub doppler_velocity: Option<Vec3>,
}

/// The last N scans of every radar, in the body frame at the newest scan's stamp.
#[derive(Debug, Clone, PartialEq)]
pub struct Submap {
    /// Stamp of the newest scan: the submap's frame is the body frame at this time.
    pub anchor_stamp: Stamp,
    /// Odometry pose of the anchor (`t_odom_anchor`).
    pub t_odom_anchor: Iso3,
    /// The points.
    pub points: Vec<SubmapPoint>,
    /// The scans, oldest first.
    pub scans: Vec<SubmapScan>,
    /// The correction of the odometry's distances the scans were placed with.
    pub speed_scale: SpeedScale,
    /// Covariance of `(x, y, yaw)` of the frame the points pin down as a whole against the anchor,
    /// from the odometry's motion between the scans (zero when the odometry gives no uncertainty):
    /// the scans' pose errors share the steps between them, so they do not average out.
    pub motion: Mat3,
}

impl Submap {
    /// Planar point set for registration: compensated (`p`, `cov`) or raw (`p_raw`, `cov_raw`) positions;
    /// the covariance is the upper-left 2x2 block.
    pub fn point_set(&self, compensated: bool) -> PointSet2 {
        let mut out = PointSet2 {
            points: Vec::with_capacity(self.points.len()),
            covs: Vec::with_capacity(self.points.len()),
            rays: Vec::with_capacity(self.points.len()),
        };
        for q in &self.points {
            let (p, c) = if compensated {
                (q.p, q.cov)
            } else {
                (q.p_raw, q.cov_raw)
            };
            out.points.push(p.xy());
            out.covs.push(c.fixed_view::<2, 2>(0, 0).into_owned());
            out.rays.push(planar_ray(&q.ray));
        }
        out
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when the submap has no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

/// The planar direction of a 3D ray (unit); along x for a vertical one, which no radar reports.
fn planar_ray(ray: &Vec3) -> Vec2 {
    ray.xy().try_normalize(1e-9).unwrap_or_else(Vec2::x)
}

/// What happened to one scan on its way into the submap window.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ScanReport {
    /// Detections kept.
    pub kept: usize,
    /// Detections dropped as moving objects.
    pub dynamic: usize,
    /// Detections dropped because their ray was undefined (zero range, non-finite).
    pub invalid: usize,
    /// Detections dropped as outside `submap.height_band`.
    pub out_of_band: usize,
    /// The Doppler ego-motion fit succeeded and ended near one of its priors.
    pub doppler_fit: bool,
    /// The radar velocity fitted from the Doppler alone against the odometry's prediction, when the
    /// radar moved fast enough to tell ([`crate::radar::consistency`]).
    pub doppler_check: Option<Verdict>,
}

#[derive(Debug, Clone)]
struct StackedScan {
    radar: usize,
    stamp: Stamp,
    t_odom_body: Iso3,
    points: Vec<BodyPoint>,
    doppler_velocity: Option<Vec3>,
    /// Body velocity (m/s) and yaw rate (rad/s) from odometry at the scan's stamp.
    odom_velocity: Option<(Vec3, f64)>,
}

/// Rolling window of processed scans, per radar, from which submaps are built.
#[derive(Debug, Clone)]
pub struct SubmapBuilder {
    cfg: SubmapConfig,
    ego: EgoMotionConfig,
    radars: Vec<RadarModel>,
    scans: VecDeque<StackedScan>,
}

impl SubmapBuilder {
    /// A builder for the given radars (index = `RadarScan::radar`).
    pub fn new(cfg: SubmapConfig, ego: EgoMotionConfig, radars: Vec<RadarModel>) -> Self {
        SubmapBuilder {
            cfg,
            ego,
            radars,
            scans: VecDeque::new(),
        }
    }

    /// The radars.
    pub fn radars(&self) -> &[RadarModel] {
        &self.radars
    }

    /// Forgets every scan (after time went backwards).
    pub fn clear(&mut self) {
        self.scans.clear();
    }

    /// Newest scan stamp held.
    pub fn newest_stamp(&self) -> Option<Stamp> {
        self.scans.iter().map(|s| s.stamp).max()
    }

    /// Adds one scan with the body pose at its stamp. Detections are compensated (eq. 4), given their
    /// covariance (eq. 7-8), moved into the body frame (eq. 5); moving objects are dropped when
    /// `reject_dynamic` is set, judged against the scan's own Doppler ego-motion fit, or, when that fails,
    /// against `velocity_prior` (body velocity m/s and yaw rate rad/s, e.g. from odometry).
    ///
    /// `None` when `scan.radar` is not a configured radar.
    pub fn add_scan(
        &mut self,
        scan: &RadarScan,
        t_odom_body: Iso3,
        velocity_prior: Option<(Vec3, f64)>,
    ) -> Option<ScanReport> {
        let model = self.radars.get(scan.radar)?;
        let mut report = ScanReport::default();
        // The prior seen by this radar: body velocity plus the yaw-rate lever arm, in the radar frame.
        let prior_radar = velocity_prior.map(|(v, w)| {
            let t = model.t_body_radar.translation.vector;
            let v_at_radar = v + Vec3::new(-w * t.y, w * t.x, 0.0);
            model.t_body_radar.rotation.inverse() * v_at_radar
        });
        let priors = self.priors(scan.radar, scan.stamp, prior_radar);
        let velocities: Vec<Vec3> = priors.iter().map(|p| p.0).collect();
        let fit = fit_radar_velocity(&scan.detections, FitDims::Auto, &velocities, &self.ego)
            .ok()
            .filter(|f| within_a_prior(&f.v_radar, &priors));
        report.doppler_fit = fit.is_some();
        // The Doppler alone, against the odometry: a check of the radar's configuration.
        report.doppler_check = prior_radar
            .filter(|p| p.xy().norm() >= consistency::MIN_SPEED)
            .and_then(|p| {
                let free = fit_radar_velocity(&scan.detections, FitDims::Planar, &[], &self.ego);
                free.ok().map(|f| consistency::compare(&f.v_radar, &p))
            });
        let keep: Vec<bool> = match (&fit, prior_radar, self.ego.reject_dynamic) {
            (_, _, false) => vec![true; scan.detections.len()],
            (Some(f), _, true) => f.inliers.clone(),
            (None, Some(p), true) => static_mask(&scan.detections, &p, self.ego.inlier_threshold),
            (None, None, true) => vec![true; scan.detections.len()],
        };
        let mut points = Vec::with_capacity(scan.detections.len());
        for (det, keep) in scan.detections.iter().zip(keep) {
            match model.to_body(det) {
                None => report.invalid += 1,
                Some(_) if !keep => report.dynamic += 1,
                Some(b) if !self.cfg.in_band(b.p.z) => report.out_of_band += 1,
                Some(b) => points.push(b),
            }
        }
        report.kept = points.len();
        self.scans.push_back(StackedScan {
            radar: scan.radar,
            stamp: scan.stamp,
            t_odom_body,
            points,
            doppler_velocity: fit.map(|f| f.v_radar),
            odom_velocity: velocity_prior,
        });
        self.trim();
        Some(report)
    }

    /// The velocities a scan's Doppler fit may lie near (radar frame), each with how far the fit
    /// may end from it: the odometry's, within `prior_tolerance`; and, when this radar's previous fit
    /// is recent, the odometry's direction at the speed that fit measured, within what hard braking
    /// (8 m/s^2) sheds in the time between the two scans plus `inlier_threshold` for the fits'
    /// noise. Wheels that spin or slide read up to a third more speed at once, beyond the
    /// prior's tolerance at highway speeds, while the body's true speed changes by no more than
    /// that. The bound on the second matters where moving objects surround the body: a fit that
    /// locks onto a stream of traffic a few m/s slower than the body is within `prior_tolerance` of
    /// the previous fit, and each such fit would let the next one slide further.
    fn priors(&self, radar: usize, stamp: Stamp, odometry: Option<Vec3>) -> Vec<(Vec3, f64)> {
        let Some(odometry) = odometry else {
            return Vec::new();
        };
        let mut priors = vec![(odometry, self.ego.prior_tolerance)];
        let recent = self.ego.prior_tolerance / HARD_BRAKING;
        let previous = self
            .scans
            .iter()
            .filter(|s| s.radar == radar && s.stamp < stamp)
            .max_by_key(|s| s.stamp)
            .filter(|s| stamp.secs_since(s.stamp) <= recent);
        let speed = odometry.xy().norm();
        if let Some(s) = previous
            && let Some(v) = s.doppler_velocity
            && speed > 1e-6
        {
            let bound = HARD_BRAKING * stamp.secs_since(s.stamp) + self.ego.inlier_threshold;
            priors.push((odometry * (v.xy().norm() / speed), bound));
        }
        priors
    }

    fn trim(&mut self) {
        let Some(newest) = self.newest_stamp() else {
            return;
        };
        let max_span = self.cfg.max_span;
        self.scans
            .retain(|s| newest.secs_since(s.stamp) <= max_span);
        for r in 0..self.radars.len() {
            let count = self.scans.iter().filter(|s| s.radar == r).count();
            let mut excess = count.saturating_sub(self.cfg.size);
            // Scans arrive roughly in time order; drop this radar's oldest first.
            while excess > 0 {
                let oldest = self
                    .scans
                    .iter()
                    .enumerate()
                    .filter(|(_, s)| s.radar == r)
                    .min_by_key(|(_, s)| s.stamp)
                    .map(|(i, _)| i);
                match oldest {
                    Some(i) => {
                        self.scans.remove(i);
                    }
                    None => break,
                }
                excess -= 1;
            }
        }
    }

    /// Scans currently held, over all radars.
    pub fn scan_count(&self) -> usize {
        self.scans.len()
    }

    /// Builds the submap in the body frame at the newest scan's stamp; `None` without scans.
    pub fn build(&self) -> Option<Submap> {
        let mut order: Vec<&StackedScan> = self.scans.iter().collect();
        order.sort_by_key(|s| (s.stamp, s.radar));
        let anchor = *order.last()?;
        let samples = self.doppler_speeds(&order);
        let speed_scale = self.speed_scale(&samples);
        let positions = match speed_scale {
            SpeedScale::Applied(_) => doppler_path(&order, &samples),
            SpeedScale::Unavailable | SpeedScale::Refused(_) => order
                .iter()
                .map(|s| s.t_odom_body.translation.vector)
                .collect(),
        };
        let anchor_position = positions[positions.len() - 1];
        let anchor_rotation = anchor.t_odom_body.rotation;
        let mut sub = Submap {
            anchor_stamp: anchor.stamp,
            t_odom_anchor: anchor.t_odom_body,
            points: Vec::with_capacity(order.iter().map(|s| s.points.len()).sum()),
            scans: Vec::with_capacity(order.len()),
            speed_scale,
            motion: Mat3::zeros(),
        };
        for (k, (s, position)) in order.iter().zip(&positions).enumerate() {
            let t_anchor_body = Iso3::from_parts(
                (anchor_rotation.inverse() * (position - anchor_position)).into(),
                anchor_rotation.inverse() * s.t_odom_body.rotation,
            );
            let rot = t_anchor_body.rotation.to_rotation_matrix().into_inner();
            let to_anchor = |p: Vec3| (t_anchor_body * nalgebra::Point3::from(p)).coords;
            sub.scans.push(SubmapScan {
                stamp: s.stamp,
                radar: s.radar,
                t_anchor_body,
                beta: self.radars.get(s.radar).map_or(0.0, |m| m.beta),
                doppler_velocity: s.doppler_velocity,
            });
            for b in &s.points {
                sub.points.push(SubmapPoint {
                    p: to_anchor(b.p),
                    cov: rot * b.cov * rot.transpose(),
                    p_raw: to_anchor(b.p_raw),
                    cov_raw: rot * b.cov_raw * rot.transpose(),
                    ray: rot * b.ray,
                    v_r: b.v_r,
                    scan: k as u32,
                });
            }
        }
        Some(sub)
    }

    /// The body's speed over the ground from each scan's Doppler fit, with the scan's stamp and
    /// odometry position (`scans` in time order; scans without a fit are left out).
    fn doppler_speeds(&self, scans: &[&StackedScan]) -> Vec<SpeedSample> {
        scans
            .iter()
            .filter_map(|s| {
                let v_radar = s.doppler_velocity?;
                let model = self.radars.get(s.radar)?;
                // The radar moves with v + w x t; the yaw rate is the odometry's (its bias is
                // negligible over a lever arm of metres).
                let w = s.odom_velocity.map_or(0.0, |(_, w)| w);
                let t = model.t_body_radar.translation.vector;
                let v_body =
                    model.t_body_radar.rotation * v_radar + Vec3::new(w * t.y, -w * t.x, 0.0);
                Some(SpeedSample {
                    stamp: s.stamp,
                    speed: v_body.xy().norm(),
                    position: s.t_odom_body.translation.vector,
                })
            })
            .collect()
    }

    /// The distance the Doppler says the body covered between the oldest and newest scans with a fit
    /// (their body speeds, trapezoids between consecutive ones) over the odometry's path between
    /// the same scans.
    fn speed_scale(&self, samples: &[SpeedSample]) -> SpeedScale {
        if self.cfg.speed_scale_bound <= 0.0 || samples.len() < 3 {
            return SpeedScale::Unavailable;
        }
        let (mut doppler, mut odom) = (0.0, 0.0);
        for w in samples.windows(2) {
            doppler += 0.5 * (w[0].speed + w[1].speed) * w[1].stamp.secs_since(w[0].stamp);
            odom += (w[1].position - w[0].position).xy().norm();
        }
        if !(odom >= 1.0 && doppler.is_finite()) {
            return SpeedScale::Unavailable;
        }
        let k = doppler / odom;
        if (k - 1.0).abs() > self.cfg.speed_scale_bound {
            SpeedScale::Refused(k)
        } else {
            SpeedScale::Applied(k)
        }
    }
}

/// Deceleration of hard braking, m/s^2: bounds how fast the body's true speed changes.
const HARD_BRAKING: f64 = 8.0;

/// Adds to each point's covariance what the odometry's motion between its scan and the anchor is
/// uncertain by, and sets [`Submap::motion`]; `motion` holds per scan (as `sub.scans`) the covariance
/// of the anchor's pose given the scan's, odometry frame ([`OdometryBuffer::motion_to`]). A scan's
/// pose relative to the anchor is off by `(dt, dtheta)` with that covariance turned into the anchor
/// frame; a point at `q` in the anchor frame moves by `dt + perp(q) dtheta`.
pub fn add_motion_noise(sub: &mut Submap, motion: &[Mat3]) {
    let (_, _, yaw) = sub.t_odom_anchor.rotation.euler_angles();
    let (s, c) = yaw.sin_cos();
    let turn = Mat3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0);
    let motion: Vec<Mat3> = motion.iter().map(|m| turn * m * turn.transpose()).collect();
    let spread = |q: &Vec3, m: &Mat3| {
        let j = nalgebra::Matrix2x3::new(1.0, 0.0, -q.y, 0.0, 1.0, q.x);
        j * m * j.transpose()
    };
    sub.motion = common_motion(&motion, &sub.points);
    for p in &mut sub.points {
        let m = &motion[p.scan as usize];
        let (extra, extra_raw) = (spread(&p.p, m), spread(&p.p_raw, m));
        let mut block = p.cov.fixed_view_mut::<2, 2>(0, 0);
        block += extra;
        let mut block = p.cov_raw.fixed_view_mut::<2, 2>(0, 0);
        block += extra_raw;
    }
}

/// Covariance of the points' weighted mean pose error, each scan weighted by its share of the points:
/// `sum_k sum_l w_k w_l C_kl`, where two scans' errors share the steps from the later of them to the
/// anchor, `C_kl = motion[max(k, l)]` (`motion` per scan, oldest first, the anchor last).
fn common_motion(motion: &[Mat3], points: &[SubmapPoint]) -> Mat3 {
    if points.is_empty() {
        return Mat3::zeros();
    }
    let mut w = vec![0.0; motion.len()];
    for p in points {
        w[p.scan as usize] += 1.0 / points.len() as f64;
    }
    let mut before = 0.0;
    let mut out = Mat3::zeros();
    for (m, wk) in motion.iter().zip(&w) {
        out += m * (wk * wk + 2.0 * wk * before);
        before += wk;
    }
    out
}

/// `v` lies within the bound of one of `priors` (velocity, bound), or there are none.
fn within_a_prior(v: &Vec3, priors: &[(Vec3, f64)]) -> bool {
    priors.is_empty() || priors.iter().any(|(p, bound)| (v - p).norm() <= *bound)
}

/// One scan's Doppler speed over the ground, m/s, with its stamp and odometry position.
#[derive(Debug, Clone, Copy)]
struct SpeedSample {
    stamp: Stamp,
    speed: f64,
    position: Vec3,
}

/// The scans' positions (odometry frame) along the odometry's path with each step's length taken from
/// the Doppler: the step between consecutive scans keeps the odometry's direction and is scaled to
/// the distance the body's speed integrates to over the step's time. A slip that covers part of the
/// submap stretches only the steps it falls in, and those are the ones shortened. The body's speed
/// changes smoothly over a submap's second or so, so it is taken as the least-squares line through
/// the scans' Doppler speeds: that averages their noise as one factor for the whole submap would,
/// and still follows an acceleration. `scans` in time order, `samples` their fitted subset (at
/// least three).
fn doppler_path(scans: &[&StackedScan], samples: &[SpeedSample]) -> Vec<Vec3> {
    let t0 = samples[0].stamp;
    let n = samples.len() as f64;
    let mean_t = samples.iter().map(|s| s.stamp.secs_since(t0)).sum::<f64>() / n;
    let mean_v = samples.iter().map(|s| s.speed).sum::<f64>() / n;
    let (mut stt, mut stv) = (0.0, 0.0);
    for s in samples {
        let dt = s.stamp.secs_since(t0) - mean_t;
        stt += dt * dt;
        stv += dt * (s.speed - mean_v);
    }
    let slope = if stt > 0.0 { stv / stt } else { 0.0 };
    let speed_at = |t: Stamp| mean_v + slope * (t.secs_since(t0) - mean_t);
    let mut out = Vec::with_capacity(scans.len());
    let mut position = scans[0].t_odom_body.translation.vector;
    out.push(position);
    for w in scans.windows(2) {
        let (a, b) = (w[0], w[1]);
        let step = b.t_odom_body.translation.vector - a.t_odom_body.translation.vector;
        let length = step.xy().norm();
        if length > 1e-9 {
            let doppler =
                0.5 * (speed_at(a.stamp) + speed_at(b.stamp)) * b.stamp.secs_since(a.stamp);
            position += step * (doppler / length);
        }
        out.push(position);
    }
    out
}

#[cfg(test)]
mod tests;
