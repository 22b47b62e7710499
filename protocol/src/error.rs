//! Typed errors of decoding and validation.

use thiserror::Error;

/// Everything that can be wrong with a message. Decoding returns these; it never panics.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ProtocolError {
    #[error("message too short: {len} bytes, the envelope alone needs {min}")]
    Truncated { len: usize, min: usize },
    #[error("message too large: {len} bytes, the limit is {max}")]
    Oversized { len: usize, max: usize },
    #[error("bad magic bytes {found:?}: not a team-protocol message")]
    BadMagic { found: [u8; 2] },
    #[error("protocol version {found} is not supported (this build speaks version {expected})")]
    VersionMismatch { found: u16, expected: u16 },
    #[error("expected a {expected} message, got kind {found}")]
    WrongKind { expected: &'static str, found: u8 },
    #[error("malformed {kind} payload: {reason}")]
    Malformed { kind: &'static str, reason: String },
    #[error("invalid identifier {what} {value:?}: {reason}")]
    BadId { what: &'static str, value: String, reason: &'static str },
    #[error("non-finite number in {field}[{index}]: {value}")]
    NonFinite { field: String, index: usize, value: f64 },
    #[error("dimension mismatch in {field}: expected {expected}, got {got}")]
    Dimension { field: String, expected: String, got: String },
    #[error("invalid {field}: {reason}")]
    Invalid { field: String, reason: String },
    #[error("json: {0}")]
    Json(String),
    /// A message whose header names another sender than the key it came on (a robot publishing
    /// terms for another robot on its own key, a team's message on another team's key).
    #[error("sender mismatch: the key {key} is {key_sender}'s, the header says {header_sender}")]
    WrongSender { key: String, key_sender: String, header_sender: String },
}

impl ProtocolError {
    pub(crate) fn dim(
        field: impl Into<String>,
        expected: impl ToString,
        got: impl ToString,
    ) -> Self {
        ProtocolError::Dimension {
            field: field.into(),
            expected: expected.to_string(),
            got: got.to_string(),
        }
    }
    pub(crate) fn invalid(field: impl Into<String>, reason: impl Into<String>) -> Self {
        ProtocolError::Invalid { field: field.into(), reason: reason.into() }
    }
}
