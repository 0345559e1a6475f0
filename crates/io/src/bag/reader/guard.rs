//! Checks of MCAP records before the mcap crate parses them. The crate reserves a string's declared
//! length before it reads the bytes, so a record of a few bytes whose string claims 1.6 GB costs 1.6 GB;
//! and its indexed reader holds every chunk that overlaps the current one in time decompressed at once.
//! Both are bounded here, from the lengths and sizes the file declares.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};

use mcap::records::ChunkIndex;

const HEADER: u8 = 0x01;
const SCHEMA: u8 = 0x03;
const CHANNEL: u8 = 0x04;
const CHUNK: u8 = 0x06;
const CHUNK_INDEX: u8 = 0x08;
const ATTACHMENT: u8 = 0x09;
const ATTACHMENT_INDEX: u8 = 0x0A;
const METADATA: u8 = 0x0C;
const METADATA_INDEX: u8 = 0x0D;

/// A walk over a record body by its field layout.
struct Fields<'a> {
    body: &'a [u8],
    at: usize,
}

impl Fields<'_> {
    fn skip(&mut self, n: usize) -> Option<()> {
        self.at = self.at.checked_add(n).filter(|&e| e <= self.body.len())?;
        Some(())
    }

    fn u32(&mut self) -> Option<usize> {
        let b = self.body.get(self.at..self.at.checked_add(4)?)?;
        self.at += 4;
        usize::try_from(u32::from_le_bytes(b.try_into().ok()?)).ok()
    }

    /// A length-prefixed string that fits in the body.
    fn string(&mut self) -> Option<()> {
        let n = self.u32()?;
        self.skip(n)
    }

    /// A `map<string, string>`: its byte length, then key and value strings within it.
    fn string_map(&mut self) -> Option<()> {
        let n = self.u32()?;
        let end = self.at.checked_add(n).filter(|&e| e <= self.body.len())?;
        while self.at < end {
            self.string()?;
            self.string()?;
        }
        (self.at == end).then_some(())
    }
}

/// Whether every length-prefixed string (and string map) of the record `op` fits in `body`. Records
/// without strings pass; so does a body too short for its fixed fields (the crate reports that itself
/// without allocating).
pub(super) fn strings_fit(op: u8, body: &[u8]) -> bool {
    let mut f = Fields { body, at: 0 };
    let fixed = |f: &mut Fields<'_>, n: usize| f.skip(n).is_some();
    let ok = match op {
        HEADER => f.string().and_then(|_| f.string()),
        SCHEMA => {
            if !fixed(&mut f, 2) {
                return true;
            }
            f.string().and_then(|_| f.string())
        }
        CHANNEL => {
            if !fixed(&mut f, 4) {
                return true;
            }
            f.string()
                .and_then(|_| f.string())
                .and_then(|_| f.string_map())
        }
        // Start and end time, uncompressed size, CRC, then the compression name.
        CHUNK => {
            if !fixed(&mut f, 28) {
                return true;
            }
            f.string()
        }
        // Start and end time, chunk offset and length, the message index offsets (a map of fixed
        // entries), their length, then the compression name.
        CHUNK_INDEX => {
            if !fixed(&mut f, 32) {
                return true;
            }
            f.u32()
                .and_then(|n| f.skip(n))
                .and_then(|_| f.skip(8))
                .and_then(|_| f.string())
        }
        ATTACHMENT => {
            if !fixed(&mut f, 16) {
                return true;
            }
            f.string().and_then(|_| f.string())
        }
        ATTACHMENT_INDEX => {
            if !fixed(&mut f, 40) {
                return true;
            }
            f.string().and_then(|_| f.string())
        }
        METADATA => f.string().and_then(|_| f.string_map()),
        METADATA_INDEX => {
            if !fixed(&mut f, 16) {
                return true;
            }
            f.string()
        }
        _ => Some(()),
    };
    ok.is_some()
}

/// Why the summary section of `file` (`len` bytes) cannot be handed to the mcap crate, if it cannot:
/// a record whose strings do not fit in it. Reads the footer for the section's place; a file without
/// one, or whose footer or section does not add up, passes (the crate reports that damage itself).
/// Reads at most `limit` bytes of summary.
pub(super) fn summary_fault(file: &mut File, len: u64, limit: usize) -> Option<String> {
    // Footer record: opcode, length, summary start, summary offset start, CRC; then the magic.
    const FOOTER_LEN: u64 = 1 + 8 + 8 + 8 + 4;
    let footer_at = len.checked_sub(FOOTER_LEN + 8)?;
    let mut footer = [0u8; FOOTER_LEN as usize];
    file.seek(SeekFrom::Start(footer_at)).ok()?;
    file.read_exact(&mut footer).ok()?;
    let start = u64::from_le_bytes(footer[9..17].try_into().ok()?);
    if footer[0] != 0x02 || start == 0 || start >= footer_at || footer_at - start > limit as u64 {
        return None;
    }
    let mut section = vec![0u8; usize::try_from(footer_at - start).ok()?];
    file.seek(SeekFrom::Start(start)).ok()?;
    file.read_exact(&mut section).ok()?;
    let mut at = 0usize;
    while let Some(head) = section.get(at..at + 9) {
        let op = head[0];
        let n = usize::try_from(u64::from_le_bytes(head[1..9].try_into().ok()?)).ok()?;
        let body = section.get(at + 9..(at + 9).checked_add(n)?)?;
        if !strings_fit(op, body) {
            return Some(format!(
                "summary record {op:#04x} at byte {} declares a string longer than the record",
                start + at as u64
            ));
        }
        at += 9 + n;
    }
    None
}

/// The most bytes that chunks overlapping in log time declare together (uncompressed): what the
/// indexed reader may hold at once when it merges them.
pub(super) fn overlapping_bytes(chunks: &[ChunkIndex]) -> u64 {
    // Sweep over the chunks' time ranges: +size at a start, -size after an end.
    let mut events: Vec<(u64, bool, u64)> = chunks
        .iter()
        .flat_map(|c| {
            let size = c.uncompressed_size.max(c.compressed_size);
            [
                (c.message_start_time, false, size),
                (c.message_end_time, true, size),
            ]
        })
        .collect();
    // At equal times the starts come first: chunks touching at one stamp overlap.
    events.sort_unstable();
    let (mut now, mut most) = (0u64, 0u64);
    for (_, end, size) in events {
        if end {
            now = now.saturating_sub(size);
        } else {
            now = now.saturating_add(size);
            most = most.max(now);
        }
    }
    most
}

#[cfg(test)]
mod tests {
    use super::*;

    fn string(s: &[u8]) -> Vec<u8> {
        let mut v = (s.len() as u32).to_le_bytes().to_vec();
        v.extend_from_slice(s);
        v
    }

    #[test]
    fn a_string_longer_than_its_record_is_refused() {
        let good = [string(b"ros2"), string(b"dc_loc")].concat();
        assert!(strings_fit(HEADER, &good));
        let mut bad = good.clone();
        bad[0..4].copy_from_slice(&0x6573_6162u32.to_le_bytes());
        assert!(!strings_fit(HEADER, &bad));
        // A channel: id, schema id, topic, encoding, then one metadata pair.
        let pair = [string(b"k"), string(b"v")].concat();
        let mut channel = vec![1, 0, 1, 0];
        channel.extend(string(b"/radar"));
        channel.extend(string(b"cdr"));
        channel.extend((pair.len() as u32).to_le_bytes());
        channel.extend(&pair);
        assert!(strings_fit(CHANNEL, &channel));
        let mut bad = channel.clone();
        let n = bad.len();
        bad[n - 5..n - 1].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(!strings_fit(CHANNEL, &bad));
        // A chunk index whose compression name runs past the record.
        let mut index = vec![0u8; 32];
        index.extend(0u32.to_le_bytes());
        index.extend([0u8; 8]);
        index.extend(string(b"zstd"));
        index.extend([0u8; 16]);
        assert!(strings_fit(CHUNK_INDEX, &index));
        index[44..48].copy_from_slice(&0x7000_0000u32.to_le_bytes());
        assert!(!strings_fit(CHUNK_INDEX, &index));
        // Records without strings pass.
        assert!(strings_fit(0x05, &[0xff; 3]));
    }

    #[test]
    fn overlapping_chunks_add_up_and_consecutive_ones_do_not() {
        let chunk = |start: u64, end: u64, size: u64| ChunkIndex {
            message_start_time: start,
            message_end_time: end,
            chunk_start_offset: 0,
            chunk_length: 0,
            message_index_offsets: Default::default(),
            message_index_length: 0,
            compression: String::new(),
            compressed_size: size,
            uncompressed_size: size,
        };
        let consecutive = [chunk(0, 9, 10), chunk(10, 19, 10), chunk(20, 29, 10)];
        assert_eq!(overlapping_bytes(&consecutive), 10);
        let stacked = [chunk(0, 100, 10), chunk(5, 6, 10), chunk(6, 50, 10)];
        assert_eq!(overlapping_bytes(&stacked), 30);
    }
}
