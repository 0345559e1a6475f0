//! rosbag2 MCAP bags and ROS 2 CDR (crates/io/src/bag) against independent truth:
//! - CDR bytes made by the Python rosbags library (tests/fixtures/cdr_fixtures.json, from
//!   tests/python/make_cdr_fixtures.py), byte for byte, both endiannesses;
//! - a bag written by rosbags (tests/fixtures/rosbags_bag, from tests/python/make_rosbags_bag.py);
//! - rosbags reading the bags written here (tests/python/check_bag_with_rosbags.py) in the ROS 2 test
//!   venv (tests/python/setup_venv.sh, made on first use);
//! - rosbag2's schema layout rules, worked out by hand for the known types.
//!
//! Plus round trips of every message type, truncated and corrupted files (errors, never panics),
//! per-message decode failures that do not stop iteration, and byte-identical output.

#[path = "python/venv.rs"]
mod venv;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use dc_loc::bag::{
    self, BagError, BagMessage, BagReader, BagWriter, Durability, QosProfile, Reliability, schema,
};
use dc_loc::math::Stamp;
use dc_loc::msgs::builtin_interfaces::Time;
use dc_loc::msgs::dc_loc::LoopClosure;
use dc_loc::msgs::geometry_msgs::{
    Point, Pose, PoseWithCovariance, Quaternion, Transform, TransformStamped, Twist,
    TwistWithCovariance, Vector3,
};
use dc_loc::msgs::nav_msgs::Odometry;
use dc_loc::msgs::rosgraph_msgs::Clock;
use dc_loc::msgs::sensor_msgs::{Imu, PointCloud2, PointField};
use dc_loc::msgs::std_msgs::Header;
use dc_loc::msgs::tf2_msgs::TFMessage;
use serde::Serialize;
use serde::de::DeserializeOwned;
use serde_json::{Value, json};

mod common;

const REPO: &str = env!("CARGO_MANIFEST_DIR");

fn fixture(name: &str) -> PathBuf {
    Path::new(REPO).join("tests/fixtures").join(name)
}

/// A fresh empty scratch directory under the target directory.
fn scratch(name: &str) -> PathBuf {
    common::scratch("bag_tests", name)
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

// ---------------------------------------------------------------------------------------------------
// CDR against rosbags

fn load_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Encodes the case's message and compares with rosbags' bytes; decodes rosbags' little- and
/// big-endian bytes and compares with the message.
fn check_cdr_case<T>(case: &Value)
where
    T: Serialize + DeserializeOwned + PartialEq + std::fmt::Debug,
{
    let name = case["name"].as_str().unwrap();
    let msg: T = serde_json::from_value(case["msg"].clone()).unwrap();
    let le = unhex(case["cdr_hex"].as_str().unwrap());
    let be = unhex(case["cdr_be_hex"].as_str().unwrap());
    let encoded = bag::encode(&msg).unwrap();
    assert_eq!(
        hex(&encoded),
        hex(&le),
        "{name}: encoded CDR differs from rosbags"
    );
    assert_eq!(bag::decode::<T>(&le).unwrap(), msg, "{name}: little endian");
    assert_eq!(bag::decode::<T>(&be).unwrap(), msg, "{name}: big endian");
    // ROS 2 writers may pad the end to a multiple of 4 bytes.
    let mut padded = le.clone();
    padded.resize(le.len().div_ceil(4) * 4, 0);
    assert_eq!(bag::decode::<T>(&padded).unwrap(), msg, "{name}: padded");
    // Every cut of the message is an error, never a panic or a wrong value.
    for cut in 0..le.len() {
        if let Ok(v) = bag::decode::<T>(&le[..cut]) {
            panic!("{name}: {cut} of {} bytes decoded to {v:?}", le.len());
        }
    }
}

/// Runs `check` with the Rust type of a ROS type name.
macro_rules! with_type {
    ($type_name:expr, $check:ident, $arg:expr) => {
        match $type_name {
            schema::POINT_CLOUD2 => $check::<PointCloud2>($arg),
            schema::ODOMETRY => $check::<Odometry>($arg),
            schema::IMU => $check::<Imu>($arg),
            schema::TF_MESSAGE => $check::<TFMessage>($arg),
            schema::CLOCK => $check::<Clock>($arg),
            schema::HEADER => $check::<Header>($arg),
            schema::LOOP_CLOSURE => $check::<LoopClosure>($arg),
            other => panic!("no Rust type for {other}"),
        }
    };
}

#[test]
fn cdr_is_byte_identical_to_rosbags() {
    let fixtures = load_json(&fixture("cdr_fixtures.json"));
    let cases = fixtures["cases"].as_array().unwrap();
    assert!(cases.len() >= 9);
    let mut types = std::collections::BTreeSet::new();
    for case in cases {
        let type_name = case["type"].as_str().unwrap();
        types.insert(type_name.to_string());
        with_type!(type_name, check_cdr_case, case);
    }
    // Every known top-level type is covered.
    for t in schema::KNOWN_TYPES {
        assert!(types.contains(*t), "no CDR fixture for {t}");
    }
}

#[test]
fn type_hashes_match_rosbags() {
    let fixtures = load_json(&fixture("cdr_fixtures.json"));
    let hashes = fixtures["type_hashes"].as_object().unwrap();
    for (type_name, want) in hashes {
        assert_eq!(
            schema::type_hash(type_name),
            want.as_str(),
            "RIHS01 of {type_name}"
        );
    }
    for t in schema::KNOWN_TYPES {
        assert!(hashes.contains_key(*t), "{t}");
    }
}

// ---------------------------------------------------------------------------------------------------
// Schema texts

/// The `MSG:` lines of a schema, in order.
fn msg_lines(schema_text: &str) -> Vec<&str> {
    schema_text
        .lines()
        .filter_map(|l| l.strip_prefix("MSG: "))
        .collect()
}

#[test]
fn schemas_follow_rosbag2_layout() {
    // Dependencies depth first, each file's dependencies in sorted order, each type once (worked out
    // by hand from rosbag2_cpp's LocalMessageDefinitionSource and the .msg files).
    let want: [(&str, &[&str]); 5] = [
        (
            schema::POINT_CLOUD2,
            &[
                "sensor_msgs/PointField",
                "std_msgs/Header",
                "builtin_interfaces/Time",
            ],
        ),
        (
            schema::ODOMETRY,
            &[
                "geometry_msgs/PoseWithCovariance",
                "geometry_msgs/Pose",
                "geometry_msgs/Point",
                "geometry_msgs/Quaternion",
                "geometry_msgs/TwistWithCovariance",
                "geometry_msgs/Twist",
                "geometry_msgs/Vector3",
                "std_msgs/Header",
                "builtin_interfaces/Time",
            ],
        ),
        (
            schema::TF_MESSAGE,
            &[
                "geometry_msgs/TransformStamped",
                "geometry_msgs/Transform",
                "geometry_msgs/Quaternion",
                "geometry_msgs/Vector3",
                "std_msgs/Header",
                "builtin_interfaces/Time",
            ],
        ),
        (schema::CLOCK, &["builtin_interfaces/Time"]),
        (
            schema::LOOP_CLOSURE,
            &[
                "builtin_interfaces/Time",
                "geometry_msgs/Pose",
                "geometry_msgs/Point",
                "geometry_msgs/Quaternion",
                "geometry_msgs/PoseWithCovariance",
                "std_msgs/Header",
            ],
        ),
    ];
    let separator = format!("\n{}\nMSG: ", "=".repeat(80));
    for (type_name, deps) in want {
        let text = schema::ros2msg_schema(type_name).unwrap();
        assert_eq!(msg_lines(&text), deps, "{type_name}");
        // Each MSG line is preceded by exactly the separator.
        assert_eq!(text.matches(&separator).count(), deps.len(), "{type_name}");
    }
    // The root text is the .msg file verbatim, comments included.
    let pc2 = schema::ros2msg_schema(schema::POINT_CLOUD2).unwrap();
    assert!(pc2.starts_with("# This message holds a collection of N-dimensional points"));
    assert!(pc2.contains("uint8[] data         # Actual point data, size is (row_step*height)\n"));
    assert!(pc2.contains("\nMSG: sensor_msgs/PointField\n# This message holds the description"));
}

#[test]
fn loop_closure_definition_matches_the_interface_package() {
    let text = schema::ros2msg_schema(schema::LOOP_CLOSURE).unwrap();
    let root = text.split(&format!("\n{}", "=".repeat(80))).next().unwrap();
    assert!(root.starts_with("std_msgs/Header header "));
    assert!(root.ends_with("float64 score\n"));
    // Once msg/LoopClosure.msg is in the repository, the schema must carry it verbatim.
    let msg_file = Path::new(REPO).join("msg/LoopClosure.msg");
    if msg_file.exists() {
        assert_eq!(root, std::fs::read_to_string(msg_file).unwrap());
    }
}

// ---------------------------------------------------------------------------------------------------
// A drive with every message type

fn header(t: Stamp, frame: &str) -> Header {
    Header {
        stamp: Time::from(t),
        frame_id: frame.to_string(),
    }
}

fn pose(x: f64, y: f64, yaw_quarter: f64) -> Pose {
    Pose {
        position: Point { x, y, z: 0.25 },
        orientation: Quaternion {
            x: 0.0,
            y: 0.0,
            z: yaw_quarter,
            w: 0.5,
        },
    }
}

fn covariance(scale: f64) -> [f64; 36] {
    std::array::from_fn(|i| scale * (i as f64 - 17.0))
}

/// A radar cloud; `kind` picks one of a few odd layouts.
fn cloud(t: Stamp, kind: usize) -> PointCloud2 {
    let field = |name: &str, offset, datatype, count| PointField {
        name: name.to_string(),
        offset,
        datatype,
        count,
    };
    match kind % 3 {
        // Packed 43-byte nuScenes record, two points.
        0 => PointCloud2 {
            header: header(t, "radar_front"),
            height: 1,
            width: 2,
            fields: vec![
                field("x", 0, PointField::FLOAT32, 1),
                field("y", 4, PointField::FLOAT32, 1),
                field("z", 8, PointField::FLOAT32, 1),
                field("dyn_prop", 12, PointField::INT8, 1),
                field("id", 13, PointField::INT16, 1),
                field("rcs", 15, PointField::FLOAT32, 1),
            ],
            is_bigendian: false,
            point_step: 43,
            row_step: 86,
            data: (0..86).map(|i| (i * 37 + kind) as u8).collect(),
            is_dense: true,
        },
        // Empty cloud with an empty frame.
        1 => PointCloud2 {
            header: header(t, ""),
            ..Default::default()
        },
        // Organized, float64 with count 3, big-endian flag.
        _ => PointCloud2 {
            header: header(t, "rädar_ß"),
            height: 3,
            width: 1,
            fields: vec![field("xyz", 0, PointField::FLOAT64, 3)],
            is_bigendian: true,
            point_step: 24,
            row_step: 24,
            data: (0..72).map(|i| (255 - i) as u8).collect(),
            is_dense: false,
        },
    }
}

fn odometry(t: Stamp, i: usize) -> Odometry {
    Odometry {
        header: header(t, "odom"),
        child_frame_id: "base_link".to_string(),
        pose: PoseWithCovariance {
            pose: pose(i as f64 * 1.5, -0.5 * i as f64, 0.5),
            covariance: covariance(0.125),
        },
        twist: TwistWithCovariance {
            twist: Twist {
                linear: Vector3 {
                    x: 10.0,
                    y: 0.0,
                    z: 0.0,
                },
                angular: Vector3 {
                    x: 0.0,
                    y: 0.0,
                    z: 0.0625 * i as f64,
                },
            },
            covariance: covariance(-1.0),
        },
    }
}

fn tf_static() -> TFMessage {
    let tf = |child: &str, x: f64, yaw_z: f64| TransformStamped {
        header: header(Stamp(0), "base_link"),
        child_frame_id: child.to_string(),
        transform: Transform {
            translation: Vector3 { x, y: 0.5, z: 0.5 },
            rotation: Quaternion {
                x: 0.0,
                y: 0.0,
                z: yaw_z,
                w: 1.0,
            },
        },
    };
    TFMessage {
        transforms: vec![
            tf("radar_front", 3.5, 0.0),
            tf("radar_back_left", -0.5, 1.0),
        ],
    }
}

fn loop_closure(t: Stamp) -> LoopClosure {
    LoopClosure {
        header: header(t, "base_link"),
        query_id: 42,
        match_id: 7,
        query_robot: 1,
        match_robot: 2,
        query_stamp: Time::from(t),
        match_stamp: Time::from(Stamp(t.0 - 60_000_000_000)),
        query_odom_pose: pose(100.0, 20.0, 0.5),
        match_odom_pose: pose(99.5, 20.5, -0.5),
        relative_pose: PoseWithCovariance {
            pose: pose(0.5, -0.5, 0.0),
            covariance: covariance(1.0 / 1024.0),
        },
        inliers: 61,
        score: 0.75,
    }
}

/// One written message: topic, type, stamp, the message as JSON (the form rosbags compares) and a
/// closure that checks a read-back message field by field.
struct Written {
    topic: &'static str,
    type_name: &'static str,
    stamp: Stamp,
    json: Value,
    check: Box<dyn Fn(&BagMessage)>,
}

fn written<T>(topic: &'static str, type_name: &'static str, stamp: Stamp, msg: T) -> Written
where
    T: Serialize + DeserializeOwned + PartialEq + std::fmt::Debug + 'static,
{
    let json = serde_json::to_value(&msg).unwrap();
    Written {
        topic,
        type_name,
        stamp,
        json,
        check: Box::new(move |m: &BagMessage| {
            assert_eq!(
                m.decode::<T>().unwrap(),
                msg,
                "{} at {:?}",
                m.topic(),
                m.log_time
            )
        }),
    }
}

const T0: i64 = 1_700_000_000_000_000_000;

/// The drive: every type, some messages written out of time order, no two at the same time.
fn drive() -> Vec<Written> {
    let ms = |m: i64| Stamp(T0 + m * 1_000_000);
    let mut out = vec![written(
        "/tf_static",
        schema::TF_MESSAGE,
        ms(0),
        tf_static(),
    )];
    for i in 0..6 {
        out.push(written(
            "/clock",
            schema::CLOCK,
            ms(100 * i as i64 + 1),
            Clock {
                clock: Time::from(ms(100 * i as i64 + 1)),
            },
        ));
        out.push(written(
            "/radar_front",
            schema::POINT_CLOUD2,
            ms(100 * i as i64 + 40),
            cloud(ms(100 * i as i64 + 40), i),
        ));
        out.push(written(
            "/odom",
            schema::ODOMETRY,
            ms(100 * i as i64 + 20),
            odometry(ms(100 * i as i64 + 20), i),
        ));
    }
    // Late arrivals: written after later messages.
    out.push(written(
        "/loop_closures",
        schema::LOOP_CLOSURE,
        ms(350),
        loop_closure(ms(350)),
    ));
    out.push(written(
        "/tf",
        schema::TF_MESSAGE,
        ms(30),
        TFMessage {
            transforms: vec![TransformStamped {
                header: header(ms(30), "odom"),
                child_frame_id: "base_link".to_string(),
                transform: Transform::default(),
            }],
        },
    ));
    out
}

fn write_bag(dir: &Path, messages: &[Written]) -> PathBuf {
    let mut writer = BagWriter::create(dir).unwrap();
    let mut ids = BTreeMap::new();
    for m in messages {
        if !ids.contains_key(m.topic) {
            ids.insert(m.topic, writer.add_topic(m.topic, m.type_name).unwrap());
        }
    }
    for m in messages {
        let id = ids[m.topic];
        match m.type_name {
            schema::POINT_CLOUD2 => writer.write(id, m.stamp, &from_json::<PointCloud2>(m)),
            schema::ODOMETRY => writer.write(id, m.stamp, &from_json::<Odometry>(m)),
            schema::TF_MESSAGE => writer.write(id, m.stamp, &from_json::<TFMessage>(m)),
            schema::CLOCK => writer.write(id, m.stamp, &from_json::<Clock>(m)),
            schema::LOOP_CLOSURE => writer.write(id, m.stamp, &from_json::<LoopClosure>(m)),
            other => panic!("{other}"),
        }
        .unwrap();
    }
    writer.finish().unwrap()
}

fn from_json<T: DeserializeOwned>(m: &Written) -> T {
    serde_json::from_value(m.json.clone()).unwrap()
}

/// Expected topics: name -> (type, count).
fn expected_topics(messages: &[Written]) -> BTreeMap<&'static str, (&'static str, u64)> {
    let mut topics = BTreeMap::new();
    for m in messages {
        topics.entry(m.topic).or_insert((m.type_name, 0)).1 += 1;
    }
    topics
}

/// Reads every message and checks it against `messages`: log-time order, every field.
fn check_read_back(reader: &BagReader, messages: &[Written]) {
    let mut want: Vec<&Written> = messages.iter().collect();
    want.sort_by_key(|m| m.stamp);
    let got: Vec<BagMessage> = reader.messages().unwrap().map(Result::unwrap).collect();
    assert_eq!(got.len(), want.len());
    for (g, w) in got.iter().zip(&want) {
        assert_eq!(
            (g.topic(), g.type_name(), g.log_time, g.publish_time),
            (w.topic, w.type_name, w.stamp, w.stamp)
        );
        assert_eq!(g.message_encoding(), "cdr");
        (w.check)(g);
    }
}

#[test]
fn round_trip_of_every_message_type() {
    let messages = drive();
    let dir = write_bag(&scratch("round_trip").join("drive"), &messages);

    // The layout `ros2 bag record -s mcap` makes.
    let mut entries: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    entries.sort();
    assert_eq!(entries, ["drive_0.mcap", "metadata.yaml"]);

    for path in [dir.clone(), dir.join("drive_0.mcap")] {
        let reader = BagReader::open(&path).unwrap();
        let want = expected_topics(&messages);
        let got: BTreeMap<&str, (&str, u64)> = reader
            .topics()
            .iter()
            .map(|t| (t.name.as_str(), (t.type_name.as_str(), t.message_count)))
            .collect();
        assert_eq!(got, want);
        for t in reader.topics() {
            assert_eq!(t.message_encoding, "cdr");
            assert_eq!(t.schema_encoding, "ros2msg");
            assert_eq!(
                String::from_utf8(t.schema.clone()).unwrap(),
                schema::ros2msg_schema(&t.type_name).unwrap()
            );
        }
        assert_eq!(reader.message_count(), messages.len() as u64);
        let first = messages.iter().map(|m| m.stamp).min().unwrap();
        let last = messages.iter().map(|m| m.stamp).max().unwrap();
        assert_eq!(reader.time_range(), Some((first, last)));
        check_read_back(&reader, &messages);

        // Topic filter.
        let odom: Vec<BagMessage> = reader
            .messages_on(&["/odom"])
            .unwrap()
            .map(Result::unwrap)
            .collect();
        assert_eq!(odom.len(), 6);
        assert!(odom.iter().all(|m| m.topic() == "/odom"));
        assert!(odom.windows(2).all(|w| w[0].log_time < w[1].log_time));
        let two = reader
            .messages_on(&["/tf_static", "/loop_closures"])
            .unwrap();
        assert_eq!(two.map(Result::unwrap).count(), 2);
        assert_eq!(reader.messages_on(&["/nope"]).unwrap().count(), 0);
    }
}

#[test]
fn metadata_yaml_is_rosbag2_version_9() {
    let messages = drive();
    let dir = write_bag(&scratch("metadata").join("meta_bag"), &messages);
    let text = std::fs::read_to_string(dir.join("metadata.yaml")).unwrap();
    // Parsed by an independent YAML parser.
    let yaml: yaml_serde::Value = yaml_serde::from_str(&text).unwrap();
    let info = &yaml["rosbag2_bagfile_information"];
    assert_eq!(info["version"].as_u64(), Some(9));
    assert_eq!(info["storage_identifier"].as_str(), Some("mcap"));
    assert_eq!(info["message_count"].as_u64(), Some(messages.len() as u64));
    let first = messages.iter().map(|m| m.stamp.0).min().unwrap();
    let last = messages.iter().map(|m| m.stamp.0).max().unwrap();
    assert_eq!(
        info["starting_time"]["nanoseconds_since_epoch"].as_i64(),
        Some(first)
    );
    assert_eq!(info["duration"]["nanoseconds"].as_i64(), Some(last - first));
    assert_eq!(info["compression_mode"].as_str(), Some(""));
    assert_eq!(
        info["relative_file_paths"][0].as_str(),
        Some("meta_bag_0.mcap")
    );
    assert_eq!(info["files"][0]["path"].as_str(), Some("meta_bag_0.mcap"));
    assert_eq!(
        info["files"][0]["message_count"].as_u64(),
        Some(messages.len() as u64)
    );
    let topics = info["topics_with_message_count"].as_sequence().unwrap();
    let want = expected_topics(&messages);
    assert_eq!(topics.len(), want.len());
    for t in topics {
        let meta = &t["topic_metadata"];
        let name = meta["name"].as_str().unwrap();
        let (type_name, count) = want[name];
        assert_eq!(meta["type"].as_str(), Some(type_name));
        assert_eq!(t["message_count"].as_u64(), Some(count));
        assert_eq!(meta["serialization_format"].as_str(), Some("cdr"));
        assert_eq!(
            meta["type_description_hash"].as_str(),
            schema::type_hash(type_name)
        );
        let qos = &meta["offered_qos_profiles"][0];
        assert_eq!(qos["reliability"].as_str(), Some("reliable"));
        let durability = if name == "/tf_static" {
            "transient_local"
        } else {
            "volatile"
        };
        assert_eq!(qos["durability"].as_str(), Some(durability));
        assert_eq!(qos["deadline"]["sec"].as_i64(), Some(9_223_372_036));
    }
}

#[test]
fn identical_input_gives_identical_files() {
    let messages = drive();
    let a = write_bag(&scratch("determinism_a").join("drive"), &messages);
    let b = write_bag(&scratch("determinism_b").join("drive"), &messages);
    for name in ["drive_0.mcap", "metadata.yaml"] {
        let (fa, fb) = (
            std::fs::read(a.join(name)).unwrap(),
            std::fs::read(b.join(name)).unwrap(),
        );
        assert!(
            fa == fb,
            "{name} differs between two writes of the same drive"
        );
    }
    // ...and a different drive gives a different file (the comparison can fail).
    let mut other = drive();
    other.pop();
    let c = write_bag(&scratch("determinism_c").join("drive"), &other);
    assert_ne!(
        std::fs::read(a.join("drive_0.mcap")).unwrap(),
        std::fs::read(c.join("drive_0.mcap")).unwrap()
    );
}

// ---------------------------------------------------------------------------------------------------
// rosbags <-> dc_loc

#[test]
fn reads_a_bag_written_by_rosbags() {
    let expected = load_json(&fixture("rosbags_bag_expected.json"));
    let reader = BagReader::open(&fixture("rosbags_bag")).unwrap();
    let want: BTreeMap<String, (String, u64)> = expected["topics"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            (
                t["name"].as_str().unwrap().to_string(),
                (
                    t["type"].as_str().unwrap().to_string(),
                    t["count"].as_u64().unwrap(),
                ),
            )
        })
        .collect();
    let got: BTreeMap<String, (String, u64)> = reader
        .topics()
        .iter()
        .map(|t| (t.name.clone(), (t.type_name.clone(), t.message_count)))
        .collect();
    assert_eq!(got, want);

    // Written out of time order; read in time order, every field as rosbags wrote it.
    let messages: Vec<BagMessage> = reader.messages().unwrap().map(Result::unwrap).collect();
    let want = expected["messages"].as_array().unwrap();
    assert_eq!(messages.len(), want.len());
    fn same<T: DeserializeOwned + PartialEq + std::fmt::Debug>((got, want): (&BagMessage, &Value)) {
        let w: T = serde_json::from_value(want["msg"].clone()).unwrap();
        assert_eq!(got.decode::<T>().unwrap(), w, "{}", want["case"]);
    }
    for (m, w) in messages.iter().zip(want) {
        assert_eq!(m.topic(), w["topic"].as_str().unwrap());
        assert_eq!(m.type_name(), w["type"].as_str().unwrap());
        assert_eq!(m.log_time, Stamp(w["log_time"].as_i64().unwrap()));
        with_type!(m.type_name(), same, (m, w));
    }

    // Without its summary (last byte cut) the file is read from start to end: every message, in
    // the order written (rosbags writes chunk CRC 0, which means "not computed").
    let cut = scratch("rosbags_cut").join("rosbags_cut.mcap");
    let full = std::fs::read(fixture("rosbags_bag/rosbags_bag.mcap")).unwrap();
    std::fs::write(&cut, &full[..full.len() - 1]).unwrap();
    let reader = BagReader::open(&cut).unwrap();
    assert_eq!(reader.message_count(), want.len() as u64);
    let items: Vec<Result<BagMessage, BagError>> = reader.messages().unwrap().collect();
    assert_eq!(items.len(), want.len() + 1);
    assert!(matches!(items.last(), Some(Err(BagError::Mcap { .. }))));
    let mut times: Vec<Stamp> = items.iter().flatten().map(|m| m.log_time).collect();
    assert!(
        !times.is_sorted(),
        "file order here is the (unsorted) write order"
    );
    times.sort();
    let want_times: Vec<Stamp> = want
        .iter()
        .map(|w| Stamp(w["log_time"].as_i64().unwrap()))
        .collect();
    assert_eq!(times, want_times);
}

#[test]
fn rosbags_reads_the_bags_written_here() {
    // The ROS 2 test venv (made on first use by tests/python/setup_venv.sh) has rosbags: mandatory.
    let python = venv::venv_python();
    let messages = drive();
    let dir = write_bag(&scratch("rosbags_check").join("py_drive"), &messages);
    let topics: Vec<Value> = expected_topics(&messages)
        .iter()
        .map(|(name, (type_name, count))| {
            let durability = if *name == "/tf_static" {
                "transient_local"
            } else {
                "volatile"
            };
            json!({"name": name, "type": type_name, "count": count,
                   "reliability": "reliable", "durability": durability})
        })
        .collect();
    let expect = json!({
        "topics": topics,
        "start_ns": messages.iter().map(|m| m.stamp.0).min(),
        "end_ns": messages.iter().map(|m| m.stamp.0).max(),
        "messages": messages.iter().map(|m| json!({
            "topic": m.topic, "type": m.type_name, "log_time": m.stamp.0, "msg": m.json,
        })).collect::<Vec<_>>(),
    });
    let expect_path = dir.parent().unwrap().join("expect.json");
    std::fs::write(&expect_path, expect.to_string()).unwrap();
    let script = Path::new(REPO).join("tests/python/check_bag_with_rosbags.py");
    // The bag directory, and the lone .mcap file (read without metadata.yaml).
    for bag in [dir.clone(), dir.join("py_drive_0.mcap")] {
        let out = Command::new(&python)
            .arg(&script)
            .arg(&bag)
            .arg(format!("@{}", expect_path.display()))
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        let stderr = String::from_utf8_lossy(&out.stderr);
        println!("{stdout}{stderr}");
        assert!(
            out.status.success(),
            "rosbags check of {} failed:\n{stdout}{stderr}",
            bag.display()
        );
    }
}

// ---------------------------------------------------------------------------------------------------
// Damage, errors, several files

/// A bag of `n` clouds of about 64 KB each (several MCAP chunks), written in time order.
fn big_drive(n: usize, t0: i64) -> Vec<Written> {
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    (0..n)
        .map(|i| {
            let t = Stamp(t0 + i as i64 * 50_000_000);
            let mut c = cloud(t, 0);
            c.width = 1500;
            c.row_step = 43 * 1500;
            // Pseudo-random bytes (xorshift): they do not compress, so chunks stay large.
            c.data = (0..c.row_step)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state >> 24) as u8
                })
                .collect();
            written("/radar_front", schema::POINT_CLOUD2, t, c)
        })
        .collect()
}

#[test]
fn truncated_or_corrupted_files_give_errors_not_panics() {
    let messages = big_drive(40, T0);
    let dir = write_bag(&scratch("truncate").join("big"), &messages);
    let full = std::fs::read(dir.join("big_0.mcap")).unwrap();
    assert!(full.len() > 2_000_000);
    let cut_dir = scratch("truncate_cuts");
    let len = full.len();
    let cuts = [
        0,
        5,
        8,
        30,
        len / 7,
        len / 3,
        len / 2,
        len - 2000,
        len - 100,
        len - 1,
    ];
    let mut complete_reads = 0;
    for cut in cuts {
        let path = cut_dir.join(format!("cut_{cut}.mcap"));
        std::fs::write(&path, &full[..cut]).unwrap();
        let reader = match BagReader::open(&path) {
            Err(e) => {
                assert!(cut < 8, "cut at {cut}: open failed: {e}");
                assert!(matches!(e, BagError::NotMcap { .. }), "{e}");
                continue;
            }
            Ok(r) => r,
        };
        let mut read = Vec::new();
        let mut errors = 0;
        for item in reader.messages().unwrap() {
            match item {
                Ok(m) => read.push(m),
                Err(e) => {
                    errors += 1;
                    assert!(e.to_string().contains("cut_"), "error names the file: {e}");
                }
            }
        }
        eprintln!(
            "cut at {cut} of {len}: {} messages, {errors} error",
            read.len()
        );
        // Never more than one error (the file then ends), always one: the file is incomplete.
        assert_eq!(errors, 1, "cut at {cut}");
        assert_eq!(reader.message_count(), read.len() as u64, "cut at {cut}");
        // What was read is a prefix of the drive, every field intact.
        for (m, w) in read.iter().zip(&messages) {
            assert_eq!(m.log_time, w.stamp);
            (w.check)(m);
        }
        if read.len() == messages.len() {
            complete_reads += 1;
        }
    }
    // Cutting only the summary loses no message; cutting the middle loses some.
    assert!(complete_reads >= 2, "{complete_reads}");

    // Corrupted bytes in the data section: errors or messages, never a panic.
    for (k, at) in [len / 5, len / 2, len - 3000].into_iter().enumerate() {
        let mut bad = full.clone();
        for (i, b) in bad[at..at + 64].iter_mut().enumerate() {
            *b ^= 0x5a ^ (i as u8);
        }
        let path = cut_dir.join(format!("corrupt_{k}.mcap"));
        std::fs::write(&path, &bad).unwrap();
        if let Ok(reader) = BagReader::open(&path) {
            for m in reader.messages().unwrap().flatten() {
                let _ = m.decode::<PointCloud2>();
            }
        }
    }
}

#[test]
fn a_bad_message_is_reported_and_iteration_goes_on() {
    let dir = scratch("bad_message").join("bad");
    let mut writer = BagWriter::create(&dir).unwrap();
    let radar = writer
        .add_topic("/radar_front", schema::POINT_CLOUD2)
        .unwrap();
    for i in 0..5 {
        let t = Stamp(T0 + i);
        if i == 2 {
            // A cloud cut short: valid header, body too short.
            let good = bag::encode(&cloud(t, 0)).unwrap();
            writer.write_cdr(radar, t, &good[..good.len() / 2]).unwrap();
        } else {
            writer.write(radar, t, &cloud(t, 0)).unwrap();
        }
    }
    writer.finish().unwrap();
    let reader = BagReader::open(&dir).unwrap();
    let (mut ok, mut bad) = (0, Vec::new());
    for m in reader.messages().unwrap() {
        match m.unwrap().decode::<PointCloud2>() {
            Ok(c) => {
                ok += 1;
                assert_eq!(c.width, 2);
            }
            Err(e) => bad.push(e),
        }
    }
    assert_eq!((ok, bad.len()), (4, 1));
    let text = bad[0].to_string();
    assert!(matches!(&bad[0], BagError::Decode { topic, stamp, .. }
            if topic == "/radar_front" && *stamp == Stamp(T0 + 2)));
    assert!(text.contains("/radar_front") && text.contains("sensor_msgs/msg/PointCloud2"));
    assert!(text.contains(&(T0 + 2).to_string()), "{text}");

    // Decoding as the wrong type fails the same way.
    let first = reader.messages().unwrap().next().unwrap().unwrap();
    assert!(matches!(
        first.decode::<Odometry>(),
        Err(BagError::Decode { .. })
    ));
}

#[test]
fn several_files_merge_by_log_time() {
    // Two recordings whose times interleave, as the split files of one bag (no metadata.yaml).
    let early: Vec<Written> = big_drive(3, T0);
    let late: Vec<Written> = big_drive(3, T0 + 25_000_000);
    let a = write_bag(&scratch("split_a").join("a"), &early);
    let b = write_bag(&scratch("split_b").join("b"), &late);
    let dir = scratch("split");
    std::fs::copy(a.join("a_0.mcap"), dir.join("split_0.mcap")).unwrap();
    std::fs::copy(b.join("b_0.mcap"), dir.join("split_1.mcap")).unwrap();
    let reader = BagReader::open(&dir).unwrap();
    assert_eq!(reader.files().len(), 2);
    assert_eq!(reader.topics().len(), 1);
    assert_eq!(reader.topics()[0].message_count, 6);
    let mut all: Vec<&Written> = early.iter().chain(&late).collect();
    all.sort_by_key(|m| m.stamp);
    let got: Vec<BagMessage> = reader.messages().unwrap().map(Result::unwrap).collect();
    assert_eq!(got.len(), 6);
    for (g, w) in got.iter().zip(all) {
        assert_eq!(g.log_time, w.stamp);
        (w.check)(g);
    }
}

#[test]
fn foreign_channels_are_listed_and_refuse_cdr_decoding() {
    // An MCAP file as foxglove tools write it: no ros2 profile, a JSON channel.
    let path = scratch("foreign").join("foxglove.mcap");
    {
        let mut w = mcap::WriteOptions::new()
            .compression(None)
            .create(std::io::BufWriter::new(
                std::fs::File::create(&path).unwrap(),
            ))
            .unwrap();
        let schema_id = w.add_schema("foxglove.Pose", "jsonschema", b"{}").unwrap();
        let ch = w
            .add_channel(schema_id, "/odom", "json", &BTreeMap::new())
            .unwrap();
        let header = mcap::records::MessageHeader {
            channel_id: ch,
            sequence: 0,
            log_time: 5,
            publish_time: 5,
        };
        w.write_to_known_channel(&header, br#"{"x": 1}"#).unwrap();
        w.finish().unwrap();
    }
    let reader = BagReader::open(&path).unwrap();
    let t = reader.topic("/odom").unwrap();
    assert_eq!(
        (
            t.type_name.as_str(),
            t.message_encoding.as_str(),
            t.schema_encoding.as_str(),
            t.message_count
        ),
        ("foxglove.Pose", "json", "jsonschema", 1)
    );
    let m = reader.messages().unwrap().next().unwrap().unwrap();
    assert_eq!(m.data(), br#"{"x": 1}"#);
    assert!(matches!(
        m.decode::<Odometry>(),
        Err(BagError::UnsupportedEncoding { encoding, .. }) if encoding == "json"
    ));
}

#[test]
fn errors_name_what_is_wrong() {
    let root = scratch("errors");
    // Reader.
    assert!(matches!(
        BagReader::open(&root.join("nope")),
        Err(BagError::NotFound { .. })
    ));
    let not_mcap = root.join("notes.mcap");
    std::fs::write(&not_mcap, b"these are not the bytes you are looking for").unwrap();
    let e = BagReader::open(&not_mcap).unwrap_err();
    assert!(matches!(e, BagError::NotMcap { .. }));
    assert!(e.to_string().contains("notes.mcap"));
    let empty = root.join("empty_dir");
    std::fs::create_dir_all(&empty).unwrap();
    assert!(matches!(
        BagReader::open(&empty),
        Err(BagError::NoMcapFiles { .. })
    ));
    let sqlite = root.join("sqlite_bag");
    std::fs::create_dir_all(&sqlite).unwrap();
    std::fs::write(
        sqlite.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n  \
         relative_file_paths:\n    - sqlite_bag_0.db3\n",
    )
    .unwrap();
    let e = BagReader::open(&sqlite).unwrap_err();
    assert!(matches!(e, BagError::Metadata { .. }), "{e}");
    assert!(e.to_string().contains("sqlite3"));

    // Writer.
    let mut w = BagWriter::create(&root.join("w")).unwrap();
    assert!(matches!(
        w.add_topic("/chatter", "std_msgs/msg/String"),
        Err(BagError::UnknownType { .. })
    ));
    assert!(matches!(
        w.add_topic("radar", schema::POINT_CLOUD2),
        Err(BagError::InvalidTopicName { .. })
    ));
    let id = w.add_topic("/clock", schema::CLOCK).unwrap();
    assert!(matches!(
        w.add_topic("/clock", schema::CLOCK),
        Err(BagError::DuplicateTopic { .. })
    ));
    assert!(matches!(
        w.write(id, Stamp(-1), &Clock::default()),
        Err(BagError::NegativeStamp { .. })
    ));
    // Custom QoS goes into the metadata.
    let best_effort = QosProfile {
        reliability: Reliability::BestEffort,
        durability: Durability::Volatile,
    };
    w.add_topic_with_qos("/radar_back", schema::POINT_CLOUD2, best_effort)
        .unwrap();
    let dir = w.finish().unwrap();
    let yaml = std::fs::read_to_string(dir.join("metadata.yaml")).unwrap();
    assert!(yaml.contains("reliability: best_effort"));
    assert!(matches!(
        BagWriter::create(&dir),
        Err(BagError::AlreadyExists { .. })
    ));
    // An empty bag reads back as empty.
    let reader = BagReader::open(&dir).unwrap();
    assert_eq!(reader.message_count(), 0);
    assert_eq!(reader.time_range(), None);
    assert_eq!(reader.messages().unwrap().count(), 0);
}

#[test]
fn an_unfinished_writer_leaves_only_a_temporary_file() {
    let dir = scratch("unfinished").join("crash");
    {
        let mut w = BagWriter::create(&dir).unwrap();
        let id = w.add_topic("/clock", schema::CLOCK).unwrap();
        w.write(id, Stamp(T0), &Clock::default()).unwrap();
        // Dropped without finish (as in a crash after this point).
    }
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert_eq!(names, ["crash_0.mcap.tmp"]);
    assert!(matches!(
        BagReader::open(&dir),
        Err(BagError::NoMcapFiles { .. })
    ));
}

/// A radar with a trigger topic (`radars.<name>.trigger_topic`): each cloud takes the stamp of the
/// newest trigger before it in the bag plus `trigger_delay`, whatever its own stamp; a cloud before any
/// trigger, and a second cloud after one trigger, are refused as `no_trigger` and the stream goes on.
#[test]
fn clouds_take_their_stamps_from_their_radars_trigger() {
    use dc_loc::input::Input;
    use dc_loc::io::rosbag::BagInputs;
    use dc_loc::odometry::OdometrySource;
    use dc_loc::pipeline::Config;
    let log = |ms: i64| Stamp(1_700_000_000_000_000_000 + ms * 1_000_000);
    let sensor = |ms: i64| Stamp(1_000_000_000_000 + ms * 1_000_000);
    let dir = scratch("trigger").join("bag");
    let mut w = BagWriter::create(&dir).unwrap();
    let radar = w.add_topic("/radar/points", schema::POINT_CLOUD2).unwrap();
    let trigger = w.add_topic("/radar/trigger", schema::HEADER).unwrap();
    let zero_stamped = || cloud(Stamp(0), 1);
    w.write(radar, log(10), &zero_stamped()).unwrap();
    w.write(trigger, log(20), &header(sensor(0), "trigger"))
        .unwrap();
    w.write(radar, log(50), &zero_stamped()).unwrap();
    w.write(radar, log(60), &cloud(log(60), 1)).unwrap();
    w.write(trigger, log(120), &header(sensor(100), "trigger"))
        .unwrap();
    w.write(radar, log(150), &cloud(log(150), 1)).unwrap();
    let reader = BagReader::open(&w.finish().unwrap()).unwrap();

    let mut cfg = Config::default();
    cfg.odometry.source = OdometrySource::Radar;
    let front = cfg.radars.get_mut("front").unwrap();
    front.topic = "/radar/points".into();
    front.frame_id = String::new();
    front.trigger_topic = "/radar/trigger".into();
    front.trigger_delay = 0.01;
    let got: Vec<Result<Stamp, &str>> = BagInputs::new(&reader, &cfg, None)
        .unwrap()
        .map(|item| match item {
            Ok(input @ Input::Radar { .. }) => Ok(input.stamp()),
            Ok(other) => panic!("{other:?}"),
            Err(issue) => Err(issue.reason.name()),
        })
        .collect();
    assert_eq!(
        got,
        [
            Err("no_trigger"),
            Ok(sensor(10)),
            Err("no_trigger"),
            Ok(sensor(110)),
        ]
    );

    // A trigger topic missing from the bag is named by its parameter.
    cfg.radars.get_mut("front").unwrap().trigger_topic = "/elsewhere".into();
    let e = BagInputs::new(&reader, &cfg, None).err().expect("refused");
    assert!(e.to_string().contains("radars.front.trigger_topic"), "{e}");
}
