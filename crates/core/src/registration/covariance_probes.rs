//! Stage 6 of a registration, what widens the winner's covariance beyond the scatter of its pairs:
//! the association bias ([`probe_bias`]), the pull of the objects that gave many points
//! ([`probe_score`]), and a common offset of the returns along their rays ([`fit_offset`]).

use super::finishing::reverse_dense;
use super::offset::{self, RaySide};
use super::prepared::{DenseSets, PairContext};
use super::types::{PointSet2, RegistrationDetail, covariance_ros_from_se2};
use super::{dense, ransac};
use crate::math::{Mat3, se2_exp, se2_log};

/// The winner's covariance widened by the association bias the pairs cannot show, when
/// `registration.dense.bias_probe` is on and the dense stage ran.
///
/// Nearest-neighbour pairs join a point of one pass with the nearest sample of the other, so the
/// dense estimate carries a bias `b_f` that the pairs' scatter does not reveal (along a flat wall
/// it is as large as the spacing of the samples). The same stage run the other way round (the
/// target's points paired with their nearest source points, from the inverse pose) carries its own
/// bias `b_b`. With the two biases independent and alike (covariance `B`), their difference `d =
/// b_b - b_f` has `E[d d^T] = 2 B`, so `d d^T / 2` is an unbiased one-sample estimate of the
/// forward estimate's bias covariance, and is added to it: large along the direction in which the
/// two directions of association disagree, nothing across it. The pose stays the forward estimate.
/// A reverse stage that fails leaves the covariance as it was.
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

/// The winner's covariance widened by the pull of the objects that gave many points, when
/// `registration.dense.score_probe` is on and the dense stage ran.
///
/// The dense stage weighs every point alike, so a facade or a row of parked cars that gave hundreds
/// of detections pulls its pose where they outnumber the poles and corners; the fit score that
/// picks the winner ([`dense::fit_score`], [`dense::SELECTION_SIGMA`]) weighs every object alike
/// ([`dense::SELECTION_OBJECT_RADIUS`]). The nearest local maximum of the fit score is a second
/// estimate of the same translation whose error comes from other points. With the two errors
/// independent and alike (covariance `P`), the translation `p` from the dense pose to that maximum
/// has `E[p p^T] = 2 P`, so `p p^T / 2` is added, as for the association bias. The pose stays the
/// dense estimate: where the points are few the fit score's maximum is the noisier of the two.
pub(super) fn probe_score(
    ctx: &PairContext<'_>,
    mut best: RegistrationDetail,
) -> RegistrationDetail {
    let cfg = ctx.cfg;
    if !(cfg.dense.enabled && cfg.dense.score_probe) || best.dense_settled.is_none() {
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
        dense::SELECTION_SIGMA,
        ransac::AMBIGUITY_TRANSLATION,
    );
    best.result.score_share = 0.5 * p * p.transpose();
    let share = best.result.score_share;
    widen(best, share)
}

/// The winner fitted once more with a common offset of the returns along their rays
/// ([`offset::fit_offset`], `registration.dense.range_offset_std`), when the dense stage ran and
/// both submaps' rays are known: at its dense pairs, the pose takes the joint step where the pair
/// shows an offset at the 5 % level, and the offset's prior widens the covariance along the
/// direction it moves the pose (a consider parameter, [`offset`]). A fit that fails leaves the
/// winner as it was.
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
