//! What enters the pipeline: [`Input`] (a radar cloud, a decoded scan, an odometry or ground-truth
//! sample, a gyro sample) from every source (rosbag2 and foxglove MCAP, nuScenes, View-of-Delft,
//! the simulator, the node's DDS subscriptions), the [`InputIssue`] a source reports for a message
//! it skips, and the conversions of ROS messages into inputs ([`odometry_pose`],
//! [`ground_truth_sample`], [`header_stamp`]).
//!
//! Stamps: an input carries its message's `header.stamp`. Some drivers leave it zero (the TI mmWave
//! ROS driver does); then the receive time (a bag's log time, the node's clock) stands in. A stamp
//! whose `nanosec` is 1e9 or more names no time: its message is skipped
//! ([`IssueReason::BadStamp`]).

use crate::math::{Iso3, Stamp, Vec3};
use crate::msgs::nav_msgs::Odometry;
use crate::msgs::radar_msgs::RadarScan as RadarScanMsg;
use crate::msgs::sensor_msgs::PointCloud2;
use crate::msgs::std_msgs::Header;
use crate::radar::trigger::{TriggerError, TriggerStamps};
use crate::radar::{Detection, RadarScan};

/// One input of the pipeline, from any source.
#[derive(Debug, Clone, PartialEq)]
pub enum Input {
    /// A radar cloud (its `header.stamp` already replaced by the receive or log time when it was
    /// zero).
    Radar {
        /// Radar index (position in `radar_names`).
        radar: usize,
        /// The cloud.
        cloud: PointCloud2,
    },
    /// A radar scan already decoded into detections (the simulator's scans, datasets read without a
    /// PointCloud2).
    Scan(RadarScan),
    /// An odometry sample.
    Odometry {
        /// Its stamp.
        stamp: Stamp,
        /// Body pose in the odometry frame.
        t_odom_body: Iso3,
    },
    /// A gyro sample (`sensor_msgs/Imu`), read with `odometry.source: radar_imu`.
    Imu {
        /// Its stamp.
        stamp: Stamp,
        /// Angular velocity in the IMU frame, rad/s.
        angular_velocity: Vec3,
    },
    /// Another robot's keyframe, the message as its node shared it (`node.fleet`).
    Keyframe(Box<crate::msgs::dc_loc::Keyframe>),
    /// A ground-truth sample (not used by the pipeline; for evaluation).
    GroundTruth {
        /// Its stamp.
        stamp: Stamp,
        /// Body pose in the map frame.
        t_map_body: Iso3,
        /// Speed: norm of the twist's linear velocity, m/s.
        speed: f64,
    },
}

impl Input {
    /// The input's stamp.
    pub fn stamp(&self) -> Stamp {
        match self {
            Input::Radar { cloud, .. } => cloud.header.stamp.into(),
            Input::Scan(scan) => scan.stamp,
            Input::Keyframe(k) => k.header.stamp.into(),
            Input::Odometry { stamp, .. }
            | Input::Imu { stamp, .. }
            | Input::GroundTruth { stamp, .. } => *stamp,
        }
    }

    /// A radar input with its stamp from its radar's trigger (unchanged for a radar without a trigger
    /// topic, and for every other input); refused when there is no trigger to take.
    pub fn with_trigger_stamp(mut self, triggers: &mut TriggerStamps) -> Result<Self, IssueReason> {
        match &mut self {
            Input::Radar { radar, cloud } => {
                cloud.header.stamp = triggers.stamp(*radar, cloud.header.stamp.into())?.into();
            }
            Input::Scan(scan) => scan.stamp = triggers.stamp(scan.radar, scan.stamp)?,
            _ => {}
        }
        Ok(self)
    }
}

/// A source's own error (a bag reader's, a dataset reader's), carried by [`IssueReason`].
pub type SourceError = Box<dyn std::error::Error + Send + Sync>;

/// Why a message of a source was not turned into an [`Input`].
#[derive(Debug, thiserror::Error)]
pub enum IssueReason {
    /// The message does not decode as its topic's type (the source's error, e.g. the CDR error).
    #[error("does not decode: {0}")]
    Decode(#[source] SourceError),
    /// An odometry or ground-truth pose with a non-finite value or a zero quaternion.
    #[error("pose is not finite (or its quaternion is zero)")]
    NonFinitePose,
    /// A gyro sample whose angular velocity is not finite.
    #[error("angular velocity is not finite")]
    NonFiniteRate,
    /// A cloud whose `header.frame_id` is not the configured `frame_id` of the topic's radar(s).
    #[error("frame_id `{got}` is not the configured `{expected}`")]
    FrameMismatch {
        /// The configured frame id(s), `|`-separated when several radars share the topic.
        expected: String,
        /// The cloud's frame id.
        got: String,
    },
    /// The bag file is damaged from here on (messages before were read; the file ends here).
    #[error("damaged bag file: {0}")]
    Damaged(#[source] SourceError),
    /// A message of a non-ROS encoding (foxglove protobuf) that does not
    /// decode or convert.
    #[error("does not convert: {0}")]
    Foreign(String),
    /// A dataset file (a nuScenes sweep, a View-of-Delft frame) that is missing or does not parse.
    #[error("unreadable file: {0}")]
    Unreadable(String),
    /// A scan of a radar that takes its stamps from a trigger topic, with no trigger to take.
    #[error("no stamp from the radar's trigger: {0}")]
    NoTrigger(#[from] TriggerError),
    /// A header stamp whose `nanosec` is 1e9 or more.
    #[error("header stamp {sec} s {nanosec} ns is not a time (nanosec must be below 1e9)")]
    BadStamp {
        /// The stamp's seconds.
        sec: i32,
        /// The stamp's nanoseconds.
        nanosec: u32,
    },
}

impl IssueReason {
    /// Short snake_case name for counts and summaries.
    pub fn name(&self) -> &'static str {
        match self {
            IssueReason::Decode(_) => "undecodable",
            IssueReason::NonFinitePose => "non_finite_pose",
            IssueReason::NonFiniteRate => "non_finite_rate",
            IssueReason::FrameMismatch { .. } => "frame_mismatch",
            IssueReason::Damaged(_) => "damaged_file",
            IssueReason::Foreign(_) => "undecodable_foreign",
            IssueReason::Unreadable(_) => "unreadable_file",
            IssueReason::BadStamp { .. } => "bad_stamp",
            IssueReason::NoTrigger(_) => "no_trigger",
        }
    }

    /// What repeats from message to message when the cause is a misconfiguration: the reason's name,
    /// and for a frame mismatch the frame found (see [`crate::repeats`]).
    pub fn cause(&self) -> String {
        match self {
            IssueReason::FrameMismatch { got, .. } => format!("frame_mismatch `{got}`"),
            other => other.name().to_string(),
        }
    }
}

impl InputIssue {
    /// Logs the issue in full the first time of its cause (topic and [`IssueReason::cause`]) in
    /// `repeats`, at debug level after; every one is counted there.
    pub fn log_once(&self, repeats: &mut crate::repeats::Repeats) {
        let cause = format!("{}: {}", self.topic, self.reason.cause());
        repeats.warn_first(module_path!(), &cause, &format!("skipped: {self}"));
    }
}

/// A message of a source that was skipped, and why.
#[derive(Debug, thiserror::Error)]
#[error("{topic} at {:.6} s: {reason}", .stamp.as_secs_f64())]
pub struct InputIssue {
    /// Topic of the message (empty for damage that belongs to no message).
    pub topic: String,
    /// Header stamp, or the log time when the header is zero or could not be read.
    pub stamp: Stamp,
    /// What is wrong.
    pub reason: IssueReason,
}

/// How large a cloud the pipeline takes (`node.max_cloud_points`, `node.max_cloud_bytes`, in the
/// node and in `dc_loc run` alike): whatever a cloud's header claims, decoding it never holds more.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InputLimits {
    /// Most points (width x height).
    pub max_cloud_points: usize,
    /// Most data bytes.
    pub max_cloud_bytes: usize,
}

impl Default for InputLimits {
    /// 200,000 points and 16 MiB: a 4D imaging radar's thousands of points fit a hundred times
    /// over.
    fn default() -> Self {
        InputLimits {
            max_cloud_points: 200_000,
            max_cloud_bytes: 16 << 20,
        }
    }
}

impl InputLimits {
    /// Why `cloud` is too large, or `Ok`.
    pub fn check(&self, cloud: &PointCloud2) -> Result<(), String> {
        let points = u64::from(cloud.width) * u64::from(cloud.height);
        self.check_size(points, cloud.data.len())
    }

    /// Why a message of `points` points in `bytes` bytes of point data is too large, or `Ok`.
    pub fn check_size(&self, points: u64, bytes: usize) -> Result<(), String> {
        if points > self.max_cloud_points as u64 {
            return Err(format!(
                "{points} points > node.max_cloud_points ({})",
                self.max_cloud_points
            ));
        }
        if bytes > self.max_cloud_bytes {
            return Err(format!(
                "{bytes} bytes > node.max_cloud_bytes ({})",
                self.max_cloud_bytes
            ));
        }
        Ok(())
    }
}

/// The header stamp, or `log_time` when the header stamp is zero (recorders that leave it unset); a
/// stamp whose `nanosec` is 1e9 or more is refused as [`IssueReason::BadStamp`].
pub fn header_stamp(header: &Header, log_time: Stamp) -> Result<Stamp, IssueReason> {
    let t = header.stamp;
    match Stamp::checked_from_sec_nanosec(t.sec, t.nanosec) {
        None => Err(IssueReason::BadStamp {
            sec: t.sec,
            nanosec: t.nanosec,
        }),
        Some(Stamp(0)) => Ok(log_time),
        Some(s) => Ok(s),
    }
}

/// A `radar_msgs/RadarScan` as the scan of radar `radar` at `stamp`: each return becomes the
/// detection at `(r cos el cos az, r cos el sin az, r sin el)` in the radar frame with `v_r =
/// doppler_velocity` (positive away, dc_loc's convention). Returns that are not finite or at zero
/// range are kept here and counted as invalid by the pipeline, as the points of a cloud are.
/// `amplitude` (dB) is not an RCS and is not read.
pub fn radar_scan_input(radar: usize, stamp: Stamp, msg: &RadarScanMsg) -> Input {
    let detections = msg
        .returns
        .iter()
        .map(|r| {
            let (range, az, el) = (
                f64::from(r.range),
                f64::from(r.azimuth),
                f64::from(r.elevation),
            );
            Detection {
                p_radar: Vec3::new(
                    range * el.cos() * az.cos(),
                    range * el.cos() * az.sin(),
                    range * el.sin(),
                ),
                v_r: f64::from(r.doppler_velocity),
                rcs: None,
            }
        })
        .collect();
    Input::Scan(RadarScan {
        radar,
        stamp,
        detections,
    })
}

/// Stamp and body pose of an odometry message; `None` when the pose is not finite.
pub fn odometry_pose(msg: &Odometry) -> Option<(Stamp, Iso3)> {
    Some((msg.header.stamp.into(), msg.pose.pose.to_iso3()?))
}

/// A `sensor_msgs/Imu` as a gyro input stamped `stamp`; `None` when its angular velocity is not
/// finite.
pub fn imu_input(stamp: Stamp, msg: &crate::msgs::sensor_msgs::Imu) -> Option<Input> {
    let w = &msg.angular_velocity;
    let angular_velocity = Vec3::new(w.x, w.y, w.z);
    angular_velocity
        .iter()
        .all(|x| x.is_finite())
        .then_some(Input::Imu {
            stamp,
            angular_velocity,
        })
}

/// Stamp, body pose and speed (norm of `twist.linear`, m/s) of a ground-truth odometry message;
/// `None` when the pose is not finite (the speed is not checked: the pose is what matters).
pub fn ground_truth_sample(msg: &Odometry) -> Option<(Stamp, Iso3, f64)> {
    let (stamp, pose) = odometry_pose(msg)?;
    let l = &msg.twist.twist.linear;
    Some((stamp, pose, Vec3::new(l.x, l.y, l.z).norm()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::radar_msgs::RadarReturn;

    #[test]
    fn radar_scan_returns_become_detections_in_the_radar_frame() {
        let ret = |range, azimuth, elevation, doppler_velocity| RadarReturn {
            range,
            azimuth,
            elevation,
            doppler_velocity,
            amplitude: 30.0,
        };
        let msg = RadarScanMsg {
            header: Header::default(),
            returns: vec![
                ret(10.0, 0.0, 0.0, -5.0),
                ret(2.0, std::f32::consts::FRAC_PI_2, 0.0, 1.0),
                ret(4.0, 0.0, -std::f32::consts::FRAC_PI_6, 0.0),
                ret(f32::NAN, 0.0, 0.0, 0.0),
            ],
        };
        let Input::Scan(scan) = radar_scan_input(2, Stamp(7), &msg) else {
            panic!("not a scan");
        };
        assert_eq!(
            (scan.radar, scan.stamp, scan.detections.len()),
            (2, Stamp(7), 4)
        );
        let d = &scan.detections;
        assert!((d[0].p_radar - Vec3::new(10.0, 0.0, 0.0)).norm() < 1e-9);
        assert_eq!(d[0].v_r, -5.0);
        assert!((d[1].p_radar - Vec3::new(0.0, 2.0, 0.0)).norm() < 1e-6);
        assert!((d[2].p_radar - Vec3::new(4.0 * 0.75f64.sqrt(), 0.0, -2.0)).norm() < 1e-6);
        assert!(d[3].p_radar.x.is_nan() && d[0].rcs.is_none());
    }
    use crate::msgs::builtin_interfaces::Time;

    #[test]
    fn converters_check_finiteness_and_fall_back_to_log_time() {
        let mut m = Odometry::default();
        m.header.stamp = Time { sec: 5, nanosec: 7 };
        m.pose.pose.position.x = 2.0;
        m.twist.twist.linear.x = 3.0;
        m.twist.twist.linear.y = 4.0;
        let (s, t, v) = ground_truth_sample(&m).unwrap();
        assert_eq!(s, Stamp(5_000_000_007));
        assert_eq!(t.translation.x, 2.0);
        assert_eq!(v, 5.0);
        m.pose.pose.orientation.w = f64::NAN;
        assert!(odometry_pose(&m).is_none());
        m.pose.pose.orientation = Default::default();
        m.pose.pose.position.y = f64::INFINITY;
        assert!(odometry_pose(&m).is_none());

        let log = Stamp(99);
        assert_eq!(
            header_stamp(&m.header, log).ok(),
            Some(Stamp(5_000_000_007))
        );
        assert_eq!(header_stamp(&Header::default(), log).ok(), Some(log));

        let mut imu = crate::msgs::sensor_msgs::Imu::default();
        imu.angular_velocity.z = 0.25;
        assert_eq!(
            imu_input(log, &imu),
            Some(Input::Imu {
                stamp: log,
                angular_velocity: Vec3::new(0.0, 0.0, 0.25)
            })
        );
        imu.angular_velocity.x = f64::NAN;
        assert_eq!(imu_input(log, &imu), None);
    }

    #[test]
    fn a_header_stamp_with_nanosec_past_a_second_is_refused() {
        let mut h = Header::default();
        let log = Stamp(99);
        assert_eq!(header_stamp(&h, log).unwrap(), log);
        h.stamp = Time {
            sec: 5,
            nanosec: 999_999_999,
        };
        assert_eq!(header_stamp(&h, log).unwrap(), Stamp(5_999_999_999));
        h.stamp.nanosec = 1_000_000_000;
        let e = header_stamp(&h, log).unwrap_err();
        assert_eq!(e.name(), "bad_stamp");
        assert!(e.to_string().contains("5 s 1000000000 ns"), "{e}");
        // Zero seconds do not make it a zero (unset) stamp.
        h.stamp.sec = 0;
        assert!(header_stamp(&h, log).is_err());
    }
}
