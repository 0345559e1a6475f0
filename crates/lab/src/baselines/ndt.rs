//! 2D Normal Distributions Transform (Biber & Strasser, IROS 2003), the "NDT" row of the paper's Table 1.
//!
//! [`register_ndt`] runs, per cell size of the schedule (coarse to fine, the coarse stages blurred),
//! Newton's method with a trust region and a line search on the NDT score of four half-cell-shifted
//! grids of Gaussians over the target ([`NdtMap`]), from an initial guess `t_target_source`, and takes
//! the covariance from the Hessian at the optimum. docs/algorithm.md, "Baselines", has the steps, why
//! the coarse stages are blurred and the covariance's derivation.
//!
//! Entry points: [`register_ndt`], [`NdtConfig`], [`NdtMap`] (the transform of the target and the
//! objective with its analytic derivatives), [`NdtObjective`].

use super::{check_points, check_pose, spd_inverse};
use dc_loc_core::math::{Iso2, Mat2, Mat3, Vec2, Vec3};
use dc_loc_core::registration::{
    PointSet2, RegistrationError, RegistrationResult, covariance_ros_from_se2,
};
use dc_loc_core::validate::{ConfigError, Range, Validator};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// Mahalanobis distance below which a source point counts as an inlier of a cell (3 sigma).
const INLIER_MAHALANOBIS: f64 = 3.0;

/// 2D NDT settings (params YAML section `baselines.ndt`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NdtConfig {
    /// Cell sizes, m, one Newton stage each, coarse to fine (non-increasing).
    pub cell_sizes: Vec<f64>,
    /// Fewest target points for a cell to get a Gaussian (the paper: 3).
    pub min_points_per_cell: usize,
    /// Smallest allowed ratio of a cell covariance's eigenvalues (the paper: 0.001).
    pub min_eigenvalue_ratio: f64,
    /// Newton iteration limit per stage.
    pub max_iterations: usize,
    /// Convergence: translation of the last accepted step below this, m.
    pub translation_tolerance: f64,
    /// Convergence: rotation of the last accepted step below this, rad.
    pub rotation_tolerance: f64,
    /// Trust region: largest translation step, in cells of the current stage.
    pub max_step_cells: f64,
    /// Trust region: largest rotation step, rad.
    pub max_step_rotation: f64,
    /// Fewest source points that must fall into cells; fewer is a failure.
    pub min_points_in_cells: usize,
    /// Coarse stages (all but the last) add `(coarse_sigma_ratio * cell size)^2` to every cell
    /// covariance's eigenvalues, widening the basin (0 = the paper's NDT at every stage).
    pub coarse_sigma_ratio: f64,
}

impl Default for NdtConfig {
    /// Cell sizes 8 m, 4 m, 2 m with the coarse stages blurred by half a cell (docs/algorithm.md, "Baselines"); the paper's 3 points per cell and eigenvalue ratio 0.001; 50 Newton iterations per stage;
    /// tolerances 1e-4 m and 1e-5 rad; steps of at most half a cell and 0.1 rad; at least 6 source points
    /// in cells.
    fn default() -> Self {
        NdtConfig {
            cell_sizes: vec![8.0, 4.0, 2.0],
            min_points_per_cell: 3,
            min_eigenvalue_ratio: 0.001,
            max_iterations: 50,
            translation_tolerance: 1e-4,
            rotation_tolerance: 1e-5,
            max_step_cells: 0.5,
            max_step_rotation: 0.1,
            min_points_in_cells: 6,
            coarse_sigma_ratio: 0.5,
        }
    }
}

impl NdtConfig {
    /// Rejects unusable values, naming them `baselines.ndt.*`.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut v = Validator::at("baselines.ndt");
        self.check(&mut v);
        v.finish()
    }

    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        let c = &self.cell_sizes;
        v.require("cell_sizes", !c.is_empty(), || {
            "at least one cell size is required".into()
        });
        for (i, &size) in c.iter().enumerate() {
            v.positive("cell_sizes", size);
            v.require("cell_sizes", i == 0 || size <= c[i - 1], || {
                "the schedule must run from coarse to fine (non-increasing)".into()
            });
        }
        v.at_least("min_points_per_cell", self.min_points_per_cell, 2);
        v.range(
            "min_eigenvalue_ratio",
            self.min_eigenvalue_ratio,
            Range::above(0.0).up_to(1.0),
        );
        v.at_least("max_iterations", self.max_iterations, 1);
        v.positive("translation_tolerance", self.translation_tolerance);
        v.positive("rotation_tolerance", self.rotation_tolerance);
        v.positive("max_step_cells", self.max_step_cells);
        v.positive("max_step_rotation", self.max_step_rotation);
        v.non_negative("coarse_sigma_ratio", self.coarse_sigma_ratio);
        v.at_least("min_points_in_cells", self.min_points_in_cells, 3);
    }
}

/// One cell's Gaussian: mean (m) and inverse covariance (1/m^2).
#[derive(Debug, Clone, Copy)]
struct Cell {
    mean: Vec2,
    inv_cov: Mat2,
}

/// The NDT of a target point set: four half-cell-shifted grids of Gaussians.
#[derive(Debug, Clone)]
pub struct NdtMap {
    cell_size: f64,
    /// Grid origins, m: (0, 0), (c/2, 0), (0, c/2), (c/2, c/2).
    offsets: [Vec2; 4],
    grids: [HashMap<(i64, i64), Cell>; 4],
}

/// `f = -score` with its derivatives over the absolute parameters `p = (t_x, t_y, phi)` of
/// `t_target_source`, and the counts the registration reports.
#[derive(Debug, Clone, PartialEq)]
pub struct NdtObjective {
    /// `f = -sum exp(-d^T Sigma^-1 d / 2)` (dimensionless; lower is better).
    pub value: f64,
    /// `df/dp`, p = (t_x m, t_y m, phi rad).
    pub gradient: Vec3,
    /// `d^2 f/dp^2`.
    pub hessian: Mat3,
    /// Its Gauss-Newton part `sum e J^T Sigma^-1 J` (positive semi-definite).
    pub gauss_newton: Mat3,
    /// `sum_i g_i g_i^T` over source points, `g_i` a point's gradient summed over its grids (the "meat"
    /// of a sandwich covariance).
    pub gradient_outer: Mat3,
    /// Source points that fall into at least one cell.
    pub points_in_cells: usize,
    /// (point, grid) pairs that fall into a cell.
    pub contributions: usize,
    /// Source points within 3 Mahalanobis units (3 sigma) of a cell's mean in at least one grid.
    pub inliers: usize,
}

impl NdtMap {
    /// Builds the transform of `points` (finite, target frame) with square cells of `cell_size` m.
    pub fn new(
        points: &[Vec2],
        cell_size: f64,
        min_points_per_cell: usize,
        min_eigenvalue_ratio: f64,
        added_variance: f64,
    ) -> Self {
        let h = cell_size / 2.0;
        let offsets = [
            Vec2::zeros(),
            Vec2::new(h, 0.0),
            Vec2::new(0.0, h),
            Vec2::new(h, h),
        ];
        let grids = offsets.map(|o| {
            let mut buckets: HashMap<(i64, i64), Vec<Vec2>> = HashMap::new();
            for p in points {
                buckets.entry(key(p, &o, cell_size)).or_default().push(*p);
            }
            buckets
                .into_iter()
                .filter(|(_, pts)| pts.len() >= min_points_per_cell)
                .filter_map(|(k, pts)| {
                    gaussian(&pts, min_eigenvalue_ratio, added_variance).map(|c| (k, c))
                })
                .collect()
        });
        NdtMap {
            cell_size,
            offsets,
            grids,
        }
    }

    /// Cell size, m.
    pub fn cell_size(&self) -> f64 {
        self.cell_size
    }

    /// Cells with a Gaussian, over all four grids.
    pub fn cells(&self) -> usize {
        self.grids.iter().map(HashMap::len).sum()
    }

    /// `f = -score` only (no derivatives), at `t_target_source`.
    pub fn value(&self, source: &[Vec2], t_target_source: &Iso2) -> f64 {
        let mut f = 0.0;
        for x in source {
            let xp = (t_target_source * nalgebra::Point2::from(*x)).coords;
            for (o, grid) in self.offsets.iter().zip(&self.grids) {
                if let Some(c) = grid.get(&key(&xp, o, self.cell_size)) {
                    let d = xp - c.mean;
                    f -= (-0.5 * d.dot(&(c.inv_cov * d))).exp();
                }
            }
        }
        f
    }

    /// `f = -score` with its analytic gradient and Hessian over `p = (t_x, t_y, phi)` (Biber & Strasser
    /// Sec. IV): with `d = R x + t - q`, `a = Sigma^-1 d`, `e = exp(-d^T a / 2)` and `J = dd/dp`,
    /// `grad f = sum e J^T a`, `hess f = sum e (J^T Sigma^-1 J - (J^T a)(J^T a)^T + a^T d2d/dphi2 [phi, phi])`.
    pub fn objective(&self, source: &[Vec2], p: &Vec3) -> NdtObjective {
        let (s, c) = p.z.sin_cos();
        let t = Vec2::new(p.x, p.y);
        let mut out = NdtObjective {
            value: 0.0,
            gradient: Vec3::zeros(),
            hessian: Mat3::zeros(),
            gauss_newton: Mat3::zeros(),
            gradient_outer: Mat3::zeros(),
            points_in_cells: 0,
            contributions: 0,
            inliers: 0,
        };
        let inlier_m = INLIER_MAHALANOBIS * INLIER_MAHALANOBIS;
        for x in source {
            let xp = Vec2::new(c * x.x - s * x.y, s * x.x + c * x.y) + t;
            // dd/dphi and d2d/dphi2; the translation part of J is the identity.
            let dphi = Vec2::new(-s * x.x - c * x.y, c * x.x - s * x.y);
            let ddphi = Vec2::new(-c * x.x + s * x.y, -s * x.x - c * x.y);
            let jac = nalgebra::Matrix2x3::new(1.0, 0.0, dphi.x, 0.0, 1.0, dphi.y);
            let (mut hit, mut inlier) = (false, false);
            let mut g_i = Vec3::zeros();
            for (o, grid) in self.offsets.iter().zip(&self.grids) {
                let Some(cell) = grid.get(&key(&xp, o, self.cell_size)) else {
                    continue;
                };
                hit = true;
                out.contributions += 1;
                let d = xp - cell.mean;
                let a = cell.inv_cov * d;
                let m = d.dot(&a);
                inlier |= m < inlier_m;
                let e = (-0.5 * m).exp();
                let ja = jac.transpose() * a;
                out.value -= e;
                out.gradient += ja * e;
                g_i += ja * e;
                let gn = jac.transpose() * cell.inv_cov * jac;
                let mut h = gn - ja * ja.transpose();
                h[(2, 2)] += a.dot(&ddphi);
                out.hessian += h * e;
                out.gauss_newton += gn * e;
            }
            out.gradient_outer += g_i * g_i.transpose();
            out.points_in_cells += usize::from(hit);
            out.inliers += usize::from(inlier);
        }
        out
    }
}

/// Grid key of `p` in the grid with origin `o`.
fn key(p: &Vec2, o: &Vec2, cell: f64) -> (i64, i64) {
    (
        ((p.x - o.x) / cell).floor() as i64,
        ((p.y - o.y) / cell).floor() as i64,
    )
}

/// A cell's regularised Gaussian; `None` when its points coincide.
fn gaussian(pts: &[Vec2], min_ratio: f64, added_variance: f64) -> Option<Cell> {
    let n = pts.len() as f64;
    let mean = pts.iter().sum::<Vec2>() / n;
    let cov = pts
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<Mat2>()
        / n;
    let eig = nalgebra::SymmetricEigen::new(cov);
    let lmax = eig.eigenvalues.max();
    // Points within a micrometre of each other carry no shape.
    if !(lmax.is_finite() && lmax > 1e-12) {
        return None;
    }
    let floor = min_ratio * lmax;
    let inv_l = eig
        .eigenvalues
        .map(|l| 1.0 / (l.max(floor) + added_variance));
    let v = eig.eigenvectors;
    let inv_cov = v * Mat2::from_diagonal(&inv_l) * v.transpose();
    Some(Cell { mean, inv_cov })
}

/// `p = (t_x, t_y, phi)` of a pose.
fn params(t: &Iso2) -> Vec3 {
    Vec3::new(t.translation.x, t.translation.y, t.rotation.angle())
}

/// The pose of `p = (t_x, t_y, phi)`.
fn pose(p: &Vec3) -> Iso2 {
    Iso2::new(Vec2::new(p.x, p.y), p.z)
}

/// A positive definite stand-in for the Hessian `H` of `f`: its eigenvalues replaced by their absolute
/// values, floored at `1e-6` of the largest.
///
/// Biber & Strasser add `lambda I` to an indefinite `H`; with translation in metres and rotation in radians
/// the rotation curvature of a 50 m submap is ~1000 times the translation's, and a `lambda` that fixes one
/// direction swamps or ignores the other. Flipping negative curvature (saddle-free Newton, Dauphin et al.
/// 2014) keeps each direction's own scale and still gives a descent direction.
fn make_positive_definite(h: &Mat3) -> Mat3 {
    let eig = nalgebra::SymmetricEigen::new((h + h.transpose()) * 0.5);
    let hi = eig.eigenvalues.abs().max().max(1e-12);
    let l = eig.eigenvalues.map(|l| l.abs().max(1e-6 * hi));
    eig.eigenvectors * Mat3::from_diagonal(&l) * eig.eigenvectors.transpose()
}

/// Registers `source` onto `target` with 2D NDT from `initial_t_target_source`.
///
/// Errors: [`RegistrationError::TooFewPoints`] when the source has fewer than `min_points_in_cells` or the
/// target fewer than `min_points_per_cell` points, [`RegistrationError::TooFewInliers`] when the target
/// yields no cell or fewer than `min_points_in_cells` source points fall into cells,
/// [`RegistrationError::Numerical`] for non-finite input or a Hessian at the optimum that is not positive
/// definite (no covariance: e.g. all source points identical). Not converging within the iteration limit
/// is not an error: the result says `converged: false`.
pub fn register_ndt(
    source: &PointSet2,
    target: &PointSet2,
    initial_t_target_source: &Iso2,
    config: &NdtConfig,
) -> Result<RegistrationResult, RegistrationError> {
    config
        .validate()
        .map_err(|e| RegistrationError::Numerical(e.to_string()))?;
    let need = config.min_points_in_cells;
    check_points("source", &source.points, need)?;
    check_points("target", &target.points, config.min_points_per_cell)?;
    check_pose("initial guess", initial_t_target_source)?;

    let mut p = params(initial_t_target_source);
    let mut iterations = 0;
    let mut converged = false;
    let mut map = None;
    for (stage, &cell) in config.cell_sizes.iter().enumerate() {
        // Step 1: the transform of the target at this cell size.
        let m = stage_map(target, config, stage, cell);
        if m.cells() == 0 {
            return Err(RegistrationError::TooFewInliers { have: 0, need });
        }
        // Step 2: Newton's method with a trust region and a backtracking line search.
        converged = newton_stage(&m, source, &mut p, config, &mut iterations)?;
        log::debug!(
            "ndt: stage {cell} m ({} cells) done after {iterations} iterations (converged: {converged})",
            m.cells()
        );
        map = Some(m);
    }
    let Some(map) = map else {
        return Err(RegistrationError::Numerical("no NDT stage ran".into()));
    };
    // Step 3: covariance from the Hessian at the optimum (docs/algorithm.md, "Baselines").
    ndt_result(&map, source, &p, config, converged, iterations)
}

/// The transform of the target for stage `stage` (cell size `cell`, m); coarse stages blurred.
fn stage_map(target: &PointSet2, config: &NdtConfig, stage: usize, cell: f64) -> NdtMap {
    let blur = if stage + 1 < config.cell_sizes.len() {
        (config.coarse_sigma_ratio * cell).powi(2)
    } else {
        0.0
    };
    NdtMap::new(
        &target.points,
        cell,
        config.min_points_per_cell,
        config.min_eigenvalue_ratio,
        blur,
    )
}

/// The accepted step `s` is below the convergence tolerances.
fn small_step(s: &Vec3, config: &NdtConfig) -> bool {
    s.xy().norm() < config.translation_tolerance && s.z.abs() < config.rotation_tolerance
}

/// Newton's method over one stage's map from `p` (updated in place), counting into `iterations`;
/// returns whether it converged within the iteration limit.
fn newton_stage(
    m: &NdtMap,
    source: &PointSet2,
    p: &mut Vec3,
    config: &NdtConfig,
    iterations: &mut usize,
) -> Result<bool, RegistrationError> {
    let need = config.min_points_in_cells;
    for _ in 0..config.max_iterations {
        *iterations += 1;
        let obj = m.objective(&source.points, p);
        if obj.points_in_cells < need {
            return Err(RegistrationError::TooFewInliers {
                have: obj.points_in_cells,
                need,
            });
        }
        let step = newton_step(&obj, config, m.cell_size())?;
        match line_search(m, source, p, &obj, &step, config) {
            Some(s) => {
                *p += s;
                p.z = dc_loc_core::math::wrap_angle(p.z);
                if small_step(&s, config) {
                    return Ok(true);
                }
            }
            // No descent even at the tolerance scale: a (local) minimum.
            None => return Ok(true),
        }
    }
    Ok(false)
}

/// The Newton step of `obj` on its Hessian made positive definite, clipped to the trust region
/// (`max_step_cells` cells of `cell` m, `max_step_rotation`).
fn newton_step(
    obj: &NdtObjective,
    config: &NdtConfig,
    cell: f64,
) -> Result<Vec3, RegistrationError> {
    let h = make_positive_definite(&obj.hessian);
    let Some(step) = h.cholesky().map(|ch| -ch.solve(&obj.gradient)) else {
        return Err(RegistrationError::Numerical(
            "NDT Hessian could not be made positive definite".into(),
        ));
    };
    if !step.iter().all(|v| v.is_finite()) {
        return Err(RegistrationError::Numerical(
            "NDT Newton step is not finite".into(),
        ));
    }
    let max_t = config.max_step_cells * cell;
    let shrink = (max_t / step.xy().norm())
        .min(config.max_step_rotation / step.z.abs())
        .min(1.0);
    Ok(step * shrink)
}

/// Backtracking (Armijo) line search along `step` from `p`: the first halving of the step that
/// decreases `f` enough, or `None` once the step is below the tolerances. Halving 60 times takes any
/// finite step below the tolerances: the search ends.
fn line_search(
    m: &NdtMap,
    source: &PointSet2,
    p: &Vec3,
    obj: &NdtObjective,
    step: &Vec3,
    config: &NdtConfig,
) -> Option<Vec3> {
    let slope = obj.gradient.dot(step);
    let mut alpha = 1.0;
    for _ in 0..60 {
        let trial = p + step * alpha;
        if m.value(&source.points, &pose(&trial)) <= obj.value + 1e-4 * alpha * slope {
            return Some(step * alpha);
        }
        if small_step(&(step * alpha), config) {
            return None;
        }
        alpha *= 0.5;
    }
    None
}

/// The registration result at the optimum `p` of the last stage's map, with the covariance of
/// docs/algorithm.md, "Baselines".
fn ndt_result(
    map: &NdtMap,
    source: &PointSet2,
    p: &Vec3,
    config: &NdtConfig,
    converged: bool,
    iterations: usize,
) -> Result<RegistrationResult, RegistrationError> {
    let need = config.min_points_in_cells;
    let obj = map.objective(&source.points, p);
    if obj.points_in_cells < need {
        return Err(RegistrationError::TooFewInliers {
            have: obj.points_in_cells,
            need,
        });
    }
    // The full Hessian can be indefinite where the minimum sits on a cell border (a kink of the
    // piecewise-smooth score); its Gauss-Newton part is the positive semi-definite fallback.
    let h_inv = spd_inverse(&obj.hessian)
        .or_else(|| spd_inverse(&obj.gauss_newton))
        .ok_or_else(|| {
            RegistrationError::Numerical(
                "NDT information at the optimum is singular (degenerate geometry)".into(),
            )
        })?;
    let multiplicity = obj.contributions as f64 / obj.points_in_cells as f64;
    let cov_p = h_inv * multiplicity;
    let (s, c) = p.z.sin_cos();
    let g = Mat3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
    let cov_delta = g.transpose() * cov_p * g;
    Ok(RegistrationResult {
        t_target_source: pose(p),
        covariance: covariance_ros_from_se2(&cov_delta),
        converged,
        iterations,
        inliers: obj.inliers,
        candidates: source.len(),
        overlap: obj.inliers as f64 / source.len() as f64,
        cost: obj.value,
        runner_up_overlap: 0.0,
        alternatives: Vec::new(),
        score_share: Mat3::zeros(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regularisation_keeps_line_cells_invertible() {
        // Collinear points: the raw covariance is singular; the floor makes it ratio 0.001.
        let pts: Vec<Vec2> = (0..5).map(|i| Vec2::new(i as f64 * 0.2, 0.0)).collect();
        let c = gaussian(&pts, 0.001, 0.0).unwrap();
        let cov = c.inv_cov.try_inverse().unwrap();
        let eig = cov.symmetric_eigenvalues();
        approx::assert_relative_eq!(eig.min() / eig.max(), 0.001, max_relative = 1e-9);
        assert!(gaussian(&[Vec2::new(1.0, 1.0); 4], 0.001, 0.0).is_none());
    }

    #[test]
    fn grids_are_shifted_by_half_a_cell() {
        // One cluster of points near (1.1, 1.1) with cell 2 m: grid 0 cell (0,0), grid 3 cell (0,0) whose
        // span is [1, 3): both hold it; at (0.9, 0.9) grid 3 puts it in cell (-1, -1).
        let pts: Vec<Vec2> = [(1.05, 1.1), (1.15, 1.05), (1.1, 1.2)]
            .iter()
            .map(|&(x, y)| Vec2::new(x, y))
            .collect();
        let m = NdtMap::new(&pts, 2.0, 3, 0.001, 0.0);
        assert_eq!(m.cells(), 4);
        assert!(m.grids[3].contains_key(&(0, 0)));
        assert_eq!(key(&Vec2::new(0.9, 0.9), &m.offsets[3], 2.0), (-1, -1));
    }

    #[test]
    fn config_validation_names_fields() {
        NdtConfig::default().validate().unwrap();
        let c = NdtConfig {
            cell_sizes: vec![],
            ..NdtConfig::default()
        };
        assert_eq!(c.validate().unwrap_err().name, "baselines.ndt.cell_sizes");
        let c = NdtConfig {
            min_eigenvalue_ratio: 0.0,
            ..NdtConfig::default()
        };
        assert_eq!(
            c.validate().unwrap_err().name,
            "baselines.ndt.min_eigenvalue_ratio"
        );
    }
}
