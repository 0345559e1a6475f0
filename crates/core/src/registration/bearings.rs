//! Where a submap's points lie as seen from its anchor ([`Bearings`]): the histogram behind
//! [`super::common_view`].

use crate::math::Vec2;

/// Sectors of the common view (30 degrees each).
const VIEW_SECTORS: usize = 12;

/// A point set's bearings from its anchor: the share of its points in each degree (0..360,
/// counterclockwise from x).
#[derive(Debug, Clone)]
pub struct Bearings([f64; 360]);

impl Bearings {
    /// The histogram of `points`.
    pub fn new(points: &[Vec2]) -> Self {
        let mut h = [0.0f64; 360];
        let w = 1.0 / points.len().max(1) as f64;
        for x in points {
            let deg = (x.y as f32).atan2(x.x as f32).to_degrees();
            // rem_euclid can round up to exactly 360.
            let k = (deg.rem_euclid(360.0) as usize).min(359);
            h[k] += w;
        }
        Bearings(h)
    }

    /// The intersection of the two 30-degree histograms, `self`'s turned by `yaw` (rounded to the
    /// degree).
    pub fn common(&self, target: &Bearings, yaw: f64) -> f64 {
        let shift = (yaw.to_degrees().round() as i64).rem_euclid(360) as usize;
        let (mut hs, mut ht) = ([0.0f64; VIEW_SECTORS], [0.0f64; VIEW_SECTORS]);
        let width = 360 / VIEW_SECTORS;
        for k in 0..360 {
            hs[((k + shift) % 360) / width] += self.0[k];
            ht[k / width] += target.0[k];
        }
        hs.iter().zip(&ht).map(|(a, b)| a.min(*b)).sum()
    }
}
