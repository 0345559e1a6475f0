//! Cheap measures of how well two point sets lie on each other, for judging and screening candidate
//! motions: the coverage grid ([`Coverage`]) and its probes, the fit score ([`fit_score`]), the
//! object weights it uses ([`object_weights`]) and its nearest local maximum ([`score_peak`]).

use super::{PointSet2, SUBSET_SEED, TargetTree};
use crate::math::{Iso2, Vec2, Vec3, se2_exp};

/// The grid cells a point set covers, widened by one cell: a cheap overlap for screening many
/// candidate motions before the few best are refined ([`Coverage::count`]).
#[derive(Debug, Clone)]
pub struct Coverage {
    origin: Vec2,
    cell: f64,
    width: usize,
    height: usize,
    bits: Vec<u64>,
}

/// Most cells of a [`Coverage`] grid (the cell grows for larger submaps): 4 M cells, 512 KB.
const COVERAGE_MAX_CELLS: usize = 1 << 22;

impl Coverage {
    /// The cells of `points` (finite) and their eight neighbours, at `cell` metres (or coarser when
    /// the points spread too far for [`COVERAGE_MAX_CELLS`]).
    pub fn new(points: &[Vec2], cell: f64) -> Self {
        let Some((lo, hi)) = crate::registration::grid::finite_bounds(points) else {
            return Coverage {
                origin: Vec2::zeros(),
                cell,
                width: 0,
                height: 0,
                bits: Vec::new(),
            };
        };
        let span = hi - lo;
        let mut cell = cell;
        while ((span.x / cell) as usize + 3) * ((span.y / cell) as usize + 3) > COVERAGE_MAX_CELLS {
            cell *= 2.0;
        }
        let origin = lo - Vec2::repeat(cell);
        let width = (span.x / cell) as usize + 3;
        let height = (span.y / cell) as usize + 3;
        let mut out = Coverage {
            origin,
            cell,
            width,
            height,
            bits: vec![0; (width * height).div_ceil(64)],
        };
        for p in points.iter().filter(|p| p.iter().all(|v| v.is_finite())) {
            let c = (p - origin) / cell;
            let (cx, cy) = (c.x as usize, c.y as usize);
            for y in cy.saturating_sub(1)..=(cy + 1).min(height - 1) {
                for x in cx.saturating_sub(1)..=(cx + 1).min(width - 1) {
                    let k = y * width + x;
                    out.bits[k / 64] |= 1 << (k % 64);
                }
            }
        }
        out
    }

    /// True when `p` lies in a covered cell.
    pub fn covered(&self, p: &Vec2) -> bool {
        let c = (p - self.origin) / self.cell;
        if !(c.x >= 0.0 && c.y >= 0.0) {
            return false;
        }
        let (x, y) = (c.x as usize, c.y as usize);
        if x >= self.width || y >= self.height {
            return false;
        }
        let k = y * self.width + x;
        self.bits[k / 64] & (1 << (k % 64)) != 0
    }

    /// How many of `probes`, moved by `t`, land in covered cells.
    pub fn count(&self, probes: &[Vec2], t: &Iso2) -> usize {
        probes
            .iter()
            .filter(|p| self.covered(&(t * nalgebra::Point2::from(**p)).coords))
            .count()
    }
}

/// At most `n` of `set`'s points, a fixed pseudo-random subset: the probes of [`Coverage::count`].
pub fn probes(set: &PointSet2, n: usize) -> Vec<Vec2> {
    crate::registration::descriptor::subset_indices(set.len(), n, SUBSET_SEED ^ 0x9E37)
        .into_iter()
        .map(|i| set.points[i as usize])
        .collect()
}

/// How well `source` moved by `t` lies on `target`: the mean over the source points of `exp(-d^2 /
/// (2 sigma^2))`, `d` the distance to the nearest target point (0..1), as `(weighted, plain)`:
/// weighted by `weights` (one per source point, [`object_weights`]; `None` or a wrong length weighs
/// all alike) and with every point alike. Unlike the overlap (the share of points with a partner
/// inside the gates) it rewards a close fit more than a loose one, so a street slid along itself,
/// whose facade samples pair within a metre, scores below the true alignment, whose poles and
/// corners fit within decimetres.
pub fn fit_score(
    source: &PointSet2,
    weights: Option<&[f64]>,
    target: &PointSet2,
    tree: &TargetTree,
    t: &Iso2,
    sigma: f64,
) -> (f64, f64) {
    if target.is_empty() {
        return (0.0, 0.0);
    }
    // Beyond 4 sigma a point adds less than exp(-8).
    let reach = 4.0 * sigma;
    score_by(source, weights, t, sigma, |_, q| {
        tree.nearest_two(q, reach).map(|(_, d2, _)| d2)
    })
}

/// [`fit_score`] with `nearest(i, q)`: the squared distance from `q`, where `t` puts source point
/// `i`, to its nearest target point within `4 sigma` (`None` when none is).
fn score_by(
    source: &PointSet2,
    weights: Option<&[f64]>,
    t: &Iso2,
    sigma: f64,
    nearest: impl Fn(usize, &Vec2) -> Option<f64>,
) -> (f64, f64) {
    if source.is_empty() {
        return (0.0, 0.0);
    }
    let k = -0.5 / (sigma * sigma);
    let weights = weights.filter(|w| w.len() == source.len());
    let (mut weighted, mut total, mut plain) = (0.0, 0.0, 0.0);
    for (i, x) in source.points.iter().enumerate() {
        let q = (t * nalgebra::Point2::from(*x)).coords;
        let f = nearest(i, &q).map_or(0.0, |d2| (k * d2).exp());
        let w = weights.map_or(1.0, |w| w[i]);
        plain += f;
        weighted += w * f;
        total += w;
    }
    let plain = plain / source.len() as f64;
    let weighted = if total > 0.0 { weighted / total } else { plain };
    (weighted, plain)
}

/// The translation `(x, y, 0)` (source frame, right perturbation: `t Exp(v)`) from `t` to the
/// nearest local maximum of the weighted [`fit_score`] at `sigma`, within `max_offset` of `t`: a
/// compass search whose step halves from [`PEAK_STEPS`]`.0` to `.1` m each time no neighbour scores
/// higher.
pub fn score_peak(
    source: &PointSet2,
    weights: &[f64],
    target: &PointSet2,
    tree: &TargetTree,
    t: &Iso2,
    sigma: f64,
    max_offset: f64,
) -> Vec3 {
    // A micrometre over the farthest move, for the rounding of the moved points.
    let near = Neighbourhoods::new(source, target, tree, t, 4.0 * sigma + max_offset + 1e-6);
    // The translations scored so far: the search comes back to some (the one it left, and the
    // finer steps' neighbours), and the same translation scores the same.
    let mut scored: Vec<(Vec3, f64)> = Vec::with_capacity(32);
    let mut score = |v: &Vec3| {
        let bits = |a: &Vec3| a.map(f64::to_bits);
        if let Some(&(_, s)) = scored.iter().find(|(u, _)| bits(u) == bits(v)) {
            return s;
        }
        let s = near.fit_score(source, weights, &(t * se2_exp(v)), sigma);
        scored.push((*v, s));
        s
    };
    let (mut at, mut best) = (Vec3::zeros(), score(&Vec3::zeros()));
    let (mut step, finest) = PEAK_STEPS;
    while step >= finest {
        let better = [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)]
            .into_iter()
            .map(|(x, y)| at + Vec3::new(x * step, y * step, 0.0))
            .filter(|v| v.xy().norm() <= max_offset)
            .map(|v| (score(&v), v))
            .find(|(s, _)| *s > best);
        match better {
            Some((s, v)) => (best, at) = (s, v),
            None => step *= 0.5,
        }
    }
    at
}

/// Per source point, the target points within a fixed radius of where `t` puts it: every target
/// point that can be the nearest within [`fit_score`]'s reach at a pose that moves the point by at
/// most the rest of the radius. [`score_peak`] evaluates the score at tens of translations of one
/// pose; scanning these short lists instead of querying the grid each time gives the same scores to
/// the bit (the same squared distances, the same minimum) at a fraction of the cost.
struct Neighbourhoods {
    /// The lists of source point `i`: `coords[start[i]..start[i + 1]]`.
    start: Vec<usize>,
    coords: Vec<[f64; 2]>,
}

impl Neighbourhoods {
    /// The lists of `source` moved by `t`, with the target points of `tree` (built over `target`)
    /// within `radius`.
    fn new(
        source: &PointSet2,
        target: &PointSet2,
        tree: &TargetTree,
        t: &Iso2,
        radius: f64,
    ) -> Self {
        let mut start = Vec::with_capacity(source.len() + 1);
        let mut coords = Vec::new();
        start.push(0);
        for x in &source.points {
            let q = (t * nalgebra::Point2::from(*x)).coords;
            tree.within(&q, radius, |j, _, _| {
                let y = target.points[j as usize];
                coords.push([y.x, y.y]);
            });
            start.push(coords.len());
        }
        Neighbourhoods { start, coords }
    }

    /// The weighted [`fit_score`] of `source` (the set the lists were made for) at `t`, which must
    /// move no point farther from where the lists were made than their radius less `4 sigma`.
    fn fit_score(&self, source: &PointSet2, weights: &[f64], t: &Iso2, sigma: f64) -> f64 {
        let reach = 4.0 * sigma;
        let r2 = reach * reach;
        let nearest = |i: usize, q: &Vec2| {
            let d1 = nearest_in(&self.coords[self.start[i]..self.start[i + 1]], q, r2);
            (d1 < r2).then_some(d1)
        };
        score_by(source, Some(weights), t, sigma, nearest).0
    }
}

/// The smallest squared distance from `q` to `points`, and `cap` when all are farther. Four
/// running minima, merged at the end: the compiler turns them into vector compares (a minimum is
/// exact in any order), where one running minimum waits on the previous compare.
#[inline]
fn nearest_in(points: &[[f64; 2]], q: &Vec2, cap: f64) -> f64 {
    let mut lanes = [cap; 4];
    let mut chunks = points.chunks_exact(4);
    for chunk in &mut chunks {
        for (lane, p) in lanes.iter_mut().zip(chunk) {
            let (dx, dy) = (p[0] - q.x, p[1] - q.y);
            let d = dx * dx + dy * dy;
            *lane = if d < *lane { d } else { *lane };
        }
    }
    for p in chunks.remainder() {
        let (dx, dy) = (p[0] - q.x, p[1] - q.y);
        let d = dx * dx + dy * dy;
        lanes[0] = if d < lanes[0] { d } else { lanes[0] };
    }
    let [a, b, c, d] = lanes;
    let (ab, cd) = (if b < a { b } else { a }, if d < c { d } else { c });
    if cd < ab { cd } else { ab }
}

/// Width of the fit score that picks the winner among a registration's refined hypotheses, m: the
/// mean over the source points of `exp(-d^2 / 2 sigma^2)`, `d` the distance to the nearest target
/// point at the hypothesis ([`fit_score`]).
pub const SELECTION_SIGMA: f64 = 0.35;

/// Radius of the objects the fit score counts once, m: each source point weighs 1 / (the source
/// points near it, itself included), so that a pole or a building corner weighs as much as a parked
/// car or a stretch of facade. Two passes of a street see its facades, poles and corners again but
/// not all its parked cars: counted by points, a street slid by a parking slot or two can fit
/// better than the truth. The weighted score only chooses;
/// [`super::super::correlative::BELOW_SCORE`] compares the plain one.
pub const SELECTION_OBJECT_RADIUS: f64 = 2.5;

/// The first and the finest step of [`score_peak`]'s search, m: the finest is a sixth of
/// [`SELECTION_SIGMA`].
const PEAK_STEPS: (f64, f64) = (0.5, 0.0625);

/// Weights of `points` in [`fit_score`]: 1 / (the points near it, itself included), so that every
/// object of about `radius` weighs about as much in total, however many detections it gave (see
/// [`SELECTION_OBJECT_RADIUS`]); all 1 when `radius` is 0. "Near" is counted from a grid of `radius
/// / 2` cells: the points of the cells within `radius` (a square of 2.5 radii on average;
/// [`crate::registration::grid::PointGrid::count_near`]), which needs no distance per pair. (The
/// dense stage's own 2 m grid, a 6 m square at 2.5 m, put 411 of the demo's 416 pairs inside 2 m
/// against 412, at the same bench time.)
pub fn object_weights(points: &[Vec2], radius: f64) -> Vec<f64> {
    if radius <= 0.0 || points.is_empty() {
        return vec![1.0; points.len()];
    }
    let grid = crate::registration::grid::PointGrid::new(points, 0.5 * radius);
    points
        .iter()
        .map(|p| 1.0 / grid.count_near(p, radius).max(1) as f64)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::target_tree;
    use super::*;

    /// The coverage grid: a point's own cell and its eight neighbours are covered, nothing else;
    /// `count` moves the probes by the motion first; an empty set covers nothing.
    #[test]
    fn coverage_marks_the_cells_around_each_point() {
        let cov = Coverage::new(&[Vec2::new(10.2, -3.7), Vec2::new(30.0, 5.0)], 1.0);
        assert!(cov.covered(&Vec2::new(10.2, -3.7)));
        assert!(cov.covered(&Vec2::new(11.1, -2.8)));
        assert!(cov.covered(&Vec2::new(29.1, 5.9)));
        assert!(!cov.covered(&Vec2::new(12.5, -3.7)));
        assert!(!cov.covered(&Vec2::new(20.0, 0.0)));
        assert!(!cov.covered(&Vec2::new(-100.0, 1e9)));
        assert!(!cov.covered(&Vec2::new(f64::NAN, 0.0)));
        let probes = [Vec2::new(0.2, -0.7), Vec2::new(20.0, 8.0)];
        let t = Iso2::new(Vec2::new(10.0, -3.0), 0.0);
        assert_eq!(cov.count(&probes, &t), 2);
        assert_eq!(cov.count(&probes, &Iso2::identity()), 0);
        // Far-spread points coarsen the cell instead of allocating without bound.
        let wide = Coverage::new(&[Vec2::new(-5e4, -5e4), Vec2::new(5e4, 5e4)], 1.0);
        assert!(wide.bits.len() * 64 <= 2 * COVERAGE_MAX_CELLS);
        assert!(wide.covered(&Vec2::new(5e4, 5e4)));
        assert!(!Coverage::new(&[], 1.0).covered(&Vec2::zeros()));
    }

    /// Object weights: the ten detections of one reflector weigh a tenth each, an isolated one
    /// weighs one, radius 0 weighs all alike; the weighted fit score is the weighted mean of the
    /// points' fits (here the cluster fits and the isolated point does not: weighted 1/2, plain
    /// 10/11), and a wrong number of weights falls back to the plain mean.
    #[test]
    fn object_weights_count_each_object_once_in_the_fit_score() {
        let mut pts: Vec<Vec2> = (0..10)
            .map(|i| Vec2::new(20.0 + 0.05 * i as f64, 5.0))
            .collect();
        pts.push(Vec2::new(-30.0, 0.0));
        let w = object_weights(&pts, 2.5);
        for wi in &w[..10] {
            assert!((wi - 0.1).abs() < 1e-12, "{w:?}");
        }
        assert_eq!(w[10], 1.0);
        assert_eq!(object_weights(&pts, 0.0), vec![1.0; 11]);
        let source = PointSet2::isotropic(pts.clone(), 0.1);
        let target = PointSet2::isotropic(pts[..10].to_vec(), 0.1);
        let tree = target_tree(&target).expect("tree");
        let (weighted, plain) =
            fit_score(&source, Some(&w), &target, &tree, &Iso2::identity(), 0.35);
        assert!((weighted - 0.5).abs() < 1e-12, "{weighted}");
        assert!((plain - 10.0 / 11.0).abs() < 1e-12, "{plain}");
        let (fallback, _) = fit_score(
            &source,
            Some(&w[..3]),
            &target,
            &tree,
            &Iso2::identity(),
            0.35,
        );
        assert_eq!(fallback, plain);
    }

    /// The neighbourhood lists give [`fit_score`]'s weighted score to the bit at every translation
    /// within their reach, however the points fall (points on and off the target, some beyond
    /// reach).
    #[test]
    fn neighbourhood_lists_score_as_the_grid_does() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let mut cloud = |n: usize| -> Vec<Vec2> {
            (0..n)
                .map(|_| Vec2::new(rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0)))
                .collect()
        };
        let target = PointSet2::isotropic(cloud(300), 0.1);
        let mut near: Vec<Vec2> = target.points[..150]
            .iter()
            .map(|p| p + Vec2::new(0.3, -0.2))
            .collect();
        near.extend(cloud(100));
        let source = PointSet2::isotropic(near, 0.1);
        let tree = target_tree(&target).expect("tree");
        let w = object_weights(&source.points, 2.5);
        let (sigma, max_offset) = (0.35, 1.0);
        let t = Iso2::new(Vec2::new(0.1, 0.05), 0.01);
        let lists =
            Neighbourhoods::new(&source, &target, &tree, &t, 4.0 * sigma + max_offset + 1e-6);
        for k in 0..200 {
            let a = k as f64 * 0.7;
            let v = Vec3::new(max_offset * a.cos(), max_offset * a.sin(), 0.0) * (k as f64 / 200.0);
            let at = t * se2_exp(&v);
            let grid = fit_score(&source, Some(&w), &target, &tree, &at, sigma).0;
            assert_eq!(lists.fit_score(&source, &w, &at, sigma), grid, "{v}");
        }
    }

    /// The fit score's peak against a known transform: twelve reflectors moved by 0.7 m along x,
    /// and a facade sampled 400 times along x, which fits at any shift along itself. From the
    /// identity the search finds the reflectors' alignment to the 1/16 m of its finest step; it
    /// stays within `max_offset`; from the peak itself it does not move.
    #[test]
    fn the_score_peak_is_the_alignment_of_the_objects() {
        let reflectors: Vec<Vec2> = (0..12)
            .map(|i| {
                let a = i as f64 * 0.52;
                Vec2::new(25.0 * a.cos(), 18.0 * (1.7 * a).sin())
            })
            .collect();
        let facade: Vec<Vec2> = (0..400)
            .map(|i| Vec2::new(-20.0 + 0.1 * i as f64, 30.0))
            .collect();
        let truth = Iso2::new(Vec2::new(0.7, 0.0), 0.0);
        let source: Vec<Vec2> = reflectors.iter().chain(&facade).copied().collect();
        let target: Vec<Vec2> = reflectors
            .iter()
            .map(|p| (truth * nalgebra::Point2::from(*p)).coords)
            .chain(facade.iter().map(|p| p + Vec2::new(0.9, 0.0)))
            .collect();
        let (source, target) = (
            PointSet2::isotropic(source, 0.1),
            PointSet2::isotropic(target, 0.1),
        );
        let tree = target_tree(&target).expect("tree");
        let w = object_weights(&source.points, 2.5);
        let pulled = Iso2::identity();
        let p = score_peak(&source, &w, &target, &tree, &pulled, 0.35, 1.0);
        assert!((p.x - 0.7).abs() <= 0.0625 && p.y.abs() <= 0.0625, "{p}");
        assert_eq!(p.z, 0.0);
        let near = score_peak(&source, &w, &target, &tree, &pulled, 0.35, 0.3);
        assert!(near.xy().norm() <= 0.3, "{near}");
        let at_peak = score_peak(&source, &w, &target, &tree, &truth, 0.35, 1.0);
        assert!(at_peak.xy().norm() <= 0.0625, "{at_peak}");
    }
}
