//! A simulated drive as a rosbag2 bag (what `dc_loc sim` writes), with the params YAML to run it.
//!
//! Entry points: [`export_drive`] (bag + `dc_loc.yaml` in one directory, an [`ExportSummary`]),
//! [`write_bag`] (the bag alone), [`params_yaml`] (any [`Config`] as a ROS 2 params file; also makes
//! the shipped `params/*.yaml`), [`drive_description`].
//!
//! The bag (`<dir>/metadata.yaml`, `<dir>/<name>_0.mcap`, written by [`BagWriter`]):
//! - each radar's scans as `sensor_msgs/msg/PointCloud2` on its topic (from [`SimDrive::to_config`]),
//!   `frame_id` the radar frame, fields `x, y, z, v_r, rcs` FLOAT32 ([`CloudLayout::radar_f32`]);
//! - [`crate::pipeline::Config`]'s odometry topic (`/odom`): `nav_msgs/msg/Odometry`, frame `odom`, child
//!   `base_link` (the simulator's `odom_frame` and `body_frame`), the drifting odometry;
//! - [`GROUND_TRUTH_TOPIC`]: `nav_msgs/msg/Odometry`, frame `map`, the true pose and twist;
//! - [`TF_STATIC_TOPIC`]: one `tf2_msgs/msg/TFMessage` at the start with `base_link -> <radar frame>`
//!   for every radar (the extrinsics), offered transient local as tf2's static broadcaster does.
//!
//! Each message's log time is its stamp. Deterministic: one drive gives byte-identical files.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde_json::{Map, Value};

use crate::bag::{BagError, BagWriter, schema};
use crate::cloud::{CloudLayout, EncodeError, encode_detections};
use crate::math::Stamp;
use crate::msgs::geometry_msgs::{Transform, TransformStamped};
use crate::msgs::std_msgs::Header;
use crate::msgs::tf2_msgs::TFMessage;
use crate::params::flatten_config;
use crate::pipeline::Config;
use crate::sim::noise::NoiseModel;
use crate::sim::{RadarPreset, SimConfig, SimDrive, SimEventRef};

/// Topic of the ground-truth odometry.
pub const GROUND_TRUTH_TOPIC: &str = "/ground_truth/odom";
/// Topic of the static transforms.
pub const TF_STATIC_TOPIC: &str = "/tf_static";
/// Name of the params file written into the bag directory.
pub const PARAMS_FILE: &str = "dc_loc.yaml";
/// Node name the params files are written for.
pub const NODE_NAME: &str = "dc_loc";

/// Why a drive could not be exported.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The bag writer failed (the directory exists and is not empty, I/O, ...).
    #[error(transparent)]
    Bag(#[from] BagError),
    /// A scan could not be encoded as a PointCloud2.
    #[error("scan of radar {radar} at {:.6} s: {source}", .stamp.as_secs_f64())]
    Encode {
        /// Radar index.
        radar: usize,
        /// Scan stamp.
        stamp: Stamp,
        /// The encoder's error.
        #[source]
        source: EncodeError,
    },
    /// The params file could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
}

/// Messages written on one topic.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicCount {
    /// Topic name.
    pub topic: String,
    /// Message type.
    pub type_name: &'static str,
    /// Messages written.
    pub count: u64,
}

/// What [`export_drive`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportSummary {
    /// The bag directory.
    pub bag_dir: PathBuf,
    /// The params YAML (inside the bag directory).
    pub params_file: PathBuf,
    /// Messages in the bag.
    pub messages: u64,
    /// Per topic, in the order added.
    pub topics: Vec<TopicCount>,
}

/// Writes the bag of `drive` into `dir` (created, or empty); returns the bag directory and the
/// messages per topic.
pub fn write_bag(drive: &SimDrive, dir: &Path) -> Result<(PathBuf, Vec<TopicCount>), ExportError> {
    let sim = &drive.setup.config;
    let cfg = drive.to_config();
    let mut bag = BagWriter::create(dir)?;
    let tf_topic = bag.add_topic(TF_STATIC_TOPIC, schema::TF_MESSAGE)?;
    let odom_topic = bag.add_topic(&cfg.odometry.topic, schema::ODOMETRY)?;
    let gt_topic = bag.add_topic(GROUND_TRUTH_TOPIC, schema::ODOMETRY)?;
    let mut radar_topics = Vec::new();
    for (_, rc) in cfg.radar_list() {
        radar_topics.push((
            bag.add_topic(&rc.topic, schema::POINT_CLOUD2)?,
            rc.frame_id.clone(),
        ));
    }
    let count = |topic: &str, type_name| TopicCount {
        topic: topic.to_string(),
        type_name,
        count: 0,
    };
    let mut counts = vec![
        count(TF_STATIC_TOPIC, schema::TF_MESSAGE),
        count(&cfg.odometry.topic, schema::ODOMETRY),
        count(GROUND_TRUTH_TOPIC, schema::ODOMETRY),
    ];
    counts.extend(
        cfg.radar_list()
            .into_iter()
            .map(|(_, rc)| count(&rc.topic, schema::POINT_CLOUD2)),
    );

    // The extrinsics once, at the start.
    let start = drive.setup.start;
    let tf = TFMessage {
        transforms: cfg
            .radar_list()
            .into_iter()
            .map(|(_, rc)| TransformStamped {
                header: Header {
                    stamp: start.into(),
                    frame_id: sim.body_frame.clone(),
                },
                child_frame_id: rc.frame_id.clone(),
                transform: Transform::from(&rc.t_body_radar()),
            })
            .collect(),
    };
    bag.write(tf_topic, start, &tf)?;
    counts[0].count += 1;

    let layout = CloudLayout::radar_f32();
    for ev in drive.events() {
        match ev {
            SimEventRef::GroundTruth(p) => {
                bag.write(
                    gt_topic,
                    p.stamp,
                    &p.to_msg(&sim.map_frame, &sim.body_frame),
                )?;
                counts[2].count += 1;
            }
            SimEventRef::Odometry(o) => {
                bag.write(
                    odom_topic,
                    o.stamp,
                    &o.to_msg(&sim.odom_frame, &sim.body_frame),
                )?;
                counts[1].count += 1;
            }
            SimEventRef::Scan(s) => {
                let r = s.scan.radar;
                let Some((topic, frame_id)) = radar_topics.get(r) else {
                    continue; // every scan's radar has a topic: to_config lists the simulated radars
                };
                let header = Header {
                    stamp: s.scan.stamp.into(),
                    frame_id: frame_id.clone(),
                };
                let cloud =
                    encode_detections(&s.scan.detections, &layout, header).map_err(|source| {
                        ExportError::Encode {
                            radar: r,
                            stamp: s.scan.stamp,
                            source,
                        }
                    })?;
                bag.write(*topic, s.scan.stamp, &cloud)?;
                counts[3 + r].count += 1;
            }
        }
    }
    Ok((bag.finish()?, counts))
}

/// Writes the bag of `drive` into `dir` and, beside its files, [`PARAMS_FILE`]: the pipeline
/// configuration of the drive ([`SimDrive::to_config`]) as a params YAML for node [`NODE_NAME`].
pub fn export_drive(drive: &SimDrive, dir: &Path) -> Result<ExportSummary, ExportError> {
    let (bag_dir, topics) = write_bag(drive, dir)?;
    let header = format!(
        "dc_loc parameters for the simulated drive in this bag directory (written by `dc_loc sim`):\n{}\n\
         Run it with: dc_loc run --bag {} --params {} --out closures.jsonl",
        drive_description(&drive.setup.config),
        bag_dir.display(),
        bag_dir.join(PARAMS_FILE).display()
    );
    let params_file = bag_dir.join(PARAMS_FILE);
    std::fs::write(&params_file, params_yaml(&drive.to_config(), &header)).map_err(|source| {
        ExportError::Io {
            path: params_file.clone(),
            source,
        }
    })?;
    Ok(ExportSummary {
        messages: topics.iter().map(|t| t.count).sum(),
        bag_dir,
        params_file,
        topics,
    })
}

/// One line describing a drive: seed, radars, noise, laps with speeds (km/h) and directions, odometry
/// errors.
pub fn drive_description(cfg: &SimConfig) -> String {
    let preset = match cfg.radar_preset {
        RadarPreset::Carla => "carla",
        RadarPreset::Nuscenes => "nuscenes",
        RadarPreset::Custom => "custom",
    };
    let noise = match cfg.noise.model {
        NoiseModel::None => "none",
        NoiseModel::Gaussian => "gaussian",
        NoiseModel::Gamma => "gamma",
        NoiseModel::StudentT => "student-t",
    };
    let laps: Vec<String> = cfg
        .laps
        .iter()
        .map(|l| {
            format!(
                "{:.0} km/h{}",
                l.speed * 3.6,
                if l.reverse { " reverse" } else { "" }
            )
        })
        .collect();
    format!(
        "seed {}, radar preset {preset} ({} radar{}), noise {noise}, laps [{}], odometry scale error {}, \
         yaw-rate bias {:.3} deg/s",
        cfg.seed,
        cfg.radar_list().len(),
        if cfg.radar_list().len() == 1 { "" } else { "s" },
        laps.join(", "),
        cfg.odometry.scale_error,
        cfg.odometry.yaw_rate_bias.to_degrees()
    )
}

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
    // Nest the dotted names back into maps.
    let mut root = Map::new();
    for (name, value) in flatten_config(cfg) {
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
    use crate::params::{ParamSet, apply};

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

    #[test]
    fn params_yaml_applies_back_to_the_config() {
        let mut cfg = SimConfig::with_preset(RadarPreset::Nuscenes).to_config();
        cfg.keyframe.distance = 7.0;
        cfg.radars.get_mut("front").unwrap().fields.rcs.clear();
        let text = params_yaml(&cfg, "a test\nsecond line");
        assert!(text.starts_with("# a test\n# second line\ndc_loc:\n  ros__parameters:\n"));
        assert!(text.contains("    keyframe:\n      angle: 0.5\n      distance: 7.0\n"));
        let set = ParamSet::from_yaml(&text, "/", NODE_NAME).unwrap();
        assert_eq!(apply(&set).unwrap(), cfg);
        // Another node name gets nothing from it.
        let other = ParamSet::from_yaml(&text, "/", "other").unwrap();
        assert!(other.entries().is_empty());
    }
}
