//! The optional outputs for pose-graph back ends that read other types than `dc_loc/msg/LoopClosure`
//! (README_NODE.md, Back ends): the message types, declared here in `.msg` field order, and the
//! conversions from a [`LoopClosure`].
//!
//! - `pose_graph_tools_msgs/PoseGraph` (MIT-SPARK's pose_graph_tools, read by Kimera-Multi, Kimera-PGMO
//!   and ROMAN's tooling): [`pose_graph`], one `LOOPCLOSE` edge per closure from the match keyframe
//!   (`key_from`) to the query keyframe (`key_to`) with `pose` the query keyframe in the match
//!   keyframe's frame (`T_from_to`, what `BetweenFactor<Pose3>(from, to, pose)` measures in
//!   Kimera-PGMO's `DeformationGraph::processPoseGraph` and Kimera-Multi's `processLocalPoseGraph`),
//!   and the two keyframes as nodes.
//! - LIO-SAM's external loop input, `std_msgs/Float64MultiArray`: [`lio_sam_pair`], `data = [query
//!   stamp, match stamp]` in seconds, the order of `loopTimeCur`, `loopTimePre` in LIO-SAM's
//!   `mapOptimization::detectLoopClosureExternal`.

use serde::{Deserialize, Serialize};

use dc_loc_core::loop_closure::LoopClosure;
use dc_loc_core::math::Iso3;
use dc_loc_core::msgs::builtin_interfaces::Time;
use dc_loc_core::msgs::geometry_msgs::Pose;
use dc_loc_core::msgs::std_msgs::Header;

/// pose_graph_tools_msgs/msg/PoseGraphNode.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseGraphNode {
    /// The keyframe's stamp and the frame its pose is in.
    pub header: Header,
    /// Robot the keyframe belongs to (`node.robot_id`).
    pub robot_id: i32,
    /// Keyframe id.
    pub key: u64,
    /// The keyframe's odometry pose.
    pub pose: Pose,
}

/// pose_graph_tools_msgs/msg/PoseGraphEdge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseGraphEdge {
    /// The query keyframe's stamp and the body frame.
    pub header: Header,
    /// The older keyframe (the match).
    pub key_from: u64,
    /// The newer keyframe (the query).
    pub key_to: u64,
    /// Robot of `key_from`.
    pub robot_from: i32,
    /// Robot of `key_to`.
    pub robot_to: i32,
    /// One of the `PoseGraphEdge::*` constants.
    #[serde(rename = "type")]
    pub edge_type: i32,
    /// `key_to`'s body frame in `key_from`'s body frame.
    pub pose: Pose,
    /// Row-major 6x6 covariance of `pose`, x y z rot x rot y rot z (as `geometry_msgs`).
    #[serde(with = "serde_big_array::BigArray")]
    pub covariance: [f64; 36],
}

impl PoseGraphEdge {
    /// Odometry between consecutive keyframes.
    pub const ODOM: i32 = 0;
    /// A loop closure.
    pub const LOOPCLOSE: i32 = 1;
    /// A landmark observation.
    pub const LANDMARK: i32 = 2;
    /// A loop closure a back end refused.
    pub const REJECTED_LOOPCLOSE: i32 = 3;
    /// Between two mesh vertices.
    pub const MESH: i32 = 4;
    /// From a pose to a mesh vertex.
    pub const POSE_MESH: i32 = 5;
    /// From a mesh vertex to a pose.
    pub const MESH_POSE: i32 = 6;
}

/// pose_graph_tools_msgs/msg/PoseGraph.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseGraph {
    /// The query keyframe's stamp and the odometry frame.
    pub header: Header,
    /// The keyframes the edges join.
    pub nodes: Vec<PoseGraphNode>,
    /// The edges.
    pub edges: Vec<PoseGraphEdge>,
}

/// std_msgs/msg/MultiArrayDimension.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct MultiArrayDimension {
    /// Name of the dimension.
    pub label: String,
    /// Its size.
    pub size: u32,
    /// Stride of the dimension.
    pub stride: u32,
}

/// std_msgs/msg/MultiArrayLayout.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct MultiArrayLayout {
    /// The dimensions, outermost first.
    pub dim: Vec<MultiArrayDimension>,
    /// Padding elements at the front of `data`.
    pub data_offset: u32,
}

/// std_msgs/msg/Float64MultiArray.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Float64MultiArray {
    /// How `data` is laid out.
    pub layout: MultiArrayLayout,
    /// The values.
    pub data: Vec<f64>,
}

impl ros2_client::Message for PoseGraph {}
impl ros2_client::Message for Float64MultiArray {}

/// The frames the pose-graph message names.
#[derive(Debug, Clone, Copy)]
pub struct GraphFrames<'a> {
    /// The body frame (the edge's frames).
    pub body: &'a str,
    /// This session's odometry frame (its keyframes' poses).
    pub odom: &'a str,
    /// The odometry frame of earlier sessions, a loaded map's (`node.map_frame`).
    pub map: &'a str,
    /// This session's number.
    pub session: u32,
}

/// A closure as a `pose_graph_tools_msgs/PoseGraph`: one `LOOPCLOSE` edge from the match keyframe (of
/// robot `robot_from`, keyed by its id in that robot's map) to the query keyframe (of this robot,
/// `robot_to`), with the closure's relative pose (`T_match_query`) and covariance unchanged, and the
/// two keyframes as nodes with their odometry poses (the match keyframe's in `frames.map` when it
/// belongs to an earlier session, and in its own robot's odometry frame when another robot made it).
pub fn pose_graph(c: &LoopClosure, frames: &GraphFrames<'_>) -> PoseGraph {
    let mut covariance = [0.0; 36];
    for (i, v) in covariance.iter_mut().enumerate() {
        *v = c.covariance[(i / 6, i % 6)];
    }
    let header = |stamp: Time, frame: &str| Header {
        stamp,
        frame_id: frame.to_string(),
    };
    let node = |robot_id: i32, key: u64, stamp: Time, frame: &str, pose: &Iso3| PoseGraphNode {
        header: header(stamp, frame),
        robot_id,
        key,
        pose: Pose::from(pose),
    };
    let (match_robot, match_key) = c.match_key();
    let match_frame = if c.match_session == frames.session {
        frames.odom
    } else {
        frames.map
    };
    PoseGraph {
        header: header(c.query_stamp.into(), frames.odom),
        nodes: vec![
            node(
                match_robot,
                match_key,
                c.match_stamp.into(),
                match_frame,
                &c.match_odom_pose,
            ),
            node(
                c.query_robot,
                c.query_id,
                c.query_stamp.into(),
                frames.odom,
                &c.query_odom_pose,
            ),
        ],
        edges: vec![PoseGraphEdge {
            header: header(c.query_stamp.into(), frames.body),
            key_from: match_key,
            key_to: c.query_id,
            robot_from: match_robot,
            robot_to: c.query_robot,
            edge_type: PoseGraphEdge::LOOPCLOSE,
            pose: Pose::from(&c.t_match_query),
            covariance,
        }],
    }
}

/// A closure as LIO-SAM's external loop input: `[query keyframe stamp, match keyframe stamp]` in seconds
/// (LIO-SAM takes the first as the current time and the second as the earlier one, finds its own
/// keyframes nearest to them and registers them itself).
pub fn lio_sam_pair(c: &LoopClosure) -> Float64MultiArray {
    Float64MultiArray {
        layout: MultiArrayLayout {
            dim: vec![MultiArrayDimension {
                label: "query_match_stamps".into(),
                size: 2,
                stride: 2,
            }],
            data_offset: 0,
        },
        data: vec![c.query_stamp.as_secs_f64(), c.match_stamp.as_secs_f64()],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use byteorder::LittleEndian;
    use dc_loc_core::keyframe_db::Origin;
    use dc_loc_core::math::{Mat6, Stamp, Vec3};
    use dc_loc_core::output::loop_closure_msg;

    fn closure(match_session: u32) -> LoopClosure {
        let mut covariance = Mat6::identity() * 1e6;
        covariance[(0, 0)] = 0.04;
        covariance[(1, 1)] = 0.01;
        covariance[(0, 1)] = 0.005;
        covariance[(1, 0)] = 0.005;
        covariance[(5, 5)] = 1e-4;
        LoopClosure {
            query_id: 90,
            match_id: 12,
            query_stamp: Stamp::from_secs_f64(1_700_000_123.25),
            match_stamp: Stamp::from_secs_f64(1_700_000_031.5),
            query_odom_pose: Iso3::new(Vec3::new(3.0, 4.0, 0.0), Vec3::z() * 1.0),
            match_odom_pose: Iso3::new(Vec3::new(2.0, 5.0, 0.0), Vec3::z() * 0.9),
            t_match_query: Iso3::new(Vec3::new(0.7, -0.2, 0.0), Vec3::z() * 0.1),
            covariance,
            inliers: 80,
            score: 0.7,
            match_session,
            query_robot: 4,
            match_origin: None,
        }
    }

    const FRAMES: GraphFrames<'static> = GraphFrames {
        body: "base_link",
        odom: "odom",
        map: "map",
        session: 1,
    };

    #[test]
    fn one_loop_edge_from_the_match_to_the_query_with_the_closure_unchanged() {
        let c = closure(1);
        let g = pose_graph(&c, &FRAMES);
        let lc = loop_closure_msg(&c, "base_link");
        assert_eq!(g.edges.len(), 1);
        let e = &g.edges[0];
        assert_eq!((e.key_from, e.key_to), (12, 90));
        assert_eq!((e.robot_from, e.robot_to), (4, 4));
        assert_eq!(e.edge_type, PoseGraphEdge::LOOPCLOSE);
        assert_eq!(e.pose, lc.relative_pose.pose);
        assert_eq!(e.covariance, lc.relative_pose.covariance);
        assert_eq!(e.header, lc.header);
        let keys: Vec<(u64, i32, Time, &str)> = g
            .nodes
            .iter()
            .map(|n| {
                (
                    n.key,
                    n.robot_id,
                    n.header.stamp,
                    n.header.frame_id.as_str(),
                )
            })
            .collect();
        assert_eq!(
            keys,
            [
                (12, 4, lc.match_stamp, "odom"),
                (90, 4, lc.query_stamp, "odom")
            ]
        );
        assert_eq!(g.nodes[0].pose, lc.match_odom_pose);
        assert_eq!(g.nodes[1].pose, lc.query_odom_pose);
        // A match in a loaded map: its node is in the map frame.
        let g = pose_graph(&closure(0), &FRAMES);
        assert_eq!(g.nodes[0].header.frame_id, "map");
        assert_eq!(g.nodes[1].header.frame_id, "odom");
        // A match another robot made: its robot and its id there.
        let mut c = closure(2);
        c.match_origin = Some(Origin {
            robot: 9,
            session: 0,
            id: 5,
        });
        let e = &pose_graph(&c, &FRAMES).edges[0];
        assert_eq!(
            (e.robot_from, e.key_from, e.robot_to, e.key_to),
            (9, 5, 4, 90)
        );
        let lc = loop_closure_msg(&c, "base_link");
        assert_eq!((lc.match_robot, lc.match_id, lc.query_robot), (9, 5, 4));
    }

    #[test]
    fn lio_sam_gets_the_query_stamp_first() {
        let m = lio_sam_pair(&closure(1));
        assert_eq!(m.data, vec![1_700_000_123.25, 1_700_000_031.5]);
        assert_eq!(m.layout.dim[0].size, 2);
    }

    #[test]
    fn cdr_round_trip_and_layout() {
        let g = pose_graph(&closure(1), &FRAMES);
        let bytes = cdr_encoding::to_vec::<_, LittleEndian>(&g).unwrap();
        let (back, _) = cdr_encoding::from_bytes::<PoseGraph, LittleEndian>(&bytes).unwrap();
        assert_eq!(back, g);
        // The edge's last field, the covariance, ends the message: 36 doubles, the last one rot z / rot z.
        let tail = &bytes[bytes.len() - 8..];
        assert_eq!(f64::from_le_bytes(tail.try_into().unwrap()), 1e-4);
        let m = lio_sam_pair(&closure(1));
        let bytes = cdr_encoding::to_vec::<_, LittleEndian>(&m).unwrap();
        let (back, _) =
            cdr_encoding::from_bytes::<Float64MultiArray, LittleEndian>(&bytes).unwrap();
        assert_eq!(back, m);
        // dim count, label (length, 18 chars + NUL, padded to 4), size, stride, data_offset, data count,
        // padding to 8, two doubles.
        assert_eq!(bytes.len(), 4 + 4 + 20 + 4 + 4 + 4 + 4 + 4 + 16);
        let second = &bytes[bytes.len() - 8..];
        assert_eq!(
            f64::from_le_bytes(second.try_into().unwrap()),
            1_700_000_031.5
        );
    }
}
