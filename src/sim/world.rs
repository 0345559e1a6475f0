//! The simulated city: streets, buildings, street furniture, vegetation, parked cars and moving road users.
//!
//! Entry points: [`World::generate`] (deterministic from a seed), [`World::empty`], [`World`] and its object lists
//! ([`Wall`], [`Scatterer`], [`Bush`], [`CarBox`], [`Mover`]), [`World::movers_at`] (road users at a time),
//! [`TargetKind`].
//!
//! Construction: every street is a corridor (centre polyline and building line half-width): the loop, the
//! streets continuing past junction corners, and side streets off the straights. Buildings are placed along
//! both sides of every street (front facade at the building line plus a setback, two side walls, a gap
//! after some), then every wall is clipped where it enters any corridor, which opens junctions and side
//! streets. The far end of each side street is closed by a building. Objects carry an `id` (unique over
//! the world) so that detections can name what they hit.

use crate::math::Vec2;
use crate::sim::config::SimConfig;
use crate::sim::route::Centerline;
use crate::sim::world_config::WorldConfig;
use crate::validate::ConfigError;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::{Deserialize, Serialize};

/// What a detection comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum TargetKind {
    /// A building wall.
    Facade,
    /// A building's front corner.
    BuildingEdge,
    /// A street light or sign post.
    Pole,
    /// A tree trunk.
    Tree,
    /// A bush.
    Vegetation,
    /// A parked car.
    ParkedCar,
    /// A moving vehicle.
    Vehicle,
    /// A walking pedestrian.
    Pedestrian,
    /// A false alarm (clutter with random range, azimuth and Doppler).
    FalseAlarm,
}

impl TargetKind {
    /// The target moves (its Doppler is not that of the static world).
    pub fn is_moving(self) -> bool {
        matches!(self, TargetKind::Vehicle | TargetKind::Pedestrian)
    }
    /// The target is part of the static world (false alarms are neither static nor moving).
    pub fn is_static(self) -> bool {
        !self.is_moving() && self != TargetKind::FalseAlarm
    }
}

/// A wall segment; it reflects on its front side (`normal`) and blocks the view from both sides.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wall {
    /// Start point, m (map frame).
    pub a: Vec2,
    /// End point, m.
    pub b: Vec2,
    /// Unit normal of the reflecting side (towards the street).
    pub normal: Vec2,
    /// Mean RCS of one surface sample at normal incidence, dBsm.
    pub rcs: f64,
    /// Object id.
    pub id: u32,
}

/// A compact reflector: a pole, a tree trunk or a building corner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scatterer {
    /// Centre, m.
    pub p: Vec2,
    /// Radius of the body (the radar sees its near side), m.
    pub radius: f64,
    /// Mean RCS, dBsm.
    pub rcs: f64,
    /// Kind.
    pub kind: TargetKind,
    /// Object id.
    pub id: u32,
    /// For a building corner: the wall it belongs to (so that wall does not hide it).
    pub wall: Option<u32>,
}

/// A bush: returns weak detections from random points inside its disc.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bush {
    /// Centre, m.
    pub center: Vec2,
    /// Radius, m.
    pub radius: f64,
    /// Object id.
    pub id: u32,
}

/// A car-sized box (parked car, or a vehicle at one time).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CarBox {
    /// Centre, m.
    pub center: Vec2,
    /// Heading of the long axis, rad.
    pub heading: f64,
    /// Length, m.
    pub length: f64,
    /// Width, m.
    pub width: f64,
    /// Lap on which a parked car is there (`None`: every lap).
    pub lap: Option<usize>,
    /// Object id.
    pub id: u32,
}

impl CarBox {
    /// Corners, counter-clockwise.
    pub fn corners(&self) -> [Vec2; 4] {
        let (s, c) = self.heading.sin_cos();
        let f = Vec2::new(c, s) * (0.5 * self.length);
        let l = Vec2::new(-s, c) * (0.5 * self.width);
        [
            self.center + f - l,
            self.center + f + l,
            self.center - f + l,
            self.center - f - l,
        ]
    }
}

/// A road user moving along the loop at constant speed in a lane (or on a sidewalk).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mover {
    /// Vehicle or pedestrian.
    pub kind: TargetKind,
    /// Loop arc length at time 0, m.
    pub s0: f64,
    /// Rate of its loop arc length, m/s (negative: against the loop direction).
    pub rate: f64,
    /// Lateral offset from the centre line, m (positive left of the loop direction).
    pub offset: f64,
    /// Length, m (pedestrians: 0.5).
    pub length: f64,
    /// Width, m.
    pub width: f64,
    /// Mean RCS of its strongest point, dBsm.
    pub rcs: f64,
    /// Object id.
    pub id: u32,
}

/// A mover at one time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MoverState {
    /// The mover.
    pub mover: Mover,
    /// Its box (centre, heading along the direction of motion).
    pub body: CarBox,
    /// Velocity of the centre, m/s (map frame).
    pub velocity: Vec2,
    /// Yaw rate, rad/s.
    pub yaw_rate: f64,
}

impl MoverState {
    /// Velocity of a point `p` of the rigid body, m/s.
    pub fn velocity_at(&self, p: Vec2) -> Vec2 {
        let r = p - self.body.center;
        self.velocity + Vec2::new(-r.y, r.x) * self.yaw_rate
    }
}

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
    fn new(points: Vec<Vec2>, half_width: f64) -> Self {
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

/// The generated world.
#[derive(Debug, Clone)]
pub struct World {
    /// The road loop's centre line.
    pub line: Centerline,
    /// Street corridors (index 0: the loop).
    pub streets: Vec<Street>,
    /// Building walls.
    pub walls: Vec<Wall>,
    /// Poles, tree trunks, building corners.
    pub scatterers: Vec<Scatterer>,
    /// Bushes.
    pub bushes: Vec<Bush>,
    /// Parked cars (some only on one lap).
    pub parked: Vec<CarBox>,
    /// Vehicles and pedestrians.
    pub movers: Vec<Mover>,
    /// Side streets as (loop arc length, side: +1 left / -1 right).
    pub side_streets: Vec<(f64, f64)>,
    laps: usize,
    next_id: u32,
}

/// The front yard of a set-back building: between the building line `a b` and the facade `depth` further
/// in direction `away`.
struct Garden {
    a: Vec2,
    b: Vec2,
    away: Vec2,
    depth: f64,
}

/// A side of a straight street: `foot(t)` on the centre line, its unit tangent, and `side` (+1 left).
struct StraightSide {
    origin: Vec2,
    dir: Vec2,
    side: f64,
    len: f64,
    building_line: f64,
}

impl World {
    /// Generates the world (all randomness from `cfg.seed`); `ConfigError` if `cfg` does not validate.
    pub fn generate(cfg: &SimConfig, line: Centerline) -> Result<World, ConfigError> {
        cfg.validate()?;
        let mut rng = StdRng::seed_from_u64(super::stream_seed(cfg.seed, 0x57_4f_52_4c_44, 0));
        let wc = &cfg.world;
        let mut w = World {
            line,
            streets: Vec::new(),
            walls: Vec::new(),
            scatterers: Vec::new(),
            bushes: Vec::new(),
            parked: Vec::new(),
            movers: Vec::new(),
            side_streets: Vec::new(),
            laps: cfg.laps.len(),
            next_id: 0,
        };
        let l = w.line.length();
        let hw = wc.street.building_line;
        // Street corridors: the loop, sampled every 2 m.
        let m = (l / 2.0).ceil() as usize;
        let mut loop_pts: Vec<Vec2> = (0..m)
            .map(|i| w.line.point(l * i as f64 / m as f64))
            .collect();
        loop_pts.push(loop_pts[0]);
        w.streets.push(Street::new(loop_pts, hw));
        // Streets continuing past junction corners, each closed by a building at its end.
        let mut straight_sides: Vec<StraightSide> = Vec::new();
        let mut ends: Vec<(Vec2, Vec2, f64)> = Vec::new();
        let jl = wc.side_streets.junction_length;
        for c in w.line.corners().to_vec() {
            if !c.junction {
                continue;
            }
            for dir in [c.d_in, -c.d_out] {
                w.streets
                    .push(Street::new(vec![c.vertex, c.vertex + dir * jl], hw));
                for side in [1.0, -1.0] {
                    straight_sides.push(StraightSide {
                        origin: c.vertex,
                        dir,
                        side,
                        len: jl,
                        building_line: hw,
                    });
                }
                ends.push((c.vertex + dir * jl, dir, hw));
            }
        }
        // Side streets along the straights, away from corners.
        let hs = wc.side_streets.length;
        for (a, b) in w.line.straights() {
            let mut s = a + rng.random_range(0.3..1.0) * wc.side_streets.spacing[0];
            while s < b {
                if !w.line.near_corner(s, 40.0) && s > 5.0 && s < l - 5.0 {
                    let sides: &[f64] = if rng.random_bool(wc.side_streets.crossing_probability) {
                        &[1.0, -1.0]
                    } else if rng.random_bool(0.5) {
                        &[1.0]
                    } else {
                        &[-1.0]
                    };
                    let th = w.line.heading(s);
                    let n = Vec2::new(-th.sin(), th.cos());
                    let foot = w.line.point(s);
                    for &side in sides {
                        let len = hw + rng.random_range(hs[0]..=hs[1]);
                        let dir = n * side;
                        let hws = wc.street.side_street_building_line;
                        w.streets
                            .push(Street::new(vec![foot, foot + dir * len], hws));
                        for ss in [1.0, -1.0] {
                            straight_sides.push(StraightSide {
                                origin: foot,
                                dir,
                                side: ss,
                                len,
                                building_line: hws,
                            });
                        }
                        ends.push((foot + dir * len, dir, hws));
                        w.side_streets.push((s, side));
                    }
                }
                s += rng.random_range(wc.side_streets.spacing[0]..=wc.side_streets.spacing[1]);
            }
        }
        // Now that every corridor exists: the buildings closing the street ends, then the buildings along
        // both sides of the loop and of the other streets.
        for (end, dir, half_width) in ends {
            w.end_wall(end, dir, half_width, &mut rng, wc);
        }
        let mut gardens = Vec::new();
        for side in [1.0, -1.0] {
            let line = w.line.clone();
            let foot = |t: f64| {
                let th = line.heading(t);
                (line.point(t), Vec2::new(th.cos(), th.sin()))
            };
            w.buildings(&foot, side, l, hw, &mut rng, wc, &mut gardens);
        }
        for ss in &straight_sides {
            let foot = |t: f64| (ss.origin + ss.dir * t, ss.dir);
            w.buildings(
                &foot,
                ss.side,
                ss.len,
                ss.building_line,
                &mut rng,
                wc,
                &mut gardens,
            );
        }
        w.furniture(&mut rng, wc, &gardens);
        w.parking(&mut rng, wc);
        w.traffic(&mut rng, wc);
        Ok(w)
    }

    /// A world with the loop's corridor but no objects (for sensor tests that place objects by hand;
    /// ids must then be set by the caller).
    pub fn empty(line: Centerline, laps: usize) -> World {
        World {
            line,
            streets: Vec::new(),
            walls: Vec::new(),
            scatterers: Vec::new(),
            bushes: Vec::new(),
            parked: Vec::new(),
            movers: Vec::new(),
            side_streets: Vec::new(),
            laps,
            next_id: 0,
        }
    }

    fn id(&mut self) -> u32 {
        self.next_id += 1;
        self.next_id - 1
    }

    /// Number of objects (ids are below this).
    pub fn object_count(&self) -> u32 {
        self.next_id
    }

    /// Whether `p` is inside a street corridor other than the loop (a junction mouth or side street).
    fn in_side_street(&self, p: Vec2, margin: f64) -> bool {
        self.streets[1..].iter().any(|s| s.contains(p, margin))
    }

    /// Adds the wall `a b` with its front towards `normal`, cut where it enters a street corridor.
    /// Returns the ids of the pieces and whether each end survived (for corner reflectors).
    fn add_wall(&mut self, a: Vec2, b: Vec2, normal: Vec2, rcs: f64) -> (Vec<u32>, bool, bool) {
        let len = (b - a).norm();
        let k = ((len / 0.5).ceil() as usize).max(1);
        let inside: Vec<bool> = (0..=k)
            .map(|i| {
                let p = a + (b - a) * (i as f64 / k as f64);
                self.streets.iter().any(|s| s.contains(p, 0.01))
            })
            .collect();
        let mut ids = Vec::new();
        let mut i = 0;
        while i <= k {
            if inside[i] {
                i += 1;
                continue;
            }
            let start = i;
            while i < k && !inside[i + 1] {
                i += 1;
            }
            let (ta, tb) = (start as f64 / k as f64, i as f64 / k as f64);
            if (tb - ta) * len >= 1.0 {
                let id = self.id();
                self.walls.push(Wall {
                    a: a + (b - a) * ta,
                    b: a + (b - a) * tb,
                    normal,
                    rcs,
                    id,
                });
                ids.push(id);
            }
            i += 1;
        }
        (ids, !inside[0], !inside[k])
    }

    /// A building across the end of a street heading `dir`, facing back along it.
    fn end_wall(&mut self, end: Vec2, dir: Vec2, hw: f64, rng: &mut StdRng, wc: &WorldConfig) {
        let across = Vec2::new(-dir.y, dir.x) * (hw + 15.0);
        let rcs = rng.random_range(wc.facades.rcs[0]..=wc.facades.rcs[1]);
        self.add_wall(end - across, end + across, -dir, rcs);
    }

    /// Buildings along one side of a street: `foot(t)` gives the centre point and unit tangent at `t` in
    /// `[0, len]`; `side` +1 builds on the left.
    #[allow(clippy::too_many_arguments)]
    fn buildings(
        &mut self,
        foot: &dyn Fn(f64) -> (Vec2, Vec2),
        side: f64,
        len: f64,
        hw: f64,
        rng: &mut StdRng,
        wc: &WorldConfig,
        gardens: &mut Vec<Garden>,
    ) {
        let f = &wc.facades;
        let off = |t: f64, d: f64| {
            let (p, tan) = foot(t);
            p + Vec2::new(-tan.y, tan.x) * (side * d)
        };
        let mut t = rng.random_range(0.0..f.gap[1].max(1.0));
        while t < len - 2.0 {
            let lb = rng.random_range(f.length[0]..=f.length[1]).min(len - t);
            let setback = if rng.random_bool(f.setback_probability) {
                rng.random_range(f.setback[0]..=f.setback[1])
            } else {
                0.0
            };
            let d = hw + setback;
            let rcs = rng.random_range(f.rcs[0]..=f.rcs[1]);
            // Front: chords of at most 4 m (straight streets give one segment per building).
            let chords = ((lb / 4.0).ceil() as usize).max(1);
            let straight = (foot(t).1 - foot(t + lb).1).norm() < 1e-9;
            let chords = if straight { 1 } else { chords };
            let mut front_ids = Vec::new();
            let (mut first_ok, mut last_ok) = (false, false);
            for c in 0..chords {
                let ta = t + lb * c as f64 / chords as f64;
                let tb = t + lb * (c + 1) as f64 / chords as f64;
                let (a, b) = (off(ta, d), off(tb, d));
                let e = b - a;
                // Normal towards the street centre.
                let normal = Vec2::new(-e.y, e.x).normalize() * (-side);
                let (ids, a_ok, b_ok) = self.add_wall(a, b, normal, rcs);
                if c == 0 {
                    first_ok = a_ok;
                }
                if c + 1 == chords {
                    last_ok = b_ok;
                }
                front_ids.extend(ids);
            }
            // Side walls, going away from the street, facing outwards of the building.
            for (tt, ok, sign) in [(t, first_ok, -1.0), (t + lb, last_ok, 1.0)] {
                let depth = rng.random_range(f.depth[0]..=f.depth[1]);
                let (p, tan) = foot(tt);
                let nrm = Vec2::new(-tan.y, tan.x) * side;
                let a = p + nrm * d;
                let b = a + nrm * depth;
                self.add_wall(a, b, tan * sign, rcs);
                if ok {
                    let wall = if sign < 0.0 {
                        front_ids.first()
                    } else {
                        front_ids.last()
                    };
                    let id = self.id();
                    self.scatterers.push(Scatterer {
                        p: a,
                        radius: 0.0,
                        rcs: f.edge_rcs,
                        kind: TargetKind::BuildingEdge,
                        id,
                        wall: wall.copied(),
                    });
                }
            }
            if setback >= 1.5 {
                let tan = foot(t + 0.5 * lb).1;
                gardens.push(Garden {
                    a: off(t, hw),
                    b: off(t + lb, hw),
                    away: Vec2::new(-tan.y, tan.x) * side,
                    depth: setback,
                });
            }
            t += lb;
            if rng.random_bool(f.gap_probability) {
                t += rng.random_range(f.gap[0]..=f.gap[1]);
            }
        }
    }

    fn furniture(&mut self, rng: &mut StdRng, wc: &WorldConfig, gardens: &[Garden]) {
        let fc = &wc.furniture;
        let st = &wc.street;
        let l = self.line.length();
        for side in [1.0, -1.0] {
            // Street lights all along the loop.
            let mut s = rng.random_range(0.0..fc.pole_spacing);
            while s < l {
                let p = self.line.offset_point(s, side * st.pole_offset);
                if !rng.random_bool(fc.pole_missing_probability) && !self.in_side_street(p, -1.0) {
                    let id = self.id();
                    self.scatterers.push(Scatterer {
                        p,
                        radius: 0.1,
                        rcs: fc.pole_rcs,
                        kind: TargetKind::Pole,
                        id,
                        wall: None,
                    });
                }
                s += fc.pole_spacing * rng.random_range(0.85..1.15);
            }
            // Tree rows on some straights.
            for (a, b) in self.line.straights() {
                if !rng.random_bool(fc.tree_row_probability) {
                    continue;
                }
                let mut s = a + rng.random_range(2.0..fc.tree_spacing[1]);
                while s < b - 2.0 {
                    let p = self.line.offset_point(s, side * st.sidewalk_offset);
                    if !self.in_side_street(p, -1.0) && !self.line.near_corner(s, 5.0) {
                        let id = self.id();
                        self.scatterers.push(Scatterer {
                            p,
                            radius: rng.random_range(0.12..0.3),
                            rcs: fc.trunk_rcs + rng.random_range(-2.0..2.0),
                            kind: TargetKind::Tree,
                            id,
                            wall: None,
                        });
                    }
                    s += rng.random_range(fc.tree_spacing[0]..=fc.tree_spacing[1]);
                }
            }
        }
        // Bushes in front gardens of set-back buildings.
        for g in gardens {
            if !rng.random_bool(fc.garden_probability) {
                continue;
            }
            let (a, e, away, depth) = (g.a, g.b - g.a, g.away, g.depth);
            if e.norm() < 1.0 {
                continue;
            }
            let count = rng.random_range(1..=3);
            for _ in 0..count {
                let r = rng
                    .random_range(fc.bush_radius[0]..=fc.bush_radius[1])
                    .min(0.5 * depth);
                let c = a
                    + e * rng.random_range(0.1..0.9)
                    + away * (r + rng.random_range(0.0..(depth - 2.0 * r).max(0.01)));
                if self.in_side_street(c, -r) {
                    continue;
                }
                let id = self.id();
                self.bushes.push(Bush {
                    center: c,
                    radius: r,
                    id,
                });
            }
        }
    }

    fn parking(&mut self, rng: &mut StdRng, wc: &WorldConfig) {
        let pc = &wc.parking;
        let st = &wc.street;
        for side in [1.0, -1.0] {
            for (a, b) in self.line.straights() {
                let mut s = a + 12.0 + rng.random_range(0.0..pc.slot_length);
                while s + pc.slot_length < b - 12.0 {
                    let mid = s + 0.5 * pc.slot_length;
                    let c = self.line.offset_point(mid, side * st.parking_offset);
                    if !self.in_side_street(c, -3.0) && !self.line.near_corner(mid, 10.0) {
                        let th = self.line.heading(mid);
                        let laps = self.laps;
                        let u: f64 = rng.random();
                        let mut car = |rng: &mut StdRng, lap: Option<usize>| {
                            let jitter = rng.random_range(-0.5..0.5);
                            let t = Vec2::new(th.cos(), th.sin());
                            let id = self.id();
                            self.parked.push(CarBox {
                                center: c + t * jitter,
                                heading: th,
                                length: pc.car_size[0]
                                    * rng
                                        .random_range(0.9f64..1.1)
                                        .min(pc.slot_length / pc.car_size[0]),
                                width: pc.car_size[1] * rng.random_range(0.95..1.05),
                                lap,
                                id,
                            });
                        };
                        if u < pc.persistent_fraction {
                            car(rng, None);
                        } else if u < pc.persistent_fraction + pc.changing_fraction {
                            for lap in 0..laps {
                                if rng.random_bool(pc.occupancy) {
                                    car(rng, Some(lap));
                                }
                            }
                        }
                    }
                    s += pc.slot_length;
                }
            }
        }
    }

    fn traffic(&mut self, rng: &mut StdRng, wc: &WorldConfig) {
        let tc = &wc.traffic;
        let l = self.line.length();
        let lane = wc.street.traffic_lane_offset();
        for dir in [1.0, -1.0] {
            let n = (tc.vehicles_per_km * l / 1000.0).round() as usize;
            let speed = rng.random_range(tc.vehicle_speed[0]..=tc.vehicle_speed[1]);
            for k in 0..n {
                let s0 = (k as f64 + rng.random_range(-0.3..0.3)) * l / n as f64;
                let id = self.id();
                self.movers.push(Mover {
                    kind: TargetKind::Vehicle,
                    s0: s0.rem_euclid(l),
                    rate: dir * speed,
                    // Right-hand traffic: forward vehicles right of the centre line.
                    offset: -dir * lane,
                    length: rng.random_range(4.0..5.2),
                    width: rng.random_range(1.7..2.0),
                    rcs: wc.parking.car_rcs,
                    id,
                });
            }
        }
        let n = (tc.pedestrians_per_km * l / 1000.0).round() as usize;
        for _ in 0..n {
            let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let dir = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let id = self.id();
            self.movers.push(Mover {
                kind: TargetKind::Pedestrian,
                s0: rng.random_range(0.0..l),
                rate: dir * rng.random_range(tc.pedestrian_speed[0]..=tc.pedestrian_speed[1]),
                offset: side * (wc.street.sidewalk_offset + rng.random_range(-1.0..1.0)),
                length: 0.5,
                width: 0.5,
                rcs: tc.pedestrian_rcs,
                id,
            });
        }
    }

    /// Every mover's box and velocity at time `t` (s since the start): exact derivatives of its path
    /// `c(s) + offset n(s)` with `s = s0 + rate t`.
    pub fn movers_at(&self, t: f64) -> Vec<MoverState> {
        self.movers
            .iter()
            .map(|m| {
                let s = m.s0 + m.rate * t;
                let th = self.line.heading(s);
                let k = self.line.curvature(s);
                let tan = Vec2::new(th.cos(), th.sin());
                let center = self.line.offset_point(s, m.offset);
                let heading = if m.rate >= 0.0 {
                    th
                } else {
                    th + std::f64::consts::PI
                };
                MoverState {
                    mover: *m,
                    body: CarBox {
                        center,
                        heading,
                        length: m.length,
                        width: m.width,
                        lap: None,
                        id: m.id,
                    },
                    velocity: tan * (m.rate * (1.0 - m.offset * k)),
                    yaw_rate: m.rate * k,
                }
            })
            .collect()
    }

    /// Parked cars present on `lap`.
    pub fn parked_on(&self, lap: usize) -> impl Iterator<Item = &CarBox> {
        self.parked
            .iter()
            .filter(move |c| c.lap.is_none_or(|l| l == lap))
    }

    /// Axis-aligned bounds of all walls (min, max), m.
    pub fn bounds(&self) -> (Vec2, Vec2) {
        let mut lo = Vec2::repeat(f64::INFINITY);
        let mut hi = Vec2::repeat(f64::NEG_INFINITY);
        for w in &self.walls {
            for p in [w.a, w.b] {
                lo = lo.inf(&p);
                hi = hi.sup(&p);
            }
        }
        (lo, hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::route::Centerline;

    fn world() -> World {
        let cfg = SimConfig::default();
        World::generate(&cfg, Centerline::new(&cfg.route).unwrap()).unwrap()
    }

    /// No wall stands inside a street and the ego lane is clear of every object.
    #[test]
    fn streets_are_clear() {
        let w = world();
        let cfg = SimConfig::default();
        for wall in &w.walls {
            for i in 0..=10 {
                let p = wall.a + (wall.b - wall.a) * (i as f64 / 10.0);
                assert!(
                    !w.streets.iter().any(|s| s.contains(p, 0.3)),
                    "wall {} in a street",
                    wall.id
                );
            }
        }
        let off = cfg.world.street.ego_lane_offset();
        let l = w.line.length();
        let mut s = 0.0;
        while s < l {
            for o in [off, -off] {
                let p = w.line.offset_point(s, o);
                for c in &w.parked {
                    assert!(
                        (c.center - p).norm() > 2.0,
                        "parked car in the ego lane at s = {s}"
                    );
                }
                for sc in &w.scatterers {
                    assert!(
                        (sc.p - p).norm() > 2.5,
                        "{:?} in the ego lane at s = {s}",
                        sc.kind
                    );
                }
            }
            s += 1.0;
        }
        // The world has each kind of object.
        assert!(w.walls.len() > 300);
        assert!(w.scatterers.iter().any(|s| s.kind == TargetKind::Pole));
        assert!(w.scatterers.iter().any(|s| s.kind == TargetKind::Tree));
        assert!(
            w.scatterers
                .iter()
                .any(|s| s.kind == TargetKind::BuildingEdge)
        );
        assert!(!w.bushes.is_empty());
        assert!(w.parked.iter().any(|c| c.lap.is_none()));
        assert!(w.parked.iter().any(|c| c.lap == Some(0)));
        assert!(w.movers.iter().any(|m| m.kind == TargetKind::Pedestrian));
        assert!(w.side_streets.len() >= 4);
    }

    /// Mover velocities are the time derivative of their positions (central differences).
    #[test]
    fn mover_velocity_is_the_derivative_of_position() {
        let w = world();
        let h = 1e-4;
        for t in [3.0, 47.0, 131.0] {
            let (a, b, m) = (w.movers_at(t - h), w.movers_at(t + h), w.movers_at(t));
            for i in 0..m.len() {
                let v = (b[i].body.center - a[i].body.center) / (2.0 * h);
                assert!((v - m[i].velocity).norm() < 1e-5, "mover {i}");
                let dyaw =
                    crate::math::wrap_angle(b[i].body.heading - a[i].body.heading) / (2.0 * h);
                assert!((dyaw - m[i].yaw_rate).abs() < 1e-5);
            }
        }
    }
}
