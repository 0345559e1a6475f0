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
//! Entry points: [`DenseConfig`], [`target_tree`], [`refine_dense`] ([`Rounds`]).//!
//! Parts: `associate` (nearest-neighbour pairs and the soft rounds' partners), `rounds` (the rounds of
//! [`refine_dense`] and [`soften`]), `screening` ([`Coverage`], [`fit_score`], [`object_weights`]).

mod associate;
mod rounds;
mod screening;

pub use associate::associate;
pub use rounds::{DenseResult, Rounds, refine_dense, soften};
pub use screening::{Coverage, fit_score, object_weights, probes};

use super::{PointSet2, RegistrationError};
use crate::math::{Mat2, Vec2};
use crate::validate::Validator;
use serde::{Deserialize, Serialize};

/// The target points' neighbour index (item = point index): a uniform grid ([`super::grid`]).
pub type TargetTree = super::grid::PointGrid;

/// Cell of the [`TargetTree`] grid, m: the size of this stage's queries (1.5 m pairs, 3 m in the
/// coarse rounds, 2 m surface neighbourhoods).
const GRID_CELL: f64 = 2.0;

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
    /// Rounds before the `iterations` ones with `max_distance` and `gate` doubled (default 4). A
    /// descriptor-stage estimate can be a few metres off along a street, where only poles and corners
    /// say where along it the submaps sit: beyond `max_distance` they pair with nothing and the
    /// facades hold the pose where it is. Measured with `dc_loc eval` on the demo drive, DC-Loc mean /
    /// max translation error over the inliers: 0 rounds 0.094 / 1.97 m, 3: 0.088 / 1.33, 4: 0.086 /
    /// 1.06, 5: 0.086 / 1.02, 8: 0.085 / 0.58 (median 0.072-0.073 m throughout); a five-radar revisit
    /// that ended 2.2 m off (and was published as a false closure) ends 0.64 m off with 4.
    pub coarse_rounds: usize,
    /// Largest Euclidean distance of a pair, m (default 1.5).
    pub max_distance: f64,
    /// Scale of the robust loss (`registration.lm.robust.kind`) in the rounds after the coarse
    /// ones and in the final solve, in sigma of the whitened residual (default 1.0; 0 keeps
    /// `registration.lm.robust.scale`). Two passes do not see the same scene: parked cars are
    /// replaced between them (the simulated city replaces or removes 45 % of them), and a car in
    /// the same slot stands half a metre further along the street; the nearest-neighbour pairs of
    /// such objects pull the pose along the street by centimetres. A tighter loss once the pose
    /// has been pulled in weighs them down. Measured with `dc_loc eval` (DC-Loc mean / max / median
    /// translation error, mean rotation error, mean NEES), the default Gaussian demo drive: 3.0
    /// (the LM's scale) 0.085 / 1.475 / 0.072 m, 0.0016 rad, 5.88; 1.5: 0.079 / 1.474 / 0.065 m,
    /// 0.0015 rad, 4.98; 1.0: 0.075 / 1.465 / 0.064 m, 0.0015 rad, 4.40. The same drive with no
    /// parked car replaced (`world.parking.changing_fraction` 0): 0.060 / 0.053 m at 3.0, 0.050 m
    /// median at 1.0 applied to every round. Student-t drive 0.084 / 0.071 -> 0.077 / 0.063 m;
    /// Gamma 0.047 / 0.033 -> 0.046 / 0.031 m (its max 0.53 -> 1.72 m: one pair); seed 2 0.074 /
    /// 0.065 -> 0.072 / 0.062 m. Applied to the coarse rounds too it pulled some Gamma pairs to
    /// slid alignments (max 1.83 m). A scale from the residuals' median (IRLS with a MAD scale)
    /// did no better (Gaussian 0.078 / 0.063 m at twice the MAD scale, Gamma max 1.84 m).
    pub robust_scale: f64,
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
    /// Move each point to the mean of that neighbourhood (default true): one step of local averaging
    /// (the zeroth-order moving least squares of point-cloud smoothing). Two passes sample a surface
    /// at different places and with independent range / cross-range noise; the means of overlapping
    /// neighbourhoods carry a fraction of that noise, so nearest neighbours of two passes pair on the
    /// surface instead of on each other's noise. The covariances stay those of single points plus the
    /// scatter (conservative). Measured with `dc_loc eval` on the demo drive (DC-Loc mean / median
    /// translation error over the inliers, mean rotation error, pairs inside 2 m):
    /// `-p registration.dense.surface_smoothing:=false` 0.115 / 0.087 m, 0.0020 rad, 91.1 %; on (this)
    /// 0.086 / 0.073 m, 0.0015 rad, 91.8 %. Moving points onto the neighbourhood's principal line
    /// instead (first-order MLS, keeping the place along the surface; a variant not kept in the code,
    /// measured before the screening and the coarse rounds) gave 0.103 / 0.075 m against 0.090 / 0.072 m
    /// for the mean.
    pub surface_smoothing: bool,
    /// Accelerated rounds ([`Rounds::Accelerated`]) that continue the winning hypothesis's rounds when they
    /// have not settled (default 0 = off). Measured with `dc_loc eval` on the demo drive, DC-Loc mean /
    /// median translation error over the inliers: off 0.121 / 0.082 m, 2 rounds 0.111 / 0.078, 3:
    /// 0.103 / 0.077, 4: 0.107 / 0.080, 6: 0.111 / 0.084, 8: 0.104 / 0.079 (differences below about
    /// 5 mm are which pairs fall inside the 2 m threshold); registration time +7 % (1000 points) to
    /// +10 % (5000 points) at 3 rounds. Off by default because of the loop-closure gates: with 3
    /// rounds the five-radar Student-t 3 % reverse drive published one false closure (2.5 m, a
    /// street-slid alignment that was already 2.5 m off before polishing; the slightly different pose
    /// and covariance let it pass the consistency check that refused it as ambiguous without
    /// polishing). Bounding the polish's move (half the ambiguity distances, or 99 % of the prior
    /// covariance) kept that closure and lost most of the accuracy gain. Since the smoothing and the
    /// coarse rounds the plain rounds end nearer their fixed point: 3 rounds then changed the demo
    /// drive's 0.086 / 0.073 m to 0.085 / 0.072 m.
    pub polish_rounds: usize,
    /// Average the winner's pose with this stage run the other way round (default false): the
    /// target's points paired with their nearest source points, from the inverse pose. Each
    /// direction pairs a point with the nearest sample of the other pass and carries its own
    /// association bias; the mean of the two halves the part they do not share. Costs one more run
    /// of this stage per registration (the winner's only; about 20 % of a 1000-point registration,
    /// callgrind instruction counts). Measured with `dc_loc eval` on the demo drives (DC-Loc mean /
    /// max / median translation error over the inliers, mean rotation error, mean NEES; pairs inside
    /// 2 m unchanged): Gaussian off 0.086 / 1.062 / 0.073 m, 0.0015 rad, NEES 5.96; on 0.078 / 0.757
    /// / 0.067 m, 0.0014 rad, 4.09. Student-t off 0.085 / 0.446 / 0.072 m, on 0.075 / 0.360 / 0.062
    /// m. Gamma 0.049 / 0.032 m mean / median either way. Off by default: over the revisit matrix
    /// (`dc_loc revisits`) it moved a few first closures of a session across the slide gate
    /// (`loop.maximum_slide_ratio`), and the five-radar Gamma drive at 3 % drift closed none of its
    /// 432 same-direction revisits (98.6 % with it off; no false closure either way).
    pub symmetric: bool,
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
    /// Soft-association rounds that finish the winning hypothesis's pose (default 0 = off): each
    /// pairs every source point with a virtual partner, the mean of its `soft_neighbours` nearest
    /// target points within `max_distance` and `gate`, weighted by their Gaussian likelihood under
    /// the combined covariance, with the weighted covariance plus the partners' scatter (EM-ICP,
    /// Granger & Pennec, ECCV 2002); one Gauss-Newton step per round, then the last round's pairs
    /// are solved to the LM's tolerances. A nearest neighbour pairs a point with one sample of the
    /// other pass, which pulls the pose by the sampling offset where the passes sampled a surface
    /// at different places; the likelihood-weighted mean averages it out. Run for the winner only
    /// (as polishing is), and kept when it ends within the ambiguity distances of it. Measured with
    /// `dc_loc eval -p registration.dense.soft_rounds:=N` on the default Gaussian demo drive (DC-Loc
    /// mean / median translation error over the inliers, mean NEES; pairs inside 2 m unchanged at
    /// 412 of 416): off 0.075 / 0.065 m, 2.90; 1 round 0.070 / 0.062 m, 2.42; 3 rounds 0.069 /
    /// 0.061 m, 2.36; 10 rounds 0.069 / 0.060 m, 2.36. The Student-t drive at 3 rounds 0.078 / 0.064
    /// -> 0.069 / 0.058 m; Gamma 0.044 / 0.031 -> 0.041 / 0.031 m. The registration bench's
    /// 1000-point pair (`DC_LOC_BENCH_PARAMS="registration.dense.soft_rounds:=N" cargo bench --bench
    /// registration`): 2.95 ms off, 3.18 ms at 1 round, 3.40 ms at 3 (the target is 3 ms), so off by
    /// default.
    pub soft_rounds: usize,
    /// Target points behind each virtual partner of the soft rounds, the likeliest (default 16; at 3
    /// rounds on the Gaussian demo drive 8 gave 0.072 / 0.065 m, 32 gave 0.068 / 0.061 m).
    pub soft_neighbours: usize,
}

impl Default for DenseConfig {
    fn default() -> Self {
        DenseConfig {
            enabled: true,
            iterations: 8,
            gate: 3.0,
            coarse_rounds: 4,
            max_distance: 1.5,
            robust_scale: 1.0,
            min_pairs: 30,
            surface_neighbours: 8,
            surface_radius: 2.0,
            surface_smoothing: true,
            polish_rounds: 0,
            symmetric: false,
            max_source_points: 2000,
            covariance_scale: 0.35,
            soft_rounds: 0,
            soft_neighbours: 16,
        }
    }
}

impl DenseConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.at_least("iterations", self.iterations, 1);
        v.positive("gate", self.gate);
        v.positive("max_distance", self.max_distance);
        v.positive("surface_radius", self.surface_radius);
        v.positive("covariance_scale", self.covariance_scale);
        v.non_negative("robust_scale", self.robust_scale);
        if self.soft_rounds > 0 {
            v.count("soft_neighbours", self.soft_neighbours, 1, 64);
        }
        v.count("surface_neighbours", self.surface_neighbours, 0, 64);
        v.at_least("max_source_points", self.max_source_points, self.min_pairs);
        v.at_least("min_pairs", self.min_pairs, 3);
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
    })
}

const SUBSET_SEED: u64 = 0xD3_45E5_0B5E;

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// A noisy facade (points along x, noise across it): smoothing moves the points to neighbourhood
    /// means, which lie much nearer the facade; the tree indexes the moved points; off leaves them.
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
