//! What the keyframe map keeps of a keyframe ([`KeyframeRecord`]): planar pose, path length, the
//! compensated submap as quantised planar points with 2x2 covariances, and its place descriptor.

use crate::math::{Iso2, Mat2, Stamp, Vec2};
use crate::place::{PlaceConfig, PlaceDescriptor};
use crate::registration::PointSet2;
use crate::submap::Submap;
use serde::{Deserialize, Serialize};

/// Stored point resolution, m (points are kept as `i16` multiples of it: +-327 m).
pub const POINT_QUANTUM: f64 = 0.01;
/// Smallest stored standard deviation, m (covariance axes are kept as 8-bit log2 codes from here).
const SIGMA_MIN: f64 = 0.001;
/// Codes per octave of a stored standard deviation (16: 4.4% steps, up to 62 m).
const SIGMA_STEPS_PER_OCTAVE: f64 = 16.0;

/// A point as stored (1 cm steps); `None` beyond +-327 m or when not finite.
pub fn quantise_point(p: Vec2) -> Option<[i16; 2]> {
    let q = |v: f64| {
        let k = (v / POINT_QUANTUM).round();
        (k.is_finite() && k.abs() <= f64::from(i16::MAX)).then_some(k as i16)
    };
    Some([q(p.x)?, q(p.y)?])
}

/// The point a stored code stands for.
pub fn dequantise_point(q: [i16; 2]) -> Vec2 {
    Vec2::new(
        f64::from(q[0]) * POINT_QUANTUM,
        f64::from(q[1]) * POINT_QUANTUM,
    )
}

/// A 2x2 covariance as stored: major and minor standard deviations as log2 codes (1 mm .. 62 m, 4.4%
/// steps, to the nearest step; smaller axes are stored as 1 mm) and the major axis
/// angle in steps of pi/256.
pub fn quantise_cov(c: &Mat2) -> [u8; 3] {
    let (a, b, d) = (c[(0, 0)], 0.5 * (c[(0, 1)] + c[(1, 0)]), c[(1, 1)]);
    let mean = 0.5 * (a + d);
    let half_diff = (0.25 * (a - d) * (a - d) + b * b).sqrt();
    let (l1, l2) = (mean + half_diff, (mean - half_diff).max(0.0));
    let theta = if half_diff > 0.0 {
        0.5 * (2.0 * b).atan2(a - d)
    } else {
        0.0
    };
    let code = |var: f64| {
        let sigma = var.max(0.0).sqrt().max(SIGMA_MIN);
        let k = (SIGMA_STEPS_PER_OCTAVE * (sigma / SIGMA_MIN).log2()).round();
        if k.is_finite() {
            k.clamp(0.0, 255.0) as u8
        } else {
            255
        }
    };
    let t = (theta.rem_euclid(std::f64::consts::PI) / (std::f64::consts::PI / 256.0)).round();
    [code(l1), code(l2), (t as u32 % 256) as u8]
}

/// The covariance a stored code stands for.
pub fn dequantise_cov(q: [u8; 3]) -> Mat2 {
    let sigma = |k: u8| SIGMA_MIN * (f64::from(k) / SIGMA_STEPS_PER_OCTAVE).exp2();
    let (s1, s2) = (sigma(q[0]), sigma(q[1]));
    let theta = f64::from(q[2]) * std::f64::consts::PI / 256.0;
    let (sn, cs) = theta.sin_cos();
    let r = Mat2::new(cs, -sn, sn, cs);
    r * Mat2::new(s1 * s1, 0.0, 0.0, s2 * s2) * r.transpose()
}

/// A planar ray's direction in one byte: its angle from x in steps of 2 pi / 256 (1.4 degrees).
pub fn quantise_ray(u: &Vec2) -> u8 {
    let turns = u.y.atan2(u.x) / std::f64::consts::TAU;
    ((turns * 256.0).round() as i64).rem_euclid(256) as u8
}

/// The unit direction a stored ray code stands for.
pub fn dequantise_ray(q: u8) -> Vec2 {
    let (s, c) = (f64::from(q) * std::f64::consts::TAU / 256.0).sin_cos();
    Vec2::new(c, s)
}

/// A keyframe as the database keeps it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KeyframeRecord {
    /// Id (position in the database).
    pub id: u64,
    /// Recording session (0 for the first drive of a map; each start of the node adds one).
    pub session: u32,
    /// Anchor stamp of its submap.
    pub stamp: Stamp,
    /// Odometry pose of the body at `stamp`, planar, in its session's odometry frame.
    pub t_odom_body: Iso2,
    /// Full 3D odometry pose (x, y, z, qx, qy, qz, qw), as published in closures.
    pub odom_pose: [f64; 7],
    /// Odometry path length of its session up to this keyframe, m.
    pub path_distance: f64,
    /// Compensated submap points (body frame at `stamp`), quantised ([`quantise_point`]).
    pub points: Vec<[i16; 2]>,
    /// Their covariances, quantised ([`quantise_cov`]).
    pub covs: Vec<[u8; 3]>,
    /// Per point, the direction of the ray from the radar that saw it ([`quantise_ray`]); empty when
    /// not known (a keyframe of an older map or of another robot).
    pub rays: Vec<u8>,
    /// Place descriptor of the points.
    pub place: PlaceDescriptor,
}

impl KeyframeRecord {
    /// The compact form of a submap: compensated points and covariances, at most `max_points` of them
    /// (an even deterministic subsample when there are more).
    #[allow(clippy::too_many_arguments)]
    pub fn from_submap(
        id: u64,
        session: u32,
        submap: &Submap,
        path_distance: f64,
        max_points: usize,
        place: &PlaceConfig,
    ) -> Self {
        let set = submap.point_set(true);
        let n = set.len();
        let keep: Vec<usize> = if n <= max_points || max_points == 0 {
            (0..n).collect()
        } else {
            (0..max_points).map(|k| k * n / max_points).collect()
        };
        let mut points: Vec<[i16; 2]> = Vec::with_capacity(keep.len());
        let mut covs: Vec<[u8; 3]> = Vec::with_capacity(keep.len());
        let mut rays: Vec<u8> = Vec::with_capacity(keep.len());
        for &i in &keep {
            if let Some(q) = quantise_point(set.points[i]) {
                points.push(q);
                covs.push(quantise_cov(&set.covs[i]));
                if let Some(u) = set.rays.get(i) {
                    rays.push(quantise_ray(u));
                }
            }
        }
        if rays.len() != points.len() {
            rays.clear();
        }
        let planar: Vec<Vec2> = points.iter().map(|&q| dequantise_point(q)).collect();
        let t = submap.t_odom_anchor;
        let q = t.rotation.quaternion();
        KeyframeRecord {
            id,
            session,
            stamp: submap.anchor_stamp,
            t_odom_body: crate::math::iso2_from_iso3(&t),
            odom_pose: [
                t.translation.x,
                t.translation.y,
                t.translation.z,
                q.i,
                q.j,
                q.k,
                q.w,
            ],
            path_distance,
            points,
            covs,
            rays,
            place: PlaceDescriptor::from_points(&planar, place),
        }
    }

    /// The points as registration input.
    pub fn point_set(&self) -> PointSet2 {
        PointSet2 {
            points: self.planar_points(),
            covs: self.covs.iter().map(|&c| dequantise_cov(c)).collect(),
            rays: self.rays.iter().map(|&q| dequantise_ray(q)).collect(),
        }
    }

    /// The points, m (body frame at `stamp`).
    pub fn planar_points(&self) -> Vec<Vec2> {
        self.points.iter().map(|&q| dequantise_point(q)).collect()
    }

    /// The 3D odometry pose.
    pub fn odom_pose_iso3(&self) -> crate::math::Iso3 {
        let [x, y, z, qx, qy, qz, qw] = self.odom_pose;
        crate::math::Iso3::from_parts(
            nalgebra::Translation3::new(x, y, z),
            crate::math::Quat::new_normalize(nalgebra::Quaternion::new(qw, qx, qy, qz)),
        )
    }

    /// Approximate bytes held (for the memory benchmark).
    pub fn heap_bytes(&self) -> usize {
        self.points.capacity() * 4
            + self.covs.capacity() * 3
            + self.rays.capacity()
            + self.place.grid.len()
            + std::mem::size_of::<Self>()
    }
}
