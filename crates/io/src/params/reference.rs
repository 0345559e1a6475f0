//! The parameter reference, from the code itself: every parameter with its type, default, accepted
//! values and description. Names and defaults come from [`Config::default`] and
//! [`NodeSettings::default`], ranges from the sections' `check` declarations ([`Validator`]),
//! descriptions from the config fields' doc comments (through their JSON schema, `schemars`) and
//! [`NODE_PARAMS`]. `dc_loc params` prints it; README_NODE.md (setup and tuning) and docs/parameters.md
//! (the rest) carry it, and a test keeps them equal.

use std::collections::BTreeMap;
use std::fmt::Write;

use serde_json::Value;

use super::live::is_live;
use super::node::{LOG_LEVELS, NODE_PARAMS, NodeSettings, all_params};
use super::tiers::{Tier, generic_name, guidance, tier};
use dc_loc_core::pipeline::Config;
use dc_loc_core::validate::{Range, Validator};

/// One parameter as the reference lists it.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamDoc {
    /// Dotted name; per-radar parameters as `radars.<name>.field`.
    pub name: String,
    /// Default value.
    pub default: Value,
    /// Accepted values of a number (`None` for other types).
    pub range: Option<Range>,
    /// The values an enumerated string takes (empty for other types).
    pub choices: Vec<String>,
    /// What it does.
    pub description: String,
    /// It may change while the node runs ([`super::live`]).
    pub live: bool,
    /// Who it is for ([`super::tiers`]).
    pub tier: Tier,
}

/// Every parameter of the node, sorted by name.
pub fn reference() -> Vec<ParamDoc> {
    let cfg = Config::default();
    let settings = NodeSettings::default();
    let mut v = Validator::describing();
    cfg.check(&mut v);
    settings.check(&mut v);
    let ranges: BTreeMap<String, Range> = v
        .ranges()
        .iter()
        .map(|(n, r)| (generic_name(n), *r))
        .collect();
    let mut described = Described::default();
    let schema = schemars::schema_for!(Config);
    described.walk(schema.as_value(), "", schema.as_value());
    for p in NODE_PARAMS {
        described.text.insert(p.name.to_string(), p.doc.to_string());
    }
    let levels = LOG_LEVELS.iter().map(|l| l.to_string()).collect();
    described.choices.insert("node.log_level".into(), levels);
    all_params(&cfg, &settings)
        .into_iter()
        .map(|(name, default)| {
            let name = generic_name(&name);
            ParamDoc {
                range: ranges.get(&name).copied(),
                choices: described.choices.get(&name).cloned().unwrap_or_default(),
                description: described.text.get(&name).cloned().unwrap_or_default(),
                live: is_live(&name),
                tier: tier(&name),
                default,
                name,
            }
        })
        .collect()
}

/// Descriptions and choices by parameter name, read off the configuration's JSON schema.
#[derive(Default)]
struct Described {
    text: BTreeMap<String, String>,
    choices: BTreeMap<String, Vec<String>>,
    /// Section descriptions (the section structs' own doc comments).
    sections: BTreeMap<String, String>,
}

impl Described {
    fn walk(&mut self, schema: &Value, prefix: &str, root: &Value) {
        let resolved = resolve(schema, root);
        if !prefix.is_empty()
            && let Some(d) = resolved.get("description").and_then(Value::as_str)
            && resolved.get("properties").is_some()
        {
            self.sections.insert(prefix.to_string(), tidy(d));
        }
        let choices = choices(resolved);
        if !choices.is_empty() {
            self.choices.insert(prefix.to_string(), choices);
        }
        if let Some(props) = resolved.get("properties").and_then(Value::as_object) {
            for (key, sub) in props {
                let name = join(prefix, key);
                if let Some(d) = sub.get("description").and_then(Value::as_str) {
                    self.text.insert(name.clone(), tidy(d));
                }
                self.walk(sub, &name, root);
            }
        }
        if let Some(each) = resolved
            .get("additionalProperties")
            .filter(|v| v.is_object())
        {
            self.walk(each, &join(prefix, "<name>"), root);
        }
    }
}

fn join(prefix: &str, key: &str) -> String {
    if prefix.is_empty() {
        key.to_string()
    } else {
        format!("{prefix}.{key}")
    }
}

/// The schema a `$ref` (possibly inside `allOf`) points to, else `schema`.
fn resolve<'a>(schema: &'a Value, root: &'a Value) -> &'a Value {
    let reference = schema.get("$ref").and_then(Value::as_str).or_else(|| {
        schema
            .get("allOf")
            .and_then(Value::as_array)
            .and_then(|a| a.first())
            .and_then(|s| s.get("$ref"))
            .and_then(Value::as_str)
    });
    match reference.and_then(|r| r.strip_prefix("#/")) {
        Some(path) => path
            .split('/')
            .try_fold(root, |node, part| node.get(part))
            .unwrap_or(schema),
        None => schema,
    }
}

/// The string values an enum schema allows (`enum`, or `oneOf` of constants).
fn choices(schema: &Value) -> Vec<String> {
    let strings = |a: &Vec<Value>| -> Vec<String> {
        a.iter()
            .filter_map(Value::as_str)
            .map(str::to_string)
            .collect()
    };
    if let Some(a) = schema.get("enum").and_then(Value::as_array) {
        return strings(a);
    }
    schema
        .get("oneOf")
        .and_then(Value::as_array)
        .map(|variants| {
            variants
                .iter()
                .flat_map(|v| {
                    v.get("const")
                        .and_then(Value::as_str)
                        .map(|s| vec![s.to_string()])
                        .or_else(|| v.get("enum").and_then(Value::as_array).map(strings))
                        .unwrap_or_default()
                })
                .collect()
        })
        .unwrap_or_default()
}

/// A doc comment as one paragraph of Markdown: lines joined, rustdoc links as plain code.
fn tidy(doc: &str) -> String {
    let joined = doc.split_whitespace().collect::<Vec<_>>().join(" ");
    let mut out = String::with_capacity(joined.len());
    let mut rest = joined.as_str();
    while let Some(i) = rest.find("[`") {
        out.push_str(&rest[..i]);
        let after = &rest[i + 1..];
        match after.find("`]") {
            Some(j) if !after[j + 2..].starts_with('(') => {
                out.push_str(&after[..j + 1]);
                rest = &after[j + 2..];
            }
            _ => {
                out.push('[');
                rest = after;
            }
        }
    }
    out.push_str(rest);
    out
}

/// A value as the reference shows it (YAML flow style).
fn shown(v: &Value) -> String {
    match v {
        Value::String(s) => format!("`\"{s}\"`"),
        Value::Array(a) => {
            let items: Vec<String> = a.iter().map(|x| x.to_string()).collect();
            format!("`[{}]`", items.join(", "))
        }
        other => format!("`{other}`"),
    }
}

fn type_of(v: &Value) -> &'static str {
    match v {
        Value::Bool(_) => "bool",
        Value::Number(n) if n.is_f64() => "double",
        Value::Number(_) => "integer",
        Value::String(_) => "string",
        Value::Array(a) if a.first().is_some_and(Value::is_string) => "string list",
        Value::Array(a) if a.first().is_some_and(|x| x.is_f64()) => "double list",
        Value::Array(_) => "list",
        _ => "",
    }
}

fn accepted(p: &ParamDoc) -> String {
    if let Some(r) = p.range {
        return r.to_string();
    }
    if !p.choices.is_empty() {
        let c: Vec<String> = p
            .choices
            .iter()
            .map(|c| {
                if c.is_empty() {
                    "`\"\"`".into()
                } else {
                    format!("`{c}`")
                }
            })
            .collect();
        return c.join(", ");
    }
    String::new()
}

/// The top-level section of a parameter (`radars.<name>` for the per-radar ones).
fn section_of(name: &str) -> &str {
    if name.starts_with("radars.<name>.") {
        return "radars.<name>";
    }
    match name.split_once('.') {
        Some((s, _)) => s,
        None => "",
    }
}

/// The user-facing reference as Markdown: the sensor setup, then the tuning knobs with their guidance.
pub fn markdown(params: &[ParamDoc]) -> String {
    let mut out = String::new();
    let header = "| parameter | type | default | accepts | live | description |";
    for (tier, title, intro) in [
        (
            Tier::Setup,
            "Sensor setup",
            "What your robot is: set these to describe it.",
        ),
        (
            Tier::Tuning,
            "Tuning knobs",
            "The defaults serve the radars and worlds tested; the last column says when to turn one.",
        ),
    ] {
        let _ = writeln!(out, "#### {title}\n\n{intro}\n");
        let guided = tier == Tier::Tuning;
        out.push_str(header);
        out.push_str(if guided {
            " when to change it |\n|---|---|---|---|---|---|---|\n"
        } else {
            "\n|---|---|---|---|---|---|\n"
        });
        for p in params.iter().filter(|p| p.tier == tier) {
            out.push_str(&row(p));
            if guided {
                let _ = write!(out, " {} |", guidance(&p.name).replace('|', "\\|"));
            }
            out.push('\n');
        }
        out.push('\n');
    }
    out
}

/// The internal constants and operational limits as Markdown: one table per section.
pub fn markdown_internal(params: &[ParamDoc]) -> String {
    let mut sections = Described::default();
    let schema = schemars::schema_for!(Config);
    sections.walk(schema.as_value(), "", schema.as_value());
    sections.sections.insert(
        "node".into(),
        "The node's own settings (not used by the offline tools, except the cloud size limits)."
            .into(),
    );
    let mut by_section: BTreeMap<&str, Vec<&ParamDoc>> = BTreeMap::new();
    for p in params.iter().filter(|p| p.tier == Tier::Internal) {
        by_section.entry(section_of(&p.name)).or_default().push(p);
    }
    let mut out = String::new();
    for (section, params) in by_section {
        let title = if section.is_empty() {
            "top level"
        } else {
            section
        };
        let _ = writeln!(out, "#### `{title}`\n");
        if let Some(d) = sections.sections.get(section) {
            let _ = writeln!(out, "{d}\n");
        }
        out.push_str("| parameter | type | default | accepts | live | description |\n");
        out.push_str("|---|---|---|---|---|---|\n");
        for p in params {
            out.push_str(&row(p));
            out.push('\n');
        }
        out.push('\n');
    }
    out
}

/// One table row, without its line end.
fn row(p: &ParamDoc) -> String {
    format!(
        "| `{}` | {} | {} | {} | {} | {} |",
        p.name,
        type_of(&p.default),
        shown(&p.default),
        accepted(p).replace('|', "\\|"),
        if p.live { "yes" } else { "" },
        p.description.replace('|', "\\|")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn doc_comments_become_one_paragraph_without_rustdoc_links() {
        assert_eq!(
            tidy("Uses [`Rounds::Accelerated`]\n  rounds, see [the paper](x)."),
            "Uses `Rounds::Accelerated` rounds, see [the paper](x)."
        );
    }

    #[test]
    fn every_parameter_has_a_description_and_every_number_a_range() {
        let reference = reference();
        assert!(reference.len() > 120, "{} parameters", reference.len());
        let mut missing = Vec::new();
        for p in &reference {
            if p.description.is_empty() {
                missing.push(format!("{}: no description", p.name));
            }
            if p.default.is_number() && p.range.is_none() {
                missing.push(format!("{}: no declared range", p.name));
            }
        }
        assert!(missing.is_empty(), "{}", missing.join("\n"));
    }

    #[test]
    fn enumerations_list_their_choices() {
        let reference = reference();
        let kind = reference
            .iter()
            .find(|p| p.name == "registration.lm.robust.kind")
            .expect("registration.lm.robust.kind");
        assert!(kind.choices.iter().any(|c| c == "cauchy"), "{kind:?}");
    }
}
