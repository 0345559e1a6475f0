//! MC-RANSAC's Doppler correction (Burnett et al., RA-L 2021), the "MC-RANSAC" row of the paper's
//! Table 1: only its Doppler part, as in the paper's comparison (automotive radars are not
//! motion-distorted).
//!
//! Each point moves along its ray by `beta (d . v_radar)`, yeti's `dopplerCorrection` generalised to any
//! extrinsic, with `v_radar` implied by the body's forward speed (the yaw rate's lever arm ignored).
//! That speed is the method's own estimate, ICP of uncorrected scans a few scans apart, and so biased.
//! docs/algorithm.md, "Baselines", has the audit of yeti's code, the generalisation and the bias.
//!
//! Entry points: [`doppler_correct_point`], [`doppler_correct_detections`] (radar frame),
//! [`doppler_correct_body`] (body frame, given the ray), [`radar_velocity_from_forward_speed`],
//! [`estimate_forward_speed`] and the stateful [`ForwardSpeedEstimator`] (the speed the correction
//! uses), [`McRansacConfig`], [`SpeedEstimate`].

use super::{IcpConfig, register_icp};
use dc_loc_core::math::{Iso2, Iso3, Stamp, Vec2, Vec3, se2_exp, se2_log};
use dc_loc_core::radar::Detection;
use dc_loc_core::registration::{PointSet2, RegistrationError, RegistrationResult};
use dc_loc_core::validate::{ConfigError, Validator};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// Settings of the MC-RANSAC-style baseline's speed estimator (params YAML section
/// `baselines.mc_ransac`). The Doppler coefficient `beta` is the radar's (`radars.<name>.beta`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct McRansacConfig {
    /// Scan-to-scan ICP.
    pub icp: IcpConfig,
    /// The reference scan is this many scans back (1 = consecutive scans); the speed is averaged over
    /// that baseline.
    pub baseline_scans: usize,
    /// A gap between scans longer than this, s, restarts the estimator (no prediction across it).
    pub max_scan_interval: f64,
}

impl Default for McRansacConfig {
    /// The default ICP (5 m, 2 m, 1 m: the zero-motion guess after a failed estimate is off by a whole
    /// baseline's motion, 4.6 m at 72 km/h over 3 scans at 13 Hz); a baseline of 3 scans (see the module
    /// doc); scans more than 0.5 s apart restart the estimator.
    fn default() -> Self {
        McRansacConfig {
            icp: IcpConfig::default(),
            baseline_scans: 3,
            max_scan_interval: 0.5,
        }
    }
}

impl McRansacConfig {
    /// Rejects unusable values, naming them `baselines.mc_ransac.*`.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut v = Validator::at("baselines.mc_ransac");
        self.check(&mut v);
        v.finish()
    }

    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.section("icp", |v| self.icp.check(v));
        v.at_least("baseline_scans", self.baseline_scans, 1);
        v.positive("max_scan_interval", self.max_scan_interval);
    }
}

/// The radar's velocity in its own frame, m/s, implied by the body's forward speed `forward_speed` (m/s):
/// `R_body_radar^T [v, 0, 0]`. The yaw rate's lever-arm term is ignored (docs/algorithm.md, "Baselines").
pub fn radar_velocity_from_forward_speed(forward_speed: f64, t_body_radar: &Iso3) -> Vec3 {
    t_body_radar.rotation.inverse() * Vec3::new(forward_speed, 0.0, 0.0)
}

/// One point in the radar frame corrected for the Doppler range shift of a static target seen by a radar
/// moving at `v_radar` (m/s, radar frame): `p + beta (d . v_radar) d`, `d = p / |p|`, `beta` in s.
/// A point at the origin is returned unchanged.
pub fn doppler_correct_point(p_radar: &Vec3, v_radar: &Vec3, beta: f64) -> Vec3 {
    let r = p_radar.norm();
    if r <= 0.0 {
        return *p_radar;
    }
    let d = p_radar / r;
    p_radar + d * (beta * d.dot(v_radar))
}

/// The detections with their positions corrected by [`doppler_correct_point`] (radial velocity and RCS
/// kept as measured). `v_radar` comes from the *estimated* forward speed via
/// [`radar_velocity_from_forward_speed`].
pub fn doppler_correct_detections(
    detections: &[Detection],
    v_radar: &Vec3,
    beta: f64,
) -> Vec<Detection> {
    detections
        .iter()
        .map(|det| Detection {
            p_radar: doppler_correct_point(&det.p_radar, v_radar, beta),
            ..*det
        })
        .collect()
}

/// A point already in the body frame (planar), corrected along its ray: `p + beta (d . [v, 0]) d` with
/// `d` the unit direction of `ray_body` (the ray from the radar to the point, in body axes) and
/// `forward_speed` (m/s) the body's estimated forward speed. Equals [`doppler_correct_point`] mapped into
/// the body frame, since `d . v` does not depend on the axes it is computed in. A zero ray leaves `p`
/// unchanged.
pub fn doppler_correct_body(p_body: &Vec2, ray_body: &Vec2, forward_speed: f64, beta: f64) -> Vec2 {
    let n = ray_body.norm();
    if n <= 0.0 {
        return *p_body;
    }
    let d = ray_body / n;
    p_body + d * (beta * d.x * forward_speed)
}

/// The forward speed a scan-to-scan registration implies.
#[derive(Debug, Clone, PartialEq)]
pub struct SpeedEstimate {
    /// Forward speed of the body, m/s: the x component of `Log(t_prev_cur) / dt`.
    pub forward_speed: f64,
    /// Lateral speed of the body, m/s: the y component of `Log(t_prev_cur) / dt`.
    pub lateral_speed: f64,
    /// Yaw rate, rad/s: `t_prev_cur.rotation.angle() / dt`.
    pub yaw_rate: f64,
    /// The current body frame in the previous one.
    pub t_prev_cur: Iso2,
    /// The ICP result behind it (`t_target_source == t_prev_cur`).
    pub registration: RegistrationResult,
}

/// Estimates the forward speed from two *uncorrected* scans (points in their body frames, m) taken `dt` s
/// apart (consecutive, or a baseline of several scans), by ICP of the current scan onto the previous one
/// seeded with `predicted_t_prev_cur` (e.g. constant velocity). See docs/algorithm.md, "Baselines", for why the result is
/// biased.
///
/// Errors: those of [`register_icp`], and [`RegistrationError::Numerical`] when `dt` is not positive.
pub fn estimate_forward_speed(
    prev_points_body: &[Vec2],
    cur_points_body: &[Vec2],
    dt: f64,
    predicted_t_prev_cur: &Iso2,
    icp: &IcpConfig,
) -> Result<SpeedEstimate, RegistrationError> {
    if !(dt.is_finite() && dt > 0.0) {
        return Err(RegistrationError::Numerical(format!(
            "scan interval {dt} s is not positive"
        )));
    }
    // The point covariances are not used by ICP.
    let source = PointSet2::isotropic(cur_points_body.to_vec(), 1.0);
    let target = PointSet2::isotropic(prev_points_body.to_vec(), 1.0);
    let registration = register_icp(&source, &target, predicted_t_prev_cur, icp)?;
    let t = registration.t_target_source;
    let twist = se2_log(&t) / dt;
    Ok(SpeedEstimate {
        forward_speed: twist.x,
        lateral_speed: twist.y,
        yaw_rate: twist.z,
        t_prev_cur: t,
        registration,
    })
}

/// Forward speed from a stream of uncorrected scans.
///
/// Each new scan is registered onto the scan `baseline_scans` back (the oldest kept one at start-up),
/// seeded with a constant-velocity prediction from the last estimate (zero motion at start-up); the speed
/// is the forward component of the twist over the elapsed time (see [`estimate_forward_speed`]). A longer
/// baseline averages the speed over more time and divides the registration noise by the baseline (see
/// [`McRansacConfig::baseline_scans`]).
#[derive(Debug, Clone)]
pub struct ForwardSpeedEstimator {
    config: McRansacConfig,
    /// The last `baseline_scans` scans, oldest first: stamp and points in their body frame.
    history: VecDeque<(Stamp, Vec<Vec2>)>,
    /// Last estimated body twist (forward m/s, lateral m/s, yaw rate rad/s).
    twist: Option<Vec3>,
}

impl ForwardSpeedEstimator {
    /// A new estimator; the configuration is validated.
    pub fn new(config: McRansacConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        Ok(ForwardSpeedEstimator {
            config,
            history: VecDeque::new(),
            twist: None,
        })
    }

    /// Forgets all scans and the last motion.
    pub fn reset(&mut self) {
        self.history.clear();
        self.twist = None;
    }

    /// The last estimated forward speed, m/s, if any.
    pub fn forward_speed(&self) -> Option<f64> {
        self.twist.map(|t| t.x)
    }

    /// Adds a scan (uncorrected points in its body frame, m) taken at `stamp`; returns the speed
    /// estimated for it, or `None` for the first scan (or after a gap above `max_scan_interval` or a stamp
    /// that does not increase, which restart the estimator). On a registration error the scan is still
    /// kept, the last motion is forgotten, and the error is returned.
    pub fn push(
        &mut self,
        stamp: Stamp,
        points_body: Vec<Vec2>,
    ) -> Result<Option<SpeedEstimate>, RegistrationError> {
        let Some((newest, _)) = self.history.back() else {
            self.history.push_back((stamp, points_body));
            return Ok(None);
        };
        let dt = stamp.secs_since(*newest);
        if !(dt > 0.0 && dt <= self.config.max_scan_interval) {
            log::warn!(
                "mc_ransac: scan interval {dt} s outside (0, max_scan_interval]: restarting"
            );
            self.reset();
            self.history.push_back((stamp, points_body));
            return Ok(None);
        }
        let result = match self.history.front() {
            Some((ref_stamp, ref_points)) => {
                let elapsed = stamp.secs_since(*ref_stamp);
                // Constant-velocity prediction over the baseline (zero motion without an estimate).
                let predicted = self
                    .twist
                    .map(|w| se2_exp(&(w * elapsed)))
                    .unwrap_or_else(Iso2::identity);
                estimate_forward_speed(
                    ref_points,
                    &points_body,
                    elapsed,
                    &predicted,
                    &self.config.icp,
                )
            }
            None => Err(RegistrationError::Numerical(
                "no reference scan kept".into(),
            )),
        };
        match &result {
            Ok(est) => {
                self.twist = Some(Vec3::new(
                    est.forward_speed,
                    est.lateral_speed,
                    est.yaw_rate,
                ))
            }
            Err(e) => {
                // Per scan (sparse side radars fail often on real data): debug, not warn.
                log::debug!("mc_ransac: speed estimate failed: {e}");
                self.twist = None;
            }
        }
        self.history.push_back((stamp, points_body));
        while self.history.len() > self.config.baseline_scans {
            self.history.pop_front();
        }
        result.map(Some)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn forward_radar_reduces_to_yeti_form() {
        let beta = 0.04;
        let v = 17.0;
        let v_radar = radar_velocity_from_forward_speed(v, &Iso3::identity());
        for (r, th) in [(10.0_f64, 0.3_f64), (55.0, -1.1), (3.0, 1.2)] {
            let p = Vec3::new(r * th.cos(), r * th.sin(), 0.0);
            let got = doppler_correct_point(&p, &v_radar, beta);
            let yeti = p + Vec3::new(th.cos(), th.sin(), 0.0) * (beta * v * th.cos());
            assert_relative_eq!(got, yeti, epsilon = 1e-12);
        }
    }

    #[test]
    fn body_form_equals_radar_form_mapped() {
        let t_body_radar = dc_loc_core::math::iso3_from_xyz_rpy(1.2, -0.8, 0.5, 0.0, 0.0, -0.9);
        let (beta, v) = (0.04, 11.0);
        let v_radar = radar_velocity_from_forward_speed(v, &t_body_radar);
        let p_radar = Vec3::new(20.0, 7.0, 0.0);
        let corrected_body =
            t_body_radar * nalgebra::Point3::from(doppler_correct_point(&p_radar, &v_radar, beta));
        let p_body = t_body_radar * nalgebra::Point3::from(p_radar);
        let ray_body = t_body_radar.rotation * p_radar;
        let got = doppler_correct_body(&p_body.xy().coords, &ray_body.xy(), v, beta);
        assert_relative_eq!(got, corrected_body.xy().coords, epsilon = 1e-12);
    }

    #[test]
    fn config_validation_names_fields() {
        McRansacConfig::default().validate().unwrap();
        let mut c = McRansacConfig::default();
        c.icp.max_iterations = 0;
        assert_eq!(
            c.validate().unwrap_err().name,
            "baselines.mc_ransac.icp.max_iterations"
        );
        let c = McRansacConfig {
            baseline_scans: 0,
            ..McRansacConfig::default()
        };
        assert_eq!(
            c.validate().unwrap_err().name,
            "baselines.mc_ransac.baseline_scans"
        );
    }
}
