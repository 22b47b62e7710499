//! The coordinator service over Zenoh: membership, tick assembly, solving, publishing.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, MemberEvent, Qos, TransportError, TypedPublisher};
use protocol::{CoordinatorMode, CoordinatorStatus, DynamicsTerms, Header, RobotDescription, TaskReferences, TickDiagnostics, TorqueCommand};
use protocol::validate::Validate;
use tokio::sync::watch;
use zenoh::Session;

use crate::team::assembly::{TickAssembler, TickOutcome};
use crate::team::membership::Membership;
use crate::TeamController;

/// Capacity of the references queue, samples.
pub const REFERENCE_QUEUE: usize = 1 << 16;

/// Settings of the coordinator service.
#[derive(Debug, Clone)]
pub struct CoordinatorConfig {
    pub team: String,
    /// How long a tick may wait for every member's terms before it is abandoned.
    pub tick_deadline: Duration,
}

/// Counters of the service, returned when it stops.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct CoordinatorCounters {
    pub ticks: u64,
    pub commands_sent: u64,
    pub deadline_misses: u64,
    pub rejected_terms: u64,
    pub controller_errors: u64,
    /// Ticks whose command came from the controller's fallback.
    pub fallbacks: u64,
    /// Ticks skipped because the controller was not ready (e.g. descriptions missing).
    pub not_ready: u64,
    /// Complete ticks not solved because a newer one was complete too (a coordinator that fell
    /// behind in real time catches up; never in lockstep).
    pub overtaken: u64,
}

/// Run the coordinator with `controller` (see [`crate::ControllerSpec::build`]) until `stop`
/// turns true.
pub async fn run(
    session: &Session,
    cfg: CoordinatorConfig,
    mut controller: Box<dyn TeamController>,
    mut stop: watch::Receiver<bool>,
) -> Result<CoordinatorCounters, TransportError> {
    let dynamics = transport::subscribe(session, keys::all_robots(&cfg.team, RobotTopic::Dynamics)?).await?;
    let members_q = transport::watch_members(session, &cfg.team).await?;
    // Agents and the bridge see the coordinator go when this token does.
    let _alive = transport::declare_coordinator(session, &cfg.team).await?;
    let descriptions = transport::subscribe(session, keys::all_robots(&cfg.team, RobotTopic::Description)?).await?;
    // A planner may send many ticks' references at once (the scenario driver does).
    let references = transport::subscribe_with_capacity(session, keys::references(&cfg.team)?, REFERENCE_QUEUE).await?;
    let mut diag_pub: TypedPublisher<TickDiagnostics> =
        TypedPublisher::declare(session, keys::diagnostics(&cfg.team)?, Qos::Telemetry).await?;
    let mut status_pub: TypedPublisher<CoordinatorStatus> =
        TypedPublisher::declare(session, keys::coordinator_status(&cfg.team)?, Qos::Telemetry).await?;
    let mut command_pubs: BTreeMap<String, TypedPublisher<TorqueCommand>> = BTreeMap::new();
    tracing::info!(team = %cfg.team, controller = controller.name(), "coordinator running");

    let mut members = Membership::default();
    let mut assembler = TickAssembler::new(cfg.tick_deadline);
    let mut counters = CoordinatorCounters::default();
    let mut commands = Vec::new();
    let mut status_tick = 0u64;
    // Expired ticks are looked for, and the status published, at least every second.
    let mut housekeeping = tokio::time::interval(cfg.tick_deadline.clamp(Duration::from_millis(10), Duration::from_secs(1)));
    let mut detail = String::from("waiting for members");
    let mut refs = ReferenceBuffer::default();
    // Whether the last status published said the team had let go of the object.
    let mut released_reported = false;
    let mut described = std::collections::BTreeSet::new();
    loop {
        let mut membership_changed = false;
        let mut publish_status = false;
        tokio::select! {
            _ = stop.changed() => { if *stop.borrow() { break; } }
            m = members_q.recv_async() => {
                let Ok(sample) = m else { break };
                if let Some(ev) = MemberEvent::from_sample(&sample) {
                    membership_changed = members.apply(&ev);
                    controller.set_members(&members.to_vec());
                    if let MemberEvent::Left(r) = &ev {
                        command_pubs.remove(r);
                    }
                    detail = match &ev {
                        MemberEvent::Joined(r) => format!("robot {r} joined"),
                        MemberEvent::Left(r) => format!("robot {r} left"),
                    };
                }
            }
            d = descriptions.recv_async() => {
                let Ok(sample) = d else { break };
                match decode_sample::<RobotDescription>(&sample) {
                    Ok(desc) => {
                        // Agents repeat their description every second: log the first only.
                        if described.insert(desc.header.robot_id().to_string()) {
                            tracing::info!(robot = desc.header.robot_id(), "robot description received");
                            // Readiness may have changed: say so now (a lockstep bridge waits for it).
                            publish_status = true;
                        } else {
                            tracing::debug!(robot = desc.header.robot_id(), "robot description received again");
                        }
                        controller.set_description(&desc);
                    }
                    Err(e) => tracing::warn!(key = %sample.key_expr(), "rejected description: {e}"),
                }
            }
            r = references.recv_async() => {
                let Ok(sample) = r else { break };
                refs.take(&sample);
            }
            d = dynamics.recv_async() => {
                let Ok(sample) = d else { break };
                // Once a tick is complete, the terms already queued are taken too and only the
                // newest complete tick is solved: a coordinator that fell behind in real time
                // catches up instead of sending commands too old to apply.
                let mut newest: Option<(u64, Vec<DynamicsTerms>)> = None;
                let mut next = Some(sample);
                while let Some(sample) = next {
                    let outcome = match decode_terms(&sample, &mut counters) {
                        Some(terms) => assembler.add(terms, &members),
                        None => TickOutcome::Pending,
                    };
                    match outcome {
                        TickOutcome::Complete(tick, terms) => {
                            if let Some((old, _)) = newest.replace((tick, terms)) {
                                counters.overtaken += 1;
                                tracing::debug!(tick = old, newer = tick, "complete tick overtaken by a newer one: not solved");
                            }
                        }
                        TickOutcome::NotAMember(r, tick) => {
                            // Its terms can beat its liveliness token: it is told to hold its
                            // posture this tick rather than left waiting for a command.
                            counters.rejected_terms += 1;
                            tracing::warn!(robot = %r, tick, "dynamics from a robot that is not a member (no liveliness token): it holds its posture this tick");
                            commands.clear();
                            commands.push(TorqueCommand::hold(&cfg.team, &r, tick));
                            publish_commands(session, &cfg, &commands, &mut command_pubs, &mut counters).await?;
                        }
                        TickOutcome::Stale(t) => tracing::debug!(tick = t, "late dynamics terms dropped"),
                        TickOutcome::Pending => {}
                    }
                    next = if newest.is_some() { dynamics.try_recv().ok().flatten() } else { None };
                }
                if let Some((tick, terms)) = newest {
                    refs.drain(&references);
                    refs.apply(tick, controller.as_mut());
                    solve_and_publish(session, &cfg, controller.as_mut(), tick, &terms, &mut commands, &mut command_pubs, &mut diag_pub, &mut counters).await?;
                    status_tick = tick;
                    // Letting go (or taking a grasp again) is said at once, not at the next
                    // housekeeping tick: a planner stops moving the team on it.
                    publish_status |= controller.released_at().is_some() != released_reported;
                }
            }
            _ = housekeeping.tick() => {
                for (tick, missing) in assembler.expire(&members) {
                    counters.deadline_misses += 1;
                    tracing::warn!(tick, ?missing, "tick abandoned: terms missing at the deadline");
                }
                publish_status = true;
            }
        }
        if membership_changed {
            // A robot that left no longer holds up the ticks it had not sent.
            for tick in assembler.pending_ticks() {
                if let TickOutcome::Complete(t, terms) = assembler.try_complete(tick, &members) {
                    refs.drain(&references);
                    refs.apply(t, controller.as_mut());
                    solve_and_publish(session, &cfg, controller.as_mut(), t, &terms, &mut commands, &mut command_pubs, &mut diag_pub, &mut counters).await?;
                    status_tick = t;
                }
            }
        }
        if membership_changed || publish_status {
            let status = CoordinatorStatus {
                header: Header::new(&cfg.team, None, status_tick, protocol::wall_clock_ns()),
                mode: if members.is_empty() || controller.not_ready(&members.to_vec()).is_some() {
                    CoordinatorMode::WaitingForMembers
                } else if controller.released_at().is_some() {
                    CoordinatorMode::Released
                } else if controller.used_fallback() {
                    CoordinatorMode::Fallback
                } else {
                    CoordinatorMode::Running
                },
                members: members.to_vec(),
                ticks: counters.ticks,
                commands_sent: counters.commands_sent,
                deadline_misses: counters.deadline_misses,
                fallbacks: counters.fallbacks,
                detail: controller.not_ready(&members.to_vec()).unwrap_or_else(|| detail.clone()),
            };
            released_reported = controller.released_at().is_some();
            status_pub.put(&status).await?;
        }
    }
    tracing::info!(?counters, "coordinator stopped");
    Ok(counters)
}

/// One sample of the dynamics key decoded, or counted and logged as rejected.
fn decode_terms(sample: &zenoh::sample::Sample, counters: &mut CoordinatorCounters) -> Option<DynamicsTerms> {
    match decode_sample::<DynamicsTerms>(sample) {
        Ok(t) => Some(t),
        Err(e) => {
            counters.rejected_terms += 1;
            tracing::warn!(key = %sample.key_expr(), "rejected dynamics terms: {e}");
            None
        }
    }
}

/// A hold order for each robot of a tick the controller failed or was not ready for (into
/// `commands`), and the tick's diagnostics saying so (`why`).
fn hold_orders(team: &str, tick: u64, robots: &[String], why: &str, commands: &mut Vec<TorqueCommand>) -> TickDiagnostics {
    commands.clear();
    commands.extend(robots.iter().map(|r| TorqueCommand::hold(team, r, tick)));
    let mut d = TickDiagnostics::empty(team, tick);
    d.header.stamp_ns = protocol::wall_clock_ns();
    d.fallback = Some(format!("{why}; every robot holds its posture"));
    d
}

/// Task references by tick. A planner may publish references ahead of time (the scenario
/// driver publishes 20,000 ticks ahead); tick `k` is solved with the newest
/// reference whose tick is at most `k`. References still queued when a tick completes are
/// taken first, so a reference published before the tick's states is never a tick late.
#[derive(Default)]
struct ReferenceBuffer {
    by_tick: BTreeMap<u64, TaskReferences>,
}

impl ReferenceBuffer {
    fn take(&mut self, sample: &zenoh::sample::Sample) {
        match decode_sample::<TaskReferences>(sample) {
            Ok(r) => {
                self.by_tick.insert(r.header.tick, r);
            }
            Err(e) => tracing::warn!(key = %sample.key_expr(), "rejected references: {e}"),
        }
    }

    fn drain(&mut self, q: &transport::SampleQueue) {
        while let Ok(Some(sample)) = q.try_recv() {
            self.take(&sample);
        }
    }

    /// Hand the controller the reference for `tick` (if a newer one than it has arrived).
    fn apply(&mut self, tick: u64, controller: &mut dyn TeamController) {
        let Some((&t, _)) = self.by_tick.range(..=tick).next_back() else { return };
        // Older entries are no longer needed; the applied one is removed once used.
        while self.by_tick.first_key_value().is_some_and(|(&k, _)| k < t) {
            self.by_tick.pop_first();
        }
        if let Some(r) = self.by_tick.remove(&t) {
            controller.set_references(&r);
        }
    }
}

#[allow(clippy::too_many_arguments)]
async fn solve_and_publish(
    session: &Session,
    cfg: &CoordinatorConfig,
    controller: &mut dyn TeamController,
    tick: u64,
    terms: &[DynamicsTerms],
    commands: &mut Vec<TorqueCommand>,
    command_pubs: &mut BTreeMap<String, TypedPublisher<TorqueCommand>>,
    diag_pub: &mut TypedPublisher<TickDiagnostics>,
    counters: &mut CoordinatorCounters,
) -> Result<(), TransportError> {
    let started = Instant::now();
    let ids: Vec<String> = terms.iter().map(|t| t.header.robot_id().to_string()).collect();
    let outcome = match controller.not_ready(&ids) {
        Some(why) => {
            counters.not_ready += 1;
            tracing::debug!(tick, "controller not ready: {why}; every robot holds its posture this tick");
            Err(format!("controller not ready: {why}"))
        }
        None => controller.solve(terms, commands).map_err(|e| {
            counters.controller_errors += 1;
            tracing::error!(tick, "controller failed: {e}; every robot holds its posture this tick");
            format!("controller error: {e}")
        }),
    };
    match outcome {
        Ok(()) => {
            if controller.used_fallback() {
                counters.fallbacks += 1;
            }
            if let Some(d) = controller.diagnostics() {
                if let Err(e) = diag_pub.put(d).await {
                    tracing::warn!(tick, "diagnostics not published: {e}");
                }
            }
        }
        Err(why) => {
            // Every robot of the tick is still commanded: it holds its posture this tick.
            let d = hold_orders(&cfg.team, tick, &ids, &why, commands);
            if let Err(e) = diag_pub.put(&d).await {
                tracing::warn!(tick, "diagnostics not published: {e}");
            }
        }
    }
    publish_commands(session, cfg, commands, command_pubs, counters).await?;
    counters.ticks += 1;
    tracing::trace!(tick, us = started.elapsed().as_micros() as u64, "tick solved");
    Ok(())
}

/// Each command on its robot's command key (publishers declared on first use).
async fn publish_commands(
    session: &Session,
    cfg: &CoordinatorConfig,
    commands: &[TorqueCommand],
    command_pubs: &mut BTreeMap<String, TypedPublisher<TorqueCommand>>,
    counters: &mut CoordinatorCounters,
) -> Result<(), TransportError> {
    for cmd in commands {
        let robot = cmd.header.robot_id();
        if !command_pubs.contains_key(robot) {
            let key = keys::robot(&cfg.team, robot, RobotTopic::Command)?;
            command_pubs.insert(robot.to_string(), TypedPublisher::declare(session, key, Qos::HotPath).await?);
        }
        let publisher = command_pubs.get_mut(robot).expect("declared above");
        match cmd.validate() {
            Ok(()) => publisher.put(cmd).await?,
            Err(e) => {
                // A controller's bad message never ends the coordinator: that robot holds.
                counters.controller_errors += 1;
                tracing::error!(robot, tick = cmd.header.tick, "invalid command from the controller ({e}); the robot holds its posture this tick");
                publisher.put(&TorqueCommand::hold(&cfg.team, robot, cmd.header.tick)).await?;
            }
        }
        counters.commands_sent += 1;
    }
    Ok(())
}


#[cfg(test)]
mod tests {
    use super::*;
    use crate::ControllerError;

    /// Records the ticks of the references it is handed.
    #[derive(Default)]
    struct Recorder(Vec<u64>);

    impl TeamController for Recorder {
        fn name(&self) -> &'static str {
            "recorder"
        }
        fn solve(&mut self, _tick: &[DynamicsTerms], _out: &mut Vec<TorqueCommand>) -> Result<(), ControllerError> {
            Ok(())
        }
        fn set_references(&mut self, r: &TaskReferences) {
            self.0.push(r.header.tick);
        }
    }

    fn refs(tick: u64) -> TaskReferences {
        TaskReferences { header: Header::new("t", None, tick, 0), object: None, torsos: Vec::new(), swing_feet: Vec::new(), foot_loads: Vec::new() }
    }

    #[test]
    fn a_tick_is_solved_with_the_newest_reference_not_after_it() {
        let mut b = ReferenceBuffer::default();
        let mut c = Recorder::default();
        b.apply(0, &mut c); // nothing yet: the controller keeps what it holds
        assert!(c.0.is_empty());
        for t in [5, 3, 4, 9] {
            b.by_tick.insert(t, refs(t));
        }
        b.apply(2, &mut c); // every reference is for a later tick
        assert!(c.0.is_empty());
        b.apply(4, &mut c); // 3 and 4 are due: 4, and 3 is dropped
        assert_eq!(c.0, vec![4]);
        b.apply(4, &mut c); // already handed over
        assert_eq!(c.0, vec![4]);
        b.apply(8, &mut c); // 5 is the newest not after 8
        assert_eq!(c.0, vec![4, 5]);
        assert_eq!(b.by_tick.keys().copied().collect::<Vec<_>>(), vec![9]);
        b.apply(100, &mut c);
        assert_eq!(c.0, vec![4, 5, 9]);
        assert!(b.by_tick.is_empty());
    }
}
