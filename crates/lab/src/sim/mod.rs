//! Radar scenario simulator: a city loop driven in laps, seen by automotive radars with the FMCW Doppler
//! range distortion, plus ground truth and drifting odometry; every accuracy number of dc_loc is
//! measured on its output. One seed gives one drive. docs/algorithm.md, "The simulator", has its
//! physics, seeding and timing.
//!
//! Entry points: [`simulate`] (the whole drive in memory, [`SimDrive`]), [`Simulator`] (the same drive
//! as a time-ordered iterator of [`SimEvent`]s, for streaming into a bag), [`SimConfig`] (with
//! [`SimConfig::to_config`] for the pipeline's radar section), [`RevisitIndex`] (revisit ground truth).
//! Parts: [`config`], [`families`] (kinds of street and the held-out protocol), [`fleet`] (robots on one
//! world), [`route`] (centre line, trajectory), [`world`] (city generation), [`sensor`] (one scan),
//! [`noise`] (the paper's noise models), [`odometry`] (drift), [`revisit`]; [`export`] writes a drive as
//! a rosbag2 bag with its params YAML.

pub mod config;
pub mod export;
pub mod families;
pub mod fleet;
pub mod imu;
pub mod inputs;
pub mod noise;
pub mod nuscenes;
pub mod odometry;
pub mod radar_config;
pub mod revisit;
pub mod route;
pub mod sensor;
pub mod world;
pub mod world_config;

pub use config::SimConfig;
pub use families::WorldFamily;
pub use noise::{NoiseConfig, NoiseModel};
pub use odometry::{OdometrySample, PoseSample};
pub use radar_config::{RadarPreset, SimRadarConfig};
pub use revisit::{Revisit, RevisitIndex};
pub use route::{EgoState, LapInfo};
pub use sensor::{DetectionTruth, Dropout};
pub use world::TargetKind;

use dc_loc_core::math::{Iso2, Stamp};
use dc_loc_core::pipeline::Config;
use dc_loc_core::radar::RadarScan;
use dc_loc_core::validate::ConfigError;
use noise::NoiseSampler;
use odometry::OdometryIntegrator;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use route::{Centerline, Trajectory};
use sensor::{RadarMotion, Reflectivity};
use world::World;

/// SplitMix64 finaliser: decorrelates seeds of the independent random streams.
fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE5_E9B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Seed of the random stream `(tag, index)` under the configuration seed.
pub(crate) fn stream_seed(seed: u64, tag: u64, index: u64) -> u64 {
    splitmix(splitmix(seed ^ splitmix(tag)) ^ index)
}

const TAG_SCAN: u64 = 0x5343_414e;
const TAG_ODOM: u64 = 0x4f44_4f4d;
const TAG_ROBOT: u64 = 0x0052_4f42_4f54;
const TAG_GHOST: u64 = 0x0047_484f_5354;
const TAG_IMU: u64 = 0x0049_4d55;

/// The seed of a robot's own noise (detections, stamps, odometry): the configuration seed for robot 0,
/// so a single robot's drive does not depend on fleets existing.
fn robot_seed(cfg: &SimConfig) -> u64 {
    match cfg.robot {
        0 => cfg.seed,
        r => stream_seed(cfg.seed, TAG_ROBOT, u64::from(r)),
    }
}

/// One scan of one radar with its truth.
#[derive(Debug, Clone, PartialEq)]
pub struct SimScan {
    /// The scan as the pipeline sees it (radar index into the drive's radar list).
    pub scan: RadarScan,
    /// Per detection, in the same order: the noise-free truth.
    pub truth: Vec<DetectionTruth>,
    /// Lap at the scan time.
    pub lap: LapInfo,
    /// Ego forward speed, m/s.
    pub speed: f64,
    /// Ego yaw rate, rad/s.
    pub yaw_rate: f64,
    /// Whether the scan came out empty or partial.
    pub dropout: Dropout,
}

/// One output of the simulator.
#[derive(Debug, Clone, PartialEq)]
pub enum SimEvent {
    /// Ground-truth pose and twist.
    GroundTruth(PoseSample),
    /// Drifting odometry.
    Odometry(OdometrySample),
    /// A radar scan.
    Scan(SimScan),
}

impl SimEvent {
    /// The event's stamp.
    pub fn stamp(&self) -> Stamp {
        match self {
            SimEvent::GroundTruth(p) => p.stamp,
            SimEvent::Odometry(o) => o.stamp,
            SimEvent::Scan(s) => s.scan.stamp,
        }
    }
}

/// A borrowed event of a [`SimDrive`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SimEventRef<'a> {
    /// Ground-truth pose and twist.
    GroundTruth(&'a PoseSample),
    /// Drifting odometry.
    Odometry(&'a OdometrySample),
    /// A radar scan.
    Scan(&'a SimScan),
    /// A gyro sample.
    Imu(&'a imu::ImuSample),
}

/// Everything shared by the streaming and the collected simulation.
#[derive(Debug, Clone)]
pub struct SimSetup {
    /// The configuration (validated).
    pub config: SimConfig,
    /// The simulated radars, in radar-index order.
    pub radars: Vec<SimRadarConfig>,
    /// The city.
    pub world: World,
    /// The ego drive.
    pub trajectory: Trajectory,
    /// Stamp of the drive's start.
    pub start: Stamp,
    /// Per radar: the occlusion buffer's bin rays.
    rays: Vec<Vec<dc_loc_core::math::Vec2>>,
}

impl SimSetup {
    /// Validates the configuration and builds the world and the drive.
    pub fn new(cfg: &SimConfig) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let line = Centerline::new(&cfg.route)?;
        let trajectory = Trajectory::new(
            line.clone(),
            &cfg.laps,
            &cfg.drive,
            cfg.world.street.ego_lane_offset(),
        )?;
        let world = World::generate(cfg, line)?;
        let radars = cfg.radar_list();
        Ok(SimSetup {
            config: cfg.clone(),
            rays: radars
                .iter()
                .map(|r| sensor::occlusion_rays(r.half_fov()))
                .collect(),
            radars,
            world,
            trajectory,
            start: Stamp::from_secs_f64(cfg.start_time),
        })
    }

    /// Seconds since the start at `stamp`.
    pub fn time_of(&self, stamp: Stamp) -> f64 {
        stamp.secs_since(self.start)
    }
    /// The stamp `t` seconds after the start (nearest nanosecond).
    pub fn stamp_at(&self, t: f64) -> Stamp {
        Stamp(self.start.0 + (t * 1e9).round() as i64)
    }
    /// The exact ego state at `stamp`.
    pub fn state_at(&self, stamp: Stamp) -> EgoState {
        self.trajectory.state(self.time_of(stamp))
    }
    /// The map-frame pose of the odometry frame (the ground-truth start pose).
    pub fn t_map_odom(&self) -> Iso2 {
        self.trajectory.state(0.0).t_map_body
    }
    /// The pipeline configuration matching the simulated radars (see [`SimConfig::to_config`]).
    pub fn to_config(&self) -> Config {
        self.config.to_config()
    }

    /// Time of scan `k` of radar `radar` after the start (its phase, period and jitter), s.
    fn scan_time(&self, radar: usize, k: u64) -> Option<f64> {
        let r = self.radars.get(radar)?;
        let mut rng = StdRng::seed_from_u64(self.scan_seed(radar, k));
        let jitter: f64 = rng.sample::<f64, _>(StandardNormal) * r.stamp_jitter;
        Some((r.phase + k as f64 / r.rate + jitter).max(0.0))
    }
    fn scan_seed(&self, radar: usize, k: u64) -> u64 {
        stream_seed(robot_seed(&self.config), TAG_SCAN + radar as u64, k)
    }

    /// Simulates scan `k` of radar `radar` (`None` for an unknown radar index); `noise` from
    /// `NoiseSampler::new(&config.noise)`.
    pub fn scan(&self, radar: usize, k: u64, noise: &NoiseSampler) -> Option<SimScan> {
        let rc = self.radars.get(radar)?;
        let rays = self.rays.get(radar)?;
        let mut rng = StdRng::seed_from_u64(self.scan_seed(radar, k));
        let _jitter: f64 = rng.sample(StandardNormal); // consumed as in `scan_time`
        let t = self.scan_time(radar, k)?;
        let stamp = self.stamp_at(t);
        // Evaluate the world at the rounded stamp so the truth matches the stamp exactly.
        let ego = self.trajectory.state(self.time_of(stamp));
        let motion = RadarMotion::new(
            ego.t_map_body.translation.vector,
            ego.heading,
            ego.speed,
            ego.yaw_rate,
            &rc.extrinsic,
        );
        let movers = self.world.movers_at(ego.t);
        let refl = Reflectivity::from(&self.config.world);
        let mut ghost_rng = StdRng::seed_from_u64(stream_seed(
            robot_seed(&self.config),
            TAG_GHOST + radar as u64,
            k,
        ));
        let (detections, truth, dropout) = sensor::simulate_scan(
            &self.world,
            rc,
            rays,
            &motion,
            ego.lap.lap,
            &movers,
            &refl,
            noise,
            &mut rng,
            &mut ghost_rng,
        );
        // Measured at `stamp`, stamped by the radar's own clock.
        let offset = (rc.stamp_offset * 1e9).round() as i64;
        Some(SimScan {
            scan: RadarScan {
                radar,
                stamp: Stamp((stamp.0 + offset).max(0)),
                detections,
            },
            truth,
            lap: ego.lap,
            speed: ego.speed,
            yaw_rate: ego.yaw_rate,
            dropout,
        })
    }
}

/// The drive as a time-ordered stream of events.
#[derive(Debug)]
pub struct Simulator {
    setup: SimSetup,
    noise: NoiseSampler,
    odometry: OdometryIntegrator,
    next_gt: u64,
    next_odom: u64,
    next_scan: Vec<u64>,
    /// Time of the next scan of each radar (`None` once past the end).
    scan_t: Vec<Option<f64>>,
}

impl Simulator {
    /// Validates `cfg` and prepares the drive.
    pub fn new(cfg: &SimConfig) -> Result<Self, ConfigError> {
        let setup = SimSetup::new(cfg)?;
        let noise = NoiseSampler::new(&cfg.noise)?;
        let odometry =
            OdometryIntegrator::new(cfg.odometry, stream_seed(robot_seed(cfg), TAG_ODOM, 0));
        let n = setup.radars.len();
        let mut sim = Simulator {
            setup,
            noise,
            odometry,
            next_gt: 0,
            next_odom: 0,
            next_scan: vec![0; n],
            scan_t: vec![None; n],
        };
        for r in 0..n {
            sim.scan_t[r] = sim.scan_time_checked(r, 0);
        }
        Ok(sim)
    }

    /// The world, drive and radars being simulated.
    pub fn setup(&self) -> &SimSetup {
        &self.setup
    }

    fn scan_time_checked(&self, r: usize, k: u64) -> Option<f64> {
        let t = self.setup.scan_time(r, k)?;
        (t <= self.setup.trajectory.duration()).then_some(t)
    }
    fn periodic(&self, k: u64, rate: f64) -> Option<Stamp> {
        let t = k as f64 / rate;
        (t <= self.setup.trajectory.duration()).then(|| self.setup.stamp_at(t))
    }
}

impl Iterator for Simulator {
    type Item = SimEvent;

    fn next(&mut self) -> Option<SimEvent> {
        let gt = self.periodic(self.next_gt, self.setup.config.ground_truth_rate);
        let od = self.periodic(self.next_odom, self.setup.config.odometry.rate);
        let scan = self
            .scan_t
            .iter()
            .enumerate()
            .filter_map(|(r, t)| t.map(|t| (self.setup.stamp_at(t), r)))
            .min();
        // Earliest first; at equal stamps ground truth, then odometry, then scans.
        let mut best: Option<(Stamp, u8, usize)> = None;
        for cand in [
            gt.map(|s| (s, 0u8, 0)),
            od.map(|s| (s, 1u8, 0)),
            scan.map(|(s, r)| (s, 2u8, r)),
        ]
        .into_iter()
        .flatten()
        {
            if best.is_none_or(|b| cand < b) {
                best = Some(cand);
            }
        }
        let (stamp, kind, r) = best?;
        Some(match kind {
            0 => {
                self.next_gt += 1;
                SimEvent::GroundTruth(PoseSample::new(stamp, &self.setup.state_at(stamp)))
            }
            1 => {
                self.next_odom += 1;
                let st = self.setup.state_at(stamp);
                SimEvent::Odometry(self.odometry.step(stamp, &st))
            }
            _ => {
                let k = self.next_scan[r];
                let s = self.setup.scan(r, k, &self.noise)?;
                self.next_scan[r] += 1;
                self.scan_t[r] = self.scan_time_checked(r, k + 1);
                SimEvent::Scan(s)
            }
        })
    }
}

/// The whole simulated drive.
#[derive(Debug, Clone)]
pub struct SimDrive {
    /// World, trajectory, radars and configuration.
    pub setup: SimSetup,
    /// Ground truth at `ground_truth_rate`.
    pub ground_truth: Vec<PoseSample>,
    /// Odometry at `odometry.rate`.
    pub odometry: Vec<OdometrySample>,
    /// All scans of all radars, in time order.
    pub scans: Vec<SimScan>,
    /// The gyro's samples (none unless `imu.rate` is set).
    pub imu: Vec<imu::ImuSample>,
}

/// Simulates the whole drive of `cfg` (validated first).
pub fn simulate(cfg: &SimConfig) -> Result<SimDrive, ConfigError> {
    let sim = Simulator::new(cfg)?;
    let setup = sim.setup().clone();
    let imu = imu::simulate_imu(
        &cfg.imu,
        &setup.trajectory,
        setup.start,
        stream_seed(robot_seed(cfg), TAG_IMU, 0),
    );
    let mut drive = SimDrive {
        setup,
        ground_truth: Vec::new(),
        odometry: Vec::new(),
        scans: Vec::new(),
        imu,
    };
    for ev in sim {
        match ev {
            SimEvent::GroundTruth(p) => drive.ground_truth.push(p),
            SimEvent::Odometry(o) => drive.odometry.push(o),
            SimEvent::Scan(s) => drive.scans.push(s),
        }
    }
    log::info!(
        "simulated {:.0} s, {:.0} m: {} scans, {} detections",
        drive.setup.trajectory.duration(),
        drive.setup.trajectory.distance(),
        drive.scans.len(),
        drive
            .scans
            .iter()
            .map(|s| s.scan.detections.len())
            .sum::<usize>()
    );
    Ok(drive)
}

impl SimDrive {
    /// The pipeline configuration matching the simulated radars: `radar_names[i]` is radar index `i` of
    /// the scans (`RadarScan::radar`), `radars[name]` its topic, frame id, extrinsic, `beta` and noise.
    pub fn to_config(&self) -> Config {
        self.setup.to_config()
    }
    /// The exact ground-truth ego state at `stamp`.
    pub fn state_at(&self, stamp: Stamp) -> EgoState {
        self.setup.state_at(stamp)
    }
    /// Lap, direction and U-turn flag at `stamp`.
    pub fn lap_at(&self, stamp: Stamp) -> LapInfo {
        self.setup.state_at(stamp).lap
    }
    /// The map-frame pose of the odometry frame.
    pub fn t_map_odom(&self) -> Iso2 {
        self.setup.t_map_odom()
    }
    /// A revisit index over the ground truth.
    pub fn revisit_index(&self) -> RevisitIndex {
        RevisitIndex::new(&self.ground_truth)
    }
    /// The earlier-lap ground-truth sample nearest to the pose at `stamp`, within `max_distance` (m) and,
    /// when given, `max_heading_difference` (rad); `index` from [`SimDrive::revisit_index`].
    pub fn revisit_of(
        &self,
        index: &RevisitIndex,
        stamp: Stamp,
        max_distance: f64,
        max_heading_difference: Option<f64>,
    ) -> Option<Revisit> {
        let s = self.state_at(stamp);
        if s.lap.turning {
            return None;
        }
        index.nearest_earlier(
            s.t_map_body.translation.vector,
            s.heading,
            s.lap.lap,
            max_distance,
            max_heading_difference,
        )
    }

    /// All events in time order (ground truth, odometry, gyro, scans at equal stamps).
    pub fn events(&self) -> impl Iterator<Item = SimEventRef<'_>> {
        let mut g = self.ground_truth.iter().peekable();
        let mut o = self.odometry.iter().peekable();
        let mut i = self.imu.iter().peekable();
        let mut s = self.scans.iter().peekable();
        std::iter::from_fn(move || {
            let tg = g.peek().map(|x| x.stamp);
            let to = o.peek().map(|x| x.stamp);
            let ti = i.peek().map(|x| x.stamp);
            let ts = s.peek().map(|x| x.scan.stamp);
            let min = [tg, to, ti, ts].into_iter().flatten().min()?;
            if tg == Some(min) {
                return g.next().map(SimEventRef::GroundTruth);
            }
            if to == Some(min) {
                return o.next().map(SimEventRef::Odometry);
            }
            if ti == Some(min) {
                return i.next().map(SimEventRef::Imu);
            }
            s.next().map(SimEventRef::Scan)
        })
    }
}
