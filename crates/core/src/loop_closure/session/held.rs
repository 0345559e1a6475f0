//! The closures held until others confirm them ([`HeldClosures`]), per session they go to. A
//! closure that passed the gates and is not published alone is held; it leaves the list Confirmed
//! with those that agree with it, or dropped: Expired, Replaced by the same pair, Outvoted by a
//! confirmation it is not part of, Refuted by a closure on the accepted alignment's word, or
//! Unreachable from a shared alignment. Each move is a transition of [`super::super::decision`],
//! and each is reported ([`Moved`]).

use std::collections::BTreeMap;

use super::super::decision::{
    ClosureState, Held, Moved, Need, agreeing, apart, confirms, expired, refuted, replaced,
    unreachable,
};
use super::super::{LoopClosure, LoopConfig};
use super::{Alignment, QueryPlace};

/// What [`HeldClosures::offer`] did with a closure.
#[derive(Debug)]
pub(super) struct Confirmation {
    /// [`ClosureState::Held`] or [`ClosureState::Confirmed`].
    pub(super) state: ClosureState,
    /// When confirmed: the confirmed closures in query order, the offered one last.
    pub(super) publish: Vec<LoopClosure>,
    /// When confirmed: the alignments they imply, the offered closure's first.
    pub(super) anchors: Vec<Alignment>,
    /// The held closures that left the list, in the order they left.
    pub(super) moved: Vec<Moved>,
}

/// The closures held for confirmation, by the session they go to.
#[derive(Debug, Clone, Default)]
pub(super) struct HeldClosures {
    by_session: BTreeMap<u32, Vec<Held>>,
}

/// Drops from `pending` the closures `leaves` says move to `to`, each noted in `moved`.
fn drop_where(
    pending: &mut Vec<Held>,
    to: ClosureState,
    moved: &mut Vec<Moved>,
    mut leaves: impl FnMut(&Held) -> bool,
) {
    pending.retain(|h| {
        let gone = leaves(h);
        if gone {
            moved.push(Moved::of(&h.closure, to));
        }
        !gone
    });
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

    /// Held → Unreachable ([`unreachable`]) for the closures held to `session`, given the
    /// alignments to it `known` here.
    pub(super) fn drop_unreachable(
        &mut self,
        session: u32,
        known: &[Alignment],
        lc: &LoopConfig,
    ) -> Vec<Moved> {
        let mut moved = Vec::new();
        let Some(pending) = self.by_session.get_mut(&session) else {
            return moved;
        };
        drop_where(pending, ClosureState::Unreachable, &mut moved, |h| {
            let gone = unreachable(h, known, lc);
            if gone {
                log::debug!(
                    "held closure {} -> {} dropped: it lies beyond the drift from every alignment to session {session} known here",
                    h.closure.query_id,
                    h.closure.match_id
                );
            }
            gone
        });
        moved
    }

    /// Held → Refuted ([`refuted`]) for the closures held to `session`: a closure at `query` that
    /// implies `alignment` was published on a fresh alignment's word.
    pub(super) fn refute(
        &mut self,
        query: &QueryPlace,
        session: u32,
        alignment: &Alignment,
        lc: &LoopConfig,
    ) -> Vec<Moved> {
        let mut moved = Vec::new();
        let Some(pending) = self.by_session.get_mut(&session) else {
            return moved;
        };
        drop_where(pending, ClosureState::Refuted, &mut moved, |h| {
            let gone = refuted(h, alignment, query, lc);
            if gone {
                log::debug!(
                    "held closure {} -> {} dropped: closure {} on the accepted alignment contradicts it (squared distance {:.1})",
                    h.closure.query_id,
                    h.closure.match_id,
                    query.id,
                    apart(&h.alignment, alignment, query, lc)
                );
            }
            gone
        });
        moved
    }

    /// A closure `c` to `session` that needs `need` and is not published alone: the held ones to
    /// that session expire first ([`expired`]); then `c` with those that agree with it
    /// ([`agreeing`]) confirms ([`confirms`]: they are Confirmed, every other one held to the
    /// session Outvoted), or `c` is Held (in place of a held closure of the same pair,
    /// [`replaced`]).
    pub(super) fn offer(
        &mut self,
        query: &QueryPlace,
        c: LoopClosure,
        (session, need): (u32, Need),
        alignment: Alignment,
        lc: &LoopConfig,
    ) -> Confirmation {
        let mut moved = Vec::new();
        let pending = self.by_session.entry(session).or_default();
        // Old unconfirmed hypotheses expire before they may confirm anything.
        drop_where(pending, ClosureState::Expired, &mut moved, |h| {
            expired(h, query, lc)
        });
        let agree = agreeing(pending, query, &c, need.turn, &alignment, lc);
        let needed = agree
            .iter()
            .map(|&k| pending[k].needed)
            .fold(need.closures, usize::max);
        let heading = query.t_odom_body.rotation.angle();
        if !confirms(pending, &agree, query, &c, need, needed, lc) {
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
            drop_where(pending, ClosureState::Replaced, &mut moved, |h| {
                replaced(h, &c)
            });
            pending.push(Held {
                closure: c,
                alignment,
                needed,
                heading,
                turn: need.turn,
            });
            return Confirmation {
                state: ClosureState::Held,
                publish: Vec::new(),
                anchors: Vec::new(),
                moved,
            };
        }
        let mut kept = std::mem::take(pending);
        let mut publish = Vec::new();
        let mut anchors = vec![alignment];
        for k in agree.into_iter().rev() {
            let h = kept.swap_remove(k);
            moved.push(Moved::of(&h.closure, ClosureState::Confirmed));
            publish.push(h.closure);
            anchors.push(h.alignment);
        }
        moved.extend(
            kept.iter()
                .map(|h| Moved::of(&h.closure, ClosureState::Outvoted)),
        );
        publish.sort_by_key(|p| p.query_id);
        publish.push(c);
        log::info!(
            "closures to session {session} confirmed by {} agreeing matches",
            publish.len()
        );
        Confirmation {
            state: ClosureState::Confirmed,
            publish,
            anchors,
            moved,
        }
    }
}
