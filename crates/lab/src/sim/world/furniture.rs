//! Street furniture, vegetation, parked cars and moving road users.

use super::buildings::Garden;
use super::{Bush, CarBox, Mover, Scatterer, TargetKind, World};
use crate::sim::world_config::WorldConfig;
use dc_loc_core::math::Vec2;
use rand::RngExt;
use rand::rngs::StdRng;

impl World {
    /// Street lights along the loop, tree rows on some straights, bushes in front gardens.
    pub(super) fn furniture(&mut self, rng: &mut StdRng, wc: &WorldConfig, gardens: &[Garden]) {
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

    /// Parked cars along the straights: some there on every lap, some changing from lap to lap.
    pub(super) fn parking(&mut self, rng: &mut StdRng, wc: &WorldConfig) {
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

    /// Vehicles in both lanes of the loop and pedestrians on the sidewalks.
    pub(super) fn traffic(&mut self, rng: &mut StdRng, wc: &WorldConfig) {
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
}
