//! Fleets: keyframes shared between robots' nodes so that each finds revisits of the others' streets.
//!
//! A node publishes each keyframe it makes ([`wire::encode`], `dc_loc/msg/Keyframe`) and takes the
//! other robots' into its own map ([`crate::pipeline::Pipeline::push`] with
//! [`crate::input::Input::Keyframe`], decoded there by [`wire::decode`]) as sessions of their own, searched by place descriptor alone: the
//! robots share no odometry frame. A pair of keyframes of two robots is registered by one node only:
//! the one that held the other's keyframe when it made its own (the new keyframe's search), or, when
//! both made theirs before receiving the other's, the one whose keyframe is the newer, when the other's
//! arrives ([`crate::keyframe_db::KeyframeDb::registers_on_arrival`],
//! [`crate::loop_closure::LoopCloser::search_arrival`]). Each keyframe on the wire says what its node
//! had received of the others' (`heard_robots`, `heard_ids`) to make this decidable on both sides.
//!
//! Entry points: [`SharedKeyframe`], [`wire`].

pub mod wire;

use crate::keyframe_db::{KeyframeRecord, Origin};

/// Another robot's keyframe as received: `record.id` and `record.session` are that robot's.
#[derive(Debug, Clone, PartialEq)]
pub struct SharedKeyframe {
    /// The robot's `node.robot_id`.
    pub robot: i32,
    /// The keyframe, its place descriptor made here.
    pub record: KeyframeRecord,
    /// The newest keyframe id of each other robot its node held when it made it.
    pub heard: Vec<(i32, u64)>,
}

impl SharedKeyframe {
    /// Where it came from.
    pub fn origin(&self) -> Origin {
        Origin {
            robot: self.robot,
            session: self.record.session,
            id: self.record.id,
        }
    }
}
