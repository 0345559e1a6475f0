//! ROS 1 message serialisation read into the [`dc_loc_core::msgs`] structs through serde.
//!
//! The wire format (ROS 1 `roscpp_serialization`): little endian, no alignment; `bool` one byte;
//! `string` and `T[]` a `u32` length (bytes or elements) then the bytes or elements; `T[N]` the N
//! elements without a length; `time` and `duration` two 32-bit words (seconds, nanoseconds); nested
//! messages inline, field after field.
//!
//! The structs mirror the ROS 2 definitions, which differ from ROS 1 in two places, both handled here:
//! `std_msgs/Header` has a `uint32 seq` before its stamp in ROS 1 (read and dropped for every struct
//! named `Header`), and `time` is `builtin_interfaces/Time` (`int32 sec, uint32 nanosec`), whose two
//! 32-bit words take ROS 1's `uint32 secs, uint32 nsecs` as they are (times after 2038 read as negative
//! seconds).
//!
//! A length that asks for more than the bytes left is an error before anything is allocated, so a
//! message of n bytes never holds more than about n bytes decoded; bytes left after the message are an
//! error too (ROS 1 has no padding: they are bytes of another type).

use serde::de::{self, DeserializeOwned, DeserializeSeed, SeqAccess, Visitor};

/// Why ROS 1 bytes did not decode as the requested type.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Ros1Error {
    /// The bytes end inside the message.
    #[error("message ends at byte {len} inside a field")]
    Truncated {
        /// The message's length.
        len: usize,
    },
    /// A string or array length asks for more than the bytes left.
    #[error("a length of {declared} at byte {at} runs past the message's end ({len} bytes)")]
    Length {
        /// The declared length (bytes or elements).
        declared: u32,
        /// Where the length field starts.
        at: usize,
        /// The message's length.
        len: usize,
    },
    /// Bytes left once the message has been read: they belong to another type.
    #[error("{extra} bytes left after the message (ROS 1 messages have no padding)")]
    TrailingBytes {
        /// Bytes left.
        extra: usize,
    },
    /// A serde form no ROS message takes (maps, enums, options, chars).
    #[error("{0}")]
    Unsupported(String),
}

impl de::Error for Ros1Error {
    fn custom<T: std::fmt::Display>(msg: T) -> Self {
        Ros1Error::Unsupported(msg.to_string())
    }
}

/// Deserialises one ROS 1 message (the bytes of a bag's message data record) as `T`.
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, Ros1Error> {
    let mut de = Deserializer {
        input: bytes,
        at: 0,
    };
    let value = T::deserialize(&mut de)?;
    let extra = bytes.len() - de.at;
    if extra > 0 {
        return Err(Ros1Error::TrailingBytes { extra });
    }
    Ok(value)
}

/// A reader over one message's bytes.
struct Deserializer<'de> {
    input: &'de [u8],
    at: usize,
}

impl<'de> Deserializer<'de> {
    fn take(&mut self, n: usize) -> Result<&'de [u8], Ros1Error> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.input.len())
            .ok_or(Ros1Error::Truncated {
                len: self.input.len(),
            })?;
        let bytes = &self.input[self.at..end];
        self.at = end;
        Ok(bytes)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], Ros1Error> {
        let b = self.take(N)?;
        let mut out = [0u8; N];
        out.copy_from_slice(b);
        Ok(out)
    }

    fn u32(&mut self) -> Result<u32, Ros1Error> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    /// A length field of `unit`-byte items, checked against the bytes left.
    fn length(&mut self, unit: usize) -> Result<usize, Ros1Error> {
        let at = self.at;
        let declared = self.u32()?;
        let n = declared as usize;
        let left = self.input.len() - self.at;
        if n.checked_mul(unit).is_none_or(|bytes| bytes > left) {
            return Err(Ros1Error::Length {
                declared,
                at,
                len: self.input.len(),
            });
        }
        Ok(n)
    }

    fn bytes(&mut self) -> Result<&'de [u8], Ros1Error> {
        let n = self.length(1)?;
        self.take(n)
    }
}

macro_rules! primitive {
    ($method:ident, $visit:ident, $ty:ty) => {
        fn $method<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Ros1Error> {
            visitor.$visit(<$ty>::from_le_bytes(self.array()?))
        }
    };
}

impl<'de> de::Deserializer<'de> for &mut Deserializer<'de> {
    type Error = Ros1Error;

    fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported(
            "ROS 1 bytes do not describe themselves: a type is needed".into(),
        ))
    }

    fn deserialize_bool<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Ros1Error> {
        // roscpp writes 0 or 1 and reads any non-zero byte as true.
        visitor.visit_bool(self.array::<1>()?[0] != 0)
    }

    primitive!(deserialize_i8, visit_i8, i8);
    primitive!(deserialize_i16, visit_i16, i16);
    primitive!(deserialize_i32, visit_i32, i32);
    primitive!(deserialize_i64, visit_i64, i64);
    primitive!(deserialize_u8, visit_u8, u8);
    primitive!(deserialize_u16, visit_u16, u16);
    primitive!(deserialize_u32, visit_u32, u32);
    primitive!(deserialize_u64, visit_u64, u64);
    primitive!(deserialize_f32, visit_f32, f32);
    primitive!(deserialize_f64, visit_f64, f64);

    fn deserialize_char<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported(
            "no ROS 1 field reads as a Rust char".into(),
        ))
    }

    fn deserialize_str<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Ros1Error> {
        self.deserialize_string(visitor)
    }

    fn deserialize_string<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Ros1Error> {
        // ROS 1 strings are bytes; frame ids and names are ASCII in practice. Invalid UTF-8 is kept
        // readable rather than refused.
        let bytes = self.bytes()?;
        visitor.visit_string(String::from_utf8_lossy(bytes).into_owned())
    }

    fn deserialize_bytes<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Ros1Error> {
        visitor.visit_borrowed_bytes(self.bytes()?)
    }

    fn deserialize_byte_buf<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Ros1Error> {
        visitor.visit_byte_buf(self.bytes()?.to_vec())
    }

    fn deserialize_option<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported(
            "ROS 1 messages have no optional fields".into(),
        ))
    }

    fn deserialize_unit<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Ros1Error> {
        visitor.visit_unit()
    }

    fn deserialize_unit_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        visitor: V,
    ) -> Result<V::Value, Ros1Error> {
        visitor.visit_unit()
    }

    fn deserialize_newtype_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        visitor: V,
    ) -> Result<V::Value, Ros1Error> {
        visitor.visit_newtype_struct(self)
    }

    fn deserialize_seq<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Ros1Error> {
        // Every element takes at least one byte, so the count is bounded by the bytes left.
        let n = self.length(1)?;
        visitor.visit_seq(Elements { de: self, left: n })
    }

    fn deserialize_tuple<V: Visitor<'de>>(
        self,
        len: usize,
        visitor: V,
    ) -> Result<V::Value, Ros1Error> {
        visitor.visit_seq(Elements {
            de: self,
            left: len,
        })
    }

    fn deserialize_tuple_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        len: usize,
        visitor: V,
    ) -> Result<V::Value, Ros1Error> {
        self.deserialize_tuple(len, visitor)
    }

    fn deserialize_map<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported("ROS 1 messages have no maps".into()))
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        name: &'static str,
        fields: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Ros1Error> {
        if name == "Header" {
            // std_msgs/Header's `uint32 seq`, which the ROS 2 struct does not have.
            self.u32()?;
        }
        visitor.visit_seq(Elements {
            de: self,
            left: fields.len(),
        })
    }

    fn deserialize_enum<V: Visitor<'de>>(
        self,
        _: &'static str,
        _: &'static [&'static str],
        _: V,
    ) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported(
            "ROS 1 messages have no enums".into(),
        ))
    }

    fn deserialize_identifier<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported("ROS 1 fields carry no names".into()))
    }

    fn deserialize_ignored_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported(
            "ROS 1 fields cannot be skipped by name".into(),
        ))
    }

    fn is_human_readable(&self) -> bool {
        false
    }
}

/// The elements of an array, tuple or struct, in order.
struct Elements<'a, 'de> {
    de: &'a mut Deserializer<'de>,
    left: usize,
}

impl<'de> SeqAccess<'de> for Elements<'_, 'de> {
    type Error = Ros1Error;

    fn next_element_seed<T: DeserializeSeed<'de>>(
        &mut self,
        seed: T,
    ) -> Result<Option<T::Value>, Ros1Error> {
        if self.left == 0 {
            return Ok(None);
        }
        self.left -= 1;
        seed.deserialize(&mut *self.de).map(Some)
    }

    fn size_hint(&self) -> Option<usize> {
        Some(self.left)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dc_loc_core::msgs::builtin_interfaces::Time;
    use dc_loc_core::msgs::sensor_msgs::{PointCloud2, PointField};
    use dc_loc_core::msgs::std_msgs::Header;

    fn string(s: &str) -> Vec<u8> {
        let mut v = (s.len() as u32).to_le_bytes().to_vec();
        v.extend_from_slice(s.as_bytes());
        v
    }

    fn header(seq: u32, sec: u32, nsec: u32, frame: &str) -> Vec<u8> {
        [
            seq.to_le_bytes().to_vec(),
            sec.to_le_bytes().to_vec(),
            nsec.to_le_bytes().to_vec(),
            string(frame),
        ]
        .concat()
    }

    #[test]
    fn header_drops_seq_and_reads_time() {
        let h: Header = decode(&header(7, 1_700_000_000, 5, "radar")).unwrap();
        assert_eq!(
            h,
            Header {
                stamp: Time {
                    sec: 1_700_000_000,
                    nanosec: 5
                },
                frame_id: "radar".into()
            }
        );
    }

    #[test]
    fn a_cloud_reads_field_by_field() {
        let mut b = header(1, 2, 3, "f");
        b.extend(1u32.to_le_bytes()); // height
        b.extend(2u32.to_le_bytes()); // width
        b.extend(1u32.to_le_bytes()); // one field
        b.extend(string("x"));
        b.extend(0u32.to_le_bytes());
        b.push(7);
        b.extend(1u32.to_le_bytes());
        b.push(0); // is_bigendian
        b.extend(4u32.to_le_bytes());
        b.extend(8u32.to_le_bytes());
        b.extend(8u32.to_le_bytes()); // data length
        b.extend(1.5f32.to_le_bytes());
        b.extend((-2.0f32).to_le_bytes());
        b.push(1); // is_dense
        let c: PointCloud2 = decode(&b).unwrap();
        assert_eq!(c.width, 2);
        assert_eq!(
            c.fields,
            vec![PointField {
                name: "x".into(),
                offset: 0,
                datatype: 7,
                count: 1
            }]
        );
        assert_eq!(c.data.len(), 8);
        assert!(c.is_dense && !c.is_bigendian);
        // One byte more or less is an error, not a different message.
        let mut longer = b.clone();
        longer.push(0);
        assert_eq!(
            decode::<PointCloud2>(&longer).unwrap_err(),
            Ros1Error::TrailingBytes { extra: 1 }
        );
        assert!(matches!(
            decode::<PointCloud2>(&b[..b.len() - 1]),
            Err(Ros1Error::Truncated { .. })
        ));
    }

    #[test]
    fn lengths_past_the_end_are_refused_before_allocating() {
        let mut b = header(0, 0, 0, "");
        b.extend(1u32.to_le_bytes());
        b.extend(1u32.to_le_bytes());
        b.extend(0xFFFF_FFF0u32.to_le_bytes()); // fields: four billion
        let e = decode::<PointCloud2>(&b).unwrap_err();
        assert!(
            matches!(
                e,
                Ros1Error::Length {
                    declared: 0xFFFF_FFF0,
                    at: 24,
                    ..
                }
            ),
            "{e}"
        );
        let e = decode::<Header>(&[0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 9, 0, 0, 0]).unwrap_err();
        assert!(e.to_string().contains("a length of 9 at byte 12"), "{e}");
    }
}
