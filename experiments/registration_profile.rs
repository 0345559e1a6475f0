//! Per-step time of the registration pipeline on synthetic pairs (single thread).
//!
//! `cargo run --release --example registration_profile [points] [repetitions]` (default 1000, 100);
//! `MAXSRC=n` sets `registration.dense.max_source_points`.
//! Each step is repeated on the same pairs and timed by the wall clock (run it on an idle machine).
#[path = "../tests/support/radar_scene.rs"]
mod radar_scene;
use dc_loc::registration::*;
use radar_scene::*;
use rand::SeedableRng;
use rand::rngs::StdRng;

/// Mean wall-clock time of `reps` runs of `f`, ms, and its last result. Run it on an idle machine:
/// the thread CPU time in /proc ticks at 10 ms, too coarse for steps of a fraction of a millisecond.
fn timed<R>(reps: usize, mut f: impl FnMut() -> R) -> (R, f64) {
    let t0 = std::time::Instant::now();
    let mut r = f();
    for _ in 1..reps {
        r = f();
    }
    (r, t0.elapsed().as_secs_f64() / reps as f64 * 1e3)
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
    let mut cfg = RegistrationConfig::default();
    if let Some(m) = std::env::var("MAXSRC").ok().and_then(|v| v.parse().ok()) {
        cfg.dense.max_source_points = m;
    }
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
        let (full, t_reg) = timed(reps, || register_prepared(&s, &g, &cfg).unwrap());
        let (fe, fr) = pose_error(&full.t_target_source, &t);
        eprintln!("full pipeline error {fe:.4} m {fr:.5} rad");
        let (_, t_tree) = timed(reps, || dense::target_tree(s.points()).unwrap());
        let tree = dense::target_tree(s.points()).unwrap();
        let (_, t_surf) = timed(reps, || {
            dense::with_surface_covariances(s.points(), &tree, &cfg.dense)
        });
        let (_, t_dsc) = timed(reps, || {
            let kp = descriptor::keypoint_indices(s.points().len(), &cfg.descriptor);
            descriptor::compute_descriptors(&s.points().points, &kp, &cfg.descriptor).unwrap()
        });
        eprintln!(
            "register_prepared {t_reg:.2} tree {t_tree:.2} surface {t_surf:.2} descriptors(one) {t_dsc:.2}"
        );
        let (_, t_all) = timed(reps, || {
            let s = PreparedSubmap::new(pair.source.set.clone(), &cfg).unwrap();
            let g = PreparedSubmap::new(pair.target.set.clone(), &cfg).unwrap();
            register_prepared(&s, &g, &cfg).unwrap()
        });
        let (te, re) = pose_error(&lm.t_target_source, &t);
        println!(
            "n {} / {} cands {} inl {} draws {} err {:.3} m {:.4} rad | ms: describe {:.2} match {:.2} ransac {:.2} lm {:.2} all {:.2}",
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
        "mean ms: describe(both) {:.2} match {:.2} ransac {:.2} lm {:.2} | whole pipeline {:.2}",
        tot[0], tot[1], tot[2], tot[3], tot[4]
    );
}
