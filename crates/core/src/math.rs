//! Scalar, vector and pose types used across dc_loc, and the few pose helpers every module needs.
//!
//! Entry points: the type aliases, [`Stamp`], [`iso3_from_xyz_rpy`], [`iso2_from_iso3`],
//! [`iso3_from_iso2`], [`interpolate_iso3`], [`wrap_angle`].
//! Naming rule: a pose `t_a_b` maps coordinates in frame `b` into frame `a` (frame `b` seen from `a`).

use serde::{Deserialize, Serialize};

/// 2-vector, metres unless stated.
pub type Vec2 = nalgebra::Vector2<f64>;
/// 3-vector, metres unless stated.
pub type Vec3 = nalgebra::Vector3<f64>;
/// 2x2 matrix (point covariances in the plane, m^2).
pub type Mat2 = nalgebra::Matrix2<f64>;
/// 3x3 matrix.
pub type Mat3 = nalgebra::Matrix3<f64>;
/// 6x6 matrix (pose covariances in ROS order x, y, z, rot x, rot y, rot z).
pub type Mat6 = nalgebra::Matrix6<f64>;
/// Planar rigid motion.
pub type Iso2 = nalgebra::Isometry2<f64>;
/// Rigid motion in 3D.
pub type Iso3 = nalgebra::Isometry3<f64>;
/// Unit quaternion.
pub type Quat = nalgebra::UnitQuaternion<f64>;

/// A point in time: integer nanoseconds since an arbitrary epoch (ROS time or bag time).
///
/// Integer so that stamps compare and hash exactly; convert with [`Stamp::as_secs_f64`] for arithmetic.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default, Serialize, Deserialize,
)]
pub struct Stamp(pub i64);

impl Stamp {
    /// From a ROS `builtin_interfaces/Time` (seconds and nanoseconds); nanoseconds of 1e9 or more
    /// carry into the seconds (see [`Stamp::checked_from_sec_nanosec`], which refuses them).
    pub fn from_sec_nanosec(sec: i32, nanosec: u32) -> Self {
        Stamp(i64::from(sec) * 1_000_000_000 + i64::from(nanosec))
    }
    /// From a ROS `builtin_interfaces/Time`; `None` when `nanosec` is 1e9 or more, which names no
    /// time (a driver's bug, not a stamp to shift by whole seconds).
    pub fn checked_from_sec_nanosec(sec: i32, nanosec: u32) -> Option<Self> {
        (nanosec < 1_000_000_000).then(|| Self::from_sec_nanosec(sec, nanosec))
    }
    /// From floating-point seconds (rounded to the nearest nanosecond).
    pub fn from_secs_f64(s: f64) -> Self {
        Stamp((s * 1e9).round() as i64)
    }
    /// Seconds as f64.
    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 * 1e-9
    }
    /// ROS `builtin_interfaces/Time` split (seconds, nanoseconds); nanoseconds always in [0, 1e9).
    pub fn to_sec_nanosec(self) -> (i32, u32) {
        let sec = self.0.div_euclid(1_000_000_000);
        let nsec = self.0.rem_euclid(1_000_000_000);
        (sec as i32, nsec as u32)
    }
    /// `self - earlier` in seconds.
    pub fn secs_since(self, earlier: Stamp) -> f64 {
        (self.0 - earlier.0) as f64 * 1e-9
    }
}

/// Wraps an angle to (-pi, pi].
pub fn wrap_angle(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let mut w = a.rem_euclid(two_pi);
    if w > std::f64::consts::PI {
        w -= two_pi;
    }
    w
}

/// Pose from translation (m) and roll, pitch, yaw (rad; applied as R = Rz(yaw) Ry(pitch) Rx(roll), as ROS/tf2).
pub fn iso3_from_xyz_rpy(x: f64, y: f64, z: f64, roll: f64, pitch: f64, yaw: f64) -> Iso3 {
    Iso3::from_parts(
        nalgebra::Translation3::new(x, y, z),
        Quat::from_euler_angles(roll, pitch, yaw),
    )
}

/// Projects a 3D pose onto the plane: x, y and the yaw of its rotation.
pub fn iso2_from_iso3(t: &Iso3) -> Iso2 {
    let (_, _, yaw) = t.rotation.euler_angles();
    Iso2::new(Vec2::new(t.translation.x, t.translation.y), yaw)
}

/// Lifts a planar pose into 3D (z = 0, rotation about z).
pub fn iso3_from_iso2(t: &Iso2) -> Iso3 {
    iso3_from_xyz_rpy(
        t.translation.x,
        t.translation.y,
        0.0,
        0.0,
        0.0,
        t.rotation.angle(),
    )
}

/// Interpolates between two poses: linear in translation, spherical-linear in rotation; `s` in [0, 1]
/// gives a pose between them, values outside extrapolate linearly in translation and along the geodesic.
pub fn interpolate_iso3(a: &Iso3, b: &Iso3, s: f64) -> Iso3 {
    let t = a.translation.vector + (b.translation.vector - a.translation.vector) * s;
    // Relative rotation scaled along its axis: works for any s, unlike slerp's clamp.
    let rel = a.rotation.inverse() * b.rotation;
    let rot = a.rotation * Quat::from_scaled_axis(rel.scaled_axis() * s);
    Iso3::from_parts(nalgebra::Translation3::from(t), rot)
}

/// Adjoint of a planar rigid motion on se(2) tangents `(x, y, theta)`: `Log(T Exp(xi) T^-1) = Ad_T xi`,
/// `Ad_T = [[R, (t_y, -t_x)^T], [0, 0, 1]]`.
pub fn se2_adjoint(t: &Iso2) -> Mat3 {
    let r = t.rotation.to_rotation_matrix();
    let v = t.translation.vector;
    Mat3::new(
        r[(0, 0)],
        r[(0, 1)],
        v.y,
        r[(1, 0)],
        r[(1, 1)],
        -v.x,
        0.0,
        0.0,
        1.0,
    )
}

/// `Exp` of se(2): `delta = (x, y, theta)` to a rigid motion (`t = V(theta) (x, y)`).
pub fn se2_exp(delta: &Vec3) -> Iso2 {
    let th = delta[2];
    let (a, b) = v_coeffs(th);
    let t = Vec2::new(a * delta[0] - b * delta[1], b * delta[0] + a * delta[1]);
    Iso2::new(t, th)
}

/// `Log` of SE(2), inverse of [`se2_exp`]; theta in (-pi, pi].
pub fn se2_log(t: &Iso2) -> Vec3 {
    let th = t.rotation.angle();
    let (a, b) = v_coeffs(th);
    let p = t.translation.vector;
    let k = 1.0 / (a * a + b * b);
    Vec3::new(k * (a * p.x + b * p.y), k * (-b * p.x + a * p.y), th)
}

/// `sin(th)/th` and `(1 - cos(th))/th`, with series near zero.
fn v_coeffs(th: f64) -> (f64, f64) {
    if th.abs() < 1e-6 {
        (1.0 - th * th / 6.0, th / 2.0 - th * th * th / 24.0)
    } else {
        (th.sin() / th, (1.0 - th.cos()) / th)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn stamp_round_trips_ros_time_including_negative() {
        for ns in [
            0i64,
            1,
            999_999_999,
            1_000_000_000,
            1_700_000_000_123_456_789,
            -1,
            -1_500_000_000,
        ] {
            let (s, n) = Stamp(ns).to_sec_nanosec();
            assert!(n < 1_000_000_000);
            assert_eq!(Stamp::from_sec_nanosec(s, n), Stamp(ns));
        }
    }

    #[test]
    fn wrap_angle_range() {
        assert_relative_eq!(
            wrap_angle(3.0 * std::f64::consts::PI),
            std::f64::consts::PI,
            epsilon = 1e-12
        );
        assert_relative_eq!(wrap_angle(-0.5), -0.5, epsilon = 1e-15);
        assert_relative_eq!(
            wrap_angle(7.0),
            7.0 - std::f64::consts::TAU,
            epsilon = 1e-12
        );
    }

    #[test]
    fn planar_projection_round_trip() {
        let t = Iso2::new(Vec2::new(1.0, -2.0), 2.9);
        let back = iso2_from_iso3(&iso3_from_iso2(&t));
        assert_relative_eq!(
            back.translation.vector,
            t.translation.vector,
            epsilon = 1e-12
        );
        assert_relative_eq!(back.rotation.angle(), 2.9, epsilon = 1e-12);
    }

    #[test]
    fn interpolation_hits_ends_midpoint_and_extrapolates() {
        let a = iso3_from_xyz_rpy(0.0, 0.0, 0.0, 0.0, 0.0, 3.0);
        let b = iso3_from_xyz_rpy(2.0, 4.0, 0.0, 0.0, 0.0, -3.0); // crosses +-pi: short way is 0.283 rad
        let m = interpolate_iso3(&a, &b, 0.5);
        assert_relative_eq!(
            m.translation.vector,
            Vec3::new(1.0, 2.0, 0.0),
            epsilon = 1e-12
        );
        let yaw = iso2_from_iso3(&m).rotation.angle();
        assert_relative_eq!(
            wrap_angle(yaw - (3.0 + (std::f64::consts::TAU - 6.0) / 2.0)),
            0.0,
            epsilon = 1e-9
        );
        assert_relative_eq!(interpolate_iso3(&a, &b, 0.0), a, epsilon = 1e-12);
        assert_relative_eq!(interpolate_iso3(&a, &b, 1.0), b, epsilon = 1e-12);
        let e = interpolate_iso3(&a, &b, 2.0);
        assert_relative_eq!(
            e.translation.vector,
            Vec3::new(4.0, 8.0, 0.0),
            epsilon = 1e-12
        );
    }

    #[test]
    fn exp_log_round_trip() {
        for d in [
            Vec3::new(1.0, -2.0, 0.3),
            Vec3::new(0.1, 0.2, -3.0),
            Vec3::new(5.0, 1.0, 1e-9),
            Vec3::new(0.0, 0.0, 0.0),
        ] {
            let back = se2_log(&se2_exp(&d));
            assert!((back - d).norm() < 1e-9, "{d} -> {back}");
        }
    }
}
