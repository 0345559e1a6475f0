//! The closure decision as a state machine: what becomes of a closure that passed the gates
//! ([`ClosureState`]) and of a session's accepted alignment ([`AlignmentState`]), with one
//! function per transition applying the one test that decides it. docs/algorithm.md ("The closure
//! decision") tabulates the same states, transitions, tests and functions.
//!
//! Each transition function is a predicate: true when its test moves the closure (or the
//! alignment) to the next state. The session keeps the closures and the alignments and moves them
//! with these functions: [`super::Session::accept`] a gated closure ([`vouched`], [`alone_enough`],
//! [`need`], [`overturns`], [`agreeing`], [`confirms`]), the held list its held closures
//! ([`expired`], [`replaced`], [`refuted`], [`unreachable`]); the loop closer a closure found by a
//! search again, for another robot's keyframe or on a walk ([`published_late`], [`off_walk`]).

use super::drift::{
    alignment_distance, anchored_inconsistency, closure_disagreement, vouches, within_reach,
};
use super::{Alignment, LoopClosure, LoopConfig};
use crate::math::Iso2;

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

/// A closure waiting for confirmation, with the alignment it implies and the number of agreeing
/// closures (itself included) it needs.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Held {
    pub(crate) closure: LoopClosure,
    pub(crate) alignment: Alignment,
    pub(crate) needed: usize,
    /// The query keyframe's odometry heading, rad.
    pub(crate) heading: f64,
    /// It lies beyond the drift model: its confirmation must span a turn
    /// ([`BEYOND_DRIFT_TURN`]).
    pub(crate) turn: bool,
}

/// Gate on the agreement of two closures' alignments (the 99.9 % chi-square quantile, 3 dof).
pub(crate) const CONFIRM_CHI2: f64 = 16.27;

/// Closures beyond the drift model confirm each other only when their query keyframes' headings
/// differ by at least this, rad (45 degrees): they come from two streets that meet at an angle. Along
/// one street the view repeats across the block grid, and a parallel street a block or more away
/// agrees with itself from every keyframe; the same shift rarely also aligns the street that turns off
/// it.
pub(crate) const BEYOND_DRIFT_TURN: f64 = std::f64::consts::FRAC_PI_4;

/// What a closure that passed the gates needs before it is published (decided by
/// [`super::gates::consistency`]).
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

/// The states of a closure that passed the gates. It starts `Gated`; `Published` and `Confirmed`
/// end in a published closure, every other state but `Held` in a dropped one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClosureState {
    /// It passed the gates, and the prediction and slide tests it needed, with a [`Standing`].
    Gated,
    /// Published alone: on a fresh alignment's word ([`vouched`], [`published_late`]), or because
    /// one closure is all its session needs ([`alone_enough`]).
    Published,
    /// Held until closures from other query keyframes agree with it ([`need`]).
    Held,
    /// Published together with the held closures that agree with it ([`agreeing`], [`confirms`]).
    Confirmed,
    /// Dropped: held more than `loop.confirmation_horizon` of path ([`expired`]).
    Expired,
    /// Dropped: its query keyframe found the same pair again, which is held in its place
    /// ([`replaced`]).
    Replaced,
    /// Dropped: closures to its session that it does not agree with were confirmed (not among
    /// [`agreeing`]).
    Outvoted,
    /// Dropped: a closure published on the accepted alignment's word contradicts it ([`refuted`]).
    Refuted,
    /// Dropped: another robot's alignment to this session arrived, and the closure lies beyond
    /// reach of every alignment to its session known here ([`unreachable`]).
    Unreachable,
    /// Dropped: found by a search again or for another robot's arriving keyframe, where only what
    /// agrees with a fresh alignment is published ([`published_late`]).
    Unvouched,
    /// Dropped: found on a walk for closures to another session, it goes to a different one
    /// ([`off_walk`]).
    OffWalk,
}

/// A held closure that left the held state: its pair of keyframes and the state it moved to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Moved {
    /// Its query keyframe.
    pub query_id: u64,
    /// Its match keyframe.
    pub match_id: u64,
    /// The state it moved to.
    pub to: ClosureState,
}

impl Moved {
    /// Closure `c` moved to `to`.
    pub(crate) fn of(c: &LoopClosure, to: ClosureState) -> Self {
        Moved {
            query_id: c.query_id,
            match_id: c.match_id,
            to,
        }
    }
}

/// The states of a session's accepted alignment to another session (or to itself). It is
/// `Vouching` or `Stale` at a given path length ([`vouching`]); the next closure to the session
/// published through [`super::Session::accept`] takes its place, and it ends `Replaced` or
/// `Overturned` ([`overturns`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AlignmentState {
    /// Fresh enough to vouch for a closure alone.
    Vouching,
    /// Too far back along the path to vouch for a closure.
    Stale,
    /// Replaced by the alignment of a newer published closure.
    Replaced,
    /// Replaced by the alignment of a closure that contradicted it while it vouched.
    Overturned,
}

/// What a held closure needs before it is published: this many agreeing closures, itself
/// included, and whether their query keyframes must span a turn ([`BEYOND_DRIFT_TURN`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Need {
    pub(crate) closures: usize,
    pub(crate) turn: bool,
}

/// Accepted alignment, Vouching or Stale at `path`: `a` is fresh enough to vouch for a closure
/// alone there, its translation standard deviation after the path since it was found at most
/// `loop.trusted_prior_std` ([`vouches`]).
pub(crate) fn vouching(a: &Alignment, path: f64, lc: &LoopConfig) -> bool {
    vouches(path - a.path, lc)
}

/// Gated → Published, alone: the closure agrees with a fresh accepted alignment to its session
/// ([`Standing::Vouched`], decided by the gates with [`vouching`]) and the session has one
/// (`accepted`).
pub(crate) fn vouched(standing: Standing, accepted: Option<&Alignment>) -> bool {
    standing == Standing::Vouched && accepted.is_some()
}

/// Accepted alignment Vouching → Overturned (once the closure is published): an unconfirmed
/// closure implies `alignment`, which lies beyond [`CONFIRM_CHI2`] of the accepted alignment
/// ([`apart`]) while that one is [`vouching`] at the closure's query keyframe. Such a closure
/// would overturn closures that agreed with each other a little way back, so it needs as many
/// agreeing closures as a first alignment without odometry ([`need`]): a street slid along itself
/// by a repeating block agrees with itself from two keyframes. A closure onto another pass of the
/// place, a lap along the earlier path, lies within the drift over that lap.
pub(crate) fn overturns(
    standing: Standing,
    accepted: Option<&Alignment>,
    alignment: &Alignment,
    query: &QueryPlace,
    lc: &LoopConfig,
) -> bool {
    standing == Standing::Unconfirmed
        && accepted
            .filter(|a| vouching(a, query.path, lc))
            .is_some_and(|fresh| apart(fresh, alignment, query, lc) > CONFIRM_CHI2)
}

/// Gated → Held, with what it needs: `loop.confirmations` agreeing closures for one to this
/// session (`own`) within the drift model that [`overturns`] nothing, else
/// `loop.foreign_confirmations` (another session, [`Standing::BeyondDrift`], or an overturn);
/// across a turn when it lies beyond the drift model.
pub(crate) fn need(own: bool, standing: Standing, overturns: bool, lc: &LoopConfig) -> Need {
    let beyond = standing == Standing::BeyondDrift;
    let closures = if own && !beyond && !overturns {
        lc.confirmations
    } else {
        lc.foreign_confirmations
    };
    Need {
        closures,
        turn: beyond,
    }
}

/// Gated → Published, alone: one closure is all its session needs ([`need`]: `loop.confirmations`
/// or `loop.foreign_confirmations` is 1).
pub(crate) fn alone_enough(need: Need) -> bool {
    need.closures <= 1
}

/// Held → Expired: the closure was held more than `loop.confirmation_horizon` of path before
/// `query`, the query keyframe of the next closure to its session that is not published alone
/// (a keyframe searched again behind it lies before it: nothing expires then).
pub(crate) fn expired(h: &Held, query: &QueryPlace, lc: &LoopConfig) -> bool {
    let within = query.path - h.alignment.path <= lc.confirmation_horizon;
    !within
}

/// Held → Replaced: `c`, about to be held, joins the same pair of keyframes as the held closure (a
/// keyframe searched again on a walk finds a pair it holds already): the pair is held once.
pub(crate) fn replaced(h: &Held, c: &LoopClosure) -> bool {
    (h.closure.query_id, h.closure.match_id) == (c.query_id, c.match_id)
}

/// Held → Refuted: a closure at `query` implying `alignment` was published on a fresh alignment's
/// word ([`vouched`]), and the held closure's alignment lies beyond [`CONFIRM_CHI2`] of it
/// ([`apart`]). The held closure contradicts an alignment that a newer closure has borne out; left
/// waiting, two such closures on either side of a stretch the alignment keeps vouching for would
/// confirm each other and replace it (a road slid along itself by its repeating posts agrees with
/// itself over the drift between them). A false accepted alignment is still replaced once it stops
/// vouching for new closures: the contradicting closures after that confirm each other.
pub(crate) fn refuted(
    h: &Held,
    alignment: &Alignment,
    query: &QueryPlace,
    lc: &LoopConfig,
) -> bool {
    let agrees = apart(&h.alignment, alignment, query, lc) <= CONFIRM_CHI2;
    !agrees
}

/// Held → Unreachable: another robot's alignment to this session arrived, and the held closure
/// lies beyond [`within_reach`] (`BEYOND_DRIFT_REACH`² × `loop.consistency_chi2`) of every
/// alignment to its session in `known` (this session's accepted one and the arrived one) as
/// odometry carries them ([`anchored_inconsistency`]): the gates would refuse it now.
pub(crate) fn unreachable(h: &Held, known: &[Alignment], lc: &LoopConfig) -> bool {
    let paths = [h.alignment.path, h.alignment.match_path];
    let d2 = |a: &Alignment| anchored_inconsistency(a, &h.closure, paths, lc);
    let reached = known
        .iter()
        .any(|a| d2(a).is_none_or(|d2| within_reach(d2, lc)));
    !reached
}

/// Gated → Published or Unvouched, for a closure found by a search again or for another robot's
/// arriving keyframe: published only when it agrees with a fresh alignment
/// ([`Standing::Vouched`]). The first closures to a session come from new keyframes, whose
/// candidates compete.
pub(crate) fn published_late(standing: Standing) -> bool {
    standing == Standing::Vouched
}

/// Gated → OffWalk: the closure, found on a walk for closures to session `walk`, goes to another
/// session (`session`).
pub(crate) fn off_walk(session: u32, walk: Option<u32>) -> bool {
    walk.is_some_and(|s| s != session)
}

/// Squared distance ([`alignment_distance`]) between an earlier alignment and `alignment`, which a
/// closure at `query` implies, with the drift over the path between the two query keyframes and
/// between the two match keyframes: two true closures onto two passes of one place a lap apart imply
/// alignments that differ by the drift over that lap.
pub(crate) fn apart(
    earlier: &Alignment,
    alignment: &Alignment,
    query: &QueryPlace,
    lc: &LoopConfig,
) -> f64 {
    let gap = (query.path - earlier.path).abs() + (alignment.match_path - earlier.match_path).abs();
    alignment_distance(&earlier.t, &alignment.t, &query.t_odom_body, gap, lc)
}

/// Closure `a` lies within [`CONFIRM_CHI2`] of its prediction from `b`, `gap` metres of path away
/// ([`closure_disagreement`]; agreeing when that is singular).
fn closures_agree(a: &LoopClosure, b: &LoopClosure, gap: f64, lc: &LoopConfig) -> bool {
    closure_disagreement(a, b, gap, lc).is_none_or(|d| d <= CONFIRM_CHI2)
}

/// Held → Confirmed, or (on a confirmation without it) Outvoted: the held closures (indices into
/// `pending`) from other query keyframes that agree with `c`, the chi-square agreement: their
/// alignments within [`CONFIRM_CHI2`] of `alignment`, `c`'s, at the generous accuracy of
/// [`alignment_distance`] plus the drift between them, and, unless `c` or the held closure lies
/// beyond the drift model (`beyond`, [`Held::turn`]), each closure within [`CONFIRM_CHI2`] of its
/// prediction from `c` under the two closures' own covariances and the drift model
/// ([`closure_disagreement`]), and of each other ([`mutually_agreeing`]). The first tells one street
/// from another; the second keeps out a closure slid along the street by the period of its posts,
/// which fits as well as the true alignment and lies metres away where its covariance says
/// centimetres. Beyond the drift model the odometry between the two keyframes is not known to the
/// model's accuracy, and only the first applies.
pub(crate) fn agreeing(
    pending: &[Held],
    query: &QueryPlace,
    c: &LoopClosure,
    beyond: bool,
    alignment: &Alignment,
    lc: &LoopConfig,
) -> Vec<usize> {
    let with_c: Vec<usize> = (0..pending.len())
        .filter(|&k| {
            let h = &pending[k];
            let gap = query.path - h.alignment.path;
            let consistent = || beyond || h.turn || closures_agree(&h.closure, c, gap, lc);
            h.closure.query_id != c.query_id
                && alignment_distance(&h.alignment.t, &alignment.t, &query.t_odom_body, gap, lc)
                    <= CONFIRM_CHI2
                && consistent()
        })
        .collect();
    if beyond {
        return with_c;
    }
    mutually_agreeing(pending, query, with_c, lc)
}

/// The held closures `agree` (indices into `pending`, ascending) that also agree with each other:
/// taken nearest `query` along the path first, each kept when it is within [`CONFIRM_CHI2`] of every
/// one kept before it ([`closure_disagreement`] over the path between their query keyframes), unless
/// one of the two lies beyond the drift model. Agreeing with the newest closure alone lets a closure
/// far back along the path through: the drift over a long stretch covers a street slid by a block,
/// which the closures in between rule out. Ascending, as `agree`.
fn mutually_agreeing(
    pending: &[Held],
    query: &QueryPlace,
    mut agree: Vec<usize>,
    lc: &LoopConfig,
) -> Vec<usize> {
    let back = |k: usize| (query.path - pending[k].alignment.path).abs();
    agree.sort_by(|&a, &b| back(a).total_cmp(&back(b)));
    let mut kept: Vec<usize> = Vec::with_capacity(agree.len());
    for k in agree {
        let h = &pending[k];
        let fits = |j: &usize| {
            let o = &pending[*j];
            let gap = h.alignment.path - o.alignment.path;
            h.turn || o.turn || closures_agree(&h.closure, &o.closure, gap, lc)
        };
        if kept.iter().all(fits) {
            kept.push(k);
        }
    }
    kept.sort_unstable();
    kept
}

/// Gated → Confirmed (else Held), with the held closures `agree` ([`agreeing`]): `needed` closures
/// in all (the most any of them [`need`]s), their query keyframes spanning
/// `loop.confirmation_span` of path, one of them strong (`loop.confirmation_overlap`), and across a
/// turn ([`turn_spanned`]) when `need` or one of them asks for it.
pub(crate) fn confirms(
    pending: &[Held],
    agree: &[usize],
    query: &QueryPlace,
    c: &LoopClosure,
    need: Need,
    needed: usize,
    lc: &LoopConfig,
) -> bool {
    let span = agree
        .iter()
        .map(|&k| (query.path - pending[k].alignment.path).abs())
        .fold(0.0, f64::max);
    let strong = c.score >= lc.confirmation_overlap
        || agree
            .iter()
            .any(|&k| pending[k].closure.score >= lc.confirmation_overlap);
    let heading = query.t_odom_body.rotation.angle();
    let turned = !(need.turn || agree.iter().any(|&k| pending[k].turn))
        || turn_spanned(heading, agree.iter().map(|&k| pending[k].heading));
    agree.len() + 1 >= needed && span >= lc.confirmation_span && strong && turned
}

/// Whether the headings, `first` and the rest, differ pairwise by at least [`BEYOND_DRIFT_TURN`]
/// somewhere.
pub(crate) fn turn_spanned(first: f64, rest: impl Iterator<Item = f64>) -> bool {
    let all: Vec<f64> = std::iter::once(first).chain(rest).collect();
    all.iter().enumerate().any(|(i, a)| {
        all[i + 1..]
            .iter()
            .any(|b| crate::math::wrap_angle(a - b).abs() >= BEYOND_DRIFT_TURN)
    })
}

#[cfg(test)]
mod tests {
    use super::super::Session;
    use super::super::session::fixtures::*;
    use super::Standing::{BeyondDrift, Unconfirmed, Vouched};
    use super::*;
    use crate::math::{Iso2, Vec2, iso3_from_iso2};

    /// The true alignment slid `x` metres along the query's heading.
    fn off(x: f64) -> Iso2 {
        true_alignment() * Iso2::new(Vec2::new(x, 0.0), 0.0)
    }

    fn moved(query_id: u64, match_id: u64, to: ClosureState) -> Moved {
        Moved {
            query_id,
            match_id,
            to,
        }
    }

    /// Gated -> Published ([`vouched`]): a closure the gates found Vouched is published alone while
    /// its session has an accepted alignment, whose place its alignment takes (Replaced); to a
    /// session without one, or not vouched, it is held.
    #[test]
    fn gated_to_published_when_vouched() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let at_100 = aligned(a, 100.0);
        let with_alignment = || {
            let mut s = Session::new(0);
            s.set_alignment(0, at_100);
            s
        };
        let mut s = with_alignment();
        let out = judge(
            &mut s,
            (12, 120.0),
            (2, 0.4),
            (aligned(a, 120.0), Vouched),
            &lc,
        );
        assert_eq!(out.state, ClosureState::Published);
        assert_eq!(ids(&out.publish), [12]);
        assert_eq!(out.replaced, Some(AlignmentState::Replaced));
        assert_eq!(s.alignments()[&0].path, 120.0);
        let mut s = with_alignment();
        let out = judge(
            &mut s,
            (12, 120.0),
            (2, 0.4),
            (aligned(a, 120.0), Unconfirmed),
            &lc,
        );
        assert_eq!((out.state, out.replaced), (ClosureState::Held, None));
        assert_eq!(s.alignments()[&0].path, 100.0);
        let mut other = Session::new(1);
        let out = judge(
            &mut other,
            (12, 120.0),
            (2, 0.4),
            (aligned(a, 120.0), Vouched),
            &lc,
        );
        assert_eq!(
            out.state,
            ClosureState::Held,
            "no accepted alignment to session 0"
        );
        assert!(vouched(Vouched, Some(&at_100)));
        assert!(!vouched(Vouched, None));
        assert!(!vouched(Unconfirmed, Some(&at_100)) && !vouched(BeyondDrift, Some(&at_100)));
    }

    /// Gated -> Published ([`alone_enough`]): with `loop.confirmations` at 1 a first closure to this
    /// session is published alone and its alignment is the first accepted one; to another session
    /// it still waits for `loop.foreign_confirmations` (4), unless that is 1 too.
    #[test]
    fn gated_to_published_when_one_closure_is_enough() {
        let a = true_alignment();
        let single = LoopConfig {
            confirmations: 1,
            ..LoopConfig::default()
        };
        let first = |s: &mut Session, lc: &LoopConfig| {
            judge(
                s,
                (10, 100.0),
                (0, 0.3),
                (aligned(a, 100.0), Unconfirmed),
                lc,
            )
        };
        let mut s = Session::new(0);
        let out = first(&mut s, &single);
        assert_eq!((out.state, out.replaced), (ClosureState::Published, None));
        assert_eq!(s.alignments()[&0].t, a);
        assert_eq!(
            first(&mut Session::new(1), &single).state,
            ClosureState::Held
        );
        let both = LoopConfig {
            foreign_confirmations: 1,
            ..single
        };
        assert_eq!(
            first(&mut Session::new(1), &both).state,
            ClosureState::Published
        );
        let need = |closures: usize| Need {
            closures,
            turn: false,
        };
        assert!(alone_enough(need(1)) && !alone_enough(need(2)));
    }

    /// Gated -> Held ([`need`]): `loop.confirmations` (2) for a closure to this session within the
    /// drift model, `loop.foreign_confirmations` (4) for one to another session, one beyond the drift
    /// model (across a turn) or one that overturns a fresh alignment.
    #[test]
    fn gated_to_held_with_the_closures_it_needs() {
        let lc = LoopConfig::default();
        let n = |closures: usize, turn: bool| Need { closures, turn };
        assert_eq!(need(true, Unconfirmed, false, &lc), n(2, false));
        assert_eq!(need(false, Unconfirmed, false, &lc), n(4, false));
        assert_eq!(need(true, BeyondDrift, false, &lc), n(4, true));
        assert_eq!(need(true, Unconfirmed, true, &lc), n(4, false));
        let mut s = Session::new(0);
        let out = judge(
            &mut s,
            (10, 100.0),
            (0, 0.7),
            (aligned(true_alignment(), 100.0), BeyondDrift),
            &lc,
        );
        assert_eq!(out.state, ClosureState::Held);
        let held = &s.held_to(0)[0];
        assert_eq!((held.needed, held.turn), (4, true));
    }

    /// The test of Vouching -> Overturned ([`overturns`]): an unconfirmed closure found 10 m of path
    /// after the accepted alignment (on both passes) lies within 16.27 of it at 1 m + 0.5 x 5 % x 20
    /// m = 1.5 m of standard deviation when 6.0 m off (16.0), beyond when 6.1 m off (16.54), and then
    /// needs four closures. 70 m after it the alignment is stale and overturns nothing.
    #[test]
    fn an_unconfirmed_closure_overturns_a_vouching_alignment_it_contradicts() {
        let lc = LoopConfig::default();
        let accepted = aligned(true_alignment(), 100.0);
        let at = place(11, 110.0);
        assert!(!overturns(
            Unconfirmed,
            Some(&accepted),
            &aligned(off(6.0), 110.0),
            &at,
            &lc
        ));
        assert!(overturns(
            Unconfirmed,
            Some(&accepted),
            &aligned(off(6.1), 110.0),
            &at,
            &lc
        ));
        assert!(!overturns(
            Vouched,
            Some(&accepted),
            &aligned(off(6.1), 110.0),
            &at,
            &lc
        ));
        assert!(!overturns(
            BeyondDrift,
            Some(&accepted),
            &aligned(off(6.1), 110.0),
            &at,
            &lc
        ));
        assert!(!overturns(
            Unconfirmed,
            None,
            &aligned(off(6.1), 110.0),
            &at,
            &lc
        ));
        let stale_at = place(17, 170.0);
        assert!(!overturns(
            Unconfirmed,
            Some(&accepted),
            &aligned(off(20.0), 170.0),
            &stale_at,
            &lc
        ));
        let needed = |x: f64| {
            let mut s = Session::new(0);
            s.set_alignment(0, accepted);
            let out = judge(
                &mut s,
                (11, 110.0),
                (1, 0.7),
                (aligned(off(x), 110.0), Unconfirmed),
                &lc,
            );
            assert_eq!(out.state, ClosureState::Held);
            s.held_to(0)[0].needed
        };
        assert_eq!((needed(6.0), needed(6.1)), (2, 4));
    }

    /// Vouching -> Overturned: four closures 20 m off the accepted alignment found at 140 m, the
    /// last at 185 m (45 m on, where it still vouches), confirm each other and overturn it. The
    /// same closures after 60 m of path meet a stale alignment: two confirm, and it is Replaced.
    #[test]
    fn a_vouching_alignment_that_confirmed_closures_contradict_is_overturned() {
        let lc = LoopConfig::default();
        let slid = off(20.0);
        let mut s = Session::new(0);
        s.set_alignment(0, aligned(true_alignment(), 140.0));
        for (q, path) in [(15, 150.0), (16, 160.0), (17, 170.0)] {
            let out = judge(
                &mut s,
                (q, path),
                (q + 10, 0.7),
                (aligned(slid, path), Unconfirmed),
                &lc,
            );
            assert_eq!(out.state, ClosureState::Held, "{q}: fewer than four");
        }
        let out = judge(
            &mut s,
            (18, 185.0),
            (28, 0.7),
            (aligned(slid, 185.0), Unconfirmed),
            &lc,
        );
        assert_eq!(out.state, ClosureState::Confirmed);
        assert_eq!(ids(&out.publish), [15, 16, 17, 18]);
        assert_eq!(out.replaced, Some(AlignmentState::Overturned));
        assert_eq!(s.alignments()[&0].t, slid);
        let mut s = Session::new(0);
        s.set_alignment(0, aligned(true_alignment(), 100.0));
        let held = judge(
            &mut s,
            (17, 170.0),
            (27, 0.7),
            (aligned(slid, 170.0), Unconfirmed),
            &lc,
        );
        assert_eq!(held.state, ClosureState::Held);
        let out = judge(
            &mut s,
            (20, 200.0),
            (30, 0.7),
            (aligned(slid, 200.0), Unconfirmed),
            &lc,
        );
        assert_eq!(out.state, ClosureState::Confirmed);
        assert_eq!(out.replaced, Some(AlignmentState::Replaced));
    }

    /// Vouching -> Stale ([`vouching`]): an accepted alignment vouches while its predicted
    /// translation standard deviation, 0.5 m + 0.5 x 5 % of the path since it was found, is at most
    /// `loop.trusted_prior_std` (2 m): 60 m either way (2.0 m), not 61 m (2.025 m).
    #[test]
    fn an_accepted_alignment_is_stale_beyond_60_m_of_path() {
        let lc = LoopConfig::default();
        let mut s = Session::new(0);
        s.set_alignment(0, aligned(true_alignment(), 100.0));
        for (path, fresh) in [(160.0, true), (161.0, false), (40.0, true), (39.0, false)] {
            assert_eq!(s.vouches_for(0, path, &lc), fresh, "at {path} m");
            assert_eq!(s.any_vouches(path, &lc), fresh, "at {path} m");
        }
        assert!(!s.vouches_for(1, 100.0, &lc), "no alignment to session 1");
    }

    /// Gated -> Confirmed ([`confirms`]): two agreeing closures to this session confirm when their
    /// query keyframes lie `loop.confirmation_span` (30 m) of path apart: at 130 m after one held at
    /// 100 m, not at 129 m.
    #[test]
    fn gated_to_confirmed_across_the_confirmation_span() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let at = |path: f64| {
            let mut s = Session::new(0);
            offer(&mut s, (10, 100.0), (0, 0.7), a, &lc);
            judge(
                &mut s,
                (13, path),
                (3, 0.7),
                (aligned(a, path), Unconfirmed),
                &lc,
            )
        };
        let out = at(130.0);
        assert_eq!(out.state, ClosureState::Confirmed);
        assert_eq!(ids(&out.publish), [10, 13]);
        assert_eq!(out.moved, [moved(10, 0, ClosureState::Confirmed)]);
        assert_eq!(at(129.0).state, ClosureState::Held);
    }

    /// Gated -> Confirmed ([`confirms`]): one of the agreeing closures must reach
    /// `loop.confirmation_overlap` (0.6), the held one or the new one.
    #[test]
    fn gated_to_confirmed_with_one_strong_closure() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let state = |held: f64, new: f64| {
            let mut s = Session::new(0);
            offer(&mut s, (10, 100.0), (0, held), a, &lc);
            judge(
                &mut s,
                (14, 140.0),
                (4, new),
                (aligned(a, 140.0), Unconfirmed),
                &lc,
            )
            .state
        };
        assert_eq!(state(0.6, 0.59), ClosureState::Confirmed);
        assert_eq!(state(0.59, 0.6), ClosureState::Confirmed);
        assert_eq!(state(0.59, 0.59), ClosureState::Held);
    }

    /// Gated -> Confirmed ([`confirms`]): to another session four agreeing closures confirm
    /// (`loop.foreign_confirmations`), three do not.
    #[test]
    fn gated_to_confirmed_by_as_many_closures_as_needed() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let mut s = Session::new(1);
        for (q, path) in [(10, 100.0), (14, 140.0), (18, 180.0)] {
            let out = judge(
                &mut s,
                (q, path),
                (q - 10, 0.7),
                (aligned(a, path), Unconfirmed),
                &lc,
            );
            assert_eq!(out.state, ClosureState::Held, "{q}");
        }
        let out = judge(
            &mut s,
            (22, 220.0),
            (12, 0.7),
            (aligned(a, 220.0), Unconfirmed),
            &lc,
        );
        assert_eq!(out.state, ClosureState::Confirmed);
        assert_eq!(ids(&out.publish), [10, 14, 18, 22]);
    }

    /// Gated -> Confirmed ([`confirms`], [`turn_spanned`]): beyond the drift model four agreeing
    /// closures confirm only when two of their query keyframes' headings lie [`BEYOND_DRIFT_TURN`]
    /// (0.785 rad) apart: 0.79 rad does, 0.78 rad does not.
    #[test]
    fn gated_to_confirmed_beyond_the_drift_model_across_a_turn() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let state = |heading: f64| {
            let mut s = Session::new(0);
            for (q, path) in [(10, 100.0), (11, 110.0), (12, 120.0)] {
                judge(
                    &mut s,
                    (q, path),
                    (q - 10, 0.7),
                    (aligned(a, path), BeyondDrift),
                    &lc,
                );
            }
            let mut corner = place(14, 140.0);
            corner.t_odom_body = Iso2::new(Vec2::new(140.0, 0.0), heading);
            let c = closure(14, 4, 0.7);
            s.accept(&corner, c, 0, aligned(a, 140.0), BeyondDrift, &lc)
                .state
        };
        assert_eq!(state(0.79), ClosureState::Confirmed);
        assert_eq!(state(0.78), ClosureState::Held);
    }

    /// Held -> Confirmed ([`agreeing`]): two closures agree when their alignments lie within 16.27
    /// of each other at 1 m + 0.5 x 5 % of the path between them, 2 m over 40 m: 8.0 m apart (16.0)
    /// they confirm, 8.1 m apart (16.40) the new one is held beside the other.
    #[test]
    fn held_to_confirmed_when_the_alignments_agree() {
        let lc = LoopConfig::default();
        let state = |x: f64| {
            let mut s = Session::new(0);
            offer(&mut s, (10, 100.0), (0, 0.7), true_alignment(), &lc);
            let out = judge(
                &mut s,
                (14, 140.0),
                (4, 0.7),
                (aligned(off(x), 140.0), Unconfirmed),
                &lc,
            );
            (out.state, s.held_to(0).len())
        };
        assert_eq!(state(8.0), (ClosureState::Confirmed, 0));
        assert_eq!(state(8.1), (ClosureState::Held, 2));
    }

    /// Held -> Outvoted: a confirmation takes the held closures that agree with the new one, and
    /// every other closure held to the session leaves with them: one 20 m off the true alignment is
    /// dropped when two true ones confirm.
    #[test]
    fn held_to_outvoted_when_others_are_confirmed() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let mut s = Session::new(0);
        assert!(offer(&mut s, (10, 100.0), (0, 0.7), off(20.0), &lc).is_empty());
        assert!(offer(&mut s, (11, 105.0), (1, 0.7), a, &lc).is_empty());
        let out = judge(
            &mut s,
            (14, 140.0),
            (4, 0.7),
            (aligned(a, 140.0), Unconfirmed),
            &lc,
        );
        assert_eq!(out.state, ClosureState::Confirmed);
        assert_eq!(ids(&out.publish), [11, 14]);
        assert_eq!(
            out.moved,
            [
                moved(11, 1, ClosureState::Confirmed),
                moved(10, 0, ClosureState::Outvoted)
            ]
        );
        assert!(s.held_to(0).is_empty());
    }

    /// Held -> Expired ([`expired`]): a closure held at 100 m still confirms with one at 250 m
    /// (`loop.confirmation_horizon`, 150 m, after it); at 250.5 m it has expired, and the new one is
    /// held alone.
    #[test]
    fn held_to_expired_beyond_the_confirmation_horizon() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let at = |path: f64| {
            let mut s = Session::new(0);
            offer(&mut s, (10, 100.0), (0, 0.7), a, &lc);
            let out = judge(
                &mut s,
                (25, path),
                (15, 0.7),
                (aligned(a, path), Unconfirmed),
                &lc,
            );
            (out, s.held_to(0).len())
        };
        let (out, held) = at(250.0);
        assert_eq!((out.state, held), (ClosureState::Confirmed, 0));
        let (out, held) = at(250.5);
        assert_eq!((out.state, held), (ClosureState::Held, 1));
        assert_eq!(out.moved, [moved(10, 0, ClosureState::Expired)]);
    }

    /// Held -> Replaced ([`replaced`]): a closure of the same pair of keyframes held again (a walk
    /// finds it again) takes the held one's place; another pair of the same query keyframe is held
    /// beside it.
    #[test]
    fn held_to_replaced_by_the_same_pair() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let mut s = Session::new(0);
        let out = judge(
            &mut s,
            (10, 100.0),
            (0, 0.7),
            (aligned(a, 100.0), Unconfirmed),
            &lc,
        );
        assert_eq!((out.state, out.moved.len()), (ClosureState::Held, 0));
        let again = aligned(off(0.5), 100.0);
        let out = judge(&mut s, (10, 100.0), (0, 0.8), (again, Unconfirmed), &lc);
        assert_eq!(out.state, ClosureState::Held);
        assert_eq!(out.moved, [moved(10, 0, ClosureState::Replaced)]);
        assert_eq!(s.held_to(0).len(), 1);
        assert_eq!(s.held_to(0)[0].alignment, again);
        let out = judge(
            &mut s,
            (10, 100.0),
            (1, 0.8),
            (aligned(a, 100.0), Unconfirmed),
            &lc,
        );
        assert!(out.moved.is_empty());
        assert_eq!(s.held_to(0).len(), 2);
    }

    /// Held -> Refuted ([`refuted`]): a closure published on the accepted alignment's word drops a
    /// held closure whose alignment lies beyond 16.27 of its own, with the drift over the 20 m of
    /// path between them on each pass (1 m + 0.5 x 5 % x 40 m = 2 m): 8.1 m off (16.40) is refuted,
    /// 8.0 m off (16.0) stays held.
    #[test]
    fn held_to_refuted_by_a_vouched_closure() {
        let lc = LoopConfig::default();
        let a = true_alignment();
        let refuted_at = |x: f64| {
            let mut s = Session::new(0);
            s.set_alignment(0, aligned(a, 90.0));
            assert!(offer(&mut s, (10, 100.0), (0, 0.7), off(x), &lc).is_empty());
            let out = judge(
                &mut s,
                (12, 120.0),
                (2, 0.7),
                (aligned(a, 120.0), Vouched),
                &lc,
            );
            assert_eq!(out.state, ClosureState::Published);
            (out.moved, s.held_to(0).len())
        };
        assert_eq!(
            refuted_at(8.1),
            (vec![moved(10, 0, ClosureState::Refuted)], 0)
        );
        assert_eq!(refuted_at(8.0), (vec![], 1));
    }

    /// Held -> Unreachable ([`unreachable`]): a closure to another robot's session is dropped when
    /// that robot's alignment arrives and the closure lies beyond three times the drift model's
    /// bounds of it. Found where the closure was (no path between), the drift is 15 m / 3 = 5 m;
    /// with the closure's 1 m, 9 x 16.27 = 146.43 allows 61.7 m: 61 m off (143.1) stays held, 62 m
    /// off (147.8) does not.
    #[test]
    fn held_to_unreachable_from_a_shared_alignment() {
        let lc = LoopConfig::default();
        let dropped = |x: f64| {
            let mut s = Session::new(1);
            let mut c = closure(10, 0, 0.7);
            c.t_match_query = iso3_from_iso2(&Iso2::new(Vec2::new(x, 0.0), 0.0));
            let implied = aligned(Iso2::identity(), 100.0);
            let out = s.accept(&place(10, 100.0), c, 0, implied, Unconfirmed, &lc);
            assert_eq!(out.state, ClosureState::Held);
            let moved = s.take_shared(0, aligned(Iso2::identity(), 100.0), &lc);
            (moved, s.held_to(0).len())
        };
        assert_eq!(dropped(61.0), (vec![], 1));
        assert_eq!(
            dropped(62.0),
            (vec![moved(10, 0, ClosureState::Unreachable)], 0)
        );
    }

    /// Gated -> Published or Unvouched ([`published_late`]): a search again and another robot's
    /// arriving keyframe publish only what a fresh alignment vouches for.
    #[test]
    fn gated_to_unvouched_late_unless_vouched() {
        assert!(published_late(Vouched));
        assert!(!published_late(Unconfirmed));
        assert!(!published_late(BeyondDrift));
    }

    /// Gated -> OffWalk ([`off_walk`]): a walk for closures to one session drops a closure to another.
    #[test]
    fn gated_to_off_walk_when_it_goes_to_another_session() {
        assert!(off_walk(0, Some(1)));
        assert!(!off_walk(1, Some(1)));
        assert!(!off_walk(0, None), "not on a walk");
    }

    /// Beyond the drift model the odometry between two keyframes is not known to the model's
    /// accuracy: a closure slid by a guard rail post period, which its neighbour 10 m on does not
    /// agree with (`a_closure_slid_by_a_post_period_is_not_confirmed_by_its_neighbour`), agrees there
    /// on its alignment alone.
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
}
