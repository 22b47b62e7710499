//! The scenario driver: the runner's own Zenoh participant during a run. It publishes the
//! task references [`LOOKAHEAD`] ticks ahead of the simulation, the first window before the
//! run starts (the coordinator solves tick `k` with the newest reference of tick `<= k`), so
//! that what the controller tracks does not depend on how fast this process keeps up with the
//! simulation (a lagging driver with a 50-tick window let the references freeze and then jump
//! on a loaded machine). In real time the window is [`REALTIME_LOOKAHEAD`] of ticks instead:
//! the simulation cannot run ahead of the wall clock, and a first window as long as the run
//! made the team's start-up work grow with the run's length. It records what the evaluation
//! needs (ground truth, the torques the agents applied, the coordinator's diagnostics and
//! status) and shows the progress. It never talks to the controller other than by
//! references: the ground truth it records is for evaluation only. A walking scenario's
//! contact sets go out
//! [`CONTACT_LOOKAHEAD`] ticks ahead on each robot's `contacts` key (the agents keep a bounded
//! schedule of them). When the coordinator reports that the team let go of the object
//! ([`CoordinatorMode::Released`]), a walk halts (at once before a lift-off, else at its next
//! quiet point) ([`ReferencePlan::halt_walk`]): robots without the object do not walk on.

use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, SampleQueue, TransportError, TypedPublisher};
use protocol::{
    AgentStatus, ContactSet, CoordinatorMode, CoordinatorStatus, DriveCommand, GroundTruth,
    TaskReferences, TickDiagnostics,
};
use tokio::sync::watch;
use zenoh::Session;

use crate::record::{RecordedMessage, Tap};
use evaluation::machine::CpuTimes;
use evaluation::records::Records;
use scenario::{Plan, ReferencePlan};

/// References are published this many ticks ahead of the last simulated tick (10 s at 2 kHz;
/// below the coordinator's reference queue, `coordinator::service::REFERENCE_QUEUE`).
pub const LOOKAHEAD: u64 = 20_000;
/// In real time references are published this far ahead (at most [`LOOKAHEAD`] ticks).
pub const REALTIME_LOOKAHEAD: Duration = Duration::from_secs(2);
/// Contact sets are published this many ticks ahead of the last simulated tick (well within
/// the agent's schedule of `robot_agent::contact_switch::SwitchConfig::max_scheduled` sets).
pub const CONTACT_LOOKAHEAD: u64 = 1_000;

/// What the driver keeps of the samples it hears.
trait Keep {
    fn take_torques(&mut self, sample: &zenoh::sample::Sample, settle: u64, tap: Option<&Tap>);
    fn take_agent_status(&mut self, sample: &zenoh::sample::Sample);
    fn take_diagnostics(&mut self, sample: &zenoh::sample::Sample, settle: u64, tap: Option<&Tap>);
}

impl Keep for Records {
    /// Keep an applied torque command of a scenario tick (settling ticks are not evaluated);
    /// every decoded one goes to the recorder.
    fn take_torques(&mut self, sample: &zenoh::sample::Sample, settle: u64, tap: Option<&Tap>) {
        if let Ok(cmd) = decode_sample::<DriveCommand>(sample) {
            if let Some(tap) = tap {
                tap.send(sample.key_expr().as_str(), RecordedMessage::Torque(cmd.clone()));
            }
            if cmd.header.tick >= settle {
                self.keep_drive(&cmd);
            }
        }
    }

    /// Keep the safe-mode entries and the team delay an agent's status reports.
    fn take_agent_status(&mut self, sample: &zenoh::sample::Sample) {
        if let Ok(st) = decode_sample::<AgentStatus>(sample) {
            self.keep_agent_status(&st);
        }
    }

    /// Keep the coordinator's diagnostics of a scenario tick.
    fn take_diagnostics(&mut self, sample: &zenoh::sample::Sample, settle: u64, tap: Option<&Tap>) {
        if let Ok(d) = decode_sample::<TickDiagnostics>(sample) {
            if let Some(tap) = tap {
                tap.send(sample.key_expr().as_str(), RecordedMessage::Diagnostics(d.clone()));
            }
            if d.header.tick >= settle {
                self.keep_diagnostics(d);
            }
        }
    }
}

/// The driver's subscriptions and publisher, declared before any other component starts.
pub struct Driver {
    truth: SampleQueue,
    torques: SampleQueue,
    diagnostics: SampleQueue,
    status: SampleQueue,
    agent_status: SampleQueue,
    /// The coordinator's liveliness: a coordinator that comes back (restarted) gets the
    /// references again.
    coordinator: transport::EventQueue,
    refs_pub: TypedPublisher<TaskReferences>,
    /// A walk's contact sets by tick, the next to publish, and each robot's publisher.
    contact_sets: Vec<ContactSet>,
    next_contact: usize,
    contact_pubs: BTreeMap<String, TypedPublisher<ContactSet>>,
    /// The team's name on the bus.
    team: String,
    plan: ReferencePlan,
    /// The records the run starts with (empty; taken by [`Driver::run`]).
    records: Records,
    total: u64,
    progress: ProgressBar,
    log_progress: bool,
    /// The recorder's queue: every message the driver decoded or published.
    tap: Option<Tap>,
    /// References of ticks below this went to the tap already (the first window is published
    /// twice; the recording keeps one reference per tick, and a second, held, for the ticks
    /// from a walk's halt to the last already sent).
    tapped_refs: u64,
    /// References go out this many ticks ahead ([`LOOKAHEAD`], or [`Driver::paced`]'s).
    lookahead: u64,
}

/// How long the driver waits after the last tick for its copies of the torques the bridge took:
/// a lost segment comes again after TCP's retransmission timeout, at least 200 ms on Linux and
/// doubled at each further loss, so that 1 s covers two losses of the same copy.
pub const FINAL_GRACE: Duration = Duration::from_millis(1000);

/// One publisher per robot that has contact sets, on its `contacts` key.
async fn contact_publishers(
    session: &Session,
    team: &str,
    contact_sets: &[ContactSet],
) -> Result<BTreeMap<String, TypedPublisher<ContactSet>>, TransportError> {
    let mut contact_pubs = BTreeMap::new();
    for c in contact_sets {
        let id = c.header.robot_id().to_string();
        if let std::collections::btree_map::Entry::Vacant(slot) = contact_pubs.entry(id) {
            let key = keys::contacts(team, slot.key())?;
            slot.insert(TypedPublisher::declare(session, key, Qos::HotPath).await?);
        }
    }
    Ok(contact_pubs)
}

/// A progress bar over `total_ticks` on stdout when `shown`, else a hidden one.
fn progress_bar(shown: bool, total_ticks: u64) -> ProgressBar {
    if shown {
        let pb = ProgressBar::with_draw_target(Some(total_ticks), ProgressDrawTarget::stdout());
        pb.set_style(
            ProgressStyle::with_template(
                "{prefix:>8} [{bar:40}] {pos}/{len} ticks  {msg}  eta {eta}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        pb.set_prefix("settling");
        pb
    } else {
        ProgressBar::hidden()
    }
}

/// Samples each of the driver's recording queues holds.
pub const RECORD_QUEUE: usize = 1 << 15;

impl Driver {
    /// Declare everything on `session`. `show_progress`: a progress bar on a terminal, log
    /// lines every 10 % otherwise.
    pub async fn start(
        session: &Session,
        team: &str,
        run: &Plan,
        show_progress: bool,
    ) -> Result<Driver, TransportError> {
        let (plan, total_ticks) = (run.references.clone(), run.total_ticks());
        // What the report is made of: room for seconds of a real-time run whose driver fell
        // behind (a queue drops its oldest when full, see `transport::SampleQueue`).
        let truth =
            transport::subscribe_with_capacity(session, keys::ground_truth(team)?, RECORD_QUEUE)
                .await?;
        let torques = transport::subscribe_with_capacity(
            session,
            keys::all_robots(team, RobotTopic::Torque)?,
            RECORD_QUEUE,
        )
        .await?;
        let diagnostics =
            transport::subscribe_with_capacity(session, keys::diagnostics(team)?, RECORD_QUEUE)
                .await?;
        let status = transport::subscribe(session, keys::coordinator_status(team)?).await?;
        let agent_status =
            transport::subscribe(session, keys::all_robots(team, RobotTopic::Status)?).await?;
        let coordinator = transport::watch_coordinator(session, team).await?;
        let refs_pub =
            TypedPublisher::declare(session, keys::references(team)?, Qos::HotPath).await?;
        let contact_sets =
            plan.walk.as_ref().map(|w| w.contact_sets(team, &plan.clock)).unwrap_or_default();
        let contact_pubs = contact_publishers(session, team, &contact_sets).await?;
        // Progress goes to stdout with the summary; stderr is the log's.
        let terminal = std::io::stdout().is_terminal();
        let progress = progress_bar(show_progress && terminal, total_ticks);
        Ok(Driver {
            team: team.to_string(),
            truth,
            torques,
            diagnostics,
            status,
            agent_status,
            coordinator,
            refs_pub,
            contact_sets,
            next_contact: 0,
            contact_pubs,
            plan,
            records: Records::new(run),
            total: total_ticks,
            progress,
            log_progress: show_progress && !terminal,
            tap: None,
            tapped_refs: 0,
            lookahead: LOOKAHEAD,
        })
    }

    /// A real-time run at `control_hz`: references go out [`REALTIME_LOOKAHEAD`] ahead.
    pub fn paced(mut self, control_hz: f64) -> Driver {
        self.lookahead =
            ((REALTIME_LOOKAHEAD.as_secs_f64() * control_hz).ceil() as u64).clamp(1, LOOKAHEAD);
        self
    }

    /// Hand every message the driver decodes or publishes to the recorder too.
    pub fn with_tap(mut self, tap: Tap) -> Driver {
        self.tap = Some(tap);
        self
    }

    async fn publish_refs(&mut self, from: u64, to: u64) -> Result<(), TransportError> {
        for tick in from..to.min(self.total) {
            let refs = self.plan.for_tick(&self.team, tick);
            self.refs_pub.put(&refs).await?;
            if let Some(tap) = self.tap.as_ref().filter(|_| tick >= self.tapped_refs) {
                tap.send(&self.refs_pub.key(), RecordedMessage::References(refs));
                self.tapped_refs = tick + 1;
            }
        }
        Ok(())
    }

    /// Publish the contact sets due before tick `until`.
    async fn publish_contacts(&mut self, until: u64) -> Result<(), TransportError> {
        while let Some(c) =
            self.contact_sets.get(self.next_contact).filter(|c| c.header.tick < until)
        {
            if let Some(p) = self.contact_pubs.get_mut(c.header.robot_id()) {
                p.put(c).await?;
                if let Some(tap) = &self.tap {
                    tap.send(&p.key(), RecordedMessage::Contacts(c.clone()));
                }
            }
            self.next_contact += 1;
        }
        Ok(())
    }

    /// The team let go after `tick`: halt the walk, at once before a lift-off, else at its next
    /// quiet point ([`planner::gait::GaitPlan::halt_point`]). The references
    /// already published from there on (up to `published_to`) are sent again, held, and
    /// recorded again (the later of a tick's two references in the recording; the coordinator
    /// may have used the first for the ticks it solved before the held ones arrived); each
    /// walking robot gets a set with all its feet down from then on, which cancels the sets it
    /// has waiting; no later set goes out.
    async fn halt_walk(&mut self, tick: u64, published_to: u64) -> Result<(), TransportError> {
        let (Some(t), Some(walk)) = (self.plan.halt_walk(tick), self.plan.walk.clone()) else {
            return Ok(());
        };
        let from = self.plan.clock.first_tick_at(t);
        tracing::warn!(
            released_after = tick,
            halt_s = t,
            halt_tick = from,
            "the team let go of the object: the walk halts \
             (at once before a lift-off, else when the lifted foot has landed)"
        );
        self.tapped_refs = self.tapped_refs.min(from);
        self.publish_refs(from, published_to).await?;
        let halt = walk.halt_sets(&self.team, &self.plan.clock, t);
        self.contact_sets.truncate(self.next_contact);
        self.contact_sets.extend(halt);
        self.publish_contacts(u64::MAX).await
    }

    /// Every torque command the bridge took is in the records too: the driver's copies come by
    /// another route and can still be in flight (a retransmission on a lossy link, or only a
    /// loaded machine: the ground truth of the last tick can come first). In real time the loop
    /// timing of each tick names the robots whose torques came in time, the last tick's and any
    /// before it (a robot that missed the last tick can still owe the one before); in lockstep
    /// (no loop timing) the bridge waited at the last tick for every robot that answered the
    /// tick before. Waits at most [`FINAL_GRACE`].
    async fn await_applied_torques(&mut self, rec: &mut Records, settle: u64) {
        let mut waiting = rec.owed_drives();
        let until = tokio::time::Instant::now() + FINAL_GRACE;
        while !waiting.is_empty() {
            match tokio::time::timeout_at(until, self.torques.recv_async()).await {
                Ok(Ok(sample)) => {
                    rec.take_torques(&sample, settle, self.tap.as_ref());
                    waiting.retain(|(r, tick)| !rec.has_drive(r, *tick));
                }
                Ok(Err(_)) => return,
                Err(_) => {
                    let (count, first) = (waiting.len(), waiting.first());
                    tracing::warn!(
                        count,
                        ?first,
                        "torques the bridge took never reached the driver"
                    );
                    return;
                }
            }
        }
    }

    /// Wait (at most `within`) for the coordinator's liveliness token, which it declares once
    /// it listens for references, then send the first window of references. Before the first
    /// tick, so that every tick is solved with its own reference whatever the processes'
    /// timing (a lockstep run replays bit for bit). `false` if no coordinator came in time.
    pub async fn send_first_window(&mut self, within: Duration) -> Result<bool, TransportError> {
        let until = tokio::time::Instant::now() + within;
        loop {
            match tokio::time::timeout_at(until, self.coordinator.recv_async()).await {
                Ok(Ok(sample)) if transport::coordinator_alive(&sample) => break,
                Ok(Ok(_)) => continue,
                Ok(Err(_)) | Err(_) => return Ok(false),
            }
        }
        self.publish_refs(0, self.lookahead.min(self.total)).await?;
        Ok(true)
    }

    /// Run until the ground truth of the last tick arrived, or `stop` turns true. The first
    /// window of references went out before ([`Driver::send_first_window`]). What it recorded,
    /// and the error that ended it early if one did (the records of the ticks seen are kept
    /// either way).
    pub async fn run(
        mut self,
        mut stop: watch::Receiver<bool>,
    ) -> (Records, Result<(), TransportError>) {
        let empty = self.records.empty();
        let rec = std::mem::replace(&mut self.records, empty);
        let mut st =
            RunState::new(rec, self.plan.clock.settle_ticks, self.lookahead.min(self.total));
        let driven = self.drive(&mut st, &mut stop).await;
        (self.finish(st).await, driven)
    }

    /// The run's loop: every sample heard, until the last tick's ground truth, `stop`, a
    /// queue that closed, or a publisher's error.
    async fn drive(
        &mut self,
        st: &mut RunState,
        stop: &mut watch::Receiver<bool>,
    ) -> Result<(), TransportError> {
        loop {
            tokio::select! {
                _ = stop.changed() => { if *stop.borrow() { break; } }
                c = self.coordinator.recv_async() => {
                    let Ok(sample) = c else { break };
                    self.on_coordinator(st, &sample).await?;
                }
                s = self.status.recv_async() => {
                    let Ok(sample) = s else { break };
                    self.on_status(st, &sample).await?;
                }
                s = self.truth.recv_async() => {
                    let Ok(sample) = s else { break };
                    if self.on_truth(st, &sample).await? {
                        break;
                    }
                }
                s = self.torques.recv_async() => {
                    let Ok(sample) = s else { break };
                    st.rec.take_torques(&sample, st.settle, self.tap.as_ref());
                }
                s = self.diagnostics.recv_async() => {
                    let Ok(sample) = s else { break };
                    st.rec.take_diagnostics(&sample, st.settle, self.tap.as_ref());
                }
                s = self.agent_status.recv_async() => {
                    let Ok(sample) = s else { break };
                    st.rec.take_agent_status(&sample);
                }
            }
        }
        Ok(())
    }

    /// The coordinator's liveliness changed: one that comes back after it was seen to go is a
    /// restarted coordinator, which has none of the references sent ahead.
    async fn on_coordinator(
        &mut self,
        st: &mut RunState,
        sample: &zenoh::sample::Sample,
    ) -> Result<(), TransportError> {
        if !transport::coordinator_alive(sample) {
            st.coordinator_lost = true;
        } else if std::mem::take(&mut st.coordinator_lost) {
            let from = st.rec.ticks_seen.saturating_sub(1);
            tracing::warn!(
                from,
                to = st.next_ref,
                "the coordinator is back: the references are sent again"
            );
            self.publish_refs(from, st.next_ref).await?;
        }
        Ok(())
    }

    /// A coordinator status: kept; the first that reports the team let go halts the walk.
    async fn on_status(
        &mut self,
        st: &mut RunState,
        sample: &zenoh::sample::Sample,
    ) -> Result<(), TransportError> {
        let Ok(status) = decode_sample::<CoordinatorStatus>(sample) else { return Ok(()) };
        if let Some(tap) = &self.tap {
            tap.send(sample.key_expr().as_str(), RecordedMessage::Status(status.clone()));
        }
        let released = status.mode == CoordinatorMode::Released && st.rec.released_at.is_none();
        let tick = status.header.tick;
        st.rec.keep_status(status);
        if released {
            self.halt_walk(tick, st.next_ref).await?;
        }
        Ok(())
    }

    /// A ground truth: the references and contact sets move ahead with it, a scenario tick's
    /// is kept, the progress moves. Whether it was the last tick's.
    async fn on_truth(
        &mut self,
        st: &mut RunState,
        sample: &zenoh::sample::Sample,
    ) -> Result<bool, TransportError> {
        let gt = match decode_sample::<GroundTruth>(sample) {
            Ok(g) => g,
            Err(e) => {
                tracing::warn!("rejected ground truth: {e}");
                return Ok(false);
            }
        };
        if let Some(tap) = &self.tap {
            tap.send(sample.key_expr().as_str(), RecordedMessage::Truth(gt.clone()));
        }
        let tick = gt.header.tick;
        st.rec.ticks_seen = st.rec.ticks_seen.max(tick + 1);
        let ahead = (tick + 1 + self.lookahead).min(self.total);
        if ahead > st.next_ref {
            self.publish_refs(st.next_ref, ahead).await?;
            st.next_ref = ahead;
        }
        self.publish_contacts(tick + 1 + CONTACT_LOOKAHEAD).await?;
        if tick + 1 == st.settle {
            st.rec.settle_end_stamp_ns = Some(gt.header.stamp_ns);
        }
        if tick >= st.settle {
            if st.run_started.is_none() {
                st.rec.settle_wall = st.started.elapsed();
                st.run_started = Some(Instant::now());
                st.cpu_at_start = CpuTimes::read();
                self.progress.set_prefix("running");
            }
            st.rec.keep_truth(gt);
        }
        self.show_progress(st, tick);
        Ok(tick + 1 >= self.total)
    }

    /// The progress bar at `tick`, or a log line every 10 %.
    fn show_progress(&self, st: &mut RunState, tick: u64) {
        self.progress.set_position(tick + 1);
        if tick.is_multiple_of(200) {
            self.progress
                .set_message(format!("t = {:.2} s", self.plan.time_of_tick(tick).unwrap_or(0.0)));
        }
        if self.log_progress && (tick + 1) * 10 / self.total > st.last_logged {
            st.last_logged = (tick + 1) * 10 / self.total;
            println!(
                "progress {}% ({}/{} ticks, {:.1} s wall)",
                st.last_logged * 10,
                tick + 1,
                self.total,
                st.started.elapsed().as_secs_f64()
            );
        }
    }

    /// After the loop: the torques the bridge took that the driver still lacks, whatever else
    /// already arrived, the wall time.
    async fn finish(mut self, st: RunState) -> Records {
        let RunState { mut rec, settle, run_started, cpu_at_start, .. } = st;
        self.await_applied_torques(&mut rec, settle).await;
        // Whatever else already arrived (torques and diagnostics of the last ticks).
        while let Ok(Some(sample)) = self.torques.try_recv() {
            rec.take_torques(&sample, settle, self.tap.as_ref());
        }
        while let Ok(Some(sample)) = self.diagnostics.try_recv() {
            rec.take_diagnostics(&sample, settle, self.tap.as_ref());
        }
        while let Ok(Some(sample)) = self.agent_status.try_recv() {
            rec.take_agent_status(&sample);
        }
        rec.run_wall = run_started.map(|s| s.elapsed()).unwrap_or_default();
        rec.machine = cpu_at_start.zip(CpuTimes::read()).and_then(|(a, b)| b.since(&a));
        self.progress.finish_and_clear();
        rec
    }
}

/// The driver's bookkeeping during a run.
struct RunState {
    rec: Records,
    /// Settling ticks (not evaluated).
    settle: u64,
    started: Instant,
    /// When the first scenario tick's ground truth arrived.
    run_started: Option<Instant>,
    /// The machine's processor counters when the scenario proper started.
    cpu_at_start: Option<CpuTimes>,
    /// Tenths of the run logged so far (progress without a terminal).
    last_logged: u64,
    /// References of ticks below this are published.
    next_ref: u64,
    /// Whether the coordinator was seen to go (its liveliness token): the next one to come is
    /// a restarted coordinator.
    coordinator_lost: bool,
}

impl RunState {
    fn new(rec: Records, settle: u64, next_ref: u64) -> RunState {
        RunState {
            rec,
            settle,
            started: Instant::now(),
            run_started: None,
            cpu_at_start: None,
            last_logged: 0,
            next_ref,
            coordinator_lost: false,
        }
    }
}
