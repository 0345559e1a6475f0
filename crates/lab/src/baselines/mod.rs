//! The baselines the evaluation compares DC-Loc against (paper Table 1). Each registers
//! [`PointSet2`](dc_loc_core::registration::PointSet2)s into a
//! [`RegistrationResult`](dc_loc_core::registration::RegistrationResult) as DC-Loc does, without their
//! per-point covariances; docs/algorithm.md, "Baselines", has the methods and their covariances.
//!
//! Entry points:
//! - [`icp`]: point-to-point ICP, coarse to fine, [`register_icp`] / [`IcpConfig`].
//! - [`ndt`]: 2D NDT on four overlapping grids, [`register_ndt`] / [`NdtConfig`] / [`NdtMap`].
//! - [`mc_ransac`]: MC-RANSAC's Doppler correction with a forward speed the method estimates itself
//!   from distorted scans, [`McRansacConfig`], [`ForwardSpeedEstimator`], [`estimate_forward_speed`],
//!   [`doppler_correct_detections`], [`doppler_correct_body`].
//! - [`BaselinesConfig`]: the three configurations, as the params YAML section `baselines`.

pub mod icp;
pub mod mc_ransac;
pub mod ndt;

pub use icp::{IcpConfig, register_icp};
pub use mc_ransac::{
    ForwardSpeedEstimator, McRansacConfig, SpeedEstimate, doppler_correct_body,
    doppler_correct_detections, doppler_correct_point, estimate_forward_speed,
    radar_velocity_from_forward_speed,
};
pub use ndt::{NdtConfig, NdtMap, NdtObjective, register_ndt};

use dc_loc_core::math::{Iso2, Mat3, Vec2};
use dc_loc_core::registration::RegistrationError;
use dc_loc_core::validate::{ConfigError, Validator};
use serde::{Deserialize, Serialize};

/// Configuration of all baselines, the params YAML section `baselines`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct BaselinesConfig {
    /// Point-to-point ICP.
    pub icp: IcpConfig,
    /// 2D NDT.
    pub ndt: NdtConfig,
    /// MC-RANSAC-style Doppler correction and its speed estimator.
    pub mc_ransac: McRansacConfig,
}

impl BaselinesConfig {
    /// Rejects unusable values, naming them `baselines.*`.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut v = Validator::at("baselines");
        v.section("icp", |v| self.icp.check(v));
        v.section("ndt", |v| self.ndt.check(v));
        v.section("mc_ransac", |v| self.mc_ransac.check(v));
        v.finish()
    }
}

/// Checks a point list: at least `need` points, all finite. `what` names it in the error.
pub(crate) fn check_points(
    what: &str,
    points: &[Vec2],
    need: usize,
) -> Result<(), RegistrationError> {
    if points.len() < need {
        return Err(RegistrationError::TooFewPoints {
            have: points.len(),
            need,
        });
    }
    if let Some(i) = points
        .iter()
        .position(|p| !(p.x.is_finite() && p.y.is_finite()))
    {
        return Err(RegistrationError::Numerical(format!(
            "{what} point {i} is not finite"
        )));
    }
    Ok(())
}

/// Checks that a pose guess is finite.
pub(crate) fn check_pose(what: &str, t: &Iso2) -> Result<(), RegistrationError> {
    let v = t.translation.vector;
    let a = t.rotation.angle();
    if v.x.is_finite() && v.y.is_finite() && a.is_finite() {
        Ok(())
    } else {
        Err(RegistrationError::Numerical(format!(
            "{what} is not finite"
        )))
    }
}

/// A 3x3 symmetric positive definite check and inverse via Cholesky; `None` when not SPD or ill-conditioned
/// beyond `1e12` (the covariance would be meaningless).
pub(crate) fn spd_inverse(h: &Mat3) -> Option<Mat3> {
    let sym = (h + h.transpose()) * 0.5;
    let eig = sym.symmetric_eigenvalues();
    let (lo, hi) = (eig.min(), eig.max());
    if !(lo.is_finite() && hi.is_finite()) || lo <= 0.0 || lo < hi * 1e-12 {
        return None;
    }
    sym.cholesky().map(|c| c.inverse())
}
