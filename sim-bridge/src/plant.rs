//! What the bridge simulates.

use protocol::{DriveCommand, GroundTruth, Header, PerturbationRequest, Pose, RobotState};
use serde::{Deserialize, Serialize};

/// What a robot's drives do when its commands stop (its agent died, stalled, or lost its link):
/// the bridge's model of a real drive's command timeout. Torques that come again restore them
/// ([`Plant::restore_drives`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum DriveLoss {
    /// Zero torque: the joints are unpowered and the robot falls where it stands.
    #[default]
    Unpowered,
    /// Each drive holds its joint where it was with its own stiff position servo (a drive's
    /// freeze mode, or a brake): the robot stays standing, sagging a little under its weight,
    /// and a hand on the object keeps its place without squeezing.
    Freeze,
}

/// A simulated team: states out, torques in, step.
pub trait Plant: Send {
    /// Robot ids in a fixed order.
    fn robots(&self) -> &[String];
    /// Actuated joints of a robot.
    fn joints(&self, robot: usize) -> usize;
    /// Write the state of robot `robot` (header fields other than tick/stamp are the caller's).
    fn state(&self, robot: usize, out: &mut RobotState);
    /// Set the torques of robot `robot` for the next step (already checked for size); ignored
    /// while its drives are lost ([`Plant::lose_drives`]). A torque is a drive command without
    /// gains: it ends the last command's law.
    fn set_torques(&mut self, robot: usize, tau: &[f64]);
    /// Robot `robot`'s drives execute `cmd` ([`DriveCommand::effort`], checked for size) at
    /// every physics step until the next; without gains it is [`Plant::set_torques`] of
    /// `tau_ff`. Ignored while its drives are lost.
    fn set_drive(&mut self, robot: usize, cmd: &DriveCommand);
    /// Robot `robot`'s drives stop taking torques and do what `loss` says until
    /// [`Plant::restore_drives`].
    fn lose_drives(&mut self, robot: usize, loss: DriveLoss);
    /// Robot `robot`'s drives take torques again (from the next [`Plant::set_torques`]).
    fn restore_drives(&mut self, robot: usize);
    /// Whether robot `robot`'s drives are lost.
    fn drives_lost(&self, robot: usize) -> bool;
    /// Physics steps so far on which robot `robot`'s drives had no valid command: its last one
    /// past its [`DriveCommand::valid_until`], or its drives lost (drive gaps).
    fn drive_gap_steps(&self, robot: usize) -> u64;
    /// Advance one control period.
    fn step(&mut self);
    /// Simulated time, s.
    fn time(&self) -> f64;
    /// Fill `out` with the ground truth of the current state; `false` if the plant has none.
    fn ground_truth(&self, _team: &str, _tick: u64, _out: &mut GroundTruth) -> bool {
        false
    }
    /// Take a perturbation request (an external wrench); an error says why it was refused.
    fn perturb(&mut self, _req: &PerturbationRequest) -> Result<(), String> {
        Err("this plant takes no perturbations".into())
    }
}

/// Smoke-run stand-in for the simulator (until the MuJoCo world lands): every joint is a unit
/// inertia, `qdd = tau`, integrated with semi-implicit Euler; the bases stay where they are.
/// It closes the loop so that the message flow can be checked against an analytic answer.
pub struct PlaceholderPlant {
    robots: Vec<String>,
    q: Vec<Vec<f64>>,
    v: Vec<Vec<f64>>,
    tau: Vec<Vec<f64>>,
    /// Each robot's drive command, run at every step while it has gains.
    drives: Vec<DriveTargets>,
    lost: Vec<Option<DriveLoss>>,
    gaps: Vec<u64>,
    dt: f64,
    steps: u64,
}

/// A robot's drive command kept by a plant, run at every physics step while `active` (it has
/// gains), and how long the last command is valid. Preallocated: taking a command of the same
/// size allocates nothing.
#[derive(Debug, Clone)]
pub struct DriveTargets {
    pub cmd: DriveCommand,
    pub active: bool,
    /// The last command's [`DriveCommand::valid_until`], with gains or without.
    pub valid_until: Option<f64>,
}

impl DriveTargets {
    /// No command yet.
    pub fn new() -> Self {
        DriveTargets {
            cmd: DriveCommand::torque("", "", 0, Vec::new()),
            active: false,
            valid_until: None,
        }
    }

    /// Keep `cmd` if it has gains (then `true`); a command without gains ends the law.
    pub fn take(&mut self, cmd: &DriveCommand) -> bool {
        self.active = cmd.has_gains();
        self.valid_until = cmd.valid_until;
        if self.active {
            self.cmd.clone_from(cmd);
        }
        self.active
    }

    /// Whether the last command is past its validity at time `t` (a drive gap).
    pub fn expired(&self, t: f64) -> bool {
        self.valid_until.is_some_and(|end| t > end)
    }
}

impl Default for DriveTargets {
    fn default() -> Self {
        DriveTargets::new()
    }
}

impl PlaceholderPlant {
    /// `robots` with `joints` joints each, all starting at `q = 0` and `qdot = v0`.
    pub fn new(robots: Vec<String>, joints: usize, v0: f64, dt: f64) -> Self {
        let n = robots.len();
        PlaceholderPlant {
            robots,
            q: vec![vec![0.0; joints]; n],
            v: vec![vec![v0; joints]; n],
            tau: vec![vec![0.0; joints]; n],
            drives: vec![DriveTargets::new(); n],
            lost: vec![None; n],
            gaps: vec![0; n],
            dt,
            steps: 0,
        }
    }

    pub fn velocities(&self, robot: usize) -> &[f64] {
        &self.v[robot]
    }
}

impl Plant for PlaceholderPlant {
    fn robots(&self) -> &[String] {
        &self.robots
    }

    fn joints(&self, robot: usize) -> usize {
        self.q[robot].len()
    }

    fn state(&self, robot: usize, out: &mut RobotState) {
        out.base_pose =
            Pose { position: [2.0 * robot as f64, 0.0, 0.55], orientation: [1.0, 0.0, 0.0, 0.0] };
        out.base_twist = [0.0; 6];
        out.joint_positions.clear();
        out.joint_positions.extend_from_slice(&self.q[robot]);
        out.joint_velocities.clear();
        out.joint_velocities.extend_from_slice(&self.v[robot]);
        out.time = self.time();
    }

    fn set_torques(&mut self, robot: usize, tau: &[f64]) {
        if self.lost[robot].is_none() {
            self.tau[robot].copy_from_slice(tau);
            self.drives[robot].active = false;
        }
    }

    fn set_drive(&mut self, robot: usize, cmd: &DriveCommand) {
        if self.lost[robot].is_some() {
            return;
        }
        if !self.drives[robot].take(cmd) {
            self.tau[robot].copy_from_slice(&cmd.tau_ff);
        }
    }

    fn lose_drives(&mut self, robot: usize, loss: DriveLoss) {
        self.lost[robot] = Some(loss);
        self.tau[robot].iter_mut().for_each(|t| *t = 0.0);
        self.drives[robot].active = false;
    }

    fn restore_drives(&mut self, robot: usize) {
        self.lost[robot] = None;
    }

    fn drives_lost(&self, robot: usize) -> bool {
        self.lost[robot].is_some()
    }

    fn drive_gap_steps(&self, robot: usize) -> u64 {
        self.gaps[robot]
    }

    fn step(&mut self) {
        let t = self.time();
        for r in 0..self.robots.len() {
            if self.lost[r].is_some() || self.drives[r].expired(t) {
                self.gaps[r] += 1;
            }
            if self.lost[r] == Some(DriveLoss::Freeze) {
                // Unit-inertia joints held where they are.
                self.v[r].iter_mut().for_each(|v| *v = 0.0);
                continue;
            }
            if self.drives[r].active {
                self.drives[r].cmd.effort(t, &self.q[r], &self.v[r], &mut self.tau[r]);
            }
            for j in 0..self.q[r].len() {
                self.v[r][j] += self.dt * self.tau[r][j];
                self.q[r][j] += self.dt * self.v[r][j];
            }
        }
        self.steps += 1;
    }

    fn time(&self) -> f64 {
        self.steps as f64 * self.dt
    }
}

/// An empty state to be filled by [`Plant::state`].
pub fn empty_state(team: &str, robot: &str) -> RobotState {
    RobotState {
        header: Header::new(team, Some(robot), 0, 0),
        base_pose: Pose::IDENTITY,
        base_twist: [0.0; 6],
        joint_positions: Vec::new(),
        joint_velocities: Vec::new(),
        time: 0.0,
        foot_forces: Vec::new(),
        object_pose: None,
    }
}
