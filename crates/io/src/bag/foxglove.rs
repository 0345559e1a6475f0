//! MCAP files written by foxglove's nuscenes2mcap (and other foxglove-schema recorders): radar as
//! `foxglove.PointCloud` protobuf, transforms as `foxglove.FrameTransform(s)`; plus the extrinsics of
//! any bag's `/tf_static` or `/tf` (rosbag2, ROS 1 or foxglove).
//!
//! Entry points: the protobuf messages ([`PointCloud`], [`FrameTransform`], [`FrameTransforms`], with
//! their `foxglove/schemas` field numbers), [`point_cloud_to_pointcloud2`], [`transforms_of`],
//! [`bag_extrinsics`], [`is_foxglove_cloud`]; the input stream of such a file is
//! `crate::sources::foxglove::FoxgloveInputs`.
//!
//! nuscenes2mcap's layout (the data formats page in docs/): topics `/radar_front` ... (or `/RADAR_FRONT` in the 2022
//! version), frame id the channel name, point stride 43, the PCD fields in order with their packed
//! offsets, `data` the raw PCD records; `/tf` carries `map -> base_link` (the ego pose, at every sweep)
//! and `base_link -> radar_*` (calibrated_sensor). The ego pose is what the pipeline gets as odometry.

use std::collections::BTreeMap;

use prost::Message;

use super::{BagError, BagReader, schema};
use dc_loc_core::math::{Iso3, Quat, Stamp};
use dc_loc_core::msgs::sensor_msgs::{PointCloud2, PointField};
use dc_loc_core::msgs::std_msgs::Header;
use dc_loc_core::msgs::tf2_msgs::TFMessage;

/// Schema name of a foxglove point cloud.
pub const POINT_CLOUD: &str = "foxglove.PointCloud";
/// Schema name of one foxglove transform.
pub const FRAME_TRANSFORM: &str = "foxglove.FrameTransform";
/// Schema name of a list of foxglove transforms.
pub const FRAME_TRANSFORMS: &str = "foxglove.FrameTransforms";

/// `google.protobuf.Timestamp`.
#[derive(Clone, PartialEq, Message)]
pub struct Timestamp {
    /// Seconds.
    #[prost(int64, tag = "1")]
    pub seconds: i64,
    /// Nanoseconds.
    #[prost(int32, tag = "2")]
    pub nanos: i32,
}

impl Timestamp {
    /// As a stamp.
    pub fn stamp(&self) -> Stamp {
        Stamp(
            self.seconds
                .saturating_mul(1_000_000_000)
                .saturating_add(i64::from(self.nanos)),
        )
    }
}

/// `foxglove.Vector3`.
#[derive(Clone, PartialEq, Message)]
pub struct Vector3 {
    /// x
    #[prost(double, tag = "1")]
    pub x: f64,
    /// y
    #[prost(double, tag = "2")]
    pub y: f64,
    /// z
    #[prost(double, tag = "3")]
    pub z: f64,
}

/// `foxglove.Quaternion`.
#[derive(Clone, PartialEq, Message)]
pub struct Quaternion {
    /// x
    #[prost(double, tag = "1")]
    pub x: f64,
    /// y
    #[prost(double, tag = "2")]
    pub y: f64,
    /// z
    #[prost(double, tag = "3")]
    pub z: f64,
    /// w
    #[prost(double, tag = "4")]
    pub w: f64,
}

/// `foxglove.Pose`.
#[derive(Clone, PartialEq, Message)]
pub struct Pose {
    /// Position.
    #[prost(message, optional, tag = "1")]
    pub position: Option<Vector3>,
    /// Orientation.
    #[prost(message, optional, tag = "2")]
    pub orientation: Option<Quaternion>,
}

/// `foxglove.PackedElementField`.
#[derive(Clone, PartialEq, Message)]
pub struct PackedElementField {
    /// Field name.
    #[prost(string, tag = "1")]
    pub name: String,
    /// Byte offset in a point.
    #[prost(fixed32, tag = "2")]
    pub offset: u32,
    /// `foxglove.NumericType`: 1 UINT8, 2 INT8, 3 UINT16, 4 INT16, 5 UINT32, 6 INT32, 7 FLOAT32,
    /// 8 FLOAT64.
    #[prost(int32, tag = "3")]
    pub r#type: i32,
}

/// `foxglove.PointCloud`.
#[derive(Clone, PartialEq, Message)]
pub struct PointCloud {
    /// Time of the cloud.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// Frame of the points.
    #[prost(string, tag = "2")]
    pub frame_id: String,
    /// Origin of the points in `frame_id` (identity in nuscenes2mcap).
    #[prost(message, optional, tag = "3")]
    pub pose: Option<Pose>,
    /// Bytes per point.
    #[prost(fixed32, tag = "4")]
    pub point_stride: u32,
    /// Fields of a point.
    #[prost(message, repeated, tag = "5")]
    pub fields: Vec<PackedElementField>,
    /// Packed points.
    #[prost(bytes = "vec", tag = "6")]
    pub data: Vec<u8>,
}

/// `foxglove.FrameTransform`: `child_frame_id` in `parent_frame_id`.
#[derive(Clone, PartialEq, Message)]
pub struct FrameTransform {
    /// Time.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// Parent frame.
    #[prost(string, tag = "2")]
    pub parent_frame_id: String,
    /// Child frame.
    #[prost(string, tag = "3")]
    pub child_frame_id: String,
    /// Translation.
    #[prost(message, optional, tag = "4")]
    pub translation: Option<Vector3>,
    /// Rotation.
    #[prost(message, optional, tag = "5")]
    pub rotation: Option<Quaternion>,
}

impl FrameTransform {
    /// The child frame's pose in the parent frame; `None` when not finite or a zero quaternion.
    pub fn to_iso3(&self) -> Option<Iso3> {
        let t = self.translation.clone().unwrap_or_default();
        let q = self.rotation.clone().unwrap_or(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        });
        let quat = nalgebra::Quaternion::new(q.w, q.x, q.y, q.z);
        if ![t.x, t.y, t.z, q.x, q.y, q.z, q.w]
            .iter()
            .all(|v| v.is_finite())
            || quat.norm() == 0.0
        {
            return None;
        }
        Some(Iso3::from_parts(
            nalgebra::Translation3::new(t.x, t.y, t.z),
            Quat::new_normalize(quat),
        ))
    }
}

/// `foxglove.FrameTransforms`.
#[derive(Clone, PartialEq, Message)]
pub struct FrameTransforms {
    /// The transforms.
    #[prost(message, repeated, tag = "1")]
    pub transforms: Vec<FrameTransform>,
}

/// Why a foxglove message could not be used.
#[derive(Debug, thiserror::Error)]
pub enum FoxgloveError {
    /// The protobuf bytes do not decode.
    #[error("{type_name} does not decode: {message}")]
    Decode {
        /// Schema name.
        type_name: &'static str,
        /// prost's message.
        message: String,
    },
    /// A point field of a numeric type PointCloud2 cannot express.
    #[error("point field `{name}` has foxglove NumericType {value}")]
    FieldType {
        /// Field name.
        name: String,
        /// The type number.
        value: i32,
    },
    /// `point_stride` is 0 or `data` is not a whole number of points.
    #[error("point_stride {stride} does not divide the {len} data bytes")]
    Stride {
        /// point_stride.
        stride: u32,
        /// data length.
        len: usize,
    },
}

/// The cloud as a `sensor_msgs/PointCloud2` (one row, little-endian, same bytes): foxglove
/// NumericType mapped to PointField datatypes.
pub fn point_cloud_to_pointcloud2(c: &PointCloud) -> Result<PointCloud2, FoxgloveError> {
    let stride = c.point_stride;
    let len = c.data.len();
    if stride == 0 || !len.is_multiple_of(stride as usize) {
        return Err(FoxgloveError::Stride { stride, len });
    }
    let width =
        u32::try_from(len / stride as usize).map_err(|_| FoxgloveError::Stride { stride, len })?;
    let fields = c
        .fields
        .iter()
        .map(|f| {
            // foxglove NumericType -> sensor_msgs/PointField datatype.
            let datatype = match f.r#type {
                1 => 2, // UINT8
                2 => 1, // INT8
                3 => 4, // UINT16
                4 => 3, // INT16
                5 => 6, // UINT32
                6 => 5, // INT32
                7 => 7, // FLOAT32
                8 => 8, // FLOAT64
                value => {
                    return Err(FoxgloveError::FieldType {
                        name: f.name.clone(),
                        value,
                    });
                }
            };
            Ok(PointField {
                name: f.name.clone(),
                offset: f.offset,
                datatype,
                count: 1,
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(PointCloud2 {
        header: Header {
            stamp: c.timestamp.clone().unwrap_or_default().stamp().into(),
            frame_id: c.frame_id.clone(),
        },
        height: 1,
        width,
        fields,
        is_bigendian: false,
        point_step: stride,
        row_step: stride * width,
        data: c.data.clone(),
        is_dense: false,
    })
}

/// Whether the bag's `topic` carries foxglove point clouds.
pub fn is_foxglove_cloud(reader: &BagReader, topic: &str) -> bool {
    reader
        .topic(topic)
        .is_some_and(|t| t.type_name == POINT_CLOUD && t.message_encoding == "protobuf")
}

/// The transforms of one message of a transform topic (tf2 TFMessage in CDR or ROS 1, or foxglove
/// FrameTransform(s) in protobuf): (parent, child, stamp, pose); undecodable messages give none.
pub fn transforms_of(msg: &super::BagMessage) -> Vec<(String, String, Stamp, Iso3)> {
    let mut out = Vec::new();
    match (msg.type_name(), msg.message_encoding()) {
        (schema::TF_MESSAGE, "cdr" | "ros1") => {
            if let Ok(tf) = msg.decode::<TFMessage>() {
                for t in tf.transforms {
                    if let Some(p) = t.transform.to_iso3() {
                        out.push((
                            t.header.frame_id,
                            t.child_frame_id,
                            t.header.stamp.into(),
                            p,
                        ));
                    }
                }
            }
        }
        (FRAME_TRANSFORM, "protobuf") => {
            if let Ok(t) = FrameTransform::decode(msg.data())
                && let Some(p) = t.to_iso3()
            {
                let s = t.timestamp.clone().unwrap_or_default().stamp();
                out.push((t.parent_frame_id, t.child_frame_id, s, p));
            }
        }
        (FRAME_TRANSFORMS, "protobuf") => {
            if let Ok(ts) = FrameTransforms::decode(msg.data()) {
                for t in ts.transforms {
                    if let Some(p) = t.to_iso3() {
                        let s = t.timestamp.clone().unwrap_or_default().stamp();
                        out.push((t.parent_frame_id, t.child_frame_id, s, p));
                    }
                }
            }
        }
        _ => {}
    }
    out
}

/// The first `body_frame -> <frame>` transform of each of `frames` found on the bag's `/tf_static`,
/// then `/tf` (tf2 or foxglove messages); reading stops once every frame is found.
pub fn bag_extrinsics(
    reader: &BagReader,
    body_frame: &str,
    frames: &[String],
) -> Result<BTreeMap<String, Iso3>, BagError> {
    let mut found: BTreeMap<String, Iso3> = BTreeMap::new();
    for topic in ["/tf_static", "/tf"] {
        let Some(info) = reader.topic(topic) else {
            continue;
        };
        if info.message_encoding == "ros1"
            && let Some(fault) = super::ros1::definition_fault(&info.type_name, &info.md5sum)
        {
            log::warn!("{topic}: {fault}; its transforms are not read");
            continue;
        }
        for msg in reader.messages_on(&[topic])? {
            let Ok(msg) = msg else { break };
            for (parent, child, _, pose) in transforms_of(&msg) {
                if parent == body_frame && frames.contains(&child) {
                    found.entry(child).or_insert(pose);
                }
            }
            if frames.iter().all(|f| found.contains_key(f)) {
                return Ok(found);
            }
        }
    }
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(stride: u32, data: Vec<u8>, types: &[i32]) -> PointCloud {
        PointCloud {
            timestamp: Some(Timestamp {
                seconds: 5,
                nanos: 7,
            }),
            frame_id: "radar_front".into(),
            pose: None,
            point_stride: stride,
            fields: types
                .iter()
                .enumerate()
                .map(|(i, &t)| PackedElementField {
                    name: format!("f{i}"),
                    offset: i as u32,
                    r#type: t,
                })
                .collect(),
            data,
        }
    }

    #[test]
    fn numeric_types_map_to_point_field_datatypes() {
        // UINT8, INT8, UINT16, INT16, UINT32, INT32, FLOAT32, FLOAT64.
        let c = cloud(8, vec![0; 16], &[1, 2, 3, 4, 5, 6, 7, 8]);
        let pc = point_cloud_to_pointcloud2(&c).unwrap();
        let types: Vec<u8> = pc.fields.iter().map(|f| f.datatype).collect();
        assert_eq!(types, [2, 1, 4, 3, 6, 5, 7, 8]);
        assert_eq!((pc.width, pc.point_step, pc.row_step), (2, 8, 16));
        assert_eq!(Stamp::from(pc.header.stamp), Stamp(5_000_000_007));
        // Through the protobuf bytes and back.
        let back = PointCloud::decode(c.encode_to_vec().as_slice()).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn bad_stride_and_unknown_type_are_named() {
        let e = point_cloud_to_pointcloud2(&cloud(43, vec![0; 50], &[7])).unwrap_err();
        assert!(e.to_string().contains("point_stride 43"), "{e}");
        let e = point_cloud_to_pointcloud2(&cloud(0, Vec::new(), &[7])).unwrap_err();
        assert!(matches!(e, FoxgloveError::Stride { .. }));
        let e = point_cloud_to_pointcloud2(&cloud(4, vec![0; 4], &[0])).unwrap_err();
        assert!(e.to_string().contains("`f0`"), "{e}");
        assert!(PointCloud::decode(&[0xff, 0xff][..]).is_err());
    }

    #[test]
    fn frame_transform_pose_and_non_finite() {
        let mut t = FrameTransform {
            timestamp: None,
            parent_frame_id: "base_link".into(),
            child_frame_id: "radar_front".into(),
            translation: Some(Vector3 {
                x: 3.412,
                y: 0.0,
                z: 0.5,
            }),
            rotation: Some(Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0017453283658983088,
                w: 0.9999984769132877,
            }),
        };
        let p = t.to_iso3().unwrap();
        assert!((p.rotation.euler_angles().2.to_degrees() - 0.2).abs() < 1e-6);
        assert_eq!(p.translation.x, 3.412);
        t.translation = Some(Vector3 {
            x: f64::NAN,
            y: 0.0,
            z: 0.0,
        });
        assert!(t.to_iso3().is_none());
    }
}
