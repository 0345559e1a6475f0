//! `sensor_msgs/PointCloud2` <-> [`Detection`](crate::radar::Detection): the decoder every radar message goes through, and the
//! encoder the simulator, the node's submap output and the tests use.
//!
//! Entry points: [`decode_detections`], [`decode_detections_into`] (reuses the output buffer),
//! [`DecodedCloud`], [`DecodeError`]; [`encode_detections`], [`CloudLayout`], [`LayoutField`],
//! [`FieldRole`], [`EncodeError`]; [`ScalarType`] (the PointField datatypes).
//!
//! Decoding resolves the field layout once per message (name lookup, datatype, offset, bounds) and then
//! runs one tight loop over the points with no allocation beyond the output vector and no string work.
//! Byte order is a const generic, so the inner loop carries no endianness branch.
//!
//! Parts: `decode` (PointCloud2 -> detections), `encode` (detections -> PointCloud2).

mod decode;
mod encode;

pub use decode::{DecodeError, DecodedCloud, decode_detections, decode_detections_into};
pub use encode::{CloudLayout, EncodeError, FieldRole, LayoutField, encode_detections};

use crate::msgs::sensor_msgs::PointField;

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

    /// The `PointField` constant's name (`FLOAT32`, `INT8`, ...).
    pub fn name(self) -> &'static str {
        match self {
            ScalarType::I8 => "INT8",
            ScalarType::U8 => "UINT8",
            ScalarType::I16 => "INT16",
            ScalarType::U16 => "UINT16",
            ScalarType::I32 => "INT32",
            ScalarType::U32 => "UINT32",
            ScalarType::F32 => "FLOAT32",
            ScalarType::F64 => "FLOAT64",
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

/// Offset of a field within a point and how to read it.
#[derive(Debug, Clone, Copy)]
struct FieldReader {
    offset: usize,
    kind: ScalarType,
}
