//! The records of a run: what the driver heard during the scenario's ticks (ground truth,
//! applied torques, the coordinator's diagnostics and statuses, the agents' statuses), which
//! every evaluation reads.

use std::collections::BTreeMap;
use std::time::Duration;

use protocol::{AgentStatus, CoordinatorStatus, DriveCommand, GroundTruth, TickDiagnostics};

/// What a run recorded (scenario ticks only; settling is not evaluated).
#[derive(Debug, Clone, Default)]
pub struct Records {
    pub truth: Vec<GroundTruth>,
    /// Applied torques per robot: (tick, torques in actuated-joint order; a drive command's
    /// `tau_ff`).
    pub torques: BTreeMap<String, Vec<(u64, Vec<f64>)>>,
    /// Per robot, how many of those drive commands carried gains (`drive_gains`).
    pub with_gains: BTreeMap<String, u64>,
    pub diagnostics: Vec<TickDiagnostics>,
    pub last_status: Option<CoordinatorStatus>,
    /// Every coordinator status heard (it goes out on every change of mode, members, stale,
    /// silent or late robots, and periodically).
    pub statuses: Vec<CoordinatorStatus>,
    /// The status tick at which the coordinator first reported the team let go of the object.
    pub released_at: Option<u64>,
    /// Wall time of the settling and of the scenario proper.
    pub settle_wall: Duration,
    pub run_wall: Duration,
    /// The machine's processors over the scenario proper (`None` where they cannot be read).
    pub machine: Option<crate::machine::MachineLoad>,
    /// Ticks seen (ground truth), settling included.
    pub ticks_seen: u64,
    /// The bridge's wall-clock stamp of the last settling tick's ground truth: the hand-over
    /// to the scenario is measured from it to the first scenario tick's.
    pub settle_end_stamp_ns: Option<u64>,
    /// Per robot, the most safe-mode entries its agent's statuses reported (robots whose agent
    /// was not heard are absent).
    pub agent_safe_mode: BTreeMap<String, u64>,
    /// Per robot, the longest team delay its agent's statuses reported, state ticks (with
    /// `team_delay_ticks = "auto"` the delay each agent came to).
    pub agent_delay: BTreeMap<String, u64>,
}

impl Records {
    /// Keep a drive command of a scenario tick: its torque, and whether it carried gains.
    pub fn keep_drive(&mut self, cmd: &DriveCommand) {
        let robot = cmd.header.robot_id();
        if cmd.has_gains() {
            *self.with_gains.entry(robot.to_string()).or_default() += 1;
        }
        self.torques
            .entry(robot.to_string())
            .or_default()
            .push((cmd.header.tick, cmd.tau_ff.clone()));
    }

    /// Keep the safe-mode entries and the team delay of an agent's status.
    pub fn keep_agent_status(&mut self, st: &AgentStatus) {
        let n = self.agent_safe_mode.entry(st.header.robot_id().to_string()).or_default();
        *n = (*n).max(st.safe_mode_entries);
        let d = self.agent_delay.entry(st.header.robot_id().to_string()).or_default();
        *d = (*d).max(st.team_delay_ticks);
    }
}
