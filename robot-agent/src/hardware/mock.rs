//! An in-memory robot, ros2_control's `mock_components::GenericSystem`: fixed base, every
//! actuated joint a unit inertia (`qdd = tau`), integrated with semi-implicit Euler at a fixed
//! step `dt`, one step per [`RobotHardware::read`] after the first:
//!
//! ```text
//! v <- v + dt tau,  q <- q + dt v
//! tau = tau_ff + kp (q_des - q) + kd (qd_des - qd)   (the drive law of the last write, at
//!                                                     the state before the step)
//! ```
//!
//! The step is fixed, not measured, so a test knows the answer exactly: with joint damping
//! `tau_k = -d v_k` applied at every tick, `v_k = (1 - dt d)^k v_0`. Pair it with
//! [`crate::dynamics_source::PlaceholderDynamics`] with `nv = joints` (unit mass matrix, no
//! gravity), which is this robot's exact model. Faults can be injected ([`MockFault`]) and
//! every step recorded ([`MockConfig::record`]).

use std::time::Instant;

use protocol::{DriveCommand, Pose, RobotState, Validate};

use super::{HardwareError, HwStatus, RobotHardware};

/// The mock robot's settings.
#[derive(Debug, Clone, PartialEq)]
pub struct MockConfig {
    /// Initial joint positions (their number is the number of joints).
    pub q0: Vec<f64>,
    /// Initial joint velocities.
    pub v0: Vec<f64>,
    /// Integration step, s (the period of the loop that drives it, normally).
    pub dt: f64,
    /// Keep every step in [`MockHardware::history`].
    pub record: bool,
}

impl MockConfig {
    /// `joints` joints at `q = 0` moving at `v0`, step `dt`.
    pub fn new(joints: usize, v0: f64, dt: f64) -> Self {
        MockConfig { q0: vec![0.0; joints], v0: vec![v0; joints], dt, record: false }
    }
}

/// A fault to inject: `read` or `write` of the cycle that reads tick `tick` returns `status`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MockFault {
    pub tick: u64,
    pub on_write: bool,
    pub status: HwStatus,
}

/// Lifecycle state, as ros2_control's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lifecycle {
    Unconfigured,
    Inactive,
    Active,
}

/// One step of the mock: the state read at `tick` and the torques written after it (if any).
#[derive(Debug, Clone, PartialEq)]
pub struct MockStep {
    pub tick: u64,
    pub q: Vec<f64>,
    pub v: Vec<f64>,
    pub tau: Option<Vec<f64>>,
}

/// The in-memory robot. See the module documentation.
#[derive(Debug, Clone)]
pub struct MockHardware {
    q: Vec<f64>,
    v: Vec<f64>,
    /// The torques of the last step (the drive law's, or `tau_ff` without gains).
    tau: Vec<f64>,
    /// The last write (a torque of zeros before).
    drive: DriveCommand,
    dt: f64,
    reads: u64,
    writes: u64,
    lifecycle: Lifecycle,
    faults: Vec<MockFault>,
    history: Option<Vec<MockStep>>,
    /// From this read on, the base reports this pose (a robot that tipped over).
    tipped: Option<(u64, Pose)>,
    /// The first read's time: the mock's clock starts there, as the loop's does.
    first_read: Option<Instant>,
}

impl MockHardware {
    pub fn new(cfg: MockConfig) -> Self {
        let n = cfg.q0.len();
        MockHardware {
            v: cfg.v0,
            q: cfg.q0,
            tau: vec![0.0; n],
            drive: DriveCommand::torque("", "", 0, vec![0.0; n]),
            dt: cfg.dt,
            reads: 0,
            first_read: None,
            writes: 0,
            lifecycle: Lifecycle::Unconfigured,
            faults: Vec::new(),
            history: cfg.record.then(Vec::new),
            tipped: None,
        }
    }

    /// From the read of `tick` on, report the base at `pose` (upright at the origin before).
    pub fn tipped_at(mut self, tick: u64, pose: Pose) -> Self {
        self.tipped = Some((tick, pose));
        self
    }

    /// Inject a fault.
    pub fn with_fault(mut self, fault: MockFault) -> Self {
        self.faults.push(fault);
        self
    }

    pub fn positions(&self) -> &[f64] {
        &self.q
    }

    pub fn velocities(&self) -> &[f64] {
        &self.v
    }

    /// Torques of the last step: the last write's drive law at the state before it (zeros
    /// before the first write).
    pub fn torques(&self) -> &[f64] {
        &self.tau
    }

    /// The last drive command written.
    pub fn drive(&self) -> &DriveCommand {
        &self.drive
    }

    pub fn reads(&self) -> u64 {
        self.reads
    }

    pub fn writes(&self) -> u64 {
        self.writes
    }

    pub fn lifecycle(&self) -> Lifecycle {
        self.lifecycle
    }

    /// Every step, if recording.
    pub fn history(&self) -> &[MockStep] {
        self.history.as_deref().unwrap_or(&[])
    }

    /// The injected status for the cycle of the latest read, if any.
    fn fault(&self, on_write: bool) -> Option<HwStatus> {
        let tick = self.reads.checked_sub(1)?;
        self.faults.iter().find(|f| f.tick == tick && f.on_write == on_write).map(|f| f.status)
    }
}

impl RobotHardware for MockHardware {
    fn joints(&self) -> usize {
        self.q.len()
    }

    fn configure(&mut self) -> Result<(), HardwareError> {
        if !(self.dt.is_finite() && self.dt > 0.0) || self.v.len() != self.q.len() {
            return Err(HardwareError::new(format!(
                "mock: step {} s, {} positions, {} velocities",
                self.dt,
                self.q.len(),
                self.v.len()
            )));
        }
        self.lifecycle = Lifecycle::Inactive;
        Ok(())
    }

    fn activate(&mut self) -> Result<(), HardwareError> {
        match self.lifecycle {
            Lifecycle::Unconfigured => Err(HardwareError::new("mock: activate before configure")),
            _ => {
                self.lifecycle = Lifecycle::Active;
                Ok(())
            }
        }
    }

    fn deactivate(&mut self) -> Result<(), HardwareError> {
        if self.lifecycle == Lifecycle::Active {
            self.lifecycle = Lifecycle::Inactive;
        }
        self.tau.iter_mut().for_each(|t| *t = 0.0);
        self.drive.tau_ff.iter_mut().for_each(|t| *t = 0.0);
        self.drive.kp.clear();
        self.drive.kd.clear();
        self.drive.q_des.clear();
        self.drive.qd_des.clear();
        Ok(())
    }

    fn read(&mut self, now: Instant, state: &mut RobotState) -> HwStatus {
        if self.lifecycle == Lifecycle::Unconfigured {
            return HwStatus::Error;
        }
        let t = now.duration_since(*self.first_read.get_or_insert(now)).as_secs_f64();
        if self.reads > 0 {
            self.drive.effort(t, &self.q, &self.v, &mut self.tau);
            for j in 0..self.q.len() {
                self.v[j] += self.dt * self.tau[j];
                self.q[j] += self.dt * self.v[j];
            }
        }
        self.reads += 1;
        if let Some(status) = self.fault(false) {
            return status;
        }
        state.base_pose = match self.tipped {
            Some((from, pose)) if self.reads > from => pose,
            _ => Pose::IDENTITY,
        };
        state.base_twist = [0.0; 6];
        state.joint_positions.clear();
        state.joint_positions.extend_from_slice(&self.q);
        state.joint_velocities.clear();
        state.joint_velocities.extend_from_slice(&self.v);
        if let Some(h) = self.history.as_mut() {
            h.push(MockStep {
                tick: self.reads - 1,
                q: self.q.clone(),
                v: self.v.clone(),
                tau: None,
            });
        }
        HwStatus::Ok
    }

    fn write(&mut self, cmd: &DriveCommand) -> HwStatus {
        if self.lifecycle != Lifecycle::Active
            || cmd.tau_ff.len() != self.tau.len()
            || cmd.validate().is_err()
        {
            return HwStatus::Error;
        }
        if let Some(status) = self.fault(true) {
            return status;
        }
        self.drive.clone_from(cmd);
        self.writes += 1;
        if let Some(step) = self.history.as_mut().and_then(|h| h.last_mut()) {
            step.tau = Some(cmd.tau_ff.clone());
        }
        HwStatus::Ok
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::Header;

    fn state() -> RobotState {
        RobotState {
            header: Header::new("t", Some("r"), 0, 0),
            base_pose: Pose::IDENTITY,
            base_twist: [0.0; 6],
            joint_positions: Vec::new(),
            joint_velocities: Vec::new(),
            time: 0.0,
            foot_forces: Vec::new(),
            object_pose: None,
        }
    }

    fn torque(tau: &[f64]) -> DriveCommand {
        DriveCommand::torque("t", "r", 0, tau.to_vec())
    }

    #[test]
    fn lifecycle_integration_and_faults() {
        let mut hw =
            MockHardware::new(MockConfig { record: true, ..MockConfig::new(2, 1.0, 0.01) })
                .with_fault(MockFault { tick: 3, on_write: true, status: HwStatus::Deactivate });
        let mut s = state();
        let t = Instant::now();
        assert_eq!(hw.read(t, &mut s), HwStatus::Error, "read before configure");
        assert!(hw.activate().is_err(), "activate before configure");
        hw.configure().unwrap();
        assert_eq!(hw.write(&torque(&[0.0, 0.0])), HwStatus::Error, "write while inactive");
        hw.activate().unwrap();
        // First read: the initial state, no step.
        assert_eq!(hw.read(t, &mut s), HwStatus::Ok);
        assert_eq!(
            (s.joint_positions.clone(), s.joint_velocities.clone()),
            (vec![0.0, 0.0], vec![1.0, 1.0])
        );
        assert_eq!(hw.write(&torque(&[-10.0, 0.0])), HwStatus::Ok);
        assert_eq!(hw.write(&torque(&[0.0])), HwStatus::Error, "wrong size");
        assert_eq!(hw.write(&torque(&[f64::NAN, 0.0])), HwStatus::Error, "not finite");
        // Second read: v <- v + dt tau, q <- q + dt v.
        assert_eq!(hw.read(t, &mut s), HwStatus::Ok);
        assert_eq!(s.joint_velocities, vec![1.0 + 0.01 * -10.0, 1.0]);
        assert_eq!(s.joint_positions, vec![0.01 * 0.9, 0.01]);
        assert_eq!(hw.read(t, &mut s), HwStatus::Ok);
        assert_eq!(hw.read(t, &mut s), HwStatus::Ok);
        assert_eq!(hw.write(&torque(&[0.0, 0.0])), HwStatus::Deactivate, "injected at tick 3");
        hw.deactivate().unwrap();
        assert_eq!(hw.lifecycle(), Lifecycle::Inactive);
        assert_eq!(hw.history().len(), 4);
        assert_eq!(hw.history()[0].tau, Some(vec![-10.0, 0.0]));
        assert_eq!(hw.history()[1].tau, None);
    }

    #[test]
    fn the_drive_law_runs_at_every_step_from_the_last_write() {
        // One write, then 2000 steps: v += dt (tau_ff + kp (q_des - q) + kd (qd_des - v)),
        // q += dt v, written out here; it settles where the spring balances the feed-forward.
        let (dt, v0) = (0.002, 0.5);
        let mut hw = MockHardware::new(MockConfig::new(2, v0, dt));
        hw.configure().unwrap();
        hw.activate().unwrap();
        let mut s = state();
        let t = Instant::now();
        hw.read(t, &mut s);
        let mut d = torque(&[1.0, 0.0]);
        (d.q_des, d.qd_des, d.kp, d.kd) =
            (vec![0.2, -0.3], vec![0.0, 0.0], vec![400.0, 100.0], vec![40.0, 20.0]);
        assert_eq!(hw.write(&d), HwStatus::Ok);
        let (mut q, mut v) = ([0.0f64; 2], [v0; 2]);
        for _ in 0..2000 {
            hw.read(t, &mut s);
            for j in 0..2 {
                v[j] += dt
                    * (d.tau_ff[j]
                        + d.kp[j] * (d.q_des[j] - q[j])
                        + d.kd[j] * (d.qd_des[j] - v[j]));
                q[j] += dt * v[j];
            }
        }
        assert_eq!((s.joint_positions.as_slice(), s.joint_velocities.as_slice()), (&q[..], &v[..]));
        assert!((q[0] - (0.2 + 1.0 / 400.0)).abs() < 1e-6 && (q[1] + 0.3).abs() < 1e-6, "{q:?}");
        // A negative gain or targets without gains are refused, and the last law stays.
        let mut bad = d.clone();
        bad.kp[1] = -1.0;
        assert_eq!(hw.write(&bad), HwStatus::Error);
        bad.kp.clear();
        assert_eq!(hw.write(&bad), HwStatus::Error, "q_des without kp");
        assert_eq!(hw.drive(), &d);
    }
}
