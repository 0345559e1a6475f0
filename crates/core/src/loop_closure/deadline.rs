//! A time limit on the revisit search one input sets off (the node's `node.keyframe_budget`). Once it
//! has passed, the loop closer leaves work out in a fixed order rather than finish late: first the
//! searches again of older keyframes (`loop.backfill_per_keyframe`; they stay queued for a later
//! input), then the rounds of candidates after the first (the next-nearest keyframes), then, when
//! the limit had passed before the search began, every candidate of the first round but the
//! best-ranked one. The new keyframe is thus always registered against its best candidate. What was
//! left out is counted ([`Trimmed`]). Without a limit (the offline runs) nothing is left out.

use std::time::Instant;

/// When the current input's search should have ended.
#[derive(Debug, Default, Clone, Copy)]
pub struct Deadline(Option<Instant>);

impl Deadline {
    /// A limit at `at` (`None`: no limit).
    pub fn new(at: Option<Instant>) -> Self {
        Deadline(at)
    }

    /// Whether the limit has passed.
    pub fn passed(&self) -> bool {
        self.0.is_some_and(|at| Instant::now() >= at)
    }
}

/// What the loop closer left out because the deadline had passed.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Trimmed {
    /// Inputs whose searches again of older keyframes were put off (what was queued stays queued).
    pub backfill: u64,
    /// Rounds of candidates after the first not registered.
    pub rounds: u64,
    /// Candidates of a first round not registered (all but its best-ranked one).
    pub candidates: u64,
}

impl Trimmed {
    /// Adds `other`'s counts.
    pub fn add(&mut self, other: Trimmed) {
        self.backfill += other.backfill;
        self.rounds += other.rounds;
        self.candidates += other.candidates;
    }

    /// Whether anything was left out.
    pub fn any(&self) -> bool {
        *self != Trimmed::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn a_deadline_passes_only_when_set_and_reached() {
        assert!(!Deadline::default().passed());
        let now = Instant::now();
        assert!(Deadline::new(Some(now)).passed());
        assert!(!Deadline::new(Some(now + Duration::from_secs(60))).passed());
        let mut t = Trimmed::default();
        assert!(!t.any());
        t.add(Trimmed {
            backfill: 1,
            rounds: 2,
            candidates: 3,
        });
        assert_eq!((t.backfill, t.rounds, t.candidates), (1, 2, 3));
        assert!(t.any());
    }
}
