//! Other robots' keyframes in the map ([`Foreigners`]): where each came from ([`Origin`]), the local
//! session each robot's session becomes, a budget per robot, and each keyframe taken once.

use std::collections::{BTreeMap, HashMap, HashSet};

use serde::{Deserialize, Serialize};

use crate::math::Stamp;

/// Where another robot's keyframe came from: that robot, its session and the keyframe's id in its map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Origin {
    /// The robot's `node.robot_id`.
    pub robot: i32,
    /// Its session there.
    pub session: u32,
    /// Its id there.
    pub id: u64,
}

/// Why another robot's keyframe was not added.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ForeignRefusal {
    /// Already in the map (a transient-local history delivered again, a restarted node).
    Duplicate,
    /// The robot already has `map.max_keyframes_per_robot` keyframes here.
    OverBudget,
    /// The map holds `map.max_keyframes`.
    MapFull,
    /// The keyframe cannot be indexed (non-finite pose).
    Invalid,
}

impl ForeignRefusal {
    /// Short snake_case name for logs and diagnostics.
    pub fn name(self) -> &'static str {
        match self {
            ForeignRefusal::Duplicate => "duplicate",
            ForeignRefusal::OverBudget => "over_budget",
            ForeignRefusal::MapFull => "map_full",
            ForeignRefusal::Invalid => "invalid",
        }
    }
}

/// The bookkeeping of other robots' keyframes in one map.
#[derive(Debug, Default, Clone)]
pub struct Foreigners {
    /// Origin by local id.
    origins: BTreeMap<u64, Origin>,
    /// What was taken, by robot, id and stamp (a robot that starts a new map reuses ids).
    seen: HashSet<(i32, u64, Stamp)>,
    /// Keyframes held per robot.
    per_robot: BTreeMap<i32, usize>,
    /// Local session of each robot's session.
    sessions: HashMap<(i32, u32), u32>,
    /// By local id: the newest keyframe id of each robot its node held when it made the keyframe.
    heard: HashMap<u64, Vec<(i32, u64)>>,
    /// The newest keyframe id held of each robot.
    newest: BTreeMap<i32, u64>,
}

impl Foreigners {
    /// The origin of local keyframe `id` (`None`: this robot's own).
    pub fn origin(&self, id: u64) -> Option<&Origin> {
        self.origins.get(&id)
    }

    /// How many of the keyframes with a local id below `id` are other robots'.
    pub fn before(&self, id: u64) -> u64 {
        self.origins.range(..id).count() as u64
    }

    /// Every origin, by local id.
    pub fn origins(&self) -> impl Iterator<Item = (u64, &Origin)> {
        self.origins.iter().map(|(k, o)| (*k, o))
    }

    /// Keyframes held of `robot`.
    pub fn count(&self, robot: i32) -> usize {
        self.per_robot.get(&robot).copied().unwrap_or(0)
    }

    /// Whether this keyframe is already held.
    pub fn holds(&self, o: &Origin, stamp: Stamp) -> bool {
        self.seen.contains(&(o.robot, o.id, stamp))
    }

    /// The local session of `o`'s session, if it has one.
    pub fn session(&self, o: &Origin) -> Option<u32> {
        self.sessions.get(&(o.robot, o.session)).copied()
    }

    /// The robot and that robot's session of local session `local`, if it is another robot's.
    pub fn session_origin(&self, local: u32) -> Option<(i32, u32)> {
        self.sessions
            .iter()
            .find(|&(_, &l)| l == local)
            .map(|(&k, _)| k)
    }

    /// The newest keyframe id held of each robot.
    pub fn newest(&self) -> Vec<(i32, u64)> {
        self.newest.iter().map(|(r, i)| (*r, *i)).collect()
    }

    /// The newest keyframe of `robot` the node that made local keyframe `id` held then.
    pub fn heard(&self, id: u64, robot: i32) -> Option<u64> {
        let heard = self.heard.get(&id)?;
        heard.iter().find(|(r, _)| *r == robot).map(|(_, i)| *i)
    }

    /// Records what the node that made local keyframe `id` held then.
    pub fn set_heard(&mut self, id: u64, heard: Vec<(i32, u64)>) {
        self.heard.insert(id, heard);
    }

    /// Records local keyframe `id` (of local session `session`, stamped `stamp`) as coming from `o`.
    pub fn record(&mut self, id: u64, session: u32, stamp: Stamp, o: Origin) {
        let newest = self.newest.entry(o.robot).or_insert(o.id);
        *newest = (*newest).max(o.id);
        self.origins.insert(id, o);
        self.seen.insert((o.robot, o.id, stamp));
        *self.per_robot.entry(o.robot).or_default() += 1;
        self.sessions.insert((o.robot, o.session), session);
    }
}
