//! The radar odometry stage ([`RadarOdometry`]): radar scans (and gyro samples) in, odometry samples
//! out, the same `t_odom_body` samples a `nav_msgs/Odometry` topic gives the pipeline.
//!
//! Steps, per time step:
//! 1. scans are grouped into a step: one scan of each radar (a step closes when every radar has
//!    reported, or when a radar reports a second time); its stamp is the newest scan's, so every scan
//!    of the step is covered by the sample it produces;
//! 2. each scan is fitted and the radars' information summed ([`super::fit`]), with the previous
//!    step's twist as the prior against large movers;
//! 3. with a gyro: its mean rate around the scans against the Doppler yaw rate (where that is
//!    observable) updates the bias ([`GyroBias`]) and the frame check; so does a step in which every
//!    radar stands still, against a yaw rate of zero (a body whose radars do not move does not
//!    turn: this is what gives one radar's gyro its bias, at the first stop); its rate, bias
//!    removed, joins the fit as a yaw-rate measurement, and its mean over the step turns the heading;
//! 4. a step the fit refuses coasts on the previous twist, its covariance grown by the motion the
//!    body may have made meanwhile;
//! 5. the pose and its covariance are integrated ([`PlanarIntegrator`]).

use std::collections::BTreeMap;

use super::config::{ImuConfig, OdometrySource};
use super::fit::{StepScan, TwistRefusal, doppler_information};
use super::gyro::{FrameCheck, Gyro, GyroBias, GyroCounts, frame_advice};
use super::integrate::{PlanarIntegrator, StepMotion};
use crate::math::{Iso3, Mat3, Stamp, Vec3};
use crate::pose_noise::PoseNoise;
use crate::radar::RadarScan;
use crate::radar::doppler::RadarModel;
use crate::radar::ego_motion::EgoMotionConfig;
use crate::submap::OdometryConfig;

/// Standard deviation of the body's acceleration while coasting, m/s^2 per second of coasting.
const COAST_ACCELERATION: f64 = 3.0;
/// Standard deviation of the yaw acceleration while coasting, rad/s^2.
const COAST_YAW_ACCELERATION: f64 = 0.5;
/// The previous twist is a prior for the next fit within this age, s.
const PRIOR_AGE: f64 = 0.5;
/// Weight of the newest step in the smoothed body acceleration (an exponential filter over steps).
const ACCELERATION_GAIN: f64 = 0.3;
/// Shortest window the gyro is averaged over around a step's scans, s.
const MIN_GYRO_WINDOW: f64 = 0.04;
/// A step whose radars all move slower than this stands still, m/s.
const STANDSTILL_SPEED: f64 = 0.05;
/// Standard deviation of the yaw rate of a body standing still, rad/s: a radar on a hand-held rig
/// turned about a point near it still moves a few cm/s per rad/s.
const STANDSTILL_YAW_SIGMA: f64 = 0.01;

/// One odometry sample of the estimator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometryEstimate {
    /// Its stamp.
    pub stamp: Stamp,
    /// Body pose in the odometry frame.
    pub t_odom_body: Iso3,
    /// The pose's uncertainty, in the form that also gives the covariance of the motion between two
    /// samples ([`OdometryEstimate::covariance`] is the pose's own).
    pub noise: PoseNoise,
    /// Body twist `(v_x m/s, v_y m/s, yaw rate rad/s)`, body frame.
    pub twist: Vec3,
    /// Its covariance.
    pub twist_covariance: Mat3,
    /// The step's fit was refused and the twist is the previous one.
    pub coasting: bool,
}

impl OdometryEstimate {
    /// Covariance of `(x m, y m, yaw rad)` of the pose, odometry frame.
    pub fn covariance(&self) -> Mat3 {
        self.noise.covariance()
    }
}

/// Counters of the radar odometry.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RadarOdometryStats {
    /// Steps closed.
    pub steps: u64,
    /// Steps that coasted, by why the fit refused them.
    pub coasted: BTreeMap<&'static str, u64>,
    /// Scans fitted.
    pub scans_fitted: u64,
    /// Scans refused, by reason.
    pub scans_refused: BTreeMap<&'static str, u64>,
    /// Scans stamped at or before the last step (too late for the odometry; still stacked).
    pub late_scans: u64,
    /// `nav_msgs/Odometry` samples ignored (the odometry comes from the radars).
    pub topic_ignored: u64,
    /// The gyro's samples.
    pub gyro: GyroCounts,
    /// Steps whose interval the gyro did not cover (the yaw rate then comes from the Doppler alone).
    pub gyro_gaps: u64,
    /// Gyro bias estimate and its standard deviation, rad/s.
    pub gyro_bias: Option<(f64, f64)>,
    /// Bias updates taken and refused as outliers.
    pub bias_updates: (u64, u64),
    /// The slope of the gyro's rate on the Doppler yaw rate, once it showed the gyro in the wrong frame.
    pub gyro_wrong_frame: Option<f64>,
}

/// The previous step.
#[derive(Debug, Clone, Copy)]
struct Previous {
    stamp: Stamp,
    twist: Vec3,
    covariance: Mat3,
    /// The body's acceleration `d twist / dt`, smoothed over the steps.
    acceleration: Vec3,
}

/// The gyro and what is known of it.
#[derive(Debug, Clone)]
struct GyroState {
    gyro: Gyro,
    bias: GyroBias,
    frame: FrameCheck,
    density: f64,
}

/// Radar scans and gyro samples in, odometry samples out (see the module documentation).
#[derive(Debug, Clone)]
pub struct RadarOdometry {
    radars: Vec<RadarModel>,
    ego: EgoMotionConfig,
    lateral_sigma: f64,
    gyro: Option<GyroState>,
    group: Vec<RadarScan>,
    previous: Option<Previous>,
    integrator: Option<PlanarIntegrator>,
    stats: RadarOdometryStats,
}

impl RadarOdometry {
    /// An estimator for `radars` (by radar index); `None` when `odometry.source` is `topic`.
    pub fn new(
        odometry: &OdometryConfig,
        imu: &ImuConfig,
        radars: Vec<RadarModel>,
        ego: EgoMotionConfig,
    ) -> Option<Self> {
        let gyro = match odometry.source {
            OdometrySource::Topic => return None,
            OdometrySource::Radar => None,
            OdometrySource::RadarImu => Some(GyroState {
                gyro: Gyro::new(imu),
                bias: GyroBias::new(imu),
                frame: FrameCheck::default(),
                density: imu.gyro_noise_density,
            }),
        };
        Some(RadarOdometry {
            radars,
            ego,
            lateral_sigma: odometry.lateral_velocity_sigma,
            gyro,
            group: Vec::new(),
            previous: None,
            integrator: None,
            stats: RadarOdometryStats::default(),
        })
    }

    /// The counters so far.
    pub fn stats(&self) -> RadarOdometryStats {
        let mut s = self.stats.clone();
        if let Some(g) = &self.gyro {
            s.gyro = g.gyro.counts;
            s.gyro_bias = Some((g.bias.bias, g.bias.variance.sqrt()));
            s.bias_updates = (g.bias.updates, g.bias.outliers);
        }
        s
    }

    /// Counts an odometry topic sample that is not used.
    pub fn ignore_topic(&mut self) {
        self.stats.topic_ignored += 1;
    }

    /// Takes one gyro sample (IMU frame, rad/s); ignored without `radar_imu`.
    pub fn push_imu(&mut self, stamp: Stamp, angular_velocity: Vec3) {
        if let Some(g) = &mut self.gyro {
            g.gyro.push(stamp, angular_velocity);
        }
    }

    /// Forgets the motion so far (time went backwards): the next step starts a new track.
    pub fn reset(&mut self) {
        self.group.clear();
        self.previous = None;
        self.integrator = None;
        if let Some(g) = &mut self.gyro {
            g.gyro.clear();
        }
    }

    /// Takes one scan; returns the odometry samples of the step it closed, if any.
    pub fn push_scan(&mut self, scan: &RadarScan) -> Vec<OdometryEstimate> {
        if scan.radar >= self.radars.len() {
            return Vec::new();
        }
        if self.integrator.is_some_and(|i| scan.stamp <= i.stamp()) {
            self.stats.late_scans += 1;
            return Vec::new();
        }
        let mut out = Vec::new();
        if self.group.iter().any(|s| s.radar == scan.radar) {
            out = self.close_step();
        }
        self.group.push(scan.clone());
        // The group holds each radar once.
        if self.group.len() == self.radars.len() {
            out.extend(self.close_step());
        }
        out
    }

    /// End of input: closes the step in progress.
    pub fn finish(&mut self) -> Vec<OdometryEstimate> {
        self.close_step()
    }

    fn close_step(&mut self) -> Vec<OdometryEstimate> {
        let group = std::mem::take(&mut self.group);
        let (Some(first), Some(last)) = (
            group.iter().map(|s| s.stamp).min(),
            group.iter().map(|s| s.stamp).max(),
        ) else {
            return Vec::new();
        };
        self.stats.steps += 1;
        let start = self.integrator.map_or(first, |i| i.stamp());
        let recent = self
            .previous
            .filter(|p| last.secs_since(p.stamp) <= PRIOR_AGE);
        let prior = recent.map(|p| p.twist);
        let acceleration = recent.map_or(Vec3::zeros(), |p| p.acceleration);
        let scans: Vec<StepScan<'_>> = group
            .iter()
            .map(|s| StepScan {
                radar: s.radar,
                t_body_radar: self.radars[s.radar].t_body_radar,
                detections: &s.detections,
                sigma_velocity: self.radars[s.radar].noise.sigma_velocity,
                shift: acceleration * last.secs_since(s.stamp),
            })
            .collect();
        let info = doppler_information(&scans, prior, self.lateral_sigma, &self.ego);
        for o in &info.scans {
            match &o.result {
                Ok(_) => self.stats.scans_fitted += 1,
                Err(e) => *self.stats.scans_refused.entry(e.name()).or_default() += 1,
            }
        }
        let doppler = info.solve(None);
        let centre = mean_stamp(&group);
        let half = 0.5 * last.secs_since(first).max(MIN_GYRO_WINDOW);
        let still = info.fastest.is_some_and(|v| v < STANDSTILL_SPEED);
        let gyro = self.gyro_step(&doppler, still, centre, half, start, last);
        let fitted = info.solve(gyro.map(|g| g.yaw_rate));
        let dt = last.secs_since(start);
        let (twist, covariance, coasting) = match (fitted, self.previous) {
            (Ok(t), _) => (t.twist, t.covariance, false),
            (Err(why), previous) => {
                *self.stats.coasted.entry(why.name()).or_default() += 1;
                let Some(p) = previous else {
                    // Nothing to coast on: no track starts yet.
                    return Vec::new();
                };
                let grown = p.covariance + coast_growth(last.secs_since(p.stamp));
                (p.twist, grown, true)
            }
        };
        let mut out = Vec::new();
        if self.integrator.is_none() {
            self.integrator = Some(PlanarIntegrator::new(first));
            out.push(start_of_track(first));
        }
        let integrator = self.integrator.as_mut().expect("set above");
        if dt > 0.0 {
            // Trapezoids: the mean of the two ends' twists over the step (the twist alone would be
            // a step late while the body accelerates: centimetres over 10 m). The white part stays
            // the newest twist's, the variance each twist adds to a sum of steps.
            let mean = recent.map_or(twist, |p| 0.5 * (p.twist + twist));
            let heading = gyro.map(|g| g.heading);
            integrator.step(last, &step_motion(mean, covariance, dt, heading));
        }
        let acceleration = match recent {
            Some(p) if !coasting && last > p.stamp => {
                let step = (twist - p.twist) / last.secs_since(p.stamp);
                p.acceleration + (step - p.acceleration) * ACCELERATION_GAIN
            }
            _ => acceleration,
        };
        self.previous = Some(Previous {
            stamp: last,
            twist,
            covariance,
            acceleration,
        });
        let bias_variance = self.gyro.as_ref().map_or(0.0, |g| g.bias.variance);
        let integrator = self.integrator.expect("set above");
        out.push(OdometryEstimate {
            stamp: last,
            t_odom_body: integrator.pose(),
            noise: integrator.noise(bias_variance),
            twist,
            twist_covariance: covariance,
            coasting,
        });
        out
    }

    /// The gyro's part in a step: the bias and the frame check updated against the Doppler yaw
    /// rate (when observable; else the bias against zero when the radars stand `still`), and the
    /// gyro's yaw rate around the scans and heading change over `[start, end]`, bias removed. `None`
    /// without a usable gyro.
    fn gyro_step(
        &mut self,
        doppler: &Result<super::fit::PlanarTwist, TwistRefusal>,
        still: bool,
        centre: Stamp,
        half: f64,
        start: Stamp,
        end: Stamp,
    ) -> Option<GyroPart> {
        let g = self.gyro.as_mut()?;
        if g.frame.wrong_frame.is_some() {
            return None;
        }
        let h = Stamp::from_secs_f64(half).0;
        let around = g.gyro.mean_rate(Stamp(centre.0 - h), Stamp(centre.0 + h));
        let Some(around) = around else {
            self.stats.gyro_gaps += 1;
            return None;
        };
        let dt = end.secs_since(start);
        g.bias.predict(dt);
        let around_var = g.density.powi(2) / (2.0 * half);
        if let Ok(d) = doppler {
            let (w, var) = (d.twist.z, d.covariance[(2, 2)]);
            if let Some(slope) = g.frame.observe(w, around) {
                log::warn!("{}", frame_advice(slope));
                self.stats.gyro_wrong_frame = Some(slope);
                return None;
            }
            g.bias.update(around - w, var + around_var);
        } else if still {
            g.bias
                .update(around, STANDSTILL_YAW_SIGMA.powi(2) + around_var);
        }
        let heading = if dt > 0.0 {
            let mean = g.gyro.mean_rate(start, end).unwrap_or(around);
            ((mean - g.bias.bias) * dt, g.density.powi(2) * dt, -dt)
        } else {
            (0.0, 0.0, 0.0)
        };
        Some(GyroPart {
            yaw_rate: (around - g.bias.bias, around_var + g.bias.variance),
            heading,
        })
    }
}

/// The gyro's measurements of a step.
#[derive(Debug, Clone, Copy)]
struct GyroPart {
    /// Yaw rate around the scans, bias removed, and its variance.
    yaw_rate: (f64, f64),
    /// Heading change over the step, its white variance and its derivative in the bias.
    heading: (f64, f64, f64),
}

/// The first sample of a track: the origin at the oldest scan of the first step.
fn start_of_track(stamp: Stamp) -> OdometryEstimate {
    OdometryEstimate {
        stamp,
        t_odom_body: Iso3::identity(),
        noise: PoseNoise::zero(),
        twist: Vec3::zeros(),
        twist_covariance: Mat3::zeros(),
        coasting: false,
    }
}

/// The mean stamp of a step's scans.
fn mean_stamp(group: &[RadarScan]) -> Stamp {
    let t0 = group[0].stamp;
    let mean = group.iter().map(|s| s.stamp.secs_since(t0)).sum::<f64>() / group.len() as f64;
    Stamp(t0.0 + Stamp::from_secs_f64(mean).0)
}

/// How much a twist may have changed in `dt` seconds of coasting.
fn coast_growth(dt: f64) -> Mat3 {
    let a = (COAST_ACCELERATION * dt).powi(2);
    Mat3::from_diagonal(&Vec3::new(a, a, (COAST_YAW_ACCELERATION * dt).powi(2)))
}

/// A step of `dt` seconds at `twist`: the heading turned by the yaw rate, or by the gyro
/// (`heading`: change, white variance, derivative in the bias) when there is one.
fn step_motion(
    twist: Vec3,
    covariance: Mat3,
    dt: f64,
    heading: Option<(f64, f64, f64)>,
) -> StepMotion {
    let scale = Mat3::from_diagonal(&Vec3::new(1.0, 1.0, dt));
    let mut q = scale * covariance * scale;
    let (dtheta, per_bias) = match heading {
        Some((dtheta, var, per_bias)) => {
            q.fixed_view_mut::<1, 3>(2, 0).fill(0.0);
            q.fixed_view_mut::<3, 1>(0, 2).fill(0.0);
            q[(2, 2)] = var;
            (dtheta, per_bias)
        }
        None => (twist.z * dt, 0.0),
    };
    StepMotion {
        velocity: twist.xy(),
        dtheta,
        covariance: q,
        dtheta_per_bias: per_bias,
    }
}
