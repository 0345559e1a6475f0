//! The node's own settings (`use_sim_time` and `node.*`, not part of the pipeline's [`Config`], which
//! the offline tools share), and the parameters as ROS 2 declares them.

use serde_json::Value;

use crate::params::{ParamError, ParamSet, flatten_config};
use dc_loc_core::input::InputLimits;
use dc_loc_core::pipeline::Config;
use dc_loc_core::validate::{Range, Validator};

/// The node's own settings.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeSettings {
    /// `use_sim_time`: stamp outputs with `/clock` (rosgraph_msgs/Clock) time.
    pub use_sim_time: bool,
    /// `node.queue_size`: messages waiting for the worker; beyond, new ones are dropped.
    pub queue_size: usize,
    /// `node.diagnostics_period`: seconds between `/diagnostics` messages.
    pub diagnostics_period: f64,
    /// `node.max_cloud_points` and `node.max_cloud_bytes`: larger clouds are refused.
    pub limits: InputLimits,
    /// `node.warn_interval`: seconds between warnings of one kind.
    pub warn_interval: f64,
    /// `node.sync_timeout`: longest wait, s, for the other inputs to reach a message's stamp before it
    /// is processed anyway.
    pub sync_timeout: f64,
    /// `node.restart_after`: consecutive inputs with stamps out of line that mean a restart.
    pub restart_after: usize,
    /// `node.shutdown_timeout`: longest time, s, the worker takes at shutdown to process the queue
    /// after the map is saved.
    pub shutdown_timeout: f64,
    /// `node.markers_period`: shortest time, s, between two `~/markers` messages.
    pub markers_period: f64,
    /// `node.keyframe_budget`: longest time, s, from an input's arrival to the end of the revisit
    /// search it sets off (0: no limit).
    pub keyframe_budget: f64,
    /// `node.log_level`: dc_loc's log level (`debug`, `info`, `warn`, `error`; empty: as started).
    pub log_level: String,
    /// `node.map_frame`: frame id of the `~/relocalized` poses.
    pub map_frame: String,
    /// `node.odom_frame`: frame id of `~/odometry` and of the keyframes' poses while no odometry
    /// message has named one.
    pub odom_frame: String,
    /// `node.odometry_tf`: broadcast the radar odometry's `odom_frame -> body_frame` on `/tf`.
    pub odometry_tf: bool,
    /// `node.extrinsics_from_tf`: take the radars' extrinsics from `/tf_static` at start.
    pub extrinsics_from_tf: bool,
    /// `node.tf_timeout`: longest wait, s, for those transforms.
    pub tf_timeout: f64,
    /// The optional outputs for pose-graph back ends (`node.robot_id`, `node.pose_graph_*`,
    /// `node.lio_sam_*`).
    pub backends: BackendSettings,
    /// Keyframes shared with other robots' nodes (`node.fleet*`).
    pub fleet: FleetSettings,
}

/// Keyframes shared with the other robots' nodes of a fleet (README_NODE.md, Fleets).
#[derive(Debug, Clone, PartialEq)]
pub struct FleetSettings {
    /// `node.fleet`: publish this robot's keyframes and take the other robots'.
    pub enabled: bool,
    /// `node.fleet_topic`: the topic they share.
    pub topic: String,
    /// `node.fleet_history`: keyframes the topic keeps for a robot that joins late.
    pub history: usize,
    /// `node.fleet_points`: most points sent per keyframe.
    pub points: usize,
    /// `node.fleet_rate`: keyframes per second taken from one robot beyond a burst of
    /// `node.fleet_history`.
    pub rate: f64,
    /// `node.fleet_enclave`: the enclave robot `{robot}`'s keyframes must come from (empty: any).
    pub enclave: String,
}

impl Default for FleetSettings {
    fn default() -> Self {
        FleetSettings {
            enabled: false,
            topic: "/dc_loc/keyframes".into(),
            history: 1000,
            points: dc_loc_core::fleet::wire::DEFAULT_WIRE_POINTS,
            rate: 10.0,
            enclave: String::new(),
        }
    }
}

impl FleetSettings {
    /// Declares each setting's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.require("node.fleet_topic", topic_name_ok(&self.topic), || {
            format!("`{}` is not a topic name", self.topic)
        });
        v.count("node.fleet_history", self.history, 1, 100_000);
        v.count("node.fleet_points", self.points, 10, 100_000);
        v.range("node.fleet_rate", self.rate, Range::POSITIVE.up_to(1000.0));
        v.require(
            "node.fleet_enclave",
            self.enclave.is_empty() || self.enclave.contains("{robot}"),
            || format!("`{}` does not hold `{{robot}}`", self.enclave),
        );
    }

    /// The settings as `(name, value)` parameters.
    fn as_params(&self) -> Vec<(String, Value)> {
        vec![
            ("node.fleet".into(), Value::Bool(self.enabled)),
            ("node.fleet_topic".into(), Value::from(self.topic.clone())),
            ("node.fleet_history".into(), Value::from(self.history)),
            ("node.fleet_points".into(), Value::from(self.points)),
            ("node.fleet_rate".into(), Value::from(self.rate)),
            (
                "node.fleet_enclave".into(),
                Value::from(self.enclave.clone()),
            ),
        ]
    }

    /// Takes `name` when it is one of these settings (`Ok(false)` when it is not).
    fn take(&mut self, name: &str, v: &Value) -> Result<bool, ParamError> {
        let count = || {
            v.as_u64()
                .map(|n| usize::try_from(n).unwrap_or(usize::MAX))
                .ok_or_else(|| type_error(name, "a non-negative integer", v))
        };
        match name {
            "node.fleet" => {
                self.enabled = v
                    .as_bool()
                    .ok_or_else(|| type_error(name, "a boolean", v))?
            }
            "node.fleet_topic" => {
                self.topic = v
                    .as_str()
                    .ok_or_else(|| type_error(name, "a string", v))?
                    .to_string()
            }
            "node.fleet_history" => self.history = count()?,
            "node.fleet_points" => self.points = count()?,
            "node.fleet_rate" => {
                self.rate = v.as_f64().ok_or_else(|| type_error(name, "a number", v))?
            }
            "node.fleet_enclave" => {
                self.enclave = v
                    .as_str()
                    .ok_or_else(|| type_error(name, "a string", v))?
                    .to_string()
            }
            _ => return Ok(false),
        }
        Ok(true)
    }
}

/// The optional outputs for pose-graph back ends that read other message types than
/// `dc_loc/msg/LoopClosure` (README_NODE.md, Back ends).
#[derive(Debug, Clone, PartialEq)]
pub struct BackendSettings {
    /// `node.robot_id`: robot id of the `pose_graph_tools_msgs` nodes and edges (an `int32` there; the
    /// range check keeps it within).
    pub robot_id: i64,
    /// `node.pose_graph_output`: publish each closure as a `pose_graph_tools_msgs/PoseGraph`.
    pub pose_graph_output: bool,
    /// `node.pose_graph_topic`: its topic.
    pub pose_graph_topic: String,
    /// `node.lio_sam_output`: publish each closure's two keyframe stamps for LIO-SAM.
    pub lio_sam_output: bool,
    /// `node.lio_sam_topic`: its topic.
    pub lio_sam_topic: String,
}

impl Default for BackendSettings {
    fn default() -> Self {
        BackendSettings {
            robot_id: 0,
            pose_graph_output: false,
            pose_graph_topic: "~/pose_graph".into(),
            lio_sam_output: false,
            lio_sam_topic: LIO_SAM_TOPIC.into(),
        }
    }
}

/// The name LIO-SAM's map optimisation subscribes to its external loop closures under (relative: it
/// resolves in the namespace of the node that uses it, so dc_loc and LIO-SAM in one namespace meet).
pub const LIO_SAM_TOPIC: &str = "lio_loop/loop_closure_detection";

impl Default for NodeSettings {
    fn default() -> Self {
        NodeSettings {
            use_sim_time: false,
            queue_size: 2000,
            diagnostics_period: 1.0,
            limits: InputLimits::default(),
            warn_interval: 5.0,
            sync_timeout: 0.2,
            restart_after: 20,
            shutdown_timeout: 5.0,
            markers_period: 1.0,
            keyframe_budget: 0.0,
            log_level: String::new(),
            map_frame: "map".into(),
            odom_frame: "odom".into(),
            odometry_tf: false,
            extrinsics_from_tf: false,
            tf_timeout: 10.0,
            backends: BackendSettings::default(),
            fleet: FleetSettings::default(),
        }
    }
}

/// One of the node's own parameters: its name and what it does (the reference lists it).
pub struct NodeParam {
    /// Dotted name.
    pub name: &'static str,
    /// What it does, its unit and why.
    pub doc: &'static str,
}

/// The node's own parameters, documented.
pub const NODE_PARAMS: &[NodeParam] = &[
    NodeParam {
        name: "use_sim_time",
        doc: "Stamp outputs with `/clock` (rosgraph_msgs/Clock) time instead of the system clock.",
    },
    NodeParam {
        name: "node.queue_size",
        doc: "Messages waiting between DDS reception and the worker; a full queue drops new messages \
              (`reception_queue_full`).",
    },
    NodeParam {
        name: "node.diagnostics_period",
        doc: "Seconds between `/diagnostics` messages.",
    },
    NodeParam {
        name: "node.max_cloud_points",
        doc: "Clouds with more points (width x height), and `radar_msgs/RadarScan`s with more returns, \
              are refused (`cloud_too_large`), here and in `dc_loc run`.",
    },
    NodeParam {
        name: "node.max_cloud_bytes",
        doc: "Clouds with more data bytes (a `radar_msgs/RadarScan`: 20 bytes a return) are refused \
              (`cloud_too_large`), here and in `dc_loc run`: with the point count, the decoder's memory \
              stays bounded whatever a cloud claims.",
    },
    NodeParam {
        name: "node.warn_interval",
        doc: "Seconds between two warnings of one kind of message refused at reception (the \
              suppressed ones are counted in the next); an input the pipeline drops is logged once \
              per cause.",
    },
    NodeParam {
        name: "node.sync_timeout",
        doc: "Longest wait, s (wall time), for the other inputs to reach a message's stamp before it is \
              processed anyway (inputs are processed in stamp order, as `dc_loc run` reads a bag).",
    },
    NodeParam {
        name: "node.restart_after",
        doc: "Consecutive inputs whose stamps are out of line with the newest input (more than 1 s \
              back or 10 s ahead) that mean a restart or a jump (bag replayed again, simulator reset, \
              a long outage) rather than bad stamps; the ones before are dropped and counted.",
    },
    NodeParam {
        name: "node.shutdown_timeout",
        doc: "Seconds the worker may take at SIGINT/SIGTERM to process what is queued, after saving \
              the map first; what is left then is dropped, so that a supervisor's kill timeout never \
              ends the process before the map is saved.",
    },
    NodeParam {
        name: "node.keyframe_budget",
        doc: "Longest time, s, from an input's arrival to the end of the revisit search it sets off \
              (0, the default: no limit, as `dc_loc run`). Past it the search leaves work out, in this \
              order: the searches again of older keyframes (they stay queued), the rounds of candidates \
              after the first, and, when the time had passed before the search began, every candidate \
              but the best-ranked one. What was left out is counted in `/diagnostics` (`budget.*`), as \
              are keyframes finished late all the same. A budget makes the closures depend on the \
              machine's speed.",
    },
    NodeParam {
        name: "node.markers_period",
        doc: "Shortest time, s, between two `~/markers` messages: keyframes and closures that come \
              sooner are sent with the next one, so the markers cost a bounded share of the worker \
              however large the map (each message holds the whole session, transient local for late \
              subscribers).",
    },
    NodeParam {
        name: "node.log_level",
        doc: "dc_loc's own log level, on stderr and `/rosout`: `debug`, `info`, `warn` or `error`; \
              empty keeps the start-up level (`--log-level`, `RUST_LOG`). Changes at run time.",
    },
    NodeParam {
        name: "node.map_frame",
        doc: "Frame id of the `~/relocalized` poses: the odometry frame of the earlier session (the \
              loaded map) the robot was found in.",
    },
    NodeParam {
        name: "node.odom_frame",
        doc: "Frame id of the radar odometry on `~/odometry` (`odometry.source: radar | radar_imu`) \
              and of the keyframe poses on `~/markers` and in the back-end outputs; with \
              `odometry.source: topic` the odometry messages' own `header.frame_id` replaces it.",
    },
    NodeParam {
        name: "node.odometry_tf",
        doc: "Broadcast the radar odometry (`odometry.source: radar | radar_imu`) as the transform \
              `node.odom_frame -> body_frame` on `/tf`, one per sample. Off by default: most robots \
              already have a node publishing that transform, and two publishers of one transform \
              make tf2 jump between them.",
    },
    NodeParam {
        name: "node.extrinsics_from_tf",
        doc: "Take each radar's extrinsic from `/tf_static` (the transform from `body_frame` to the \
              radar's `frame_id`, published by robot_state_publisher or a static_transform_publisher) \
              instead of `radars.<name>.extrinsic`: the node waits for them at start, before it \
              subscribes to the radars, and stops (exit 1, naming the missing frames) when they do not \
              come within `node.tf_timeout`. Radars without a `frame_id` keep their parameter.",
    },
    NodeParam {
        name: "node.tf_timeout",
        doc: "Longest wait, s, for the `/tf_static` extrinsics (`node.extrinsics_from_tf`).",
    },
    NodeParam {
        name: "node.robot_id",
        doc: "The robot's identity in a fleet and in multi-robot back ends: its keyframes on the fleet \
              topic and its closures carry it (`robot_id`, `query_robot`, `match_robot`), each robot \
              numbers its own keyframes 0, 1, 2, ..., and the `pose_graph_tools_msgs` nodes and edges \
              carry it (`robot_id`, `robot_from`, `robot_to`: Kimera-Multi maps it to its key prefix). \
              Give every robot of a fleet its own.",
    },
    NodeParam {
        name: "node.fleet",
        doc: "Share keyframes with the other robots' nodes of a fleet: publish each keyframe as \
              `dc_loc/msg/Keyframe` on `node.fleet_topic`, take the other robots' (told apart by \
              `node.robot_id`) into the map and close loops between robots (README_NODE.md, Fleets).",
    },
    NodeParam {
        name: "node.fleet_topic",
        doc: "Topic the fleet's keyframes share (reliable, transient local, keep last \
              `node.fleet_history`); absolute, so that nodes in different namespaces meet.",
    },
    NodeParam {
        name: "node.fleet_history",
        doc: "Keyframes the fleet topic keeps per node for a robot's node that starts late (and the \
              burst taken from one robot before `node.fleet_rate` applies).",
    },
    NodeParam {
        name: "node.fleet_points",
        doc: "Most points sent per keyframe (an even subsample; 8 bytes a point): 2000 keep a \
              keyframe under 16 KiB on the wire.",
    },
    NodeParam {
        name: "node.fleet_rate",
        doc: "Keyframes per second taken from one robot beyond a burst of `node.fleet_history`; more \
              are dropped and counted under that robot (`/diagnostics`, `fleet`): a robot that floods \
              the topic cannot starve the node.",
    },
    NodeParam {
        name: "node.fleet_enclave",
        doc: "On a secured domain, the enclave each robot's keyframes must come from, `{robot}` \
              standing for its `node.robot_id` (e.g. `/fleet/robot_{robot}`): a keyframe is taken \
              only from a participant that authenticated with that enclave's certificate (its common \
              name), others are dropped as `keyframe_identity`. Empty (default): any member of the \
              keystore allowed to publish on the fleet topic may send any robot's keyframes.",
    },
    NodeParam {
        name: "node.pose_graph_output",
        doc: "Publish each closure also as a `pose_graph_tools_msgs/PoseGraph` (MIT-SPARK's \
              definition) on `node.pose_graph_topic`: one LOOPCLOSE edge from the match keyframe to \
              the query keyframe (`pose` the query in the match frame, `covariance` as the closure's) \
              and the two keyframes as nodes (README_NODE.md, Back ends). Off by default: the message \
              package must be installed where it is read.",
    },
    NodeParam {
        name: "node.pose_graph_topic",
        doc: "Topic of the `pose_graph_tools_msgs/PoseGraph` output (reliable, transient local, keep \
              last 100, as `~/loop_closures`).",
    },
    NodeParam {
        name: "node.lio_sam_output",
        doc: "Publish each closure also as LIO-SAM's external loop input, a \
              `std_msgs/Float64MultiArray` holding the query and the match keyframe stamps in seconds, \
              on `node.lio_sam_topic`; LIO-SAM registers the pair itself. Off by default.",
    },
    NodeParam {
        name: "node.lio_sam_topic",
        doc: "Topic of the LIO-SAM output (reliable, volatile, keep last 100). The default is the \
              relative name LIO-SAM's map optimisation subscribes to, so both meet when they run in \
              one namespace.",
    },
];

/// The log levels `node.log_level` takes.
pub const LOG_LEVELS: [&str; 5] = ["", "debug", "info", "warn", "error"];

impl NodeSettings {
    /// `node.log_level` as a filter (`None` when empty).
    pub fn log_filter(&self) -> Option<log::LevelFilter> {
        match self.log_level.as_str() {
            "debug" => Some(log::LevelFilter::Debug),
            "info" => Some(log::LevelFilter::Info),
            "warn" => Some(log::LevelFilter::Warn),
            "error" => Some(log::LevelFilter::Error),
            _ => None,
        }
    }

    /// The settings as `(name, value)` parameters.
    pub fn as_params(&self) -> Vec<(String, Value)> {
        vec![
            ("use_sim_time".into(), Value::Bool(self.use_sim_time)),
            ("node.queue_size".into(), Value::from(self.queue_size)),
            (
                "node.diagnostics_period".into(),
                Value::from(self.diagnostics_period),
            ),
            (
                "node.max_cloud_points".into(),
                Value::from(self.limits.max_cloud_points),
            ),
            (
                "node.max_cloud_bytes".into(),
                Value::from(self.limits.max_cloud_bytes),
            ),
            ("node.warn_interval".into(), Value::from(self.warn_interval)),
            ("node.sync_timeout".into(), Value::from(self.sync_timeout)),
            ("node.restart_after".into(), Value::from(self.restart_after)),
            (
                "node.shutdown_timeout".into(),
                Value::from(self.shutdown_timeout),
            ),
            (
                "node.markers_period".into(),
                Value::from(self.markers_period),
            ),
            (
                "node.keyframe_budget".into(),
                Value::from(self.keyframe_budget),
            ),
            ("node.log_level".into(), Value::from(self.log_level.clone())),
            ("node.map_frame".into(), Value::from(self.map_frame.clone())),
            (
                "node.odom_frame".into(),
                Value::from(self.odom_frame.clone()),
            ),
            ("node.odometry_tf".into(), Value::Bool(self.odometry_tf)),
            (
                "node.extrinsics_from_tf".into(),
                Value::Bool(self.extrinsics_from_tf),
            ),
            ("node.tf_timeout".into(), Value::from(self.tf_timeout)),
            ("node.robot_id".into(), Value::from(self.backends.robot_id)),
            (
                "node.pose_graph_output".into(),
                Value::Bool(self.backends.pose_graph_output),
            ),
            (
                "node.pose_graph_topic".into(),
                Value::from(self.backends.pose_graph_topic.clone()),
            ),
            (
                "node.lio_sam_output".into(),
                Value::Bool(self.backends.lio_sam_output),
            ),
            (
                "node.lio_sam_topic".into(),
                Value::from(self.backends.lio_sam_topic.clone()),
            ),
        ]
        .into_iter()
        .chain(self.fleet.as_params())
        .collect()
    }

    /// Declares each setting's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.count("node.queue_size", self.queue_size, 1, 1_000_000);
        v.range(
            "node.diagnostics_period",
            self.diagnostics_period,
            Range::POSITIVE.up_to(3600.0),
        );
        v.count(
            "node.max_cloud_points",
            self.limits.max_cloud_points,
            1,
            10_000_000,
        );
        v.count(
            "node.max_cloud_bytes",
            self.limits.max_cloud_bytes,
            1,
            1 << 30,
        );
        v.range(
            "node.warn_interval",
            self.warn_interval,
            Range::POSITIVE.up_to(86_400.0),
        );
        v.range(
            "node.sync_timeout",
            self.sync_timeout,
            Range::POSITIVE.up_to(60.0),
        );
        v.count("node.restart_after", self.restart_after, 1, 100_000);
        v.range(
            "node.shutdown_timeout",
            self.shutdown_timeout,
            Range::POSITIVE.up_to(600.0),
        );
        v.range(
            "node.markers_period",
            self.markers_period,
            Range::POSITIVE.up_to(3600.0),
        );
        v.range(
            "node.keyframe_budget",
            self.keyframe_budget,
            Range::NON_NEGATIVE.up_to(3600.0),
        );
        v.range(
            "node.tf_timeout",
            self.tf_timeout,
            Range::POSITIVE.up_to(3600.0),
        );
        v.require("node.map_frame", !self.map_frame.is_empty(), || {
            "must not be empty".into()
        });
        v.require("node.odom_frame", !self.odom_frame.is_empty(), || {
            "must not be empty".into()
        });
        v.require(
            "node.log_level",
            LOG_LEVELS.contains(&self.log_level.as_str()),
            || {
                format!(
                    "`{}` must be one of debug, info, warn, error or empty",
                    self.log_level
                )
            },
        );
        self.backends.check(v);
        self.fleet.check(v);
    }

    /// Splits the node's own parameters off `params` and checks their ranges; the rest go to
    /// [`crate::params::apply`].
    pub fn take_from(params: &ParamSet) -> Result<(Self, ParamSet), ParamError> {
        let mut s = NodeSettings::default();
        let mut rest = ParamSet::default();
        for (name, v) in params.entries() {
            match name.as_str() {
                "use_sim_time" => {
                    s.use_sim_time = v
                        .as_bool()
                        .ok_or_else(|| type_error(name, "a boolean", v))?
                }
                "node.queue_size" => s.queue_size = count(name, v)?,
                "node.max_cloud_points" => s.limits.max_cloud_points = count(name, v)?,
                "node.max_cloud_bytes" => s.limits.max_cloud_bytes = count(name, v)?,
                "node.restart_after" => s.restart_after = count(name, v)?,
                "node.diagnostics_period" => s.diagnostics_period = number(name, v)?,
                "node.warn_interval" => s.warn_interval = number(name, v)?,
                "node.sync_timeout" => s.sync_timeout = number(name, v)?,
                "node.shutdown_timeout" => s.shutdown_timeout = number(name, v)?,
                "node.markers_period" => s.markers_period = number(name, v)?,
                "node.keyframe_budget" => s.keyframe_budget = number(name, v)?,
                "node.tf_timeout" => s.tf_timeout = number(name, v)?,
                "node.extrinsics_from_tf" => {
                    s.extrinsics_from_tf = v
                        .as_bool()
                        .ok_or_else(|| type_error(name, "a boolean", v))?
                }
                "node.odometry_tf" => {
                    s.odometry_tf = v
                        .as_bool()
                        .ok_or_else(|| type_error(name, "a boolean", v))?
                }
                "node.odom_frame" => {
                    s.odom_frame = v
                        .as_str()
                        .ok_or_else(|| type_error(name, "a string", v))?
                        .to_string()
                }
                "node.map_frame" => {
                    s.map_frame = v
                        .as_str()
                        .ok_or_else(|| type_error(name, "a string", v))?
                        .to_string()
                }
                "node.log_level" => {
                    s.log_level = v
                        .as_str()
                        .ok_or_else(|| type_error(name, "a string", v))?
                        .to_string()
                }
                n if n.starts_with("node.") => {
                    if !s.backends.take(name, v)? && !s.fleet.take(name, v)? {
                        return Err(ParamError::Unknown(name.clone()));
                    }
                }
                _ => rest.set(name.clone(), v.clone()),
            }
        }
        let mut v = Validator::new();
        s.check(&mut v);
        v.finish()?;
        Ok((s, rest))
    }
}

impl BackendSettings {
    /// Declares each setting's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.range(
            "node.robot_id",
            self.robot_id as f64,
            Range::closed(0.0, f64::from(i32::MAX)),
        );
        for (name, topic) in [
            ("node.pose_graph_topic", &self.pose_graph_topic),
            ("node.lio_sam_topic", &self.lio_sam_topic),
        ] {
            v.require(name, topic_name_ok(topic), || {
                format!(
                    "`{topic}` is not a topic name: letters, digits, `_` and `/` separators, \
                     optionally `~/` first, no empty or digit-first part"
                )
            });
        }
    }

    /// Takes `name` when it is one of these settings (`Ok(false)` when it is not).
    fn take(&mut self, name: &str, v: &Value) -> Result<bool, ParamError> {
        let text = || {
            v.as_str()
                .map(str::to_string)
                .ok_or_else(|| type_error(name, "a string", v))
        };
        let flag = || v.as_bool().ok_or_else(|| type_error(name, "a boolean", v));
        match name {
            "node.robot_id" => {
                // Beyond i64 it is refused by the range check like any other value out of range.
                self.robot_id = v
                    .as_i64()
                    .or_else(|| v.as_u64().map(|_| i64::MAX))
                    .ok_or_else(|| type_error(name, "an integer", v))?;
            }
            "node.pose_graph_output" => self.pose_graph_output = flag()?,
            "node.pose_graph_topic" => self.pose_graph_topic = text()?,
            "node.lio_sam_output" => self.lio_sam_output = flag()?,
            "node.lio_sam_topic" => self.lio_sam_topic = text()?,
            _ => return Ok(false),
        }
        Ok(true)
    }
}

/// A ROS 2 topic name as rcl accepts it before expansion: absolute (`/a/b`), relative (`a/b`) or
/// private (`~/a`, `~`); each part non-empty, of letters, digits and `_`, not starting with a digit.
fn topic_name_ok(name: &str) -> bool {
    let rest = if name == "~" {
        return true;
    } else if let Some(r) = name.strip_prefix("~/") {
        r
    } else {
        name.strip_prefix('/').unwrap_or(name)
    };
    !rest.is_empty()
        && rest.split('/').all(|part| {
            part.chars()
                .next()
                .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
                && part.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        })
}

fn type_error(name: &str, expected: &'static str, v: &Value) -> ParamError {
    ParamError::Type {
        name: name.to_string(),
        expected,
        got: v.to_string(),
    }
}

/// A non-negative integer (its range is checked with the others).
fn count(name: &str, v: &Value) -> Result<usize, ParamError> {
    v.as_u64()
        .map(|n| usize::try_from(n).unwrap_or(usize::MAX))
        .ok_or_else(|| type_error(name, "a non-negative integer", v))
}

/// A number (its range is checked with the others).
fn number(name: &str, v: &Value) -> Result<f64, ParamError> {
    v.as_f64().ok_or_else(|| type_error(name, "a number", v))
}

/// Every parameter of the node (the pipeline's and the node's own), sorted by name.
pub fn all_params(cfg: &Config, settings: &NodeSettings) -> Vec<(String, Value)> {
    let mut all = flatten_config(cfg);
    all.extend(settings.as_params());
    all.sort_by(|a, b| a.0.cmp(&b.0));
    all
}

/// The effective configuration, one `name: value` per line.
pub fn describe(cfg: &Config, settings: &NodeSettings) -> String {
    all_params(cfg, settings)
        .iter()
        .map(|(n, v)| format!("  {n}: {v}"))
        .collect::<Vec<_>>()
        .join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_settings_split_and_checked() {
        let mut set = ParamSet::default();
        set.set_override("node.queue_size:=10").unwrap();
        set.set_override("use_sim_time:=true").unwrap();
        set.set_override("submap.size:=4").unwrap();
        let (s, rest) = NodeSettings::take_from(&set).unwrap();
        assert_eq!(s.queue_size, 10);
        assert!(s.use_sim_time);
        assert_eq!(rest.entries().len(), 1);
        let mut bad = ParamSet::default();
        bad.set_override("node.queue_size:=0").unwrap();
        assert!(
            matches!(NodeSettings::take_from(&bad), Err(ParamError::Invalid(e)) if e.name == "node.queue_size")
        );
        // Every node setting refuses absurd values with its name (never a panic or an allocation).
        for (name, value) in NodeSettings::default().as_params() {
            if !name.starts_with("node.") {
                continue;
            }
            let huge = if value.is_f64() {
                "1e20"
            } else {
                "18446744073709551615"
            };
            let mut bad = ParamSet::default();
            bad.set_override(&format!("{name}:={huge}")).unwrap();
            let refused = match NodeSettings::take_from(&bad) {
                Err(ParamError::Invalid(e)) => e.name == name,
                Err(ParamError::Type { name: n, .. }) => n == name,
                _ => false,
            };
            assert!(refused, "{name}:={huge} accepted");
        }
        let mut bad = ParamSet::default();
        bad.set_override("node.queue:=3").unwrap();
        assert_eq!(
            NodeSettings::take_from(&bad).err(),
            Some(ParamError::Unknown("node.queue".into()))
        );
        let mut bad = ParamSet::default();
        bad.set_override("use_sim_time:=1").unwrap();
        assert!(matches!(
            NodeSettings::take_from(&bad),
            Err(ParamError::Type { .. })
        ));
    }

    #[test]
    fn backend_outputs_are_off_by_default_and_checked() {
        let b = NodeSettings::default().backends;
        assert!(!b.pose_graph_output && !b.lio_sam_output);
        assert_eq!(b.robot_id, 0);
        assert_eq!(b.lio_sam_topic, "lio_loop/loop_closure_detection");
        let mut set = ParamSet::default();
        for o in [
            "node.robot_id:=3",
            "node.pose_graph_output:=true",
            "node.pose_graph_topic:=/kimera/loop_closures",
            "node.lio_sam_output:=true",
            "node.lio_sam_topic:=~/lio",
        ] {
            set.set_override(o).unwrap();
        }
        let (s, _) = NodeSettings::take_from(&set).unwrap();
        assert_eq!(s.backends.robot_id, 3);
        assert!(s.backends.pose_graph_output && s.backends.lio_sam_output);
        assert_eq!(s.backends.pose_graph_topic, "/kimera/loop_closures");
        assert_eq!(s.backends.lio_sam_topic, "~/lio");
        for (bad, name) in [
            ("node.robot_id:=-1", "node.robot_id"),
            ("node.robot_id:=2147483648", "node.robot_id"),
            ("node.pose_graph_topic:=''", "node.pose_graph_topic"),
            ("node.pose_graph_topic:=a//b", "node.pose_graph_topic"),
            ("node.lio_sam_topic:=/1loop", "node.lio_sam_topic"),
            ("node.lio_sam_topic:=loop/", "node.lio_sam_topic"),
            ("node.lio_sam_topic:=lo-op", "node.lio_sam_topic"),
        ] {
            let mut set = ParamSet::default();
            set.set_override(bad).unwrap();
            let refused = matches!(
                NodeSettings::take_from(&set),
                Err(ParamError::Invalid(e)) if e.name == name
            );
            assert!(refused, "{bad} accepted");
        }
        let mut set = ParamSet::default();
        set.set_override("node.pose_graph_output:=1").unwrap();
        assert!(matches!(
            NodeSettings::take_from(&set),
            Err(ParamError::Type { .. })
        ));
    }
}
