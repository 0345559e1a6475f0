//! The ROS 2 node: DDS reception on the executor, the [`Pipeline`] on a worker thread of its own.
//!
//! [`run`], in order: parse the command line and the environment ([`super::args`]) and the parameters
//! ([`dc_loc_io::params`] plus the node's own, [`super::settings`]); load the keyframe map; make the DDS
//! participant (loopback only when `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`) and the node with every
//! parameter declared; subscribe the inputs and create the outputs; start the worker
//! ([`super::worker`]); then receive ([`super::inputs`]: one task per subscription, a bounded queue to
//! the worker) until SIGINT/SIGTERM, when the worker drains the queue (the last closures are
//! published), saves the map and ends; entities are dropped before the context.

use std::net::Ipv4Addr;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use ros2_client::{Context, Node, NodeName, NodeOptions, ParameterValue};
use serde_json::Value;

use super::args::{ArgsError, DdsEnv, DiscoveryRange, RosArgs};
use super::endpoints::{Subscriptions, outputs, tf_static};
pub use super::error::NodeError;
use super::error::dds;
use super::inputs::Reception;
use super::map_store::{LoadedMap, MapSaver, load_map};
use super::security::SecurityEnv;
use super::services::SaveRequests;
use super::shared::{Inbox, Shared, Work};
use super::tf::static_extrinsics;
use super::worker::{Controls, Worker};
use dc_loc_core::pipeline::{Config, Pipeline};
use dc_loc_io::params::checks::defaulted_noise;
use dc_loc_io::params::live::LiveParams;
use dc_loc_io::params::node::{NodeSettings, all_params, describe};
use dc_loc_io::params::{ParamSet, apply};

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
    /// The keyframe map, loaded (or empty); `None` until the extrinsics are known when they come from
    /// `/tf_static` (the map records the extrinsics it was made with).
    pub map: Option<LoadedMap>,
    /// The parameters as given (what run-time changes start from).
    pub params: ParamSet,
}

/// Reads the parameters and the map: everything that can refuse a start before DDS is touched.
pub fn start_up(ros_args: &RosArgs) -> Result<StartUp, NodeError> {
    let params = ros_args.param_set()?;
    let (settings, rest) = NodeSettings::take_from(&params)?;
    let cfg = apply(&rest)?;
    for warning in defaulted_noise(&params, &cfg) {
        log::warn!("{warning}");
    }
    let map = if settings.extrinsics_from_tf {
        None
    } else {
        Some(load_map(&cfg).map_err(NodeError::Map)?)
    };
    Ok(StartUp {
        cfg,
        settings,
        map,
        params,
    })
}

/// Replaces the radars' extrinsics by their `/tf_static` transforms, waiting for them at most
/// `node.tf_timeout` (the spinner runs meanwhile: `runtime` drives it).
fn tf_extrinsics(
    runtime: &tokio::runtime::Runtime,
    node: &mut Node,
    ros_args: &RosArgs,
    settings: &NodeSettings,
    cfg: &mut Config,
) -> Result<(), NodeError> {
    let frames = cfg.radar_frames();
    let sub = tf_static(node, ros_args)?;
    log::info!(
        "waiting up to {} s for the /tf_static transforms from `{}` to {frames:?}",
        settings.tf_timeout,
        cfg.body_frame
    );
    let timeout = Duration::from_secs_f64(settings.tf_timeout);
    let found = runtime.block_on(static_extrinsics(&sub, &cfg.body_frame, &frames, timeout))?;
    cfg.set_extrinsics(&found, "/tf_static");
    cfg.validate().map_err(|e| NodeError::Param(e.into()))
}

fn run(ros_args: &RosArgs) -> Result<(), NodeError> {
    let env = DdsEnv::from_env(|k| std::env::var(k).ok())?;
    let enclave = SecurityEnv::from_env(|k| std::env::var(k).ok())
        .enclave_dir(ros_args.enclave.as_deref())?;
    let StartUp {
        mut cfg,
        settings,
        map,
        params,
    } = start_up(ros_args)?;
    if let Some(level) = settings.log_filter() {
        super::rosout::set_level(level);
    }
    let live = Arc::new(LiveParams::new(&params));
    let (save_tx, save_rx) = SaveRequests::channel();
    log::info!(
        "dc_loc node {} (ROS_DOMAIN_ID {}, discovery {:?}, {}), effective configuration:\n{}",
        ros_args.fully_qualified_name(),
        env.domain_id,
        env.range,
        enclave
            .as_ref()
            .map_or("unsecured".to_string(), |d| format!(
                "DDS security with the enclave {}",
                d.display()
            )),
        describe(&cfg, &settings)
    );
    let runtime = runtime()?;
    let _entered = runtime.enter();
    let context = dds_context(&env, enclave.as_deref())?;
    let mut node = make_node(&context, ros_args, &cfg, &settings, live.clone())?;
    super::rosout::forward(node.logging_handle(), ros_args.logger_name());
    let spin_task = tokio::spawn(node.spinner().map_err(dds("spinner"))?.spin());
    if settings.extrinsics_from_tf {
        tf_extrinsics(&runtime, &mut node, ros_args, &settings, &mut cfg)?;
    }
    let LoadedMap {
        db,
        save_to,
        lock: _lock,
    } = match map {
        Some(m) => m,
        None => load_map(&cfg).map_err(NodeError::Map)?,
    };
    let secured = enclave.is_some().then(|| context.domain_participant());
    let subs = Subscriptions::new(&mut node, ros_args, &cfg, &settings, secured)?;
    let outputs = outputs(&mut node, ros_args, &cfg)?;

    let shared = Arc::new(Shared::new(Duration::from_secs_f64(settings.warn_interval)));
    let (tx, rx) = std::sync::mpsc::sync_channel::<Work>(settings.queue_size);
    let inbox = Inbox::new(tx, shared.clone());
    let saver =
        save_to.map(|path| MapSaver::new(path, cfg.map_shape(), cfg.map.save_interval, &db));
    let pipeline = Pipeline::with_map(cfg.clone(), db).map_err(|e| NodeError::Param(e.into()))?;
    let controls = Controls {
        live,
        save_requests: save_rx,
    };
    let name = ros_args.fully_qualified_name();
    let worker = Worker::new(
        pipeline,
        outputs,
        shared.clone(),
        settings.clone(),
        saver,
        name,
        controls,
    );
    let (worker, done_rx) = spawn_worker(worker, rx)?;
    let stop = stop_signal();
    println!("dc_loc: node {} running", ros_args.fully_qualified_name());
    let reception = Reception {
        shared: shared.clone(),
        inbox: inbox.clone(),
        use_sim_time: settings.use_sim_time,
    };
    let ended =
        runtime.block_on(subs.receive(&node, reception, settings.limits, stop, done_rx, save_tx));
    log::info!("shutting down: saving the map, then processing the queued messages");
    shared.stopping.store(true, Ordering::SeqCst);
    inbox.stop();
    drop(inbox);
    let result = worker.join();
    // Drop order: streams and entities, then the node (which tells its spinner to stop), the
    // spinner's own readers as it ends, and the context last: an entity dropped after the context
    // finds DDS gone and logs an error.
    drop(subs);
    drop(node);
    let spinner_ended = runtime.block_on(async {
        tokio::time::timeout(Duration::from_secs(2), spin_task)
            .await
            .is_ok()
    });
    if !spinner_ended {
        log::warn!("the ROS 2 spinner did not stop within 2 s");
    }
    drop(context);
    let saved = result.map_err(|_| NodeError::Runtime("the worker thread panicked".into()))?;
    if let Some(why) = ended {
        return Err(NodeError::Runtime(why));
    }
    saved.map_err(|e| NodeError::Runtime(format!("the map was not saved at shutdown: {e}")))
}

/// One tokio thread runs DDS reception, the spinner and the timers; the pipeline has a thread of its
/// own ([`spawn_worker`]).
fn runtime() -> Result<tokio::runtime::Runtime, NodeError> {
    tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .map_err(|e| NodeError::Runtime(format!("tokio runtime: {e}")))
}

/// The worker's thread: its result is the final map save's.
type WorkerThread = JoinHandle<Result<(), String>>;

/// The worker on its thread, and a signal when it ends (before a stop was asked for, the node cannot
/// go on).
fn spawn_worker(
    worker: Worker,
    rx: std::sync::mpsc::Receiver<Work>,
) -> Result<(WorkerThread, tokio::sync::oneshot::Receiver<()>), NodeError> {
    let (done_tx, done_rx) = tokio::sync::oneshot::channel::<()>();
    let handle = std::thread::Builder::new()
        .name("dc_loc-worker".into())
        .spawn(move || {
            let result = worker.run(rx);
            let _ = done_tx.send(());
            result
        })
        .map_err(|e| NodeError::Runtime(format!("worker thread: {e}")))?;
    Ok((handle, done_rx))
}

/// The DDS participant and context: loopback only when asked (ros2-client reads neither
/// `ROS_DOMAIN_ID` nor `ROS_AUTOMATIC_DISCOVERY_RANGE` itself), secured with `enclave` when given
/// (its key unencrypted, as sros2 writes it). A participant the enclave's files do not make (a
/// certificate not signed by its CA, a document whose signature fails) is a configuration error.
fn dds_context(env: &DdsEnv, enclave: Option<&Path>) -> Result<Context, NodeError> {
    use ros2_client::dds::rustdds::{self, DomainParticipantBuilder};
    let mut builder = DomainParticipantBuilder::new(env.domain_id);
    if env.range != DiscoveryRange::Subnet {
        builder = builder.with_only_networks([Ipv4Addr::LOCALHOST]);
    }
    if let Some(dir) = enclave {
        let files = rustdds::DomainParticipantSecurityConfigFiles::with_ros_default_names(
            dir,
            String::new(),
        );
        builder = builder.builtin_security(files);
    }
    let participant = builder.build().map_err(|e| match enclave {
        Some(dir) => NodeError::Args(ArgsError::Security(format!(
            "the enclave {} does not make a secured participant: {e:?}",
            dir.display()
        ))),
        None => dds("domain participant")(e),
    })?;
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
