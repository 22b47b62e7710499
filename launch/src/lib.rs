//! # launch
//!
//! Starting and running a team: the sim-bridge, one robot-agent per robot and the coordinator,
//! embedded (every component a task of one process on one Zenoh session), as processes on
//! loopback, or on test hosts (network namespaces).
//!
//! * [`processes`]: the team's binaries as child processes.
//! * [`hosts`]: test hosts, each component on its own network namespace.
//! * [`priority`]: a real-time run's scheduling priority (raised where permitted).
//! * [`router`]: `team router`: a site's Zenoh router, which several teams share
//!   (`protocol::site`).
//! * [`launcher`]: the one launcher for every run of the team, smoke or scenario.
//! * [`faults`]: faults injected into a run (killed, stalled and restarted components).
//! * [`record`]: the run as MCAP (`run.mcap`), live to Foxglove (`--live`), and read back
//!   (`team report run.mcap`).
//! * [`driver`]: the runner's participant during a run: references out, records in, progress.
//! * [`run`]: `team run`: a scenario's plan with the whole stack, embedded or distributed.
//! * [`smoke`]: the smoke run: placeholder dynamics, controller and plant, real messages.
//! * [`echo`]: `team echo`: every message on a key, decoded.

pub mod driver;
pub mod echo;
pub mod faults;
pub mod hosts;
pub mod launcher;
pub mod priority;
pub mod processes;
pub mod record;
pub mod router;
pub mod run;
pub mod smoke;
