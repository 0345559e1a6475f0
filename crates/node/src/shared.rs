//! What the reception tasks and the worker share: counters ([`Shared`]), the bounded queue of work
//! between them ([`Inbox`], [`Work`]), and the node's clock ([`receive_time`]).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{SyncSender, TrySendError};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant, SystemTime};

use dc_loc_core::input::Input;
use dc_loc_core::math::Stamp;

/// Counters shared by the reception tasks and the worker.
#[derive(Default)]
pub struct Shared {
    /// Messages received per input (radar name or `odometry`).
    pub received: Mutex<BTreeMap<String, u64>>,
    /// Messages not used, by reason.
    pub dropped: Mutex<BTreeMap<String, u64>>,
    /// Matched publishers per input.
    pub publishers: Mutex<BTreeMap<String, usize>>,
    /// Messages in the queue now.
    pub queued: AtomicUsize,
    /// Most messages ever queued.
    pub queued_max: AtomicUsize,
    /// Messages held by the worker to be put in stamp order.
    pub held: AtomicUsize,
    /// `/clock` time, ns (sim time).
    pub clock_ns: AtomicI64,
    /// A shutdown was asked for: the worker saves the map first, then drains the queue.
    pub stopping: AtomicBool,
    /// Subscriptions discovered on `~/markers` and `~/submap`: with none, the worker does not publish
    /// them (rustdds keeps up to 8192 unread samples of a writer without readers, and ros2-client
    /// cannot set the ResourceLimits that would bound them).
    pub map_view_readers: [AtomicUsize; 2],
    /// Other robots' keyframes dropped at reception beyond `node.fleet_rate`, by robot.
    pub fleet_flood: Mutex<BTreeMap<i32, u64>>,
    /// Rate limiting of warnings: reason -> (last warning, suppressed since).
    warned: Mutex<BTreeMap<String, (Instant, u64)>>,
    /// `node.warn_interval`, ns.
    warn_interval_ns: AtomicU64,
}

/// The guarded value, also after a panic elsewhere poisoned the lock (counters stay usable).
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Shared {
    /// Counters that warn of one reason at most every `warn_interval`.
    pub fn new(warn_interval: Duration) -> Self {
        let shared = Shared::default();
        shared.set_warn_interval(warn_interval);
        shared
    }

    /// A new `node.warn_interval`.
    pub fn set_warn_interval(&self, interval: Duration) {
        let ns = u64::try_from(interval.as_nanos()).unwrap_or(u64::MAX);
        self.warn_interval_ns.store(ns, Ordering::Relaxed);
    }

    fn warn_interval(&self) -> Duration {
        Duration::from_nanos(self.warn_interval_ns.load(Ordering::Relaxed))
    }

    /// One more message received on `input`.
    pub fn count_received(&self, input: &str) {
        *lock(&self.received).entry(input.to_string()).or_default() += 1;
    }

    /// Counts a dropped message and warns, at most once per `warn_interval` per reason.
    pub fn drop_msg(&self, reason: &str, detail: &str) {
        *lock(&self.dropped).entry(reason.to_string()).or_default() += 1;
        self.warn(reason, detail);
    }

    /// Warns, at most once per `warn_interval` per reason (the suppressed ones are counted).
    pub fn warn(&self, reason: &str, detail: &str) {
        let mut w = lock(&self.warned);
        let now = Instant::now();
        match w.get_mut(reason) {
            Some((last, suppressed)) if now.duration_since(*last) < self.warn_interval() => {
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
pub enum Work {
    /// An input for the pipeline.
    Input {
        /// The input.
        input: Box<Input>,
        /// The odometry's `header.frame_id` (the markers' frame).
        odom_frame: Option<String>,
        /// When it arrived.
        arrived: Instant,
    },
    /// Shutdown: everything before it has been processed.
    Stop,
}

/// Sends work to the worker without waiting; a full queue drops and counts.
#[derive(Clone)]
pub struct Inbox {
    tx: SyncSender<Work>,
    shared: Arc<Shared>,
}

impl Inbox {
    /// The sending side of the worker's queue.
    pub fn new(tx: SyncSender<Work>, shared: Arc<Shared>) -> Self {
        Inbox { tx, shared }
    }

    /// Queues `w`, or drops and counts it when the worker is behind.
    pub fn send(&self, w: Work) {
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

    /// Asks the worker to stop after what is queued (waiting for room: a stop is never dropped).
    pub fn stop(&self) {
        self.shared.queued.fetch_add(1, Ordering::SeqCst);
        if self.tx.send(Work::Stop).is_err() {
            self.shared.queued.fetch_sub(1, Ordering::SeqCst);
        }
    }
}

/// Now: `/clock` time with `use_sim_time`, else the system clock.
pub fn receive_time(shared: &Shared, use_sim_time: bool) -> Stamp {
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
