//! Submap-to-submap registration: DC-Loc's association and uncertainty-aware optimisation.
//!
//! Entry points: [`PointSet2`] (points with 2x2 covariances, the input of every method),
//! [`RegistrationResult`] (output of every method, DC-Loc and baselines alike), [`RegistrationError`],
//! [`covariance_ros_from_se2`]; DC-Loc itself: [`RegistrationConfig`], [`PreparedSubmap`] (a submap
//! with its keypoint descriptors and their index, built once per keyframe), [`register`] /
//! [`register_prepared`] (descriptors -> KNN -> RANSAC -> LM -> inlier re-selection -> LM ->
//! covariance), [`register_detailed`] (the same, with the correspondences and inliers) and
//! [`register_correspondences`] (everything after association, on given candidates). The steps are
//! public for reuse (e.g. by the MC-RANSAC-style baseline): [`descriptor`] (RSD), [`matching`]
//! (KNN), [`ransac`], [`lm`] (eq. 10 and the covariance), [`robust`].
//! Naming: the *source* is the current (query) submap X, the *target* the previous (match) submap Y;
//! `t_target_source` maps source coordinates into the target frame (paper: `T_b^p`), `d_i = y_i - T x_i`.
//! Pose covariances are over `delta = (x, y, theta)` with `T_true = T_est * Exp(delta)` (right
//! perturbation in the source body frame, GTSAM `Pose2` convention) before the ROS reordering.

mod bearings;
mod config;
pub mod correlative;
pub mod dense;
pub mod descriptor;
mod finishing;
pub mod grid;
pub mod lm;
pub mod matching;
pub mod offset;
mod prepared;
mod probes;
pub mod ransac;
pub mod robust;
mod search;

pub use config::RegistrationConfig;
pub use prepared::PreparedSubmap;
pub use probes::{SLIDE_SHIFTS, common_view, overlap_near, slide_overlap};

use crate::math::{Iso2, Mat2, Mat3, Mat6, Vec2};
use prepared::{DenseSets, DenseSide, PairContext, check_point_set, checked_config};

/// Variance (m^2 or rad^2) reported for the axes a planar registration does not observe (z, roll, pitch).
///
/// Large enough that a pose-graph back end gives those axes no weight, small enough to stay finite in
/// single precision after inversion: 1e6 (a 1 km / 1000 rad standard deviation).
pub const UNOBSERVED_VARIANCE: f64 = 1e6;

/// A planar point set with per-point covariances (m^2), in one submap frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointSet2 {
    /// Point positions, m.
    pub points: Vec<Vec2>,
    /// One covariance per point (symmetric positive definite), m^2.
    pub covs: Vec<Mat2>,
    /// Per point, the unit planar direction of the ray from the radar that saw it, in the same
    /// frame; empty when not known (the common offset along the rays is then not estimated,
    /// [`offset`]).
    pub rays: Vec<Vec2>,
}

impl PointSet2 {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }
    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
    /// Points with an isotropic covariance `sigma^2 I`.
    pub fn isotropic(points: Vec<Vec2>, sigma: f64) -> Self {
        let covs = vec![Mat2::identity() * sigma * sigma; points.len()];
        PointSet2 {
            points,
            covs,
            rays: Vec::new(),
        }
    }
}

/// What a registration method returns.
#[derive(Debug, Clone, PartialEq)]
pub struct RegistrationResult {
    /// Source (current) frame in the target (previous) frame.
    pub t_target_source: Iso2,
    /// Covariance of `t_target_source`, 6x6 in ROS order (x, y, z, rot x, rot y, rot z), row-major when
    /// flattened; unobserved axes carry [`UNOBSERVED_VARIANCE`].
    pub covariance: Mat6,
    /// The optimiser met its convergence criterion (not just the iteration limit).
    pub converged: bool,
    /// Optimiser iterations used.
    pub iterations: usize,
    /// Correspondences kept as inliers at the end.
    pub inliers: usize,
    /// Candidate correspondences before outlier rejection.
    pub candidates: usize,
    /// Final cost (method specific; lower is better).
    pub cost: f64,
    /// Share of source points with a partner in the target at the final pose (0..1), a geometric check
    /// of the alignment independent of the descriptors (DC-Loc: nearest neighbours inside the dense
    /// stage's gates; ICP: pairs within the last distance; NDT: points scored by a cell).
    pub overlap: f64,
    /// Overlap of the best other alignment (a refined RANSAC hypothesis farther than
    /// `ambiguity_translation` / `ambiguity_rotation` from the result), 0 when there was none: close to
    /// `overlap` means the scene aliases (a street sliding along itself) and the result may be the
    /// wrong one of two. Only DC-Loc registration fills it; the baselines report 0.
    pub runner_up_overlap: f64,
    /// The other alignments behind `runner_up_overlap`, each with the overlap it counts with (a refined
    /// hypothesis: its own; a screened motion: the result's overlap scaled by its coverage ratio):
    /// a prior (an accepted alignment of the session) can tell them from the result where the
    /// submaps alone cannot. Empty for the baselines.
    pub alternatives: Vec<(Iso2, f64)>,
    /// The share of `covariance` over `(x, y, theta)` that the score probe added
    /// (`registration.dense.score_probe`): the pull of the objects that gave many points. The loop
    /// closure gates judge the registration without it; published closures carry it. Zero for the
    /// baselines and without the probe.
    pub score_share: Mat3,
}

/// Why a registration produced no result.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RegistrationError {
    /// A point set is too small for the method.
    #[error("too few points: {have} (need at least {need})")]
    TooFewPoints {
        /// Points available.
        have: usize,
        /// Points needed.
        need: usize,
    },
    /// Outlier rejection left too few correspondences.
    #[error("too few inlier correspondences: {have} (need at least {need})")]
    TooFewInliers {
        /// Inliers found.
        have: usize,
        /// Inliers needed.
        need: usize,
    },
    /// The optimisation produced a non-finite or singular result.
    #[error("optimisation failed: {0}")]
    Numerical(String),
}

/// Embeds a planar covariance over (x, y, theta) into the 6x6 ROS-order covariance
/// (x, y, z, rot x, rot y, rot z); z, roll and pitch get [`UNOBSERVED_VARIANCE`] and no correlation.
pub fn covariance_ros_from_se2(cov_xy_theta: &Mat3) -> Mat6 {
    let mut c = Mat6::zeros();
    let idx = [0usize, 1, 5];
    for (i, &a) in idx.iter().enumerate() {
        for (j, &b) in idx.iter().enumerate() {
            c[(a, b)] = cov_xy_theta[(i, j)];
        }
    }
    for k in [2usize, 3, 4] {
        c[(k, k)] = UNOBSERVED_VARIANCE;
    }
    c
}

/// The planar block `(x, y, yaw)` of a 6x6 covariance in ROS order (rows and columns 0, 1, 5): the
/// inverse of [`covariance_ros_from_se2`] on what it embeds.
pub fn covariance_se2_from_ros(cov: &Mat6) -> Mat3 {
    let idx = [0usize, 1, 5];
    Mat3::from_fn(|i, j| cov[(idx[i], idx[j])])
}

/// Everything [`register_detailed`] found, for evaluation and plots.
#[derive(Debug, Clone, PartialEq)]
pub struct RegistrationDetail {
    /// The result as every method reports it.
    pub result: RegistrationResult,
    /// 3x3 covariance over `(x, y, theta)`, `T_true = T_est * Exp(delta)` (including
    /// `covariance_scale`).
    pub covariance_se2: Mat3,
    /// Candidate correspondences from descriptor matching.
    pub candidates: Vec<ransac::Correspondence>,
    /// Indices into `candidates` of the RANSAC inliers that went into LM.
    pub inliers: Vec<usize>,
    /// The RANSAC estimate (LM's initial guess).
    pub t_ransac: Iso2,
    /// RANSAC draws.
    pub ransac_iterations: usize,
    /// `None` when the dense stage did not run; else whether its last round moved the pose less than
    /// its stopping step.
    pub dense_settled: Option<bool>,
    /// The fit score the hypotheses competed with ([`dense::fit_score`], each point weighted by
    /// `registration.selection_object_radius`).
    pub score: f64,
    /// The same with every point weighing alike: what `correlative.below_score` compares.
    pub plain_score: f64,
    /// The covariance came from the dense pairs (an alignment of the correlative search that too few
    /// descriptor pairs agree with), not from the descriptor inliers.
    pub dense_covariance: bool,
}

/// DC-Loc registration of the current submap (`source`) against a previous one (`target`).
///
/// Prepares both (descriptors) and runs [`register_prepared`]. When the target is a keyframe matched
/// many times, prepare it once with [`PreparedSubmap::new`] instead.
pub fn register(
    source: &PointSet2,
    target: &PointSet2,
    cfg: &RegistrationConfig,
) -> Result<RegistrationResult, RegistrationError> {
    check_sizes(source.len(), target.len(), cfg)?;
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

fn check_sizes(ns: usize, nt: usize, cfg: &RegistrationConfig) -> Result<(), RegistrationError> {
    let need = cfg.min_points.max(2);
    for have in [ns, nt] {
        if have < need {
            return Err(RegistrationError::TooFewPoints { have, need });
        }
    }
    Ok(())
}

/// The DC-Loc pipeline, steps in order: KNN in descriptor space -> RANSAC -> geometry check ->
/// LM on eq. 10 -> covariance.
pub fn register_detailed(
    source: &PreparedSubmap,
    target: &PreparedSubmap,
    cfg: &RegistrationConfig,
) -> Result<RegistrationDetail, RegistrationError> {
    checked_config(cfg)?;
    check_sizes(source.points().len(), target.points().len(), cfg)?;
    if !source.fits(cfg) || !target.fits(cfg) {
        return Err(RegistrationError::Numerical(
            "submaps were prepared with other descriptor, matching or dense-stage settings than `cfg`"
                .into(),
        ));
    }
    // 1. Coarse association: K nearest neighbours in descriptor space (RSD), for a bounded set of
    //    source points.
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
    // 2.-5. RANSAC, screening, refinement, the search beyond the descriptors, finishing.
    let sets = DenseSets::new(source.dense(), target.dense());
    search_and_finish(source.points(), target.points(), sets, candidates, cfg)
}

/// RANSAC + LM on given candidate correspondences (the part of the pipeline after association;
/// also what a baseline with its own association reuses):
/// 2. RANSAC on a planar rigid motion removes the false matches;
/// 3. inliers on a line (or a point) are refused (`min_inlier_spread`);
/// 4. LM on eq. (10) from the RANSAC estimate;
/// 5. inlier re-selection: the candidates within `reselect_gate` (Mahalanobis, with the LM weights)
///    of the LM estimate become the inliers and LM runs again, up to `reselect_rounds` times. RANSAC's
///    metric threshold cuts far points, whose noise is larger, and keeps residuals that agree with its
///    own noisy estimate; re-selecting with the noise model removes that bias. A re-selection that
///    leaves fewer than `min_inliers` (or collinear ones) is not taken: descriptor pairs join different
///    samples of a surface, so the noise model can refuse most of a true alignment's pairs; the RANSAC
///    inliers stay.
pub fn register_correspondences(
    source: &PointSet2,
    target: &PointSet2,
    candidates: Vec<ransac::Correspondence>,
    cfg: &RegistrationConfig,
) -> Result<RegistrationDetail, RegistrationError> {
    checked_config(cfg)?;
    check_sizes(source.len(), target.len(), cfg)?;
    check_point_set(source)?;
    check_point_set(target)?;
    let (src, tgt) = (DenseSide::new(source, cfg)?, DenseSide::new(target, cfg)?);
    let sets = DenseSets::new(&src, &tgt);
    search_and_finish(source, target, sets, candidates, cfg)
}

/// Steps 2-6 over one pair: screening, refinement, the search beyond the descriptors, and the
/// winner's finishing steps ([`search`], [`finishing`]).
fn search_and_finish(
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
    let screened = search::screen(&ctx)?;
    let mut refined = search::Refined::default();
    refined.hypotheses(&ctx, &screened);
    refined.beyond_descriptors(&ctx);
    let Some(best) = refined.best else {
        return Err(refined
            .first_error
            .unwrap_or(RegistrationError::TooFewInliers {
                have: 0,
                need: cfg.min_inliers,
            }));
    };
    let mut d = finishing::finish(&ctx, best, &refined.all, &screened);
    d.candidates = candidates;
    d.result.candidates = d.candidates.len();
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros_order_puts_yaw_last() {
        let c = Mat3::new(1.0, 2.0, 3.0, 2.0, 4.0, 5.0, 3.0, 5.0, 6.0);
        let r = covariance_ros_from_se2(&c);
        assert_eq!(r[(0, 0)], 1.0);
        assert_eq!(r[(0, 1)], 2.0);
        assert_eq!(r[(0, 5)], 3.0);
        assert_eq!(r[(5, 0)], 3.0);
        assert_eq!(r[(1, 5)], 5.0);
        assert_eq!(r[(5, 5)], 6.0);
        assert_eq!(r[(2, 2)], UNOBSERVED_VARIANCE);
        assert_eq!(r[(3, 3)], UNOBSERVED_VARIANCE);
        assert_eq!(r[(4, 4)], UNOBSERVED_VARIANCE);
        assert_eq!(r[(2, 5)], 0.0);
        assert_eq!(r, r.transpose());
        assert_eq!(covariance_se2_from_ros(&r), c);
    }
}
