//! The worker thread: owns the [`Pipeline`], takes the queued inputs in stamp order across topics
//! ([`StampMerger`], at most `node.sync_timeout` of waiting) so that the pipeline sees the sequence
//! `dc_loc run` reads from a bag, and publishes closures, markers, the submap and the radar odometry
//! as they come, diagnostics every `node.diagnostics_period`; the map is saved by [`MapSaver`].

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use super::backends::{GraphFrames, lio_sam_pair, pose_graph};
use super::convert::{MarkerArray, MarkerPoint, markers, submap_cloud};
use super::diagnostics::{Diagnostics, Measures, Report};
use super::endpoints::Outputs;
use super::map_store::MapSaver;
use super::merge::StampMerger;
use super::odometry::{odometry_msg, odometry_tf};
use super::services::{SaveRequest, TriggerResponse, relocalized};
use super::shared::{Shared, Work, receive_time};
use dc_loc_core::fleet::{FleetState, wire};
use dc_loc_core::input::Input;
use dc_loc_core::keyframe_db::KeyframeRecord;
use dc_loc_core::loop_closure::LoopClosure;
use dc_loc_core::math::{Iso3, Stamp};
use dc_loc_core::msgs::builtin_interfaces::Time;
use dc_loc_core::odometry::OdometryEstimate;
use dc_loc_core::output::loop_closure_msg;
use dc_loc_core::pipeline::{Event, Pipeline};
use dc_loc_io::params::live::LiveParams;
use dc_loc_io::params::node::NodeSettings;

/// This session's newest keyframe positions (odometry frame) and closure edges, for `~/markers`: at
/// most `cap` of each (`map.max_keyframes`), the oldest leaving first, so a long run's markers stay
/// bounded.
struct Markers {
    frame: String,
    cap: usize,
    points: BTreeMap<u64, MarkerPoint>,
    edges: VecDeque<(MarkerPoint, MarkerPoint)>,
}

impl Markers {
    fn keyframe(&mut self, id: u64, t_odom_body: &Iso3) {
        let p = t_odom_body.translation.vector;
        self.points.insert(id, MarkerPoint { x: p.x, y: p.y });
        while self.points.len() > self.cap {
            self.points.pop_first();
        }
    }

    /// An edge between two keyframes of this session's odometry frame (a loaded map's keyframes are
    /// in another frame, another robot's in that robot's, and its ids are of its own sequence).
    fn closure(&mut self, c: &LoopClosure) {
        if c.match_origin.is_some() {
            return;
        }
        if let (Some(a), Some(b)) = (self.points.get(&c.query_id), self.points.get(&c.match_id)) {
            self.edges.push_back((*a, *b));
            while self.edges.len() > self.cap {
                self.edges.pop_front();
            }
        }
    }

    /// Points of the markers message: one per keyframe, two per edge.
    fn point_count(&self) -> usize {
        self.points.len() + 2 * self.edges.len()
    }

    fn message(&self, now: Time) -> MarkerArray {
        let kfs: Vec<MarkerPoint> = self.points.values().copied().collect();
        let edges: Vec<(MarkerPoint, MarkerPoint)> = self.edges.iter().copied().collect();
        markers(now, &self.frame, &kfs, &edges)
    }
}

/// What reaches the worker besides inputs: run-time parameter changes and `~/save_map` requests.
pub struct Controls {
    /// Checked parameter changes.
    pub live: Arc<LiveParams>,
    /// Saves asked for.
    pub save_requests: Receiver<SaveRequest>,
}

/// The pipeline and everything that reports on it.
pub struct Worker {
    pipeline: Pipeline,
    out: Outputs,
    shared: Arc<Shared>,
    settings: NodeSettings,
    body_frame: String,
    markers: Markers,
    /// Keyframes or closures not yet in a `~/markers` message.
    markers_pending: bool,
    markers_sent: Option<Instant>,
    /// `DC_LOC_FAULT_WORKER_PANIC`: the worker panics at its first periodic tick, so that a supervisor
    /// setup can be tested against a dying node (README_NODE.md, Failure behaviour).
    fault_panic: bool,
    controls: Controls,
    measures: Measures,
    diagnostics: Diagnostics,
    saver: Option<MapSaver>,
}

impl Worker {
    /// A worker for `pipeline` (with its map loaded) publishing on `out`.
    pub fn new(
        mut pipeline: Pipeline,
        out: Outputs,
        shared: Arc<Shared>,
        settings: NodeSettings,
        saver: Option<MapSaver>,
        hardware_id: String,
        controls: Controls,
    ) -> Self {
        let mut markers = Markers {
            frame: settings.odom_frame.clone(),
            cap: pipeline.config().map.max_keyframes,
            points: BTreeMap::new(),
            edges: VecDeque::new(),
        };
        for r in pipeline.db().records() {
            if r.session == pipeline.session() {
                markers.keyframe(r.id, &r.odom_pose_iso3());
            }
        }
        // The range check of `node.robot_id` keeps it within i32.
        pipeline.set_robot(i32::try_from(settings.backends.robot_id).unwrap_or(i32::MAX));
        pipeline.set_restart_after(settings.restart_after);
        pipeline.set_input_limits(settings.limits);
        Worker {
            body_frame: pipeline.config().body_frame.clone(),
            pipeline,
            out,
            shared,
            settings,
            markers,
            markers_pending: true,
            markers_sent: None,
            fault_panic: std::env::var_os("DC_LOC_FAULT_WORKER_PANIC").is_some(),
            controls,
            measures: Measures::default(),
            diagnostics: Diagnostics::new(hardware_id),
            saver,
        }
    }

    fn now(&self) -> Time {
        receive_time(&self.shared, self.settings.use_sim_time).into()
    }

    /// Processes the queue until a shutdown: then saves the map first, processes what is queued up
    /// to [`Work::Stop`] for at most `node.shutdown_timeout` (the rest is dropped and counted), saves
    /// the map again and returns the final save's error, if any.
    pub fn run(mut self, rx: Receiver<Work>) -> Result<(), String> {
        let n_radars = self.pipeline.config().radar_names.len();
        // Streams: each radar, then the pose input (odometry or gyro).
        let mut merger: StampMerger<Work> = StampMerger::new(
            n_radars + 1,
            Duration::from_secs_f64(self.settings.sync_timeout),
            Duration::from_secs(1),
        );
        let mut deadline: Option<Instant> = None;
        loop {
            let now = Instant::now();
            if deadline.is_none() && self.shared.stopping.load(Ordering::SeqCst) {
                self.save_first();
                let timeout = Duration::from_secs_f64(self.settings.shutdown_timeout);
                deadline = Some(Instant::now() + timeout);
            }
            if deadline.is_some_and(|d| now >= d) {
                self.drop_rest(&rx);
                break;
            }
            let period = self.settings.diagnostics_period;
            let since = self.diagnostics.since_last();
            let mut wait = Duration::from_secs_f64((period - since).max(0.0));
            let markers_due = self.markers_due();
            if let Some(d) = merger
                .deadline()
                .into_iter()
                .chain(deadline)
                .chain(markers_due)
                .min()
            {
                wait = wait.min(d.saturating_duration_since(now));
            }
            match rx.recv_timeout(wait) {
                Err(RecvTimeoutError::Disconnected) => break,
                Ok(w) => {
                    self.shared.queued.fetch_sub(1, Ordering::SeqCst);
                    if matches!(w, Work::Stop) {
                        break;
                    }
                    // Other robots' keyframes keep no time order with this robot's inputs.
                    if matches!(&w, Work::Input { input, .. } if matches!(input.as_ref(), Input::Keyframe(_)))
                    {
                        self.handle(w);
                    } else {
                        let (stream, stamp) = stream_of(&w, n_radars);
                        merger.push(stream, stamp, Instant::now(), w);
                    }
                }
                Err(RecvTimeoutError::Timeout) => {}
            }
            self.take_live_parameters();
            self.serve_save_requests();
            while let Some(w) = merger.pop_ready(Instant::now()) {
                self.handle(w);
            }
            self.shared.held.store(merger.len(), Ordering::SeqCst);
            if markers_due.is_some_and(|d| Instant::now() >= d) {
                self.publish_markers();
            }
            if self.diagnostics.since_last() >= period {
                assert!(!self.fault_panic, "DC_LOC_FAULT_WORKER_PANIC is set");
                self.publish_diagnostics();
            }
            if let Some(s) = &mut self.saver {
                s.maybe_save(self.pipeline.db());
            }
        }
        self.shutdown(merger)
    }

    /// A run-time parameter change (`ros2 param set`), already checked: the gates and the keyframe
    /// spacing to the pipeline, the periods and the log level here.
    fn take_live_parameters(&mut self) {
        let Some((cfg, settings)) = self.controls.live.take_pending() else {
            return;
        };
        self.pipeline.update_live(&cfg);
        self.shared
            .set_warn_interval(Duration::from_secs_f64(settings.warn_interval));
        if let Some(level) = settings.log_filter() {
            super::rosout::set_level(level);
        }
        self.settings.diagnostics_period = settings.diagnostics_period;
        self.settings.warn_interval = settings.warn_interval;
        self.settings.markers_period = settings.markers_period;
        self.settings.keyframe_budget = settings.keyframe_budget;
        self.settings.log_level = settings.log_level;
    }

    /// `~/save_map`: the map saved now, between two inputs.
    fn serve_save_requests(&mut self) {
        while let Ok(reply) = self.controls.save_requests.try_recv() {
            let response = match &mut self.saver {
                None => TriggerResponse {
                    success: false,
                    message: "no map.file is set: nothing to save to".into(),
                },
                Some(s) => match s.save_now(self.pipeline.db()) {
                    None => TriggerResponse {
                        success: true,
                        message: format!(
                            "{} keyframes saved to {}",
                            self.pipeline.db().len(),
                            s.path().display()
                        ),
                    },
                    Some(e) => TriggerResponse {
                        success: false,
                        message: format!("not saved: {e}"),
                    },
                },
            };
            let _ = reply.send(response);
        }
    }

    /// The map saved before the queue is drained, so that a supervisor's kill timeout cannot lose it.
    fn save_first(&mut self) {
        if let Some(s) = &mut self.saver {
            s.save_now(self.pipeline.db());
        }
    }

    /// What is still queued when the shutdown's time is up: dropped and counted.
    fn drop_rest(&mut self, rx: &Receiver<Work>) {
        let mut n = 0u64;
        while let Ok(w) = rx.try_recv() {
            self.shared.queued.fetch_sub(1, Ordering::SeqCst);
            if matches!(w, Work::Input { .. }) {
                n += 1;
            }
        }
        if n > 0 {
            log::warn!(
                "node.shutdown_timeout ({} s) passed: {n} queued messages not processed",
                self.settings.shutdown_timeout
            );
            *super::shared::lock(&self.shared.dropped)
                .entry("shutdown_timeout".into())
                .or_default() += n;
        }
    }

    /// The held inputs and the pipeline's last events, the final diagnostics and map save.
    fn shutdown(mut self, mut merger: StampMerger<Work>) -> Result<(), String> {
        while let Some(w) = merger.pop_any() {
            self.handle(w);
        }
        self.shared.held.store(0, Ordering::SeqCst);
        let events = self.pipeline.finish();
        self.handle_events(events, None);
        if self.markers_pending {
            self.publish_markers();
        }
        self.publish_diagnostics();
        let saved = match self.saver.take() {
            Some(s) => s.finish(self.pipeline.db()).map_or(Ok(()), Err),
            None => Ok(()),
        };
        let published = self.measures.closures_published;
        log::info!(
            "stopped: {} keyframes, {published} closures published",
            self.pipeline.stats().keyframes,
        );
        // Give reliable readers a moment to fetch the last samples before the writers go away.
        if published > 0 || self.measures.odometry_published > 0 {
            std::thread::sleep(Duration::from_millis(300));
        }
        saved
    }

    /// One input through the pipeline's input path (the one `dc_loc run` uses): decoding, stamps going
    /// backwards, duplicate stamps and odometry gaps are checked and counted there.
    fn handle(&mut self, w: Work) {
        let Work::Input {
            input,
            odom_frame,
            arrived,
        } = w
        else {
            return;
        };
        let t0 = Instant::now();
        let deadline = (self.settings.keyframe_budget > 0.0)
            .then(|| arrived + Duration::from_secs_f64(self.settings.keyframe_budget));
        self.pipeline.set_deadline(deadline);
        let events = self.pipeline.push(&input);
        let accepted = !events.iter().any(|e| matches!(e, Event::Dropped { .. }));
        if let Some(frame) = odom_frame.filter(|f| accepted && !f.is_empty()) {
            self.markers.frame = frame;
        }
        let keyframe = events.iter().any(|e| matches!(e, Event::Keyframe { .. }));
        self.handle_events(events, Some(arrived));
        if keyframe {
            self.measures.keyframe_time.push(t0.elapsed().as_secs_f64());
            if deadline.is_some_and(|d| Instant::now() > d) {
                self.measures.late_keyframes += 1;
            }
        }
        self.measures
            .input_latency
            .push(arrived.elapsed().as_secs_f64());
    }

    fn handle_events(&mut self, events: Vec<Event>, arrived: Option<Instant>) {
        let mut changed = false;
        for e in events {
            match e {
                Event::Keyframe {
                    id,
                    t_odom_body,
                    record,
                    fleet,
                    ..
                } => {
                    self.markers.keyframe(id, &t_odom_body);
                    self.share_keyframe(&record, &fleet);
                    changed = true;
                }
                Event::Closure(c) => {
                    self.publish_closure(&c, arrived);
                    self.markers.closure(&c);
                    changed = true;
                }
                Event::Rejected { .. } => {}
                Event::Odometry(e) => self.publish_odometry(&e),
                // Counted in the pipeline's stats and logged there, the first of each cause in full.
                Event::Dropped { .. } => {}
                Event::EmptyScan { detail } => self.shared.warn("empty_cloud", &detail),
                Event::TimeReset { previous, got } => self.shared.warn(
                    "time_reset",
                    &format!(
                        "time went back from {:.3} s to {:.3} s: pipeline reset, keyframes kept",
                        previous.as_secs_f64(),
                        got.as_secs_f64()
                    ),
                ),
            }
        }
        if changed {
            self.publish_map_views();
        }
    }

    fn publish_closure(&mut self, c: &LoopClosure, arrived: Option<Instant>) {
        let msg = loop_closure_msg(c, &self.body_frame);
        match self.out.closures.publish(msg) {
            Ok(()) => self.measures.closures_published += 1,
            Err(e) => log::error!(
                "loop closure {} -> {}: publish failed: {e:?}",
                c.query_id,
                c.match_id
            ),
        }
        let session = self.pipeline.session();
        if let Some(pose) = relocalized(c, session, self.now(), &self.settings.map_frame)
            && let Err(e) = self.out.relocalized.publish(pose)
        {
            log::debug!("relocalized: {e:?}");
        }
        // The back ends' own formats (off unless `node.pose_graph_output`, `node.lio_sam_output`).
        if let Some(p) = &self.out.pose_graph {
            let frames = GraphFrames {
                body: &self.body_frame,
                odom: &self.markers.frame,
                map: &self.settings.map_frame,
                session,
            };
            if let Err(e) = p.publish(pose_graph(c, &frames)) {
                log::warn!(
                    "pose graph {} -> {}: publish failed: {e:?}",
                    c.match_id,
                    c.query_id
                );
            }
        }
        if let Some(p) = &self.out.lio_sam
            && let Err(e) = p.publish(lio_sam_pair(c))
        {
            log::warn!(
                "LIO-SAM pair {} -> {}: publish failed: {e:?}",
                c.query_id,
                c.match_id
            );
        }
        if let Some(a) = arrived {
            self.measures
                .closure_latency
                .push(a.elapsed().as_secs_f64());
        }
        log::debug!(
            "published loop closure {} -> {} ({} inliers, overlap {:.2})",
            c.query_id,
            c.match_id,
            c.inliers,
            c.score
        );
    }

    /// A radar odometry sample on `~/odometry` and, with `node.odometry_tf`, on `/tf`.
    fn publish_odometry(&mut self, e: &OdometryEstimate) {
        let frame = &self.settings.odom_frame;
        if let Some(p) = &self.out.odometry {
            match p.publish(odometry_msg(e, frame, &self.body_frame)) {
                Ok(()) => self.measures.odometry_published += 1,
                Err(e) => log::debug!("odometry: {e:?}"),
            }
        }
        if let Some(p) = &self.out.tf
            && let Err(e) = p.publish(odometry_tf(e, frame, &self.body_frame))
        {
            log::debug!("/tf: {e:?}");
        }
    }

    /// A new keyframe to the fleet (`node.fleet`).
    fn share_keyframe(&self, record: &KeyframeRecord, fleet: &FleetState) {
        let Some(p) = &self.out.keyframes else { return };
        let robot = self.pipeline.robot();
        let points = self.settings.fleet.points;
        let msg = wire::encode(robot, record, fleet, points, &self.body_frame);
        if let Err(e) = p.publish(msg) {
            log::warn!("keyframe {}: publish to the fleet failed: {e:?}", record.id);
        }
    }

    /// Subscriptions discovered on `~/markers` (0) or `~/submap` (1).
    fn readers(&self, view: usize) -> usize {
        self.shared.map_view_readers[view].load(Ordering::SeqCst)
    }

    /// When the pending markers are due (`None`: nothing pending, or nobody subscribes: they wait for
    /// the first subscriber).
    fn markers_due(&self) -> Option<Instant> {
        let period = Duration::from_secs_f64(self.settings.markers_period);
        (self.markers_pending && self.readers(0) > 0)
            .then(|| self.markers_sent.map_or_else(Instant::now, |t| t + period))
    }

    /// The session's keyframes and closures on `~/markers`.
    fn publish_markers(&mut self) {
        let msg = self.markers.message(self.now());
        if let Err(e) = self.out.markers.publish(msg) {
            log::debug!("markers: {e:?}");
        }
        self.markers_pending = false;
        self.markers_sent = Some(Instant::now());
    }

    /// The markers (when due) and the current submap (when someone subscribes).
    fn publish_map_views(&mut self) {
        self.markers_pending = true;
        self.measures.markers_points = self.markers.point_count();
        if self.readers(1) > 0
            && let Some(s) = self.pipeline.current_submap()
            && let Err(e) = self.out.submap.publish(submap_cloud(&s, &self.body_frame))
        {
            log::debug!("submap: {e:?}");
        }
    }

    fn publish_diagnostics(&mut self) {
        let report = Report {
            now: self.now(),
            stats: self.pipeline.stats(),
            map_keyframes: self.pipeline.db().len(),
            queue_size: self.settings.queue_size,
            measures: &self.measures,
            map_save: self.saver.as_ref().map(|s| s.status()),
            radar_names: &self.pipeline.config().radar_names,
        };
        let msg = self.diagnostics.message(&self.shared, &report);
        if let Err(e) = self.out.diagnostics.publish(msg) {
            log::debug!("diagnostics: {e:?}");
        }
    }
}

/// The merger's stream of an input (each radar, then the pose input: odometry or gyro) and its stamp.
fn stream_of(w: &Work, n_radars: usize) -> (usize, Stamp) {
    match w {
        Work::Input { input, .. } => match input.as_ref() {
            Input::Radar { radar, .. } => (*radar, input.stamp()),
            Input::Scan(scan) => (scan.radar, scan.stamp),
            _ => (n_radars, input.stamp()),
        },
        Work::Stop => (n_radars, Stamp(0)),
    }
}
