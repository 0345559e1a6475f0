//! The secured node (SROS2, Enforce) with a second DDS implementation on its domain: Debian's Cyclone
//! DDS 0.10 with its DDS Security plugins, through the cyclonedds Python binding built against it
//! (`tests/python/setup_cyclone_security.sh`, run from here; `tests/python/cyclone_secured_peer.py`).
//!
//! One keystore from `launch_scripts/make_keystore.sh` holds the enclaves `/dc_loc` (the node),
//! `/replayer` (the rustdds participant that replays a simulated drive into the node, so that it
//! publishes loop closures) and `/cyclone` (the Cyclone member). While the drive plays:
//! - the Cyclone member reads the node's loop closures and `/diagnostics`, and publishes clouds that the
//!   node refuses as `bad_stamp` (nanosec 1.5e9), which shows that they arrive;
//! - an unsecured Cyclone participant on the same domain subscribes to the same topics and publishes
//!   clouds in a frame no radar has (they would be refused as `unknown_frame`).
//!
//! The member must read every closure the node published (its `closures` counter), and its clouds must
//! be counted; the outsider must read nothing, match none of the node's endpoints, and none of its
//! clouds may reach the node.
//!
//! It passes with the rustdds of `third_party/rustdds` and Cyclone sending the handshake's optional
//! fields (third_party/README.md); the crates.io rustdds 0.15.1 authenticates no Cyclone participant.
//!
//! DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST for the node; rustdds on 127.0.0.1;
//! Cyclone with `tests/python/cyclonedds_loopback.xml`), on a domain no other test uses.
//! The keystore has sros2's governance (payloads encrypted); `DC_LOC_PAYLOAD_PROTECTION=NONE` (or `SIGN`)
//! makes it with that payload protection instead (docs/experiments.md, "DDS Security").

mod common;
#[path = "../examples/support/replay.rs"]
mod replay;

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use replay::{Drive, Security, make_keystore, start_node, stop_node};
use serde_json::Value;

/// The keystore's domain (below the range 51..101 that the Python tests reserve from, and used by no
/// other test).
const DOMAIN: u16 = 46;

/// The drive is replayed this many times faster than real time.
const RATE: f64 = 2.0;

/// The interpreter of the secured Cyclone venv, after making sure the venv is current (once per test
/// binary; a current venv costs a second, a new one about a minute).
fn cyclone_python() -> PathBuf {
    static PYTHON: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    let result = PYTHON.get_or_init(|| {
        let script =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/setup_cyclone_security.sh");
        let out = Command::new("bash")
            .arg(&script)
            .output()
            .map_err(|e| format!("cannot run {}: {e}", script.display()))?;
        let log = common::text(&out.stderr);
        if !out.status.success() {
            return Err(format!(
                "{} failed ({}):\n{log}",
                script.display(),
                out.status
            ));
        }
        eprint!("{log}");
        let stdout = common::text(&out.stdout);
        let python = PathBuf::from(stdout.lines().last().unwrap_or_default());
        if python.is_file() {
            Ok(python)
        } else {
            Err(format!(
                "{} printed no interpreter: {stdout}",
                script.display()
            ))
        }
    });
    match result {
        Ok(python) => python.clone(),
        Err(e) => panic!("{e}"),
    }
}

/// A running `cyclone_secured_peer.py`.
struct Peer {
    child: Child,
    stdout: BufReader<ChildStdout>,
}

impl Peer {
    /// Starts the peer with `args` and waits until its entities exist.
    fn start(args: &[String]) -> Peer {
        let script =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/cyclone_secured_peer.py");
        let mut child = Command::new(cyclone_python())
            .arg(&script)
            .arg("--domain")
            .arg(DOMAIN.to_string())
            .args(args)
            .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
            .env_remove("CYCLONEDDS_URI")
            .env_remove("PYTHONPATH")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("cannot start cyclone_secured_peer.py");
        let mut stdout = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        stdout.read_line(&mut line).unwrap();
        assert_eq!(
            line.trim(),
            "ready",
            "the Cyclone peer did not start ({args:?})"
        );
        Peer { child, stdout }
    }

    /// Closes the peer's stdin (its signal to finish) and returns its report (killed after 30 s).
    fn finish(mut self) -> Value {
        drop(self.child.stdin.take());
        let mut stdout = self.stdout;
        let reader = std::thread::spawn(move || {
            let mut out = String::new();
            let _ = stdout.read_to_string(&mut out);
            out
        });
        let t0 = Instant::now();
        let status = loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                break status;
            }
            if t0.elapsed() > Duration::from_secs(30) {
                let _ = self.child.kill();
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        let out = reader.join().unwrap();
        assert!(
            status.success(),
            "the Cyclone peer failed ({status}): {out}"
        );
        serde_json::from_str(out.lines().last().unwrap_or_default())
            .unwrap_or_else(|e| panic!("the Cyclone peer's report is not JSON ({e}): {out}"))
    }
}

/// The keystore with the enclaves of the node, the replayer and the Cyclone member.
fn keystore(dir: &Path) -> PathBuf {
    let protection = std::env::var("DC_LOC_PAYLOAD_PROTECTION").unwrap_or("ENCRYPT".into());
    let ks = dir.join(format!("keystore_{protection}"));
    make_keystore(
        &ks,
        DOMAIN,
        &protection,
        &["/dc_loc", "/replayer", "/cyclone"],
    );
    ks
}

fn count(values: &BTreeMap<String, String>, key: &str) -> u64 {
    values.get(key).map_or(0, |v| v.parse().unwrap())
}

/// `report[key]` as a list of closures (query id, match id, query robot, match robot).
fn closures(report: &Value) -> Vec<Vec<u64>> {
    serde_json::from_value(report["closures"].clone()).unwrap()
}

#[test]
fn a_secured_cyclone_peer_reads_the_closures_and_an_unsecured_one_nothing() {
    let dir = common::scratch("security_interop", "replay");
    let ks = keystore(&dir);
    let drive = Drive::simulate(&dir.join("drive"));
    let member_topic = drive.radar_topics[0].clone();
    let outsider_topic = drive.radar_topics[1].clone();
    let log_path = dir.join("node.log");
    let log = std::fs::File::create(&log_path).unwrap();
    let node = start_node(
        env!("CARGO_BIN_EXE_dc_loc"),
        &drive.summary.params_file,
        &["-p".into(), "node.diagnostics_period:=0.5".into()],
        DOMAIN,
        Some(&Security::new(&ks, "/dc_loc")),
        log.into(),
    );
    let member = Peer::start(&[
        "--enclave".into(),
        ks.join("enclaves/cyclone").display().to_string(),
        "--cloud-topic".into(),
        member_topic.clone(),
        "--bad-stamp".into(),
    ]);
    let outsider = Peer::start(&[
        "--cloud-topic".into(),
        outsider_topic.clone(),
        "--cloud-frame".into(),
        "cyclone_outsider".into(),
    ]);
    let t0 = Instant::now();
    let diagnostics =
        replay::replay_drive(DOMAIN, &drive, RATE, Some(&Security::new(&ks, "/replayer")));
    let member = member.finish();
    let outsider = outsider.finish();
    let code = stop_node(node);
    let log = std::fs::read_to_string(&log_path).unwrap();
    let tail: Vec<&str> = log.lines().rev().take(20).collect();
    assert_eq!(
        code,
        Some(0),
        "the node's exit; its log ends with {tail:#?}"
    );

    let published = count(&diagnostics, "closures");
    let read = closures(&member);
    println!(
        "replayed in {:.0} s; node: {published} closures published, bad_stamp {}, unknown_frame {}",
        t0.elapsed().as_secs_f64(),
        count(&diagnostics, "bad_stamp"),
        count(&diagnostics, "unknown_frame"),
    );
    let member_view = &member["diagnostics_values"];
    println!(
        "Cyclone member: {} closures, {} diagnostics (closures {}, bad_stamp {}), {} clouds sent; \
         outsider: {} closures, {} diagnostics, {} clouds sent",
        read.len(),
        member["diagnostics"],
        member_view["closures"],
        member_view["bad_stamp"],
        member["clouds_sent"],
        closures(&outsider).len(),
        outsider["diagnostics"],
        outsider["clouds_sent"],
    );
    // The member reads every closure, once, and the node's diagnostics.
    assert!(published > 0, "the node published no closure");
    assert_eq!(read.len() as u64, published, "closures read by the member");
    let mut pairs: Vec<(u64, u64)> = read.iter().map(|c| (c[0], c[1])).collect();
    pairs.sort_unstable();
    pairs.dedup();
    assert_eq!(pairs.len(), read.len(), "a closure read twice");
    assert!(member["diagnostics"].as_u64().unwrap() > 0);
    // The member's clouds reach the node (those sent before the handshakes completed are lost).
    let sent = member["clouds_sent"].as_u64().unwrap();
    let refused = count(&diagnostics, "bad_stamp");
    assert!(refused > 0 && refused <= sent, "{refused} of {sent}");
    // The outsider reads nothing, matches nothing, and none of its clouds reaches the node.
    assert!(closures(&outsider).is_empty(), "the outsider read closures");
    assert_eq!(outsider["diagnostics"], 0, "the outsider read diagnostics");
    assert_eq!(outsider["closure_writers_matched"], 0);
    assert_eq!(outsider["cloud_readers_matched"], 0);
    assert_eq!(
        count(&diagnostics, "unknown_frame"),
        0,
        "the outsider's clouds"
    );
    assert!(!log.contains("cyclone_outsider"), "{log}");
}
