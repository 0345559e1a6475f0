//! Candidate correspondences: K nearest neighbours in descriptor space (paper section III-D: "we take
//! the K-Nearest Neighbor algorithm to find coarse associations based on the RSD").
//!
//! Each queried source descriptor (at most `max_queries`, a fixed pseudo-random subset) takes its exact
//! K nearest target descriptors, optionally thinned by a Lowe ratio test generalised to K. Two backends
//! give the same neighbours ([`MatchingBackend`]): a blocked linear scan (the default) and a kiddo k-d
//! tree. docs/algorithm.md, "Correspondences", has the cost, the backends' comparison and the choice
//! of k.
//!
//! Entry points: [`MatchingConfig`], [`DescriptorIndex`] (built once per submap), [`select_queries`],
//! [`match_descriptors`], [`MatchingBackend`].

use crate::registration::descriptor::{DESCRIPTOR_DIM, Descriptor};
use crate::registration::ransac::Correspondence;
use crate::registration::types::RegistrationError;
use crate::validate::{Range, Validator};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};
use std::num::NonZeroUsize;

/// Largest supported `k` (+1 for the ratio test).
pub const MAX_K: usize = 16;

/// How the nearest descriptors are found (both exact, same result up to ties).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum MatchingBackend {
    /// Blocked linear scan (default; faster at this dimension, docs/algorithm.md, "Correspondences").
    Scan,
    /// kiddo k-d tree.
    KdTree,
}

/// Matching settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct MatchingConfig {
    /// Nearest target descriptors kept per queried source point (default 3, at most 15).
    pub k: usize,
    /// Ratio test: keep the m-th neighbour only if its distance is below `ratio` times that of the
    /// (k+1)-th neighbour; 1.0 = off (default 1.0).
    pub ratio: f64,
    /// Most source keypoints queried; above it a fixed pseudo-random subset (default 400, i.e. all
    /// of the default 400 keypoints).
    pub max_queries: usize,
    /// Search backend (default `scan`).
    pub backend: MatchingBackend,
}

impl Default for MatchingConfig {
    fn default() -> Self {
        MatchingConfig {
            k: 3,
            ratio: 1.0,
            max_queries: 400,
            backend: MatchingBackend::Scan,
        }
    }
}

impl MatchingConfig {
    /// Declares each field's range (see [`Validator`]).
    pub fn check(&self, v: &mut Validator) {
        v.count("k", self.k, 1, MAX_K - 1);
        v.range("ratio", self.ratio, Range::above(0.0).up_to(1.0));
        v.at_least("max_queries", self.max_queries, 2);
    }
}

/// The indices of the source points to query: all when there are at most `max_queries`, otherwise a
/// pseudo-random subset of that size from `seed`, ascending.
pub fn select_queries(n: usize, max_queries: usize, seed: u64) -> Vec<u32> {
    let mut idx: Vec<u32> = (0..n as u32).collect();
    if n > max_queries {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        for i in 0..max_queries {
            let j = rng.random_range(i..n);
            idx.swap(i, j);
        }
        idx.truncate(max_queries);
        idx.sort_unstable();
    }
    idx
}

const LANES: usize = 8;
type Block = [[f32; LANES]; DESCRIPTOR_DIM];

/// The descriptors of one submap arranged for nearest-neighbour search.
#[derive(Debug)]
pub struct DescriptorIndex {
    len: usize,
    dims: usize,
    blocks: Vec<Block>,
    tree: Option<ImmutableKdTree<f32, DESCRIPTOR_DIM>>,
}

impl DescriptorIndex {
    /// Arranges `descriptors` whose first `dims` entries are used (the rest are 0); builds the kiddo
    /// tree too when `backend` asks for it.
    pub fn new(
        descriptors: &[Descriptor],
        dims: usize,
        backend: MatchingBackend,
    ) -> Result<Self, RegistrationError> {
        let dims = dims.clamp(1, DESCRIPTOR_DIM);
        // Padding lanes sit at infinity so that they never enter a result.
        let mut blocks =
            vec![[[f32::INFINITY; LANES]; DESCRIPTOR_DIM]; descriptors.len().div_ceil(LANES)];
        for (j, d) in descriptors.iter().enumerate() {
            for (k, v) in d.iter().enumerate() {
                blocks[j / LANES][k][j % LANES] = *v;
            }
        }
        let tree = match backend {
            MatchingBackend::Scan => None,
            MatchingBackend::KdTree => {
                Some(ImmutableKdTree::new_from_slice(descriptors).map_err(|e| {
                    RegistrationError::Numerical(format!("descriptor k-d tree: {e}"))
                })?)
            }
        };
        Ok(DescriptorIndex {
            len: descriptors.len(),
            dims,
            blocks,
            tree,
        })
    }

    /// Number of descriptors.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The `n` nearest descriptors to `q` as (squared distance, index), nearest first, written into
    /// `out` (cleared first); `n <= MAX_K`.
    pub fn nearest(&self, q: &Descriptor, n: usize, out: &mut Vec<(f32, u32)>) {
        out.clear();
        let n = n.min(MAX_K).min(self.len);
        if n == 0 {
            return;
        }
        if let Some(tree) = &self.tree {
            if let Some(nn) = NonZeroUsize::new(n) {
                out.extend(
                    tree.query(q)
                        .nearest_n::<SquaredEuclidean<f32>>(nn)
                        .execute()
                        .iter()
                        .map(|r| (r.distance, r.item)),
                );
            }
            return;
        }
        // Sorted best list, worst last; scanned 8 targets at a time.
        let mut best = [(f32::INFINITY, u32::MAX); MAX_K];
        let mut worst = f32::INFINITY;
        let dims = self.dims;
        for (b, blk) in self.blocks.iter().enumerate() {
            let mut acc = [0.0f32; LANES];
            for (k, row) in blk.iter().enumerate().take(dims) {
                let qk = q[k];
                for l in 0..LANES {
                    let e = row[l] - qk;
                    acc[l] += e * e;
                }
            }
            for (l, &d) in acc.iter().enumerate() {
                if d < worst {
                    // Insert into the sorted list.
                    let mut m = n - 1;
                    while m > 0 && best[m - 1].0 > d {
                        best[m] = best[m - 1];
                        m -= 1;
                    }
                    best[m] = (d, (b * LANES + l) as u32);
                    worst = best[n - 1].0;
                }
            }
        }
        out.extend(best[..n].iter().copied().filter(|e| e.1 != u32::MAX));
    }
}

/// Candidate correspondences: for each queried source point, its `cfg.k` nearest target descriptors
/// (after the optional ratio test).
pub fn match_descriptors(
    source: &[Descriptor],
    queries: &[u32],
    target: &DescriptorIndex,
    cfg: &MatchingConfig,
) -> Vec<Correspondence> {
    let k = cfg.k.min(MAX_K - 1).min(target.len());
    if k == 0 {
        return Vec::new();
    }
    let use_ratio = cfg.ratio < 1.0 && target.len() > k;
    let query_n = if use_ratio { k + 1 } else { k };
    let ratio2 = (cfg.ratio * cfg.ratio) as f32;
    let mut out = Vec::with_capacity(queries.len() * k);
    let mut nn = Vec::with_capacity(MAX_K);
    for &i in queries {
        let Some(d) = source.get(i as usize) else {
            continue;
        };
        target.nearest(d, query_n, &mut nn);
        let cut = if use_ratio {
            nn.last().map(|r| r.0 * ratio2).unwrap_or(f32::INFINITY)
        } else {
            f32::INFINITY
        };
        for &(dist2, j) in nn.iter().take(k) {
            if use_ratio && dist2 >= cut {
                continue;
            }
            out.push(Correspondence {
                source: i,
                target: j,
                descriptor_distance: dist2.sqrt(),
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn desc(v: f32) -> Descriptor {
        let mut d = [0.0; DESCRIPTOR_DIM];
        d[0] = v;
        d[1] = 2.0 * v;
        d
    }

    #[test]
    fn nearest_descriptors_are_found_and_filtered() {
        let target: Vec<Descriptor> = (0..50).map(|i| desc(i as f32)).collect();
        let source = vec![desc(10.1), desc(30.45)];
        for backend in [MatchingBackend::Scan, MatchingBackend::KdTree] {
            let idx = DescriptorIndex::new(&target, DESCRIPTOR_DIM, backend).unwrap();
            let cfg = MatchingConfig {
                k: 2,
                ..MatchingConfig::default()
            };
            let c = match_descriptors(&source, &[0, 1], &idx, &cfg);
            let pairs: Vec<(u32, u32)> = c.iter().map(|c| (c.source, c.target)).collect();
            assert_eq!(
                pairs,
                vec![(0, 10), (0, 11), (1, 30), (1, 31)],
                "{backend:?}"
            );
            // Ratio 0.5 with k = 1: 10.1 is far closer to 10 than to 11 (kept); 30.45 is ambiguous.
            let cfg = MatchingConfig {
                k: 1,
                ratio: 0.5,
                ..MatchingConfig::default()
            };
            let c = match_descriptors(&source, &[0, 1], &idx, &cfg);
            assert_eq!(c.len(), 1);
            assert_eq!((c[0].source, c[0].target), (0, 10));
        }
    }

    /// The scan agrees with a plain sort over random descriptors, including a partial last block.
    #[test]
    fn scan_matches_sorting() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let mut rand_desc = || {
            let mut d = [0.0f32; DESCRIPTOR_DIM];
            for v in d.iter_mut() {
                *v = rng.random::<f32>();
            }
            d
        };
        let target: Vec<Descriptor> = (0..203).map(|_| rand_desc()).collect();
        let idx = DescriptorIndex::new(&target, DESCRIPTOR_DIM, MatchingBackend::Scan).unwrap();
        let tree = DescriptorIndex::new(&target, DESCRIPTOR_DIM, MatchingBackend::KdTree).unwrap();
        let mut out = Vec::new();
        let mut out_tree = Vec::new();
        for _ in 0..20 {
            let q = rand_desc();
            idx.nearest(&q, 5, &mut out);
            tree.nearest(&q, 5, &mut out_tree);
            let mut all: Vec<(f32, u32)> = target
                .iter()
                .enumerate()
                .map(|(j, t)| {
                    (
                        t.iter().zip(&q).map(|(a, b)| (a - b) * (a - b)).sum(),
                        j as u32,
                    )
                })
                .collect();
            all.sort_by(|a, b| a.0.total_cmp(&b.0));
            let want: Vec<u32> = all[..5].iter().map(|e| e.1).collect();
            assert_eq!(out.iter().map(|e| e.1).collect::<Vec<_>>(), want);
            assert_eq!(out_tree.iter().map(|e| e.1).collect::<Vec<_>>(), want);
        }
    }

    #[test]
    fn query_subset_is_deterministic_and_bounded() {
        let a = select_queries(1000, 100, 9);
        assert_eq!(a.len(), 100);
        assert_eq!(a, select_queries(1000, 100, 9));
        assert!(a.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(select_queries(50, 100, 9), (0..50).collect::<Vec<u32>>());
    }
}
