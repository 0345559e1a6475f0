//! Bad input told once per cause: [`Repeats`] counts the occurrences of each cause (a reason and what
//! it concerns: a radar, a topic, a frame) and says which one to log in full, the first. A
//! misconfiguration repeats with every message (a wrong field name, a wrong `frame_id`); it so gives
//! one line with the details, then a counter, not one line a message. The pipeline's dropped inputs
//! ([`crate::pipeline::Event::Dropped`]) and the sources' skipped messages
//! ([`crate::input::InputIssue`], through [`crate::runner`]) are both told this way, in the node,
//! `dc_loc run` and `dc_loc eval` alike.

use std::collections::BTreeMap;

/// Most distinct causes counted one by one; later new causes are counted together under
/// [`OTHER_CAUSES`], so that input that varies with every message cannot grow the map without bound.
pub const MAX_CAUSES: usize = 64;

/// The cause that counts the new causes beyond [`MAX_CAUSES`].
pub const OTHER_CAUSES: &str = "other causes";

/// Occurrences per cause.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Repeats {
    counts: BTreeMap<String, u64>,
}

impl Repeats {
    /// Counts one occurrence of `cause`; true for its first one (to be logged in full then).
    pub fn first(&mut self, cause: &str) -> bool {
        if let Some(n) = self.counts.get_mut(cause) {
            *n += 1;
            return false;
        }
        let key = if self.counts.len() < MAX_CAUSES {
            cause
        } else {
            OTHER_CAUSES
        };
        let n = self.counts.entry(key.to_string()).or_default();
        *n += 1;
        *n == 1
    }

    /// Occurrences per cause.
    pub fn counts(&self) -> &BTreeMap<String, u64> {
        &self.counts
    }

    /// Logs `message` under the log target `target` (the caller's module, so that log filters apply
    /// as to its other records) at `warn` for the first occurrence of `cause`, saying that the others
    /// are only counted, and at `debug` for the others.
    pub fn warn_first(&mut self, target: &str, cause: &str, message: &str) {
        if self.first(cause) {
            log::warn!(target: target, "{message} (told once: further ones of this cause are only counted)");
        } else {
            log::debug!(target: target, "{message}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_of_each_cause_is_told_and_all_are_counted() {
        let mut r = Repeats::default();
        assert!(r.first("bad_cloud: radar `front`"));
        assert!(!r.first("bad_cloud: radar `front`"));
        assert!(r.first("bad_cloud: radar `rear`"));
        assert!(!r.first("bad_cloud: radar `front`"));
        assert_eq!(r.counts()["bad_cloud: radar `front`"], 3);
        assert_eq!(r.counts()["bad_cloud: radar `rear`"], 1);
    }

    #[test]
    fn causes_beyond_the_bound_are_counted_together() {
        let mut r = Repeats::default();
        for i in 0..MAX_CAUSES {
            assert!(r.first(&format!("cause {i}")));
        }
        assert!(r.first("one more"), "the first beyond the bound is told");
        assert!(!r.first("and another"));
        assert_eq!(r.counts().len(), MAX_CAUSES + 1);
        assert_eq!(r.counts()[OTHER_CAUSES], 2);
    }
}
