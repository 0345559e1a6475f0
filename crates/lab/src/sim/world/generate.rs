//! World generation, in order: the street corridors (the loop, the stretches through its crossings if it
//! crosses itself, the streets continuing past junction corners, the side streets off the straights), the
//! buildings closing the street ends and those along every street, then furniture, parked cars and traffic.

use super::buildings::Garden;
use super::{Street, World};
use crate::sim::config::SimConfig;
use crate::sim::route::Centerline;
use crate::sim::world_config::WorldConfig;
use dc_loc_core::math::Vec2;
use dc_loc_core::validate::ConfigError;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

/// A side of a straight street: `foot(t)` on the centre line, its unit tangent, and `side` (+1 left).
struct StraightSide {
    origin: Vec2,
    dir: Vec2,
    side: f64,
    len: f64,
    building_line: f64,
}

/// The streets other than the loop, for the buildings: both sides of each, and each end to close (end
/// point, direction, building line half-width).
#[derive(Default)]
struct Layout {
    straight_sides: Vec<StraightSide>,
    ends: Vec<(Vec2, Vec2, f64)>,
}

impl Layout {
    /// A straight street from `origin` along `dir` for `len` m: both its sides and its end.
    fn add_street(&mut self, origin: Vec2, dir: Vec2, len: f64, building_line: f64) {
        for side in [1.0, -1.0] {
            self.straight_sides.push(StraightSide {
                origin,
                dir,
                side,
                len,
                building_line,
            });
        }
        self.ends.push((origin + dir * len, dir, building_line));
    }
}

impl World {
    /// Generates the world (all randomness from `cfg.seed`); `ConfigError` if `cfg` does not validate.
    pub fn generate(cfg: &SimConfig, line: Centerline) -> Result<World, ConfigError> {
        cfg.validate()?;
        let mut rng = StdRng::seed_from_u64(crate::sim::stream_seed(cfg.seed, 0x57_4f_52_4c_44, 0));
        let wc = &cfg.world;
        let mut w = World::empty(line, cfg.laps.len());
        w.loop_corridor(wc);
        w.crossings(wc);
        let mut layout = Layout::default();
        w.junction_streets(wc, &mut layout);
        w.side_streets(&mut rng, wc, &mut layout);
        let gardens = w.buildings_along_streets(&layout, &mut rng, wc);
        w.furniture(&mut rng, wc, &gardens);
        w.parking(&mut rng, wc);
        w.traffic(&mut rng, wc);
        Ok(w)
    }

    /// The loop's corridor, its centre line sampled every 2 m.
    fn loop_corridor(&mut self, wc: &WorldConfig) {
        let l = self.line.length();
        let m = (l / 2.0).ceil() as usize;
        let mut loop_pts: Vec<Vec2> = (0..m)
            .map(|i| self.line.point(l * i as f64 / m as f64))
            .collect();
        loop_pts.push(loop_pts[0]);
        self.streets
            .push(Street::new(loop_pts, wc.street.building_line));
    }

    /// Where the loop crosses itself (a figure eight): a short corridor along each of the two stretches
    /// through the crossing, so that neither street's furniture and parked cars stand in the other.
    fn crossings(&mut self, wc: &WorldConfig) {
        let hw = wc.street.building_line;
        let pts = &self.streets[0].points;
        let step = self.line.length() / (pts.len() - 1) as f64;
        // Segments this many apart along the loop cannot touch unless the loop crosses itself.
        let apart = ((4.0 * hw) / step).ceil() as usize + 1;
        let n = pts.len() - 1;
        let mut pieces = Vec::new();
        for i in 0..n {
            for j in i + apart..n {
                if n - j + i < apart {
                    continue;
                }
                if let Some(x) = segment_intersection(pts[i], pts[i + 1], pts[j], pts[j + 1]) {
                    for (a, b) in [(pts[i], pts[i + 1]), (pts[j], pts[j + 1])] {
                        let d = (b - a).normalize() * (hw + 2.0);
                        pieces.push(Street::new(vec![x - d, x + d], hw));
                    }
                }
            }
        }
        self.streets.extend(pieces);
    }

    /// Streets continuing past junction corners, each closed by a building at its end.
    fn junction_streets(&mut self, wc: &WorldConfig, layout: &mut Layout) {
        let hw = wc.street.building_line;
        let jl = wc.side_streets.junction_length;
        for c in self.line.corners().to_vec() {
            if !c.junction {
                continue;
            }
            for dir in [c.d_in, -c.d_out] {
                self.streets
                    .push(Street::new(vec![c.vertex, c.vertex + dir * jl], hw));
                layout.add_street(c.vertex, dir, jl, hw);
            }
        }
    }

    /// Side streets along the straights, away from corners: one side or both (a crossing).
    fn side_streets(&mut self, rng: &mut StdRng, wc: &WorldConfig, layout: &mut Layout) {
        let l = self.line.length();
        let hw = wc.street.building_line;
        let hs = wc.side_streets.length;
        for (a, b) in self.line.straights() {
            let mut s = a + rng.random_range(0.3..1.0) * wc.side_streets.spacing[0];
            while s < b {
                if !self.line.near_corner(s, 40.0) && s > 5.0 && s < l - 5.0 {
                    let sides: &[f64] = if rng.random_bool(wc.side_streets.crossing_probability) {
                        &[1.0, -1.0]
                    } else if rng.random_bool(0.5) {
                        &[1.0]
                    } else {
                        &[-1.0]
                    };
                    let th = self.line.heading(s);
                    let n = Vec2::new(-th.sin(), th.cos());
                    let foot = self.line.point(s);
                    for &side in sides {
                        let len = hw + rng.random_range(hs[0]..=hs[1]);
                        let dir = n * side;
                        let hws = wc.street.side_street_building_line;
                        self.streets
                            .push(Street::new(vec![foot, foot + dir * len], hws));
                        layout.add_street(foot, dir, len, hws);
                        self.side_streets.push((s, side));
                    }
                }
                s += rng.random_range(wc.side_streets.spacing[0]..=wc.side_streets.spacing[1]);
            }
        }
    }

    /// Now that every corridor exists: the buildings closing the street ends, then the buildings along
    /// both sides of the loop and of the other streets; returns the front gardens they left.
    fn buildings_along_streets(
        &mut self,
        layout: &Layout,
        rng: &mut StdRng,
        wc: &WorldConfig,
    ) -> Vec<Garden> {
        let l = self.line.length();
        let hw = wc.street.building_line;
        for &(end, dir, half_width) in &layout.ends {
            self.end_wall(end, dir, half_width, rng, wc);
        }
        let mut gardens = Vec::new();
        for side in [1.0, -1.0] {
            let line = self.line.clone();
            let foot = |t: f64| {
                let th = line.heading(t);
                (line.point(t), Vec2::new(th.cos(), th.sin()))
            };
            self.buildings(&foot, side, l, hw, rng, wc, &mut gardens);
        }
        for ss in &layout.straight_sides {
            let foot = |t: f64| (ss.origin + ss.dir * t, ss.dir);
            self.buildings(
                &foot,
                ss.side,
                ss.len,
                ss.building_line,
                rng,
                wc,
                &mut gardens,
            );
        }
        gardens
    }
}

/// The point where segments `a b` and `c d` cross, if they do.
fn segment_intersection(a: Vec2, b: Vec2, c: Vec2, d: Vec2) -> Option<Vec2> {
    let (r, q) = (b - a, d - c);
    let den = r.perp(&q);
    if den.abs() < 1e-12 {
        return None;
    }
    let t = (c - a).perp(&q) / den;
    let u = (c - a).perp(&r) / den;
    ((0.0..=1.0).contains(&t) && (0.0..=1.0).contains(&u)).then(|| a + r * t)
}
