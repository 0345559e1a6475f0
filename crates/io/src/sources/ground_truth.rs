//! Ground truth from any source, brought to what the evaluation compares against: [`PoseSpeed`] (the
//! speed of ground truth that has poses only) and [`to_body`] (a tracked frame's pose moved to the body
//! frame).

use dc_loc_core::input::Input;
use dc_loc_core::math::{Iso3, Stamp};

/// The speed of ground truth that has poses and no twist (a `geometry_msgs/PoseStamped` topic, a TUM
/// file): the distance from the previous pose over the time between them, m/s; 0 for the first pose
/// and for one whose stamp is not after the previous one.
#[derive(Debug, Clone, Default)]
pub struct PoseSpeed {
    last: Option<(Stamp, Iso3)>,
}

impl PoseSpeed {
    /// The speed at `stamp`, arriving at `pose`; remembers both for the next call.
    pub fn next(&mut self, stamp: Stamp, pose: &Iso3) -> f64 {
        let speed = match self.last {
            Some((t, last)) if stamp > t => {
                (pose.translation.vector - last.translation.vector).norm() / stamp.secs_since(t)
            }
            _ => 0.0,
        };
        self.last = Some((stamp, *pose));
        speed
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

    #[test]
    fn pose_speed_is_distance_over_time_and_zero_without_a_step_forward() {
        let mut s = PoseSpeed::default();
        let at = |x: f64| iso3_from_xyz_rpy(x, 0.0, 0.0, 0.0, 0.0, 0.0);
        assert_eq!(s.next(Stamp(0), &at(0.0)), 0.0);
        assert!((s.next(Stamp(500_000_000), &at(5.0)) - 10.0).abs() < 1e-12);
        assert_eq!(s.next(Stamp(500_000_000), &at(6.0)), 0.0);
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
