//! RANSAC on a planar rigid motion (Fischler & Bolles 1981) over candidate correspondences.
//!
//! Entry points: [`RansacConfig`], [`ransac`] (RANSAC on given correspondences), [`RansacResult`],
//! [`fit_rigid`] (closed-form least-squares rigid fit, 2-D Procrustes / Umeyama 1991).
//!
//! Minimal sets are 2 correspondences. A drawn pair is rejected before any scoring when its two source
//! points are closer than `min_sample_separation` (the rotation would be ill-defined) or when the
//! distances `|x_a - x_b|` and `|y_a - y_b|` disagree by more than the two inlier radii (no rigid motion
//! can make both inliers). Those checks cost a few flops and throw away most wrong pairs, so rejected
//! draws are cheap; they still count as iterations in the adaptive stopping rule
//! `N = ln(1 - p) / ln(1 - w^2)` (w = best inlier share so far), which is what that rule assumes.
//! Scoring stops early once a hypothesis can no longer beat the best one. The random generator is
//! seeded from the configuration: the same input gives the same output.

use crate::math::{Iso2, Mat2, Vec2};
use crate::registration::{PointSet2, RegistrationError};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::{Deserialize, Serialize};

/// A candidate match: source (current submap) point index, target (previous submap) point index.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Correspondence {
    /// Index into the source point set.
    pub source: u32,
    /// Index into the target point set.
    pub target: u32,
    /// Descriptor distance (Euclidean; 0 when the match did not come from descriptors).
    pub descriptor_distance: f32,
}

impl Correspondence {
    /// A correspondence without a descriptor distance.
    pub fn new(source: usize, target: usize) -> Self {
        Correspondence {
            source: source as u32,
            target: target as u32,
            descriptor_distance: 0.0,
        }
    }
}

/// RANSAC settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RansacConfig {
    /// Inlier radius `|y - T x|`, m (default 1.0; the DC-Loc authors' code uses 0.75).
    pub inlier_threshold: f64,
    /// When > 0, inliers are judged by the Mahalanobis distance `sqrt(d^T (Sy + R Sx R^T)^-1 d)`
    /// against this gate (in sigma) instead of `inlier_threshold`; 0 = off (default 0). During
    /// the search a rotation-free bound is used (`|d|^2 <= gate^2 (lmax(Sx) + lmax(Sy))`), the exact
    /// test in the final refit.
    pub mahalanobis_gate: f64,
    /// Probability of having drawn at least one all-inlier pair when stopping (default 0.999).
    pub confidence: f64,
    /// Upper bound on drawn pairs, rejected or not (default 20000).
    pub max_iterations: usize,
    /// Minimum distance between the two source points of a minimal set, m (default 2.0).
    pub min_sample_separation: f64,
    /// Least-squares refits on the inlier set after the search (default 3).
    pub refit_rounds: usize,
    /// Seed of the random generator (default 0x5EED).
    pub seed: u64,
}

impl Default for RansacConfig {
    fn default() -> Self {
        RansacConfig {
            inlier_threshold: 1.0,
            mahalanobis_gate: 0.0,
            confidence: 0.999,
            max_iterations: 20_000,
            min_sample_separation: 2.0,
            refit_rounds: 3,
            seed: 0x5EED,
        }
    }
}

impl RansacConfig {
    /// Rejects unusable values; `prefix` is the dotted section name.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        use crate::config::ConfigError;
        let name = |f: &str| format!("{prefix}.{f}");
        if !(self.inlier_threshold.is_finite() && self.inlier_threshold > 0.0) {
            return Err(ConfigError::new(
                name("inlier_threshold"),
                format!("{} must be finite and > 0 m", self.inlier_threshold),
            ));
        }
        if !(self.mahalanobis_gate.is_finite() && self.mahalanobis_gate >= 0.0) {
            return Err(ConfigError::new(
                name("mahalanobis_gate"),
                format!("{} must be finite and >= 0", self.mahalanobis_gate),
            ));
        }
        if !(self.confidence > 0.0 && self.confidence < 1.0) {
            return Err(ConfigError::new(
                name("confidence"),
                format!("{} is not in (0, 1)", self.confidence),
            ));
        }
        if self.max_iterations == 0 {
            return Err(ConfigError::new(
                name("max_iterations"),
                "must be at least 1",
            ));
        }
        if !(self.min_sample_separation.is_finite() && self.min_sample_separation >= 0.0) {
            return Err(ConfigError::new(
                name("min_sample_separation"),
                format!("{} must be finite and >= 0 m", self.min_sample_separation),
            ));
        }
        Ok(())
    }
}

/// What [`ransac`] returns.
#[derive(Debug, Clone, PartialEq)]
pub struct RansacResult {
    /// Source frame in the target frame, refitted on the inliers.
    pub t_target_source: Iso2,
    /// Indices into the correspondence slice of the inliers, at most one per source point (the
    /// smallest residual), ascending.
    pub inliers: Vec<usize>,
    /// Pairs drawn (including those rejected before scoring).
    pub iterations: usize,
    /// Hypotheses scored.
    pub hypotheses: usize,
}

/// Least-squares rigid motion `y ~ R x + t` over pairs (2-D Procrustes, closed form).
/// Returns `None` for fewer than 2 pairs or when all source points coincide.
pub fn fit_rigid(pairs: impl Iterator<Item = (Vec2, Vec2)> + Clone) -> Option<Iso2> {
    let (mut n, mut sx, mut sy) = (0.0, Vec2::zeros(), Vec2::zeros());
    for (x, y) in pairs.clone() {
        n += 1.0;
        sx += x;
        sy += y;
    }
    if n < 2.0 {
        return None;
    }
    let (mx, my) = (sx / n, sy / n);
    let (mut dot, mut cross, mut spread) = (0.0, 0.0, 0.0);
    for (x, y) in pairs {
        let (a, b) = (x - mx, y - my);
        dot += a.dot(&b);
        cross += a.x * b.y - a.y * b.x;
        spread += a.norm_squared();
    }
    if spread <= 1e-18 {
        return None;
    }
    let rot = nalgebra::UnitComplex::new(cross.atan2(dot));
    let t = my - rot * mx;
    Some(Iso2::from_parts(t.into(), rot))
}

fn lambda_max(c: &Mat2) -> f64 {
    let tr = c[(0, 0)] + c[(1, 1)];
    let det = c[(0, 0)] * c[(1, 1)] - c[(0, 1)] * c[(1, 0)];
    0.5 * tr + (0.25 * tr * tr - det).max(0.0).sqrt()
}

/// RANSAC over `correspondences` between `source` and `target`.
///
/// Errors: [`RegistrationError::TooFewInliers`] when there are fewer than 2 correspondences or no
/// usable minimal set (e.g. all source points within `min_sample_separation` of each other);
/// [`RegistrationError::Numerical`] for an index out of range or a non-finite point.
pub fn ransac(
    source: &PointSet2,
    target: &PointSet2,
    correspondences: &[Correspondence],
    cfg: &RansacConfig,
) -> Result<RansacResult, RegistrationError> {
    let n = correspondences.len();
    if n < 2 {
        return Err(RegistrationError::TooFewInliers { have: n, need: 2 });
    }
    // Gather the pairs contiguously (cache-friendly scoring) and the per-pair squared inlier radius.
    let mut xs = Vec::with_capacity(n);
    let mut ys = Vec::with_capacity(n);
    let mut thr2 = Vec::with_capacity(n);
    let maha = cfg.mahalanobis_gate > 0.0;
    for c in correspondences {
        let (i, j) = (c.source as usize, c.target as usize);
        let (Some(x), Some(y)) = (source.points.get(i), target.points.get(j)) else {
            return Err(RegistrationError::Numerical(format!(
                "correspondence ({i}, {j}) out of range ({} source, {} target points)",
                source.len(),
                target.len()
            )));
        };
        if !(x.iter().all(|v| v.is_finite()) && y.iter().all(|v| v.is_finite())) {
            return Err(RegistrationError::Numerical(format!(
                "non-finite point in correspondence ({i}, {j})"
            )));
        }
        xs.push(*x);
        ys.push(*y);
        thr2.push(if maha {
            let (Some(sx), Some(sy)) = (source.covs.get(i), target.covs.get(j)) else {
                return Err(RegistrationError::Numerical(
                    "point set has fewer covariances than points".into(),
                ));
            };
            cfg.mahalanobis_gate * cfg.mahalanobis_gate * (lambda_max(sx) + lambda_max(sy))
        } else {
            cfg.inlier_threshold * cfg.inlier_threshold
        });
    }

    let mut rng = StdRng::seed_from_u64(cfg.seed);
    let min_sep2 = cfg.min_sample_separation * cfg.min_sample_separation;
    let log_fail = (1.0 - cfg.confidence).ln();
    let mut needed = cfg.max_iterations;
    let (mut best_count, mut best_t) = (0usize, None::<Iso2>);
    let (mut iterations, mut hypotheses) = (0usize, 0usize);
    while iterations < needed {
        iterations += 1;
        let a = rng.random_range(0..n);
        let b = rng.random_range(0..n);
        let (ca, cb) = (&correspondences[a], &correspondences[b]);
        if ca.source == cb.source || ca.target == cb.target {
            continue;
        }
        let u = xs[b] - xs[a];
        let v = ys[b] - ys[a];
        let (lu2, lv2) = (u.norm_squared(), v.norm_squared());
        if lu2 < min_sep2 || lu2 <= 1e-18 {
            continue;
        }
        // Rigidity: ||u| - |v|| can be at most the sum of the two inlier radii.
        let slack = thr2[a].sqrt() + thr2[b].sqrt();
        if (lu2.sqrt() - lv2.sqrt()).abs() > slack {
            continue;
        }
        hypotheses += 1;
        let rot = nalgebra::UnitComplex::new((u.x * v.y - u.y * v.x).atan2(u.dot(&v)));
        let (c, s) = (rot.re, rot.im);
        let mid_x = 0.5 * (xs[a] + xs[b]);
        let mid_y = 0.5 * (ys[a] + ys[b]);
        let tx = mid_y.x - (c * mid_x.x - s * mid_x.y);
        let ty = mid_y.y - (s * mid_x.x + c * mid_x.y);
        // Score with early exit once the best count is out of reach.
        let mut count = 0usize;
        for k in 0..n {
            let x = &xs[k];
            let dx = ys[k].x - (c * x.x - s * x.y + tx);
            let dy = ys[k].y - (s * x.x + c * x.y + ty);
            if dx * dx + dy * dy <= thr2[k] {
                count += 1;
            } else if count + (n - k - 1) <= best_count {
                break;
            }
        }
        if count > best_count {
            best_count = count;
            best_t = Some(Iso2::from_parts(Vec2::new(tx, ty).into(), rot));
            let w = count as f64 / n as f64;
            let p_good = w * w;
            needed = if p_good >= 1.0 {
                iterations
            } else {
                let k = (log_fail / (1.0 - p_good).ln()).ceil();
                if k.is_finite() {
                    (k as usize).clamp(1, cfg.max_iterations)
                } else {
                    cfg.max_iterations
                }
            };
        }
    }
    let Some(mut t) = best_t else {
        return Err(RegistrationError::TooFewInliers { have: 0, need: 2 });
    };

    // Final least-squares refits: inliers of the current motion, then refit, until stable.
    let mut inliers = classify(source, target, correspondences, &xs, &ys, &thr2, &t, cfg);
    for _ in 0..cfg.refit_rounds {
        let Some(t_new) = fit_rigid(inliers.iter().map(|&k| (xs[k], ys[k]))) else {
            break;
        };
        let new_inliers = classify(
            source,
            target,
            correspondences,
            &xs,
            &ys,
            &thr2,
            &t_new,
            cfg,
        );
        if new_inliers.len() < inliers.len() {
            break;
        }
        let same = new_inliers == inliers;
        t = t_new;
        inliers = new_inliers;
        if same {
            break;
        }
    }
    Ok(RansacResult {
        t_target_source: t,
        inliers,
        iterations,
        hypotheses,
    })
}

/// Inliers of `t`, one per source point (smallest residual), ascending.
#[allow(clippy::too_many_arguments)]
fn classify(
    source: &PointSet2,
    target: &PointSet2,
    corr: &[Correspondence],
    xs: &[Vec2],
    ys: &[Vec2],
    thr2: &[f64],
    t: &Iso2,
    cfg: &RansacConfig,
) -> Vec<usize> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let mut kept: Vec<(u32, f64, usize)> = Vec::new();
    for k in 0..xs.len() {
        let d = ys[k] - (r * xs[k] + t.translation.vector);
        let e2 = d.norm_squared();
        if e2 > thr2[k] {
            continue;
        }
        let score = if cfg.mahalanobis_gate > 0.0 {
            let (i, j) = (corr[k].source as usize, corr[k].target as usize);
            let c = target.covs[j] + r * source.covs[i] * r.transpose();
            match c.try_inverse() {
                Some(w) => {
                    let m2 = d.dot(&(w * d));
                    // NaN fails the gate too.
                    if m2.is_nan() || m2 > cfg.mahalanobis_gate * cfg.mahalanobis_gate {
                        continue;
                    }
                    m2
                }
                None => continue,
            }
        } else {
            e2
        };
        kept.push((corr[k].source, score, k));
    }
    // One inlier per source point: the smallest residual wins.
    kept.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    kept.dedup_by_key(|e| e.0);
    let mut out: Vec<usize> = kept.into_iter().map(|e| e.2).collect();
    out.sort_unstable();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_rigid_recovers_exact_motion() {
        let t = Iso2::new(Vec2::new(3.0, -2.0), 2.5);
        let xs = [
            Vec2::new(0.0, 0.0),
            Vec2::new(10.0, 1.0),
            Vec2::new(-3.0, 7.0),
        ];
        let pairs = xs
            .iter()
            .map(|x| (*x, (t * nalgebra::Point2::from(*x)).coords));
        let f = fit_rigid(pairs).unwrap();
        assert!((f.translation.vector - t.translation.vector).norm() < 1e-12);
        assert!((f.rotation.angle() - 2.5).abs() < 1e-12);
        assert!(fit_rigid(std::iter::repeat_n((Vec2::zeros(), Vec2::zeros()), 5)).is_none());
    }
}
