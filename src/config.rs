//! Configuration: one serde struct tree that mirrors the ROS 2 parameter YAML sections.
//!
//! Entry points: [`Config`] (root), [`RadarConfig`], [`FieldsConfig`]; [`Config::validate`] rejects
//! nonsense with a message naming the parameter (it never clamps).
//! Every `Default` is written by hand and documented; units are SI unless a name says otherwise.

use crate::math::{Iso3, iso3_from_xyz_rpy};
use crate::pipeline::{KeyframeConfig, LoopConfig, MapConfig};
use crate::place::PlaceConfig;
use crate::radar::RadarNoise;
use crate::radar::ego_motion::EgoMotionConfig;
use crate::registration::RegistrationConfig;
use crate::submap::{OdometryConfig, SubmapConfig};
pub use crate::validate::ConfigError;
use crate::validate::{Range, Validator};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Names of the PointCloud2 fields a radar driver publishes.
///
/// Radial velocity comes either from one scalar field (`velocity`, e.g. `v_r`, `velocity`, `doppler`) or,
/// when `velocity` is empty, from the vector components `velocity_x`, `velocity_y` in the radar frame
/// (nuScenes `vx`, `vy`), projected on the ray. An empty `z` or `rcs` means the field is not read.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
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

/// One radar: where it publishes, where it sits, and how it measures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RadarConfig {
    /// PointCloud2 topic (default `/radar/points`).
    pub topic: String,
    /// Expected `header.frame_id` (default `radar`); empty accepts any.
    pub frame_id: String,
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
            frame_id: "radar".into(),
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

/// Root of the configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Body frame id (default `base_link`).
    pub body_frame: String,
    /// Radars in use, in order; each needs an entry in `radars`.
    pub radar_names: Vec<String>,
    /// Per-radar settings by name.
    pub radars: BTreeMap<String, RadarConfig>,
    /// Odometry buffering and interpolation.
    pub odometry: OdometryConfig,
    /// Doppler ego-motion and moving-object rejection.
    pub ego_motion: EgoMotionConfig,
    /// Submap stacking.
    pub submap: SubmapConfig,
    /// Keyframe spacing.
    pub keyframe: KeyframeConfig,
    /// Revisit search and closure acceptance.
    pub r#loop: LoopConfig,
    /// Place descriptors (revisits whatever the odometry says).
    pub place: PlaceConfig,
    /// The keyframe map file.
    pub map: MapConfig,
    /// Registration (descriptors, matching, RANSAC, LM).
    pub registration: RegistrationConfig,
}

impl Default for Config {
    /// One forward radar named `front` with the paper's CARLA settings.
    fn default() -> Self {
        let mut radars = BTreeMap::new();
        radars.insert("front".to_string(), RadarConfig::default());
        Config {
            body_frame: "base_link".into(),
            radar_names: vec!["front".into()],
            radars,
            odometry: OdometryConfig::default(),
            ego_motion: EgoMotionConfig::default(),
            submap: SubmapConfig::default(),
            keyframe: KeyframeConfig::default(),
            r#loop: LoopConfig::default(),
            place: PlaceConfig::default(),
            map: MapConfig::default(),
            registration: RegistrationConfig::default(),
        }
    }
}

impl Config {
    /// The radars in `radar_names` order, with their names.
    pub fn radar_list(&self) -> Vec<(&str, &RadarConfig)> {
        self.radar_names
            .iter()
            .filter_map(|n| self.radars.get(n).map(|r| (n.as_str(), r)))
            .collect()
    }

    /// Rejects values that cannot work; the error names the parameter.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut v = Validator::new();
        self.check(&mut v);
        v.finish()
    }

    /// Every numeric parameter's range, by dotted name (radars as configured).
    pub fn ranges(&self) -> Vec<(String, Range)> {
        let mut v = Validator::describing();
        self.check(&mut v);
        v.ranges().to_vec()
    }

    /// Declares every section's ranges and rules (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.require("body_frame", !self.body_frame.is_empty(), || {
            "must not be empty".into()
        });
        v.require("radar_names", !self.radar_names.is_empty(), || {
            "at least one radar is required".into()
        });
        for (i, n) in self.radar_names.iter().enumerate() {
            v.require("radar_names", !self.radar_names[..i].contains(n), || {
                format!("`{n}` is listed twice")
            });
            match self.radars.get(n) {
                Some(r) => v.section(&format!("radars.{n}"), |v| r.check(v)),
                None => v.require(&format!("radars.{n}"), false, || {
                    "listed in radar_names but not configured".into()
                }),
            }
        }
        if let Some(extra) = self.radars.keys().find(|k| !self.radar_names.contains(k)) {
            v.require(&format!("radars.{extra}"), false, || {
                "configured but not listed in radar_names".into()
            });
        }
        v.section("odometry", |v| self.odometry.check(v));
        v.section("ego_motion", |v| self.ego_motion.check(v));
        v.section("submap", |v| self.submap.check(v));
        v.section("keyframe", |v| self.keyframe.check(v));
        v.section("loop", |v| self.r#loop.check(v));
        v.section("place", |v| self.place.check(v));
        v.section("map", |v| self.map.check(v));
        v.section("registration", |v| self.registration.check(v));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_valid() {
        Config::default().validate().unwrap();
    }

    #[test]
    fn bad_values_name_the_parameter() {
        let mut c = Config::default();
        c.radars.get_mut("front").unwrap().beta = -1.0;
        assert_eq!(c.validate().unwrap_err().name, "radars.front.beta");

        let mut c = Config::default();
        c.radar_names.push("rear".into());
        assert_eq!(c.validate().unwrap_err().name, "radars.rear");

        let mut c = Config::default();
        fn fields(c: &mut Config) -> &mut FieldsConfig {
            &mut c.radars.get_mut("front").unwrap().fields
        }
        fields(&mut c).velocity_x = "vx".into();
        assert_eq!(
            c.validate().unwrap_err().name,
            "radars.front.fields.velocity"
        );
        fields(&mut c).velocity.clear();
        assert_eq!(
            c.validate().unwrap_err().name,
            "radars.front.fields.velocity_x"
        );
        fields(&mut c).velocity_y = "vy".into();
        c.validate().unwrap();
    }
}
