//! `dc_loc demo`: the whole method on the built-in default, in one command: simulate the default two-lap
//! drive (72 then 40 km/h, forward radar), write it as a rosbag2 bag, run the pipeline over it and
//! evaluate every method against ground truth, printing the paper's tables and where the plot is.

use std::path::PathBuf;
use std::time::Instant;

use super::CliError;
use super::eval::{GroundTruth, collect, evaluate_and_report};
use super::params::load_params;
use crate::eval::{EvalConfig, Method};
use crate::sim::export::export_drive;
use crate::sim::{NoiseModel, SimConfig, simulate};

/// Arguments of `dc_loc demo`.
#[derive(Debug, Clone, clap::Args)]
pub struct DemoArgs {
    /// Output directory (the bag, its params file, the plot, the per-pair results).
    #[arg(long, value_name = "DIR", default_value = "out/demo")]
    pub out: PathBuf,
    /// Noise model of the simulated radar.
    #[arg(long, value_enum, default_value = "gaussian")]
    pub noise: super::sim::NoiseArg,
    /// Simulation seed.
    #[arg(long, default_value_t = SimConfig::default().seed)]
    pub seed: u64,
}

/// Runs `dc_loc demo`.
pub fn main(args: &DemoArgs) -> Result<(), CliError> {
    let t0 = Instant::now();
    let mut sim = SimConfig {
        seed: args.seed,
        ..SimConfig::default()
    };
    sim.noise.model = match args.noise {
        super::sim::NoiseArg::Gaussian => NoiseModel::Gaussian,
        super::sim::NoiseArg::Gamma => NoiseModel::Gamma,
        super::sim::NoiseArg::StudentT => NoiseModel::StudentT,
        super::sim::NoiseArg::None => NoiseModel::None,
    };
    sim.validate().map_err(|e| CliError::Usage(e.to_string()))?;
    println!(
        "1/3 simulating the default drive (seed {}, {:?} noise)...",
        sim.seed, sim.noise.model
    );
    let drive = simulate(&sim).map_err(|e| CliError::Usage(e.to_string()))?;
    let bag_dir = args.out.join("drive");
    if bag_dir.exists() {
        std::fs::remove_dir_all(&bag_dir)
            .map_err(|e| CliError::Runtime(format!("{}: {e}", bag_dir.display())))?;
    }
    let summary = export_drive(&drive, &bag_dir).map_err(|e| CliError::Runtime(e.to_string()))?;
    println!(
        "    {:.0} s, {:.0} m, {} scans -> {} ({} messages)",
        drive.setup.trajectory.duration(),
        drive.setup.trajectory.distance(),
        drive.scans.len(),
        summary.bag_dir.display(),
        summary.messages
    );
    drop(drive);
    println!("2/3 running the pipeline over the bag...");
    let cfg = load_params(&summary.params_file, "/", "dc_loc", &[])?;
    let eval = EvalConfig::default();
    let kfs = collect(
        &summary.bag_dir,
        &cfg,
        &GroundTruth::topic(crate::sim::export::GROUND_TRUTH_TOPIC),
        &eval,
    )?;
    println!("3/3 registering keyframe pairs of the two laps with every method...\n");
    evaluate_and_report(&kfs, &cfg, &eval, &Method::all(), &args.out)?;
    println!("\ndemo finished in {:.1} s", t0.elapsed().as_secs_f64());
    Ok(())
}
