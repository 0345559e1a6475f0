//! The radars' extrinsics from `/tf_static` (`node.extrinsics_from_tf`): before the node subscribes to
//! its inputs, it reads the static transforms (reliable, transient local, as tf2's static broadcaster
//! publishes them) until each radar frame has its `body_frame -> frame_id` transform, and stops with the
//! missing frames named when they do not all come within `node.tf_timeout`.

use std::collections::BTreeMap;
use std::time::Duration;

use futures::StreamExt;
use ros2_client::Subscription;

use super::error::NodeError;
use dc_loc_core::math::Iso3;
use dc_loc_core::msgs::tf2_msgs::TFMessage;

/// The direct transforms `body_frame -> f` for each `f` of `frames` that `msg` holds.
pub fn transforms_to(msg: &TFMessage, body_frame: &str, frames: &[String]) -> Vec<(String, Iso3)> {
    msg.transforms
        .iter()
        .filter(|t| t.header.frame_id == body_frame && frames.contains(&t.child_frame_id))
        .filter_map(|t| Some((t.child_frame_id.clone(), t.transform.to_iso3()?)))
        .collect()
}

/// Reads `sub` until every frame of `frames` has its transform from `body_frame`, for at most
/// `timeout`.
pub async fn static_extrinsics(
    sub: &Subscription<TFMessage>,
    body_frame: &str,
    frames: &[String],
    timeout: Duration,
) -> Result<BTreeMap<String, Iso3>, NodeError> {
    let mut found = BTreeMap::new();
    let mut stream = std::pin::pin!(sub.async_stream());
    let read = async {
        while found.len() < frames.len() {
            match stream.next().await {
                Some(Ok((msg, _))) => {
                    for (frame, t) in transforms_to(&msg, body_frame, frames) {
                        found.entry(frame).or_insert(t);
                    }
                }
                Some(Err(e)) => log::warn!("/tf_static: undecodable message: {e:?}"),
                None => break,
            }
        }
    };
    let _ = tokio::time::timeout(timeout, read).await;
    if found.len() == frames.len() {
        return Ok(found);
    }
    let missing: Vec<&str> = frames
        .iter()
        .filter(|f| !found.contains_key(*f))
        .map(String::as_str)
        .collect();
    Err(NodeError::Runtime(format!(
        "node.extrinsics_from_tf: no /tf_static transform from `{body_frame}` to {} within {:.1} s \
         (node.tf_timeout); publish them (robot_state_publisher, static_transform_publisher) or set \
         radars.<name>.extrinsic and node.extrinsics_from_tf:=false",
        missing
            .iter()
            .map(|f| format!("`{f}`"))
            .collect::<Vec<_>>()
            .join(", "),
        timeout.as_secs_f64()
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dc_loc_core::math::Vec3;
    use dc_loc_core::msgs::geometry_msgs::{Quaternion, Transform, TransformStamped, Vector3};
    use dc_loc_core::msgs::std_msgs::Header;

    fn transform(parent: &str, child: &str, x: f64) -> TransformStamped {
        TransformStamped {
            header: Header {
                frame_id: parent.into(),
                ..Default::default()
            },
            child_frame_id: child.into(),
            transform: Transform {
                translation: Vector3 { x, y: 0.0, z: 0.5 },
                rotation: Quaternion {
                    x: 0.0,
                    y: 0.0,
                    z: 0.0,
                    w: 1.0,
                },
            },
        }
    }

    #[test]
    fn only_direct_transforms_from_the_body_to_a_radar_count() {
        let msg = TFMessage {
            transforms: vec![
                transform("base_link", "radar_front", 3.5),
                transform("base_link", "imu", 0.1),
                transform("chassis", "radar_rear", -1.0),
            ],
        };
        let frames = ["radar_front".to_string(), "radar_rear".to_string()];
        let got = transforms_to(&msg, "base_link", &frames);
        assert_eq!(got.len(), 1);
        assert_eq!(got[0].0, "radar_front");
        assert_eq!(got[0].1.translation.vector, Vec3::new(3.5, 0.0, 0.5));
    }
}
