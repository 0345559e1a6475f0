//! A session's alignments to other sessions ([`Alignments`]): the accepted ones, which the closures
//! the session publishes set, and the shared ones, which other robots' nodes accepted to this
//! session and send. An accepted alignment is Vouching or Stale at a path length
//! ([`vouching`]) and ends Replaced or Overturned when a newer closure's alignment takes its
//! place ([`Alignments::accept`]); a search again may stand another in its place for a while
//! ([`Alignments::swap_in`]).

use std::collections::BTreeMap;

use super::super::LoopConfig;
use super::super::decision::{AlignmentState, vouching};
use crate::math::Iso2;

/// An accepted alignment of this session's odometry frame into an earlier session's frame, and the
/// path lengths of the two keyframes the closure that gave it joined.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    /// This session's odometry frame in the other session's frame.
    pub t: Iso2,
    /// Path length at which it was found (its query keyframe's), m of this session's odometry.
    pub path: f64,
    /// Path length of its match keyframe, m of the other session's odometry.
    pub match_path: f64,
}

impl Alignment {
    /// The same closure seen from the other session: that session's frame in this one's, the two
    /// path lengths swapped.
    pub fn inverse(&self) -> Alignment {
        Alignment {
            t: self.t.inverse(),
            path: self.match_path,
            match_path: self.path,
        }
    }
}

#[cfg(test)]
impl Alignment {
    /// The alignment `t` found at `path` metres, its match keyframe as far along the other pass.
    pub(crate) fn along_one_pass(t: Iso2, path: f64) -> Self {
        Alignment {
            t,
            path,
            match_path: path,
        }
    }
}

/// The accepted and the shared alignments, by session.
#[derive(Debug, Clone, Default)]
pub(super) struct Alignments {
    /// Per earlier session: the latest accepted alignment.
    accepted: BTreeMap<u32, Alignment>,
    /// Per other robot's session: the latest alignment that robot's node accepted to this session,
    /// inverted (this session's frame in that one's).
    shared: BTreeMap<u32, Alignment>,
}

impl Alignments {
    /// The accepted alignments, by session.
    pub(super) fn accepted(&self) -> &BTreeMap<u32, Alignment> {
        &self.accepted
    }

    /// The shared alignments, by session.
    pub(super) fn shared(&self) -> &BTreeMap<u32, Alignment> {
        &self.shared
    }

    /// The state of the accepted alignment to `session` at path length `path`:
    /// [`AlignmentState::Vouching`] or [`AlignmentState::Stale`] ([`vouching`]); `None` without one.
    pub(super) fn state(&self, session: u32, path: f64, lc: &LoopConfig) -> Option<AlignmentState> {
        self.accepted.get(&session).map(|a| {
            if vouching(a, path, lc) {
                AlignmentState::Vouching
            } else {
                AlignmentState::Stale
            }
        })
    }

    /// Some accepted alignment is fresh enough at `path` to vouch for a closure alone
    /// ([`vouching`]).
    pub(super) fn any_vouching(&self, path: f64, lc: &LoopConfig) -> bool {
        self.accepted.values().any(|a| vouching(a, path, lc))
    }

    /// `alignment`, a published closure's, is the accepted alignment to `session` now; the state the
    /// one it replaces ends in: [`AlignmentState::Overturned`] when the closure [`overturns`] it,
    /// else [`AlignmentState::Replaced`] (`None`: there was none).
    ///
    /// [`overturns`]: super::super::decision::overturns
    pub(super) fn accept(
        &mut self,
        session: u32,
        alignment: Alignment,
        overturns: bool,
    ) -> Option<AlignmentState> {
        let before = self.accepted.insert(session, alignment)?;
        if !overturns {
            return Some(AlignmentState::Replaced);
        }
        log::debug!(
            "the accepted alignment to session {session} ({:.2} {:.2} {:.3}, found at {:.0} m) overturned at {:.0} m",
            before.t.translation.x,
            before.t.translation.y,
            before.t.rotation.angle(),
            before.path,
            alignment.path
        );
        Some(AlignmentState::Overturned)
    }

    /// Keeps `alignment` as the one `session`'s robot accepted to this session; whether it is the
    /// first from that robot.
    pub(super) fn share(&mut self, session: u32, alignment: Alignment) -> bool {
        self.shared.insert(session, alignment).is_none()
    }

    /// Puts `a` in place of the accepted alignment to `session`; returns the one it stands in for.
    pub(super) fn swap_in(&mut self, session: u32, a: Alignment) -> Option<Alignment> {
        self.accepted.insert(session, a)
    }

    /// Undoes [`Alignments::swap_in`]: `before` is the accepted alignment to `session` again.
    pub(super) fn restore(&mut self, session: u32, before: Option<Alignment>) {
        match before {
            Some(v) => self.accepted.insert(session, v),
            None => self.accepted.remove(&session),
        };
    }
}
