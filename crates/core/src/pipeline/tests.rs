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

/// Keyframe `id` of session `session` of robot `robot` on the wire, its node knowing `fleet`: fifty
/// points on a slanted line, at the origin of that robot's odometry, `id` metres along its path.
fn foreign_keyframe(
    robot: i32,
    session: u32,
    id: u64,
    place: &crate::place::PlaceConfig,
    fleet: &FleetState,
) -> Input {
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
        place: crate::place::PlaceDescriptor::from_points(&pts, place),
    };
    Input::Keyframe(Box::new(wire::encode(
        robot,
        &record,
        fleet,
        0,
        "base_link",
    )))
}

/// A received keyframe's alignment to this robot's session becomes, inverted, the prior for closures
/// to the sender's session (by its local number); alignments to other robots or sessions are not
/// this node's. A node shares its own accepted alignments with its keyframes by the other robot's id
/// and session.
#[test]
fn another_robots_alignment_to_this_session_is_taken_inverted() {
    let mut p = Pipeline::new(Config::default()).expect("config");
    p.set_robot(1);
    let place = p.config().place.clone();
    let t = crate::math::Iso2::new(crate::math::Vec2::new(120.0, -40.0), 2.0);
    let shared = |robot: i32, session: u32| SharedAlignment {
        robot,
        session,
        alignment: crate::loop_closure::Alignment {
            t,
            path: 300.0,
            match_path: 80.0,
        },
    };
    let fleet = FleetState {
        heard: vec![(1, 0)],
        alignments: vec![shared(7, 0), shared(1, 3), shared(1, 0)],
    };
    p.push(&foreign_keyframe(5, 2, 4, &place, &fleet));
    let local = p
        .db()
        .foreign()
        .session(&crate::keyframe_db::Origin {
            robot: 5,
            session: 2,
            id: 4,
        })
        .expect("the sender's session has a local number");
    let got = p.loops.state().shared();
    assert_eq!(got.len(), 1, "{got:?}");
    let a = got[&local];
    assert_eq!((a.path, a.match_path), (80.0, 300.0));
    let back = a.t * t;
    assert!(back.translation.vector.norm() < 1e-9 && back.rotation.angle().abs() < 1e-12);
    let own = crate::loop_closure::Alignment {
        t,
        path: 50.0,
        match_path: 60.0,
    };
    p.loops.state_mut().set_alignment(local, own);
    let state = p.fleet_state();
    assert_eq!(state.alignments.len(), 1);
    let sent = state.alignments[0];
    assert_eq!((sent.robot, sent.session, sent.alignment), (5, 2, own));
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
        foreign_keyframe(robot, session, id, &place, &FleetState::default())
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
    let mut bad = wire::encode(
        5,
        &p.db().get(0).unwrap().clone(),
        &FleetState::default(),
        0,
        "base_link",
    );
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

/// A cloud without the configured velocity field is dropped as `bad_cloud` with a detail naming the
/// field and the cloud's fields; every such cloud is counted, all under one cause (logged once).
#[test]
fn a_missing_field_is_one_cause_counted_per_cloud() {
    use crate::cloud::{CloudLayout, encode_detections};
    use crate::msgs::std_msgs::Header;
    let mut cfg = Config::default();
    if let Some(r) = cfg.radars.get_mut("front") {
        r.fields.velocity = "v".into();
    }
    let mut p = Pipeline::new(cfg).expect("config");
    let det = Detection {
        p_radar: Vec3::new(10.0, 1.0, 0.0),
        v_r: -1.0,
        rcs: Some(1.0),
    };
    let mut details = Vec::new();
    for k in 0..5 {
        let header = Header {
            stamp: Stamp::from_secs_f64(1.0 + 0.1 * f64::from(k)).into(),
            frame_id: "radar".into(),
        };
        let cloud = encode_detections(&[det], &CloudLayout::radar_f32(), header).unwrap();
        for e in p.push(&Input::Radar { radar: 0, cloud }) {
            if let Event::Dropped { reason, detail } = e {
                assert_eq!(reason, DropReason::BadCloud);
                details.push(detail);
            }
        }
    }
    assert_eq!(details.len(), 5);
    assert_eq!(
        details[0],
        "radar `front`: field `v` (velocity) is not in the cloud; its fields: x FLOAT32, y FLOAT32, \
         z FLOAT32, v_r FLOAT32, rcs FLOAT32"
    );
    assert_eq!(p.stats().dropped[&DropReason::BadCloud], 5);
    let causes = p.stats().drop_causes.counts();
    assert_eq!(causes.len(), 1, "{causes:?}");
    assert_eq!(causes[&format!("bad_cloud: {}", details[0])], 5);
}
