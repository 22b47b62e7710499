//! A test-side standing controller (not the product's controller, which is the coordinator's
//! PIDC): per tick, from OUR model (`robot_model`), joint-space PD around the
//! standing configuration plus gravity compensation in which the weight is carried by the
//! stance feet: `tau = g_j - (J_c^T f)_j + Kp (q_ref - q) - Kd qdot`, where `f` are the
//! minimum-norm foot forces that balance the base rows of `g` (`J_c,base^T f = g_base`).
//! It is deterministic (same state, same torques) and used by the plant tests of this crate
//! (`tests/{standing_offline,grasp,lockstep_mujoco}.rs`). Plus [`serve`], which runs it over
//! Zenoh as a stand-in coordinator (or, `direct`, as stand-in agents).

// Index loops over joint vectors read as the equations do (as in sim-bridge, where this lived).
#![allow(clippy::needless_range_loop)]

use std::sync::Arc;

use nalgebra::{DMatrix, DVector, Matrix6xX};
use protocol::conventions::quat_from_wxyz;
use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, TransportError, TypedPublisher};
use protocol::{DriveCommand, DynamicsTerms, Header, RobotState, TorqueCommand};
use robot_model::{forward_kinematics, frame_jacobian, gravity, Data, FrameId, Robot};
use tokio::sync::watch;
use zenoh::sample::Sample;
use zenoh::Session;

/// Gains of the standing controller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StandingGains {
    pub leg_kp: f64,
    pub leg_kd: f64,
    pub arm_kp: f64,
    pub arm_kd: f64,
    pub wrist_kp: f64,
    pub wrist_kd: f64,
}

impl Default for StandingGains {
    fn default() -> Self {
        StandingGains {
            leg_kp: 400.0,
            leg_kd: 8.0,
            arm_kp: 200.0,
            arm_kd: 4.0,
            wrist_kp: 40.0,
            wrist_kd: 0.5,
        }
    }
}

/// A force the hand applies to the held object (world frame): `squeeze` newtons along the
/// palm normal plus `carry` newtons upward (a share of the object's weight).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandPush {
    pub squeeze: f64,
    pub carry: f64,
}

/// PD + stance-feet gravity compensation for one robot.
pub struct StandingController {
    hand: Option<(FrameId, HandPush)>,
    robot: Arc<Robot>,
    data: Data,
    feet: Vec<FrameId>,
    q_ref: Vec<f64>,
    kp: Vec<f64>,
    kd: Vec<f64>,
    q: Vec<f64>,
    jac: Matrix6xX<f64>,
}

impl StandingController {
    /// Around `q_ref` (joint positions, the robot's actuated order), or the standing pose.
    pub fn new(
        robot: Arc<Robot>,
        q_ref: Option<Vec<f64>>,
        gains: StandingGains,
    ) -> Result<Self, String> {
        let nj = robot.joints();
        let off = robot.model.nq - nj;
        let q_ref = q_ref.unwrap_or_else(|| robot.standing_q.as_slice()[off..].to_vec());
        if q_ref.len() != nj {
            return Err(format!("reference has {} joints, the robot {nj}", q_ref.len()));
        }
        let mut kp = Vec::new();
        let mut kd = Vec::new();
        for name in &robot.actuated_joints {
            let (p, d) = if name.starts_with("arm_joint_4")
                || name.starts_with("arm_joint_5")
                || name.starts_with("arm_joint_6")
            {
                (gains.wrist_kp, gains.wrist_kd)
            } else if name.starts_with("arm") {
                (gains.arm_kp, gains.arm_kd)
            } else {
                (gains.leg_kp, gains.leg_kd)
            };
            kp.push(p);
            kd.push(d);
        }
        let feet = robot
            .foot_frames
            .iter()
            .map(|f| robot.model.frame_id(f).map_err(|e| e.to_string()))
            .collect::<Result<Vec<_>, _>>()?;
        let data = Data::new(&robot.model);
        let nq = robot.model.nq;
        let nv = robot.model.nv;
        Ok(StandingController {
            hand: None,
            robot,
            data,
            feet,
            q_ref,
            kp,
            kd,
            q: vec![0.0; nq],
            jac: Matrix6xX::zeros(nv),
        })
    }

    /// Also push on a held object with the hand (feed-forward through the hand Jacobian, its
    /// reaction carried by the feet).
    pub fn with_hand_push(mut self, load: HandPush) -> Result<Self, String> {
        let f = self.robot.model.frame_id(&self.robot.hand_frame).map_err(|e| e.to_string())?;
        self.hand = Some((f, load));
        Ok(self)
    }

    pub fn joints(&self) -> usize {
        self.q_ref.len()
    }

    /// Torques for `state` (clamped to the torque limits).
    pub fn torques(&mut self, state: &RobotState, tau: &mut Vec<f64>) -> Result<(), String> {
        let model = &self.robot.model;
        let nj = self.q_ref.len();
        if state.joint_positions.len() != nj {
            return Err(format!(
                "state has {} joints, the robot {nj}",
                state.joint_positions.len()
            ));
        }
        let off = model.nq - nj;
        if model.floating_base {
            self.q[0..3].copy_from_slice(&state.base_pose.position);
            let u = quat_from_wxyz(state.base_pose.orientation);
            self.q[3..7].copy_from_slice(&[u.w, u.i, u.j, u.k]);
        }
        self.q[off..].copy_from_slice(&state.joint_positions);
        let g: DVector<f64> =
            gravity(model, &mut self.data, &self.q).map_err(|e| e.to_string())?.clone();
        let nb = model.nv - nj;
        let mut tau_g: Vec<f64> = g.as_slice()[nb..].to_vec();
        if model.floating_base && !self.feet.is_empty() {
            let zero = vec![0.0; model.nv];
            forward_kinematics(model, &mut self.data, &self.q, &zero).map_err(|e| e.to_string())?;
            let nc = 3 * self.feet.len();
            let mut jc = DMatrix::zeros(nc, model.nv);
            for (i, &f) in self.feet.iter().enumerate() {
                frame_jacobian(model, &self.data, f, &mut self.jac).map_err(|e| e.to_string())?;
                jc.view_mut((3 * i, 0), (3, model.nv)).copy_from(&self.jac.rows(0, 3));
            }
            // Hand wrench W on the object: g = S^T tau + J_c^T f - J_h^T W at rest.
            let mut jh_w = DVector::zeros(model.nv);
            if let Some((hf, load)) = self.hand {
                frame_jacobian(model, &self.data, hf, &mut self.jac).map_err(|e| e.to_string())?;
                let z = self.data.o_m_f[hf].rot.column(2).into_owned();
                let w = z * load.squeeze + nalgebra::Vector3::z() * load.carry;
                jh_w = self.jac.rows(0, 3).transpose() * w;
            }
            // J_c,base^T f = g_base + J_h,base^T W, minimum norm.
            let a: DMatrix<f64> = jc.columns(0, nb).transpose();
            let gb = DVector::from_column_slice(&g.as_slice()[..nb]) + jh_w.rows(0, nb);
            let f = a.clone().svd(true, true).solve(&gb, 1e-9).map_err(|e| e.to_string())?;
            let jt_f = jc.transpose() * f;
            for k in 0..nj {
                tau_g[k] += jh_w[nb + k] - jt_f[nb + k];
            }
        }
        tau.clear();
        for k in 0..nj {
            let t = tau_g[k] + self.kp[k] * (self.q_ref[k] - state.joint_positions[k])
                - self.kd[k] * state.joint_velocities[k];
            let lim = self.robot.torque_limits[k];
            tau.push(t.clamp(-lim, lim));
        }
        Ok(())
    }
}

/// Where [`serve`] sends a robot's torques: the agent's command key, or (acting as the agent)
/// the drives' torque key.
enum Out {
    Command(TypedPublisher<TorqueCommand>),
    Drive(TypedPublisher<DriveCommand>),
}

/// Each robot's torque output for [`serve`]: with `direct`, its drives' torque key (and its
/// membership declared, as its agent would); otherwise its agent's command key.
async fn declare_outputs(
    session: &Session,
    team: &str,
    robots: &[(String, StandingController)],
    direct: bool,
) -> Result<(Vec<Out>, Vec<zenoh::liveliness::LivelinessToken>), TransportError> {
    let mut pubs = Vec::new();
    let mut tokens = Vec::new();
    for (id, _) in robots {
        pubs.push(if direct {
            tokens.push(transport::declare_member(session, team, id).await?);
            Out::Drive(
                TypedPublisher::declare(
                    session,
                    keys::robot(team, id, RobotTopic::Torque)?,
                    Qos::HotPath,
                )
                .await?,
            )
        } else {
            Out::Command(
                TypedPublisher::declare(
                    session,
                    keys::robot(team, id, RobotTopic::Command)?,
                    Qos::HotPath,
                )
                .await?,
            )
        });
    }
    Ok((pubs, tokens))
}

/// A state sample for [`serve`]: kept as its robot's latest; the robot and tick to answer when
/// its agent has shown it has the state too (or at once, `direct`).
fn take_state(
    sample: &Sample,
    robots: &[(String, StandingController)],
    latest: &mut [Option<RobotState>],
    seen: &[Option<u64>],
    direct: bool,
) -> Option<(usize, u64)> {
    match decode_sample::<RobotState>(sample) {
        Ok(st) => {
            let i = robots.iter().position(|(id, _)| id == st.header.robot_id());
            let tick = st.header.tick;
            // Ready when the agent has shown it has the state too (its dynamics of
            // this tick may arrive before or after the state reaches us).
            let i = i?;
            latest[i] = Some(st);
            (direct || seen[i] == Some(tick)).then_some((i, tick))
        }
        Err(e) => {
            tracing::warn!("standing controller dropped a state: {e}");
            None
        }
    }
}

/// A dynamics sample for [`serve`] (not `direct`): the agent has seen its robot's state of
/// that tick; the robot and tick to answer.
fn take_dynamics(
    sample: &Sample,
    robots: &[(String, StandingController)],
    seen: &mut [Option<u64>],
    direct: bool,
) -> Option<(usize, u64)> {
    match decode_sample::<DynamicsTerms>(sample) {
        Ok(t) if !direct => robots.iter().position(|(id, _)| id == t.header.robot_id()).map(|i| {
            seen[i] = Some(t.state_tick);
            (i, t.state_tick)
        }),
        _ => None,
    }
}

/// Publish robot `id`'s torques `cmd` of `tick` on its output.
async fn send_torques(
    out: &mut Out,
    cmd: &TorqueCommand,
    team: &str,
    id: &str,
    tick: u64,
) -> Result<(), TransportError> {
    match out {
        Out::Command(p) => p.put(cmd).await?,
        Out::Drive(p) => {
            p.put(&DriveCommand {
                header: cmd.header.clone(),
                ..DriveCommand::torque(team, id, tick, cmd.tau.clone())
            })
            .await?
        }
    }
    Ok(())
}

/// Run standing controllers for `robots` over Zenoh as a stand-in coordinator: for each robot,
/// it keeps the latest `state(k)` and, when the robot's agent publishes `dynamics(k)` (so the
/// agent has seen the state), publishes `command(k)` on the command key. With `direct`, it
/// acts as the agents too: it declares their membership and publishes on the torque key as
/// soon as `state(k)` arrives. Runs until `stop`.
pub async fn serve(
    session: &Session,
    team: &str,
    mut robots: Vec<(String, StandingController)>,
    direct: bool,
    mut stop: watch::Receiver<bool>,
) -> Result<u64, TransportError> {
    let states = transport::subscribe(session, keys::all_robots(team, RobotTopic::State)?).await?;
    let dynamics =
        transport::subscribe(session, keys::all_robots(team, RobotTopic::Dynamics)?).await?;
    let (mut pubs, tokens) = declare_outputs(session, team, &robots, direct).await?;
    let mut latest: Vec<Option<RobotState>> = vec![None; robots.len()];
    let mut sent: Vec<Option<u64>> = vec![None; robots.len()];
    let mut seen: Vec<Option<u64>> = vec![None; robots.len()];
    let mut cmd = TorqueCommand {
        header: Header::new(team, Some(&robots[0].0), 0, 0),
        tau: Vec::new(),
        hold: false,
        delay_ticks: 0,
        qdd: Vec::new(),
    };
    let mut count = 0u64;
    loop {
        let ready: Option<(usize, u64)> = tokio::select! {
            _ = stop.changed() => { if *stop.borrow() { break; } None }
            s = states.recv_async() => {
                let Ok(sample) = s else { break };
                take_state(&sample, &robots, &mut latest, &seen, direct)
            }
            d = dynamics.recv_async() => {
                let Ok(sample) = d else { break };
                take_dynamics(&sample, &robots, &mut seen, direct)
            }
        };
        let Some((i, tick)) = ready else { continue };
        let Some(st) = latest[i].as_ref().filter(|s| s.header.tick == tick) else { continue };
        if sent[i] == Some(tick) {
            continue;
        }
        match robots[i].1.torques(st, &mut cmd.tau) {
            Ok(()) => {
                cmd.header = Header::new(team, Some(&robots[i].0), tick, protocol::wall_clock_ns());
                send_torques(&mut pubs[i], &cmd, team, &robots[i].0, tick).await?;
                sent[i] = Some(tick);
                count += 1;
            }
            Err(e) => tracing::warn!(robot = %robots[i].0, "standing controller: {e}"),
        }
    }
    drop(tokens);
    Ok(count)
}
