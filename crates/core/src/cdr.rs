//! CDR as ROS 2 puts it on the wire and in bags: a 4-byte encapsulation header followed by plain CDR
//! (XCDR1) whose alignment is counted from the first byte after the header.
//!
//! Entry points: [`encode`], [`decode`], [`CdrError`].
//!
//! The header is the representation identifier (big endian `u16`: `0x0000` CDR big endian,
//! `0x0001` CDR little endian) and two option bytes (written as zero; on read they may carry the
//! count of padding bytes at the end, which is ignored). The body is serde through the
//! `cdr-encoding` crate, the CDR implementation of rustdds; the message structs of
//! [`crate::msgs`] map onto it field by field (`uint8[]` as serde bytes, fixed arrays as tuples).

use byteorder::{BigEndian, LittleEndian};
use serde::Serialize;
use serde::de::DeserializeOwned;

/// Representation identifier of plain CDR, big endian.
const CDR_BE: [u8; 2] = [0x00, 0x00];
/// Representation identifier of plain CDR, little endian (what ROS 2 writes on x86 and ARM).
const CDR_LE: [u8; 2] = [0x00, 0x01];
/// ROS 2 writers pad the body to a multiple of 4 bytes at most; more unread bytes mean a type mismatch.
const MAX_TRAILING_PADDING: usize = 3;

/// Why CDR bytes could not be made or read.
#[derive(Debug, thiserror::Error)]
pub enum CdrError {
    /// Fewer bytes than the 4-byte encapsulation header.
    #[error("{len} bytes is too short for the 4-byte CDR encapsulation header")]
    TooShort {
        /// Length of the buffer.
        len: usize,
    },
    /// A representation other than plain CDR (e.g. XCDR2 or parameter lists), which ROS 2 does not
    /// use for messages.
    #[error("unsupported CDR representation identifier {id:#06x} (plain CDR is 0x0000 or 0x0001)")]
    UnsupportedRepresentation {
        /// The identifier found in the header.
        id: u16,
    },
    /// The body does not hold a value of the requested type (too short, bad bool or UTF-8, ...).
    #[error("malformed CDR body: {0}")]
    Malformed(#[source] cdr_encoding::Error),
    /// The value was read but more bytes follow than end padding allows: the bytes are of another type.
    #[error(
        "{extra} bytes left after the message (at most {MAX_TRAILING_PADDING} bytes of padding)"
    )]
    TrailingBytes {
        /// Bytes left unread.
        extra: usize,
    },
    /// The value could not be serialised (a sequence of unknown length, a length over 2^32 - 1).
    #[error("CDR serialisation failed: {0}")]
    Serialize(#[source] cdr_encoding::Error),
}

/// Serialises `msg` as ROS 2 does: header `00 01 00 00` (CDR little endian), then the body.
pub fn encode<T: Serialize>(msg: &T) -> Result<Vec<u8>, CdrError> {
    let mut out = Vec::with_capacity(4 + 2 * std::mem::size_of_val(msg));
    out.extend_from_slice(&CDR_LE);
    out.extend_from_slice(&[0, 0]);
    // cdr-encoding aligns relative to the first byte it writes itself, which is the first byte after
    // the header, as CDR in ROS 2 requires.
    cdr_encoding::to_writer::<T, LittleEndian, _>(&mut out, msg).map_err(CdrError::Serialize)?;
    Ok(out)
}

/// Deserialises a ROS 2 CDR message (header included), little or big endian.
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, CdrError> {
    let Some((header, body)) = bytes.split_first_chunk::<4>() else {
        return Err(CdrError::TooShort { len: bytes.len() });
    };
    let id = [header[0], header[1]];
    let (value, consumed) = if id == CDR_LE {
        cdr_encoding::from_bytes::<T, LittleEndian>(body)
    } else if id == CDR_BE {
        cdr_encoding::from_bytes::<T, BigEndian>(body)
    } else {
        return Err(CdrError::UnsupportedRepresentation {
            id: u16::from_be_bytes(id),
        });
    }
    .map_err(CdrError::Malformed)?;
    let extra = body.len().saturating_sub(consumed);
    if extra > MAX_TRAILING_PADDING {
        return Err(CdrError::TrailingBytes { extra });
    }
    Ok(value)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::builtin_interfaces::Time;

    #[test]
    fn header_errors_are_typed() {
        assert!(matches!(
            decode::<Time>(&[0, 1, 0]),
            Err(CdrError::TooShort { len: 3 })
        ));
        assert!(matches!(
            decode::<Time>(&[0, 7, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0]),
            Err(CdrError::UnsupportedRepresentation { id: 7 })
        ));
        assert!(matches!(
            decode::<Time>(&[0, 1, 0, 0, 1, 0, 0]),
            Err(CdrError::Malformed(_))
        ));
        assert!(matches!(
            decode::<Time>(&[0, 1, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 9, 9, 9, 9]),
            Err(CdrError::TrailingBytes { extra: 4 })
        ));
        // Up to three bytes of end padding are fine.
        let t: Time = decode(&[0, 1, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 0, 0, 0]).unwrap();
        assert_eq!((t.sec, t.nanosec), (1, 2));
    }
}
