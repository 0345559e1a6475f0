//! Revisit ground truth for the evaluation: where a later lap passes a place an earlier lap saw.
//!
//! Entry points: [`RevisitIndex`] (built from ground-truth samples), [`RevisitIndex::nearest_earlier`],
//! [`Revisit`].
//!
//! As in the paper's evaluation, a pair is the nearest ground-truth position on an earlier lap within a
//! distance (5 m in the paper); an optional heading gate keeps only passes in (roughly) the same
//! direction. U-turn samples are never matched. A reverse lap drives the opposite lane, two lane offsets
//! (10.5 m by default) from the forward laps, so a 5 m gate pairs it with no forward lap.

use crate::sim::odometry::PoseSample;
use dc_loc_core::math::{Stamp, Vec2, wrap_angle};
use kiddo::{ImmutableKdTree, SquaredEuclidean};

/// The earlier pass matched to a later stamp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Revisit {
    /// Stamp of the earlier ground-truth sample.
    pub stamp: Stamp,
    /// Its lap.
    pub lap: usize,
    /// Distance between the two ground-truth positions, m.
    pub distance: f64,
    /// Heading of the later pose minus that of the earlier, wrapped, rad.
    pub heading_difference: f64,
}

struct LapTree {
    lap: usize,
    tree: ImmutableKdTree<f64, 2>,
    samples: Vec<usize>,
}

/// Ground-truth positions per lap in k-d trees.
pub struct RevisitIndex {
    samples: Vec<PoseSample>,
    laps: Vec<LapTree>,
}

impl std::fmt::Debug for RevisitIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RevisitIndex")
            .field("samples", &self.samples.len())
            .field("laps", &self.laps.len())
            .finish()
    }
}

impl RevisitIndex {
    /// Indexes the ground-truth samples (U-turn samples excluded).
    pub fn new(samples: &[PoseSample]) -> Self {
        let max_lap = samples.iter().map(|s| s.lap.lap).max().unwrap_or(0);
        let mut laps = Vec::new();
        for lap in 0..=max_lap {
            let idx: Vec<usize> = (0..samples.len())
                .filter(|&i| samples[i].lap.lap == lap && !samples[i].lap.turning)
                .collect();
            let pts: Vec<[f64; 2]> = idx
                .iter()
                .map(|&i| {
                    let p = samples[i].t_map_body.translation.vector;
                    [p.x, p.y]
                })
                .collect();
            if let Ok(tree) = ImmutableKdTree::new_from_slice(&pts) {
                laps.push(LapTree {
                    lap,
                    tree,
                    samples: idx,
                });
            }
        }
        RevisitIndex {
            samples: samples.to_vec(),
            laps,
        }
    }

    /// The ground-truth sample nearest to `position` among laps before `lap`, if one lies within
    /// `max_distance` (m) and, when given, within `max_heading_difference` (rad) of `heading`.
    pub fn nearest_earlier(
        &self,
        position: Vec2,
        heading: f64,
        lap: usize,
        max_distance: f64,
        max_heading_difference: Option<f64>,
    ) -> Option<Revisit> {
        let mut best: Option<Revisit> = None;
        for lt in self.laps.iter().filter(|l| l.lap < lap) {
            let found = lt
                .tree
                .query(&[position.x, position.y])
                .within::<SquaredEuclidean<f64>>(max_distance * max_distance)
                .execute();
            for item in found {
                let Some(&si) = lt.samples.get(item.item as usize) else {
                    continue;
                };
                let s = &self.samples[si];
                let dh = wrap_angle(heading - s.heading);
                if max_heading_difference.is_some_and(|m| dh.abs() > m) {
                    continue;
                }
                let d = item.distance.sqrt();
                if best.is_none_or(|b| d < b.distance) {
                    best = Some(Revisit {
                        stamp: s.stamp,
                        lap: s.lap.lap,
                        distance: d,
                        heading_difference: dh,
                    });
                }
                break; // results come nearest first
            }
        }
        best
    }
}
