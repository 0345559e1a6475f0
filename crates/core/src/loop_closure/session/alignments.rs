//! A session's alignments to other sessions ([`Alignments`]): the accepted ones, which the closures
//! the session publishes set, and the shared ones, which other robots' nodes accepted to this
//! session and send. An accepted alignment vouches for a closure alone while it is fresh
//! ([`vouches`]), and a search again may stand another in its place for a while
//! ([`Alignments::swap_in`]).

use std::collections::BTreeMap;

use super::super::LoopConfig;
use super::super::drift::vouches;
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

    /// The accepted alignment to `session` is fresh enough at `path` to vouch for a closure alone.
    pub(super) fn vouches_for(&self, session: u32, path: f64, lc: &LoopConfig) -> bool {
        self.accepted
            .get(&session)
            .is_some_and(|a| vouches(path - a.path, lc))
    }

    /// Some accepted alignment is fresh enough at `path` to vouch for a closure alone.
    pub(super) fn any_vouches(&self, path: f64, lc: &LoopConfig) -> bool {
        self.accepted.values().any(|a| vouches(path - a.path, lc))
    }

    /// `alignment` is the accepted alignment to `session` now.
    pub(super) fn accept(&mut self, session: u32, alignment: Alignment) {
        self.accepted.insert(session, alignment);
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
