//! Per-step CPU time of the registration pipeline on synthetic pairs (single thread).
//!
//! `cargo run --release --example registration_profile [points] [repetitions]` (default 1000, 100).
//! Each step is repeated on the same pairs and timed by the thread's CPU time from /proc (Linux),
//! which a loaded machine does not inflate the way it inflates the wall clock.
#[path = "../tests/support/radar_scene.rs"]
mod radar_scene;
use dc_loc::registration::*;
use radar_scene::*;
use rand::SeedableRng;
use rand::rngs::StdRng;

/// Thread CPU time (user + system), s, from /proc/thread-self/stat (10 ms ticks).
fn cpu_s() -> f64 {
    let s = std::fs::read_to_string("/proc/thread-self/stat").unwrap_or_default();
    let rest = s.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

fn timed<R>(reps: usize, mut f: impl FnMut() -> R) -> (R, f64) {
    let t0 = cpu_s();
    let mut r = f();
    for _ in 1..reps {
        r = f();
    }
    (r, (cpu_s() - t0) / reps as f64 * 1e3)
}

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(1000);
    let reps: usize = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(100);
    let cfg = RegistrationConfig::default();
    let mut rng = StdRng::seed_from_u64(1);
    let v = View {
        t_world_sensor: dc_loc::math::Iso2::identity(),
        max_range: 100.0,
        half_fov: std::f64::consts::PI,
        p_detect: if n > 2000 { 0.9 } else { 0.5 },
        clutter_ratio: 0.2,
        sweeps: 10,
    };
    let mut tot = [0.0f64; 5];
    let pairs = 4;
    for _ in 0..pairs {
        // About n points per submap: 10 scans, p_d as above, 20 % clutter, 75 % of the reflectors in range.
        let per_reflector = 10.0 * if n > 2000 { 0.9 } else { 0.5 } * 1.2 * 0.76;
        let scene = random_scene(&mut rng, (n as f64 / per_reflector) as usize, 115.0);
        let t = random_motion(&mut rng, 10.0);
        let pair = independent_pair(&mut rng, &scene, t, v, v, &Noise::default());
        let ((s, g), t_desc) = timed(reps, || {
            (
                PreparedSubmap::new(pair.source.set.clone(), &cfg).unwrap(),
                PreparedSubmap::new(pair.target.set.clone(), &cfg).unwrap(),
            )
        });
        let q = matching::select_queries(
            s.keypoints().len(),
            cfg.matching.max_queries,
            cfg.ransac.seed,
        );
        let (mut cands, t_match) = timed(reps, || {
            matching::match_descriptors(s.descriptors(), &q, g.index(), &cfg.matching)
        });
        for c in &mut cands {
            c.source = s.keypoints()[c.source as usize];
            c.target = g.keypoints()[c.target as usize];
        }
        let (rs, t_ransac) = timed(reps, || {
            ransac::ransac(s.points(), g.points(), &cands, &cfg.ransac).unwrap()
        });
        let pairs_: Vec<(usize, usize)> = rs
            .inliers
            .iter()
            .map(|&k| (cands[k].source as usize, cands[k].target as usize))
            .collect();
        let (lm, t_lm) = timed(reps, || {
            lm::refine(
                s.points(),
                g.points(),
                &pairs_,
                &rs.t_target_source,
                &cfg.lm,
            )
            .unwrap()
        });
        let (_, t_all) = timed(reps, || {
            let s = PreparedSubmap::new(pair.source.set.clone(), &cfg).unwrap();
            let g = PreparedSubmap::new(pair.target.set.clone(), &cfg).unwrap();
            register_prepared(&s, &g, &cfg).unwrap()
        });
        let (te, re) = pose_error(&lm.t_target_source, &t);
        println!(
            "n {} / {} cands {} inl {} draws {} err {:.3} m {:.4} rad | cpu ms: describe {:.2} match {:.2} ransac {:.2} lm {:.2} all {:.2}",
            s.points().len(),
            g.points().len(),
            cands.len(),
            rs.inliers.len(),
            rs.iterations,
            te,
            re,
            t_desc,
            t_match,
            t_ransac,
            t_lm,
            t_all
        );
        for (a, b) in tot.iter_mut().zip([t_desc, t_match, t_ransac, t_lm, t_all]) {
            *a += b / pairs as f64;
        }
    }
    println!(
        "mean cpu ms: describe(both) {:.2} match {:.2} ransac {:.2} lm {:.2} | whole pipeline {:.2}",
        tot[0], tot[1], tot[2], tot[3], tot[4]
    );
}
