//! Ground truth from any source, brought to what the evaluation compares against: [`PoseSpeed`] (the
//! speed of ground truth that has poses only) and [`to_body`] (a tracked frame's pose moved to the body
//! frame).

use dc_loc_core::input::Input;
use dc_loc_core::math::{Iso3, Stamp};

/// Ground-truth inputs from poses without a twist (a `geometry_msgs/PoseStamped` topic, a TUM file),
/// with their speed: the distance from the previous pose over the time between them, m/s. The first
/// pose waits for the second and takes its speed (a recording may start on the move; 0 would put the
/// first keyframes' speed far off); a pose whose stamp is not after the previous one's takes 0, and so
/// does a single pose.
#[derive(Debug, Clone, Default)]
pub struct PoseSpeed {
    last: Option<(Stamp, Iso3)>,
    /// The first pose, until the second arrives.
    first: Option<(Stamp, Iso3)>,
}

impl PoseSpeed {
    /// Takes the next pose; returns the ground-truth inputs now complete (none for the first pose,
    /// both the first and the second at the second).
    pub fn push(&mut self, stamp: Stamp, pose: &Iso3) -> Vec<Input> {
        if self.last.is_none() {
            self.first = Some((stamp, *pose));
            self.last = Some((stamp, *pose));
            return Vec::new();
        }
        let speed = match self.last {
            Some((t, last)) if stamp > t => {
                (pose.translation.vector - last.translation.vector).norm() / stamp.secs_since(t)
            }
            _ => 0.0,
        };
        self.last = Some((stamp, *pose));
        let mut ready: Vec<Input> = self
            .first
            .take()
            .map(|(t, p)| sample(t, p, speed))
            .into_iter()
            .collect();
        ready.push(sample(stamp, *pose, speed));
        ready
    }

    /// The end of the poses: the first pose if it is still waiting (a single pose, speed 0).
    pub fn finish(&mut self) -> Option<Input> {
        self.first.take().map(|(t, p)| sample(t, p, 0.0))
    }
}

fn sample(stamp: Stamp, t_map_body: Iso3, speed: f64) -> Input {
    Input::GroundTruth {
        stamp,
        t_map_body,
        speed,
    }
}

/// `input` with a ground-truth pose of the tracked frame (a GNSS/INS unit, a motion-capture marker)
/// moved to the body frame: `t_map_body = t_map_gt * t_gt_body`. Other inputs pass unchanged, and so
/// does the speed, which stays the tracked frame's.
pub fn to_body(input: Input, t_gt_body: &Iso3) -> Input {
    match input {
        Input::GroundTruth {
            stamp,
            t_map_body: t_map_gt,
            speed,
        } => Input::GroundTruth {
            stamp,
            t_map_body: t_map_gt * t_gt_body,
            speed,
        },
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dc_loc_core::math::iso3_from_xyz_rpy;

    fn speeds(inputs: &[Input]) -> Vec<(i64, f64)> {
        inputs
            .iter()
            .map(|i| match i {
                Input::GroundTruth { stamp, speed, .. } => (stamp.0, *speed),
                other => panic!("not ground truth: {other:?}"),
            })
            .collect()
    }

    #[test]
    fn pose_speed_is_distance_over_time_and_the_first_pose_takes_the_seconds() {
        let mut s = PoseSpeed::default();
        let at = |x: f64| iso3_from_xyz_rpy(x, 0.0, 0.0, 0.0, 0.0, 0.0);
        assert!(s.push(Stamp(0), &at(0.0)).is_empty());
        let both = speeds(&s.push(Stamp(500_000_000), &at(5.0)));
        assert_eq!(both, vec![(0, 10.0), (500_000_000, 10.0)]);
        let same_stamp = speeds(&s.push(Stamp(500_000_000), &at(6.0)));
        assert_eq!(same_stamp, vec![(500_000_000, 0.0)]);
        assert!(s.finish().is_none());

        let mut single = PoseSpeed::default();
        assert!(single.push(Stamp(7), &at(1.0)).is_empty());
        assert_eq!(speeds(&[single.finish().unwrap()]), vec![(7, 0.0)]);
        assert!(single.finish().is_none());
    }

    #[test]
    fn to_body_composes_on_the_right() {
        let t_map_gt = iso3_from_xyz_rpy(10.0, 0.0, 0.0, 0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let t_gt_body = iso3_from_xyz_rpy(1.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let moved = to_body(
            Input::GroundTruth {
                stamp: Stamp(1),
                t_map_body: t_map_gt,
                speed: 3.0,
            },
            &t_gt_body,
        );
        let Input::GroundTruth {
            t_map_body, speed, ..
        } = moved
        else {
            panic!("not ground truth");
        };
        // One metre ahead of the tracked frame, which faces +y.
        assert!(
            (t_map_body.translation.vector - nalgebra::Vector3::new(10.0, 1.0, 0.0)).norm() < 1e-12
        );
        assert_eq!(speed, 3.0);
    }
}
