//! Stage 3 of a registration, the refinement: each of the best hypotheses by LM on eq. 10 from the
//! RANSAC estimate, the inliers re-selected with the noise model, and the dense stage
//! ([`refine_hypothesis`]); a pose from the search beyond the descriptors by the dense stage alone
//! ([`refine_from_pose`]). Each refined alignment reports its overlap, fit score and covariance
//! ([`conclude`]); the best fit score wins ([`Refined`]), and every other one stays an alternative
//! for the ambiguity gate.

use super::config::RegistrationConfig;
use super::prepared::{DenseSets, PairContext};
use super::ransac::{self, Screened};
use super::types::{
    PointSet2, RegistrationDetail, RegistrationError, RegistrationResult, covariance_ros_from_se2,
};
use super::{correlative, dense, lm, robust};
use crate::math::{Iso2, Mat2, Mat3, Vec2, Vec3};

/// The refined alignments so far: the best by fit score, every one (pose, overlap) for the
/// runner-up, and the first error.
#[derive(Default)]
pub(super) struct Refined {
    /// The best so far.
    pub(super) best: Option<RegistrationDetail>,
    /// Every refined alignment, with its overlap.
    pub(super) all: Vec<(Iso2, f64)>,
    /// The first refinement that failed.
    pub(super) first_error: Option<RegistrationError>,
}

impl Refined {
    /// A motion within the ambiguity distances of an alignment already refined is that alignment
    /// again: refining it would repeat the work and cannot add a runner-up.
    pub(super) fn already(&self, t: &Iso2, cfg: &RegistrationConfig) -> bool {
        self.all.iter().any(|(r, _)| cfg.same_alignment(r, t))
    }

    pub(super) fn add(&mut self, d: Result<RegistrationDetail, RegistrationError>) {
        match d {
            Ok(d) => {
                self.all.push((d.result.t_target_source, d.result.overlap));
                if self.best.as_ref().is_none_or(|b| d.score > b.score) {
                    self.best = Some(d);
                }
            }
            Err(e) => {
                self.first_error.get_or_insert(e);
            }
        }
    }

    /// Refines the best `hypotheses` screened motions.
    pub(super) fn hypotheses(&mut self, ctx: &PairContext<'_>, screened: &Screened) {
        for (_, rs) in screened.iter().take(ctx.cfg.hypotheses.max(1)) {
            if self.already(&rs.t_target_source, ctx.cfg) {
                continue;
            }
            let d = refine_hypothesis(ctx, rs.inliers.clone(), rs.t_target_source).map(|mut d| {
                d.ransac_iterations = rs.iterations;
                d
            });
            self.add(d);
        }
    }

    /// Alignments from poses (the correlative search's, the slides'): each not yet refined runs the
    /// dense stage and competes.
    pub(super) fn poses(&mut self, ctx: &PairContext<'_>, poses: &[Iso2]) {
        for &pose in poses {
            if !self.already(&pose, ctx.cfg) {
                self.add(refine_from_pose(ctx, pose));
            }
        }
    }
}

/// One RANSAC hypothesis refined: LM on its inliers (eq. 10), re-selection of the inliers with the
/// noise model, the dense stage, the covariance, the overlap.
pub(super) fn refine_hypothesis(
    ctx: &PairContext<'_>,
    mut inliers: Vec<usize>,
    t_ransac: Iso2,
) -> Result<RegistrationDetail, RegistrationError> {
    let PairContext {
        source,
        target,
        sets,
        candidates,
        cfg,
    } = *ctx;
    let DenseSets { src, tgt, tree, .. } = sets;
    let pairs_of = |sel: &[usize]| descriptor_pairs(candidates, sel);
    let pairs = pairs_of(&inliers);
    check_inliers(source, &pairs, cfg)?;
    let mut lm = lm::refine_pose(source, target, &pairs, &t_ransac, &cfg.lm)?;
    let mut iterations = lm.iterations;
    for _ in 0..cfg.reselect_rounds {
        let sel = reselect(ctx, &lm.t_target_source);
        if sel == inliers {
            break;
        }
        let new_pairs = pairs_of(&sel);
        // Too few (or collinear) under the noise model: keep the inliers RANSAC's radius gave.
        if check_inliers(source, &new_pairs, cfg).is_err() {
            break;
        }
        lm = lm::refine_pose(source, target, &new_pairs, &lm.t_target_source, &cfg.lm)?;
        iterations += lm.iterations;
        inliers = sel;
    }
    // The covariance comes from the descriptor pairs (evaluated at the final pose): they are distinct
    // physical matches whose scatter the sandwich estimator measures. Nearest-neighbour pairs share
    // target points and their residuals are not independent, so their information overstates the
    // certainty (pipeline NEES about 20 instead of 3); `dense::COVARIANCE_SCALE` accounts for the
    // dense pose being more accurate than that.
    let mut dense_settled = None;
    if cfg.dense.enabled
        && let Some(d) = dense::refine_dense(
            src,
            tgt,
            tree,
            &lm.t_target_source,
            &cfg.dense,
            &cfg.lm,
            dense::Rounds::Plain,
        )?
    {
        lm.t_target_source = d.t_target_source;
        lm.converged = d.converged;
        lm.cost = d.cost;
        iterations += d.iterations;
        dense_settled = Some(d.settled);
    }
    let fit = Fit {
        t_target_source: lm.t_target_source,
        converged: lm.converged,
        cost: lm.cost,
        iterations,
        dense_settled,
        overlap: None,
        score: None,
        dense_covariance: false,
    };
    conclude(ctx, inliers, t_ransac, fit)
}

/// A correlative candidate refined: the dense stage from `pose`, then the descriptor candidates
/// within [`RESELECT_GATE`] of where it ends (one per point; at least [`correlative::MIN_INLIERS`],
/// not on a line) give the covariance, as the descriptor inliers do for a RANSAC hypothesis.
pub(super) fn refine_from_pose(
    ctx: &PairContext<'_>,
    pose: Iso2,
) -> Result<RegistrationDetail, RegistrationError> {
    let PairContext {
        source,
        sets,
        candidates,
        cfg,
        ..
    } = *ctx;
    let d = dense::refine_dense(
        sets.src,
        sets.tgt,
        sets.tree,
        &pose,
        &cfg.dense,
        &cfg.lm,
        dense::Rounds::Plain,
    )?
    .ok_or(RegistrationError::TooFewInliers {
        have: 0,
        need: dense::MIN_PAIRS,
    })?;
    let inliers = reselect(ctx, &d.t_target_source);
    let relaxed = RegistrationConfig {
        min_inliers: correlative::MIN_INLIERS,
        ..cfg.clone()
    };
    // Too few descriptor pairs agree (or they lie on a line): the covariance comes from the dense pairs.
    let dense_covariance =
        check_inliers(source, &descriptor_pairs(candidates, &inliers), &relaxed).is_err();
    let fit = Fit {
        t_target_source: d.t_target_source,
        converged: d.converged,
        cost: d.cost,
        iterations: d.iterations,
        dense_settled: Some(d.settled),
        overlap: None,
        score: None,
        dense_covariance,
    };
    let have = inliers.len();
    let d = conclude(ctx, inliers, pose, fit)?;
    // Without the descriptors' vote the geometry alone must speak clearly.
    if d.dense_covariance && d.result.overlap < correlative::MIN_OVERLAP {
        return Err(RegistrationError::TooFewInliers {
            have,
            need: correlative::MIN_INLIERS,
        });
    }
    Ok(d)
}

/// Where a hypothesis's refinement ended.
pub(super) struct Fit {
    pub(super) t_target_source: Iso2,
    pub(super) converged: bool,
    pub(super) cost: f64,
    pub(super) iterations: usize,
    /// `None` when the dense stage did not run; else whether its rounds had settled.
    pub(super) dense_settled: Option<bool>,
    /// The overlap to report when it is already known; else measured at the pose.
    pub(super) overlap: Option<f64>,
    /// The fit scores likewise (weighted, plain).
    pub(super) score: Option<(f64, f64)>,
    /// The covariance comes from the dense pairs
    /// ([`correlative::CorrelativeConfig::covariance_scale`]) instead of the descriptor inliers.
    pub(super) dense_covariance: bool,
}

/// The (source, target) point indices of the candidates `sel` (indices into `candidates`).
pub(super) fn descriptor_pairs(
    candidates: &[ransac::Correspondence],
    sel: &[usize],
) -> Vec<(usize, usize)> {
    sel.iter()
        .map(|&k| (candidates[k].source as usize, candidates[k].target as usize))
        .collect()
}

/// Overlap and covariance at a refined pose: the detail of one hypothesis.
pub(super) fn conclude(
    ctx: &PairContext<'_>,
    inliers: Vec<usize>,
    t_ransac: Iso2,
    fit: Fit,
) -> Result<RegistrationDetail, RegistrationError> {
    let PairContext {
        source,
        target,
        sets,
        candidates,
        cfg,
    } = *ctx;
    let DenseSets {
        src,
        weights,
        tgt,
        tree,
        ..
    } = sets;
    let pairs = descriptor_pairs(candidates, &inliers);
    let overlap = fit.overlap.unwrap_or_else(|| {
        dense::associate(src, tgt, tree, &fit.t_target_source, &cfg.dense).len() as f64
            / src.len().max(1) as f64
    });
    let (score, plain_score) = fit.score.unwrap_or_else(|| {
        dense::fit_score(
            src,
            Some(weights),
            tgt,
            tree,
            &fit.t_target_source,
            dense::SELECTION_SIGMA,
        )
    });
    // Covariance at the optimum; also refuses an unobservable pose (singular information).
    let covariance_se2 = if fit.dense_covariance {
        let dense_pairs = dense::associate(src, tgt, tree, &fit.t_target_source, &cfg.dense);
        let labels =
            correlative::cluster_labels(src, &dense_pairs, correlative::COVARIANCE_CLUSTER);
        lm::covariance_clustered(
            &fit.t_target_source,
            src,
            tgt,
            &dense_pairs,
            &labels,
            &cfg.lm,
        )? * correlative::COVARIANCE_SCALE
    } else {
        let covariance = lm::covariance_at(&fit.t_target_source, source, target, &pairs, &cfg.lm)?;
        let scale = if fit.dense_settled.is_some() {
            COVARIANCE_SCALE * dense::COVARIANCE_SCALE
        } else {
            COVARIANCE_SCALE
        };
        covariance * scale
    };
    let covariance_se2 = if fit.dense_settled.is_some() {
        let [ft, fr] = cfg.covariance_floor;
        covariance_se2 + Mat3::from_diagonal(&Vec3::new(ft * ft, ft * ft, fr * fr))
    } else {
        covariance_se2
    };
    let result = RegistrationResult {
        t_target_source: fit.t_target_source,
        covariance: covariance_ros_from_se2(&covariance_se2),
        converged: fit.converged,
        iterations: fit.iterations,
        inliers: pairs.len(),
        candidates: candidates.len(),
        cost: fit.cost,
        overlap,
        runner_up_overlap: 0.0,
        alternatives: Vec::new(),
        score_share: Mat3::zeros(),
    };
    Ok(RegistrationDetail {
        result,
        covariance_se2,
        candidates: Vec::new(),
        inliers,
        t_ransac,
        ransac_iterations: 0,
        dense_settled: fit.dense_settled,
        score,
        plain_score,
        dense_covariance: fit.dense_covariance,
    })
}

/// Enough inliers, not all on a line.
pub(super) fn check_inliers(
    source: &PointSet2,
    pairs: &[(usize, usize)],
    cfg: &RegistrationConfig,
) -> Result<(), RegistrationError> {
    if pairs.len() < cfg.min_inliers {
        return Err(RegistrationError::TooFewInliers {
            have: pairs.len(),
            need: cfg.min_inliers,
        });
    }
    // Inliers along a line (or on a point) cannot fix the motion along it: refuse.
    let spread = min_spread(pairs.iter().map(|&(i, _)| source.points[i]));
    if spread < cfg.min_inlier_spread {
        return Err(RegistrationError::Numerical(format!(
            "degenerate inlier geometry: spread {spread:.3} m along the thinnest direction is below \
             registration.min_inlier_spread = {} m",
            cfg.min_inlier_spread
        )));
    }
    Ok(())
}

/// Factor on the covariance of a descriptor-stage result: descriptor association also accepts
/// neighbouring reflectors within the gate, whose offsets bias the estimate beyond what the
/// residual scatter shows.
pub const COVARIANCE_SCALE: f64 = 1.3;

/// After LM, the candidates within this many sigma of the estimate (Mahalanobis with the LM
/// weights) become the inliers, one per source and per target point, and LM runs again: 99.8 % of
/// 2-D Gaussian residuals. RANSAC's metric threshold keeps residuals that agree with its own noisy
/// estimate, the noise model does not.
pub const RESELECT_GATE: f64 = 3.5;

/// Candidates within [`RESELECT_GATE`] sigma of `t` (LM weights), one per source point (the
/// closest), as ascending indices into `candidates`.
pub(super) fn reselect(ctx: &PairContext<'_>, t: &Iso2) -> Vec<usize> {
    let PairContext {
        source,
        target,
        candidates,
        cfg,
        ..
    } = *ctx;
    let gate2 = RESELECT_GATE * RESELECT_GATE;
    let iso_var = cfg.lm.isotropic_sigma * cfg.lm.isotropic_sigma;
    let plain = robust::RobustLoss::none();
    // (source, target, candidate index) of the candidates within the gate.
    let mut kept: Vec<(u32, u32, usize)> = Vec::new();
    for (k, c) in candidates.iter().enumerate() {
        let (i, j) = (c.source as usize, c.target as usize);
        let (Some(x), Some(y)) = (source.points.get(i), target.points.get(j)) else {
            continue;
        };
        let cov = match (
            cfg.lm.use_uncertainty,
            source.covs.get(i),
            target.covs.get(j),
        ) {
            (true, Some(sx), Some(sy)) => Some((sx, sy)),
            (true, _, _) => continue,
            (false, _, _) => None,
        };
        if let Some(p) = lm::pair_terms(t, x, y, cov, iso_var, &plain)
            && p.s <= gate2
        {
            kept.push((c.source, c.target, k));
        }
    }
    // One pair per source point and per target point: a point shared by several pairs would give
    // them a common error that LM counts as independent. Which candidate stays is decided by the
    // indices, not by the residual or the descriptor distance: both prefer pairs whose noise
    // happens to agree, and the covariance then claims more than the data hold.
    kept.sort_unstable_by_key(|e| (e.0, e.1));
    kept.dedup_by_key(|e| e.0);
    kept.sort_unstable_by_key(|e| (e.1, e.0));
    kept.dedup_by_key(|e| e.1);
    let mut out: Vec<usize> = kept.into_iter().map(|e| e.2).collect();
    out.sort_unstable();
    out
}

/// Standard deviation of points along their least-spread direction, m (0 for fewer than 2 points).
fn min_spread(points: impl Iterator<Item = Vec2> + Clone) -> f64 {
    let (mut n, mut sum) = (0.0, Vec2::zeros());
    for p in points.clone() {
        n += 1.0;
        sum += p;
    }
    if n < 2.0 {
        return 0.0;
    }
    let mean = sum / n;
    let mut c = Mat2::zeros();
    for p in points {
        let d = p - mean;
        c += d * d.transpose();
    }
    c /= n;
    let tr = c[(0, 0)] + c[(1, 1)];
    let det = c[(0, 0)] * c[(1, 1)] - c[(0, 1)] * c[(1, 0)];
    let lmin = 0.5 * tr - (0.25 * tr * tr - det).max(0.0).sqrt();
    lmin.max(0.0).sqrt()
}
