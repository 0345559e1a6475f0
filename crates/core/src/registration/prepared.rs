//! What a registration works on: a submap prepared once per keyframe ([`PreparedSubmap`]:
//! descriptors, their index, and what the dense stage and the screening need, [`DenseSide`]), and
//! one pair of submaps as every stage sees it ([`PairContext`]).

use super::bearings::Bearings;
use super::config::RegistrationConfig;
use super::types::{PointSet2, RegistrationError};
use super::{dense, descriptor, matching, ransac};
use crate::math::Vec2;

/// Cell of the screening's coverage grid, m: a RANSAC motion a metre off still scores its overlap.
const SCREEN_CELL: f64 = 1.0;
/// Source points probed per screened motion.
const SCREEN_PROBES: usize = 256;

/// What the dense stage and the screening keep of one submap.
#[derive(Debug)]
pub struct DenseSide {
    /// The points with surface covariances, smoothed.
    points: PointSet2,
    /// Their tree (as a target).
    tree: dense::TargetTree,
    /// The dense stage's source points when they are a subset of `points`.
    subset: Option<PointSet2>,
    /// The fit score's weight of each source point ([`dense::object_weights`]).
    weights: Vec<f64>,
    /// Cells covered by `points` (as a target) and the probes (as a source) of the screening.
    coverage: dense::Coverage,
    probes: Vec<Vec2>,
    /// The raw points' bearings from the anchor ([`super::common_view`]).
    bearings: Bearings,
}

impl DenseSide {
    /// The dense stage's and the screening's view of `points`.
    pub fn new(points: &PointSet2, cfg: &RegistrationConfig) -> Result<Self, RegistrationError> {
        let (dense_points, tree) = dense::prepare(points, &cfg.dense)?;
        let subset = dense::source_subset(&dense_points, &cfg.dense);
        let weights = dense::object_weights(
            &subset.as_ref().unwrap_or(&dense_points).points,
            dense::SELECTION_OBJECT_RADIUS,
        );
        Ok(DenseSide {
            coverage: dense::Coverage::new(&dense_points.points, SCREEN_CELL),
            probes: dense::probes(&dense_points, SCREEN_PROBES),
            bearings: Bearings::new(&points.points),
            points: dense_points,
            tree,
            subset,
            weights,
        })
    }

    /// The points the dense stage pairs when this submap is the source.
    pub fn as_source(&self) -> &PointSet2 {
        self.subset.as_ref().unwrap_or(&self.points)
    }

    /// All points, as a target.
    pub fn as_target(&self) -> &PointSet2 {
        &self.points
    }

    /// Their tree, as a target.
    pub fn tree(&self) -> &dense::TargetTree {
        &self.tree
    }

    /// The bearings of the raw points.
    pub fn bearings(&self) -> &Bearings {
        &self.bearings
    }
}

/// What the dense stage and the screening use of the two submaps.
#[derive(Clone, Copy)]
pub struct DenseSets<'a> {
    /// Source points (surface covariances, smoothed, at most `max_source_points`).
    pub src: &'a PointSet2,
    /// Their weights in the fit score ([`dense::object_weights`]).
    pub weights: &'a [f64],
    /// Target points, likewise (all of them), and their tree.
    pub tgt: &'a PointSet2,
    /// The target points' tree.
    pub tree: &'a dense::TargetTree,
    /// The other way round, for the symmetric dense stage: the target's points as a source (at most
    /// `max_source_points`), the source's points as a target (all of them) and their tree.
    pub tgt_as_source: &'a PointSet2,
    /// The source's points as a target.
    pub src_as_target: &'a PointSet2,
    /// Their tree.
    pub src_tree: &'a dense::TargetTree,
    /// Source probes of the screening.
    pub probes: &'a [Vec2],
    /// Target coverage of the screening.
    pub coverage: &'a dense::Coverage,
    /// Bearings of the source's and the target's points.
    pub bearings: (&'a Bearings, &'a Bearings),
}

impl<'a> DenseSets<'a> {
    /// The sets of a registration of `src` onto `tgt`.
    pub fn new(src: &'a DenseSide, tgt: &'a DenseSide) -> Self {
        DenseSets {
            src: src.as_source(),
            weights: &src.weights,
            tgt: &tgt.points,
            tree: &tgt.tree,
            tgt_as_source: tgt.as_source(),
            src_as_target: &src.points,
            src_tree: &src.tree,
            probes: &src.probes,
            coverage: &tgt.coverage,
            bearings: (&src.bearings, &tgt.bearings),
        }
    }
}

/// One registration's inputs as every stage sees them: the two point sets (the descriptor pairs'
/// points), their dense sets, the candidate correspondences and the settings.
#[derive(Clone, Copy)]
pub struct PairContext<'a> {
    /// The source (query) points.
    pub source: &'a PointSet2,
    /// The target (match) points.
    pub target: &'a PointSet2,
    /// What the dense stage and the screening use.
    pub sets: DenseSets<'a>,
    /// Candidate correspondences from descriptor matching (point indices).
    pub candidates: &'a [ransac::Correspondence],
    /// The settings.
    pub cfg: &'a RegistrationConfig,
}

/// The dense-stage settings a [`PreparedSubmap`] bakes in.
#[derive(Debug, Clone, Copy, PartialEq)]
struct DenseBaked {
    surface_neighbours: usize,
    surface_radius: f64,
    surface_smoothing: bool,
    max_source_points: usize,
}

impl DenseBaked {
    fn of(cfg: &RegistrationConfig) -> Self {
        let d = &cfg.dense;
        DenseBaked {
            surface_neighbours: d.surface_neighbours,
            surface_radius: d.surface_radius,
            surface_smoothing: d.surface_smoothing,
            max_source_points: d.max_source_points,
        }
    }
}

/// A submap ready for matching: its points, descriptors and descriptor index, and what the dense
/// stage and the screening need. Build it once per keyframe and reuse it for every registration
/// against that keyframe.
#[derive(Debug)]
pub struct PreparedSubmap {
    points: PointSet2,
    keypoints: Vec<u32>,
    descriptors: Vec<descriptor::Descriptor>,
    index: matching::DescriptorIndex,
    descriptor_config: descriptor::DescriptorConfig,
    backend: matching::MatchingBackend,
    baked: DenseBaked,
    dense: DenseSide,
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
        let dense = DenseSide::new(&points, cfg)?;
        Ok(PreparedSubmap {
            points,
            keypoints,
            descriptors,
            index,
            descriptor_config: cfg.descriptor.clone(),
            backend: cfg.matching.backend,
            baked: DenseBaked::of(cfg),
            dense,
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
    /// What the dense stage and the screening use of it.
    pub fn dense(&self) -> &DenseSide {
        &self.dense
    }
    /// True when it was built with `cfg`'s descriptor, matching-backend and dense-stage preparation
    /// settings (surface neighbours, radius and smoothing, most source points, the fit score's
    /// object radius), i.e. registering it under `cfg` is the same as preparing it anew.
    pub fn fits(&self, cfg: &RegistrationConfig) -> bool {
        self.descriptor_config == cfg.descriptor
            && self.backend == cfg.matching.backend
            && self.baked == DenseBaked::of(cfg)
    }
    /// The descriptor settings it was built with.
    pub fn descriptor_config(&self) -> &descriptor::DescriptorConfig {
        &self.descriptor_config
    }
}

/// An invalid configuration as a registration error (the registration entry points check it, so
/// that no setting can make them panic or return nonsense).
pub fn checked_config(cfg: &RegistrationConfig) -> Result<(), RegistrationError> {
    cfg.validate()
        .map_err(|e| RegistrationError::Numerical(format!("invalid configuration: {e}")))
}

/// Every point finite with one positive definite covariance.
pub fn check_point_set(set: &PointSet2) -> Result<(), RegistrationError> {
    if set.covs.len() != set.points.len() {
        return Err(RegistrationError::Numerical(format!(
            "{} points but {} covariances",
            set.points.len(),
            set.covs.len()
        )));
    }
    if !(set.rays.is_empty() || set.rays.len() == set.points.len()) {
        return Err(RegistrationError::Numerical(format!(
            "{} points but {} rays",
            set.points.len(),
            set.rays.len()
        )));
    }
    if let Some(i) = set
        .rays
        .iter()
        .position(|u| !u.iter().all(|v| v.is_finite()))
    {
        return Err(RegistrationError::Numerical(format!(
            "point {i}: non-finite ray"
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
