//! Scratch: where DC-Loc's errors on the demo drive come from, pair by pair.
//!
//! `cargo run --release --example pair_floor [-- --nonoise] [--perfect-odom]`: on the default drive
//! (or without noise / with perfect odometry), for every evaluation pair (`dc_loc eval`'s), the dense
//! stage started at the true pose (mean / median translation error: the estimator's own accuracy),
//! and for the pairs DC-Loc gets wrong or fails, the descriptor candidates within 1 m of their partner
//! at the true pose (counted by source point) against the support of the best RANSAC motion.
use dc_loc::eval::{Collector, EvalConfig, make_pairs};
use dc_loc::registration::{PreparedSubmap, matching, overlap_near, ransac, register_detailed};
use dc_loc::sim::{NoiseModel, SimConfig, config::OdometrySimConfig, simulate};
use rayon::prelude::*;
use std::collections::HashSet;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mut cfg = SimConfig::default();
    if args.iter().any(|a| a == "--nonoise") {
        cfg.noise.model = NoiseModel::None;
    }
    if args.iter().any(|a| a == "--perfect-odom") {
        cfg.odometry = OdometrySimConfig::perfect();
    }
    let drive = simulate(&cfg).unwrap();
    let pcfg = drive.to_config();
    let ecfg = EvalConfig::default();
    let mut col = Collector::new(&pcfg, &ecfg).unwrap();
    col.push_sim_drive(&drive).unwrap();
    let (kfs, _) = col.finish();
    let pairs = make_pairs(&kfs, &ecfg);
    let rcfg = &pcfg.registration;
    // Per pair: error of the dense stage from the truth; for a wrong or failed DC-Loc result, the
    // true candidates and the best RANSAC support.
    let rows: Vec<(f64, Option<(usize, usize)>)> = pairs
        .par_iter()
        .map(|p| {
            let (q, t) = (&kfs[p.query], &kfs[p.target]);
            let truth = t.t_map_body.inverse() * q.t_map_body;
            let s = PreparedSubmap::new(q.submap.point_set(true), rcfg).unwrap();
            let g = PreparedSubmap::new(t.submap.point_set(true), rcfg).unwrap();
            let err =
                |e: &dc_loc::math::Iso2| (e.translation.vector - truth.translation.vector).norm();
            let from_truth = overlap_near(&s, &g, &truth, rcfg)
                .unwrap()
                .map_or(f64::INFINITY, |(e, _)| err(&e));
            let ok = register_detailed(&s, &g, rcfg)
                .is_ok_and(|d| err(&d.result.t_target_source) <= 2.0);
            if ok {
                return (from_truth, None);
            }
            let queries = matching::select_queries(
                s.keypoints().len(),
                rcfg.matching.max_queries,
                rcfg.ransac.seed,
            );
            let cands: Vec<_> =
                matching::match_descriptors(s.descriptors(), &queries, g.index(), &rcfg.matching)
                    .into_iter()
                    .map(|mut c| {
                        c.source = s.keypoints()[c.source as usize];
                        c.target = g.keypoints()[c.target as usize];
                        c
                    })
                    .collect();
            let true_sources: HashSet<u32> = cands
                .iter()
                .filter(|c| {
                    let x = s.points().points[c.source as usize];
                    let y = g.points().points[c.target as usize];
                    ((truth * nalgebra::Point2::from(x)).coords - y).norm() < 1.0
                })
                .map(|c| c.source)
                .collect();
            let best = ransac::ransac(s.points(), g.points(), &cands, &rcfg.ransac)
                .map_or(0, |r| r.inliers.len());
            (from_truth, Some((true_sources.len(), best)))
        })
        .collect();
    let mut from_truth: Vec<f64> = rows.iter().map(|r| r.0).filter(|e| e.is_finite()).collect();
    from_truth.sort_by(f64::total_cmp);
    println!(
        "{} pairs; dense stage from the true pose: mean {:.3} m, median {:.3} m",
        pairs.len(),
        from_truth.iter().sum::<f64>() / from_truth.len().max(1) as f64,
        from_truth[from_truth.len() / 2]
    );
    let mut bad: Vec<(usize, usize)> = rows.iter().filter_map(|r| r.1).collect();
    bad.sort();
    println!(
        "{} pairs wrong or failed; (true candidates by source point, best RANSAC support):",
        bad.len()
    );
    println!("{bad:?}");
}
