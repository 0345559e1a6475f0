//! `dc_loc eval`: loop closures against ground truth (placeholder: the subcommand is being written).

use super::CliError;

/// Arguments of `dc_loc eval` (accepted as they come until the subcommand exists).
#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Arguments (not read yet).
    #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
    pub args: Vec<String>,
}

/// Runs `dc_loc eval`: not yet available (exit code 2).
pub fn main(_args: &EvalArgs) -> Result<(), CliError> {
    Err(CliError::Usage("not yet: `eval` is being written".into()))
}
