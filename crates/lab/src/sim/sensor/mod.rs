//! One radar scan: what an ARS408-like radar reports from the world at one instant.
//!
//! [`simulate_scan`] moves the radar with its lever arm, finds what it can see ([`occlusion_rays`]),
//! draws candidate reflections (walls, cars, bushes, poles, corners, pedestrians; multipath ghosts and,
//! with elevation, the road when configured), applies the FMCW physics, merges what one resolution cell
//! holds, detects cells by their SNR margin, adds false alarms, the cap and dropouts, and measures with
//! noise and the Doppler range shift. docs/algorithm.md, "A radar scan", has the steps 1-7 in detail.
//!
//! Entry points: [`simulate_scan`], [`occlusion_rays`], [`DetectionTruth`], [`Dropout`], [`RadarMotion`],
//! [`Reflectivity`].
//! Parts, by those steps: `occlusion` (2), `reflections`, `multipath` and `elevation` (3 and 4),
//! `detection` (4 to 7).

mod detection;
mod elevation;
mod multipath;
mod occlusion;
mod reflections;

pub use occlusion::occlusion_rays;

use crate::sim::noise::NoiseSampler;
use crate::sim::radar_config::SimRadarConfig;
use crate::sim::world::{MoverState, TargetKind, World};
use crate::sim::world_config::WorldConfig;
use dc_loc_core::math::{Vec2, Vec3};
use dc_loc_core::radar::Detection;
use rand::rngs::StdRng;
use serde::{Deserialize, Serialize};

/// Object id of false alarms.
pub const NO_OBJECT: u32 = u32::MAX;

/// The noise-free truth behind one detection.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DetectionTruth {
    /// True (undistorted, noise-free) position in the radar frame, m; z = 0 for a planar radar.
    pub p_radar: Vec3,
    /// True radial velocity, m/s (positive away from the radar).
    pub v_r: f64,
    /// The noise added: range (m), azimuth (rad), radial velocity (m/s).
    pub noise: [f64; 3],
    /// What it comes from (the strongest reflection in its resolution cell).
    pub kind: TargetKind,
    /// Object id in the world ([`NO_OBJECT`] for false alarms).
    pub object: u32,
    /// Number of reflections merged into this detection (0 for false alarms).
    pub members: u32,
}

/// What went wrong with a scan as a whole.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Dropout {
    /// A complete scan.
    None,
    /// The scan came out empty.
    Empty,
    /// The scan lost the tail of its detection list.
    Partial,
}

/// The radar's pose and velocity in the map frame at the scan time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RadarMotion {
    /// Radar position, m.
    pub position: Vec2,
    /// Radar boresight heading, rad.
    pub heading: f64,
    /// Radar velocity, m/s (body velocity plus the yaw-rate lever arm).
    pub velocity: Vec2,
}

impl RadarMotion {
    /// From the body pose (position, heading), forward speed and yaw rate, and the radar extrinsic
    /// `[x, y, z, roll, pitch, yaw]` in the body frame.
    pub fn new(
        body_position: Vec2,
        body_heading: f64,
        speed: f64,
        yaw_rate: f64,
        extrinsic: &[f64; 6],
    ) -> Self {
        let (s, c) = body_heading.sin_cos();
        let lever = Vec2::new(
            c * extrinsic[0] - s * extrinsic[1],
            s * extrinsic[0] + c * extrinsic[1],
        );
        RadarMotion {
            position: body_position + lever,
            heading: body_heading + extrinsic[5],
            velocity: Vec2::new(c, s) * speed + Vec2::new(-lever.y, lever.x) * yaw_rate,
        }
    }
    fn radar_from_map(&self, p: Vec2) -> Vec2 {
        let (s, c) = self.heading.sin_cos();
        let d = p - self.position;
        Vec2::new(c * d.x + s * d.y, -s * d.x + c * d.y)
    }
}

/// How densely surfaces are sampled and how strongly they reflect (from `WorldConfig`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reflectivity {
    /// Wall samples per metre per scan.
    pub facade_density: f64,
    /// Wall relief depth, m.
    pub facade_roughness: f64,
    /// Car side samples per metre per scan.
    pub car_density: f64,
    /// Mean RCS of a parked car's strongest corner, dBsm.
    pub car_rcs: f64,
    /// Mean RCS of a vegetation sample, dBsm.
    pub vegetation_rcs: f64,
    /// Vegetation samples per square metre per scan.
    pub vegetation_density: f64,
}

impl Reflectivity {
    /// The surface sample densities times `gain` (a radar that resolves more scatterers per surface).
    fn scaled(&self, gain: f64) -> Reflectivity {
        Reflectivity {
            facade_density: self.facade_density * gain,
            car_density: self.car_density * gain,
            vegetation_density: self.vegetation_density * gain,
            ..*self
        }
    }
}

impl From<&WorldConfig> for Reflectivity {
    fn from(w: &WorldConfig) -> Self {
        Reflectivity {
            facade_density: w.facades.density,
            facade_roughness: w.facades.roughness,
            car_density: w.parking.car_density,
            car_rcs: w.parking.car_rcs,
            vegetation_rcs: w.furniture.vegetation_rcs,
            vegetation_density: w.furniture.vegetation_density,
        }
    }
}

/// The world as one radar sees it at one instant: detections in the radar frame, their truth (same order)
/// and the dropout that hit the scan. `lap` selects the parked cars; `movers` are the road users at the
/// scan time; `rays` are the radar's [`occlusion_rays`]; `ghost_rng` draws the multipath ghosts and
/// nothing else (untouched when `radar.multipath_probability` is 0).
#[allow(clippy::too_many_arguments)]
pub fn simulate_scan(
    world: &World,
    radar: &SimRadarConfig,
    rays: &[Vec2],
    motion: &RadarMotion,
    lap: usize,
    movers: &[MoverState],
    refl: &Reflectivity,
    noise: &NoiseSampler,
    rng: &mut StdRng,
    ghost_rng: &mut StdRng,
) -> (Vec<Detection>, Vec<DetectionTruth>, Dropout) {
    let reach = occlusion::Reach::new(radar, motion);
    let scene = occlusion::scene_in_view(world, radar, rays, motion, &reach, lap, movers);
    let refl = refl.scaled(radar.scatter_gain);
    let mut cands = reflections::candidates(world, &scene, movers, &reach, &refl, rng);
    multipath::add_ghosts(&mut cands, &scene, radar, motion, ghost_rng);
    if radar.has_elevation() {
        cands.extend(elevation::ground(radar, motion, rng));
    }
    let cells = detection::resolution_cells(&cands, radar, motion, &scene.depth, rng);
    let mut clean = detection::detect_cells(&cells, radar, rng);
    detection::add_false_alarms(&mut clean, radar, rng);
    let dropout = detection::cap_and_drop(&mut clean, radar, rng);
    let (dets, truth) = detection::measure(&clean, radar, noise, rng);
    (dets, truth, dropout)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::config::{RouteConfig, SimConfig};
    use crate::sim::noise::NoiseConfig;
    use crate::sim::route::Centerline;
    use crate::sim::world::{Scatterer, Wall};
    use rand::SeedableRng;

    fn radar() -> SimRadarConfig {
        SimRadarConfig {
            false_alarm_rate: 0.0,
            empty_scan_probability: 0.0,
            partial_scan_probability: 0.0,
            detection_spread: 0.5,
            reference_rcs: -20.0,
            ..SimRadarConfig::default()
        }
    }

    fn refl() -> Reflectivity {
        Reflectivity {
            facade_density: 3.0,
            ..Reflectivity::from(&SimConfig::default().world)
        }
    }

    fn wall(a: (f64, f64), b: (f64, f64), id: u32) -> Wall {
        Wall {
            a: Vec2::new(a.0, a.1),
            b: Vec2::new(b.0, b.1),
            normal: Vec2::new(-1.0, 0.0),
            rcs: 10.0,
            id,
        }
    }

    /// The detections of `scans` noise-free scans by radar `r` moving as `motion`, each with its truth.
    fn scan_all(
        world: &World,
        r: &SimRadarConfig,
        motion: &RadarMotion,
        movers: &[MoverState],
        refl: &Reflectivity,
        scans: u64,
    ) -> Vec<(Detection, DetectionTruth)> {
        let rays = occlusion_rays(r.half_fov());
        let noise = NoiseSampler::new(&NoiseConfig::none()).unwrap();
        let mut all = Vec::new();
        for k in 0..scans {
            let mut rng = StdRng::seed_from_u64(k);
            let mut ghost_rng = StdRng::seed_from_u64(k + 1000);
            let (d, t, _) = simulate_scan(
                world,
                r,
                &rays,
                motion,
                0,
                movers,
                refl,
                &noise,
                &mut rng,
                &mut ghost_rng,
            );
            assert_eq!(d.len(), t.len());
            all.extend(d.into_iter().zip(t));
        }
        all
    }

    fn run(world: &World, scans: u64) -> Vec<DetectionTruth> {
        let motion = RadarMotion::new(Vec2::zeros(), 0.0, 0.0, 0.0, &[0.0; 6]);
        scan_all(world, &radar(), &motion, &[], &refl(), scans)
            .into_iter()
            .map(|(_, t)| t)
            .collect()
    }

    fn empty_world() -> World {
        World::empty(Centerline::new(&RouteConfig::default()).unwrap(), 1)
    }

    /// A near wall hides the part of a far wall behind it, and only that part.
    #[test]
    fn a_wall_hides_what_is_behind_it() {
        let mut w = empty_world();
        w.walls.push(wall((40.0, -30.0), (40.0, 30.0), 1));
        let far_alone = run(&w, 30);
        let in_shadow = |t: &DetectionTruth| (t.p_radar.y / t.p_radar.x).abs() < 5.0 / 20.0 - 0.01;
        assert!(
            far_alone
                .iter()
                .filter(|t| t.object == 1 && in_shadow(t))
                .count()
                > 50
        );

        w.walls.push(wall((20.0, -5.0), (20.0, 5.0), 0));
        let both = run(&w, 30);
        assert!(both.iter().any(|t| t.object == 0));
        assert!(
            both.iter()
                .filter(|t| t.object == 1 && !in_shadow(t))
                .count()
                > 50
        );
        assert_eq!(
            both.iter()
                .filter(|t| t.object == 1 && in_shadow(t))
                .count(),
            0
        );
        // Surfaces are sampled afresh per scan: no two wall detections coincide.
        let mut ys: Vec<f64> = both
            .iter()
            .filter(|t| t.object == 1)
            .map(|t| t.p_radar.y)
            .collect();
        ys.sort_by(f64::total_cmp);
        assert!(ys.windows(2).all(|p| p[1] > p[0]));
    }

    /// Two reflectors in one range/azimuth/Doppler cell merge into one detection between them; apart by more
    /// than the azimuth resolution, they are resolved.
    #[test]
    fn unresolved_reflectors_merge() {
        let pole = |y: f64, id: u32| Scatterer {
            p: Vec2::new(29.9, y),
            radius: 0.0,
            rcs: 30.0,
            kind: TargetKind::Pole,
            id,
            wall: None,
        };
        let mut w = empty_world();
        w.scatterers = vec![pole(0.05, 0), pole(0.45, 1)];
        let t = run(&w, 20);
        assert_eq!(t.len(), 20);
        for d in &t {
            assert_eq!(d.members, 2);
            assert!(d.p_radar.y > 0.05 && d.p_radar.y < 0.45);
        }
        w.scatterers[1].p.y = 4.0; // 7.6 deg apart
        let t = run(&w, 20);
        assert_eq!(t.len(), 40);
        assert!(t.iter().all(|d| d.members == 1));
    }

    /// A world of one long wall along y = 10 facing the radar at the origin (no surface samples, so only
    /// what it mirrors shows) and a pole at (30, 3); the wall runs over x in `wall_x`.
    fn mirror_world(wall_x: (f64, f64)) -> World {
        let mut w = empty_world();
        w.walls.push(Wall {
            normal: Vec2::new(0.0, -1.0),
            ..wall((wall_x.0, 10.0), (wall_x.1, 10.0), 1)
        });
        w.scatterers.push(Scatterer {
            p: Vec2::new(30.0, 3.0),
            radius: 0.0,
            rcs: 30.0,
            kind: TargetKind::Pole,
            id: 0,
            wall: None,
        });
        w
    }

    /// The ghosts of `scans` scans of a radar at the origin driving along x at 10 m/s, with multipath
    /// probability `p`.
    fn ghosts(
        world: &World,
        p: f64,
        movers: &[MoverState],
        scans: u64,
    ) -> Vec<(Detection, DetectionTruth)> {
        let r = SimRadarConfig {
            multipath_probability: p,
            ..radar()
        };
        let motion = RadarMotion::new(Vec2::zeros(), 0.0, 10.0, 0.0, &[0.0; 6]);
        let refl = Reflectivity {
            facade_density: 0.0,
            ..refl()
        };
        scan_all(world, &r, &motion, movers, &refl, scans)
            .into_iter()
            .filter(|(_, t)| t.kind == TargetKind::Ghost)
            .collect()
    }

    /// The measured range and azimuth of a noise-free detection at `p` (radar frame) with radial velocity
    /// `v_r`: the Doppler distortion `beta v_r` on the range.
    fn assert_measured_at(d: &Detection, p: Vec2, v_r: f64) {
        let beta = radar().beta;
        assert!((d.p_radar.xy().norm() - (p.norm() + beta * v_r)).abs() < 1e-9);
        assert!((d.p_radar.y.atan2(d.p_radar.x) - p.y.atan2(p.x)).abs() < 1e-9);
        assert!((d.v_r - v_r).abs() < 1e-9, "{} vs {v_r}", d.v_r);
    }

    /// A pole seen via a wall: with probability 1 each scan holds its ghost at the mirror image (30, 17),
    /// with the radial velocity of a static point there; with probability 0, or a wall that does not
    /// reach the specular point (x = 17.6), none.
    #[test]
    fn a_wall_mirrors_a_pole_into_a_ghost() {
        let w = mirror_world((0.0, 80.0));
        let image = Vec2::new(30.0, 17.0);
        let static_v_r = -image.normalize().dot(&Vec2::new(10.0, 0.0));
        let g = ghosts(&w, 1.0, &[], 20);
        assert_eq!(g.len(), 20);
        for (d, t) in &g {
            assert_eq!(t.object, 0);
            assert!((t.p_radar.xy() - image).norm() < 1e-9);
            assert_measured_at(d, image, static_v_r);
        }
        assert!(ghosts(&w, 0.0, &[], 50).is_empty());
        assert!(ghosts(&mirror_world((20.0, 80.0)), 1.0, &[], 50).is_empty());
    }

    /// A pedestrian at (30, 3) walking at (1, 2) m/s has a ghost walking at (1, -2) m/s, its mirror image.
    #[test]
    fn a_moving_reflector_has_a_ghost_moving_as_its_mirror_image() {
        let mut w = mirror_world((0.0, 80.0));
        w.scatterers.clear();
        let walker = MoverState {
            mover: crate::sim::world::Mover {
                kind: TargetKind::Pedestrian,
                s0: 0.0,
                rate: 0.0,
                offset: 0.0,
                length: 0.5,
                width: 0.5,
                rcs: 30.0,
                id: 5,
            },
            body: crate::sim::world::CarBox {
                center: Vec2::new(30.0, 3.0),
                heading: 0.0,
                length: 0.5,
                width: 0.5,
                lap: None,
                id: 5,
            },
            velocity: Vec2::new(1.0, 2.0),
            yaw_rate: 0.0,
        };
        let image = Vec2::new(30.0, 17.0);
        let v_r = image
            .normalize()
            .dot(&(Vec2::new(1.0, -2.0) - Vec2::new(10.0, 0.0)));
        let g = ghosts(&w, 1.0, &[walker], 10);
        assert_eq!(g.len(), 10);
        for (d, t) in &g {
            assert_eq!(t.object, 5);
            assert_measured_at(d, image, v_r);
        }
    }

    /// A radar 0.5 m up that measures elevation (+-14 deg) before a wall 10 m ahead: every wall return
    /// lies within the wall's 8 m and the field of view, so nothing above 10 tan(14 deg) = 2.5 m over
    /// the radar; the returns spread over that height; the road returns lie on the ground, in front of
    /// the wall (within the occlusion tolerance of 0.3 m), within `ground_range`.
    #[test]
    fn an_elevation_radar_sees_a_wall_at_its_heights_and_the_road_before_it() {
        let fov = 14f64.to_radians();
        let r = SimRadarConfig {
            extrinsic: [0.0, 0.0, 0.5, 0.0, 0.0, 0.0],
            elevation_fov: fov,
            elevation_noise: 0.0,
            ground_rate: 50.0,
            ..radar()
        };
        let mut w = empty_world();
        w.walls.push(wall((10.0, -30.0), (10.0, 30.0), 1));
        let motion = RadarMotion::new(Vec2::zeros(), 0.0, 0.0, 0.0, &r.extrinsic);
        let seen = scan_all(&w, &r, &motion, &[], &refl(), 20);
        let wall: Vec<&DetectionTruth> = seen
            .iter()
            .map(|(_, t)| t)
            .filter(|t| t.object == 1)
            .collect();
        assert!(wall.len() > 100, "{} wall returns", wall.len());
        for t in &wall {
            let (z, h) = (t.p_radar.z, t.p_radar.xy().norm());
            assert!((-0.5 - 1e-9..=7.5 + 1e-9).contains(&z), "z {z}");
            assert!(z.atan2(h).abs() <= fov + 1e-9, "z {z} at {h} m");
        }
        assert!(wall.iter().any(|t| t.p_radar.z > 2.0));
        assert!(wall.iter().any(|t| t.p_radar.z < 0.0));
        let road: Vec<&DetectionTruth> = seen
            .iter()
            .map(|(_, t)| t)
            .filter(|t| t.kind == TargetKind::Ground)
            .collect();
        assert!(road.len() > 200, "{} road returns", road.len());
        for t in &road {
            assert!((t.p_radar.z + 0.5).abs() < 1e-9, "z {}", t.p_radar.z);
            assert!(
                t.p_radar.x < 10.3 && t.p_radar.xy().norm() <= r.ground_range,
                "{:?}",
                t.p_radar
            );
        }
        // The measured points carry the elevation too: z = r sin(e).
        for (d, t) in &seen {
            assert!((d.p_radar - t.p_radar).norm() < 1e-9 + r.beta * t.v_r.abs());
        }
    }

    /// Lever arm: a radar 3 m ahead of the body turning at 0.5 rad/s moves sideways at 1.5 m/s.
    #[test]
    fn radar_velocity_includes_the_lever_arm() {
        let m = RadarMotion::new(
            Vec2::new(1.0, 2.0),
            0.5 * std::f64::consts::PI,
            10.0,
            0.5,
            &[3.0, 0.0, 0.5, 0.0, 0.0, 0.3],
        );
        assert!((m.position - Vec2::new(1.0, 5.0)).norm() < 1e-12);
        assert!((m.velocity - Vec2::new(-1.5, 10.0)).norm() < 1e-12);
        assert!((m.heading - (0.5 * std::f64::consts::PI + 0.3)).abs() < 1e-15);
    }
}
