//! Submap-to-submap registration: DC-Loc's association and uncertainty-aware optimisation.
//!
//! Entry points: [`PointSet2`] (points with 2x2 covariances, the input of every method),
//! [`RegistrationResult`] (output of every method, DC-Loc and baselines alike), [`RegistrationError`],
//! [`covariance_ros_from_se2`].
//! Naming: the *source* is the current (query) submap X, the *target* the previous (match) submap Y;
//! `t_target_source` maps source coordinates into the target frame (paper: `T_b^p`), `d_i = y_i - T x_i`.

use crate::math::{Iso2, Mat2, Mat3, Mat6, Vec2};

/// Variance (m^2 or rad^2) reported for the axes a planar registration does not observe (z, roll, pitch).
///
/// Large enough that a pose-graph back end gives those axes no weight, small enough to stay finite in
/// single precision after inversion: 1e6 (a 1 km / 1000 rad standard deviation).
pub const UNOBSERVED_VARIANCE: f64 = 1e6;

/// A planar point set with per-point covariances (m^2), in one submap frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointSet2 {
    /// Point positions, m.
    pub points: Vec<Vec2>,
    /// One covariance per point (symmetric positive definite), m^2.
    pub covs: Vec<Mat2>,
}

impl PointSet2 {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }
    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
    /// Points with an isotropic covariance `sigma^2 I`.
    pub fn isotropic(points: Vec<Vec2>, sigma: f64) -> Self {
        let covs = vec![Mat2::identity() * sigma * sigma; points.len()];
        PointSet2 { points, covs }
    }
}

/// What a registration method returns.
#[derive(Debug, Clone, PartialEq)]
pub struct RegistrationResult {
    /// Source (current) frame in the target (previous) frame.
    pub t_target_source: Iso2,
    /// Covariance of `t_target_source`, 6x6 in ROS order (x, y, z, rot x, rot y, rot z), row-major when
    /// flattened; unobserved axes carry [`UNOBSERVED_VARIANCE`].
    pub covariance: Mat6,
    /// The optimiser met its convergence criterion (not just the iteration limit).
    pub converged: bool,
    /// Optimiser iterations used.
    pub iterations: usize,
    /// Correspondences kept as inliers at the end.
    pub inliers: usize,
    /// Candidate correspondences before outlier rejection.
    pub candidates: usize,
    /// Final cost (method specific; lower is better).
    pub cost: f64,
}

/// Why a registration produced no result.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RegistrationError {
    /// A point set is too small for the method.
    #[error("too few points: {have} (need at least {need})")]
    TooFewPoints {
        /// Points available.
        have: usize,
        /// Points needed.
        need: usize,
    },
    /// Outlier rejection left too few correspondences.
    #[error("too few inlier correspondences: {have} (need at least {need})")]
    TooFewInliers {
        /// Inliers found.
        have: usize,
        /// Inliers needed.
        need: usize,
    },
    /// The optimisation produced a non-finite or singular result.
    #[error("optimisation failed: {0}")]
    Numerical(String),
}

/// Embeds a planar covariance over (x, y, theta) into the 6x6 ROS-order covariance
/// (x, y, z, rot x, rot y, rot z); z, roll and pitch get [`UNOBSERVED_VARIANCE`] and no correlation.
pub fn covariance_ros_from_se2(cov_xy_theta: &Mat3) -> Mat6 {
    let mut c = Mat6::zeros();
    let idx = [0usize, 1, 5];
    for (i, &a) in idx.iter().enumerate() {
        for (j, &b) in idx.iter().enumerate() {
            c[(a, b)] = cov_xy_theta[(i, j)];
        }
    }
    for k in [2usize, 3, 4] {
        c[(k, k)] = UNOBSERVED_VARIANCE;
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros_order_puts_yaw_last() {
        let c = Mat3::new(1.0, 2.0, 3.0, 2.0, 4.0, 5.0, 3.0, 5.0, 6.0);
        let r = covariance_ros_from_se2(&c);
        assert_eq!(r[(0, 0)], 1.0);
        assert_eq!(r[(0, 1)], 2.0);
        assert_eq!(r[(0, 5)], 3.0);
        assert_eq!(r[(5, 0)], 3.0);
        assert_eq!(r[(1, 5)], 5.0);
        assert_eq!(r[(5, 5)], 6.0);
        assert_eq!(r[(2, 2)], UNOBSERVED_VARIANCE);
        assert_eq!(r[(3, 3)], UNOBSERVED_VARIANCE);
        assert_eq!(r[(4, 4)], UNOBSERVED_VARIANCE);
        assert_eq!(r[(2, 5)], 0.0);
        assert_eq!(r, r.transpose());
    }
}
