//! One radar scan: what an ARS408-like radar reports from the world at one instant.
//!
//! Entry points: [`simulate_scan`], [`occlusion_rays`], [`DetectionTruth`], [`Dropout`], [`RadarMotion`],
//! [`Reflectivity`].
//!
//! Steps, in order:
//! 1. Radar pose and velocity in the map frame: `v_radar = v_body + omega x t_body_radar` (lever arm).
//! 2. Occlusion: a 1D depth buffer over azimuth (0.1 deg bins) of every wall and car box in range; a
//!    reflection is visible when nothing nearer lies on its ray.
//! 3. Candidate reflections, drawn afresh each scan: random points along visible walls (with surface
//!    relief) and car sides, random points in bushes, the near side of poles and trunks, building corners,
//!    pedestrians. Each gets a Swerling-1 RCS (`10 log10(Exp(1))` around its mean) and, on walls, an
//!    incidence loss.
//! 4. Physics (METHOD.md section 1): true range `r`, azimuth `phi`, radial velocity
//!    `v_r = d . (v_target - v_radar)`.
//! 5. Resolution: candidates in one (range, azimuth, Doppler) resolution cell merge into one detection at
//!    their power-weighted mean; the cell is detected with a logistic probability of its SNR margin
//!    `rcs - reference_rcs - 40 log10(r / r_max(phi))`.
//! 6. False alarms (random range, azimuth and Doppler), the cap on detections (strongest kept), dropouts.
//! 7. Measurement: `r_hat = r + beta v_r + n_r`, `phi_hat = phi + n_phi`, `v_hat = v_r + n_v`, `z = 0`.

use crate::math::{Vec2, Vec3};
use crate::radar::Detection;
use crate::sim::noise::NoiseSampler;
use crate::sim::radar_config::SimRadarConfig;
use crate::sim::world::{CarBox, MoverState, TargetKind, World};
use crate::sim::world_config::WorldConfig;
use rand::RngExt;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Exp1, Poisson};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// Azimuth bin of the occlusion buffer, rad.
const OCCLUSION_BIN: f64 = 0.1 * std::f64::consts::PI / 180.0;
/// A reflection this much behind the nearest occluder on its ray still counts as visible, m.
const OCCLUSION_TOLERANCE: f64 = 0.3;
/// Object id of false alarms.
pub const NO_OBJECT: u32 = u32::MAX;

/// The noise-free truth behind one detection.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DetectionTruth {
    /// True (undistorted, noise-free) position in the radar frame, m; z = 0.
    pub p_radar: Vec3,
    /// True radial velocity, m/s (positive away from the radar).
    pub v_r: f64,
    /// The noise added: range (m), azimuth (rad), radial velocity (m/s).
    pub noise: [f64; 3],
    /// What it comes from (the strongest reflection in its resolution cell).
    pub kind: TargetKind,
    /// Object id in the world ([`NO_OBJECT`] for false alarms).
    pub object: u32,
    /// Number of reflections merged into this detection (0 for false alarms).
    pub members: u32,
}

/// What went wrong with a scan as a whole.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Dropout {
    /// A complete scan.
    None,
    /// The scan came out empty.
    Empty,
    /// The scan lost the tail of its detection list.
    Partial,
}

/// The radar's pose and velocity in the map frame at the scan time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RadarMotion {
    /// Radar position, m.
    pub position: Vec2,
    /// Radar boresight heading, rad.
    pub heading: f64,
    /// Radar velocity, m/s (body velocity plus the yaw-rate lever arm).
    pub velocity: Vec2,
}

impl RadarMotion {
    /// From the body pose (position, heading), forward speed and yaw rate, and the radar extrinsic
    /// `[x, y, z, roll, pitch, yaw]` in the body frame.
    pub fn new(
        body_position: Vec2,
        body_heading: f64,
        speed: f64,
        yaw_rate: f64,
        extrinsic: &[f64; 6],
    ) -> Self {
        let (s, c) = body_heading.sin_cos();
        let lever = Vec2::new(
            c * extrinsic[0] - s * extrinsic[1],
            s * extrinsic[0] + c * extrinsic[1],
        );
        RadarMotion {
            position: body_position + lever,
            heading: body_heading + extrinsic[5],
            velocity: Vec2::new(c, s) * speed + Vec2::new(-lever.y, lever.x) * yaw_rate,
        }
    }
    fn radar_from_map(&self, p: Vec2) -> Vec2 {
        let (s, c) = self.heading.sin_cos();
        let d = p - self.position;
        Vec2::new(c * d.x + s * d.y, -s * d.x + c * d.y)
    }
}

/// Nearest occluder per azimuth bin.
struct DepthBuffer<'a> {
    half_fov: f64,
    /// Unit ray of each bin centre.
    rays: &'a [Vec2],
    depth: Vec<f64>,
    id: Vec<u32>,
}

/// Unit rays of the occlusion bins over `[-half_fov, half_fov]`.
pub fn occlusion_rays(half_fov: f64) -> Vec<Vec2> {
    let n = ((2.0 * half_fov / OCCLUSION_BIN).ceil() as usize).max(1) + 1;
    (0..n)
        .map(|i| {
            let az = -half_fov + i as f64 * OCCLUSION_BIN;
            Vec2::new(az.cos(), az.sin())
        })
        .collect()
}

impl<'a> DepthBuffer<'a> {
    fn new(half_fov: f64, rays: &'a [Vec2]) -> Self {
        let n = rays.len();
        DepthBuffer {
            half_fov,
            rays,
            depth: vec![f64::INFINITY; n],
            id: vec![NO_OBJECT; n],
        }
    }
    fn bin(&self, az: f64) -> Option<usize> {
        let b = ((az + self.half_fov) / OCCLUSION_BIN).round();
        (b >= 0.0 && (b as usize) < self.depth.len()).then_some(b as usize)
    }
    /// Rasterises the segment `a b` (radar frame) into the bins it covers.
    fn add_segment(&mut self, a: Vec2, b: Vec2, id: u32) {
        // Keep the part in front of the radar (x > 0): the field of view is below +-90 deg.
        let eps = 1e-3;
        let (a, b) = match (a.x > eps, b.x > eps) {
            (true, true) => (a, b),
            (false, false) => return,
            (ia, _) => {
                let t = (eps - a.x) / (b.x - a.x);
                let c = a + (b - a) * t;
                if ia { (a, c) } else { (c, b) }
            }
        };
        let (za, zb) = (a.y.atan2(a.x), b.y.atan2(b.x));
        let (lo, hi) = if za <= zb { (za, zb) } else { (zb, za) };
        let lo = lo.max(-self.half_fov);
        let hi = hi.min(self.half_fov);
        if lo > hi + OCCLUSION_BIN {
            return;
        }
        let i0 = ((lo + self.half_fov) / OCCLUSION_BIN).floor().max(0.0) as usize;
        let i1 = (((hi + self.half_fov) / OCCLUSION_BIN).ceil() as usize).min(self.depth.len() - 1);
        let e = b - a;
        for i in i0..=i1 {
            let d = self.rays[i];
            let den = d.perp(&e);
            if den.abs() < 1e-12 {
                continue;
            }
            // Ray r d meets a + t e: r = (a x e) / (d x e), t = (a x d) / (d x e).
            let r = a.perp(&e) / den;
            let t = a.perp(&d) / den;
            if r > 0.0 && (-1e-9..=1.0 + 1e-9).contains(&t) && r < self.depth[i] {
                self.depth[i] = r;
                self.id[i] = id;
            }
        }
    }
    fn add_box(&mut self, motion: &RadarMotion, body: &CarBox) {
        let c = body.corners().map(|p| motion.radar_from_map(p));
        for k in 0..4 {
            self.add_segment(c[k], c[(k + 1) % 4], body.id);
        }
    }
    /// Visible: the nearest occluder on the ray is the object itself, or not nearer than `r`.
    fn visible(&self, az: f64, r: f64, id: u32) -> bool {
        match self.bin(az) {
            Some(i) => self.id[i] == id || r <= self.depth[i] + OCCLUSION_TOLERANCE,
            None => false,
        }
    }
}

/// How densely surfaces are sampled and how strongly they reflect (from `WorldConfig`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reflectivity {
    /// Wall samples per metre per scan.
    pub facade_density: f64,
    /// Wall relief depth, m.
    pub facade_roughness: f64,
    /// Car side samples per metre per scan.
    pub car_density: f64,
    /// Mean RCS of a parked car's strongest corner, dBsm.
    pub car_rcs: f64,
    /// Mean RCS of a vegetation sample, dBsm.
    pub vegetation_rcs: f64,
    /// Vegetation samples per square metre per scan.
    pub vegetation_density: f64,
}

impl From<&WorldConfig> for Reflectivity {
    fn from(w: &WorldConfig) -> Self {
        Reflectivity {
            facade_density: w.facades.density,
            facade_roughness: w.facades.roughness,
            car_density: w.parking.car_density,
            car_rcs: w.parking.car_rcs,
            vegetation_rcs: w.furniture.vegetation_rcs,
            vegetation_density: w.furniture.vegetation_density,
        }
    }
}

/// The parameter interval `[t0, t1]` of the segment `a b` (radar frame) that lies in front of the radar
/// and within the largest coverage range over the segment's azimuths; `None` if none does.
fn segment_view(radar: &SimRadarConfig, a: Vec2, b: Vec2) -> Option<(f64, f64)> {
    let eps = 1e-3;
    let (mut t0, mut t1) = (0.0, 1.0);
    match (a.x > eps, b.x > eps) {
        (false, false) => return None,
        (false, true) => t0 = (eps - a.x) / (b.x - a.x),
        (true, false) => t1 = (eps - a.x) / (b.x - a.x),
        (true, true) => {}
    }
    let e = b - a;
    let (pa, pb) = (a + e * t0, a + e * t1);
    let (za, zb) = (pa.y.atan2(pa.x), pb.y.atan2(pb.x));
    let fov = radar.half_fov();
    let (lo, hi) = (za.min(zb).max(-fov), za.max(zb).min(fov));
    if lo > hi {
        return None;
    }
    // The coverage is piecewise linear in |azimuth|: its maximum lies at an end or a breakpoint.
    let mut r_over = radar.range_at(lo).max(radar.range_at(hi));
    for c in &radar.coverage {
        if (lo..=hi).contains(&c[0]) || (lo..=hi).contains(&-c[0]) {
            r_over = r_over.max(c[1]);
        }
    }
    // Clip to the disc of that radius: |pa + s (pb - pa)| = r_over.
    let d = pb - pa;
    let qa = d.norm_squared();
    if qa <= 0.0 {
        return None;
    }
    let qb = pa.dot(&d);
    let disc = qb * qb - qa * (pa.norm_squared() - r_over * r_over);
    if disc <= 0.0 {
        return None;
    }
    let s0 = ((-qb - disc.sqrt()) / qa).max(0.0);
    let s1 = ((-qb + disc.sqrt()) / qa).min(1.0);
    (s1 > s0).then_some((t0 + s0 * (t1 - t0), t0 + s1 * (t1 - t0)))
}

/// A reflection offered to the radar.
struct Candidate {
    p: Vec2,
    v: Vec2,
    rcs: f64,
    kind: TargetKind,
    id: u32,
    /// Id of the occluder it lies on (itself for walls and cars).
    surface: u32,
}

/// Swerling-1 fluctuation in dB: exponential power around the mean.
fn swerling(rng: &mut StdRng) -> f64 {
    let x: f64 = Exp1.sample(rng);
    10.0 * x.max(1e-12).log10()
}

fn poisson(rng: &mut StdRng, lambda: f64) -> usize {
    if lambda <= 0.0 {
        return 0;
    }
    match Poisson::new(lambda) {
        Ok(p) => {
            let k: f64 = p.sample(rng);
            k as usize
        }
        Err(_) => 0,
    }
}

/// One resolution cell being accumulated.
struct Cell {
    w: f64,
    wr: f64,
    wphi: f64,
    wv: f64,
    rcs_lin: f64,
    best_w: f64,
    kind: TargetKind,
    id: u32,
    members: u32,
}

/// A detection before measurement noise.
struct Clean {
    r: f64,
    phi: f64,
    v_r: f64,
    rcs: f64,
    margin: f64,
    kind: TargetKind,
    id: u32,
    members: u32,
}

/// The world as one radar sees it at one instant: detections in the radar frame, their truth (same order)
/// and the dropout that hit the scan. `lap` selects the parked cars; `movers` are the road users at the
/// scan time; `rays` are the radar's [`occlusion_rays`].
#[allow(clippy::too_many_arguments)]
pub fn simulate_scan(
    world: &World,
    radar: &SimRadarConfig,
    rays: &[Vec2],
    motion: &RadarMotion,
    lap: usize,
    movers: &[MoverState],
    refl: &Reflectivity,
    noise: &NoiseSampler,
    rng: &mut StdRng,
) -> (Vec<Detection>, Vec<DetectionTruth>, Dropout) {
    let r_lim = radar.max_range();
    let pos = motion.position;
    let near = |p: Vec2, extent: f64| (p - pos).norm() <= r_lim + extent;

    // 2. Occlusion buffer, and which walls can be seen at all (in front, in the field of view, in range).
    let mut depth = DepthBuffer::new(radar.half_fov(), rays);
    let mut seen_walls = Vec::new();
    for w in &world.walls {
        let half = 0.5 * (w.b - w.a).norm();
        if !near(0.5 * (w.a + w.b), half) {
            continue;
        }
        let (a, b) = (motion.radar_from_map(w.a), motion.radar_from_map(w.b));
        if let Some((t0, t1)) = segment_view(radar, a, b) {
            depth.add_segment(a, b, w.id);
            seen_walls.push((w, t0, t1));
        }
    }
    let parked: Vec<&CarBox> = world
        .parked_on(lap)
        .filter(|c| near(c.center, 3.0))
        .collect();
    for c in &parked {
        depth.add_box(motion, c);
    }
    let vehicles: Vec<&MoverState> = movers
        .iter()
        .filter(|m| m.mover.kind == TargetKind::Vehicle && near(m.body.center, 3.0))
        .collect();
    for m in &vehicles {
        depth.add_box(motion, &m.body);
    }

    // 3. Candidate reflections.
    let mut cands: Vec<Candidate> = Vec::new();
    for &(w, t0, t1) in &seen_walls {
        let e = w.b - w.a;
        let len = e.norm();
        if w.normal.dot(&(pos - w.a)) <= 0.0 {
            continue;
        }
        for _ in 0..poisson(rng, refl.facade_density * (t1 - t0) * len) {
            let t = rng.random_range(t0..=t1);
            let p = w.a + e * t - w.normal * rng.random_range(0.0..=refl.facade_roughness);
            let ray = (p - pos).normalize();
            let cos_inc = ray.dot(&w.normal).abs();
            cands.push(Candidate {
                p,
                v: Vec2::zeros(),
                rcs: w.rcs + 10.0 * (0.15 + 0.85 * cos_inc).log10() + swerling(rng),
                kind: TargetKind::Facade,
                id: w.id,
                surface: w.id,
            });
        }
    }
    for s in &world.scatterers {
        if !near(s.p, 0.0) {
            continue;
        }
        let d = s.p - pos;
        let p = s.p - d.normalize() * s.radius;
        cands.push(Candidate {
            p,
            v: Vec2::zeros(),
            rcs: s.rcs + swerling(rng),
            kind: s.kind,
            id: s.id,
            surface: s.wall.unwrap_or(s.id),
        });
    }
    for b in &world.bushes {
        if !near(b.center, b.radius) {
            continue;
        }
        let area = std::f64::consts::PI * b.radius * b.radius;
        for _ in 0..poisson(rng, refl.vegetation_density * area) {
            let rr = b.radius * rng.random::<f64>().sqrt();
            let a = rng.random_range(0.0..std::f64::consts::TAU);
            cands.push(Candidate {
                p: b.center + Vec2::new(a.cos(), a.sin()) * rr,
                v: Vec2::zeros(),
                rcs: refl.vegetation_rcs + swerling(rng),
                kind: TargetKind::Vegetation,
                id: b.id,
                surface: b.id,
            });
        }
    }
    let add_box = |cands: &mut Vec<Candidate>,
                   rng: &mut StdRng,
                   body: &CarBox,
                   rcs: f64,
                   kind,
                   m: Option<&MoverState>| {
        let corners = body.corners();
        let vel = |p: Vec2| m.map_or(Vec2::zeros(), |m| m.velocity_at(p));
        // The corner nearest the radar is the strongest reflector (bumper corner, wheel arch).
        let (ci, _) = corners
            .iter()
            .enumerate()
            .map(|(i, c)| (i, (c - pos).norm()))
            .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
        let c = corners[ci];
        cands.push(Candidate {
            p: c,
            v: vel(c),
            rcs: rcs + swerling(rng),
            kind,
            id: body.id,
            surface: body.id,
        });
        for k in 0..4 {
            let (a, b) = (corners[k], corners[(k + 1) % 4]);
            let e = b - a;
            // Outward normal of a counter-clockwise polygon edge.
            let nrm = Vec2::new(e.y, -e.x);
            if nrm.dot(&(pos - a)) <= 0.0 {
                continue;
            }
            for _ in 0..poisson(rng, refl.car_density * e.norm()) {
                let p = a + e * rng.random::<f64>();
                cands.push(Candidate {
                    p,
                    v: vel(p),
                    rcs: rcs - 6.0 + swerling(rng),
                    kind,
                    id: body.id,
                    surface: body.id,
                });
            }
        }
    };
    let car_rcs = refl.car_rcs;
    for c in &parked {
        add_box(&mut cands, rng, c, car_rcs, TargetKind::ParkedCar, None);
    }
    for m in &vehicles {
        add_box(
            &mut cands,
            rng,
            &m.body,
            m.mover.rcs,
            TargetKind::Vehicle,
            Some(m),
        );
    }
    for m in movers
        .iter()
        .filter(|m| m.mover.kind == TargetKind::Pedestrian && near(m.body.center, 0.0))
    {
        cands.push(Candidate {
            p: m.body.center,
            v: m.velocity,
            rcs: m.mover.rcs + swerling(rng),
            kind: TargetKind::Pedestrian,
            id: m.mover.id,
            surface: m.mover.id,
        });
    }

    // 4.-5. Physics, visibility, resolution cells.
    let mut cells: Vec<Cell> = Vec::new();
    let mut cell_at: HashMap<(i64, i64, i64), usize> = HashMap::new();
    for c in &cands {
        let q = motion.radar_from_map(c.p);
        let r = q.norm();
        let phi = q.y.atan2(q.x);
        let r_max = radar.range_at(phi);
        if r < radar.min_range || r > r_max || !depth.visible(phi, r, c.surface) {
            continue;
        }
        let d = (c.p - pos) / r;
        let v_r = d.dot(&(c.v - motion.velocity));
        let margin = c.rcs - radar.reference_rcs - 40.0 * (r / r_max).log10();
        let w = 10f64.powf(margin / 10.0);
        let key = (
            (r / radar.range_resolution).floor() as i64,
            (phi / radar.azimuth_resolution).floor() as i64,
            (v_r / radar.velocity_resolution).floor() as i64,
        );
        let idx = *cell_at.entry(key).or_insert_with(|| {
            cells.push(Cell {
                w: 0.0,
                wr: 0.0,
                wphi: 0.0,
                wv: 0.0,
                rcs_lin: 0.0,
                best_w: 0.0,
                kind: c.kind,
                id: c.id,
                members: 0,
            });
            cells.len() - 1
        });
        let cell = &mut cells[idx];
        cell.w += w;
        cell.wr += w * r;
        cell.wphi += w * phi;
        cell.wv += w * v_r;
        cell.rcs_lin += 10f64.powf(c.rcs / 10.0);
        cell.members += 1;
        if w > cell.best_w {
            cell.best_w = w;
            cell.kind = c.kind;
            cell.id = c.id;
        }
    }
    let mut clean: Vec<Clean> = Vec::new();
    for cell in &cells {
        let margin = 10.0 * cell.w.log10();
        let p_d = 1.0 / (1.0 + (-margin / radar.detection_spread).exp());
        if rng.random::<f64>() < p_d {
            clean.push(Clean {
                r: cell.wr / cell.w,
                phi: cell.wphi / cell.w,
                v_r: cell.wv / cell.w,
                rcs: 10.0 * cell.rcs_lin.log10(),
                margin,
                kind: cell.kind,
                id: cell.id,
                members: cell.members,
            });
        }
    }

    // 6. False alarms, cap, dropouts.
    let half_fov = radar.half_fov();
    for _ in 0..poisson(rng, radar.false_alarm_rate) {
        let phi = rng.random_range(-half_fov..=half_fov);
        let r_max = radar.range_at(phi);
        if r_max <= radar.min_range {
            continue;
        }
        clean.push(Clean {
            r: rng.random_range(radar.min_range..r_max),
            phi,
            v_r: rng.random_range(-25.0..25.0),
            rcs: rng.random_range(-15.0..-5.0),
            margin: 0.0,
            kind: TargetKind::FalseAlarm,
            id: NO_OBJECT,
            members: 0,
        });
    }
    clean.sort_by(|a, b| b.margin.total_cmp(&a.margin));
    clean.truncate(radar.max_detections);
    clean.sort_by(|a, b| a.r.total_cmp(&b.r));
    let u: f64 = rng.random();
    let dropout = if u < radar.empty_scan_probability {
        clean.clear();
        Dropout::Empty
    } else if u < radar.empty_scan_probability + radar.partial_scan_probability {
        let keep = (clean.len() as f64 * rng.random_range(0.2..0.8)).round() as usize;
        clean.truncate(keep);
        Dropout::Partial
    } else {
        Dropout::None
    };

    // 7. Measurement.
    let mut dets = Vec::with_capacity(clean.len());
    let mut truth = Vec::with_capacity(clean.len());
    for c in &clean {
        let n = noise.sample(rng);
        let r_hat = c.r + radar.beta * c.v_r + n[0];
        if r_hat < radar.min_range {
            continue;
        }
        let phi_hat = c.phi + n[1];
        dets.push(Detection {
            p_radar: Vec3::new(r_hat * phi_hat.cos(), r_hat * phi_hat.sin(), 0.0),
            v_r: c.v_r + n[2],
            // The ARS408 reports RCS in 0.5 dBsm steps.
            rcs: Some((c.rcs * 2.0).round() / 2.0),
        });
        truth.push(DetectionTruth {
            p_radar: Vec3::new(c.r * c.phi.cos(), c.r * c.phi.sin(), 0.0),
            v_r: c.v_r,
            noise: n,
            kind: c.kind,
            object: c.id,
            members: c.members,
        });
    }
    (dets, truth, dropout)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::config::{RouteConfig, SimConfig};
    use crate::sim::noise::NoiseConfig;
    use crate::sim::route::Centerline;
    use crate::sim::world::{Scatterer, Wall};
    use rand::SeedableRng;

    fn radar() -> SimRadarConfig {
        SimRadarConfig {
            false_alarm_rate: 0.0,
            empty_scan_probability: 0.0,
            partial_scan_probability: 0.0,
            detection_spread: 0.5,
            reference_rcs: -20.0,
            ..SimRadarConfig::default()
        }
    }

    fn refl() -> Reflectivity {
        Reflectivity {
            facade_density: 3.0,
            ..Reflectivity::from(&SimConfig::default().world)
        }
    }

    fn wall(a: (f64, f64), b: (f64, f64), id: u32) -> Wall {
        Wall {
            a: Vec2::new(a.0, a.1),
            b: Vec2::new(b.0, b.1),
            normal: Vec2::new(-1.0, 0.0),
            rcs: 10.0,
            id,
        }
    }

    fn run(world: &World, scans: u64) -> Vec<DetectionTruth> {
        let r = radar();
        let rays = occlusion_rays(r.half_fov());
        let noise = NoiseSampler::new(&NoiseConfig::none()).unwrap();
        let motion = RadarMotion::new(Vec2::zeros(), 0.0, 0.0, 0.0, &[0.0; 6]);
        let mut all = Vec::new();
        for k in 0..scans {
            let mut rng = StdRng::seed_from_u64(k);
            let (d, t, _) =
                simulate_scan(world, &r, &rays, &motion, 0, &[], &refl(), &noise, &mut rng);
            assert_eq!(d.len(), t.len());
            all.extend(t);
        }
        all
    }

    fn empty_world() -> World {
        World::empty(Centerline::new(&RouteConfig::default()).unwrap(), 1)
    }

    /// A near wall hides the part of a far wall behind it, and only that part.
    #[test]
    fn a_wall_hides_what_is_behind_it() {
        let mut w = empty_world();
        w.walls.push(wall((40.0, -30.0), (40.0, 30.0), 1));
        let far_alone = run(&w, 30);
        let in_shadow = |t: &DetectionTruth| (t.p_radar.y / t.p_radar.x).abs() < 5.0 / 20.0 - 0.01;
        assert!(
            far_alone
                .iter()
                .filter(|t| t.object == 1 && in_shadow(t))
                .count()
                > 50
        );

        w.walls.push(wall((20.0, -5.0), (20.0, 5.0), 0));
        let both = run(&w, 30);
        assert!(both.iter().any(|t| t.object == 0));
        assert!(
            both.iter()
                .filter(|t| t.object == 1 && !in_shadow(t))
                .count()
                > 50
        );
        assert_eq!(
            both.iter()
                .filter(|t| t.object == 1 && in_shadow(t))
                .count(),
            0
        );
        // Surfaces are sampled afresh per scan: no two wall detections coincide.
        let mut ys: Vec<f64> = both
            .iter()
            .filter(|t| t.object == 1)
            .map(|t| t.p_radar.y)
            .collect();
        ys.sort_by(f64::total_cmp);
        assert!(ys.windows(2).all(|p| p[1] > p[0]));
    }

    /// Two reflectors in one range/azimuth/Doppler cell merge into one detection between them; apart by more
    /// than the azimuth resolution, they are resolved.
    #[test]
    fn unresolved_reflectors_merge() {
        let pole = |y: f64, id: u32| Scatterer {
            p: Vec2::new(29.9, y),
            radius: 0.0,
            rcs: 30.0,
            kind: TargetKind::Pole,
            id,
            wall: None,
        };
        let mut w = empty_world();
        w.scatterers = vec![pole(0.05, 0), pole(0.45, 1)];
        let t = run(&w, 20);
        assert_eq!(t.len(), 20);
        for d in &t {
            assert_eq!(d.members, 2);
            assert!(d.p_radar.y > 0.05 && d.p_radar.y < 0.45);
        }
        w.scatterers[1].p.y = 4.0; // 7.6 deg apart
        let t = run(&w, 20);
        assert_eq!(t.len(), 40);
        assert!(t.iter().all(|d| d.members == 1));
    }

    /// Lever arm: a radar 3 m ahead of the body turning at 0.5 rad/s moves sideways at 1.5 m/s.
    #[test]
    fn radar_velocity_includes_the_lever_arm() {
        let m = RadarMotion::new(
            Vec2::new(1.0, 2.0),
            0.5 * std::f64::consts::PI,
            10.0,
            0.5,
            &[3.0, 0.0, 0.5, 0.0, 0.0, 0.3],
        );
        assert!((m.position - Vec2::new(1.0, 5.0)).norm() < 1e-12);
        assert!((m.velocity - Vec2::new(-1.5, 10.0)).norm() < 1e-12);
        assert!((m.heading - (0.5 * std::f64::consts::PI + 0.3)).abs() < 1e-15);
    }
}
