//! The node as pose-graph back ends see it: a simulated drive whose odometry drifts by 3 % of the distance
//! (speed scale error 0.01, yaw-rate bias 0.34 deg/s) replayed into the `dc_loc` binary with its back-end
//! outputs on (tests/python/test_backend_replay.py), while examples/backend_gtsam.py runs beside it as a
//! real rclpy + GTSAM back end.
//!
//! Checked against the simulator's ground truth:
//! - the `pose_graph_tools_msgs/PoseGraph` and LIO-SAM messages received by rclpy carry each closure
//!   unchanged (edge from the match to the query, the relative pose and covariance of the closure; the
//!   two stamps, query first);
//! - the back end's optimised keyframes have an absolute trajectory error (after the best rigid
//!   alignment) at most a third of the odometry's, and within 10 % of the same graph whose closures carry
//!   the true relative poses of their pairs (tests/python/test_backend_graph.py builds those variants
//!   offline with the back end's own code), so a closure error or a covariance in the wrong frame shows.

#[path = "python/venv.rs"]
mod venv;

mod common;
use common::{SHORT_DRIVE, text};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use dc_loc::math::{Iso2, Stamp, Vec2};
use dc_loc::output::{ClosureRecord, PoseRecord};
use dc_loc::sim::{SimConfig, SimDrive, simulate};

/// [`SHORT_DRIVE`] with odometry that drifts by about 3 % of the distance driven: a speed scale error
/// of 1 % and a yaw-rate bias (the part loop closures can correct: a scale error alone leaves a closed
/// loop closed, and no closure can see it).
fn drifting_drive() -> String {
    let drive = SHORT_DRIVE.replace(
        "odometry:\n  rate: 25.0\n",
        "odometry:\n  rate: 25.0\n  scale_error: 0.01\n  yaw_rate_bias: 0.006\n",
    );
    assert_ne!(drive, SHORT_DRIVE, "SHORT_DRIVE has no odometry section");
    drive
}

/// The odometry's position error at the end of the drive over the distance driven (both poses taken
/// relative to the first sample).
fn end_drift(drive: &SimDrive) -> f64 {
    let (o0, o1) = (&drive.odometry[0], drive.odometry.last().unwrap());
    let t0 = truth_at(drive, o0.stamp.as_secs_f64());
    let t1 = drive.state_at(o1.stamp);
    let odom = o0.t_odom_body.inverse() * o1.t_odom_body;
    let truth = t0.inverse() * t1.t_map_body;
    (odom.translation.vector - truth.translation.vector).norm() / t1.distance
}

fn dc_loc(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_dc_loc"))
        .args(args)
        .output()
        .expect("cannot start dc_loc");
    assert!(out.status.success(), "{}", text(&out.stderr));
}

/// Runs a venv script, echoing its output; panics when it fails.
fn script(name: &str, args: &[&str]) {
    let out = venv::python_script(name)
        .args(args)
        .output()
        .expect("cannot start the venv's python");
    print!("{}", text(&out.stdout));
    let stderr = text(&out.stderr);
    let interesting: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("WARN  dc_loc") || l.contains("ERROR") || l.contains("Error"))
        .take(40)
        .collect();
    for l in interesting {
        eprintln!("{l}");
    }
    if !out.status.success() {
        for l in stderr
            .lines()
            .rev()
            .take(30)
            .collect::<Vec<_>>()
            .iter()
            .rev()
        {
            eprintln!("{l}");
        }
    }
    assert!(out.status.success(), "{name} failed ({})", out.status);
}

fn yaw(p: &PoseRecord) -> f64 {
    2.0 * p.qz.atan2(p.qw)
}

fn iso2(p: &PoseRecord) -> Iso2 {
    Iso2::new(Vec2::new(p.x, p.y), yaw(p))
}

fn truth_at(drive: &SimDrive, stamp: f64) -> Iso2 {
    drive.state_at(Stamp::from_secs_f64(stamp)).t_map_body
}

/// Root-mean-square position error of `est` against `truth` (pairs of points) after the rigid 2D
/// motion that fits them best (least squares).
fn ate(pairs: &[(Vec2, Vec2)]) -> f64 {
    let n = pairs.len() as f64;
    let (ce, ct) = pairs
        .iter()
        .fold((Vec2::zeros(), Vec2::zeros()), |(a, b), (e, t)| {
            (a + e, b + t)
        });
    let (ce, ct) = (ce / n, ct / n);
    let (mut s, mut c) = (0.0, 0.0);
    for (e, t) in pairs {
        let (e, t) = (e - ce, t - ct);
        s += e.x * t.y - e.y * t.x;
        c += e.x * t.x + e.y * t.y;
    }
    let r = nalgebra::Rotation2::new(s.atan2(c));
    let sum: f64 = pairs
        .iter()
        .map(|(e, t)| ((r * (e - ce)) - (t - ct)).norm_squared())
        .sum();
    (sum / n).sqrt()
}

/// A trajectory: keyframe id -> (stamp, x, y).
type Trajectory = BTreeMap<u64, (f64, Vec2)>;

fn ate_of(traj: &Trajectory, drive: &SimDrive) -> f64 {
    let pairs: Vec<(Vec2, Vec2)> = traj
        .values()
        .map(|(t, p)| (*p, truth_at(drive, *t).translation.vector))
        .collect();
    ate(&pairs)
}

/// The back end's CSV (key, stamp, x, y, yaw).
fn read_csv(path: &Path) -> Trajectory {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            (v[0] as u64, (v[1], Vec2::new(v[2], v[3])))
        })
        .collect()
}

/// Rows `[[key, stamp, x, y, yaw], ...]` of test_backend_graph.py.
fn rows(v: &serde_json::Value) -> Trajectory {
    v.as_array()
        .unwrap()
        .iter()
        .map(|r| {
            let f = |i: usize| r[i].as_f64().unwrap();
            (r[0].as_u64().unwrap(), (f(1), Vec2::new(f(2), f(3))))
        })
        .collect()
}

/// The keyframes the closures name at their odometry poses.
fn odometry(closures: &[ClosureRecord]) -> Trajectory {
    let mut t = Trajectory::new();
    for c in closures {
        let q = iso2(&c.query_odom_pose).translation.vector;
        let m = iso2(&c.match_odom_pose).translation.vector;
        t.insert(c.query_id, (c.query_stamp, q));
        t.insert(c.match_id, (c.match_stamp, m));
    }
    t
}

/// `c` with the true relative pose of its pair (the covariance unchanged).
fn with_true_pose(c: &ClosureRecord, drive: &SimDrive) -> ClosureRecord {
    let t = truth_at(drive, c.match_stamp).inverse() * truth_at(drive, c.query_stamp);
    let a = t.rotation.angle();
    let mut c = c.clone();
    c.relative_pose = PoseRecord {
        x: t.translation.x,
        y: t.translation.y,
        z: 0.0,
        qx: 0.0,
        qy: 0.0,
        qz: (a / 2.0).sin(),
        qw: (a / 2.0).cos(),
    };
    c
}

fn record_values(closures: &[ClosureRecord]) -> serde_json::Value {
    closures
        .iter()
        .map(|c| serde_json::from_str::<serde_json::Value>(&c.to_json_line()).unwrap())
        .collect()
}

fn scratch(name: &str) -> PathBuf {
    common::scratch("backend_tests", name)
}

fn assert_messages_carry_the_closures(r: &serde_json::Value, closures: &[ClosureRecord]) {
    let graphs = r["pose_graphs"].as_array().unwrap();
    let pairs = r["lio_sam"].as_array().unwrap();
    assert_eq!(graphs.len(), closures.len(), "one PoseGraph per closure");
    assert_eq!(pairs.len(), closures.len(), "one LIO-SAM pair per closure");
    for ((c, g), p) in closures.iter().zip(graphs).zip(pairs) {
        let what = format!("closure {} -> {}", c.query_id, c.match_id);
        let edges = g["edges"].as_array().unwrap();
        assert_eq!(edges.len(), 1, "{what}");
        let e = &edges[0];
        assert_eq!(e["type"].as_i64(), Some(1), "{what}: LOOPCLOSE");
        assert_eq!(e["key_from"].as_u64(), Some(c.match_id), "{what}");
        assert_eq!(e["key_to"].as_u64(), Some(c.query_id), "{what}");
        assert_eq!(e["robot_from"].as_i64(), Some(2), "{what}");
        assert_eq!(e["robot_to"].as_i64(), Some(2), "{what}");
        let pos = &e["pose"]["position"];
        let ori = &e["pose"]["orientation"];
        let got = [
            pos["x"].as_f64().unwrap(),
            pos["y"].as_f64().unwrap(),
            ori["z"].as_f64().unwrap(),
            ori["w"].as_f64().unwrap(),
        ];
        let rel = &c.relative_pose;
        assert_eq!(got, [rel.x, rel.y, rel.qz, rel.qw], "{what}: pose");
        let cov: Vec<f64> = e["covariance"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(cov, c.covariance, "{what}: covariance");
        let keys: Vec<u64> = g["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| n["key"].as_u64().unwrap())
            .collect();
        assert_eq!(keys, [c.match_id, c.query_id], "{what}: nodes");
        let stamps: Vec<f64> = p["data"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(stamps.len(), 2, "{what}");
        assert!(
            (stamps[0] - c.query_stamp).abs() < 1e-6 && (stamps[1] - c.match_stamp).abs() < 1e-6,
            "{what}: LIO-SAM stamps {stamps:?}"
        );
    }
}

#[test]
fn gtsam_back_end_on_drifting_odometry_is_as_good_as_with_true_closures() {
    let root = scratch("drift");
    let yaml = drifting_drive();
    let config = root.join("drive.yaml");
    std::fs::write(&config, &yaml).unwrap();
    let bag = root.join("bag");
    dc_loc(&[
        "sim",
        "--config",
        config.to_str().unwrap(),
        "--out",
        bag.to_str().unwrap(),
    ]);
    let drive = simulate(&yaml_serde::from_str::<SimConfig>(&yaml).unwrap()).unwrap();
    let drift = end_drift(&drive);
    println!("odometry drift: {:.1} % of the distance", drift * 100.0);
    assert!((0.02..0.04).contains(&drift), "drift {drift}");

    let result = root.join("result.json");
    let live = root.join("backend.csv");
    let rate = std::env::var("DCLOC_REPLAY_RATE").unwrap_or_else(|_| "5".into());
    script(
        "test_backend_replay.py",
        &[
            "--node",
            env!("CARGO_BIN_EXE_dc_loc"),
            "--bag",
            bag.to_str().unwrap(),
            "--out",
            result.to_str().unwrap(),
            "--backend-out",
            live.to_str().unwrap(),
            "--rate",
            &rate,
            "--",
            "--params-file",
            bag.join("dc_loc.yaml").to_str().unwrap(),
            "-p",
            "node.pose_graph_output:=true",
            "-p",
            "node.lio_sam_output:=true",
            "-p",
            "node.robot_id:=2",
        ],
    );
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&result).unwrap()).unwrap();
    assert_eq!(r["node_exit"].as_i64(), Some(0), "SIGINT ends the node");
    assert_eq!(r["backend_exit"].as_i64(), Some(0), "the back end exits");
    let closures: Vec<ClosureRecord> = r["closures"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| ClosureRecord::from_json_line(&v.to_string()).unwrap())
        .collect();
    assert!(
        closures.len() >= 10,
        "only {} closures on the drive",
        closures.len()
    );
    assert_messages_carry_the_closures(&r, &closures);

    // The same graph offline: as received, with the true relative poses, with the covariance turned.
    let truth: Vec<ClosureRecord> = closures.iter().map(|c| with_true_pose(c, &drive)).collect();
    let variants = serde_json::json!({
        "received": {"closures": record_values(&closures)},
        "true_poses": {"closures": record_values(&truth)},
        "covariance_turned_90": {"closures": record_values(&closures), "rotate_covariance": 90.0},
    });
    let variants_path = root.join("variants.json");
    std::fs::write(&variants_path, variants.to_string()).unwrap();
    let graphs = root.join("graphs.json");
    script(
        "test_backend_graph.py",
        &[
            "--bag",
            bag.to_str().unwrap(),
            "--variants",
            variants_path.to_str().unwrap(),
            "--out",
            graphs.to_str().unwrap(),
        ],
    );
    let g: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&graphs).unwrap()).unwrap();

    let live = read_csv(&live);
    let odom = odometry(&closures);
    assert_eq!(
        live.keys().collect::<Vec<_>>(),
        odom.keys().collect::<Vec<_>>(),
        "the back end's keyframes are the closures'"
    );
    let ate_live = ate_of(&live, &drive);
    let ate_offline = ate_of(&rows(&g["received"]), &drive);
    let ate_true = ate_of(&rows(&g["true_poses"]), &drive);
    let ate_turned = ate_of(&rows(&g["covariance_turned_90"]), &drive);
    let ate_odom = ate_of(&odom, &drive);
    println!(
        "ATE over {} keyframes: odometry {ate_odom:.3} m, live back end {ate_live:.3} m, \
         offline graph {ate_offline:.3} m, true relative poses {ate_true:.3} m, covariance turned \
         90 deg {ate_turned:.3} m",
        live.len()
    );
    assert!(
        (ate_live - ate_offline).abs() < 1e-3,
        "the live back end and its offline graph agree"
    );
    assert!(
        ate_live <= ate_odom / 3.0,
        "ATE {ate_live:.3} m is not a third of the odometry's {ate_odom:.3} m"
    );
    assert!(
        ate_live <= 1.1 * ate_true,
        "ATE {ate_live:.3} m is more than 10 % over the true closures' {ate_true:.3} m"
    );
}
