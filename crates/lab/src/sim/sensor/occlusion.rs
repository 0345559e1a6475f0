//! Step 2 of a scan: what the radar can see. A 1D depth buffer over azimuth holds the nearest wall or car
//! box on each ray; the walls in view come with the part of each that lies in front of the radar and
//! within coverage.

use super::{NO_OBJECT, RadarMotion};
use crate::sim::radar_config::SimRadarConfig;
use crate::sim::world::{CarBox, MoverState, TargetKind, Wall, World};
use dc_loc_core::math::Vec2;

/// Azimuth bin of the occlusion buffer, rad.
const OCCLUSION_BIN: f64 = 0.1 * std::f64::consts::PI / 180.0;
/// A reflection this much behind the nearest occluder on its ray still counts as visible, m.
const OCCLUSION_TOLERANCE: f64 = 0.3;

/// Nearest occluder per azimuth bin.
pub(super) struct DepthBuffer<'a> {
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
    pub(super) fn visible(&self, az: f64, r: f64, id: u32) -> bool {
        match self.bin(az) {
            Some(i) => self.id[i] == id || r <= self.depth[i] + OCCLUSION_TOLERANCE,
            None => false,
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

/// The radar position and the largest range of its coverage: what lies farther (beyond an object's
/// extent) cannot be seen.
#[derive(Debug, Clone, Copy)]
pub(super) struct Reach {
    /// Radar position, m (map frame).
    pub pos: Vec2,
    r_lim: f64,
}

impl Reach {
    pub fn new(radar: &SimRadarConfig, motion: &RadarMotion) -> Self {
        Reach {
            pos: motion.position,
            r_lim: radar.max_range(),
        }
    }
    /// Whether an object at `p` reaching `extent` metres around it can lie within range.
    pub fn near(&self, p: Vec2, extent: f64) -> bool {
        (p - self.pos).norm() <= self.r_lim + extent
    }
}

/// What the radar can see at one instant: the occlusion buffer, the walls in view (each with the
/// parameter interval of it in front of the radar and within coverage), the parked cars and the moving
/// vehicles in range.
pub(super) struct Scene<'a> {
    pub depth: DepthBuffer<'a>,
    pub walls: Vec<(&'a Wall, f64, f64)>,
    pub parked: Vec<&'a CarBox>,
    pub vehicles: Vec<&'a MoverState>,
}

/// Builds the occlusion buffer from every wall and car box in range; `lap` selects the parked cars.
pub(super) fn scene_in_view<'a>(
    world: &'a World,
    radar: &SimRadarConfig,
    rays: &'a [Vec2],
    motion: &RadarMotion,
    reach: &Reach,
    lap: usize,
    movers: &'a [MoverState],
) -> Scene<'a> {
    let mut depth = DepthBuffer::new(radar.half_fov(), rays);
    let mut walls = Vec::new();
    for w in &world.walls {
        let half = 0.5 * (w.b - w.a).norm();
        if !reach.near(0.5 * (w.a + w.b), half) {
            continue;
        }
        let (a, b) = (motion.radar_from_map(w.a), motion.radar_from_map(w.b));
        if let Some((t0, t1)) = segment_view(radar, a, b) {
            depth.add_segment(a, b, w.id);
            walls.push((w, t0, t1));
        }
    }
    let parked: Vec<&CarBox> = world
        .parked_on(lap)
        .filter(|c| reach.near(c.center, 3.0))
        .collect();
    for c in &parked {
        depth.add_box(motion, c);
    }
    let vehicles: Vec<&MoverState> = movers
        .iter()
        .filter(|m| m.mover.kind == TargetKind::Vehicle && reach.near(m.body.center, 3.0))
        .collect();
    for m in &vehicles {
        depth.add_box(motion, &m.body);
    }
    Scene {
        depth,
        walls,
        parked,
        vehicles,
    }
}
