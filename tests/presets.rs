//! The presets in params/examples for the datasets' radars and the public ROS drivers, each against
//! the layout its source writes (the sources are named in each preset's comments):
//! - every preset loads and validates as the node and `dc_loc run` read it, and every dataset or
//!   driver preset has a case here;
//! - per preset, a `sensor_msgs/PointCloud2` in the source's exact layout (field names, datatypes,
//!   offsets, point_step, topic, header.frame_id) holding a few known detections goes through a
//!   rosbag2 and `BagInputs` (the input path of `dc_loc run`) to the preset's radar, and decodes with
//!   the preset's field names into those detections, the radial velocity positive away; a
//!   `radar_msgs/RadarScan` goes through `radar_scan_input`, as the bag reader and the node read it;
//! - TIER IV's ARS408 RadarScan carries VrelLong / cos(azimuth), the radial velocity only at the
//!   boresight;
//! - the extrinsics are the datasets' calibrations they were converted from.

mod common;

use std::path::{Path, PathBuf};

use dc_loc::bag::{BagReader, BagWriter, schema};
use dc_loc::cli::params::load_params;
use dc_loc::cloud::decode_detections;
use dc_loc::input::{Input, radar_scan_input};
use dc_loc::io::rosbag::BagInputs;
use dc_loc::math::{Mat3, Stamp, Vec3};
use dc_loc::msgs::nav_msgs::Odometry;
use dc_loc::msgs::radar_msgs::{RadarReturn, RadarScan};
use dc_loc::msgs::sensor_msgs::{Imu, PointCloud2, PointField};
use dc_loc::msgs::std_msgs::Header;
use dc_loc::odometry::OdometrySource;
use dc_loc::pipeline::Config;
use dc_loc::radar::{Detection, RadarConfig, RadarMessage};
use nalgebra::{Matrix4, Quaternion, UnitQuaternion};

const REPO: &str = env!("CARGO_MANIFEST_DIR");

/// The generic examples of docs/robot.md, which stand for no particular driver or dataset.
const GENERIC: [&str; 3] = ["ars408.yaml", "imaging_4d.yaml", "ti_awr1843.yaml"];

/// Presets checked by a test of their own rather than a case of [`cases`].
const OWN_TEST: [&str; 1] = ["driver_tier4_ars408_scan.yaml"];

const I8: u8 = PointField::INT8;
const U8: u8 = PointField::UINT8;
const U16: u8 = PointField::UINT16;
const F32: u8 = PointField::FLOAT32;

/// One PointCloud2 field as a source writes it.
#[derive(Debug, Clone, Copy)]
struct Field {
    name: &'static str,
    offset: u32,
    datatype: u8,
}

const fn field(name: &'static str, offset: u32, datatype: u8) -> Field {
    Field {
        name,
        offset,
        datatype,
    }
}

/// A detection in the radar frame: position and the target's velocity relative to the radar.
#[derive(Debug, Clone, Copy)]
struct Target {
    p: Vec3,
    u: Vec3,
}

impl Target {
    fn range(&self) -> f64 {
        self.p.norm()
    }
    /// Radial velocity, positive when the target moves away (dc_loc's sign).
    fn radial(&self) -> f64 {
        self.u.dot(&self.p) / self.p.norm()
    }
    fn azimuth(&self) -> f64 {
        self.p.y.atan2(self.p.x)
    }
    fn elevation(&self) -> f64 {
        (self.p.z / self.p.norm()).asin()
    }
}

/// The radar drives forward at 5 m/s: three static targets come closer (negative radial velocity),
/// a car ahead pulls away (positive). `planar`: a radar without elevation (z = 0).
fn targets(planar: bool) -> Vec<Target> {
    let still = Vec3::new(-5.0, 0.0, 0.0);
    let mut t = vec![
        Target {
            p: Vec3::new(20.0, 0.0, 0.0),
            u: still,
        },
        Target {
            p: Vec3::new(12.0, 7.0, 1.2),
            u: still,
        },
        Target {
            p: Vec3::new(6.0, -9.0, -0.7),
            u: still,
        },
        Target {
            p: Vec3::new(30.0, 2.0, 0.4),
            u: Vec3::new(3.0, 0.5, 0.0),
        },
    ];
    if planar {
        for x in &mut t {
            x.p.z = 0.0;
            x.u.z = 0.0;
        }
    }
    assert!(t[0].radial() < -4.9 && t[3].radial() > 2.9);
    t
}

/// How a source writes its radar's detections.
enum Message {
    /// A PointCloud2 of `fields`, `point_step` bytes a point, `values` giving every field's value.
    Cloud {
        fields: &'static [Field],
        point_step: u32,
        values: fn(&Target) -> Vec<(&'static str, f64)>,
    },
    /// A radar_msgs/RadarScan, each return from one detection.
    Scan(fn(&Target) -> RadarReturn),
}

/// One radar of a preset: what its source publishes.
struct Radar {
    /// The radar's name in the preset.
    name: &'static str,
    topic: &'static str,
    /// The header.frame_id the source writes ("" where it is not published).
    frame_id: &'static str,
    /// The sensor measures no elevation.
    planar: bool,
    message: Message,
}

struct Case {
    preset: &'static str,
    radars: Vec<Radar>,
}

// --- The sources' layouts (each preset's comments name the file and commit they come from) ---

/// TI ti_mmwave_rospkg (ROS 2, and ROS 1 3.x): mmWaveCloudType through pcl::toROSMsg.
const TI_MMWAVE: &[Field] = &[
    field("x", 0, F32),
    field("y", 4, F32),
    field("z", 8, F32),
    field("intensity", 16, F32),
    field("velocity", 20, F32),
];

fn ti_mmwave(t: &Target) -> Vec<(&'static str, f64)> {
    vec![
        ("x", t.p.x),
        ("y", t.p.y),
        ("z", t.p.z),
        ("intensity", 17.5),
        ("velocity", t.radial()),
    ]
}

/// robotics-upo/ars548_ros: PointCloud2Modifier::setPointCloud2Fields, packed without padding.
const ARS548_ROS: &[Field] = &[
    field("x", 0, F32),
    field("y", 4, F32),
    field("z", 8, F32),
    field("v", 12, F32),
    field("r", 16, F32),
    field("RCS", 20, I8),
    field("azimuth", 21, F32),
    field("elevation", 25, F32),
];

fn ars548_ros(t: &Target) -> Vec<(&'static str, f64)> {
    vec![
        ("x", t.p.x),
        ("y", t.p.y),
        ("z", t.p.z),
        ("v", t.radial()),
        ("r", t.range()),
        ("RCS", -3.0),
        ("azimuth", t.azimuth()),
        ("elevation", t.elevation()),
    ]
}

/// tier4/nebula: struct PointARS548Detection (alignas(16), 64 bytes) through nebula::ros::to_ros_msg.
const NEBULA_ARS548: &[Field] = &[
    field("x", 0, F32),
    field("y", 4, F32),
    field("z", 8, F32),
    field("azimuth", 16, F32),
    field("azimuth_std", 20, F32),
    field("elevation", 24, F32),
    field("elevation_std", 28, F32),
    field("range", 32, F32),
    field("range_std", 36, F32),
    field("range_rate", 40, F32),
    field("range_rate_std", 44, F32),
    field("rcs", 48, I8),
    field("measurement_id", 50, U16),
    field("positive_predictive_value", 52, U8),
    field("classification", 53, U8),
    field("multi_target_probability", 54, U8),
    field("object_id", 56, U16),
    field("ambiguity_flag", 58, U8),
];

fn nebula_ars548(t: &Target) -> Vec<(&'static str, f64)> {
    vec![
        ("x", t.p.x),
        ("y", t.p.y),
        ("z", t.p.z),
        ("azimuth", t.azimuth()),
        ("azimuth_std", 0.002),
        ("elevation", t.elevation()),
        ("elevation_std", 0.004),
        ("range", t.range()),
        ("range_std", 0.1),
        ("range_rate", t.radial()),
        ("range_rate_std", 0.05),
        ("rcs", 7.0),
        ("measurement_id", 1234.0),
        ("positive_predictive_value", 90.0),
        ("classification", 1.0),
        ("multi_target_probability", 0.0),
        ("object_id", 65535.0),
        ("ambiguity_flag", 0.0),
    ]
}

/// tier4/nebula's RadarScan: range, azimuth, elevation and range_rate of each detection.
fn nebula_ars548_scan(t: &Target) -> RadarReturn {
    RadarReturn {
        range: t.range() as f32,
        azimuth: t.azimuth() as f32,
        elevation: t.elevation() as f32,
        doppler_velocity: t.radial() as f32,
        amplitude: 7.0,
    }
}

/// leochien1110/ars_40X_ros2 radar_points: struct PointCloudRadar (EIGEN_ALIGN16, 48 bytes) through
/// pcl::toROSMsg.
const ARS_40X_ROS2: &[Field] = &[
    field("x", 0, F32),
    field("y", 4, F32),
    field("z", 8, F32),
    field("intensity", 16, F32),
    field("velocity", 20, F32),
    field("vx", 24, F32),
    field("vy", 28, F32),
    field("dynamic_property", 32, I8),
    field("cls", 33, I8),
    field("prob_of_exist", 34, I8),
    field("ambig_state", 35, I8),
    field("invalid_state", 36, I8),
];

fn ars_40x_ros2(t: &Target) -> Vec<(&'static str, f64)> {
    vec![
        ("x", t.p.x),
        ("y", t.p.y),
        ("z", 0.0),
        ("intensity", 5.5),
        // sqrt(vx^2 + vy^2): a speed without sign, which the preset must not read.
        ("velocity", t.u.x.hypot(t.u.y)),
        ("vx", t.u.x),
        ("vy", t.u.y),
        ("dynamic_property", 1.0),
        ("cls", 0.0),
        ("prob_of_exist", 7.0),
        ("ambig_state", 4.0),
        ("invalid_state", 0.0),
    ]
}

/// SNAIL-Radar /ars548 as the dataset's folder_to_bag.py rebuilds it (4 bytes after z).
const SNAIL_ARS548: &[Field] = &[
    field("x", 0, F32),
    field("y", 4, F32),
    field("z", 8, F32),
    field("doppler", 16, F32),
    field("intensity", 20, F32),
    field("range_std", 24, F32),
    field("azimuth_std", 28, F32),
    field("elevation_std", 32, F32),
    field("doppler_std", 36, F32),
];

fn snail_ars548(t: &Target) -> Vec<(&'static str, f64)> {
    vec![
        ("x", t.p.x),
        ("y", t.p.y),
        ("z", t.p.z),
        ("doppler", t.radial()),
        ("intensity", 12.0),
        ("range_std", 0.08),
        ("azimuth_std", 0.003),
        ("elevation_std", 0.005),
        ("doppler_std", 0.04),
    ]
}

/// SNAIL-Radar /radar_pcl2 (Oculii Eagle) as the dataset's folder_to_bag.py rebuilds it: 17 FLOAT32
/// back to back.
const SNAIL_EAGLE: &[Field] = &[
    field("x", 0, F32),
    field("y", 4, F32),
    field("z", 8, F32),
    field("Doppler", 12, F32),
    field("Range", 16, F32),
    field("Power", 20, F32),
    field("Alpha", 24, F32),
    field("Beta", 28, F32),
    field("rangeAccu", 32, F32),
    field("aziAccu", 36, F32),
    field("eleAccu", 40, F32),
    field("dopplerAccu", 44, F32),
    field("recoveredSpeed", 48, F32),
    field("dotFlags", 52, F32),
    field("denoiseFlag", 56, F32),
    field("historyFrameFlag", 60, F32),
    field("dopplerCorrectionFlag", 64, F32),
];

fn snail_eagle(t: &Target) -> Vec<(&'static str, f64)> {
    let mut v = eagle_channels(t);
    v.extend([
        ("rangeAccu", 0.22),
        ("aziAccu", 0.5),
        ("eleAccu", 1.0),
        ("dopplerAccu", 0.05),
        ("recoveredSpeed", t.u.x),
        ("dotFlags", 0.0),
        ("denoiseFlag", 0.0),
        ("historyFrameFlag", 0.0),
        ("dopplerCorrectionFlag", 0.0),
    ]);
    v
}

/// NTU4DRadLM's sensor_msgs/PointCloud turned into a PointCloud2 as sensor_msgs'
/// convertPointCloudToPointCloud2 does: x, y, z, then one FLOAT32 per channel, back to back.
const NTU_EAGLE: &[Field] = &[
    field("x", 0, F32),
    field("y", 4, F32),
    field("z", 8, F32),
    field("Doppler", 12, F32),
    field("Range", 16, F32),
    field("Power", 20, F32),
    field("Alpha", 24, F32),
    field("Beta", 28, F32),
];

/// The Eagle's position and channel values (Alpha, Beta: degrees in the native right-down-forward
/// frame, not read).
fn eagle_channels(t: &Target) -> Vec<(&'static str, f64)> {
    vec![
        ("x", t.p.x),
        ("y", t.p.y),
        ("z", t.p.z),
        ("Doppler", t.radial()),
        ("Range", t.range()),
        ("Power", 21.0),
        ("Alpha", -t.azimuth().to_degrees()),
        ("Beta", -t.elevation().to_degrees()),
    ]
}

/// ColoRadar /mmWaveDataHdl/RScan as goggles' RadarPoint lays it out (PCL_ADD_POINT4D, intensity,
/// range, doppler).
const COLORADAR_SINGLE_CHIP: &[Field] = &[
    field("x", 0, F32),
    field("y", 4, F32),
    field("z", 8, F32),
    field("intensity", 16, F32),
    field("range", 20, F32),
    field("doppler", 24, F32),
];

fn coloradar_single_chip(t: &Target) -> Vec<(&'static str, f64)> {
    vec![
        ("x", t.p.x),
        ("y", t.p.y),
        ("z", t.p.z),
        ("intensity", 30.0),
        ("range", t.range()),
        ("doppler", t.radial()),
    ]
}

/// ColoRadar cascade detections of coloradar_tools' heatmap_to_pointcloud.py (create_cloud, packed).
const COLORADAR_CASCADE: &[Field] = &[
    field("x", 0, F32),
    field("y", 4, F32),
    field("z", 8, F32),
    field("intensity", 12, F32),
    field("doppler", 16, F32),
];

fn coloradar_cascade(t: &Target) -> Vec<(&'static str, f64)> {
    vec![
        ("x", t.p.x),
        ("y", t.p.y),
        ("z", t.p.z),
        ("intensity", 0.8),
        ("doppler", t.radial()),
    ]
}

/// rio's own cloud format (reve's RadarPointCloudType, registered fields only; range@28 unregistered).
const RIO: &[Field] = &[
    field("x", 0, F32),
    field("y", 4, F32),
    field("z", 8, F32),
    field("snr_db", 16, F32),
    field("noise_db", 24, F32),
    field("v_doppler_mps", 20, F32),
];

fn rio(t: &Target) -> Vec<(&'static str, f64)> {
    vec![
        ("x", t.p.x),
        ("y", t.p.y),
        ("z", t.p.z),
        ("snr_db", 14.0),
        ("noise_db", 61.0),
        ("v_doppler_mps", t.radial()),
    ]
}

/// MSC-RAD4R /oculii_radar/point_cloud as a public reader of its bags declares the point.
const MSC_RAD4R: &[Field] = &[
    field("x", 0, F32),
    field("y", 4, F32),
    field("z", 8, F32),
    field("alpha", 16, F32),
    field("beta", 20, F32),
    field("range", 24, F32),
    field("doppler", 28, F32),
    field("power", 32, F32),
    field("recoveredSpeed", 36, F32),
    field("dotFlags", 40, U16),
    field("denoiseFlag", 42, U16),
    field("historyFrameFlag", 44, U16),
    field("dopplerCorrectionFlag", 46, U16),
];

fn msc_rad4r(t: &Target) -> Vec<(&'static str, f64)> {
    vec![
        ("x", t.p.x),
        ("y", t.p.y),
        ("z", t.p.z),
        ("alpha", t.azimuth().to_degrees()),
        ("beta", t.elevation().to_degrees()),
        ("range", t.range()),
        ("doppler", t.radial()),
        ("power", 19.0),
        ("recoveredSpeed", t.u.x),
        ("dotFlags", 0.0),
        ("denoiseFlag", 0.0),
        ("historyFrameFlag", 0.0),
        ("dopplerCorrectionFlag", 1.0),
    ]
}

fn cloud_radar(
    name: &'static str,
    topic: &'static str,
    frame_id: &'static str,
    fields: &'static [Field],
    point_step: u32,
    values: fn(&Target) -> Vec<(&'static str, f64)>,
) -> Radar {
    Radar {
        name,
        topic,
        frame_id,
        planar: false,
        message: Message::Cloud {
            fields,
            point_step,
            values,
        },
    }
}

/// Every dataset and driver preset and what its source publishes.
fn cases() -> Vec<Case> {
    let one = |preset, radar| Case {
        preset,
        radars: vec![radar],
    };
    vec![
        one(
            "driver_ars548_ros.yaml",
            cloud_radar(
                "front",
                "/PointCloudDetection",
                "ARS_548",
                ARS548_ROS,
                29,
                ars548_ros,
            ),
        ),
        one(
            "driver_nebula_ars548_points.yaml",
            cloud_radar(
                "front",
                "/detection_points",
                "continental",
                NEBULA_ARS548,
                64,
                nebula_ars548,
            ),
        ),
        one(
            "driver_nebula_ars548_scan.yaml",
            Radar {
                name: "front",
                topic: "/scan_raw",
                frame_id: "continental",
                planar: false,
                message: Message::Scan(nebula_ars548_scan),
            },
        ),
        one(
            "driver_ti_mmwave.yaml",
            cloud_radar(
                "ti",
                "/ti_mmwave/radar_scan_pcl",
                "ti_mmwave_0",
                TI_MMWAVE,
                32,
                ti_mmwave,
            ),
        ),
        one(
            "driver_ars_40x_ros2.yaml",
            Radar {
                planar: true,
                ..cloud_radar("front", "/radar_points", "", ARS_40X_ROS2, 48, ars_40x_ros2)
            },
        ),
        one(
            "rio_iwr6843.yaml",
            cloud_radar(
                "right",
                "/ti_mmwave/radar_scan_pcl",
                "",
                TI_MMWAVE,
                32,
                ti_mmwave,
            ),
        ),
        Case {
            preset: "x_rio_iwr6843.yaml",
            radars: ["left", "center", "right"]
                .into_iter()
                .zip([
                    "/sensor_platform/radar_left/scan",
                    "/sensor_platform/radar_center/scan",
                    "/sensor_platform/radar_right/scan",
                ])
                .map(|(name, topic)| cloud_radar(name, topic, "", RIO, 32, rio))
                .collect(),
        },
        one(
            "snail_ars548.yaml",
            cloud_radar(
                "ars548",
                "/ars548",
                "ars548",
                SNAIL_ARS548,
                40,
                snail_ars548,
            ),
        ),
        one(
            "snail_eagle.yaml",
            cloud_radar(
                "eagle",
                "/radar_pcl2",
                "oculii",
                SNAIL_EAGLE,
                68,
                snail_eagle,
            ),
        ),
        one(
            "ntu4dradlm_eagle.yaml",
            cloud_radar("eagle", "/radar_pcl", "", NTU_EAGLE, 32, eagle_channels),
        ),
        one(
            "coloradar_awr1843.yaml",
            cloud_radar(
                "single_chip",
                "/mmWaveDataHdl/RScan",
                "",
                COLORADAR_SINGLE_CHIP,
                32,
                coloradar_single_chip,
            ),
        ),
        one(
            "coloradar_cascade.yaml",
            cloud_radar(
                "cascade",
                "/cascade/pointcloud",
                "cascade_radar",
                COLORADAR_CASCADE,
                20,
                coloradar_cascade,
            ),
        ),
        one(
            "msc_rad4r_eagle.yaml",
            cloud_radar(
                "eagle",
                "/oculii_radar/point_cloud",
                "",
                MSC_RAD4R,
                48,
                msc_rad4r,
            ),
        ),
    ]
}

// --- Helpers ---

fn preset_path(file: &str) -> PathBuf {
    Path::new(REPO).join("params/examples").join(file)
}

/// A preset as the node and `dc_loc run` read it (node `/dc_loc`), validated.
fn load(file: &str) -> Config {
    load_params(&preset_path(file), "/", "dc_loc", &[]).unwrap_or_else(|e| panic!("{file}: {e}"))
}

fn t0() -> Stamp {
    Stamp(1_700_000_000_000_000_000)
}

/// Fields inside a point and not overlapping: the layout tables are typed in by hand.
fn check_layout(fields: &[Field], point_step: u32) {
    let size = |d: u8| match d {
        PointField::INT8 | PointField::UINT8 => 1,
        PointField::INT16 | PointField::UINT16 => 2,
        PointField::FLOAT64 => 8,
        _ => 4,
    };
    let mut spans: Vec<(u32, u32, &str)> = fields
        .iter()
        .map(|f| (f.offset, f.offset + size(f.datatype), f.name))
        .collect();
    spans.sort();
    for w in spans.windows(2) {
        assert!(w[0].1 <= w[1].0, "fields {} and {} overlap", w[0].2, w[1].2);
    }
    let end = spans.last().map_or(0, |s| s.1);
    assert!(
        end <= point_step,
        "field {} ends past point_step {point_step}",
        spans.last().unwrap().2
    );
}

/// A little-endian cloud of `fields`, one point per entry of `points` (every field given a value, the
/// bytes between fields left as garbage).
fn cloud(
    fields: &[Field],
    point_step: u32,
    frame_id: &str,
    points: &[Vec<(&'static str, f64)>],
) -> PointCloud2 {
    check_layout(fields, point_step);
    let mut data = Vec::new();
    for values in points {
        for (name, _) in values {
            assert!(fields.iter().any(|f| f.name == *name), "no field {name}");
        }
        let mut rec = vec![0xAAu8; point_step as usize];
        for f in fields {
            let v = values
                .iter()
                .find(|(n, _)| *n == f.name)
                .unwrap_or_else(|| panic!("no value for field {}", f.name))
                .1;
            let bytes = match f.datatype {
                PointField::INT8 => (v as i8).to_le_bytes().to_vec(),
                PointField::UINT8 => (v as u8).to_le_bytes().to_vec(),
                PointField::UINT16 => (v as u16).to_le_bytes().to_vec(),
                PointField::FLOAT32 => (v as f32).to_le_bytes().to_vec(),
                other => panic!("datatype {other} not used by any source here"),
            };
            let o = f.offset as usize;
            rec[o..o + bytes.len()].copy_from_slice(&bytes);
        }
        data.extend(rec);
    }
    let width = points.len() as u32;
    PointCloud2 {
        header: Header {
            stamp: t0().into(),
            frame_id: frame_id.into(),
        },
        height: 1,
        width,
        fields: fields
            .iter()
            .map(|f| PointField {
                name: f.name.into(),
                offset: f.offset,
                datatype: f.datatype,
                count: 1,
            })
            .collect(),
        is_bigendian: false,
        point_step,
        row_step: point_step * width,
        data,
        is_dense: true,
    }
}

/// The clouds, each on its radar's topic (after a trigger, for a radar with a trigger topic), and one
/// sample of the preset's pose input (odometry, or a gyro sample), through a rosbag2 and
/// `BagInputs`: what reaches the pipeline, by radar index.
fn through_bag(
    name: &str,
    cfg: &Config,
    clouds: &[(&str, PointCloud2)],
) -> Vec<(usize, PointCloud2)> {
    let dir = common::scratch("presets_tests", name).join("bag");
    let mut w = BagWriter::create(&dir).unwrap();
    match cfg.odometry.source {
        OdometrySource::Topic => {
            let odom_topic = w.add_topic(&cfg.odometry.topic, schema::ODOMETRY).unwrap();
            let mut odom = Odometry::default();
            odom.header.stamp = t0().into();
            odom.header.frame_id = "odom".into();
            odom.child_frame_id = cfg.body_frame.clone();
            w.write(odom_topic, t0(), &odom).unwrap();
        }
        OdometrySource::Radar => {}
        OdometrySource::RadarImu => {
            let imu_topic = w.add_topic(&cfg.imu.topic, schema::IMU).unwrap();
            let mut imu = Imu::default();
            imu.header.stamp = t0().into();
            w.write(imu_topic, t0(), &imu).unwrap();
        }
    }
    let mut topics = std::collections::BTreeMap::new();
    let mut id_of = |w: &mut BagWriter, topic: &str, type_name: &'static str| {
        *topics
            .entry(topic.to_string())
            .or_insert_with(|| w.add_topic(topic, type_name).unwrap())
    };
    for (k, (topic, c)) in clouds.iter().enumerate() {
        let at = Stamp(t0().0 + 1_000_000 * (k as i64 + 1));
        let trigger = cfg
            .radar_list()
            .into_iter()
            .find(|(_, r)| r.topic == *topic && !r.trigger_topic.is_empty())
            .map(|(_, r)| r.trigger_topic.clone());
        if let Some(trigger) = trigger {
            let id = id_of(&mut w, &trigger, schema::HEADER);
            let header = Header {
                stamp: at.into(),
                frame_id: String::new(),
            };
            w.write(id, at, &header).unwrap();
        }
        let id = id_of(&mut w, topic, schema::POINT_CLOUD2);
        w.write(id, at, c).unwrap();
    }
    w.finish().unwrap();
    let reader = BagReader::open(&dir).unwrap();
    BagInputs::new(&reader, cfg, None)
        .unwrap_or_else(|e| panic!("{name}: {e}"))
        .filter_map(
            |item| match item.unwrap_or_else(|e| panic!("{name}: {e}")) {
                Input::Radar { radar, cloud } => Some((radar, cloud)),
                _ => None,
            },
        )
        .collect()
}

/// The decoded detections are the targets: positions (float32 precision), the radial velocity
/// positive away, and the rcs field's value where the preset reads one.
fn check_detections(what: &str, got: &[Detection], want: &[Target], rcs: Option<f64>) {
    assert_eq!(got.len(), want.len(), "{what}: detections");
    for (i, (d, t)) in got.iter().zip(want).enumerate() {
        let dp = (d.p_radar - t.p).norm();
        assert!(
            dp < 1e-4,
            "{what}: point {i} at {:?}, want {:?}",
            d.p_radar,
            t.p
        );
        assert!(
            (d.v_r - t.radial()).abs() < 1e-4,
            "{what}: point {i} v_r {}, want {} (positive away)",
            d.v_r,
            t.radial()
        );
        assert_eq!(d.rcs, rcs, "{what}: point {i} rcs");
    }
}

// --- Tests ---

/// Every preset of params/examples loads and validates; every one but the generic examples has a case
/// (or a test of its own).
#[test]
fn every_preset_loads_and_has_a_case() {
    let mut files: Vec<String> = std::fs::read_dir(Path::new(REPO).join("params/examples"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".yaml"))
        .collect();
    files.sort();
    let cases = cases();
    for f in &files {
        let cfg = load(f);
        assert!(!cfg.radar_names.is_empty(), "{f}");
        if !GENERIC.contains(&f.as_str()) && !OWN_TEST.contains(&f.as_str()) {
            assert!(
                cases.iter().any(|c| c.preset == f.as_str()),
                "{f} has no case in tests/presets.rs"
            );
        }
    }
    for c in &cases {
        assert!(
            files.iter().any(|f| f.as_str() == c.preset),
            "{} is missing",
            c.preset
        );
    }
}

/// A cloud or RadarScan in each source's exact layout decodes through the preset into the detections
/// it holds, the radial velocity positive away.
#[test]
fn each_source_layout_decodes_through_its_preset() {
    for case in cases() {
        let cfg = load(case.preset);
        let names: Vec<&str> = case.radars.iter().map(|r| r.name).collect();
        assert_eq!(cfg.radar_names, names, "{}: radar_names", case.preset);
        let mut clouds = Vec::new();
        for r in &case.radars {
            let rc: &RadarConfig = &cfg.radars[r.name];
            let what = format!("{} {}", case.preset, r.name);
            assert_eq!(rc.topic, r.topic, "{what}: topic");
            // The source's frame, or "" (accept any) where the source's is not published.
            assert_eq!(rc.frame_id, r.frame_id, "{what}: frame_id");
            let want = targets(r.planar);
            match &r.message {
                Message::Cloud {
                    fields,
                    point_step,
                    values,
                } => {
                    assert_eq!(rc.message, RadarMessage::PointCloud2, "{what}");
                    let points: Vec<_> = want.iter().map(values).collect();
                    clouds.push((r.topic, cloud(fields, *point_step, r.frame_id, &points)));
                }
                Message::Scan(ret) => {
                    assert_eq!(rc.message, RadarMessage::RadarScan, "{what}");
                    let msg = RadarScan {
                        header: Header {
                            stamp: t0().into(),
                            frame_id: r.frame_id.into(),
                        },
                        returns: want.iter().map(ret).collect(),
                    };
                    let Input::Scan(scan) = radar_scan_input(0, t0(), &msg) else {
                        panic!("{what}: not a scan");
                    };
                    check_detections(&what, &scan.detections, &want, None);
                }
            }
        }
        if clouds.is_empty() {
            continue;
        }
        let name = case.preset.trim_end_matches(".yaml");
        let got = through_bag(name, &cfg, &clouds);
        assert_eq!(
            got.len(),
            clouds.len(),
            "{}: clouds through the bag",
            case.preset
        );
        for (index, r) in case.radars.iter().enumerate() {
            let Message::Cloud { values, .. } = &r.message else {
                continue;
            };
            let what = format!("{} {}", case.preset, r.name);
            let rc = &cfg.radars[r.name];
            let mine: Vec<&PointCloud2> = got
                .iter()
                .filter(|(radar, _)| *radar == index)
                .map(|(_, c)| c)
                .collect();
            assert_eq!(mine.len(), 1, "{what}: clouds routed to the radar");
            let decoded =
                decode_detections(mine[0], &rc.fields).unwrap_or_else(|e| panic!("{what}: {e}"));
            let want = targets(r.planar);
            let rcs = (!rc.fields.rcs.is_empty()).then(|| {
                values(&want[0])
                    .into_iter()
                    .find(|(n, _)| *n == rc.fields.rcs)
                    .unwrap_or_else(|| panic!("{what}: no rcs field {}", rc.fields.rcs))
                    .1
            });
            check_detections(&what, &decoded.detections, &want, rcs);
        }
    }
}

/// TIER IV's ars408_driver fills doppler_velocity with VrelLong / cos(azimuth) of each tracked object
/// (ConvertRadarObjectToRadarReturn): the radial velocity at the boresight, 1 / cos(azimuth)^2 times
/// it for a static object off the boresight. The preset reads it as the driver writes it.
#[test]
fn tier4_ars408_scan_is_radial_only_at_the_boresight() {
    let cfg = load("driver_tier4_ars408_scan.yaml");
    let rc = &cfg.radars["front"];
    assert_eq!(
        (rc.topic.as_str(), rc.frame_id.as_str(), rc.message),
        ("/scan", "ars408", RadarMessage::RadarScan)
    );
    let want = targets(true);
    let tier4 = |t: &Target| RadarReturn {
        range: t.p.x.hypot(t.p.y) as f32,
        azimuth: t.azimuth() as f32,
        elevation: 0.0,
        doppler_velocity: (t.u.x / t.azimuth().cos()) as f32,
        amplitude: 0.0,
    };
    let msg = RadarScan {
        header: Header {
            stamp: t0().into(),
            frame_id: "ars408".into(),
        },
        returns: want.iter().map(tier4).collect(),
    };
    let Input::Scan(scan) = radar_scan_input(0, t0(), &msg) else {
        panic!("not a scan");
    };
    let d = &scan.detections;
    for (got, t) in d.iter().zip(&want) {
        assert!((got.p_radar - t.p).norm() < 1e-4);
        assert!((got.v_r - t.u.x / t.azimuth().cos()).abs() < 1e-4);
    }
    // Dead ahead the driver's value is the radial velocity ...
    assert!((d[0].v_r - want[0].radial()).abs() < 1e-4);
    // ... off the boresight a static object's is 1 / cos(az)^2 times it (30 degrees: 1.34).
    for i in [1, 2] {
        let scale = want[i].azimuth().cos().powi(2);
        assert!((d[i].v_r * scale - want[i].radial()).abs() < 1e-4);
        assert!((d[i].v_r - want[i].radial()).abs() > 0.5);
    }
}

/// `R = Rz(yaw) Ry(pitch) Rx(roll)` and the translation of a preset's radar equal a calibration's.
fn assert_mount(cfg: &Config, radar: &str, r: Mat3, t: [f64; 3], what: &str) {
    let iso = cfg.radars[radar].t_body_radar();
    let got = iso.rotation.to_rotation_matrix().into_inner();
    assert!(
        (got - r).norm() < 1e-5,
        "{what}: rotation\n{got}\nwant\n{r}"
    );
    assert!(
        (iso.translation.vector - Vec3::from(t)).norm() < 1e-6,
        "{what}: translation {:?}, want {t:?}",
        iso.translation.vector
    );
}

/// Rotation of a quaternion given as x, y, z, w.
fn quat(x: f64, y: f64, z: f64, w: f64) -> Mat3 {
    UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
        .to_rotation_matrix()
        .into_inner()
}

/// The presets' extrinsics are the datasets' calibrations, as their files give them.
#[test]
fn extrinsics_are_the_dataset_calibrations() {
    // rio calib_ti_mmwave_rospkg_dataset.yaml: q_b_r in rio's radar frame (x right, y boresight),
    // which rio reaches from a ti_mmwave_rospkg point by (x, y, z) -> (-y, x, z).
    let rio_of_ros = Mat3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let q = quat(
        0.923218461092,
        0.375992995522,
        -0.0267831268675,
        -0.0746967504749,
    );
    assert_mount(
        &load("rio_iwr6843.yaml"),
        "right",
        q * rio_of_ros,
        [0.03, 0.03, -0.06],
        "rio",
    );

    // x_rio_demo_calib_*.yaml: the clouds are in rio's radar frame already.
    let x_rio = load("x_rio_iwr6843.yaml");
    for (radar, t, q) in [
        (
            "left",
            [0.02, 0.11, 0.07],
            quat(-0.376115074, -0.926436839, -0.001703021, 0.015790310),
        ),
        (
            "center",
            [0.04, 0.03, -0.03],
            quat(0.030573233, -0.031111548, -0.712571593, 0.700242154),
        ),
        (
            "right",
            [0.05, -0.04, 0.04],
            quat(-0.926237675, -0.373772748, 0.026054024, 0.041217599),
        ),
    ] {
        assert_mount(&x_rio, radar, q, t, &format!("x_rio {radar}"));
    }

    // SNAIL-Radar matlab/Body_T_X36d.m, Body_T_Ars548.m (2024-01-13 on), Body_T_Oculii.m (refined).
    let x36d_r_xt32 = Mat3::new(
        -0.001402106,
        -0.999967799,
        0.007901562,
        0.999997759,
        -0.001414596,
        -0.001575345,
        0.001586472,
        0.007899336,
        0.999967541,
    );
    let body_r_xt32 = Mat3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let body_r_x36d = body_r_xt32 * x36d_r_xt32.transpose();
    let x36d_r_ars548 = Mat3::new(
        0.998536832685765,
        0.0494527313667313,
        -0.0218774114156895,
        -0.0494029253854064,
        0.998774972684787,
        0.00281156573196022,
        0.0219896505939817,
        -0.0017266438170843,
        0.999756707388295,
    );
    assert_mount(
        &load("snail_ars548.yaml"),
        "ars548",
        body_r_x36d * x36d_r_ars548,
        [0.0, 0.0, 0.07],
        "SNAIL ars548",
    );
    let x36d_r_oculii = Mat3::new(
        0.999829834123514,
        0.0183936527785399,
        -0.001405821470991,
        -0.0183512882701082,
        0.999498727400647,
        0.0257977546176971,
        0.00187963171211191,
        -0.0257675660851007,
        0.999666194048132,
    );
    assert_mount(
        &load("snail_eagle.yaml"),
        "eagle",
        body_r_x36d * x36d_r_oculii,
        [0.07, 0.0, -0.115],
        "SNAIL eagle",
    );

    // NTU4DRadLM, 4DRadarSLAM apps/preprocessing_nodelet.cpp: Radar_to_livox =
    // inverse(livox_to_RGB) * Thermal_to_RGB * Radar_to_Thermal * Change_Radarframe.
    #[rustfmt::skip]
    let livox_to_rgb = Matrix4::new(
        -0.006878330000, -0.999969000000, 0.003857230000, 0.029164500000,
        -7.737180000000e-05, -0.003856790000, -0.999993000000, 0.045695200000,
        0.999976000000, -0.006878580000, -5.084110000000e-05, -0.19018000000,
        0.0, 0.0, 0.0, 1.0,
    );
    #[rustfmt::skip]
    let thermal_to_rgb = Matrix4::new(
        0.9999526089706319, 0.008963747151337641, -0.003798822163962599, 0.18106962419014,
        -0.008945181135788245, 0.9999481006917174, 0.004876439015823288, -0.04546324090016857,
        0.00384233617405678, -0.004842226763999368, 0.999980894463835, 0.08046453079998771,
        0.0, 0.0, 0.0, 1.0,
    );
    #[rustfmt::skip]
    let radar_to_thermal = Matrix4::new(
        0.999665, 0.00925436, -0.0241851, -0.0248342,
        -0.00826999, 0.999146, 0.0404891, 0.0958317,
        0.0245392, -0.0402755, 0.998887, 0.0268037,
        0.0, 0.0, 0.0, 1.0,
    );
    #[rustfmt::skip]
    let change_radarframe = Matrix4::new(
        0.0, -1.0, 0.0, 0.0,
        0.0, 0.0, -1.0, 0.0,
        1.0, 0.0, 0.0, 0.0,
        0.0, 0.0, 0.0, 1.0,
    );
    let radar_to_livox =
        livox_to_rgb.try_inverse().unwrap() * thermal_to_rgb * radar_to_thermal * change_radarframe;
    let r: Mat3 = radar_to_livox.fixed_view::<3, 3>(0, 0).into_owned();
    let t = radar_to_livox.fixed_view::<3, 1>(0, 3);
    assert_mount(
        &load("ntu4dradlm_eagle.yaml"),
        "eagle",
        r,
        [t[0], t[1], t[2]],
        "NTU4DRadLM",
    );
}

/// Every preset sets each radar's `beta` and noise sigmas: none of them is left on the defaults
/// (which describe an ARS408-21), so none warns at start.
#[test]
fn every_preset_sets_its_radars_noise() {
    use dc_loc::params::ParamSet;
    use dc_loc::params::checks::defaulted_noise;
    for entry in std::fs::read_dir(Path::new(REPO).join("params/examples")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "yaml") {
            continue;
        }
        let file = path.file_name().unwrap().to_string_lossy().into_owned();
        let text = std::fs::read_to_string(&path).unwrap();
        let set = ParamSet::from_yaml(&text, "/", "dc_loc").unwrap();
        let warnings = defaulted_noise(&set, &load(&file));
        assert!(warnings.is_empty(), "{file}: {warnings:?}");
    }
}
