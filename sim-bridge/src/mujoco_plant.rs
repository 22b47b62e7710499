//! A [`Plant`] over MuJoCo: the team's world of [`crate::world`], stepped `substeps` physics
//! steps per control tick. States are written in the protocol's convention (base twist in the
//! base frame, converted only through `protocol::conventions`); torques go to the motors of the
//! actuated joints (MuJoCo clamps them to `ctrlrange` = the torque limits). Every index comes
//! from the world's name maps.

use mujoco_rs::mujoco_c::{self, mjData, mjModel};
use mujoco_rs::prelude::*;
use protocol::conventions::{base_twist_from_mujoco, base_twist_to_mujoco};
use protocol::{DriveCommand, GroundTruth, PerturbationRequest, Pose, RobotState};

use crate::perturbation::Perturbations;
use crate::plant::{DriveLoss, DriveTargets, Plant};
use crate::world::{World, WorldError};

/// The team in MuJoCo.
pub struct MujocoPlant {
    pub world: World,
    data: MjData<std::sync::Arc<MjModel>>,
    ids: Vec<String>,
    ticks: u64,
    /// Timed external wrenches, applied through `xfrc_applied` at every physics step.
    pub perturbations: Perturbations,
    /// Robots whose drives are lost ([`Plant::lose_drives`]), with their freeze servos.
    lost: Vec<Option<LostDrives>>,
    /// Each robot's drive command, run at every physics step while it has gains.
    drives: Vec<DriveTargets>,
    /// The drive law's joint positions, velocities and torques (the largest robot's size).
    drive_q: Vec<f64>,
    drive_qd: Vec<f64>,
    drive_tau: Vec<f64>,
    /// Each robot's drive gaps so far ([`Plant::drive_gap_steps`]).
    gaps: Vec<u64>,
}

/// A robot's drives after they lost their commands: unpowered, or each joint held at `q_hold`
/// by the drive's own servo `tau = kp (q_hold - q) - kd qdot` (clamped to the torque limit by
/// MuJoCo's `ctrlrange`), run at every physics step as a drive's inner loop would.
#[derive(Debug, Clone)]
struct LostDrives {
    loss: DriveLoss,
    q_hold: Vec<f64>,
    kp: Vec<f64>,
    kd: Vec<f64>,
}

/// A freezing drive reaches its torque limit at this joint error, rad: its stiffness is
/// `limit / FREEZE_ERROR_AT_LIMIT` (legs 1600 N m/rad, shoulder 780, wrist 180).
pub const FREEZE_ERROR_AT_LIMIT: f64 = 0.05;

// SAFETY: MjData owns its buffers and its boxed model; nothing is shared between threads.
unsafe impl Send for MujocoPlant {}

impl MujocoPlant {
    /// The object's pose as the robots measure it ([`crate::world::Sensors::object_pose`]): its
    /// free joint's position and unit quaternion; `None` without an object or that sensor.
    fn measured_object(&self) -> Option<Pose> {
        let (_, a, _) = self.world.object?;
        if !self.world.spec.sensors.object_pose {
            return None;
        }
        let d = self.data.ffi();
        let q = |k: usize| unsafe { *d.qpos.add(a + k) };
        let mut quat = [q(3), q(4), q(5), q(6)];
        let n = quat.iter().map(|x| x * x).sum::<f64>().sqrt();
        quat.iter_mut().for_each(|x| *x /= n);
        Some(Pose { position: [q(0), q(1), q(2)], orientation: quat })
    }

    /// A plant at the world's initial condition (robots at their standing configuration with
    /// overrides and noise, zero velocities, object at its pose), forward-evaluated.
    pub fn new(world: World) -> Result<Self, WorldError> {
        let model = world.model.clone();
        let data = MjData::new(model);
        let ids = world.robots.iter().map(|r| r.id.clone()).collect();
        let lost = vec![None; world.robots.len()];
        let gaps = vec![0; world.robots.len()];
        let drives = vec![DriveTargets::new(); world.robots.len()];
        let most = world.robots.iter().map(|r| r.actuator.len()).max().unwrap_or(0);
        let (drive_q, drive_qd, drive_tau) = (vec![0.0; most], vec![0.0; most], vec![0.0; most]);
        let mut p = MujocoPlant {
            world,
            data,
            ids,
            ticks: 0,
            perturbations: Perturbations::default(),
            lost,
            drives,
            drive_q,
            drive_qd,
            drive_tau,
            gaps,
        };
        for i in 0..p.world.robots.len() {
            let q = p.world.robots[i].initial_q.clone();
            p.set_configuration(i, &q, None);
        }
        p.forward();
        Ok(p)
    }

    pub fn raw(&self) -> (&mjModel, &mjData) {
        (self.world.model.ffi(), self.data.ffi())
    }

    pub fn data_ptr(&mut self) -> *mut mjData {
        unsafe { self.data.ffi_mut() as *mut mjData }
    }

    /// Set robot `i`'s configuration `q` (our convention: `[p; quat wxyz; joints]`) and,
    /// optionally, velocity `v` (`[v_B; omega_B; joint velocities]`, base frame).
    pub fn set_configuration(&mut self, i: usize, q: &[f64], v: Option<&[f64]>) {
        let r = &self.world.robots[i];
        let d = unsafe { self.data.ffi_mut() };
        let off_q = r.robot.model.nq - r.joint_qpos.len();
        let off_v = r.robot.model.nv - r.joint_dof.len();
        unsafe {
            for k in 0..7 {
                *d.qpos.add(r.free_qpos + k) = q[k];
            }
            for (k, &a) in r.joint_qpos.iter().enumerate() {
                *d.qpos.add(a) = q[off_q + k];
            }
            let quat = [q[3], q[4], q[5], q[6]];
            let (tw, jv) = match v {
                Some(v) => ([v[0], v[1], v[2], v[3], v[4], v[5]], &v[off_v..]),
                None => ([0.0; 6], &[][..]),
            };
            let mj = base_twist_to_mujoco(quat, tw);
            for k in 0..6 {
                *d.qvel.add(r.free_dof + k) = mj[k];
            }
            for (k, &a) in r.joint_dof.iter().enumerate() {
                *d.qvel.add(a) = jv.get(k).copied().unwrap_or(0.0);
            }
        }
    }

    /// Robot `i`'s configuration in our convention.
    pub fn configuration(&self, i: usize) -> Vec<f64> {
        let r = &self.world.robots[i];
        let d = self.data.ffi();
        let mut q = vec![0.0; 7 + r.joint_qpos.len()];
        unsafe {
            for k in 0..7 {
                q[k] = *d.qpos.add(r.free_qpos + k);
            }
            for (k, &a) in r.joint_qpos.iter().enumerate() {
                q[7 + k] = *d.qpos.add(a);
            }
        }
        q
    }

    /// Run MuJoCo's forward pass (positions, contacts, forces) without stepping.
    pub fn forward(&mut self) {
        self.data.forward();
    }

    /// Full MuJoCo state for comparisons: qpos then qvel.
    pub fn full_state(&self) -> Vec<f64> {
        let (m, d) = self.raw();
        let mut out = Vec::with_capacity((m.nq + m.nv) as usize);
        unsafe {
            out.extend_from_slice(std::slice::from_raw_parts(d.qpos, m.nq as usize));
            out.extend_from_slice(std::slice::from_raw_parts(d.qvel, m.nv as usize));
        }
        out
    }

    /// Control ticks done since construction.
    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    /// Robot `i`'s freeze servo at its current configuration: stiffness from each joint's
    /// torque limit ([`FREEZE_ERROR_AT_LIMIT`]), damping critical for the joint's own inertia
    /// (the mass matrix's diagonal, armature included) `kd = 2 sqrt(kp M_jj)`.
    fn freeze_servo(&self, i: usize, loss: DriveLoss) -> LostDrives {
        let r = &self.world.robots[i];
        let (m, d) = self.raw();
        let nv = m.nv as usize;
        // The dense mass matrix (once, at the loss), for each joint's own inertia.
        let mut full = vec![0.0; nv * nv];
        unsafe { mujoco_c::mj_fullM(m, d, full.as_mut_ptr()) };
        let mut out = LostDrives {
            loss,
            q_hold: Vec::with_capacity(r.joint_qpos.len()),
            kp: Vec::new(),
            kd: Vec::new(),
        };
        for ((&qa, &va), &a) in r.joint_qpos.iter().zip(&r.joint_dof).zip(&r.actuator) {
            let limit = unsafe {
                (*m.actuator_ctrlrange.add(2 * a + 1))
                    .abs()
                    .max((*m.actuator_ctrlrange.add(2 * a)).abs())
            };
            let inertia = full[va * nv + va];
            let kp =
                if limit.is_finite() && limit > 0.0 { limit / FREEZE_ERROR_AT_LIMIT } else { 0.0 };
            out.q_hold.push(unsafe { *d.qpos.add(qa) });
            out.kp.push(kp);
            out.kd.push(2.0 * (kp * inertia.max(0.0)).sqrt());
        }
        out
    }

    /// The lost drives' torques for the coming physics step.
    fn drive_lost(&mut self) {
        for (i, lost) in self.lost.iter().enumerate() {
            let Some(l) = lost.as_ref().filter(|l| l.loss == DriveLoss::Freeze) else { continue };
            let r = &self.world.robots[i];
            let d = unsafe { self.data.ffi_mut() };
            for (k, ((&qa, &va), &a)) in
                r.joint_qpos.iter().zip(&r.joint_dof).zip(&r.actuator).enumerate()
            {
                unsafe {
                    *d.ctrl.add(a) =
                        l.kp[k] * (l.q_hold[k] - *d.qpos.add(qa)) - l.kd[k] * *d.qvel.add(va)
                };
            }
        }
    }

    /// The drive law of every robot whose command has gains, for the coming physics step
    /// ([`DriveCommand::effort`] at the current joint state; MuJoCo clamps to `ctrlrange`).
    fn drive_commands(&mut self) {
        let t = self.data.ffi().time;
        for (i, drive) in self.drives.iter().enumerate() {
            if self.lost[i].is_some() || drive.expired(t) {
                self.gaps[i] += 1;
            }
            if !drive.active || self.lost[i].is_some() {
                continue;
            }
            let r = &self.world.robots[i];
            let n = r.actuator.len();
            let d = unsafe { self.data.ffi_mut() };
            for (k, (&qa, &va)) in r.joint_qpos.iter().zip(&r.joint_dof).enumerate() {
                unsafe {
                    self.drive_q[k] = *d.qpos.add(qa);
                    self.drive_qd[k] = *d.qvel.add(va);
                }
            }
            drive.cmd.effort(t, &self.drive_q[..n], &self.drive_qd[..n], &mut self.drive_tau[..n]);
            for (k, &a) in r.actuator.iter().enumerate() {
                let t = self.drive_tau[k];
                unsafe { *d.ctrl.add(a) = if t.is_finite() { t } else { 0.0 } };
            }
        }
    }

    /// Reset the tick count and simulated time (after settling): the scenario clock starts.
    pub fn restart_clock(&mut self) {
        self.ticks = 0;
        unsafe { self.data.ffi_mut() }.time = 0.0;
    }
}

impl Plant for MujocoPlant {
    fn robots(&self) -> &[String] {
        &self.ids
    }

    fn joints(&self, robot: usize) -> usize {
        self.world.robots[robot].joint_qpos.len()
    }

    fn state(&self, robot: usize, out: &mut RobotState) {
        let r = &self.world.robots[robot];
        let d = self.data.ffi();
        unsafe {
            let a = r.free_qpos;
            let position = [*d.qpos.add(a), *d.qpos.add(a + 1), *d.qpos.add(a + 2)];
            let mut quat =
                [*d.qpos.add(a + 3), *d.qpos.add(a + 4), *d.qpos.add(a + 5), *d.qpos.add(a + 6)];
            let n = quat.iter().map(|x| x * x).sum::<f64>().sqrt();
            quat.iter_mut().for_each(|x| *x /= n);
            out.base_pose = Pose { position, orientation: quat };
            let mut mj = [0.0; 6];
            for k in 0..6 {
                mj[k] = *d.qvel.add(r.free_dof + k);
            }
            out.base_twist = base_twist_from_mujoco(quat, mj);
            out.joint_positions.clear();
            out.joint_velocities.clear();
            for (&qa, &va) in r.joint_qpos.iter().zip(&r.joint_dof) {
                out.joint_positions.push(*d.qpos.add(qa));
                out.joint_velocities.push(*d.qvel.add(va));
            }
        }
        out.time = self.time();
        foot_forces(self.world.model.ffi(), d, r, &mut out.foot_forces);
        out.object_pose = self.measured_object();
    }

    fn set_torques(&mut self, robot: usize, tau: &[f64]) {
        if self.lost[robot].is_some() {
            return;
        }
        self.drives[robot].active = false;
        let r = &self.world.robots[robot];
        let d = unsafe { self.data.ffi_mut() };
        for (&a, &t) in r.actuator.iter().zip(tau) {
            unsafe { *d.ctrl.add(a) = if t.is_finite() { t } else { 0.0 } };
        }
    }

    fn set_drive(&mut self, robot: usize, cmd: &DriveCommand) {
        if self.lost[robot].is_some() {
            return;
        }
        if !self.drives[robot].take(cmd) {
            self.set_torques(robot, &cmd.tau_ff);
        }
    }

    fn lose_drives(&mut self, robot: usize, loss: DriveLoss) {
        self.drives[robot].active = false;
        let servo = self.freeze_servo(robot, loss);
        let r = &self.world.robots[robot];
        let d = unsafe { self.data.ffi_mut() };
        for &a in &r.actuator {
            unsafe { *d.ctrl.add(a) = 0.0 };
        }
        self.lost[robot] = Some(servo);
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
        let m = self.world.model.ffi() as *const mjModel;
        for _ in 0..self.world.substeps {
            self.drive_lost();
            self.drive_commands();
            let t = self.data.ffi().time;
            let d = unsafe { self.data.ffi_mut() as *mut mjData };
            unsafe { self.perturbations.apply(&*m, &mut *d, &self.world, t) };
            unsafe { mujoco_c::mj_step(m, d) };
        }
        self.ticks += 1;
    }

    fn time(&self) -> f64 {
        self.data.ffi().time
    }

    fn ground_truth(&self, team: &str, tick: u64, out: &mut GroundTruth) -> bool {
        crate::ground_truth::compute(&self.world, self.data.ffi(), team, tick, out);
        true
    }

    fn perturb(&mut self, req: &PerturbationRequest) -> Result<(), String> {
        let now = self.time();
        self.perturbations.add_request(&self.world, req, now).map_err(|e| e.to_string())
    }
}

/// Each foot's normal contact force, N, in the description's foot order (the sum over the
/// foot's contacts with anything but its own robot's palm): what foot sensors would measure.
fn foot_forces(m: &mjModel, d: &mjData, r: &crate::world::RobotIndex, out: &mut Vec<f64>) {
    out.clear();
    out.resize(r.foot_bodies.len(), 0.0);
    for i in 0..d.ncon as usize {
        let c = unsafe { &*d.contact.add(i) };
        for (g, other) in [(c.geom[0], c.geom[1]), (c.geom[1], c.geom[0])] {
            if !r.foot_geoms.iter().any(|&f| f as i32 == g)
                || r.hand_geoms.iter().any(|&h| h as i32 == other)
            {
                continue;
            }
            let body = unsafe { *m.geom_bodyid.add(g as usize) } as usize;
            if let Some(k) = r.foot_bodies.iter().position(|&b| b == body) {
                let mut f = [0.0; 6];
                unsafe { mujoco_c::mj_contactForce(m, d, i as i32, &mut f) };
                out[k] += f[0].max(0.0);
            }
        }
    }
}
