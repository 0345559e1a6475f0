//! Doppler ego-motion on the real sensor files: the velocity fitted by RANSAC from the
//! raw radial velocities alone must match the velocity implied by the sensors' own compensated fields
//! (nuScenes: raw minus `*_comp`; View-of-Delft: `v_r - v_r_compensated`) within 0.05 m/s.
//!
//! The reference is computed here independently: a plain least-squares fit of
//! `d . (v_raw - v_comp) = -d . v_ego` over every point, which holds exactly for static and moving points
//! alike because the compensation removes the same ego term from each.
//!
//! nuScenes caveat, measured here: on both files the Doppler of the points the radar itself flags as
//! stationary (`dyn_prop` 1 or 3, |v_comp| < 0.5 m/s) implies a speed 1.7-2.0 % higher than the ego velocity
//! behind the `*_comp` fields (a scale difference between the ARS408's Doppler and the vehicle speed used
//! for the compensation; the same on a Boston and a Singapore vehicle). No estimator that sees only the
//! Doppler can land within 0.05 m/s of that reference at 9.4 m/s; ours lands within 0.05 m/s of the
//! Doppler truth (the least-squares fit over the radar's own stationary points) and within 2.5 % of the
//! compensated-field velocity. View-of-Delft has no such offset and meets 0.05 m/s against its reference.

mod common;

use dc_loc::io::nuscenes_pcd::{NuscenesRadarFilter, NuscenesRadarPcd};
use dc_loc::io::vod;
use dc_loc::math::Vec3;
use dc_loc::radar::Detection;
use dc_loc::radar::ego_motion::{EgoMotionConfig, FitDims, fit_radar_velocity};
use nalgebra::{DMatrix, DVector};

/// Least squares `b_i = -d_i . v` over the given rays (3 columns; planar fits pass z = 0 rays and
/// get a zero z component back through the pseudo-inverse).
fn reference_fit(rows: &[(Vec3, f64)], dims: usize) -> Vec3 {
    let a = DMatrix::from_fn(rows.len(), dims, |i, k| -rows[i].0[k]);
    let b = DVector::from_iterator(rows.len(), rows.iter().map(|r| r.1));
    let x = a.svd(true, true).solve(&b, 1e-12).unwrap();
    let mut v = Vec3::zeros();
    for k in 0..dims {
        v[k] = x[k];
    }
    v
}

#[test]
fn nuscenes_doppler_fit_matches_compensated_fields() {
    let Some(root) = common::real_data() else {
        return;
    };
    for file in [
        "nuscenes-radar-pcd/n008-2018-08-01-15-34-25-0400__RADAR_BACK_RIGHT__1533152711219287.pcd",
        "nuscenes-radar-pcd/n015-2018-07-25-16-15-50+0800__RADAR_BACK_LEFT__1532506682462345.pcd",
    ] {
        let pcd = NuscenesRadarPcd::read(root.join(file)).unwrap();
        // Reference: radial part of (raw - comp) over every point.
        let rows: Vec<(Vec3, f64)> = pcd
            .points
            .iter()
            .filter_map(|p| {
                let d = p.p_radar().try_normalize(0.0)?;
                let dv = Vec3::new(
                    f64::from(p.vx - p.vx_comp),
                    f64::from(p.vy - p.vy_comp),
                    0.0,
                );
                Some((d, d.dot(&dv)))
            })
            .collect();
        let v_ref = reference_fit(&rows, 2);
        // Ours: raw radial velocities only, no flags, moving points included.
        let dets: Vec<Detection> = pcd.detections(&NuscenesRadarFilter::keep_all());
        let fit =
            fit_radar_velocity(&dets, FitDims::Auto, &[], &EgoMotionConfig::default()).unwrap();
        // Doppler truth: least squares over the points the radar flags stationary, raw radial velocity.
        let stationary: Vec<(Vec3, f64)> = pcd
            .points
            .iter()
            .filter(|p| {
                matches!(p.dyn_prop, 1 | 3)
                    && f64::from(p.vx_comp).hypot(f64::from(p.vy_comp)) < 0.5
            })
            .filter_map(|p| Some((p.p_radar().try_normalize(0.0)?, p.radial_velocity()?)))
            .collect();
        let v_doppler = reference_fit(&stationary, 2);
        let err_doppler = (fit.v_radar - v_doppler).norm();
        let err = (fit.v_radar - v_ref).norm();
        println!(
            "{file}: fitted {:.3?}; Doppler of flagged-stationary points {:.3?} (|err| {err_doppler:.4}); \
             compensated-field reference {:.3?} (|err| {err:.4} m/s = {:.1} %); {} of {} static",
            fit.v_radar.as_slice(),
            v_doppler.as_slice(),
            v_ref.as_slice(),
            100.0 * err / v_ref.norm(),
            fit.num_inliers,
            dets.len()
        );
        assert!(
            err_doppler < 0.05,
            "{file}: fitted {:?} vs stationary Doppler {:?}",
            fit.v_radar,
            v_doppler
        );
        assert!(
            err < 0.025 * v_ref.norm(),
            "{file}: fitted {:?} vs reference {:?}",
            fit.v_radar,
            v_ref
        );
        assert_eq!(fit.v_radar.z, 0.0, "ARS408 has no elevation: planar fit");
        // Points the radar itself calls moving (dyn_prop 0 moving, 2 oncoming, 6 crossing moving) with a
        // clearly non-zero compensated speed must not be called static by our fit.
        for (p, d) in pcd.points.iter().zip(&dets) {
            let v_comp = (f64::from(p.vx_comp).powi(2) + f64::from(p.vy_comp).powi(2)).sqrt();
            if matches!(p.dyn_prop, 0 | 2 | 6) && v_comp > 1.0 {
                let resid = (d.v_r + d.p_radar.normalize().dot(&fit.v_radar)).abs();
                assert!(
                    resid > EgoMotionConfig::default().inlier_threshold,
                    "mover kept as static"
                );
            }
        }
    }
}

#[test]
fn view_of_delft_doppler_fit_matches_compensated_fields() {
    let Some(root) = common::real_data() else {
        return;
    };
    for frame in ["00549", "01047", "01201"] {
        let pts = vod::read_radar_bin(root.join(format!(
            "view-of-delft-example/radar/training/velodyne/{frame}.bin"
        )))
        .unwrap();
        let rows: Vec<(Vec3, f64)> = pts
            .iter()
            .filter_map(|p| {
                Some((
                    p.p_radar().try_normalize(0.0)?,
                    f64::from(p.v_r - p.v_r_compensated),
                ))
            })
            .collect();
        let v_ref = reference_fit(&rows, 3);
        let dets: Vec<Detection> = pts.iter().filter_map(|p| p.to_detection()).collect();
        let fit =
            fit_radar_velocity(&dets, FitDims::Auto, &[], &EgoMotionConfig::default()).unwrap();
        let err = (fit.v_radar - v_ref).norm();
        println!(
            "VoD {frame}: fitted {:.3?} reference {:.3?} |err| {err:.4} m/s, {} of {} static",
            fit.v_radar.as_slice(),
            v_ref.as_slice(),
            fit.num_inliers,
            dets.len()
        );
        assert!(
            err < 0.05,
            "VoD {frame}: fitted {:?} vs {:?}",
            fit.v_radar,
            v_ref
        );
    }
}
