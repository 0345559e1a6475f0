//! Per-point, rotation-invariant neighbourhood descriptors: the Radial Statistics Descriptor (RSD)
//! of Cen & Newman (ICRA 2019) as DC-Loc uses it for association (paper section III-D).
//!
//! Up to `max_keypoints` points of a submap each get a descriptor of their neighbours within
//! `radius` (found in a [`super::grid::PointGrid`]): a soft radial histogram and, optionally, a
//! rotation invariant statistic of their bearings ([`AngularStatistic`]), normalised by the
//! neighbour count ([`Normalisation`]). docs/algorithm.md, "Descriptors", has the construction, the
//! implementations it follows and the defaults.
//!
//! Entry points: [`DescriptorConfig`], [`compute_descriptors`], [`keypoint_indices`],
//! [`subset_indices`], [`Descriptor`], [`DESCRIPTOR_DIM`], [`AngularStatistic`], [`Normalisation`].

use super::grid::PointGrid;
use crate::math::Vec2;
use crate::registration::types::RegistrationError;
use crate::validate::Validator;
use serde::{Deserialize, Serialize};

/// Weight of the angular part relative to the radial part.
pub const ANGULAR_WEIGHT: f64 = 1.0;

/// Length of every descriptor; unused trailing entries are 0. A compile-time constant because the
/// kiddo k-d tree is const-generic over its dimension.
pub const DESCRIPTOR_DIM: usize = 16;

/// One descriptor (f32: half the memory and twice the SIMD width of f64 in the k-d tree).
pub type Descriptor = [f32; DESCRIPTOR_DIM];

/// Rotation-invariant angular part of the descriptor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum AngularStatistic {
    /// Radial histogram only (as the DC-Loc authors' code).
    None,
    /// Magnitude spectrum of the neighbours' bearings, harmonics `1..=angular_bins`.
    Spectrum,
    /// Sector counts, cyclically shifted so that the fullest sector is first.
    Sectors,
}

/// How the counts are normalised.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Normalisation {
    /// Raw (soft) counts.
    None,
    /// Counts divided by the number of neighbours: a distribution, density independent.
    Total,
    /// Square root of the `Total` histogram (Hellinger / "RootSIFT" embedding: Euclidean distance
    /// between descriptors becomes the Hellinger distance between the distributions, which weighs
    /// sparse bins more fairly). Spectrum magnitudes are divided by the count, not rooted.
    Hellinger,
    /// Each part scaled to [0, 1] by its own minimum and maximum (the DC-Loc authors' code).
    MinMax,
}

/// Descriptor settings. Defaults: a 25 m neighbourhood in 10 rings plus the first 6 angular
/// harmonics, Hellinger-normalised, at most 400 keypoints and 1500 support points per submap; the
/// measurements behind them are in docs/algorithm.md, "Descriptors".
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct DescriptorConfig {
    /// Neighbourhood radius, m (default 25).
    pub radius: f64,
    /// Number of equal-width rings over `[0, radius]` (default 10).
    pub radial_bins: usize,
    /// Angular statistic (default `spectrum`).
    pub angular: AngularStatistic,
    /// Harmonics (`spectrum`) or sectors (`sectors`) of the angular part (default 6).
    pub angular_bins: usize,
    /// Normalisation (default `hellinger`).
    pub normalisation: Normalisation,
    /// Most points used as neighbours (the "support"): above it the statistics are taken over a
    /// fixed pseudo-random subset of this size (default 1500). Bounds the cost for dense submaps
    /// and, with the normalisation, makes dense and sparse submaps of a place look alike.
    pub max_support: usize,
    /// Most points that get a descriptor (the "keypoints"): above it a fixed pseudo-random subset
    /// (default 400). A submap stacks several scans, so each reflector appears several times and
    /// a subset still holds most reflectors; this bounds the descriptor cost and the matching
    /// database.
    pub max_keypoints: usize,
}

impl Default for DescriptorConfig {
    fn default() -> Self {
        DescriptorConfig {
            radius: 25.0,
            radial_bins: 10,
            angular: AngularStatistic::Spectrum,
            angular_bins: 6,
            normalisation: Normalisation::Hellinger,
            max_support: 1500,
            max_keypoints: 400,
        }
    }
}

impl DescriptorConfig {
    /// Entries actually used (the rest of [`Descriptor`] is 0).
    pub fn used_dim(&self) -> usize {
        self.radial_bins
            + match self.angular {
                AngularStatistic::None => 0,
                _ => self.angular_bins,
            }
    }

    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.positive("radius", self.radius);
        v.at_least("radial_bins", self.radial_bins, 1);
        if self.angular != AngularStatistic::None {
            let min = if self.angular == AngularStatistic::Sectors {
                2
            } else {
                1
            };
            v.at_least("angular_bins", self.angular_bins, min);
        }
        v.require("radial_bins", self.used_dim() <= DESCRIPTOR_DIM, || {
            format!(
                "radial_bins + angular_bins = {} exceeds the descriptor length {DESCRIPTOR_DIM}",
                self.used_dim()
            )
        });
        v.at_least("max_support", self.max_support, 2);
        v.at_least("max_keypoints", self.max_keypoints, 2);
    }
}

/// A pseudo-random subset of `0..n` of size `max` (all of `0..n` when `n <= max`), ascending.
/// Deterministic: the same `(n, max, seed)` always gives the same subset.
pub fn subset_indices(n: usize, max: usize, seed: u64) -> Vec<u32> {
    let mut idx: Vec<u32> = (0..n as u32).collect();
    if n > max {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        // Partial Fisher-Yates: the first `max` entries become a uniform random subset.
        for i in 0..max {
            let j = rng.random_range(i..n);
            idx.swap(i, j);
        }
        idx.truncate(max);
        idx.sort_unstable();
    }
    idx
}

const SUPPORT_SEED: u64 = 0x5D_5E1E_C701;
const KEYPOINT_SEED: u64 = 0x4B_E7B0_1A72;

/// The keypoints of a submap of `n` points: the points that get a descriptor (all, or a fixed
/// pseudo-random subset of `cfg.max_keypoints`).
pub fn keypoint_indices(n: usize, cfg: &DescriptorConfig) -> Vec<u32> {
    subset_indices(n, cfg.max_keypoints, KEYPOINT_SEED)
}

/// Descriptors of the points `keypoints` (indices into `points`), in that order (see the module
/// doc). Points must be finite; `cfg` must be valid.
///
/// Errors only when the support does not fit the grid's `u32` item index.
pub fn compute_descriptors(
    points: &[Vec2],
    keypoints: &[u32],
    cfg: &DescriptorConfig,
) -> Result<Vec<Descriptor>, RegistrationError> {
    if u32::try_from(points.len()).is_err() {
        return Err(RegistrationError::Numerical(format!(
            "{} points do not fit the neighbour grid's u32 index",
            points.len()
        )));
    }
    let support = subset_indices(points.len(), cfg.max_support, SUPPORT_SEED);
    let coords: Vec<Vec2> = support.iter().map(|&i| points[i as usize]).collect();
    // Cells of a third of the radius: a query visits at most 7 x 7 of them.
    let grid = PointGrid::new(&coords, cfg.radius / 3.0);
    Ok(compute_descriptors_with_grid(points, keypoints, &grid, cfg))
}

/// As [`compute_descriptors`], with a neighbour grid built over the support points (any subset of
/// `points`; the neighbours of a keypoint are the grid's points within `cfg.radius`).
pub fn compute_descriptors_with_grid(
    points: &[Vec2],
    keypoints: &[u32],
    grid: &PointGrid,
    cfg: &DescriptorConfig,
) -> Vec<Descriptor> {
    let nr = cfg.radial_bins.clamp(1, DESCRIPTOR_DIM);
    let na = match cfg.angular {
        AngularStatistic::None => 0,
        _ => cfg.angular_bins.min(DESCRIPTOR_DIM - nr),
    };
    let mut out = Vec::with_capacity(keypoints.len());
    // Scratch reused for every point: no allocation per point once the buffers have grown.
    let mut radial = [0.0f64; DESCRIPTOR_DIM];
    let mut angular = [0.0f64; DESCRIPTOR_DIM];
    let mut n = Neighbours::default();
    for &idx in keypoints {
        let Some(p) = points.get(idx as usize) else {
            out.push([0.0; DESCRIPTOR_DIM]);
            continue;
        };
        radial[..nr].fill(0.0);
        angular[..na].fill(0.0);
        n.gather(grid, p, cfg.radius, na > 0);
        radial_rings(&n.rho, &mut radial[..nr], cfg.radius);
        match cfg.angular {
            AngularStatistic::Spectrum if na > 0 => n.bearing_spectrum(&mut angular[..na]),
            AngularStatistic::Sectors if na > 0 => n.fullest_sector_first(&mut angular[..na]),
            _ => {}
        }
        out.push(finish(
            &radial[..nr],
            &angular[..na],
            n.rho.len() as f64,
            cfg,
        ));
    }
    out
}

/// One keypoint's neighbours within the descriptor radius, as offsets in f32 (the scratch of
/// [`compute_descriptors_with_grid`], reused from keypoint to keypoint).
#[derive(Default)]
struct Neighbours {
    /// Offsets from the keypoint, then unit bearings once gathered with `bearings`.
    dx: Vec<f32>,
    dy: Vec<f32>,
    /// Distances.
    rho: Vec<f32>,
    /// Scratch for the bearing spectrum's powers.
    zr: Vec<f32>,
    zi: Vec<f32>,
}

impl Neighbours {
    /// Gathers the grid's points within `radius` of `p` (the point itself and exact duplicates, at
    /// distance 0, are not neighbours), their distances, and with `bearings` their unit directions
    /// in place of their offsets. Tight loops over the gathered values, which the compiler can
    /// vectorise.
    #[inline]
    fn gather(&mut self, grid: &PointGrid, p: &Vec2, radius: f64, bearings: bool) {
        self.dx.clear();
        self.dy.clear();
        self.rho.clear();
        grid.within(p, radius, |_, squared, offset| {
            if squared > 0.0 {
                self.dx.push(offset.x as f32);
                self.dy.push(offset.y as f32);
                self.rho.push(squared as f32);
            }
        });
        // `rho` holds squared distances until here.
        for r in self.rho.iter_mut() {
            *r = r.sqrt();
        }
        if bearings {
            for ((x, y), r) in self.dx.iter_mut().zip(self.dy.iter_mut()).zip(&self.rho) {
                *x /= r;
                *y /= r;
            }
        }
    }

    /// `|sum_q exp(i k phi_q)|` into `angular[k - 1]`, `k = 1..=angular.len()`, by repeated complex
    /// multiplication of the unit bearings.
    #[inline]
    fn bearing_spectrum(&mut self, angular: &mut [f64]) {
        let na = angular.len();
        self.zr.clear();
        self.zr.extend_from_slice(&self.dx);
        self.zi.clear();
        self.zi.extend_from_slice(&self.dy);
        for (k, a) in angular.iter_mut().enumerate() {
            let (sr, si) = (sum_lanes(&self.zr), sum_lanes(&self.zi));
            *a = (sr * sr + si * si).sqrt();
            if k + 1 < na {
                for ((r, i), (ux, uy)) in self
                    .zr
                    .iter_mut()
                    .zip(self.zi.iter_mut())
                    .zip(self.dx.iter().zip(&self.dy))
                {
                    let nr_ = *r * ux - *i * uy;
                    *i = *r * uy + *i * ux;
                    *r = nr_;
                }
            }
        }
    }

    /// Neighbour counts in `angular.len()` equal sectors of bearing, soft-assigned between the two
    /// nearest sector centres (cyclic), then rotated so that the fullest sector comes first.
    #[inline]
    fn fullest_sector_first(&self, angular: &mut [f64]) {
        let na = angular.len();
        let sector_scale = (na as f64 / std::f64::consts::TAU) as f32;
        for (x, y) in self.dx.iter().zip(&self.dy) {
            let phi = y.atan2(*x).rem_euclid(std::f32::consts::TAU);
            let f = phi * sector_scale - 0.5;
            let f = if f < 0.0 { f + na as f32 } else { f };
            let i0 = (f as usize).min(na - 1);
            let w1 = (f - i0 as f32).clamp(0.0, 1.0) as f64;
            angular[i0] += 1.0 - w1;
            angular[(i0 + 1) % na] += w1;
        }
        let (mut best, mut best_v) = (0usize, f64::NEG_INFINITY);
        for (k, &v) in angular.iter().enumerate() {
            if v > best_v {
                best = k;
                best_v = v;
            }
        }
        angular.rotate_left(best);
    }
}

/// The radial histogram of the distances `rho` into the `radial.len()` equal rings over `[0,
/// radius]`, soft-assigned between the two nearest ring centres: a neighbour adds the hat function
/// `max(0, 1 - |f_q - b|)` to ring `b`, `f_q` its position in ring units (clamped to the first and
/// last ring centres), i.e. `1 - w` to ring `floor(f_q)` and `w` to the next, `w = f_q -
/// floor(f_q)`. One scatter per neighbour (a pass per ring costs the ring count).
#[inline]
fn radial_rings(rho: &[f32], radial: &mut [f64], radius: f64) {
    let nr = radial.len();
    let inv_width = (nr as f64 / radius) as f32;
    let last = (nr - 1) as f32;
    for r in rho {
        let f = (*r * inv_width - 0.5).clamp(0.0, last);
        // f >= 0: truncation is the floor.
        let b0 = (f as usize).min(nr - 1);
        let w = (f - b0 as f32) as f64;
        radial[b0] += 1.0 - w;
        if b0 + 1 < nr {
            radial[b0 + 1] += w;
        }
    }
}

/// Sum in f64 of eight interleaved f32 partial sums (vectorisable, unlike a sequential fold).
fn sum_lanes(v: &[f32]) -> f64 {
    sum_lanes_map(v, |x| x)
}

/// `sum_q g(v_q)` with eight interleaved f32 partial sums.
#[inline(always)]
fn sum_lanes_map(v: &[f32], g: impl Fn(f32) -> f32) -> f64 {
    let mut acc = [0.0f32; 8];
    let mut chunks = v.chunks_exact(8);
    for c in &mut chunks {
        for (a, x) in acc.iter_mut().zip(c) {
            *a += g(*x);
        }
    }
    let tail: f32 = chunks.remainder().iter().map(|x| g(*x)).sum();
    acc.iter().map(|&a| a as f64).sum::<f64>() + tail as f64
}

/// Normalises and packs the two parts into one descriptor.
fn finish(radial: &[f64], angular: &[f64], count: f64, cfg: &DescriptorConfig) -> Descriptor {
    let mut d = [0.0f32; DESCRIPTOR_DIM];
    let nr = radial.len();
    let inv = if count > 0.0 { 1.0 / count } else { 0.0 };
    let w = ANGULAR_WEIGHT;
    let spectrum = cfg.angular == AngularStatistic::Spectrum;
    match cfg.normalisation {
        Normalisation::None => {
            for (k, v) in radial.iter().enumerate() {
                d[k] = *v as f32;
            }
            for (k, v) in angular.iter().enumerate() {
                d[nr + k] = (w * v) as f32;
            }
        }
        Normalisation::Total => {
            for (k, v) in radial.iter().enumerate() {
                d[k] = (v * inv) as f32;
            }
            for (k, v) in angular.iter().enumerate() {
                d[nr + k] = (w * v * inv) as f32;
            }
        }
        Normalisation::Hellinger => {
            for (k, v) in radial.iter().enumerate() {
                d[k] = (v * inv).sqrt() as f32;
            }
            for (k, v) in angular.iter().enumerate() {
                let a = if spectrum { v * inv } else { (v * inv).sqrt() };
                d[nr + k] = (w * a) as f32;
            }
        }
        Normalisation::MinMax => {
            let scale = |part: &[f64]| {
                let lo = part.iter().copied().fold(f64::INFINITY, f64::min);
                let hi = part.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                if hi > lo {
                    (lo, 1.0 / (hi - lo))
                } else {
                    (lo, 0.0)
                }
            };
            let (lo, s) = scale(radial);
            for (k, v) in radial.iter().enumerate() {
                d[k] = ((v - lo) * s) as f32;
            }
            if !angular.is_empty() {
                let (lo, s) = scale(angular);
                for (k, v) in angular.iter().enumerate() {
                    d[nr + k] = (w * (v - lo) * s) as f32;
                }
            }
        }
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Iso2;

    fn all(n: usize) -> Vec<u32> {
        (0..n as u32).collect()
    }

    fn scatter(n: usize, seed: u64) -> Vec<Vec2> {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| Vec2::new(rng.random_range(-40.0..40.0), rng.random_range(-40.0..40.0)))
            .collect()
    }

    /// A rigid motion of the whole set leaves every descriptor unchanged (up to rounding), for
    /// every variant: the invariance the association relies on.
    #[test]
    fn descriptors_are_invariant_to_rigid_motion() {
        let pts = scatter(400, 1);
        for angular in [
            AngularStatistic::None,
            AngularStatistic::Spectrum,
            AngularStatistic::Sectors,
        ] {
            for normalisation in [
                Normalisation::None,
                Normalisation::Total,
                Normalisation::Hellinger,
                Normalisation::MinMax,
            ] {
                let cfg = DescriptorConfig {
                    angular,
                    normalisation,
                    angular_bins: 6,
                    ..DescriptorConfig::default()
                };
                // Sector counts are invariant only to rotations by whole sectors (2 of 6 here).
                let yaw = if angular == AngularStatistic::Sectors {
                    2.0 * std::f64::consts::TAU / 6.0
                } else {
                    2.1
                };
                let t = Iso2::new(Vec2::new(13.0, -7.0), yaw);
                let moved: Vec<Vec2> = pts
                    .iter()
                    .map(|p| (t * nalgebra::Point2::from(*p)).coords)
                    .collect();
                let a = compute_descriptors(&pts, &all(pts.len()), &cfg).unwrap();
                let b = compute_descriptors(&moved, &all(moved.len()), &cfg).unwrap();
                let mut worst = 0.0f32;
                let mut mismatched = 0;
                for (da, db) in a.iter().zip(&b) {
                    let e = da
                        .iter()
                        .zip(db)
                        .map(|(u, v)| (u - v).abs())
                        .fold(0.0, f32::max);
                    worst = worst.max(e);
                    if e > 1e-3 {
                        mismatched += 1;
                    }
                }
                if angular == AngularStatistic::Sectors {
                    // Rounding can flip ties between equally full sectors.
                    assert!(
                        mismatched < a.len() / 50,
                        "{angular:?}/{normalisation:?}: {mismatched}"
                    );
                } else {
                    assert!(worst < 1e-3, "{angular:?}/{normalisation:?}: worst {worst}");
                }
            }
        }
    }

    /// Known geometry: one neighbour at 7.5 m with 10 rings of 2.5 m lands exactly on the centre of
    /// ring 2; with angular spectrum the single bearing has magnitude 1 at every harmonic.
    #[test]
    fn single_neighbour_hand_computed() {
        let cfg = DescriptorConfig {
            normalisation: Normalisation::None,
            ..DescriptorConfig::default()
        };
        let pts = vec![Vec2::new(0.0, 0.0), Vec2::new(0.0, 6.25)];
        let d = compute_descriptors(&pts, &all(pts.len()), &cfg).unwrap();
        // 6.25 m / 2.5 m = 2.5 -> f = 2.0: all weight on ring 2.
        assert!((d[0][2] - 1.0).abs() < 1e-6 && d[0][1].abs() < 1e-6 && d[0][3].abs() < 1e-6);
        for k in 0..6 {
            assert!((d[0][10 + k] - 1.0).abs() < 1e-6);
        }
        // Halfway between ring centres 2 and 3 splits the weight.
        let pts = vec![Vec2::new(0.0, 0.0), Vec2::new(7.5, 0.0)];
        let d = compute_descriptors(&pts, &all(pts.len()), &cfg).unwrap();
        assert!((d[0][2] - 0.5).abs() < 1e-6 && (d[0][3] - 0.5).abs() < 1e-6);
        // Two opposite neighbours: odd harmonics cancel, even ones add.
        let pts = vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(5.0, 0.0),
            Vec2::new(-5.0, 0.0),
        ];
        let d = compute_descriptors(&pts, &all(pts.len()), &cfg).unwrap();
        assert!(d[0][10].abs() < 1e-6 && (d[0][11] - 2.0).abs() < 1e-6);
    }

    #[test]
    fn total_normalisation_is_density_independent() {
        // Duplicating every point doubles all counts (a point's own duplicate, at distance 0, is not
        // a neighbour); every normalised variant stays the same.
        let pts = scatter(300, 2);
        let mut doubled = pts.clone();
        doubled.extend(pts.iter().copied());
        for normalisation in [
            Normalisation::Total,
            Normalisation::Hellinger,
            Normalisation::MinMax,
        ] {
            let cfg = DescriptorConfig {
                normalisation,
                ..DescriptorConfig::default()
            };
            let a = compute_descriptors(&pts, &all(pts.len()), &cfg).unwrap();
            let b = compute_descriptors(&doubled, &all(pts.len()), &cfg).unwrap();
            for (da, db) in a.iter().zip(&b) {
                let e = da
                    .iter()
                    .zip(db)
                    .map(|(u, v)| (u - v).abs())
                    .fold(0.0, f32::max);
                assert!(e < 1e-5, "{normalisation:?}: {e}");
            }
        }
    }
}
