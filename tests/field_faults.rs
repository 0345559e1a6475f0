//! Field faults through the real offline path: `dc_loc run` on rosbag2 bags written by `dc_loc sim`,
//! copied here with one fault injected (tests/cli.rs and tests/node.rs run the clean drives):
//! - one odometry outlier (x = y = 1e154 m, x = 1e6 m, a 500 m jump) keeps >= 95 % of the closures of
//!   the clean run and is counted as `bad_odometry`;
//! - one radar cloud stamped in 2038 keeps >= 95 % of the closures and is counted as `stamp_ahead`;
//! - a radar whose radial velocity has the opposite sign (the single radar of the short drive, one of
//!   the five of the nuScenes preset) is flagged, with the likely cause, within 10 s of driving; the
//!   correctly configured radars and the clean drives are not;
//! - crafted inputs of at most 1 MB (MCAP chunks and records that claim or really expand to 1 GiB, a
//!   bag of four such files, a PointCloud2 that claims 1e9 points) are refused, counted, and keep
//!   `dc_loc run` under 512 MB peak RSS, measured from outside (GNU time, else Python's
//!   `getrusage`) and as `dc_loc run` itself reports it.
//!
//! The two drives are simulated once per test binary; each run takes seconds.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use dc_loc::bag::{BagReader, BagWriter, decode, encode, schema};
use dc_loc::math::Stamp;
use dc_loc::msgs::nav_msgs::Odometry;
use dc_loc::msgs::sensor_msgs::{PointCloud2, PointField};
use dc_loc::msgs::std_msgs::Header;

mod common;
use common::{SHORT_DRIVE, text};

/// Peak RSS that no crafted input may push `dc_loc run` past, KiB.
const MEMORY_BUDGET_KIB: u64 = 512 * 1024;
/// Share of the clean run's closures a drive with one fault keeps.
const KEPT: f64 = 0.95;
const ODOM_TOPIC: &str = "/odom";

fn scratch(name: &str) -> PathBuf {
    common::scratch("field_faults", name)
}

/// A simulated drive: its bag, params and clean run.
struct Drive {
    bag: PathBuf,
    params: PathBuf,
    clean: Run,
    /// First log time of the bag.
    start: Stamp,
}

/// The short drive with one radar (`front`).
fn single() -> &'static Drive {
    static D: OnceLock<Drive> = OnceLock::new();
    D.get_or_init(|| make_drive("single", SHORT_DRIVE))
}

/// The short drive with the five radars of the nuScenes car.
fn five() -> &'static Drive {
    static D: OnceLock<Drive> = OnceLock::new();
    D.get_or_init(|| make_drive("five", &format!("{SHORT_DRIVE}radar_preset: nuscenes\n")))
}

fn make_drive(name: &str, yaml: &str) -> Drive {
    let root = scratch(name);
    let config = root.join("drive.yaml");
    std::fs::write(&config, yaml).unwrap();
    let bag = root.join("bag");
    let out = common::run_dc_loc(
        &["sim", "--config", path(&config), "--out", path(&bag)],
        "warn",
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let params = bag.join("dc_loc.yaml");
    let clean = run(&bag, &params, &format!("{name}_clean"), &[]);
    assert!(clean.output.status.success(), "{}", clean.stderr());
    assert!(clean.closures >= 50, "{} closures", clean.closures);
    let start = BagReader::open(&bag).unwrap().time_range().unwrap().0;
    Drive {
        bag,
        params,
        clean,
        start,
    }
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// One `dc_loc run`: its output, closures and peak RSS.
struct Run {
    output: Output,
    closures: usize,
    /// Peak RSS measured from outside, KiB (`None` without GNU time or Python).
    peak_kib: Option<u64>,
}

impl Run {
    fn stdout(&self) -> String {
        text(&self.output.stdout)
    }
    fn stderr(&self) -> String {
        text(&self.output.stderr)
    }

    /// The count of `name` in the summary line starting with `prefix` (`name N, name N`); 0 if absent.
    fn count(&self, prefix: &str, name: &str) -> u64 {
        let stdout = self.stdout();
        let Some(line) = stdout
            .lines()
            .find_map(|l| l.split_once(prefix).map(|x| x.1))
        else {
            panic!("no `{prefix}` in the summary:\n{stdout}");
        };
        line.split(", ")
            .find_map(|kv| kv.strip_prefix(name)?.trim().parse().ok())
            .unwrap_or(0)
    }
    fn dropped(&self, name: &str) -> u64 {
        self.count("dropped inputs: ", name)
    }
    fn skipped(&self, name: &str) -> u64 {
        self.count("skipped messages: ", name)
    }

    /// The peak memory `dc_loc run` reports itself, MB.
    fn reported_peak_mb(&self) -> u64 {
        let stdout = self.stdout();
        stdout
            .lines()
            .find_map(|l| {
                l.strip_prefix("peak memory: ")?
                    .strip_suffix(" MB")?
                    .parse()
                    .ok()
            })
            .unwrap_or_else(|| panic!("no `peak memory: N MB` line:\n{stdout}"))
    }

    /// Both peak figures are within the budget.
    fn assert_within_budget(&self, what: &str) {
        let reported = self.reported_peak_mb();
        println!(
            "{what}: peak RSS {} KiB measured, {reported} MB reported",
            self.peak_kib.map_or("-".into(), |k| k.to_string())
        );
        assert!(reported * 1024 < MEMORY_BUDGET_KIB, "{what}: {reported} MB");
        if let Some(k) = self.peak_kib {
            assert!(k < MEMORY_BUDGET_KIB, "{what}: peak RSS {k} KiB");
        }
    }
}

/// `dc_loc run --bag bag --params params` (plus `extra`) into a scratch folder `name`.
fn run(bag: &Path, params: &Path, name: &str, extra: &[&str]) -> Run {
    let dir = scratch(name);
    let out = dir.join("closures.jsonl");
    let mut args = vec!["run", "--bag", path(bag), "--params", path(params)];
    args.extend(["--out", path(&out)]);
    args.extend(extra);
    let (output, peak_kib) = measured(&args, &dir.join("peak_kib"));
    let closures = std::fs::read_to_string(&out).map_or(0, |s| s.lines().count());
    Run {
        output,
        closures,
        peak_kib,
    }
}

/// Runs `dc_loc args` under GNU time (`-f %M`), else a Python `getrusage(RUSAGE_CHILDREN)` wrapper,
/// and reads the child's peak RSS (KiB) from `peak_file`.
fn measured(args: &[&str], peak_file: &Path) -> (Output, Option<u64>) {
    const WRAPPER: &str = "import resource, subprocess, sys\n\
rc = subprocess.call(sys.argv[2:])\n\
open(sys.argv[1], 'w').write('%d\\n' % resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n\
sys.exit(rc)\n";
    let exe = env!("CARGO_BIN_EXE_dc_loc");
    let mut cmd = if Path::new("/usr/bin/time").is_file() {
        let mut c = Command::new("/usr/bin/time");
        c.args(["-f", "%M", "-o", path(peak_file), exe]);
        c
    } else {
        let mut c = Command::new("python3");
        c.args(["-c", WRAPPER, path(peak_file), exe]);
        c
    };
    let output = cmd
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .or_else(|_| {
            Command::new(exe)
                .args(args)
                .env("RUST_LOG", "warn")
                .output()
        })
        .expect("cannot start dc_loc");
    // GNU time puts "Command exited with non-zero status N" before the figure.
    let peak = std::fs::read_to_string(peak_file)
        .ok()
        .and_then(|s| s.lines().last()?.trim().parse().ok());
    if peak.is_none() {
        common::skipped("no GNU time or python3 to measure the peak RSS from outside");
    }
    (output, peak)
}

/// Copies bag `src` into a new bag `dst` in log-time order; `edit(topic, index on the topic, data)`
/// may replace a message (its log time stays).
fn rewrite(src: &Path, dst: &Path, mut edit: impl FnMut(&str, usize, &[u8]) -> Option<Vec<u8>>) {
    let reader = BagReader::open(src).unwrap();
    let mut w = BagWriter::create(dst).unwrap();
    let ids: BTreeMap<String, _> = reader
        .topics()
        .iter()
        .map(|t| (t.name.clone(), w.add_topic(&t.name, &t.type_name).unwrap()))
        .collect();
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    for m in reader.messages().unwrap() {
        let m = m.unwrap();
        let n = counts.entry(m.topic().to_string()).or_default();
        let data = edit(m.topic(), *n, m.data()).unwrap_or_else(|| m.data().to_vec());
        *n += 1;
        w.write_cdr(ids[m.topic()], m.log_time, &data).unwrap();
    }
    w.finish().unwrap();
}

/// Messages on `topic` in the bag.
fn count_on(bag: &Path, topic: &str) -> usize {
    BagReader::open(bag)
        .unwrap()
        .topic(topic)
        .unwrap()
        .message_count as usize
}

/// `d`'s bag with message `index` of `topic` changed by `change`, run; asserts it kept >= 95 % of
/// the clean run's closures.
fn run_with_fault(
    d: &Drive,
    name: &str,
    topic: &str,
    index: usize,
    change: impl Fn(&[u8]) -> Vec<u8>,
) -> Run {
    let bag = scratch(&format!("{name}_bag")).join("bag");
    rewrite(&d.bag, &bag, |t, i, data| {
        (t == topic && i == index).then(|| change(data))
    });
    let r = run(&bag, &d.params, name, &[]);
    assert!(r.output.status.success(), "{name}: {}", r.stderr());
    println!(
        "{name}: {} closures, clean {} ({:.1} %)",
        r.closures,
        d.clean.closures,
        100.0 * r.closures as f64 / d.clean.closures as f64
    );
    assert!(
        r.closures as f64 >= KEPT * d.clean.closures as f64,
        "{name}: {} closures of the clean run's {}\n{}",
        r.closures,
        d.clean.closures,
        r.stdout()
    );
    r
}

fn odometry_moved(data: &[u8], f: impl Fn(&mut Odometry)) -> Vec<u8> {
    let mut m: Odometry = decode(data).unwrap();
    f(&mut m);
    encode(&m).unwrap()
}

#[test]
fn one_odometry_outlier_keeps_the_closures_and_is_counted() {
    let d = single();
    let index = count_on(&d.bag, ODOM_TOPIC) / 3;
    type Fault = fn(&mut Odometry);
    let faults: [(&str, Fault); 3] = [
        ("odom_1e154", |m| {
            m.pose.pose.position.x = 1e154;
            m.pose.pose.position.y = 1e154;
        }),
        ("odom_1e6", |m| m.pose.pose.position.x = 1e6),
        ("odom_jump_500m", |m| m.pose.pose.position.x += 500.0),
    ];
    for (name, fault) in faults {
        let r = run_with_fault(d, name, ODOM_TOPIC, index, |data| {
            odometry_moved(data, fault)
        });
        assert_eq!(
            r.dropped("bad_odometry"),
            d.clean.dropped("bad_odometry") + 1,
            "{name}:\n{}",
            r.stdout()
        );
    }
}

/// The first radar topic of a drive's bag (sorted by name).
fn radar_topics(d: &Drive) -> Vec<String> {
    BagReader::open(&d.bag)
        .unwrap()
        .topics()
        .iter()
        .filter(|t| t.type_name == schema::POINT_CLOUD2)
        .map(|t| t.name.clone())
        .collect()
}

fn cloud_restamped(data: &[u8], sec: i32, nanosec: u32) -> Vec<u8> {
    let mut c: PointCloud2 = decode(data).unwrap();
    c.header.stamp.sec = sec;
    c.header.stamp.nanosec = nanosec;
    encode(&c).unwrap()
}

#[test]
fn a_radar_cloud_stamped_in_2038_keeps_the_closures_and_is_counted() {
    let d = single();
    let topic = &radar_topics(d)[0];
    let index = count_on(&d.bag, topic) / 3;
    // 2038-01-01T00:00:00Z; the log time (the recorder's receive time) stays.
    let r = run_with_fault(d, "stamp_2038", topic, index, |data| {
        cloud_restamped(data, 2_145_916_800, 0)
    });
    // One stamp out of line is dropped, not taken as the new time (node.restart_after, 20).
    assert_eq!(r.dropped("stamp_ahead"), 1, "{}", r.stdout());
    assert!(!r.stdout().contains("time resets"), "{}", r.stdout());
}

#[test]
fn a_header_stamp_with_nanosec_past_a_second_is_a_counted_skip() {
    let d = single();
    let topic = radar_topics(d)[0].clone();
    let (radar_index, odom_index) = (
        count_on(&d.bag, &topic) / 3,
        count_on(&d.bag, ODOM_TOPIC) / 2,
    );
    let bag = scratch("nanosec_bag").join("bag");
    rewrite(&d.bag, &bag, |t, i, data| {
        if t == topic && i == radar_index {
            let c: PointCloud2 = decode(data).unwrap();
            Some(cloud_restamped(data, c.header.stamp.sec, 1_500_000_000))
        } else if t == ODOM_TOPIC && i == odom_index {
            Some(odometry_moved(data, |m| m.header.stamp.nanosec = u32::MAX))
        } else {
            None
        }
    });
    let r = run(&bag, &d.params, "nanosec", &[]);
    assert!(r.output.status.success(), "{}", r.stderr());
    assert_eq!(r.skipped("bad_stamp"), 2, "{}", r.stdout());
    assert!(r.stderr().contains("nanosec"), "{}", r.stderr());
    assert!(r.closures as f64 >= KEPT * d.clean.closures as f64);
}

fn flip_velocity(data: &[u8]) -> Vec<u8> {
    let mut c: PointCloud2 = decode(data).unwrap();
    let f = c.fields.iter().find(|f| f.name == "v_r").unwrap();
    assert!(f.datatype == PointField::FLOAT32 && !c.is_bigendian);
    let (at, step) = (f.offset as usize, c.point_step as usize);
    for p in c.data.chunks_exact_mut(step) {
        let v = f32::from_le_bytes(p[at..at + 4].try_into().unwrap());
        p[at..at + 4].copy_from_slice(&(-v).to_le_bytes());
    }
    encode(&c).unwrap()
}

/// The radar names flagged in the summary, with their stamps (s).
fn flagged(r: &Run) -> BTreeMap<String, f64> {
    r.stdout()
        .lines()
        .filter_map(|l| {
            let rest = l.strip_prefix("doppler: radar `")?;
            let (name, rest) = rest.split_once("` flagged at ")?;
            let stamp = rest.split_once(" s")?.0.parse().ok()?;
            Some((name.to_string(), stamp))
        })
        .collect()
}

/// The drive with the velocity of every cloud on `topic` negated: radar `radar` is flagged within
/// 10 s of driving (the warning once on stderr, naming the sign), and no other radar.
fn flipped_radar_is_flagged(d: &Drive, name: &str, topic: &str, radar: &str) {
    let bag = scratch(&format!("{name}_bag")).join("bag");
    rewrite(&d.bag, &bag, |t, _, data| {
        (t == topic).then(|| flip_velocity(data))
    });
    let r = run(&bag, &d.params, name, &[]);
    assert!(r.output.status.success(), "{}", r.stderr());
    let flags = flagged(&r);
    assert_eq!(
        flags.keys().collect::<Vec<_>>(),
        [radar],
        "{name}:\n{}",
        r.stdout()
    );
    let after = flags[radar] - d.start.as_secs_f64();
    println!("{name}: radar `{radar}` flagged {after:.2} s into the drive");
    assert!(
        (0.0..10.0).contains(&after),
        "{name}: flagged after {after:.2} s"
    );
    let stderr = r.stderr();
    let warnings: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("Doppler speeds disagree"))
        .collect();
    assert_eq!(warnings.len(), 1, "{name}: {warnings:?}");
    assert!(
        warnings[0].contains(&format!("`{radar}`")) && warnings[0].contains("sign-flipped"),
        "{}",
        warnings[0]
    );
}

#[test]
fn a_sign_flipped_radar_is_flagged_within_seconds() {
    let d = single();
    flipped_radar_is_flagged(d, "flipped_single", &radar_topics(d)[0], "front");
}

#[test]
fn a_sign_flipped_radar_of_five_is_flagged_alone() {
    let d = five();
    let topics = radar_topics(d);
    assert_eq!(topics.len(), 5, "{topics:?}");
    let topic = "/radar_front_left/points";
    assert!(topics.iter().any(|t| t == topic), "{topics:?}");
    flipped_radar_is_flagged(d, "flipped_five", topic, "front_left");
}

#[test]
fn clean_drives_flag_no_radar() {
    for d in [single(), five()] {
        assert!(flagged(&d.clean).is_empty(), "{}", d.clean.stdout());
        assert!(
            !d.clean.stderr().contains("Doppler speeds disagree"),
            "{}",
            d.clean.stderr()
        );
        assert_eq!(d.clean.dropped("bad_odometry"), 0);
        d.clean.assert_within_budget("clean drive");
    }
}

/// Hand-written MCAP files (the format's records, with whatever sizes they claim).
mod mcap_file {
    pub const MAGIC: &[u8] = b"\x89MCAP0\r\n";
    pub const GIB: u64 = 1 << 30;

    /// A record: opcode, u64 length, body.
    pub fn record(op: u8, body: &[u8]) -> Vec<u8> {
        let mut r = vec![op];
        r.extend((body.len() as u64).to_le_bytes());
        r.extend(body);
        r
    }

    /// Little-endian fields and u32-prefixed strings.
    #[derive(Default)]
    pub struct Body(pub Vec<u8>);
    impl Body {
        pub fn u16(mut self, v: u16) -> Self {
            self.0.extend(v.to_le_bytes());
            self
        }
        pub fn u32(mut self, v: u32) -> Self {
            self.0.extend(v.to_le_bytes());
            self
        }
        pub fn u64(mut self, v: u64) -> Self {
            self.0.extend(v.to_le_bytes());
            self
        }
        pub fn str(self, s: &str) -> Self {
            self.bytes32(s.as_bytes())
        }
        pub fn bytes32(mut self, b: &[u8]) -> Self {
            self = self.u32(b.len() as u32);
            self.0.extend(b);
            self
        }
        pub fn raw(mut self, b: &[u8]) -> Self {
            self.0.extend(b);
            self
        }
    }

    /// A zstd frame of RLE blocks (4 bytes per 128 KiB) that expands to `bytes` zeros.
    pub fn zstd_zeros(bytes: u64) -> Vec<u8> {
        const BLOCK: u64 = 128 << 10;
        // Magic; frame header: no content size, one byte of window descriptor (128 KiB).
        let mut f = vec![0x28, 0xB5, 0x2F, 0xFD, 0x00, 0x38];
        let mut left = bytes;
        while left > 0 {
            let n = left.min(BLOCK);
            left -= n;
            // Last-block bit, block type 1 (RLE), size; then the byte repeated.
            let header = u32::from(left == 0) | (1 << 1) | ((n as u32) << 3);
            f.extend(&header.to_le_bytes()[..3]);
            f.push(0);
        }
        f
    }
}

/// The crafted MCAP files: each at most 1 MB, each claiming or expanding to far more.
#[derive(Debug, Clone, Copy)]
enum Bomb {
    /// A chunk that claims 1 GiB uncompressed, read through the chunk index of its summary.
    ClaimsIndexed,
    /// The same without a summary (read from start to end).
    ClaimsLinear,
    /// A zstd chunk that really expands to 1 GiB of zeros, without a summary.
    ExpandsLinear,
    /// A zstd chunk that really expands to 63 MB (within the reader's 64 MiB), through its index.
    ExpandsIndexed,
    /// A message record whose length field claims 1 GiB.
    RecordLength,
}

/// What [`Bomb::ExpandsIndexed`] expands to: 7e6 records of 9 zero bytes.
const EXPANDS_TO: u64 = 63_000_000;

/// An MCAP file with the topics of the single drive (`/odom`, `radar_topic`), two odometry messages
/// at `t0` and `t0` + 40 ms, then `bomb`.
fn bomb_file(bomb: Bomb, radar_topic: &str, t0: u64) -> Vec<u8> {
    use mcap_file::{Body, GIB, MAGIC, record, zstd_zeros};
    let header = record(0x01, &Body::default().str("ros2").str("field_faults").0);
    let schema = |id, name: &str| {
        record(
            0x03,
            &Body::default()
                .u16(id)
                .str(name)
                .str("ros2msg")
                .bytes32(b"")
                .0,
        )
    };
    let channel = |id, topic: &str| {
        let body = Body::default().u16(id).u16(id).str(topic).str("cdr");
        record(0x04, &body.u32(0).0)
    };
    let defs = [
        schema(1, schema::ODOMETRY),
        schema(2, schema::POINT_CLOUD2),
        channel(1, ODOM_TOPIC),
        channel(2, radar_topic),
    ]
    .concat();
    let mut file = [MAGIC, &header, &defs].concat();
    for (seq, t) in [t0, t0 + 40_000_000].into_iter().enumerate() {
        let mut odom = Odometry::default();
        odom.header.stamp = Stamp(t as i64).into();
        let body = Body::default().u16(1).u32(seq as u32).u64(t).u64(t);
        file.extend(record(0x05, &body.raw(&encode(&odom).unwrap()).0));
    }
    let (claimed, frame) = match bomb {
        Bomb::ClaimsIndexed | Bomb::ClaimsLinear => (GIB, zstd_zeros(4096)),
        // Whole 9-byte records of zeros (opcode 0, length 0): a chunk that reads to its end.
        Bomb::ExpandsLinear => (GIB / 9 * 9, zstd_zeros(GIB / 9 * 9)),
        Bomb::ExpandsIndexed => (EXPANDS_TO, zstd_zeros(EXPANDS_TO)),
        Bomb::RecordLength => {
            let mut r = record(0x05, &[7u8; 512]);
            r[1..9].copy_from_slice(&GIB.to_le_bytes());
            file.extend(r);
            return file;
        }
    };
    let chunk_at = file.len() as u64;
    let chunk = Body::default()
        .u64(t0)
        .u64(t0 + 40_000_000)
        .u64(claimed)
        .u32(0);
    let chunk = record(
        0x06,
        &chunk.str("zstd").u64(frame.len() as u64).raw(&frame).0,
    );
    let chunk_len = chunk.len() as u64;
    file.extend(chunk);
    file.extend(record(0x0F, &Body::default().u32(0).0));
    let summary_at = file.len() as u64;
    if matches!(bomb, Bomb::ClaimsIndexed | Bomb::ExpandsIndexed) {
        file.extend(&defs);
        let stats = Body::default().u64(2).u16(2).u32(2).u32(0).u32(0).u32(1);
        let stats = stats.u64(t0).u64(t0 + 40_000_000).u32(10).u16(1).u64(2);
        file.extend(record(0x0B, &stats.0));
        let index = Body::default().u64(t0).u64(t0 + 40_000_000).u64(chunk_at);
        let index = index.u64(chunk_len).u32(0).u64(0).str("zstd");
        file.extend(record(0x08, &index.u64(frame.len() as u64).u64(claimed).0));
    }
    let summary_start = if file.len() as u64 > summary_at {
        summary_at
    } else {
        0
    };
    let footer = Body::default().u64(summary_start).u64(0).u32(0);
    file.extend(record(0x02, &footer.0));
    file.extend(MAGIC);
    assert!(file.len() <= 1 << 20, "{bomb:?}: {} bytes", file.len());
    file
}

/// The single drive's first cloud (its radar topic, frame and first stamp).
fn first_cloud(d: &Drive) -> (String, PointCloud2) {
    let topic = radar_topics(d)[0].clone();
    let reader = BagReader::open(&d.bag).unwrap();
    let m = reader
        .messages_on(&[&topic])
        .unwrap()
        .next()
        .unwrap()
        .unwrap();
    (topic, m.decode().unwrap())
}

/// `dc_loc run` on `bag`: refused as damage (exit 1, counted, named), within the memory budget.
fn assert_refused(bag: &Path, d: &Drive, name: &str, files: u64) -> Run {
    let r = run(bag, &d.params, &format!("{name}_run"), &[]);
    println!(
        "{name}: {}",
        r.stderr()
            .lines()
            .filter(|l| l.contains("skipped"))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    assert_eq!(r.output.status.code(), Some(1), "{name}: {}", r.stderr());
    assert!(r.stderr().contains("damaged"), "{name}: {}", r.stderr());
    assert!(
        r.stderr().contains("limit") || r.stderr().contains("the reader takes"),
        "{name}: {}",
        r.stderr()
    );
    assert_eq!(r.skipped("damaged_file"), files, "{name}:\n{}", r.stdout());
    r.assert_within_budget(name);
    r
}

#[test]
fn mcap_bombs_are_refused_within_the_memory_budget() {
    let d = single();
    let (topic, _) = first_cloud(d);
    let t0 = d.start.0 as u64;
    for bomb in [
        Bomb::ClaimsIndexed,
        Bomb::ClaimsLinear,
        Bomb::ExpandsLinear,
        Bomb::RecordLength,
    ] {
        let name = format!("{bomb:?}");
        let dir = scratch(&format!("{name}_bag"));
        std::fs::write(dir.join("bomb.mcap"), bomb_file(bomb, &topic, t0)).unwrap();
        assert_refused(&dir.join("bomb.mcap"), d, &name, 1);
    }
    // Within the reader's limit, a chunk that really expands to 63 MB is read (no message in it).
    let dir = scratch("ExpandsIndexed_bag");
    let file = dir.join("bomb.mcap");
    std::fs::write(&file, bomb_file(Bomb::ExpandsIndexed, &topic, t0)).unwrap();
    let r = run(&file, &d.params, "ExpandsIndexed_run", &[]);
    assert!(r.output.status.success(), "{}", r.stderr());
    r.assert_within_budget("ExpandsIndexed");
}

#[test]
fn a_bag_of_four_bombs_is_refused_within_the_memory_budget() {
    let d = single();
    let (topic, _) = first_cloud(d);
    let t0 = d.start.0 as u64;
    // Overlapping time ranges: the four are open together.
    let bag = scratch("four_bombs_bag").join("bag");
    std::fs::create_dir_all(&bag).unwrap();
    for (i, bomb) in [
        Bomb::ClaimsIndexed,
        Bomb::ClaimsLinear,
        Bomb::ExpandsLinear,
        Bomb::RecordLength,
    ]
    .into_iter()
    .enumerate()
    {
        std::fs::write(
            bag.join(format!("bag_{i}.mcap")),
            bomb_file(bomb, &topic, t0),
        )
        .unwrap();
    }
    assert_refused(&bag, d, "four_bombs", 4);
    // Files open together share 256 MiB: four chunks that each expand to 63 MB are read; of eight,
    // each may hold 32 MiB, and each is refused.
    for files in [4, 8] {
        let name = format!("{files}_expanding");
        let bag = scratch(&format!("{name}_bag")).join("bag");
        std::fs::create_dir_all(&bag).unwrap();
        for i in 0..files {
            let file = bomb_file(Bomb::ExpandsIndexed, &topic, t0);
            std::fs::write(bag.join(format!("bag_{i}.mcap")), file).unwrap();
        }
        if files == 4 {
            let r = run(&bag, &d.params, &name, &[]);
            assert!(r.output.status.success(), "{}", r.stderr());
            r.assert_within_budget(&name);
        } else {
            let r = assert_refused(&bag, d, &name, files);
            assert!(r.stderr().contains("32 MiB"), "{}", r.stderr());
        }
    }
}

#[test]
fn a_point_cloud_claiming_a_billion_points_is_refused_within_the_memory_budget() {
    let d = single();
    let (topic, real) = first_cloud(d);
    let bag = scratch("cloud_bomb_bag").join("bag");
    let mut w = BagWriter::create(&bag).unwrap();
    let odom = w.add_topic(ODOM_TOPIC, schema::ODOMETRY).unwrap();
    let radar = w.add_topic(&topic, schema::POINT_CLOUD2).unwrap();
    let ms = |k: i64| Stamp(d.start.0 + k * 1_000_000);
    for k in 0..50 {
        let mut m = Odometry::default();
        m.header.stamp = ms(40 * k).into();
        m.pose.pose.position.x = 0.4 * k as f64;
        w.write(odom, ms(40 * k), &m).unwrap();
    }
    // (width, height, point_step): 1e9 points of 1 byte, 1e9 points in 1000 rows, 1e7 points of 16
    // bytes; each with 1 MB of data.
    let claims = [
        (1_000_000_000, 1, 1),
        (1_000_000, 1000, 16),
        (10_000_000, 1, 16),
    ];
    for (k, (width, height, point_step)) in claims.into_iter().enumerate() {
        let cloud = PointCloud2 {
            header: Header {
                stamp: ms(200 + 300 * k as i64).into(),
                frame_id: real.header.frame_id.clone(),
            },
            height,
            width,
            point_step,
            row_step: width * point_step,
            data: vec![0u8; 1 << 20],
            ..real.clone()
        };
        w.write(radar, ms(200 + 300 * k as i64), &cloud).unwrap();
    }
    w.finish().unwrap();
    let r = run(&bag, &d.params, "cloud_bomb", &[]);
    assert!(r.output.status.success(), "{}", r.stderr());
    assert_eq!(r.dropped("cloud_too_large"), 3, "{}", r.stdout());
    r.assert_within_budget("cloud_bomb");
    // With the limits raised as far as they go, the 1e7-point claim reaches the decoder, which checks
    // it against the data before reserving anything.
    let raised = [
        "-p",
        "node.max_cloud_points:=10000000",
        "-p",
        "node.max_cloud_bytes:=1073741824",
    ];
    let r = run(&bag, &d.params, "cloud_bomb_raised", &raised);
    assert!(r.output.status.success(), "{}", r.stderr());
    assert_eq!(r.dropped("cloud_too_large"), 2, "{}", r.stdout());
    assert_eq!(r.dropped("bad_cloud"), 1, "{}", r.stdout());
    r.assert_within_budget("cloud_bomb_raised");
}
