//! Revisit candidates of a query keyframe ([`KeyframeDb::candidates`]): keyframes of the current session
//! near the odometry position, within a radius that grows with the path driven since each (a drift
//! model), keyframes near the position an accepted or held alignment predicts (in this session's
//! frame, or in another session's through an alignment to it), and keyframes of any session whose
//! place descriptor is close, whatever the odometry says.

use super::{KeyframeDb, KeyframeRecord};
use crate::math::{Iso2, Vec2};
use crate::place::column_distance;

/// Where a candidate came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CandidateSource {
    /// Near the (drift-tolerant) odometry position.
    Odometry,
    /// Close place descriptor.
    Place,
    /// Both.
    Both,
}

/// A revisit candidate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    /// Index (= id) in the database.
    pub index: usize,
    /// Where it came from.
    pub source: CandidateSource,
    /// Place-descriptor distance (0..1).
    pub place_distance: f64,
}

/// What a candidate search is given about the query.
#[derive(Debug, Clone, Copy)]
pub struct CandidateQuery<'a> {
    /// The query keyframe (not yet inserted).
    pub query: &'a KeyframeRecord,
    /// The current session's odometry-to-corrected alignment, if a closure gave one, and the path length
    /// at which it was found.
    pub alignment: Option<(Iso2, f64)>,
    /// The alignment is accepted and fresh enough to vouch for a closure alone
    /// (`loop.trusted_prior_std`): the position it predicts is known to within metres.
    pub vouched: bool,
    /// Alignments to other sessions (other robots', a loaded map's), accepted or held for
    /// confirmation: their keyframes near the position each predicts are candidates as this
    /// session's are near its own prediction.
    pub others: &'a [SessionPrior],
}

/// An alignment of the query's session into another session's frame: the accepted one, or before
/// there is one the newest held closure's, or else the one that session's robot accepted and shares
/// ([`crate::loop_closure::Session::search_prior`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionPrior {
    /// The other session.
    pub session: u32,
    /// The query session's odometry frame in that session's frame.
    pub t: Iso2,
    /// Path length of the query session at which it was found, m.
    pub path: f64,
    /// It is fresh enough to vouch for a closure alone (`loop.trusted_prior_std`).
    pub vouched: bool,
}

/// Candidate-search settings (a view of [`crate::loop_closure::LoopConfig`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchSettings {
    /// Base radius, m.
    pub radius: f64,
    /// Radius growth per metre of path, m/m.
    pub drift_rate: f64,
    /// Largest radius, m.
    pub max_radius: f64,
    /// Fewest metres of path between the query and a same-session candidate.
    pub min_path_gap: f64,
    /// Place candidates retrieved by ring key.
    pub place_retrieve: usize,
    /// Largest place distance of a place candidate.
    pub place_max_distance: f64,
    /// Candidates returned at most.
    pub max_candidates: usize,
}

impl KeyframeDb {
    /// Revisit candidates for `q`, at most `max_candidates`: alternately the next nearest to the predicted
    /// position and the next closest place descriptor; while the alignment vouches, the nearest to the
    /// predicted position first.
    pub fn candidates(
        &self,
        q: &CandidateQuery<'_>,
        session: u32,
        s: &SearchSettings,
    ) -> Vec<Candidate> {
        self.candidate_rounds(q, session, s)
            .into_iter()
            .next()
            .unwrap_or_default()
    }

    /// The candidates of [`KeyframeDb::candidates`] as the first round and, while the alignment
    /// vouches, further rounds of at most `max_candidates` each: the next nearest keyframes to the
    /// predicted position, registered only when no candidate of the rounds before closes.
    pub fn candidate_rounds(
        &self,
        q: &CandidateQuery<'_>,
        session: u32,
        s: &SearchSettings,
    ) -> Vec<Vec<Candidate>> {
        let search = Search {
            db: self,
            query: q.query,
            session,
            s,
        };
        // 1. Odometry, drift-tolerant: |p_q - p_i| <= radius + drift_rate * (path_q - path_i), and, once a
        //    closure aligned this session, the same around the corrected position with the drift since then.
        let p = q.query.t_odom_body.translation.vector;
        let corrected = q.alignment.map(|(a, path_a)| {
            let c = (a * nalgebra::Point2::from(p)).coords;
            (
                c,
                (s.radius + s.drift_rate * (q.query.path_distance - path_a).abs())
                    .min(s.max_radius),
            )
        });
        let centre = corrected.map_or(p, |(c, _)| c);
        let mut found = search.odometry_hits(p, corrected);
        // 2. Other sessions' keyframes around the positions their alignments predict, with the
        //    drift since each was found.
        let mut centres = vec![(session, centre, q.vouched)];
        for other in q.others {
            let c = (other.t * nalgebra::Point2::from(p)).coords;
            let r = (s.radius + s.drift_rate * (q.query.path_distance - other.path).abs())
                .min(s.max_radius);
            search.around(other.session, c, r, &mut found, false);
            centres.push((other.session, c, other.vouched));
        }
        // 3. Place descriptors, any session.
        search.add_place_hits(&mut found);
        let all = search.scored(merge_sources(found));
        search.rounds(&all, &centres)
    }
}

/// One candidate search: the database, the query, its session and the settings.
struct Search<'a> {
    db: &'a KeyframeDb,
    query: &'a KeyframeRecord,
    session: u32,
    s: &'a SearchSettings,
}

impl Search<'_> {
    /// Another session's keyframe that is this node's to register against the query, or one of this
    /// session at least `min_path_gap` of path before the query.
    fn eligible(&self, r: &KeyframeRecord) -> bool {
        if r.session == self.session {
            self.query.path_distance - r.path_distance >= self.s.min_path_gap
        } else {
            self.db.registers_pair(self.query, r.id as usize)
        }
    }

    /// This session's keyframes around the odometry position `p` within the drift radius and, given
    /// `corrected` (the corrected position and its radius), around that; only the hits nearest the
    /// (corrected) predicted position are kept for ranking: a long drive makes the drift radius hold
    /// hundreds of keyframes, and comparing place descriptors with all of them would dominate the
    /// query (the place retrieval still sees every keyframe).
    fn odometry_hits(
        &self,
        p: Vec2,
        corrected: Option<(Vec2, f64)>,
    ) -> Vec<(usize, CandidateSource)> {
        let (query, s) = (self.query, self.s);
        let mut found: Vec<(usize, CandidateSource)> = Vec::new();
        let outer = (s.radius + s.drift_rate * query.path_distance.max(0.0)).min(s.max_radius);
        self.around(self.session, p, outer, &mut found, true);
        if let Some((c, r)) = corrected {
            self.around(self.session, c, r, &mut found, false);
        }
        let keep = (4 * s.max_candidates).max(16);
        if found.len() > keep {
            let centre = corrected.map_or(p, |(c, _)| c);
            let d2 = |i: usize| {
                (self.db.records[i].t_odom_body.translation.vector - centre).norm_squared()
            };
            found.sort_by(|a, b| d2(a.0).total_cmp(&d2(b.0)).then(a.0.cmp(&b.0)));
            found.dedup_by_key(|f| f.0);
            found.truncate(keep);
        }
        found
    }

    /// Session `session`'s eligible keyframes within `r` of `centre` (in that session's frame), and
    /// with `drift_radius` (this session only) also within the drift radius of the path driven since
    /// each.
    fn around(
        &self,
        session: u32,
        centre: Vec2,
        r: f64,
        found: &mut Vec<(usize, CandidateSource)>,
        drift_radius: bool,
    ) {
        let (query, s) = (self.query, self.s);
        let mut visit = |i: usize, d2: f64| {
            let Some(rec) = self.db.records.get(i) else {
                return;
            };
            if rec.session != session || !self.eligible(rec) {
                return;
            }
            if drift_radius {
                let allowed = (s.radius + s.drift_rate * (query.path_distance - rec.path_distance))
                    .min(s.max_radius);
                if d2.sqrt() > allowed {
                    return;
                }
            }
            found.push((i, CandidateSource::Odometry));
        };
        self.db
            .positions
            .within(&[centre.x, centre.y], r, &mut visit);
    }

    /// The eligible keyframes of any session among the `place_retrieve` nearest place descriptors.
    fn add_place_hits(&self, found: &mut Vec<(usize, CandidateSource)>) {
        for (item, _) in self
            .db
            .place
            .nearest(&self.query.place, self.s.place_retrieve)
        {
            let i = item as usize;
            if self.db.records.get(i).is_some_and(|r| self.eligible(r)) {
                found.push((i, CandidateSource::Place));
            }
        }
    }

    /// Each candidate with its place distance; place-only candidates beyond `place_max_distance`
    /// dropped.
    fn scored(&self, merged: Vec<(usize, CandidateSource)>) -> Vec<Candidate> {
        let query = self.query;
        let query_columns = query.place.columns();
        merged
            .into_iter()
            .filter_map(|(index, source)| {
                let place_distance = if query.place.sectors == self.db.records[index].place.sectors
                {
                    column_distance(&query_columns, &self.db.place_columns[index]).0
                } else {
                    1.0
                };
                let keep =
                    source != CandidateSource::Place || place_distance <= self.s.place_max_distance;
                keep.then_some(Candidate {
                    index,
                    source,
                    place_distance,
                })
            })
            .collect()
    }

    /// The candidate rounds ([`KeyframeDb::candidate_rounds`]): the first from both rankings
    /// ([`first_round`]), and while an alignment vouches up to [`VOUCHED_ROUNDS`] in all, the later
    /// ones of the next keyframes nearest to the positions the vouching alignments predict.
    /// `centres` holds, per session searched by position, the predicted position in its frame and
    /// whether an alignment vouches for it; the position ranking puts those that vouch first.
    fn rounds(&self, all: &[Candidate], centres: &[(u32, Vec2, bool)]) -> Vec<Vec<Candidate>> {
        let centre_of = |i: usize| {
            let rec = &self.db.records[i];
            centres
                .iter()
                .find(|c| c.0 == rec.session)
                .map(|&(_, c, vouched)| ((rec.t_odom_body.translation.vector - c).norm(), vouched))
        };
        // (candidate, distance to its session's predicted position, vouched)
        let mut by_position: Vec<(&Candidate, f64, bool)> = all
            .iter()
            .filter(|c| c.source != CandidateSource::Place)
            .filter_map(|c| centre_of(c.index).map(|(d, v)| (c, d, v)))
            .collect();
        by_position.sort_by(|a, b| {
            b.2.cmp(&a.2)
                .then(a.1.total_cmp(&b.1))
                .then(a.0.index.cmp(&b.0.index))
        });
        let vouched = by_position.first().is_some_and(|c| c.2);
        let mut by_place: Vec<&Candidate> = all.iter().collect();
        by_place.sort_by(|a, b| {
            a.place_distance
                .total_cmp(&b.place_distance)
                .then(a.index.cmp(&b.index))
        });
        let max_candidates = self.s.max_candidates;
        let position: Vec<&Candidate> = by_position.iter().map(|c| c.0).collect();
        let first = first_round(&position, &by_place, max_candidates, vouched);
        let mut rounds = vec![first];
        if vouched && max_candidates > 0 {
            let rest: Vec<Candidate> = by_position
                .iter()
                .filter(|c| c.2 && !rounds[0].iter().any(|o| o.index == c.0.index))
                .map(|c| *c.0)
                .collect();
            let later = rest.chunks(max_candidates).take(VOUCHED_ROUNDS - 1);
            rounds.extend(later.map(<[Candidate]>::to_vec));
        }
        rounds
    }
}

/// Rounds of candidates at most while the alignment vouches. The revisit lies within metres of the
/// predicted position, but on a reverse pass (the other side of every object in view) the nearest
/// keyframes often fail to register where one a few metres on does; the later rounds, registered
/// only when no candidate before them closes, reach those at no cost where the first round closes.
/// Three rounds of four reach the eleven nearest keyframes within the search radius around the
/// predicted position; the farther a candidate lies from the revisit, the more its overlap is the
/// kind a closure slid along the street is made of.
const VOUCHED_ROUNDS: usize = 3;

/// The first round: the two rankings, `by_position` (odometry candidates nearest to the predicted
/// position first: right when drift is small) and `by_place` (every candidate by place distance:
/// right when the odometry has drifted or the keyframe is another session's), interleaved, at most
/// `max_candidates`. When `vouched`, every slot but the last goes to the position ranking, the last
/// to the place ranking: one place candidate a keyframe still lets closures that contradict the
/// alignment be found.
fn first_round(
    by_position: &[&Candidate],
    by_place: &[&Candidate],
    max_candidates: usize,
    vouched: bool,
) -> Vec<Candidate> {
    let mut out: Vec<Candidate> = Vec::with_capacity(max_candidates);
    let (mut a, mut b) = (by_position.iter(), by_place.iter());
    if vouched {
        let quota = max_candidates.saturating_sub(1).max(1);
        out.extend(a.by_ref().take(quota).map(|c| **c));
        std::mem::swap(&mut a, &mut b);
    }
    while out.len() < max_candidates {
        let next = [a.next(), b.next()];
        if next.iter().all(Option::is_none) {
            break;
        }
        for c in next.into_iter().flatten() {
            if out.len() < max_candidates && !out.iter().any(|o| o.index == c.index) {
                out.push(**c);
            }
        }
    }
    out
}

impl KeyframeDb {
    /// The keyframes of session `session` that may revisit keyframe `index` (another robot's, just
    /// added) and are this node's to register against it ([`KeyframeDb::registers_on_arrival`]): among the
    /// `place_retrieve` nearest place descriptors, within `place_max_distance`, nearest first, at most
    /// `max_candidates`.
    pub fn revisits_of(&self, index: usize, session: u32, s: &SearchSettings) -> Vec<Candidate> {
        let Some(arrived) = self.records.get(index) else {
            return Vec::new();
        };
        let columns = arrived.place.columns();
        let mut found: Vec<Candidate> = self
            .place
            .nearest(&arrived.place, s.place_retrieve)
            .into_iter()
            .filter_map(|(item, _)| {
                let i = item as usize;
                let r = self.records.get(i)?;
                if r.session != session || !self.registers_on_arrival(r, index) {
                    return None;
                }
                let d = if r.place.sectors == arrived.place.sectors {
                    column_distance(&columns, &self.place_columns[i]).0
                } else {
                    1.0
                };
                (d <= s.place_max_distance).then_some(Candidate {
                    index: i,
                    source: CandidateSource::Place,
                    place_distance: d,
                })
            })
            .collect();
        found.sort_by(|a, b| {
            a.place_distance
                .total_cmp(&b.place_distance)
                .then(a.index.cmp(&b.index))
        });
        found.truncate(s.max_candidates);
        found
    }
}

/// The hits by keyframe, each once: from the odometry, from the place descriptor, or both.
fn merge_sources(mut found: Vec<(usize, CandidateSource)>) -> Vec<(usize, CandidateSource)> {
    found.sort_by_key(|f| f.0);
    let mut merged: Vec<(usize, CandidateSource)> = Vec::with_capacity(found.len());
    for (i, src) in found {
        match merged.last_mut() {
            Some(last) if last.0 == i => {
                if last.1 != src {
                    last.1 = CandidateSource::Both;
                }
            }
            _ => merged.push((i, src)),
        }
    }
    merged
}
