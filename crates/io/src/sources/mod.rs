//! Sources of recorded radar data: each yields the pipeline's [`Input`]s (or an [`InputIssue`] for a
//! message it skips), in time order.
//!
//! Entry points:
//! - [`rosbag`]: a rosbag2 or ROS 1 bag ([`rosbag::BagInputs`]).
//! - [`foxglove`]: a foxglove MCAP from nuscenes2mcap ([`foxglove::FoxgloveInputs`]).
//! - [`nuscenes_pcd`]: nuScenes ARS408 radar PCD files ([`nuscenes_pcd::NuscenesRadarPcd`], all 18
//!   fields per point, the devkit's default filter [`nuscenes_pcd::NuscenesRadarFilter`], conversion to
//!   [`Detection`] from the RAW `vx, vy` projected on the ray, and [`nuscenes_pcd::pcd_to_pointcloud2`]
//!   which wraps the PCD records into the PointCloud2 that nuscenes2bag/nuscenes2mcap published).
//! - [`nuscenes`]: the nuScenes tables (`NuscenesDb::open`), scenes of radar sweeps with calibration and
//!   ego poses, and a scene as an input stream ([`nuscenes::SceneInputs`]).
//! - [`vod`]: View-of-Delft 4D-radar `.bin` frames ([`vod::read_radar_bin`]), camera poses
//!   ([`vod::VodPoses`]) and KITTI calibration ([`vod::KittiCalib::t_camera_radar`]).
//! - [`vod_sequence`]: a VoD directory split into sequences of consecutive frames, each an input stream
//!   ([`vod_sequence::VodInputs`]).
//!
//! Every reader returns a typed error naming the file, header key or field at fault; none panics on
//! malformed bytes.
//!
//! [`Detection`]: dc_loc_core::radar::Detection
//! [`Input`]: dc_loc_core::input::Input
//! [`InputIssue`]: dc_loc_core::input::InputIssue

pub mod foxglove;
pub mod nuscenes;
pub mod nuscenes_pcd;
pub mod rosbag;
pub mod vod;
pub mod vod_sequence;
