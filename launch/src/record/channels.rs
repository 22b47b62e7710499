//! The key channels of a recording: one MCAP channel per Zenoh key (the topic is the key,
//! e.g. `team/team/robot/r1/state`), message encoding `json`, schema encoding `jsonschema`
//! with the message's JSON Schema (the same schemas as `protocol/schemas/`). The dynamics
//! terms are recorded as a [`DynamicsSummary`] (the full mass matrix and Jacobians at every
//! tick would be most of the file and no tool draws them).

use std::collections::HashMap;
use std::sync::Arc;

use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, Schema};
use protocol::{DynamicsTerms, FrameRole, Header};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{Item, RecordedMessage};

/// The dynamics terms an agent published, in short: what a plot needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct DynamicsSummary {
    pub header: Header,
    /// Tick of the state the terms were computed at.
    pub state_tick: u64,
    pub floating_base: bool,
    pub nv: u32,
    /// Diagonal of the joint-space mass matrix M(q).
    pub mass_diagonal: Vec<f64>,
    /// Bias forces h(q, v) = C(q, v) v + g(q).
    pub bias: Vec<f64>,
    pub hand_in_grasp: bool,
    /// Every frame the terms carry (torso, feet, hand) with its world position.
    pub frames: Vec<FrameSummary>,
}

/// One frame of a [`DynamicsSummary`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct FrameSummary {
    pub name: String,
    pub role: FrameRole,
    pub position: [f64; 3],
}

impl DynamicsSummary {
    pub fn of(d: &DynamicsTerms) -> DynamicsSummary {
        let n = d.mass_matrix.rows().min(d.mass_matrix.cols());
        DynamicsSummary {
            header: d.header.clone(),
            state_tick: d.state_tick,
            floating_base: d.floating_base,
            nv: d.nv,
            mass_diagonal: (0..n).map(|i| d.mass_matrix.get(i, i).unwrap_or(f64::NAN)).collect(),
            bias: d.bias.clone(),
            hand_in_grasp: d.hand_in_grasp,
            frames: d
                .frames
                .iter()
                .map(|f| FrameSummary { name: f.name.clone(), role: f.role, position: f.position })
                .collect(),
        }
    }
}

/// Schema name and JSON Schema of a message kind.
pub fn schema_of(message: &RecordedMessage) -> (&'static str, fn() -> schemars::Schema) {
    match message {
        RecordedMessage::State(_) => {
            ("team.RobotState", || schemars::schema_for!(protocol::RobotState))
        }
        RecordedMessage::Dynamics(_) => {
            ("team.DynamicsSummary", || schemars::schema_for!(DynamicsSummary))
        }
        RecordedMessage::Command(_) => {
            ("team.TorqueCommand", || schemars::schema_for!(protocol::TorqueCommand))
        }
        RecordedMessage::Torque(_) => {
            ("team.DriveCommand", || schemars::schema_for!(protocol::DriveCommand))
        }
        RecordedMessage::Contacts(_) => {
            ("team.ContactSet", || schemars::schema_for!(protocol::ContactSet))
        }
        RecordedMessage::AgentStatus(_) => {
            ("team.AgentStatus", || schemars::schema_for!(protocol::AgentStatus))
        }
        RecordedMessage::Truth(_) => {
            ("team.GroundTruth", || schemars::schema_for!(protocol::GroundTruth))
        }
        RecordedMessage::Diagnostics(_) => {
            ("team.TickDiagnostics", || schemars::schema_for!(protocol::TickDiagnostics))
        }
        RecordedMessage::Status(_) => {
            ("team.CoordinatorStatus", || schemars::schema_for!(protocol::CoordinatorStatus))
        }
        RecordedMessage::References(_) => {
            ("team.TaskReferences", || schemars::schema_for!(protocol::TaskReferences))
        }
    }
}

/// The message as recorded (JSON).
pub fn to_json(message: &RecordedMessage) -> serde_json::Result<Vec<u8>> {
    match message {
        RecordedMessage::State(m) => serde_json::to_vec(m),
        RecordedMessage::Dynamics(m) => serde_json::to_vec(&DynamicsSummary::of(m)),
        RecordedMessage::Command(m) => serde_json::to_vec(m),
        RecordedMessage::Torque(m) => serde_json::to_vec(m),
        RecordedMessage::Contacts(m) => serde_json::to_vec(m),
        RecordedMessage::AgentStatus(m) => serde_json::to_vec(m),
        RecordedMessage::Truth(m) => serde_json::to_vec(m),
        RecordedMessage::Diagnostics(m) => serde_json::to_vec(m),
        RecordedMessage::Status(m) => serde_json::to_vec(m),
        RecordedMessage::References(m) => serde_json::to_vec(m),
    }
}

/// The key channels, created on a key's first message.
pub struct Channels {
    ctx: Arc<Context>,
    by_key: HashMap<String, Arc<RawChannel>>,
}

impl Channels {
    pub fn new(ctx: Arc<Context>) -> Channels {
        Channels { ctx, by_key: HashMap::new() }
    }

    /// Log one item at `log_time` (ns of sim time).
    pub fn log(&mut self, item: &Item, log_time: u64) -> Result<(), String> {
        let bytes = to_json(&item.message).map_err(|e| format!("{}: {e}", item.key))?;
        let channel = match self.by_key.get(&item.key) {
            Some(c) => c,
            None => {
                let (name, schema) = schema_of(&item.message);
                let data = serde_json::to_vec(&schema()).map_err(|e| e.to_string())?;
                let c = ChannelBuilder::new(item.key.clone())
                    .context(&self.ctx)
                    .message_encoding("json")
                    .schema(Schema::new(name, "jsonschema", data))
                    .build_raw()
                    .map_err(|e| format!("{}: {e}", item.key))?;
                self.by_key.entry(item.key.clone()).or_insert(c)
            }
        };
        channel.log_with_meta(&bytes, PartialMetadata { log_time: Some(log_time) });
        Ok(())
    }
}
