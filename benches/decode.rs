//! Decode speed: one 125-point radar cloud (FLOAT32 x, y, z, v_r, rcs; scalar velocity path) and a real
//! nuScenes ARS408 scan wrapped as PointCloud2 (43-byte records; vx, vy projected on the ray).
//! The scan-ingest budget (decode + compensate + covariance of a 125-point scan) is 20 us on one core:
//! `ingest_125_*` times exactly that, decoding into a reused buffer and turning every detection into a
//! body-frame point with its Doppler compensation (eq. 4), its covariance (eq. 7-8, compensated and
//! raw) and the extrinsic (eq. 5) ([`RadarModel::to_body`]).
//!
//! Run: `cargo bench --bench decode`. The real-data bench reads `$DC_LOC_REAL_DATA` or
//! `<manifest>/../shared/data/real` or `<manifest>/../../shared/data/real`, and is left out when none
//! exists.

use criterion::{Criterion, criterion_group, criterion_main};
use dc_loc::cloud::{
    CloudLayout, DecodedCloud, decode_detections, decode_detections_into, encode_detections,
};
use dc_loc::io::nuscenes_pcd::{nuscenes_fields_config, pcd_to_pointcloud2};
use dc_loc::math::Vec3;
use dc_loc::msgs::std_msgs::Header;
use dc_loc::radar::Detection;
use dc_loc::radar::FieldsConfig;
use dc_loc::radar::doppler::{BodyPoint, RadarModel};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use std::hint::black_box;
use std::path::PathBuf;

fn synthetic_cloud() -> dc_loc::msgs::sensor_msgs::PointCloud2 {
    let mut rng = StdRng::seed_from_u64(1);
    let dets: Vec<Detection> = (0..125)
        .map(|_| {
            let (r, phi) = (rng.random_range(1.0..100.0), rng.random_range(-1.3..1.3f64));
            Detection {
                p_radar: Vec3::new(r * phi.cos(), r * phi.sin(), rng.random_range(-1.0..1.0)),
                v_r: rng.random_range(-20.0..20.0),
                rcs: Some(rng.random_range(-10.0..30.0)),
            }
        })
        .collect();
    encode_detections(&dets, &CloudLayout::radar_f32(), Header::default()).expect("encodable")
}

fn real_pcd() -> Option<Vec<u8>> {
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut dirs: Vec<PathBuf> = std::env::var_os("DC_LOC_REAL_DATA")
        .map(PathBuf::from)
        .into_iter()
        .collect();
    dirs.push(manifest.join("../shared/data/real"));
    dirs.push(manifest.join("../../shared/data/real"));
    let file =
        "nuscenes-radar-pcd/n008-2018-08-01-15-34-25-0400__RADAR_BACK_RIGHT__1533152711219287.pcd";
    let found = dirs.iter().find_map(|d| std::fs::read(d.join(file)).ok());
    if found.is_none() {
        eprintln!("real nuScenes PCD not found in {dirs:?}: skipping that bench");
    }
    found
}

fn bench_decode(c: &mut Criterion) {
    let cloud = synthetic_cloud();
    let fields = FieldsConfig::default();
    c.bench_function("decode_125_f32_xyz_vr_rcs", |b| {
        b.iter(|| decode_detections(black_box(&cloud), black_box(&fields)))
    });
    let mut out = DecodedCloud::default();
    c.bench_function("decode_into_125_f32_xyz_vr_rcs", |b| {
        b.iter(|| decode_detections_into(black_box(&cloud), black_box(&fields), &mut out))
    });

    // Decode, compensate, covariance and extrinsic: the whole per-scan ingest.
    let model = RadarModel {
        t_body_radar: dc_loc::math::iso3_from_xyz_rpy(3.4, 0.0, 0.6, 0.0, 0.0, 0.0),
        beta: 0.04,
        noise: dc_loc::radar::RadarNoise::default(),
    };
    let mut points: Vec<BodyPoint> = Vec::with_capacity(128);
    let mut ingest = |b: &mut criterion::Bencher,
                      cloud: &dc_loc::msgs::sensor_msgs::PointCloud2,
                      fields: &FieldsConfig| {
        b.iter(|| {
            decode_detections_into(black_box(cloud), black_box(fields), &mut out).expect("decodes");
            points.clear();
            points.extend(out.detections.iter().filter_map(|d| model.to_body(d)));
            black_box(points.len())
        })
    };
    c.bench_function("ingest_125_f32_xyz_vr_rcs", |b| ingest(b, &cloud, &fields));

    if let Some(bytes) = real_pcd() {
        let cloud = pcd_to_pointcloud2(&bytes, Header::default()).expect("real PCD wraps");
        let fields = nuscenes_fields_config();
        c.bench_function("decode_nuscenes_pcd_125_vx_vy", |b| {
            b.iter(|| decode_detections(black_box(&cloud), black_box(&fields)))
        });
        c.bench_function("ingest_nuscenes_pcd_125_vx_vy", |b| {
            ingest(b, &cloud, &fields)
        });
    }
}

criterion_group!(benches, bench_decode);
criterion_main!(benches);
