//! The ROS 2 node: DDS reception on the executor, the [`Pipeline`] on a worker thread of its own.
//!
//! Shape: [`main`] parses the command line and the environment ([`super::args`]), the parameters
//! ([`crate::params`] plus the node's own `node.*` and `use_sim_time`), loads the keyframe map, makes the
//! DDS participant (loopback only when `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`) and the node with every
//! parameter declared, then:
//! - one async task per input topic takes messages off DDS, does the cheap checks (frame id, size) and
//!   hands them to the worker through a bounded channel (`node.queue_size`); a full queue drops the
//!   message and counts it, so reception never waits for registration;
//! - the worker thread owns the pipeline: inputs are put back in stamp order across topics
//!   ([`super::merge::StampMerger`], at most `node.sync_timeout` of waiting) so that the pipeline sees
//!   the sequence `dc_loc run` reads from a bag; stamps going backwards are held back (a single stale message
//!   is dropped; a run of them is a restart and resets the pipeline), clouds are decoded, closures,
//!   markers and the submap are published as they come, diagnostics every `node.diagnostics_period`,
//!   the map is saved every `map.save_interval` by a saver thread;
//! - SIGINT/SIGTERM stop reception; the worker drains the queue (the last closures are published),
//!   saves the map and ends; entities are dropped before the context.
//!
//! Every message that is not used is counted by reason in `/diagnostics` and warned about at most every
//! `node.warn_interval` seconds per reason.

use std::collections::{BTreeMap, VecDeque};
use std::net::Ipv4Addr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use futures::StreamExt;
use ros2_client::{
    Context, MessageTypeName, Name, NodeName, NodeOptions, ParameterValue, Publisher, QosProfile,
    Subscription,
    qos::{Durability, History, Reliability, WhenFull},
};
use serde_json::Value;

use super::args::{ArgsError, DdsEnv, DiscoveryRange, RosArgs};
use super::convert::{
    DiagnosticArray, DiagnosticStatus, KeyValue, MarkerArray, MarkerPoint, markers, submap_cloud,
};
use super::merge::StampMerger;
use crate::input::{Input, odometry_pose};
use crate::keyframe_db::{KeyframeDb, KeyframeRecord, save_records};
use crate::math::{Iso3, Stamp};
use crate::msgs::builtin_interfaces::Time;
use crate::msgs::dc_loc::LoopClosure as LoopClosureMsg;
use crate::msgs::nav_msgs::Odometry;
use crate::msgs::rosgraph_msgs::Clock;
use crate::msgs::sensor_msgs::PointCloud2;
use crate::msgs::std_msgs::Header;
use crate::output::loop_closure_msg;
use crate::params::{ParamError, ParamSet, apply, flatten_config};
use crate::pipeline::Config;
use crate::pipeline::{Event, Pipeline};

/// The node's own settings (not part of [`Config`], which the offline tools share).
#[derive(Debug, Clone, PartialEq)]
pub struct NodeSettings {
    /// `use_sim_time` (bool, false): stamp outputs with `/clock` (rosgraph_msgs/Clock) time.
    pub use_sim_time: bool,
    /// `node.queue_size` (int, 2000): messages waiting for the worker; beyond, new ones are dropped.
    pub queue_size: usize,
    /// `node.diagnostics_period` (double, 1.0): seconds between `/diagnostics` messages.
    pub diagnostics_period: f64,
    /// `node.max_cloud_points` (int, 200000): larger clouds are refused.
    pub max_cloud_points: usize,
    /// `node.warn_interval` (double, 5.0): seconds between warnings of one kind.
    pub warn_interval: f64,
    /// `node.sync_timeout` (double, 0.2): longest wait, s, for the other inputs to reach a message's stamp
    /// before it is processed anyway (inputs are processed in stamp order, as `dc_loc run` reads a bag).
    pub sync_timeout: f64,
    /// `node.restart_after` (int, 20): consecutive inputs with stamps going backwards that mean a restart
    /// (bag replayed again, simulator reset) rather than stale messages.
    pub restart_after: usize,
}

impl Default for NodeSettings {
    fn default() -> Self {
        NodeSettings {
            use_sim_time: false,
            queue_size: 2000,
            diagnostics_period: 1.0,
            max_cloud_points: 200_000,
            warn_interval: 5.0,
            sync_timeout: 0.2,
            restart_after: 20,
        }
    }
}

impl NodeSettings {
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
                Value::from(self.max_cloud_points),
            ),
            ("node.warn_interval".into(), Value::from(self.warn_interval)),
            ("node.sync_timeout".into(), Value::from(self.sync_timeout)),
            ("node.restart_after".into(), Value::from(self.restart_after)),
        ]
    }

    /// Splits the node's own parameters off `params`; the rest go to [`apply`].
    pub fn take_from(params: &ParamSet) -> Result<(Self, ParamSet), ParamError> {
        let mut s = NodeSettings::default();
        let mut rest = ParamSet::default();
        let ty = |name: &str, expected: &'static str, v: &Value| ParamError::Type {
            name: name.to_string(),
            expected,
            got: v.to_string(),
        };
        let positive = |name: &str, v: f64| -> Result<f64, ParamError> {
            if v.is_finite() && v > 0.0 {
                Ok(v)
            } else {
                Err(crate::validate::ConfigError::new(name, format!("{v} must be > 0")).into())
            }
        };
        for (name, v) in params.entries() {
            let count = |v: &Value| -> Result<usize, ParamError> {
                match v.as_u64() {
                    Some(n) if n >= 1 => Ok(n as usize),
                    Some(_) => {
                        Err(crate::validate::ConfigError::new(name, "must be at least 1").into())
                    }
                    None => Err(ty(name, "a positive integer", v)),
                }
            };
            let secs = |v: &Value| v.as_f64().ok_or_else(|| ty(name, "a number", v));
            match name.as_str() {
                "use_sim_time" => {
                    s.use_sim_time = v.as_bool().ok_or_else(|| ty(name, "a boolean", v))?
                }
                "node.queue_size" => s.queue_size = count(v)?,
                "node.max_cloud_points" => s.max_cloud_points = count(v)?,
                "node.restart_after" => s.restart_after = count(v)?,
                "node.diagnostics_period" => s.diagnostics_period = positive(name, secs(v)?)?,
                "node.warn_interval" => s.warn_interval = positive(name, secs(v)?)?,
                "node.sync_timeout" => s.sync_timeout = positive(name, secs(v)?)?,
                n if n.starts_with("node.") => return Err(ParamError::Unknown(name.clone())),
                _ => rest.set(name.clone(), v.clone()),
            }
        }
        Ok((s, rest))
    }
}

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
}

impl NodeError {
    fn exit_code(&self) -> i32 {
        match self {
            NodeError::Dds(_) => 1,
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
    init_logging(ros_args.log_level);
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
/// query before the first match), dc_loc's level set by `--log-level`.
fn init_logging(level: Option<log::LevelFilter>) {
    let mut b = env_logger::Builder::from_env(env_logger::Env::default().default_filter_or(
        "warn,rustdds=error,ros2_client=error,ros2_client::node=off,dc_loc=info",
    ));
    if let Some(l) = level {
        b.filter_module("dc_loc", l);
    }
    let _ = b.try_init();
}

/// The configuration, the node settings and the map, or why the node cannot start.
pub struct StartUp {
    /// Validated configuration.
    pub cfg: Config,
    /// The node's own settings.
    pub settings: NodeSettings,
    /// Loaded (or empty) keyframe map.
    pub db: KeyframeDb,
    /// Where the map is saved (`map.file`, or `<file>.new` when the file was refused and
    /// `map.start_empty_on_error` allowed an empty start); `None` without persistence.
    pub save_to: Option<PathBuf>,
}

/// Reads the parameters and the map: everything that can refuse a start before DDS is touched.
pub fn start_up(ros_args: &RosArgs) -> Result<StartUp, NodeError> {
    let params = ros_args.param_set()?;
    let (settings, rest) = NodeSettings::take_from(&params)?;
    let cfg = apply(&rest)?;
    let (db, save_to) = load_map(&cfg)?;
    Ok(StartUp {
        cfg,
        settings,
        db,
        save_to,
    })
}

fn load_map(cfg: &Config) -> Result<(KeyframeDb, Option<PathBuf>), NodeError> {
    let empty = || KeyframeDb::new(cfg.place.clone(), cfg.map.prepared_cache);
    if cfg.map.file.is_empty() {
        return Ok((empty(), None));
    }
    let path = PathBuf::from(&cfg.map.file);
    if !path.exists() {
        log::info!(
            "map file {} does not exist yet: starting an empty map",
            path.display()
        );
        return Ok((empty(), Some(path)));
    }
    match KeyframeDb::load(&path, cfg.place.clone(), cfg.map.prepared_cache) {
        Ok(db) => {
            log::info!(
                "map file {}: {} keyframes loaded (sessions up to {:?})",
                path.display(),
                db.len(),
                db.last_session()
            );
            Ok((db, Some(path)))
        }
        Err(e) if cfg.map.start_empty_on_error => {
            let new = PathBuf::from(format!("{}.new", cfg.map.file));
            log::warn!(
                "{e}; starting with an empty map (map.start_empty_on_error), saving to {} and leaving the file untouched",
                new.display()
            );
            Ok((empty(), Some(new)))
        }
        Err(e) => Err(NodeError::Map(format!(
            "parameter `map.file`: {e}; refusing to start (set map.start_empty_on_error:=true to start with an empty map)"
        ))),
    }
}

/// The effective configuration, one `name: value` per line.
fn describe(cfg: &Config, settings: &NodeSettings) -> String {
    let mut all = flatten_config(cfg);
    all.extend(settings.as_params());
    all.sort_by(|a, b| a.0.cmp(&b.0));
    all.iter()
        .map(|(n, v)| format!("  {n}: {v}"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// A parameter value as ROS 2 declares it.
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

/// Counters shared by the reception tasks and the worker.
#[derive(Default)]
struct Shared {
    /// Messages received per input (radar name or `odometry`).
    received: Mutex<BTreeMap<String, u64>>,
    /// Messages not used, by reason.
    dropped: Mutex<BTreeMap<String, u64>>,
    /// Matched publishers per input.
    publishers: Mutex<BTreeMap<String, usize>>,
    /// Messages in the queue now.
    queued: AtomicUsize,
    /// Most messages ever queued.
    queued_max: AtomicUsize,
    /// Messages held by the worker to be put in stamp order.
    held: AtomicUsize,
    /// `/clock` time, ns (sim time).
    clock_ns: AtomicI64,
    /// Rate limiting of warnings: reason -> (last warning, suppressed since).
    warned: Mutex<BTreeMap<String, (Instant, u64)>>,
    warn_interval: Duration,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Shared {
    fn count_received(&self, input: &str) {
        *lock(&self.received).entry(input.to_string()).or_default() += 1;
    }

    /// Counts a dropped message and warns, at most once per `warn_interval` per reason.
    fn drop_msg(&self, reason: &str, detail: &str) {
        *lock(&self.dropped).entry(reason.to_string()).or_default() += 1;
        self.warn(reason, detail);
    }

    fn warn(&self, reason: &str, detail: &str) {
        let mut w = lock(&self.warned);
        let now = Instant::now();
        match w.get_mut(reason) {
            Some((last, suppressed)) if now.duration_since(*last) < self.warn_interval => {
                *suppressed += 1;
            }
            Some((last, suppressed)) => {
                log::warn!(
                    "{reason}: {detail} ({} more since the last warning)",
                    suppressed
                );
                *last = now;
                *suppressed = 0;
            }
            None => {
                log::warn!("{reason}: {detail}");
                w.insert(reason.to_string(), (now, 0));
            }
        }
    }
}

/// What the reception tasks hand to the worker.
enum Work {
    Cloud {
        radar: usize,
        cloud: Box<PointCloud2>,
        arrived: Instant,
    },
    Odometry {
        stamp: Stamp,
        t_odom_body: Iso3,
        frame_id: String,
        arrived: Instant,
    },
    /// Shutdown: everything before it has been processed.
    Stop,
}

/// Sends work to the worker without waiting; a full queue drops and counts.
#[derive(Clone)]
struct Inbox {
    tx: SyncSender<Work>,
    shared: Arc<Shared>,
}

impl Inbox {
    fn send(&self, w: Work) {
        self.shared.queued.fetch_add(1, Ordering::SeqCst);
        match self.tx.try_send(w) {
            Ok(()) => {
                let q = self.shared.queued.load(Ordering::SeqCst);
                self.shared.queued_max.fetch_max(q, Ordering::SeqCst);
            }
            Err(TrySendError::Full(_)) => {
                self.shared.queued.fetch_sub(1, Ordering::SeqCst);
                self.shared.drop_msg(
                    "reception_queue_full",
                    "the worker is behind; message dropped",
                );
            }
            Err(TrySendError::Disconnected(_)) => {
                self.shared.queued.fetch_sub(1, Ordering::SeqCst);
            }
        }
    }
}

/// Asks the worker to stop after what is queued.
fn self_stop(inbox: &Inbox) {
    inbox.shared.queued.fetch_add(1, Ordering::SeqCst);
    if inbox.tx.send(Work::Stop).is_err() {
        inbox.shared.queued.fetch_sub(1, Ordering::SeqCst);
    }
}

/// The outputs, owned by the worker thread.
struct Outputs {
    closures: Publisher<LoopClosureMsg>,
    markers: Publisher<MarkerArray>,
    submap: Publisher<PointCloud2>,
    diagnostics: Publisher<DiagnosticArray>,
}

fn reliable(depth: usize, durability: Durability) -> QosProfile {
    QosProfile::publisher_default()
        .reliability(Reliability::Reliable {
            when_full: WhenFull::Wait(Duration::from_millis(200)),
        })
        .durability(durability)
        .history(History::KeepLast { depth })
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

fn topic_name(resolved: &str) -> Result<Name, NodeError> {
    Name::parse(resolved).map_err(|e| NodeError::Dds(format!("topic name {resolved}: {e:?}")))
}

fn run(ros_args: &RosArgs) -> Result<(), NodeError> {
    let env = DdsEnv::from_env(|k| std::env::var(k).ok())?;
    let StartUp {
        cfg,
        settings,
        db,
        save_to,
    } = start_up(ros_args)?;
    log::info!(
        "dc_loc node {} (ROS_DOMAIN_ID {}, discovery {:?}), effective configuration:\n{}",
        ros_args.fully_qualified_name(),
        env.domain_id,
        env.range,
        describe(&cfg, &settings)
    );

    // DDS participant: loopback only when asked (ros2-client reads neither variable itself).
    let mut builder = ros2_client::dds::rustdds::DomainParticipantBuilder::new(env.domain_id);
    if env.range != DiscoveryRange::Subnet {
        builder = builder.with_only_networks([Ipv4Addr::LOCALHOST]);
    }
    let participant = builder.build().map_err(dds("domain participant"))?;
    let context = Context::from_domain_participant(participant).map_err(dds("context"))?;

    // Every parameter declared, read-only once running (the pipeline is built from them at start).
    let started = Arc::new(AtomicBool::new(false));
    let mut options = NodeOptions::new().enable_rosout(true);
    let mut declared = flatten_config(&cfg);
    declared.extend(settings.as_params());
    for (n, v) in &declared {
        options = options.declare_parameter(n, parameter_value(v));
    }
    let started_check = started.clone();
    options = options.parameter_validator(Box::new(move |name, _value| {
        if started_check.load(Ordering::SeqCst) {
            Err(format!(
                "dc_loc parameters are read at start-up: restart the node to change `{name}`"
            ))
        } else {
            Ok(())
        }
    }));
    let node_name =
        NodeName::new(&ros_args.namespace, &ros_args.node_name).map_err(dds("node name"))?;
    let mut node = context.new_node(node_name, options).map_err(dds("node"))?;
    started.store(true, Ordering::SeqCst);
    let spinner = node.spinner().map_err(dds("spinner"))?;
    let spin_task = smol::spawn(spinner.spin());

    let shared = Arc::new(Shared {
        warn_interval: Duration::from_secs_f64(settings.warn_interval),
        ..Shared::default()
    });

    // Inputs: radar topics (several radars may share one; the frame id tells them apart), odometry.
    let mut radar_topics: BTreeMap<String, Vec<(usize, String, String)>> = BTreeMap::new();
    for (i, (name, rc)) in cfg.radar_list().into_iter().enumerate() {
        radar_topics
            .entry(ros_args.resolve_topic(&rc.topic))
            .or_default()
            .push((i, name.to_string(), rc.frame_id.clone()));
    }
    let mut radar_subs = Vec::new();
    for (topic, radars) in &radar_topics {
        let t = node
            .create_topic(
                &topic_name(topic)?,
                MessageTypeName::new("sensor_msgs", "PointCloud2"),
                &sensor_qos(INPUT_DEPTH),
            )
            .map_err(dds("radar topic"))?;
        let sub: Subscription<PointCloud2> = node
            .create_subscription(&t, Some(sensor_qos(INPUT_DEPTH)))
            .map_err(dds("radar subscription"))?;
        log::info!(
            "radar {} on {topic}",
            radars
                .iter()
                .map(|r| r.1.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
        radar_subs.push((topic.clone(), radars.clone(), sub));
    }
    let odom_topic = ros_args.resolve_topic(&cfg.odometry.topic);
    let t = node
        .create_topic(
            &topic_name(&odom_topic)?,
            MessageTypeName::new("nav_msgs", "Odometry"),
            &sensor_qos(INPUT_DEPTH),
        )
        .map_err(dds("odometry topic"))?;
    let odom_sub: Subscription<Odometry> = node
        .create_subscription(&t, Some(sensor_qos(INPUT_DEPTH)))
        .map_err(dds("odometry subscription"))?;
    log::info!("odometry on {odom_topic}");
    let clock_sub: Option<Subscription<Clock>> = if settings.use_sim_time {
        let t = node
            .create_topic(
                &topic_name("/clock")?,
                MessageTypeName::new("rosgraph_msgs", "Clock"),
                &sensor_qos(10),
            )
            .map_err(dds("clock topic"))?;
        Some(
            node.create_subscription(&t, Some(sensor_qos(10)))
                .map_err(dds("clock subscription"))?,
        )
    } else {
        None
    };

    // Outputs.
    let publisher = |name: &str, pkg: &str, ty: &str, qos: QosProfile| {
        let resolved = ros_args.resolve_topic(name);
        let t = node
            .create_topic(&topic_name(&resolved)?, MessageTypeName::new(pkg, ty), &qos)
            .map_err(dds("output topic"))?;
        log::info!("publishing {pkg}/msg/{ty} on {resolved}");
        Ok::<_, NodeError>((t, qos))
    };
    let (t_closures, q_closures) = publisher(
        "~/loop_closures",
        "dc_loc",
        "LoopClosure",
        reliable(100, Durability::TransientLocal),
    )?;
    let (t_markers, q_markers) = publisher(
        "~/markers",
        "visualization_msgs",
        "MarkerArray",
        reliable(1, Durability::TransientLocal),
    )?;
    let (t_submap, q_submap) = publisher(
        "~/submap",
        "sensor_msgs",
        "PointCloud2",
        reliable(1, Durability::Volatile),
    )?;
    let (t_diag, q_diag) = publisher(
        "/diagnostics",
        "diagnostic_msgs",
        "DiagnosticArray",
        reliable(10, Durability::Volatile),
    )?;
    let outputs = Outputs {
        closures: node
            .create_publisher(&t_closures, Some(q_closures))
            .map_err(dds("publisher"))?,
        markers: node
            .create_publisher(&t_markers, Some(q_markers))
            .map_err(dds("publisher"))?,
        submap: node
            .create_publisher(&t_submap, Some(q_submap))
            .map_err(dds("publisher"))?,
        diagnostics: node
            .create_publisher(&t_diag, Some(q_diag))
            .map_err(dds("publisher"))?,
    };

    // The worker and its queue.
    let (tx, rx) = std::sync::mpsc::sync_channel::<Work>(settings.queue_size);
    let inbox = Inbox {
        tx,
        shared: shared.clone(),
    };
    let pipeline = Pipeline::with_map(cfg.clone(), db).map_err(|e| NodeError::Param(e.into()))?;
    let worker = {
        let shared = shared.clone();
        let settings = settings.clone();
        let hardware_id = ros_args.fully_qualified_name();
        std::thread::Builder::new()
            .name("dc_loc-worker".into())
            .spawn(move || {
                Worker::new(pipeline, outputs, shared, settings, save_to, hardware_id).run(rx)
            })
            .map_err(|e| NodeError::Dds(format!("worker thread: {e}")))?
    };

    // Shutdown on SIGINT/SIGTERM; a second signal ends the process at once.
    let (stop_tx, stop_rx) = smol::channel::bounded::<()>(1);
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
    println!("dc_loc: node {} running", ros_args.fully_qualified_name());

    let max_points = settings.max_cloud_points;
    let use_sim_time = settings.use_sim_time;
    smol::block_on(async {
        let mut tasks: Vec<futures::future::BoxFuture<'_, ()>> = Vec::new();
        for (topic, radars, sub) in &radar_subs {
            let inbox = inbox.clone();
            let shared = shared.clone();
            tasks.push(Box::pin(async move {
                let mut stream = std::pin::pin!(sub.async_stream());
                while let Some(r) = stream.next().await {
                    let arrived = Instant::now();
                    let cloud = match r {
                        Ok((mut c, _)) => {
                            // A zero stamp (drivers that leave it unset): the receive time, as
                            // `dc_loc run` takes the bag's log time.
                            if Stamp::from(c.header.stamp) == Stamp(0) {
                                c.header.stamp = receive_time(&shared, use_sim_time).into();
                            }
                            c
                        }
                        Err(e) => {
                            shared.drop_msg("undecodable", &format!("{topic}: {e:?}"));
                            continue;
                        }
                    };
                    let got = &cloud.header.frame_id;
                    let Some((radar, name, _)) = radars
                        .iter()
                        .find(|(_, _, frame)| frame.is_empty() || frame == got)
                    else {
                        shared.drop_msg(
                            "unknown_frame",
                            &format!("{topic}: frame_id `{got}` is not a configured radar frame"),
                        );
                        continue;
                    };
                    shared.count_received(name);
                    let points = u64::from(cloud.width) * u64::from(cloud.height);
                    if points > max_points as u64 {
                        shared.drop_msg(
                            "cloud_too_large",
                            &format!("{topic}: {points} points > node.max_cloud_points"),
                        );
                        continue;
                    }
                    inbox.send(Work::Cloud {
                        radar: *radar,
                        cloud: Box::new(cloud),
                        arrived,
                    });
                }
            }));
        }
        {
            let inbox = inbox.clone();
            let shared = shared.clone();
            let odom_sub = &odom_sub;
            let odom_topic = &odom_topic;
            tasks.push(Box::pin(async move {
                let mut stream = std::pin::pin!(odom_sub.async_stream());
                while let Some(r) = stream.next().await {
                    let arrived = Instant::now();
                    let odom = match r {
                        Ok((mut o, _)) => {
                            if Stamp::from(o.header.stamp) == Stamp(0) {
                                o.header.stamp = receive_time(&shared, use_sim_time).into();
                            }
                            o
                        }
                        Err(e) => {
                            shared.drop_msg("undecodable", &format!("{odom_topic}: {e:?}"));
                            continue;
                        }
                    };
                    shared.count_received("odometry");
                    match odometry_pose(&odom) {
                        Some((stamp, t_odom_body)) => inbox.send(Work::Odometry {
                            stamp,
                            t_odom_body,
                            frame_id: odom.header.frame_id,
                            arrived,
                        }),
                        None => shared.drop_msg(
                            "bad_odometry",
                            &format!("{odom_topic}: pose not finite or zero quaternion"),
                        ),
                    }
                }
            }));
        }
        if let Some(sub) = &clock_sub {
            let shared = shared.clone();
            tasks.push(Box::pin(async move {
                let mut stream = std::pin::pin!(sub.async_stream());
                while let Some(r) = stream.next().await {
                    if let Ok((c, _)) = r {
                        let s: Stamp = c.clock.into();
                        shared.clock_ns.store(s.0, Ordering::SeqCst);
                    }
                }
            }));
        }
        // Matched publishers per input, for /diagnostics (a user or test waits for them before sending).
        {
            let shared = shared.clone();
            let node = &node;
            let radar_subs = &radar_subs;
            let odom_sub = &odom_sub;
            tasks.push(Box::pin(async move {
                loop {
                    let mut counts = Vec::new();
                    for (_, radars, sub) in radar_subs {
                        let n = sub.get_publisher_count(node);
                        counts.extend(radars.iter().map(|(_, name, _)| (name.clone(), n)));
                    }
                    counts.push(("odometry".to_string(), odom_sub.get_publisher_count(node)));
                    lock(&shared.publishers).extend(counts);
                    smol::Timer::after(Duration::from_millis(250)).await;
                }
            }));
        }
        let inputs = futures::future::join_all(tasks);
        futures::future::select(std::pin::pin!(inputs), std::pin::pin!(stop_rx.recv())).await;
    });
    log::info!("shutting down: processing the queued messages");
    // Blocking: the worker is draining the queue, and Stop must not be dropped as a full queue would.
    self_stop(&inbox);
    drop(inbox);
    let result = worker.join();
    // Drop order: streams and entities before the context.
    drop(radar_subs);
    drop(odom_sub);
    drop(clock_sub);
    drop(spin_task);
    drop(node);
    drop(context);
    match result {
        Ok(Ok(())) => Ok(()),
        Ok(Err(e)) => Err(e),
        Err(_) => Err(NodeError::Dds("the worker thread panicked".into())),
    }
}

/// Now: `/clock` time with `use_sim_time`, else the system clock.
fn receive_time(shared: &Shared, use_sim_time: bool) -> Stamp {
    if use_sim_time {
        Stamp(shared.clock_ns.load(Ordering::SeqCst))
    } else {
        Stamp(
            SystemTime::now()
                .duration_since(SystemTime::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as i64),
        )
    }
}

/// Rolling latency samples, seconds.
#[derive(Default)]
struct Latencies {
    samples: VecDeque<f64>,
}

impl Latencies {
    const KEEP: usize = 2000;
    fn push(&mut self, s: f64) {
        if self.samples.len() == Self::KEEP {
            self.samples.pop_front();
        }
        self.samples.push_back(s);
    }
    /// (p50, p99, max) in ms, or None.
    fn summary(&self) -> Option<(f64, f64, f64)> {
        if self.samples.is_empty() {
            return None;
        }
        let mut v: Vec<f64> = self.samples.iter().copied().collect();
        v.sort_by(f64::total_cmp);
        let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize] * 1e3;
        Some((q(0.5), q(0.99), q(1.0)))
    }
}

struct Worker {
    pipeline: Pipeline,
    out: Outputs,
    shared: Arc<Shared>,
    settings: NodeSettings,
    hardware_id: String,
    body_frame: String,
    odom_frame: String,
    /// Markers: keyframe positions (odometry frame) and closure edges.
    kf_points: BTreeMap<u64, MarkerPoint>,
    edges: Vec<(MarkerPoint, MarkerPoint)>,
    /// Arrival to processed (every input), arrival to published closure, keyframe processing time.
    input_latency: Latencies,
    closure_latency: Latencies,
    keyframe_time: Latencies,
    /// Counters at the last diagnostics, for rates.
    last_diag: Instant,
    last_received: BTreeMap<String, u64>,
    closures_published: u64,
    /// Map saving.
    save_to: Option<PathBuf>,
    last_save: Instant,
    saved_keyframes: usize,
    saver: Option<Saver>,
}

/// The map saver thread and the channel of snapshots to it.
type Saver = (
    SyncSender<Vec<Arc<KeyframeRecord>>>,
    std::thread::JoinHandle<()>,
);

impl Worker {
    fn new(
        pipeline: Pipeline,
        out: Outputs,
        shared: Arc<Shared>,
        settings: NodeSettings,
        save_to: Option<PathBuf>,
        hardware_id: String,
    ) -> Self {
        let kf_points = pipeline
            .db()
            .records()
            .filter(|r| r.session == pipeline.session())
            .map(|r| {
                let p = r.odom_pose_iso3().translation.vector;
                (r.id, MarkerPoint { x: p.x, y: p.y })
            })
            .collect();
        let saver = save_to.as_ref().map(|path| {
            let (tx, rx) = std::sync::mpsc::sync_channel::<Vec<Arc<KeyframeRecord>>>(1);
            let path = path.clone();
            let place = pipeline.config().place.clone();
            let h = std::thread::spawn(move || {
                for records in rx {
                    save_map(&records, &place, &path);
                }
            });
            (tx, h)
        });
        let mut pipeline = pipeline;
        pipeline.set_restart_after(settings.restart_after);
        Worker {
            body_frame: pipeline.config().body_frame.clone(),
            saved_keyframes: pipeline.db().len(),
            pipeline,
            out,
            shared,
            settings,
            hardware_id,
            odom_frame: "odom".into(),
            kf_points,
            edges: Vec::new(),
            input_latency: Latencies::default(),
            closure_latency: Latencies::default(),
            keyframe_time: Latencies::default(),
            last_diag: Instant::now(),
            last_received: BTreeMap::new(),
            closures_published: 0,
            save_to,
            last_save: Instant::now(),
            saver,
        }
    }

    fn now(&self) -> Time {
        receive_time(&self.shared, self.settings.use_sim_time).into()
    }

    fn run(mut self, rx: Receiver<Work>) -> Result<(), NodeError> {
        let period = Duration::from_secs_f64(self.settings.diagnostics_period);
        let n_radars = self.pipeline.config().radar_names.len();
        // Streams: each radar, then odometry.
        let mut merger: StampMerger<Work> = StampMerger::new(
            n_radars + 1,
            Duration::from_secs_f64(self.settings.sync_timeout),
            Duration::from_secs(1),
        );
        loop {
            let now = Instant::now();
            let mut wait = period.saturating_sub(self.last_diag.elapsed());
            if let Some(d) = merger.deadline() {
                wait = wait.min(d.saturating_duration_since(now));
            }
            match rx.recv_timeout(wait) {
                Err(RecvTimeoutError::Disconnected) => break,
                Ok(w) => {
                    self.shared.queued.fetch_sub(1, Ordering::SeqCst);
                    if matches!(w, Work::Stop) {
                        break;
                    }
                    let (stream, stamp) = match &w {
                        Work::Cloud { radar, cloud, .. } => (*radar, cloud.header.stamp.into()),
                        Work::Odometry { stamp, .. } => (n_radars, *stamp),
                        Work::Stop => (n_radars, Stamp(0)),
                    };
                    merger.push(stream, stamp, Instant::now(), w);
                }
                Err(RecvTimeoutError::Timeout) => {}
            }
            while let Some(w) = merger.pop_ready(Instant::now()) {
                self.handle(w);
            }
            self.shared.held.store(merger.len(), Ordering::SeqCst);
            if self.last_diag.elapsed() >= period {
                self.publish_diagnostics();
            }
            self.maybe_save();
        }
        while let Some(w) = merger.pop_any() {
            self.handle(w);
        }
        self.shared.held.store(0, Ordering::SeqCst);
        let events = self.pipeline.finish();
        self.handle_events(events, None);
        self.publish_diagnostics();
        // The final save, after any periodic save in flight.
        if let Some((tx, h)) = self.saver.take() {
            drop(tx);
            let _ = h.join();
        }
        if let Some(path) = &self.save_to {
            save_map(
                &self.pipeline.db().snapshot(),
                &self.pipeline.config().place,
                path,
            );
        }
        log::info!(
            "stopped: {} keyframes, {} closures published",
            self.pipeline.stats().keyframes,
            self.closures_published
        );
        // Give reliable readers a moment to fetch the last samples before the writers go away.
        if self.closures_published > 0 {
            std::thread::sleep(Duration::from_millis(300));
        }
        Ok(())
    }

    /// One message through the pipeline's input path (the one `dc_loc run` uses): decoding, stamps going
    /// backwards, duplicate stamps and odometry gaps are checked and counted there.
    fn handle(&mut self, w: Work) {
        let t0 = Instant::now();
        let (events, arrived) = match w {
            Work::Cloud {
                radar,
                cloud,
                arrived,
            } => (
                self.pipeline.push(&Input::Radar {
                    radar,
                    cloud: *cloud,
                }),
                arrived,
            ),
            Work::Odometry {
                stamp,
                t_odom_body,
                frame_id,
                arrived,
            } => {
                let events = self.pipeline.push(&Input::Odometry { stamp, t_odom_body });
                let accepted = !events.iter().any(|e| matches!(e, Event::Dropped { .. }));
                if accepted && !frame_id.is_empty() {
                    self.odom_frame = frame_id;
                }
                (events, arrived)
            }
            Work::Stop => return,
        };
        let keyframe = events.iter().any(|e| matches!(e, Event::Keyframe { .. }));
        self.handle_events(events, Some(arrived));
        if keyframe {
            self.keyframe_time.push(t0.elapsed().as_secs_f64());
        }
        self.input_latency.push(arrived.elapsed().as_secs_f64());
    }

    fn handle_events(&mut self, events: Vec<Event>, arrived: Option<Instant>) {
        let mut new_keyframe = false;
        for e in events {
            match e {
                Event::Keyframe {
                    id, t_odom_body, ..
                } => {
                    let p = t_odom_body.translation.vector;
                    self.kf_points.insert(id, MarkerPoint { x: p.x, y: p.y });
                    new_keyframe = true;
                }
                Event::Closure(c) => {
                    let msg = loop_closure_msg(&c, &self.body_frame);
                    if let Err(e) = self.out.closures.publish(msg) {
                        log::error!(
                            "loop closure {} -> {}: publish failed: {e:?}",
                            c.query_id,
                            c.match_id
                        );
                    } else {
                        self.closures_published += 1;
                    }
                    if let Some(a) = arrived {
                        self.closure_latency.push(a.elapsed().as_secs_f64());
                    }
                    log::debug!(
                        "published loop closure {} -> {} ({} inliers, overlap {:.2})",
                        c.query_id,
                        c.match_id,
                        c.inliers,
                        c.score
                    );
                    // Edges of this session's odometry frame only (a loaded map's are another frame).
                    if let (Some(a), Some(b)) = (
                        self.kf_points.get(&c.query_id),
                        self.kf_points.get(&c.match_id),
                    ) {
                        self.edges.push((*a, *b));
                    }
                    new_keyframe = true;
                }
                Event::Rejected { .. } => {}
                Event::Dropped { reason, detail } => {
                    // Counted in the pipeline's stats; warned here, rate-limited.
                    self.shared.warn(reason.name(), &detail);
                }
                Event::EmptyScan { detail } => self.shared.warn("empty_cloud", &detail),
                Event::TimeReset { previous, got } => {
                    self.shared.warn(
                        "time_reset",
                        &format!(
                            "time went back from {:.3} s to {:.3} s: pipeline reset, keyframes kept",
                            previous.as_secs_f64(),
                            got.as_secs_f64()
                        ),
                    );
                }
            }
        }
        if new_keyframe {
            let kfs: Vec<MarkerPoint> = self.kf_points.values().copied().collect();
            let m = markers(self.now(), &self.odom_frame, &kfs, &self.edges);
            if let Err(e) = self.out.markers.publish(m) {
                log::debug!("markers: {e:?}");
            }
            if let Some(s) = self.pipeline.current_submap() {
                if let Err(e) = self.out.submap.publish(submap_cloud(&s, &self.body_frame)) {
                    log::debug!("submap: {e:?}");
                }
            }
        }
    }

    fn maybe_save(&mut self) {
        if self.save_to.is_none()
            || self.last_save.elapsed().as_secs_f64() < self.pipeline.config().map.save_interval
        {
            return;
        }
        self.last_save = Instant::now();
        if self.pipeline.db().len() == self.saved_keyframes {
            return;
        }
        if let Some((tx, _)) = &self.saver {
            // A save still running: the next interval takes the newer map.
            if tx.try_send(self.pipeline.db().snapshot()).is_ok() {
                self.saved_keyframes = self.pipeline.db().len();
            }
        }
    }

    fn publish_diagnostics(&mut self) {
        let dt = self.last_diag.elapsed().as_secs_f64().max(1e-6);
        self.last_diag = Instant::now();
        let kv = |k: &str, v: String| KeyValue {
            key: k.to_string(),
            value: v,
        };
        let received = lock(&self.shared.received).clone();
        let mut input = Vec::new();
        for (name, n) in &received {
            let before = self.last_received.get(name).copied().unwrap_or(0);
            input.push(kv(
                &format!("{name}.rate_hz"),
                format!("{:.2}", (n - before) as f64 / dt),
            ));
            input.push(kv(&format!("{name}.received"), n.to_string()));
        }
        self.last_received = received;
        for (name, n) in lock(&self.shared.publishers).iter() {
            input.push(kv(&format!("{name}.publishers"), n.to_string()));
        }

        let stats = self.pipeline.stats().clone();
        let mut dropped: BTreeMap<String, u64> = lock(&self.shared.dropped).clone();
        for (r, n) in &stats.dropped {
            *dropped.entry(r.name().to_string()).or_default() += n;
        }
        let total_dropped: u64 = dropped.values().sum();
        let mut drop_values: Vec<KeyValue> =
            dropped.iter().map(|(k, v)| kv(k, v.to_string())).collect();
        drop_values.push(kv("nan_points", stats.detections_invalid.to_string()));
        drop_values.push(kv("empty_clouds", stats.empty_scans.to_string()));
        drop_values.push(kv("time_resets", stats.time_resets.to_string()));

        let mut proc = vec![
            kv(
                "queue_depth",
                self.shared.queued.load(Ordering::SeqCst).to_string(),
            ),
            kv(
                "queue_depth_max",
                self.shared.queued_max.load(Ordering::SeqCst).to_string(),
            ),
            kv("queue_size", self.settings.queue_size.to_string()),
            kv(
                "held_for_order",
                self.shared.held.load(Ordering::SeqCst).to_string(),
            ),
            kv("pending_scans", stats.pending_scans.to_string()),
            kv("scans", stats.scans.to_string()),
            kv("keyframes", stats.keyframes.to_string()),
            kv("map_keyframes", self.pipeline.db().len().to_string()),
            kv("registrations", stats.registrations.to_string()),
            kv("closures", self.closures_published.to_string()),
            kv(
                "odometry_speed_scale",
                stats
                    .speed_scale
                    .map_or_else(|| "-".to_string(), |k| format!("{k:.4}")),
            ),
            kv(
                "odometry_speed_scale_refused",
                stats.speed_scale_refused.to_string(),
            ),
        ];
        for (r, n) in &stats.rejected {
            proc.push(kv(&format!("rejected.{}", r.name()), n.to_string()));
        }
        for (name, l) in [
            ("latency_ms", &self.input_latency),
            ("closure_latency_ms", &self.closure_latency),
            ("keyframe_processing_ms", &self.keyframe_time),
        ] {
            if let Some((p50, p99, max)) = l.summary() {
                proc.push(kv(&format!("{name}.p50"), format!("{p50:.3}")));
                proc.push(kv(&format!("{name}.p99"), format!("{p99:.3}")));
                proc.push(kv(&format!("{name}.max"), format!("{max:.3}")));
            }
        }
        let status =
            |name: &str, level: u8, message: String, values: Vec<KeyValue>| DiagnosticStatus {
                level,
                name: format!("dc_loc: {name}"),
                message,
                hardware_id: self.hardware_id.clone(),
                values,
            };
        let msg = DiagnosticArray {
            header: Header {
                stamp: self.now(),
                frame_id: String::new(),
            },
            status: vec![
                status(
                    "input",
                    DiagnosticStatus::OK,
                    "messages received".into(),
                    input,
                ),
                status(
                    "dropped",
                    if total_dropped > 0 {
                        DiagnosticStatus::WARN
                    } else {
                        DiagnosticStatus::OK
                    },
                    format!("{total_dropped} messages not used"),
                    drop_values,
                ),
                status(
                    "processing",
                    DiagnosticStatus::OK,
                    format!(
                        "{} keyframes, {} closures",
                        stats.keyframes, self.closures_published
                    ),
                    proc,
                ),
            ],
        };
        if let Err(e) = self.out.diagnostics.publish(msg) {
            log::debug!("diagnostics: {e:?}");
        }
    }
}

fn save_map(records: &[Arc<KeyframeRecord>], place: &crate::place::PlaceConfig, path: &Path) {
    let t0 = Instant::now();
    match save_records(records, place, path) {
        Ok(()) => log::info!(
            "map saved: {} keyframes to {} in {:.0} ms",
            records.len(),
            path.display(),
            t0.elapsed().as_secs_f64() * 1e3
        ),
        Err(e) => log::error!("map not saved: {e}"),
    }
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
