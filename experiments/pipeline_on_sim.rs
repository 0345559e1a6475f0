//! Scratch: the pipeline over the default simulated drive, closures against ground truth.
use dc_loc::math::{iso2_from_iso3, wrap_angle};
use dc_loc::pipeline::{Event, Pipeline};
use dc_loc::sim::inputs::{ScanEncoding, SimInputs};
use dc_loc::sim::{SimConfig, simulate};
use std::time::Instant;

fn main() {
    let mut cfg = SimConfig::default();
    if std::env::args().any(|a| a == "--perfect") {
        cfg.odometry = dc_loc::sim::config::OdometrySimConfig::perfect();
    }
    if std::env::args().any(|a| a == "--nonoise") {
        cfg.noise.model = dc_loc::sim::NoiseModel::None;
    }
    let t0 = Instant::now();
    let drive = simulate(&cfg).unwrap();
    println!("sim {:.2} s", t0.elapsed().as_secs_f64());
    let mut p = Pipeline::new(drive.to_config()).unwrap();
    let t0 = Instant::now();
    let mut closures = Vec::new();
    for input in SimInputs::new(&drive, ScanEncoding::Detections).flatten() {
        let out = p.push(&input);
        for e in out {
            if let Event::Closure(c) = e {
                let q = drive.state_at(c.query_stamp).t_map_body;
                let m = drive.state_at(c.match_stamp).t_map_body;
                let truth = m.inverse() * q;
                let est = iso2_from_iso3(&c.t_match_query);
                println!(
                    "closure {} -> {}: err {:.2} m, truth dist {:.1} m, inliers {} overlap {:.2}",
                    c.query_id,
                    c.match_id,
                    (truth.translation.vector - est.translation.vector).norm(),
                    truth.translation.vector.norm(),
                    c.inliers,
                    c.score
                );
                closures.push(*c);
            }
        }
    }
    println!(
        "pipeline {:.2} s, {:?}",
        t0.elapsed().as_secs_f64(),
        p.stats()
    );
    let mut errs: Vec<(f64, f64, u32, f64)> = Vec::new();
    let mut bad = 0;
    let (mut st, mut sr) = (0.0, 0.0);
    for c in &closures {
        let q = drive.state_at(c.query_stamp).t_map_body;
        let m = drive.state_at(c.match_stamp).t_map_body;
        let truth = m.inverse() * q;
        let est = iso2_from_iso3(&c.t_match_query);
        let et = (truth.translation.vector - est.translation.vector).norm();
        let er = wrap_angle(truth.rotation.angle() - est.rotation.angle()).abs();
        errs.push((et, er, c.inliers, c.covariance[(0, 0)].sqrt()));
        st += et;
        sr += er;
        if et > 1.0 {
            bad += 1;
        }
    }
    errs.sort_by(|a, b| a.0.total_cmp(&b.0));
    for q in [0.1, 0.25, 0.5, 0.75, 0.9, 0.95, 1.0] {
        let i = ((errs.len() as f64 - 1.0) * q) as usize;
        if let Some(e) = errs.get(i) {
            println!(
                "q{q}: t {:.3} r {:.4} inliers {} sx {:.3}",
                e.0, e.1, e.2, e.3
            );
        }
    }
    let n = closures.len().max(1) as f64;
    println!(
        "closures {} bad {} mean t {:.3} m mean r {:.4} rad",
        closures.len(),
        bad,
        st / n,
        sr / n
    );
}
