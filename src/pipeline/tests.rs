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
