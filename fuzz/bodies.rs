//! The body of every fuzz target: what one fuzz input does to the library.
//!
//! Shared by the libFuzzer targets (`fuzz/fuzz_targets/*.rs`, nightly) and by the stable regression test
//! (`tests/fuzz_regressions.rs`), which include this file by path, so that an input that crashes a
//! target reproduces in the regression test exactly.
//!
//! Each body asserts nothing but "no panic": errors are fine. Unbounded allocation is caught by the
//! fuzzer's `-rss_limit_mb` / `-malloc_limit_mb`.
//!
//! Targets ([`TARGETS`]):
//! - `pointcloud2`: a `sensor_msgs/PointCloud2` built from the input by [`cloud_from_bytes`] (layout,
//!   sizes, byte order, fields config, input limits, data), through the pipeline's limit check and
//!   decoder.
//! - `cdr`: the input as a ROS 2 CDR message (encapsulation header included) decoded as PointCloud2,
//!   Odometry, TFMessage and the fleet's Keyframe, the clouds then decoded into detections, the odometry
//!   into poses, the keyframe into a record and into a pipeline of the robot its alignments name.
//! - `bag_reader`: the input as an MCAP file read by `BagReader` (every message, a topic selection,
//!   and the pipeline's `BagInputs`), each message decoded as its type.
//! - `rosbag1`: the input as a ROS 1 bag read by `BagReader` (every message decoded as its type, a
//!   topic selection, the pipeline's `BagInputs` with a PoseStamped or Odometry ground truth, the
//!   `/tf_static` extrinsics).
//! - `pcd`: the input as a PCD file: header, binary records, nuScenes radar points, PointCloud2.
//! - `keyframe_map`: the input as a keyframe map file, framed with magic, version and a valid CRC-32
//!   or taken as the raw file ([`map_file_from_bytes`]), loaded into a `KeyframeDb`.

use std::path::{Path, PathBuf};

use dc_loc::bag::{BagReader, schema};
use dc_loc::cloud::{DecodedCloud, decode_detections_into};
use dc_loc::fleet::wire::decode as decode_keyframe;
use dc_loc::input::{Input, InputLimits, ground_truth_sample, odometry_pose};
use dc_loc::io::nuscenes_pcd::{
    NuscenesRadarFilter, NuscenesRadarPcd, PcdHeader, filtered_pointcloud2, nuscenes_fields_config,
    pcd_to_pointcloud2,
};
use dc_loc::io::rosbag::BagInputs;
use dc_loc::keyframe_db::{KeyframeDb, MAP_FORMAT_VERSION};
use dc_loc::msgs::dc_loc::Keyframe;
use dc_loc::msgs::geometry_msgs::PoseStamped;
use dc_loc::msgs::nav_msgs::Odometry;
use dc_loc::msgs::radar_msgs::RadarScan;
use dc_loc::msgs::sensor_msgs::{Imu, PointCloud2, PointField};
use dc_loc::msgs::std_msgs::Header;
use dc_loc::msgs::tf2_msgs::TFMessage;
use dc_loc::pipeline::{Config, Pipeline};
use dc_loc::place::PlaceConfig;
use dc_loc::radar::FieldsConfig;
use dc_loc::sim::export::GROUND_TRUTH_TOPIC;

/// A fuzz target's body: it runs on one input and panics on a defect.
pub type Body = fn(&[u8]);

/// Every target: its name (the directory under `fuzz/corpus/` and `fuzz/regressions/`) and its body.
pub const TARGETS: [(&str, Body); 6] = [
    ("pointcloud2", pointcloud2),
    ("cdr", cdr),
    ("bag_reader", bag_reader),
    ("rosbag1", rosbag1),
    ("pcd", pcd),
    ("keyframe_map", keyframe_map),
];

/// Target `pointcloud2`: a structured PointCloud2 through the limit check and the decoder.
pub fn pointcloud2(data: &[u8]) {
    let input = cloud_from_bytes(data);
    decode_cloud(&input.cloud, &input.limits, &input.fields);
}

/// Target `cdr`: the input decoded as each message type the bag and node paths read.
pub fn cdr(data: &[u8]) {
    if let Ok(cloud) = dc_loc::bag::decode::<PointCloud2>(data) {
        decode_cloud_as_radar(&cloud);
    }
    if let Ok(odom) = dc_loc::bag::decode::<Odometry>(data) {
        check_odometry(&odom);
    }
    let _ = dc_loc::bag::decode::<TFMessage>(data);
    if let Ok(keyframe) = dc_loc::bag::decode::<Keyframe>(data) {
        receive_keyframe(keyframe);
    }
}

/// A fleet keyframe as a node receives it: decoded, then pushed into the pipeline of the robot whose
/// id follows the sender's (a seed's alignment names that robot, so that the pipeline takes it).
fn receive_keyframe(keyframe: Keyframe) {
    let _ = decode_keyframe(&keyframe, &PlaceConfig::default());
    let Ok(mut pipeline) = Pipeline::new(Config::default()) else {
        return;
    };
    pipeline.set_robot(keyframe.robot_id.wrapping_add(1));
    pipeline.push(&Input::Keyframe(Box::new(keyframe)));
}

/// Target `bag_reader`: the input as an MCAP file, every message read and decoded.
pub fn bag_reader(data: &[u8]) {
    with_temp_file("input.mcap", data, |path| {
        let Ok(reader) = BagReader::open(path) else {
            return;
        };
        read_every_message(&reader);
        // What `dc_loc run --bag` does with the default configuration's topics.
        if let Ok(inputs) = BagInputs::new(&reader, &Config::default(), Some(GROUND_TRUTH_TOPIC)) {
            for input in inputs.flatten() {
                if let Input::Radar { cloud, .. } = input {
                    decode_cloud_as_radar(&cloud);
                }
            }
        }
    });
}

/// Target `rosbag1`: the input as a ROS 1 bag, every message read and decoded as its type.
pub fn rosbag1(data: &[u8]) {
    with_temp_file("input.bag", data, |path| {
        let Ok(reader) = BagReader::open(path) else {
            return;
        };
        read_every_message(&reader);
        let _ =
            dc_loc::bag::foxglove::bag_extrinsics(&reader, "base_link", &["radar_front".into()]);
        // What `dc_loc run --bag` and `dc_loc eval --bag` read with the fixtures' topics.
        let mut cfg = Config::default();
        if let Some(radar) = cfg.radars.values_mut().next() {
            radar.topic = "/radar_front".into();
            radar.frame_id = String::new();
        }
        for gt in ["/ground_truth", "/odom"] {
            if let Ok(inputs) = BagInputs::new(&reader, &cfg, Some(gt)) {
                for input in inputs.flatten() {
                    if let Input::Radar { cloud, .. } = input {
                        decode_cloud_as_radar(&cloud);
                    }
                }
            }
        }
    });
}

/// Every message of a bag decoded as its type, then one topic read through a topic selection (which
/// takes another path through indexed files: chunks without the topic are skipped).
fn read_every_message(reader: &BagReader) {
    let _ = (reader.message_count(), reader.time_range());
    if let Ok(messages) = reader.messages() {
        for message in messages.flatten() {
            match message.type_name() {
                schema::POINT_CLOUD2 => {
                    if let Ok(cloud) = message.decode::<PointCloud2>() {
                        decode_cloud_as_radar(&cloud);
                    }
                }
                schema::ODOMETRY => {
                    if let Ok(odom) = message.decode::<Odometry>() {
                        check_odometry(&odom);
                    }
                }
                schema::POSE_STAMPED => {
                    let _ = message.decode::<PoseStamped>();
                }
                schema::IMU => {
                    let _ = message.decode::<Imu>();
                }
                schema::RADAR_SCAN => {
                    let _ = message.decode::<RadarScan>();
                }
                _ => {
                    let _ = message.decode::<TFMessage>();
                }
            }
        }
    }
    if let Some(topic) = reader.topics().last().map(|t| t.name.clone())
        && let Ok(messages) = reader.messages_on(&[topic.as_str()])
    {
        messages.for_each(drop);
    }
}

/// Target `pcd`: the input as a PCD file, through every reader of PCD bytes.
pub fn pcd(data: &[u8]) {
    if let Ok(header) = PcdHeader::parse(data) {
        let _ = header.binary_records(data);
        for f in &header.fields {
            let _ = f.scalar_type();
        }
    }
    if let Ok(pcd) = NuscenesRadarPcd::from_bytes(data) {
        let _ = pcd.detections(&NuscenesRadarFilter::default());
        let _ = pcd.detections(&NuscenesRadarFilter::keep_all());
    }
    let fields = nuscenes_fields_config();
    if let Ok(cloud) = pcd_to_pointcloud2(data, Header::default()) {
        decode_cloud(&cloud, &InputLimits::default(), &fields);
    }
    if let Ok(cloud) =
        filtered_pointcloud2(data, &NuscenesRadarFilter::default(), Header::default())
    {
        decode_cloud(&cloud, &InputLimits::default(), &fields);
    }
}

/// Target `keyframe_map`: the map file [`map_file_from_bytes`] makes of the input, loaded.
pub fn keyframe_map(data: &[u8]) {
    let file = map_file_from_bytes(data);
    with_temp_file("map.dcloc", &file, |path| {
        if let Ok(db) = KeyframeDb::load(path, PlaceConfig::default(), 4) {
            let _ = db.shape().differences(&Config::default().map_shape());
            let _ = (db.len(), db.last_session());
        }
    });
}

// ---------------------------------------------------------------------------------------------------
// Shared steps.

/// The pipeline's steps for one cloud: the size limit check, then (when it passes) the decoder.
fn decode_cloud(cloud: &PointCloud2, limits: &InputLimits, fields: &FieldsConfig) {
    if limits.check(cloud).is_ok() {
        let mut out = DecodedCloud::default();
        let _ = decode_detections_into(cloud, fields, &mut out);
    }
}

/// A cloud read from a bag or CDR, decoded with the default radar fields and the nuScenes fields.
fn decode_cloud_as_radar(cloud: &PointCloud2) {
    let limits = InputLimits::default();
    decode_cloud(cloud, &limits, &FieldsConfig::default());
    decode_cloud(cloud, &limits, &nuscenes_fields_config());
}

/// The conversions an odometry message goes through.
fn check_odometry(odom: &Odometry) {
    let _ = odometry_pose(odom);
    let _ = ground_truth_sample(odom);
}

/// Runs `f` on a file holding `bytes`, in a directory of this process and thread under `/dev/shm`
/// (memory, when present) or the system temporary directory; file and directory are removed after.
/// The readers fuzzed here only open paths.
pub fn with_temp_file<R>(name: &str, bytes: &[u8], f: impl FnOnce(&Path) -> R) -> R {
    let base = if Path::new("/dev/shm").is_dir() {
        PathBuf::from("/dev/shm")
    } else {
        std::env::temp_dir()
    };
    // Thread ids print as `ThreadId(N)`: the digits name the directory.
    let thread: String = format!("{:?}", std::thread::current().id())
        .chars()
        .filter(char::is_ascii_digit)
        .collect();
    let dir = base.join(format!("dc_loc_fuzz.{}.{thread}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("create the fuzz scratch directory");
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("write the fuzz input file");
    let result = f(&path);
    let _ = std::fs::remove_file(&path);
    let _ = std::fs::remove_dir(&dir);
    result
}

// ---------------------------------------------------------------------------------------------------
// Input formats.

/// Reads values from the front of a fuzz input; past the end every value is 0 (as `arbitrary`'s
/// `Unstructured` does), so every input means something.
pub struct ByteSource<'a> {
    data: &'a [u8],
}

impl<'a> ByteSource<'a> {
    /// A reader over `data`.
    pub fn new(data: &'a [u8]) -> Self {
        ByteSource { data }
    }

    /// Up to `n` bytes (fewer at the end of the input).
    pub fn bytes(&mut self, n: usize) -> &'a [u8] {
        let (head, tail) = self.data.split_at(n.min(self.data.len()));
        self.data = tail;
        head
    }

    /// The remaining bytes.
    pub fn rest(&mut self) -> &'a [u8] {
        self.bytes(self.data.len())
    }

    /// One byte.
    pub fn u8(&mut self) -> u8 {
        self.bytes(1).first().copied().unwrap_or(0)
    }

    /// A little-endian value of `N` bytes, zero-extended at the end of the input.
    fn le<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        let b = self.bytes(N);
        out[..b.len()].copy_from_slice(b);
        out
    }

    /// A size, mostly small: one byte below 0xE0 is the value itself; 0xE0..0xF0 is followed by a u16,
    /// 0xF0.. by a u32 (little endian). Small layouts cost the fuzzer one byte per value, and any u32
    /// stays reachable.
    pub fn size(&mut self) -> u32 {
        match self.u8() {
            t @ 0..0xE0 => u32::from(t),
            0xE0..0xF0 => u32::from(u16::from_le_bytes(self.le())),
            _ => u32::from_le_bytes(self.le()),
        }
    }

    /// A name: an index into [`NAMES`], or (past its end) a length byte and that many bytes of text.
    pub fn name(&mut self) -> String {
        let i = usize::from(self.u8());
        match NAMES.get(i) {
            Some(n) => (*n).to_string(),
            None => {
                let n = usize::from(self.u8());
                String::from_utf8_lossy(self.bytes(n)).into_owned()
            }
        }
    }
}

/// Bytes of a size as [`ByteSource::size`] reads it.
pub fn size_bytes(v: u32) -> Vec<u8> {
    if v < 0xE0 {
        vec![v as u8]
    } else if let Ok(v16) = u16::try_from(v) {
        let mut b = vec![0xE0];
        b.extend(v16.to_le_bytes());
        b
    } else {
        let mut b = vec![0xF0];
        b.extend(v.to_le_bytes());
        b
    }
}

/// Bytes of a name as [`ByteSource::name`] reads it.
pub fn name_bytes(name: &str) -> Vec<u8> {
    match NAMES.iter().position(|n| *n == name) {
        Some(i) => vec![i as u8],
        None => {
            let text = &name.as_bytes()[..name.len().min(255)];
            let mut b = vec![NAMES.len() as u8, text.len() as u8];
            b.extend(text);
            b
        }
    }
}

/// Field names the decoder looks for (the default and nuScenes field configurations) and a few
/// others, one byte each.
pub const NAMES: [&str; 11] = [
    "x",
    "y",
    "z",
    "v_r",
    "vx",
    "vy",
    "rcs",
    "",
    "intensity",
    "velocity",
    "doppler",
];

/// A cloud, the field configuration it is decoded with and the limits checked first.
#[derive(Debug, Clone, PartialEq)]
pub struct CloudInput {
    /// The cloud.
    pub cloud: PointCloud2,
    /// The radar's field names.
    pub fields: FieldsConfig,
    /// The pipeline's size limits.
    pub limits: InputLimits,
}

/// Which field configuration a cloud input uses (bits 2..=3 of its first byte).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FieldsChoice {
    /// `FieldsConfig::default()`.
    Default,
    /// `nuscenes_fields_config()`.
    Nuscenes,
    /// Seven names from the input.
    Input,
}

/// The cloud input of target `pointcloud2`, read in this order:
/// - a flags byte: bit 0 `is_bigendian`, bit 1 `is_dense`, bits 2..=3 the fields configuration
///   ([`FieldsChoice`]: 0 default, 1 nuScenes, 2 and 3 from the input), bit 4 limits from the input
///   (else `InputLimits::default()`);
/// - sizes ([`ByteSource::size`]): height, width, point_step, row_step;
/// - a byte: the number of fields (modulo 17); per field a name ([`ByteSource::name`]), a size
///   offset, a datatype byte (any value) and a size count;
/// - with fields from the input: names of x, y, z, velocity, velocity_x, velocity_y, rcs;
/// - with limits from the input: sizes max_cloud_points, max_cloud_bytes;
/// - the rest: `data`.
pub fn cloud_from_bytes(data: &[u8]) -> CloudInput {
    let mut s = ByteSource::new(data);
    let flags = s.u8();
    let (height, width, point_step, row_step) = (s.size(), s.size(), s.size(), s.size());
    let n_fields = s.u8() % 17;
    let fields = (0..n_fields)
        .map(|_| PointField {
            name: s.name(),
            offset: s.size(),
            datatype: s.u8(),
            count: s.size(),
        })
        .collect();
    let config = match (flags >> 2) & 3 {
        0 => FieldsConfig::default(),
        1 => nuscenes_fields_config(),
        _ => FieldsConfig {
            x: s.name(),
            y: s.name(),
            z: s.name(),
            velocity: s.name(),
            velocity_x: s.name(),
            velocity_y: s.name(),
            rcs: s.name(),
        },
    };
    let limits = if flags & 0x10 != 0 {
        InputLimits {
            max_cloud_points: s.size() as usize,
            max_cloud_bytes: s.size() as usize,
        }
    } else {
        InputLimits::default()
    };
    let cloud = PointCloud2 {
        header: Header::default(),
        height,
        width,
        fields,
        is_bigendian: flags & 1 != 0,
        point_step,
        row_step,
        data: s.rest().to_vec(),
        is_dense: flags & 2 != 0,
    };
    CloudInput {
        cloud,
        fields: config,
        limits,
    }
}

/// The bytes [`cloud_from_bytes`] reads back as `cloud` (header aside, at most 16 fields, names of at
/// most 255 bytes) with `fields` and `limits` (`None`: the default limits).
pub fn cloud_to_bytes(
    cloud: &PointCloud2,
    fields: FieldsChoice,
    config: &FieldsConfig,
    limits: Option<InputLimits>,
) -> Vec<u8> {
    let choice: u8 = match fields {
        FieldsChoice::Default => 0,
        FieldsChoice::Nuscenes => 1,
        FieldsChoice::Input => 2,
    };
    let flags = u8::from(cloud.is_bigendian)
        | u8::from(cloud.is_dense) << 1
        | choice << 2
        | u8::from(limits.is_some()) << 4;
    let mut b = vec![flags];
    for v in [cloud.height, cloud.width, cloud.point_step, cloud.row_step] {
        b.extend(size_bytes(v));
    }
    b.push(cloud.fields.len().min(16) as u8);
    for f in cloud.fields.iter().take(16) {
        b.extend(name_bytes(&f.name));
        b.extend(size_bytes(f.offset));
        b.push(f.datatype);
        b.extend(size_bytes(f.count));
    }
    if fields == FieldsChoice::Input {
        for n in [
            &config.x,
            &config.y,
            &config.z,
            &config.velocity,
            &config.velocity_x,
            &config.velocity_y,
            &config.rcs,
        ] {
            b.extend(name_bytes(n));
        }
    }
    if let Some(l) = limits {
        for v in [l.max_cloud_points, l.max_cloud_bytes] {
            b.extend(size_bytes(u32::try_from(v).unwrap_or(u32::MAX)));
        }
    }
    b.extend(&cloud.data);
    b
}

/// Map file magic (as `crates/core/src/keyframe_db/file.rs` writes it).
pub const MAP_MAGIC: &[u8; 8] = b"DCLOCMAP";

/// The map file of target `keyframe_map`. The first byte of the input chooses, modulo 4:
/// - 0: the rest is the whole file (magic, version, CRC and all);
/// - 1: the rest is a format version 3 payload, framed as `read_map` expects: magic, version, payload,
///   CRC-32 of what precedes it;
/// - 2: the same with format version 2;
/// - 3: the same with the version written today.
///
/// The framed modes let the fuzzer reach the payload decoding past the checksum.
pub fn map_file_from_bytes(data: &[u8]) -> Vec<u8> {
    let Some((&mode, rest)) = data.split_first() else {
        return Vec::new();
    };
    match mode % 4 {
        0 => rest.to_vec(),
        1 => frame_map_payload(3, rest),
        2 => frame_map_payload(2, rest),
        _ => frame_map_payload(MAP_FORMAT_VERSION, rest),
    }
}

/// Magic, `version` (u32 little endian), `payload`, and the CRC-32 of those (u32 little endian).
pub fn frame_map_payload(version: u32, payload: &[u8]) -> Vec<u8> {
    let mut file = Vec::with_capacity(payload.len() + 16);
    file.extend_from_slice(MAP_MAGIC);
    file.extend_from_slice(&version.to_le_bytes());
    file.extend_from_slice(payload);
    let crc = crc32fast::hash(&file);
    file.extend_from_slice(&crc.to_le_bytes());
    file
}
