//! View-of-Delft directories and foxglove (nuscenes2mcap) MCAP files through `dc_loc run` / `eval`:
//! the real VoD example frames, a VoD directory and a nuscenes2mcap-layout MCAP that the tests write
//! from simulated drives.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Output;

use dc_loc::bag::foxglove::{
    FrameTransform, PackedElementField, PointCloud, Quaternion, Timestamp, Vector3,
};
use dc_loc::input::Input;
use dc_loc::io::nuscenes::RADAR_CHANNELS;
use dc_loc::io::vod_sequence::{VodInputs, open_sequences};
use dc_loc::math::{Iso3, Stamp, iso3_from_iso2, iso3_from_xyz_rpy};
use dc_loc::sim::{SimDrive, SimScan, simulate};
use prost::Message;

mod common;
use common::{real_data, text};

/// Two laps of a 130 x 80 m block (54 and 36 km/h).
fn scratch(name: &str) -> PathBuf {
    common::scratch("realdata_tests", name)
}

fn dc_loc(args: &[&str]) -> Output {
    common::run_dc_loc(args, "warn,dc_loc=info")
}

fn drive(preset: &str) -> SimDrive {
    let yaml = format!(
        "seed: 7\nradar_preset: {preset}\nlaps:\n  - speed: 15.0\n  - speed: 10.0\n\
         ground_truth_rate: 20.0\nodometry:\n  rate: 25.0\nroute:\n  corners:\n\
         \x20   - {{x: 0.0, y: 0.0, radius: 15.0, junction: true}}\n\
         \x20   - {{x: 130.0, y: 0.0, radius: 20.0, junction: false}}\n\
         \x20   - {{x: 130.0, y: 80.0, radius: 15.0, junction: true}}\n\
         \x20   - {{x: 0.0, y: 80.0, radius: 20.0, junction: false}}\n"
    );
    simulate(&yaml_serde::from_str(&yaml).unwrap()).unwrap()
}

fn closures(path: &Path) -> usize {
    std::fs::read_to_string(path).unwrap().lines().count()
}

/// The three real VoD example frames: not consecutive, so three runs of one frame, each giving ground
/// truth, odometry and a cloud of all its points, with the radar near the camera in the map frame.
#[test]
fn real_vod_example_frames_are_three_runs() {
    let Some(real) = real_data() else { return };
    let dir = real.join("view-of-delft-example");
    let seqs = open_sequences(&dir).unwrap();
    let numbers: Vec<Vec<u32>> = seqs
        .iter()
        .map(|s| s.frames.iter().map(|f| f.number).collect())
        .collect();
    assert_eq!(numbers, vec![vec![549], vec![1047], vec![1201]]);
    // SOURCE.md: camera (x, y) in the map frame, and points per frame.
    for (seq, (cam, points)) in seqs.iter().zip([
        ((-748.9, 1023.5), 322u32),
        ((-1411.5, 1581.8), 352),
        ((-1457.9, 1558.5), 242),
    ]) {
        let f = &seq.frames[0];
        let d = (f.t_map_radar.translation.x - cam.0).hypot(f.t_map_radar.translation.y - cam.1);
        assert!(d < 3.0, "radar {d} m from the camera");
        let inputs: Vec<Input> = VodInputs::new(seq, 10.0).map(Result::unwrap).collect();
        assert_eq!(inputs.len(), 3);
        match &inputs[2] {
            Input::Radar { radar: 0, cloud } => assert_eq!(cloud.width, points),
            other => panic!("{other:?}"),
        }
    }
    // Not a VoD directory: named.
    let e = open_sequences(&real.join("nuscenes-radar-pcd")).unwrap_err();
    assert!(e.to_string().contains("velodyne"), "{e}");
}

/// A row-major 4x4 as VoD's pose JSON writes it.
fn row_major(t: &Iso3) -> Vec<f64> {
    let m = t.to_homogeneous();
    (0..4)
        .flat_map(|r| (0..4).map(move |c| m[(r, c)]))
        .collect()
}

/// Writes the drive's scans as a VoD directory: lap 1 as frames 0.., lap 2 as frames 10000.. (two
/// clips), camera at the KITTI convention 0.5 m above the radar.
fn write_vod(drive: &SimDrive, dir: &Path) -> usize {
    for sub in ["velodyne", "pose", "calib"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
    }
    // Radar (x fwd, y left, z up) -> camera (x right, y down, z fwd), camera 0.5 m above the radar.
    let r = nalgebra::Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
    let t_camera_radar = Iso3::from_parts(
        nalgebra::Translation3::new(0.0, 0.5, 0.0),
        nalgebra::UnitQuaternion::from_matrix(&r),
    );
    let tr: Vec<String> = (0..3)
        .flat_map(|i| (0..4).map(move |j| (i, j)))
        .map(|(i, j)| format!("{:e}", t_camera_radar.to_homogeneous()[(i, j)]))
        .collect();
    let t_odom_map = iso3_from_xyz_rpy(-20.0, 5.0, 0.0, 0.0, 0.0, 0.3);
    let ext = drive.setup.radars[0].extrinsic;
    let t_body_radar = iso3_from_xyz_rpy(ext[0], ext[1], ext[2], ext[3], ext[4], ext[5]);
    let mut count = [0u32; 2];
    let mut frames = 0;
    for s in &drive.scans {
        let lap = s.lap.lap.min(1);
        let n = lap as u32 * 10_000 + count[lap];
        count[lap] += 1;
        let mut bin = Vec::new();
        for d in &s.scan.detections {
            for v in [
                d.p_radar.x,
                d.p_radar.y,
                d.p_radar.z,
                d.rcs.unwrap_or(0.0),
                d.v_r,
                0.0,
                0.0,
            ] {
                bin.extend((v as f32).to_le_bytes());
            }
        }
        std::fs::write(dir.join(format!("velodyne/{n:05}.bin")), bin).unwrap();
        let t_map_radar = iso3_from_iso2(&drive.state_at(s.scan.stamp).t_map_body) * t_body_radar;
        let t_map_camera = t_map_radar * t_camera_radar.inverse();
        let pose = format!(
            "{}\n{}\n{}\n",
            serde_json::json!({"odomToCamera": row_major(&(t_odom_map * t_map_camera))}),
            serde_json::json!({"mapToCamera": row_major(&t_map_camera)}),
            serde_json::json!({"UTMToCamera": row_major(&t_map_camera)}),
        );
        std::fs::write(dir.join(format!("pose/{n:05}.json")), pose).unwrap();
        std::fs::write(
            dir.join(format!("calib/{n:05}.txt")),
            format!(
                "P2: 1 0 0 0 0 1 0 0 0 0 1 0\nTr_velo_to_cam: {}\n",
                tr.join(" ")
            ),
        )
        .unwrap();
        frames += 1;
    }
    frames
}

/// `run --vod` and `eval --vod` on a VoD directory written from a simulated drive with the paper's
/// forward radar (13 Hz): two clips over the same loop give closures and evaluated pairs.
#[test]
fn vod_directory_runs_and_evaluates() {
    let d = drive("carla");
    let root = scratch("vod");
    let dir = root.join("radar").join("training");
    let frames = write_vod(&d, &dir);
    let seqs = open_sequences(&root).unwrap();
    assert_eq!(seqs.len(), 2, "two clips");
    assert_eq!(seqs.iter().map(|s| s.frames.len()).sum::<usize>(), frames);

    let out = root.join("closures.jsonl");
    let run = dc_loc(&[
        "run",
        "--vod",
        root.to_str().unwrap(),
        "--frame-rate",
        "13",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(run.status.success(), "{}", text(&run.stderr));
    let stdout = text(&run.stdout);
    assert!(stdout.contains(&format!("{frames} frames")), "{stdout}");
    assert!(closures(&out) >= 1, "{stdout}");

    let out_dir = root.join("eval");
    let ev = dc_loc(&[
        "eval",
        "--vod",
        root.to_str().unwrap(),
        "--frame-rate",
        "13",
        "--dcloc-only",
        "--out-dir",
        out_dir.to_str().unwrap(),
    ]);
    assert!(ev.status.success(), "{}", text(&ev.stderr));
    let stdout = text(&ev.stdout);
    assert!(stdout.contains("Table 1 layout"), "{stdout}");
    let lines = std::fs::read_to_string(out_dir.join("pairs.jsonl")).unwrap();
    let errors: Vec<f64> = lines
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            v["translation_error"].as_f64().unwrap_or(f64::INFINITY)
        })
        .collect();
    assert!(errors.len() >= 10, "{} pairs", errors.len());
    let inliers: Vec<f64> = errors.iter().copied().filter(|e| *e <= 2.0).collect();
    assert!(inliers.len() * 10 >= errors.len() * 7, "{errors:?}");
    let mean = inliers.iter().sum::<f64>() / inliers.len() as f64;
    assert!(mean < 0.5, "DC-Loc mean {mean} m");

    // Not a VoD directory: a usage error naming what is expected.
    let bad = dc_loc(&[
        "eval",
        "--vod",
        root.join("eval").to_str().unwrap(),
        "--out-dir",
        out_dir.to_str().unwrap(),
    ]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(text(&bad.stderr).contains("velodyne"));
}

fn ts(s: Stamp) -> Option<Timestamp> {
    Some(Timestamp {
        seconds: s.0.div_euclid(1_000_000_000),
        nanos: s.0.rem_euclid(1_000_000_000) as i32,
    })
}

fn frame_transform(stamp: Stamp, parent: &str, child: &str, t: &Iso3) -> FrameTransform {
    let q = t.rotation.quaternion();
    FrameTransform {
        timestamp: ts(stamp),
        parent_frame_id: parent.into(),
        child_frame_id: child.into(),
        translation: Some(Vector3 {
            x: t.translation.x,
            y: t.translation.y,
            z: t.translation.z,
        }),
        rotation: Some(Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        }),
    }
}

/// The ARS408 PCD record of each detection (43 bytes, nuScenes field order).
fn records(s: &SimScan) -> Vec<u8> {
    let mut b = Vec::new();
    for (i, d) in s.scan.detections.iter().enumerate() {
        let r = d.p_radar.norm().max(1e-9);
        let f = |b: &mut Vec<u8>, v: f64| b.extend((v as f32).to_le_bytes());
        f(&mut b, d.p_radar.x);
        f(&mut b, d.p_radar.y);
        f(&mut b, 0.0);
        b.push(1);
        b.extend((i as i16).to_le_bytes());
        f(&mut b, d.rcs.unwrap_or(0.0));
        f(&mut b, d.v_r * d.p_radar.x / r);
        f(&mut b, d.v_r * d.p_radar.y / r);
        f(&mut b, 0.0);
        f(&mut b, 0.0);
        b.extend([1, 3, 0, 0, 0, 0, 0, 0]);
    }
    b
}

/// nuscenes2mcap's PackedElementFields: the PCD header's fields in order, F4 -> FLOAT32 (7),
/// I1 -> INT8 (2), I2 -> INT16 (4).
fn pcd_fields() -> Vec<PackedElementField> {
    let layout: [(&str, i32, u32); 18] = [
        ("x", 7, 4),
        ("y", 7, 4),
        ("z", 7, 4),
        ("dyn_prop", 2, 1),
        ("id", 4, 2),
        ("rcs", 7, 4),
        ("vx", 7, 4),
        ("vy", 7, 4),
        ("vx_comp", 7, 4),
        ("vy_comp", 7, 4),
        ("is_quality_valid", 2, 1),
        ("ambig_state", 2, 1),
        ("x_rms", 2, 1),
        ("y_rms", 2, 1),
        ("invalid_state", 2, 1),
        ("pdh0", 2, 1),
        ("vx_rms", 2, 1),
        ("vy_rms", 2, 1),
    ];
    let mut offset = 0;
    layout
        .iter()
        .map(|&(name, t, size)| {
            let f = PackedElementField {
                name: name.into(),
                offset,
                r#type: t,
            };
            offset += size;
            f
        })
        .collect()
}

/// Writes the drive as nuscenes2mcap does (current layout): `/radar_<channel>` foxglove.PointCloud with
/// the PCD records, `/tf` foxglove.FrameTransform with map -> base_link at every sweep and
/// base_link -> radar_* every 0.5 s. The schema data is an empty FileDescriptorSet (a valid encoding of
/// an empty message; dc_loc reads by schema name).
fn write_foxglove_mcap(drive: &SimDrive, path: &Path, upper_case: bool) -> usize {
    // The 2022 protobuf version names topics and frames by the upper-case channel.
    let frame = |c: &str| {
        if upper_case {
            c.to_string()
        } else {
            c.to_ascii_lowercase()
        }
    };
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::Writer::new(file).unwrap();
    let pc = w
        .add_schema("foxglove.PointCloud", "protobuf", &[])
        .unwrap();
    let tf = w
        .add_schema("foxglove.FrameTransform", "protobuf", &[])
        .unwrap();
    let meta = BTreeMap::new();
    let tf_ch = w.add_channel(tf, "/tf", "protobuf", &meta).unwrap();
    let radar_ch: Vec<u16> = RADAR_CHANNELS
        .iter()
        .map(|c| {
            w.add_channel(pc, &format!("/{}", frame(c)), "protobuf", &meta)
                .unwrap()
        })
        .collect();
    let mut seq = 0u32;
    let mut put = |w: &mut mcap::Writer<_>, ch: u16, stamp: Stamp, data: Vec<u8>| {
        seq += 1;
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: seq,
                log_time: stamp.0 as u64,
                publish_time: stamp.0 as u64,
            },
            &data,
        )
        .unwrap();
    };
    let mut next_calib = Stamp(0);
    for s in &drive.scans {
        let stamp = s.scan.stamp;
        if stamp >= next_calib {
            for (i, r) in drive.setup.radars.iter().enumerate() {
                let e = r.extrinsic;
                let t = iso3_from_xyz_rpy(e[0], e[1], e[2], e[3], e[4], e[5]);
                let child = frame(RADAR_CHANNELS[i]);
                let m = frame_transform(stamp, "base_link", &child, &t);
                put(&mut w, tf_ch, stamp, m.encode_to_vec());
            }
            next_calib = Stamp(stamp.0 + 500_000_000);
        }
        let ego = iso3_from_iso2(&drive.state_at(stamp).t_map_body);
        put(
            &mut w,
            tf_ch,
            stamp,
            frame_transform(stamp, "map", "base_link", &ego).encode_to_vec(),
        );
        let r = s.scan.radar;
        let cloud = PointCloud {
            timestamp: ts(stamp),
            frame_id: frame(RADAR_CHANNELS[r]),
            pose: None,
            point_stride: 43,
            fields: pcd_fields(),
            data: records(s),
        };
        put(&mut w, radar_ch[r], stamp, cloud.encode_to_vec());
    }
    w.finish().unwrap();
    drive.scans.len()
}

/// `dc_loc run` on an MCAP in nuscenes2mcap's layout, without a params file: the five radars from the
/// topics, extrinsics from /tf, odometry from map -> base_link; the two laps close loops.
#[test]
fn foxglove_nuscenes2mcap_file_runs() {
    let d = drive("nuscenes");
    let mut outputs = Vec::new();
    for upper_case in [false, true] {
        let root = scratch(if upper_case {
            "foxglove_2022"
        } else {
            "foxglove"
        });
        let mcap_path = root.join("scene.mcap");
        let sweeps = write_foxglove_mcap(&d, &mcap_path, upper_case);
        let out = root.join("closures.jsonl");
        let t0 = std::time::Instant::now();
        let run = dc_loc(&[
            "run",
            "--bag",
            mcap_path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        let (stdout, stderr) = (text(&run.stdout), text(&run.stderr));
        assert!(run.status.success(), "{stderr}");
        eprintln!("run took {:.1} s\n{stdout}", t0.elapsed().as_secs_f64());
        assert!(
            stdout.contains(&format!("inputs: {sweeps} radar clouds")),
            "{stdout}"
        );
        for c in RADAR_CHANNELS {
            let f = if upper_case {
                c.to_string()
            } else {
                c.to_ascii_lowercase()
            };
            assert!(
                stderr.contains(&format!("base_link -> {f}")),
                "extrinsic of {c} from /tf: {stderr}"
            );
        }
        let n = closures(&out);
        assert!(n >= 3, "{n} closures\n{stdout}");
        outputs.push(std::fs::read_to_string(&out).unwrap());
    }
    // Both layouts carry the same drive: the same closures, byte for byte.
    assert_eq!(outputs[0], outputs[1]);
}

/// A ROS 2 bag's /tf_static overrides the params file's extrinsics: a params file with a wrong radar
/// mounting gives the same closures as the right one, and the run says where the extrinsic came from.
#[test]
fn ros2_bag_extrinsics_come_from_tf_static() {
    use dc_loc::sim::export::{export_drive, params_yaml};
    let d = drive("carla");
    let root = scratch("tf_static");
    let bag = export_drive(&d, &root.join("bag")).unwrap().bag_dir;
    let mut wrong = d.to_config();
    for r in wrong.radars.values_mut() {
        r.extrinsic = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    }
    let wrong_params = root.join("wrong.yaml");
    std::fs::write(&wrong_params, params_yaml(&wrong, "wrong extrinsics")).unwrap();
    let mut outputs = Vec::new();
    for params in [bag.join("dc_loc.yaml"), wrong_params] {
        let out = root.join("closures.jsonl");
        let run = dc_loc(&[
            "run",
            "--bag",
            bag.to_str().unwrap(),
            "--params",
            params.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        let stderr = text(&run.stderr);
        assert!(run.status.success(), "{stderr}");
        assert!(
            stderr.contains("extrinsic from the bag's transforms (base_link -> radar_front)"),
            "{stderr}"
        );
        outputs.push(std::fs::read_to_string(&out).unwrap());
    }
    assert!(closures_in(&outputs[0]) >= 1);
    assert_eq!(outputs[0], outputs[1]);
}

fn closures_in(text: &str) -> usize {
    text.lines().count()
}
