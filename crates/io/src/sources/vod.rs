//! View-of-Delft (VoD, Palffy et al., RA-L 2022) radar frames: the ZF FRGen21 4D-radar `.bin` files,
//! the per-frame pose JSON and the KITTI-style calibration.
//!
//! Entry points: [`parse_radar_bin`] / [`read_radar_bin`] -> [`VodRadarPoint`]
//! ([`VodRadarPoint::to_detection`]); [`VodPoses::parse`] / [`VodPoses::read`] (camera poses
//! `t_odom_camera`, `t_map_camera`, `t_utm_camera`); [`KittiCalib::parse`] / [`KittiCalib::read`]
//! ([`KittiCalib::t_camera_radar`]); [`iso3_from_matrix`].
//!
//! Frames: the radar frame is x forward, y left, z up; the camera frame is KITTI's (z forward, x right,
//! y down). The radar pose in the map frame is `t_map_camera * t_camera_radar`.

use dc_loc_core::math::{Iso3, Mat3, Quat, Vec3};
use dc_loc_core::radar::Detection;
use nalgebra::{Matrix3x4, Matrix4};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Why a VoD file could not be read. Variants name the file, line or key at fault.
#[derive(Debug, thiserror::Error)]
pub enum VodError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A reader error, with the file it came from.
    #[error("{path}: {source}")]
    InFile {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: Box<VodError>,
    },
    /// A radar `.bin` whose length is not a multiple of 28 bytes (7 float32 per point).
    #[error("radar .bin has {len} bytes, not a multiple of 28 (7 x float32)")]
    BinLength {
        /// File length, bytes.
        len: usize,
    },
    /// A pose JSON line is not valid JSON of the expected shape.
    #[error("pose JSON line {line}: {message}")]
    Json {
        /// 1-based line number.
        line: usize,
        /// The parser's message.
        message: String,
    },
    /// A pose matrix is missing.
    #[error("pose JSON has no `{0}`")]
    MissingPose(&'static str),
    /// A matrix has the wrong number of values, or a 4x4 whose last row is not 0 0 0 1.
    #[error("`{key}`: {reason}")]
    BadMatrix {
        /// The JSON key or calibration line.
        key: String,
        /// What is wrong.
        reason: String,
    },
    /// A calibration value is not a number.
    #[error("calibration line {line}: cannot parse `{value}`")]
    CalibValue {
        /// 1-based line number.
        line: usize,
        /// The offending value.
        value: String,
    },
    /// A calibration entry is missing.
    #[error("calibration has no `{0}`")]
    MissingCalib(&'static str),
}

/// One VoD radar point: the 7 float32 of a `.bin` record, radar frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VodRadarPoint {
    /// m
    pub x: f32,
    /// m
    pub y: f32,
    /// m
    pub z: f32,
    /// Radar cross-section, dBsm.
    pub rcs: f32,
    /// Relative radial velocity (as measured), m/s. Use this for Doppler compensation.
    pub v_r: f32,
    /// Radial velocity with the ego motion removed, m/s. Not for Doppler compensation.
    pub v_r_compensated: f32,
    /// Time offset of the point within an accumulated cloud, s (0 for single scans).
    pub time: f32,
}

impl VodRadarPoint {
    /// Position in the radar frame, m.
    pub fn p_radar(&self) -> Vec3 {
        Vec3::new(f64::from(self.x), f64::from(self.y), f64::from(self.z))
    }

    /// As a [`Detection`] with the measured `v_r` as radial velocity. `None` for a non-finite position
    /// or velocity, or range 0.
    pub fn to_detection(&self) -> Option<Detection> {
        let p_radar = self.p_radar();
        let v_r = f64::from(self.v_r);
        let range = p_radar.norm();
        if !(range.is_finite() && range > 0.0 && v_r.is_finite()) {
            return None;
        }
        let rcs = f64::from(self.rcs);
        Some(Detection {
            p_radar,
            v_r,
            rcs: rcs.is_finite().then_some(rcs),
        })
    }
}

/// Parses a VoD radar `.bin`: little-endian float32, N x 7 (x, y, z, RCS, v_r, v_r_compensated, time).
pub fn parse_radar_bin(bytes: &[u8]) -> Result<Vec<VodRadarPoint>, VodError> {
    if !bytes.len().is_multiple_of(28) {
        return Err(VodError::BinLength { len: bytes.len() });
    }
    Ok(bytes
        .chunks_exact(28)
        .map(|r| {
            let f = |i: usize| {
                r.get(4 * i..)
                    .and_then(|s| s.first_chunk::<4>())
                    .map_or(f32::NAN, |b| f32::from_le_bytes(*b))
            };
            VodRadarPoint {
                x: f(0),
                y: f(1),
                z: f(2),
                rcs: f(3),
                v_r: f(4),
                v_r_compensated: f(5),
                time: f(6),
            }
        })
        .collect())
}

/// Reads a VoD radar `.bin`; errors name the file.
pub fn read_radar_bin(path: impl AsRef<Path>) -> Result<Vec<VodRadarPoint>, VodError> {
    let path = path.as_ref();
    let bytes = read_bytes(path)?;
    parse_radar_bin(&bytes).map_err(|e| in_file(path, e))
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, VodError> {
    std::fs::read(path).map_err(|source| VodError::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn in_file(path: &Path, e: VodError) -> VodError {
    VodError::InFile {
        path: path.to_path_buf(),
        source: Box::new(e),
    }
}

/// The camera poses of one VoD frame (`pose/NNNNN.json`), as 4x4 homogeneous matrices exactly as stored.
///
/// Each maps camera-frame coordinates into the named frame (the devkit's `T_odom_camera` etc.): the
/// camera pose. Convert with [`iso3_from_matrix`].
#[derive(Debug, Clone, PartialEq)]
pub struct VodPoses {
    /// `odomToCamera`: camera pose in the odometry frame.
    pub t_odom_camera: Matrix4<f64>,
    /// `mapToCamera`: camera pose in the map frame.
    pub t_map_camera: Matrix4<f64>,
    /// `UTMToCamera`: camera pose in UTM coordinates.
    pub t_utm_camera: Matrix4<f64>,
}

impl VodPoses {
    /// Parses the pose file: one JSON object per non-empty line, each holding one or more of
    /// `odomToCamera`, `mapToCamera`, `UTMToCamera` as 16 numbers (row-major 4x4). All three are needed.
    pub fn parse(text: &str) -> Result<VodPoses, VodError> {
        let mut found: BTreeMap<String, Vec<f64>> = BTreeMap::new();
        for (i, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let obj: BTreeMap<String, Vec<f64>> =
                serde_json::from_str(line).map_err(|e| VodError::Json {
                    line: i + 1,
                    message: e.to_string(),
                })?;
            found.extend(obj);
        }
        let mut take = |key: &'static str| -> Result<Matrix4<f64>, VodError> {
            let v = found.remove(key).ok_or(VodError::MissingPose(key))?;
            homogeneous_4x4(key, &v)
        };
        Ok(VodPoses {
            t_odom_camera: take("odomToCamera")?,
            t_map_camera: take("mapToCamera")?,
            t_utm_camera: take("UTMToCamera")?,
        })
    }

    /// Reads and parses a pose file; errors name the file.
    pub fn read(path: impl AsRef<Path>) -> Result<VodPoses, VodError> {
        let path = path.as_ref();
        let bytes = read_bytes(path)?;
        let text = String::from_utf8_lossy(&bytes);
        VodPoses::parse(&text).map_err(|e| in_file(path, e))
    }
}

/// A row-major 4x4 from 16 values, with the last row checked to be 0 0 0 1.
fn homogeneous_4x4(key: &str, v: &[f64]) -> Result<Matrix4<f64>, VodError> {
    if v.len() != 16 {
        return Err(VodError::BadMatrix {
            key: key.to_string(),
            reason: format!("{} values, expected 16", v.len()),
        });
    }
    let m = Matrix4::from_row_slice(v);
    if m.row(3).iter().copied().ne([0.0, 0.0, 0.0, 1.0]) {
        return Err(VodError::BadMatrix {
            key: key.to_string(),
            reason: "last row is not 0 0 0 1".into(),
        });
    }
    Ok(m)
}

/// A KITTI calibration file (`calib/NNNNN.txt`): `key: values` lines. Entries without values (VoD's
/// `Tr_imu_to_velo:`) are kept empty.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct KittiCalib {
    /// Every entry by key, values in file order.
    pub entries: BTreeMap<String, Vec<f64>>,
}

impl KittiCalib {
    /// Parses the text.
    pub fn parse(text: &str) -> Result<KittiCalib, VodError> {
        let mut entries = BTreeMap::new();
        for (i, line) in text.lines().enumerate() {
            let Some((key, values)) = line.split_once(':') else {
                continue;
            };
            let values = values
                .split_whitespace()
                .map(|w| {
                    w.parse::<f64>().map_err(|_| VodError::CalibValue {
                        line: i + 1,
                        value: w.to_string(),
                    })
                })
                .collect::<Result<Vec<f64>, _>>()?;
            entries.insert(key.trim().to_string(), values);
        }
        Ok(KittiCalib { entries })
    }

    /// Reads and parses a calibration file; errors name the file.
    pub fn read(path: impl AsRef<Path>) -> Result<KittiCalib, VodError> {
        let path = path.as_ref();
        let bytes = read_bytes(path)?;
        KittiCalib::parse(&String::from_utf8_lossy(&bytes)).map_err(|e| in_file(path, e))
    }

    /// A 3x4 row-major entry.
    pub fn matrix3x4(&self, key: &'static str) -> Result<Matrix3x4<f64>, VodError> {
        let v = self.entries.get(key).ok_or(VodError::MissingCalib(key))?;
        if v.len() != 12 {
            return Err(VodError::BadMatrix {
                key: key.to_string(),
                reason: format!("{} values, expected 12", v.len()),
            });
        }
        Ok(Matrix3x4::from_row_slice(v))
    }

    /// The radar-to-camera extrinsic `Tr_velo_to_cam` (KITTI's name; in VoD it holds the radar) as a
    /// homogeneous 4x4: `T_camera_radar`, mapping radar-frame points into the camera frame.
    pub fn t_camera_radar(&self) -> Result<Matrix4<f64>, VodError> {
        let m = self.matrix3x4("Tr_velo_to_cam")?;
        let mut t = Matrix4::identity();
        t.fixed_view_mut::<3, 4>(0, 0).copy_from(&m);
        Ok(t)
    }

    /// The left colour camera's projection matrix `P2` (pixels).
    pub fn p2(&self) -> Result<Matrix3x4<f64>, VodError> {
        self.matrix3x4("P2")
    }
}

/// The rigid motion in a homogeneous 4x4 whose top-left 3x3 is a rotation to within `tolerance`
/// (max |R^T R - I| entry, and det R > 0); the rotation is re-orthonormalised. `None` otherwise, or when
/// a value is not finite.
pub fn iso3_from_matrix(m: &Matrix4<f64>, tolerance: f64) -> Option<Iso3> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    let r: Mat3 = m.fixed_view::<3, 3>(0, 0).into_owned();
    let err = (r.transpose() * r - Mat3::identity()).abs().max();
    if !(err <= tolerance && r.determinant() > 0.0) {
        return None;
    }
    let q = Quat::from_matrix(&r);
    let t = Vec3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    Some(Iso3::from_parts(t.into(), q))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bin_length_must_be_a_multiple_of_28() {
        let mut b = Vec::new();
        for v in [1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0] {
            b.extend(v.to_le_bytes());
        }
        let p = parse_radar_bin(&b).unwrap();
        assert_eq!(p.len(), 1);
        assert_eq!(
            (p[0].x, p[0].rcs, p[0].v_r, p[0].time),
            (1.0, 4.0, 5.0, 7.0)
        );
        assert_eq!(p[0].to_detection().unwrap().v_r, 5.0);
        b.push(0);
        assert!(matches!(
            parse_radar_bin(&b),
            Err(VodError::BinLength { len: 29 })
        ));
    }

    #[test]
    fn poses_need_all_three_keys_and_16_values() {
        let m = "[1,0,0,1, 0,1,0,2, 0,0,1,3, 0,0,0,1]";
        let text = format!(
            "{{\"odomToCamera\": {m}}}\n{{\"mapToCamera\": {m}}}\n{{\"UTMToCamera\": {m}}}"
        );
        let p = VodPoses::parse(&text).unwrap();
        assert_eq!(p.t_map_camera[(1, 3)], 2.0);
        let missing = text.replace("UTMToCamera", "other");
        assert!(matches!(
            VodPoses::parse(&missing),
            Err(VodError::MissingPose("UTMToCamera"))
        ));
        let short = text.replacen(", 0,0,0,1]", "]", 1);
        assert!(matches!(
            VodPoses::parse(&short),
            Err(VodError::BadMatrix { .. })
        ));
        assert!(matches!(
            VodPoses::parse("{oops"),
            Err(VodError::Json { line: 1, .. })
        ));
    }

    #[test]
    fn rigid_check_rejects_reflections_and_shear() {
        let mut m = Matrix4::identity();
        m[(0, 3)] = 5.0;
        let t = iso3_from_matrix(&m, 1e-9).unwrap();
        assert_eq!(t.translation.x, 5.0);
        m[(2, 2)] = -1.0;
        assert!(iso3_from_matrix(&m, 1e-9).is_none());
        m[(2, 2)] = 1.0;
        m[(0, 1)] = 0.01;
        assert!(iso3_from_matrix(&m, 1e-3).is_none());
    }
}
