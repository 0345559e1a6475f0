//! `dc_loc params`: every parameter with its default, accepted values and description (Markdown), or
//! a params file with every parameter at its default (`--yaml`), to start a robot's own file from.

use super::CliError;
use crate::params::file::params_file;
use crate::params::node::{NodeSettings, all_params};
use crate::params::reference::{markdown, reference};
use crate::pipeline::Config;

/// Arguments of `dc_loc params`.
#[derive(Debug, clap::Args)]
pub struct ParamsArgs {
    /// Print a ROS 2 params file (node `dc_loc`) with every parameter at its default instead of the
    /// reference.
    #[arg(long)]
    pub yaml: bool,
}

/// Prints the reference or the params file on stdout.
pub fn main(args: &ParamsArgs) -> Result<(), CliError> {
    if args.yaml {
        let params = all_params(&Config::default(), &NodeSettings::default());
        let header = "dc_loc parameters, every one at its default (dc_loc params --yaml).\n\
                      The parameter reference: dc_loc params, or README_NODE.md.";
        print!("{}", params_file(&params, header));
    } else {
        print!("{}", markdown(&reference()));
    }
    Ok(())
}
