//! ROS 2 message types as plain serde structs (field order exactly as in each `.msg`), shared by the
//! node, the bag reader/writer and the simulator. No DDS here: CDR bytes come from serialising these.
//!
//! Entry points: one module per ROS package ([`builtin_interfaces`], [`std_msgs`], [`geometry_msgs`],
//! [`sensor_msgs`], [`nav_msgs`], [`tf2_msgs`], [`radar_msgs`], [`rosgraph_msgs`], [`dc_loc`]).

/// builtin_interfaces
pub mod builtin_interfaces {
    use crate::math::Stamp;
    use serde::{Deserialize, Serialize};

    /// builtin_interfaces/msg/Time
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct Time {
        /// Seconds.
        pub sec: i32,
        /// Nanoseconds, [0, 1e9).
        pub nanosec: u32,
    }

    impl From<Stamp> for Time {
        fn from(s: Stamp) -> Self {
            let (sec, nanosec) = s.to_sec_nanosec();
            Time { sec, nanosec }
        }
    }
    impl From<Time> for Stamp {
        fn from(t: Time) -> Self {
            Stamp::from_sec_nanosec(t.sec, t.nanosec)
        }
    }
}

/// std_msgs
pub mod std_msgs {
    use super::builtin_interfaces::Time;
    use serde::{Deserialize, Serialize};

    /// std_msgs/msg/Header
    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct Header {
        /// Acquisition time.
        pub stamp: Time,
        /// Frame of the data.
        pub frame_id: String,
    }
}

/// geometry_msgs
pub mod geometry_msgs {
    use super::std_msgs::Header;
    use crate::math::{Iso3, Quat, Vec3};
    use serde::{Deserialize, Serialize};

    /// geometry_msgs/msg/Point
    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct Point {
        /// m
        pub x: f64,
        /// m
        pub y: f64,
        /// m
        pub z: f64,
    }

    /// geometry_msgs/msg/Vector3
    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct Vector3 {
        /// x component
        pub x: f64,
        /// y component
        pub y: f64,
        /// z component
        pub z: f64,
    }

    /// geometry_msgs/msg/Quaternion
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct Quaternion {
        /// x
        pub x: f64,
        /// y
        pub y: f64,
        /// z
        pub z: f64,
        /// w
        pub w: f64,
    }

    impl Default for Quaternion {
        /// Identity (w = 1), as the ROS default.
        fn default() -> Self {
            Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            }
        }
    }

    /// geometry_msgs/msg/Pose
    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct Pose {
        /// Position, m.
        pub position: Point,
        /// Orientation.
        pub orientation: Quaternion,
    }

    /// geometry_msgs/msg/PoseStamped (the ground truth of some datasets).
    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct PoseStamped {
        /// Stamp and the frame of the pose.
        pub header: Header,
        /// The pose.
        pub pose: Pose,
    }

    /// geometry_msgs/msg/PoseWithCovariance
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct PoseWithCovariance {
        /// The pose.
        pub pose: Pose,
        /// Row-major 6x6 covariance in x, y, z, rot x, rot y, rot z.
        #[serde(with = "serde_big_array::BigArray")]
        pub covariance: [f64; 36],
    }

    impl Default for PoseWithCovariance {
        fn default() -> Self {
            PoseWithCovariance {
                pose: Pose::default(),
                covariance: [0.0; 36],
            }
        }
    }

    /// geometry_msgs/msg/Twist
    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct Twist {
        /// m/s
        pub linear: Vector3,
        /// rad/s
        pub angular: Vector3,
    }

    /// geometry_msgs/msg/TwistWithCovariance
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct TwistWithCovariance {
        /// The twist.
        pub twist: Twist,
        /// Row-major 6x6 covariance.
        #[serde(with = "serde_big_array::BigArray")]
        pub covariance: [f64; 36],
    }

    impl Default for TwistWithCovariance {
        fn default() -> Self {
            TwistWithCovariance {
                twist: Twist::default(),
                covariance: [0.0; 36],
            }
        }
    }

    /// geometry_msgs/msg/Transform
    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct Transform {
        /// m
        pub translation: Vector3,
        /// Rotation.
        pub rotation: Quaternion,
    }

    /// geometry_msgs/msg/TransformStamped
    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct TransformStamped {
        /// Stamp and parent frame.
        pub header: Header,
        /// Child frame.
        pub child_frame_id: String,
        /// Child frame in the parent frame.
        pub transform: Transform,
    }

    impl From<&Iso3> for Pose {
        fn from(t: &Iso3) -> Self {
            let q = t.rotation.quaternion();
            Pose {
                position: Point {
                    x: t.translation.x,
                    y: t.translation.y,
                    z: t.translation.z,
                },
                orientation: Quaternion {
                    x: q.i,
                    y: q.j,
                    z: q.k,
                    w: q.w,
                },
            }
        }
    }

    impl From<&Iso3> for Transform {
        fn from(t: &Iso3) -> Self {
            let p = Pose::from(t);
            Transform {
                translation: Vector3 {
                    x: p.position.x,
                    y: p.position.y,
                    z: p.position.z,
                },
                rotation: p.orientation,
            }
        }
    }

    impl Quaternion {
        /// As a unit quaternion; `None` when not finite or of zero norm.
        pub fn to_unit(&self) -> Option<Quat> {
            let q = nalgebra::Quaternion::new(self.w, self.x, self.y, self.z);
            let n = q.norm();
            if !(n.is_finite() && n > 1e-9) {
                return None;
            }
            Some(Quat::new_normalize(q))
        }
    }

    impl Pose {
        /// As an isometry; `None` when any value is not finite or the quaternion is zero.
        pub fn to_iso3(&self) -> Option<Iso3> {
            let p = Vec3::new(self.position.x, self.position.y, self.position.z);
            if !p.iter().all(|v| v.is_finite()) {
                return None;
            }
            Some(Iso3::from_parts(p.into(), self.orientation.to_unit()?))
        }
    }

    impl Transform {
        /// As an isometry; `None` when any value is not finite or the quaternion is zero.
        pub fn to_iso3(&self) -> Option<Iso3> {
            Pose {
                position: Point {
                    x: self.translation.x,
                    y: self.translation.y,
                    z: self.translation.z,
                },
                orientation: self.rotation,
            }
            .to_iso3()
        }
    }
}

/// sensor_msgs
pub mod sensor_msgs {
    use super::geometry_msgs::{Quaternion, Vector3};
    use super::std_msgs::Header;
    use serde::{Deserialize, Serialize};

    /// sensor_msgs/msg/PointField
    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct PointField {
        /// Field name.
        pub name: String,
        /// Byte offset within a point.
        pub offset: u32,
        /// One of the `PointField::*` datatype constants.
        pub datatype: u8,
        /// Number of elements.
        pub count: u32,
    }

    impl PointField {
        /// int8
        pub const INT8: u8 = 1;
        /// uint8
        pub const UINT8: u8 = 2;
        /// int16
        pub const INT16: u8 = 3;
        /// uint16
        pub const UINT16: u8 = 4;
        /// int32
        pub const INT32: u8 = 5;
        /// uint32
        pub const UINT32: u8 = 6;
        /// float32
        pub const FLOAT32: u8 = 7;
        /// float64
        pub const FLOAT64: u8 = 8;
    }

    /// sensor_msgs/msg/PointCloud2
    #[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct PointCloud2 {
        /// Stamp and sensor frame.
        pub header: Header,
        /// Rows.
        pub height: u32,
        /// Points per row.
        pub width: u32,
        /// Field layout.
        pub fields: Vec<PointField>,
        /// Byte order of `data`.
        pub is_bigendian: bool,
        /// Bytes per point.
        pub point_step: u32,
        /// Bytes per row.
        pub row_step: u32,
        /// The points.
        #[serde(with = "serde_bytes")]
        pub data: Vec<u8>,
        /// True when no point is invalid.
        pub is_dense: bool,
    }

    /// sensor_msgs/msg/Imu (a gyro: the pipeline takes its `angular_velocity`, see `input::imu_input`).
    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct Imu {
        /// Stamp and sensor frame.
        pub header: Header,
        /// Orientation.
        pub orientation: Quaternion,
        /// Row-major 3x3 covariance of the orientation (x, y, z axes); -1 in the first element: none.
        pub orientation_covariance: [f64; 9],
        /// rad/s
        pub angular_velocity: Vector3,
        /// Row-major 3x3 covariance.
        pub angular_velocity_covariance: [f64; 9],
        /// m/s^2
        pub linear_acceleration: Vector3,
        /// Row-major 3x3 covariance.
        pub linear_acceleration_covariance: [f64; 9],
    }
}

/// nav_msgs
pub mod nav_msgs {
    use super::geometry_msgs::{PoseWithCovariance, TwistWithCovariance};
    use super::std_msgs::Header;
    use serde::{Deserialize, Serialize};

    /// nav_msgs/msg/Odometry
    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct Odometry {
        /// Stamp and the frame of the pose (e.g. `odom`).
        pub header: Header,
        /// Frame of the twist (the body frame).
        pub child_frame_id: String,
        /// Body pose in `header.frame_id`.
        pub pose: PoseWithCovariance,
        /// Body velocity in `child_frame_id`.
        pub twist: TwistWithCovariance,
    }
}

/// tf2_msgs
pub mod tf2_msgs {
    use super::geometry_msgs::TransformStamped;
    use serde::{Deserialize, Serialize};

    /// tf2_msgs/msg/TFMessage
    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct TFMessage {
        /// The transforms.
        pub transforms: Vec<TransformStamped>,
    }
}

/// radar_msgs (ros-perception/radar_msgs)
pub mod radar_msgs {
    use super::std_msgs::Header;
    use serde::{Deserialize, Serialize};

    /// radar_msgs/msg/RadarReturn: one detection, in the radar frame (REP-103 angles).
    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    pub struct RadarReturn {
        /// Distance, m.
        pub range: f32,
        /// Angle in the azimuth plane, rad, anticlockwise from the boresight.
        pub azimuth: f32,
        /// Angle in the elevation plane, rad, negative below the sensor.
        pub elevation: f32,
        /// Doppler speed, m/s.
        pub doppler_velocity: f32,
        /// Amplitude, dB.
        pub amplitude: f32,
    }

    /// radar_msgs/msg/RadarScan
    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct RadarScan {
        /// Stamp and radar frame.
        pub header: Header,
        /// The detections.
        pub returns: Vec<RadarReturn>,
    }
}

/// rosgraph_msgs
pub mod rosgraph_msgs {
    use super::builtin_interfaces::Time;
    use serde::{Deserialize, Serialize};

    /// rosgraph_msgs/msg/Clock
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
    pub struct Clock {
        /// Simulated time.
        pub clock: Time,
    }
}

/// This package's own messages (`msg/`).
pub mod dc_loc {
    use super::builtin_interfaces::Time;
    use super::geometry_msgs::{Pose, PoseWithCovariance};
    use super::std_msgs::Header;
    use serde::{Deserialize, Serialize};

    /// dc_loc/msg/LoopClosure (`msg/LoopClosure.msg`).
    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct LoopClosure {
        /// stamp: query keyframe time; frame_id: body frame.
        pub header: Header,
        /// Newer keyframe.
        pub query_id: u64,
        /// Older, revisited keyframe (its id in `match_robot`'s map).
        pub match_id: u64,
        /// `node.robot_id` of the node that published the closure.
        pub query_robot: i32,
        /// Robot of the match keyframe.
        pub match_robot: i32,
        /// Query keyframe time.
        pub query_stamp: Time,
        /// Match keyframe time.
        pub match_stamp: Time,
        /// Odometry pose of the query keyframe.
        pub query_odom_pose: Pose,
        /// Odometry pose of the match keyframe.
        pub match_odom_pose: Pose,
        /// Query body frame in the match body frame; covariance row-major x y z rotx roty rotz.
        pub relative_pose: PoseWithCovariance,
        /// RANSAC inliers behind the estimate.
        pub inliers: u32,
        /// Match quality (higher is better).
        pub score: f64,
    }

    /// dc_loc/msg/Keyframe (`msg/Keyframe.msg`): a keyframe as a robot's node shares it with the fleet.
    #[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
    pub struct Keyframe {
        /// stamp: keyframe time; frame_id: the robot's body frame.
        pub header: Header,
        /// `node.robot_id` of the robot that made it.
        pub robot_id: i32,
        /// That robot's session.
        pub session: u32,
        /// Its id in that robot's map.
        pub id: u64,
        /// Body pose at the stamp in that robot's odometry frame.
        pub odom_pose: Pose,
        /// Odometry path length of its session up to it, m.
        pub path_distance: f64,
        /// Robots of `heard_ids`.
        pub heard_robots: Vec<i32>,
        /// The newest keyframe id of each of `heard_robots` the node held when it made this one.
        pub heard_ids: Vec<u64>,
        /// Robots of the node's accepted alignments to other robots' sessions.
        pub aligned_robots: Vec<i32>,
        /// Their sessions.
        pub aligned_sessions: Vec<u32>,
        /// Per alignment x, y (m), yaw (rad): the node's odometry frame in that session's frame.
        pub aligned_poses: Vec<f64>,
        /// Per alignment the path lengths of the closure's two keyframes, this robot's then the
        /// other's, m.
        pub aligned_paths: Vec<f64>,
        /// Planar points, x0 y0 x1 y1 ..., cm.
        pub points: Vec<i16>,
        /// Three covariance codes per point.
        pub covariances: Vec<u8>,
        /// One ray direction code per point, or none.
        pub rays: Vec<u8>,
    }
}
