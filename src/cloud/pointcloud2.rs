//! `sensor_msgs/PointCloud2` <-> [`Detection`]: the decoder every radar message goes through, and the
//! encoder the simulator, the node's submap output and the tests use.
//!
//! Entry points: [`decode_detections`], [`decode_detections_into`] (reuses the output buffer),
//! [`DecodedCloud`], [`DecodeError`]; [`encode_detections`], [`CloudLayout`], [`LayoutField`],
//! [`FieldRole`], [`EncodeError`]; [`ScalarType`] (the PointField datatypes).
//!
//! Decoding resolves the field layout once per message (name lookup, datatype, offset, bounds) and then
//! runs one tight loop over the points with no allocation beyond the output vector and no string work.
//! Byte order is a const generic, so the inner loop carries no endianness branch.

use crate::math::Vec3;
use crate::msgs::sensor_msgs::{PointCloud2, PointField};
use crate::msgs::std_msgs::Header;
use crate::radar::Detection;
use crate::radar::FieldsConfig;

/// The scalar types a `PointField` can hold (`PointField::INT8` ..= `PointField::FLOAT64`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ScalarType {
    /// `INT8`
    I8,
    /// `UINT8`
    U8,
    /// `INT16`
    I16,
    /// `UINT16`
    U16,
    /// `INT32`
    I32,
    /// `UINT32`
    U32,
    /// `FLOAT32`
    F32,
    /// `FLOAT64`
    F64,
}

impl ScalarType {
    /// All eight types, in datatype-code order.
    pub const ALL: [ScalarType; 8] = [
        ScalarType::I8,
        ScalarType::U8,
        ScalarType::I16,
        ScalarType::U16,
        ScalarType::I32,
        ScalarType::U32,
        ScalarType::F32,
        ScalarType::F64,
    ];

    /// From a `PointField::datatype` code; `None` for codes outside 1..=8.
    pub fn from_datatype(code: u8) -> Option<Self> {
        Some(match code {
            PointField::INT8 => ScalarType::I8,
            PointField::UINT8 => ScalarType::U8,
            PointField::INT16 => ScalarType::I16,
            PointField::UINT16 => ScalarType::U16,
            PointField::INT32 => ScalarType::I32,
            PointField::UINT32 => ScalarType::U32,
            PointField::FLOAT32 => ScalarType::F32,
            PointField::FLOAT64 => ScalarType::F64,
            _ => return None,
        })
    }

    /// The `PointField::datatype` code.
    pub fn datatype(self) -> u8 {
        match self {
            ScalarType::I8 => PointField::INT8,
            ScalarType::U8 => PointField::UINT8,
            ScalarType::I16 => PointField::INT16,
            ScalarType::U16 => PointField::UINT16,
            ScalarType::I32 => PointField::INT32,
            ScalarType::U32 => PointField::UINT32,
            ScalarType::F32 => PointField::FLOAT32,
            ScalarType::F64 => PointField::FLOAT64,
        }
    }

    /// Size of one element, bytes.
    pub fn size(self) -> usize {
        match self {
            ScalarType::I8 | ScalarType::U8 => 1,
            ScalarType::I16 | ScalarType::U16 => 2,
            ScalarType::I32 | ScalarType::U32 | ScalarType::F32 => 4,
            ScalarType::F64 => 8,
        }
    }

    /// True for the two floating-point types.
    pub fn is_float(self) -> bool {
        matches!(self, ScalarType::F32 | ScalarType::F64)
    }
}

/// Why a PointCloud2 could not be decoded. Every variant names the field or size at fault.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// The field mapping gives no name for a required quantity (e.g. an empty `x`, or neither a scalar
    /// velocity nor both vector components).
    #[error("no field name configured for the {role} of a detection")]
    Unconfigured {
        /// What the field would hold (`x`, `y`, `velocity`, ...).
        role: &'static str,
    },
    /// A required field is not in the cloud.
    #[error("field `{name}` ({role}) is not in the cloud")]
    MissingField {
        /// What the field holds.
        role: &'static str,
        /// The configured field name.
        name: String,
    },
    /// A field that is read has a datatype code outside `PointField::INT8..=FLOAT64`.
    #[error("field `{name}` has unsupported datatype code {datatype}")]
    UnsupportedDatatype {
        /// Field name.
        name: String,
        /// The datatype code found.
        datatype: u8,
    },
    /// A field that is read has `count == 0`, so it holds no value.
    #[error("field `{name}` has count 0")]
    ZeroCount {
        /// Field name.
        name: String,
    },
    /// A field that is read does not fit inside one point.
    #[error("field `{name}` (offset {offset}, {size} bytes) extends past point_step {point_step}")]
    FieldPastPointStep {
        /// Field name.
        name: String,
        /// Its byte offset.
        offset: u32,
        /// Its element size, bytes.
        size: usize,
        /// The cloud's point_step.
        point_step: u32,
    },
    /// `point_step` is 0 in a cloud that has points.
    #[error("point_step is 0")]
    ZeroPointStep,
    /// `row_step` is smaller than `width * point_step`, so rows would overlap.
    #[error("row_step {row_step} < width {width} * point_step {point_step}")]
    RowStepTooSmall {
        /// The cloud's row_step.
        row_step: u32,
        /// The cloud's width.
        width: u32,
        /// The cloud's point_step.
        point_step: u32,
    },
    /// The byte count the header implies does not fit in memory addresses (`usize`).
    #[error("cloud size {height} x {width} (row_step {row_step}) overflows")]
    SizeOverflow {
        /// The cloud's height.
        height: u32,
        /// The cloud's width.
        width: u32,
        /// The cloud's row_step.
        row_step: u32,
    },
    /// `data` is shorter than `height * row_step`.
    #[error("data has {len} bytes, height * row_step needs {needed}")]
    Truncated {
        /// Bytes needed.
        needed: u64,
        /// Bytes present.
        len: usize,
    },
}

/// The detections of one cloud and how many points were skipped.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DecodedCloud {
    /// Valid detections, in the radar frame, in cloud order (row-major).
    pub detections: Vec<Detection>,
    /// Points skipped because a required value (x, y, z, velocity) or the range was not finite.
    pub skipped_nonfinite: usize,
    /// Points skipped because they sit exactly at the radar (range 0: no ray, no radial direction).
    pub skipped_zero_range: usize,
}

/// Offset of a field within a point and how to read it.
#[derive(Debug, Clone, Copy)]
struct FieldReader {
    offset: usize,
    kind: ScalarType,
}

#[derive(Debug, Clone, Copy)]
enum VelocityReader {
    /// One scalar radial velocity field.
    Radial(FieldReader),
    /// Vector components (vx, vy) in the radar frame, projected on the ray.
    Vector(FieldReader, FieldReader),
}

/// A cloud's field layout, resolved once per message.
#[derive(Debug, Clone, Copy)]
struct ResolvedLayout {
    x: FieldReader,
    y: FieldReader,
    z: Option<FieldReader>,
    velocity: VelocityReader,
    rcs: Option<FieldReader>,
}

/// Decodes a radar PointCloud2 into detections (radar frame), using the field names in `fields`.
///
/// Any field order, offsets, datatypes `INT8..=FLOAT64`, either byte order, row padding
/// (`row_step > width * point_step`) and `count >= 1` (element 0 is read) are accepted. Integer fields
/// are read as their value (no scaling). The radial velocity comes from the scalar field
/// `fields.velocity` or, when that name is empty, from `(vx, vy, 0) . p / |p|` with `vx`, `vy` the
/// fields `fields.velocity_x`, `fields.velocity_y` (positive = moving away). `fields.z` empty gives
/// z = 0; `fields.rcs` empty or absent from the cloud gives `rcs: None`, and a non-finite rcs value
/// also gives `None`.
///
/// Points with a non-finite required value or range, or with range 0, are skipped and counted in the
/// result. A cloud without points (`height * width == 0`) decodes to nothing without looking at its
/// layout.
pub fn decode_detections(
    cloud: &PointCloud2,
    fields: &FieldsConfig,
) -> Result<DecodedCloud, DecodeError> {
    let mut out = DecodedCloud::default();
    decode_detections_into(cloud, fields, &mut out)?;
    Ok(out)
}

/// As [`decode_detections`], but refills `out` (cleared first, also on error) so that its allocation is
/// reused from message to message.
pub fn decode_detections_into(
    cloud: &PointCloud2,
    fields: &FieldsConfig,
    out: &mut DecodedCloud,
) -> Result<(), DecodeError> {
    out.detections.clear();
    out.skipped_nonfinite = 0;
    out.skipped_zero_range = 0;
    if cloud.height == 0 || cloud.width == 0 {
        return Ok(());
    }
    let geometry = check_geometry(cloud)?;
    let layout = resolve_layout(cloud, fields)?;
    out.detections.reserve(geometry.height * geometry.width);
    if cloud.is_bigendian {
        decode_points::<true>(&cloud.data, &geometry, &layout, out);
    } else {
        decode_points::<false>(&cloud.data, &geometry, &layout, out);
    }
    Ok(())
}

/// Sizes of a cloud, checked against each other and against `data`.
struct Geometry {
    height: usize,
    width: usize,
    point_step: usize,
    row_step: usize,
}

fn check_geometry(cloud: &PointCloud2) -> Result<Geometry, DecodeError> {
    let (height, width) = (cloud.height, cloud.width);
    let (point_step, row_step) = (cloud.point_step, cloud.row_step);
    if point_step == 0 {
        return Err(DecodeError::ZeroPointStep);
    }
    // u32 * u32 always fits in u64.
    let row_bytes = u64::from(width) * u64::from(point_step);
    if u64::from(row_step) < row_bytes {
        return Err(DecodeError::RowStepTooSmall {
            row_step,
            width,
            point_step,
        });
    }
    let needed = u64::from(height) * u64::from(row_step);
    let overflow = DecodeError::SizeOverflow {
        height,
        width,
        row_step,
    };
    let to_usize = |v: u64| usize::try_from(v).map_err(|_| overflow.clone());
    let needed_usize = to_usize(needed)?;
    // The point count must be addressable too (it is bounded by `needed` since point_step >= 1).
    to_usize(u64::from(height) * u64::from(width))?;
    if cloud.data.len() < needed_usize {
        return Err(DecodeError::Truncated {
            needed,
            len: cloud.data.len(),
        });
    }
    Ok(Geometry {
        height: to_usize(u64::from(height))?,
        width: to_usize(u64::from(width))?,
        point_step: to_usize(u64::from(point_step))?,
        row_step: to_usize(u64::from(row_step))?,
    })
}

/// Finds the first field called `name` and checks that element 0 can be read inside a point.
fn find_field(cloud: &PointCloud2, name: &str) -> Result<Option<FieldReader>, DecodeError> {
    let Some(f) = cloud.fields.iter().find(|f| f.name == name) else {
        return Ok(None);
    };
    let kind =
        ScalarType::from_datatype(f.datatype).ok_or_else(|| DecodeError::UnsupportedDatatype {
            name: f.name.clone(),
            datatype: f.datatype,
        })?;
    if f.count == 0 {
        return Err(DecodeError::ZeroCount {
            name: f.name.clone(),
        });
    }
    let end = u64::from(f.offset) + kind.size() as u64;
    if end > u64::from(cloud.point_step) {
        return Err(DecodeError::FieldPastPointStep {
            name: f.name.clone(),
            offset: f.offset,
            size: kind.size(),
            point_step: cloud.point_step,
        });
    }
    Ok(Some(FieldReader {
        // offset < point_step, which fits in usize (checked in check_geometry).
        offset: f.offset as usize,
        kind,
    }))
}

fn required_field(
    cloud: &PointCloud2,
    role: &'static str,
    name: &str,
) -> Result<FieldReader, DecodeError> {
    if name.is_empty() {
        return Err(DecodeError::Unconfigured { role });
    }
    find_field(cloud, name)?.ok_or_else(|| DecodeError::MissingField {
        role,
        name: name.to_string(),
    })
}

fn resolve_layout(
    cloud: &PointCloud2,
    fields: &FieldsConfig,
) -> Result<ResolvedLayout, DecodeError> {
    let x = required_field(cloud, "x", &fields.x)?;
    let y = required_field(cloud, "y", &fields.y)?;
    let z = if fields.z.is_empty() {
        None
    } else {
        Some(required_field(cloud, "z", &fields.z)?)
    };
    let velocity = if !fields.velocity.is_empty() {
        VelocityReader::Radial(required_field(cloud, "velocity", &fields.velocity)?)
    } else if !fields.velocity_x.is_empty() || !fields.velocity_y.is_empty() {
        VelocityReader::Vector(
            required_field(cloud, "velocity_x", &fields.velocity_x)?,
            required_field(cloud, "velocity_y", &fields.velocity_y)?,
        )
    } else {
        return Err(DecodeError::Unconfigured { role: "velocity" });
    };
    // rcs is optional: absent from the cloud means None, but a present and malformed field is an error.
    let rcs = if fields.rcs.is_empty() {
        None
    } else {
        find_field(cloud, &fields.rcs)?
    };
    Ok(ResolvedLayout {
        x,
        y,
        z,
        velocity,
        rcs,
    })
}

/// `N` bytes at `offset` of `point`, or `None` when they are not all there.
#[inline(always)]
fn bytes_at<const N: usize>(point: &[u8], offset: usize) -> Option<[u8; N]> {
    point.get(offset..)?.first_chunk::<N>().copied()
}

/// Reads element 0 of a field as f64. Bounds were checked when the layout was resolved; should they not
/// hold, NaN comes back and the point is skipped as non-finite instead of panicking.
#[inline(always)]
fn read<const BE: bool>(f: FieldReader, point: &[u8]) -> f64 {
    macro_rules! num {
        ($t:ty) => {
            match bytes_at(point, f.offset) {
                Some(b) => {
                    if BE {
                        <$t>::from_be_bytes(b) as f64
                    } else {
                        <$t>::from_le_bytes(b) as f64
                    }
                }
                None => f64::NAN,
            }
        };
    }
    match f.kind {
        ScalarType::I8 => num!(i8),
        ScalarType::U8 => num!(u8),
        ScalarType::I16 => num!(i16),
        ScalarType::U16 => num!(u16),
        ScalarType::I32 => num!(i32),
        ScalarType::U32 => num!(u32),
        ScalarType::F32 => num!(f32),
        ScalarType::F64 => num!(f64),
    }
}

fn decode_points<const BE: bool>(
    data: &[u8],
    g: &Geometry,
    l: &ResolvedLayout,
    out: &mut DecodedCloud,
) {
    let row_bytes = g.width * g.point_step;
    for r in 0..g.height {
        let start = r * g.row_step;
        // Present by check_geometry; `get` keeps a broken invariant from turning into a panic.
        let Some(row) = data.get(start..start + row_bytes) else {
            break;
        };
        for p in row.chunks_exact(g.point_step) {
            let x = read::<BE>(l.x, p);
            let y = read::<BE>(l.y, p);
            let z = l.z.map_or(0.0, |f| read::<BE>(f, p));
            let (va, vb) = match l.velocity {
                VelocityReader::Radial(f) => (read::<BE>(f, p), 0.0),
                VelocityReader::Vector(fx, fy) => (read::<BE>(fx, p), read::<BE>(fy, p)),
            };
            if !(x.is_finite()
                && y.is_finite()
                && z.is_finite()
                && va.is_finite()
                && vb.is_finite())
            {
                out.skipped_nonfinite += 1;
                continue;
            }
            let range = (x * x + y * y + z * z).sqrt();
            if range == 0.0 {
                out.skipped_zero_range += 1;
                continue;
            }
            let v_r = match l.velocity {
                VelocityReader::Radial(_) => va,
                // Radial part of v = (vx, vy, 0): v . p / |p|.
                VelocityReader::Vector(..) => (va * x + vb * y) / range,
            };
            // Finite inputs can still overflow (FLOAT64 values near f64::MAX).
            if !(range.is_finite() && v_r.is_finite()) {
                out.skipped_nonfinite += 1;
                continue;
            }
            let rcs = l.rcs.map(|f| read::<BE>(f, p)).filter(|v| v.is_finite());
            out.detections.push(Detection {
                p_radar: Vec3::new(x, y, z),
                v_r,
                rcs,
            });
        }
    }
}

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
    if detections.len() % rows != 0 {
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
