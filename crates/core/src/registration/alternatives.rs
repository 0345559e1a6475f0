//! Stage 7 of a registration, the alternatives the ambiguity gate compares the winner with: the
//! other refined alignments, and the screened motions that were not refined, by their coverage
//! relative to the winner's (a street slid along itself by metres covers the same cells).

use super::prepared::PairContext;
use super::ransac::Screened;
use super::types::RegistrationDetail;

/// A screened motion farther than this from the result, m, whose coverage comes near the result's
/// is a runner-up alignment too: `runner_up_overlap` is at least the result's overlap times that
/// coverage ratio. Coarser than [`super::ransac::AMBIGUITY_TRANSLATION`] because coverage cannot
/// resolve less.
pub const SCREEN_AMBIGUITY_TRANSLATION: f64 = 3.0;
use crate::math::Iso2;

/// The winner `d` with its alternatives (farther than the ambiguity distances from it) and the best
/// of their overlaps, `runner_up_overlap`.
pub(super) fn attach(
    ctx: &PairContext<'_>,
    mut d: RegistrationDetail,
    refined: &[(Iso2, f64)],
    screened: &Screened,
) -> RegistrationDetail {
    let cfg = ctx.cfg;
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
                    > SCREEN_AMBIGUITY_TRANSLATION
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
