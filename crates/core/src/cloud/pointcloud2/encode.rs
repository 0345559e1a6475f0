//! [`Detection`] -> PointCloud2: the encoder the simulator, the node's submap output and the tests use,
//! with any [`CloudLayout`].

use super::{FieldReader, ScalarType};
use crate::msgs::sensor_msgs::{PointCloud2, PointField};
use crate::msgs::std_msgs::Header;
use crate::radar::Detection;
use crate::radar::FieldsConfig;

/// What a field of an encoded cloud holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FieldRole {
    /// x coordinate, m.
    X,
    /// y coordinate, m.
    Y,
    /// z coordinate, m.
    Z,
    /// Scalar radial velocity, m/s, positive moving away.
    RadialVelocity,
    /// x component of a planar velocity vector whose projection on the ray is the radial velocity.
    VelocityX,
    /// y component of that vector.
    VelocityY,
    /// Radar cross-section, dBsm; a detection without one writes NaN (float types) or 0 (integers).
    Rcs,
    /// A field dc_loc does not produce (e.g. nuScenes `dyn_prop`); written as 0.
    Zero,
}

/// One field of a [`CloudLayout`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LayoutField {
    /// PointField name.
    pub name: String,
    /// What it holds.
    pub role: FieldRole,
    /// `PointField` datatype code (`PointField::INT8..=FLOAT64`).
    pub datatype: u8,
    /// Unused bytes inserted before this field (alignment padding), bytes.
    pub gap_before: u32,
}

impl LayoutField {
    /// A field with no gap before it.
    pub fn new(name: impl Into<String>, role: FieldRole, datatype: u8) -> Self {
        LayoutField {
            name: name.into(),
            role,
            datatype,
            gap_before: 0,
        }
    }
    /// The same field with `bytes` of padding before it.
    pub fn with_gap(mut self, bytes: u32) -> Self {
        self.gap_before = bytes;
        self
    }
}

/// How [`encode_detections`] lays out a PointCloud2: fields packed in the given order (plus each field's
/// `gap_before`), `point_padding` bytes after the last field, `row_padding` bytes after each row.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CloudLayout {
    /// Fields in byte order within a point.
    pub fields: Vec<LayoutField>,
    /// Big-endian data.
    pub is_bigendian: bool,
    /// Unused bytes at the end of each point.
    pub point_padding: u32,
    /// Unused bytes at the end of each row (`row_step = width * point_step + row_padding`).
    pub row_padding: u32,
    /// Rows (`height`); the detections are split row-major and their count must be a multiple.
    pub rows: u32,
}

impl CloudLayout {
    /// The common radar layout: `x, y, z, v_r, rcs`, FLOAT32, little-endian, point_step 20, one row.
    pub fn radar_f32() -> Self {
        let f32 = PointField::FLOAT32;
        CloudLayout {
            fields: vec![
                LayoutField::new("x", FieldRole::X, f32),
                LayoutField::new("y", FieldRole::Y, f32),
                LayoutField::new("z", FieldRole::Z, f32),
                LayoutField::new("v_r", FieldRole::RadialVelocity, f32),
                LayoutField::new("rcs", FieldRole::Rcs, f32),
            ],
            is_bigendian: false,
            point_padding: 0,
            row_padding: 0,
            rows: 1,
        }
    }

    /// The nuScenes radar layout (the 18 PCD fields, INT8/INT16/FLOAT32, packed, point_step 43, as
    /// nuscenes2bag/nuscenes2mcap publish it). `vx, vy` carry the radial velocity as a vector; every
    /// field dc_loc does not produce (`dyn_prop`, `id`, `vx_comp`, `vy_comp`, the state and rms fields)
    /// is written as 0.
    pub fn nuscenes_radar() -> Self {
        let (i8_, i16_, f32_) = (PointField::INT8, PointField::INT16, PointField::FLOAT32);
        let mut fields = vec![
            LayoutField::new("x", FieldRole::X, f32_),
            LayoutField::new("y", FieldRole::Y, f32_),
            LayoutField::new("z", FieldRole::Z, f32_),
            LayoutField::new("dyn_prop", FieldRole::Zero, i8_),
            LayoutField::new("id", FieldRole::Zero, i16_),
            LayoutField::new("rcs", FieldRole::Rcs, f32_),
            LayoutField::new("vx", FieldRole::VelocityX, f32_),
            LayoutField::new("vy", FieldRole::VelocityY, f32_),
            LayoutField::new("vx_comp", FieldRole::Zero, f32_),
            LayoutField::new("vy_comp", FieldRole::Zero, f32_),
        ];
        for name in [
            "is_quality_valid",
            "ambig_state",
            "x_rms",
            "y_rms",
            "invalid_state",
            "pdh0",
            "vx_rms",
            "vy_rms",
        ] {
            fields.push(LayoutField::new(name, FieldRole::Zero, i8_));
        }
        CloudLayout {
            fields,
            is_bigendian: false,
            point_padding: 0,
            row_padding: 0,
            rows: 1,
        }
    }

    /// The field mapping that decodes this layout: the name of the first field of each role (empty
    /// when the role is absent). With both a scalar and a vector velocity, the scalar one is used.
    pub fn fields_config(&self) -> FieldsConfig {
        let name = |role: FieldRole| {
            self.fields
                .iter()
                .find(|f| f.role == role)
                .map_or_else(String::new, |f| f.name.clone())
        };
        let velocity = name(FieldRole::RadialVelocity);
        let vector = velocity.is_empty();
        FieldsConfig {
            x: name(FieldRole::X),
            y: name(FieldRole::Y),
            z: name(FieldRole::Z),
            velocity_x: if vector {
                name(FieldRole::VelocityX)
            } else {
                String::new()
            },
            velocity_y: if vector {
                name(FieldRole::VelocityY)
            } else {
                String::new()
            },
            velocity,
            rcs: name(FieldRole::Rcs),
        }
    }
}

/// Why a layout could not be encoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// A layout field has a datatype code outside `PointField::INT8..=FLOAT64`.
    #[error("layout field `{name}` has unsupported datatype code {datatype}")]
    UnsupportedDatatype {
        /// Field name.
        name: String,
        /// The datatype code.
        datatype: u8,
    },
    /// `rows` is 0.
    #[error("layout has 0 rows")]
    ZeroRows,
    /// The detection count is not a multiple of `rows`.
    #[error("{points} detections do not fill {rows} equal rows")]
    RowsDoNotDivide {
        /// Detections given.
        points: usize,
        /// Rows asked for.
        rows: u32,
    },
    /// A size (point_step, row_step, width) does not fit the message's u32 fields.
    #[error("encoded cloud too large: {what} overflows u32")]
    TooLarge {
        /// Which size.
        what: &'static str,
    },
}

/// Encodes detections (radar frame) into a PointCloud2 with the given layout and header.
///
/// Integer fields get the value rounded to the nearest integer and saturated to the type's range (NaN
/// gives 0). `VelocityX`/`VelocityY` get the planar vector `v_r |p| / (x^2 + y^2) * (x, y)`, the one whose
/// projection `(vx, vy, 0) . p / |p|` gives back `v_r`; with z = 0 (planar radars such as the ARS408)
/// this is exactly the radial velocity vector `v_r p / |p|`; on the z axis it is 0. `is_dense` is true
/// when every detection has a finite position and velocity and a non-zero range.
pub fn encode_detections(
    detections: &[Detection],
    layout: &CloudLayout,
    header: Header,
) -> Result<PointCloud2, EncodeError> {
    let too_large = |what| EncodeError::TooLarge { what };
    // Field offsets, packed in order.
    let mut fields = Vec::with_capacity(layout.fields.len());
    let mut writers = Vec::with_capacity(layout.fields.len());
    let mut offset: u32 = 0;
    for f in &layout.fields {
        let kind = ScalarType::from_datatype(f.datatype).ok_or_else(|| {
            EncodeError::UnsupportedDatatype {
                name: f.name.clone(),
                datatype: f.datatype,
            }
        })?;
        offset = offset
            .checked_add(f.gap_before)
            .ok_or_else(|| too_large("point_step"))?;
        fields.push(PointField {
            name: f.name.clone(),
            offset,
            datatype: f.datatype,
            count: 1,
        });
        writers.push((
            FieldReader {
                offset: offset as usize,
                kind,
            },
            f.role,
        ));
        offset = offset
            .checked_add(kind.size() as u32)
            .ok_or_else(|| too_large("point_step"))?;
    }
    let point_step = offset
        .checked_add(layout.point_padding)
        .ok_or_else(|| too_large("point_step"))?;

    if layout.rows == 0 {
        return Err(EncodeError::ZeroRows);
    }
    let rows = layout.rows as usize;
    if !detections.len().is_multiple_of(rows) {
        return Err(EncodeError::RowsDoNotDivide {
            points: detections.len(),
            rows: layout.rows,
        });
    }
    let width = u32::try_from(detections.len() / rows).map_err(|_| too_large("width"))?;
    let row_step = width
        .checked_mul(point_step)
        .and_then(|b| b.checked_add(layout.row_padding))
        .ok_or_else(|| too_large("row_step"))?;
    let total = (row_step as usize)
        .checked_mul(rows)
        .ok_or_else(|| too_large("data"))?;

    let mut data = vec![0u8; total];
    let mut is_dense = true;
    let (ps, rs) = (point_step as usize, row_step as usize);
    let w = (width as usize).max(1);
    for (i, d) in detections.iter().enumerate() {
        let start = (i / w) * rs + (i % w) * ps;
        let Some(point) = data.get_mut(start..start + ps) else {
            continue; // cannot happen: total covers every point
        };
        let p = d.p_radar;
        let range = p.norm();
        is_dense &= p.iter().all(|v| v.is_finite()) && d.v_r.is_finite() && range > 0.0;
        let planar2 = p.x * p.x + p.y * p.y;
        let scale = if planar2 > 0.0 {
            d.v_r * range / planar2
        } else {
            0.0
        };
        for (w, role) in &writers {
            let value = match role {
                FieldRole::X => p.x,
                FieldRole::Y => p.y,
                FieldRole::Z => p.z,
                FieldRole::RadialVelocity => d.v_r,
                FieldRole::VelocityX => scale * p.x,
                FieldRole::VelocityY => scale * p.y,
                FieldRole::Rcs => d.rcs.unwrap_or(f64::NAN),
                FieldRole::Zero => 0.0,
            };
            write(*w, point, value, layout.is_bigendian);
        }
    }
    Ok(PointCloud2 {
        header,
        height: layout.rows,
        width,
        fields,
        is_bigendian: layout.is_bigendian,
        point_step,
        row_step,
        data,
        is_dense,
    })
}

/// Writes `v` into `point` at the field's offset; out-of-range targets are left untouched.
fn write(f: FieldReader, point: &mut [u8], v: f64, big_endian: bool) {
    macro_rules! put {
        ($t:ty, $x:expr) => {{
            let x: $t = $x;
            let b = if big_endian {
                x.to_be_bytes()
            } else {
                x.to_le_bytes()
            };
            if let Some(dst) = point.get_mut(f.offset..f.offset + b.len()) {
                dst.copy_from_slice(&b);
            }
        }};
    }
    // `as` from f64 to an integer saturates and maps NaN to 0.
    let r = v.round();
    match f.kind {
        ScalarType::I8 => put!(i8, r as i8),
        ScalarType::U8 => put!(u8, r as u8),
        ScalarType::I16 => put!(i16, r as i16),
        ScalarType::U16 => put!(u16, r as u16),
        ScalarType::I32 => put!(i32, r as i32),
        ScalarType::U32 => put!(u32, r as u32),
        ScalarType::F32 => put!(f32, v as f32),
        ScalarType::F64 => put!(f64, v),
    }
}
