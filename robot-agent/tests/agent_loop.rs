//! The agent loop over real Zenoh: the agent runs in-process (`agent::run`) on its own session
//! (no listener, no connection: no test meets another's messages) and the test publishes states,
//! commands and contact sets on that session, as the sim-bridge and the coordinator would.

#[path = "common/hold_law.rs"]
mod hold_law;
use hold_law::{hold_kd, hold_kp};
use std::time::Duration;

use protocol::keys::{self, RobotTopic};
use protocol::transport::{self, decode_sample, Qos, Role, SampleQueue, TypedPublisher, ZenohArgs};
use protocol::{
    AgentMode, AgentStatus, ContactSet, DriveCommand, DynamicsTerms, FrameRole, Header, Message,
    Pose, RobotDescription, RobotState, TorqueCommand, Validate,
};
use robot_agent::agent::{
    self, AgentConfig, AgentCounters, CommandDeadline, HoldGains, ModelDynamics,
};
use robot_model::{default_robot_path, Robot};
use zenoh::Session;

const ID: &str = "r1";
const WAIT: Duration = Duration::from_secs(10);

fn robot() -> Robot {
    Robot::load(default_robot_path()).unwrap()
}

/// The standing state at `tick`, with joint 0 moved by `dq0` and joint velocities `qd`.
fn standing_state(robot: &Robot, team: &str, tick: u64, dq0: f64, qd: f64) -> RobotState {
    let q = robot.standing_q.as_slice();
    let mut joints = q[7..].to_vec();
    joints[0] += dq0;
    RobotState {
        header: Header::new(team, Some(ID), tick, protocol::wall_clock_ns()),
        base_pose: Pose { position: [q[0], q[1], q[2]], orientation: [q[3], q[4], q[5], q[6]] },
        base_twist: [0.0; 6],
        joint_positions: joints,
        joint_velocities: vec![qd; robot.joints()],
        time: tick as f64 * 0.005,
        foot_forces: Vec::new(),
        object_pose: None,
    }
}

fn command(team: &str, robot: &str, tick: u64, tau: Vec<f64>) -> TorqueCommand {
    TorqueCommand {
        header: Header::new(team, Some(robot), tick, 0),
        tau,
        hold: false,
        delay_ticks: 0,
        qdd: Vec::new(),
    }
}

struct Harness {
    team: String,
    session: Session,
    states: TypedPublisher<RobotState>,
    commands: TypedPublisher<TorqueCommand>,
    contacts: TypedPublisher<ContactSet>,
    dynamics: SampleQueue,
    torques: SampleQueue,
    status: SampleQueue,
    description: SampleQueue,
    agent: agent::AgentThread,
}

impl Harness {
    async fn start(team: &str, cfg: impl FnOnce(AgentConfig) -> AgentConfig) -> Harness {
        let session = transport::open(&ZenohArgs::default(), Role::Alone).await.unwrap();
        let key = |t| keys::robot(team, ID, t).unwrap();
        let dynamics = transport::subscribe(&session, key(RobotTopic::Dynamics)).await.unwrap();
        let torques = transport::subscribe(&session, key(RobotTopic::Torque)).await.unwrap();
        let status = transport::subscribe(&session, key(RobotTopic::Status)).await.unwrap();
        let description =
            transport::subscribe(&session, key(RobotTopic::Description)).await.unwrap();
        let states =
            TypedPublisher::declare(&session, key(RobotTopic::State), Qos::HotPath).await.unwrap();
        let commands = TypedPublisher::declare(&session, key(RobotTopic::Command), Qos::HotPath)
            .await
            .unwrap();
        let contacts =
            TypedPublisher::declare(&session, keys::contacts(team, ID).unwrap(), Qos::HotPath)
                .await
                .unwrap();
        let mut c = AgentConfig::new(team, ID);
        c.status_period = Duration::from_millis(20);
        let c = cfg(c);
        let source = ModelDynamics::new(robot()).unwrap();
        let agent = agent::spawn(&session, c, source).unwrap();
        let mut h = Harness {
            team: team.into(),
            session,
            states,
            commands,
            contacts,
            dynamics,
            torques,
            status,
            description,
            agent,
        };
        // The first status comes after every subscription of the agent is declared.
        h.status_where(|_| true).await;
        h
    }

    async fn state(&mut self, s: &RobotState) {
        self.states.put(s).await.unwrap();
    }

    async fn command(&mut self, c: &TorqueCommand) {
        self.commands.put(c).await.unwrap();
    }

    async fn next<M: Message>(q: &SampleQueue) -> M {
        let sample = tokio::time::timeout(WAIT, q.recv_async()).await.expect("timed out").unwrap();
        decode_sample(&sample).unwrap()
    }

    async fn dynamics_of(&mut self, tick: u64) -> DynamicsTerms {
        loop {
            let d: DynamicsTerms = Self::next(&self.dynamics).await;
            if d.header.tick == tick {
                return d;
            }
        }
    }

    async fn torque(&mut self) -> DriveCommand {
        Self::next(&self.torques).await
    }

    async fn status_where(&mut self, pred: impl Fn(&AgentStatus) -> bool) -> AgentStatus {
        let deadline = tokio::time::Instant::now() + WAIT;
        loop {
            let left = deadline.saturating_duration_since(tokio::time::Instant::now());
            let sample = tokio::time::timeout(left, self.status.recv_async())
                .await
                .expect("status never matched")
                .unwrap();
            let s: AgentStatus = decode_sample(&sample).unwrap();
            if pred(&s) {
                return s;
            }
        }
    }

    /// No torque arrives within `d`.
    async fn no_torque_for(&mut self, d: Duration) {
        if let Ok(Ok(sample)) = tokio::time::timeout(d, self.torques.recv_async()).await {
            let t: DriveCommand = decode_sample(&sample).unwrap();
            panic!("unexpected torque for tick {}: {:?}", t.header.tick, t.tau_ff);
        }
    }

    async fn stop(self) -> AgentCounters {
        let joined = tokio::task::spawn_blocking(move || self.agent.join());
        let counters = tokio::time::timeout(WAIT, joined).await.unwrap().unwrap().unwrap().counters;
        self.session.close().await.unwrap();
        counters
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn publishes_dynamics_for_each_state_for_its_contact_set_and_its_description() {
    let robot = robot();
    let mut h = Harness::start("loop1", |c| c.with_deadline_time(Duration::from_secs(5))).await;
    let team = h.team.clone();

    // The description, at start.
    let d: RobotDescription = Harness::next(&h.description).await;
    d.validate().unwrap();
    assert_eq!(d.header.robot_id(), ID);
    assert_eq!(d.joint_names, robot.actuated_joints);
    assert_eq!(d.torque_limits, robot.torque_limits);
    assert_eq!((d.nq, d.nv), (25, 24));
    assert_eq!(d.hand_frame, "hand_contact");

    for tick in 0..5 {
        h.state(&standing_state(&robot, &team, tick, 0.0, 0.0)).await;
        let terms = h.dynamics_of(tick).await;
        terms.validate().unwrap();
        assert_eq!(terms.state_tick, tick);
        assert_eq!(terms.nv(), 24);
        assert_eq!(terms.mass_matrix.rows(), 24);
        assert!((terms.mass_matrix.get(0, 0).unwrap() - robot.model.total_mass).abs() < 1e-9);
        // Default contact set: every foot in stance, the hand in the grasp.
        assert!(terms.hand_in_grasp);
        let names: Vec<(&str, FrameRole)> =
            terms.frames.iter().map(|f| (f.name.as_str(), f.role)).collect();
        assert_eq!(
            names,
            vec![
                ("LF_FOOT", FrameRole::StanceFoot),
                ("RF_FOOT", FrameRole::StanceFoot),
                ("LH_FOOT", FrameRole::StanceFoot),
                ("RH_FOOT", FrameRole::StanceFoot),
                ("hand_contact", FrameRole::Hand),
                ("base", FrameRole::Torso),
            ]
        );
        // Stance feet on the ground (the contact point, the sphere's bottom), hand where the
        // description says.
        for f in &terms.frames[..4] {
            assert!(f.position[2].abs() < 1e-3, "{} at {:?}", f.name, f.position);
            assert_eq!(f.jacobian.rows(), 3);
        }
        let hand = &terms.frames[4];
        let hp = robot.standing_hand_position;
        let base_z = robot.standing_q[2];
        assert!(
            (hand.position[0] - hp[0]).abs() < 1e-3
                && (hand.position[2] - (base_z + hp[2])).abs() < 1e-3
        );
        assert_eq!(hand.jacobian.rows(), 6);
    }

    // Lift the left front foot and open the hand: the next terms say so.
    let set = ContactSet {
        header: Header::new(&team, Some(ID), 5, 0),
        stance_feet: vec!["RF_FOOT".into(), "LH_FOOT".into(), "RH_FOOT".into()],
        hand_in_grasp: false,
    };
    h.contacts.put(&set).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    h.state(&standing_state(&robot, &team, 5, 0.0, 0.0)).await;
    let terms = h.dynamics_of(5).await;
    assert!(!terms.hand_in_grasp);
    assert_eq!(terms.frames_with(FrameRole::StanceFoot).count(), 3);
    let swing: Vec<&str> =
        terms.frames_with(FrameRole::SwingFoot).map(|f| f.name.as_str()).collect();
    assert_eq!(swing, vec!["LF_FOOT"]);

    // An unknown foot is refused: the contact set stays as it was.
    let bad = ContactSet {
        header: Header::new(&team, Some(ID), 6, 0),
        stance_feet: vec!["LF_FOOT".into(), "XX_FOOT".into()],
        hand_in_grasp: true,
    };
    h.contacts.put(&bad).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    h.state(&standing_state(&robot, &team, 6, 0.0, 0.0)).await;
    let terms = h.dynamics_of(6).await;
    assert!(!terms.hand_in_grasp);
    assert_eq!(terms.frames_with(FrameRole::SwingFoot).count(), 1);

    // A set sent ahead for tick 8 lands the foot: not before tick 8, and only once the foot's
    // measured force confirms the touchdown.
    let land = ContactSet {
        header: Header::new(&team, Some(ID), 8, 0),
        stance_feet: vec!["LF_FOOT".into(), "RF_FOOT".into(), "LH_FOOT".into(), "RH_FOOT".into()],
        hand_in_grasp: true,
    };
    h.contacts.put(&land).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    for (tick, lf_force, swinging) in [(7, 0.0, 1), (8, 0.0, 1), (9, 80.0, 0)] {
        let mut st = standing_state(&robot, &team, tick, 0.0, 0.0);
        st.foot_forces = vec![lf_force, 100.0, 100.0, 100.0];
        h.state(&st).await;
        let terms = h.dynamics_of(tick).await;
        assert_eq!(terms.frames_with(FrameRole::SwingFoot).count(), swinging, "tick {tick}");
        assert_eq!(terms.hand_in_grasp, tick >= 8, "tick {tick}");
    }

    let c = h.stop().await;
    assert_eq!(c.states, 10);
    assert_eq!(c.dynamics, 10);
    assert_eq!((c.liftoffs, c.touchdowns), (1, 1));
    assert_eq!((c.contacts_applied, c.contacts_rejected), (2, 1));
    assert!(c.descriptions >= 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rejects_stale_wrong_robot_wrong_size_nan_future_and_old_commands_and_clamps() {
    let robot = robot();
    let mut h = Harness::start("loop2", |mut c| {
        c.deadline = CommandDeadline { ticks: 0, time: Some(Duration::from_secs(5)) };
        c.max_command_age_ticks = 5;
        c
    })
    .await;
    let team = h.team.clone();
    let n = robot.joints();

    h.state(&standing_state(&robot, &team, 1, 0.0, 0.0)).await;
    h.dynamics_of(1).await;
    let good: Vec<f64> = (0..n).map(|i| 0.5 * i as f64 - 3.0).collect();
    h.command(&command(&team, ID, 1, good.clone())).await;
    let t = h.torque().await;
    assert_eq!((t.header.tick, t.header.robot_id()), (1, ID));
    assert_eq!(t.tau_ff, good);

    // Stale (tick 1 again), another robot's, wrong size, from the future.
    h.command(&command(&team, ID, 1, good.clone())).await;
    h.command(&command(&team, "r9", 1, good.clone())).await;
    h.command(&command(&team, ID, 1, vec![0.0; n - 1])).await;
    h.command(&command(&team, ID, 7, good.clone())).await;
    // NaN: bytes encoded without validation, published raw.
    let mut nan = command(&team, ID, 1, good.clone());
    nan.tau[3] = f64::NAN;
    let mut bytes = Vec::new();
    protocol::codec::encode_into(&nan, &mut bytes).unwrap();
    h.session.put(keys::robot(&team, ID, RobotTopic::Command).unwrap(), bytes).await.unwrap();
    let s = h.status_where(|s| s.commands_rejected == 5).await;
    assert_eq!(s.commands_applied, 1);
    assert_eq!(s.last_applied_tick, Some(1));
    assert!(
        s.last_rejection.as_deref().unwrap_or("").contains("non-finite"),
        "{:?}",
        s.last_rejection
    );
    h.no_torque_for(Duration::from_millis(200)).await;

    // Too old: the state of tick 2, then six ticks later that of tick 8 (at most 5 ticks).
    h.state(&standing_state(&robot, &team, 2, 0.0, 0.0)).await;
    h.dynamics_of(2).await;
    h.state(&standing_state(&robot, &team, 8, 0.0, 0.0)).await;
    h.dynamics_of(8).await;
    h.command(&command(&team, ID, 2, good.clone())).await;
    let s = h.status_where(|s| s.commands_rejected == 6).await;
    assert!(
        s.last_rejection.as_deref().unwrap_or("").contains("6 ticks old, at most 5"),
        "{:?}",
        s.last_rejection
    );
    h.no_torque_for(Duration::from_millis(100)).await;

    // Over the limits: clamped, applied, counted.
    h.state(&standing_state(&robot, &team, 9, 0.0, 0.0)).await;
    h.dynamics_of(9).await;
    let mut over = vec![1.0; n];
    over[0] = 100.0; // leg, limit 80
    over[12] = -50.0; // arm_joint_1, limit 39
    over[17] = 9.5; // arm_joint_6, limit 9
    h.command(&command(&team, ID, 9, over)).await;
    let t = h.torque().await;
    assert_eq!(t.header.tick, 9);
    assert_eq!((t.tau_ff[0], t.tau_ff[12], t.tau_ff[17], t.tau_ff[1]), (80.0, -39.0, 9.0, 1.0));
    let s = h.status_where(|s| s.commands_clamped == 1).await;
    assert_eq!((s.commands_applied, s.commands_rejected, s.last_applied_tick), (2, 6, Some(9)));
    assert_eq!(s.mode, AgentMode::Commanded);

    let c = h.stop().await;
    assert_eq!((c.applied, c.rejected, c.clamped, c.safe_mode_entries), (2, 6, 1, 0));
}

/// The joint torques that hold the robot up at rest on its four feet at `state`, written out
/// again: the model's gravity from RNEA at zero velocity and acceleration, the feet's least-norm
/// forces on the base by an SVD pseudo-inverse, `tau = g_a - J_ca^T pinv(J_cb^T) g_b` (not the
/// agent's own solve; the contact Jacobians are the agent's terms).
fn gravity_oracle(robot: &Robot, state: &RobotState) -> Vec<f64> {
    use robot_agent::agent::DynamicsSource;
    use robot_agent::terms::{empty_terms, ActiveContacts as Contacts};
    let mut q = robot.standing_q.clone();
    q.as_mut_slice()[7..].copy_from_slice(&state.joint_positions);
    let mut data = robot_model::Data::new(&robot.model);
    let nv = robot.model.nv;
    let zero = vec![0.0; nv];
    let g = robot_model::rnea(&robot.model, &mut data, q.as_slice(), &zero, &zero).unwrap();
    // The four stance feet's contact-point Jacobians, as the agent publishes them.
    let mut terms = empty_terms("t", ID);
    ModelDynamics::new(robot.clone())
        .unwrap()
        .compute(state, &Contacts::all_stance(robot), &mut terms)
        .unwrap();
    let feet: Vec<nalgebra::DMatrix<f64>> =
        terms.frames_with(FrameRole::StanceFoot).map(|f| f.jacobian.to_dmatrix()).collect();
    assert_eq!(feet.len(), 4);
    let jc = nalgebra::DMatrix::from_fn(12, nv, |r, c| feet[r / 3][(r % 3, c)]);
    // Least-norm foot forces balancing the base rows: lambda = pinv(J_cb^T) g_b, by SVD.
    let jcb_t = jc.columns(0, 6).transpose();
    let lambda = jcb_t.clone().pseudo_inverse(1e-12).unwrap() * g.rows(0, 6);
    assert!((&jcb_t * &lambda - g.rows(0, 6)).norm() < 1e-6, "the feet balance the base");
    // Physics: the feet carry the robot's weight (world z up).
    let up: f64 = (0..4).map(|k| lambda[3 * k + 2]).sum();
    let weight = robot.model.total_mass * 9.81;
    assert!((up - weight).abs() < 1e-6 * weight, "the feet carry {up} N of a {weight} N robot");
    let tau = g - jc.transpose() * lambda;
    robot.actuated_indices.iter().map(|&i| tau[i]).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn enters_safe_mode_after_the_deadline_holds_posture_and_leaves_on_a_fresh_command() {
    let robot = robot();
    // Ticks only, so that the entry tick is exact on a loaded machine.
    let mut h = Harness::start("loop3", |mut c| {
        c.deadline = CommandDeadline { ticks: 5, time: None };
        c.max_command_age = Duration::from_secs(5);
        // Commands apply at once when they take over (the takeover has its own test).
        c.takeover = Duration::ZERO;
        c
    })
    .await;
    let team = h.team.clone();
    let n = robot.joints();

    h.state(&standing_state(&robot, &team, 0, 0.0, 0.0)).await;
    h.dynamics_of(0).await;
    h.command(&command(&team, ID, 0, vec![1.0; n])).await;
    assert_eq!(h.torque().await.header.tick, 0);
    h.status_where(|s| s.mode == AgentMode::Commanded).await;

    // Ticks 1..4 without commands: still commanded, no torques.
    for tick in 1..5 {
        h.state(&standing_state(&robot, &team, tick, 0.0, 0.0)).await;
        h.dynamics_of(tick).await;
    }
    h.no_torque_for(Duration::from_millis(150)).await;
    // Tick 5: five ticks since the last command: safe mode, holding the standing pose and
    // carrying what the last command (1 N m per joint) carried beyond gravity: at the held
    // posture the hold is that command.
    let standing = standing_state(&robot, &team, 5, 0.0, 0.0);
    h.state(&standing).await;
    let t = h.torque().await;
    assert_eq!(t.header.tick, 5);
    let g = gravity_oracle(&robot, &standing);
    for i in 0..n {
        assert!(
            (t.tau_ff[i] - 1.0).abs() < 1e-9,
            "joint {i}: hold {} vs the last command 1.0",
            t.tau_ff[i]
        );
    }
    assert!(g.iter().any(|x| x.abs() > 1.0), "gravity torques are not trivially zero");
    let s = h.status_where(|s| s.mode == AgentMode::SafeMode).await;
    assert_eq!(s.safe_mode_entries, 1);

    // Tick 6: joint 0 pushed 0.01 rad away and every joint moving at 0.1 rad/s: PD + gravity
    // + the carried load (1 - g at the held posture).
    let pushed = standing_state(&robot, &team, 6, 0.01, 0.1);
    h.state(&pushed).await;
    let t = h.torque().await;
    assert_eq!(t.header.tick, 6);
    let (g6, g5) = (gravity_oracle(&robot, &pushed), g);
    for i in 0..n {
        let dq = if i == 0 { -0.01 } else { 0.0 };
        let limit = robot.torque_limits[i];
        let want = (hold_kp(limit) * dq - hold_kd(limit) * 0.1 + g6[i] + (1.0 - g5[i]))
            .clamp(-robot.torque_limits[i], robot.torque_limits[i]);
        assert!((t.tau_ff[i] - want).abs() < 1e-6, "joint {i}: {} vs {want}", t.tau_ff[i]);
    }

    // A command of tick 5 (before safe mode was entered) does not end it ...
    h.command(&command(&team, ID, 5, vec![2.0; n])).await;
    let s = h.status_where(|s| s.commands_rejected == 1).await;
    assert_eq!(s.mode, AgentMode::SafeMode);
    assert!(
        s.last_rejection.as_deref().unwrap_or("").contains("safe mode"),
        "{:?}",
        s.last_rejection
    );
    h.no_torque_for(Duration::from_millis(100)).await;
    // ... a command of the fresh tick 6 does.
    h.command(&command(&team, ID, 6, vec![2.0; n])).await;
    let t = h.torque().await;
    assert_eq!((t.header.tick, t.tau_ff[0]), (6, 2.0));
    let s = h.status_where(|s| s.mode == AgentMode::Commanded).await;
    assert_eq!((s.commands_applied, s.last_applied_tick, s.safe_mode_entries), (2, Some(6), 1));

    let c = h.stop().await;
    assert_eq!(c.hold_torques, 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn enters_safe_mode_by_time_without_new_states() {
    let robot = robot();
    let mut h = Harness::start("loop4", |mut c| {
        c.deadline = CommandDeadline { ticks: 0, time: Some(Duration::from_millis(50)) };
        c.first_command = c.deadline;
        c.max_command_age = Duration::from_secs(5);
        c.takeover = Duration::ZERO;
        c
    })
    .await;
    let team = h.team.clone();
    let state = standing_state(&robot, &team, 0, 0.0, 0.0);
    h.state(&state).await;
    h.dynamics_of(0).await;
    // No command at all: after 50 ms the agent holds its posture for the latest tick.
    let t = h.torque().await;
    assert_eq!(t.header.tick, 0);
    let g = gravity_oracle(&robot, &state);
    assert!(t.tau_ff.iter().zip(&g).all(|(a, b)| (a - b).abs() < 1e-6));
    let s = h.status_where(|s| s.mode == AgentMode::SafeMode).await;
    assert_eq!(s.safe_mode_entries, 1);
    // A command for tick 0 is not fresh; tick 1 is.
    h.command(&command(&team, ID, 0, vec![0.0; robot.joints()])).await;
    h.status_where(|s| s.commands_rejected == 1).await;
    h.state(&standing_state(&robot, &team, 1, 0.0, 0.0)).await;
    h.dynamics_of(1).await;
    // The hold torques of tick 1 come first (still in safe mode), then the command's.
    let hold = h.torque().await;
    assert_eq!(hold.header.tick, 1);
    h.command(&command(&team, ID, 1, vec![0.5; robot.joints()])).await;
    let t = h.torque().await;
    assert_eq!((t.header.tick, t.tau_ff[0]), (1, 0.5));
    h.status_where(|s| s.mode == AgentMode::Commanded).await;
    h.stop().await;
}

/// The blends' tests: safe mode two ticks without a command (ticks only), no age limit a loaded
/// machine could trip, and a takeover of 20 ms (4 ticks of 5 ms of robot time).
fn blending(mut c: AgentConfig) -> AgentConfig {
    c.deadline = CommandDeadline { ticks: 2, time: None };
    c.max_command_age = Duration::from_secs(5);
    c.takeover = Duration::from_millis(20);
    c
}

/// Entering safe mode from commands blends the other way: over the takeover (20 ms, 4 ticks of
/// 5 ms) the torque moves linearly from the last command to the hold. The joints move at `qd`,
/// so the hold (carrying the last command, at the same posture) is `cmd - Kd qd`: its damping
/// comes in over the 4 ticks instead of at once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_posture_hold_takes_over_from_the_last_command_without_a_jump() {
    let robot = robot();
    let mut h = Harness::start("loop6", blending).await;
    let (team, n) = (h.team.clone(), robot.joints());
    let (cmd, qd) = (vec![3.0; n], 0.2);
    let kd: Vec<f64> = robot.torque_limits.iter().map(|l| hold_kd(*l)).collect();
    for tick in 0..2 {
        h.state(&standing_state(&robot, &team, tick, 0.0, qd)).await;
        h.dynamics_of(tick).await;
        h.command(&command(&team, ID, tick, cmd.clone())).await;
        assert_eq!(h.torque().await.tau_ff, cmd);
    }
    h.state(&standing_state(&robot, &team, 2, 0.0, qd)).await;
    h.dynamics_of(2).await;
    // Tick 3 is the deadline (two ticks after the last command): safe mode.
    for (k, tick) in (3..9).enumerate() {
        h.state(&standing_state(&robot, &team, tick, 0.0, qd)).await;
        h.dynamics_of(tick).await;
        let t = h.torque().await;
        assert_eq!(t.header.tick, tick);
        let a = (k as f64 * 0.25).min(1.0);
        for i in 0..n {
            let want = cmd[i] - a * kd[i] * qd;
            assert!(
                (t.tau_ff[i] - want).abs() < 1e-6,
                "tick {tick} joint {i}: {} vs {want} (weight of the hold {a})",
                t.tau_ff[i]
            );
        }
    }
    assert_eq!(h.stop().await.safe_mode_entries, 1);
}

/// After safe mode, commands take over from the posture hold without a jump: over the
/// takeover (20 ms of robot time here, 4 ticks of 5 ms) the torque applied moves linearly from
/// the hold torque (gravity at the standing pose: the RNEA oracle) to the command; a hold order
/// in between starts the blend again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commands_take_over_from_the_posture_hold_without_a_jump() {
    let robot = robot();
    let mut h = Harness::start("loop5", blending).await;
    let (team, n) = (h.team.clone(), robot.joints());
    let cmd = vec![3.0; n];
    for tick in 0..3 {
        h.state(&standing_state(&robot, &team, tick, 0.0, 0.0)).await;
        h.dynamics_of(tick).await;
    }
    // Two ticks without a command: safe mode, the hold of tick 2.
    let hold = h.torque().await;
    assert_eq!(hold.header.tick, 2);
    let g = gravity_oracle(&robot, &standing_state(&robot, &team, 2, 0.0, 0.0));
    // Commands of ticks 3..: each state 5 ms later, so the command's weight is (t - t3) / 20 ms.
    for (k, tick) in (3..9).enumerate() {
        h.state(&standing_state(&robot, &team, tick, 0.0, 0.0)).await;
        h.dynamics_of(tick).await;
        if tick == 3 {
            // Still in safe mode at this state: its hold comes first.
            assert_eq!(h.torque().await.header.tick, 3);
        }
        h.command(&command(&team, ID, tick, cmd.clone())).await;
        let t = h.torque().await;
        assert_eq!(t.header.tick, tick);
        let a = (k as f64 * 0.25).min(1.0);
        for i in 0..n {
            let want = (1.0 - a) * g[i] + a * cmd[i];
            assert!(
                (t.tau_ff[i] - want).abs() < 1e-6,
                "tick {tick} joint {i}: {} vs {want} (weight {a})",
                t.tau_ff[i]
            );
        }
    }
    // A hold order, then a command: the blend starts again from the hold, which carries the
    // last command's load (at the same posture: the last command itself).
    h.state(&standing_state(&robot, &team, 9, 0.0, 0.0)).await;
    h.dynamics_of(9).await;
    h.command(&TorqueCommand::hold(&team, ID, 9)).await;
    let t = h.torque().await;
    assert!(
        t.tau_ff.iter().zip(&cmd).all(|(a, b)| (a - b).abs() < 1e-9),
        "the hold order holds, carrying the load: {:?}",
        t.tau_ff
    );
    h.state(&standing_state(&robot, &team, 10, 0.0, 0.0)).await;
    h.dynamics_of(10).await;
    h.command(&command(&team, ID, 10, vec![5.0; n])).await;
    let t = h.torque().await;
    assert!(
        t.tau_ff.iter().zip(&cmd).all(|(a, b)| (a - b).abs() < 1e-9),
        "the blend restarts at the hold, not at the new command: {:?}",
        t.tau_ff
    );
    let c = h.stop().await;
    assert_eq!(c.blended, 6, "ticks 3..6 and 10 blended, 7 and 8 were the command's alone");
}

/// The posture hold without Zenoh: at zero error and zero velocity the hold torque holds the
/// robot up on its four feet, the oracle being the model's RNEA and the feet's forces by an SVD
/// pseudo-inverse (`gravity_oracle`), not the agent's own solve.
#[test]
fn posture_hold_at_the_standing_pose_is_gravity_compensation() {
    use robot_agent::agent::{DynamicsSource, PostureHold};
    use robot_agent::terms::{empty_terms, ActiveContacts as Contacts};
    let robot = robot();
    let state = standing_state(&robot, "t", 0, 0.0, 0.0);
    let oracle = gravity_oracle(&robot, &state);
    let limits = robot.torque_limits.clone();
    let contacts = Contacts::all_stance(&robot);
    let mut source = ModelDynamics::new(robot).unwrap();
    let mut terms = empty_terms("t", ID);
    source.compute(&state, &contacts, &mut terms).unwrap();
    let mut g = vec![0.0; limits.len()];
    source.actuated_gravity(&mut g);
    let mut hold = PostureHold::new(HoldGains::from_torque_limits(&limits), limits.clone());
    hold.hold(&state.joint_positions);
    let mut tau = Vec::new();
    assert_eq!(hold.torques(&state.joint_positions, &state.joint_velocities, &g, &mut tau), 0);
    for i in 0..tau.len() {
        assert!((tau[i] - oracle[i]).abs() < 1e-6, "joint {i}: {} vs {}", tau[i], oracle[i]);
    }
    // The arm's shoulder carries the arm: clearly non-zero, within its limit.
    assert!(
        oracle[13].abs() > 5.0 && oracle[13].abs() < limits[13],
        "arm_joint_2 gravity {}",
        oracle[13]
    );
}

/// The gains the agent holds with by default are the law written out above: the default
/// robot's legs (80 N m) 160 N m/rad and 4 N m s/rad, an arm's wrist (9 N m) 18 and 0.45.
#[test]
fn the_default_hold_gains_follow_the_torque_limits() {
    let limits = [80.0, 9.0, f64::INFINITY];
    let gains = HoldGains::from_torque_limits(&limits);
    for (i, l) in limits.iter().enumerate() {
        assert!(
            (gains.kp[i] - hold_kp(*l)).abs() < 1e-12 && (gains.kd[i] - hold_kd(*l)).abs() < 1e-12,
            "joint {i}: {gains:?}"
        );
    }
    assert!((gains.kp[0] - 160.0).abs() < 1e-12 && (gains.kd[0] - 4.0).abs() < 1e-12, "{gains:?}");
}
