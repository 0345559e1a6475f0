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
//! With `--one-core`, each node runs on one core: its process pinned to CPU 0 (`taskset -c 0`) and its
//! thread pool cut to one thread (`RAYON_NUM_THREADS=1`; the node's other threads are fixed: one tokio
//! thread for DDS reception and timers, the pipeline's worker, the map store's and `/rosout`'s writers,
//! and rustdds's own). The CPU share is of one core in every mode.
//!
//! With `--fleet N`, N nodes on one domain exchange keyframes (`-p node.fleet:=true`, each its own
//! `node.robot_id` and namespace `/robot_k`): the drive's world driven once by each of N robots
//! (`sim::fleet::fleet`, every other robot the other way round), all replayed at the same time, each
//! robot's messages into its own node. Each node's CPU share is over its own robot's replay. The nodes
//! publish on one `/diagnostics` topic, so the summary gives the CPU of each and the fleet counts.
//!
//! `--json OUT` writes every run's figures (CPU, wall time, threads, the last `/diagnostics` values) to
//! OUT, for `examples/budgets.rs`.
//!
//! ```text
//! cargo build --release && cargo run --release --example node_latency -- [--rate 1.0] [--secure] \
//!     [--one-core] [--fleet 3] [--json OUT] [--node target/release/dc_loc] [--params FILE] \
//!     [-- NODE ROS ARGS, e.g. -p node.sync_timeout:=0.01]
//! ```
//! DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; domain ROS_DOMAIN_ID, default 77).
//! Prints one line per five seconds and a summary per run; the figures go into README_NODE.md.

#[path = "support/replay.rs"]
mod replay;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use dc_loc::sim::SimConfig;
use replay::{
    DRIVE, Drive, Replayer, Security, arg, cpu_seconds, make_keystore, node_args, proc_status,
    scratch, start_node_with, stop_node,
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
    threads: u64,
    values: BTreeMap<String, String>,
}

impl Figures {
    fn cpu_share(&self) -> f64 {
        self.cpu / self.wall
    }

    fn json(&self, label: &str) -> serde_json::Value {
        serde_json::json!({
            "label": label,
            "cpu_seconds": self.cpu,
            "wall_seconds": self.wall,
            "cpu_share": self.cpu_share(),
            "threads": self.threads,
            "values": self.values,
        })
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
    one_core: bool,
}

/// The command that runs the node: its binary, or with `one_core` the binary pinned to CPU 0 with one
/// rayon thread.
fn node_command(bin: &str, one_core: bool) -> Command {
    if one_core {
        let mut c = Command::new("taskset");
        c.args(["-c", "0", bin]).env("RAYON_NUM_THREADS", "1");
        c
    } else {
        let mut c = Command::new(bin);
        c.env_remove("RAYON_NUM_THREADS");
        c
    }
}

impl Run<'_> {
    /// Starts the node (secured with `security`'s enclave `/dc_loc` when given, the replayer then with
    /// its enclave `/replayer`), replays the drive in real time times `rate`, and stops the node.
    fn measure(&self, security: Option<&Security>) -> Figures {
        let node = start_node_with(
            node_command(self.node_bin, self.one_core),
            self.params,
            &node_args(),
            self.domain,
            security,
            Stdio::inherit(),
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
        let threads = proc_status(pid, "Threads").unwrap_or(0);
        let values = replayer
            .latest
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .0
            .clone();
        stop_node(node);
        Figures {
            cpu,
            wall,
            threads,
            values,
        }
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
         node CPU: {:.1} s in {:.1} s = {:.1} % of one core ({} threads)\n\
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
        f.threads,
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

/// A fleet of `robots` nodes on one domain, each robot's drive replayed into its own node, all at once:
/// each node's figures (CPU over its own robot's replay).
fn measure_fleet(
    robots: u32,
    dir: &Path,
    node_bin: &str,
    domain: u16,
    rate: f64,
    one_core: bool,
) -> Vec<Figures> {
    let cfg: SimConfig = yaml_serde::from_str(DRIVE).expect("drive config");
    let configs = dc_loc::sim::fleet::fleet(&cfg, robots).expect("fleet");
    let drives: Vec<Drive> = configs
        .iter()
        .enumerate()
        .map(|(k, c)| Drive::simulate_config(c, &dir.join(format!("robot_{k}"))))
        .collect();
    for (k, d) in drives.iter().enumerate() {
        println!(
            "robot {k}: {} messages over {:.0} s",
            d.messages.len(),
            d.duration()
        );
    }
    let nodes: Vec<_> = drives
        .iter()
        .enumerate()
        .map(|(k, d)| {
            let ns = format!("/robot_{k}");
            // The parameters under the node's full name; the drive's topics (absolute in them) remapped
            // into the robot's namespace, where its replayer publishes.
            let text = std::fs::read_to_string(&d.summary.params_file).expect("params");
            assert!(text.contains("\ndc_loc:"), "no top-level dc_loc: section");
            let params = dir.join(format!("robot_{k}.yaml"));
            std::fs::write(
                &params,
                text.replacen("\ndc_loc:", &format!("\n{ns}/dc_loc:"), 1),
            )
            .expect("params");
            let mut extra: Vec<String> = vec![
                "-r".into(),
                format!("__ns:={ns}"),
                "-p".into(),
                format!("node.robot_id:={k}"),
                "-p".into(),
                "node.fleet:=true".into(),
            ];
            for t in d.radar_topics.iter().map(String::as_str).chain(["/odom"]) {
                extra.extend(["-r".into(), format!("{t}:={ns}{t}")]);
            }
            extra.extend(node_args());
            start_node_with(
                node_command(node_bin, one_core),
                &params,
                &extra,
                domain,
                None,
                Stdio::inherit(),
            )
        })
        .collect();
    let pids: Vec<u32> = nodes.iter().map(|n| n.id()).collect();
    let rt = replay::runtime();
    let _entered = rt.enter();
    let replayers: Vec<Replayer> = drives
        .iter()
        .enumerate()
        .map(|(k, d)| Replayer::in_namespace(domain, &format!("/robot_{k}"), &d.radar_topics, None))
        .collect();
    let measured: Vec<(f64, f64, u64)> = rt.block_on(async {
        for r in &replayers {
            r.wait_for_node().await;
        }
        let plays = replayers
            .iter()
            .zip(&drives)
            .zip(&pids)
            .map(|((r, d), &pid)| async move {
                let cpu0 = cpu_seconds(pid).unwrap_or(0.0);
                let start = Instant::now();
                r.play(&d.messages, rate).await;
                let wall = start.elapsed().as_secs_f64();
                let cpu = cpu_seconds(pid).unwrap_or(0.0) - cpu0;
                (cpu, wall, proc_status(pid, "Threads").unwrap_or(0))
            });
        let out = futures::future::join_all(plays).await;
        // Two more diagnostics periods for the final figures.
        tokio::time::sleep(Duration::from_millis(2500)).await;
        out
    });
    // The nodes share `/diagnostics`: every replayer heard all of them; the first one's values.
    let values = replayers[0]
        .latest
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .0
        .clone();
    for n in nodes {
        stop_node(n);
    }
    measured
        .into_iter()
        .map(|(cpu, wall, threads)| Figures {
            cpu,
            wall,
            threads,
            values: values.clone(),
        })
        .collect()
}

fn print_fleet(figures: &[Figures]) {
    println!("\nsummary (fleet of {}):", figures.len());
    for (k, f) in figures.iter().enumerate() {
        println!(
            "  node {k}: CPU {:.1} s in {:.1} s = {:.1} % of one core ({} threads)",
            f.cpu,
            f.wall,
            100.0 * f.cpu_share(),
            f.threads
        );
    }
    if let Some(f) = figures.first() {
        for (k, v) in f.values.iter().filter(|(k, _)| k.starts_with("fleet.")) {
            println!("  {k}: {v}");
        }
    }
}

fn write_json(path: Option<String>, mode: &str, runs: serde_json::Value) {
    if let Some(path) = path {
        let body = serde_json::json!({ "mode": mode, "runs": runs });
        std::fs::write(&path, format!("{body:#}\n"))
            .unwrap_or_else(|e| panic!("cannot write {path}: {e}"));
    }
}

fn main() {
    let rate: f64 = arg("--rate").and_then(|r| r.parse().ok()).unwrap_or(1.0);
    let node_bin = arg("--node").unwrap_or_else(|| "target/release/dc_loc".into());
    let flag = |name: &str| {
        std::env::args()
            .take_while(|a| a != "--")
            .any(|a| a == name)
    };
    let (secure, one_core) = (flag("--secure"), flag("--one-core"));
    let fleet: Option<u32> = arg("--fleet").and_then(|n| n.parse().ok());
    let json = arg("--json");
    let domain: u16 = std::env::var("ROS_DOMAIN_ID")
        .ok()
        .and_then(|d| d.parse().ok())
        .unwrap_or(77);
    let dir = scratch("node_latency");
    if one_core {
        println!("one core: each node pinned to CPU 0, RAYON_NUM_THREADS=1");
    }
    if let Some(robots) = fleet {
        println!("fleet of {robots} nodes, replayed at {rate}x");
        let figures = measure_fleet(robots, &dir, &node_bin, domain, rate, one_core);
        print_fleet(&figures);
        let runs = figures
            .iter()
            .enumerate()
            .map(|(k, f)| f.json(&format!("robot_{k}")))
            .collect();
        write_json(json, "fleet", serde_json::Value::Array(runs));
        let _ = std::fs::remove_dir_all(&dir);
        return;
    }
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
        one_core,
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
        let runs = vec![plain.json("unsecured"), secured.json("secured")];
        write_json(json, "secure", serde_json::Value::Array(runs));
    } else {
        let figures = run.measure(None);
        print_summary("unsecured", radars, messages, &figures);
        write_json(
            json,
            "single",
            serde_json::Value::Array(vec![figures.json("unsecured")]),
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
