//! A simulated drive as a rosbag2 bag (what `dc_loc sim` writes), with the params YAML to run it.
//!
//! Entry points: [`export_drive`] (bag + `dc_loc.yaml` in one directory, an [`ExportSummary`]),
//! [`write_bag`] (the bag alone), [`params_yaml`] (any [`dc_loc_core::pipeline::Config`] as a ROS 2
//! params file; also makes the shipped `params/*.yaml`), [`drive_description`].
//!
//! The bag, written by [`BagWriter`] with log time = stamp (one drive, byte-identical files), holds
//! each radar's scans on its topic ([`SimDrive::to_config`]) as `PointCloud2` in its frame with FLOAT32
//! `x, y, z, v_r, rcs` ([`CloudLayout::radar_f32`]); the drifting odometry on `/odom` (`odom` ->
//! `base_link`, the simulator's `odom_frame` and `body_frame`) and the true pose and twist on
//! [`GROUND_TRUTH_TOPIC`] (frame `map`), both `nav_msgs/msg/Odometry`; with a simulated gyro
//! (`imu.rate`), its samples as `sensor_msgs/msg/Imu` on `imu.topic` in the body frame (angular
//! velocity only: no orientation, its covariance's first element -1); at the start, a
//! `tf2_msgs/msg/TFMessage` on [`TF_STATIC_TOPIC`] with every radar's extrinsic `base_link -> <radar
//! frame>`, offered transient local as tf2's static broadcaster does.

use std::path::{Path, PathBuf};

use crate::sim::{SimConfig, SimDrive, SimEventRef};
use dc_loc_core::cloud::{CloudLayout, EncodeError, encode_detections};
use dc_loc_core::math::Stamp;
use dc_loc_core::msgs::geometry_msgs::{Transform, TransformStamped};
use dc_loc_core::msgs::std_msgs::Header;
use dc_loc_core::msgs::tf2_msgs::TFMessage;
use dc_loc_io::bag::{BagError, BagWriter, schema};

/// Topic of the ground-truth odometry.
pub const GROUND_TRUTH_TOPIC: &str = "/ground_truth/odom";
/// Topic of the static transforms.
pub const TF_STATIC_TOPIC: &str = "/tf_static";
/// Name of the params file written into the bag directory.
pub const PARAMS_FILE: &str = "dc_loc.yaml";
pub use dc_loc_io::params::file::{NODE_NAME, params_yaml};

/// Why a drive could not be exported.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The bag writer failed (the directory exists and is not empty, I/O, ...).
    #[error(transparent)]
    Bag(#[from] BagError),
    /// A scan could not be encoded as a PointCloud2.
    #[error("scan of radar {radar} at {:.6} s: {source}", .stamp.as_secs_f64())]
    Encode {
        /// Radar index.
        radar: usize,
        /// Scan stamp.
        stamp: Stamp,
        /// The encoder's error.
        #[source]
        source: EncodeError,
    },
    /// The params file could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
}

/// Messages written on one topic.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicCount {
    /// Topic name.
    pub topic: String,
    /// Message type.
    pub type_name: &'static str,
    /// Messages written.
    pub count: u64,
}

/// What [`export_drive`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportSummary {
    /// The bag directory.
    pub bag_dir: PathBuf,
    /// The params YAML (inside the bag directory).
    pub params_file: PathBuf,
    /// Messages in the bag.
    pub messages: u64,
    /// Per topic, in the order added.
    pub topics: Vec<TopicCount>,
}

/// Writes the bag of `drive` into `dir` (created, or empty); returns the bag directory and the
/// messages per topic.
pub fn write_bag(drive: &SimDrive, dir: &Path) -> Result<(PathBuf, Vec<TopicCount>), ExportError> {
    let sim = &drive.setup.config;
    let cfg = drive.to_config();
    let mut bag = BagWriter::create(dir)?;
    let tf_topic = bag.add_topic(TF_STATIC_TOPIC, schema::TF_MESSAGE)?;
    let odom_topic = bag.add_topic(&cfg.odometry.topic, schema::ODOMETRY)?;
    let gt_topic = bag.add_topic(GROUND_TRUTH_TOPIC, schema::ODOMETRY)?;
    let imu_topic = if drive.imu.is_empty() {
        None
    } else {
        Some(bag.add_topic(&cfg.imu.topic, schema::IMU)?)
    };
    let mut radar_topics = Vec::new();
    for (_, rc) in cfg.radar_list() {
        radar_topics.push((
            bag.add_topic(&rc.topic, schema::POINT_CLOUD2)?,
            rc.frame_id.clone(),
        ));
    }
    let count = |topic: &str, type_name| TopicCount {
        topic: topic.to_string(),
        type_name,
        count: 0,
    };
    let mut counts = vec![
        count(TF_STATIC_TOPIC, schema::TF_MESSAGE),
        count(&cfg.odometry.topic, schema::ODOMETRY),
        count(GROUND_TRUTH_TOPIC, schema::ODOMETRY),
    ];
    counts.extend(
        cfg.radar_list()
            .into_iter()
            .map(|(_, rc)| count(&rc.topic, schema::POINT_CLOUD2)),
    );
    // The gyro's count, last, when there is one.
    let imu_count = counts.len();
    if imu_topic.is_some() {
        counts.push(count(&cfg.imu.topic, schema::IMU));
    }

    // The extrinsics once, at the start.
    let start = drive.setup.start;
    let tf = TFMessage {
        transforms: cfg
            .radar_list()
            .into_iter()
            .map(|(_, rc)| TransformStamped {
                header: Header {
                    stamp: start.into(),
                    frame_id: sim.body_frame.clone(),
                },
                child_frame_id: rc.frame_id.clone(),
                transform: Transform::from(&rc.t_body_radar()),
            })
            .collect(),
    };
    bag.write(tf_topic, start, &tf)?;
    counts[0].count += 1;

    let layout = CloudLayout::radar_f32();
    for ev in drive.events() {
        match ev {
            SimEventRef::GroundTruth(p) => {
                bag.write(
                    gt_topic,
                    p.stamp,
                    &p.to_msg(&sim.map_frame, &sim.body_frame),
                )?;
                counts[2].count += 1;
            }
            SimEventRef::Odometry(o) => {
                bag.write(
                    odom_topic,
                    o.stamp,
                    &o.to_msg(&sim.odom_frame, &sim.body_frame),
                )?;
                counts[1].count += 1;
            }
            SimEventRef::Imu(i) => {
                if let Some(topic) = imu_topic {
                    let sigma = sim.imu.noise_density * sim.imu.rate.sqrt();
                    bag.write(topic, i.stamp, &i.to_msg(&sim.body_frame, sigma))?;
                    counts[imu_count].count += 1;
                }
            }
            SimEventRef::Scan(s) => {
                let r = s.scan.radar;
                let Some((topic, frame_id)) = radar_topics.get(r) else {
                    continue; // every scan's radar has a topic: to_config lists the simulated radars
                };
                let header = Header {
                    stamp: s.scan.stamp.into(),
                    frame_id: frame_id.clone(),
                };
                let cloud =
                    encode_detections(&s.scan.detections, &layout, header).map_err(|source| {
                        ExportError::Encode {
                            radar: r,
                            stamp: s.scan.stamp,
                            source,
                        }
                    })?;
                bag.write(*topic, s.scan.stamp, &cloud)?;
                counts[3 + r].count += 1;
            }
        }
    }
    Ok((bag.finish()?, counts))
}

/// Writes the bag of `drive` into `dir` and, beside its files, [`PARAMS_FILE`]: the pipeline
/// configuration of the drive ([`SimDrive::to_config`]) as a params YAML for node [`NODE_NAME`].
pub fn export_drive(drive: &SimDrive, dir: &Path) -> Result<ExportSummary, ExportError> {
    let (bag_dir, topics) = write_bag(drive, dir)?;
    let mut header = format!(
        "dc_loc parameters for the simulated drive in this bag directory (written by `dc_loc sim`):\n{}\n\
         Run it with: dc_loc run --bag {} --params {} --out closures.jsonl",
        drive_description(&drive.setup.config),
        bag_dir.display(),
        bag_dir.join(PARAMS_FILE).display()
    );
    if !drive.imu.is_empty() {
        header.push_str(
            "\nWithout the wheel odometry, from the radar and the gyro: add -p odometry.source:=radar_imu",
        );
    }
    let params_file = bag_dir.join(PARAMS_FILE);
    std::fs::write(&params_file, params_yaml(&drive.to_config(), &header)).map_err(|source| {
        ExportError::Io {
            path: params_file.clone(),
            source,
        }
    })?;
    Ok(ExportSummary {
        messages: topics.iter().map(|t| t.count).sum(),
        bag_dir,
        params_file,
        topics,
    })
}

/// One line describing a drive: seed, radars, noise, laps with speeds (km/h) and directions, odometry
/// errors.
pub fn drive_description(cfg: &SimConfig) -> String {
    let preset = cfg.radar_preset.name();
    let noise = cfg.noise.model.name();
    let laps: Vec<String> = cfg
        .laps
        .iter()
        .map(|l| {
            format!(
                "{:.0} km/h{}",
                l.speed * 3.6,
                if l.reverse { " reverse" } else { "" }
            )
        })
        .collect();
    let robot = if cfg.robot == 0 && cfg.drive.start == 0.0 {
        String::new()
    } else {
        format!(
            ", robot {} from {:.0} m along the loop",
            cfg.robot, cfg.drive.start
        )
    };
    format!(
        "seed {}{robot}, radar preset {preset} ({} radar{}), noise {noise}, laps [{}], odometry scale \
         error {}, yaw-rate bias {:.3} deg/s",
        cfg.seed,
        cfg.radar_list().len(),
        if cfg.radar_list().len() == 1 { "" } else { "s" },
        laps.join(", "),
        cfg.odometry.scale_error,
        cfg.odometry.yaw_rate_bias.to_degrees()
    )
}

#[cfg(test)]
mod tests {
    use dc_loc_io::params::{ParamSet, apply};

    use super::*;
    use crate::sim::{RadarPreset, SimConfig};

    /// A drive with a gyro: its samples on `imu.topic` as `sensor_msgs/Imu`, each as simulated, and
    /// the params file says how to run on them.
    #[test]
    fn the_simulated_gyro_goes_into_the_bag() {
        use crate::sim::config::ImuSimConfig;
        use crate::sim::config::LapConfig;
        use crate::sim::simulate;
        use dc_loc_core::msgs::sensor_msgs::Imu;
        use dc_loc_io::bag::BagReader;

        let cfg = SimConfig {
            laps: vec![LapConfig::default()],
            imu: ImuSimConfig::at_100_hz(),
            ..SimConfig::default()
        };
        let drive = simulate(&cfg).unwrap();
        let dir = std::env::temp_dir().join(format!("dc_loc_gyro_bag_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let summary = export_drive(&drive, &dir).unwrap();
        let imu = summary.topics.iter().find(|t| t.topic == "/imu").unwrap();
        assert_eq!(
            (imu.type_name, imu.count),
            (schema::IMU, drive.imu.len() as u64)
        );
        let reader = BagReader::open(&summary.bag_dir).unwrap();
        let got: Vec<Imu> = reader
            .messages_on(&["/imu"])
            .unwrap()
            .map(|m| m.unwrap().decode::<Imu>().unwrap())
            .collect();
        assert_eq!(got.len(), drive.imu.len());
        for (m, s) in got.iter().zip(&drive.imu) {
            assert_eq!(Stamp::from(m.header.stamp), s.stamp);
            assert_eq!(m.header.frame_id, cfg.body_frame);
            let w = &m.angular_velocity;
            assert_eq!(
                [w.x, w.y, w.z],
                [
                    s.angular_velocity.x,
                    s.angular_velocity.y,
                    s.angular_velocity.z
                ]
            );
            assert_eq!(m.orientation_covariance[0], -1.0);
        }
        let params = std::fs::read_to_string(&summary.params_file).unwrap();
        assert!(params.contains("odometry.source:=radar_imu"), "{params}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn params_yaml_applies_back_to_the_config() {
        let mut cfg = SimConfig::with_preset(RadarPreset::Nuscenes).to_config();
        cfg.keyframe.distance = 7.0;
        cfg.radars.get_mut("front").unwrap().fields.rcs.clear();
        let text = params_yaml(&cfg, "a test\nsecond line");
        assert!(text.starts_with("# a test\n# second line\ndc_loc:\n  ros__parameters:\n"));
        assert!(text.contains("    keyframe:\n      angle: 0.5\n      distance: 7.0\n"));
        let set = ParamSet::from_yaml(&text, "/", NODE_NAME).unwrap();
        assert_eq!(apply(&set).unwrap(), cfg);
        // Another node name gets nothing from it.
        let other = ParamSet::from_yaml(&text, "/", "other").unwrap();
        assert!(other.entries().is_empty());
    }
}
