//! The node's DDS endpoints with their QoS: the input subscriptions and the reception loop over them
//! ([`Subscriptions`]), the publishers the worker owns ([`Outputs`], with the radar odometry's
//! outputs and the optional back-end outputs of `node.pose_graph_output` and `node.lio_sam_output`)
//! and the service servers.

use std::sync::Mutex;
use std::sync::mpsc::SyncSender;
use std::time::Duration;

use ros2_client::dds::rustdds::DomainParticipant;
use ros2_client::{
    MessageTypeName, Name, Node, Publisher, QosProfile, Server, ServiceMapping, ServiceTypeName,
    Subscription,
    qos::{Durability, History, Reliability, WhenFull},
};
use serde::de::DeserializeOwned;

use super::args::RosArgs;
use super::backends::{Float64MultiArray, PoseGraph};
use super::convert::{DiagnosticArray, MarkerArray};
use super::error::{NodeError, dds};
use super::fleet_identity::FleetIdentity;
use super::inputs::{self, RadarSubscription, Reception, TopicRadars};
use super::services::{
    self, PoseWithCovarianceStamped, SaveRequest, TriggerRequest, TriggerResponse,
};
use dc_loc_core::input::InputLimits;
use dc_loc_core::msgs::dc_loc::{Keyframe as KeyframeMsg, LoopClosure as LoopClosureMsg};
use dc_loc_core::msgs::nav_msgs::Odometry;
use dc_loc_core::msgs::rosgraph_msgs::Clock;
use dc_loc_core::msgs::sensor_msgs::{Imu, PointCloud2};
use dc_loc_core::msgs::std_msgs::Header;
use dc_loc_core::msgs::tf2_msgs::TFMessage;
use dc_loc_core::odometry::OdometrySource;
use dc_loc_core::pipeline::Config;
use dc_loc_core::radar::RadarMessage;
use dc_loc_core::radar::trigger::TriggerStamps;
use dc_loc_io::params::node::{FleetSettings, NodeSettings};

/// The node's publishers, owned by the worker thread.
pub struct Outputs {
    /// `~/loop_closures`.
    pub closures: Publisher<LoopClosureMsg>,
    /// `~/markers`.
    pub markers: Publisher<MarkerArray>,
    /// `~/submap`.
    pub submap: Publisher<PointCloud2>,
    /// `/diagnostics`.
    pub diagnostics: Publisher<DiagnosticArray>,
    /// `~/relocalized`.
    pub relocalized: Publisher<PoseWithCovarianceStamped>,
    /// `node.pose_graph_topic`, when `node.pose_graph_output` is on.
    pub pose_graph: Option<Publisher<PoseGraph>>,
    /// `node.lio_sam_topic`, when `node.lio_sam_output` is on.
    pub lio_sam: Option<Publisher<Float64MultiArray>>,
    /// `node.fleet_topic`, when `node.fleet` is on.
    pub keyframes: Option<Publisher<KeyframeMsg>>,
    /// `~/odometry`, when the odometry comes from the radars (`odometry.source: radar | radar_imu`).
    pub odometry: Option<Publisher<Odometry>>,
    /// `/tf`, when the radar odometry is also broadcast as a transform (`node.odometry_tf`).
    pub tf: Option<Publisher<TFMessage>>,
}

/// A trigger topic, the radars (indices in `radar_names`) it triggers, and its subscription.
type TriggerSubscription = (String, Vec<usize>, Subscription<Header>);

/// The node's input subscriptions.
pub struct Subscriptions {
    /// Per radar topic (several radars may share one; the frame id tells them apart).
    radars: Vec<(String, TopicRadars, RadarSubscription)>,
    /// `odometry.topic`, with `odometry.source: topic`.
    odometry: Option<(String, Subscription<Odometry>)>,
    /// `imu.topic`, with `odometry.source: radar_imu`.
    imu: Option<(String, Subscription<Imu>)>,
    /// Per trigger topic (`radars.<name>.trigger_topic`): the radars it triggers.
    triggers: Vec<TriggerSubscription>,
    /// The radars' newest triggers, which their scans take their stamps from.
    trigger_stamps: Mutex<TriggerStamps>,
    clock: Option<Subscription<Clock>>,
    /// `~/save_map`.
    save_map: Server<TriggerRequest, TriggerResponse>,
    /// `~/markers` and `~/submap`, resolved: their readers are counted.
    map_views: [String; 2],
    /// `node.fleet_topic`, when `node.fleet` is on: the other robots' keyframes, and the check of their
    /// senders' identities (`node.fleet_enclave`).
    keyframes: Option<FleetSubscription>,
}

/// The fleet topic, its subscription, the fleet settings and the check of the senders' identities.
type FleetSubscription = (
    String,
    Subscription<KeyframeMsg>,
    FleetSettings,
    Option<FleetIdentity>,
);

impl Subscriptions {
    /// Subscribes the radars (one subscription per topic), the pose input of `odometry.source` (the
    /// odometry topic, nothing, or the gyro), with sim time `/clock`, and with `node.fleet` the
    /// fleet's keyframes (their senders' identities read from `secured`, the node's participant when
    /// the domain is secured).
    pub fn new(
        node: &mut Node,
        ros_args: &RosArgs,
        cfg: &Config,
        settings: &NodeSettings,
        secured: Option<DomainParticipant>,
    ) -> Result<Self, NodeError> {
        let use_sim_time = settings.use_sim_time;
        // The radars sharing a topic share its message type (the configuration's check).
        let mut by_topic: std::collections::BTreeMap<String, (RadarMessage, TopicRadars)> =
            Default::default();
        for (i, (name, rc)) in cfg.radar_list().into_iter().enumerate() {
            by_topic
                .entry(ros_args.resolve_topic(&rc.topic))
                .or_insert_with(|| (rc.message, Vec::new()))
                .1
                .push((i, name.to_string(), rc.frame_id.clone()));
        }
        let mut radars = Vec::new();
        for (topic, (message, topic_radars)) in by_topic {
            let sub = match message {
                RadarMessage::PointCloud2 => RadarSubscription::Cloud(subscribe(
                    node,
                    &topic,
                    "sensor_msgs",
                    "PointCloud2",
                    INPUT_DEPTH,
                )?),
                RadarMessage::RadarScan => RadarSubscription::Scan(subscribe(
                    node,
                    &topic,
                    "radar_msgs",
                    "RadarScan",
                    INPUT_DEPTH,
                )?),
            };
            let names: Vec<&str> = topic_radars.iter().map(|r| r.1.as_str()).collect();
            log::info!("radar {} on {topic} ({message:?})", names.join(", "));
            radars.push((topic, topic_radars, sub));
        }
        let (odometry, imu) = pose_input(node, ros_args, cfg)?;
        let triggers = trigger_subscriptions(node, ros_args, cfg)?;
        let clock = if use_sim_time {
            Some(subscribe(node, "/clock", "rosgraph_msgs", "Clock", 10)?)
        } else {
            None
        };
        let save_map = node
            .create_server(
                ServiceMapping::Enhanced,
                &topic_name(&ros_args.resolve_topic("~/save_map"))?,
                &ServiceTypeName::new("std_srvs", "Trigger"),
                reliable(10, Durability::Volatile),
                reliable(10, Durability::Volatile),
            )
            .map_err(dds("~/save_map service"))?;
        let keyframes = if settings.fleet.enabled {
            let fleet = &settings.fleet;
            let topic = ros_args.resolve_topic(&fleet.topic);
            let qos = reliable(fleet.history, Durability::TransientLocal);
            let t = node
                .create_topic(
                    &topic_name(&topic)?,
                    MessageTypeName::new("dc_loc", "Keyframe"),
                    &qos,
                )
                .map_err(dds("fleet topic"))?;
            let sub = node
                .create_subscription(&t, Some(qos))
                .map_err(dds("fleet subscription"))?;
            log::info!("other robots' keyframes on {topic}");
            let identity = FleetIdentity::new(&fleet.enclave, secured);
            Some((topic, sub, fleet.clone(), identity))
        } else {
            None
        };
        Ok(Subscriptions {
            radars,
            odometry,
            imu,
            triggers,
            trigger_stamps: Mutex::new(TriggerStamps::new(cfg.trigger_delays())),
            clock,
            keyframes,
            save_map,
            map_views: [
                ros_args.resolve_topic("~/markers"),
                ros_args.resolve_topic("~/submap"),
            ],
        })
    }

    /// Runs every reception task until `stop` completes; `Some(cause)` when the node cannot go on (a
    /// task or the worker ended first).
    pub async fn receive(
        &self,
        node: &Node,
        r: Reception,
        limits: InputLimits,
        mut stop: tokio::sync::mpsc::Receiver<()>,
        worker_done: tokio::sync::oneshot::Receiver<()>,
        save_requests: SyncSender<SaveRequest>,
    ) -> Option<String> {
        let mut tasks: Vec<futures::future::BoxFuture<'_, ()>> = Vec::new();
        let stamps = &self.trigger_stamps;
        for (topic, radars, sub) in &self.radars {
            let shared = r.shared.clone();
            match sub {
                RadarSubscription::Cloud(sub) => tasks.push(Box::pin(inputs::take(
                    topic,
                    sub,
                    r.clone(),
                    move |c, _| {
                        let input = inputs::radar_input(topic, radars, &limits, &shared, c);
                        inputs::trigger_stamped(topic, stamps, input)
                    },
                ))),
                RadarSubscription::Scan(sub) => tasks.push(Box::pin(inputs::take(
                    topic,
                    sub,
                    r.clone(),
                    move |s, _| {
                        let input = inputs::radar_scan(topic, radars, &limits, &shared, s);
                        inputs::trigger_stamped(topic, stamps, input)
                    },
                ))),
            }
        }
        for (topic, radars, sub) in &self.triggers {
            tasks.push(Box::pin(inputs::triggers(
                topic,
                sub,
                radars,
                stamps,
                r.clone(),
            )));
        }
        if let Some((topic, sub)) = &self.odometry {
            let shared = r.shared.clone();
            tasks.push(Box::pin(inputs::take(
                topic,
                sub,
                r.clone(),
                move |o, _| inputs::odometry_input(topic, &shared, o),
            )));
        }
        if let Some((topic, sub)) = &self.imu {
            let shared = r.shared.clone();
            tasks.push(Box::pin(inputs::take(
                topic,
                sub,
                r.clone(),
                move |m, _| inputs::imu_input(topic, &shared, m),
            )));
        }
        if let Some(sub) = &self.clock {
            tasks.push(Box::pin(inputs::clock(sub, r.shared.clone())));
        }
        if let Some((topic, sub, fleet, identity)) = &self.keyframes {
            let shared = r.shared.clone();
            let mut gate = inputs::FleetGate::new(fleet);
            tasks.push(Box::pin(inputs::take(
                topic,
                sub,
                r.clone(),
                move |k, info| {
                    inputs::keyframe_input(topic, &mut gate, identity.as_ref(), &shared, (k, info))
                },
            )));
        }
        let counts = inputs::publisher_counts(
            node,
            &self.radars,
            inputs::PoseSubscriptions {
                odometry: self.odometry.as_ref().map(|(t, s)| (t.as_str(), s)),
                imu: self.imu.as_ref().map(|(t, s)| (t.as_str(), s)),
            },
            &self.map_views,
            r.shared,
        );
        tasks.push(Box::pin(counts));
        tasks.push(Box::pin(services::save_map(&self.save_map, save_requests)));
        // Every task runs as long as the node: the first to end is a failure.
        let any_ended = futures::future::select_all(tasks);
        let failure = async {
            futures::future::select(any_ended, worker_done).await;
            log::error!("a task the node needs ended: stopping");
        };
        let stopped = async {
            let _ = stop.recv().await;
        };
        match futures::future::select(Box::pin(stopped), Box::pin(failure)).await {
            futures::future::Either::Left(_) => None,
            futures::future::Either::Right(_) => {
                Some("a reception task or the worker ended unexpectedly".into())
            }
        }
    }
}

/// One `std_msgs/Header` subscription per trigger topic (`radars.<name>.trigger_topic`), with the
/// radars (indices in `radar_names`) it triggers, with the radars' QoS.
fn trigger_subscriptions(
    node: &mut Node,
    ros_args: &RosArgs,
    cfg: &Config,
) -> Result<Vec<TriggerSubscription>, NodeError> {
    let mut by_topic: std::collections::BTreeMap<String, Vec<usize>> = Default::default();
    for (i, (_, rc)) in cfg.radar_list().into_iter().enumerate() {
        if !rc.trigger_topic.is_empty() {
            by_topic
                .entry(ros_args.resolve_topic(&rc.trigger_topic))
                .or_default()
                .push(i);
        }
    }
    let mut subs = Vec::new();
    for (topic, radars) in by_topic {
        let sub = subscribe(node, &topic, "std_msgs", "Header", INPUT_DEPTH)?;
        log::info!("radar triggers on {topic}");
        subs.push((topic, radars, sub));
    }
    Ok(subs)
}

/// The pose input `odometry.source` asks for: `nav_msgs/Odometry` on `odometry.topic` (`topic`), none
/// (`radar`: the radars make the odometry, so no `/odom` is needed), or the `sensor_msgs/Imu` gyro on
/// `imu.topic` (`radar_imu`). Both with the radars' QoS ([`sensor_qos`]).
#[allow(clippy::type_complexity)]
fn pose_input(
    node: &mut Node,
    ros_args: &RosArgs,
    cfg: &Config,
) -> Result<
    (
        Option<(String, Subscription<Odometry>)>,
        Option<(String, Subscription<Imu>)>,
    ),
    NodeError,
> {
    match cfg.odometry.source {
        OdometrySource::Topic => {
            let topic = ros_args.resolve_topic(&cfg.odometry.topic);
            let sub = subscribe(node, &topic, "nav_msgs", "Odometry", INPUT_DEPTH)?;
            log::info!("odometry on {topic}");
            Ok((Some((topic, sub)), None))
        }
        OdometrySource::Radar => {
            log::info!("odometry from the radars' Doppler: no odometry topic read");
            Ok((None, None))
        }
        OdometrySource::RadarImu => {
            let topic = ros_args.resolve_topic(&cfg.imu.topic);
            let sub = subscribe(node, &topic, "sensor_msgs", "Imu", INPUT_DEPTH)?;
            log::info!("odometry from the radars' Doppler and the gyro on {topic}");
            Ok((None, Some((topic, sub))))
        }
    }
}

/// DDS reader history of each input: deep enough that a busy executor never makes the reader discard
/// a sample (about 8 s of 5 radars at 13 Hz, 40 s of odometry at 25 Hz, 10 s of a 100 Hz gyro).
const INPUT_DEPTH: usize = 1000;

/// Best-effort, volatile, keep-last: matches reliable and best-effort publishers alike.
fn sensor_qos(depth: usize) -> QosProfile {
    QosProfile::subscription_default()
        .reliability(Reliability::BestEffort)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth })
}

fn reliable(depth: usize, durability: Durability) -> QosProfile {
    QosProfile::publisher_default()
        .reliability(Reliability::Reliable {
            when_full: WhenFull::Wait(Duration::from_millis(200)),
        })
        .durability(durability)
        .history(History::KeepLast { depth })
}

fn topic_name(resolved: &str) -> Result<Name, NodeError> {
    Name::parse(resolved).map_err(|e| NodeError::Dds(format!("topic name {resolved}: {e:?}")))
}

fn subscribe<M: DeserializeOwned + 'static>(
    node: &mut Node,
    topic: &str,
    package: &str,
    type_name: &str,
    depth: usize,
) -> Result<Subscription<M>, NodeError> {
    let qos = sensor_qos(depth);
    let t = node
        .create_topic(
            &topic_name(topic)?,
            MessageTypeName::new(package, type_name),
            &qos,
        )
        .map_err(dds("input topic"))?;
    node.create_subscription(&t, Some(qos))
        .map_err(dds("subscription"))
}

/// `/tf_static` (remappable) as tf2's listeners read it: reliable, transient local, keep last 100.
pub fn tf_static(
    node: &mut Node,
    ros_args: &RosArgs,
) -> Result<Subscription<TFMessage>, NodeError> {
    let qos = reliable(100, Durability::TransientLocal);
    let t = node
        .create_topic(
            &topic_name(&ros_args.resolve_topic("/tf_static"))?,
            MessageTypeName::new("tf2_msgs", "TFMessage"),
            &qos,
        )
        .map_err(dds("/tf_static topic"))?;
    node.create_subscription(&t, Some(qos))
        .map_err(dds("/tf_static subscription"))
}

/// The publishers, with the outputs the node's parameters (`ros_args`: files and `-p`) turn on; see
/// [`outputs_with`].
pub fn outputs(node: &mut Node, ros_args: &RosArgs, cfg: &Config) -> Result<Outputs, NodeError> {
    let (settings, _) = NodeSettings::take_from(&ros_args.param_set()?)?;
    let radar_odometry = cfg.odometry.source != OdometrySource::Topic;
    outputs_with(node, ros_args, &settings, radar_odometry)
}

/// The publishers: `~/loop_closures` (reliable, transient-local: a back end that starts late still
/// gets the history), `~/markers`, `~/submap`, `/diagnostics`, `~/relocalized`, and the back-end
/// outputs `settings` turns on: the `pose_graph_tools_msgs/PoseGraph` topic (QoS of
/// `~/loop_closures`), the LIO-SAM topic (reliable, volatile: LIO-SAM takes its pairs as they come) and
/// the fleet's keyframes (reliable, transient local, keep last `node.fleet_history`: a robot that
/// starts late gets the recent ones); with `radar_odometry`, `~/odometry` (reliable, volatile, keep
/// last 100: as an odometry driver publishes) and with `node.odometry_tf` also `/tf` (as tf2's
/// broadcaster: reliable, volatile, keep last 100).
pub fn outputs_with(
    node: &mut Node,
    ros_args: &RosArgs,
    settings: &NodeSettings,
    radar_odometry: bool,
) -> Result<Outputs, NodeError> {
    let backends = &settings.backends;
    let fleet = &settings.fleet;
    let odometry = if radar_odometry {
        Some(publisher(
            node,
            ros_args,
            "~/odometry",
            ("nav_msgs", "Odometry"),
            reliable(100, Durability::Volatile),
        )?)
    } else {
        None
    };
    let tf = if radar_odometry && settings.odometry_tf {
        Some(publisher(
            node,
            ros_args,
            "/tf",
            ("tf2_msgs", "TFMessage"),
            reliable(100, Durability::Volatile),
        )?)
    } else {
        None
    };
    Ok(Outputs {
        odometry,
        tf,
        closures: publisher(
            node,
            ros_args,
            "~/loop_closures",
            ("dc_loc", "LoopClosure"),
            reliable(100, Durability::TransientLocal),
        )?,
        markers: publisher(
            node,
            ros_args,
            "~/markers",
            ("visualization_msgs", "MarkerArray"),
            reliable(1, Durability::TransientLocal),
        )?,
        submap: publisher(
            node,
            ros_args,
            "~/submap",
            ("sensor_msgs", "PointCloud2"),
            reliable(1, Durability::Volatile),
        )?,
        diagnostics: publisher(
            node,
            ros_args,
            "/diagnostics",
            ("diagnostic_msgs", "DiagnosticArray"),
            reliable(10, Durability::Volatile),
        )?,
        relocalized: publisher(
            node,
            ros_args,
            "~/relocalized",
            ("geometry_msgs", "PoseWithCovarianceStamped"),
            reliable(1, Durability::TransientLocal),
        )?,
        pose_graph: if backends.pose_graph_output {
            Some(publisher(
                node,
                ros_args,
                &backends.pose_graph_topic,
                ("pose_graph_tools_msgs", "PoseGraph"),
                reliable(100, Durability::TransientLocal),
            )?)
        } else {
            None
        },
        keyframes: if fleet.enabled {
            Some(publisher(
                node,
                ros_args,
                &fleet.topic,
                ("dc_loc", "Keyframe"),
                reliable(fleet.history, Durability::TransientLocal),
            )?)
        } else {
            None
        },
        lio_sam: if backends.lio_sam_output {
            Some(publisher(
                node,
                ros_args,
                &backends.lio_sam_topic,
                ("std_msgs", "Float64MultiArray"),
                reliable(100, Durability::Volatile),
            )?)
        } else {
            None
        },
    })
}

/// A publisher of `package/msg/type_name` on the topic `name` resolves to.
fn publisher<M: serde::Serialize>(
    node: &mut Node,
    ros_args: &RosArgs,
    name: &str,
    (package, type_name): (&str, &str),
    qos: QosProfile,
) -> Result<Publisher<M>, NodeError> {
    let resolved = ros_args.resolve_topic(name);
    let t = node
        .create_topic(
            &topic_name(&resolved)?,
            MessageTypeName::new(package, type_name),
            &qos,
        )
        .map_err(dds("output topic"))?;
    log::info!("publishing {package}/msg/{type_name} on {resolved}");
    node.create_publisher(&t, Some(qos))
        .map_err(dds("publisher"))
}
