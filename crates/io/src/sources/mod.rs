//! Sources of recorded radar data: each yields the pipeline's [`Input`](dc_loc_core::input::Input)s
//! (or an [`InputIssue`](dc_loc_core::input::InputIssue) for a message it skips), in time order. Every
//! reader returns a typed error naming the file, header key or field at fault; none panics on malformed
//! bytes.
//!
//! Entry points: [`rosbag`] (a rosbag2 or ROS 1 bag, [`rosbag::BagInputs`]), [`foxglove`] (a foxglove
//! MCAP from nuscenes2mcap, [`foxglove::FoxgloveInputs`]), [`nuscenes_pcd`] (nuScenes ARS408 radar PCD
//! files: all 18 fields, the devkit's default filter, detections from the raw `vx, vy` projected on the
//! ray, the PointCloud2 that nuscenes2bag/nuscenes2mcap published), [`nuscenes`] (the nuScenes tables,
//! a scene as an input stream, [`nuscenes::SceneInputs`]), [`vod`] (View-of-Delft 4D-radar frames,
//! camera poses and KITTI calibration) and [`vod_sequence`] (a VoD directory as sequences of
//! consecutive frames, each an input stream, [`vod_sequence::VodInputs`]). Ground truth may also come
//! from a file of its own: [`tum`] (TUM trajectory files), with [`ground_truth`] (the speed of poses
//! without a twist, a tracked frame's pose moved to the body frame) shared by every source.

pub mod foxglove;
pub mod ground_truth;
pub mod nuscenes;
pub mod nuscenes_pcd;
pub mod rosbag;
pub mod tum;
pub mod vod;
pub mod vod_sequence;
