//! The node's services and the pose it reports in a prior map.
//!
//! - `~/save_map` (`std_srvs/srv/Trigger`): the worker saves the keyframe map now ([`SaveRequests`]);
//!   the reply says where, or why not.
//! - `~/relocalized` (`geometry_msgs/msg/PoseWithCovarianceStamped`): each published closure onto a
//!   keyframe of an earlier session (a loaded map) gives the query keyframe's body pose in that
//!   session's odometry frame ([`relocalized`]).

use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};

use futures::StreamExt;
use ros2_client::Server;
use serde::{Deserialize, Serialize};

use dc_loc_core::loop_closure::LoopClosure;
use dc_loc_core::math::Mat6;
use dc_loc_core::msgs::builtin_interfaces::Time;
use dc_loc_core::msgs::geometry_msgs::{Pose, PoseWithCovariance};
use dc_loc_core::msgs::std_msgs::Header;

/// std_srvs/srv/Trigger request (no fields; CDR carries one padding byte for an empty struct).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct TriggerRequest {
    structure_needs_at_least_one_member: u8,
}

/// std_srvs/srv/Trigger response.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct TriggerResponse {
    /// The action was done.
    pub success: bool,
    /// What was done, or why not.
    pub message: String,
}

impl ros2_client::Message for TriggerRequest {}
impl ros2_client::Message for TriggerResponse {}

/// geometry_msgs/msg/PoseWithCovarianceStamped.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseWithCovarianceStamped {
    /// Stamp and frame of the pose.
    pub header: Header,
    /// The pose and its covariance.
    pub pose: PoseWithCovariance,
}

/// A save asked for, and where its answer goes.
pub type SaveRequest = tokio::sync::oneshot::Sender<TriggerResponse>;

/// The channel from the `~/save_map` service to the worker.
pub struct SaveRequests;

impl SaveRequests {
    /// A bounded channel (a few requests at once; more are answered "busy").
    pub fn channel() -> (SyncSender<SaveRequest>, Receiver<SaveRequest>) {
        sync_channel(4)
    }
}

/// Serves `~/save_map` until the node stops: each request goes to the worker, which saves the map
/// between two inputs and answers.
pub async fn save_map(
    server: &Server<TriggerRequest, TriggerResponse>,
    to_worker: SyncSender<SaveRequest>,
) {
    let mut requests = std::pin::pin!(server.receive_request_stream());
    while let Some(request) = requests.next().await {
        let Ok((id, _)) = request else {
            continue;
        };
        let (tx, rx) = tokio::sync::oneshot::channel();
        let response = match to_worker.try_send(tx) {
            Ok(()) => rx.await.unwrap_or_else(|_| TriggerResponse {
                success: false,
                message: "the node is stopping".into(),
            }),
            Err(TrySendError::Full(_)) => TriggerResponse {
                success: false,
                message: "saves already queued: try again".into(),
            },
            Err(TrySendError::Disconnected(_)) => return,
        };
        if let Err(e) = server.async_send_response(id, response).await {
            log::warn!("~/save_map: reply not sent: {e:?}");
        }
    }
}

/// The query keyframe's body pose in the odometry frame of the matched keyframe's session, when the
/// closure reaches an earlier session (`None` within this session). The covariance is the closure's
/// (a right perturbation in the query body frame) with its axes turned into `frame_id`'s.
pub fn relocalized(
    c: &LoopClosure,
    session: u32,
    stamp: Time,
    frame_id: &str,
) -> Option<PoseWithCovarianceStamped> {
    if c.match_session == session {
        return None;
    }
    let t_map_query = c.match_odom_pose * c.t_match_query;
    let r = t_map_query.rotation.to_rotation_matrix();
    let mut turn = Mat6::zeros();
    turn.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
    turn.fixed_view_mut::<3, 3>(3, 3).copy_from(r.matrix());
    let cov = turn * c.covariance * turn.transpose();
    let mut covariance = [0.0; 36];
    for (i, v) in covariance.iter_mut().enumerate() {
        *v = cov[(i / 6, i % 6)];
    }
    Some(PoseWithCovarianceStamped {
        header: Header {
            stamp,
            frame_id: frame_id.to_string(),
        },
        pose: PoseWithCovariance {
            pose: Pose::from(&t_map_query),
            covariance,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use dc_loc_core::math::{Iso3, Vec3};

    #[test]
    fn relocalized_pose_is_the_match_pose_times_the_closure() {
        let mut cov = Mat6::identity() * 1e6;
        cov[(0, 0)] = 0.04; // along the query's x
        cov[(1, 1)] = 0.01;
        cov[(5, 5)] = 1e-4;
        let c = LoopClosure {
            query_id: 9,
            match_id: 2,
            query_stamp: dc_loc_core::math::Stamp(0),
            match_stamp: dc_loc_core::math::Stamp(0),
            query_odom_pose: Iso3::identity(),
            match_odom_pose: Iso3::new(
                Vec3::new(10.0, 0.0, 0.0),
                Vec3::z() * std::f64::consts::FRAC_PI_2,
            ),
            t_match_query: Iso3::new(Vec3::new(1.0, 0.0, 0.0), Vec3::zeros()),
            covariance: cov,
            inliers: 50,
            score: 0.8,
            match_session: 0,
            query_robot: 0,
            match_origin: None,
        };
        assert!(relocalized(&c, 0, Time::default(), "map").is_none());
        let p = relocalized(&c, 1, Time::default(), "map").unwrap();
        // 1 m along the match keyframe's x, which points along the map's y.
        assert!((p.pose.pose.position.x - 10.0).abs() < 1e-12);
        assert!((p.pose.pose.position.y - 1.0).abs() < 1e-12);
        // The query's along-x variance is the map's along-y variance.
        assert!(
            (p.pose.covariance[7] - 0.04).abs() < 1e-12,
            "{:?}",
            &p.pose.covariance[..8]
        );
        assert!((p.pose.covariance[0] - 0.01).abs() < 1e-12);
        assert!((p.pose.covariance[35] - 1e-4).abs() < 1e-12);
    }
}
