//! Commands that came before the state they apply at: the coordinator answered a tick with a
//! robot's latest terms before that robot had the tick's state, or the team's delay
//! (`crate::core::AgentConfig::team_delay`) makes every command wait that many states. Each
//! waits here until its state arrives; then the newest due one is checked and applied, and
//! older due ones are dropped (a newer command supersedes them).
//!
//! The slots are allocated at start-up, one command of the robot's size each: keeping and
//! taking commands copies into them and never allocates.

use protocol::{Header, TorqueCommand};

/// A fixed number of commands waiting for their state, in no order.
#[derive(Debug)]
pub struct EarlyCommands {
    slots: Vec<TorqueCommand>,
    pending: usize,
}

/// What [`EarlyCommands::keep`] did with a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeepOutcome {
    /// KeepOutcome in a free slot.
    New,
    /// It replaced a command of the same tick, or the oldest one when every slot was taken.
    Replaced,
    /// Every slot holds a newer command: dropped.
    Dropped,
}

impl EarlyCommands {
    /// Room for `capacity` commands of `joints` torques each.
    pub fn new(team: &str, robot: &str, joints: usize, capacity: usize) -> Self {
        let empty = || TorqueCommand {
            header: Header::new(team, Some(robot), 0, 0),
            tau: Vec::with_capacity(joints),
            hold: false,
            delay_ticks: 0,
            qdd: Vec::with_capacity(joints),
        };
        EarlyCommands { slots: (0..capacity.max(1)).map(|_| empty()).collect(), pending: 0 }
    }

    /// Commands waiting.
    pub fn len(&self) -> usize {
        self.pending
    }

    pub fn is_empty(&self) -> bool {
        self.pending == 0
    }

    /// The tick of the newest command waiting.
    pub fn newest_tick(&self) -> Option<u64> {
        self.slots[..self.pending].iter().map(|c| c.header.tick).max()
    }

    /// Forget every waiting command (the robot fell, or left safe mode for a newer one).
    pub fn clear(&mut self) {
        self.pending = 0;
    }

    /// Keep `cmd` (checked already for its robot and size) until its state arrives.
    pub fn keep(&mut self, cmd: &TorqueCommand) -> KeepOutcome {
        let tick = cmd.header.tick;
        let waiting = &self.slots[..self.pending];
        let (slot, kept) = if let Some(i) = waiting.iter().position(|c| c.header.tick == tick) {
            (i, KeepOutcome::Replaced)
        } else if self.pending < self.slots.len() {
            self.pending += 1;
            (self.pending - 1, KeepOutcome::New)
        } else {
            let oldest = (0..self.pending).min_by_key(|&i| self.slots[i].header.tick).unwrap_or(0);
            if self.slots[oldest].header.tick > tick {
                return KeepOutcome::Dropped;
            }
            (oldest, KeepOutcome::Replaced)
        };
        copy(cmd, &mut self.slots[slot]);
        kept
    }

    /// The newest waiting command whose tick `due` says applies now, copied into `out` (whose
    /// storage is reused); it and every older due one leave the queue. The number of older due
    /// ones dropped, or `None` when no command is due.
    pub fn take_due(
        &mut self,
        due: impl Fn(u64) -> bool,
        out: &mut TorqueCommand,
    ) -> Option<usize> {
        let newest = (0..self.pending)
            .filter(|&i| due(self.slots[i].header.tick))
            .max_by_key(|&i| self.slots[i].header.tick)?;
        copy(&self.slots[newest], out);
        let mut dropped = 0;
        let mut i = 0;
        while i < self.pending {
            if due(self.slots[i].header.tick) {
                dropped += 1;
                self.slots.swap(i, self.pending - 1);
                self.pending -= 1;
            } else {
                i += 1;
            }
        }
        Some(dropped - 1)
    }
}

/// `from`'s tick, stamp, hold flag, torques and accelerations into `to` (same team and robot).
fn copy(from: &TorqueCommand, to: &mut TorqueCommand) {
    to.header.tick = from.header.tick;
    to.header.stamp_ns = from.header.stamp_ns;
    to.hold = from.hold;
    to.tau.clear();
    to.tau.extend_from_slice(&from.tau);
    to.qdd.clear();
    to.qdd.extend_from_slice(&from.qdd);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cmd(tick: u64, tau: f64) -> TorqueCommand {
        TorqueCommand {
            header: Header::new("t", Some("r1"), tick, tick * 10),
            tau: vec![tau; 3],
            hold: false,
            delay_ticks: 0,
            qdd: Vec::new(),
        }
    }

    fn out() -> TorqueCommand {
        cmd(0, 0.0)
    }

    #[test]
    fn the_newest_due_command_is_taken_and_older_due_ones_dropped() {
        let mut q = EarlyCommands::new("t", "r1", 3, 4);
        for k in [5, 3, 4] {
            assert_eq!(q.keep(&cmd(k, k as f64)), KeepOutcome::New);
        }
        let mut o = out();
        assert_eq!(q.take_due(|t| t + 2 <= 4, &mut o), None, "tick 3 applies at 5, not 4");
        assert_eq!(
            q.take_due(|t| t + 2 <= 6, &mut o),
            Some(1),
            "ticks 3 and 4 due at 6: 4 taken, 3 dropped"
        );
        assert_eq!((o.header.tick, o.header.stamp_ns, o.tau.clone()), (4, 40, vec![4.0; 3]));
        assert_eq!((q.len(), q.newest_tick()), (1, Some(5)), "tick 5 still waits");
        assert_eq!(q.take_due(|t| t + 2 <= 7, &mut o), Some(0));
        assert_eq!(o.header.tick, 5);
        assert!(q.is_empty());
    }

    #[test]
    fn a_full_queue_replaces_its_oldest_and_drops_older_commands() {
        let mut q = EarlyCommands::new("t", "r1", 3, 2);
        q.keep(&cmd(7, 7.0));
        q.keep(&cmd(8, 8.0));
        assert_eq!(q.keep(&cmd(8, -8.0)), KeepOutcome::Replaced, "same tick: the newer copy");
        assert_eq!(q.keep(&cmd(6, 6.0)), KeepOutcome::Dropped, "older than every waiting one");
        assert_eq!(q.keep(&cmd(9, 9.0)), KeepOutcome::Replaced, "tick 7 made room");
        let mut o = out();
        assert_eq!(q.take_due(|t| t <= 8, &mut o), Some(0));
        assert_eq!((o.header.tick, o.tau[0]), (8, -8.0));
        assert_eq!(q.take_due(|t| t <= 9, &mut o).map(|_| o.header.tick), Some(9));
    }

    #[test]
    fn keeping_and_taking_reuse_the_slots() {
        let mut q = EarlyCommands::new("t", "r1", 3, 3);
        let mut o = out();
        let before: Vec<*const f64> = q.slots.iter().map(|c| c.tau.as_ptr()).collect();
        for k in 0..50 {
            q.keep(&cmd(k, 1.0));
            if k % 3 == 0 {
                q.take_due(|t| t <= k, &mut o);
            }
        }
        let mut after: Vec<*const f64> = q.slots.iter().map(|c| c.tau.as_ptr()).collect();
        let mut sorted = before.clone();
        sorted.sort();
        after.sort();
        assert_eq!(sorted, after, "the same buffers, moved between slots");
    }
}
