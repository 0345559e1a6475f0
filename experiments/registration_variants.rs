//! Measures the association choices of DC-Loc registration on synthetic submap pairs and prints tables.
//!
//! `cargo run --release --example registration_variants [pairs]` (default 30 pairs per scenario).
//!
//! Scenes: street-like reflectors (facades, cars, poles) within 115 m; a submap stacks 10 scans of a
//! 100 m radar with the paper's noise (0.25 m, 0.5 deg, 0.1 m/s, beta 0.04), detection probability
//! p_d per scan and 20 % clutter; the two submaps of a pair are independent observations, the motion
//! is yaw U(-pi, pi), translation U(-10, 10) m.
//!
//! Columns, over the queried source keypoints that have a counterpart (same reflector) among the
//! target keypoints: `hit@K` = share whose counterpart is among their K nearest target descriptors;
//! `prec` = share of candidate correspondences (k = 3) that are true (what RANSAC sees); `succ` =
//! share of pairs the full pipeline registers within 0.5 m and 1 deg; `t_err` = mean translation
//! error of those, m; `r_err` = mean rotation error, mrad; `nees` = mean NEES of those (3 when the
//! reported covariance is consistent); `cpu` = thread CPU time per pair
//! (descriptors of both submaps + matching + RANSAC + LM), ms (10 ms ticks summed over all pairs).

#[path = "../tests/support/radar_scene.rs"]
mod radar_scene;

use dc_loc::registration::descriptor::{AngularStatistic, DescriptorConfig, Normalisation};
use dc_loc::registration::{PreparedSubmap, RegistrationConfig, register_detailed};
use radar_scene::*;
use rand::SeedableRng;
use rand::rngs::StdRng;

fn cpu_s() -> f64 {
    let s = std::fs::read_to_string("/proc/thread-self/stat").unwrap_or_default();
    let rest = s.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

struct Scenario {
    name: &'static str,
    /// Largest yaw difference, rad.
    max_yaw: f64,
    target: View,
    source: View,
    reflectors: usize,
    noise: Noise,
}

fn view(half_fov_deg: f64, p_detect: f64, sweeps: usize) -> View {
    View {
        t_world_sensor: dc_loc::math::Iso2::identity(),
        max_range: 100.0,
        half_fov: half_fov_deg.to_radians(),
        p_detect,
        clutter_ratio: 0.2,
        sweeps,
    }
}

fn main() {
    let pairs: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(30);
    let only: Option<String> = std::env::args().nth(2);
    let scenarios = [
        Scenario {
            max_yaw: std::f64::consts::PI,
            name: "A: ~1000 points (10 scans, p_d 0.5, 220 reflectors)",
            target: view(180.0, 0.5, 10),
            source: view(180.0, 0.5, 10),
            reflectors: 220,
            noise: Noise::default(),
        },
        Scenario {
            max_yaw: std::f64::consts::PI,
            name: "B: ~5000 points (10 scans, p_d 0.9, 600 reflectors)",
            target: view(180.0, 0.9, 10),
            source: view(180.0, 0.9, 10),
            reflectors: 600,
            noise: Noise::default(),
        },
        Scenario {
            max_yaw: std::f64::consts::PI,
            name: "C: density mismatch (p_d 0.8 / 0.25, 400 reflectors)",
            target: view(180.0, 0.8, 10),
            source: view(180.0, 0.25, 10),
            reflectors: 400,
            noise: Noise::default(),
        },
        Scenario {
            max_yaw: 30f64.to_radians(),
            name: "D: one forward radar, 150 deg FOV, yaw within 30 deg (p_d 0.5, 500 reflectors)",
            target: view(75.0, 0.5, 10),
            source: view(75.0, 0.5, 10),
            reflectors: 500,
            noise: Noise::default(),
        },
    ];
    use AngularStatistic as A;
    use Normalisation as N;
    type Edit = Box<dyn Fn(&mut RegistrationConfig)>;
    let desc = |radius: f64,
                radial_bins: usize,
                angular: A,
                angular_bins: usize,
                normalisation: N|
     -> Edit {
        Box::new(move |c: &mut RegistrationConfig| {
            c.descriptor = DescriptorConfig {
                radius,
                radial_bins,
                angular,
                angular_bins,
                normalisation,
                ..c.descriptor.clone()
            }
        })
    };
    let edit = |f: fn(&mut RegistrationConfig)| -> Edit { Box::new(f) };
    let variants: Vec<(&str, Edit)> = vec![
        ("default", edit(|_| {})),
        (
            "radial16 R25 hell",
            desc(25.0, 16, A::None, 0, N::Hellinger),
        ),
        ("radial16 R25 none", desc(25.0, 16, A::None, 0, N::None)),
        ("radial16 R25 total", desc(25.0, 16, A::None, 0, N::Total)),
        ("radial16 R25 minmax", desc(25.0, 16, A::None, 0, N::MinMax)),
        (
            "r10+spec6 R25 hell",
            desc(25.0, 10, A::Spectrum, 6, N::Hellinger),
        ),
        (
            "r10+spec6 R25 none",
            desc(25.0, 10, A::Spectrum, 6, N::None),
        ),
        (
            "r10+spec6 R25 total",
            desc(25.0, 10, A::Spectrum, 6, N::Total),
        ),
        (
            "r10+sect6 R25 hell",
            desc(25.0, 10, A::Sectors, 6, N::Hellinger),
        ),
        (
            "r12+spec4 R25 hell",
            desc(25.0, 12, A::Spectrum, 4, N::Hellinger),
        ),
        (
            "r8+spec8 R25 hell",
            desc(25.0, 8, A::Spectrum, 8, N::Hellinger),
        ),
        (
            "r10+spec6 R20 hell",
            desc(20.0, 10, A::Spectrum, 6, N::Hellinger),
        ),
        (
            "r10+spec6 R30 hell",
            desc(30.0, 10, A::Spectrum, 6, N::Hellinger),
        ),
        (
            "r10+spec6 R35 hell",
            desc(35.0, 10, A::Spectrum, 6, N::Hellinger),
        ),
        (
            "keypoints 1000",
            edit(|c| c.descriptor.max_keypoints = 1000),
        ),
        (
            "kp 400, queries 300",
            edit(|c| {
                c.descriptor.max_keypoints = 400;
                c.matching.max_queries = 300;
            }),
        ),
        (
            "kp 400, queries 400",
            edit(|c| {
                c.descriptor.max_keypoints = 400;
                c.matching.max_queries = 400;
            }),
        ),
        (
            "kp 300, queries 300",
            edit(|c| {
                c.descriptor.max_keypoints = 300;
                c.matching.max_queries = 300;
            }),
        ),
        (
            "keypoints 2000",
            edit(|c| c.descriptor.max_keypoints = 2000),
        ),
        ("support 800", edit(|c| c.descriptor.max_support = 800)),
        ("support 3000", edit(|c| c.descriptor.max_support = 3000)),
        ("k 1", edit(|c| c.matching.k = 1)),
        ("k 5", edit(|c| c.matching.k = 5)),
        ("k 3 ratio 0.9", edit(|c| c.matching.ratio = 0.9)),
        ("queries 200", edit(|c| c.matching.max_queries = 200)),
        (
            "kp 800, queries 800",
            edit(|c| {
                c.descriptor.max_keypoints = 800;
                c.matching.max_queries = 800;
            }),
        ),
        (
            "ransac maha gate 3",
            edit(|c| c.ransac.mahalanobis_gate = 3.0),
        ),
        ("no re-selection", edit(|c| c.reselect_rounds = 0)),
        ("LM no U.E.", edit(|c| c.lm.use_uncertainty = false)),
        (
            "LM Huber 1.5",
            edit(|c| {
                c.lm.robust = dc_loc::registration::robust::RobustLoss {
                    kind: dc_loc::registration::robust::RobustKind::Huber,
                    scale: 1.5,
                }
            }),
        ),
    ];
    println!("pairs per scenario: {pairs}");
    for sc in &scenarios {
        if let Some(o) = &only
            && !sc.name.starts_with(o.as_str())
        {
            continue;
        }
        println!("\n## {}", sc.name);
        println!(
            "{:<22} {:>5} {:>6} {:>6} {:>6} {:>6} {:>5} {:>6} {:>6} {:>5} {:>6}",
            "variant",
            "pts",
            "hit@1",
            "hit@3",
            "hit@5",
            "prec",
            "succ",
            "t_err",
            "r_err",
            "nees",
            "cpu"
        );
        for (name, edit) in &variants {
            let mut rng = StdRng::seed_from_u64(7);
            let (mut hits, mut cand_ok, mut cand_all, mut n_true) = ([0usize; 3], 0, 0, 0);
            let (mut succ, mut t_err_sum, mut r_err_sum, mut cpu, mut pts) =
                (0usize, 0.0, 0.0, 0.0, 0usize);
            let mut nees_sum = 0.0;
            let mut cfg = RegistrationConfig::default();
            edit(&mut cfg);
            let mut nn = Vec::new();
            for _ in 0..pairs {
                let scene = random_scene(&mut rng, sc.reflectors, 115.0);
                let t = random_motion(&mut rng, 10.0);
                let t = dc_loc::math::Iso2::new(
                    t.translation.vector,
                    t.rotation.angle() * sc.max_yaw / std::f64::consts::PI,
                );
                let pair = independent_pair(&mut rng, &scene, t, sc.target, sc.source, &sc.noise);
                pts += pair.source.set.len() + pair.target.set.len();
                let c0 = cpu_s();
                let s = PreparedSubmap::new(pair.source.set.clone(), &cfg).unwrap();
                let g = PreparedSubmap::new(pair.target.set.clone(), &cfg).unwrap();
                let res = register_detailed(&s, &g, &cfg);
                cpu += cpu_s() - c0;
                // Descriptor quality against the truth, over the queried keypoints.
                let queries = dc_loc::registration::matching::select_queries(
                    s.keypoints().len(),
                    cfg.matching.max_queries,
                    cfg.ransac.seed,
                );
                let tgt_ids: std::collections::HashSet<usize> = g
                    .keypoints()
                    .iter()
                    .filter_map(|&j| pair.target.ids[j as usize])
                    .collect();
                for &qs in &queries {
                    let i = s.keypoints()[qs as usize] as usize;
                    let Some(id) = pair.source.ids[i] else {
                        continue;
                    };
                    if !tgt_ids.contains(&id) {
                        continue;
                    }
                    n_true += 1;
                    g.index().nearest(&s.descriptors()[qs as usize], 5, &mut nn);
                    for (slot, k) in [1usize, 3, 5].iter().enumerate() {
                        if nn.iter().take(*k).any(|&(_, j)| {
                            same_reflector(&pair, i, g.keypoints()[j as usize] as usize)
                        }) {
                            hits[slot] += 1;
                        }
                    }
                }
                if let Ok(det) = &res {
                    for c in &det.candidates {
                        cand_all += 1;
                        if same_reflector(&pair, c.source as usize, c.target as usize) {
                            cand_ok += 1;
                        }
                    }
                    let (te, re) = pose_error(&det.result.t_target_source, &t);
                    if te < 0.5 && re < 1f64.to_radians() {
                        succ += 1;
                        t_err_sum += te;
                        r_err_sum += re;
                        let e = dc_loc::math::se2_log(&(det.result.t_target_source.inverse() * t));
                        if let Some(inf) = det.covariance_se2.try_inverse() {
                            nees_sum += e.dot(&(inf * e));
                        }
                    }
                }
            }
            let f = |h: usize| 100.0 * h as f64 / n_true.max(1) as f64;
            println!(
                "{:<22} {:>5} {:>5.1}% {:>5.1}% {:>5.1}% {:>5.1}% {:>4.0}% {:>6.3} {:>6.2} {:>5.2} {:>6.2}",
                name,
                pts / (2 * pairs),
                f(hits[0]),
                f(hits[1]),
                f(hits[2]),
                100.0 * cand_ok as f64 / cand_all.max(1) as f64,
                100.0 * succ as f64 / pairs as f64,
                t_err_sum / succ.max(1) as f64,
                1e3 * r_err_sum / succ.max(1) as f64,
                nees_sum / succ.max(1) as f64,
                1e3 * cpu / pairs as f64
            );
        }
    }
}
