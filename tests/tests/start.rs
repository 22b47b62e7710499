//! A team's start is not a fault. The first command of a run comes after the coordinator's
//! start-up work (its first solve, its first window of references); the agents' real-time
//! deadlines (a few ticks, 25 ms) run only from their first command, and the first command
//! has a deadline of its own ([`FIRST_COMMAND`], from the first state). A robot whose team
//! never answers still goes to safe mode, after that deadline.
//!
//! Every component runs in this process on one Zenoh session (the embedded mode); the plant
//! and the agents' dynamics are the placeholders (the subject is the timing of the start, not
//! the physics). The slow controller is a test double of the controller only: joint damping
//! that sleeps on its first solve.

use std::time::{Duration, Instant};

use coordinator::joint_damping::JointDamping;
use coordinator::{ControllerError, TeamController};
use protocol::{DynamicsTerms, TorqueCommand};
use robot_agent::core::AgentConfig;
use robot_agent::safe_mode::FIRST_COMMAND;

mod common;
use common::team::{agent_with_config, bridge, coordinator, session, stop};

/// Joint damping whose first solve takes `pause` (a cold start: allocations, a first QP of
/// its shape, a burst of references to decode).
struct SlowFirstSolve {
    pause: Duration,
    solved: bool,
}

impl TeamController for SlowFirstSolve {
    fn name(&self) -> &'static str {
        "joint damping, slow first solve"
    }

    fn solve(
        &mut self,
        tick: &[DynamicsTerms],
        out: &mut Vec<TorqueCommand>,
    ) -> Result<(), ControllerError> {
        if !self.solved {
            self.solved = true;
            std::thread::sleep(self.pause);
        }
        JointDamping { damping: 2.0 }.solve(tick, out)
    }
}

/// Runs a lockstep team of two whose coordinator's first solve takes `pause`; returns each
/// agent's counters after `ticks` ticks.
async fn start_with_first_solve(
    team: &str,
    pause: Duration,
    ticks: u64,
) -> Vec<robot_agent::status::AgentCounters> {
    let s = session().await;
    let c = coordinator(&s, team, Box::new(SlowFirstSolve { pause, solved: false }));
    // The real-time defaults: deadline 5 ticks or 25 ms, commands at most 5 ticks behind.
    let agents = ["r1", "r2"].map(|r| agent_with_config(&s, AgentConfig::new(team, r)));
    let b = bridge(&s, team, &["r1", "r2"], ticks, 500);
    let report = tokio::time::timeout(Duration::from_secs(60), b.task)
        .await
        .expect("bounded")
        .unwrap()
        .expect("the run completes");
    assert_eq!(report.ticks, ticks);
    let mut counters = Vec::new();
    for a in agents {
        counters.push(stop(a).await);
    }
    stop(c).await;
    s.close().await.unwrap();
    counters
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_first_solve_slower_than_a_tick_deadline_is_no_fault() {
    // 60 ms: more than twice the 25 ms real-time deadline, as a cold start measured on a loaded
    // two-core machine.
    let ticks = 100;
    let started = Instant::now();
    let counters = start_with_first_solve("start1", Duration::from_millis(60), ticks).await;
    assert!(started.elapsed() >= Duration::from_millis(60), "the run waited for the first solve");
    for (i, c) in counters.iter().enumerate() {
        assert_eq!(c.safe_mode_entries, 0, "robot {i}: the start is not a missed deadline");
        // (`rejected` may count a copy of tick 0's command: the lockstep bridge sends a state
        // again while it waits, and the coordinator answers the copy too.)
        assert_eq!(c.hold_torques, 0, "robot {i}: no posture hold stood in for a command");
        assert_eq!(
            c.applied, ticks,
            "robot {i}: every tick's command applied, tick 0's included: it was not too old"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_team_that_does_not_answer_within_the_first_command_deadline_sends_its_robots_to_safe_mode(
) {
    let first = FIRST_COMMAND.time.expect("the first command has a time deadline");
    let ticks = 50;
    for (i, c) in start_with_first_solve("start2", first + Duration::from_millis(500), ticks)
        .await
        .iter()
        .enumerate()
    {
        assert_eq!(
            c.safe_mode_entries, 1,
            "robot {i}: safe mode once, at the first command's deadline"
        );
        assert!(c.hold_torques >= 1, "robot {i}: the hold answered while the team was silent");
    }
}
