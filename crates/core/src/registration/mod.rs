//! Submap-to-submap registration: DC-Loc's association and uncertainty-aware optimisation.
//!
//! [`register_detailed`] runs the stages in order, each in its own module with its own settings
//! (sections of [`RegistrationConfig`]):
//! 1. matching: K nearest neighbours in descriptor space (RSD, [`descriptor`], [`matching`]);
//! 2. hypotheses: RANSAC's distinct supported motions ranked by geometric coverage ([`ransac`],
//!    `hypotheses`);
//! 3. refinement: LM on eq. 10 ([`lm`], with a [`robust`] loss), inliers re-selected with the noise
//!    model, the [`dense`] stage, and the covariance at the optimum (`refine`);
//! 4. beyond the descriptors: the [`correlative`] search and slides along the street when the
//!    winner is weak (`beyond`);
//! 5. finishing: the winner polished, symmetrised and softened (`finishing`);
//! 6. covariance probes: the association bias, the score's pull and a common [`offset`] along the
//!    rays widen the covariance (`covariance_probes`);
//! 7. alternatives: the other alignments and the runner-up overlap for the ambiguity gate
//!    (`alternatives`).
//!
//! Entry points: [`register`], [`register_prepared`] (on [`PreparedSubmap`]s, built once per
//! keyframe), [`register_detailed`] (with the correspondences and inliers) and
//! [`register_correspondences`] (stages 2-7 on given candidates, as the MC-RANSAC-style baseline
//! uses them). The types every method shares are in `types` ([`PointSet2`], [`RegistrationResult`],
//! [`RegistrationError`]); [`overlap_near`], [`slide_overlap`] and [`common_view`] probe other
//! alignments for the loop-closure gates.
//!
//! The source is the current (query) submap, the target the previous (match) one; docs/algorithm.md,
//! "Frames" and "Registration", has the naming, the covariance convention and each stage's detail.

mod alternatives;
mod bearings;
mod beyond;
mod config;
pub mod correlative;
mod covariance_probes;
pub mod dense;
pub mod descriptor;
mod finishing;
pub mod grid;
mod hypotheses;
pub mod lm;
pub mod matching;
pub mod offset;
mod prepared;
mod probes;
pub mod ransac;
mod refine;
pub mod robust;
mod types;

pub use config::RegistrationConfig;

/// The constants of the registration's own stages (those of the correlative search, the dense
/// stage, the descriptors and RANSAC are in their modules).
pub mod constants {
    pub use super::MIN_POINTS;
    pub use super::alternatives::SCREEN_AMBIGUITY_TRANSLATION;
    pub use super::refine::{COVARIANCE_SCALE, RESELECT_GATE};
}
pub use prepared::PreparedSubmap;
pub use probes::{SLIDE_SHIFTS, common_view, overlap_near, slide_overlap};
pub use types::{
    PointSet2, RegistrationDetail, RegistrationError, RegistrationResult, UNOBSERVED_VARIANCE,
    covariance_ros_from_se2, covariance_se2_from_ros,
};

use prepared::{DenseSets, DenseSide, PairContext, check_point_set, checked_config};

/// DC-Loc registration of the current submap (`source`) against a previous one (`target`).
///
/// Prepares both (descriptors) and runs [`register_prepared`]. When the target is a keyframe
/// matched many times, prepare it once with [`PreparedSubmap::new`] instead.
pub fn register(
    source: &PointSet2,
    target: &PointSet2,
    cfg: &RegistrationConfig,
) -> Result<RegistrationResult, RegistrationError> {
    check_sizes(source.len(), target.len())?;
    let s = PreparedSubmap::new(source.clone(), cfg)?;
    let t = PreparedSubmap::new(target.clone(), cfg)?;
    register_prepared(&s, &t, cfg)
}

/// As [`register`], on prepared submaps.
pub fn register_prepared(
    source: &PreparedSubmap,
    target: &PreparedSubmap,
    cfg: &RegistrationConfig,
) -> Result<RegistrationResult, RegistrationError> {
    register_detailed(source, target, cfg).map(|d| d.result)
}

/// Fewest points a submap must have for a registration.
pub const MIN_POINTS: usize = 10;

fn check_sizes(ns: usize, nt: usize) -> Result<(), RegistrationError> {
    for have in [ns, nt] {
        if have < MIN_POINTS {
            return Err(RegistrationError::TooFewPoints {
                have,
                need: MIN_POINTS,
            });
        }
    }
    Ok(())
}

/// DC-Loc registration of prepared submaps, the stages in order (module docs).
pub fn register_detailed(
    source: &PreparedSubmap,
    target: &PreparedSubmap,
    cfg: &RegistrationConfig,
) -> Result<RegistrationDetail, RegistrationError> {
    checked_config(cfg)?;
    check_sizes(source.points().len(), target.points().len())?;
    if !source.fits(cfg) || !target.fits(cfg) {
        return Err(RegistrationError::Numerical(
            "submaps were prepared with other descriptor, matching or dense-stage settings than `cfg`"
                .into(),
        ));
    }
    // 1. Matching.
    let candidates = descriptor_candidates(source, target, cfg);
    let sets = DenseSets::new(source.dense(), target.dense());
    register_pair(source.points(), target.points(), sets, candidates, cfg)
}

/// Stages 2-7 on given candidate correspondences (everything after the matching; also what a
/// baseline with its own association reuses).
pub fn register_correspondences(
    source: &PointSet2,
    target: &PointSet2,
    candidates: Vec<ransac::Correspondence>,
    cfg: &RegistrationConfig,
) -> Result<RegistrationDetail, RegistrationError> {
    checked_config(cfg)?;
    check_sizes(source.len(), target.len())?;
    check_point_set(source)?;
    check_point_set(target)?;
    let (src, tgt) = (DenseSide::new(source, cfg)?, DenseSide::new(target, cfg)?);
    let sets = DenseSets::new(&src, &tgt);
    register_pair(source, target, sets, candidates, cfg)
}

/// Stage 1: K nearest neighbours in descriptor space for a bounded set of the source's keypoints,
/// as point indices of the two submaps.
fn descriptor_candidates(
    source: &PreparedSubmap,
    target: &PreparedSubmap,
    cfg: &RegistrationConfig,
) -> Vec<ransac::Correspondence> {
    let queries = matching::select_queries(
        source.keypoints().len(),
        cfg.matching.max_queries,
        cfg.ransac.seed,
    );
    let mut candidates = matching::match_descriptors(
        source.descriptors(),
        &queries,
        target.index(),
        &cfg.matching,
    );
    // Keypoint slots -> point indices.
    for c in &mut candidates {
        c.source = source.keypoints()[c.source as usize];
        c.target = target.keypoints()[c.target as usize];
    }
    candidates
}

/// Stages 2-7 over one pair.
fn register_pair(
    source: &PointSet2,
    target: &PointSet2,
    sets: DenseSets<'_>,
    candidates: Vec<ransac::Correspondence>,
    cfg: &RegistrationConfig,
) -> Result<RegistrationDetail, RegistrationError> {
    let ctx = PairContext {
        source,
        target,
        sets,
        candidates: &candidates,
        cfg,
    };
    // 2. Hypotheses: RANSAC's distinct supported motions, ranked by how much of the target they cover.
    let screened = hypotheses::screen(&ctx)?;
    // 3. Refinement: the best hypotheses by LM on eq. 10, inlier re-selection and the dense stage.
    let mut refined = refine::Refined::default();
    refined.hypotheses(&ctx, &screened);
    // 4. Beyond the descriptors: the correlative search's poses and a weak winner's slides compete.
    beyond::search(&mut refined, &ctx);
    let Some(best) = refined.best else {
        return Err(refined
            .first_error
            .unwrap_or(RegistrationError::TooFewInliers {
                have: 0,
                need: cfg.min_inliers,
            }));
    };
    // 5. Finishing: the winner's pose polished, symmetrised and softened.
    let best = finishing::polish(&ctx, best);
    let best = finishing::symmetrise(&ctx, best);
    let best = finishing::soften(&ctx, best);
    // 6. Covariance probes: the association bias, the score's pull, an offset along the rays.
    let best = covariance_probes::probe_bias(&ctx, best);
    let best = covariance_probes::probe_score(&ctx, best);
    let best = covariance_probes::fit_offset(&ctx, best);
    // 7. Alternatives for the ambiguity gate.
    let mut d = alternatives::attach(&ctx, best, &refined.all, &screened);
    d.candidates = candidates;
    d.result.candidates = d.candidates.len();
    Ok(d)
}
