//! Who is in the team: liveliness tokens seen join and leave ([`Membership`]), and of those
//! members, whom the coordinator commands tick by tick ([`Roster`]).

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

use protocol::transport::MemberEvent;

/// How long a member of a running team whose liveliness token vanished stays in the team,
/// waiting for the token to come back ([`Roster::apply`]). A link that drops and reconnects
/// (Zenoh reopens it within milliseconds) withdraws and redeclares every token across it; a
/// robot that truly leaves announces it ([`Roster::leave`]: a fallen or stopping agent deletes
/// its dynamics key first) or goes silent ([`Roster::silence`]), and is out at once.
pub const DEPARTURE_GRACE: Duration = Duration::from_millis(100);

/// In real time, a departing member whose terms stopped too (the coordinator reused them) has
/// left once they are this many ticks old ([`Roster::reused`]): an agent that died is noticed
/// within 3 ticks, not at the end of [`DEPARTURE_GRACE`]; a link that comes back sooner keeps
/// its robot in the team.
pub const DEPARTURE_TICKS: u64 = 3;

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
                    tracing::info!(
                        robot = %r,
                        members = self.members.len(),
                        "robot joined the team"
                    );
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

    /// The members as a set of ids.
    fn set(&self) -> &BTreeSet<String> {
        &self.members
    }
}

/// What the coordinator does with a member's terms of one tick ([`Roster::admit`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Admission {
    /// The robot is in the team: its terms go to the tick.
    Team,
    /// The robot is not a member (no liveliness token yet, or any more): it holds its posture
    /// this tick rather than wait for a command.
    NotAMember,
    /// The robot holds its posture this tick (a hold order), for the reason given.
    Hold(String),
    /// Terms of a silent robot for a tick already solved (a backlog it sends as it comes
    /// back): dropped; only fresh terms bring it back.
    Stale,
}

/// Whom the coordinator commands: the [`Membership`] (liveliness), less the members left out.
///
/// * **Start.** Until the team's first tick is solved, every member is in, and the controller
///   waits until it can command all of them (their descriptions): a team forms whole. With
///   [`Roster::expect`] it also waits (every member holding its posture) until the robots it
///   expects have all joined, for a bounded time: a coordinator restarted mid-run meets its
///   agents one by one as they reconnect, and a team formed with some of them would take the
///   others for late joiners (or let go of a grasp left with one hand).
/// * **Silent members.** A member whose terms stopped for longer than the coordinator reuses
///   them ([`crate::team::assembly::TermsReuse`]) is left out ([`Roster::silence`]): the others are
///   solved without it, as if it had left, though its liveliness token holds.
/// * **Late members.** A robot that joins a running team (a restarted agent), or a silent one
///   whose terms come again, is *late*: it is in the team from its first terms, with its hand
///   out of the grasp: it stands beside the team and does not take the object (taking a grasp
///   again is not built). It is commanded at once: its drives held it meanwhile, and an agent
///   in safe mode blends into the commands itself (`robot_agent::safe_mode::Takeover`). (A
///   hold order first was tried: a restarted agent's own posture hold, without the weight its
///   legs carry, let the torso sag 3 cm before the commands took over, which then swung it
///   4 cm; commanded at once it stays within 2 mm.)
/// * **Departures.** A team member whose liveliness token vanishes stays in the team for
///   [`DEPARTURE_GRACE`] (its ticks wait for its terms, as in lockstep they always do): a
///   link that drops and reconnects withdraws and redeclares the token within milliseconds,
///   and the grasp it holds must not be let go of for that. Its token back within the grace,
///   nothing changed; past it ([`Roster::depart_due`]), it has left. In real time it has also
///   left once its terms, reused meanwhile, are [`DEPARTURE_TICKS`] old ([`Roster::reused`]).
///   A robot that announces its leaving ([`Roster::leave`]) is out at once.
/// * A member the controller cannot command yet (no description) holds its posture.
#[derive(Debug, Clone, Default)]
pub struct Roster {
    members: Membership,
    /// Team members whose token vanished, and until when they are waited for.
    departing: BTreeMap<String, Instant>,
    silent: BTreeSet<String>,
    /// Late members, and of them those admitted (their terms came).
    late: BTreeSet<String>,
    admitted: BTreeSet<String>,
    started: bool,
    team: Vec<String>,
    /// The robots to wait for before the first tick, and until when.
    expected: Vec<String>,
    forming_until: Option<std::time::Instant>,
}

impl Roster {
    /// Wait, before the first tick, until every robot of `expected` has joined, or until
    /// `until`.
    pub fn expect(&mut self, expected: &[String], until: std::time::Instant) {
        self.expected = expected.to_vec();
        self.forming_until = Some(until);
    }

    /// Expected robots that have not joined yet while the team is still forming at `now`
    /// (empty: formed, or no longer waited for).
    pub fn forming(&self, now: std::time::Instant) -> Vec<&str> {
        if self.started || self.forming_until.is_none_or(|t| now >= t) {
            return Vec::new();
        }
        self.expected.iter().filter(|r| !self.members.contains(r)).map(String::as_str).collect()
    }

    /// A liveliness event at `now`; returns whether the team changed. A team member's leaving
    /// is only a departure until [`DEPARTURE_GRACE`] has passed (see [`Roster::depart_due`]).
    pub fn apply(&mut self, event: &MemberEvent, now: Instant) -> bool {
        match event {
            MemberEvent::Left(r) if self.departing.contains_key(r) => return false,
            MemberEvent::Left(r) if self.started && self.in_team(r) => {
                tracing::warn!(
                    robot = %r,
                    grace_ms = DEPARTURE_GRACE.as_millis() as u64,
                    "a member's token vanished: it stays in the team while its link may come back"
                );
                self.departing.insert(r.clone(), now + DEPARTURE_GRACE);
                return false;
            }
            MemberEvent::Joined(r) if self.departing.remove(r).is_some() => {
                tracing::info!(
                    robot = %r,
                    "a departing member's token is back: it never left the team"
                );
                return false;
            }
            _ => {}
        }
        self.depart(event)
    }

    /// When the next departure is due ([`Roster::depart_due`]), if one is pending.
    pub fn next_departure(&self) -> Option<Instant> {
        self.departing.values().min().copied()
    }

    /// The departures due at `now`: those members have left. Returns them.
    pub fn depart_due(&mut self, now: Instant) -> Vec<String> {
        let due: Vec<String> =
            self.departing.iter().filter(|(_, at)| **at <= now).map(|(r, _)| r.clone()).collect();
        for r in &due {
            self.departing.remove(r);
            tracing::warn!(robot = %r, "a departing member's token did not come back");
            self.depart(&MemberEvent::Left(r.clone()));
        }
        due
    }

    /// `robot` announced that it leaves (a fallen or stopping agent): out of the team at once,
    /// without a grace. Returns whether the team changed. A departing robot (its token gone
    /// already) has left; one whose token still holds is left out as if silent until the token
    /// goes (its withdrawal may arrive after a new agent's token under the same name: the new
    /// agent's first terms then bring it back, late, rather than never).
    pub fn leave(&mut self, robot: &str) -> bool {
        if self.departing.remove(robot).is_some() {
            return self.depart(&MemberEvent::Left(robot.to_string()));
        }
        if !self.members.contains(robot) || !self.silent.insert(robot.to_string()) {
            return false;
        }
        tracing::warn!(robot, "the robot says it leaves: solving without it");
        self.recompute()
    }

    /// `robot`'s terms were reused for a tick, `age` ticks old (real time): a departing member
    /// whose terms are [`DEPARTURE_TICKS`] old has left. Returns whether it left now.
    pub fn reused(&mut self, robot: &str, age: u64) -> bool {
        if age < DEPARTURE_TICKS || !self.departing.contains_key(robot) {
            return false;
        }
        tracing::warn!(robot, age, "a departing member's terms stopped too: it has left");
        self.leave(robot);
        true
    }

    /// Whether `robot`'s token vanished and it is waited for.
    pub fn is_departing(&self, robot: &str) -> bool {
        self.departing.contains_key(robot)
    }

    /// Apply `event` to the membership and the lists that follow from it.
    fn depart(&mut self, event: &MemberEvent) -> bool {
        if !self.members.apply(event) {
            return false;
        }
        match event {
            MemberEvent::Joined(r) if self.started => {
                tracing::info!(
                    robot = %r,
                    "robot joined a running team: it stands beside it, hand out of the grasp"
                );
                self.late.insert(r.clone());
                self.admitted.remove(r);
            }
            MemberEvent::Left(r) => {
                self.silent.remove(r);
            }
            _ => {}
        }
        self.recompute()
    }

    /// What to do with robot `robot`'s terms this tick; `ready` says whether the controller
    /// can command it, `fresh` whether the terms are for a tick not yet solved. Admitting a
    /// late robot changes the team (see [`Roster::team`]).
    pub fn admit(&mut self, robot: &str, ready: bool, fresh: bool) -> Admission {
        if !self.members.contains(robot) {
            return Admission::NotAMember;
        }
        if self.silent.contains(robot) && !fresh {
            return Admission::Stale;
        }
        if self.silent.remove(robot) {
            tracing::warn!(
                robot,
                "a silent robot sends again: it comes back beside the team, hand out of the grasp"
            );
            self.late.insert(robot.to_string());
            self.admitted.remove(robot);
        }
        if self.started && !ready {
            return Admission::Hold(format!(
                "robot {robot} cannot be commanded yet (no description)"
            ));
        }
        if self.late.contains(robot) && self.admitted.insert(robot.to_string()) {
            tracing::info!(robot, "late robot admitted into the team, hand out of the grasp");
            self.recompute();
        }
        Admission::Team
    }

    /// Leave `robot` out of the team: alive, but silent. Returns whether the team changed.
    pub fn silence(&mut self, robot: &str) -> bool {
        if !self.members.contains(robot) || !self.silent.insert(robot.to_string()) {
            return false;
        }
        tracing::warn!(robot, "robot silent: solving without it until it sends again");
        self.recompute()
    }

    /// The team's first tick was solved: from now on joins are late.
    pub fn start(&mut self) {
        self.started = true;
    }

    pub fn started(&self) -> bool {
        self.started
    }

    /// The team, sorted: members neither silent nor late and still to be admitted.
    pub fn team(&self) -> &[String] {
        &self.team
    }

    pub fn in_team(&self, robot: &str) -> bool {
        self.team.binary_search_by(|r| r.as_str().cmp(robot)).is_ok()
    }

    /// Whether `robot` is late (its hand stays out of the grasp).
    pub fn is_late(&self, robot: &str) -> bool {
        self.late.contains(robot)
    }

    pub fn members(&self) -> &Membership {
        &self.members
    }

    pub fn silent(&self) -> Vec<String> {
        self.silent.iter().cloned().collect()
    }

    /// Late members still present, sorted.
    pub fn late(&self) -> Vec<String> {
        self.late.iter().filter(|r| self.members.contains(r)).cloned().collect()
    }

    fn recompute(&mut self) -> bool {
        let team: Vec<String> = self
            .members
            .set()
            .iter()
            .filter(|r| {
                !self.silent.contains(*r) && (!self.late.contains(*r) || self.admitted.contains(*r))
            })
            .cloned()
            .collect();
        let changed = team != self.team;
        self.team = team;
        changed
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

    fn now() -> Instant {
        Instant::now()
    }

    /// A roster whose team of `ids` joined at `t0` and has solved its first tick.
    fn started(ids: &[&str], t0: Instant) -> Roster {
        let mut r = Roster::default();
        for id in ids {
            r.apply(&joined(id), t0);
        }
        r.start();
        r
    }

    fn joined(r: &str) -> MemberEvent {
        MemberEvent::Joined(r.into())
    }

    #[test]
    fn a_team_forms_whole_then_late_robots_are_admitted_beside_it() {
        let mut r = Roster::default();
        assert!(r.apply(&joined("r2"), now()));
        assert!(r.apply(&joined("r1"), now()));
        assert_eq!(r.team(), ["r1", "r2"]);
        // Before the start a robot without a description is in the team: the controller
        // itself waits for the whole team.
        assert_eq!(r.admit("r1", false, true), Admission::Team);
        assert_eq!(r.admit("r9", true, true), Admission::NotAMember);
        r.start();
        assert!(
            matches!(r.admit("r2", false, true), Admission::Hold(why) if why.contains("description"))
        );
        // r3 joins the running team: in from its first terms, late.
        assert!(!r.apply(&joined("r3"), now()), "not in the team before its first terms");
        assert!(!r.in_team("r3"));
        assert_eq!(r.admit("r3", true, true), Admission::Team);
        assert!(r.in_team("r3") && r.is_late("r3"));
        assert_eq!(r.admit("r3", true, true), Admission::Team);
        assert_eq!(r.late(), vec!["r3"]);
        assert!(!r.is_late("r1"));
    }

    #[test]
    fn a_team_expected_whole_forms_whole_or_at_its_deadline() {
        let t0 = std::time::Instant::now();
        let mut r = Roster::default();
        r.expect(&["r1".to_string(), "r2".to_string()], t0 + std::time::Duration::from_secs(1));
        assert_eq!(r.forming(t0), vec!["r1", "r2"]);
        r.apply(&joined("r1"), now());
        assert_eq!(r.forming(t0), vec!["r2"]);
        assert!(
            r.forming(t0 + std::time::Duration::from_secs(2)).is_empty(),
            "not waited for past the deadline"
        );
        r.apply(&joined("r2"), now());
        assert!(r.forming(t0).is_empty());
        r.apply(&MemberEvent::Left("r2".into()), now());
        r.start();
        assert!(r.forming(t0).is_empty(), "once started it never waits again");
    }

    #[test]
    fn a_silent_member_is_left_out_and_comes_back_late() {
        let mut r = started(&["r1", "r2", "r3"], now());
        assert!(r.silence("r3"));
        assert!(!r.silence("r3"), "once");
        assert!(!r.silence("r7"), "not a member");
        assert_eq!(r.team(), ["r1", "r2"]);
        assert_eq!(r.silent(), vec!["r3"]);
        // Its backlog does not bring it back, fresh terms do: in the team, hand out of the grasp.
        assert_eq!(r.admit("r3", true, false), Admission::Stale);
        assert_eq!(r.silent(), vec!["r3"]);
        assert_eq!(r.admit("r3", true, true), Admission::Team);
        assert!(r.silent().is_empty());
        assert_eq!(r.team(), ["r1", "r2", "r3"]);
        assert!(r.is_late("r3"));
        // Leaving (its token gone past the grace) takes it out of every list.
        let t0 = Instant::now();
        r.apply(&MemberEvent::Left("r3".into()), t0);
        assert_eq!(r.depart_due(t0 + DEPARTURE_GRACE), vec!["r3"]);
        assert_eq!(r.team(), ["r1", "r2"]);
        assert!(r.late().is_empty());
    }

    fn left(r: &str) -> MemberEvent {
        MemberEvent::Left(r.into())
    }

    #[test]
    fn a_member_whose_token_comes_back_within_the_grace_never_left() {
        let t0 = Instant::now();
        let mut r = started(&["r1", "r2"], t0);
        // A link drops and reconnects: the token goes and comes back within the grace.
        assert!(!r.apply(&left("r1"), t0), "a departure does not change the team");
        assert!(r.is_departing("r1") && r.in_team("r1"));
        assert!(!r.apply(&left("r1"), t0), "a second withdrawal changes nothing either");
        assert_eq!(r.next_departure(), Some(t0 + DEPARTURE_GRACE));
        assert!(r.depart_due(t0 + DEPARTURE_GRACE / 2).is_empty());
        assert!(!r.apply(&joined("r1"), t0 + DEPARTURE_GRACE / 2), "back: the team is unchanged");
        assert!(!r.is_departing("r1") && !r.is_late("r1"), "not late: its hand stays in the grasp");
        assert_eq!(r.team(), ["r1", "r2"]);
        assert_eq!(r.next_departure(), None);
        assert_eq!(r.admit("r1", true, true), Admission::Team);
    }

    #[test]
    fn a_member_whose_token_stays_away_past_the_grace_has_left_and_comes_back_late() {
        let t0 = Instant::now();
        let mut r = started(&["r1", "r2"], t0);
        r.apply(&left("r2"), t0);
        assert!(r.depart_due(t0 + DEPARTURE_GRACE - Duration::from_millis(1)).is_empty());
        assert_eq!(r.depart_due(t0 + DEPARTURE_GRACE), vec!["r2"]);
        assert_eq!(r.team(), ["r1"]);
        assert!(!r.members().contains("r2") && !r.is_departing("r2"));
        assert_eq!(r.admit("r2", true, true), Admission::NotAMember);
        // Its token back after that: a late joiner, hand out of the grasp.
        r.apply(&joined("r2"), t0 + DEPARTURE_GRACE * 2);
        assert_eq!(r.admit("r2", true, true), Admission::Team);
        assert!(r.is_late("r2"));
    }

    #[test]
    fn a_departing_member_whose_terms_stop_too_leaves_within_departure_ticks() {
        let t0 = Instant::now();
        let mut r = started(&["r1", "r2", "r3"], t0);
        assert!(
            !r.reused("r3", DEPARTURE_TICKS + 5),
            "a member with its token (a slow link) is reused, not left out"
        );
        r.apply(&left("r3"), t0);
        assert!(!r.reused("r3", DEPARTURE_TICKS - 1), "younger terms: still waited for");
        assert!(r.in_team("r3"));
        assert!(r.reused("r3", DEPARTURE_TICKS), "its terms stopped with its token: it has left");
        assert_eq!(r.team(), ["r1", "r2"]);
        assert!(!r.is_departing("r3") && !r.members().contains("r3"));
        assert!(r.depart_due(t0 + DEPARTURE_GRACE).is_empty(), "its grace is over with it");
    }

    #[test]
    fn an_announced_leave_a_silent_member_and_a_team_not_started_leave_at_once() {
        let t0 = Instant::now();
        let mut r = Roster::default();
        for id in ["r1", "r2", "r3", "r4"] {
            r.apply(&joined(id), t0);
        }
        assert!(r.apply(&left("r4"), t0), "before the first tick a token's loss is a leave");
        r.start();
        assert!(r.leave("r1"), "announced: out at once");
        assert!(!r.leave("r1"), "once");
        assert!(
            !r.in_team("r1") && r.members().contains("r1"),
            "out of the team; its token still holds"
        );
        r.apply(&left("r2"), t0);
        assert!(r.leave("r2"), "announced while departing: out at once");
        assert!(!r.is_departing("r2") && !r.members().contains("r2"));
        assert!(r.silence("r3"));
        assert!(!r.apply(&left("r3"), t0), "a silent member is out of the team already");
        assert!(
            !r.members().contains("r3") && !r.is_departing("r3"),
            "and it is no member any more"
        );
        assert!(r.team().is_empty());
        // r1's token goes after its announcement: no member any more, no grace.
        assert!(!r.apply(&left("r1"), t0));
        assert!(!r.members().contains("r1") && !r.is_departing("r1"));
        assert!(!r.leave("r9"), "not a member");
    }

    #[test]
    fn an_announcement_that_arrives_after_a_new_agents_token_does_not_shut_it_out() {
        // A stopping agent's deletion is handled after its token went and a new agent's came.
        let t0 = Instant::now();
        let mut r = started(&["r1", "r2"], t0);
        r.apply(&left("r2"), t0);
        r.apply(&joined("r2"), t0);
        assert!(r.leave("r2"));
        assert!(!r.in_team("r2"));
        // The new agent's first terms bring it back: late, its hand out of the grasp.
        assert_eq!(r.admit("r2", true, true), Admission::Team);
        assert!(r.in_team("r2") && r.is_late("r2"));
    }
}
