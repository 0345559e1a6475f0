//! [`BagWriter`]: writes a rosbag2 bag directory with one MCAP file, as `ros2 bag record -s mcap` does.
//!
//! A finished bag `<dir>` holds `metadata.yaml` (`rosbag2_bagfile_information`, version 9) and
//! `<name>_0.mcap` (`<name>` the last component of `<dir>`), MCAP profile `ros2`: a schema per message
//! type (encoding `ros2msg`, the `.msg` text with its dependencies, see [`super::schema`]), a channel per
//! topic (message encoding `cdr`, metadata `offered_qos_profiles`, `topic_type_hash`), the messages
//! (log time = publish time = the stamp given to [`BagWriter::write`]) in zstd chunks of about 1 MiB
//! with message indexes, a metadata record `rosbag2` holding `serialized_metadata`, and the summary
//! section (schemas, channels, statistics, chunk indexes).
//!
//! Each file goes through `<file>.tmp`, synced and renamed, the MCAP file first: a bag directory with a
//! `metadata.yaml` is complete; a writer dropped without [`BagWriter::finish`] leaves a `.tmp` file only.
//! No wall-clock time or random state enters and zstd runs single threaded: same messages, same bytes.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::BagError;
use super::cdr;
use super::metadata::{BagMetadata, QosProfile, TopicMetadata};
use super::schema;
use dc_loc_core::math::Stamp;

/// Handle of a topic added to a [`BagWriter`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TopicId(usize);

struct Topic {
    meta: TopicMetadata,
    channel_id: u16,
    /// MCAP sequence number of the next message on this channel.
    sequence: u32,
}

/// Writes a rosbag2 MCAP bag directory (see the module documentation for the exact layout).
pub struct BagWriter {
    dir: PathBuf,
    file_name: String,
    tmp_path: PathBuf,
    mcap: mcap::Writer<BufWriter<File>>,
    topics: Vec<Topic>,
    /// Schema id per type name.
    schema_ids: BTreeMap<String, u16>,
    /// Earliest and latest stamp written, ns.
    time_range: Option<(i64, i64)>,
    message_count: u64,
}

/// Checks a topic name against the ROS 2 rules for fully qualified names: `/` then tokens of
/// `[A-Za-z0-9_]` separated by single `/`, no token starting with a digit, no trailing `/`.
fn check_topic_name(topic: &str) -> Result<(), BagError> {
    let invalid = |reason: &'static str| BagError::InvalidTopicName {
        topic: topic.to_string(),
        reason,
    };
    let Some(rest) = topic.strip_prefix('/') else {
        return Err(invalid("must start with '/'"));
    };
    for token in rest.split('/') {
        if token.is_empty() {
            return Err(invalid("empty name token ('//' or trailing '/')"));
        }
        if !token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(invalid("only A-Z, a-z, 0-9, '_' and '/' are allowed"));
        }
        if token.starts_with(|c: char| c.is_ascii_digit()) {
            return Err(invalid("a name token must not start with a digit"));
        }
    }
    Ok(())
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> BagError + '_ {
    move |source| BagError::Io {
        path: path.to_path_buf(),
        source,
    }
}

impl BagWriter {
    /// Starts a bag in directory `dir`, which is created (with its parents) or must be empty.
    pub fn create(dir: &Path) -> Result<Self, BagError> {
        let name = dir
            .file_name()
            .and_then(|n| n.to_str())
            .filter(|n| !n.is_empty() && *n != "." && *n != "..")
            .ok_or_else(|| BagError::InvalidBagPath {
                path: dir.to_path_buf(),
                reason: "the bag directory needs a UTF-8 last component to name its file",
            })?;
        if dir.exists() {
            let mut entries = std::fs::read_dir(dir).map_err(io_err(dir))?;
            if entries.next().is_some() {
                return Err(BagError::AlreadyExists {
                    path: dir.to_path_buf(),
                });
            }
        } else {
            std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        }
        let file_name = format!("{name}_0.mcap");
        let tmp_path = dir.join(format!("{file_name}.tmp"));
        let file = File::create(&tmp_path).map_err(io_err(&tmp_path))?;
        let mcap = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("dc_loc ", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd))
            // Single-threaded zstd: deterministic output and no threads spawned by the library.
            .compression_threads(0)
            .create(BufWriter::new(file))
            .map_err(|source| BagError::Mcap {
                path: tmp_path.clone(),
                source,
            })?;
        Ok(BagWriter {
            dir: dir.to_path_buf(),
            file_name,
            tmp_path,
            mcap,
            topics: Vec::new(),
            schema_ids: BTreeMap::new(),
            time_range: None,
            message_count: 0,
        })
    }

    /// Adds a topic of a known message type (`sensor_msgs/msg/PointCloud2`, see
    /// [`schema::KNOWN_TYPES`]) with the default QoS for its name ([`QosProfile::for_topic`]).
    pub fn add_topic(&mut self, topic: &str, type_name: &str) -> Result<TopicId, BagError> {
        self.add_topic_with_qos(topic, type_name, QosProfile::for_topic(topic))
    }

    /// Adds a topic of a known message type with an explicit offered QoS.
    pub fn add_topic_with_qos(
        &mut self,
        topic: &str,
        type_name: &str,
        qos: QosProfile,
    ) -> Result<TopicId, BagError> {
        check_topic_name(topic)?;
        if self.topics.iter().any(|t| t.meta.name == topic) {
            return Err(BagError::DuplicateTopic {
                topic: topic.to_string(),
            });
        }
        let (Some(schema_text), Some(type_hash)) = (
            schema::ros2msg_schema(type_name),
            schema::type_hash(type_name),
        ) else {
            return Err(BagError::UnknownType {
                type_name: type_name.to_string(),
            });
        };
        let mcap_err = |source| BagError::Mcap {
            path: self.tmp_path.clone(),
            source,
        };
        let schema_id = match self.schema_ids.get(type_name) {
            Some(id) => *id,
            None => {
                let id = self
                    .mcap
                    .add_schema(type_name, "ros2msg", schema_text.as_bytes())
                    .map_err(mcap_err)?;
                self.schema_ids.insert(type_name.to_string(), id);
                id
            }
        };
        let metadata = BTreeMap::from([
            ("offered_qos_profiles".to_string(), qos.to_channel_yaml()),
            ("topic_type_hash".to_string(), type_hash.to_string()),
        ]);
        let channel_id = self
            .mcap
            .add_channel(schema_id, topic, "cdr", &metadata)
            .map_err(|source| BagError::Mcap {
                path: self.tmp_path.clone(),
                source,
            })?;
        self.topics.push(Topic {
            meta: TopicMetadata {
                name: topic.to_string(),
                type_name: type_name.to_string(),
                qos,
                type_hash: type_hash.to_string(),
                message_count: 0,
            },
            channel_id,
            sequence: 1,
        });
        Ok(TopicId(self.topics.len() - 1))
    }

    /// Serialises `msg` to CDR and writes it on `topic` with log and publish time `stamp`.
    ///
    /// `T` must be the Rust struct of the topic's type (from [`dc_loc_core::msgs`]); the writer cannot check
    /// that. Messages may come in any time order.
    pub fn write<T: Serialize>(
        &mut self,
        topic: TopicId,
        stamp: Stamp,
        msg: &T,
    ) -> Result<(), BagError> {
        let t = self.topic(topic)?;
        let data = cdr::encode(msg).map_err(|source| BagError::Encode {
            topic: t.meta.name.clone(),
            type_name: t.meta.type_name.clone(),
            source,
        })?;
        self.write_cdr(topic, stamp, &data)
    }

    /// Writes an already serialised CDR message (encapsulation header included) on `topic`.
    pub fn write_cdr(&mut self, topic: TopicId, stamp: Stamp, cdr: &[u8]) -> Result<(), BagError> {
        let t = self.topic(topic)?;
        let Ok(log_time) = u64::try_from(stamp.0) else {
            return Err(BagError::NegativeStamp {
                topic: t.meta.name.clone(),
                stamp,
            });
        };
        let header = mcap::records::MessageHeader {
            channel_id: t.channel_id,
            sequence: t.sequence,
            log_time,
            publish_time: log_time,
        };
        self.mcap
            .write_to_known_channel(&header, cdr)
            .map_err(|source| BagError::Mcap {
                path: self.tmp_path.clone(),
                source,
            })?;
        let t = &mut self.topics[topic.0];
        t.sequence = t.sequence.wrapping_add(1);
        t.meta.message_count += 1;
        self.message_count += 1;
        self.time_range = Some(match self.time_range {
            None => (stamp.0, stamp.0),
            Some((a, b)) => (a.min(stamp.0), b.max(stamp.0)),
        });
        Ok(())
    }

    fn topic(&self, topic: TopicId) -> Result<&Topic, BagError> {
        self.topics
            .get(topic.0)
            .ok_or(BagError::UnknownTopicId { id: topic.0 })
    }

    /// Messages written so far.
    pub fn message_count(&self) -> u64 {
        self.message_count
    }

    /// The metadata describing what has been written so far.
    pub fn metadata(&self) -> BagMetadata {
        let (start, end) = self.time_range.unwrap_or((0, 0));
        BagMetadata {
            file_name: self.file_name.clone(),
            starting_time_ns: start,
            duration_ns: end - start,
            message_count: self.message_count,
            topics: self.topics.iter().map(|t| t.meta.clone()).collect(),
        }
    }

    /// Completes the bag: MCAP summary, rename of the MCAP file to its final name, `metadata.yaml`.
    /// Returns the bag directory.
    pub fn finish(mut self) -> Result<PathBuf, BagError> {
        let metadata = self.metadata();
        let mcap_err = |path: &Path| {
            let path = path.to_path_buf();
            move |source| BagError::Mcap { path, source }
        };
        self.mcap
            .write_metadata(&mcap::records::Metadata {
                name: "rosbag2".to_string(),
                metadata: BTreeMap::from([(
                    "serialized_metadata".to_string(),
                    metadata.to_serialized_metadata(),
                )]),
            })
            .map_err(mcap_err(&self.tmp_path))?;
        self.mcap.finish().map_err(mcap_err(&self.tmp_path))?;
        let file = self
            .mcap
            .into_inner()
            .into_inner()
            .map_err(|e| BagError::Io {
                path: self.tmp_path.clone(),
                source: e.into_error(),
            })?;
        file.sync_all().map_err(io_err(&self.tmp_path))?;
        drop(file);
        let final_path = self.dir.join(&self.file_name);
        std::fs::rename(&self.tmp_path, &final_path).map_err(io_err(&final_path))?;

        let yaml_path = self.dir.join("metadata.yaml");
        let yaml_tmp = self.dir.join("metadata.yaml.tmp");
        {
            let mut f = File::create(&yaml_tmp).map_err(io_err(&yaml_tmp))?;
            f.write_all(metadata.to_metadata_yaml().as_bytes())
                .map_err(io_err(&yaml_tmp))?;
            f.sync_all().map_err(io_err(&yaml_tmp))?;
        }
        std::fs::rename(&yaml_tmp, &yaml_path).map_err(io_err(&yaml_path))?;
        // Make the renames themselves durable.
        File::open(&self.dir)
            .and_then(|d| d.sync_all())
            .map_err(io_err(&self.dir))?;
        Ok(self.dir)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topic_names_follow_ros_rules() {
        for ok in ["/tf", "/radar_front", "/a/b_c/d9"] {
            assert!(check_topic_name(ok).is_ok(), "{ok}");
        }
        for bad in ["tf", "/", "//tf", "/tf/", "/9lives", "/a b", "/a-b", ""] {
            assert!(check_topic_name(bad).is_err(), "{bad}");
        }
    }
}
