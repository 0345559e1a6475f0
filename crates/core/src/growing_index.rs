//! A k-d index that grows one point at a time, by the logarithmic method (Bentley & Saxe 1980): the
//! points are covered by a few of kiddo's immutable trees over consecutive ranges, each at most half the
//! size of the one before, plus a short tail searched linearly. When the tail reaches `TAIL_MAX` points it
//! becomes a tree, and the newest trees are merged (rebuilt as one) while the newer is at least half the
//! older. A point is rebuilt O(log n) times (amortised O(log² n) per insertion), a query visits
//! O(log n) trees and at most `TAIL_MAX` tail points, and no insertion rebuilds more than the trees it
//! merges.
//!
//! Why not kiddo's mutable tree: its `add` refuses a bucket whose points share a coordinate on the split
//! axis (`UnsplittableBucket`), which is exactly what keyframes along an axis-aligned road or identical
//! place ring keys produce; such keyframes were silently left out of the search.
//!
//! Entry point: [`GrowingIndex`].

use kiddo::SquaredEuclidean;

/// Points searched linearly before they are put in a tree.
const TAIL_MAX: usize = 256;

/// One immutable tree over the points `start..start + len`.
struct Level<const K: usize> {
    start: usize,
    len: usize,
    tree: kiddo::ImmutableKdTree<f64, K>,
}

/// Points in `K` dimensions, identified by their insertion index.
pub struct GrowingIndex<const K: usize> {
    points: Vec<[f64; K]>,
    /// Trees over consecutive ranges, oldest (largest) first.
    levels: Vec<Level<K>>,
    /// Points covered by `levels`; the rest is the tail.
    covered: usize,
}

impl<const K: usize> Default for GrowingIndex<K> {
    fn default() -> Self {
        GrowingIndex {
            points: Vec::new(),
            levels: Vec::new(),
            covered: 0,
        }
    }
}

impl<const K: usize> std::fmt::Debug for GrowingIndex<K> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GrowingIndex")
            .field("len", &self.points.len())
            .field(
                "levels",
                &self.levels.iter().map(|l| l.len).collect::<Vec<_>>(),
            )
            .finish()
    }
}

fn dist2<const K: usize>(a: &[f64; K], b: &[f64; K]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

impl<const K: usize> GrowingIndex<K> {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The point with index `i`.
    pub fn get(&self, i: usize) -> Option<&[f64; K]> {
        self.points.get(i)
    }

    /// Adds a point; returns its index, or `None` (nothing added) when a coordinate is not finite.
    pub fn push(&mut self, p: [f64; K]) -> Option<usize> {
        if !p.iter().all(|v| v.is_finite()) {
            return None;
        }
        self.points.push(p);
        if self.points.len() - self.covered >= TAIL_MAX {
            // The tail and the trees it is at least half of become one tree.
            let mut start = self.covered;
            while let Some(last) = self.levels.last() {
                if 2 * (self.points.len() - start) < last.len {
                    break;
                }
                start = last.start;
                self.levels.pop();
            }
            match kiddo::ImmutableKdTree::new_from_slice(&self.points[start..]) {
                Ok(tree) => {
                    self.levels.push(Level {
                        start,
                        len: self.points.len() - start,
                        tree,
                    });
                    self.covered = self.points.len();
                }
                Err(e) => {
                    // The popped trees' points are searched linearly until a rebuild succeeds.
                    self.covered = start;
                    log::warn!("k-d index not rebuilt ({e}); searching its tail linearly");
                }
            }
        }
        Some(self.points.len() - 1)
    }

    /// Calls `visit(index, squared distance)` for every point within `radius` of `centre` (any order).
    pub fn within(&self, centre: &[f64; K], radius: f64, mut visit: impl FnMut(usize, f64)) {
        if radius.is_nan() || radius < 0.0 {
            return;
        }
        let r2 = radius * radius;
        for level in &self.levels {
            level
                .tree
                .query(centre)
                .within::<SquaredEuclidean<f64>>(r2)
                .unsorted()
                .visit(|n| visit(level.start + n.item as usize, n.distance));
        }
        for (i, q) in self.points.iter().enumerate().skip(self.covered) {
            let d2 = dist2(q, centre);
            if d2 <= r2 {
                visit(i, d2);
            }
        }
    }

    /// The `k` nearest points to `centre` as (index, squared distance), nearest first (ties by index).
    pub fn nearest(&self, centre: &[f64; K], k: usize) -> Vec<(usize, f64)> {
        let Some(nz) = std::num::NonZeroUsize::new(k) else {
            return Vec::new();
        };
        let mut out: Vec<(usize, f64)> = Vec::with_capacity(k * (self.levels.len() + 1) + TAIL_MAX);
        for level in &self.levels {
            out.extend(
                level
                    .tree
                    .query(centre)
                    .nearest_n::<SquaredEuclidean<f64>>(nz)
                    .execute()
                    .iter()
                    .map(|n| (level.start + n.item as usize, n.distance)),
            );
        }
        out.extend(
            self.points
                .iter()
                .enumerate()
                .skip(self.covered)
                .map(|(i, q)| (i, dist2(q, centre))),
        );
        out.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        out.truncate(k);
        out
    }

    /// Approximate heap bytes held.
    pub fn heap_bytes(&self) -> usize {
        // The points, and each tree's own copy of its range with split values and indices.
        self.points.capacity() * K * 8 + self.covered * (K * 8 + 8 + 8)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng, rngs::StdRng};

    fn brute_within(pts: &[[f64; 2]], c: &[f64; 2], r: f64) -> Vec<usize> {
        (0..pts.len())
            .filter(|&i| dist2(&pts[i], c) <= r * r)
            .collect()
    }

    #[test]
    fn agrees_with_a_linear_scan_on_collinear_duplicate_and_random_points() {
        let mut rng = StdRng::seed_from_u64(7);
        let mut idx = GrowingIndex::<2>::default();
        let mut pts = Vec::new();
        for i in 0..6000 {
            // Runs along x = const (the case kiddo's mutable tree refuses), exact duplicates, and noise.
            let p = match i % 3 {
                0 => [100.0, (i / 3) as f64 * 0.5],
                1 => [5.0, 5.0],
                _ => [
                    rng.random_range(-500.0..500.0),
                    rng.random_range(-500.0..500.0),
                ],
            };
            assert_eq!(idx.push(p), Some(pts.len()));
            pts.push(p);
            if i % 97 == 0 {
                let c = [
                    rng.random_range(-50.0..150.0),
                    rng.random_range(-50.0..500.0),
                ];
                let r = rng.random_range(0.0..60.0);
                let mut got = Vec::new();
                idx.within(&c, r, |j, d2| {
                    assert!((d2 - dist2(&pts[j], &c)).abs() < 1e-9);
                    got.push(j)
                });
                got.sort_unstable();
                assert_eq!(got, brute_within(&pts, &c, r));
                let near = idx.nearest(&c, 5);
                let mut all: Vec<f64> = pts.iter().map(|q| dist2(q, &c)).collect();
                all.sort_by(f64::total_cmp);
                let got_d: Vec<f64> = near.iter().map(|n| n.1).collect();
                assert_eq!(got_d, all[..near.len()].to_vec());
                assert_eq!(near.len(), 5.min(pts.len()));
            }
        }
        assert!(idx.covered > 5700, "trees are built as the index grows");
        assert!(
            idx.levels.len() <= 7,
            "logarithmically many trees: {:?}",
            idx
        );
        for w in idx.levels.windows(2) {
            assert_eq!(w[0].start + w[0].len, w[1].start);
            assert!(w[1].len < w[0].len, "{idx:?}");
        }
        assert_eq!(idx.push([f64::NAN, 0.0]), None);
        assert_eq!(idx.len(), 6000);
    }
}
