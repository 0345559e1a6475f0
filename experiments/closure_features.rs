//! Scratch: features of judged closures (from `dc_loc revisits --closures-out`), true against false:
//! relative yaw, common view (`loop.minimum_common_view`), overlap, the slid alternatives' overlap and its ratio (`loop.maximum_slide_ratio`), runner-up,
//! inliers, point overlap within 0.75 m at the result and slid by 5-20 m without refinement, and the
//! translation standard deviations.
//! `closure_features FILE "carla gaussian 3% same" [EVERY]` (every EVERY-th true closure, all false ones).
use dc_loc::eval::revisits::{RevisitScenario, feed};
use dc_loc::math::Vec2;
use dc_loc::pipeline::Pipeline;
use dc_loc::registration::{PreparedSubmap, common_view, register_detailed, slide_overlap};
use dc_loc::sim::{NoiseModel, RadarPreset, simulate};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let label = &a[2];
    let w: Vec<&str> = label.split_whitespace().collect();
    let sc = RevisitScenario::new(
        if w[0] == "carla" {
            RadarPreset::Carla
        } else {
            RadarPreset::Nuscenes
        },
        match w[1] {
            "gamma" => NoiseModel::Gamma,
            "student-t" => NoiseModel::StudentT,
            _ => NoiseModel::Gaussian,
        },
        w[2].trim_end_matches('%').parse::<f64>().unwrap() / 100.0,
        w[3] == "reverse",
    );
    let drive = simulate(&sc.sim_config()).unwrap();
    let mut c = drive.to_config();
    c.r#loop.enabled = false;
    let mut p = Pipeline::new(c.clone()).unwrap();
    feed(&drive, &mut p, |_| {});
    let rcfg = c.registration.clone();
    let db = p.db();
    let text = std::fs::read_to_string(&a[1]).unwrap();
    let every: usize = a.get(3).map_or(1, |s| s.parse().unwrap());
    let mut k = 0;
    for line in text.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        if v["scenario"].as_str() != Some(label.as_str()) {
            continue;
        }
        let cl = &v["closure"];
        let err = cl["translation_error"].as_f64().unwrap();
        let bad = err > 2.0;
        k += 1;
        if !bad && k % every != 0 {
            continue;
        }
        let (q, m) = (
            cl["query_id"].as_u64().unwrap(),
            cl["match_id"].as_u64().unwrap(),
        );
        let sp = db.get(q).unwrap().point_set();
        let tp = db.get(m).unwrap().point_set();
        let s = PreparedSubmap::new(sp.clone(), &rcfg).unwrap();
        let g = PreparedSubmap::new(tp.clone(), &rcfg).unwrap();
        let d = register_detailed(&s, &g, &rcfg).unwrap();
        let t = d.result.t_target_source;
        let near = |x: Vec2, r: f64| tp.points.iter().any(|y| (x - y).norm() < r);
        let distinct = |i: usize| {
            let x = sp.points[i];
            let nb: Vec<Vec2> = sp
                .points
                .iter()
                .filter(|y| (x - **y).norm() < 2.0)
                .copied()
                .collect();
            if nb.len() < 3 {
                return true;
            }
            let mean = nb.iter().fold(Vec2::zeros(), |a, y| a + y) / nb.len() as f64;
            let s = nb.iter().fold(nalgebra::Matrix2::<f64>::zeros(), |a, y| {
                a + (y - mean) * (y - mean).transpose()
            });
            let e = s.symmetric_eigenvalues();
            e.min() / e.max().max(1e-12) > 0.05
        };
        let dir = t.rotation * Vec2::new(1.0, 0.0);
        let iso = |shift: f64, only: bool| {
            let (mut n, mut hit) = (0, 0);
            for (i, x) in sp.points.iter().enumerate() {
                if only && !distinct(i) {
                    continue;
                }
                n += 1;
                let y = (t * nalgebra::Point2::from(*x)).coords + dir * shift;
                if near(y, 0.75) {
                    hit += 1;
                }
            }
            (hit as f64 / n.max(1) as f64, n)
        };
        let (i0, _) = iso(0.0, false);
        let (d0, nd) = iso(0.0, true);
        let slide = [-20.0, -10.0, -5.0, 5.0, 10.0, 20.0]
            .iter()
            .map(|&s| iso(s, false).0)
            .fold(0.0, f64::max);
        let dslide = [-20.0, -10.0, -5.0, 5.0, 10.0, 20.0]
            .iter()
            .map(|&s| iso(s, true).0)
            .fold(0.0, f64::max);
        let alt = slide_overlap(&s, &g, &t, &rcfg, f64::INFINITY).unwrap();
        let view = common_view(&s, &g, &t);
        let cov = d.covariance_se2;
        let e = cov.fixed_view::<2, 2>(0, 0).symmetric_eigenvalues();
        println!(
            "{} {q:4}->{m:4} err {err:7.2} yaw {:5.2} view {view:.2} ov {:.2} alt {alt:.2} ratio {:.2} ru {:.2} inl {:3} | iso {i0:.2} slide {slide:.2} | distinct {d0:.2} (n {nd:3}) slide {dslide:.2} | std {:.3} {:.3} n {} {}",
            if bad { "FALSE" } else { "true " },
            t.rotation.angle(),
            d.result.overlap,
            alt / d.result.overlap,
            d.result.runner_up_overlap,
            d.result.inliers,
            e.max().sqrt(),
            e.min().sqrt(),
            sp.len(),
            tp.len()
        );
    }
}
