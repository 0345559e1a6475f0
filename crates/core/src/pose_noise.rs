//! The uncertainty of a dead-reckoned planar pose ([`PoseNoise`]), kept in the form that gives the
//! covariance of the motion between two of its poses: what the points of a submap, stacked with that
//! motion, are uncertain by.
//!
//! Dead reckoning propagates the covariance of `(x, y, theta)` (odometry frame) step by step as
//! `P' = F P F^T + G Q G^T` with `F = [[1, 0, -dy], [0, 1, dx], [0, 0, 1]]`, a shear by the step
//! `(dx, dy)`. Shears compose by adding their steps, so from pose `a` to pose `b` the product of the
//! steps' `F` is the shear by the whole displacement `b - a`, and the errors the steps between them
//! add are `P_b - F_ab P_a F_ab^T`. A gyro bias, constant along the drive, is carried as a sensitivity
//! `s = d pose / d bias`; its part in the motion is `sigma_b^2 (s_b - F_ab s_a) (s_b - F_ab s_a)^T`.

use crate::math::{Mat3, Vec2, Vec3};

/// Covariance of an integrated pose, split into the white errors and a bias's sensitivity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseNoise {
    /// Covariance of `(x, y, theta)` from the white errors, odometry frame.
    pub white: Mat3,
    /// `d (x, y, theta) / d bias` of a gyro bias (zero without one).
    pub sensitivity: Vec3,
    /// Variance of the bias.
    pub bias_variance: f64,
}

impl PoseNoise {
    /// No uncertainty: the start of a track.
    pub fn zero() -> Self {
        PoseNoise {
            white: Mat3::zeros(),
            sensitivity: Vec3::zeros(),
            bias_variance: 0.0,
        }
    }

    /// Covariance of `(x, y, theta)` of the pose, odometry frame.
    pub fn covariance(&self) -> Mat3 {
        self.white + self.sensitivity * self.sensitivity.transpose() * self.bias_variance
    }

    /// Covariance of `(x, y, theta)` of this pose given the `earlier` one, odometry frame: the
    /// errors of the steps between them. `shift` is this pose's position minus the earlier one's.
    /// Negative eigenvalues that rounding may leave are cut to zero.
    pub fn since(&self, earlier: &PoseNoise, shift: Vec2) -> Mat3 {
        let f = shear(shift);
        let white = self.white - f * earlier.white * f.transpose();
        let s = self.sensitivity - f * earlier.sensitivity;
        let c = white + s * s.transpose() * self.bias_variance;
        let mut eig = (0.5 * (c + c.transpose())).symmetric_eigen();
        eig.eigenvalues.iter_mut().for_each(|l| *l = l.max(0.0));
        eig.recompose()
    }
}

/// `F` of a step `d`: how a heading error turns the positions after it.
pub fn shear(d: Vec2) -> Mat3 {
    Mat3::new(1.0, 0.0, -d.y, 0.0, 1.0, d.x, 0.0, 0.0, 1.0)
}
