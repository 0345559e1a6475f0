//! A simulated drive as an input stream ([`SimInputs`]): its odometry, ground truth, gyro and radar scans in
//! time order, each as the pipeline's [`Input`]. The scans come either as decoded detections
//! ([`ScanEncoding::Detections`]) or encoded as the simulator's bags carry them
//! ([`ScanEncoding::Clouds`]: float32 `x y z v_r rcs` PointCloud2), so that a drive fed in memory
//! gives what a bag of it would.

use crate::sim::{SimDrive, SimEventRef, SimScan};
use dc_loc_core::cloud::{CloudLayout, encode_detections};
use dc_loc_core::input::{Input, InputIssue, IssueReason};
use dc_loc_core::math::iso3_from_iso2;
use dc_loc_core::msgs::std_msgs::Header;

/// How [`SimInputs`] hands over the radar scans.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScanEncoding {
    /// As decoded detections ([`Input::Scan`]), in double precision.
    Detections,
    /// As the float32 PointCloud2 of the simulator's bags ([`Input::Radar`]).
    Clouds,
}

/// The inputs of a [`SimDrive`], in time order.
pub struct SimInputs<'a> {
    events: Box<dyn Iterator<Item = SimEventRef<'a>> + 'a>,
    encoding: ScanEncoding,
    layout: CloudLayout,
}

impl<'a> SimInputs<'a> {
    /// The inputs of `drive`, its scans as `encoding` says.
    pub fn new(drive: &'a SimDrive, encoding: ScanEncoding) -> Self {
        SimInputs {
            events: Box::new(drive.events()),
            encoding,
            layout: CloudLayout::radar_f32(),
        }
    }

    fn encode_scan(&self, s: &SimScan) -> Result<Input, InputIssue> {
        if self.encoding == ScanEncoding::Detections {
            return Ok(Input::Scan(s.scan.clone()));
        }
        let header = Header {
            stamp: s.scan.stamp.into(),
            frame_id: String::new(),
        };
        match encode_detections(&s.scan.detections, &self.layout, header) {
            Ok(cloud) => Ok(Input::Radar {
                radar: s.scan.radar,
                cloud,
            }),
            Err(e) => Err(InputIssue {
                topic: format!("radar {}", s.scan.radar),
                stamp: s.scan.stamp,
                reason: IssueReason::Foreign(e.to_string()),
            }),
        }
    }
}

impl Iterator for SimInputs<'_> {
    type Item = Result<Input, InputIssue>;

    fn next(&mut self) -> Option<Self::Item> {
        Some(match self.events.next()? {
            SimEventRef::Odometry(o) => Ok(Input::Odometry {
                stamp: o.stamp,
                t_odom_body: iso3_from_iso2(&o.t_odom_body),
            }),
            SimEventRef::GroundTruth(g) => Ok(Input::GroundTruth {
                stamp: g.stamp,
                t_map_body: iso3_from_iso2(&g.t_map_body),
                speed: g.speed,
            }),
            SimEventRef::Imu(i) => Ok(Input::Imu {
                stamp: i.stamp,
                angular_velocity: i.angular_velocity,
            }),
            SimEventRef::Scan(s) => self.encode_scan(s),
        })
    }
}
