//! The fuzz targets' bodies (fuzz/bodies.rs) on stable Rust, in the normal `cargo test`: every file of
//! `fuzz/corpus/<target>/` (the seeds) and `fuzz/regressions/<target>/` (inputs that once crashed a
//! target), then deterministic pseudo-random mutations of them. A panic in a body, or a body holding
//! more than 512 MiB at once (counted by this test's global allocator, as the fuzzer's memory limits),
//! fails the test and names the input (mutated ones are written out so that they can become
//! regression files).
//!
//! Also checks that the seeds still reach the deep paths (a seed map still loads, a seed bag still has
//! messages...), so that a format change cannot silently turn the corpus into noise, and that the
//! `pointcloud2` input format reads back what it writes.
//!
//! The seeds are made by the ignored test `write_seed_corpus` (the `rosbag1` ones by
//! tests/python/ros1_bags.py in the ROS 2 test venv, which it runs):
//! `cargo test --test fuzz_regressions -- --ignored write_seed_corpus`.

#[allow(dead_code)]
#[path = "../fuzz/bodies.rs"]
mod bodies;
#[path = "python/venv.rs"]
mod venv;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use dc_loc::bag::{BagReader, BagWriter, schema};
use dc_loc::cloud::{CloudLayout, FieldRole, LayoutField, decode_detections, encode_detections};
use dc_loc::fleet::{FleetState, SharedAlignment};
use dc_loc::input::InputLimits;
use dc_loc::io::nuscenes_pcd::{NuscenesRadarPcd, nuscenes_fields_config};
use dc_loc::keyframe_db::{
    KeyframeDb, KeyframeRecord, RecordV4, quantise_cov, quantise_point, quantise_ray, save_records,
};
use dc_loc::loop_closure::Alignment;
use dc_loc::math::{Iso2, Mat2, Stamp, Vec2, Vec3};
use dc_loc::msgs::geometry_msgs::{Quaternion, TransformStamped};
use dc_loc::msgs::nav_msgs::Odometry;
use dc_loc::msgs::sensor_msgs::{PointCloud2, PointField};
use dc_loc::msgs::std_msgs::Header;
use dc_loc::msgs::tf2_msgs::TFMessage;
use dc_loc::pipeline::Config;
use dc_loc::place::{PlaceConfig, PlaceDescriptor};
use dc_loc::radar::{Detection, FieldsConfig};
use dc_loc::sim::export::{GROUND_TRUTH_TOPIC, TF_STATIC_TOPIC};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

use bodies::{FieldsChoice, cloud_from_bytes, cloud_to_bytes};

/// Mutated inputs run per target.
const MUTATIONS: usize = 5000;
/// Most bytes a body may hold at once on one input (the fuzz runs' `-malloc_limit_mb` and
/// `-rss_limit_mb`).
const MAX_PEAK_BYTES: usize = 512 << 20;

/// The system allocator, counting the bytes each thread holds and their peak, so that a body's peak
/// allocation on one input can be checked on stable Rust as the fuzzer's memory limits check it.
struct CountingAllocator;

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

thread_local! {
    static LIVE_BYTES: Cell<usize> = const { Cell::new(0) };
    static PEAK_BYTES: Cell<usize> = const { Cell::new(0) };
}

fn count_alloc(bytes: usize) {
    let _ = LIVE_BYTES.try_with(|live| {
        let now = live.get().saturating_add(bytes);
        live.set(now);
        let _ = PEAK_BYTES.try_with(|peak| peak.set(peak.get().max(now)));
    });
}

fn count_free(bytes: usize) {
    // Memory freed by another thread than the one that allocated it only lowers this one's count.
    let _ = LIVE_BYTES.try_with(|live| live.set(live.get().saturating_sub(bytes)));
}

// SAFETY: every call goes to `System` unchanged; the counting touches only const-initialised
// thread-locals, which never allocate.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            count_alloc(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            count_alloc(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        count_free(layout.size());
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            count_free(layout.size());
            count_alloc(new_size);
        }
        p
    }
}

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz")
}

/// The files of `fuzz/<kind>/<target>/`, sorted by name (none when the directory does not exist).
fn files(kind: &str, target: &str) -> Vec<(PathBuf, Vec<u8>)> {
    let dir = fuzz_dir().join(kind).join(target);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let mut paths: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    paths.sort();
    paths
        .into_iter()
        .map(|p| {
            let bytes = std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            (p, bytes)
        })
        .collect()
}

fn body(target: &str) -> fn(&[u8]) {
    bodies::TARGETS
        .iter()
        .find(|(name, _)| *name == target)
        .unwrap_or_else(|| panic!("no fuzz target {target}"))
        .1
}

/// One mutation of `input` (as libFuzzer's common ones: bit flips, interesting values, inserted,
/// erased, duplicated or spliced ranges, truncation).
fn mutate(input: &mut Vec<u8>, other: &[u8], rng: &mut StdRng) {
    const INTERESTING: [u32; 10] = [
        0,
        1,
        2,
        0x7F,
        0x80,
        0xFF,
        0xFFFF,
        0x7FFF_FFFF,
        0x8000_0000,
        0xFFFF_FFFF,
    ];
    if input.is_empty() {
        input.push(rng.random());
        return;
    }
    let at = rng.random_range(0..input.len());
    match rng.random_range(0..8u8) {
        0 => input[at] ^= 1 << rng.random_range(0..8),
        1 => input[at] = rng.random(),
        2 => {
            let v = INTERESTING[rng.random_range(0..INTERESTING.len())];
            let width = [1usize, 2, 4][rng.random_range(0..3)];
            let bytes = if rng.random() {
                v.to_le_bytes()
            } else {
                v.to_be_bytes()
            };
            for (k, b) in bytes.iter().take(width).enumerate() {
                if let Some(slot) = input.get_mut(at + k) {
                    *slot = *b;
                }
            }
        }
        3 => {
            let n = rng.random_range(1..=8);
            for _ in 0..n {
                input.insert(at, rng.random());
            }
        }
        4 => {
            let end = (at + rng.random_range(1..=16)).min(input.len());
            input.drain(at..end);
        }
        5 => {
            let end = (at + rng.random_range(1..=32)).min(input.len());
            let copy: Vec<u8> = input[at..end].to_vec();
            let to = rng.random_range(0..=input.len());
            input.splice(to..to, copy);
        }
        6 if !other.is_empty() => {
            let from = rng.random_range(0..other.len());
            let end = (from + rng.random_range(1..=64)).min(other.len());
            let to_end = (at + (end - from)).min(input.len());
            input.splice(at..to_end, other[from..end].iter().copied());
        }
        _ => input.truncate(at),
    }
}

/// Runs `body` on `input`; a panic becomes its message, and so does a peak allocation over
/// [`MAX_PEAK_BYTES`].
fn run(body: fn(&[u8]), input: &[u8]) -> Result<(), String> {
    let start = LIVE_BYTES.with(Cell::get);
    PEAK_BYTES.with(|p| p.set(start));
    catch_unwind(AssertUnwindSafe(|| body(input))).map_err(|p| {
        p.downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "non-string panic".into())
    })?;
    let peak = PEAK_BYTES.with(Cell::get).saturating_sub(start);
    if peak > MAX_PEAK_BYTES {
        return Err(format!(
            "held {} MiB at once (limit {} MiB)",
            peak >> 20,
            MAX_PEAK_BYTES >> 20
        ));
    }
    Ok(())
}

/// The seeds and regression files of `target`, then [`MUTATIONS`] mutations of the seeds (1 to 4
/// each), through its body; fails naming every input that panicked or held too much memory.
/// Regression inputs are not mutated: many are allocation bombs, whose mutants would mostly be slow
/// bombs too.
fn check_target(target: &str) {
    let body = body(target);
    let seeds = files("corpus", target);
    assert!(
        !seeds.is_empty(),
        "fuzz/corpus/{target}/ holds no seed (see write_seed_corpus)"
    );
    let mut failures = Vec::new();
    for (path, bytes) in seeds.iter().chain(&files("regressions", target)) {
        if let Err(msg) = run(body, bytes) {
            failures.push(format!("{}: {msg}", path.display()));
        }
    }
    let out_dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("fuzz_regressions")
        .join(target);
    // One fixed seed per target, so that a failure reproduces run after run.
    let seed = target
        .bytes()
        .fold(0u64, |h, b| h.wrapping_mul(131) ^ u64::from(b));
    let mut rng = StdRng::seed_from_u64(seed);
    for i in 0..MUTATIONS {
        let mut input = seeds[rng.random_range(0..seeds.len())].1.clone();
        let other = &seeds[rng.random_range(0..seeds.len())].1;
        for _ in 0..rng.random_range(1..=4) {
            mutate(&mut input, other, &mut rng);
        }
        if let Err(msg) = run(body, &input) {
            let _ = std::fs::create_dir_all(&out_dir);
            let path = out_dir.join(format!("mutation-{i}"));
            let _ = std::fs::write(&path, &input);
            failures.push(format!(
                "mutation {i} (written to {}): {msg}",
                path.display()
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "fuzz target {target} panicked on {} input(s) (copy a file into fuzz/regressions/{target}/ \
         to keep it):\n{}",
        failures.len(),
        failures.join("\n")
    );
}

#[test]
fn pointcloud2() {
    check_target("pointcloud2");
}

#[test]
fn cdr() {
    check_target("cdr");
}

#[test]
fn bag_reader() {
    check_target("bag_reader");
}

#[test]
fn rosbag1() {
    check_target("rosbag1");
}

#[test]
fn pcd() {
    check_target("pcd");
}

#[test]
fn keyframe_map() {
    check_target("keyframe_map");
}

/// Every target has a corpus directory, and nothing else sits in `fuzz/corpus/`.
#[test]
fn corpus_directories_are_the_targets() {
    let mut dirs: Vec<String> = std::fs::read_dir(fuzz_dir().join("corpus"))
        .expect("fuzz/corpus")
        .filter_map(|e| e.ok())
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    dirs.sort();
    let mut targets: Vec<String> = bodies::TARGETS.iter().map(|(n, _)| n.to_string()).collect();
    targets.sort();
    assert_eq!(dirs, targets);
}

/// The seeds get past the checks into the code each target is about.
#[test]
fn seeds_reach_the_deep_paths() {
    let decoded_points = files("corpus", "pointcloud2")
        .iter()
        .filter(|(_, b)| {
            let input = cloud_from_bytes(b);
            decode_detections(&input.cloud, &input.fields).is_ok_and(|d| !d.detections.is_empty())
        })
        .count();
    assert!(
        decoded_points >= 3,
        "pointcloud2 seeds decoding to detections: {decoded_points}"
    );

    let cdr = files("corpus", "cdr");
    let clouds = cdr
        .iter()
        .filter(|(_, b)| dc_loc::bag::decode::<PointCloud2>(b).is_ok())
        .count();
    let odoms = cdr
        .iter()
        .filter(|(_, b)| dc_loc::bag::decode::<Odometry>(b).is_ok())
        .count();
    let tfs = cdr
        .iter()
        .filter(|(_, b)| dc_loc::bag::decode::<TFMessage>(b).is_ok())
        .count();
    let keyframes = cdr
        .iter()
        .filter_map(|(_, b)| dc_loc::bag::decode::<dc_loc::msgs::dc_loc::Keyframe>(b).ok())
        .filter(|k| {
            dc_loc::fleet::wire::decode(k, &PlaceConfig::default())
                .is_ok_and(|s| !s.fleet.alignments.is_empty())
        })
        .count();
    assert!(
        clouds >= 2 && odoms >= 1 && tfs >= 1 && keyframes >= 1,
        "cdr seeds: {clouds} clouds, {odoms} odometry, {tfs} tf, {keyframes} keyframes"
    );

    let mut bag_messages = Vec::new();
    for (path, bytes) in files("corpus", "bag_reader") {
        let n = bodies::with_temp_file("seed.mcap", &bytes, |p| {
            let reader = BagReader::open(p).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            reader.messages().unwrap().filter(|m| m.is_ok()).count()
        });
        bag_messages.push(n);
    }
    assert!(
        bag_messages.len() >= 3 && bag_messages.iter().all(|&n| n > 0),
        "messages per bag seed: {bag_messages:?}"
    );

    let mut ros1_messages = Vec::new();
    for (path, bytes) in files("corpus", "rosbag1") {
        let n = bodies::with_temp_file("seed.bag", &bytes, |p| {
            let reader = BagReader::open(p).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            reader.messages().unwrap().filter(|m| m.is_ok()).count()
        });
        ros1_messages.push(n);
    }
    assert!(
        ros1_messages.len() >= 3 && ros1_messages.iter().all(|&n| n > 0),
        "messages per ROS 1 bag seed: {ros1_messages:?}"
    );

    let pcds = files("corpus", "pcd")
        .iter()
        .filter(|(_, b)| NuscenesRadarPcd::from_bytes(b).is_ok_and(|p| !p.points.is_empty()))
        .count();
    assert!(pcds >= 1, "nuScenes PCD seeds: {pcds}");

    let mut maps = Vec::new();
    for (_, bytes) in files("corpus", "keyframe_map") {
        let file = bodies::map_file_from_bytes(&bytes);
        let loaded = bodies::with_temp_file("seed.dcloc", &file, |p| {
            KeyframeDb::load(p, PlaceConfig::default(), 4).map(|db| db.len())
        });
        maps.push(loaded.map_err(|e| e.to_string()));
    }
    assert!(
        maps.len() >= 3 && maps.iter().all(|m| m.as_ref().is_ok_and(|&n| n > 0)),
        "keyframes per map seed: {maps:?}"
    );
}

/// `cloud_to_bytes` writes what `cloud_from_bytes` reads, with every size encoding and name kind.
#[test]
fn cloud_input_format_round_trips() {
    let cloud = PointCloud2 {
        header: Header::default(),
        height: 3,
        width: 0xE0,
        fields: vec![
            PointField {
                name: "x".into(),
                offset: 0x1_0000,
                datatype: 200,
                count: 7,
            },
            PointField {
                name: "a name not in the table".into(),
                offset: 0xDF,
                datatype: 7,
                count: 0xFFFF_FFFF,
            },
        ],
        is_bigendian: true,
        point_step: 0xFFFF,
        row_step: 0,
        data: vec![1, 2, 3],
        is_dense: true,
    };
    let config = FieldsConfig {
        velocity: String::new(),
        velocity_x: "vx".into(),
        velocity_y: "other".into(),
        ..FieldsConfig::default()
    };
    let limits = InputLimits {
        max_cloud_points: 5,
        max_cloud_bytes: 70_000,
    };
    let back = cloud_from_bytes(&cloud_to_bytes(
        &cloud,
        FieldsChoice::Input,
        &config,
        Some(limits),
    ));
    assert_eq!(back.cloud, cloud);
    assert_eq!(back.fields, config);
    assert_eq!(back.limits, limits);
    let back = cloud_from_bytes(&cloud_to_bytes(
        &cloud,
        FieldsChoice::Nuscenes,
        &config,
        None,
    ));
    assert_eq!(back.fields, nuscenes_fields_config());
    assert_eq!(back.limits, InputLimits::default());
}

// ---------------------------------------------------------------------------------------------------
// The seed corpus.

fn detections(n: usize) -> Vec<Detection> {
    (0..n)
        .map(|i| {
            let a = i as f64 * 0.7;
            Detection {
                p_radar: Vec3::new(5.0 + 3.0 * a.cos(), 4.0 * a.sin(), 0.25 * i as f64),
                v_r: -1.5 + 0.5 * i as f64,
                rcs: (i % 3 != 0).then_some(2.0 * i as f64),
            }
        })
        .collect()
}

fn header(frame: &str, stamp: Stamp) -> Header {
    Header {
        stamp: stamp.into(),
        frame_id: frame.into(),
    }
}

fn radar_cloud(stamp: Stamp, n: usize) -> PointCloud2 {
    encode_detections(
        &detections(n),
        &CloudLayout::radar_f32(),
        header("radar", stamp),
    )
    .unwrap()
}

fn odometry(stamp: Stamp, x: f64, frame: &str) -> Odometry {
    let mut m = Odometry {
        header: header(frame, stamp),
        child_frame_id: "base_link".into(),
        ..Odometry::default()
    };
    m.pose.pose.position.x = x;
    m.pose.pose.orientation = Quaternion {
        x: 0.0,
        y: 0.0,
        z: 0.0998,
        w: 0.995,
    };
    m.twist.twist.linear.x = 10.0;
    m
}

fn tf(stamp: Stamp) -> TFMessage {
    let mut t = TransformStamped {
        header: header("base_link", stamp),
        child_frame_id: "radar".into(),
        ..TransformStamped::default()
    };
    t.transform.translation.x = 3.6;
    TFMessage {
        transforms: vec![t],
    }
}

/// Seeds of `pointcloud2`: the radar layout, the nuScenes layout, and a big-endian layout of mixed
/// datatypes with gaps, point and row padding, two rows, fields from the input and tight limits.
fn pointcloud2_seeds() -> Vec<(&'static str, Vec<u8>)> {
    let d = detections(6);
    let radar = encode_detections(&d, &CloudLayout::radar_f32(), Header::default()).unwrap();
    let nuscenes =
        encode_detections(&d, &CloudLayout::nuscenes_radar(), Header::default()).unwrap();
    let mixed_layout = CloudLayout {
        fields: vec![
            LayoutField::new("x", FieldRole::X, PointField::FLOAT64),
            LayoutField::new("y", FieldRole::Y, PointField::FLOAT32).with_gap(3),
            LayoutField::new("z", FieldRole::Z, PointField::INT16),
            LayoutField::new("velocity", FieldRole::RadialVelocity, PointField::FLOAT64),
            LayoutField::new("intensity", FieldRole::Rcs, PointField::UINT8).with_gap(1),
        ],
        is_bigendian: true,
        point_padding: 2,
        row_padding: 5,
        rows: 2,
    };
    let mixed = encode_detections(&d, &mixed_layout, Header::default()).unwrap();
    let mixed_fields = FieldsConfig {
        velocity: "velocity".into(),
        rcs: "intensity".into(),
        ..FieldsConfig::default()
    };
    let limits = InputLimits {
        max_cloud_points: 64,
        max_cloud_bytes: 4096,
    };
    let config = FieldsConfig::default();
    vec![
        (
            "radar_f32",
            cloud_to_bytes(&radar, FieldsChoice::Default, &config, None),
        ),
        (
            "nuscenes",
            cloud_to_bytes(&nuscenes, FieldsChoice::Nuscenes, &config, None),
        ),
        (
            "mixed_big_endian",
            cloud_to_bytes(&mixed, FieldsChoice::Input, &mixed_fields, Some(limits)),
        ),
    ]
}

/// Seeds of `cdr`: PointCloud2 in both byte orders, the nuScenes layout, Odometry, TFMessage, a fleet
/// Keyframe.
fn cdr_seeds() -> Vec<(&'static str, Vec<u8>)> {
    let cloud = radar_cloud(Stamp(1_500_000_000), 4);
    let mut big_endian = vec![0, 0, 0, 0];
    big_endian
        .extend(cdr_encoding::to_vec::<_, byteorder::BigEndian>(&cloud).expect("big-endian CDR"));
    let nuscenes = encode_detections(
        &detections(3),
        &CloudLayout::nuscenes_radar(),
        header("RADAR_FRONT", Stamp(7)),
    )
    .unwrap();
    vec![
        ("pointcloud2_le.cdr", dc_loc::bag::encode(&cloud).unwrap()),
        ("pointcloud2_be.cdr", big_endian),
        (
            "pointcloud2_nuscenes.cdr",
            dc_loc::bag::encode(&nuscenes).unwrap(),
        ),
        (
            "odometry.cdr",
            dc_loc::bag::encode(&odometry(Stamp(3), 1.0, "odom")).unwrap(),
        ),
        ("tf.cdr", dc_loc::bag::encode(&tf(Stamp(3))).unwrap()),
        (
            "keyframe.cdr",
            dc_loc::bag::encode(&fleet_keyframe()).unwrap(),
        ),
    ]
}

/// A fleet keyframe of robot 3 with 40 points, carrying an alignment to robot 4's session 0 (the
/// robot whose pipeline the `cdr` target pushes it into) and one to robot 7's.
fn fleet_keyframe() -> dc_loc::msgs::dc_loc::Keyframe {
    let aligned = |robot: i32| SharedAlignment {
        robot,
        session: 0,
        alignment: Alignment {
            t: Iso2::new(Vec2::new(-40.0, 12.5), 2.5),
            path: 300.0,
            match_path: 80.0,
        },
    };
    let fleet = FleetState {
        heard: vec![(4, 17)],
        alignments: vec![aligned(4), aligned(7)],
    };
    dc_loc::fleet::wire::encode(3, &keyframe(5, 40), &fleet, 0, "base_link")
}

/// The messages of the seed bags: one `tf_static`, then per step odometry, ground truth and a cloud;
/// the topics and frames of the default configuration, so that `BagInputs` reads them.
fn bag_messages() -> Vec<(&'static str, &'static str, Stamp, Vec<u8>)> {
    let cfg = Config::default();
    let radar_topic: &'static str = cfg.radars["front"].topic.clone().leak();
    let odom_topic: &'static str = cfg.odometry.topic.clone().leak();
    let mut out = vec![(
        TF_STATIC_TOPIC,
        schema::TF_MESSAGE,
        Stamp(1_000_000_000),
        dc_loc::bag::encode(&tf(Stamp(1_000_000_000))).unwrap(),
    )];
    for k in 0..3i64 {
        let t = Stamp(1_000_000_000 + k * 75_000_000);
        let x = k as f64;
        out.push((
            odom_topic,
            schema::ODOMETRY,
            t,
            dc_loc::bag::encode(&odometry(t, x, "odom")).unwrap(),
        ));
        out.push((
            GROUND_TRUTH_TOPIC,
            schema::ODOMETRY,
            t,
            dc_loc::bag::encode(&odometry(t, x, "map")).unwrap(),
        ));
        out.push((
            radar_topic,
            schema::POINT_CLOUD2,
            t,
            dc_loc::bag::encode(&radar_cloud(t, 3)).unwrap(),
        ));
    }
    out
}

/// An MCAP file of [`bag_messages`] written with the mcap crate directly: no compression and no chunk
/// CRCs (so that mutated chunks are still read), chunked with a summary or not chunked at all. The
/// schemas carry their names only (the reader needs no `.msg` text), which keeps the file small.
fn raw_mcap(chunked: bool) -> Vec<u8> {
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .compression(None)
        .calculate_chunk_crcs(false)
        .use_chunks(chunked)
        .create(std::io::Cursor::new(Vec::new()))
        .unwrap();
    let mut channels: BTreeMap<&str, u16> = BTreeMap::new();
    for (sequence, (topic, type_name, stamp, data)) in (1..).zip(bag_messages()) {
        let id = match channels.get(topic) {
            Some(&id) => id,
            None => {
                let schema_id = w.add_schema(type_name, "ros2msg", b"").unwrap();
                let id = w
                    .add_channel(schema_id, topic, "cdr", &BTreeMap::new())
                    .unwrap();
                channels.insert(topic, id);
                id
            }
        };
        let t = stamp.0 as u64;
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: id,
                sequence,
                log_time: t,
                publish_time: t,
            },
            &data,
        )
        .unwrap();
    }
    w.finish().unwrap();
    w.into_inner().into_inner()
}

/// The MCAP file the crate's own `BagWriter` (as `dc_loc sim`) makes of [`bag_messages`]: zstd chunks,
/// chunk CRCs, summary.
fn writer_mcap() -> Vec<u8> {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("fuzz_seed_bag");
    let _ = std::fs::remove_dir_all(&dir);
    let mut bag = BagWriter::create(&dir).unwrap();
    let mut topics = BTreeMap::new();
    for (topic, type_name, stamp, data) in bag_messages() {
        let id = *topics
            .entry(topic)
            .or_insert_with(|| bag.add_topic(topic, type_name).unwrap());
        bag.write_cdr(id, stamp, &data).unwrap();
    }
    bag.finish().unwrap();
    let bytes = std::fs::read(dir.join("fuzz_seed_bag_0.mcap")).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    bytes
}

/// A nuScenes radar PCD file (the 18 standard fields) of `points` (x, y) with trailing padding.
fn nuscenes_pcd(points: &[[f32; 2]]) -> Vec<u8> {
    let mut b = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n\
         FIELDS x y z dyn_prop id rcs vx vy vx_comp vy_comp is_quality_valid ambig_state x_rms \
         y_rms invalid_state pdh0 vx_rms vy_rms\n\
         SIZE 4 4 4 1 2 4 4 4 4 4 1 1 1 1 1 1 1 1\n\
         TYPE F F F I I F F F F F I I I I I I I I\n\
         COUNT 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1\n\
         WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n",
        n = points.len()
    )
    .into_bytes();
    for (i, &[x, y]) in points.iter().enumerate() {
        b.extend(x.to_le_bytes());
        b.extend(y.to_le_bytes());
        b.extend(0f32.to_le_bytes());
        b.push(i as u8); // dyn_prop
        b.extend((i as i16).to_le_bytes()); // id
        b.extend(5.5f32.to_le_bytes()); // rcs
        b.extend(1f32.to_le_bytes()); // vx
        b.extend((-2f32).to_le_bytes()); // vy
        b.extend(0.5f32.to_le_bytes()); // vx_comp
        b.extend(0.25f32.to_le_bytes()); // vy_comp
        b.extend([1, 3, 0, 0, 0, 1, 0, 0]); // the eight state and rms bytes
    }
    b.extend([0u8; 8]);
    b
}

/// A PCD file of another sensor: x y z intensity, a COUNT of 2, an unsigned field, v0.6 style (no
/// VIEWPOINT or POINTS).
fn generic_pcd() -> Vec<u8> {
    let mut b = b"VERSION .6\nFIELDS x y z intensity ring\nSIZE 4 4 4 4 2\nTYPE F F F F U\n\
COUNT 1 1 1 2 1\nWIDTH 2\nHEIGHT 1\nDATA binary\n"
        .to_vec();
    for i in 0..2u16 {
        for v in [1.0f32 + f32::from(i), 2.0, 0.5, 10.0, 11.0] {
            b.extend(v.to_le_bytes());
        }
        b.extend(i.to_le_bytes());
    }
    b
}

/// A keyframe record with `n` points around the origin.
fn keyframe(id: u64, n: usize) -> KeyframeRecord {
    let pts: Vec<Vec2> = (0..n)
        .map(|i| {
            let a = i as f64 * 0.9;
            Vec2::new((5.0 + i as f64) * a.cos(), (5.0 + i as f64) * a.sin())
        })
        .collect();
    let x = 10.0 * id as f64;
    let yaw = 0.2 * id as f64;
    KeyframeRecord {
        id,
        session: id as u32 % 2,
        stamp: Stamp(1_000_000_000 * (id as i64 + 1)),
        t_odom_body: Iso2::new(Vec2::new(x, 1.0), yaw),
        odom_pose: [x, 1.0, 0.0, 0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()],
        path_distance: x,
        points: pts.iter().filter_map(|&p| quantise_point(p)).collect(),
        covs: pts
            .iter()
            .map(|_| quantise_cov(&Mat2::new(0.04, 0.001, 0.001, 0.09)))
            .collect(),
        rays: pts.iter().map(|p| quantise_ray(&p.normalize())).collect(),
        place: PlaceDescriptor::from_points(&pts, &PlaceConfig::default()),
    }
}

/// Seeds of `keyframe_map`: a map file of three keyframes as `KeyframeDb` saves it (raw, mode 0), its
/// payload (framed with today's version, mode 3), and the same keyframes as a version 2 payload
/// (mode 2). A
/// map of place settings other than the default is added, whose descriptors a load recomputes.
fn keyframe_map_seeds() -> Vec<(&'static str, Vec<u8>)> {
    let records: Vec<Arc<KeyframeRecord>> = (0..3).map(|i| Arc::new(keyframe(i, 6))).collect();
    let saved = |shape: &dc_loc::keyframe_db::MapShape| {
        let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("fuzz_seed_map.dcloc");
        save_records(&records, shape, &path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let _ = std::fs::remove_file(&path);
        bytes
    };
    let shape = Config::default().map_shape();
    let file = saved(&shape);
    let payload = &file[12..file.len() - 4];
    let mut other_shape = shape.clone();
    other_shape.place.max_range = 50.0;
    let other = saved(&other_shape);
    #[derive(serde::Serialize)]
    struct MapFileV2<'a> {
        written_by: &'a str,
        place: &'a PlaceConfig,
        keyframes: Vec<RecordV4>,
    }
    let v2 = postcard::to_stdvec(&MapFileV2 {
        written_by: "dc_loc 0.1.0",
        place: &shape.place,
        keyframes: records.iter().map(|r| RecordV4::from(r.as_ref())).collect(),
    })
    .unwrap();
    let with_mode = |mode: u8, bytes: &[u8]| {
        let mut b = vec![mode];
        b.extend(bytes);
        b
    };
    vec![
        ("raw_v5", with_mode(0, &file)),
        ("payload_v5", with_mode(3, payload)),
        ("payload_v2", with_mode(2, &v2)),
        (
            "payload_v5_other_place",
            with_mode(3, &other[12..other.len() - 4]),
        ),
    ]
}

/// A target's seed files: name and contents.
type Seeds = Vec<(&'static str, Vec<u8>)>;

/// Writes the seed corpus into `fuzz/corpus/<target>/` (replacing the files of the same names).
#[test]
#[ignore = "writes the seed corpus into the source tree; run by hand"]
fn write_seed_corpus() {
    let rosbags = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/rosbags_bag/rosbags_bag.mcap"),
    )
    .unwrap();
    // ROS 1 bags of every chunk compression, written by rosbags (tests/python/ros1_bags.py).
    let ros1 = std::env::temp_dir().join("dc_loc_ros1_seeds");
    let out = venv::python_script("ros1_bags.py")
        .arg("fixtures")
        .arg(&ros1)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let ros1_seed = |c: &str| std::fs::read(ros1.join(format!("{c}.bag"))).unwrap();
    let seeds: Vec<(&str, Seeds)> = vec![
        ("pointcloud2", pointcloud2_seeds()),
        ("cdr", cdr_seeds()),
        (
            "bag_reader",
            vec![
                ("dc_loc_writer.mcap", writer_mcap()),
                ("uncompressed_chunks.mcap", raw_mcap(true)),
                ("unchunked.mcap", raw_mcap(false)),
                ("rosbags.mcap", rosbags),
            ],
        ),
        (
            "rosbag1",
            vec![
                ("none.bag", ros1_seed("none")),
                ("bz2.bag", ros1_seed("bz2")),
                ("lz4.bag", ros1_seed("lz4")),
            ],
        ),
        (
            "pcd",
            vec![
                (
                    "nuscenes.pcd",
                    nuscenes_pcd(&[[3.0, 4.0], [10.0, -2.0], [0.0, 0.0]]),
                ),
                ("generic.pcd", generic_pcd()),
            ],
        ),
        ("keyframe_map", keyframe_map_seeds()),
    ];
    for (target, files) in seeds {
        let dir = fuzz_dir().join("corpus").join(target);
        std::fs::create_dir_all(&dir).unwrap();
        for (name, bytes) in files {
            std::fs::write(dir.join(name), bytes).unwrap();
        }
    }
}
