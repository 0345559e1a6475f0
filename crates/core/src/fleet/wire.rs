//! `dc_loc/msg/Keyframe`, the keyframe on the wire: the record's quantised points, covariances and
//! rays (8 bytes a point), at most a given number of them (an even subsample), with the odometry pose and
//! path length, and what its node knew of the fleet ([`FleetState`]: the keyframes it held, its
//! accepted alignments). The place descriptor is not sent: the receiver makes it from the points with
//! its own `place.*` settings.

use super::{FleetState, SharedAlignment, SharedKeyframe};
use crate::keyframe_db::{KeyframeRecord, dequantise_point};
use crate::loop_closure::Alignment;
use crate::math::{Iso2, Stamp, Vec2, iso2_from_iso3};
use crate::msgs::dc_loc::Keyframe;
use crate::msgs::geometry_msgs::Pose;
use crate::msgs::std_msgs::Header;
use crate::place::{PlaceConfig, PlaceDescriptor};

/// Points sent per keyframe by default: 16 000 bytes of points, under 16 KiB a message.
pub const DEFAULT_WIRE_POINTS: usize = 2000;

/// Most points a received keyframe may carry.
const MAX_RECEIVED_POINTS: usize = 100_000;

/// Most alignments a received keyframe may carry.
const MAX_RECEIVED_ALIGNMENTS: usize = 10_000;

/// The message of keyframe `rec` of robot `robot`, made while its node knew `fleet` (the newest
/// keyframe id of each other robot, its accepted alignments to their sessions), with at most
/// `max_points` points (0: all).
pub fn encode(
    robot: i32,
    rec: &KeyframeRecord,
    fleet: &FleetState,
    max_points: usize,
    body_frame: &str,
) -> Keyframe {
    let n = rec.points.len();
    let keep: Vec<usize> = if max_points == 0 || n <= max_points {
        (0..n).collect()
    } else {
        (0..max_points).map(|k| k * n / max_points).collect()
    };
    Keyframe {
        header: Header {
            stamp: rec.stamp.into(),
            frame_id: body_frame.to_string(),
        },
        robot_id: robot,
        session: rec.session,
        id: rec.id,
        odom_pose: Pose::from(&rec.odom_pose_iso3()),
        path_distance: rec.path_distance,
        heard_robots: fleet.heard.iter().map(|h| h.0).collect(),
        heard_ids: fleet.heard.iter().map(|h| h.1).collect(),
        aligned_robots: fleet.alignments.iter().map(|a| a.robot).collect(),
        aligned_sessions: fleet.alignments.iter().map(|a| a.session).collect(),
        aligned_poses: fleet
            .alignments
            .iter()
            .map(|a| a.alignment.t)
            .flat_map(|t| [t.translation.x, t.translation.y, t.rotation.angle()])
            .collect(),
        aligned_paths: fleet
            .alignments
            .iter()
            .flat_map(|a| [a.alignment.path, a.alignment.match_path])
            .collect(),
        points: keep.iter().flat_map(|&i| rec.points[i]).collect(),
        covariances: keep.iter().flat_map(|&i| rec.covs[i]).collect(),
        rays: if rec.rays.len() == n {
            keep.iter().map(|&i| rec.rays[i]).collect()
        } else {
            Vec::new()
        },
    }
}

/// The keyframe a message carries, its place descriptor made with `place`; why not, when the message
/// is malformed (a bad stamp, a pose that is not finite or not a rotation, a negative path, points,
/// covariances and rays that do not pair up, too many points, alignments that do not pair up or are
/// not finite).
pub fn decode(msg: &Keyframe, place: &PlaceConfig) -> Result<SharedKeyframe, String> {
    let t = msg.header.stamp;
    let stamp = Stamp::checked_from_sec_nanosec(t.sec, t.nanosec)
        .ok_or_else(|| format!("stamp {}.{:09} names no time", t.sec, t.nanosec))?;
    let pose = msg
        .odom_pose
        .to_iso3()
        .ok_or("odometry pose not finite or not a rotation")?;
    if !(msg.path_distance.is_finite() && msg.path_distance >= 0.0) {
        return Err(format!("path length {}", msg.path_distance));
    }
    if !msg.points.len().is_multiple_of(2) || msg.covariances.len() != msg.points.len() / 2 * 3 {
        return Err(format!(
            "{} point coordinates and {} covariance codes do not pair up (2 and 3 a point)",
            msg.points.len(),
            msg.covariances.len()
        ));
    }
    if msg.heard_robots.len() != msg.heard_ids.len() {
        return Err(format!(
            "{} heard robots and {} heard ids",
            msg.heard_robots.len(),
            msg.heard_ids.len()
        ));
    }
    let alignments = alignments(msg)?;
    let n = msg.points.len() / 2;
    if !(msg.rays.is_empty() || msg.rays.len() == n) {
        return Err(format!("{n} points and {} rays", msg.rays.len()));
    }
    if n > MAX_RECEIVED_POINTS {
        return Err(format!("{n} points, more than {MAX_RECEIVED_POINTS}"));
    }
    let points: Vec<[i16; 2]> = msg.points.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
    let covs: Vec<[u8; 3]> = msg
        .covariances
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let planar: Vec<_> = points.iter().map(|&q| dequantise_point(q)).collect();
    let q = pose.rotation.quaternion();
    let p = pose.translation.vector;
    Ok(SharedKeyframe {
        robot: msg.robot_id,
        record: KeyframeRecord {
            id: msg.id,
            session: msg.session,
            stamp,
            t_odom_body: iso2_from_iso3(&pose),
            odom_pose: [p.x, p.y, p.z, q.i, q.j, q.k, q.w],
            path_distance: msg.path_distance,
            points,
            covs,
            rays: msg.rays.clone(),
            place: PlaceDescriptor::from_points(&planar, place),
        },
        fleet: FleetState {
            heard: msg
                .heard_robots
                .iter()
                .copied()
                .zip(msg.heard_ids.iter().copied())
                .collect(),
            alignments,
        },
    })
}

/// The accepted alignments a message carries; why not, when their fields do not pair up (one robot,
/// session, three pose values and two path lengths each), there are too many, or a value is not
/// finite or a path length is negative.
fn alignments(msg: &Keyframe) -> Result<Vec<SharedAlignment>, String> {
    let n = msg.aligned_robots.len();
    if msg.aligned_sessions.len() != n
        || msg.aligned_poses.len() != 3 * n
        || msg.aligned_paths.len() != 2 * n
    {
        return Err(format!(
            "{n} aligned robots, {} sessions, {} pose values and {} path lengths do not pair up (1, 1, 3 and 2 per alignment)",
            msg.aligned_sessions.len(),
            msg.aligned_poses.len(),
            msg.aligned_paths.len()
        ));
    }
    if n > MAX_RECEIVED_ALIGNMENTS {
        return Err(format!(
            "{n} alignments, more than {MAX_RECEIVED_ALIGNMENTS}"
        ));
    }
    let finite = msg.aligned_poses.iter().all(|v| v.is_finite());
    let paths = msg.aligned_paths.iter().all(|p| p.is_finite() && *p >= 0.0);
    if !(finite && paths) {
        return Err("an alignment's pose is not finite or its path length is negative".into());
    }
    Ok((0..n)
        .map(|k| {
            let (x, y, yaw) = (
                msg.aligned_poses[3 * k],
                msg.aligned_poses[3 * k + 1],
                msg.aligned_poses[3 * k + 2],
            );
            SharedAlignment {
                robot: msg.aligned_robots[k],
                session: msg.aligned_sessions[k],
                alignment: Alignment {
                    t: Iso2::new(Vec2::new(x, y), yaw),
                    path: msg.aligned_paths[2 * k],
                    match_path: msg.aligned_paths[2 * k + 1],
                },
            }
        })
        .collect())
}

/// Bytes of a message on the wire (CDR with its encapsulation header, as a DDS sample carries it).
pub fn wire_bytes(msg: &Keyframe) -> usize {
    crate::cdr::encode(msg).map_or(0, |b| b.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::keyframe_db::{quantise_cov, quantise_point, quantise_ray};
    use crate::math::{Iso2, Mat2, Vec2};

    fn record(n: usize) -> KeyframeRecord {
        let pts: Vec<Vec2> = (0..n)
            .map(|i| {
                let a = i as f64 * 0.37;
                Vec2::new(30.0 * a.cos() + 0.01 * i as f64, 20.0 * a.sin())
            })
            .collect();
        let cov = Mat2::new(0.04, 0.01, 0.01, 0.09);
        let points: Vec<[i16; 2]> = pts.iter().filter_map(|&p| quantise_point(p)).collect();
        let planar: Vec<Vec2> = points.iter().map(|&q| dequantise_point(q)).collect();
        KeyframeRecord {
            id: 41,
            session: 2,
            stamp: Stamp::from_secs_f64(3612.25),
            t_odom_body: Iso2::new(Vec2::new(10.0, -4.0), 0.3),
            odom_pose: {
                let (s, c) = (0.15f64).sin_cos();
                [10.0, -4.0, 0.2, 0.0, 0.0, s, c]
            },
            path_distance: 512.5,
            points,
            covs: vec![quantise_cov(&cov); n],
            rays: planar
                .iter()
                .map(|p| quantise_ray(&p.normalize()))
                .collect(),
            place: PlaceDescriptor::from_points(&planar, &PlaceConfig::default()),
        }
    }

    #[test]
    fn a_keyframe_crosses_the_wire_whole_and_within_16_kb_in_a_fleet_of_four() {
        let rec = record(1500);
        let fleet = FleetState {
            heard: vec![(2, 90)],
            alignments: vec![SharedAlignment {
                robot: 2,
                session: 1,
                alignment: Alignment {
                    t: Iso2::new(Vec2::new(-310.5, 42.25), -2.5),
                    path: 812.0,
                    match_path: 95.5,
                },
            }],
        };
        let msg = encode(7, &rec, &fleet, DEFAULT_WIRE_POINTS, "base_link");
        let got = decode(&msg, &PlaceConfig::default()).unwrap();
        assert_eq!(got.robot, 7);
        assert_eq!(got.fleet.heard, fleet.heard);
        let (got_a, sent) = (got.fleet.alignments[0], fleet.alignments[0]);
        let (a, b) = (got_a.alignment, sent.alignment);
        assert_eq!(
            (got_a.robot, got_a.session, a.path, a.match_path),
            (2, 1, 812.0, 95.5)
        );
        assert!((a.t.translation.vector - b.t.translation.vector).norm() < 1e-12);
        assert!((a.t.rotation.angle() - b.t.rotation.angle()).abs() < 1e-12);
        let r = &got.record;
        assert!(r.place == rec.place, "the same points give the same place");
        assert!(r.points == rec.points && r.covs == rec.covs && r.rays == rec.rays);
        assert_eq!((r.id, r.session, r.stamp), (41, 2, rec.stamp));
        assert_eq!(r.path_distance, rec.path_distance);
        let pose_error = (0..7).map(|i| (r.odom_pose[i] - rec.odom_pose[i]).abs());
        assert!(pose_error.fold(0.0, f64::max) < 1e-12);
        assert!((r.t_odom_body.rotation.angle() - 0.3).abs() < 1e-9);
        // A robot of a fleet of four: three others heard and aligned to.
        let full = record(4000);
        let of_four = FleetState {
            heard: vec![(2, 90); 3],
            alignments: vec![fleet.alignments[0]; 3],
        };
        let msg = encode(7, &full, &of_four, DEFAULT_WIRE_POINTS, "base_link");
        assert_eq!(msg.points.len(), 2 * DEFAULT_WIRE_POINTS);
        assert_eq!(msg.rays.len(), DEFAULT_WIRE_POINTS);
        let bytes = wire_bytes(&msg);
        assert!(bytes <= 16 * 1024, "{bytes} bytes");
        assert!(bytes > 8 * DEFAULT_WIRE_POINTS, "{bytes} bytes");
        let got = decode(&msg, &PlaceConfig::default()).unwrap();
        let sent: Vec<usize> = (0..DEFAULT_WIRE_POINTS)
            .map(|k| k * 4000 / DEFAULT_WIRE_POINTS)
            .collect();
        assert!(
            sent.iter()
                .zip(&got.record.rays)
                .all(|(&i, &q)| full.rays[i] == q)
        );
    }

    /// A keyframe whose rays are not known (a map of an older format) goes without them.
    #[test]
    fn a_keyframe_without_rays_crosses_the_wire_without_them() {
        let mut rec = record(300);
        rec.rays.clear();
        let msg = encode(
            7,
            &rec,
            &FleetState::default(),
            DEFAULT_WIRE_POINTS,
            "base_link",
        );
        assert!(msg.rays.is_empty());
        let got = decode(&msg, &PlaceConfig::default()).unwrap();
        assert!(got.record.rays.is_empty() && got.record.points == rec.points);
    }

    #[test]
    fn malformed_keyframes_are_refused_with_the_reason() {
        let fleet = FleetState {
            heard: vec![(0, 3)],
            alignments: vec![SharedAlignment {
                robot: 0,
                session: 0,
                alignment: Alignment {
                    t: Iso2::identity(),
                    path: 10.0,
                    match_path: 20.0,
                },
            }],
        };
        let good = encode(1, &record(100), &fleet, 0, "base_link");
        let place = PlaceConfig::default();
        type Spoil = Box<dyn Fn(&mut Keyframe)>;
        let cases: Vec<(Spoil, &str)> = vec![
            (
                Box::new(|m| m.header.stamp.nanosec = 1_000_000_000),
                "stamp",
            ),
            (Box::new(|m| m.odom_pose.position.x = f64::NAN), "pose"),
            (
                Box::new(|m| {
                    m.odom_pose.orientation.z = 0.0;
                    m.odom_pose.orientation.w = 0.0;
                }),
                "pose",
            ),
            (Box::new(|m| m.path_distance = -1.0), "path"),
            (Box::new(|m| m.points.push(3)), "pair up"),
            (
                Box::new(|m| m.covariances.pop().map_or((), drop)),
                "pair up",
            ),
            (Box::new(|m| m.heard_ids.push(4)), "heard"),
            (Box::new(|m| m.rays.push(9)), "rays"),
            (Box::new(|m| m.aligned_sessions.push(2)), "pair up"),
            (
                Box::new(|m| m.aligned_poses.pop().map_or((), drop)),
                "pair up",
            ),
            (Box::new(|m| m.aligned_poses[2] = f64::INFINITY), "finite"),
            (Box::new(|m| m.aligned_paths[1] = -5.0), "negative"),
        ];
        for (spoil, why) in cases {
            let mut m = good.clone();
            spoil(&mut m);
            let e = decode(&m, &place).unwrap_err();
            assert!(e.contains(why), "{e}");
        }
    }
}
