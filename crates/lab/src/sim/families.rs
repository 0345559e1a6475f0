//! World families: kinds of street the simulator builds besides the default city, each a change of
//! the [`WorldConfig`] sections (and, for one, of the road), and the held-out protocol that splits
//! families and seeds into a `dev` set (what tuning may look at) and a `test` set (what it may not).
//!
//! The families differ in what the registration has to hold on to: short detached houses with gardens
//! and trees (`suburb`), long flat walls with few corners (`industrial`), a wide road lined by guard
//! rail posts and distant buildings, nearly featureless along the road (`arterial`), streets lined by
//! the same parked cars on every lap (`parking`), a road between guard rails (`highway`), and a long
//! narrow loop between unbroken walls (`corridor`, the one family with a road of its own).

use super::config::{CornerConfig, RouteConfig, SimConfig};
use super::world_config::ParkingConfig;
use super::world_config::WorldConfig;
use serde::Serialize;

/// A kind of street.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub enum WorldFamily {
    /// The default city: four lanes, parking, buildings with gaps and setbacks.
    City,
    /// Two lanes, detached houses set back behind gardens, tree rows, little traffic.
    Suburb,
    /// Long flat warehouse walls with few gaps, little vegetation, sparse parking.
    Industrial,
    /// Six lanes, guard rail posts every 4 m, buildings 35 m from the centre line, no parking.
    Arterial,
    /// Streets lined by parked cars that stay on every lap, long facades with few gaps.
    Parking,
    /// A four-lane road between guard rails whose posts repeat every 2 m, with sparse tree rows and
    /// halls 45 m and more away: little but the rails along most of the road.
    Highway,
    /// A loop of two 1 km straights 140 m apart, each a street canyon between flat walls 10 m from
    /// the centre line with rare gaps, side streets every 300 to 600 m and sparse street lights: the
    /// walls fix the lateral position and the heading, almost nothing fixes the position along the
    /// road.
    Corridor,
}

impl WorldFamily {
    /// Every family, in table order.
    pub const ALL: [WorldFamily; 7] = [
        WorldFamily::City,
        WorldFamily::Suburb,
        WorldFamily::Industrial,
        WorldFamily::Arterial,
        WorldFamily::Parking,
        WorldFamily::Highway,
        WorldFamily::Corridor,
    ];

    /// The family's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            WorldFamily::City => "city",
            WorldFamily::Suburb => "suburb",
            WorldFamily::Industrial => "industrial",
            WorldFamily::Arterial => "arterial",
            WorldFamily::Parking => "parking",
            WorldFamily::Highway => "highway",
            WorldFamily::Corridor => "corridor",
        }
    }

    /// The family of a command-line name.
    pub fn parse(s: &str) -> Option<WorldFamily> {
        Self::ALL.into_iter().find(|f| f.name() == s)
    }

    /// The family's world: the default city with this family's changes.
    pub fn world(self) -> WorldConfig {
        let mut w = WorldConfig::default();
        match self {
            WorldFamily::City => {}
            WorldFamily::Suburb => suburb(&mut w),
            WorldFamily::Industrial => industrial(&mut w),
            WorldFamily::Arterial => arterial(&mut w),
            WorldFamily::Parking => parking(&mut w),
            WorldFamily::Highway => highway(&mut w),
            WorldFamily::Corridor => corridor(&mut w),
        }
        w
    }

    /// The family's own road, where it has one (the others drive the default loop).
    pub fn route(self) -> Option<RouteConfig> {
        match self {
            WorldFamily::Corridor => Some(corridor_route()),
            _ => None,
        }
    }

    /// Puts the family's world into `c`, and its road where it has one (else `c` keeps its road).
    pub fn apply(self, c: &mut SimConfig) {
        c.world = self.world();
        if let Some(route) = self.route() {
            c.route = route;
        }
    }
}

fn suburb(w: &mut WorldConfig) {
    let s = &mut w.street;
    (s.lane_width, s.lanes_per_direction) = (3.25, 1);
    (s.parking_offset, s.pole_offset, s.sidewalk_offset) = (5.5, 7.0, 8.0);
    (s.building_line, s.side_street_building_line) = (14.0, 12.0);
    let f = &mut w.facades;
    (f.length, f.gap_probability, f.gap) = ([9.0, 16.0], 0.8, [6.0, 15.0]);
    (f.setback_probability, f.setback, f.depth) = (0.9, [2.0, 8.0], [8.0, 12.0]);
    f.density = 0.5;
    let u = &mut w.furniture;
    (u.pole_spacing, u.tree_row_probability) = (40.0, 0.7);
    (u.garden_probability, u.vegetation_density) = (0.9, 0.5);
    (w.parking.persistent_fraction, w.parking.changing_fraction) = (0.2, 0.4);
    (w.traffic.vehicles_per_km, w.traffic.pedestrians_per_km) = (3.0, 6.0);
}

fn industrial(w: &mut WorldConfig) {
    w.street.building_line = 16.0;
    let f = &mut w.facades;
    (f.length, f.gap_probability, f.gap) = ([60.0, 160.0], 0.15, [8.0, 20.0]);
    (f.setback_probability, f.setback, f.depth) = (0.2, [1.0, 4.0], [30.0, 60.0]);
    (f.rcs, f.roughness) = ([4.0, 10.0], 0.05);
    let u = &mut w.furniture;
    (u.pole_spacing, u.tree_row_probability, u.garden_probability) = (45.0, 0.05, 0.05);
    (w.parking.persistent_fraction, w.parking.changing_fraction) = (0.1, 0.2);
    w.traffic.pedestrians_per_km = 2.0;
}

fn arterial(w: &mut WorldConfig) {
    let s = &mut w.street;
    (s.lane_width, s.lanes_per_direction) = (3.75, 3);
    (s.parking_offset, s.pole_offset, s.sidewalk_offset) = (12.5, 13.5, 15.0);
    s.building_line = 35.0;
    let f = &mut w.facades;
    (f.gap_probability, f.density) = (0.6, 0.3);
    let u = &mut w.furniture;
    (u.pole_spacing, u.pole_missing_probability, u.pole_rcs) = (4.0, 0.05, -2.0);
    (u.tree_row_probability, u.garden_probability) = (0.2, 0.1);
    (w.parking.persistent_fraction, w.parking.changing_fraction) = (0.0, 0.0);
    (w.traffic.vehicles_per_km, w.traffic.pedestrians_per_km) = (15.0, 1.0);
}

fn parking(w: &mut WorldConfig) {
    let f = &mut w.facades;
    (f.length, f.gap_probability) = ([40.0, 80.0], 0.1);
    let p = &mut w.parking;
    (
        p.slot_length,
        p.persistent_fraction,
        p.changing_fraction,
        p.occupancy,
    ) = (5.5, 0.85, 0.1, 0.9);
    w.furniture.tree_row_probability = 0.1;
}

fn highway(w: &mut WorldConfig) {
    let s = &mut w.street;
    (s.lane_width, s.lanes_per_direction) = (3.75, 2);
    (s.parking_offset, s.pole_offset, s.sidewalk_offset) = (8.5, 9.0, 16.0);
    (s.building_line, s.side_street_building_line) = (45.0, 30.0);
    let f = &mut w.facades;
    (f.length, f.gap_probability, f.gap) = ([20.0, 80.0], 0.85, [40.0, 150.0]);
    (f.setback_probability, f.setback, f.density) = (0.5, [0.0, 20.0], 0.3);
    w.side_streets.spacing = [400.0, 900.0];
    let u = &mut w.furniture;
    (u.pole_spacing, u.pole_missing_probability, u.pole_rcs) = (2.0, 0.02, -5.0);
    (
        u.tree_row_probability,
        u.garden_probability,
        u.vegetation_density,
    ) = (0.3, 0.0, 0.1);
    no_parked_cars(&mut w.parking);
    (w.traffic.vehicles_per_km, w.traffic.pedestrians_per_km) = (25.0, 0.0);
}

fn corridor(w: &mut WorldConfig) {
    let s = &mut w.street;
    (s.pole_offset, s.sidewalk_offset) = (8.5, 9.0);
    (s.building_line, s.side_street_building_line) = (10.0, 8.0);
    let f = &mut w.facades;
    (f.length, f.gap_probability, f.gap) = ([100.0, 250.0], 0.1, [3.0, 6.0]);
    (f.setback_probability, f.setback, f.depth) = (0.1, [0.2, 1.0], [15.0, 30.0]);
    f.roughness = 0.1;
    w.side_streets.spacing = [300.0, 600.0];
    let u = &mut w.furniture;
    (u.pole_spacing, u.pole_missing_probability) = (50.0, 0.3);
    (
        u.tree_row_probability,
        u.garden_probability,
        u.vegetation_density,
    ) = (0.0, 0.0, 0.0);
    no_parked_cars(&mut w.parking);
    (w.traffic.vehicles_per_km, w.traffic.pedestrians_per_km) = (20.0, 2.0);
}

/// No parking slot is ever taken.
fn no_parked_cars(p: &mut ParkingConfig) {
    (p.persistent_fraction, p.changing_fraction, p.occupancy) = (0.0, 0.0, 0.0);
}

/// A rectangle 1,000 x 140 m driven counter-clockwise, junctions at two opposite corners.
fn corridor_route() -> RouteConfig {
    let c = |x: f64, y: f64, junction: bool| CornerConfig {
        x,
        y,
        radius: 20.0,
        junction,
    };
    RouteConfig {
        corners: vec![
            c(0.0, 0.0, false),
            c(1000.0, 0.0, true),
            c(1000.0, 140.0, false),
            c(0.0, 140.0, true),
        ],
        ..RouteConfig::default()
    }
}

/// One world of the held-out protocol: a family and a seed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct ProtocolWorld {
    /// The family.
    pub family: WorldFamily,
    /// The simulator seed.
    pub seed: u64,
}

/// The worlds that tuning may look at: the default city with two seeds.
pub const DEV: [ProtocolWorld; 2] = [
    ProtocolWorld {
        family: WorldFamily::City,
        seed: 1,
    },
    ProtocolWorld {
        family: WorldFamily::City,
        seed: 2,
    },
];

/// The held-out worlds: every other family with seeds tuning never used. Results on these are
/// reported, never tuned on.
pub const TEST: [ProtocolWorld; 4] = [
    ProtocolWorld {
        family: WorldFamily::Suburb,
        seed: 101,
    },
    ProtocolWorld {
        family: WorldFamily::Industrial,
        seed: 102,
    },
    ProtocolWorld {
        family: WorldFamily::Arterial,
        seed: 103,
    },
    ProtocolWorld {
        family: WorldFamily::Parking,
        seed: 104,
    },
];

/// The worlds of a protocol set by its command-line name (`dev` or `test`).
pub fn protocol_set(name: &str) -> Option<&'static [ProtocolWorld]> {
    match name {
        "dev" => Some(&DEV),
        "test" => Some(&TEST),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dc_loc_core::validate::Validator;

    #[test]
    fn every_family_is_a_valid_world_that_differs_from_the_city() {
        for f in WorldFamily::ALL {
            let w = f.world();
            let mut v = Validator::at("world");
            w.check(&mut v);
            if let Err(e) = v.finish() {
                panic!("{}: {e}", f.name());
            }
            assert_eq!(WorldFamily::parse(f.name()), Some(f));
            assert_eq!(w == WorldConfig::default(), f == WorldFamily::City);
            if let Some(r) = f.route() {
                r.validate().unwrap_or_else(|e| panic!("{}: {e}", f.name()));
            }
        }
    }

    #[test]
    fn dev_and_test_share_no_family_and_no_seed() {
        for d in DEV {
            for t in TEST {
                assert_ne!(d.family, t.family);
                assert_ne!(d.seed, t.seed);
            }
        }
    }
}
