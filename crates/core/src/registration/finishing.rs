//! The winner's last steps and what every refined alignment reports: its overlap, fit score and
//! covariance ([`conclude`]); polishing, the symmetric dense stage and the soft rounds
//! ([`polish`], [`symmetrise`], [`soften`]); the common offset along the rays ([`fit_offset`]); the
//! inliers re-selected with the noise model
//! ([`reselect`]); and the alternatives the ambiguity gate compares the winner with ([`finish`]).

use super::offset::RaySide;
use super::prepared::{DenseSets, PairContext};
use super::ransac::Screened;
use super::{
    PointSet2, RegistrationConfig, RegistrationDetail, RegistrationError, RegistrationResult,
    correlative, covariance_ros_from_se2, dense, lm, offset, ransac, robust,
};
use crate::math::{Iso2, Mat2, Mat3, Vec2, Vec3, se2_exp, se2_log};

/// The winner `d` finished (polished, symmetrised, softened) and its alternatives: the other refined
/// alignments, and the screened motions that were not refined, by their coverage relative to the
/// winner's (a street slid along itself by metres covers the same cells).
pub fn finish(
    ctx: &PairContext<'_>,
    d: RegistrationDetail,
    refined: &[(Iso2, f64)],
    screened: &Screened,
) -> RegistrationDetail {
    let cfg = ctx.cfg;
    let d = polish(ctx, d);
    let d = symmetrise(ctx, d);
    let d = soften(ctx, d);
    let d = probe_bias(ctx, d);
    let d = probe_score(ctx, d);
    let mut d = fit_offset(ctx, d);
    let win = d.result.t_target_source;
    let far = |t: &Iso2| !cfg.same_alignment(&win, t);
    let mut alternatives: Vec<(Iso2, f64)> =
        refined.iter().filter(|(t, _)| far(t)).copied().collect();
    let sets = &ctx.sets;
    let win_cov = sets.coverage.count(sets.probes, &win).max(1);
    let overlap = d.result.overlap;
    alternatives.extend(
        screened
            .iter()
            .filter(|(_, h)| {
                (win.inverse() * h.t_target_source)
                    .translation
                    .vector
                    .norm()
                    > cfg.screen_ambiguity_translation
            })
            .map(|(c, h)| {
                let scaled = overlap * (*c as f64 / win_cov as f64).min(1.0);
                (h.t_target_source, scaled)
            }),
    );
    d.result.runner_up_overlap = alternatives.iter().map(|a| a.1).fold(0.0, f64::max);
    d.result.alternatives = alternatives;
    d
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
    /// The covariance comes from the dense pairs ([`correlative::CorrelativeConfig::covariance_scale`])
    /// instead of the descriptor inliers.
    pub(super) dense_covariance: bool,
}

impl Fit {
    /// The winner `best` moved to `t` by a finishing step (polishing, the symmetric stage, the soft
    /// rounds) that took `iterations` more. The overlap and fit scores stay those the hypotheses
    /// competed with (all refined alike), so that the ambiguity gate compares like with like: a
    /// finishing step changes the pose and its covariance only.
    pub(super) fn finishing(
        best: &RegistrationDetail,
        t: Iso2,
        converged: bool,
        cost: f64,
        iterations: usize,
        dense_settled: Option<bool>,
    ) -> Fit {
        Fit {
            t_target_source: t,
            converged,
            cost,
            iterations: best.result.iterations + iterations,
            dense_settled,
            overlap: Some(best.result.overlap),
            score: Some((best.score, best.plain_score)),
            dense_covariance: best.dense_covariance,
        }
    }
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
        if cfg.selection_sigma > 0.0 {
            dense::fit_score(
                src,
                Some(weights),
                tgt,
                tree,
                &fit.t_target_source,
                cfg.selection_sigma,
            )
        } else {
            (overlap, overlap)
        }
    });
    // Covariance at the optimum; also refuses an unobservable pose (singular information).
    let covariance_se2 = if fit.dense_covariance {
        let dense_pairs = dense::associate(src, tgt, tree, &fit.t_target_source, &cfg.dense);
        let labels =
            correlative::cluster_labels(src, &dense_pairs, cfg.correlative.covariance_cluster);
        lm::covariance_clustered(
            &fit.t_target_source,
            src,
            tgt,
            &dense_pairs,
            &labels,
            &cfg.lm,
        )? * cfg.correlative.covariance_scale
    } else {
        let covariance = lm::covariance_at(&fit.t_target_source, source, target, &pairs, &cfg.lm)?;
        let scale = if fit.dense_settled.is_some() {
            cfg.covariance_scale * cfg.dense.covariance_scale
        } else {
            cfg.covariance_scale
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

/// The winning hypothesis's dense rounds continued, accelerated ([`dense::Rounds::Accelerated`]), when they
/// had not settled (`registration.dense.polish_rounds`, off by default: see there); its covariance at
/// the polished pose. Kept as it was when polishing fails (too few pairs, a numerical failure).
pub(super) fn polish(ctx: &PairContext<'_>, best: RegistrationDetail) -> RegistrationDetail {
    let PairContext { sets, cfg, .. } = *ctx;
    if best.dense_settled != Some(false) || cfg.dense.polish_rounds == 0 {
        return best;
    }
    let DenseSets { src, tgt, tree, .. } = sets;
    let r = &best.result;
    let refined = dense::refine_dense(
        src,
        tgt,
        tree,
        &r.t_target_source,
        &cfg.dense,
        &cfg.lm,
        dense::Rounds::Accelerated,
    );
    let Ok(Some(d)) = refined else {
        return best;
    };
    let fit = Fit::finishing(
        &best,
        d.t_target_source,
        d.converged,
        d.cost,
        d.iterations,
        Some(d.settled),
    );
    reconclude(ctx, best, fit)
}

/// `best` with its pose replaced by `fit`'s and its covariance taken there (same inliers, RANSAC
/// estimate and draws); `best` as it was when that fails.
fn reconclude(ctx: &PairContext<'_>, best: RegistrationDetail, fit: Fit) -> RegistrationDetail {
    let inliers = best.inliers.clone();
    match conclude(ctx, inliers, best.t_ransac, fit) {
        Ok(mut out) => {
            out.ransac_iterations = best.ransac_iterations;
            out
        }
        Err(_) => best,
    }
}

/// The winner's pose finished by the soft rounds (`registration.dense.soft_rounds`), when the dense
/// stage ran; its covariance at the new pose. Kept as it was when they fail or end farther from it
/// than the ambiguity distances (then they found another alignment, not the last centimetres).
pub(super) fn soften(ctx: &PairContext<'_>, best: RegistrationDetail) -> RegistrationDetail {
    let PairContext { sets, cfg, .. } = *ctx;
    if !cfg.dense.enabled || cfg.dense.soft_rounds == 0 || best.dense_settled.is_none() {
        return best;
    }
    let r = &best.result;
    let soft = dense::soften(
        sets.src,
        sets.tgt,
        sets.tree,
        &r.t_target_source,
        &cfg.dense,
        &cfg.lm,
    );
    let Ok(Some(d)) = soft else {
        return best;
    };
    if !cfg.same_alignment(&r.t_target_source, &d.t_target_source) {
        return best;
    }
    let fit = Fit::finishing(
        &best,
        d.t_target_source,
        d.converged,
        d.cost,
        d.iterations,
        best.dense_settled,
    );
    reconclude(ctx, best, fit)
}

/// The winner's pose averaged with the dense stage run the other way round (the target's points
/// paired with their nearest source points, from the inverse of the winner's pose), when
/// `registration.dense.symmetric` is on and the dense stage ran; its covariance at the averaged pose.
/// Nearest-neighbour pairs join a point of one pass with the nearest sample of the other, so each
/// direction carries its own association bias; the two directions' estimates differ by that and
/// their mean halves what they do not share (see `DenseConfig::symmetric` for the measurements).
/// Kept as it was when the reverse stage fails or ends farther apart than the ambiguity distances
/// (then the two directions disagree about the alignment, not its last centimetres).
pub(super) fn symmetrise(ctx: &PairContext<'_>, best: RegistrationDetail) -> RegistrationDetail {
    let cfg = ctx.cfg;
    if !(cfg.dense.enabled && cfg.dense.symmetric) || best.dense_settled.is_none() {
        return best;
    }
    let r = &best.result;
    let forward = r.t_target_source;
    let Some((backward, rev)) = reverse_dense(ctx, &forward) else {
        return best;
    };
    if !cfg.same_alignment(&forward, &backward) {
        return best;
    }
    let rel = forward.inverse() * backward;
    let mean = Iso2::new(
        0.5 * (forward.translation.vector + backward.translation.vector),
        forward.rotation.angle() + 0.5 * rel.rotation.angle(),
    );
    let fit = Fit::finishing(
        &best,
        mean,
        r.converged && rev.converged,
        r.cost,
        rev.iterations,
        best.dense_settled.map(|s| s && rev.settled),
    );
    reconclude(ctx, best, fit)
}

/// The winner's covariance widened by the association bias the pairs cannot show, when
/// `registration.dense.bias_probe` is on and the dense stage ran.
///
/// Nearest-neighbour pairs join a point of one pass with the nearest sample of the other, so the
/// dense estimate carries a bias `b_f` that the pairs' scatter does not reveal (along a flat wall it
/// is as large as the spacing of the samples). The same stage run the other way round (the target's
/// points paired with their nearest source points, from the inverse pose) carries its own bias `b_b`.
/// With the two biases independent and alike (covariance `B`), their difference `d = b_b - b_f`
/// has `E[d d^T] = 2 B`, so `d d^T / 2` is an unbiased one-sample estimate of the forward estimate's
/// bias covariance, and is added to it: large along the direction in which the two directions of
/// association disagree, nothing across it. The pose stays the forward estimate. A reverse stage that
/// fails leaves the covariance as it was.
pub(super) fn probe_bias(ctx: &PairContext<'_>, best: RegistrationDetail) -> RegistrationDetail {
    let cfg = ctx.cfg;
    if !(cfg.dense.enabled && cfg.dense.bias_probe) || best.dense_settled.is_none() {
        return best;
    }
    let forward = best.result.t_target_source;
    let Some((backward, _)) = reverse_dense(ctx, &forward) else {
        return best;
    };
    let d = se2_log(&(forward.inverse() * backward));
    widen(best, 0.5 * d * d.transpose())
}

/// The winner fitted once more with a common offset of the returns along their rays
/// ([`offset::fit_offset`], `registration.dense.range_offset_std`), when the dense stage ran and both
/// submaps' rays are known: at its dense pairs, the pose takes the joint step where the pair shows an
/// offset at the 5 % level, and the offset's prior widens the covariance along the direction it moves
/// the pose (a consider parameter, [`offset`]). A fit that fails leaves the winner as it was.
pub(super) fn fit_offset(ctx: &PairContext<'_>, best: RegistrationDetail) -> RegistrationDetail {
    let PairContext { sets, cfg, .. } = *ctx;
    let (src, tgt) = (sets.src, sets.tgt);
    let known = |s: &PointSet2| !s.is_empty() && s.rays.len() == s.len();
    if cfg.dense.range_offset_std <= 0.0
        || best.dense_settled.is_none()
        || !(known(src) && known(tgt))
    {
        return best;
    }
    let t = best.result.t_target_source;
    let pairs = dense::associate(src, tgt, sets.tree, &t, &cfg.dense);
    fn side(s: &PointSet2) -> RaySide<'_> {
        RaySide {
            points: &s.points,
            covs: &s.covs,
            rays: &s.rays,
        }
    }
    let Some(f) = offset::fit_offset(
        &t,
        &side(src),
        &side(tgt),
        &pairs,
        &cfg.lm,
        cfg.dense.range_offset_std,
    ) else {
        return best;
    };
    log::debug!(
        "common offset along the rays {:+.3} +- {:.3} m over {} pairs{}",
        f.offset,
        f.variance.sqrt(),
        pairs.len(),
        if f.significant() { ", taken" } else { "" }
    );
    let mut best = best;
    if f.significant() {
        best.result.t_target_source = t * se2_exp(&f.step);
    }
    widen(best, f.covariance(cfg.dense.range_offset_std))
}

/// `best` with `c` over `(x, y, yaw)` added to its covariance, in both of its forms.
fn widen(mut best: RegistrationDetail, c: Mat3) -> RegistrationDetail {
    best.covariance_se2 += c;
    best.result.covariance = covariance_ros_from_se2(&best.covariance_se2);
    best
}

/// The winner's covariance widened by the pull of the objects that gave many points, when
/// `registration.dense.score_probe` is on and the dense stage ran.
///
/// The dense stage weighs every point alike, so a facade or a row of parked cars that gave hundreds
/// of detections pulls its pose where they outnumber the poles and corners; the fit score that picks
/// the winner ([`dense::fit_score`], `selection_sigma`) weighs every object alike
/// (`selection_object_radius`). The nearest local maximum of the fit score is a second estimate of
/// the same translation whose error comes from other points. With the two errors independent and
/// alike (covariance `P`), the translation `p` from the dense pose to that maximum has
/// `E[p p^T] = 2 P`, so `p p^T / 2` is added, as for the association bias. The pose stays the dense
/// estimate: where the points are few the fit score's maximum is the noisier of the two.
pub(super) fn probe_score(
    ctx: &PairContext<'_>,
    mut best: RegistrationDetail,
) -> RegistrationDetail {
    let cfg = ctx.cfg;
    if !(cfg.dense.enabled && cfg.dense.score_probe)
        || cfg.selection_sigma <= 0.0
        || best.dense_settled.is_none()
    {
        return best;
    }
    let DenseSets {
        src,
        weights,
        tgt,
        tree,
        ..
    } = ctx.sets;
    let p = dense::score_peak(
        src,
        weights,
        tgt,
        tree,
        &best.result.t_target_source,
        cfg.selection_sigma,
        cfg.ambiguity_translation,
    );
    best.result.score_share = 0.5 * p * p.transpose();
    let share = best.result.score_share;
    widen(best, share)
}

/// The dense stage run the other way round from `forward` (the target's points paired with their
/// nearest source points, from the inverse pose): the source-in-target pose it ends at, and its
/// result; `None` when it fails.
fn reverse_dense(ctx: &PairContext<'_>, forward: &Iso2) -> Option<(Iso2, dense::DenseResult)> {
    let PairContext { sets, cfg, .. } = *ctx;
    let rev = dense::refine_dense(
        sets.tgt_as_source,
        sets.src_as_target,
        sets.src_tree,
        &forward.inverse(),
        &cfg.dense,
        &cfg.lm,
        dense::Rounds::Plain,
    )
    .ok()??;
    Some((rev.t_target_source.inverse(), rev))
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

/// Candidates within `reselect_gate` sigma of `t` (LM weights), one per source point (the closest),
/// as ascending indices into `candidates`.
pub(super) fn reselect(ctx: &PairContext<'_>, t: &Iso2) -> Vec<usize> {
    let PairContext {
        source,
        target,
        candidates,
        cfg,
        ..
    } = *ctx;
    let gate2 = cfg.reselect_gate * cfg.reselect_gate;
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
