//! Scratch: how well revisit candidates and registration do at true revisits of the default drive.
use dc_loc::eval::revisits::feed;
use dc_loc::math::{iso2_from_iso3, wrap_angle};
use dc_loc::pipeline::Pipeline;
use dc_loc::registration::{PreparedSubmap, register_prepared};
use dc_loc::sim::{SimConfig, simulate};

fn main() {
    let cfg = SimConfig::default();
    let drive = simulate(&cfg).unwrap();
    let mut c = drive.to_config();
    c.r#loop.enabled = false;
    let mut p = Pipeline::new(c.clone()).unwrap();
    feed(&drive, &mut p, |_| {});
    let recs: Vec<_> = p.db().records().cloned().collect();
    let gt: Vec<_> = recs
        .iter()
        .map(|r| drive.state_at(r.stamp).t_map_body)
        .collect();
    let prep: Vec<_> = recs
        .iter()
        .map(|r| PreparedSubmap::new(r.point_set(), &c.registration).ok())
        .collect();
    let (mut n, mut ok, mut rank1, mut rank5, mut rank25) = (0, 0, 0, 0, 0);
    let mut errs = Vec::new();
    for q in 0..recs.len() {
        // True neighbour: nearest keyframe >= 100 m of path earlier within 5 m.
        let mut best: Option<(usize, f64)> = None;
        for m in 0..q {
            if recs[q].path_distance - recs[m].path_distance < 100.0 {
                continue;
            }
            let d = (gt[q].translation.vector - gt[m].translation.vector).norm();
            if d < 5.0 && best.is_none_or(|b| d < b.1) {
                best = Some((m, d));
            }
        }
        let Some((m, _)) = best else { continue };
        n += 1;
        let dm = recs[q].place.distance(&recs[m].place).0;
        let rank = (0..q)
            .filter(|&k| recs[q].path_distance - recs[k].path_distance >= 100.0)
            .filter(|&k| recs[q].place.distance(&recs[k].place).0 < dm)
            .count();
        rank1 += (rank < 1) as usize;
        rank5 += (rank < 5) as usize;
        rank25 += (rank < 25) as usize;
        let (Some(a), Some(b)) = (&prep[q], &prep[m]) else {
            continue;
        };
        if let Ok(r) = register_prepared(a, b, &c.registration) {
            let truth = gt[m].inverse() * gt[q];
            let e = (truth.translation.vector - r.t_target_source.translation.vector).norm();
            let er = wrap_angle(truth.rotation.angle() - r.t_target_source.rotation.angle()).abs();
            errs.push((e, er, r.inliers, r.overlap));
            if e < 1.0 {
                ok += 1;
            }
        }
    }
    println!(
        "keyframes {} revisits {n} reg<1m {ok} place rank1 {rank1} rank5 {rank5} rank25 {rank25}",
        recs.len()
    );
    errs.sort_by(|a, b| a.0.total_cmp(&b.0));
    for qq in [0.5, 0.8, 0.9, 0.95] {
        let e = errs[((errs.len() - 1) as f64 * qq) as usize];
        println!("q{qq}: {e:?}");
    }
    let _ = iso2_from_iso3;
}
