//! Where the pipeline's odometry comes from ([`OdometrySource`]) and the settings of the estimator
//! that reads a gyro ([`ImuConfig`]); the rest of `odometry.*` is [`crate::submap::OdometryConfig`].

use crate::math::{Iso3, iso3_from_xyz_rpy};
use crate::validate::{Range, Validator};
use serde::{Deserialize, Serialize};

/// Where the body pose the submaps and the revisit search use comes from (`odometry.source`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum OdometrySource {
    /// `nav_msgs/Odometry` on `odometry.topic`.
    #[default]
    Topic,
    /// The planar ego-motion fitted from every radar's static detections (two or more radars mounted
    /// apart, or one with `odometry.lateral_velocity_sigma`).
    Radar,
    /// The radars' velocity and the yaw rate of a `sensor_msgs/Imu` gyro on `imu.topic`.
    RadarImu,
}

impl OdometrySource {
    /// The parameter value (`topic`, `radar`, `radar_imu`).
    pub fn name(self) -> &'static str {
        match self {
            OdometrySource::Topic => "topic",
            OdometrySource::Radar => "radar",
            OdometrySource::RadarImu => "radar_imu",
        }
    }
}

/// The gyro (`imu.*`): its topic, its mounting and its noise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ImuConfig {
    /// `sensor_msgs/Imu` topic (default `/imu`), read with `odometry.source: radar_imu`.
    pub topic: String,
    /// Pose of the IMU frame in the body frame, `[x, y, z, roll, pitch, yaw]` (m, rad; default
    /// identity). Only its rotation matters: the yaw rate is the same everywhere on a rigid body.
    pub extrinsic: [f64; 6],
    /// White noise density of each gyro axis, rad/s/sqrt(Hz) (default 0.003, about 0.17 deg/s at
    /// 100 Hz: a consumer MEMS gyro).
    pub gyro_noise_density: f64,
    /// Random walk of the gyro bias, rad/s/sqrt(s) (default 1e-4).
    pub gyro_bias_walk: f64,
    /// Standard deviation of the gyro bias before any estimate, rad/s (default 0.005, about 0.3 deg/s).
    pub gyro_bias_sigma: f64,
    /// The gyro's measuring range, rad/s (default 8.7, 500 deg/s): a sample at it is saturated.
    pub gyro_range: f64,
}

impl Default for ImuConfig {
    fn default() -> Self {
        ImuConfig {
            topic: "/imu".into(),
            extrinsic: [0.0; 6],
            gyro_noise_density: 0.003,
            gyro_bias_walk: 1e-4,
            gyro_bias_sigma: 0.005,
            gyro_range: 500f64.to_radians(),
        }
    }
}

impl ImuConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.require("topic", !self.topic.is_empty(), || {
            "must not be empty".into()
        });
        let bad = self.extrinsic.iter().position(|x| !x.is_finite());
        v.require("extrinsic", bad.is_none(), || {
            "six finite values [x, y, z, roll, pitch, yaw]".into()
        });
        v.positive("gyro_noise_density", self.gyro_noise_density);
        v.non_negative("gyro_bias_walk", self.gyro_bias_walk);
        v.positive("gyro_bias_sigma", self.gyro_bias_sigma);
        v.range("gyro_range", self.gyro_range, Range::POSITIVE);
    }

    /// `t_body_imu`.
    pub fn t_body_imu(&self) -> Iso3 {
        let [x, y, z, roll, pitch, yaw] = self.extrinsic;
        iso3_from_xyz_rpy(x, y, z, roll, pitch, yaw)
    }
}
