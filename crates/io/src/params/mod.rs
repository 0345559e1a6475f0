//! ROS 2 parameters for dc_loc without ROS: the standard params YAML (`node: ros__parameters: ...`,
//! wildcards `/**` and `/**/node`) and `-p name:=value` overrides, mapped onto [`Config`] by the
//! field paths joined by dots (`radars.front.beta`, `loop.search_radius`), as ROS 2 flattens nested
//! YAML. Each name in `radar_names` gets the radar defaults, then its `radars.<name>.*` parameters.
//! Unknown names and wrong types are refused with the parameter's name; nothing is silently ignored
//! or clamped.
//!
//! Entry points: [`ParamSet`] (dotted name -> value, in application order),
//! [`ParamSet::from_yaml`], [`ParamSet::set_override`], [`apply`] (defaults + params -> validated
//! [`Config`]), [`flatten_config`] (a config as dotted parameters, to declare as ROS 2 parameters
//! and to print the effective one). Parts: [`node`] (the node's own settings, `use_sim_time` and
//! `node.*`), [`live`] (what changes at run time), [`file`] (params files written), [`reference`]
//! (every parameter's default, range and description: `dc_loc params`, README_NODE.md), [`tiers`]
//! (sensor setup, tuning knobs, constants), [`checks`] (what a params file leaves to chance: sections
//! that miss the node, radars on the default noise).

pub mod checks;
pub mod constants;
pub mod file;
pub mod live;
pub mod node;
pub mod reference;
pub mod tiers;

use dc_loc_core::pipeline::Config;
use dc_loc_core::radar::RadarConfig;
use dc_loc_core::validate::ConfigError;
use serde_json::{Map, Value};

/// Why parameters could not be read or applied.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamError {
    /// The YAML does not parse.
    #[error("params file: {0}")]
    Yaml(String),
    /// A `-p` argument is not `name:=value`.
    #[error("bad parameter override `{0}` (expected name:=value)")]
    BadOverride(String),
    /// No such parameter.
    #[error("unknown parameter `{0}`")]
    Unknown(String),
    /// The value has the wrong type.
    #[error("parameter `{name}`: expected {expected}, got `{got}`")]
    Type {
        /// Parameter name.
        name: String,
        /// Expected type.
        expected: &'static str,
        /// The value given.
        got: String,
    },
    /// The name is a constant of the method, given another value than the constant's.
    #[error(
        "`{name}` is a constant of the method ({value}), not a parameter, and cannot be set to `{got}`: remove it from the params file"
    )]
    Constant {
        /// Its name.
        name: String,
        /// The constant's value.
        value: f64,
        /// The value given.
        got: String,
    },
    /// The value is of the right type but unusable.
    #[error(transparent)]
    Invalid(#[from] ConfigError),
}

/// Parameters by dotted name, later entries overriding earlier ones.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ParamSet {
    entries: Vec<(String, Value)>,
}

impl ParamSet {
    /// The parameters in order of application.
    pub fn entries(&self) -> &[(String, Value)] {
        &self.entries
    }

    /// Adds (or overrides) one parameter.
    pub fn set(&mut self, name: impl Into<String>, value: Value) {
        self.entries.push((name.into(), value));
    }

    /// Parses `name:=value` (the value as YAML: `0.5`, `true`, `[a, b]`, `text`).
    pub fn set_override(&mut self, arg: &str) -> Result<(), ParamError> {
        let (name, value) = arg
            .split_once(":=")
            .ok_or_else(|| ParamError::BadOverride(arg.to_string()))?;
        if name.is_empty() {
            return Err(ParamError::BadOverride(arg.to_string()));
        }
        let v: Value = if value.is_empty() {
            Value::String(String::new())
        } else {
            yaml_serde::from_str(value).map_err(|e| ParamError::Yaml(format!("`{arg}`: {e}")))?
        };
        self.set(name, v);
        Ok(())
    }

    /// Reads the sections of a ROS 2 params YAML that apply to the node `/namespace/node_name`
    /// (`/ns/node`, `node` meaning `/node`, `/**`, `/**/node`), in file order, flattening nested
    /// maps under `ros__parameters` into dotted names.
    pub fn from_yaml(text: &str, namespace: &str, node_name: &str) -> Result<Self, ParamError> {
        let doc: Value = yaml_serde::from_str(text).map_err(|e| ParamError::Yaml(e.to_string()))?;
        let mut set = ParamSet::default();
        let Value::Object(top) = doc else {
            if doc.is_null() {
                return Ok(set);
            }
            return Err(ParamError::Yaml(
                "top level must be a map of node names".into(),
            ));
        };
        let fq = fully_qualified(namespace, node_name);
        for (key, section) in top {
            if !node_key_matches(&key, &fq, node_name) {
                continue;
            }
            let params = match section.get("ros__parameters") {
                Some(Value::Object(m)) => m.clone(),
                Some(Value::Null) | None => continue,
                Some(_) => {
                    return Err(ParamError::Yaml(format!(
                        "`{key}.ros__parameters` must be a map"
                    )));
                }
            };
            flatten_into("", &Value::Object(params), &mut set.entries);
        }
        Ok(set)
    }
}

/// `/ns/name` from a namespace (`/`, `/car1`, `car1`) and a node name.
pub fn fully_qualified(namespace: &str, node_name: &str) -> String {
    let ns = namespace.trim_matches('/');
    if ns.is_empty() {
        format!("/{node_name}")
    } else {
        format!("/{ns}/{node_name}")
    }
}

/// Whether the params file section `key` applies to node `fq` (`/ns/node_name`), as ROS 2 decides.
fn node_key_matches(key: &str, fq: &str, node_name: &str) -> bool {
    let key = key.trim();
    if key == "/**" || key == "**" {
        return true;
    }
    if let Some(rest) = key.strip_prefix("/**/") {
        return rest == node_name;
    }
    let k = if key.starts_with('/') {
        key.to_string()
    } else {
        format!("/{key}")
    };
    k == fq
}

fn flatten_into(prefix: &str, v: &Value, out: &mut Vec<(String, Value)>) {
    match v {
        Value::Object(m) => {
            for (k, child) in m {
                let name = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten_into(&name, child, out);
            }
        }
        other => out.push((prefix.to_string(), other.clone())),
    }
}

/// A configuration as dotted parameters with their values (leaves of its serialised tree), sorted.
pub fn flatten_config(cfg: &Config) -> Vec<(String, Value)> {
    let v = serde_json::to_value(cfg).unwrap_or(Value::Null);
    let mut out = Vec::new();
    flatten_into("", &v, &mut out);
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

fn type_name(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(n) if n.is_f64() => "a number",
        Value::Number(_) => "an integer",
        Value::String(_) => "a string",
        Value::Array(_) => "a list",
        Value::Object(_) => "a map",
    }
}

/// Coerces `given` to the type of `default`, as ROS 2 does for parameters (an integer literal is
/// accepted for a double; nothing else converts).
fn coerce(name: &str, default: &Value, given: &Value) -> Result<Value, ParamError> {
    let err = || ParamError::Type {
        name: name.to_string(),
        expected: type_name(default),
        got: given.to_string(),
    };
    Ok(match (default, given) {
        (Value::Bool(_), Value::Bool(_)) | (Value::String(_), Value::String(_)) => given.clone(),
        (Value::Number(d), Value::Number(g)) => {
            if d.is_f64() {
                Value::from(g.as_f64().ok_or_else(err)?)
            } else if g.is_u64() || g.is_i64() {
                given.clone()
            } else {
                return Err(err());
            }
        }
        (Value::Array(d), Value::Array(g)) => {
            let elem = d.first();
            let mut out = Vec::with_capacity(g.len());
            for (i, x) in g.iter().enumerate() {
                out.push(match elem {
                    Some(e) => coerce(&format!("{name}[{i}]"), e, x)?,
                    None => x.clone(),
                });
            }
            Value::Array(out)
        }
        _ => return Err(err()),
    })
}

/// Applies parameters to the defaults and validates: `Config::default()` -> radars from
/// `radar_names` -> every parameter in order -> [`Config::validate`].
pub fn apply(params: &ParamSet) -> Result<Config, ParamError> {
    let mut tree =
        serde_json::to_value(Config::default()).map_err(|e| ParamError::Yaml(e.to_string()))?;
    let radar_default = serde_json::to_value(RadarConfig::default())
        .map_err(|e| ParamError::Yaml(e.to_string()))?;
    // 1. The radar list decides which radar sections exist.
    let names_param = params
        .entries
        .iter()
        .rev()
        .find(|(n, _)| n == "radar_names");
    if let Some((_, v)) = names_param {
        let v = coerce(
            "radar_names",
            &Value::Array(vec![Value::String(String::new())]),
            v,
        )?;
        let mut radars = Map::new();
        for n in v.as_array().into_iter().flatten() {
            let name = n.as_str().unwrap_or_default().to_string();
            if name.is_empty() || name.contains('.') {
                return Err(ConfigError::new(
                    "radar_names",
                    format!("`{name}` is not a usable radar name"),
                )
                .into());
            }
            radars.insert(name, radar_default.clone());
        }
        tree["radar_names"] = v;
        tree["radars"] = Value::Object(radars);
    }
    // 2. Every parameter onto the tree, refusing unknown names and wrong types.
    for (name, value) in &params.entries {
        if name == "radar_names" || constants::is_constant(name, value)? {
            continue;
        }
        let mut node = &mut tree;
        for part in name.split('.') {
            node = match node {
                Value::Object(m) => m
                    .get_mut(part)
                    .ok_or_else(|| ParamError::Unknown(name.clone()))?,
                _ => return Err(ParamError::Unknown(name.clone())),
            };
        }
        if node.is_object() {
            return Err(ParamError::Unknown(name.clone()));
        }
        *node = coerce(name, node, value)?;
    }
    let cfg: Config = serde_json::from_value(tree).map_err(|e| ParamError::Yaml(e.to_string()))?;
    cfg.validate()?;
    Ok(cfg)
}

#[cfg(test)]
mod tests {
    use super::*;

    const YAML: &str = r#"
/**:
  ros__parameters:
    body_frame: base_footprint
other_node:
  ros__parameters:
    body_frame: wrong
/car1/loc:
  ros__parameters:
    radar_names: [front, rear]
    radars:
      front:
        topic: /radar/front
        beta: 0.05
      rear:
        topic: /radar/rear
        extrinsic: [-1.0, 0.0, 0.5, 0.0, 0.0, 3.1]
    loop:
      search_radius: 20
"#;

    #[test]
    fn sections_wildcards_and_flattening() {
        let set = ParamSet::from_yaml(YAML, "/car1", "loc").unwrap();
        let cfg = apply(&set).unwrap();
        assert_eq!(cfg.body_frame, "base_footprint");
        assert_eq!(cfg.radar_names, vec!["front", "rear"]);
        assert_eq!(cfg.radars["front"].beta, 0.05);
        assert_eq!(cfg.radars["rear"].extrinsic[5], 3.1);
        assert_eq!(
            cfg.radars["rear"].beta, 0.04,
            "unset fields keep the defaults"
        );
        assert_eq!(
            cfg.r#loop.search_radius, 20.0,
            "integer literal accepted for a double"
        );
        // Another node name only gets the wildcard section.
        let other = apply(&ParamSet::from_yaml(YAML, "/", "dc_loc").unwrap()).unwrap();
        assert_eq!(other.body_frame, "base_footprint");
        assert_eq!(other.radar_names, vec!["front"]);
    }

    #[test]
    fn overrides_win_and_errors_name_the_parameter() {
        let mut set = ParamSet::from_yaml(YAML, "/car1", "loc").unwrap();
        set.set_override("radars.rear.beta:=0.02").unwrap();
        set.set_override("submap.size:=5").unwrap();
        let cfg = apply(&set).unwrap();
        assert_eq!(cfg.radars["rear"].beta, 0.02);
        assert_eq!(cfg.submap.size, 5);

        let mut bad = set.clone();
        bad.set_override("radars.rear.betta:=0.02").unwrap();
        assert_eq!(
            apply(&bad),
            Err(ParamError::Unknown("radars.rear.betta".into()))
        );
        let mut bad = set.clone();
        bad.set_override("submap.size:=ten").unwrap();
        assert!(matches!(apply(&bad), Err(ParamError::Type { name, .. }) if name == "submap.size"));
        let mut bad = set.clone();
        bad.set_override("submap.size:=2.5").unwrap();
        assert!(matches!(apply(&bad), Err(ParamError::Type { name, .. }) if name == "submap.size"));
        let mut bad = set.clone();
        bad.set_override("radars.front.beta:=-3").unwrap();
        assert!(
            matches!(apply(&bad), Err(ParamError::Invalid(e)) if e.name == "radars.front.beta")
        );
        let mut bad = set.clone();
        bad.set_override("radars.front:=1").unwrap();
        assert_eq!(apply(&bad), Err(ParamError::Unknown("radars.front".into())));
        assert!(set.clone().set_override("nonsense").is_err());
    }

    #[test]
    fn flattened_defaults_apply_back_to_the_defaults() {
        let mut set = ParamSet::default();
        for (n, v) in flatten_config(&Config::default()) {
            set.set(n, v);
        }
        assert_eq!(apply(&set).unwrap(), Config::default());
    }
}
