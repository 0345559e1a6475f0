//! Keyframe database benchmark (a bench binary, not a timed test): revisit query cost at 10,000 /
//! 100,000 / 1,000,000 keyframes, map memory per keyframe, and save / load time of a 100,000-keyframe
//! map. Targets (issue 5): query under 1 ms at 1,000,000 keyframes, under 32 KB per keyframe.
//!
//! Run: `cargo bench --bench keyframe_db`. `DC_LOC_BENCH_SIZES=10000,100000` picks the query sizes and
//! `DC_LOC_BENCH_MAP=20000` the size of the saved map (default 100000: about 3 GB on disk for the
//! save / load part, in the system temp directory, removed afterwards).
//!
//! The synthetic map: keyframes every 5 m along random-walk roads over a city 10 km wide (so the
//! odometry search finds a realistic handful of neighbours), place descriptors from 500 random scenes
//! (so place retrieval competes with many near-identical keys), and for the memory and load parts the
//! worst case of `map.max_points_per_keyframe` = 4000 points per keyframe.

use dc_loc::keyframe_db::{
    CandidateQuery, KeyframeDb, KeyframeRecord, quantise_cov, quantise_point,
};
use dc_loc::loop_closure::LoopConfig;
use dc_loc::math::{Iso2, Mat2, Stamp, Vec2};
use dc_loc::place::{PlaceConfig, PlaceDescriptor};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use std::hint::black_box;
use std::time::Instant;

fn scene(rng: &mut StdRng, n: usize) -> Vec<Vec2> {
    (0..n)
        .map(|_| {
            let r: f64 = rng.random_range(2.0..80.0);
            let a: f64 = rng.random_range(-3.2..3.2);
            Vec2::new(r * a.cos(), r * a.sin())
        })
        .collect()
}

/// `n` keyframes along random-walk roads; `points` stored points each.
fn build(n: usize, points: usize, rng: &mut StdRng) -> KeyframeDb {
    let place = PlaceConfig::default();
    let scenes: Vec<PlaceDescriptor> = (0..500)
        .map(|_| PlaceDescriptor::from_points(&scene(rng, 400), &place))
        .collect();
    let stored_pts: Vec<[i16; 2]> = scene(rng, points)
        .into_iter()
        .filter_map(quantise_point)
        .collect();
    let stored_covs: Vec<[u8; 3]> = (0..stored_pts.len())
        .map(|_| quantise_cov(&Mat2::new(0.09, 0.01, 0.01, 0.25)))
        .collect();
    let stored_rays: Vec<u8> = (0..stored_pts.len()).map(|k| (k % 256) as u8).collect();
    let mut db = KeyframeDb::new(place, 8);
    let (mut x, mut y, mut h, mut path) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for id in 0..n as u64 {
        if id % 2000 == 0 {
            // A new road somewhere in the city.
            x = rng.random_range(-5000.0..5000.0);
            y = rng.random_range(-5000.0..5000.0);
            h = rng.random_range(-3.2..3.2);
        }
        h += rng.random_range(-0.1..0.1);
        x += 5.0 * h.cos();
        y += 5.0 * h.sin();
        path += 5.0;
        let rec = KeyframeRecord {
            id,
            session: (id / 50_000) as u32,
            stamp: Stamp(1_000_000_000 * (id as i64 + 1)),
            t_odom_body: Iso2::new(Vec2::new(x, y), h),
            odom_pose: [x, y, 0.0, 0.0, 0.0, (h / 2.0).sin(), (h / 2.0).cos()],
            path_distance: path,
            points: stored_pts.clone(),
            covs: stored_covs.clone(),
            rays: stored_rays.clone(),
            place: scenes[rng.random_range(0..scenes.len())].clone(),
        };
        if !db.insert(rec) {
            eprintln!("keyframe {id} refused");
        }
    }
    db
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn sizes(var: &str, default: &[usize]) -> Vec<usize> {
    std::env::var(var)
        .ok()
        .map(|s| s.split(',').filter_map(|t| t.trim().parse().ok()).collect())
        .unwrap_or_else(|| default.to_vec())
}

fn main() {
    // `cargo bench` passes `--bench`; nothing else is understood.
    let mut rng = StdRng::seed_from_u64(1);
    let search = LoopConfig::default().search();
    println!("revisit query (odometry radius + place retrieval, default loop settings):");
    for n in sizes("DC_LOC_BENCH_SIZES", &[10_000, 100_000, 1_000_000]) {
        let t0 = Instant::now();
        let db = build(n, 0, &mut rng);
        let built = t0.elapsed().as_secs_f64();
        let mut times = Vec::new();
        let mut found = 0usize;
        for k in 0..2000 {
            let Some(base) = db.get(rng.random_range(0..n as u64)) else {
                continue;
            };
            let mut q = base.clone();
            q.id = db.next_id();
            q.session = 1000;
            q.path_distance = base.path_distance + 1000.0;
            let t = Instant::now();
            let c = db.candidates(
                &CandidateQuery {
                    query: &q,
                    alignment: None,
                    vouched: false,
                    others: &[],
                },
                q.session,
                &search,
            );
            let dt = t.elapsed().as_secs_f64();
            if k >= 100 {
                times.push(dt * 1e3);
            }
            found += black_box(c).len();
        }
        let p50 = percentile(&mut times, 0.5);
        let p99 = percentile(&mut times, 0.99);
        println!(
            "  {n:>9} keyframes: p50 {p50:.3} ms, p99 {p99:.3} ms ({:.1} candidates per query; built in {built:.1} s)",
            found as f64 / 2000.0
        );
    }

    let n = sizes("DC_LOC_BENCH_MAP", &[100_000])
        .first()
        .copied()
        .unwrap_or(100_000);
    let points = 4000;
    let t0 = Instant::now();
    let db = build(n, points, &mut rng);
    let built = t0.elapsed().as_secs_f64();
    let rec_bytes: usize = db.records().map(|r| r.heap_bytes()).sum();
    println!(
        "map memory: {:.1} KB per keyframe at {points} points (records; built {n} in {built:.1} s)",
        rec_bytes as f64 / n as f64 / 1024.0
    );
    let dir = std::env::temp_dir().join(format!("dc_loc_bench_map_{}", std::process::id()));
    if std::fs::create_dir_all(&dir).is_err() {
        eprintln!("cannot create {}", dir.display());
        return;
    }
    let path = dir.join("map.dcloc");
    let t = Instant::now();
    if let Err(e) = db.save(&path) {
        eprintln!("save failed: {e}");
        let _ = std::fs::remove_dir_all(&dir);
        return;
    }
    let saved = t.elapsed().as_secs_f64();
    let file = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
    drop(db);
    let t = Instant::now();
    let loaded = KeyframeDb::load(&path, PlaceConfig::default(), 8);
    let load = t.elapsed().as_secs_f64();
    match loaded {
        Ok(db) => println!(
            "map file: {n} keyframes, {:.1} KB per keyframe on disk; save {saved:.2} s, load {load:.2} s ({} keyframes back)",
            file as f64 / n as f64 / 1024.0,
            db.len()
        ),
        Err(e) => eprintln!("load failed: {e}"),
    }
    let _ = std::fs::remove_dir_all(&dir);
}
