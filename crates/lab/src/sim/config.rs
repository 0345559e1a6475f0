//! Simulator configuration: one serde tree, every `Default` written by hand, `validate()` names the field.
//!
//! Entry points: [`SimConfig`] (root) and its sections [`LapConfig`], [`DriveConfig`], [`RouteConfig`],
//! [`WorldConfig`], [`SimRadarConfig`] (with the presets of [`RadarPreset`]), [`NoiseConfig`],
//! [`OdometrySimConfig`].
//! Units are SI (m, s, rad, m/s); RCS values are in dBsm. Parameters that are probabilities are in [0, 1].

use crate::sim::noise::{NoiseConfig, NoiseModel};
use crate::sim::radar_config::{RadarPreset, SimRadarConfig};
use crate::sim::world_config::WorldConfig;
use dc_loc_core::math::Vec2;
use dc_loc_core::pipeline::Config;
use dc_loc_core::radar::{FieldsConfig, RadarConfig, RadarMessage};
use dc_loc_core::validate::{ConfigError, Range, Validator};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Root of the simulator configuration.
///
/// The default world (seed 1): a 2.11 km road loop (2.14 km driven in the outer lane) with 7 corners of
/// 15 to 150 m radius, 5 junctions and 9 side streets, inside a 920 x 600 m city of about 880 wall
/// segments, 550 poles, trunks and building corners, 100 bushes, 340 parked cars (over both laps) and
/// 60 road users. Lap 1 (72 km/h cruise) takes 131 s at a mean 59 km/h, lap 2 (40 km/h) 195 s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Seed of every random choice (world, traffic, detections, noise, odometry). Default 1.
    pub seed: u64,
    /// Which robot of a fleet drives (default 0): robots sharing a `seed` drive one world, each with
    /// detection, stamp and odometry noise of its own.
    pub robot: u32,
    /// Time of the first sample, s since the Unix epoch (default 1_700_000_000, so bag times look real).
    pub start_time: f64,
    /// The laps, in driving order (default: 72 km/h, then 40 km/h, both forward, as the paper's CARLA
    /// drives); 1 to 64 laps. A change of direction between two laps inserts a U-turn at the lap start.
    /// A slower lap slows down after its lap line, so its first tens of metres run faster.
    pub laps: Vec<LapConfig>,
    /// Vehicle dynamics limits.
    pub drive: DriveConfig,
    /// Road loop geometry.
    pub route: RouteConfig,
    /// What stands along the road.
    pub world: WorldConfig,
    /// Which radar set to simulate (default `carla`); `custom` uses `radars`.
    pub radar_preset: RadarPreset,
    /// The radars when `radar_preset` is `custom` (must be empty otherwise). Default empty.
    pub radars: Vec<SimRadarConfig>,
    /// Measurement noise of all radars.
    pub noise: NoiseConfig,
    /// Wheel/gyro odometry error model.
    pub odometry: OdometrySimConfig,
    /// The gyro (default: none).
    pub imu: ImuSimConfig,
    /// Ground-truth pose rate, Hz (default 50).
    pub ground_truth_rate: f64,
    /// Map frame id of the ground truth (default `map`).
    pub map_frame: String,
    /// Odometry frame id (default `odom`).
    pub odom_frame: String,
    /// Body frame id (default `base_link`).
    pub body_frame: String,
}

impl Default for SimConfig {
    /// The paper's CARLA experiment: one forward radar (100 m, 150 deg, 13 Hz, beta 0.04 s), Gaussian noise,
    /// one lap at 72 km/h then one at 40 km/h around a 2.2 km city loop, 1 % odometry scale error.
    fn default() -> Self {
        SimConfig {
            seed: 1,
            robot: 0,
            start_time: 1_700_000_000.0,
            laps: vec![
                LapConfig {
                    speed: 72.0 / 3.6,
                    reverse: false,
                },
                LapConfig {
                    speed: 40.0 / 3.6,
                    reverse: false,
                },
            ],
            drive: DriveConfig::default(),
            route: RouteConfig::default(),
            world: WorldConfig::default(),
            radar_preset: RadarPreset::Carla,
            radars: Vec::new(),
            noise: NoiseConfig::default(),
            odometry: OdometrySimConfig::default(),
            imu: Default::default(),
            ground_truth_rate: 50.0,
            map_frame: "map".into(),
            odom_frame: "odom".into(),
            body_frame: "base_link".into(),
        }
    }
}

impl SimConfig {
    /// The default drive with another radar preset (and that preset's noise).
    pub fn with_preset(preset: RadarPreset) -> Self {
        SimConfig {
            radar_preset: preset,
            noise: preset.noise(),
            ..SimConfig::default()
        }
    }

    /// The radars that will be simulated: the preset's, or `radars` when the preset is `custom`.
    pub fn radar_list(&self) -> Vec<SimRadarConfig> {
        match self.radar_preset {
            RadarPreset::Custom => self.radars.clone(),
            p => p.radars(),
        }
    }

    /// The `dc_loc_core::pipeline::Config` radar section matching the simulated radars: names, topics, frame ids,
    /// extrinsics, `beta`, field names `x, y, z, v_r, rcs` and the noise standard deviations of the selected
    /// noise model (see [`NoiseConfig::std_devs`]); with a radar that measures elevation, the height
    /// band `[0.3, 5.0]` m.
    pub fn to_config(&self) -> Config {
        let std = self.noise.std_devs();
        let mut radars = BTreeMap::new();
        let mut names = Vec::new();
        for r in self.radar_list() {
            names.push(r.name.clone());
            radars.insert(
                r.name.clone(),
                RadarConfig {
                    topic: r.topic.clone(),
                    message: RadarMessage::PointCloud2,
                    frame_id: r.frame_id.clone(),
                    trigger_topic: String::new(),
                    trigger_delay: 0.0,
                    extrinsic: r.extrinsic,
                    beta: r.beta,
                    fields: FieldsConfig::default(),
                    sigma_range: std.range,
                    sigma_velocity: std.velocity,
                    sigma_azimuth: std.azimuth,
                },
            );
        }
        let mut cfg = Config {
            body_frame: self.body_frame.clone(),
            radar_names: names,
            radars,
            ..Config::default()
        };
        // Radars that measure elevation see the road and what stands above the street: keep what
        // stands on the ground (the body frame is on the ground).
        if self.radar_list().iter().any(SimRadarConfig::has_elevation) {
            cfg.submap.height_band = [0.3, 5.0];
        }
        cfg
    }

    /// Rejects values that cannot work; the error names the parameter (dotted, as in YAML).
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut v = Validator::new();
        self.check(&mut v);
        v.finish()?;
        // The radar section handed to the pipeline must itself be valid.
        self.to_config().validate()
    }

    /// Declares each field's range and rule (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        // ROS time is a 32-bit second count.
        v.range(
            "start_time",
            self.start_time,
            Range::NON_NEGATIVE.below(2.0e9),
        );
        v.require("laps", !self.laps.is_empty(), || {
            "at least one lap is required".into()
        });
        v.require("laps", self.laps.len() <= 64, || "at most 64 laps".into());
        for (i, l) in self.laps.iter().enumerate() {
            v.range(
                &format!("laps[{i}].speed"),
                l.speed,
                Range::closed(1.0, 70.0),
            );
        }
        v.section("drive", |v| self.drive.check(v));
        v.section("route", |v| self.route.check(v));
        v.section("world", |v| self.world.check(v));
        let ego_offset = self.world.street.ego_lane_offset();
        for (i, c) in self.route.corners.iter().enumerate() {
            v.require(
                &format!("route.corners[{i}].radius"),
                c.radius >= ego_offset + 4.0,
                || {
                    format!(
                        "{} m is too tight for a lane {ego_offset} m off the centre line (need >= {} m)",
                        c.radius,
                        ego_offset + 4.0
                    )
                },
            );
        }
        let radars_ok = match self.radar_preset {
            RadarPreset::Custom => !self.radars.is_empty(),
            RadarPreset::Carla | RadarPreset::Nuscenes | RadarPreset::Ti | RadarPreset::Imaging => {
                self.radars.is_empty()
            }
        };
        v.require("radars", radars_ok, || {
            if self.radars.is_empty() {
                "preset `custom` needs at least one radar".into()
            } else {
                "only used with radar_preset `custom`; leave it empty or set the preset to custom"
                    .into()
            }
        });
        let list = self.radar_list();
        for (i, r) in list.iter().enumerate() {
            v.section(&format!("radars[{i}]"), |v| {
                r.check(v);
                v.require("name", !list[..i].iter().any(|o| o.name == r.name), || {
                    format!("`{}` is used twice", r.name)
                });
            });
        }
        v.section("noise", |v| self.noise.check(v));
        v.section("odometry", |v| self.odometry.check(v));
        v.section("imu", |v| self.imu.check(v));
        v.range(
            "ground_truth_rate",
            self.ground_truth_rate,
            Range::closed(1.0, 1000.0),
        );
        for (field, name) in [
            ("map_frame", &self.map_frame),
            ("odom_frame", &self.odom_frame),
            ("body_frame", &self.body_frame),
        ] {
            v.require(field, !name.is_empty(), || "must not be empty".into());
        }
    }
}

/// One lap of the loop.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LapConfig {
    /// Cruise speed on straights, m/s (default 20 m/s = 72 km/h). Corners are taken slower
    /// (`drive.max_lateral_acceleration`).
    pub speed: f64,
    /// Drive the loop the other way round (default false).
    pub reverse: bool,
}

impl Default for LapConfig {
    fn default() -> Self {
        LapConfig {
            speed: 20.0,
            reverse: false,
        }
    }
}

/// Limits of the ego vehicle's speed profile.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DriveConfig {
    /// Largest lateral acceleration in corners, m/s^2 (default 3.0: brisk city driving). Sets the corner
    /// speed `sqrt(a / curvature)`.
    pub max_lateral_acceleration: f64,
    /// Largest forward acceleration, m/s^2 (default 1.5).
    pub max_acceleration: f64,
    /// Largest braking deceleration, m/s^2 (default 2.5).
    pub max_deceleration: f64,
    /// Speed limit in a U-turn (between a forward and a reverse lap), m/s (default 4).
    pub uturn_speed: f64,
    /// Where the drive starts and each lap ends: metres along the loop from the middle of its first
    /// straight (default 0). The robots of a fleet start at different places on one world.
    pub start: f64,
}

impl Default for DriveConfig {
    fn default() -> Self {
        DriveConfig {
            max_lateral_acceleration: 3.0,
            max_acceleration: 1.5,
            max_deceleration: 2.5,
            uturn_speed: 4.0,
            start: 0.0,
        }
    }
}

impl DriveConfig {
    fn check(&self, v: &mut Validator) {
        v.positive("max_lateral_acceleration", self.max_lateral_acceleration);
        v.positive("max_acceleration", self.max_acceleration);
        v.positive("max_deceleration", self.max_deceleration);
        v.range("uturn_speed", self.uturn_speed, Range::at_least(1.0));
        v.non_negative("start", self.start);
    }
}

/// One corner of the road loop: the centre line turns at the polygon vertex `(x, y)` with a circular arc of
/// `radius`, entered and left through clothoids.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CornerConfig {
    /// Vertex x, m (map frame).
    pub x: f64,
    /// Vertex y, m.
    pub y: f64,
    /// Radius of the constant-curvature part, m.
    pub radius: f64,
    /// A junction: both streets continue past the corner (with facades), so the corner opens up.
    pub junction: bool,
}

/// The road: a closed polygon of corners, driven in list order: a loop (one full turn), or a figure
/// eight (no net turn) whose two halves cross, with the buildings cut back where they do.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RouteConfig {
    /// Polygon vertices with their corner radii (default: 7 corners, 2.2 km, radii 15 to 150 m, one right
    /// turn, five junctions). The drive starts in the middle of the first straight (corner 0 to 1).
    pub corners: Vec<CornerConfig>,
    /// Clothoid length at each end of a corner, m (default 15); shortened to half the corner's arc length
    /// where the corner is too short.
    pub transition_length: f64,
}

impl Default for RouteConfig {
    fn default() -> Self {
        let c = |x: f64, y: f64, radius: f64, junction: bool| CornerConfig {
            x,
            y,
            radius,
            junction,
        };
        RouteConfig {
            corners: vec![
                c(0.0, 0.0, 15.0, true),
                c(700.0, 0.0, 20.0, true),
                c(760.0, 250.0, 60.0, false),
                c(560.0, 420.0, 150.0, false),
                c(300.0, 380.0, 30.0, true),
                c(220.0, 250.0, 40.0, true),
                c(-20.0, 280.0, 18.0, true),
            ],
            transition_length: 15.0,
        }
    }
}

impl RouteConfig {
    /// Rejects corner lists that do not form a closed loop or figure eight of proper corners.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut v = Validator::at("route");
        self.check(&mut v);
        v.finish()
    }

    /// Declares each field's range; the corners must form a closed loop or a figure eight of proper
    /// corners.
    pub fn check(&self, v: &mut Validator) {
        let n = self.corners.len();
        v.require("corners", n >= 3, || {
            "at least 3 corners are required".into()
        });
        for (i, c) in self.corners.iter().enumerate() {
            v.require(
                &format!("corners[{i}]"),
                c.x.is_finite() && c.y.is_finite(),
                || "x and y must be finite".into(),
            );
            v.positive(&format!("corners[{i}].radius"), c.radius);
        }
        v.non_negative("transition_length", self.transition_length);
        if n < 3 {
            return;
        }
        // Turning angles must be proper corners.
        let mut total = 0.0;
        for i in 0..n {
            let at = |k: usize| {
                let c = &self.corners[k % n];
                Vec2::new(c.x, c.y)
            };
            let d_in = at(i + n) - at(i + n - 1);
            let d_out = at(i + 1) - at(i);
            let corner = format!("corners[{i}]");
            v.require(&corner, d_in.norm() >= 1.0 && d_out.norm() >= 1.0, || {
                "coincides with its neighbour".into()
            });
            let turn = d_in.perp(&d_out).atan2(d_in.dot(&d_out));
            let proper = (5f64.to_radians()..=150f64.to_radians()).contains(&turn.abs());
            v.require(&corner, proper, || {
                format!(
                    "turns by {:.1} deg; corners must turn by 5 to 150 deg",
                    turn.to_degrees()
                )
            });
            total += turn;
        }
        // One full turn is a loop; no net turn is a figure eight, whose two halves cross.
        let net = total.abs();
        v.require(
            "corners",
            (net - std::f64::consts::TAU).abs() <= 1e-6 || net <= 1e-6,
            || {
                format!(
                    "turns add up to {:.1} deg, not +-360 (a loop) or 0 (a figure eight)",
                    total.to_degrees()
                )
            },
        );
    }
}

/// Odometry error model: the true motion between two samples is distorted by a speed scale error, a
/// yaw-rate bias, white noise and wheel slip episodes, then integrated.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometrySimConfig {
    /// Sample rate, Hz (default 50).
    pub rate: f64,
    /// Relative speed scale error (default 0.01: wheel radius 1 % off, the odometry overestimates distance).
    pub scale_error: f64,
    /// Yaw-rate bias, rad/s (default 0.1 deg/s: an automotive yaw-rate sensor after its standstill
    /// calibration). Over a 100 s lap it turns the heading by 10 deg.
    pub yaw_rate_bias: f64,
    /// White speed noise per sample, m/s (default 0.05).
    pub speed_noise: f64,
    /// White yaw-rate noise per sample, rad/s (default 0.2 deg/s).
    pub yaw_rate_noise: f64,
    /// Wheel slip episodes per km driven, starting as a Poisson process in distance (default 0: none).
    /// During an episode the wheels spin or slide: the odometry's distance and speed read `1 + s` times
    /// the truth, the yaw rate (from the gyro) is unaffected, and the published covariance does not know.
    pub slip_rate: f64,
    /// Range of the relative extra distance `s` of an episode, drawn uniformly per episode (default 0.05
    /// to 0.3).
    pub slip: [f64; 2],
    /// Range of an episode's duration, s, drawn uniformly per episode (default 0.5 to 2).
    pub slip_duration: [f64; 2],
}

impl Default for OdometrySimConfig {
    fn default() -> Self {
        OdometrySimConfig {
            rate: 50.0,
            scale_error: 0.01,
            yaw_rate_bias: 0.1f64.to_radians(),
            speed_noise: 0.05,
            yaw_rate_noise: 0.2f64.to_radians(),
            slip_rate: 0.0,
            slip: [0.05, 0.3],
            slip_duration: [0.5, 2.0],
        }
    }
}

impl OdometrySimConfig {
    /// No error at all: the odometry is the ground truth expressed in the odometry frame.
    pub fn perfect() -> Self {
        OdometrySimConfig {
            scale_error: 0.0,
            yaw_rate_bias: 0.0,
            speed_noise: 0.0,
            yaw_rate_noise: 0.0,
            ..OdometrySimConfig::default()
        }
    }

    fn check(&self, v: &mut Validator) {
        v.range("rate", self.rate, Range::closed(1.0, 1000.0));
        let half = Range::above(-0.5).below(0.5);
        v.range("scale_error", self.scale_error, half);
        v.range("yaw_rate_bias", self.yaw_rate_bias, half);
        v.non_negative("speed_noise", self.speed_noise);
        v.non_negative("yaw_rate_noise", self.yaw_rate_noise);
        v.range("slip_rate", self.slip_rate, Range::closed(0.0, 1000.0));
        v.interval("slip", self.slip, Range::NON_NEGATIVE);
        v.require("slip", self.slip[1] <= 1.0, || {
            "at most 1 (twice the true distance)".into()
        });
        v.interval("slip_duration", self.slip_duration, Range::POSITIVE);
        v.require("slip_duration", self.slip_duration[1] <= 60.0, || {
            "at most 60 s".into()
        });
    }
}

impl NoiseConfig {
    /// Noise-free measurements (for tests of the geometry).
    pub fn none() -> Self {
        NoiseConfig {
            model: NoiseModel::None,
            ..NoiseConfig::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_presets_match_the_nuscenes_calibration() {
        SimConfig::default().validate().unwrap();
        let c = SimConfig::with_preset(RadarPreset::Nuscenes);
        c.validate().unwrap();
        let r = c.radar_list();
        assert_eq!(r.len(), 5);
        let yaw_deg: Vec<f64> = r.iter().map(|r| r.extrinsic[5].to_degrees()).collect();
        for (got, want) in yaw_deg.iter().zip([0.20, 88.36, -90.98, 174.41, -176.11]) {
            assert!((got - want).abs() < 0.01, "{got} vs {want}");
        }
        assert_eq!(r[3].extrinsic[..3], [-0.562, 0.628, 0.53]);
        let cfg = c.to_config();
        assert_eq!(cfg.radar_names[1], "front_left");
        assert_eq!(cfg.radars["back_right"].topic, "/radar_back_right/points");
        assert_eq!(cfg.radars["back_right"].frame_id, "radar_back_right");
    }

    /// The TI preset: one short-range radar whose pipeline section carries its own beta and the
    /// noisier azimuth.
    #[test]
    fn ti_preset_is_a_short_range_radar_with_its_noise() {
        let c = SimConfig::with_preset(RadarPreset::Ti);
        c.validate().unwrap();
        let r = c.radar_list();
        assert_eq!(r.len(), 1);
        assert_eq!(r[0].max_range(), 50.0);
        assert_eq!(r[0].range_at(60f64.to_radians()), 25.0);
        let cfg = c.to_config();
        let radar = &cfg.radars[&cfg.radar_names[0]];
        assert_eq!(radar.beta, 0.0026);
        assert!((radar.sigma_azimuth - 1.5f64.to_radians()).abs() < 1e-12);
        assert_eq!(radar.sigma_range, 0.1);
    }

    #[test]
    fn coverage_profile_interpolates() {
        let r = &RadarPreset::Nuscenes.radars()[0];
        assert_eq!(r.range_at(0.0), 250.0);
        assert!((r.range_at(6.5f64.to_radians()) - 200.0).abs() < 1e-9);
        assert_eq!(r.range_at(-30f64.to_radians()), 70.0);
        assert!((r.range_at(52.5f64.to_radians()) - 45.0).abs() < 1e-9);
        assert_eq!(r.range_at(61f64.to_radians()), 0.0);
        let carla = SimRadarConfig::default();
        assert_eq!(carla.range_at(74f64.to_radians()), 100.0);
        assert_eq!(carla.range_at(76f64.to_radians()), 0.0);
    }

    #[test]
    fn bad_values_name_the_field() {
        let mut c = SimConfig::default();
        c.laps[1].speed = 0.0;
        assert_eq!(c.validate().unwrap_err().name, "laps[1].speed");
        let mut c = SimConfig::default();
        c.route.corners[2].radius = 6.0;
        assert_eq!(c.validate().unwrap_err().name, "route.corners[2].radius");
        // A pentagram turns twice around: neither a loop nor a figure eight.
        let mut c = SimConfig::default();
        c.route.corners = (0..5)
            .map(|k| {
                let a = (k as f64 * 144.0).to_radians();
                CornerConfig {
                    x: 300.0 * a.cos(),
                    y: 300.0 * a.sin(),
                    radius: 15.0,
                    junction: false,
                }
            })
            .collect();
        assert_eq!(c.validate().unwrap_err().name, "route.corners");
        // The default loop with two corners swapped crosses itself: a figure eight.
        let mut c = SimConfig::default();
        c.route.corners.swap(1, 2);
        assert!(c.validate().is_ok());
        let mut c = SimConfig::default();
        c.radars.push(SimRadarConfig::default());
        assert_eq!(c.validate().unwrap_err().name, "radars");
        c.radar_preset = RadarPreset::Custom;
        c.radars[0].coverage.clear();
        assert_eq!(c.validate().unwrap_err().name, "radars[0].coverage");
        let mut c = SimConfig::default();
        c.noise.gamma_shape = 0.0;
        assert_eq!(c.validate().unwrap_err().name, "noise.gamma_shape");
        let mut c = SimConfig::default();
        c.world.street.building_line = 9.0;
        assert_eq!(c.validate().unwrap_err().name, "world.street.building_line");
        let mut c = SimConfig::default();
        c.odometry.slip = [0.3, 0.1];
        assert_eq!(c.validate().unwrap_err().name, "odometry.slip");
        let mut c = SimConfig::with_preset(RadarPreset::Custom);
        c.radars = vec![SimRadarConfig {
            multipath_probability: 1.5,
            ..SimRadarConfig::default()
        }];
        assert_eq!(
            c.validate().unwrap_err().name,
            "radars[0].multipath_probability"
        );
    }

    #[test]
    fn serde_round_trip() {
        // (serde_json's default float parser may be 1 ulp off, so use values it reads back exactly.)
        let mut c = SimConfig::with_preset(RadarPreset::Custom);
        c.radars = vec![SimRadarConfig {
            phase: 0.01,
            extrinsic: [1.0, -0.5, 0.5, 0.0, 0.0, 0.25],
            ..SimRadarConfig::default()
        }];
        c.laps[1].reverse = true;
        c.noise.model = NoiseModel::Gamma;
        c.validate().unwrap();
        let back: SimConfig = serde_json::from_str(&serde_json::to_string(&c).unwrap()).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn unknown_fields_are_rejected() {
        let e = serde_json::from_str::<SimConfig>(r#"{"seed": 3, "lapz": []}"#);
        assert!(e.is_err());
        let c: SimConfig =
            serde_json::from_str(r#"{"seed": 3, "noise": {"model": "student_t"}}"#).unwrap();
        assert_eq!(c.seed, 3);
        assert_eq!(c.noise.model, NoiseModel::StudentT);
        assert_eq!(c.laps, SimConfig::default().laps);
    }
}

/// The gyro's error model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ImuSimConfig {
    /// Sample rate, Hz (default 0: no IMU).
    pub rate: f64,
    /// Bias at the start, rad/s (default 0.2 deg/s: a consumer MEMS gyro after power-up).
    pub bias: f64,
    /// Random walk of the bias, rad/s/sqrt(s) (default 1e-4).
    pub bias_walk: f64,
    /// White noise density, rad/s/sqrt(Hz) (default 0.003); a sample's standard deviation is this
    /// times the square root of the rate.
    pub noise_density: f64,
}

impl Default for ImuSimConfig {
    fn default() -> Self {
        ImuSimConfig {
            rate: 0.0,
            bias: 0.2f64.to_radians(),
            bias_walk: 1e-4,
            noise_density: 0.003,
        }
    }
}

impl ImuSimConfig {
    /// A 100 Hz gyro with the default errors.
    pub fn at_100_hz() -> Self {
        ImuSimConfig {
            rate: 100.0,
            ..ImuSimConfig::default()
        }
    }

    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.range("rate", self.rate, Range::closed(0.0, 2000.0));
        v.range("bias", self.bias, Range::FINITE);
        v.non_negative("bias_walk", self.bias_walk);
        v.non_negative("noise_density", self.noise_density);
    }
}
