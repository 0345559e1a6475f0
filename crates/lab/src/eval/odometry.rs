//! The odometry the pipeline used, measured against the simulator's ground truth ([`measure_odometry`]):
//! its drift at the end of the first lap (share of the distance, heading in degrees per 100 m), and
//! whether its covariance is honest: the NEES of its relative motion over 10 m windows.
//!
//! A window runs from one odometry sample `a` to the first sample `b` at least 10 m of ground-truth
//! path later; the next window starts at `b`, so windows do not overlap and their errors are
//! independent. The relative motion `r = (R_a^T (p_b - p_a), theta_b - theta_a)` is compared with the
//! truth's. Its covariance follows from the published ones: errors accumulate step by step, so the
//! pose error at `b` is `F_ab` times the one at `a` plus the window's own, `Q_ab = P_b - F_ab P_a
//! F_ab^T` (`F_ab = [[1, 0, -(y_b - y_a)], [0, 1, x_b - x_a], [0, 0, 1]]`), which `r` sees rotated
//! into frame `a`. A consistent covariance gives NEES values distributed as chi-square(3).

use crate::sim::SimDrive;
use dc_loc_core::math::{Iso2, Mat3, Stamp, Vec3, wrap_angle};
use serde::Serialize;

/// Length of the windows the relative motion is judged over, m.
pub const NEES_WINDOW: f64 = 10.0;
/// The chi-square(3) 99 % quantile.
const CHI2_3_99: f64 = 11.345;

/// One odometry sample: stamp, `t_odom_body`, covariance of `(x, y, yaw)` in the odometry frame.
pub type OdometryTrackSample = (Stamp, Iso2, Mat3);

/// How the odometry drifted and how honest its covariance was.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct OdometryDrift {
    /// Position error at the end of the first lap over the path driven, share.
    pub share: f64,
    /// Heading error at the end of the first lap per 100 m of path, degrees.
    pub heading_deg_per_100m: f64,
    /// Windows judged.
    pub windows: usize,
    /// Mean NEES of the windows' relative motion (3 when the covariance is right).
    pub nees_mean: f64,
    /// Share of windows above the chi-square(3) 99 % bound.
    pub nees_above_99: f64,
}

/// Measures `samples` (time order) against the ground truth of `drive`; `None` with fewer than two
/// samples or none in the first lap.
pub fn measure_odometry(
    drive: &SimDrive,
    samples: &[OdometryTrackSample],
) -> Option<OdometryDrift> {
    let (first, _) = samples.split_first()?;
    let truth = |s: Stamp| drive.state_at(s);
    let start = truth(first.0);
    let t_map_odom = start.t_map_body * first.1.inverse();
    let end_of_lap = drive.ground_truth.iter().rfind(|g| g.lap.lap == 0)?;
    let end = samples
        .iter()
        .min_by_key(|s| (s.0.0 - end_of_lap.stamp.0).abs())?;
    let g = truth(end.0);
    let est = t_map_odom * end.1;
    let distance = (g.distance - start.distance).max(1.0);
    let position = (est.translation.vector - g.t_map_body.translation.vector).norm();
    let heading = wrap_angle(est.rotation.angle() - g.t_map_body.rotation.angle());
    let mut out = OdometryDrift {
        share: position / distance,
        heading_deg_per_100m: heading.to_degrees().abs() * 100.0 / distance,
        ..OdometryDrift::default()
    };
    let nees = window_nees(drive, samples);
    out.windows = nees.len();
    if !nees.is_empty() {
        out.nees_mean = nees.iter().sum::<f64>() / nees.len() as f64;
        let above = nees.iter().filter(|n| **n > CHI2_3_99).count();
        out.nees_above_99 = above as f64 / nees.len() as f64;
    }
    Some(out)
}

/// The NEES of the relative motion over each 10 m window (see the module documentation).
fn window_nees(drive: &SimDrive, samples: &[OdometryTrackSample]) -> Vec<f64> {
    let mut out = Vec::new();
    let mut a = 0;
    let distance = |i: usize| drive.state_at(samples[i].0).distance;
    for b in 1..samples.len() {
        if distance(b) - distance(a) < NEES_WINDOW {
            continue;
        }
        if let Some(n) = nees(drive, &samples[a], &samples[b]) {
            out.push(n);
        }
        a = b;
    }
    out
}

fn nees(drive: &SimDrive, a: &OdometryTrackSample, b: &OdometryTrackSample) -> Option<f64> {
    let relative = |pa: &Iso2, pb: &Iso2| {
        let d = pa.rotation.inverse() * (pb.translation.vector - pa.translation.vector);
        Vec3::new(d.x, d.y, pb.rotation.angle() - pa.rotation.angle())
    };
    let (ga, gb) = (
        drive.state_at(a.0).t_map_body,
        drive.state_at(b.0).t_map_body,
    );
    let mut e = relative(&a.1, &b.1) - relative(&ga, &gb);
    e.z = wrap_angle(e.z);
    let step = b.1.translation.vector - a.1.translation.vector;
    let f = Mat3::new(1.0, 0.0, -step.y, 0.0, 1.0, step.x, 0.0, 0.0, 1.0);
    let q = b.2 - f * a.2 * f.transpose();
    let (s, c) = a.1.rotation.angle().sin_cos();
    let m = Mat3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0);
    let q = m * q * m.transpose();
    let info = q.try_inverse()?;
    let n = (e.transpose() * info * e)[0];
    (n.is_finite() && n >= 0.0).then_some(n)
}
