//! Radar detections and what is done to them before they enter a submap.
//!
//! Entry points: [`Detection`], [`RadarScan`], [`RadarNoise`]; [`doppler`] (paper eq. 4-8: compensation,
//! extrinsics, per-point covariance); [`ego_motion`] (velocity and planar twist from radial velocities,
//! moving-object rejection).

pub mod config;
pub mod consistency;
pub mod doppler;
pub mod ego_motion;
pub mod trigger;

pub use config::{FieldsConfig, RadarConfig, RadarMessage};

use crate::math::{Stamp, Vec3};
use serde::{Deserialize, Serialize};

/// One detection as the radar reports it, in the radar frame (x along the boresight, y left, z up).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    /// Measured position, m. Its range carries the Doppler distortion `beta * v_r` (paper eq. 3).
    pub p_radar: Vec3,
    /// Measured radial velocity, m/s, positive when the target moves away from the radar.
    pub v_r: f64,
    /// Radar cross-section, dBsm, when the sensor reports it.
    pub rcs: Option<f64>,
}

impl Detection {
    /// Range |p|, m.
    pub fn range(&self) -> f64 {
        self.p_radar.norm()
    }
    /// Azimuth atan2(y, x), rad.
    pub fn azimuth(&self) -> f64 {
        self.p_radar.y.atan2(self.p_radar.x)
    }
}

/// One scan (one message) of one radar.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct RadarScan {
    /// Index of the radar in the configuration's radar list.
    pub radar: usize,
    /// Measurement time.
    pub stamp: Stamp,
    /// The detections, in the radar frame.
    pub detections: Vec<Detection>,
}

/// Standard deviations of a radar's polar measurements (paper eq. 6).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RadarNoise {
    /// Range, m.
    pub sigma_range: f64,
    /// Radial velocity, m/s.
    pub sigma_velocity: f64,
    /// Azimuth, rad.
    pub sigma_azimuth: f64,
}

impl Default for RadarNoise {
    /// The paper's CARLA Gaussian noise: 0.25 m, 0.1 m/s, 0.5 deg.
    fn default() -> Self {
        RadarNoise {
            sigma_range: 0.25,
            sigma_velocity: 0.1,
            sigma_azimuth: 0.5_f64.to_radians(),
        }
    }
}
