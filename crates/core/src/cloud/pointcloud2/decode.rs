//! PointCloud2 -> [`Detection`]: the field layout resolved once per message, then one tight loop over
//! the points, the byte order a const generic.

use super::{FieldReader, ScalarType};
use crate::math::Vec3;
use crate::msgs::sensor_msgs::PointCloud2;
use crate::radar::Detection;
use crate::radar::FieldsConfig;

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
    #[error("field `{name}` ({role}) is not in the cloud; its fields: {available}")]
    MissingField {
        /// What the field holds.
        role: &'static str,
        /// The configured field name.
        name: String,
        /// The cloud's fields with their datatypes (`x FLOAT32, y FLOAT32, RCS INT8`), so that the
        /// right name can be read off the message.
        available: String,
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
        available: field_list(cloud),
    })
}

/// The cloud's fields as `name DATATYPE` (`[count]` when not 1), comma-separated, in message order.
pub(crate) fn field_list(cloud: &PointCloud2) -> String {
    if cloud.fields.is_empty() {
        return "none".into();
    }
    cloud
        .fields
        .iter()
        .map(|f| {
            let kind = ScalarType::from_datatype(f.datatype)
                .map_or_else(|| format!("datatype {}", f.datatype), |t| t.name().into());
            match f.count {
                1 => format!("{} {kind}", f.name),
                n => format!("{} {kind}[{n}]", f.name),
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
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
