//! A simulated gyro: the body's yaw rate measured with a bias that wanders and white noise, at its
//! own rate ([`simulate_imu`]). The IMU frame is the body frame. Off by default (`rate` 0), so that
//! drives without it are unchanged.

use crate::sim::config::ImuSimConfig;
use crate::sim::route::Trajectory;
use dc_loc_core::math::{Stamp, Vec3};
use dc_loc_core::msgs::geometry_msgs::{Quaternion, Vector3};
use dc_loc_core::msgs::sensor_msgs::Imu;
use dc_loc_core::msgs::std_msgs::Header;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};

/// One gyro sample with its truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Its stamp.
    pub stamp: Stamp,
    /// Measured angular velocity, IMU (= body) frame, rad/s.
    pub angular_velocity: Vec3,
    /// The bias it carries, rad/s.
    pub bias: f64,
}

impl ImuSample {
    /// The sample as a gyro-only `sensor_msgs/Imu` in `frame_id`: no orientation (its covariance's
    /// first element -1, as the message asks), the angular velocity with the white noise's variance on
    /// the diagonal (`sigma^2`, rad^2/s^2, `0` when unknown), no acceleration (first element -1).
    pub fn to_msg(&self, frame_id: &str, sigma: f64) -> Imu {
        let w = self.angular_velocity;
        let unknown = {
            let mut c = [0.0; 9];
            c[0] = -1.0;
            c
        };
        let var = sigma * sigma;
        Imu {
            header: Header {
                stamp: self.stamp.into(),
                frame_id: frame_id.to_string(),
            },
            orientation: Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            },
            orientation_covariance: unknown,
            angular_velocity: Vector3 {
                x: w.x,
                y: w.y,
                z: w.z,
            },
            angular_velocity_covariance: [var, 0.0, 0.0, 0.0, var, 0.0, 0.0, 0.0, var],
            linear_acceleration: Vector3::default(),
            linear_acceleration_covariance: unknown,
        }
    }
}

/// The gyro's samples over the drive, from `start`, drawn from the random stream `seed`.
pub fn simulate_imu(
    cfg: &ImuSimConfig,
    trajectory: &Trajectory,
    start: Stamp,
    seed: u64,
) -> Vec<ImuSample> {
    if cfg.rate <= 0.0 {
        return Vec::new();
    }
    let mut rng = StdRng::seed_from_u64(seed);
    let dt = 1.0 / cfg.rate;
    let sigma = cfg.noise_density * cfg.rate.sqrt();
    let mut bias = cfg.bias;
    let mut out = Vec::new();
    for k in 0.. {
        let t = k as f64 * dt;
        if t > trajectory.duration() {
            break;
        }
        if k > 0 {
            let n: f64 = StandardNormal.sample(&mut rng);
            bias += cfg.bias_walk * dt.sqrt() * n;
        }
        let n: f64 = StandardNormal.sample(&mut rng);
        let yaw_rate = trajectory.state(t).yaw_rate + bias + sigma * n;
        out.push(ImuSample {
            stamp: Stamp(start.0 + (t * 1e9).round() as i64),
            angular_velocity: Vec3::new(0.0, 0.0, yaw_rate),
            bias,
        });
    }
    out
}
