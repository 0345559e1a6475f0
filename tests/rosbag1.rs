//! ROS 1 bags (format 2.0) read by the bag reader and by `dc_loc run` / `dc_loc eval`:
//! - bags written by the Python rosbags library (tests/python/ros1_bags.py, in the ROS 2 test venv) in
//!   uncompressed, bz2 and lz4 chunks: every message decodes from its ROS 1 bytes to the same struct as
//!   from its ROS 2 CDR bytes, with topics, types, md5sums and times as written;
//! - damage (a truncated file, a corrupted chunk, lying lengths, an index past the end): refused with a
//!   message naming the byte, the messages before it read, the run going on to the end it can reach;
//! - a connection whose md5sum is not the standard definition of its type: refused, naming topic,
//!   type and both sums;
//! - a simulated drive written as MCAP and converted to ROS 1: `dc_loc run` writes byte-identical
//!   closure files from both, and `dc_loc eval` prints the same evaluation;
//! - the real TI mmWave bag of the shared data (every scan, its fields, the Doppler ego-motion fit's
//!   inlier share), skipped with a message when the data folder is absent.

mod common;
#[path = "python/venv.rs"]
mod venv;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use dc_loc::bag::{BagError, BagMessage, BagReader, cdr, schema};
use dc_loc::cloud::decode_detections;
use dc_loc::input::{Input, IssueReason};
use dc_loc::io::rosbag::{BagInputError, BagInputs};
use dc_loc::math::Stamp;
use dc_loc::msgs::geometry_msgs::PoseStamped;
use dc_loc::msgs::nav_msgs::Odometry;
use dc_loc::msgs::radar_msgs::RadarScan;
use dc_loc::msgs::sensor_msgs::{Imu, PointCloud2, PointField};
use dc_loc::msgs::tf2_msgs::TFMessage;
use dc_loc::pipeline::Config;
use dc_loc::radar::FieldsConfig;
use dc_loc::radar::ego_motion::{EgoMotionConfig, FitDims, fit_radar_velocity};
use serde_json::Value;

use common::{SHORT_DRIVE, run_dc_loc, scratch, text};

/// The fixture bags written by rosbags once per test binary: `<dir>/{none,bz2,lz4}.bag`,
/// `<dir>/expected.json`.
fn fixtures() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = scratch("rosbag1", "fixtures");
        let out = venv::python_script("ros1_bags.py")
            .arg("fixtures")
            .arg(&dir)
            .output()
            .expect("cannot run ros1_bags.py");
        assert!(
            out.status.success(),
            "ros1_bags.py fixtures: {}{}",
            text(&out.stdout),
            text(&out.stderr)
        );
        dir
    })
}

fn expected() -> Vec<Value> {
    let json = std::fs::read_to_string(fixtures().join("expected.json")).unwrap();
    serde_json::from_str::<Vec<Value>>(&json).unwrap()
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// `msg` decoded from ROS 1 and `cdr` decoded from CDR, as `T`, are equal.
fn same<T>(msg: &BagMessage, cdr_bytes: &[u8])
where
    T: serde::de::DeserializeOwned + PartialEq + std::fmt::Debug,
{
    let ros1: T = msg
        .decode()
        .unwrap_or_else(|e| panic!("{}: {e}", msg.topic()));
    let ros2: T = cdr::decode(cdr_bytes).unwrap();
    assert_eq!(ros1, ros2, "{}", msg.topic());
}

/// Decodes `msg` as its type and compares it with the CDR decoding of `cdr_bytes`.
fn check_message(msg: &BagMessage, cdr_bytes: &[u8]) {
    match msg.type_name() {
        schema::POINT_CLOUD2 => same::<PointCloud2>(msg, cdr_bytes),
        schema::ODOMETRY => same::<Odometry>(msg, cdr_bytes),
        schema::TF_MESSAGE => same::<TFMessage>(msg, cdr_bytes),
        schema::POSE_STAMPED => same::<PoseStamped>(msg, cdr_bytes),
        schema::IMU => same::<Imu>(msg, cdr_bytes),
        schema::RADAR_SCAN => same::<RadarScan>(msg, cdr_bytes),
        other => panic!("unexpected type {other}"),
    }
}

/// The messages of a bag until the first error, each as (topic, log time, bytes), and the error.
type Read = (Vec<(String, Stamp, Vec<u8>)>, Option<BagError>);

/// The messages of a bag until the first error, and the error.
fn read_all(reader: &BagReader) -> Read {
    let mut out = Vec::new();
    for m in reader.messages().unwrap() {
        match m {
            Ok(m) => out.push((m.topic().to_string(), m.log_time, m.data().to_vec())),
            Err(e) => return (out, Some(e)),
        }
    }
    (out, None)
}

#[test]
fn every_message_reads_as_its_cdr_twin_in_each_compression() {
    let expected = expected();
    for compression in ["none", "bz2", "lz4"] {
        let path = fixtures().join(format!("{compression}.bag"));
        let bytes = std::fs::read(&path).unwrap();
        let tag = format!("compression={compression}");
        assert!(
            bytes.windows(tag.len()).any(|w| w == tag.as_bytes()),
            "{compression}.bag has no {tag} chunk"
        );
        let reader = BagReader::open(&path).unwrap();
        assert_eq!(reader.message_count(), expected.len() as u64);
        let mut counts: BTreeMap<&str, u64> = BTreeMap::new();
        for e in &expected {
            *counts.entry(e["topic"].as_str().unwrap()).or_default() += 1;
        }
        for t in reader.topics() {
            assert_eq!(t.message_encoding, "ros1", "{}", t.name);
            assert_eq!(t.schema_encoding, "ros1msg", "{}", t.name);
            assert_eq!(Some(&t.message_count), counts.get(t.name.as_str()));
            assert_eq!(
                dc_loc::bag::ros1::known_md5sum(&t.type_name),
                Some(t.md5sum.as_str()),
                "{} ({})",
                t.name,
                t.type_name
            );
            let definition = String::from_utf8(t.schema.clone()).unwrap();
            assert!(
                definition.contains("MSG: std_msgs/Header\nuint32 seq\ntime stamp"),
                "{}: {definition}",
                t.name
            );
        }
        let t0 = expected[0]["time"].as_i64().unwrap();
        let t1 = expected.last().unwrap()["time"].as_i64().unwrap();
        assert_eq!(reader.time_range(), Some((Stamp(t0), Stamp(t1))));
        let messages: Vec<BagMessage> = reader.messages().unwrap().map(Result::unwrap).collect();
        assert_eq!(messages.len(), expected.len());
        for (m, e) in messages.iter().zip(&expected) {
            assert_eq!(m.topic(), e["topic"].as_str().unwrap());
            assert_eq!(m.type_name(), e["type"].as_str().unwrap());
            assert_eq!(m.log_time, Stamp(e["time"].as_i64().unwrap()));
            check_message(m, &unhex(e["cdr"].as_str().unwrap()));
        }
        // A topic selection reads the same messages of that topic, other chunks skipped.
        let odom: Vec<Vec<u8>> = reader
            .messages_on(&["/odom"])
            .unwrap()
            .map(|m| m.unwrap().data().to_vec())
            .collect();
        let want: Vec<Vec<u8>> = messages
            .iter()
            .filter(|m| m.topic() == "/odom")
            .map(|m| m.data().to_vec())
            .collect();
        assert_eq!(odom, want);
        assert_eq!(odom.len(), 2);
    }
}

/// The configuration of the fixtures: the radar on /radar_front (frame radar_front), odometry on
/// /odom.
fn fixture_config() -> Config {
    let mut cfg = Config::default();
    let name = cfg.radar_names[0].clone();
    cfg.radar_names = vec![name.clone()];
    cfg.radars.retain(|n, _| *n == name);
    let r = cfg.radars.get_mut(&name).unwrap();
    r.topic = "/radar_front".into();
    r.frame_id = String::new();
    cfg.odometry.topic = "/odom".into();
    cfg
}

#[test]
fn bag_inputs_read_a_ros1_bag_with_pose_stamped_ground_truth() {
    let reader = BagReader::open(&fixtures().join("lz4.bag")).unwrap();
    let inputs = BagInputs::new(&reader, &fixture_config(), Some("/ground_truth")).unwrap();
    let (mut radar, mut odometry, mut ground_truth, mut issues) = (0, 0, 0, Vec::new());
    for item in inputs {
        match item {
            Ok(Input::Radar { cloud, .. }) => {
                radar += 1;
                assert_ne!(Stamp::from(cloud.header.stamp), Stamp(0));
            }
            Ok(Input::Odometry { .. }) => odometry += 1,
            Ok(Input::GroundTruth {
                t_map_body, speed, ..
            }) => {
                ground_truth += 1;
                assert_eq!(t_map_body.translation.x, 10.5);
                assert_eq!(speed, 0.0);
            }
            Ok(other) => panic!("unexpected input {other:?}"),
            Err(issue) => issues.push(issue.to_string()),
        }
    }
    assert_eq!((radar, odometry, ground_truth), (3, 2, 1), "{issues:?}");
    assert!(issues.is_empty(), "{issues:?}");
}

/// One top-level record of a bag file: offset, op, header (offset, length), data (offset, length).
#[derive(Debug, Clone, Copy)]
struct Rec {
    at: usize,
    op: u8,
    header: (usize, usize),
    data: (usize, usize),
}

fn u32_at(b: &[u8], at: usize) -> usize {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize
}

/// The top-level records of an intact bag, after the magic.
fn records(b: &[u8]) -> Vec<Rec> {
    let mut out = Vec::new();
    let mut at = 13;
    while at < b.len() {
        let hl = u32_at(b, at);
        let h = at + 4;
        let mut op = 0;
        let mut f = h;
        while f < h + hl {
            let n = u32_at(b, f);
            let field = &b[f + 4..f + 4 + n];
            if field.starts_with(b"op=") {
                op = field[3];
            }
            f += 4 + n;
        }
        let dl = u32_at(b, h + hl);
        let d = h + hl + 4;
        out.push(Rec {
            at,
            op,
            header: (h, hl),
            data: (d, dl),
        });
        at = d + dl;
    }
    out
}

/// Where the header field `name=` of `rec` holds its value.
fn field_at(b: &[u8], rec: Rec, name: &str) -> usize {
    let (h, hl) = rec.header;
    let mut f = h;
    while f < h + hl {
        let n = u32_at(b, f);
        if b[f + 4..f + 4 + n].starts_with(format!("{name}=").as_bytes()) {
            return f + 4 + name.len() + 1;
        }
        f += 4 + n;
    }
    panic!("no field {name}");
}

fn chunks(b: &[u8]) -> Vec<Rec> {
    records(b).into_iter().filter(|r| r.op == 0x05).collect()
}

/// Writes `bytes` as `<scratch>/<name>.bag` and reads it: the messages up to the first error, and it.
fn read_damaged(name: &str, bytes: &[u8]) -> Read {
    let dir = scratch("rosbag1", name);
    let path = dir.join(format!("{name}.bag"));
    std::fs::write(&path, bytes).unwrap();
    let reader = BagReader::open(&path).unwrap_or_else(|e| panic!("{name}: open: {e}"));
    read_all(&reader)
}

#[test]
fn damage_is_refused_with_a_message_and_what_came_before_is_kept() {
    for compression in ["none", "bz2", "lz4"] {
        let path = fixtures().join(format!("{compression}.bag"));
        let good = std::fs::read(&path).unwrap();
        let (all, err) = read_all(&BagReader::open(&path).unwrap());
        assert!(err.is_none());
        let cs = chunks(&good);
        assert!(cs.len() >= 4, "{compression}: {} chunks", cs.len());
        // Messages in the chunks before the third one.
        let before_third = {
            let cut = &good[..cs[2].at];
            let (m, e) = read_damaged(&format!("{compression}_cut_between"), cut);
            assert!(
                e.is_none(),
                "{compression}: a cut between chunks is a clean end: {e:?}"
            );
            m.len()
        };
        assert!(before_third > 0 && before_third < all.len());
        let expect_prefix = |name: &str, (got, err): Read, want: &str| {
            let err = err.unwrap_or_else(|| panic!("{compression} {name}: no error"));
            let msg = err.to_string();
            assert!(
                matches!(err, BagError::Ros1Damaged { .. }),
                "{compression} {name}: {msg}"
            );
            assert!(msg.contains(want), "{compression} {name}: {msg}");
            assert_eq!(got.len(), before_third, "{compression} {name}: {msg}");
            assert_eq!(got[..], all[..got.len()], "{compression} {name}");
            println!(
                "{compression} {name}: {} messages kept, then: {msg}",
                got.len()
            );
        };
        // A truncated file: cut inside the third chunk (index gone, the file is scanned).
        let third = cs[2];
        let cut = &good[..third.data.0 + third.data.1 / 2];
        expect_prefix(
            "truncated",
            read_damaged(&format!("{compression}_truncated"), cut),
            &format!("record at byte {} declares a data of", third.at),
        );
        // A corrupted chunk: its data overwritten (the index is intact).
        let mut bad = good.clone();
        let (d, n) = third.data;
        for b in &mut bad[d + n / 4..d + n / 2] {
            *b ^= 0x5A;
        }
        let (got, err) = read_damaged(&format!("{compression}_corrupted"), &bad);
        // Its counts come from the intact index, a truncated file's from the scan up to the damage.
        let dir = scratch("rosbag1", &format!("{compression}_counts"));
        std::fs::write(dir.join("corrupted.bag"), &bad).unwrap();
        let reader = BagReader::open(&dir.join("corrupted.bag")).unwrap();
        assert_eq!(reader.message_count(), all.len() as u64);
        std::fs::write(dir.join("truncated.bag"), cut).unwrap();
        let reader = BagReader::open(&dir.join("truncated.bag")).unwrap();
        assert_eq!(reader.message_count(), before_third as u64);
        if compression == "none" {
            // Uncompressed records: the flipped bytes land in a record header or in message data;
            // either a record is refused or the messages still read (their content is not checked
            // here), but never past the damage with garbage lengths.
            if let Some(e) = &err {
                assert!(matches!(e, BagError::Ros1Damaged { .. }), "{e}");
                assert!(got.len() >= before_third);
            }
        } else {
            expect_prefix(
                "corrupted",
                (got, err),
                &format!("chunk at byte {}", third.at),
            );
        }
        // Lying lengths: the chunk's data length past the end of the file, its uncompressed size
        // beyond the reader's limit.
        let mut bad = good.clone();
        bad[third.data.0 - 4..third.data.0].copy_from_slice(&0x7FFF_FFF0u32.to_le_bytes());
        expect_prefix(
            "data length",
            read_damaged(&format!("{compression}_data_length"), &bad),
            "past the end of the file",
        );
        let mut bad = good.clone();
        let size = field_at(&good, third, "size");
        bad[size..size + 4].copy_from_slice(&0x7000_0000u32.to_le_bytes());
        expect_prefix(
            "chunk size",
            read_damaged(&format!("{compression}_size"), &bad),
            "more than the 64 MiB",
        );
        // A header length past the end of the file.
        let mut bad = good.clone();
        bad[third.at..third.at + 4].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
        expect_prefix(
            "header length",
            read_damaged(&format!("{compression}_header_length"), &bad),
            "past the end of the file",
        );
        // The bag header's index position past the end: the file is scanned, everything is read.
        let mut bad = good.clone();
        let header = records(&good)[0];
        let index_pos = field_at(&good, header, "index_pos");
        bad[index_pos..index_pos + 8].copy_from_slice(&u64::MAX.to_le_bytes());
        let (got, err) = read_damaged(&format!("{compression}_index_pos"), &bad);
        assert!(err.is_none(), "{err:?}");
        assert_eq!(got, all);
    }
}

#[test]
fn a_record_running_past_its_chunk_is_refused() {
    let good = std::fs::read(fixtures().join("none.bag")).unwrap();
    let cs = chunks(&good);
    let third = cs[2];
    // The first record inside the third (uncompressed) chunk: its data length made to run past it.
    let (d, _) = third.data;
    let hl = u32_at(&good, d);
    let mut bad = good.clone();
    bad[d + 4 + hl..d + 8 + hl].copy_from_slice(&0x00FF_FFFFu32.to_le_bytes());
    let (got, err) = read_damaged("inner_length", &bad);
    let msg = err.expect("no error").to_string();
    assert!(msg.contains("past the chunk's end"), "{msg}");
    let before = read_damaged("inner_cut", &good[..third.at]).0;
    assert_eq!(got, before, "{msg}");
}

#[test]
fn a_damaged_bag_runs_to_the_damage_and_reports_it() {
    let good = std::fs::read(fixtures().join("bz2.bag")).unwrap();
    let cs = chunks(&good);
    let last = *cs.last().unwrap();
    let dir = scratch("rosbag1", "inputs_damaged");
    let path = dir.join("cut.bag");
    std::fs::write(&path, &good[..last.data.0 + 10]).unwrap();
    let reader = BagReader::open(&path).unwrap();
    let items: Vec<_> = BagInputs::new(&reader, &fixture_config(), Some("/ground_truth"))
        .unwrap()
        .collect();
    let damaged: Vec<_> = items
        .iter()
        .filter_map(|i| i.as_ref().err())
        .filter(|i| matches!(i.reason, IssueReason::Damaged(_)))
        .collect();
    assert_eq!(damaged.len(), 1, "{items:?}");
    assert!(
        matches!(items.last(), Some(Err(_))),
        "the damage is the last item"
    );
    assert!(items.iter().filter(|i| i.is_ok()).count() >= 3);
}

#[test]
fn a_connection_of_another_definition_is_refused_naming_it() {
    let good = std::fs::read(fixtures().join("none.bag")).unwrap();
    let md5 = b"cd5e73d190d741a2f92e81eda573aca7";
    let mut bad = good.clone();
    let mut n = 0;
    for i in 0..bad.len() - md5.len() {
        if &bad[i..i + md5.len()] == md5 {
            bad[i..i + md5.len()].copy_from_slice(b"00000000000000000000000000000000");
            n += 1;
        }
    }
    assert!(n >= 2, "md5sum found {n} times");
    let dir = scratch("rosbag1", "definition");
    let path = dir.join("other_odometry.bag");
    std::fs::write(&path, &bad).unwrap();
    let reader = BagReader::open(&path).unwrap();
    let err = BagInputs::new(&reader, &fixture_config(), None)
        .err()
        .expect("refused");
    let msg = err.to_string();
    assert!(matches!(err, BagInputError::Definition { .. }), "{msg}");
    for part in [
        "odometry.topic",
        "/odom",
        "nav_msgs/Odometry",
        "\"00000000000000000000000000000000\"",
        "cd5e73d190d741a2f92e81eda573aca7",
    ] {
        assert!(msg.contains(part), "{part}: {msg}");
    }
    println!("{msg}");
    // Decoding a message of that connection says the same.
    let m = reader
        .messages_on(&["/odom"])
        .unwrap()
        .next()
        .unwrap()
        .unwrap();
    let e = m.decode::<Odometry>().unwrap_err();
    assert!(matches!(e, BagError::Ros1Definition { .. }), "{e}");
    // A type with no known ROS 1 layout.
    let e = dc_loc::bag::ros1::definition_fault("std_msgs/msg/String", "x").unwrap();
    assert!(e.contains("no ROS 1 layout of std_msgs/String"), "{e}");
}

#[test]
fn not_a_bag_of_format_2_0_is_named() {
    let dir = scratch("rosbag1", "version");
    let path = dir.join("old.bag");
    std::fs::write(&path, b"#ROSBAG V1.2\n\0\0\0\0").unwrap();
    let e = BagReader::open(&path).unwrap_err();
    assert!(matches!(e, BagError::Ros1Version { .. }), "{e}");
    assert!(e.to_string().contains("\"1.2\""), "{e}");
    let path = dir.join("nothing.bag");
    std::fs::write(&path, b"#ROSBAG V2.0\n").unwrap();
    let e = BagReader::open(&path).unwrap_err();
    assert!(e.to_string().contains("no bag header"), "{e}");
}

/// `dc_loc run` on the bag at `bag` with `params`; the closure file's bytes and stdout.
fn run(bag: &Path, params: &Path, out: &Path) -> (Vec<u8>, String) {
    let o = run_dc_loc(
        &[
            "run",
            "--bag",
            bag.to_str().unwrap(),
            "--params",
            params.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        "warn",
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    (std::fs::read(out).unwrap(), text(&o.stdout))
}

#[test]
fn a_simulated_drive_gives_identical_closures_as_mcap_and_as_ros1() {
    let root = scratch("rosbag1", "sim");
    let config = root.join("short.yaml");
    std::fs::write(&config, SHORT_DRIVE).unwrap();
    let mcap = root.join("short");
    let o = run_dc_loc(
        &[
            "sim",
            "--config",
            config.to_str().unwrap(),
            "--out",
            mcap.to_str().unwrap(),
        ],
        "warn",
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    let params = mcap.join("dc_loc.yaml");
    let (closures, stdout) = run(&mcap, &params, &root.join("mcap.jsonl"));
    let n = closures.iter().filter(|&&b| b == b'\n').count();
    assert!(n > 0, "the drive has closures: {stdout}");
    for compression in ["lz4", "bz2"] {
        let bag = root.join(format!("short_{compression}.bag"));
        let o = venv::python_script("ros1_bags.py")
            .args(["convert", mcap.to_str().unwrap(), bag.to_str().unwrap()])
            .args(["--compression", compression])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}{}", text(&o.stdout), text(&o.stderr));
        println!("{}", text(&o.stdout).trim());
        let (ros1, ros1_stdout) = run(&bag, &params, &root.join(format!("{compression}.jsonl")));
        assert!(
            ros1 == closures,
            "{compression}: closure files differ\nMCAP:\n{stdout}\nROS 1:\n{ros1_stdout}"
        );
        println!(
            "{compression}: {n} closures, {} bytes, identical to the MCAP run's",
            ros1.len()
        );
    }
    // The ROS 1 bag cut at 60 %: the run goes to the damage, writes the closures found up to it (the
    // first ones of the whole run) and exits with 1, naming the damage.
    let whole = std::fs::read(root.join("short_lz4.bag")).unwrap();
    let cut = root.join("cut.bag");
    std::fs::write(&cut, &whole[..whole.len() * 3 / 5]).unwrap();
    let out = root.join("cut.jsonl");
    let o = run_dc_loc(
        &[
            "run",
            "--bag",
            cut.to_str().unwrap(),
            "--params",
            params.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        "warn",
    );
    let stderr = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("damaged ROS 1 bag"), "{stderr}");
    let kept = std::fs::read(&out).unwrap();
    let k = kept.iter().filter(|&&b| b == b'\n').count();
    assert!(k > 0 && k < n, "{k} of {n} closures before the damage");
    assert!(
        closures.starts_with(&kept),
        "the closures before the damage are the whole run's"
    );
    println!(
        "cut at 60 %: {k} of {n} closures written, then: {}",
        stderr.lines().last().unwrap_or_default()
    );
    // `dc_loc eval` prints the same evaluation from both.
    let eval = |bag: &Path, dir: &str| {
        let o = run_dc_loc(
            &[
                "eval",
                "--bag",
                bag.to_str().unwrap(),
                "--params",
                params.to_str().unwrap(),
                "--out-dir",
                root.join(dir).to_str().unwrap(),
                "--dcloc-only",
            ],
            "warn",
        );
        assert!(o.status.success(), "{}", text(&o.stderr));
        text(&o.stdout)
            .lines()
            .filter(|l| !l.contains(dir) && !l.contains("time"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    let a = eval(&mcap, "eval_mcap");
    let b = eval(&root.join("short_lz4.bag"), "eval_ros1");
    assert_eq!(a, b);
    println!("eval (both):\n{a}");
}

/// The TI mmWave layout: x, y, z, velocity (FLOAT32).
fn ti_fields() -> FieldsConfig {
    FieldsConfig {
        velocity: "velocity".into(),
        rcs: String::new(),
        ..FieldsConfig::default()
    }
}

#[test]
fn the_ti_mmwave_bag_reads_completely() {
    let Some(real) = common::real_data() else {
        return;
    };
    let path = real.join("rio-ti-mmwave-demo/ti_mmwave_rospkg_demo.bag");
    if !path.is_file() {
        common::skipped(&format!("{} not found", path.display()));
        return;
    }
    let reader = BagReader::open(&path).unwrap();
    let topics: BTreeMap<&str, (&str, u64)> = reader
        .topics()
        .iter()
        .map(|t| (t.name.as_str(), (t.type_name.as_str(), t.message_count)))
        .collect();
    println!("topics: {topics:?}");
    assert_eq!(reader.message_count(), 11_152);
    assert_eq!(
        topics["/ti_mmwave/radar_scan_pcl"],
        (schema::POINT_CLOUD2, 412)
    );
    assert_eq!(topics["/sensor_platform/imu"], (schema::IMU, 8270));
    let (a, b) = reader.time_range().unwrap();
    println!("span {:.2} s", b.secs_since(a));
    assert!((b.secs_since(a) - 40.3).abs() < 0.1);

    let fields = ti_fields();
    let (mut scans, mut points, mut inliers, mut fitted) = (0usize, 0usize, 0usize, 0usize);
    let (mut min_pts, mut max_pts) = (usize::MAX, 0usize);
    let (mut v_min, mut v_max) = (f64::MAX, f64::MIN);
    let mut shares = Vec::new();
    let mut speeds = Vec::new();
    let (mut moving, mut moving_points, mut moving_inliers) = (0usize, 0usize, 0usize);
    let mut last = Stamp(0);
    for m in reader.messages_on(&["/ti_mmwave/radar_scan_pcl"]).unwrap() {
        let m = m.unwrap();
        assert!(m.log_time >= last, "file order is time order here");
        last = m.log_time;
        let cloud: PointCloud2 = m.decode().unwrap();
        scans += 1;
        assert_eq!(cloud.header.frame_id, "");
        assert_eq!(Stamp::from(cloud.header.stamp), Stamp(0));
        assert_eq!(
            (cloud.height, cloud.point_step, cloud.is_bigendian),
            (1, 32, false)
        );
        assert_eq!(cloud.row_step, 32 * cloud.width);
        let layout: Vec<(&str, u32, u8, u32)> = cloud
            .fields
            .iter()
            .map(|f| (f.name.as_str(), f.offset, f.datatype, f.count))
            .collect();
        let f32s = PointField::FLOAT32;
        assert_eq!(
            layout,
            [
                ("x", 0, f32s, 1),
                ("y", 4, f32s, 1),
                ("z", 8, f32s, 1),
                ("intensity", 16, f32s, 1),
                ("velocity", 20, f32s, 1)
            ]
        );
        let decoded = decode_detections(&cloud, &fields).unwrap();
        let n = decoded.detections.len();
        assert_eq!(
            n + decoded.skipped_nonfinite + decoded.skipped_zero_range,
            cloud.width as usize
        );
        points += n;
        min_pts = min_pts.min(cloud.width as usize);
        max_pts = max_pts.max(cloud.width as usize);
        for d in &decoded.detections {
            v_min = v_min.min(d.v_r);
            v_max = v_max.max(d.v_r);
        }
        if let Ok(fit) = fit_radar_velocity(
            &decoded.detections,
            FitDims::Auto,
            &[],
            &EgoMotionConfig::default(),
        ) {
            fitted += 1;
            inliers += fit.num_inliers;
            shares.push(fit.num_inliers as f64 / n as f64);
            speeds.push(fit.v_radar.norm());
            if fit.v_radar.norm() > 0.1 {
                moving += 1;
                moving_points += n;
                moving_inliers += fit.num_inliers;
            }
        }
    }
    shares.sort_by(f64::total_cmp);
    speeds.sort_by(f64::total_cmp);
    let share = inliers as f64 / points as f64;
    println!(
        "{scans} scans, {min_pts}-{max_pts} points each, {points} points, velocity {v_min:.2} to \
         {v_max:.2} m/s; ego-motion fitted on {fitted} scans: inlier share {:.3} of all points \
         (per scan: median {:.3}, 10th percentile {:.3}); radar speed median {:.2}, 90th \
         percentile {:.2}, max {:.2} m/s; {moving} scans moving faster than 0.1 m/s, their inlier \
         share {:.3}",
        share,
        shares[shares.len() / 2],
        shares[shares.len() / 10],
        speeds[speeds.len() / 2],
        speeds[speeds.len() * 9 / 10],
        speeds[speeds.len() - 1],
        moving_inliers as f64 / moving_points as f64
    );
    assert_eq!(scans, 412);
    assert_eq!((min_pts, max_pts), (19, 87));
    assert!(
        (v_min + 2.87).abs() < 0.01 && (v_max - 1.50).abs() < 0.01,
        "{v_min} {v_max}"
    );
    assert!(fitted >= 400, "{fitted} of {scans} scans fitted");
    assert!(share > 0.5, "inlier share {share}");
    assert!(moving >= 100, "{moving} moving scans");
    assert!(
        moving_inliers as f64 > 0.5 * moving_points as f64,
        "inlier share of the moving scans {moving_inliers}/{moving_points}"
    );

    // Every IMU message decodes; gravity is about 9.81 m/s^2.
    let mut imu = 0;
    let mut g = Vec::new();
    for m in reader.messages_on(&["/sensor_platform/imu"]).unwrap() {
        let m: Imu = m.unwrap().decode().unwrap();
        imu += 1;
        let a = m.linear_acceleration;
        g.push((a.x * a.x + a.y * a.y + a.z * a.z).sqrt());
    }
    g.sort_by(f64::total_cmp);
    println!("{imu} IMU messages, median |a| {:.3} m/s^2", g[g.len() / 2]);
    assert_eq!(imu, 8270);
    assert!((g[g.len() / 2] - 9.81).abs() < 0.3);
}

/// The TI bag with its preset (`params/examples/rio_iwr6843.yaml`: stamps from the radar's trigger
/// topic, odometry from the radar's Doppler and the IMU's gyro): every scan is stamped from its
/// trigger, on the IMU's clock, and every step of the radar-inertial odometry is fitted; the gyro
/// bias is learned while the rig stands at the start.
#[test]
fn the_ti_bag_gives_radar_inertial_odometry_through_every_scan() {
    let Some(real) = common::real_data() else {
        return;
    };
    let path = real.join("rio-ti-mmwave-demo/ti_mmwave_rospkg_demo.bag");
    if !path.is_file() {
        common::skipped(&format!("{} not found", path.display()));
        return;
    }
    let dir = common::scratch("rosbag1", "ti_radar_imu");
    let params = Path::new(env!("CARGO_MANIFEST_DIR")).join("params/examples/rio_iwr6843.yaml");
    let tum = dir.join("odometry.tum");
    let o = run_dc_loc(
        &[
            "run",
            "--bag",
            path.to_str().unwrap(),
            "--params",
            params.to_str().unwrap(),
            "--out",
            dir.join("closures.jsonl").to_str().unwrap(),
            "--odometry-out",
            tum.to_str().unwrap(),
            "--quiet-config",
        ],
        "warn",
    );
    let (stdout, stderr) = (text(&o.stdout), text(&o.stderr));
    assert!(o.status.success(), "{stderr}");
    println!("{stdout}");
    for line in [
        "inputs: 412 radar clouds, 0 odometry; skipped messages: none",
        "dropped inputs: none",
        "radar odometry: 412 steps, coasted none; scans fitted 412, refused none; late scans 0",
        "gyro: 8270 samples, 0 saturated, 0 out of order, 0 not finite; 0 steps without gyro coverage",
        "odometry samples 413",
    ] {
        assert!(stdout.contains(line), "`{line}` not in\n{stdout}");
    }
    let bias = stdout
        .lines()
        .find_map(|l| {
            l.split_once("; bias ")?
                .1
                .split_once(" rad/s")?
                .0
                .split_once(" +- ")
        })
        .map(|(b, s)| (b.parse::<f64>().unwrap(), s.parse::<f64>().unwrap()))
        .expect("a bias line");
    assert!(bias.1 < 0.002, "bias {bias:?}");
    // The samples are on the IMU's clock (the log times run 3.9 days later) and cover the 40 s.
    // Each line: stamp, x, y, z, qx, qy, qz, qw.
    let samples: Vec<Vec<f64>> = std::fs::read_to_string(&tum)
        .unwrap()
        .lines()
        .map(|l| l.split(' ').map(|v| v.parse().unwrap()).collect())
        .collect();
    let stamps: Vec<f64> = samples.iter().map(|s| s[0]).collect();
    assert_eq!(stamps.len(), 413);
    // What the track looks like (the bag has no ground truth): its length, where it ends, and how far
    // the heading turns while the rig stands at the start.
    let path: f64 = samples
        .windows(2)
        .map(|w| (w[1][1] - w[0][1]).hypot(w[1][2] - w[0][2]))
        .sum();
    let end = samples[412][1].hypot(samples[412][2]);
    let standing = samples
        .iter()
        .take_while(|s| s[0] - stamps[0] <= 11.6)
        .last()
        .unwrap();
    let heading = 2.0 * standing[6].atan2(standing[7]);
    println!(
        "odometry: {path:.2} m of path, ends {end:.2} m from its start; heading {:.2} deg after \
         {:.1} s standing",
        heading.to_degrees(),
        standing[0] - stamps[0]
    );
    assert!(heading.to_degrees().abs() < 1.5, "heading {heading}");
    assert!(
        (stamps[0] - 1_631_895_354.028).abs() < 0.001,
        "{}",
        stamps[0]
    );
    assert!(
        (stamps[412] - stamps[0] - 40.2).abs() < 0.3,
        "{}",
        stamps[412]
    );
}
