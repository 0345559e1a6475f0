//! View-of-Delft sequences as drives: a directory of frames (`velodyne/NNNNN.bin`, `pose/NNNNN.json`,
//! `calib/NNNNN.txt`) split into runs of consecutive frames, each the runner's input stream.
//!
//! Entry points: [`open_sequences`] (the frames of a directory, split into [`VodSequence`]s),
//! [`VodInputs`] (a sequence as [`Input`]s), [`vod_config`] (the pipeline configuration of the radar).
//!
//! Frames: the body frame is the radar frame (x forward, y left, z up; VoD has no vehicle frame), so the
//! radar's extrinsic is the identity; odometry is `T_odom_camera * T_camera_radar` from `odomToCamera`,
//! ground truth `T_map_camera * T_camera_radar` from `mapToCamera`. Time: the radar `.bin` files carry
//! no time (their `time` column is 0), so frame `n` is stamped `n / frame_rate` (VoD's frames run at
//! about 10 Hz).
//!
//! A sequence ends where a frame number is skipped or the odometry jumps more than `MAX_JUMP` metres
//! between two frames (VoD numbers its clips one after another).

use crate::sources::vod::{KittiCalib, VodError, VodPoses, iso3_from_matrix};
use dc_loc_core::input::{Input, InputIssue, IssueReason};
use dc_loc_core::math::{Iso3, Stamp};
use dc_loc_core::msgs::sensor_msgs::{PointCloud2, PointField};
use dc_loc_core::msgs::std_msgs::Header;
use dc_loc_core::pipeline::Config;
use dc_loc_core::radar::{FieldsConfig, RadarConfig};
use std::path::{Path, PathBuf};

/// Odometry jump that splits a sequence, m.
pub const MAX_JUMP: f64 = 10.0;

/// Why a VoD directory could not be read; each variant names the path or frame.
#[derive(Debug, thiserror::Error)]
pub enum VodSequenceError {
    /// The directory has no `velodyne/` (nor `radar/training/velodyne/`).
    #[error(
        "{0} is not a View-of-Delft radar directory: expected velodyne/, pose/ and calib/ in it (or in \
         its radar/training/)"
    )]
    NotVod(PathBuf),
    /// No `.bin` frames.
    #[error("{0} holds no NNNNN.bin radar frames")]
    NoFrames(PathBuf),
    /// A frame's file could not be read or parsed.
    #[error("frame {frame}: {source}")]
    Frame {
        /// Frame number.
        frame: u32,
        /// The reader's error (it names the file).
        source: VodError,
    },
    /// A pose or calibration matrix is not a rigid motion.
    #[error("frame {frame}: `{key}` is not a rigid motion")]
    NotRigid {
        /// Frame number.
        frame: u32,
        /// The matrix.
        key: &'static str,
    },
}

/// One frame.
#[derive(Debug, Clone, PartialEq)]
pub struct VodFrame {
    /// Frame number (file stem).
    pub number: u32,
    /// The radar `.bin`.
    pub bin: PathBuf,
    /// Radar pose in the odometry frame.
    pub t_odom_radar: Iso3,
    /// Radar pose in the map frame (ground truth).
    pub t_map_radar: Iso3,
}

impl VodFrame {
    /// The frame's stamp at `frame_rate` Hz.
    pub fn stamp(&self, frame_rate: f64) -> Stamp {
        Stamp::from_secs_f64(f64::from(self.number) / frame_rate)
    }
}

/// A run of consecutive frames.
#[derive(Debug, Clone, PartialEq)]
pub struct VodSequence {
    /// Frames in order.
    pub frames: Vec<VodFrame>,
}

impl VodSequence {
    /// `first-last` frame numbers.
    pub fn name(&self) -> String {
        match (self.frames.first(), self.frames.last()) {
            (Some(a), Some(b)) => format!("{:05}-{:05}", a.number, b.number),
            _ => "empty".into(),
        }
    }
}

/// The folder holding `velodyne/`, `pose/`, `calib/`.
pub fn resolve_dir(dir: &Path) -> Result<PathBuf, VodSequenceError> {
    for cand in [dir.to_path_buf(), dir.join("radar").join("training")] {
        if cand.join("velodyne").is_dir() {
            return Ok(cand);
        }
    }
    Err(VodSequenceError::NotVod(dir.to_path_buf()))
}

/// Reads every frame of `dir` (see [`resolve_dir`]) and splits them into sequences.
pub fn open_sequences(dir: &Path) -> Result<Vec<VodSequence>, VodSequenceError> {
    let dir = resolve_dir(dir)?;
    let velodyne = dir.join("velodyne");
    let mut numbers: Vec<u32> = std::fs::read_dir(&velodyne)
        .map_err(|source| VodSequenceError::Frame {
            frame: 0,
            source: VodError::Io {
                path: velodyne.clone(),
                source,
            },
        })?
        .filter_map(Result::ok)
        .filter_map(|e| {
            let p = e.path();
            (p.extension().and_then(|x| x.to_str()) == Some("bin"))
                .then(|| p.file_stem()?.to_str()?.parse::<u32>().ok())
                .flatten()
        })
        .collect();
    numbers.sort_unstable();
    if numbers.is_empty() {
        return Err(VodSequenceError::NoFrames(velodyne));
    }
    let mut sequences: Vec<VodSequence> = Vec::new();
    let mut t_camera_radar: Option<Iso3> = None;
    for n in numbers {
        let stem = format!("{n:05}");
        let frame_err = |source| VodSequenceError::Frame { frame: n, source };
        if t_camera_radar.is_none() {
            let calib = KittiCalib::read(dir.join("calib").join(format!("{stem}.txt")))
                .map_err(frame_err)?;
            let m = calib.t_camera_radar().map_err(frame_err)?;
            t_camera_radar = Some(iso3_from_matrix(&m, 1e-3).ok_or(
                VodSequenceError::NotRigid {
                    frame: n,
                    key: "Tr_velo_to_cam",
                },
            )?);
        }
        let t_cr = t_camera_radar.unwrap_or_else(Iso3::identity);
        let poses =
            VodPoses::read(dir.join("pose").join(format!("{stem}.json"))).map_err(frame_err)?;
        let rigid =
            |m, key| iso3_from_matrix(m, 1e-3).ok_or(VodSequenceError::NotRigid { frame: n, key });
        let frame = VodFrame {
            number: n,
            bin: velodyne.join(format!("{stem}.bin")),
            t_odom_radar: rigid(&poses.t_odom_camera, "odomToCamera")? * t_cr,
            t_map_radar: rigid(&poses.t_map_camera, "mapToCamera")? * t_cr,
        };
        let continues = sequences
            .last()
            .and_then(|s| s.frames.last())
            .is_some_and(|p| {
                p.number + 1 == n
                    && (p.t_odom_radar.translation.vector - frame.t_odom_radar.translation.vector)
                        .norm()
                        <= MAX_JUMP
            });
        match sequences.last_mut() {
            Some(s) if continues => s.frames.push(frame),
            _ => sequences.push(VodSequence {
                frames: vec![frame],
            }),
        }
    }
    Ok(sequences)
}

/// The pipeline configuration of the VoD radar on top of `base` (its other sections kept): one radar
/// `radar` on topic `/radar`, frame id `radar`, identity extrinsic (the body is the radar frame), fields
/// `x, y, z, v_r, rcs` of the `.bin`, `beta` and noise from the base's first radar.
pub fn vod_config(base: &Config) -> Config {
    let template = base
        .radar_list()
        .first()
        .map(|(_, r)| (*r).clone())
        .unwrap_or_default();
    let mut cfg = base.clone();
    cfg.radar_names = vec!["radar".into()];
    cfg.radars.clear();
    cfg.radars.insert(
        "radar".into(),
        RadarConfig {
            topic: "/radar".into(),
            frame_id: "radar".into(),
            extrinsic: [0.0; 6],
            fields: FieldsConfig::default(),
            ..template
        },
    );
    cfg
}

/// The `.bin` bytes as a PointCloud2: 7 FLOAT32 fields `x, y, z, rcs, v_r, v_r_compensated, time`,
/// point step 28.
pub fn bin_to_pointcloud2(bytes: &[u8], header: Header) -> Result<PointCloud2, VodError> {
    if !bytes.len().is_multiple_of(28) {
        return Err(VodError::BinLength { len: bytes.len() });
    }
    let n =
        u32::try_from(bytes.len() / 28).map_err(|_| VodError::BinLength { len: bytes.len() })?;
    let fields = ["x", "y", "z", "rcs", "v_r", "v_r_compensated", "time"]
        .iter()
        .zip(0u32..)
        .map(|(name, i)| PointField {
            name: (*name).into(),
            offset: 4 * i,
            datatype: dc_loc_core::cloud::ScalarType::F32.datatype(),
            count: 1,
        })
        .collect();
    Ok(PointCloud2 {
        header,
        height: 1,
        width: n,
        fields,
        is_bigendian: false,
        point_step: 28,
        row_step: 28 * n,
        data: bytes.to_vec(),
        is_dense: false,
    })
}

/// A sequence as an input stream: per frame the ground truth (map pose, speed from the neighbouring
/// frames), the odometry and the radar cloud. A frame file that cannot be read is reported as an
/// [`InputIssue`] and skipped; the sequence goes on.
pub struct VodInputs<'a> {
    seq: &'a VodSequence,
    frame_rate: f64,
    next: usize,
    queue: std::collections::VecDeque<Result<Input, InputIssue>>,
}

impl<'a> VodInputs<'a> {
    /// The inputs of `seq` with frames at `frame_rate` Hz.
    pub fn new(seq: &'a VodSequence, frame_rate: f64) -> Self {
        VodInputs {
            seq,
            frame_rate,
            next: 0,
            queue: Default::default(),
        }
    }

    fn speed(&self, i: usize) -> f64 {
        let f = &self.seq.frames;
        let (a, b) = (i.saturating_sub(1), (i + 1).min(f.len().saturating_sub(1)));
        let (Some(fa), Some(fb)) = (f.get(a), f.get(b)) else {
            return 0.0;
        };
        let dt = fb
            .stamp(self.frame_rate)
            .secs_since(fa.stamp(self.frame_rate));
        if dt <= 0.0 {
            return 0.0;
        }
        (fb.t_map_radar.translation.vector - fa.t_map_radar.translation.vector).norm() / dt
    }
}

impl Iterator for VodInputs<'_> {
    type Item = Result<Input, InputIssue>;

    fn next(&mut self) -> Option<Self::Item> {
        if let Some(i) = self.queue.pop_front() {
            return Some(i);
        }
        let i = self.next;
        let frame = self.seq.frames.get(i)?;
        self.next += 1;
        let stamp = frame.stamp(self.frame_rate);
        self.queue.push_back(Ok(Input::GroundTruth {
            stamp,
            t_map_body: frame.t_map_radar,
            speed: self.speed(i),
        }));
        self.queue.push_back(Ok(Input::Odometry {
            stamp,
            t_odom_body: frame.t_odom_radar,
        }));
        let header = Header {
            stamp: stamp.into(),
            frame_id: "radar".into(),
        };
        let cloud = std::fs::read(&frame.bin)
            .map_err(|source| VodError::Io {
                path: frame.bin.clone(),
                source,
            })
            .and_then(|b| {
                bin_to_pointcloud2(&b, header).map_err(|e| VodError::InFile {
                    path: frame.bin.clone(),
                    source: Box::new(e),
                })
            });
        // A frame that cannot be read is skipped and reported; the sequence goes on.
        self.queue.push_back(match cloud {
            Ok(cloud) => Ok(Input::Radar { radar: 0, cloud }),
            Err(source) => Err(InputIssue {
                topic: format!("frame {:05}", frame.number),
                stamp,
                reason: IssueReason::Unreadable(
                    VodSequenceError::Frame {
                        frame: frame.number,
                        source,
                    }
                    .to_string(),
                ),
            }),
        });
        self.queue.pop_front()
    }
}
