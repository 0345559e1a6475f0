//! The joint planar ego-motion fit of one time step: the body's `(v_x, v_y, yaw rate)` from the static
//! detections of every radar, with the extrinsics.
//!
//! A static detection of radar `k` (pose `t_body_radar = (R, p)`) along the unit ray `d` (radar frame)
//! has `v_r = -d . R^T (v_body + omega x p)` (docs/algorithm.md, "Radar odometry"). Each radar's scan
//! is fitted first with the Doppler ego-motion fit the submaps use ([`fit_radar_velocity`]: RANSAC,
//! the adaptive inlier threshold, a prior against large movers), which gives that radar's planar
//! velocity `u_k` and its covariance `C_k`; `u_k = A_k x` is linear in the body twist `x`, so the
//! twist is the information-weighted combination `(sum A^T C^-1 A)^-1 sum A^T C^-1 u`: the least
//! squares over every static detection of every radar, each radar weighted by its own residual spread.
//! A scan the fit refuses (too few static returns, dominated by movers) leaves the others.
//!
//! Entry points: [`doppler_information`] (the radars' information on the twist, and each scan's
//! outcome), [`DopplerInformation::solve`] (the twist, with a gyro's yaw rate when there is one).

use crate::math::{Iso3, Mat3, Vec2, Vec3};
use crate::radar::Detection;
use crate::radar::ego_motion::{EgoMotionConfig, EgoMotionError, FitDims, fit_radar_velocity};
use nalgebra::Matrix2x3;

/// A yaw rate known worse than this is no estimate, rad/s: 0.2 rad/s turns the heading by 11 degrees
/// a second. Radars mounted a few centimetres apart see the yaw rate that badly.
pub const MAX_YAW_RATE_SIGMA: f64 = 0.2;

/// One radar's scan in a time step.
#[derive(Debug, Clone, Copy)]
pub struct StepScan<'a> {
    /// Radar index.
    pub radar: usize,
    /// The radar's pose in the body frame.
    pub t_body_radar: Iso3,
    /// Its detections (radar frame).
    pub detections: &'a [Detection],
    /// The radar's radial-velocity noise, m/s (`radars.<name>.sigma_velocity`): the floor of the
    /// residual spread a fit's covariance is scaled by.
    pub sigma_velocity: f64,
    /// How much the body twist changes from the scan's stamp to the step's, `(m/s, m/s, rad/s)`: the
    /// radars of a step measure at different times, and between the left and the right radars a
    /// speed change of a few cm/s reads as a yaw rate of a few hundredths of a rad/s.
    pub shift: Vec3,
}

/// Why one radar's scan gave no velocity.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScanRefusal {
    /// Fewer static returns than the fit needs.
    #[error("too few static returns: {have} (need {need})")]
    TooFewStatic {
        /// Static returns found (or usable detections).
        have: usize,
        /// Needed (`ego_motion.min_inliers`).
        need: usize,
    },
    /// No velocity near the prior gathered enough returns: moving objects fill the view.
    #[error("dominated by moving objects: best consensus {best} (need {need})")]
    DominatedByMovers {
        /// Largest consensus.
        best: usize,
        /// Needed.
        need: usize,
    },
    /// The rays do not constrain the radar's planar velocity (all along one line of sight).
    #[error("the rays do not constrain the velocity")]
    Degenerate,
    /// The refined fit ended farther from the prior than the body can change speed in a step.
    #[error("fit {distance:.2} m/s from the previous velocity (ego_motion.prior_tolerance)")]
    FarFromPrior {
        /// Distance to the prior, m/s.
        distance: f64,
    },
}

impl ScanRefusal {
    /// Short snake_case name for counts.
    pub fn name(&self) -> &'static str {
        match self {
            ScanRefusal::TooFewStatic { .. } => "too_few_static",
            ScanRefusal::DominatedByMovers { .. } => "dominated_by_movers",
            ScanRefusal::Degenerate => "degenerate",
            ScanRefusal::FarFromPrior { .. } => "far_from_prior",
        }
    }
}

/// Why a time step gave no twist.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TwistRefusal {
    /// Every radar's scan was refused (or the step had none).
    #[error("no radar gave a velocity")]
    NoRadar,
    /// The yaw rate is not observable: one radar (or radars at one place) without a gyro or the
    /// lateral-velocity constraint.
    #[error("yaw rate unobservable from {radars} radar(s) (sigma {sigma:.3} rad/s)")]
    YawRateUnobservable {
        /// Radars that gave a velocity.
        radars: usize,
        /// The yaw rate's standard deviation, rad/s (infinite when singular).
        sigma: f64,
    },
}

impl TwistRefusal {
    /// Short snake_case name for counts.
    pub fn name(&self) -> &'static str {
        match self {
            TwistRefusal::NoRadar => "no_radar",
            TwistRefusal::YawRateUnobservable { .. } => "yaw_rate_unobservable",
        }
    }
}

/// One radar's part in a step.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanOutcome {
    /// Radar index.
    pub radar: usize,
    /// Static returns used, or why the scan was refused.
    pub result: Result<usize, ScanRefusal>,
}

/// The radars' information on the body twist `x = (v_x, v_y, yaw rate)` of one step.
#[derive(Debug, Clone, PartialEq)]
pub struct DopplerInformation {
    /// `sum A^T C^-1 A` (plus the lateral constraint).
    pub information: Mat3,
    /// `sum A^T C^-1 u`.
    pub vector: Vec3,
    /// Each scan's outcome, in input order.
    pub scans: Vec<ScanOutcome>,
    /// The largest planar speed a radar of the step measured, m/s (`None`: no scan was fitted).
    pub fastest: Option<f64>,
}

/// A fitted planar body twist.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanarTwist {
    /// `(v_x m/s, v_y m/s, yaw rate rad/s)`, body frame.
    pub twist: Vec3,
    /// Its covariance.
    pub covariance: Mat3,
}

/// `A` of `u = A x`: the planar velocity of a radar mounted at `t_body_radar` (radar frame) for the
/// body twist `x`: `R^T (v + omega x p)`, first two rows.
pub fn radar_velocity_map(t_body_radar: &Iso3) -> Matrix2x3<f64> {
    let rt = t_body_radar
        .rotation
        .inverse()
        .to_rotation_matrix()
        .into_inner();
    let p = t_body_radar.translation.vector;
    Matrix2x3::from_fn(|i, j| match j {
        0 => rt[(i, 0)],
        1 => rt[(i, 1)],
        _ => rt[(i, 1)] * p.x - rt[(i, 0)] * p.y,
    })
}

/// Fits each scan of a step and sums the radars' information on the twist. `prior` (the previous
/// step's twist) keeps large movers from winning a scan's fit; `lateral_sigma` > 0 adds `v_y = 0`
/// with that standard deviation.
pub fn doppler_information(
    scans: &[StepScan<'_>],
    prior: Option<Vec3>,
    lateral_sigma: f64,
    cfg: &EgoMotionConfig,
) -> DopplerInformation {
    let mut info = DopplerInformation {
        information: Mat3::zeros(),
        vector: Vec3::zeros(),
        scans: Vec::with_capacity(scans.len()),
        fastest: None,
    };
    for s in scans {
        let a = radar_velocity_map(&s.t_body_radar);
        let result = fit_scan(s, prior.map(|x| a * x), cfg).map(|(u, c, n)| {
            info.fastest = Some(info.fastest.unwrap_or(0.0).max(u.norm()));
            let u = u + a * s.shift;
            let w = c.try_inverse().unwrap_or_else(Mat3::zeros);
            let w2 = w.fixed_view::<2, 2>(0, 0).into_owned();
            info.information += a.transpose() * w2 * a;
            info.vector += a.transpose() * w2 * u;
            n
        });
        info.scans.push(ScanOutcome {
            radar: s.radar,
            result,
        });
    }
    if lateral_sigma > 0.0 {
        info.information[(1, 1)] += lateral_sigma.powi(-2);
    }
    info
}

/// One scan's planar velocity (radar frame), its covariance (z padded) and its static returns. The
/// covariance is scaled by the residual spread, but never by less than the radar's noise: with a few
/// dozen returns, trimmed by the adaptive threshold, the spread comes out below the noise often
/// enough to make the fused twist overconfident (mean NEES 5.4 instead of 3 with 15 returns a radar).
fn fit_scan(
    scan: &StepScan<'_>,
    prior: Option<Vec2>,
    cfg: &EgoMotionConfig,
) -> Result<(Vec2, Mat3, usize), ScanRefusal> {
    let priors: Vec<Vec3> = prior.iter().map(|p| Vec3::new(p.x, p.y, 0.0)).collect();
    let dets = scan.detections;
    let fit = fit_radar_velocity(dets, FitDims::Planar, &priors, cfg).map_err(|e| match e {
        EgoMotionError::TooFewDetections { have, need } => ScanRefusal::TooFewStatic { have, need },
        EgoMotionError::NoConsensus { best, need } => ScanRefusal::DominatedByMovers { best, need },
        EgoMotionError::Degenerate => ScanRefusal::Degenerate,
    })?;
    let u = fit.v_radar.xy();
    if let Some(p) = prior {
        let distance = (u - p).norm();
        if distance > cfg.prior_tolerance {
            return Err(ScanRefusal::FarFromPrior { distance });
        }
    }
    let n = fit.num_inliers as f64;
    let spread = fit.rms.powi(2) * n / (n - 2.0).max(1.0);
    let mut c = fit.unit_covariance * scan.sigma_velocity.powi(2).max(spread);
    c[(2, 2)] = 1.0;
    Ok((u, c, fit.num_inliers))
}

impl DopplerInformation {
    /// Radars that gave a velocity.
    pub fn radars(&self) -> usize {
        self.scans.iter().filter(|s| s.result.is_ok()).count()
    }

    /// The twist from the radars and, when given, a yaw rate `(rad/s, variance)` from a gyro.
    pub fn solve(&self, yaw_rate: Option<(f64, f64)>) -> Result<PlanarTwist, TwistRefusal> {
        let radars = self.radars();
        if radars == 0 {
            return Err(TwistRefusal::NoRadar);
        }
        let (mut l, mut eta) = (self.information, self.vector);
        if let Some((w, var)) = yaw_rate {
            l[(2, 2)] += 1.0 / var;
            eta[2] += w / var;
        }
        let eig = l.symmetric_eigenvalues();
        let unobservable = TwistRefusal::YawRateUnobservable {
            radars,
            sigma: f64::INFINITY,
        };
        if !(eig.max() > 0.0 && eig.min() > 1e-9 * eig.max()) {
            return Err(unobservable);
        }
        let covariance = l.try_inverse().ok_or(unobservable)?;
        let sigma = covariance[(2, 2)].sqrt();
        if sigma > MAX_YAW_RATE_SIGMA {
            return Err(TwistRefusal::YawRateUnobservable { radars, sigma });
        }
        Ok(PlanarTwist {
            twist: covariance * eta,
            covariance,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::iso3_from_xyz_rpy;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// The nuScenes mountings: five radars around a car, body frame on the rear axle.
    fn nuscenes_mounts() -> Vec<Iso3> {
        [
            (3.412, 0.0, 0.2),
            (2.422, 0.8, 88.36),
            (2.422, -0.8, -90.98),
            (-0.562, 0.628, 174.41),
            (-0.562, -0.618, -176.11),
        ]
        .iter()
        .map(|&(x, y, yaw)| iso3_from_xyz_rpy(x, y, 0.5, 0.0, 0.0, f64::to_radians(yaw)))
        .collect()
    }

    /// Detections of a radar mounted at `m` on a body moving with `x`: `n` static returns with
    /// 0.1 m/s Doppler noise within +-75 degrees, then `movers` returns of a car at 8 m/s.
    fn scan(m: &Iso3, x: Vec3, n: usize, movers: usize, rng: &mut StdRng) -> Vec<Detection> {
        let p = m.translation.vector;
        let v_at = Vec3::new(x.x - x.z * p.y, x.y + x.z * p.x, 0.0);
        let v_radar = m.rotation.inverse() * v_at;
        let noise = Normal::new(0.0, 0.1).unwrap();
        (0..n + movers)
            .map(|i| {
                let phi: f64 = rng.random_range(-1.3..1.3);
                let d = Vec3::new(phi.cos(), phi.sin(), 0.0);
                let v_target = if i < n {
                    Vec3::zeros()
                } else {
                    Vec3::new(8.0, 0.0, 0.0)
                };
                Detection {
                    p_radar: d * rng.random_range(3.0..80.0),
                    v_r: d.dot(&(v_target - v_radar)) + noise.sample(rng),
                    rcs: None,
                }
            })
            .collect()
    }

    fn step<'a>(mounts: &[Iso3], scans: &'a [Vec<Detection>]) -> Vec<StepScan<'a>> {
        mounts
            .iter()
            .zip(scans)
            .enumerate()
            .map(|(radar, (m, d))| StepScan {
                radar,
                t_body_radar: *m,
                detections: d,
                sigma_velocity: 0.1,
                shift: Vec3::zeros(),
            })
            .collect()
    }

    /// Five radars recover a known twist within three of its own standard deviations on every axis,
    /// over many draws, and the standard deviations are of the size the spread says.
    #[test]
    fn five_radars_recover_a_known_twist() {
        let mounts = nuscenes_mounts();
        let truth = Vec3::new(14.0, 0.3, 0.25);
        let cfg = EgoMotionConfig::default();
        let mut rng = StdRng::seed_from_u64(3);
        let mut nees = 0.0;
        let draws = 200;
        const N_STATIC: usize = 15;
        for _ in 0..draws {
            let scans: Vec<Vec<Detection>> = mounts
                .iter()
                .map(|m| scan(m, truth, N_STATIC, 8, &mut rng))
                .collect();
            let info = doppler_information(&step(&mounts, &scans), None, 0.0, &cfg);
            assert_eq!(info.radars(), 5);
            let fit = info.solve(None).expect("observable");
            let e = fit.twist - truth;
            nees += (e.transpose() * fit.covariance.try_inverse().unwrap() * e)[0];
            for k in 0..3 {
                assert!(e[k].abs() < 5.0 * fit.covariance[(k, k)].sqrt(), "{e:?}");
            }
        }
        // Mean NEES of a consistent 3-dof estimate is 3; 200 draws put it within about +-0.5 (15
        // returns a radar: the residual spread alone would give 5.4).
        let mean = nees / draws as f64;
        assert!((2.4..3.8).contains(&mean), "mean NEES {mean}");
    }

    /// One radar alone does not see the yaw rate: refused by name. A gyro, or a car that does not
    /// slide sideways (the radar mounted ahead of the rear axle), makes it observable.
    #[test]
    fn one_radar_needs_a_gyro_or_the_lateral_constraint() {
        let mounts = &nuscenes_mounts()[..1];
        let truth = Vec3::new(14.0, 0.0, 0.1);
        let cfg = EgoMotionConfig::default();
        let mut rng = StdRng::seed_from_u64(4);
        let scans = vec![scan(&mounts[0], truth, 60, 0, &mut rng)];
        let alone = doppler_information(&step(mounts, &scans), None, 0.0, &cfg);
        assert!(matches!(
            alone.solve(None),
            Err(TwistRefusal::YawRateUnobservable { radars: 1, .. })
        ));
        let gyro = alone.solve(Some((0.1, 1e-6))).expect("with a gyro");
        assert!((gyro.twist - truth).norm() < 0.1, "{:?}", gyro.twist);
        let lateral = doppler_information(&step(mounts, &scans), None, 0.05, &cfg);
        let fit = lateral.solve(None).expect("with the lateral constraint");
        assert!((fit.twist.z - truth.z).abs() < 3.0 * fit.covariance[(2, 2)].sqrt());
        // Two radars at one place see no more than one.
        let same = [mounts[0], iso3_from_xyz_rpy(3.412, 0.0, 0.5, 0.0, 0.0, 1.2)];
        let scans2 = vec![scans[0].clone(), scan(&same[1], truth, 60, 0, &mut rng)];
        let both = doppler_information(&step(&same, &scans2), None, 0.0, &cfg);
        assert!(matches!(
            both.solve(None),
            Err(TwistRefusal::YawRateUnobservable { radars: 2, .. })
        ));
    }

    /// A scan whose view a bus fills (the static world a minority, the prior on the static world) and
    /// a scan with three returns: the first is fitted on the static world, the second refused by
    /// name, and the step stands on the rest.
    #[test]
    fn a_bad_scan_is_refused_and_the_others_carry_the_step() {
        let mounts = nuscenes_mounts();
        let truth = Vec3::new(10.0, 0.0, -0.2);
        let cfg = EgoMotionConfig::default();
        let mut rng = StdRng::seed_from_u64(5);
        let mut scans: Vec<Vec<Detection>> = mounts
            .iter()
            .map(|m| scan(m, truth, 30, 0, &mut rng))
            .collect();
        scans[0] = scan(&mounts[0], truth, 12, 40, &mut rng);
        scans[4].truncate(3);
        let prior = Some(truth + Vec3::new(0.5, 0.0, 0.0));
        let info = doppler_information(&step(&mounts, &scans), prior, 0.0, &cfg);
        assert!(matches!(
            info.scans[4].result,
            Err(ScanRefusal::TooFewStatic { have: 3, .. })
        ));
        assert_eq!(info.radars(), 4);
        let fit = info.solve(None).unwrap();
        assert!((fit.twist - truth).norm() < 0.15, "{:?}", fit.twist);
        let blind = doppler_information(&step(&mounts[..1], &scans[..1]), None, 0.0, &cfg);
        let Ok(n) = blind.scans[0].result else {
            panic!("fitted")
        };
        assert!(n >= 40, "without a prior the bus wins: {n} returns");
    }
}
