//! Doppler compensation and per-point uncertainty (paper eq. 4-8).
//!
//! Entry points: [`compensate`] (eq. 4), [`jacobian`] (eq. 8), [`polar_covariance`] (eq. 7),
//! [`RadarModel`] (one radar's extrinsic, `beta` and noise) and [`RadarModel::to_body`], which turns a
//! scan into [`BodyPoint`]s in the body frame (eq. 5) carrying both the compensated and the raw position
//! and their covariances, so every ablation row can be built from the same data.
//!
//! Conventions (paper eq. 3-4): `r_hat = r + beta * v_r`, `v_r` positive away from the radar, the
//! radial velocity itself undistorted. Elevation is ignored in the covariance (z = 0 rows), as in the paper.

use crate::math::{Iso3, Mat3, Vec3};
use crate::radar::RadarConfig;
use crate::radar::{Detection, RadarNoise};

/// Doppler-compensated position of a detection, radar frame (eq. 4):
/// `p_bar = p_hat - beta * v_r * p_hat / |p_hat|`. A zero-range detection is returned unchanged.
pub fn compensate(det: &Detection, beta: f64) -> Vec3 {
    let r = det.p_radar.norm();
    if r <= 0.0 {
        return det.p_radar;
    }
    det.p_radar * (1.0 - beta * det.v_r / r)
}

/// Jacobian of the compensated Cartesian point `f(g) = [(r - beta v) cos phi, (r - beta v) sin phi, 0]`
/// with respect to the polar measurement `g = [r, v, phi]` (eq. 8).
pub fn jacobian(r: f64, v: f64, phi: f64, beta: f64) -> Mat3 {
    let (s, c) = phi.sin_cos();
    let rc = r - beta * v;
    Mat3::new(c, -beta * c, -rc * s, s, -beta * s, rc * c, 0.0, 0.0, 0.0)
}

/// Covariance of the compensated point in the radar frame, `J Sigma_p J^T` (eq. 7), with
/// `Sigma_p = diag(sigma_r^2, sigma_v^2, sigma_phi^2)` (eq. 6).
pub fn polar_covariance(r: f64, v: f64, phi: f64, beta: f64, noise: &RadarNoise) -> Mat3 {
    let j = jacobian(r, v, phi, beta);
    let sp = Mat3::from_diagonal(&Vec3::new(
        noise.sigma_range.powi(2),
        noise.sigma_velocity.powi(2),
        noise.sigma_azimuth.powi(2),
    ));
    j * sp * j.transpose()
}

/// One radar as the core needs it: where it sits, its Doppler coupling and its noise.
#[derive(Debug, Clone, PartialEq)]
pub struct RadarModel {
    /// Radar frame in the body frame.
    pub t_body_radar: Iso3,
    /// `beta = f_c / K`, s.
    pub beta: f64,
    /// Polar measurement noise.
    pub noise: RadarNoise,
}

impl From<&RadarConfig> for RadarModel {
    fn from(c: &RadarConfig) -> Self {
        RadarModel {
            t_body_radar: c.t_body_radar(),
            beta: c.beta,
            noise: c.noise(),
        }
    }
}

/// A detection carried into the body frame (eq. 5), in both its compensated and its raw form.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyPoint {
    /// Doppler-compensated position, body frame, m.
    pub p: Vec3,
    /// Covariance of `p` (eq. 7-8 rotated into the body frame), m^2.
    pub cov: Mat3,
    /// Measured (distorted) position, body frame, m.
    pub p_raw: Vec3,
    /// Covariance of `p_raw` (eq. 8 with `beta = 0`: range and azimuth noise only), m^2.
    pub cov_raw: Mat3,
    /// Unit ray from the radar towards the detection, body frame.
    pub ray: Vec3,
    /// Measured radial velocity, m/s.
    pub v_r: f64,
    /// Radar cross-section, dBsm, when reported.
    pub rcs: Option<f64>,
}

impl RadarModel {
    /// Compensates one detection (eq. 4), computes its covariance (eq. 7-8) and moves both into the body
    /// frame with the extrinsic (eq. 5): `p_body = T_b^m p_bar`, `Sigma_body = R Sigma R^T`.
    /// `None` for a zero-range detection (its ray is undefined).
    pub fn to_body(&self, det: &Detection) -> Option<BodyPoint> {
        let r = det.p_radar.norm();
        if !(r > 0.0 && r.is_finite() && det.v_r.is_finite()) {
            return None;
        }
        let phi = det.azimuth();
        let rot = self.t_body_radar.rotation.to_rotation_matrix();
        let rot = rot.matrix();
        let ray_radar = det.p_radar / r;
        let p_bar = det.p_radar - ray_radar * (self.beta * det.v_r);
        let cov = polar_covariance(r, det.v_r, phi, self.beta, &self.noise);
        let cov_raw = polar_covariance(r, det.v_r, phi, 0.0, &self.noise);
        let to_body = |p: Vec3| (self.t_body_radar * nalgebra::Point3::from(p)).coords;
        Some(BodyPoint {
            p: to_body(p_bar),
            cov: rot * cov * rot.transpose(),
            p_raw: to_body(det.p_radar),
            cov_raw: rot * cov_raw * rot.transpose(),
            ray: rot * ray_radar,
            v_r: det.v_r,
            rcs: det.rcs,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::iso3_from_xyz_rpy;
    use approx::assert_relative_eq;

    /// Central finite differences of `f(g)` against the analytic eq. 8 over a spread of measurements.
    #[test]
    fn jacobian_matches_finite_differences() {
        let beta = 0.04;
        let f = |g: Vec3| {
            let rc = g[0] - beta * g[1];
            Vec3::new(rc * g[2].cos(), rc * g[2].sin(), 0.0)
        };
        for &(r, v, phi) in &[
            (1.0, 0.0, 0.0),
            (12.3, -20.0, 0.7),
            (99.0, 15.0, -1.2),
            (40.0, -3.3, 2.9),
            (5.0, 7.0, -3.1),
        ] {
            let g = Vec3::new(r, v, phi);
            let j = jacobian(r, v, phi, beta);
            for k in 0..3 {
                let h = 1e-6 * (1.0 + g[k].abs());
                let mut gp = g;
                let mut gm = g;
                gp[k] += h;
                gm[k] -= h;
                let col = (f(gp) - f(gm)) / (2.0 * h);
                assert_relative_eq!(j.column(k).into_owned(), col, epsilon = 1e-6);
            }
        }
    }

    /// Simulate the FMCW distortion of static points seen from a moving radar and undo it.
    #[test]
    fn compensation_restores_true_points() {
        let beta = 0.04;
        let v_radar = Vec3::new(20.0, -1.5, 0.0); // 72 km/h with a little sideslip
        for i in 0..200 {
            let phi = -1.3 + 2.6 * (i as f64) / 199.0;
            let r = 2.0 + 0.49 * i as f64;
            let p_true = Vec3::new(r * phi.cos(), r * phi.sin(), 0.0);
            let d = p_true / r;
            let v_r = -d.dot(&v_radar); // static point, radar moving
            let det = Detection {
                p_radar: d * (r + beta * v_r),
                v_r,
                rcs: None,
            };
            let p = compensate(&det, beta);
            assert_relative_eq!(p, p_true, epsilon = 1e-12 * r.max(1.0));
            // And the displacement is the paper's: ~0.8 m straight ahead at 20 m/s with beta 0.04 s.
            if phi.abs() < 0.01 {
                assert_relative_eq!((det.p_radar - p).norm(), 0.8, epsilon = 0.01);
            }
        }
    }

    #[test]
    fn covariance_is_thin_across_the_ray_far_away() {
        let noise = RadarNoise::default();
        let c = polar_covariance(80.0, -10.0, 0.0, 0.04, &noise);
        // Along the ray (x): sigma_r^2 + beta^2 sigma_v^2; across (y): (r - beta v)^2 sigma_phi^2.
        assert_relative_eq!(
            c[(0, 0)],
            0.25f64.powi(2) + (0.04f64 * 0.1).powi(2),
            epsilon = 1e-12
        );
        let rc: f64 = 80.0 + 0.4;
        assert_relative_eq!(
            c[(1, 1)],
            (rc * 0.5f64.to_radians()).powi(2),
            epsilon = 1e-9
        );
        assert!(c[(1, 1)] > 5.0 * c[(0, 0)]); // 0.70 m across vs 0.25 m along at 80 m
        assert_eq!(c[(2, 2)], 0.0);
    }

    /// Eq. 5 with a rotated, offset radar: positions transform as points, covariances as `R C R^T`.
    #[test]
    fn extrinsic_moves_points_and_rotates_covariance() {
        let model = RadarModel {
            t_body_radar: iso3_from_xyz_rpy(-0.5, 0.6, 0.5, 0.0, 0.0, 174.4f64.to_radians()),
            beta: 0.04,
            noise: RadarNoise::default(),
        };
        let det = Detection {
            p_radar: Vec3::new(30.0, 5.0, 0.0),
            v_r: -8.0,
            rcs: Some(3.0),
        };
        let b = model.to_body(&det).unwrap();
        let expect = model.t_body_radar * nalgebra::Point3::from(compensate(&det, 0.04));
        assert_relative_eq!(b.p, expect.coords, epsilon = 1e-12);
        let r = model
            .t_body_radar
            .rotation
            .to_rotation_matrix()
            .into_inner();
        let c = polar_covariance(det.range(), det.v_r, det.azimuth(), 0.04, &model.noise);
        assert_relative_eq!(b.cov, r * c * r.transpose(), epsilon = 1e-12);
        // The ray points from the radar origin to the raw point.
        let origin = model.t_body_radar.translation.vector;
        assert_relative_eq!(b.ray, (b.p_raw - origin).normalize(), epsilon = 1e-12);
        assert!(
            model
                .to_body(&Detection {
                    p_radar: Vec3::zeros(),
                    v_r: 0.0,
                    rcs: None
                })
                .is_none()
        );
    }
}
