//! Global place descriptors: find revisits whatever the odometry says.
//!
//! A polar occupancy grid of a compensated submap around its anchor (Scan Context, Kim & Kim, IROS 2018,
//! adapted to sparse radar): `rings` rings out to `max_range`, `sectors` sectors; a cell holds how many
//! points fall in it (saturated), normalised per descriptor. Two keys come from it:
//! - the *ring key* (occupancy per ring, rotation invariant), indexed with kiddo for retrieval;
//! - the full grid, compared under every cyclic column shift (= every yaw), which re-ranks the retrieved
//!   candidates and estimates their relative yaw.
//!
//! Entry points: [`PlaceConfig`], [`PlaceDescriptor::from_points`], [`PlaceDescriptor::distance`],
//! [`PlaceIndex`] (insert, query).

use crate::growing_index::GrowingIndex;
use crate::math::Vec2;
use crate::validate::{Range, Validator};
use serde::{Deserialize, Serialize};

/// Ring-key dimension (fixed: kiddo's dimension is a compile-time constant).
pub const RING_KEY_DIM: usize = 12;

/// Settings of the place descriptor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct PlaceConfig {
    /// Outer radius of the grid, m (default 80).
    pub max_range: f64,
    /// Sectors (columns) over 360 degrees (default 60: 6 degrees each).
    pub sectors: usize,
}

impl Default for PlaceConfig {
    fn default() -> Self {
        PlaceConfig {
            max_range: 80.0,
            sectors: 60,
        }
    }
}

impl PlaceConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.range("max_range", self.max_range, Range::above(1.0));
        v.count("sectors", self.sectors, 8, 360);
    }
}

/// A submap's place descriptor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlaceDescriptor {
    /// Points per ring, normalised to unit sum (rotation invariant).
    pub ring_key: [f32; RING_KEY_DIM],
    /// Row-major `RING_KEY_DIM x sectors` grid, values 0..=255 (saturated counts).
    pub grid: Vec<u8>,
    /// Sectors in `grid`.
    pub sectors: u16,
}

impl PlaceDescriptor {
    /// Builds the descriptor of points given in the submap (anchor body) frame.
    pub fn from_points(points: &[Vec2], cfg: &PlaceConfig) -> Self {
        let rings = RING_KEY_DIM;
        let sectors = cfg.sectors;
        let mut counts = vec![0u32; rings * sectors];
        for p in points {
            let r = p.norm();
            if !(r.is_finite() && r < cfg.max_range) {
                continue;
            }
            // Rings of equal area would starve the inner ones of sparse radar points; equal width it is.
            let ring = ((r / cfg.max_range) * rings as f64) as usize;
            let a = p.y.atan2(p.x).rem_euclid(std::f64::consts::TAU);
            let sector = ((a / std::f64::consts::TAU) * sectors as f64) as usize;
            if let Some(c) = counts.get_mut(ring.min(rings - 1) * sectors + sector.min(sectors - 1))
            {
                *c += 1;
            }
        }
        let grid: Vec<u8> = counts.iter().map(|&c| c.min(255) as u8).collect();
        let mut ring_key = [0f32; RING_KEY_DIM];
        for (ring, k) in ring_key.iter_mut().enumerate() {
            // Points per ring: exactly rotation invariant (occupied-cell counts are not: a wall crosses
            // more or fewer sectors as it turns); the normalisation removes the overall density.
            *k = counts[ring * sectors..(ring + 1) * sectors]
                .iter()
                .sum::<u32>() as f32;
        }
        let sum: f32 = ring_key.iter().sum();
        if sum > 0.0 {
            ring_key.iter_mut().for_each(|k| *k /= sum);
        }
        PlaceDescriptor {
            ring_key,
            grid,
            sectors: sectors as u16,
        }
    }

    /// The grid's columns as bitmasks of occupied rings (what [`PlaceDescriptor::distance`]
    /// compares); worth keeping when one descriptor is compared with many.
    pub fn columns(&self) -> Vec<u32> {
        let s = self.sectors as usize;
        (0..s)
            .map(|j| {
                (0..RING_KEY_DIM).fold(0u32, |m, r| {
                    m | (u32::from(self.grid.get(r * s + j).is_some_and(|&v| v > 0)) << r)
                })
            })
            .collect()
    }

    /// Scan-Context distance (0 = identical, 1 = nothing in common) minimised over cyclic sector
    /// shifts, and the yaw of `other` relative to `self` at the best shift (rad): the mean cosine
    /// distance of occupied columns, with occupancy as binary.
    pub fn distance(&self, other: &PlaceDescriptor) -> (f64, f64) {
        if self.sectors == 0 || other.sectors != self.sectors {
            return (1.0, 0.0);
        }
        column_distance(&self.columns(), &other.columns())
    }
}

/// `1 - |x & y| / sqrt(|x| |y|)` for every (|x & y|, |x|, |y|) of two columns' ring counts: the
/// term of one column pair in [`column_distance`], looked up instead of computed 3600 times per
/// comparison.
static COLUMN_TERMS: std::sync::LazyLock<Vec<f64>> = std::sync::LazyLock::new(|| {
    const N: usize = RING_KEY_DIM + 1;
    let mut t = vec![1.0; N * N * N];
    for inter in 0..N {
        for ca in 0..N {
            for cb in 0..N {
                let norm = ((ca as f64) * (cb as f64)).sqrt();
                if norm > 0.0 {
                    t[(inter * N + ca) * N + cb] = 1.0 - inter as f64 / norm;
                }
            }
        }
    }
    t
});

/// [`PlaceDescriptor::distance`] on precomputed [`PlaceDescriptor::columns`] (equal lengths).
pub fn column_distance(a: &[u32], b: &[u32]) -> (f64, f64) {
    const N: usize = RING_KEY_DIM + 1;
    let s = a.len();
    if s == 0 || b.len() != s {
        return (1.0, 0.0);
    }
    let terms = &*COLUMN_TERMS;
    let count = |x: u32| (x.count_ones() as usize).min(RING_KEY_DIM);
    // Each column of `a` with its ring count; `b` twice over, so that a shift needs no modulo.
    let ca: Vec<(u32, usize)> = a.iter().map(|&x| (x, count(x) * N)).collect();
    let bb: Vec<(u32, usize)> = b.iter().chain(b).map(|&y| (y, count(y))).collect();
    let mut best = (f64::INFINITY, 0usize);
    for shift in 0..s {
        let (mut sum, mut n) = (0.0, 0usize);
        for (&(x, xa), &(y, yb)) in ca.iter().zip(&bb[shift..shift + s]) {
            if x == 0 && y == 0 {
                continue;
            }
            let inter = ((x & y).count_ones() as usize).min(RING_KEY_DIM);
            sum += terms[inter * N * N + xa + yb];
            n += 1;
        }
        let d = if n > 0 { sum / n as f64 } else { 1.0 };
        if d < best.0 {
            best = (d, shift);
        }
    }
    let yaw = best.1 as f64 * std::f64::consts::TAU / s as f64;
    (best.0, crate::math::wrap_angle(yaw))
}

/// Ring keys of many keyframes, for retrieval by kiddo.
#[derive(Debug, Default)]
pub struct PlaceIndex {
    keys: GrowingIndex<RING_KEY_DIM>,
    items: Vec<u32>,
}

impl PlaceIndex {
    /// Adds keyframe `item` with its descriptor.
    pub fn insert(&mut self, item: u32, d: &PlaceDescriptor) {
        if self.keys.push(d.ring_key.map(f64::from)).is_some() {
            self.items.push(item);
        }
    }

    /// Number of keyframes indexed.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// The `k` keyframes with the closest ring keys (item, squared distance), nearest first.
    pub fn nearest(&self, d: &PlaceDescriptor, k: usize) -> Vec<(u32, f32)> {
        self.keys
            .nearest(&d.ring_key.map(f64::from), k)
            .into_iter()
            .filter_map(|(i, d2)| Some((*self.items.get(i)?, d2 as f32)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Iso2;

    fn scene(seed: u64) -> Vec<Vec2> {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        // Walls: random segments, sampled every metre or so, like facades in a radar submap.
        let mut pts = Vec::new();
        for _ in 0..12 {
            let a = Vec2::new(rng.random_range(-70.0..70.0), rng.random_range(-70.0..70.0));
            let dir: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let len: f64 = rng.random_range(10.0..40.0);
            let n = len as usize;
            for i in 0..n {
                pts.push(
                    a + Vec2::new(dir.cos(), dir.sin()) * (i as f64 + rng.random_range(0.0..1.0)),
                );
            }
        }
        pts
    }

    #[test]
    fn rotation_invariant_key_and_yaw_estimate() {
        let cfg = PlaceConfig::default();
        let pts = scene(1);
        let yaw = 1.0;
        let t = Iso2::new(Vec2::zeros(), yaw);
        let rotated: Vec<Vec2> = pts
            .iter()
            .map(|p| (t * nalgebra::Point2::from(*p)).coords)
            .collect();
        let a = PlaceDescriptor::from_points(&pts, &cfg);
        let b = PlaceDescriptor::from_points(&rotated, &cfg);
        let key_diff: f32 = a
            .ring_key
            .iter()
            .zip(&b.ring_key)
            .map(|(x, y)| (x - y).abs())
            .sum();
        assert!(key_diff < 1e-6, "ring key changed by {key_diff}");
        let (d, est) = a.distance(&b);
        assert!(d < 0.35, "distance {d}");
        assert!(
            (crate::math::wrap_angle(est - yaw)).abs() < 0.11,
            "yaw {est} vs {yaw}"
        );
        let other = PlaceDescriptor::from_points(&scene(2), &cfg);
        let far = a.distance(&other).0;
        assert!(
            far > d + 0.15,
            "another place must be farther: {far} vs {d}"
        );
    }

    #[test]
    fn index_retrieves_the_same_place_first() {
        let cfg = PlaceConfig::default();
        let mut idx = PlaceIndex::default();
        for s in 0..50u32 {
            idx.insert(
                s,
                &PlaceDescriptor::from_points(&scene(u64::from(s) + 100), &cfg),
            );
        }
        let q = PlaceDescriptor::from_points(&scene(117), &cfg);
        assert_eq!(idx.nearest(&q, 3)[0].0, 17);
        assert_eq!(idx.len(), 50);
    }

    /// The definition of the distance, term by term with the modulo shift: the lookup table and the
    /// doubled columns of [`column_distance`] must give exactly the same value and shift.
    fn column_distance_by_definition(a: &[u32], b: &[u32]) -> (f64, usize) {
        let s = a.len();
        let mut best = (f64::INFINITY, 0usize);
        for shift in 0..s {
            let (mut sum, mut n) = (0.0, 0usize);
            for j in 0..s {
                let (x, y) = (a[j], b[(j + shift) % s]);
                if x == 0 && y == 0 {
                    continue;
                }
                let inter = f64::from((x & y).count_ones());
                let norm = (f64::from(x.count_ones()) * f64::from(y.count_ones())).sqrt();
                sum += if norm > 0.0 { 1.0 - inter / norm } else { 1.0 };
                n += 1;
            }
            let d = if n > 0 { sum / n as f64 } else { 1.0 };
            if d < best.0 {
                best = (d, shift);
            }
        }
        best
    }

    #[test]
    fn column_distance_equals_its_definition() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let mask = (1u32 << RING_KEY_DIM) - 1;
        for trial in 0..200 {
            let s = [8, 60, 61][trial % 3];
            // Sparse columns (many empty ones), as radar submaps give.
            let col = |rng: &mut rand::rngs::StdRng| {
                if rng.random_range(0.0..1.0) < 0.4 {
                    0
                } else {
                    rng.random::<u32>() & rng.random::<u32>() & mask
                }
            };
            let a: Vec<u32> = (0..s).map(|_| col(&mut rng)).collect();
            let b: Vec<u32> = (0..s).map(|_| col(&mut rng)).collect();
            let (d, yaw) = column_distance(&a, &b);
            let (d_ref, shift) = column_distance_by_definition(&a, &b);
            assert_eq!(
                d.to_bits(),
                d_ref.to_bits(),
                "trial {trial}: {d} vs {d_ref}"
            );
            let yaw_ref = crate::math::wrap_angle(shift as f64 * std::f64::consts::TAU / s as f64);
            assert_eq!(yaw.to_bits(), yaw_ref.to_bits(), "trial {trial}");
        }
        assert_eq!(column_distance(&[], &[]), (1.0, 0.0));
        assert_eq!(column_distance(&[1, 2], &[1]), (1.0, 0.0));
    }
}
