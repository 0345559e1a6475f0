//! The ROS 2 node: DDS reception on the executor, the [`Pipeline`] on a worker thread of its own.
//!
//! [`run`], in order: parse the command line and the environment ([`super::args`]) and the parameters
//! ([`crate::params`] plus the node's own, [`super::settings`]); load the keyframe map; make the DDS
//! participant (loopback only when `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`) and the node with every
//! parameter declared; subscribe the inputs and create the outputs; start the worker
//! ([`super::worker`]); then receive ([`super::inputs`]: one task per subscription, a bounded queue to
//! the worker) until SIGINT/SIGTERM, when the worker drains the queue (the last closures are
//! published), saves the map and ends; entities are dropped before the context.

use std::net::Ipv4Addr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use ros2_client::{
    Context, MessageTypeName, Name, Node, NodeName, NodeOptions, ParameterValue, QosProfile,
    Subscription,
    qos::{Durability, History, Reliability, WhenFull},
};
use serde::de::DeserializeOwned;
use serde_json::Value;

use super::args::{ArgsError, DdsEnv, DiscoveryRange, RosArgs};
use super::inputs::{self, Reception, TopicRadars};
use super::map_store::{LoadedMap, MapSaver, load_map};
use super::shared::{Inbox, Shared, Work};
use super::worker::{Outputs, Worker};
use crate::input::InputLimits;
use crate::keyframe_db::KeyframeDb;
use crate::keyframe_db::lock::MapLock;
use crate::msgs::nav_msgs::Odometry;
use crate::msgs::rosgraph_msgs::Clock;
use crate::msgs::sensor_msgs::PointCloud2;
use crate::params::live::LiveParams;
use crate::params::node::{NodeSettings, all_params, describe};
use crate::params::{ParamError, ParamSet, apply};
use crate::pipeline::{Config, Pipeline};

/// A failure of the node, with its exit code (2: usage or configuration, 1: runtime).
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// Command line or environment.
    #[error(transparent)]
    Args(#[from] ArgsError),
    /// Parameters.
    #[error(transparent)]
    Param(#[from] ParamError),
    /// The map file cannot be used.
    #[error("{0}")]
    Map(String),
    /// DDS could not be set up.
    #[error("DDS: {0}")]
    Dds(String),
    /// The node could not go on: a task it needs ended, or the map could not be saved at shutdown.
    #[error("{0}")]
    Runtime(String),
}

impl NodeError {
    fn exit_code(&self) -> i32 {
        match self {
            NodeError::Dds(_) | NodeError::Runtime(_) => 1,
            _ => 2,
        }
    }
}

fn dds<E: std::fmt::Debug>(what: &str) -> impl FnOnce(E) -> NodeError + '_ {
    move |e| NodeError::Dds(format!("{what}: {e:?}"))
}

/// Runs the node (`args` as from `std::env::args`); returns the process exit code.
pub fn main(args: &[String]) -> i32 {
    let ros_args = match RosArgs::parse(args) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("dc_loc: error: {e}");
            return 2;
        }
    };
    init_logging(ros_args.log_level, ros_args.rosout);
    match run(&ros_args) {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("dc_loc: error: {e}");
            e.exit_code()
        }
    }
}

/// env_logger on stderr: `RUST_LOG` (default `warn,dc_loc=info`, DDS internals at `error`: rustdds warns
/// about every loopback peer; ros2-client's node module off: it logs an error for each matched-publisher
/// query before the first match), dc_loc's level set by `--log-level`; dc_loc's records also to
/// `/rosout` unless `rosout` is false ([`super::rosout`]).
fn init_logging(level: Option<log::LevelFilter>, rosout: bool) {
    let builder = || {
        env_logger::Builder::from_env(env_logger::Env::default().default_filter_or(
            "warn,rustdds=error,ros2_client=error,ros2_client::node=off,dc_loc=info",
        ))
    };
    super::rosout::init(builder, level, rosout);
}

/// The configuration, the node settings and the map, or why the node cannot start.
pub struct StartUp {
    /// Validated configuration.
    pub cfg: Config,
    /// The node's own settings.
    pub settings: NodeSettings,
    /// Loaded (or empty) keyframe map.
    pub db: KeyframeDb,
    /// Where the map is saved; `None` without persistence.
    pub save_to: Option<PathBuf>,
    /// The lock on the map file, held while the node runs.
    pub lock: Option<MapLock>,
    /// The parameters as given (what run-time changes start from).
    pub params: ParamSet,
}

/// Reads the parameters and the map: everything that can refuse a start before DDS is touched.
pub fn start_up(ros_args: &RosArgs) -> Result<StartUp, NodeError> {
    let params = ros_args.param_set()?;
    let (settings, rest) = NodeSettings::take_from(&params)?;
    let cfg = apply(&rest)?;
    let LoadedMap { db, save_to, lock } = load_map(&cfg).map_err(NodeError::Map)?;
    Ok(StartUp {
        cfg,
        settings,
        db,
        save_to,
        lock,
        params,
    })
}

fn run(ros_args: &RosArgs) -> Result<(), NodeError> {
    let env = DdsEnv::from_env(|k| std::env::var(k).ok())?;
    let StartUp {
        cfg,
        settings,
        db,
        save_to,
        lock: _lock,
        params,
    } = start_up(ros_args)?;
    if let Some(level) = settings.log_filter() {
        super::rosout::set_level(level);
    }
    let live = Arc::new(LiveParams::new(&params));
    log::info!(
        "dc_loc node {} (ROS_DOMAIN_ID {}, discovery {:?}), effective configuration:\n{}",
        ros_args.fully_qualified_name(),
        env.domain_id,
        env.range,
        describe(&cfg, &settings)
    );
    // One tokio thread runs DDS reception, the spinner and the timers; the pipeline has a thread of
    // its own.
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .map_err(|e| NodeError::Runtime(format!("tokio runtime: {e}")))?;
    let _entered = runtime.enter();
    let context = dds_context(&env)?;
    let mut node = make_node(&context, ros_args, &cfg, &settings, live.clone())?;
    super::rosout::forward(node.logging_handle(), ros_args.logger_name());
    let spin_task = tokio::spawn(node.spinner().map_err(dds("spinner"))?.spin());
    let subs = Subscriptions::new(&mut node, ros_args, &cfg, settings.use_sim_time)?;
    let outputs = outputs(&mut node, ros_args)?;

    let shared = Arc::new(Shared::new(Duration::from_secs_f64(settings.warn_interval)));
    let (tx, rx) = std::sync::mpsc::sync_channel::<Work>(settings.queue_size);
    let inbox = Inbox::new(tx, shared.clone());
    let saver =
        save_to.map(|path| MapSaver::new(path, cfg.map_shape(), cfg.map.save_interval, &db));
    let pipeline = Pipeline::with_map(cfg.clone(), db).map_err(|e| NodeError::Param(e.into()))?;
    // The worker says when it ends: before a stop was asked for, the node cannot go on.
    let (done_tx, done_rx) = tokio::sync::oneshot::channel::<()>();
    let worker = {
        let worker = Worker::new(
            pipeline,
            outputs,
            shared.clone(),
            settings.clone(),
            saver,
            ros_args.fully_qualified_name(),
            live,
        );
        std::thread::Builder::new()
            .name("dc_loc-worker".into())
            .spawn(move || {
                let result = worker.run(rx);
                let _ = done_tx.send(());
                result
            })
            .map_err(|e| NodeError::Runtime(format!("worker thread: {e}")))?
    };
    let stop = stop_signal();
    println!("dc_loc: node {} running", ros_args.fully_qualified_name());
    let reception = Reception {
        shared: shared.clone(),
        inbox: inbox.clone(),
        use_sim_time: settings.use_sim_time,
    };
    let ended = runtime.block_on(subs.receive(&node, reception, settings.limits, stop, done_rx));
    log::info!("shutting down: saving the map, then processing the queued messages");
    shared.stopping.store(true, Ordering::SeqCst);
    inbox.stop();
    drop(inbox);
    let result = worker.join();
    // Drop order: streams and entities before the context.
    drop(subs);
    spin_task.abort();
    drop(node);
    drop(context);
    let saved = result.map_err(|_| NodeError::Runtime("the worker thread panicked".into()))?;
    if let Some(why) = ended {
        return Err(NodeError::Runtime(why));
    }
    saved.map_err(|e| NodeError::Runtime(format!("the map was not saved at shutdown: {e}")))
}

/// The DDS participant and context: loopback only when asked (ros2-client reads neither
/// `ROS_DOMAIN_ID` nor `ROS_AUTOMATIC_DISCOVERY_RANGE` itself).
fn dds_context(env: &DdsEnv) -> Result<Context, NodeError> {
    let mut builder = ros2_client::dds::rustdds::DomainParticipantBuilder::new(env.domain_id);
    if env.range != DiscoveryRange::Subnet {
        builder = builder.with_only_networks([Ipv4Addr::LOCALHOST]);
    }
    let participant = builder.build().map_err(dds("domain participant"))?;
    Context::from_domain_participant(participant).map_err(dds("context"))
}

/// The node with every parameter declared; once running, the live ones ([`LiveParams`]) change on
/// `ros2 param set` (checked, applied by the worker at the next keyframe), the others are refused.
fn make_node(
    context: &Context,
    ros_args: &RosArgs,
    cfg: &Config,
    settings: &NodeSettings,
    live: Arc<LiveParams>,
) -> Result<Node, NodeError> {
    let started = Arc::new(AtomicBool::new(false));
    let mut options = NodeOptions::new().enable_rosout(ros_args.rosout);
    for (n, v) in all_params(cfg, settings) {
        options = options.declare_parameter(&n, parameter_value(&v));
    }
    let (started_check, live_check) = (started.clone(), live.clone());
    options = options.parameter_validator(Box::new(move |name, value| {
        if !started_check.load(Ordering::SeqCst) {
            return Ok(());
        }
        live_check.check(name, &json_value(value)).map(|_| ())
    }));
    let started_set = started.clone();
    options = options.parameter_set_action(Box::new(move |name, value| {
        if !started_set.load(Ordering::SeqCst) {
            return Ok(());
        }
        live.set(name, &json_value(value))
    }));
    let node_name =
        NodeName::new(&ros_args.namespace, &ros_args.node_name).map_err(dds("node name"))?;
    let node = context.new_node(node_name, options).map_err(dds("node"))?;
    started.store(true, Ordering::SeqCst);
    Ok(node)
}

/// A future that completes at the first SIGINT or SIGTERM; a second signal ends the process at once.
fn stop_signal() -> tokio::sync::mpsc::Receiver<()> {
    let (stop_tx, stop_rx) = tokio::sync::mpsc::channel::<()>(1);
    let requested = AtomicBool::new(false);
    if let Err(e) = ctrlc::set_handler(move || {
        if requested.swap(true, Ordering::SeqCst) {
            eprintln!("dc_loc: second signal: exiting without saving");
            std::process::exit(130);
        }
        let _ = stop_tx.try_send(());
    }) {
        log::warn!("cannot install the SIGINT/SIGTERM handler: {e}");
    }
    stop_rx
}

/// The node's input subscriptions.
struct Subscriptions {
    /// Per radar topic (several radars may share one; the frame id tells them apart).
    radars: Vec<(String, TopicRadars, Subscription<PointCloud2>)>,
    odometry: (String, Subscription<Odometry>),
    clock: Option<Subscription<Clock>>,
}

impl Subscriptions {
    fn new(
        node: &mut Node,
        ros_args: &RosArgs,
        cfg: &Config,
        use_sim_time: bool,
    ) -> Result<Self, NodeError> {
        let mut by_topic: std::collections::BTreeMap<String, TopicRadars> = Default::default();
        for (i, (name, rc)) in cfg.radar_list().into_iter().enumerate() {
            by_topic
                .entry(ros_args.resolve_topic(&rc.topic))
                .or_default()
                .push((i, name.to_string(), rc.frame_id.clone()));
        }
        let mut radars = Vec::new();
        for (topic, topic_radars) in by_topic {
            let sub = subscribe(node, &topic, "sensor_msgs", "PointCloud2", INPUT_DEPTH)?;
            let names: Vec<&str> = topic_radars.iter().map(|r| r.1.as_str()).collect();
            log::info!("radar {} on {topic}", names.join(", "));
            radars.push((topic, topic_radars, sub));
        }
        let odom_topic = ros_args.resolve_topic(&cfg.odometry.topic);
        let odometry = subscribe(node, &odom_topic, "nav_msgs", "Odometry", INPUT_DEPTH)?;
        log::info!("odometry on {odom_topic}");
        let clock = if use_sim_time {
            Some(subscribe(node, "/clock", "rosgraph_msgs", "Clock", 10)?)
        } else {
            None
        };
        Ok(Subscriptions {
            radars,
            odometry: (odom_topic, odometry),
            clock,
        })
    }

    /// Runs every reception task until `stop` completes; `Some(cause)` when the node cannot go on (a
    /// task or the worker ended first).
    async fn receive(
        &self,
        node: &Node,
        r: Reception,
        limits: InputLimits,
        mut stop: tokio::sync::mpsc::Receiver<()>,
        worker_done: tokio::sync::oneshot::Receiver<()>,
    ) -> Option<String> {
        let mut tasks: Vec<futures::future::BoxFuture<'_, ()>> = Vec::new();
        for (topic, radars, sub) in &self.radars {
            let shared = r.shared.clone();
            tasks.push(Box::pin(inputs::take(topic, sub, r.clone(), move |c| {
                inputs::radar_input(topic, radars, &limits, &shared, c)
            })));
        }
        let (topic, sub) = &self.odometry;
        let shared = r.shared.clone();
        tasks.push(Box::pin(inputs::take(topic, sub, r.clone(), move |o| {
            inputs::odometry_input(topic, &shared, o)
        })));
        if let Some(sub) = &self.clock {
            tasks.push(Box::pin(inputs::clock(sub, r.shared.clone())));
        }
        let counts = inputs::publisher_counts(node, &self.radars, &self.odometry.1, r.shared);
        tasks.push(Box::pin(counts));
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

/// DDS reader history of each input: deep enough that a busy executor never makes the reader discard
/// a sample (about 8 s of 5 radars at 13 Hz, 40 s of odometry at 25 Hz).
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

/// The publishers: `~/loop_closures` (reliable, transient-local: a back end that starts late still
/// gets the history), `~/markers`, `~/submap`, `/diagnostics`.
fn outputs(node: &mut Node, ros_args: &RosArgs) -> Result<Outputs, NodeError> {
    fn publisher<M: serde::Serialize>(
        node: &mut Node,
        ros_args: &RosArgs,
        name: &str,
        (package, type_name): (&str, &str),
        qos: QosProfile,
    ) -> Result<ros2_client::Publisher<M>, NodeError> {
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
    Ok(Outputs {
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
    })
}

/// A parameter value as ROS 2 declares it.
/// A ROS 2 parameter value as the JSON value the configuration takes.
fn json_value(v: &ParameterValue) -> Value {
    match v {
        ParameterValue::NotSet => Value::Null,
        ParameterValue::Boolean(b) => Value::from(*b),
        ParameterValue::Integer(i) => Value::from(*i),
        ParameterValue::Double(d) => Value::from(*d),
        ParameterValue::String(s) => Value::from(s.clone()),
        ParameterValue::ByteArray(a) => Value::from(a.clone()),
        ParameterValue::BooleanArray(a) => Value::from(a.clone()),
        ParameterValue::IntegerArray(a) => Value::from(a.clone()),
        ParameterValue::DoubleArray(a) => Value::from(a.clone()),
        ParameterValue::StringArray(a) => Value::from(a.clone()),
    }
}

fn parameter_value(v: &Value) -> ParameterValue {
    match v {
        Value::Bool(b) => ParameterValue::Boolean(*b),
        Value::Number(n) if n.is_f64() => ParameterValue::Double(n.as_f64().unwrap_or(f64::NAN)),
        Value::Number(n) => ParameterValue::Integer(n.as_i64().unwrap_or(i64::MAX)),
        Value::String(s) => ParameterValue::String(s.clone()),
        Value::Array(a) => {
            if a.iter().all(Value::is_string) {
                ParameterValue::StringArray(
                    a.iter()
                        .filter_map(|x| x.as_str().map(String::from))
                        .collect(),
                )
            } else if a.iter().all(Value::is_boolean) {
                ParameterValue::BooleanArray(a.iter().filter_map(Value::as_bool).collect())
            } else if a.iter().all(|x| x.as_i64().is_some() && !x.is_f64()) {
                ParameterValue::IntegerArray(a.iter().filter_map(Value::as_i64).collect())
            } else {
                ParameterValue::DoubleArray(a.iter().filter_map(Value::as_f64).collect())
            }
        }
        Value::Null | Value::Object(_) => ParameterValue::NotSet,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameter_values_keep_their_types() {
        assert_eq!(
            parameter_value(&serde_json::json!(0.0)),
            ParameterValue::Double(0.0)
        );
        assert_eq!(
            parameter_value(&serde_json::json!(3)),
            ParameterValue::Integer(3)
        );
        assert_eq!(
            parameter_value(&serde_json::json!([0.0, 1.5])),
            ParameterValue::DoubleArray(vec![0.0, 1.5])
        );
        assert_eq!(
            parameter_value(&serde_json::json!(["a"])),
            ParameterValue::StringArray(vec!["a".into()])
        );
    }
}
