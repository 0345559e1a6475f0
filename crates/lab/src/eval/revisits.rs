//! Revisit detection measured on simulated drives: precision and recall of the published loop closures
//! under odometry drift, same-direction and reverse laps, the three noise models, one and five radars.
//!
//! Steps, in order: simulate the scenario ([`RevisitScenario::sim_config`]); drive the [`Pipeline`] with
//! revisit search on, exactly as the node does ([`evaluate_revisits`]); judge every published closure
//! against the ground truth of its two keyframes and count the revisit opportunities closed
//! ([`super::judge`], which defines them). A scenario with a fleet runs [`super::fleet`] instead.

use super::judge::{
    Collected, RevisitReport, judge, keyframe_truth, measured_drift, reverse_radius,
};
use super::odometry::{OdometryTrackSample, measure_odometry};
use crate::sim::config::ImuSimConfig;
use crate::sim::inputs::{ScanEncoding, SimInputs};
use crate::sim::{
    NoiseModel, RadarPreset, SimConfig, SimDrive, WorldFamily, config::LapConfig, simulate,
};
use dc_loc_core::math::wrap_angle;
use dc_loc_core::odometry::OdometrySource;
use dc_loc_core::pipeline::Config;
use dc_loc_core::pipeline::{Event, Pipeline};
use serde::Serialize;

/// Standard deviation of a simulated car's sideways velocity on its rear axle, m/s
/// (`odometry.lateral_velocity_sigma` of the radar odometry): the simulated cars do not slide, real
/// ones slide by about this much in normal driving.
pub const CAR_LATERAL_VELOCITY_SIGMA: f64 = 0.1;

/// The simulator's Gamma noise shape, which the scenarios use unless told otherwise.
pub const DEFAULT_GAMMA_SHAPE: f64 = 1.0;

/// One simulated scenario.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RevisitScenario {
    /// Radar set.
    pub radars: RadarPreset,
    /// Measurement noise model.
    pub noise: NoiseModel,
    /// Odometry drift as a share of distance (0.01 = 1 %): the speed scale error; the yaw-rate bias is
    /// `drift * 10` deg/s (0.1 deg/s at 1 %, the simulator's default).
    pub drift: f64,
    /// Second lap driven in the opposite direction (after a U-turn).
    pub reverse: bool,
    /// Simulator seed.
    pub seed: u64,
    /// Kind of street ([`WorldFamily::City`] is the simulator's default world).
    pub world: WorldFamily,
    /// Extrinsic calibration error of the radars the pipeline is given (zero: the true extrinsics).
    pub calibration: CalibrationError,
    /// Radar clock offset, s: radar `i`'s stamps run this far ahead of the time it measured (`i` even)
    /// or behind it (`i` odd); 0: synchronised clocks.
    pub time_offset: f64,
    /// Robots of a fleet on this world, each driving one lap ([`crate::sim::fleet`]; `reverse` then
    /// unused); 0 or 1: one robot driving the two laps.
    pub fleet: u32,
    /// Multipath ghost probability of every radar (`SimRadarConfig::multipath_probability`); 0: none.
    pub multipath: f64,
    /// Wheel slip episodes per km (`OdometrySimConfig::slip_rate`); 0: none.
    pub wheel_slip: f64,
    /// Shape of the Gamma noise (`NoiseConfig::gamma_shape`; the simulator's default 1 is the most
    /// skewed it models); used with [`NoiseModel::Gamma`] only.
    pub gamma_shape: f64,
    /// Factors on the noise model's range, azimuth and radial-velocity scales (1: the model's own).
    pub noise_factors: [f64; 3],
    /// Where the pipeline's odometry comes from: the simulated wheel odometry (`topic`, drifting by
    /// `drift`), or the radar odometry (`radar`; `radar_imu` with a simulated 100 Hz gyro).
    pub odometry: OdometrySource,
}

/// An extrinsic calibration error: each radar's extrinsic as the pipeline is told it is off from the
/// simulated mount by `yaw_deg` of yaw (sign alternating from radar to radar) and `offset` metres in
/// the horizontal plane (in a direction turning by 72 degrees from radar to radar), so that five radars
/// carry five different errors. Deterministic, so runs compare.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct CalibrationError {
    /// Yaw error, degrees.
    pub yaw_deg: f64,
    /// Position error, m.
    pub offset: f64,
}

impl CalibrationError {
    /// True when the pipeline is given the true extrinsics.
    pub fn is_zero(&self) -> bool {
        self.yaw_deg == 0.0 && self.offset == 0.0
    }

    /// Applies the error to the radars of `cfg` (in name order).
    pub fn apply(&self, cfg: &mut Config) {
        for (i, radar) in cfg.radars.values_mut().enumerate() {
            let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
            let dir = (72.0 * i as f64).to_radians();
            let e = &mut radar.extrinsic;
            e[0] += self.offset * dir.cos();
            e[1] += self.offset * dir.sin();
            e[5] = wrap_angle(e[5] + sign * self.yaw_deg.to_radians());
        }
    }
}

impl RevisitScenario {
    /// A scenario on the default city with seed 1, the true extrinsics, synchronised clocks, no
    /// ghosts, no wheel slip, one robot and the simulator's Gamma shape.
    pub fn new(radars: RadarPreset, noise: NoiseModel, drift: f64, reverse: bool) -> Self {
        RevisitScenario {
            radars,
            noise,
            drift,
            reverse,
            seed: 1,
            world: WorldFamily::City,
            calibration: CalibrationError::default(),
            time_offset: 0.0,
            fleet: 0,
            multipath: 0.0,
            wheel_slip: 0.0,
            gamma_shape: DEFAULT_GAMMA_SHAPE,
            noise_factors: [1.0; 3],
            odometry: OdometrySource::Topic,
        }
    }

    /// The simulator configuration: the scenario's world (and its road, where it has one), a 72 km/h lap
    /// then a 40 km/h lap.
    pub fn sim_config(&self) -> SimConfig {
        let mut c = SimConfig::with_preset(self.radars);
        c.seed = self.seed;
        self.world.apply(&mut c);
        c.noise.model = self.noise;
        c.noise.gamma_shape = self.gamma_shape;
        let [fr, fa, fv] = self.noise_factors;
        for scales in [
            &mut c.noise.gaussian,
            &mut c.noise.gamma,
            &mut c.noise.student_t,
        ] {
            scales.range *= fr;
            scales.azimuth *= fa;
            scales.velocity *= fv;
        }
        c.odometry.scale_error = self.drift;
        c.odometry.yaw_rate_bias = (self.drift * 10.0).to_radians();
        c.odometry.slip_rate = self.wheel_slip;
        if self.odometry == OdometrySource::RadarImu {
            c.imu = ImuSimConfig::at_100_hz();
        }
        if self.time_offset != 0.0 || self.multipath != 0.0 {
            c.radars = c.radar_list();
            c.radar_preset = RadarPreset::Custom;
            for (i, r) in c.radars.iter_mut().enumerate() {
                let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
                r.stamp_offset = sign * self.time_offset;
                r.multipath_probability = self.multipath;
            }
        }
        c.laps = vec![
            LapConfig {
                speed: 72.0 / 3.6,
                reverse: false,
            },
            LapConfig {
                speed: 40.0 / 3.6,
                reverse: self.reverse,
            },
        ];
        c
    }

    /// A short label, e.g. `nuscenes gaussian 3% reverse`, prefixed by the family and seed outside the
    /// default city with seed 1 (`suburb/101 nuscenes gaussian 3% reverse`).
    pub fn label(&self) -> String {
        let world = if self.world == WorldFamily::City && self.seed == 1 {
            String::new()
        } else {
            format!("{}/{} ", self.world.name(), self.seed)
        };
        let calibration = if self.calibration.is_zero() {
            String::new()
        } else {
            format!(
                " calibration {}deg/{}m",
                self.calibration.yaw_deg, self.calibration.offset
            )
        };
        let clock = if self.time_offset == 0.0 {
            String::new()
        } else {
            format!(" clock +-{}ms", (self.time_offset * 1e3).round())
        };
        let multipath = if self.multipath == 0.0 {
            String::new()
        } else {
            format!(" multipath {}", self.multipath)
        };
        let slip = if self.wheel_slip == 0.0 {
            String::new()
        } else {
            format!(" slip {}/km", self.wheel_slip)
        };
        let shape = if self.noise == NoiseModel::Gamma && self.gamma_shape != DEFAULT_GAMMA_SHAPE {
            format!(" shape {}", self.gamma_shape)
        } else {
            String::new()
        };
        let factors = if self.noise_factors == [1.0; 3] {
            String::new()
        } else {
            let [r, a, v] = self.noise_factors;
            format!(" x{r},{a},{v}")
        };
        let odometry = match self.odometry {
            OdometrySource::Topic => format!("{}%", fmt_pct(self.drift)),
            other => other.name().to_string(),
        };
        let passes = match (self.fleet, self.reverse) {
            (0 | 1, false) => "same".to_string(),
            (0 | 1, true) => "reverse".to_string(),
            (n, _) => format!("fleet of {n}"),
        };
        format!(
            "{world}{} {}{shape}{factors} {odometry} {passes}{calibration}{clock}{multipath}{slip}",
            self.radars.name(),
            self.noise.name(),
        )
    }
}

fn fmt_pct(v: f64) -> String {
    let p = v * 100.0;
    if (p - p.round()).abs() < 1e-9 {
        format!("{p:.0}")
    } else {
        format!("{p:.1}")
    }
}

/// Simulates `scenario` and evaluates it with the pipeline configured by `tweak` applied to the
/// drive's own configuration.
pub fn evaluate_scenario(
    scenario: &RevisitScenario,
    tweak: impl FnOnce(&mut Config),
) -> Result<RevisitReport, dc_loc_core::validate::ConfigError> {
    if scenario.fleet >= 2 {
        let robots = crate::sim::fleet::fleet(&scenario.sim_config(), scenario.fleet)?;
        let mut r = super::fleet::evaluate_fleet(&robots, |cfg| {
            scenario.calibration.apply(cfg);
            tweak(cfg);
        })?;
        r.scenario = scenario.label();
        return Ok(r);
    }
    let drive = simulate(&scenario.sim_config())?;
    let mut cfg = drive.to_config();
    cfg.odometry.source = scenario.odometry;
    if scenario.odometry != OdometrySource::Topic {
        // The simulated vehicles are cars with their body frame on the rear axle: they do not
        // slide sideways.
        cfg.odometry.lateral_velocity_sigma = CAR_LATERAL_VELOCITY_SIGMA;
    }
    scenario.calibration.apply(&mut cfg);
    tweak(&mut cfg);
    let mut r = evaluate_revisits(&drive, cfg)?;
    r.scenario = scenario.label();
    Ok(r)
}

/// Drives the pipeline (revisit search on) over `drive` and judges its closures.
pub fn evaluate_revisits(
    drive: &SimDrive,
    mut cfg: Config,
) -> Result<RevisitReport, dc_loc_core::validate::ConfigError> {
    cfg.r#loop.enabled = true;
    let mut p = Pipeline::new(cfg)?;
    let mut seen = Collected::default();
    feed(drive, &mut p, |events| seen.take(events));
    seen.take(p.finish());
    let truth = keyframe_truth(drive, &seen.keyframes, |s| s.lap.lap);
    let radar_odometry = !seen.odometry.is_empty();
    let track: Vec<OdometryTrackSample> = if radar_odometry {
        seen.odometry.clone()
    } else {
        drive
            .odometry
            .iter()
            .map(|o| (o.stamp, o.t_odom_body, o.covariance))
            .collect()
    };
    let mut odometry = measure_odometry(drive, &track).unwrap_or_default();
    if !radar_odometry {
        // The simulated wheel odometry's covariance is a fixed stand-in, not an estimate to judge.
        odometry.windows = 0;
        odometry.nees_mean = 0.0;
        odometry.nees_above_99 = 0.0;
    }
    let drift = if radar_odometry {
        odometry.share
    } else {
        measured_drift(drive)
    };
    let mut report = judge(truth, reverse_radius(drive), drift, &seen, p.stats());
    report.odometry = odometry;
    Ok(report)
}

/// Pushes a simulated drive's inputs through `p` in time order (its scans as decoded detections),
/// handing each input's events to `sink`.
pub fn feed(drive: &SimDrive, p: &mut Pipeline, mut sink: impl FnMut(Vec<Event>)) {
    for input in SimInputs::new(drive, ScanEncoding::Detections).flatten() {
        sink(p.push(&input));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::noise::NoiseConfig;

    /// `--gamma-shape` and `--noise-factors` reach the simulated noise (skewness 2 / sqrt(shape), the
    /// scales times the factors) and the scenario's label; the defaults leave the label as it was.
    #[test]
    fn a_gamma_shape_and_noise_factors_reach_the_simulated_noise_and_the_label() {
        use rand::SeedableRng;
        let mut scenario = RevisitScenario::new(RadarPreset::Carla, NoiseModel::Gamma, 0.01, false);
        assert_eq!(scenario.label(), "carla gamma 1% same");
        scenario.gamma_shape = 100.0;
        assert_eq!(scenario.label(), "carla gamma shape 100 1% same");
        scenario.noise_factors = [1.0, 0.5, 2.0];
        assert_eq!(scenario.label(), "carla gamma shape 100 x1,0.5,2 1% same");
        let scaled = scenario.sim_config().noise.std_devs();
        let own = NoiseConfig::default().gamma;
        assert_eq!(scaled.range, own.range);
        assert_eq!(scaled.azimuth, 0.5 * own.azimuth);
        assert_eq!(scaled.velocity, 2.0 * own.velocity);
        scenario.noise_factors = [1.0; 3];
        let noise = scenario.sim_config().noise;
        let sampler = crate::sim::noise::NoiseSampler::new(&noise).expect("valid");
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let n = 100_000;
        let range: Vec<f64> = (0..n).map(|_| sampler.sample(&mut rng)[0]).collect();
        let m = range.iter().sum::<f64>() / n as f64;
        let sd = (range.iter().map(|r| (r - m).powi(2)).sum::<f64>() / n as f64).sqrt();
        let skew = range.iter().map(|r| ((r - m) / sd).powi(3)).sum::<f64>() / n as f64;
        assert!((skew - 0.2).abs() < 0.05, "skewness {skew}");
        assert!(
            (sd / noise.std_devs().range - 1.0).abs() < 0.02,
            "scale {sd}"
        );
    }
}
