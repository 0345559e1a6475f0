//! TUM trajectory files: one pose a line, `t x y z qx qy qz qw` (t in seconds, the position in metres,
//! the orientation as a unit quaternion), blank lines and `#` comment lines skipped. Datasets ship their
//! ground truth this way (NTU4DRadLM, SNAIL-Radar, MSC-RAD4R), and `dc_loc` writes odometry and
//! simulated ground truth this way.
//!
//! Entry points: [`read_tum`] / [`parse_tum`] (the poses, stamps exact to the nanosecond, every
//! malformed line refused with its line number and the reason), [`ground_truth_inputs`] (the poses as
//! the pipeline's ground-truth inputs) and [`tum_line`] (one pose as a line).

use std::path::Path;

use super::ground_truth::PoseSpeed;
use dc_loc_core::input::Input;
use dc_loc_core::math::{Iso3, Quat, Stamp, Vec3};

/// How far a quaternion's norm may be from 1 and still be taken (then normalised): the rounding of
/// quaternions printed with a few decimals, not a quaternion of another convention or scale.
const QUATERNION_NORM_TOLERANCE: f64 = 0.01;

/// One pose of a trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TumPose {
    /// Its stamp.
    pub stamp: Stamp,
    /// The tracked frame's pose in the trajectory's fixed frame.
    pub pose: Iso3,
}

/// Why a TUM file could not be read.
#[derive(Debug, thiserror::Error)]
pub enum TumError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A line is not a pose.
    #[error("{path}:{line}: {reason}")]
    Line {
        /// The file.
        path: String,
        /// Its line number, from 1.
        line: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// The file has no pose at all.
    #[error("{path}: no poses (only blank or `#` comment lines)")]
    Empty {
        /// The file.
        path: String,
    },
}

/// The poses of the TUM file `path` (see [`parse_tum`]).
pub fn read_tum(path: &Path) -> Result<Vec<TumPose>, TumError> {
    let name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| TumError::Io {
        path: name.clone(),
        source,
    })?;
    parse_tum(&text, &name)
}

/// The poses of the TUM text `text`, named `path` in errors. Refuses a line that has not eight
/// numbers, a stamp that is not a decimal number or not after the previous line's, a position that is
/// not finite, and a quaternion that is not finite or not of unit norm (within 1 %; a near-unit one is
/// normalised).
pub fn parse_tum(text: &str, path: &str) -> Result<Vec<TumPose>, TumError> {
    let mut poses: Vec<TumPose> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let pose = parse_line(line).and_then(|pose| match poses.last() {
            Some(prev) if pose.stamp <= prev.stamp => Err(format!(
                "stamp {} s is not after the previous pose's ({} s)",
                stamp_text(pose.stamp),
                stamp_text(prev.stamp)
            )),
            _ => Ok(pose),
        });
        poses.push(pose.map_err(|reason| TumError::Line {
            path: path.to_string(),
            line: i + 1,
            reason,
        })?);
    }
    if poses.is_empty() {
        return Err(TumError::Empty {
            path: path.to_string(),
        });
    }
    Ok(poses)
}

/// One line's pose: `t x y z qx qy qz qw`.
fn parse_line(line: &str) -> Result<TumPose, String> {
    let fields: Vec<&str> = line.split_whitespace().collect();
    let [t, rest @ ..] = fields.as_slice() else {
        return Err("empty line".into());
    };
    if rest.len() != 7 {
        return Err(format!(
            "{} values, expected 8 (t x y z qx qy qz qw)",
            fields.len()
        ));
    }
    let stamp = parse_stamp(t)?;
    let mut v = [0.0; 7];
    for ((value, text), name) in v
        .iter_mut()
        .zip(rest)
        .zip(["x", "y", "z", "qx", "qy", "qz", "qw"])
    {
        *value = text
            .parse::<f64>()
            .map_err(|_| format!("{name} `{text}` is not a number"))?;
    }
    let [x, y, z, qx, qy, qz, qw] = v;
    let position = Vec3::new(x, y, z);
    if !position.iter().all(|c| c.is_finite()) {
        return Err(format!("position ({x}, {y}, {z}) is not finite"));
    }
    let rotation = unit_quaternion(qx, qy, qz, qw)?;
    Ok(TumPose {
        stamp,
        pose: Iso3::from_parts(position.into(), rotation),
    })
}

/// The rotation of a quaternion whose norm is 1 within [`QUATERNION_NORM_TOLERANCE`].
fn unit_quaternion(qx: f64, qy: f64, qz: f64, qw: f64) -> Result<Quat, String> {
    let q = nalgebra::Quaternion::new(qw, qx, qy, qz);
    let norm = q.norm();
    if !norm.is_finite() {
        return Err(format!("quaternion ({qx}, {qy}, {qz}, {qw}) is not finite"));
    }
    if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(format!(
            "quaternion ({qx}, {qy}, {qz}, {qw}) has norm {norm:.6}, not 1"
        ));
    }
    Ok(Quat::new_normalize(q))
}

/// A decimal number of seconds (`1700000000.123456789`, `-0.5`, `1.7e9`) as a stamp, read digit by
/// digit so that every nanosecond the text gives is kept (an f64 of seconds today keeps only about
/// 0.2 us); digits below the nanosecond are rounded.
fn parse_stamp(text: &str) -> Result<Stamp, String> {
    let bad = || format!("stamp `{text}` is not a decimal number of seconds");
    let (negative, unsigned) = match text.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, text.strip_prefix('+').unwrap_or(text)),
    };
    let (mantissa, exponent) = match unsigned.split_once(['e', 'E']) {
        Some((m, e)) => (m, e.parse::<i64>().map_err(|_| bad())?),
        None => (unsigned, 0),
    };
    let (int, frac) = mantissa.split_once('.').unwrap_or((mantissa, ""));
    let is_digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
    if (int.is_empty() && frac.is_empty()) || !is_digits(int) || !is_digits(frac) {
        return Err(bad());
    }
    let all = format!("{int}{frac}");
    let digits = all.trim_start_matches('0');
    // The digits are an integer; this power of ten makes it nanoseconds.
    let shift = 9 + exponent - frac.len() as i64;
    let out_of_range = || format!("stamp `{text}` is out of range");
    let ns = if shift >= 0 {
        let scale = u32::try_from(shift)
            .ok()
            .and_then(|s| 10i128.checked_pow(s));
        match (digits.is_empty(), scale) {
            (true, _) => 0,
            (false, None) => return Err(out_of_range()),
            (false, Some(scale)) => digits
                .parse::<i128>()
                .ok()
                .and_then(|d| d.checked_mul(scale))
                .ok_or_else(out_of_range)?,
        }
    } else {
        let kept = digits.len() as i64 + shift;
        if kept < 0 {
            0
        } else {
            let (whole, dropped) = digits.split_at(kept as usize);
            let whole = if whole.is_empty() {
                0
            } else {
                whole.parse::<i128>().map_err(|_| out_of_range())?
            };
            whole + i128::from(dropped.as_bytes().first().is_some_and(|&d| d >= b'5'))
        }
    };
    let ns = if negative { -ns } else { ns };
    i64::try_from(ns).map(Stamp).map_err(|_| out_of_range())
}

/// `stamp` in seconds, to the nanosecond, written from its integer nanoseconds.
fn stamp_text(stamp: Stamp) -> String {
    let ns = stamp.0.unsigned_abs();
    let sign = if stamp.0 < 0 { "-" } else { "" };
    format!("{sign}{}.{:09}", ns / 1_000_000_000, ns % 1_000_000_000)
}

/// A pose as a TUM line: `stamp x y z qx qy qz qw`, the stamp to the nanosecond (written from its
/// integer nanoseconds: a float of seconds keeps only about 0.2 us at today's epoch).
pub fn tum_line(stamp: Stamp, t: &Iso3) -> String {
    let (p, q) = (t.translation.vector, t.rotation.coords);
    format!(
        "{} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}",
        stamp_text(stamp),
        p.x,
        p.y,
        p.z,
        q.x,
        q.y,
        q.z,
        q.w
    )
}

/// `poses` as ground-truth inputs: the poses as they are, the speed by the rule of ground truth without
/// a twist ([`PoseSpeed`]).
pub fn ground_truth_inputs(poses: &[TumPose]) -> Vec<Input> {
    let mut speed = PoseSpeed::default();
    let mut inputs = Vec::with_capacity(poses.len());
    for p in poses {
        inputs.extend(speed.push(p.stamp, &p.pose));
    }
    inputs.extend(speed.finish());
    inputs
}

#[cfg(test)]
mod tests {
    use super::*;
    use dc_loc_core::math::iso3_from_xyz_rpy;

    fn line_error(text: &str) -> (usize, String) {
        match parse_tum(text, "gt.txt") {
            Err(TumError::Line { line, reason, .. }) => (line, reason),
            other => panic!("expected a line error, got {other:?}"),
        }
    }

    #[test]
    fn stamps_are_exact_to_the_nanosecond() {
        let s = |t: &str| parse_stamp(t).unwrap().0;
        assert_eq!(s("1700000000.123456789"), 1_700_000_000_123_456_789);
        assert_eq!(s("1700000000"), 1_700_000_000_000_000_000);
        assert_eq!(s("1700000000.5"), 1_700_000_000_500_000_000);
        assert_eq!(s("0.000000001"), 1);
        assert_eq!(s(".25"), 250_000_000);
        assert_eq!(s("-0.5"), -500_000_000);
        assert_eq!(s("1.700000000123456789e9"), 1_700_000_000_123_456_789);
        assert_eq!(s("1.7E+9"), 1_700_000_000_000_000_000);
        // Below the nanosecond: rounded.
        assert_eq!(s("1.0000000014"), 1_000_000_001);
        assert_eq!(s("1.0000000015"), 1_000_000_002);
        assert_eq!(s("0.0000000004"), 0);
        for bad in ["", ".", "1.2.3", "1,5", "abc", "1e", "0x10", "nan", "inf"] {
            assert!(parse_stamp(bad).is_err(), "{bad}");
        }
        assert!(parse_stamp("1e30").unwrap_err().contains("out of range"));
    }

    #[test]
    fn comments_and_blank_lines_are_skipped_and_a_near_unit_quaternion_normalised() {
        let text = "# timestamp tx ty tz qx qy qz qw\n\n\
                    1700000000.123456789 1 2 3 0 0 0 1\n  # a comment after a pose\n\
                    1700000000.223456789\t4 5 6 0 0 0.7071 0.7071\n";
        let poses = parse_tum(text, "gt.txt").unwrap();
        assert_eq!(poses.len(), 2);
        assert_eq!(poses[0].stamp, Stamp(1_700_000_000_123_456_789));
        assert_eq!(poses[0].pose.translation.vector, Vec3::new(1.0, 2.0, 3.0));
        let yaw = poses[1].pose.rotation.euler_angles().2;
        assert!((yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-9, "{yaw}");
        assert!((poses[1].pose.rotation.coords.norm() - 1.0).abs() < 1e-15);
    }

    #[test]
    fn a_bad_line_is_named_with_its_number_and_reason() {
        let good = "# header\n1.0 0 0 0 0 0 0 1\n";
        let (line, reason) = line_error(&format!("{good}2.0 0 0 0 0 0 1\n"));
        assert_eq!(line, 3);
        assert!(reason.contains("7 values, expected 8"), "{reason}");
        let (line, reason) = line_error(&format!("{good}\n2.0 0 0 x 0 0 0 1\n"));
        assert_eq!(line, 4);
        assert!(reason.contains("z `x` is not a number"), "{reason}");
        let (line, reason) = line_error("1.0 0 0 0 0 0 0 2\n");
        assert_eq!(line, 1);
        assert!(reason.contains("norm 2.000000, not 1"), "{reason}");
        let (_, reason) = line_error("1.0 0 0 0 NaN 0 0 1\n");
        assert!(reason.contains("not finite"), "{reason}");
        let (_, reason) = line_error("1.0 inf 0 0 0 0 0 1\n");
        assert!(reason.contains("position"), "{reason}");
        let (line, reason) = line_error(&format!("{good}1.0 0 0 0 0 0 0 1\n"));
        assert_eq!(line, 3);
        assert!(reason.contains("not after"), "{reason}");
        let (_, reason) = line_error("1,0 0 0 0 0 0 0 1\n");
        assert!(reason.contains("stamp `1,0`"), "{reason}");
        let err = parse_tum("# only a comment\n", "gt.txt").unwrap_err();
        assert_eq!(
            err.to_string(),
            "gt.txt: no poses (only blank or `#` comment lines)"
        );
    }

    #[test]
    fn written_lines_read_back_to_the_nanosecond() {
        let t = iso3_from_xyz_rpy(1.5, -2.25, 0.125, 0.0, 0.0, 0.3);
        for stamp in [Stamp(1_700_000_000_123_456_789), Stamp(-1_500_000_001)] {
            let back = parse_tum(&tum_line(stamp, &t), "-").unwrap();
            assert_eq!(back[0].stamp, stamp);
            assert!((back[0].pose.translation.vector - t.translation.vector).norm() < 1e-6);
            assert!(back[0].pose.rotation.angle_to(&t.rotation) < 1e-8);
        }
    }

    #[test]
    fn ground_truth_inputs_carry_the_speed_of_consecutive_poses() {
        let at = |ns: i64, x: f64| TumPose {
            stamp: Stamp(ns),
            pose: iso3_from_xyz_rpy(x, 0.0, 0.0, 0.0, 0.0, 0.0),
        };
        let inputs = ground_truth_inputs(&[at(0, 0.0), at(100_000_000, 2.0)]);
        let speeds: Vec<f64> = inputs
            .iter()
            .map(|i| match i {
                Input::GroundTruth { speed, .. } => *speed,
                _ => panic!("not ground truth"),
            })
            .collect();
        assert_eq!(speeds.len(), 2);
        assert!(speeds.iter().all(|v| (v - 20.0).abs() < 1e-9), "{speeds:?}");
    }
}
