//! Uncertainty-aware refinement (paper eq. 10) by Levenberg-Marquardt on SE(2), and the covariance of
//! the result.
//!
//! [`refine`] runs LM on eq. 10 with a robust loss from an initial guess on given correspondences,
//! each pair weighted by its combined point covariance, or isotropically when the uncertainty is off.
//! The step is on the right, `T <- T * Exp(delta)` in the source (query) body frame, and the returned
//! covariance is over that `delta` (GTSAM's `Pose2` convention). docs/algorithm.md, "Registration"
//! (step 4) and "Levenberg-Marquardt", has the problem, its weights and its derivatives.
//!
//! Entry points: [`LmConfig`], [`refine`], [`LmResult`], [`CovarianceMode`]; [`pair_terms`] (one
//! residual's cost, gradient and Gauss-Newton block, public so that tests can check it against finite
//! differences).

use crate::math::{Iso2, Mat2, Mat3, Vec2, Vec3, se2_exp};
use crate::registration::robust::RobustLoss;
use crate::registration::types::{PointSet2, RegistrationError};
use crate::validate::Validator;
use serde::{Deserialize, Serialize};

/// How the covariance of the estimate is computed at the optimum. The empirical sandwich (the default)
/// stays consistent (mean NEES near 3 with known correspondences) whatever the loss and the weights;
/// the information form only with least squares and the true point covariances
/// (`covariance_is_consistent` in tests/registration.rs checks the default).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum CovarianceMode {
    /// Inverse of the robust-weighted Gauss-Newton information `sum rho'_i J_i^T W_i J_i`. Trusts the
    /// point covariances; with a robust loss it overstates the uncertainty a little on clean data.
    Information,
    /// Model-based sandwich: `kappa (sum J_i^T W_i J_i)^-1`, with `kappa` the asymptotic variance
    /// factor of the robust M-estimator when the whitened residuals are standard normal (Huber 1981).
    /// Trusts the point covariances.
    Expected,
    /// Empirical sandwich (Huber-White) `A^-1 B A^-1` with `A` the robust Hessian and
    /// `B = sum rho'^2 g_i g_i^T` from the actual residuals, scaled by `n / (n - 3)`. Honest even when
    /// the point covariances are mis-scaled (e.g. the isotropic "no U.E." weights); noisier when
    /// there are few correspondences.
    Sandwich,
}

/// Levenberg-Marquardt settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct LmConfig {
    /// Weight residuals by the point covariances (eq. 10); `false` gives the isotropic "no U.E."
    /// ablation (default true).
    pub use_uncertainty: bool,
    /// Standard deviation of each residual component when `use_uncertainty` is false, m
    /// (default 0.5). Scales the isotropic weights so that `robust.scale` keeps its meaning in sigma.
    pub isotropic_sigma: f64,
    /// Robust loss on the squared normalised residual (default Cauchy, scale 3.0).
    pub robust: RobustLoss,
    /// Iteration limit (default 50).
    pub max_iterations: usize,
    /// Converged when a step is shorter than this (norm of `(dx, dy, dtheta)` in m and rad; default 1e-7).
    pub step_tolerance: f64,
    /// Converged when an accepted step lowers the cost by less than this fraction (default 1e-10).
    pub cost_tolerance: f64,
    /// Initial damping relative to the diagonal of the normal matrix (default 1e-4).
    pub initial_lambda: f64,
    /// Covariance estimator (default `sandwich`; see [`CovarianceMode`] and the consistency test).
    pub covariance: CovarianceMode,
}

impl Default for LmConfig {
    fn default() -> Self {
        LmConfig {
            use_uncertainty: true,
            isotropic_sigma: 0.5,
            robust: RobustLoss::default(),
            max_iterations: 50,
            step_tolerance: 1e-7,
            cost_tolerance: 1e-10,
            initial_lambda: 1e-4,
            covariance: CovarianceMode::Sandwich,
        }
    }
}

impl LmConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.positive("isotropic_sigma", self.isotropic_sigma);
        v.positive("step_tolerance", self.step_tolerance);
        v.positive("cost_tolerance", self.cost_tolerance);
        v.positive("initial_lambda", self.initial_lambda);
        v.at_least("max_iterations", self.max_iterations, 1);
        v.section("robust", |v| self.robust.check(v));
    }
}

/// What [`refine`] returns.
#[derive(Debug, Clone, PartialEq)]
pub struct LmResult {
    /// Source frame in the target frame.
    pub t_target_source: Iso2,
    /// Covariance over `delta = (x, y, theta)` with `T_true = T_est * Exp(delta)` (m^2, m rad, rad^2).
    pub covariance: Mat3,
    /// Robust-weighted Gauss-Newton information `sum rho' J^T W J` at the optimum.
    pub information: Mat3,
    /// Final cost `1/2 sum rho(s_i)`.
    pub cost: f64,
    /// Iterations (linearisations) used.
    pub iterations: usize,
    /// A tolerance was met before the iteration limit.
    pub converged: bool,
}

/// `[0 -1; 1 0] v`: the generator of planar rotation applied to `v`.
#[inline]
fn perp(v: &Vec2) -> Vec2 {
    Vec2::new(-v.y, v.x)
}

/// One residual's contribution, for a pose `t` and a matched pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairTerms {
    /// Squared normalised residual `s = d^T W d`.
    pub s: f64,
    /// `1/2 rho(s)`.
    pub cost: f64,
    /// Exact gradient of `1/2 rho(s)` w.r.t. the right perturbation `delta`, through the weight too.
    pub gradient: Vec3,
    /// Gauss-Newton block `rho'(s) J^T W J` (weight derivative left out; docs/algorithm.md, "Levenberg-Marquardt").
    pub hessian_gn: Mat3,
    /// `J^T W d`, with `J = d(d)/d(delta) = -R [I | perp(x)]`; the score of this pair before `rho'`.
    pub jtwd: Vec3,
    /// `J^T W J`.
    pub jtwj: Mat3,
    /// `rho'(s)`.
    pub drho: f64,
    /// `rho''(s)`.
    pub ddrho: f64,
}

/// Cost, exact gradient and Gauss-Newton block of one residual `d = y - T x` (eq. 10).
///
/// `cov` = `Some((Sigma_x, Sigma_y))` weights by `(Sigma_y + R Sigma_x R^T)^-1`; `None` by
/// `I / iso_var`. Returns `None` when the combined covariance is not positive definite.
#[inline(always)]
pub fn pair_terms(
    t: &Iso2,
    x: &Vec2,
    y: &Vec2,
    cov: Option<(&Mat2, &Mat2)>,
    iso_var: f64,
    robust: &RobustLoss,
) -> Option<PairTerms> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let d = y - (r * x + t.translation.vector);
    // J = d(d)/d(delta) = -R [I | perp(x)] (2x3)
    let rp = r * perp(x);
    let (w, c_theta) = match cov {
        Some((sx, sy)) => {
            let c = sy + r * sx * r.transpose();
            let w = inverse_spd2(&c)?;
            // d/dtheta of R Rot(theta) Sx Rot(theta)^T R^T at 0, with G = [0 -1; 1 0]: R (G Sx - Sx G) R^T
            let g = Mat2::new(0.0, -1.0, 1.0, 0.0);
            let c_th = r * (g * sx - sx * g) * r.transpose();
            (w, Some(c_th))
        }
        None => (Mat2::identity() / iso_var, None),
    };
    let wd = w * d;
    let s = d.dot(&wd);
    let (rho, drho, ddrho) = robust.rho(s);
    // J^T W d and J^T W J with J = -[R | R perp(x)]
    let jtwd = -Vec3::new(
        r[(0, 0)] * wd.x + r[(1, 0)] * wd.y,
        r[(0, 1)] * wd.x + r[(1, 1)] * wd.y,
        rp.dot(&wd),
    );
    let rt_w_r = r.transpose() * w * r;
    let rt_w_rp = r.transpose() * (w * rp);
    let rp_w_rp = rp.dot(&(w * rp));
    let jtwj = Mat3::new(
        rt_w_r[(0, 0)],
        rt_w_r[(0, 1)],
        rt_w_rp.x,
        rt_w_r[(1, 0)],
        rt_w_r[(1, 1)],
        rt_w_rp.y,
        rt_w_rp.x,
        rt_w_rp.y,
        rp_w_rp,
    );
    // ds/ddelta = 2 J^T W d + e_theta d^T (dW/dtheta) d, dW/dtheta = -W C_theta W.
    let mut ds = 2.0 * jtwd;
    if let Some(c_th) = c_theta {
        ds[2] -= wd.dot(&(c_th * wd));
    }
    Some(PairTerms {
        s,
        cost: 0.5 * rho,
        gradient: 0.5 * drho * ds,
        hessian_gn: drho * jtwj,
        jtwd,
        jtwj,
        drho,
        ddrho,
    })
}

/// Inverse of a symmetric 2x2 matrix that must be positive definite (finite, det > 0, trace > 0).
#[inline]
fn inverse_spd2(c: &Mat2) -> Option<Mat2> {
    let det = c[(0, 0)] * c[(1, 1)] - c[(0, 1)] * c[(1, 0)];
    let tr = c[(0, 0)] + c[(1, 1)];
    if !(det.is_finite() && det > 1e-300 && tr > 0.0) {
        return None;
    }
    Some(Mat2::new(c[(1, 1)], -c[(0, 1)], -c[(1, 0)], c[(0, 0)]) / det)
}

struct Totals {
    cost: f64,
    gradient: Vec3,
    hessian: Mat3,
}

/// With `COST` false the cost is left at 0 and not computed (a Gauss-Newton step needs only the
/// gradient and the Hessian; Cauchy's cost is a logarithm per pair).
fn totals<const COST: bool>(
    t: &Iso2,
    source: &PointSet2,
    target: &PointSet2,
    pairs: &[(usize, usize)],
    cfg: &LmConfig,
) -> Result<Totals, RegistrationError> {
    let iso_var = cfg.isotropic_sigma * cfg.isotropic_sigma;
    let mut out = Totals {
        cost: 0.0,
        gradient: Vec3::zeros(),
        hessian: Mat3::zeros(),
    };
    for &(i, j) in pairs {
        let cov = cfg
            .use_uncertainty
            .then(|| (&source.covs[i], &target.covs[j]));
        let p = pair_terms(
            t,
            &source.points[i],
            &target.points[j],
            cov,
            iso_var,
            &cfg.robust,
        )
        .ok_or_else(|| {
            RegistrationError::Numerical(format!(
                "point covariance of pair (source {i}, target {j}) is not positive definite"
            ))
        })?;
        if COST {
            out.cost += p.cost;
        }
        out.gradient += p.gradient;
        out.hessian += p.hessian_gn;
    }
    Ok(out)
}

/// Levenberg-Marquardt on eq. 10 from `initial` over the pairs `(source index, target index)`.
///
/// Errors: fewer than 2 pairs, an index out of range or a covariance that is not positive definite,
/// or an information matrix that is singular at the optimum (e.g. all source points identical:
/// the rotation is unobservable) - never a covariance that claims more than the data hold.
pub fn refine(
    source: &PointSet2,
    target: &PointSet2,
    pairs: &[(usize, usize)],
    initial: &Iso2,
    cfg: &LmConfig,
) -> Result<LmResult, RegistrationError> {
    let p = refine_pose(source, target, pairs, initial, cfg)?;
    let covariance = covariance_at(&p.t_target_source, source, target, pairs, cfg)?;
    Ok(LmResult {
        t_target_source: p.t_target_source,
        covariance,
        information: p.information,
        cost: p.cost,
        iterations: p.iterations,
        converged: p.converged,
    })
}

/// What [`refine_pose`] returns: [`LmResult`] without the covariance.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LmPose {
    pub(crate) t_target_source: Iso2,
    pub(crate) information: Mat3,
    pub(crate) cost: f64,
    pub(crate) iterations: usize,
    pub(crate) converged: bool,
}

/// [`totals`] after checking that there are at least 2 pairs and that their indices are in range.
fn checked_totals<const COST: bool>(
    t: &Iso2,
    source: &PointSet2,
    target: &PointSet2,
    pairs: &[(usize, usize)],
    cfg: &LmConfig,
) -> Result<Totals, RegistrationError> {
    if pairs.len() < 2 {
        return Err(RegistrationError::TooFewInliers {
            have: pairs.len(),
            need: 2,
        });
    }
    check_sets(source, target, pairs)?;
    totals::<COST>(t, source, target, pairs, cfg)
}

/// One Gauss-Newton step of eq. 10 from `t` over `pairs` (the robust-weighted normal equations,
/// a trace of damping for safety), taken without checking the cost: what an ICP round needs when
/// its pairs will change before the next step anyway. The cost is not evaluated (`cost` is NaN).
pub(crate) fn gauss_newton_step(
    source: &PointSet2,
    target: &PointSet2,
    pairs: &[(usize, usize)],
    t: &Iso2,
    cfg: &LmConfig,
) -> Result<LmPose, RegistrationError> {
    let cur = checked_totals::<false>(t, source, target, pairs, cfg)?;
    let mut a = cur.hessian;
    for k in 0..3 {
        a[(k, k)] += 1e-9 * cur.hessian[(k, k)].max(1e-12);
    }
    let delta = a
        .cholesky()
        .map(|c| -c.solve(&cur.gradient))
        .filter(|d| d.iter().all(|v| v.is_finite()))
        .ok_or_else(|| RegistrationError::Numerical("singular Gauss-Newton step".into()))?;
    Ok(LmPose {
        t_target_source: t * se2_exp(&delta),
        information: cur.hessian,
        cost: f64::NAN,
        iterations: 1,
        converged: delta.norm() < cfg.step_tolerance,
    })
}

/// The LM iterations of [`refine`] without the covariance (for intermediate solves).
pub(crate) fn refine_pose(
    source: &PointSet2,
    target: &PointSet2,
    pairs: &[(usize, usize)],
    initial: &Iso2,
    cfg: &LmConfig,
) -> Result<LmPose, RegistrationError> {
    let mut t = *initial;
    let mut cur = checked_totals::<true>(&t, source, target, pairs, cfg)?;
    let mut lambda = cfg.initial_lambda;
    let mut converged = false;
    let mut iterations = 0;
    while iterations < cfg.max_iterations {
        iterations += 1;
        let mut stepped = false;
        // Inner loop: raise the damping until a step lowers the cost.
        for _ in 0..30 {
            let mut a = cur.hessian;
            for k in 0..3 {
                a[(k, k)] += lambda * cur.hessian[(k, k)].max(1e-12);
            }
            let Some(delta) = a.cholesky().map(|c| -c.solve(&cur.gradient)) else {
                lambda *= 10.0;
                continue;
            };
            if !delta.iter().all(|v| v.is_finite()) {
                return Err(RegistrationError::Numerical("non-finite LM step".into()));
            }
            let t_new = t * se2_exp(&delta);
            let new = totals::<true>(&t_new, source, target, pairs, cfg)?;
            if new.cost <= cur.cost {
                let small_step = delta.norm() < cfg.step_tolerance;
                let small_gain = cur.cost - new.cost <= cfg.cost_tolerance * cur.cost.max(1e-300);
                t = t_new;
                cur = new;
                lambda = (lambda * 0.1).max(1e-12);
                stepped = true;
                converged = small_step || small_gain;
                break;
            }
            if delta.norm() < cfg.step_tolerance {
                // The step is too small to change the cost: we are at the minimum.
                converged = true;
                break;
            }
            lambda *= 10.0;
        }
        if converged || !stepped {
            break;
        }
    }
    Ok(LmPose {
        t_target_source: t,
        information: cur.hessian,
        cost: cur.cost,
        iterations,
        converged,
    })
}

fn check_sets(
    source: &PointSet2,
    target: &PointSet2,
    pairs: &[(usize, usize)],
) -> Result<(), RegistrationError> {
    if source.covs.len() != source.points.len() || target.covs.len() != target.points.len() {
        return Err(RegistrationError::Numerical(
            "point set has a different number of covariances than points".into(),
        ));
    }
    for &(i, j) in pairs {
        if i >= source.len() || j >= target.len() {
            return Err(RegistrationError::Numerical(format!(
                "correspondence ({i}, {j}) out of range ({} source, {} target points)",
                source.len(),
                target.len()
            )));
        }
    }
    Ok(())
}

/// Inverse of a 3x3 information matrix, refused when it is not well conditioned.
fn checked_inverse(m: &Mat3, what: &str) -> Result<Mat3, RegistrationError> {
    let sym = (m + m.transpose()) * 0.5;
    let eig = sym.symmetric_eigenvalues();
    let (lo, hi) = (eig.min(), eig.max());
    if !(lo.is_finite() && hi.is_finite() && hi > 0.0 && lo > 1e-10 * hi) {
        return Err(RegistrationError::Numerical(format!(
            "{what} is singular (eigenvalues {lo:.3e} .. {hi:.3e}): the pose is not observable"
        )));
    }
    sym.try_inverse()
        .map(|i| (i + i.transpose()) * 0.5)
        .ok_or_else(|| RegistrationError::Numerical(format!("{what} is not invertible")))
}

/// Calls `f(k, terms)` with the terms of every pair `pairs[k]` at `t` (eq. 10 weights when
/// `cfg.use_uncertainty`, else isotropic); indices must have been checked.
fn for_each_pair_terms(
    t: &Iso2,
    source: &PointSet2,
    target: &PointSet2,
    pairs: &[(usize, usize)],
    cfg: &LmConfig,
    mut f: impl FnMut(usize, &PairTerms),
) -> Result<(), RegistrationError> {
    let iso_var = cfg.isotropic_sigma * cfg.isotropic_sigma;
    for (k, &(i, j)) in pairs.iter().enumerate() {
        let cov = cfg
            .use_uncertainty
            .then(|| (&source.covs[i], &target.covs[j]));
        let p = pair_terms(
            t,
            &source.points[i],
            &target.points[j],
            cov,
            iso_var,
            &cfg.robust,
        )
        .ok_or_else(|| RegistrationError::Numerical("covariance not positive definite".into()))?;
        f(k, &p);
    }
    Ok(())
}

/// Hessian of `1/2 rho(s)` of one pair in the Gauss-Newton sense, with the `rho''` curvature
/// (Triggs et al. 2000): the `A` of the sandwich.
fn robust_hessian(p: &PairTerms) -> Mat3 {
    p.hessian_gn + 2.0 * p.ddrho * p.jtwd * p.jtwd.transpose()
}

/// The covariance of the estimate at `t` (see [`CovarianceMode`]).
pub fn covariance_at(
    t: &Iso2,
    source: &PointSet2,
    target: &PointSet2,
    pairs: &[(usize, usize)],
    cfg: &LmConfig,
) -> Result<Mat3, RegistrationError> {
    check_sets(source, target, pairs)?;
    let mut info_robust = Mat3::zeros();
    let mut info_plain = Mat3::zeros();
    let mut a = Mat3::zeros();
    let mut b = Mat3::zeros();
    for_each_pair_terms(t, source, target, pairs, cfg, |_, p| {
        info_robust += p.hessian_gn;
        info_plain += p.jtwj;
        a += robust_hessian(p);
        b += (p.drho * p.drho) * p.jtwd * p.jtwd.transpose();
    })?;
    match cfg.covariance {
        CovarianceMode::Information => checked_inverse(&info_robust, "information matrix"),
        CovarianceMode::Expected => Ok(robust_variance_factor(&cfg.robust)
            * checked_inverse(&info_plain, "information matrix")?),
        CovarianceMode::Sandwich => {
            let n = pairs.len() as f64;
            if n <= 3.0 {
                return Err(RegistrationError::TooFewInliers {
                    have: pairs.len(),
                    need: 4,
                });
            }
            // A can lose definiteness when many residuals sit on the descending part of Cauchy:
            // fall back to the Gauss-Newton part, which is PSD.
            let a_inv = checked_inverse(&a, "robust Hessian")
                .or_else(|_| checked_inverse(&info_robust, "information matrix"))?;
            // B must be well conditioned too, otherwise the sandwich claims certainty the data lack.
            checked_inverse(&b, "score covariance")?;
            let c = a_inv * b * a_inv * (n / (n - 3.0));
            Ok((c + c.transpose()) * 0.5)
        }
    }
}

/// Cluster-robust sandwich covariance (Liang and Zeger 1986) of the estimate at `t`: `A^-1 B A^-1`
/// with `A` the robust Hessian and `B = sum_c g_c g_c^T`, `g_c` the summed scores of the pairs of
/// cluster `c`, scaled by `G / (G - 1)` for `G` clusters. Pairs whose errors are correlated (nearest
/// neighbours that share target points or smoothed neighbourhoods, a facade sampled at other places
/// by the two passes) belong to one cluster, so their common error counts once instead of as
/// independent evidence. `clusters[k]` is the cluster of `pairs[k]` (any labels).
pub fn covariance_clustered(
    t: &Iso2,
    source: &PointSet2,
    target: &PointSet2,
    pairs: &[(usize, usize)],
    clusters: &[u64],
    cfg: &LmConfig,
) -> Result<Mat3, RegistrationError> {
    check_sets(source, target, pairs)?;
    if clusters.len() != pairs.len() {
        return Err(RegistrationError::Numerical(format!(
            "{} cluster labels for {} pairs",
            clusters.len(),
            pairs.len()
        )));
    }
    let mut info_robust = Mat3::zeros();
    let mut a = Mat3::zeros();
    let mut scores: Vec<(u64, Vec3)> = Vec::with_capacity(pairs.len());
    for_each_pair_terms(t, source, target, pairs, cfg, |k, p| {
        info_robust += p.hessian_gn;
        a += robust_hessian(p);
        scores.push((clusters[k], p.drho * p.jtwd));
    })?;
    scores.sort_unstable_by_key(|e| e.0);
    let mut b = Mat3::zeros();
    let mut groups = 0usize;
    for chunk in scores.chunk_by(|x, y| x.0 == y.0) {
        let g: Vec3 = chunk.iter().map(|e| e.1).sum();
        b += g * g.transpose();
        groups += 1;
    }
    if groups <= 3 {
        return Err(RegistrationError::TooFewInliers {
            have: groups,
            need: 4,
        });
    }
    let a_inv = checked_inverse(&a, "robust Hessian")
        .or_else(|_| checked_inverse(&info_robust, "information matrix"))?;
    checked_inverse(&b, "score covariance")?;
    let g = groups as f64;
    let c = a_inv * b * a_inv * (g / (g - 1.0));
    Ok((c + c.transpose()) * 0.5)
}

/// Asymptotic variance factor `E[rho'^2 s] / 2 / (E[rho' + rho'' s])^2` of the robust M-estimator for
/// 2-D whitened residuals (`s ~ chi^2_2`, density `exp(-s/2)/2`); 1 for least squares.
pub fn robust_variance_factor(robust: &RobustLoss) -> f64 {
    // Midpoint rule on u = 1 - exp(-s/2) in (0, 1): s = -2 ln(1 - u), density becomes uniform.
    let n = 4000;
    let (mut num, mut den) = (0.0, 0.0);
    for k in 0..n {
        let u = (k as f64 + 0.5) / n as f64;
        let s = -2.0 * (1.0 - u).ln();
        let (_, d1, d2) = robust.rho(s);
        num += d1 * d1 * s;
        den += d1 + d2 * s;
    }
    let num = num / n as f64 / 2.0;
    let den = den / n as f64;
    num / (den * den)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registration::robust::RobustKind;

    fn spd(a: f64, b: f64, c: f64) -> Mat2 {
        // L L^T with L lower triangular [a 0; b c]
        let l = Mat2::new(a, 0.0, b, c);
        l * l.transpose()
    }

    #[test]
    fn residual_jacobian_matches_finite_differences() {
        let t = Iso2::new(Vec2::new(3.0, -1.0), 2.2);
        let x = Vec2::new(12.0, 7.0);
        let y = Vec2::new(-4.0, 9.0);
        let r = t.rotation.to_rotation_matrix().into_inner();
        let rp = r * perp(&x);
        let h = 1e-6;
        for k in 0..3 {
            let mut e = Vec3::zeros();
            e[k] = h;
            let dp = y - (t * se2_exp(&e) * nalgebra::Point2::from(x)).coords;
            let dm = y - (t * se2_exp(&-e) * nalgebra::Point2::from(x)).coords;
            let fd = (dp - dm) / (2.0 * h);
            let an = if k < 2 {
                -Vec2::new(r[(0, k)], r[(1, k)])
            } else {
                -rp
            };
            assert!((fd - an).norm() < 1e-7, "column {k}: fd {fd} analytic {an}");
        }
    }

    /// The gradient must include the rotation dependence of W = (Sy + R Sx R^T)^-1: compare the
    /// analytic gradient with central differences of the exact cost.
    #[test]
    fn gradient_matches_finite_differences_through_weights() {
        let sx = spd(0.3, 1.2, 0.4); // strongly anisotropic, rotated
        let sy = spd(0.5, -0.2, 0.9);
        let x = Vec2::new(30.0, -12.0);
        let t = Iso2::new(Vec2::new(2.0, 5.0), -0.7);
        let y = (t * nalgebra::Point2::from(x)).coords + Vec2::new(0.8, -1.1);
        for kind in [RobustKind::None, RobustKind::Cauchy, RobustKind::Huber] {
            let robust = RobustLoss { kind, scale: 1.3 };
            let p = pair_terms(&t, &x, &y, Some((&sx, &sy)), 1.0, &robust).unwrap();
            let cost = |e: &Vec3| {
                pair_terms(&(t * se2_exp(e)), &x, &y, Some((&sx, &sy)), 1.0, &robust)
                    .unwrap()
                    .cost
            };
            let h = 1e-6;
            let mut fd = Vec3::zeros();
            for k in 0..3 {
                let mut e = Vec3::zeros();
                e[k] = h;
                fd[k] = (cost(&e) - cost(&-e)) / (2.0 * h);
            }
            let err = (fd - p.gradient).norm() / fd.norm();
            assert!(err < 1e-6, "{kind:?}: fd {fd} analytic {}", p.gradient);
            // The weight-derivative term is not negligible here: freezing W gives a different theta
            // component, so this test would catch its omission.
            let frozen = p.drho * p.jtwd;
            assert!((frozen[2] - fd[2]).abs() > 1e-3 * fd[2].abs());
        }
    }

    /// The Gauss-Newton block is the exact Hessian of the cost at a zero residual (where the weight
    /// derivative and rho'' terms vanish).
    #[test]
    fn gauss_newton_block_is_hessian_at_zero_residual() {
        let sx = spd(0.3, 1.2, 0.4);
        let sy = spd(0.5, -0.2, 0.9);
        let x = Vec2::new(30.0, -12.0);
        let t = Iso2::new(Vec2::new(2.0, 5.0), -0.7);
        let y = (t * nalgebra::Point2::from(x)).coords;
        let robust = RobustLoss::default();
        let p = pair_terms(&t, &x, &y, Some((&sx, &sy)), 1.0, &robust).unwrap();
        let grad = |e: &Vec3| {
            pair_terms(&(t * se2_exp(e)), &x, &y, Some((&sx, &sy)), 1.0, &robust)
                .unwrap()
                .gradient
        };
        let h = 1e-6;
        for k in 0..3 {
            let mut e = Vec3::zeros();
            e[k] = h;
            let col = (grad(&e) - grad(&-e)) / (2.0 * h);
            let an = p.hessian_gn.column(k).into_owned();
            assert!(
                (col - an).norm() < 1e-5 * an.norm().max(1.0),
                "col {k}: {col} vs {an}"
            );
        }
    }

    #[test]
    fn variance_factor_of_least_squares_is_one_and_robust_above_one() {
        assert!((robust_variance_factor(&RobustLoss::none()) - 1.0).abs() < 1e-3);
        let k = robust_variance_factor(&RobustLoss::default());
        assert!(k > 1.0 && k < 1.2, "Cauchy c=3 factor {k}");
    }

    #[test]
    fn identical_source_points_give_an_error_not_a_covariance() {
        let src = PointSet2::isotropic(vec![Vec2::new(5.0, 5.0); 20], 0.3);
        let tgt = PointSet2::isotropic(vec![Vec2::new(1.0, 2.0); 20], 0.3);
        let pairs: Vec<_> = (0..20).map(|i| (i, i)).collect();
        for mode in [
            CovarianceMode::Information,
            CovarianceMode::Expected,
            CovarianceMode::Sandwich,
        ] {
            let cfg = LmConfig {
                covariance: mode,
                ..LmConfig::default()
            };
            let r = refine(&src, &tgt, &pairs, &Iso2::identity(), &cfg);
            assert!(
                matches!(r, Err(RegistrationError::Numerical(_))),
                "{mode:?}: {r:?}"
            );
        }
    }

    /// The cluster-robust sandwich with one pair per cluster is the empirical sandwich (up to its
    /// small-sample factor); a pair entered twice in one cluster adds no information, where the
    /// plain sandwich would take it as a second, independent measurement.
    #[test]
    fn clustered_covariance_counts_a_cluster_once() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let t = Iso2::new(Vec2::new(1.0, -2.0), 0.3);
        let n = 60;
        let xs: Vec<Vec2> = (0..n)
            .map(|_| Vec2::new(rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0)))
            .collect();
        let ys: Vec<Vec2> = xs
            .iter()
            .map(|x| {
                (t * nalgebra::Point2::from(*x)).coords
                    + Vec2::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3))
            })
            .collect();
        let cfg = LmConfig {
            covariance: CovarianceMode::Sandwich,
            ..LmConfig::default()
        };
        let set = |pts: Vec<Vec2>| PointSet2::isotropic(pts, 0.2);
        let (src, tgt) = (set(xs.clone()), set(ys.clone()));
        let pairs: Vec<(usize, usize)> = (0..n).map(|i| (i, i)).collect();
        let own: Vec<u64> = (0..n as u64).collect();
        let clustered = covariance_clustered(&t, &src, &tgt, &pairs, &own, &cfg).unwrap();
        let sandwich = covariance_at(&t, &src, &tgt, &pairs, &cfg).unwrap();
        let (g, m) = (n as f64, n as f64);
        let expected = sandwich * ((g / (g - 1.0)) / (m / (m - 3.0)));
        assert!(
            (clustered - expected).norm() < 1e-9 * expected.norm(),
            "{clustered} {expected}"
        );
        // Every pair twice: the plain sandwich halves, the clustered one (pairs of a point in one
        // cluster) stays.
        let doubled: Vec<(usize, usize)> = pairs.iter().chain(&pairs).copied().collect();
        let labels: Vec<u64> = own.iter().chain(&own).copied().collect();
        let twice = covariance_clustered(&t, &src, &tgt, &doubled, &labels, &cfg).unwrap();
        assert!((twice - clustered).norm() < 1e-9 * clustered.norm());
        let plain_twice = covariance_at(&t, &src, &tgt, &doubled, &cfg).unwrap();
        assert!(plain_twice.trace() < 0.6 * sandwich.trace());
        // Labels must match the pairs.
        assert!(covariance_clustered(&t, &src, &tgt, &pairs, &own[1..], &cfg).is_err());
    }
}
