//! What a calibration error does to a closure: the radars' extrinsics (`loop.extrinsic_std`) and
//! their clocks (`loop.clock_std`).
//!
//! Both submaps of a closure are built through the same extrinsics. When those are off by a small
//! body-frame motion `D = Exp(xi)`, every point of both submaps is moved by `D`, and the registration
//! finds `T' = D T D^-1` instead of `T` (`T = T_match_query`). In the convention of the published
//! covariance (`T_true = T_est Exp(delta)`), `Exp(delta) = T'^-1 T = Exp(xi) Exp(-Ad_{T^-1} xi)`, so to
//! first order `delta = (I - Ad_{T^-1}) xi`. A closure between keyframes at the same pose is
//! unaffected; one across a street in the other direction (`T` a half turn, metres apart) takes the
//! offset twice and the yaw error times the distance. The yaw of a closure is never affected (planar
//! rotations commute).

use crate::math::{Iso2, Mat3, Mat6, Vec3, se2_adjoint};

/// Covariance over `(x, y, yaw)` that an extrinsic calibration with standard deviations
/// `[translation m (each axis), yaw rad]` adds to the closure `t_match_query`.
pub fn calibration_covariance(t_match_query: &Iso2, extrinsic_std: [f64; 2]) -> Mat3 {
    let [st, sr] = extrinsic_std;
    let j = Mat3::identity() - se2_adjoint(&t_match_query.inverse());
    let sigma = Mat3::from_diagonal(&Vec3::new(st * st, st * st, sr * sr));
    j * sigma * j.transpose()
}

/// Covariance over `(x, y, yaw)` that radar clocks off the odometry's by `clock_std` seconds add to
/// the closure `t_match_query` between keyframes driven at `speeds` = `[query, match]` m/s.
///
/// A scan stamped `dt` late is placed where the body was `dt` later, so a submap is expressed in its
/// body frame `speed dt` behind the keyframe's: the query submap in `F_q Exp(-dt v_q e_x)`, the match
/// submap in `F_m Exp(-dt v_m e_x)`. The registration then finds `T' = Exp(dt v_m e_x) T Exp(-dt v_q
/// e_x)`, and `Exp(delta) = T'^-1 T` gives, to first order, `delta = dt (v_q e_x - v_m Ad_{T^-1}
/// e_x)`: nothing between keyframes at one pose and one speed, the speed difference along the
/// heading, the speed sum for a closure driven the other way.
pub fn clock_covariance(t_match_query: &Iso2, speeds: [f64; 2], clock_std: f64) -> Mat3 {
    moved_frames_covariance(t_match_query, Vec3::x(), speeds, clock_std)
}

/// Covariance over `(x, y, yaw)` when the query's submap lies in its body frame moved by `a_q e` and
/// the match's by `a_m e` (`amounts` = `[a_q, a_m]`, `e` a body-frame motion), both scaled by one
/// unknown of standard deviation `std`: the registration finds `Exp(a_m e) T Exp(-a_q e)`, to first
/// order `delta = a_q e - a_m Ad_{T^-1} e`, whose outer product times `std^2` is returned.
pub fn moved_frames_covariance(t_match_query: &Iso2, e: Vec3, amounts: [f64; 2], std: f64) -> Mat3 {
    let [aq, am] = amounts;
    let j = e * aq - se2_adjoint(&t_match_query.inverse()) * e * am;
    j * j.transpose() * (std * std)
}

/// Covariance over `(x, y, yaw)` that independent errors of the two submaps' frames, each of
/// covariance `motion`, add to the closure `t_match_query`: the registration finds
/// `Exp(xi_m) T Exp(-xi_q)`, to first order `delta = xi_q - Ad_{T^-1} xi_m`.
pub fn submap_motion_covariance(t_match_query: &Iso2, motion: &Mat3) -> Mat3 {
    let a = se2_adjoint(&t_match_query.inverse());
    motion + a * motion * a.transpose()
}

/// `cov6` (ROS order) with the planar covariance `c` over `(x, y, yaw)` added to its x, y and yaw rows
/// and columns.
pub fn add_planar(cov6: &Mat6, c: &Mat3) -> Mat6 {
    let mut out = *cov6;
    let idx = [0usize, 1, 5];
    for (i, &a) in idx.iter().enumerate() {
        for (j, &b) in idx.iter().enumerate() {
            out[(a, b)] += c[(i, j)];
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Vec2, se2_exp, se2_log};

    /// The first-order error against the exact one: submaps moved by a small calibration error
    /// `D`, the registration's answer `D T D^-1`, its error `Log((D T D^-1)^-1 T)`.
    #[test]
    fn first_order_error_matches_the_moved_submaps() {
        let cases = [
            Iso2::new(Vec2::new(3.0, -1.0), 0.2),
            Iso2::new(Vec2::new(-2.0, 14.0), std::f64::consts::PI - 0.1),
            Iso2::new(Vec2::new(0.5, 0.5), -1.3),
        ];
        let xi = Vec3::new(0.03, -0.02, 0.02);
        for t in cases {
            let d = se2_exp(&xi);
            let seen = d * t * d.inverse();
            let exact = se2_log(&(seen.inverse() * t));
            let first = (Mat3::identity() - se2_adjoint(&t.inverse())) * xi;
            // Second-order terms only: under a tenth of `xi` and of the error at this size of `xi`.
            assert!(
                (exact - first).norm() < 0.1 * xi.norm(),
                "{exact} vs {first}"
            );
            assert!(
                (exact - first).norm() < 0.1 * exact.norm(),
                "{exact} vs {first}"
            );
        }
    }

    /// The first-order clock error against the exact one: submaps in frames moved back by `dt` times
    /// their speeds, the registration's answer between those frames.
    #[test]
    fn clock_error_matches_the_moved_frames() {
        let (dt, vq, vm) = (0.03, 20.0, 11.0);
        for t in [
            Iso2::new(Vec2::new(2.0, -0.5), 0.05),
            Iso2::new(Vec2::new(1.0, 9.0), std::f64::consts::PI - 0.05),
        ] {
            let back = |v: f64| se2_exp(&Vec3::new(-dt * v, 0.0, 0.0));
            let seen = back(vm).inverse() * t * back(vq);
            let exact = se2_log(&(seen.inverse() * t));
            let c = clock_covariance(&t, [vq, vm], dt);
            // The covariance of a known offset `dt` is the outer product of the error it makes.
            assert!(
                (c - exact * exact.transpose()).norm() < 0.05 * exact.norm_squared(),
                "{c} vs {exact}"
            );
        }
        let same = clock_covariance(&Iso2::identity(), [15.0, 15.0], 0.03);
        assert!(same.norm() < 1e-15);
        // Driven the other way: the speeds add along the heading.
        let other_way = Iso2::new(Vec2::new(0.0, 0.0), std::f64::consts::PI);
        let c = clock_covariance(&other_way, [10.0, 8.0], 0.01);
        assert!((c[(0, 0)] - (18.0f64 * 0.01).powi(2)).abs() < 1e-12, "{c}");
    }

    #[test]
    fn nothing_at_the_same_pose_and_most_across_the_street_the_other_way() {
        let std = [0.05, 0.026];
        let same = calibration_covariance(&Iso2::identity(), std);
        assert!(same.norm() < 1e-15);
        let across = Iso2::new(Vec2::new(0.0, 12.0), std::f64::consts::PI);
        let c = calibration_covariance(&across, std);
        // Turned half round, 12 m away: the yaw error swings the query 12 m x 0.026 rad sideways and
        // the offset counts twice in both axes; planar rotations commute, so the yaw itself is exact.
        let want_x = (2.0 * 0.05_f64).powi(2) + (12.0 * 0.026_f64).powi(2);
        assert!((c[(0, 0)] - want_x).abs() < 1e-9, "{c}");
        assert!((c[(1, 1)] - (2.0 * 0.05_f64).powi(2)).abs() < 1e-12, "{c}");
        assert!(c[(2, 2)].abs() < 1e-15, "{c}");
        assert_eq!(c, c.transpose());
    }
}
