//! Real-time mode: the simulation is paced by the wall clock, one control tick per control
//! period. Each tick publishes every robot's state, collects torques until the tick's wall-clock
//! deadline (for a robot whose drives are lost, until [`LOST_DRIVES_WINDOW`]), and steps. A
//! robot whose torques for the tick did not arrive in time keeps its last torques, and the miss
//! is counted per robot. A run that starts in real time, with no settle
//! before it, waits at its first tick for every robot's torques ([`Start`]); after a settle the
//! robots are driven already and the first tick is paced like the others. Torques of older ticks
//! that arrive late are taken as the newest available, also counted as misses of the tick.
//!
//! A tick that starts behind its schedule (the bridge's own work, or a loaded machine, overran
//! the period) still gives the robots most of a period to answer ([`MIN_WINDOW`]), and when it
//! has fallen a whole period behind the schedule slips instead
//! (reported as [`RealtimeReport::slipped`]; the simulation then runs slower than the wall
//! clock). A real robot's state stream never bursts; catching up at once sent states back to
//! back with no time to answer them, every one a miss, and the burst loaded the machine that
//! had fallen behind.
//!
//! A robot whose torques have not come for [`LockstepConfig::drive_timeout`] (its agent died,
//! stalled or lost its link) loses its drives as [`crate::lockstep::AgentLoss`] says (frozen
//! or unpowered). Torques of the tick drive it again; one of an earlier tick that comes for
//! them (a restarted agent answering through the coordinator, after the window) makes the next
//! tick wait for it to the deadline.
//!
//! Every tick's ground truth carries the loop as measured here ([`protocol::LoopTiming`]): per
//! robot, state-to-torque latency (one clock: the states leave and the torques arrive here),
//! the tick of the torques applied, and the late arrivals.

use std::time::{Duration, Instant};

use protocol::transport::{self, decode_sample};
use protocol::DriveCommand;
use tokio::sync::watch;
use zenoh::sample::Sample;
use zenoh::Session;

use crate::lockstep::{BridgeError, BridgeIo, LockstepConfig, LoopDuties, TickSide};
use crate::plant::Plant;

/// What a real-time run did.
#[derive(Debug, Clone, PartialEq)]
pub struct RealtimeReport {
    pub ticks: u64,
    pub sim_time: f64,
    pub wall_time: Duration,
    /// Per robot (plant order): ticks stepped without that tick's torques.
    pub missed: Vec<(String, u64)>,
    /// Ticks that ended (torques taken, physics stepped) after the next tick was due.
    pub overruns: u64,
    /// Wall-clock time the schedule slipped: ticks that started more than a period late were
    /// rescheduled from when they started (the simulation ran slower than the wall clock).
    pub slipped: Duration,
    pub rejected_torques: u64,
    /// Per robot (plant order): times its drives were lost for want of torques.
    pub drive_losses: Vec<(String, u64)>,
}

/// Run `cfg.ticks` ticks of `plant` in real time with control period `period`, from its first
/// tick ([`Start::Driven`]: a robot stands with no torque until its first come).
pub async fn run(
    session: &Session,
    cfg: &LockstepConfig,
    period: Duration,
    plant: &mut impl Plant,
    extras: &mut LoopDuties,
    stop: watch::Receiver<bool>,
) -> Result<RealtimeReport, BridgeError> {
    let robots: Vec<String> = plant.robots().to_vec();
    let mut io = BridgeIo::open(session, cfg, &robots, extras, &stop).await?;
    run_on(&mut io, cfg, period, plant, extras, Start::Driven, stop).await
}

/// How a real-time phase starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Start {
    /// The robots are driven already (a settle ran before, in lockstep, on the same
    /// [`BridgeIo`]), or may stand undriven until their first torques: the first tick is paced
    /// like any other, from its start.
    Driven,
    /// No torques have driven the robots yet: the first tick waits for every robot's (within
    /// `cfg.command_timeout.max(cfg.start_timeout)`, as the lockstep loop's first tick), so that
    /// the team's start-up work is not simulated time with the drives off; the pacing starts
    /// after it.
    WaitForFirstTorques,
}

/// Run `cfg.ticks` ticks of `plant` in real time through `io`, whose robots are present (a
/// phase of a run that opened `io` once).
pub async fn run_on(
    io: &mut BridgeIo,
    cfg: &LockstepConfig,
    period: Duration,
    plant: &mut impl Plant,
    extras: &mut LoopDuties,
    start: Start,
    stop: watch::Receiver<bool>,
) -> Result<RealtimeReport, BridgeError> {
    let BridgeIo { torques, states, side } = io;
    // The drive timeout in ticks.
    let timeout_ticks =
        (cfg.drive_timeout.as_secs_f64() / period.as_secs_f64()).ceil().max(1.0) as u64;
    let mut arrivals = Arrivals::new(plant.robots().to_vec(), extras.first_tick);
    let mut overruns = 0u64;
    let started = Instant::now();
    let mut schedule = Schedule::new(started, period);
    let mut waiting_first = start == Start::WaitForFirstTorques;
    for tick in extras.first_tick..extras.first_tick + cfg.ticks {
        if *stop.borrow() {
            return Err(BridgeError::Stopped);
        }
        let deadline = if waiting_first {
            Instant::now() + cfg.command_timeout.max(cfg.start_timeout)
        } else {
            schedule.start_tick(Instant::now())
        };
        states.publish(plant, tick).await?;
        let sent = Instant::now();
        arrivals.begin_tick(side);
        let window = Window { deadline, lost: sent + period.mul_f64(LOST_DRIVES_WINDOW) };
        arrivals.collect(torques, window, tick, sent, plant, side).await?;
        arrivals.end_tick(tick, side);
        arrivals.lose_silent_drives(cfg, plant, tick, timeout_ticks);
        side.step(plant, &cfg.team, tick, extras).await?;
        if std::mem::take(&mut waiting_first) {
            // The pacing starts from the end of the first tick.
            schedule = Schedule::new(Instant::now(), period);
            continue;
        }
        // Pace: wait for the next tick's start (the torques may all have come early).
        if Instant::now() > schedule.due {
            overruns += 1;
        }
        wait_until(schedule.due).await;
        if cfg.progress_every > 0 && (tick + 1 - extras.first_tick) % cfg.progress_every == 0 {
            arrivals.log_progress(tick + 1, cfg.ticks, plant.time());
        }
    }
    Ok(arrivals.into_report(cfg.ticks, plant.time(), started.elapsed(), overruns, schedule.slipped))
}

/// Wait until `due`: sleeping on Tokio's timer while more than 2 ms are left (it has 1 ms
/// resolution), then on the thread ([`blocking`]).
async fn wait_until(due: Instant) {
    while let Some(left) = due.checked_duration_since(Instant::now()).filter(|d| !d.is_zero()) {
        if left > Duration::from_millis(2) {
            tokio::time::sleep(left - Duration::from_millis(1)).await;
        } else if blocking(|| std::thread::sleep(left)).is_none() {
            tokio::task::yield_now().await;
        }
    }
}

/// Run `f` on this thread, blocking it, in a multi-thread runtime (its other tasks go to other
/// workers meanwhile); `None` in a single-thread runtime, which must not block. The last
/// milliseconds of a tick wait here rather than spin: a spinning loop held one of two cores
/// that the robots' agents needed to answer.
fn blocking<T>(f: impl FnOnce() -> T) -> Option<T> {
    match tokio::runtime::Handle::current().runtime_flavor() {
        tokio::runtime::RuntimeFlavor::MultiThread => Some(tokio::task::block_in_place(f)),
        _ => None,
    }
}

/// The next torque sample before `left` runs out, if one came (`None`: look at the deadline
/// again).
async fn poll_torques(
    torques: &transport::SampleQueue,
    left: Duration,
) -> Result<Option<Sample>, BridgeError> {
    // Tokio's timers have 1 ms resolution, as long as a 1 kHz period: wait on the queue
    // asynchronously only while more than 2 ms are left, then on the thread ([`blocking`]), or
    // poll and yield until the deadline where the runtime has one thread.
    match torques.try_recv() {
        Ok(Some(s)) => Ok(Some(s)),
        Ok(None) if left > Duration::from_millis(2) => {
            match tokio::time::timeout(left - Duration::from_millis(1), torques.recv_async()).await
            {
                Ok(Ok(s)) => Ok(Some(s)),
                Ok(Err(_)) => Err(BridgeError::Stopped),
                Err(_) => Ok(None),
            }
        }
        Ok(None) => match blocking(|| torques.recv_timeout(left)) {
            Some(Ok(s)) => Ok(s),
            Some(Err(_)) => Err(BridgeError::Stopped),
            None => {
                tokio::task::yield_now().await;
                Ok(None)
            }
        },
        Err(_) => Err(BridgeError::Stopped),
    }
}

/// The real-time loop's account of the robots' torques, per robot in plant order.
struct Arrivals {
    robots: Vec<String>,
    /// Ticks stepped without that tick's torques.
    missed: Vec<u64>,
    /// This tick's torques came in time.
    got: Vec<bool>,
    /// The tick of the torques applied last.
    last_tick: Vec<Option<u64>>,
    /// The last tick whose torques came in time.
    last_fresh: Vec<u64>,
    /// Times the drives were lost for want of torques.
    drive_losses: Vec<u64>,
    /// The tick during which torques of an earlier tick came for lost drives: their agent is
    /// back, and the next tick waits for it to its deadline.
    stirring: Vec<Option<u64>>,
    rejected: u64,
}

impl Arrivals {
    fn new(robots: Vec<String>, first_tick: u64) -> Self {
        let n = robots.len();
        Arrivals {
            robots,
            missed: vec![0; n],
            got: vec![false; n],
            last_tick: vec![None; n],
            last_fresh: vec![first_tick; n],
            drive_losses: vec![0; n],
            stirring: vec![None; n],
            rejected: 0,
        }
    }

    /// The progress line of the real-time loop, after `ticks` of `of`.
    fn log_progress(&self, ticks: u64, of: u64, sim_time: f64) {
        tracing::info!(
            tick = ticks,
            of,
            sim_time,
            missed = ?self.missed,
            "progress (real time)"
        );
    }

    /// The report of a run of `ticks` ticks that ended at `sim_time` after `wall_time`.
    fn into_report(
        self,
        ticks: u64,
        sim_time: f64,
        wall_time: Duration,
        overruns: u64,
        slipped: Duration,
    ) -> RealtimeReport {
        RealtimeReport {
            ticks,
            sim_time,
            wall_time,
            drive_losses: self.robots.iter().cloned().zip(self.drive_losses).collect(),
            missed: self.robots.into_iter().zip(self.missed).collect(),
            overruns,
            slipped,
            rejected_torques: self.rejected,
        }
    }

    /// A tick starts: no torques yet, and its loop timing cleared.
    fn begin_tick(&mut self, side: &mut TickSide) {
        self.got.iter_mut().for_each(|g| *g = false);
        for t in side.loop_timing(&self.robots) {
            t.latency_us = None;
            t.late = 0;
        }
    }

    /// Take torques until every robot's for `tick` came or the window passed (for a robot
    /// whose drives are lost, its shorter part); the states left at `sent`.
    async fn collect(
        &mut self,
        torques: &transport::SampleQueue,
        window: Window,
        tick: u64,
        sent: Instant,
        plant: &mut impl Plant,
        side: &mut TickSide,
    ) -> Result<(), BridgeError> {
        loop {
            let missing = |lost: bool| {
                let lost_now = |i| plant.drives_lost(i) && !self.stirred(i, tick);
                self.got.iter().enumerate().any(|(i, g)| !*g && lost_now(i) == lost)
            };
            let until = match (missing(false), missing(true)) {
                (true, _) => window.deadline,
                (false, true) => window.deadline.min(window.lost),
                (false, false) => break,
            };
            let left = until.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            let Some(sample) = poll_torques(torques, left).await? else { continue };
            self.take(&sample, tick, sent, plant, side);
        }
        Ok(())
    }

    /// One torque sample during `tick`: the newest torques of a robot drive it (waking its
    /// lost drives if they are this tick's); older ones are counted late.
    fn take(
        &mut self,
        sample: &Sample,
        tick: u64,
        sent: Instant,
        plant: &mut impl Plant,
        side: &mut TickSide,
    ) {
        let cmd = match decode_sample::<DriveCommand>(sample) {
            Ok(c) => c,
            Err(e) => {
                self.rejected += 1;
                tracing::warn!("rejected torques: {e}");
                return;
            }
        };
        let Some(i) = self.robots.iter().position(|r| r == cmd.header.robot_id()) else { return };
        if cmd.header.tick > tick {
            return;
        }
        let timing = &mut side.loop_timing(&self.robots)[i];
        if cmd.header.tick < tick {
            timing.late += 1;
        }
        if self.last_tick[i].is_some_and(|t| cmd.header.tick <= t) {
            return;
        }
        if cmd.tau_ff.len() != plant.joints(i) {
            self.rejected += 1;
            return;
        }
        if plant.drives_lost(i) {
            if cmd.header.tick < tick {
                // Too old to wake the drives; the next tick waits for its agent.
                self.stirring[i] = Some(tick);
                return;
            }
            tracing::info!(robot = %self.robots[i], tick, "the robot's drives take torques again");
            plant.restore_drives(i);
        }
        plant.set_drive(i, &cmd);
        self.last_tick[i] = Some(cmd.header.tick);
        self.got[i] = cmd.header.tick == tick;
        if self.got[i] {
            timing.latency_us = Some(sent.elapsed().as_secs_f64() * 1e6);
        }
    }

    /// Whether torques for robot `i`'s lost drives came late during the tick before `tick` or
    /// during it.
    fn stirred(&self, i: usize, tick: u64) -> bool {
        self.stirring[i].is_some_and(|t| t + 1 >= tick)
    }

    /// The tick's deadline passed: the torques applied go in the loop timing, and a robot
    /// whose torques did not come missed the tick.
    fn end_tick(&mut self, tick: u64, side: &mut TickSide) {
        for (i, (g, timing)) in self.got.iter().zip(side.loop_timing(&self.robots)).enumerate() {
            timing.applied_tick = self.last_tick[i];
            if *g {
                self.last_fresh[i] = tick;
            } else {
                self.missed[i] += 1;
            }
        }
    }

    /// A robot whose torques have not come in time for `timeout_ticks` loses its drives
    /// ([`LockstepConfig::agent_loss`]).
    fn lose_silent_drives(
        &mut self,
        cfg: &LockstepConfig,
        plant: &mut impl Plant,
        tick: u64,
        timeout_ticks: u64,
    ) {
        for (i, r) in self.robots.iter().enumerate() {
            if let Some(loss) = cfg
                .agent_loss
                .drive_loss()
                .filter(|_| tick - self.last_fresh[i] >= timeout_ticks && !plant.drives_lost(i))
            {
                tracing::warn!(
                    robot = %r,
                    tick,
                    since = self.last_fresh[i],
                    ?loss,
                    "no torques for the drive timeout: the robot's drives lose their commands"
                );
                plant.lose_drives(i, loss);
                self.drive_losses[i] += 1;
            }
        }
    }
}

/// How long a tick waits for the torques of a robot whose drives are lost, in control periods
/// from its states: long enough for an agent that answers in time (a restarted one wakes its
/// drives with a command of the tick, `Arrivals::take`), short enough that a dead agent does
/// not hold every tick to its deadline and the physics step past the next tick's start.
pub const LOST_DRIVES_WINDOW: f64 = 0.5;

/// When a tick stops waiting for torques: at its `deadline`, or at `lost` if only robots whose
/// drives are lost have not answered.
#[derive(Debug, Clone, Copy)]
struct Window {
    deadline: Instant,
    lost: Instant,
}

/// The least time a tick gives the robots to answer, in control periods: a tick that starts
/// late has its deadline at least this long after it starts (its states leave then).
pub const MIN_WINDOW: f64 = 0.75;

/// When ticks are due and when their torques are: one period apart, no window for torques
/// shorter than [`MIN_WINDOW`] periods, slipping once a whole period behind.
#[derive(Debug, Clone, Copy)]
pub struct Schedule {
    period: Duration,
    /// When the next tick is due to start.
    pub due: Instant,
    /// Time given up to slips so far.
    pub slipped: Duration,
}

impl Schedule {
    pub fn new(start: Instant, period: Duration) -> Self {
        Schedule { period, due: start, slipped: Duration::ZERO }
    }

    /// A tick starts at `now`: its deadline for torques. Advances [`Schedule::due`] to the next.
    pub fn start_tick(&mut self, now: Instant) -> Instant {
        if now > self.due + self.period {
            self.slipped += now - self.due;
            self.due = now;
        }
        let deadline = (self.due + self.period).max(now + self.period.mul_f64(MIN_WINDOW));
        self.due += self.period;
        deadline
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: Duration = Duration::from_millis(8);

    fn ms(x: f64) -> Duration {
        Duration::from_micros((x * 1e3).round() as u64)
    }

    #[test]
    fn on_time_ticks_keep_the_period_and_never_slip() {
        let t0 = Instant::now();
        let mut s = Schedule::new(t0, P);
        for k in 0..100u32 {
            // Each tick starts within 0.1 ms of when it is due.
            let now = t0 + P * k + ms(0.1 * f64::from(k % 2));
            assert_eq!(s.start_tick(now), t0 + P * (k + 1));
        }
        assert_eq!(s.slipped, Duration::ZERO);
    }

    #[test]
    fn a_late_tick_gets_three_quarters_of_a_period_and_the_schedule_catches_up() {
        let t0 = Instant::now();
        let mut s = Schedule::new(t0, P);
        // Tick 0 starts 5 ms late (of 8): due at 8, answered no earlier than 5 + 6 = 11.
        assert_eq!(s.start_tick(t0 + ms(5.0)), t0 + ms(11.0));
        // Ticks then start as soon as the last deadline passed; each gives 6 ms at least and
        // the lag (3 ms after tick 0) shrinks by 2 ms a tick until it is gone.
        let mut now = t0 + ms(11.0);
        let mut windows = Vec::new();
        for _ in 0..4 {
            let d = s.start_tick(now);
            windows.push(d - now);
            now = d;
        }
        assert_eq!(windows, vec![ms(6.0), ms(7.0), P, P]);
        assert_eq!(s.slipped, Duration::ZERO, "caught up without slipping");
        assert_eq!(s.due, t0 + P * 5);
    }

    #[test]
    fn a_tick_more_than_a_period_late_slips_the_schedule() {
        let t0 = Instant::now();
        let mut s = Schedule::new(t0, P);
        s.start_tick(t0);
        // Tick 1 was due at 8 ms and starts at 30 ms: 22 ms given up, a whole period to answer.
        assert_eq!(s.start_tick(t0 + ms(30.0)), t0 + ms(38.0));
        assert_eq!(s.slipped, ms(22.0));
        assert_eq!(s.due, t0 + ms(38.0));
        // No burst: whatever the start times, no window is shorter than MIN_WINDOW periods.
        let mut now = t0 + ms(38.0);
        for late in [0.0, 3.0, 9.0, 0.5, 20.0, 7.9] {
            now += ms(late);
            let d = s.start_tick(now);
            assert!(d - now >= P.mul_f64(MIN_WINDOW), "window {:?}", d - now);
            now = d;
        }
    }
}
