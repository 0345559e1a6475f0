//! The registration's settings (`registration.*`): one struct that mirrors the params YAML section.

use super::{correlative, dense, descriptor, lm, matching, ransac};
use crate::math::Iso2;
use crate::validate::{ConfigError, Validator};

/// All DC-Loc registration parameters; mirrors the `registration` section of the params YAML.
///
/// Defaults are written out on each field; [`RegistrationConfig::validate`] rejects (never clamps)
/// unusable values and names them as `registration.<section>.<field>`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RegistrationConfig {
    /// Fewest points a submap must have (default 10).
    pub min_points: usize,
    /// Fewest RANSAC inliers for a result (default 30): unrelated street scenes line up by chance on
    /// up to about 20 descriptor pairs, true pairs give a hundred and more.
    pub min_inliers: usize,
    /// Smallest standard deviation of the inlier source points along their least-spread direction, m
    /// (default 1.0). Below it the inliers lie on a line (or a point): descriptor matches can slide
    /// along it, so the registration is refused rather than reported with a covariance that lies.
    pub min_inlier_spread: f64,
    /// After LM, the candidates within this many sigma of the estimate (Mahalanobis with the LM
    /// weights) become the inliers, one per source and per target point, and LM runs again (default
    /// 3.5: 99.8 % of 2-D Gaussian residuals): RANSAC's metric threshold keeps residuals that agree with
    /// its own noisy estimate, the noise model does not.
    pub reselect_gate: f64,
    /// Rounds of that re-selection; 0 = off (default 2).
    pub reselect_rounds: usize,
    /// Factor on the reported covariance (default 1.3; 1.0 for the bare estimator): descriptor
    /// association also accepts neighbouring reflectors within the gate, whose offsets bias the
    /// estimate beyond what the residual scatter shows.
    pub covariance_scale: f64,
    /// Standard deviations added (as variances) to the reported covariance when the dense stage ran:
    /// `[translation m (each axis), rotation rad]` (default `[0.02, 0.0005]`; zeros = off). Two passes
    /// sample each surface at different places and parked cars change between them, so the last
    /// centimetres of a dense alignment carry an error that the pairs' scatter cannot show and that
    /// does not shrink with more pairs.
    pub covariance_floor: [f64; 2],
    /// RANSAC motions refined per registration (LM on their descriptor inliers, re-selection, dense
    /// stage), the one with the best fit score kept (default 3): the best of the
    /// `screened_hypotheses` by coverage; one within `ambiguity_translation` / `ambiguity_rotation`
    /// of an alignment already refined is that alignment and is not refined again.
    pub hypotheses: usize,
    /// RANSAC motions kept for screening (default 32): the best-supported motions (each explaining at
    /// least `min_inliers` source points) that differ by more than the ambiguity distances, each
    /// scored by its coverage (the share of 256 source probes landing in target grid cells of 1 m).
    /// Descriptor support does not tell a street slid along itself, or another street, from the true
    /// alignment; geometry does.
    pub screened_hypotheses: usize,
    /// A screened motion farther than this from the result, m, whose coverage comes near the
    /// result's is a runner-up alignment too (default 3.0): `runner_up_overlap` is at least the
    /// result's overlap times that coverage ratio. Coarser than `ambiguity_translation` because
    /// coverage cannot resolve less.
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
    /// once): each source point weighs 1 / (the source points near it, itself included), so that a
    /// pole or a building corner weighs as much as a parked car or a stretch of facade. Two passes of
    /// a street see its facades, poles and corners again but not all its parked cars: counted by
    /// points, a street slid by a parking slot or two can fit better than the truth. The weighted score
    /// only chooses; `correlative.below_score` compares the plain one.
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
    /// `registration.screened_hypotheses:=1`, `registration.correlative.enabled:=false`: about half
    /// the time of the default on 1000-point pairs, and several times its error.
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
        v.count("hypotheses", self.hypotheses, 0, 1000);
        v.count("reselect_rounds", self.reselect_rounds, 0, 100);
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
