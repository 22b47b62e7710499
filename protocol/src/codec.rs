//! Binary (hot path) and JSON (tools) encodings. See the crate docs for the format and why.
//! Which one a message travels in is fixed per type ([`Message::WIRE`]): the hot path
//! (state, dynamics terms, torque commands, contact sets) is binary, documented byte for byte
//! in `protocol/WIRE.md`; what tools read (status, diagnostics, ground truth, references,
//! perturbations, descriptions) is JSON with a published JSON Schema
//! (`protocol/schemas/<Name>.json`).

use bincode::Options;
use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::messages::*;
use crate::{ProtocolError, Validate, PROTOCOL_VERSION};

/// Largest accepted message. A 64-DoF robot's dynamics terms are about 40 KiB; this bounds what
/// a malformed length prefix can make the decoder allocate.
pub const MAX_MESSAGE_BYTES: usize = 4 << 20;

const MAGIC: [u8; 2] = *b"TQ";
const ENVELOPE: usize = 6;

/// The message types, as numbered on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum MessageKind {
    RobotState = 1,
    DynamicsTerms = 2,
    TorqueCommand = 3,
    TaskReferences = 4,
    PerturbationRequest = 5,
    CoordinatorStatus = 6,
    TickDiagnostics = 7,
    AgentStatus = 8,
    RobotDescription = 9,
    ContactSet = 10,
    GroundTruth = 11,
    DriveCommand = 12,
}

/// How a message type travels on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wire {
    /// The 6-byte envelope and bincode (see the crate docs and `protocol/WIRE.md`); Zenoh
    /// encoding `zenoh/bytes;team.<Name>/v<version>`.
    Binary,
    /// Compact JSON of the message (its JSON Schema: `protocol/schemas/<Name>.json`); Zenoh
    /// encoding `application/json;team.<Name>/v<version>`. The version is the header's.
    Json,
}

/// A message that travels: it has a kind, a wire format, a header and can validate itself.
pub trait Message: Serialize + DeserializeOwned + Validate {
    const KIND: MessageKind;
    const NAME: &'static str;
    const WIRE: Wire;
    fn header(&self) -> &Header;
}

macro_rules! message {
    ($t:ident, $wire:ident) => {
        impl Message for $t {
            const KIND: MessageKind = MessageKind::$t;
            const NAME: &'static str = stringify!($t);
            const WIRE: Wire = Wire::$wire;
            fn header(&self) -> &Header {
                &self.header
            }
        }
    };
}
message!(RobotState, Binary);
message!(DynamicsTerms, Binary);
message!(TorqueCommand, Binary);
message!(ContactSet, Binary);
message!(DriveCommand, Binary);
message!(TaskReferences, Json);
message!(PerturbationRequest, Json);
message!(CoordinatorStatus, Json);
message!(TickDiagnostics, Json);
message!(AgentStatus, Json);
message!(RobotDescription, Json);
message!(GroundTruth, Json);

/// The schema part of a message's Zenoh encoding: `team.<Name>/v<version>`.
pub fn schema_id<M: Message>() -> String {
    format!("team.{}/v{PROTOCOL_VERSION}", M::NAME)
}

fn options() -> impl Options {
    bincode::DefaultOptions::new()
        .with_varint_encoding()
        .with_little_endian()
        .with_limit(MAX_MESSAGE_BYTES as u64)
        .reject_trailing_bytes()
}

/// Validate and encode for the wire.
pub fn encode<M: Message>(msg: &M) -> Result<Vec<u8>, ProtocolError> {
    msg.validate()?;
    let mut out = Vec::with_capacity(ENVELOPE + 256);
    encode_into(msg, &mut out)?;
    Ok(out)
}

/// Encode into a reusable buffer (cleared first), without validating: for senders that have
/// already validated what they built.
pub fn encode_into<M: Message>(msg: &M, out: &mut Vec<u8>) -> Result<(), ProtocolError> {
    out.clear();
    if M::WIRE == Wire::Json {
        serde_json::to_writer(&mut *out, msg)
            .map_err(|e| ProtocolError::Malformed { kind: M::NAME, reason: e.to_string() })?;
        if out.len() > MAX_MESSAGE_BYTES {
            return Err(ProtocolError::Oversized { len: out.len(), max: MAX_MESSAGE_BYTES });
        }
        return Ok(());
    }
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&PROTOCOL_VERSION.to_le_bytes());
    out.push(M::KIND as u8);
    out.push(0);
    options()
        .serialize_into(&mut *out, msg)
        .map_err(|e| ProtocolError::Malformed { kind: M::NAME, reason: e.to_string() })?;
    if out.len() > MAX_MESSAGE_BYTES {
        return Err(ProtocolError::Oversized { len: out.len(), max: MAX_MESSAGE_BYTES });
    }
    Ok(())
}

/// Decode and validate a wire message of type `M`.
pub fn decode<M: Message>(bytes: &[u8]) -> Result<M, ProtocolError> {
    if bytes.len() < ENVELOPE {
        return Err(ProtocolError::Truncated { len: bytes.len(), min: ENVELOPE });
    }
    if bytes.len() > MAX_MESSAGE_BYTES {
        return Err(ProtocolError::Oversized { len: bytes.len(), max: MAX_MESSAGE_BYTES });
    }
    if M::WIRE == Wire::Json {
        return decode_json(bytes);
    }
    if bytes[0..2] != MAGIC {
        return Err(ProtocolError::BadMagic { found: [bytes[0], bytes[1]] });
    }
    let version = u16::from_le_bytes([bytes[2], bytes[3]]);
    if version != PROTOCOL_VERSION {
        return Err(ProtocolError::VersionMismatch { found: version, expected: PROTOCOL_VERSION });
    }
    if bytes[4] != M::KIND as u8 {
        return Err(ProtocolError::WrongKind { expected: M::NAME, found: bytes[4] });
    }
    let msg: M = options()
        .deserialize(&bytes[ENVELOPE..])
        .map_err(|e| ProtocolError::Malformed { kind: M::NAME, reason: e.to_string() })?;
    msg.validate()?;
    Ok(msg)
}

/// A JSON wire message: the version in its header must be ours.
fn decode_json<M: Message>(bytes: &[u8]) -> Result<M, ProtocolError> {
    let msg: M = serde_json::from_slice(bytes)
        .map_err(|e| ProtocolError::Malformed { kind: M::NAME, reason: e.to_string() })?;
    let version = msg.header().version;
    if version != PROTOCOL_VERSION {
        return Err(ProtocolError::VersionMismatch { found: version, expected: PROTOCOL_VERSION });
    }
    msg.validate()?;
    Ok(msg)
}

/// Decode a wire message of `kind` (either wire format) into its JSON value, for tools that
/// print any key (`team echo`).
pub fn decode_to_json(kind: MessageKind, bytes: &[u8]) -> Result<serde_json::Value, ProtocolError> {
    fn value<M: Message>(bytes: &[u8]) -> Result<serde_json::Value, ProtocolError> {
        serde_json::to_value(decode::<M>(bytes)?).map_err(|e| ProtocolError::Json(e.to_string()))
    }
    match kind {
        MessageKind::RobotState => value::<RobotState>(bytes),
        MessageKind::DynamicsTerms => value::<DynamicsTerms>(bytes),
        MessageKind::TorqueCommand => value::<TorqueCommand>(bytes),
        MessageKind::TaskReferences => value::<TaskReferences>(bytes),
        MessageKind::PerturbationRequest => value::<PerturbationRequest>(bytes),
        MessageKind::CoordinatorStatus => value::<CoordinatorStatus>(bytes),
        MessageKind::TickDiagnostics => value::<TickDiagnostics>(bytes),
        MessageKind::AgentStatus => value::<AgentStatus>(bytes),
        MessageKind::RobotDescription => value::<RobotDescription>(bytes),
        MessageKind::ContactSet => value::<ContactSet>(bytes),
        MessageKind::GroundTruth => value::<GroundTruth>(bytes),
        MessageKind::DriveCommand => value::<DriveCommand>(bytes),
    }
}

/// Validate and encode as pretty JSON, for tools and files.
pub fn to_json<M: Message>(msg: &M) -> Result<String, ProtocolError> {
    msg.validate()?;
    serde_json::to_string_pretty(msg).map_err(|e| ProtocolError::Json(e.to_string()))
}

/// Decode JSON and validate.
pub fn from_json<M: Message>(text: &str) -> Result<M, ProtocolError> {
    if text.len() > MAX_MESSAGE_BYTES * 4 {
        return Err(ProtocolError::Oversized { len: text.len(), max: MAX_MESSAGE_BYTES * 4 });
    }
    let msg: M = serde_json::from_str(text).map_err(|e| ProtocolError::Json(e.to_string()))?;
    msg.validate()?;
    Ok(msg)
}
