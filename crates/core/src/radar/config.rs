//! One radar's settings (`radars.<name>.*`): where it publishes, where it sits, how it measures, and
//! the names of its PointCloud2 fields.

use crate::math::{Iso3, iso3_from_xyz_rpy};
use crate::radar::RadarNoise;
use crate::validate::{Range, Validator};
use serde::{Deserialize, Serialize};

/// Names of the PointCloud2 fields a radar driver publishes.
///
/// Radial velocity comes either from one scalar field (`velocity`, e.g. `v_r`, `velocity`, `doppler`) or,
/// when `velocity` is empty, from the vector components `velocity_x`, `velocity_y` in the radar frame
/// (nuScenes `vx`, `vy`), projected on the ray. An empty `z` or `rcs` means the field is not read.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct FieldsConfig {
    /// x coordinate field (default `x`).
    pub x: String,
    /// y coordinate field (default `y`).
    pub y: String,
    /// z coordinate field (default `z`; empty = 0).
    pub z: String,
    /// Scalar radial velocity field (default `v_r`; empty = use `velocity_x`/`velocity_y`).
    pub velocity: String,
    /// Radial velocity vector, x component (default empty).
    pub velocity_x: String,
    /// Radial velocity vector, y component (default empty).
    pub velocity_y: String,
    /// Radar cross-section field (default `rcs`; empty = not read; optional in the cloud).
    pub rcs: String,
}

impl Default for FieldsConfig {
    fn default() -> Self {
        FieldsConfig {
            x: "x".into(),
            y: "y".into(),
            z: "z".into(),
            velocity: "v_r".into(),
            velocity_x: String::new(),
            velocity_y: String::new(),
            rcs: "rcs".into(),
        }
    }
}

/// The message type a radar publishes.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
pub enum RadarMessage {
    /// `sensor_msgs/PointCloud2`, read through `fields`.
    #[default]
    #[serde(rename = "pointcloud2")]
    PointCloud2,
    /// `radar_msgs/RadarScan`: range, azimuth, elevation, doppler_velocity per return (`fields` unused;
    /// `doppler_velocity` read as the radial velocity, positive away).
    #[serde(rename = "radar_scan")]
    RadarScan,
}

/// One radar: where it publishes, where it sits, and how it measures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RadarConfig {
    /// Topic (default `/radar/points`).
    pub topic: String,
    /// Message type on `topic`: `pointcloud2` (default) or `radar_scan` (`radar_msgs/RadarScan`).
    pub message: RadarMessage,
    /// Expected `header.frame_id` (default `radar`); empty accepts any.
    pub frame_id: String,
    /// A `std_msgs/Header` topic published at the start of each of the radar's frames (default
    /// empty: none). When set, each scan takes the stamp of the newest trigger that arrived before
    /// it plus `trigger_delay`, in place of its own: for drivers that stamp their clouds with zero
    /// or with another clock than the IMU's. A scan with no new trigger is dropped (`no_trigger`).
    pub trigger_topic: String,
    /// Time from a trigger to the instant its scan stands for, s (default 0; half the frame's chirp
    /// time puts it mid-frame).
    pub trigger_delay: f64,
    /// Radar frame in the body frame: x, y, z (m), roll, pitch, yaw (rad). Default: 0.
    pub extrinsic: [f64; 6],
    /// Doppler range coupling `beta = f_c / K`, s (default 0.04, the ARS408-21 per the paper).
    pub beta: f64,
    /// Field names.
    pub fields: FieldsConfig,
    /// Range noise standard deviation, m (default 0.25).
    pub sigma_range: f64,
    /// Radial velocity noise standard deviation, m/s (default 0.1).
    pub sigma_velocity: f64,
    /// Azimuth noise standard deviation, rad (default 0.5 deg).
    pub sigma_azimuth: f64,
}

impl Default for RadarConfig {
    fn default() -> Self {
        let noise = RadarNoise::default();
        RadarConfig {
            topic: "/radar/points".into(),
            message: RadarMessage::PointCloud2,
            frame_id: "radar".into(),
            trigger_topic: String::new(),
            trigger_delay: 0.0,
            extrinsic: [0.0; 6],
            beta: 0.04,
            fields: FieldsConfig::default(),
            sigma_range: noise.sigma_range,
            sigma_velocity: noise.sigma_velocity,
            sigma_azimuth: noise.sigma_azimuth,
        }
    }
}

impl RadarConfig {
    /// The radar's pose in the body frame, `t_body_radar`.
    pub fn t_body_radar(&self) -> Iso3 {
        let [x, y, z, roll, pitch, yaw] = self.extrinsic;
        iso3_from_xyz_rpy(x, y, z, roll, pitch, yaw)
    }
    /// The polar noise model.
    pub fn noise(&self) -> RadarNoise {
        RadarNoise {
            sigma_range: self.sigma_range,
            sigma_velocity: self.sigma_velocity,
            sigma_azimuth: self.sigma_azimuth,
        }
    }

    /// Declares each field's range and rule (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.require("topic", !self.topic.is_empty(), || {
            "must not be empty".into()
        });
        let bad = self.extrinsic.iter().position(|x| !x.is_finite());
        v.require("extrinsic", bad.is_none(), || {
            format!("element {} is not finite", bad.unwrap_or_default())
        });
        v.range("beta", self.beta, Range::NON_NEGATIVE.below(1.0));
        v.range(
            "trigger_delay",
            self.trigger_delay,
            Range::NON_NEGATIVE.below(1.0),
        );
        v.positive("sigma_range", self.sigma_range);
        v.positive("sigma_velocity", self.sigma_velocity);
        v.positive("sigma_azimuth", self.sigma_azimuth);
        v.section("fields", |v| self.fields.check(v));
    }
}

impl FieldsConfig {
    /// Coordinates are required, and the radial velocity as one scalar field or as a vector.
    pub fn check(&self, v: &mut Validator) {
        v.require("x", !self.x.is_empty() && !self.y.is_empty(), || {
            "x and y field names are required".into()
        });
        let scalar = !self.velocity.is_empty();
        let vector = !self.velocity_x.is_empty() || !self.velocity_y.is_empty();
        v.require("velocity", !(scalar && vector), || {
            "give either a scalar `velocity` field or `velocity_x`/`velocity_y`, not both".into()
        });
        v.require("velocity", scalar || vector, || {
            "a radial velocity field is required (`velocity`, or `velocity_x` and `velocity_y`)"
                .into()
        });
        v.require(
            "velocity_x",
            scalar || !vector || !(self.velocity_x.is_empty() || self.velocity_y.is_empty()),
            || "both `velocity_x` and `velocity_y` are needed".into(),
        );
    }
}
