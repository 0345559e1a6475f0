//! Fleets: keyframes shared between robots' nodes so that each finds revisits of the others' streets.
//!
//! A node publishes each keyframe it makes ([`wire::encode`], `dc_loc/msg/Keyframe`) and takes the
//! other robots' into its map ([`crate::pipeline::Pipeline::push`] with
//! [`crate::input::Input::Keyframe`], decoded there by [`wire::decode`]) as sessions of their own: the
//! robots share no odometry frame. A pair of two robots' keyframes is registered by one node only
//! ([`crate::keyframe_db::KeyframeDb::registers_on_arrival`],
//! [`crate::loop_closure::LoopCloser::search_arrival`]), decided alike on both sides from what each
//! keyframe says its node had received (`heard_robots`, `heard_ids`). Each keyframe also carries its
//! node's accepted alignments ([`SharedAlignment`]), a prior for the receiver's closures to the sender
//! ([`crate::loop_closure::LoopCloser::take_shared`]). README_NODE.md, "Fleets", has the rules.
//!
//! Entry points: [`SharedKeyframe`], [`FleetState`], [`wire`].

pub mod wire;

use crate::keyframe_db::{KeyframeRecord, Origin};
use crate::loop_closure::Alignment;

/// An alignment a node accepted, of its session's odometry frame into session `session` of robot
/// `robot` (its path lengths: the sender's keyframe, then that session's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SharedAlignment {
    /// The other robot's `node.robot_id`.
    pub robot: i32,
    /// The other robot's session.
    pub session: u32,
    /// The alignment, as the sender's session holds it.
    pub alignment: Alignment,
}

/// What a node knew of the fleet when it made a keyframe, sent with it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FleetState {
    /// The newest keyframe id of each other robot it held.
    pub heard: Vec<(i32, u64)>,
    /// Its accepted alignments to other robots' sessions.
    pub alignments: Vec<SharedAlignment>,
}

/// Another robot's keyframe as received: `record.id` and `record.session` are that robot's.
#[derive(Debug, Clone, PartialEq)]
pub struct SharedKeyframe {
    /// The robot's `node.robot_id`.
    pub robot: i32,
    /// The keyframe, its place descriptor made here.
    pub record: KeyframeRecord,
    /// What its node knew of the fleet when it made it.
    pub fleet: FleetState,
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
