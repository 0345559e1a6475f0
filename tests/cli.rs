//! The `dc_loc` binary's offline subcommands and the bag runner, end to end:
//! - a bag written by `dc_loc sim` (a short custom drive) is read by the Python `rosbags` library
//!   (tests/python/check_sim_bag.py in the test venv) with the topics, types, counts, stamps, frames,
//!   cloud layout, odometry and static transforms the in-process `SimDrive` of the same configuration
//!   says; a second `sim` gives byte-identical files;
//! - `dc_loc run` on it twice gives byte-identical JSON lines; every line parses, its odometry poses
//!   are the simulated odometry at its stamps, and the closures agree with the ground truth;
//! - usage errors exit 2 naming the parameter or key; a missing bag exits 1 naming the path;
//! - the runner reports, and goes on after, an undecodable cloud, a cloud of another frame and a
//!   non-finite odometry pose, and replaces a zero header stamp by the log time;
//! - the shipped params files equal the configurations they stand for, and every example params file
//!   is accepted.

#[path = "python/venv.rs"]
mod venv;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use dc_loc::bag::{BagReader, BagWriter, schema};
use dc_loc::cloud::{CloudLayout, encode_detections};
use dc_loc::input::{Input, IssueReason};
use dc_loc::io::rosbag::BagInputs;
use dc_loc::io::tum::{read_tum, tum_line};
use dc_loc::math::{
    Iso2, Stamp, Vec3, interpolate_iso3, iso2_from_iso3, iso3_from_iso2, iso3_from_xyz_rpy,
    wrap_angle,
};
use dc_loc::msgs::builtin_interfaces::Time;
use dc_loc::msgs::nav_msgs::Odometry;
use dc_loc::msgs::std_msgs::Header;
use dc_loc::output::ClosureRecord;
use dc_loc::params::file::setup_yaml;
use dc_loc::params::{ParamSet, apply};
use dc_loc::pipeline::Config;
use dc_loc::pipeline::Pipeline;
use dc_loc::radar::Detection;
use dc_loc::runner::run_inputs;
use dc_loc::sim::export::{GROUND_TRUTH_TOPIC, TF_STATIC_TOPIC};
use dc_loc::sim::{RadarPreset, SimConfig, SimDrive, simulate};
use serde_json::json;

mod common;
use common::{SHORT_DRIVE, text};

const REPO: &str = env!("CARGO_MANIFEST_DIR");

struct SimBag {
    dir: PathBuf,
    drive: SimDrive,
    stdout: String,
}

/// `dc_loc sim` of the short drive (once per test binary), and the same drive simulated here.
fn scratch(name: &str) -> PathBuf {
    common::scratch("cli_tests", name)
}

fn dc_loc(args: &[&str]) -> Output {
    common::run_dc_loc(args, "warn")
}

fn sim_bag() -> &'static SimBag {
    static BAG: OnceLock<SimBag> = OnceLock::new();
    BAG.get_or_init(|| {
        let root = scratch("sim");
        let config = root.join("short.yaml");
        std::fs::write(&config, SHORT_DRIVE).unwrap();
        let dir = root.join("short");
        let out = dc_loc(&[
            "sim",
            "--config",
            config.to_str().unwrap(),
            "--out",
            dir.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", text(&out.stderr));
        let cfg: SimConfig = yaml_serde::from_str(SHORT_DRIVE).unwrap();
        SimBag {
            dir,
            drive: simulate(&cfg).unwrap(),
            stdout: text(&out.stdout),
        }
    })
}

/// Planar rotation angle of a (qz, qw) yaw-only quaternion.
fn yaw(qz: f64, qw: f64) -> f64 {
    2.0 * qz.atan2(qw)
}

#[test]
fn sim_bag_reads_back_with_rosbags() {
    let bag = sim_bag();
    let d = &bag.drive;
    let cfg = d.to_config();
    let radar = &cfg.radars["front"];
    let (gt0, gt1) = (d.ground_truth[0], *d.ground_truth.last().unwrap());
    let (od0, od1) = (d.odometry[0], *d.odometry.last().unwrap());
    let (sc0, sc1) = (&d.scans[0].scan, &d.scans.last().unwrap().scan);
    let detections: usize = d.scans.iter().map(|s| s.scan.detections.len()).sum();
    let [ex, ey, ez, _, _, eyaw] = radar.extrinsic;
    let start = d.setup.start.0;
    let end = gt1.stamp.0.max(od1.stamp.0).max(sc1.stamp.0);
    assert!(d.scans.len() > 1000 && detections > 50_000, "a real drive");
    assert!(
        bag.stdout
            .contains(&format!("scans {} from 1 radar", d.scans.len()))
    );

    let expect = json!({
        "start_ns": start,
        "end_ns": end,
        "topics": [
            {"name": TF_STATIC_TOPIC, "type": schema::TF_MESSAGE, "count": 1, "durability": "transient_local"},
            {"name": "/odom", "type": schema::ODOMETRY, "count": d.odometry.len(), "durability": "volatile"},
            {"name": GROUND_TRUTH_TOPIC, "type": schema::ODOMETRY, "count": d.ground_truth.len(), "durability": "volatile"},
            {"name": radar.topic, "type": schema::POINT_CLOUD2, "count": d.scans.len(), "durability": "volatile"},
        ],
        "stamps": {
            TF_STATIC_TOPIC: {"first_ns": start, "last_ns": start},
            "/odom": {"first_ns": od0.stamp.0, "last_ns": od1.stamp.0},
            GROUND_TRUTH_TOPIC: {"first_ns": gt0.stamp.0, "last_ns": gt1.stamp.0},
            radar.topic.as_str(): {"first_ns": sc0.stamp.0, "last_ns": sc1.stamp.0},
        },
        "odometry": {
            "/odom": {"frame_id": "odom", "child_frame_id": "base_link",
                      "last_xy": [od1.t_odom_body.translation.x, od1.t_odom_body.translation.y],
                      "last_speed": od1.speed},
            GROUND_TRUTH_TOPIC: {"frame_id": "map", "child_frame_id": "base_link",
                      "last_xy": [gt1.t_map_body.translation.x, gt1.t_map_body.translation.y],
                      "last_speed": gt1.speed},
        },
        "clouds": {radar.topic.as_str(): {"frame_id": "radar_front", "detections": detections}},
        "tf_static": [{"parent": "base_link", "child": "radar_front",
                       "translation": [ex, ey, ez],
                       "rotation": [0.0, 0.0, (eyaw / 2.0).sin(), (eyaw / 2.0).cos()]}],
    });
    let expect_path = bag.dir.parent().unwrap().join("expect.json");
    std::fs::write(&expect_path, expect.to_string()).unwrap();
    let out = Command::new(venv::venv_python())
        .arg(Path::new(REPO).join("tests/python/check_sim_bag.py"))
        .arg(&bag.dir)
        .arg(format!("@{}", expect_path.display()))
        .output()
        .unwrap();
    println!("{}{}", text(&out.stdout), text(&out.stderr));
    assert!(
        out.status.success(),
        "{}{}",
        text(&out.stdout),
        text(&out.stderr)
    );

    // The same drive again: byte-identical bag and params file.
    let again = scratch("sim_again").join("short");
    let config = bag.dir.parent().unwrap().join("short.yaml");
    let out = dc_loc(&[
        "sim",
        "--config",
        config.to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    for f in ["short_0.mcap", "metadata.yaml"] {
        assert!(
            std::fs::read(bag.dir.join(f)).unwrap() == std::fs::read(again.join(f)).unwrap(),
            "{f} differs between two runs"
        );
    }
}

/// The odometry of the drive interpolated at `stamp` (as the pipeline's buffer does).
fn odometry_at(d: &SimDrive, stamp: Stamp) -> Iso2 {
    let i = d.odometry.partition_point(|o| o.stamp <= stamp);
    let (a, b) = (&d.odometry[i - 1], &d.odometry[i.min(d.odometry.len() - 1)]);
    let s = if b.stamp > a.stamp {
        stamp.secs_since(a.stamp) / b.stamp.secs_since(a.stamp)
    } else {
        0.0
    };
    iso2_from_iso3(&interpolate_iso3(
        &iso3_from_iso2(&a.t_odom_body),
        &iso3_from_iso2(&b.t_odom_body),
        s,
    ))
}

#[test]
fn run_is_deterministic_and_its_closures_match_the_drive() {
    let bag = sim_bag();
    let d = &bag.drive;
    let root = scratch("run");
    let params = bag.dir.join("dc_loc.yaml");
    let mut outputs = Vec::new();
    for name in ["a.jsonl", "b.jsonl"] {
        let path = root.join(name);
        let out = dc_loc(&[
            "run",
            "--bag",
            bag.dir.to_str().unwrap(),
            "--params",
            params.to_str().unwrap(),
            "--out",
            path.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", text(&out.stderr));
        outputs.push((std::fs::read(&path).unwrap(), text(&out.stdout)));
    }
    assert!(outputs[0].0 == outputs[1].0, "two runs differ");
    let lines = String::from_utf8(outputs[0].0.clone()).unwrap();
    let records: Vec<ClosureRecord> = lines
        .lines()
        .map(|l| ClosureRecord::from_json_line(l).unwrap())
        .collect();
    assert!(records.len() >= 20, "{} closures", records.len());
    let stdout = &outputs[0].1;
    assert!(
        stdout.contains(&format!("closures {} ->", records.len())),
        "{stdout}"
    );
    assert!(
        stdout.contains(&format!(
            "inputs: {} radar clouds, {} odometry",
            d.scans.len(),
            d.odometry.len()
        )),
        "{stdout}"
    );

    let mut errors = Vec::new();
    for r in &records {
        assert_eq!(r.frame_id, "base_link");
        assert_eq!(r.stamp, r.query_stamp);
        assert!(r.match_id < r.query_id && r.match_stamp < r.query_stamp);
        assert!(r.inliers >= 15, "loop.minimum_inliers");
        let cov = r.covariance_matrix().unwrap();
        assert!((cov - cov.transpose()).abs().max() < 1e-12 && cov[(0, 0)] > 0.0);
        // The keyframe poses are the simulated odometry at the keyframe stamps (up to the pipeline's
        // extrapolation over at most `odometry.max_extrapolation` = 50 ms past the newest sample: a
        // stamp off by 10 ms would be 0.1 m off here).
        for (pose, t) in [
            (&r.query_odom_pose, r.query_stamp),
            (&r.match_odom_pose, r.match_stamp),
        ] {
            let want = odometry_at(d, Stamp::from_secs_f64(t));
            let got = Vec3::new(pose.x, pose.y, pose.z);
            assert!(
                (got.xy() - want.translation.vector).norm() < 0.02 && got.z == 0.0,
                "{got} vs {want}"
            );
            assert!(wrap_angle(yaw(pose.qz, pose.qw) - want.rotation.angle()).abs() < 2e-3);
        }
        // Against the ground truth: the query body frame in the match body frame.
        let q = d.state_at(Stamp::from_secs_f64(r.query_stamp)).t_map_body;
        let m = d.state_at(Stamp::from_secs_f64(r.match_stamp)).t_map_body;
        let truth = m.inverse() * q;
        let rel = &r.relative_pose;
        let dt = (truth.translation.vector - nalgebra::Vector2::new(rel.x, rel.y)).norm();
        let dr = wrap_angle(truth.rotation.angle() - yaw(rel.qz, rel.qw)).abs();
        errors.push((dt, dr));
    }
    errors.sort_by(|a, b| a.0.total_cmp(&b.0));
    let median = errors[errors.len() / 2];
    println!(
        "{} closures, median error {:.3} m / {:.4} rad",
        errors.len(),
        median.0,
        median.1
    );
    assert!(median.0 < 0.5 && median.1 < 0.02, "median error {median:?}");
}

#[test]
fn usage_errors_exit_2_and_a_missing_bag_exits_1() {
    let bag = sim_bag();
    let root = scratch("usage");
    let out_file = root.join("c.jsonl");
    let params = bag.dir.join("dc_loc.yaml");
    let run = |extra: &[&str], bag_path: &str, params: &str| {
        let mut args = vec![
            "run",
            "--bag",
            bag_path,
            "--params",
            params,
            "--out",
            out_file.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        dc_loc(&args)
    };
    let (b, p) = (bag.dir.to_str().unwrap(), params.to_str().unwrap());
    for (extra, name) in [
        (&["-p", "loop.search_radius:=far"][..], "loop.search_radius"),
        (&["-p", "keyframe.distance:=-1.0"][..], "keyframe.distance"),
        (&["-p", "keyframe.distanse:=1.0"][..], "keyframe.distanse"),
        (
            &["-p", "radars.front.topic:=/radar/points"][..],
            "radars.front.topic",
        ),
    ] {
        let out = run(extra, b, p);
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{extra:?}: {err}");
        assert!(err.contains(name), "{extra:?}: {err}");
    }
    let missing = root.join("no_such_bag");
    let out = run(&[], missing.to_str().unwrap(), p);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    assert!(text(&out.stderr).contains(missing.to_str().unwrap()));

    // Simulator configuration: unknown keys and bad values are named.
    let cfg = root.join("bad.yaml");
    for (yaml, name) in [
        ("lapz: []\n", "lapz"),
        ("laps:\n  - speed: 0.0\n", "laps[0].speed"),
        ("odometry:\n  scale_eror: 0.1\n", "scale_eror"),
    ] {
        std::fs::write(&cfg, yaml).unwrap();
        let out = dc_loc(&[
            "sim",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            root.join("never").to_str().unwrap(),
        ]);
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{yaml}: {err}");
        assert!(err.contains(name), "{yaml}: {err}");
        assert!(!root.join("never").exists());
    }
    let out = dc_loc(&[
        "sim",
        "--out",
        root.join("never").to_str().unwrap(),
        "--noise",
        "cauchy",
    ]);
    assert_eq!(out.status.code(), Some(2));
    for sub in ["eval", "demo"] {
        let out = dc_loc(&[sub, "--anything"]);
        assert_eq!(out.status.code(), Some(2));
        assert!(
            text(&out.stderr).contains("--anything"),
            "{}",
            text(&out.stderr)
        );
    }
    assert_eq!(dc_loc(&["help"]).status.code(), Some(0));
}

/// A cloud of a few detections on the default radar.
fn cloud(stamp: Stamp, frame_id: &str) -> dc_loc::msgs::sensor_msgs::PointCloud2 {
    let dets: Vec<Detection> = (0..20)
        .map(|i| Detection {
            p_radar: Vec3::new(10.0 + i as f64, -5.0 + 0.5 * i as f64, 0.0),
            v_r: -1.0,
            rcs: Some(5.0),
        })
        .collect();
    let header = Header {
        stamp: stamp.into(),
        frame_id: frame_id.into(),
    };
    encode_detections(&dets, &CloudLayout::radar_f32(), header).unwrap()
}

fn odometry(stamp: Stamp, x: f64) -> Odometry {
    let mut m = Odometry::default();
    m.header.stamp = stamp.into();
    m.header.frame_id = "odom".into();
    m.child_frame_id = "base_link".into();
    m.pose.pose.position.x = x;
    m
}

#[test]
fn runner_reports_bad_messages_and_goes_on() {
    let t0 = 1_700_000_000_000_000_000i64;
    let ms = |k: i64| Stamp(t0 + k * 1_000_000);
    let dir = scratch("issues").join("bad");
    let mut w = BagWriter::create(&dir).unwrap();
    let odom = w.add_topic("/odom", schema::ODOMETRY).unwrap();
    let radar = w.add_topic("/radar/points", schema::POINT_CLOUD2).unwrap();
    let other = w.add_topic("/unrelated", schema::ODOMETRY).unwrap();
    for i in 0..20 {
        let mut m = odometry(ms(50 * i), 0.5 * i as f64);
        if i == 10 {
            m.pose.pose.position.y = f64::NAN;
        }
        w.write(odom, ms(50 * i), &m).unwrap();
        w.write(other, ms(50 * i), &m).unwrap();
    }
    w.write(radar, ms(25), &cloud(ms(25), "radar")).unwrap();
    // A CDR header, then too few bytes for a PointCloud2.
    w.write_cdr(radar, ms(125), &[0, 1, 0, 0, 7, 0, 0]).unwrap();
    w.write(radar, ms(225), &cloud(ms(225), "radar_rear"))
        .unwrap();
    let mut zero = cloud(ms(325), "radar");
    zero.header.stamp = Time::default();
    w.write(radar, ms(325), &zero).unwrap();
    w.write(radar, ms(425), &cloud(ms(425), "radar")).unwrap();
    w.finish().unwrap();

    let reader = BagReader::open(&dir).unwrap();
    let cfg = Config::default();
    let items: Vec<_> = BagInputs::new(&reader, &cfg, None).unwrap().collect();
    assert_eq!(items.len(), 20 + 5, "the unrelated topic is not read");
    let stamps: Vec<Stamp> = items
        .iter()
        .map(|i| match i {
            Ok(input) => input.stamp(),
            Err(issue) => issue.stamp,
        })
        .collect();
    assert!(stamps.is_sorted());
    let issues: Vec<(&str, Stamp, &str)> = items
        .iter()
        .filter_map(|i| i.as_ref().err())
        .map(|e| (e.topic.as_str(), e.stamp, e.reason.name()))
        .collect();
    assert_eq!(
        issues,
        [
            ("/radar/points", ms(125), "undecodable"),
            ("/radar/points", ms(225), "frame_mismatch"),
            ("/odom", ms(500), "non_finite_pose"),
        ]
    );
    let mismatch = items
        .iter()
        .filter_map(|i| i.as_ref().err())
        .nth(1)
        .unwrap();
    assert!(
        matches!(&mismatch.reason, IssueReason::FrameMismatch { expected, got } if expected == "radar" && got == "radar_rear")
    );
    let clouds: Vec<Stamp> = items
        .iter()
        .filter_map(|i| match i {
            Ok(Input::Radar { radar: 0, cloud }) => Some(cloud.header.stamp.into()),
            _ => None,
        })
        .collect();
    assert_eq!(
        clouds,
        [ms(25), ms(325), ms(425)],
        "zero stamp replaced by the log time"
    );

    // Through the pipeline: every good input is used.
    let mut pipeline = Pipeline::new(cfg.clone()).unwrap();
    let report = run_inputs(
        &mut pipeline,
        BagInputs::new(&reader, &cfg, None).unwrap(),
        |_| {},
    );
    assert_eq!((report.radar_inputs, report.odometry_inputs), (3, 19));
    assert_eq!(report.issue_count(), 3);
    assert_eq!(report.stats.scans, 3);
    assert!(
        report.stats.dropped.is_empty(),
        "{:?}",
        report.stats.dropped
    );

    // And through the binary, with the shipped default parameters.
    let out_file = dir.parent().unwrap().join("c.jsonl");
    let out = dc_loc(&[
        "run",
        "--bag",
        dir.to_str().unwrap(),
        "--params",
        &format!("{REPO}/params/dc_loc.yaml"),
        "--out",
        out_file.to_str().unwrap(),
    ]);
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        stdout.contains("skipped messages: frame_mismatch 1, non_finite_pose 1, undecodable 1"),
        "{stdout}"
    );
    assert_eq!(std::fs::read(&out_file).unwrap(), b"");
}

/// The shipped params files hold the sensor setup and what differs from the defaults; read, each is
/// exactly its configuration.
#[test]
fn shipped_params_files_equal_their_configs() {
    let bless = "Regenerate with DC_LOC_BLESS=1 cargo test --test cli shipped_params.";
    // The configuration of a simulated drive (a short one: the drive does not change it).
    let sim = |p: RadarPreset, what: &str| {
        let mut short: SimConfig = yaml_serde::from_str(SHORT_DRIVE).unwrap();
        short.radar_preset = p;
        short.laps.truncate(1);
        (
            simulate(&short).unwrap().to_config(),
            format!(
                "dc_loc parameters for drives of `dc_loc sim --preset {what}` (Gaussian noise; other noise\n\
                 models change the radars' sigma_* values: use the dc_loc.yaml that `dc_loc sim` writes\n\
                 into each bag directory): the sensor setup and what differs from the defaults (`dc_loc\n\
                 params`). Applied, equal to SimConfig::with_preset(..).to_config().\n{bless}"
            ),
        )
    };
    let files = [
        (
            "params/dc_loc.yaml",
            (
                Config::default(),
                format!(
                    "dc_loc node parameters: the sensor setup of the defaults, one forward radar `front`\n\
                     (PointCloud2 on /radar/points, frame `radar`, fields x y z v_r rcs) and odometry on\n\
                     /odom; every other parameter keeps its default (`dc_loc params`). Applied, equal to\n\
                     Config::default(). {bless}"
                ),
            ),
        ),
        ("params/sim_carla.yaml", sim(RadarPreset::Carla, "carla")),
        (
            "params/sim_nuscenes.yaml",
            sim(RadarPreset::Nuscenes, "nuscenes"),
        ),
        ("params/nuscenes.yaml", {
            // The five ARS408 radars of nuScenes with their extrinsics (docs/interfaces.md, as the simulator's
            // preset), the raw vx/vy fields of the PCD records, nuscenes2mcap's topics and frames; every
            // other section the defaults.
            let drive = sim(RadarPreset::Nuscenes, "nuscenes").0;
            let base = Config {
                radars: drive.radars.clone(),
                radar_names: drive.radar_names.clone(),
                ..Config::default()
            };
            (
                dc_loc::io::nuscenes::nuscenes_config(&base, &[None; 5]),
                format!(
                    "dc_loc node parameters for the five Continental ARS408-21 radars of nuScenes: extrinsics in\n\
                     the body frame from the dataset's calibration (docs/interfaces.md), radial velocity from the raw\n\
                     vx, vy fields, topics /radar_<name> and frames radar_<name> as nuscenes2mcap writes them\n\
                     (remap to your own). Every other parameter keeps its default (`dc_loc params`). {bless}"
                ),
            )
        }),
    ];
    for (file, (cfg, header)) in files {
        let path = Path::new(REPO).join(file);
        if std::env::var_os("DC_LOC_BLESS").is_some() {
            std::fs::write(&path, setup_yaml(&cfg, &header).unwrap()).unwrap();
        }
        let yaml = std::fs::read_to_string(&path).unwrap();
        let got = apply(&ParamSet::from_yaml(&yaml, "/", "dc_loc").unwrap()).unwrap();
        assert!(got == cfg, "{file} differs from its configuration. {bless}");
        assert!(yaml.contains("dc_loc:\n  ros__parameters:\n"));
    }
}

#[test]
fn a_damaged_bag_gives_the_closures_before_the_damage_and_exit_1() {
    let bag = sim_bag();
    let root = scratch("damaged");
    let params = bag.dir.join("dc_loc.yaml");
    let full = std::fs::read(bag.dir.join("short_0.mcap")).unwrap();
    // Cut at 80 %: no summary, the last chunks lost; read from the start as a lone .mcap file.
    let cut = root.join("cut.mcap");
    std::fs::write(&cut, &full[..full.len() * 4 / 5]).unwrap();
    let run = |bag: &Path, out: &Path| {
        dc_loc(&[
            "run",
            "--bag",
            bag.to_str().unwrap(),
            "--params",
            params.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let (whole, part) = (root.join("whole.jsonl"), root.join("part.jsonl"));
    assert!(run(&bag.dir, &whole).status.success());
    let out = run(&cut, &part);
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("damaged"), "{err}");
    let (whole, part) = (
        std::fs::read_to_string(&whole).unwrap(),
        std::fs::read_to_string(&part).unwrap(),
    );
    let n = part.lines().count();
    assert!(
        n >= 10 && n < whole.lines().count(),
        "{n} closures before the damage"
    );
    assert!(
        whole.starts_with(&part),
        "the closures before the damage are those of the whole bag"
    );
}

/// `dc_loc sim --fleet 3` writes one bag and params file per robot, each robot's drive starting
/// elsewhere on the one loop; `--fleet 0` is a usage error.
#[test]
fn sim_fleet_writes_a_bag_per_robot() {
    let root = scratch("fleet");
    let config = root.join("short.yaml");
    std::fs::write(&config, SHORT_DRIVE).unwrap();
    let out_dir = root.join("fleet");
    let out = dc_loc(&[
        "sim",
        "--config",
        config.to_str().unwrap(),
        "--fleet",
        "3",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    for k in 0..3 {
        let bag = out_dir.join(format!("robot_{k}"));
        assert!(bag.join("metadata.yaml").is_file() && bag.join("dc_loc.yaml").is_file());
    }
    assert!(stdout.contains("robot 1 from "), "{stdout}");
    assert!(stdout.contains("laps [36 km/h reverse]"), "{stdout}");
    let out = dc_loc(&[
        "sim",
        "--fleet",
        "0",
        "--out",
        root.join("none").to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
}

/// A bag whose radar publishes `radar_msgs/RadarScan` (written by rosbags alone,
/// tests/python/radar_scan_bag.py: each cloud's detections as range, azimuth, elevation and Doppler)
/// gives the closures of the same detections in PointCloud2; a scan with more returns than
/// `node.max_cloud_points` is dropped and counted, and the run goes on.
#[test]
fn a_radar_scan_bag_gives_the_closures_of_its_pointcloud2_twin() {
    let bag = sim_bag();
    let root = scratch("radar_scan");
    let params = bag.dir.join("dc_loc.yaml");
    let scans = root.join("scans");
    let out = venv::python_script("radar_scan_bag.py")
        .arg(&bag.dir)
        .arg(&scans)
        .output()
        .expect("cannot start the venv's python");
    assert!(out.status.success(), "{}", text(&out.stderr));
    let run = |bag: &Path, name: &str, extra: &[&str]| {
        let path = root.join(name);
        let mut args = vec![
            "run",
            "--bag",
            bag.to_str().unwrap(),
            "--params",
            params.to_str().unwrap(),
            "--out",
            path.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let out = dc_loc(&args);
        assert!(out.status.success(), "{}", text(&out.stderr));
        let records: Vec<ClosureRecord> = std::fs::read_to_string(&path)
            .unwrap()
            .lines()
            .map(|l| ClosureRecord::from_json_line(l).unwrap())
            .collect();
        (records, text(&out.stdout))
    };
    let (want, _) = run(&bag.dir, "clouds.jsonl", &[]);
    let scan_param = ["-p", "radars.front.message:=radar_scan"];
    let (got, stdout) = run(&scans, "scans.jsonl", &scan_param);
    let n = bag.drive.scans.len();
    assert!(
        stdout.contains(&format!("inputs: {n} radar clouds")),
        "{stdout}"
    );
    let key = |r: &ClosureRecord| (r.query_id, r.match_id);
    let common: Vec<(&ClosureRecord, &ClosureRecord)> = want
        .iter()
        .filter_map(|w| got.iter().find(|g| key(g) == key(w)).map(|g| (w, g)))
        .collect();
    println!(
        "{} closures from RadarScan, {} from PointCloud2, {} pairs in common",
        got.len(),
        want.len(),
        common.len()
    );
    assert!(want.len() >= 20);
    assert!(
        common.len() * 100 >= want.len() * 98 && got.len() * 100 <= want.len() * 102,
        "{} closures, {} of the PointCloud2 run's {} pairs",
        got.len(),
        common.len(),
        want.len()
    );
    for (w, g) in common {
        let (a, b) = (&w.relative_pose, &g.relative_pose);
        let dt = ((a.x - b.x).powi(2) + (a.y - b.y).powi(2)).sqrt();
        let dr = wrap_angle(yaw(a.qz, a.qw) - yaw(b.qz, b.qw)).abs();
        assert!(
            dt < 0.01 && dr < 1e-3,
            "closure {:?}: {dt} m, {dr} rad",
            key(w)
        );
    }

    // Scans of more than 100 returns are refused; the smaller ones still make keyframes.
    let mut limited = scan_param.to_vec();
    limited.extend_from_slice(&["-p", "node.max_cloud_points:=100"]);
    let (_, stdout) = run(&scans, "limited.jsonl", &limited);
    let big = bag
        .drive
        .scans
        .iter()
        .filter(|s| s.scan.detections.len() > 100)
        .count();
    assert!(
        big > 0 && big < n,
        "{big} of {n} scans have over 100 returns"
    );
    assert!(
        stdout.contains(&format!("cloud_too_large {big}")),
        "{stdout}"
    );
}

/// `dc_loc eval` on the short drive: it pairs the two laps, registers every pair with every method,
/// writes the plot and the per-pair results, and DC-Loc is more accurate than ICP from the identity.
#[test]
fn eval_on_the_short_drive_puts_dcloc_ahead_of_icp() {
    let bag = sim_bag();
    let out_dir = scratch("eval");
    let params = bag.dir.join("dc_loc.yaml");
    let out = dc_loc(&[
        "eval",
        "--bag",
        bag.dir.to_str().unwrap(),
        "--params",
        params.to_str().unwrap(),
        "--out-dir",
        out_dir.to_str().unwrap(),
        "--export-pairs",
        out_dir.join("export").to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(
        stdout.contains("Table 1 layout") && stdout.contains("Table 2 layout"),
        "{stdout}"
    );
    let svg = std::fs::read_to_string(out_dir.join("eval.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("DC-Loc"));
    // Per method: inlier translation errors from the per-pair file.
    let mut errors: std::collections::BTreeMap<String, (usize, Vec<f64>)> = Default::default();
    for line in std::fs::read_to_string(out_dir.join("pairs.jsonl"))
        .unwrap()
        .lines()
    {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let e = errors
            .entry(v["method"].as_str().unwrap().to_string())
            .or_default();
        e.0 += 1;
        if let Some(t) = v["translation_error"].as_f64().filter(|t| *t <= 2.0) {
            e.1.push(t);
        }
    }
    let mean = |m: &str| {
        let (_, v) = &errors[m];
        v.iter().sum::<f64>() / v.len() as f64
    };
    let (pairs, dcloc) = &errors["DC-Loc"];
    assert!(*pairs >= 20, "only {pairs} pairs");
    assert!(
        dcloc.len() * 10 >= pairs * 6,
        "DC-Loc registered {} of {pairs}",
        dcloc.len()
    );
    assert!(
        mean("DC-Loc") < mean("ICP"),
        "DC-Loc {} m vs ICP {} m",
        mean("DC-Loc"),
        mean("ICP")
    );
    assert_eq!(errors.len(), dc_loc::eval::Method::all().len());
    exported_pairs_align_under_their_truth(&out_dir.join("export"), *pairs);
}

/// The exported pairs (`--export-pairs`): every pair's query points, moved by its true
/// `T_target_query`, land on its target points (median nearest-neighbour distance well under the
/// identity's); DC-Loc's exported estimate is as far from the truth as its exported error says.
fn exported_pairs_align_under_their_truth(dir: &std::path::Path, pairs: usize) {
    let bytes = std::fs::read(dir.join("points.f32")).unwrap();
    let floats: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    let points = |span: &serde_json::Value| -> Vec<[f64; 2]> {
        let (o, n) = (
            span["offset"].as_u64().unwrap(),
            span["count"].as_u64().unwrap(),
        );
        (o..o + n)
            .map(|i| {
                [
                    floats[2 * i as usize] as f64,
                    floats[2 * i as usize + 1] as f64,
                ]
            })
            .collect()
    };
    let median_nn = |q: &[[f64; 2]], t: &[[f64; 2]], x: [f64; 3]| {
        let (s, c) = x[2].sin_cos();
        let mut d: Vec<f64> = q
            .iter()
            .map(|p| {
                let m = [c * p[0] - s * p[1] + x[0], s * p[0] + c * p[1] + x[1]];
                t.iter()
                    .map(|u| (u[0] - m[0]).hypot(u[1] - m[1]))
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        d.sort_by(f64::total_cmp);
        d[d.len() / 2]
    };
    let lines = std::fs::read_to_string(dir.join("pairs.jsonl")).unwrap();
    let (mut closer, mut n) = (0, 0);
    for line in lines.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let truth: [f64; 3] = serde_json::from_value(v["truth"].clone()).unwrap();
        let (q, t) = (points(&v["query"]), points(&v["target"]));
        if truth[0].hypot(truth[1]) > 2.0 {
            n += 1;
            let (aligned, identity) = (median_nn(&q, &t, truth), median_nn(&q, &t, [0.0; 3]));
            closer += usize::from(aligned < 0.5 * identity);
        }
        if let Some(est) = v["dcloc"]["estimate"].as_array() {
            let e: Vec<f64> = est.iter().map(|x| x.as_f64().unwrap()).collect();
            let err = v["dcloc"]["translation_error"].as_f64().unwrap();
            assert!(((e[0] - truth[0]).hypot(e[1] - truth[1]) - err).abs() < 1e-9);
            assert!(v["dcloc"]["seconds"].as_f64().unwrap() > 0.0);
        }
    }
    assert_eq!(lines.lines().count(), pairs);
    assert!(
        n >= 5 && closer * 10 >= n * 9,
        "{closer} of {n} pairs align under their truth"
    );
}

/// `dc_loc eval --dcloc-only` on the bag `bag` with `extra` arguments: its stdout, with the output
/// directory's path cut out.
fn eval_dcloc(bag: &Path, name: &str, extra: &[&str]) -> String {
    let out_dir = scratch(name);
    let params = bag.join("dc_loc.yaml");
    let mut args = vec![
        "eval",
        "--bag",
        bag.to_str().unwrap(),
        "--params",
        params.to_str().unwrap(),
        "--dcloc-only",
        "--out-dir",
        out_dir.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let out = dc_loc(&args);
    assert!(out.status.success(), "{}", text(&out.stderr));
    text(&out.stdout).replace(out_dir.to_str().unwrap(), "<out>")
}

/// Ground truth from the TUM file `dc_loc sim --ground-truth-tum` wrote gives `dc_loc eval` the tables
/// the bag's topic gives; so does a TUM file of another frame on the vehicle (the body's poses moved
/// by the inverse of a known `t_gt_body`) with that `--ground-truth-to-body`. Both laps are driven at
/// one speed that no corner lowers: the twist's speed and the one from consecutive poses (which lags
/// half a sample, and for the other frame is that frame's) then put every pair in the same velocity
/// bin, where a speed change could move a pair on a bin edge to the next bin.
#[test]
fn eval_with_ground_truth_from_a_tum_file_prints_the_topics_tables() {
    let root = scratch("eval_gt");
    let config = root.join("one_speed.yaml");
    let one_speed = SHORT_DRIVE.replace("speed: 15.0", "speed: 10.0")
        + "drive:\n  max_lateral_acceleration: 8.0\n";
    std::fs::write(&config, one_speed).unwrap();
    let (bag, tum) = (root.join("bag"), root.join("ground_truth.txt"));
    let sim = dc_loc(&[
        "sim",
        "--config",
        config.to_str().unwrap(),
        "--out",
        bag.to_str().unwrap(),
        "--ground-truth-tum",
        tum.to_str().unwrap(),
    ]);
    assert!(sim.status.success(), "{}", text(&sim.stderr));

    let from_topic = eval_dcloc(&bag, "eval_gt_topic", &[]);
    assert!(from_topic.contains("Table 1 layout"), "{from_topic}");
    let from_file = eval_dcloc(
        &bag,
        "eval_gt_file",
        &["--ground-truth", tum.to_str().unwrap()],
    );
    assert_eq!(from_file, from_topic);

    // A unit 1.2 m behind, 0.4 m right of and 0.3 m above the body, turned by 30 deg.
    let t_gt_body = iso3_from_xyz_rpy(1.2, 0.4, -0.3, 0.0, 0.0, (-30f64).to_radians());
    let unit = root.join("unit.txt");
    let moved: String = read_tum(&tum)
        .unwrap()
        .iter()
        .map(|p| tum_line(p.stamp, &(p.pose * t_gt_body.inverse())) + "\n")
        .collect();
    std::fs::write(&unit, moved).unwrap();
    let from_unit = eval_dcloc(
        &bag,
        "eval_gt_unit",
        &[
            "--ground-truth",
            unit.to_str().unwrap(),
            "--ground-truth-to-body",
            "1.2,0.4,-0.3,-30",
        ],
    );
    assert_eq!(from_unit, from_topic);
}

/// A malformed TUM file is refused naming its line; a file and a topic together are refused.
#[test]
fn eval_refuses_a_bad_tum_file_and_a_file_with_a_topic() {
    let bag = sim_bag();
    let dir = scratch("eval_gt_bad");
    let bad = dir.join("bad.txt");
    std::fs::write(
        &bad,
        "# t x y z qx qy qz qw\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n",
    )
    .unwrap();
    let params = bag.dir.join("dc_loc.yaml");
    let eval = |extra: &[&str]| {
        let mut args = vec![
            "eval",
            "--bag",
            bag.dir.to_str().unwrap(),
            "--params",
            params.to_str().unwrap(),
            "--out-dir",
            dir.to_str().unwrap(),
            "--ground-truth",
            bad.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        dc_loc(&args)
    };
    let out = eval(&[]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains(&format!("{}:3: 7 values, expected 8", bad.display())),
        "{stderr}"
    );
    let both = eval(&["--ground-truth-topic", "/ground_truth/odom"]);
    assert_eq!(both.status.code(), Some(2));
    assert!(
        text(&both.stderr).contains("--ground-truth-topic"),
        "{}",
        text(&both.stderr)
    );
}

/// `dc_loc eval` without ground truth in the bag says so and exits 2.
#[test]
fn eval_without_ground_truth_is_a_usage_error() {
    let bag = sim_bag();
    let out = dc_loc(&[
        "eval",
        "--bag",
        bag.dir.to_str().unwrap(),
        "--params",
        bag.dir.join("dc_loc.yaml").to_str().unwrap(),
        "--ground-truth-topic",
        "/nowhere",
        "--out-dir",
        scratch("eval_no_gt").to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    assert!(
        text(&out.stderr).contains("/nowhere"),
        "{}",
        text(&out.stderr)
    );
}

/// Every example params file of params/examples is accepted as the node and `dc_loc run` read it,
/// and sets what it says it sets.
#[test]
fn example_params_files_are_accepted() {
    let dir = Path::new(REPO).join("params/examples");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .collect();
    files.sort();
    assert!(files.len() >= 3, "{files:?}");
    for f in &files {
        let cfg = dc_loc::cli::params::load_params(f, "/", "dc_loc", &[])
            .unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        if f.ends_with("imaging_4d.yaml") {
            assert_eq!(cfg.submap.height_band, [0.3, 5.0]);
        }
    }
}

/// Misconfiguration through `dc_loc run`, each named once: a velocity field the clouds do not have
/// (the missing name and the clouds' fields with their datatypes, one line, then counted), a wrong
/// `frame_id` (the frame and the configured one, one line, then counted), the effective configuration
/// at start (hidden by `--quiet-config`), radars left on the default noise, and a params file whose
/// only section names the node in another namespace.
#[test]
fn misconfiguration_is_named_once() {
    let t0 = 1_700_000_000_000_000_000i64;
    let ms = |k: i64| Stamp(t0 + k * 1_000_000);
    let dir = scratch("misconfig").join("bag");
    let mut w = BagWriter::create(&dir).unwrap();
    let odom = w.add_topic("/odom", schema::ODOMETRY).unwrap();
    let radar = w.add_topic("/radar/points", schema::POINT_CLOUD2).unwrap();
    for i in 0..60 {
        w.write(odom, ms(50 * i), &odometry(ms(50 * i), 0.5 * i as f64))
            .unwrap();
        let frame = if i % 2 == 0 { "radar" } else { "radar_rear" };
        w.write(radar, ms(50 * i + 25), &cloud(ms(50 * i + 25), frame))
            .unwrap();
    }
    w.finish().unwrap();
    let out_file = dir.parent().unwrap().join("c.jsonl");
    let lines = |s: &str, what: &str| s.lines().filter(|l| l.contains(what)).count();

    let shipped = format!("{REPO}/params/dc_loc.yaml");
    let args = [
        "run",
        "--bag",
        dir.to_str().unwrap(),
        "--params",
        &shipped,
        "-p",
        "radars.front.fields.velocity:=v",
        "--out",
        out_file.to_str().unwrap(),
    ];
    let out = common::run_dc_loc(&args, "warn,dc_loc=info");
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stderr}");
    let missing = "radar `front`: field `v` (velocity) is not in the cloud; its fields: x FLOAT32, \
                   y FLOAT32, z FLOAT32, v_r FLOAT32, rcs FLOAT32";
    assert_eq!(lines(&stderr, missing), 1, "{stderr}");
    let frame = "frame_id `radar_rear` is not the configured `radar`";
    assert_eq!(lines(&stderr, frame), 1, "{stderr}");
    assert!(stdout.contains("dropped inputs: bad_cloud 30"), "{stdout}");
    assert!(
        stdout.contains("skipped messages: frame_mismatch 30"),
        "{stdout}"
    );
    assert_eq!(lines(&stderr, "effective configuration"), 1, "{stderr}");
    assert_eq!(
        lines(&stderr, "  radars.front.fields.velocity: \"v\""),
        1,
        "{stderr}"
    );
    assert_eq!(lines(&stderr, "not set; the defaults"), 0, "{stderr}");

    // A section for node /dc_loc read as /robot1/dc_loc: nothing applies, the noise keeps the
    // defaults; both said once; the configuration not logged.
    let params = dir.parent().unwrap().join("robot.yaml");
    std::fs::write(
        &params,
        "dc_loc:\n  ros__parameters:\n    body_frame: base_link\n",
    )
    .unwrap();
    let args = [
        "run",
        "--bag",
        dir.to_str().unwrap(),
        "--params",
        params.to_str().unwrap(),
        "--namespace",
        "/robot1",
        "--quiet-config",
        "--out",
        out_file.to_str().unwrap(),
    ];
    let out = common::run_dc_loc(&args, "warn,dc_loc=info");
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert_eq!(lines(&stderr, "effective configuration"), 0, "{stderr}");
    assert_eq!(
        lines(
            &stderr,
            "no section applies to node `/robot1/dc_loc` (sections: `dc_loc`)"
        ),
        1,
        "{stderr}"
    );
    assert_eq!(
        lines(
            &stderr,
            "radar `front`: radars.front.beta, radars.front.sigma_range, \
             radars.front.sigma_velocity, radars.front.sigma_azimuth not set"
        ),
        1,
        "{stderr}"
    );
}
