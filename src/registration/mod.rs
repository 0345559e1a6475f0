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

pub mod correlative;
pub mod dense;
pub mod descriptor;
pub mod grid;
pub mod lm;
pub mod matching;
pub mod ransac;
pub mod robust;

use crate::math::{Iso2, Mat2, Mat3, Mat6, Vec2, Vec3};
use crate::validate::{ConfigError, Validator};

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
        PointSet2 { points, covs }
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

/// All DC-Loc registration parameters; mirrors the `registration` section of the params YAML.
///
/// Defaults are written out on each field; [`RegistrationConfig::validate`] rejects (never clamps)
/// unusable values and names them as `registration.<section>.<field>`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RegistrationConfig {
    /// Fewest points a submap must have (default 10).
    pub min_points: usize,
    /// Fewest RANSAC inliers for a result (default 30). Two unrelated synthetic submaps of about
    /// 1000 points gave up to 18 coincidental inliers (facades line up by chance); true pairs give
    /// 100-250 with the default matching settings.
    pub min_inliers: usize,
    /// Smallest standard deviation of the inlier source points along their least-spread direction, m
    /// (default 1.0). Below it the inliers lie on a line (or a point): descriptor matches can slide
    /// along it, so the registration is refused rather than reported with a covariance that lies.
    pub min_inlier_spread: f64,
    /// After LM, candidates within this many sigma of the estimate (Mahalanobis with the LM weights)
    /// become the inliers, one per source and per target point, and LM runs again (default 3.5:
    /// 99.8 % of 2-D Gaussian residuals); see [`register_correspondences`]. Measured on the
    /// synthetic scenes (mean NEES of the pipeline, ideal 3, before `covariance_scale`): 13-20
    /// without the re-selection, 3.1-4.3 with it; keeping one pair per source point with the
    /// smallest residual instead (measured with 500 keypoints) gave 6.5-15.6.
    pub reselect_gate: f64,
    /// Rounds of that re-selection; 0 = off (default 2).
    pub reselect_rounds: usize,
    /// Factor on the reported covariance (default 1.3). LM's covariance is consistent when the
    /// correspondences are right (tests/registration.rs, `covariance_is_consistent`); descriptor
    /// association also accepts neighbouring reflectors within the gate, whose offsets bias the
    /// estimate beyond what the residual scatter shows. On the four synthetic scenarios of
    /// `examples/registration_variants.rs` the full pipeline's mean NEES was 3.1-4.3 (ideal 3)
    /// without this factor, 2.4-3.3 with 1.3. Set 1.0 for the bare estimator.
    pub covariance_scale: f64,
    /// Standard deviations added (as variances) to the reported covariance when the dense stage ran:
    /// `[translation m (each axis), rotation rad]` (default `[0.02, 0.0005]`; zeros = off). What the
    /// pair model leaves out does not shrink with more pairs: two passes sample each surface at
    /// different places and parked cars change between them, so the last centimetres of a dense
    /// alignment carry an error of their own that the pairs' scatter cannot show. Measured with
    /// `dc_loc eval -p "registration.covariance_floor:=[T,R]"` (mean NEES over the inliers, ideal 3)
    /// on the Gaussian / Gamma / Student-t / seed-2 demo drives: off 3.97 / 15.16 / 3.95 / 3.59;
    /// [0.02, 0.0005] 2.90 / 2.46 / 3.04 / 2.73; [0.03, 0.0005] 2.41 / 1.77 / 2.58 / 2.32; [0.03,
    /// 0.001] 2.25 / 1.47 / 2.43 / 2.13. No pose changes. The Gamma drive's errors are the smallest
    /// (0.044 m mean) but its NEES without the floor the largest: a few pairs off by a few
    /// milliradians with covariances of a tenth of that.
    pub covariance_floor: [f64; 2],
    /// RANSAC motions refined per registration (LM on their descriptor inliers, re-selection, dense
    /// stage), the one with the largest overlap kept (default 3). They are the best of the
    /// `screened_hypotheses` motions by coverage; one within `ambiguity_translation` /
    /// `ambiguity_rotation` of an alignment already refined is that alignment and is not refined again.
    pub hypotheses: usize,
    /// RANSAC motions kept for screening (default 32): the best-supported motions (each explaining at
    /// least `min_inliers` source points) that differ by more than the ambiguity distances. Each is
    /// scored by its coverage, the share of 256 source probes landing in target grid cells (1 m,
    /// widened by one cell), and the `hypotheses` with the largest coverage are refined. Descriptor
    /// support does not tell a street slid along itself, or another street, from the true alignment
    /// (on the demo drive's failed pairs the best RANSAC motion had 27-114 supporting points against
    /// the true motion's 6-70, `examples/pair_floor.rs`); geometry does. Measured with `dc_loc eval`
    /// on the demo drive, pairs inside 2 m: refining the best-supported motion and the best of what
    /// its inliers left (before) 80.5 %, 16 motions ranked by their dense-stage overlap instead of
    /// coverage (a slower variant not kept in the code) 91.1 %, 32 motions ranked by coverage 91.8 %
    /// (this).
    pub screened_hypotheses: usize,
    /// A screened motion farther than this from the result, m, whose coverage comes near the
    /// result's is a runner-up alignment too (default 3.0): `runner_up_overlap` is at least the
    /// result's overlap times that coverage ratio. Coarser than `ambiguity_translation` because
    /// coverage cannot resolve less (counting motions that differ in rotation only, as the refined
    /// runner-up does, refused a third of the true closures of tests/node.rs's drive). Measured with
    /// `dc_loc revisits` on the Gaussian and Student-t drives at 3 % drift: one radar, 47 false
    /// closures without it, 17 with it; five radars, none either way, same-direction recall 98.6-98.8 %
    /// without it, 96.1 % with it.
    pub screen_ambiguity_translation: f64,
    /// Two refined hypotheses farther apart than this, m, are different alignments for
    /// `runner_up_overlap` (default 1.0).
    pub ambiguity_translation: f64,
    /// The same in rotation, rad (default 0.05).
    pub ambiguity_rotation: f64,
    /// Dense refinement after the descriptor stage (default on): the descriptor pairs join different
    /// samples of the same surfaces, which leaves a bias of decimetres; re-associating every source point
    /// with its nearest target point under the current estimate and solving eq. 10 again removes it.
    pub dense: dense::DenseConfig,
    /// Width of the fit score that picks the winner among the refined hypotheses, m (default 0.35; 0 =
    /// the overlap instead): the mean over the source points of `exp(-d^2 / 2 sigma^2)`, `d` the
    /// distance to the nearest target point at the hypothesis ([`dense::fit_score`]).
    pub selection_sigma: f64,
    /// Radius of the objects the fit score counts once, m (default 2.5; 0 = every point counts
    /// once): each source point weighs 1 / (the source points near it, itself included;
    /// [`dense::object_weights`]), so that a pole or a building corner weighs as much as a parked car
    /// or a stretch of facade, whatever their numbers of detections. Two passes of a street see its
    /// facades, poles and corners again but not all its parked cars (the simulated city replaces or
    /// removes 45 % of them between laps, on a 6 m slot grid): counted by points, a street slid by a
    /// slot or two, which pairs the cars of one pass with other cars of the other, can fit better
    /// than the truth, whose poles and corners fit but are few points. Measured with `dc_loc eval -p
    /// registration.selection_object_radius:=R` on the default demo drive (the whole registration,
    /// with the correlative search and slides as `correlative` says): 403 pairs of 416 inside 2 m
    /// at 0, 412 at 1.5, 411 at 2.0, 412 at 2.5, 411 at 4.0. The weighted score only chooses:
    /// `correlative.below_score` compares the plain one.
    pub selection_object_radius: f64,
    /// Correlative search beyond a weak descriptor stage (see [`correlative`]).
    pub correlative: correlative::CorrelativeConfig,
    /// Descriptors (RSD).
    pub descriptor: descriptor::DescriptorConfig,
    /// KNN matching in descriptor space (its query subset is drawn with `ransac.seed`).
    pub matching: matching::MatchingConfig,
    /// RANSAC.
    pub ransac: ransac::RansacConfig,
    /// Levenberg-Marquardt (eq. 10) and the covariance.
    pub lm: lm::LmConfig,
}

impl Default for RegistrationConfig {
    fn default() -> Self {
        RegistrationConfig {
            min_points: 10,
            min_inliers: 30,
            min_inlier_spread: 1.0,
            reselect_gate: 3.5,
            reselect_rounds: 2,
            covariance_scale: 1.3,
            covariance_floor: [0.02, 0.0005],
            hypotheses: 3,
            screened_hypotheses: 32,
            screen_ambiguity_translation: 3.0,
            ambiguity_translation: 1.0,
            ambiguity_rotation: 0.05,
            dense: dense::DenseConfig::default(),
            selection_sigma: 0.35,
            selection_object_radius: 2.5,
            correlative: correlative::CorrelativeConfig::default(),
            descriptor: descriptor::DescriptorConfig::default(),
            matching: matching::MatchingConfig::default(),
            ransac: ransac::RansacConfig::default(),
            lm: lm::LmConfig::default(),
        }
    }
}

impl RegistrationConfig {
    /// `a` and `b` are the same alignment: within `ambiguity_translation` and `ambiguity_rotation`
    /// of each other.
    pub fn same_alignment(&self, a: &Iso2, b: &Iso2) -> bool {
        ransac::same_motion(a, b, self.ambiguity_translation, self.ambiguity_rotation)
    }

    /// The paper's steps only, for speed: descriptors, KNN, RANSAC (its best motion alone, no
    /// screening of 32), LM with re-selection, covariance; no dense stage and no surface covariances.
    /// The same as the parameter overrides `registration.dense.enabled:=false`,
    /// `registration.dense.surface_neighbours:=0`, `registration.hypotheses:=1`,
    /// `registration.screened_hypotheses:=1`, `registration.correlative.enabled:=false`. Measured (README): about 2.5 times faster than the
    /// default on 1000-point pairs, and on the demo drive 0.287 / 0.211 m mean / median translation
    /// error with 85.8 % of the pairs inside 2 m, against the default's 0.086 / 0.073 m and 91.8 %.
    pub fn paper_steps() -> Self {
        let mut cfg = RegistrationConfig {
            hypotheses: 1,
            screened_hypotheses: 1,
            ..RegistrationConfig::default()
        };
        cfg.dense.enabled = false;
        cfg.dense.surface_neighbours = 0;
        cfg.correlative.enabled = false;
        cfg
    }

    /// Rejects values that cannot work; the error names the parameter (`registration.*`).
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut v = Validator::at("registration");
        self.check(&mut v);
        v.finish()
    }

    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.at_least("min_points", self.min_points, 3);
        v.at_least("min_inliers", self.min_inliers, 3);
        v.non_negative("min_inlier_spread", self.min_inlier_spread);
        v.positive("reselect_gate", self.reselect_gate);
        v.non_negative("selection_object_radius", self.selection_object_radius);
        v.positive("covariance_scale", self.covariance_scale);
        let floor_ok = self
            .covariance_floor
            .iter()
            .all(|x| x.is_finite() && *x >= 0.0);
        v.require("covariance_floor", floor_ok, || {
            format!(
                "{:?} must be two finite values >= 0 (m, rad)",
                self.covariance_floor
            )
        });
        v.positive("ambiguity_translation", self.ambiguity_translation);
        v.positive("ambiguity_rotation", self.ambiguity_rotation);
        v.positive(
            "screen_ambiguity_translation",
            self.screen_ambiguity_translation,
        );
        v.non_negative("selection_sigma", self.selection_sigma);
        v.at_least(
            "screened_hypotheses",
            self.screened_hypotheses,
            self.hypotheses.max(1),
        );
        v.section("descriptor", |v| self.descriptor.check(v));
        v.section("matching", |v| self.matching.check(v));
        v.section("ransac", |v| self.ransac.check(v));
        v.section("lm", |v| self.lm.check(v));
        v.section("correlative", |v| self.correlative.check(v));
        v.section("dense", |v| self.dense.check(v));
    }
}

/// Cell of the screening's coverage grid, m: a RANSAC motion a metre off still scores its overlap.
const SCREEN_CELL: f64 = 1.0;
/// Source points probed per screened motion.
const SCREEN_PROBES: usize = 256;

/// What the dense stage and the screening use of the two submaps.
#[derive(Clone, Copy)]
struct DenseSets<'a> {
    /// Source points (surface covariances, smoothed, at most `max_source_points`).
    src: &'a PointSet2,
    /// Their weights in the fit score ([`dense::object_weights`]).
    weights: &'a [f64],
    /// Target points, likewise (all of them), and their tree.
    tgt: &'a PointSet2,
    tree: &'a dense::TargetTree,
    /// The other way round, for the symmetric dense stage: the target's points as a source (at most
    /// `max_source_points`), the source's points as a target (all of them) and their tree.
    tgt_as_source: &'a PointSet2,
    src_as_target: &'a PointSet2,
    src_tree: &'a dense::TargetTree,
    /// Source probes and target coverage of the screening.
    probes: &'a [Vec2],
    coverage: &'a dense::Coverage,
    /// Bearings of the source's and the target's points ([`common_view`]).
    bearings: (&'a Bearings, &'a Bearings),
}

/// The dense-stage settings a [`PreparedSubmap`] bakes in.
fn dense_baked(cfg: &RegistrationConfig) -> (usize, f64, bool, usize, f64) {
    let d = &cfg.dense;
    (
        d.surface_neighbours,
        d.surface_radius,
        d.surface_smoothing,
        d.max_source_points,
        cfg.selection_object_radius,
    )
}

/// A submap ready for matching: its points, descriptors and descriptor index. Build it once per
/// keyframe and reuse it for every registration against that keyframe.
#[derive(Debug)]
pub struct PreparedSubmap {
    points: PointSet2,
    keypoints: Vec<u32>,
    descriptors: Vec<descriptor::Descriptor>,
    index: matching::DescriptorIndex,
    descriptor_config: descriptor::DescriptorConfig,
    backend: matching::MatchingBackend,
    /// The dense settings baked in: surface neighbours, surface radius, smoothing, most source
    /// points, and the fit score's object radius.
    dense_baked: (usize, f64, bool, usize, f64),
    point_tree: dense::TargetTree,
    dense_points: PointSet2,
    /// The dense stage's source points when they are a subset of `dense_points`.
    dense_subset: Option<PointSet2>,
    /// The fit score's weight of each dense source point ([`dense::object_weights`]).
    fit_weights: Vec<f64>,
    /// Cells covered by `dense_points` (as a target) and the probes (as a source) of the screening.
    coverage: dense::Coverage,
    probes: Vec<Vec2>,
    /// The points' bearings from the anchor ([`common_view`]).
    bearings: Bearings,
}

impl PreparedSubmap {
    /// Checks the points (finite, one covariance each, positive definite) and computes the
    /// descriptors (`cfg.descriptor`) and their index (`cfg.matching.backend`).
    pub fn new(points: PointSet2, cfg: &RegistrationConfig) -> Result<Self, RegistrationError> {
        checked_config(cfg)?;
        check_point_set(&points)?;
        let keypoints = descriptor::keypoint_indices(points.len(), &cfg.descriptor);
        let descriptors =
            descriptor::compute_descriptors(&points.points, &keypoints, &cfg.descriptor)?;
        let index = matching::DescriptorIndex::new(
            &descriptors,
            cfg.descriptor.used_dim(),
            cfg.matching.backend,
        )?;
        let (dense_points, point_tree) = dense::prepare(&points, &cfg.dense)?;
        let dense_subset = dense::source_subset(&dense_points, &cfg.dense);
        let fit_weights = dense::object_weights(
            &dense_subset.as_ref().unwrap_or(&dense_points).points,
            cfg.selection_object_radius,
        );
        let coverage = dense::Coverage::new(&dense_points.points, SCREEN_CELL);
        let probes = dense::probes(&dense_points, SCREEN_PROBES);
        let bearings = Bearings::new(&points.points);
        Ok(PreparedSubmap {
            points,
            keypoints,
            descriptors,
            index,
            descriptor_config: cfg.descriptor.clone(),
            backend: cfg.matching.backend,
            dense_baked: dense_baked(cfg),
            point_tree,
            dense_points,
            dense_subset,
            fit_weights,
            coverage,
            probes,
            bearings,
        })
    }
    /// The points and covariances.
    pub fn points(&self) -> &PointSet2 {
        &self.points
    }
    /// The points that have a descriptor (indices into [`Self::points`], ascending).
    pub fn keypoints(&self) -> &[u32] {
        &self.keypoints
    }
    /// One descriptor per keypoint, in the order of [`Self::keypoints`].
    pub fn descriptors(&self) -> &[descriptor::Descriptor] {
        &self.descriptors
    }
    /// The descriptor index over [`Self::descriptors`] (items are keypoint slots).
    pub fn index(&self) -> &matching::DescriptorIndex {
        &self.index
    }
    /// The points (with surface covariances) the dense stage pairs when this submap is the source.
    fn dense_source(&self) -> &PointSet2 {
        self.dense_subset.as_ref().unwrap_or(&self.dense_points)
    }
    /// True when it was built with `cfg`'s descriptor, matching-backend and dense-stage preparation
    /// settings (surface neighbours, radius and smoothing, most source points), i.e. registering it under `cfg`
    /// is the same as preparing it anew.
    pub fn fits(&self, cfg: &RegistrationConfig) -> bool {
        self.descriptor_config == cfg.descriptor
            && self.backend == cfg.matching.backend
            && self.dense_baked == dense_baked(cfg)
    }
    /// The descriptor settings it was built with.
    pub fn descriptor_config(&self) -> &descriptor::DescriptorConfig {
        &self.descriptor_config
    }
}

/// An invalid configuration as a registration error (the registration entry points check it, so
/// that no setting can make them panic or return nonsense).
fn checked_config(cfg: &RegistrationConfig) -> Result<(), RegistrationError> {
    cfg.validate()
        .map_err(|e| RegistrationError::Numerical(format!("invalid configuration: {e}")))
}

fn check_point_set(set: &PointSet2) -> Result<(), RegistrationError> {
    if set.covs.len() != set.points.len() {
        return Err(RegistrationError::Numerical(format!(
            "{} points but {} covariances",
            set.points.len(),
            set.covs.len()
        )));
    }
    for (i, (p, c)) in set.points.iter().zip(&set.covs).enumerate() {
        let finite = p.iter().chain(c.iter()).all(|v| v.is_finite());
        let det = c[(0, 0)] * c[(1, 1)] - c[(0, 1)] * c[(1, 0)];
        if !finite || c[(0, 0)] <= 0.0 || det <= 0.0 {
            return Err(RegistrationError::Numerical(format!(
                "point {i}: non-finite position or covariance not positive definite"
            )));
        }
    }
    Ok(())
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
    check_sizes(source.points.len(), target.points.len(), cfg)?;
    if !source.fits(cfg) || !target.fits(cfg) {
        return Err(RegistrationError::Numerical(
            "submaps were prepared with other descriptor, matching or dense-stage settings than `cfg`"
                .into(),
        ));
    }
    // 1. Coarse association: K nearest neighbours in descriptor space (RSD), for a bounded set of
    //    source points.
    let queries = matching::select_queries(
        source.keypoints.len(),
        cfg.matching.max_queries,
        cfg.ransac.seed,
    );
    let mut candidates =
        matching::match_descriptors(&source.descriptors, &queries, &target.index, &cfg.matching);
    // Keypoint slots -> point indices.
    for c in &mut candidates {
        c.source = source.keypoints[c.source as usize];
        c.target = target.keypoints[c.target as usize];
    }
    // 2.-5. RANSAC, geometry check, LM, inlier re-selection.
    ransac_and_refine(
        &source.points,
        &target.points,
        Some(DenseSets {
            src: source.dense_source(),
            weights: &source.fit_weights,
            tgt: &target.dense_points,
            tree: &target.point_tree,
            tgt_as_source: target.dense_source(),
            src_as_target: &source.dense_points,
            src_tree: &source.point_tree,
            probes: &source.probes,
            coverage: &target.coverage,
            bearings: (&source.bearings, &target.bearings),
        }),
        candidates,
        cfg,
    )
}

/// The best support near a given pose: the dense stage started at `initial`, and the overlap (as in
/// [`RegistrationResult::overlap`]) where it ends, with that pose. A check of an alternative alignment (a
/// prior from odometry or earlier closures) against the one registration found: no descriptors, no
/// covariance. `None` when too few points pair up near `initial`.
pub fn overlap_near(
    source: &PreparedSubmap,
    target: &PreparedSubmap,
    initial: &Iso2,
    cfg: &RegistrationConfig,
) -> Result<Option<(Iso2, f64)>, RegistrationError> {
    let refined = dense::refine_dense(
        source.dense_source(),
        &target.dense_points,
        &target.point_tree,
        initial,
        &cfg.dense,
        &cfg.lm,
        dense::Rounds::Plain,
    )?;
    Ok(refined.map(|d| {
        let src = source.dense_source();
        let n = dense::associate(
            src,
            &target.dense_points,
            &target.point_tree,
            &d.t_target_source,
            &cfg.dense,
        )
        .len();
        (d.t_target_source, n as f64 / src.len().max(1) as f64)
    }))
}

/// Shifts along the source's x axis (a vehicle's heading) tried by [`slide_overlap`], m.
pub const SLIDE_SHIFTS: [f64; 10] = [-3.0, 3.0, -6.0, 6.0, -10.0, 10.0, -16.0, 16.0, -24.0, 24.0];

/// How well the alignment `t` slid along the source's x axis fits: the best overlap (as
/// [`overlap_near`]) of the local optima reached from `t` shifted by each of [`SLIDE_SHIFTS`] that end
/// more than 2 m from `t` (0 when none does). Along a straight street the facades fit at any shift,
/// and only poles, building edges and gaps tell the shifts apart; a result whose slid alternatives fit
/// nearly as well is a guess along the street. The shifts still to be refined are skipped once one
/// ends above `stop_above` (`f64::INFINITY` refines all): the answer is then some overlap above it,
/// not necessarily the largest (whether it exceeds `stop_above` does not depend on the order).
pub fn slide_overlap(
    source: &PreparedSubmap,
    target: &PreparedSubmap,
    t: &Iso2,
    cfg: &RegistrationConfig,
    stop_above: f64,
) -> Result<f64, RegistrationError> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    let along = t.rotation * Vec2::x();
    let done = AtomicBool::new(false);
    // The shifts are independent: refined in parallel, nearest first.
    let ends: Vec<_> = SLIDE_SHIFTS
        .par_iter()
        .map(|shift| {
            if done.load(Ordering::Relaxed) {
                return Ok(0.0);
            }
            let start =
                Iso2::from_parts((t.translation.vector + along * *shift).into(), t.rotation);
            let o = match overlap_near(source, target, &start, cfg)? {
                Some((end, o)) if (end.translation.vector - t.translation.vector).norm() > 2.0 => o,
                _ => 0.0,
            };
            if o > stop_above {
                done.store(true, Ordering::Relaxed);
            }
            Ok(o)
        })
        .collect();
    ends.into_iter()
        .try_fold(0.0f64, |best, o: Result<f64, RegistrationError>| {
            Ok(best.max(o?))
        })
}

/// Sectors of [`common_view`] (30 degrees each).
const VIEW_SECTORS: usize = 12;

/// A point set's bearings from its anchor: the share of its points in each degree (0..360,
/// counterclockwise from x).
#[derive(Debug, Clone)]
struct Bearings([f64; 360]);

impl Bearings {
    fn new(points: &[Vec2]) -> Self {
        let mut h = [0.0f64; 360];
        let w = 1.0 / points.len().max(1) as f64;
        for x in points {
            let deg = (x.y as f32).atan2(x.x as f32).to_degrees();
            // rem_euclid can round up to exactly 360.
            let k = (deg.rem_euclid(360.0) as usize).min(359);
            h[k] += w;
        }
        Bearings(h)
    }

    /// The intersection of the two 30-degree histograms, `self`'s turned by `yaw` (rounded to the
    /// degree).
    fn common(&self, target: &Bearings, yaw: f64) -> f64 {
        let shift = (yaw.to_degrees().round() as i64).rem_euclid(360) as usize;
        let (mut hs, mut ht) = ([0.0f64; VIEW_SECTORS], [0.0f64; VIEW_SECTORS]);
        let width = 360 / VIEW_SECTORS;
        for k in 0..360 {
            hs[((k + shift) % 360) / width] += self.0[k];
            ht[k / width] += target.0[k];
        }
        hs.iter().zip(&ht).map(|(a, b)| a.min(*b)).sum()
    }
}

/// How much two submaps can have seen in common, whatever their points: the intersection (0..1) of
/// their points' bearing histograms (12 sectors of 30 degrees, each histogram summing to 1) seen from
/// their anchors, with the source's turned by the yaw of `t` (to the degree). Matched submaps lie
/// metres apart, so the bearings from either anchor are close enough. One forward radar revisiting a
/// street the other way sees what lies behind the first pass (0.05-0.14 for the closures of the
/// simulated reverse laps, true and false), five radars with overlapping fields of view see all
/// around (0.40-0.77), a forward radar the same way 0.55-0.99.
pub fn common_view(source: &PreparedSubmap, target: &PreparedSubmap, t: &Iso2) -> f64 {
    source.bearings.common(&target.bearings, t.rotation.angle())
}

/// RANSAC + LM on given candidate correspondences (the part of the pipeline after association;
/// also what a baseline with its own association reuses):
/// 2. RANSAC on a planar rigid motion removes the false matches;
/// 3. inliers on a line (or a point) are refused (`min_inlier_spread`);
/// 4. LM on eq. (10) from the RANSAC estimate;
/// 5. inlier re-selection: the candidates within `reselect_gate` (Mahalanobis, with the LM weights)
///    of the LM estimate become the inliers and LM runs again, up to `reselect_rounds` times. RANSAC's
///    metric threshold cuts far points, whose noise is larger, and keeps residuals that agree with its
///    own noisy estimate; re-selecting with the noise model removes that bias (measured: without it,
///    the mean NEES of the pipeline is too high). A re-selection that leaves fewer than `min_inliers`
///    (or collinear ones) is not taken: descriptor pairs join different samples of a surface, so the
///    noise model can refuse most of a true alignment's pairs; the RANSAC inliers stay (measured
///    with the screening on the demo drive, a variant not kept in the code: 80.8 % of the pairs inside 2 m when such a re-selection
///    failed the registration, 91.1 % when it is not taken).
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
    ransac_and_refine(source, target, None, candidates, cfg)
}

/// Steps 2-6 on checked input: RANSAC keeps up to `screened_hypotheses` distinct motions, the coverage
/// grid ranks them, the best `hypotheses` are refined (LM, re-selection, dense stage); the one with
/// the largest overlap wins.
fn ransac_and_refine(
    source: &PointSet2,
    target: &PointSet2,
    prepared_dense: Option<DenseSets<'_>>,
    candidates: Vec<ransac::Correspondence>,
    cfg: &RegistrationConfig,
) -> Result<RegistrationDetail, RegistrationError> {
    let built;
    let dense_sets = match prepared_dense {
        Some(p) => p,
        None => {
            let (src, st) = dense::prepare(source, &cfg.dense)?;
            let (tgt, tt) = dense::prepare(target, &cfg.dense)?;
            let coverage = dense::Coverage::new(&tgt.points, SCREEN_CELL);
            let probes = dense::probes(&src, SCREEN_PROBES);
            let subset = dense::source_subset(&src, &cfg.dense);
            let weights = dense::object_weights(
                &subset.as_ref().unwrap_or(&src).points,
                cfg.selection_object_radius,
            );
            built = (
                subset,
                dense::source_subset(&tgt, &cfg.dense),
                (src, st),
                (tgt, tt),
                probes,
                coverage,
                weights,
                (Bearings::new(&source.points), Bearings::new(&target.points)),
            );
            DenseSets {
                src: built.0.as_ref().unwrap_or(&built.2.0),
                weights: &built.6,
                tgt: &built.3.0,
                tree: &built.3.1,
                tgt_as_source: built.1.as_ref().unwrap_or(&built.3.0),
                src_as_target: &built.2.0,
                src_tree: &built.2.1,
                probes: &built.4,
                coverage: &built.5,
                bearings: (&built.7.0, &built.7.1),
            }
        }
    };
    // 2. RANSAC: the best-supported motions that differ by more than the ambiguity distances.
    let distinct = ransac::Distinct {
        // At least `hypotheses` (validated).
        keep: cfg.screened_hypotheses,
        translation: cfg.ambiguity_translation,
        rotation: cfg.ambiguity_rotation,
        min_support: cfg.min_inliers,
    };
    // A RANSAC failure (too few candidates) still leaves the correlative search.
    let found = match ransac::ransac_hypotheses(source, target, &candidates, &cfg.ransac, &distinct)
    {
        Ok(f) => f,
        Err(e) => {
            if !correlative_applies(cfg) {
                return Err(e);
            }
            Vec::new()
        }
    };
    let most = found.first().map_or(0, |h| h.inliers.len());
    // 3. Screening: descriptor support does not tell a street slid along itself (or a repeated block)
    //    from the true alignment, geometry does: the share of source points with a partner at the
    //    motion. The best `hypotheses` of the supported motions by that overlap are refined.
    let mut screened: Vec<(usize, ransac::RansacResult)> = found
        .into_iter()
        .filter(|h| h.inliers.len() >= cfg.min_inliers)
        .map(|h| {
            (
                dense_sets
                    .coverage
                    .count(dense_sets.probes, &h.t_target_source),
                h,
            )
        })
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
    let mut best: Option<RegistrationDetail> = None;
    // Every refined alignment (pose, overlap), for the runner-up.
    let mut refined: Vec<(Iso2, f64)> = Vec::new();
    let mut first_error = None;
    // A motion within the ambiguity distances of an alignment already refined is that alignment
    // again: refining it would repeat the work and cannot add a runner-up.
    let already =
        |refined: &[(Iso2, f64)], t: &Iso2| refined.iter().any(|(r, _)| cfg.same_alignment(r, t));
    let keep = |d: RegistrationDetail, best: &mut Option<RegistrationDetail>| {
        let better = best.as_ref().is_none_or(|b| d.score > b.score);
        if better {
            *best = Some(d);
        }
    };
    // Alignments from poses (the correlative search's, the slides'): each not yet refined runs the
    // dense stage and competes.
    let refine_poses = |poses: &[Iso2],
                        refined: &mut Vec<(Iso2, f64)>,
                        best: &mut Option<RegistrationDetail>,
                        first_error: &mut Option<RegistrationError>| {
        for &pose in poses {
            if already(refined, &pose) {
                continue;
            }
            match refine_from_pose(source, target, dense_sets, &candidates, pose, cfg) {
                Ok(d) => {
                    refined.push((d.result.t_target_source, d.result.overlap));
                    keep(d, best);
                }
                Err(e) => {
                    first_error.get_or_insert(e);
                }
            }
        }
    };
    for (_, rs) in screened.iter().take(cfg.hypotheses.max(1)) {
        if already(&refined, &rs.t_target_source) {
            continue;
        }
        match refine_hypothesis(
            source,
            target,
            dense_sets,
            &candidates,
            rs.inliers.clone(),
            rs.t_target_source,
            cfg,
        ) {
            Ok(mut d) => {
                d.ransac_iterations = rs.iterations;
                refined.push((d.result.t_target_source, d.result.overlap));
                keep(d, &mut best);
            }
            Err(e) => {
                first_error.get_or_insert(e);
            }
        }
    }
    // 4. Correlative search when the descriptor stage found nothing or little overlap.
    let weak = best
        .as_ref()
        .is_none_or(|b| weak_result(b, &dense_sets, cfg));
    if correlative_applies(cfg) && weak {
        let found = correlative::candidates(
            dense_sets.src_as_target,
            dense_sets.src_tree,
            dense_sets.tgt,
            dense_sets.tree,
            &cfg.correlative,
        );
        // Scored where the votes put them (a cell and the histogram's resolution off), best first.
        let mut scored: Vec<(f64, Iso2)> = found
            .into_iter()
            .map(|(_, t)| {
                let sigma = cfg.selection_sigma.max(0.35);
                let probes = PointSet2 {
                    points: dense_sets.probes.to_vec(),
                    covs: Vec::new(),
                };
                (
                    dense::fit_score(
                        &probes,
                        None,
                        dense_sets.tgt,
                        dense_sets.tree,
                        &t,
                        2.0 * sigma,
                    )
                    .1,
                    t,
                )
            })
            .collect();
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        let poses: Vec<Iso2> = scored
            .into_iter()
            .take(cfg.correlative.candidates)
            .map(|(_, pose)| pose)
            .collect();
        refine_poses(&poses, &mut refined, &mut best, &mut first_error);
    }
    // 5. A weak winner's slides along its street (`correlative.slide_shifts`).
    let weak_winner = best
        .as_ref()
        .filter(|b| weak_result(b, &dense_sets, cfg))
        .map(|b| b.result.t_target_source);
    if let Some(win) = weak_winner.filter(|_| correlative_applies(cfg)) {
        let poses: Vec<Iso2> = cfg
            .correlative
            .slide_shifts
            .iter()
            .map(|&dx| win * Iso2::new(Vec2::new(dx, 0.0), 0.0))
            .collect();
        refine_poses(&poses, &mut refined, &mut best, &mut first_error);
    }
    match best {
        Some(d) => {
            let d = polish(source, target, dense_sets, &candidates, d, cfg);
            let d = symmetrise(source, target, dense_sets, &candidates, d, cfg);
            let mut d = soften(source, target, dense_sets, &candidates, d, cfg);
            let win = d.result.t_target_source;
            let far = |t: &Iso2| !cfg.same_alignment(&win, t);
            let mut alternatives: Vec<(Iso2, f64)> =
                refined.iter().filter(|(t, _)| far(t)).copied().collect();
            // The screened motions that were not refined count too, by their coverage relative to
            // the winner's: a street slid along itself by metres covers the same cells.
            let win_cov = dense_sets.coverage.count(dense_sets.probes, &win).max(1);
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
            d.candidates = candidates;
            d.result.candidates = d.candidates.len();
            Ok(d)
        }
        None => Err(first_error.unwrap_or(RegistrationError::TooFewInliers {
            have: 0,
            need: cfg.min_inliers,
        })),
    }
}

/// One RANSAC hypothesis refined: LM on its inliers (eq. 10), re-selection of the inliers with the noise
/// model, the dense stage, the covariance, the overlap.
#[allow(clippy::too_many_arguments)]
fn refine_hypothesis(
    source: &PointSet2,
    target: &PointSet2,
    sets: DenseSets<'_>,
    candidates: &[ransac::Correspondence],
    mut inliers: Vec<usize>,
    t_ransac: Iso2,
    cfg: &RegistrationConfig,
) -> Result<RegistrationDetail, RegistrationError> {
    let DenseSets { src, tgt, tree, .. } = sets;
    let pairs_of = |sel: &[usize]| descriptor_pairs(candidates, sel);
    let pairs = pairs_of(&inliers);
    check_inliers(source, &pairs, cfg)?;
    let mut lm = lm::refine_pose(source, target, &pairs, &t_ransac, &cfg.lm)?;
    let mut iterations = lm.iterations;
    for _ in 0..cfg.reselect_rounds {
        let sel = reselect(source, target, candidates, &lm.t_target_source, cfg);
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
    if cfg.dense.enabled {
        if let Some(d) = dense::refine_dense(
            src,
            tgt,
            tree,
            &lm.t_target_source,
            &cfg.dense,
            &cfg.lm,
            dense::Rounds::Plain,
        )? {
            lm.t_target_source = d.t_target_source;
            lm.converged = d.converged;
            lm.cost = d.cost;
            iterations += d.iterations;
            dense_settled = Some(d.settled);
        }
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
    conclude(
        source, target, sets, candidates, inliers, t_ransac, fit, cfg,
    )
}

/// A result searched beyond (`registration.correlative`): its plain fit score below `below_score`,
/// and fewer than `below_inliers` descriptor inliers unless its plain score is below
/// `rich_below_score` or its common view ([`common_view`]) below `below_common_view`.
fn weak_result(d: &RegistrationDetail, sets: &DenseSets<'_>, cfg: &RegistrationConfig) -> bool {
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
fn correlative_applies(cfg: &RegistrationConfig) -> bool {
    cfg.correlative.enabled && cfg.dense.enabled
}

/// A correlative candidate refined: the dense stage from `pose`, then the descriptor candidates
/// within `reselect_gate` of where it ends (one per point; at least `correlative.min_inliers`, not on
/// a line) give the covariance, as the descriptor inliers do for a RANSAC hypothesis.
fn refine_from_pose(
    source: &PointSet2,
    target: &PointSet2,
    sets: DenseSets<'_>,
    candidates: &[ransac::Correspondence],
    pose: Iso2,
    cfg: &RegistrationConfig,
) -> Result<RegistrationDetail, RegistrationError> {
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
    let inliers = reselect(source, target, candidates, &d.t_target_source, cfg);
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
    let d = conclude(source, target, sets, candidates, inliers, pose, fit, cfg)?;
    // Without the descriptors' vote the geometry alone must speak clearly.
    if d.dense_covariance && d.result.overlap < cfg.correlative.min_overlap {
        return Err(RegistrationError::TooFewInliers {
            have,
            need: cfg.correlative.min_inliers,
        });
    }
    Ok(d)
}

/// Where a hypothesis's refinement ended.
struct Fit {
    t_target_source: Iso2,
    converged: bool,
    cost: f64,
    iterations: usize,
    /// `None` when the dense stage did not run; else whether its rounds had settled.
    dense_settled: Option<bool>,
    /// The overlap to report when it is already known; else measured at the pose.
    overlap: Option<f64>,
    /// The fit scores likewise (weighted, plain).
    score: Option<(f64, f64)>,
    /// The covariance comes from the dense pairs ([`correlative::CorrelativeConfig::covariance_scale`])
    /// instead of the descriptor inliers.
    dense_covariance: bool,
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

/// The (source, target) point indices of the candidates `sel` (indices into `candidates`).
fn descriptor_pairs(candidates: &[ransac::Correspondence], sel: &[usize]) -> Vec<(usize, usize)> {
    sel.iter()
        .map(|&k| (candidates[k].source as usize, candidates[k].target as usize))
        .collect()
}

/// Overlap and covariance at a refined pose: the detail of one hypothesis.
#[allow(clippy::too_many_arguments)]
fn conclude(
    source: &PointSet2,
    target: &PointSet2,
    sets: DenseSets<'_>,
    candidates: &[ransac::Correspondence],
    inliers: Vec<usize>,
    t_ransac: Iso2,
    fit: Fit,
    cfg: &RegistrationConfig,
) -> Result<RegistrationDetail, RegistrationError> {
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
fn polish(
    source: &PointSet2,
    target: &PointSet2,
    sets: DenseSets<'_>,
    candidates: &[ransac::Correspondence],
    best: RegistrationDetail,
    cfg: &RegistrationConfig,
) -> RegistrationDetail {
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
    reconclude(source, target, sets, candidates, best, fit, cfg)
}

/// `best` with its pose replaced by `fit`'s and its covariance taken there (same inliers, RANSAC
/// estimate and draws); `best` as it was when that fails.
fn reconclude(
    source: &PointSet2,
    target: &PointSet2,
    sets: DenseSets<'_>,
    candidates: &[ransac::Correspondence],
    best: RegistrationDetail,
    fit: Fit,
    cfg: &RegistrationConfig,
) -> RegistrationDetail {
    let inliers = best.inliers.clone();
    match conclude(
        source,
        target,
        sets,
        candidates,
        inliers,
        best.t_ransac,
        fit,
        cfg,
    ) {
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
fn soften(
    source: &PointSet2,
    target: &PointSet2,
    sets: DenseSets<'_>,
    candidates: &[ransac::Correspondence],
    best: RegistrationDetail,
    cfg: &RegistrationConfig,
) -> RegistrationDetail {
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
    reconclude(source, target, sets, candidates, best, fit, cfg)
}

/// The winner's pose averaged with the dense stage run the other way round (the target's points
/// paired with their nearest source points, from the inverse of the winner's pose), when
/// `registration.dense.symmetric` is on and the dense stage ran; its covariance at the averaged pose.
/// Nearest-neighbour pairs join a point of one pass with the nearest sample of the other, so each
/// direction carries its own association bias; the two directions' estimates differ by that and
/// their mean halves what they do not share (see `DenseConfig::symmetric` for the measurements).
/// Kept as it was when the reverse stage fails or ends farther apart than the ambiguity distances
/// (then the two directions disagree about the alignment, not its last centimetres).
fn symmetrise(
    source: &PointSet2,
    target: &PointSet2,
    sets: DenseSets<'_>,
    candidates: &[ransac::Correspondence],
    best: RegistrationDetail,
    cfg: &RegistrationConfig,
) -> RegistrationDetail {
    if !(cfg.dense.enabled && cfg.dense.symmetric) || best.dense_settled.is_none() {
        return best;
    }
    let r = &best.result;
    let forward = r.t_target_source;
    let reverse = dense::refine_dense(
        sets.tgt_as_source,
        sets.src_as_target,
        sets.src_tree,
        &forward.inverse(),
        &cfg.dense,
        &cfg.lm,
        dense::Rounds::Plain,
    );
    let Ok(Some(rev)) = reverse else {
        return best;
    };
    let backward = rev.t_target_source.inverse();
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
    reconclude(source, target, sets, candidates, best, fit, cfg)
}

/// Enough inliers, not all on a line.
fn check_inliers(
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
fn reselect(
    source: &PointSet2,
    target: &PointSet2,
    candidates: &[ransac::Correspondence],
    t: &Iso2,
    cfg: &RegistrationConfig,
) -> Vec<usize> {
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
        if let Some(p) = lm::pair_terms(t, x, y, cov, iso_var, &plain) {
            if p.s <= gate2 {
                kept.push((c.source, c.target, k));
            }
        }
    }
    // One pair per source point and per target point: a point shared by several pairs would give
    // them a common error that LM counts as independent. Which candidate stays is decided by the
    // indices, not by the residual or the descriptor distance: both prefer pairs whose noise
    // happens to agree, and the covariance then claims more than the data hold (measured, see
    // `reselect_gate`).
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Along bare facades every slid alignment fits as well as the true one; poles and building
    /// edges at irregular places make the true one stand out.
    #[test]
    fn slid_alignments_fit_a_bare_street_but_not_one_with_poles() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let mut street = |poles: bool| -> Vec<Vec2> {
            let mut p = Vec::new();
            for side in [-8.0, 8.0] {
                for _ in 0..150 {
                    p.push(Vec2::new(
                        rng.random_range(-60.0..60.0),
                        side + rng.random_range(-0.1..0.1),
                    ));
                }
            }
            if poles {
                // Clusters of detections (poles, building edges) at irregular places.
                for x in [-47.0, -31.0, -22.5, -5.0, 3.0, 17.5, 26.0, 44.0] {
                    let y: f64 = if x > 0.0 { 5.5 } else { -5.5 };
                    for _ in 0..25 {
                        p.push(Vec2::new(
                            x + rng.random_range(-0.15..0.15),
                            y + rng.random_range(-0.15..0.15),
                        ));
                    }
                }
            }
            p
        };
        let cfg = RegistrationConfig::default();
        // Measured: 0.90 bare (points slid off the street's ends), 0.63 with poles.
        for (poles, bound) in [(false, 0.85), (true, 0.7)] {
            let pts = street(poles);
            let target =
                PreparedSubmap::new(PointSet2::isotropic(pts.clone(), 0.15), &cfg).expect("target");
            // The source: the same street seen from 4 m further along, with fresh noise.
            let t = Iso2::new(Vec2::new(4.0, 0.0), 0.0);
            let src: Vec<Vec2> = pts
                .iter()
                .map(|p| t.inverse_transform_point(&(*p).into()).coords + Vec2::new(0.03, -0.02))
                .collect();
            let source =
                PreparedSubmap::new(PointSet2::isotropic(src, 0.15), &cfg).expect("source");
            let (_, overlap) = overlap_near(&source, &target, &t, &cfg)
                .expect("refined")
                .expect("pairs");
            let slid = slide_overlap(&source, &target, &t, &cfg, f64::INFINITY).expect("slid");
            let ratio = slid / overlap;
            if poles {
                assert!(ratio < bound, "with poles: {slid:.2} / {overlap:.2}");
            } else {
                assert!(ratio > bound, "bare: {slid:.2} / {overlap:.2}");
            }
            // Stopping early gives the same verdict against any limit.
            for limit in [0.3 * overlap, bound * overlap, 0.99 * slid, slid] {
                let early = slide_overlap(&source, &target, &t, &cfg, limit).expect("slid");
                assert_eq!(
                    early > limit,
                    slid > limit,
                    "limit {limit:.3}: {early} vs {slid}"
                );
                assert!(early <= slid + 1e-12);
            }
        }
    }

    /// A forward-looking cone of points turned half round shares no bearing with itself; turned
    /// a little, most.
    #[test]
    fn common_view_of_forward_cones() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let cone: Vec<Vec2> = (0..400)
            .map(|_| {
                let (r, a) = (rng.random_range(5.0..60.0), rng.random_range(-1.3..1.3f64));
                Vec2::new(r * a.cos(), r * a.sin())
            })
            .collect();
        let all_round: Vec<Vec2> = (0..400)
            .map(|_| {
                let (r, a) = (
                    rng.random_range(5.0..60.0),
                    rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
                );
                Vec2::new(r * a.cos(), r * a.sin())
            })
            .collect();
        let cfg = RegistrationConfig::default();
        let prep = |p: &[Vec2]| {
            PreparedSubmap::new(PointSet2::isotropic(p.to_vec(), 0.15), &cfg).expect("prepared")
        };
        let (c, a) = (prep(&cone), prep(&all_round));
        let at = |yaw: f64| Iso2::new(Vec2::new(1.0, 0.5), yaw);
        assert!(common_view(&c, &c, &at(0.0)) > 0.9);
        assert!(common_view(&c, &c, &at(0.3)) > 0.6);
        assert!(common_view(&c, &c, &at(std::f64::consts::PI)) < 0.05);
        assert!(common_view(&c, &c, &at(-3.0)) < 0.1);
        // All round: half turn or not, the cone's bearings are among the other's.
        assert!(common_view(&a, &a, &at(std::f64::consts::PI)) > 0.85);
        assert!(common_view(&c, &a, &at(std::f64::consts::PI)) > 0.3);
    }

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
    }
}
