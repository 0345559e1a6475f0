//! Stage 2 of a registration, the hypotheses: RANSAC keeps up to `screened_hypotheses` distinct,
//! well-supported motions of the descriptor candidates, and the screening ranks them by geometry
//! (the coverage of the target by the motion's source probes): descriptor support does not tell a
//! street slid along itself from the true alignment, geometry does.

use super::config::RegistrationConfig;
use super::prepared::PairContext;
use super::ransac::{self, Screened};
use super::types::RegistrationError;

/// RANSAC and the screening: the supported motions ranked by coverage, best first. Empty when
/// RANSAC found nothing but the correlative search may still; an error when nothing can follow.
pub(super) fn screen(ctx: &PairContext<'_>) -> Result<Screened, RegistrationError> {
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
        translation: ransac::AMBIGUITY_TRANSLATION,
        rotation: ransac::AMBIGUITY_ROTATION,
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

/// The correlative search runs: enabled, and the dense stage it refines with is on.
pub(super) fn correlative_applies(cfg: &RegistrationConfig) -> bool {
    cfg.correlative.enabled && cfg.dense.enabled
}
