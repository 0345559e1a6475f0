//! How the node fails: [`NodeError`] and its exit code (2: usage or configuration, 1: runtime).

use super::args::ArgsError;
use dc_loc_io::params::ParamError;

/// A failure of the node, with its exit code (2: usage or configuration, 1: runtime).
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// Command line or environment.
    #[error(transparent)]
    Args(#[from] ArgsError),
    /// Parameters.
    #[error(transparent)]
    Param(#[from] ParamError),
    /// The map file cannot be used.
    #[error("{0}")]
    Map(String),
    /// DDS could not be set up.
    #[error("DDS: {0}")]
    Dds(String),
    /// The node could not go on: a task it needs ended, or the map could not be saved at shutdown.
    #[error("{0}")]
    Runtime(String),
}

impl NodeError {
    /// The process exit code.
    pub fn exit_code(&self) -> i32 {
        match self {
            NodeError::Dds(_) | NodeError::Runtime(_) => 1,
            _ => 2,
        }
    }
}

/// A DDS error as a [`NodeError`], saying what was being made.
pub fn dds<E: std::fmt::Debug>(what: &str) -> impl FnOnce(E) -> NodeError + '_ {
    move |e| NodeError::Dds(format!("{what}: {e:?}"))
}
