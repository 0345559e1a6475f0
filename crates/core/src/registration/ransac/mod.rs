//! RANSAC on a planar rigid motion (Fischler & Bolles 1981) over candidate correspondences.
//!
//! Minimal sets of two correspondences are screened by cheap distance checks, scored by their
//! support (source points with a candidate within the inlier radius) and drawn until the adaptive
//! stopping rule is met; a motion that enters the kept set is locally optimised (LO-RANSAC). The
//! random generator is seeded from the configuration: the same input gives the same output.
//! docs/algorithm.md, "RANSAC", has the checks, the stopping rule and why support counts points.
//!
//! Entry points: [`RansacConfig`], [`ransac`] (RANSAC on given correspondences),
//! [`ransac_hypotheses`] (the best distinct motions, [`Distinct`], for the caller to judge
//! geometrically), [`RansacResult`], [`fit_rigid`] (closed-form least-squares rigid fit, 2-D
//! Procrustes / Umeyama 1991). Parts: `columns` (the inlier test and support count over blocks of
//! pairs).

mod columns;

use crate::math::{Iso2, Mat2, Vec2};
pub use crate::registration::types::Correspondence;
use crate::registration::types::{PointSet2, RegistrationError};
use crate::validate::{Range, Validator};
use columns::{Columns, Scorer};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::{Deserialize, Serialize};

/// Upper bound on drawn pairs, rejected or not.
pub const MAX_ITERATIONS: usize = 20_000;

/// Minimum distance between the two source points of a minimal set, m.
pub const MIN_SAMPLE_SEPARATION: f64 = 2.0;

/// Least-squares refits on the inlier set after the search.
pub const REFIT_ROUNDS: usize = 3;

/// RANSAC settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RansacConfig {
    /// Inlier radius `|y - T x|`, m (default 1.0; the DC-Loc authors' code uses 0.75).
    pub inlier_threshold: f64,
    /// When > 0, inliers are judged by the Mahalanobis distance `sqrt(d^T (Sy + R Sx R^T)^-1 d)`
    /// against this gate (in sigma) instead of `inlier_threshold`; 0 = off (default 0). During the
    /// search a rotation-free bound is used (`|d|^2 <= gate^2 (lmax(Sx) + lmax(Sy))`), the exact
    /// test in the final refit.
    pub mahalanobis_gate: f64,
    /// Probability of having drawn at least one all-inlier pair when stopping (default 0.999).
    pub confidence: f64,
    /// Seed of the random generator (default 0x5EED).
    pub seed: u64,
}

impl Default for RansacConfig {
    fn default() -> Self {
        RansacConfig {
            inlier_threshold: 1.0,
            mahalanobis_gate: 0.0,
            confidence: 0.999,
            seed: 0x5EED,
        }
    }
}

impl RansacConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.range("seed", self.seed as f64, Range::NON_NEGATIVE);
        v.positive("inlier_threshold", self.inlier_threshold);
        v.non_negative("mahalanobis_gate", self.mahalanobis_gate);
        v.range("confidence", self.confidence, Range::above(0.0).below(1.0));
    }
}

/// The motions RANSAC found and their screening coverage (the dense stage's count of covered
/// points), best first.
pub type Screened = Vec<(usize, RansacResult)>;

/// What [`ransac`] returns.
#[derive(Debug, Clone, PartialEq)]
pub struct RansacResult {
    /// Source frame in the target frame, refitted on the inliers.
    pub t_target_source: Iso2,
    /// Indices into the correspondence slice of the inliers, at most one per source point (the
    /// smallest residual), ascending.
    pub inliers: Vec<usize>,
    /// Pairs drawn (including those rejected before scoring).
    pub iterations: usize,
    /// Hypotheses scored.
    pub hypotheses: usize,
}

/// Least-squares rigid motion `y ~ R x + t` over pairs (2-D Procrustes, closed form).
/// Returns `None` for fewer than 2 pairs or when all source points coincide.
pub fn fit_rigid(pairs: impl Iterator<Item = (Vec2, Vec2)> + Clone) -> Option<Iso2> {
    let (mut n, mut sx, mut sy) = (0.0, Vec2::zeros(), Vec2::zeros());
    for (x, y) in pairs.clone() {
        n += 1.0;
        sx += x;
        sy += y;
    }
    if n < 2.0 {
        return None;
    }
    let (mx, my) = (sx / n, sy / n);
    let (mut dot, mut cross, mut spread) = (0.0, 0.0, 0.0);
    for (x, y) in pairs {
        let (a, b) = (x - mx, y - my);
        dot += a.dot(&b);
        cross += a.x * b.y - a.y * b.x;
        spread += a.norm_squared();
    }
    if spread <= 1e-18 {
        return None;
    }
    let rot = nalgebra::UnitComplex::new(cross.atan2(dot));
    let t = my - rot * mx;
    Some(Iso2::from_parts(t.into(), rot))
}

fn lambda_max(c: &Mat2) -> f64 {
    let tr = c[(0, 0)] + c[(1, 1)];
    let det = c[(0, 0)] * c[(1, 1)] - c[(0, 1)] * c[(1, 0)];
    0.5 * tr + (0.25 * tr * tr - det).max(0.0).sqrt()
}

/// RANSAC over `correspondences` between `source` and `target`: the motion explaining the most
/// source points.
///
/// Errors: [`RegistrationError::TooFewInliers`] when there are fewer than 2 correspondences or no
/// usable minimal set (e.g. all source points within [`MIN_SAMPLE_SEPARATION`] of each other);
/// [`RegistrationError::Numerical`] for an index out of range or a non-finite point.
pub fn ransac(
    source: &PointSet2,
    target: &PointSet2,
    correspondences: &[Correspondence],
    cfg: &RansacConfig,
) -> Result<RansacResult, RegistrationError> {
    ransac_hypotheses(source, target, correspondences, cfg, &Distinct::best_only())?
        .into_iter()
        .next()
        .ok_or(RegistrationError::TooFewInliers { have: 0, need: 2 })
}

/// Two refined hypotheses farther apart than this, m, are different alignments (for
/// `runner_up_overlap`, and for refining a hypothesis only once).
pub const AMBIGUITY_TRANSLATION: f64 = 1.0;

/// The same in rotation, rad.
pub const AMBIGUITY_ROTATION: f64 = 0.05;

/// `a` and `b` are within `translation` (m) and `rotation` (rad) of each other.
pub fn same_motion(a: &Iso2, b: &Iso2, translation: f64, rotation: f64) -> bool {
    let rel = a.inverse() * b;
    rel.translation.vector.norm() <= translation && rel.rotation.angle().abs() <= rotation
}

/// Which hypotheses [`ransac_hypotheses`] keeps besides the best one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distinct {
    /// Most hypotheses kept.
    pub keep: usize,
    /// Two motions closer than this in translation, m, ...
    pub translation: f64,
    /// ... and in rotation, rad, are the same alignment (the better-supported one is kept).
    pub rotation: f64,
    /// Fewest source points a hypothesis must explain to be kept (the best one is always kept).
    pub min_support: usize,
}

impl Distinct {
    /// Only the best hypothesis.
    pub fn best_only() -> Self {
        Distinct {
            keep: 1,
            translation: f64::INFINITY,
            rotation: f64::INFINITY,
            min_support: 0,
        }
    }
    fn same(&self, a: &Iso2, b: &Iso2) -> bool {
        same_motion(a, b, self.translation, self.rotation)
    }
}

/// RANSAC keeping up to `distinct.keep` different motions, best supported first: the best one and
/// the best other local maxima of the support (source points explained). Scene aliasing (a facade
/// slid by a window spacing, a repeated block) can give a wrong motion more descriptor support than
/// the true one; the caller then judges the kept motions by their geometric overlap.
///
/// The stopping rule follows the best support; each kept motion is locally optimised (LO-RANSAC,
/// Chum et al. 2003: refit on its inliers and rescore while the support grows) and finally refitted
/// as [`ransac`] describes. Errors as [`ransac`].
pub fn ransac_hypotheses(
    source: &PointSet2,
    target: &PointSet2,
    correspondences: &[Correspondence],
    cfg: &RansacConfig,
    distinct: &Distinct,
) -> Result<Vec<RansacResult>, RegistrationError> {
    let n = correspondences.len();
    if n < 2 {
        return Err(RegistrationError::TooFewInliers { have: n, need: 2 });
    }
    let pairs = Pairs::gather(source, target, correspondences, cfg)?;
    let search = search(&pairs, correspondences, cfg, distinct);
    if search.kept.is_empty() {
        return Err(RegistrationError::TooFewInliers { have: 0, need: 2 });
    }
    // Final least-squares refits of each kept motion: inliers of the current motion, then refit,
    // until stable.
    let inliers_of = |t: &Iso2| {
        classify(
            source,
            target,
            correspondences,
            &pairs.xs,
            &pairs.ys,
            &pairs.thr2,
            t,
            cfg,
        )
    };
    let mut out = Vec::with_capacity(search.kept.len());
    for (_, t) in search.kept {
        let (t, inliers) = refit(t, &pairs, &inliers_of);
        out.push(RansacResult {
            t_target_source: t,
            inliers,
            iterations: search.iterations,
            hypotheses: search.hypotheses,
        });
    }
    Ok(out)
}

/// The correspondences' points gathered contiguously (cache-friendly scoring) with each pair's
/// squared inlier radius.
struct Pairs {
    xs: Vec<Vec2>,
    ys: Vec<Vec2>,
    thr2: Vec<f64>,
}

impl Pairs {
    /// Errors for an index out of range, a non-finite point or missing covariances (as [`ransac`]).
    fn gather(
        source: &PointSet2,
        target: &PointSet2,
        correspondences: &[Correspondence],
        cfg: &RansacConfig,
    ) -> Result<Self, RegistrationError> {
        let n = correspondences.len();
        let mut xs = Vec::with_capacity(n);
        let mut ys = Vec::with_capacity(n);
        let mut thr2 = Vec::with_capacity(n);
        let maha = cfg.mahalanobis_gate > 0.0;
        for c in correspondences {
            let (i, j) = (c.source as usize, c.target as usize);
            let (Some(x), Some(y)) = (source.points.get(i), target.points.get(j)) else {
                return Err(RegistrationError::Numerical(format!(
                    "correspondence ({i}, {j}) out of range ({} source, {} target points)",
                    source.len(),
                    target.len()
                )));
            };
            if !(x.iter().all(|v| v.is_finite()) && y.iter().all(|v| v.is_finite())) {
                return Err(RegistrationError::Numerical(format!(
                    "non-finite point in correspondence ({i}, {j})"
                )));
            }
            xs.push(*x);
            ys.push(*y);
            thr2.push(if maha {
                let (Some(sx), Some(sy)) = (source.covs.get(i), target.covs.get(j)) else {
                    return Err(RegistrationError::Numerical(
                        "point set has fewer covariances than points".into(),
                    ));
                };
                cfg.mahalanobis_gate * cfg.mahalanobis_gate * (lambda_max(sx) + lambda_max(sy))
            } else {
                cfg.inlier_threshold * cfg.inlier_threshold
            });
        }
        Ok(Pairs { xs, ys, thr2 })
    }
}

/// What the sampling kept: motions (support, motion), best first, with the pairs drawn and the
/// hypotheses scored.
struct Search {
    kept: Vec<(usize, Iso2)>,
    iterations: usize,
    hypotheses: usize,
}

/// The sampling loop: draws minimal sets until the adaptive stopping rule (or `max_iterations`) is
/// met, scores each motion that passes the cheap checks, locally optimises those that enter the
/// kept set.
fn search(
    pairs: &Pairs,
    correspondences: &[Correspondence],
    cfg: &RansacConfig,
    distinct: &Distinct,
) -> Search {
    let n = correspondences.len();
    let (xs, ys, thr2) = (&pairs.xs, &pairs.ys, &pairs.thr2);
    // Source slot of each pair (dense ids): a motion is scored by the source points it explains, not
    // by its pairs, as the final inliers are counted (one per source point).
    let mut slot_of: std::collections::HashMap<u32, u32> = std::collections::HashMap::new();
    let slots: Vec<u32> = correspondences
        .iter()
        .map(|c| {
            let next = slot_of.len() as u32;
            *slot_of.entry(c.source).or_insert(next)
        })
        .collect();
    let cols = Columns::new(xs, ys, thr2);
    let mut ids = Vec::with_capacity(n);
    let mut score = Scorer::new(&cols, &slots, slot_of.len());

    let mut rng = StdRng::seed_from_u64(cfg.seed);
    let min_sep2 = MIN_SAMPLE_SEPARATION * MIN_SAMPLE_SEPARATION;
    let log_fail = (1.0 - cfg.confidence).ln();
    let mut needed = MAX_ITERATIONS;
    // Kept motions (support, motion), best first.
    let mut kept: Vec<(usize, Iso2)> = Vec::with_capacity(distinct.keep + 1);
    let keep = distinct.keep.max(1);
    let (mut iterations, mut hypotheses) = (0usize, 0usize);
    while iterations < needed {
        iterations += 1;
        let a = rng.random_range(0..n);
        let b = rng.random_range(0..n);
        let Some(t) = minimal_motion(pairs, correspondences, a, b, min_sep2) else {
            continue;
        };
        hypotheses += 1;
        // The support a motion needs to enter the kept list.
        let bar = match kept.last() {
            None => 0,
            Some(_) if kept.len() < keep => distinct.min_support,
            Some(last) => last.0,
        };
        let count = score.count(&t, bar);
        if count <= bar {
            continue;
        }
        let (count, t) = local_optimisation(&cols, &mut score, &mut ids, count, t);
        let best_before = kept.first().map_or(0, |k| k.0);
        insert_distinct(&mut kept, (count, t), keep, distinct);
        if count > best_before {
            needed = iterations_needed(count, n, log_fail, iterations);
        }
    }
    Search {
        kept,
        iterations,
        hypotheses,
    }
}

/// The motion of the minimal set of pairs `a` and `b`, or `None` when the set is rejected before
/// scoring: a point shared, source points closer than [`MIN_SAMPLE_SEPARATION`] (squared:
/// `min_sep2`), or distances that no rigid motion can make both inliers.
fn minimal_motion(
    pairs: &Pairs,
    correspondences: &[Correspondence],
    a: usize,
    b: usize,
    min_sep2: f64,
) -> Option<Iso2> {
    let (xs, ys, thr2) = (&pairs.xs, &pairs.ys, &pairs.thr2);
    let (ca, cb) = (&correspondences[a], &correspondences[b]);
    if ca.source == cb.source || ca.target == cb.target {
        return None;
    }
    let u = xs[b] - xs[a];
    let v = ys[b] - ys[a];
    let (lu2, lv2) = (u.norm_squared(), v.norm_squared());
    if lu2 < min_sep2 || lu2 <= 1e-18 {
        return None;
    }
    // Rigidity: ||u| - |v|| can be at most the sum of the two inlier radii.
    let slack = thr2[a].sqrt() + thr2[b].sqrt();
    if (lu2.sqrt() - lv2.sqrt()).abs() > slack {
        return None;
    }
    let rot = nalgebra::UnitComplex::new((u.x * v.y - u.y * v.x).atan2(u.dot(&v)));
    let mid_x = 0.5 * (xs[a] + xs[b]);
    let mid_y = 0.5 * (ys[a] + ys[b]);
    Some(Iso2::from_parts((mid_y - rot * mid_x).into(), rot))
}

/// Local optimisation (LO-RANSAC): a minimal sample's motion is as noisy as its two points, which
/// cuts far inliers off; refit on the inliers and rescore while the support grows. Returns the
/// final (support, motion).
fn local_optimisation(
    cols: &Columns,
    score: &mut Scorer<'_>,
    ids: &mut Vec<usize>,
    count: usize,
    t: Iso2,
) -> (usize, Iso2) {
    let (mut count, mut t) = (count, t);
    for _ in 0..LOCAL_ROUNDS {
        cols.inliers_into(&t, ids);
        let Some(t_fit) = cols.fit(ids) else {
            break;
        };
        let c_fit = score.count(&t_fit, 0);
        if c_fit <= count {
            break;
        }
        count = c_fit;
        t = t_fit;
    }
    (count, t)
}

/// The adaptive stopping rule `N = ln(1 - p) / ln(1 - w^2)` for a best support of `count` of `n`
/// pairs, clamped to `1..=`[`MAX_ITERATIONS`] (`iterations`, the pairs drawn so far, when every
/// pair is an inlier).
fn iterations_needed(count: usize, n: usize, log_fail: f64, iterations: usize) -> usize {
    let w = count as f64 / n as f64;
    let p_good = w * w;
    if p_good >= 1.0 {
        iterations
    } else {
        let k = (log_fail / (1.0 - p_good).ln()).ceil();
        if k.is_finite() {
            (k as usize).clamp(1, MAX_ITERATIONS)
        } else {
            MAX_ITERATIONS
        }
    }
}

/// Least-squares refits of motion `t` on its inliers (`inliers_of`) until they are stable, at most
/// [`REFIT_ROUNDS`]; a refit that loses inliers is not taken. Returns the motion and its inliers.
fn refit(
    mut t: Iso2,
    pairs: &Pairs,
    inliers_of: &dyn Fn(&Iso2) -> Vec<usize>,
) -> (Iso2, Vec<usize>) {
    let mut inliers = inliers_of(&t);
    for _ in 0..REFIT_ROUNDS {
        let Some(t_new) = fit_rigid(inliers.iter().map(|&k| (pairs.xs[k], pairs.ys[k]))) else {
            break;
        };
        let new_inliers = inliers_of(&t_new);
        if new_inliers.len() < inliers.len() {
            break;
        }
        let same = new_inliers == inliers;
        t = t_new;
        inliers = new_inliers;
        if same {
            break;
        }
    }
    (t, inliers)
}

/// Inserts `h` into `kept` (best first, at most `keep`): it replaces a kept motion that is the same
/// alignment when it is better supported, and is dropped when one such is at least as good.
fn insert_distinct(kept: &mut Vec<(usize, Iso2)>, h: (usize, Iso2), keep: usize, d: &Distinct) {
    if let Some(pos) = kept.iter().position(|k| d.same(&k.1, &h.1)) {
        if kept[pos].0 >= h.0 {
            return;
        }
        kept.remove(pos);
    }
    let at = kept.partition_point(|k| k.0 >= h.0);
    kept.insert(at, h);
    kept.truncate(keep);
}

/// Local-optimisation rounds per new best hypothesis.
const LOCAL_ROUNDS: usize = 4;

/// Inliers of `t`, one per source point (smallest residual), ascending.
#[allow(clippy::too_many_arguments)]
fn classify(
    source: &PointSet2,
    target: &PointSet2,
    corr: &[Correspondence],
    xs: &[Vec2],
    ys: &[Vec2],
    thr2: &[f64],
    t: &Iso2,
    cfg: &RansacConfig,
) -> Vec<usize> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let mut kept: Vec<(u32, f64, usize)> = Vec::new();
    for k in 0..xs.len() {
        let d = ys[k] - (r * xs[k] + t.translation.vector);
        let e2 = d.norm_squared();
        if e2 > thr2[k] {
            continue;
        }
        let score = if cfg.mahalanobis_gate > 0.0 {
            let (i, j) = (corr[k].source as usize, corr[k].target as usize);
            let c = target.covs[j] + r * source.covs[i] * r.transpose();
            match c.try_inverse() {
                Some(w) => {
                    let m2 = d.dot(&(w * d));
                    // NaN fails the gate too.
                    if m2.is_nan() || m2 > cfg.mahalanobis_gate * cfg.mahalanobis_gate {
                        continue;
                    }
                    m2
                }
                None => continue,
            }
        } else {
            e2
        };
        kept.push((corr[k].source, score, k));
    }
    // One inlier per source point: the smallest residual wins.
    kept.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    kept.dedup_by_key(|e| e.0);
    let mut out: Vec<usize> = kept.into_iter().map(|e| e.2).collect();
    out.sort_unstable();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Correspondences for `n` source points under motion `t`: each source point has `per_point`
    /// candidates, all within 0.3 m of its image (as k > 1 neighbours along a facade would be).
    fn supported(
        rng: &mut StdRng,
        t: &Iso2,
        n: usize,
        per_point: usize,
        source: &mut PointSet2,
        target: &mut PointSet2,
        out: &mut Vec<Correspondence>,
    ) {
        for _ in 0..n {
            let x = Vec2::new(rng.random_range(-50.0..50.0), rng.random_range(-50.0..50.0));
            let i = source.points.len();
            source.points.push(x);
            source.covs.push(Mat2::identity() * 0.01);
            for _ in 0..per_point {
                let y = (t * nalgebra::Point2::from(x)).coords
                    + Vec2::new(rng.random_range(-0.2..0.2), rng.random_range(-0.2..0.2));
                out.push(Correspondence::new(i, target.points.len()));
                target.points.push(y);
                target.covs.push(Mat2::identity() * 0.01);
            }
        }
    }

    fn near(a: &Iso2, b: &Iso2) -> bool {
        let rel = a.inverse() * b;
        rel.translation.vector.norm() < 0.5 && rel.rotation.angle().abs() < 0.01
    }

    /// A motion is scored by the source points it explains: 20 points with three candidates each
    /// (60 pairs) lose to 30 points with one candidate each.
    #[test]
    fn support_counts_source_points_not_pairs() {
        let mut rng = StdRng::seed_from_u64(11);
        let (mut s, mut g, mut c) = (PointSet2::default(), PointSet2::default(), Vec::new());
        let slid = Iso2::new(Vec2::new(8.0, 0.0), 0.0);
        let truth = Iso2::new(Vec2::new(-3.0, 5.0), 0.4);
        supported(&mut rng, &slid, 20, 3, &mut s, &mut g, &mut c);
        supported(&mut rng, &truth, 30, 1, &mut s, &mut g, &mut c);
        let r = ransac(&s, &g, &c, &RansacConfig::default()).expect("a motion");
        assert!(near(&r.t_target_source, &truth), "{}", r.t_target_source);
        // (A slid pair may land within the radius by chance.)
        assert!((30..=32).contains(&r.inliers.len()), "{}", r.inliers.len());
    }

    /// Kept hypotheses: the distinct motions, best supported first, none of them twice; a motion
    /// below `min_support` is not kept.
    #[test]
    fn distinct_motions_are_kept_best_first() {
        let mut rng = StdRng::seed_from_u64(12);
        let (mut s, mut g, mut c) = (PointSet2::default(), PointSet2::default(), Vec::new());
        let motions = [
            Iso2::new(Vec2::new(1.0, 2.0), 0.1),
            Iso2::new(Vec2::new(-20.0, 4.0), 3.0),
            Iso2::new(Vec2::new(6.0, -9.0), -1.2),
        ];
        for (m, n) in motions.iter().zip([45, 30, 6]) {
            supported(&mut rng, m, n, 1, &mut s, &mut g, &mut c);
        }
        // Outliers: random pairs.
        for _ in 0..150 {
            let i = rng.random_range(0..s.len());
            let j = rng.random_range(0..g.len());
            c.push(Correspondence::new(i, j));
        }
        let distinct = Distinct {
            keep: 8,
            translation: 1.0,
            rotation: 0.05,
            min_support: 10,
        };
        let cfg = RansacConfig {
            confidence: 0.99999,
            ..RansacConfig::default()
        };
        let kept = ransac_hypotheses(&s, &g, &c, &cfg, &distinct).expect("motions");
        assert!(near(&kept[0].t_target_source, &motions[0]));
        assert!(kept[0].inliers.len() >= 45);
        let second = kept
            .iter()
            .position(|h| near(&h.t_target_source, &motions[1]))
            .expect("the second motion is kept");
        assert!(kept[second].inliers.len() >= 30);
        assert!(!kept.iter().any(|h| near(&h.t_target_source, &motions[2])));
        for (a, h) in kept.iter().enumerate() {
            for b in &kept[a + 1..] {
                assert!(!distinct.same(&h.t_target_source, &b.t_target_source));
            }
        }
    }

    #[test]
    fn fit_rigid_recovers_exact_motion() {
        let t = Iso2::new(Vec2::new(3.0, -2.0), 2.5);
        let xs = [
            Vec2::new(0.0, 0.0),
            Vec2::new(10.0, 1.0),
            Vec2::new(-3.0, 7.0),
        ];
        let pairs = xs
            .iter()
            .map(|x| (*x, (t * nalgebra::Point2::from(*x)).coords));
        let f = fit_rigid(pairs).unwrap();
        assert!((f.translation.vector - t.translation.vector).norm() < 1e-12);
        assert!((f.rotation.angle() - 2.5).abs() < 1e-12);
        assert!(fit_rigid(std::iter::repeat_n((Vec2::zeros(), Vec2::zeros()), 5)).is_none());
    }
}
