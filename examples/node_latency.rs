//! Latency benchmark of the ROS 2 node: five radars at 13 Hz (the simulator's nuScenes preset) and
//! odometry at 25 Hz published in real time to the running `dc_loc` node, which reports in
//! `/diagnostics` the time from a message's arrival (taken off DDS) to the end of its processing,
//! outputs published (`latency_ms`), and from arrival to a loop closure's publication
//! (`closure_latency_ms`); the node's CPU share comes from /proc.
//!
//! With `--secure`, one run measures the node twice on the same drive: unsecured, then on a secured
//! domain (SROS2, Enforce) with a keystore made by `launch_scripts/make_keystore.sh` in a scratch
//! directory, the node and the replaying participant each with an enclave of it; then it prints the
//! ratios secured / unsecured of CPU share and latencies. The keystore has sros2's governance: every
//! DATA submessage is encrypted (`metadata_protection_kind: ENCRYPT`), and every payload inside it once
//! more (`data_protection_kind: ENCRYPT`).
//!
//! ```text
//! cargo build --release && cargo run --release --example node_latency -- [--rate 1.0] [--secure] \
//!     [--node target/release/dc_loc] [--params FILE] [-- NODE ROS ARGS, e.g. -p node.sync_timeout:=0.01]
//! ```
//! DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; domain ROS_DOMAIN_ID, default 77).
//! Prints one line per five seconds and a summary per run; the figures go into README_NODE.md.

#[path = "support/replay.rs"]
mod replay;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use replay::{
    Drive, Replayer, Security, arg, cpu_seconds, make_keystore, node_args, scratch, start_node,
    stop_node,
};

/// The `/diagnostics` keys whose secured / unsecured ratio `--secure` prints.
const COMPARED: [&str; 6] = [
    "latency_ms.p50",
    "latency_ms.p99",
    "keyframe_processing_ms.p50",
    "keyframe_processing_ms.p99",
    "closure_latency_ms.p50",
    "closure_latency_ms.p99",
];

/// What one run measured: the node's CPU time over the replay's wall time, and its last
/// `/diagnostics` values.
struct Figures {
    cpu: f64,
    wall: f64,
    values: BTreeMap<String, String>,
}

impl Figures {
    fn cpu_share(&self) -> f64 {
        self.cpu / self.wall
    }

    fn get(&self, key: &str) -> &str {
        self.values.get(key).map_or("-", String::as_str)
    }

    fn number(&self, key: &str) -> Option<f64> {
        self.values.get(key)?.parse().ok()
    }
}

/// How one run is set up.
struct Run<'a> {
    drive: &'a Drive,
    node_bin: &'a str,
    params: &'a Path,
    domain: u16,
    rate: f64,
}

impl Run<'_> {
    /// Starts the node (secured with `security`'s enclave `/dc_loc` when given, the replayer then with
    /// its enclave `/replayer`), replays the drive in real time times `rate`, and stops the node.
    fn measure(&self, security: Option<&Security>) -> Figures {
        let node = start_node(
            self.node_bin,
            self.params,
            &node_args(),
            self.domain,
            security,
            std::process::Stdio::inherit(),
        );
        let pid = node.id();
        let rt = replay::runtime();
        let _entered = rt.enter();
        let replayer_security = security.map(|s| s.with_enclave("/replayer"));
        let replayer = Replayer::new(
            self.domain,
            &self.drive.radar_topics,
            replayer_security.as_ref(),
        );
        let (cpu, wall) = rt.block_on(self.replay(&replayer, pid));
        let values = replayer
            .latest
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .0
            .clone();
        stop_node(node);
        Figures { cpu, wall, values }
    }

    /// Publishes the drive's messages at their times; returns the node's CPU time and the wall time
    /// of the replay, s.
    async fn replay(&self, replayer: &Replayer, pid: u32) -> (f64, f64) {
        replayer.wait_for_node().await;
        let cpu0 = cpu_seconds(pid).unwrap_or(0.0);
        let start = Instant::now();
        let first = self.drive.messages[0].0;
        let mut last_print = Instant::now();
        for (t, m) in &self.drive.messages {
            let due = start + Duration::from_secs_f64(t.secs_since(first) / self.rate);
            if let Some(wait) = due.checked_duration_since(Instant::now()) {
                tokio::time::sleep(wait).await;
            }
            replayer.publish(m).await;
            if last_print.elapsed() > Duration::from_secs(5) {
                last_print = Instant::now();
                println!(
                    "{:5.1} s: latency p50 {} ms p99 {} ms, queue {}, keyframes {}, closures {}",
                    start.elapsed().as_secs_f64(),
                    replayer.value("latency_ms.p50"),
                    replayer.value("latency_ms.p99"),
                    replayer.value("queue_depth"),
                    replayer.value("keyframes"),
                    replayer.value("closures"),
                );
            }
        }
        let wall = start.elapsed().as_secs_f64();
        let cpu = cpu_seconds(pid).unwrap_or(0.0) - cpu0;
        // Two more diagnostics periods for the final figures.
        tokio::time::sleep(Duration::from_millis(2500)).await;
        (cpu, wall)
    }
}

fn print_summary(label: &str, radars: usize, messages: usize, f: &Figures) {
    let g = |k: &str| f.get(k);
    println!(
        "\nsummary ({label}): {radars} radars + odometry, {messages} messages in {:.1} s\n\
         arrival -> processed and published (last 2000 inputs): p50 {} ms, p99 {} ms, max {} ms\n\
         arrival -> loop closure published: p50 {} ms, p99 {} ms, max {} ms\n\
         keyframe processing: p50 {} ms, p99 {} ms\n\
         node CPU: {:.1} s in {:.1} s = {:.0} % of one core\n\
         queue depth max {}, dropped reception_queue_full {}, keyframes {}, closures {}",
        f.wall,
        g("latency_ms.p50"),
        g("latency_ms.p99"),
        g("latency_ms.max"),
        g("closure_latency_ms.p50"),
        g("closure_latency_ms.p99"),
        g("closure_latency_ms.max"),
        g("keyframe_processing_ms.p50"),
        g("keyframe_processing_ms.p99"),
        f.cpu,
        f.wall,
        100.0 * f.cpu_share(),
        g("queue_depth_max"),
        g("reception_queue_full"),
        g("keyframes"),
        g("closures"),
    );
}

/// Secured / unsecured, one line per figure.
fn print_ratios(plain: &Figures, secured: &Figures) {
    println!("\nsecured / unsecured:");
    println!(
        "  CPU share: {:.0} % / {:.0} % of one core = {:.2}",
        100.0 * secured.cpu_share(),
        100.0 * plain.cpu_share(),
        secured.cpu_share() / plain.cpu_share()
    );
    for key in COMPARED {
        match (secured.number(key), plain.number(key)) {
            (Some(s), Some(p)) if p > 0.0 => {
                println!("  {key}: {s} ms / {p} ms = {:.2}", s / p)
            }
            _ => println!(
                "  {key}: {} / {} (no ratio)",
                secured.get(key),
                plain.get(key)
            ),
        }
    }
    println!(
        "  closures: {} / {}",
        secured.get("closures"),
        plain.get("closures")
    );
}

fn main() {
    let rate: f64 = arg("--rate").and_then(|r| r.parse().ok()).unwrap_or(1.0);
    let node_bin = arg("--node").unwrap_or_else(|| "target/release/dc_loc".into());
    let secure = std::env::args()
        .take_while(|a| a != "--")
        .any(|a| a == "--secure");
    let domain: u16 = std::env::var("ROS_DOMAIN_ID")
        .ok()
        .and_then(|d| d.parse().ok())
        .unwrap_or(77);
    let dir = scratch("node_latency");
    let drive = Drive::simulate(&dir);
    let radars = drive.radar_topics.len();
    let messages = drive.messages.len();
    println!(
        "drive: {radars} radars, {messages} messages over {:.0} s, replayed at {rate}x",
        drive.duration()
    );
    // `--params FILE` replaces the drive's parameter file (an older build may not know every parameter).
    let params = arg("--params").map_or(drive.summary.params_file.clone(), Into::into);
    let run = Run {
        drive: &drive,
        node_bin: &node_bin,
        params: &params,
        domain,
        rate,
    };
    if secure {
        let keystore = dir.join("keystore");
        make_keystore(&keystore, domain, "ENCRYPT", &["/dc_loc", "/replayer"]);
        println!(
            "keystore {} (sros2's governance: payloads encrypted)",
            keystore.display()
        );
        println!("\n-- unsecured --");
        let plain = run.measure(None);
        print_summary("unsecured", radars, messages, &plain);
        println!("\n-- secured (SROS2, Enforce) --");
        let secured = run.measure(Some(&Security::new(&keystore, "/dc_loc")));
        print_summary("secured", radars, messages, &secured);
        print_ratios(&plain, &secured);
    } else {
        let figures = run.measure(None);
        print_summary("unsecured", radars, messages, &figures);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
