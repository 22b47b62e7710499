//! The coordinator service over Zenoh: membership, tick assembly, solving, publishing.
//!
//! Who is commanded is the [`Roster`]'s (members by liveliness, silent members left out, late
//! ones admitted beside the team); a tick is gathered by the [`TickAssembler`], in real time
//! with a late member's latest terms reused ([`TermsReuse`]) so that one late link delays nobody.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, MemberEvent, Qos, TransportError, TypedPublisher};
use protocol::validate::Validate;
use protocol::{
    CoordinatorMode, CoordinatorStatus, DynamicsTerms, Header, ProtocolError, RobotDescription,
    TaskReferences, TickDiagnostics, TorqueCommand,
};
use tokio::sync::watch;
use zenoh::sample::SampleKind;
use zenoh::Session;

use crate::team::assembly::{AssemblyStatus, ReusedTerms, TermsReuse, TickAssembler};
use crate::team::membership::{Admission, Roster};
use crate::team::prediction::DelayPredictor;
use crate::TeamController;

/// Capacity of the references queue, samples.
pub const REFERENCE_QUEUE: usize = 1 << 16;

/// Settings of the coordinator service.
#[derive(Debug, Clone)]
pub struct CoordinatorConfig {
    pub team: String,
    /// How long a tick may wait for every member's terms before it is abandoned.
    pub tick_deadline: Duration,
    /// Real time: solve a tick with a late member's latest terms ([`TermsReuse`]) and leave out a
    /// member silent for longer, and solve the newest complete tick when several are queued;
    /// `None` (lockstep) waits for every member's own terms and solves every tick in order.
    pub reuse: Option<TermsReuse>,
    /// The robots the team is made of: the first tick waits until all have joined (every
    /// member holding its posture meanwhile), at most [`FORMATION_TIMEOUT`] from the
    /// coordinator's start ([`Roster::expect`]). Empty: whoever is there.
    pub expected: Vec<String>,
    /// The robots' control rate, Hz. With it, a tick solved for a team delay carries each
    /// robot's state over the commands still in flight ([`crate::team::prediction`]);
    /// without it, each command answers the state as measured.
    pub robot_hz: Option<f64>,
    /// A planner sends the task references (the scenario driver does): every robot holds its
    /// posture until the first references came, at most this long from the coordinator's
    /// start, so that a coordinator that starts (or restarts) inside a run never commands the
    /// tasks toward the poses they happened to have. `None`: solve at once, each task held
    /// where it was first seen until references name it.
    pub wait_for_references: Option<Duration>,
    /// Real time: how long a tick's solve may take before the controller's fallback answers
    /// ([`TeamController::set_solve_budget`]). `None` (lockstep): every tick solved to its end.
    pub solve_budget: Option<Duration>,
}

/// How long a coordinator of a run waits for its first references
/// ([`CoordinatorConfig::wait_for_references`]; the driver sends them as soon as it sees the
/// coordinator's token).
pub const REFERENCE_WAIT: Duration = Duration::from_secs(2);

/// How long a coordinator waits at its start for the robots it expects.
pub const FORMATION_TIMEOUT: Duration = Duration::from_secs(3);

impl CoordinatorConfig {
    /// A lockstep coordinator: no reuse, no expected team.
    pub fn lockstep(team: &str, tick_deadline: Duration) -> Self {
        CoordinatorConfig {
            team: team.to_string(),
            tick_deadline,
            reuse: None,
            expected: Vec::new(),
            robot_hz: None,
            wait_for_references: None,
            solve_budget: None,
        }
    }
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
    /// Hold orders sent to a single robot outside the team (not a member yet, being admitted,
    /// no description).
    pub held: u64,
    /// Members' terms taken from an earlier tick (real time, [`TermsReuse`]).
    pub reused_terms: u64,
    /// Times a member went silent and was left out.
    pub silenced: u64,
    /// Commands sent again: a member sent the terms of the tick last solved with them again
    /// (its command was lost; `Service::answer_again`).
    pub repeated_commands: u64,
    /// Messages refused as they arrived (terms, descriptions, references): undecodable, out of
    /// range, or from another sender than their key's (`protocol::keys::check_sender`).
    pub refused: u64,
    /// What the last refusal was, naming the key and the error.
    pub last_refusal: Option<String>,
}

impl CoordinatorCounters {
    /// Count and log a message of kind `what` refused on `key`.
    fn refuse(&mut self, what: &str, key: &str, e: &dyn std::fmt::Display) {
        self.refused += 1;
        tracing::warn!(key, "refused {what}: {e}");
        self.last_refusal = Some(format!("{what} on {key}: {e}"));
    }
}

/// The service's publishers, buffers and bookkeeping between ticks.
struct Service<'a> {
    session: &'a Session,
    cfg: CoordinatorConfig,
    diag_pub: TypedPublisher<TickDiagnostics>,
    status_pub: TypedPublisher<CoordinatorStatus>,
    command_pubs: BTreeMap<String, TypedPublisher<TorqueCommand>>,
    /// The commands of the last solved tick (what `answer_again` sends again).
    commands: Vec<TorqueCommand>,
    /// The tick `commands` belong to (none before the first solve).
    solved_tick: Option<u64>,
    counters: CoordinatorCounters,
    refs: ReferenceBuffer,
    roster: Roster,
    /// Members whose terms the last solved tick reused.
    stale: Vec<String>,
    /// The robots of the last solved tick (what the controller was told to expect).
    solved_members: Vec<String>,
    status_tick: u64,
    detail: String,
    /// Whether the last status published said the team had let go of the object.
    released_reported: bool,
    /// Lockstep: terms of a tick newer than the one just completed, read while draining that
    /// tick's copies; handled before the next wait (every tick is solved, in order).
    deferred: Option<zenoh::sample::Sample>,
    /// The states carried over the team's delay ([`CoordinatorConfig::robot_hz`]).
    predictor: Option<DelayPredictor>,
    /// When the service started: the wait for the first references counts from it.
    started: Instant,
}

/// Run the coordinator with `controller` (see [`crate::ControllerSpec::build`]) until `stop`
/// turns true.
pub async fn run(
    session: &Session,
    cfg: CoordinatorConfig,
    mut controller: Box<dyn TeamController>,
    stop: watch::Receiver<bool>,
) -> Result<CoordinatorCounters, TransportError> {
    let mut io = Inputs::open(session, &cfg, stop).await?;
    if cfg.solve_budget.is_some() && !controller.set_solve_budget(cfg.solve_budget) {
        tracing::warn!(controller = controller.name(), "the controller keeps no solve budget");
    }
    // Seen go by agents and bridge; declared last, so whoever sees it is heard (first references).
    let _alive = transport::declare_coordinator(session, &cfg.team).await?;
    let mut svc = Service::start(session, cfg).await?;
    tracing::info!(
        team = %svc.cfg.team,
        controller = controller.name(),
        reuse = ?svc.cfg.reuse,
        "coordinator running"
    );

    let mut assembler = TickAssembler::new(svc.cfg.tick_deadline).with_reuse(svc.cfg.reuse);
    svc.roster.expect(&svc.cfg.expected, Instant::now() + FORMATION_TIMEOUT);
    while let Some((mut team_changed, mut publish_status)) =
        svc.next_event(&mut io, &mut assembler, controller.as_mut()).await?
    {
        let (changed, solved) = svc
            .on_deferred(&io.dynamics, &mut assembler, controller.as_mut(), &io.references)
            .await?;
        (team_changed, publish_status) = (team_changed | changed, publish_status | solved);
        if team_changed {
            svc.team_changed(&mut assembler, controller.as_mut(), &io.references).await?;
            publish_status = true;
        }
        if publish_status {
            svc.publish_status(controller.as_mut()).await?;
        }
    }
    tracing::info!(counters = ?svc.counters, "coordinator stopped");
    Ok(svc.counters)
}

/// What the service waits on: the team's keys, its stop signal and its housekeeping timer.
struct Inputs {
    dynamics: transport::SampleQueue,
    members: transport::EventQueue,
    descriptions: transport::SampleQueue,
    references: transport::SampleQueue,
    stop: watch::Receiver<bool>,
    /// Expired ticks are looked for, and the status published, at least every second.
    housekeeping: tokio::time::Interval,
    /// The robots whose description came already (only the first is logged).
    described: std::collections::BTreeSet<String>,
}

impl Inputs {
    /// Subscribe to the team's dynamics, members, descriptions and references on `session`.
    async fn open(
        session: &Session,
        cfg: &CoordinatorConfig,
        stop: watch::Receiver<bool>,
    ) -> Result<Inputs, TransportError> {
        let dynamics =
            transport::subscribe(session, keys::all_robots(&cfg.team, RobotTopic::Dynamics)?)
                .await?;
        let members = transport::watch_members(session, &cfg.team).await?;
        let descriptions =
            transport::subscribe(session, keys::all_robots(&cfg.team, RobotTopic::Description)?)
                .await?;
        // A planner may send many ticks' references at once (the scenario driver does).
        let references = transport::subscribe_with_capacity(
            session,
            keys::references(&cfg.team)?,
            REFERENCE_QUEUE,
        )
        .await?;
        let housekeeping = tokio::time::interval(
            cfg.tick_deadline.clamp(Duration::from_millis(10), Duration::from_secs(1)),
        );
        Ok(Inputs {
            dynamics,
            members,
            descriptions,
            references,
            stop,
            housekeeping,
            described: std::collections::BTreeSet::new(),
        })
    }
}

/// A robot's description arrived in `sample`: handed to the controller; whether it is the
/// robot's first (readiness may have changed: the status says so now, a lockstep bridge waits
/// for it). Agents repeat their description every second: only the first is logged.
fn description(
    sample: &zenoh::sample::Sample,
    described: &mut std::collections::BTreeSet<String>,
    controller: &mut dyn TeamController,
    counters: &mut CoordinatorCounters,
) -> bool {
    match decode_sample::<RobotDescription>(sample) {
        Ok(desc) => {
            let first = described.insert(desc.header.robot_id().to_string());
            if first {
                tracing::info!(robot = desc.header.robot_id(), "robot description received");
            } else {
                tracing::debug!(robot = desc.header.robot_id(), "robot description received again");
            }
            controller.set_description(&desc);
            first
        }
        Err(e) => {
            counters.refuse("description", sample.key_expr().as_str(), &e);
            false
        }
    }
}

/// Sleep until `at` (forever without one: the branch is disabled then).
async fn sleep_until(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at.into()).await,
        None => std::future::pending().await,
    }
}

impl<'a> Service<'a> {
    /// The service's publishers on `session`, with nothing solved yet.
    async fn start(
        session: &'a Session,
        cfg: CoordinatorConfig,
    ) -> Result<Service<'a>, TransportError> {
        Ok(Service {
            session,
            diag_pub: TypedPublisher::declare(
                session,
                keys::diagnostics(&cfg.team)?,
                Qos::Telemetry,
            )
            .await?,
            status_pub: TypedPublisher::declare(
                session,
                keys::coordinator_status(&cfg.team)?,
                Qos::Telemetry,
            )
            .await?,
            command_pubs: BTreeMap::new(),
            commands: Vec::new(),
            solved_tick: None,
            counters: CoordinatorCounters::default(),
            refs: ReferenceBuffer::default(),
            roster: Roster::default(),
            stale: Vec::new(),
            solved_members: Vec::new(),
            status_tick: 0,
            detail: String::from("waiting for members"),
            released_reported: false,
            deferred: None,
            predictor: cfg
                .robot_hz
                .filter(|hz| hz.is_finite() && *hz > 0.0)
                .map(DelayPredictor::new),
            started: Instant::now(),
            cfg,
        })
    }

    /// Why the tasks cannot be commanded yet, while the first references are awaited
    /// ([`CoordinatorConfig::wait_for_references`]); warns once when the wait ran out.
    fn awaiting_references(&mut self) -> Option<String> {
        let limit = self.cfg.wait_for_references?;
        if self.refs.applied {
            return None;
        }
        if self.started.elapsed() < limit {
            return Some(format!(
                "waiting for the task references (at most {:.1} s)",
                limit.as_secs_f64()
            ));
        }
        if !std::mem::replace(&mut self.refs.gave_up, true) {
            tracing::warn!(
                waited_s = limit.as_secs_f64(),
                "no task references came: every task holds where it is until references name it"
            );
        }
        None
    }

    /// Wait for the next event on `io` and handle it: whether the team changed and whether the
    /// status is due, or `None` once the service is to stop.
    async fn next_event(
        &mut self,
        io: &mut Inputs,
        assembler: &mut TickAssembler,
        controller: &mut dyn TeamController,
    ) -> Result<Option<(bool, bool)>, TransportError> {
        let mut team_changed = false;
        let mut publish_status = false;
        // Late terms are reused only once the team has formed: before its first tick every
        // member's own terms are waited for (one not heard of yet is not silent).
        let reuse_at = if self.roster.started() { assembler.reuse_at() } else { None };
        let departure = self.roster.next_departure();
        tokio::select! {
            _ = io.stop.changed() => { if *io.stop.borrow() { return Ok(None); } }
            m = io.members.recv_async() => {
                let Ok(sample) = m else { return Ok(None) };
                if let Some(ev) = MemberEvent::from_sample(&sample) {
                    team_changed = self.member_event(&ev);
                    publish_status = true;
                }
            }
            d = io.descriptions.recv_async() => {
                let Ok(sample) = d else { return Ok(None) };
                publish_status |=
                    description(&sample, &mut io.described, controller, &mut self.counters);
            }
            r = io.references.recv_async() => {
                let Ok(sample) = r else { return Ok(None) };
                self.refs.take_all(&sample, &io.references, &mut self.counters);
            }
            d = io.dynamics.recv_async() => {
                let Ok(sample) = d else { return Ok(None) };
                let (changed, solved) = self
                    .on_dynamics(sample, &io.dynamics, assembler, controller, &io.references)
                    .await?;
                team_changed |= changed;
                publish_status |= solved;
            }
            _ = sleep_until(departure), if departure.is_some() => {
                team_changed |= self.depart_due();
                publish_status = true;
            }
            _ = sleep_until(reuse_at), if reuse_at.is_some() => {
                let (solved, changed) =
                    self.reuse_due(assembler, controller, &io.references).await?;
                team_changed |= changed;
                publish_status |= solved;
            }
            _ = io.housekeeping.tick() => {
                self.expire(assembler);
                publish_status = true;
            }
        }
        Ok(Some((team_changed, publish_status)))
    }

    /// A member joined or its token vanished: the roster and the status's detail follow;
    /// whether the team changed.
    fn member_event(&mut self, ev: &MemberEvent) -> bool {
        let changed = self.roster.apply(ev, Instant::now());
        self.detail = match ev {
            MemberEvent::Joined(r) => format!("robot {r} joined"),
            MemberEvent::Left(r) if self.roster.is_departing(r) => {
                format!("robot {r}'s token vanished: waiting for its link to come back")
            }
            MemberEvent::Left(r) => self.left(r),
        };
        changed
    }

    /// Members whose link did not come back in time leave; whether any did.
    fn depart_due(&mut self) -> bool {
        let mut any = false;
        for r in self.roster.depart_due(Instant::now()) {
            any = true;
            self.detail = self.left(&r);
        }
        any
    }

    /// Ticks whose terms are still missing at the deadline are abandoned (and counted).
    fn expire(&mut self, assembler: &mut TickAssembler) {
        for (tick, missing) in assembler.expire(self.roster.team()) {
            self.counters.deadline_misses += 1;
            tracing::warn!(tick, ?missing, "tick abandoned: terms missing at the deadline");
        }
    }

    /// The team changed: a robot that left (or went silent) no longer holds up the ticks it
    /// had not sent, so every pending tick complete without it is solved.
    async fn team_changed(
        &mut self,
        assembler: &mut TickAssembler,
        controller: &mut dyn TeamController,
        references: &transport::SampleQueue,
    ) -> Result<(), TransportError> {
        for tick in assembler.pending_ticks() {
            if let AssemblyStatus::Complete(t, terms) =
                assembler.try_complete(tick, self.roster.team())
            {
                self.solve(controller, t, terms, references, Vec::new()).await?;
            }
        }
        Ok(())
    }

    /// Terms arrived (`sample`, then whatever else is queued): the complete tick solved.
    /// Whether the team changed, and whether the status is due.
    async fn on_dynamics(
        &mut self,
        sample: zenoh::sample::Sample,
        queue: &transport::SampleQueue,
        assembler: &mut TickAssembler,
        controller: &mut dyn TeamController,
        references: &transport::SampleQueue,
    ) -> Result<(bool, bool), TransportError> {
        let (newest, changed) = self.gather(sample, queue, assembler, controller).await?;
        let mut solved = false;
        if let Some((tick, terms)) = newest {
            solved = self.solve(controller, tick, terms, references, Vec::new()).await?;
        }
        Ok((changed, solved))
    }

    /// Lockstep: the terms deferred while a tick was completed ([`Service::deferred`]), each
    /// tick they complete solved in order. Whether the team changed, and whether the status is
    /// due.
    async fn on_deferred(
        &mut self,
        queue: &transport::SampleQueue,
        assembler: &mut TickAssembler,
        controller: &mut dyn TeamController,
        references: &transport::SampleQueue,
    ) -> Result<(bool, bool), TransportError> {
        let (mut changed, mut solved) = (false, false);
        while let Some(sample) = self.deferred.take() {
            let (c, s) = self.on_dynamics(sample, queue, assembler, controller, references).await?;
            (changed, solved) = (changed | c, solved | s);
        }
        Ok((changed, solved))
    }

    /// Take `first` and, once a tick is complete, the terms already queued. In real time only
    /// the newest complete tick is returned for solving (a coordinator that fell behind catches
    /// up instead of sending commands too old to apply); in lockstep the first, and terms of a
    /// newer tick wait in [`Service::deferred`]. Terms of robots outside the team get a hold
    /// order for their tick. Also returns whether the team changed.
    async fn gather(
        &mut self,
        first: zenoh::sample::Sample,
        queue: &transport::SampleQueue,
        assembler: &mut TickAssembler,
        controller: &mut dyn TeamController,
    ) -> Result<(Option<(u64, Vec<DynamicsTerms>)>, bool), TransportError> {
        let mut newest: Option<(u64, Vec<DynamicsTerms>)> = None;
        let mut team_changed = false;
        let mut next = Some(first);
        while let Some(sample) = next {
            if sample.kind() == SampleKind::Delete {
                team_changed |= self.announced_leave(&sample);
            } else if let Some(terms) = decode_terms(&sample, &mut self.counters) {
                let (robot, tick) = (terms.header.robot_id().to_string(), terms.header.tick);
                if self.cfg.reuse.is_none() && newest.as_ref().is_some_and(|(done, _)| tick > *done)
                {
                    // Lockstep solves every tick: a newer one waits for this one's solve.
                    self.deferred = Some(sample);
                    break;
                }
                if self.hold_while_forming(&robot, tick).await? {
                    next = None;
                    continue;
                }
                let outcome = if self.refuse_ahead(&sample, &robot, tick, assembler) {
                    AssemblyStatus::Pending
                } else if let Err(e) = controller.check_terms(&terms) {
                    self.refuse_terms(&sample, &robot, tick, &e.to_string(), assembler).await?
                } else {
                    self.admit(&robot, tick, terms, assembler, controller, &mut team_changed)
                        .await?
                };
                self.keep_newest(outcome, &robot, &mut newest, assembler).await?;
            }
            // Once a tick is complete, the queued terms are read too: copies of its terms (the
            // lockstep bridge republishes states), or in real time a newer complete tick that
            // overtakes it. In lockstep every tick is solved, in order (with a team delay the
            // robots' states run ahead of the team's answers, and each answer is awaited).
            next = if newest.is_some() { queue.try_recv().ok().flatten() } else { None };
        }
        Ok((newest, team_changed))
    }

    /// While the team forms, `robot`'s terms of `tick` are answered with a hold order (and the
    /// tick counted as not ready); whether they were.
    async fn hold_while_forming(&mut self, robot: &str, tick: u64) -> Result<bool, TransportError> {
        let waiting = self.roster.forming(Instant::now());
        if waiting.is_empty() {
            return Ok(false);
        }
        self.counters.not_ready += 1;
        let why = format!("forming the team: waiting for {waiting:?} to join");
        self.detail.clone_from(&why);
        self.hold_one(robot, tick, &why).await?;
        Ok(true)
    }

    /// Terms of `tick` too far ahead of the team's newest tick are refused (and counted);
    /// whether they were.
    fn refuse_ahead(
        &mut self,
        sample: &zenoh::sample::Sample,
        robot: &str,
        tick: u64,
        assembler: &TickAssembler,
    ) -> bool {
        let Some(newest) = assembler.ahead_of_team(robot, tick, self.roster.team()) else {
            return false;
        };
        self.counters.rejected_terms += 1;
        let why = format!(
            "terms of tick {tick}, more than {} ticks ahead of the team's newest, {newest}",
            crate::team::assembly::MAX_LEAD_TICKS
        );
        self.counters.refuse("dynamics terms", sample.key_expr().as_str(), &why);
        true
    }

    /// What became of a tick `robot`'s terms went to: a complete tick replaces (overtakes)
    /// `newest`; terms of the tick last completed are answered again.
    async fn keep_newest(
        &mut self,
        outcome: AssemblyStatus,
        robot: &str,
        newest: &mut Option<(u64, Vec<DynamicsTerms>)>,
        assembler: &TickAssembler,
    ) -> Result<(), TransportError> {
        match outcome {
            AssemblyStatus::Complete(tick, terms) => {
                if let Some((old, _)) = newest.replace((tick, terms)) {
                    self.counters.overtaken += 1;
                    tracing::debug!(
                        tick = old,
                        newer = tick,
                        "complete tick overtaken by a newer one: not solved"
                    );
                }
            }
            AssemblyStatus::Stale(t) => {
                tracing::debug!(tick = t, "dynamics terms of a tick solved already");
                if assembler.last_completed() == Some(t) {
                    self.answer_again(robot, t).await?;
                }
            }
            AssemblyStatus::Pending => {}
        }
        Ok(())
    }

    /// Admit `robot`'s fitting terms of `tick` to the team's tick (the roster decides:
    /// [`Admission`]); what became of the tick.
    async fn admit(
        &mut self,
        robot: &str,
        tick: u64,
        terms: DynamicsTerms,
        assembler: &mut TickAssembler,
        controller: &mut dyn TeamController,
        team_changed: &mut bool,
    ) -> Result<AssemblyStatus, TransportError> {
        let before = self.roster.team().len();
        let fresh = assembler.last_completed().is_none_or(|t| tick > t);
        Ok(match self.roster.admit(robot, controller.ready(robot), fresh) {
            Admission::Stale => AssemblyStatus::Stale(tick),
            Admission::NotAMember => {
                // Its terms can beat its liveliness token: it is told to hold its
                // posture this tick rather than left waiting for a command.
                self.counters.rejected_terms += 1;
                tracing::warn!(
                    robot,
                    tick,
                    "dynamics from a robot that is not a member (no liveliness token): \
                     it holds its posture this tick"
                );
                self.hold_one(robot, tick, "not a member").await?;
                AssemblyStatus::Pending
            }
            Admission::Hold(why) => {
                *team_changed |= self.roster.team().len() != before;
                self.hold_one(robot, tick, &why).await?;
                // The tick goes on without it (admitted, it is in from the next tick).
                held_in_tick(assembler, robot, tick, self.roster.team())
            }
            Admission::Team => assembler.add(terms, self.roster.team()),
        })
    }

    /// `robot`'s terms of `tick` do not fit the controller (`why`): refused and counted, and the
    /// robot holds its posture this tick; a member's tick goes on without it.
    async fn refuse_terms(
        &mut self,
        sample: &zenoh::sample::Sample,
        robot: &str,
        tick: u64,
        why: &str,
        assembler: &mut TickAssembler,
    ) -> Result<AssemblyStatus, TransportError> {
        self.counters.rejected_terms += 1;
        self.counters.refuse("dynamics terms", sample.key_expr().as_str(), &why);
        self.hold_one(robot, tick, &format!("its terms were refused: {why}")).await?;
        if !self.roster.team().iter().any(|m| m == robot) {
            return Ok(AssemblyStatus::Pending);
        }
        Ok(held_in_tick(assembler, robot, tick, self.roster.team()))
    }

    /// Terms of the tick last solved, arriving after it was solved (a robot of the team sends
    /// them again, or one that joined sends them late). Nobody is left waiting for a command:
    /// * a robot solved with its own terms is asking again, so its command did not arrive (a
    ///   link that dropped and came back; in lockstep the bridge republishes the tick's states
    ///   while it waits for some robot's torques, and an agent whose state is still unanswered
    ///   answers each with its terms): its command goes again;
    /// * a robot that was not in that tick (it joined, or came back, after the tick was
    ///   solved without it; the lockstep bridge waits for its torques from the tick it joined)
    ///   gets a hold order for it, as a robot whose terms beat its token does;
    /// * a robot whose terms that tick reused (a late member in real time) was commanded: its
    ///   late terms are dropped;
    /// * a tick complete but not solved yet (`gather` drains the queue before solving it) is
    ///   answered by its solve: nothing is sent now. A hold order here would reach the robot
    ///   before its command, which it would then refuse as not newer. (A robot that is not in
    ///   that tick gets its hold order when its terms come again, after the solve.)
    async fn answer_again(&mut self, robot: &str, tick: u64) -> Result<(), TransportError> {
        if self.solved_tick != Some(tick) || self.stale.iter().any(|r| r == robot) {
            return Ok(());
        }
        let Some(cmd) =
            self.commands.iter().find(|c| c.header.tick == tick && c.header.robot_id() == robot)
        else {
            return self
                .hold_one(robot, tick, "its terms came after its tick was solved without it")
                .await;
        };
        let Some(publisher) = self.command_pubs.get_mut(robot) else { return Ok(()) };
        // What was sent: the controller's command, or the hold order that replaced an invalid
        // one (counted as a controller error when it was first sent).
        let _ = put_checked(publisher, &self.cfg.team, cmd).await?;
        self.counters.repeated_commands += 1;
        // Counted (`repeated_commands`, in the coordinator's final counters): in lockstep the
        // bridge resends a tick's states while it waits, and the first tick waits long.
        tracing::debug!(
            robot,
            tick,
            "terms of the tick last solved came again: its command sent again"
        );
        Ok(())
    }

    /// A robot that leaves deletes its dynamics key first (`sample`): out at once. Returns
    /// whether the team changed.
    fn announced_leave(&mut self, sample: &zenoh::sample::Sample) -> bool {
        let Some(robot) = keys::robot_of(sample.key_expr().as_str()) else { return false };
        if !self.roster.leave(robot) {
            return false;
        }
        self.detail = self.left(robot);
        true
    }

    /// `robot` has left the team: its command publisher goes. Returns the status's detail.
    fn left(&mut self, robot: &str) -> String {
        self.command_pubs.remove(robot);
        format!("robot {robot} left")
    }

    /// A hold order for `robot` at `tick` (it is outside the team this tick, `why`).
    async fn hold_one(&mut self, robot: &str, tick: u64, why: &str) -> Result<(), TransportError> {
        self.counters.held += 1;
        tracing::debug!(robot, tick, "{why}: it holds its posture this tick");
        // Not into `commands`: they stay the last solved tick's, for `answer_again`.
        // At the team's delay of the last solved tick.
        let delay_ticks = self.commands.first().map_or(0, |c| c.delay_ticks);
        if let Some(p) = &mut self.predictor {
            p.record_hold(robot, tick, delay_ticks);
        }
        let order =
            TorqueCommand { delay_ticks, ..TorqueCommand::hold(&self.cfg.team, robot, tick) };
        publish_commands(
            self.session,
            &self.cfg,
            std::slice::from_ref(&order),
            &mut self.command_pubs,
            &mut self.counters,
        )
        .await
    }

    /// Ticks due for reuse: solve the newest (with its late members' latest terms), leaving out
    /// the members too silent for it. Returns whether a tick was solved and whether the team
    /// changed.
    async fn reuse_due(
        &mut self,
        assembler: &mut TickAssembler,
        controller: &mut dyn TeamController,
        references: &transport::SampleQueue,
    ) -> Result<(bool, bool), TransportError> {
        let mut team_changed = false;
        loop {
            match assembler.reuse_due(Instant::now(), self.roster.team()) {
                Some(ReusedTerms::Complete { tick, mut terms, reused }) => {
                    tracing::debug!(tick, ?reused, "late terms: solved with the latest of each");
                    let mut stale = Vec::with_capacity(reused.len());
                    for (r, from) in reused {
                        // A departing member whose terms stopped too has left (a dead agent).
                        if self.roster.reused(&r, tick.saturating_sub(from)) {
                            terms.retain(|t| t.header.robot_id() != r);
                            team_changed = true;
                            self.detail = self.left(&r);
                        } else {
                            stale.push(r);
                        }
                    }
                    self.counters.reused_terms += stale.len() as u64;
                    self.solve(controller, tick, terms, references, stale).await?;
                    return Ok((true, team_changed));
                }
                Some(ReusedTerms::Silent { tick, robots }) => {
                    for r in &robots {
                        if self.roster.silence(r) {
                            self.counters.silenced += 1;
                            team_changed = true;
                            self.detail = format!(
                                "robot {r} silent since before tick {tick}: solving without it"
                            );
                        }
                    }
                    if let AssemblyStatus::Complete(t, terms) =
                        assembler.try_complete(tick, self.roster.team())
                    {
                        self.solve(controller, t, terms, references, Vec::new()).await?;
                        return Ok((true, team_changed));
                    }
                }
                None => return Ok((false, team_changed)),
            }
        }
    }

    /// Solve a complete tick and publish its commands; `stale`: members whose terms were
    /// reused. Late members' hands stay out of the grasp. Returns whether the status should go
    /// out now (letting go, or taking a grasp again, is said at once: a planner stops moving
    /// the team on it; so is a change of the stale members).
    async fn solve(
        &mut self,
        controller: &mut dyn TeamController,
        tick: u64,
        mut terms: Vec<DynamicsTerms>,
        references: &transport::SampleQueue,
        stale: Vec<String>,
    ) -> Result<bool, TransportError> {
        for t in terms.iter_mut().filter(|t| self.roster.is_late(t.header.robot_id())) {
            t.hand_in_grasp = false;
        }
        // The controller expects exactly the robots of the tick (members holding their posture
        // this tick are not in it).
        if self.solved_members.len() != terms.len()
            || self.solved_members.iter().zip(&terms).any(|(m, t)| m != t.header.robot_id())
        {
            self.solved_members = terms.iter().map(|t| t.header.robot_id().to_string()).collect();
            controller.set_members(&self.solved_members);
            controller.set_late(&self.roster.late());
        }
        self.refs.drain(references, &mut self.counters);
        let delay = team_delay(&terms);
        // What the torques accelerate goes with every command (the drives' trajectory follows
        // it), and carries the state over the team's delay to where the command applies, which
        // is solved with that tick's references.
        let predicting = controller.keep_accelerations(true) && self.predictor.is_some();
        self.refs.apply(if predicting { tick.saturating_add(delay) } else { tick }, controller);
        let waiting = self.awaiting_references();
        if let Some(p) = self.predictor.as_ref().filter(|_| predicting) {
            p.predict(tick, delay, &mut terms);
        }
        let solved = self.solve_and_publish(controller, waiting, tick, delay, &terms).await?;
        if let Some(p) = self.predictor.as_mut().filter(|_| predicting) {
            p.record(tick, delay, &terms, solved.then_some(&*controller));
        }
        self.solved_tick = Some(tick);
        if solved && !self.roster.started() {
            tracing::info!(tick, team = ?self.roster.team(), "the team's first tick is solved");
            self.roster.start();
        }
        self.status_tick = tick;
        let stale_changed = stale != self.stale;
        self.stale = stale;
        Ok(stale_changed || controller.released_at().is_some() != self.released_reported)
    }

    /// Solve `tick` from `terms` (or hold every robot: the controller is not ready, or
    /// `waiting` says why the tasks cannot be commanded yet) and publish its commands, each with
    /// the team's delay `delay` ([`team_delay`]). Returns whether the tick was solved.
    async fn solve_and_publish(
        &mut self,
        controller: &mut dyn TeamController,
        waiting: Option<String>,
        tick: u64,
        delay: u64,
        terms: &[DynamicsTerms],
    ) -> Result<bool, TransportError> {
        let started = Instant::now();
        let ids: Vec<String> = terms.iter().map(|t| t.header.robot_id().to_string()).collect();
        let (commands, counters) = (&mut self.commands, &mut self.counters);
        let outcome = attempt(controller, waiting, tick, terms, &ids, commands, counters);
        let solved = outcome.is_ok();
        match outcome {
            Ok(()) => {
                if controller.used_fallback() {
                    self.counters.fallbacks += 1;
                }
                if let Some(d) = controller.diagnostics() {
                    if let Err(e) = self.diag_pub.put(d).await {
                        tracing::warn!(tick, "diagnostics not published: {e}");
                    }
                }
            }
            Err(why) => {
                // Every robot of the tick is still commanded: it holds its posture this tick.
                let d = hold_orders(&self.cfg.team, tick, &ids, &why, &mut self.commands);
                if let Err(e) = self.diag_pub.put(&d).await {
                    tracing::warn!(tick, "diagnostics not published: {e}");
                }
            }
        }
        for c in self.commands.iter_mut() {
            c.delay_ticks = delay;
        }
        publish_commands(
            self.session,
            &self.cfg,
            &self.commands,
            &mut self.command_pubs,
            &mut self.counters,
        )
        .await?;
        self.counters.ticks += 1;
        tracing::trace!(tick, us = started.elapsed().as_micros() as u64, "tick solved");
        Ok(solved)
    }

    async fn publish_status(
        &mut self,
        controller: &mut dyn TeamController,
    ) -> Result<(), TransportError> {
        let waiting = self.awaiting_references();
        let members = self.roster.members().to_vec();
        let team = self.roster.team();
        let forming = !self.roster.forming(Instant::now()).is_empty();
        let status = CoordinatorStatus {
            header: Header::new(&self.cfg.team, None, self.status_tick, protocol::wall_clock_ns()),
            // Waiting for the references is not waiting for members: the team is formed, and a
            // bridge may start its ticks (they are answered with hold orders meanwhile).
            mode: if forming || team.is_empty() || controller.not_ready(team).is_some() {
                CoordinatorMode::WaitingForMembers
            } else if controller.released_at().is_some() {
                CoordinatorMode::Released
            } else if controller.used_fallback() {
                CoordinatorMode::Fallback
            } else {
                CoordinatorMode::Running
            },
            ticks: self.counters.ticks,
            commands_sent: self.counters.commands_sent,
            deadline_misses: self.counters.deadline_misses,
            fallbacks: self.counters.fallbacks,
            detail: controller
                .not_ready(&members)
                .or(waiting)
                .unwrap_or_else(|| self.detail.clone()),
            members,
            stale: self.stale.clone(),
            silent: self.roster.silent(),
            late: self.roster.late(),
            reused_terms: self.counters.reused_terms,
            refused: self.counters.refused,
            last_refusal: self.counters.last_refusal.clone(),
        };
        self.released_reported = controller.released_at().is_some();
        self.status_pub.put(&status).await
    }
}

/// Member `robot`, told to hold its posture at `tick`, is counted in the tick as holding: what
/// became of the tick. A tick solved already needs nothing more (the hold order answered it).
fn held_in_tick(
    assembler: &mut TickAssembler,
    robot: &str,
    tick: u64,
    team: &[String],
) -> AssemblyStatus {
    match assembler.hold(robot, tick, team) {
        AssemblyStatus::Stale(_) => AssemblyStatus::Pending,
        outcome => outcome,
    }
}

/// One sample of the dynamics key decoded, or counted and logged as rejected.
fn decode_terms(
    sample: &zenoh::sample::Sample,
    counters: &mut CoordinatorCounters,
) -> Option<DynamicsTerms> {
    match decode_sample::<DynamicsTerms>(sample) {
        Ok(t) => Some(t),
        Err(e) => {
            counters.rejected_terms += 1;
            counters.refuse("dynamics terms", sample.key_expr().as_str(), &e);
            None
        }
    }
}

/// A hold order for each robot of a tick the controller failed or was not ready for (into
/// `commands`), and the tick's diagnostics saying so (`why`).
fn hold_orders(
    team: &str,
    tick: u64,
    robots: &[String],
    why: &str,
    commands: &mut Vec<TorqueCommand>,
) -> TickDiagnostics {
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
    /// Whether a reference has been handed to the controller: one for a tick at most the one
    /// solved (a planner's references far ahead of the team, which a restarted coordinator
    /// can hear first, do not end the wait).
    applied: bool,
    /// Whether the wait for the first references ran out.
    gave_up: bool,
}

impl ReferenceBuffer {
    fn take(&mut self, sample: &zenoh::sample::Sample, counters: &mut CoordinatorCounters) {
        match decode_sample::<TaskReferences>(sample) {
            Ok(r) => {
                self.by_tick.insert(r.header.tick, r);
            }
            Err(e) => counters.refuse("references", sample.key_expr().as_str(), &e),
        }
    }

    /// `first` and every reference queued behind it, in one go: a window of references is
    /// decoded as it arrives, not one per event while ticks wait (and the rest inside a tick's
    /// solve).
    fn take_all(
        &mut self,
        first: &zenoh::sample::Sample,
        q: &transport::SampleQueue,
        counters: &mut CoordinatorCounters,
    ) {
        self.take(first, counters);
        self.drain(q, counters);
    }

    fn drain(&mut self, q: &transport::SampleQueue, counters: &mut CoordinatorCounters) {
        while let Ok(Some(sample)) = q.try_recv() {
            self.take(&sample, counters);
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
            self.applied = true;
        }
    }
}

/// The controller's commands for `tick` (robots `ids`) into `commands`, or why every robot
/// holds its posture instead: the controller is not ready, `waiting` says why the tasks cannot
/// be commanded yet, or the controller failed (each counted and logged).
fn attempt(
    controller: &mut dyn TeamController,
    waiting: Option<String>,
    tick: u64,
    terms: &[DynamicsTerms],
    ids: &[String],
    commands: &mut Vec<TorqueCommand>,
    counters: &mut CoordinatorCounters,
) -> Result<(), String> {
    match controller.not_ready(ids).or(waiting) {
        Some(why) => {
            counters.not_ready += 1;
            tracing::debug!(
                tick,
                "controller not ready: {why}; every robot holds its posture this tick"
            );
            Err(format!("controller not ready: {why}"))
        }
        None => controller.solve(terms, commands).map_err(|e| {
            counters.controller_errors += 1;
            tracing::error!(
                tick,
                "controller failed: {e}; every robot holds its posture this tick"
            );
            format!("controller error: {e}")
        }),
    }
}

/// The team's delay for a tick: the longest its robots ask for, so that every robot applies
/// the tick's commands at the same state (each robot's own delay would have two robots apply
/// the team's answers of different ticks at once).
fn team_delay(terms: &[DynamicsTerms]) -> u64 {
    terms.iter().map(|t| t.team_delay_ticks).max().unwrap_or(0)
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
            command_pubs.insert(
                robot.to_string(),
                TypedPublisher::declare(session, key, Qos::HotPath).await?,
            );
        }
        let publisher = command_pubs.get_mut(robot).expect("declared above");
        if let Err(e) = put_checked(publisher, &cfg.team, cmd).await? {
            // A controller's bad message never ends the coordinator: that robot holds.
            counters.controller_errors += 1;
            tracing::error!(
                robot,
                tick = cmd.header.tick,
                "invalid command from the controller ({e}); the robot holds its posture this tick"
            );
        }
        counters.commands_sent += 1;
    }
    Ok(())
}

/// Put `cmd` on its robot's `publisher`, or, if it is invalid, a hold order for its tick in its
/// place (the robot holds its posture). Returns why it was invalid.
async fn put_checked(
    publisher: &mut TypedPublisher<TorqueCommand>,
    team: &str,
    cmd: &TorqueCommand,
) -> Result<Result<(), ProtocolError>, TransportError> {
    match cmd.validate() {
        Ok(()) => publisher.put(cmd).await.map(Ok),
        Err(e) => {
            let hold = TorqueCommand {
                delay_ticks: cmd.delay_ticks.min(protocol::MAX_TEAM_DELAY_TICKS),
                ..TorqueCommand::hold(team, cmd.header.robot_id(), cmd.header.tick)
            };
            publisher.put(&hold).await?;
            Ok(Err(e))
        }
    }
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
        fn solve(
            &mut self,
            _tick: &[DynamicsTerms],
            _out: &mut Vec<TorqueCommand>,
        ) -> Result<(), ControllerError> {
            Ok(())
        }
        fn set_references(&mut self, r: &TaskReferences) {
            self.0.push(r.header.tick);
        }
    }

    fn refs(tick: u64) -> TaskReferences {
        TaskReferences {
            header: Header::new("t", None, tick, 0),
            object: None,
            torsos: Vec::new(),
            swing_feet: Vec::new(),
            foot_loads: Vec::new(),
        }
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
