//! The body's planar pose integrated from the fitted twists, with its covariance propagated step by
//! step ([`PlanarIntegrator`]): SE(2) in the odometry frame, lifted to [`Iso3`] as the pipeline uses.
//!
//! One step from `t_a` to `t_b` (`dt`) takes the mean body velocity `v` of its two ends and the heading
//! change `dtheta` (from the yaw rates at the ends, or the gyro over the interval):
//!
//! ```text
//! theta_m = theta + dtheta / 2,   p' = p + R(theta_m) v dt,   theta' = theta + dtheta
//! ```
//!
//! and the covariance of `(x, y, theta)` (odometry frame) to first order, `P' = F P F^T + G Q G^T`,
//! with `F = [[1, 0, -dy], [0, 1, dx], [0, 0, 1]]` (`(dx, dy)` the step in the odometry frame), `G` the
//! step's derivative in `(v_x, v_y, dtheta)` and `Q` their covariance. A gyro bias error `db`, constant
//! over the drive, turns the heading by `-db dt` every step: its effect is carried as a sensitivity
//! `s = d pose / d bias` and added as `sigma_b^2 s s^T` (a consider covariance) rather than as white
//! noise, which would shrink it by the square root of the steps.

use crate::math::{Iso3, Mat3, Stamp, Vec2, Vec3, iso3_from_iso2};
use crate::pose_noise::{PoseNoise, shear};
use nalgebra::{Isometry2, Matrix2};

/// One step's motion: body velocity and heading change with their covariance, and how much of the
/// heading change is `-bias dt` of a gyro.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepMotion {
    /// Body velocity over the step, m/s.
    pub velocity: Vec2,
    /// Heading change, rad.
    pub dtheta: f64,
    /// Covariance of `(v_x, v_y, dtheta)` (white part).
    pub covariance: Mat3,
    /// Derivative of `dtheta` in the gyro bias, s (`-dt` with a gyro, 0 without).
    pub dtheta_per_bias: f64,
}

/// The integrated pose and its covariance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanarIntegrator {
    stamp: Stamp,
    xy: Vec2,
    theta: f64,
    /// Covariance of `(x, y, theta)` from the white errors.
    white: Mat3,
    /// `d (x, y, theta) / d bias`.
    sensitivity: Vec3,
}

impl PlanarIntegrator {
    /// At the odometry frame's origin at `stamp`, with no uncertainty.
    pub fn new(stamp: Stamp) -> Self {
        PlanarIntegrator {
            stamp,
            xy: Vec2::zeros(),
            theta: 0.0,
            white: Mat3::zeros(),
            sensitivity: Vec3::zeros(),
        }
    }

    /// The stamp of the pose.
    pub fn stamp(&self) -> Stamp {
        self.stamp
    }

    /// The planar pose `t_odom_body`.
    pub fn pose2(&self) -> Isometry2<f64> {
        Isometry2::new(self.xy, self.theta)
    }

    /// The pose `t_odom_body`, lifted to 3D.
    pub fn pose(&self) -> Iso3 {
        iso3_from_iso2(&self.pose2())
    }

    /// Covariance of `(x, y, theta)` in the odometry frame with a gyro bias of variance
    /// `bias_variance` (0 without a gyro).
    pub fn covariance(&self, bias_variance: f64) -> Mat3 {
        self.noise(bias_variance).covariance()
    }

    /// The pose's uncertainty with a gyro bias of variance `bias_variance`, in the form that gives
    /// the covariance of the motion between two poses.
    pub fn noise(&self, bias_variance: f64) -> PoseNoise {
        PoseNoise {
            white: self.white,
            sensitivity: self.sensitivity,
            bias_variance,
        }
    }

    /// Moves the pose to `stamp` by `m`.
    pub fn step(&mut self, stamp: Stamp, m: &StepMotion) {
        let dt = stamp.secs_since(self.stamp).max(0.0);
        self.stamp = stamp;
        let theta_m = self.theta + 0.5 * m.dtheta;
        let (s, c) = theta_m.sin_cos();
        let rot = Matrix2::new(c, -s, s, c);
        let d = rot * m.velocity * dt;
        let f = shear(d);
        // Derivative in (v_x, v_y, dtheta): the velocity through R dt, the heading change through
        // the mid-step heading (half of it) and the heading itself.
        let mut g = Mat3::zeros();
        g.fixed_view_mut::<2, 2>(0, 0).copy_from(&(rot * dt));
        g[(0, 2)] = -0.5 * d.y;
        g[(1, 2)] = 0.5 * d.x;
        g[(2, 2)] = 1.0;
        self.white = f * self.white * f.transpose() + g * m.covariance * g.transpose();
        self.sensitivity = f * self.sensitivity + g.column(2) * m.dtheta_per_bias;
        self.xy += d;
        self.theta += m.dtheta;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::wrap_angle;
    use rand::SeedableRng;
    use rand::rngs::StdRng;
    use rand_distr::{Distribution, Normal};

    fn motion(v: Vec2, dtheta: f64) -> StepMotion {
        StepMotion {
            velocity: v,
            dtheta,
            covariance: Mat3::from_diagonal(&Vec3::new(0.01, 0.01, 1e-5)),
            dtheta_per_bias: 0.0,
        }
    }

    /// A constant twist integrates to the arc of a circle of radius v / omega.
    #[test]
    fn a_constant_twist_drives_a_circle() {
        let (v, w, dt) = (10.0, 0.2, 0.01);
        let mut i = PlanarIntegrator::new(Stamp(0));
        let steps = (std::f64::consts::PI / w / dt).round() as i64;
        for k in 1..=steps {
            i.step(
                Stamp::from_secs_f64(k as f64 * dt),
                &motion(Vec2::new(v, 0.0), w * dt),
            );
        }
        let p = i.pose2();
        // About half a turn on the circle of radius v / w to the left of the start.
        let (theta, r) = (steps as f64 * w * dt, v / w);
        let on_circle = Vec2::new(r * theta.sin(), r * (1.0 - theta.cos()));
        assert!((p.translation.vector - on_circle).norm() < 0.05, "{p}");
        assert!((wrap_angle(p.rotation.angle() - theta)).abs() < 1e-9);
    }

    /// The propagated covariance matches the scatter of many noisy integrations of a curve, and a
    /// bias's sensitivity is its heading error per unit bias.
    #[test]
    fn the_covariance_matches_monte_carlo() {
        let mut rng = StdRng::seed_from_u64(2);
        let n_v = Normal::new(0.0, 0.1).unwrap();
        let n_w = Normal::new(0.0, 1e-5f64.sqrt()).unwrap();
        let (runs, steps, dt) = (2000, 100, 0.05);
        let truth = |k: usize| (Vec2::new(12.0, 0.0), 0.01 * (k as f64 * 0.1).sin());
        let mut finals = Vec::new();
        let mut reference = PlanarIntegrator::new(Stamp(0));
        for k in 0..steps {
            let (v, dth) = truth(k);
            let mut m = motion(v, dth);
            m.dtheta_per_bias = -dt;
            reference.step(Stamp::from_secs_f64((k + 1) as f64 * dt), &m);
        }
        for _ in 0..runs {
            let mut i = PlanarIntegrator::new(Stamp(0));
            for k in 0..steps {
                let (v, dth) = truth(k);
                let noisy = Vec2::new(v.x + n_v.sample(&mut rng), v.y + n_v.sample(&mut rng));
                i.step(
                    Stamp::from_secs_f64((k + 1) as f64 * dt),
                    &motion(noisy, dth + n_w.sample(&mut rng)),
                );
            }
            let p = i.pose2();
            finals.push(Vec3::new(
                p.translation.x,
                p.translation.y,
                p.rotation.angle(),
            ));
        }
        let mean = finals.iter().sum::<Vec3>() / runs as f64;
        let scatter = finals
            .iter()
            .map(|f| (f - mean) * (f - mean).transpose())
            .sum::<Mat3>()
            / runs as f64;
        let predicted = reference.covariance(0.0);
        for k in 0..3 {
            let ratio = scatter[(k, k)] / predicted[(k, k)];
            assert!((0.85..1.15).contains(&ratio), "axis {k}: {ratio}");
        }
        assert!((reference.sensitivity.z + steps as f64 * dt).abs() < 1e-9);
        let with_bias = reference.covariance(1e-4);
        assert!(with_bias[(2, 2)] > predicted[(2, 2)] + 1e-4 * 24.0);
    }

    /// The motion between two poses of a track is what a track started at the earlier pose
    /// integrates over the same steps, turned by the earlier heading: white errors and bias alike.
    #[test]
    fn the_motion_between_two_poses_is_a_fresh_track_over_the_same_steps() {
        let (dt, split, bias_variance) = (0.05, 25, 1e-4);
        let mut whole = PlanarIntegrator::new(Stamp(0));
        let mut earlier = None;
        let mut fresh: Option<PlanarIntegrator> = None;
        for k in 0..60 {
            let mut m = motion(Vec2::new(10.0, 0.3), 0.02 * (k as f64 * 0.2).sin() + 0.01);
            m.dtheta_per_bias = -dt;
            let t = Stamp::from_secs_f64((k + 1) as f64 * dt);
            whole.step(t, &m);
            if let Some(f) = fresh.as_mut() {
                f.step(t, &m);
            }
            if k + 1 == split {
                earlier = Some(whole);
                fresh = Some(PlanarIntegrator::new(t));
            }
        }
        let (a, fresh) = (earlier.unwrap(), fresh.unwrap());
        let shift = whole.pose2().translation.vector - a.pose2().translation.vector;
        let motion = whole
            .noise(bias_variance)
            .since(&a.noise(bias_variance), shift);
        let mut turn = Mat3::identity();
        let (s, c) = a.theta.sin_cos();
        turn.fixed_view_mut::<2, 2>(0, 0)
            .copy_from(&Matrix2::new(c, -s, s, c));
        let expected = turn * fresh.covariance(bias_variance) * turn.transpose();
        let scale = expected.abs().max();
        assert!(scale > 1e-3, "{expected}");
        assert!(
            (motion - expected).abs().max() < 1e-9 * scale,
            "{motion} against {expected}"
        );
        // Not the whole track's covariance: the steps before `a` are left out.
        assert!(whole.covariance(bias_variance)[(2, 2)] > 2.0 * expected[(2, 2)]);
    }
}
