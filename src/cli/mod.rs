//! Command-line front ends: the offline subcommands and the node's entry point.
//!
//! Entry points: [`main`] (subcommands, one module each: [`sim`], [`run`], [`eval`] with
//! [`eval_datasets`] for `--nuscenes` and `--vod`, [`demo`], [`revisits`], [`reference`] (`dc_loc params`); the data they read in
//! [`source`], its parameters in [`params`]), [`node_main`] (the ROS 2 node).
//!
//! Conventions of every subcommand: results and summaries on stdout; logs on stderr through
//! `env_logger` (`RUST_LOG` honoured; default `warn` with dc_loc's own messages at `info`), kept clear of
//! the progress bar; exit code 0 on success, 1 on a runtime failure (an unreadable bag, a file that
//! cannot be written), 2 on a usage or configuration error (the message names the parameter or file).

pub mod demo;
pub mod eval;
pub mod eval_datasets;
pub mod eval_set;
pub mod params;
pub mod progress;
pub mod reference;
pub mod revisits;
pub mod run;
pub mod sim;
pub mod source;

use clap::{Parser, Subcommand};

/// `dc_loc`: DC-Loc radar loop closures; offline tools (the ROS 2 node runs without a subcommand).
#[derive(Debug, Parser)]
#[command(
    name = "dc_loc",
    version,
    about,
    long_about = None,
    after_help = "Without a subcommand, dc_loc runs the ROS 2 node (dc_loc --ros-args ...)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Simulate a drive and write it as a rosbag2 bag with its params file.
    Sim(sim::SimArgs),
    /// Run the pipeline over a bag and write the loop closures as JSON lines.
    Run(run::RunArgs),
    /// The paper's evaluation on a bag with ground truth: every method and ablation row, tables, plot.
    Eval(eval::EvalArgs),
    /// Simulate the default drive, run it and evaluate it: the whole method in one command.
    Demo(demo::DemoArgs),
    /// Precision and recall of the loop closures on simulated drives under odometry drift.
    Revisits(revisits::RevisitArgs),
    /// The parameter reference (Markdown), or a params file with every default (--yaml).
    Params(reference::ParamsArgs),
}

/// A subcommand's failure, with the exit code it maps to.
#[derive(Debug, thiserror::Error)]
pub enum CliError {
    /// Bad arguments, parameters or configuration files (exit code 2).
    #[error("{0}")]
    Usage(String),
    /// The work could not be done: unreadable input, unwritable output (exit code 1).
    #[error("{0}")]
    Runtime(String),
}

impl CliError {
    /// The process exit code.
    pub fn exit_code(&self) -> i32 {
        match self {
            CliError::Usage(_) => 2,
            CliError::Runtime(_) => 1,
        }
    }
}

/// Runs an offline subcommand (`args` as from `std::env::args`, program name first); returns the
/// process exit code.
pub fn main(args: &[String]) -> i32 {
    let cli = match Cli::try_parse_from(args) {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            // Help and version are not errors.
            return if e.use_stderr() { 2 } else { 0 };
        }
    };
    init_logging();
    let (name, result) = match cli.command {
        Command::Sim(a) => ("sim", sim::main(&a)),
        Command::Run(a) => ("run", run::main(&a)),
        Command::Eval(a) if a.source.nuscenes.is_some() => {
            ("eval", eval_datasets::eval_nuscenes(&a))
        }
        Command::Eval(a) if a.source.vod.is_some() => ("eval", eval_datasets::eval_vod(&a)),
        Command::Eval(a) if a.set.is_some() => ("eval", eval_set::main(&a)),
        Command::Eval(a) => ("eval", eval::main(&a)),
        Command::Demo(a) => ("demo", demo::main(&a)),
        Command::Revisits(a) => ("revisits", revisits::main(&a)),
        Command::Params(a) => ("params", reference::main(&a)),
    };
    match result {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("dc_loc {name}: error: {e}");
            e.exit_code()
        }
    }
}

/// Runs the ROS 2 node; returns the process exit code.
#[cfg(feature = "ros")]
pub fn node_main(args: &[String]) -> i32 {
    crate::ros::node::main(args)
}

/// Without the `ros` feature there is no node: says so (exit code 2).
#[cfg(not(feature = "ros"))]
pub fn node_main(_args: &[String]) -> i32 {
    eprintln!(
        "dc_loc: built without the `ros` feature: no ROS 2 node (offline tools: dc_loc help)"
    );
    2
}

/// env_logger, with each record written while the progress bar is cleared from the screen.
struct CliLogger(env_logger::Logger);

impl log::Log for CliLogger {
    fn enabled(&self, metadata: &log::Metadata<'_>) -> bool {
        self.0.enabled(metadata)
    }
    fn log(&self, record: &log::Record<'_>) {
        if !self.0.matches(record) {
            return;
        }
        progress::suspended(|| self.0.log(record));
    }
    fn flush(&self) {
        self.0.flush();
    }
}

/// Logs to stderr; `RUST_LOG` overrides the default `warn,dc_loc=info`. A second call (or a logger
/// set by someone else) leaves the first in place.
fn init_logging() {
    let logger = env_logger::Builder::from_env(
        env_logger::Env::default().default_filter_or("warn,dc_loc=info"),
    )
    .build();
    let max = logger.filter();
    if log::set_boxed_logger(Box::new(CliLogger(logger))).is_ok() {
        log::set_max_level(max);
    }
}
