//! The state of closure acceptance over a session ([`Session`]), the owner of three parts with one
//! job each: the accepted and shared alignments ([`alignments`]), the closures held until others
//! confirm them ([`held`]), and the keyframes searched again after a confirmation or along a walk
//! ([`search_again`]). Each change of state is a named operation: [`Session::note_keyframe`],
//! [`Session::accept`] (publish, hold or confirm), [`Session::published`], [`Session::take_shared`],
//! and the search-again queue.

mod alignments;
mod held;
mod search_again;

use std::collections::BTreeMap;

pub use alignments::Alignment;

use super::{LoopClosure, LoopConfig};
use crate::math::Iso2;
use alignments::Alignments;
use held::{CONFIRM_CHI2, HeldClosures, Need, apart};
use search_again::SearchAgain;

#[cfg(test)]
impl Session {
    /// Sets the accepted alignment to `session`, as a confirmation would.
    pub(crate) fn set_alignment(&mut self, session: u32, a: Alignment) {
        self.alignments.accept(session, a);
    }
}

/// What a closure that passed the gates needs before it is published.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Standing {
    /// It agrees with an accepted alignment fresh enough to vouch for it: published alone.
    Vouched,
    /// It agrees with odometry, or goes to another session that has nothing to contradict it:
    /// published once `loop.confirmations` (another session's, or when it contradicts a fresh
    /// accepted alignment beyond the drift between them: `loop.foreign_confirmations`) closures
    /// agree.
    Unconfirmed,
    /// A closure to this session beyond the drift model while no accepted alignment vouches (none
    /// yet, or a stale one): odometry no longer tells where the session is, as between two
    /// sessions, so it needs as many agreeing closures as a closure to another session
    /// (`loop.foreign_confirmations`), across a turn.
    BeyondDrift,
}

/// Where a closure's query keyframe lies: its id, path length and odometry pose.
#[derive(Debug, Clone, Copy)]
pub struct QueryPlace {
    /// The query keyframe's id.
    pub id: u64,
    /// Its path length, m.
    pub path: f64,
    /// Its odometry pose.
    pub t_odom_body: Iso2,
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
    /// for confirmation that lie beyond [`super::drift::within_reach`] of it and of this session's
    /// own alignment to `session` are dropped, as the gates would refuse them now
    /// ([`super::drift::Prior::Anchored`]).
    pub fn take_shared(&mut self, session: u32, alignment: Alignment, lc: &LoopConfig) {
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
            return;
        }
        let known: Vec<Alignment> = [self.alignments.accepted().get(&session), Some(&alignment)]
            .into_iter()
            .flatten()
            .copied()
            .collect();
        self.held.drop_unreachable(session, &known, lc);
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

    /// The accepted alignment to `session` is fresh enough at `path` to vouch for a closure alone.
    pub fn vouches_for(&self, session: u32, path: f64, lc: &LoopConfig) -> bool {
        self.alignments.vouches_for(session, path, lc)
    }

    /// Some accepted alignment is fresh enough at `path` to vouch for a closure alone.
    pub fn any_vouches(&self, path: f64, lc: &LoopConfig) -> bool {
        self.alignments.any_vouches(path, lc)
    }

    /// Takes a closure that passed the gates, with the alignment of this session into `session` it
    /// implies: published at once when a fresh accepted alignment vouches for it
    /// ([`Standing::Vouched`]) or one closure confirms a session; else held until closures from
    /// other query keyframes agree with it (`loop.confirmations`, `foreign_confirmations`,
    /// `confirmation_span`, `confirmation_overlap`, `confirmation_horizon`). Returns what to publish
    /// now, in order; on a confirmation the keyframes that got nothing since are queued to be
    /// searched again. A closure that contradicts the accepted alignment and is confirmed (while the
    /// alignment is fresh enough to vouch, by `foreign_confirmations`, `overturns_fresh`)
    /// replaces it, so that one false closure that slipped through cannot block every true one
    /// after it; a closure published on that alignment's word drops the held ones it contradicts
    /// ([`HeldClosures::refute`]).
    pub fn accept(
        &mut self,
        query: &QueryPlace,
        c: LoopClosure,
        session: u32,
        alignment: Alignment,
        standing: Standing,
        lc: &LoopConfig,
    ) -> Vec<LoopClosure> {
        let beyond = standing == Standing::BeyondDrift;
        let overturns = standing == Standing::Unconfirmed
            && self.overturns_fresh(query, session, &alignment, lc);
        let needed = if session == self.own && !beyond && !overturns {
            lc.confirmations
        } else {
            lc.foreign_confirmations
        };
        let vouched =
            standing == Standing::Vouched && self.alignments.accepted().contains_key(&session);
        let publish = if vouched {
            self.held.refute(query, session, &alignment, lc);
            vec![c]
        } else if needed <= 1 {
            vec![c]
        } else {
            let need = Need {
                closures: needed,
                turn: beyond,
            };
            match self.held.confirm(query, c, (session, need), alignment, lc) {
                Some((publish, anchors)) => {
                    self.again
                        .confirmed((session, alignment), anchors, query, &publish, lc);
                    publish
                }
                None => return Vec::new(),
            }
        };
        self.alignments.accept(session, alignment);
        publish
    }

    /// A closure that implies `alignment` to `session` contradicts the accepted alignment to it, and
    /// that one is fresh enough to vouch: the two lie beyond [`CONFIRM_CHI2`] of each other
    /// ([`apart`], as [`HeldClosures::refute`] compares them). Such a closure would
    /// overturn closures that agreed with each other a little way back, so it needs as many agreeing
    /// closures as a first alignment without odometry (`loop.foreign_confirmations`): a street slid
    /// along itself by a repeating block agrees with itself from two keyframes. A closure onto
    /// another pass of the place, a lap along the earlier path, lies within the drift over that lap.
    fn overturns_fresh(
        &self,
        query: &QueryPlace,
        session: u32,
        alignment: &Alignment,
        lc: &LoopConfig,
    ) -> bool {
        self.alignments
            .accepted()
            .get(&session)
            .filter(|a| super::drift::vouches(query.path - a.path, lc))
            .is_some_and(|fresh| apart(fresh, alignment, query, lc) > CONFIRM_CHI2)
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
    use super::super::drift::{alignment_distance, closure_disagreement};
    use super::Standing::{BeyondDrift, Unconfirmed, Vouched};
    use super::held::{Held, agreeing, turn_spanned};
    use super::*;
    use crate::math::{Iso3, Mat3, Mat6, Stamp, Vec2, Vec3, iso3_from_iso2};
    use crate::registration::covariance_ros_from_se2;

    fn closure(query_id: u64, match_id: u64, score: f64) -> LoopClosure {
        LoopClosure {
            query_id,
            match_id,
            query_stamp: Stamp(0),
            match_stamp: Stamp(0),
            query_odom_pose: Iso3::identity(),
            match_odom_pose: Iso3::identity(),
            t_match_query: Iso3::identity(),
            covariance: Mat6::identity(),
            inliers: 50,
            score,
            match_session: 0,
            query_robot: 0,
            match_origin: None,
        }
    }

    fn aligned(t: Iso2, path: f64) -> Alignment {
        Alignment::along_one_pass(t, path)
    }

    fn place(id: u64, path: f64) -> QueryPlace {
        QueryPlace {
            id,
            path,
            t_odom_body: Iso2::new(Vec2::new(path, 0.0), 0.0),
        }
    }

    /// Offers query keyframe `q` at `path` metres, matched to keyframe `m` with overlap `score`, as an
    /// unconfirmed closure to session 0 that implies the alignment `a`.
    fn offer(
        s: &mut Session,
        (q, path): (u64, f64),
        (m, score): (u64, f64),
        a: Iso2,
        lc: &LoopConfig,
    ) -> Vec<LoopClosure> {
        take(
            s,
            (q, path),
            (m, score),
            (aligned(a, path), Unconfirmed),
            lc,
        )
    }

    /// Offers query keyframe `q` at `path` metres, matched to keyframe `m` with overlap `score`, as a
    /// closure to session 0 that implies `alignment` and has `standing`.
    fn take(
        s: &mut Session,
        (q, path): (u64, f64),
        (m, score): (u64, f64),
        (alignment, standing): (Alignment, Standing),
        lc: &LoopConfig,
    ) -> Vec<LoopClosure> {
        s.accept(
            &place(q, path),
            closure(q, m, score),
            0,
            alignment,
            standing,
            lc,
        )
    }

    /// The alignment to session 0 that every true closure of these tests implies.
    fn true_alignment() -> Iso2 {
        Iso2::new(Vec2::new(3.0, -2.0), 0.05)
    }

    /// Keyframes 0..n of this session, 10 m apart.
    fn session_with_keyframes(n: u64, lc: &LoopConfig) -> Session {
        let mut s = Session::default();
        for id in 0..n {
            s.note_keyframe(id, 10.0 * id as f64, lc.backfill_horizon);
        }
        s
    }

    /// Query keyframe `q` at `path` metres along a straight street (odometry x), matched to the
    /// keyframe of the earlier pass at the same place (whose odometry frame `true_alignment` maps
    /// this one into), the registration slid by `slide` metres along the street, with `sigma`
    /// metres (and a fiftieth of it in radians) of standard deviation: the closure and the
    /// alignment it implies.
    fn street_closure(q: u64, path: f64, slide: f64, sigma: f64) -> (LoopClosure, Iso2) {
        let query = Iso2::new(Vec2::new(path, 0.0), 0.0);
        let matched = true_alignment() * query * Iso2::new(Vec2::new(0.0, 3.5), 0.0);
        let t =
            matched.inverse() * true_alignment() * query * Iso2::new(Vec2::new(slide, 0.0), 0.0);
        let planar = Mat3::from_diagonal(&Vec3::new(
            sigma * sigma,
            sigma * sigma,
            (sigma / 50.0).powi(2),
        ));
        let mut c = closure(q, q + 100, 0.9);
        c.query_odom_pose = iso3_from_iso2(&query);
        c.match_odom_pose = iso3_from_iso2(&matched);
        c.t_match_query = iso3_from_iso2(&t);
        c.covariance = covariance_ros_from_se2(&planar);
        (c, matched * t * query.inverse())
    }

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
            let held = s.accept(&place(q, path), c, 0, aligned(a, path), Unconfirmed, &lc);
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
        let out = s.accept(
            &place(20, 200.0),
            c,
            0,
            aligned(held, 200.0),
            Unconfirmed,
            &lc,
        );
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
    /// agrees with; the slid one is left waiting. (Over 30 m the drift model's 5 % is as large as
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
        };
        assert!(offer_at(8, 0.0).is_empty());
        assert!(
            offer_at(10, 2.0).is_empty(),
            "20 m of path is too short to confirm"
        );
        let published: Vec<u64> = offer_at(11, 0.0).iter().map(|c| c.query_id).collect();
        assert_eq!(published, [8, 11]);
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
    /// the three true ones confirm each other without it, and it stays held.
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
        };
        assert!(offer_at(0, 12.0).is_empty());
        assert!(offer_at(6, 0.0).is_empty());
        assert!(offer_at(8, 0.0).is_empty());
        let published: Vec<u64> = offer_at(10, 0.0).iter().map(|c| c.query_id).collect();
        assert_eq!(published, [6, 8, 10]);
        let (slid, _) = street_closure(0, 0.0, 12.0, 0.3);
        let (newest, _) = street_closure(10, 100.0, 0.0, 0.3);
        let (between, _) = street_closure(6, 60.0, 0.0, 0.3);
        assert!(
            closure_disagreement(&slid, &newest, -100.0, &lc).expect("regular") <= CONFIRM_CHI2
        );
        assert!(closure_disagreement(&slid, &between, -60.0, &lc).expect("regular") > CONFIRM_CHI2);
    }

    /// Beyond the drift model the odometry between two keyframes is not known to the model's
    /// accuracy: the slid closure of the test above agrees there on its alignment alone.
    #[test]
    fn beyond_the_drift_model_closures_agree_on_their_alignments_alone() {
        let lc = LoopConfig::default();
        let (slid, a_slid) = street_closure(10, 100.0, 2.0, 0.05);
        let (c, a) = street_closure(11, 110.0, 0.0, 0.05);
        let held = |turn: bool| Held {
            closure: slid.clone(),
            alignment: aligned(a_slid, 100.0),
            needed: 4,
            heading: 0.0,
            turn,
        };
        let query = QueryPlace {
            id: 11,
            path: 110.0,
            t_odom_body: Iso2::new(Vec2::new(110.0, 0.0), 0.0),
        };
        let alignment = aligned(a, 110.0);
        let agree = |turn: bool, beyond: bool| {
            agreeing(&[held(turn)], &query, &c, beyond, &alignment, &lc).len()
        };
        assert_eq!(agree(false, false), 0);
        assert_eq!(agree(true, false), 1);
        assert_eq!(agree(false, true), 1);
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
        s.accept(
            &place(10, 100.0),
            closure(10, 0, 0.7),
            1,
            aligned(a, 100.0),
            Unconfirmed,
            &lc,
        );
        let published = s.accept(
            &place(14, 140.0),
            closure(14, 4, 0.7),
            1,
            aligned(a, 140.0),
            Unconfirmed,
            &lc,
        );
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
    fn a_turn_is_read_from_the_headings_pairwise() {
        let q = std::f64::consts::FRAC_PI_4;
        assert!(!turn_spanned(0.0, [0.3, -0.3].into_iter()));
        assert!(
            turn_spanned(0.0, [0.5, -0.5].into_iter()),
            "1 rad between the two others"
        );
        assert!(
            turn_spanned(3.0, [-3.0 + 2.0 * q].into_iter()),
            "across +-pi"
        );
        assert!(!turn_spanned(3.1, [-3.1].into_iter()));
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

    /// All the keyframes [`Session::next_backfill`] gives.
    fn drain_backfill(s: &mut Session) -> Vec<u64> {
        std::iter::from_fn(|| s.next_backfill()).collect()
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
