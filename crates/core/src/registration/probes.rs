//! Probes of alignments other than the one a registration found, which the loop-closure gates use:
//! where the dense stage ends from a given pose ([`overlap_near`]), how well the alignment fits slid
//! along the heading ([`slide_overlap`]), and how much the two submaps can have seen in common
//! ([`common_view`]).

use super::config::RegistrationConfig;
use super::dense;
use super::prepared::PreparedSubmap;
use super::types::RegistrationError;
use crate::math::{Iso2, Vec2};

/// The best support near a given pose: the dense stage started at `initial`, and the overlap (as in
/// [`RegistrationResult::overlap`]) where it ends, with that pose. A check of an alternative alignment (a
/// prior from odometry or earlier closures) against the one registration found: no descriptors, no
/// covariance. `None` when too few points pair up near `initial`.
pub fn overlap_near(
    source: &PreparedSubmap,
    target: &PreparedSubmap,
    initial: &Iso2,
    cfg: &RegistrationConfig,
) -> Result<Option<(Iso2, f64)>, RegistrationError> {
    let (src, tgt) = (source.dense(), target.dense());
    let refined = dense::refine_dense(
        src.as_source(),
        tgt.as_target(),
        tgt.tree(),
        initial,
        &cfg.dense,
        &cfg.lm,
        dense::Rounds::Plain,
    )?;
    Ok(refined.map(|d| {
        let src = src.as_source();
        let n = dense::associate(
            src,
            tgt.as_target(),
            tgt.tree(),
            &d.t_target_source,
            &cfg.dense,
        )
        .len();
        (d.t_target_source, n as f64 / src.len().max(1) as f64)
    }))
}

/// Shifts along the source's x axis (a vehicle's heading) tried by [`slide_overlap`], m.
pub const SLIDE_SHIFTS: [f64; 10] = [-3.0, 3.0, -6.0, 6.0, -10.0, 10.0, -16.0, 16.0, -24.0, 24.0];

/// How well the alignment `t` slid along the source's x axis fits: the best overlap (as
/// [`overlap_near`]) of the local optima reached from `t` shifted by each of [`SLIDE_SHIFTS`] that end
/// more than 2 m from `t` (0 when none does). Along a straight street the facades fit at any shift,
/// and only poles, building edges and gaps tell the shifts apart; a result whose slid alternatives fit
/// nearly as well is a guess along the street. The shifts still to be refined are skipped once one
/// ends above `stop_above` (`f64::INFINITY` refines all): the answer is then some overlap above it,
/// not necessarily the largest (whether it exceeds `stop_above` does not depend on the order).
pub fn slide_overlap(
    source: &PreparedSubmap,
    target: &PreparedSubmap,
    t: &Iso2,
    cfg: &RegistrationConfig,
    stop_above: f64,
) -> Result<f64, RegistrationError> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    let along = t.rotation * Vec2::x();
    let done = AtomicBool::new(false);
    // The shifts are independent: refined in parallel, nearest first.
    let ends: Vec<_> = SLIDE_SHIFTS
        .par_iter()
        .map(|shift| {
            if done.load(Ordering::Relaxed) {
                return Ok(0.0);
            }
            let start =
                Iso2::from_parts((t.translation.vector + along * *shift).into(), t.rotation);
            let o = match overlap_near(source, target, &start, cfg)? {
                Some((end, o)) if (end.translation.vector - t.translation.vector).norm() > 2.0 => o,
                _ => 0.0,
            };
            if o > stop_above {
                done.store(true, Ordering::Relaxed);
            }
            Ok(o)
        })
        .collect();
    ends.into_iter()
        .try_fold(0.0f64, |best, o: Result<f64, RegistrationError>| {
            Ok(best.max(o?))
        })
}

/// How much two submaps can have seen in common, whatever their points: the intersection (0..1) of
/// their points' bearing histograms (12 sectors of 30 degrees, each histogram summing to 1) seen from
/// their anchors, with the source's turned by the yaw of `t` (to the degree). Matched submaps lie
/// metres apart, so the bearings from either anchor are close enough. A forward radar revisiting a
/// street the other way sees what lay behind it the first time, and shares little; radars that see
/// all around share much at any yaw.
pub fn common_view(source: &PreparedSubmap, target: &PreparedSubmap, t: &Iso2) -> f64 {
    source
        .dense()
        .bearings()
        .common(target.dense().bearings(), t.rotation.angle())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registration::types::PointSet2;

    /// Along bare facades every slid alignment fits as well as the true one; poles and building
    /// edges at irregular places make the true one stand out.
    #[test]
    fn slid_alignments_fit_a_bare_street_but_not_one_with_poles() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let mut street = |poles: bool| -> Vec<Vec2> {
            let mut p = Vec::new();
            for side in [-8.0, 8.0] {
                for _ in 0..150 {
                    p.push(Vec2::new(
                        rng.random_range(-60.0..60.0),
                        side + rng.random_range(-0.1..0.1),
                    ));
                }
            }
            if poles {
                // Clusters of detections (poles, building edges) at irregular places.
                for x in [-47.0, -31.0, -22.5, -5.0, 3.0, 17.5, 26.0, 44.0] {
                    let y: f64 = if x > 0.0 { 5.5 } else { -5.5 };
                    for _ in 0..25 {
                        p.push(Vec2::new(
                            x + rng.random_range(-0.15..0.15),
                            y + rng.random_range(-0.15..0.15),
                        ));
                    }
                }
            }
            p
        };
        let cfg = RegistrationConfig::default();
        // The ratios here are about 0.90 bare (points slid off the street's ends), 0.63 with poles.
        for (poles, bound) in [(false, 0.85), (true, 0.7)] {
            let pts = street(poles);
            let target =
                PreparedSubmap::new(PointSet2::isotropic(pts.clone(), 0.15), &cfg).expect("target");
            // The source: the same street seen from 4 m further along, with fresh noise.
            let t = Iso2::new(Vec2::new(4.0, 0.0), 0.0);
            let src: Vec<Vec2> = pts
                .iter()
                .map(|p| t.inverse_transform_point(&(*p).into()).coords + Vec2::new(0.03, -0.02))
                .collect();
            let source =
                PreparedSubmap::new(PointSet2::isotropic(src, 0.15), &cfg).expect("source");
            let (_, overlap) = overlap_near(&source, &target, &t, &cfg)
                .expect("refined")
                .expect("pairs");
            let slid = slide_overlap(&source, &target, &t, &cfg, f64::INFINITY).expect("slid");
            let ratio = slid / overlap;
            if poles {
                assert!(ratio < bound, "with poles: {slid:.2} / {overlap:.2}");
            } else {
                assert!(ratio > bound, "bare: {slid:.2} / {overlap:.2}");
            }
            // Stopping early gives the same verdict against any limit.
            for limit in [0.3 * overlap, bound * overlap, 0.99 * slid, slid] {
                let early = slide_overlap(&source, &target, &t, &cfg, limit).expect("slid");
                assert_eq!(
                    early > limit,
                    slid > limit,
                    "limit {limit:.3}: {early} vs {slid}"
                );
                assert!(early <= slid + 1e-12);
            }
        }
    }

    /// A forward-looking cone of points turned half round shares no bearing with itself; turned
    /// a little, most.
    #[test]
    fn common_view_of_forward_cones() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let cone: Vec<Vec2> = (0..400)
            .map(|_| {
                let (r, a) = (rng.random_range(5.0..60.0), rng.random_range(-1.3..1.3f64));
                Vec2::new(r * a.cos(), r * a.sin())
            })
            .collect();
        let all_round: Vec<Vec2> = (0..400)
            .map(|_| {
                let (r, a) = (
                    rng.random_range(5.0..60.0),
                    rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
                );
                Vec2::new(r * a.cos(), r * a.sin())
            })
            .collect();
        let cfg = RegistrationConfig::default();
        let prep = |p: &[Vec2]| {
            PreparedSubmap::new(PointSet2::isotropic(p.to_vec(), 0.15), &cfg).expect("prepared")
        };
        let (c, a) = (prep(&cone), prep(&all_round));
        let at = |yaw: f64| Iso2::new(Vec2::new(1.0, 0.5), yaw);
        assert!(common_view(&c, &c, &at(0.0)) > 0.9);
        assert!(common_view(&c, &c, &at(0.3)) > 0.6);
        assert!(common_view(&c, &c, &at(std::f64::consts::PI)) < 0.05);
        assert!(common_view(&c, &c, &at(-3.0)) < 0.1);
        // All round: half turn or not, the cone's bearings are among the other's.
        assert!(common_view(&a, &a, &at(std::f64::consts::PI)) > 0.85);
        assert!(common_view(&c, &a, &at(std::f64::consts::PI)) > 0.3);
    }
}
