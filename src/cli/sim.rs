//! `dc_loc sim`: simulate a drive and write it as a rosbag2 bag directory with its params file
//! (see [`crate::sim::export`] for the bag's contents).
//!
//! The drive is `SimConfig::default()` (the paper's CARLA experiment), then the `--config` YAML (any
//! [`SimConfig`] fields; unknown keys are refused), then the flags.

use std::path::{Path, PathBuf};

use clap::ValueEnum;

use super::CliError;
use crate::bag::BagError;
use crate::io::tum::tum_line;
use crate::math::iso3_from_iso2;
use crate::sim::export::{ExportError, drive_description, export_drive};
use crate::sim::{NoiseConfig, NoiseModel, RadarPreset, SimConfig, WorldFamily, simulate};

/// Radar sets of `--preset`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PresetArg {
    /// One forward radar (100 m, 150 deg, 13 Hz), as the paper's CARLA data.
    Carla,
    /// The five ARS408-21 radars of the nuScenes car.
    Nuscenes,
    /// One forward TI AWR1843-class radar (50 m, 120 deg, 15 Hz, noisier azimuth).
    Ti,
    /// One forward 4D imaging radar (elevation, up to 2,000 detections a scan, road returns).
    Imaging,
}

/// Kinds of street of `--world` ([`WorldFamily`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum WorldArg {
    /// The default city: four lanes, parking, buildings with gaps and setbacks.
    City,
    /// Two lanes, detached houses behind gardens, tree rows.
    Suburb,
    /// Long flat warehouse walls with few gaps.
    Industrial,
    /// Six lanes, guard rail posts, distant buildings, no parking.
    Arterial,
    /// Streets lined by the same parked cars on every lap.
    Parking,
    /// Four lanes between guard rails, little else.
    Highway,
    /// A 1 km x 140 m loop between unbroken walls (its own road).
    Corridor,
}

/// Noise models of `--noise`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum NoiseArg {
    /// Gaussian (the paper's N(0, 0.25^2) m, N(0, (0.5 deg)^2), N(0, 0.1^2) m/s).
    Gaussian,
    /// Zero-mean Gamma.
    Gamma,
    /// Scaled Student-t with 100 degrees of freedom.
    StudentT,
    /// No measurement noise.
    None,
}

/// Arguments of `dc_loc sim`.
#[derive(Debug, Clone, clap::Args)]
pub struct SimArgs {
    /// Bag directory to write (created; must not exist or be empty). The params file goes inside.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Simulator configuration YAML (fields of SimConfig; unknown keys are refused).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Seed of the world, traffic, noise and odometry.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Radar set.
    #[arg(long, value_enum)]
    pub preset: Option<PresetArg>,
    /// Kind of street: replaces the `world` section of `--config` (and, for `corridor`, its `route`).
    #[arg(long, value_enum)]
    pub world: Option<WorldArg>,
    /// Radar measurement noise model.
    #[arg(long, value_enum)]
    pub noise: Option<NoiseArg>,
    /// Cruise speed of each lap in km/h, comma-separated (one lap per value).
    #[arg(long, value_name = "KMH,...", value_delimiter = ',')]
    pub speeds: Vec<f64>,
    /// Drive the laps after the first the other way round (a U-turn after lap 1).
    #[arg(long)]
    pub reverse_lap: bool,
    /// Odometry speed scale error, as a fraction (0.01: distances 1 % too long).
    #[arg(long, value_name = "FRACTION", allow_negative_numbers = true)]
    pub odom_scale_error: Option<f64>,
    /// Odometry yaw-rate bias, deg/s.
    #[arg(long, value_name = "DEG_PER_S", allow_negative_numbers = true)]
    pub odom_yaw_rate_bias_deg: Option<f64>,
    /// Also write the drive as a nuScenes dataset (tables in `<DIR>/v1.0-mini`, radar PCDs, one scene
    /// per lap) for `dc_loc eval --nuscenes DIR`; needs `--preset nuscenes`.
    #[arg(long, value_name = "DIR")]
    pub nuscenes_out: Option<PathBuf>,
    /// A fleet of this many robots on the drive's world instead of one drive: `<DIR>/robot_<k>` holds
    /// robot k's bag and params file. Each robot drives one lap from its own start (evenly spaced
    /// round the loop, every other one the other way), an hour after the one before, with noise and an
    /// odometry frame of its own.
    #[arg(long, value_name = "N")]
    pub fleet: Option<u32>,
    /// Also write the drive's ground truth (the body's pose in the map frame, as on
    /// `/ground_truth/odom`) as a TUM trajectory file, `t x y z qx qy qz qw` a line, t to the
    /// nanosecond; for `dc_loc eval --ground-truth FILE`.
    #[arg(long, value_name = "FILE", conflicts_with = "fleet")]
    pub ground_truth_tum: Option<PathBuf>,
}

/// The simulator configuration the arguments describe (file, then flags), validated.
pub fn sim_config(args: &SimArgs) -> Result<SimConfig, CliError> {
    let mut cfg = match &args.config {
        None => SimConfig::default(),
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| CliError::Usage(format!("--config {}: {e}", path.display())))?;
            let cfg: Option<SimConfig> = yaml_serde::from_str(&text)
                .map_err(|e| CliError::Usage(format!("--config {}: {e}", path.display())))?;
            // An empty file is the default drive.
            cfg.unwrap_or_default()
        }
    };
    if let Some(seed) = args.seed {
        cfg.seed = seed;
    }
    if let Some(p) = args.preset {
        cfg.radar_preset = match p {
            PresetArg::Carla => RadarPreset::Carla,
            PresetArg::Nuscenes => RadarPreset::Nuscenes,
            PresetArg::Ti => RadarPreset::Ti,
            PresetArg::Imaging => RadarPreset::Imaging,
        };
        // A preset with radars of its own brings their noise scales, the model kept (--noise below
        // may change it); the others keep the noise of the config file.
        if let Some(own) = cfg.radar_preset.own_noise() {
            cfg.noise = NoiseConfig {
                model: cfg.noise.model,
                ..own
            };
        }
        // A preset replaces the custom radars of a config file.
        cfg.radars.clear();
    }
    if let Some(w) = args.world {
        let family = match w {
            WorldArg::City => WorldFamily::City,
            WorldArg::Suburb => WorldFamily::Suburb,
            WorldArg::Industrial => WorldFamily::Industrial,
            WorldArg::Arterial => WorldFamily::Arterial,
            WorldArg::Parking => WorldFamily::Parking,
            WorldArg::Highway => WorldFamily::Highway,
            WorldArg::Corridor => WorldFamily::Corridor,
        };
        family.apply(&mut cfg);
    }
    if let Some(n) = args.noise {
        cfg.noise.model = match n {
            NoiseArg::Gaussian => NoiseModel::Gaussian,
            NoiseArg::Gamma => NoiseModel::Gamma,
            NoiseArg::StudentT => NoiseModel::StudentT,
            NoiseArg::None => NoiseModel::None,
        };
    }
    if !args.speeds.is_empty() {
        let template = cfg.laps.first().copied().unwrap_or_default();
        cfg.laps = args
            .speeds
            .iter()
            .map(|kmh| crate::sim::config::LapConfig {
                speed: kmh / 3.6,
                ..template
            })
            .collect();
    }
    if args.reverse_lap {
        if cfg.laps.len() < 2 {
            return Err(CliError::Usage(
                "--reverse-lap needs at least two laps (see --speeds)".into(),
            ));
        }
        // The other way round from the first lap.
        let first_reverse = cfg.laps.first().is_some_and(|l| l.reverse);
        for lap in cfg.laps.iter_mut().skip(1) {
            lap.reverse = !first_reverse;
        }
    }
    if let Some(e) = args.odom_scale_error {
        cfg.odometry.scale_error = e;
    }
    if let Some(b) = args.odom_yaw_rate_bias_deg {
        cfg.odometry.yaw_rate_bias = b.to_radians();
    }
    cfg.validate()
        .map_err(|e| CliError::Usage(format!("simulator configuration: {e}")))?;
    Ok(cfg)
}

/// Runs `dc_loc sim`.
pub fn main(args: &SimArgs) -> Result<(), CliError> {
    let cfg = sim_config(args)?;
    if args.nuscenes_out.is_some() && cfg.radar_preset != crate::sim::RadarPreset::Nuscenes {
        return Err(CliError::Usage(
            "--nuscenes-out needs the five nuScenes radars: add --preset nuscenes".into(),
        ));
    }
    if let Some(n) = args.fleet {
        if args.nuscenes_out.is_some() {
            return Err(CliError::Usage(
                "--nuscenes-out writes one drive: not with --fleet".into(),
            ));
        }
        let robots = crate::sim::fleet::fleet(&cfg, n)
            .map_err(|e| CliError::Usage(format!("--fleet: {e}")))?;
        for (k, robot) in robots.iter().enumerate() {
            println!("robot {k}:");
            write_drive(robot, &args.out.join(format!("robot_{k}")))?;
        }
        return Ok(());
    }
    let drive = write_drive(&cfg, &args.out)?;
    if let Some(path) = &args.ground_truth_tum {
        write_ground_truth_tum(&drive, path)?;
    }
    if let Some(dir) = &args.nuscenes_out {
        let ex = crate::sim::nuscenes::export_nuscenes(&drive, dir, "v1.0-mini", "sim-city")
            .map_err(|e| CliError::Runtime(e.to_string()))?;
        println!(
            "nuScenes: {} (v1.0-mini, scenes {}, {} sweeps of which {} keyframes)",
            dir.display(),
            ex.scenes.join(", "),
            ex.sweeps,
            ex.keyframes
        );
    }
    Ok(())
}

/// Simulates `cfg`, writes it to the bag directory `out` with its params file and prints a summary.
fn write_drive(cfg: &SimConfig, out: &std::path::Path) -> Result<crate::sim::SimDrive, CliError> {
    log::info!("simulating: {}", drive_description(cfg));
    let drive =
        simulate(cfg).map_err(|e| CliError::Usage(format!("simulator configuration: {e}")))?;
    let summary = export_drive(&drive, out).map_err(|e| match e {
        ExportError::Bag(BagError::AlreadyExists { .. } | BagError::InvalidBagPath { .. }) => {
            CliError::Usage(format!("--out: {e}"))
        }
        e => CliError::Runtime(e.to_string()),
    })?;
    let detections: usize = drive.scans.iter().map(|s| s.scan.detections.len()).sum();
    let traj = &drive.setup.trajectory;
    println!("drive: {}", drive_description(cfg));
    println!(
        "duration {:.1} s, distance {:.0} m, {} lap{}",
        traj.duration(),
        traj.distance(),
        cfg.laps.len(),
        if cfg.laps.len() == 1 { "" } else { "s" }
    );
    println!(
        "scans {} from {} radar{}, detections {detections}",
        drive.scans.len(),
        drive.setup.radars.len(),
        if drive.setup.radars.len() == 1 {
            ""
        } else {
            "s"
        }
    );
    println!(
        "bag: {} ({} messages)",
        summary.bag_dir.display(),
        summary.messages
    );
    for t in &summary.topics {
        println!("  {} {} x{}", t.topic, t.type_name, t.count);
    }
    println!("params: {}", summary.params_file.display());
    Ok(drive)
}

/// Writes the drive's ground truth to `path` as a TUM trajectory file and says so.
fn write_ground_truth_tum(drive: &crate::sim::SimDrive, path: &Path) -> Result<(), CliError> {
    let mut text = String::from("# t x y z qx qy qz qw: the body in the map frame (s, m)\n");
    for p in &drive.ground_truth {
        text.push_str(&tum_line(p.stamp, &iso3_from_iso2(&p.t_map_body)));
        text.push('\n');
    }
    std::fs::write(path, text)
        .map_err(|e| CliError::Runtime(format!("--ground-truth-tum {}: {e}", path.display())))?;
    println!(
        "ground truth: {} ({} poses)",
        path.display(),
        drive.ground_truth.len()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(config: Option<PathBuf>, preset: PresetArg, noise: Option<NoiseArg>) -> SimArgs {
        SimArgs {
            out: PathBuf::from("unused"),
            config,
            seed: None,
            preset: Some(preset),
            world: None,
            noise,
            speeds: Vec::new(),
            reverse_lap: false,
            odom_scale_error: None,
            odom_yaw_rate_bias_deg: None,
            nuscenes_out: None,
            fleet: None,
            ground_truth_tum: None,
        }
    }

    /// A preset with radars of its own brings their noise scales whatever the file says; the paper's
    /// radars keep the file's. The model is the file's unless `--noise` names one.
    #[test]
    fn a_preset_brings_its_radars_noise_and_keeps_the_model() {
        let dir = std::env::temp_dir().join(format!("dc_loc_sim_args_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("sim.yaml");
        std::fs::write(&file, "noise:\n  model: gamma\n  gamma:\n    range: 0.4\n").unwrap();

        let ti = sim_config(&args(Some(file.clone()), PresetArg::Ti, None)).unwrap();
        assert_eq!(ti.noise.model, NoiseModel::Gamma);
        assert_eq!(ti.noise.gamma.range, 0.1);
        assert!((ti.noise.gaussian.azimuth - 1.5f64.to_radians()).abs() < 1e-12);

        let carla = sim_config(&args(Some(file.clone()), PresetArg::Carla, None)).unwrap();
        assert_eq!(carla.noise.model, NoiseModel::Gamma);
        assert_eq!(carla.noise.gamma.range, 0.4);

        let named = sim_config(&args(
            Some(file),
            PresetArg::Imaging,
            Some(NoiseArg::StudentT),
        ));
        let named = named.unwrap();
        assert_eq!(named.noise.model, NoiseModel::StudentT);
        assert_eq!(named.noise.student_t.range, 0.1);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
