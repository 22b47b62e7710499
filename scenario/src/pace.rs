//! How a run is clocked, and the loop it runs with in each case.
//!
//! **Lockstep** keeps the paper's loop exactly as the file says: one robot tick per control
//! period, the team's torques applied at the state they answer, no drive gains.
//!
//! **Real time** puts only the team loop on the network and keeps the robots' own loop at the
//! robots. A network cannot carry four hops inside every millisecond of a 1 kHz robot, and no
//! robot waits for one to close its joints' loop. So, unless the file or `--set` says
//! otherwise:
//!
//! * `drive_gains = "inertia"`: each drive command carries gains and a short trajectory from the
//!   state it answers (`protocol::DriveCommand::targets_at`), valid until the agent's command
//!   deadline, which the drives follow at every physics step. Between two team commands the
//!   drives need nothing from anyone.
//! * `team_delay_ticks = "auto"`: the delay follows the latency the agents measure.
//! * The loop over the network (states out, terms, commands, drive commands back) runs at
//!   `team_hz`, by default [`TEAM_HZ`] (or the file's `control_hz` if slower): that becomes
//!   the run's control rate, and the physics steps between are the drives'. A robot tick
//!   between two team ticks would otherwise cross the network to its agent and back.
//!
//! What these defaults hold, on which machine, is in `docs/results.md`.

use serde::Deserialize;

/// The team loop's rate in real time when the scenario sets none, Hz.
pub const TEAM_HZ: f64 = 250.0;

/// Keys a real-time run sets when the file and the overrides leave them out, with their
/// values.
pub const REALTIME_DEFAULTS: [(&str, &str); 2] =
    [("drive_gains", "inertia"), ("team_delay_ticks", "auto")];

/// How a run is clocked.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Pacing {
    /// Each tick waits for every robot's torques: deterministic, the paper's loop.
    #[default]
    Lockstep,
    /// The simulator runs against the wall clock, as robots live it.
    Realtime,
}

impl Pacing {
    pub fn as_str(self) -> &'static str {
        match self {
            Pacing::Lockstep => "lockstep",
            Pacing::Realtime => "realtime",
        }
    }

    /// The pace a recording's metadata names (lockstep for anything else, as recordings made
    /// before the pace was recorded were).
    pub fn parse(s: &str) -> Pacing {
        if s == "realtime" {
            Pacing::Realtime
        } else {
            Pacing::Lockstep
        }
    }
}

/// The real-time defaults into a scenario's TOML, for the keys it does not set.
pub fn realtime_defaults(value: &mut toml::Value) {
    let Some(table) = value.as_table_mut() else { return };
    for (key, v) in REALTIME_DEFAULTS {
        table.entry(key).or_insert_with(|| toml::Value::String(v.into()));
    }
}

/// The real-time loop rate: the team's rate (`team_hz`, else [`TEAM_HZ`] or `control_hz` if
/// slower) becomes the control rate, and the team answers every tick of it. Returns the rate.
pub fn realtime_rate(control_hz: &mut f64, team_hz: &mut Option<f64>) -> f64 {
    let team = team_hz.take().unwrap_or(TEAM_HZ.min(*control_hz));
    *control_hz = team;
    team
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_fill_only_what_the_scenario_leaves_out() {
        let mut v: toml::Value = toml::from_str("drive_gains = \"none\"\nname = \"x\"").unwrap();
        realtime_defaults(&mut v);
        assert_eq!(v["drive_gains"].as_str(), Some("none"), "the file's choice stays");
        assert_eq!(v["team_delay_ticks"].as_str(), Some("auto"));
    }

    #[test]
    fn the_team_rate_becomes_the_control_rate() {
        let (mut c, mut t) = (1000.0, None);
        assert_eq!(realtime_rate(&mut c, &mut t), TEAM_HZ);
        assert_eq!((c, t), (TEAM_HZ, None));
        let (mut c, mut t) = (1000.0, Some(500.0));
        realtime_rate(&mut c, &mut t);
        assert_eq!((c, t), (500.0, None));
        let (mut c, mut t) = (100.0, None);
        realtime_rate(&mut c, &mut t);
        assert_eq!(c, 100.0, "a scenario slower than the default keeps its rate");
        assert_eq!(Pacing::parse("realtime"), Pacing::Realtime);
        assert_eq!(Pacing::parse(""), Pacing::Lockstep);
    }
}
