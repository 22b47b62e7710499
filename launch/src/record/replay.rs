//! Reading a recording back: the scenario it ran, the run's facts, and the driver's
//! [`Records`] rebuilt from the key channels by the driver's own rules (scenario ticks only,
//! in arrival order), so that `team report run.mcap` evaluates exactly what the live run did.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use protocol::{CoordinatorStatus, DriveCommand, GroundTruth, TickDiagnostics, TorqueCommand};
use thiserror::Error;

use super::{RunFacts, ScenarioSource, RUN_METADATA};
use evaluation::evaluate::{self, Evaluation};
use evaluation::records::Records;
use scenario::file::ScenarioError;
use scenario::plan::{self, Plan, PlanError};

/// Errors reading a recording.
#[derive(Debug, Error)]
pub enum ReplayError {
    #[error("cannot read {path}: {reason}")]
    Io { path: PathBuf, reason: String },
    #[error("{path} is not a readable MCAP file: {reason}")]
    Mcap { path: PathBuf, reason: String },
    #[error(
        "{path} has no '{RUN_METADATA}' metadata record \
         (not written by `team run`, or the run did not finish)"
    )]
    NoRunMetadata { path: PathBuf },
    #[error("{path}: message on {topic} does not decode: {reason}")]
    Message { path: PathBuf, topic: String, reason: String },
    #[error("the recorded scenario: {0}")]
    Scenario(#[from] ScenarioError),
    /// Boxed: a plan error is large, and every reading function returns this type.
    #[error("planning the recorded scenario: {0}")]
    Plan(Box<PlanError>),
}

impl From<PlanError> for ReplayError {
    fn from(e: PlanError) -> Self {
        ReplayError::Plan(Box::new(e))
    }
}

/// Evaluate a recording as `team run` evaluated the run: the recorded scenario planned again
/// (robot descriptions from `root`), the driver's records rebuilt from the messages. A run
/// that ended in an error, or a recording short of its plan, is evaluated as failed
/// ([`evaluate::evaluate_failed`]): its report names the error and never passes.
pub fn evaluate_recording(
    path: &Path,
    root: &Path,
) -> Result<(Plan, Records, Evaluation), ReplayError> {
    let rec = read(path)?;
    if rec.dropped > 0 {
        tracing::warn!(
            dropped = rec.dropped,
            "the recording misses messages: the metrics may differ from the run's"
        );
    }
    let s = rec.scenario.load()?;
    let plan = plan::plan(&s, root)?;
    let records = rec.records(plan.references.clock.settle_ticks);
    let eval = match rec.facts.error.clone().or_else(|| cut_short(&plan, &records)) {
        Some(e) => evaluate::evaluate_failed(&plan, &records, &rec.facts.mode, &e),
        None => evaluate::evaluate(&plan, &records, &rec.facts.mode),
    };
    Ok((plan, records, eval))
}

/// Why a recording without an error is short of its plan, if it is: the run stopped before
/// its end without saying why (a recording of an older version, or one closed by hand).
fn cut_short(plan: &Plan, records: &Records) -> Option<String> {
    (records.ticks_seen < plan.total_ticks()).then(|| {
        format!(
            "the recording ends after {} of the {} ticks planned",
            records.ticks_seen,
            plan.total_ticks()
        )
    })
}

/// What a recording holds for the evaluation.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    pub scenario: ScenarioSource,
    pub facts: RunFacts,
    /// Messages the recorder dropped while recording (0: the recording is complete).
    pub dropped: u64,
    pub truth: Vec<GroundTruth>,
    /// What the robots' drives were commanded (`torque` keys).
    pub torques: Vec<DriveCommand>,
    pub diagnostics: Vec<TickDiagnostics>,
    pub statuses: Vec<CoordinatorStatus>,
    /// Messages per channel topic.
    pub counts: BTreeMap<String, u64>,
}

impl Recording {
    /// The driver's records, with the scenario proper starting at tick `settle`.
    pub fn records(&self, settle: u64) -> Records {
        let mut rec = Records {
            truth: self.truth.iter().filter(|g| g.header.tick >= settle).cloned().collect(),
            diagnostics: self
                .diagnostics
                .iter()
                .filter(|d| d.header.tick >= settle)
                .cloned()
                .collect(),
            last_status: self.statuses.last().cloned(),
            statuses: self.statuses.clone(),
            released_at: self
                .statuses
                .iter()
                .find(|s| s.mode == protocol::CoordinatorMode::Released)
                .map(|s| s.header.tick),
            settle_wall: self.facts.settle_wall,
            run_wall: self.facts.run_wall,
            machine: self.facts.machine,
            ticks_seen: self.truth.iter().map(|g| g.header.tick + 1).max().unwrap_or(0),
            ..Records::default()
        };
        for c in self.torques.iter().filter(|c| c.header.tick >= settle) {
            rec.keep_drive(c);
        }
        rec
    }
}

/// The run's metadata record into `rec`: the scenario as loaded, the run's facts, the
/// messages dropped.
fn run_metadata_into(meta: &BTreeMap<String, String>, rec: &mut Recording) {
    let get = |k: &str| meta.get(k).cloned().unwrap_or_default();
    let nanos = |k: &str| Duration::from_nanos(get(k).parse::<u64>().unwrap_or(0));
    rec.scenario = ScenarioSource {
        path: PathBuf::from(get("scenario_path")),
        text: get("scenario_text"),
        overrides: serde_json::from_str(&get("overrides")).unwrap_or_default(),
        pace: scenario::Pacing::parse(&get("pace")),
    };
    rec.facts = RunFacts {
        mode: get("mode"),
        settle_wall: nanos("settle_wall_ns"),
        run_wall: nanos("run_wall_ns"),
        machine: machine_load(meta),
        error: meta.get("error").cloned(),
    };
    rec.dropped = get("dropped").parse().unwrap_or(0);
}

/// The machine's figures of a recording's metadata (`None` in a recording without them).
fn machine_load(meta: &BTreeMap<String, String>) -> Option<evaluation::machine::MachineLoad> {
    let share = |k: &str| meta.get(k).and_then(|v| v.parse::<f64>().ok());
    Some(evaluation::machine::MachineLoad {
        busy: share("machine_busy")?,
        steal: share("machine_steal")?,
    })
}

/// Read `path`.
pub fn read(path: &Path) -> Result<Recording, ReplayError> {
    let bytes = std::fs::read(path)
        .map_err(|e| ReplayError::Io { path: path.to_path_buf(), reason: e.to_string() })?;
    let mcap_err =
        |e: mcap::McapError| ReplayError::Mcap { path: path.to_path_buf(), reason: e.to_string() };
    let mut rec = Recording::default();
    let mut meta = None;
    for record in mcap::read::LinearReader::new(&bytes).map_err(mcap_err)? {
        if let mcap::records::Record::Metadata(m) = record.map_err(mcap_err)? {
            if m.name == RUN_METADATA {
                meta = Some(m.metadata);
            }
        }
    }
    let meta = meta.ok_or_else(|| ReplayError::NoRunMetadata { path: path.to_path_buf() })?;
    run_metadata_into(&meta, &mut rec);
    for message in mcap::MessageStream::new(&bytes).map_err(mcap_err)? {
        let m = message.map_err(mcap_err)?;
        let topic = m.channel.topic.as_str();
        *rec.counts.entry(topic.to_string()).or_default() += 1;
        let schema = m.channel.schema.as_ref().map(|s| s.name.as_str()).unwrap_or("");
        let bad = |e: serde_json::Error| ReplayError::Message {
            path: path.to_path_buf(),
            topic: topic.to_string(),
            reason: e.to_string(),
        };
        match schema {
            "team.GroundTruth" => rec.truth.push(serde_json::from_slice(&m.data).map_err(bad)?),
            "team.DriveCommand" if topic.ends_with("/torque") => {
                rec.torques.push(serde_json::from_slice(&m.data).map_err(bad)?)
            }
            // Recordings of the first protocol version: torques on the torque keys.
            "team.TorqueCommand" if topic.ends_with("/torque") => {
                rec.torques.push(torque_as_drive(serde_json::from_slice(&m.data).map_err(bad)?))
            }
            "team.TickDiagnostics" => {
                rec.diagnostics.push(serde_json::from_slice(&m.data).map_err(bad)?)
            }
            "team.CoordinatorStatus" => {
                rec.statuses.push(serde_json::from_slice(&m.data).map_err(bad)?)
            }
            _ => {}
        }
    }
    Ok(rec)
}

/// A torque command of the first protocol version, as the drive command without gains it was.
fn torque_as_drive(t: TorqueCommand) -> DriveCommand {
    DriveCommand { header: t.header, ..DriveCommand::torque("", "", 0, t.tau) }
}
