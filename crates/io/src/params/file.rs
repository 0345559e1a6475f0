//! ROS 2 params files written by dc_loc: [`params_yaml`] (a [`Config`] as the params file of node
//! [`NODE_NAME`], every parameter, as `dc_loc sim` writes it beside each bag), [`setup_yaml`] (the
//! sensor setup and what differs from the defaults, as the shipped files in params/ are) and
//! [`params_file`] (any parameters, the node's own `node.*` too: `dc_loc params --yaml`).

use std::fmt::Write as _;

use serde_json::{Map, Value};

use super::tiers::{Tier, generic_name, tier};
use super::{ParamError, ParamSet, apply, flatten_config};
use dc_loc_core::pipeline::Config;

/// Node name the params files are written for.
pub const NODE_NAME: &str = "dc_loc";

/// Top-level sections of [`Config`] in the order written, with their group comments.
const GROUPS: &[(&str, &str)] = &[
    (
        "body_frame",
        "Body frame: child frame of the odometry, frame of the loop closures.",
    ),
    (
        "radar_names",
        "Radars in use, in order; each needs a `radars.<name>` section.",
    ),
    (
        "radars",
        "Per radar: PointCloud2 topic and frame_id (empty accepts any), extrinsic in the body frame\n\
         [x, y, z (m), roll, pitch, yaw (rad)], Doppler coupling beta (s), field names, and the noise\n\
         standard deviations sigma_range (m), sigma_velocity (m/s), sigma_azimuth (rad).",
    ),
    (
        "odometry",
        "nav_msgs/Odometry input: topic; history kept, largest gap interpolated, extrapolation (s).",
    ),
    (
        "ego_motion",
        "Doppler ego-motion fit and moving-object rejection.",
    ),
    (
        "submap",
        "Submap stacking: compensated scans per submap (the paper's N = 10).",
    ),
    (
        "keyframe",
        "Keyframe spacing: distance (m), heading change (rad), fewest points.",
    ),
    (
        "loop",
        "Revisit search and closure acceptance: search radius and path gap (m), candidates, gates.",
    ),
    (
        "registration",
        "Registration: descriptors, matching, RANSAC, Levenberg-Marquardt, dense refinement.",
    ),
    (
        "use_sim_time",
        "Stamp outputs with /clock time (the node only).",
    ),
    (
        "node",
        "The node's own settings: queue, diagnostics, input size limits (also dc_loc run), stamps,\n\
         shutdown.",
    ),
];

/// A configuration as a ROS 2 params file for node [`NODE_NAME`]: `header` as comment lines, then
/// `dc_loc: ros__parameters:` with every parameter of [`flatten_config`] nested back into maps, one
/// commented group per top-level section.
///
/// Values are written so that ROS 2 types them as [`crate::params::apply`] expects: doubles always with
/// a decimal point (`5.0`, `1.0e-6`), strings quoted, lists in flow style. Reading the text back with
/// [`crate::params::ParamSet::from_yaml`] and applying it gives `cfg` exactly (floats are written in
/// their shortest round-trip form).
pub fn params_yaml(cfg: &Config, header: &str) -> String {
    params_file(&flatten_config(cfg), header)
}

/// A configuration as a ROS 2 params file that holds the sensor setup (every [`Tier::Setup`]
/// parameter: what a user describes of a robot) and every other parameter whose value is not its
/// default; the rest keeps its default when the file is read. Applying the file gives `cfg` exactly,
/// as for [`params_yaml`].
pub fn setup_yaml(cfg: &Config, header: &str) -> Result<String, ParamError> {
    // The defaults for the same radars: every listed radar with the radar defaults.
    let mut names = ParamSet::default();
    names.set(
        "radar_names",
        serde_json::to_value(&cfg.radar_names).unwrap_or_default(),
    );
    let defaults: Map<String, Value> = flatten_config(&apply(&names)?).into_iter().collect();
    let params: Vec<(String, Value)> = flatten_config(cfg)
        .into_iter()
        .filter(|(name, value)| {
            tier(&generic_name(name)) == Tier::Setup || defaults.get(name) != Some(value)
        })
        .collect();
    Ok(params_file(&params, header))
}

/// Parameters `(dotted name, value)` as a ROS 2 params file for node [`NODE_NAME`] (as
/// [`params_yaml`], for any set of parameters: the node's own ones too).
pub fn params_file(params: &[(String, Value)], header: &str) -> String {
    // Nest the dotted names back into maps.
    let mut root = Map::new();
    for (name, value) in params {
        let value = value.clone();
        let mut node = &mut root;
        let mut parts = name.split('.').peekable();
        while let Some(part) = parts.next() {
            if parts.peek().is_none() {
                node.insert(part.to_string(), value.clone());
                break;
            }
            let child = node
                .entry(part.to_string())
                .or_insert_with(|| Value::Object(Map::new()));
            if !child.is_object() {
                *child = Value::Object(Map::new());
            }
            let Value::Object(m) = child else { break };
            node = m;
        }
    }
    let mut out = String::new();
    for line in header.lines() {
        let _ = writeln!(out, "{}", format!("# {line}").trim_end());
    }
    let _ = writeln!(out, "{NODE_NAME}:\n  ros__parameters:");
    let mut keys: Vec<&String> = root.keys().collect();
    let rank = |k: &str| {
        GROUPS
            .iter()
            .position(|(g, _)| *g == k)
            .unwrap_or(GROUPS.len())
    };
    keys.sort_by(|a, b| rank(a).cmp(&rank(b)).then(a.cmp(b)));
    for (i, key) in keys.into_iter().enumerate() {
        if i > 0 {
            out.push('\n');
        }
        if let Some((_, comment)) = GROUPS.iter().find(|(g, _)| *g == key.as_str()) {
            for line in comment.lines() {
                let _ = writeln!(out, "    # {line}");
            }
        }
        if let Some(v) = root.get(key) {
            write_entry(&mut out, 4, key, v);
        }
    }
    out
}

fn write_entry(out: &mut String, indent: usize, key: &str, v: &Value) {
    let pad = " ".repeat(indent);
    match v {
        Value::Object(m) => {
            let _ = writeln!(out, "{pad}{key}:");
            for (k, child) in m {
                write_entry(out, indent + 2, k, child);
            }
        }
        leaf => {
            let _ = writeln!(out, "{pad}{key}: {}", yaml_scalar(leaf));
        }
    }
}

/// A leaf value in YAML flow syntax that ROS 2 types as the config does.
fn yaml_scalar(v: &Value) -> String {
    match v {
        Value::Null => "null".into(),
        Value::Bool(b) => b.to_string(),
        Value::Number(n) => match (n.as_f64(), n.is_f64()) {
            (Some(f), true) => yaml_float(f),
            _ => n.to_string(),
        },
        // A JSON string is a valid YAML double-quoted scalar.
        Value::String(s) => Value::String(s.clone()).to_string(),
        Value::Array(items) => {
            let items: Vec<String> = items.iter().map(yaml_scalar).collect();
            format!("[{}]", items.join(", "))
        }
        Value::Object(_) => "{}".into(),
    }
}

/// A double in its shortest round-trip form, always with a decimal point and, in exponent form, an
/// exponent sign (YAML 1.1 floats, as yaml-cpp and PyYAML read them).
fn yaml_float(f: f64) -> String {
    if f.is_nan() {
        return ".nan".into();
    }
    if f.is_infinite() {
        return if f > 0.0 { ".inf" } else { "-.inf" }.into();
    }
    let s = format!("{f:?}");
    match s.split_once('e') {
        Some((mantissa, exp)) => {
            let mantissa = if mantissa.contains('.') {
                mantissa.to_string()
            } else {
                format!("{mantissa}.0")
            };
            let exp = if exp.starts_with('-') {
                exp.to_string()
            } else {
                format!("+{exp}")
            };
            format!("{mantissa}e{exp}")
        }
        None => s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floats_keep_a_decimal_point_and_round_trip() {
        for (f, want) in [
            (5.0, "5.0"),
            (0.04, "0.04"),
            (1e-6, "1.0e-6"),
            (2.5e-7, "2.5e-7"),
            (1e20, "1.0e+20"),
            (-3.0, "-3.0"),
        ] {
            let s = yaml_float(f);
            assert_eq!(s, want);
            let back: f64 = yaml_serde::from_str(&s).unwrap();
            assert_eq!(back, f);
        }
    }
}
