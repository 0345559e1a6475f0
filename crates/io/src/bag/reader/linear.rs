//! [`LinearSource`]: the messages of an MCAP file without a usable summary, read from start to end.
//!
//! Before reading, the file's top-level records are walked by their lengths ([`oversize_chunk`]): the
//! first chunk that declares more than the record limit (its record or its uncompressed size) is
//! where reading stops with an error, as the indexed reader refuses such a chunk from its index. The
//! linear reader streams a chunk's records, so it never holds the declared size; the walk keeps it
//! from decompressing a chunk that claims more than any real one.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::guard::strings_fit;
use super::{BagError, BagMessage, ChannelMeta, READ_SIZE, io_err, mcap_err, oversize};

/// The records messages need: schemas and channels (for the channel of each message) and messages.
const NEEDED: [u8; 3] = [0x03, 0x04, 0x05];

/// Messages of one file in file order, from start to end.
pub(super) struct LinearSource {
    path: PathBuf,
    file: BufReader<File>,
    reader: LinearReader,
    /// Bytes of the file handed to the reader so far.
    fed: u64,
    /// Where the first oversize chunk starts and why it is refused: no byte from there is read.
    stop: Option<(u64, String)>,
    /// Schemas seen so far: id -> (name, encoding, data).
    schemas: HashMap<u16, (String, String, Vec<u8>)>,
    /// Channels seen so far.
    pub(super) channels: BTreeMap<u16, Arc<ChannelMeta>>,
    topics: Option<Vec<String>>,
    /// The last message read by [`Self::next_raw`].
    last: Option<(mcap::records::MessageHeader, Vec<u8>)>,
}

impl LinearSource {
    /// Opens `path` for reading (the messages of `topics`, or all), refusing records and chunks that
    /// declare more than `limit` bytes.
    pub(super) fn open(
        path: &Path,
        topics: Option<&[&str]>,
        limit: usize,
    ) -> Result<Self, BagError> {
        let stop = oversize_chunk(path, limit).map_err(io_err(path))?;
        let file = File::open(path).map_err(io_err(path))?;
        let options = LinearReaderOptions::default()
            .with_record_length_limit(limit)
            .with_validate_chunk_crcs(true);
        Ok(LinearSource {
            path: path.to_path_buf(),
            file: BufReader::with_capacity(1 << 16, file),
            reader: LinearReader::new_with_options(options),
            fed: 0,
            stop,
            schemas: HashMap::new(),
            channels: BTreeMap::new(),
            topics: topics.map(|t| t.iter().map(|s| s.to_string()).collect()),
            last: None,
        })
    }

    /// Advances to the next message (kept in `self.last`); returns its channel id and log time.
    pub(super) fn next_raw(&mut self) -> Option<Result<(u16, u64), BagError>> {
        enum Step {
            Read(usize),
            Message(mcap::records::MessageHeader, Vec<u8>),
            Other,
        }
        loop {
            let step = match self.reader.next_event()? {
                Err(e) => return Some(Err(mcap_err(&self.path)(e))),
                Ok(LinearReadEvent::ReadRequest(n)) => Step::Read(n),
                // Only the records messages need are parsed, each once its strings are known to fit.
                Ok(LinearReadEvent::Record { opcode, .. }) if !NEEDED.contains(&opcode) => {
                    Step::Other
                }
                Ok(LinearReadEvent::Record { opcode, data }) if !strings_fit(opcode, data) => {
                    return Some(Err(BagError::Damaged {
                        path: self.path.clone(),
                        reason: format!(
                            "record {opcode:#04x} declares a string longer than the record"
                        ),
                    }));
                }
                Ok(LinearReadEvent::Record { opcode, data }) => {
                    match mcap::parse_record(opcode, data) {
                        Err(e) => return Some(Err(mcap_err(&self.path)(e))),
                        Ok(Record::Schema { header, data }) => {
                            self.schemas
                                .insert(header.id, (header.name, header.encoding, data.to_vec()));
                            Step::Other
                        }
                        Ok(Record::Channel(c)) => {
                            let (type_name, schema_encoding, schema) =
                                self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                            self.channels.insert(
                                c.id,
                                Arc::new(ChannelMeta {
                                    topic: c.topic,
                                    type_name,
                                    message_encoding: c.message_encoding,
                                    schema_encoding,
                                    schema,
                                    md5sum: String::new(),
                                }),
                            );
                            Step::Other
                        }
                        Ok(Record::Message { header, data }) => {
                            Step::Message(header, data.into_owned())
                        }
                        Ok(_) => Step::Other,
                    }
                }
            };
            match step {
                Step::Read(n) => {
                    let mut n = n.min(READ_SIZE);
                    if let Some((at, why)) = &self.stop {
                        // Every record before the oversize chunk has been read once the reader
                        // asks for the chunk's first byte.
                        let left = at.saturating_sub(self.fed);
                        if left == 0 {
                            return Some(Err(BagError::Damaged {
                                path: self.path.clone(),
                                reason: why.clone(),
                            }));
                        }
                        n = n.min(usize::try_from(left).unwrap_or(usize::MAX));
                    }
                    let buf = self.reader.insert(n);
                    match self.file.read(buf) {
                        Ok(got) => {
                            self.fed += got as u64;
                            self.reader.notify_read(got);
                        }
                        Err(e) => return Some(Err(io_err(&self.path)(e))),
                    }
                }
                Step::Message(header, data) => {
                    let (id, t) = (header.channel_id, header.log_time);
                    self.last = Some((header, data));
                    return Some(Ok((id, t)));
                }
                Step::Other => {}
            }
        }
    }

    pub(super) fn next(&mut self) -> Option<Result<BagMessage, BagError>> {
        loop {
            if let Err(e) = self.next_raw()? {
                return Some(Err(e));
            }
            let (header, data) = self.last.take()?;
            let Some(channel) = self.channels.get(&header.channel_id) else {
                return Some(Err(BagError::UnknownChannel {
                    path: self.path.clone(),
                    channel_id: header.channel_id,
                }));
            };
            if let Some(topics) = &self.topics
                && !topics.contains(&channel.topic)
            {
                continue;
            }
            return Some(Ok(BagMessage::read(channel, &header, data)));
        }
    }
}

/// The first chunk of the file at `path` that declares more than `limit` bytes (its record length or
/// its uncompressed size): its byte offset in the file and why it is refused. Walks the
/// top-level records by their lengths from the magic to the footer, or to the first record the end of
/// the file cuts off (the reader reports that damage itself).
fn oversize_chunk(path: &Path, limit: usize) -> std::io::Result<Option<(u64, String)>> {
    const MAGIC_LEN: u64 = 8;
    const FOOTER: u8 = 0x02;
    const CHUNK: u8 = 0x06;
    let mut file = BufReader::with_capacity(1 << 16, File::open(path)?);
    let len = file.get_ref().metadata()?.len();
    file.seek(SeekFrom::Start(MAGIC_LEN))?;
    let mut at = MAGIC_LEN;
    // Opcode, record length, then a chunk's start time, end time, uncompressed size, CRC and the
    // length of its compression name.
    let mut head = [0u8; 9 + 32];
    loop {
        if file.read_exact(&mut head[..9]).is_err() || head[0] == FOOTER {
            return Ok(None);
        }
        let record_len = u64::from_le_bytes(head[1..9].try_into().unwrap_or_default());
        let mut read = 9;
        if head[0] == CHUNK {
            if file.read_exact(&mut head[9..]).is_err() {
                return Ok(None);
            }
            read += 32;
            let uncompressed = u64::from_le_bytes(head[25..33].try_into().unwrap_or_default());
            let declared = record_len.max(uncompressed);
            if declared > limit as u64 {
                return Ok(Some((at, oversize(at, declared, limit))));
            }
            let name = u64::from(u32::from_le_bytes(
                head[37..41].try_into().unwrap_or_default(),
            ));
            if name > record_len.saturating_sub(32) {
                let why = format!(
                    "chunk at byte {at} declares a compression name of {name} bytes, longer than \
                     the chunk"
                );
                return Ok(Some((at, why)));
            }
            if name == 0 {
                let (walked, fault) = uncompressed_chunk_fault(&mut file, at, record_len)?;
                read += walked;
                if fault.is_some() {
                    return Ok(fault.map(|why| (at, why)));
                }
            }
        }
        let Some(next) = at.checked_add(9).and_then(|a| a.checked_add(record_len)) else {
            return Ok(None);
        };
        if next > len {
            return Ok(None);
        }
        // A chunk shorter than the head read above is damage the reader reports when it gets there.
        let Some(rest) = (next - at).checked_sub(read) else {
            let why =
                format!("chunk at byte {at} is shorter than a chunk header ({record_len} bytes)");
            return Ok(Some((at, why)));
        };
        file.seek_relative(i64::try_from(rest).unwrap_or(i64::MAX))?;
        at = next;
    }
}

/// Whether the records of an uncompressed chunk (at byte `at`, `record_len` bytes; the file is just past
/// its empty compression name) run past the chunk's end, which the mcap crate's reader does not check.
/// Returns the bytes read and the fault, if any.
fn uncompressed_chunk_fault(
    file: &mut BufReader<File>,
    at: u64,
    record_len: u64,
) -> std::io::Result<(u64, Option<String>)> {
    // The chunk's fields before its records: times, uncompressed size, CRC, empty name, records length.
    const FIXED: u64 = 8 + 8 + 8 + 4 + 4 + 8;
    let mut word = [0u8; 8];
    if file.read_exact(&mut word).is_err() {
        return Ok((0, None));
    }
    let records = u64::from_le_bytes(word);
    let mut walked = 8;
    let fault = |why: &str| Some(format!("chunk at byte {at}: {why}"));
    if records > record_len.saturating_sub(FIXED) {
        return Ok((walked, fault("its records run past the chunk")));
    }
    let mut left = records;
    let mut head = [0u8; 9];
    while left > 0 {
        if left < 9 || file.read_exact(&mut head).is_err() {
            return Ok((walked, fault("a record inside it is cut off")));
        }
        walked += 9;
        let n = u64::from_le_bytes(head[1..9].try_into().unwrap_or_default());
        if n > left - 9 {
            return Ok((walked, fault("a record inside it runs past the chunk")));
        }
        file.seek_relative(i64::try_from(n).unwrap_or(i64::MAX))?;
        walked += n;
        left -= 9 + n;
    }
    Ok((walked, None))
}
