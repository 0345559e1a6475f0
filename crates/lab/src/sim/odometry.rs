//! Wheel/gyro odometry with drift: the true motion between two samples, distorted and integrated.
//!
//! [`OdometryIntegrator`] measures each step of the ground truth with a scale error, a yaw-rate bias,
//! white noise and episodes of wheel slip, composes it onto the previous odometry pose (the odometry
//! frame starts at the ground-truth start pose), and propagates the pose covariance to first order;
//! slip is not in the covariance. docs/algorithm.md, "Odometry", has the model and the propagation.
//!
//! Entry points: [`OdometryIntegrator`], [`OdometrySample`], [`PoseSample`] (ground truth) and their
//! `to_msg` conversions to `nav_msgs/Odometry`.

use crate::sim::config::OdometrySimConfig;
use crate::sim::route::{EgoState, LapInfo};
use dc_loc_core::math::{Iso2, Mat3, Stamp, Vec2, iso3_from_iso2};
use dc_loc_core::msgs::geometry_msgs::{
    Pose, PoseWithCovariance, Twist, TwistWithCovariance, Vector3,
};
use dc_loc_core::msgs::nav_msgs::Odometry;
use dc_loc_core::msgs::std_msgs::Header;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::{Exp1, StandardNormal};

/// A ground-truth sample (frame `map`, child `base_link`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseSample {
    /// Time.
    pub stamp: Stamp,
    /// Body pose in the map frame.
    pub t_map_body: Iso2,
    /// Heading, rad, continuous over the drive.
    pub heading: f64,
    /// Forward speed, m/s.
    pub speed: f64,
    /// Yaw rate, rad/s.
    pub yaw_rate: f64,
    /// Distance driven since the start, m.
    pub distance: f64,
    /// Lap and direction.
    pub lap: LapInfo,
}

impl PoseSample {
    /// From an exact ego state.
    pub fn new(stamp: Stamp, s: &EgoState) -> Self {
        PoseSample {
            stamp,
            t_map_body: s.t_map_body,
            heading: s.heading,
            speed: s.speed,
            yaw_rate: s.yaw_rate,
            distance: s.distance,
            lap: s.lap,
        }
    }
    /// As `nav_msgs/Odometry` (zero covariance: it is the truth).
    pub fn to_msg(&self, frame_id: &str, child_frame_id: &str) -> Odometry {
        odometry_msg(
            self.stamp,
            frame_id,
            child_frame_id,
            &self.t_map_body,
            self.speed,
            self.yaw_rate,
            [0.0; 36],
            [0.0; 36],
        )
    }
}

/// An odometry sample (frame `odom`, child `base_link`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometrySample {
    /// Time.
    pub stamp: Stamp,
    /// Body pose in the odometry frame.
    pub t_odom_body: Iso2,
    /// Heading in the odometry frame, rad, continuous.
    pub heading: f64,
    /// Measured forward speed, m/s.
    pub speed: f64,
    /// Measured yaw rate, rad/s.
    pub yaw_rate: f64,
    /// Covariance of (x, y, yaw), m^2 and rad^2.
    pub covariance: Mat3,
    /// Variance of the measured speed (m/s)^2 and yaw rate (rad/s)^2.
    pub twist_variance: [f64; 2],
}

impl OdometrySample {
    /// As `nav_msgs/Odometry`: pose covariance from (x, y, yaw) in ROS order, z / roll / pitch at 1e-6
    /// (planar motion is known), twist covariance from the noise model.
    pub fn to_msg(&self, frame_id: &str, child_frame_id: &str) -> Odometry {
        let mut pc = [0.0; 36];
        let idx = [0usize, 1, 5];
        for (a, &i) in idx.iter().enumerate() {
            for (b, &j) in idx.iter().enumerate() {
                pc[i * 6 + j] = self.covariance[(a, b)];
            }
        }
        for i in [2usize, 3, 4] {
            pc[i * 6 + i] = 1e-6;
        }
        let mut tc = [0.0; 36];
        for i in 0..6 {
            tc[i * 6 + i] = 1e-6;
        }
        tc[0] = self.twist_variance[0];
        tc[35] = self.twist_variance[1];
        odometry_msg(
            self.stamp,
            frame_id,
            child_frame_id,
            &self.t_odom_body,
            self.speed,
            self.yaw_rate,
            pc,
            tc,
        )
    }
}

#[allow(clippy::too_many_arguments)]
fn odometry_msg(
    stamp: Stamp,
    frame_id: &str,
    child_frame_id: &str,
    pose: &Iso2,
    speed: f64,
    yaw_rate: f64,
    pose_cov: [f64; 36],
    twist_cov: [f64; 36],
) -> Odometry {
    Odometry {
        header: Header {
            stamp: stamp.into(),
            frame_id: frame_id.into(),
        },
        child_frame_id: child_frame_id.into(),
        pose: PoseWithCovariance {
            pose: Pose::from(&iso3_from_iso2(pose)),
            covariance: pose_cov,
        },
        twist: TwistWithCovariance {
            twist: Twist {
                linear: Vector3 {
                    x: speed,
                    y: 0.0,
                    z: 0.0,
                },
                angular: Vector3 {
                    x: 0.0,
                    y: 0.0,
                    z: yaw_rate,
                },
            },
            covariance: twist_cov,
        },
    }
}

/// Offset of the slip episodes' seed from the integrator's: their own random stream.
const SLIP_SEED_OFFSET: u64 = 0x534c_4950;

/// Wheel slip episodes: each starts once a distance drawn from the exponential distribution of mean
/// `1 / slip_rate` has been driven since the previous one ended, and lasts its own duration.
#[derive(Debug)]
struct WheelSlip {
    rng: StdRng,
    /// Episodes per metre.
    rate: f64,
    slip: [f64; 2],
    duration: [f64; 2],
    /// Distance driven at which the next episode starts, m.
    next_start: f64,
    /// The current episode: its distance factor `1 + s` and end time, s.
    episode: Option<(f64, f64)>,
}

impl WheelSlip {
    /// The episodes of `cfg` (`None` when `slip_rate` is 0), from `seed`.
    fn new(cfg: &OdometrySimConfig, seed: u64) -> Option<Self> {
        (cfg.slip_rate > 0.0).then(|| {
            let mut w = WheelSlip {
                rng: StdRng::seed_from_u64(seed.wrapping_add(SLIP_SEED_OFFSET)),
                rate: cfg.slip_rate / 1000.0,
                slip: cfg.slip,
                duration: cfg.slip_duration,
                next_start: 0.0,
                episode: None,
            };
            w.next_start = w.gap();
            w
        })
    }
    /// Distance to the next episode's start, m.
    fn gap(&mut self) -> f64 {
        let x: f64 = self.rng.sample(Exp1);
        x / self.rate
    }
    /// A uniform draw in `[lo, hi]` (`lo` when the range is empty).
    fn uniform(&mut self, [lo, hi]: [f64; 2]) -> f64 {
        if hi > lo {
            self.rng.random_range(lo..=hi)
        } else {
            lo
        }
    }
    /// The distance factor at time `t` (s) after `distance` (m) driven: `1 + s` in an episode, else 1.
    fn factor(&mut self, t: f64, distance: f64) -> f64 {
        if let Some((f, end)) = self.episode {
            if t <= end {
                return f;
            }
            self.episode = None;
            self.next_start = distance + self.gap();
        }
        if distance < self.next_start {
            return 1.0;
        }
        let f = 1.0 + self.uniform(self.slip);
        let end = t + self.uniform(self.duration);
        self.episode = Some((f, end));
        f
    }
}

/// Integrates distorted ground-truth increments into drifting odometry.
#[derive(Debug)]
pub struct OdometryIntegrator {
    cfg: OdometrySimConfig,
    rng: StdRng,
    /// Wheel slip episodes (`None`: no slip).
    slip: Option<WheelSlip>,
    prev: Option<(Iso2, f64, f64)>,
    pose: Iso2,
    heading: f64,
    /// Covariance of (x, y, yaw, scale error, yaw-rate bias).
    cov: Mat5,
}

type Mat5 = nalgebra::Matrix5<f64>;

impl OdometryIntegrator {
    /// A new integrator; `seed` feeds its noise.
    pub fn new(cfg: OdometrySimConfig, seed: u64) -> Self {
        OdometryIntegrator {
            cfg,
            rng: StdRng::seed_from_u64(seed),
            slip: WheelSlip::new(&cfg, seed),
            prev: None,
            pose: Iso2::identity(),
            heading: 0.0,
            cov: Mat5::from_diagonal(&nalgebra::Vector5::new(
                0.0,
                0.0,
                0.0,
                cfg.scale_error.powi(2),
                cfg.yaw_rate_bias.powi(2),
            )),
        }
    }

    /// The next sample, from the exact ground truth at its time (`t` in seconds since the start).
    pub fn step(&mut self, stamp: Stamp, truth: &EgoState) -> OdometrySample {
        let c = self.cfg;
        let n_v: f64 = self.rng.sample::<f64, _>(StandardNormal) * c.speed_noise;
        let n_w: f64 = self.rng.sample::<f64, _>(StandardNormal) * c.yaw_rate_noise;
        let slip = self
            .slip
            .as_mut()
            .map_or(1.0, |s| s.factor(truth.t, truth.distance));
        if let Some((prev_pose, prev_heading, prev_t)) = self.prev {
            let dt = truth.t - prev_t;
            let rel = prev_pose.inverse() * truth.t_map_body;
            let dp = rel.translation.vector;
            let dist = dp.norm();
            let along = if dist > 0.0 {
                dp / dist
            } else {
                Vec2::new(1.0, 0.0)
            };
            let dp_m = (dp * (1.0 + c.scale_error) + along * (n_v * dt)) * slip;
            let dth_m = (truth.heading - prev_heading) + (c.yaw_rate_bias + n_w) * dt;
            // First-order propagation of (x, y, yaw, scale error, yaw-rate bias); the last two are unknown
            // constants, so their share of the pose covariance grows linearly with distance and time.
            let th = self.heading;
            let (sn, cs) = th.sin_cos();
            let rot = |v: Vec2| Vec2::new(cs * v.x - sn * v.y, sn * v.x + cs * v.y);
            let dw = rot(dp_m);
            let dtrue = rot(dp);
            let a = rot(along);
            let mut f = Mat5::identity();
            f[(0, 2)] = -dw.y;
            f[(1, 2)] = dw.x;
            f[(0, 3)] = dtrue.x;
            f[(1, 3)] = dtrue.y;
            f[(2, 4)] = dt;
            let q_d = (c.speed_noise * dt).powi(2);
            let q_t = (c.yaw_rate_noise * dt).powi(2);
            let mut q = Mat5::zeros();
            q[(0, 0)] = a.x * a.x * q_d;
            q[(0, 1)] = a.x * a.y * q_d;
            q[(1, 0)] = a.x * a.y * q_d;
            q[(1, 1)] = a.y * a.y * q_d;
            q[(2, 2)] = q_t;
            self.cov = f * self.cov * f.transpose() + q;
            self.pose *= Iso2::new(dp_m, dth_m);
            self.heading += dth_m;
        }
        self.prev = Some((truth.t_map_body, truth.heading, truth.t));
        OdometrySample {
            stamp,
            t_odom_body: self.pose,
            heading: self.heading,
            speed: (truth.speed * (1.0 + c.scale_error) + n_v) * slip,
            yaw_rate: truth.yaw_rate + c.yaw_rate_bias + n_w,
            covariance: self.cov.fixed_view::<3, 3>(0, 0).into_owned(),
            twist_variance: [
                (c.speed_noise.powi(2) + (c.scale_error * truth.speed).powi(2)).max(1e-9),
                (c.yaw_rate_noise.powi(2) + c.yaw_rate_bias.powi(2)).max(1e-12),
            ],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::route::LapInfo;

    const SPEED: f64 = 20.0;

    /// The ego driving along x at 20 m/s, `t` s after the start.
    fn straight(t: f64) -> EgoState {
        EgoState {
            t,
            t_map_body: Iso2::new(Vec2::new(SPEED * t, 0.0), 0.0),
            heading: 0.0,
            speed: SPEED,
            acceleration: 0.0,
            yaw_rate: 0.0,
            curvature: 0.0,
            distance: SPEED * t,
            lap: LapInfo {
                lap: 0,
                reverse: false,
                turning: false,
            },
            loop_position: 0.0,
        }
    }

    /// `seconds` of the straight drive sampled at `cfg.rate`.
    fn drive(cfg: OdometrySimConfig, seconds: f64) -> Vec<OdometrySample> {
        let mut integ = OdometryIntegrator::new(cfg, 9);
        (0..=(seconds * cfg.rate).round() as u64)
            .map(|k| {
                let t = k as f64 / cfg.rate;
                integ.step(Stamp::from_secs_f64(t), &straight(t))
            })
            .collect()
    }

    /// The runs of samples at one slipping speed: (relative extra distance, samples).
    fn episodes(odo: &[OdometrySample]) -> Vec<(f64, usize)> {
        let mut out: Vec<(f64, usize)> = Vec::new();
        let mut prev = SPEED;
        for o in odo {
            if o.speed > SPEED * (1.0 + 1e-9) {
                if o.speed == prev {
                    out.last_mut().unwrap().1 += 1;
                } else {
                    out.push((o.speed / SPEED - 1.0, 1));
                }
            }
            prev = o.speed;
        }
        out
    }

    /// 10 km at 5 slip episodes per km, otherwise perfect: each episode slips by 5 to 30 % for 0.5 to 2 s
    /// (one sample more at most), and the odometry's extra distance is what the episodes add, within the
    /// bounds the configuration implies. The heading and yaw rate are those of the run without slip.
    #[test]
    fn wheel_slip_lengthens_the_distance_by_its_episodes() {
        let cfg = OdometrySimConfig {
            slip_rate: 5.0,
            ..OdometrySimConfig::perfect()
        };
        let seconds = 500.0;
        let odo = drive(cfg, seconds);
        let eps = episodes(&odo);
        assert!((20..=80).contains(&eps.len()), "{} episodes", eps.len());
        let dt = 1.0 / cfg.rate;
        for &(s, n) in &eps {
            assert!((0.05..=0.3).contains(&s), "{s}");
            let d = n as f64 * dt;
            assert!(d >= 0.5 - 1e-9 && d <= 2.0 + dt + 1e-9, "{d}");
        }
        let extra = odo.last().unwrap().t_odom_body.translation.vector.x - SPEED * seconds;
        let from_episodes: f64 = eps.iter().map(|&(s, n)| s * SPEED * n as f64 * dt).sum();
        assert!(
            (extra - from_episodes).abs() < 1e-6,
            "{extra} vs {from_episodes}"
        );
        let n = eps.len() as f64;
        assert!(extra >= n * 0.05 * SPEED * 0.5 && extra <= n * 0.3 * SPEED * (2.0 + dt));
        // The gyro does not slip: with noise on, the headings and yaw rates match the run without slip.
        let noisy = |slip_rate| {
            drive(
                OdometrySimConfig {
                    slip_rate,
                    ..OdometrySimConfig::default()
                },
                60.0,
            )
        };
        for (a, b) in noisy(5.0).iter().zip(&noisy(0.0)) {
            assert_eq!((a.heading, a.yaw_rate), (b.heading, b.yaw_rate));
        }
    }

    /// With `slip_rate` 0 the other slip settings change nothing.
    #[test]
    fn no_slip_rate_no_slip() {
        let off = OdometrySimConfig {
            slip_rate: 0.0,
            slip: [0.5, 0.9],
            slip_duration: [5.0, 10.0],
            ..OdometrySimConfig::default()
        };
        assert_eq!(drive(off, 60.0), drive(OdometrySimConfig::default(), 60.0));
    }
}
