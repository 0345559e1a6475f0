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
//!
//! Parts: `street` (corridors), `generate` (the order of construction), `buildings`, `furniture`
//! (furniture, parked cars, traffic).

mod buildings;
mod furniture;
mod generate;
mod street;

pub use street::{Street, point_segment_distance};

use crate::sim::route::Centerline;
use dc_loc_core::math::Vec2;
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
    /// A multipath ghost: a reflector seen via a wall, at its mirror image across the wall (the
    /// detection's object is the reflector's id).
    Ghost,
    /// The road surface, seen by a radar that measures elevation.
    Ground,
}

impl TargetKind {
    /// The target moves (its Doppler is not that of the static world).
    pub fn is_moving(self) -> bool {
        matches!(self, TargetKind::Vehicle | TargetKind::Pedestrian)
    }
    /// The target is part of the static world (false alarms and ghosts are neither static nor moving).
    pub fn is_static(self) -> bool {
        !self.is_moving() && !matches!(self, TargetKind::FalseAlarm | TargetKind::Ghost)
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

impl World {
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
    use crate::sim::config::SimConfig;

    fn world() -> World {
        let cfg = SimConfig::default();
        World::generate(&cfg, Centerline::new(&cfg.route).unwrap()).unwrap()
    }

    /// City blocks in a figure eight whose halves cross at right angles at the origin.
    fn figure_eight() -> SimConfig {
        let c = |x: f64, y: f64| crate::sim::config::CornerConfig {
            x,
            y,
            radius: 15.0,
            junction: false,
        };
        let mut cfg = SimConfig::default();
        cfg.route.corners = vec![
            c(100.0, 0.0),
            c(100.0, 100.0),
            c(0.0, 100.0),
            c(0.0, -100.0),
            c(-100.0, -100.0),
            c(-100.0, 0.0),
        ];
        cfg
    }

    /// No wall stands inside a street and the ego lane is clear of every object, on the default loop
    /// and on a figure eight (whose crossing cuts the buildings of both streets back).
    #[test]
    fn streets_are_clear() {
        let w = streets_are_clear_in(&SimConfig::default());
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
        let cfg = figure_eight();
        let w = streets_are_clear_in(&cfg);
        assert!(w.line.total_turn().abs() < 1e-9, "a figure eight");
        assert_eq!(
            w.streets.len() - 1,
            2 + w.side_streets.len(),
            "one crossing"
        );
    }

    fn streets_are_clear_in(cfg: &SimConfig) -> World {
        let w = World::generate(cfg, Centerline::new(&cfg.route).unwrap()).unwrap();
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
        w
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
                let dyaw = dc_loc_core::math::wrap_angle(b[i].body.heading - a[i].body.heading)
                    / (2.0 * h);
                assert!((dyaw - m[i].yaw_rate).abs() < 1e-5);
            }
        }
    }
}
