//! Binding a fleet keyframe's robot id to the certificate of the participant that sent it
//! (`node.fleet_enclave`): on a secured domain the DDS authentication tells which identity certificate
//! each remote participant holds, and a keyframe claiming robot `k` is taken only from a participant
//! whose certificate's common name is the enclave `node.fleet_enclave` names for `k` (sros2 names an
//! enclave's certificate `CN=<enclave path>`).

use ros2_client::dds::rustdds::{DomainParticipant, GUID};
use ros2_client::gid::Gid;

/// The check of `node.fleet_enclave`, or none when it is empty.
pub struct FleetIdentity {
    /// The enclave of robot `{robot}`, e.g. `/fleet/robot_{robot}`.
    pattern: String,
    /// The secured participant whose authentications name the senders; `None` on an unsecured domain,
    /// where no sender has an identity and every keyframe is refused.
    participant: Option<DomainParticipant>,
}

impl FleetIdentity {
    /// The check of `pattern` (`node.fleet_enclave`) through `participant` (`None` when the domain is
    /// not secured); `None` when `pattern` is empty.
    pub fn new(pattern: &str, participant: Option<DomainParticipant>) -> Option<FleetIdentity> {
        if pattern.is_empty() {
            return None;
        }
        if participant.is_none() {
            log::warn!(
                "node.fleet_enclave is set but DDS security is off: no other robot's keyframe can \
                 prove its identity, and every one is refused (keyframe_identity)"
            );
        }
        Some(FleetIdentity {
            pattern: pattern.to_string(),
            participant,
        })
    }

    /// The enclave that robot `robot`'s keyframes must come from.
    pub fn enclave_of(&self, robot: i32) -> String {
        self.pattern.replace("{robot}", &robot.to_string())
    }

    /// `Err(detail)` unless the publisher `sender` authenticated with the certificate of robot
    /// `robot`'s enclave.
    pub fn check(&self, robot: i32, sender: Gid) -> Result<(), String> {
        let wanted = self.enclave_of(robot);
        let Some(participant) = &self.participant else {
            return Err(format!(
                "robot {robot}'s keyframe on an unsecured domain (node.fleet_enclave wants {wanted})"
            ));
        };
        let prefix = GUID::from_bytes(sender.to_bytes16()).prefix;
        match participant.authenticated_subject_name(prefix) {
            None => Err(format!(
                "robot {robot}'s keyframe from a participant with no authenticated identity"
            )),
            Some(subject) => match common_name(&subject) {
                Some(cn) if cn == wanted => Ok(()),
                _ => Err(format!(
                    "robot {robot}'s keyframe from the certificate {subject} (node.fleet_enclave \
                     wants CN={wanted})"
                )),
            },
        }
    }
}

/// The common name of an RFC 4514 subject (`CN=/robot_1` or `O=x,CN=/robot_1`); `None` without one.
/// Enclave paths hold no comma, so the attributes split at every comma.
pub fn common_name(subject: &str) -> Option<&str> {
    subject
        .split(',')
        .find_map(|attribute| attribute.trim().strip_prefix("CN="))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_common_name_is_read_from_any_place_of_the_subject() {
        assert_eq!(common_name("CN=/robot_1"), Some("/robot_1"));
        assert_eq!(common_name("O=fleet,CN=/a/robot_2"), Some("/a/robot_2"));
        assert_eq!(common_name("O=fleet"), None);
    }

    #[test]
    fn each_robot_has_the_enclave_of_the_pattern() {
        let id = FleetIdentity::new("/fleet/robot_{robot}", None).unwrap();
        assert_eq!(id.enclave_of(3), "/fleet/robot_3");
        assert!(FleetIdentity::new("", None).is_none());
        let refused = id.check(3, Gid::ZERO).unwrap_err();
        assert!(refused.contains("unsecured"), "{refused}");
    }
}
