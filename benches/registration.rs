//! DC-Loc registration speed: descriptors of both submaps + KNN matching + RANSAC + LM for one pair,
//! single thread, on synthetic submaps of about 1000 and 5000 points (10 stacked scans with the
//! paper's noise, 20 % clutter, yaw in +-pi, translation in +-10 m; tests/support/radar_scene.rs).
//!
//! `cargo bench --bench registration`. Targets: 1000-point pair <= 3 ms median, 5000-point pair
//! <= 20 ms median on one core. `pair_1000_points_paper_steps` times the paper's steps alone
//! ([`RegistrationConfig::paper_steps`]), `pair_1000_points_without_bias_probe` the default without
//! the reverse dense run that widens the covariance; the other cases the default pipeline with its
//! stages beyond the paper (screening of 32 RANSAC motions, three refined, the dense stage).
//!
//! `DC_LOC_BENCH_PARAMS` times the default pipeline under parameter overrides instead (node
//! parameters, `name:=value` separated by spaces), e.g.
//! `DC_LOC_BENCH_PARAMS="registration.dense.soft_rounds:=3" cargo bench --bench registration`.

#[path = "../tests/support/radar_scene.rs"]
mod radar_scene;

use criterion::{Criterion, criterion_group, criterion_main};
use dc_loc::math::Iso2;
use dc_loc::registration::{PreparedSubmap, RegistrationConfig, register_prepared};
use radar_scene::*;
use rand::SeedableRng;
use rand::rngs::StdRng;
use std::hint::black_box;

/// Four pairs of about `n` points each (cycled through by the benchmark).
fn pairs(n: usize, seed: u64) -> Vec<Pair> {
    let mut rng = StdRng::seed_from_u64(seed);
    let p_detect = if n > 2000 { 0.9 } else { 0.5 };
    let view = View {
        t_world_sensor: Iso2::identity(),
        max_range: 100.0,
        half_fov: std::f64::consts::PI,
        p_detect,
        clutter_ratio: 0.2,
        sweeps: 10,
    };
    // Points per reflector: 10 scans x p_d x 1.2 (clutter) x ~0.76 (share of reflectors in range).
    let reflectors = (n as f64 / (10.0 * p_detect * 1.2 * 0.76)) as usize;
    (0..4)
        .map(|_| {
            let scene = random_scene(&mut rng, reflectors, 115.0);
            let t = random_motion(&mut rng, 10.0);
            independent_pair(&mut rng, &scene, t, view, view, &Noise::default())
        })
        .collect()
}

/// The default registration settings under the overrides of `DC_LOC_BENCH_PARAMS`, if set.
fn config() -> RegistrationConfig {
    let Ok(overrides) = std::env::var("DC_LOC_BENCH_PARAMS") else {
        return RegistrationConfig::default();
    };
    let mut params = dc_loc::params::ParamSet::default();
    for arg in overrides.split_whitespace() {
        params
            .set_override(arg)
            .unwrap_or_else(|e| panic!("DC_LOC_BENCH_PARAMS: {e}"));
    }
    let cfg = dc_loc::params::apply(&params)
        .unwrap_or_else(|e| panic!("DC_LOC_BENCH_PARAMS: {e}"))
        .registration;
    eprintln!("registration settings overridden by DC_LOC_BENCH_PARAMS=\"{overrides}\"");
    cfg
}

fn bench(c: &mut Criterion) {
    let cfg = config();
    for (name, n) in [("pair_1000_points", 1000usize), ("pair_5000_points", 5000)] {
        let set = pairs(n, n as u64);
        let mean_pts = set
            .iter()
            .map(|p| p.source.set.len() + p.target.set.len())
            .sum::<usize>()
            / (2 * set.len());
        eprintln!("{name}: {mean_pts} points per submap on average");
        let mut k = 0usize;
        c.bench_function(name, |b| {
            b.iter(|| {
                let p = &set[k % set.len()];
                k += 1;
                let s = PreparedSubmap::new(p.source.set.clone(), &cfg).unwrap();
                let t = PreparedSubmap::new(p.target.set.clone(), &cfg).unwrap();
                black_box(register_prepared(&s, &t, &cfg).unwrap())
            })
        });
        // The same with the target prepared beforehand (a keyframe matched again).
        let prepared: Vec<PreparedSubmap> = set
            .iter()
            .map(|p| PreparedSubmap::new(p.target.set.clone(), &cfg).unwrap())
            .collect();
        let mut k = 0usize;
        c.bench_function(&format!("{name}_target_prepared"), |b| {
            b.iter(|| {
                let i = k % set.len();
                k += 1;
                let s = PreparedSubmap::new(set[i].source.set.clone(), &cfg).unwrap();
                black_box(register_prepared(&s, &prepared[i], &cfg).unwrap())
            })
        });
    }
    // The default without the reverse dense run that widens the covariance by the association bias
    // (`registration.dense.bias_probe`), 1000 points: the probe's cost as a ratio in the same run.
    let mut no_probe = cfg.clone();
    no_probe.dense.bias_probe = false;
    let set = pairs(1000, 1000);
    let mut k = 0usize;
    c.bench_function("pair_1000_points_without_bias_probe", |b| {
        b.iter(|| {
            let p = &set[k % set.len()];
            k += 1;
            let s = PreparedSubmap::new(p.source.set.clone(), &no_probe).unwrap();
            let t = PreparedSubmap::new(p.target.set.clone(), &no_probe).unwrap();
            black_box(register_prepared(&s, &t, &no_probe).unwrap())
        })
    });
    // The paper's steps alone (descriptors, KNN, RANSAC, LM; no dense stage, no screening), 1000 points.
    let paper = RegistrationConfig::paper_steps();
    let set = pairs(1000, 1000);
    let mut k = 0usize;
    c.bench_function("pair_1000_points_paper_steps", |b| {
        b.iter(|| {
            let p = &set[k % set.len()];
            k += 1;
            let s = PreparedSubmap::new(p.source.set.clone(), &paper).unwrap();
            let t = PreparedSubmap::new(p.target.set.clone(), &paper).unwrap();
            black_box(register_prepared(&s, &t, &paper).unwrap())
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
