//! Replaying a simulated drive into a running `dc_loc` node over DDS (ros2-client publishers on
//! loopback), with the node's `/diagnostics` collected and its process read from /proc; optionally on a
//! secured domain (SROS2), the node and the replayer each with an enclave of one keystore. Shared by the
//! node benchmarks (`node_latency`, `soak`) and the security interoperability test.

#![allow(dead_code)]

use std::collections::BTreeMap;
use std::net::Ipv4Addr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use dc_loc::bag::BagReader;
use dc_loc::math::Stamp;
use dc_loc::msgs::nav_msgs::Odometry;
use dc_loc::msgs::sensor_msgs::PointCloud2;
use dc_loc::ros::convert::DiagnosticArray;
use dc_loc::sim::SimConfig;
use dc_loc::sim::export::{ExportSummary, export_drive};
use futures::StreamExt;
use ros2_client::{
    Context, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, QosProfile,
    qos::{Durability, History, Reliability, WhenFull},
};
use rustdds::{DomainParticipantBuilder, DomainParticipantSecurityConfigFiles};

/// Two laps of a small block with the five radars of the nuScenes car (about 106 s).
pub const DRIVE: &str = "\
seed: 3
radar_preset: nuscenes
laps:
  - speed: 15.0
  - speed: 10.0
ground_truth_rate: 20.0
odometry:
  rate: 25.0
route:
  corners:
    - {x: 0.0, y: 0.0, radius: 15.0, junction: true}
    - {x: 170.0, y: 0.0, radius: 20.0, junction: false}
    - {x: 170.0, y: 110.0, radius: 15.0, junction: true}
    - {x: 0.0, y: 110.0, radius: 20.0, junction: false}
";

/// The value after `name` on the command line.
pub fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

/// Arguments after `--` (for the node).
pub fn node_args() -> Vec<String> {
    std::env::args().skip_while(|a| a != "--").skip(1).collect()
}

/// One message of the drive.
#[derive(Clone)]
pub enum Message {
    /// A radar cloud on its topic.
    Cloud(String, PointCloud2),
    /// Odometry.
    Odometry(Box<Odometry>),
}

/// The drive as a bag (with its params file) and its messages in log-time order.
pub struct Drive {
    /// The exported bag and params file.
    pub summary: ExportSummary,
    /// Radar topics.
    pub radar_topics: Vec<String>,
    /// Log time and message.
    pub messages: Vec<(Stamp, Message)>,
}

impl Drive {
    /// Simulates [`DRIVE`] into `dir` and reads it back.
    pub fn simulate(dir: &Path) -> Drive {
        let cfg: SimConfig = yaml_serde::from_str(DRIVE).expect("drive config");
        Drive::simulate_config(&cfg, dir)
    }

    /// Simulates the drive of `cfg` into `dir` and reads it back.
    pub fn simulate_config(cfg: &SimConfig, dir: &Path) -> Drive {
        let drive = dc_loc::sim::simulate(cfg).expect("simulate");
        let summary = export_drive(&drive, dir).expect("export");
        let reader = BagReader::open(&summary.bag_dir).expect("bag");
        let radar_topics: Vec<String> = reader
            .topics()
            .iter()
            .filter(|t| t.type_name.ends_with("PointCloud2"))
            .map(|t| t.name.clone())
            .collect();
        let mut wanted: Vec<&str> = radar_topics.iter().map(String::as_str).collect();
        wanted.push("/odom");
        let mut messages = Vec::new();
        for m in reader.messages_on(&wanted).expect("messages") {
            let m = m.expect("message");
            let msg = if m.topic() == "/odom" {
                Message::Odometry(Box::new(m.decode::<Odometry>().expect("odometry")))
            } else {
                Message::Cloud(m.topic().to_string(), m.decode().expect("cloud"))
            };
            messages.push((m.log_time, msg));
        }
        Drive {
            summary,
            radar_topics,
            messages,
        }
    }

    /// Seconds from the first to the last message.
    pub fn duration(&self) -> f64 {
        match (self.messages.first(), self.messages.last()) {
            (Some(a), Some(b)) => b.0.secs_since(a.0),
            _ => 0.0,
        }
    }
}

/// An enclave of an SROS2 keystore, for the node or the replayer.
#[derive(Clone, Debug)]
pub struct Security {
    /// The keystore (`ROS_SECURITY_KEYSTORE`).
    pub keystore: PathBuf,
    /// The enclave's path, e.g. `/dc_loc`.
    pub enclave: String,
}

impl Security {
    /// `enclave` of `keystore`.
    pub fn new(keystore: &Path, enclave: &str) -> Security {
        Security {
            keystore: keystore.to_path_buf(),
            enclave: enclave.to_string(),
        }
    }

    /// The enclave's directory, which holds its six files.
    pub fn enclave_dir(&self) -> PathBuf {
        self.keystore
            .join("enclaves")
            .join(self.enclave.trim_start_matches('/'))
    }

    /// The same keystore's enclave `enclave`.
    pub fn with_enclave(&self, enclave: &str) -> Security {
        Security::new(&self.keystore, enclave)
    }
}

/// Makes (or extends) the keystore `dir` with `launch_scripts/make_keystore.sh`: its governance and
/// permissions for `domain`, payloads protected as `payload_protection` says (`NONE`, `SIGN`,
/// `ENCRYPT`), one enclave per entry of `enclaves`, each allowed every topic.
pub fn make_keystore(dir: &Path, domain: u16, payload_protection: &str, enclaves: &[&str]) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("launch_scripts/make_keystore.sh");
    let out = Command::new("bash")
        .arg(&script)
        .args(["--payload-protection", payload_protection])
        .arg(dir)
        .args(enclaves)
        .env("ROS_DOMAIN_ID", domain.to_string())
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", script.display()));
    assert!(
        out.status.success(),
        "make_keystore.sh failed: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Starts the node on `params` with `extra` ROS arguments, on loopback in `domain`, its log to
/// `stderr`; secured (Enforce) with `security`'s enclave when given, else unsecured whatever the
/// caller's environment says.
pub fn start_node(
    bin: &str,
    params: &Path,
    extra: &[String],
    domain: u16,
    security: Option<&Security>,
    stderr: Stdio,
) -> Child {
    start_node_with(Command::new(bin), params, extra, domain, security, stderr)
}

/// As [`start_node`], the node run by `command` (the node's binary, or a wrapper such as `taskset -c 0
/// BIN`, with any environment of the caller's own, e.g. `RAYON_NUM_THREADS`).
pub fn start_node_with(
    mut command: Command,
    params: &Path,
    extra: &[String],
    domain: u16,
    security: Option<&Security>,
    stderr: Stdio,
) -> Child {
    let shown = format!("{command:?}");
    command
        .args(["--ros-args", "--params-file"])
        .arg(params)
        .args(extra)
        .env("ROS_DOMAIN_ID", domain.to_string())
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .env("RUST_LOG", "warn,rustdds=off,ros2_client=off")
        .env_remove("ROS_SECURITY_ENABLE")
        .env_remove("ROS_SECURITY_STRATEGY")
        .env_remove("ROS_SECURITY_KEYSTORE")
        .env_remove("ROS_SECURITY_ENCLAVE_OVERRIDE");
    if let Some(s) = security {
        command
            .args(["--enclave", &s.enclave])
            .env("ROS_SECURITY_ENABLE", "true")
            .env("ROS_SECURITY_STRATEGY", "Enforce")
            .env("ROS_SECURITY_KEYSTORE", &s.keystore);
    }
    command
        .stdout(Stdio::null())
        .stderr(stderr)
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {shown}: {e}"))
}

/// SIGINT, then waits for the node.
pub fn stop_node(mut node: Child) -> Option<i32> {
    let _ = Command::new("kill")
        .args(["-INT", &node.id().to_string()])
        .status();
    node.wait().ok().and_then(|s| s.code())
}

/// A ROS 2 context of `domain` on loopback, secured with `security`'s enclave when given.
pub fn context(domain: u16, security: Option<&Security>) -> Context {
    let mut builder =
        DomainParticipantBuilder::new(domain).with_only_networks([Ipv4Addr::LOCALHOST]);
    if let Some(s) = security {
        // The enclave's files under sros2's names; no PKCS#11 key.
        builder = builder.builtin_security(
            DomainParticipantSecurityConfigFiles::with_ros_default_names(
                s.enclave_dir(),
                String::new(),
            ),
        );
    }
    let dp = builder.build().expect("participant");
    Context::from_domain_participant(dp).expect("context")
}

/// The newest value of every `/diagnostics` key, and when the newest message came.
pub type Latest = (BTreeMap<String, String>, Option<Instant>);

/// The publishers of the drive's topics and the latest `/diagnostics` values.
pub struct Replayer {
    /// The ROS 2 node the publishers belong to.
    pub node: Node,
    clouds: BTreeMap<String, Publisher<PointCloud2>>,
    odometry: Publisher<Odometry>,
    /// The newest value of every diagnostics key, and when the newest message came.
    pub latest: Arc<Mutex<Latest>>,
    /// Longest time between two `/diagnostics` messages, s.
    pub longest_gap: Arc<Mutex<f64>>,
    _context: Context,
}

impl Replayer {
    /// Publishers for `radar_topics` and `/odom`, and a `/diagnostics` subscriber, in `domain`,
    /// secured with `security`'s enclave when given (call inside a tokio runtime: [`runtime`]).
    pub fn new(domain: u16, radar_topics: &[String], security: Option<&Security>) -> Replayer {
        Replayer::in_namespace(domain, "", radar_topics, security)
    }

    /// As [`Replayer::new`], each topic of the drive published under `namespace` (e.g. `/robot_1`:
    /// `/odom` goes to `/robot_1/odom`).
    pub fn in_namespace(
        domain: u16,
        namespace: &str,
        radar_topics: &[String],
        security: Option<&Security>,
    ) -> Replayer {
        let context = context(domain, security);
        let mut node = context
            .new_node(
                NodeName::new("/", "dc_loc_replayer").expect("name"),
                NodeOptions::new(),
            )
            .expect("node");
        let qos = QosProfile::publisher_default()
            .reliability(Reliability::Reliable {
                when_full: WhenFull::Wait(Duration::from_millis(100)),
            })
            .durability(Durability::Volatile)
            .history(History::KeepLast { depth: 100 });
        let topic = |name: &str, pkg: &str, ty: &str| {
            node.create_topic(
                &Name::parse(name).expect("topic"),
                MessageTypeName::new(pkg, ty),
                &qos,
            )
            .expect("topic")
        };
        let cloud_topics: Vec<_> = radar_topics
            .iter()
            .map(|t| {
                let cloud = topic(&format!("{namespace}{t}"), "sensor_msgs", "PointCloud2");
                (t.clone(), cloud)
            })
            .collect();
        let odom_topic = topic(&format!("{namespace}/odom"), "nav_msgs", "Odometry");
        let diag_topic = topic("/diagnostics", "diagnostic_msgs", "DiagnosticArray");
        let clouds = cloud_topics
            .into_iter()
            .map(|(name, t)| (name, node.create_publisher(&t, None).expect("pub")))
            .collect();
        let odometry = node.create_publisher(&odom_topic, None).expect("pub");
        let diag = node
            .create_subscription::<DiagnosticArray>(&diag_topic, Some(qos.clone()))
            .expect("sub");
        let latest = Arc::new(Mutex::new((BTreeMap::new(), None::<Instant>)));
        let longest_gap = Arc::new(Mutex::new(0.0));
        let (l, g) = (latest.clone(), longest_gap.clone());
        tokio::spawn(async move {
            let mut s = std::pin::pin!(diag.async_stream());
            while let Some(Ok((d, _))) = s.next().await {
                let mut l = l.lock().unwrap_or_else(|e| e.into_inner());
                if let Some(prev) = l.1 {
                    let mut g = g.lock().unwrap_or_else(|e| e.into_inner());
                    *g = f64::max(*g, prev.elapsed().as_secs_f64());
                }
                l.1 = Some(Instant::now());
                for st in &d.status {
                    for kv in &st.values {
                        l.0.insert(kv.key.clone(), kv.value.clone());
                    }
                }
            }
        });
        tokio::spawn(node.spinner().expect("spinner").spin());
        Replayer {
            node,
            clouds,
            odometry,
            latest,
            longest_gap,
            _context: context,
        }
    }

    /// Waits until the node matched every publisher.
    pub async fn wait_for_node(&self) {
        let t0 = Instant::now();
        while self.odometry.get_subscription_count(&self.node) == 0
            || self
                .clouds
                .values()
                .any(|p| p.get_subscription_count(&self.node) == 0)
        {
            assert!(
                t0.elapsed() < Duration::from_secs(30),
                "the node did not match"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Publishes one message.
    pub async fn publish(&self, m: &Message) {
        match m {
            Message::Cloud(topic, c) => {
                let _ = self.clouds[topic].async_publish(c.clone()).await;
            }
            Message::Odometry(o) => {
                let _ = self.odometry.async_publish((**o).clone()).await;
            }
        }
    }

    /// Publishes `messages` at `rate` times the pace of their log times.
    pub async fn play(&self, messages: &[(Stamp, Message)], rate: f64) {
        let Some(first) = messages.first().map(|m| m.0) else {
            return;
        };
        let start = Instant::now();
        for (t, m) in messages {
            let due = start + Duration::from_secs_f64(t.secs_since(first) / rate);
            if let Some(wait) = due.checked_duration_since(Instant::now()) {
                tokio::time::sleep(wait).await;
            }
            self.publish(m).await;
        }
    }

    /// The newest value of a diagnostics key (`-` when not seen yet).
    pub fn value(&self, key: &str) -> String {
        let l = self.latest.lock().unwrap_or_else(|e| e.into_inner());
        l.0.get(key).cloned().unwrap_or_else(|| "-".into())
    }
}

/// Replays `drive` into the node on `domain` at `rate` times real time (secured with `security`'s
/// enclave when given); returns the node's last `/diagnostics` values, read three diagnostics
/// periods (of 0.5 s) after the last message.
pub fn replay_drive(
    domain: u16,
    drive: &Drive,
    rate: f64,
    security: Option<&Security>,
) -> BTreeMap<String, String> {
    let rt = runtime();
    let _entered = rt.enter();
    let replayer = Replayer::new(domain, &drive.radar_topics, security);
    rt.block_on(async {
        replayer.wait_for_node().await;
        replayer.play(&drive.messages, rate).await;
        tokio::time::sleep(Duration::from_millis(1600)).await;
    });
    let latest = replayer.latest.lock().unwrap_or_else(|e| e.into_inner());
    latest.0.clone()
}

/// The runtime the replay runs on (one thread, with timers).
pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .expect("tokio runtime")
}

/// CPU time (user + system) of a process, s (clock ticks of 1/100 s).
pub fn cpu_seconds(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let after = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// A `/proc/<pid>/status` field in kB (`VmRSS`, `VmHWM`) or a count (`Threads`).
pub fn proc_status(pid: u32, key: &str) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix(key)?.strip_prefix(':'))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
}

/// Open file descriptors of a process.
pub fn open_files(pid: u32) -> Option<usize> {
    Some(std::fs::read_dir(format!("/proc/{pid}/fd")).ok()?.count())
}

/// A scratch directory of this process.
pub fn scratch(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("dc_loc_{name}_{}", std::process::id()))
}
