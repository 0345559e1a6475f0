//! Point-to-point ICP in the plane (Besl & McKay 1992), the "ICP" row of the paper's Table 1.
//!
//! [`register_icp`] builds the target's k-d tree once and, from an initial guess `t_target_source`, for
//! each maximum correspondence distance of the schedule (coarse to fine) pairs every transformed source
//! point with its nearest target point and solves the rigid motion in closed form until the step is
//! below the tolerances; the covariance comes from the final pairs at the optimum. docs/algorithm.md,
//! "Baselines", has the closed form, the covariance and how far it can be trusted.
//!
//! Entry points: [`register_icp`], [`IcpConfig`].

use super::{check_points, check_pose, spd_inverse};
use dc_loc_core::math::{Iso2, Mat3, Vec2};
use dc_loc_core::registration::{
    PointSet2, RegistrationError, RegistrationResult, covariance_ros_from_se2,
};
use dc_loc_core::validate::{ConfigError, Validator};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};

/// Point-to-point ICP settings (params YAML section `baselines.icp`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IcpConfig {
    /// Maximum correspondence distances, m, one ICP stage each, coarse to fine (non-increasing).
    pub max_correspondence_distances: Vec<f64>,
    /// Iteration limit per stage.
    pub max_iterations: usize,
    /// Convergence: translation of the last step below this, m.
    pub translation_tolerance: f64,
    /// Convergence: rotation of the last step below this, rad.
    pub rotation_tolerance: f64,
    /// Fewest correspondences an iteration may use; fewer is a failure.
    pub min_correspondences: usize,
}

impl Default for IcpConfig {
    /// Schedule 5 m, 2 m, 1 m (a first stage of 5 m catches guesses off by 1-2 m and 5-10 degrees;
    /// ending at 1 m, four times the 0.25 m range noise, refines); 50 iterations per stage; step tolerances 1e-4 m and 1e-5 rad; at least 6
    /// correspondences.
    fn default() -> Self {
        IcpConfig {
            max_correspondence_distances: vec![5.0, 2.0, 1.0],
            max_iterations: 50,
            translation_tolerance: 1e-4,
            rotation_tolerance: 1e-5,
            min_correspondences: 6,
        }
    }
}

impl IcpConfig {
    /// Rejects unusable values, naming them `baselines.icp.*`.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut v = Validator::at("baselines.icp");
        self.check(&mut v);
        v.finish()
    }

    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        let d = &self.max_correspondence_distances;
        v.require("max_correspondence_distances", !d.is_empty(), || {
            "at least one distance is required".into()
        });
        for (i, &dist) in d.iter().enumerate() {
            v.positive("max_correspondence_distances", dist);
            v.require(
                "max_correspondence_distances",
                i == 0 || dist <= d[i - 1],
                || "the schedule must run from coarse to fine (non-increasing)".into(),
            );
        }
        v.at_least("max_iterations", self.max_iterations, 1);
        v.positive("translation_tolerance", self.translation_tolerance);
        v.positive("rotation_tolerance", self.rotation_tolerance);
        v.at_least("min_correspondences", self.min_correspondences, 3);
    }
}

/// Registers `source` onto `target` by point-to-point ICP from `initial_t_target_source`.
///
/// Errors: [`RegistrationError::TooFewPoints`] when either set has fewer than `min_correspondences`
/// points, [`RegistrationError::TooFewInliers`] when an iteration finds fewer pairs than that within the
/// correspondence distance, [`RegistrationError::Numerical`] for non-finite input or degenerate geometry
/// (e.g. all points identical: the rotation is then unobservable). Not converging within the iteration
/// limit is not an error: the result says `converged: false`.
pub fn register_icp(
    source: &PointSet2,
    target: &PointSet2,
    initial_t_target_source: &Iso2,
    config: &IcpConfig,
) -> Result<RegistrationResult, RegistrationError> {
    config
        .validate()
        .map_err(|e| RegistrationError::Numerical(e.to_string()))?;
    let need = config.min_correspondences;
    check_points("source", &source.points, need)?;
    check_points("target", &target.points, need)?;
    check_pose("initial guess", initial_t_target_source)?;

    // Step 1: the target tree, built once.
    let coords: Vec<[f64; 2]> = target.points.iter().map(|p| [p.x, p.y]).collect();
    let tree: ImmutableKdTree<f64, 2> = ImmutableKdTree::new_from_slice(&coords)
        .map_err(|e| RegistrationError::Numerical(format!("target k-d tree: {e}")))?;
    let nearest = |q: &Vec2| {
        let nn = tree
            .query(&[q.x, q.y])
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute();
        (nn.item as usize, nn.distance)
    };
    let pairs_at = |t: &Iso2, max_dist: f64| -> Vec<(Vec2, Vec2)> {
        let max_sq = max_dist * max_dist;
        source
            .points
            .iter()
            .filter_map(|x| {
                let (j, d2) = nearest(&(t * nalgebra::Point2::from(*x)).coords);
                (d2 <= max_sq).then(|| (*x, target.points[j]))
            })
            .collect()
    };

    // Step 2: the schedule, coarse to fine.
    let mut t = *initial_t_target_source;
    let mut iterations = 0;
    let mut converged = false;
    for &max_dist in &config.max_correspondence_distances {
        converged = false;
        for _ in 0..config.max_iterations {
            iterations += 1;
            let pairs = pairs_at(&t, max_dist);
            if pairs.len() < need {
                return Err(RegistrationError::TooFewInliers {
                    have: pairs.len(),
                    need,
                });
            }
            let t_new = umeyama_2d(&pairs)?;
            let step = t.inverse() * t_new;
            t = t_new;
            if step.translation.vector.norm() < config.translation_tolerance
                && step.rotation.angle().abs() < config.rotation_tolerance
            {
                converged = true;
                break;
            }
        }
        log::debug!(
            "icp: stage {max_dist} m done after {iterations} iterations (converged: {converged})"
        );
    }

    // Step 3: residuals and covariance at the optimum, with the finest distance.
    let last = config
        .max_correspondence_distances
        .last()
        .copied()
        .unwrap_or(f64::INFINITY);
    let pairs = pairs_at(&t, last);
    if pairs.len() < need {
        return Err(RegistrationError::TooFewInliers {
            have: pairs.len(),
            need,
        });
    }
    let (cov, mse) = point_to_point_covariance(&t, &pairs)?;
    Ok(RegistrationResult {
        t_target_source: t,
        covariance: covariance_ros_from_se2(&cov),
        converged,
        iterations,
        inliers: pairs.len(),
        candidates: source.len(),
        overlap: pairs.len() as f64 / source.len() as f64,
        cost: mse,
        runner_up_overlap: 0.0,
        alternatives: Vec::new(),
        score_share: Mat3::zeros(),
    })
}

/// Closed-form rigid motion minimising `sum |y_i - T x_i|^2` over pairs `(x_i, y_i)` (Umeyama 1991 in 2D).
fn umeyama_2d(pairs: &[(Vec2, Vec2)]) -> Result<Iso2, RegistrationError> {
    let n = pairs.len() as f64;
    let (sx, sy) = pairs
        .iter()
        .fold((Vec2::zeros(), Vec2::zeros()), |(a, b), (x, y)| {
            (a + x, b + y)
        });
    let (mx, my) = (sx / n, sy / n);
    let (mut dot, mut cross, mut sxx, mut syy) = (0.0, 0.0, 0.0, 0.0);
    for (x, y) in pairs {
        let (a, b) = (x - mx, y - my);
        dot += a.dot(&b);
        cross += a.x * b.y - a.y * b.x;
        sxx += a.norm_squared();
        syy += b.norm_squared();
    }
    // Points within a micrometre of their centroid: the rotation is unobservable.
    if sxx / n < 1e-12 || syy / n < 1e-12 {
        return Err(RegistrationError::Numerical(
            "correspondences have no spatial extent: rotation unobservable".into(),
        ));
    }
    let theta = cross.atan2(dot);
    let rot = nalgebra::Rotation2::new(theta);
    Ok(Iso2::new(my - rot * mx, theta))
}

/// `(Cov(delta), mean squared residual)` of point-to-point pairs at `t` (docs/algorithm.md, "Baselines").
fn point_to_point_covariance(
    t: &Iso2,
    pairs: &[(Vec2, Vec2)],
) -> Result<(Mat3, f64), RegistrationError> {
    let mut h = Mat3::zeros();
    let mut sq = 0.0;
    for (x, y) in pairs {
        let e = y - (t * nalgebra::Point2::from(*x)).coords;
        sq += e.norm_squared();
        // Rows of [I, J x]: d(T Exp(delta) x)/d delta = R [I, J x]; R drops out of A^T A.
        let a = nalgebra::Matrix2x3::new(1.0, 0.0, -x.y, 0.0, 1.0, x.x);
        h += a.transpose() * a;
    }
    let dof = (2 * pairs.len()).saturating_sub(3).max(1) as f64;
    let s2 = sq / dof;
    let h_inv = spd_inverse(&h)
        .ok_or_else(|| RegistrationError::Numerical("ICP information matrix is singular".into()))?;
    Ok((h_inv * s2, sq / pairs.len() as f64))
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn umeyama_recovers_exact_motion() {
        let truth = Iso2::new(Vec2::new(1.5, -0.7), 0.4);
        let xs = [
            Vec2::new(0.0, 0.0),
            Vec2::new(3.0, 1.0),
            Vec2::new(-2.0, 4.0),
            Vec2::new(5.0, -3.0),
        ];
        let pairs: Vec<_> = xs
            .iter()
            .map(|x| (*x, (truth * nalgebra::Point2::from(*x)).coords))
            .collect();
        let t = umeyama_2d(&pairs).unwrap();
        assert_relative_eq!(t, truth, epsilon = 1e-12);
    }

    #[test]
    fn umeyama_rejects_identical_points() {
        let p = Vec2::new(2.0, 3.0);
        let pairs = vec![(p, p); 10];
        assert!(matches!(
            umeyama_2d(&pairs),
            Err(RegistrationError::Numerical(_))
        ));
    }

    #[test]
    fn covariance_matches_linear_least_squares() {
        // Pairs with residuals; compare s^2 H^-1 against the covariance of the linearised LS problem
        // assembled column by column from finite differences of the residual map.
        let t = Iso2::new(Vec2::new(0.3, -0.2), 0.1);
        let xs: Vec<Vec2> = (0..8)
            .map(|i| Vec2::new(i as f64 * 1.3 - 4.0, (i as f64 * 0.7).sin() * 3.0))
            .collect();
        let pairs: Vec<_> = xs
            .iter()
            .enumerate()
            .map(|(i, x)| {
                let e = Vec2::new((i as f64).cos() * 0.1, (i as f64 * 1.7).sin() * 0.1);
                (*x, (t * nalgebra::Point2::from(*x)).coords + e)
            })
            .collect();
        let (cov, _) = point_to_point_covariance(&t, &pairs).unwrap();
        let residual = |d: &nalgebra::Vector3<f64>| -> nalgebra::DVector<f64> {
            let td = t * Iso2::new(Vec2::new(d.x, d.y), d.z);
            nalgebra::DVector::from_iterator(
                2 * pairs.len(),
                pairs.iter().flat_map(|(x, y)| {
                    let e = y - (td * nalgebra::Point2::from(*x)).coords;
                    [e.x, e.y]
                }),
            )
        };
        let r0 = residual(&nalgebra::Vector3::zeros());
        let mut jac = nalgebra::DMatrix::zeros(2 * pairs.len(), 3);
        for k in 0..3 {
            let mut d = nalgebra::Vector3::zeros();
            d[k] = 1e-6;
            let col = (residual(&d) - residual(&-d)) / 2e-6;
            jac.set_column(k, &col);
        }
        let jtj = jac.transpose() * &jac;
        let s2 = r0.norm_squared() / (2 * pairs.len() - 3) as f64;
        let expect = jtj.try_inverse().unwrap() * s2;
        for i in 0..3 {
            for j in 0..3 {
                assert_relative_eq!(cov[(i, j)], expect[(i, j)], max_relative = 1e-5);
            }
        }
    }

    #[test]
    fn config_validation_names_fields() {
        IcpConfig::default().validate().unwrap();
        let c = IcpConfig {
            max_correspondence_distances: vec![1.0, 2.0],
            ..IcpConfig::default()
        };
        assert_eq!(
            c.validate().unwrap_err().name,
            "baselines.icp.max_correspondence_distances"
        );
        let c = IcpConfig {
            min_correspondences: 2,
            ..IcpConfig::default()
        };
        assert_eq!(
            c.validate().unwrap_err().name,
            "baselines.icp.min_correspondences"
        );
        let c: Result<IcpConfig, _> = serde_json::from_str(r#"{"max_iteration": 3}"#);
        assert!(c.is_err(), "unknown fields are rejected");
    }
}
