//! The reception side: one task per subscription takes messages off DDS, gives a zero stamp the
//! receive time, does the cheap checks (frame id, size, finite pose) and hands the input to the
//! worker through the bounded queue ([`take`]); reception never waits for registration. Each message
//! that is not used is counted by reason.

use std::collections::BTreeMap;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures::StreamExt;
use ros2_client::{MessageInfo, Node, Subscription};
use serde::de::DeserializeOwned;

use super::fleet_identity::FleetIdentity;
use super::shared::{Inbox, Shared, Work, lock, receive_time};
use dc_loc_core::input::imu_input as gyro_input;
use dc_loc_core::input::{Input, InputLimits, header_stamp, odometry_pose, radar_scan_input};
use dc_loc_core::math::Stamp;
use dc_loc_core::msgs::dc_loc::Keyframe as KeyframeMsg;
use dc_loc_core::msgs::nav_msgs::Odometry;
use dc_loc_core::msgs::radar_msgs::RadarScan;
use dc_loc_core::msgs::rosgraph_msgs::Clock;
use dc_loc_core::msgs::sensor_msgs::{Imu, PointCloud2};
use dc_loc_core::msgs::std_msgs::Header;
use dc_loc_core::radar::trigger::TriggerStamps;
use dc_loc_io::params::node::FleetSettings;

/// A message whose zero `header.stamp` the receive time replaces (drivers that leave it unset), as
/// `dc_loc run` takes a bag's log time.
pub trait Stamped {
    /// The message's header.
    fn header_mut(&mut self) -> &mut Header;
}

impl Stamped for PointCloud2 {
    fn header_mut(&mut self) -> &mut Header {
        &mut self.header
    }
}

impl Stamped for RadarScan {
    fn header_mut(&mut self) -> &mut Header {
        &mut self.header
    }
}

impl Stamped for Odometry {
    fn header_mut(&mut self) -> &mut Header {
        &mut self.header
    }
}

impl Stamped for Header {
    fn header_mut(&mut self) -> &mut Header {
        self
    }
}

impl Stamped for Imu {
    fn header_mut(&mut self) -> &mut Header {
        &mut self.header
    }
}

/// Why a message is not used: the counter's name and a detail for the warning.
pub type Refusal = (&'static str, String);

/// Where a subscription's messages go, and what the reception counts.
#[derive(Clone)]
pub struct Reception {
    /// The counters.
    pub shared: Arc<Shared>,
    /// The worker's queue.
    pub inbox: Inbox,
    /// Stamps from `/clock`.
    pub use_sim_time: bool,
}

/// Takes every message of `sub` (on `topic`) off DDS until the stream ends: each with a usable stamp
/// ([`received`]) is turned by `convert` into an input or a refusal (counted), and the input goes to
/// the worker.
pub async fn take<M, F>(topic: &str, sub: &Subscription<M>, r: Reception, mut convert: F)
where
    M: Stamped + DeserializeOwned + 'static,
    F: FnMut(M, &MessageInfo) -> Result<(Input, Option<String>), Refusal>,
{
    let mut stream = std::pin::pin!(sub.async_stream());
    while let Some(item) = stream.next().await {
        let arrived = Instant::now();
        let Some((msg, info)) = received(topic, item, &r) else {
            continue;
        };
        match convert(msg, &info) {
            Ok((input, odom_frame)) => r.inbox.send(Work::Input {
                input: Box::new(input),
                odom_frame,
                arrived,
            }),
            Err((reason, detail)) => r.shared.drop_msg(reason, &detail),
        }
    }
}

/// A message off DDS with a usable stamp: undecodable ones (`undecodable`) and stamps whose
/// `nanosec` is 1e9 or more (`bad_stamp`) are counted and give `None`; a zero stamp becomes the
/// receive time.
fn received<M: Stamped, I, E: std::fmt::Debug>(
    topic: &str,
    item: Result<(M, I), E>,
    r: &Reception,
) -> Option<(M, I)> {
    let (mut msg, info) = match item {
        Ok(m) => m,
        Err(e) => {
            r.shared.drop_msg("undecodable", &format!("{topic}: {e:?}"));
            return None;
        }
    };
    let header = msg.header_mut();
    if let Err(e) = header_stamp(header, Stamp(0)) {
        r.shared.drop_msg(e.name(), &format!("{topic}: {e}"));
        return None;
    }
    if Stamp::from(header.stamp) == Stamp(0) {
        header.stamp = receive_time(&r.shared, r.use_sim_time).into();
    }
    Some((msg, info))
}

/// The radars on one topic: (index in `radar_names`, name, expected `frame_id`; empty accepts any).
pub type TopicRadars = Vec<(usize, String, String)>;

/// A radar topic's subscription, by its message type (`radars.<name>.message`).
pub enum RadarSubscription {
    /// `sensor_msgs/PointCloud2`.
    Cloud(Subscription<PointCloud2>),
    /// `radar_msgs/RadarScan`.
    Scan(Subscription<RadarScan>),
}

/// The radar of `radars` whose frame is `got` (several radars may share a topic), counted as received;
/// refused when no configured radar has that frame.
fn radar_of(
    topic: &str,
    radars: &TopicRadars,
    shared: &Shared,
    got: &str,
) -> Result<usize, Refusal> {
    let Some((radar, name, _)) = radars
        .iter()
        .find(|(_, _, frame)| frame.is_empty() || frame == got)
    else {
        let configured: Vec<String> = radars
            .iter()
            .map(|(_, name, frame)| format!("`{frame}` (radars.{name}.frame_id)"))
            .collect();
        return Err((
            "unknown_frame",
            format!(
                "{topic}: frame_id `{got}` is not a configured radar frame: {}",
                configured.join(", ")
            ),
        ));
    };
    shared.count_received(name);
    Ok(*radar)
}

/// A cloud of `topic` as the input of the radar its `frame_id` names, refused when no configured radar
/// has that frame or it is larger than `limits`.
pub fn radar_input(
    topic: &str,
    radars: &TopicRadars,
    limits: &InputLimits,
    shared: &Shared,
    cloud: PointCloud2,
) -> Result<(Input, Option<String>), Refusal> {
    let radar = radar_of(topic, radars, shared, &cloud.header.frame_id)?;
    // Refused before the queue, so that huge clouds never wait in it.
    if let Err(e) = limits.check(&cloud) {
        return Err(("cloud_too_large", format!("{topic}: {e}")));
    }
    Ok((Input::Radar { radar, cloud }, None))
}

/// A radar input with its stamp from its radar's trigger (`radars.<name>.trigger_topic`), refused
/// (`no_trigger`) when no trigger has arrived since the radar's previous scan.
pub fn trigger_stamped(
    topic: &str,
    triggers: &Mutex<TriggerStamps>,
    received: Result<(Input, Option<String>), Refusal>,
) -> Result<(Input, Option<String>), Refusal> {
    let (input, frame) = received?;
    match input.with_trigger_stamp(&mut lock(triggers)) {
        Ok(input) => Ok((input, frame)),
        Err(e) => Err((e.name(), format!("{topic}: {e}"))),
    }
}

/// Takes every trigger on `topic` (a `std_msgs/Header` at the start of each frame of `radars`) off
/// DDS until the stream ends: its stamp ([`received`]) becomes those radars' newest trigger.
pub async fn triggers(
    topic: &str,
    sub: &Subscription<Header>,
    radars: &[usize],
    stamps: &Mutex<TriggerStamps>,
    r: Reception,
) {
    let mut stream = std::pin::pin!(sub.async_stream());
    while let Some(item) = stream.next().await {
        let Some((header, _)) = received(topic, item, &r) else {
            continue;
        };
        r.shared.count_received("trigger");
        let mut stamps = lock(stamps);
        for &radar in radars {
            stamps.trigger(radar, header.stamp.into());
        }
    }
}

/// A `radar_msgs/RadarScan` of `topic` as the input of the radar its `frame_id` names, refused as a
/// cloud is (its returns count as points, 20 bytes each).
pub fn radar_scan(
    topic: &str,
    radars: &TopicRadars,
    limits: &InputLimits,
    shared: &Shared,
    scan: RadarScan,
) -> Result<(Input, Option<String>), Refusal> {
    let radar = radar_of(topic, radars, shared, &scan.header.frame_id)?;
    // Each return is five float32 fields.
    let n = scan.returns.len();
    if let Err(e) = limits.check_size(n as u64, n.saturating_mul(20)) {
        return Err(("cloud_too_large", format!("{topic}: {e}")));
    }
    let input = radar_scan_input(radar, scan.header.stamp.into(), &scan);
    Ok((input, None))
}

impl Stamped for KeyframeMsg {
    fn header_mut(&mut self) -> &mut Header {
        &mut self.header
    }
}

/// At most `node.fleet_rate` keyframes a second from each robot beyond a burst of
/// `node.fleet_history` (a token bucket per robot).
pub struct FleetGate {
    rate: f64,
    burst: f64,
    buckets: BTreeMap<i32, (f64, Instant)>,
}

impl FleetGate {
    /// A gate for `settings`.
    pub fn new(settings: &FleetSettings) -> Self {
        FleetGate {
            rate: settings.rate,
            burst: settings.history as f64,
            buckets: BTreeMap::new(),
        }
    }

    /// Whether a keyframe of `robot` arriving `now` may pass.
    pub fn pass(&mut self, robot: i32, now: Instant) -> bool {
        let (tokens, last) = self.buckets.entry(robot).or_insert((self.burst, now));
        let refill = now.saturating_duration_since(*last).as_secs_f64() * self.rate;
        *tokens = (*tokens + refill).min(self.burst);
        *last = now;
        if *tokens >= 1.0 {
            *tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// Another robot's keyframe as the input (the pipeline decodes and checks it), refused when its
/// sender is not the robot's enclave (`keyframe_identity`, with `node.fleet_enclave`) and beyond
/// `node.fleet_rate` for its robot (`keyframe_over_rate`, counted under the robot).
pub fn keyframe_input(
    topic: &str,
    gate: &mut FleetGate,
    identity: Option<&FleetIdentity>,
    shared: &Shared,
    (msg, info): (KeyframeMsg, &MessageInfo),
) -> Result<(Input, Option<String>), Refusal> {
    shared.count_received("keyframes");
    if let Some(identity) = identity {
        let sender = info.publisher_gid();
        identity
            .check(msg.robot_id, sender)
            .map_err(|detail| ("keyframe_identity", format!("{topic}: {detail}")))?;
    }
    if !gate.pass(msg.robot_id, Instant::now()) {
        *lock(&shared.fleet_flood).entry(msg.robot_id).or_default() += 1;
        let detail = format!(
            "{topic}: robot {} sends more keyframes than node.fleet_rate allows",
            msg.robot_id
        );
        return Err(("keyframe_over_rate", detail));
    }
    Ok((Input::Keyframe(Box::new(msg)), None))
}

/// An odometry message as the input, refused when its pose is not finite.
pub fn odometry_input(
    topic: &str,
    shared: &Shared,
    odom: Odometry,
) -> Result<(Input, Option<String>), Refusal> {
    shared.count_received("odometry");
    let Some((stamp, t_odom_body)) = odometry_pose(&odom) else {
        return Err((
            "bad_odometry",
            format!("{topic}: pose not finite or zero quaternion"),
        ));
    };
    let input = Input::Odometry { stamp, t_odom_body };
    Ok((input, Some(odom.header.frame_id)))
}

/// A gyro sample (`odometry.source: radar_imu`) as the input, refused (`bad_imu`) when its angular
/// velocity is not finite.
pub fn imu_input(
    topic: &str,
    shared: &Shared,
    imu: Imu,
) -> Result<(Input, Option<String>), Refusal> {
    shared.count_received("imu");
    match gyro_input(imu.header.stamp.into(), &imu) {
        Some(input) => Ok((input, None)),
        None => Err(("bad_imu", format!("{topic}: angular velocity not finite"))),
    }
}

/// `/clock` into the shared clock (sim time).
pub async fn clock(sub: &Subscription<Clock>, shared: Arc<Shared>) {
    let mut stream = std::pin::pin!(sub.async_stream());
    while let Some(r) = stream.next().await {
        if let Ok((c, _)) = r {
            let s: Stamp = c.clock.into();
            shared.clock_ns.store(s.0, Ordering::SeqCst);
        }
    }
}

/// The pose input's subscription, as `odometry.source` asks for it (at most one is set).
pub struct PoseSubscriptions<'a> {
    /// `odometry.topic` (`topic`), resolved, and its subscription.
    pub odometry: Option<(&'a str, &'a Subscription<Odometry>)>,
    /// `imu.topic` (`radar_imu`), resolved, and its subscription.
    pub imu: Option<(&'a str, &'a Subscription<Imu>)>,
}

/// Publishers matched to `sub` on `topic`, asked of ros2-client only once a publisher on the topic is
/// discovered: ros2-client logs an error for a subscription that no publisher has matched yet.
fn matched<M: 'static>(node: &Node, topic: &str, sub: &Subscription<M>) -> usize {
    if node.publisher_count(topic) == 0 {
        0
    } else {
        sub.get_publisher_count(node)
    }
}

/// Matched publishers per input, every 250 ms, for `/diagnostics` (a user or test waits for them
/// before sending), and the subscriptions discovered on the map views (`~/markers`, `~/submap`).
pub async fn publisher_counts(
    node: &Node,
    radars: &[(String, TopicRadars, RadarSubscription)],
    pose: PoseSubscriptions<'_>,
    map_views: &[String; 2],
    shared: Arc<Shared>,
) {
    loop {
        for (topic, readers) in map_views.iter().zip(&shared.map_view_readers) {
            readers.store(node.subscription_count(topic), Ordering::SeqCst);
        }
        let mut counts = Vec::new();
        for (topic, topic_radars, sub) in radars {
            let n = match sub {
                RadarSubscription::Cloud(s) => matched(node, topic, s),
                RadarSubscription::Scan(s) => matched(node, topic, s),
            };
            counts.extend(topic_radars.iter().map(|(_, name, _)| (name.clone(), n)));
        }
        if let Some((topic, s)) = pose.odometry {
            counts.push(("odometry".to_string(), matched(node, topic, s)));
        }
        if let Some((topic, s)) = pose.imu {
            counts.push(("imu".to_string(), matched(node, topic, s)));
        }
        lock(&shared.publishers).extend(counts);
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A gyro sample is counted as received; one whose angular velocity is not finite is refused as
    /// `bad_imu`, naming the topic.
    #[test]
    fn a_gyro_sample_that_is_not_finite_is_refused() {
        let shared = Shared::new(Duration::from_secs(5));
        let mut imu = Imu::default();
        imu.header.stamp.sec = 3;
        imu.angular_velocity.z = 0.5;
        let (input, frame) = imu_input("/imu", &shared, imu.clone()).unwrap();
        assert_eq!(input.stamp(), Stamp(3_000_000_000));
        assert!(frame.is_none());
        imu.angular_velocity.y = f64::INFINITY;
        let (reason, detail) = imu_input("/imu", &shared, imu).unwrap_err();
        assert_eq!(reason, "bad_imu");
        assert!(detail.contains("/imu"), "{detail}");
        assert_eq!(lock(&shared.received).get("imu"), Some(&2));
    }

    /// A cloud of a radar with a trigger topic takes the newest trigger's stamp plus the delay; one
    /// with no trigger since the previous cloud is refused as `no_trigger`, naming the topic; a
    /// radar without a trigger topic keeps its cloud's stamp.
    #[test]
    fn a_cloud_takes_its_stamp_from_the_trigger_once() {
        let triggers = Mutex::new(TriggerStamps::new(vec![None, Some(0.5)]));
        let cloud = |radar, sec| {
            let mut cloud = PointCloud2::default();
            cloud.header.stamp.sec = sec;
            Ok((Input::Radar { radar, cloud }, None))
        };
        let stamp = |r: Result<(Input, Option<String>), Refusal>| r.map(|(i, _)| i.stamp());
        let (reason, detail) = stamp(trigger_stamped("/r", &triggers, cloud(1, 9))).unwrap_err();
        assert_eq!(reason, "no_trigger");
        assert!(detail.contains("/r"), "{detail}");
        lock(&triggers).trigger(1, Stamp(2_000_000_000));
        let got = stamp(trigger_stamped("/r", &triggers, cloud(1, 9)));
        assert_eq!(got, Ok(Stamp(2_500_000_000)));
        let got = stamp(trigger_stamped("/r", &triggers, cloud(1, 9)));
        assert_eq!(got.map_err(|e| e.0), Err("no_trigger"));
        let got = stamp(trigger_stamped("/r", &triggers, cloud(0, 9)));
        assert_eq!(got, Ok(Stamp(9_000_000_000)));
    }

    /// A cloud whose `frame_id` no radar of its topic has is refused as `unknown_frame`, naming the
    /// frame and each radar's configured one; a configured frame is counted under its radar.
    #[test]
    fn an_unknown_frame_is_refused_naming_the_configured_frames() {
        let shared = Shared::new(Duration::from_secs(5));
        let radars: TopicRadars = vec![
            (0, "front".into(), "ARS_548".into()),
            (1, "rear".into(), "radar_rear".into()),
        ];
        let limits = InputLimits::default();
        let mut cloud = PointCloud2::default();
        cloud.header.frame_id = "radar_1".into();
        let Err((reason, detail)) =
            radar_input("/points", &radars, &limits, &shared, cloud.clone())
        else {
            panic!("an unknown frame was taken");
        };
        assert_eq!(reason, "unknown_frame");
        assert_eq!(
            detail,
            "/points: frame_id `radar_1` is not a configured radar frame: `ARS_548` \
             (radars.front.frame_id), `radar_rear` (radars.rear.frame_id)"
        );
        cloud.header.frame_id = "radar_rear".into();
        let (input, _) = radar_input("/points", &radars, &limits, &shared, cloud).unwrap();
        assert!(matches!(input, Input::Radar { radar: 1, .. }));
        assert_eq!(lock(&shared.received).get("rear"), Some(&1));
    }

    /// A robot gets a burst of `node.fleet_history` keyframes, then `node.fleet_rate` a second; another
    /// robot's allowance is its own.
    #[test]
    fn a_flooding_robot_is_held_to_its_rate() {
        let settings = FleetSettings {
            history: 50,
            rate: 10.0,
            ..FleetSettings::default()
        };
        let mut gate = FleetGate::new(&settings);
        let t0 = Instant::now();
        let passed = (0..1000).filter(|_| gate.pass(7, t0)).count();
        assert_eq!(passed, 50, "the burst");
        let later = t0 + Duration::from_secs(2);
        let passed = (0..1000).filter(|_| gate.pass(7, later)).count();
        assert_eq!(passed, 20, "two seconds at 10 a second");
        assert!(gate.pass(8, later), "another robot has its own allowance");
    }
}
