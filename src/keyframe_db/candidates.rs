//! Revisit candidates of a query keyframe ([`KeyframeDb::candidates`]): keyframes of the current session
//! near the odometry position, within a radius that grows with the path driven since each (a drift
//! model), keyframes near the position an accepted alignment predicts, and keyframes of any session
//! whose place descriptor is close, whatever the odometry says.

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
    /// position and the next closest place descriptor.
    pub fn candidates(
        &self,
        q: &CandidateQuery<'_>,
        session: u32,
        s: &SearchSettings,
    ) -> Vec<Candidate> {
        let query = q.query;
        let mut found: Vec<(usize, CandidateSource)> = Vec::new();
        let eligible = |r: &KeyframeRecord| {
            r.session != session || query.path_distance - r.path_distance >= s.min_path_gap
        };
        // 1. Odometry, drift-tolerant: |p_q - p_i| <= radius + drift_rate * (path_q - path_i), and, once a
        //    closure aligned this session, the same around the corrected position with the drift since then.
        let p = query.t_odom_body.translation.vector;
        let outer = (s.radius + s.drift_rate * query.path_distance.max(0.0)).min(s.max_radius);
        let corrected = q.alignment.map(|(a, path_a)| {
            let c = (a * nalgebra::Point2::from(p)).coords;
            (
                c,
                (s.radius + s.drift_rate * (query.path_distance - path_a).abs()).min(s.max_radius),
            )
        });
        let around = |centre: Vec2,
                      r: f64,
                      found: &mut Vec<(usize, CandidateSource)>,
                      drift_radius: bool| {
            let mut visit = |i: usize, d2: f64| {
                let Some(rec) = self.records.get(i) else {
                    return;
                };
                if rec.session != session || !eligible(rec) {
                    return;
                }
                if drift_radius {
                    let allowed = (s.radius
                        + s.drift_rate * (query.path_distance - rec.path_distance))
                        .min(s.max_radius);
                    if d2.sqrt() > allowed {
                        return;
                    }
                }
                found.push((i, CandidateSource::Odometry));
            };
            self.positions.within(&[centre.x, centre.y], r, &mut visit);
        };
        around(p, outer, &mut found, true);
        if let Some((c, r)) = corrected {
            around(c, r, &mut found, false);
        }
        // Only the odometry hits nearest the (corrected) predicted position are ranked further: a long
        // drive makes the drift radius hold hundreds of keyframes, and comparing place descriptors with
        // all of them would dominate the query (the place retrieval below still sees every keyframe).
        let keep = (4 * s.max_candidates).max(16);
        if found.len() > keep {
            let centre = corrected.map_or(p, |(c, _)| c);
            let d2 =
                |i: usize| (self.records[i].t_odom_body.translation.vector - centre).norm_squared();
            found.sort_by(|a, b| d2(a.0).total_cmp(&d2(b.0)).then(a.0.cmp(&b.0)));
            found.dedup_by_key(|f| f.0);
            found.truncate(keep);
        }
        // 2. Place descriptors, any session.
        for (item, _) in self.place.nearest(&query.place, s.place_retrieve) {
            let i = item as usize;
            if self.records.get(i).is_some_and(|r| eligible(r)) {
                found.push((i, CandidateSource::Place));
            }
        }
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
        let query_columns = query.place.columns();
        let all: Vec<Candidate> = merged
            .into_iter()
            .filter_map(|(index, source)| {
                let place_distance = if query.place.sectors == self.records[index].place.sectors {
                    column_distance(&query_columns, &self.place_columns[index]).0
                } else {
                    1.0
                };
                let keep =
                    source != CandidateSource::Place || place_distance <= s.place_max_distance;
                keep.then_some(Candidate {
                    index,
                    source,
                    place_distance,
                })
            })
            .collect();
        // Two rankings, interleaved: odometry candidates nearest to the (corrected) predicted position
        // first (right when drift is small), and every candidate by place distance (right when the
        // odometry has drifted or the keyframe is another session's).
        let centre = corrected.map_or(p, |(c, _)| c);
        let metric = |i: usize| (self.records[i].t_odom_body.translation.vector - centre).norm();
        let mut by_position: Vec<&Candidate> = all
            .iter()
            .filter(|c| c.source != CandidateSource::Place)
            .collect();
        by_position.sort_by(|a, b| {
            metric(a.index)
                .total_cmp(&metric(b.index))
                .then(a.index.cmp(&b.index))
        });
        let mut by_place: Vec<&Candidate> = all.iter().collect();
        by_place.sort_by(|a, b| {
            a.place_distance
                .total_cmp(&b.place_distance)
                .then(a.index.cmp(&b.index))
        });
        let mut out: Vec<Candidate> = Vec::with_capacity(s.max_candidates);
        let (mut a, mut b) = (by_position.into_iter(), by_place.into_iter());
        while out.len() < s.max_candidates {
            let next = [a.next(), b.next()];
            if next.iter().all(Option::is_none) {
                break;
            }
            for c in next.into_iter().flatten() {
                if out.len() < s.max_candidates && !out.iter().any(|o| o.index == c.index) {
                    out.push(*c);
                }
            }
        }
        out
    }
}
