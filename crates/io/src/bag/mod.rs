//! rosbag2 bags in MCAP storage with CDR messages: what the simulator writes and `dc_loc run --bag`
//! reads, compatible with `ros2 bag` (Jazzy) and the Python `rosbags` library; and ROS 1 bags
//! (`.bag`, format 2.0), read through the same reader ([`ros1`]).
//!
//! Entry points:
//! - [`BagWriter`] (`create`, `add_topic`, `write`, `finish`) writes a bag directory
//!   (`<dir>/metadata.yaml` + `<dir>/<dir name>_0.mcap`; layout in [`writer`]).
//! - [`BagReader`] (`open`, `topics`, `messages`, `messages_on`) reads a bag directory, a single
//!   `.mcap` file or a ROS 1 `.bag` file; [`BagMessage::decode`] turns a message (CDR or ROS 1) into a
//!   [`dc_loc_core::msgs`] struct.
//! - [`decode`] / [`encode`]: ROS 2 CDR with its encapsulation header (`dc_loc_core::cdr`).
//! - [`schema`]: the `.msg` definitions and `ros2msg` schema texts of the known types;
//!   [`metadata`]: QoS profiles and `metadata.yaml`.
//!
//! Times are [`Stamp`]s (ns since the epoch); a message's MCAP log time is its stamp.

pub mod foxglove;
pub mod metadata;
pub mod reader;
pub mod ros1;
pub mod schema;
pub mod writer;

use std::path::PathBuf;

use dc_loc_core::math::Stamp;

pub use dc_loc_core::cdr::{self, CdrError, decode, encode};
pub use metadata::{Durability, QosProfile, Reliability};
pub use reader::{BagMessage, BagReader, Messages, TopicInfo};
pub use writer::{BagWriter, TopicId};

/// Errors of the bag reader and writer. Each names the file, topic or type it concerns.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    /// A file or directory could not be read, written, created or renamed.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The bag path, or a file its `metadata.yaml` lists, does not exist.
    #[error("{path}: no such bag directory or file")]
    NotFound {
        /// The missing path.
        path: PathBuf,
    },
    /// A bag directory without `.mcap` files.
    #[error("{path}: no .mcap file in the bag directory")]
    NoMcapFiles {
        /// The directory.
        path: PathBuf,
    },
    /// `metadata.yaml` is not rosbag2 metadata, or describes a bag this reader cannot read (other
    /// storage, file or message compression).
    #[error("{path}: {reason}")]
    Metadata {
        /// The `metadata.yaml` file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The file starts with neither the MCAP magic bytes nor a ROS bag's `#ROSBAG V`.
    #[error("{path}: neither an MCAP file nor a ROS 1 bag")]
    NotMcap {
        /// The file.
        path: PathBuf,
    },
    /// The ROS 1 bag is damaged or truncated (reported when reached; messages before it were read):
    /// a length past its record or the file, a record or chunk over the reader's limit, a chunk that
    /// does not decompress to its declared size, a record that does not belong where it stands.
    #[error("{path}: damaged ROS 1 bag: {reason}")]
    Ros1Damaged {
        /// The file.
        path: PathBuf,
        /// What is wrong, and at which byte.
        reason: String,
    },
    /// A ROS bag of a format other than 2.0 (ROS 1 bags since 2010 are 2.0).
    #[error("{path}: ROS bag format {version:?} is not read (only 2.0)")]
    Ros1Version {
        /// The file.
        path: PathBuf,
        /// What follows `#ROSBAG V`.
        version: String,
    },
    /// The MCAP file is damaged or truncated (reported when reached; messages before it were read),
    /// or the MCAP writer failed.
    #[error("{path}: damaged or truncated MCAP file: {source}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// What the MCAP library found.
        #[source]
        source: mcap::McapError,
    },
    /// The MCAP file's index points outside the file.
    #[error("{path}: damaged MCAP file: {reason}")]
    Damaged {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A message on a channel the file never defined.
    #[error("{path}: message on undefined channel id {channel_id}")]
    UnknownChannel {
        /// The file.
        path: PathBuf,
        /// The channel id of the message.
        channel_id: u16,
    },
    /// A topic whose message encoding is not CDR (e.g. protobuf or JSON from foxglove tools) was asked
    /// to decode as CDR.
    #[error(
        "topic {topic} ({type_name}): message encoding {encoding:?} is not supported (only cdr)"
    )]
    UnsupportedEncoding {
        /// Topic name.
        topic: String,
        /// Message type.
        type_name: String,
        /// The channel's message encoding.
        encoding: String,
    },
    /// One message could not be decoded as the requested type. Concerns that message only: skip it
    /// and go on iterating.
    #[error("topic {topic} ({type_name}) at {t_ns} ns: {source}", t_ns = .stamp.0)]
    Decode {
        /// Topic name.
        topic: String,
        /// Message type.
        type_name: String,
        /// Log time of the message.
        stamp: Stamp,
        /// The CDR error.
        #[source]
        source: CdrError,
    },
    /// One ROS 1 message could not be decoded as the requested type. Concerns that message only.
    #[error("topic {topic} ({type_name}) at {t_ns} ns: {source}", t_ns = .stamp.0)]
    DecodeRos1 {
        /// Topic name.
        topic: String,
        /// Message type, as ROS 1 names it.
        type_name: String,
        /// Record time of the message.
        stamp: Stamp,
        /// What does not fit.
        #[source]
        source: ros1::Ros1Error,
    },
    /// A ROS 1 connection whose type has no known layout, or whose md5sum names another definition
    /// than the one its type's struct mirrors.
    #[error("topic {topic}: {fault}")]
    Ros1Definition {
        /// Topic name.
        topic: String,
        /// Type, md5sum and what was expected.
        fault: String,
    },
    /// A message could not be serialised to CDR.
    #[error("topic {topic} ({type_name}): {source}")]
    Encode {
        /// Topic name.
        topic: String,
        /// Message type.
        type_name: String,
        /// The CDR error.
        #[source]
        source: CdrError,
    },
    /// The writer has no `.msg` definition for this type (see [`schema::KNOWN_TYPES`]).
    #[error("message type {type_name:?} has no known ros2msg definition")]
    UnknownType {
        /// The type name.
        type_name: String,
    },
    /// The topic name is not a valid fully qualified ROS 2 name.
    #[error("invalid topic name {topic:?}: {reason}")]
    InvalidTopicName {
        /// The topic name.
        topic: String,
        /// The rule it breaks.
        reason: &'static str,
    },
    /// The topic was added to the writer before.
    #[error("topic {topic} added twice")]
    DuplicateTopic {
        /// The topic name.
        topic: String,
    },
    /// A [`TopicId`] that this writer did not hand out.
    #[error("topic id {id} does not belong to this bag writer")]
    UnknownTopicId {
        /// The id.
        id: usize,
    },
    /// A message stamp before the epoch (MCAP times are unsigned).
    #[error("topic {topic}: stamp {t_ns} ns is before the epoch", t_ns = .stamp.0)]
    NegativeStamp {
        /// Topic name.
        topic: String,
        /// The stamp.
        stamp: Stamp,
    },
    /// The bag directory exists and is not empty: the writer does not overwrite.
    #[error("{path}: bag directory exists and is not empty")]
    AlreadyExists {
        /// The directory.
        path: PathBuf,
    },
    /// The bag directory path cannot name a bag (no last component, not UTF-8).
    #[error("{path}: {reason}")]
    InvalidBagPath {
        /// The path.
        path: PathBuf,
        /// Why.
        reason: &'static str,
    },
}
