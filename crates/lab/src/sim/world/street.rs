//! Street corridors: the spaces no building may enter.

use dc_loc_core::math::Vec2;

/// A street corridor: no building stands within `half_width` of its centre polyline.
#[derive(Debug, Clone, PartialEq)]
pub struct Street {
    /// Centre polyline, m.
    pub points: Vec<Vec2>,
    /// Building line distance, m.
    pub half_width: f64,
    /// Bounding boxes of consecutive chunks of segments (min, max), for fast rejection.
    chunks: Vec<(usize, usize, Vec2, Vec2)>,
}

impl Street {
    /// The corridor of half-width `half_width` around the polyline `points`.
    pub(super) fn new(points: Vec<Vec2>, half_width: f64) -> Self {
        let mut chunks = Vec::new();
        let n = points.len();
        let mut i = 0;
        while i + 1 < n {
            let j = (i + 32).min(n - 1);
            let mut lo = points[i];
            let mut hi = points[i];
            for p in &points[i..=j] {
                lo = lo.inf(p);
                hi = hi.sup(p);
            }
            chunks.push((i, j, lo, hi));
            i = j;
        }
        Street {
            points,
            half_width,
            chunks,
        }
    }

    /// Whether `p` lies strictly inside the corridor (by more than `margin`), m.
    pub fn contains(&self, p: Vec2, margin: f64) -> bool {
        let w = self.half_width - margin;
        if w <= 0.0 {
            return false;
        }
        for &(i, j, lo, hi) in &self.chunks {
            if p.x < lo.x - w || p.y < lo.y - w || p.x > hi.x + w || p.y > hi.y + w {
                continue;
            }
            for k in i..j {
                if point_segment_distance(p, self.points[k], self.points[k + 1]) < w {
                    return true;
                }
            }
        }
        false
    }
}

/// Distance from `p` to the segment `a b`, m.
pub fn point_segment_distance(p: Vec2, a: Vec2, b: Vec2) -> f64 {
    let e = b - a;
    let l2 = e.norm_squared();
    let t = if l2 > 0.0 {
        ((p - a).dot(&e) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + e * t - p).norm()
}
