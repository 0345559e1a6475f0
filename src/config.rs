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
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// A configuration value that cannot be used, with the dotted parameter name.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid parameter `{name}`: {reason}")]
pub struct ConfigError {
    /// Dotted parameter name, as in the params YAML (e.g. `radars.front.beta`).
    pub name: String,
    /// What is wrong with it.
    pub reason: String,
}

impl ConfigError {
    /// Shorthand constructor.
    pub fn new(name: impl Into<String>, reason: impl Into<String>) -> Self {
        ConfigError {
            name: name.into(),
            reason: reason.into(),
        }
    }
}

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

    fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        let name = |f: &str| format!("{prefix}.{f}");
        if self.topic.is_empty() {
            return Err(ConfigError::new(name("topic"), "must not be empty"));
        }
        if let Some(i) = self.extrinsic.iter().position(|v| !v.is_finite()) {
            return Err(ConfigError::new(
                name("extrinsic"),
                format!("element {i} is not finite"),
            ));
        }
        if !(self.beta.is_finite() && self.beta >= 0.0 && self.beta < 1.0) {
            return Err(ConfigError::new(
                name("beta"),
                format!("{} is not in [0, 1) s", self.beta),
            ));
        }
        for (f, v) in [
            ("sigma_range", self.sigma_range),
            ("sigma_velocity", self.sigma_velocity),
            ("sigma_azimuth", self.sigma_azimuth),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(ConfigError::new(
                    name(f),
                    format!("{v} must be finite and > 0"),
                ));
            }
        }
        let fl = &self.fields;
        if fl.x.is_empty() || fl.y.is_empty() {
            return Err(ConfigError::new(
                name("fields.x/y"),
                "x and y field names are required",
            ));
        }
        let vector = !fl.velocity_x.is_empty() || !fl.velocity_y.is_empty();
        match (fl.velocity.is_empty(), vector) {
            (false, true) => {
                return Err(ConfigError::new(
                    name("fields.velocity"),
                    "give either a scalar `velocity` field or `velocity_x`/`velocity_y`, not both",
                ));
            }
            (true, false) => {
                return Err(ConfigError::new(
                    name("fields.velocity"),
                    "a radial velocity field is required (`velocity`, or `velocity_x` and `velocity_y`)",
                ));
            }
            (true, true) if fl.velocity_x.is_empty() || fl.velocity_y.is_empty() => {
                return Err(ConfigError::new(
                    name("fields.velocity_x"),
                    "both `velocity_x` and `velocity_y` are needed",
                ));
            }
            _ => {}
        }
        Ok(())
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
        if self.body_frame.is_empty() {
            return Err(ConfigError::new("body_frame", "must not be empty"));
        }
        if self.radar_names.is_empty() {
            return Err(ConfigError::new(
                "radar_names",
                "at least one radar is required",
            ));
        }
        for (i, n) in self.radar_names.iter().enumerate() {
            if self.radar_names[..i].contains(n) {
                return Err(ConfigError::new(
                    "radar_names",
                    format!("`{n}` is listed twice"),
                ));
            }
            let Some(r) = self.radars.get(n) else {
                return Err(ConfigError::new(
                    format!("radars.{n}"),
                    "listed in radar_names but not configured",
                ));
            };
            r.validate(&format!("radars.{n}"))?;
        }
        if let Some(extra) = self.radars.keys().find(|k| !self.radar_names.contains(k)) {
            return Err(ConfigError::new(
                format!("radars.{extra}"),
                "configured but not listed in radar_names",
            ));
        }
        self.odometry.validate("odometry")?;
        self.ego_motion.validate("ego_motion")?;
        self.submap.validate("submap")?;
        self.keyframe.validate("keyframe")?;
        self.r#loop.validate("loop")?;
        self.place.validate("place")?;
        self.map.validate("map")?;
        self.registration.validate()
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
