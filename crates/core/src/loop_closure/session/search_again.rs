//! The keyframes searched again ([`SearchAgain`]): this session's recent keyframes without a
//! closure, the queue a confirmation fills with them (walking away from the confirming keyframe,
//! forward then back), the chain of alignments they are searched around and the confirmed
//! closures' anchors, and the walks over keyframes without a closure for closures to another
//! robot's session.

use std::collections::VecDeque;

use super::super::drift::vouches;
use super::super::{LoopClosure, LoopConfig};
use super::{Alignment, QueryPlace};

/// Keyframes queued to be searched again, in the order they are searched: (id, path length).
type Queue = VecDeque<(u64, f64)>;

/// What is searched again, and around which alignment.
#[derive(Debug, Clone, Default)]
pub(super) struct SearchAgain {
    /// This session's keyframes of the last `loop.backfill_horizon` metres without a published
    /// closure (id, path length).
    unclosed: VecDeque<(u64, f64)>,
    /// Keyframes queued to be searched again, each further along the path from the confirmation
    /// than the one before: those made after the confirming keyframe, oldest first (there are some
    /// only when it was an older keyframe searched around a shared alignment), then `behind`.
    backfill: Queue,
    /// The keyframes made before the confirming keyframe, newest first, and the confirmation's
    /// alignment (its session) that the chain starts from again when `backfill` is done with.
    behind: Option<(Queue, (u32, Alignment))>,
    /// The alignment the queued keyframes are searched around (its session): the confirmation's,
    /// then each closure those searches publish.
    chain: Option<(u32, Alignment)>,
    /// The alignments of the closures the confirmation published: a queued keyframe where the
    /// chain's is no longer fresh is searched around the one found nearest to it along the path.
    anchors: Vec<Alignment>,
    /// Keyframes without a closure to search as new keyframes are, for closures to a session (its
    /// number first) that are held until others agree ([`SearchAgain::next_walk`]): those left when
    /// a shared alignment to a session arrives before this session has one of its own
    /// ([`SearchAgain::walk_unclosed`]), and those a search again to another robot's session leaves
    /// where no alignment is fresh enough ([`SearchAgain::walk_gone_stale`]).
    walks: VecDeque<(u32, VecDeque<u64>)>,
}

impl SearchAgain {
    /// The alignment the queued keyframes are searched around, and its session.
    #[cfg(test)]
    pub(super) fn chain(&self) -> Option<(u32, Alignment)> {
        self.chain
    }

    /// A new keyframe of this session at `path`: it has no closure yet (keyframes farther back than
    /// `horizon` are forgotten).
    pub(super) fn note_keyframe(&mut self, id: u64, path: f64, horizon: f64) {
        self.unclosed.retain(|&(_, p)| path - p <= horizon);
        self.unclosed.push_back((id, path));
    }

    /// `c` was published: its query keyframe has a closure.
    pub(super) fn published(&mut self, c: &LoopClosure) {
        self.unclosed.retain(|&(id, _)| id != c.query_id);
    }

    /// A walk over the keyframes without a closure, newest first, for closures to `session`.
    pub(super) fn walk_unclosed(&mut self, session: u32) {
        let unclosed = self.unclosed.iter().rev().map(|&(id, _)| id).collect();
        self.walks.push_back((session, unclosed));
    }

    /// Closures to `session` were confirmed at `query` (`publish`, the alignment `alignment`, the
    /// confirmed closures' alignments `anchors`): the keyframes that got nothing are queued to be
    /// searched again around the chain that starts from `alignment`.
    pub(super) fn confirmed(
        &mut self,
        (session, alignment): (u32, Alignment),
        anchors: Vec<Alignment>,
        query: &QueryPlace,
        publish: &[LoopClosure],
        lc: &LoopConfig,
    ) {
        self.anchors = anchors;
        self.chain = Some((session, alignment));
        self.queue_unclosed(query, publish, lc);
    }

    /// Queues the keyframes that got nothing to be searched again after a confirmation at `query`
    /// (not even at the end of a bag when `backfill_per_keyframe` is 0), walking away from it: those
    /// made after it forward, then those before it back; `query` and the confirmed closures' query
    /// keyframes are done. Each walk follows its own chain of alignments from the confirmation's.
    fn queue_unclosed(&mut self, query: &QueryPlace, publish: &[LoopClosure], lc: &LoopConfig) {
        let unclosed = std::mem::take(&mut self.unclosed);
        self.backfill.clear();
        self.behind = None;
        if lc.backfill_per_keyframe == 0 {
            return;
        }
        let done = |id: u64| id == query.id || publish.iter().any(|p| p.query_id == id);
        let open: Vec<(u64, f64)> = unclosed.into_iter().filter(|&(id, _)| !done(id)).collect();
        let (after, before): (Vec<_>, Vec<_>) = open.iter().partition(|&&(_, p)| p > query.path);
        self.backfill = after.into_iter().copied().collect();
        let behind = before.into_iter().rev().copied().collect();
        self.behind = self.chain.map(|chain| (behind, chain));
    }

    /// The next keyframe to search again, if any. The walk back from the confirmation starts
    /// from the confirmation's alignment again.
    pub(super) fn next_backfill(&mut self) -> Option<u64> {
        if self.backfill.is_empty() {
            let (behind, chain) = self.behind.take()?;
            self.backfill = behind;
            self.chain = Some(chain);
        }
        self.backfill.pop_front().map(|(id, _)| id)
    }

    /// Keyframes queued to be searched again on the present walk away from the confirmation.
    pub(super) fn backfill_len(&self) -> usize {
        self.backfill.len()
    }

    /// No alignment is fresh enough at keyframe `id` (path length `path`), just taken from the search
    /// again's present walk away from the confirmation. When the chain's session is another robot's
    /// (`another_robot`), it and the rest of that walk go back to the keyframes without a closure and
    /// are searched as new keyframes are, for closures to that session that are held until others
    /// agree ([`SearchAgain::next_walk`]): two robots driving at once can pass the same places for
    /// kilometres before the first confirmation between them. Otherwise the rest of the walk is
    /// dropped: one robot's keyframes beyond lie before its revisit began, and searched around an
    /// alignment that no longer vouches they find places that repeat along its own route.
    pub(super) fn walk_gone_stale(
        &mut self,
        id: u64,
        path: f64,
        another_robot: impl Fn(u32) -> bool,
    ) {
        let mut rest = std::mem::take(&mut self.backfill);
        rest.push_front((id, path));
        let Some((session, _)) = self.chain.filter(|&(s, _)| another_robot(s)) else {
            return;
        };
        self.walks
            .push_back((session, rest.iter().map(|&(id, _)| id).collect()));
        self.unclosed.extend(rest);
        self.unclosed
            .make_contiguous()
            .sort_by(|a, b| a.1.total_cmp(&b.1));
    }

    /// The next keyframe to search as a new keyframe is, and the session its closure must go to
    /// (the walks): one that still has no closure. A confirmation queues the keyframes
    /// without a closure to be searched again, which ends the walks over them.
    pub(super) fn next_walk(&mut self) -> Option<(u32, u64)> {
        while let Some((session, ids)) = self.walks.front_mut() {
            match ids.pop_front() {
                Some(id) if self.unclosed.iter().any(|&(u, _)| u == id) => {
                    return Some((*session, id));
                }
                Some(_) => {}
                None => {
                    self.walks.pop_front();
                }
            }
        }
        None
    }

    /// A closure published by a search again moves the chain to the alignment it implies.
    pub(super) fn extend_chain(&mut self, session: u32, alignment: Alignment) {
        if self.chain.is_some_and(|(s, _)| s != session) {
            self.anchors.clear();
        }
        self.chain = Some((session, alignment));
    }

    /// The alignment a keyframe at `path` is searched again around, and its session: the chain's,
    /// or, where the chain's is no longer fresh enough to vouch at `path`, the alignment of the
    /// confirmed closure found nearest to it along the path (a yaw-rate bias turns the alignment as
    /// the robot drives).
    pub(super) fn chain_alignment(&self, path: f64, lc: &LoopConfig) -> Option<(u32, Alignment)> {
        let (s, chain) = self.chain?;
        let a = if vouches(path - chain.path, lc) {
            chain
        } else {
            self.anchors
                .iter()
                .copied()
                .min_by(|a, b| (a.path - path).abs().total_cmp(&(b.path - path).abs()))
                .unwrap_or(chain)
        };
        Some((s, a))
    }
}
