//! `dc_loc demo`: simulate, run and evaluate in one go (placeholder: the subcommand is being written).

use super::CliError;

/// Arguments of `dc_loc demo` (accepted as they come until the subcommand exists).
#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Arguments (not read yet).
    #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
    pub args: Vec<String>,
}

/// Runs `dc_loc demo`: not yet available (exit code 2).
pub fn main(_args: &DemoArgs) -> Result<(), CliError> {
    Err(CliError::Usage("not yet: `demo` is being written".into()))
}
