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
    /// Fewest RANSAC inliers for a result (default 30): unrelated street scenes line up by chance
    /// on up to about 20 descriptor pairs, true pairs give a hundred and more.
    pub min_inliers: usize,
    /// Smallest standard deviation of the inlier source points along their least-spread direction,
    /// m (default 1.0). Below it the inliers lie on a line (or a point): descriptor matches can
    /// slide along it, so the registration is refused rather than reported with a covariance that
    /// lies.
    pub min_inlier_spread: f64,
    /// Rounds of that re-selection; 0 = off (default 2).
    pub reselect_rounds: usize,
    /// Standard deviations added (as variances) to the reported covariance when the dense stage
    /// ran: `[translation m (each axis), rotation rad]` (default `[0.02, 0.0005]`; zeros = off).
    /// Two passes sample each surface at different places and parked cars change between them, so
    /// the last centimetres of a dense alignment carry an error that the pairs' scatter cannot show
    /// and that does not shrink with more pairs.
    pub covariance_floor: [f64; 2],
    /// RANSAC motions refined per registration (LM on their descriptor inliers, re-selection, dense
    /// stage), the one with the best fit score kept (default 3): the best of the
    /// `screened_hypotheses` by coverage; one within [`ransac::AMBIGUITY_TRANSLATION`] /
    /// [`ransac::AMBIGUITY_ROTATION`] of an alignment already refined is that alignment and is not
    /// refined again.
    pub hypotheses: usize,
    /// RANSAC motions kept for screening (default 32): the best-supported motions (each explaining
    /// at least `min_inliers` source points) that differ by more than the ambiguity distances, each
    /// scored by its coverage (the share of 256 source probes landing in target grid cells of 1 m).
    /// Descriptor support does not tell a street slid along itself, or another street, from the
    /// true alignment; geometry does.
    pub screened_hypotheses: usize,
    /// Dense refinement after the descriptor stage (default on): the descriptor pairs join
    /// different samples of the same surfaces, which leaves a bias of decimetres; re-associating
    /// every source point with its nearest target point under the current estimate and solving eq.
    /// 10 again removes it.
    pub dense: dense::DenseConfig,
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
            min_inliers: 30,
            min_inlier_spread: 1.0,
            reselect_rounds: 2,
            covariance_floor: [0.02, 0.0005],
            hypotheses: 3,
            screened_hypotheses: 32,
            dense: dense::DenseConfig::default(),
            correlative: correlative::CorrelativeConfig::default(),
            descriptor: descriptor::DescriptorConfig::default(),
            matching: matching::MatchingConfig::default(),
            ransac: ransac::RansacConfig::default(),
            lm: lm::LmConfig::default(),
        }
    }
}

impl RegistrationConfig {
    /// `a` and `b` are the same alignment: within [`ransac::AMBIGUITY_TRANSLATION`] and
    /// [`ransac::AMBIGUITY_ROTATION`] of each other.
    pub fn same_alignment(&self, a: &Iso2, b: &Iso2) -> bool {
        ransac::same_motion(
            a,
            b,
            ransac::AMBIGUITY_TRANSLATION,
            ransac::AMBIGUITY_ROTATION,
        )
    }

    /// The paper's steps only, for speed: descriptors, KNN, RANSAC (its best motion alone, no
    /// screening of 32), LM with re-selection, covariance; no dense stage and no surface
    /// covariances. The same as the parameter overrides `registration.dense.enabled:=false`,
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
        v.at_least("min_inliers", self.min_inliers, 3);
        v.non_negative("min_inlier_spread", self.min_inlier_spread);
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
