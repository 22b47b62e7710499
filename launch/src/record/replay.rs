//! Reading a recording back: the scenario it ran, the run's facts, and the driver's
//! [`Records`] rebuilt from the key channels by the driver's own rules (scenario ticks only,
//! in arrival order), so that `team report run.mcap` evaluates exactly what the live run did.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use protocol::{DriveCommand, GroundTruth, TickDiagnostics, TorqueCommand};
use thiserror::Error;

use super::segments::segment_path;
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
    #[error(
        "{path} ends a recording split into {of} earlier files, of which {missing:?} are gone \
         (removed past --record-keep): the report the run wrote is the whole run's"
    )]
    MissingSegments { path: PathBuf, missing: Vec<u64>, of: u64 },
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
/// ([`evaluate::evaluate_failed`]): its report names the error and never passes. The files are
/// read through a bounded buffer and the messages measured as they are read, so a recording of
/// any length is evaluated in bounded memory.
pub fn evaluate_recording(
    path: &Path,
    root: &Path,
) -> Result<(Plan, Records, Evaluation), ReplayError> {
    let info = run_info(path)?;
    if info.dropped > 0 {
        tracing::warn!(
            dropped = info.dropped,
            "the recording misses messages: the metrics may differ from the run's"
        );
    }
    let files = files_of(path, info.segments)?;
    let s = info.scenario.load()?;
    let plan = plan::plan(&s, root)?;
    let records = records_of(&files, &plan, &info.facts)?;
    let eval = match info.facts.error.clone().or_else(|| cut_short(&plan, &records)) {
        Some(e) => evaluate::evaluate_failed(&plan, &records, &info.facts.mode, &e),
        None => evaluate::evaluate(&plan, &records, &info.facts.mode),
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

/// What a recording's metadata says of its run.
#[derive(Debug, Clone, Default)]
pub struct RunInfo {
    pub scenario: ScenarioSource,
    pub facts: RunFacts,
    /// Messages the recorder dropped while recording (0: the recording is complete).
    pub dropped: u64,
    /// Files the recording was split into before this one ([`super::segments`]).
    pub segments: u64,
}

/// The driver's records of a run of `plan` from the recording's `files` (in the order they
/// were written), by the driver's rules: scenario ticks only, in one pass in the order the
/// driver took them (the recorder wrote them as the driver handed them over), so that a
/// release halts the walk's references where it did in the live run.
fn records_of(files: &[PathBuf], plan: &Plan, facts: &RunFacts) -> Result<Records, ReplayError> {
    let settle = plan.references.clock.settle_ticks;
    let mut rec = Records::new(plan);
    rec.settle_wall = facts.settle_wall;
    rec.run_wall = facts.run_wall;
    rec.machine = facts.machine;
    for f in files {
        each_message(f, |m| {
            match m.schema {
                "team.CoordinatorStatus" => rec.keep_status(m.decode()?),
                "team.GroundTruth" => {
                    let g: GroundTruth = m.decode()?;
                    rec.ticks_seen = rec.ticks_seen.max(g.header.tick + 1);
                    if g.header.tick >= settle {
                        rec.keep_truth(g);
                    }
                }
                "team.DriveCommand" | "team.TorqueCommand" if m.topic.ends_with("/torque") => {
                    let c = match m.schema {
                        "team.DriveCommand" => m.decode()?,
                        // Recordings of the first protocol version: torques on the torque keys.
                        _ => torque_as_drive(m.decode()?),
                    };
                    if c.header.tick >= settle {
                        rec.keep_drive(&c);
                    }
                }
                "team.TickDiagnostics" => {
                    let d: TickDiagnostics = m.decode()?;
                    if d.header.tick >= settle {
                        rec.keep_diagnostics(d);
                    }
                }
                _ => {}
            }
            Ok(())
        })?;
    }
    Ok(rec)
}

/// The run's metadata record into `rec`: the scenario as loaded, the run's facts, the
/// messages dropped.
fn run_metadata_into(meta: &BTreeMap<String, String>, rec: &mut RunInfo) {
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
    rec.segments = get("segments").parse().unwrap_or(0);
}

/// The machine's figures of a recording's metadata (`None` in a recording without them).
fn machine_load(meta: &BTreeMap<String, String>) -> Option<evaluation::machine::MachineLoad> {
    let share = |k: &str| meta.get(k).and_then(|v| v.parse::<f64>().ok());
    Some(evaluation::machine::MachineLoad {
        busy: share("machine_busy")?,
        steal: share("machine_steal")?,
    })
}

/// What the recording at `path` says of its run (its [`RUN_METADATA`] record; chunks are
/// skipped, not decompressed).
pub fn run_info(path: &Path) -> Result<RunInfo, ReplayError> {
    let mut meta = None;
    each_record(path, true, |r| {
        if let mcap::records::Record::Metadata(m) = r {
            if m.name == RUN_METADATA {
                meta = Some(m.metadata);
            }
        }
        Ok(())
    })?;
    let meta = meta.ok_or_else(|| ReplayError::NoRunMetadata { path: path.to_path_buf() })?;
    let mut info = RunInfo::default();
    run_metadata_into(&meta, &mut info);
    Ok(info)
}

/// The files of the recording at `path` in the order they were written: the `split` it was
/// split into before it, then itself.
fn files_of(path: &Path, split: u64) -> Result<Vec<PathBuf>, ReplayError> {
    let missing: Vec<u64> = (1..=split).filter(|k| !segment_path(path, *k).exists()).collect();
    if !missing.is_empty() {
        return Err(ReplayError::MissingSegments { path: path.to_path_buf(), missing, of: split });
    }
    Ok((1..=split).map(|k| segment_path(path, k)).chain([path.to_path_buf()]).collect())
}

/// One message of a recording: its channel's topic and schema name, and its bytes.
struct Message<'a> {
    path: &'a Path,
    topic: &'a str,
    schema: &'a str,
    data: &'a [u8],
}

impl Message<'_> {
    fn decode<T: serde::de::DeserializeOwned>(&self) -> Result<T, ReplayError> {
        serde_json::from_slice(self.data).map_err(|e| ReplayError::Message {
            path: self.path.to_path_buf(),
            topic: self.topic.to_string(),
            reason: e.to_string(),
        })
    }
}

/// Every message of the MCAP file at `path`, in file order.
fn each_message(
    path: &Path,
    mut f: impl FnMut(Message) -> Result<(), ReplayError>,
) -> Result<(), ReplayError> {
    let mut schemas: BTreeMap<u16, String> = BTreeMap::new();
    let mut channels: BTreeMap<u16, (String, String)> = BTreeMap::new();
    each_record(path, false, |r| {
        use mcap::records::Record;
        match r {
            Record::Schema { header, .. } => {
                schemas.insert(header.id, header.name);
            }
            Record::Channel(c) => {
                let schema = schemas.get(&c.schema_id).cloned().unwrap_or_default();
                channels.insert(c.id, (c.topic, schema));
            }
            Record::Message { header, data } => {
                if let Some((topic, schema)) = channels.get(&header.channel_id) {
                    f(Message { path, topic, schema, data: &data })?;
                }
            }
            _ => {}
        }
        Ok(())
    })
}

/// Every record of the MCAP file at `path`, read through a bounded buffer (`chunks`: chunk
/// records as they are, else the records inside them).
fn each_record(
    path: &Path,
    chunks: bool,
    mut f: impl FnMut(mcap::records::Record) -> Result<(), ReplayError>,
) -> Result<(), ReplayError> {
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
    use std::io::Read;
    let io =
        |e: std::io::Error| ReplayError::Io { path: path.to_path_buf(), reason: e.to_string() };
    let mcap_err =
        |e: mcap::McapError| ReplayError::Mcap { path: path.to_path_buf(), reason: e.to_string() };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut reader =
        LinearReader::new_with_options(LinearReaderOptions::default().with_emit_chunks(chunks));
    while let Some(event) = reader.next_event() {
        match event.map_err(mcap_err)? {
            LinearReadEvent::ReadRequest(n) => {
                let read = file.read(reader.insert(n)).map_err(io)?;
                reader.notify_read(read);
            }
            LinearReadEvent::Record { data, opcode } => {
                f(mcap::parse_record(opcode, data).map_err(mcap_err)?)?;
            }
        }
    }
    Ok(())
}

/// A torque command of the first protocol version, as the drive command without gains it was.
fn torque_as_drive(t: TorqueCommand) -> DriveCommand {
    DriveCommand { header: t.header, ..DriveCommand::torque("", "", 0, t.tau) }
}
