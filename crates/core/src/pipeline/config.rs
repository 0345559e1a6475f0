//! The pipeline's configuration: one serde struct tree that mirrors the ROS 2 parameter YAML sections
//! ([`Config`]), each section's struct living with the module that uses it, and the keyframe spacing
//! ([`KeyframeConfig`]). [`Config::validate`] rejects nonsense with a message naming the parameter (it
//! never clamps). Every `Default` is written by hand; units are SI unless a name says otherwise.

use crate::keyframe_db::{MapConfig, MapShape, RadarMount};
use crate::loop_closure::LoopConfig;
use crate::math::Iso3;
use crate::odometry::{ImuConfig, OdometrySource};
use crate::place::PlaceConfig;
use crate::radar::RadarConfig;
use crate::radar::ego_motion::EgoMotionConfig;
use crate::registration::RegistrationConfig;
use crate::submap::{OdometryConfig, SubmapConfig};
use crate::validate::{ConfigError, Range, Validator};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// When a new keyframe is taken.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct KeyframeConfig {
    /// Odometry distance travelled since the last keyframe, m (default 5.0).
    pub distance: f64,
    /// Odometry heading change since the last keyframe, rad (default 0.5).
    pub angle: f64,
    /// Fewest submap points for a keyframe (default 50).
    pub min_points: usize,
}

impl Default for KeyframeConfig {
    fn default() -> Self {
        KeyframeConfig {
            distance: 5.0,
            angle: 0.5,
            min_points: 50,
        }
    }
}

impl KeyframeConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.positive("distance", self.distance);
        v.positive("angle", self.angle);
        v.at_least("min_points", self.min_points, 10);
    }
}

/// Root of the configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Body frame id (default `base_link`).
    pub body_frame: String,
    /// Radars in use, in order; each needs an entry in `radars`.
    pub radar_names: Vec<String>,
    /// Per-radar settings by name.
    pub radars: BTreeMap<String, RadarConfig>,
    /// Odometry: its source, buffering and interpolation.
    pub odometry: OdometryConfig,
    /// The gyro read with `odometry.source: radar_imu`.
    pub imu: ImuConfig,
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
            imu: ImuConfig::default(),
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

    /// Per radar (in `radar_names` order): its trigger delay when it takes its stamps from a trigger
    /// topic ([`crate::radar::trigger`]).
    pub fn trigger_delays(&self) -> Vec<Option<f64>> {
        self.radar_names
            .iter()
            .map(|n| {
                self.radars
                    .get(n)
                    .filter(|r| !r.trigger_topic.is_empty())
                    .map(|r| r.trigger_delay)
            })
            .collect()
    }

    /// Where the body pose comes from, as a log line says it (`odometry.source`).
    pub fn pose_input(&self) -> String {
        match self.odometry.source {
            OdometrySource::Topic => format!("odometry on {}", self.odometry.topic),
            OdometrySource::Radar => "odometry from the radars' Doppler".into(),
            OdometrySource::RadarImu => format!(
                "odometry from the radars' Doppler and the gyro on {}",
                self.imu.topic
            ),
        }
    }

    /// The radars' frame ids (the child frames their extrinsics are transforms to), those set, each
    /// once (radars may share a frame).
    pub fn radar_frames(&self) -> Vec<String> {
        let mut frames: Vec<String> = self
            .radar_list()
            .iter()
            .map(|(_, r)| r.frame_id.clone())
            .filter(|f| !f.is_empty())
            .collect();
        frames.sort();
        frames.dedup();
        frames
    }

    /// Replaces the extrinsic of each radar whose frame id `found` has (`body_frame -> frame_id`
    /// transforms), logging each one with `source`; returns the names of the radars it set.
    pub fn set_extrinsics(&mut self, found: &BTreeMap<String, Iso3>, source: &str) -> Vec<String> {
        let mut set = Vec::new();
        for (name, r) in self.radars.iter_mut() {
            let Some(t) = found.get(&r.frame_id) else {
                continue;
            };
            let (roll, pitch, yaw) = t.rotation.euler_angles();
            let v = &t.translation.vector;
            r.extrinsic = [v.x, v.y, v.z, roll, pitch, yaw];
            log::info!(
                "radar {name}: extrinsic from {source} ({} -> {}): {:?}",
                self.body_frame,
                r.frame_id,
                r.extrinsic
            );
            set.push(name.clone());
        }
        set
    }

    /// The settings that shape the keyframes of a map (stored with it).
    pub fn map_shape(&self) -> MapShape {
        MapShape {
            body_frame: self.body_frame.clone(),
            radars: self
                .radar_list()
                .into_iter()
                .map(|(name, r)| RadarMount {
                    name: name.to_string(),
                    extrinsic: r.extrinsic,
                    beta: r.beta,
                })
                .collect(),
            max_points_per_keyframe: self.map.max_points_per_keyframe,
            place: self.place.clone(),
        }
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
                Some(r) => {
                    v.section(&format!("radars.{n}"), |v| r.check(v));
                    // One DDS topic carries one type.
                    let clash = self.radar_names[..i]
                        .iter()
                        .filter_map(|m| self.radars.get(m).map(|o| (m, o)))
                        .find(|(_, o)| o.topic == r.topic && o.message != r.message);
                    v.require(&format!("radars.{n}.message"), clash.is_none(), || {
                        format!(
                            "radar `{}` on the same topic `{}` has another message type",
                            clash.map_or("", |c| c.0.as_str()),
                            r.topic
                        )
                    });
                }
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
        v.section("imu", |v| self.imu.check(v));
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
    use crate::radar::FieldsConfig;

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
