//! `dc_loc revisits`: precision and recall of the published loop closures on simulated drives, over a
//! matrix of radar sets, noise models, odometry drifts and lap directions ([`crate::eval::revisits`]).
//!
//! Scenarios run in parallel (rayon); the table goes to stdout in Markdown, every judged closure to
//! `--closures-out` as JSON lines when given.

use std::io::Write;
use std::path::PathBuf;

use rayon::prelude::*;

use super::CliError;
use crate::eval::judge::{RevisitReport, format_revisit_table};
use crate::eval::revisits::{
    CalibrationError, DEFAULT_GAMMA_SHAPE, RevisitScenario, evaluate_scenario,
};
use crate::odometry::OdometrySource;
use crate::params::{ParamSet, apply, flatten_config};
use crate::pipeline::Config;
use crate::sim::families::{self, ProtocolWorld};
use crate::sim::{NoiseModel, RadarPreset, WorldFamily};

/// Arguments of `dc_loc revisits`.
#[derive(Debug, Clone, clap::Args)]
pub struct RevisitArgs {
    /// Radar sets: `carla` (one forward radar), `nuscenes` (five ARS408), `ti` (one forward TI
    /// AWR1843-class radar), `imaging` (one forward 4D imaging radar).
    #[arg(long, value_delimiter = ',', default_value = "carla,nuscenes")]
    pub radars: Vec<String>,
    /// Noise models: `gaussian`, `gamma`, `student-t`, `none` (no measurement noise, for geometry experiments).
    #[arg(long, value_delimiter = ',', default_value = "gaussian")]
    pub noise: Vec<String>,
    /// Odometry drift, percent of distance (the yaw-rate bias is 0.1 deg/s per percent).
    #[arg(long, value_delimiter = ',', default_value = "1,3")]
    pub drift: Vec<f64>,
    /// Lap directions: `same`, `reverse`.
    #[arg(long, value_delimiter = ',', default_value = "same,reverse")]
    pub direction: Vec<String>,
    /// Simulator seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Kinds of street: `city` (the default world), `suburb`, `industrial`, `arterial`, `parking`,
    /// `highway`, `corridor`.
    #[arg(long, value_delimiter = ',', default_value = "city")]
    pub world: Vec<String>,
    /// A protocol set instead of `--world` and `--seed`: `dev` (the worlds tuning may look at: the city
    /// with seeds 1 and 2) or `test` (held out: every other family, each with its own seed).
    #[arg(long, value_name = "dev|test", conflicts_with_all = ["world", "seed"])]
    pub set: Option<String>,
    /// Extrinsic calibration error of every radar the pipeline is given: yaw in degrees and offset in
    /// metres (e.g. `1.5,0.05`), sign and direction varying from radar to radar.
    #[arg(
        long,
        value_name = "DEG,M",
        value_delimiter = ',',
        allow_negative_numbers = true
    )]
    pub calibration_error: Vec<f64>,
    /// Radar clock offset, milliseconds: every other radar's stamps run this far ahead of the time it
    /// measured, the others' as far behind (one radar: ahead). 0: synchronised.
    #[arg(long, value_name = "MS", default_value_t = 0.0)]
    pub time_offset: f64,
    /// Robots of a fleet per world (2 or more; 0: one robot): each drives one lap from its own start,
    /// every other one the other way, and the table counts the closures between robots
    /// (`--direction` is not used then).
    #[arg(long, default_value_t = 0)]
    pub fleet: u32,
    /// Multipath ghost probability of every radar: a reflection also seen via a wall, at its mirror
    /// image, with this probability. 0: no ghosts.
    #[arg(long, value_name = "P", default_value_t = 0.0)]
    pub multipath: f64,
    /// Wheel slip episodes per km driven (each 5-30 % extra odometry distance for 0.5-2 s). 0: none.
    #[arg(long, value_name = "PER_KM", default_value_t = 0.0)]
    pub wheel_slip: f64,
    /// Shape of the Gamma noise (with `--noise gamma`): 1 is the most skewed (skewness 2), larger
    /// shapes are nearer a Gaussian (skewness 2 / sqrt(shape)); the scale stays the same.
    #[arg(long, value_name = "K", default_value_t = DEFAULT_GAMMA_SHAPE)]
    pub gamma_shape: f64,
    /// Factors on the noise model's range, azimuth and radial-velocity scales, each above 0 (e.g.
    /// `1,0.01,0.01`: the range noise alone). The pipeline is told the scaled standard deviations.
    #[arg(long, value_name = "R,AZ,V", value_delimiter = ',', default_values_t = [1.0, 1.0, 1.0])]
    pub noise_factors: Vec<f64>,
    /// Parameter override applied to every scenario's pipeline configuration (repeatable).
    #[arg(short = 'p', long = "param", value_name = "NAME:=VALUE")]
    pub overrides: Vec<String>,
    /// Where the pipeline's odometry comes from: `topic` (the simulated wheel odometry, drifting by
    /// `--drift`), `radar` (the radars' Doppler), `radar_imu` (the radars' Doppler and a simulated
    /// 100 Hz gyro).
    #[arg(long, value_delimiter = ',', default_value = "topic")]
    pub odometry: Vec<String>,
    /// Writes every judged closure as JSON lines here.
    #[arg(long, value_name = "FILE")]
    pub closures_out: Option<PathBuf>,
}

pub(super) fn parse_preset(s: &str) -> Result<RadarPreset, CliError> {
    match s {
        "carla" => Ok(RadarPreset::Carla),
        "nuscenes" => Ok(RadarPreset::Nuscenes),
        "ti" => Ok(RadarPreset::Ti),
        "imaging" => Ok(RadarPreset::Imaging),
        _ => Err(CliError::Usage(format!(
            "--radars: unknown radar set `{s}` (carla, nuscenes, ti, imaging)"
        ))),
    }
}

pub(super) fn parse_noise(s: &str) -> Result<NoiseModel, CliError> {
    match s {
        "gaussian" => Ok(NoiseModel::Gaussian),
        "gamma" => Ok(NoiseModel::Gamma),
        "student-t" | "student_t" => Ok(NoiseModel::StudentT),
        "none" => Ok(NoiseModel::None),
        _ => Err(CliError::Usage(format!(
            "--noise: unknown noise model `{s}` (gaussian, gamma, student-t, none)"
        ))),
    }
}

pub(super) fn parse_odometry(s: &str) -> Result<OdometrySource, CliError> {
    match s {
        "topic" => Ok(OdometrySource::Topic),
        "radar" => Ok(OdometrySource::Radar),
        "radar_imu" | "radar-imu" => Ok(OdometrySource::RadarImu),
        _ => Err(CliError::Usage(format!(
            "--odometry: unknown source `{s}` (topic, radar, radar_imu)"
        ))),
    }
}

/// The worlds of the protocol set `name`.
pub(super) fn protocol_set(name: &str) -> Result<Vec<ProtocolWorld>, CliError> {
    families::protocol_set(name)
        .map(<[ProtocolWorld]>::to_vec)
        .ok_or_else(|| CliError::Usage(format!("--set: `{name}` is not `dev` or `test`")))
}

/// The worlds of `args`: the protocol set, or each `--world` family with `--seed`.
fn worlds(args: &RevisitArgs) -> Result<Vec<ProtocolWorld>, CliError> {
    if let Some(name) = &args.set {
        return protocol_set(name);
    }
    args.world
        .iter()
        .map(|w| {
            WorldFamily::parse(w)
                .map(|family| ProtocolWorld {
                    family,
                    seed: args.seed,
                })
                .ok_or_else(|| {
                    let names: Vec<&str> = WorldFamily::ALL.iter().map(|f| f.name()).collect();
                    CliError::Usage(format!(
                        "--world: unknown family `{w}` ({})",
                        names.join(", ")
                    ))
                })
        })
        .collect()
}

/// The calibration error of `--calibration-error`.
fn calibration(args: &RevisitArgs) -> Result<CalibrationError, CliError> {
    match args.calibration_error[..] {
        [] => Ok(CalibrationError::default()),
        [yaw_deg, offset]
            if (0.0..=10.0).contains(&yaw_deg.abs()) && (0.0..=1.0).contains(&offset.abs()) =>
        {
            Ok(CalibrationError { yaw_deg, offset })
        }
        _ => Err(CliError::Usage(format!(
            "--calibration-error: {:?} is not DEG,M within 10 degrees and 1 m",
            args.calibration_error
        ))),
    }
}

/// The scenario matrix of `args`.
pub fn scenarios(args: &RevisitArgs) -> Result<Vec<RevisitScenario>, CliError> {
    let mut out = Vec::new();
    for world in worlds(args)? {
        scenarios_in(args, world, &mut out)?;
    }
    Ok(out)
}

fn scenarios_in(
    args: &RevisitArgs,
    world: ProtocolWorld,
    out: &mut Vec<RevisitScenario>,
) -> Result<(), CliError> {
    if !(args.time_offset.is_finite() && args.time_offset.abs() <= 500.0) {
        return Err(CliError::Usage(format!(
            "--time-offset: {} ms is not within +-500 ms",
            args.time_offset
        )));
    }
    if !(0.0..=1.0).contains(&args.multipath) {
        return Err(CliError::Usage(format!(
            "--multipath: {} is not a probability",
            args.multipath
        )));
    }
    if !(0.0..=1000.0).contains(&args.wheel_slip) {
        return Err(CliError::Usage(format!(
            "--wheel-slip: {} is not within [0, 1000] per km",
            args.wheel_slip
        )));
    }
    if !(args.gamma_shape.is_finite() && (0.1..=1e4).contains(&args.gamma_shape)) {
        return Err(CliError::Usage(format!(
            "--gamma-shape: {} is not within [0.1, 10000]",
            args.gamma_shape
        )));
    }
    let noise_factors: [f64; 3] = match args.noise_factors[..] {
        [r, a, v] if [r, a, v].iter().all(|f| f.is_finite() && *f > 0.0) => [r, a, v],
        _ => {
            return Err(CliError::Usage(format!(
                "--noise-factors: {:?} is not three factors above 0",
                args.noise_factors
            )));
        }
    };
    for r in &args.radars {
        let radars = parse_preset(r)?;
        for o in &args.odometry {
            let odometry = parse_odometry(o)?;
            scenarios_for(args, world, radars, odometry, noise_factors, out)?;
        }
    }
    Ok(())
}

/// The scenarios of one world, radar set and odometry source: every noise model, drift and direction.
fn scenarios_for(
    args: &RevisitArgs,
    world: ProtocolWorld,
    radars: RadarPreset,
    odometry: OdometrySource,
    noise_factors: [f64; 3],
    out: &mut Vec<RevisitScenario>,
) -> Result<(), CliError> {
    {
        for n in &args.noise {
            let noise = parse_noise(n)?;
            for &d in &args.drift {
                if !(d.is_finite() && (0.0..=20.0).contains(&d)) {
                    return Err(CliError::Usage(format!(
                        "--drift: {d} is not a percentage in [0, 20]"
                    )));
                }
                let directions = if args.fleet >= 2 {
                    &args.direction[..args.direction.len().min(1)]
                } else {
                    &args.direction[..]
                };
                for dir in directions {
                    let reverse = match dir.as_str() {
                        "same" => false,
                        "reverse" => true,
                        _ => {
                            return Err(CliError::Usage(format!(
                                "--direction: `{dir}` is not `same` or `reverse`"
                            )));
                        }
                    };
                    out.push(RevisitScenario {
                        radars,
                        noise,
                        drift: d / 100.0,
                        reverse,
                        seed: world.seed,
                        world: world.family,
                        calibration: calibration(args)?,
                        fleet: args.fleet,
                        time_offset: args.time_offset / 1e3,
                        multipath: args.multipath,
                        wheel_slip: args.wheel_slip,
                        gamma_shape: args.gamma_shape,
                        noise_factors,
                        odometry,
                    });
                }
            }
        }
    }
    Ok(())
}

/// Applies `-p` overrides to a scenario's own configuration.
pub(super) fn with_overrides(cfg: &Config, overrides: &[String]) -> Result<Config, String> {
    let mut set = ParamSet::default();
    for (n, v) in flatten_config(cfg) {
        set.set(n, v);
    }
    for o in overrides {
        set.set_override(o).map_err(|e| format!("-p: {e}"))?;
    }
    apply(&set).map_err(|e| format!("-p: {e}"))
}

/// Runs `dc_loc revisits`.
pub fn main(args: &RevisitArgs) -> Result<(), CliError> {
    let list = scenarios(args)?;
    // Check the overrides once, on the first scenario, before hours of work.
    if let Some(first) = list.first() {
        let drive_cfg = crate::sim::SimSetup::new(&first.sim_config())
            .map_err(|e| CliError::Usage(e.to_string()))?
            .to_config();
        with_overrides(&drive_cfg, &args.overrides).map_err(CliError::Usage)?;
    }
    eprintln!("dc_loc revisits: {} scenarios", list.len());
    let results: Vec<Result<RevisitReport, String>> = list
        .par_iter()
        .map(|s| {
            let mut err = None;
            let r = evaluate_scenario(s, |cfg| match with_overrides(cfg, &args.overrides) {
                Ok(c) => *cfg = c,
                Err(e) => err = Some(e),
            })
            .map_err(|e| e.to_string());
            if let Some(e) = err {
                return Err(e);
            }
            if let Ok(rep) = &r {
                eprintln!(
                    "  {}: same {}/{} closed, {} false; reverse {}/{} closed, {} false; rejected {:?}; missed opportunities had {:?}",
                    rep.scenario,
                    rep.same.closed,
                    rep.same.opportunities,
                    rep.same.false_closures,
                    rep.reverse.closed,
                    rep.reverse.opportunities,
                    rep.reverse.false_closures,
                    rep.rejected,
                    rep.missed
                );
            }
            r
        })
        .collect();
    let mut reports = Vec::new();
    for r in results {
        reports.push(r.map_err(CliError::Runtime)?);
    }
    print!("{}", format_revisit_table(&reports));
    if let Some(path) = &args.closures_out {
        let mut f = std::io::BufWriter::new(
            std::fs::File::create(path)
                .map_err(|e| CliError::Runtime(format!("{}: {e}", path.display())))?,
        );
        for r in &reports {
            for c in &r.closures {
                let line = serde_json::json!({"scenario": r.scenario, "closure": c});
                writeln!(f, "{line}")
                    .map_err(|e| CliError::Runtime(format!("{}: {e}", path.display())))?;
            }
        }
        f.flush()
            .map_err(|e| CliError::Runtime(format!("{}: {e}", path.display())))?;
    }
    let false_total: usize = reports
        .iter()
        .map(|r| r.same.false_closures + r.reverse.false_closures)
        .sum();
    if false_total > 0 {
        eprintln!("dc_loc revisits: {false_total} false closures over all scenarios");
    }
    Ok(())
}
