//! The offline runner: a rosbag2 bag turned into the pipeline's inputs, in log-time order, and a driver
//! that feeds them to a [`Pipeline`]. `dc_loc run`, `dc_loc eval` and the tests share it; the ROS 2 node
//! reuses its message converters.
//!
//! Entry points:
//! - [`BagInputs`] (`new(&BagReader, &Config, ground_truth_topic)`): an iterator of
//!   `Result<`[`Input`]`, `[`InputIssue`]`>`. Radar clouds come from `radars.<name>.topic` (radar index =
//!   position in `radar_names`), odometry from `odometry.topic`, ground truth (optional) from any
//!   `nav_msgs/Odometry` topic. Other topics are not read.
//! - [`drive_pipeline`] (one input into the pipeline) and [`run_bag`] (a whole input stream, every
//!   input, issue and [`Event`] handed to a closure as a [`RunItem`], counts in a [`RunReport`]).
//! - Converters: [`odometry_pose`], [`ground_truth_sample`], [`stamp_or_log_time`],
//!   [`loop_closure_msg`].
//! - [`ClosureRecord`]: the JSON-lines record of one loop closure (`dc_loc run --out`), with
//!   [`ClosureRecord::from_json_line`] to read it back.
//!
//! Bad messages never stop a run: a message that does not decode, an odometry pose that is not finite,
//! a cloud whose `header.frame_id` is not the radar's configured `frame_id` (when that is not empty), or
//! damage in the bag file itself come out as [`InputIssue`]s (topic, stamp, [`IssueReason`]) and the
//! stream goes on. A configuration that does not fit the bag (a configured topic missing, or of another
//! type) is refused up front by [`BagInputs::new`] with a [`RunnerError`] naming the parameter.
//!
//! Stamps: an input carries its message's `header.stamp`. Some recorders leave it zero (the TI mmWave
//! ROS driver does: every cloud of the rio-ti-mmwave-demo bag in `shared/data/real` has stamp 0); then
//! the bag's log time (the receive time) stands in, and a radar cloud's `header.stamp` is rewritten to it
//! so that [`Pipeline::push_cloud`] sees the same time.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::bag::{BagError, BagReader, Messages, schema};
use crate::config::Config;
use crate::math::{Iso3, Stamp, Vec3};
use crate::msgs::builtin_interfaces::Time;
use crate::msgs::geometry_msgs::{Pose, PoseWithCovariance};
use crate::msgs::nav_msgs::Odometry;
use crate::msgs::sensor_msgs::PointCloud2;
use crate::msgs::std_msgs::Header;
use crate::msgs::{self};
use crate::pipeline::{Event, LoopClosure, Pipeline, PipelineStats};

/// One input of the pipeline, as read from a bag.
#[derive(Debug, Clone, PartialEq)]
pub enum Input {
    /// A radar cloud (its `header.stamp` already replaced by the log time when it was zero).
    Radar {
        /// Radar index (position in `radar_names`).
        radar: usize,
        /// The cloud.
        cloud: PointCloud2,
    },
    /// An odometry sample.
    Odometry {
        /// Its stamp.
        stamp: Stamp,
        /// Body pose in the odometry frame.
        t_odom_body: Iso3,
    },
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
            Input::Odometry { stamp, .. } | Input::GroundTruth { stamp, .. } => *stamp,
        }
    }
}

/// Why a message of the bag was not turned into an [`Input`].
#[derive(Debug, thiserror::Error)]
pub enum IssueReason {
    /// The message does not decode as its topic's type (the CDR error).
    #[error("does not decode: {0}")]
    Decode(#[source] BagError),
    /// An odometry or ground-truth pose with a non-finite value or a zero quaternion.
    #[error("pose is not finite (or its quaternion is zero)")]
    NonFinitePose,
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
    Damaged(#[source] BagError),
    /// A message of a non-ROS encoding (foxglove protobuf, [`crate::bag::foxglove`]) that does not
    /// decode or convert.
    #[error("does not convert: {0}")]
    Foreign(String),
}

impl IssueReason {
    /// Short snake_case name for counts and summaries.
    pub fn name(&self) -> &'static str {
        match self {
            IssueReason::Decode(_) => "undecodable",
            IssueReason::NonFinitePose => "non_finite_pose",
            IssueReason::FrameMismatch { .. } => "frame_mismatch",
            IssueReason::Damaged(_) => "damaged_file",
            IssueReason::Foreign(_) => "undecodable_foreign",
        }
    }
}

/// A message of the bag that was skipped, and why.
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

/// Why a bag cannot be run with a configuration.
#[derive(Debug, thiserror::Error)]
pub enum RunnerError {
    /// The bag could not be read.
    #[error(transparent)]
    Bag(#[from] BagError),
    /// A configured topic is not in the bag.
    #[error(
        "parameter `{parameter}`: topic {topic} is not in the bag {bag} (its topics: {available})"
    )]
    MissingTopic {
        /// The parameter naming the topic (`radars.front.topic`, `odometry.topic`, or
        /// `ground_truth_topic`).
        parameter: String,
        /// The topic.
        topic: String,
        /// The bag path.
        bag: String,
        /// The bag's topics, comma-separated.
        available: String,
    },
    /// A configured topic has another message type in the bag.
    #[error(
        "parameter `{parameter}`: topic {topic} has type {got} in the bag, expected {expected}"
    )]
    TopicType {
        /// The parameter naming the topic.
        parameter: String,
        /// The topic.
        topic: String,
        /// The type dc_loc reads there.
        expected: &'static str,
        /// The type in the bag.
        got: String,
    },
}

/// What a topic is read as.
#[derive(Debug, Clone)]
enum Route {
    /// Radar clouds: the radars publishing on this topic, with their expected frame ids.
    Radar(Vec<(usize, String)>),
    Odometry,
    GroundTruth,
}

/// The pipeline inputs of a bag, in log-time order (see the module documentation).
pub struct BagInputs {
    messages: Messages,
    routes: BTreeMap<String, Route>,
    /// Newest log time seen: the stamp of damage reports.
    last_log_time: Stamp,
    total: u64,
}

impl BagInputs {
    /// Prepares to read the radar and odometry topics of `cfg` (and `ground_truth_topic`, a
    /// `nav_msgs/Odometry` topic, when given) from `reader`.
    ///
    /// Fails when a configured topic is missing from the bag or has another type, naming the parameter.
    pub fn new(
        reader: &BagReader,
        cfg: &Config,
        ground_truth_topic: Option<&str>,
    ) -> Result<Self, RunnerError> {
        let mut routes: BTreeMap<String, Route> = BTreeMap::new();
        let mut wanted: Vec<(String, String, &'static str)> = Vec::new();
        for (i, name) in cfg.radar_names.iter().enumerate() {
            let Some(rc) = cfg.radars.get(name) else {
                continue;
            };
            wanted.push((
                format!("radars.{name}.topic"),
                rc.topic.clone(),
                schema::POINT_CLOUD2,
            ));
            if let Route::Radar(list) = routes
                .entry(rc.topic.clone())
                .or_insert_with(|| Route::Radar(Vec::new()))
            {
                list.push((i, rc.frame_id.clone()));
            }
        }
        wanted.push((
            "odometry.topic".into(),
            cfg.odometry.topic.clone(),
            schema::ODOMETRY,
        ));
        routes
            .entry(cfg.odometry.topic.clone())
            .or_insert(Route::Odometry);
        if let Some(gt) = ground_truth_topic {
            wanted.push((
                "ground_truth_topic".into(),
                gt.to_string(),
                schema::ODOMETRY,
            ));
            routes.entry(gt.to_string()).or_insert(Route::GroundTruth);
        }
        let mut total = 0;
        for (parameter, topic, expected) in &wanted {
            let Some(info) = reader.topic(topic) else {
                return Err(RunnerError::MissingTopic {
                    parameter: parameter.clone(),
                    topic: topic.clone(),
                    bag: reader.path().display().to_string(),
                    available: reader
                        .topics()
                        .iter()
                        .map(|t| t.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", "),
                });
            };
            if info.type_name != *expected {
                return Err(RunnerError::TopicType {
                    parameter: parameter.clone(),
                    topic: topic.clone(),
                    expected,
                    got: info.type_name.clone(),
                });
            }
        }
        for topic in routes.keys() {
            total += reader.topic(topic).map_or(0, |t| t.message_count);
        }
        let topics: Vec<&str> = routes.keys().map(String::as_str).collect();
        let messages = reader.messages_on(&topics)?;
        Ok(BagInputs {
            messages,
            routes,
            last_log_time: Stamp(0),
            total,
        })
    }

    /// Messages on the topics read (the length of the stream, issues included, for progress).
    pub fn total_messages(&self) -> u64 {
        self.total
    }
}

impl Iterator for BagInputs {
    type Item = Result<Input, InputIssue>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let msg = match self.messages.next()? {
                Ok(m) => m,
                Err(e) => {
                    return Some(Err(InputIssue {
                        topic: String::new(),
                        stamp: self.last_log_time,
                        reason: IssueReason::Damaged(e),
                    }));
                }
            };
            self.last_log_time = msg.log_time;
            // Unknown topics cannot come (the reader filters), but skip them rather than trust that.
            let Some(route) = self.routes.get(msg.topic()) else {
                continue;
            };
            let issue = |stamp, reason| InputIssue {
                topic: msg.topic().to_string(),
                stamp,
                reason,
            };
            return Some(match route {
                Route::Radar(radars) => match msg.decode::<PointCloud2>() {
                    Err(e) => Err(issue(msg.log_time, IssueReason::Decode(e))),
                    Ok(mut cloud) => {
                        let stamp = stamp_or_log_time(&cloud.header, msg.log_time);
                        cloud.header.stamp = stamp.into();
                        let got = &cloud.header.frame_id;
                        match radars
                            .iter()
                            .find(|(_, frame)| frame.is_empty() || frame == got)
                        {
                            Some(&(radar, _)) => Ok(Input::Radar { radar, cloud }),
                            None => Err(issue(
                                stamp,
                                IssueReason::FrameMismatch {
                                    expected: radars
                                        .iter()
                                        .map(|(_, f)| f.as_str())
                                        .collect::<Vec<_>>()
                                        .join("|"),
                                    got: got.clone(),
                                },
                            )),
                        }
                    }
                },
                Route::Odometry | Route::GroundTruth => match msg.decode::<Odometry>() {
                    Err(e) => Err(issue(msg.log_time, IssueReason::Decode(e))),
                    Ok(odom) => {
                        let stamp = stamp_or_log_time(&odom.header, msg.log_time);
                        match ground_truth_sample(&odom) {
                            None => Err(issue(stamp, IssueReason::NonFinitePose)),
                            Some((_, pose, speed)) => Ok(if matches!(route, Route::Odometry) {
                                Input::Odometry {
                                    stamp,
                                    t_odom_body: pose,
                                }
                            } else {
                                Input::GroundTruth {
                                    stamp,
                                    t_map_body: pose,
                                    speed,
                                }
                            }),
                        }
                    }
                },
            });
        }
    }
}

/// The header stamp, or `log_time` when the header stamp is zero (recorders that leave it unset).
pub fn stamp_or_log_time(header: &Header, log_time: Stamp) -> Stamp {
    let s: Stamp = header.stamp.into();
    if s == Stamp(0) { log_time } else { s }
}

/// Stamp and body pose of an odometry message; `None` when the pose is not finite.
pub fn odometry_pose(msg: &Odometry) -> Option<(Stamp, Iso3)> {
    Some((msg.header.stamp.into(), msg.pose.pose.to_iso3()?))
}

/// Stamp, body pose and speed (norm of `twist.linear`, m/s) of a ground-truth odometry message; `None`
/// when the pose is not finite (the speed is not checked: the pose is what matters).
pub fn ground_truth_sample(msg: &Odometry) -> Option<(Stamp, Iso3, f64)> {
    let (stamp, pose) = odometry_pose(msg)?;
    let l = &msg.twist.twist.linear;
    Some((stamp, pose, Vec3::new(l.x, l.y, l.z).norm()))
}

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
        match_id: c.match_id,
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

/// Feeds one input to the pipeline and returns what it produced (ground truth produces nothing).
pub fn drive_pipeline(pipeline: &mut Pipeline, input: &Input) -> Vec<Event> {
    match input {
        Input::Radar { radar, cloud } => pipeline.push_cloud(*radar, cloud),
        Input::Odometry { stamp, t_odom_body } => pipeline.push_odometry(*stamp, *t_odom_body),
        Input::GroundTruth { .. } => Vec::new(),
    }
}

/// What [`run_bag`] hands to its closure, in stream order: each input or issue, then the events the
/// input produced.
#[derive(Debug, Clone, Copy)]
pub enum RunItem<'a> {
    /// An input, before it goes into the pipeline.
    Input(&'a Input),
    /// A skipped message.
    Issue(&'a InputIssue),
    /// An event of the pipeline (those of [`Pipeline::finish`] come last).
    Event(&'a Event),
}

/// Counts of a run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunReport {
    /// Radar clouds fed to the pipeline.
    pub radar_inputs: u64,
    /// Odometry samples fed to the pipeline.
    pub odometry_inputs: u64,
    /// Ground-truth samples read (not fed to the pipeline).
    pub ground_truth_inputs: u64,
    /// Skipped messages by [`IssueReason::name`].
    pub issues: BTreeMap<&'static str, u64>,
    /// The pipeline's counters after [`Pipeline::finish`].
    pub stats: PipelineStats,
}

impl RunReport {
    /// Skipped messages in all.
    pub fn issue_count(&self) -> u64 {
        self.issues.values().sum()
    }
}

/// Drives `pipeline` through a whole input stream, then [`Pipeline::finish`]; every input, issue and
/// event goes to `on_item`. Issues are logged (`warn`) and counted, never fatal.
pub fn run_bag<I, F>(pipeline: &mut Pipeline, inputs: I, mut on_item: F) -> RunReport
where
    I: IntoIterator<Item = Result<Input, InputIssue>>,
    F: FnMut(RunItem<'_>),
{
    let mut report = RunReport::default();
    for item in inputs {
        match item {
            Ok(input) => {
                match &input {
                    Input::Radar { .. } => report.radar_inputs += 1,
                    Input::Odometry { .. } => report.odometry_inputs += 1,
                    Input::GroundTruth { .. } => report.ground_truth_inputs += 1,
                }
                on_item(RunItem::Input(&input));
                for e in drive_pipeline(pipeline, &input) {
                    on_item(RunItem::Event(&e));
                }
            }
            Err(issue) => {
                log::warn!("skipped: {issue}");
                *report.issues.entry(issue.reason.name()).or_default() += 1;
                on_item(RunItem::Issue(&issue));
            }
        }
    }
    for e in pipeline.finish() {
        on_item(RunItem::Event(&e));
    }
    report.stats = pipeline.stats().clone();
    report
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
    /// Older, revisited keyframe.
    pub match_id: u64,
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
        assert_eq!(stamp_or_log_time(&m.header, log), Stamp(5_000_000_007));
        assert_eq!(stamp_or_log_time(&Header::default(), log), log);
    }
}
