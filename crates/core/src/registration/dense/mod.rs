//! Dense refinement: eq. 10 again, over nearest-neighbour pairs instead of descriptor pairs.
//!
//! Descriptor matching pairs a source point with a *similar-looking* target point. Two radar passes
//! sample a facade at different places, so those pairs join different points of the same surface
//! and the pose they give is off by a fraction of the sampling spacing (decimetres). Once RANSAC
//! and LM have brought the submaps within that distance, every source point is paired with its
//! nearest target point under the current estimate, pairs beyond a Mahalanobis gate on the combined
//! covariance `Sigma_y + R Sigma_x R^T` (and a distance cap) are dropped, and eq. 10 is solved
//! again, a few times (iterative closest point with the paper's residuals and loss, as in GICP).
//! Beyond the paper.
//!
//! Entry points: [`DenseConfig`], [`target_tree`], [`refine_dense`] ([`Rounds`]).//! Parts:
//! `associate` (nearest-neighbour pairs and the soft rounds' partners), `rounds` (the rounds of
//! [`refine_dense`] and [`soften`]), `screening` ([`Coverage`], [`fit_score`], [`object_weights`]).

mod associate;
mod rounds;
mod screening;

pub use associate::associate;
pub use rounds::{DenseResult, Rounds, refine_dense, soften};
pub use screening::{
    Coverage, SELECTION_OBJECT_RADIUS, SELECTION_SIGMA, fit_score, object_weights, probes,
    score_peak,
};

use super::types::{PointSet2, RegistrationError};
use crate::math::{Mat2, Vec2};
use crate::validate::Validator;
use serde::{Deserialize, Serialize};

/// Re-association rounds at most; stops earlier when the pose moves less than 1 mm and 0.01 mrad.
pub const ITERATIONS: usize = 8;

/// Rounds before the [`ITERATIONS`] ones with `max_distance` and `gate` doubled. A descriptor-stage
/// estimate can be a few metres off along a street, where only poles and corners say where along it
/// the submaps sit: beyond `max_distance` they pair with nothing and the facades hold the pose
/// where it is.
pub const COARSE_ROUNDS: usize = 4;

/// Fewest pairs, else the descriptor-stage estimate is kept.
pub const MIN_PAIRS: usize = 30;

/// Factor on the covariance (from the descriptor pairs at the refined pose) when this stage ran:
/// the dense pose is more accurate than the descriptor pairs' own scatter says.
pub const COVARIANCE_SCALE: f64 = 0.35;

/// Target points behind each virtual partner of the soft rounds, the likeliest.
pub const SOFT_NEIGHBOURS: usize = 16;

/// The target points' neighbour index (item = point index): a uniform grid ([`super::grid`]).
pub type TargetTree = super::grid::PointGrid;

/// Cell of the [`TargetTree`] grid, m: the size of this stage's queries (1.5 m pairs, 3 m in the
/// coarse rounds, 2 m surface neighbourhoods).
const GRID_CELL: f64 = 2.0;

/// Settings of the dense stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct DenseConfig {
    /// Run it (default true; off reproduces the paper's descriptor-pairs-only estimate).
    pub enabled: bool,
    /// Largest Mahalanobis distance of a pair under the combined covariance (default 3.0).
    pub gate: f64,
    /// Largest Euclidean distance of a pair, m (default 1.5).
    pub max_distance: f64,
    /// Scale of the robust loss (`registration.lm.robust.kind`) in the rounds after the coarse
    /// ones and in the final solve, in sigma of the whitened residual (default 1.0; 0 keeps
    /// `registration.lm.robust.scale`). Two passes do not see the same scene (parked cars come and
    /// go); once the pose has been pulled in, a tighter loss weighs such pairs down.
    pub robust_scale: f64,
    /// Neighbours whose scatter is added to each point's covariance in this stage (default 8; 0 =
    /// off). Two passes sample a surface at different places, so a nearest neighbour is the same
    /// surface, not the same point: the scatter of the local neighbourhood (long along a facade,
    /// thin across it) models where along the surface the partner may lie, as GICP's surface
    /// covariances do (Segal et al., RSS 2009), on top of the measurement covariance of eq. 7-8.
    pub surface_neighbours: usize,
    /// Radius of that neighbourhood, m (default 2.0).
    pub surface_radius: f64,
    /// Move each point to the mean of that neighbourhood (default true): one step of local
    /// averaging (zeroth-order moving least squares), so nearest neighbours of two passes pair on
    /// the surface instead of on each other's noise. The covariances stay those of single points
    /// plus the scatter.
    pub surface_smoothing: bool,
    /// Accelerated rounds ([`Rounds::Accelerated`]) that continue the winning hypothesis's rounds
    /// when they have not settled (default 0 = off: with it on, a street-slid alignment can pass
    /// the consistency gate).
    pub polish_rounds: usize,
    /// Average the winner's pose with this stage run the other way round (default false): the
    /// target's points paired with their nearest source points, from the inverse pose, which halves
    /// the association bias the two directions do not share. Costs one more run of this stage per
    /// registration; off by default because it moves some first closures of a session across the
    /// slide gate (`loop.maximum_slide_ratio`).
    pub symmetric: bool,
    /// Widen the reported covariance by the association bias (default true): this stage runs once
    /// more the other way round (target points paired with their nearest source points) and half
    /// the outer product of the two poses' difference is added (docs/algorithm.md, "The covariance
    /// reported"). Costs one more run of this stage per registration.
    pub bias_probe: bool,
    /// Widen the reported covariance by the pull of the objects that gave many points (default
    /// true): the translation from the pose to the nearest local maximum of the fit score, which
    /// counts every object once ([`SELECTION_SIGMA`], [`SELECTION_OBJECT_RADIUS`]), adds half its
    /// outer product (docs/algorithm.md, "The covariance reported"); the loop closure gates judge
    /// without it. Costs about 20 evaluations of the fit score per registration.
    pub score_probe: bool,
    /// Prior standard deviation of a common offset of the returns along their rays, m (default
    /// 0.25, the ARS408's range noise; 0 = not estimated). The winner's pose is fitted once more
    /// with the offset (an object's near face, a skewed range noise) at its dense pairs; where the
    /// pair shows one at the 5 % level the pose takes the joint fit, and the offset's prior widens
    /// the covariance along the direction it moves the pose (docs/algorithm.md, "The covariance
    /// reported"). Two passes that saw the scene along the same rays cannot tell it, and are left
    /// as they were.
    pub range_offset_std: f64,
    /// Most source points paired in this stage (default 2000): above it a fixed pseudo-random
    /// subset (the target keeps all its points). A submap stacks several scans, so 2000 points
    /// still hold every reflector several times.
    pub max_source_points: usize,
    /// Soft-association rounds that finish the winning hypothesis's pose (default 0 = off): each
    /// pairs every source point with the likelihood-weighted mean of its [`SOFT_NEIGHBOURS`]
    /// nearest target points within `max_distance` and `gate` (EM-ICP, Granger & Pennec, ECCV
    /// 2002), one Gauss-Newton step per round; kept when it ends within the ambiguity distances.
    /// Slightly more accurate, about 15 % slower per registration, so off by default.
    pub soft_rounds: usize,
}

impl Default for DenseConfig {
    fn default() -> Self {
        DenseConfig {
            enabled: true,
            gate: 3.0,
            max_distance: 1.5,
            robust_scale: 1.0,
            surface_neighbours: 8,
            surface_radius: 2.0,
            surface_smoothing: true,
            polish_rounds: 0,
            symmetric: false,
            bias_probe: true,
            score_probe: true,
            range_offset_std: 0.25,
            max_source_points: 2000,
            soft_rounds: 0,
        }
    }
}

impl DenseConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.positive("gate", self.gate);
        v.positive("max_distance", self.max_distance);
        v.positive("surface_radius", self.surface_radius);
        v.non_negative("robust_scale", self.robust_scale);
        v.non_negative("range_offset_std", self.range_offset_std);
        v.count("polish_rounds", self.polish_rounds, 0, 100);
        v.count("soft_rounds", self.soft_rounds, 0, 100);
        v.count("surface_neighbours", self.surface_neighbours, 0, 64);
        v.at_least("max_source_points", self.max_source_points, MIN_PAIRS);
    }
}

/// Builds the target's neighbour index (items are `u32`: at most `u32::MAX` points).
pub fn target_tree(target: &PointSet2) -> Result<TargetTree, RegistrationError> {
    if u32::try_from(target.len()).is_err() {
        return Err(RegistrationError::Numerical(format!(
            "{} points do not fit the neighbour grid's u32 index",
            target.len()
        )));
    }
    Ok(TargetTree::new(&target.points, GRID_CELL))
}

/// The points this stage pairs, with their tree: each covariance enlarged by the scatter of its
/// `surface_neighbours` nearest neighbours within `surface_radius` (including itself), see
/// [`DenseConfig::surface_neighbours`], and with `surface_smoothing` each point moved to that
/// neighbourhood's mean; the tree indexes the moved points.
pub fn prepare(
    set: &PointSet2,
    cfg: &DenseConfig,
) -> Result<(PointSet2, TargetTree), RegistrationError> {
    let tree = target_tree(set)?;
    let out = with_surface_covariances(set, &tree, cfg);
    if out.points == set.points {
        return Ok((out, tree));
    }
    let moved = target_tree(&out)?;
    Ok((out, moved))
}

/// [`prepare`]'s points, given the tree of `set`.
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
    // Scratch reused for every point.
    let mut nn = Vec::with_capacity(4 * k.get());
    let mut near: Vec<&Vec2> = Vec::with_capacity(k.get());
    for ((p, c), moved) in set
        .points
        .iter()
        .zip(out.covs.iter_mut())
        .zip(out.points.iter_mut())
    {
        tree.nearest_k(p, k.get(), cfg.surface_radius, &mut nn);
        near.clear();
        near.extend(nn.iter().filter_map(|n| set.points.get(n.0 as usize)));
        if near.len() < 3 {
            continue;
        }
        let mean = near.iter().fold(crate::math::Vec2::zeros(), |a, q| a + *q) / near.len() as f64;
        let scatter = near.iter().fold(Mat2::zeros(), |a, q| {
            let d = *q - mean;
            a + d * d.transpose()
        }) / (near.len() - 1) as f64;
        *c += scatter;
        if cfg.surface_smoothing {
            *moved = mean;
        }
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
        rays: if set.rays.is_empty() {
            Vec::new()
        } else {
            keep.iter().map(|&i| set.rays[i as usize]).collect()
        },
    })
}

const SUBSET_SEED: u64 = 0xD3_45E5_0B5E;

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// A noisy facade (points along x, noise across it): smoothing moves the points to
    /// neighbourhood means, which lie much nearer the facade; the tree indexes the moved points;
    /// off leaves them.
    #[test]
    fn smoothing_pulls_facade_points_onto_the_surface_and_the_tree_follows() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let points: Vec<Vec2> = (0..400)
            .map(|i| Vec2::new(i as f64 * 0.1, 0.25 * (rng.random::<f64>() - 0.5) * 3.46))
            .collect();
        let set = PointSet2::isotropic(points, 0.25);
        let rms = |s: &PointSet2| {
            (s.points.iter().map(|p| p.y * p.y).sum::<f64>() / s.len() as f64).sqrt()
        };
        let cfg = DenseConfig::default();
        let (smoothed, tree) = prepare(&set, &cfg).expect("prepared");
        assert!(rms(&set) > 0.2, "{}", rms(&set));
        // 8 neighbours: about 1/sqrt(8) of the noise for independent means; overlapping ones keep more.
        assert!(
            rms(&smoothed) < 0.65 * rms(&set),
            "{} {}",
            rms(&smoothed),
            rms(&set)
        );
        // Along the facade the points keep their place to within the neighbourhood's reach.
        for (a, b) in set.points.iter().zip(&smoothed.points) {
            assert!((a.x - b.x).abs() < 0.5, "{a} -> {b}");
        }
        for (i, p) in smoothed.points.iter().enumerate().step_by(37) {
            let nn = tree.nearest_two(p, 1.0).expect("itself");
            assert_eq!(nn.1, 0.0, "point {i}");
        }
        // The covariances grow by the scatter, whatever the smoothing.
        assert!(
            smoothed
                .covs
                .iter()
                .zip(&set.covs)
                .all(|(a, b)| a[(0, 0)] > b[(0, 0)])
        );
        let off = DenseConfig {
            surface_smoothing: false,
            ..DenseConfig::default()
        };
        let (kept, _) = prepare(&set, &off).expect("prepared");
        assert_eq!(kept.points, set.points);
    }
}
