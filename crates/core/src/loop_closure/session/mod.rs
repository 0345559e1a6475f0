//! The state of closure acceptance over a session ([`Session`]), the owner of three parts with one
//! job each: the accepted and shared alignments ([`alignments`]), the closures held until others
//! confirm them ([`held`]), and the keyframes searched again after a confirmation or along a walk
//! ([`search_again`]). [`Session::accept`] takes a closure that passed the gates through the
//! closure decision ([`super::decision`]): published, held, or confirmed with held ones.

mod alignments;
#[cfg(test)]
pub(crate) mod fixtures;
mod held;
mod search_again;

use std::collections::BTreeMap;

pub(crate) use super::decision::QueryPlace;
pub use alignments::Alignment;

use super::decision::{
    AlignmentState, ClosureState, Moved, Standing, alone_enough, need, overturns, vouched,
};
use super::{LoopClosure, LoopConfig};
use alignments::Alignments;
use held::HeldClosures;
use search_again::SearchAgain;

#[cfg(test)]
impl Session {
    /// Sets the accepted alignment to `session`, as a confirmation would.
    pub(crate) fn set_alignment(&mut self, session: u32, a: Alignment) {
        self.alignments.accept(session, a, false);
    }

    /// The closures held to `session`.
    pub(crate) fn held_to(&self, session: u32) -> &[super::decision::Held] {
        self.held.of(session)
    }
}

/// What [`Session::accept`] did with a closure that passed the gates.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// Its state now: [`ClosureState::Published`], [`ClosureState::Held`] or
    /// [`ClosureState::Confirmed`].
    pub state: ClosureState,
    /// What to publish now, in order: on a confirmation the held closures in query order, then this
    /// one.
    pub publish: Vec<LoopClosure>,
    /// The held closures to its session that left the held state, in the order they left.
    pub moved: Vec<Moved>,
    /// What became of the accepted alignment to its session that this closure's alignment replaced
    /// ([`AlignmentState::Replaced`] or [`AlignmentState::Overturned`]); `None` when it replaced
    /// none.
    pub replaced: Option<AlignmentState>,
}

impl Outcome {
    /// `c` Published alone; `moved`, the held closures that left the held state.
    fn published(c: LoopClosure, moved: Vec<Moved>) -> Self {
        Outcome {
            state: ClosureState::Published,
            publish: vec![c],
            moved,
            replaced: None,
        }
    }
}

/// Closure acceptance over one session.
#[derive(Debug, Clone, Default)]
pub struct Session {
    /// This session's number: its own earlier keyframes need `loop.confirmations`, another
    /// session's `loop.foreign_confirmations`.
    own: u32,
    /// The accepted alignments to other sessions and the shared ones from other robots.
    alignments: Alignments,
    /// Per session: closures waiting for confirmation.
    held: HeldClosures,
    /// The keyframes without a closure, and what is searched again.
    again: SearchAgain,
}

impl Session {
    /// The acceptance state of session `own`.
    pub fn new(own: u32) -> Self {
        Session {
            own,
            ..Session::default()
        }
    }

    /// The accepted alignments, by session.
    pub fn alignments(&self) -> &BTreeMap<u32, Alignment> {
        self.alignments.accepted()
    }

    /// The other robots' accepted alignments to this session, inverted, by their sessions.
    pub fn shared(&self) -> &BTreeMap<u32, Alignment> {
        self.alignments.shared()
    }

    /// Another robot's node accepted `alignment` (inverted: this session's frame in that robot's
    /// session `session`): kept as a prior for closures to `session`, and the closures to it held
    /// for confirmation that lie beyond reach of it and of this session's own alignment to `session`
    /// are dropped, as the gates would refuse them now
    /// ([`unreachable`](super::decision::unreachable)); returns those. The first from that robot,
    /// before this session has an alignment of its own to `session`, starts a walk over the
    /// keyframes without a closure ([`Session::next_walk`]).
    pub fn take_shared(
        &mut self,
        session: u32,
        alignment: Alignment,
        lc: &LoopConfig,
    ) -> Vec<Moved> {
        if self.alignments.share(session, alignment) {
            if !self.alignments.accepted().contains_key(&session) && lc.backfill_per_keyframe > 0 {
                self.again.walk_unclosed(session);
            }
            log::debug!(
                "session {session}'s robot accepted an alignment to this session ({:.2} {:.2} {:.3}, at {:.0} m here, {:.0} m there)",
                alignment.t.translation.x,
                alignment.t.translation.y,
                alignment.t.rotation.angle(),
                alignment.path,
                alignment.match_path
            );
        }
        if lc.consistency_chi2 <= 0.0 {
            return Vec::new();
        }
        let known: Vec<Alignment> = [self.alignments.accepted().get(&session), Some(&alignment)]
            .into_iter()
            .flatten()
            .copied()
            .collect();
        self.held.drop_unreachable(session, &known, lc)
    }

    /// A new keyframe of this session at `path`: it has no closure yet (keyframes farther back than
    /// `horizon` are forgotten).
    pub fn note_keyframe(&mut self, id: u64, path: f64, horizon: f64) {
        self.again.note_keyframe(id, path, horizon);
    }

    /// The alignment a revisit search of `session` looks around: the accepted one, or before there is
    /// one the newest held closure's (so that the closures that would confirm it are registered), or
    /// else the one `session`'s robot accepted to this session ([`Session::take_shared`]): the pairs
    /// of keyframes this node registers are found where that robot's closures put them.
    pub fn search_prior(&self, session: u32) -> Option<Alignment> {
        self.alignments
            .accepted()
            .get(&session)
            .copied()
            .or_else(|| self.held.newest(session))
            .or_else(|| self.alignments.shared().get(&session).copied())
    }

    /// Every other session with a [`Session::search_prior`], and that prior.
    pub fn other_search_priors(&self) -> impl Iterator<Item = (u32, Alignment)> + '_ {
        let sessions: std::collections::BTreeSet<u32> = self
            .alignments
            .accepted()
            .keys()
            .copied()
            .chain(self.held.sessions())
            .chain(self.alignments.shared().keys().copied())
            .filter(|&s| s != self.own)
            .collect();
        sessions
            .into_iter()
            .filter_map(|s| Some((s, self.search_prior(s)?)))
    }

    /// The accepted alignment to `session` is fresh enough at `path` to vouch for a closure alone
    /// ([`AlignmentState::Vouching`]).
    pub fn vouches_for(&self, session: u32, path: f64, lc: &LoopConfig) -> bool {
        self.alignments.state(session, path, lc) == Some(AlignmentState::Vouching)
    }

    /// Some accepted alignment is fresh enough at `path` to vouch for a closure alone.
    pub fn any_vouches(&self, path: f64, lc: &LoopConfig) -> bool {
        self.alignments.any_vouching(path, lc)
    }

    /// Takes a closure that passed the gates, with the alignment of this session into `session` it
    /// implies, through the closure decision ([`super::decision`]): Published alone when a fresh
    /// accepted alignment vouches for it ([`vouched`]; the held closures it contradicts are
    /// Refuted) or one closure is all the session needs ([`alone_enough`]); else offered
    /// to the held closures ([`held::HeldClosures::offer`]): Confirmed with those that agree with it,
    /// or Held. A published closure's alignment becomes the accepted one (the one it replaces
    /// Overturned when the closure contradicted it while it vouched, [`overturns`], else
    /// Replaced), so that one false closure that slipped through cannot block every true one after
    /// it; on a confirmation the keyframes that got nothing since are queued to be searched again.
    pub fn accept(
        &mut self,
        query: &QueryPlace,
        c: LoopClosure,
        session: u32,
        alignment: Alignment,
        standing: Standing,
        lc: &LoopConfig,
    ) -> Outcome {
        let accepted = self.alignments.accepted().get(&session);
        let overturns = overturns(standing, accepted, &alignment, query, lc);
        let need = need(session == self.own, standing, overturns, lc);
        let mut outcome = if vouched(standing, accepted) {
            let moved = self.held.refute(query, session, &alignment, lc);
            Outcome::published(c, moved)
        } else if alone_enough(need) {
            Outcome::published(c, Vec::new())
        } else {
            let confirmation = self.held.offer(query, c, (session, need), alignment, lc);
            let outcome = Outcome {
                state: confirmation.state,
                publish: confirmation.publish,
                moved: confirmation.moved,
                replaced: None,
            };
            if outcome.state == ClosureState::Held {
                return outcome;
            }
            let anchors = confirmation.anchors;
            self.again
                .confirmed((session, alignment), anchors, query, &outcome.publish, lc);
            outcome
        };
        outcome.replaced = self.alignments.accept(session, alignment, overturns);
        outcome
    }

    /// `c` was published: its query keyframe has a closure.
    pub fn published(&mut self, c: &LoopClosure) {
        self.again.published(c);
    }

    /// The next keyframe to search again, if any. The walk back from the confirmation starts
    /// from the confirmation's alignment again.
    pub fn next_backfill(&mut self) -> Option<u64> {
        self.again.next_backfill()
    }

    /// Keyframes queued to be searched again on the present walk away from the confirmation.
    pub fn backfill_len(&self) -> usize {
        self.again.backfill_len()
    }

    /// No alignment is fresh enough at keyframe `id` (path length `path`), just taken from the search
    /// again's present walk away from the confirmation: the rest of the walk goes back to the
    /// keyframes without a closure when the chain's session is another robot's (`another_robot`),
    /// else it is dropped ([`search_again::SearchAgain::walk_gone_stale`]).
    pub fn walk_gone_stale(&mut self, id: u64, path: f64, another_robot: impl Fn(u32) -> bool) {
        self.again.walk_gone_stale(id, path, another_robot);
    }

    /// The next keyframe to search as a new keyframe is, and the session its closure must go to
    /// (the walks): one that still has no closure. A confirmation queues the keyframes
    /// without a closure to be searched again, which ends the walks over them.
    pub fn next_walk(&mut self) -> Option<(u32, u64)> {
        self.again.next_walk()
    }

    /// A closure published by a search again moves the chain to the alignment it implies.
    pub fn extend_chain(&mut self, session: u32, alignment: Alignment) {
        self.again.extend_chain(session, alignment);
    }

    /// Puts the chain's alignment in place of its session's accepted one, or, where the chain's is no
    /// longer fresh enough to vouch at `path`, the alignment of the confirmed closure found nearest
    /// to it along the path ([`search_again::SearchAgain::chain_alignment`]); returns what to put
    /// back with [`Session::restore`].
    pub fn swap_in_chain(
        &mut self,
        path: f64,
        lc: &LoopConfig,
    ) -> Option<(u32, Option<Alignment>)> {
        let (s, a) = self.again.chain_alignment(path, lc)?;
        Some((s, self.alignments.swap_in(s, a)))
    }

    /// Undoes [`Session::swap_in_chain`].
    pub fn restore(&mut self, swapped: Option<(u32, Option<Alignment>)>) {
        if let Some((s, before)) = swapped {
            self.alignments.restore(s, before);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::decision::CONFIRM_CHI2;
    use super::super::drift::{alignment_distance, closure_disagreement};
    use super::Standing::{BeyondDrift, Unconfirmed, Vouched};
    use super::fixtures::*;
    use super::*;
    use crate::math::{Iso2, Vec2};

    /// A closure to another robot's session held for confirmation is dropped once that robot's node
    /// shares an alignment to this session that it lies far beyond (the street matched 300 m along
    /// itself); a closure within the drift of it stays held, and the shared alignment is kept for the
    /// gates.
    #[test]
    fn a_shared_alignment_drops_the_held_closures_far_beyond_it() {
        let lc = LoopConfig::default();
        let mut s = Session::new(1);
        let mut hold = |q: u64, slide: f64| {
            let path = 10.0 * q as f64;
            let (c, a) = street_closure(q, path, slide, 0.05);
            let held = s
                .accept(&place(q, path), c, 0, aligned(a, path), Unconfirmed, &lc)
                .publish;
            assert!(held.is_empty());
            a
        };
        let true_one = hold(10, 0.0);
        let slid = hold(20, 300.0);
        let mut s2 = s.clone();
        assert_eq!(
            s.search_prior(0).map(|p| p.t),
            Some(slid),
            "the newest held"
        );
        // Found by the other robot at this session's 150 m and its own 150 m: the drift over the 100
        // m between (a 6.7 m standard deviation) allows neither 300 m nor a few metres less.
        s.take_shared(0, aligned(true_alignment(), 150.0), &lc);
        assert_eq!(s.shared()[&0].t, true_alignment());
        assert_eq!(
            s.search_prior(0).map(|p| p.t),
            Some(true_one),
            "the slid one is gone"
        );
        // The slid one is kept while this session's own alignment to session 0 agrees with it.
        s2.set_alignment(0, aligned(slid, 200.0));
        s2.take_shared(0, aligned(true_alignment(), 150.0), &lc);
        assert_eq!(
            s2.held.of(0).len(),
            2,
            "both held closures lie within reach of one"
        );
    }

    /// Another robot's shared alignment to this session is searched around while this session has no
    /// closure of its own to that robot: it is that session's search prior, behind a held closure and
    /// an accepted alignment of this session's own, and never this session's prior to itself.
    #[test]
    fn a_shared_alignment_is_searched_around_until_this_session_has_its_own() {
        let lc = LoopConfig::default();
        let mut s = Session::new(1);
        assert_eq!(s.other_search_priors().count(), 0);
        let shared = Iso2::new(Vec2::new(3.4, -2.2), 0.052);
        s.take_shared(0, aligned(shared, 150.0), &lc);
        assert_eq!(s.search_prior(0).map(|p| p.t), Some(shared));
        assert_eq!(s.search_prior(1), None);
        let priors: Vec<(u32, Iso2)> = s.other_search_priors().map(|(k, a)| (k, a.t)).collect();
        assert_eq!(priors, vec![(0, shared)]);
        // A held closure of this session's own comes first, and its accepted alignment before that.
        let (c, held) = street_closure(20, 200.0, 0.0, 0.05);
        let out = s
            .accept(
                &place(20, 200.0),
                c,
                0,
                aligned(held, 200.0),
                Unconfirmed,
                &lc,
            )
            .publish;
        assert!(out.is_empty(), "a first closure to another robot waits");
        assert_eq!(s.search_prior(0).map(|p| p.t), Some(held));
        let own = Iso2::new(Vec2::new(3.1, -2.1), 0.049);
        s.set_alignment(0, aligned(own, 210.0));
        assert_eq!(s.search_prior(0).map(|p| p.t), Some(own));
    }

    /// Along a road whose guard rail posts repeat every 2 m a closure slid by a post period fits as
    /// well as the true one, and its alignment lies within the metres two alignments may differ by.
    /// A true closure 10 m further on does not confirm it: carried there through 10 m of odometry,
    /// the two differ by 2 m where each says 5 cm. It confirms the true closure 30 m back, which it
    /// agrees with; the slid one is dropped, Outvoted. (Over 30 m the drift model's 5 % is as large as
    /// the period: a slid closure that only a closure that far away confirms is not caught.)
    #[test]
    fn a_closure_slid_by_a_post_period_is_not_confirmed_by_its_neighbour() {
        let lc = LoopConfig::default();
        let mut s = session_with_keyframes(20, &lc);
        let mut offer_at = |q: u64, slide: f64| {
            let path = 10.0 * q as f64;
            let (c, a) = street_closure(q, path, slide, 0.05);
            let place = QueryPlace {
                id: q,
                path,
                t_odom_body: Iso2::new(Vec2::new(path, 0.0), 0.0),
            };
            s.accept(&place, c, 0, aligned(a, path), Unconfirmed, &lc)
                .publish
        };
        assert!(offer_at(8, 0.0).is_empty());
        assert!(
            offer_at(10, 2.0).is_empty(),
            "20 m of path is too short to confirm"
        );
        let published: Vec<u64> = offer_at(11, 0.0).iter().map(|c| c.query_id).collect();
        assert_eq!(published, [8, 11]);
        assert!(s.held_to(0).is_empty(), "the slid closure is outvoted");
        // Unchecked against the closures' covariances, the slid closure would have been published
        // with them: its alignment agrees at the alignments' generous accuracy.
        let (slid, a_slid) = street_closure(10, 100.0, 2.0, 0.05);
        let (c, a) = street_closure(11, 110.0, 0.0, 0.05);
        let at = Iso2::new(Vec2::new(110.0, 0.0), 0.0);
        assert!(alignment_distance(&a_slid, &a, &at, 10.0, &lc) <= CONFIRM_CHI2);
        assert!(closure_disagreement(&slid, &c, 10.0, &lc).expect("regular") > CONFIRM_CHI2);
    }

    /// A closure slid 12 m along the street, held 100 m back, agrees with a true closure that far on
    /// (the drift over 100 m covers 12 m) but not with the true closures held 20-40 m after it:
    /// the three true ones confirm each other without it, and it is dropped, Outvoted.
    #[test]
    fn a_confirmation_takes_only_closures_that_agree_with_each_other() {
        let lc = LoopConfig {
            confirmations: 3,
            ..LoopConfig::default()
        };
        let mut s = session_with_keyframes(11, &lc);
        let mut offer_at = |q: u64, slide: f64| {
            let path = 10.0 * q as f64;
            let (c, a) = street_closure(q, path, slide, 0.3);
            s.accept(&place(q, path), c, 0, aligned(a, path), Unconfirmed, &lc)
                .publish
        };
        assert!(offer_at(0, 12.0).is_empty());
        assert!(offer_at(6, 0.0).is_empty());
        assert!(offer_at(8, 0.0).is_empty());
        let published: Vec<u64> = offer_at(10, 0.0).iter().map(|c| c.query_id).collect();
        assert_eq!(published, [6, 8, 10]);
        assert!(s.held_to(0).is_empty(), "the slid closure is outvoted");
        let (slid, _) = street_closure(0, 0.0, 12.0, 0.3);
        let (newest, _) = street_closure(10, 100.0, 0.0, 0.3);
        let (between, _) = street_closure(6, 60.0, 0.0, 0.3);
        assert!(
            closure_disagreement(&slid, &newest, -100.0, &lc).expect("regular") <= CONFIRM_CHI2
        );
        assert!(closure_disagreement(&slid, &between, -60.0, &lc).expect("regular") > CONFIRM_CHI2);
    }

    #[test]
    fn a_first_closure_is_held_until_another_keyframe_agrees() {
        let lc = LoopConfig::default();
        let mut s = session_with_keyframes(20, &lc);
        let a = true_alignment();
        let held = offer(&mut s, (10, 100.0), (0, 0.7), a, &lc);
        assert!(held.is_empty(), "the first closure to a session waits");
        assert!(s.alignments().is_empty());
        assert_eq!(
            s.search_prior(0).map(|p| p.t),
            Some(a),
            "searched around it"
        );
        // The same query keyframe does not confirm itself.
        assert!(offer(&mut s, (10, 100.0), (1, 0.7), a, &lc).is_empty());
        // Another keyframe 40 m on, with an agreeing alignment: both published, in query order.
        let published = offer(&mut s, (14, 140.0), (4, 0.5), a, &lc);
        let ids: Vec<u64> = published.iter().map(|c| c.query_id).collect();
        assert_eq!(ids, [10, 10, 14]);
        assert_eq!(s.alignments()[&0].t, a);
        assert_eq!(s.alignments()[&0].path, 140.0);
        // The keyframes that got nothing are queued: those made after it oldest first, then those
        // before it newest first.
        assert_eq!(s.next_backfill(), Some(15));
        assert_eq!(s.backfill_len(), 4, "16 to 19");
        assert_eq!(
            drain_backfill(&mut s),
            [16, 17, 18, 19, 13, 12, 11, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0]
        );
    }

    /// Another session's first closures (a loaded map, another robot) wait for
    /// `loop.foreign_confirmations` agreeing query keyframes, the own session's for `confirmations`.
    #[test]
    fn another_session_needs_its_own_number_of_confirmations() {
        let lc = LoopConfig::default();
        assert_eq!((lc.confirmations, lc.foreign_confirmations), (2, 4));
        let a = true_alignment();
        let mut s = Session::new(1);
        assert!(offer(&mut s, (10, 100.0), (0, 0.7), a, &lc).is_empty());
        assert!(
            offer(&mut s, (14, 140.0), (4, 0.7), a, &lc).is_empty(),
            "two agreeing closures do not confirm another session"
        );
        assert!(
            offer(&mut s, (18, 180.0), (8, 0.7), a, &lc).is_empty(),
            "nor do three"
        );
        let published = offer(&mut s, (22, 220.0), (12, 0.7), a, &lc);
        let ids: Vec<u64> = published.iter().map(|c| c.query_id).collect();
        assert_eq!(ids, [10, 14, 18, 22]);
        // The own session (1) is confirmed by two.
        let mut s = Session::new(1);
        let first = s.accept(
            &place(10, 100.0),
            closure(10, 0, 0.7),
            1,
            aligned(a, 100.0),
            Unconfirmed,
            &lc,
        );
        assert_eq!(first.state, ClosureState::Held);
        let published = s
            .accept(
                &place(14, 140.0),
                closure(14, 4, 0.7),
                1,
                aligned(a, 140.0),
                Unconfirmed,
                &lc,
            )
            .publish;
        assert_eq!(published.len(), 2);
    }

    /// Closures that contradict the session's accepted alignment to itself while it is fresh enough
    /// to vouch need `foreign_confirmations` agreeing closures, not `confirmations`: two keyframes
    /// onto a street slid along itself by a block agree with each other as well as true ones do.
    /// Four such closures still replace the alignment.
    #[test]
    fn overturning_a_fresh_alignment_needs_foreign_confirmations() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let mut s = Session::new(0);
        assert!(offer(&mut s, (10, 100.0), (0, 0.7), a, &lc).is_empty());
        assert_eq!(offer(&mut s, (14, 140.0), (4, 0.7), a, &lc).len(), 2);
        assert!(s.vouches_for(0, 150.0, &lc));
        let slid = a * Iso2::new(Vec2::new(20.0, 0.0), 0.0);
        assert!(offer(&mut s, (15, 150.0), (25, 0.7), slid, &lc).is_empty());
        assert!(
            offer(&mut s, (19, 190.0), (29, 0.7), slid, &lc).is_empty(),
            "two closures do not overturn a fresh alignment"
        );
        assert!(offer(&mut s, (20, 200.0), (30, 0.7), slid, &lc).is_empty());
        let published = offer(&mut s, (21, 210.0), (31, 0.7), slid, &lc);
        let ids: Vec<u64> = published.iter().map(|c| c.query_id).collect();
        assert_eq!(ids, [15, 19, 20, 21], "four do");
    }

    /// A closure to the own session beyond the drift model needs `foreign_confirmations`, and so
    /// does every confirmation it takes part in, whatever the others' standing; and the agreeing
    /// closures' query keyframes must span a turn (two headings `BEYOND_DRIFT_TURN` apart).
    #[test]
    fn a_closure_beyond_the_drift_model_needs_foreign_confirmations_across_a_turn() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let beyond = |s: &mut Session, q: QueryPlace, m: u64| {
            s.accept(
                &q,
                closure(q.id, m, 0.7),
                0,
                aligned(a, q.path),
                BeyondDrift,
                &lc,
            )
            .publish
        };
        let mut s = Session::new(0);
        assert!(beyond(&mut s, place(10, 100.0), 0).is_empty());
        for (k, q) in [(14u64, 140.0), (18, 180.0)] {
            let published = offer(&mut s, (k, q), (k - 10, 0.7), a, &lc);
            assert!(published.is_empty(), "{k}: fewer than four agree");
        }
        // Four agree, but all along one street: a parallel street would agree as well.
        assert!(beyond(&mut s, place(22, 220.0), 12).is_empty());
        // Round a corner: the street that turns off confirms them.
        let mut corner = place(24, 240.0);
        corner.t_odom_body = Iso2::new(Vec2::new(230.0, 10.0), std::f64::consts::FRAC_PI_2);
        let published = beyond(&mut s, corner, 16);
        let ids: Vec<u64> = published.iter().map(|c| c.query_id).collect();
        assert_eq!(ids, [10, 14, 18, 22, 24]);
    }

    #[test]
    fn confirmation_needs_span_strength_and_agreement() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        // Too close along the path (10 m < confirmation_span).
        let mut s = Session::default();
        offer(&mut s, (10, 100.0), (0, 0.7), a, &lc);
        assert!(offer(&mut s, (11, 110.0), (1, 0.7), a, &lc).is_empty());
        // Weak: no closure reaches confirmation_overlap.
        let mut s = Session::default();
        offer(&mut s, (10, 100.0), (0, 0.5), a, &lc);
        assert!(offer(&mut s, (14, 140.0), (4, 0.5), a, &lc).is_empty());
        // Disagreeing: an alignment 20 m off.
        let mut s = Session::default();
        offer(&mut s, (10, 100.0), (0, 0.7), a, &lc);
        let off = Iso2::new(Vec2::new(23.0, -2.0), 0.05);
        assert!(offer(&mut s, (14, 140.0), (4, 0.7), off, &lc).is_empty());
        // Expired: held longer than confirmation_horizon.
        let mut s = Session::default();
        offer(&mut s, (10, 100.0), (0, 0.7), a, &lc);
        assert!(offer(&mut s, (30, 300.0), (20, 0.7), a, &lc).is_empty());
    }

    #[test]
    fn agreeing_closures_are_published_alone_and_one_confirmation_publishes_at_once() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let mut s = Session::default();
        offer(&mut s, (10, 100.0), (0, 0.7), a, &lc);
        offer(&mut s, (14, 140.0), (4, 0.7), a, &lc);
        let one = take(
            &mut s,
            (15, 150.0),
            (5, 0.4),
            (aligned(a, 150.0), Vouched),
            &lc,
        );
        assert_eq!(one.len(), 1);
        assert_eq!(s.alignments()[&0].path, 150.0);
        // Without an accepted alignment `agrees` alone publishes nothing.
        assert!(
            s.accept(
                &place(16, 160.0),
                closure(16, 6, 0.9),
                1,
                aligned(a, 160.0),
                Vouched,
                &lc
            )
            .publish
            .is_empty()
        );
        let single = LoopConfig {
            confirmations: 1,
            ..lc
        };
        let mut s = Session::default();
        assert_eq!(offer(&mut s, (10, 100.0), (0, 0.1), a, &single).len(), 1);
    }

    #[test]
    fn a_confirmed_contradiction_replaces_the_alignment() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let mut s = Session::default();
        offer(&mut s, (10, 100.0), (0, 0.7), a, &lc);
        offer(&mut s, (14, 140.0), (4, 0.7), a, &lc);
        let b = Iso2::new(Vec2::new(9.0, 4.0), -0.02);
        assert!(offer(&mut s, (20, 200.0), (9, 0.7), b, &lc).is_empty());
        assert_eq!(s.alignments()[&0].t, a, "held, not yet taken");
        let published = offer(&mut s, (24, 240.0), (13, 0.7), b, &lc);
        assert_eq!(published.len(), 2);
        assert_eq!(s.alignments()[&0].t, b);
    }

    /// A held closure that contradicts the accepted alignment is dropped when a newer closure is
    /// published on that alignment's word: the next contradicting closure does not confirm it and
    /// waits for one of its own. Once the accepted alignment stops vouching for new closures, the
    /// contradictions after it confirm each other and replace it. A held closure onto another pass
    /// of the place is not dropped.
    #[test]
    fn a_contradiction_refuted_by_a_newer_vouched_closure_confirms_nothing() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let b = Iso2::new(Vec2::new(9.0, 4.0), -0.02);
        let mut s = Session::default();
        offer(&mut s, (10, 100.0), (0, 0.7), a, &lc);
        offer(&mut s, (14, 140.0), (4, 0.7), a, &lc);
        assert!(offer(&mut s, (20, 200.0), (9, 0.7), b, &lc).is_empty());
        let vouched = take(
            &mut s,
            (22, 220.0),
            (11, 0.7),
            (aligned(a, 220.0), Vouched),
            &lc,
        );
        assert_eq!(vouched.len(), 1, "published on the alignment's word");
        assert!(
            offer(&mut s, (29, 290.0), (18, 0.7), b, &lc).is_empty(),
            "the held contradiction was refuted by keyframe 22"
        );
        assert_eq!(s.alignments()[&0].t, a);
        let published: Vec<u64> = offer(&mut s, (33, 330.0), (22, 0.7), b, &lc)
            .iter()
            .map(|c| c.query_id)
            .collect();
        assert_eq!(published, [29, 33]);
        assert_eq!(s.alignments()[&0].t, b);
        // A held closure onto another pass of the place, a lap further along the earlier path, may
        // imply an alignment metres away from the accepted one by the drift over that lap: a closure
        // onto the nearer pass does not refute it.
        let other_pass = |path: f64| Alignment {
            t: b * Iso2::new(Vec2::new(8.0, 0.0), 0.05),
            path,
            match_path: path + 3000.0,
        };
        let held = take(
            &mut s,
            (40, 400.0),
            (50, 0.7),
            (other_pass(400.0), Unconfirmed),
            &lc,
        );
        assert!(held.is_empty());
        let on_b = take(
            &mut s,
            (41, 410.0),
            (30, 0.7),
            (aligned(b, 410.0), Vouched),
            &lc,
        );
        assert_eq!(on_b.len(), 1);
        let published: Vec<u64> = take(
            &mut s,
            (44, 440.0),
            (54, 0.7),
            (other_pass(440.0), Unconfirmed),
            &lc,
        )
        .iter()
        .map(|c| c.query_id)
        .collect();
        assert_eq!(published, [40, 44]);
    }
}
