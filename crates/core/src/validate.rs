//! Configuration checks shared by every section: [`ConfigError`], [`Range`] and [`Validator`].
//!
//! A config section declares the range of each numeric field once, in its `check` method
//! (`v.positive("distance", self.distance)`). The same declaration refuses a value out of range (the
//! first one found is the error, named by its dotted parameter) and lists every range
//! ([`Validator::ranges`]) for the parameter reference and the ROS 2 parameter descriptors. Nothing is
//! clamped.

use std::fmt;

/// A configuration value that cannot be used, with the dotted parameter name.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid parameter `{name}`: {reason}")]
pub struct ConfigError {
    /// Dotted parameter name, as in the params YAML (e.g. `radars.front.beta`).
    pub name: String,
    /// What is wrong with it.
    pub reason: String,
}

impl ConfigError {
    /// Shorthand constructor.
    pub fn new(name: impl Into<String>, reason: impl Into<String>) -> Self {
        ConfigError {
            name: name.into(),
            reason: reason.into(),
        }
    }
}

/// The values a numeric parameter accepts: finite, between `lo` and `hi` (either may be infinite),
/// each end open or closed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    /// Lower end (`-inf` for none).
    pub lo: f64,
    /// `lo` itself is refused.
    pub lo_open: bool,
    /// Upper end (`inf` for none).
    pub hi: f64,
    /// `hi` itself is refused.
    pub hi_open: bool,
}

impl Range {
    /// `(0, inf)`.
    pub const POSITIVE: Range = Range::above(0.0);
    /// `[0, inf)`.
    pub const NON_NEGATIVE: Range = Range::at_least(0.0);
    /// `[0, 1]`.
    pub const UNIT: Range = Range::closed(0.0, 1.0);
    /// Any finite value.
    pub const FINITE: Range = Range::closed(f64::NEG_INFINITY, f64::INFINITY);

    /// `[lo, hi]`.
    pub const fn closed(lo: f64, hi: f64) -> Self {
        Range {
            lo,
            lo_open: false,
            hi,
            hi_open: false,
        }
    }
    /// `[lo, inf)`.
    pub const fn at_least(lo: f64) -> Self {
        Range::closed(lo, f64::INFINITY)
    }
    /// `(lo, inf)`.
    pub const fn above(lo: f64) -> Self {
        Range {
            lo,
            lo_open: true,
            hi: f64::INFINITY,
            hi_open: false,
        }
    }
    /// The same range with `hi` excluded.
    pub const fn below(self, hi: f64) -> Self {
        Range {
            hi,
            hi_open: true,
            ..self
        }
    }
    /// The same range with `hi` included.
    pub const fn up_to(self, hi: f64) -> Self {
        Range {
            hi,
            hi_open: false,
            ..self
        }
    }

    /// `v` is finite and inside.
    pub fn contains(&self, v: f64) -> bool {
        let lo_ok = if self.lo_open {
            v > self.lo
        } else {
            v >= self.lo
        };
        let hi_ok = if self.hi_open {
            v < self.hi
        } else {
            v <= self.hi
        };
        v.is_finite() && lo_ok && hi_ok
    }
}

impl fmt::Display for Range {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.lo.is_finite(), self.hi.is_finite()) {
            (false, false) => write!(f, "finite"),
            (true, false) => write!(f, "{} {}", if self.lo_open { ">" } else { ">=" }, self.lo),
            (false, true) => write!(f, "{} {}", if self.hi_open { "<" } else { "<=" }, self.hi),
            (true, true) => write!(
                f,
                "in {}{}, {}{}",
                if self.lo_open { "(" } else { "[" },
                self.lo,
                self.hi,
                if self.hi_open { ")" } else { "]" }
            ),
        }
    }
}

/// Walks a configuration: checks each declared value and keeps the first error; when describing, also
/// every range.
#[derive(Debug, Default)]
pub struct Validator {
    prefix: Vec<String>,
    error: Option<ConfigError>,
    describe: bool,
    ranges: Vec<(String, Range)>,
}

impl Validator {
    /// A validator at the root (parameter names as declared).
    pub fn new() -> Self {
        Validator::default()
    }

    /// A validator whose names start with `prefix` (`registration` gives `registration.min_points`).
    pub fn at(prefix: &str) -> Self {
        Validator {
            prefix: vec![prefix.to_string()],
            ..Validator::default()
        }
    }

    /// A validator at the root that also keeps every declared range ([`Validator::ranges`]).
    pub fn describing() -> Self {
        Validator {
            describe: true,
            ..Validator::default()
        }
    }

    /// The dotted name of `field` here.
    pub fn name(&self, field: &str) -> String {
        let mut parts: Vec<&str> = self.prefix.iter().map(String::as_str).collect();
        parts.push(field);
        parts.retain(|p| !p.is_empty());
        parts.join(".")
    }

    /// Checks a nested section under `name`.
    pub fn section(&mut self, name: &str, f: impl FnOnce(&mut Self)) {
        self.prefix.push(name.to_string());
        f(self);
        self.prefix.pop();
    }

    /// `value` must lie in `range`.
    pub fn range(&mut self, field: &str, value: f64, range: Range) {
        if !range.contains(value) {
            let name = self.name(field);
            self.fail(&name, || format!("{value} must be {range}"));
        }
        if self.describe {
            let name = self.name(field);
            self.ranges.push((name, range));
        }
    }

    /// `value` must be finite and > 0.
    pub fn positive(&mut self, field: &str, value: f64) {
        self.range(field, value, Range::POSITIVE);
    }

    /// `value` must be finite and >= 0.
    pub fn non_negative(&mut self, field: &str, value: f64) {
        self.range(field, value, Range::NON_NEGATIVE);
    }

    /// `value` must lie in [0, 1].
    pub fn unit(&mut self, field: &str, value: f64) {
        self.range(field, value, Range::UNIT);
    }

    /// A count: `value` must be at least `min`.
    pub fn at_least(&mut self, field: &str, value: usize, min: usize) {
        self.range(field, value as f64, Range::at_least(min as f64));
    }

    /// A count: `value` must lie in `[min, max]`.
    pub fn count(&mut self, field: &str, value: usize, min: usize, max: usize) {
        self.range(field, value as f64, Range::closed(min as f64, max as f64));
    }

    /// An interval `[lo, hi]` given as two values: `lo` in `lo_range`, `hi` finite and at least `lo`.
    pub fn interval(&mut self, field: &str, value: [f64; 2], lo_range: Range) {
        let [lo, hi] = value;
        let ok = lo_range.contains(lo) && hi.is_finite() && lo <= hi;
        self.require(field, ok, || {
            format!("[{lo}, {hi}] must be finite with lo {lo_range} and lo <= hi")
        });
    }

    /// A rule beyond a range (a relation between fields, a non-empty name): `ok` or the error `reason`.
    pub fn require(&mut self, field: &str, ok: bool, reason: impl FnOnce() -> String) {
        if !ok {
            let name = self.name(field);
            self.fail(&name, reason);
        }
    }

    fn fail(&mut self, name: &str, reason: impl FnOnce() -> String) {
        if self.error.is_none() {
            self.error = Some(ConfigError::new(name, reason()));
        }
    }

    /// Every range declared so far, by dotted name (empty unless [`Validator::describing`]).
    pub fn ranges(&self) -> &[(String, Range)] {
        &self.ranges
    }

    /// The first error, if any.
    pub fn finish(self) -> Result<(), ConfigError> {
        self.error.map_or(Ok(()), Err)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_check_and_describe_themselves() {
        assert!(Range::POSITIVE.contains(1e-9));
        assert!(!Range::POSITIVE.contains(0.0));
        assert!(!Range::POSITIVE.contains(f64::INFINITY));
        assert!(!Range::NON_NEGATIVE.contains(f64::NAN));
        assert!(Range::UNIT.contains(1.0));
        assert!(!Range::at_least(0.0).below(1.0).contains(1.0));
        assert_eq!(Range::POSITIVE.to_string(), "> 0");
        assert_eq!(Range::UNIT.to_string(), "in [0, 1]");
        assert_eq!(Range::at_least(0.0).below(1.0).to_string(), "in [0, 1)");
    }

    #[test]
    fn the_first_error_names_the_parameter_and_every_range_is_kept() {
        let mut v = Validator {
            describe: true,
            ..Validator::at("loop")
        };
        v.positive("search_radius", 15.0);
        v.section("inner", |v| {
            v.unit("share", 1.5);
            v.at_least("count", 0, 1);
        });
        v.require("other", false, || "never reported".into());
        assert_eq!(v.ranges().len(), 3);
        assert_eq!(v.ranges()[1].0, "loop.inner.share");
        let e = v.finish().expect_err("1.5 is out of range");
        assert_eq!(e.name, "loop.inner.share");
        assert_eq!(e.reason, "1.5 must be in [0, 1]");
    }
}
