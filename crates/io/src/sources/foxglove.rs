//! A foxglove MCAP (nuscenes2mcap's output) as the pipeline's input stream: [`FoxgloveInputs`].

use std::collections::{BTreeMap, VecDeque};

use prost::Message;

use crate::bag::foxglove::{
    FoxgloveError, POINT_CLOUD, PointCloud, point_cloud_to_pointcloud2, transforms_of,
};
use crate::bag::{BagError, BagReader, Messages};
use dc_loc_core::input::{Input, InputIssue, IssueReason};
use dc_loc_core::math::Stamp;

/// A foxglove MCAP as an input stream: radar clouds from `foxglove.PointCloud` topics
/// (radar index by topic), odometry from `map_frame -> body_frame` transforms on `/tf`. Messages that do
/// not decode come out as issues; the stream goes on.
pub struct FoxgloveInputs {
    messages: Messages,
    radar_of: BTreeMap<String, usize>,
    map_frame: String,
    body_frame: String,
    queue: VecDeque<Input>,
    total: u64,
}

impl FoxgloveInputs {
    /// Reads `radar_topics[i]` as radar `i` and `/tf` for the ego pose (`map_frame -> body_frame`).
    pub fn new(
        reader: &BagReader,
        radar_topics: &[String],
        map_frame: &str,
        body_frame: &str,
    ) -> Result<Self, BagError> {
        let mut topics: Vec<&str> = radar_topics.iter().map(String::as_str).collect();
        if reader.topic("/tf").is_some() {
            topics.push("/tf");
        }
        let total = topics
            .iter()
            .map(|t| reader.topic(t).map_or(0, |i| i.message_count))
            .sum();
        Ok(FoxgloveInputs {
            messages: reader.messages_on(&topics)?,
            radar_of: radar_topics
                .iter()
                .enumerate()
                .map(|(i, t)| (t.clone(), i))
                .collect(),
            map_frame: map_frame.to_string(),
            body_frame: body_frame.to_string(),
            queue: Default::default(),
            total,
        })
    }

    /// Messages on the topics read (for progress).
    pub fn total_messages(&self) -> u64 {
        self.total
    }
}

impl Iterator for FoxgloveInputs {
    type Item = Result<Input, InputIssue>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(i) = self.queue.pop_front() {
                return Some(Ok(i));
            }
            let msg = match self.messages.next()? {
                Ok(m) => m,
                Err(e) => {
                    return Some(Err(InputIssue {
                        topic: String::new(),
                        stamp: Stamp(0),
                        reason: IssueReason::Damaged(Box::new(e)),
                    }));
                }
            };
            let issue = |reason| InputIssue {
                topic: msg.topic().to_string(),
                stamp: msg.log_time,
                reason,
            };
            if let Some(&radar) = self.radar_of.get(msg.topic()) {
                let cloud = PointCloud::decode(msg.data())
                    .map_err(|e| FoxgloveError::Decode {
                        type_name: POINT_CLOUD,
                        message: e.to_string(),
                    })
                    .and_then(|c| point_cloud_to_pointcloud2(&c));
                return Some(match cloud {
                    Ok(mut cloud) => {
                        if Stamp::from(cloud.header.stamp) == Stamp(0) {
                            cloud.header.stamp = msg.log_time.into();
                        }
                        Ok(Input::Radar { radar, cloud })
                    }
                    Err(e) => Err(issue(IssueReason::Foreign(e.to_string()))),
                });
            }
            for (parent, child, stamp, pose) in transforms_of(&msg) {
                if parent == self.map_frame && child == self.body_frame {
                    let stamp = if stamp == Stamp(0) {
                        msg.log_time
                    } else {
                        stamp
                    };
                    self.queue.push_back(Input::Odometry {
                        stamp,
                        t_odom_body: pose,
                    });
                }
            }
        }
    }
}
