//! A scene as the runner's input stream: ground truth and odometry from the ego poses, radar clouds
//! from the PCD files read one sweep at a time.

use super::{NuscenesError, NuscenesScene, RADAR_CHANNELS, RadarSweep};
use crate::sources::nuscenes_pcd::{NuscenesRadarFilter, filtered_pointcloud2};
use dc_loc_core::input::{Input, InputIssue, IssueReason};
use dc_loc_core::math::{Iso3, Quat, Stamp};
use dc_loc_core::msgs::std_msgs::Header;
use std::path::Path;

/// Odometry error injected into the ego poses (all zero: perfect odometry).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OdometryDrift {
    /// Relative scale error of the distance driven (0.01: the odometry overestimates by 1 %).
    pub scale_error: f64,
    /// Yaw-rate bias, rad/s.
    pub yaw_rate_bias: f64,
}

/// A scene as an input stream: per sweep, in time order, the ground truth (ego pose, speed
/// from the neighbouring ego poses), the odometry (the ego poses with [`OdometryDrift`] integrated in)
/// and the radar cloud (the PCD records that pass the filter, as a PointCloud2 stamped with the sweep
/// time, frame id `radar_<channel>`). A missing or damaged PCD file, or one whose name leaves the
/// data root (never opened), is reported as an [`InputIssue`] and skipped; the scene goes on.
pub struct SceneInputs<'a> {
    dataroot: &'a Path,
    scene: &'a NuscenesScene,
    filter: NuscenesRadarFilter,
    drift: OdometryDrift,
    next: usize,
    queue: std::collections::VecDeque<Result<Input, InputIssue>>,
    odom: Option<(Stamp, Iso3, Iso3)>,
    speeds: Vec<f64>,
}

impl<'a> SceneInputs<'a> {
    /// The inputs of `scene` with PCD files under `dataroot`.
    pub fn new(
        dataroot: &'a Path,
        scene: &'a NuscenesScene,
        filter: NuscenesRadarFilter,
        drift: OdometryDrift,
    ) -> Self {
        SceneInputs {
            dataroot,
            scene,
            filter,
            drift,
            next: 0,
            queue: Default::default(),
            odom: None,
            speeds: ego_speeds(&scene.sweeps),
        }
    }

    fn odometry(&mut self, stamp: Stamp, gt: Iso3) -> Option<Iso3> {
        let out = match self.odom {
            None => gt,
            Some((t0, _, _)) if stamp <= t0 => return None,
            Some((t0, gt0, od0)) => {
                let mut d = gt0.inverse() * gt;
                let dt = stamp.secs_since(t0);
                d.translation.vector *= 1.0 + self.drift.scale_error;
                d.rotation =
                    Quat::from_euler_angles(0.0, 0.0, self.drift.yaw_rate_bias * dt) * d.rotation;
                od0 * d
            }
        };
        self.odom = Some((stamp, gt, out));
        Some(out)
    }
}

/// Speed at each sweep from the ego poses about +-0.25 s around it (the ego poses of one instant come
/// from five radars within milliseconds, too close for a difference), m/s.
fn ego_speeds(sweeps: &[RadarSweep]) -> Vec<f64> {
    let n = sweeps.len();
    (0..n)
        .map(|i| {
            let t = sweeps[i].timestamp_us;
            let a = sweeps[..i]
                .iter()
                .rposition(|s| t - s.timestamp_us >= 250_000)
                .unwrap_or(0);
            let b = sweeps[i..]
                .iter()
                .position(|s| s.timestamp_us - t >= 250_000)
                .map_or(n - 1, |k| i + k);
            let (sa, sb) = (&sweeps[a], &sweeps[b]);
            let dt = (sb.timestamp_us - sa.timestamp_us) as f64 * 1e-6;
            if dt <= 0.0 {
                return 0.0;
            }
            (sb.t_global_ego.translation.vector - sa.t_global_ego.translation.vector).norm() / dt
        })
        .collect()
}

impl Iterator for SceneInputs<'_> {
    type Item = Result<Input, InputIssue>;

    fn next(&mut self) -> Option<Self::Item> {
        if let Some(i) = self.queue.pop_front() {
            return Some(i);
        }
        let sweep = self.scene.sweeps.get(self.next)?;
        let speed = self.speeds.get(self.next).copied().unwrap_or(0.0);
        self.next += 1;
        let channel = RADAR_CHANNELS
            .get(sweep.channel)
            .copied()
            .unwrap_or("RADAR");
        let stamp = sweep.stamp();
        if let Some(t_odom_body) = self.odometry(stamp, sweep.t_global_ego) {
            self.queue.push_back(Ok(Input::GroundTruth {
                stamp,
                t_map_body: sweep.t_global_ego,
                speed,
            }));
            self.queue
                .push_back(Ok(Input::Odometry { stamp, t_odom_body }));
        }
        let header = Header {
            stamp: stamp.into(),
            frame_id: channel.to_ascii_lowercase(),
        };
        let cloud = match sweep.path_in(self.dataroot) {
            None => Err(NuscenesError::OutsideDataroot {
                filename: sweep.filename.clone(),
                token: sweep.token.clone(),
            }),
            Some(path) => match std::fs::read(&path) {
                Err(source) => Err(NuscenesError::MissingSweep {
                    path,
                    token: sweep.token.clone(),
                    source,
                }),
                Ok(bytes) => filtered_pointcloud2(&bytes, &self.filter, header)
                    .map_err(|source| NuscenesError::Pcd { path, source }),
            },
        };
        // A sweep that cannot be read is skipped and reported; the scene goes on.
        self.queue.push_back(match cloud {
            Ok(cloud) => Ok(Input::Radar {
                radar: sweep.channel,
                cloud,
            }),
            Err(e) => Err(InputIssue {
                topic: channel.to_string(),
                stamp,
                reason: IssueReason::Unreadable(e.to_string()),
            }),
        });
        self.queue.pop_front()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drift_free_odometry_is_the_ego_pose_and_drift_grows() {
        let scene = NuscenesScene {
            token: "s".into(),
            name: "scene-x".into(),
            description: String::new(),
            location: "here".into(),
            logfile: "log".into(),
            sweeps: Vec::new(),
        };
        let root = Path::new(".");
        let mut inputs = SceneInputs::new(
            root,
            &scene,
            NuscenesRadarFilter::default(),
            OdometryDrift {
                scale_error: 0.1,
                yaw_rate_bias: 0.0,
            },
        );
        let p = |x: f64| dc_loc_core::math::iso3_from_xyz_rpy(x, 0.0, 0.0, 0.0, 0.0, 0.0);
        assert_eq!(inputs.odometry(Stamp(0), p(5.0)), Some(p(5.0)));
        let o = inputs.odometry(Stamp(1_000_000_000), p(15.0)).unwrap();
        assert!((o.translation.x - 16.0).abs() < 1e-12);
        assert_eq!(inputs.odometry(Stamp(1_000_000_000), p(15.0)), None);
    }

    /// A PCD file in the nuScenes radar layout without points.
    const EMPTY_PCD: &str = "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n\
FIELDS x y z dyn_prop id rcs vx vy vx_comp vy_comp is_quality_valid ambig_state x_rms y_rms invalid_state pdh0 vx_rms vy_rms\n\
SIZE 4 4 4 1 2 4 4 4 4 4 1 1 1 1 1 1 1 1\nTYPE F F F I I F F F F F I I I I I I I I\n\
COUNT 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1\n\
WIDTH 0\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 0\nDATA binary\n";

    #[test]
    fn sweep_names_that_leave_the_dataroot_are_refused_unopened() {
        // Readable PCD files inside and outside the data root: only the inside one may be read.
        let base =
            std::env::temp_dir().join(format!("dc_loc_nuscenes_paths_{}", std::process::id()));
        let root = base.join("root");
        std::fs::create_dir_all(root.join("sweeps")).unwrap();
        std::fs::write(root.join("sweeps/in.pcd"), EMPTY_PCD).unwrap();
        std::fs::write(base.join("secret.pcd"), EMPTY_PCD).unwrap();
        let outside = base.join("secret.pcd").to_str().unwrap().to_string();
        let names = [
            "sweeps/in.pcd".to_string(),
            "../secret.pcd".into(),
            "sweeps/../../secret.pcd".into(),
            outside,
            String::new(),
        ];
        let sweeps = names
            .iter()
            .enumerate()
            .map(|(k, name)| RadarSweep {
                channel: 0,
                timestamp_us: 1_000_000 + 100_000 * k as i64,
                is_key_frame: false,
                filename: name.clone(),
                token: format!("t{k}"),
                t_ego_radar: Iso3::identity(),
                t_global_ego: Iso3::identity(),
            })
            .collect();
        let scene = NuscenesScene {
            token: "s".into(),
            name: "scene-x".into(),
            description: String::new(),
            location: "here".into(),
            logfile: "log".into(),
            sweeps,
        };
        let filter = NuscenesRadarFilter::keep_all();
        let inputs = SceneInputs::new(&root, &scene, filter, OdometryDrift::default());
        let (mut clouds, mut refused) = (0, Vec::new());
        for item in inputs {
            match item {
                Ok(Input::Radar { .. }) => clouds += 1,
                Ok(_) => {}
                Err(issue) => {
                    assert_eq!(issue.reason.name(), "unreadable_file");
                    refused.push(issue.reason.to_string());
                }
            }
        }
        std::fs::remove_dir_all(&base).unwrap();
        assert_eq!(clouds, 1);
        assert_eq!(refused.len(), 4, "{refused:?}");
        for (why, name) in refused.iter().zip(&names[1..]) {
            assert!(why.contains("leaves the dataroot"), "{why}");
            assert!(why.contains(&format!("{name:?}")), "{why}");
        }
    }
}
