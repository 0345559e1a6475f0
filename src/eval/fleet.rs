//! Inter-robot loop closures measured on a simulated fleet ([`crate::sim::fleet`]): the robots' drives
//! go through the pipeline one after the other, each continuing the keyframe map the earlier ones left
//! ([`Pipeline::with_map`]: their keyframes are another session's, found by place descriptor alone, with
//! no shared odometry frame), as a robot that receives the others' keyframes would search them.
//!
//! Judged as [`super::revisits`] judges laps, with robots for laps: an opportunity is a keyframe of a
//! robot with an earlier robot's keyframe within 5 m in the same direction (or across the street in the
//! other direction); a closure is correct within 2 m of the ground truth, both robots' poses in the
//! world's one map frame.

use std::collections::BTreeMap;

use super::revisits::{
    Collected, RevisitReport, feed, judge, keyframe_truth, measured_drift, reverse_radius,
};
use crate::pipeline::{Config, Pipeline, PipelineStats};
use crate::sim::{SimConfig, simulate};
use crate::validate::ConfigError;

/// Drives the fleet `configs` (robot `k` = `configs[k]`) through one keyframe map in turn, with the
/// pipeline configured from robot 0's drive and `tweak`, and judges the closures between robots.
pub fn evaluate_fleet(
    configs: &[SimConfig],
    tweak: impl FnOnce(&mut Config),
) -> Result<RevisitReport, ConfigError> {
    let Some(first) = configs.first() else {
        return Err(ConfigError::new("fleet", "no robot"));
    };
    let mut cfg = first.to_config();
    tweak(&mut cfg);
    cfg.r#loop.enabled = true;
    let mut seen = Collected::default();
    let mut truth = BTreeMap::new();
    let mut stats = PipelineStats::default();
    let (mut drift, mut radius) = (0.0f64, 0.0f64);
    let mut db = None;
    for (robot, c) in configs.iter().enumerate() {
        let drive = simulate(c)?;
        let mut p = match db.take() {
            None => Pipeline::new(cfg.clone())?,
            Some(map) => Pipeline::with_map(cfg.clone(), map)?,
        };
        let mut mine = Collected::default();
        feed(&drive, &mut p, |events| mine.take(events));
        mine.take(p.finish());
        truth.append(&mut keyframe_truth(&drive, &mine.keyframes, |_| robot));
        stats.keyframes += p.stats().keyframes;
        for (reason, n) in &p.stats().rejected {
            *stats.rejected.entry(*reason).or_default() += n;
        }
        seen.keyframes.append(&mut mine.keyframes);
        seen.closures.append(&mut mine.closures);
        seen.rejections.append(&mut mine.rejections);
        drift = drift.max(measured_drift(&drive));
        radius = radius.max(reverse_radius(&drive));
        db = Some(p.into_db());
    }
    Ok(judge(truth, radius, drift, &seen, &stats))
}
