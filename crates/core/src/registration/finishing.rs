//! Stage 5 of a registration, the winner's pose finished: its unsettled dense rounds polished
//! ([`polish`]), averaged with the dense stage run the other way round ([`symmetrise`]), and the soft
//! rounds ([`soften`]); its covariance taken again at the finished pose.

use super::dense;
use super::prepared::{DenseSets, PairContext};
use super::refine::{Fit, conclude};
use super::types::RegistrationDetail;
use crate::math::Iso2;

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

/// The dense stage run the other way round from `forward` (the target's points paired with their
/// nearest source points, from the inverse pose): the source-in-target pose it ends at, and its
/// result; `None` when it fails.
pub(super) fn reverse_dense(
    ctx: &PairContext<'_>,
    forward: &Iso2,
) -> Option<(Iso2, dense::DenseResult)> {
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

impl Fit {
    /// The winner `best` moved to `t` by a finishing step (polishing, the symmetric stage, the soft
    /// rounds) that took `iterations` more. The overlap and fit scores stay those the hypotheses
    /// competed with (all refined alike), so that the ambiguity gate compares like with like: a
    /// finishing step changes the pose and its covariance only.
    fn finishing(
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
