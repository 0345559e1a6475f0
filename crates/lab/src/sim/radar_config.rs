//! Simulated radars: the presets ([`RadarPreset`]: the paper's CARLA radar, the five nuScenes
//! ARS408-21) and one radar's mounting, coverage and detection model ([`SimRadarConfig`]).

use super::noise::NoiseConfig;
use dc_loc_core::math::Quat;
use dc_loc_core::validate::{Range, Validator};
use serde::{Deserialize, Serialize};

/// A ready-made radar set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RadarPreset {
    /// The paper's CARLA radar: one forward radar, 100 m range, 150 deg field of view, 13 Hz, beta 0.04 s.
    Carla,
    /// The five nuScenes Continental ARS408-21 radars with their real extrinsics (from the nuScenes calibration), each at
    /// 13 Hz with its own phase.
    Nuscenes,
    /// A TI AWR1843-class radar: one forward radar with a short range (50 m ahead, 25 m at +-60 deg),
    /// 15 Hz, a fast chirp (beta 0.0026 s), wide beams (15 deg), more false alarms, and a noisier
    /// azimuth (1.5 deg: [`RadarPreset::noise`], which `dc_loc sim --preset ti` and `dc_loc revisits
    /// --radars ti` apply; a config file sets `noise` itself).
    Ti,
    /// A 4D imaging radar (Continental ARS548 or ZF FRGen21 class): one forward radar that measures
    /// elevation (+-14 deg), 200 m ahead, 60 deg to each side at 60 m, fine cells (0.22 m, 1.2 deg),
    /// a fast chirp (beta 0.005 s), 20 Hz, up to 2,000 detections a scan, road-surface returns, and a
    /// finer range and azimuth noise (0.1 m, half the paper's azimuth: [`RadarPreset::noise`]).
    Imaging,
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
    /// How far the scans' stamps run ahead of the time they were measured, s (default 0; negative:
    /// behind): a radar whose clock is not synchronised with the odometry's.
    pub stamp_offset: f64,
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
    /// Probability that a reflection other than a wall point is also seen via a wall, as a multipath
    /// ghost at its mirror image across the wall (default 0: no ghosts).
    pub multipath_probability: f64,
    /// RCS loss of the bounced path against the direct one, dB (default 10).
    pub multipath_loss: f64,
    /// Half the elevation field of view, rad (default 0: a planar radar, every detection at z = 0 in
    /// its frame). Above 0 the radar measures elevation: each reflection gets a height within its
    /// object's vertical extent (on flat ground, z = 0 at the body frame's origin), is seen when its
    /// elevation lies within the field of view, and is reported at its slant range.
    pub elevation_fov: f64,
    /// Elevation resolution, rad (default 2 deg; used when `elevation_fov` > 0).
    pub elevation_resolution: f64,
    /// Standard deviation of the measured elevation, rad (default 0.3 deg; used when `elevation_fov`
    /// > 0).
    pub elevation_noise: f64,
    /// Mean number of returns from the road surface per scan (default 0; used when `elevation_fov` >
    /// 0): static points on the ground within `ground_range`, below the radar's boresight.
    pub ground_rate: f64,
    /// Farthest ground return, m (default 30).
    pub ground_range: f64,
    /// Factor on the world's surface sample densities (walls, car sides, bushes) this radar resolves
    /// (default 1): an imaging radar's finer cells separate more scatterers on one surface.
    pub scatter_gain: f64,
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
            stamp_offset: 0.0,
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
            multipath_probability: 0.0,
            multipath_loss: 10.0,
            elevation_fov: 0.0,
            elevation_resolution: 2f64.to_radians(),
            elevation_noise: 0.3f64.to_radians(),
            ground_rate: 0.0,
            ground_range: 30.0,
            scatter_gain: 1.0,
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

    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        for (field, x) in [
            ("name", &self.name),
            ("topic", &self.topic),
            ("frame_id", &self.frame_id),
        ] {
            v.require(field, !x.is_empty(), || "must not be empty".into());
        }
        let bad = self.extrinsic.iter().position(|x| !x.is_finite());
        v.require("extrinsic", bad.is_none(), || {
            format!("element {} is not finite", bad.unwrap_or_default())
        });
        let planar = self.extrinsic[3].abs() <= 1e-9 && self.extrinsic[4].abs() <= 1e-9;
        v.require("extrinsic", planar, || {
            "roll and pitch must be 0 (planar simulation)".into()
        });
        v.range("beta", self.beta, Range::NON_NEGATIVE.below(1.0));
        v.range("rate", self.rate, Range::closed(0.5, 100.0));
        v.range(
            "phase",
            self.phase,
            Range::NON_NEGATIVE.below(1.0 / self.rate),
        );
        v.range(
            "stamp_jitter",
            self.stamp_jitter,
            Range::NON_NEGATIVE.below(0.1 / self.rate),
        );
        v.range("stamp_offset", self.stamp_offset, Range::closed(-0.5, 0.5));
        v.require("coverage", !self.coverage.is_empty(), || {
            "needs at least one [azimuth, range] pair".into()
        });
        let mut prev = -1.0;
        for (i, &[a, r]) in self.coverage.iter().enumerate() {
            let ok = a.is_finite()
                && r.is_finite()
                && a >= prev
                && a < 89f64.to_radians()
                && r > 0.0
                && r <= 400.0;
            v.require("coverage", ok, || {
                format!(
                    "entry {i} [{a}, {r}]: azimuths must rise within [0, 89 deg), ranges in (0, 400] m"
                )
            });
            prev = a;
        }
        v.range(
            "min_range",
            self.min_range,
            Range::NON_NEGATIVE.below(self.max_range()),
        );
        v.positive("range_resolution", self.range_resolution);
        v.positive("azimuth_resolution", self.azimuth_resolution);
        v.positive("velocity_resolution", self.velocity_resolution);
        v.range("reference_rcs", self.reference_rcs, Range::FINITE);
        v.positive("detection_spread", self.detection_spread);
        v.at_least("max_detections", self.max_detections, 1);
        v.range(
            "false_alarm_rate",
            self.false_alarm_rate,
            Range::closed(0.0, 100.0),
        );
        v.unit("empty_scan_probability", self.empty_scan_probability);
        v.unit("partial_scan_probability", self.partial_scan_probability);
        v.unit("multipath_probability", self.multipath_probability);
        v.range(
            "multipath_loss",
            self.multipath_loss,
            Range::closed(0.0, 100.0),
        );
        v.range(
            "elevation_fov",
            self.elevation_fov,
            Range::NON_NEGATIVE.below(60f64.to_radians()),
        );
        v.positive("elevation_resolution", self.elevation_resolution);
        v.range(
            "elevation_noise",
            self.elevation_noise,
            Range::NON_NEGATIVE.below(0.2),
        );
        v.range("ground_rate", self.ground_rate, Range::closed(0.0, 10000.0));
        v.positive("ground_range", self.ground_range);
        v.range("scatter_gain", self.scatter_gain, Range::closed(0.0, 100.0));
    }

    /// The radar measures elevation.
    pub fn has_elevation(&self) -> bool {
        self.elevation_fov > 0.0
    }
}

impl RadarPreset {
    /// The radars of this preset (empty for `Custom`).
    pub fn radars(self) -> Vec<SimRadarConfig> {
        match self {
            RadarPreset::Carla => vec![SimRadarConfig::default()],
            RadarPreset::Nuscenes => nuscenes_radars(),
            RadarPreset::Ti => vec![ti_radar()],
            RadarPreset::Imaging => vec![imaging_radar()],
            RadarPreset::Custom => Vec::new(),
        }
    }

    /// The preset's name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            RadarPreset::Carla => "carla",
            RadarPreset::Nuscenes => "nuscenes",
            RadarPreset::Ti => "ti",
            RadarPreset::Imaging => "imaging",
            RadarPreset::Custom => "custom",
        }
    }

    /// The measurement noise of this preset's radars: [`Self::own_noise`], else the paper's.
    pub fn noise(self) -> NoiseConfig {
        self.own_noise().unwrap_or_default()
    }

    /// The noise of a preset whose radars are not the paper's: for `ti` a finer range (0.1 m) and a
    /// three times coarser azimuth (1.5 deg Gaussian); for `imaging` a finer range (0.1 m) and half
    /// the azimuth noise (0.25 deg Gaussian). `None` for `carla`, `nuscenes` and `custom`.
    pub fn own_noise(self) -> Option<NoiseConfig> {
        let azimuth_factor = match self {
            RadarPreset::Ti => 3.0,
            RadarPreset::Imaging => 0.5,
            RadarPreset::Carla | RadarPreset::Nuscenes | RadarPreset::Custom => return None,
        };
        let mut n = NoiseConfig::default();
        for s in [&mut n.gaussian, &mut n.gamma, &mut n.student_t] {
            s.range = 0.1;
            s.azimuth *= azimuth_factor;
        }
        Some(n)
    }
}

/// The TI AWR1843-class radar of [`RadarPreset::Ti`], where the CARLA radar sits.
fn ti_radar() -> SimRadarConfig {
    SimRadarConfig {
        beta: 0.0026,
        rate: 15.0,
        coverage: vec![[0.0, 50.0], [60f64.to_radians(), 25.0]],
        range_resolution: 0.2,
        azimuth_resolution: 15f64.to_radians(),
        velocity_resolution: 0.1,
        reference_rcs: 0.0,
        max_detections: 100,
        false_alarm_rate: 8.0,
        empty_scan_probability: 0.01,
        ..SimRadarConfig::default()
    }
}

/// The 4D imaging radar of [`RadarPreset::Imaging`], where the CARLA radar sits.
fn imaging_radar() -> SimRadarConfig {
    SimRadarConfig {
        beta: 0.005,
        rate: 20.0,
        coverage: vec![
            [0.0, 200.0],
            [20f64.to_radians(), 120.0],
            [60f64.to_radians(), 60.0],
        ],
        range_resolution: 0.22,
        azimuth_resolution: 1.2f64.to_radians(),
        velocity_resolution: 0.1,
        reference_rcs: 5.0,
        max_detections: 2000,
        false_alarm_rate: 10.0,
        elevation_fov: 14f64.to_radians(),
        elevation_resolution: 2.3f64.to_radians(),
        elevation_noise: 0.3f64.to_radians(),
        ground_rate: 200.0,
        ground_range: 30.0,
        scatter_gain: 8.0,
        ..SimRadarConfig::default()
    }
}

/// The five ARS408-21 radars of the nuScenes Singapore vehicle (nuScenes calibration: translation in the ego frame
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
