//! Step 3 of a scan: the candidate reflections, drawn afresh each scan. Random points along the visible
//! walls (with surface relief, an incidence loss) and car sides, random points in bushes, the near side
//! of poles and trunks, building corners, pedestrians; each with a Swerling-1 RCS around its mean.

use super::Reflectivity;
use super::occlusion::{Reach, Scene};
use crate::sim::world::{CarBox, MoverState, TargetKind, Wall, World};
use dc_loc_core::math::Vec2;
use rand::RngExt;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Exp1, Poisson};

/// A reflection offered to the radar.
pub(super) struct Candidate {
    pub p: Vec2,
    pub v: Vec2,
    pub rcs: f64,
    pub kind: TargetKind,
    pub id: u32,
    /// Id of the occluder it lies on (itself for walls and cars).
    pub surface: u32,
}

/// Swerling-1 fluctuation in dB: exponential power around the mean.
pub(super) fn swerling(rng: &mut StdRng) -> f64 {
    let x: f64 = Exp1.sample(rng);
    10.0 * x.max(1e-12).log10()
}

/// A Poisson draw of mean `lambda` (0 for a mean that is not positive).
pub(super) fn poisson(rng: &mut StdRng, lambda: f64) -> usize {
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

/// Every candidate reflection of the scene, in a fixed order (walls, compact reflectors, bushes, parked
/// cars, vehicles, pedestrians) so that one seed gives one scan.
pub(super) fn candidates(
    world: &World,
    scene: &Scene<'_>,
    movers: &[MoverState],
    reach: &Reach,
    refl: &Reflectivity,
    rng: &mut StdRng,
) -> Vec<Candidate> {
    let mut s = Sampler {
        pos: reach.pos,
        refl,
        out: Vec::new(),
    };
    s.walls(&scene.walls, rng);
    s.compact(world, reach, rng);
    s.bushes(world, reach, rng);
    let car_rcs = refl.car_rcs;
    for c in &scene.parked {
        s.car(rng, c, car_rcs, TargetKind::ParkedCar, None);
    }
    for m in &scene.vehicles {
        s.car(rng, &m.body, m.mover.rcs, TargetKind::Vehicle, Some(m));
    }
    s.pedestrians(movers, reach, rng);
    s.out
}

/// Collects candidates seen from the radar position `pos`.
struct Sampler<'a> {
    pos: Vec2,
    refl: &'a Reflectivity,
    out: Vec<Candidate>,
}

impl Sampler<'_> {
    /// Random points on the front side of each wall in view, set back by the surface relief, with the
    /// incidence loss of the ray.
    fn walls(&mut self, walls: &[(&Wall, f64, f64)], rng: &mut StdRng) {
        let pos = self.pos;
        for &(w, t0, t1) in walls {
            let e = w.b - w.a;
            let len = e.norm();
            if w.normal.dot(&(pos - w.a)) <= 0.0 {
                continue;
            }
            for _ in 0..poisson(rng, self.refl.facade_density * (t1 - t0) * len) {
                let t = rng.random_range(t0..=t1);
                let p = w.a + e * t - w.normal * rng.random_range(0.0..=self.refl.facade_roughness);
                let ray = (p - pos).normalize();
                let cos_inc = ray.dot(&w.normal).abs();
                self.out.push(Candidate {
                    p,
                    v: Vec2::zeros(),
                    rcs: w.rcs + 10.0 * (0.15 + 0.85 * cos_inc).log10() + swerling(rng),
                    kind: TargetKind::Facade,
                    id: w.id,
                    surface: w.id,
                });
            }
        }
    }

    /// The near side of each pole, trunk and building corner in range.
    fn compact(&mut self, world: &World, reach: &Reach, rng: &mut StdRng) {
        for s in &world.scatterers {
            if !reach.near(s.p, 0.0) {
                continue;
            }
            let d = s.p - self.pos;
            let p = s.p - d.normalize() * s.radius;
            self.out.push(Candidate {
                p,
                v: Vec2::zeros(),
                rcs: s.rcs + swerling(rng),
                kind: s.kind,
                id: s.id,
                surface: s.wall.unwrap_or(s.id),
            });
        }
    }

    /// Random points inside each bush in range.
    fn bushes(&mut self, world: &World, reach: &Reach, rng: &mut StdRng) {
        for b in &world.bushes {
            if !reach.near(b.center, b.radius) {
                continue;
            }
            let area = std::f64::consts::PI * b.radius * b.radius;
            for _ in 0..poisson(rng, self.refl.vegetation_density * area) {
                let rr = b.radius * rng.random::<f64>().sqrt();
                let a = rng.random_range(0.0..std::f64::consts::TAU);
                self.out.push(Candidate {
                    p: b.center + Vec2::new(a.cos(), a.sin()) * rr,
                    v: Vec2::zeros(),
                    rcs: self.refl.vegetation_rcs + swerling(rng),
                    kind: TargetKind::Vegetation,
                    id: b.id,
                    surface: b.id,
                });
            }
        }
    }

    /// A car box: its corner nearest the radar (the strongest reflector) and random points along the
    /// sides that face the radar, 6 dB weaker; `mover` gives the velocity of a moving one.
    fn car(
        &mut self,
        rng: &mut StdRng,
        body: &CarBox,
        rcs: f64,
        kind: TargetKind,
        mover: Option<&MoverState>,
    ) {
        let pos = self.pos;
        let corners = body.corners();
        let vel = |p: Vec2| mover.map_or(Vec2::zeros(), |m| m.velocity_at(p));
        // The corner nearest the radar is the strongest reflector (bumper corner, wheel arch).
        let (ci, _) = corners
            .iter()
            .enumerate()
            .map(|(i, c)| (i, (c - pos).norm()))
            .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
        let c = corners[ci];
        self.out.push(Candidate {
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
            for _ in 0..poisson(rng, self.refl.car_density * e.norm()) {
                let p = a + e * rng.random::<f64>();
                self.out.push(Candidate {
                    p,
                    v: vel(p),
                    rcs: rcs - 6.0 + swerling(rng),
                    kind,
                    id: body.id,
                    surface: body.id,
                });
            }
        }
    }

    /// Each pedestrian in range, at its centre.
    fn pedestrians(&mut self, movers: &[MoverState], reach: &Reach, rng: &mut StdRng) {
        for m in movers
            .iter()
            .filter(|m| m.mover.kind == TargetKind::Pedestrian && reach.near(m.body.center, 0.0))
        {
            self.out.push(Candidate {
                p: m.body.center,
                v: m.velocity,
                rcs: m.mover.rcs + swerling(rng),
                kind: TargetKind::Pedestrian,
                id: m.mover.id,
                surface: m.mover.id,
            });
        }
    }
}
