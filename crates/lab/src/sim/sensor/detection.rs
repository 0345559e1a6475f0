//! Steps 4 to 7 of a scan: from candidate reflections to measured detections. Physics and visibility
//! of each candidate, merging into resolution cells and the detection draw per cell; false alarms, the
//! cap on detections and dropouts; measurement noise and the Doppler range distortion.

use super::elevation;
use super::occlusion::DepthBuffer;
use super::reflections::{Candidate, poisson};
use super::{DetectionTruth, Dropout, NO_OBJECT, RadarMotion};
use crate::sim::noise::NoiseSampler;
use crate::sim::radar_config::SimRadarConfig;
use crate::sim::world::TargetKind;
use dc_loc_core::math::Vec3;
use dc_loc_core::radar::Detection;
use rand::RngExt;
use rand::rngs::StdRng;
use rand_distr::StandardNormal;
use std::collections::HashMap;

/// One resolution cell being accumulated.
pub(super) struct Cell {
    w: f64,
    wr: f64,
    wphi: f64,
    wv: f64,
    we: f64,
    rcs_lin: f64,
    best_w: f64,
    kind: TargetKind,
    id: u32,
    members: u32,
}

/// A detection before measurement noise (`r` the slant range, `elev` 0 for a planar radar).
pub(super) struct Clean {
    r: f64,
    phi: f64,
    elev: f64,
    v_r: f64,
    rcs: f64,
    margin: f64,
    kind: TargetKind,
    id: u32,
    members: u32,
}

/// Steps 4 and 5, physics and resolution: each visible candidate in range, with its radial velocity and
/// SNR margin, merged into its (range, azimuth, Doppler, elevation) cell, power-weighted. A radar that
/// measures elevation sees each candidate at a height drawn from its object's extent (`rng`), at its
/// slant range, and only within its elevation field of view; a planar one draws nothing.
pub(super) fn resolution_cells(
    cands: &[Candidate],
    radar: &SimRadarConfig,
    motion: &RadarMotion,
    depth: &DepthBuffer<'_>,
    rng: &mut StdRng,
) -> Vec<Cell> {
    let pos = motion.position;
    let mut cells: Vec<Cell> = Vec::new();
    let mut cell_at: HashMap<(i64, i64, i64, i64), usize> = HashMap::new();
    for c in cands {
        let q = motion.radar_from_map(c.p);
        let planar = q.norm();
        let phi = q.y.atan2(q.x);
        let r_max = radar.range_at(phi);
        if planar < radar.min_range || planar > r_max || !depth.visible(phi, planar, c.surface) {
            continue;
        }
        let (r, elev) = if radar.has_elevation() {
            match elevation::place(radar, c.kind, planar, rng) {
                Some(seen) => seen,
                None => continue,
            }
        } else {
            (planar, 0.0)
        };
        let d = (c.p - pos) / planar;
        // The velocities are horizontal: the radial velocity along a ray at elevation `elev`.
        let v_r = d.dot(&(c.v - motion.velocity)) * elev.cos();
        let margin = c.rcs - radar.reference_rcs - 40.0 * (r / r_max).log10();
        let w = 10f64.powf(margin / 10.0);
        let key = (
            (r / radar.range_resolution).floor() as i64,
            (phi / radar.azimuth_resolution).floor() as i64,
            (v_r / radar.velocity_resolution).floor() as i64,
            (elev / radar.elevation_resolution).floor() as i64,
        );
        let idx = *cell_at.entry(key).or_insert_with(|| {
            cells.push(Cell {
                w: 0.0,
                wr: 0.0,
                wphi: 0.0,
                wv: 0.0,
                we: 0.0,
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
        cell.we += w * elev;
        cell.rcs_lin += 10f64.powf(c.rcs / 10.0);
        cell.members += 1;
        if w > cell.best_w {
            cell.best_w = w;
            cell.kind = c.kind;
            cell.id = c.id;
        }
    }
    cells
}

/// The cells detected, each with a logistic probability of its SNR margin, at their power-weighted
/// mean.
pub(super) fn detect_cells(cells: &[Cell], radar: &SimRadarConfig, rng: &mut StdRng) -> Vec<Clean> {
    let mut clean: Vec<Clean> = Vec::new();
    for cell in cells {
        let margin = 10.0 * cell.w.log10();
        let p_d = 1.0 / (1.0 + (-margin / radar.detection_spread).exp());
        if rng.random::<f64>() < p_d {
            clean.push(Clean {
                r: cell.wr / cell.w,
                phi: cell.wphi / cell.w,
                elev: cell.we / cell.w,
                v_r: cell.wv / cell.w,
                rcs: 10.0 * cell.rcs_lin.log10(),
                margin,
                kind: cell.kind,
                id: cell.id,
                members: cell.members,
            });
        }
    }
    clean
}

/// Step 6, first part: false alarms at random range, azimuth and Doppler.
pub(super) fn add_false_alarms(clean: &mut Vec<Clean>, radar: &SimRadarConfig, rng: &mut StdRng) {
    let half_fov = radar.half_fov();
    for _ in 0..poisson(rng, radar.false_alarm_rate) {
        let phi = rng.random_range(-half_fov..=half_fov);
        let r_max = radar.range_at(phi);
        if r_max <= radar.min_range {
            continue;
        }
        let elev = if radar.has_elevation() {
            elevation::random_elevation(radar, rng)
        } else {
            0.0
        };
        clean.push(Clean {
            r: rng.random_range(radar.min_range..r_max),
            phi,
            elev,
            v_r: rng.random_range(-25.0..25.0),
            rcs: rng.random_range(-15.0..-5.0),
            margin: 0.0,
            kind: TargetKind::FalseAlarm,
            id: NO_OBJECT,
            members: 0,
        });
    }
}

/// Step 6, second part: the strongest `max_detections` kept, ordered by range, then the scan's dropout
/// (all lost, or the tail of the list).
pub(super) fn cap_and_drop(
    clean: &mut Vec<Clean>,
    radar: &SimRadarConfig,
    rng: &mut StdRng,
) -> Dropout {
    clean.sort_by(|a, b| b.margin.total_cmp(&a.margin));
    clean.truncate(radar.max_detections);
    clean.sort_by(|a, b| a.r.total_cmp(&b.r));
    let u: f64 = rng.random();
    if u < radar.empty_scan_probability {
        clean.clear();
        Dropout::Empty
    } else if u < radar.empty_scan_probability + radar.partial_scan_probability {
        let keep = (clean.len() as f64 * rng.random_range(0.2..0.8)).round() as usize;
        clean.truncate(keep);
        Dropout::Partial
    } else {
        Dropout::None
    }
}

/// Step 7, measurement: noise and the Doppler range distortion added, detections below the minimum
/// range dropped; the detections and their truth, in the same order.
pub(super) fn measure(
    clean: &[Clean],
    radar: &SimRadarConfig,
    noise: &NoiseSampler,
    rng: &mut StdRng,
) -> (Vec<Detection>, Vec<DetectionTruth>) {
    let mut dets = Vec::with_capacity(clean.len());
    let mut truth = Vec::with_capacity(clean.len());
    for c in clean {
        let n = noise.sample(rng);
        let r_hat = c.r + radar.beta * c.v_r + n[0];
        if r_hat < radar.min_range {
            continue;
        }
        let phi_hat = c.phi + n[1];
        let elev_hat = if radar.has_elevation() {
            c.elev + radar.elevation_noise * rng.sample::<f64, _>(StandardNormal)
        } else {
            0.0
        };
        dets.push(Detection {
            p_radar: spherical(r_hat, phi_hat, elev_hat),
            v_r: c.v_r + n[2],
            // The ARS408 reports RCS in 0.5 dBsm steps.
            rcs: Some((c.rcs * 2.0).round() / 2.0),
        });
        truth.push(DetectionTruth {
            p_radar: spherical(c.r, c.phi, c.elev),
            v_r: c.v_r,
            noise: n,
            kind: c.kind,
            object: c.id,
            members: c.members,
        });
    }
    (dets, truth)
}

/// The point at range `r`, azimuth `phi` and elevation `elev` (radar frame); `z = 0` at elevation 0.
fn spherical(r: f64, phi: f64, elev: f64) -> Vec3 {
    let h = r * elev.cos();
    Vec3::new(h * phi.cos(), h * phi.sin(), r * elev.sin())
}
