//! The node's start-up refusals and its map file as an operator meets them: out-of-range node
//! settings stop the start with exit code 2 and the cause (DDS security: tests/security.rs); a radar left on
//! the default noise is warned about once at start; a map another node holds is refused naming the
//! holder, and the holder keeps and saves it; files a killed writer left are removed; a refused map with `map.start_empty_on_error` saves to `<map>.new`, then
//! `<map>.new.1`, never over an earlier session; a clean shutdown logs no ERROR line. No Python here: the node runs alone on a domain of
//! its own, on loopback.

mod common;
use common::{interrupt, text};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const DOMAIN: &str = "87";

fn node() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_dc_loc"));
    c.env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .env("ROS_DOMAIN_ID", DOMAIN)
        .env_remove("ROS_SECURITY_ENABLE")
        .env_remove("ROS_SECURITY_STRATEGY");
    c
}

fn run(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut c = node();
    c.args(args);
    for (k, v) in env {
        c.env(k, v);
    }
    c.output().expect("cannot start dc_loc")
}

fn scratch(name: &str) -> PathBuf {
    common::scratch("node_faults", name)
}

/// A node on `map`, started and running (see [`common::start_node`]).
fn start(map: &Path, extra: &[&str]) -> Child {
    let mut args = vec!["--ros-args".to_string(), "-p".into()];
    args.push(format!("map.file:={}", map.display()));
    for e in extra {
        args.push((*e).into());
    }
    let mut command = node();
    command.args(&args);
    common::start_node(command)
}

#[test]
fn out_of_range_node_settings_stop_the_start() {
    for (p, name) in [
        ("node.queue_size:=100000000000000000000", "node.queue_size"),
        ("node.shutdown_timeout:=1e20", "node.shutdown_timeout"),
        ("node.max_cloud_points:=-5", "node.max_cloud_points"),
        ("node.diagnostics_period:=0.0", "node.diagnostics_period"),
        ("imu.topic:=''", "imu.topic"),
        ("node.odom_frame:=''", "node.odom_frame"),
    ] {
        let out = run(&["--ros-args", "-p", p], &[]);
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{p}: {err}");
        assert!(
            err.contains(name),
            "{p}: the message does not name {name}: {err}"
        );
    }
}

/// A radar whose noise sigmas no parameter sets is warned about once at start, naming the unset
/// parameters (its `beta`, set here, is not named) and whose values the defaults are.
#[test]
fn a_radar_left_on_the_default_noise_is_named_at_start() {
    let dir = scratch("default_noise");
    std::fs::create_dir_all(&dir).unwrap();
    let child = start(&dir.join("map.dcmap"), &["-p", "radars.front.beta:=0.005"]);
    let (_, err) = interrupt(child);
    let warning = "radar `front`: radars.front.sigma_range, radars.front.sigma_velocity, \
                   radars.front.sigma_azimuth not set; the defaults";
    assert_eq!(err.matches(warning).count(), 1, "{err}");
    assert!(
        err.contains("ARS408-21") && !err.contains("radars.front.beta, "),
        "{err}"
    );
}

/// A node of a fleet stopped by SIGINT on loopback exits 0 and logs no ERROR line: its DDS readers
/// and writers go before the participant, and rustdds' report of a multicast group it cannot leave on
/// loopback (harmless: the closing socket drops the membership) is logged at debug level.
#[test]
fn a_clean_shutdown_logs_no_error() {
    let dir = scratch("clean_shutdown");
    std::fs::create_dir_all(&dir).unwrap();
    let mut command = node();
    command.env("RUST_LOG", "warn").args([
        "--ros-args",
        "-p",
        &format!("map.file:={}", dir.join("map.dcmap").display()),
        "-p",
        "node.fleet:=true",
    ]);
    let (code, err) = interrupt(common::start_node(command));
    assert_eq!(code, Some(0), "{err}");
    let errors: Vec<&str> = err.lines().filter(|l| l.contains(" ERROR ")).collect();
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

#[test]
fn a_map_in_use_is_refused_and_its_holder_keeps_it() {
    let dir = scratch("in_use");
    let map = dir.join("map.bin");
    // A temporary file a killed writer left behind.
    let stale = dir.join(".map.bin.tmp-999999");
    std::fs::write(&stale, b"half a map").unwrap();
    let first = start(&map, &[]);
    assert!(
        !stale.exists(),
        "the killed writer's temporary file is still there"
    );

    let second = run(
        &["--ros-args", "-p", &format!("map.file:={}", map.display())],
        &[],
    );
    let err = text(&second.stderr);
    assert_eq!(second.status.code(), Some(2), "{err}");
    assert!(err.contains("in use"), "{err}");
    assert!(
        err.contains(&first.id().to_string()),
        "the holder's pid: {err}"
    );

    let (code, err) = interrupt(first);
    assert_eq!(code, Some(0), "{err}");
    assert!(map.exists(), "the holder did not save its map: {err}");
    // The saved map loads.
    dc_loc::keyframe_db::KeyframeDb::load(&map, Default::default(), 4).expect("saved map");
}

#[test]
fn a_refused_map_is_never_overwritten_and_fallbacks_are_numbered() {
    let dir = scratch("fallback");
    let map = dir.join("map.bin");
    let garbage = b"not a dc_loc map at all".to_vec();
    std::fs::write(&map, &garbage).unwrap();

    let out = run(
        &["--ros-args", "-p", &format!("map.file:={}", map.display())],
        &[],
    );
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("map.file"), "{err}");

    for expected in ["map.bin.new", "map.bin.new.1"] {
        let child = start(&map, &["-p", "map.start_empty_on_error:=true"]);
        let (code, err) = interrupt(child);
        assert_eq!(code, Some(0), "{err}");
        assert!(dir.join(expected).exists(), "{expected} not written: {err}");
        assert_eq!(
            std::fs::read(&map).unwrap(),
            garbage,
            "the refused map changed"
        );
    }
}

#[test]
fn a_dying_worker_ends_the_process_at_once() {
    let dir = scratch("panic");
    let mut child = node()
        .args(["--ros-args", "-p", "node.diagnostics_period:=0.5"])
        .env("DC_LOC_FAULT_WORKER_PANIC", "1")
        .current_dir(&dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("cannot start dc_loc");
    let stderr = child.stderr.take().unwrap();
    let mut lines = BufReader::new(stderr).lines();
    // The panic message, then the process must be gone within a second.
    let panicked = lines.any(|l| l.is_ok_and(|l| l.contains("DC_LOC_FAULT_WORKER_PANIC")));
    assert!(panicked, "no panic message");
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t0.elapsed() > Duration::from_secs(1) {
            let _ = child.kill();
            panic!("the node is still running 1 s after its worker died");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    assert!(!status.success(), "{status}");
}
