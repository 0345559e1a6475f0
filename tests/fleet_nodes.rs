//! A fleet of `dc_loc` nodes as real ROS 2 users see it: three robots of one simulated world (`dc_loc sim
//! --fleet 3` on the short block of tests/common with the five radars of the nuScenes car), each replayed
//! into a node of its own (`-r __ns:=/robot_k -p node.robot_id:=k -p node.fleet:=true`) by rclpy
//! publishers (tests/python/test_fleet_nodes.py). Two robots drive at the same time; the third robot's node
//! starts only once they have finished, and takes their keyframes from the transient-local history of
//! `/dc_loc/keyframes`.
//!
//! Robot 1 drives the loop the other way round (`sim::fleet`), robots 0 and 2 the same way. With robots 0
//! and 1 at once and robot 2 late, the same-direction opportunities are robot 2's onto robot 0, found by
//! the late joiner; with robots 0 and 2 at once and robot 1 late, they are found while both drive, each
//! pair registered by whichever node held the other's keyframe first. The opposite-direction closures
//! count for precision.
//!
//! Checked against the simulator's ground truth (the bags' `/ground_truth/odom`, and here once more with
//! the simulator's exact poses): every closure between robots within 2 m, no pair of keyframes published
//! twice by the fleet, at least 90 % of the same-direction opportunities closed (an opportunity: a
//! keyframe with an older keyframe of another robot within 5 m, headings within 90 degrees; closed when it
//! is the newer keyframe of a correct closure between robots), the late joiner closes onto the earlier
//! robots, every closure names keyframes the fleet topic carried, each node publishes each of its
//! keyframes and numbers them 0, 1, 2, ... (the late joiner too, after the others' keyframes came), the alignments the nodes send with their keyframes (at least one) lie within 2 m at the
//! keyframes of the closures that gave them, and every node exits 0 on SIGINT or SIGTERM. The offline evaluation of the same fleet
//! (`eval::fleet::evaluate_fleet`: a pipeline per robot, keyframes through the wire format) is printed
//! beside it.
//! Also, examples/backend_gtsam.py optimises the three robots in one pose graph (`optimise_fleet`): its
//! keyframes must come out in one frame: after one rigid alignment of all robots together, within 2 m
//! (RMS) of the ground truth and at most half the error of the starting values (each robot's odometry
//! placed by its first closure onto a placed robot).
//!
//! A flood, in the first test (nodes started with `-p node.fleet_history:=200 -p node.fleet_rate:=5`):
//! a quarter into the concurrent replay, an rclpy publisher on `/dc_loc/keyframes` poses as robot 99 and
//! sends a handful of malformed keyframes, then as fast as it can 700 well-formed ones (20 random points
//! each). Each running node must count the malformed ones as `bad_keyframe`, add at most
//! `fleet_history + fleet_rate * t + 2` of robot 99's keyframes (t: seconds from the flood's first keyframe
//! until its counts were seen complete or steady), count the rest as over rate (`fleet.robot_99` and
//! `keyframe_over_rate`), and publish no closure onto robot 99; the late joiner (started after the flood's
//! publisher is gone) hears nothing of robot 99; everything above holds for the real robots.
//!
//! DDS stays on loopback in a domain id of the script's own. Replayed at `DCLOC_REPLAY_RATE` (default 5)
//! times real time: about 45 s per test on two cores, one test at a time.

#[path = "python/venv.rs"]
mod venv;

mod common;
use common::{SHORT_DRIVE, text};
use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::process::Command;
use std::sync::{Mutex, MutexGuard, OnceLock};

use dc_loc::math::{Iso2, Stamp, wrap_angle};
use dc_loc::sim::{SimConfig, SimSetup};

const ROBOTS: u32 = 3;

/// The flood's fake robot, and the nodes' `node.fleet_history` and `node.fleet_rate` in that run (each
/// real robot makes about 110 keyframes: well within the history, so the late joiner still gets them all
/// and the rate never bites a real robot).
const FLOOD_ROBOT: i64 = 99;
const FLOOD_HISTORY: u64 = 200;
const FLOOD_RATE: f64 = 5.0;

fn sim_yaml() -> String {
    format!("{SHORT_DRIVE}radar_preset: nuscenes\n")
}

fn replay_rate() -> String {
    std::env::var("DCLOC_REPLAY_RATE").unwrap_or_else(|_| "5".into())
}

/// A closure as the script reports it.
struct Closure {
    topic_robot: i64,
    query: (i64, u64),
    matched: (i64, u64),
    query_stamp: f64,
    match_stamp: f64,
    relative: Iso2,
    translation_error: f64,
    correct: bool,
}

fn closure(v: &serde_json::Value) -> Closure {
    let r = &v["relative_pose"];
    let f = |v: &serde_json::Value| v.as_f64().unwrap();
    Closure {
        topic_robot: v["topic_robot"].as_i64().unwrap(),
        query: (
            v["query_robot"].as_i64().unwrap(),
            v["query_id"].as_u64().unwrap(),
        ),
        matched: (
            v["match_robot"].as_i64().unwrap(),
            v["match_id"].as_u64().unwrap(),
        ),
        query_stamp: f(&v["query_stamp"]),
        match_stamp: f(&v["match_stamp"]),
        relative: Iso2::new(
            nalgebra::Vector2::new(f(&r["x"]), f(&r["y"])),
            2.0 * f(&r["qz"]).atan2(f(&r["qw"])),
        ),
        translation_error: f(&v["translation_error"]),
        correct: v["correct"].as_bool().unwrap(),
    }
}

/// The fleet's bags (`dc_loc sim --fleet`) and each robot's exact ground truth, made once per test
/// binary; the offline evaluation of the same fleet is printed.
struct Fleet {
    dir: PathBuf,
    setups: Vec<SimSetup>,
}

fn fleet() -> &'static Fleet {
    static FLEET: OnceLock<Fleet> = OnceLock::new();
    FLEET.get_or_init(|| {
        let root = common::scratch("fleet_nodes", "fleet");
        let config = root.join("short.yaml");
        std::fs::write(&config, sim_yaml()).unwrap();
        let dir = root.join("fleet");
        let out = Command::new(env!("CARGO_BIN_EXE_dc_loc"))
            .args(["sim", "--config", config.to_str().unwrap(), "--fleet"])
            .arg(ROBOTS.to_string())
            .args(["--out", dir.to_str().unwrap()])
            .output()
            .expect("cannot start dc_loc");
        assert!(out.status.success(), "{}", text(&out.stderr));
        let cfg: SimConfig = yaml_serde::from_str(&sim_yaml()).unwrap();
        let configs = dc_loc::sim::fleet::fleet(&cfg, ROBOTS).unwrap();
        let setups = configs.iter().map(|c| SimSetup::new(c).unwrap()).collect();
        let offline = dc_loc::eval::fleet::evaluate_fleet(&configs, |_| {}).unwrap();
        println!(
            "offline (eval::fleet): same direction {}/{} closed, {} published, {} false; opposite {} published, {} false",
            offline.same.closed,
            offline.same.opportunities,
            offline.same.published,
            offline.same.false_closures,
            offline.reverse.published,
            offline.reverse.false_closures
        );
        Fleet { dir, setups }
    })
}

/// The tests of this file run one at a time (three nodes each, two cores).
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// Robots 0 and 1 drive at the same time, robot 2 joins once they have finished; while 0 and 1 drive, a
/// fake robot floods the fleet topic (module documentation).
#[test]
fn three_nodes_share_keyframes_and_close_loops_between_robots() {
    let _serial = serial();
    check_fleet_run("late_2", "0,1", "2", true);
}

/// Robots 0 and 2 drive the same way round at the same time, so each pair of their keyframes is
/// registered by whichever node held the other's keyframe first (the older keyframe's node, too); robot
/// 1 joins once they have finished.
#[test]
fn robots_driving_the_same_way_at_once_register_each_pair_once() {
    let _serial = serial();
    check_fleet_run("late_1", "0,2", "1", false);
}

/// Runs test_fleet_nodes.py with the robots of `concurrent` at once and then those of `late` (with
/// `flood`, robot 99's flood during the concurrent replay), and checks what it reports (module
/// documentation).
fn check_fleet_run(name: &str, concurrent: &str, late: &str, flood: bool) {
    let f = fleet();
    let (fleet_dir, setups) = (&f.dir, &f.setups);
    let root = common::scratch("fleet_nodes", name);
    let result_path = root.join("result.json");
    let started = std::time::Instant::now();
    let mut script = venv::python_script("test_fleet_nodes.py");
    script
        .args(["--node", env!("CARGO_BIN_EXE_dc_loc")])
        .args(["--fleet", fleet_dir.to_str().unwrap()])
        .args(["--out", result_path.to_str().unwrap()])
        .args(["--rate", &replay_rate()])
        .args(["--concurrent", concurrent, "--late", late, "--backend"]);
    if flood {
        script
            .args(["--fleet-history", &FLOOD_HISTORY.to_string()])
            .args(["--fleet-rate", &FLOOD_RATE.to_string()])
            .args(["--flood", &FLOOD_ROBOT.to_string()]);
    }
    let output = script.output().expect("cannot start the venv's python");
    println!(
        "{name}: test_fleet_nodes.py took {:.1} s",
        started.elapsed().as_secs_f64()
    );
    let stdout = text(&output.stdout);
    let stderr = text(&output.stderr);
    print!("{stdout}");
    // The nodes' logs are long: their warnings and errors, and the tail.
    for l in stderr
        .lines()
        .filter(|l| l.contains("WARN  dc_loc") || l.contains("ERROR") || l.contains("Error"))
        .take(60)
    {
        eprintln!("{l}");
    }
    let tail: Vec<&str> = stderr.lines().rev().take(25).collect();
    for l in tail.iter().rev() {
        eprintln!("{l}");
    }
    assert!(
        output.status.success(),
        "test_fleet_nodes.py failed ({})",
        output.status
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&result_path).unwrap()).unwrap();
    let s = &v["summary"];
    if flood {
        check_flood(s, concurrent, late);
    }

    // Every node ended cleanly on its signal.
    for k in 0..ROBOTS {
        let k = k.to_string();
        assert_eq!(
            s["exits"][&k].as_i64(),
            Some(0),
            "robot {k}'s node after {}: exit {}",
            s["signals"][&k],
            s["exits"][&k]
        );
    }
    // Each node published each of its keyframes on the fleet topic.
    for k in 0..ROBOTS {
        let k = k.to_string();
        assert!(s["diag_keyframes"][&k].as_i64().unwrap() > 50, "{s}");
        assert_eq!(
            s["keyframes"][&k], s["diag_keyframes"][&k],
            "robot {k}: keyframes on /dc_loc/keyframes vs the node's count"
        );
    }

    // The closures, judged once more with the simulator's exact poses.
    let closures: Vec<Closure> = v["closures"]
        .as_array()
        .unwrap()
        .iter()
        .map(closure)
        .collect();
    let truth = |robot: i64, stamp: f64| -> Iso2 {
        setups[robot as usize]
            .state_at(Stamp::from_secs_f64(stamp))
            .t_map_body
    };
    let mut inter = 0;
    for c in &closures {
        let t = truth(c.matched.0, c.match_stamp).inverse() * truth(c.query.0, c.query_stamp);
        let et = (t.translation.vector - c.relative.translation.vector).norm();
        let er = wrap_angle(t.rotation.angle() - c.relative.rotation.angle()).abs();
        assert!(
            (et - c.translation_error).abs() < 0.05,
            "closure {:?} -> {:?}: {et:.3} m from the simulator's poses, {:.3} m from the bags' ground truth",
            c.query,
            c.matched,
            c.translation_error
        );
        assert_eq!(c.correct, et <= 2.0);
        assert_eq!(
            c.topic_robot, c.query.0,
            "query_robot is the publisher's id"
        );
        if c.query.0 != c.matched.0 {
            inter += 1;
            assert!(
                et <= 2.0,
                "false closure between robots {:?} -> {:?}: {et:.2} m, {er:.3} rad",
                c.query,
                c.matched
            );
        }
    }
    let i = &s["inter_robot"];
    assert_eq!(i["published"].as_u64(), Some(inter));
    assert!(inter > 0, "no closure between robots");
    assert_eq!(i["precision"].as_f64(), Some(1.0), "{i}");
    // Each pair of keyframes once across the fleet.
    let mut pairs = BTreeSet::new();
    for c in &closures {
        let pair = (c.query.min(c.matched), c.query.max(c.matched));
        assert!(pairs.insert(pair), "pair {pair:?} published twice");
    }
    assert_eq!(s["duplicates"].as_array().map(Vec::len), Some(0), "{s}");
    // Every alignment a node sent with its keyframes is correct where it was found.
    let a = &s["shared_alignments"];
    assert!(a["count"].as_u64().unwrap() > 0, "no alignment shared: {a}");
    assert_eq!(a["correct"], a["count"], "{a}");
    assert_eq!(a["unmatched"].as_array().map(Vec::len), Some(0), "{a}");
    // Every closure names keyframes the fleet topic carried, with their stamps.
    assert_eq!(
        s["unknown_keyframes"].as_array().map(Vec::len),
        Some(0),
        "{}",
        s["unknown_keyframes"]
    );

    // Recall over the same-direction opportunities, counted again here from the keyframes.
    let keyframes: BTreeMap<(i64, u64), f64> = v["keyframes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| {
            (
                (k[0].as_i64().unwrap(), k[2].as_u64().unwrap()),
                k[3].as_f64().unwrap(),
            )
        })
        .collect();
    // Each robot numbers its own keyframes 0, 1, 2, ... whatever it received from the others first
    // (the late joiner held the other robots' keyframes before it made its first).
    for r in 0..i64::from(ROBOTS) {
        let ids: Vec<u64> = keyframes.keys().filter(|k| k.0 == r).map(|k| k.1).collect();
        let expected: Vec<u64> = (0..ids.len() as u64).collect();
        assert!(!ids.is_empty(), "robot {r} published no keyframe");
        assert_eq!(ids, expected, "robot {r}'s keyframe ids");
    }
    let poses: Vec<(i64, u64, f64, dc_loc::sim::EgoState)> = keyframes
        .iter()
        .map(|(&(r, id), &t)| {
            (
                r,
                id,
                t,
                setups[r as usize].state_at(Stamp::from_secs_f64(t)),
            )
        })
        .collect();
    // Found: the newer keyframe of a correct closure between robots (the pair is registered by the node
    // that held the other's keyframe when it made its own, which may be the older one's).
    let found: BTreeSet<(i64, u64)> = closures
        .iter()
        .filter(|c| c.correct && c.query.0 != c.matched.0)
        .map(|c| {
            if c.query_stamp >= c.match_stamp {
                c.query
            } else {
                c.matched
            }
        })
        .collect();
    let mut opportunities = BTreeMap::new();
    for (r, id, t, q) in &poses {
        let seen = poses.iter().any(|(r2, _, t2, m)| {
            r2 != r
                && t2 < t
                && (q.t_map_body.translation.vector - m.t_map_body.translation.vector).norm() <= 5.0
                && wrap_angle(q.heading - m.heading).abs() <= std::f64::consts::FRAC_PI_2
        });
        if seen {
            opportunities.insert((*r, *id), found.contains(&(*r, *id)));
        }
    }
    let closed = opportunities.values().filter(|f| **f).count();
    let recall = closed as f64 / opportunities.len().max(1) as f64;
    println!(
        "fleet: {closed}/{} same-direction opportunities closed ({:.1} %; the script: {}/{})",
        opportunities.len(),
        100.0 * recall,
        s["found"],
        s["opportunities"]
    );
    let script_opportunities = s["opportunities"].as_u64().unwrap() as i64;
    assert!(
        (script_opportunities - opportunities.len() as i64).abs() <= 2,
        "opportunities: {} here, {script_opportunities} in the script",
        opportunities.len()
    );
    assert!(opportunities.len() >= 50, "too few opportunities");
    assert!(recall >= 0.9, "recall {recall:.3} < 0.9");
    assert!(s["recall"].as_f64().unwrap() >= 0.9, "{s}");

    // The late joiner closed onto the earlier robots' keyframes (from the transient-local history).
    let joiner = &s["late_joiner"];
    assert!(
        joiner["correct"].as_u64().unwrap_or(0) > 0,
        "no closure of robot {late} onto the robots of {concurrent}: {joiner}"
    );

    // One pose graph over the fleet: every robot placed, one frame for all.
    let b = &s["backend"];
    println!("back end over the fleet: {b}");
    assert_eq!(
        b["unplaced"].as_array().map(Vec::len),
        Some(0),
        "robots the back end could not place: {b}"
    );
    let (ate, ate_initial) = (
        b["ate"].as_f64().unwrap(),
        b["ate_initial"].as_f64().unwrap(),
    );
    assert!(
        ate < 2.0 && ate < 0.5 * ate_initial,
        "fleet ATE after one rigid alignment {ate:.2} m, of the odometry placed by the first closures {ate_initial:.2} m: {b}"
    );
}

/// The flood of robot 99 (module documentation): bounded at each node that got it, the excess counted
/// as over rate, the malformed keyframes as `bad_keyframe`, no closure onto it, nothing of it at the late
/// joiner, the real robots untouched by the gate.
fn check_flood(s: &serde_json::Value, concurrent: &str, late: &str) {
    let f = &s["flood"];
    assert_eq!(f["robot"].as_i64(), Some(FLOOD_ROBOT), "{f}");
    let sent = f["sent"].as_u64().unwrap();
    let malformed = f["malformed"].as_u64().unwrap();
    assert_eq!(sent, FLOOD_HISTORY + 500);
    assert!(malformed >= 3, "{f}");
    assert_eq!(f["note"].as_str(), Some(""), "{f}");
    // The real robots stay within the history (the late joiner takes them all) and the burst.
    for k in 0..ROBOTS {
        let n = s["keyframes"][k.to_string()].as_u64().unwrap();
        assert!(
            n <= FLOOD_HISTORY,
            "robot {k} makes {n} keyframes, more than node.fleet_history {FLOOD_HISTORY}"
        );
    }
    let flooded: Vec<&str> = concurrent.split(',').collect();
    for k in &flooded {
        let n = &f["nodes"][*k];
        let get = |key: &str| {
            n[key]
                .as_u64()
                .unwrap_or_else(|| panic!("robot {k}: no {key}: {n}"))
        };
        let (received, added, over_rate) = (get("received"), get("added"), get("over_rate"));
        let elapsed = n["elapsed_s"]
            .as_f64()
            .unwrap_or_else(|| panic!("robot {k}'s node: the flood's counts never steadied: {n}"));
        let bound = FLOOD_HISTORY as f64 + FLOOD_RATE * elapsed + 2.0;
        println!(
            "flood at robot {k}'s node: added {added} of {sent} (bound {bound:.1} after {elapsed:.2} s), over rate {over_rate}, bad_keyframe {}, all delivered {}",
            get("bad_keyframe"),
            n["all_delivered"]
        );
        // Bounded: the burst plus the rate over the time the flood took.
        assert!(
            added as f64 <= bound,
            "robot {k}'s node added {added} of robot {FLOOD_ROBOT}'s keyframes in {elapsed:.2} s: {n}"
        );
        // ... and the burst is honoured (the malformed ones took their tokens too).
        assert!(
            added + malformed >= FLOOD_HISTORY,
            "robot {k}'s node added only {added} of the flood: {n}"
        );
        // Nothing more of it arrived after it was counted.
        assert_eq!(n["added_then"].as_u64(), Some(added), "{n}");
        assert_eq!(n["over_rate_then"].as_u64(), Some(over_rate), "{n}");
        // The excess is counted as over rate, at the robot and among the dropped messages (only robot 99's).
        assert!(
            over_rate > 0,
            "robot {k}'s node: no keyframe over rate: {n}"
        );
        assert_eq!(get("keyframe_over_rate"), over_rate, "{n}");
        // The malformed ones are bad keyframes, each once.
        assert_eq!(get("bad_keyframe"), malformed, "{n}");
        // The well-formed ones it took were added (no duplicates, within the budget).
        assert_eq!((get("duplicates"), get("refused")), (0, 0), "{n}");
        assert_eq!(received, added, "{n}");
        // No more counted than sent.
        assert!(
            received + over_rate <= sent,
            "robot {k}'s node counts more than was sent: {n}"
        );
        // The real robots' keyframes are never over rate.
        let counts = &s["fleet_counts"][*k];
        for j in 0..ROBOTS {
            let c = &counts[j.to_string()];
            if !c.is_null() {
                assert_eq!(
                    c["over_rate"].as_f64(),
                    Some(0.0),
                    "robot {k}'s node: robot {j} over rate: {counts}"
                );
            }
        }
    }
    // The late joiner started after the flood's publisher was gone: nothing of robot 99 there.
    for k in late.split(',') {
        let counts = &s["fleet_counts"][k];
        assert!(
            counts[FLOOD_ROBOT.to_string()].is_null(),
            "robot {k}'s node (late) has robot {FLOOD_ROBOT}'s keyframes: {counts}"
        );
    }
    // A closure onto the flood's random points would be false.
    assert_eq!(
        f["closures"].as_array().map(Vec::len),
        Some(0),
        "closures naming robot {FLOOD_ROBOT}: {}",
        f["closures"]
    );
}
