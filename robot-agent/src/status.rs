//! The agent's status ([`protocol::AgentStatus`] on `team/{team}/robot/{id}/status`):
//! mode, counters, last tick, latencies. Published periodically and on every mode change.

use protocol::{AgentMode, AgentStatus, Header};

/// What an agent did, for its status, its logs and tests.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct AgentCounters {
    /// Valid states received (repeats of a tick included).
    pub states: u64,
    /// States refused: undecodable, another robot's, out of order, wrong size.
    pub states_rejected: u64,
    pub dynamics: u64,
    /// Commands applied (handed to the torque sink).
    pub applied: u64,
    /// Commands refused by the checks (undecodable ones included).
    pub rejected: u64,
    /// Commands that came before the state of their tick and waited for it.
    pub early: u64,
    /// Applied commands of which at least one torque was clamped to its limit.
    pub clamped: u64,
    pub safe_mode_entries: u64,
    /// Posture-hold torques handed to the torque sink.
    pub hold_torques: u64,
    /// Commands applied blended with the hold (a takeover, see `safe_mode::Takeover`).
    pub blended: u64,
    /// Contact sets accepted into the schedule / refused (unknown feet, another robot's,
    /// undecodable, schedule full).
    pub contacts_applied: u64,
    pub contacts_rejected: u64,
    /// Feet lifted off and landed (touchdown confirmed), and states at which a scheduled
    /// lift-off was deferred (the foot still loaded, or too few feet would have stayed down).
    pub liftoffs: u64,
    pub touchdowns: u64,
    pub liftoffs_deferred: u64,
    /// Descriptions published.
    pub descriptions: u64,
}

/// The status message, kept up to date and reused.
pub struct StatusBoard {
    pub status: AgentStatus,
}

impl StatusBoard {
    pub fn new(team: &str, robot: &str) -> Self {
        StatusBoard {
            status: AgentStatus {
                header: Header::new(team, Some(robot), 0, 0),
                mode: AgentMode::WaitingForState,
                states_received: 0,
                dynamics_published: 0,
                commands_applied: 0,
                commands_rejected: 0,
                commands_clamped: 0,
                safe_mode_entries: 0,
                last_applied_tick: None,
                dynamics_latency_us: 0.0,
                command_latency_us: 0.0,
                last_rejection: None,
                team_delay_ticks: 0,
            },
        }
    }

    /// The team's delay the agent starts with (`crate::delay`).
    pub fn with_team_delay(mut self, ticks: u64) -> Self {
        self.status.team_delay_ticks = ticks;
        self
    }

    /// Copy the counters and the latest tick into the message (the sender stamps it).
    pub fn refresh(
        &mut self,
        c: &AgentCounters,
        latest_tick: Option<u64>,
        last_applied: Option<u64>,
    ) -> &mut AgentStatus {
        let s = &mut self.status;
        s.header.tick = latest_tick.unwrap_or(0);
        s.states_received = c.states;
        s.dynamics_published = c.dynamics;
        s.commands_applied = c.applied;
        s.commands_rejected = c.rejected;
        s.commands_clamped = c.clamped;
        s.safe_mode_entries = c.safe_mode_entries;
        s.last_applied_tick = last_applied;
        &mut self.status
    }
}
