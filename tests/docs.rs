//! The documentation keeps up with the code: every parameter of the configuration tree is documented in
//! README_NODE.md as `name` (type, default), with the default the code has.

use dc_loc::params::flatten_config;
use dc_loc::pipeline::Config;

#[test]
fn every_parameter_is_documented_with_its_default() {
    let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README_NODE.md"))
        .expect("README_NODE.md");
    let mut missing = Vec::new();
    for (name, value) in flatten_config(&Config::default()) {
        // Per-radar parameters are documented once, as `radars.<name>.*`.
        let name = match name.strip_prefix("radars.") {
            Some(rest) => match rest.split_once('.') {
                Some((_, field)) => format!("radars.<name>.{field}"),
                None => continue,
            },
            None => name,
        };
        let line = doc
            .lines()
            .find(|l| l.starts_with(&format!("- `{name}` (")) && l.contains("default: "));
        let Some(l) = line else {
            missing.push(format!("{name}: not documented"));
            continue;
        };
        // The documented default, read as YAML, equals the code's (numbers compared as numbers).
        let documented = l
            .split_once("default: ")
            .and_then(|(_, rest)| rest.split_once(") - "))
            .map(|(d, _)| d.to_string())
            .unwrap_or_default();
        let parsed: Result<serde_json::Value, _> = yaml_serde::from_str(&documented);
        let same = match (&parsed, &value) {
            (Ok(serde_json::Value::Number(a)), serde_json::Value::Number(b)) => {
                a.as_f64() == b.as_f64()
            }
            (Ok(serde_json::Value::Array(a)), serde_json::Value::Array(b)) => {
                a.len() == b.len()
                    && a.iter()
                        .zip(b)
                        .all(|(x, y)| x == y || x.as_f64().is_some_and(|x| Some(x) == y.as_f64()))
            }
            (Ok(a), b) => a == b,
            (Err(_), _) => false,
        };
        if !same {
            missing.push(format!(
                "{name}: default {value} but documented `{documented}`"
            ));
        }
    }
    assert!(
        missing.is_empty(),
        "README_NODE.md is behind the code:\n{}",
        missing.join("\n")
    );
}

/// The Rust version the crate declares (and README.md names) is the newest any locked dependency needs.
#[test]
fn msrv_is_what_the_locked_crates_need() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let lock = std::fs::read_to_string(root.join("Cargo.lock")).expect("Cargo.lock");
    let home = std::env::var_os("CARGO_HOME")
        .map(std::path::PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| std::path::PathBuf::from(h).join(".cargo")))
        .expect("CARGO_HOME or HOME");
    let registries: Vec<_> = std::fs::read_dir(home.join("registry/src"))
        .expect("the registry sources (cargo fetched them to build this test)")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    let version = |s: &str| -> Vec<u32> { s.split('.').filter_map(|p| p.parse().ok()).collect() };
    let field = |text: &str, key: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(&format!("{key} = \"")))
            .and_then(|v| v.strip_suffix('"'))
            .map(str::to_string)
    };
    let (mut newest, mut who, mut read) = (Vec::new(), String::new(), 0);
    for block in lock.split("[[package]]").skip(1) {
        let (Some(name), Some(ver)) = (field(block, "name"), field(block, "version")) else {
            continue;
        };
        let Some(manifest) = registries
            .iter()
            .map(|r| r.join(format!("{name}-{ver}/Cargo.toml")))
            .find(|p| p.is_file())
        else {
            continue;
        };
        read += 1;
        let text = std::fs::read_to_string(&manifest).unwrap_or_default();
        if let Some(rv) = field(&text, "rust-version")
            && version(&rv) > newest
        {
            newest = version(&rv);
            who = format!("{name} {ver}");
        }
    }
    assert!(read > 50, "only {read} locked crates found in the registry");
    let msrv = newest
        .iter()
        .take(2)
        .map(u32::to_string)
        .collect::<Vec<_>>()
        .join(".");
    let manifest = std::fs::read_to_string(root.join("Cargo.toml")).expect("Cargo.toml");
    assert_eq!(
        field(&manifest, "rust-version").map(|v| version(&v)[..2].to_vec()),
        Some(newest[..2].to_vec()),
        "Cargo.toml's rust-version should be {msrv} ({who} needs it)"
    );
    let readme = std::fs::read_to_string(root.join("README.md")).expect("README.md");
    assert!(
        readme.contains(&format!("Rust {msrv} or newer")),
        "README.md should say `Rust {msrv} or newer` ({who} needs it)"
    );
}

/// Code comments and documents say what is, not how it came to be.
#[test]
fn no_development_history_in_code_or_docs() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let forbidden = [
        "measured while building",
        "no switch left",
        "not kept in the code",
        "this round",
        "previous round",
        "previous session",
        // The method and formats pages are referred to by what they hold, not by file name.
        "method.md",
        "formats.md",
    ];
    let mut files = Vec::new();
    let mut stack = vec![root.join("src"), root.join("docs")];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                files.push(p);
            }
        }
    }
    for f in std::fs::read_dir(&root).expect("root").flatten() {
        let name = f.file_name().to_string_lossy().into_owned();
        if name.starts_with("README") && name.ends_with(".md") {
            files.push(f.path());
        }
    }
    let issue = |l: &str| {
        let lower = l.to_ascii_lowercase();
        lower.match_indices("issue ").any(|(i, _)| {
            lower[i + 6..]
                .chars()
                .next()
                .is_some_and(|c| c.is_ascii_digit())
        })
    };
    let mut found = Vec::new();
    for f in files {
        let Ok(text) = std::fs::read_to_string(&f) else {
            continue;
        };
        for (n, l) in text.lines().enumerate() {
            let lower = l.to_ascii_lowercase();
            let hit = forbidden.iter().any(|w| lower.contains(w)) || issue(l);
            if hit {
                found.push(format!("{}:{}: {l}", f.display(), n + 1));
            }
        }
    }
    assert!(
        found.is_empty(),
        "development history:\n{}",
        found.join("\n")
    );
}
