//! Recording a run: every message the runner sees goes to `run.mcap` (and, with `--live`, to
//! Foxglove over WebSocket) without slowing the run.
//!
//! * The sources are the runner's own: the scenario driver hands every ground truth, applied
//!   torque, diagnostics and status sample it decoded, and every reference it published, to a
//!   [`Tap`]; [`subscribe`] adds the robots' own keys (state, dynamics, command, contacts,
//!   agent status) from Zenoh subscriptions on the runner's session.
//! * A [`Tap`] never blocks: it puts the message on a bounded queue ([`QUEUE`]) and counts
//!   what did not fit ([`Recorder::finish`] reports it, and the recording's metadata keeps it).
//! * One writer thread turns each message into JSON on a channel named after its Zenoh key
//!   (schema: the message's JSON Schema, [`channels`]), and every [`SCENE_HZ`] of sim time
//!   adds the 3-D view ([`scene`]): link frames from each robot's state through its model
//!   (`/tf`, `foxglove.FrameTransforms`), the object and contact forces (`/scene`,
//!   `foxglove.SceneUpdate`).
//! * The foxglove SDK does the rest: the MCAP file, and with `--live` its WebSocket server
//!   (a sink that costs nothing while no client subscribes).
//! * [`replay`] reads a recording back into the driver's [`evaluation::records::Records`], so that
//!   `team report run.mcap` gives the metrics of the live run.

pub mod channels;
pub mod replay;
pub mod scene;
pub mod segments;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;

use protocol::{
    AgentStatus, ContactSet, CoordinatorStatus, DriveCommand, DynamicsTerms, GroundTruth,
    RobotState, TaskReferences, TickDiagnostics, TorqueCommand,
};
use thiserror::Error;

use scenario::plan::Plan;

/// Messages the queue holds before a [`Tap`] drops (about 2 s of a 2-robot run at 2 kHz).
pub const QUEUE: usize = 65_536;
/// Rate of the 3-D view channels (`/tf`, `/scene`) in sim time, Hz; the key channels keep
/// every message.
pub const SCENE_HZ: f64 = 100.0;
/// Name of the metadata record that describes the run (what [`replay`] needs).
pub const RUN_METADATA: &str = "team-run";

/// Errors of the recorder.
#[derive(Debug, Error)]
pub enum RecordError {
    #[error("recording {path}: {reason}")]
    Mcap { path: String, reason: String },
    #[error("live server on port {port}: {reason}")]
    Live { port: u16, reason: String },
    #[error("the recorder's writer thread failed: {0}")]
    Writer(String),
}

/// One decoded message of the run.
#[derive(Debug, Clone)]
pub enum RecordedMessage {
    State(RobotState),
    Dynamics(DynamicsTerms),
    Command(TorqueCommand),
    Torque(DriveCommand),
    Contacts(ContactSet),
    AgentStatus(AgentStatus),
    Truth(GroundTruth),
    Diagnostics(TickDiagnostics),
    Status(CoordinatorStatus),
    References(TaskReferences),
}

/// A message with the Zenoh key it travelled on.
#[derive(Debug, Clone)]
pub struct Item {
    pub key: String,
    pub message: RecordedMessage,
}

/// The scenario as the run loaded it: file, text, `--set` overrides and pace (replayed by
/// `team report`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ScenarioSource {
    pub path: PathBuf,
    pub text: String,
    pub overrides: Vec<String>,
    /// Lockstep or real time: a real-time run loads the scenario with the real-time loop's
    /// defaults ([`scenario::pace`]).
    pub pace: scenario::Pacing,
}

impl ScenarioSource {
    /// Read the scenario file of a run at `pace`.
    pub fn read(
        path: &Path,
        overrides: &[String],
        pace: scenario::Pacing,
    ) -> std::io::Result<ScenarioSource> {
        Ok(ScenarioSource {
            path: path.to_path_buf(),
            text: std::fs::read_to_string(path)?,
            overrides: overrides.to_vec(),
            pace,
        })
    }

    /// The scenario as the run loaded it.
    pub fn load(&self) -> Result<scenario::Scenario, scenario::ScenarioError> {
        scenario::Scenario::from_str_paced(&self.text, &self.path, &self.overrides, self.pace)
    }
}

/// What to record, and where.
#[derive(Debug, Clone)]
pub struct RecordOptions {
    /// The MCAP file (`<report>/run.mcap`).
    pub path: PathBuf,
    pub scenario: ScenarioSource,
    /// Serve the run to Foxglove on this port (127.0.0.1; 0 picks a free port).
    pub live: Option<u16>,
    /// Split the recording into files of bounded size ([`segments`]; `None`: one file).
    pub split: Option<segments::Split>,
}

/// The producer side: cheap to clone, never blocks.
#[derive(Clone)]
pub struct Tap {
    tx: SyncSender<Item>,
    dropped: Arc<AtomicU64>,
    sent: Arc<AtomicU64>,
}

impl Tap {
    /// Queue a message; if the queue is full it is dropped and counted.
    pub fn send(&self, key: &str, message: RecordedMessage) {
        match self.tx.try_send(Item { key: key.to_string(), message }) {
            Ok(()) => {
                self.sent.fetch_add(1, Ordering::Relaxed);
            }
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

/// What a recording holds, in numbers.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecordingSummary {
    pub path: PathBuf,
    /// Messages written on the key channels.
    pub messages: u64,
    /// Messages dropped at the queue (0 in a healthy run).
    pub dropped: u64,
    /// Messages that could not be written (encoding errors).
    pub failed: u64,
    /// Bytes of every file of the recording (a split one's closed files still on disk
    /// included).
    pub bytes: u64,
    /// Files it was split into before the last (`segments`; 0: one file).
    pub segments: u64,
    /// Why the recording could not be written whole (a full disk, an unwritable file), if so:
    /// the run itself went on (the recorder only ever drops what it cannot write).
    pub error: Option<String>,
}

/// The run's facts that are not messages, written as the [`RUN_METADATA`] record at the end.
#[derive(Debug, Clone, Default)]
pub struct RunFacts {
    pub mode: String,
    pub settle_wall: std::time::Duration,
    pub run_wall: std::time::Duration,
    /// The machine's processors over the scenario proper.
    pub machine: Option<evaluation::machine::MachineLoad>,
    /// The error the run ended in (`None`: it ran to its end).
    pub error: Option<String>,
}

/// A recording in progress: the writer thread and its queue.
pub struct Recorder {
    tap: Tap,
    writer: Option<JoinHandle<Result<scene::WriterCounts, RecordError>>>,
    handle: Arc<
        std::sync::Mutex<Option<foxglove::McapWriterHandle<std::io::BufWriter<std::fs::File>>>>,
    >,
    live: Option<foxglove::WebSocketServerHandle>,
    scenario: ScenarioSource,
    path: PathBuf,
}

impl Recorder {
    /// Open the MCAP file and start the writer thread. With `opts.live`, also start the
    /// WebSocket server (needs a Tokio runtime: call from within one).
    pub async fn start(plan: &Plan, opts: &RecordOptions) -> Result<Recorder, RecordError> {
        let ctx = foxglove::Context::new();
        let mcap_err =
            |e: String| RecordError::Mcap { path: opts.path.display().to_string(), reason: e };
        // A run again into the same report folder replaces the recording.
        let file = std::fs::File::create(&opts.path).map_err(|e| mcap_err(e.to_string()))?;
        let handle = ctx
            .mcap_writer_with_options(write_options())
            .create(std::io::BufWriter::new(file))
            .map_err(|e| mcap_err(e.to_string()))?;
        let live = match opts.live {
            Some(port) => Some(
                foxglove::WebSocketServer::new()
                    .name(format!("team run: {}", plan.scenario.name))
                    .bind("127.0.0.1", port)
                    .context(&ctx)
                    .start()
                    .await
                    .map_err(|e| RecordError::Live { port, reason: e.to_string() })?,
            ),
            None => None,
        };
        let (tx, rx) = sync_channel(QUEUE);
        let tap =
            Tap { tx, dropped: Arc::new(AtomicU64::new(0)), sent: Arc::new(AtomicU64::new(0)) };
        let view = scene::SceneBuilder::new(plan);
        let paced = plan.scene.realtime;
        let handle = Arc::new(std::sync::Mutex::new(Some(handle)));
        let rotation = opts.split.map(|split| Rotation {
            segments: segments::Segments::new(&opts.path, split),
            handle: handle.clone(),
            scenario: opts.scenario.clone(),
        });
        let writer = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || {
                // In real time, below the team's threads: a recording never delays the control
                // loop, and the wall clock bounds what it has to write. A lockstep run goes as
                // fast as the team computes; a writer below it fell behind and dropped a tenth
                // of a walk's messages.
                let _background = paced.then(crate::priority::background_thread);
                write_loop(&ctx, rx, view, rotation)
            })
            .map_err(|e| RecordError::Writer(e.to_string()))?;
        Ok(Recorder {
            tap,
            writer: Some(writer),
            handle,
            live,
            scenario: opts.scenario.clone(),
            path: opts.path.clone(),
        })
    }

    /// The producer side.
    pub fn tap(&self) -> Tap {
        self.tap.clone()
    }

    /// The port of the live server, if any.
    pub fn live_port(&self) -> Option<u16> {
        self.live.as_ref().map(|h| h.port())
    }

    /// Stop the writer once the queue is drained, write the run's facts and close the file.
    /// Producers still holding a [`Tap`] only count drops from now on.
    pub fn finish(mut self, facts: &RunFacts) -> Result<RecordingSummary, RecordError> {
        let Tap { tx, dropped, sent } = self.tap.clone();
        drop(tx);
        // The writer ends when every sender is gone; taps held elsewhere must be dropped by
        // then (the driver and the subscriptions end with the run).
        self.tap = Tap { tx: sync_channel(1).0, dropped: dropped.clone(), sent };
        let mut error = None;
        let counts = match self.writer.take().map(|w| w.join()) {
            Some(Ok(Ok(counts))) => counts,
            Some(Ok(Err(e))) => {
                error = Some(e.to_string());
                scene::WriterCounts::default()
            }
            Some(Err(_)) => return Err(RecordError::Writer("panicked".into())),
            None => scene::WriterCounts::default(),
        };
        let dropped = dropped.load(Ordering::Relaxed);
        let handle = self.handle.lock().map_err(|_| RecordError::Writer("poisoned".into()))?.take();
        if let Some(h) = handle {
            let closed = h
                .write_metadata(RUN_METADATA, {
                    let mut m = run_metadata(&self.scenario, facts, &counts, dropped);
                    m.insert("segments".into(), counts.segments.to_string());
                    m
                })
                .map_err(|e| e.to_string())
                .and_then(|_| h.close().map(|_| ()).map_err(|e| e.to_string()));
            if let Err(e) = closed {
                error.get_or_insert_with(|| {
                    RecordError::Mcap { path: self.path.display().to_string(), reason: e }
                        .to_string()
                });
            }
        }
        if let Some(live) = self.live.take() {
            drop(live.stop());
        }
        let size = |p: &Path| std::fs::metadata(p).map(|m| m.len()).unwrap_or(0);
        let closed = (1..=counts.segments).map(|k| size(&segments::segment_path(&self.path, k)));
        let bytes = size(&self.path) + closed.sum::<u64>();
        if dropped > 0 {
            tracing::warn!(dropped, "the recorder dropped messages (queue of {QUEUE} full)");
        }
        if let Some(e) = &error {
            tracing::error!("the recording is incomplete: {e}");
        }
        Ok(RecordingSummary {
            path: self.path.clone(),
            messages: counts.messages,
            dropped,
            failed: counts.failed,
            bytes,
            segments: counts.segments,
            error,
        })
    }
}

/// The MCAP file's options: zstd-compressed chunks (the default chunk size, 1 MiB) at level 1,
/// compressed on the writer thread itself (no compression threads: the run's processes keep
/// the cores). Level 1 is the fastest and, on these files, also the smallest (a 1 MiB chunk of
/// S4's JSON: level 1 3.33 times smaller, level 3 3.01, level 9 3.27): full-precision floats'
/// low digits are what is left, and no level packs them.
fn write_options() -> foxglove::McapWriteOptions {
    foxglove::McapWriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_level(1)
        .compression_threads(0)
}

/// The [`RUN_METADATA`] record.
fn run_metadata(
    s: &ScenarioSource,
    facts: &RunFacts,
    counts: &scene::WriterCounts,
    dropped: u64,
) -> BTreeMap<String, String> {
    let mut m = BTreeMap::new();
    m.insert("scenario_path".into(), s.path.display().to_string());
    m.insert("scenario_text".into(), s.text.clone());
    m.insert(
        "overrides".into(),
        serde_json::to_string(&s.overrides).unwrap_or_else(|_| "[]".into()),
    );
    m.insert("pace".into(), s.pace.as_str().into());
    m.insert("mode".into(), facts.mode.clone());
    m.insert("settle_wall_ns".into(), facts.settle_wall.as_nanos().to_string());
    m.insert("run_wall_ns".into(), facts.run_wall.as_nanos().to_string());
    if let Some(machine) = &facts.machine {
        m.insert("machine_busy".into(), machine.busy.to_string());
        m.insert("machine_steal".into(), machine.steal.to_string());
    }
    if let Some(e) = &facts.error {
        m.insert("error".into(), e.clone());
    }
    m.insert("messages".into(), counts.messages.to_string());
    m.insert("dropped".into(), dropped.to_string());
    m.insert("failed".into(), counts.failed.to_string());
    m
}

/// What a splitting recorder's writer needs to close a file and open the next.
struct Rotation {
    segments: segments::Segments,
    /// The file being written (shared with [`Recorder::finish`], which closes the last).
    handle: Arc<
        std::sync::Mutex<Option<foxglove::McapWriterHandle<std::io::BufWriter<std::fs::File>>>>,
    >,
    scenario: ScenarioSource,
}

impl Rotation {
    /// Close the file being written (its metadata names the scenario and the segment), rename
    /// it, and go on in a new one at the recording's path.
    fn rotate(&mut self, ctx: &Arc<foxglove::Context>, path: &Path) -> Result<(), RecordError> {
        let err = |e: String| RecordError::Mcap { path: path.display().to_string(), reason: e };
        let mut slot = self.handle.lock().map_err(|_| RecordError::Writer("poisoned".into()))?;
        if let Some(h) = slot.take() {
            let mut meta =
                run_metadata(&self.scenario, &RunFacts::default(), &Default::default(), 0);
            meta.insert("segment".into(), (self.segments.closed + 1).to_string());
            h.write_metadata(RUN_METADATA, meta).map_err(|e| err(e.to_string()))?;
            h.close().map_err(|e| err(e.to_string()))?;
        }
        let closed = self.segments.closed_one().map_err(|e| err(e.to_string()))?;
        tracing::info!(file = %closed.display(), "recording split");
        let file = std::fs::File::create(path).map_err(|e| err(e.to_string()))?;
        let next = ctx
            .mcap_writer_with_options(write_options())
            .create(std::io::BufWriter::new(file))
            .map_err(|e| err(e.to_string()))?;
        *slot = Some(next);
        Ok(())
    }
}

/// The writer thread: until every [`Tap`] is gone; a splitting recorder closes its file and
/// opens the next between two messages.
fn write_loop(
    ctx: &Arc<foxglove::Context>,
    rx: Receiver<Item>,
    mut view: scene::SceneBuilder,
    mut rotation: Option<Rotation>,
) -> Result<scene::WriterCounts, RecordError> {
    let mut chans = channels::Channels::new(ctx.clone());
    let mut counts = scene::WriterCounts::default();
    while let Ok(item) = rx.recv() {
        let log_time = view.log_time(&item.message);
        match chans.log(&item, log_time) {
            Ok(()) => counts.messages += 1,
            Err(e) => {
                counts.failed += 1;
                tracing::debug!("recorder: {e}");
            }
        }
        view.observe(ctx, &item.message, log_time);
        if let Some(r) = rotation.as_mut() {
            if r.segments.due() {
                let path = r.segments.path().to_path_buf();
                r.rotate(ctx, &path)?;
                counts.segments = r.segments.closed;
            }
        }
    }
    Ok(counts)
}

/// Forward the robots' own keys (state, dynamics, command, contacts, agent status) from
/// Zenoh to the tap until `stop` turns true (then what already arrived). The subscriptions
/// are declared before this returns; one task per key.
pub async fn subscribe(
    session: &zenoh::Session,
    team: &str,
    tap: &Tap,
    stop: &tokio::sync::watch::Receiver<bool>,
) -> Result<Vec<tokio::task::JoinHandle<()>>, protocol::transport::TransportError> {
    use protocol::keys::{all_robots, RobotTopic};
    use protocol::transport::subscribe_with_capacity;
    let topics = [
        RobotTopic::State,
        RobotTopic::Dynamics,
        RobotTopic::Command,
        RobotTopic::Contacts,
        RobotTopic::Status,
    ];
    let mut tasks = Vec::new();
    for topic in topics {
        let queue = subscribe_with_capacity(session, all_robots(team, topic)?, 4096).await?;
        let (tap, mut stop) = (tap.clone(), stop.clone());
        tasks.push(tokio::spawn(async move {
            loop {
                tokio::select! {
                    // Stopped, or the run ended without saying so (sender gone).
                    r = stop.changed() => { if r.is_err() || *stop.borrow() { break; } }
                    s = queue.recv_async() => match s {
                        Ok(s) => forward(topic, &s, &tap),
                        Err(_) => break,
                    },
                }
            }
            while let Ok(Some(s)) = queue.try_recv() {
                forward(topic, &s, &tap);
            }
        }));
    }
    Ok(tasks)
}

/// Decode a sample of a robot's `topic` and queue it.
fn forward(topic: protocol::keys::RobotTopic, s: &zenoh::sample::Sample, tap: &Tap) {
    use protocol::keys::RobotTopic;
    use protocol::transport::decode_sample;
    let m = match topic {
        RobotTopic::State => decode_sample(s).map(RecordedMessage::State),
        RobotTopic::Dynamics => decode_sample(s).map(RecordedMessage::Dynamics),
        RobotTopic::Command => decode_sample(s).map(RecordedMessage::Command),
        RobotTopic::Contacts => decode_sample(s).map(RecordedMessage::Contacts),
        RobotTopic::Status => decode_sample(s).map(RecordedMessage::AgentStatus),
        _ => return,
    };
    if let Ok(m) = m {
        tap.send(s.key_expr().as_str(), m);
    }
}
