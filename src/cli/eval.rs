//! `dc_loc eval`: the paper's evaluation protocol on a bag with ground truth (the datasets on disk:
//! [`super::eval_datasets`]). The ground truth is a topic of the bag or a TUM trajectory file, of the
//! body frame or of another frame on the vehicle ([`GroundTruth`]).
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
use crate::io::ground_truth::to_body;
use crate::io::tum::{TumError, ground_truth_inputs, read_tum};
use crate::math::{Iso3, Stamp, iso3_from_xyz_rpy};
use crate::pipeline::Config;

/// Arguments of `dc_loc eval`.
#[derive(Debug, Clone, clap::Args)]
pub struct EvalArgs {
    /// The data and its parameters (a bag needs ground truth, on `--ground-truth-topic` or in
    /// `--ground-truth`; nuScenes pairs scenes at one location, View-of-Delft runs of consecutive
    /// frames).
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
    /// Ground-truth topic of the bag, nav_msgs/Odometry or geometry_msgs/PoseStamped (map frame).
    #[arg(long, default_value = "/ground_truth/odom")]
    pub ground_truth_topic: String,
    /// Ground truth from this TUM trajectory file instead of a topic: `t x y z qx qy qz qw` a line
    /// (t in seconds on the bag's clock, `#` lines are comments).
    #[arg(
        long,
        value_name = "FILE",
        conflicts_with = "ground_truth_topic",
        requires = "bag"
    )]
    pub ground_truth: Option<PathBuf>,
    /// The body frame's pose in the frame the ground truth tracks (a GNSS/INS unit, say), m and
    /// degrees: `X,Y,Z,YAW_DEG` or `X,Y,Z,ROLL_DEG,PITCH_DEG,YAW_DEG` (roll, pitch, yaw about the
    /// fixed x, y, z axes, as ROS's RPY). Every ground-truth pose becomes `t_map_gt * t_gt_body`.
    /// Default: the ground truth tracks the body frame.
    #[arg(
        long,
        value_name = "X,Y,Z,YAW_DEG",
        value_parser = parse_t_gt_body,
        allow_hyphen_values = true,
        requires = "bag"
    )]
    pub ground_truth_to_body: Option<Iso3>,
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

/// Where the ground truth of a bag comes from.
#[derive(Debug, Clone)]
pub enum GroundTruthSource {
    /// A topic of the bag, nav_msgs/Odometry or geometry_msgs/PoseStamped.
    Topic(String),
    /// A TUM trajectory file.
    File(PathBuf),
}

/// The ground truth of a bag: where it comes from, and the body frame's pose in the frame it tracks.
#[derive(Debug, Clone)]
pub struct GroundTruth {
    /// Where it comes from.
    pub source: GroundTruthSource,
    /// The body frame's pose in the tracked frame (`t_map_body = t_map_gt * t_gt_body`).
    pub t_gt_body: Iso3,
}

impl GroundTruth {
    /// Ground truth of the body frame on `topic`.
    pub fn topic(topic: &str) -> Self {
        GroundTruth {
            source: GroundTruthSource::Topic(topic.to_string()),
            t_gt_body: Iso3::identity(),
        }
    }

    /// The ground truth of the arguments: the file if given, else the topic.
    fn of(args: &EvalArgs) -> Self {
        GroundTruth {
            source: match &args.ground_truth {
                Some(file) => GroundTruthSource::File(file.clone()),
                None => GroundTruthSource::Topic(args.ground_truth_topic.clone()),
            },
            t_gt_body: args.ground_truth_to_body.unwrap_or_else(Iso3::identity),
        }
    }

    /// The topic to read from the bag, if any.
    fn bag_topic(&self) -> Option<&str> {
        match &self.source {
            GroundTruthSource::Topic(topic) => Some(topic),
            GroundTruthSource::File(_) => None,
        }
    }

    /// The samples of the file, if any, as ground-truth inputs.
    fn file_inputs(&self) -> Result<Vec<Input>, CliError> {
        let GroundTruthSource::File(path) = &self.source else {
            return Ok(Vec::new());
        };
        match read_tum(path) {
            Ok(poses) => Ok(ground_truth_inputs(&poses)),
            Err(e @ TumError::Io { .. }) => Err(CliError::Runtime(format!("--ground-truth {e}"))),
            Err(e) => Err(CliError::Usage(format!("--ground-truth {e}"))),
        }
    }
}

impl std::fmt::Display for GroundTruth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.source {
            GroundTruthSource::Topic(topic) => write!(f, "on {topic}"),
            GroundTruthSource::File(path) => write!(f, "in {}", path.display()),
        }
    }
}

/// The body frame's pose in the ground truth's tracked frame from `X,Y,Z,YAW_DEG` or
/// `X,Y,Z,ROLL_DEG,PITCH_DEG,YAW_DEG`.
fn parse_t_gt_body(text: &str) -> Result<Iso3, String> {
    let values = text
        .split(',')
        .map(|v| {
            v.trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("`{}` is not a finite number", v.trim()))
        })
        .collect::<Result<Vec<f64>, String>>()?;
    let (x, y, z, [roll, pitch, yaw]) = match values[..] {
        [x, y, z, yaw] => (x, y, z, [0.0, 0.0, yaw]),
        [x, y, z, roll, pitch, yaw] => (x, y, z, [roll, pitch, yaw]),
        _ => {
            return Err(format!(
                "{} values, expected X,Y,Z,YAW_DEG or X,Y,Z,ROLL_DEG,PITCH_DEG,YAW_DEG",
                values.len()
            ));
        }
    };
    let [roll, pitch, yaw] = [roll, pitch, yaw].map(f64::to_radians);
    Ok(iso3_from_xyz_rpy(x, y, z, roll, pitch, yaw))
}

/// What [`collect`] read, by kind, with the time spans of the radar and the ground truth.
#[derive(Default)]
struct Counts {
    ground_truth: u64,
    radar: u64,
    odometry: u64,
    skipped: u64,
    ground_truth_span: Option<(Stamp, Stamp)>,
    radar_span: Option<(Stamp, Stamp)>,
}

impl Counts {
    fn add(&mut self, input: &Input) {
        let widen = |span: &mut Option<(Stamp, Stamp)>, t: Stamp| {
            *span = Some(span.map_or((t, t), |(a, b)| (a.min(t), b.max(t))));
        };
        match input {
            Input::GroundTruth { stamp, .. } => {
                self.ground_truth += 1;
                widen(&mut self.ground_truth_span, *stamp);
            }
            Input::Radar { .. } | Input::Scan(_) => {
                self.radar += 1;
                widen(&mut self.radar_span, input.stamp());
            }
            Input::Odometry { .. } => self.odometry += 1,
            Input::Keyframe(_) | Input::Imu { .. } => {}
        }
    }

    /// Why no keyframe has ground truth: the two time spans, which do not meet when the ground truth
    /// is on another clock.
    fn no_keyframe(&self, gt: &GroundTruth) -> String {
        let span = |s: Option<(Stamp, Stamp)>| {
            s.map_or("none".into(), |(a, b)| {
                format!("{:.3} to {:.3} s", a.as_secs_f64(), b.as_secs_f64())
            })
        };
        format!(
            "no keyframe has ground truth {gt}: radar {}, ground truth {} (on the same clock?)",
            span(self.radar_span),
            span(self.ground_truth_span)
        )
    }
}

/// Collects the keyframes of a bag with ground truth. A file's ground truth goes into the same input
/// stream ahead of the bag's messages (the pipeline ignores ground truth; the collector keeps all of
/// it), and every ground-truth pose is moved to the body frame on its way in.
pub fn collect(
    bag: &Path,
    cfg: &Config,
    gt: &GroundTruth,
    eval: &EvalConfig,
) -> Result<Vec<EvalKeyframe>, CliError> {
    let reader = BagReader::open(bag).map_err(|e| CliError::Runtime(e.to_string()))?;
    let from_file = gt.file_inputs()?;
    let inputs = bag_inputs(&reader, cfg, gt.bag_topic())?;
    let mut collector = Collector::new(cfg, eval).map_err(|e| CliError::Usage(e.to_string()))?;
    let bar = bar(from_file.len() as u64 + inputs.total_messages(), "messages");
    let mut counts = Counts::default();
    let mut causes = crate::repeats::Repeats::default();
    for item in from_file.into_iter().map(Ok).chain(inputs) {
        bar.inc(1);
        match item {
            Ok(input) => {
                counts.add(&input);
                collector.push(&to_body(input, &gt.t_gt_body));
            }
            Err(issue) => {
                counts.skipped += 1;
                issue.log_once(&mut causes);
            }
        }
    }
    progress::clear(&bar);
    if counts.ground_truth == 0 {
        return Err(CliError::Usage(format!(
            "no ground truth {gt} in {}",
            bag.display()
        )));
    }
    let (kfs, _) = collector.finish();
    if kfs.is_empty() {
        return Err(CliError::Usage(counts.no_keyframe(gt)));
    }
    log::info!(
        "{} radar clouds, {} odometry, {} ground truth {gt}, {} skipped; {} keyframes with ground truth",
        counts.radar,
        counts.odometry,
        counts.ground_truth,
        counts.skipped,
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
    let kfs = collect(bag, &cfg, &GroundTruth::of(args), &eval)?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn t_gt_body_takes_yaw_alone_or_roll_pitch_yaw_in_degrees() {
        let t = parse_t_gt_body("1.5,-0.5,0.25,90").unwrap();
        assert_eq!(
            t.translation.vector,
            crate::math::Vec3::new(1.5, -0.5, 0.25)
        );
        let (roll, pitch, yaw) = t.rotation.euler_angles();
        assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12);
        assert!((yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        let t = parse_t_gt_body(" 0, 0, 0, 10, -20, 30 ").unwrap();
        let (roll, pitch, yaw) = t.rotation.euler_angles();
        let deg = [roll, pitch, yaw].map(f64::to_degrees);
        assert!((deg[0] - 10.0).abs() < 1e-9 && (deg[1] + 20.0).abs() < 1e-9);
        assert!((deg[2] - 30.0).abs() < 1e-9, "{deg:?}");
        let err = parse_t_gt_body("1,2,3").unwrap_err();
        assert!(err.starts_with("3 values, expected X,Y,Z,YAW_DEG"), "{err}");
        let err = parse_t_gt_body("1,2,3,nan").unwrap_err();
        assert!(err.contains("`nan` is not a finite number"), "{err}");
    }
}
