//! Simulator configuration: one serde tree, every `Default` written by hand, `validate()` names the field.
//!
//! Entry points: [`SimConfig`] (root) and its sections [`LapConfig`], [`DriveConfig`], [`RouteConfig`],
//! [`WorldConfig`], [`SimRadarConfig`] (with the presets of [`RadarPreset`]), [`NoiseConfig`],
//! [`OdometrySimConfig`].
//! Units are SI (m, s, rad, m/s); RCS values are in dBsm. Parameters that are probabilities are in [0, 1].

use crate::config::{Config, ConfigError, FieldsConfig, RadarConfig};
use crate::math::{Quat, Vec2};
use crate::sim::noise::{NoiseConfig, NoiseModel};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

fn err(name: impl Into<String>, reason: impl Into<String>) -> ConfigError {
    ConfigError::new(name, reason)
}

/// `v` must be finite and > 0.
fn positive(name: &str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(err(name, format!("{v} must be finite and > 0")))
    }
}

/// `v` must be finite and >= 0.
fn non_negative(name: &str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(err(name, format!("{v} must be finite and >= 0")))
    }
}

/// `v` must be a probability.
fn probability(name: &str, v: f64) -> Result<(), ConfigError> {
    if (0.0..=1.0).contains(&v) {
        Ok(())
    } else {
        Err(err(name, format!("{v} is not in [0, 1]")))
    }
}

/// `[lo, hi]` must be finite with `0 <= lo <= hi` (or `lo > 0` when `strict`).
fn range(name: &str, r: [f64; 2], strict: bool) -> Result<(), ConfigError> {
    let [lo, hi] = r;
    let lo_ok = if strict { lo > 0.0 } else { lo >= 0.0 };
    if lo.is_finite() && hi.is_finite() && lo_ok && lo <= hi {
        Ok(())
    } else {
        Err(err(
            name,
            format!(
                "[{lo}, {hi}] must be finite with {} lo <= hi",
                if strict { "0 <" } else { "0 <=" }
            ),
        ))
    }
}

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
            ground_truth_rate: 50.0,
            map_frame: "map".into(),
            odom_frame: "odom".into(),
            body_frame: "base_link".into(),
        }
    }
}

impl SimConfig {
    /// The default drive with another radar preset.
    pub fn with_preset(preset: RadarPreset) -> Self {
        SimConfig {
            radar_preset: preset,
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

    /// The `crate::config::Config` radar section matching the simulated radars: names, topics, frame ids,
    /// extrinsics, `beta`, field names `x, y, z, v_r, rcs` and the noise standard deviations of the selected
    /// noise model (see [`NoiseConfig::std_devs`]).
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
                    frame_id: r.frame_id.clone(),
                    extrinsic: r.extrinsic,
                    beta: r.beta,
                    fields: FieldsConfig::default(),
                    sigma_range: std.range,
                    sigma_velocity: std.velocity,
                    sigma_azimuth: std.azimuth,
                },
            );
        }
        Config {
            body_frame: self.body_frame.clone(),
            radar_names: names,
            radars,
            ..Config::default()
        }
    }

    /// Rejects values that cannot work; the error names the parameter (dotted, as in YAML).
    pub fn validate(&self) -> Result<(), ConfigError> {
        if !(self.start_time.is_finite() && self.start_time >= 0.0 && self.start_time < 2.0e9) {
            return Err(err(
                "start_time",
                format!(
                    "{} must be in [0, 2e9) s (ROS time is a 32-bit second count)",
                    self.start_time
                ),
            ));
        }
        if self.laps.is_empty() {
            return Err(err("laps", "at least one lap is required"));
        }
        if self.laps.len() > 64 {
            return Err(err("laps", "at most 64 laps"));
        }
        for (i, l) in self.laps.iter().enumerate() {
            if !(l.speed.is_finite() && (1.0..=70.0).contains(&l.speed)) {
                return Err(err(
                    format!("laps[{i}].speed"),
                    format!("{} is not in [1, 70] m/s", l.speed),
                ));
            }
        }
        self.drive.validate()?;
        self.route.validate()?;
        self.world.validate()?;
        let ego_offset = self.world.street.ego_lane_offset();
        if let Some((i, c)) = self
            .route
            .corners
            .iter()
            .enumerate()
            .find(|(_, c)| c.radius < ego_offset + 4.0)
        {
            return Err(err(
                format!("route.corners[{i}].radius"),
                format!(
                    "{} m is too tight for a lane {ego_offset} m off the centre line (need >= {} m)",
                    c.radius,
                    ego_offset + 4.0
                ),
            ));
        }
        match self.radar_preset {
            RadarPreset::Custom if self.radars.is_empty() => {
                return Err(err("radars", "preset `custom` needs at least one radar"));
            }
            RadarPreset::Carla | RadarPreset::Nuscenes if !self.radars.is_empty() => {
                return Err(err(
                    "radars",
                    "only used with radar_preset `custom`; leave it empty or set the preset to custom",
                ));
            }
            _ => {}
        }
        let list = self.radar_list();
        for (i, r) in list.iter().enumerate() {
            r.validate(&format!("radars[{i}]"))?;
            if list[..i].iter().any(|o| o.name == r.name) {
                return Err(err(
                    format!("radars[{i}].name"),
                    format!("`{}` is used twice", r.name),
                ));
            }
        }
        self.noise.validate("noise")?;
        self.odometry.validate("odometry")?;
        if !(self.ground_truth_rate.is_finite() && (1.0..=1000.0).contains(&self.ground_truth_rate))
        {
            return Err(err(
                "ground_truth_rate",
                format!("{} is not in [1, 1000] Hz", self.ground_truth_rate),
            ));
        }
        for (n, v) in [
            ("map_frame", &self.map_frame),
            ("odom_frame", &self.odom_frame),
            ("body_frame", &self.body_frame),
        ] {
            if v.is_empty() {
                return Err(err(n, "must not be empty"));
            }
        }
        // The radar section handed to the pipeline must itself be valid.
        self.to_config().validate()?;
        Ok(())
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
}

impl Default for DriveConfig {
    fn default() -> Self {
        DriveConfig {
            max_lateral_acceleration: 3.0,
            max_acceleration: 1.5,
            max_deceleration: 2.5,
            uturn_speed: 4.0,
        }
    }
}

impl DriveConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        positive(
            "drive.max_lateral_acceleration",
            self.max_lateral_acceleration,
        )?;
        positive("drive.max_acceleration", self.max_acceleration)?;
        positive("drive.max_deceleration", self.max_deceleration)?;
        if !(self.uturn_speed.is_finite() && self.uturn_speed >= 1.0) {
            return Err(err(
                "drive.uturn_speed",
                format!("{} must be >= 1 m/s", self.uturn_speed),
            ));
        }
        Ok(())
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

/// The road loop: a closed polygon of corners, driven in list order.
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
    /// Rejects corner lists that do not form a simple closed loop of proper corners.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let n = self.corners.len();
        if n < 3 {
            return Err(err("route.corners", "at least 3 corners are required"));
        }
        for (i, c) in self.corners.iter().enumerate() {
            if !(c.x.is_finite() && c.y.is_finite()) {
                return Err(err(format!("route.corners[{i}]"), "x and y must be finite"));
            }
            positive(&format!("route.corners[{i}].radius"), c.radius)?;
        }
        non_negative("route.transition_length", self.transition_length)?;
        // Turning angles must be proper corners and add up to one full turn (a simple closed loop).
        let mut total = 0.0;
        for i in 0..n {
            let v = |k: usize| {
                let c = &self.corners[k % n];
                Vec2::new(c.x, c.y)
            };
            let d_in = v(i + n) - v(i + n - 1);
            let d_out = v(i + 1) - v(i);
            if d_in.norm() < 1.0 || d_out.norm() < 1.0 {
                return Err(err(
                    format!("route.corners[{i}]"),
                    "coincides with its neighbour",
                ));
            }
            let turn = d_in.perp(&d_out).atan2(d_in.dot(&d_out));
            if turn.abs() < 5f64.to_radians() || turn.abs() > 150f64.to_radians() {
                return Err(err(
                    format!("route.corners[{i}]"),
                    format!(
                        "turns by {:.1} deg; corners must turn by 5 to 150 deg",
                        turn.to_degrees()
                    ),
                ));
            }
            total += turn;
        }
        if (total.abs() - std::f64::consts::TAU).abs() > 1e-6 {
            return Err(err(
                "route.corners",
                format!(
                    "turns add up to {:.1} deg, not +-360: not a simple loop",
                    total.to_degrees()
                ),
            ));
        }
        Ok(())
    }
}

/// Cross-section of the streets (distances from the centre line, m).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StreetConfig {
    /// Lane width, m (default 3.5).
    pub lane_width: f64,
    /// Lanes per direction (default 2). The ego drives in the outermost lane, traffic in the innermost.
    pub lanes_per_direction: u32,
    /// Centre of the parking strip, m (default 8.0).
    pub parking_offset: f64,
    /// Street lights and signs, m (default 9.6).
    pub pole_offset: f64,
    /// Trees and pedestrians, m (default 11.0).
    pub sidewalk_offset: f64,
    /// Building line: the nearest a facade comes to the centre line, m (default 13.0).
    pub building_line: f64,
    /// Building line of side streets, m (default 9.0).
    pub side_street_building_line: f64,
}

impl Default for StreetConfig {
    fn default() -> Self {
        StreetConfig {
            lane_width: 3.5,
            lanes_per_direction: 2,
            parking_offset: 8.0,
            pole_offset: 9.6,
            sidewalk_offset: 11.0,
            building_line: 13.0,
            side_street_building_line: 9.0,
        }
    }
}

impl StreetConfig {
    /// Distance of the ego's lane centre from the road centre line, m (outermost lane).
    pub fn ego_lane_offset(&self) -> f64 {
        (f64::from(self.lanes_per_direction) - 0.5) * self.lane_width
    }
    /// Distance of the traffic lane centre from the road centre line, m (innermost lane).
    pub fn traffic_lane_offset(&self) -> f64 {
        0.5 * self.lane_width
    }

    fn validate(&self) -> Result<(), ConfigError> {
        positive("world.street.lane_width", self.lane_width)?;
        if !(1..=4).contains(&self.lanes_per_direction) {
            return Err(err("world.street.lanes_per_direction", "must be 1 to 4"));
        }
        let road = f64::from(self.lanes_per_direction) * self.lane_width;
        let order = [
            ("world.street.parking_offset", self.parking_offset),
            ("world.street.pole_offset", self.pole_offset),
            ("world.street.sidewalk_offset", self.sidewalk_offset),
            ("world.street.building_line", self.building_line),
        ];
        let mut prev = road + 0.9; // half a car width beyond the road edge
        for (n, v) in order {
            if !(v.is_finite() && v >= prev) {
                return Err(err(
                    n,
                    format!(
                        "{v} m must be >= {prev} m (road edge, parking, poles, sidewalk, buildings, outwards)"
                    ),
                ));
            }
            prev = v + 0.5;
        }
        positive(
            "world.street.side_street_building_line",
            self.side_street_building_line,
        )?;
        Ok(())
    }
}

/// Buildings along the streets: each building is a front facade plus two side walls.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FacadeConfig {
    /// Building frontage length range, m (default 12 to 60).
    pub length: [f64; 2],
    /// Probability of a gap (alley, yard) after a building (default 0.35).
    pub gap_probability: f64,
    /// Gap width range, m (default 3 to 12).
    pub gap: [f64; 2],
    /// Probability that a building stands back from the building line (default 0.5).
    pub setback_probability: f64,
    /// Setback range, m (default 0.5 to 5).
    pub setback: [f64; 2],
    /// Depth of the side walls, m (default 8 to 20).
    pub depth: [f64; 2],
    /// Mean RCS of one facade sample at normal incidence, dBsm, drawn per building (default 0 to 8).
    pub rcs: [f64; 2],
    /// Surface samples offered to the radar per metre of wall per scan (default 0.6).
    pub density: f64,
    /// Relief of the facade (windows, doors, balconies): samples lie up to this far behind the wall line,
    /// m (default 0.3).
    pub roughness: f64,
    /// RCS of a building's front corners (strong edge reflectors), dBsm (default 8).
    pub edge_rcs: f64,
}

impl Default for FacadeConfig {
    fn default() -> Self {
        FacadeConfig {
            length: [12.0, 60.0],
            gap_probability: 0.35,
            gap: [3.0, 12.0],
            setback_probability: 0.5,
            setback: [0.5, 5.0],
            depth: [8.0, 20.0],
            rcs: [0.0, 8.0],
            density: 0.6,
            roughness: 0.3,
            edge_rcs: 8.0,
        }
    }
}

impl FacadeConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        range("world.facades.length", self.length, true)?;
        if self.length[0] < 2.0 {
            return Err(err(
                "world.facades.length",
                "buildings must be at least 2 m long",
            ));
        }
        probability("world.facades.gap_probability", self.gap_probability)?;
        range("world.facades.gap", self.gap, false)?;
        probability(
            "world.facades.setback_probability",
            self.setback_probability,
        )?;
        range("world.facades.setback", self.setback, false)?;
        range("world.facades.depth", self.depth, true)?;
        finite_range("world.facades.rcs", self.rcs)?;
        non_negative("world.facades.density", self.density)?;
        non_negative("world.facades.roughness", self.roughness)?;
        finite("world.facades.edge_rcs", self.edge_rcs)
    }
}

fn finite(name: &str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(err(name, "must be finite"))
    }
}

fn finite_range(name: &str, r: [f64; 2]) -> Result<(), ConfigError> {
    if r[0].is_finite() && r[1].is_finite() && r[0] <= r[1] {
        Ok(())
    } else {
        Err(err(
            name,
            format!("[{}, {}] must be finite with lo <= hi", r[0], r[1]),
        ))
    }
}

/// Side streets branching off the straights, and the streets that continue past junction corners.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SideStreetConfig {
    /// Distance between side streets along a straight, m (default 110 to 240).
    pub spacing: [f64; 2],
    /// Side street length, m (default 50 to 120); a building closes its far end.
    pub length: [f64; 2],
    /// Probability that a side street crosses (opens on both sides) rather than branching to one side
    /// (default 0.3).
    pub crossing_probability: f64,
    /// Length of the streets continuing past a junction corner, m (default 70).
    pub junction_length: f64,
}

impl Default for SideStreetConfig {
    fn default() -> Self {
        SideStreetConfig {
            spacing: [110.0, 240.0],
            length: [50.0, 120.0],
            crossing_probability: 0.3,
            junction_length: 70.0,
        }
    }
}

impl SideStreetConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        range("world.side_streets.spacing", self.spacing, true)?;
        if self.spacing[0] < 40.0 {
            return Err(err(
                "world.side_streets.spacing",
                "side streets must be >= 40 m apart",
            ));
        }
        range("world.side_streets.length", self.length, true)?;
        probability(
            "world.side_streets.crossing_probability",
            self.crossing_probability,
        )?;
        positive("world.side_streets.junction_length", self.junction_length)
    }
}

/// Street furniture and vegetation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FurnitureConfig {
    /// Street light spacing along each side, m (default 30).
    pub pole_spacing: f64,
    /// Probability that a street light is missing (default 0.2).
    pub pole_missing_probability: f64,
    /// RCS of a street light or sign post, dBsm (default 5).
    pub pole_rcs: f64,
    /// Fraction of straights with a row of trees on a side (default 0.4).
    pub tree_row_probability: f64,
    /// Tree spacing in a row, m (default 7 to 12).
    pub tree_spacing: [f64; 2],
    /// RCS of a tree trunk, dBsm (default -2).
    pub trunk_rcs: f64,
    /// Probability that a set-back building has a front garden (bushes) (default 0.6).
    pub garden_probability: f64,
    /// Bush radius, m (default 0.8 to 2.5).
    pub bush_radius: [f64; 2],
    /// Mean RCS of one vegetation sample, dBsm (default -10).
    pub vegetation_rcs: f64,
    /// Vegetation samples offered per square metre per scan (default 0.25).
    pub vegetation_density: f64,
}

impl Default for FurnitureConfig {
    fn default() -> Self {
        FurnitureConfig {
            pole_spacing: 30.0,
            pole_missing_probability: 0.2,
            pole_rcs: 5.0,
            tree_row_probability: 0.4,
            tree_spacing: [7.0, 12.0],
            trunk_rcs: -2.0,
            garden_probability: 0.6,
            bush_radius: [0.8, 2.5],
            vegetation_rcs: -10.0,
            vegetation_density: 0.25,
        }
    }
}

impl FurnitureConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        if !(self.pole_spacing.is_finite() && self.pole_spacing >= 2.0) {
            return Err(err("world.furniture.pole_spacing", "must be >= 2 m"));
        }
        probability(
            "world.furniture.pole_missing_probability",
            self.pole_missing_probability,
        )?;
        finite("world.furniture.pole_rcs", self.pole_rcs)?;
        probability(
            "world.furniture.tree_row_probability",
            self.tree_row_probability,
        )?;
        range("world.furniture.tree_spacing", self.tree_spacing, true)?;
        if self.tree_spacing[0] < 2.0 {
            return Err(err(
                "world.furniture.tree_spacing",
                "trees must be >= 2 m apart",
            ));
        }
        finite("world.furniture.trunk_rcs", self.trunk_rcs)?;
        probability(
            "world.furniture.garden_probability",
            self.garden_probability,
        )?;
        range("world.furniture.bush_radius", self.bush_radius, true)?;
        finite("world.furniture.vegetation_rcs", self.vegetation_rcs)?;
        non_negative(
            "world.furniture.vegetation_density",
            self.vegetation_density,
        )
    }
}

/// Parked cars along the curbs of the loop's straights.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ParkingConfig {
    /// Length of a parking slot, m (default 6.0).
    pub slot_length: f64,
    /// Fraction of slots that hold the same car on every lap (default 0.35).
    pub persistent_fraction: f64,
    /// Fraction of slots whose occupancy changes: on each lap such a slot holds a (different) car with
    /// `occupancy` probability (default 0.45). The remaining slots are always empty.
    pub changing_fraction: f64,
    /// Occupancy of a changing slot on a lap (default 0.5).
    pub occupancy: f64,
    /// Car length and width, m (default 4.5 x 1.8).
    pub car_size: [f64; 2],
    /// Mean RCS of a car's strongest corner, dBsm (default 10).
    pub car_rcs: f64,
    /// Samples offered per metre of visible car side per scan (default 0.6).
    pub car_density: f64,
}

impl Default for ParkingConfig {
    fn default() -> Self {
        ParkingConfig {
            slot_length: 6.0,
            persistent_fraction: 0.35,
            changing_fraction: 0.45,
            occupancy: 0.5,
            car_size: [4.5, 1.8],
            car_rcs: 10.0,
            car_density: 0.6,
        }
    }
}

impl ParkingConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        positive("world.parking.slot_length", self.slot_length)?;
        probability(
            "world.parking.persistent_fraction",
            self.persistent_fraction,
        )?;
        probability("world.parking.changing_fraction", self.changing_fraction)?;
        if self.persistent_fraction + self.changing_fraction > 1.0 {
            return Err(err(
                "world.parking.changing_fraction",
                "persistent_fraction + changing_fraction must be <= 1",
            ));
        }
        probability("world.parking.occupancy", self.occupancy)?;
        positive("world.parking.car_size", self.car_size[0])?;
        positive("world.parking.car_size", self.car_size[1])?;
        if self.car_size[0] > self.slot_length {
            return Err(err("world.parking.car_size", "a car must fit its slot"));
        }
        finite("world.parking.car_rcs", self.car_rcs)?;
        non_negative("world.parking.car_density", self.car_density)
    }
}

/// Moving road users: vehicles in the inner lanes (both directions), pedestrians on the sidewalks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrafficConfig {
    /// Vehicles per km of loop in each direction (default 8).
    pub vehicles_per_km: f64,
    /// Range of the lane speeds, m/s (default 7 to 14); all vehicles of one lane share its speed.
    pub vehicle_speed: [f64; 2],
    /// Pedestrians per km of loop (both sides, both walking directions; default 12).
    pub pedestrians_per_km: f64,
    /// Walking speed range, m/s (default 0.8 to 1.8).
    pub pedestrian_speed: [f64; 2],
    /// Mean RCS of a pedestrian, dBsm (default -8).
    pub pedestrian_rcs: f64,
}

impl Default for TrafficConfig {
    fn default() -> Self {
        TrafficConfig {
            vehicles_per_km: 8.0,
            vehicle_speed: [7.0, 14.0],
            pedestrians_per_km: 12.0,
            pedestrian_speed: [0.8, 1.8],
            pedestrian_rcs: -8.0,
        }
    }
}

impl TrafficConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        if !(self.vehicles_per_km.is_finite() && (0.0..=80.0).contains(&self.vehicles_per_km)) {
            return Err(err("world.traffic.vehicles_per_km", "must be in [0, 80]"));
        }
        range("world.traffic.vehicle_speed", self.vehicle_speed, true)?;
        if !(self.pedestrians_per_km.is_finite()
            && (0.0..=500.0).contains(&self.pedestrians_per_km))
        {
            return Err(err(
                "world.traffic.pedestrians_per_km",
                "must be in [0, 500]",
            ));
        }
        range(
            "world.traffic.pedestrian_speed",
            self.pedestrian_speed,
            true,
        )?;
        finite("world.traffic.pedestrian_rcs", self.pedestrian_rcs)
    }
}

/// Everything along the road.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorldConfig {
    /// Street cross-section.
    pub street: StreetConfig,
    /// Buildings.
    pub facades: FacadeConfig,
    /// Side streets and junctions.
    pub side_streets: SideStreetConfig,
    /// Poles, trees, bushes.
    pub furniture: FurnitureConfig,
    /// Parked cars.
    pub parking: ParkingConfig,
    /// Moving vehicles and pedestrians.
    pub traffic: TrafficConfig,
}

impl Default for WorldConfig {
    /// Each section's default: a four-lane city street with parking, street lights, some tree rows,
    /// buildings with gaps and setbacks, side streets every 110-240 m, 8 vehicles per km and direction.
    fn default() -> Self {
        WorldConfig {
            street: StreetConfig::default(),
            facades: FacadeConfig::default(),
            side_streets: SideStreetConfig::default(),
            furniture: FurnitureConfig::default(),
            parking: ParkingConfig::default(),
            traffic: TrafficConfig::default(),
        }
    }
}

impl WorldConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        self.street.validate()?;
        self.facades.validate()?;
        self.side_streets.validate()?;
        self.furniture.validate()?;
        self.parking.validate()?;
        self.traffic.validate()
    }
}

/// A ready-made radar set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RadarPreset {
    /// The paper's CARLA radar: one forward radar, 100 m range, 150 deg field of view, 13 Hz, beta 0.04 s.
    Carla,
    /// The five nuScenes Continental ARS408-21 radars with their real extrinsics (FORMATS.md), each at
    /// 13 Hz with its own phase.
    Nuscenes,
    /// The radars listed in `radars`.
    Custom,
}

/// One simulated radar: where it sits, what it publishes, and how it detects.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimRadarConfig {
    /// Name (the key in the pipeline's `radars` map), e.g. `front`.
    pub name: String,
    /// PointCloud2 topic, e.g. `/radar_front/points`.
    pub topic: String,
    /// `header.frame_id`, e.g. `radar_front`.
    pub frame_id: String,
    /// Radar frame in the body frame: x, y, z (m), roll, pitch, yaw (rad). Roll and pitch must be 0
    /// (the simulation is planar).
    pub extrinsic: [f64; 6],
    /// Doppler range coupling `beta`, s (default 0.04).
    pub beta: f64,
    /// Scan rate, Hz (default 13).
    pub rate: f64,
    /// Time of the first scan after the drive starts, s (default 0).
    pub phase: f64,
    /// Standard deviation of the scan time jitter, s (default 0.0005).
    pub stamp_jitter: f64,
    /// Coverage: `[|azimuth| (rad), max range (m)]` breakpoints, azimuth increasing, range linear in
    /// between; nothing is seen beyond the last azimuth. Default: 100 m out to +-75 deg (the CARLA radar).
    pub coverage: Vec<[f64; 2]>,
    /// Shortest range reported, m (default 0.2).
    pub min_range: f64,
    /// Range resolution, m (default 0.39, ARS408-21 near range per the paper).
    pub range_resolution: f64,
    /// Azimuth resolution, rad (default 3.2 deg, ARS408-21 per the paper).
    pub azimuth_resolution: f64,
    /// Radial velocity resolution, m/s (default 0.12, ARS408-21 0.43 km/h).
    pub velocity_resolution: f64,
    /// RCS detected with probability 0.5 at the coverage range, dBsm (default 10, a car). Detection
    /// probability is logistic in the SNR margin `rcs - reference_rcs - 40 log10(r / r_max(azimuth))`.
    pub reference_rcs: f64,
    /// Width of the logistic detection curve, dB (default 2).
    pub detection_spread: f64,
    /// Most detections reported per scan, strongest kept (default 125, the ARS408 scans in
    /// nuscenes-radar-pcd/ hold 125).
    pub max_detections: usize,
    /// Mean number of false alarms per scan (random range, azimuth and Doppler; default 3).
    pub false_alarm_rate: f64,
    /// Probability that a scan comes out empty (default 0.005).
    pub empty_scan_probability: f64,
    /// Probability that a scan loses its tail (a random 20-80 % of its detections; default 0.02).
    pub partial_scan_probability: f64,
}

impl Default for SimRadarConfig {
    /// The paper's CARLA forward radar, mounted where nuScenes' RADAR_FRONT sits (3.412 m ahead of the
    /// rear axle, 0.5 m up).
    fn default() -> Self {
        SimRadarConfig {
            name: "front".into(),
            topic: "/radar_front/points".into(),
            frame_id: "radar_front".into(),
            extrinsic: [3.412, 0.0, 0.5, 0.0, 0.0, 0.0],
            beta: 0.04,
            rate: 13.0,
            phase: 0.0,
            stamp_jitter: 0.0005,
            coverage: vec![[0.0, 100.0], [75f64.to_radians(), 100.0]],
            min_range: 0.2,
            range_resolution: 0.39,
            azimuth_resolution: 3.2f64.to_radians(),
            velocity_resolution: 0.12,
            reference_rcs: 10.0,
            detection_spread: 2.0,
            max_detections: 125,
            false_alarm_rate: 3.0,
            empty_scan_probability: 0.005,
            partial_scan_probability: 0.02,
        }
    }
}

impl SimRadarConfig {
    /// Largest range seen at any azimuth, m.
    pub fn max_range(&self) -> f64 {
        self.coverage.iter().map(|c| c[1]).fold(0.0, f64::max)
    }
    /// Half field of view, rad.
    pub fn half_fov(&self) -> f64 {
        self.coverage.last().map_or(0.0, |c| c[0])
    }
    /// Coverage range at `azimuth` (rad), m; 0 outside the field of view.
    pub fn range_at(&self, azimuth: f64) -> f64 {
        let a = azimuth.abs();
        let c = &self.coverage;
        for w in c.windows(2) {
            let ([a0, r0], [a1, r1]) = (w[0], w[1]);
            if a <= a1 {
                if a1 <= a0 {
                    return r1;
                }
                return r0 + (r1 - r0) * ((a - a0) / (a1 - a0)).max(0.0);
            }
        }
        match c[..] {
            [only] if a <= only[0] => only[1],
            _ => 0.0,
        }
    }

    fn validate(&self, p: &str) -> Result<(), ConfigError> {
        let n = |f: &str| format!("{p}.{f}");
        for (f, v) in [
            ("name", &self.name),
            ("topic", &self.topic),
            ("frame_id", &self.frame_id),
        ] {
            if v.is_empty() {
                return Err(err(n(f), "must not be empty"));
            }
        }
        if let Some(i) = self.extrinsic.iter().position(|v| !v.is_finite()) {
            return Err(err(n("extrinsic"), format!("element {i} is not finite")));
        }
        if self.extrinsic[3].abs() > 1e-9 || self.extrinsic[4].abs() > 1e-9 {
            return Err(err(
                n("extrinsic"),
                "roll and pitch must be 0 (planar simulation)",
            ));
        }
        if !(self.beta.is_finite() && (0.0..1.0).contains(&self.beta)) {
            return Err(err(n("beta"), format!("{} is not in [0, 1) s", self.beta)));
        }
        if !(self.rate.is_finite() && (0.5..=100.0).contains(&self.rate)) {
            return Err(err(
                n("rate"),
                format!("{} is not in [0.5, 100] Hz", self.rate),
            ));
        }
        if !(self.phase.is_finite() && self.phase >= 0.0 && self.phase < 1.0 / self.rate) {
            return Err(err(
                n("phase"),
                format!("{} must be in [0, 1/rate) s", self.phase),
            ));
        }
        if !(self.stamp_jitter.is_finite()
            && self.stamp_jitter >= 0.0
            && self.stamp_jitter < 0.1 / self.rate)
        {
            return Err(err(
                n("stamp_jitter"),
                "must be >= 0 and below a tenth of the scan period",
            ));
        }
        if self.coverage.is_empty() {
            return Err(err(
                n("coverage"),
                "needs at least one [azimuth, range] pair",
            ));
        }
        let mut prev = -1.0;
        for (i, &[a, r]) in self.coverage.iter().enumerate() {
            if !(a.is_finite()
                && r.is_finite()
                && a >= prev
                && a < 89f64.to_radians()
                && r > 0.0
                && r <= 400.0)
            {
                return Err(err(
                    n("coverage"),
                    format!(
                        "entry {i} [{a}, {r}]: azimuths must rise within [0, 89 deg), ranges in (0, 400] m"
                    ),
                ));
            }
            prev = a;
        }
        if !(self.min_range.is_finite()
            && self.min_range >= 0.0
            && self.min_range < self.max_range())
        {
            return Err(err(
                n("min_range"),
                "must be >= 0 and below the coverage range",
            ));
        }
        positive(&n("range_resolution"), self.range_resolution)?;
        positive(&n("azimuth_resolution"), self.azimuth_resolution)?;
        positive(&n("velocity_resolution"), self.velocity_resolution)?;
        finite(&n("reference_rcs"), self.reference_rcs)?;
        positive(&n("detection_spread"), self.detection_spread)?;
        if self.max_detections == 0 {
            return Err(err(n("max_detections"), "must be >= 1"));
        }
        if !(self.false_alarm_rate.is_finite() && (0.0..=100.0).contains(&self.false_alarm_rate)) {
            return Err(err(n("false_alarm_rate"), "must be in [0, 100] per scan"));
        }
        probability(&n("empty_scan_probability"), self.empty_scan_probability)?;
        probability(
            &n("partial_scan_probability"),
            self.partial_scan_probability,
        )
    }
}

impl RadarPreset {
    /// The radars of this preset (empty for `Custom`).
    pub fn radars(self) -> Vec<SimRadarConfig> {
        match self {
            RadarPreset::Carla => vec![SimRadarConfig::default()],
            RadarPreset::Nuscenes => nuscenes_radars(),
            RadarPreset::Custom => Vec::new(),
        }
    }
}

/// The five ARS408-21 radars of the nuScenes Singapore vehicle (FORMATS.md: translation in the ego frame
/// at the rear-axle midpoint, rotation as quaternion w, x, y, z about z only).
fn nuscenes_radars() -> Vec<SimRadarConfig> {
    // (channel, translation, quaternion w, z)
    let table: [(&str, [f64; 3], f64, f64); 5] = [
        (
            "front",
            [3.412, 0.0, 0.5],
            0.9999984769132877,
            0.0017453283658983088,
        ),
        (
            "front_left",
            [2.422, 0.8, 0.78],
            0.7171539204983457,
            0.6969148113750004,
        ),
        (
            "front_right",
            [2.422, -0.8, 0.77],
            0.7010337393110511,
            -0.7131281065471795,
        ),
        (
            "back_left",
            [-0.562, 0.628, 0.53],
            0.04876260733128922,
            0.9988103964848657,
        ),
        (
            "back_right",
            [-0.562, -0.618, 0.53],
            0.0339401344459428,
            -0.9994238676726663,
        ),
    ];
    // ARS408-21 coverage (Continental data sheet): far range 250 m within +-4 deg falling to 150 m at
    // +-9 deg; near range 70 m out to +-45 deg, falling to 20 m at +-60 deg.
    let coverage = vec![
        [0.0, 250.0],
        [4f64.to_radians(), 250.0],
        [9f64.to_radians(), 150.0],
        [10f64.to_radians(), 70.0],
        [45f64.to_radians(), 70.0],
        [60f64.to_radians(), 20.0],
    ];
    let period = 1.0 / 13.0;
    table
        .iter()
        .enumerate()
        .map(|(i, &(name, t, w, z))| {
            let q = Quat::new_normalize(nalgebra::Quaternion::new(w, 0.0, 0.0, z));
            let yaw = q.euler_angles().2;
            SimRadarConfig {
                name: name.into(),
                topic: format!("/radar_{name}/points"),
                frame_id: format!("radar_{name}"),
                extrinsic: [t[0], t[1], t[2], 0.0, 0.0, yaw],
                coverage: coverage.clone(),
                // Own phase per radar: the five sweeps interleave.
                phase: period * i as f64 / 5.0,
                ..SimRadarConfig::default()
            }
        })
        .collect()
}

/// Odometry error model: the true motion between two samples is distorted by a speed scale error, a
/// yaw-rate bias and white noise, then integrated.
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
}

impl Default for OdometrySimConfig {
    fn default() -> Self {
        OdometrySimConfig {
            rate: 50.0,
            scale_error: 0.01,
            yaw_rate_bias: 0.1f64.to_radians(),
            speed_noise: 0.05,
            yaw_rate_noise: 0.2f64.to_radians(),
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

    fn validate(&self, p: &str) -> Result<(), ConfigError> {
        if !(self.rate.is_finite() && (1.0..=1000.0).contains(&self.rate)) {
            return Err(err(
                format!("{p}.rate"),
                format!("{} is not in [1, 1000] Hz", self.rate),
            ));
        }
        if !(self.scale_error.is_finite() && self.scale_error.abs() < 0.5) {
            return Err(err(format!("{p}.scale_error"), "must be in (-0.5, 0.5)"));
        }
        if !(self.yaw_rate_bias.is_finite() && self.yaw_rate_bias.abs() < 0.5) {
            return Err(err(
                format!("{p}.yaw_rate_bias"),
                "must be in (-0.5, 0.5) rad/s",
            ));
        }
        non_negative(&format!("{p}.speed_noise"), self.speed_noise)?;
        non_negative(&format!("{p}.yaw_rate_noise"), self.yaw_rate_noise)
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
    fn defaults_validate_and_presets_match_formats_md() {
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

    #[test]
    fn coverage_profile_interpolates() {
        let r = &nuscenes_radars()[0];
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
        let mut c = SimConfig::default();
        c.route.corners.swap(1, 2);
        assert!(c.validate().unwrap_err().name.starts_with("route.corners"));
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
