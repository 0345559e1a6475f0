//! ROS 2 message definitions (`.msg` texts) and the `ros2msg` schema text rosbag2 stores per type.
//!
//! Entry points: [`ros2msg_schema`] (a type's full schema text, as `ros2 bag record` writes it),
//! [`type_hash`] (RIHS01 hash), [`is_known_type`], [`KNOWN_TYPES`], type names ([`POINT_CLOUD2`], ...).
//!
//! The `.msg` texts are the installed files verbatim, comments and all, as rosbag2 copies them: those of
//! the ROS 2 Jazzy PyPI wheels `ros-{builtin-interfaces,rosgraph-msgs}==2.0.3` and
//! `ros-{std,sensor,nav,geometry}-msgs==5.3.6`, geometry2's one-line `tf2_msgs/TFMessage` and this
//! package's `msg/LoopClosure.msg`. The RIHS01 hashes are rosbags 0.11.9's (`Typestore.hash_rihs01`,
//! ROS2_JAZZY store), checked by tests/bag.rs against tests/fixtures/cdr_fixtures.json. A schema is laid
//! out as rosbag2_cpp's `LocalMessageDefinitionSource::get_full_text` does: the root text, then each
//! dependency not yet written (depth first, a file's in sorted order) after `"\n"`, a line of 80 `=` and
//! `MSG: pkg/Type` (as the field spells it, package-relative names qualified with the file's package).

use std::collections::{BTreeSet, HashSet};

/// `sensor_msgs/msg/PointCloud2`.
pub const POINT_CLOUD2: &str = "sensor_msgs/msg/PointCloud2";
/// `nav_msgs/msg/Odometry`.
pub const ODOMETRY: &str = "nav_msgs/msg/Odometry";
/// `tf2_msgs/msg/TFMessage` (`/tf`, `/tf_static`).
pub const TF_MESSAGE: &str = "tf2_msgs/msg/TFMessage";
/// `rosgraph_msgs/msg/Clock` (`/clock`).
pub const CLOCK: &str = "rosgraph_msgs/msg/Clock";
/// `dc_loc/msg/LoopClosure`.
pub const LOOP_CLOSURE: &str = "dc_loc/msg/LoopClosure";
/// `geometry_msgs/msg/PoseStamped` (read as ground truth; the writer has no schema for it).
pub const POSE_STAMPED: &str = "geometry_msgs/msg/PoseStamped";
/// `sensor_msgs/msg/Imu` (a gyro, read with `odometry.source: radar_imu`).
pub const IMU: &str = "sensor_msgs/msg/Imu";
/// `std_msgs/msg/Header` (a radar's trigger, `radars.<name>.trigger_topic`).
pub const HEADER: &str = "std_msgs/msg/Header";
/// `radar_msgs/msg/RadarScan` (read only; the writer has no schema for it).
pub const RADAR_SCAN: &str = "radar_msgs/msg/RadarScan";

/// One `.msg` file.
struct MsgFile {
    /// Full type name, `pkg/msg/Type`.
    name: &'static str,
    /// RIHS01 type description hash.
    type_hash: &'static str,
    /// The file, verbatim.
    text: &'static str,
}

/// Every `.msg` file known here (top-level types and their dependencies).
const MSG_FILES: &[MsgFile] = &[
    MsgFile {
        name: "builtin_interfaces/msg/Time",
        type_hash: "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
        text: r#"# This message communicates ROS Time defined here:
# https://design.ros2.org/articles/clock_and_time.html

# The seconds component, valid over all int32 values.
int32 sec

# The nanoseconds component, valid in the range [0, 1e9), to be added to the seconds component. 
# e.g.
# The time -1.7 seconds is represented as {sec: -2, nanosec: 3e8}
# The time 1.7 seconds is represented as {sec: 1, nanosec: 7e8}
uint32 nanosec
"#,
    },
    MsgFile {
        name: "std_msgs/msg/Header",
        type_hash: "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
        text: r#"# Standard metadata for higher-level stamped data types.
# This is generally used to communicate timestamped data
# in a particular coordinate frame.

# Two-integer timestamp that is expressed as seconds and nanoseconds.
builtin_interfaces/Time stamp

# Transform frame with which this data is associated.
string frame_id
"#,
    },
    MsgFile {
        name: "sensor_msgs/msg/PointField",
        type_hash: "RIHS01_5c6a4750728c2bcfbbf7037225b20b02d4429634732146b742dee1726637ef01",
        text: r#"# This message holds the description of one point entry in the
# PointCloud2 message format.
uint8 INT8    = 1
uint8 UINT8   = 2
uint8 INT16   = 3
uint8 UINT16  = 4
uint8 INT32   = 5
uint8 UINT32  = 6
uint8 FLOAT32 = 7
uint8 FLOAT64 = 8

# Common PointField names are x, y, z, intensity, rgb, rgba
string name      # Name of field
uint32 offset    # Offset from start of point struct
uint8  datatype  # Datatype enumeration, see above
uint32 count     # How many elements in the field
"#,
    },
    MsgFile {
        name: "sensor_msgs/msg/PointCloud2",
        type_hash: "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
        text: r#"# This message holds a collection of N-dimensional points, which may
# contain additional information such as normals, intensity, etc. The
# point data is stored as a binary blob, its layout described by the
# contents of the "fields" array.
#
# The point cloud data may be organized 2d (image-like) or 1d (unordered).
# Point clouds organized as 2d images may be produced by camera depth sensors
# such as stereo or time-of-flight.

# Time of sensor data acquisition, and the coordinate frame ID (for 3d points).
std_msgs/Header header

# 2D structure of the point cloud. If the cloud is unordered, height is
# 1 and width is the length of the point cloud.
uint32 height
uint32 width

# Describes the channels and their layout in the binary data blob.
PointField[] fields

bool    is_bigendian # Is this data bigendian?
uint32  point_step   # Length of a point in bytes
uint32  row_step     # Length of a row in bytes
uint8[] data         # Actual point data, size is (row_step*height)

bool is_dense        # True if there are no invalid points
"#,
    },
    MsgFile {
        name: "geometry_msgs/msg/Point",
        type_hash: "RIHS01_6963084842a9b04494d6b2941d11444708d892da2f4b09843b9c43f42a7f6881",
        text: r#"# This contains the position of a point in free space
float64 x
float64 y
float64 z
"#,
    },
    MsgFile {
        name: "geometry_msgs/msg/Quaternion",
        type_hash: "RIHS01_8a765f66778c8ff7c8ab94afcc590a2ed5325a1d9a076ffff38fbce36f458684",
        text: r#"# This represents an orientation in free space in quaternion form.

float64 x 0
float64 y 0
float64 z 0
float64 w 1
"#,
    },
    MsgFile {
        name: "geometry_msgs/msg/Pose",
        type_hash: "RIHS01_d501954e9476cea2996984e812054b68026ae0bfae789d9a10b23daf35cc90fa",
        text: r#"# A representation of pose in free space, composed of position and orientation.

Point position
Quaternion orientation
"#,
    },
    MsgFile {
        name: "geometry_msgs/msg/PoseWithCovariance",
        type_hash: "RIHS01_9a7c0fd234b7f45c6098745ecccd773ca1085670e64107135397aee31c02e1bb",
        text: r#"# This represents a pose in free space with uncertainty.

Pose pose

# Row-major representation of the 6x6 covariance matrix
# The orientation parameters use a fixed-axis representation.
# In order, the parameters are:
# (x, y, z, rotation about X axis, rotation about Y axis, rotation about Z axis)
float64[36] covariance
"#,
    },
    MsgFile {
        name: "geometry_msgs/msg/Vector3",
        type_hash: "RIHS01_cc12fe83e4c02719f1ce8070bfd14aecd40f75a96696a67a2a1f37f7dbb0765d",
        text: r#"# This represents a vector in free space.

# This is semantically different than a point.
# A vector is always anchored at the origin.
# When a transform is applied to a vector, only the rotational component is applied.

float64 x
float64 y
float64 z
"#,
    },
    MsgFile {
        name: "geometry_msgs/msg/Twist",
        type_hash: "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
        text: r#"# This expresses velocity in free space broken into its linear and angular parts.

Vector3  linear
Vector3  angular
"#,
    },
    MsgFile {
        name: "geometry_msgs/msg/TwistWithCovariance",
        type_hash: "RIHS01_49f574f033f095d8b6cd1beaca5ca7925e296e84af1716d16c89d38b059c8c18",
        text: r#"# This expresses velocity in free space with uncertainty.

Twist twist

# Row-major representation of the 6x6 covariance matrix
# The orientation parameters use a fixed-axis representation.
# In order, the parameters are:
# (x, y, z, rotation about X axis, rotation about Y axis, rotation about Z axis)
float64[36] covariance
"#,
    },
    MsgFile {
        name: "geometry_msgs/msg/Transform",
        type_hash: "RIHS01_beb83fbe698636351461f6f35d1abb20010c43d55374d81bd041f1ba2581fddc",
        text: r#"# This represents the transform between two coordinate frames in free space.

Vector3 translation
Quaternion rotation
"#,
    },
    MsgFile {
        name: "geometry_msgs/msg/TransformStamped",
        type_hash: "RIHS01_0a241f87d04668d94099cbb5ba11691d5ad32c2f29682e4eb5653424bd275206",
        text: r#"# This expresses a transform from coordinate frame header.frame_id
# to the coordinate frame child_frame_id at the time of header.stamp
#
# This message is mostly used by the
# <a href="https://docs.ros.org/en/rolling/p/tf2/">tf2</a> package.
# See its documentation for more information.
#
# The child_frame_id is necessary in addition to the frame_id
# in the Header to communicate the full reference for the transform
# in a self contained message.

# The frame id in the header is used as the reference frame of this transform.
std_msgs/Header header

# The frame id of the child frame to which this transform points.
string child_frame_id

# Translation and rotation in 3-dimensions of child_frame_id from header.frame_id.
Transform transform
"#,
    },
    MsgFile {
        name: "nav_msgs/msg/Odometry",
        type_hash: "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
        text: r#"# This represents an estimate of a position and velocity in free space.
# The pose in this message should be specified in the coordinate frame given by header.frame_id
# The twist in this message should be specified in the coordinate frame given by the child_frame_id

# Includes the frame id of the pose parent.
std_msgs/Header header

# Frame id the pose points to. The twist is in this coordinate frame.
string child_frame_id

# Estimated pose that is typically relative to a fixed world frame.
geometry_msgs/PoseWithCovariance pose

# Estimated linear and angular velocity relative to child_frame_id.
geometry_msgs/TwistWithCovariance twist
"#,
    },
    MsgFile {
        name: "sensor_msgs/msg/Imu",
        type_hash: "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
        text: r#"# This is a message to hold data from an IMU (Inertial Measurement Unit)
#
# Accelerations should be in m/s^2 (not in g's), and rotational velocity should be in rad/sec
#
# If the covariance of the measurement is known, it should be filled in (if all you know is the
# variance of each measurement, e.g. from the datasheet, just put those along the diagonal)
# A covariance matrix of all zeros will be interpreted as "covariance unknown", and to use the
# data a covariance will have to be assumed or gotten from some other source
#
# If you have no estimate for one of the data elements (e.g. your IMU doesn't produce an
# orientation estimate), please set element 0 of the associated covariance matrix to -1
# If you are interpreting this message, please check for a value of -1 in the first element of each
# covariance matrix, and disregard the associated estimate.

std_msgs/Header header

geometry_msgs/Quaternion orientation
float64[9] orientation_covariance # Row major about x, y, z axes

geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance # Row major about x, y, z axes

geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance # Row major x, y z
"#,
    },
    MsgFile {
        name: "rosgraph_msgs/msg/Clock",
        type_hash: "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
        text: r#"# This message communicates the current time.
#
# For more information, see https://design.ros2.org/articles/clock_and_time.html.
builtin_interfaces/Time clock
"#,
    },
    MsgFile {
        name: "tf2_msgs/msg/TFMessage",
        type_hash: "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
        text: r#"geometry_msgs/TransformStamped[] transforms
"#,
    },
    MsgFile {
        name: "dc_loc/msg/LoopClosure",
        type_hash: "RIHS01_31a7a72571844f2ce6355761c7f4cb198643ffc5b41e54dddd83cd807d4a4e0e",
        text: include_str!("../../../../msg/LoopClosure.msg"),
    },
];

/// Top-level message types the bag writer knows (they have a schema text and a hash).
pub const KNOWN_TYPES: &[&str] = &[
    POINT_CLOUD2,
    ODOMETRY,
    IMU,
    TF_MESSAGE,
    CLOCK,
    LOOP_CLOSURE,
    HEADER,
];

/// The ROS primitive type names of `.msg` fields (rosbag2's list).
const PRIMITIVES: &[&str] = &[
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
    "uint32", "int64", "uint64", "string",
];

fn msg_file(full_name: &str) -> Option<&'static MsgFile> {
    MSG_FILES.iter().find(|f| f.name == full_name)
}

/// `pkg/Type` (as `.msg` fields and `MSG:` lines spell it) to `pkg/msg/Type`.
fn full_name(short: &str) -> Option<String> {
    let (pkg, ty) = short.split_once('/')?;
    Some(format!("{pkg}/msg/{ty}"))
}

/// Message types a `.msg` text names in its fields, as rosbag2 finds them: the first word of each
/// field line without its array suffix, primitives skipped, names without a package qualified with
/// `package`. Sorted, as rosbag2 keeps them in a `std::set`.
fn dependencies(text: &str, package: &str) -> BTreeSet<String> {
    text.lines()
        .map(str::trim_start)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .filter_map(|l| l.split_whitespace().next())
        .map(|t| t.split('[').next().unwrap_or(t))
        .filter(|t| !PRIMITIVES.contains(t) && !t.starts_with("string<"))
        .map(|t| {
            if t.contains('/') {
                t.to_string()
            } else {
                format!("{package}/{t}")
            }
        })
        .collect()
}

/// The `ros2msg` schema text rosbag2 stores for `type_name` (`pkg/msg/Type`), or `None` when the type
/// (or one of its dependencies) is not known here.
pub fn ros2msg_schema(type_name: &str) -> Option<String> {
    fn append(
        full: &str,
        seen: &mut HashSet<String>,
        out: &mut String,
        depth: usize,
    ) -> Option<()> {
        // Message definitions nest a few levels; the bound only guards against a cycle.
        if depth > 32 {
            return None;
        }
        let file = msg_file(full)?;
        out.push_str(file.text);
        let package = full.split('/').next()?;
        for dep in dependencies(file.text, package) {
            if seen.insert(dep.clone()) {
                out.push('\n');
                out.push_str(&"=".repeat(80));
                out.push_str("\nMSG: ");
                out.push_str(&dep);
                out.push('\n');
                append(&full_name(&dep)?, seen, out, depth + 1)?;
            }
        }
        Some(())
    }
    let mut out = String::new();
    append(type_name, &mut HashSet::new(), &mut out, 0)?;
    Some(out)
}

/// The RIHS01 type description hash of `type_name` (`pkg/msg/Type`), as rosbag2 stores it in
/// `type_description_hash`, or `None` when the type is not known here.
pub fn type_hash(type_name: &str) -> Option<&'static str> {
    msg_file(type_name).map(|f| f.type_hash)
}

/// True when the writer has a schema for `type_name` (`pkg/msg/Type`).
pub fn is_known_type(type_name: &str) -> bool {
    ros2msg_schema(type_name).is_some()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dependencies_follow_rosbag2_rules() {
        let deps = dependencies(
            "# c\nstd_msgs/Header header\nPointField[] fields\nuint8[] data\nfloat64[36] c\n",
            "sensor_msgs",
        );
        let want: BTreeSet<String> = ["sensor_msgs/PointField", "std_msgs/Header"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        assert_eq!(deps, want);
    }

    #[test]
    fn every_dependency_of_every_known_type_is_present() {
        for t in KNOWN_TYPES {
            assert!(ros2msg_schema(t).is_some(), "{t}");
            assert!(type_hash(t).is_some_and(|h| h.starts_with("RIHS01_") && h.len() == 71));
        }
        assert!(ros2msg_schema("std_msgs/msg/String").is_none());
    }
}
