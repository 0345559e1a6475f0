//! Soak run of the ROS 2 node: the simulator's five-radar drive replayed over and over into the running
//! `dc_loc` node (with a map file), each pass continuing the last one (stamps shifted on, odometry
//! composed onto the previous pass's end), for `--minutes` of wall time at `--rate` times real time.
//! Every minute it samples the node's resident memory, threads, open files, map file size, the points
//! of its newest `~/markers` message and its p99 latency, and the longest silence of `/diagnostics`.
//!
//! ```text
//! cargo build --release && cargo run --release --example soak -- [--minutes 60] [--rate 10] \
//!     [--node target/release/dc_loc] [--log soak_node.log] [-- NODE ROS ARGS]
//! ```
//! DDS stays on loopback (domain ROS_DOMAIN_ID, default 78). Not part of the test suite (an hour).
//! At the end it prints the verdicts: threads and open files flat after the first minutes, memory
//! per map keyframe, `/diagnostics` never silent for more than twice its period.

#[path = "support/replay.rs"]
mod replay;

use std::time::{Duration, Instant};

use dc_loc::math::{Iso3, Stamp};
use dc_loc::msgs::geometry_msgs::Pose;
use replay::{
    Drive, Message, Replayer, arg, node_args, open_files, proc_status, scratch, start_node,
    stop_node,
};

/// One minute's sample.
struct Sample {
    minute: u32,
    drive_hours: f64,
    rss_mb: f64,
    threads: u64,
    files: usize,
    map_mb: f64,
    map_keyframes: u64,
    marker_points: u64,
    p99_ms: String,
    dropped_queue: String,
    closures: String,
}

/// `pose` moved by `offset` (left-multiplied).
fn moved(pose: &Pose, offset: &Iso3) -> Pose {
    let p = pose.to_iso3().map(|p| offset * p).unwrap_or(*offset);
    let (t, q) = (p.translation.vector, p.rotation);
    let mut out = *pose;
    out.position.x = t.x;
    out.position.y = t.y;
    out.position.z = t.z;
    out.orientation.x = q.i;
    out.orientation.y = q.j;
    out.orientation.z = q.k;
    out.orientation.w = q.w;
    out
}

/// Pass `k` of the drive: stamps shifted by `shift`, odometry moved by `offset`.
fn pass_message(m: &Message, shift: i64, offset: &Iso3) -> Message {
    let restamp = |s: dc_loc::msgs::builtin_interfaces::Time| {
        let t: Stamp = s.into();
        Stamp(t.0 + shift).into()
    };
    match m {
        Message::Cloud(topic, c) => {
            let mut c = c.clone();
            c.header.stamp = restamp(c.header.stamp);
            Message::Cloud(topic.clone(), c)
        }
        Message::Odometry(o) => {
            let mut o = o.clone();
            o.header.stamp = restamp(o.header.stamp);
            o.pose.pose = moved(&o.pose.pose, offset);
            Message::Odometry(o)
        }
    }
}

/// The first and last odometry poses of the drive.
fn end_poses(drive: &Drive) -> (Iso3, Iso3) {
    let poses: Vec<Iso3> = drive
        .messages
        .iter()
        .filter_map(|(_, m)| match m {
            Message::Odometry(o) => o.pose.pose.to_iso3(),
            Message::Cloud(..) => None,
        })
        .collect();
    (poses[0], *poses.last().expect("odometry"))
}

fn sample(
    minute: u32,
    pid: u32,
    replayer: &Replayer,
    map: &std::path::Path,
    drive_s: f64,
) -> Sample {
    let num = |k: &str| replayer.value(k).parse::<u64>().unwrap_or(0);
    Sample {
        minute,
        drive_hours: drive_s / 3600.0,
        rss_mb: proc_status(pid, "VmRSS").unwrap_or(0) as f64 / 1024.0,
        threads: proc_status(pid, "Threads").unwrap_or(0),
        files: open_files(pid).unwrap_or(0),
        map_mb: std::fs::metadata(map).map_or(0.0, |m| m.len() as f64 / 1e6),
        map_keyframes: num("map_keyframes"),
        marker_points: num("markers_points"),
        p99_ms: replayer.value("latency_ms.p99"),
        dropped_queue: replayer.value("reception_queue_full"),
        closures: replayer.value("closures"),
    }
}

fn print_sample(s: &Sample) {
    println!(
        "| {} | {:.2} | {:.0} | {} | {} | {:.1} | {} | {} | {} | {} | {} |",
        s.minute,
        s.drive_hours,
        s.rss_mb,
        s.threads,
        s.files,
        s.map_mb,
        s.map_keyframes,
        s.marker_points,
        s.p99_ms,
        s.dropped_queue,
        s.closures
    );
}

fn verdicts(samples: &[Sample], longest_gap: f64, period: f64) {
    let settled = &samples[samples.len().min(3) - 1..];
    let span = |f: &dyn Fn(&Sample) -> f64| {
        let v: Vec<f64> = settled.iter().map(f).collect();
        let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        (lo, hi)
    };
    let (t_lo, t_hi) = span(&|s| s.threads as f64);
    let (f_lo, f_hi) = span(&|s| s.files as f64);
    let last = samples.last().expect("samples");
    let first = &samples[0];
    let per_kf = if last.map_keyframes > first.map_keyframes {
        (last.rss_mb - first.rss_mb) * 1024.0 / (last.map_keyframes - first.map_keyframes) as f64
    } else {
        f64::NAN
    };
    println!("\nthreads after minute 3: {t_lo} .. {t_hi}; open files: {f_lo} .. {f_hi}");
    println!(
        "memory: {:.0} MB at minute {} -> {:.0} MB at minute {}; {:.1} kB per map keyframe added",
        first.rss_mb, first.minute, last.rss_mb, last.minute, per_kf
    );
    println!(
        "longest /diagnostics silence: {longest_gap:.2} s (period {period} s; verdict: {})",
        if longest_gap <= 2.0 * period {
            "ok"
        } else {
            "TOO LONG"
        }
    );
}

fn main() {
    let minutes: u32 = arg("--minutes").and_then(|m| m.parse().ok()).unwrap_or(60);
    let rate: f64 = arg("--rate").and_then(|r| r.parse().ok()).unwrap_or(10.0);
    let node_bin = arg("--node").unwrap_or_else(|| "target/release/dc_loc".into());
    let domain: u16 = std::env::var("ROS_DOMAIN_ID")
        .ok()
        .and_then(|d| d.parse().ok())
        .unwrap_or(78);
    let dir = scratch("soak");
    let drive = Drive::simulate(&dir);
    let map = dir.join("soak.map");
    let mut extra = vec!["-p".to_string(), format!("map.file:={}", map.display())];
    extra.extend(node_args());
    // The node's log goes to a file beside the output (`--log FILE`, default soak_node.log).
    let log_path = arg("--log").unwrap_or_else(|| "soak_node.log".into());
    let log = std::fs::File::create(&log_path).expect("node log file");
    let node = start_node(
        &node_bin,
        &drive.summary.params_file,
        &extra,
        domain,
        None,
        log.into(),
    );
    let pid = node.id();
    let rt = replay::runtime();
    let _entered = rt.enter();
    let replayer = Replayer::new(domain, &drive.radar_topics, None);
    let (start_pose, end_pose) = end_poses(&drive);
    // One pass: the drive's duration plus one odometry period, so stamps never repeat.
    let pass_ns = ((drive.duration() + 0.04) * 1e9) as i64;
    let one_pass = end_pose * start_pose.inverse();
    println!(
        "soak: {minutes} min at {rate}x, passes of {:.0} s of the five-radar drive, map {}",
        drive.duration(),
        map.display()
    );
    println!(
        "\n| minute | drive h | RSS MB | threads | files | map MB | map keyframes | marker points | latency p99 ms | reception_queue_full | closures |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let mut samples = Vec::new();
    rt.block_on(async {
        replayer.wait_for_node().await;
        let start = Instant::now();
        let end = start + Duration::from_secs(u64::from(minutes) * 60);
        let first = drive.messages[0].0;
        let (mut offset, mut pass) = (Iso3::identity(), 0i64);
        let mut next_sample = start + Duration::from_secs(60);
        'passes: loop {
            for (t, m) in &drive.messages {
                let drive_s = (pass * pass_ns) as f64 * 1e-9 + t.secs_since(first);
                let due = start + Duration::from_secs_f64(drive_s / rate);
                if let Some(wait) = due.checked_duration_since(Instant::now()) {
                    tokio::time::sleep(wait).await;
                }
                replayer
                    .publish(&pass_message(m, pass * pass_ns, &offset))
                    .await;
                if Instant::now() >= next_sample {
                    next_sample += Duration::from_secs(60);
                    let s = sample(samples.len() as u32 + 1, pid, &replayer, &map, drive_s);
                    print_sample(&s);
                    samples.push(s);
                }
                if Instant::now() >= end {
                    break 'passes;
                }
            }
            pass += 1;
            offset *= one_pass;
        }
        tokio::time::sleep(Duration::from_secs(3)).await;
    });
    let gap = *replayer
        .longest_gap
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    if !samples.is_empty() {
        verdicts(&samples, gap, 1.0);
    }
    let code = stop_node(node);
    println!("node exit code {code:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
