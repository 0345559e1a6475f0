//! Revisit detection end to end on a simulated drive, judged against its ground truth: the five-radar
//! nuScenes layout, Gaussian noise, 1 % odometry drift (1.8 % measured with the yaw-rate bias), a second
//! lap in the same direction. Every published closure must be within 2 m of the truth (no false loop
//! closure), and the recall bars hold. Also the command line of `dc_loc revisits`.

use dc_loc::eval::judge::CHI2_3_99;
use dc_loc::eval::revisits::{RevisitScenario, evaluate_scenario};
use dc_loc::sim::{NoiseModel, RadarPreset, WorldFamily};
use std::process::Command;

#[test]
fn five_radars_same_direction_one_percent_drift_no_false_closure() {
    let scenario = RevisitScenario::new(RadarPreset::Nuscenes, NoiseModel::Gaussian, 0.01, false);
    let r = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    eprintln!(
        "{}: {:?}; missed {:?}; rejected {:?}",
        r.scenario, r.same, r.missed, r.rejected
    );
    assert!(r.measured_drift > 0.01, "drift {}", r.measured_drift);
    assert!(r.same.opportunities > 300, "{:?}", r.same);
    assert_no_false_closure(&r);
    assert!(r.same.recall() >= 0.95, "recall {:?}", r.same);
    // Accuracy of what is published: the node issue's bar for nearly all.
    assert!(
        r.same.within_accuracy_bar as f64 >= 0.97 * r.same.published as f64,
        "{:?}",
        r.same
    );
}

/// Keyframes searched again once closures to a session are confirmed (`loop.backfill_per_keyframe`)
/// close revisits that waited for the confirmation, walking back along the route
/// (`loop.backfill_horizon`), and every closure they add is true. Five radars, Student-t noise, 1 %
/// drift: the first closures are confirmed about 340 m into the revisit (measured: recall 99.3 %
/// with the defaults, 89.0 % when the searches again reach 150 m back, 83.6 % without them).
#[test]
fn searching_keyframes_again_after_a_confirmation_adds_true_closures() {
    let scenario = RevisitScenario::new(RadarPreset::Nuscenes, NoiseModel::StudentT, 0.01, false);
    let with = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    let short =
        evaluate_scenario(&scenario, |c| c.r#loop.backfill_horizon = 150.0).expect("scenario runs");
    let without = evaluate_scenario(&scenario, |c| c.r#loop.backfill_per_keyframe = 0)
        .expect("scenario runs");
    eprintln!(
        "with {:?}; 150 m {:?}; without {:?}",
        with.same, short.same, without.same
    );
    for r in [&with, &short, &without] {
        assert_no_false_closure(r);
    }
    assert!(with.same.recall() >= 0.95, "{:?}", with.same);
    assert!(
        with.same.recall() > short.same.recall() && short.same.recall() >= without.same.recall(),
        "with {:?}, 150 m {:?}, without {:?}",
        with.same,
        short.same,
        without.same
    );
}

/// One forward radar driving the second lap the other way sees what lay behind it on the first: no
/// closure may be published there (before `loop.minimum_common_view`, 5 of 12 were false).
#[test]
fn one_forward_radar_reverse_lap_no_false_closure() {
    let scenario = RevisitScenario::new(RadarPreset::Carla, NoiseModel::Gaussian, 0.01, true);
    let r = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    eprintln!("{}: {:?}; rejected {:?}", r.scenario, r.reverse, r.rejected);
    assert!(r.reverse.opportunities > 300, "{:?}", r.reverse);
    assert_no_false_closure(&r);
    assert!(
        r.rejected.get("no_common_view").copied().unwrap_or(0) > 0,
        "{:?}",
        r.rejected
    );
}

/// One forward radar, Gamma noise, 1 % drift: a closure that agrees with a fresh alignment is
/// published alone only where the dense stage started at the alignment's prediction ends
/// (`loop.maximum_ambiguity`); without that test a closure slid 4.57 m along its street was
/// published (with the Doppler speed scale of `submap.speed_scale_bound`).
#[test]
fn one_forward_radar_agreeing_closures_are_where_the_prediction_leads() {
    let scenario = RevisitScenario::new(RadarPreset::Carla, NoiseModel::Gamma, 0.01, false);
    let r = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    eprintln!("{}: {:?}; rejected {:?}", r.scenario, r.same, r.rejected);
    assert!(r.same.opportunities > 300, "{:?}", r.same);
    assert_no_false_closure(&r);
    assert!(r.same.recall() >= 0.9, "{:?}", r.same);
}

/// Five radars, Gamma noise, 3 % drift, the second lap the same way: closures between keyframes more
/// than 60 m apart are registered from returns 100-200 m away, which the two keyframes see from the two
/// ends of the street between them, and their errors grow with the distance (up to about 1 m). The
/// covariance covers them with the heading drift within the submaps (`loop.drift_yaw_rate`) and the
/// returns' offsets along their rays (`registration.dense.range_offset_std`): at most 3 of them lie
/// above the chi-square(3) 99 % bound (measured: 1 of 35; 35 of 37 without the two shares).
#[test]
fn long_baseline_closures_are_covered_by_their_covariance() {
    let scenario = RevisitScenario::new(RadarPreset::Nuscenes, NoiseModel::Gamma, 0.03, false);
    let r = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    assert_no_false_closure(&r);
    let far: Vec<_> = r.closures.iter().filter(|c| c.distance > 60.0).collect();
    let above: Vec<_> = far.iter().filter(|c| c.nees > CHI2_3_99).collect();
    eprintln!(
        "{}: {} closures beyond 60 m, {} above the bound",
        r.scenario,
        far.len(),
        above.len()
    );
    assert!(far.len() >= 20, "{} beyond 60 m", far.len());
    assert!(above.len() <= 3, "{above:?}");
}

/// Five radars at 5 % drift (5.9 % measured, beyond the drift model), Student-t noise: weak matches
/// of a street 147 m away used to confirm each other; `loop.confirmation_overlap` wants one strong
/// match among them. With the offset along the rays held at its prior in the covariance the gates
/// already refuse those matches, so the drive publishes no false closure with or without the rule
/// (measured: 447 of 447 closed either way); the rule stays as the guard where the covariance does
/// not catch them. The session confirms itself within the first lap, and by the second lap the
/// yaw-rate bias has turned that alignment as far as odometry: with no fresh alignment to vouch, the
/// second lap's closures are held for confirmation beyond the drift model and the lap closes.
#[test]
fn weak_matches_alone_do_not_confirm_a_session() {
    let scenario = RevisitScenario::new(RadarPreset::Nuscenes, NoiseModel::StudentT, 0.05, false);
    let with = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    let without = evaluate_scenario(&scenario, |c| c.r#loop.confirmation_overlap = 0.0)
        .expect("scenario runs");
    eprintln!("with {:?}; without {:?}", with.same, without.same);
    for r in [&with, &without] {
        assert_no_false_closure(r);
        assert!(r.same.recall() >= 0.9, "{:?}", r.same);
    }
}

/// One forward radar at 3 % drift on the dev city's seed 2: the yaw-rate bias (0.3 deg/s) puts
/// odometry 100-300 m off by the second lap, beyond the drift model. Refused as inconsistent
/// (`loop.confirm_beyond_drift` off), the session's first closures never come and nothing is
/// published; held for `loop.foreign_confirmations` across a turn, as closures to another session
/// are (the default), they are confirmed, and the lap closes without a false closure (measured: 0
/// and 94.2 %).
#[test]
fn first_closures_beyond_the_drift_model_are_confirmed_as_between_sessions() {
    let scenario = RevisitScenario {
        seed: 2,
        ..RevisitScenario::new(RadarPreset::Carla, NoiseModel::Gaussian, 0.03, false)
    };
    let with = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    let without = evaluate_scenario(&scenario, |c| c.r#loop.confirm_beyond_drift = false)
        .expect("scenario runs");
    eprintln!("with {:?}; without {:?}", with.same, without.same);
    assert!(with.measured_drift > 0.03, "drift {}", with.measured_drift);
    assert_eq!(without.same.published, 0, "{:?}", without.same);
    assert_no_false_closure(&with);
    assert!(with.same.recall() >= 0.9, "{:?}", with.same);
}

/// One forward radar at 5 % drift on the dev city: refusing what lies beyond the drift model leaves
/// only candidates where the drifted odometry predicts them, and there streets 600-700 m away look
/// alike and confirm each other (measured: 8 false closures). Confirming the true first closures
/// beyond the drift model gives the session an alignment that refuses them (0 false, 93.0 %).
#[test]
fn the_true_alignment_beyond_the_drift_model_keeps_out_look_alikes_within_it() {
    let scenario = RevisitScenario::new(RadarPreset::Carla, NoiseModel::Gaussian, 0.05, false);
    let with = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    let without = evaluate_scenario(&scenario, |c| c.r#loop.confirm_beyond_drift = false)
        .expect("scenario runs");
    eprintln!("with {:?}; without {:?}", with.same, without.same);
    assert!(
        without.closures.iter().any(|c| c.translation_error > 100.0),
        "{:?}",
        without.same
    );
    assert_no_false_closure(&with);
    assert!(with.same.recall() >= 0.9, "{:?}", with.same);
}

/// The held-out industrial blocks, one forward radar, Gamma noise, 3 % drift: near the end of the
/// first lap a parallel street 318 m away matches seven keyframes in a row, beyond the drift model
/// but within its reach, and the matches agree with each other. Confirmations beyond the drift model
/// must span a turn, which the parallel street does not follow: no false closure, and the lap's true
/// closures, which turn corners, are confirmed (measured: 94.2 %).
#[test]
fn a_parallel_street_does_not_confirm_itself_beyond_the_drift_model() {
    let scenario = RevisitScenario {
        noise: NoiseModel::Gamma,
        drift: 0.03,
        ..held_out(1, RadarPreset::Carla, false)
    };
    assert_eq!(scenario.world, WorldFamily::Industrial);
    let r = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    eprintln!("{:?}", r.same);
    assert_no_false_closure(&r);
    assert!(r.same.recall() >= 0.9, "{:?}", r.same);
}

/// The held-out worlds (`dc_loc revisits --set test`: suburb, industrial, arterial, parking, each with
/// its own seed; no parameter was tuned on them), Gaussian noise, 1 % drift, same direction: every
/// closure true; recall at least 95 % with five radars and 90 % with one forward radar; covariances a
/// pose graph can trust: mean NEES at most 4 and at most 3 % of the closures above the chi-square(3)
/// 99 % bound. Without the bias probe (`registration.dense.bias_probe`) the industrial world's
/// one-radar closures have 8.7 % above the bound.
#[test]
fn held_out_worlds_true_closures_and_honest_covariances() {
    for w in dc_loc::sim::families::TEST {
        for (radars, min_recall) in [(RadarPreset::Nuscenes, 0.95), (RadarPreset::Carla, 0.9)] {
            let mut scenario = RevisitScenario::new(radars, NoiseModel::Gaussian, 0.01, false);
            (scenario.world, scenario.seed) = (w.family, w.seed);
            let r = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
            eprintln!("{}: {:?}; NEES {:?}", r.scenario, r.same, r.nees);
            assert!(r.same.opportunities > 300, "{}: {:?}", r.scenario, r.same);
            assert_no_false_closure(&r);
            assert!(
                r.same.recall() >= min_recall,
                "{}: {:?}",
                r.scenario,
                r.same
            );
            assert!(r.nees.count > 300, "{}: {:?}", r.scenario, r.nees);
            assert_covariance_holds(&r);
        }
    }
}

/// A 4D imaging radar (`--radars imaging`: elevation, road returns, 600-700 detections a scan) with
/// the simulator's parameter file, which cuts the road and what passes overhead out of the submaps
/// (`submap.height_band` [0.3, 5.0] m): on the held-out suburb every closure is true, recall and the
/// covariance hold; on the dev city with every height kept the road returns land in the plane as
/// clutter: fewer revisits close (measured 95.3 % against 93.0 %) and some closures miss the
/// accuracy bar (2 of 403), none with the band.
#[test]
fn an_imaging_radar_closes_revisits_with_the_road_cut_out() {
    let r = evaluate_scenario(&held_out(0, RadarPreset::Imaging, false), |_| {})
        .expect("scenario runs");
    eprintln!("{}: {:?}; NEES {:?}", r.scenario, r.same, r.nees);
    assert!(r.same.opportunities > 300, "{:?}", r.same);
    assert_no_false_closure(&r);
    assert!(r.same.recall() >= 0.95, "{:?}", r.same);
    assert_covariance_holds(&r);

    let dev = RevisitScenario::new(RadarPreset::Imaging, NoiseModel::Gaussian, 0.01, false);
    let cut = evaluate_scenario(&dev, |_| {}).expect("scenario runs");
    let all =
        evaluate_scenario(&dev, |c| c.submap.height_band = [-100.0, 100.0]).expect("scenario runs");
    eprintln!("band: {:?}; every height: {:?}", cut.same, all.same);
    assert_no_false_closure(&cut);
    assert_no_false_closure(&all);
    assert!(cut.same.recall() >= 0.85, "{:?}", cut.same);
    assert!(
        cut.same.recall() > all.same.recall(),
        "{:?} vs {:?}",
        cut.same,
        all.same
    );
    assert_eq!(
        cut.same.within_accuracy_bar, cut.same.published,
        "{:?}",
        cut.same
    );
}

/// The imaging radar on the held-out industrial blocks: it resolves the long walls and the parked
/// cars in hundreds of points, which pull the dense stage's pose along the street by up to a metre
/// where they outnumber the poles and corners. The score probe (`registration.dense.score_probe`)
/// widens the covariance by the distance to the fit score's peak, which counts every object once:
/// every closure true, mean NEES within 4 and at most 3 % above the chi-square(3) 99 % bound
/// (measured 1.6 and 0.2 %); without it over twice that share (measured 10.9 %). The gates judge
/// without the probe's share, so both publish the same closures.
#[test]
fn the_score_probe_covers_the_pull_of_the_imaging_radar_s_dense_objects() {
    let scenario = held_out(1, RadarPreset::Imaging, false);
    let probed = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    let bare = evaluate_scenario(&scenario, |c| c.registration.dense.score_probe = false)
        .expect("scenario runs");
    eprintln!(
        "probe: {:?} {:?}; without: {:?}",
        probed.same, probed.nees, bare.nees
    );
    assert_no_false_closure(&probed);
    assert!(probed.same.recall() >= 0.85, "{:?}", probed.same);
    assert!(probed.nees.mean <= 4.0, "{:?}", probed.nees);
    assert!(probed.nees.share_above_99() <= 0.03, "{:?}", probed.nees);
    assert!(bare.nees.share_above_99() > 0.06, "{:?}", bare.nees);
    assert_eq!(probed.same.closed, bare.same.closed);
}

/// Radars whose extrinsics are known to 1.5 degrees and 5 cm (`--calibration-error 1.5,0.05`), five
/// radars on the held-out suburb, reverse lap: the closures stay true, but the registration's own
/// covariance does not know the calibration, and more than a tenth of the closures across the street
/// fall outside its 99 % bound (measured 16.5 %). Declared as `loop.extrinsic_std`, the calibration's
/// share brings them back within the bar of 5 % (measured 1.7 %).
#[test]
fn declared_extrinsic_uncertainty_covers_a_calibration_error() {
    let mut scenario = held_out(0, RadarPreset::Nuscenes, true);
    scenario.calibration = dc_loc::eval::revisits::CalibrationError {
        yaw_deg: 1.5,
        offset: 0.05,
    };
    let blind = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    let declared = evaluate_scenario(&scenario, |c| {
        c.r#loop.extrinsic_std = [0.05, 1.5_f64.to_radians()]
    })
    .expect("scenario runs");
    eprintln!("without {:?}; with {:?}", blind.nees, declared.nees);
    for r in [&blind, &declared] {
        assert_no_false_closure(r);
        assert!(r.reverse.recall() >= 0.8, "{:?}", r.reverse);
    }
    assert!(blind.nees.share_above_99() > 0.1, "{:?}", blind.nees);
    assert!(
        declared.nees.share_above_99() <= 0.05,
        "{:?}",
        declared.nees
    );
}

/// One forward radar whose clock runs 30 ms ahead of the odometry's (`--time-offset 30`) on the
/// held-out suburb: the closures stay true, but each submap lies `speed x 30 ms` along the heading
/// from its keyframe, and with the laps at 72 and 40 km/h many closures fall outside the registration's
/// own 99 % bound. Declared as `loop.clock_std`, the clocks' share brings them within 3 %, mean NEES
/// within 4, and no closure is lost.
#[test]
fn declared_clock_uncertainty_covers_a_radar_clock_offset() {
    let mut scenario = held_out(0, RadarPreset::Carla, false);
    scenario.time_offset = 0.03;
    let blind = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    let declared =
        evaluate_scenario(&scenario, |c| c.r#loop.clock_std = 0.03).expect("scenario runs");
    eprintln!("without {:?}; with {:?}", blind.nees, declared.nees);
    for r in [&blind, &declared] {
        assert_no_false_closure(r);
        assert!(r.same.recall() >= 0.85, "{:?}", r.same);
    }
    assert_eq!(blind.same.closed, declared.same.closed);
    assert!(blind.nees.share_above_99() > 0.1, "{:?}", blind.nees);
    assert!(
        declared.nees.share_above_99() <= 0.03,
        "{:?}",
        declared.nees
    );
    assert!(declared.nees.mean <= 4.0, "{:?}", declared.nees);
}

/// Wheels that slip twice a km (each time 5-30 % more distance for 0.5-2 s) on the held-out
/// industrial world, one forward radar: the Doppler speed scale (`submap.speed_scale_bound`) takes the
/// over-read out of each submap, so no closure is false and the covariances hold (mean NEES within 4,
/// at most 5 % above the 99 % bound). Bounded at 0.1, the correction refuses the slipping submaps,
/// which keep their stretch: the mean NEES is about three times as high.
#[test]
fn the_doppler_speed_scale_takes_out_wheel_slip() {
    let mut scenario = held_out(1, RadarPreset::Carla, false);
    scenario.wheel_slip = 2.0;
    let corrected = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
    let narrow =
        evaluate_scenario(&scenario, |c| c.submap.speed_scale_bound = 0.1).expect("scenario runs");
    eprintln!(
        "bound 0.5: {:?} {:?}; bound 0.1: {:?} {:?}",
        corrected.same, corrected.nees, narrow.same, narrow.nees
    );
    assert_no_false_closure(&corrected);
    assert!(corrected.same.recall() >= 0.9, "{:?}", corrected.same);
    assert!(corrected.nees.mean <= 4.0, "{:?}", corrected.nees);
    assert!(
        corrected.nees.share_above_99() <= 0.05,
        "{:?}",
        corrected.nees
    );
    assert!(
        narrow.nees.mean > 2.0 * corrected.nees.mean,
        "{:?} {:?}",
        narrow.nees,
        corrected.nees
    );
}

/// The same slips on the held-out arterial road, whose guard rail posts repeat every 4 m, so a
/// stretched submap fits a slid one: slips that cover part of a submap are taken out step by step
/// between its scans, and with five radars or one no closure is false and at most 5 % lie above the
/// 99 % bound.
#[test]
fn a_slip_in_part_of_a_submap_slides_no_closure_on_the_arterial_road() {
    for radars in [RadarPreset::Nuscenes, RadarPreset::Carla] {
        let mut scenario = held_out(2, radars, false);
        scenario.wheel_slip = 2.0;
        let r = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
        eprintln!("{}: {:?}; NEES {:?}", r.scenario, r.same, r.nees);
        assert_no_false_closure(&r);
        assert!(r.same.recall() >= 0.85, "{}: {:?}", r.scenario, r.same);
        assert!(
            r.nees.share_above_99() <= 0.05,
            "{}: {:?}",
            r.scenario,
            r.nees
        );
    }
}

/// The highway (`dc_loc revisits --world highway --seed 105`), one forward radar, 1 % drift, the same
/// direction, Gaussian and Student-t noise: its guard rail posts repeat every 2 m, and a registration
/// slid by one post period, or by a dozen, fits as well as the true one. A closure slid by a post
/// period, confirmed by a neighbour whose alignment agrees to a few metres, would be 2 m off with 5 cm
/// sigmas; confirmations test the closures against each other under their own covariances. Two
/// closures slid by 24-30 m, held on either side of a stretch the accepted alignment kept vouching
/// for, would confirm each other and replace it; a newer closure on that alignment drops them. None is
/// false and the covariances hold (mean NEES <= 4, at most 3 % above the 99 % bound).
#[test]
fn the_highway_publishes_no_closure_slid_by_a_post_period() {
    for noise in [NoiseModel::Gaussian, NoiseModel::StudentT] {
        let mut scenario = RevisitScenario::new(RadarPreset::Carla, noise, 0.01, false);
        scenario.world = WorldFamily::Highway;
        scenario.seed = 105;
        let r = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
        eprintln!("{}: {:?}; NEES {:?}", r.scenario, r.same, r.nees);
        assert_no_false_closure(&r);
        assert!(r.same.recall() >= 0.7, "{}: {:?}", r.scenario, r.same);
        assert_covariance_holds(&r);
    }
}

/// The corridor (`dc_loc revisits --world corridor --seed 106`), 1 % drift, the same direction,
/// Gaussian noise: two 1 km straights between flat walls, where the walls fix the lateral position
/// and the heading and little but rare gaps, side streets and street lights fixes the position along
/// the road. A registration slid along the walls fits nearly as well as the true one, and the published
/// covariances are long along the road. No closure is false; with five radars
/// at least 90 % of the opportunities are closed and the covariances hold (mean NEES <= 4, at most 3 %
/// above the 99 % bound); with one forward radar at least 40 % are closed, mean NEES <= 4, at most 5 %
/// above the bound.
#[test]
fn the_corridor_publishes_no_closure_slid_along_its_walls() {
    for (radars, min_recall, max_above) in [
        (RadarPreset::Nuscenes, 0.9, 0.03),
        (RadarPreset::Carla, 0.4, 0.05),
    ] {
        let mut scenario = RevisitScenario::new(radars, NoiseModel::Gaussian, 0.01, false);
        scenario.world = WorldFamily::Corridor;
        scenario.seed = 106;
        let r = evaluate_scenario(&scenario, |_| {}).expect("scenario runs");
        eprintln!("{}: {:?}; NEES {:?}", r.scenario, r.same, r.nees);
        assert_no_false_closure(&r);
        assert!(r.same.opportunities > 400, "{}: {:?}", r.scenario, r.same);
        assert!(
            r.same.recall() >= min_recall,
            "{}: {:?}",
            r.scenario,
            r.same
        );
        assert!(r.nees.mean <= 4.0, "{}: {:?}", r.scenario, r.nees);
        assert!(
            r.nees.share_above_99() <= max_above,
            "{}: {:?}",
            r.scenario,
            r.nees
        );
    }
}

/// A fleet of three robots on the city (each one lap from its own start, every other one the other
/// way, an hour apart, each with its own odometry frame and noise), five radars, 1 % drift: the robots
/// find each other's keyframes by place, and from their first closure to another robot on, where
/// that closure (then the accepted alignment) puts them. Every closure between robots is correct, at
/// least 90 % of the same-direction and 85 % of the opposite-direction opportunities are closed
/// (measured: 99.8 % and 89.4 %; searched by place alone, 2.4 % of the opposite), no pair is published
/// by two nodes, and the covariances hold (mean NEES <= 4, at most 3 % above the 99 % bound).
#[test]
fn a_fleet_closes_loops_between_robots() {
    let r = fleet_of_three(RevisitScenario::new(
        RadarPreset::Nuscenes,
        NoiseModel::Gaussian,
        0.01,
        false,
    ));
    assert_no_false_closure(&r);
    assert!(r.same.opportunities > 300, "{:?}", r.same);
    assert!(r.same.recall() >= 0.9, "{:?}", r.same);
    assert!(r.reverse.recall() >= 0.85, "{:?}", r.reverse);
    assert_covariance_holds(&r);
}

/// A fleet of three on the dev city's seed 2, five radars, Student-t noise, 3 % drift: robot 0
/// registers closures onto a street of robot 1's 600 m away, turned by half a turn, which agree with
/// each other and, confirmed, replaced robot 0's stale alignment to robot 1 (measured: 4 false closures
/// among 499). Tested against the alignments to robot 1 that robot 0 knows (its own, stale, and the one
/// robot 1 found a moment before and sends with its keyframes), each carried to the pair with the
/// odometry drift along both robots' paths, they lie beyond three times the drift model's bounds and
/// are refused: every closure between the robots is correct.
#[test]
fn a_look_alike_street_far_from_every_known_alignment_stays_out_of_a_fleet() {
    let r = fleet_of_three(RevisitScenario {
        seed: 2,
        ..RevisitScenario::new(RadarPreset::Nuscenes, NoiseModel::StudentT, 0.03, false)
    });
    assert_no_false_closure(&r);
    assert!(r.same.recall() >= 0.9, "{:?}", r.same);
    assert!(r.reverse.published > 30, "{:?}", r.reverse);
}

/// A fleet of three on the held-out suburb, five radars, 1 % drift: the middle robot drives the loop
/// the other way. From a robot's first closure to another robot's session on (held for
/// confirmation, then accepted), it searches that robot's keyframes near where the closure's
/// alignment puts it, as it searches its own, and before that near where the alignment that robot's
/// node accepted and shares puts it. By place descriptor alone the robots closed 12.5 % of the
/// opposite-direction opportunities and 94.7 % of the same-direction ones; around their own
/// alignments 83.0 % and 99.8 %; around the shared ones as well 91.4 % and 99.8 % (measured). Every
/// closure is correct, and no pair is published twice.
#[test]
fn aligned_robots_search_each_others_streets_where_the_alignment_puts_them() {
    let scenario = held_out(0, RadarPreset::Nuscenes, false);
    assert_eq!(scenario.world, WorldFamily::Suburb);
    let r = fleet_of_three(scenario);
    assert_no_false_closure(&r);
    assert!(r.same.recall() >= 0.97, "{:?}", r.same);
    assert!(r.reverse.recall() >= 0.87, "{:?}", r.reverse);
    assert_covariance_holds(&r);
}

/// The held-out arterial road driven by a fleet of three, five radars: robots 0 and 1 drive at once in
/// opposite directions, and their first confirmation comes some 1,300 m into robot 1's lap. The search
/// again after a confirmation walks away from it while an alignment vouches; where none does any more,
/// the keyframes beyond are searched as new keyframes are, and a robot's keyframes without a closure
/// are searched again where the other robot's shared alignment puts them when it arrives. Measured:
/// 67.9 % of the opposite-direction opportunities closed (46.7 % when the walk stopped at a stale
/// alignment and shared alignments started none); every closure is correct, no pair twice.
#[test]
fn robots_driving_at_once_walk_back_to_the_streets_they_passed_before_confirming() {
    let scenario = held_out(2, RadarPreset::Nuscenes, false);
    assert_eq!(scenario.world, WorldFamily::Arterial);
    let r = fleet_of_three(scenario);
    assert_no_false_closure(&r);
    assert!(r.same.recall() >= 0.97, "{:?}", r.same);
    assert!(r.reverse.recall() >= 0.6, "{:?}", r.reverse);
    assert_covariance_holds(&r);
}

/// `scenario` driven by a fleet of three robots (`dc_loc revisits --fleet 3`), its figures printed.
fn fleet_of_three(scenario: RevisitScenario) -> dc_loc::eval::judge::RevisitReport {
    let fleet = RevisitScenario {
        fleet: 3,
        ..scenario
    };
    let r = evaluate_scenario(&fleet, |_| {}).expect("scenario runs");
    eprintln!(
        "same {:?}; reverse {:?}; NEES {:?}",
        r.same, r.reverse, r.nees
    );
    assert_each_pair_once(&r);
    r
}

/// No pair of keyframes is published twice (by the two robots' nodes, or by one node twice).
fn assert_each_pair_once(r: &dc_loc::eval::judge::RevisitReport) {
    let mut pairs: Vec<_> = r
        .closures
        .iter()
        .map(|c| (c.query_id.min(c.match_id), c.query_id.max(c.match_id)))
        .collect();
    let n = pairs.len();
    pairs.sort_unstable();
    pairs.dedup();
    assert_eq!(pairs.len(), n, "{}: a pair published twice", r.scenario);
}

/// Two robots driving the same way round the city at the same time, a third of the loop apart, five
/// radars: each place is passed first by one robot and then by the other, whose node holds the first
/// one's keyframes by then and registers the pair, whichever robot's clock is later. Every closure is
/// correct, at least 87 % of the opportunities are closed (measured: 88.6 %; each node's closures
/// often join the other robot's next keyframe ahead, 5-7 m on, which the registration's overlap
/// prefers to the nearest, and skip some of its keyframes), and no pair of keyframes is published by
/// both nodes.
#[test]
fn two_robots_driving_at_once_close_each_pair_once() {
    let base =
        RevisitScenario::new(RadarPreset::Nuscenes, NoiseModel::Gaussian, 0.01, false).sim_config();
    let mut robots = dc_loc::sim::fleet::fleet(&base, 2).expect("fleet");
    robots[1].laps[0].reverse = false;
    let r = dc_loc::eval::fleet::evaluate_fleet(&robots, |_| {}).expect("fleet runs");
    eprintln!(
        "same {:?}; reverse {:?}; NEES {:?}",
        r.same, r.reverse, r.nees
    );
    assert_no_false_closure(&r);
    assert!(r.same.opportunities > 100, "{:?}", r.same);
    assert!(r.same.recall() >= 0.87, "{:?}", r.same);
    assert_each_pair_once(&r);
}

#[test]
fn the_revisits_command_rejects_bad_arguments() {
    let out = Command::new(env!("CARGO_BIN_EXE_dc_loc"))
        .args(["revisits", "--radars", "lidar"])
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("lidar"));
    let out = Command::new(env!("CARGO_BIN_EXE_dc_loc"))
        .args([
            "revisits",
            "--radars",
            "carla",
            "-p",
            "loop.maximum_ambiguity:=3",
        ])
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("maximum_ambiguity"));
    for args in [
        ["revisits", "--world", "desert"],
        ["revisits", "--set", "train"],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_dc_loc"))
            .args(args)
            .output()
            .expect("runs");
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        assert!(String::from_utf8_lossy(&out.stderr).contains(args[2]));
    }
}

/// [`RevisitScenario::new`] at 1 % drift with Gaussian noise on the held-out world `TEST[k]` (its family and seed).
fn held_out(k: usize, radars: RadarPreset, reverse: bool) -> RevisitScenario {
    let w = dc_loc::sim::families::TEST[k];
    RevisitScenario {
        world: w.family,
        seed: w.seed,
        ..RevisitScenario::new(radars, NoiseModel::Gaussian, 0.01, reverse)
    }
}

/// The covariances hold: mean NEES at most 4, at most 3 % of the closures above the 99 % bound.
fn assert_covariance_holds(r: &dc_loc::eval::judge::RevisitReport) {
    assert!(r.nees.mean <= 4.0, "{}: {:?}", r.scenario, r.nees);
    assert!(
        r.nees.share_above_99() <= 0.03,
        "{}: {:?}",
        r.scenario,
        r.nees
    );
}

/// Every published closure lies within 2 m of the ground truth.
fn assert_no_false_closure(r: &dc_loc::eval::judge::RevisitReport) {
    let wrong: Vec<_> = r
        .closures
        .iter()
        .filter(|c| c.translation_error > 2.0)
        .collect();
    assert!(wrong.is_empty(), "false closures: {wrong:?}");
}
