//! # evaluation
//!
//! What a run measured and whether it passed: the run's [`records`] in, metrics, acceptance
//! checks, CSV time series, `metrics.json`, figures and `report.html` out. Nothing here runs or
//! talks to the team; the same code evaluates a live run and a recording read back.
//!
//! * [`records`]: what a run recorded (ground truth, applied torques, diagnostics, statuses).
//! * [`metrics`]: the measures of success (`docs/scenarios.md`).
//! * [`loop_timing`]: the control loop of a real-time run, from the ground truth's stamps.
//! * [`machine`]: the machine a run had (its processors' busy share, the host's steal).
//! * [`walking`]: a walk's evaluation from the ground truth (steps, slides, final poses).
//! * [`tally`]: a run's measures taken as its messages come, in bounded memory.
//! * [`evaluate`]: a run's metrics, time series and acceptance checks ([`evaluate::Evaluation`]).
//! * [`report`]: CSV time series and JSON files of a run.
//! * [`plots`]: the figures of a report and its index page, `report.html`.

pub mod evaluate;
pub mod loop_timing;
pub mod machine;
pub mod metrics;
pub mod plots;
pub mod records;
pub mod report;
pub mod tally;
pub mod walking;
