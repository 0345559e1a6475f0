//! The simulated city: street cross-section, facades, side streets, street furniture, parked cars
//! and traffic ([`WorldConfig`] and its sections). Units are SI; RCS values are in dBsm.

use dc_loc_core::validate::{Range, Validator};
use serde::{Deserialize, Serialize};

/// Cross-section of the streets (distances from the centre line, m).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StreetConfig {
    /// Lane width, m (default 3.5).
    pub lane_width: f64,
    /// Lanes per direction (default 2). The ego drives in the outermost lane, traffic in the innermost.
    pub lanes_per_direction: u32,
    /// Centre of the parking strip, m (default 8.0).
    pub parking_offset: f64,
    /// Street lights and signs, m (default 9.6).
    pub pole_offset: f64,
    /// Trees and pedestrians, m (default 11.0).
    pub sidewalk_offset: f64,
    /// Building line: the nearest a facade comes to the centre line, m (default 13.0).
    pub building_line: f64,
    /// Building line of side streets, m (default 9.0).
    pub side_street_building_line: f64,
}

impl Default for StreetConfig {
    fn default() -> Self {
        StreetConfig {
            lane_width: 3.5,
            lanes_per_direction: 2,
            parking_offset: 8.0,
            pole_offset: 9.6,
            sidewalk_offset: 11.0,
            building_line: 13.0,
            side_street_building_line: 9.0,
        }
    }
}

impl StreetConfig {
    /// Distance of the ego's lane centre from the road centre line, m (outermost lane).
    pub fn ego_lane_offset(&self) -> f64 {
        (f64::from(self.lanes_per_direction) - 0.5) * self.lane_width
    }
    /// Distance of the traffic lane centre from the road centre line, m (innermost lane).
    pub fn traffic_lane_offset(&self) -> f64 {
        0.5 * self.lane_width
    }

    fn check(&self, v: &mut Validator) {
        v.positive("lane_width", self.lane_width);
        v.count(
            "lanes_per_direction",
            self.lanes_per_direction as usize,
            1,
            4,
        );
        let road = f64::from(self.lanes_per_direction) * self.lane_width;
        // Outwards from the road edge (half a car width beyond it), at least 0.5 m apart.
        let mut prev = road + 0.9;
        for (field, x) in [
            ("parking_offset", self.parking_offset),
            ("pole_offset", self.pole_offset),
            ("sidewalk_offset", self.sidewalk_offset),
            ("building_line", self.building_line),
        ] {
            v.range(field, x, Range::at_least(prev));
            prev = x + 0.5;
        }
        v.positive("side_street_building_line", self.side_street_building_line);
    }
}

/// Buildings along the streets: each building is a front facade plus two side walls.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FacadeConfig {
    /// Building frontage length range, m (default 12 to 60).
    pub length: [f64; 2],
    /// Probability of a gap (alley, yard) after a building (default 0.35).
    pub gap_probability: f64,
    /// Gap width range, m (default 3 to 12).
    pub gap: [f64; 2],
    /// Probability that a building stands back from the building line (default 0.5).
    pub setback_probability: f64,
    /// Setback range, m (default 0.5 to 5).
    pub setback: [f64; 2],
    /// Depth of the side walls, m (default 8 to 20).
    pub depth: [f64; 2],
    /// Mean RCS of one facade sample at normal incidence, dBsm, drawn per building (default 0 to 8).
    pub rcs: [f64; 2],
    /// Surface samples offered to the radar per metre of wall per scan (default 0.6).
    pub density: f64,
    /// Relief of the facade (windows, doors, balconies): samples lie up to this far behind the wall line,
    /// m (default 0.3).
    pub roughness: f64,
    /// RCS of a building's front corners (strong edge reflectors), dBsm (default 8).
    pub edge_rcs: f64,
}

impl Default for FacadeConfig {
    fn default() -> Self {
        FacadeConfig {
            length: [12.0, 60.0],
            gap_probability: 0.35,
            gap: [3.0, 12.0],
            setback_probability: 0.5,
            setback: [0.5, 5.0],
            depth: [8.0, 20.0],
            rcs: [0.0, 8.0],
            density: 0.6,
            roughness: 0.3,
            edge_rcs: 8.0,
        }
    }
}

impl FacadeConfig {
    fn check(&self, v: &mut Validator) {
        v.interval("length", self.length, Range::at_least(2.0));
        v.unit("gap_probability", self.gap_probability);
        v.interval("gap", self.gap, Range::NON_NEGATIVE);
        v.unit("setback_probability", self.setback_probability);
        v.interval("setback", self.setback, Range::NON_NEGATIVE);
        v.interval("depth", self.depth, Range::POSITIVE);
        v.interval("rcs", self.rcs, Range::FINITE);
        v.non_negative("density", self.density);
        v.non_negative("roughness", self.roughness);
        v.range("edge_rcs", self.edge_rcs, Range::FINITE);
    }
}

/// Side streets branching off the straights, and the streets that continue past junction corners.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SideStreetConfig {
    /// Distance between side streets along a straight, m (default 110 to 240).
    pub spacing: [f64; 2],
    /// Side street length, m (default 50 to 120); a building closes its far end.
    pub length: [f64; 2],
    /// Probability that a side street crosses (opens on both sides) rather than branching to one side
    /// (default 0.3).
    pub crossing_probability: f64,
    /// Length of the streets continuing past a junction corner, m (default 70).
    pub junction_length: f64,
}

impl Default for SideStreetConfig {
    fn default() -> Self {
        SideStreetConfig {
            spacing: [110.0, 240.0],
            length: [50.0, 120.0],
            crossing_probability: 0.3,
            junction_length: 70.0,
        }
    }
}

impl SideStreetConfig {
    fn check(&self, v: &mut Validator) {
        v.interval("spacing", self.spacing, Range::at_least(40.0));
        v.interval("length", self.length, Range::POSITIVE);
        v.unit("crossing_probability", self.crossing_probability);
        v.positive("junction_length", self.junction_length);
    }
}

/// Street furniture and vegetation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FurnitureConfig {
    /// Street light spacing along each side, m (default 30).
    pub pole_spacing: f64,
    /// Probability that a street light is missing (default 0.2).
    pub pole_missing_probability: f64,
    /// RCS of a street light or sign post, dBsm (default 5).
    pub pole_rcs: f64,
    /// Fraction of straights with a row of trees on a side (default 0.4).
    pub tree_row_probability: f64,
    /// Tree spacing in a row, m (default 7 to 12).
    pub tree_spacing: [f64; 2],
    /// RCS of a tree trunk, dBsm (default -2).
    pub trunk_rcs: f64,
    /// Probability that a set-back building has a front garden (bushes) (default 0.6).
    pub garden_probability: f64,
    /// Bush radius, m (default 0.8 to 2.5).
    pub bush_radius: [f64; 2],
    /// Mean RCS of one vegetation sample, dBsm (default -10).
    pub vegetation_rcs: f64,
    /// Vegetation samples offered per square metre per scan (default 0.25).
    pub vegetation_density: f64,
}

impl Default for FurnitureConfig {
    fn default() -> Self {
        FurnitureConfig {
            pole_spacing: 30.0,
            pole_missing_probability: 0.2,
            pole_rcs: 5.0,
            tree_row_probability: 0.4,
            tree_spacing: [7.0, 12.0],
            trunk_rcs: -2.0,
            garden_probability: 0.6,
            bush_radius: [0.8, 2.5],
            vegetation_rcs: -10.0,
            vegetation_density: 0.25,
        }
    }
}

impl FurnitureConfig {
    fn check(&self, v: &mut Validator) {
        v.range("pole_spacing", self.pole_spacing, Range::at_least(2.0));
        v.unit("pole_missing_probability", self.pole_missing_probability);
        v.range("pole_rcs", self.pole_rcs, Range::FINITE);
        v.unit("tree_row_probability", self.tree_row_probability);
        v.interval("tree_spacing", self.tree_spacing, Range::at_least(2.0));
        v.range("trunk_rcs", self.trunk_rcs, Range::FINITE);
        v.unit("garden_probability", self.garden_probability);
        v.interval("bush_radius", self.bush_radius, Range::POSITIVE);
        v.range("vegetation_rcs", self.vegetation_rcs, Range::FINITE);
        v.non_negative("vegetation_density", self.vegetation_density);
    }
}

/// Parked cars along the curbs of the loop's straights.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ParkingConfig {
    /// Length of a parking slot, m (default 6.0).
    pub slot_length: f64,
    /// Fraction of slots that hold the same car on every lap (default 0.35).
    pub persistent_fraction: f64,
    /// Fraction of slots whose occupancy changes: on each lap such a slot holds a (different) car with
    /// `occupancy` probability (default 0.45). The remaining slots are always empty.
    pub changing_fraction: f64,
    /// Occupancy of a changing slot on a lap (default 0.5).
    pub occupancy: f64,
    /// Car length and width, m (default 4.5 x 1.8).
    pub car_size: [f64; 2],
    /// Mean RCS of a car's strongest corner, dBsm (default 10).
    pub car_rcs: f64,
    /// Samples offered per metre of visible car side per scan (default 0.6).
    pub car_density: f64,
}

impl Default for ParkingConfig {
    fn default() -> Self {
        ParkingConfig {
            slot_length: 6.0,
            persistent_fraction: 0.35,
            changing_fraction: 0.45,
            occupancy: 0.5,
            car_size: [4.5, 1.8],
            car_rcs: 10.0,
            car_density: 0.6,
        }
    }
}

impl ParkingConfig {
    fn check(&self, v: &mut Validator) {
        v.positive("slot_length", self.slot_length);
        v.unit("persistent_fraction", self.persistent_fraction);
        v.range(
            "changing_fraction",
            self.changing_fraction,
            Range::closed(0.0, 1.0 - self.persistent_fraction),
        );
        v.unit("occupancy", self.occupancy);
        v.positive("car_size", self.car_size[0]);
        v.positive("car_size", self.car_size[1]);
        v.require("car_size", self.car_size[0] <= self.slot_length, || {
            "a car must fit its slot".into()
        });
        v.range("car_rcs", self.car_rcs, Range::FINITE);
        v.non_negative("car_density", self.car_density);
    }
}

/// Moving road users: vehicles in the inner lanes (both directions), pedestrians on the sidewalks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrafficConfig {
    /// Vehicles per km of loop in each direction (default 8).
    pub vehicles_per_km: f64,
    /// Range of the lane speeds, m/s (default 7 to 14); all vehicles of one lane share its speed.
    pub vehicle_speed: [f64; 2],
    /// Pedestrians per km of loop (both sides, both walking directions; default 12).
    pub pedestrians_per_km: f64,
    /// Walking speed range, m/s (default 0.8 to 1.8).
    pub pedestrian_speed: [f64; 2],
    /// Mean RCS of a pedestrian, dBsm (default -8).
    pub pedestrian_rcs: f64,
}

impl Default for TrafficConfig {
    fn default() -> Self {
        TrafficConfig {
            vehicles_per_km: 8.0,
            vehicle_speed: [7.0, 14.0],
            pedestrians_per_km: 12.0,
            pedestrian_speed: [0.8, 1.8],
            pedestrian_rcs: -8.0,
        }
    }
}

impl TrafficConfig {
    fn check(&self, v: &mut Validator) {
        v.range(
            "vehicles_per_km",
            self.vehicles_per_km,
            Range::closed(0.0, 80.0),
        );
        v.interval("vehicle_speed", self.vehicle_speed, Range::POSITIVE);
        v.range(
            "pedestrians_per_km",
            self.pedestrians_per_km,
            Range::closed(0.0, 500.0),
        );
        v.interval("pedestrian_speed", self.pedestrian_speed, Range::POSITIVE);
        v.range("pedestrian_rcs", self.pedestrian_rcs, Range::FINITE);
    }
}

/// Everything along the road.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorldConfig {
    /// Street cross-section.
    pub street: StreetConfig,
    /// Buildings.
    pub facades: FacadeConfig,
    /// Side streets and junctions.
    pub side_streets: SideStreetConfig,
    /// Poles, trees, bushes.
    pub furniture: FurnitureConfig,
    /// Parked cars.
    pub parking: ParkingConfig,
    /// Moving vehicles and pedestrians.
    pub traffic: TrafficConfig,
}

impl Default for WorldConfig {
    /// Each section's default: a four-lane city street with parking, street lights, some tree rows,
    /// buildings with gaps and setbacks, side streets every 110-240 m, 8 vehicles per km and direction.
    fn default() -> Self {
        WorldConfig {
            street: StreetConfig::default(),
            facades: FacadeConfig::default(),
            side_streets: SideStreetConfig::default(),
            furniture: FurnitureConfig::default(),
            parking: ParkingConfig::default(),
            traffic: TrafficConfig::default(),
        }
    }
}

impl WorldConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.section("street", |v| self.street.check(v));
        v.section("facades", |v| self.facades.check(v));
        v.section("side_streets", |v| self.side_streets.check(v));
        v.section("furniture", |v| self.furniture.check(v));
        v.section("parking", |v| self.parking.check(v));
        v.section("traffic", |v| self.traffic.check(v));
    }
}
