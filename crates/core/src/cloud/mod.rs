//! Point clouds as bytes: `sensor_msgs/PointCloud2` in and out.
//!
//! Entry points (all in [`pointcloud2`], re-exported here):
//! - [`decode_detections`] / [`decode_detections_into`]: PointCloud2 + [`FieldsConfig`] field names ->
//!   [`DecodedCloud`] (radar-frame [`Detection`]s plus counts of skipped points), or a [`DecodeError`]
//!   naming the field or size at fault. Any field order/offset, datatypes INT8..=FLOAT64, both byte
//!   orders, row padding; radial velocity from one scalar field or from `vx, vy` projected on the ray.
//! - [`encode_detections`] with a [`CloudLayout`] ([`CloudLayout::radar_f32`],
//!   [`CloudLayout::nuscenes_radar`], or any caller-built list of [`LayoutField`]s): detections ->
//!   PointCloud2, for the simulator, the node's submap output and tests. Decoding an encoded cloud with
//!   [`CloudLayout::fields_config`] gives the detections back within each datatype's precision.
//! - [`ScalarType`]: the PointField datatypes and their sizes.
//!
//! [`FieldsConfig`]: crate::radar::FieldsConfig
//! [`Detection`]: crate::radar::Detection

pub mod pointcloud2;

pub use pointcloud2::{
    CloudLayout, DecodeError, DecodedCloud, EncodeError, FieldRole, LayoutField, ScalarType,
    decode_detections, decode_detections_into, encode_detections,
};
