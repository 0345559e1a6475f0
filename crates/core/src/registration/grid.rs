//! A uniform grid over a planar point set for fixed-radius neighbour queries.
//!
//! The dense stage asks, many times per registration, for the nearest target point within a metre or
//! two of a moved source point, and the surface covariances for the few neighbours within two metres
//! of every point. Radar submaps are sparse (hundreds to a few thousand points over a couple of
//! hundred metres), so a grid whose cells are as large as the query radius answers from the 3 x 3
//! cells around the query, with no tree to descend and no result collection to manage: several times
//! fewer instructions than a k-d tree's bounded two-nearest query on such submaps.
//!
//! Entry points: [`PointGrid::new`], [`PointGrid::nearest_two`], [`PointGrid::nearest_k`],
//! [`PointGrid::within`].

use crate::math::Vec2;

/// Most cells of a grid; a larger extent gets larger cells (queries stay exact, only slower).
const MAX_CELLS: usize = 1 << 20;

/// At most `u32::MAX` points (items are `u32`). Points bucketed by cell (compressed rows: the points of cell `c` are
/// `order[start[c]..start[c + 1]]`).
#[derive(Debug, Clone)]
pub struct PointGrid {
    origin: Vec2,
    cell: f64,
    width: usize,
    height: usize,
    start: Vec<u32>,
    /// Point indices, cell by cell.
    order: Vec<u32>,
    /// The points in that order (x, y), so that a cell's points are contiguous in memory.
    coords: Vec<[f64; 2]>,
}

impl PointGrid {
    /// The grid of `points` with cells of at least `cell` metres (larger when the points spread over
    /// more than [`MAX_CELLS`] cells). Non-finite points are left out.
    pub fn new(points: &[Vec2], cell: f64) -> Self {
        let finite = |p: &&Vec2| p.x.is_finite() && p.y.is_finite();
        let mut cell = if cell.is_finite() && cell > 0.0 {
            cell
        } else {
            1.0
        };
        let Some((lo, hi)) = finite_bounds(points) else {
            return PointGrid {
                origin: Vec2::zeros(),
                cell,
                width: 0,
                height: 0,
                start: vec![0],
                order: Vec::new(),
                coords: Vec::new(),
            };
        };
        let span = hi - lo;
        while (span.x / cell + 1.0) * (span.y / cell + 1.0) > MAX_CELLS as f64 {
            cell *= 2.0;
        }
        let width = (span.x / cell) as usize + 1;
        let height = (span.y / cell) as usize + 1;
        let index = |p: &Vec2| {
            let c = (p - lo) / cell;
            let (x, y) = (
                (c.x as usize).min(width - 1),
                (c.y as usize).min(height - 1),
            );
            y * width + x
        };
        let mut start = vec![0u32; width * height + 1];
        for p in points.iter().filter(finite) {
            start[index(p) + 1] += 1;
        }
        for c in 0..width * height {
            start[c + 1] += start[c];
        }
        let mut fill = start.clone();
        let n = start[width * height] as usize;
        let mut order = vec![0u32; n];
        let mut coords = vec![[0.0; 2]; n];
        for (i, p) in points.iter().enumerate().filter(|(_, p)| finite(p)) {
            let c = index(p);
            let at = fill[c] as usize;
            fill[c] += 1;
            order[at] = i as u32;
            coords[at] = [p.x, p.y];
        }
        PointGrid {
            origin: lo,
            cell,
            width,
            height,
            start,
            order,
            coords,
        }
    }

    /// Points in the grid.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// True when the grid holds no point.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// The cells within `radius` of `q` as `(x0, x1, y0, y1)`, inclusive, clamped to the grid (the
    /// saturating float-to-int casts map anything left of or below the grid to 0 and beyond it to
    /// the last cell); `None` when there is none or `q` is not finite.
    #[inline]
    fn cell_range(&self, q: &Vec2, radius: f64) -> Option<(usize, usize, usize, usize)> {
        if self.width == 0 || !(q.x.is_finite() && q.y.is_finite()) {
            return None;
        }
        let c = (q - self.origin) / self.cell;
        let r = radius / self.cell;
        let x0 = floor(c.x - r).max(0);
        let y0 = floor(c.y - r).max(0);
        let x1 = floor(c.x + r).min(self.width as i64 - 1);
        let y1 = floor(c.y + r).min(self.height as i64 - 1);
        (x0 <= x1 && y0 <= y1).then_some((x0 as usize, x1 as usize, y0 as usize, y1 as usize))
    }

    /// How many points lie in the cells within `radius` of `q` (the cells [`Self::within`] visits;
    /// a superset of the points within `radius`), from the cell counts alone.
    pub fn count_near(&self, q: &Vec2, radius: f64) -> usize {
        let Some((x0, x1, y0, y1)) = self.cell_range(q, radius) else {
            return 0;
        };
        (y0..=y1)
            .map(|y| {
                let row = y * self.width;
                (self.start[row + x1 + 1] - self.start[row + x0]) as usize
            })
            .sum()
    }

    /// Calls `f(index, squared distance)` for every point whose cell lies within `radius` of `q`
    /// (a superset of the points within `radius`).
    #[inline]
    fn visit(&self, q: &Vec2, radius: f64, mut f: impl FnMut(u32, f64, f64, f64)) {
        let Some((x0, x1, y0, y1)) = self.cell_range(q, radius) else {
            return;
        };
        for y in y0..=y1 {
            let row = y * self.width;
            let (a, b) = (
                self.start[row + x0] as usize,
                self.start[row + x1 + 1] as usize,
            );
            for k in a..b {
                let p = self.coords[k];
                let (dx, dy) = (p[0] - q.x, p[1] - q.y);
                f(self.order[k], dx * dx + dy * dy, dx, dy);
            }
        }
    }

    /// Calls `f(index, squared distance, offset)` for every point within `radius` of `q` (the offset
    /// is the point minus `q`), in no particular order.
    #[inline]
    pub fn within(&self, q: &Vec2, radius: f64, mut f: impl FnMut(u32, f64, Vec2)) {
        let r2 = radius * radius;
        self.visit(q, radius, |i, d, dx, dy| {
            if d <= r2 {
                f(i, d, Vec2::new(dx, dy))
            }
        });
    }

    /// The nearest point within `radius` of `q` (index, squared distance) and the squared distance
    /// of the second nearest, capped at `radius^2`; `None` when no point lies within `radius`.
    pub fn nearest_two(&self, q: &Vec2, radius: f64) -> Option<(u32, f64, f64)> {
        let r2 = radius * radius;
        let (mut best, mut d1, mut d2) = (u32::MAX, r2, r2);
        self.visit(q, radius, |i, d, _, _| {
            if d < d1 {
                d2 = d1;
                d1 = d;
                best = i;
            } else if d < d2 {
                d2 = d;
            }
        });
        (best != u32::MAX).then_some((best, d1, d2))
    }

    /// [`Self::nearest_two`], or when no point lies within `radius`, a lower bound on the squared
    /// distance from `q` to every point of the grid (0 when `q` is not finite): the nearest of the
    /// points in the cells visited and the edges of those cells, beyond which the others lie.
    pub fn nearest_two_or_bound(&self, q: &Vec2, radius: f64) -> Result<(u32, f64, f64), f64> {
        let r2 = radius * radius;
        let Some(range) = self.cell_range(q, radius) else {
            let finite = q.x.is_finite() && q.y.is_finite();
            return Err(if finite { r2 } else { 0.0 });
        };
        let (mut best, mut d1, mut d2, mut beyond) = (u32::MAX, r2, r2, f64::INFINITY);
        self.visit(q, radius, |i, d, _, _| {
            if d < d1 {
                d2 = d1;
                d1 = d;
                best = i;
            } else if d < d2 {
                d2 = d;
            } else {
                beyond = beyond.min(d);
            }
        });
        if best != u32::MAX {
            return Ok((best, d1, d2));
        }
        let edge = self.range_edge(q, range);
        Err(beyond.min(edge * edge))
    }

    /// The distance from `q` to the nearest edge of the cells `(x0, x1, y0, y1)` that has grid
    /// cells beyond it (less [`CELL_MARGIN`]): every point outside those cells lies at least that
    /// far from `q`.
    fn range_edge(&self, q: &Vec2, (x0, x1, y0, y1): (usize, usize, usize, usize)) -> f64 {
        let mut edge = f64::INFINITY;
        let (ox, oy, c) = (self.origin.x, self.origin.y, self.cell);
        if x0 > 0 {
            edge = edge.min(q.x - (ox + x0 as f64 * c));
        }
        if x1 + 1 < self.width {
            edge = edge.min(ox + (x1 + 1) as f64 * c - q.x);
        }
        if y0 > 0 {
            edge = edge.min(q.y - (oy + y0 as f64 * c));
        }
        if y1 + 1 < self.height {
            edge = edge.min(oy + (y1 + 1) as f64 * c - q.y);
        }
        (edge - CELL_MARGIN).max(0.0)
    }

    /// The `k` nearest points within `radius` of `q` (index, squared distance) into `out`, in no
    /// particular order; ties at the `k`-th distance broken by the smaller index. Collecting and
    /// selecting is faster than keeping a sorted list of `k`: dense facades put tens of points within
    /// reach.
    pub fn nearest_k(&self, q: &Vec2, k: usize, radius: f64, out: &mut Vec<(u32, f64)>) {
        out.clear();
        if k == 0 {
            return;
        }
        let r2 = radius * radius;
        self.visit(q, radius, |i, d, _, _| {
            if d <= r2 {
                out.push((i, d));
            }
        });
        if out.len() > k {
            out.select_nth_unstable_by(k - 1, |a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            out.truncate(k);
        }
    }
}

/// The lower and upper corners of the finite points of `points`; `None` when there is none.
pub fn finite_bounds(points: &[Vec2]) -> Option<(Vec2, Vec2)> {
    let (lo, hi) = points
        .iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite())
        .fold(
            (Vec2::repeat(f64::INFINITY), Vec2::repeat(f64::NEG_INFINITY)),
            |(lo, hi), p| (lo.inf(p), hi.sup(p)),
        );
    (lo.x <= hi.x && lo.y <= hi.y).then_some((lo, hi))
}

/// Margin on a distance to a cell's edge, m: a point's cell index comes from rounded arithmetic,
/// so a point may lie this much outside its cell (far more than the rounding of coordinates of a
/// few kilometres).
const CELL_MARGIN: f64 = 1e-6;

/// `v.floor()` as an integer, inline: without SSE4.1 the float `floor` is a library call, and the
/// grid takes four per query. Saturates for values beyond `i64`.
#[inline(always)]
fn floor(v: f64) -> i64 {
    let t = v as i64;
    if (t as f64) > v { t - 1 } else { t }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    fn brute(points: &[Vec2], q: &Vec2) -> Vec<(u32, f64)> {
        let mut all: Vec<(u32, f64)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (i as u32, (p - q).norm_squared()))
            .collect();
        all.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        all
    }

    /// Both queries agree with brute force on random clustered points, for radii below, at and
    /// above the cell size.
    #[test]
    fn queries_match_brute_force() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let mut points: Vec<Vec2> = (0..600)
            .map(|_| Vec2::new(rng.random_range(-80.0..80.0), rng.random_range(-50.0..50.0)))
            .collect();
        // A dense facade and duplicates.
        points.extend((0..200).map(|i| Vec2::new(i as f64 * 0.05, 3.0)));
        points.push(points[10]);
        let grid = PointGrid::new(&points, 1.5);
        assert_eq!(grid.len(), points.len());
        let mut out = Vec::new();
        for _ in 0..500 {
            let q = Vec2::new(rng.random_range(-90.0..90.0), rng.random_range(-60.0..60.0));
            let all = brute(&points, &q);
            for radius in [0.7, 1.5, 4.0] {
                let r2 = radius * radius;
                let within: Vec<&(u32, f64)> = all.iter().filter(|e| e.1 <= r2).collect();
                match grid.nearest_two(&q, radius) {
                    None => assert!(within.first().is_none_or(|e| e.1 >= r2)),
                    Some((i, d1, d2)) => {
                        assert_eq!(d1, within[0].1);
                        assert_eq!((points[i as usize] - q).norm_squared(), d1);
                        let second = within.get(1).map_or(r2, |e| e.1.min(r2));
                        assert_eq!(d2, second);
                    }
                }
                // With nothing within reach, the bound lies between the reach and the nearest.
                match grid.nearest_two_or_bound(&q, radius) {
                    Ok(n) => assert_eq!(Some(n), grid.nearest_two(&q, radius)),
                    Err(bound) => {
                        assert_eq!(grid.nearest_two(&q, radius), None);
                        assert!(bound >= (radius - 1e-6) * (radius - 1e-6), "{bound}");
                        assert!(bound <= all[0].1, "{bound} > {}", all[0].1);
                    }
                }
                let mut all_within = Vec::new();
                grid.within(&q, radius, |i, d, o| {
                    assert!((o - (points[i as usize] - q)).norm() < 1e-9);
                    all_within.push((i, d))
                });
                all_within.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
                let want_all: Vec<(u32, f64)> = within.iter().map(|e| **e).collect();
                assert_eq!(all_within, want_all);
                grid.nearest_k(&q, 8, radius, &mut out);
                let mut got: Vec<f64> = out.iter().map(|e| e.1).collect();
                got.sort_by(f64::total_cmp);
                let want: Vec<f64> = within.iter().take(8).map(|e| e.1).collect();
                assert_eq!(got, want);
                // The cell count: every point within the radius, none beyond the cells' square
                // (the radius plus one cell on each side).
                let count = grid.count_near(&q, radius);
                let square = radius + grid.cell;
                let in_square = points
                    .iter()
                    .filter(|p| (p.x - q.x).abs() <= square && (p.y - q.y).abs() <= square)
                    .count();
                assert!(count >= within.len(), "{count} < {}", within.len());
                assert!(count <= in_square, "{count} > {in_square}");
            }
        }
    }

    #[test]
    fn floor_matches_the_float_floor() {
        for v in [-2.5, -2.0, -0.1, -0.0, 0.0, 0.3, 1.0, 7.99, 1e12, -1e12] {
            assert_eq!(floor(v), v.floor() as i64, "{v}");
        }
    }

    /// No points, non-finite points and a huge extent neither panic nor lose points.
    #[test]
    fn degenerate_sets() {
        let empty = PointGrid::new(&[], 1.0);
        assert!(empty.is_empty());
        assert!(empty.nearest_two(&Vec2::zeros(), 5.0).is_none());
        let pts = vec![
            Vec2::new(f64::NAN, 0.0),
            Vec2::new(0.0, 0.0),
            Vec2::new(1e7, -1e7),
        ];
        let g = PointGrid::new(&pts, 0.5);
        assert_eq!(g.len(), 2);
        assert_eq!(
            g.nearest_two(&Vec2::new(0.1, 0.0), 1.0).map(|n| n.0),
            Some(1)
        );
        assert_eq!(
            g.nearest_two(&Vec2::new(1e7, -1e7), 1.0).map(|n| n.0),
            Some(2)
        );
        assert!(g.nearest_two(&Vec2::new(f64::NAN, 0.0), 1.0).is_none());
    }
}
