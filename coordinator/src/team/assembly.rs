//! Gathering one tick: every member's dynamics terms of the same tick, with a deadline.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use protocol::DynamicsTerms;

use crate::team::membership::Membership;

/// Dynamics terms collected per tick until every member has sent its own.
#[derive(Debug)]
pub struct TickAssembler {
    pending: BTreeMap<u64, (Instant, BTreeMap<String, DynamicsTerms>)>,
    last_completed: Option<u64>,
    deadline: Duration,
}

/// What became of a tick.
#[derive(Debug, Clone, PartialEq)]
pub enum TickOutcome {
    /// Not complete yet.
    Pending,
    /// Every member's terms are here, sorted by robot id.
    Complete(u64, Vec<DynamicsTerms>),
    /// The terms belong to a tick already completed or abandoned.
    Stale(u64),
    /// A robot that is not a member (no liveliness token yet, or any more) sent the terms of
    /// a tick: (robot, tick).
    NotAMember(String, u64),
}

impl TickAssembler {
    pub fn new(deadline: Duration) -> Self {
        TickAssembler { pending: BTreeMap::new(), last_completed: None, deadline }
    }

    pub fn last_completed(&self) -> Option<u64> {
        self.last_completed
    }

    /// Add one robot's terms; the tick completes when every present member has sent.
    pub fn add(&mut self, terms: DynamicsTerms, members: &Membership) -> TickOutcome {
        let robot = terms.header.robot_id().to_string();
        if !members.contains(&robot) {
            return TickOutcome::NotAMember(robot, terms.header.tick);
        }
        let tick = terms.header.tick;
        if self.last_completed.is_some_and(|t| tick <= t) {
            return TickOutcome::Stale(tick);
        }
        let entry = self.pending.entry(tick).or_insert_with(|| (Instant::now(), BTreeMap::new()));
        entry.1.insert(robot, terms);
        self.try_complete(tick, members)
    }

    /// Re-check a tick after membership changed (a robot that left no longer holds it up).
    pub fn try_complete(&mut self, tick: u64, members: &Membership) -> TickOutcome {
        let Some((_, got)) = self.pending.get(&tick) else { return TickOutcome::Pending };
        if members.is_empty() || !members.ids().all(|m| got.contains_key(m)) {
            return TickOutcome::Pending;
        }
        let (_, got) = self.pending.remove(&tick).expect("present");
        // Older ticks can never complete now.
        self.pending.retain(|t, _| *t > tick);
        self.last_completed = Some(tick);
        TickOutcome::Complete(tick, got.into_iter().filter(|(r, _)| members.contains(r)).map(|(_, t)| t).collect())
    }

    /// Pending ticks, oldest first.
    pub fn pending_ticks(&self) -> Vec<u64> {
        self.pending.keys().copied().collect()
    }

    /// Drop ticks older than the deadline; returns the ticks missed and who was missing.
    pub fn expire(&mut self, members: &Membership) -> Vec<(u64, Vec<String>)> {
        let now = Instant::now();
        let mut missed = Vec::new();
        self.pending.retain(|tick, (since, got)| {
            if now.duration_since(*since) > self.deadline {
                let missing = members.ids().filter(|m| !got.contains_key(*m)).cloned().collect();
                missed.push((*tick, missing));
                false
            } else {
                true
            }
        });
        missed
    }
}
