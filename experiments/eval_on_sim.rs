//! Scratch: the evaluation protocol on a simulated drive, in memory.
use dc_loc::eval::{Collector, EvalConfig, Method, evaluate, make_pairs, report};
use dc_loc::sim::inputs::{ScanEncoding, SimInputs};
use dc_loc::sim::{SimConfig, simulate};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mut cfg = SimConfig::default();
    if args.iter().any(|a| a == "--nonoise") {
        cfg.noise.model = dc_loc::sim::NoiseModel::None;
    }
    if args.iter().any(|a| a == "--gamma") {
        cfg.noise.model = dc_loc::sim::NoiseModel::Gamma;
    }
    if args.iter().any(|a| a == "--student") {
        cfg.noise.model = dc_loc::sim::NoiseModel::StudentT;
    }
    let t0 = Instant::now();
    let drive = simulate(&cfg).unwrap();
    let mut pcfg = drive.to_config();
    for a in &args {
        if let Some(v) = a.strip_prefix("--min-inliers=") {
            pcfg.registration.min_inliers = v.parse().unwrap();
        }
        if let Some(v) = a.strip_prefix("--k=") {
            pcfg.registration.matching.k = v.parse().unwrap();
        }
        if let Some(v) = a.strip_prefix("--spread=") {
            pcfg.registration.min_inlier_spread = v.parse().unwrap();
        }
        if let Some(v) = a.strip_prefix("--keypoints=") {
            pcfg.registration.descriptor.max_keypoints = v.parse().unwrap();
            pcfg.registration.matching.max_queries = v.parse().unwrap();
        }
        if let Some(v) = a.strip_prefix("--radius=") {
            pcfg.registration.descriptor.radius = v.parse().unwrap();
        }
    }
    let ecfg = EvalConfig::default();
    let mut col = Collector::new(&pcfg, &ecfg).unwrap();
    for input in SimInputs::new(&drive, ScanEncoding::Clouds).flatten() {
        col.push(&input);
    }
    let (kfs, _) = col.finish();
    let pairs = make_pairs(&kfs, &ecfg);
    println!(
        "collect {:.1} s: {} keyframes, {} pairs",
        t0.elapsed().as_secs_f64(),
        kfs.len(),
        pairs.len()
    );
    let t0 = Instant::now();
    let methods = if args.iter().any(|a| a == "--only-dcloc") {
        vec![Method::DCLOC]
    } else {
        Method::all()
    };
    let res = evaluate(&kfs, &pairs, &methods, &pcfg.registration, &ecfg);
    println!("evaluate {:.1} s", t0.elapsed().as_secs_f64());
    let mut reasons = std::collections::BTreeMap::new();
    for r in res.iter().filter(|r| r.method == Method::DCLOC) {
        let key = match &r.failure {
            Some(f) => f.chars().take(70).collect::<String>(),
            None if r.translation_error > 2.0 => "wrong".to_string(),
            None => continue,
        };
        *reasons.entry(key).or_insert(0) += 1;
    }
    println!("DC-Loc failures: {reasons:?}");
    if args.iter().any(|a| a == "--overlap") {
        for r in res
            .iter()
            .filter(|r| r.method == Method::DCLOC && r.failure.is_none())
        {
            println!("OV {:.3} {:.3}", r.translation_error, r.overlap);
        }
    }
    if args.iter().any(|a| a == "--only-dcloc") {
        return;
    }
    let sums = report::summarize(&res, &methods, &ecfg);
    println!("{}", report::table_methods(&sums));
    println!("{}", report::table_ablation(&sums));
    println!("{}", report::table_velocity(&sums, &ecfg));
    report::plot_svg(&sums, &ecfg, std::path::Path::new("/tmp/eval.svg")).unwrap();
}

#[allow(dead_code)]
fn unused() {}
