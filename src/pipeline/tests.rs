//! Unit tests of the pipeline's input side: stamps, duplicates, empty scans.

use super::*;
use crate::math::Vec3;
use crate::radar::Detection;

fn scan(stamp: f64) -> Input {
    Input::Scan(RadarScan {
        radar: 0,
        stamp: Stamp::from_secs_f64(stamp),
        detections: vec![Detection {
            p_radar: Vec3::new(10.0, 1.0, 0.0),
            v_r: -1.0,
            rcs: None,
        }],
    })
}

fn odom(p: &mut Pipeline, t: f64) -> Vec<Event> {
    p.push(&Input::Odometry {
        stamp: Stamp::from_secs_f64(t),
        t_odom_body: Iso3::identity(),
    })
}

fn dropped(events: &[Event], reason: DropReason) -> bool {
    events
        .iter()
        .any(|e| matches!(e, Event::Dropped { reason: r, .. } if *r == reason))
}

#[test]
fn backwards_stamps_are_dropped_until_a_run_makes_a_restart() {
    let mut p = Pipeline::new(Config::default()).expect("default config");
    p.set_restart_after(3);
    odom(&mut p, 100.0);
    p.push(&scan(100.0));
    // Two stale inputs: dropped, nothing reset.
    assert!(dropped(&odom(&mut p, 50.0), DropReason::StampBackwards));
    assert!(dropped(&p.push(&scan(50.1)), DropReason::StampBackwards));
    assert_eq!(p.stats().time_resets, 0);
    // A fresh input ends the run; two more stale ones are dropped again.
    assert!(!dropped(&odom(&mut p, 100.1), DropReason::StampBackwards));
    odom(&mut p, 10.0);
    odom(&mut p, 10.1);
    assert_eq!(p.stats().dropped[&DropReason::StampBackwards], 4);
    // The third in a row is a restart.
    let ev = odom(&mut p, 10.2);
    assert!(ev.iter().any(|e| matches!(e, Event::TimeReset { .. })));
    assert_eq!(p.stats().time_resets, 1);
    // The default (as `dc_loc run`): the first stale input restarts.
    let mut q = Pipeline::new(Config::default()).expect("default config");
    odom(&mut q, 100.0);
    odom(&mut q, 10.0);
    assert_eq!(q.stats().time_resets, 1);
    assert!(!q.stats().dropped.contains_key(&DropReason::StampBackwards));
}

#[test]
fn a_second_scan_with_the_same_stamp_is_dropped_and_empty_scans_are_counted() {
    let mut p = Pipeline::new(Config::default()).expect("default config");
    assert!(!dropped(&p.push(&scan(5.0)), DropReason::DuplicateStamp));
    let Input::Scan(mut empty) = scan(5.0) else {
        unreachable!()
    };
    empty.detections.clear();
    let ev = p.push(&Input::Scan(empty));
    assert!(dropped(&ev, DropReason::DuplicateStamp));
    assert!(ev.iter().any(|e| matches!(e, Event::EmptyScan { .. })));
    assert_eq!(p.stats().empty_scans, 1);
    assert!(!dropped(&p.push(&scan(5.1)), DropReason::DuplicateStamp));
    assert_eq!(p.stats().dropped[&DropReason::DuplicateStamp], 1);
}

/// Another robot's keyframe: added once, refused beyond its robot's budget and when it carries this
/// robot's id from another session, each counted under the robot; this robot's own echo is ignored.
#[test]
fn other_robots_keyframes_are_counted_by_robot() {
    let mut cfg = Config::default();
    cfg.map.max_keyframes_per_robot = 2;
    let mut p = Pipeline::new(cfg).expect("config");
    p.set_robot(1);
    let place = p.config().place.clone();
    let keyframe = |robot: i32, session: u32, id: u64| {
        let pts: Vec<crate::math::Vec2> = (0..50)
            .map(|i| crate::math::Vec2::new(5.0 + i as f64, (i % 7) as f64))
            .collect();
        let record = KeyframeRecord {
            id,
            session,
            stamp: Stamp::from_secs_f64(10.0 + id as f64),
            t_odom_body: crate::math::Iso2::identity(),
            odom_pose: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            path_distance: id as f64,
            points: pts
                .iter()
                .filter_map(|&q| crate::keyframe_db::quantise_point(q))
                .collect(),
            covs: vec![[40, 40, 0]; 50],
            rays: Vec::new(),
            place: crate::place::PlaceDescriptor::from_points(&pts, &place),
        };
        Input::Keyframe(Box::new(wire::encode(robot, &record, &[], 0, "base_link")))
    };
    for id in 0..3 {
        p.push(&keyframe(5, 0, id));
    }
    p.push(&keyframe(5, 0, 1));
    assert!(p.push(&keyframe(1, 0, 0)).is_empty(), "own echo");
    assert!(dropped(
        &p.push(&keyframe(1, 9, 0)),
        DropReason::KeyframeSameRobotId
    ));
    let c = p.stats().robots[&5];
    assert_eq!((c.received, c.added, c.duplicates, c.refused), (4, 2, 1, 1));
    assert_eq!(p.stats().dropped[&DropReason::KeyframeOverBudget], 1);
    assert_eq!(p.db().len(), 2);
    assert_eq!(p.stats().robots[&1].refused, 1);
    let mut bad = wire::encode(5, &p.db().get(0).unwrap().clone(), &[], 0, "base_link");
    bad.covariances.pop();
    assert!(dropped(
        &p.push(&Input::Keyframe(Box::new(bad))),
        DropReason::BadKeyframe
    ));
    assert_eq!(
        p.stats().robots[&5].received,
        4,
        "a malformed keyframe names no robot reliably"
    );
}
