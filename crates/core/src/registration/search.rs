//! The search for the alignment, steps 2-5 of a registration over one [`PairContext`]:
//! 2. RANSAC keeps up to `screened_hypotheses` distinct, well-supported motions;
//! 3. screening ranks them by geometry (the coverage of the target by the motion's source probes),
//!    and the best `hypotheses` are refined ([`refine_hypothesis`]: LM on eq. 10, re-selection, the
//!    dense stage);
//! 4. when the descriptor stage found nothing or little, the correlative search proposes poses;
//! 5. a weak winner's slides along its street compete too ([`refine_from_pose`]).
//!
//! The refined alignment with the best fit score wins; every other refined or screened alignment is
//! kept as an alternative for the ambiguity gate.

use super::finishing::{Fit, check_inliers, conclude, descriptor_pairs, reselect};
use super::prepared::{DenseSets, PairContext};
use super::ransac::Screened;
use super::{
    PointSet2, RegistrationConfig, RegistrationDetail, RegistrationError, correlative, dense, lm,
    ransac,
};
use crate::math::{Iso2, Vec2};

/// RANSAC and the screening: the supported motions ranked by coverage, best first. Empty when RANSAC
/// found nothing but the correlative search may still; an error when nothing can follow.
pub fn screen(ctx: &PairContext<'_>) -> Result<Screened, RegistrationError> {
    let PairContext {
        source,
        target,
        sets,
        candidates,
        cfg,
    } = *ctx;
    // The best-supported motions that differ by more than the ambiguity distances.
    let distinct = ransac::Distinct {
        // At least `hypotheses` (validated).
        keep: cfg.screened_hypotheses,
        translation: cfg.ambiguity_translation,
        rotation: cfg.ambiguity_rotation,
        min_support: cfg.min_inliers,
    };
    // A RANSAC failure (too few candidates) still leaves the correlative search.
    let found = match ransac::ransac_hypotheses(source, target, candidates, &cfg.ransac, &distinct)
    {
        Ok(f) => f,
        Err(e) if !correlative_applies(cfg) => return Err(e),
        Err(_) => Vec::new(),
    };
    let most = found.first().map_or(0, |h| h.inliers.len());
    // Descriptor support does not tell a street slid along itself (or a repeated block) from the
    // true alignment, geometry does: the share of source probes with a target cell at the motion.
    let mut screened: Screened = found
        .into_iter()
        .filter(|h| h.inliers.len() >= cfg.min_inliers)
        .map(|h| (sets.coverage.count(sets.probes, &h.t_target_source), h))
        .collect();
    if screened.is_empty() && !correlative_applies(cfg) {
        return Err(RegistrationError::TooFewInliers {
            have: most,
            need: cfg.min_inliers,
        });
    }
    screened.sort_by(|a, b| {
        b.0.cmp(&a.0)
            .then(b.1.inliers.len().cmp(&a.1.inliers.len()))
    });
    Ok(screened)
}

/// The refined alignments so far: the best by fit score, every one (pose, overlap) for the runner-up,
/// and the first error.
#[derive(Default)]
pub struct Refined {
    /// The best so far.
    pub best: Option<RegistrationDetail>,
    /// Every refined alignment, with its overlap.
    pub all: Vec<(Iso2, f64)>,
    /// The first refinement that failed.
    pub first_error: Option<RegistrationError>,
}

impl Refined {
    /// A motion within the ambiguity distances of an alignment already refined is that alignment
    /// again: refining it would repeat the work and cannot add a runner-up.
    fn already(&self, t: &Iso2, cfg: &RegistrationConfig) -> bool {
        self.all.iter().any(|(r, _)| cfg.same_alignment(r, t))
    }

    fn add(&mut self, d: Result<RegistrationDetail, RegistrationError>) {
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
    pub fn hypotheses(&mut self, ctx: &PairContext<'_>, screened: &Screened) {
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
    pub fn poses(&mut self, ctx: &PairContext<'_>, poses: &[Iso2]) {
        for &pose in poses {
            if !self.already(&pose, ctx.cfg) {
                self.add(refine_from_pose(ctx, pose));
            }
        }
    }

    /// The correlative search when the descriptor stage found nothing or little overlap, then a
    /// weak winner's slides along its street (`correlative.slide_shifts`).
    pub fn beyond_descriptors(&mut self, ctx: &PairContext<'_>) {
        let cfg = ctx.cfg;
        if !correlative_applies(cfg) {
            return;
        }
        if self.best.as_ref().is_none_or(|b| weak_result(b, ctx)) {
            self.poses(ctx, &correlative_poses(&ctx.sets, cfg));
        }
        let weak_winner = self
            .best
            .as_ref()
            .filter(|b| weak_result(b, ctx))
            .map(|b| b.result.t_target_source);
        if let Some(win) = weak_winner {
            let poses: Vec<Iso2> = cfg
                .correlative
                .slide_shifts
                .iter()
                .map(|&dx| win * Iso2::new(Vec2::new(dx, 0.0), 0.0))
                .collect();
            self.poses(ctx, &poses);
        }
    }
}

/// The correlative search's candidate poses, scored where the votes put them (a cell and the
/// histogram's resolution off), best first.
fn correlative_poses(sets: &DenseSets<'_>, cfg: &RegistrationConfig) -> Vec<Iso2> {
    let found = correlative::candidates(
        sets.src_as_target,
        sets.src_tree,
        sets.tgt,
        sets.tree,
        &cfg.correlative,
    );
    let sigma = cfg.selection_sigma.max(0.35);
    let probes = PointSet2 {
        points: sets.probes.to_vec(),
        covs: Vec::new(),
        rays: Vec::new(),
    };
    let mut scored: Vec<(f64, Iso2)> = found
        .into_iter()
        .map(|(_, t)| {
            let score = dense::fit_score(&probes, None, sets.tgt, sets.tree, &t, 2.0 * sigma).1;
            (score, t)
        })
        .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    scored
        .into_iter()
        .take(cfg.correlative.candidates)
        .map(|(_, pose)| pose)
        .collect()
}

/// One RANSAC hypothesis refined: LM on its inliers (eq. 10), re-selection of the inliers with the noise
/// model, the dense stage, the covariance, the overlap.
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
    // certainty (pipeline NEES about 20 instead of 3); `dense.covariance_scale` accounts for the dense
    // pose being more accurate than that.
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

/// A result searched beyond (`registration.correlative`): its plain fit score below `below_score`,
/// and fewer than `below_inliers` descriptor inliers unless its plain score is below
/// `rich_below_score` or its common view ([`common_view`]) below `below_common_view`.
pub(super) fn weak_result(d: &RegistrationDetail, ctx: &PairContext<'_>) -> bool {
    let (sets, cfg) = (&ctx.sets, ctx.cfg);
    d.plain_score < cfg.correlative.below_score
        && (d.result.inliers < cfg.correlative.below_inliers
            || d.plain_score < cfg.correlative.rich_below_score
            || sets
                .bearings
                .0
                .common(sets.bearings.1, d.result.t_target_source.rotation.angle())
                < cfg.correlative.below_common_view)
}

/// The correlative search runs: enabled, and the dense stage it refines with is on.
pub(super) fn correlative_applies(cfg: &RegistrationConfig) -> bool {
    cfg.correlative.enabled && cfg.dense.enabled
}

/// A correlative candidate refined: the dense stage from `pose`, then the descriptor candidates
/// within `reselect_gate` of where it ends (one per point; at least `correlative.min_inliers`, not on
/// a line) give the covariance, as the descriptor inliers do for a RANSAC hypothesis.
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
        need: cfg.dense.min_pairs,
    })?;
    let inliers = reselect(ctx, &d.t_target_source);
    let relaxed = RegistrationConfig {
        min_inliers: cfg.correlative.min_inliers,
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
    if d.dense_covariance && d.result.overlap < cfg.correlative.min_overlap {
        return Err(RegistrationError::TooFewInliers {
            have,
            need: cfg.correlative.min_inliers,
        });
    }
    Ok(d)
}
