//! The pipeline configuration of an offline run: a ROS 2 params file (the node's section) and `-p`
//! overrides onto the defaults, or onto a dataset's own radar layout ([`dataset_config`]). The node's
//! own settings (`node.*`, `use_sim_time`) are accepted, so one file serves the node and `dc_loc run`:
//! they are checked, and the cloud size limits and `node.restart_after` apply offline too
//! ([`node_settings`]).

use std::path::Path;

use super::CliError;
use crate::params::checks::{defaulted_noise, section_mismatch};
use crate::params::node::NodeSettings;
use crate::params::{ParamError, ParamSet, apply, flatten_config};
use crate::pipeline::Config;

/// The configuration from a params file (the section of node `/namespace/node_name`) and `-p`
/// overrides, validated.
pub fn load_params(
    params: &Path,
    namespace: &str,
    node_name: &str,
    overrides: &[String],
) -> Result<Config, CliError> {
    let file = params.display();
    let mut set = read_params(params, namespace, node_name, true)?;
    add_overrides(&mut set, overrides)?;
    let cfg = pipeline_config(&set)
        .map_err(|e| CliError::Usage(format!("parameters ({file} and -p): {e}")))?;
    for warning in defaulted_noise(&set, &cfg) {
        log::warn!("{warning}");
    }
    Ok(cfg)
}

/// The configuration for a dataset whose radars `template` describes: `template`'s parameters, then the
/// params file's (optional), then the overrides.
pub fn dataset_config(
    template: &Config,
    params: Option<&Path>,
    node_name: &str,
    overrides: &[String],
) -> Result<Config, CliError> {
    let mut set = ParamSet::default();
    for (name, value) in flatten_config(template) {
        set.set(name, value);
    }
    if let Some(p) = params {
        for (name, value) in read_params(p, "/", node_name, true)?.entries() {
            set.set(name.clone(), value.clone());
        }
    }
    add_overrides(&mut set, overrides)?;
    pipeline_config(&set).map_err(|e| CliError::Usage(format!("parameters: {e}")))
}

/// The node's own parameters split off and checked, the rest applied.
fn pipeline_config(set: &ParamSet) -> Result<Config, ParamError> {
    let (_, rest) = NodeSettings::take_from(set)?;
    apply(&rest)
}

/// The node's own settings of the params file (optional) and the overrides; `dc_loc run` takes the
/// cloud size limits and `node.restart_after` from them, as the node does.
pub fn node_settings(
    params: Option<&Path>,
    namespace: &str,
    node_name: &str,
    overrides: &[String],
) -> Result<NodeSettings, CliError> {
    let mut set = match params {
        Some(p) => read_params(p, namespace, node_name, false)?,
        None => ParamSet::default(),
    };
    add_overrides(&mut set, overrides)?;
    let (settings, _) =
        NodeSettings::take_from(&set).map_err(|e| CliError::Usage(format!("parameters: {e}")))?;
    Ok(settings)
}

/// The parameters of node `/namespace/node_name` in the params file `path`; with `check`, a file none of
/// whose sections applies to the node is warned about (the file is read twice, for the pipeline and
/// for the node's own settings: one of them checks).
fn read_params(
    path: &Path,
    namespace: &str,
    node_name: &str,
    check: bool,
) -> Result<ParamSet, CliError> {
    let file = path.display();
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::Usage(format!("--params {file}: {e}")))?;
    let bad = |e: ParamError| CliError::Usage(format!("--params {file}: {e}"));
    if check && let Some(warning) = section_mismatch(&text, namespace, node_name).map_err(bad)? {
        log::warn!("--params {file}: {warning}");
    }
    ParamSet::from_yaml(&text, namespace, node_name).map_err(bad)
}

fn add_overrides(set: &mut ParamSet, overrides: &[String]) -> Result<(), CliError> {
    for o in overrides {
        set.set_override(o)
            .map_err(|e| CliError::Usage(format!("-p: {e}")))?;
    }
    Ok(())
}

/// A flag's list of kept states: comma-separated integers, or `all` (no filtering on that flag).
pub fn parse_states(flag: &str, value: &str) -> Result<Option<Vec<i8>>, CliError> {
    if value.trim() == "all" {
        return Ok(None);
    }
    value
        .split(',')
        .map(|v| {
            v.trim().parse::<i8>().map_err(|_| {
                CliError::Usage(format!(
                    "--{flag}: `{v}` is not a state number (give e.g. 0,1,2 or all)"
                ))
            })
        })
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}
