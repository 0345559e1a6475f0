//! The ROS 2 node as real ROS 2 users see it: the `dc_loc` binary, fed by rclpy publishers replaying a
//! simulated drive (tests/python/test_node_replay.py), its loop closures received by an rclpy subscriber
//! (typed `dc_loc/msg/LoopClosure`) and a Cyclone DDS subscriber, checked against the ground truth and
//! against `dc_loc run` on the same bag; without wheel odometry (`odometry.source: radar`, and `radar_imu`
//! with the simulated gyro), also `~/odometry` against `dc_loc run --odometry-out`.
//!
//! The drive: `dc_loc sim` of two laps (54 and 36 km/h) of a 170 x 110 m block, about 106 s, replayed at
//! `DCLOC_REPLAY_RATE` times real time (default 5). DDS stays on loopback: the script reserves a domain id
//! of its own and sets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and the loopback XML profiles for itself and
//! the node; it stops every process it starts, also on failure. The tests of this file run one at a time
//! (two cores).

#[path = "python/venv.rs"]
mod venv;

mod common;
use common::{SHORT_DRIVE, text};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::{Mutex, MutexGuard, OnceLock};

use dc_loc::bag::BagReader;
use dc_loc::eval::{Collector, EvalConfig, make_pairs};
use dc_loc::io::rosbag::BagInputs;
use dc_loc::math::{Stamp, wrap_angle};
use dc_loc::output::{ClosureRecord, PoseRecord};
use dc_loc::pipeline::Config;
use dc_loc::sim::export::GROUND_TRUTH_TOPIC;
use dc_loc::sim::{SimConfig, SimDrive, simulate};

fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

fn scratch(name: &str) -> PathBuf {
    common::scratch("node_tests", name)
}

fn dc_loc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dc_loc"))
        .args(args)
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .output()
        .expect("cannot start dc_loc")
}

struct Drive {
    dir: PathBuf,
    params: PathBuf,
    drive: SimDrive,
    /// `dc_loc run` closures.
    offline: Vec<ClosureRecord>,
    /// Revisit opportunities (crates/lab/src/eval's pairs: nearest earlier keyframe of another pass within 5 m,
    /// same direction): query keyframe id -> target keyframe id.
    opportunities: BTreeMap<u64, u64>,
}

/// The drive, its offline closures and its revisit opportunities (once per test binary).
fn drive() -> &'static Drive {
    static DRIVE: OnceLock<Drive> = OnceLock::new();
    DRIVE.get_or_init(|| make_drive("drive", SHORT_DRIVE))
}

/// The same drive with the five radars of the nuScenes car (13 Hz each).
fn five_radar_drive() -> &'static Drive {
    static DRIVE: OnceLock<Drive> = OnceLock::new();
    DRIVE.get_or_init(|| {
        make_drive(
            "drive_nuscenes",
            &format!("{SHORT_DRIVE}radar_preset: nuscenes\n"),
        )
    })
}

/// The one-radar drive with a simulated 100 Hz gyro on `/imu`.
fn gyro_drive() -> &'static Drive {
    static DRIVE: OnceLock<Drive> = OnceLock::new();
    DRIVE.get_or_init(|| make_drive("drive_gyro", &format!("{SHORT_DRIVE}imu:\n  rate: 100.0\n")))
}

fn make_drive(name: &str, sim_yaml: &str) -> Drive {
    {
        let root = scratch(name);
        let config = root.join("short.yaml");
        std::fs::write(&config, sim_yaml).unwrap();
        let dir = root.join("short");
        let out = dc_loc(&[
            "sim",
            "--config",
            config.to_str().unwrap(),
            "--out",
            dir.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", text(&out.stderr));
        let params = dir.join("dc_loc.yaml");
        let jsonl = root.join("offline.jsonl");
        let out = dc_loc(&[
            "run",
            "--bag",
            dir.to_str().unwrap(),
            "--params",
            params.to_str().unwrap(),
            "--out",
            jsonl.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", text(&out.stderr));
        let offline = read_records(&std::fs::read_to_string(&jsonl).unwrap());

        let cfg: Config = dc_loc::params::apply(
            &dc_loc::params::ParamSet::from_yaml(
                &std::fs::read_to_string(&params).unwrap(),
                "/",
                "dc_loc",
            )
            .unwrap(),
        )
        .unwrap();
        let reader = BagReader::open(&dir).unwrap();
        let eval = EvalConfig::default();
        let mut collector = Collector::new(&cfg, &eval).unwrap();
        for input in BagInputs::new(&reader, &cfg, Some(GROUND_TRUTH_TOPIC)).unwrap() {
            collector.push(&input.unwrap());
        }
        let (kfs, _) = collector.finish();
        let opportunities = make_pairs(&kfs, &eval)
            .iter()
            .map(|p| (kfs[p.query].id, kfs[p.target].id))
            .collect();
        let sim_cfg: SimConfig = yaml_serde::from_str(sim_yaml).unwrap();
        Drive {
            dir,
            params,
            drive: simulate(&sim_cfg).unwrap(),
            offline,
            opportunities,
        }
    }
}

fn read_records(lines: &str) -> Vec<ClosureRecord> {
    lines
        .lines()
        .map(|l| ClosureRecord::from_json_line(l).unwrap())
        .collect()
}

/// What the replay script reports.
struct Replay {
    rclpy: Vec<ClosureRecord>,
    cyclone: Vec<ClosureRecord>,
    diagnostics: BTreeMap<String, String>,
    sent_malformed: BTreeMap<String, u64>,
    node_exit: i64,
    replay_seconds: f64,
    /// `~/markers` (points per marker namespace of the latest) and `~/submap` (count, points, fields).
    outputs: serde_json::Value,
    /// `--set-at`: the stamp of the drive at the parameter change and the service's answer.
    set_at: Option<(f64, String)>,
    /// `--record-odometry`: the node's `~/odometry` messages, in arrival order.
    odometry: Vec<serde_json::Value>,
    /// `--record-tf`: the transforms on `/tf`, in arrival order.
    tf: Vec<serde_json::Value>,
}

impl Replay {
    fn diag(&self, key: &str) -> u64 {
        self.diagnostics
            .get(key)
            .map_or(0, |v| v.parse().unwrap_or_else(|_| panic!("{key}={v}")))
    }
}

fn replay_rate() -> String {
    std::env::var("DCLOC_REPLAY_RATE").unwrap_or_else(|_| "5".into())
}

/// Runs the replay script (`script_args`, then `--` and the node's ROS arguments).
fn replay(name: &str, script_args: &[&str], node_args: &[&str]) -> Replay {
    replay_on(drive(), name, script_args, node_args)
}

/// [`replay`] of drive `d`.
fn replay_on(d: &Drive, name: &str, script_args: &[&str], node_args: &[&str]) -> Replay {
    let out_path = scratch(name).join("result.json");
    let rate = replay_rate();
    let mut cmd = venv::python_script("test_node_replay.py");
    cmd.args([
        "--node",
        env!("CARGO_BIN_EXE_dc_loc"),
        "--bag",
        d.dir.to_str().unwrap(),
        "--out",
        out_path.to_str().unwrap(),
        "--rate",
        &rate,
    ])
    .args(script_args)
    .arg("--")
    .args(node_args);
    let output = cmd.output().expect("cannot start the venv's python");
    let stdout = text(&output.stdout);
    let stderr = text(&output.stderr);
    print!("{stdout}");
    if !output.status.success() {
        for l in stderr
            .lines()
            .filter(|l| !l.contains("INFO") && !l.contains("rustdds"))
        {
            eprintln!("{l}");
        }
    }
    // The node's log is long: its warnings and errors, and the tail.
    for l in stderr
        .lines()
        .filter(|l| l.contains("WARN  dc_loc") || l.contains("ERROR") || l.contains("Error"))
        .take(60)
    {
        eprintln!("{l}");
    }
    let tail: Vec<&str> = stderr.lines().rev().take(15).collect();
    for l in tail.iter().rev() {
        eprintln!("{l}");
    }
    assert!(
        output.status.success(),
        "test_node_replay.py failed ({})",
        output.status
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out_path).unwrap()).unwrap();
    let records = |k: &str| -> Vec<ClosureRecord> {
        v[k].as_array()
            .unwrap()
            .iter()
            .map(|r| ClosureRecord::from_json_line(&r.to_string()).unwrap())
            .collect()
    };
    Replay {
        rclpy: records("rclpy"),
        cyclone: records("cyclone"),
        diagnostics: v["diagnostics"]
            .as_object()
            .unwrap()
            .iter()
            .map(|(k, v)| {
                let key = k.split_once('/').map_or(k.as_str(), |(_, k)| k);
                (key.to_string(), v.as_str().unwrap().to_string())
            })
            .collect(),
        sent_malformed: v["sent"]["malformed"]
            .as_object()
            .unwrap()
            .iter()
            .map(|(k, n)| (k.clone(), n.as_u64().unwrap()))
            .collect(),
        node_exit: v["node_exit"].as_i64().unwrap(),
        replay_seconds: v["replay_seconds"].as_f64().unwrap(),
        outputs: v["outputs"].clone(),
        odometry: v["odometry"].as_array().cloned().unwrap_or_default(),
        tf: v["tf"].as_array().cloned().unwrap_or_default(),
        set_at: v["set_at_stamp"].as_f64().map(|t| {
            let answer = v["set_result"].as_str().unwrap_or_default().to_string();
            (t, answer)
        }),
    }
}

fn yaw(p: &PoseRecord) -> f64 {
    2.0 * p.qz.atan2(p.qw)
}

/// Translation (m) and rotation (rad) differences of two relative poses.
fn pose_difference(a: &PoseRecord, b: &PoseRecord) -> (f64, f64) {
    (
        ((a.x - b.x).powi(2) + (a.y - b.y).powi(2) + (a.z - b.z).powi(2)).sqrt(),
        wrap_angle(yaw(a) - yaw(b)).abs(),
    )
}

fn by_pair(rs: &[ClosureRecord]) -> BTreeMap<(u64, u64), &ClosureRecord> {
    rs.iter().map(|r| ((r.query_id, r.match_id), r)).collect()
}

/// Both subscribers got exactly the same closures, and they are the offline runner's (same pairs, poses
/// within 1 mm / 1e-4 rad, same inliers).
fn assert_same_as_offline(r: &Replay, offline: &[ClosureRecord]) {
    assert_eq!(
        r.rclpy.len(),
        r.cyclone.len(),
        "rclpy and cyclone got different numbers"
    );
    for (a, b) in r.rclpy.iter().zip(&r.cyclone) {
        assert_eq!(a, b, "rclpy and cyclone subscribers differ");
    }
    let got = by_pair(&r.rclpy);
    let want = by_pair(offline);
    let missing: Vec<_> = want.keys().filter(|k| !got.contains_key(k)).collect();
    let extra: Vec<_> = got.keys().filter(|k| !want.contains_key(k)).collect();
    assert!(
        missing.is_empty() && extra.is_empty(),
        "node vs dc_loc run: missing {missing:?}, extra {extra:?}"
    );
    for (k, g) in &got {
        let w = want[k];
        let (dt, dr) = pose_difference(&g.relative_pose, &w.relative_pose);
        assert!(
            dt < 1e-3 && dr < 1e-4 && g.inliers == w.inliers,
            "closure {k:?}: node {g:?} vs offline {w:?}"
        );
    }
}

#[test]
fn replayed_drive_gives_the_offline_closures_within_the_ground_truth() {
    let _serial = serial();
    let d = drive();
    let r = replay("clean", &[], &["--params-file", d.params.to_str().unwrap()]);
    assert_eq!(r.node_exit, 0, "SIGINT must end the node cleanly");
    assert_same_as_offline(&r, &d.offline);

    // Against the ground truth: every closure, and the revisit opportunities closed.
    let mut worst = (0.0f64, 0.0f64);
    let mut off_truth = Vec::new();
    let mut errors = Vec::new();
    for c in &r.rclpy {
        let q = d
            .drive
            .state_at(Stamp::from_secs_f64(c.query_stamp))
            .t_map_body;
        let m = d
            .drive
            .state_at(Stamp::from_secs_f64(c.match_stamp))
            .t_map_body;
        let truth = m.inverse() * q;
        let rel = &c.relative_pose;
        let dt = (truth.translation.vector - nalgebra::Vector2::new(rel.x, rel.y)).norm();
        let dr = wrap_angle(truth.rotation.angle() - yaw(rel)).abs();
        worst = (worst.0.max(dt), worst.1.max(dr));
        if dt > 1.0 || dr > 0.02 {
            off_truth.push(format!(
                "{} -> {}: {dt:.3} m / {dr:.4} rad",
                c.query_id, c.match_id
            ));
        }
        errors.push(dt);
    }
    errors.sort_by(f64::total_cmp);
    let closed_queries: std::collections::BTreeSet<u64> =
        r.rclpy.iter().map(|c| c.query_id).collect();
    let closed = d
        .opportunities
        .keys()
        .filter(|q| closed_queries.contains(q))
        .count();
    let recall = closed as f64 / d.opportunities.len().max(1) as f64;
    println!(
        "node: {} closures in {:.1} s of replay, median error {:.3} m, worst {:.3} m / {:.4} rad, {closed}/{} revisit opportunities closed ({:.1} %), latency p50 {} ms p99 {} ms",
        r.rclpy.len(),
        r.replay_seconds,
        errors[errors.len() / 2],
        worst.0,
        worst.1,
        d.opportunities.len(),
        recall * 100.0,
        r.diagnostics
            .get("latency_ms.p50")
            .map_or("-", String::as_str),
        r.diagnostics
            .get("latency_ms.p99")
            .map_or("-", String::as_str),
    );
    assert!(
        d.opportunities.len() >= 50,
        "too few opportunities: {}",
        d.opportunities.len()
    );
    assert!(recall >= 0.9, "recall {recall:.3} < 0.9");
    // The 1.0 m / 0.02 rad bound on every closure is the core's (the node's closures are `dc_loc run`'s,
    // asserted above): see `every_closure_within_1m_and_0_02rad_of_the_ground_truth`.
    println!("beyond 1.0 m / 0.02 rad: {off_truth:?}");
    assert!(errors[errors.len() / 2] < 0.5, "median error");
    // The markers show every keyframe and closure; submaps came with the x y z v_r fields.
    let o = &r.outputs;
    assert_eq!(
        o["markers"]["keyframes"].as_u64(),
        Some(r.diag("keyframes")),
        "{o}"
    );
    assert_eq!(
        o["markers"]["loop_closures"].as_u64(),
        Some(2 * r.rclpy.len() as u64),
        "{o}"
    );
    assert!(o["submaps"].as_u64().unwrap_or(0) >= 100, "{o}");
    assert!(o["submap_points"].as_u64().unwrap_or(0) >= 50, "{o}");
    assert_eq!(
        o["submap_fields"],
        serde_json::json!(["x", "y", "z", "v_r"])
    );
    // Nothing lost on the way.
    assert_eq!(r.diag("queue_full") + r.diag("reception_queue_full"), 0);
    assert_eq!(
        r.diag("front.received") as usize,
        d.drive.scans.len(),
        "radar clouds received"
    );
    assert_eq!(r.diag("odometry.received") as usize, d.drive.odometry.len());
}

#[test]
fn five_radars_give_the_offline_closures() {
    let _serial = serial();
    let d = five_radar_drive();
    let r = replay_on(
        d,
        "five_radars",
        // 9515 messages: at 3x real time (the last --rate wins).
        &["--rate", "3"],
        &["--params-file", d.params.to_str().unwrap()],
    );
    assert_eq!(r.node_exit, 0);
    assert_same_as_offline(&r, &d.offline);
    assert!(r.rclpy.len() >= 50, "{} closures", r.rclpy.len());
    let received: u64 = [
        "front",
        "front_left",
        "front_right",
        "back_left",
        "back_right",
    ]
    .iter()
    .map(|n| r.diag(&format!("{n}.received")))
    .sum();
    assert_eq!(
        received as usize,
        d.drive.scans.len(),
        "{:?}",
        r.diagnostics
    );
    println!("five radars: {} closures, as dc_loc run", r.rclpy.len());
}

/// `dc_loc run` of drive `d` with `odometry.source` set to `source`: its closures and its radar
/// odometry (`--odometry-out`: stamp in ns, position).
fn offline_radar_odometry(
    d: &Drive,
    name: &str,
    source: &str,
) -> (Vec<ClosureRecord>, Vec<(i64, [f64; 3])>) {
    let root = scratch(name);
    let (closures, odometry) = (root.join("closures.jsonl"), root.join("odometry.tum"));
    let out = dc_loc(&[
        "run",
        "--bag",
        d.dir.to_str().unwrap(),
        "--params",
        d.params.to_str().unwrap(),
        "-p",
        &format!("odometry.source:={source}"),
        "--out",
        closures.to_str().unwrap(),
        "--odometry-out",
        odometry.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let tum = std::fs::read_to_string(&odometry).unwrap();
    let poses = tum
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            let (sec, frac) = f[0].split_once('.').unwrap();
            assert_eq!(frac.len(), 9, "{l}");
            let ns = sec.parse::<i64>().unwrap() * 1_000_000_000 + frac.parse::<i64>().unwrap();
            (ns, [1, 2, 3].map(|i| f[i].parse::<f64>().unwrap()))
        })
        .collect();
    let closures = read_records(&std::fs::read_to_string(&closures).unwrap());
    (closures, poses)
}

/// The node's `~/odometry` is `dc_loc run --odometry-out` of the same setting: the same samples in
/// stamp order (same stamps to the nanosecond), each position within 1 mm; frames and covariance
/// layout as ROS users read them. Returns the largest position difference, m.
fn assert_odometry_as_offline(r: &Replay, offline: &[(i64, [f64; 3])]) -> f64 {
    assert!(!offline.is_empty(), "dc_loc run wrote no radar odometry");
    let mut live = Vec::new();
    for m in &r.odometry {
        let ns = m["sec"].as_i64().unwrap() * 1_000_000_000 + m["nanosec"].as_i64().unwrap();
        assert_eq!(m["frame_id"], "odom", "{m}");
        assert_eq!(m["child_frame_id"], "base_link", "{m}");
        let cov: Vec<f64> = serde_json::from_value(m["covariance"].clone()).unwrap();
        // x, y and yaw variances observed (zero at the start, which defines the frame); z, roll and
        // pitch marked unobserved.
        assert!(cov[0] >= 0.0 && cov[7] >= 0.0 && cov[35] >= 0.0, "{m}");
        assert!(cov[14] >= 1e6 && cov[21] >= 1e6 && cov[28] >= 1e6, "{m}");
        live.push((ns, ["x", "y", "z"].map(|k| m[k].as_f64().unwrap())));
    }
    let last = &r.odometry.last().unwrap()["covariance"];
    assert!(last[0].as_f64() > Some(0.0), "the covariance grows: {last}");
    live.sort_by_key(|(ns, _)| *ns);
    let stamps = |v: &[(i64, [f64; 3])]| v.iter().map(|(ns, _)| *ns).collect::<Vec<_>>();
    let (got, want) = (stamps(&live), stamps(offline));
    if got != want {
        let first = got.iter().zip(&want).position(|(a, b)| a != b);
        panic!(
            "~/odometry: {} samples, dc_loc run --odometry-out: {}; first different stamp at index \
             {first:?}",
            got.len(),
            want.len()
        );
    }
    let mut worst = 0.0f64;
    for ((ns, p), (_, q)) in live.iter().zip(offline) {
        let d = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
        assert!(d < 1e-3, "~/odometry at {ns} ns: {p:?}, offline {q:?}");
        worst = worst.max(d);
    }
    worst
}

/// No odometry subscription and nothing about odometry missing: the node reads only the radars (and
/// the gyro).
fn assert_no_odometry_topic(r: &Replay) {
    assert_eq!(
        r.outputs["odom_subscribers"].as_u64(),
        Some(0),
        "{}",
        r.outputs
    );
    for k in ["odometry.received", "odometry.publishers", "no_odometry"] {
        assert!(
            !r.diagnostics.contains_key(k) || r.diag(k) == 0,
            "{k}: {:?}",
            r.diagnostics
        );
    }
}

/// Five radars, odometry from their Doppler alone (`odometry.source: radar`) and no `/odom`
/// published: the closures and `~/odometry` are `dc_loc run`'s with the same setting; with
/// `node.odometry_tf`, `/tf` carries each sample as `odom -> base_link`.
#[test]
fn five_radars_without_wheel_odometry_give_the_offline_closures_and_odometry() {
    let _serial = serial();
    let d = five_radar_drive();
    let (closures, odometry) = offline_radar_odometry(d, "five_radars_radar_offline", "radar");
    let r = replay_on(
        d,
        "five_radars_radar",
        &[
            "--rate",
            "3",
            "--no-odom",
            "--record-odometry",
            "--record-tf",
        ],
        &[
            "--params-file",
            d.params.to_str().unwrap(),
            "-p",
            "odometry.source:=radar",
            "-p",
            "node.odometry_tf:=true",
        ],
    );
    assert_eq!(r.node_exit, 0);
    assert_same_as_offline(&r, &closures);
    assert!(!closures.is_empty(), "no closures with the radar odometry");
    assert_no_odometry_topic(&r);
    let worst = assert_odometry_as_offline(&r, &odometry);
    // /tf: one transform per sample, the same poses.
    assert_eq!(r.tf.len(), r.odometry.len());
    for (t, o) in r.tf.iter().zip(&r.odometry) {
        assert_eq!(
            (&t["frame_id"], &t["child_frame_id"]),
            (&o["frame_id"], &o["child_frame_id"])
        );
        for k in ["sec", "nanosec", "x", "y", "z"] {
            assert_eq!(t[k], o[k], "{t} vs {o}");
        }
    }
    println!(
        "five radars, radar odometry: {} closures and {} odometry samples as dc_loc run (positions \
         within {worst:.2e} m)",
        r.rclpy.len(),
        r.odometry.len()
    );
}

/// One radar and a 100 Hz gyro (`odometry.source: radar_imu`), `/imu` published from the bag and no
/// `/odom`: the closures and `~/odometry` are `dc_loc run`'s with the same setting.
#[test]
fn one_radar_and_a_gyro_give_the_offline_closures_and_odometry() {
    let _serial = serial();
    let d = gyro_drive();
    let (closures, odometry) = offline_radar_odometry(d, "gyro_radar_imu_offline", "radar_imu");
    let r = replay_on(
        d,
        "gyro_radar_imu",
        &["--rate", "3", "--no-odom", "--imu", "--record-odometry"],
        &[
            "--params-file",
            d.params.to_str().unwrap(),
            "-p",
            "odometry.source:=radar_imu",
        ],
    );
    assert_eq!(r.node_exit, 0);
    assert_same_as_offline(&r, &closures);
    assert!(
        !closures.is_empty(),
        "no closures with the radar and gyro odometry"
    );
    assert_no_odometry_topic(&r);
    let imu = d.drive.imu.len() as u64;
    assert_eq!(r.diag("imu.received"), imu, "{:?}", r.diagnostics);
    assert_eq!(r.diag("bad_imu"), 0);
    // The estimator's counters: nearly every scan fitted, the gyro's samples taken.
    let steps = r.diag("radar_odometry.steps");
    assert!(steps > 100, "{:?}", r.diagnostics);
    assert!(
        r.diag("radar_odometry.scans_fitted") * 50 >= steps * 49,
        "{:?}",
        r.diagnostics
    );
    assert!(
        r.diag("gyro.samples") * 10 >= imu * 9,
        "{:?}",
        r.diagnostics
    );
    let worst = assert_odometry_as_offline(&r, &odometry);
    println!(
        "one radar and a gyro: {} closures and {} odometry samples as dc_loc run (positions within \
         {worst:.2e} m)",
        r.rclpy.len(),
        r.odometry.len()
    );
}

#[test]
fn malformed_inputs_are_counted_and_change_no_closure() {
    let _serial = serial();
    let d = drive();
    let r = replay(
        "malformed",
        &["--malformed"],
        &[
            "--params-file",
            d.params.to_str().unwrap(),
            "-p",
            "node.max_cloud_points:=5000",
        ],
    );
    assert_eq!(r.node_exit, 0);
    // Same closures as without the bad messages.
    assert_same_as_offline(&r, &d.offline);
    // Every kind was sent three times and is counted under its reason.
    let sent = &r.sent_malformed;
    println!("sent {sent:?}\ndiagnostics {:?}", r.diagnostics);
    assert_eq!(sent.get("bad_cloud"), Some(&12), "four kinds x 3");
    for (key, n) in sent {
        if key == "empty_clouds" {
            // The drive has clouds without a valid point of its own (counted, fed on as by dc_loc run),
            // so the count is at least what was sent.
            assert!(
                r.diag(key) >= *n,
                "diagnostics `{key}`: {} for {n} sent",
                r.diag(key)
            );
            continue;
        }
        assert_eq!(
            r.diag(key),
            *n,
            "diagnostics `{key}`: {} for {n} sent",
            r.diag(key)
        );
    }
    // The empty and NaN clouds carried the stamp of the good cloud before them: dropped as duplicates.
    assert_eq!(r.diag("duplicate_stamp"), sent["empty_clouds"]);
    assert!(r.diag("nan_points") > 0);
}

#[test]
fn a_live_gate_change_applies_from_the_next_keyframe() {
    let _serial = serial();
    let d = drive();
    // At 60 % of the drive the revisit search is switched off with `ros2 param set`.
    let r = replay(
        "live",
        &["--set-at", "0.6", "loop.enabled:=false"],
        &["--params-file", d.params.to_str().unwrap()],
    );
    assert_eq!(r.node_exit, 0);
    let (t_set, answer) = r.set_at.clone().expect("the parameter was set");
    assert_eq!(answer, "ok");
    // Before the change the closures are the offline run's; after it (beyond the keyframes then in
    // flight) there are none.
    let before: Vec<&ClosureRecord> = d
        .offline
        .iter()
        .filter(|c| c.query_stamp < t_set - 2.0)
        .collect();
    let after_offline = d
        .offline
        .iter()
        .filter(|c| c.query_stamp > t_set + 2.0)
        .count();
    assert!(
        before.len() >= 10 && after_offline >= 20,
        "{} / {after_offline}",
        before.len()
    );
    let got = by_pair(&r.rclpy);
    for c in &before {
        assert!(
            got.contains_key(&(c.query_id, c.match_id)),
            "closure {} -> {} missing",
            c.query_id,
            c.match_id
        );
    }
    let late: Vec<_> = r
        .rclpy
        .iter()
        .filter(|c| c.query_stamp > t_set + 2.0)
        .collect();
    assert!(
        late.is_empty(),
        "{} closures after loop.enabled:=false",
        late.len()
    );
}

fn run_node(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dc_loc"))
        .args(args)
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .env("ROS_DOMAIN_ID", "0")
        .output()
        .expect("cannot start dc_loc")
}

#[test]
fn bad_parameters_stop_the_start_naming_them() {
    let _serial = serial();
    let d = drive();
    let params = d.params.to_str().unwrap();
    for (args, name) in [
        (
            vec![
                "--ros-args",
                "--params-file",
                params,
                "-p",
                "submap.size:=ten",
            ],
            "submap.size",
        ),
        (
            vec!["--ros-args", "-p", "radars.front.beta:=-1.0"],
            "radars.front.beta",
        ),
        (
            vec!["--ros-args", "-p", "loop.serch_radius:=3.0"],
            "loop.serch_radius",
        ),
        (
            vec!["--ros-args", "-p", "node.queue_size:=0"],
            "node.queue_size",
        ),
        (
            vec!["--ros-args", "--params-file", "/nonexistent.yaml"],
            "/nonexistent.yaml",
        ),
        (vec!["--bogus"], "--bogus"),
    ] {
        let out = run_node(&args);
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains(name),
            "{args:?}: message does not name {name}: {err}"
        );
    }
    // The shell launcher passes its options and the arguments after `--` on.
    let launcher = venv::repo_root().join("launch_scripts/dc_loc.sh");
    for (args, name) in [
        (vec!["-p", "/nonexistent.yaml"], "/nonexistent.yaml"),
        (
            vec!["-p", params, "--", "-p", "submap.size:=ten"],
            "submap.size",
        ),
    ] {
        let out = Command::new("bash")
            .arg(&launcher)
            .args(&args)
            .env("DC_LOC", env!("CARGO_BIN_EXE_dc_loc"))
            .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
            .output()
            .unwrap();
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "dc_loc.sh {args:?}: {err}");
        assert!(err.contains(name), "dc_loc.sh {args:?}: {err}");
    }
    let out = Command::new(env!("CARGO_BIN_EXE_dc_loc"))
        .args(["--ros-args"])
        .env("ROS_DOMAIN_ID", "999")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("ROS_DOMAIN_ID"));
}

/// A params file whose only section names the node in the root namespace, given to the node started
/// in `/robot1`, is warned about naming the file's sections and the node's name (the start is then
/// refused by a bad override, so that no DDS is needed).
#[test]
fn a_params_file_for_another_namespace_is_named() {
    let dir = scratch("namespace");
    std::fs::create_dir_all(&dir).unwrap();
    let params = dir.join("robot.yaml");
    std::fs::write(
        &params,
        "dc_loc:\n  ros__parameters:\n    body_frame: base_link\n",
    )
    .unwrap();
    let out = run_node(&[
        "--ros-args",
        "-r",
        "__ns:=/robot1",
        "--params-file",
        params.to_str().unwrap(),
        "-p",
        "node.queue_size:=0",
    ]);
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    let warning = "no section applies to node `/robot1/dc_loc` (sections: `dc_loc`)";
    assert_eq!(err.matches(warning).count(), 1, "{err}");
}

#[test]
fn parameters_remapping_and_namespace_as_ros2_users_see_them() {
    let _serial = serial();
    let d = drive();
    let output = venv::python_script("test_node_params.py")
        .args([
            "--node",
            env!("CARGO_BIN_EXE_dc_loc"),
            "--params",
            d.params.to_str().unwrap(),
        ])
        .output()
        .expect("cannot start the venv's python");
    let stdout = text(&output.stdout);
    print!("{stdout}");
    let stderr = text(&output.stderr);
    for l in stderr.lines().filter(|l| !l.contains("rustdds")).take(80) {
        eprintln!("{l}");
    }
    assert!(output.status.success(), "test_node_params.py failed");
    assert!(stdout.contains("params: all checks passed"), "{stdout}");
}

#[test]
fn map_survives_sigkill_and_the_second_half_closes_on_the_first() {
    let _serial = serial();
    let d = drive();
    let map = scratch("map").join("keyframes.map");
    let map_arg = format!("map.file:={}", map.display());
    let common = [
        "--params-file",
        d.params.to_str().unwrap(),
        "-p",
        map_arg.as_str(),
        "-p",
        "map.save_interval:=0.5",
    ];
    // First lap (and a bit), then SIGKILL: no clean shutdown, the periodic saves must have the map.
    let first = replay("map_first", &["--stop-after", "0.55", "--kill"], &common);
    assert_ne!(first.node_exit, 0, "killed");
    assert!(map.exists(), "no map file after the kill");
    let first_keyframes = first.diag("keyframes");
    assert!(
        first_keyframes >= 80,
        "{first_keyframes} keyframes in the first part"
    );
    // The rest of the drive into a new node that loads the map; ~/save_map called before the stop.
    let second = replay(
        "map_second",
        &["--skip-before", "0.55", "--save-map"],
        &common,
    );
    assert_eq!(second.node_exit, 0);
    let saved = &second.outputs["save_map"];
    assert_eq!(saved["success"], true, "{saved}");
    let on_request = dc_loc::keyframe_db::KeyframeDb::load(&map, Default::default(), 4).unwrap();
    assert_eq!(
        on_request.len() as u64,
        second.diag("map_keyframes"),
        "{saved}"
    );
    let loaded = second.diag("map_keyframes") - second.diag("keyframes");
    assert!(
        loaded + 2 >= first_keyframes && loaded <= first_keyframes,
        "{loaded} keyframes loaded, {first_keyframes} made before the kill (saved every 0.5 s)"
    );
    // Closures of the second half: matches in the first session, right by the ground truth.
    let earlier: Vec<&ClosureRecord> = second
        .rclpy
        .iter()
        .filter(|c| c.match_id < loaded)
        .collect();
    println!(
        "map: {loaded} keyframes loaded, {} closures after restart, {} onto the first session",
        second.rclpy.len(),
        earlier.len()
    );
    assert!(
        earlier.len() >= 20,
        "{} closures onto the loaded map",
        earlier.len()
    );
    // Each closure onto the loaded map gave the pose in it: the match keyframe's pose in the map
    // times the true motion from the match to the query keyframe, up to the closure's error.
    let relocalized = second.outputs["relocalized"].as_array().unwrap();
    assert_eq!(
        relocalized.len(),
        earlier.len(),
        "one ~/relocalized per closure onto the map"
    );
    for (p, c) in relocalized.iter().zip(&earlier) {
        let at = |t: f64| d.drive.state_at(Stamp::from_secs_f64(t)).t_map_body;
        let truth = at(c.match_stamp).inverse() * at(c.query_stamp);
        let m = &c.match_odom_pose;
        let (sin, cos) = yaw(m).sin_cos();
        let v = truth.translation.vector;
        let expected = (m.x + cos * v.x - sin * v.y, m.y + sin * v.x + cos * v.y);
        let dx = p["x"].as_f64().unwrap() - expected.0;
        let dy = p["y"].as_f64().unwrap() - expected.1;
        assert!(dx.hypot(dy) < 1.0, "relocalized {p} vs {expected:?}");
        assert_eq!(p["frame_id"], "map");
        assert!(p["cov_xx"].as_f64().unwrap() > 0.0 && p["cov_yy"].as_f64().unwrap() > 0.0);
    }
    for c in &earlier {
        let q = d
            .drive
            .state_at(Stamp::from_secs_f64(c.query_stamp))
            .t_map_body;
        let m = d
            .drive
            .state_at(Stamp::from_secs_f64(c.match_stamp))
            .t_map_body;
        let truth = m.inverse() * q;
        let rel = &c.relative_pose;
        let dt = (truth.translation.vector - nalgebra::Vector2::new(rel.x, rel.y)).norm();
        let dr = wrap_angle(truth.rotation.angle() - yaw(rel)).abs();
        assert!(
            dt <= 1.0 && dr <= 0.02,
            "closure {} -> {}: {dt:.3} m / {dr:.4} rad from the ground truth",
            c.query_id,
            c.match_id
        );
    }
    // A damaged map is refused unless an empty start is allowed.
    let bytes = std::fs::read(&map).unwrap();
    std::fs::write(&map, &bytes[..bytes.len() / 2]).unwrap();
    let out = run_node(&["--ros-args", "-p", &map_arg]);
    assert_eq!(out.status.code(), Some(2));
    let err = text(&out.stderr);
    assert!(err.contains("map.file") && err.contains("corrupt"), "{err}");
    // ... and with map.start_empty_on_error the node starts empty, leaves it alone, saves to `.new`
    // (stopped with SIGTERM).
    let out = venv::python_script("test_node_map_fallback.py")
        .args(["--node", env!("CARGO_BIN_EXE_dc_loc"), "--map"])
        .arg(&map)
        .output()
        .unwrap();
    let stdout = text(&out.stdout);
    print!("{stdout}");
    assert!(
        out.status.success() && stdout.contains("fallback: all checks passed"),
        "{}",
        text(&out.stderr)
    );
    assert!(Path::new(&format!("{}.new", map.display())).exists());
}

/// The issue's bound on every closure, on `dc_loc run`'s closures (the node's are the same, see
/// `replayed_drive_gives_the_offline_closures_within_the_ground_truth`).
#[test]
fn every_closure_within_1m_and_0_02rad_of_the_ground_truth() {
    let d = drive();
    let mut off = Vec::new();
    for c in &d.offline {
        let q = d
            .drive
            .state_at(Stamp::from_secs_f64(c.query_stamp))
            .t_map_body;
        let m = d
            .drive
            .state_at(Stamp::from_secs_f64(c.match_stamp))
            .t_map_body;
        let truth = m.inverse() * q;
        let rel = &c.relative_pose;
        let dt = (truth.translation.vector - nalgebra::Vector2::new(rel.x, rel.y)).norm();
        let dr = wrap_angle(truth.rotation.angle() - yaw(rel)).abs();
        if dt > 1.0 || dr > 0.02 {
            off.push(format!(
                "{} -> {}: {dt:.3} m / {dr:.4} rad",
                c.query_id, c.match_id
            ));
        }
    }
    assert!(off.is_empty(), "{off:?}");
}

#[test]
fn extrinsics_from_tf_static_give_the_offline_closures() {
    let _serial = serial();
    let d = drive();
    // The extrinsic parameter is zeroed: only /tf_static (the bag's, published transient local before
    // the node starts) gives the right one.
    let r = replay(
        "tf_static",
        &["--tf-static"],
        &[
            "--params-file",
            d.params.to_str().unwrap(),
            "-p",
            "node.extrinsics_from_tf:=true",
            "-p",
            "radars.front.extrinsic:=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]",
        ],
    );
    assert_eq!(r.node_exit, 0);
    assert_same_as_offline(&r, &d.offline);
}

#[test]
fn without_tf_static_the_node_stops_naming_the_missing_frame() {
    let _serial = serial();
    let d = drive();
    let out = Command::new(env!("CARGO_BIN_EXE_dc_loc"))
        .args([
            "--ros-args",
            "--params-file",
            d.params.to_str().unwrap(),
            "-p",
            "node.extrinsics_from_tf:=true",
            "-p",
            "node.tf_timeout:=1.0",
        ])
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .env("ROS_DOMAIN_ID", "229")
        .output()
        .expect("cannot start dc_loc");
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("no /tf_static transform from `base_link` to `radar_front` within 1.0 s"),
        "{stderr}"
    );
    assert!(!text(&out.stdout).contains("running"), "never half-alive");
}

#[test]
fn radar_scan_input_gives_the_closures_of_the_same_detections_in_pointcloud2() {
    let _serial = serial();
    let d = drive();
    // Each cloud goes out as the radar_msgs/RadarScan of its detections (float32 range, azimuth,
    // elevation: the positions come back within a few micrometres).
    let r = replay(
        "radar_scan",
        &["--radar-scan"],
        &[
            "--params-file",
            d.params.to_str().unwrap(),
            "-p",
            "radars.front.message:=radar_scan",
        ],
    );
    assert_eq!(r.node_exit, 0);
    assert_eq!(
        r.diag("front.received") as usize,
        d.drive.scans.len(),
        "every scan received"
    );
    let got = by_pair(&r.rclpy);
    let want = by_pair(&d.offline);
    let common: Vec<_> = want.keys().filter(|k| got.contains_key(k)).collect();
    assert!(
        common.len() * 100 >= want.len() * 98 && got.len() * 100 <= want.len() * 102,
        "{} closures, {} of dc_loc run's {} pairs",
        got.len(),
        common.len(),
        want.len()
    );
    for k in common {
        let (dt, dr) = pose_difference(&got[k].relative_pose, &want[k].relative_pose);
        assert!(dt < 0.01 && dr < 1e-3, "closure {k:?}: {dt} m, {dr} rad");
    }
}
