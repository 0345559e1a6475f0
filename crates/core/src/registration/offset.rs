//! A common offset of the returns along their rays, estimated with the pose ([`fit_offset`]).
//!
//! A return comes from an object's near face, and a skewed range noise crowds a pass's detections on
//! one side of the true range: every return of a pass lies about the same distance `delta` along its
//! ray from its surface, and passes that saw a scene from other sides pull the pose by `sensitivity *
//! delta`. [`fit_offset`] takes the joint Gauss-Newton step of the pose and `delta` at fixed pairs, with
//! the pose's own robust weights and a zero-mean prior on `delta`; [`OffsetFit`] holds `delta`, its
//! variance and the pose's sensitivity, which enters the covariance as a consider parameter
//! ([`OffsetFit::covariance`]). docs/algorithm.md, "The covariance reported", has the system, its
//! Schur complement and why the offset is only considered.
//!
//! Entry points: [`fit_offset`], [`RaySide`], [`OffsetFit`].

use super::lm::LmConfig;
use crate::math::{Iso2, Mat2, Mat3, Vec2, Vec3};

/// Two-sided 95 % quantile of the standard normal: `delta` enters the pose only where the pair
/// shows it at this level (the likelihood-ratio test of the pose with and without it, one degree of
/// freedom).
const Z_95: f64 = 1.959_964;

/// What the pairs say about a common offset along the rays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OffsetFit {
    /// The offset estimated with the pose, m (positive: the returns lie beyond the surfaces).
    pub offset: f64,
    /// Its variance, m^2.
    pub variance: f64,
    /// How the pose moves per metre of offset admitted, over (x, y, yaw) (right perturbation).
    pub sensitivity: Vec3,
    /// The joint Gauss-Newton step of the pose (right perturbation).
    pub step: Vec3,
}

impl OffsetFit {
    /// The pairs show an offset: it differs from zero at the 5 % level.
    pub fn significant(&self) -> bool {
        self.offset.abs() > Z_95 * self.variance.sqrt()
    }

    /// What an offset of standard deviation `prior_std` adds to the pose covariance along the
    /// sensitivity (a consider parameter, see the module doc).
    pub fn covariance(&self, prior_std: f64) -> Mat3 {
        self.sensitivity * self.sensitivity.transpose() * (prior_std * prior_std)
    }
}

/// One side of the pairs: positions, covariances and unit rays, all in that side's frame.
pub struct RaySide<'a> {
    /// Positions, m.
    pub points: &'a [Vec2],
    /// Their covariances, m^2.
    pub covs: &'a [Mat2],
    /// The unit directions of their rays.
    pub rays: &'a [Vec2],
}

/// The joint step of the pose and a common offset at `t` over `pairs` (see the module doc), weighted as
/// `cfg` weighs the pose's own fit. `None` when the pose's information is singular or a pair's
/// combined covariance is not positive definite; indices must be valid.
pub fn fit_offset(
    t: &Iso2,
    source: &RaySide<'_>,
    target: &RaySide<'_>,
    pairs: &[(usize, usize)],
    cfg: &LmConfig,
    prior_std: f64,
) -> Option<OffsetFit> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let iso = Mat2::identity() / (cfg.isotropic_sigma * cfg.isotropic_sigma);
    let mut a = Mat3::zeros();
    let mut b = Vec3::zeros();
    let mut c = 1.0 / (prior_std * prior_std);
    let mut g_pose = Vec3::zeros();
    let mut g_delta = 0.0;
    for &(i, j) in pairs {
        let x = source.points[i];
        let d = target.points[j] - (r * x + t.translation.vector);
        let e = r * source.rays[i] - target.rays[j];
        let w = if cfg.use_uncertainty {
            (target.covs[j] + r * source.covs[i] * r.transpose()).try_inverse()?
        } else {
            iso
        };
        let (_, drho, _) = cfg.robust.rho(d.dot(&(w * d)));
        // J = d(d)/d(Delta) = -R [I | perp(x)], one column per pose coordinate.
        let rp = r * Vec2::new(-x.y, x.x);
        let jac = [-r.column(0).into_owned(), -r.column(1).into_owned(), -rp];
        let (wd, we) = (w * d, w * e);
        for m in 0..3 {
            let wj = w * jac[m];
            for n in 0..3 {
                a[(m, n)] += drho * jac[n].dot(&wj);
            }
            b[m] += drho * jac[m].dot(&we);
            g_pose[m] += drho * jac[m].dot(&wd);
        }
        c += drho * e.dot(&we);
        g_delta += drho * e.dot(&wd);
    }
    let a_inv = a.try_inverse()?;
    let schur = c - b.dot(&(a_inv * b));
    if !(schur.is_finite() && schur > 0.0) {
        return None;
    }
    let offset = -(g_delta - b.dot(&(a_inv * g_pose))) / schur;
    Some(OffsetFit {
        offset,
        variance: 1.0 / schur,
        sensitivity: -(a_inv * b),
        step: -(a_inv * (g_pose + b * offset)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::se2_exp;
    use crate::registration::robust::RobustLoss;
    use rand::{RngExt, SeedableRng};

    /// A street's returns seen by a pass at `sensor` (target frame): each point moved by `delta`
    /// along its ray, then written in the pass's frame `pose` (target from pass), with its ray.
    fn pass(scene: &[Vec2], sensor: Vec2, pose: &Iso2, delta: f64) -> (Vec<Vec2>, Vec<Vec2>) {
        let inv = pose.inverse();
        let r_inv = inv.rotation.to_rotation_matrix().into_inner();
        scene
            .iter()
            .map(|p| {
                let u = (p - sensor).normalize();
                let seen = p + delta * u;
                ((inv * nalgebra::Point2::from(seen)).coords, r_inv * u)
            })
            .unzip()
    }

    fn street(seed: u64) -> Vec<Vec2> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        (0..300)
            .map(|k| {
                let side = if k % 2 == 0 { 1.0 } else { -1.0 };
                Vec2::new(
                    rng.random_range(-40.0..40.0),
                    side * rng.random_range(4.0..25.0),
                )
            })
            .collect()
    }

    fn least_squares() -> LmConfig {
        LmConfig {
            robust: RobustLoss::none(),
            ..LmConfig::default()
        }
    }

    fn fit(
        t: &Iso2,
        s: &(Vec<Vec2>, Vec<Vec2>),
        g: &(Vec<Vec2>, Vec<Vec2>),
        prior: f64,
    ) -> OffsetFit {
        let covs = vec![Mat2::identity() * 0.01; s.0.len()];
        let source = RaySide {
            points: &s.0,
            covs: &covs,
            rays: &s.1,
        };
        let target = RaySide {
            points: &g.0,
            covs: &covs,
            rays: &g.1,
        };
        let pairs: Vec<(usize, usize)> = (0..s.0.len()).map(|k| (k, k)).collect();
        fit_offset(t, &source, &target, &pairs, &least_squares(), prior).expect("fit")
    }

    /// A reverse pass on the other side of the road, every return 0.2 m beyond its surface in both:
    /// the joint steps from a pose off by 0.3 m and 0.01 rad end at the true pose and offset; the pose
    /// fitted with the offset held at zero lies the sensitivity times the offset away, the other way.
    #[test]
    fn the_joint_steps_recover_the_pose_and_the_offset_of_a_reverse_pass() {
        let scene = street(7);
        let truth = Iso2::new(Vec2::new(3.0, -7.0), std::f64::consts::PI - 0.05);
        let delta = 0.2;
        let target = pass(&scene, Vec2::new(0.0, 3.0), &Iso2::identity(), delta);
        let source = pass(&scene, truth.translation.vector, &truth, delta);
        let mut t = truth * se2_exp(&Vec3::new(0.3, -0.2, 0.01));
        let mut last = None;
        for _ in 0..6 {
            let f = fit(&t, &source, &target, 1e3);
            t *= se2_exp(&f.step);
            last = Some(f);
        }
        let f = last.expect("fit");
        let err = crate::math::se2_log(&(truth.inverse() * t));
        assert!(err.norm() < 1e-6, "pose error {err:?}");
        assert!((f.offset - delta).abs() < 1e-6, "offset {}", f.offset);
        assert!(f.significant());
        // The pose that fits with the offset held at zero: the truth moved by -sensitivity * delta.
        let mut held = truth;
        for _ in 0..6 {
            let f0 = fit(&held, &source, &target, 1e-9);
            held *= se2_exp(&f0.step);
        }
        let slide = crate::math::se2_log(&(truth.inverse() * held));
        assert!(
            slide.xy().norm() > 0.02,
            "the offset moves the pose: {slide:?}"
        );
        assert!(
            (slide + f.sensitivity * delta).norm() < 0.1 * slide.norm(),
            "slide {slide:?}, sensitivity * delta {:?}",
            f.sensitivity * delta
        );
    }

    /// Two passes along the same rays (the same sensor position) cannot tell the offset from the
    /// pose: the step is nil, the offset stays at the prior's zero with the prior's variance, and
    /// nothing is added to the covariance.
    #[test]
    fn passes_along_the_same_rays_leave_the_pose_alone() {
        let scene = street(8);
        let pose = Iso2::new(Vec2::new(0.0, 0.0), 0.0);
        let target = pass(&scene, Vec2::new(0.0, 3.0), &pose, 0.2);
        let f = fit(&pose, &target, &target, 0.25);
        assert!(f.step.norm() < 1e-12, "step {:?}", f.step);
        assert!(f.offset.abs() < 1e-12);
        assert!((f.variance - 0.0625).abs() < 1e-12);
        assert!(!f.significant());
        assert!(f.covariance(0.25).norm() < 1e-20);
    }
}
