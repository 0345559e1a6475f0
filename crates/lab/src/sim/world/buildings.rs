//! Buildings: walls cut where they enter a street corridor, the buildings closing street ends, and the
//! buildings along one side of a street (front facade, side walls, corner reflectors, front gardens).

use super::{Scatterer, TargetKind, Wall, World};
use crate::sim::world_config::WorldConfig;
use dc_loc_core::math::Vec2;
use rand::RngExt;
use rand::rngs::StdRng;

/// The front yard of a set-back building: between the building line `a b` and the facade `depth` further
/// in direction `away`.
pub(super) struct Garden {
    pub a: Vec2,
    pub b: Vec2,
    pub away: Vec2,
    pub depth: f64,
}

impl World {
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
    pub(super) fn end_wall(
        &mut self,
        end: Vec2,
        dir: Vec2,
        hw: f64,
        rng: &mut StdRng,
        wc: &WorldConfig,
    ) {
        let across = Vec2::new(-dir.y, dir.x) * (hw + 15.0);
        let rcs = rng.random_range(wc.facades.rcs[0]..=wc.facades.rcs[1]);
        self.add_wall(end - across, end + across, -dir, rcs);
    }

    /// Buildings along one side of a street: `foot(t)` gives the centre point and unit tangent at `t` in
    /// `[0, len]`; `side` +1 builds on the left.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn buildings(
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
}
