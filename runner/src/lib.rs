//! # team-runner
//!
//! Runs a whole team: the sim-bridge, one robot-agent per robot and the coordinator.
//!
//! * [`smoke`]: the smoke run of the foundation: placeholder dynamics, controller and plant,
//!   real Zenoh messages, embedded (every component in one process on one session) or
//!   distributed (every component its own process, on loopback).
//! * [`processes`]: the team's binaries as child processes on loopback.
//! * [`plan`]: a scenario turned into what each component runs (scene, controller, references);
//!   each robot's description is loaded there, once, and shared (`Arc<robot_model::Robot>`).
//! * [`capacity`]: the payload check of a plan (the static team problem at the start pose) and
//!   the team's capacity (`team capacity`).
//! * [`placing`]: the planner (`planner`: robot placement, hands on the object, references,
//!   the walk) on the simulator's world spec and the controller's planned grasp.
//! * [`run`]: `team run`: the scenario with the whole stack, embedded or distributed.
//! * [`site`]: `team router`: a site's Zenoh router, which several teams share
//!   (`protocol::site`).
//! * [`priority`]: a real-time run's scheduling priority (raised where permitted).
//! * [`driver`]: the runner's participant during a run: references out, records in, progress.
//! * [`compare`]: controllers side by side on the same scenarios (experiment S3) and the motion
//!   sweep; [`compare_plot`] draws its object-Z figure.
//! * [`evaluate`]: metrics, time series, plots and acceptance checks of a run.
//! * [`scenario`]: scenario files (TOML) with `--set key=value` overrides.
//! * [`walk`]: a walk's evaluation from the ground truth (steps, slides, final poses); the
//!   walk itself is planned by `planner::walk`.
//! * [`metrics`]: the measures of success (`docs/scenarios.md`).
//! * [`report`]: CSV time series, `metrics.json` and plots of a run.
//! * [`record`]: the run as MCAP (`run.mcap`), live to Foxglove (`--live`), and read back
//!   (`team report run.mcap`).

pub mod capacity;
pub mod compare;
pub mod compare_plot;
pub mod driver;
pub mod hosts;
pub mod echo;
pub mod evaluate;
pub mod faults;
pub mod launch;
pub mod loop_timing;
pub mod metrics;
pub mod placing;
pub mod plan;
pub mod priority;
pub mod plots;
pub mod processes;
pub mod record;
pub mod report;
pub mod run;
pub mod scenario;
pub mod site;
pub mod smoke;
pub mod walk;
