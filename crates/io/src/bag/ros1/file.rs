//! The records of a ROS 1 bag file: [`open`] learns its connections, counts and time range (from the
//! index section, or by a scan up to the damage), [`Source`] yields its messages in file order.

use std::collections::{BTreeMap, BTreeSet};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::super::BagError;
use super::super::reader::{BagMessage, ChannelMeta, MAX_RECORD_BYTES};
use super::{MAGIC, MAGIC_PREFIX, ros2_type_name};

const OP_MESSAGE_DATA: u8 = 0x02;
const OP_BAG_HEADER: u8 = 0x03;
const OP_INDEX_DATA: u8 = 0x04;
const OP_CHUNK: u8 = 0x05;
const OP_CHUNK_INFO: u8 = 0x06;
const OP_CONNECTION: u8 = 0x07;

/// What [`open`] learned of a file, for its [`Source`]s.
#[derive(Debug)]
pub(crate) struct Layout {
    /// Byte after the bag header record: the first chunk.
    start: u64,
    /// Where the chunk section ends: the index section, or the end of the file when the index is not
    /// usable.
    end: u64,
    /// Connections by id.
    connections: BTreeMap<u32, Arc<ChannelMeta>>,
    /// From a whole index: each chunk's position and the connections with messages in it (chunks
    /// without a selected topic are skipped undecompressed).
    chunks: Option<BTreeMap<u64, BTreeSet<u32>>>,
}

/// Channels with their message counts, and the earliest and latest message time (ns).
pub(crate) type Opened = (
    Layout,
    BTreeMap<u32, (Arc<ChannelMeta>, u64)>,
    Option<(u64, u64)>,
);

/// The fields of a record header (`name=value` pairs, each after its `u32` length).
struct Fields<'a> {
    fields: Vec<(&'a [u8], &'a [u8])>,
}

impl<'a> Fields<'a> {
    fn parse(bytes: &'a [u8]) -> Result<Self, String> {
        let mut fields = Vec::new();
        let mut rest = bytes;
        while !rest.is_empty() {
            let Some((len, tail)) = rest.split_first_chunk::<4>() else {
                return Err("a header field length is cut off".into());
            };
            let n = u32::from_le_bytes(*len) as usize;
            if n > tail.len() {
                return Err(format!(
                    "a header field declares {n} bytes, more than the {} left in its header",
                    tail.len()
                ));
            }
            let (field, tail) = tail.split_at(n);
            let Some(eq) = field.iter().position(|&b| b == b'=') else {
                return Err("a header field has no `=`".into());
            };
            fields.push((&field[..eq], &field[eq + 1..]));
            rest = tail;
        }
        Ok(Fields { fields })
    }

    fn get(&self, name: &str) -> Result<&'a [u8], String> {
        self.fields
            .iter()
            .find(|(n, _)| *n == name.as_bytes())
            .map(|(_, v)| *v)
            .ok_or_else(|| format!("no `{name}` field"))
    }

    fn fixed<const N: usize>(&self, name: &str) -> Result<[u8; N], String> {
        let v = self.get(name)?;
        v.try_into()
            .map_err(|_| format!("field `{name}` has {} bytes, not {N}", v.len()))
    }

    fn op(&self) -> Result<u8, String> {
        Ok(self.fixed::<1>("op")?[0])
    }

    fn u32(&self, name: &str) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.fixed(name)?))
    }

    fn u64(&self, name: &str) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.fixed(name)?))
    }

    /// A `time` field (seconds and nanoseconds, two `u32`) in ns.
    fn time(&self, name: &str) -> Result<u64, String> {
        let b: [u8; 8] = self.fixed(name)?;
        let sec = u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
        let nsec = u64::from(u32::from_le_bytes([b[4], b[5], b[6], b[7]]));
        Ok(sec * 1_000_000_000 + nsec)
    }

    fn string(&self, name: &str) -> Result<String, String> {
        Ok(String::from_utf8_lossy(self.get(name)?).into_owned())
    }
}

/// A connection record's header and data as the channel they define: `(id, channel)`.
fn connection(header: &Fields<'_>, data: &[u8]) -> Result<(u32, ChannelMeta), String> {
    let id = header.u32("conn")?;
    let info = Fields::parse(data).map_err(|e| format!("connection {id}: {e}"))?;
    let field = |name: &str| {
        info.string(name)
            .map_err(|e| format!("connection {id}: {e}"))
    };
    let topic = match info.get("topic") {
        Ok(_) => field("topic")?,
        Err(_) => header.string("topic")?,
    };
    let ros1_type = field("type")?;
    Ok((
        id,
        ChannelMeta {
            topic,
            type_name: ros2_type_name(&ros1_type),
            message_encoding: "ros1".into(),
            schema_encoding: "ros1msg".into(),
            schema: info.get("message_definition").unwrap_or_default().to_vec(),
            md5sum: field("md5sum")?,
        },
    ))
}

/// One record read from the file: its offset, header bytes, and data (`None` when skipped).
struct Record {
    at: u64,
    header: Vec<u8>,
    data: Option<Vec<u8>>,
}

/// Reads top-level records from `at` up to `end`, each bounded by the file and by `limit`.
struct Records {
    file: BufReader<File>,
    at: u64,
    end: u64,
    limit: usize,
}

impl Records {
    fn new(path: &Path, at: u64, end: u64, limit: usize) -> std::io::Result<Self> {
        let mut file = BufReader::with_capacity(1 << 16, File::open(path)?);
        file.seek(SeekFrom::Start(at))?;
        Ok(Records {
            file,
            at,
            end,
            limit,
        })
    }

    /// A length field at `self.at` that must fit before `self.end` and within the limit.
    fn length(&mut self, what: &str, record: u64) -> Result<usize, String> {
        let mut word = [0u8; 4];
        if self.end.saturating_sub(self.at) < 4 || self.file.read_exact(&mut word).is_err() {
            return Err(format!(
                "record at byte {record} is cut off: the file ends in its {what} length"
            ));
        }
        self.at += 4;
        let n = u64::from(u32::from_le_bytes(word));
        if n > self.end - self.at {
            return Err(format!(
                "record at byte {record} declares a {what} of {n} bytes, past the end of the \
                 file (byte {})",
                self.end
            ));
        }
        if n > self.limit as u64 {
            return Err(oversize(record, n, self.limit));
        }
        Ok(n as usize)
    }

    /// The next record; `wanted(op, at)` says whether its data is read or skipped. `None` at the end.
    fn next(&mut self, wanted: impl Fn(u8, u64) -> bool) -> Option<Result<Record, String>> {
        if self.at >= self.end {
            return None;
        }
        Some(self.read(wanted))
    }

    fn read(&mut self, wanted: impl Fn(u8, u64) -> bool) -> Result<Record, String> {
        let at = self.at;
        let n = self.length("header", at)?;
        let mut header = vec![0u8; n];
        self.file
            .read_exact(&mut header)
            .map_err(|e| format!("record at byte {at}: {e}"))?;
        self.at += n as u64;
        let op = Fields::parse(&header)
            .and_then(|f| f.op())
            .map_err(|e| format!("record at byte {at}: {e}"))?;
        let n = self.length("data", at)?;
        let data = if wanted(op, at) {
            let mut data = vec![0u8; n];
            self.file
                .read_exact(&mut data)
                .map_err(|e| format!("record at byte {at}: {e}"))?;
            Some(data)
        } else {
            self.file
                .seek_relative(n as i64)
                .map_err(|e| format!("record at byte {at}: {e}"))?;
            None
        };
        self.at += n as u64;
        Ok(Record { at, header, data })
    }
}

/// Why a record at byte `at` that declares `declared` bytes is refused.
fn oversize(at: u64, declared: u64, limit: usize) -> String {
    format!(
        "record at byte {at} declares {declared} bytes, more than the {:.0} MiB the reader takes \
         from one file (a damaged or crafted file)",
        limit as f64 / f64::from(1 << 20)
    )
}

/// The records of a chunk's data, decompressed: `(compression, declared size)` from its header.
fn decompress(
    at: u64,
    header: &Fields<'_>,
    data: Vec<u8>,
    limit: usize,
) -> Result<Vec<u8>, String> {
    let fault = |e: String| format!("chunk at byte {at}: {e}");
    let compression = header.string("compression").map_err(fault)?;
    let size = u64::from(header.u32("size").map_err(fault)?);
    if size > limit as u64 {
        return Err(format!(
            "chunk at byte {at} declares {size} bytes uncompressed, more than the {:.0} MiB the \
             reader takes from one file (a damaged or crafted file)",
            limit as f64 / f64::from(1 << 20)
        ));
    }
    let mut out = Vec::new();
    let read = match compression.as_str() {
        "none" => {
            out = data;
            Ok(out.len())
        }
        "bz2" => {
            out.reserve_exact(first_reservation(size, data.len()));
            bzip2::read::BzDecoder::new(data.as_slice())
                .take(size + 1)
                .read_to_end(&mut out)
        }
        "lz4" => {
            out.reserve_exact(first_reservation(size, data.len()));
            lz4::Decoder::new(data.as_slice()).and_then(|d| d.take(size + 1).read_to_end(&mut out))
        }
        other => {
            return Err(fault(format!(
                "compression {other:?} is not read (only none, bz2 and lz4)"
            )));
        }
    };
    if let Err(e) = read {
        return Err(fault(format!(
            "{compression} data does not decompress: {e}"
        )));
    }
    if out.len() as u64 != size {
        let got = if out.len() as u64 > size {
            "more".to_string()
        } else {
            out.len().to_string()
        };
        return Err(fault(format!(
            "declares {size} bytes uncompressed, its {compression} data holds {got}"
        )));
    }
    Ok(out)
}

/// Bytes reserved for a chunk of `size` declared bytes whose compressed data is `compressed` bytes:
/// the declared size, unless it is far more than the data can hold (then the buffer grows as the data
/// decompresses, up to the declared size).
fn first_reservation(size: u64, compressed: usize) -> usize {
    usize::try_from(size)
        .unwrap_or(usize::MAX)
        .min(compressed.saturating_mul(16))
}

/// A record inside a chunk's decompressed bytes, from `at`: `(op, header, data, next)`.
fn inner_record(bytes: &[u8], at: usize) -> Result<(Fields<'_>, &[u8], usize), String> {
    let take = |from: usize, what: &str| -> Result<(&[u8], usize), String> {
        let len = bytes
            .get(from..from + 4)
            .ok_or_else(|| format!("its {what} length is cut off"))?;
        let n = u32::from_le_bytes([len[0], len[1], len[2], len[3]]) as usize;
        let start = from + 4;
        let body = start
            .checked_add(n)
            .and_then(|end| bytes.get(start..end))
            .ok_or_else(|| {
                format!(
                    "its {what} declares {n} bytes, past the chunk's end ({} bytes)",
                    bytes.len()
                )
            })?;
        Ok((body, start + n))
    };
    let (header, next) = take(at, "header")?;
    let (data, next) = take(next, "data")?;
    Ok((Fields::parse(header)?, data, next))
}

/// What the bag header record says.
struct BagHeader {
    /// The byte after it: the first chunk.
    start: u64,
    /// Where the index section starts (0 while a recording is open).
    index_pos: u64,
    /// Connections and chunks the index lists.
    conn_count: u32,
    chunk_count: u32,
}

/// Reads the bag header record.
fn bag_header(path: &Path, len: u64) -> Result<BagHeader, BagError> {
    let damaged = |reason: String| BagError::Ros1Damaged {
        path: path.to_path_buf(),
        reason,
    };
    let at = MAGIC.len() as u64;
    let mut records =
        Records::new(path, at, len, MAX_RECORD_BYTES).map_err(|source| BagError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    let record = records
        .next(|_, _| false)
        .ok_or_else(|| damaged("the file ends after its magic: no bag header".into()))?
        .map_err(&damaged)?;
    let fields = Fields::parse(&record.header).map_err(&damaged)?;
    if fields.op() != Ok(OP_BAG_HEADER) {
        return Err(damaged(format!(
            "the record at byte {at} is not a bag header (op {:?})",
            fields.op().ok()
        )));
    }
    let field = |e: String| damaged(format!("bag header: {e}"));
    Ok(BagHeader {
        start: records.at,
        index_pos: fields.u64("index_pos").map_err(field)?,
        conn_count: fields.u32("conn_count").map_err(field)?,
        chunk_count: fields.u32("chunk_count").map_err(field)?,
    })
}

/// Opens a ROS 1 bag: checks its magic, reads its bag header, then its index section, or scans its
/// chunks when the index is missing or damaged.
pub(crate) fn open(path: &Path) -> Result<Opened, BagError> {
    let io = |source| BagError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    let mut magic = Vec::with_capacity(MAGIC.len());
    (&mut file)
        .take(MAGIC.len() as u64)
        .read_to_end(&mut magic)
        .map_err(io)?;
    if magic != MAGIC {
        let version = String::from_utf8_lossy(&magic[MAGIC_PREFIX.len().min(magic.len())..])
            .trim_end()
            .to_string();
        return Err(BagError::Ros1Version {
            path: path.to_path_buf(),
            version,
        });
    }
    let header = bag_header(path, len)?;
    let (start, index_pos) = (header.start, header.index_pos);
    if index_pos >= start && index_pos < len {
        match read_index(path, &header, len) {
            Ok(opened) => return Ok(opened),
            Err(e) => log::warn!(
                "{}: no usable ROS 1 bag index ({e}); reading the file from start to end",
                path.display()
            ),
        }
    } else {
        log::warn!(
            "{}: the bag header's index position {index_pos} is not in the file (a recording that \
             did not close, or a truncated copy); reading the file from start to end",
            path.display()
        );
    }
    scan(path, start, len)
}

/// Connections, counts and time range from the index section (connections, then chunk infos).
fn read_index(path: &Path, bag: &BagHeader, len: u64) -> Result<Opened, String> {
    let (start, index_pos) = (bag.start, bag.index_pos);
    let mut records =
        Records::new(path, index_pos, len, MAX_RECORD_BYTES).map_err(|e| e.to_string())?;
    let mut connections = BTreeMap::new();
    let mut counts: BTreeMap<u32, u64> = BTreeMap::new();
    let mut chunks: BTreeMap<u64, BTreeSet<u32>> = BTreeMap::new();
    let mut time_range: Option<(u64, u64)> = None;
    while let Some(record) = records.next(|_, _| true) {
        let record = record?;
        let header = Fields::parse(&record.header)?;
        let data = record.data.unwrap_or_default();
        match header.op()? {
            OP_CONNECTION => {
                let (id, meta) = connection(&header, &data)?;
                connections.insert(id, Arc::new(meta));
            }
            OP_CHUNK_INFO => {
                let fault = |e: String| format!("chunk info at byte {}: {e}", record.at);
                let chunk_pos = header.u64("chunk_pos").map_err(fault)?;
                if chunk_pos >= index_pos {
                    return Err(fault(format!(
                        "its chunk position {chunk_pos} is past the chunk section"
                    )));
                }
                let n = header.u32("count").map_err(fault)? as usize;
                if n.checked_mul(8) != Some(data.len()) {
                    return Err(fault(format!(
                        "{n} connections do not fill its {} bytes",
                        data.len()
                    )));
                }
                let (first, last) = (
                    header.time("start_time").map_err(fault)?,
                    header.time("end_time").map_err(fault)?,
                );
                let here = chunks.entry(chunk_pos).or_default();
                let mut total = 0u64;
                for entry in data.chunks_exact(8) {
                    let id = u32::from_le_bytes([entry[0], entry[1], entry[2], entry[3]]);
                    let count = u32::from_le_bytes([entry[4], entry[5], entry[6], entry[7]]);
                    *counts.entry(id).or_default() += u64::from(count);
                    total += u64::from(count);
                    here.insert(id);
                }
                if total > 0 {
                    time_range = Some(match time_range {
                        None => (first, last),
                        Some((a, b)) => (a.min(first), b.max(last)),
                    });
                }
            }
            op => {
                return Err(format!(
                    "record at byte {} (op {op:#04x}) does not belong in the index section",
                    record.at
                ));
            }
        }
    }
    let (conns, infos) = (connections.len(), chunks.len());
    if (conns, infos) != (bag.conn_count as usize, bag.chunk_count as usize) {
        return Err(format!(
            "it lists {conns} connections and {infos} chunks, the bag header {} and {}",
            bag.conn_count, bag.chunk_count
        ));
    }
    if let Some(id) = counts.keys().find(|id| !connections.contains_key(id)) {
        return Err(format!(
            "chunk infos count messages of connection {id}, which it does not define"
        ));
    }
    let channels = connections
        .iter()
        .map(|(id, meta)| (*id, (meta.clone(), counts.get(id).copied().unwrap_or(0))))
        .collect();
    Ok((
        Layout {
            start,
            end: index_pos,
            connections,
            chunks: Some(chunks),
        },
        channels,
        time_range,
    ))
}

/// Connections, counts and time range from every chunk from `start` to the end of the file or to the
/// first damage.
fn scan(path: &Path, start: u64, len: u64) -> Result<Opened, BagError> {
    let layout = Layout {
        start,
        end: len,
        connections: BTreeMap::new(),
        chunks: None,
    };
    let mut source = Source::open(path, Arc::new(layout), None, MAX_RECORD_BYTES)?;
    let mut counts: BTreeMap<u32, u64> = BTreeMap::new();
    let mut time_range: Option<(u64, u64)> = None;
    while let Some(item) = source.next_raw() {
        match item {
            Ok((id, t)) => {
                *counts.entry(id).or_default() += 1;
                time_range = Some(match time_range {
                    None => (t, t),
                    Some((a, b)) => (a.min(t), b.max(t)),
                });
            }
            Err(e) => {
                log::warn!("{e}; the messages before the damage are read");
                break;
            }
        }
    }
    let channels = source
        .connections
        .iter()
        .map(|(id, meta)| (*id, (meta.clone(), counts.get(id).copied().unwrap_or(0))))
        .collect();
    let layout = Layout {
        start,
        end: len,
        connections: source.connections.clone(),
        chunks: None,
    };
    Ok((layout, channels, time_range))
}

/// A record inside a chunk.
enum Inner {
    /// A connection: its id and channel.
    Connection(u32, ChannelMeta),
    /// A message: its connection and time (ns).
    Message(u32, u64),
}

/// The messages of a ROS 1 bag in file order.
pub(crate) struct Source {
    path: PathBuf,
    records: Records,
    layout: Arc<Layout>,
    /// Connections known so far (the layout's, and those met in chunks).
    connections: BTreeMap<u32, Arc<ChannelMeta>>,
    /// The topics read, or all.
    topics: Option<Vec<String>>,
    /// The chunk being read (decompressed) and where its next record starts.
    chunk: Vec<u8>,
    chunk_at: u64,
    next: usize,
    /// The last message read by [`Self::next_raw`]: connection, time and bytes.
    last: Option<(u32, u64, Vec<u8>)>,
    /// Set once a fault ended the file.
    failed: bool,
}

impl Source {
    /// Opens `path` for reading the messages of `topics` (or all), chunks and records of more than
    /// `limit` bytes refused.
    pub(crate) fn open(
        path: &Path,
        layout: Arc<Layout>,
        topics: Option<&[&str]>,
        limit: usize,
    ) -> Result<Self, BagError> {
        let records =
            Records::new(path, layout.start, layout.end, limit).map_err(|source| BagError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        Ok(Source {
            path: path.to_path_buf(),
            records,
            connections: layout.connections.clone(),
            layout,
            topics: topics.map(|t| t.iter().map(|s| s.to_string()).collect()),
            chunk: Vec::new(),
            chunk_at: 0,
            next: 0,
            last: None,
            failed: false,
        })
    }

    fn selected(&self, id: u32) -> bool {
        match (&self.topics, self.connections.get(&id)) {
            (None, _) => true,
            (Some(topics), Some(c)) => topics.contains(&c.topic),
            (Some(_), None) => false,
        }
    }

    fn damaged(&mut self, reason: String) -> BagError {
        self.failed = true;
        BagError::Ros1Damaged {
            path: self.path.clone(),
            reason,
        }
    }

    /// Advances to the next message (kept in `self.last`); returns its connection and time.
    pub(crate) fn next_raw(&mut self) -> Option<Result<(u32, u64), BagError>> {
        if self.failed {
            return None;
        }
        loop {
            if self.next < self.chunk.len() {
                let at = self.next;
                let parsed = inner_record(&self.chunk, at).and_then(|(header, data, next)| {
                    let inner = match header.op()? {
                        OP_CONNECTION => {
                            let (id, meta) = connection(&header, data)?;
                            Inner::Connection(id, meta)
                        }
                        OP_MESSAGE_DATA => {
                            Inner::Message(header.u32("conn")?, header.time("time")?)
                        }
                        op => {
                            return Err(format!(
                                "a record of op {op:#04x} does not belong in a chunk"
                            ));
                        }
                    };
                    Ok((inner, data.len(), next))
                });
                let (inner, len, next) = match parsed {
                    Ok(p) => p,
                    Err(e) => {
                        let why = format!(
                            "chunk at byte {}: record at offset {at}: {e}",
                            self.chunk_at
                        );
                        return Some(Err(self.damaged(why)));
                    }
                };
                self.next = next;
                match inner {
                    Inner::Connection(id, meta) => {
                        self.connections.insert(id, Arc::new(meta));
                    }
                    Inner::Message(id, t) => {
                        if !self.connections.contains_key(&id) {
                            let why = format!(
                                "chunk at byte {}: a message on connection {id}, which no \
                                 connection record defines",
                                self.chunk_at
                            );
                            return Some(Err(self.damaged(why)));
                        }
                        if self.selected(id) {
                            let data = self.chunk[next - len..next].to_vec();
                            self.last = Some((id, t, data));
                            return Some(Ok((id, t)));
                        }
                    }
                }
                continue;
            }
            self.chunk = Vec::new();
            self.next = 0;
            let record = {
                let layout = &self.layout;
                let topics = &self.topics;
                let connections = &self.connections;
                self.records.next(|op, at| match op {
                    OP_CHUNK => {
                        let Some(chunks) = &layout.chunks else {
                            return true;
                        };
                        let Some(topics) = topics else { return true };
                        chunks.get(&at).is_none_or(|ids| {
                            ids.iter().any(|id| {
                                connections
                                    .get(id)
                                    .is_none_or(|c| topics.contains(&c.topic))
                            })
                        })
                    }
                    OP_CONNECTION | OP_MESSAGE_DATA => true,
                    _ => false,
                })
            };
            let record = match record? {
                Ok(r) => r,
                Err(e) => return Some(Err(self.damaged(e))),
            };
            let header = match Fields::parse(&record.header) {
                Ok(h) => h,
                Err(e) => {
                    return Some(Err(
                        self.damaged(format!("record at byte {}: {e}", record.at))
                    ));
                }
            };
            let op = header.op().unwrap_or_default();
            let Some(data) = record.data else {
                // A chunk without the topics read, or an index record: skipped.
                if !matches!(op, OP_CHUNK | OP_INDEX_DATA | OP_CHUNK_INFO) {
                    let why = format!(
                        "record at byte {} (op {op:#04x}) does not belong in a bag",
                        record.at
                    );
                    return Some(Err(self.damaged(why)));
                }
                continue;
            };
            match op {
                OP_CHUNK => match decompress(record.at, &header, data, self.records.limit) {
                    Ok(chunk) => {
                        self.chunk = chunk;
                        self.chunk_at = record.at;
                    }
                    Err(e) => return Some(Err(self.damaged(e))),
                },
                // Connections and messages outside chunks (the index section's connections, or a
                // writer that does not chunk): read as a chunk of one record.
                _ => {
                    let mut one = Vec::with_capacity(8 + record.header.len() + data.len());
                    one.extend((record.header.len() as u32).to_le_bytes());
                    one.extend(&record.header);
                    one.extend((data.len() as u32).to_le_bytes());
                    one.extend(&data);
                    self.chunk = one;
                    self.chunk_at = record.at;
                }
            }
        }
    }

    /// The next message of the topics read.
    pub(crate) fn next(&mut self) -> Option<Result<BagMessage, BagError>> {
        if let Err(e) = self.next_raw()? {
            return Some(Err(e));
        }
        let (id, t, data) = self.last.take()?;
        let channel = self.connections.get(&id)?;
        Some(Ok(BagMessage::ros1(channel, t, data)))
    }
}
