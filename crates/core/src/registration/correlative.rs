//! Correlative search: alignments found by geometry alone, for registrations whose descriptor stage
//! found nothing good.
//!
//! [`candidates`] takes candidate rotations from the circular correlation of the two submaps'
//! histograms of local line directions and, per rotation, candidate translations from the votes of
//! source probes into cells of [`CELL`] metres. The caller refines the best with the dense stage
//! and keeps one only under the conditions docs/algorithm.md, "Correlative search", gives (among
//! them [`MIN_INLIERS`]); that section also says why the search is needed.
//!
//! Entry points: [`CorrelativeConfig`], [`candidates`].

use super::dense::TargetTree;
use super::grid::finite_bounds;
use super::types::PointSet2;
use crate::math::{Iso2, Vec2};
use crate::validate::Validator;
use serde::{Deserialize, Serialize};

/// Plain fit score ([`super::dense::SELECTION_SIGMA`], every point alike) under which a result with
/// fewer than `below_inliers` descriptor inliers is searched beyond: the correlative search after
/// the descriptor stage, and the slides (`slide_shifts`) of the winner. About half of a drive's
/// pairs score below 0.6, so the search runs for about half of them.
pub const BELOW_SCORE: f64 = 0.6;

/// Plain fit score under which a result is searched beyond however many descriptor inliers back it:
/// a street slid tens of metres along itself can gather a hundred descriptor inliers and still fit
/// few of its points.
pub const RICH_BELOW_SCORE: f64 = 0.4;

/// Common view ([`super::common_view`]) under which a result is searched beyond however many
/// descriptor inliers back it: two sides of a street look alike turned by half a turn, and the
/// loop-closure gates would refuse that result for its common view anyway.
pub const BELOW_COMMON_VIEW: f64 = 0.25;

/// Peaks of the direction-histogram correlation tried, each with its half-turn.
pub const ROTATION_PEAKS: usize = 3;

/// Source points that vote.
pub const PROBES: usize = 256;

/// Vote cell, m.
pub const CELL: f64 = 0.5;

/// Rotations tried either side of each histogram peak, [`ROTATION_STEP_DEG`] apart.
pub const ROTATION_STEPS: usize = 1;

/// Spacing of those rotations, degrees.
pub const ROTATION_STEP_DEG: f64 = 1.0;

/// Best translations kept per candidate rotation.
pub const PER_ROTATION: usize = 8;

/// Candidates refined, best scored first.
pub const CANDIDATES: usize = 4;

/// Fewest descriptor candidates that must agree with a refined candidate (within the re-selection
/// gate, one per point, not on a line) for its covariance to come from them as for a RANSAC
/// hypothesis. With fewer, the covariance comes from the dense pairs ([`COVARIANCE_CLUSTER`],
/// [`COVARIANCE_SCALE`]).
pub const MIN_INLIERS: usize = 10;

/// Smallest overlap (as `RegistrationResult::overlap`) of an alignment whose covariance comes from
/// the dense pairs: without the descriptors' agreement the geometry alone must speak clearly.
pub const MIN_OVERLAP: f64 = 0.4;

/// Cluster size of that dense-pair covariance, m: pairs whose source points share a cell of this
/// size count as one piece of evidence ([`super::lm::covariance_clustered`]).
pub const COVARIANCE_CLUSTER: f64 = 5.0;

/// Factor on that dense-pair covariance. Nearest-neighbour pairs of two passes that sampled the
/// surfaces at other places err together beyond what their residuals show.
pub const COVARIANCE_SCALE: f64 = 5.0;

/// Settings of the correlative search.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct CorrelativeConfig {
    /// Run it (default true) when the descriptor stage gives no result or a weak one
    /// ([`BELOW_SCORE`], `below_inliers`); it needs the dense stage (`registration.dense.enabled`).
    pub enabled: bool,
    /// Shifts along the winner's own x axis (the vehicle's heading), m, from which the dense stage
    /// is run again when the winner is weak ([`BELOW_SCORE`], `below_inliers`; default -3, 3, -6,
    /// 6, -12, 12; empty = off); a refined slide that fits better wins. Along a street lined with
    /// parked cars the descriptor stage and the correlative search can both land a slot or two (6
    /// m) along it, and the true alignment is then not among the alignments refined at all.
    pub slide_shifts: Vec<f64>,
    /// Descriptor inliers at and above which a result is not searched beyond, unless its plain
    /// score is below [`RICH_BELOW_SCORE`] or its common view below [`BELOW_COMMON_VIEW`] (default
    /// 100): many descriptor inliers are usually the descriptors' clear answer, and the search
    /// costs ten times a registration.
    pub below_inliers: usize,
}

impl Default for CorrelativeConfig {
    fn default() -> Self {
        CorrelativeConfig {
            enabled: true,
            slide_shifts: vec![-3.0, 3.0, -6.0, 6.0, -12.0, 12.0],
            below_inliers: 100,
        }
    }
}

impl CorrelativeConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.count("below_inliers", self.below_inliers, 0, 1_000_000);
        let shifts_ok = self.slide_shifts.len() <= 32
            && self
                .slide_shifts
                .iter()
                .all(|s| s.is_finite() && s.abs() <= 200.0);
        v.require("slide_shifts", shifts_ok, || {
            "must be at most 32 finite shifts within +-200 m".into()
        });
    }
}

/// Bins of the direction histograms (1 degree each over a half-turn).
const BINS: usize = 180;
/// Neighbours (and their radius, m) whose principal axis is a point's local direction.
const NEIGHBOURS: usize = 24;
const NEIGHBOUR_RADIUS: f64 = 8.0;
/// Largest vote grid (cells); coarser cells beyond it.
const MAX_CELLS: usize = 1 << 20;

/// Histogram of the points' local line directions modulo pi (1-degree bins, linear interpolation
/// between the two nearest, smoothed over 5 bins), each weighted by `(l1 - l2) / (l1 + l2)` of its
/// neighbourhood's scatter (1 on a line, 0 in an isotropic blob).
pub fn direction_histogram(points: &[Vec2], tree: &TargetTree) -> Vec<f64> {
    let mut h = vec![0.0; BINS];
    let mut nn = Vec::with_capacity(4 * NEIGHBOURS);
    let mut near: Vec<Vec2> = Vec::with_capacity(NEIGHBOURS);
    for p in points {
        tree.nearest_k(p, NEIGHBOURS, NEIGHBOUR_RADIUS, &mut nn);
        near.clear();
        near.extend(nn.iter().filter_map(|n| points.get(n.0 as usize).copied()));
        if near.len() < 4 {
            continue;
        }
        let mean = near.iter().fold(Vec2::zeros(), |a, q| a + q) / near.len() as f64;
        let (mut sxx, mut syy, mut sxy) = (0.0f64, 0.0f64, 0.0f64);
        for q in &near {
            let d = q - mean;
            sxx += d.x * d.x;
            syy += d.y * d.y;
            sxy += d.x * d.y;
        }
        let trace = sxx + syy;
        if trace <= 1e-12 {
            continue;
        }
        let linearity = (((sxx - syy).powi(2) + 4.0 * sxy * sxy).sqrt() / trace).powi(3);
        let angle = (0.5 * (2.0 * sxy).atan2(sxx - syy)).rem_euclid(std::f64::consts::PI);
        let f = angle / std::f64::consts::PI * BINS as f64;
        let b = (f.floor() as usize) % BINS;
        let w = f - f.floor();
        h[b] += linearity * (1.0 - w);
        h[(b + 1) % BINS] += linearity * w;
    }
    let kernel = [1.0, 2.0, 3.0, 2.0, 1.0];
    (0..BINS)
        .map(|b| {
            kernel
                .iter()
                .enumerate()
                .map(|(o, w)| w * h[(b + BINS + o - 2) % BINS])
                .sum()
        })
        .collect()
}

/// Candidate rotations source -> target, rad: the `peaks` best local maxima (over +-5 bins) of the
/// circular correlation of the two direction histograms, refined by a parabola through the peak and
/// its neighbours, each with its half-turn (directions modulo pi cannot tell them apart).
pub fn rotation_candidates(source_hist: &[f64], target_hist: &[f64], peaks: usize) -> Vec<f64> {
    if source_hist.len() != BINS || target_hist.len() != BINS {
        return Vec::new();
    }
    let corr: Vec<f64> = (0..BINS)
        .map(|d| {
            (0..BINS)
                .map(|b| source_hist[b] * target_hist[(b + d) % BINS])
                .sum()
        })
        .collect();
    let mut maxima: Vec<usize> = (0..BINS)
        .filter(|&d| {
            corr[d] > 0.0
                && (1..=5).all(|o| {
                    corr[d] >= corr[(d + o) % BINS] && corr[d] >= corr[(d + BINS - o) % BINS]
                })
        })
        .collect();
    maxima.sort_by(|a, b| corr[*b].total_cmp(&corr[*a]).then(a.cmp(b)));
    maxima.dedup_by(|a, b| (*a as i64 - *b as i64).abs() <= 5);
    let mut out = Vec::with_capacity(2 * peaks);
    for &d in maxima.iter().take(peaks) {
        let (l, c, r) = (corr[(d + BINS - 1) % BINS], corr[d], corr[(d + 1) % BINS]);
        let den = l - 2.0 * c + r;
        let off = if den.abs() > 1e-12 {
            (0.5 * (l - r) / den).clamp(-0.5, 0.5)
        } else {
            0.0
        };
        let a = (d as f64 + off) * std::f64::consts::PI / BINS as f64;
        out.push(a);
        out.push(a + std::f64::consts::PI);
    }
    out
}

/// Cells of a target's occupancy for [`vote_translations`]: the cells (of `cell` metres) holding a
/// target point, each widened by one cell, without repeats.
pub struct Occupancy {
    cell: f64,
    /// Lower corner of cell (0, 0), m.
    origin: Vec2,
    /// Occupied cells (column, row), widened by one.
    cells: Vec<(i32, i32)>,
    /// Smallest and largest column and row of `cells`.
    bounds: ((i32, i32), (i32, i32)),
    /// Extent of the points, m.
    lo: Vec2,
    hi: Vec2,
}

impl Occupancy {
    /// The occupancy of `target` (finite points) at `cell` metres.
    pub fn new(target: &[Vec2], cell: f64) -> Option<Self> {
        let (lo, hi) = finite_bounds(target)?;
        let pts: Vec<&Vec2> = target
            .iter()
            .filter(|p| p.iter().all(|v| v.is_finite()))
            .collect();
        let origin = lo - Vec2::repeat(cell);
        let mut cells: Vec<(i32, i32)> = Vec::with_capacity(9 * pts.len());
        for p in pts {
            let c = (p - origin) / cell;
            let (i, j) = (c.x as i32, c.y as i32);
            for dj in -1..=1 {
                for di in -1..=1 {
                    cells.push((i + di, j + dj));
                }
            }
        }
        cells.sort_unstable();
        cells.dedup();
        let bounds = cells.iter().fold(
            ((i32::MAX, i32::MAX), (i32::MIN, i32::MIN)),
            |(lo, hi), &(i, j)| ((lo.0.min(i), lo.1.min(j)), (hi.0.max(i), hi.1.max(j))),
        );
        Some(Occupancy {
            cell,
            origin,
            cells,
            bounds,
            lo,
            hi,
        })
    }
}

/// The best-voted translations for rotation `theta`: up to `top` (votes, motion), most votes first,
/// no two within `separation` cells of each other. Each probe, turned by `theta`, votes once for
/// every translation (in cells of the occupancy) that puts it into an occupied target cell: a
/// cell's votes are the probes landing within about a cell of a target point there (an overlap
/// count over every translation at once, a correlative scan match). A probe counts once per
/// translation however many target points surround it, so dense facades outvote poles less than in
/// a vote per point pair.
pub fn vote_translations(
    probes: &[Vec2],
    occupancy: &Occupancy,
    theta: f64,
    top: usize,
    separation: usize,
) -> Vec<(u32, Iso2)> {
    let rot = nalgebra::UnitComplex::new(theta);
    let turned: Vec<Vec2> = probes
        .iter()
        .map(|x| rot * x)
        .filter(|x| x.iter().all(|v| v.is_finite()))
        .collect();
    let Some((xlo, xhi)) = finite_bounds(&turned) else {
        return Vec::new();
    };
    if top == 0 || occupancy.cells.is_empty() {
        return Vec::new();
    }
    let cell = occupancy.cell;
    // Translation t = (cell centre) - x; its grid index is the target cell's index plus a per-probe
    // offset. Grid (0, 0) at `occupancy.origin - xhi`, one cell of margin each side.
    let t_lo = occupancy.origin - xhi - Vec2::repeat(cell);
    let span = (occupancy.hi - occupancy.lo) + (xhi - xlo) + Vec2::repeat(6.0 * cell);
    let w = (span.x / cell) as usize + 2;
    let h = (span.y / cell) as usize + 2;
    if w.saturating_mul(h) > MAX_CELLS {
        return Vec::new();
    }
    let grid = tally(&turned, occupancy, t_lo, w, h);
    strongest(&grid, w, top, separation)
        .into_iter()
        .map(|(s, i, j)| {
            let t = t_lo + Vec2::new((i as f64 + 0.5) * cell, (j as f64 + 0.5) * cell);
            (s, Iso2::from_parts(t.into(), rot))
        })
        .collect()
}

/// The vote grid (`w` x `h` cells of the occupancy's size, cell (0, 0) the translation `t_lo`):
/// each turned probe adds one to every translation that puts it into an occupied target cell.
fn tally(turned: &[Vec2], occupancy: &Occupancy, t_lo: Vec2, w: usize, h: usize) -> Vec<u16> {
    let cell = occupancy.cell;
    let mut grid = vec![0u16; w * h];
    // The occupied cells as offsets into the vote grid from the corner of their bounding box: a
    // probe whose box lies inside the grid adds its own base to each (no per-cell bounds test).
    let (lo_c, hi_c) = occupancy.bounds;
    let offsets: Vec<usize> = occupancy
        .cells
        .iter()
        .map(|&(ci, cj)| (cj - lo_c.1) as usize * w + (ci - lo_c.0) as usize)
        .collect();
    for x in turned {
        // Index of the translation that puts x at the centre of target cell (0, 0).
        let t0 = (occupancy.origin + Vec2::repeat(0.5 * cell) - x - t_lo) / cell;
        let (oi, oj) = (t0.x.floor() as i64, t0.y.floor() as i64);
        let (i0, j0) = (lo_c.0 as i64 + oi, lo_c.1 as i64 + oj);
        let inside = i0 >= 0
            && j0 >= 0
            && ((hi_c.0 as i64 + oi) as usize) < w
            && ((hi_c.1 as i64 + oj) as usize) < h;
        if inside {
            let votes = &mut grid[j0 as usize * w + i0 as usize..];
            for &k in &offsets {
                votes[k] = votes[k].saturating_add(1);
            }
            continue;
        }
        for &(ci, cj) in &occupancy.cells {
            let (i, j) = (ci as i64 + oi, cj as i64 + oj);
            if i >= 0 && j >= 0 && (i as usize) < w && (j as usize) < h {
                let c = &mut grid[j as usize * w + i as usize];
                *c = c.saturating_add(1);
            }
        }
    }
    grid
}

/// The `top` most-voted cells of a `w`-wide vote grid as (votes, column, row), most votes first, no
/// two within `separation` cells of each other; of equal votes the first in row-major order.
fn strongest(grid: &[u16], w: usize, top: usize, separation: usize) -> Vec<(u32, usize, usize)> {
    let mut best: Vec<(u32, usize, usize)> = Vec::with_capacity(top + 1);
    // The votes a cell must beat: 0 until `top` cells are kept, then the weakest kept's.
    let weakest = |best: &Vec<(u32, usize, usize)>| match best.last() {
        Some(b) if best.len() == top => b.0,
        _ => 0,
    };
    // In runs of cells in memory order; a run whose largest count does not beat it is skipped whole.
    const RUN: usize = 32;
    for (r, run) in grid.chunks(RUN).enumerate() {
        if u32::from(run.iter().copied().max().unwrap_or(0)) <= weakest(&best) {
            continue;
        }
        for (k, &s) in run.iter().enumerate() {
            let s = u32::from(s);
            if s <= weakest(&best) {
                continue;
            }
            let n = r * RUN + k;
            keep(&mut best, (s, n % w, n / w), top, separation);
        }
    }
    best
}

/// Adds cell `c` (votes, column, row) to `best` (most votes first, at most `top`) unless a cell
/// within `separation` has at least its votes; the weaker cells near it leave.
fn keep(
    best: &mut Vec<(u32, usize, usize)>,
    c: (u32, usize, usize),
    top: usize,
    separation: usize,
) {
    let near = |b: &(u32, usize, usize)| {
        b.1.abs_diff(c.1) <= separation && b.2.abs_diff(c.2) <= separation
    };
    if best.iter().any(|b| near(b) && b.0 >= c.0) {
        return;
    }
    best.retain(|b| !near(b));
    let at = best.partition_point(|b| b.0 >= c.0);
    best.insert(at, c);
    best.truncate(top);
}

/// The search's candidate alignments (source -> target) with their votes, most votes first:
/// [`rotation_candidates`] from the two sets' direction histograms (each set with its own tree),
/// then the [`PER_ROTATION`] best translations of each ([`vote_translations`], [`PROBES`] source
/// points, cells of [`CELL`], at least 2 m apart).
pub fn candidates(
    source: &PointSet2,
    source_tree: &TargetTree,
    target: &PointSet2,
    target_tree: &TargetTree,
) -> Vec<(u32, Iso2)> {
    if source.len() < 4 || target.len() < 4 {
        return Vec::new();
    }
    let Some(occupancy) = Occupancy::new(&target.points, CELL) else {
        return Vec::new();
    };
    let hs = direction_histogram(&source.points, source_tree);
    let ht = direction_histogram(&target.points, target_tree);
    let probes: Vec<Vec2> = super::descriptor::subset_indices(source.len(), PROBES, PROBE_SEED)
        .into_iter()
        .filter_map(|i| source.points.get(i as usize).copied())
        .collect();
    let separation = (2.0 / CELL).ceil() as usize;
    let step = ROTATION_STEP_DEG.to_radians();
    let mut all: Vec<(u32, Iso2)> = rotation_candidates(&hs, &ht, ROTATION_PEAKS)
        .into_iter()
        .flat_map(|theta| {
            (-(ROTATION_STEPS as i64)..=ROTATION_STEPS as i64).map(move |k| theta + k as f64 * step)
        })
        .flat_map(|theta| vote_translations(&probes, &occupancy, theta, PER_ROTATION, separation))
        .collect();
    all.sort_by_key(|c| std::cmp::Reverse(c.0));
    all
}

/// Cluster labels of `pairs` (source index, target index) for [`super::lm::covariance_clustered`]:
/// the `cell`-metre grid cell of each pair's source point.
pub fn cluster_labels(source: &PointSet2, pairs: &[(usize, usize)], cell: f64) -> Vec<u64> {
    pairs
        .iter()
        .map(|&(i, _)| {
            let p = source.points.get(i).map_or(Vec2::zeros(), |p| p / cell);
            // Two's-complement cell indices packed into one label.
            (u64::from(p.x.floor() as i32 as u32) << 32) | u64::from(p.y.floor() as i32 as u32)
        })
        .collect()
}

const PROBE_SEED: u64 = 0xC0_22E1_A7E5;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registration::dense::target_tree;

    /// An L-shaped street corner with a few poles, seen from two poses: the search's candidates
    /// include the true motion (within a cell and a degree) although no descriptor is involved.
    #[test]
    fn finds_a_known_motion_by_geometry_alone() {
        let mut pts = Vec::new();
        for i in 0..120 {
            let s = i as f64 * 0.5;
            pts.push(Vec2::new(s - 20.0, 8.0)); // a facade along x
            pts.push(Vec2::new(25.0, s - 30.0)); // a facade along y
        }
        for k in 0..6 {
            pts.push(Vec2::new(-15.0 + 7.0 * k as f64, -4.0));
        }
        let truth = Iso2::new(Vec2::new(3.0, -1.5), 0.4);
        // source = truth^-1 * target points (so truth maps source onto target)
        let source: Vec<Vec2> = pts
            .iter()
            .map(|p| (truth.inverse() * nalgebra::Point2::from(*p)).coords)
            .collect();
        let s = PointSet2::isotropic(source, 0.1);
        let t = PointSet2::isotropic(pts, 0.1);
        let cands = candidates(&s, &target_tree(&s).unwrap(), &t, &target_tree(&t).unwrap());
        // The corner pins the translation: the best-voted candidate is the true motion (within a
        // cell and a rotation step).
        let (_, best) = cands.first().copied().expect("candidates");
        let rel = truth.inverse() * best;
        assert!(
            rel.translation.vector.norm() < 1.0 && rel.rotation.angle().abs() < 0.02,
            "{cands:?}"
        );
        // The half-turn is a candidate rotation too.
        let rots = rotation_candidates(
            &direction_histogram(&s.points, &target_tree(&s).unwrap()),
            &direction_histogram(&t.points, &target_tree(&t).unwrap()),
            1,
        );
        assert_eq!(rots.len(), 2);
        assert!((rots[1] - rots[0] - std::f64::consts::PI).abs() < 1e-12);
    }

    /// A probe counts once per translation however many target points surround it: one probe
    /// against a dense facade of 40 points and a single pole gets at most one vote anywhere, and
    /// the translations that put it on the pole and on the facade get one each.
    #[test]
    fn a_probe_votes_once_per_translation() {
        let mut target: Vec<Vec2> = (0..40).map(|i| Vec2::new(i as f64 * 0.1, 0.0)).collect();
        target.push(Vec2::new(20.0, 10.0));
        let occ = Occupancy::new(&target, 0.5).unwrap();
        let votes = vote_translations(&[Vec2::new(1.0, 1.0)], &occ, 0.0, 64, 0);
        assert!(votes.iter().all(|v| v.0 == 1), "{votes:?}");
        let near = |t: Vec2| {
            votes
                .iter()
                .any(|(_, m)| (m.translation.vector - t).norm() <= 0.75)
        };
        assert!(near(Vec2::new(19.0, 9.0)), "pole");
        assert!(near(Vec2::new(1.0, -1.0)), "facade");
    }

    /// Skipping runs of weak cells keeps the cells that offering every voted cell to [`keep`] keeps
    /// (grids with long empty stretches, ties and clusters).
    #[test]
    fn the_strongest_cells_are_those_every_cell_compared_keeps() {
        use rand::{RngExt, SeedableRng};
        let plain = |grid: &[u16], w: usize, top: usize, sep: usize| {
            let mut best = Vec::new();
            for (n, &s) in grid.iter().enumerate() {
                if s > 0 {
                    keep(&mut best, (u32::from(s), n % w, n / w), top, sep);
                }
            }
            best
        };
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        for case in 0..200 {
            let (w, h) = (rng.random_range(1..90), rng.random_range(1..60));
            let mut grid = vec![0u16; w * h];
            for _ in 0..rng.random_range(0..40) {
                let (i, j) = (rng.random_range(0..w), rng.random_range(0..h));
                let peak = rng.random_range(1..12u16);
                for (dj, di) in [(0, 0), (0, 1), (1, 0)] {
                    if i + di < w && j + dj < h {
                        grid[(j + dj) * w + i + di] = peak - (di + dj) as u16;
                    }
                }
            }
            let (top, sep) = (rng.random_range(1..10), rng.random_range(0..5));
            assert_eq!(
                strongest(&grid, w, top, sep),
                plain(&grid, w, top, sep),
                "case {case}"
            );
        }
    }

    /// Degenerate input gives no candidate instead of a panic.
    #[test]
    fn too_few_points_give_nothing() {
        let s = PointSet2::isotropic(vec![Vec2::zeros(); 3], 0.1);
        let tree = target_tree(&s).unwrap();
        assert!(candidates(&s, &tree, &s, &tree).is_empty());
        let occ = Occupancy::new(&[Vec2::zeros()], 1.0).unwrap();
        assert!(vote_translations(&[], &occ, 0.0, 2, 2).is_empty());
        assert!(Occupancy::new(&[], 1.0).is_none());
        assert!(Occupancy::new(&[Vec2::new(f64::NAN, 0.0)], 1.0).is_none());
        assert!(rotation_candidates(&[0.0; 3], &[0.0; 3], 2).is_empty());
    }

    #[test]
    fn bad_settings_are_named() {
        let validate = |c: &CorrelativeConfig| {
            let mut v = Validator::at("r.c");
            c.check(&mut v);
            v.finish()
        };
        let mut c = CorrelativeConfig::default();
        assert!(validate(&c).is_ok());
        c.slide_shifts = vec![f64::NAN];
        assert!(
            validate(&c)
                .unwrap_err()
                .to_string()
                .contains("r.c.slide_shifts")
        );
    }
}
