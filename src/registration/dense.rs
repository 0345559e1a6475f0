//! Dense refinement: eq. 10 again, over nearest-neighbour pairs instead of descriptor pairs.
//!
//! Descriptor matching pairs a source point with a *similar-looking* target point. Two radar passes
//! sample a facade at different places, so those pairs join different points of the same surface and
//! the pose they give is off by a fraction of the sampling spacing (decimetres). Once RANSAC and LM have
//! brought the submaps within that distance, every source point is paired with its nearest target point
//! under the current estimate, pairs beyond a Mahalanobis gate on the combined covariance
//! `Sigma_y + R Sigma_x R^T` (and a distance cap) are dropped, and eq. 10 is solved again, a few times
//! (iterative closest point with the paper's residuals and loss, as in GICP). Beyond the paper.
//!
//! Entry points: [`DenseConfig`], [`target_tree`], [`refine_dense`].

use super::lm::{self, LmConfig};
use super::{PointSet2, RegistrationError};
use crate::math::{Iso2, Mat2};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};

/// The target points' 2D k-d tree (item = point index).
pub type TargetTree = ImmutableKdTree<f64, 2>;

/// Settings of the dense stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DenseConfig {
    /// Run it (default true; off reproduces the paper's descriptor-pairs-only estimate).
    pub enabled: bool,
    /// Re-association rounds at most (default 8); stops earlier when the pose moves less than 1 mm and
    /// 0.01 mrad.
    pub iterations: usize,
    /// Largest Mahalanobis distance of a pair under the combined covariance (default 3.0).
    pub gate: f64,
    /// Largest Euclidean distance of a pair, m (default 1.5).
    pub max_distance: f64,
    /// Fewest pairs, else the descriptor-stage estimate is kept (default 30).
    pub min_pairs: usize,
    /// Neighbours whose scatter is added to each point's covariance in this stage (default 8; 0 = off).
    /// Two passes sample a surface at different places, so a nearest neighbour is the same surface, not
    /// the same point: the scatter of the local neighbourhood (long along a facade, thin across it)
    /// models where along the surface the partner may lie, as GICP's surface covariances do (Segal et
    /// al., RSS 2009), on top of the measurement covariance of eq. 7-8.
    pub surface_neighbours: usize,
    /// Radius of that neighbourhood, m (default 2.0).
    pub surface_radius: f64,
    /// Most source points paired in this stage (default 2000): above it a fixed pseudo-random subset
    /// (the target keeps all its points). A submap stacks several scans, so 2000 points still hold
    /// every reflector several times. Measured on the four 5000-point synthetic pairs of
    /// `examples/registration_profile.rs` (`MAXSRC=n` sets it there), whole registration time and mean
    /// translation error: 1500 points 13.1 ms / 2.5 cm, 2000: 15.0 ms / 2.3 cm, 3000: 19.1 ms /
    /// 1.8 cm, all 5000: 27.4 ms / 1.3 cm. Submaps up to this size are unaffected.
    pub max_source_points: usize,
    /// Factor on the covariance (from the descriptor pairs at the refined pose) when this stage ran
    /// (default 0.35). The dense pose is more accurate than the descriptor pairs' own scatter says; the
    /// factor is measured (mean NEES near 3 on the synthetic scenes of tests/registration.rs and on the
    /// simulated drives of `dc_loc eval`, which reports the NEES it finds).
    pub covariance_scale: f64,
}

impl Default for DenseConfig {
    fn default() -> Self {
        DenseConfig {
            enabled: true,
            iterations: 8,
            gate: 3.0,
            max_distance: 1.5,
            min_pairs: 30,
            surface_neighbours: 8,
            surface_radius: 2.0,
            max_source_points: 2000,
            covariance_scale: 0.35,
        }
    }
}

impl DenseConfig {
    /// Rejects unusable values, naming the field under `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        use crate::config::ConfigError;
        if self.iterations == 0 {
            return Err(ConfigError::new(
                format!("{prefix}.iterations"),
                "must be at least 1",
            ));
        }
        for (f, v) in [
            ("gate", self.gate),
            ("max_distance", self.max_distance),
            ("surface_radius", self.surface_radius),
            ("covariance_scale", self.covariance_scale),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(ConfigError::new(
                    format!("{prefix}.{f}"),
                    format!("{v} must be > 0"),
                ));
            }
        }
        if self.surface_neighbours > 64 {
            return Err(ConfigError::new(
                format!("{prefix}.surface_neighbours"),
                "must be at most 64",
            ));
        }
        if self.max_source_points < self.min_pairs {
            return Err(ConfigError::new(
                format!("{prefix}.max_source_points"),
                format!(
                    "{} is below min_pairs = {}",
                    self.max_source_points, self.min_pairs
                ),
            ));
        }
        if self.min_pairs < 3 {
            return Err(ConfigError::new(
                format!("{prefix}.min_pairs"),
                "must be at least 3",
            ));
        }
        Ok(())
    }
}

/// Builds the target tree.
pub fn target_tree(target: &PointSet2) -> Result<TargetTree, RegistrationError> {
    let coords: Vec<[f64; 2]> = target.points.iter().map(|p| [p.x, p.y]).collect();
    TargetTree::new_from_slice(&coords)
        .map_err(|e| RegistrationError::Numerical(format!("target k-d tree: {e}")))
}

/// The point set with each covariance enlarged by the scatter of its `surface_neighbours` nearest
/// neighbours within `surface_radius` (including itself), see [`DenseConfig::surface_neighbours`].
pub fn with_surface_covariances(
    set: &PointSet2,
    tree: &TargetTree,
    cfg: &DenseConfig,
) -> PointSet2 {
    let mut out = set.clone();
    let Some(k) = std::num::NonZeroUsize::new(cfg.surface_neighbours).filter(|k| k.get() >= 3)
    else {
        return out;
    };
    let r2 = cfg.surface_radius * cfg.surface_radius;
    let mut scratch = tree.create_scratch::<SquaredEuclidean<f64>>();
    for (p, c) in set.points.iter().zip(out.covs.iter_mut()) {
        let nn = tree
            .query(&[p.x, p.y])
            .nearest_n::<SquaredEuclidean<f64>>(k)
            .within(r2)
            .unsorted()
            .with_scratch(&mut scratch)
            .execute();
        let near: Vec<_> = nn
            .iter()
            .filter_map(|n| set.points.get(n.item as usize))
            .collect();
        if near.len() < 3 {
            continue;
        }
        let mean = near.iter().fold(crate::math::Vec2::zeros(), |a, q| a + *q) / near.len() as f64;
        let scatter = near.iter().fold(Mat2::zeros(), |a, q| {
            let d = *q - mean;
            a + d * d.transpose()
        }) / (near.len() - 1) as f64;
        *c += scatter;
    }
    out
}

/// The fixed pseudo-random subset of `set` this stage pairs as a source when `set` has more than
/// `cfg.max_source_points` points; `None` when it pairs all of them.
pub fn source_subset(set: &PointSet2, cfg: &DenseConfig) -> Option<PointSet2> {
    if set.len() <= cfg.max_source_points {
        return None;
    }
    let keep = super::descriptor::subset_indices(set.len(), cfg.max_source_points, SUBSET_SEED);
    Some(PointSet2 {
        points: keep.iter().map(|&i| set.points[i as usize]).collect(),
        covs: keep.iter().map(|&i| set.covs[i as usize]).collect(),
    })
}

const SUBSET_SEED: u64 = 0xD3_45E5_0B5E;

/// Nearest-neighbour pairs (source index, target index) under `t` that pass the gates.
pub fn associate(
    source: &PointSet2,
    target: &PointSet2,
    tree: &TargetTree,
    t: &Iso2,
    cfg: &DenseConfig,
) -> Vec<(usize, usize)> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let max_sq = cfg.max_distance * cfg.max_distance;
    let gate_sq = cfg.gate * cfg.gate;
    let mut pairs = Vec::with_capacity(source.len());
    for (i, (x, cx)) in source.points.iter().zip(&source.covs).enumerate() {
        let q = t * nalgebra::Point2::from(*x);
        let nn = tree
            .query(&[q.x, q.y])
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute();
        if nn.distance > max_sq {
            continue;
        }
        let j = nn.item as usize;
        let (Some(y), Some(cy)) = (target.points.get(j), target.covs.get(j)) else {
            continue;
        };
        let d = y - q.coords;
        let s: Mat2 = cy + r * cx * r.transpose();
        let Some(s_inv) = s.try_inverse() else {
            continue;
        };
        if d.dot(&(s_inv * d)) <= gate_sq {
            pairs.push((i, j));
        }
    }
    pairs
}

/// Result of the dense stage.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseResult {
    /// Refined pose.
    pub t_target_source: Iso2,
    /// Final pairs.
    pub pairs: Vec<(usize, usize)>,
    /// LM iterations over all rounds.
    pub iterations: usize,
    /// The last LM converged.
    pub converged: bool,
    /// Final cost.
    pub cost: f64,
}

/// Re-associates and re-solves eq. 10 from `initial`; `None` when too few pairs pass the gates (the
/// caller keeps its estimate).
pub fn refine_dense(
    source: &PointSet2,
    target: &PointSet2,
    tree: &TargetTree,
    initial: &Iso2,
    cfg: &DenseConfig,
    lm_cfg: &LmConfig,
) -> Result<Option<DenseResult>, RegistrationError> {
    let mut t = *initial;
    let mut out: Option<DenseResult> = None;
    let mut iterations = 0;
    // The pairs change from round to round, so the rounds in between solve only to a tenth of the
    // stopping step (0.1 mm, 1 microrad); the last pairs are then solved to `lm_cfg`'s tolerances.
    // Measured on the synthetic 1000- and 5000-point pairs of `examples/registration_profile.rs`: the
    // same pose errors to 0.1 mm, about 5 % less registration time.
    let round_cfg = LmConfig {
        step_tolerance: lm_cfg.step_tolerance.max(1e-4),
        cost_tolerance: lm_cfg.cost_tolerance.max(1e-7),
        ..lm_cfg.clone()
    };
    for _ in 0..cfg.iterations {
        let pairs = associate(source, target, tree, &t, cfg);
        if pairs.len() < cfg.min_pairs {
            break;
        }
        let p = lm::refine_pose(source, target, &pairs, &t, &round_cfg)?;
        iterations += p.iterations;
        let step = t.inverse() * p.t_target_source;
        t = p.t_target_source;
        out = Some(DenseResult {
            t_target_source: t,
            pairs,
            iterations,
            converged: p.converged,
            cost: p.cost,
        });
        if step.translation.vector.norm() < 1e-3 && step.rotation.angle().abs() < 1e-5 {
            break;
        }
    }
    if let Some(d) = out.as_mut() {
        let p = lm::refine_pose(source, target, &d.pairs, &d.t_target_source, lm_cfg)?;
        d.iterations += p.iterations;
        d.t_target_source = p.t_target_source;
        d.converged = p.converged;
        d.cost = p.cost;
    }
    Ok(out)
}
