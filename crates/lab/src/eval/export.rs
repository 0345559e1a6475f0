//! The evaluation's pairs on disk, for registering them with other tools (`examples/peers.py`).
//!
//! `DIR/points.f32` holds every exported submap's Doppler-compensated points, (x, y) as little-endian
//! float32 in the submap's anchor body frame, one submap after another. `DIR/pairs.jsonl` has a line a
//! pair: where its query and target submaps lie in the points file (`offset` and `count` in points),
//! the true `T_target_query` as `[x, y, yaw]`, and DC-Loc's own estimate, errors and single-threaded
//! time on that pair (`seconds`), of which `prepare_seconds` went into preparing the two submaps.
//! `DIR/meta.json` says how many pairs there are and what produced them.
//!
//! DC-Loc's time covers preparing both submaps and registering them on one thread, as a peer that
//! computes its features and registers is timed.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use super::{
    EvalConfig, EvalKeyframe, Method, Pair, PairResult, StageSeconds, ground_truth, score,
    timed_stages,
};
use dc_loc_core::math::Iso2;
use dc_loc_core::registration::RegistrationConfig;

/// Name of the points file in the export directory.
pub const POINTS_FILE: &str = "points.f32";

/// DC-Loc on one pair, its two stages timed on the calling thread.
pub fn timed_dcloc(
    kfs: &[EvalKeyframe],
    pair: &Pair,
    registration: &RegistrationConfig,
) -> (PairResult, StageSeconds) {
    let (q, t) = (&kfs[pair.query], &kfs[pair.target]);
    let (s, g) = (q.submap.point_set(true), t.submap.point_set(true));
    let (res, seconds) = timed_stages(&s, &g, registration);
    (score(pair, Method::DCLOC, kfs, res), seconds)
}

/// Writes the pairs, their submaps and DC-Loc's results on them into `dir`; `source` describes the
/// drive for `meta.json`. DC-Loc runs on a single thread.
pub fn export_pairs(
    dir: &Path,
    kfs: &[EvalKeyframe],
    pairs: &[Pair],
    registration: &RegistrationConfig,
    eval: &EvalConfig,
    source: &str,
) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let spans = write_points(&dir.join(POINTS_FILE), kfs, pairs)?;
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(std::io::Error::other)?;
    let mut out = std::io::BufWriter::new(std::fs::File::create(dir.join("pairs.jsonl"))?);
    for pair in pairs {
        let (r, seconds) = one_thread.install(|| timed_dcloc(kfs, pair, registration));
        let line = serde_json::json!({
            "query": span_json(kfs, pair.query, &spans),
            "target": span_json(kfs, pair.target, &spans),
            "truth": se2_array(&ground_truth(kfs, pair)),
            "distance": pair.distance,
            "dcloc": dcloc_json(&r, seconds),
        });
        writeln!(out, "{line}")?;
    }
    out.flush()?;
    let meta = serde_json::json!({
        "pairs": pairs.len(),
        "points_file": POINTS_FILE,
        "outlier_threshold": eval.outlier_threshold,
        "dcloc_threads": 1,
        "source": source,
    });
    std::fs::write(dir.join("meta.json"), format!("{meta:#}\n"))
}

/// Writes the compensated points of every keyframe a pair uses; returns each one's (offset, count).
fn write_points(
    path: &Path,
    kfs: &[EvalKeyframe],
    pairs: &[Pair],
) -> std::io::Result<BTreeMap<usize, (usize, usize)>> {
    let mut spans = BTreeMap::new();
    for p in pairs {
        spans.insert(p.query, (0, 0));
        spans.insert(p.target, (0, 0));
    }
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut offset = 0;
    for (&k, span) in spans.iter_mut() {
        let set = kfs[k].submap.point_set(true);
        for p in &set.points {
            out.write_all(&(p.x as f32).to_le_bytes())?;
            out.write_all(&(p.y as f32).to_le_bytes())?;
        }
        *span = (offset, set.points.len());
        offset += set.points.len();
    }
    out.flush()?;
    Ok(spans)
}

fn span_json(
    kfs: &[EvalKeyframe],
    k: usize,
    spans: &BTreeMap<usize, (usize, usize)>,
) -> serde_json::Value {
    let (offset, count) = spans[&k];
    serde_json::json!({ "id": kfs[k].id, "offset": offset, "count": count })
}

fn se2_array(t: &Iso2) -> [f64; 3] {
    [t.translation.x, t.translation.y, t.rotation.angle()]
}

fn dcloc_json(r: &PairResult, seconds: StageSeconds) -> serde_json::Value {
    let finite = |x: f64| x.is_finite().then_some(x);
    serde_json::json!({
        "estimate": r.estimate.as_ref().map(se2_array),
        "seconds": seconds.prepare + seconds.register,
        "prepare_seconds": seconds.prepare,
        "translation_error": finite(r.translation_error),
        "rotation_error": finite(r.rotation_error),
        "failure": r.failure,
    })
}
