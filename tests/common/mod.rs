//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The real-data folder: `$DC_LOC_REAL_DATA` if set, else `<manifest>/../shared/data/real` (the main
/// checkout), else `<manifest>/../../shared/data/real` (a worktree under `/work/wt/`). `None` (after
/// printing why) only when none exists: that is the only case in which real-data tests skip.
pub fn real_data() -> Option<PathBuf> {
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut candidates = Vec::new();
    if let Some(dir) = std::env::var_os("DC_LOC_REAL_DATA") {
        candidates.push(PathBuf::from(dir));
    }
    candidates.push(manifest.join("../shared/data/real"));
    candidates.push(manifest.join("../../shared/data/real"));
    let found = candidates.iter().find(|p| p.is_dir()).cloned();
    if found.is_none() {
        skipped(&format!(
            "real data folder not found (tried {candidates:?}); set DC_LOC_REAL_DATA to run"
        ));
    }
    found
}

/// Says that the running test skipped its work and why: on stderr past the test harness's capture,
/// and as a line of `<target>/tmp/skipped-tests.txt`, which CI counts.
pub fn skipped(why: &str) {
    use std::io::Write;
    let test = std::thread::current()
        .name()
        .unwrap_or("a test")
        .to_string();
    let line = format!("SKIPPED {test}: {why}\n");
    let _ = std::io::stderr().write_all(line.as_bytes());
    let log = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("skipped-tests.txt");
    if let Ok(mut f) = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(log)
    {
        let _ = f.write_all(line.as_bytes());
    }
}

/// A fresh scratch directory `<target tmp>/<suite>/<name>` (emptied first).
pub fn scratch(suite: &str, name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(suite)
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs the `dc_loc` binary with `RUST_LOG` set to `rust_log` and waits for it.
pub fn run_dc_loc(args: &[&str], rust_log: &str) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_dc_loc"))
        .args(args)
        .env("RUST_LOG", rust_log)
        .output()
        .expect("cannot start dc_loc")
}

/// Bytes of a child's output as text.
pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// A short drive: two laps (54 and 36 km/h) of a 170 x 110 m block, about 106 s, fewer pose samples.
pub const SHORT_DRIVE: &str = "\
seed: 3
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

/// The node of `command` (its arguments and environment set), started and running: it printed that
/// it runs, after its signal handler is in place. Its stderr is kept for the end; what else it
/// prints is read, so that it never writes to a closed pipe.
pub fn start_node(mut command: std::process::Command) -> std::process::Child {
    use std::io::{BufRead, BufReader};
    use std::process::Stdio;
    let mut child = command
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("cannot start dc_loc");
    let stdout = child.stdout.take().unwrap();
    let mut lines = BufReader::new(stdout).lines();
    if !lines.any(|l| l.is_ok_and(|l| l.contains("running"))) {
        let out = child.wait_with_output().unwrap();
        panic!("the node ended ({}): {}", out.status, text(&out.stderr));
    }
    std::thread::spawn(move || lines.for_each(drop));
    child
}

/// SIGINT to a node of [`start_node`], then its exit code and stderr (killed after 30 s). Its stderr is
/// read while it shuts down, so that a node logging much never blocks on a full pipe.
pub fn interrupt(mut child: std::process::Child) -> (Option<i32>, String) {
    use std::io::Read;
    use std::time::{Duration, Instant};
    let mut stderr = child.stderr.take().expect("stderr piped");
    let reader = std::thread::spawn(move || {
        let mut buf = Vec::new();
        let _ = stderr.read_to_end(&mut buf);
        buf
    });
    let pid = child.id().to_string();
    let sent = std::process::Command::new("kill")
        .args(["-INT", &pid])
        .status()
        .unwrap();
    assert!(sent.success());
    let t0 = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if t0.elapsed() > Duration::from_secs(30) {
            let _ = child.kill();
            panic!("the node did not end within 30 s of SIGINT");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    (status.code(), text(&reader.join().unwrap()))
}
