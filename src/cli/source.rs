//! The data `dc_loc run` and `dc_loc eval` read, opened once ([`Dataset`]: a rosbag2, ROS 1 or foxglove
//! MCAP bag, a nuScenes directory, a View-of-Delft directory) with its pipeline configuration, and its runs
//! ([`Segment`]: a configuration and an input stream; nuScenes gives one per location, where the
//! scenes share a map frame, everything else one).
//!
//! Parameters: for a bag, its params file (required, except for a foxglove nuscenes2mcap file, whose
//! radar topics say the layout); for a dataset, the defaults with the dataset's radars, then the
//! params file (optional); then the `-p` overrides. A bag's `/tf_static` (or `/tf`) extrinsics replace
//! the configured ones; a dataset's calibration is its own.

use std::path::{Path, PathBuf};

use super::CliError;
use super::params::{dataset_config, load_params, parse_states};
use super::progress;
use crate::bag::BagReader;
use crate::input::{Input, InputIssue};
use crate::io::foxglove::FoxgloveInputs;
use crate::io::nuscenes::{
    NuscenesDb, NuscenesScene, OdometryDrift, RADAR_CHANNELS, SceneInputs, nuscenes_config,
};
use crate::io::nuscenes_pcd::NuscenesRadarFilter;
use crate::io::rosbag::{BagInputError, BagInputs};
use crate::io::vod_sequence::{
    VodInputs, VodSequence, VodSequenceError, open_sequences, vod_config,
};
use crate::pipeline::Config;

/// Where the data comes from, as `dc_loc run` and `dc_loc eval` take it.
#[derive(Debug, Clone, clap::Args)]
pub struct SourceArgs {
    /// Bag: a rosbag2 directory or single .mcap file, a ROS 1 .bag file (format 2.0), or a foxglove
    /// MCAP from nuscenes2mcap.
    #[arg(
        long,
        value_name = "BAG",
        conflicts_with_all = ["vod", "nuscenes"]
    )]
    pub bag: Option<PathBuf>,
    /// ROS 2 params YAML (e.g. the `dc_loc.yaml` that `dc_loc sim` writes into its bag directory).
    /// Required with `--bag` (but for a foxglove nuscenes2mcap file); optional with `--nuscenes` and
    /// `--vod` (defaults, radars and extrinsics from the dataset).
    #[arg(long, value_name = "FILE")]
    pub params: Option<PathBuf>,
    /// nuScenes data root (holding `<version>/`, `samples/`, `sweeps/`) instead of a bag.
    #[arg(long, value_name = "DIR", conflicts_with = "vod")]
    pub nuscenes: Option<PathBuf>,
    /// nuScenes version folder.
    #[arg(long, default_value = "v1.0-mini")]
    pub version: String,
    /// nuScenes: only these scenes (comma-separated names, e.g. scene-0061,scene-0103).
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<String>,
    /// nuScenes radar filter: kept `invalid_state` values (comma-separated, or `all`).
    #[arg(long, default_value = "0")]
    pub radar_invalid_states: String,
    /// nuScenes radar filter: kept `dyn_prop` values (comma-separated, or `all`; the devkit keeps 0-6,
    /// the DC-Loc authors' code only stationary points: 1).
    #[arg(long, default_value = "0,1,2,3,4,5,6")]
    pub radar_dynprop_states: String,
    /// nuScenes radar filter: kept `ambig_state` values (comma-separated, or `all`).
    #[arg(long, default_value = "3")]
    pub radar_ambig_states: String,
    /// View-of-Delft radar directory (`velodyne/`, `pose/`, `calib/`, or a folder holding
    /// `radar/training/`) instead of a bag.
    #[arg(long, value_name = "DIR")]
    pub vod: Option<PathBuf>,
    /// VoD frame rate, Hz (the `.bin` files carry no time).
    #[arg(long, default_value_t = 10.0)]
    pub frame_rate: f64,
    /// Node name whose section of the params file applies.
    #[arg(long, default_value = "dc_loc")]
    pub node_name: String,
    /// Parameter override, applied after the file (repeatable).
    #[arg(short = 'p', long = "param", value_name = "NAME:=VALUE")]
    pub overrides: Vec<String>,
}

impl SourceArgs {
    /// The nuScenes radar flag filter of the `--radar-*-states` flags.
    pub fn radar_filter(&self) -> Result<NuscenesRadarFilter, CliError> {
        Ok(NuscenesRadarFilter {
            invalid_states: parse_states("radar-invalid-states", &self.radar_invalid_states)?,
            dynprop_states: parse_states("radar-dynprop-states", &self.radar_dynprop_states)?,
            ambig_states: parse_states("radar-ambig-states", &self.radar_ambig_states)?,
        })
    }

    /// The configuration of a dataset whose radars `template` describes (see [`dataset_config`]).
    pub fn dataset_config(&self, template: &Config) -> Result<Config, CliError> {
        dataset_config(
            template,
            self.params.as_deref(),
            &self.node_name,
            &self.overrides,
        )
    }
}

/// Opened data and the configuration it runs with.
pub enum Dataset {
    /// A rosbag2 or ROS 1 bag, or a foxglove MCAP (`foxglove` true: radar as `foxglove.PointCloud`, odometry
    /// from the `map_frame -> body` transforms on `/tf`).
    Bag {
        /// The bag's path.
        path: PathBuf,
        /// The open bag.
        reader: BagReader,
        /// Its configuration.
        cfg: Config,
        /// A foxglove MCAP.
        foxglove: bool,
        /// The frame whose transforms to the body frame are the odometry of a foxglove MCAP.
        map_frame: String,
    },
    /// A nuScenes directory.
    Nuscenes {
        /// The tables.
        db: NuscenesDb,
        /// Indices into `db.scenes` of the scenes read.
        scenes: Vec<usize>,
        /// The configuration before each location's extrinsics.
        base: Config,
        /// The radar flag filter.
        filter: NuscenesRadarFilter,
    },
    /// A View-of-Delft directory: its runs of consecutive frames.
    Vod {
        /// The directory.
        dir: PathBuf,
        /// The runs of consecutive frames.
        sequences: Vec<VodSequence>,
        /// Its configuration.
        cfg: Config,
        /// Frames per second.
        frame_rate: f64,
    },
}

/// One run of the pipeline: a configuration and the inputs in time order.
pub struct Segment<'a> {
    /// What the run covers (a bag, a nuScenes location, a VoD directory).
    pub label: String,
    /// The pipeline's configuration.
    pub config: Config,
    /// The inputs, or the issues of messages skipped.
    pub inputs: Box<dyn Iterator<Item = Result<Input, InputIssue>> + 'a>,
    /// Radar messages in `inputs` (for progress).
    pub radar_messages: u64,
}

impl Dataset {
    /// Opens the data `args` names; `namespace` selects the params file's section of a bag.
    pub fn open(args: &SourceArgs, namespace: &str, map_frame: &str) -> Result<Self, CliError> {
        if let Some(dir) = &args.vod {
            return open_vod(args, dir);
        }
        if let Some(root) = &args.nuscenes {
            let base = args.dataset_config(&nuscenes_config(&Config::default(), &[None; 5]))?;
            let filter = args.radar_filter()?;
            let db = open_nuscenes(root, &args.version)?;
            let scenes = select_scenes(&db, &args.scenes)?;
            return Ok(Dataset::Nuscenes {
                db,
                scenes,
                base,
                filter,
            });
        }
        let Some(path) = &args.bag else {
            return Err(CliError::Usage(
                "--bag, --nuscenes or --vod is required".into(),
            ));
        };
        let reader = BagReader::open(path).map_err(|e| CliError::Runtime(e.to_string()))?;
        let mut cfg = match (&args.params, nuscenes_mcap_config(&reader)) {
            (None, Some(template)) => args.dataset_config(&template)?,
            (Some(params), _) => load_params(params, namespace, &args.node_name, &args.overrides)?,
            (None, None) => {
                return Err(CliError::Usage(
                    "--bag needs --params (the params file of the bag's radars and topics)".into(),
                ));
            }
        };
        apply_bag_extrinsics(&reader, &mut cfg)?;
        let foxglove = cfg
            .radar_list()
            .iter()
            .any(|(_, r)| crate::bag::foxglove::is_foxglove_cloud(&reader, &r.topic));
        Ok(Dataset::Bag {
            path: path.clone(),
            reader,
            cfg,
            foxglove,
            map_frame: map_frame.to_string(),
        })
    }

    /// The runs of the pipeline over this data, in order.
    pub fn segments(&self) -> Result<Vec<Segment<'_>>, CliError> {
        match self {
            Dataset::Bag {
                path,
                reader,
                cfg,
                foxglove,
                map_frame,
            } => {
                let topics: Vec<String> = cfg
                    .radar_list()
                    .iter()
                    .map(|(_, r)| r.topic.clone())
                    .collect();
                let radar_messages = topics
                    .iter()
                    .map(|t| reader.topic(t).map_or(0, |i| i.message_count))
                    .sum();
                let inputs: Box<dyn Iterator<Item = _>> = if *foxglove {
                    let f = FoxgloveInputs::new(reader, &topics, map_frame, &cfg.body_frame)
                        .map_err(|e| CliError::Runtime(e.to_string()))?;
                    Box::new(f)
                } else {
                    Box::new(bag_inputs(reader, cfg, None)?)
                };
                Ok(vec![Segment {
                    label: path.display().to_string(),
                    config: cfg.clone(),
                    inputs,
                    radar_messages,
                }])
            }
            Dataset::Nuscenes {
                db,
                scenes,
                base,
                filter,
            } => Ok(nuscenes_segments(db, scenes, base, filter)),
            Dataset::Vod {
                dir,
                sequences,
                cfg,
                frame_rate,
            } => {
                let frame_rate = *frame_rate;
                let inputs = sequences
                    .iter()
                    .flat_map(move |s| VodInputs::new(s, frame_rate));
                Ok(vec![Segment {
                    label: dir.display().to_string(),
                    config: cfg.clone(),
                    inputs: Box::new(inputs),
                    radar_messages: sequences.iter().map(|s| s.frames.len() as u64).sum(),
                }])
            }
        }
    }

    /// One line saying what was read.
    pub fn describe(&self) -> String {
        match self {
            Dataset::Bag { path, reader, .. } => {
                let span = reader.time_range().map_or(0.0, |(a, b)| b.secs_since(a));
                format!(
                    "bag: {} ({} messages, {span:.1} s)",
                    path.display(),
                    reader.message_count()
                )
            }
            Dataset::Nuscenes { db, scenes, .. } => {
                let chosen: Vec<&NuscenesScene> = scenes.iter().map(|&i| &db.scenes[i]).collect();
                let mut locations: Vec<&str> = chosen.iter().map(|s| s.location.as_str()).collect();
                locations.sort_unstable();
                locations.dedup();
                let sweeps: usize = chosen.iter().map(|s| s.sweeps.len()).sum();
                format!(
                    "nuScenes {} in {}: {} scenes at {} locations, {sweeps} radar sweeps",
                    db.version,
                    db.dataroot.display(),
                    chosen.len(),
                    locations.len()
                )
            }
            Dataset::Vod { dir, sequences, .. } => format!(
                "View-of-Delft {}: {} runs of consecutive frames, {} frames",
                dir.display(),
                sequences.len(),
                sequences.iter().map(|s| s.frames.len()).sum::<usize>()
            ),
        }
    }
}

/// The inputs of a rosbag2 or ROS 1 bag for `cfg` (and a ground-truth topic), a configuration that does not
/// fit the bag being a usage error.
pub fn bag_inputs(
    reader: &BagReader,
    cfg: &Config,
    ground_truth_topic: Option<&str>,
) -> Result<BagInputs, CliError> {
    BagInputs::new(reader, cfg, ground_truth_topic).map_err(|e| match e {
        BagInputError::Bag(e) => CliError::Runtime(e.to_string()),
        e => CliError::Usage(e.to_string()),
    })
}

/// Per location, its scenes in time order through one pipeline (odometry = ego poses in the
/// location's global frame, so revisits across scenes are found), with the extrinsics of the
/// location's first scene (a warning names a scene whose calibration differs).
fn nuscenes_segments<'a>(
    db: &'a NuscenesDb,
    scenes: &[usize],
    base: &Config,
    filter: &NuscenesRadarFilter,
) -> Vec<Segment<'a>> {
    let mut chosen: Vec<&'a NuscenesScene> = scenes
        .iter()
        .map(|&i| &db.scenes[i])
        .filter(|s| !s.sweeps.is_empty())
        .collect();
    chosen.sort_by_key(|s| s.sweeps.first().map_or(0, |w| w.timestamp_us));
    let mut locations: Vec<&str> = chosen.iter().map(|s| s.location.as_str()).collect();
    locations.sort_unstable();
    locations.dedup();
    let mut out = Vec::new();
    for location in locations {
        let here: Vec<&'a NuscenesScene> = chosen
            .iter()
            .copied()
            .filter(|s| s.location == location)
            .collect();
        let Some(first) = here.first() else { continue };
        let extrinsics = first.extrinsics();
        for scene in &here {
            if !same_calibration(&scene.extrinsics(), &extrinsics) {
                log::warn!(
                    "{}: radar calibration differs from {}'s, which this run uses",
                    scene.name,
                    first.name
                );
            }
        }
        let filter = filter.clone();
        let inputs = here.clone().into_iter().flat_map(move |scene| {
            SceneInputs::new(
                &db.dataroot,
                scene,
                filter.clone(),
                OdometryDrift::default(),
            )
        });
        out.push(Segment {
            label: location.to_string(),
            config: nuscenes_config(base, &extrinsics),
            inputs: Box::new(inputs),
            radar_messages: here.iter().map(|s| s.sweeps.len() as u64).sum(),
        });
    }
    out
}

/// Two scenes' radar extrinsics agree (to 1 cm and 0.1 degree where both have one).
fn same_calibration(
    a: &[Option<crate::math::Iso3>; 5],
    b: &[Option<crate::math::Iso3>; 5],
) -> bool {
    a.iter().zip(b).all(|(a, b)| match (a, b) {
        (Some(a), Some(b)) => {
            (a.translation.vector - b.translation.vector).norm() <= 0.01
                && a.rotation.angle_to(&b.rotation) <= 0.1f64.to_radians()
        }
        _ => true,
    })
}

fn open_vod(args: &SourceArgs, dir: &Path) -> Result<Dataset, CliError> {
    let cfg = vod_config(&args.dataset_config(&vod_config(&Config::default()))?);
    Ok(Dataset::Vod {
        dir: dir.to_path_buf(),
        sequences: vod_sequences(dir, args.frame_rate)?,
        cfg,
        frame_rate: args.frame_rate,
    })
}

/// The runs of consecutive frames of a View-of-Delft directory.
pub fn vod_sequences(dir: &Path, frame_rate: f64) -> Result<Vec<VodSequence>, CliError> {
    if !(frame_rate.is_finite() && frame_rate > 0.0) {
        return Err(CliError::Usage(format!(
            "--frame-rate {frame_rate}: must be > 0 Hz"
        )));
    }
    open_sequences(dir).map_err(|e| match e {
        VodSequenceError::Frame { .. } => CliError::Runtime(e.to_string()),
        e => CliError::Usage(e.to_string()),
    })
}

/// The tables of `root/version`, with a progress bar over their bytes.
pub fn open_nuscenes(root: &Path, version: &str) -> Result<NuscenesDb, CliError> {
    let bar = progress::bar(
        0,
        "{elapsed_precise} [{wide_bar}] {bytes}/{total_bytes} tables ({msg})",
    );
    let db = NuscenesDb::open(root, version, &mut |p| {
        bar.set_length(p.total);
        bar.set_position(p.read);
        bar.set_message(p.table);
    });
    progress::clear(&bar);
    db.map_err(|e| match e {
        crate::io::nuscenes::NuscenesError::Table { .. } => CliError::Runtime(e.to_string()),
        e => CliError::Usage(e.to_string()),
    })
}

/// Indices of the scenes named in `names` (all when empty); an unknown name is a usage error.
pub fn select_scenes(db: &NuscenesDb, names: &[String]) -> Result<Vec<usize>, CliError> {
    if let Some(name) = names
        .iter()
        .find(|n| !db.scenes.iter().any(|s| &s.name == *n))
    {
        return Err(CliError::Usage(format!(
            "--scenes: no scene `{name}` in {} {}",
            db.dataroot.display(),
            db.version
        )));
    }
    Ok((0..db.scenes.len())
        .filter(|&i| names.is_empty() || names.contains(&db.scenes[i].name))
        .collect())
}

/// The five-radar nuScenes configuration for a bag written by nuscenes2mcap (or nuscenes2bag): each
/// channel whose topic is in the bag (`/radar_front` with frame `radar_front`, or the 2022 layout's
/// `/RADAR_FRONT` with frame `RADAR_FRONT`) as `foxglove.PointCloud`. `None` when the bag has none of
/// them (a ROS bag needs its params file: its odometry topic is not implied).
fn nuscenes_mcap_config(reader: &BagReader) -> Option<Config> {
    let mut cfg = nuscenes_config(&Config::default(), &[None; 5]);
    let mut names = Vec::new();
    for (i, channel) in RADAR_CHANNELS.iter().enumerate() {
        let name = cfg.radar_names.get(i)?.clone();
        let lower = channel.to_ascii_lowercase();
        let found = [lower.as_str(), *channel]
            .into_iter()
            .find(|frame| crate::bag::foxglove::is_foxglove_cloud(reader, &format!("/{frame}")));
        match (found, cfg.radars.get_mut(&name)) {
            (Some(frame), Some(r)) => {
                r.topic = format!("/{frame}");
                r.frame_id = frame.to_string();
                names.push(name);
            }
            _ => {
                cfg.radars.remove(&name);
            }
        }
    }
    if names.is_empty() {
        return None;
    }
    cfg.radar_names = names;
    cfg.odometry.topic = "/tf".into();
    Some(cfg)
}

/// Replaces each radar's extrinsic by the bag's `body_frame -> frame_id` transform from `/tf_static` or
/// `/tf`, when the bag has one (logged).
fn apply_bag_extrinsics(reader: &BagReader, cfg: &mut Config) -> Result<(), CliError> {
    let found = crate::bag::foxglove::bag_extrinsics(reader, &cfg.body_frame, &cfg.radar_frames())
        .map_err(|e| CliError::Runtime(e.to_string()))?;
    cfg.set_extrinsics(&found, "the bag's transforms");
    Ok(())
}
