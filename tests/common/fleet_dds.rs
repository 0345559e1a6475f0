//! Raw rustdds participants on the fleet topic `/dc_loc/keyframes`, for the security tests: a
//! participant on loopback (secured with an enclave of an SROS2 keystore, or not), a writer and a
//! reader with the QoS the nodes' fleet endpoints use, and a small well-formed keyframe of any robot.
//! Each test uses what it needs of it.

#![allow(dead_code)]

use std::net::Ipv4Addr;
use std::path::Path;

use dc_loc::msgs::dc_loc::Keyframe;
use rustdds::policy::{Durability, History, Reliability};
use rustdds::{
    DomainParticipant, DomainParticipantBuilder, DomainParticipantSecurityConfigFiles, QosPolicies,
    QosPolicyBuilder, Topic, TopicKind,
};

/// A participant of `domain` on loopback, secured with the enclave directory `enclave` (sros2's file
/// names) when given.
pub fn participant(domain: u16, enclave: Option<&Path>) -> DomainParticipant {
    let mut b = DomainParticipantBuilder::new(domain).with_only_networks([Ipv4Addr::LOCALHOST]);
    if let Some(dir) = enclave {
        b = b.builtin_security(
            DomainParticipantSecurityConfigFiles::with_ros_default_names(dir, String::new()),
        );
    }
    b.build().expect("participant")
}

/// The fleet topic's QoS as the nodes use it (reliable, transient local).
fn keyframe_qos() -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(100),
        })
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 100 })
        .build()
}

fn keyframe_topic(participant: &DomainParticipant) -> Result<Topic, String> {
    participant
        .create_topic(
            "rt/dc_loc/keyframes".into(),
            "dc_loc::msg::dds_::Keyframe_".into(),
            &keyframe_qos(),
            TopicKind::NoKey,
        )
        .map_err(|e| format!("{e:?}"))
}

/// A writer of fleet keyframes on `participant`; the access control's refusal when its permissions do
/// not allow it.
pub fn keyframe_writer(
    participant: &DomainParticipant,
) -> Result<rustdds::no_key::DataWriter<Keyframe>, String> {
    let topic = keyframe_topic(participant)?;
    participant
        .create_publisher(&keyframe_qos())
        .map_err(|e| format!("{e:?}"))?
        .create_datawriter_no_key_cdr(&topic, None)
        .map_err(|e| format!("{e:?}"))
}

/// A reader of fleet keyframes on `participant`.
pub fn keyframe_reader(
    participant: &DomainParticipant,
) -> Result<rustdds::no_key::DataReader<Keyframe>, String> {
    let topic = keyframe_topic(participant)?;
    participant
        .create_subscriber(&keyframe_qos())
        .map_err(|e| format!("{e:?}"))?
        .create_datareader_no_key_cdr(&topic, None)
        .map_err(|e| format!("{e:?}"))
}

/// Robot `robot`'s keyframe `id` as the fleet topic carries it: forty points around the origin.
pub fn fleet_keyframe(robot: i32, id: u64) -> Keyframe {
    use dc_loc::keyframe_db::{KeyframeRecord, quantise_cov, quantise_point};
    use dc_loc::math::{Iso2, Mat2, Stamp, Vec2};
    let pts: Vec<Vec2> = (0..40)
        .map(|i| Vec2::new(5.0 + i as f64, (i % 7) as f64))
        .collect();
    let place = dc_loc::place::PlaceConfig::default();
    let record = KeyframeRecord {
        id,
        session: 0,
        stamp: Stamp::from_secs_f64(100.0 + id as f64),
        t_odom_body: Iso2::identity(),
        odom_pose: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        path_distance: 5.0 * id as f64,
        points: pts.iter().filter_map(|&p| quantise_point(p)).collect(),
        covs: pts
            .iter()
            .map(|_| quantise_cov(&Mat2::new(0.04, 0.0, 0.0, 0.04)))
            .collect(),
        rays: Vec::new(),
        place: dc_loc::place::PlaceDescriptor::from_points(&pts, &place),
    };
    let fleet = dc_loc::fleet::FleetState::default();
    dc_loc::fleet::wire::encode(robot, &record, &fleet, 0, "base_link")
}
