//! Latency benchmark of the ROS 2 node: five radars at 13 Hz (the simulator's nuScenes preset) and
//! odometry at 25 Hz published in real time to the running `dc_loc` node, which reports in
//! `/diagnostics` the time from a message's arrival (taken off DDS) to the end of its processing,
//! outputs published (`latency_ms`), and from arrival to a loop closure's publication
//! (`closure_latency_ms`); the node's CPU share comes from /proc.
//!
//! ```text
//! cargo build --release && cargo run --release --example node_latency -- [--rate 1.0] \
//!     [--node target/release/dc_loc] [--params FILE] [-- NODE ROS ARGS, e.g. -p node.sync_timeout:=0.01]
//! ```
//! DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; domain ROS_DOMAIN_ID, default 77).
//! Prints one line per second and a summary; the figures go into README_NODE.md.

#[path = "support/replay.rs"]
mod replay;

use std::time::{Duration, Instant};

use replay::{Drive, Replayer, arg, cpu_seconds, node_args, scratch, start_node, stop_node};

fn main() {
    let rate: f64 = arg("--rate").and_then(|r| r.parse().ok()).unwrap_or(1.0);
    let node_bin = arg("--node").unwrap_or_else(|| "target/release/dc_loc".into());
    let domain: u16 = std::env::var("ROS_DOMAIN_ID")
        .ok()
        .and_then(|d| d.parse().ok())
        .unwrap_or(77);
    let dir = scratch("node_latency");
    let drive = Drive::simulate(&dir);
    let radars = drive.radar_topics.len();
    println!(
        "drive: {radars} radars, {} messages over {:.0} s, replayed at {rate}x",
        drive.messages.len(),
        drive.duration()
    );
    // `--params FILE` replaces the drive's parameter file (an older build may not know every parameter).
    let params = arg("--params").map_or(drive.summary.params_file.clone(), Into::into);
    let node = start_node(
        &node_bin,
        &params,
        &node_args(),
        domain,
        std::process::Stdio::inherit(),
    );
    let pid = node.id();
    let rt = replay::runtime();
    let _entered = rt.enter();
    let replayer = Replayer::new(domain, &drive.radar_topics);
    rt.block_on(async {
        replayer.wait_for_node().await;
        let cpu0 = cpu_seconds(pid).unwrap_or(0.0);
        let start = Instant::now();
        let first = drive.messages[0].0;
        let mut last_print = Instant::now();
        for (t, m) in &drive.messages {
            let due = start + Duration::from_secs_f64(t.secs_since(first) / rate);
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
        let g = |k: &str| replayer.value(k);
        println!(
            "\nsummary: {radars} radars + odometry, {} messages in {wall:.1} s\n\
             arrival -> processed and published (last 2000 inputs): p50 {} ms, p99 {} ms, max {} ms\n\
             arrival -> loop closure published: p50 {} ms, p99 {} ms, max {} ms\n\
             keyframe processing: p50 {} ms, p99 {} ms\n\
             node CPU: {cpu:.1} s in {wall:.1} s = {:.0} % of one core\n\
             queue depth max {}, dropped reception_queue_full {}, keyframes {}, closures {}",
            drive.messages.len(),
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
            g("reception_queue_full"),
            g("keyframes"),
            g("closures"),
        );
    });
    stop_node(node);
    let _ = std::fs::remove_dir_all(&dir);
}
