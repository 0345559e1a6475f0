//! What leaves the pipeline for its users: a [`LoopClosure`] as the `dc_loc/msg/LoopClosure` message
//! ([`loop_closure_msg`]) and as the JSON-lines record of `dc_loc run --out` ([`ClosureRecord`], with
//! [`ClosureRecord::from_json_line`] to read it back).

use serde::{Deserialize, Serialize};

use crate::loop_closure::LoopClosure;
use crate::math::{Iso3, Stamp};
use crate::msgs::builtin_interfaces::Time;
use crate::msgs::geometry_msgs::{Pose, PoseWithCovariance};
use crate::msgs::std_msgs::Header;
use crate::msgs::{self};

/// A loop closure as `dc_loc/msg/LoopClosure`, stamped with the query keyframe time in `frame_id` (the
/// body frame).
pub fn loop_closure_msg(c: &LoopClosure, frame_id: &str) -> msgs::dc_loc::LoopClosure {
    let mut covariance = [0.0; 36];
    for (i, v) in covariance.iter_mut().enumerate() {
        *v = c.covariance[(i / 6, i % 6)];
    }
    msgs::dc_loc::LoopClosure {
        header: Header {
            stamp: c.query_stamp.into(),
            frame_id: frame_id.to_string(),
        },
        query_id: c.query_id,
        match_id: c.match_key().1,
        query_robot: c.query_robot,
        match_robot: c.match_key().0,
        query_stamp: c.query_stamp.into(),
        match_stamp: c.match_stamp.into(),
        query_odom_pose: Pose::from(&c.query_odom_pose),
        match_odom_pose: Pose::from(&c.match_odom_pose),
        relative_pose: PoseWithCovariance {
            pose: Pose::from(&c.t_match_query),
            covariance,
        },
        inliers: c.inliers,
        score: c.score,
    }
}

/// A pose in a [`ClosureRecord`]: position (m) and unit quaternion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseRecord {
    /// Position x, m.
    pub x: f64,
    /// Position y, m.
    pub y: f64,
    /// Position z, m.
    pub z: f64,
    /// Quaternion x.
    pub qx: f64,
    /// Quaternion y.
    pub qy: f64,
    /// Quaternion z.
    pub qz: f64,
    /// Quaternion w.
    pub qw: f64,
}

impl From<&Iso3> for PoseRecord {
    fn from(t: &Iso3) -> Self {
        let q = t.rotation.quaternion();
        PoseRecord {
            x: t.translation.x,
            y: t.translation.y,
            z: t.translation.z,
            qx: q.i,
            qy: q.j,
            qz: q.k,
            qw: q.w,
        }
    }
}

impl PoseRecord {
    /// As an isometry (the quaternion normalised); `None` when not finite or of zero norm.
    pub fn to_iso3(&self) -> Option<Iso3> {
        Pose {
            position: msgs::geometry_msgs::Point {
                x: self.x,
                y: self.y,
                z: self.z,
            },
            orientation: msgs::geometry_msgs::Quaternion {
                x: self.qx,
                y: self.qy,
                z: self.qz,
                w: self.qw,
            },
        }
        .to_iso3()
    }
}

/// One loop closure as a JSON-lines record: the fields of `dc_loc/msg/LoopClosure`, times in seconds
/// (f64: about 0.2 us resolution at today's epoch times), poses as x, y, z, qx, qy, qz, qw.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClosureRecord {
    /// Header stamp (the query keyframe time), s.
    pub stamp: f64,
    /// Header frame id (the body frame).
    pub frame_id: String,
    /// Newer keyframe.
    pub query_id: u64,
    /// Older, revisited keyframe (its id in `match_robot`'s map).
    pub match_id: u64,
    /// `node.robot_id` of the robot that found the closure (0 when not set).
    #[serde(default)]
    pub query_robot: i32,
    /// Robot of the match keyframe.
    #[serde(default)]
    pub match_robot: i32,
    /// Query keyframe time, s.
    pub query_stamp: f64,
    /// Match keyframe time, s.
    pub match_stamp: f64,
    /// Odometry pose of the query keyframe.
    pub query_odom_pose: PoseRecord,
    /// Odometry pose of the match keyframe.
    pub match_odom_pose: PoseRecord,
    /// Query body frame in the match body frame.
    pub relative_pose: PoseRecord,
    /// Covariance of `relative_pose`, 36 values row-major, x y z rot x rot y rot z (m, rad).
    pub covariance: Vec<f64>,
    /// Registration inliers.
    pub inliers: u32,
    /// Quality score (0..1).
    pub score: f64,
}

fn secs(t: Time) -> f64 {
    Stamp::from(t).as_secs_f64()
}

impl From<&msgs::dc_loc::LoopClosure> for ClosureRecord {
    fn from(m: &msgs::dc_loc::LoopClosure) -> Self {
        let pose = |p: &Pose| PoseRecord {
            x: p.position.x,
            y: p.position.y,
            z: p.position.z,
            qx: p.orientation.x,
            qy: p.orientation.y,
            qz: p.orientation.z,
            qw: p.orientation.w,
        };
        ClosureRecord {
            stamp: secs(m.header.stamp),
            frame_id: m.header.frame_id.clone(),
            query_id: m.query_id,
            match_id: m.match_id,
            query_robot: m.query_robot,
            match_robot: m.match_robot,
            query_stamp: secs(m.query_stamp),
            match_stamp: secs(m.match_stamp),
            query_odom_pose: pose(&m.query_odom_pose),
            match_odom_pose: pose(&m.match_odom_pose),
            relative_pose: pose(&m.relative_pose.pose),
            covariance: m.relative_pose.covariance.to_vec(),
            inliers: m.inliers,
            score: m.score,
        }
    }
}

impl From<&LoopClosure> for ClosureRecord {
    /// The record with an empty `frame_id` (a [`LoopClosure`] does not know the body frame); see
    /// [`ClosureRecord::new`].
    fn from(c: &LoopClosure) -> Self {
        ClosureRecord::from(&loop_closure_msg(c, ""))
    }
}

impl ClosureRecord {
    /// The record of closure `c` in the body frame `frame_id`.
    pub fn new(c: &LoopClosure, frame_id: &str) -> Self {
        ClosureRecord::from(&loop_closure_msg(c, frame_id))
    }

    /// One JSON line (no trailing newline).
    pub fn to_json_line(&self) -> String {
        // Plain numbers, strings and a list: serialisation cannot fail (NaN is written as null).
        serde_json::to_string(self).unwrap_or_default()
    }

    /// Parses one JSON line; unknown or missing fields are errors.
    pub fn from_json_line(line: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(line)
    }

    /// The covariance as a matrix; `None` unless there are exactly 36 values.
    pub fn covariance_matrix(&self) -> Option<crate::math::Mat6> {
        (self.covariance.len() == 36).then(|| crate::math::Mat6::from_row_slice(&self.covariance))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Mat6, iso3_from_xyz_rpy};
    use std::f64::consts::FRAC_PI_2;

    fn closure() -> LoopClosure {
        let mut cov = Mat6::zeros();
        for r in 0..6 {
            for c in 0..6 {
                cov[(r, c)] = (10 * r + c) as f64;
            }
        }
        LoopClosure {
            query_id: 42,
            match_id: 7,
            query_stamp: Stamp(1_700_000_123_250_000_000),
            match_stamp: Stamp(1_700_000_010_500_000_000),
            query_odom_pose: iso3_from_xyz_rpy(10.0, -2.0, 0.0, 0.0, 0.0, FRAC_PI_2),
            match_odom_pose: iso3_from_xyz_rpy(9.0, -1.5, 0.0, 0.0, 0.0, 0.0),
            t_match_query: iso3_from_xyz_rpy(1.5, 0.25, 0.0, 0.0, 0.0, -FRAC_PI_2),
            covariance: cov,
            inliers: 31,
            score: 0.625,
            match_session: 0,
            query_robot: 0,
            match_origin: None,
        }
    }

    #[test]
    fn closure_record_fields_and_round_trip() {
        let c = closure();
        let rec = ClosureRecord::new(&c, "base_link");
        let line = rec.to_json_line();
        let v: serde_json::Value = serde_json::from_str(&line).unwrap();
        // Values written by hand from the closure above (yaw 90 deg: qz = qw = sqrt(1/2)).
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert_eq!(v["frame_id"], "base_link");
        assert_eq!(v["stamp"].as_f64().unwrap(), 1_700_000_123.25);
        assert_eq!(v["query_stamp"].as_f64().unwrap(), 1_700_000_123.25);
        assert_eq!(v["match_stamp"].as_f64().unwrap(), 1_700_000_010.5);
        assert_eq!(v["query_id"], 42);
        assert_eq!(v["match_id"], 7);
        assert!((v["query_odom_pose"]["qz"].as_f64().unwrap() - h).abs() < 1e-15);
        assert!((v["query_odom_pose"]["qw"].as_f64().unwrap() - h).abs() < 1e-15);
        assert!((v["relative_pose"]["qz"].as_f64().unwrap() + h).abs() < 1e-15);
        assert_eq!(v["relative_pose"]["x"].as_f64().unwrap(), 1.5);
        assert_eq!(v["match_odom_pose"]["y"].as_f64().unwrap(), -1.5);
        // Row-major: element (r, c) at 6 r + c.
        let cov = v["covariance"].as_array().unwrap();
        assert_eq!(cov.len(), 36);
        assert_eq!(cov[6 + 5].as_f64().unwrap(), 15.0);
        assert_eq!(cov[5 * 6 + 1].as_f64().unwrap(), 51.0);
        assert_eq!(v["inliers"], 31);
        assert_eq!(v["score"].as_f64().unwrap(), 0.625);

        let back = ClosureRecord::from_json_line(&line).unwrap();
        assert_eq!(back, rec);
        assert_eq!(back.covariance_matrix().unwrap(), c.covariance);
        let t = back.relative_pose.to_iso3().unwrap();
        assert!((t.translation.vector - c.t_match_query.translation.vector).norm() < 1e-15);
        assert!(t.rotation.angle_to(&c.t_match_query.rotation) < 1e-12);
        assert!(ClosureRecord::from_json_line(&line.replace("\"score\"", "\"scor\"")).is_err());
    }
}
