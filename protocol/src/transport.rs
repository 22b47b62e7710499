//! The one place that opens a Zenoh session, and typed publishers and subscribers on it.
//!
//! A session comes from a Zenoh JSON5 configuration file (`--zenoh-config`), from flags
//! (`--mode peer|client`, `--listen`, `--connect`), or from the safe single-machine default:
//! peer mode, multicast scouting off, loopback TCP only. In the default topology one component
//! (the [`Role::Hub`], normally the coordinator) listens on [`DEFAULT_ENDPOINT`] and the others
//! ([`Role::Member`]) connect to it and retry until it is there; they listen on a random
//! loopback port, and gossip lets peers meet and connect directly (peers do not route for each
//! other). Across hosts, give members a routable `--listen` (e.g. `tcp/0.0.0.0:0`) or use a
//! Zenoh router and client mode. A `team run` also listens on [`TOOLS_ENDPOINT`] when the
//! port is free ([`open_discoverable`]), so that a tool started with no flags finds it.
//! Flags override the file; the file overrides the defaults.
//!
//! Hot-path messages (state, dynamics, command, torque) are published with
//! [`Qos::HotPath`]: express (no batching), real-time priority, and congestion control
//! `Block` so that a lockstep tick never loses a message. A real robot's own loop publishes
//! with [`Qos::NeverWait`] instead: the same, but dropped under congestion rather than
//! blocking the robot. Status and diagnostics use [`Qos::Telemetry`]: data priority, dropped
//! under congestion.
//!
//! Every declaration and put has an `async` form for the components that run on Tokio and a
//! synchronous one (`*_wait`, as Zenoh's `Wait`) for a robot's loop on a thread of its own;
//! a synchronous reader is woken by the `notify` callback of [`subscribe_notifying`] and
//! [`watch_liveliness_notifying`].

use std::marker::PhantomData;
use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Duration;

use thiserror::Error;
use zenoh::handlers::{IntoHandler, RingChannel};
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::sample::{Sample, SampleKind};
use zenoh::{Session, Wait};

use crate::{decode, keys, Message, ProtocolError};

/// The default rendezvous of a single-machine team: the hub listens here and the team's
/// other binaries connect here when started without flags.
pub const DEFAULT_ENDPOINT: &str = "tcp/127.0.0.1:7447";
/// Where tools started without flags (`team echo`, [`Role::Tool`]) find a running team: a
/// `team run` listens here if it can ([`open_discoverable`]). A port of its own, which the
/// team's binaries never connect to: an agent started by hand must not join a simulated team.
pub const TOOLS_ENDPOINT: &str = "tcp/127.0.0.1:7449";
/// The port of [`TOOLS_ENDPOINT`].
pub const TOOLS_PORT: u16 = 7449;

/// Errors opening a session or talking on it.
#[derive(Debug, Error)]
pub enum TransportError {
    #[error("cannot read Zenoh configuration {path}: {reason}")]
    ConfigFile { path: PathBuf, reason: String },
    #[error("invalid Zenoh setting {key} = {value}: {reason}")]
    ConfigValue { key: String, value: String, reason: String },
    #[error("cannot open the Zenoh session: {0}")]
    Open(String),
    #[error("Zenoh {op} on {key}: {reason}")]
    Zenoh { op: &'static str, key: String, reason: String },
    #[error(transparent)]
    Protocol(#[from] ProtocolError),
}

/// Zenoh session mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Mode {
    Peer,
    Client,
}

/// Which side of the default topology a component takes when no endpoint is given.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Listens on [`DEFAULT_ENDPOINT`].
    Hub,
    /// Connects to [`DEFAULT_ENDPOINT`].
    Member,
    /// Neither listens nor connects unless told to: every component in one process on one
    /// session (the embedded mode; [`open_discoverable`] adds the tools' endpoint).
    Alone,
    /// A tool that looks at a team: connects to [`TOOLS_ENDPOINT`] (a `team run`) and to
    /// [`DEFAULT_ENDPOINT`] (a hub started by hand), whichever is there.
    Tool,
}

impl Role {
    /// Where the role listens unless told otherwise: loopback only. Members listen on a
    /// random loopback port so that peers met through gossip can connect to them directly.
    fn listens(self) -> &'static [&'static str] {
        match self {
            Role::Hub => &[DEFAULT_ENDPOINT],
            Role::Member | Role::Tool => &["tcp/127.0.0.1:0"],
            Role::Alone => &[],
        }
    }

    /// Where the role connects unless told otherwise.
    fn connects(self) -> &'static [&'static str] {
        match self {
            Role::Member => &[DEFAULT_ENDPOINT],
            Role::Tool => &[TOOLS_ENDPOINT, DEFAULT_ENDPOINT],
            Role::Hub | Role::Alone => &[],
        }
    }
}

/// The Zenoh flags every binary shares.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ZenohArgs {
    /// Zenoh JSON5 configuration file (peer/client mode, endpoints, TLS, access control).
    /// The flags below override what it says.
    #[arg(long = "zenoh-config", value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Session mode.
    #[arg(long, value_enum)]
    pub mode: Option<Mode>,
    /// Endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable).
    #[arg(long, value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// Endpoint to connect to, e.g. tcp/10.0.0.2:7447 (repeatable).
    #[arg(long, value_name = "ENDPOINT")]
    pub connect: Vec<String>,
}

impl ZenohArgs {
    /// Arguments that listen on one endpoint (tests give every test its own port).
    pub fn listening(endpoint: &str) -> Self {
        ZenohArgs { listen: vec![endpoint.to_string()], ..Default::default() }
    }

    /// Arguments that connect to one endpoint.
    pub fn connecting(endpoint: &str) -> Self {
        ZenohArgs { connect: vec![endpoint.to_string()], ..Default::default() }
    }

    /// The flags as command-line arguments, to start another process with the same settings.
    pub fn to_cli(&self) -> Vec<String> {
        let mut out = Vec::new();
        if let Some(c) = &self.config {
            out.extend(["--zenoh-config".to_string(), c.display().to_string()]);
        }
        if let Some(m) = self.mode {
            out.extend([
                "--mode".to_string(),
                if m == Mode::Peer { "peer" } else { "client" }.to_string(),
            ]);
        }
        for l in &self.listen {
            out.extend(["--listen".to_string(), l.clone()]);
        }
        for c in &self.connect {
            out.extend(["--connect".to_string(), c.clone()]);
        }
        out
    }

    /// These arguments listening on [`TOOLS_ENDPOINT`] too; `None` when a configuration file
    /// sets the session up (its access control is the file's to open), in client mode (a
    /// client listens nowhere), when they name the endpoint themselves, or when another
    /// process holds the port.
    pub fn discoverable(&self, role: Role) -> Option<ZenohArgs> {
        let mut listen: Vec<String> = if self.listen.is_empty() {
            role.listens().iter().map(|l| l.to_string()).collect()
        } else {
            self.listen.clone()
        };
        let client = self.mode == Some(Mode::Client);
        if self.config.is_some() || client || listen.iter().any(|l| l == TOOLS_ENDPOINT) {
            return None;
        }
        // Bound and let go at once: a taken port is skipped without Zenoh logging about it.
        std::net::TcpListener::bind(("127.0.0.1", TOOLS_PORT)).ok()?;
        listen.push(TOOLS_ENDPOINT.to_string());
        Some(ZenohArgs { listen, ..self.clone() })
    }

    /// The Zenoh configuration these arguments describe.
    pub fn to_config(&self, role: Role) -> Result<zenoh::Config, TransportError> {
        let mut config = match &self.config {
            Some(path) => zenoh::Config::from_file(path).map_err(|e| {
                TransportError::ConfigFile { path: path.clone(), reason: e.to_string() }
            })?,
            None => {
                let mut c = zenoh::Config::default();
                set(&mut c, "mode", "\"peer\"")?;
                set(&mut c, "scouting/multicast/enabled", "false")?;
                set(&mut c, "listen/endpoints", &json_list(role.listens()))?;
                if !role.connects().is_empty() {
                    set(&mut c, "connect/endpoints", &json_list(role.connects()))?;
                }
                c
            }
        };
        // Retry quickly: components of a team start within moments of each other.
        set(
            &mut config,
            "connect/retry",
            "{period_init_ms: 50, period_max_ms: 500, period_increase_factor: 2}",
        )?;
        if let Some(m) = self.mode {
            set(&mut config, "mode", if m == Mode::Peer { "\"peer\"" } else { "\"client\"" })?;
        }
        if !self.listen.is_empty() {
            set(&mut config, "listen/endpoints", &json_list(&self.listen))?;
        }
        if !self.connect.is_empty() {
            set(&mut config, "connect/endpoints", &json_list(&self.connect))?;
        }
        Ok(config)
    }
}

fn json_list<S: AsRef<str>>(items: &[S]) -> String {
    let quoted: Vec<String> = items.iter().map(|s| format!("{:?}", s.as_ref())).collect();
    format!("[{}]", quoted.join(","))
}

fn set(c: &mut zenoh::Config, key: &str, value: &str) -> Result<(), TransportError> {
    c.insert_json5(key, value).map_err(|e| TransportError::ConfigValue {
        key: key.to_string(),
        value: value.to_string(),
        reason: e.to_string(),
    })
}

/// Serialises this process's [`open_discoverable`] calls from the port's probe to its bind:
/// runs started in parallel threads take the port in turn.
static DISCOVERY: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Open a session from the arguments that also listens on [`TOOLS_ENDPOINT`] if it can
/// ([`ZenohArgs::discoverable`]), so that a tool started on this machine without flags finds
/// it. Returns the session and, if it listens there, that endpoint. Another process that binds
/// the port between the probe and the bind makes Zenoh warn that it could not listen; the
/// session then opens without it.
pub async fn open_discoverable(
    args: &ZenohArgs,
    role: Role,
) -> Result<(Session, Option<String>), TransportError> {
    let _turn = DISCOVERY.lock().await;
    if let Some(with) = args.discoverable(role) {
        match open(&with, role).await {
            Ok(session) => return Ok((session, Some(TOOLS_ENDPOINT.to_string()))),
            Err(e) => tracing::debug!("not listening on {TOOLS_ENDPOINT}: {e}"),
        }
    }
    Ok((open(args, role).await?, None))
}

/// Open a session from the arguments. The only function in the project that opens one
/// ([`open_discoverable`] opens through it).
pub async fn open(args: &ZenohArgs, role: Role) -> Result<Session, TransportError> {
    let config = args.to_config(role)?;
    let session = zenoh::open(config).await.map_err(|e| TransportError::Open(e.to_string()))?;
    tracing::debug!(zid = %session.zid(), ?role, "zenoh session open");
    Ok(session)
}

/// How long [`close`] lets what a session sent leave before it closes. A QUIC link (mutual
/// TLS) discards data it has not sent yet when it closes, where a TCP socket's kernel buffer
/// still delivers it: without the wait, a bridge that closes right after its last tick loses
/// that tick's ground truth on a loaded machine.
pub const CLOSE_LINGER: Duration = Duration::from_millis(500);

/// Close a session after [`CLOSE_LINGER`], so that its last messages arrive. The one way the
/// components end their session.
pub async fn close(session: Session) -> Result<(), TransportError> {
    tokio::time::sleep(CLOSE_LINGER).await;
    session.close().await.map_err(|e| TransportError::Zenoh {
        op: "close",
        key: session.zid().to_string(),
        reason: e.to_string(),
    })
}

/// Quality of service of a publisher.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Qos {
    /// State, dynamics, commands, torques: express, real-time priority, never dropped.
    HotPath,
    /// A real robot's hot path: express, real-time priority, dropped under congestion (after
    /// Zenoh's short `wait_before_drop`) rather than blocking the robot's loop; its watchdog
    /// protects the robot when messages go missing.
    NeverWait,
    /// Status and diagnostics: data priority, may be dropped under congestion.
    Telemetry,
}

/// Serialises this process's declarations (publishers, subscribers, liveliness tokens and
/// subscribers). Zenoh declares a key expression's wire id, then sends its declaration to the
/// routing tables after letting go of the session's lock: a second declaration on the same key
/// from another thread in that window reuses the id and can reach the tables first, which then
/// log "Declare keyexpr interest with unknown scope" and "Unknown wire expr" (the components of
/// an embedded run declare on one session from several threads). Declarations happen at start
/// and on changes of membership, never per tick, so the lock costs nothing on the hot path.
static DECLARATIONS: Mutex<()> = Mutex::new(());

/// Run one declaration (`f` resolves a Zenoh builder synchronously) while no other declaration
/// of this process runs.
fn declared<T>(f: impl FnOnce() -> zenoh::Result<T>) -> zenoh::Result<T> {
    let _only = DECLARATIONS.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    f()
}

/// A publisher of one message type that encodes into a reused buffer.
pub struct TypedPublisher<M> {
    publisher: Publisher<'static>,
    buffer: Vec<u8>,
    _message: PhantomData<fn(&M)>,
}

impl<M: Message> TypedPublisher<M> {
    /// Declare a publisher on `key`.
    pub async fn declare(session: &Session, key: String, qos: Qos) -> Result<Self, TransportError> {
        Self::declare_wait(session, key, qos)
    }

    /// [`TypedPublisher::declare`] for a caller outside any async runtime (or inside one).
    pub fn declare_wait(session: &Session, key: String, qos: Qos) -> Result<Self, TransportError> {
        let encoding = match M::WIRE {
            crate::codec::Wire::Json => zenoh::bytes::Encoding::APPLICATION_JSON,
            crate::codec::Wire::Binary => zenoh::bytes::Encoding::ZENOH_BYTES,
        };
        let builder = session
            .declare_publisher(key.clone())
            .encoding(encoding.with_schema(crate::codec::schema_id::<M>()));
        let builder = match qos {
            Qos::HotPath => builder
                .express(true)
                .priority(Priority::RealTime)
                .congestion_control(CongestionControl::Block),
            Qos::NeverWait => builder
                .express(true)
                .priority(Priority::RealTime)
                .congestion_control(CongestionControl::Drop),
            Qos::Telemetry => {
                builder.priority(Priority::Data).congestion_control(CongestionControl::Drop)
            }
        };
        let publisher =
            declared(|| builder.wait()).map_err(|e| zenoh_err("declare_publisher", &key, e))?;
        Ok(TypedPublisher { publisher, buffer: Vec::with_capacity(1024), _message: PhantomData })
    }

    /// Validate, encode and publish.
    pub async fn put(&mut self, msg: &M) -> Result<(), TransportError> {
        msg.validate()?;
        crate::codec::encode_into(msg, &mut self.buffer)?;
        let put = self.publisher.put(self.buffer.as_slice()).await;
        put.map_err(|e| zenoh_err("put", self.publisher.key_expr().as_str(), e))
    }

    /// [`TypedPublisher::put`] for a synchronous caller. Allocates nothing once the buffer has
    /// grown to the message's size.
    pub fn put_wait(&mut self, msg: &M) -> Result<(), TransportError> {
        msg.validate()?;
        crate::codec::encode_into(msg, &mut self.buffer)?;
        let put = self.publisher.put(self.buffer.as_slice()).wait();
        put.map_err(|e| zenoh_err("put", self.publisher.key_expr().as_str(), e))
    }

    /// Delete the key: its subscribers see that its publisher is gone for good (an agent that
    /// leaves the team deletes its dynamics key before it withdraws its token).
    pub async fn delete(&self) -> Result<(), TransportError> {
        self.delete_wait()
    }

    /// [`TypedPublisher::delete`] for a synchronous caller.
    pub fn delete_wait(&self) -> Result<(), TransportError> {
        let delete = self.publisher.delete().wait();
        delete.map_err(|e| zenoh_err("delete", self.publisher.key_expr().as_str(), e))
    }

    pub fn key(&self) -> String {
        self.publisher.key_expr().to_string()
    }
}

/// Samples a data subscription keeps before it drops its oldest ([`subscribe`]).
pub const QUEUE_CAPACITY: usize = 1024;

/// A data subscription's queue on a key expression: first in, first out, and when its reader
/// falls [`QUEUE_CAPACITY`] (or its own capacity) behind, the oldest sample is dropped.
///
/// It never blocks the publisher. Zenoh delivers a sample to a subscriber of the same session by
/// calling its handler on the publisher's thread, and a full blocking queue there stalls that
/// thread: with every component in one process (`team run` embedded), a real-time run that fell
/// behind blocked both runtime threads in such sends while the readers waited to be scheduled.
/// In lockstep nothing is ever dropped: a tick has a bounded number of messages in flight. In
/// real time a sample that old is useless anyway (the loop counts what it misses).
pub type SampleQueue = Subscriber<zenoh::handlers::RingChannelHandler<Sample>>;

/// Liveliness events (joins and leaves): first in, first out, never dropped while it is read
/// ([`watch_liveliness`]).
///
/// A watcher may go while Zenoh still delivers to it: a token's history and its declaration
/// both arrive, and the one who waited for the members drops the queue after the first. Zenoh
/// undeclares a dropped subscriber without waiting for a delivery in progress, and its own FIFO
/// handler logs an ERROR for an event sent to a reader that is gone; this queue lets it go.
pub type EventQueue = Subscriber<flume::Receiver<Sample>>;

/// Subscribe to `key` with a queue of [`QUEUE_CAPACITY`] samples ([`SampleQueue`]).
pub async fn subscribe(session: &Session, key: String) -> Result<SampleQueue, TransportError> {
    subscribe_with_capacity(session, key, QUEUE_CAPACITY).await
}

/// Subscribe to `key` with a queue of `capacity` samples: a publisher that sends a burst, such as
/// a whole run's references, or a reader that must not lose any (the run's recorder), needs more.
pub async fn subscribe_with_capacity(
    session: &Session,
    key: String,
    capacity: usize,
) -> Result<SampleQueue, TransportError> {
    let builder =
        session.declare_subscriber(key.clone()).with(zenoh::handlers::RingChannel::new(capacity));
    declared(|| builder.wait()).map_err(|e| zenoh_err("declare_subscriber", &key, e))
}

/// [`subscribe_with_capacity`] for a synchronous reader: `notify` is called after each sample
/// is queued (on Zenoh's thread: it must be short and never block), so that a loop waiting
/// for any of several queues can wake up.
pub fn subscribe_notifying(
    session: &Session,
    key: String,
    capacity: usize,
    notify: impl Fn() + Send + Sync + 'static,
) -> Result<SampleQueue, TransportError> {
    let (queue, handler) = RingChannel::new(capacity).into_handler();
    let callback = move |sample: Sample| {
        queue.call(sample);
        notify();
    };
    let builder = session.declare_subscriber(key.clone()).with((callback, handler));
    declared(|| builder.wait()).map_err(|e| zenoh_err("declare_subscriber", &key, e))
}

/// Decode a sample's payload as `M`, and refuse it when its header names another sender than
/// its key ([`keys::check_sender`]): every component takes a message's team and robot from
/// its header only once the key it came on agrees.
pub fn decode_sample<M: Message>(sample: &Sample) -> Result<M, ProtocolError> {
    let bytes = sample.payload().to_bytes();
    let msg = decode::<M>(&bytes)?;
    keys::check_sender(sample.key_expr().as_str(), msg.header())?;
    Ok(msg)
}

/// A membership change seen through liveliness.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum MemberEvent {
    Joined(String),
    Left(String),
}

impl MemberEvent {
    /// The event a liveliness sample describes, if its key is a member token.
    pub fn from_sample(sample: &Sample) -> Option<Self> {
        let robot = keys::robot_of(sample.key_expr().as_str())?.to_string();
        Some(match sample.kind() {
            SampleKind::Put => MemberEvent::Joined(robot),
            SampleKind::Delete => MemberEvent::Left(robot),
        })
    }
}

/// Declare this robot's membership token; membership lasts as long as the token lives.
pub async fn declare_member(
    session: &Session,
    team: &str,
    robot: &str,
) -> Result<zenoh::liveliness::LivelinessToken, TransportError> {
    declare_token(session, keys::member(team, robot)?).await
}

/// Watch the team's membership: current members first (history), then joins and leaves.
pub async fn watch_members(session: &Session, team: &str) -> Result<EventQueue, TransportError> {
    watch_liveliness(session, keys::all_members(team)?).await
}

/// Declare the coordinator's liveliness token; it is alive as long as the token lives.
pub async fn declare_coordinator(
    session: &Session,
    team: &str,
) -> Result<zenoh::liveliness::LivelinessToken, TransportError> {
    declare_token(session, keys::coordinator_alive(team)?).await
}

/// Watch the coordinator's liveliness: a `Put` sample when it is (or comes) alive, a `Delete`
/// when it goes ([`coordinator_alive`]).
pub async fn watch_coordinator(
    session: &Session,
    team: &str,
) -> Result<EventQueue, TransportError> {
    watch_liveliness(session, keys::coordinator_alive(team)?).await
}

/// A liveliness token on `key`.
async fn declare_token(
    session: &Session,
    key: String,
) -> Result<zenoh::liveliness::LivelinessToken, TransportError> {
    let liveliness = session.liveliness();
    declared(|| liveliness.declare_token(key.clone()).wait())
        .map_err(|e| zenoh_err("declare_token", &key, e))
}

/// The liveliness tokens on `key` (wildcards allowed): those present first (history), then
/// their comings and goings (a `Put` sample when one comes, a `Delete` when it goes).
pub async fn watch_liveliness(
    session: &Session,
    key: String,
) -> Result<EventQueue, TransportError> {
    let liveliness = session.liveliness();
    let builder = liveliness.declare_subscriber(key.clone()).history(true);
    declared(|| builder.with(event_channel()).wait())
        .map_err(|e| zenoh_err("liveliness subscriber", &key, e))
}

/// An unbounded channel whose sending side ignores a reader that is gone ([`EventQueue`]).
fn event_channel() -> (impl Fn(Sample) + Send + Sync + 'static, flume::Receiver<Sample>) {
    let (sender, receiver) = flume::unbounded();
    (move |sample| drop(sender.send(sample)), receiver)
}

/// [`watch_liveliness`] for a synchronous reader, with [`subscribe_notifying`]'s `notify`;
/// the oldest events are dropped beyond `capacity`.
pub fn watch_liveliness_notifying(
    session: &Session,
    key: String,
    capacity: usize,
    notify: impl Fn() + Send + Sync + 'static,
) -> Result<SampleQueue, TransportError> {
    let (queue, handler) = RingChannel::new(capacity).into_handler();
    let callback = move |sample: Sample| {
        queue.call(sample);
        notify();
    };
    let liveliness = session.liveliness();
    let builder =
        liveliness.declare_subscriber(key.clone()).history(true).with((callback, handler));
    declared(|| builder.wait()).map_err(|e| zenoh_err("liveliness subscriber", &key, e))
}

/// [`declare_member`] for a synchronous caller.
pub fn declare_member_wait(
    session: &Session,
    team: &str,
    robot: &str,
) -> Result<zenoh::liveliness::LivelinessToken, TransportError> {
    let key = keys::member(team, robot)?;
    let liveliness = session.liveliness();
    declared(|| liveliness.declare_token(key.clone()).wait())
        .map_err(|e| zenoh_err("declare_token", &key, e))
}

/// Whether a sample of [`watch_coordinator`] says the coordinator is alive.
pub fn coordinator_alive(sample: &Sample) -> bool {
    sample.kind() == SampleKind::Put
}

fn zenoh_err(op: &'static str, key: &str, e: impl std::fmt::Display) -> TransportError {
    TransportError::Zenoh { op, key: key.to_string(), reason: e.to_string() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_loopback_peer_without_multicast() {
        let hub = ZenohArgs::default().to_config(Role::Hub).unwrap();
        let s = format!("{hub:?}");
        assert!(s.contains("127.0.0.1:7447"));
        let json = hub.get_json("scouting/multicast/enabled").unwrap();
        assert_eq!(json, "false");
        assert_eq!(hub.get_json("mode").unwrap(), "\"peer\"");
        let member = ZenohArgs::default().to_config(Role::Member).unwrap();
        assert!(member.get_json("connect/endpoints").unwrap().contains("127.0.0.1:7447"));
        assert_eq!(member.get_json("listen/endpoints").unwrap(), "[\"tcp/127.0.0.1:0\"]");
        let alone = ZenohArgs::default().to_config(Role::Alone).unwrap();
        assert_eq!(alone.get_json("listen/endpoints").unwrap(), "[]");
        assert_eq!(alone.get_json("connect/endpoints").unwrap(), "[]");
        let tool = ZenohArgs::default().to_config(Role::Tool).unwrap();
        let connects = tool.get_json("connect/endpoints").unwrap();
        assert!(connects.contains("127.0.0.1:7449") && connects.contains("127.0.0.1:7447"));
        assert_eq!(TOOLS_ENDPOINT, format!("tcp/127.0.0.1:{TOOLS_PORT}"));
    }

    /// Runs set up by a configuration file (TLS, sites: the file's access control) and clients
    /// never get the tools' plain TCP port; nor do arguments that already listen there.
    #[test]
    fn the_tools_port_is_added_only_where_no_configuration_decides() {
        let file = ZenohArgs { config: Some("zenoh-tls.json5".into()), ..ZenohArgs::default() };
        assert!(file.discoverable(Role::Member).is_none());
        let client = ZenohArgs { mode: Some(Mode::Client), ..ZenohArgs::default() };
        assert!(client.discoverable(Role::Member).is_none());
        let named = ZenohArgs::listening(TOOLS_ENDPOINT);
        assert!(named.discoverable(Role::Alone).is_none());
        // Where the port is free, the role's own endpoints stay and the tools' is added.
        if let Some(args) = ZenohArgs::default().discoverable(Role::Member) {
            assert_eq!(args.listen, ["tcp/127.0.0.1:0", TOOLS_ENDPOINT]);
        }
    }

    #[test]
    fn flags_override_and_bad_values_are_errors() {
        let a = ZenohArgs {
            mode: Some(Mode::Client),
            connect: vec!["tcp/10.0.0.2:7447".into()],
            ..Default::default()
        };
        let c = a.to_config(Role::Hub).unwrap();
        assert_eq!(c.get_json("mode").unwrap(), "\"client\"");
        assert!(c.get_json("connect/endpoints").unwrap().contains("10.0.0.2"));
        let bad = ZenohArgs { listen: vec!["not an endpoint".into()], ..Default::default() };
        assert!(bad.to_config(Role::Hub).is_err());
        let missing =
            ZenohArgs { config: Some("/nonexistent/zenoh.json5".into()), ..Default::default() };
        assert!(matches!(missing.to_config(Role::Hub), Err(TransportError::ConfigFile { .. })));
        let round = ZenohArgs::from_cli_for_test(&a.to_cli());
        assert_eq!(round.connect, a.connect);
    }

    impl ZenohArgs {
        fn from_cli_for_test(args: &[String]) -> ZenohArgs {
            use clap::Parser;
            #[derive(clap::Parser)]
            struct Cli {
                #[command(flatten)]
                z: ZenohArgs,
            }
            let mut v = vec!["x".to_string()];
            v.extend_from_slice(args);
            Cli::parse_from(v).z
        }
    }
}
