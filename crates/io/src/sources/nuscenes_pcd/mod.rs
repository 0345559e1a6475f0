//! nuScenes radar PCD files (Continental ARS408-21): header, the 18 per-point fields, the devkit's
//! default filter, and conversions to [`Detection`] and to `sensor_msgs/PointCloud2`.
//!
//! Entry points: [`PcdHeader::parse`] (any PCD header), [`NuscenesRadarPcd::from_bytes`] /
//! [`NuscenesRadarPcd::read`], [`NuscenesRadarPoint`] and [`NuscenesRadarPoint::to_detection`],
//! [`NuscenesRadarFilter`], [`pcd_to_pointcloud2`], [`nuscenes_fields_config`]. Parts: `pcd` (any PCD
//! header and its records; [`PcdHeader`], [`PcdError`], [`pcd_to_pointcloud2`]).
//!
//! Layout (nuScenes v1.0, checked on real files): an ASCII header ending with `DATA binary`, packed
//! little-endian records, 43 bytes for the standard 18 fields, then zero padding: exactly `POINTS`
//! records are read. `vx, vy`, the raw relative velocity in the radar frame, give the radial velocity
//! Doppler compensation needs (projected on the ray, docs/algorithm.md, "Sign conventions"); `vx_comp,
//! vy_comp` have the ego motion removed and are never used for it.

mod pcd;

pub use pcd::{PcdError, PcdField, PcdHeader, pcd_to_pointcloud2};

use dc_loc_core::math::Vec3;
use dc_loc_core::msgs::sensor_msgs::PointCloud2;
use dc_loc_core::msgs::std_msgs::Header;
use dc_loc_core::radar::Detection;
use dc_loc_core::radar::FieldsConfig;
use std::path::Path;

/// One ARS408 cluster as nuScenes stores it (radar frame: x forward, y left, z up; z is always 0).
///
/// Enumerations (from the nuscenes-devkit `RadarPointCloud.from_file` documentation):
/// `dyn_prop` 0 moving, 1 stationary, 2 oncoming, 3 stationary candidate, 4 unknown, 5 crossing
/// stationary, 6 crossing moving, 7 stopped; `ambig_state` (Doppler ambiguity) 0 invalid, 1 ambiguous,
/// 2 staggered ramp, 3 unambiguous, 4 stationary candidates; `invalid_state` 0 valid, others per the
/// ARS408 cluster-quality table (e.g. 1 low RCS, 2 near-field artefact, 4 valid with low RCS); `pdh0`
/// false-alarm probability class.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NuscenesRadarPoint {
    /// m
    pub x: f32,
    /// m
    pub y: f32,
    /// m (always 0 for the ARS408)
    pub z: f32,
    /// Dynamic property class.
    pub dyn_prop: i8,
    /// Cluster id.
    pub id: i16,
    /// Radar cross-section, dBsm.
    pub rcs: f32,
    /// Raw relative velocity, x component in the radar frame, m/s. Use this (with `vy`) for Doppler.
    pub vx: f32,
    /// Raw relative velocity, y component, m/s.
    pub vy: f32,
    /// Ego-motion-compensated velocity, x component, m/s. Not for Doppler compensation.
    pub vx_comp: f32,
    /// Ego-motion-compensated velocity, y component, m/s.
    pub vy_comp: f32,
    /// Quality flag.
    pub is_quality_valid: i8,
    /// Doppler ambiguity state.
    pub ambig_state: i8,
    /// Position rms class, x.
    pub x_rms: i8,
    /// Position rms class, y.
    pub y_rms: i8,
    /// Cluster validity state (0 valid).
    pub invalid_state: i8,
    /// False-alarm probability class.
    pub pdh0: i8,
    /// Velocity rms class, x.
    pub vx_rms: i8,
    /// Velocity rms class, y.
    pub vy_rms: i8,
}

impl NuscenesRadarPoint {
    /// Position in the radar frame, m.
    pub fn p_radar(&self) -> Vec3 {
        Vec3::new(f64::from(self.x), f64::from(self.y), f64::from(self.z))
    }

    /// Radial velocity from the RAW velocity: `(vx, vy, 0) . p / |p|`, m/s, positive moving away.
    /// `None` at range 0 or when a value is not finite.
    pub fn radial_velocity(&self) -> Option<f64> {
        let p = self.p_radar();
        let range = p.norm();
        let v_r = (f64::from(self.vx) * p.x + f64::from(self.vy) * p.y) / range;
        (range > 0.0 && v_r.is_finite()).then_some(v_r)
    }

    /// As a [`Detection`] (raw `vx, vy` projected on the ray; rcs kept). `None` when the point has a
    /// non-finite value or range 0 (the devkit treats a NaN first point as an empty cloud).
    pub fn to_detection(&self) -> Option<Detection> {
        let p_radar = self.p_radar();
        if !p_radar.iter().all(|v| v.is_finite()) {
            return None;
        }
        let rcs = f64::from(self.rcs);
        Some(Detection {
            p_radar,
            v_r: self.radial_velocity()?,
            rcs: rcs.is_finite().then_some(rcs),
        })
    }
}

/// The point filter of the nuscenes-devkit `RadarPointCloud.from_file`: a point is kept when each
/// enabled criterion lists its value. `None` switches a criterion off.
///
/// [`Default`] is the devkit's default (`default_filters()`): `invalid_state` in {0}, `dyn_prop` in
/// 0..=6 (everything but 7 "stopped"), `ambig_state` in {3} (unambiguous Doppler).
/// [`NuscenesRadarFilter::keep_all`] switches all three off.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NuscenesRadarFilter {
    /// Kept `invalid_state` values.
    pub invalid_states: Option<Vec<i8>>,
    /// Kept `dyn_prop` values.
    pub dynprop_states: Option<Vec<i8>>,
    /// Kept `ambig_state` values.
    pub ambig_states: Option<Vec<i8>>,
}

impl Default for NuscenesRadarFilter {
    fn default() -> Self {
        NuscenesRadarFilter {
            invalid_states: Some(vec![0]),
            dynprop_states: Some((0..=6).collect()),
            ambig_states: Some(vec![3]),
        }
    }
}

impl NuscenesRadarFilter {
    /// No filtering.
    pub fn keep_all() -> Self {
        NuscenesRadarFilter {
            invalid_states: None,
            dynprop_states: None,
            ambig_states: None,
        }
    }

    /// True when the point passes every enabled criterion.
    pub fn keeps(&self, p: &NuscenesRadarPoint) -> bool {
        let ok = |allowed: &Option<Vec<i8>>, v: i8| allowed.as_ref().is_none_or(|a| a.contains(&v));
        ok(&self.invalid_states, p.invalid_state)
            && ok(&self.dynprop_states, p.dyn_prop)
            && ok(&self.ambig_states, p.ambig_state)
    }
}

/// A nuScenes radar PCD file: its header and all its points, unfiltered.
#[derive(Debug, Clone, PartialEq)]
pub struct NuscenesRadarPcd {
    /// The header.
    pub header: PcdHeader,
    /// All `POINTS` points, in file order.
    pub points: Vec<NuscenesRadarPoint>,
}

/// The 18 fields the reader needs: name, TYPE, SIZE.
const NUSCENES_FIELDS: [(&str, char, usize); 18] = [
    ("x", 'F', 4),
    ("y", 'F', 4),
    ("z", 'F', 4),
    ("dyn_prop", 'I', 1),
    ("id", 'I', 2),
    ("rcs", 'F', 4),
    ("vx", 'F', 4),
    ("vy", 'F', 4),
    ("vx_comp", 'F', 4),
    ("vy_comp", 'F', 4),
    ("is_quality_valid", 'I', 1),
    ("ambig_state", 'I', 1),
    ("x_rms", 'I', 1),
    ("y_rms", 'I', 1),
    ("invalid_state", 'I', 1),
    ("pdh0", 'I', 1),
    ("vx_rms", 'I', 1),
    ("vy_rms", 'I', 1),
];

impl NuscenesRadarPcd {
    /// Parses a whole file's bytes. Fields are found by name (any order, extra fields ignored) and must
    /// have the standard types; exactly `POINTS` records are read, trailing bytes are ignored, fewer
    /// bytes than `POINTS` records is an error.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, PcdError> {
        let header = PcdHeader::parse(bytes)?;
        let records = header.binary_records(bytes)?;
        let mut offsets = [0usize; 18];
        for (slot, &(name, kind, size)) in offsets.iter_mut().zip(NUSCENES_FIELDS.iter()) {
            let f = header.field(name).ok_or(PcdError::MissingField(name))?;
            if f.kind != kind || f.size != size || f.count == 0 {
                return Err(PcdError::WrongFieldType {
                    name,
                    kind: f.kind,
                    size: f.size,
                    expected_kind: kind,
                    expected_size: size,
                });
            }
            *slot = f.offset;
        }
        let [
            ox,
            oy,
            oz,
            odp,
            oid,
            orcs,
            ovx,
            ovy,
            ovxc,
            ovyc,
            oq,
            oa,
            oxr,
            oyr,
            oinv,
            opdh,
            ovxr,
            ovyr,
        ] = offsets;
        let points = if header.point_size == 0 {
            Vec::new()
        } else {
            records
                .chunks_exact(header.point_size)
                .map(|r| {
                    let f = |o| read_le::<4>(r, o).map_or(f32::NAN, f32::from_le_bytes);
                    let b = |o| read_le::<1>(r, o).map_or(0, i8::from_le_bytes);
                    NuscenesRadarPoint {
                        x: f(ox),
                        y: f(oy),
                        z: f(oz),
                        dyn_prop: b(odp),
                        id: read_le::<2>(r, oid).map_or(0, i16::from_le_bytes),
                        rcs: f(orcs),
                        vx: f(ovx),
                        vy: f(ovy),
                        vx_comp: f(ovxc),
                        vy_comp: f(ovyc),
                        is_quality_valid: b(oq),
                        ambig_state: b(oa),
                        x_rms: b(oxr),
                        y_rms: b(oyr),
                        invalid_state: b(oinv),
                        pdh0: b(opdh),
                        vx_rms: b(ovxr),
                        vy_rms: b(ovyr),
                    }
                })
                .collect()
        };
        Ok(NuscenesRadarPcd { header, points })
    }

    /// Reads and parses a file; errors name the file.
    pub fn read(path: impl AsRef<Path>) -> Result<Self, PcdError> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|source| PcdError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(&bytes).map_err(|e| PcdError::InFile {
            path: path.to_path_buf(),
            source: Box::new(e),
        })
    }

    /// The points that pass `filter`, as detections (raw-velocity Doppler; points without a valid
    /// detection, see [`NuscenesRadarPoint::to_detection`], are dropped).
    pub fn detections(&self, filter: &NuscenesRadarFilter) -> Vec<Detection> {
        self.points
            .iter()
            .filter(|p| filter.keeps(p))
            .filter_map(NuscenesRadarPoint::to_detection)
            .collect()
    }
}

/// `N` bytes at `offset` of `record`; `None` if they are not all there (cannot happen once the header
/// offsets are checked, but keeps the reader panic-free).
fn read_le<const N: usize>(record: &[u8], offset: usize) -> Option<[u8; N]> {
    record.get(offset..)?.first_chunk::<N>().copied()
}

/// Like [`pcd_to_pointcloud2`], keeping only the records whose point passes `filter` (the sensor's own
/// `dyn_prop`, `invalid_state` and `ambig_state` flags); `width` is the number kept, `height` 1.
pub fn filtered_pointcloud2(
    bytes: &[u8],
    filter: &NuscenesRadarFilter,
    header: Header,
) -> Result<PointCloud2, PcdError> {
    let pcd = NuscenesRadarPcd::from_bytes(bytes)?;
    let mut cloud = pcd_to_pointcloud2(bytes, header)?;
    let step = pcd.header.point_size;
    if step == 0 {
        return Ok(cloud);
    }
    let mut data = Vec::with_capacity(cloud.data.len());
    for (record, p) in cloud.data.chunks_exact(step).zip(&pcd.points) {
        if filter.keeps(p) {
            data.extend_from_slice(record);
        }
    }
    let kept = u32::try_from(data.len() / step).map_err(|_| PcdError::SizeOverflow)?;
    cloud.height = 1;
    cloud.width = kept;
    cloud.row_step = kept
        .checked_mul(cloud.point_step)
        .ok_or(PcdError::SizeOverflow)?;
    cloud.data = data;
    Ok(cloud)
}

/// The field mapping for nuScenes radar clouds: `x, y, z`, radial velocity from the raw `vx, vy`,
/// `rcs`.
pub fn nuscenes_fields_config() -> FieldsConfig {
    FieldsConfig {
        x: "x".into(),
        y: "y".into(),
        z: "z".into(),
        velocity: String::new(),
        velocity_x: "vx".into(),
        velocity_y: "vy".into(),
        rcs: "rcs".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A two-point file in the nuScenes layout with `pad` trailing zero bytes.
    fn file(points: &[[f32; 2]], pad: usize) -> Vec<u8> {
        let mut b = b"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n\
FIELDS x y z dyn_prop id rcs vx vy vx_comp vy_comp is_quality_valid ambig_state x_rms y_rms invalid_state pdh0 vx_rms vy_rms\n\
SIZE 4 4 4 1 2 4 4 4 4 4 1 1 1 1 1 1 1 1\nTYPE F F F I I F F F F F I I I I I I I I\n\
COUNT 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1\n"
            .to_vec();
        b.extend(
            format!(
                "WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n",
                n = points.len()
            )
            .bytes(),
        );
        for (i, &[x, y]) in points.iter().enumerate() {
            b.extend(x.to_le_bytes());
            b.extend(y.to_le_bytes());
            b.extend(0f32.to_le_bytes());
            b.push(i as u8); // dyn_prop
            b.extend((-300i16 + i as i16).to_le_bytes()); // id
            b.extend(5.5f32.to_le_bytes()); // rcs
            b.extend(1f32.to_le_bytes()); // vx
            b.extend(2f32.to_le_bytes()); // vy
            b.extend(7f32.to_le_bytes()); // vx_comp
            b.extend(8f32.to_le_bytes()); // vy_comp
            b.extend([1, 3, 4, 5, 0xF6, 7, 8, 9]); // invalid_state = -10 as i8
        }
        b.extend(std::iter::repeat_n(0u8, pad));
        b
    }

    #[test]
    fn reads_records_ignores_padding_and_rejects_truncation() {
        let bytes = file(&[[3.0, 4.0], [0.0, -2.0]], 28);
        let pcd = NuscenesRadarPcd::from_bytes(&bytes).unwrap();
        assert_eq!(pcd.header.point_size, 43);
        assert_eq!(pcd.points.len(), 2);
        let p = pcd.points[1];
        assert_eq!((p.x, p.y, p.dyn_prop, p.id), (0.0, -2.0, 1, -299));
        assert_eq!(
            (p.rcs, p.vx, p.vy, p.vx_comp, p.vy_comp),
            (5.5, 1.0, 2.0, 7.0, 8.0)
        );
        assert_eq!(
            [
                p.is_quality_valid,
                p.ambig_state,
                p.x_rms,
                p.y_rms,
                p.invalid_state,
                p.pdh0,
                p.vx_rms,
                p.vy_rms
            ],
            [1, 3, 4, 5, -10, 7, 8, 9]
        );
        // (vx, vy) . p / |p| = (1*3 + 2*4) / 5 for the first point, (2 * -2) / 2 for the second.
        assert_eq!(pcd.points[0].radial_velocity(), Some(11.0 / 5.0));
        assert_eq!(p.to_detection().unwrap().v_r, -2.0);

        let full = file(&[[3.0, 4.0], [0.0, -2.0]], 0);
        assert_eq!(NuscenesRadarPcd::from_bytes(&full).unwrap(), pcd);
        let short = &full[..full.len() - 1];
        assert!(matches!(
            NuscenesRadarPcd::from_bytes(short),
            Err(PcdError::Truncated { needed: 86, .. })
        ));
    }

    #[test]
    fn header_errors_name_the_key() {
        let bytes = file(&[[1.0, 0.0]], 0);
        let text = String::from_utf8_lossy(&bytes[..300]).to_string();
        let no_data = text.split("DATA").next().unwrap().as_bytes().to_vec();
        assert!(matches!(
            PcdHeader::parse(&no_data),
            Err(PcdError::NoDataLine)
        ));
        let wrong_size = String::from_utf8_lossy(&bytes)
            .replacen("SIZE 4 4 4 1 2", "SIZE 4 4 4 1", 1)
            .into_bytes();
        assert!(matches!(
            PcdHeader::parse(&wrong_size),
            Err(PcdError::FieldCountMismatch { key: "SIZE", .. })
        ));
        let ascii = String::from_utf8_lossy(&bytes)
            .replacen("DATA binary", "DATA ascii", 1)
            .into_bytes();
        assert!(matches!(
            NuscenesRadarPcd::from_bytes(&ascii),
            Err(PcdError::UnsupportedData(_))
        ));
        let points = String::from_utf8_lossy(&bytes)
            .replacen("POINTS 1", "POINTS 2", 1)
            .into_bytes();
        assert!(matches!(
            PcdHeader::parse(&points),
            Err(PcdError::PointsMismatch { points: 2, .. })
        ));
    }

    #[test]
    fn default_filter_is_the_devkits() {
        let mut p = NuscenesRadarPcd::from_bytes(&file(&[[1.0, 0.0]], 0))
            .unwrap()
            .points[0];
        p.invalid_state = 0;
        p.ambig_state = 3;
        let f = NuscenesRadarFilter::default();
        for dyn_prop in 0..=7 {
            p.dyn_prop = dyn_prop;
            assert_eq!(f.keeps(&p), dyn_prop <= 6, "dyn_prop {dyn_prop}");
        }
        p.dyn_prop = 1;
        p.ambig_state = 2;
        assert!(!f.keeps(&p));
        assert!(
            NuscenesRadarFilter {
                ambig_states: None,
                ..f.clone()
            }
            .keeps(&p)
        );
        p.invalid_state = 4;
        assert!(
            !NuscenesRadarFilter {
                ambig_states: None,
                ..f
            }
            .keeps(&p)
        );
        assert!(NuscenesRadarFilter::keep_all().keeps(&p));
    }
}
