//! Gathering one tick: every team member's dynamics terms of the same tick, with a deadline,
//! and in real time, a member's latest terms reused when its own are late ([`TermsReuse`]).

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use protocol::DynamicsTerms;

/// Reusing late terms (real time): a tick whose terms are incomplete [`TermsReuse::after`] its
/// first
/// terms arrived is solved with each missing member's latest terms, if they are at most
/// [`TermsReuse::max_age`] ticks older than the tick; a member whose latest are older (or who has
/// none) is silent, and the tick goes on without it ([`crate::team::membership::Roster`]).
/// One late link then no longer delays every robot's command, and an agent that stopped
/// answering is noticed at the first tick it misses and left out after `max_age` ticks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TermsReuse {
    pub after: Duration,
    pub max_age: u64,
}

/// Dynamics terms collected per tick until every team member has sent its own.
#[derive(Debug)]
pub struct TickAssembler {
    /// Per tick: when its first terms came, and each member's terms (`None`: the member holds
    /// its posture this tick, [`TickAssembler::hold`]).
    pending: BTreeMap<u64, (Instant, BTreeMap<String, Option<DynamicsTerms>>)>,
    last_completed: Option<u64>,
    deadline: Duration,
    reuse: Option<TermsReuse>,
    /// Each robot's latest terms (any tick), kept for [`TermsReuse`].
    latest: BTreeMap<String, DynamicsTerms>,
    /// Each robot's newest tick added.
    newest: BTreeMap<String, u64>,
}

/// How many ticks a member's terms may be ahead of the newest terms of every other member
/// ([`TickAssembler::ahead_of_team`]): a second at 1 kHz. Members answer the same states, so
/// terms further ahead come from a broken clock or a forger, and would hold a tick open that
/// the others never reach.
pub const MAX_LEAD_TICKS: u64 = 1000;

/// What became of a tick.
#[derive(Debug, Clone, PartialEq)]
pub enum AssemblyStatus {
    /// Not complete yet.
    Pending,
    /// Every member's terms are here, sorted by robot id.
    Complete(u64, Vec<DynamicsTerms>),
    /// The terms belong to a tick already completed or abandoned.
    Stale(u64),
}

/// A tick completed by [`TickAssembler::reuse_due`].
#[derive(Debug, Clone, PartialEq)]
pub enum ReusedTerms {
    /// Complete with the listed members' latest terms (robot, tick of the terms reused).
    Complete { tick: u64, terms: Vec<DynamicsTerms>, reused: Vec<(String, u64)> },
    /// These members' latest terms are too old (or missing): they are silent. The caller
    /// leaves them out and completes the tick again ([`TickAssembler::try_complete`]).
    Silent { tick: u64, robots: Vec<String> },
}

impl TickAssembler {
    pub fn new(deadline: Duration) -> Self {
        TickAssembler {
            pending: BTreeMap::new(),
            last_completed: None,
            deadline,
            reuse: None,
            latest: BTreeMap::new(),
            newest: BTreeMap::new(),
        }
    }

    /// TermsReuse late terms ([`TermsReuse`]); `None` waits for every member's own (lockstep).
    pub fn with_reuse(mut self, reuse: Option<TermsReuse>) -> Self {
        self.reuse = reuse;
        self
    }

    pub fn last_completed(&self) -> Option<u64> {
        self.last_completed
    }

    /// The newest tick of the other members of `team` when `robot`'s terms of `tick` are more
    /// than [`MAX_LEAD_TICKS`] ahead of it (or of the last completed tick): such terms are
    /// refused. `None` when they are not, or when no other member has sent terms yet.
    pub fn ahead_of_team(&self, robot: &str, tick: u64, team: &[String]) -> Option<u64> {
        let others =
            team.iter().filter(|m| m.as_str() != robot).filter_map(|m| self.newest.get(m)).copied();
        let reference = others.chain(self.last_completed).max()?;
        (tick > reference.saturating_add(MAX_LEAD_TICKS)).then_some(reference)
    }

    /// Add one team member's terms; the tick completes when every member of `team` (sorted)
    /// has sent.
    pub fn add(&mut self, terms: DynamicsTerms, team: &[String]) -> AssemblyStatus {
        let tick = terms.header.tick;
        if self.reuse.is_some() {
            let robot = terms.header.robot_id();
            match self.latest.get_mut(robot) {
                Some(old) if old.header.tick < tick => old.clone_from(&terms),
                Some(_) => {}
                None => {
                    self.latest.insert(robot.to_string(), terms.clone());
                }
            }
        }
        let newest = self.newest.entry(terms.header.robot_id().to_string()).or_insert(tick);
        *newest = (*newest).max(tick);
        if self.last_completed.is_some_and(|t| tick <= t) {
            return AssemblyStatus::Stale(tick);
        }
        let robot = terms.header.robot_id().to_string();
        let entry = self.pending.entry(tick).or_insert_with(|| (Instant::now(), BTreeMap::new()));
        entry.1.insert(robot, Some(terms));
        self.try_complete(tick, team)
    }

    /// Team member `robot` holds its posture at `tick` (a hold order went out): the tick does
    /// not wait for its terms and is solved without it.
    pub fn hold(&mut self, robot: &str, tick: u64, team: &[String]) -> AssemblyStatus {
        if self.last_completed.is_some_and(|t| tick <= t) {
            return AssemblyStatus::Stale(tick);
        }
        let entry = self.pending.entry(tick).or_insert_with(|| (Instant::now(), BTreeMap::new()));
        entry.1.insert(robot.to_string(), None);
        self.try_complete(tick, team)
    }

    /// Re-check a tick after the team changed (a robot that left no longer holds it up).
    pub fn try_complete(&mut self, tick: u64, team: &[String]) -> AssemblyStatus {
        let Some((_, got)) = self.pending.get(&tick) else { return AssemblyStatus::Pending };
        if team.is_empty() || !team.iter().all(|m| got.contains_key(m)) {
            return AssemblyStatus::Pending;
        }
        let (_, got) = self.pending.remove(&tick).expect("present");
        self.complete(tick);
        AssemblyStatus::Complete(tick, solved(got, team))
    }

    /// The tick is done: older ones can never complete now.
    fn complete(&mut self, tick: u64) {
        self.pending.retain(|t, _| *t > tick);
        self.last_completed = Some(tick);
    }

    /// When the oldest pending tick is due for [`TermsReuse`] (none without reuse or pending
    /// ticks).
    pub fn reuse_at(&self) -> Option<Instant> {
        let reuse = self.reuse?;
        self.pending.values().map(|(since, _)| *since + reuse.after).min()
    }

    /// At `now`: the newest tick due for [`TermsReuse`] completed with the missing members' latest
    /// terms, or the members too silent for it. Older due ticks are dropped (overtaken).
    pub fn reuse_due(&mut self, now: Instant, team: &[String]) -> Option<ReusedTerms> {
        let reuse = self.reuse?;
        let tick =
            *self.pending.iter().rev().find(|(_, (since, _))| now >= *since + reuse.after)?.0;
        let got = &self.pending[&tick].1;
        let missing: Vec<&String> = team.iter().filter(|m| !got.contains_key(*m)).collect();
        let fresh = |r: &String| {
            self.latest
                .get(r)
                .filter(|t| t.header.tick < tick && tick - t.header.tick <= reuse.max_age)
        };
        let silent: Vec<String> =
            missing.iter().filter(|r| fresh(r).is_none()).map(|r| r.to_string()).collect();
        if !silent.is_empty() {
            return Some(ReusedTerms::Silent { tick, robots: silent });
        }
        let (_, mut got) = self.pending.remove(&tick).expect("present");
        let mut reused = Vec::with_capacity(missing.len());
        for r in missing {
            // The terms answer this tick; `state_tick` still says which state they came from.
            let mut t = fresh(r).expect("checked").clone();
            reused.push((r.clone(), t.header.tick));
            t.header.tick = tick;
            got.insert(r.clone(), Some(t));
        }
        self.complete(tick);
        Some(ReusedTerms::Complete { tick, terms: solved(got, team), reused })
    }

    /// Pending ticks, oldest first.
    pub fn pending_ticks(&self) -> Vec<u64> {
        self.pending.keys().copied().collect()
    }

    /// Drop ticks older than the deadline; returns the ticks missed and who was missing.
    pub fn expire(&mut self, team: &[String]) -> Vec<(u64, Vec<String>)> {
        let now = Instant::now();
        let mut missed = Vec::new();
        self.pending.retain(|tick, (since, got)| {
            if now.duration_since(*since) > self.deadline {
                let missing = team.iter().filter(|m| !got.contains_key(*m)).cloned().collect();
                missed.push((*tick, missing));
                false
            } else {
                true
            }
        });
        missed
    }
}

/// The terms of a complete tick that are solved: the team's, sorted by robot id, less those
/// holding their posture.
fn solved(got: BTreeMap<String, Option<DynamicsTerms>>, team: &[String]) -> Vec<DynamicsTerms> {
    got.into_iter().filter(|(r, _)| team.contains(r)).filter_map(|(_, t)| t).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Header, Matrix};

    fn terms(robot: &str, tick: u64) -> DynamicsTerms {
        DynamicsTerms {
            header: Header::new("t", Some(robot), tick, 0),
            floating_base: false,
            nv: 1,
            mass_matrix: Matrix::zeros(1, 1),
            bias: vec![0.0],
            velocity: vec![0.0],
            frames: Vec::new(),
            hand_in_grasp: false,
            state_tick: tick,
            team_delay_ticks: 0,
            object_pose: None,
        }
    }

    fn team(ids: &[&str]) -> Vec<String> {
        ids.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn a_tick_completes_when_every_member_sent_and_later_terms_are_stale() {
        let mut a = TickAssembler::new(Duration::from_secs(1));
        let t = team(&["r1", "r2"]);
        assert_eq!(a.add(terms("r2", 5), &t), AssemblyStatus::Pending);
        match a.add(terms("r1", 5), &t) {
            AssemblyStatus::Complete(5, got) => assert_eq!(
                got.iter().map(|x| x.header.robot_id()).collect::<Vec<_>>(),
                ["r1", "r2"]
            ),
            other => panic!("{other:?}"),
        }
        assert_eq!(a.add(terms("r1", 5), &t), AssemblyStatus::Stale(5));
        assert_eq!(a.add(terms("r1", 4), &t), AssemblyStatus::Stale(4));
        assert_eq!(a.reuse_at(), None, "no reuse unless asked");
    }

    /// Terms more than `MAX_LEAD_TICKS` (1000) ahead of every other member's newest are named;
    /// at the bound, or with no other member heard yet, they are not.
    #[test]
    fn terms_far_ahead_of_the_team_are_named() {
        let mut a = TickAssembler::new(Duration::from_secs(1));
        let t = team(&["r1", "r2"]);
        assert_eq!(a.ahead_of_team("r2", 1_000_000, &t), None, "nobody else heard yet");
        a.add(terms("r1", 40), &t);
        assert_eq!(a.ahead_of_team("r2", 1040, &t), None, "1000 ahead: within the lead");
        assert_eq!(a.ahead_of_team("r2", 1041, &t), Some(40));
        assert_eq!(a.ahead_of_team("r1", 5000, &t), None, "r1 is not compared with itself");
        a.add(terms("r2", 40), &t);
        assert_eq!(
            a.ahead_of_team("r1", 5000, &t),
            Some(40),
            "once the tick completed, nor with the last completed tick"
        );
    }

    #[test]
    fn late_terms_are_reused_within_their_age_and_older_ones_silence_the_member() {
        let reuse = TermsReuse { after: Duration::from_millis(2), max_age: 3 };
        let mut a = TickAssembler::new(Duration::from_secs(1)).with_reuse(Some(reuse));
        let t = team(&["r1", "r2"]);
        for k in 10..=11 {
            a.add(terms("r1", k), &t);
            assert!(matches!(a.add(terms("r2", k), &t), AssemblyStatus::Complete(..)));
        }
        // r2's terms of 12 and 13 are late: r1's alone are pending.
        assert_eq!(a.add(terms("r1", 12), &t), AssemblyStatus::Pending);
        assert_eq!(a.add(terms("r1", 13), &t), AssemblyStatus::Pending);
        let due = a.reuse_at().expect("a due time");
        assert_eq!(a.reuse_due(due - Duration::from_millis(1), &t), None, "not before it is due");
        let later = Instant::now() + Duration::from_millis(5);
        match a.reuse_due(later, &t) {
            Some(ReusedTerms::Complete { tick: 13, terms, reused }) => {
                assert_eq!(reused, vec![("r2".to_string(), 11)], "r2's latest, of tick 11");
                assert_eq!(terms.len(), 2);
                assert_eq!(
                    (terms[1].header.tick, terms[1].state_tick),
                    (13, 11),
                    "answering 13 from the state of 11"
                );
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(a.pending_ticks(), Vec::<u64>::new(), "tick 12 was overtaken");
        assert_eq!(a.add(terms("r2", 12), &t), AssemblyStatus::Stale(12));
        // r2 stays silent: at tick 16 its latest (12) is 4 ticks old.
        a.add(terms("r1", 16), &t);
        match a.reuse_due(Instant::now() + Duration::from_millis(5), &t) {
            Some(ReusedTerms::Silent { tick: 16, robots }) => {
                assert_eq!(robots, vec!["r2".to_string()])
            }
            other => panic!("{other:?}"),
        }
        // Without r2 the tick completes.
        assert!(
            matches!(a.try_complete(16, &team(&["r1"])), AssemblyStatus::Complete(16, got) if got.len() == 1)
        );
    }

    #[test]
    fn a_member_holding_its_posture_does_not_hold_up_the_tick() {
        let mut a = TickAssembler::new(Duration::from_secs(1));
        let t = team(&["r1", "r2", "r3"]);
        a.add(terms("r1", 7), &t);
        assert_eq!(a.hold("r3", 7, &t), AssemblyStatus::Pending);
        match a.add(terms("r2", 7), &t) {
            AssemblyStatus::Complete(7, got) => assert_eq!(
                got.iter().map(|x| x.header.robot_id()).collect::<Vec<_>>(),
                ["r1", "r2"],
                "r3 holds"
            ),
            other => panic!("{other:?}"),
        }
        assert_eq!(a.hold("r3", 7, &t), AssemblyStatus::Stale(7));
    }

    #[test]
    fn a_member_never_heard_of_is_silent_not_reused() {
        let mut a = TickAssembler::new(Duration::from_secs(1))
            .with_reuse(Some(TermsReuse { after: Duration::ZERO, max_age: 3 }));
        let t = team(&["r1", "r2"]);
        a.add(terms("r1", 1), &t);
        assert!(
            matches!(a.reuse_due(Instant::now(), &t), Some(ReusedTerms::Silent { robots, .. }) if robots == ["r2"])
        );
    }
}
