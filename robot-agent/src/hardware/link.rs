//! The loop's connection to its team, without `async` and without blocking the robot's
//! cycle: terms, status and description out; commands, contact sets and the coordinator's
//! presence in, each waking the loop's [`Bell`]. [`ZenohLink`] is the one over Zenoh; tests
//! may put the team in memory.

use std::time::Instant;

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, SampleQueue, TransportError, TypedPublisher};
use protocol::{AgentStatus, ContactSet, DynamicsTerms, Message, RobotDescription, TorqueCommand};
use zenoh::liveliness::LivelinessToken;
use zenoh::sample::Sample;
use zenoh::{Session, Wait};

use super::bell::Bell;

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

/// The team as the robot's loop sees it. Sending does not wait on the network beyond the
/// link's QoS (a message may be dropped under congestion, and the error is for the log: the
/// loop carries on and its watchdog protects the robot); receiving never waits, and
/// [`TeamLink::wait`] is the loop's one bounded wait.
pub trait TeamLink {
    fn send_terms(&mut self, terms: &DynamicsTerms) -> Result<(), TransportError>;
    fn send_status(&mut self, status: &AgentStatus) -> Result<(), TransportError>;
    fn send_description(&mut self, description: &RobotDescription) -> Result<(), TransportError>;
    /// Wait until something arrives (here or at the robot, when it shares the link's bell) or
    /// until `deadline`, whichever comes first.
    fn wait(&mut self, deadline: Instant);
    /// The next command, if one is waiting.
    fn try_recv_command(&mut self) -> Inbound<TorqueCommand>;
    /// The next contact set, if one is waiting.
    fn try_recv_contacts(&mut self) -> Inbound<ContactSet>;
    /// The next change of the coordinator's presence, if one is waiting.
    fn try_recv_coordinator(&mut self) -> Option<Presence>;
    /// Withdraw the robot's team membership (it fell, [`crate::fall`]), saying so first (its
    /// dynamics key deleted): the coordinator then solves the team without it at once. Called
    /// once.
    fn leave_team(&mut self) -> Result<(), TransportError>;
}

/// The team over Zenoh: the robot's `command` and `contacts` keys and the coordinator's
/// liveliness token in (each a ring of [`INBOX`] samples that never blocks Zenoh and rings the
/// link's [`Bell`]), `dynamics`, `status` and `description` out, and the membership token.
pub struct ZenohLink {
    commands: SampleQueue,
    contacts: SampleQueue,
    coordinator: SampleQueue,
    dynamics: TypedPublisher<DynamicsTerms>,
    status: TypedPublisher<AgentStatus>,
    description: TypedPublisher<RobotDescription>,
    bell: Bell,
    /// The membership, until [`TeamLink::leave_team`].
    token: Option<LivelinessToken>,
}

impl ZenohLink {
    /// Subscribe, declare the publishers (the terms with `hot`: [`Qos::HotPath`] in a
    /// simulation, where a lockstep tick must lose nothing; [`Qos::NeverWait`] on a real
    /// robot), then join the team, so that whoever sees the robot join can already reach it.
    pub fn declare(
        session: &Session,
        team: &str,
        robot: &str,
        hot: Qos,
    ) -> Result<Self, TransportError> {
        Self::declare_with_bell(session, team, robot, hot, Bell::new())
    }

    /// [`ZenohLink::declare`] ringing `bell`, shared with a robot that sends its own states
    /// (declared first, so that the robot's states are already subscribed when it joins).
    pub fn declare_with_bell(
        session: &Session,
        team: &str,
        robot: &str,
        hot: Qos,
        bell: Bell,
    ) -> Result<Self, TransportError> {
        let key = |t| keys::robot(team, robot, t);
        let ring = |b: &Bell| {
            let b = b.clone();
            move || b.ring()
        };
        let commands =
            transport::subscribe_notifying(session, key(RobotTopic::Command)?, INBOX, ring(&bell))?;
        let contacts = transport::subscribe_notifying(
            session,
            keys::contacts(team, robot)?,
            INBOX,
            ring(&bell),
        )?;
        // A coordinator already present is reported first (history).
        let alive = keys::coordinator_alive(team)?;
        let coordinator =
            transport::watch_liveliness_notifying(session, alive, INBOX, ring(&bell))?;
        let dynamics = TypedPublisher::declare_wait(session, key(RobotTopic::Dynamics)?, hot)?;
        let status =
            TypedPublisher::declare_wait(session, key(RobotTopic::Status)?, Qos::Telemetry)?;
        let description =
            TypedPublisher::declare_wait(session, key(RobotTopic::Description)?, Qos::Telemetry)?;
        let token = Some(transport::declare_member_wait(session, team, robot)?);
        Ok(ZenohLink {
            commands,
            contacts,
            coordinator,
            dynamics,
            status,
            description,
            bell,
            token,
        })
    }

    /// The bell the link rings: a robot whose states arrive on their own (a simulator) rings
    /// it too, so that the loop waits for both at once.
    pub fn bell(&self) -> Bell {
        self.bell.clone()
    }
}

impl TeamLink for ZenohLink {
    fn send_terms(&mut self, terms: &DynamicsTerms) -> Result<(), TransportError> {
        self.dynamics.put_wait(terms)
    }

    fn send_status(&mut self, status: &AgentStatus) -> Result<(), TransportError> {
        self.status.put_wait(status)
    }

    fn send_description(&mut self, description: &RobotDescription) -> Result<(), TransportError> {
        self.description.put_wait(description)
    }

    fn wait(&mut self, deadline: Instant) {
        self.bell.wait_until(deadline);
    }

    fn try_recv_command(&mut self) -> Inbound<TorqueCommand> {
        inbound(self.commands.handler().try_recv())
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
                self.dynamics.delete_wait()?;
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
            if let Err(e) = self.dynamics.delete_wait() {
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
