//! `dc_loc eval --set dev|test`: the paper's evaluation protocol on every world of a protocol set
//! ([`crate::sim::families`]), with each radar set and noise model asked for.
//!
//! Each world is simulated as `dc_loc revisits` does (a 72 km/h lap, then a 40 km/h lap the same way,
//! 1 % odometry drift), its inputs go through the one input path as a bag's would (scans encoded as
//! the simulator's PointCloud2), and its keyframe pairs are registered with the chosen methods. One row
//! a world and method; `--export-pairs DIR` writes each world's pairs to `DIR/<world>`.

use super::CliError;
use super::eval::{EvalArgs, eval_config, export, methods};
use super::revisits::{parse_noise, parse_preset, protocol_set, with_overrides};
use crate::eval::judge::CHI2_3_99;
use crate::eval::report::stats;
use crate::eval::revisits::RevisitScenario;
use crate::eval::{Collector, EvalConfig, EvalKeyframe, PairResult, evaluate, make_pairs};
use crate::pipeline::Config;
use crate::sim::inputs::{ScanEncoding, SimInputs};
use crate::sim::simulate;

/// Runs `dc_loc eval --set`.
pub fn main(args: &EvalArgs) -> Result<(), CliError> {
    let Some(set) = &args.set else {
        return Err(CliError::Usage("--set dev|test is required".into()));
    };
    let eval = eval_config(args);
    eval.validate()
        .map_err(|e| CliError::Usage(e.to_string()))?;
    let scenarios = scenarios(args, set)?;
    let methods = methods(args);
    let mut table = vec![header()];
    for s in &scenarios {
        eprintln!("dc_loc eval: {}", s.label());
        let (kfs, cfg) = keyframes(s, &args.source.overrides, &eval)?;
        let pairs = make_pairs(&kfs, &eval);
        let results = evaluate(&kfs, &pairs, &methods, &cfg.registration, &eval);
        for &m in &methods {
            let of: Vec<&PairResult> = results.iter().filter(|r| r.method == m).collect();
            table.push(row(&s.label(), &m.name(), &of, &eval));
        }
        if let Some(dir) = &args.export_pairs {
            export(
                &dir.join(slug(&s.label())),
                &kfs,
                &pairs,
                &cfg,
                &eval,
                &s.label(),
            )?;
        }
    }
    println!("{}", table.join("\n"));
    Ok(())
}

/// One scenario a world of the set, radar set and noise model, at 1 % drift, both laps the same way.
fn scenarios(args: &EvalArgs, set: &str) -> Result<Vec<RevisitScenario>, CliError> {
    let mut out = Vec::new();
    for world in protocol_set(set)? {
        for r in &args.radars {
            for n in &args.noise {
                out.push(RevisitScenario {
                    seed: world.seed,
                    world: world.family,
                    ..RevisitScenario::new(parse_preset(r)?, parse_noise(n)?, 0.01, false)
                });
            }
        }
    }
    Ok(out)
}

/// Simulates a scenario and collects its keyframes with ground truth through the input path.
fn keyframes(
    s: &RevisitScenario,
    overrides: &[String],
    eval: &EvalConfig,
) -> Result<(Vec<EvalKeyframe>, Config), CliError> {
    let drive = simulate(&s.sim_config()).map_err(|e| CliError::Usage(e.to_string()))?;
    let cfg = with_overrides(&drive.to_config(), overrides).map_err(CliError::Usage)?;
    let mut collector = Collector::new(&cfg, eval).map_err(|e| CliError::Usage(e.to_string()))?;
    for input in SimInputs::new(&drive, ScanEncoding::Clouds).flatten() {
        collector.push(&input);
    }
    Ok((collector.finish().0, cfg))
}

fn header() -> String {
    "| world | method | pairs inside 2 m | translation mean / median / max (m) | rotation mean (rad) | \
     mean NEES | above the 99 % bound |\n|---|---|---|---|---|---|---|"
        .into()
}

/// A table row: errors over the pairs inside the outlier threshold, NEES over the same pairs.
fn row(world: &str, method: &str, results: &[&PairResult], eval: &EvalConfig) -> String {
    let inside: Vec<&&PairResult> = results
        .iter()
        .filter(|r| r.translation_error <= eval.outlier_threshold)
        .collect();
    let [t_mean, t_max, t_median] = stats(inside.iter().map(|r| r.translation_error).collect());
    let rot = stats(inside.iter().map(|r| r.rotation_error).collect())[0];
    let nees: Vec<f64> = inside.iter().filter_map(|r| r.nees).collect();
    let (nees_mean, above) = if nees.is_empty() {
        ("-".to_string(), "-".to_string())
    } else {
        let above = nees.iter().filter(|&&x| x > CHI2_3_99).count();
        (
            format!("{:.2}", stats(nees.clone())[0]),
            format!("{:.1} %", 100.0 * above as f64 / nees.len() as f64),
        )
    };
    format!(
        "| {world} | {method} | {}/{} | {t_mean:.3} / {t_median:.3} / {t_max:.3} | {rot:.4} | \
         {nees_mean} | {above} |",
        inside.len(),
        results.len(),
    )
}

/// A directory name for a scenario label (`suburb/101 carla gaussian 1% same` ->
/// `suburb-101-carla-gaussian-1pct-same`).
fn slug(label: &str) -> String {
    label
        .replace('%', "pct")
        .split(|c: char| !c.is_ascii_alphanumeric())
        .filter(|s| !s.is_empty())
        .collect::<Vec<_>>()
        .join("-")
}
