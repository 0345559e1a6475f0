//! Scratch: one revisit registration of a revisit scenario, with its RANSAC hypotheses against the
//! truth. `one_pair nuscenes|carla gaussian|gamma|student-t DRIFT same|reverse QUERY MATCH`
use dc_loc::eval::revisits::{RevisitScenario, feed};
use dc_loc::math::{Iso2, wrap_angle};
use dc_loc::pipeline::Pipeline;
use dc_loc::registration::{PreparedSubmap, dense, ransac, register_detailed};
use dc_loc::sim::{NoiseModel, RadarPreset, simulate};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let sc = RevisitScenario::new(
        if a[1] == "carla" {
            RadarPreset::Carla
        } else {
            RadarPreset::Nuscenes
        },
        match a[2].as_str() {
            "gamma" => NoiseModel::Gamma,
            "student-t" => NoiseModel::StudentT,
            _ => NoiseModel::Gaussian,
        },
        a[3].parse::<f64>().unwrap() / 100.0,
        a[4] == "reverse",
    );
    let (qid, mid): (u64, u64) = (a[5].parse().unwrap(), a[6].parse().unwrap());
    let drive = simulate(&sc.sim_config()).unwrap();
    let mut c = drive.to_config();
    c.r#loop.enabled = false;
    let mut p = Pipeline::new(c.clone()).unwrap();
    feed(&drive, &mut p, |_| {});
    let q = p.db().get(qid).unwrap().clone();
    let m = p.db().get(mid).unwrap().clone();
    let truth = drive.state_at(m.stamp).t_map_body.inverse() * drive.state_at(q.stamp).t_map_body;
    let rcfg = c.registration.clone();
    let s = PreparedSubmap::new(q.point_set(), &rcfg).unwrap();
    let g = PreparedSubmap::new(m.point_set(), &rcfg).unwrap();
    let err = |e: &Iso2| (e.translation.vector - truth.translation.vector).norm();
    let d = register_detailed(&s, &g, &rcfg).unwrap();
    println!(
        "result err {:.2} overlap {:.3} runner-up {:.3} inliers {} cov-std {:.3}",
        err(&d.result.t_target_source),
        d.result.overlap,
        d.result.runner_up_overlap,
        d.result.inliers,
        d.covariance_se2[(0, 0)]
            .max(d.covariance_se2[(1, 1)])
            .sqrt()
    );
    // The RANSAC motions the registration screened, from its own descriptor candidates.
    let distinct = ransac::Distinct {
        keep: rcfg.screened_hypotheses,
        translation: ransac::AMBIGUITY_TRANSLATION,
        rotation: ransac::AMBIGUITY_ROTATION,
        min_support: rcfg.min_inliers,
    };
    let hs = ransac::ransac_hypotheses(
        s.points(),
        g.points(),
        &d.candidates,
        &rcfg.ransac,
        &distinct,
    )
    .unwrap();
    let (src, _) = dense::prepare(s.points(), &rcfg.dense).unwrap();
    let (tgt, tt) = dense::prepare(g.points(), &rcfg.dense).unwrap();
    let cov = dense::Coverage::new(&tgt.points, 1.0);
    let probes = dense::probes(&src, 256);
    println!(
        "truth: coverage {} overlap {}",
        cov.count(&probes, &truth),
        dense::associate(&src, &tgt, &tt, &truth, &rcfg.dense).len()
    );
    for h in &hs {
        let e = h.t_target_source.translation.vector - truth.translation.vector;
        println!(
            "  support {:3} coverage {:3} overlap {:4} err {:6.2} ({:6.2} {:6.2}) rot {:7.4}",
            h.inliers.len(),
            cov.count(&probes, &h.t_target_source),
            dense::associate(&src, &tgt, &tt, &h.t_target_source, &rcfg.dense).len(),
            err(&h.t_target_source),
            e.x,
            e.y,
            wrap_angle(h.t_target_source.rotation.angle() - truth.rotation.angle())
        );
    }
}
