//! `dc_loc eval`: the paper's evaluation protocol on a bag with ground truth (the datasets on disk:
//! [`super::eval_datasets`]).
//!
//! Drives the pipeline over the bag (revisit search off), pairs keyframes of different passes over the
//! same place by ground truth, registers every pair with every method and ablation row, prints the
//! paper's Table 1 and Table 2 layouts and the errors by ego-velocity difference, and writes
//! `eval.svg` (error against velocity difference) and `pairs.jsonl` (every pair and method) into
//! `--out-dir`.

use std::io::Write;
use std::path::{Path, PathBuf};

use super::params::load_params;
use super::source::{SourceArgs, bag_inputs};
use super::{CliError, progress};
use crate::bag::BagReader;
use crate::eval::export::export_pairs;
use crate::eval::report::{self, MethodSummary};
use crate::eval::{
    Collector, EvalConfig, EvalKeyframe, Method, Pair, PairResult, evaluate, make_pairs,
};
use crate::input::Input;
use crate::pipeline::Config;

/// Arguments of `dc_loc eval`.
#[derive(Debug, Clone, clap::Args)]
pub struct EvalArgs {
    /// The data and its parameters (a bag needs ground truth on `--ground-truth-topic`; nuScenes
    /// pairs scenes at one location, View-of-Delft runs of consecutive frames).
    #[command(flatten)]
    pub source: SourceArgs,
    /// nuScenes: skip scenes whose sweep files are missing (a partly extracted trainval) instead of
    /// stopping.
    #[arg(long)]
    pub skip_incomplete_scenes: bool,
    /// nuScenes: odometry from the ego poses with this relative scale error (0.01 = 1 %).
    #[arg(long, default_value_t = 0.0)]
    pub odometry_scale_error: f64,
    /// nuScenes: odometry from the ego poses with this yaw-rate bias, deg/s.
    #[arg(long, default_value_t = 0.0)]
    pub odometry_yaw_bias_deg: f64,
    /// Ground-truth nav_msgs/Odometry topic (map frame).
    #[arg(long, default_value = "/ground_truth/odom")]
    pub ground_truth_topic: String,
    /// Where the plot and the per-pair results go.
    #[arg(long, value_name = "DIR", default_value = "out/eval")]
    pub out_dir: PathBuf,
    /// Pairs: ground-truth distance at most this, m.
    #[arg(long, default_value_t = 5.0)]
    pub pair_radius: f64,
    /// Pairs: ground-truth path between the two keyframes at least this, m (another pass).
    #[arg(long, default_value_t = 200.0)]
    pub min_pass_gap: f64,
    /// Include pairs driven in opposite directions (the paper's pairs share the heading).
    #[arg(long)]
    pub any_heading: bool,
    /// Only DC-Loc (skip the baselines and the ablation).
    #[arg(long)]
    pub dcloc_only: bool,
    /// A protocol set of simulated worlds instead of a bag: `dev` (the worlds tuning may look at) or
    /// `test` (held out). Each world is driven twice (72 then 40 km/h, 1 % odometry drift) with each
    /// `--radars` set and `--noise` model, and evaluated as a bag is.
    #[arg(long, value_name = "dev|test", conflicts_with_all = ["bag", "nuscenes", "vod"])]
    pub set: Option<String>,
    /// With `--set`: radar sets, `carla` (one forward radar), `nuscenes` (five ARS408), `ti`.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "carla,nuscenes",
        requires = "set"
    )]
    pub radars: Vec<String>,
    /// With `--set`: noise models, `gaussian`, `gamma`, `student-t`, `none` (no measurement noise).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "gaussian",
        requires = "set"
    )]
    pub noise: Vec<String>,
    /// Writes the pairs, their submaps and DC-Loc's single-threaded result on each into this directory
    /// (one subdirectory a world with `--set`), for registering them with other tools
    /// (`examples/peers.py`). Not with `--nuscenes` or `--vod`.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["nuscenes", "vod"])]
    pub export_pairs: Option<PathBuf>,
}

/// What an evaluation produced.
pub struct EvalOutcome {
    /// Keyframes with ground truth.
    pub keyframes: usize,
    /// Pairs evaluated.
    pub pairs: usize,
    /// Per method.
    pub summaries: Vec<MethodSummary>,
    /// The plot.
    pub plot: PathBuf,
}

fn bar(len: u64, what: &str) -> indicatif::ProgressBar {
    progress::bar(
        len,
        &format!("{{elapsed_precise}} [{{wide_bar}}] {{pos}}/{{len}} {what} ({{eta}} left)"),
    )
}

/// Collects the keyframes of a bag with ground truth.
pub fn collect(
    bag: &Path,
    cfg: &Config,
    gt_topic: &str,
    eval: &EvalConfig,
) -> Result<Vec<EvalKeyframe>, CliError> {
    let reader = BagReader::open(bag).map_err(|e| CliError::Runtime(e.to_string()))?;
    let inputs = bag_inputs(&reader, cfg, Some(gt_topic))?;
    let mut collector = Collector::new(cfg, eval).map_err(|e| CliError::Usage(e.to_string()))?;
    let bar = bar(inputs.total_messages(), "messages");
    let (mut ground_truth, mut radar, mut odometry, mut skipped) = (0u64, 0u64, 0u64, 0u64);
    let mut causes = crate::repeats::Repeats::default();
    for item in inputs {
        bar.inc(1);
        match item {
            Ok(input) => {
                match &input {
                    Input::GroundTruth { .. } => ground_truth += 1,
                    Input::Radar { .. } | Input::Scan(_) => radar += 1,
                    Input::Odometry { .. } => odometry += 1,
                    Input::Keyframe(_) | Input::Imu { .. } => {}
                }
                collector.push(&input);
            }
            Err(issue) => {
                skipped += 1;
                issue.log_once(&mut causes);
            }
        }
    }
    progress::clear(&bar);
    if ground_truth == 0 {
        return Err(CliError::Usage(format!(
            "no ground truth on {gt_topic} in {}",
            bag.display()
        )));
    }
    let (kfs, _) = collector.finish();
    log::info!(
        "{radar} radar clouds, {odometry} odometry, {ground_truth} ground truth, {skipped} skipped; \
         {} keyframes with ground truth",
        kfs.len()
    );
    Ok(kfs)
}

/// Pairs, registers, summarises, prints and writes the outputs.
pub fn evaluate_and_report(
    kfs: &[EvalKeyframe],
    cfg: &Config,
    eval: &EvalConfig,
    methods: &[Method],
    out_dir: &Path,
) -> Result<EvalOutcome, CliError> {
    let pairs = make_pairs(kfs, eval);
    if pairs.is_empty() {
        return Err(CliError::Usage(format!(
            "no keyframe pairs: nothing of another pass within {} m (min pass gap {} m)",
            eval.pair_radius, eval.min_pass_gap
        )));
    }
    let bar = bar(pairs.len() as u64, "pairs");
    // Chunks keep the progress bar moving while rayon works inside each.
    let mut results: Vec<PairResult> = Vec::new();
    for chunk in pairs.chunks(16) {
        results.extend(evaluate(kfs, chunk, methods, &cfg.registration, eval));
        bar.inc(chunk.len() as u64);
    }
    progress::clear(&bar);
    let summaries = report::summarize(&results, methods, eval);
    let plot = write_and_print(
        &summaries,
        eval,
        methods,
        out_dir,
        |jsonl| write_pairs(jsonl, kfs, &results),
        &format!(
            "{} keyframes, {} pairs (ground truth within {} m, another pass), outlier threshold {} m\n",
            kfs.len(),
            pairs.len(),
            eval.pair_radius,
            eval.outlier_threshold
        ),
    )?;
    Ok(EvalOutcome {
        keyframes: kfs.len(),
        pairs: pairs.len(),
        summaries,
        plot,
    })
}

/// Writes the plot and the per-pair file (`write_jsonl`) into `out_dir`, prints `intro` and the tables
/// (Table 1 and 2 layouts, ours beside the paper's numbers, errors by velocity difference); returns the
/// plot's path.
pub fn write_and_print(
    summaries: &[MethodSummary],
    eval: &EvalConfig,
    methods: &[Method],
    out_dir: &Path,
    write_jsonl: impl FnOnce(&Path) -> std::io::Result<()>,
    intro: &str,
) -> Result<PathBuf, CliError> {
    std::fs::create_dir_all(out_dir)
        .map_err(|e| CliError::Runtime(format!("{}: {e}", out_dir.display())))?;
    let plot = out_dir.join("eval.svg");
    report::plot_svg(summaries, eval, &plot).map_err(CliError::Runtime)?;
    let jsonl = out_dir.join("pairs.jsonl");
    write_jsonl(&jsonl).map_err(|e| CliError::Runtime(format!("{}: {e}", jsonl.display())))?;
    println!("{intro}");
    println!(
        "Methods (the paper's Table 1 layout):\n{}{}",
        report::table_methods(summaries),
        report::nees_unambiguous_line(summaries, eval)
    );
    if methods.len() > 1 {
        println!(
            "Ablation (the paper's Table 2 layout):\n{}",
            report::table_ablation(summaries)
        );
    }
    println!(
        "Ours beside the paper's nuScenes numbers (Tables 1 and 2):\n{}",
        report::table_paper_comparison(summaries)
    );
    println!(
        "Mean error by ego-velocity difference:\n{}",
        report::table_velocity(summaries, eval)
    );
    println!("plot: {}\nper pair: {}", plot.display(), jsonl.display());
    Ok(plot)
}

fn write_pairs(path: &Path, kfs: &[EvalKeyframe], results: &[PairResult]) -> std::io::Result<()> {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    for r in results {
        let v = serde_json::json!({
            "method": r.method.name(),
            "query_stamp": kfs[r.pair.query].stamp.as_secs_f64(),
            "target_stamp": kfs[r.pair.target].stamp.as_secs_f64(),
            "distance": r.pair.distance,
            "velocity_difference": r.velocity_difference,
            "translation_error": if r.translation_error.is_finite() { Some(r.translation_error) } else { None },
            "rotation_error": if r.rotation_error.is_finite() { Some(r.rotation_error) } else { None },
            "nees": r.nees,
            "overlap": r.overlap,
            "inliers": r.inliers,
            "runner_up_overlap": r.runner_up_overlap,
            "failure": r.failure,
        });
        writeln!(out, "{v}")?;
    }
    out.flush()
}

/// The evaluation settings from the arguments.
pub fn eval_config(args: &EvalArgs) -> EvalConfig {
    EvalConfig {
        pair_radius: args.pair_radius,
        min_pass_gap: args.min_pass_gap,
        max_heading_difference: if args.any_heading {
            std::f64::consts::PI
        } else {
            std::f64::consts::FRAC_PI_2
        },
        ..EvalConfig::default()
    }
}

/// The methods to evaluate: every method and ablation row, or DC-Loc alone.
pub fn methods(args: &EvalArgs) -> Vec<Method> {
    if args.dcloc_only {
        vec![Method::DCLOC]
    } else {
        Method::all()
    }
}

/// Runs `dc_loc eval --bag`.
pub fn main(args: &EvalArgs) -> Result<(), CliError> {
    let Some(bag) = &args.source.bag else {
        return Err(CliError::Usage(
            "--bag, --nuscenes, --vod or --set is required".into(),
        ));
    };
    let Some(params) = &args.source.params else {
        return Err(CliError::Usage(
            "--bag needs --params (the params file of the bag's radars and topics)".into(),
        ));
    };
    let src = &args.source;
    let cfg = load_params(params, "/", &src.node_name, &src.overrides)?;
    let eval = eval_config(args);
    eval.validate()
        .map_err(|e| CliError::Usage(e.to_string()))?;
    let kfs = collect(bag, &cfg, &args.ground_truth_topic, &eval)?;
    evaluate_and_report(&kfs, &cfg, &eval, &methods(args), &args.out_dir)?;
    if let Some(dir) = &args.export_pairs {
        let pairs = make_pairs(&kfs, &eval);
        export(dir, &kfs, &pairs, &cfg, &eval, &bag.display().to_string())?;
    }
    Ok(())
}

/// Writes `pairs` of `kfs` for other tools into `dir` ([`crate::eval::export`]).
pub fn export(
    dir: &Path,
    kfs: &[EvalKeyframe],
    pairs: &[Pair],
    cfg: &Config,
    eval: &EvalConfig,
    source: &str,
) -> Result<(), CliError> {
    export_pairs(dir, kfs, pairs, &cfg.registration, eval, source)
        .map_err(|e| CliError::Runtime(format!("{}: {e}", dir.display())))?;
    println!(
        "pairs for other tools: {} ({} pairs)",
        dir.display(),
        pairs.len()
    );
    Ok(())
}
