//! docs/results.md is what the commands print: every table under a `Command:` line is a choice of the
//! lines that command prints, word for word. The demo's tables are checked in every test run; every
//! other command takes minutes to hours and is checked by
//! `cargo test --release --test results -- --ignored`. A table under `Summary of:` condenses a
//! command's output and is not compared.

mod common;

use std::path::Path;

use common::{scratch, text};

/// A table of docs/results.md and the command whose output it copies.
struct Section {
    /// The command as the document gives it (`dc_loc ...` or `cargo ...`).
    command: String,
    /// The table's lines (header and separator included), in order.
    rows: Vec<String>,
    /// Line number of the `Command:` line, for messages.
    line: usize,
}

/// Every `Command:` line with the markdown table that follows it (before the next `Command:` or
/// `Summary of:` line or heading).
fn sections() -> Vec<Section> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/results.md");
    let doc = std::fs::read_to_string(&path).expect("docs/results.md");
    let mut out: Vec<Section> = Vec::new();
    let mut current: Option<Section> = None;
    for (n, line) in doc.lines().enumerate() {
        if let Some(rest) = line.strip_prefix("Command: `") {
            out.extend(current.take());
            let command = rest.strip_suffix('`').expect("a command in backticks");
            current = Some(Section {
                command: command.to_string(),
                rows: Vec::new(),
                line: n + 1,
            });
        } else if line.starts_with("Summary of: ") || line.starts_with('#') {
            out.extend(current.take());
        } else if let Some(s) = current.as_mut()
            && line.starts_with('|')
        {
            s.rows.push(line.to_string());
        }
    }
    out.extend(current);
    out
}

/// The words of a command line, with double quotes grouping (no other shell syntax is used there).
fn words(command: &str) -> Vec<String> {
    let (mut out, mut word, mut quoted) = (Vec::new(), String::new(), false);
    for c in command.chars() {
        match c {
            '"' => quoted = !quoted,
            ' ' if !quoted => {
                if !word.is_empty() {
                    out.push(std::mem::take(&mut word));
                }
            }
            _ => word.push(c),
        }
    }
    if !word.is_empty() {
        out.push(word);
    }
    out
}

/// Runs `dc_loc` with `args` in a scratch directory (commands write `out/...` relative to it) and
/// returns what it printed on stdout.
fn printed(args: &[String], name: &str) -> String {
    let dir = scratch("results", name);
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_dc_loc"))
        .args(args)
        .current_dir(&dir)
        .env("RUST_LOG", "error")
        .output()
        .expect("cannot start dc_loc");
    assert!(
        out.status.success(),
        "dc_loc {}: {}",
        args.join(" "),
        text(&out.stderr)
    );
    text(&out.stdout)
}

/// The rows of `section` that `stdout` does not print, with the section's place.
fn missing(section: &Section, stdout: &str) -> Vec<String> {
    let lines: Vec<&str> = stdout.lines().collect();
    section
        .rows
        .iter()
        .filter(|r| !lines.contains(&r.as_str()))
        .map(|r| {
            format!(
                "docs/results.md:{} `{}`: not printed: {r}",
                section.line, section.command
            )
        })
        .collect()
}

/// Checks every section whose command `select` accepts, running each command once.
fn check(select: impl Fn(&str) -> bool) {
    let all = sections();
    assert!(!all.is_empty(), "docs/results.md has no `Command:` line");
    let mut failures = Vec::new();
    let mut outputs: Vec<(String, String)> = Vec::new();
    for (k, s) in all.iter().enumerate() {
        assert!(
            !s.rows.is_empty(),
            "docs/results.md:{}: no table under `Command: {}`",
            s.line,
            s.command
        );
        if !select(&s.command) {
            continue;
        }
        let w = words(&s.command);
        if w.first().map(String::as_str) != Some("dc_loc") {
            eprintln!("not run here (a test of its own): {}", s.command);
            continue;
        }
        if !outputs.iter().any(|(c, _)| *c == s.command) {
            let stdout = printed(&w[1..], &format!("section{k}"));
            outputs.push((s.command.clone(), stdout));
        }
        let stdout = &outputs.iter().find(|(c, _)| *c == s.command).unwrap().1;
        failures.extend(missing(s, stdout));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn the_demo_tables_are_what_the_demo_prints() {
    check(|c| c == "dc_loc demo");
}

#[test]
#[ignore = "runs every command of docs/results.md: hours on two cores"]
fn every_table_is_what_its_command_prints() {
    check(|c| c != "dc_loc demo");
}

#[test]
fn command_lines_split_into_words() {
    assert_eq!(
        words(r#"dc_loc revisits --set test -p "a:=[1, 2]"  --drift 1"#),
        [
            "dc_loc",
            "revisits",
            "--set",
            "test",
            "-p",
            "a:=[1, 2]",
            "--drift",
            "1"
        ]
    );
}
