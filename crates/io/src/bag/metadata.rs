//! rosbag2 metadata: offered QoS profiles and `metadata.yaml`, written the way rosbag2 (Jazzy,
//! metadata version 9, yaml-cpp) writes them, and read back leniently.
//!
//! Entry points: [`QosProfile`] ([`Reliability`], [`Durability`]), [`BagMetadata`] (what the writer
//! records) with [`BagMetadata::to_metadata_yaml`] and [`BagMetadata::to_serialized_metadata`], and
//! [`read_metadata_yaml`] for the reader.
//!
//! Version 9 writes QoS policies as names (`reliable`, `transient_local`, ...) and
//! `offered_qos_profiles` in `metadata.yaml` as a YAML list; the MCAP channel keeps the same list as a
//! YAML string. Durations are `{sec, nsec}`; the values here are those a Jazzy `ros2 bag record`
//! stores for a default publisher (history unknown with depth 0, because DDS discovery does not carry
//! them; infinite deadline, lifespan and lease as `RMW_DURATION_INFINITE`).

use std::fmt::Write as _;
use std::path::Path;

use serde::Deserialize;

use super::BagError;

/// rosbag2 metadata version written (Jazzy).
pub const METADATA_VERSION: u32 = 9;

/// `RMW_DURATION_INFINITE` as rosbag2 writes it: seconds part.
const INFINITE_SEC: i64 = 9_223_372_036;
/// `RMW_DURATION_INFINITE` as rosbag2 writes it: nanoseconds part.
const INFINITE_NSEC: i64 = 854_775_807;

/// QoS reliability of a topic's publisher.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reliability {
    /// Every sample is delivered (retransmitted when lost).
    Reliable,
    /// Samples may be lost.
    BestEffort,
}

/// QoS durability of a topic's publisher.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Durability {
    /// Late joiners get nothing published before they joined.
    Volatile,
    /// Late joiners get the publisher's history (`/tf_static`, latched topics).
    TransientLocal,
}

/// The offered QoS profile recorded for a topic (the parts a player needs to re-offer it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QosProfile {
    /// Reliability policy.
    pub reliability: Reliability,
    /// Durability policy.
    pub durability: Durability,
}

impl QosProfile {
    /// Reliable, volatile: sensor data, odometry, loop closures as recorded data.
    pub const RELIABLE_VOLATILE: QosProfile = QosProfile {
        reliability: Reliability::Reliable,
        durability: Durability::Volatile,
    };
    /// Reliable, transient local: `/tf_static` (what tf2's static broadcaster offers).
    pub const RELIABLE_TRANSIENT_LOCAL: QosProfile = QosProfile {
        reliability: Reliability::Reliable,
        durability: Durability::TransientLocal,
    };

    /// The default profile for a topic name: transient local for `/tf_static`, else reliable volatile.
    pub fn for_topic(topic: &str) -> QosProfile {
        if topic == "/tf_static" {
            QosProfile::RELIABLE_TRANSIENT_LOCAL
        } else {
            QosProfile::RELIABLE_VOLATILE
        }
    }

    /// The profile as one YAML list item (version 9 names), lines indented by `indent` spaces.
    fn write_yaml_item(&self, out: &mut String, indent: usize) {
        let pad = " ".repeat(indent);
        let reliability = match self.reliability {
            Reliability::Reliable => "reliable",
            Reliability::BestEffort => "best_effort",
        };
        let durability = match self.durability {
            Durability::Volatile => "volatile",
            Durability::TransientLocal => "transient_local",
        };
        let infinite = |out: &mut String, key: &str| {
            let _ = write!(
                out,
                "{pad}  {key}:\n{pad}    sec: {INFINITE_SEC}\n{pad}    nsec: {INFINITE_NSEC}\n"
            );
        };
        let _ = write!(
            out,
            "{pad}- history: unknown\n{pad}  depth: 0\n{pad}  reliability: {reliability}\n\
             {pad}  durability: {durability}\n"
        );
        infinite(out, "deadline");
        infinite(out, "lifespan");
        let _ = writeln!(out, "{pad}  liveliness: automatic");
        infinite(out, "liveliness_lease_duration");
        let _ = writeln!(out, "{pad}  avoid_ros_namespace_conventions: false");
    }

    /// `offered_qos_profiles` as the YAML string rosbag2 stores in the MCAP channel metadata
    /// (yaml-cpp `Dump` of a one-element list, no final newline).
    pub fn to_channel_yaml(&self) -> String {
        let mut out = String::new();
        self.write_yaml_item(&mut out, 0);
        out.trim_end().to_string()
    }
}

/// One topic as recorded in the metadata.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicMetadata {
    /// Topic name.
    pub name: String,
    /// Type name, `pkg/msg/Type`.
    pub type_name: String,
    /// Offered QoS.
    pub qos: QosProfile,
    /// RIHS01 type hash (empty when unknown).
    pub type_hash: String,
    /// Messages written.
    pub message_count: u64,
}

/// What the writer knows about the bag it has written (one storage file).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BagMetadata {
    /// Name of the MCAP file, relative to the bag directory.
    pub file_name: String,
    /// Earliest message time, ns since the epoch (0 for an empty bag).
    pub starting_time_ns: i64,
    /// Latest minus earliest message time, ns.
    pub duration_ns: i64,
    /// Messages written.
    pub message_count: u64,
    /// Topics in the order they were added.
    pub topics: Vec<TopicMetadata>,
}

/// A YAML plain scalar when `s` is safe as one, else a double-quoted one.
fn yaml_str(s: &str) -> String {
    let plain = !s.is_empty()
        && s.chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '/' || c == '_')
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "_/.-".contains(c))
        && !matches!(s, "true" | "false" | "null" | "yes" | "no" | "on" | "off");
    if plain {
        s.to_string()
    } else {
        // A JSON string is a valid YAML double-quoted scalar.
        serde_json::Value::String(s.to_string()).to_string()
    }
}

impl BagMetadata {
    /// The body of `rosbag2_bagfile_information` (yaml-cpp block style), each line indented by
    /// `indent` spaces.
    fn write_body(&self, out: &mut String, indent: usize) {
        let p = " ".repeat(indent);
        let file = yaml_str(&self.file_name);
        let _ = write!(
            out,
            "{p}version: {METADATA_VERSION}\n{p}storage_identifier: mcap\n\
             {p}duration:\n{p}  nanoseconds: {}\n\
             {p}starting_time:\n{p}  nanoseconds_since_epoch: {}\n\
             {p}message_count: {}\n",
            self.duration_ns, self.starting_time_ns, self.message_count
        );
        if self.topics.is_empty() {
            let _ = writeln!(out, "{p}topics_with_message_count: []");
        } else {
            let _ = writeln!(out, "{p}topics_with_message_count:");
            for t in &self.topics {
                let _ = write!(
                    out,
                    "{p}  - topic_metadata:\n{p}      name: {}\n{p}      type: {}\n\
                     {p}      serialization_format: cdr\n{p}      offered_qos_profiles:\n",
                    yaml_str(&t.name),
                    yaml_str(&t.type_name)
                );
                t.qos.write_yaml_item(out, indent + 8);
                let _ = write!(
                    out,
                    "{p}      type_description_hash: {}\n{p}    message_count: {}\n",
                    if t.type_hash.is_empty() {
                        "\"\"".to_string()
                    } else {
                        yaml_str(&t.type_hash)
                    },
                    t.message_count
                );
            }
        }
        let _ = write!(
            out,
            "{p}compression_format: \"\"\n{p}compression_mode: \"\"\n\
             {p}relative_file_paths:\n{p}  - {file}\n\
             {p}files:\n{p}  - path: {file}\n\
             {p}    starting_time:\n{p}      nanoseconds_since_epoch: {}\n\
             {p}    duration:\n{p}      nanoseconds: {}\n\
             {p}    message_count: {}\n\
             {p}custom_data: ~\n{p}ros_distro: jazzy\n",
            self.starting_time_ns, self.duration_ns, self.message_count
        );
    }

    /// The `metadata.yaml` file of the bag directory.
    pub fn to_metadata_yaml(&self) -> String {
        let mut out = String::from("rosbag2_bagfile_information:\n");
        self.write_body(&mut out, 2);
        out
    }

    /// The `serialized_metadata` value of the MCAP metadata record `rosbag2` (the same content
    /// without the top-level key), which `ros2 bag info` reads from a lone `.mcap` file.
    pub fn to_serialized_metadata(&self) -> String {
        let mut out = String::new();
        self.write_body(&mut out, 0);
        out.trim_end().to_string()
    }
}

/// The parts of a `metadata.yaml` the reader uses.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BagDirectoryInfo {
    /// Metadata version.
    pub version: u32,
    /// Storage files, relative to the bag directory.
    pub relative_file_paths: Vec<String>,
}

#[derive(Deserialize)]
struct MetadataFile {
    rosbag2_bagfile_information: MetadataBody,
}

#[derive(Deserialize)]
struct MetadataBody {
    version: u32,
    storage_identifier: String,
    relative_file_paths: Vec<String>,
    #[serde(default)]
    compression_format: Option<String>,
    #[serde(default)]
    compression_mode: Option<String>,
}

/// Reads a bag directory's `metadata.yaml` and checks that this reader can read the bag: MCAP
/// storage, no file or message compression (chunk compression inside MCAP is fine).
pub fn read_metadata_yaml(path: &Path) -> Result<BagDirectoryInfo, BagError> {
    let text = std::fs::read_to_string(path).map_err(|source| BagError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let bad = |reason: String| BagError::Metadata {
        path: path.to_path_buf(),
        reason,
    };
    let file: MetadataFile =
        yaml_serde::from_str(&text).map_err(|e| bad(format!("not rosbag2 metadata: {e}")))?;
    let body = file.rosbag2_bagfile_information;
    if body.storage_identifier != "mcap" {
        return Err(bad(format!(
            "storage {:?} is not supported (only mcap)",
            body.storage_identifier
        )));
    }
    let mode = body.compression_mode.unwrap_or_default().to_lowercase();
    if !(mode.is_empty() || mode == "none") {
        return Err(bad(format!(
            "compression mode {mode:?} ({}) is not supported (only uncompressed files; MCAP chunk \
             compression is fine)",
            body.compression_format.unwrap_or_default()
        )));
    }
    Ok(BagDirectoryInfo {
        version: body.version,
        relative_file_paths: body.relative_file_paths,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaml_strings_are_quoted_when_needed() {
        assert_eq!(yaml_str("/radar_front"), "/radar_front");
        assert_eq!(yaml_str("drive_0.mcap"), "drive_0.mcap");
        assert_eq!(yaml_str(""), "\"\"");
        assert_eq!(yaml_str("a b: c"), "\"a b: c\"");
        assert_eq!(yaml_str("-x"), "\"-x\"");
        assert_eq!(yaml_str("true"), "\"true\"");
    }
}
