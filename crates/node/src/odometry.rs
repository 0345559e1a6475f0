//! The radar odometry (`odometry.source: radar | radar_imu`) as ROS messages: each
//! [`OdometryEstimate`] as the `nav_msgs/Odometry` of `~/odometry` ([`odometry_msg`]) and, with
//! `node.odometry_tf`, as the `odom -> body` transform of `/tf` ([`odometry_tf`]).
//!
//! The estimate is planar: its covariances are 3x3 over `(x, y, yaw)` (pose, odometry frame) and
//! `(v_x, v_y, yaw rate)` (twist, body frame). ROS orders a 6x6 covariance `(x, y, z, roll, pitch,
//! yaw)`, row-major ([`ros_covariance`]): the planar block goes to rows and columns 0, 1 and 5, and
//! the axes the radars do not observe (z, roll, pitch) get [`UNOBSERVED_VARIANCE`] on the diagonal,
//! so that a fusion filter (robot_localization) takes nothing from them.

use dc_loc_core::math::Mat3;
use dc_loc_core::msgs::geometry_msgs::{
    Pose, PoseWithCovariance, Transform, TransformStamped, Twist, TwistWithCovariance, Vector3,
};
use dc_loc_core::msgs::nav_msgs::Odometry;
use dc_loc_core::msgs::std_msgs::Header;
use dc_loc_core::msgs::tf2_msgs::TFMessage;
use dc_loc_core::odometry::OdometryEstimate;

/// Variance of the axes a planar odometry does not observe (z, roll, pitch and their rates): 1e6
/// (m^2, rad^2 and their rates'), the customary "unknown" of planar odometry publishers.
pub const UNOBSERVED_VARIANCE: f64 = 1e6;

/// Rows (and columns) of `x`, `y` and `yaw` in a ROS 6x6 covariance.
const PLANAR_AXES: [usize; 3] = [0, 1, 5];

/// A 3x3 `(x, y, yaw)` covariance as the row-major 6x6 `(x, y, z, roll, pitch, yaw)` of ROS messages,
/// z, roll and pitch unobserved ([`UNOBSERVED_VARIANCE`], uncorrelated).
pub fn ros_covariance(c: &Mat3) -> [f64; 36] {
    let mut out = [0.0; 36];
    for axis in [2, 3, 4] {
        out[axis * 6 + axis] = UNOBSERVED_VARIANCE;
    }
    for (i, &r) in PLANAR_AXES.iter().enumerate() {
        for (j, &k) in PLANAR_AXES.iter().enumerate() {
            out[r * 6 + k] = c[(i, j)];
        }
    }
    out
}

/// The estimate as `nav_msgs/Odometry`: pose of `body_frame` in `odom_frame`, twist in `body_frame`.
pub fn odometry_msg(e: &OdometryEstimate, odom_frame: &str, body_frame: &str) -> Odometry {
    Odometry {
        header: Header {
            stamp: e.stamp.into(),
            frame_id: odom_frame.to_string(),
        },
        child_frame_id: body_frame.to_string(),
        pose: PoseWithCovariance {
            pose: Pose::from(&e.t_odom_body),
            covariance: ros_covariance(&e.covariance()),
        },
        twist: TwistWithCovariance {
            twist: Twist {
                linear: Vector3 {
                    x: e.twist.x,
                    y: e.twist.y,
                    z: 0.0,
                },
                angular: Vector3 {
                    x: 0.0,
                    y: 0.0,
                    z: e.twist.z,
                },
            },
            covariance: ros_covariance(&e.twist_covariance),
        },
    }
}

/// The estimate as the `/tf` transform `odom_frame -> body_frame`.
pub fn odometry_tf(e: &OdometryEstimate, odom_frame: &str, body_frame: &str) -> TFMessage {
    TFMessage {
        transforms: vec![TransformStamped {
            header: Header {
                stamp: e.stamp.into(),
                frame_id: odom_frame.to_string(),
            },
            child_frame_id: body_frame.to_string(),
            transform: Transform::from(&e.t_odom_body),
        }],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dc_loc_core::math::{Iso3, Stamp, Vec3, iso3_from_xyz_rpy};

    fn estimate() -> OdometryEstimate {
        OdometryEstimate {
            stamp: Stamp(12_500_000_000),
            t_odom_body: iso3_from_xyz_rpy(3.0, -2.0, 0.0, 0.0, 0.0, 0.5),
            // Distinct entries, so that a misplaced one shows.
            noise: dc_loc_core::pose_noise::PoseNoise {
                white: Mat3::new(1.0, 0.2, 0.3, 0.2, 2.0, 0.4, 0.3, 0.4, 3.0),
                sensitivity: Vec3::zeros(),
                bias_variance: 0.0,
            },
            twist: Vec3::new(10.0, -0.5, 0.1),
            twist_covariance: Mat3::new(4.0, 0.5, 0.6, 0.5, 5.0, 0.7, 0.6, 0.7, 6.0),
            coasting: false,
        }
    }

    /// Every element of the 6x6, written out by hand: (x, y, yaw) at rows and columns 0, 1, 5.
    #[test]
    fn planar_covariance_lands_on_x_y_and_yaw() {
        let u = UNOBSERVED_VARIANCE;
        #[rustfmt::skip]
        let want = [
            1.0, 0.2, 0.0, 0.0, 0.0, 0.3,
            0.2, 2.0, 0.0, 0.0, 0.0, 0.4,
            0.0, 0.0, u,   0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, u,   0.0, 0.0,
            0.0, 0.0, 0.0, 0.0, u,   0.0,
            0.3, 0.4, 0.0, 0.0, 0.0, 3.0,
        ];
        assert_eq!(ros_covariance(&estimate().covariance()), want);
        let m = odometry_msg(&estimate(), "odom", "base_link");
        assert_eq!(m.pose.covariance, want);
        // The twist's: v_x, v_y, yaw rate.
        let c = m.twist.covariance;
        assert_eq!(
            (c[0], c[1], c[5], c[6], c[7], c[11]),
            (4.0, 0.5, 0.6, 0.5, 5.0, 0.7)
        );
        assert_eq!((c[30], c[31], c[35]), (0.6, 0.7, 6.0));
        assert_eq!((c[14], c[21], c[28]), (u, u, u));
    }

    #[test]
    fn pose_twist_frames_and_stamp() {
        let m = odometry_msg(&estimate(), "odom", "base_link");
        assert_eq!(m.header.frame_id, "odom");
        assert_eq!(m.child_frame_id, "base_link");
        assert_eq!(
            (m.header.stamp.sec, m.header.stamp.nanosec),
            (12, 500_000_000)
        );
        let p = &m.pose.pose;
        assert_eq!((p.position.x, p.position.y, p.position.z), (3.0, -2.0, 0.0));
        let yaw = 2.0 * p.orientation.z.atan2(p.orientation.w);
        assert!((yaw - 0.5).abs() < 1e-12);
        let t = &m.twist.twist;
        assert_eq!((t.linear.x, t.linear.y, t.angular.z), (10.0, -0.5, 0.1));
        let tf = odometry_tf(&estimate(), "odom", "base_link");
        let back: Iso3 = tf.transforms[0].transform.to_iso3().unwrap();
        assert!((back.translation.vector - Vec3::new(3.0, -2.0, 0.0)).norm() < 1e-12);
        assert_eq!(tf.transforms[0].header.frame_id, "odom");
        assert_eq!(tf.transforms[0].child_frame_id, "base_link");
    }
}
