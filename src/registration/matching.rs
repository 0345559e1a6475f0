//! Candidate correspondences: K nearest neighbours in descriptor space (paper section III-D: "we take
//! the K-Nearest Neighbor algorithm to find coarse associations based on the RSD").
//!
//! Entry points: [`MatchingConfig`], [`DescriptorTree`], [`descriptor_tree`], [`match_descriptors`].
//! Each source descriptor is looked up in a kiddo k-d tree over the target descriptors (built once per
//! submap and reused, see [`super::PreparedSubmap`]). Two optional filters: Lowe's ratio test
//! generalised to K (keep the m-th neighbour only if its distance is below `ratio` times the
//! distance of the (K+1)-th), and mutual consistency (keep i -> j only if i is also among the K
//! nearest source descriptors of j).

use crate::registration::RegistrationError;
use crate::registration::descriptor::{DESCRIPTOR_DIM, Descriptor};
use crate::registration::ransac::Correspondence;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};
use std::num::NonZeroUsize;

/// A k-d tree over descriptors; item = point index.
pub type DescriptorTree = ImmutableKdTree<f32, DESCRIPTOR_DIM>;

/// Builds the descriptor tree of one submap.
pub fn descriptor_tree(descriptors: &[Descriptor]) -> Result<DescriptorTree, RegistrationError> {
    DescriptorTree::new_from_slice(descriptors)
        .map_err(|e| RegistrationError::Numerical(format!("descriptor k-d tree: {e}")))
}

/// Matching settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatchingConfig {
    /// Nearest target descriptors kept per source point (default 3).
    pub k: usize,
    /// Keep i -> j only when i is also among the `k` nearest source descriptors of j (default false).
    pub mutual: bool,
    /// Ratio test: keep the m-th neighbour only if its distance is below `ratio` times that of the
    /// (k+1)-th neighbour; 1.0 = off (default 1.0).
    pub ratio: f64,
}

impl Default for MatchingConfig {
    fn default() -> Self {
        MatchingConfig {
            k: 3,
            mutual: false,
            ratio: 1.0,
        }
    }
}

impl MatchingConfig {
    /// Rejects unusable values; `prefix` is the dotted section name.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        use crate::config::ConfigError;
        if self.k == 0 {
            return Err(ConfigError::new(
                format!("{prefix}.k"),
                "must be at least 1",
            ));
        }
        if !(self.ratio > 0.0 && self.ratio <= 1.0) {
            return Err(ConfigError::new(
                format!("{prefix}.ratio"),
                format!("{} is not in (0, 1]", self.ratio),
            ));
        }
        Ok(())
    }
}

/// Candidate correspondences source -> target by descriptor distance (see the module doc).
///
/// `source_tree` is needed only for `mutual`; without it mutual filtering is skipped.
pub fn match_descriptors(
    source: &[Descriptor],
    target: &[Descriptor],
    target_tree: &DescriptorTree,
    source_tree: Option<&DescriptorTree>,
    cfg: &MatchingConfig,
) -> Vec<Correspondence> {
    if target.is_empty() || source.is_empty() {
        return Vec::new();
    }
    let k = cfg.k.min(target.len());
    let use_ratio = cfg.ratio < 1.0 && target.len() > k;
    let query_n = if use_ratio { k + 1 } else { k };
    let Some(query_n) = NonZeroUsize::new(query_n) else {
        return Vec::new();
    };
    let ratio2 = (cfg.ratio * cfg.ratio) as f32;
    let mut out = Vec::with_capacity(source.len() * k);
    for (i, d) in source.iter().enumerate() {
        let nn = target_tree
            .query(d)
            .nearest_n::<SquaredEuclidean<f32>>(query_n)
            .execute();
        let cut = if use_ratio {
            nn.last()
                .map(|r| r.distance * ratio2)
                .unwrap_or(f32::INFINITY)
        } else {
            f32::INFINITY
        };
        for r in nn.iter().take(k) {
            if use_ratio && r.distance >= cut {
                continue;
            }
            out.push(Correspondence {
                source: i as u32,
                target: r.item,
                descriptor_distance: r.distance.sqrt(),
            });
        }
    }
    if let (true, Some(st)) = (cfg.mutual, source_tree) {
        let kk = NonZeroUsize::new(cfg.k.min(source.len()).max(1)).unwrap_or(NonZeroUsize::MIN);
        // Reverse neighbours, computed once per target point that appears.
        let mut reverse: Vec<Option<Vec<u32>>> = vec![None; target.len()];
        out.retain(|c| {
            let j = c.target as usize;
            let Some(dj) = target.get(j) else {
                return false;
            };
            let back = reverse[j].get_or_insert_with(|| {
                st.query(dj)
                    .nearest_n::<SquaredEuclidean<f32>>(kk)
                    .execute()
                    .iter()
                    .map(|r| r.item)
                    .collect()
            });
            back.contains(&c.source)
        });
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
        let tt = descriptor_tree(&target).unwrap();
        let cfg = MatchingConfig {
            k: 2,
            ..MatchingConfig::default()
        };
        let c = match_descriptors(&source, &target, &tt, None, &cfg);
        let pairs: Vec<(u32, u32)> = c.iter().map(|c| (c.source, c.target)).collect();
        assert_eq!(pairs, vec![(0, 10), (0, 11), (1, 30), (1, 31)]);
        // Ratio 0.5 with k = 1: 10.1 is far closer to 10 than to 11 (kept); 30.45 is ambiguous.
        let cfg = MatchingConfig {
            k: 1,
            ratio: 0.5,
            ..MatchingConfig::default()
        };
        let c = match_descriptors(&source, &target, &tt, None, &cfg);
        assert_eq!(c.len(), 1);
        assert_eq!((c[0].source, c[0].target), (0, 10));
        // Mutual with k = 1: target 10's nearest source is 0 (kept).
        let st = descriptor_tree(&source).unwrap();
        let cfg = MatchingConfig {
            k: 1,
            mutual: true,
            ..MatchingConfig::default()
        };
        let c = match_descriptors(&source, &target, &tt, Some(&st), &cfg);
        assert_eq!(c.len(), 2);
        // A source far from everything is not the mutual neighbour of its nearest target
        // when another source is closer to that target.
        let source = vec![desc(49.0), desc(60.0)];
        let st = descriptor_tree(&source).unwrap();
        let c = match_descriptors(&source, &target, &tt, Some(&st), &cfg);
        let pairs: Vec<(u32, u32)> = c.iter().map(|c| (c.source, c.target)).collect();
        assert_eq!(pairs, vec![(0, 49)]);
    }
}
