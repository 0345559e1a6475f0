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
use super::session::{Held, QueryPlace};
use super::{Alignment, LoopClosure, LoopConfig};

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
    use super::super::session::fixtures::*;
    use super::*;
    use crate::math::{Iso2, Vec2};

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
