//! `dc_loc params`: the sensor setup and tuning knobs with their defaults, accepted values and
//! descriptions (Markdown; `--all` adds the internal constants), or a params file with every parameter
//! at its default (`--yaml`), to start a robot's own file from.

use super::CliError;
use crate::params::file::params_file;
use crate::params::node::{NodeSettings, all_params};
use crate::params::reference::{markdown, markdown_internal, reference};
use crate::pipeline::Config;

/// Arguments of `dc_loc params`.
#[derive(Debug, clap::Args)]
pub struct ParamsArgs {
    /// Print a ROS 2 params file (node `dc_loc`) with every parameter at its default instead of the
    /// reference.
    #[arg(long)]
    pub yaml: bool,
    /// Also print the internal constants and operational limits (docs/parameters.md).
    #[arg(long)]
    pub all: bool,
}

/// Prints the reference or the params file on stdout.
pub fn main(args: &ParamsArgs) -> Result<(), CliError> {
    if args.yaml {
        let params = all_params(&Config::default(), &NodeSettings::default());
        let header = "dc_loc parameters, every one at its default (dc_loc params --yaml).\n\
                      The parameter reference: dc_loc params --all, or README_NODE.md and docs/parameters.md.";
        print!("{}", params_file(&params, header));
    } else {
        let params = reference();
        print!("{}", markdown(&params));
        if args.all {
            println!("### Internal constants and operational limits\n");
            print!("{}", markdown_internal(&params));
        }
    }
    Ok(())
}
