//! The synchronous loop's connection to its team: what the Zenoh shell's publishers and
//! subscribers are to [`crate::agent`], without `async` and without blocking the robot's
//! cycle. [`ZenohLink`] is the one over Zenoh; tests may put the team in memory.

use std::marker::PhantomData;
use std::time::Instant;

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, TransportError};
use protocol::{AgentStatus, ContactSet, DynamicsTerms, Message, RobotDescription, TorqueCommand};
use zenoh::handlers::{RingChannel, RingChannelHandler};
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::sample::Sample;
use zenoh::{Session, Wait};

/// Commands and contact sets kept while the loop is busy; the oldest are dropped beyond.
pub const INBOX: usize = 64;

/// What a receive yields.
#[derive(Debug, Clone, PartialEq)]
pub enum Inbound<M> {
    Message(M),
    /// Something arrived that does not decode (the reason, for the log).
    Undecodable(String),
    /// Nothing arrived in time.
    Empty,
}

/// A change of the coordinator's presence, as its liveliness token says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Presence {
    /// Its token appeared: it started, came back after a restart, or its link did.
    Came,
    /// Its token went: it stopped, or its link dropped (it may come back).
    Went,
}

/// The team as the synchronous loop sees it. Sending never blocks (a message may be dropped
/// under congestion, and the error is for the log: the loop carries on and its watchdog
/// protects the robot); receiving waits at most until the deadline given.
pub trait TeamLink {
    fn send_terms(&mut self, terms: &DynamicsTerms) -> Result<(), TransportError>;
    fn send_status(&mut self, status: &AgentStatus) -> Result<(), TransportError>;
    fn send_description(&mut self, description: &RobotDescription) -> Result<(), TransportError>;
    /// The next command, waiting until `deadline` at most.
    fn recv_command(&mut self, deadline: Instant) -> Inbound<TorqueCommand>;
    /// The next contact set, if one is waiting.
    fn try_recv_contacts(&mut self) -> Inbound<ContactSet>;
    /// The next change of the coordinator's presence, if one is waiting.
    fn try_recv_coordinator(&mut self) -> Option<Presence>;
    /// Withdraw the robot's team membership (it fell, [`crate::fall`]), saying so first (its
    /// dynamics key deleted): the coordinator then solves the team without it at once. Called
    /// once.
    fn leave_team(&mut self) -> Result<(), TransportError>;
}

/// A publisher of one message type for a synchronous caller: validates, encodes into a reused
/// buffer, and puts without waiting (congestion control `Drop`, express, real-time priority).
pub struct SyncPublisher<M> {
    publisher: Publisher<'static>,
    buffer: Vec<u8>,
    _message: PhantomData<fn(&M)>,
}

impl<M: Message> SyncPublisher<M> {
    pub fn declare(
        session: &Session,
        key: String,
        priority: Priority,
    ) -> Result<Self, TransportError> {
        let publisher = session
            .declare_publisher(key.clone())
            .express(true)
            .priority(priority)
            .congestion_control(CongestionControl::Drop)
            .wait()
            .map_err(|e| zenoh_err("declare_publisher", &key, e))?;
        Ok(SyncPublisher { publisher, buffer: Vec::with_capacity(1024), _message: PhantomData })
    }

    pub fn put(&mut self, msg: &M) -> Result<(), TransportError> {
        msg.validate()?;
        protocol::codec::encode_into(msg, &mut self.buffer)?;
        self.publisher
            .put(self.buffer.as_slice())
            .wait()
            .map_err(|e| zenoh_err("put", self.publisher.key_expr().as_str(), e))
    }

    /// Delete the key: its publisher is gone for good.
    pub fn delete(&mut self) -> Result<(), TransportError> {
        self.publisher
            .delete()
            .wait()
            .map_err(|e| zenoh_err("delete", self.publisher.key_expr().as_str(), e))
    }
}

/// The team over Zenoh: the robot's `command` and `contacts` keys and the coordinator's
/// liveliness token in (each a ring of [`INBOX`] samples that never blocks Zenoh), `dynamics`,
/// `status` and `description` out, and the membership token. Declare it from a thread outside
/// any async runtime (it uses Zenoh's blocking API).
pub struct ZenohLink {
    commands: Subscriber<RingChannelHandler<Sample>>,
    contacts: Subscriber<RingChannelHandler<Sample>>,
    coordinator: Subscriber<RingChannelHandler<Sample>>,
    dynamics: SyncPublisher<DynamicsTerms>,
    status: SyncPublisher<AgentStatus>,
    description: SyncPublisher<RobotDescription>,
    /// The membership, until [`TeamLink::leave_team`].
    token: Option<LivelinessToken>,
}

impl ZenohLink {
    /// Subscribe, declare the publishers, then join the team (so that whoever sees the robot
    /// join can already reach it).
    pub fn declare(session: &Session, team: &str, robot: &str) -> Result<Self, TransportError> {
        let key = |t| keys::robot(team, robot, t);
        let subscribe = |key: String| {
            session
                .declare_subscriber(key.clone())
                .with(RingChannel::new(INBOX))
                .wait()
                .map_err(|e| zenoh_err("declare_subscriber", &key, e))
        };
        let commands = subscribe(key(RobotTopic::Command)?)?;
        let contacts = subscribe(keys::contacts(team, robot)?)?;
        // A coordinator already present is reported first (history), as the async agent's
        // `transport::watch_coordinator` does.
        let alive = keys::coordinator_alive(team)?;
        let coordinator = session
            .liveliness()
            .declare_subscriber(alive.clone())
            .history(true)
            .with(RingChannel::new(INBOX))
            .wait()
            .map_err(|e| zenoh_err("declare_liveliness_subscriber", &alive, e))?;
        let dynamics =
            SyncPublisher::declare(session, key(RobotTopic::Dynamics)?, Priority::RealTime)?;
        let status = SyncPublisher::declare(session, key(RobotTopic::Status)?, Priority::Data)?;
        let description =
            SyncPublisher::declare(session, key(RobotTopic::Description)?, Priority::Data)?;
        let member = keys::member(team, robot)?;
        let token = session
            .liveliness()
            .declare_token(member.clone())
            .wait()
            .map_err(|e| zenoh_err("declare_token", &member, e))?;
        Ok(ZenohLink {
            commands,
            contacts,
            coordinator,
            dynamics,
            status,
            description,
            token: Some(token),
        })
    }
}

impl TeamLink for ZenohLink {
    fn send_terms(&mut self, terms: &DynamicsTerms) -> Result<(), TransportError> {
        self.dynamics.put(terms)
    }

    fn send_status(&mut self, status: &AgentStatus) -> Result<(), TransportError> {
        self.status.put(status)
    }

    fn send_description(&mut self, description: &RobotDescription) -> Result<(), TransportError> {
        self.description.put(description)
    }

    fn recv_command(&mut self, deadline: Instant) -> Inbound<TorqueCommand> {
        inbound(self.commands.handler().recv_deadline(deadline))
    }

    fn try_recv_contacts(&mut self) -> Inbound<ContactSet> {
        inbound(self.contacts.handler().try_recv())
    }

    fn try_recv_coordinator(&mut self) -> Option<Presence> {
        match self.coordinator.handler().try_recv() {
            Ok(Some(sample)) if transport::coordinator_alive(&sample) => Some(Presence::Came),
            Ok(Some(_)) => Some(Presence::Went),
            // A closed subscriber reports nothing more: the command deadline still holds the
            // robot if the commands stop.
            Ok(None) | Err(_) => None,
        }
    }

    fn leave_team(&mut self) -> Result<(), TransportError> {
        match self.token.take() {
            Some(t) => {
                // Said first: a token that vanishes alone may be a link that comes back, which
                // the coordinator waits for (`coordinator::team::membership::DEPARTURE_GRACE`).
                self.dynamics.delete()?;
                t.undeclare().wait().map_err(|e| zenoh_err("undeclare_token", "member", e))
            }
            None => Ok(()),
        }
    }
}

impl Drop for ZenohLink {
    /// The link dropped with its token still held (the robot's owner is done with it): the
    /// leaving is said first, as [`TeamLink::leave_team`] says it, then the token goes with it.
    fn drop(&mut self) {
        if self.token.is_some() {
            if let Err(e) = self.dynamics.delete() {
                tracing::warn!("leaving not announced: {e}");
            }
        }
    }
}

fn inbound<M: Message, E>(r: Result<Option<Sample>, E>) -> Inbound<M> {
    match r {
        Ok(Some(sample)) => match decode_sample::<M>(&sample) {
            Ok(m) => Inbound::Message(m),
            Err(e) => Inbound::Undecodable(e.to_string()),
        },
        // A closed subscriber gives nothing more: the watchdog takes it from there.
        Ok(None) | Err(_) => Inbound::Empty,
    }
}

fn zenoh_err(op: &'static str, key: &str, e: impl std::fmt::Display) -> TransportError {
    TransportError::Zenoh { op, key: key.to_string(), reason: e.to_string() }
}
