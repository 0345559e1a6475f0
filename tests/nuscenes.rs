//! `dc_loc eval --nuscenes` on a nuScenes-format dataset the test writes itself from a simulated drive
//! (two scenes over the same place, the five ARS408 radars), against `dc_loc eval --bag` on the same
//! drive as a bag; the reader's errors; the real PCD files through the flag filter.

use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::OnceLock;

mod common;
use common::{real_data, text};

use dc_loc::io::nuscenes::{NuscenesDb, NuscenesError, RADAR_CHANNELS};
use dc_loc::io::nuscenes_pcd::{NuscenesRadarFilter, NuscenesRadarPcd, filtered_pointcloud2};
use dc_loc::msgs::std_msgs::Header;
use dc_loc::sim::export::export_drive;
use dc_loc::sim::nuscenes::export_nuscenes;
use dc_loc::sim::{SimConfig, simulate};

/// Two laps (54 and 36 km/h) of a 130 x 80 m block with the five nuScenes radars.
const DRIVE: &str = "\
seed: 5
radar_preset: nuscenes
laps:
  - speed: 15.0
  - speed: 10.0
ground_truth_rate: 20.0
odometry:
  rate: 25.0
route:
  corners:
    - {x: 0.0, y: 0.0, radius: 15.0, junction: true}
    - {x: 130.0, y: 0.0, radius: 20.0, junction: false}
    - {x: 130.0, y: 80.0, radius: 15.0, junction: true}
    - {x: 0.0, y: 80.0, radius: 20.0, junction: false}
";

struct Fixture {
    bag: PathBuf,
    dataroot: PathBuf,
    scenes: Vec<String>,
}

/// The drive as a bag and as a nuScenes dataset (once per test binary).
fn scratch(name: &str) -> PathBuf {
    common::scratch("nuscenes_tests", name)
}

fn dc_loc(args: &[&str]) -> Output {
    common::run_dc_loc(args, "warn")
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let root = scratch("fixture");
        let cfg: SimConfig = yaml_serde::from_str(DRIVE).unwrap();
        let drive = simulate(&cfg).unwrap();
        let bag = export_drive(&drive, &root.join("bag")).unwrap().bag_dir;
        let dataroot = root.join("nuscenes");
        let ex = export_nuscenes(&drive, &dataroot, "v1.0-mini", "sim-city").unwrap();
        assert_eq!(ex.scenes.len(), 2);
        assert!(ex.keyframes * 5 < ex.sweeps, "{ex:?}");
        Fixture {
            bag,
            dataroot,
            scenes: ex.scenes,
        }
    })
}

/// Per method: (pairs, mean inlier translation error, mean inlier rotation error) from pairs.jsonl.
fn per_method(out_dir: &Path) -> std::collections::BTreeMap<String, (usize, f64, f64)> {
    let mut acc: std::collections::BTreeMap<String, (usize, Vec<f64>, Vec<f64>)> =
        Default::default();
    for line in std::fs::read_to_string(out_dir.join("pairs.jsonl"))
        .unwrap()
        .lines()
    {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let e = acc
            .entry(v["method"].as_str().unwrap().to_string())
            .or_default();
        e.0 += 1;
        if let Some(t) = v["translation_error"].as_f64().filter(|t| *t <= 2.0) {
            e.1.push(t);
            e.2.push(v["rotation_error"].as_f64().unwrap());
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    acc.into_iter()
        .map(|(k, (n, t, r))| (k, (n, mean(&t), mean(&r))))
        .collect()
}

#[test]
fn the_tables_read_back_with_every_sweep_calibration_and_pose() {
    let f = fixture();
    let db = NuscenesDb::open(&f.dataroot, "v1.0-mini", &mut |_| {}).unwrap();
    assert_eq!(
        db.scenes.iter().map(|s| s.name.clone()).collect::<Vec<_>>(),
        f.scenes
    );
    for s in &db.scenes {
        assert_eq!(s.location, "sim-city");
        // Every channel, ~13 Hz each, time-ordered, keyframes at ~2 Hz.
        let duration =
            (s.sweeps.last().unwrap().timestamp_us - s.sweeps[0].timestamp_us) as f64 * 1e-6;
        for ch in 0..RADAR_CHANNELS.len() {
            let n = s.sweeps.iter().filter(|w| w.channel == ch).count() as f64;
            assert!(
                (n / duration - 13.0).abs() < 0.5,
                "{} {ch}: {n} in {duration} s",
                s.name
            );
            let k = s
                .sweeps
                .iter()
                .filter(|w| w.channel == ch && w.is_key_frame)
                .count() as f64;
            assert!(
                (k / duration - 2.0).abs() < 0.2,
                "{k} keyframes in {duration} s"
            );
        }
        assert!(
            s.sweeps
                .windows(2)
                .all(|w| w[0].timestamp_us <= w[1].timestamp_us)
        );
        // RADAR_BACK_LEFT's calibration: yaw +174.41 deg (nuScenes calibrated_sensor).
        let bl = s.extrinsics()[3].unwrap();
        assert!((bl.rotation.euler_angles().2.to_degrees() - 174.41).abs() < 0.01);
    }
}

/// The headline check: the same drive gives the same table as a bag and as a nuScenes dataset.
#[test]
fn eval_nuscenes_matches_eval_on_the_same_drive_as_a_bag() {
    let f = fixture();
    let (bag_out, nus_out) = (scratch("eval_bag"), scratch("eval_nuscenes"));
    let out = dc_loc(&[
        "eval",
        "--bag",
        f.bag.to_str().unwrap(),
        "--params",
        f.bag.join("dc_loc.yaml").to_str().unwrap(),
        "--out-dir",
        bag_out.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let t0 = std::time::Instant::now();
    let out = dc_loc(&[
        "eval",
        "--nuscenes",
        f.dataroot.to_str().unwrap(),
        "--version",
        "v1.0-mini",
        // The simulated odometry's error (SimConfig default), so both runs build the same submaps.
        "--odometry-scale-error",
        "0.01",
        "--odometry-yaw-bias-deg",
        "0.1",
        "--out-dir",
        nus_out.to_str().unwrap(),
    ]);
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    eprintln!(
        "eval --nuscenes took {:.1} s\n{stdout}",
        t0.elapsed().as_secs_f64()
    );
    assert!(stdout.contains("Table 1 layout") && stdout.contains("Table 2 layout"));
    assert!(
        stdout.contains("0.290"),
        "paper numbers beside ours: {stdout}"
    );
    let (a, b) = (per_method(&bag_out), per_method(&nus_out));
    eprintln!("bag:      {a:?}\nnuscenes: {b:?}");
    assert_eq!(a.len(), b.len());
    for (m, &(na, ta, ra)) in &a {
        let &(nb, tb, rb) = b.get(m).unwrap();
        // Same pairs within a few (the bag may also pair the end of lap 1 with its start).
        assert!(
            nb >= 10 && (na as f64 - nb as f64).abs() <= 0.25 * na as f64 + 3.0,
            "{m}: {na} vs {nb} pairs"
        );
        assert!(
            (ta - tb).abs() <= 0.05 + 0.25 * ta.max(tb),
            "{m}: translation {ta} (bag) vs {tb} (nuscenes)"
        );
        assert!(
            (ra - rb).abs() <= 0.002 + 0.25 * ra.max(rb),
            "{m}: rotation {ra} (bag) vs {rb} (nuscenes)"
        );
    }
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dst = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &dst);
        } else {
            std::fs::copy(e.path(), dst).unwrap();
        }
    }
}

#[test]
fn wrong_directory_version_table_or_sweep_are_named() {
    let f = fixture();
    let nothing = &mut |_| {};
    // Not a directory.
    let e = NuscenesDb::open(&f.dataroot.join("nope"), "v1.0-mini", nothing).unwrap_err();
    assert!(matches!(e, NuscenesError::NotADirectory(_)), "{e}");
    // Version mismatch: the versions present are listed.
    let e = NuscenesDb::open(&f.dataroot, "v1.0-trainval", nothing).unwrap_err();
    assert!(e.to_string().contains("v1.0-mini"), "{e}");
    // The version folder given as the dataroot: a hint.
    let e = NuscenesDb::open(&f.dataroot.join("v1.0-mini"), "v1.0-mini", nothing).unwrap_err();
    assert!(e.to_string().contains("parent"), "{e}");

    // A missing table, then a missing sweep file, through the command line.
    let root = scratch("broken");
    copy_dir(&f.dataroot, &root);
    std::fs::rename(
        root.join("v1.0-mini/ego_pose.json"),
        root.join("v1.0-mini/ego_pose.json.bak"),
    )
    .unwrap();
    let args = |out: &Path| {
        vec![
            "eval".to_string(),
            "--nuscenes".into(),
            root.to_str().unwrap().into(),
            "--dcloc-only".into(),
            "--out-dir".into(),
            out.to_str().unwrap().into(),
        ]
    };
    let a = args(&root.join("out"));
    let out = dc_loc(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("ego_pose"),
        "{}",
        text(&out.stderr)
    );
    std::fs::rename(
        root.join("v1.0-mini/ego_pose.json.bak"),
        root.join("v1.0-mini/ego_pose.json"),
    )
    .unwrap();
    let db = NuscenesDb::open(&root, "v1.0-mini", nothing).unwrap();
    let victim = root.join(&db.scenes[1].sweeps[40].filename);
    std::fs::remove_file(&victim).unwrap();
    let out = dc_loc(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out.stderr);
    assert!(
        err.contains(victim.file_name().unwrap().to_str().unwrap()),
        "{err}"
    );
    // Skipping the incomplete scene leaves one scene: no pairs, said so.
    let mut skip = a.clone();
    skip.push("--skip-incomplete-scenes".into());
    let out = dc_loc(&skip.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(out.status.code(), Some(2));
    let err = text(&out.stderr);
    assert!(
        err.contains("scene skipped") && err.contains("no keyframe pairs"),
        "{err}"
    );
    // A damaged table names the table.
    std::fs::write(root.join("v1.0-mini/sample.json"), "[{\"token\": 1").unwrap();
    let e = NuscenesDb::open(&root, "v1.0-mini", nothing).unwrap_err();
    assert!(e.to_string().contains("sample"), "{e}");
}

/// The real ARS408 files through the flag filter: the PointCloud2 keeps exactly the records the
/// devkit's default filter keeps, byte for byte.
#[test]
fn real_pcds_filter_by_the_sensor_flags() {
    for name in [
        "n008-2018-08-01-15-34-25-0400__RADAR_BACK_RIGHT__1533152711219287.pcd",
        "n015-2018-07-25-16-15-50+0800__RADAR_BACK_LEFT__1532506682462345.pcd",
    ] {
        let Some(real) = real_data() else { return };
        let bytes = std::fs::read(real.join("nuscenes-radar-pcd").join(name)).unwrap();
        let pcd = NuscenesRadarPcd::from_bytes(&bytes).unwrap();
        assert_eq!(pcd.points.len(), 125);
        for (filter, label) in [
            (NuscenesRadarFilter::default(), "devkit"),
            (NuscenesRadarFilter::keep_all(), "all"),
            (
                NuscenesRadarFilter {
                    dynprop_states: Some(vec![1]),
                    ..NuscenesRadarFilter::keep_all()
                },
                "stationary",
            ),
        ] {
            let kept: Vec<_> = pcd.points.iter().filter(|p| filter.keeps(p)).collect();
            let cloud = filtered_pointcloud2(&bytes, &filter, Header::default()).unwrap();
            assert_eq!(cloud.width as usize, kept.len(), "{name} {label}");
            assert_eq!(cloud.data.len(), kept.len() * 43);
            // Record k of the cloud is the k-th kept point (x at offset 0, dyn_prop at 12).
            for (r, p) in cloud.data.chunks_exact(43).zip(&kept) {
                assert_eq!(f32::from_le_bytes(r[0..4].try_into().unwrap()), p.x);
                assert_eq!(r[12] as i8, p.dyn_prop);
            }
        }
        let devkit = pcd
            .points
            .iter()
            .filter(|p| NuscenesRadarFilter::default().keeps(p))
            .count();
        assert!(devkit < 125, "{name}: the devkit filter removes points");
    }
}

/// `dc_loc sim --nuscenes-out` needs the five nuScenes radars.
#[test]
fn sim_nuscenes_out_needs_the_nuscenes_preset() {
    let root = scratch("sim_out");
    let out = dc_loc(&[
        "sim",
        "--out",
        root.join("bag").to_str().unwrap(),
        "--nuscenes-out",
        root.join("nus").to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("--preset nuscenes"),
        "{}",
        text(&out.stderr)
    );
    assert!(!root.join("bag").exists() && !root.join("nus").exists());
}

/// `dc_loc run --nuscenes`: the two scenes of one location through one pipeline close loops across
/// the scenes (the second lap revisits the first).
#[test]
fn run_nuscenes_closes_loops_across_scenes() {
    let f = fixture();
    let root = scratch("run");
    let out = root.join("closures.jsonl");
    let run = dc_loc(&[
        "run",
        "--nuscenes",
        f.dataroot.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let stdout = text(&run.stdout);
    assert!(run.status.success(), "{}", text(&run.stderr));
    assert!(stdout.contains("2 scenes at 1 locations"), "{stdout}");
    let db = NuscenesDb::open(&f.dataroot, "v1.0-mini", &mut |_| {}).unwrap();
    let second_start = db.scenes[1].sweeps[0].timestamp_us as f64 * 1e-6;
    let lines = std::fs::read_to_string(&out).unwrap();
    let across = lines
        .lines()
        .filter(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            v["query_stamp"].as_f64().unwrap() >= second_start
                && v["match_stamp"].as_f64().unwrap() < second_start
        })
        .count();
    assert!(across >= 3, "{across} closures across scenes\n{stdout}");
}
