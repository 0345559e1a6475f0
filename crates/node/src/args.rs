//! The node's command line as ROS 2 defines it (ros2-client does not parse it): `--ros-args` followed by
//! `--params-file FILE`, `-p`/`--param NAME:=VALUE`, `-r`/`--remap FROM:=TO` (also `__ns`, `__node` and
//! `node:FROM:=TO`), `--log-level [LOGGER:=]LEVEL`, closed by `--` or the end; plus the environment
//! (`ROS_DOMAIN_ID`, `ROS_AUTOMATIC_DISCOVERY_RANGE`, the older `ROS_LOCALHOST_ONLY`).
//!
//! Entry points: [`RosArgs::parse`], [`RosArgs::resolve_topic`] (a topic name with namespace, `~` and the
//! remapping rules applied), [`RosArgs::param_set`] (params files then `-p`, in order),
//! [`DdsEnv::from_env`]. Pure: no DDS here, so it is unit-tested.

use std::path::PathBuf;

use dc_loc_io::params::checks::section_mismatch;
use dc_loc_io::params::{ParamError, ParamSet};

/// What is wrong with the command line or the environment (exit code 2, the message names the
/// argument or variable).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ArgsError {
    /// An argument outside `--ros-args` or one that is not a ROS argument.
    #[error(
        "unknown argument `{0}` (the node takes `--ros-args ...`; offline tools: `dc_loc help`)"
    )]
    Unknown(String),
    /// An option without its value.
    #[error("`{0}` needs a value")]
    MissingValue(String),
    /// A remapping rule that is not `from:=to` or names an invalid node name or namespace.
    #[error("bad remapping `{0}`: {1}")]
    BadRemap(String, String),
    /// A log level that is not one of debug, info, warn, error, fatal.
    #[error("bad log level `{0}` (debug, info, warn, error, fatal)")]
    BadLogLevel(String),
    /// A params file that cannot be read or parsed.
    #[error("--params-file {path}: {reason}")]
    ParamsFile {
        /// The file.
        path: String,
        /// Why.
        reason: String,
    },
    /// A `-p` argument that is not `name:=value`.
    #[error(transparent)]
    Param(#[from] ParamError),
    /// DDS security is asked for and cannot be set up: the cause, naming the variable, the enclave
    /// or the file.
    #[error("DDS security (ROS_SECURITY_ENABLE=true): {0}")]
    Security(String),
    /// An environment variable with an unusable value.
    #[error("environment variable {name}={value:?}: {reason}")]
    Env {
        /// Variable.
        name: &'static str,
        /// Its value.
        value: String,
        /// Why it is refused.
        reason: String,
    },
}

/// Where a parameter came from, in order of application.
#[derive(Debug, Clone, PartialEq)]
enum ParamSource {
    File(PathBuf),
    Override(String),
}

/// The parsed ROS arguments.
#[derive(Debug, Clone, PartialEq)]
pub struct RosArgs {
    /// Node namespace, absolute (`/` by default; `-r __ns:=/car1`).
    pub namespace: String,
    /// Node name (`dc_loc` by default; `-r __node:=loc`).
    pub node_name: String,
    /// Topic remappings, `(from, to)` as given (resolved when matched).
    pub remaps: Vec<(String, String)>,
    /// `--log-level`: the level for dc_loc's own logs (`None`: `RUST_LOG` or the default).
    pub log_level: Option<log::LevelFilter>,
    /// Logs also go to `/rosout` (`--disable-rosout-logs` turns it off).
    pub rosout: bool,
    /// `--enclave`: the security enclave (`ROS_SECURITY_ENCLAVE_OVERRIDE` overrides it).
    pub enclave: Option<String>,
    sources: Vec<ParamSource>,
}

impl Default for RosArgs {
    fn default() -> Self {
        RosArgs {
            namespace: "/".into(),
            node_name: "dc_loc".into(),
            remaps: Vec::new(),
            log_level: None,
            rosout: true,
            enclave: None,
            sources: Vec::new(),
        }
    }
}

fn valid_token(s: &str) -> bool {
    let mut chars = s.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphabetic() || c == '_')
        && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        && !s.contains("__")
}

impl RosArgs {
    /// Parses `args` (program name first). Arguments must come after `--ros-args`; `--` ends a ROS
    /// argument block, and another `--ros-args` may open a new one.
    pub fn parse(args: &[String]) -> Result<Self, ArgsError> {
        let mut out = RosArgs::default();
        let mut in_ros = false;
        let mut it = args.iter().skip(1);
        let value = |it: &mut std::iter::Skip<std::slice::Iter<'_, String>>, opt: &str| {
            it.next()
                .cloned()
                .ok_or_else(|| ArgsError::MissingValue(opt.to_string()))
        };
        while let Some(a) = it.next() {
            match a.as_str() {
                "--ros-args" => in_ros = true,
                "--" if in_ros => in_ros = false,
                _ if !in_ros => return Err(ArgsError::Unknown(a.clone())),
                "--params-file" => out
                    .sources
                    .push(ParamSource::File(PathBuf::from(value(&mut it, a)?))),
                "-p" | "--param" => {
                    let v = value(&mut it, a)?;
                    // Checked now so that the message points at the argument.
                    ParamSet::default().set_override(&v)?;
                    out.sources.push(ParamSource::Override(v));
                }
                "-r" | "--remap" => {
                    let v = value(&mut it, a)?;
                    out.add_remap(&v)?;
                }
                "--log-level" => {
                    let v = value(&mut it, a)?;
                    // `--log-level LEVEL` or `--log-level logger:=LEVEL` (only dc_loc's logger here).
                    let level = v.rsplit_once(":=").map_or(v.as_str(), |(_, l)| l);
                    out.log_level = Some(match level.to_ascii_lowercase().as_str() {
                        "debug" => log::LevelFilter::Debug,
                        "info" => log::LevelFilter::Info,
                        "warn" => log::LevelFilter::Warn,
                        "error" | "fatal" => log::LevelFilter::Error,
                        _ => return Err(ArgsError::BadLogLevel(v)),
                    });
                }
                "--enable-rosout-logs" => out.rosout = true,
                "--disable-rosout-logs" => out.rosout = false,
                // Accepted and without effect here (the log always goes to stderr).
                "--enable-stdout-logs"
                | "--disable-stdout-logs"
                | "--disable-external-lib-logs" => {}
                "-e" | "--enclave" => out.enclave = Some(value(&mut it, a)?),
                _ => return Err(ArgsError::Unknown(a.clone())),
            }
        }
        Ok(out)
    }

    fn add_remap(&mut self, rule: &str) -> Result<(), ArgsError> {
        let bad = |why: &str| ArgsError::BadRemap(rule.to_string(), why.to_string());
        let (from, to) = rule
            .split_once(":=")
            .ok_or_else(|| bad("expected from:=to"))?;
        // `node_name:from:=to` applies to that node only.
        let from = match from.split_once(':') {
            Some((node, f)) => {
                if node != self.node_name {
                    return Ok(());
                }
                f
            }
            None => from,
        };
        if to.is_empty() || from.is_empty() {
            return Err(bad("empty name"));
        }
        match from {
            "__ns" => {
                let ns = if to.starts_with('/') {
                    to.to_string()
                } else {
                    format!("/{to}")
                };
                let trimmed = ns.trim_end_matches('/');
                if ns != "/" && !trimmed[1..].split('/').all(valid_token) {
                    return Err(bad("not a valid namespace"));
                }
                self.namespace = if trimmed.is_empty() {
                    "/".into()
                } else {
                    trimmed.to_string()
                };
            }
            "__node" | "__name" => {
                if !valid_token(to) {
                    return Err(bad("not a valid node name"));
                }
                self.node_name = to.to_string();
            }
            _ => self.remaps.push((from.to_string(), to.to_string())),
        }
        Ok(())
    }

    /// `/ns/node`.
    pub fn fully_qualified_name(&self) -> String {
        dc_loc_io::params::fully_qualified(&self.namespace, &self.node_name)
    }

    /// The logger name ROS 2 gives the node: namespace and name joined by dots (`car1.loc`).
    pub fn logger_name(&self) -> String {
        self.fully_qualified_name()
            .trim_start_matches('/')
            .replace('/', ".")
    }

    /// A name made absolute: `~/x` -> `/ns/node/x`, `x` -> `/ns/x`, `/x` unchanged.
    pub fn expand(&self, name: &str) -> String {
        let ns = self.namespace.trim_end_matches('/');
        if let Some(rest) = name.strip_prefix("~/") {
            format!("{}/{rest}", self.fully_qualified_name())
        } else if name == "~" {
            self.fully_qualified_name()
        } else if name.starts_with('/') {
            name.to_string()
        } else {
            format!("{ns}/{name}")
        }
    }

    /// The topic a name refers to: expanded, then the first matching remapping rule (its `from` expanded
    /// the same way) applied, as rcl does.
    pub fn resolve_topic(&self, name: &str) -> String {
        let expanded = self.expand(name);
        for (from, to) in &self.remaps {
            if self.expand(from) == expanded {
                return self.expand(to);
            }
        }
        expanded
    }

    /// The parameters: each params file's sections for this node, and the `-p` overrides, in command-line
    /// order (ROS 2 applies them in that order too).
    pub fn param_set(&self) -> Result<ParamSet, ArgsError> {
        let mut set = ParamSet::default();
        for s in &self.sources {
            match s {
                ParamSource::File(path) => {
                    let text =
                        std::fs::read_to_string(path).map_err(|e| ArgsError::ParamsFile {
                            path: path.display().to_string(),
                            reason: e.to_string(),
                        })?;
                    let bad = |e: ParamError| ArgsError::ParamsFile {
                        path: path.display().to_string(),
                        reason: e.to_string(),
                    };
                    if let Some(w) =
                        section_mismatch(&text, &self.namespace, &self.node_name).map_err(bad)?
                    {
                        log::warn!("--params-file {}: {w}", path.display());
                    }
                    let file = ParamSet::from_yaml(&text, &self.namespace, &self.node_name)
                        .map_err(bad)?;
                    for (n, v) in file.entries() {
                        set.set(n.clone(), v.clone());
                    }
                }
                ParamSource::Override(o) => set.set_override(o)?,
            }
        }
        Ok(set)
    }
}

/// How far DDS discovery reaches (`ROS_AUTOMATIC_DISCOVERY_RANGE`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DiscoveryRange {
    /// Loopback only: every packet stays on 127.0.0.1.
    Localhost,
    /// The DDS default (every interface).
    Subnet,
    /// No automatic discovery: the participant binds loopback and finds no one on its own.
    Off,
}

/// The DDS settings ROS 2 takes from the environment.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DdsEnv {
    /// `ROS_DOMAIN_ID` (default 0).
    pub domain_id: u16,
    /// `ROS_AUTOMATIC_DISCOVERY_RANGE` (default SUBNET; `ROS_LOCALHOST_ONLY=1` means LOCALHOST when the
    /// range is unset).
    pub range: DiscoveryRange,
}

impl DdsEnv {
    /// Reads the variables through `get` (normally `std::env::var`).
    pub fn from_env(get: impl Fn(&str) -> Option<String>) -> Result<Self, ArgsError> {
        let domain_id = match get("ROS_DOMAIN_ID").filter(|v| !v.trim().is_empty()) {
            None => 0,
            Some(v) => match v.trim().parse::<u16>() {
                Ok(id) if id <= 232 => id,
                _ => {
                    return Err(ArgsError::Env {
                        name: "ROS_DOMAIN_ID",
                        value: v,
                        reason: "must be an integer in 0..=232".into(),
                    });
                }
            },
        };
        let range = match get("ROS_AUTOMATIC_DISCOVERY_RANGE").filter(|v| !v.is_empty()) {
            Some(v) => match v.as_str() {
                "LOCALHOST" => DiscoveryRange::Localhost,
                "SUBNET" | "SYSTEM_DEFAULT" => DiscoveryRange::Subnet,
                "OFF" => DiscoveryRange::Off,
                _ => {
                    return Err(ArgsError::Env {
                        name: "ROS_AUTOMATIC_DISCOVERY_RANGE",
                        value: v,
                        reason: "expected LOCALHOST, SUBNET, SYSTEM_DEFAULT or OFF".into(),
                    });
                }
            },
            None if get("ROS_LOCALHOST_ONLY").as_deref() == Some("1") => DiscoveryRange::Localhost,
            None => DiscoveryRange::Subnet,
        };
        Ok(DdsEnv { domain_id, range })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(s: &str) -> Vec<String> {
        std::iter::once("dc_loc")
            .chain(s.split_whitespace())
            .map(String::from)
            .collect()
    }

    #[test]
    fn ros_args_names_and_remapping() {
        let a = RosArgs::parse(&args(
            "--ros-args -r __ns:=/car1 -r __node:=loc -r /odom:=/wheel/odom -r other:x:=y \
             -r radar:=/r2 --log-level debug",
        ))
        .unwrap();
        assert_eq!(a.fully_qualified_name(), "/car1/loc");
        assert_eq!(a.log_level, Some(log::LevelFilter::Debug));
        assert_eq!(a.resolve_topic("/odom"), "/wheel/odom");
        assert_eq!(
            a.resolve_topic("~/loop_closures"),
            "/car1/loc/loop_closures"
        );
        assert_eq!(a.resolve_topic("radar"), "/r2");
        assert_eq!(
            a.resolve_topic("/car1/radar"),
            "/r2",
            "relative from, resolved"
        );
        assert_eq!(a.resolve_topic("/x"), "/x", "rule of another node ignored");
        assert_eq!(a.resolve_topic("/diagnostics"), "/diagnostics");
    }

    #[test]
    fn bad_arguments_are_named() {
        assert_eq!(
            RosArgs::parse(&args("--bogus")),
            Err(ArgsError::Unknown("--bogus".into()))
        );
        assert_eq!(
            RosArgs::parse(&args("--ros-args --params-file")),
            Err(ArgsError::MissingValue("--params-file".into()))
        );
        assert!(matches!(
            RosArgs::parse(&args("--ros-args -r __node:=9x")),
            Err(ArgsError::BadRemap(..))
        ));
        assert!(matches!(
            RosArgs::parse(&args("--ros-args -p novalue")),
            Err(ArgsError::Param(_))
        ));
        assert!(matches!(
            RosArgs::parse(&args("--ros-args --log-level loud")),
            Err(ArgsError::BadLogLevel(_))
        ));
        // `--` closes the block; what follows is not a ROS argument.
        assert!(RosArgs::parse(&args("--ros-args -- x")).is_err());
    }

    #[test]
    fn params_files_and_overrides_in_order() {
        let dir = std::env::temp_dir().join(format!("dc_loc_args_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("p.yaml");
        std::fs::write(
            &file,
            "/car1/loc:\n  ros__parameters:\n    submap:\n      size: 7\n    keyframe:\n      distance: 4.0\n",
        )
        .unwrap();
        let a = RosArgs::parse(&args(&format!(
            "--ros-args -r __ns:=car1 -r __node:=loc -p submap.size:=3 --params-file {} -p keyframe.distance:=6.5",
            file.display()
        )))
        .unwrap();
        let cfg = dc_loc_io::params::apply(&a.param_set().unwrap()).unwrap();
        assert_eq!(cfg.submap.size, 7, "the file comes after the first -p");
        assert_eq!(cfg.keyframe.distance, 6.5);
        let missing = RosArgs::parse(&args("--ros-args --params-file /nonexistent.yaml")).unwrap();
        assert!(matches!(
            missing.param_set(),
            Err(ArgsError::ParamsFile { .. })
        ));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn environment() {
        let env = |pairs: &'static [(&'static str, &'static str)]| {
            move |k: &str| {
                pairs
                    .iter()
                    .find(|(n, _)| *n == k)
                    .map(|(_, v)| v.to_string())
            }
        };
        assert_eq!(
            DdsEnv::from_env(env(&[])).unwrap(),
            DdsEnv {
                domain_id: 0,
                range: DiscoveryRange::Subnet
            }
        );
        let e = DdsEnv::from_env(env(&[
            ("ROS_DOMAIN_ID", "42"),
            ("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST"),
        ]))
        .unwrap();
        assert_eq!((e.domain_id, e.range), (42, DiscoveryRange::Localhost));
        let e = DdsEnv::from_env(env(&[("ROS_LOCALHOST_ONLY", "1")])).unwrap();
        assert_eq!(e.range, DiscoveryRange::Localhost);
        assert!(matches!(
            DdsEnv::from_env(env(&[("ROS_DOMAIN_ID", "300")])),
            Err(ArgsError::Env {
                name: "ROS_DOMAIN_ID",
                ..
            })
        ));
        assert!(matches!(
            DdsEnv::from_env(env(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "everywhere")])),
            Err(ArgsError::Env {
                name: "ROS_AUTOMATIC_DISCOVERY_RANGE",
                ..
            })
        ));
    }

    /// `--enclave` names the enclave; security itself is read from the environment
    /// (`crate::security`).
    #[test]
    fn the_enclave_argument_is_taken() {
        let a = RosArgs::parse(&args("--ros-args --enclave /robots/car1")).unwrap();
        assert_eq!(a.enclave.as_deref(), Some("/robots/car1"));
        assert_eq!(RosArgs::parse(&args("--ros-args")).unwrap().enclave, None);
    }
}
