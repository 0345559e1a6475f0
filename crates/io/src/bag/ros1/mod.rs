//! ROS 1 bags (format 2.0, `#ROSBAG V2.0`): what `rosbag record` writes, read through the same
//! [`BagReader`](super::BagReader) as rosbag2 MCAP bags.
//!
//! A `.bag` file is a list of records (a header of `name=value` fields, then data): the bag header,
//! then chunks (uncompressed, `bz2` or `lz4`), each holding connection records and messages, each
//! chunk followed by its index records, and at the end the index section (every connection once, then
//! one chunk info per chunk with its message counts and time range).
//!
//! What the reader takes from it:
//! - Topics: from the connection records. A topic's type is the connection's `type` with `msg/`
//!   inserted (`sensor_msgs/PointCloud2` reads as `sensor_msgs/msg/PointCloud2`, the name rosbag2
//!   uses), so the same configuration and checks serve both kinds of bag; its message encoding is
//!   `ros1`, its schema the connection's `message_definition` (schema encoding `ros1msg`), and
//!   [`TopicInfo::md5sum`](super::TopicInfo::md5sum) its `md5sum`.
//! - Messages: in file order (the order `rosbag record` received them), each with the record's time
//!   as its log time. [`BagMessage::decode`](super::BagMessage::decode) reads the ROS 1 bytes ([`de`])
//!   into the [`dc_loc_core::msgs`] structs, after checking that the connection's md5sum is the one of
//!   the definition those structs mirror ([`KNOWN_TYPES`]): a connection of another definition under a
//!   known name is refused, naming topic, type and both sums.
//! - Counts and time range: from the index section when it is whole; otherwise (a recording that
//!   never closed, a truncated copy) the file is scanned once, up to its damage.
//!
//! Memory and damage, as for MCAP: one chunk is held at a time, compressed and decompressed; a record
//! or chunk that declares more than [`MAX_RECORD_BYTES`](super::reader::MAX_RECORD_BYTES) (its data
//! or its uncompressed size) is refused, as is a length that runs past its record or the file, a
//! chunk that does not decompress to its declared size, or a record of a kind that does not belong
//! where it stands. The reader stops at the first such fault with a [`BagError::Ros1Damaged`] naming
//! the byte; the messages before it have been read.
//!
//! [`BagError::Ros1Damaged`]: super::BagError::Ros1Damaged

pub mod de;
mod file;

pub(super) use file::{Layout, Source, open};

pub use de::Ros1Error;

/// The first bytes of a ROS 1 bag of format 2.0.
pub const MAGIC: &[u8] = b"#ROSBAG V2.0\n";
/// The first bytes of any ROS bag (followed by its format version).
pub const MAGIC_PREFIX: &[u8] = b"#ROSBAG V";

/// The message types whose ROS 1 layout the reader knows: the rosbag2 name and the md5sum of the ROS 1
/// definition (as `rosmsg md5` prints it) that the [`dc_loc_core::msgs`] struct of that name reads.
pub const KNOWN_TYPES: &[(&str, &str)] = &[
    (
        "sensor_msgs/msg/PointCloud2",
        "1158d486dd51d683ce2f1be655c3c181",
    ),
    ("nav_msgs/msg/Odometry", "cd5e73d190d741a2f92e81eda573aca7"),
    ("sensor_msgs/msg/Imu", "6a62c6daae103f4ff57a132d6f95cec2"),
    ("tf2_msgs/msg/TFMessage", "94810edda583a504dfda3829e70d7eec"),
    (
        "geometry_msgs/msg/PoseStamped",
        "d3812c3cbc69362b77dc0b19b345f8f5",
    ),
    ("radar_msgs/msg/RadarScan", RADAR_SCAN_MD5),
    ("std_msgs/msg/Header", "2176decaecbce78abc3b96ef049fabed"),
];

/// md5sum of ros-perception's ROS 1 `radar_msgs/RadarScan` (Header, then `RadarReturn[]` of five
/// float32: range, azimuth, elevation, doppler_velocity, amplitude).
const RADAR_SCAN_MD5: &str = "6dfacef1e665538dbd8e159d5ce7a97a";

/// The md5sum of the ROS 1 definition the reader takes for `type_name` (rosbag2 spelling), if known.
pub fn known_md5sum(type_name: &str) -> Option<&'static str> {
    KNOWN_TYPES
        .iter()
        .find(|(t, _)| *t == type_name)
        .map(|(_, m)| *m)
}

/// A ROS 1 type name in rosbag2 spelling: `pkg/Type` becomes `pkg/msg/Type`; other names are kept.
pub fn ros2_type_name(ros1: &str) -> String {
    match ros1.split_once('/') {
        Some((pkg, ty)) if !pkg.is_empty() && !ty.is_empty() && !ty.contains('/') => {
            format!("{pkg}/msg/{ty}")
        }
        _ => ros1.to_string(),
    }
}

/// A ROS 1 type name as ROS 1 spells it (`pkg/msg/Type` becomes `pkg/Type`), for messages.
pub fn ros1_type_name(type_name: &str) -> String {
    type_name.replacen("/msg/", "/", 1)
}

/// Why a ROS 1 connection of `type_name` with `md5sum` cannot be read as that type: the type has no
/// known layout, or the connection's definition is another one.
pub fn definition_fault(type_name: &str, md5sum: &str) -> Option<String> {
    let ros1 = ros1_type_name(type_name);
    match known_md5sum(type_name) {
        None => Some(format!(
            "no ROS 1 layout of {ros1} is known (dc_loc reads {})",
            KNOWN_TYPES
                .iter()
                .map(|(t, _)| ros1_type_name(t))
                .collect::<Vec<_>>()
                .join(", ")
        )),
        Some(expected) if expected != md5sum => Some(format!(
            "the connection's definition of {ros1} has md5sum {md5sum:?}, not the standard \
             {expected} that dc_loc reads"
        )),
        Some(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn type_names_convert_both_ways() {
        assert_eq!(
            ros2_type_name("sensor_msgs/PointCloud2"),
            "sensor_msgs/msg/PointCloud2"
        );
        assert_eq!(ros2_type_name("*"), "*");
        assert_eq!(ros2_type_name("a/b/c"), "a/b/c");
        assert_eq!(
            ros1_type_name("sensor_msgs/msg/PointCloud2"),
            "sensor_msgs/PointCloud2"
        );
    }

    #[test]
    fn definitions_are_checked_by_md5sum() {
        assert_eq!(
            definition_fault("nav_msgs/msg/Odometry", "cd5e73d190d741a2f92e81eda573aca7"),
            None
        );
        let e = definition_fault("nav_msgs/msg/Odometry", "0123").unwrap();
        assert!(
            e.contains("nav_msgs/Odometry") && e.contains("cd5e73d1"),
            "{e}"
        );
        let e =
            definition_fault("std_msgs/msg/String", "992ce8a1687cec8c8bd883ec73ca41d1").unwrap();
        assert!(e.contains("no ROS 1 layout of std_msgs/String"), "{e}");
    }
}
