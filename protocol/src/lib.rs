//! # protocol: what the team says to itself
//!
//! Every component of the team (robot agents, the coordinator, the sim-bridge, tools) talks
//! through the types, key expressions and encodings of this crate, and through nothing else.
//!
//! ## Conventions (fixed here, once)
//!
//! See [`conventions`]: SI units, world z up, gravity 9.81 m/s² downward; quaternions are
//! `(w, x, y, z)`; wrenches are `[force; moment]`; a robot's generalized velocity is
//! `[base linear velocity in the base frame; base angular velocity in the base frame; joint
//! velocities]` (Pinocchio's convention). MuJoCo's free joint uses a different convention
//! (linear velocity in the world frame); the only conversion lives in
//! [`conventions::base_twist_from_mujoco`] and [`conventions::base_twist_to_mujoco`].
//!
//! ## Key-expression tree
//!
//! Built only by the functions of [`keys`]; `{team}` and `{robot}` are validated identifiers
//! (`[A-Za-z0-9_-]{1,64}`).
//!
//! Every key is under `team/{team}/` (left out of the table).
//!
//! | key | message | publisher → subscriber |
//! | --- | --- | --- |
//! | `robot/{robot}/state` | [`RobotState`] | state source (sim-bridge) → agent |
//! | `robot/{robot}/dynamics` | [`DynamicsTerms`] | agent → coordinator |
//! | `robot/{robot}/command` | [`TorqueCommand`] (torques, or a hold order) | coordinator → agent |
//! | `robot/{robot}/torque` | [`DriveCommand`] (checked) | agent → its drives (sim-bridge) |
//! | `robot/{robot}/status` | [`AgentStatus`] | agent → tools |
//! | `robot/{robot}/description` | [`RobotDescription`] | agent → coordinator, tools (queryable) |
//! | `member/{robot}` | liveliness token | agent → coordinator |
//! | `coordinator/status` | [`CoordinatorStatus`] | coordinator → tools |
//! | `coordinator/diagnostics` | [`TickDiagnostics`] | coordinator → reports |
//! | `coordinator/alive` | liveliness token | coordinator → agents, sim-bridge |
//! | `references` | [`TaskReferences`] | scenario runner → coordinator |
//! | `perturbation` | [`PerturbationRequest`] | tools → sim-bridge |
//! | `robot/{robot}/contacts` | [`ContactSet`] | runner, gait planner → agent |
//! | `ground-truth` | [`GroundTruth`] | sim-bridge → evaluation (never the controller) |
//!
//! Wildcards for subscribers (`team/{team}/robot/*/dynamics`, `team/{team}/member/*`) come
//! from the same module.
//!
//! ## Encodings
//!
//! * **Binary, for the hot path** ([`encode`], [`decode`]): a 6-byte envelope (magic `b"TQ"`,
//!   protocol version `u16` little-endian, message kind `u8`, reserved `u8`) followed by the
//!   message in bincode 1 with variable-length integers and little-endian IEEE-754 floats.
//!   *Size*: the payload is dominated by `f64` arrays (a 24-DoF robot's mass matrix alone is
//!   4.6 KiB), which bincode writes as raw 8-byte values with no per-field names or tags, so a
//!   dynamics message is within a few percent of the raw numbers; self-describing formats
//!   (JSON, CBOR, MessagePack) repeat field names and, for JSON, print every float as text
//!   (three times the size, and slow to parse). *Speed*: encoding is a serde walk with
//!   `memcpy`-like float writes, microseconds for the largest message. *Schema evolution*:
//!   bincode is positional, so compatibility is by explicit version: every envelope carries
//!   [`PROTOCOL_VERSION`] and the kind; a decoder rejects another version with a typed error
//!   instead of misreading bytes. Changing any message bumps the version; components of one
//!   team must run the same version (the coordinator names the offending robot).
//! * **JSON, for tools** ([`to_json`], [`from_json`]): the same types, human readable; the
//!   version travels in every [`Header`]. The tool-facing keys travel in JSON on the wire too
//!   ([`Wire`]: status, diagnostics, ground truth, references, perturbations, descriptions),
//!   with the Zenoh encoding `application/json;team.<Name>/v<version>` and the JSON Schemas
//!   published in `protocol/schemas/` (generated from the types, checked by a test), so any
//!   Zenoh client in any language reads them. The hot path (state, dynamics terms, torque
//!   commands, contact sets) stays binary, `zenoh/bytes;team.<Name>/v<version>`, its layout
//!   written out byte for byte in `protocol/WIRE.md`.
//!
//! Decoding never panics and never trusts its input: the envelope, a size limit
//! ([`MAX_MESSAGE_BYTES`]), trailing bytes, the version, identifiers, every dimension against
//! the others and every number's finiteness are checked ([`Validate`]); failures are typed
//! [`ProtocolError`]s.

#[cfg(feature = "transport")]
pub mod access;
pub mod clock;
pub mod codec;
pub mod conventions;
pub mod error;
pub mod keys;
#[cfg(feature = "transport")]
pub mod logging;
pub mod matrix;
pub mod messages;
#[cfg(feature = "transport")]
pub mod site;
#[cfg(feature = "transport")]
pub mod transport;
pub mod validate;

pub use clock::RunClock;
pub use codec::{
    decode, encode, from_json, schema_id, to_json, Message, MessageKind, Wire, MAX_MESSAGE_BYTES,
};
pub use error::ProtocolError;
pub use matrix::Matrix;
pub use messages::*;
pub use validate::{validate_id, Validate};

/// Version of the wire protocol. Bump it whenever a message type changes.
pub const PROTOCOL_VERSION: u16 = 6;

/// Wall-clock time in nanoseconds since the Unix epoch, for [`Header::stamp_ns`] (0 if the
/// clock is before the epoch).
pub fn wall_clock_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}
