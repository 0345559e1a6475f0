//! The offline run loop: any source's inputs through a [`Pipeline`], every input, issue and [`Event`]
//! handed to a sink, counts in a [`RunReport`]. `dc_loc run`, `dc_loc eval` and the tests share it.

use std::collections::BTreeMap;

use crate::input::{Input, InputIssue};
use crate::math::Stamp;
use crate::pipeline::{Event, Pipeline, PipelineStats};
use crate::repeats::Repeats;

/// What [`run_inputs`] hands to its closure, in stream order: each input or issue, then the events the
/// input produced.
#[derive(Debug, Clone, Copy)]
pub enum RunItem<'a> {
    /// An input, before it goes into the pipeline.
    Input(&'a Input),
    /// A skipped message.
    Issue(&'a InputIssue),
    /// An event of the pipeline (those of [`Pipeline::finish`] come last).
    Event(&'a Event),
}

/// Counts of a run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunReport {
    /// Radar clouds and scans fed to the pipeline.
    pub radar_inputs: u64,
    /// Odometry samples fed to the pipeline.
    pub odometry_inputs: u64,
    /// Gyro samples fed to the pipeline.
    pub imu_inputs: u64,
    /// Ground-truth samples read (not fed to the pipeline).
    pub ground_truth_inputs: u64,
    /// Stamp of the first radar or odometry input fed to the pipeline: where the drive starts.
    pub first_stamp: Option<Stamp>,
    /// Skipped messages by [`IssueReason::name`].
    pub issues: BTreeMap<&'static str, u64>,
    /// Skipped messages by topic and cause; the first of each cause is logged in full.
    pub issue_causes: Repeats,
    /// The pipeline's counters after [`Pipeline::finish`].
    pub stats: PipelineStats,
}

impl RunReport {
    /// Skipped messages in all.
    pub fn issue_count(&self) -> u64 {
        self.issues.values().sum()
    }
}

/// Drives `pipeline` through a whole input stream, then [`Pipeline::finish`]; every input, issue and
/// event goes to `on_item`. Issues are counted, never fatal, and logged (`warn`) the first time of
/// each topic and cause ([`InputIssue::log_once`]).
pub fn run_inputs<I, F>(pipeline: &mut Pipeline, inputs: I, mut on_item: F) -> RunReport
where
    I: IntoIterator<Item = Result<Input, InputIssue>>,
    F: FnMut(RunItem<'_>),
{
    let mut report = RunReport::default();
    for item in inputs {
        match item {
            Ok(input) => {
                match &input {
                    Input::Radar { .. } | Input::Scan(_) => report.radar_inputs += 1,
                    Input::Odometry { .. } => report.odometry_inputs += 1,
                    Input::Imu { .. } => report.imu_inputs += 1,
                    Input::GroundTruth { .. } => report.ground_truth_inputs += 1,
                    Input::Keyframe(_) => {}
                }
                if !matches!(
                    input,
                    Input::GroundTruth { .. } | Input::Keyframe(_) | Input::Imu { .. }
                ) {
                    report.first_stamp.get_or_insert(input.stamp());
                }
                on_item(RunItem::Input(&input));
                for e in pipeline.push(&input) {
                    on_item(RunItem::Event(&e));
                }
            }
            Err(issue) => {
                issue.log_once(&mut report.issue_causes);
                *report.issues.entry(issue.reason.name()).or_default() += 1;
                on_item(RunItem::Issue(&issue));
            }
        }
    }
    for e in pipeline.finish() {
        on_item(RunItem::Event(&e));
    }
    report.stats = pipeline.stats().clone();
    report
}
