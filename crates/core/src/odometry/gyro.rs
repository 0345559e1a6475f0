//! The gyro: `sensor_msgs/Imu` angular velocities turned into the body's yaw rate ([`Gyro`]), its bias
//! estimated online against the radars' Doppler yaw rate ([`GyroBias`]), and a gyro mounted other
//! than `imu.extrinsic` says detected from its persistent disagreement with that yaw rate
//! ([`FrameCheck`]).

use std::collections::VecDeque;

use super::config::ImuConfig;
use crate::math::{Mat3, Stamp, Vec3};

/// Gyro samples kept, s: a few steps of the slowest radar.
const HISTORY: f64 = 2.0;
/// A gap between samples longer than this is no coverage, s.
const MAX_GAP: f64 = 0.1;

/// Counters of the gyro's input.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GyroCounts {
    /// Samples taken.
    pub samples: u64,
    /// Samples with an axis at the measuring range (`imu.gyro_range`), dropped.
    pub saturated: u64,
    /// Samples stamped before the newest one, dropped.
    pub out_of_order: u64,
    /// Samples with a non-finite value, dropped.
    pub non_finite: u64,
}

/// The body's yaw rate as a gyro measures it, sample by sample (bias not removed).
#[derive(Debug, Clone)]
pub struct Gyro {
    r_body_imu: Mat3,
    range: f64,
    samples: VecDeque<(Stamp, f64)>,
    /// What happened to the samples.
    pub counts: GyroCounts,
}

impl Gyro {
    /// A gyro mounted as `cfg.extrinsic` says.
    pub fn new(cfg: &ImuConfig) -> Self {
        Gyro {
            r_body_imu: cfg.t_body_imu().rotation.to_rotation_matrix().into_inner(),
            range: cfg.gyro_range,
            samples: VecDeque::new(),
            counts: GyroCounts::default(),
        }
    }

    /// Takes one angular velocity (IMU frame, rad/s); saturated, non-finite and out-of-order
    /// samples are counted and dropped.
    pub fn push(&mut self, stamp: Stamp, angular_velocity: Vec3) {
        if !angular_velocity.iter().all(|w| w.is_finite()) {
            self.counts.non_finite += 1;
            return;
        }
        if angular_velocity.amax() >= self.range {
            self.counts.saturated += 1;
            return;
        }
        if self.samples.back().is_some_and(|&(t, _)| stamp <= t) {
            self.counts.out_of_order += 1;
            return;
        }
        self.counts.samples += 1;
        let yaw_rate = (self.r_body_imu * angular_velocity).z;
        self.samples.push_back((stamp, yaw_rate));
        while self
            .samples
            .front()
            .is_some_and(|&(t, _)| stamp.secs_since(t) > HISTORY)
        {
            self.samples.pop_front();
        }
    }

    /// Forgets every sample (after time went backwards).
    pub fn clear(&mut self) {
        self.samples.clear();
    }

    /// The mean yaw rate over `[t0, t1]` (trapezoids between samples, the nearest sample held at the
    /// ends), or `None` when the samples do not cover the interval (a gap over 0.1 s, or none near
    /// an end).
    pub fn mean_rate(&self, t0: Stamp, t1: Stamp) -> Option<f64> {
        let near = |t: Stamp| {
            self.samples
                .iter()
                .any(|&(s, _)| s.secs_since(t).abs() <= MAX_GAP)
        };
        if t1 <= t0 || !near(t0) || !near(t1) {
            return None;
        }
        let rate_at = |t: Stamp| -> f64 {
            let i = self.samples.partition_point(|&(s, _)| s <= t);
            match (
                i.checked_sub(1).map(|j| self.samples[j]),
                self.samples.get(i),
            ) {
                (Some(a), Some(b)) => {
                    let f = t.secs_since(a.0) / b.0.secs_since(a.0);
                    a.1 + f * (b.1 - a.1)
                }
                (Some(a), None) => a.1,
                (None, Some(b)) => b.1,
                (None, None) => 0.0,
            }
        };
        let mut knots = vec![(t0, rate_at(t0))];
        let inside = self.samples.iter().filter(|&&(s, _)| s > t0 && s < t1);
        let mut last = t0;
        for &(s, w) in inside {
            if s.secs_since(last) > MAX_GAP {
                return None;
            }
            knots.push((s, w));
            last = s;
        }
        if t1.secs_since(last) > MAX_GAP {
            return None;
        }
        knots.push((t1, rate_at(t1)));
        let area: f64 = knots
            .windows(2)
            .map(|k| 0.5 * (k[0].1 + k[1].1) * k[1].0.secs_since(k[0].0))
            .sum();
        Some(area / t1.secs_since(t0))
    }
}

/// A scalar Kalman filter on the gyro's yaw-rate bias: a random walk, measured by the difference of
/// the gyro's mean rate and the radars' Doppler yaw rate over the same interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GyroBias {
    /// The estimate, rad/s.
    pub bias: f64,
    /// Its variance, (rad/s)^2.
    pub variance: f64,
    walk: f64,
    /// Updates taken.
    pub updates: u64,
    /// Updates refused by the gate (more than 4 standard deviations off).
    pub outliers: u64,
}

impl GyroBias {
    /// The prior: zero bias with `imu.gyro_bias_sigma`.
    pub fn new(cfg: &ImuConfig) -> Self {
        GyroBias {
            bias: 0.0,
            variance: cfg.gyro_bias_sigma.powi(2),
            walk: cfg.gyro_bias_walk,
            updates: 0,
            outliers: 0,
        }
    }

    /// Lets `dt` seconds of random walk pass.
    pub fn predict(&mut self, dt: f64) {
        self.variance += self.walk.powi(2) * dt.max(0.0);
    }

    /// Takes `z = gyro mean - Doppler yaw rate` with variance `r`; returns its normalised innovation
    /// squared (refused above 16).
    pub fn update(&mut self, z: f64, r: f64) -> f64 {
        let s = self.variance + r;
        let innovation = z - self.bias;
        let nis = innovation * innovation / s;
        if nis > 16.0 {
            self.outliers += 1;
            return nis;
        }
        let k = self.variance / s;
        self.bias += k * innovation;
        self.variance *= 1.0 - k;
        self.updates += 1;
        nis
    }
}

/// Pairs kept to judge the gyro's frame.
const FRAME_WINDOW: usize = 200;
/// Spread of the Doppler yaw rate over the window that makes a slope meaningful, rad/s (turns).
const MIN_SPREAD: f64 = 0.05;
/// Slope of the gyro's rate on the Doppler's beyond which the gyro is not measuring the body's yaw.
const MAX_SLOPE_ERROR: f64 = 0.3;

/// Detects a gyro whose body-frame z axis is not the body's: the least-squares slope of its rate on
/// the Doppler yaw rate, over the last pairs, is far from 1 (-1: upside down; 0: the axis lies in
/// the plane).
#[derive(Debug, Clone, Default)]
pub struct FrameCheck {
    pairs: VecDeque<(f64, f64)>,
    /// The slope once the gyro was found in the wrong frame.
    pub wrong_frame: Option<f64>,
}

impl FrameCheck {
    /// Takes one pair `(Doppler yaw rate, gyro mean rate)`; returns the slope when it first shows
    /// the gyro in the wrong frame.
    pub fn observe(&mut self, doppler: f64, gyro: f64) -> Option<f64> {
        self.pairs.push_back((doppler, gyro));
        if self.pairs.len() > FRAME_WINDOW {
            self.pairs.pop_front();
        }
        if self.wrong_frame.is_some() || self.pairs.len() < FRAME_WINDOW {
            return None;
        }
        let n = self.pairs.len() as f64;
        let (mx, my) = self
            .pairs
            .iter()
            .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / n, b + y / n));
        let (sxx, sxy) = self.pairs.iter().fold((0.0, 0.0), |(a, b), (x, y)| {
            (a + (x - mx).powi(2), b + (x - mx) * (y - my))
        });
        if (sxx / n).sqrt() < MIN_SPREAD {
            return None;
        }
        let slope = sxy / sxx;
        if (slope - 1.0).abs() > MAX_SLOPE_ERROR {
            self.wrong_frame = Some(slope);
            return Some(slope);
        }
        None
    }
}

/// What a slope of the gyro's rate on the Doppler's says about the mounting.
pub fn frame_advice(slope: f64) -> String {
    let hint = if slope < -0.5 {
        "its z axis points down: check the roll or pitch of imu.extrinsic (off by 180 degrees?)"
    } else if slope.abs() <= 0.5 {
        "its z axis lies near the horizontal: check the roll and pitch of imu.extrinsic"
    } else {
        "its scale is off: check the IMU driver's units (deg/s for rad/s?)"
    };
    format!(
        "the gyro's yaw rate is {slope:.2} times the radars' Doppler yaw rate: {hint}; the gyro is no longer used"
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand::rngs::StdRng;
    use rand_distr::{Distribution, Normal};

    fn at(t: f64) -> Stamp {
        Stamp::from_secs_f64(100.0 + t)
    }

    /// A gyro mounted upside down (roll pi) reports the body's yaw rate negated until the extrinsic
    /// says so; saturated, out-of-order and non-finite samples are counted and dropped; the mean over
    /// an interval integrates a ramp exactly.
    #[test]
    fn samples_turn_into_the_body_yaw_rate() {
        let flipped = ImuConfig {
            extrinsic: [0.0, 0.0, 0.0, std::f64::consts::PI, 0.0, 0.0],
            ..ImuConfig::default()
        };
        let mut g = Gyro::new(&flipped);
        for k in 0..=100 {
            let t = k as f64 * 0.01;
            g.push(at(t), Vec3::new(0.0, 0.0, -(0.1 + 0.2 * t)));
        }
        let mean = g.mean_rate(at(0.2), at(0.6)).unwrap();
        assert!((mean - (0.1 + 0.2 * 0.4)).abs() < 1e-9, "{mean}");
        g.push(at(0.5), Vec3::zeros());
        g.push(at(1.1), Vec3::new(0.0, 20.0, 0.0));
        g.push(at(1.2), Vec3::new(f64::NAN, 0.0, 0.0));
        let c = g.counts;
        assert_eq!(
            (c.samples, c.out_of_order, c.saturated, c.non_finite),
            (101, 1, 1, 1)
        );
        assert!(
            g.mean_rate(at(0.9), at(1.3)).is_none(),
            "no sample near the end"
        );
    }

    /// The bias filter, fed the gyro-minus-Doppler differences of a drive with a 0.02 rad/s bias,
    /// converges to it within three of its standard deviations, which shrink below 2e-3 rad/s.
    #[test]
    fn the_bias_converges_to_the_true_bias() {
        let cfg = ImuConfig::default();
        let mut f = GyroBias::new(&cfg);
        let mut rng = StdRng::seed_from_u64(9);
        let doppler_sigma = 0.01;
        let noise = Normal::new(
            0.0,
            (doppler_sigma * doppler_sigma + 0.003f64.powi(2) / 0.077).sqrt(),
        )
        .unwrap();
        for _ in 0..2000 {
            f.predict(0.077);
            let z = 0.02 + noise.sample(&mut rng);
            f.update(z, doppler_sigma.powi(2) + 0.003f64.powi(2) / 0.077);
        }
        let sigma = f.variance.sqrt();
        assert!(sigma < 2e-3, "sigma {sigma}");
        assert!(
            (f.bias - 0.02).abs() < 3.0 * sigma,
            "bias {} +- {sigma}",
            f.bias
        );
    }

    /// A gyro that reads the yaw rate negated is found once the body has turned both ways; one
    /// that reads it right is not.
    #[test]
    fn a_gyro_in_the_wrong_frame_is_found() {
        let mut right = FrameCheck::default();
        let mut wrong = FrameCheck::default();
        let mut found = None;
        for k in 0..400 {
            let w = 0.3 * (k as f64 * 0.05).sin();
            assert!(right.observe(w, w + 0.01).is_none());
            if let Some(s) = wrong.observe(w, -w) {
                found = Some((k, s));
            }
        }
        let (k, slope) = found.expect("found");
        assert!(k < FRAME_WINDOW + 1 && (slope + 1.0).abs() < 1e-9);
        assert!(frame_advice(slope).contains("points down"));
    }
}
