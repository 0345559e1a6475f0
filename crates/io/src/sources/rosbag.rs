//! A bag (rosbag2 MCAP or ROS 1) as the pipeline's input stream: [`BagInputs`] reads the radar and
//! pose topics of a configuration (and optionally a ground-truth topic, `nav_msgs/Odometry` or
//! `geometry_msgs/PoseStamped`) in log-time order (a ROS 1 bag: in file order).
//!
//! Radar clouds (`sensor_msgs/PointCloud2`, or `radar_msgs/RadarScan` for a radar whose
//! `radars.<name>.message` is `radar_scan`) come from `radars.<name>.topic` (radar index = position in
//! `radar_names`). The pose input follows `odometry.source`: `nav_msgs/Odometry` from
//! `odometry.topic` with `topic`; nothing with `radar` (the radars make the odometry); the
//! `sensor_msgs/Imu` gyro from `imu.topic` with `radar_imu`. Bad messages never stop a run: a message
//! that does not decode, an odometry pose or a gyro rate that is not finite, a cloud whose
//! `header.frame_id` is not the radar's configured `frame_id` (when that is not empty), or damage in
//! the bag file itself come out as [`InputIssue`]s and the stream goes on. A configuration that does not fit the bag (a configured topic missing, or of another type,
//! or in a ROS 1 bag of another definition than the type's standard one) is refused up front by
//! [`BagInputs::new`], naming the parameter. A cloud's zero `header.stamp` is replaced by the bag's log
//! time; a radar with a `trigger_topic` takes its scans' stamps from the `std_msgs/Header` triggers
//! on that topic instead, the newest one before each scan in file order
//! ([`dc_loc_core::radar::trigger`]). A `PoseStamped` ground truth has no twist: its speed is the
//! distance from the previous pose over the time between them ([`PoseSpeed`]: the first pose comes
//! with the second and takes its speed).

use std::collections::{BTreeMap, VecDeque};

use super::ground_truth::PoseSpeed;
use crate::bag::{BagError, BagReader, Messages, ros1, schema};
use dc_loc_core::input::{
    Input, InputIssue, IssueReason, ground_truth_sample, header_stamp, imu_input, radar_scan_input,
};
use dc_loc_core::math::Stamp;
use dc_loc_core::msgs::geometry_msgs::PoseStamped;
use dc_loc_core::msgs::nav_msgs::Odometry;
use dc_loc_core::msgs::radar_msgs::RadarScan as RadarScanMsg;
use dc_loc_core::msgs::sensor_msgs::{Imu, PointCloud2};
use dc_loc_core::msgs::std_msgs::Header;
use dc_loc_core::odometry::OdometrySource;
use dc_loc_core::pipeline::Config;
use dc_loc_core::radar::RadarMessage;
use dc_loc_core::radar::trigger::TriggerStamps;

/// Why a bag cannot be run with a configuration.
#[derive(Debug, thiserror::Error)]
pub enum BagInputError {
    /// The bag could not be read.
    #[error(transparent)]
    Bag(#[from] BagError),
    /// A configured topic is not in the bag.
    #[error(
        "parameter `{parameter}`: topic {topic} is not in the bag {bag} (its topics: {available})"
    )]
    MissingTopic {
        /// The parameter naming the topic (`radars.front.topic`, `odometry.topic`, `imu.topic` or
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
    /// A configured topic of a ROS 1 bag whose connection has another definition of its type.
    #[error("parameter `{parameter}`: topic {topic}: {fault}")]
    Definition {
        /// The parameter naming the topic.
        parameter: String,
        /// The topic.
        topic: String,
        /// The type, its md5sum and the one expected.
        fault: String,
    },
}

/// What a topic is read as.
#[derive(Debug, Clone)]
enum Route {
    /// Radar messages: the radars publishing on this topic, with their expected frame ids, and the
    /// topic's message type.
    Radar(Vec<(usize, String)>, RadarMessage),
    Odometry,
    /// The gyro (`odometry.source: radar_imu`).
    Imu,
    /// Ground truth as `nav_msgs/Odometry` (false) or `geometry_msgs/PoseStamped` (true).
    GroundTruth(bool),
    /// `std_msgs/Header` triggers of these radars.
    Trigger(Vec<usize>),
}

use schema::RADAR_SCAN;

/// What a ground-truth topic may carry.
const GROUND_TRUTH_TYPES: &str = "nav_msgs/msg/Odometry or geometry_msgs/msg/PoseStamped";

/// The radar of `radars` whose frame is `got` (an empty configured frame accepts any).
fn radar_for(radars: &[(usize, String)], got: &str) -> Result<usize, IssueReason> {
    radars
        .iter()
        .find(|(_, frame)| frame.is_empty() || frame == got)
        .map(|&(radar, _)| radar)
        .ok_or_else(|| IssueReason::FrameMismatch {
            expected: radars
                .iter()
                .map(|(_, f)| f.as_str())
                .collect::<Vec<_>>()
                .join("|"),
            got: got.to_string(),
        })
}

/// The pipeline inputs of a bag, in log-time order (see the module documentation).
pub struct BagInputs {
    messages: Messages,
    routes: BTreeMap<String, Route>,
    /// Newest log time seen: the stamp of damage reports.
    last_log_time: Stamp,
    /// The speed of `PoseStamped` ground truth.
    pose_speed: PoseSpeed,
    /// The radars' stamps from their triggers.
    triggers: TriggerStamps,
    /// Items ready and not yet returned: the second of the first two ground-truth poses, or the
    /// damage that ends the file after a ground-truth pose still waiting.
    pending: VecDeque<Result<Input, InputIssue>>,
    total: u64,
}

impl BagInputs {
    /// Prepares to read the radar and pose topics of `cfg` (and `ground_truth_topic`, a
    /// `nav_msgs/Odometry` or `geometry_msgs/PoseStamped` topic, when given) from `reader`.
    ///
    /// Fails when a configured topic is missing from the bag or has another type (in a ROS 1 bag: or
    /// another definition of it), naming the parameter.
    pub fn new(
        reader: &BagReader,
        cfg: &Config,
        ground_truth_topic: Option<&str>,
    ) -> Result<Self, BagInputError> {
        let mut routes: BTreeMap<String, Route> = BTreeMap::new();
        let mut wanted: Vec<(String, String, &'static str)> = Vec::new();
        for (i, name) in cfg.radar_names.iter().enumerate() {
            let Some(rc) = cfg.radars.get(name) else {
                continue;
            };
            let expected = match rc.message {
                RadarMessage::PointCloud2 => schema::POINT_CLOUD2,
                RadarMessage::RadarScan => RADAR_SCAN,
            };
            wanted.push((format!("radars.{name}.topic"), rc.topic.clone(), expected));
            if let Route::Radar(list, _) = routes
                .entry(rc.topic.clone())
                .or_insert_with(|| Route::Radar(Vec::new(), rc.message))
            {
                list.push((i, rc.frame_id.clone()));
            }
            if !rc.trigger_topic.is_empty() {
                wanted.push((
                    format!("radars.{name}.trigger_topic"),
                    rc.trigger_topic.clone(),
                    schema::HEADER,
                ));
                if let Route::Trigger(list) = routes
                    .entry(rc.trigger_topic.clone())
                    .or_insert_with(|| Route::Trigger(Vec::new()))
                {
                    list.push(i);
                }
            }
        }
        let pose_input = match cfg.odometry.source {
            OdometrySource::Topic => Some(("odometry.topic", &cfg.odometry.topic, Route::Odometry)),
            OdometrySource::Radar => None,
            OdometrySource::RadarImu => Some(("imu.topic", &cfg.imu.topic, Route::Imu)),
        };
        if let Some((parameter, topic, route)) = pose_input {
            let expected = match route {
                Route::Imu => schema::IMU,
                _ => schema::ODOMETRY,
            };
            wanted.push((parameter.into(), topic.clone(), expected));
            routes.entry(topic.clone()).or_insert(route);
        }
        if let Some(gt) = ground_truth_topic {
            let pose_stamped = reader
                .topic(gt)
                .is_some_and(|t| t.type_name == schema::POSE_STAMPED);
            wanted.push((
                "ground_truth_topic".into(),
                gt.to_string(),
                if pose_stamped {
                    schema::POSE_STAMPED
                } else {
                    schema::ODOMETRY
                },
            ));
            routes
                .entry(gt.to_string())
                .or_insert(Route::GroundTruth(pose_stamped));
        }
        let mut total = 0;
        for (parameter, topic, expected) in &wanted {
            let Some(info) = reader.topic(topic) else {
                return Err(BagInputError::MissingTopic {
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
                return Err(BagInputError::TopicType {
                    parameter: parameter.clone(),
                    topic: topic.clone(),
                    expected: if parameter == "ground_truth_topic" {
                        GROUND_TRUTH_TYPES
                    } else {
                        expected
                    },
                    got: info.type_name.clone(),
                });
            }
            if info.message_encoding == "ros1"
                && let Some(fault) = ros1::definition_fault(&info.type_name, &info.md5sum)
            {
                return Err(BagInputError::Definition {
                    parameter: parameter.clone(),
                    topic: topic.clone(),
                    fault,
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
            pose_speed: PoseSpeed::default(),
            triggers: TriggerStamps::new(cfg.trigger_delays()),
            pending: VecDeque::new(),
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
        if let Some(item) = self.pending.pop_front() {
            return Some(item);
        }
        loop {
            let msg = match self.messages.next() {
                // A single ground-truth pose still waits for a second one.
                None => return self.pose_speed.finish().map(Ok),
                Some(Ok(m)) => m,
                Some(Err(e)) => {
                    // The damage ends the file: a waiting pose comes out before it.
                    self.pending.extend(self.pose_speed.finish().map(Ok));
                    self.pending.push_back(Err(InputIssue {
                        topic: String::new(),
                        stamp: self.last_log_time,
                        reason: IssueReason::Damaged(Box::new(e)),
                    }));
                    return self.pending.pop_front();
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
                Route::Radar(radars, RadarMessage::PointCloud2) => {
                    match msg.decode::<PointCloud2>() {
                        Err(e) => Err(issue(msg.log_time, IssueReason::Decode(Box::new(e)))),
                        Ok(mut cloud) => match header_stamp(&cloud.header, msg.log_time) {
                            Err(reason) => Err(issue(msg.log_time, reason)),
                            Ok(stamp) => {
                                cloud.header.stamp = stamp.into();
                                radar_for(radars, &cloud.header.frame_id)
                                    .map(|radar| Input::Radar { radar, cloud })
                                    .and_then(|input| input.with_trigger_stamp(&mut self.triggers))
                                    .map_err(|reason| issue(stamp, reason))
                            }
                        },
                    }
                }
                Route::Radar(radars, RadarMessage::RadarScan) => {
                    match msg.decode::<RadarScanMsg>() {
                        Err(e) => Err(issue(msg.log_time, IssueReason::Decode(Box::new(e)))),
                        Ok(scan) => match header_stamp(&scan.header, msg.log_time) {
                            Err(reason) => Err(issue(msg.log_time, reason)),
                            Ok(stamp) => radar_for(radars, &scan.header.frame_id)
                                .map(|radar| radar_scan_input(radar, stamp, &scan))
                                .and_then(|input| input.with_trigger_stamp(&mut self.triggers))
                                .map_err(|reason| issue(stamp, reason)),
                        },
                    }
                }
                Route::Trigger(radars) => match msg.decode::<Header>() {
                    Err(e) => Err(issue(msg.log_time, IssueReason::Decode(Box::new(e)))),
                    Ok(header) => match header_stamp(&header, msg.log_time) {
                        Err(reason) => Err(issue(msg.log_time, reason)),
                        Ok(stamp) => {
                            for &radar in radars {
                                self.triggers.trigger(radar, stamp);
                            }
                            continue;
                        }
                    },
                },
                Route::Imu => match msg.decode::<Imu>() {
                    Err(e) => Err(issue(msg.log_time, IssueReason::Decode(Box::new(e)))),
                    Ok(imu) => match header_stamp(&imu.header, msg.log_time) {
                        Err(reason) => Err(issue(msg.log_time, reason)),
                        Ok(stamp) => match imu_input(stamp, &imu) {
                            Some(input) => Ok(input),
                            None => Err(issue(stamp, IssueReason::NonFiniteRate)),
                        },
                    },
                },
                Route::GroundTruth(true) => match msg.decode::<PoseStamped>() {
                    Err(e) => Err(issue(msg.log_time, IssueReason::Decode(Box::new(e)))),
                    Ok(p) => match header_stamp(&p.header, msg.log_time) {
                        Err(reason) => Err(issue(msg.log_time, reason)),
                        Ok(stamp) => match p.pose.to_iso3() {
                            None => Err(issue(stamp, IssueReason::NonFinitePose)),
                            Some(pose) => {
                                let ready = self.pose_speed.push(stamp, &pose);
                                self.pending.extend(ready.into_iter().map(Ok));
                                match self.pending.pop_front() {
                                    Some(item) => item,
                                    None => continue,
                                }
                            }
                        },
                    },
                },
                Route::Odometry | Route::GroundTruth(false) => match msg.decode::<Odometry>() {
                    Err(e) => Err(issue(msg.log_time, IssueReason::Decode(Box::new(e)))),
                    Ok(odom) => {
                        let stamp = match header_stamp(&odom.header, msg.log_time) {
                            Ok(s) => s,
                            Err(reason) => return Some(Err(issue(msg.log_time, reason))),
                        };
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
