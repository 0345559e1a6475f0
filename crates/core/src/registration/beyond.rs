//! Stage 4 of a registration, the search beyond the descriptors: when the descriptor stage found
//! nothing or a weak alignment won, the correlative search proposes poses, and a weak winner's
//! slides along its street (`correlative.slide_shifts`) compete too, each refined by the dense
//! stage.

use super::hypotheses::correlative_applies;
use super::prepared::{DenseSets, PairContext};
use super::refine::Refined;
use super::types::{PointSet2, RegistrationDetail};
use super::{correlative, dense};
use crate::math::{Iso2, Vec2};

/// The correlative search when the descriptor stage found nothing or little overlap, then a
/// weak winner's slides along its street (`correlative.slide_shifts`).
pub(super) fn search(refined: &mut Refined, ctx: &PairContext<'_>) {
    let cfg = ctx.cfg;
    if !correlative_applies(cfg) {
        return;
    }
    if refined.best.as_ref().is_none_or(|b| weak_result(b, ctx)) {
        refined.poses(ctx, &correlative_poses(&ctx.sets));
    }
    let weak_winner = refined
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
        refined.poses(ctx, &poses);
    }
}

/// The correlative search's candidate poses, scored where the votes put them (a cell and the
/// histogram's resolution off), best first.
fn correlative_poses(sets: &DenseSets<'_>) -> Vec<Iso2> {
    let found = correlative::candidates(sets.src_as_target, sets.src_tree, sets.tgt, sets.tree);
    let sigma = dense::SELECTION_SIGMA;
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
        .take(correlative::CANDIDATES)
        .map(|(_, pose)| pose)
        .collect()
}

/// A result searched beyond (`registration.correlative`): its plain fit score below
/// [`correlative::BELOW_SCORE`], and fewer than `below_inliers` descriptor inliers unless its plain
/// score is below [`correlative::RICH_BELOW_SCORE`] or its common view ([`common_view`]) below
/// [`correlative::BELOW_COMMON_VIEW`].
fn weak_result(d: &RegistrationDetail, ctx: &PairContext<'_>) -> bool {
    let (sets, cfg) = (&ctx.sets, ctx.cfg);
    d.plain_score < correlative::BELOW_SCORE
        && (d.result.inliers < cfg.correlative.below_inliers
            || d.plain_score < correlative::RICH_BELOW_SCORE
            || sets
                .bearings
                .0
                .common(sets.bearings.1, d.result.t_target_source.rotation.angle())
                < correlative::BELOW_COMMON_VIEW)
}
