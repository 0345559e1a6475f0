//! Loop closures: revisits of a new keyframe searched in the keyframe map, registered, gated and
//! published, held until confirmed, or refused with a reason.
//!
//! Steps for each new keyframe ([`LoopCloser::search`]), in order: candidates from the keyframe map
//! (around the odometry position under the drift model, around an accepted or held alignment, around
//! the position an accepted or held alignment to another session predicts in its frame, and by place
//! descriptor); registration of each, in parallel; the gates ([`gates`]); the best closure
//! that passes the prediction and slide tests (while an alignment vouches and none passes, the same
//! for the next keyframes nearest to the position it predicts, [`KeyframeDb::candidate_rounds`]);
//! the closure decision ([`decision`], applied by [`Session::accept`]: published, held, or
//! confirmed with those it agrees with). After a confirmation, the keyframes that got nothing are
//! searched again, a few per new keyframe ([`LoopCloser::backfill`]).
//!
//! Entry points: [`LoopCloser`], [`LoopClosure`], [`Decision`], [`RejectReason`], [`LoopConfig`];
//! the closure decision's states and transitions are [`decision`], the state of acceptance is
//! [`Session`], the drift model [`drift`].

pub mod calibration;
mod config;
pub mod deadline;
pub mod decision;
pub mod drift;
pub mod gates;
mod session;

pub use config::LoopConfig;
pub use decision::QueryPlace;
pub use decision::{AlignmentState, ClosureState, Moved, Standing};
pub use session::{Alignment, Outcome, Session};

use rayon::prelude::*;
use std::sync::Arc;

use crate::keyframe_db::{
    Candidate, CandidateQuery, KeyframeDb, KeyframeRecord, Origin, SessionPrior,
};
use crate::math::{Iso3, Mat3, Mat6, Stamp, iso2_from_iso3};
use crate::registration::{PreparedSubmap, RegistrationConfig, register_prepared};
use deadline::{Deadline, Trimmed};
use gates::{Gated, Gates, Pair, gate, later_round, prediction_test, slide_test};

/// A verified loop closure: the query keyframe's body frame in the match keyframe's body frame.
/// Inside the loop closer the ids are local (positions in the keyframe map); the pipeline's events name
/// each keyframe by its id in its robot's own sequence ([`KeyframeDb::public_id`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LoopClosure {
    /// Newer keyframe.
    pub query_id: u64,
    /// Older, revisited keyframe (of `match_origin`'s robot when set).
    pub match_id: u64,
    /// Query keyframe stamp.
    pub query_stamp: Stamp,
    /// Match keyframe stamp.
    pub match_stamp: Stamp,
    /// Odometry pose of the query keyframe.
    pub query_odom_pose: Iso3,
    /// Odometry pose of the match keyframe.
    pub match_odom_pose: Iso3,
    /// Query body frame in the match body frame.
    pub t_match_query: Iso3,
    /// Covariance of `t_match_query`, ROS order (x, y, z, rot x, rot y, rot z), right perturbation.
    pub covariance: Mat6,
    /// Registration inliers.
    pub inliers: u32,
    /// Quality score: the registration's overlap (share of points with a partner, 0..1).
    pub score: f64,
    /// Session of the match keyframe (an earlier drive when it came from a loaded map).
    pub match_session: u32,
    /// `node.robot_id` of this robot, whose keyframe the query is.
    pub query_robot: i32,
    /// Where the match keyframe came from when another robot made it (`None`: this robot's own).
    pub match_origin: Option<Origin>,
}

impl LoopClosure {
    /// The match keyframe as the fleet names it: its robot and its id in that robot's map.
    pub fn match_key(&self) -> (i32, u64) {
        self.match_origin
            .map_or((self.query_robot, self.match_id), |o| (o.robot, o.id))
    }
}

/// Why a candidate revisit was not published.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum RejectReason {
    /// Registration failed (too few points or inliers, numerical failure).
    Registration,
    /// Fewer inliers than `loop.minimum_inliers`.
    FewInliers,
    /// The optimiser did not converge.
    NotConverged,
    /// The covariance exceeds `loop.maximum_*_std`.
    Uncertain,
    /// The overlap is below `loop.minimum_overlap`.
    LowOverlap,
    /// The closure contradicts odometry and earlier closures (`loop.consistency_chi2`).
    Inconsistent,
    /// Another alignment fits nearly as well (`loop.maximum_ambiguity`, `loop.maximum_slide_ratio`).
    Ambiguous,
    /// The two submaps look in directions too different to have seen the same things
    /// (`loop.minimum_common_view`).
    NoCommonView,
}

impl RejectReason {
    /// Short snake_case name for logs and diagnostics.
    pub fn name(self) -> &'static str {
        match self {
            RejectReason::Registration => "registration_failed",
            RejectReason::FewInliers => "few_inliers",
            RejectReason::NotConverged => "not_converged",
            RejectReason::Uncertain => "covariance_too_large",
            RejectReason::LowOverlap => "low_overlap",
            RejectReason::Inconsistent => "inconsistent",
            RejectReason::Ambiguous => "ambiguous",
            RejectReason::NoCommonView => "no_common_view",
        }
    }
}

/// What the loop closer decided about a candidate revisit.
#[derive(Debug, Clone, PartialEq)]
pub enum Decision {
    /// A loop closure passed every gate and is published.
    Published(Box<LoopClosure>),
    /// A candidate was refused.
    Rejected {
        /// Query keyframe.
        query_id: u64,
        /// Candidate keyframe.
        match_id: u64,
        /// Why.
        reason: RejectReason,
        /// Details for the log.
        detail: String,
    },
}

/// The decisions of one step, the registrations it ran and what its deadline left out.
#[derive(Debug, Default)]
pub struct Decisions {
    /// In the order they were taken.
    pub decisions: Vec<Decision>,
    /// Registrations run.
    pub registrations: u64,
    /// Work left out because the deadline had passed ([`LoopCloser::set_deadline`]).
    pub trimmed: Trimmed,
}

impl Decisions {
    fn reject(&mut self, query_id: u64, match_id: u64, (reason, detail): gates::Refusal) {
        log::debug!(
            "revisit {query_id} -> {match_id} rejected ({}): {detail}",
            reason.name()
        );
        self.decisions.push(Decision::Rejected {
            query_id,
            match_id,
            reason,
            detail,
        });
    }
}

/// Revisit search and closure acceptance for one session.
pub struct LoopCloser {
    lc: LoopConfig,
    rc: RegistrationConfig,
    session: u32,
    state: Session,
    /// Time from the oldest to the newest scan of the last submap, s.
    submap_span: f64,
    /// The last submap's [`crate::submap::Submap::motion`].
    submap_motion: Mat3,
    /// When the current input's search should have ended.
    deadline: Deadline,
}

impl LoopCloser {
    /// New gates and search settings (a run-time parameter change); the session state stays.
    pub fn set_config(&mut self, lc: LoopConfig) {
        self.lc = lc;
    }

    /// A loop closer for session `session` (earlier sessions are those of a loaded map).
    pub fn new(lc: LoopConfig, rc: RegistrationConfig, session: u32) -> Self {
        LoopCloser {
            lc,
            rc,
            session,
            state: Session::new(session),
            submap_span: 0.0,
            submap_motion: Mat3::zeros(),
            deadline: Deadline::default(),
        }
    }

    /// The time by which the searches of the next input should end (`None`: no limit); past it,
    /// work is left out in the order [`deadline`] gives.
    pub fn set_deadline(&mut self, at: Option<std::time::Instant>) {
        self.deadline = Deadline::new(at);
    }

    /// The time the newest keyframe's submap spans, from its oldest to its newest scan, s: every
    /// submap stacks the same number of scans of the same radars, so a keyframe's scans lie on
    /// average half of it times the keyframe's speed behind the keyframe.
    pub fn note_submap_span(&mut self, seconds: f64) {
        if seconds.is_finite() && seconds >= 0.0 {
            self.submap_span = seconds;
        }
    }

    /// The newest keyframe's submap's uncertainty from the odometry's motion
    /// ([`crate::submap::Submap::motion`]): the odometry's noise is the same along a drive, so every
    /// submap of it, the candidates' too, carries about as much ([`Pair::motion`]).
    pub fn note_submap_motion(&mut self, motion: Mat3) {
        if motion.iter().all(|v| v.is_finite()) {
            self.submap_motion = motion;
        }
    }

    /// The speeds and arms of a pair of keyframes ([`Pair::speeds`], [`Pair::arms`]).
    fn motion(
        &self,
        db: &KeyframeDb,
        query: &KeyframeRecord,
        cand: &KeyframeRecord,
    ) -> ([f64; 2], [f64; 2]) {
        let speeds = speeds(db, query, cand);
        (speeds, speeds.map(|v| 0.5 * v * self.submap_span))
    }

    /// Another robot's node accepted an alignment of its session `session` (local number) to this
    /// session; `alignment` is it inverted. Closures to `session` are tested against it until this
    /// session has an alignment of its own ([`Session::take_shared`]).
    pub fn take_shared(&mut self, session: u32, alignment: Alignment) {
        self.state.take_shared(session, alignment, &self.lc);
    }

    /// The state of acceptance.
    pub fn state(&self) -> &Session {
        &self.state
    }

    /// The state of acceptance, to set up a test.
    #[cfg(test)]
    pub(crate) fn state_mut(&mut self) -> &mut Session {
        &mut self.state
    }

    /// A new keyframe of this session (not yet in `db`): its revisits searched, its closure published
    /// or held.
    pub fn search(
        &mut self,
        db: &mut KeyframeDb,
        query: &KeyframeRecord,
        prepared: &PreparedSubmap,
        out: &mut Decisions,
    ) {
        let horizon = self.lc.backfill_horizon;
        self.state
            .note_keyframe(query.id, query.path_distance, horizon);
        if let Some(found) = self.best_closure(db, query, prepared, out) {
            self.offer(db, query, found, None, out);
        }
    }

    /// `query`'s best closure among its candidates, offered for acceptance: published, held or
    /// confirming held ones ([`Session::accept`]). With `only` (a walk's session), a closure to
    /// another session is dropped ([`decision::off_walk`]).
    fn offer(
        &mut self,
        db: &KeyframeDb,
        query: &KeyframeRecord,
        (c, standing): (LoopClosure, Standing),
        only: Option<u32>,
        out: &mut Decisions,
    ) {
        let Some((session, alignment)) = closure_alignment(db, query, &c) else {
            return;
        };
        if decision::off_walk(session, only) {
            return;
        }
        let place = QueryPlace {
            id: query.id,
            path: query.path_distance,
            t_odom_body: query.t_odom_body,
        };
        let outcome = self
            .state
            .accept(&place, c, session, alignment, standing, &self.lc);
        self.publish(outcome.publish, out);
    }

    /// Another robot's keyframe `index`, just added to `db`: this session's keyframes that may revisit
    /// it and are this node's to register ([`KeyframeDb::revisits_of`]) are registered against it and
    /// gated; as in [`LoopCloser::backfill`], a closure is published only when it agrees with a fresh
    /// alignment to that robot's session.
    pub fn search_arrival(&mut self, db: &mut KeyframeDb, index: u64, out: &mut Decisions) {
        let Some(arrived) = db.get(index).cloned() else {
            return;
        };
        // Only keyframes an accepted alignment to the robot's session vouches for (`trusted_prior_std`)
        // could publish what is found here: the others are not registered.
        let Some(alignment) = self.state.alignments().get(&arrived.session).copied() else {
            return;
        };
        let target = match db.prepared(index as usize, &self.rc) {
            Ok(t) => t,
            Err(e) => {
                log::debug!("keyframe {index} of another robot not searched: {e}");
                return;
            }
        };
        let mut pairs = Vec::new();
        for cand in db.revisits_of(index as usize, self.session, &self.lc.search()) {
            let Some(query) = db.get(cand.index as u64).cloned() else {
                continue;
            };
            if !decision::vouching(&alignment, query.path_distance, &self.lc) {
                continue;
            }
            match db.prepared(cand.index, &self.rc) {
                Ok(source) => pairs.push((query, source)),
                Err(e) => out.reject(query.id, index, (RejectReason::Registration, e.to_string())),
            }
        }
        out.registrations += pairs.len() as u64;
        let cfg = self.search_registration();
        let results: Vec<_> = pairs
            .par_iter()
            .map(|(_, source)| register_prepared(source, &target, &cfg))
            .collect();
        for ((query, source), res) in pairs.into_iter().zip(results) {
            let (speeds, arms) = self.motion(db, &query, &arrived);
            let pair = Pair {
                query: &query,
                cand: &arrived,
                source: &source,
                target: &target,
                speeds,
                arms,
                motion: self.submap_motion,
            };
            let passed = match gate(&self.gates(), &pair, res) {
                Ok(gated) => vec![(gated, target.clone())],
                Err(refusal) => {
                    out.reject(query.id, index, refusal);
                    continue;
                }
            };
            // Only what agrees with a fresh alignment to the robot's session is published from here:
            // the first closures to a session come from new keyframes, whose candidates compete.
            match self.first_that_passes(passed, &source, out) {
                Some((c, standing)) if decision::published_late(standing) => {
                    self.publish(vec![c], out)
                }
                Some((c, _)) => log::debug!(
                    "revisit {} -> {index} of another robot passed the gates, but no fresh alignment to its session vouches for it",
                    c.query_id
                ),
                None => {}
            }
        }
    }

    /// Searches up to `n` keyframes again (`loop.backfill_per_keyframe`; at the end of the input, all
    /// of them): first those queued after a confirmation ([`LoopCloser::search_again`]), then the
    /// walks over keyframes without a closure to another robot's session ([`LoopCloser::walk`]).
    pub fn backfill(&mut self, db: &mut KeyframeDb, n: usize, out: &mut Decisions) {
        for _ in 0..n {
            if self.deadline.passed() {
                out.trimmed.backfill += 1;
                return;
            }
            if let Some(id) = self.state.next_backfill() {
                self.search_again(db, id, out);
            } else if let Some((session, id)) = self.state.next_walk() {
                self.walk(db, session, id, out);
            } else {
                return;
            }
        }
    }

    /// Searches keyframe `id`, queued after a confirmation, again. Only what agrees with a fresh
    /// alignment is published from here, and the keyframes queued after this one on its walk lie
    /// further along the path from the confirmation: once no alignment is fresh enough to vouch
    /// (`loop.trusted_prior_std`), the rest of that walk is not searched again here
    /// ([`Session::walk_gone_stale`] says what becomes of it).
    fn search_again(&mut self, db: &mut KeyframeDb, id: u64, out: &mut Decisions) {
        let Some((rec, prepared)) = self.keyframe(db, id) else {
            return;
        };
        // Searched around the chain's alignment instead of the newest one, which is put back after.
        let swapped = self.state.swap_in_chain(rec.path_distance, &self.lc);
        let fresh = self.state.any_vouches(rec.path_distance, &self.lc);
        let found = if fresh {
            self.best_closure(db, &rec, &prepared, out)
        } else {
            None
        };
        self.state.restore(swapped);
        if !fresh {
            log::debug!(
                "search again stopped at keyframe {id} ({} beyond it): no alignment is fresh enough there",
                self.state.backfill_len()
            );
            let foreign = db.foreign();
            self.state.walk_gone_stale(id, rec.path_distance, |s| {
                foreign.session_origin(s).is_some()
            });
            return;
        }
        // Only what agrees with the alignment that vouches is published.
        let Some((c, standing)) = found else {
            return;
        };
        if !decision::published_late(standing) {
            return;
        }
        if let Some((s, alignment)) = closure_alignment(db, &rec, &c) {
            self.state.extend_chain(s, alignment);
        }
        self.publish(vec![c], out);
    }

    /// Searches keyframe `id`, which has no closure, again as a new keyframe is searched, for a
    /// closure to `session` (another robot's): around that robot's shared alignment, or the
    /// alignment this node accepted that no longer vouches there ([`Session::next_walk`]). What it
    /// finds is offered for acceptance and held until others agree.
    fn walk(&mut self, db: &mut KeyframeDb, session: u32, id: u64, out: &mut Decisions) {
        let Some((rec, prepared)) = self.keyframe(db, id) else {
            return;
        };
        if let Some(found) = self.best_closure(db, &rec, &prepared, out) {
            self.offer(db, &rec, found, Some(session), out);
        }
    }

    /// Keyframe `id` of the map and its prepared submap, if it can be searched.
    fn keyframe(
        &self,
        db: &mut KeyframeDb,
        id: u64,
    ) -> Option<(KeyframeRecord, Arc<PreparedSubmap>)> {
        let rec = db.get(id).cloned()?;
        match db.prepared(id as usize, &self.rc) {
            Ok(p) => Some((rec, p)),
            Err(e) => {
                log::debug!("keyframe {id} not searched again: {e}");
                None
            }
        }
    }

    /// The best closure of `query` among its candidates, and whether it agrees with a fresh
    /// alignment; every refused candidate goes to `out`.
    fn best_closure(
        &self,
        db: &mut KeyframeDb,
        query: &KeyframeRecord,
        prepared: &PreparedSubmap,
        out: &mut Decisions,
    ) -> Option<(LoopClosure, Standing)> {
        let alignment = self.state.search_prior(self.session).map(|a| (a.t, a.path));
        let path = query.path_distance;
        let vouched = self.state.vouches_for(self.session, path, &self.lc);
        let others: Vec<SessionPrior> = self
            .state
            .other_search_priors()
            .map(|(session, a)| SessionPrior {
                session,
                t: a.t,
                path: a.path,
                vouched: self.state.vouches_for(session, path, &self.lc),
            })
            .collect();
        let rounds = db.candidate_rounds(
            &CandidateQuery {
                query,
                alignment,
                vouched,
                others: &others,
            },
            self.session,
            &self.lc.search(),
        );
        let late_from_start = self.deadline.passed();
        let total = rounds.len();
        for (i, mut round) in rounds.into_iter().enumerate() {
            if i > 0 && self.deadline.passed() {
                out.trimmed.rounds += (total - i) as u64;
                return None;
            }
            if i == 0 && late_from_start && round.len() > 1 {
                out.trimmed.candidates += (round.len() - 1) as u64;
                round.truncate(1);
            }
            if let Some(found) = self.register_round(db, query, prepared, round, i > 0, out) {
                return Some(found);
            }
        }
        None
    }

    /// One round of candidates registered, gated and tested: the best closure that passes. A later
    /// round's closures also pass [`later_round`].
    fn register_round(
        &self,
        db: &mut KeyframeDb,
        query: &KeyframeRecord,
        prepared: &PreparedSubmap,
        candidates: Vec<Candidate>,
        later: bool,
        out: &mut Decisions,
    ) -> Option<(LoopClosure, Standing)> {
        let mut targets = Vec::with_capacity(candidates.len());
        for cand in candidates {
            let id = cand.index as u64;
            match db.prepared(cand.index, &self.rc) {
                Ok(t) => targets.push((id, t)),
                Err(e) => out.reject(query.id, id, (RejectReason::Registration, e.to_string())),
            }
        }
        // The registrations are independent: they run in parallel and are gated in candidate order,
        // so the outcome is the same as one after another, sooner.
        out.registrations += targets.len() as u64;
        let cfg = self.search_registration();
        let results: Vec<_> = targets
            .par_iter()
            .map(|(_, target)| register_prepared(prepared, target, &cfg))
            .collect();
        let g = self.gates();
        let mut passed = Vec::new();
        for ((id, target), res) in targets.into_iter().zip(results) {
            let Some(cand) = db.get(id) else { continue };
            let (speeds, arms) = self.motion(db, query, cand);
            let pair = Pair {
                query,
                cand,
                source: prepared,
                target: &target,
                speeds,
                arms,
                motion: self.submap_motion,
            };
            let verdict = gate(&g, &pair, res).and_then(|gated| {
                if later {
                    later_round(&self.lc, gated)
                } else {
                    Ok(gated)
                }
            });
            match verdict {
                Ok(gated) => passed.push((gated, target)),
                Err(refusal) => out.reject(query.id, id, refusal),
            }
        }
        self.first_that_passes(passed, prepared, out)
    }

    /// The best of the gated closures that passes the prediction and slide tests: those that agree
    /// with the accepted alignment first, then by score, the earlier candidate among equals. The
    /// tests, the costliest gates, run in that order until one passes: the same closure as testing
    /// every one, with less work (the candidates after the winner are neither tested nor counted as
    /// rejected).
    fn first_that_passes(
        &self,
        mut passed: Vec<(Gated, std::sync::Arc<PreparedSubmap>)>,
        prepared: &PreparedSubmap,
        out: &mut Decisions,
    ) -> Option<(LoopClosure, Standing)> {
        passed.sort_by(|(a, _), (b, _)| {
            let vouched = |g: &Gated| g.standing == Standing::Vouched;
            (vouched(b), b.closure.score)
                .partial_cmp(&(vouched(a), a.closure.score))
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        let g = self.gates();
        for (gated, target) in passed {
            let c = &gated.closure;
            let tested = gated
                .prediction
                .map_or(Ok(()), |p| prediction_test(&g, &p, c, prepared, &target))
                .and_then(|()| {
                    gated
                        .slide
                        .map_or(Ok(()), |s| slide_test(&self.rc, &s, prepared, &target))
                });
            match tested {
                Ok(()) => return Some((gated.closure, gated.standing)),
                Err(refusal) => out.reject(c.query_id, c.match_id, refusal),
            }
        }
        None
    }

    /// The registration settings of a revisit search (`loop.correlative_search` may turn the
    /// correlative search off).
    fn search_registration(&self) -> RegistrationConfig {
        let mut cfg = self.rc.clone();
        cfg.correlative.enabled &= self.lc.correlative_search;
        cfg
    }

    fn gates(&self) -> Gates<'_> {
        Gates {
            lc: &self.lc,
            rc: &self.rc,
            session: self.session,
            alignments: self.state.alignments(),
            shared: self.state.shared(),
        }
    }

    fn publish(&mut self, closures: Vec<LoopClosure>, out: &mut Decisions) {
        for c in closures {
            self.state.published(&c);
            log::info!(
                "loop closure {} -> {} (session {}): {} inliers, overlap {:.2}",
                c.query_id,
                c.match_id,
                c.match_session,
                c.inliers,
                c.score
            );
            out.decisions.push(Decision::Published(Box::new(c)));
        }
    }
}

/// The odometry's speeds at a pair's keyframes, 0 where the map cannot tell.
fn speeds(db: &KeyframeDb, query: &KeyframeRecord, cand: &KeyframeRecord) -> [f64; 2] {
    [query, cand].map(|r| db.speed_at(r).unwrap_or(0.0))
}

/// The session a closure goes to and the alignment of this session's odometry frame into that
/// session's frame it implies.
fn closure_alignment(
    db: &KeyframeDb,
    query: &KeyframeRecord,
    c: &LoopClosure,
) -> Option<(u32, Alignment)> {
    let m = db.get(c.match_id)?;
    let t = m.t_odom_body * iso2_from_iso3(&c.t_match_query) * query.t_odom_body.inverse();
    let alignment = Alignment {
        t,
        path: query.path_distance,
        match_path: m.path_distance,
    };
    Some((m.session, alignment))
}
