//! Association: each source point paired with its nearest target point under the current pose
//! (behind a distance cap and a Mahalanobis gate), remembering nearest neighbours across rounds;
//! and the soft rounds' virtual partners, likelihood-weighted means of several target points.

use super::{DenseConfig, PointSet2, TargetTree};
use crate::math::{Iso2, Mat2, Vec2};

/// Nearest-neighbour pairs (source index, target index) under `t` that pass the gates.
pub fn associate(
    source: &PointSet2,
    target: &PointSet2,
    tree: &TargetTree,
    t: &Iso2,
    cfg: &DenseConfig,
) -> Vec<(usize, usize)> {
    associate_with(source, target, tree, t, cfg, None)
}

/// What the rounds remember of each source point's nearest neighbours: the nearest target point,
/// the distance of the second nearest, and where the source point was when they were found. A later
/// round that has moved the point by `delta` keeps the nearest without a tree query when the
/// nearest is still closer than `second - delta`: no other target point can have come that close
/// (triangle inequality), so the pairs are exactly those of a fresh query. The rounds move points
/// by millimetres, so most of a round's queries are saved. A point with no target point within
/// reach remembers how far the nearest one was at least, and is not queried again while it stays
/// beyond the reach of the round (by [`NOTHING_MARGIN`]).
#[derive(Default)]
pub(super) struct NearestMemory {
    /// Per source point, what the last query found.
    entries: Vec<Remembered>,
}

/// What a query found for one source point ([`NearestMemory`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
enum Remembered {
    /// Not queried yet.
    #[default]
    Unknown,
    /// The nearest target point, the distance of the second nearest (capped at the query's
    /// reach) and where the source point was.
    Nearest(u32, f64, Vec2),
    /// No target point within reach: every one lay at least this far from where the source point
    /// was.
    Nothing(f64, Vec2),
}

/// Margin of the test that a point with no target point within reach still has none, m: far more
/// than the rounding of the distances, so that a point kept out is one a fresh query finds nothing
/// for.
const NOTHING_MARGIN: f64 = 1e-6;

/// [`associate`], remembering nearest neighbours across calls in `memory` (see [`NearestMemory`]).
pub(super) fn associate_with(
    source: &PointSet2,
    target: &PointSet2,
    tree: &TargetTree,
    t: &Iso2,
    cfg: &DenseConfig,
    mut memory: Option<&mut NearestMemory>,
) -> Vec<(usize, usize)> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let max_sq = cfg.max_distance * cfg.max_distance;
    let gate_sq = cfg.gate * cfg.gate;
    if let Some(m) = memory.as_deref_mut() {
        m.entries.resize(source.len(), Remembered::Unknown);
    }
    let mut pairs = Vec::with_capacity(source.len());
    for (i, (x, cx)) in source.points.iter().zip(&source.covs).enumerate() {
        let q = (t * nalgebra::Point2::from(*x)).coords;
        let found = match memory.as_deref_mut() {
            None => tree
                .nearest_two(&q, cfg.max_distance)
                .map(|(j, d, _)| (j as usize, d)),
            Some(m) => remembered_nearest(&mut m.entries[i], tree, target, &q, cfg.max_distance),
        };
        let Some((j, dist_sq)) = found else {
            continue;
        };
        if dist_sq > max_sq {
            continue;
        }
        let (Some(y), Some(cy)) = (target.points.get(j), target.covs.get(j)) else {
            continue;
        };
        let d = y - q;
        let s: Mat2 = cy + r * cx * r.transpose();
        let Some(s_inv) = s.try_inverse() else {
            continue;
        };
        if d.dot(&(s_inv * d)) <= gate_sq {
            pairs.push((i, j));
        }
    }
    pairs
}

/// The nearest target point within `reach` of `q` (index, squared distance) as a fresh query
/// finds it, from what `entry` remembers when that settles it, else from a query that `entry` then
/// remembers (see [`NearestMemory`]).
#[inline]
fn remembered_nearest(
    entry: &mut Remembered,
    tree: &TargetTree,
    target: &PointSet2,
    q: &Vec2,
    reach: f64,
) -> Option<(usize, f64)> {
    match *entry {
        Remembered::Nearest(j, second, at) => {
            if let Some(y) = target.points.get(j as usize) {
                let d = (y - q).norm();
                if d < second - (q - at).norm() {
                    return Some((j as usize, d * d));
                }
            }
        }
        Remembered::Nothing(beyond, at) => {
            if beyond - (q - at).norm() > reach + NOTHING_MARGIN {
                return None;
            }
        }
        Remembered::Unknown => {}
    }
    // Only partners within `reach` count: a second nearest beyond it is remembered at that
    // distance (still a valid bound for the test above).
    match tree.nearest_two_or_bound(q, reach) {
        Ok((j, d1, d2)) => {
            *entry = Remembered::Nearest(j, d2.sqrt(), *q);
            Some((j as usize, d1))
        }
        Err(bound) => {
            *entry = Remembered::Nothing(bound.sqrt(), *q);
            None
        }
    }
}

/// Virtual partners of the soft rounds (see [`DenseConfig::soft_rounds`]) under `t`: for each
/// source point, the likelihood-weighted mean of its `super::SOFT_NEIGHBOURS` nearest target points
/// within `cfg.max_distance`, with the weighted covariance plus the partners' weighted scatter, as
/// `(virtual targets, pairs)`. A point whose partners' total likelihood is below one partner's at
/// the gate (`cfg.gate`) gets none.
pub(super) fn soft_partners(
    source: &PointSet2,
    target: &PointSet2,
    tree: &TargetTree,
    t: &Iso2,
    cfg: &DenseConfig,
) -> (PointSet2, Vec<(usize, usize)>) {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let gate_sq = cfg.gate * cfg.gate;
    let floor = (-0.5 * gate_sq).exp();
    let mut virt = PointSet2 {
        points: Vec::with_capacity(source.len()),
        covs: Vec::with_capacity(source.len()),
        rays: Vec::new(),
    };
    let mut pairs = Vec::with_capacity(source.len());
    let r2 = cfg.max_distance * cfg.max_distance;
    let mut within: Vec<(u32, f64, Vec2)> = Vec::new();
    let mut near: Vec<(u32, f64)> = Vec::new();
    for (i, (x, cx)) in source.points.iter().zip(&source.covs).enumerate() {
        let q = (t * nalgebra::Point2::from(*x)).coords;
        // One grid visit per point: the target points within reach, then the nearest of them
        // (strictly inside the reach, the first of equals, as `PointGrid::nearest_two`).
        within.clear();
        tree.within(&q, cfg.max_distance, |j, d2, d| within.push((j, d2, d)));
        let nearest =
            within
                .iter()
                .filter(|w| w.1 < r2)
                .fold(None, |best: Option<&(u32, f64, Vec2)>, w| match best {
                    Some(b) if b.1 <= w.1 => Some(b),
                    _ => Some(w),
                });
        // One combined covariance per point, with the nearest partner's covariance: neighbours on
        // one surface carry nearly the same one, and a 2x2 inverse per neighbour doubled the cost.
        let Some(cy) = nearest.and_then(|n| target.covs.get(n.0 as usize)) else {
            continue;
        };
        let Some(s_inv) = (cy + r * cx * r.transpose()).try_inverse() else {
            continue;
        };
        near.clear();
        near.extend(within.iter().filter_map(|&(j, _, d)| {
            let m = d.dot(&(s_inv * d));
            (m <= gate_sq).then_some((j, m))
        }));
        if near.len() > super::SOFT_NEIGHBOURS {
            near.select_nth_unstable_by(super::SOFT_NEIGHBOURS - 1, |a, b| {
                a.1.total_cmp(&b.1).then(a.0.cmp(&b.0))
            });
            near.truncate(super::SOFT_NEIGHBOURS);
        }
        let (mut total, mut sum) = (0.0, Vec2::zeros());
        for w in near.iter_mut() {
            w.1 = (-0.5 * w.1).exp();
            total += w.1;
            sum += target.points[w.0 as usize] * w.1;
        }
        if !total.is_finite() || total <= floor {
            continue;
        }
        let mean = sum / total;
        let cov = near.iter().fold(Mat2::zeros(), |a, &(j, w)| {
            let d = target.points[j as usize] - mean;
            a + (target.covs[j as usize] + d * d.transpose()) * w
        }) / total;
        pairs.push((i, virt.points.len()));
        virt.points.push(mean);
        virt.covs.push(cov);
    }
    (virt, pairs)
}

#[cfg(test)]
mod tests {
    use super::super::target_tree;
    use super::*;

    /// Remembered nearest neighbours give exactly the pairs of fresh queries, pose after pose
    /// (small moves, where most are kept, and a jump, where most are queried again).
    #[test]
    fn remembered_nearest_neighbours_give_the_pairs_of_fresh_queries() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let pts = |rng: &mut rand::rngs::StdRng, n: usize| -> Vec<crate::math::Vec2> {
            (0..n)
                .map(|_| {
                    crate::math::Vec2::new(
                        rng.random_range(-30.0..30.0),
                        rng.random_range(-30.0..30.0),
                    )
                })
                .collect()
        };
        let source = PointSet2::isotropic(pts(&mut rng, 800), 0.2);
        let target = PointSet2::isotropic(pts(&mut rng, 900), 0.2);
        let tree = target_tree(&target).expect("tree");
        let cfg = DenseConfig::default();
        let mut memory = NearestMemory::default();
        let mut t = Iso2::new(crate::math::Vec2::new(0.3, -0.2), 0.01);
        for step in 0..30 {
            let jump = if step == 15 { 0.8 } else { 0.004 };
            t *= Iso2::new(
                crate::math::Vec2::new(
                    rng.random_range(-jump..jump),
                    rng.random_range(-jump..jump),
                ),
                rng.random_range(-jump..jump) * 0.01,
            );
            let before = memory.entries.clone();
            let fresh = associate(&source, &target, &tree, &t, &cfg);
            let kept = associate_with(&source, &target, &tree, &t, &cfg, Some(&mut memory));
            assert_eq!(kept, fresh, "step {step}");
            assert!(fresh.len() > 100, "step {step}: {} pairs", fresh.len());
            // An entry left as it was is a query saved.
            let known = |e: &&Remembered| matches!(e, Remembered::Nearest(..));
            let saved = before
                .iter()
                .zip(&memory.entries)
                .filter(|(a, b)| known(a) && a == b)
                .count();
            // Points with no target point within `max_distance` have no nearest to remember.
            let remembered = before.iter().filter(known).count();
            match step {
                0 => assert_eq!(saved, 0, "nothing to remember yet"),
                15 => assert!(saved < remembered / 2, "the jump: {saved} saved"),
                _ => {
                    assert!(remembered > 100, "step {step}: {remembered} remembered");
                    assert!(saved > remembered * 9 / 10, "step {step}: {saved} saved")
                }
            }
        }
    }

    /// A virtual partner is the likelihood-weighted mean of the target points inside the gate, by
    /// hand: three points at Mahalanobis distances 0, 1 and 2 under the combined covariance (the
    /// point's and its nearest partner's), a fourth beyond the gate that adds nothing, and a source
    /// point with no target point within reach that gets no partner.
    #[test]
    fn soft_partner_is_the_likelihood_weighted_mean_inside_the_gate() {
        let sigma = 0.1;
        let combined: f64 = 2.0 * sigma * sigma;
        let s = combined.sqrt();
        let target = PointSet2::isotropic(
            vec![
                Vec2::new(10.0, 0.0),
                Vec2::new(10.0 + s, 0.0),
                Vec2::new(10.0, 2.0 * s),
                Vec2::new(10.0 - 3.5 * s, 0.0),
            ],
            sigma,
        );
        let source = PointSet2::isotropic(vec![Vec2::new(0.0, 0.0), Vec2::new(-20.0, 0.0)], sigma);
        let tree = target_tree(&target).expect("tree");
        let t = Iso2::new(Vec2::new(10.0, 0.0), 0.0);
        let (virt, pairs) = soft_partners(&source, &target, &tree, &t, &DenseConfig::default());
        assert_eq!(pairs, vec![(0, 0)]);
        let w = [1.0, (-0.5f64).exp(), (-2.0f64).exp()];
        let total: f64 = w.iter().sum();
        let mean =
            (target.points[0] * w[0] + target.points[1] * w[1] + target.points[2] * w[2]) / total;
        assert!(
            (virt.points[0] - mean).norm() < 1e-12,
            "{:?}",
            virt.points[0]
        );
        let scatter = (0..3).fold(Mat2::zeros(), |a, k| {
            let d = target.points[k] - mean;
            a + (target.covs[k] + d * d.transpose()) * w[k]
        }) / total;
        assert!((virt.covs[0] - scatter).norm() < 1e-12);
    }
}
