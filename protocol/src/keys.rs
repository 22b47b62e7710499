//! Key expressions, built here and nowhere else.
//!
//! The tree (see the crate docs for who publishes what):
//!
//! ```text
//! team/{team}/robot/{robot}/{state|dynamics|command|torque|status|description|contacts}
//! team/{team}/member/{robot}                  liveliness tokens
//! team/{team}/coordinator/{status|diagnostics}
//! team/{team}/coordinator/alive              the coordinator's liveliness token
//! team/{team}/references
//! team/{team}/perturbation
//! team/{team}/ground-truth
//! ```

use crate::{validate_id, ProtocolError};

const ROOT: &str = "team";

/// What a robot publishes or receives on its own sub-tree.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RobotTopic {
    State,
    Dynamics,
    Command,
    Torque,
    Status,
    Description,
    Contacts,
}

impl RobotTopic {
    pub const fn as_str(self) -> &'static str {
        match self {
            RobotTopic::State => "state",
            RobotTopic::Dynamics => "dynamics",
            RobotTopic::Command => "command",
            RobotTopic::Torque => "torque",
            RobotTopic::Status => "status",
            RobotTopic::Description => "description",
            RobotTopic::Contacts => "contacts",
        }
    }
}

/// `team/{team}/robot/{robot}/{topic}`.
pub fn robot(team: &str, robot: &str, topic: RobotTopic) -> Result<String, ProtocolError> {
    validate_id("team", team)?;
    validate_id("robot", robot)?;
    Ok(format!("{ROOT}/{team}/robot/{robot}/{}", topic.as_str()))
}

/// `team/{team}/robot/*/{topic}`: every robot's topic.
pub fn all_robots(team: &str, topic: RobotTopic) -> Result<String, ProtocolError> {
    validate_id("team", team)?;
    Ok(format!("{ROOT}/{team}/robot/*/{}", topic.as_str()))
}

/// `team/{team}/**`: every key of the team (access-control rules).
pub fn everything(team: &str) -> Result<String, ProtocolError> {
    validate_id("team", team)?;
    Ok(format!("{ROOT}/{team}/**"))
}

/// `team/{team}/member/{robot}`: the liveliness token of a member.
pub fn member(team: &str, robot: &str) -> Result<String, ProtocolError> {
    validate_id("team", team)?;
    validate_id("robot", robot)?;
    Ok(format!("{ROOT}/{team}/member/{robot}"))
}

/// `team/{team}/member/*`: every member's liveliness token.
pub fn all_members(team: &str) -> Result<String, ProtocolError> {
    validate_id("team", team)?;
    Ok(format!("{ROOT}/{team}/member/*"))
}

/// `team/{team}/coordinator/status`.
pub fn coordinator_status(team: &str) -> Result<String, ProtocolError> {
    validate_id("team", team)?;
    Ok(format!("{ROOT}/{team}/coordinator/status"))
}

/// `team/{team}/coordinator/alive`: the coordinator's liveliness token (agents go to safe
/// mode and the bridge counts ticks from the moment it disappears).
pub fn coordinator_alive(team: &str) -> Result<String, ProtocolError> {
    validate_id("team", team)?;
    Ok(format!("{ROOT}/{team}/coordinator/alive"))
}

/// `team/{team}/coordinator/diagnostics`.
pub fn diagnostics(team: &str) -> Result<String, ProtocolError> {
    validate_id("team", team)?;
    Ok(format!("{ROOT}/{team}/coordinator/diagnostics"))
}

/// `team/{team}/references`.
pub fn references(team: &str) -> Result<String, ProtocolError> {
    validate_id("team", team)?;
    Ok(format!("{ROOT}/{team}/references"))
}

/// `team/{team}/perturbation`.
pub fn perturbation(team: &str) -> Result<String, ProtocolError> {
    validate_id("team", team)?;
    Ok(format!("{ROOT}/{team}/perturbation"))
}

/// `team/{team}/ground-truth`: the simulator's ground truth, for evaluation only.
pub fn ground_truth(team: &str) -> Result<String, ProtocolError> {
    validate_id("team", team)?;
    Ok(format!("{ROOT}/{team}/ground-truth"))
}

/// The robot id in a key of the form `team/{team}/robot/{robot}/...` or
/// `team/{team}/member/{robot}`, if the key has that form.
pub fn robot_of(key: &str) -> Option<&str> {
    let mut parts = key.split('/');
    if parts.next()? != ROOT {
        return None;
    }
    let _team = parts.next()?;
    match parts.next()? {
        "robot" | "member" => {
            let id = parts.next()?;
            validate_id("robot", id).ok().map(|_| id)
        }
        _ => None,
    }
}

/// The team id in a key of the form `team/{team}/...`, if the key has that form.
pub fn team_of(key: &str) -> Option<&str> {
    let mut parts = key.split('/');
    (parts.next()? == ROOT).then_some(())?;
    parts.next()
}

/// Refuse a message whose `header` names another sender than `key`: another team than the
/// key's, or, on a robot's key (`team/{team}/robot/{robot}/...`), another robot or none. With
/// the access-control list, which lets each certificate publish its own keys only
/// ([`crate::access`]), this binds the header to the identity that Zenoh authenticated.
pub fn check_sender(key: &str, header: &crate::Header) -> Result<(), ProtocolError> {
    let key_team = team_of(key);
    let key_robot = if key.split('/').nth(2) == Some("robot") { robot_of(key) } else { None };
    let team_ok = key_team == Some(header.team.as_str());
    let robot_ok = key_robot.is_none_or(|r| header.robot.as_deref() == Some(r));
    if team_ok && robot_ok {
        return Ok(());
    }
    let name = |team: Option<&str>, robot: Option<&str>| match robot {
        Some(r) => format!("robot {r} of team {}", team.unwrap_or("?")),
        None => format!("team {}", team.unwrap_or("?")),
    };
    Err(ProtocolError::WrongSender {
        key: key.to_string(),
        key_sender: name(key_team, key_robot),
        header_sender: name(Some(&header.team), header.robot.as_deref()),
    })
}

/// `team/{team}/robot/{robot}/contacts`: the robot's contact set ([`crate::ContactSet`]).
pub fn contacts(team: &str, robot_id: &str) -> Result<String, ProtocolError> {
    robot(team, robot_id, RobotTopic::Contacts)
}

/// The message type a key carries, from its shape (`None` for liveliness tokens and keys
/// outside the tree).
pub fn kind_of(key: &str) -> Option<crate::MessageKind> {
    use crate::MessageKind as K;
    let parts: Vec<&str> = key.split('/').collect();
    if parts.first() != Some(&ROOT) || parts.len() < 3 {
        return None;
    }
    match (parts[2], parts.len()) {
        ("robot", 5) => match parts[4] {
            "state" => Some(K::RobotState),
            "dynamics" => Some(K::DynamicsTerms),
            "command" => Some(K::TorqueCommand),
            "torque" => Some(K::DriveCommand),
            "status" => Some(K::AgentStatus),
            "description" => Some(K::RobotDescription),
            "contacts" => Some(K::ContactSet),
            _ => None,
        },
        ("coordinator", 4) => match parts[3] {
            "status" => Some(K::CoordinatorStatus),
            "diagnostics" => Some(K::TickDiagnostics),
            _ => None,
        },
        ("references", 3) => Some(K::TaskReferences),
        ("perturbation", 3) => Some(K::PerturbationRequest),
        ("ground-truth", 3) => Some(K::GroundTruth),
        _ => None,
    }
}

/// Whether `key` (wildcards allowed) names liveliness tokens rather than messages:
/// `team/{team}/member/{robot}` and `team/{team}/coordinator/alive`.
pub fn is_liveliness(key: &str) -> bool {
    let parts: Vec<&str> = key.split('/').collect();
    parts.len() == 4
        && parts[0] == ROOT
        && (parts[2] == "member" || (parts[2] == "coordinator" && parts[3] == "alive"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rule written out: a robot's key takes a header of that robot of that team only; a
    /// team's key a header of that team (any robot or none).
    #[test]
    fn a_header_must_name_the_sender_its_key_names() {
        use crate::Header;
        let h = |team: &str, robot: Option<&str>| Header::new(team, robot, 7, 0);
        let terms = robot("t1", "r1", RobotTopic::Dynamics).unwrap();
        assert!(check_sender(&terms, &h("t1", Some("r1"))).is_ok());
        for (header, says) in [
            (h("t1", Some("r2")), "robot r2 of team t1"),
            (h("t2", Some("r1")), "robot r1 of team t2"),
            (h("t1", None), "team t1"),
        ] {
            let e = check_sender(&terms, &header).expect_err("refused");
            let text = e.to_string();
            assert!(
                text.contains("robot r1 of team t1") && text.contains(says),
                "both names: {text}"
            );
        }
        let status = coordinator_status("t1").unwrap();
        assert!(check_sender(&status, &h("t1", None)).is_ok());
        assert!(
            check_sender(&status, &h("t2", None)).is_err(),
            "another team's status on this team's key"
        );
        assert!(
            check_sender(&member("t1", "r1").unwrap(), &h("t1", None)).is_ok(),
            "a member token is not a robot's message key"
        );
        assert!(
            check_sender("elsewhere/t1", &h("t1", None)).is_err(),
            "a key outside the tree names no sender"
        );
    }

    #[test]
    fn keys_have_the_documented_shape() {
        assert_eq!(robot("t1", "r2", RobotTopic::Dynamics).unwrap(), "team/t1/robot/r2/dynamics");
        assert_eq!(all_robots("t1", RobotTopic::State).unwrap(), "team/t1/robot/*/state");
        assert_eq!(member("t1", "r2").unwrap(), "team/t1/member/r2");
        assert_eq!(robot_of("team/t1/member/r2"), Some("r2"));
        assert_eq!(robot_of("team/t1/robot/r9/command"), Some("r9"));
        assert_eq!(robot_of("team/t1/coordinator/status"), None);
        assert_eq!(robot_of("other/t1/robot/r9/command"), None);
        use crate::MessageKind as K;
        assert_eq!(kind_of("team/t1/robot/r2/torque"), Some(K::DriveCommand));
        assert_eq!(kind_of(&coordinator_status("t1").unwrap()), Some(K::CoordinatorStatus));
        assert_eq!(kind_of(&diagnostics("t1").unwrap()), Some(K::TickDiagnostics));
        assert_eq!(kind_of(&ground_truth("t1").unwrap()), Some(K::GroundTruth));
        assert_eq!(kind_of(&contacts("t1", "r1").unwrap()), Some(K::ContactSet));
        assert_eq!(kind_of("team/t1/member/r2"), None);
        assert_eq!(kind_of(&coordinator_alive("t1").unwrap()), None);
        assert!(is_liveliness("team/t1/member/r2") && is_liveliness("team/t1/member/*"));
        assert!(is_liveliness(&coordinator_alive("t1").unwrap()));
        assert!(
            !is_liveliness(&coordinator_status("t1").unwrap())
                && !is_liveliness("team/t1/robot/r2/state")
        );
        assert_eq!(kind_of("team/t1/robot/r2/state/extra"), None);
    }

    #[test]
    fn ids_that_would_break_the_tree_are_rejected() {
        for bad in ["", "a/b", "*", "**", "a b", "r$1", &"x".repeat(65)] {
            assert!(robot("t", bad, RobotTopic::State).is_err(), "{bad:?} accepted");
            assert!(member(bad, "r").is_err(), "{bad:?} accepted as team");
        }
    }

    #[test]
    fn contacts_key() {
        assert_eq!(contacts("t1", "r2").unwrap(), "team/t1/robot/r2/contacts");
        assert!(contacts("t1", "a/b").is_err());
    }
}
