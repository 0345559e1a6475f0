//! The node's log on stderr and on `/rosout` (rcl_interfaces/Log), as ROS 2 nodes log: [`init`]
//! installs a logger that writes what env_logger lets through to stderr and hands dc_loc's own records
//! to a bounded queue; [`forward`] starts the thread that publishes them through the node's rosout
//! publisher once the node exists. Records of the DDS libraries stay on stderr only (publishing them
//! would log again). A full queue drops records (rosout is best effort; stderr has them all).
//! dc_loc's own level can change at run time ([`set_level`], `node.log_level`).

use std::sync::OnceLock;

use log::Log as _;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};

use ros2_client::builtin_interfaces::Time;
use ros2_client::log::LogLevel;
use ros2_client::rosout::{NodeLoggingHandle, RosoutRaw};

/// Records waiting for the rosout thread.
const QUEUE: usize = 1000;

/// One log record as rosout carries it.
struct Entry {
    level: LogLevel,
    msg: String,
    file: String,
    function: String,
    line: u32,
}

/// The queue to the rosout thread (set by [`init`] when rosout is on).
static QUEUE_TX: OnceLock<SyncSender<Entry>> = OnceLock::new();
/// Its other end, taken by [`forward`].
static QUEUE_RX: std::sync::Mutex<Option<Receiver<Entry>>> = std::sync::Mutex::new(None);

/// dc_loc's own level (a `log::LevelFilter` as usize); the other crates' levels stay env_logger's.
static DC_LOC_LEVEL: AtomicUsize = AtomicUsize::new(log::LevelFilter::Info as usize);
/// The most detailed level env_logger's filter lets through for any crate.
static FILTER_MAX: AtomicUsize = AtomicUsize::new(log::LevelFilter::Info as usize);

fn own(target: &str) -> bool {
    target.starts_with("dc_loc")
}

struct Tee {
    /// env_logger with dc_loc's records all let through (their level is [`DC_LOC_LEVEL`]'s).
    stderr: env_logger::Logger,
}

impl Tee {
    fn passes(&self, metadata: &log::Metadata<'_>) -> bool {
        if own(metadata.target()) {
            metadata.level() as usize <= DC_LOC_LEVEL.load(Ordering::Relaxed)
        } else {
            self.stderr.enabled(metadata)
        }
    }

    /// Whether `record` is rustdds' report that leaving the discovery multicast group failed as a
    /// socket closes. rustdds joins the group on each interface it uses but leaves it on the
    /// unspecified one, which the kernel refuses when the participant uses loopback only; the closing
    /// socket drops the membership anyway, so the report is harmless and goes out at debug level.
    fn harmless(record: &log::Record<'_>) -> bool {
        record.target() == "rustdds::network::udp_listener"
            && record.level() == log::Level::Error
            && record
                .args()
                .to_string()
                .starts_with("leave_multicast_group")
    }
}

impl log::Log for Tee {
    fn enabled(&self, metadata: &log::Metadata<'_>) -> bool {
        self.passes(metadata)
    }

    fn log(&self, record: &log::Record<'_>) {
        if !self.passes(record.metadata()) {
            return;
        }
        if Self::harmless(record) {
            let metadata = log::Metadata::builder()
                .target(record.target())
                .level(log::Level::Debug)
                .build();
            if self.stderr.enabled(&metadata) {
                self.stderr.log(
                    &log::Record::builder()
                        .metadata(metadata)
                        .args(*record.args())
                        .module_path(record.module_path())
                        .file(record.file())
                        .line(record.line())
                        .build(),
                );
            }
            return;
        }
        self.stderr.log(record);
        let Some(tx) = QUEUE_TX.get() else { return };
        if !own(record.target()) {
            return;
        }
        let entry = Entry {
            level: level(record.level()),
            msg: record.args().to_string(),
            file: record.file().unwrap_or_default().to_string(),
            function: record.module_path().unwrap_or_default().to_string(),
            line: record.line().unwrap_or(0),
        };
        if let Err(TrySendError::Disconnected(_)) = tx.try_send(entry) {
            // The node is gone: stderr only from here on.
        }
    }

    fn flush(&self) {
        self.stderr.flush();
    }
}

fn level(l: log::Level) -> LogLevel {
    match l {
        log::Level::Error => LogLevel::Error,
        log::Level::Warn => LogLevel::Warn,
        log::Level::Info => LogLevel::Info,
        log::Level::Debug | log::Level::Trace => LogLevel::Debug,
    }
}

/// The most detailed level env_logger's filter lets through for `target`.
fn level_of(logger: &env_logger::Logger, target: &str) -> log::LevelFilter {
    let levels = [
        log::Level::Trace,
        log::Level::Debug,
        log::Level::Info,
        log::Level::Warn,
        log::Level::Error,
    ];
    levels
        .into_iter()
        .find(|&level| {
            logger.enabled(&log::Metadata::builder().target(target).level(level).build())
        })
        .map_or(log::LevelFilter::Off, |l| l.to_level_filter())
}

/// Sets dc_loc's own level.
pub fn set_level(level: log::LevelFilter) {
    DC_LOC_LEVEL.store(level as usize, Ordering::Relaxed);
    let other = FILTER_MAX.load(Ordering::Relaxed);
    let max = [
        log::LevelFilter::Off,
        log::LevelFilter::Error,
        log::LevelFilter::Warn,
        log::LevelFilter::Info,
        log::LevelFilter::Debug,
        log::LevelFilter::Trace,
    ]
    .into_iter()
    .find(|l| *l as usize == other.max(level as usize))
    .unwrap_or(log::LevelFilter::Trace);
    // Records above every filter are not even formatted.
    log::set_max_level(max);
}

/// Installs the logger: env_logger's filter (from `builder()`) and format on stderr, dc_loc's level
/// `level` or else the filter's, and, when `rosout` is true, dc_loc's records queued for `/rosout`.
pub fn init(
    builder: impl Fn() -> env_logger::Builder,
    level: Option<log::LevelFilter>,
    rosout: bool,
) {
    let probe = builder().build();
    FILTER_MAX.store(probe.filter() as usize, Ordering::Relaxed);
    let configured = level_of(&probe, "dc_loc");
    let stderr = builder()
        .filter_module("dc_loc", log::LevelFilter::Trace)
        .build();
    if rosout {
        let (tx, rx) = sync_channel(QUEUE);
        let _ = QUEUE_TX.set(tx);
        *QUEUE_RX.lock().unwrap_or_else(|e| e.into_inner()) = Some(rx);
    }
    if log::set_boxed_logger(Box::new(Tee { stderr })).is_ok() {
        set_level(level.unwrap_or(configured));
    }
}

/// Publishes the queued records on `/rosout` through `handle` (the node's) under the logger name
/// `logger` (the node's, `car1.loc` for `/car1/loc`), on a thread of its own, until the process ends.
pub fn forward(handle: NodeLoggingHandle, logger: String) {
    let Some(rx) = QUEUE_RX.lock().unwrap_or_else(|e| e.into_inner()).take() else {
        return;
    };
    let spawned = std::thread::Builder::new()
        .name("dc_loc-rosout".into())
        .spawn(move || {
            for e in rx {
                handle.rosout_raw(
                    Time::now(),
                    e.level,
                    &logger,
                    &e.msg,
                    &e.file,
                    &e.function,
                    e.line,
                );
            }
        });
    if let Err(e) = spawned {
        log::warn!("no /rosout: cannot start its thread: {e}");
    }
}
