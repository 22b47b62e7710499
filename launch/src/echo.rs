//! `team echo KEY`: every message on a key (wildcards allowed, e.g. `team/team/robot/*/state`)
//! printed as one JSON line `{"key", "encoding", "message"}`, like `ros2 topic echo`. The
//! message type comes from the key's shape ([`protocol::keys::kind_of`]), so binary hot-path
//! messages print as JSON too. Liveliness keys (`team/{team}/member/*`,
//! `team/{team}/coordinator/alive`) carry no message: their tokens' comings and goings print as
//! `{"key", "alive"}`.

use std::io::Write;
use std::time::Duration;

use protocol::transport::{self, TransportError};
use thiserror::Error;
use zenoh::Session;

/// Errors of `team echo`.
#[derive(Debug, Error)]
pub enum EchoError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(
        "nothing on {key} for {waited:?} (is a run going, and reachable from here? see --connect)"
    )]
    Silent { key: String, waited: Duration },
    #[error("writing the output: {0}")]
    Output(String),
}

/// What to print.
#[derive(Debug, Clone)]
pub struct EchoOptions {
    pub key: String,
    /// Stop after this many messages.
    pub count: Option<u64>,
    /// Stop (with [`EchoError::Silent`] if nothing came at all) after this long without a
    /// message.
    pub wait: Duration,
}

/// One sample as a JSON line; samples whose type is unknown or that do not decode print
/// with an `"error"` instead of the message.
pub fn line(key: &str, encoding: &str, payload: &[u8]) -> serde_json::Value {
    let decoded = match protocol::keys::kind_of(key) {
        Some(kind) => protocol::codec::decode_to_json(kind, payload).map_err(|e| e.to_string()),
        None => Err("no message type for this key".to_string()),
    };
    match decoded {
        Ok(m) => serde_json::json!({ "key": key, "encoding": encoding, "message": m }),
        Err(e) => serde_json::json!({
            "key": key,
            "encoding": encoding,
            "error": e,
            "bytes": payload.len()
        }),
    }
}

/// A liveliness token's coming (`alive: true`) or going as a JSON line.
pub fn token_line(key: &str, alive: bool) -> serde_json::Value {
    serde_json::json!({ "key": key, "alive": alive })
}

/// Print messages on `opts.key` to `out` until the count is reached or the key is silent for
/// `opts.wait`; returns how many were printed.
/// Liveliness keys (`member/*`, `coordinator/alive`) print `{"key", "alive"}` per coming and
/// going, the tokens present first.
pub async fn echo(
    session: &Session,
    opts: &EchoOptions,
    out: &mut impl Write,
) -> Result<u64, EchoError> {
    let tokens = protocol::keys::is_liveliness(&opts.key);
    let (events, samples) = if tokens {
        (Some(transport::watch_liveliness(session, opts.key.clone()).await?), None)
    } else {
        (None, Some(transport::subscribe_with_capacity(session, opts.key.clone(), 4096).await?))
    };
    let next = || async {
        match (&events, &samples) {
            (Some(q), _) => q.recv_async().await.ok(),
            (_, Some(q)) => q.recv_async().await.ok(),
            (None, None) => None,
        }
    };
    let mut printed = 0u64;
    while opts.count.is_none_or(|n| printed < n) {
        let sample = match tokio::time::timeout(opts.wait, next()).await {
            Ok(Some(s)) => s,
            Ok(None) => break,
            Err(_) if printed == 0 => {
                return Err(EchoError::Silent { key: opts.key.clone(), waited: opts.wait })
            }
            Err(_) => break,
        };
        let v = if tokens {
            token_line(sample.key_expr().as_str(), sample.kind() == zenoh::sample::SampleKind::Put)
        } else {
            line(
                sample.key_expr().as_str(),
                &sample.encoding().to_string(),
                &sample.payload().to_bytes(),
            )
        };
        writeln!(out, "{v}").map_err(|e| EchoError::Output(e.to_string()))?;
        printed += 1;
    }
    out.flush().map_err(|e| EchoError::Output(e.to_string()))?;
    Ok(printed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{CoordinatorMode, CoordinatorStatus, Header, Pose, RobotState};

    #[test]
    fn binary_and_json_keys_print_as_json() {
        let s = RobotState {
            header: Header::new("t", Some("r1"), 5, 0),
            base_pose: Pose::IDENTITY,
            base_twist: [0.0; 6],
            joint_positions: vec![0.5],
            joint_velocities: vec![0.0],
            time: 0.005,
            foot_forces: Vec::new(),
            object_pose: None,
        };
        let v = line(
            "team/t/robot/r1/state",
            &format!("zenoh/bytes;team.RobotState/v{}", protocol::PROTOCOL_VERSION),
            &protocol::encode(&s).unwrap(),
        );
        assert_eq!(v["message"]["joint_positions"][0], 0.5);
        assert_eq!(v["message"]["header"]["tick"], 5);
        let st = CoordinatorStatus {
            header: Header::new("t", None, 9, 0),
            mode: CoordinatorMode::Running,
            members: vec![],
            ticks: 9,
            commands_sent: 0,
            deadline_misses: 0,
            fallbacks: 0,
            detail: String::new(),
            stale: vec![],
            silent: vec![],
            late: vec![],
            reused_terms: 0,
            refused: 0,
            last_refusal: None,
        };
        let v =
            line("team/t/coordinator/status", "application/json", &protocol::encode(&st).unwrap());
        assert_eq!(v["message"]["mode"], "Running");
        // A payload of the wrong type, or a key without a type: an error line, no panic.
        assert!(line("team/t/robot/r1/dynamics", "", &protocol::encode(&s).unwrap())["error"]
            .is_string());
        assert!(line("team/t/member/r1", "", b"x")["error"].is_string());
    }
}
