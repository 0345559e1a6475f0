//! Synthetic radar submaps for the registration tests, the variant study (examples) and the bench.
//!
//! Test support, deliberately outside the library so that the truth it produces is independent of the
//! code under test. Included by path (`#[path = ".../tests/support/radar_scene.rs"] mod radar_scene;`).
//!
//! World: persistent point reflectors within `radius` of the origin, the way an automotive radar sees
//! an urban street: building facades and fences (reflectors every 1.5-4 m along random segments),
//! poles and signs (isolated reflectors), parked cars (clusters of 3-6 within 2 m).
//! A view (one submap) of the world from a sensor pose: each reflector within range (and field of
//! view) is detected with a probability, its position perturbed by its own covariance (the polar model
//! of docs/algorithm.md (per-point covariance): sigma_r, sigma_phi, sigma_v, beta, `Sigma = J diag(sr^2, sv^2, sphi^2) J^T`
//! at its range and azimuth from the submap origin), and clutter (false alarms, no identity) is added.
#![allow(dead_code)]

use dc_loc::math::{Iso2, Mat2, Vec2};
use dc_loc::registration::PointSet2;
use rand::RngExt;
use rand::rngs::StdRng;
use rand_distr::StandardNormal;

/// Polar measurement noise (the paper's CARLA Gaussian setting by default).
#[derive(Debug, Clone, Copy)]
pub struct Noise {
    /// Range, m.
    pub sigma_r: f64,
    /// Azimuth, rad.
    pub sigma_phi: f64,
    /// Radial velocity, m/s.
    pub sigma_v: f64,
    /// Doppler-range coupling, s.
    pub beta: f64,
}

impl Default for Noise {
    fn default() -> Self {
        Noise {
            sigma_r: 0.25,
            sigma_phi: 0.5_f64.to_radians(),
            sigma_v: 0.1,
            beta: 0.04,
        }
    }
}

impl Noise {
    /// Covariance of a static point at `p` (sensor frame): `J Sigma_p J^T` with J of eq. (8), v = 0.
    pub fn cov_at(&self, p: &Vec2) -> Mat2 {
        let r = p.norm().max(1e-3);
        let (c, s) = (p.x / r, p.y / r);
        // Columns of J: d/dr, d/dv, d/dphi.
        let jr = Vec2::new(c, s);
        let jv = Vec2::new(-self.beta * c, -self.beta * s);
        let jphi = Vec2::new(-r * s, r * c);
        jr * jr.transpose() * self.sigma_r.powi(2)
            + jv * jv.transpose() * self.sigma_v.powi(2)
            + jphi * jphi.transpose() * self.sigma_phi.powi(2)
    }
}

/// A sample of N(0, cov).
pub fn gaussian2(rng: &mut StdRng, cov: &Mat2) -> Vec2 {
    let l = cov.cholesky().map(|c| c.l()).unwrap_or_else(Mat2::zeros);
    let z = Vec2::new(rng.sample(StandardNormal), rng.sample(StandardNormal));
    l * z
}

/// The world: persistent reflectors, world frame.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Reflector positions, m.
    pub reflectors: Vec<Vec2>,
}

/// Builds a random street-like scene with about `n` reflectors within `radius` m of the origin.
pub fn random_scene(rng: &mut StdRng, n: usize, radius: f64) -> Scene {
    let mut refl = Vec::with_capacity(n + 64);
    let in_disk = |p: &Vec2| p.norm() <= radius;
    let uniform_disk = |rng: &mut StdRng| loop {
        let p = Vec2::new(
            rng.random_range(-radius..radius),
            rng.random_range(-radius..radius),
        );
        if in_disk(&p) {
            break p;
        }
    };
    // About 60 % on facades, 25 % in car clusters, 15 % poles.
    let n_wall = (0.6 * n as f64) as usize;
    let n_cars = (0.25 * n as f64) as usize;
    while refl.len() < n_wall {
        let c = uniform_disk(rng);
        let dir = rng.random_range(0.0..std::f64::consts::PI);
        let u = Vec2::new(dir.cos(), dir.sin());
        let len = rng.random_range(10.0..60.0);
        let mut s = -0.5 * len;
        while s < 0.5 * len && refl.len() < n_wall {
            let p = c + u * s + Vec2::new(-u.y, u.x) * rng.random_range(-0.1..0.1);
            if in_disk(&p) {
                refl.push(p);
            }
            s += rng.random_range(1.5..4.0);
        }
    }
    while refl.len() < n_wall + n_cars {
        let c = uniform_disk(rng);
        for _ in 0..rng.random_range(3..=6) {
            let p = c + Vec2::new(rng.random_range(-2.0..2.0), rng.random_range(-1.0..1.0));
            if in_disk(&p) {
                refl.push(p);
            }
        }
    }
    while refl.len() < n {
        refl.push(uniform_disk(rng));
    }
    Scene { reflectors: refl }
}

/// How one submap sees the world.
#[derive(Debug, Clone, Copy)]
pub struct View {
    /// Submap (sensor) frame in the world.
    pub t_world_sensor: Iso2,
    /// Maximum range, m.
    pub max_range: f64,
    /// Half field of view about the x axis, rad (pi = all around, as several radars stacked).
    pub half_fov: f64,
    /// Detection probability of a reflector in view.
    pub p_detect: f64,
    /// False alarms, as a share of the detections (uniform in the field of view).
    pub clutter_ratio: f64,
    /// Scans stacked into the submap: each reflector can be detected once per scan, each detection
    /// with its own noise (a submap is 10 stacked scans in the paper).
    pub sweeps: usize,
}

impl View {
    /// All-round view from `t_world_sensor` out to 100 m, every reflector detected, no clutter.
    pub fn all(t_world_sensor: Iso2) -> Self {
        View {
            t_world_sensor,
            max_range: 100.0,
            half_fov: std::f64::consts::PI,
            p_detect: 1.0,
            clutter_ratio: 0.0,
            sweeps: 1,
        }
    }
}

/// One observed submap: the point set and, per point, the reflector it came from (None = clutter).
#[derive(Debug, Clone)]
pub struct Observed {
    /// Points and covariances in the sensor frame.
    pub set: PointSet2,
    /// Reflector index per point.
    pub ids: Vec<Option<usize>>,
}

/// Observes `scene` from `view` with `noise`.
pub fn observe(rng: &mut StdRng, scene: &Scene, view: &View, noise: &Noise) -> Observed {
    let inv = view.t_world_sensor.inverse();
    let mut set = PointSet2::default();
    let mut ids = Vec::new();
    let visible = |p: &Vec2| {
        let r = p.norm();
        r > 1.0 && r <= view.max_range && p.y.atan2(p.x).abs() <= view.half_fov
    };
    for (k, w) in scene.reflectors.iter().enumerate() {
        let p = (inv * nalgebra::Point2::from(*w)).coords;
        if !visible(&p) {
            continue;
        }
        for _ in 0..view.sweeps.max(1) {
            if rng.random::<f64>() >= view.p_detect {
                continue;
            }
            let noisy = p + gaussian2(rng, &noise.cov_at(&p));
            set.covs.push(noise.cov_at(&noisy));
            set.points.push(noisy);
            ids.push(Some(k));
        }
    }
    let n_clutter = (view.clutter_ratio * set.len() as f64).round() as usize;
    let mut added = 0;
    while added < n_clutter {
        let r = view.max_range * rng.random::<f64>().sqrt();
        let phi = rng.random_range(-view.half_fov..view.half_fov);
        let p = Vec2::new(r * phi.cos(), r * phi.sin());
        if !visible(&p) {
            continue;
        }
        set.covs.push(noise.cov_at(&p));
        set.points.push(p);
        ids.push(None);
        added += 1;
    }
    Observed { set, ids }
}

/// A pair of submaps and its truth.
#[derive(Debug, Clone)]
pub struct Pair {
    /// Current submap X.
    pub source: Observed,
    /// Previous submap Y.
    pub target: Observed,
    /// True source frame in the target frame.
    pub t_target_source: Iso2,
}

impl Pair {
    /// True correspondences (source index, target index): same reflector (the first target
    /// detection of it when there are several).
    pub fn truth_pairs(&self) -> Vec<(usize, usize)> {
        let mut by_id = std::collections::HashMap::new();
        for (j, id) in self.target.ids.iter().enumerate() {
            if let Some(id) = id {
                by_id.entry(*id).or_insert(j);
            }
        }
        self.source
            .ids
            .iter()
            .enumerate()
            .filter_map(|(i, id)| id.and_then(|id| by_id.get(&id).map(|&j| (i, j))))
            .collect()
    }
}

/// A random motion: yaw uniform in [-pi, pi), translation uniform in [-max_t, max_t]^2.
pub fn random_motion(rng: &mut StdRng, max_t: f64) -> Iso2 {
    Iso2::new(
        Vec2::new(
            rng.random_range(-max_t..max_t),
            rng.random_range(-max_t..max_t),
        ),
        rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
    )
}

/// The same reflectors seen from the target origin and from `t_target_source`: every reflector in
/// both (1:1, index i in both sets), each observation perturbed independently by its own covariance.
pub fn same_points_pair(
    rng: &mut StdRng,
    scene: &Scene,
    t_target_source: Iso2,
    noise: &Noise,
) -> Pair {
    // Only reflectors that both views can see (more than 1 m from both origins), so that the
    // two point lists correspond index by index.
    let inv = t_target_source.inverse();
    let scene = Scene {
        reflectors: scene
            .reflectors
            .iter()
            .copied()
            .filter(|w| w.norm() > 1.0 && (inv * nalgebra::Point2::from(*w)).coords.norm() > 1.0)
            .collect(),
    };
    let all = |t: Iso2, rng: &mut StdRng| {
        let mut v = View::all(t);
        v.max_range = f64::INFINITY;
        observe(rng, &scene, &v, noise)
    };
    let target = all(Iso2::identity(), rng);
    let source = all(t_target_source, rng);
    Pair {
        source,
        target,
        t_target_source,
    }
}

/// Two independent views of `scene`: the target from the origin, the source from `t_target_source`,
/// each with its own detections and clutter (partial overlap through range, field of view and
/// detection probability).
pub fn independent_pair(
    rng: &mut StdRng,
    scene: &Scene,
    t_target_source: Iso2,
    target_view: View,
    source_view: View,
    noise: &Noise,
) -> Pair {
    let target = observe(
        rng,
        scene,
        &View {
            t_world_sensor: Iso2::identity(),
            ..target_view
        },
        noise,
    );
    let source = observe(
        rng,
        scene,
        &View {
            t_world_sensor: t_target_source,
            ..source_view
        },
        noise,
    );
    Pair {
        source,
        target,
        t_target_source,
    }
}

/// True when source point `i` and target point `j` come from the same reflector.
pub fn same_reflector(pair: &Pair, i: usize, j: usize) -> bool {
    matches!((pair.source.ids.get(i), pair.target.ids.get(j)), (Some(Some(a)), Some(Some(b))) if a == b)
}

/// Translation error (m) and absolute rotation error (rad) of an estimate.
pub fn pose_error(est: &Iso2, truth: &Iso2) -> (f64, f64) {
    let e = est.inverse() * truth;
    (e.translation.vector.norm(), e.rotation.angle().abs())
}
