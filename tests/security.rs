//! The node on a secured DDS domain (SROS2), with a keystore made by `launch_scripts/make_keystore.sh`:
//! - Enforce without a usable enclave stops the start with exit code 2, naming the variable, the
//!   enclave's missing file, or the enclave whose files make no secured participant;
//! - Permissive without a keystore warns and runs unsecured, as ROS 2 does;
//! - a secured node talks to participants of its keystore and to no one else: a secured observer
//!   reads its `/diagnostics` and gets its clouds to it, while an unsecured participant on the same
//!   domain, and one with an identity of another keystore (another CA), read nothing and none of their
//!   clouds is received;
//! - only enclaves whose permissions allow publishing on the fleet topic add keyframes to a secured
//!   fleet node's map;
//! - with `node.fleet_enclave`, a keyframe's robot id is taken only from that robot's enclave.
//!
//! The participants here are rustdds's, secured with the keystore's enclaves as the node is; the node
//! runs alone on a domain of its own, on loopback.

mod common;
#[path = "common/fleet_dds.rs"]
mod fleet_dds;
use common::{interrupt, text};
use fleet_dds::{fleet_keyframe, keyframe_writer};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};

use dc_loc::msgs::sensor_msgs::PointCloud2;
use dc_loc::ros::convert::DiagnosticArray;
use rustdds::policy::Reliability;
use rustdds::{DomainParticipant, QosPolicyBuilder, TopicKind};

/// The keystore's domain, where the secured node runs (and the nodes that never start); the
/// unsecured node runs on the next one, so that it is never the outsider the secured test watches
/// for.
const DOMAIN: u16 = 88;

/// Held by each test whose node runs on [`DOMAIN`]: one at a time, so that no test reads another's node.
static ON_DOMAIN: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn on_domain() -> std::sync::MutexGuard<'static, ()> {
    ON_DOMAIN.lock().unwrap_or_else(|e| e.into_inner())
}

fn scratch(name: &str) -> PathBuf {
    common::scratch("security", name)
}

/// A keystore at `dir` with the enclaves `/dc_loc` and `/observer`, made by the script with sros2's
/// governance (payloads encrypted); `DC_LOC_PAYLOAD_PROTECTION=NONE` (or `SIGN`) makes it with that
/// payload protection instead.
fn keystore(dir: &Path) -> PathBuf {
    let ks = dir.join(format!("keystore_{}", protection()));
    if !ks.join("enclaves/observer/permissions.p7s").is_file() {
        make_keystore(&ks, &[], &["/dc_loc", "/observer"]);
    }
    ks
}

/// The payload protection the keystores are made with (`DC_LOC_PAYLOAD_PROTECTION`, else sros2's).
fn protection() -> String {
    std::env::var("DC_LOC_PAYLOAD_PROTECTION").unwrap_or("ENCRYPT".into())
}

/// Runs `launch_scripts/make_keystore.sh` for [`DOMAIN`] (sros2 writes the governance and
/// permissions for the domain of ROS_DOMAIN_ID): the keystore `ks`, made or extended with `enclaves`,
/// the script's `options` before them.
fn make_keystore(ks: &Path, options: &[&str], enclaves: &[&str]) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("launch_scripts/make_keystore.sh");
    let out = Command::new("bash")
        .env("ROS_DOMAIN_ID", DOMAIN.to_string())
        .arg(&script)
        .args(["--payload-protection", &protection()])
        .args(options)
        .arg(ks)
        .args(enclaves)
        .output()
        .expect("cannot run make_keystore.sh");
    assert!(
        out.status.success(),
        "make_keystore.sh: {}{}",
        text(&out.stdout),
        text(&out.stderr)
    );
}

fn node(domain: u16, security: &[(&str, &str)]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_dc_loc"));
    c.env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .env("ROS_DOMAIN_ID", domain.to_string());
    for k in [
        "ROS_SECURITY_ENABLE",
        "ROS_SECURITY_STRATEGY",
        "ROS_SECURITY_KEYSTORE",
        "ROS_SECURITY_ENCLAVE_OVERRIDE",
    ] {
        c.env_remove(k);
    }
    for (k, v) in security {
        c.env(k, v);
    }
    c
}

fn run(args: &[&str], security: &[(&str, &str)]) -> Output {
    node(DOMAIN, security)
        .args(args)
        .output()
        .expect("cannot start dc_loc")
}

/// The node, started and running (see [`common::start_node`]).
fn start(domain: u16, map: &Path, extra: &[&str], security: &[(&str, &str)]) -> Child {
    let mut args = vec!["--ros-args".to_string(), "-p".into()];
    args.push(format!("map.file:={}", map.display()));
    args.extend(extra.iter().map(|e| e.to_string()));
    let mut command = node(domain, security);
    command.args(&args);
    common::start_node(command)
}

fn enforce(ks: &Path) -> Vec<(&'static str, String)> {
    vec![
        ("ROS_SECURITY_ENABLE", "true".into()),
        ("ROS_SECURITY_STRATEGY", "Enforce".into()),
        ("ROS_SECURITY_KEYSTORE", ks.display().to_string()),
    ]
}

fn pairs<'a>(v: &'a [(&'static str, String)]) -> Vec<(&'static str, &'a str)> {
    v.iter().map(|(k, s)| (*k, s.as_str())).collect()
}

#[test]
fn enforce_without_a_usable_enclave_stops_the_start() {
    let dir = scratch("enforce");
    let ks = keystore(&dir);
    // No keystore named.
    let out = run(
        &["--ros-args", "--enclave", "/dc_loc"],
        &[
            ("ROS_SECURITY_ENABLE", "true"),
            ("ROS_SECURITY_STRATEGY", "Enforce"),
        ],
    );
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("ROS_SECURITY_KEYSTORE is not set"), "{err}");
    // An enclave that is not in the keystore.
    let out = run(
        &["--ros-args", "--enclave", "/nobody"],
        &pairs(&enforce(&ks)),
    );
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("no enclave `/nobody`"), "{err}");
    // An enclave without its permissions.
    let broken = dir.join("broken");
    let _ = std::fs::remove_dir_all(&broken);
    copy_dir(&ks, &broken);
    std::fs::remove_file(broken.join("enclaves/dc_loc/permissions.p7s")).unwrap();
    let out = run(
        &["--ros-args", "--enclave", "/dc_loc"],
        &pairs(&enforce(&broken)),
    );
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("permissions.p7s"), "{err}");
    // A certificate that is not one: the participant refuses the enclave.
    copy_dir(&ks, &broken);
    std::fs::write(broken.join("enclaves/dc_loc/cert.pem"), "not a certificate").unwrap();
    let out = run(
        &["--ros-args", "--enclave", "/dc_loc"],
        &pairs(&enforce(&broken)),
    );
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("does not make a secured participant"), "{err}");
}

#[test]
fn permissive_without_a_keystore_runs_unsecured() {
    let dir = scratch("permissive");
    std::fs::create_dir_all(&dir).unwrap();
    let child = start(
        DOMAIN + 1,
        &dir.join("map.dcmap"),
        &[],
        &[
            ("ROS_SECURITY_ENABLE", "true"),
            ("ROS_SECURITY_STRATEGY", "Permissive"),
        ],
    );
    let (code, err) = interrupt(child);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        err.contains("ROS_SECURITY_KEYSTORE is not set; running unsecured"),
        "{err}"
    );
}

/// A participant on loopback in [`DOMAIN`], secured with `enclave` of `ks` when given.
fn participant(secured: Option<(&Path, &str)>) -> DomainParticipant {
    let dir = secured.map(|(ks, enclave)| ks.join("enclaves").join(enclave));
    fleet_dds::participant(DOMAIN, dir.as_deref())
}

/// What one participant sees and does: reads `/diagnostics`, writes radar clouds.
struct Peer {
    _participant: DomainParticipant,
    diagnostics: rustdds::no_key::DataReader<DiagnosticArray>,
    clouds: rustdds::no_key::DataWriter<PointCloud2>,
}

impl Peer {
    fn new(participant: DomainParticipant) -> Self {
        let qos = QosPolicyBuilder::new()
            .reliability(Reliability::BestEffort)
            .build();
        let diag = participant
            .create_topic(
                "rt/diagnostics".into(),
                "diagnostic_msgs::msg::dds_::DiagnosticArray_".into(),
                &qos,
                TopicKind::NoKey,
            )
            .unwrap();
        let radar = participant
            .create_topic(
                "rt/radar/points".into(),
                "sensor_msgs::msg::dds_::PointCloud2_".into(),
                &qos,
                TopicKind::NoKey,
            )
            .unwrap();
        let diagnostics = participant
            .create_subscriber(&qos)
            .unwrap()
            .create_datareader_no_key_cdr(&diag, None)
            .unwrap();
        let clouds = participant
            .create_publisher(&qos)
            .unwrap()
            .create_datawriter_no_key_cdr(&radar, None)
            .unwrap();
        Peer {
            _participant: participant,
            diagnostics,
            clouds,
        }
    }

    /// Takes the diagnostics messages that came; the newest goes to `seen`. Returns how many came.
    fn take(&mut self, seen: &mut Option<DiagnosticArray>) -> usize {
        let mut n = 0;
        while let Ok(Some(s)) = self.diagnostics.take_next_sample() {
            *seen = Some(s.into_value());
            n += 1;
        }
        n
    }

    /// Sends an empty cloud in `frame`.
    fn send_cloud(&self, frame: &str) {
        let mut cloud = PointCloud2::default();
        cloud.header.frame_id = frame.into();
        self.clouds.write(cloud, None).unwrap();
    }
}

fn value(d: &DiagnosticArray, key: &str) -> Option<String> {
    d.status
        .iter()
        .flat_map(|s| &s.values)
        .find(|v| v.key == key)
        .map(|v| v.value.clone())
}

#[test]
fn a_secured_node_talks_only_to_its_keystore() {
    let _domain = on_domain();
    let dir = scratch("secured");
    let ks = keystore(&dir);
    let child = start(
        DOMAIN,
        &dir.join("map.dcmap"),
        &["--enclave", "/dc_loc", "-p", "node.diagnostics_period:=0.5"],
        &pairs(&enforce(&ks)),
    );
    let mut member = Peer::new(participant(Some((&ks, "observer"))));
    let mut outsider = Peer::new(participant(None));
    // A stranger with an identity of another keystore (its own CA, the same enclave names).
    let other_ks = keystore(&dir.join("other"));
    let mut stranger = Peer::new(participant(Some((&other_ks, "observer"))));
    let (mut member_seen, mut outsider_seen, mut stranger_seen) = (None, None, None);
    let (mut member_n, mut outsider_n, mut stranger_n) = (0, 0, 0);
    let t0 = Instant::now();
    // Each sends a cloud every 100 ms for 8 s, and on until the member has read the node's
    // diagnostics 4 times (the handshakes take longer on a loaded machine; at most 40 s); the
    // member's in the radar's frame, the outsider's and the stranger's in frames of their own: the
    // node counts the first as `front.received`, would refuse the others as `unknown_frame`.
    let mut sent = 0;
    let mut member_first = None;
    while (t0.elapsed() < Duration::from_secs(8) || member_n < 4)
        && t0.elapsed() < Duration::from_secs(40)
    {
        member.send_cloud("radar");
        outsider.send_cloud("outsider");
        stranger.send_cloud("stranger");
        sent += 1;
        member_n += member.take(&mut member_seen);
        if member_n > 0 && member_first.is_none() {
            member_first = Some(t0.elapsed().as_secs_f64());
        }
        outsider_n += outsider.take(&mut outsider_seen);
        stranger_n += stranger.take(&mut stranger_seen);
        std::thread::sleep(Duration::from_millis(100));
    }
    println!("the member's first diagnostics after {member_first:?} s");
    let (code, err) = interrupt(child);
    assert_eq!(code, Some(0), "{err}");
    println!(
        "sent {sent} clouds from each; diagnostics read: member {member_n}, outsider {outsider_n}, \
         stranger {stranger_n}"
    );
    assert!(err.contains("DDS security with the enclave"), "{err}");
    assert_eq!(outsider_n, 0, "the outsider read the node's diagnostics");
    assert_eq!(stranger_n, 0, "the stranger read the node's diagnostics");
    let d = member_seen.expect("the member read no diagnostics");
    let received: u64 = value(&d, "front.received")
        .expect("front.received")
        .parse()
        .unwrap();
    let refused = value(&d, "unknown_frame").map_or(0, |v| v.parse::<u64>().unwrap());
    println!("front.received {received}, unknown_frame {refused}");
    // The member's clouds arrive (those sent before the handshake completed are lost); none of the
    // outsider's does.
    assert!(received > 0 && received <= sent, "{received} of {sent}");
    assert_eq!(
        refused, 0,
        "the outsider's or the stranger's clouds reached the node"
    );
}

/// An enclave `/listener` in the keystore `ks` whose permissions let it read the fleet's keyframes and
/// `/diagnostics` but publish on neither (the script's `--topics`).
fn listener_enclave(dir: &Path, ks: &Path) {
    let topics = dir.join("listener_topics.txt");
    std::fs::write(
        &topics,
        "subscribe /dc_loc/keyframes\nsubscribe /diagnostics\n",
    )
    .unwrap();
    make_keystore(ks, &["--topics", topics.to_str().unwrap()], &["/listener"]);
}

/// Who may add keyframes to a secured fleet's maps is what the keystore's permissions say: a member
/// allowed to publish on the fleet topic gets its keyframes into the node's map; an enclave of the
/// same keystore allowed only to read it cannot even make a writer there (the access control
/// refuses it), and the node counts no keyframe of its robot.
#[test]
fn only_enclaves_allowed_to_publish_on_the_fleet_topic_add_keyframes() {
    let _domain = on_domain();
    let dir = scratch("fleet_permissions");
    let ks = keystore(&dir);
    listener_enclave(&dir, &ks);
    let child = start(
        DOMAIN,
        &dir.join("map.dcmap"),
        &[
            "--enclave",
            "/dc_loc",
            "-p",
            "node.fleet:=true",
            "-p",
            "node.diagnostics_period:=0.5",
        ],
        &pairs(&enforce(&ks)),
    );
    let member = participant(Some((&ks, "observer")));
    let writer = keyframe_writer(&member).expect("the member may publish keyframes");
    let listener = participant(Some((&ks, "listener")));
    let refused = keyframe_writer(&listener);
    let mut diagnostics = Peer::new(participant(Some((&ks, "observer"))));
    let mut seen = None;
    let t0 = Instant::now();
    let mut id = 0;
    // 8 s, and on until the node counts robot 5 (the handshakes take longer on a loaded machine).
    let counted = |seen: &Option<DiagnosticArray>| {
        seen.as_ref()
            .is_some_and(|d| value(d, "fleet.robot_5").is_some())
    };
    while (t0.elapsed() < Duration::from_secs(8) || !counted(&seen))
        && t0.elapsed() < Duration::from_secs(40)
    {
        writer.write(fleet_keyframe(5, id), None).unwrap();
        if let Ok(w) = &refused {
            let _ = w.write(fleet_keyframe(6, id), None);
        }
        id += 1;
        diagnostics.take(&mut seen);
        std::thread::sleep(Duration::from_millis(200));
    }
    let (code, err) = interrupt(child);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        refused.is_err(),
        "the listener's permissions allow no keyframe writer, yet one was made"
    );
    let d = seen.expect("no diagnostics read");
    let member_counts = value(&d, "fleet.robot_5").expect("no keyframe of the member's robot");
    println!(
        "sent {id} keyframes as robot 5: {member_counts}; the listener's writer: {}",
        refused.err().unwrap_or_default()
    );
    assert!(
        member_counts.starts_with("received ") && !member_counts.starts_with("received 0,"),
        "{member_counts}"
    );
    assert_eq!(value(&d, "fleet.robot_6"), None, "robot 6 reached the node");
}

/// The enclaves `/fleet/robot_5` and `/fleet/robot_6` in the keystore `ks`, each allowed every topic.
fn robot_enclaves(ks: &Path) {
    make_keystore(ks, &[], &["/fleet/robot_5", "/fleet/robot_6"]);
}

/// With `node.fleet_enclave`, a keyframe's robot id must be its sender's identity: robot 5's enclave
/// gets its own keyframes into the map, while the keyframes it sends as robot 6, and those another
/// member of the keystore (`/observer`) sends as robot 5, are dropped as `keyframe_identity`.
#[test]
fn with_fleet_enclave_a_robot_id_is_taken_only_from_its_enclave() {
    let _domain = on_domain();
    let dir = scratch("fleet_identity");
    let ks = keystore(&dir);
    robot_enclaves(&ks);
    let child = start(
        DOMAIN,
        &dir.join("map.dcmap"),
        &[
            "--enclave",
            "/dc_loc",
            "-p",
            "node.fleet:=true",
            "-p",
            "node.fleet_enclave:=/fleet/robot_{robot}",
            "-p",
            "node.diagnostics_period:=0.5",
        ],
        &pairs(&enforce(&ks)),
    );
    let robot_5 = participant(Some((&ks, "fleet/robot_5")));
    let robot_5_writer = keyframe_writer(&robot_5).unwrap();
    let observer = participant(Some((&ks, "observer")));
    let observer_writer = keyframe_writer(&observer).unwrap();
    let mut diagnostics = Peer::new(participant(Some((&ks, "observer"))));
    let mut seen = None;
    let t0 = Instant::now();
    let mut id = 0;
    // 8 s, and on until the node counts robot 5 (the handshakes take longer on a loaded machine).
    let counted = |seen: &Option<DiagnosticArray>| {
        seen.as_ref()
            .is_some_and(|d| value(d, "fleet.robot_5").is_some())
    };
    while (t0.elapsed() < Duration::from_secs(8) || !counted(&seen))
        && t0.elapsed() < Duration::from_secs(40)
    {
        robot_5_writer.write(fleet_keyframe(5, id), None).unwrap();
        robot_5_writer.write(fleet_keyframe(6, id), None).unwrap();
        observer_writer
            .write(fleet_keyframe(5, 1000 + id), None)
            .unwrap();
        id += 1;
        diagnostics.take(&mut seen);
        std::thread::sleep(Duration::from_millis(200));
    }
    let (code, err) = interrupt(child);
    assert_eq!(code, Some(0), "{err}");
    let d = seen.expect("no diagnostics read");
    let robot_5_counts = value(&d, "fleet.robot_5").expect("no keyframe of robot 5");
    let refused: u64 = value(&d, "keyframe_identity")
        .expect("no keyframe_identity count")
        .parse()
        .unwrap();
    println!(
        "sent {id} keyframes of each kind: robot 5 {robot_5_counts}; keyframe_identity {refused}"
    );
    let received: u64 = robot_5_counts
        .strip_prefix("received ")
        .and_then(|r| r.split(',').next()?.parse().ok())
        .unwrap();
    // Robot 5's own keyframes (those sent before the handshake completed are lost), none of the others.
    assert!(received > 0 && received <= id, "{robot_5_counts}");
    assert_eq!(value(&d, "fleet.robot_6"), None, "robot 6 reached the node");
    assert!(refused >= received, "{refused} refused, {received} taken");
    // The warning names the sender's certificate and the one wanted.
    assert!(
        err.contains("keyframe from the certificate CN=/")
            && err.contains("wants CN=/fleet/robot_"),
        "no keyframe_identity warning naming the certificates: {err}"
    );
}

/// Copies a keystore (its files and symlinks' targets) from `from` to `to`.
fn copy_dir(from: &Path, to: &Path) {
    let _ = std::fs::remove_dir_all(to);
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.path().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), target).unwrap();
        }
    }
}
