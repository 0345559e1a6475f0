//! The closures held until others confirm them ([`HeldClosures`]), per session: a closure that
//! passed the gates and is not published alone is held, and leaves the list confirmed with those
//! that agree with it, or dropped (expired, replaced by the same pair, left out of a confirmation,
//! refuted by a closure on the accepted alignment's word, or beyond reach of a shared alignment).

use std::collections::BTreeMap;

use super::super::drift::{
    alignment_distance, anchored_inconsistency, closure_disagreement, within_reach,
};
use super::super::{LoopClosure, LoopConfig};
use super::{Alignment, QueryPlace};

/// Gate on the agreement of two closures' alignments (the 99.9 % chi-square quantile, 3 dof).
pub(super) const CONFIRM_CHI2: f64 = 16.27;

/// Closures beyond the drift model confirm each other only when their query keyframes' headings
/// differ by at least this, rad (45 degrees): they come from two streets that meet at an angle. Along
/// one street the view repeats across the block grid, and a parallel street a block or more away
/// agrees with itself from every keyframe; the same shift rarely also aligns the street that turns off
/// it.
const BEYOND_DRIFT_TURN: f64 = std::f64::consts::FRAC_PI_4;

/// A closure waiting for confirmation, with the alignment it implies and the number of agreeing
/// closures (itself included) it needs.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Held {
    pub(super) closure: LoopClosure,
    pub(super) alignment: Alignment,
    pub(super) needed: usize,
    /// The query keyframe's odometry heading, rad.
    pub(super) heading: f64,
    /// It lies beyond the drift model: its confirmation must span a turn ([`BEYOND_DRIFT_TURN`]).
    pub(super) turn: bool,
}

/// What a held closure needs before it is published: this many agreeing closures, itself
/// included, and whether their query keyframes must span a turn ([`BEYOND_DRIFT_TURN`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Need {
    pub(super) closures: usize,
    pub(super) turn: bool,
}

/// The closures held for confirmation, by the session they go to.
#[derive(Debug, Clone, Default)]
pub(super) struct HeldClosures {
    by_session: BTreeMap<u32, Vec<Held>>,
}

impl HeldClosures {
    /// The alignment of the newest closure held to `session`.
    pub(super) fn newest(&self, session: u32) -> Option<Alignment> {
        Some(self.by_session.get(&session)?.last()?.alignment)
    }

    /// The sessions closures have been held to.
    pub(super) fn sessions(&self) -> impl Iterator<Item = u32> + '_ {
        self.by_session.keys().copied()
    }

    /// The closures held to `session`.
    #[cfg(test)]
    pub(super) fn of(&self, session: u32) -> &[Held] {
        self.by_session.get(&session).map_or(&[], Vec::as_slice)
    }

    /// Drops the closures held to `session` that lie beyond [`within_reach`] of every alignment in
    /// `known` ([`super::super::drift::Prior::Anchored`]).
    pub(super) fn drop_unreachable(&mut self, session: u32, known: &[Alignment], lc: &LoopConfig) {
        let Some(pending) = self.by_session.get_mut(&session) else {
            return;
        };
        pending.retain(|h| {
            let paths = [h.alignment.path, h.alignment.match_path];
            let d2 = |a: &Alignment| anchored_inconsistency(a, &h.closure, paths, lc);
            let keep = known
                .iter()
                .any(|a| d2(a).is_none_or(|d2| within_reach(d2, lc)));
            if !keep {
                log::debug!(
                    "held closure {} -> {} dropped: it lies beyond the drift from every alignment to session {session} known here",
                    h.closure.query_id,
                    h.closure.match_id
                );
            }
            keep
        });
    }

    /// A closure to `session` with `alignment` was published on a fresh alignment's word: the held
    /// closures to that session whose alignments it contradicts are dropped ([`apart`] beyond
    /// [`CONFIRM_CHI2`]). Each contradicts an alignment that
    /// a newer closure has borne out; left waiting, two such closures on either side of a stretch
    /// the alignment keeps vouching for would confirm each other and replace it (a road slid along
    /// itself by its repeating posts agrees with itself over the drift between them). A false
    /// accepted alignment is still replaced once it stops vouching for new closures: the
    /// contradicting closures after that confirm each other.
    pub(super) fn refute(
        &mut self,
        query: &QueryPlace,
        session: u32,
        alignment: &Alignment,
        lc: &LoopConfig,
    ) {
        let Some(pending) = self.by_session.get_mut(&session) else {
            return;
        };
        pending.retain(|h| {
            let d2 = apart(&h.alignment, alignment, query, lc);
            if d2 > CONFIRM_CHI2 {
                log::debug!(
                    "held closure {} -> {} dropped: closure {} on the accepted alignment contradicts it (squared distance {d2:.1})",
                    h.closure.query_id,
                    h.closure.match_id,
                    query.id
                );
            }
            d2 <= CONFIRM_CHI2
        });
    }

    /// Holds `c` or, when enough closures to `session` agree (held ones and `c`, as many as the most
    /// demanding of them needs, across a turn when one of them needs it), returns them with it (in
    /// query order, `c` last) and the alignments they imply (`c`'s first).
    pub(super) fn confirm(
        &mut self,
        query: &QueryPlace,
        c: LoopClosure,
        (session, need): (u32, Need),
        alignment: Alignment,
        lc: &LoopConfig,
    ) -> Option<(Vec<LoopClosure>, Vec<Alignment>)> {
        let pending = self.by_session.entry(session).or_default();
        // Old unconfirmed hypotheses expire before they may confirm anything.
        pending.retain(|h| query.path - h.alignment.path <= lc.confirmation_horizon);
        let agree = agreeing(pending, query, &c, need.turn, &alignment, lc);
        let needed = agree
            .iter()
            .map(|&k| pending[k].needed)
            .fold(need.closures, usize::max);
        let heading = query.t_odom_body.rotation.angle();
        if !confirmed(pending, &agree, query, &c, need, needed, lc) {
            log::debug!(
                "closure {} -> {} held until another closure to session {session} confirms it ({} inliers, overlap {:.2}, alignment {:.2} {:.2} {:.3})",
                c.query_id,
                c.match_id,
                c.inliers,
                c.score,
                alignment.t.translation.x,
                alignment.t.translation.y,
                alignment.t.rotation.angle()
            );
            // A keyframe searched again (a walk) can find a pair it holds already: held once.
            let pair = (c.query_id, c.match_id);
            pending.retain(|h| (h.closure.query_id, h.closure.match_id) != pair);
            pending.push(Held {
                closure: c,
                alignment,
                needed,
                heading,
                turn: need.turn,
            });
            return None;
        }
        let mut kept = std::mem::take(pending);
        let mut publish = Vec::new();
        let mut anchors = vec![alignment];
        for k in agree.into_iter().rev() {
            let h = kept.swap_remove(k);
            publish.push(h.closure);
            anchors.push(h.alignment);
        }
        publish.sort_by_key(|p| p.query_id);
        publish.push(c);
        log::info!(
            "closures to session {session} confirmed by {} agreeing matches",
            publish.len()
        );
        Some((publish, anchors))
    }
}

/// Whether the headings, `first` and the rest, differ pairwise by at least [`BEYOND_DRIFT_TURN`]
/// somewhere.
pub(super) fn turn_spanned(first: f64, rest: impl Iterator<Item = f64>) -> bool {
    let all: Vec<f64> = std::iter::once(first).chain(rest).collect();
    all.iter().enumerate().any(|(i, a)| {
        all[i + 1..]
            .iter()
            .any(|b| crate::math::wrap_angle(a - b).abs() >= BEYOND_DRIFT_TURN)
    })
}

/// Squared distance ([`alignment_distance`]) between an earlier alignment and `alignment`, which a
/// closure at `query` implies, with the drift over the path between the two query keyframes and
/// between the two match keyframes: two true closures onto two passes of one place a lap apart imply
/// alignments that differ by the drift over that lap.
pub(super) fn apart(
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

/// The held closures (indices into `pending`) from other query keyframes that agree with `c`: their
/// alignments within [`CONFIRM_CHI2`] of `alignment`, `c`'s, at the generous accuracy of
/// [`alignment_distance`] plus the drift between them, and, unless `c` or the held closure lies
/// beyond the drift model (`beyond`, [`Held::turn`]), each closure within [`CONFIRM_CHI2`] of its
/// prediction from `c` under the two closures' own covariances and the drift model
/// ([`closure_disagreement`]). The first tells one street from another; the second keeps out a
/// closure slid along the street by the period of its posts, which fits as well as the true
/// alignment and lies metres away where its covariance says centimetres. Beyond the drift model the
/// odometry between the two keyframes is not known to the model's accuracy, and only the first
/// applies.
pub(super) fn agreeing(
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

/// Whether `c` with the held closures `agree` confirms: `needed` closures in all, their query
/// keyframes spanning `confirmation_span` of path, one of them strong (`confirmation_overlap`), and
/// across a turn when `need` or one of them asks for it.
fn confirmed(
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
