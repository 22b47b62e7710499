//! Who is in the team: liveliness tokens seen join and leave.

use std::collections::BTreeSet;

use protocol::transport::MemberEvent;

/// The present members, sorted by robot id.
#[derive(Debug, Clone, Default)]
pub struct Membership {
    members: BTreeSet<String>,
}

impl Membership {
    /// Apply a join or a leave; returns whether membership changed. Logs the change.
    pub fn apply(&mut self, event: &MemberEvent) -> bool {
        match event {
            MemberEvent::Joined(r) => {
                let changed = self.members.insert(r.clone());
                if changed {
                    tracing::info!(robot = %r, members = self.members.len(), "robot joined the team");
                }
                changed
            }
            MemberEvent::Left(r) => {
                let changed = self.members.remove(r);
                if changed {
                    tracing::warn!(robot = %r, members = self.members.len(), "robot left the team");
                }
                changed
            }
        }
    }

    pub fn contains(&self, robot: &str) -> bool {
        self.members.contains(robot)
    }

    pub fn len(&self) -> usize {
        self.members.len()
    }

    pub fn is_empty(&self) -> bool {
        self.members.is_empty()
    }

    pub fn ids(&self) -> impl Iterator<Item = &String> {
        self.members.iter()
    }

    pub fn to_vec(&self) -> Vec<String> {
        self.members.iter().cloned().collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joins_and_leaves_change_membership_once() {
        let mut m = Membership::default();
        assert!(m.apply(&MemberEvent::Joined("r2".into())));
        assert!(m.apply(&MemberEvent::Joined("r1".into())));
        assert!(!m.apply(&MemberEvent::Joined("r1".into())));
        assert_eq!(m.to_vec(), vec!["r1", "r2"]);
        assert!(m.apply(&MemberEvent::Left("r1".into())));
        assert!(!m.apply(&MemberEvent::Left("r1".into())));
        assert_eq!(m.to_vec(), vec!["r2"]);
    }
}
