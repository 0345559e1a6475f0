//! Fleets: keyframes shared between robots' nodes so that each finds revisits of the others' streets.
//!
//! A node publishes each keyframe it makes ([`wire::encode`], `dc_loc/msg/Keyframe`) and takes the
//! other robots' into its own map ([`crate::pipeline::Pipeline::push`] with
//! [`crate::input::Input::Keyframe`], decoded there by [`wire::decode`]) as sessions of their own,
//! searched by place descriptor until a closure to a robot's session (held, then accepted) puts this
//! robot in that robot's frame: the robots share no odometry frame. A pair of keyframes of two
//! robots is registered by one node only: the one that held the other's keyframe when it made its own
//! (the new keyframe's search), or, when both made theirs before receiving the other's, the one whose
//! keyframe is the newer, when the other's arrives
//! ([`crate::keyframe_db::KeyframeDb::registers_on_arrival`],
//! [`crate::loop_closure::LoopCloser::search_arrival`]). Each keyframe on the wire says what its node
//! had received of the others' (`heard_robots`, `heard_ids`) to make this decidable on both sides.
//!
//! Each keyframe also carries the alignments its node has accepted to the other robots' sessions
//! ([`SharedAlignment`]). A receiver takes the one to its own session, inverted, as a prior for its
//! closures to the sender: before it has an alignment of its own, a closure far beyond what the
//! odometry drift along both robots' paths allows from it is refused
//! ([`crate::loop_closure::LoopCloser::take_shared`]).
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
