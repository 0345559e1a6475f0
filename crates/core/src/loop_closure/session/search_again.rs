//! The keyframes searched again ([`SearchAgain`]): this session's recent keyframes without a
//! closure, the queue a confirmation fills with them (walking away from the confirming keyframe,
//! forward then back), the chain of alignments they are searched around and the confirmed
//! closures' anchors, and the walks over keyframes without a closure for closures to another
//! robot's session.

use std::collections::VecDeque;

use super::super::decision::vouching;
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
        let a = if vouching(&chain, path, lc) {
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

#[cfg(test)]
mod tests {
    use super::super::Session;
    use super::super::Standing::Vouched;
    use super::super::fixtures::*;
    use super::*;
    use crate::math::{Iso2, Vec2};

    #[test]
    fn no_backfill_when_switched_off_and_published_keyframes_leave_the_queue() {
        let off = LoopConfig {
            backfill_per_keyframe: 0,
            ..LoopConfig::default()
        };
        let a = true_alignment();
        let mut s = session_with_keyframes(20, &off);
        offer(&mut s, (10, 100.0), (0, 0.7), a, &off);
        offer(&mut s, (14, 140.0), (4, 0.7), a, &off);
        assert_eq!(s.backfill_len(), 0);
        // Keyframes beyond the horizon are forgotten; published ones leave the unclosed list.
        let lc = LoopConfig::default();
        let mut s = session_with_keyframes(3, &lc);
        s.note_keyframe(3, 10.0 + lc.backfill_horizon, lc.backfill_horizon);
        s.published(&closure(3, 0, 0.7));
        offer(&mut s, (4, 0.0), (0, 0.7), a, &lc);
        offer(&mut s, (8, 40.0), (4, 0.7), a, &lc);
        let mut queued = Vec::new();
        while let Some(id) = s.next_backfill() {
            queued.push(id);
        }
        assert_eq!(queued, [2, 1], "keyframe 0 beyond the horizon, 3 published");
    }

    #[test]
    fn a_keyframe_searched_again_is_searched_around_the_nearest_confirmed_closure() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let later = Iso2::new(Vec2::new(3.3, -2.0), 0.05);
        let mut s = session_with_keyframes(30, &lc);
        offer(&mut s, (10, 100.0), (0, 0.7), a, &lc);
        assert_eq!(offer(&mut s, (24, 240.0), (14, 0.7), later, &lc).len(), 2);
        // The confirmation's alignment vouches up to 60 m back; beyond, the nearest confirmed one.
        for (path, expected) in [(200.0, later), (150.0, a), (110.0, a), (290.0, later)] {
            let swapped = s.swap_in_chain(path, &lc);
            assert_eq!(s.alignments()[&0].t, expected, "at {path} m");
            s.restore(swapped);
        }
        // A search again that publishes moves the chain on, and it is kept while it vouches.
        let walked = aligned(Iso2::new(Vec2::new(3.1, -2.0), 0.05), 150.0);
        s.extend_chain(0, walked);
        for (path, expected) in [(110.0, walked), (60.0, aligned(a, 100.0))] {
            let swapped = s.swap_in_chain(path, &lc);
            assert_eq!(s.alignments()[&0], expected, "at {path} m");
            s.restore(swapped);
        }
    }

    #[test]
    fn the_chain_alignment_is_swapped_in_and_restored() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let mut s = Session::default();
        offer(&mut s, (10, 100.0), (0, 0.7), a, &lc);
        offer(&mut s, (14, 140.0), (4, 0.7), a, &lc);
        let newer = Iso2::new(Vec2::new(3.5, -2.0), 0.05);
        take(
            &mut s,
            (18, 180.0),
            (8, 0.7),
            (aligned(newer, 180.0), Vouched),
            &lc,
        );
        let chain = aligned(a, 90.0);
        s.extend_chain(0, chain);
        let swapped = s.swap_in_chain(90.0, &lc);
        assert_eq!(s.alignments()[&0], chain);
        assert!(s.any_vouches(100.0, &lc) && !s.any_vouches(200.0, &lc));
        s.restore(swapped);
        assert_eq!(s.alignments()[&0].t, newer);
        // A chain to a session without an alignment leaves none behind.
        s.extend_chain(7, chain);
        let swapped = s.swap_in_chain(90.0, &lc);
        assert!(s.alignments().contains_key(&7));
        s.restore(swapped);
        assert!(!s.alignments().contains_key(&7));
    }

    /// Keyframes 0 to 19, 10 m apart: a closure held at keyframe 12 is confirmed at the older
    /// keyframe 8 (as keyframes searched again by a walk find them), and the first keyframe to search
    /// again, 9, is taken.
    fn confirmed_at_an_older_keyframe(lc: &LoopConfig) -> Session {
        let a = true_alignment();
        let mut s = session_with_keyframes(20, lc);
        offer(&mut s, (12, 120.0), (2, 0.7), a, lc);
        assert_eq!(offer(&mut s, (8, 80.0), (0, 0.7), a, lc).len(), 2);
        assert_eq!(s.next_backfill(), Some(9));
        s
    }

    /// A confirmation at an older keyframe (an older keyframe searched around a shared alignment)
    /// queues the keyframes made after it oldest first, then those before it newest first, and the
    /// walk back starts from the confirmation's alignment again, not from where the walk forward
    /// ended.
    #[test]
    fn a_confirmation_at_an_older_keyframe_walks_forward_then_back() {
        let lc = LoopConfig::default();
        let mut s = confirmed_at_an_older_keyframe(&lc);
        s.extend_chain(0, aligned(Iso2::new(Vec2::new(3.2, -2.0), 0.05), 90.0));
        let forward: Vec<u64> = std::iter::from_fn(|| s.next_backfill())
            .take_while(|&id| id != 7)
            .collect();
        assert_eq!(forward, [10, 11, 13, 14, 15, 16, 17, 18, 19]);
        assert_eq!(
            s.again.chain(),
            Some((0, aligned(true_alignment(), 80.0))),
            "back from the confirmation"
        );
        assert_eq!(drain_backfill(&mut s), [6, 5, 4, 3, 2, 1, 0]);
    }

    /// Where no alignment vouches any more, the rest of a search again's walk to another robot's
    /// session is searched as new keyframes are, for closures to that session (to one robot's own
    /// session it ends there); the walk back from the confirmation still follows a walk forward that
    /// went stale, and a confirmation among the keyframes walked ends the walk over them.
    #[test]
    fn a_walk_to_another_robot_gone_stale_is_searched_as_new_keyframes() {
        let lc = LoopConfig::default();
        let mut s = confirmed_at_an_older_keyframe(&lc);
        assert_eq!(s.next_backfill(), Some(10));
        let mut lone = s.clone();
        lone.walk_gone_stale(10, 100.0, |_| false);
        assert_eq!(drain_backfill(&mut lone), [7, 6, 5, 4, 3, 2, 1, 0]);
        assert_eq!(lone.next_walk(), None, "one robot's walk ends there");
        s.walk_gone_stale(10, 100.0, |session| session == 0);
        assert_eq!(drain_backfill(&mut s), [7, 6, 5, 4, 3, 2, 1, 0]);
        assert_eq!(s.next_walk(), Some((0, 10)));
        s.published(&closure(11, 1, 0.7));
        assert_eq!(s.next_walk(), Some((0, 13)), "11 has a closure now");
        // Two walked keyframes confirm a new alignment: the walk ends, and what it had not reached
        // is queued to be searched again around that alignment.
        let b = Iso2::new(Vec2::new(3.6, -2.0), 0.05);
        offer(&mut s, (14, 140.0), (4, 0.7), b, &lc);
        assert_eq!(offer(&mut s, (17, 170.0), (7, 0.7), b, &lc).len(), 2);
        assert_eq!(s.next_walk(), None);
        assert_eq!(drain_backfill(&mut s), [18, 19, 16, 15, 13, 10]);
    }

    /// A shared alignment to a session that arrives before this session has one of its own walks
    /// over this session's keyframes that have no closure, newest first; once this session has its
    /// own, a second shared alignment starts no walk.
    #[test]
    fn a_shared_alignment_walks_over_the_keyframes_without_a_closure() {
        let lc = LoopConfig::default();
        let mut s = session_with_keyframes(5, &lc);
        s.own = 1;
        s.published(&closure(3, 0, 0.7));
        s.take_shared(0, aligned(true_alignment(), 30.0), &lc);
        let walked: Vec<(u32, u64)> = std::iter::from_fn(|| s.next_walk()).collect();
        assert_eq!(walked, [(0, 4), (0, 2), (0, 1), (0, 0)]);
        // A walked keyframe that finds the pair it holds already holds it once, and a confirmation
        // publishes it once.
        let a = true_alignment();
        assert!(offer(&mut s, (0, 0.0), (7, 0.7), a, &lc).is_empty());
        assert!(offer(&mut s, (0, 0.0), (7, 0.7), a, &lc).is_empty());
        assert_eq!(s.held.of(0).len(), 1);
        let mut s = session_with_keyframes(5, &lc);
        s.own = 1;
        s.set_alignment(2, aligned(true_alignment(), 30.0));
        s.take_shared(2, aligned(true_alignment(), 30.0), &lc);
        assert_eq!(s.next_walk(), None);
    }
}
