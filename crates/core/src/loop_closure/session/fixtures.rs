//! Closures, places and sessions the tests of the closure decision and the session build on.

use super::super::{LoopClosure, LoopConfig, Standing};
use super::{Alignment, Outcome, QueryPlace, Session};
use crate::math::{Iso2, Iso3, Mat3, Mat6, Stamp, Vec2, Vec3, iso3_from_iso2};
use crate::registration::covariance_ros_from_se2;

/// A closure of query keyframe `query_id` to keyframe `match_id` with overlap `score`, at
/// identity poses with an identity covariance.
pub(crate) fn closure(query_id: u64, match_id: u64, score: f64) -> LoopClosure {
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

/// The alignment `t` found at `path` metres, its match keyframe as far along the other pass.
pub(crate) fn aligned(t: Iso2, path: f64) -> Alignment {
    Alignment::along_one_pass(t, path)
}

/// Query keyframe `id` at `path` metres along odometry x, heading 0.
pub(crate) fn place(id: u64, path: f64) -> QueryPlace {
    QueryPlace {
        id,
        path,
        t_odom_body: Iso2::new(Vec2::new(path, 0.0), 0.0),
    }
}

/// Offers query keyframe `q` at `path` metres, matched to keyframe `m` with overlap `score`, as an
/// unconfirmed closure to session 0 that implies the alignment `a`.
pub(crate) fn offer(
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
        (aligned(a, path), Standing::Unconfirmed),
        lc,
    )
}

/// Offers query keyframe `q` at `path` metres, matched to keyframe `m` with overlap `score`, as a
/// closure to session 0 that implies `alignment` and has `standing`.
pub(crate) fn take(
    s: &mut Session,
    (q, path): (u64, f64),
    (m, score): (u64, f64),
    (alignment, standing): (Alignment, Standing),
    lc: &LoopConfig,
) -> Vec<LoopClosure> {
    judge(s, (q, path), (m, score), (alignment, standing), lc).publish
}

/// [`take`], with all [`Session::accept`] says.
pub(crate) fn judge(
    s: &mut Session,
    (q, path): (u64, f64),
    (m, score): (u64, f64),
    (alignment, standing): (Alignment, Standing),
    lc: &LoopConfig,
) -> Outcome {
    s.accept(
        &place(q, path),
        closure(q, m, score),
        0,
        alignment,
        standing,
        lc,
    )
}

/// The query keyframes of `closures`, in order.
pub(crate) fn ids(closures: &[LoopClosure]) -> Vec<u64> {
    closures.iter().map(|c| c.query_id).collect()
}

/// All the keyframes [`Session::next_backfill`] gives.
pub(crate) fn drain_backfill(s: &mut Session) -> Vec<u64> {
    std::iter::from_fn(|| s.next_backfill()).collect()
}

/// The alignment to session 0 that every true closure of these tests implies.
pub(crate) fn true_alignment() -> Iso2 {
    Iso2::new(Vec2::new(3.0, -2.0), 0.05)
}

/// Keyframes 0..n of this session, 10 m apart.
pub(crate) fn session_with_keyframes(n: u64, lc: &LoopConfig) -> Session {
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
pub(crate) fn street_closure(q: u64, path: f64, slide: f64, sigma: f64) -> (LoopClosure, Iso2) {
    let query = Iso2::new(Vec2::new(path, 0.0), 0.0);
    let matched = true_alignment() * query * Iso2::new(Vec2::new(0.0, 3.5), 0.0);
    let t = matched.inverse() * true_alignment() * query * Iso2::new(Vec2::new(slide, 0.0), 0.0);
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
