//! Step 3b of a scan: multipath ghosts. A reflector seen via a wall appears at its mirror image across
//! the wall's line, at the range of the bounced path, and moves as that mirror image: a static reflector
//! seen via a static wall gives a ghost with the Doppler of a static point, which a static-world filter
//! keeps.

use super::RadarMotion;
use super::occlusion::Scene;
use super::reflections::Candidate;
use crate::sim::radar_config::SimRadarConfig;
use crate::sim::world::{TargetKind, Wall};
use dc_loc_core::math::Vec2;
use rand::RngExt;
use rand::rngs::StdRng;

/// A reflector closer than this to a wall's line is on the wall: it has no ghost via that wall, m.
const MIN_WALL_OFFSET: f64 = 0.05;

/// Adds a ghost for each candidate that is not a wall point with probability `multipath_probability`,
/// via the wall in view giving the shortest bounced path. Draws from `rng` only when that probability
/// is positive.
pub(super) fn add_ghosts(
    cands: &mut Vec<Candidate>,
    scene: &Scene<'_>,
    radar: &SimRadarConfig,
    motion: &RadarMotion,
    rng: &mut StdRng,
) {
    let p = radar.multipath_probability;
    if p <= 0.0 {
        return;
    }
    let ghosts: Vec<Candidate> = cands
        .iter()
        .filter(|c| c.kind != TargetKind::Facade && rng.random::<f64>() < p)
        .filter_map(|c| ghost(c, scene, motion, radar.multipath_loss))
        .collect();
    cands.extend(ghosts);
}

/// The ghost of `c` via the wall in view whose specular point is seen by the radar and gives the shortest
/// bounced path; `None` when no wall does. The ghost lies on the wall's occlusion ray (its `surface` is the
/// wall), so that wall does not hide it.
fn ghost(c: &Candidate, scene: &Scene<'_>, motion: &RadarMotion, loss: f64) -> Option<Candidate> {
    let pos = motion.position;
    let (wall, image, n) = scene
        .walls
        .iter()
        .filter_map(|&(w, _, _)| {
            bounce(w, pos, c.p).map(|(image, specular, n)| (w, image, specular, n))
        })
        .filter(|&(w, _, specular, _)| {
            let q = motion.radar_from_map(specular);
            scene.depth.visible(q.y.atan2(q.x), q.norm(), w.id)
        })
        .map(|(w, image, _, n)| (w, image, n))
        .min_by(|a, b| (a.1 - pos).norm().total_cmp(&(b.1 - pos).norm()))?;
    Some(Candidate {
        p: image,
        v: c.v - n * (2.0 * n.dot(&c.v)),
        rcs: c.rcs - loss,
        kind: TargetKind::Ghost,
        id: c.id,
        surface: wall.id,
    })
}

/// The bounce off wall `w` from the radar at `pos` to a reflector at `p`: the mirror image of `p` across
/// the wall's line, the specular point (where the segment from the radar to the image crosses that line)
/// and the line's unit normal. `None` unless the radar sees the wall's front, the reflector stands off
/// the line on the radar's side, and the specular point lies on the wall.
fn bounce(w: &Wall, pos: Vec2, p: Vec2) -> Option<(Vec2, Vec2, Vec2)> {
    let e = w.b - w.a;
    let len = e.norm();
    if len <= 0.0 || w.normal.dot(&(pos - w.a)) <= 0.0 {
        return None;
    }
    let n = Vec2::new(-e.y, e.x) / len;
    // Signed distances of the radar and the reflector from the line.
    let (h_radar, h_refl) = (n.dot(&(pos - w.a)), n.dot(&(p - w.a)));
    if h_radar * h_refl <= 0.0 || h_refl.abs() < MIN_WALL_OFFSET {
        return None;
    }
    let image = p - n * (2.0 * h_refl);
    // The image lies at signed distance -h_refl: the segment crosses the line at this share of its length.
    let specular = pos + (image - pos) * (h_radar / (h_radar + h_refl));
    let t = (specular - w.a).dot(&e) / (len * len);
    (0.0..=1.0).contains(&t).then_some((image, specular, n))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wall(a: (f64, f64), b: (f64, f64)) -> Wall {
        Wall {
            a: Vec2::new(a.0, a.1),
            b: Vec2::new(b.0, b.1),
            normal: Vec2::new(0.0, -1.0),
            rcs: 10.0,
            id: 7,
        }
    }

    /// A reflector at (30, 3) seen from the origin via the line y = 10: image (30, 17), specular point
    /// at x = 30 * 10 / 17; a wall that stops short of it, or a reflector behind the wall, has none.
    #[test]
    fn bounce_mirrors_across_the_wall_line() {
        let (pos, p) = (Vec2::zeros(), Vec2::new(30.0, 3.0));
        let (image, specular, n) = bounce(&wall((0.0, 10.0), (80.0, 10.0)), pos, p).unwrap();
        assert!((image - Vec2::new(30.0, 17.0)).norm() < 1e-12);
        assert!((specular - Vec2::new(300.0 / 17.0, 10.0)).norm() < 1e-12);
        assert!((n.y.abs() - 1.0).abs() < 1e-12);
        assert!(bounce(&wall((20.0, 10.0), (80.0, 10.0)), pos, p).is_none());
        assert!(bounce(&wall((0.0, 10.0), (80.0, 10.0)), pos, Vec2::new(30.0, 12.0)).is_none());
        // The wall's back side does not reflect.
        let mut back = wall((0.0, 10.0), (80.0, 10.0));
        back.normal = Vec2::new(0.0, 1.0);
        assert!(bounce(&back, pos, p).is_none());
    }
}
