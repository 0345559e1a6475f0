//! What a radar that measures elevation adds to a scan: the height of each reflection within its
//! object's vertical extent, the elevation it is seen at, and returns from the road surface. The world
//! is planar; its objects stand on flat ground at z = 0 of the body frame, and occlusion stays planar: a
//! parked car hides the whole facade behind it.

use super::reflections::{Candidate, poisson, swerling};
use super::{NO_OBJECT, RadarMotion};
use crate::sim::radar_config::SimRadarConfig;
use crate::sim::world::TargetKind;
use dc_loc_core::math::Vec2;
use rand::RngExt;
use rand::rngs::StdRng;

/// Lowest and highest point of a kind of object above the ground, m.
fn vertical_extent(kind: TargetKind) -> (f64, f64) {
    match kind {
        TargetKind::Facade | TargetKind::BuildingEdge => (0.0, 8.0),
        TargetKind::Pole => (0.0, 5.0),
        // Trunk and crown.
        TargetKind::Tree => (0.0, 6.0),
        TargetKind::Vegetation => (0.0, 1.5),
        TargetKind::ParkedCar => (0.2, 1.5),
        TargetKind::Vehicle => (0.2, 1.6),
        TargetKind::Pedestrian | TargetKind::Ghost => (0.2, 1.8),
        TargetKind::FalseAlarm | TargetKind::Ground => (0.0, 0.0),
    }
}

/// Where a reflection of `kind` at planar range `r` from the radar is seen: `(slant range,
/// elevation)`, its height drawn uniformly over the object's vertical extent; `None` when the
/// elevation lies outside the field of view.
pub(super) fn place(
    radar: &SimRadarConfig,
    kind: TargetKind,
    r: f64,
    rng: &mut StdRng,
) -> Option<(f64, f64)> {
    let (lo, hi) = vertical_extent(kind);
    let h = if hi > lo {
        rng.random_range(lo..=hi)
    } else {
        lo
    };
    let dz = h - radar.extrinsic[2];
    let e = dz.atan2(r);
    (e.abs() <= radar.elevation_fov).then(|| (r.hypot(dz), e))
}

/// Returns from the road surface: `radar.ground_rate` on average, at planar ranges uniform up to
/// `radar.ground_range` and azimuths uniform over the field of view, static, weak (-15 dBsm mean).
pub(super) fn ground(
    radar: &SimRadarConfig,
    motion: &RadarMotion,
    rng: &mut StdRng,
) -> Vec<Candidate> {
    let half_fov = radar.half_fov();
    let near = radar.min_range.max(1.0);
    if radar.ground_range <= near {
        return Vec::new();
    }
    (0..poisson(rng, radar.ground_rate))
        .map(|_| {
            let r = rng.random_range(near..radar.ground_range);
            let a = motion.heading + rng.random_range(-half_fov..=half_fov);
            Candidate {
                p: motion.position + Vec2::new(a.cos(), a.sin()) * r,
                v: Vec2::zeros(),
                rcs: -15.0 + swerling(rng),
                kind: TargetKind::Ground,
                id: NO_OBJECT,
                surface: NO_OBJECT,
            }
        })
        .collect()
}

/// A false alarm's elevation: uniform over the field of view.
pub(super) fn random_elevation(radar: &SimRadarConfig, rng: &mut StdRng) -> f64 {
    rng.random_range(-radar.elevation_fov..=radar.elevation_fov)
}
