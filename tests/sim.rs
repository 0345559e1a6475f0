//! Simulator checks against independent truth: the Doppler distortion is undone exactly by eq. 4, static
//! radial velocities match finite differences of the ground-truth radar pose, the loop closes, speeds and
//! yaw rates match the configured laps and corner radii, odometry drift follows its error model, and the
//! drive is deterministic per seed.

use dc_loc::math::{Iso2, Stamp, Vec2, Vec3, wrap_angle};
use dc_loc::radar::Detection;
use dc_loc::radar::doppler::compensate;
use dc_loc::sim::config::OdometrySimConfig;
use dc_loc::sim::odometry::OdometryIntegrator;
use dc_loc::sim::{
    Dropout, NoiseConfig, NoiseModel, RadarPreset, SimConfig, SimDrive, SimEvent, SimSetup,
    Simulator, TargetKind, simulate,
};
use std::sync::OnceLock;

/// The default drive (CARLA radar, 72 then 40 km/h, Gaussian noise), simulated once for all tests.
fn default_drive() -> &'static SimDrive {
    static D: OnceLock<SimDrive> = OnceLock::new();
    D.get_or_init(|| simulate(&SimConfig::default()).unwrap())
}

/// The first `n` events of a configuration.
fn events(cfg: &SimConfig, n: usize) -> Vec<SimEvent> {
    Simulator::new(cfg).unwrap().take(n).collect()
}

fn scans(ev: &[SimEvent]) -> impl Iterator<Item = &dc_loc::sim::SimScan> {
    ev.iter().filter_map(|e| match e {
        SimEvent::Scan(s) => Some(s),
        _ => None,
    })
}

/// Radar pose in the map frame at `stamp` from the ground truth and the extrinsic.
fn radar_pose(d: &SimDrive, radar: usize, stamp: Stamp) -> Iso2 {
    let e = d.setup.radars[radar].extrinsic;
    d.state_at(stamp).t_map_body * Iso2::new(Vec2::new(e[0], e[1]), e[5])
}

/// With the true radial velocity, eq. 4 restores the true point exactly: noise-free, the measured point;
/// with noise, the point at the noisy range and azimuth (the range noise is not a Doppler effect).
#[test]
fn compensation_with_true_velocity_restores_the_truth() {
    let cfg = SimConfig {
        noise: NoiseConfig::none(),
        ..SimConfig::default()
    };
    let ev = events(&cfg, 3000);
    let mut n = 0;
    let mut max_shift: f64 = 0.0;
    for s in scans(&ev) {
        let beta = cfg.radar_list()[s.scan.radar].beta;
        for (det, t) in s.scan.detections.iter().zip(&s.truth) {
            assert_eq!(det.v_r, t.v_r);
            let p = compensate(det, beta);
            assert!(
                (p - t.p_radar).norm() < 1e-12 * t.p_radar.norm().max(1.0),
                "{p} vs {}",
                t.p_radar
            );
            // The distortion itself is beta * v_r along the ray.
            let shift = (det.p_radar - t.p_radar).norm();
            assert!((shift - beta * t.v_r.abs()).abs() < 1e-9);
            max_shift = max_shift.max(shift);
            n += 1;
        }
    }
    assert!(n > 10_000, "{n} detections");
    // At 72 km/h a static point straight ahead moves by ~0.8 m (docs/algorithm.md, Doppler range distortion).
    assert!(max_shift > 0.75 && max_shift < 2.5, "{max_shift}");

    for s in default_drive().scans.iter().take(500) {
        for (det, t) in s.scan.detections.iter().zip(&s.truth) {
            let with_true_v = Detection { v_r: t.v_r, ..*det };
            let p = compensate(&with_true_v, 0.04);
            let (r, phi) = (
                t.p_radar.norm() + t.noise[0],
                t.p_radar.y.atan2(t.p_radar.x) + t.noise[1],
            );
            let want = Vec3::new(r * phi.cos(), r * phi.sin(), 0.0);
            assert!((p - want).norm() < 1e-9, "{p} vs {want}");
            assert!((det.v_r - t.v_r - t.noise[2]).abs() < 1e-12);
            assert_eq!(det.p_radar.z, 0.0);
        }
    }
}

/// Static detections: `v_r = -d . v_radar` with the radar velocity from central differences of the
/// ground-truth radar position (body pose times extrinsic: the yaw-rate lever arm comes in by itself).
/// Moving targets break it.
#[test]
fn static_radial_velocity_matches_the_radar_motion() {
    let d = default_drive();
    let h = 1e-5;
    let (mut checked, mut merged, mut moving, mut moving_off) = (0, 0, 0, 0);
    let duration = d.setup.trajectory.duration();
    for s in d.scans.iter().step_by(7) {
        let st = s.scan.stamp;
        if !(0.001..duration - 0.001).contains(&d.setup.time_of(st)) {
            continue; // the drive's ends: no central difference
        }
        let (a, b) = (
            radar_pose(d, 0, Stamp(st.0 - 10_000)),
            radar_pose(d, 0, Stamp(st.0 + 10_000)),
        );
        let v_map = (b.translation.vector - a.translation.vector) / (2.0 * h);
        let rot = radar_pose(d, 0, st).rotation;
        let v_radar = rot.inverse() * v_map;
        for t in &s.truth {
            let dir = Vec2::new(t.p_radar.x, t.p_radar.y).normalize();
            let predicted = -dir.dot(&v_radar);
            if t.kind.is_static() {
                if t.members == 1 {
                    assert!(
                        (t.v_r - predicted).abs() < 1e-4,
                        "{:?}: {} vs {predicted}",
                        t.kind,
                        t.v_r
                    );
                    checked += 1;
                } else {
                    // A merged cell averages its members over less than the azimuth resolution.
                    assert!((t.v_r - predicted).abs() < 0.05, "{} vs {predicted}", t.v_r);
                    merged += 1;
                }
            } else if t.kind == TargetKind::Vehicle {
                moving += 1;
                if (t.v_r - predicted).abs() > 1.0 {
                    moving_off += 1;
                }
            }
        }
    }
    assert!(checked > 5000 && merged > 100, "{checked} {merged}");
    assert!(
        moving > 100 && moving_off * 10 > moving * 7,
        "{moving_off} of {moving}"
    );
    // The lever arm matters: in a corner the radar 3.4 m ahead moves sideways.
    let s = d
        .scans
        .iter()
        .max_by(|a, b| a.yaw_rate.abs().total_cmp(&b.yaw_rate.abs()))
        .unwrap();
    assert!(s.yaw_rate.abs() * 3.412 > 0.9, "{}", s.yaw_rate);
}

/// Per-scan detection counts, the share of moving targets, false alarms and dropouts.
#[test]
fn scan_statistics_look_like_an_ars408() {
    let d = default_drive();
    let mut counts: Vec<usize> = d.scans.iter().map(|s| s.scan.detections.len()).collect();
    counts.sort_unstable();
    let n = counts.len();
    let (p05, p50, p95) = (counts[n / 20], counts[n / 2], counts[n * 19 / 20]);
    assert!(
        p05 >= 15 && (40..=100).contains(&p50) && p95 <= 125,
        "{p05} {p50} {p95}"
    );
    assert_eq!(counts[n - 1], 125); // the cap is reached in busy places
    let all: Vec<_> = d.scans.iter().flat_map(|s| &s.truth).collect();
    let frac = |k: &dyn Fn(TargetKind) -> bool| {
        all.iter().filter(|t| k(t.kind)).count() as f64 / all.len() as f64
    };
    let moving = frac(&|k| k.is_moving());
    let false_alarms = frac(&|k| k == TargetKind::FalseAlarm);
    let facades = frac(&|k| k == TargetKind::Facade);
    assert!(moving > 0.02 && moving < 0.2, "{moving}");
    assert!(false_alarms > 0.02 && false_alarms < 0.08, "{false_alarms}");
    assert!(facades > 0.2, "{facades}");
    // Dropouts at the configured rates (0.5 % empty, 2 % partial), within 4 binomial sigmas.
    let rate = |k: Dropout| d.scans.iter().filter(|s| s.dropout == k).count() as f64;
    for (k, p) in [(Dropout::Empty, 0.005), (Dropout::Partial, 0.02)] {
        let sd = (n as f64 * p * (1.0 - p)).sqrt();
        assert!(
            (rate(k) - n as f64 * p).abs() < 4.0 * sd,
            "{k:?}: {}",
            rate(k)
        );
    }
    assert!(
        d.scans
            .iter()
            .filter(|s| s.dropout == Dropout::Empty)
            .all(|s| s.scan.detections.is_empty())
    );
    // The merged event stream holds everything once, in time order, ground truth first at equal stamps.
    let ev: Vec<_> = d.events().collect();
    assert_eq!(
        ev.len(),
        d.ground_truth.len() + d.odometry.len() + d.scans.len()
    );
    let stamp = |e: &dc_loc::sim::SimEventRef| match e {
        dc_loc::sim::SimEventRef::GroundTruth(g) => g.stamp,
        dc_loc::sim::SimEventRef::Odometry(o) => o.stamp,
        dc_loc::sim::SimEventRef::Scan(s) => s.scan.stamp,
        dc_loc::sim::SimEventRef::Imu(i) => i.stamp,
    };
    assert!(ev.windows(2).all(|w| stamp(&w[0]) <= stamp(&w[1])));
    assert!(matches!(ev[0], dc_loc::sim::SimEventRef::GroundTruth(_)));
    assert_eq!(stamp(&ev[0]), Stamp::from_secs_f64(1.7e9));
    // 13 Hz: consecutive scans 1/13 s apart (up to the jitter).
    for w in d.scans.windows(2) {
        let dt = w[1].scan.stamp.secs_since(w[0].scan.stamp);
        assert!((dt - 1.0 / 13.0).abs() < 0.005, "{dt}");
    }
}

/// Noise of the recorded detections has each model's documented standard deviation.
#[test]
fn detection_noise_follows_the_selected_model() {
    for model in [
        NoiseModel::Gaussian,
        NoiseModel::Gamma,
        NoiseModel::StudentT,
    ] {
        let mut cfg = SimConfig::default();
        cfg.noise.model = model;
        let ev = events(&cfg, 8000);
        let noise: Vec<[f64; 3]> = scans(&ev)
            .flat_map(|s| s.truth.iter().map(|t| t.noise))
            .collect();
        let want = cfg.noise.std_devs();
        let n = noise.len() as f64;
        assert!(n > 50_000.0);
        for (k, w) in [want.range, want.azimuth, want.velocity]
            .into_iter()
            .enumerate()
        {
            let m = noise.iter().map(|x| x[k]).sum::<f64>() / n;
            let sd = (noise.iter().map(|x| (x[k] - m).powi(2)).sum::<f64>() / n).sqrt();
            assert!(m.abs() < 5.0 * w / n.sqrt(), "{model:?} {k}: mean {m}");
            assert!((sd / w - 1.0).abs() < 0.03, "{model:?} {k}: {sd} vs {w}");
        }
    }
}

/// The loop closes (lap end meets lap start), cruise speeds are reached on the long straight, and in the
/// middle of every corner the yaw rate is the speed over the ego lane's radius (configured radius plus or
/// minus the lane offset). Heading, speed and yaw rate agree with central differences of the pose.
#[test]
fn trajectory_closes_and_follows_the_configured_geometry() {
    let d = default_drive();
    let tr = &d.setup.trajectory;
    let cfg = &d.setup.config;
    for &(ta, tb) in tr.lap_times() {
        let (a, b) = (tr.state(ta), tr.state(tb));
        assert!((a.t_map_body.translation.vector - b.t_map_body.translation.vector).norm() < 1e-6);
        assert!((b.heading - a.heading - 2.0 * std::f64::consts::PI).abs() < 1e-9);
    }
    let lap_lengths = tr.lap_lengths();
    let ego = cfg.world.street.ego_lane_offset();
    // Outer lane of a counter-clockwise loop: longer than the centre line by 2 pi times the offset.
    assert!(
        (lap_lengths[0] - tr.centerline().length() - 2.0 * std::f64::consts::PI * ego).abs() < 1e-6
    );
    // Straight through the start: 100-250 m after the lap line each lap runs at its cruise speed.
    for (lap, &(ta, tb)) in tr.lap_times().iter().enumerate() {
        let mut t = ta;
        let mut seen = 0;
        while t < tb {
            let s = tr.state(t);
            let along = s.distance - tr.state(ta).distance;
            if (100.0..250.0).contains(&along) {
                assert!(
                    (s.speed - cfg.laps[lap].speed).abs() < 1e-9,
                    "lap {lap}: {}",
                    s.speed
                );
                seen += 1;
            }
            t += 0.5;
        }
        assert!(seen > 10);
    }
    // Corners: yaw rate = speed / (R + offset) in the arc's middle (outer lane of left turns).
    let line = tr.centerline();
    for c in line.corners() {
        let mid = 0.5 * (c.s_start + c.s_end);
        let k = line.curvature(mid);
        let r_lane = 1.0 / k.abs() + ego * k.signum();
        let t = (0..(tr.duration() * 20.0) as usize)
            .map(|i| i as f64 / 20.0)
            .min_by(|&a, &b| {
                let f = |t: f64| (tr.state(t).loop_position - mid).abs();
                f(a).total_cmp(&f(b))
            })
            .unwrap();
        let s = tr.state(t);
        if (s.loop_position - mid).abs() < 0.6 {
            assert!(
                (s.yaw_rate.abs() - s.speed / r_lane).abs() < 1e-3 * s.yaw_rate.abs(),
                "{} vs {}",
                s.yaw_rate,
                s.speed / r_lane
            );
            // Corner speed respects the lateral acceleration limit.
            assert!(s.speed * s.yaw_rate.abs() <= cfg.drive.max_lateral_acceleration + 1e-6);
        }
    }
    let h = 1e-5;
    for i in 1..300 {
        let t = tr.duration() * i as f64 / 300.0;
        let (a, m, b) = (tr.state(t - h), tr.state(t), tr.state(t + h));
        let v = (b.t_map_body.translation.vector - a.t_map_body.translation.vector) / (2.0 * h);
        assert!((v.norm() - m.speed).abs() < 1e-4, "speed at {t}");
        assert!(wrap_angle(v.y.atan2(v.x) - m.t_map_body.rotation.angle()).abs() < 1e-5);
        let w = wrap_angle(b.heading - a.heading) / (2.0 * h);
        assert!(
            (w - m.yaw_rate).abs() < 1e-4,
            "yaw rate at {t}: {w} vs {}",
            m.yaw_rate
        );
    }
}

/// A reverse lap after a U-turn: the drive stays continuous and its revisits come from the other lane.
#[test]
fn reverse_lap_turns_around_continuously() {
    let mut cfg = SimConfig::default();
    cfg.laps[1].reverse = true;
    let setup = SimSetup::new(&cfg).unwrap();
    let tr = &setup.trajectory;
    let (_, end0) = tr.lap_times()[0];
    let (start1, _) = tr.lap_times()[1];
    let ego = cfg.world.street.ego_lane_offset();
    // A half circle of the lane offset's radius at no more than the U-turn speed.
    assert!(start1 - end0 >= std::f64::consts::PI * ego / cfg.drive.uturn_speed - 1e-9);
    let (a, b) = (tr.state(end0), tr.state(start1));
    // Left U-turn: heading turned by pi, position moved two lane offsets to the left.
    assert!((b.heading - a.heading - std::f64::consts::PI).abs() < 1e-9);
    let shift = a
        .t_map_body
        .inverse_transform_point(&b.t_map_body.translation.vector.into());
    assert!((shift.coords - Vec2::new(0.0, 2.0 * ego)).norm() < 1e-9);
    let mid = tr.state(0.5 * (end0 + start1));
    assert!(mid.lap.turning && mid.speed <= cfg.drive.uturn_speed + 1e-9);
    // Position is continuous across the turn (no jumps at 50 Hz).
    let mut prev = tr.state(end0 - 2.0).t_map_body.translation.vector;
    let mut t = end0 - 2.0;
    while t < start1 + 2.0 {
        t += 0.02;
        let p = tr.state(t).t_map_body.translation.vector;
        assert!((p - prev).norm() < 0.02 * 21.0);
        prev = p;
    }
}

/// Odometry: exact with all errors off; with only a scale error, off by exactly `s |p - p0|`; with only a
/// yaw-rate bias, its heading error is `bias * t`.
#[test]
fn odometry_drift_follows_its_error_model() {
    let base = SimConfig {
        radar_preset: RadarPreset::Carla,
        ..SimConfig::default()
    };
    let setup = SimSetup::new(&base).unwrap();
    let lap_end = setup.trajectory.lap_times()[0].1;
    // Odometry at 50 Hz over the first lap.
    let run = |o: OdometrySimConfig| {
        let mut integ = OdometryIntegrator::new(o, 5);
        (0..)
            .map(|k| k as f64 / o.rate)
            .take_while(|&t| t <= lap_end)
            .map(|t| {
                let stamp = setup.stamp_at(t);
                integ.step(stamp, &setup.state_at(stamp))
            })
            .collect::<Vec<_>>()
    };
    let odo = run(OdometrySimConfig::perfect());
    let t_map_odom = setup.t_map_odom();
    let p0 = t_map_odom.translation.vector;
    for o in &odo {
        let gt = setup.state_at(o.stamp);
        let e = t_map_odom * o.t_odom_body;
        assert!((e.translation.vector - gt.t_map_body.translation.vector).norm() < 1e-6);
        assert!(wrap_angle(e.rotation.angle() - gt.t_map_body.rotation.angle()).abs() < 1e-9);
        assert!((o.speed - gt.speed).abs() < 1e-12 && (o.yaw_rate - gt.yaw_rate).abs() < 1e-12);
    }
    let scale = 0.01;
    let odo = run(OdometrySimConfig {
        scale_error: scale,
        ..OdometrySimConfig::perfect()
    });
    let mut max_err: f64 = 0.0;
    for o in &odo {
        let gt = setup.state_at(o.stamp).t_map_body.translation.vector;
        let err = ((t_map_odom * o.t_odom_body).translation.vector - gt).norm();
        assert!((err - scale * (gt - p0).norm()).abs() < 1e-6, "{err}");
        max_err = max_err.max(err);
    }
    // About 1 % of the largest distance from the start point.
    assert!(max_err > 3.0, "{max_err}");
    let bias = 0.1f64.to_radians();
    let odo = run(OdometrySimConfig {
        yaw_rate_bias: bias,
        ..OdometrySimConfig::perfect()
    });
    let last = odo.last().unwrap();
    let t = setup.time_of(last.stamp);
    let gt = setup.state_at(last.stamp);
    let heading_err = last.heading + t_map_odom.rotation.angle() - gt.heading;
    assert!(
        (heading_err - bias * t).abs() < 1e-9,
        "{heading_err} vs {}",
        bias * t
    );
    let pos_err = ((t_map_odom * last.t_odom_body).translation.vector
        - gt.t_map_body.translation.vector)
        .norm();
    assert!(pos_err > 10.0, "{pos_err}");
    // The default odometry (with noise) drifts, and its covariance is of the size of the drift.
    let d = default_drive();
    let o = d
        .odometry
        .iter()
        .find(|o| d.setup.time_of(o.stamp) >= tr_end(d))
        .unwrap();
    let gt = d.state_at(o.stamp).t_map_body.translation.vector;
    let err = ((d.t_map_odom() * o.t_odom_body).translation.vector - gt).norm();
    let sigma = (o.covariance[(0, 0)] + o.covariance[(1, 1)]).sqrt();
    assert!(
        err > 5.0 && sigma > err / 3.0 && sigma < err * 3.0,
        "error {err}, sigma {sigma}"
    );
    let msg = o.to_msg("odom", "base_link");
    assert_eq!(msg.header.frame_id, "odom");
    assert_eq!(msg.pose.covariance[0], o.covariance[(0, 0)]);
    assert_eq!(msg.pose.covariance[35], o.covariance[(2, 2)]);
    assert_eq!(msg.pose.covariance[5], o.covariance[(0, 2)]);
}

fn tr_end(d: &SimDrive) -> f64 {
    d.setup.trajectory.lap_times()[0].1
}

/// Same seed, same drive; another seed, another world and other detections.
#[test]
fn deterministic_per_seed() {
    let cfg = SimConfig::default();
    let a = events(&cfg, 1500);
    let b = events(&cfg, 1500);
    assert_eq!(a, b);
    let c = events(
        &SimConfig {
            seed: 2,
            ..cfg.clone()
        },
        1500,
    );
    assert_ne!(scans(&a).next(), scans(&c).next());
    // Changing the noise model changes the noise but not the world or the trajectory.
    let mut g = cfg.clone();
    g.noise.model = NoiseModel::StudentT;
    let e = events(&g, 1500);
    for (x, y) in scans(&a).zip(scans(&e)) {
        assert_eq!(x.scan.stamp, y.scan.stamp);
        assert_eq!(x.truth.len(), y.truth.len());
        for (p, q) in x.truth.iter().zip(&y.truth) {
            assert_eq!(p.p_radar, q.p_radar);
            assert_ne!(p.noise, q.noise);
        }
    }
}

/// Revisits: every stamp of lap 1 has a lap-0 sample within 5 m (same lane), the k-d tree finds the true
/// nearest one (brute force), and lap-0 stamps have none.
#[test]
fn revisits_pair_later_laps_with_earlier_ones() {
    let d = default_drive();
    let idx = d.revisit_index();
    let lap0: Vec<_> = d.ground_truth.iter().filter(|g| g.lap.lap == 0).collect();
    let mut found = 0;
    for s in d.scans.iter().step_by(5) {
        let r = d.revisit_of(&idx, s.scan.stamp, 5.0, Some(0.5));
        if s.lap.lap == 0 {
            assert!(r.is_none());
            continue;
        }
        let r = r.expect("lap 1 drives the same lane");
        let p = d.state_at(s.scan.stamp).t_map_body.translation.vector;
        let brute = lap0
            .iter()
            .map(|g| (g.t_map_body.translation.vector - p).norm())
            .fold(f64::INFINITY, f64::min);
        assert!((r.distance - brute).abs() < 1e-9);
        assert!(r.distance < 0.25, "{}", r.distance); // 50 Hz at <= 20 m/s: samples 0.4 m apart
        assert_eq!(r.lap, 0);
        let g = d.state_at(r.stamp).t_map_body.translation.vector;
        assert!(((g - p).norm() - r.distance).abs() < 1e-9);
        found += 1;
    }
    assert!(found > 200);
}

/// The radar section handed to the pipeline matches the simulated radars, in radar-index order.
#[test]
fn pipeline_config_matches_the_radars() {
    let cfg = SimConfig::with_preset(RadarPreset::Nuscenes);
    let c = cfg.to_config();
    c.validate().unwrap();
    let radars = cfg.radar_list();
    for (i, (name, rc)) in c.radar_list().into_iter().enumerate() {
        assert_eq!(name, radars[i].name);
        assert_eq!(rc.extrinsic, radars[i].extrinsic);
        assert_eq!(rc.beta, 0.04);
        assert_eq!(rc.fields.velocity, "v_r");
        assert_eq!(rc.sigma_range, 0.25);
    }
    // The nuScenes preset: five interleaved radars, each at 13 Hz.
    let ev = events(&cfg, 1000);
    let mut per = [0usize; 5];
    for s in scans(&ev) {
        per[s.scan.radar] += 1;
    }
    assert!(per.iter().all(|&n| n >= 40), "{per:?}");
    let stamps: Vec<Stamp> = ev.iter().map(|e| e.stamp()).collect();
    assert!(stamps.windows(2).all(|w| w[0] <= w[1]));
}

/// A radar clock offset moves the scans' stamps by exactly the offset and leaves what they measured
/// unchanged.
#[test]
fn a_clock_offset_moves_stamps_not_measurements() {
    let cfg = SimConfig::default();
    let mut shifted = cfg.clone();
    shifted.radars = cfg.radar_list();
    shifted.radar_preset = RadarPreset::Custom;
    shifted.radars[0].stamp_offset = -0.03;
    let (a, b) = (events(&cfg, 3000), events(&shifted, 3000));
    let (a, b): (Vec<_>, Vec<_>) = (scans(&a).collect(), scans(&b).collect());
    assert!(a.len() > 100 && a.len() == b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(y.scan.stamp.0 - x.scan.stamp.0, -30_000_000);
        assert_eq!(x.scan.detections, y.scan.detections);
    }
}
