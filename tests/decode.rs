//! PointCloud2 decoding and encoding: hand-built byte layouts, round trips over random layouts, every
//! error variant, and a no-panic fuzz over random and mutated clouds.

use dc_loc::cloud::{
    CloudLayout, DecodeError, DecodedCloud, EncodeError, FieldRole, LayoutField, ScalarType,
    decode_detections, decode_detections_into, encode_detections,
};
use dc_loc::math::Vec3;
use dc_loc::msgs::sensor_msgs::{PointCloud2, PointField};
use dc_loc::msgs::std_msgs::Header;
use dc_loc::radar::Detection;
use dc_loc::radar::FieldsConfig;
use rand::rngs::StdRng;
use rand::seq::{IndexedRandom, SliceRandom};
use rand::{RngExt, SeedableRng};

fn field(name: &str, offset: u32, datatype: u8) -> PointField {
    PointField {
        name: name.into(),
        offset,
        datatype,
        count: 1,
    }
}

fn fields_scalar(velocity: &str) -> FieldsConfig {
    FieldsConfig {
        velocity: velocity.into(),
        ..FieldsConfig::default()
    }
}

fn fields_vector() -> FieldsConfig {
    FieldsConfig {
        velocity: String::new(),
        velocity_x: "vx".into(),
        velocity_y: "vy".into(),
        ..FieldsConfig::default()
    }
}

/// The TI mmWave layout of the rio demo bag (x@0 y@4 z@8 intensity@16 velocity@20, FLOAT32, point_step
/// 32), written byte by byte, two rows of two points with 5 bytes of row padding.
#[test]
fn ti_mmwave_layout_by_hand() {
    let pts = [
        [1.0f32, 2.0, 0.5, 7.0, -1.25],
        [3.0, -4.0, 0.0, 8.0, 0.5],
        [-2.0, 0.0, 1.0, 9.0, 2.0],
        [0.25, 0.25, -0.5, 10.0, -0.75],
    ];
    for big in [false, true] {
        let mut data = Vec::new();
        for row in pts.chunks(2) {
            for p in row {
                let mut rec = [0xAAu8; 32]; // garbage in the unused bytes
                for (v, off) in [(p[0], 0), (p[1], 4), (p[2], 8), (p[3], 16), (p[4], 20)] {
                    let b = if big {
                        v.to_be_bytes()
                    } else {
                        v.to_le_bytes()
                    };
                    rec[off..off + 4].copy_from_slice(&b);
                }
                data.extend(rec);
            }
            data.extend([0x55u8; 5]);
        }
        let cloud = PointCloud2 {
            height: 2,
            width: 2,
            fields: vec![
                field("x", 0, PointField::FLOAT32),
                field("y", 4, PointField::FLOAT32),
                field("z", 8, PointField::FLOAT32),
                field("intensity", 16, PointField::FLOAT32),
                field("velocity", 20, PointField::FLOAT32),
            ],
            is_bigendian: big,
            point_step: 32,
            row_step: 69,
            data,
            ..Default::default()
        };
        let fields = FieldsConfig {
            rcs: "intensity".into(),
            ..fields_scalar("velocity")
        };
        let d = decode_detections(&cloud, &fields).unwrap();
        assert_eq!(d.detections.len(), 4);
        for (det, p) in d.detections.iter().zip(&pts) {
            let want = Vec3::new(p[0].into(), p[1].into(), p[2].into());
            assert_eq!(det.p_radar, want);
            assert_eq!(det.v_r, f64::from(p[4]));
            assert_eq!(det.rcs, Some(f64::from(p[3])));
        }
    }
}

/// Mixed integer types, big-endian, fields out of order, a count-3 field (element 0 is read).
#[test]
fn mixed_types_big_endian_by_hand() {
    // point_step 16: v_r FLOAT64 @0, x INT16 @8, y UINT8 @10, rcs INT8 x3 @11..14, z INT16 @14.
    let mut rec = Vec::new();
    rec.extend((-0.5f64).to_be_bytes());
    rec.extend((-300i16).to_be_bytes());
    rec.push(200u8);
    rec.extend([-12i8 as u8, 99, 99]);
    rec.extend(7i16.to_be_bytes());
    assert_eq!(rec.len(), 16);
    let mut rcs = field("rcs", 11, PointField::INT8);
    rcs.count = 3;
    let cloud = PointCloud2 {
        height: 1,
        width: 1,
        fields: vec![
            field("z", 14, PointField::INT16),
            rcs,
            field("y", 10, PointField::UINT8),
            field("x", 8, PointField::INT16),
            field("v_r", 0, PointField::FLOAT64),
        ],
        is_bigendian: true,
        point_step: 16,
        row_step: 16,
        data: rec,
        ..Default::default()
    };
    let d = decode_detections(&cloud, &FieldsConfig::default()).unwrap();
    assert_eq!(
        d.detections,
        vec![Detection {
            p_radar: Vec3::new(-300.0, 200.0, 7.0),
            v_r: -0.5,
            rcs: Some(-12.0),
        }]
    );
}

/// Vector velocity: positive radial velocity means moving away, whatever side the point is on.
#[test]
fn vector_velocity_projects_on_the_ray() {
    // (x, y, vx, vy) -> expected v_r.
    let cases = [
        ([10.0f32, 0.0, 3.0, 5.0], 3.0), // ahead, moving away along x
        ([-10.0, 0.0, 3.0, 5.0], -3.0),  // behind, moving +x = approaching
        ([3.0, 4.0, 3.0, 4.0], 5.0),     // radial vector of length 5, outward
        ([3.0, 4.0, -4.0, 3.0], 0.0),    // tangential
        ([0.0, -2.0, 100.0, 1.5], -1.5), // on the -y axis
    ];
    let mut data = Vec::new();
    for (v, _) in &cases {
        for c in [v[0], v[1], 0.0, v[2], v[3]] {
            data.extend(c.to_le_bytes());
        }
    }
    let cloud = PointCloud2 {
        height: 1,
        width: cases.len() as u32,
        fields: vec![
            field("x", 0, PointField::FLOAT32),
            field("y", 4, PointField::FLOAT32),
            field("z", 8, PointField::FLOAT32),
            field("vx", 12, PointField::FLOAT32),
            field("vy", 16, PointField::FLOAT32),
        ],
        point_step: 20,
        row_step: 20 * cases.len() as u32,
        data,
        ..Default::default()
    };
    let d = decode_detections(&cloud, &fields_vector()).unwrap();
    for (det, (_, want)) in d.detections.iter().zip(&cases) {
        assert!((det.v_r - want).abs() < 1e-12, "{} vs {want}", det.v_r);
        assert_eq!(det.rcs, None, "rcs is absent from the cloud");
    }
}

/// Points with a non-finite required value or zero range are skipped and counted separately; a
/// non-finite rcs only drops the rcs; an empty z name gives z = 0.
#[test]
fn non_dense_points_are_skipped_and_counted() {
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    // x y z v_r rcs
    let pts = [
        [1.0f32, 1.0, 1.0, 1.0, 1.0], // ok
        [nan, 1.0, 1.0, 1.0, 1.0],    // non-finite x
        [1.0, 1.0, inf, 1.0, 1.0],    // non-finite z
        [1.0, 1.0, 1.0, -inf, 1.0],   // non-finite v_r
        [0.0, 0.0, 0.0, 1.0, 1.0],    // zero range
        [0.0, 0.0, 0.0, nan, 1.0],    // non-finite wins over zero range
        [2.0, 0.0, 0.0, 1.0, nan],    // ok, rcs None
        [-0.0, 0.0, 0.0, 0.0, 0.0],   // zero range (negative zero)
    ];
    let mut data = Vec::new();
    for p in &pts {
        for c in p {
            data.extend(c.to_le_bytes());
        }
    }
    let cloud = PointCloud2 {
        height: 1,
        width: pts.len() as u32,
        fields: ["x", "y", "z", "v_r", "rcs"]
            .iter()
            .enumerate()
            .map(|(i, n)| field(n, 4 * i as u32, PointField::FLOAT32))
            .collect(),
        point_step: 20,
        row_step: 20 * pts.len() as u32,
        data,
        is_dense: false,
        ..Default::default()
    };
    let d = decode_detections(&cloud, &FieldsConfig::default()).unwrap();
    assert_eq!(d.detections.len(), 2);
    assert_eq!(d.skipped_nonfinite, 4);
    assert_eq!(d.skipped_zero_range, 2);
    assert_eq!(d.detections[0].rcs, Some(1.0));
    assert_eq!(d.detections[1].rcs, None);

    // z not read: the inf z point becomes valid, z = 0 everywhere.
    let no_z = FieldsConfig {
        z: String::new(),
        ..FieldsConfig::default()
    };
    let d = decode_detections(&cloud, &no_z).unwrap();
    assert_eq!(d.detections.len(), 3);
    assert!(d.detections.iter().all(|det| det.p_radar.z == 0.0));
    // rcs not read.
    let no_rcs = FieldsConfig {
        rcs: String::new(),
        ..FieldsConfig::default()
    };
    let d = decode_detections(&cloud, &no_rcs).unwrap();
    assert!(d.detections.iter().all(|det| det.rcs.is_none()));
}

fn radar_cloud(n: u32) -> PointCloud2 {
    let dets: Vec<Detection> = (0..n)
        .map(|i| Detection {
            p_radar: Vec3::new(1.0 + f64::from(i), 2.0, 0.0),
            v_r: 0.5,
            rcs: Some(1.0),
        })
        .collect();
    encode_detections(&dets, &CloudLayout::radar_f32(), Header::default()).unwrap()
}

#[test]
fn every_error_names_its_cause() {
    let good = radar_cloud(3);
    let fc = FieldsConfig::default();
    let check = |cloud: &PointCloud2, fields: &FieldsConfig, want: DecodeError| {
        assert_eq!(decode_detections(cloud, fields).unwrap_err(), want);
    };

    let mut c = good.clone();
    c.fields.retain(|f| f.name != "v_r");
    check(
        &c,
        &fc,
        DecodeError::MissingField {
            role: "velocity",
            name: "v_r".into(),
            available: "x FLOAT32, y FLOAT32, z FLOAT32, rcs FLOAT32".into(),
        },
    );
    check(
        &good,
        &fields_vector(),
        DecodeError::MissingField {
            role: "velocity_x",
            name: "vx".into(),
            available: "x FLOAT32, y FLOAT32, z FLOAT32, v_r FLOAT32, rcs FLOAT32".into(),
        },
    );
    let no_velocity = FieldsConfig {
        velocity: String::new(),
        ..fc.clone()
    };
    check(
        &good,
        &no_velocity,
        DecodeError::Unconfigured { role: "velocity" },
    );
    let no_x = FieldsConfig {
        x: String::new(),
        ..fc.clone()
    };
    check(&good, &no_x, DecodeError::Unconfigured { role: "x" });

    for bad in [0u8, 9, 255] {
        let mut c = good.clone();
        c.fields[1].datatype = bad;
        check(
            &c,
            &fc,
            DecodeError::UnsupportedDatatype {
                name: "y".into(),
                datatype: bad,
            },
        );
    }
    // rcs is optional, but a present and broken rcs field is an error.
    let mut c = good.clone();
    c.fields[4].datatype = 42;
    assert!(matches!(
        decode_detections(&c, &fc),
        Err(DecodeError::UnsupportedDatatype { ref name, .. }) if name == "rcs"
    ));
    let mut c = good.clone();
    c.fields[2].count = 0;
    check(&c, &fc, DecodeError::ZeroCount { name: "z".into() });
    let mut c = good.clone();
    c.fields[3].offset = 17; // v_r at 17..21 > point_step 20
    check(
        &c,
        &fc,
        DecodeError::FieldPastPointStep {
            name: "v_r".into(),
            offset: 17,
            size: 4,
            point_step: 20,
        },
    );
    let mut c = good.clone();
    c.fields[0].offset = u32::MAX;
    assert!(matches!(
        decode_detections(&c, &fc),
        Err(DecodeError::FieldPastPointStep { .. })
    ));
    let mut c = good.clone();
    c.point_step = 0;
    check(&c, &fc, DecodeError::ZeroPointStep);
    let mut c = good.clone();
    c.row_step = 59;
    check(
        &c,
        &fc,
        DecodeError::RowStepTooSmall {
            row_step: 59,
            width: 3,
            point_step: 20,
        },
    );
    let mut c = good.clone();
    c.data.pop();
    check(
        &c,
        &fc,
        DecodeError::Truncated {
            needed: 60,
            len: 59,
        },
    );
    let mut c = good.clone();
    c.height = u32::MAX;
    c.width = u32::MAX;
    c.row_step = u32::MAX;
    c.point_step = 1;
    check(
        &c,
        &fc,
        DecodeError::Truncated {
            needed: u64::from(u32::MAX) * u64::from(u32::MAX),
            len: 60,
        },
    );

    // The message text names the field.
    let mut c = good.clone();
    c.fields[1].name = "why".into();
    let msg = decode_detections(&c, &fc).unwrap_err().to_string();
    assert!(msg.contains("`y`"), "{msg}");
}

#[test]
fn empty_clouds_and_buffer_reuse() {
    // No points: nothing to decode and no layout needed (drivers publish such clouds between targets).
    let empty = PointCloud2::default();
    let d = decode_detections(&empty, &FieldsConfig::default()).unwrap();
    assert_eq!(d, DecodedCloud::default());

    let mut out = DecodedCloud::default();
    decode_detections_into(&radar_cloud(5), &FieldsConfig::default(), &mut out).unwrap();
    assert_eq!(out.detections.len(), 5);
    decode_detections_into(&radar_cloud(2), &FieldsConfig::default(), &mut out).unwrap();
    assert_eq!(out.detections.len(), 2, "cleared before refilling");
    let mut broken = radar_cloud(2);
    broken.point_step = 0;
    assert!(decode_detections_into(&broken, &FieldsConfig::default(), &mut out).is_err());
    assert!(out.detections.is_empty(), "cleared on error");
}

#[test]
fn duplicate_names_use_the_first_field() {
    let mut c = radar_cloud(1);
    // A second `x` after the real one, pointing at the y bytes.
    c.fields.push(field("x", 4, PointField::FLOAT32));
    let d = decode_detections(&c, &FieldsConfig::default()).unwrap();
    assert_eq!(d.detections[0].p_radar.x, 1.0);
}

#[test]
fn encoder_rejects_bad_layouts() {
    let dets = vec![
        Detection {
            p_radar: Vec3::new(1.0, 0.0, 0.0),
            v_r: 0.0,
            rcs: None,
        };
        3
    ];
    let mut l = CloudLayout::radar_f32();
    l.rows = 2;
    assert_eq!(
        encode_detections(&dets, &l, Header::default()).unwrap_err(),
        EncodeError::RowsDoNotDivide { points: 3, rows: 2 }
    );
    l.rows = 0;
    assert_eq!(
        encode_detections(&dets, &l, Header::default()).unwrap_err(),
        EncodeError::ZeroRows
    );
    let mut l = CloudLayout::radar_f32();
    l.fields[2].datatype = 0;
    assert!(matches!(
        encode_detections(&dets, &l, Header::default()),
        Err(EncodeError::UnsupportedDatatype { ref name, datatype: 0 }) if name == "z"
    ));
}

/// The nuScenes-like layout: point_step 43, packed offsets as in the PCD, and `vx, vy` equal the radial
/// velocity vector `v_r p / |p|` for planar points.
#[test]
fn nuscenes_layout_writes_the_radial_vector() {
    let dets = vec![
        Detection {
            p_radar: Vec3::new(-3.0, 4.0, 0.0),
            v_r: 2.5,
            rcs: Some(-5.0),
        },
        Detection {
            p_radar: Vec3::new(30.0, -0.5, 0.0),
            v_r: -7.0,
            rcs: None,
        },
    ];
    let layout = CloudLayout::nuscenes_radar();
    let c = encode_detections(&dets, &layout, Header::default()).unwrap();
    assert_eq!(c.point_step, 43);
    let offsets: Vec<u32> = c.fields.iter().map(|f| f.offset).collect();
    assert_eq!(
        offsets,
        [
            0, 4, 8, 12, 13, 15, 19, 23, 27, 31, 35, 36, 37, 38, 39, 40, 41, 42
        ]
    );
    let f32_at = |i: usize, off: usize| {
        f32::from_le_bytes(c.data[i * 43 + off..i * 43 + off + 4].try_into().unwrap())
    };
    // Point 0: v_r p / |p| = 2.5 * (-0.6, 0.8).
    assert!((f32_at(0, 19) - -1.5).abs() < 1e-6);
    assert!((f32_at(0, 23) - 2.0).abs() < 1e-6);
    assert!(f32_at(1, 15).is_nan(), "missing rcs written as NaN");
    let d = decode_detections(&c, &layout.fields_config()).unwrap();
    for (a, b) in d.detections.iter().zip(&dets) {
        assert!((a.v_r - b.v_r).abs() < 1e-5);
        assert!((a.p_radar - b.p_radar).norm() < 1e-5);
    }
    assert_eq!(d.detections[0].rcs, Some(-5.0));
    assert_eq!(d.detections[1].rcs, None);
}

/// Value range usable for each type in the round trip, and whether values must be integers.
fn value_range(t: ScalarType) -> (f64, f64, bool) {
    match t {
        ScalarType::I8 => (-128.0, 127.0, true),
        ScalarType::U8 => (0.0, 255.0, true),
        ScalarType::I16 | ScalarType::I32 => (-300.0, 300.0, true),
        ScalarType::U16 | ScalarType::U32 => (0.0, 300.0, true),
        ScalarType::F32 | ScalarType::F64 => (-300.0, 300.0, false),
    }
}

fn draw(rng: &mut StdRng, t: ScalarType) -> f64 {
    let (lo, hi, int) = value_range(t);
    let v = rng.random_range(lo..=hi);
    if int { v.round() } else { v }
}

/// Relative rounding error of a type (0 for the integers: the test uses integer values there).
fn epsilon(t: ScalarType) -> f64 {
    match t {
        ScalarType::F64 => f64::EPSILON,
        ScalarType::F32 => f64::from(f32::EPSILON),
        _ => 0.0,
    }
}

fn close(a: f64, b: f64, t: ScalarType, scale: f64) -> bool {
    match t {
        ScalarType::F64 => (a - b).abs() <= 1e-12 * scale.max(1.0),
        ScalarType::F32 => (a - b).abs() <= 2e-7 * scale.max(1.0),
        _ => a == b,
    }
}

/// decode(encode(x)) == x within each type's precision, over random layouts: every datatype, both byte
/// orders, shuffled field order, gaps, point and row padding, several rows, scalar and vector velocity,
/// with and without z and rcs, extra fields.
#[test]
fn round_trip_over_random_layouts() {
    let mut rng = StdRng::seed_from_u64(20220523);
    let floats = [ScalarType::F32, ScalarType::F64];
    for case in 0..600 {
        let any = |rng: &mut StdRng| *ScalarType::ALL.choose(rng).unwrap();
        let (tx, ty) = (any(&mut rng), any(&mut rng));
        let tz = rng.random_bool(0.7).then(|| any(&mut rng));
        let vector = rng.random_bool(0.5);
        // The vector path divides by the range: keep it in floats to compare within precision.
        let tv = if vector {
            *floats.choose(&mut rng).unwrap()
        } else {
            any(&mut rng)
        };
        let trcs = rng.random_bool(0.7).then(|| any(&mut rng));

        let mut fields = vec![
            LayoutField::new("px", FieldRole::X, tx.datatype()),
            LayoutField::new("py", FieldRole::Y, ty.datatype()),
        ];
        if let Some(t) = tz {
            fields.push(LayoutField::new("pz", FieldRole::Z, t.datatype()));
        }
        if vector {
            fields.push(LayoutField::new(
                "vel_x",
                FieldRole::VelocityX,
                tv.datatype(),
            ));
            fields.push(LayoutField::new(
                "vel_y",
                FieldRole::VelocityY,
                tv.datatype(),
            ));
        } else {
            fields.push(LayoutField::new(
                "doppler",
                FieldRole::RadialVelocity,
                tv.datatype(),
            ));
        }
        if let Some(t) = trcs {
            fields.push(LayoutField::new("intensity", FieldRole::Rcs, t.datatype()));
        }
        for k in 0..rng.random_range(0..3) {
            fields.push(LayoutField::new(
                format!("extra{k}"),
                FieldRole::Zero,
                any(&mut rng).datatype(),
            ));
        }
        fields.shuffle(&mut rng);
        for f in &mut fields {
            f.gap_before = rng.random_range(0..4);
        }
        let rows = rng.random_range(1..4u32);
        let layout = CloudLayout {
            fields,
            is_bigendian: rng.random_bool(0.5),
            point_padding: rng.random_range(0..9),
            row_padding: rng.random_range(0..17),
            rows,
        };

        let n = rows as usize * rng.random_range(1..20usize);
        let mut dets = Vec::with_capacity(n);
        while dets.len() < n {
            let p = Vec3::new(
                draw(&mut rng, tx),
                draw(&mut rng, ty),
                tz.map_or(0.0, |t| draw(&mut rng, t)),
            );
            // Zero range is skipped by design; the vector path needs the point off the z axis.
            if p.norm() == 0.0 || (vector && p.x.abs() + p.y.abs() < 1.0) {
                continue;
            }
            let v_r = if vector {
                rng.random_range(-40.0..40.0)
            } else {
                draw(&mut rng, tv).clamp(-100.0, 100.0)
            };
            dets.push(Detection {
                p_radar: p,
                v_r,
                rcs: trcs.map(|t| draw(&mut rng, t)),
            });
        }

        let cloud = encode_detections(&dets, &layout, Header::default()).unwrap();
        assert_eq!(cloud.height, rows);
        assert!(cloud.is_dense);
        let back = decode_detections(&cloud, &layout.fields_config()).unwrap();
        assert_eq!(back.detections.len(), n, "case {case}");
        for (a, b) in back.detections.iter().zip(&dets) {
            let ctx = format!("case {case}: {a:?} vs {b:?} ({layout:?})");
            assert!(
                close(a.p_radar.x, b.p_radar.x, tx, b.p_radar.x.abs()),
                "{ctx}"
            );
            assert!(
                close(a.p_radar.y, b.p_radar.y, ty, b.p_radar.y.abs()),
                "{ctx}"
            );
            match tz {
                Some(t) => assert!(
                    close(a.p_radar.z, b.p_radar.z, t, b.p_radar.z.abs()),
                    "{ctx}"
                ),
                None => assert_eq!(a.p_radar.z, 0.0, "{ctx}"),
            }
            if vector {
                // Rounding x, y, z, vx, vy by a relative eps moves v_r by about eps |v_xy|, and
                // |v_xy| = |v_r| |p| / |p_xy| for the vector the encoder writes.
                let p = b.p_radar;
                let eps = [Some(tx), Some(ty), tz, Some(tv)]
                    .into_iter()
                    .flatten()
                    .map(epsilon)
                    .fold(0.0, f64::max);
                let tol = 10.0 * eps * (b.v_r.abs() * p.norm() / p.xy().norm() + 1.0);
                assert!((a.v_r - b.v_r).abs() <= tol, "{ctx}");
            } else {
                assert!(close(a.v_r, b.v_r, tv, b.v_r.abs()), "{ctx}");
            }
            match (trcs, a.rcs, b.rcs) {
                (Some(t), Some(x), Some(y)) => assert!(close(x, y, t, y.abs()), "{ctx}"),
                (None, None, _) => {}
                _ => panic!("rcs mismatch: {ctx}"),
            }
        }
    }
}

/// Thousands of random and mutated clouds: decode returns Ok or Err, never panics, and on Ok the
/// counts add up and every detection is finite with a non-zero range.
#[test]
fn fuzz_never_panics() {
    let mut rng = StdRng::seed_from_u64(7);
    let names = ["x", "y", "z", "v_r", "rcs", "vx", "vy", "intensity", ""];
    let configs = [
        FieldsConfig::default(),
        fields_vector(),
        FieldsConfig {
            z: String::new(),
            rcs: String::new(),
            ..FieldsConfig::default()
        },
        FieldsConfig {
            velocity: String::new(),
            ..FieldsConfig::default()
        },
    ];
    let (mut oks, mut errs) = (0, 0);
    let mut out = DecodedCloud::default();
    for case in 0..6000 {
        let cloud = if case % 2 == 0 {
            random_cloud(&mut rng, &names)
        } else {
            mutated_cloud(&mut rng)
        };
        let fields = configs.choose(&mut rng).unwrap();
        match decode_detections_into(&cloud, fields, &mut out) {
            Ok(()) => {
                oks += 1;
                let total = u64::from(cloud.height) * u64::from(cloud.width);
                let seen = out.detections.len() + out.skipped_nonfinite + out.skipped_zero_range;
                assert_eq!(seen as u64, total, "case {case}");
                for d in &out.detections {
                    assert!(d.p_radar.iter().all(|v| v.is_finite()) && d.v_r.is_finite());
                    assert!(d.range() > 0.0);
                    assert!(d.rcs.is_none_or(f64::is_finite));
                }
            }
            Err(e) => {
                errs += 1;
                assert!(!e.to_string().is_empty());
            }
        }
    }
    // Both outcomes must have been exercised for the fuzz to mean anything.
    assert!(oks > 500 && errs > 500, "ok {oks}, err {errs}");
}

fn random_cloud(rng: &mut StdRng, names: &[&str]) -> PointCloud2 {
    let point_step = match rng.random_range(0..10) {
        0 => 0,
        1 => u32::MAX,
        _ => rng.random_range(1..48),
    };
    let n_fields = rng.random_range(0..8);
    let fields = (0..n_fields)
        .map(|_| PointField {
            name: names.choose(rng).unwrap().to_string(),
            offset: if rng.random_bool(0.05) {
                rng.random()
            } else {
                rng.random_range(0..48)
            },
            datatype: rng.random_range(0..11),
            count: rng.random_range(0..3),
        })
        .collect();
    let dim = |rng: &mut StdRng| match rng.random_range(0..10) {
        0 => u32::MAX,
        1 => rng.random(),
        2 => 0,
        _ => rng.random_range(1..8),
    };
    let (height, width) = (dim(rng), dim(rng));
    let row_step = match rng.random_range(0..4) {
        0 => rng.random(),
        1 => rng.random_range(0..64),
        _ => width
            .saturating_mul(point_step)
            .saturating_add(rng.random_range(0..5)),
    };
    let len = rng.random_range(0..1500);
    let data = (0..len).map(|_| rng.random()).collect();
    PointCloud2 {
        height,
        width,
        fields,
        is_bigendian: rng.random_bool(0.5),
        point_step,
        row_step,
        data,
        ..Default::default()
    }
}

fn mutated_cloud(rng: &mut StdRng) -> PointCloud2 {
    let dets: Vec<Detection> = (0..rng.random_range(0..30))
        .map(|_| Detection {
            p_radar: Vec3::new(
                rng.random_range(-50.0..50.0),
                rng.random_range(-50.0..50.0),
                0.0,
            ),
            v_r: rng.random_range(-10.0..10.0),
            rcs: Some(1.0),
        })
        .collect();
    let layout = if rng.random_bool(0.5) {
        CloudLayout::radar_f32()
    } else {
        CloudLayout::nuscenes_radar()
    };
    let mut c = encode_detections(&dets, &layout, Header::default()).unwrap();
    for _ in 0..rng.random_range(1..4) {
        match rng.random_range(0..9) {
            0 => c.data.truncate(rng.random_range(0..=c.data.len())),
            1 => {
                // Random bytes (NaN/inf patterns included).
                for _ in 0..rng.random_range(1..20) {
                    if !c.data.is_empty() {
                        let i = rng.random_range(0..c.data.len());
                        c.data[i] = rng.random();
                    }
                }
            }
            2 => c.width = rng.random(),
            3 => c.height = rng.random(),
            4 => c.row_step = rng.random(),
            5 => c.point_step = rng.random_range(0..50),
            6 => {
                if !c.fields.is_empty() {
                    let i = rng.random_range(0..c.fields.len());
                    let f = &mut c.fields[i];
                    match rng.random_range(0..3) {
                        0 => f.datatype = rng.random(),
                        1 => f.offset = rng.random_range(0..60),
                        _ => f.count = rng.random_range(0..3),
                    }
                }
            }
            7 => {
                // Duplicate a field with a new offset.
                if let Some(f) = c.fields.choose(rng).cloned() {
                    c.fields.insert(
                        0,
                        PointField {
                            offset: rng.random_range(0..60),
                            ..f
                        },
                    );
                }
            }
            _ => c.is_bigendian = !c.is_bigendian,
        }
    }
    c
}

/// A missing field's error says what a user needs to fix the name: the configured name, its role, and
/// every field of the cloud with its datatype (and count when not 1), unknown datatypes as their code.
#[test]
fn a_missing_field_names_the_clouds_fields() {
    let mut c = radar_cloud(2);
    c.fields[2].count = 3;
    c.fields[4].datatype = PointField::INT8;
    c.fields.push(PointField {
        name: "odd".into(),
        offset: 0,
        datatype: 42,
        count: 1,
    });
    let fields = FieldsConfig {
        velocity: "v".into(),
        ..FieldsConfig::default()
    };
    let e = decode_detections(&c, &fields).unwrap_err().to_string();
    assert_eq!(
        e,
        "field `v` (velocity) is not in the cloud; its fields: x FLOAT32, y FLOAT32, z FLOAT32[3], \
         v_r FLOAT32, rcs INT8, odd datatype 42"
    );
}
