//! Ego-motion from Doppler, and moving-object rejection.
//!
//! A static target seen from a radar moving with velocity `v` (radar frame) has the radial velocity
//! `v_r = -d . v`, `d` the unit ray (radial velocity positive away from the radar). Static detections therefore fit one linear model
//! and moving ones do not.
//!
//! Entry points: [`fit_radar_velocity`] (one radar: 2D or 3D velocity, RANSAC + least squares),
//! [`fit_body_twist`] (several radars with different mountings: planar body twist `vx, vy, yaw rate`),
//! [`static_mask`] (which detections agree with a given velocity), [`EgoMotionConfig`].
//! Rays come from the measured positions; the Doppler range error moves a point along its ray, so it does
//! not change `d` and the fit needs no compensation first.

use crate::math::{Iso3, Mat3, Vec3};
use crate::radar::Detection;
use crate::validate::{Range, Validator};
use rand::SeedableRng;
use rand::rngs::StdRng;
use serde::{Deserialize, Serialize};

/// Settings of the Doppler ego-motion fit and of moving-object rejection.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct EgoMotionConfig {
    /// Drop detections whose radial velocity disagrees with the ego-motion from submaps (default true).
    pub reject_dynamic: bool,
    /// Largest |v_r + d . v| of a static detection, m/s (default 0.3: 3 sigma of the 0.1 m/s velocity noise).
    pub inlier_threshold: f64,
    /// Lower bound of the adaptive inlier threshold, m/s (default 0.03). After RANSAC the threshold
    /// shrinks to 3.5 robust sigmas of the residuals seen, within [this, `inlier_threshold`]; set it equal
    /// to `inlier_threshold` for a fixed threshold.
    pub min_inlier_threshold: f64,
    /// Fewest static detections for a fit to count (default 6).
    pub min_inliers: usize,
    /// Upper bound on RANSAC hypotheses (default 200; stops earlier once 99.9 % confident).
    pub max_iterations: usize,
    /// When an odometry velocity is given as prior, hypotheses farther than this from it are discarded, m/s
    /// (default 3.0). Protects against a large moving object outvoting the static world. The submap
    /// builder adds a second prior, the odometry's direction at the radar's previous Doppler speed,
    /// so that wheels that slip do not pull the fit off the static world; a fit farther than this
    /// from the odometry must lie within what hard braking sheds since that previous fit.
    pub prior_tolerance: f64,
    /// Seed of the RANSAC sampler; fits are deterministic (default 7).
    pub seed: u64,
}

impl Default for EgoMotionConfig {
    fn default() -> Self {
        EgoMotionConfig {
            reject_dynamic: true,
            inlier_threshold: 0.3,
            min_inlier_threshold: 0.03,
            min_inliers: 6,
            max_iterations: 200,
            prior_tolerance: 3.0,
            seed: 7,
        }
    }
}

impl EgoMotionConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.range("seed", self.seed as f64, Range::NON_NEGATIVE);
        v.positive("inlier_threshold", self.inlier_threshold);
        v.range(
            "min_inlier_threshold",
            self.min_inlier_threshold,
            Range::POSITIVE.up_to(self.inlier_threshold),
        );
        v.at_least("min_inliers", self.min_inliers, 3);
        v.at_least("max_iterations", self.max_iterations, 1);
        v.positive("prior_tolerance", self.prior_tolerance);
    }
}

/// Why no ego-motion could be fitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EgoMotionError {
    /// Fewer usable detections than the model needs.
    #[error("too few detections for an ego-motion fit: {have} (need {need})")]
    TooFewDetections {
        /// Usable detections.
        have: usize,
        /// Needed.
        need: usize,
    },
    /// No hypothesis gathered enough static detections.
    #[error("no consistent ego-motion: best consensus {best} detections (need {need})")]
    NoConsensus {
        /// Largest consensus found.
        best: usize,
        /// Needed.
        need: usize,
    },
    /// The rays do not constrain every unknown (e.g. all detections on one line of sight).
    #[error("ego-motion is unobservable from these detections")]
    Degenerate,
}

/// Which velocity components a single-radar fit estimates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum FitDims {
    /// x, y (z = 0): radars without elevation (ARS408: z is always 0).
    Planar,
    /// x, y, z: 4D radars with elevation.
    Full,
    /// Full when the detections' elevation angles span more than 5 degrees, else Planar.
    Auto,
}

/// A radar velocity fitted from radial velocities.
#[derive(Debug, Clone, PartialEq)]
pub struct VelocityFit {
    /// The radar's velocity in its own frame, m/s (z = 0 for a planar fit).
    pub v_radar: Vec3,
    /// Covariance of `v_radar` from the inliers' residual spread, (m/s)^2.
    pub covariance: Mat3,
    /// Covariance of `v_radar` per unit variance of a radial velocity, `(A^T A)^-1` over the static
    /// detections: scaled by a known noise variance it stays right where the residuals are all zero
    /// (a radar whose Doppler bins put every static return of a standing rig at exactly 0 m/s).
    pub unit_covariance: Mat3,
    /// Per detection (input order): true when static (consistent with `v_radar`).
    pub inliers: Vec<bool>,
    /// Number of static detections.
    pub num_inliers: usize,
    /// RMS radial-velocity residual of the static detections, m/s.
    pub rms: f64,
}

/// A planar body twist fitted from several radars.
#[derive(Debug, Clone, PartialEq)]
pub struct TwistFit {
    /// Body velocity (vx, vy), body frame, m/s.
    pub v_body: nalgebra::Vector2<f64>,
    /// Yaw rate, rad/s.
    pub yaw_rate: f64,
    /// Covariance of (vx, vy, yaw rate).
    pub covariance: Mat3,
    /// Per input scan, per detection: static.
    pub inliers: Vec<Vec<bool>>,
    /// Number of static detections over all scans.
    pub num_inliers: usize,
    /// RMS residual of the static detections, m/s.
    pub rms: f64,
}

/// Which detections are static under a radar velocity `v_radar` (radar frame): |v_r + d . v| <= threshold.
pub fn static_mask(dets: &[Detection], v_radar: &Vec3, threshold: f64) -> Vec<bool> {
    dets.iter()
        .map(|d| match unit_ray(d) {
            Some(ray) => (d.v_r + ray.dot(v_radar)).abs() <= threshold,
            None => false,
        })
        .collect()
}

fn unit_ray(d: &Detection) -> Option<Vec3> {
    let r = d.p_radar.norm();
    (r > 0.0 && r.is_finite() && d.v_r.is_finite()).then(|| d.p_radar / r)
}

/// A linear robust fit `b_i = a_i . x` with RANSAC over minimal sets, then least squares on the consensus.
/// Rows are the regressors `a_i` (length = unknowns), `b` the observations.
struct LinearRansac<'a> {
    rows: &'a [[f64; 3]],
    b: &'a [f64],
    unknowns: usize,
    threshold: f64,
    min_threshold: f64,
    /// Hypotheses farther than the tolerance from every one of these are discarded (none: all kept).
    priors: Vec<Vec3>,
    prior_tolerance: f64,
}

struct LinearFit {
    x: Vec3,
    covariance: Mat3,
    unit_covariance: Mat3,
    inliers: Vec<bool>,
    num_inliers: usize,
    rms: f64,
}

impl LinearRansac<'_> {
    fn residual(&self, i: usize, x: &Vec3) -> f64 {
        let a = &self.rows[i];
        self.b[i] - (0..self.unknowns).map(|k| a[k] * x[k]).sum::<f64>()
    }

    fn consensus(&self, x: &Vec3, threshold: f64) -> (usize, Vec<bool>) {
        let mask: Vec<bool> = (0..self.b.len())
            .map(|i| self.residual(i, x).abs() <= threshold)
            .collect();
        (mask.iter().filter(|m| **m).count(), mask)
    }

    /// Least squares on the rows in `mask`; `None` when the normal matrix is (near) singular.
    /// Unused unknowns (planar fits) are padded with an identity block and come back as zero.
    fn least_squares(&self, mask: &[bool]) -> Option<(Vec3, Mat3)> {
        self.solve_rows(mask.iter().enumerate().filter(|(_, m)| **m).map(|(i, _)| i))
    }

    fn solve_rows(&self, rows: impl Iterator<Item = usize>) -> Option<(Vec3, Mat3)> {
        let n = self.unknowns;
        let mut ata = Mat3::zeros();
        let mut atb = Vec3::zeros();
        for i in rows {
            // A planar fit leaves out the rows' z: an elevated ray's z would otherwise couple the
            // unused unknown into the two it solves.
            let mut a = Vec3::from(self.rows[i]);
            for k in n..3 {
                a[k] = 0.0;
            }
            ata += a * a.transpose();
            atb += a * self.b[i];
        }
        for k in n..3 {
            ata[(k, k)] = 1.0;
            atb[k] = 0.0;
        }
        // Reject near-singular systems relative to their own scale.
        let eig = ata.symmetric_eigenvalues();
        let (lo, hi) = (eig.min(), eig.max());
        if !(hi > 0.0 && lo > 1e-9 * hi) {
            return None;
        }
        let inv = ata.try_inverse()?;
        let mut x = inv * atb;
        let mut cov = inv;
        for k in n..3 {
            x[k] = 0.0;
            cov[(k, k)] = 0.0;
        }
        Some((x, cov))
    }

    fn minimal_solve(&self, idx: &[usize]) -> Option<Vec3> {
        self.solve_rows(idx.iter().copied()).map(|(x, _)| x)
    }

    fn run(&self, cfg: &EgoMotionConfig) -> Result<LinearFit, EgoMotionError> {
        use rand::RngExt;
        let n = self.b.len();
        let need = cfg.min_inliers.max(self.unknowns + 1);
        if n < need {
            return Err(EgoMotionError::TooFewDetections { have: n, need });
        }
        let mut rng = StdRng::seed_from_u64(cfg.seed);
        let mut best: Option<(usize, Vec3)> = None;
        let mut iterations = cfg.max_iterations;
        let mut it = 0;
        let mut sample = [0usize; 3];
        while it < iterations {
            it += 1;
            for k in 0..self.unknowns {
                loop {
                    let c = rng.random_range(0..n);
                    if !sample[..k].contains(&c) {
                        sample[k] = c;
                        break;
                    }
                }
            }
            let Some(x) = self.minimal_solve(&sample[..self.unknowns]) else {
                continue;
            };
            if !self.priors.is_empty()
                && self
                    .priors
                    .iter()
                    .all(|p| (x - p).norm() > self.prior_tolerance)
            {
                continue;
            }
            let (count, _) = self.consensus(&x, self.threshold);
            if best.is_none_or(|(c, _)| count > c) {
                best = Some((count, x));
                // Adaptive stop: 99.9 % confidence of one all-inlier minimal set.
                let w = (count as f64 / n as f64).powi(self.unknowns as i32);
                if w >= 1.0 - 1e-12 {
                    iterations = it;
                } else if w > 0.0 {
                    let k = ((1.0 - 0.999f64).ln() / (1.0 - w).ln()).ceil();
                    iterations = iterations.min((k as usize).max(it));
                }
            }
        }
        let best_count = best.map_or(0, |(c, _)| c);
        let Some((_, mut x)) = best else {
            return Err(EgoMotionError::Degenerate);
        };
        if best_count < need {
            return Err(EgoMotionError::NoConsensus {
                best: best_count,
                need,
            });
        }
        // Refine: least squares on the consensus, then re-select with a threshold adapted to the noise
        // actually seen (3.5 robust sigmas from the median absolute residual, between `min_threshold` and
        // the configured threshold): a radar with 0.01 m/s Doppler noise should not let slow walkers in.
        let mut cov = Mat3::zeros();
        let mut threshold = self.threshold;
        let (mut count, mut mask) = self.consensus(&x, threshold);
        for _ in 0..6 {
            let Some((xr, c)) = self.least_squares(&mask) else {
                return Err(EgoMotionError::Degenerate);
            };
            x = xr;
            cov = c;
            if self.min_threshold < self.threshold {
                let mut abs: Vec<f64> = (0..n)
                    .filter(|&i| mask[i])
                    .map(|i| self.residual(i, &x).abs())
                    .collect();
                abs.sort_by(f64::total_cmp);
                let sigma = 1.4826 * abs.get(abs.len() / 2).copied().unwrap_or(self.threshold);
                threshold = (3.5 * sigma).clamp(self.min_threshold, self.threshold);
            }
            let (c2, m2) = self.consensus(&x, threshold);
            if m2 == mask {
                break;
            }
            count = c2;
            mask = m2;
        }
        if count < need {
            return Err(EgoMotionError::NoConsensus { best: count, need });
        }
        let ss: f64 = (0..n)
            .filter(|&i| mask[i])
            .map(|i| self.residual(i, &x).powi(2))
            .sum();
        let dof = (count - self.unknowns).max(1) as f64;
        let sigma2 = ss / dof;
        Ok(LinearFit {
            x,
            covariance: cov * sigma2,
            unit_covariance: cov,
            inliers: mask,
            num_inliers: count,
            rms: (ss / count as f64).sqrt(),
        })
    }
}

/// Fits one radar's velocity (radar frame) to its detections' radial velocities: RANSAC over minimal
/// sets, then least squares on the static consensus. `priors` (radar frame, e.g. from odometry)
/// discard hypotheses farther than `cfg.prior_tolerance` from all of them; none keeps every one.
pub fn fit_radar_velocity(
    dets: &[Detection],
    dims: FitDims,
    priors: &[Vec3],
    cfg: &EgoMotionConfig,
) -> Result<VelocityFit, EgoMotionError> {
    let usable: Vec<(usize, Vec3)> = dets
        .iter()
        .enumerate()
        .filter_map(|(i, d)| unit_ray(d).map(|r| (i, r)))
        .collect();
    let full = match dims {
        FitDims::Planar => false,
        FitDims::Full => true,
        FitDims::Auto => {
            let (lo, hi) = usable
                .iter()
                .fold((f64::MAX, f64::MIN), |(lo, hi), (_, r)| {
                    let e = r.z.asin();
                    (lo.min(e), hi.max(e))
                });
            hi - lo > 5f64.to_radians()
        }
    };
    // v_r = -d . v  =>  b = v_r, a = -d.
    let rows: Vec<[f64; 3]> = usable.iter().map(|(_, r)| [-r.x, -r.y, -r.z]).collect();
    let b: Vec<f64> = usable.iter().map(|(i, _)| dets[*i].v_r).collect();
    let solver = LinearRansac {
        rows: &rows,
        b: &b,
        unknowns: if full { 3 } else { 2 },
        threshold: cfg.inlier_threshold,
        min_threshold: cfg.min_inlier_threshold,
        priors: priors
            .iter()
            .map(|p| if full { *p } else { Vec3::new(p.x, p.y, 0.0) })
            .collect(),
        prior_tolerance: cfg.prior_tolerance,
    };
    let fit = solver.run(cfg)?;
    let mut inliers = vec![false; dets.len()];
    for ((i, _), m) in usable.iter().zip(&fit.inliers) {
        inliers[*i] = *m;
    }
    Ok(VelocityFit {
        v_radar: fit.x,
        covariance: fit.covariance,
        unit_covariance: fit.unit_covariance,
        inliers,
        num_inliers: fit.num_inliers,
        rms: fit.rms,
    })
}

/// Fits the planar body twist (vx, vy, yaw rate) to the radial velocities of several radars, each given
/// with its pose in the body frame. Needs radars with different mountings for the yaw rate to be
/// observable (one radar only sees its own 2D velocity).
///
/// The radar at `t` in the body frame moves with `v_b + w z x t = (vx - w t_y, vy + w t_x)`, so a static
/// detection with body-frame ray `d` has `v_r = -(d_x vx + d_y vy + w (d_y t_x - d_x t_y))`.
pub fn fit_body_twist(
    scans: &[(Iso3, &[Detection])],
    prior: Option<Vec3>,
    cfg: &EgoMotionConfig,
) -> Result<TwistFit, EgoMotionError> {
    let mut rows = Vec::new();
    let mut b = Vec::new();
    let mut owner = Vec::new();
    for (s, (t_body_radar, dets)) in scans.iter().enumerate() {
        let rot = t_body_radar.rotation;
        let t = t_body_radar.translation.vector;
        for (i, d) in dets.iter().enumerate() {
            if let Some(ray) = unit_ray(d) {
                let db = rot * ray;
                rows.push([-db.x, -db.y, -(db.y * t.x - db.x * t.y)]);
                b.push(d.v_r);
                owner.push((s, i));
            }
        }
    }
    let solver = LinearRansac {
        rows: &rows,
        b: &b,
        unknowns: 3,
        threshold: cfg.inlier_threshold,
        min_threshold: cfg.min_inlier_threshold,
        priors: prior.into_iter().collect(),
        prior_tolerance: cfg.prior_tolerance,
    };
    let fit = solver.run(cfg)?;
    let mut inliers: Vec<Vec<bool>> = scans.iter().map(|(_, d)| vec![false; d.len()]).collect();
    for (&(s, i), &m) in owner.iter().zip(&fit.inliers) {
        inliers[s][i] = m;
    }
    Ok(TwistFit {
        v_body: nalgebra::Vector2::new(fit.x.x, fit.x.y),
        yaw_rate: fit.x.z,
        covariance: fit.covariance,
        inliers,
        num_inliers: fit.num_inliers,
        rms: fit.rms,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::iso3_from_xyz_rpy;
    use approx::assert_relative_eq;
    use rand::RngExt;
    use rand_distr::{Distribution, Normal};

    /// Static detections seen by a radar moving at `v_radar`, plus movers with their own velocity.
    fn scene(
        v_radar: Vec3,
        n_static: usize,
        movers: &[(Vec3, usize)],
        seed: u64,
        elevation: bool,
    ) -> Vec<Detection> {
        let mut rng = StdRng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 0.1).unwrap();
        let mut out = Vec::new();
        let mut push = |rng: &mut StdRng, v_target: Vec3| {
            let phi: f64 = rng.random_range(-1.3..1.3);
            let el: f64 = if elevation {
                rng.random_range(-0.25..0.25)
            } else {
                0.0
            };
            let r: f64 = rng.random_range(3.0..90.0);
            let d = Vec3::new(phi.cos() * el.cos(), phi.sin() * el.cos(), el.sin());
            let v_r = d.dot(&(v_target - v_radar)) + noise.sample(rng);
            out.push(Detection {
                p_radar: d * r,
                v_r,
                rcs: None,
            });
        };
        for _ in 0..n_static {
            push(&mut rng, Vec3::zeros());
        }
        for (v, k) in movers {
            for _ in 0..*k {
                push(&mut rng, *v);
            }
        }
        out
    }

    #[test]
    fn planar_fit_recovers_velocity_and_flags_movers() {
        let v = Vec3::new(19.5, -0.8, 0.0);
        let movers = [
            (Vec3::new(-15.0, 0.5, 0.0), 15),
            (Vec3::new(3.0, 8.0, 0.0), 10),
        ];
        let dets = scene(v, 60, &movers, 1, false);
        let fit =
            fit_radar_velocity(&dets, FitDims::Auto, &[], &EgoMotionConfig::default()).unwrap();
        assert_relative_eq!(fit.v_radar, v, epsilon = 0.06);
        assert_eq!(fit.v_radar.z, 0.0);
        // Movers are rejected (their radial velocity differs by metres per second).
        assert!(
            fit.inliers[60..].iter().all(|m| !m),
            "a mover was called static"
        );
        assert!(
            fit.num_inliers >= 55,
            "static detections lost: {}",
            fit.num_inliers
        );
        // The reported covariance is of the right size: ~ sigma_v^2 / n per axis.
        assert!(fit.covariance[(0, 0)].sqrt() < 0.05 && fit.covariance[(0, 0)] > 0.0);
        assert_relative_eq!(fit.rms, 0.1, epsilon = 0.04);
    }

    #[test]
    fn full_fit_with_elevation() {
        let v = Vec3::new(2.9, -0.5, -0.08);
        let dets = scene(v, 300, &[(Vec3::new(10.0, 0.0, 0.0), 30)], 2, true);
        let fit =
            fit_radar_velocity(&dets, FitDims::Auto, &[], &EgoMotionConfig::default()).unwrap();
        // Each axis within 3 sigma of its own reported uncertainty (z is weakly observed: +-14 deg rays).
        for k in 0..3 {
            let sigma = fit.covariance[(k, k)].sqrt();
            assert!(sigma < 0.06, "axis {k}: sigma {sigma}");
            assert!(
                (fit.v_radar[k] - v[k]).abs() < 3.0 * sigma,
                "axis {k}: {:?} vs {v:?}",
                fit.v_radar
            );
        }
    }

    /// A planar fit of rays up to 14 degrees above and below the boresight, the radar moving level,
    /// recovers its velocity and keeps the static detections: the rays' z must not enter it.
    #[test]
    fn planar_fit_of_elevated_rays() {
        let v = Vec3::new(20.0, -0.6, 0.0);
        let dets = scene(v, 300, &[(Vec3::new(-10.0, 0.0, 0.0), 30)], 5, true);
        let fit =
            fit_radar_velocity(&dets, FitDims::Planar, &[], &EgoMotionConfig::default()).unwrap();
        assert_relative_eq!(fit.v_radar, v, epsilon = 0.05);
        assert!(fit.num_inliers >= 290, "{} inliers", fit.num_inliers);
    }

    #[test]
    fn prior_keeps_a_large_mover_from_winning() {
        // A truck fills most of the scan; the static world is the minority.
        let v = Vec3::new(10.0, 0.0, 0.0);
        let dets = scene(v, 20, &[(Vec3::new(9.0, 0.0, 0.0), 60)], 3, false);
        let cfg = EgoMotionConfig::default();
        let blind = fit_radar_velocity(&dets, FitDims::Planar, &[], &cfg).unwrap();
        assert!(
            (blind.v_radar - v).norm() > 0.5,
            "without a prior the majority (the truck) wins"
        );
        let fit =
            fit_radar_velocity(&dets, FitDims::Planar, &[Vec3::new(10.8, 0.3, 0.0)], &cfg).unwrap();
        assert_relative_eq!(fit.v_radar, v, epsilon = 0.1);
    }

    #[test]
    fn too_few_and_degenerate() {
        let cfg = EgoMotionConfig::default();
        let dets = scene(Vec3::new(5.0, 0.0, 0.0), 3, &[], 4, false);
        assert!(matches!(
            fit_radar_velocity(&dets, FitDims::Planar, &[], &cfg),
            Err(EgoMotionError::TooFewDetections { .. })
        ));
        // All on one line of sight: lateral velocity unobservable.
        let one_ray: Vec<Detection> = (1..20)
            .map(|i| Detection {
                p_radar: Vec3::new(i as f64, 0.0, 0.0),
                v_r: -5.0,
                rcs: None,
            })
            .collect();
        assert!(fit_radar_velocity(&one_ray, FitDims::Planar, &[], &cfg).is_err());
        assert!(fit_radar_velocity(&[], FitDims::Auto, &[], &cfg).is_err());
    }

    /// Five radars with the nuScenes mountings: the twist, including yaw rate, comes back.
    #[test]
    fn twist_from_five_radars() {
        let mounts = [
            iso3_from_xyz_rpy(3.412, 0.0, 0.5, 0.0, 0.0, 0.2f64.to_radians()),
            iso3_from_xyz_rpy(2.422, 0.8, 0.78, 0.0, 0.0, 88.36f64.to_radians()),
            iso3_from_xyz_rpy(2.422, -0.8, 0.77, 0.0, 0.0, -90.98f64.to_radians()),
            iso3_from_xyz_rpy(-0.562, 0.628, 0.53, 0.0, 0.0, 174.41f64.to_radians()),
            iso3_from_xyz_rpy(-0.562, -0.618, 0.53, 0.0, 0.0, -176.11f64.to_radians()),
        ];
        let (vx, vy, w) = (11.0, 0.3, 0.25);
        let scans: Vec<(Iso3, Vec<Detection>)> = mounts
            .iter()
            .enumerate()
            .map(|(k, m)| {
                let t = m.translation.vector;
                let v_body_at_radar = Vec3::new(vx - w * t.y, vy + w * t.x, 0.0);
                let v_radar = m.rotation.inverse() * v_body_at_radar;
                (
                    *m,
                    scene(
                        v_radar,
                        40,
                        &[(Vec3::new(-5.0, 2.0, 0.0), 6)],
                        10 + k as u64,
                        false,
                    ),
                )
            })
            .collect();
        let input: Vec<(Iso3, &[Detection])> =
            scans.iter().map(|(m, d)| (*m, d.as_slice())).collect();
        let fit = fit_body_twist(&input, None, &EgoMotionConfig::default()).unwrap();
        assert_relative_eq!(fit.v_body.x, vx, epsilon = 0.05);
        assert_relative_eq!(fit.v_body.y, vy, epsilon = 0.05);
        assert_relative_eq!(fit.yaw_rate, w, epsilon = 0.02);
        for (s, (_, d)) in scans.iter().enumerate() {
            assert!(fit.inliers[s][40..d.len()].iter().all(|m| !m));
        }
        // One radar alone cannot see the yaw rate.
        assert!(fit_body_twist(&input[..1], None, &EgoMotionConfig::default()).is_err());
    }
}
