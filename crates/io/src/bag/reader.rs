//! [`BagReader`]: reads a rosbag2 MCAP bag directory, a single MCAP file, or a ROS 1 bag ([`super::ros1`]),
//! streaming.
//!
//! A file with a summary section (every finished rosbag2 or rosbags file) is read through its chunk
//! indexes, one chunk at a time, in log-time order even when chunks overlap; one without a usable
//! summary (a crashed recording, a truncated copy, `fastwrite` without chunks) from start to end, in
//! file order, after one scan in [`BagReader::open`] lists its topics. A bag's files are read in time
//! order, those whose time ranges overlap together, their messages merged by log time.
//!
//! Memory: one decompressed chunk per open file, never a whole file. A chunk or record that declares
//! more than 64 MiB (compressed or not) is refused as damage, whatever the file claims; files open
//! together share 256 MiB (of n files, each at most 256 MiB / n, 64 MiB at most). Not tied to ROS 2:
//! every channel is listed with its message and schema encoding and [`BagMessage::data`] gives any
//! payload (foxglove protobuf or JSON too); only [`BagMessage::decode`] needs CDR.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use mcap::sans_io::indexed_reader::{
    IndexedReadEvent, IndexedReader, IndexedReaderOptions, ReadOrder,
};
use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
use serde::de::DeserializeOwned;

use super::metadata::read_metadata_yaml;
use super::{BagError, cdr, ros1};
use dc_loc_core::math::Stamp;

/// Largest record or chunk (compressed or not) the reader accepts, bytes: the bound of what one file
/// holds decompressed, whatever a corrupt length field asks for. Real chunks are around 1 MiB; a
/// single radar cloud is well under 1 MiB.
pub const MAX_RECORD_BYTES: usize = 64 << 20;
/// Most bytes that the files read together (a group of overlapping files) may hold decompressed:
/// each of n files takes chunks of at most this / n bytes (and [`MAX_RECORD_BYTES`]).
pub const MAX_GROUP_BYTES: usize = 256 << 20;
/// Largest single read into the linear reader, bytes.
const READ_SIZE: usize = 1 << 20;

mod guard;
mod linear;
use linear::LinearSource;

/// Why a chunk at byte `at` of `declared` bytes is refused.
fn oversize(at: u64, declared: u64, limit: usize) -> String {
    format!(
        "chunk at byte {at} declares {declared} bytes, more than the {:.0} MiB the reader takes \
         from one file (a damaged or crafted file)",
        limit as f64 / f64::from(1 << 20)
    )
}

/// One topic (channel) of a bag, summed over its files.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicInfo {
    /// Topic name.
    pub name: String,
    /// Message type: the schema name (`sensor_msgs/msg/PointCloud2`, `foxglove.PointCloud`); empty
    /// for a channel without schema.
    pub type_name: String,
    /// Message encoding (`cdr` for ROS 2; `protobuf`, `json`, ... from other writers).
    pub message_encoding: String,
    /// Schema encoding (`ros2msg`, `ros2idl`, `protobuf`, `jsonschema`, or empty).
    pub schema_encoding: String,
    /// Schema data (the `ros2msg` text, a protobuf `FileDescriptorSet`, ...).
    pub schema: Vec<u8>,
    /// Number of messages.
    pub message_count: u64,
    /// ROS 1 bags: the connection's md5sum of the message definition; empty for MCAP channels.
    pub md5sum: String,
}

/// What a message's channel (an MCAP channel, a ROS 1 connection) says about it.
#[derive(Debug)]
pub(crate) struct ChannelMeta {
    pub(crate) topic: String,
    pub(crate) type_name: String,
    pub(crate) message_encoding: String,
    pub(crate) schema_encoding: String,
    pub(crate) schema: Vec<u8>,
    /// A ROS 1 connection's md5sum; empty for MCAP.
    pub(crate) md5sum: String,
}

/// One message read from a bag.
#[derive(Debug, Clone)]
pub struct BagMessage {
    channel: Arc<ChannelMeta>,
    /// Log time (for rosbag2: receive time; for the dc_loc writer: the message stamp).
    pub log_time: Stamp,
    /// Publish time.
    pub publish_time: Stamp,
    /// Channel sequence number (0 when the writer did not count).
    pub sequence: u32,
    data: Vec<u8>,
}

impl BagMessage {
    /// A ROS 1 message on `channel` recorded at `time` (ns).
    pub(crate) fn ros1(channel: &Arc<ChannelMeta>, time: u64, data: Vec<u8>) -> Self {
        BagMessage {
            channel: channel.clone(),
            log_time: stamp(time),
            publish_time: stamp(time),
            sequence: 0,
            data,
        }
    }

    /// The message of `header` with payload `data` on `channel`.
    fn read(
        channel: &Arc<ChannelMeta>,
        header: &mcap::records::MessageHeader,
        data: Vec<u8>,
    ) -> Self {
        BagMessage {
            channel: channel.clone(),
            log_time: stamp(header.log_time),
            publish_time: stamp(header.publish_time),
            sequence: header.sequence,
            data,
        }
    }

    /// Topic name.
    pub fn topic(&self) -> &str {
        &self.channel.topic
    }
    /// Message type (schema name).
    pub fn type_name(&self) -> &str {
        &self.channel.type_name
    }
    /// Message encoding of the channel (`cdr` for ROS 2, `ros1` for a ROS 1 bag).
    pub fn message_encoding(&self) -> &str {
        &self.channel.message_encoding
    }
    /// The serialised message: CDR with its encapsulation header for ROS 2 channels, the ROS 1
    /// serialisation for a ROS 1 bag.
    pub fn data(&self) -> &[u8] {
        &self.data
    }
    /// Decodes the payload (CDR, or ROS 1 after the connection's md5sum is checked against the
    /// definition the struct mirrors) as `T` (the Rust struct of [`Self::type_name`]).
    ///
    /// A failure names topic, type and time and concerns this message only: the caller skips it and
    /// goes on iterating.
    pub fn decode<T: DeserializeOwned>(&self) -> Result<T, BagError> {
        if self.channel.message_encoding == "ros1" {
            if let Some(fault) =
                ros1::definition_fault(&self.channel.type_name, &self.channel.md5sum)
            {
                return Err(BagError::Ros1Definition {
                    topic: self.channel.topic.clone(),
                    fault,
                });
            }
            return ros1::de::decode(&self.data).map_err(|source| BagError::DecodeRos1 {
                topic: self.channel.topic.clone(),
                type_name: ros1::ros1_type_name(&self.channel.type_name),
                stamp: self.log_time,
                source,
            });
        }
        if self.channel.message_encoding != "cdr" {
            return Err(BagError::UnsupportedEncoding {
                topic: self.channel.topic.clone(),
                type_name: self.channel.type_name.clone(),
                encoding: self.channel.message_encoding.clone(),
            });
        }
        cdr::decode(&self.data).map_err(|source| BagError::Decode {
            topic: self.channel.topic.clone(),
            type_name: self.channel.type_name.clone(),
            stamp: self.log_time,
            source,
        })
    }
}

/// A file of the bag (MCAP, or a ROS 1 bag), as opened.
#[derive(Debug)]
struct BagFile {
    path: PathBuf,
    /// The summary when the file is read through its indexes.
    summary: Option<mcap::Summary>,
    /// What a ROS 1 bag's header and index say (`None`: an MCAP file).
    ros1: Option<Arc<ros1::Layout>>,
    /// Channels (MCAP channel or ROS 1 connection ids) and their message counts (from the summary,
    /// the index or the scan).
    channels: BTreeMap<u32, (Arc<ChannelMeta>, u64)>,
    /// Earliest and latest log time, ns.
    time_range: Option<(u64, u64)>,
}

/// Reads a rosbag2 bag (directory or single `.mcap` file); see the module documentation.
#[derive(Debug)]
pub struct BagReader {
    path: PathBuf,
    files: Vec<Arc<BagFile>>,
    topics: Vec<TopicInfo>,
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> BagError + '_ {
    move |source| BagError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn mcap_err(path: &Path) -> impl FnOnce(mcap::McapError) -> BagError + '_ {
    move |source| BagError::Mcap {
        path: path.to_path_buf(),
        source,
    }
}

/// Log time as a [`Stamp`]; times past the year 2262 (beyond i64 ns) saturate.
fn stamp(t: u64) -> Stamp {
    Stamp(i64::try_from(t).unwrap_or(i64::MAX))
}

fn channel_meta(channel: &mcap::Channel<'_>) -> ChannelMeta {
    let (type_name, schema_encoding, schema) = match &channel.schema {
        Some(s) => (s.name.clone(), s.encoding.clone(), s.data.to_vec()),
        None => (String::new(), String::new(), Vec::new()),
    };
    ChannelMeta {
        topic: channel.topic.clone(),
        type_name,
        message_encoding: channel.message_encoding.clone(),
        schema_encoding,
        schema,
        md5sum: String::new(),
    }
}

/// The `.mcap` files of a bag directory: those its `metadata.yaml` lists, else all `*.mcap` files in
/// split order (`name_0`, `name_1`, ..., `name_10`).
fn bag_files(dir: &Path) -> Result<Vec<PathBuf>, BagError> {
    let yaml = dir.join("metadata.yaml");
    if yaml.exists() {
        let info = read_metadata_yaml(&yaml)?;
        let files: Vec<PathBuf> = info
            .relative_file_paths
            .iter()
            // rosbag2 wrote paths relative to the working directory before version 4: keep the name.
            .filter_map(|p| Path::new(p).file_name().map(|n| dir.join(n)))
            .collect();
        if let Some(missing) = files.iter().find(|p| !p.is_file()) {
            return Err(BagError::NotFound {
                path: missing.clone(),
            });
        }
        if files.is_empty() {
            return Err(BagError::NoMcapFiles {
                path: dir.to_path_buf(),
            });
        }
        return Ok(files);
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(io_err(dir))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == "mcap"))
        .collect();
    // Split order: by the number after the last '_', then by name.
    let split_index = |p: &PathBuf| -> (u64, String) {
        let stem = p.file_stem().and_then(|s| s.to_str()).unwrap_or_default();
        let n = stem
            .rsplit_once('_')
            .and_then(|(_, n)| n.parse().ok())
            .unwrap_or(0);
        (n, stem.to_string())
    };
    files.sort_by_key(split_index);
    if files.is_empty() {
        return Err(BagError::NoMcapFiles {
            path: dir.to_path_buf(),
        });
    }
    Ok(files)
}

/// Reads the summary section, or `None` when the file has none or it cannot be read.
fn read_summary(file: &mut File, len: u64, path: &Path) -> Option<mcap::Summary> {
    if let Some(fault) = guard::summary_fault(file, len, MAX_GROUP_BYTES) {
        log::warn!(
            "{}: no usable MCAP summary ({fault}); reading the file from start to end",
            path.display()
        );
        return None;
    }
    let options = SummaryReaderOptions::default()
        .with_file_size(len)
        .with_record_length_limit(MAX_RECORD_BYTES);
    let mut reader = SummaryReader::new_with_options(options);
    let result: Result<(), String> = (|| {
        while let Some(event) = reader.next_event() {
            match event.map_err(|e| e.to_string())? {
                SummaryReadEvent::ReadRequest(n) => {
                    let got = file.read(reader.insert(n)).map_err(|e| e.to_string())?;
                    reader.notify_read(got);
                }
                SummaryReadEvent::SeekRequest(to) => {
                    let pos = file.seek(to).map_err(|e| e.to_string())?;
                    reader.notify_seeked(pos);
                }
            }
        }
        Ok(())
    })();
    match result {
        Ok(()) => reader.finish(),
        Err(e) => {
            log::warn!(
                "{}: no usable MCAP summary ({e}); reading the file from start to end",
                path.display()
            );
            None
        }
    }
}

impl BagFile {
    fn open(path: &Path) -> Result<BagFile, BagError> {
        let mut file = File::open(path).map_err(io_err(path))?;
        let len = file.metadata().map_err(io_err(path))?.len();
        let mut magic = [0u8; 9];
        let got = file.read(&mut magic).map_err(io_err(path))?;
        if magic[..got].starts_with(ros1::MAGIC_PREFIX) {
            let (layout, channels, time_range) = ros1::open(path)?;
            return Ok(BagFile {
                path: path.to_path_buf(),
                summary: None,
                ros1: Some(Arc::new(layout)),
                channels,
                time_range,
            });
        }
        if got < 8 || magic[..8] != *mcap::MAGIC {
            return Err(BagError::NotMcap {
                path: path.to_path_buf(),
            });
        }
        let summary = read_summary(&mut file, len, path);
        if let Some(summary) = summary {
            // Indexed reading needs chunk indexes and statistics (for the counts); an unchunked file
            // with a summary is read linearly below.
            if let Some(stats) = &summary.stats
                && (!summary.chunk_indexes.is_empty() || stats.message_count == 0)
            {
                let mut ids: Vec<u16> = summary.channels.keys().copied().collect();
                ids.sort_unstable();
                let channels = ids
                    .into_iter()
                    .filter_map(|id| {
                        let c = summary.channels.get(&id)?;
                        let count = stats.channel_message_counts.get(&id).copied().unwrap_or(0);
                        Some((u32::from(id), (Arc::new(channel_meta(c)), count)))
                    })
                    .collect();
                let time_range = (stats.message_count > 0)
                    .then_some((stats.message_start_time, stats.message_end_time));
                return Ok(BagFile {
                    path: path.to_path_buf(),
                    summary: Some(summary),
                    ros1: None,
                    channels,
                    time_range,
                });
            }
        }
        // No summary: scan the file once for its channels and counts, up to any damage.
        let mut source = LinearSource::open(path, None, MAX_RECORD_BYTES)?;
        let mut counts: BTreeMap<u16, u64> = BTreeMap::new();
        let mut time_range: Option<(u64, u64)> = None;
        while let Some(item) = source.next_raw() {
            match item {
                Ok((channel_id, header_time)) => {
                    *counts.entry(channel_id).or_default() += 1;
                    time_range = Some(match time_range {
                        None => (header_time, header_time),
                        Some((a, b)) => (a.min(header_time), b.max(header_time)),
                    });
                }
                Err(e) => {
                    log::warn!("{e}; the messages before the damage are read");
                    break;
                }
            }
        }
        let channels = source
            .channels
            .iter()
            .map(|(id, meta)| {
                let count = counts.get(id).copied().unwrap_or(0);
                (u32::from(*id), (meta.clone(), count))
            })
            .collect();
        Ok(BagFile {
            path: path.to_path_buf(),
            summary: None,
            ros1: None,
            channels,
            time_range,
        })
    }

    /// Opens the file for reading, refusing chunks and records of more than `limit` bytes.
    fn source(&self, topics: Option<&[&str]>, limit: usize) -> Result<Source, BagError> {
        if let Some(layout) = &self.ros1 {
            return Ok(Source::Ros1(Box::new(ros1::Source::open(
                &self.path,
                layout.clone(),
                topics,
                limit,
            )?)));
        }
        match &self.summary {
            Some(summary) => Ok(Source::Indexed(Box::new(IndexedSource::open(
                &self.path,
                summary,
                &self.channels,
                topics,
                limit,
            )?))),
            None => Ok(Source::Linear(Box::new(LinearSource::open(
                &self.path, topics, limit,
            )?))),
        }
    }
}

/// Messages of one file in log-time order through its chunk indexes.
struct IndexedSource {
    path: PathBuf,
    file: File,
    len: u64,
    reader: IndexedReader,
    channels: HashMap<u16, Arc<ChannelMeta>>,
    buf: Vec<u8>,
    /// Whether `channels` is a topic selection (then other channels are skipped, not errors).
    selective: bool,
}

impl IndexedSource {
    fn open(
        path: &Path,
        summary: &mcap::Summary,
        channels: &BTreeMap<u32, (Arc<ChannelMeta>, u64)>,
        topics: Option<&[&str]>,
        limit: usize,
    ) -> Result<Self, BagError> {
        // The mcap reader refuses these too, naming only the compressed size.
        let declared = |c: &mcap::records::ChunkIndex| c.compressed_size.max(c.uncompressed_size);
        if let Some(c) = summary
            .chunk_indexes
            .iter()
            .find(|c| declared(c) > limit as u64)
        {
            return Err(BagError::Damaged {
                path: path.to_path_buf(),
                reason: oversize(c.chunk_start_offset, declared(c), limit),
            });
        }
        let together = guard::overlapping_bytes(&summary.chunk_indexes);
        if together > limit as u64 {
            return Err(BagError::Damaged {
                path: path.to_path_buf(),
                reason: format!(
                    "chunks overlapping in time declare {together} bytes together, more than the \
                     {:.0} MiB the reader holds of one file (a damaged or crafted file)",
                    limit as f64 / f64::from(1 << 20)
                ),
            });
        }
        let file = File::open(path).map_err(io_err(path))?;
        let len = file.metadata().map_err(io_err(path))?.len();
        let mut options = IndexedReaderOptions::new()
            .with_order(ReadOrder::LogTime)
            .with_record_length_limit(limit);
        // Channels to yield. (An empty topic set means "all" to the mcap reader, so the selection
        // is also applied here.)
        let channels: HashMap<u16, Arc<ChannelMeta>> = channels
            .iter()
            .filter(|(_, (meta, _))| topics.is_none_or(|t| t.contains(&meta.topic.as_str())))
            .filter_map(|(id, (meta, _))| Some((u16::try_from(*id).ok()?, meta.clone())))
            .collect();
        if let Some(topics) = topics {
            options = options.include_topics(topics.iter().copied());
        }
        let reader = IndexedReader::new_with_options(summary, options).map_err(mcap_err(path))?;
        Ok(IndexedSource {
            path: path.to_path_buf(),
            file,
            len,
            reader,
            channels,
            buf: Vec::new(),
            selective: topics.is_some(),
        })
    }

    fn next(&mut self) -> Option<Result<BagMessage, BagError>> {
        enum Step {
            Load(u64, usize),
            Message(mcap::records::MessageHeader, Vec<u8>),
        }
        if self.selective && self.channels.is_empty() {
            return None;
        }
        loop {
            // The event borrows the reader: turn it into an owned step first.
            let step = match self.reader.next_event()? {
                Err(e) => return Some(Err(mcap_err(&self.path)(e))),
                Ok(IndexedReadEvent::ReadChunkRequest { offset, length }) => {
                    Step::Load(offset, length)
                }
                Ok(IndexedReadEvent::Message { header, data }) => {
                    Step::Message(header, data.to_vec())
                }
            };
            match step {
                Step::Load(offset, length) => {
                    if let Err(e) = self.load_chunk(offset, length) {
                        return Some(Err(e));
                    }
                }
                Step::Message(header, data) => {
                    let Some(channel) = self.channels.get(&header.channel_id) else {
                        if self.selective {
                            continue;
                        }
                        return Some(Err(BagError::UnknownChannel {
                            path: self.path.clone(),
                            channel_id: header.channel_id,
                        }));
                    };
                    return Some(Ok(BagMessage::read(channel, &header, data)));
                }
            }
        }
    }

    fn load_chunk(&mut self, offset: u64, length: usize) -> Result<(), BagError> {
        let end = offset.checked_add(length as u64);
        if end.is_none_or(|end| end > self.len) {
            return Err(BagError::Damaged {
                path: self.path.clone(),
                reason: format!(
                    "chunk at byte {offset} ({length} bytes) reaches past the end of the file ({} \
                     bytes)",
                    self.len
                ),
            });
        }
        self.file
            .seek(SeekFrom::Start(offset))
            .map_err(io_err(&self.path))?;
        self.buf.resize(length, 0);
        self.file
            .read_exact(&mut self.buf)
            .map_err(io_err(&self.path))?;
        self.reader
            .insert_chunk_record_data(offset, &self.buf)
            .map_err(mcap_err(&self.path))
    }
}

/// One open file's reader (boxed: they differ much in size).
enum Source {
    Indexed(Box<IndexedSource>),
    Linear(Box<LinearSource>),
    Ros1(Box<ros1::Source>),
}

impl Source {
    fn next(&mut self) -> Option<Result<BagMessage, BagError>> {
        match self {
            Source::Indexed(s) => s.next(),
            Source::Linear(s) => s.next(),
            Source::Ros1(s) => s.next(),
        }
    }
}

/// Iterator over the messages of a bag in log-time order: its files read one group after another
/// (a group: files whose time ranges overlap, merged by log time; ties: earlier file first). An `Err`
/// item reports damage in one file; that file then ends and the others go on.
pub struct Messages {
    /// The groups still to open, in time order.
    groups: std::collections::VecDeque<Vec<Arc<BagFile>>>,
    topics: Option<Vec<String>>,
    /// The open group's files (`None`: the file could not be opened; its error is its first item).
    sources: Vec<Option<Source>>,
    /// Next item of each source; `None` once the source is exhausted.
    peeked: Vec<Option<Result<BagMessage, BagError>>>,
    /// Whether each source has ended.
    done: Vec<bool>,
}

impl Messages {
    fn new(files: &[Arc<BagFile>], topics: Option<&[&str]>) -> Self {
        // Files in time order (by index among equals); those without messages come last.
        let mut order: Vec<usize> = (0..files.len()).collect();
        order.sort_by_key(|&i| (files[i].time_range.map_or(u64::MAX, |r| r.0), i));
        let mut groups: std::collections::VecDeque<Vec<Arc<BagFile>>> = Default::default();
        let mut end = 0u64;
        for i in order {
            let f = &files[i];
            let joins = f.time_range.is_some_and(|r| r.0 <= end) && !groups.is_empty();
            if !joins {
                groups.push_back(Vec::new());
                end = 0;
            }
            end = end.max(f.time_range.map_or(0, |r| r.1));
            if let Some(g) = groups.back_mut() {
                g.push(f.clone());
            }
        }
        // Within a group the files keep their bag order, which breaks ties between equal log times.
        for g in &mut groups {
            g.sort_by_key(|f| files.iter().position(|x| Arc::ptr_eq(x, f)));
        }
        Messages {
            groups,
            topics: topics.map(|t| t.iter().map(|s| s.to_string()).collect()),
            sources: Vec::new(),
            peeked: Vec::new(),
            done: Vec::new(),
        }
    }

    /// Opens the next group once every source of the current one has ended; false when none is left.
    /// The group's files share [`MAX_GROUP_BYTES`]; a file that cannot be opened reports why as its
    /// only item, and the others of the group go on.
    fn advance(&mut self) -> bool {
        if self.done.iter().any(|d| !d) {
            return true;
        }
        let Some(group) = self.groups.pop_front() else {
            return false;
        };
        let topics: Option<Vec<&str>> = self
            .topics
            .as_ref()
            .map(|t| t.iter().map(String::as_str).collect());
        let limit = MAX_RECORD_BYTES.min(MAX_GROUP_BYTES / group.len().max(1));
        self.sources.clear();
        self.peeked.clear();
        for f in &group {
            match f.source(topics.as_deref(), limit) {
                Ok(s) => {
                    self.sources.push(Some(s));
                    self.peeked.push(None);
                }
                Err(e) => {
                    self.sources.push(None);
                    self.peeked.push(Some(Err(e)));
                }
            }
        }
        self.done = vec![false; self.sources.len()];
        true
    }
}

impl Iterator for Messages {
    type Item = Result<BagMessage, BagError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if !self.advance() {
                return None;
            }
            if let Some(item) = self.next_in_group() {
                return Some(item);
            }
        }
    }
}

impl Messages {
    /// The next message of the open group, or `None` when the group has ended.
    fn next_in_group(&mut self) -> Option<Result<BagMessage, BagError>> {
        for (i, source) in self.sources.iter_mut().enumerate() {
            if self.peeked[i].is_none() && !self.done[i] {
                self.peeked[i] = source.as_mut().and_then(Source::next);
                self.done[i] = self.peeked[i].is_none();
            }
        }
        if let Some(i) = self.peeked.iter().position(|p| matches!(p, Some(Err(_)))) {
            self.done[i] = true;
            return self.peeked[i].take();
        }
        let next = self
            .peeked
            .iter()
            .enumerate()
            .filter_map(|(i, p)| match p {
                Some(Ok(m)) => Some((m.log_time, i)),
                _ => None,
            })
            .min()?;
        self.peeked[next.1].take()
    }
}

impl BagReader {
    /// Opens a bag directory (with or without `metadata.yaml`), a single MCAP file, or a ROS 1 bag
    /// (a `.bag` file of format 2.0, told by its first bytes `#ROSBAG V2.0`).
    pub fn open(path: &Path) -> Result<Self, BagError> {
        if !path.exists() {
            return Err(BagError::NotFound {
                path: path.to_path_buf(),
            });
        }
        let paths = if path.is_dir() {
            bag_files(path)?
        } else {
            vec![path.to_path_buf()]
        };
        let files = paths
            .iter()
            .map(|p| BagFile::open(p).map(Arc::new))
            .collect::<Result<Vec<_>, _>>()?;
        // Topics summed over files, keyed by name, type and encoding; sorted by name.
        let mut topics: BTreeMap<(String, String, String), TopicInfo> = BTreeMap::new();
        for (meta, count) in files.iter().flat_map(|f| f.channels.values()) {
            let key = (
                meta.topic.clone(),
                meta.type_name.clone(),
                meta.message_encoding.clone(),
            );
            topics
                .entry(key)
                .or_insert_with(|| TopicInfo {
                    name: meta.topic.clone(),
                    type_name: meta.type_name.clone(),
                    message_encoding: meta.message_encoding.clone(),
                    schema_encoding: meta.schema_encoding.clone(),
                    schema: meta.schema.clone(),
                    message_count: 0,
                    md5sum: meta.md5sum.clone(),
                })
                .message_count += count;
        }
        Ok(BagReader {
            path: path.to_path_buf(),
            files,
            topics: topics.into_values().collect(),
        })
    }

    /// The path given to [`Self::open`].
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The MCAP files read, in order.
    pub fn files(&self) -> Vec<&Path> {
        self.files.iter().map(|f| f.path.as_path()).collect()
    }

    /// All topics, sorted by name.
    pub fn topics(&self) -> &[TopicInfo] {
        &self.topics
    }

    /// The topic named `name` (the first, should one name carry several types).
    pub fn topic(&self, name: &str) -> Option<&TopicInfo> {
        self.topics.iter().find(|t| t.name == name)
    }

    /// Number of messages in the bag (of a damaged file: those before the damage).
    pub fn message_count(&self) -> u64 {
        self.topics.iter().map(|t| t.message_count).sum()
    }

    /// Earliest and latest message log time, or `None` for an empty bag.
    pub fn time_range(&self) -> Option<(Stamp, Stamp)> {
        self.files
            .iter()
            .filter_map(|f| f.time_range)
            .reduce(|(a, b), (c, d)| (a.min(c), b.max(d)))
            .map(|(a, b)| (stamp(a), stamp(b)))
    }

    /// Iterates over all messages in log-time order.
    pub fn messages(&self) -> Result<Messages, BagError> {
        self.messages_filtered(None)
    }

    /// Iterates over the messages of the given topics in log-time order (chunks without them are
    /// skipped in indexed files).
    pub fn messages_on(&self, topics: &[&str]) -> Result<Messages, BagError> {
        self.messages_filtered(Some(topics))
    }

    fn messages_filtered(&self, topics: Option<&[&str]>) -> Result<Messages, BagError> {
        Ok(Messages::new(&self.files, topics))
    }
}
