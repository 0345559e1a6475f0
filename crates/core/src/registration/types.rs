//! The types every registration method shares: the input ([`PointSet2`]), the output
//! ([`RegistrationResult`], and DC-Loc's [`RegistrationDetail`] with its [`Correspondence`]s), the
//! failure ([`RegistrationError`]), and the embedding of a planar covariance in ROS order
//! ([`covariance_ros_from_se2`]).

use crate::math::{Iso2, Mat2, Mat3, Mat6, Vec2};
use serde::{Deserialize, Serialize};

/// Variance (m^2 or rad^2) reported for the axes a planar registration does not observe (z, roll,
/// pitch).
///
/// Large enough that a pose-graph back end gives those axes no weight, small enough to stay finite
/// in single precision after inversion: 1e6 (a 1 km / 1000 rad standard deviation).
pub const UNOBSERVED_VARIANCE: f64 = 1e6;

/// A candidate match: source (current submap) point index, target (previous submap) point index.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Correspondence {
    /// Index into the source point set.
    pub source: u32,
    /// Index into the target point set.
    pub target: u32,
    /// Descriptor distance (Euclidean; 0 when the match did not come from descriptors).
    pub descriptor_distance: f32,
}

impl Correspondence {
    /// A correspondence without a descriptor distance.
    pub fn new(source: usize, target: usize) -> Self {
        Correspondence {
            source: source as u32,
            target: target as u32,
            descriptor_distance: 0.0,
        }
    }
}

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
    /// Covariance of `t_target_source`, 6x6 in ROS order (x, y, z, rot x, rot y, rot z), row-major
    /// when flattened; unobserved axes carry [`UNOBSERVED_VARIANCE`].
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
    /// Share of source points with a partner in the target at the final pose (0..1), a geometric
    /// check of the alignment independent of the descriptors (DC-Loc: nearest neighbours inside the
    /// dense stage's gates; ICP: pairs within the last distance; NDT: points scored by a cell).
    pub overlap: f64,
    /// Overlap of the best other alignment (a refined RANSAC hypothesis farther than
    /// [`super::ransac::AMBIGUITY_TRANSLATION`] / [`super::ransac::AMBIGUITY_ROTATION`] from the
    /// result), 0 when there was none: close to
    /// `overlap` means the scene aliases (a street sliding along itself) and the result may be the
    /// wrong one of two. Only DC-Loc registration fills it; the baselines report 0.
    pub runner_up_overlap: f64,
    /// The other alignments behind `runner_up_overlap`, each with the overlap it counts with (a
    /// refined hypothesis: its own; a screened motion: the result's overlap scaled by its coverage
    /// ratio): a prior (an accepted alignment of the session) can tell them from the result where
    /// the submaps alone cannot. Empty for the baselines.
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

/// Embeds a planar covariance over (x, y, theta) into the 6x6 ROS-order covariance (x, y, z, rot x,
/// rot y, rot z); z, roll and pitch get [`UNOBSERVED_VARIANCE`] and no correlation.
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
    pub candidates: Vec<Correspondence>,
    /// Indices into `candidates` of the RANSAC inliers that went into LM.
    pub inliers: Vec<usize>,
    /// The RANSAC estimate (LM's initial guess).
    pub t_ransac: Iso2,
    /// RANSAC draws.
    pub ransac_iterations: usize,
    /// `None` when the dense stage did not run; else whether its last round moved the pose less
    /// than its stopping step.
    pub dense_settled: Option<bool>,
    /// The fit score the hypotheses competed with ([`dense::fit_score`], each point weighted by
    /// [`dense::SELECTION_OBJECT_RADIUS`]).
    pub score: f64,
    /// The same with every point weighing alike: what [`super::correlative::BELOW_SCORE`] compares.
    pub plain_score: f64,
    /// The covariance came from the dense pairs (an alignment of the correlative search that too
    /// few descriptor pairs agree with), not from the descriptor inliers.
    pub dense_covariance: bool,
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
