//! The project's budgets, each measured against its peer or its limit in one run on this computer, one
//! line a budget: `name value limit OK|SHORT`. It reports and does not gate: the exit code is 0 whatever
//! the lines say (and 0 when a measurement could not run: its line then says `n/a ... SHORT` and why).
//!
//! ```text
//! cargo build --release && cargo run --release --example budgets -- [--quick] [--node BIN] [--venv DIR]
//! ```
//! It runs the project's own tools one after the other, so that what they measure shows up here
//! unchanged:
//!
//! - `dc_loc eval --set test --dcloc-only --export-pairs DIR` (the held-out worlds, one forward radar and
//!   the five ARS408 of the nuScenes car), then `examples/peers.py DIR/<world> --json` in the Python venv
//!   (`DCLOC_VENV`, else `<repo>/.venv`; tests/python/setup_venv.sh makes it), every peer on one thread:
//!   DC-Loc registering a prepared pair against Open3D point-to-point ICP's whole time, DC-Loc's whole
//!   pair (preparing both submaps, descriptors included) against FPFH + RANSAC + ICP's, and DC-Loc's mean
//!   error against the best peer's (the worst world of each radar set). Times pooled over the worlds of
//!   a radar set (total time over total time).
//! - `cargo run --release --example node_latency -- --one-core` (five radars at 13 Hz in real time, the
//!   node pinned to one CPU with `RAYON_NUM_THREADS=1`): its CPU as a share of one core, keyframe
//!   processing p99, arrival-to-closure p99; and with `--fleet 3`, three such nodes exchanging keyframes,
//!   each node's CPU.
//! - `cargo run --release --example soak -- --minutes M --rate 10`: the node's resident memory added per
//!   map keyframe, and its map file's bytes per keyframe.
//! - `cargo bench --bench keyframe_db` (`DC_LOC_BENCH_MAP=100000`): the load time of a 100,000-keyframe map.
//!
//! `--quick` (23 minutes on a loaded 2-core machine, most of it simulating drives): peers.py on at most
//! 30 pairs of a world, the soak for 2 minutes instead of 5, and the load of a 20,000-keyframe map
//! scaled to 100,000 (its line says so). The node runs are the same in both. DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), in domains
//! ROS_DOMAIN_ID (default 70) and the one after it. Every tool's output goes to a log in the scratch
//! directory, which the run prints and keeps.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use serde_json::Value;

/// The repository (the examples, the scripts).
fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The value after `name` on the command line.
fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

/// Whether a value is within its limit: at most, or below.
#[derive(Clone, Copy)]
enum Bound {
    AtMost,
    Below,
}

/// One budget's line.
struct Line {
    name: String,
    value: Option<f64>,
    limit: f64,
    bound: Bound,
    unit: &'static str,
    note: String,
}

impl Line {
    fn new(name: &str, value: Option<f64>, limit: f64, unit: &'static str) -> Line {
        Line {
            name: name.into(),
            value,
            limit,
            bound: Bound::AtMost,
            unit,
            note: String::new(),
        }
    }

    fn below(mut self) -> Line {
        self.bound = Bound::Below;
        self
    }

    fn note(mut self, note: impl Into<String>) -> Line {
        self.note = note.into();
        self
    }

    fn ok(&self) -> bool {
        match (self.value, self.bound) {
            (Some(v), Bound::AtMost) => v <= self.limit,
            (Some(v), Bound::Below) => v < self.limit,
            (None, _) => false,
        }
    }

    fn print(&self) {
        let fmt = |v: f64| match self.unit {
            "x" => format!("{v:.2}x"),
            "%" => format!("{v:.1}%"),
            u => format!("{v:.2}{u}"),
        };
        let value = self.value.map_or("n/a".to_string(), fmt);
        let bound = match self.bound {
            Bound::AtMost => "",
            Bound::Below => "<",
        };
        let verdict = if self.ok() { "OK" } else { "SHORT" };
        let note = if self.note.is_empty() {
            String::new()
        } else {
            format!("  # {}", self.note)
        };
        println!(
            "{} {value} {bound}{} {verdict}{note}",
            self.name,
            fmt(self.limit)
        );
    }
}

/// Runs `command` with its output to `log`; whether it succeeded, and its stdout.
fn run(mut command: Command, log: &Path) -> Result<String, String> {
    let shown = format!("{command:?}");
    eprintln!("budgets: {shown}");
    let t0 = Instant::now();
    let out = command
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("cannot start {shown}: {e}"))?;
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let _ = std::fs::write(
        log,
        format!("$ {shown}\n{stdout}\n--- stderr ---\n{stderr}"),
    );
    eprintln!(
        "budgets:   {:.0} s, exit {:?}, log {}",
        t0.elapsed().as_secs_f64(),
        out.status.code(),
        log.display()
    );
    if out.status.success() {
        Ok(stdout)
    } else {
        Err(format!("{shown} failed (log {})", log.display()))
    }
}

/// `cargo` with the arguments, in the repository (the target directory as this run's).
fn cargo(args: &[&str]) -> Command {
    let mut c = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    c.args(args).current_dir(repo());
    c
}

/// A number of a JSON object at `path`.
fn num(v: &Value, path: &[&str]) -> Option<f64> {
    path.iter().try_fold(v, |v, k| v.get(k))?.as_f64()
}

/// The figures of one world's `peers.py --json`.
struct World {
    name: String,
    pairs: f64,
    register_ms: f64,
    whole_ms: f64,
    icp_ms: f64,
    fpfh_ms: f64,
    error: f64,
    best_peer_error: f64,
    best_peer: String,
}

impl World {
    fn from_json(name: &str, v: &Value) -> Option<World> {
        let m = v.get("methods")?;
        let dc = m.get("dcloc")?;
        let (best_peer, best_peer_error) = ["icp", "fpfh", "gicp"]
            .iter()
            .filter_map(|p| Some((p.to_string(), num(m, &[p, "inside_mean"])?)))
            .min_by(|a, b| a.1.total_cmp(&b.1))?;
        Some(World {
            name: name.into(),
            pairs: num(v, &["pairs"])?,
            register_ms: num(dc, &["register_ms_mean"])?,
            whole_ms: num(dc, &["ms_mean"])?,
            icp_ms: num(m, &["icp", "ms_mean"])?,
            fpfh_ms: num(m, &["fpfh", "ms_mean"])?,
            error: num(dc, &["inside_mean"])?,
            best_peer_error,
            best_peer,
        })
    }
}

/// DC-Loc beside its peers on the held-out worlds: the pairs exported, then peers.py on each world.
fn peers(dir: &Path, node_bin: &Path, venv: &Path, quick: bool) -> Vec<Line> {
    let pairs = dir.join("pairs");
    let mut export = Command::new(node_bin);
    export
        .args(["eval", "--set", "test", "--dcloc-only", "--export-pairs"])
        .arg(&pairs)
        .arg("--out-dir")
        .arg(dir.join("eval"));
    let failed = |why: String| {
        ["five_radars", "one_radar"]
            .iter()
            .flat_map(|r| {
                [
                    Line::new(&format!("register_prepared_pair/icp.{r}"), None, 1.0, "x"),
                    Line::new(&format!("whole_pair/fpfh_ransac_icp.{r}"), None, 0.15, "x"),
                    Line::new(&format!("mean_error/best_peer.{r}"), None, 0.6, "x"),
                ]
            })
            .map(|l| l.note(why.clone()))
            .collect::<Vec<_>>()
    };
    if let Err(e) = run(export, &dir.join("export.log")) {
        return failed(e);
    }
    let python = venv.join("bin/python3");
    let mut worlds = Vec::new();
    let mut subdirs: Vec<PathBuf> = std::fs::read_dir(&pairs)
        .map(|d| {
            d.flatten()
                .map(|e| e.path())
                .filter(|p| p.is_dir())
                .collect()
        })
        .unwrap_or_default();
    subdirs.sort();
    for sub in subdirs {
        let name = sub
            .file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned();
        let report = dir.join(format!("peers_{name}.json"));
        let mut script = Command::new(&python);
        script
            .arg(repo().join("examples/peers.py"))
            .arg(&sub)
            .arg("--json")
            .arg(&report);
        if quick {
            script.args(["--max-pairs", "30"]);
        }
        if let Err(e) = run(script, &dir.join(format!("peers_{name}.log"))) {
            return failed(e);
        }
        let parsed = std::fs::read_to_string(&report)
            .ok()
            .and_then(|t| serde_json::from_str::<Value>(&t).ok())
            .and_then(|v| World::from_json(&name, &v));
        match parsed {
            Some(w) => worlds.push(w),
            None => return failed(format!("{} lacks a figure", report.display())),
        }
    }
    let mut lines = Vec::new();
    for (radars, key) in [("five_radars", "nuscenes"), ("one_radar", "carla")] {
        let set: Vec<&World> = worlds.iter().filter(|w| w.name.contains(key)).collect();
        if set.is_empty() {
            lines.extend(failed(format!("no {key} world in {}", pairs.display())));
            continue;
        }
        let total = |f: &dyn Fn(&World) -> f64| set.iter().map(|w| w.pairs * f(w)).sum::<f64>();
        let n = total(&|_| 1.0);
        lines.push(
            Line::new(
                &format!("register_prepared_pair/icp.{radars}"),
                Some(total(&|w| w.register_ms) / total(&|w| w.icp_ms)),
                1.0,
                "x",
            )
            .note(format!(
                "{:.2} / {:.2} ms a pair, {} worlds, {n} pairs",
                total(&|w| w.register_ms) / n,
                total(&|w| w.icp_ms) / n,
                set.len()
            )),
        );
        lines.push(
            Line::new(
                &format!("whole_pair/fpfh_ransac_icp.{radars}"),
                Some(total(&|w| w.whole_ms) / total(&|w| w.fpfh_ms)),
                0.15,
                "x",
            )
            .note(format!(
                "{:.2} / {:.2} ms a pair",
                total(&|w| w.whole_ms) / n,
                total(&|w| w.fpfh_ms) / n
            )),
        );
        let worst = set
            .iter()
            .max_by(|a, b| (a.error / a.best_peer_error).total_cmp(&(b.error / b.best_peer_error)))
            .expect("a world");
        lines.push(
            Line::new(
                &format!("mean_error/best_peer.{radars}"),
                Some(worst.error / worst.best_peer_error),
                0.6,
                "x",
            )
            .note(format!(
                "worst world {}: {:.3} m / {} {:.3} m",
                worst.name, worst.error, worst.best_peer, worst.best_peer_error
            )),
        );
    }
    lines
}

/// The node on one core, five radars at 13 Hz: node_latency's `--json` figures of each node.
fn node_runs(dir: &Path, node_bin: &Path, domain: u16, fleet: bool) -> Result<Vec<Value>, String> {
    let label = if fleet { "fleet" } else { "one_core" };
    let json = dir.join(format!("node_{label}.json"));
    let mut c = cargo(&["run", "--release", "--example", "node_latency", "--"]);
    c.arg("--one-core")
        .arg("--node")
        .arg(node_bin)
        .arg("--json")
        .arg(&json);
    if fleet {
        c.args(["--fleet", "3"]);
    }
    c.env("ROS_DOMAIN_ID", domain.to_string())
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST");
    run(c, &dir.join(format!("node_{label}.log")))?;
    let v: Value = std::fs::read_to_string(&json)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .ok_or_else(|| format!("{} unreadable", json.display()))?;
    v.get("runs")
        .and_then(Value::as_array)
        .cloned()
        .ok_or_else(|| format!("{} has no runs", json.display()))
}

fn node(dir: &Path, node_bin: &Path, domain: u16) -> Vec<Line> {
    let names = [
        ("node_cpu_one_core", 4.0, "%"),
        ("keyframe_processing_p99", 25.0, "ms"),
        ("arrival_to_closure_p99", 40.0, "ms"),
    ];
    let runs = match node_runs(dir, node_bin, domain, false) {
        Ok(r) if !r.is_empty() => r,
        Ok(_) => return vec![Line::new("node_cpu_one_core", None, 4.0, "%").note("no run")],
        Err(e) => {
            return names
                .iter()
                .map(|(n, l, u)| Line::new(n, None, *l, u).note(e.clone()))
                .collect();
        }
    };
    let r = &runs[0];
    let value = |k: &str| {
        r.get("values")
            .and_then(|v| v.get(k))
            .and_then(Value::as_str)
            .and_then(|s| s.parse::<f64>().ok())
    };
    vec![
        Line::new(
            "node_cpu_one_core",
            num(r, &["cpu_share"]).map(|s| 100.0 * s),
            4.0,
            "%",
        )
        .note(format!(
            "{:.1} s CPU in {:.1} s, {} threads",
            num(r, &["cpu_seconds"]).unwrap_or(f64::NAN),
            num(r, &["wall_seconds"]).unwrap_or(f64::NAN),
            num(r, &["threads"]).unwrap_or(f64::NAN)
        )),
        Line::new(
            "keyframe_processing_p99",
            value("keyframe_processing_ms.p99"),
            25.0,
            "ms",
        ),
        Line::new(
            "arrival_to_closure_p99",
            value("closure_latency_ms.p99"),
            40.0,
            "ms",
        )
        .note(format!(
            "{} closures",
            r.get("values")
                .and_then(|v| v.get("closures"))
                .and_then(Value::as_str)
                .unwrap_or("-")
        )),
    ]
}

fn fleet(dir: &Path, node_bin: &Path, domain: u16) -> Vec<Line> {
    match node_runs(dir, node_bin, domain, true) {
        Ok(runs) if runs.len() == 3 => runs
            .iter()
            .enumerate()
            .map(|(k, r)| {
                Line::new(
                    &format!("fleet_node_cpu_one_core.robot_{k}"),
                    num(r, &["cpu_share"]).map(|s| 100.0 * s),
                    8.0,
                    "%",
                )
                .note(format!(
                    "{:.1} s CPU in {:.1} s",
                    num(r, &["cpu_seconds"]).unwrap_or(f64::NAN),
                    num(r, &["wall_seconds"]).unwrap_or(f64::NAN)
                ))
            })
            .collect(),
        Ok(runs) => vec![
            Line::new("fleet_node_cpu_one_core", None, 8.0, "%")
                .note(format!("{} nodes reported", runs.len())),
        ],
        Err(e) => vec![Line::new("fleet_node_cpu_one_core", None, 8.0, "%").note(e)],
    }
}

/// The soak: resident memory added per map keyframe (its verdict line), and the map file's bytes per
/// keyframe (its last minute's row: map MB, map keyframes).
fn soak(dir: &Path, node_bin: &Path, domain: u16, minutes: u32) -> Vec<Line> {
    let mut c = cargo(&["run", "--release", "--example", "soak", "--"]);
    c.args(["--minutes", &minutes.to_string(), "--rate", "10"])
        .arg("--node")
        .arg(node_bin)
        .arg("--log")
        .arg(dir.join("soak_node.log"))
        .env("ROS_DOMAIN_ID", domain.to_string())
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST");
    let out = match run(c, &dir.join("soak.log")) {
        Ok(o) => o,
        Err(e) => {
            return vec![
                Line::new("memory.rss_per_keyframe", None, 8.0, "KB").note(e.clone()),
                Line::new("memory.file_per_keyframe", None, 8.0, "KB").note(e),
            ];
        }
    };
    // "... -> N MB at minute M; X kB per map keyframe added"
    let rss = out
        .lines()
        .find(|l| l.contains("per map keyframe added"))
        .and_then(|l| {
            l.rsplit_once("; ")?
                .1
                .split_whitespace()
                .next()?
                .parse()
                .ok()
        });
    // The last table row: | minute | drive h | RSS MB | threads | files | map MB | map keyframes | ...
    let last_row: Vec<f64> = out
        .lines()
        .rfind(|l| {
            l.starts_with("| ")
                && l.split('|')
                    .nth(1)
                    .is_some_and(|c| c.trim().parse::<u32>().is_ok())
        })
        .map(|l| l.split('|').filter_map(|c| c.trim().parse().ok()).collect())
        .unwrap_or_default();
    let file = match last_row.as_slice() {
        [_, _, _, _, _, map_mb, keyframes, ..] if *keyframes > 0.0 => {
            Some((map_mb * 1e6 / keyframes / 1024.0, *keyframes))
        }
        _ => None,
    };
    vec![
        Line::new("memory.rss_per_keyframe", rss, 8.0, "KB")
            .note(format!("soak, {minutes} min at 10x")),
        Line::new("memory.file_per_keyframe", file.map(|f| f.0), 8.0, "KB").note(
            file.map_or("no map row".into(), |f| {
                format!("the soak's map file at {} keyframes", f.1)
            }),
        ),
    ]
}

/// The load time of a 100,000-keyframe map (keyframe_db bench; with `quick`, 20,000 scaled up).
fn load(dir: &Path, quick: bool) -> Vec<Line> {
    let size = if quick { 20_000 } else { 100_000 };
    let mut c = cargo(&["bench", "--bench", "keyframe_db"]);
    c.env("DC_LOC_BENCH_SIZES", "10000")
        .env("DC_LOC_BENCH_MAP", size.to_string());
    let out = match run(c, &dir.join("keyframe_db.log")) {
        Ok(o) => o,
        Err(e) => {
            return vec![
                Line::new("load_100000_keyframes", None, 2.0, "s")
                    .below()
                    .note(e),
            ];
        }
    };
    // "map file: N keyframes, X KB per keyframe on disk; save S s, load L s (...)"
    let line = out.lines().find(|l| l.starts_with("map file:"));
    let loaded = line.and_then(|l| {
        let after = l.split("load ").nth(1)?;
        after.split_whitespace().next()?.parse::<f64>().ok()
    });
    let scale = 100_000.0 / size as f64;
    let note = if quick {
        format!(
            "{size} keyframes loaded in {:.2} s, scaled",
            loaded.unwrap_or(f64::NAN)
        )
    } else {
        "keyframe_db bench".into()
    };
    vec![
        Line::new("load_100000_keyframes", loaded.map(|l| l * scale), 2.0, "s")
            .below()
            .note(format!("{note}; {}", line.unwrap_or("no map file line"))),
    ]
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let exe = std::env::current_exe().expect("own path");
    // target/<profile>/examples/budgets -> target/<profile>/dc_loc
    let default_bin = exe
        .parent()
        .and_then(Path::parent)
        .map(|d| d.join("dc_loc"))
        .unwrap_or_else(|| "target/release/dc_loc".into());
    let node_bin = arg("--node").map_or(default_bin, PathBuf::from);
    let venv = arg("--venv")
        .or_else(|| std::env::var("DCLOC_VENV").ok())
        .map_or(repo().join(".venv"), PathBuf::from);
    let domain: u16 = std::env::var("ROS_DOMAIN_ID")
        .ok()
        .and_then(|d| d.parse().ok())
        .unwrap_or(70);
    let dir = std::env::temp_dir().join(format!("dc_loc_budgets_{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("scratch directory");
    let cpus = std::thread::available_parallelism().map_or(0, |n| n.get());
    let load_avg = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    eprintln!(
        "budgets: {} run, node {}, venv {}, logs in {}; {cpus} CPUs, load average {}",
        if quick { "quick" } else { "full" },
        node_bin.display(),
        venv.display(),
        dir.display(),
        load_avg
            .split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    );
    let t0 = Instant::now();
    let mut lines = Vec::new();
    lines.extend(peers(&dir, &node_bin, &venv, quick));
    lines.extend(node(&dir, &node_bin, domain));
    lines.extend(fleet(&dir, &node_bin, domain.saturating_add(1)));
    lines.extend(soak(&dir, &node_bin, domain, if quick { 2 } else { 5 }));
    lines.extend(load(&dir, quick));
    let short = lines.iter().filter(|l| !l.ok()).count();
    for l in &lines {
        l.print();
    }
    println!(
        "# {} budgets, {} OK, {short} SHORT; {:.0} s; logs in {}",
        lines.len(),
        lines.len() - short,
        t0.elapsed().as_secs_f64(),
        dir.display()
    );
}
