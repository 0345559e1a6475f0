//! Summaries of an evaluation: the paper's Table 1 (methods) and Table 2 (ablation) layouts, errors by
//! ego-velocity difference, and the plot of error against velocity difference.
//!
//! Entry points: [`summarize`], [`MethodSummary`], [`table_methods`], [`table_ablation`],
//! [`table_paper_comparison`] (ours beside the paper's nuScenes numbers),
//! [`table_velocity`], [`plot_svg`].

use super::{EvalConfig, Method, PairResult};
use std::fmt::Write as _;
use std::path::Path;

/// Statistics of one method over all pairs.
#[derive(Debug, Clone, PartialEq)]
pub struct MethodSummary {
    /// The method.
    pub method: Method,
    /// Pairs evaluated.
    pub pairs: usize,
    /// Pairs with a result within the outlier threshold.
    pub inliers: usize,
    /// Translation error over the inliers, m: mean, max, median.
    pub translation: [f64; 3],
    /// Rotation error over the inliers, rad: mean, max, median.
    pub rotation: [f64; 3],
    /// Mean NEES (3 dof) over the inliers, for methods that report a covariance.
    pub nees: Option<f64>,
    /// The same over the inliers that are not ambiguous (`EvalConfig::ambiguity_ratio`), with their
    /// number.
    pub nees_unambiguous: Option<(f64, usize)>,
    /// Per velocity-difference bin (lower edge, m/s): inliers, mean translation (m), mean rotation (rad).
    pub by_velocity: Vec<(f64, usize, f64, f64)>,
}

impl MethodSummary {
    /// Inlier share, 0..1.
    pub fn inlier_share(&self) -> f64 {
        if self.pairs == 0 {
            0.0
        } else {
            self.inliers as f64 / self.pairs as f64
        }
    }
}

/// Mean, max and median of `v` (NaN when empty).
pub fn stats(mut v: Vec<f64>) -> [f64; 3] {
    if v.is_empty() {
        return [f64::NAN; 3];
    }
    v.sort_by(f64::total_cmp);
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let n = v.len();
    let median = if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    };
    [mean, v[n - 1], median]
}

/// Summarises results per method, in the order of `methods`.
pub fn summarize(
    results: &[PairResult],
    methods: &[Method],
    cfg: &EvalConfig,
) -> Vec<MethodSummary> {
    methods
        .iter()
        .map(|&m| {
            let all: Vec<&PairResult> = results.iter().filter(|r| r.method == m).collect();
            let inl: Vec<&PairResult> = all
                .iter()
                .copied()
                .filter(|r| r.translation_error <= cfg.outlier_threshold)
                .collect();
            let nees: Vec<f64> = inl.iter().filter_map(|r| r.nees).collect();
            let clear: Vec<f64> = inl
                .iter()
                .filter(|r| r.runner_up_overlap <= cfg.ambiguity_ratio * r.overlap)
                .filter_map(|r| r.nees)
                .collect();
            let max_bin = inl
                .iter()
                .map(|r| (r.velocity_difference / cfg.velocity_bin_width) as usize)
                .max();
            let by_velocity = (0..=max_bin.unwrap_or(0))
                .filter_map(|b| {
                    let lo = b as f64 * cfg.velocity_bin_width;
                    let in_bin: Vec<&&PairResult> = inl
                        .iter()
                        .filter(|r| (r.velocity_difference / cfg.velocity_bin_width) as usize == b)
                        .collect();
                    (!in_bin.is_empty()).then(|| {
                        let n = in_bin.len() as f64;
                        (
                            lo,
                            in_bin.len(),
                            in_bin.iter().map(|r| r.translation_error).sum::<f64>() / n,
                            in_bin.iter().map(|r| r.rotation_error).sum::<f64>() / n,
                        )
                    })
                })
                .collect();
            MethodSummary {
                method: m,
                pairs: all.len(),
                inliers: inl.len(),
                translation: stats(inl.iter().map(|r| r.translation_error).collect()),
                rotation: stats(inl.iter().map(|r| r.rotation_error).collect()),
                nees: (!nees.is_empty()).then(|| nees.iter().sum::<f64>() / nees.len() as f64),
                nees_unambiguous: (!clear.is_empty())
                    .then(|| (clear.iter().sum::<f64>() / clear.len() as f64, clear.len())),
                by_velocity,
            }
        })
        .collect()
}

fn row(out: &mut String, name: &str, s: &MethodSummary) {
    let _ = writeln!(
        out,
        "| {name} | {:.3} | {:.3} | {:.3} | {:.4} | {:.4} | {:.4} | {:.1} % ({}/{}) | {} |",
        s.translation[0],
        s.translation[1],
        s.translation[2],
        s.rotation[0],
        s.rotation[1],
        s.rotation[2],
        100.0 * s.inlier_share(),
        s.inliers,
        s.pairs,
        s.nees.map_or("-".into(), |n| format!("{n:.2}")),
    );
}

const HEADER: &str = "| Translation (m) mean | max | median | Rotation (rad) mean | max | median | inliers (<= threshold) | mean NEES |";

/// One line on the mean NEES over the unambiguous inliers of the methods that report a covariance
/// (empty when none does).
pub fn nees_unambiguous_line(summaries: &[MethodSummary], cfg: &EvalConfig) -> String {
    let parts: Vec<String> = summaries
        .iter()
        .filter_map(|s| {
            s.nees_unambiguous
                .map(|(n, k)| format!("{} {n:.2} ({k}/{})", s.method.name(), s.inliers))
        })
        .collect();
    if parts.is_empty() {
        return String::new();
    }
    format!(
        "Mean NEES over the inliers whose runner-up alignment fits with at most {} of their overlap (what the node's loop.maximum_ambiguity passes): {}\n",
        cfg.ambiguity_ratio,
        parts.join(", ")
    )
}

/// Table 1 layout: the methods (ICP, NDT, MC-RANSAC-style, DC-Loc and its paper form).
pub fn table_methods(summaries: &[MethodSummary]) -> String {
    let mut out = format!("| Method {HEADER}\n|---|---|---|---|---|---|---|---|---|\n");
    for s in summaries {
        let show = matches!(s.method, Method::Icp | Method::Ndt | Method::McRansac)
            || matches!(
                s.method,
                Method::DcLoc {
                    ue: true,
                    dc: true,
                    ..
                }
            );
        if show {
            row(&mut out, &s.method.name(), s);
        }
    }
    out
}

/// Table 2 layout: the ablation (U.E. / D.C. on and off, with the dense stage).
pub fn table_ablation(summaries: &[MethodSummary]) -> String {
    let mut out = format!("| U.E. | D.C. {HEADER}\n|---|---|---|---|---|---|---|---|---|---|\n");
    for s in summaries {
        if let Method::DcLoc {
            ue,
            dc,
            dense: true,
        } = s.method
        {
            let mark = |b: bool| if b { "yes" } else { "-" };
            row(&mut out, &format!("{} | {}", mark(ue), mark(dc)), s);
        }
    }
    out
}

/// The paper's nuScenes numbers: Table 1 as (method, mean / max / median
/// translation m when given, mean rotation rad), Table 2 as (U.E., D.C., mean translation m).
pub const PAPER_TABLE1: [(&str, [Option<f64>; 3], f64); 5] = [
    ("ICP", [Some(0.993), None, None], 0.0536),
    ("NDT", [Some(0.400), None, None], 0.0564),
    (
        "UTR (learned, not reproduced)",
        [Some(1.324), None, None],
        0.0576,
    ),
    ("MC-RANSAC", [Some(0.379), None, None], 0.0018),
    ("DC-Loc", [Some(0.290), Some(0.873), Some(0.243)], 0.0017),
];

/// See [`PAPER_TABLE1`].
pub const PAPER_TABLE2: [(bool, bool, f64); 4] = [
    (false, false, 0.450),
    (true, false, 0.435),
    (false, true, 0.292),
    (true, true, 0.290),
];

fn paper_cell(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |v| format!("{v:.digits$}"))
}

/// Table 1 and Table 2 with the paper's nuScenes numbers beside ours: `ours / paper` per cell
/// (translation m, rotation rad). The full DC-Loc row (with the dense stage) and the paper's form are
/// both compared with the paper's DC-Loc.
pub fn table_paper_comparison(summaries: &[MethodSummary]) -> String {
    let mut out = String::from(
        "| Method | Translation mean (ours / paper) | max | median | Rotation mean (ours / paper) | inliers |\n\
         |---|---|---|---|---|---|\n",
    );
    let find = |m: Method| summaries.iter().find(|s| s.method == m);
    let mut line = |name: &str, s: Option<&MethodSummary>, paper: &([Option<f64>; 3], f64)| {
        let ours = |v: Option<f64>, d: usize| paper_cell(v.filter(|v| v.is_finite()), d);
        let (t, r) = (s.map(|s| s.translation), s.map(|s| s.rotation[0]));
        let _ = writeln!(
            out,
            "| {name} | {} / {} | {} / {} | {} / {} | {} / {} | {} |",
            ours(t.map(|t| t[0]), 3),
            paper_cell(paper.0[0], 3),
            ours(t.map(|t| t[1]), 3),
            paper_cell(paper.0[1], 3),
            ours(t.map(|t| t[2]), 3),
            paper_cell(paper.0[2], 3),
            ours(r, 4),
            paper_cell(Some(paper.1), 4),
            s.map_or("-".into(), |s| format!("{}/{}", s.inliers, s.pairs)),
        );
    };
    let p = |i: usize| (PAPER_TABLE1[i].1, PAPER_TABLE1[i].2);
    line("ICP", find(Method::Icp), &p(0));
    line("NDT", find(Method::Ndt), &p(1));
    line(PAPER_TABLE1[2].0, None, &p(2));
    line("MC-RANSAC-style", find(Method::McRansac), &p(3));
    line("DC-Loc", find(Method::DCLOC), &p(4));
    line(
        "DC-Loc (paper: no dense stage)",
        find(Method::DcLoc {
            ue: true,
            dc: true,
            dense: false,
        }),
        &p(4),
    );
    out.push_str("\n| U.E. | D.C. | Translation mean (ours / paper) |\n|---|---|---|\n");
    for (ue, dc, paper) in PAPER_TABLE2 {
        let s = find(Method::DcLoc {
            ue,
            dc,
            dense: true,
        });
        let mark = |b: bool| if b { "yes" } else { "-" };
        let _ = writeln!(
            out,
            "| {} | {} | {} / {paper:.3} |",
            mark(ue),
            mark(dc),
            paper_cell(s.map(|s| s.translation[0]).filter(|v| v.is_finite()), 3)
        );
    }
    out
}

/// Mean translation / rotation error per ego-velocity-difference bin, one column per method.
pub fn table_velocity(summaries: &[MethodSummary], cfg: &EvalConfig) -> String {
    let bins: Vec<f64> = {
        let mut b: Vec<f64> = summaries
            .iter()
            .flat_map(|s| s.by_velocity.iter().map(|v| v.0))
            .collect();
        b.sort_by(f64::total_cmp);
        b.dedup();
        b
    };
    let mut out = String::from("| dv (m/s) |");
    for s in summaries {
        let _ = write!(out, " {} |", s.method.name());
    }
    out.push_str("\n|---|");
    out.push_str(&"---|".repeat(summaries.len()));
    out.push('\n');
    for lo in bins {
        let _ = write!(out, "| {lo:.0}-{:.0} |", lo + cfg.velocity_bin_width);
        for s in summaries {
            match s.by_velocity.iter().find(|v| v.0 == lo) {
                Some(&(_, n, t, r)) => {
                    let _ = write!(out, " {t:.3} m / {r:.4} rad (n={n}) |");
                }
                None => out.push_str(" - |"),
            }
        }
        out.push('\n');
    }
    out
}

/// Writes the mean translation error against velocity difference, one line per method, as SVG.
pub fn plot_svg(summaries: &[MethodSummary], cfg: &EvalConfig, path: &Path) -> Result<(), String> {
    use plotters::prelude::*;
    let max_dv = summaries
        .iter()
        .flat_map(|s| s.by_velocity.iter().map(|v| v.0 + cfg.velocity_bin_width))
        .fold(cfg.velocity_bin_width, f64::max);
    let max_t = summaries
        .iter()
        .flat_map(|s| s.by_velocity.iter().map(|v| v.2))
        .filter(|t| t.is_finite())
        .fold(0.1, f64::max);
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    let e = |e: DrawingAreaErrorKind<_>| format!("plot {}: {e}", path.display());
    root.fill(&WHITE).map_err(e)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Mean translation error vs ego-velocity difference",
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..max_dv, 0.0..max_t * 1.1)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("ego-velocity difference (m/s)")
        .y_desc("mean translation error (m)")
        .draw()
        .map_err(e)?;
    for (i, s) in summaries.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        let pts: Vec<(f64, f64)> = s
            .by_velocity
            .iter()
            .map(|v| (v.0 + 0.5 * cfg.velocity_bin_width, v.2))
            .collect();
        chart
            .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
            .map_err(e)?
            .label(s.method.name())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
        chart
            .draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))
            .map_err(e)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(e)?;
    root.present().map_err(e)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::Pair;

    const DC_LOC: Method = Method::DcLoc {
        ue: true,
        dc: true,
        dense: true,
    };

    fn result(error: f64, nees: f64, overlap: f64, runner_up: f64, dv: f64) -> PairResult {
        PairResult {
            pair: Pair {
                query: 1,
                target: 0,
                distance: 1.0,
            },
            method: DC_LOC,
            velocity_difference: dv,
            estimate: None,
            translation_error: error,
            rotation_error: 0.001,
            nees: Some(nees),
            failure: None,
            overlap,
            inliers: 50,
            runner_up_overlap: runner_up,
        }
    }

    /// Outliers leave the statistics; the ambiguous inlier (runner-up above 0.8 of its overlap)
    /// leaves the unambiguous NEES only.
    #[test]
    fn summary_over_the_inliers_and_the_unambiguous_ones() {
        let results = vec![
            result(0.1, 2.0, 0.8, 0.2, 1.0),
            result(0.3, 4.0, 0.6, 0.3, 9.0),
            result(1.5, 300.0, 0.5, 0.5, 9.0),
            result(7.0, 9000.0, 0.5, 0.1, 9.0),
        ];
        let cfg = EvalConfig::default();
        let s = &summarize(&results, &[DC_LOC], &cfg)[0];
        assert_eq!((s.pairs, s.inliers), (4, 3));
        assert!((s.translation[0] - 1.9 / 3.0).abs() < 1e-12);
        assert_eq!(s.translation[1], 1.5);
        assert_eq!(s.translation[2], 0.3);
        assert!((s.nees.unwrap() - 102.0).abs() < 1e-12);
        assert_eq!(s.nees_unambiguous, Some((3.0, 2)));
        assert_eq!(s.by_velocity.len(), 2);
        assert_eq!(s.by_velocity[1].1, 2);
        let line = nees_unambiguous_line(std::slice::from_ref(s), &cfg);
        assert!(line.contains("3.00 (2/3)"), "{line}");
    }
}
