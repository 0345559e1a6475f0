//! Unit tests of submap stacking.

use super::*;
use crate::math::{iso2_from_iso3, iso3_from_xyz_rpy};
use crate::radar::{Detection, RadarNoise};
use approx::assert_relative_eq;

fn odom_circle(buf: &mut OdometryBuffer, t_end: f64, rate: f64) {
    // Constant speed 10 m/s, yaw rate 0.2 rad/s: an exact circle of radius 50 m.
    let n = (t_end * rate) as usize;
    for i in 0..=n {
        let t = i as f64 / rate;
        buf.push(Stamp::from_secs_f64(t), circle_pose(t), None)
            .unwrap();
    }
}

fn circle_pose(t: f64) -> Iso3 {
    circle_pose_at(t, 10.0)
}

/// The pose at `t` on a circle driven at speed `v` and yaw rate 0.2 rad/s.
fn circle_pose_at(t: f64, v: f64) -> Iso3 {
    let w = 0.2;
    let yaw = w * t;
    iso3_from_xyz_rpy(
        v / w * yaw.sin(),
        v / w * (1.0 - yaw.cos()),
        0.0,
        0.0,
        0.0,
        yaw,
    )
}

#[test]
fn interpolation_on_a_circle_and_its_limits() {
    let mut buf = OdometryBuffer::new(OdometryConfig::default());
    odom_circle(&mut buf, 5.0, 50.0);
    for &t in &[0.0, 0.013, 1.0, 2.37, 4.999, 5.0] {
        let p = buf.pose_at(Stamp::from_secs_f64(t)).unwrap();
        let truth = circle_pose(t);
        // Chord vs arc between 20 ms samples: <= v^2 w dt^2 / 8 ~ 1e-4 m.
        assert_relative_eq!(
            p.translation.vector,
            truth.translation.vector,
            epsilon = 2e-4
        );
        assert_relative_eq!(p.rotation.angle_to(&truth.rotation), 0.0, epsilon = 1e-9);
    }
    // 30 ms past the newest: extrapolated; 100 ms: not yet.
    let e = buf.pose_at(Stamp::from_secs_f64(5.03)).unwrap();
    assert_relative_eq!(
        e.translation.vector,
        circle_pose(5.03).translation.vector,
        epsilon = 2e-3
    );
    assert!(matches!(
        buf.pose_at(Stamp::from_secs_f64(5.1)),
        Err(OdometryError::NotYet { .. })
    ));
    assert!(matches!(
        buf.pose_at(Stamp::from_secs_f64(-0.1)),
        Err(OdometryError::TooOld { .. })
    ));
    let (v, w) = buf.velocity_at(Stamp::from_secs_f64(2.0), 0.05).unwrap();
    assert_relative_eq!(v, Vec3::new(10.0, 0.0, 0.0), epsilon = 1e-3);
    assert_relative_eq!(w, 0.2, epsilon = 1e-6);
    // Backwards time is refused and changes nothing.
    let before = buf.len();
    assert!(matches!(
        buf.push(Stamp::from_secs_f64(1.0), circle_pose(1.0), None),
        Err(OdometryError::TimeWentBackwards { .. })
    ));
    assert_eq!(buf.len(), before);
}

#[test]
fn gaps_are_not_bridged() {
    let mut buf = OdometryBuffer::new(OdometryConfig::default());
    buf.push(Stamp::from_secs_f64(0.0), circle_pose(0.0), None)
        .unwrap();
    buf.push(Stamp::from_secs_f64(2.0), circle_pose(2.0), None)
        .unwrap();
    assert!(matches!(
        buf.pose_at(Stamp::from_secs_f64(1.0)),
        Err(OdometryError::Gap { .. })
    ));
    assert!(
        buf.push(
            Stamp::from_secs_f64(3.0),
            Iso3::translation(f64::NAN, 0.0, 0.0),
            None
        )
        .is_err()
    );
}

/// The Doppler speed scale on, at the bound it is documented with.
const ON: SubmapConfig = SubmapConfig {
    size: 10,
    max_span: 3.0,
    speed_scale_bound: 0.1,
    height_band: [-100.0, 100.0],
};

/// A world of static points around the circle.
fn circle_world() -> Vec<Vec3> {
    (0..60)
        .map(|i| {
            let a = i as f64 * 0.37;
            Vec3::new(40.0 + 30.0 * a.cos(), 25.0 + 30.0 * a.sin(), 0.5)
        })
        .collect()
}

/// Drives the circle (truly at 10 m/s) for 14 scans of a forward radar, with an odometry that
/// reports `odom_speed` on the same yaw rate, into a builder with `cfg`.
fn circle_submap(odom_speed: f64, cfg: SubmapConfig) -> Submap {
    circle_submap_with(|t| circle_pose_at(t, odom_speed), cfg)
}

/// The odometry of the circle (10 m/s, 0.2 rad/s) whose wheels read 13 m/s between 1.3 and 1.6 s:
/// the heading stays the gyro's, the path's speed is the wheels'.
fn slipping_circle_pose(t: f64) -> Iso3 {
    let w = 0.2;
    let speed = |t: f64| if (1.3..1.6).contains(&t) { 13.0 } else { 10.0 };
    let knots = [0.0, 1.3, 1.6, f64::MAX];
    let (mut x, mut y) = (0.0, 0.0);
    for k in knots.windows(2) {
        let (t0, t1) = (k[0], k[1].min(t));
        if t1 <= t0 {
            break;
        }
        let v = speed(t0);
        x += v / w * ((w * t1).sin() - (w * t0).sin());
        y += v / w * ((w * t0).cos() - (w * t1).cos());
    }
    iso3_from_xyz_rpy(x, y, 0.0, 0.0, 0.0, w * t)
}

/// Drives the circle (truly at 10 m/s) for 14 scans of a forward radar, with the odometry
/// `odom_pose(t)`, into a builder with `cfg`.
fn circle_submap_with(odom_pose: impl Fn(f64) -> Iso3, cfg: SubmapConfig) -> Submap {
    let mut odom = OdometryBuffer::new(OdometryConfig::default());
    for i in 0..=150 {
        let t = i as f64 / 50.0;
        odom.push(Stamp::from_secs_f64(t), odom_pose(t), None)
            .unwrap();
    }
    let radar = RadarModel {
        t_body_radar: iso3_from_xyz_rpy(3.4, 0.0, 0.5, 0.0, 0.0, 0.0),
        beta: 0.04,
        noise: RadarNoise::default(),
    };
    let world = circle_world();
    let mut builder = SubmapBuilder::new(cfg, EgoMotionConfig::default(), vec![radar.clone()]);
    for k in 0..14 {
        let t = 1.0 + k as f64 / 13.0;
        let t_odom_body = circle_pose(t);
        let (v_body, w) = (Vec3::new(10.0, 0.0, 0.0), 0.2);
        let t_br = radar.t_body_radar.translation.vector;
        let v_radar = radar.t_body_radar.rotation.inverse()
            * (v_body + Vec3::new(-w * t_br.y, w * t_br.x, 0.0));
        let t_odom_radar = t_odom_body * radar.t_body_radar;
        let mut dets = Vec::new();
        for q in &world {
            let p = t_odom_radar.inverse() * nalgebra::Point3::from(*q);
            let r = p.coords.norm();
            if p.x <= 0.0 || r > 100.0 {
                continue;
            }
            let d = p.coords / r;
            let v_r = -d.dot(&v_radar);
            dets.push(Detection {
                p_radar: d * (r + 0.04 * v_r),
                v_r,
                rcs: None,
            });
        }
        let scan = RadarScan {
            radar: 0,
            stamp: Stamp::from_secs_f64(t),
            detections: dets,
        };
        let pose = odom.pose_at(scan.stamp).unwrap();
        let prior = odom.velocity_at(scan.stamp, 0.05);
        let rep = builder.add_scan(&scan, pose, prior).unwrap();
        assert!(rep.doppler_fit);
        assert_eq!(rep.dynamic, 0);
    }
    builder.build().unwrap()
}

/// The largest distance of a submap point (compensated or raw) from the nearest world point, in
/// the true anchor frame.
fn worst_error(sub: &Submap, raw: bool) -> f64 {
    let t_anchor_odom = circle_pose(2.0).inverse();
    let truth: Vec<Vec3> = circle_world()
        .iter()
        .map(|q| (t_anchor_odom * nalgebra::Point3::from(*q)).coords)
        .collect();
    sub.points
        .iter()
        .map(|p| {
            let p = if raw { p.p_raw } else { p.p };
            truth
                .iter()
                .map(|t| (t - p).norm())
                .fold(f64::MAX, f64::min)
        })
        .fold(0.0, f64::max)
}

/// A world of static points seen by a forward radar while driving the circle: every scan, placed with
/// interpolated odometry and compensated, lands its points on the true world points in the anchor frame.
#[test]
fn submap_stacks_compensated_scans_on_the_world() {
    let sub = circle_submap(10.0, ON);
    assert_eq!(sub.scans.len(), 10, "only the last N = 10 scans");
    assert_eq!(sub.anchor_stamp, Stamp::from_secs_f64(1.0 + 13.0 / 13.0));
    let err = worst_error(&sub, false);
    assert!(err < 1e-3, "compensated point off the world by {err}");
    let worst_raw = worst_error(&sub, true);
    assert!(
        worst_raw > 0.3,
        "the raw points do carry the Doppler distortion ({worst_raw})"
    );
    // Odometry and Doppler agree: chord against arc between scans, 1e-5.
    let SpeedScale::Applied(k) = sub.speed_scale else {
        panic!("{:?}", sub.speed_scale);
    };
    assert_relative_eq!(k, 1.0, epsilon = 1e-4);
    let ps = sub.point_set(true);
    assert_eq!(ps.len(), sub.len());
    assert_eq!(
        iso2_from_iso3(&sub.scans[9].t_anchor_body)
            .translation
            .vector
            .norm(),
        0.0
    );
}

/// An odometry 4 % long (a larger circle on the same yaw rate): uncorrected, the oldest scan lands
/// 4 % of its 7 m from the anchor off; the Doppler speeds scale the distances back.
#[test]
fn the_doppler_speeds_correct_the_odometry_distances() {
    let off = circle_submap(
        10.4,
        SubmapConfig {
            speed_scale_bound: 0.0,
            ..ON
        },
    );
    assert_eq!(off.speed_scale, SpeedScale::Unavailable);
    let err_off = worst_error(&off, false);
    assert!(
        err_off > 0.2,
        "the odometry stretches the submap ({err_off})"
    );
    let on = circle_submap(10.4, ON);
    let SpeedScale::Applied(k) = on.speed_scale else {
        panic!("{:?}", on.speed_scale);
    };
    assert_relative_eq!(k, 1.0 / 1.04, epsilon = 1e-4);
    let err_on = worst_error(&on, false);
    assert!(err_on < 2e-3, "corrected points off the world by {err_on}");
    // Beyond the bound the odometry is used as it is, and the ratio is reported.
    let refused = circle_submap(
        10.4,
        SubmapConfig {
            speed_scale_bound: 0.03,
            ..ON
        },
    );
    let SpeedScale::Refused(k) = refused.speed_scale else {
        panic!("{:?}", refused.speed_scale);
    };
    assert_relative_eq!(k, 1.0 / 1.04, epsilon = 1e-4);
    assert_relative_eq!(worst_error(&refused, false), err_off, epsilon = 1e-12);
}

/// Wheels that read 30 % more for 0.3 s in the middle of the submap: the odometry's steps through
/// the slip are the ones shortened, so the scans on either side of it land where they were seen
/// (one factor for the whole submap would leave those just after the slip 0.4 m off).
#[test]
fn the_doppler_speeds_take_out_a_slip_in_part_of_the_submap() {
    let off = circle_submap_with(
        slipping_circle_pose,
        SubmapConfig {
            speed_scale_bound: 0.0,
            ..ON
        },
    );
    let err_off = worst_error(&off, false);
    assert!(err_off > 0.5, "the slip stretches the submap ({err_off})");
    let on = circle_submap_with(
        slipping_circle_pose,
        SubmapConfig {
            speed_scale_bound: 0.5,
            ..ON
        },
    );
    let SpeedScale::Applied(k) = on.speed_scale else {
        panic!("{:?}", on.speed_scale);
    };
    // The scans span 1 + 4/13 to 2 s: 9/13 s at 10 m/s, of which the odometry reads 3 m/s more
    // until 1.6 s.
    let doppler = 90.0 / 13.0;
    assert_relative_eq!(
        k,
        doppler / (doppler + 3.0 * (1.6 - 17.0 / 13.0)),
        epsilon = 1e-3
    );
    let err_on = worst_error(&on, false);
    assert!(err_on < 0.02, "corrected points off the world by {err_on}");
    // The same factor applied to every translation from the anchor leaves the scans after the slip
    // short by up to 0.4 m.
    let one_factor = Submap {
        points: off
            .points
            .iter()
            .map(|q| SubmapPoint {
                p: q.p + (k - 1.0) * off.scans[q.scan as usize].t_anchor_body.translation.vector,
                ..*q
            })
            .collect(),
        ..off.clone()
    };
    let err_one = worst_error(&one_factor, false);
    assert!(err_one > 0.3, "one factor leaves {err_one}");
}

/// 30 static points ahead of a radar moving with `v_radar` (radar frame), at 10-39 m over 2 rad.
fn static_detections(v_radar: Vec3) -> Vec<Detection> {
    (0..30)
        .map(|i| {
            let a = -1.0 + i as f64 / 15.0;
            let d = Vec3::new(a.cos(), a.sin(), 0.0);
            Detection {
                p_radar: d * (10.0 + i as f64),
                v_r: -d.dot(&v_radar),
                rcs: None,
            }
        })
        .collect()
}

/// A scan of radar 0, driving straight ahead at `speed`, at `stamp` (s).
fn static_scan(stamp: f64, speed: f64) -> RadarScan {
    RadarScan {
        radar: 0,
        stamp: Stamp::from_secs_f64(stamp),
        detections: static_detections(Vec3::new(speed, 0.0, 0.0)),
    }
}

/// Wheels that start to slip at 20 m/s read 26 m/s, 6 m/s from the truth, twice the prior's
/// tolerance: a radar whose previous scan 70 ms before measured 20 m/s still fits its true speed
/// and keeps the static world, where a radar with no recent fit, left with the odometry's prior,
/// cannot.
#[test]
fn a_slipping_odometry_does_not_pull_the_doppler_fit_off_the_static_world() {
    let radar = RadarModel {
        t_body_radar: Iso3::identity(),
        beta: 0.04,
        noise: RadarNoise::default(),
    };
    let builder = || {
        SubmapBuilder::new(
            SubmapConfig::default(),
            EgoMotionConfig::default(),
            vec![radar.clone()],
        )
    };
    let slipping = Some((Vec3::new(26.0, 0.0, 0.0), 0.0));
    let mut tracked = builder();
    let before = tracked
        .add_scan(
            &static_scan(0.0, 20.0),
            Iso3::identity(),
            Some((Vec3::new(20.0, 0.0, 0.0), 0.0)),
        )
        .unwrap();
    assert!(before.doppler_fit);
    let during = tracked
        .add_scan(&static_scan(0.07, 20.0), Iso3::identity(), slipping)
        .unwrap();
    assert!(during.doppler_fit);
    assert_eq!((during.kept, during.dynamic), (30, 0));
    let v = tracked.scans.back().unwrap().doppler_velocity.unwrap();
    assert_relative_eq!(v, Vec3::new(20.0, 0.0, 0.0), epsilon = 1e-6);
    let mut fresh = builder();
    let alone = fresh
        .add_scan(&static_scan(0.07, 20.0), Iso3::identity(), slipping)
        .unwrap();
    assert!(!alone.doppler_fit);
    assert_eq!(
        alone.kept, 0,
        "the odometry's prior calls the static world moving"
    );
}

/// A radar surrounded by traffic that moves a little slower scan after scan: each fit lies within
/// the prior's tolerance of the previous one, but the body cannot slow down that fast. The fits
/// end where they leave both the odometry's tolerance and what hard braking allows since the
/// previous fit; the chain does not carry them to the traffic's speed.
#[test]
fn a_fit_does_not_slide_away_from_the_static_world_faster_than_the_body_brakes() {
    let radar = RadarModel {
        t_body_radar: Iso3::identity(),
        beta: 0.04,
        noise: RadarNoise::default(),
    };
    let mut builder = SubmapBuilder::new(
        SubmapConfig::default(),
        EgoMotionConfig::default(),
        vec![radar],
    );
    let odometry = Some((Vec3::new(10.0, 0.0, 0.0), 0.0));
    let fitted: Vec<bool> = [9.0, 7.5, 6.0, 4.5, 3.0]
        .iter()
        .enumerate()
        .map(|(k, &seen)| {
            let scan = static_scan(0.077 * k as f64, seen);
            builder
                .add_scan(&scan, Iso3::identity(), odometry)
                .unwrap()
                .doppler_fit
        })
        .collect();
    assert_eq!(fitted, [true, true, false, false, false]);
}

#[test]
fn movers_are_rejected_and_each_radar_keeps_its_own_window() {
    let radars = vec![
        RadarModel {
            t_body_radar: Iso3::identity(),
            beta: 0.04,
            noise: RadarNoise::default(),
        },
        RadarModel {
            t_body_radar: iso3_from_xyz_rpy(0.0, 0.0, 0.0, 0.0, 0.0, std::f64::consts::PI),
            beta: 0.04,
            noise: RadarNoise::default(),
        },
    ];
    let cfg = SubmapConfig {
        size: 3,
        ..SubmapConfig::default()
    };
    let mut b = SubmapBuilder::new(cfg, EgoMotionConfig::default(), radars);
    for k in 0..8 {
        for radar in 0..2 {
            // Radar 1 faces backwards: it sees static points receding.
            let v_radar = if radar == 0 {
                Vec3::new(10.0, 0.0, 0.0)
            } else {
                Vec3::new(-10.0, 0.0, 0.0)
            };
            let mut dets = static_detections(v_radar);
            // An oncoming car straight ahead.
            dets.push(Detection {
                p_radar: Vec3::new(20.0, 0.5, 0.0),
                v_r: -25.0,
                rcs: None,
            });
            let scan = RadarScan {
                radar,
                stamp: Stamp::from_secs_f64(k as f64 * 0.077 + radar as f64 * 0.01),
                detections: dets,
            };
            let rep = b.add_scan(&scan, Iso3::identity(), None).unwrap();
            assert_eq!(rep.dynamic, 1);
            assert_eq!(rep.kept, 30);
        }
    }
    assert_eq!(b.scan_count(), 6);
    let sub = b.build().unwrap();
    assert_eq!(sub.scans.iter().filter(|s| s.radar == 1).count(), 3);
    assert!(
        b.add_scan(
            &RadarScan {
                radar: 5,
                ..Default::default()
            },
            Iso3::identity(),
            None
        )
        .is_none()
    );
}

/// One radar 0.5 m above the body origin, looking ahead.
fn raised_radar() -> Vec<RadarModel> {
    vec![RadarModel {
        t_body_radar: iso3_from_xyz_rpy(0.0, 0.0, 0.5, 0.0, 0.0, 0.0),
        beta: 0.04,
        noise: RadarNoise::default(),
    }]
}

/// A radar 0.5 m up that sees the road 0.5 m below it and a sign 6 m above the ground besides the
/// static world at its own height: with `height_band` [0.3, 5.0] the submap keeps only the world and
/// counts the rest; with the default band it keeps all.
#[test]
fn the_height_band_keeps_what_stands_on_the_ground() {
    let radars = raised_radar();
    let v_radar = Vec3::new(10.0, 0.0, 0.0);
    let mut dets = static_detections(v_radar);
    let world = dets.len();
    for (x, z) in [(8.0, -0.5), (9.0, -0.5), (10.0, 5.5)] {
        let p = Vec3::new(x, 1.0, z);
        dets.push(Detection {
            p_radar: p,
            v_r: -p.normalize().dot(&v_radar),
            rcs: None,
        });
    }
    let scan = RadarScan {
        radar: 0,
        stamp: Stamp::from_secs_f64(1.0),
        detections: dets,
    };
    for (band, kept) in [([0.3, 5.0], world), ([-100.0, 100.0], world + 3)] {
        let cfg = SubmapConfig {
            height_band: band,
            ..SubmapConfig::default()
        };
        let mut b = SubmapBuilder::new(cfg, EgoMotionConfig::default(), radars.clone());
        let rep = b.add_scan(&scan, Iso3::identity(), None).unwrap();
        assert!(rep.doppler_fit);
        assert_eq!((rep.kept, rep.dynamic), (kept, 0), "band {band:?}");
        assert_eq!(rep.out_of_band, world + 3 - kept, "band {band:?}");
        let sub = b.build().unwrap();
        assert!(
            sub.points
                .iter()
                .all(|p| (band[0]..=band[1]).contains(&p.p.z))
        );
    }
}

/// The Doppler ego-motion fit uses the detections the height band cuts: a scan whose static world
/// is mostly road (cut by the band) and three posts, with a car moving among them, fits its
/// velocity on the road returns and drops the car, which the three posts alone could not tell apart.
#[test]
fn the_doppler_fit_uses_the_points_the_height_band_cuts() {
    let radars = raised_radar();
    let v_radar = Vec3::new(10.0, 0.0, 0.0);
    let radial = |p: Vec3, v: Vec3| -p.normalize().dot(&v);
    let mut dets: Vec<Detection> = static_detections(v_radar)
        .into_iter()
        .map(|d| {
            let p = d.p_radar - Vec3::new(0.0, 0.0, 0.5);
            Detection {
                p_radar: p,
                v_r: radial(p, v_radar),
                rcs: None,
            }
        })
        .collect();
    let road = dets.len();
    for y in [-4.0, 3.0, 6.0] {
        let p = Vec3::new(15.0, y, 0.0);
        dets.push(Detection {
            p_radar: p,
            v_r: radial(p, v_radar),
            rcs: None,
        });
    }
    // A car ahead driving away at 8 m/s.
    let car = Vec3::new(20.0, 1.0, 0.0);
    dets.push(Detection {
        p_radar: car,
        v_r: radial(car, v_radar - Vec3::new(8.0, 0.0, 0.0)),
        rcs: None,
    });
    let scan = RadarScan {
        radar: 0,
        stamp: Stamp::from_secs_f64(1.0),
        detections: dets,
    };
    let cfg = SubmapConfig {
        height_band: [0.3, 5.0],
        ..SubmapConfig::default()
    };
    let mut b = SubmapBuilder::new(cfg, EgoMotionConfig::default(), radars);
    let rep = b.add_scan(&scan, Iso3::identity(), None).unwrap();
    assert!(rep.doppler_fit);
    assert_eq!((rep.kept, rep.dynamic, rep.out_of_band), (3, 1, road));
}

/// Each point of an older scan gains the scatter that the anchor's pose error relative to that scan
/// gives it in the anchor frame, checked against poses drawn from that error; the anchor's own points
/// gain nothing; the submap's own frame takes the scans' shared error.
#[test]
fn the_motion_between_a_scan_and_the_anchor_spreads_its_points() {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let radar = RadarModel {
        t_body_radar: Iso3::identity(),
        beta: 0.04,
        noise: RadarNoise::default(),
    };
    let pose = |x: f64, y: f64, yaw: f64| iso3_from_xyz_rpy(x, y, 0.0, 0.0, 0.0, yaw);
    let (p0, pa) = (
        pose(100.0, 50.0, 0.3),
        pose(100.0 + 2.0 * 0.3f64.cos(), 50.0 + 2.0 * 0.3f64.sin(), 0.35),
    );
    let a = Mat3::new(0.1, 0.0, 0.0, 0.03, 0.08, 0.0, 0.002, -0.001, 0.006);
    let sigma = a * a.transpose();
    let mut b = SubmapBuilder::new(
        SubmapConfig::default(),
        EgoMotionConfig::default(),
        vec![radar],
    );
    b.add_scan(&static_scan(0.0, 20.0), p0, None).unwrap();
    b.add_scan(&static_scan(0.1, 20.0), pa, None).unwrap();
    let plain = b.build().unwrap();
    let mut spread = plain.clone();
    add_motion_noise(&mut spread, &[sigma, Mat3::zeros()]);
    // The frame takes the older scan's error times the square of its share of the points.
    let share = plain.points.iter().filter(|p| p.scan == 0).count() as f64 / plain.len() as f64;
    let (_, _, yaw_a) = pa.rotation.euler_angles();
    let turn = nalgebra::Rotation2::new(yaw_a);
    let mut in_anchor = Mat3::identity();
    in_anchor
        .fixed_view_mut::<2, 2>(0, 0)
        .copy_from(turn.inverse().matrix());
    let expected = in_anchor * sigma * in_anchor.transpose() * share * share;
    assert!((spread.motion - expected).abs().max() < 1e-12 * expected.abs().max());

    let chol = sigma.cholesky().unwrap().l();
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let draws: Vec<Vec3> = (0..20_000)
        .map(|_| chol * Vec3::from_fn(|_, _| StandardNormal.sample(&mut rng)))
        .collect();
    let ta = pa.translation.vector.xy();
    for (p, q) in plain.points.iter().zip(&spread.points) {
        let extra = (q.cov - p.cov).fixed_view::<2, 2>(0, 0).into_owned();
        if p.scan == 1 {
            assert!(extra.abs().max() < 1e-12, "the anchor's own point: {extra}");
            continue;
        }
        // The point in the odometry frame, seen from anchors drawn around the true one.
        let x = (pa * nalgebra::Point3::from(p.p)).coords.xy();
        let seen: Vec<Vec2> = draws
            .iter()
            .map(|d| nalgebra::Rotation2::new(yaw_a + d.z).inverse() * (x - ta - d.xy()))
            .collect();
        let mean = seen.iter().sum::<Vec2>() / seen.len() as f64;
        let scatter = seen
            .iter()
            .map(|s| (s - mean) * (s - mean).transpose())
            .sum::<nalgebra::Matrix2<f64>>()
            / seen.len() as f64;
        let scale = scatter.abs().max();
        assert!(
            (scatter - extra).abs().max() < 0.05 * scale,
            "point at {:?}: {scatter} drawn, {extra} added",
            p.p.xy()
        );
    }
}

/// The steps' own errors, each turned to the end by the heading error it carries, add up to the
/// motion between two samples of a dead-reckoned track; a stamp halfway through a step takes half of
/// it, and an odometry without uncertainty gives none.
#[test]
fn the_steps_between_two_samples_add_up_to_their_motion() {
    use crate::odometry::integrate::{PlanarIntegrator, StepMotion};
    let mut track = PlanarIntegrator::new(Stamp(0));
    let mut buf = OdometryBuffer::new(OdometryConfig::default());
    buf.push(Stamp(0), track.pose(), Some(track.noise(0.0)))
        .unwrap();
    let mut samples = vec![track];
    for k in 1..=12 {
        let m = StepMotion {
            velocity: Vec2::new(15.0, 0.2),
            dtheta: 0.01 * k as f64,
            covariance: Mat3::from_diagonal(&Vec3::new(0.01, 0.02, 1e-5)),
            dtheta_per_bias: 0.0,
        };
        track.step(Stamp::from_secs_f64(0.1 * k as f64), &m);
        buf.push(track.stamp(), track.pose(), Some(track.noise(0.0)))
            .unwrap();
        samples.push(track);
    }
    let xy = |i: &PlanarIntegrator| i.pose2().translation.vector;
    let (from, to) = (&samples[3], &samples[12]);
    let whole = to.noise(0.0).since(&from.noise(0.0), xy(to) - xy(from));
    let got = buf.motion_to(&[from.stamp()], to.stamp()).unwrap()[0];
    assert!(
        (got - whole).abs().max() < 1e-9 * whole.abs().max(),
        "{got} against {whole}"
    );

    let half = Stamp::from_secs_f64(1.15);
    let [last, between] = buf
        .motion_to(&[samples[11].stamp(), half], to.stamp())
        .unwrap()[..]
    else {
        unreachable!()
    };
    assert!((between - last * 0.5).abs().max() < 1e-9 * last.abs().max());

    let mut plain = OdometryBuffer::new(OdometryConfig::default());
    plain.push(Stamp(0), Iso3::identity(), None).unwrap();
    plain
        .push(Stamp::from_secs_f64(0.1), Iso3::identity(), None)
        .unwrap();
    assert!(
        plain
            .motion_to(&[Stamp(0)], Stamp::from_secs_f64(0.1))
            .is_none()
    );
}
