//! Latency benchmark of the ROS 2 node: five radars at 13 Hz (the simulator's nuScenes preset) and
//! odometry at 25 Hz published in real time to the running `dc_loc` node, which reports in
//! `/diagnostics` the time from a message's arrival (taken off DDS) to the end of its processing,
//! outputs published (`latency_ms`), and from arrival to a loop closure's publication
//! (`closure_latency_ms`); the node's CPU share comes from /proc.
//!
//! ```text
//! cargo build --release && cargo run --release --example node_latency -- [--rate 1.0] \
//!     [--node target/release/dc_loc] [-- NODE ROS ARGS, e.g. -p node.sync_timeout:=0.01]
//! ```
//! DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; domain ROS_DOMAIN_ID, default 77).
//! Prints one line per second and a summary; the figures go into README_NODE.md.

use std::collections::BTreeMap;
use std::net::Ipv4Addr;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use dc_loc::bag::BagReader;
use dc_loc::msgs::nav_msgs::Odometry;
use dc_loc::msgs::sensor_msgs::PointCloud2;
use dc_loc::ros::convert::DiagnosticArray;
use dc_loc::sim::SimConfig;
use dc_loc::sim::export::export_drive;
use futures::StreamExt;
use ros2_client::{
    Context, MessageTypeName, Name, NodeName, NodeOptions, QosProfile,
    qos::{Durability, History, Reliability, WhenFull},
};

/// Two laps of a small block with the five radars of the nuScenes car (about 106 s).
const DRIVE: &str = "\
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

fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

/// CPU time (user + system) of a process, s (clock ticks of 1/100 s).
fn cpu_seconds(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let after = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

fn main() {
    let rate: f64 = arg("--rate").and_then(|r| r.parse().ok()).unwrap_or(1.0);
    let node_bin = arg("--node").unwrap_or_else(|| "target/release/dc_loc".into());
    let domain: u16 = std::env::var("ROS_DOMAIN_ID")
        .ok()
        .and_then(|d| d.parse().ok())
        .unwrap_or(77);

    // The drive as a bag with its params file.
    let dir = std::env::temp_dir().join(format!("dc_loc_node_latency_{}", std::process::id()));
    let cfg: SimConfig = yaml_serde::from_str(DRIVE).expect("drive config");
    let drive = dc_loc::sim::simulate(&cfg).expect("simulate");
    let summary = export_drive(&drive, &dir).expect("export");
    let reader = BagReader::open(&summary.bag_dir).expect("bag");
    let topics: Vec<String> = reader
        .topics()
        .iter()
        .filter(|t| t.type_name.ends_with("PointCloud2") || t.name == "/odom")
        .map(|t| t.name.clone())
        .collect();
    let topic_refs: Vec<&str> = topics.iter().map(String::as_str).collect();
    let mut messages = Vec::new();
    for m in reader.messages_on(&topic_refs).expect("messages") {
        let m = m.expect("message");
        let t = m.log_time;
        if m.topic() == "/odom" {
            messages.push((t, m.topic().to_string(), None, m.decode::<Odometry>().ok()));
        } else {
            messages.push((
                t,
                m.topic().to_string(),
                m.decode::<PointCloud2>().ok(),
                None,
            ));
        }
    }
    let radars = topics.len() - 1;
    println!(
        "drive: {} radars, {} messages over {:.0} s, replayed at {rate}x",
        radars,
        messages.len(),
        messages
            .last()
            .map_or(0.0, |m| m.0.secs_since(messages[0].0))
    );

    // The node.
    // Arguments after `--` go to the node (e.g. `-p node.sync_timeout:=0.01`).
    let extra: Vec<String> = std::env::args().skip_while(|a| a != "--").skip(1).collect();
    let mut node_proc = Command::new(&node_bin)
        .args(["--ros-args", "--params-file"])
        .arg(&summary.params_file)
        .args(&extra)
        .env("ROS_DOMAIN_ID", domain.to_string())
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .env("RUST_LOG", "warn,rustdds=off,ros2_client=off")
        .stdout(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {node_bin}: {e}"));
    let pid = node_proc.id();

    // The publishers and the diagnostics subscriber.
    let dp = ros2_client::dds::rustdds::DomainParticipantBuilder::new(domain)
        .with_only_networks([Ipv4Addr::LOCALHOST])
        .build()
        .expect("participant");
    let ctx = Context::from_domain_participant(dp).expect("context");
    let mut node = ctx
        .new_node(
            NodeName::new("/", "dc_loc_latency_bench").expect("name"),
            NodeOptions::new(),
        )
        .expect("node");
    let qos = QosProfile::publisher_default()
        .reliability(Reliability::Reliable {
            when_full: WhenFull::Wait(Duration::from_millis(100)),
        })
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 100 });
    let mut cloud_pubs = BTreeMap::new();
    let mut odom_pub = None;
    for t in &topics {
        let (pkg, ty) = if t == "/odom" {
            ("nav_msgs", "Odometry")
        } else {
            ("sensor_msgs", "PointCloud2")
        };
        let topic = node
            .create_topic(
                &Name::parse(t).expect("topic"),
                MessageTypeName::new(pkg, ty),
                &qos,
            )
            .expect("topic");
        if t == "/odom" {
            odom_pub = Some(
                node.create_publisher::<Odometry>(&topic, None)
                    .expect("pub"),
            );
        } else {
            cloud_pubs.insert(
                t.clone(),
                node.create_publisher::<PointCloud2>(&topic, None)
                    .expect("pub"),
            );
        }
    }
    let odom_pub = odom_pub.expect("no /odom in the bag");
    let diag_topic = node
        .create_topic(
            &Name::parse("/diagnostics").expect("topic"),
            MessageTypeName::new("diagnostic_msgs", "DiagnosticArray"),
            &qos,
        )
        .expect("topic");
    let diag_sub = node
        .create_subscription::<DiagnosticArray>(&diag_topic, Some(qos.clone()))
        .expect("sub");
    let spinner = node.spinner().expect("spinner");
    let _spin = smol::spawn(spinner.spin());

    let latest = std::sync::Arc::new(std::sync::Mutex::new(BTreeMap::<String, String>::new()));
    smol::block_on(async {
        // Wait for the node to match every publisher (discovery takes 0.2 to 1.5 s).
        let t0 = Instant::now();
        while odom_pub.get_subscription_count(&node) == 0
            || cloud_pubs
                .values()
                .any(|p| p.get_subscription_count(&node) == 0)
        {
            assert!(
                t0.elapsed() < Duration::from_secs(30),
                "the node did not match"
            );
            smol::Timer::after(Duration::from_millis(50)).await;
        }
        let latest2 = latest.clone();
        let diag_task = smol::spawn(async move {
            let mut s = std::pin::pin!(diag_sub.async_stream());
            while let Some(Ok((d, _))) = s.next().await {
                let mut l = latest2.lock().unwrap_or_else(|e| e.into_inner());
                for st in &d.status {
                    for kv in &st.values {
                        l.insert(kv.key.clone(), kv.value.clone());
                    }
                }
            }
        });
        let cpu0 = cpu_seconds(pid).unwrap_or(0.0);
        let start = Instant::now();
        let first = messages[0].0;
        let mut last_print = Instant::now();
        for (t, topic, cloud, odom) in &messages {
            let due = start + Duration::from_secs_f64(t.secs_since(first) / rate);
            if let Some(wait) = due.checked_duration_since(Instant::now()) {
                smol::Timer::after(wait).await;
            }
            if let Some(c) = cloud {
                let _ = cloud_pubs[topic].async_publish(c.clone()).await;
            } else if let Some(o) = odom {
                let _ = odom_pub.async_publish(o.clone()).await;
            }
            if last_print.elapsed() > Duration::from_secs(5) {
                last_print = Instant::now();
                let l = latest.lock().unwrap_or_else(|e| e.into_inner()).clone();
                println!(
                    "{:5.1} s: latency p50 {} ms p99 {} ms, queue {}, keyframes {}, closures {}",
                    start.elapsed().as_secs_f64(),
                    l.get("latency_ms.p50").map_or("-", String::as_str),
                    l.get("latency_ms.p99").map_or("-", String::as_str),
                    l.get("queue_depth").map_or("-", String::as_str),
                    l.get("keyframes").map_or("-", String::as_str),
                    l.get("closures").map_or("-", String::as_str),
                );
            }
        }
        let wall = start.elapsed().as_secs_f64();
        let cpu = cpu_seconds(pid).unwrap_or(0.0) - cpu0;
        // Two more diagnostics periods for the final figures.
        smol::Timer::after(Duration::from_millis(2500)).await;
        let l = latest.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let g = |k: &str| l.get(k).cloned().unwrap_or_else(|| "-".into());
        println!(
            "\nsummary: {radars} radars + odometry, {} messages in {wall:.1} s\n\
             arrival -> processed and published (last 2000 inputs): p50 {} ms, p99 {} ms, max {} ms\n\
             arrival -> loop closure published: p50 {} ms, p99 {} ms, max {} ms\n\
             keyframe processing: p50 {} ms, p99 {} ms\n\
             node CPU: {cpu:.1} s in {wall:.1} s = {:.0} % of one core\n\
             queue depth max {}, dropped queue_full {}, keyframes {}, closures {}",
            messages.len(),
            g("latency_ms.p50"),
            g("latency_ms.p99"),
            g("latency_ms.max"),
            g("closure_latency_ms.p50"),
            g("closure_latency_ms.p99"),
            g("closure_latency_ms.max"),
            g("keyframe_processing_ms.p50"),
            g("keyframe_processing_ms.p99"),
            100.0 * cpu / wall,
            g("queue_depth_max"),
            l.get("queue_full").cloned().unwrap_or_else(|| "0".into()),
            g("keyframes"),
            g("closures"),
        );
        drop(diag_task);
    });
    let _ = Command::new("kill")
        .args(["-INT", &pid.to_string()])
        .status();
    let _ = node_proc.wait();
    let _ = std::fs::remove_dir_all(&dir);
}
