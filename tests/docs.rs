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
