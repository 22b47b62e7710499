//! The agent's core driven tick by tick, without any I/O: time is an argument, outputs are
//! values. The robot is a three-joint stand-in with known limits and a constant gravity.

use std::time::{Duration, Instant};

use protocol::{
    AgentMode, ContactSet as ContactMsg, DynamicsTerms, Header, Matrix, Pose, RobotDescription,
    RobotState, TorqueCommand,
};
use robot_agent::core::{
    AgentConfig, AgentCore, ContactRejection, Outputs, Sent, StateRejection, COORDINATOR_GRACE,
};
use robot_agent::delay::TeamDelay;
use robot_agent::drive_gains::DriveGainsMode;
use robot_agent::dynamics_source::{DynamicsSource, SourceError};
use robot_agent::gate::CommandRejection;
use robot_agent::safe_mode::{CommandDeadline, HoldGains};
use robot_agent::terms::ActiveContacts;

const ID: &str = "r1";
const LIMITS: [f64; 3] = [10.0, 10.0, 2.0];
const GRAVITY: [f64; 3] = [1.5, -0.5, 0.25];
/// The mass matrix's diagonal (its off-diagonal entries are zero).
const INERTIA: [f64; 3] = [0.5, 1e-3, 0.2];

/// Fixed base, diagonal mass matrix, constant gravity, two feet.
struct Stub {
    feet: Vec<String>,
    last_contacts: Option<ActiveContacts>,
    /// A floating base (the fall test); fixed otherwise.
    floating: bool,
}

impl DynamicsSource for Stub {
    fn joints(&self) -> usize {
        3
    }
    fn floating_base(&self) -> bool {
        self.floating
    }
    fn torque_limits(&self) -> Vec<f64> {
        LIMITS.to_vec()
    }
    fn foot_frames(&self) -> &[String] {
        &self.feet
    }
    fn description(&self, _team: &str, _id: &str) -> Option<RobotDescription> {
        None
    }
    fn compute(
        &mut self,
        state: &RobotState,
        contacts: &ActiveContacts,
        out: &mut DynamicsTerms,
    ) -> Result<(), SourceError> {
        out.floating_base = false;
        out.nv = 3;
        out.mass_matrix = Matrix::zeros(3, 3);
        for (j, m) in INERTIA.iter().enumerate() {
            out.mass_matrix.data[j * 3 + j] = *m;
        }
        out.bias = GRAVITY.to_vec();
        out.velocity = state.joint_velocities.clone();
        out.hand_in_grasp = contacts.hand_in_grasp;
        self.last_contacts = Some(contacts.clone());
        Ok(())
    }
    fn actuated_gravity(&self, out: &mut [f64]) {
        out.copy_from_slice(&GRAVITY);
    }
}

fn core(deadline: CommandDeadline) -> AgentCore<Stub> {
    let mut cfg = AgentConfig::new("t", ID);
    cfg.deadline = deadline;
    cfg.max_command_age = Duration::from_millis(25);
    // Commands apply at once after a hold (the takeover's blend: tests/agent_loop.rs).
    cfg.takeover = Duration::ZERO;
    AgentCore::new(
        &cfg,
        Stub { feet: vec!["LF".into(), "RF".into()], last_contacts: None, floating: false },
    )
    .unwrap()
}

fn state(tick: u64, q: [f64; 3], v: [f64; 3]) -> RobotState {
    RobotState {
        header: Header::new("t", Some(ID), tick, 1_000_000_000 + tick * 5_000_000),
        base_pose: Pose::IDENTITY,
        base_twist: [0.0; 6],
        joint_positions: q.to_vec(),
        joint_velocities: v.to_vec(),
        time: tick as f64 * 0.005,
        foot_forces: Vec::new(),
        object_pose: None,
    }
}

fn command(robot: &str, tick: u64, tau: &[f64]) -> TorqueCommand {
    TorqueCommand {
        header: Header::new("t", Some(robot), tick, 0),
        tau: tau.to_vec(),
        hold: false,
        delay_ticks: 0,
        qdd: Vec::new(),
    }
}

/// A command at the team's delay `d` (the coordinator sends the longest its robots ask for).
fn delayed(d: u64, robot: &str, tick: u64, tau: &[f64]) -> TorqueCommand {
    TorqueCommand { delay_ticks: d, ..command(robot, tick, tau) }
}

fn ms(k: u64) -> Duration {
    Duration::from_millis(k)
}

/// A call's outputs in brief: the terms' tick, the torques (tick and values), the status flag.
type Summary = (Option<u64>, Option<(u64, Vec<f64>)>, bool);

fn summary(out: Outputs<'_>) -> Summary {
    (
        out.terms.map(|t| t.header.tick),
        out.drive.map(|t| (t.header.tick, t.tau_ff.clone())),
        out.status,
    )
}

#[test]
fn deadline_safe_mode_and_recovery_only_on_a_fresh_tick() {
    let t0 = Instant::now();
    let mut c = core(CommandDeadline { ticks: 5, time: Some(ms(25)) });
    assert!(c.start(t0).status);
    assert_eq!(
        c.on_command(&command(ID, 0, &[0.0; 3]), t0).unwrap_err(),
        CommandRejection::NoState
    );

    // Tick 0: terms, no torques, still waiting.
    let q = [0.1, -0.2, 0.3];
    assert_eq!(summary(c.on_state(&state(0, q, [0.0; 3]), t0).unwrap()), (Some(0), None, false));
    assert_eq!(c.mode(), AgentMode::WaitingForState);
    // Its command: clamped, applied, the mode changes (status due).
    let out = c.on_command(&command(ID, 0, &[12.0, -3.0, -2.5]), t0 + ms(1)).unwrap();
    assert_eq!(summary(out), (None, Some((0, vec![10.0, -3.0, -2.0])), true));
    assert_eq!(
        (c.mode(), c.counters().applied, c.counters().clamped),
        (AgentMode::Commanded, 1, 1)
    );

    // Ticks 1..4 without commands: nothing to apply. Tick 5: five ticks since the last
    // command: safe mode; the hold carries the last command's load beyond gravity, so at zero
    // error and velocity it is that command.
    for tick in 1..5 {
        assert_eq!(
            summary(c.on_state(&state(tick, q, [0.0; 3]), t0 + ms(1 + tick)).unwrap()),
            (Some(tick), None, false)
        );
    }
    let last = [10.0, -3.0, -2.0];
    let out = c.on_state(&state(5, q, [0.0; 3]), t0 + ms(6)).unwrap();
    assert_eq!(summary(out), (Some(5), Some((5, last.to_vec())), true));
    assert_eq!(
        (c.mode(), c.safe_mode_since(), c.counters().safe_mode_entries),
        (AgentMode::SafeMode, Some(5), 1)
    );

    // Tick 6, pushed and moving: PD about the held posture plus gravity, clamped.
    let gains = HoldGains::from_torque_limits(&LIMITS);
    let (q6, v6) = ([0.11, -0.2, 1.0], [0.1, 0.0, 0.0]);
    let out = c.on_state(&state(6, q6, v6), t0 + ms(7)).unwrap();
    let (_, torques, status) = summary(out);
    let (tick, tau) = torques.unwrap();
    assert_eq!((tick, status), (6, false));
    for i in 0..3 {
        let carried = last[i] - GRAVITY[i];
        let want = (gains.kp[i] * (q[i] - q6[i]) - gains.kd[i] * v6[i] + GRAVITY[i] + carried)
            .clamp(-LIMITS[i], LIMITS[i]);
        assert!((tau[i] - want).abs() < 1e-12, "joint {i}: {} vs {want}", tau[i]);
    }
    assert_eq!(tau[2], -2.0, "-0.7 rad of error on joint 2 saturates its 2 N m");

    // A command of the entry tick does not end safe mode; one of the fresh tick 6 does.
    let r = c.on_command(&command(ID, 5, &[1.0; 3]), t0 + ms(7)).unwrap_err();
    assert_eq!(r, CommandRejection::BeforeSafeMode { tick: 5, entered: 5 });
    assert_eq!(c.mode(), AgentMode::SafeMode);
    let out = c.on_command(&command(ID, 6, &[1.0; 3]), t0 + ms(8)).unwrap();
    assert_eq!(summary(out), (None, Some((6, vec![1.0; 3])), true));
    assert_eq!((c.mode(), c.safe_mode_since()), (AgentMode::Commanded, None));

    // By time, without new states: 25 ms after the last command the timer enters safe mode
    // with the hold of the latest state (tick 6); once only.
    assert!(c.on_timer(t0 + ms(8 + 25)).drive.is_none(), "the deadline is exclusive");
    let out = c.on_timer(t0 + ms(8 + 26));
    assert!(out.status);
    assert_eq!(out.drive.map(|t| t.header.tick), Some(6));
    assert!(c.on_timer(t0 + ms(40)).drive.is_none());
    assert_eq!(
        (c.mode(), c.safe_mode_since(), c.counters().safe_mode_entries),
        (AgentMode::SafeMode, Some(6), 2)
    );
    // Tick 6 again is not fresh (repeats of the latest state are admitted, not fresh).
    c.on_state(&state(6, q6, v6), t0 + ms(41)).unwrap();
    assert!(matches!(
        c.on_command(&command(ID, 6, &[0.0; 3]), t0 + ms(41)),
        Err(CommandRejection::Stale { .. })
    ));
    let counters = c.counters();
    assert_eq!((counters.applied, counters.rejected, counters.hold_torques), (2, 3, 4));
    assert_eq!(c.status().commands_rejected, 3);
    assert!(c.status().last_rejection.as_deref().unwrap().contains("not newer"));
}

/// The coordinator's token going is not safe mode yet: back within the grace, commands go on
/// as if nothing happened; gone for the grace, the next timer holds posture (the hold at the
/// latest state, once), unless the command deadline came first.
#[test]
fn the_coordinator_gone_for_its_grace_is_safe_mode_and_back_within_it_is_nothing() {
    // Lockstep-like: no time deadline, so only the grace can end the wait.
    let t0 = Instant::now();
    let grace = COORDINATOR_GRACE;
    let mut c = core(CommandDeadline { ticks: 0, time: None });
    c.start(t0);
    let q = [0.1, -0.2, 0.3];
    c.on_state(&state(0, q, [0.0; 3]), t0).unwrap();
    c.on_command(&command(ID, 0, &[1.0, 2.0, 0.5]), t0).unwrap();
    // A link that drops and comes back: the token goes and is back 5 ms later. Tick 0 is
    // answered (its command applied): its terms do not go again.
    assert_eq!(summary(c.on_coordinator_lost(t0 + ms(10))), (None, None, false));
    assert_eq!(
        summary(c.on_coordinator(t0 + ms(15))).0,
        None,
        "an answered state's terms do not go again"
    );
    assert_eq!(
        summary(c.on_timer(t0 + ms(10) + grace * 2)).1,
        None,
        "no hold after the token came back"
    );
    assert_eq!((c.mode(), c.counters().safe_mode_entries), (AgentMode::Commanded, 0));
    c.on_state(&state(1, q, [0.0; 3]), t0 + grace * 2).unwrap();
    // Tick 1 unanswered (its terms or its command may be lost in a drop): its terms go again,
    // to a coordinator that appears and for the state republished.
    assert_eq!(
        summary(c.on_coordinator(t0 + grace * 2)).0,
        Some(1),
        "the unanswered state's terms again"
    );
    assert_eq!(
        summary(c.on_state(&state(1, q, [0.0; 3]), t0 + grace * 2).unwrap()).0,
        Some(1),
        "the republished unanswered state's terms"
    );
    let out = c.on_command(&command(ID, 1, &[1.5, 2.0, 0.5]), t0 + grace * 2).unwrap();
    assert_eq!(summary(out).1, Some((1, vec![1.5, 2.0, 0.5])), "commands still apply");
    // Answered: republished for another robot's sake, it sends nothing.
    assert_eq!(
        summary(c.on_state(&state(1, q, [0.0; 3]), t0 + grace * 2).unwrap()),
        (None, None, false),
        "an answered state republished: no terms"
    );

    // Gone for good: nothing before the grace, the hold at the first timer after it.
    let lost = t0 + grace * 3;
    c.on_coordinator_lost(lost);
    c.on_coordinator_lost(lost + ms(20)); // a second event does not restart the grace
    assert_eq!(summary(c.on_timer(lost + grace - ms(1))).1, None);
    assert_eq!(c.mode(), AgentMode::Commanded);
    let out = c.on_timer(lost + grace);
    let (_, torques, status) = summary(out);
    assert_eq!(
        (torques.map(|t| t.0), status),
        (Some(1), true),
        "the hold at the latest state, announced"
    );
    assert_eq!(
        (c.mode(), c.safe_mode_since(), c.counters().safe_mode_entries),
        (AgentMode::SafeMode, Some(1), 1)
    );
    assert_eq!(summary(c.on_timer(lost + grace * 2)).1, None, "entered once");
    assert_eq!(c.counters().safe_mode_entries, 1);
    // A coordinator that comes back (restarted) to an agent in safe mode: its hold answered the
    // state, so no terms of a tick the robot has passed.
    c.on_state(&state(2, q, [0.0; 3]), lost + grace * 2).unwrap();
    assert_eq!(summary(c.on_coordinator(lost + grace * 3)).0, None, "no terms again in safe mode");

    // A zero grace holds at once, on the event.
    let mut cfg = AgentConfig::new("t", ID);
    cfg.coordinator_grace = Duration::ZERO;
    let mut c = AgentCore::new(
        &cfg,
        Stub { feet: vec!["LF".into(), "RF".into()], last_contacts: None, floating: false },
    )
    .unwrap();
    c.on_state(&state(0, q, [0.0; 3]), t0).unwrap();
    c.on_command(&command(ID, 0, &[1.0; 3]), t0).unwrap();
    assert_eq!(summary(c.on_coordinator_lost(t0 + ms(1))).1.map(|t| t.0), Some(0));
    assert_eq!(c.mode(), AgentMode::SafeMode);
}

#[test]
fn rejected_commands_are_counted_and_nothing_is_applied() {
    let t0 = Instant::now();
    let mut c = core(CommandDeadline { ticks: 0, time: None });
    c.on_state(&state(3, [0.0; 3], [0.0; 3]), t0).unwrap();
    let refused = [
        (command("r9", 3, &[0.0; 3]), "WrongRobot"),
        (command(ID, 3 + robot_agent::core::EARLY_TICKS + 1, &[0.0; 3]), "FromTheFuture"),
        (command(ID, 3, &[0.0; 2]), "WrongSize"),
        (command(ID, 3, &[0.0, f64::NAN, 0.0]), "NonFinite"),
    ];
    for (i, (cmd, what)) in refused.iter().enumerate() {
        let r = c.on_command(cmd, t0 + ms(1)).unwrap_err();
        assert!(format!("{r:?}").starts_with(what), "{r:?} is not {what}");
        assert_eq!(c.counters().rejected, i as u64 + 1);
    }
    let mut stamped = command(ID, 3, &[0.0; 3]);
    stamped.header.stamp_ns = 1;
    assert!(
        matches!(c.on_command(&stamped, t0 + ms(1)), Err(CommandRejection::TooOld { .. })),
        "stamped long before its state"
    );
    assert_eq!(
        c.on_undecodable_command("bad magic"),
        CommandRejection::Undecodable("bad magic".into())
    );
    assert_eq!((c.counters().rejected, c.counters().applied, c.last_applied_tick()), (6, 0, None));
    let status = c.status();
    assert_eq!((status.commands_rejected, status.mode), (6, AgentMode::WaitingForState));
    assert_eq!(status.last_rejection.as_deref(), Some("undecodable command: bad magic"));
    // A good one still passes; no deadline, so the timer never holds.
    assert!(c
        .on_command(&command(ID, 3, &[-20.0, 20.0, 0.5]), t0 + ms(2))
        .unwrap()
        .drive
        .is_some_and(|t| t.tau_ff == [-10.0, 10.0, 0.5]));
    assert!(c.on_timer(t0 + Duration::from_secs(3600)).drive.is_none());
}

#[test]
fn a_command_ahead_of_its_state_waits_for_it_and_is_checked_then() {
    let t0 = Instant::now();
    let mut c = core(CommandDeadline { ticks: 3, time: None });
    c.on_state(&state(3, [0.0; 3], [0.0; 3]), t0).unwrap();
    // Tick 4's command overtook tick 4's state: nothing now, nothing refused.
    let out = c.on_command(&command(ID, 4, &[1.0, -20.0, 0.5]), t0 + ms(1)).unwrap();
    assert!(out.drive.is_none());
    assert_eq!((c.counters().rejected, c.counters().early, c.last_applied_tick()), (0, 1, None));
    // A newer early command replaces it; the wrong size is refused at once.
    assert!(matches!(
        c.on_command(&command(ID, 5, &[0.0; 2]), t0 + ms(1)),
        Err(CommandRejection::WrongSize { .. })
    ));
    // Tick 4's state: its terms and its command, clamped, in the same outputs.
    let out = c.on_state(&state(4, [0.0; 3], [0.0; 3]), t0 + ms(5)).unwrap();
    assert!(out.terms.is_some());
    assert_eq!(
        out.drive.map(|t| (t.header.tick, t.tau_ff.clone())),
        Some((4, vec![1.0, -10.0, 0.5]))
    );
    assert_eq!((c.counters().applied, c.last_applied_tick()), (1, Some(4)));
    // The next state brings nothing: the early command was used once.
    assert!(c.on_state(&state(5, [0.0; 3], [0.0; 3]), t0 + ms(10)).unwrap().drive.is_none());
    // An early command whose state never comes (tick 7 skipped) is one tick old when tick 8
    // arrives, within the 5 allowed (the default age): it answers tick 8.
    c.on_command(&command(ID, 7, &[0.0; 3]), t0 + ms(11)).unwrap();
    let out = c.on_state(&state(8, [0.0; 3], [0.0; 3]), t0 + ms(20)).unwrap();
    assert_eq!(out.drive.map(|t| t.header.tick), Some(7));
    // One whose next state comes 6 ticks after it (ticks 10-14 skipped) is too old then.
    c.on_command(&command(ID, 9, &[0.0; 3]), t0 + ms(21)).unwrap();
    let out = c.on_state(&state(15, [0.0; 3], [0.0; 3]), t0 + ms(40)).unwrap();
    assert!(
        out.drive.is_none_or(|t| t.header.tick == 15),
        "the command 6 ticks behind is not applied"
    );
    assert_eq!(c.last_applied_tick(), Some(7));
    assert!(
        c.status().last_rejection.as_deref().unwrap().contains("6 ticks old, at most 5"),
        "{:?}",
        c.status().last_rejection
    );
}

#[test]
fn states_are_checked_and_contact_sets_apply_from_the_next_state() {
    let t0 = Instant::now();
    let mut c = core(CommandDeadline { ticks: 0, time: None });
    let mut other = state(1, [0.0; 3], [0.0; 3]);
    other.header = Header::new("t", Some("r2"), 1, 0);
    assert_eq!(
        c.on_state(&other, t0).unwrap_err(),
        StateRejection::OtherRobot { got: "r2".into() }
    );
    let mut short = state(1, [0.0; 3], [0.0; 3]);
    short.joint_velocities.pop();
    assert!(matches!(c.on_state(&short, t0), Err(StateRejection::WrongSize { got: 2, .. })));
    c.on_state(&state(2, [0.0; 3], [0.0; 3]), t0).unwrap();
    assert!(
        c.on_state(&state(2, [0.0; 3], [0.0; 3]), t0).is_ok(),
        "a repeat of the latest tick is recomputed"
    );
    assert_eq!(
        c.on_state(&state(1, [0.0; 3], [0.0; 3]), t0).unwrap_err(),
        StateRejection::OutOfOrder { tick: 1, latest: Some(2) }
    );
    c.on_undecodable_state("truncated");
    let mut three_feet = state(3, [0.0; 3], [0.0; 3]);
    three_feet.foot_forces = vec![10.0; 3];
    assert!(matches!(
        c.on_state(&three_feet, t0),
        Err(StateRejection::WrongFootForces { expected: 2, got: 3, .. })
    ));
    assert_eq!(
        (c.counters().states, c.counters().states_rejected, c.counters().dynamics),
        (2, 5, 2)
    );

    let set = |robot: &str, feet: &[&str], grasp| ContactMsg {
        header: Header::new("t", Some(robot), 0, 0),
        stance_feet: feet.iter().map(|f| f.to_string()).collect(),
        hand_in_grasp: grasp,
    };
    assert_eq!(c.contacts(), &ActiveContacts { stance: vec![true, true], hand_in_grasp: true });
    c.on_contacts(&set(ID, &["RF"], false)).unwrap();
    assert!(matches!(
        c.on_contacts(&set(ID, &["XX"], true)),
        Err(ContactRejection::UnknownFeet { .. })
    ));
    assert!(matches!(
        c.on_contacts(&set("r2", &["LF"], true)),
        Err(ContactRejection::OtherRobot { .. })
    ));
    c.on_undecodable_contacts("truncated");
    assert_eq!((c.counters().contacts_applied, c.counters().contacts_rejected), (1, 3));
    let out = c.on_state(&state(3, [0.0; 3], [0.0; 3]), t0).unwrap();
    assert!(!out.terms.unwrap().hand_in_grasp);
    assert_eq!(
        c.source().last_contacts,
        Some(ActiveContacts { stance: vec![false, true], hand_in_grasp: false })
    );
}

#[test]
fn timer_paces_the_status_and_latencies_come_from_what_was_sent() {
    let t0 = Instant::now();
    let mut cfg = AgentConfig::new("t", ID);
    cfg.deadline = CommandDeadline { ticks: 0, time: None };
    cfg.status_period = ms(100);
    let mut c =
        AgentCore::new(&cfg, Stub { feet: vec![], last_contacts: None, floating: false }).unwrap();
    let out = c.start(t0);
    assert!(out.status && out.description.is_none(), "a source without a model has no description");
    assert!(!c.on_timer(t0 + ms(99)).status);
    assert!(c.on_timer(t0 + ms(100)).status);
    assert!(!c.on_timer(t0 + ms(150)).status);
    c.on_state(&state(0, [0.0; 3], [0.0; 3]), t0 + ms(200)).unwrap();
    c.sent(&Sent { terms_at: Some(t0 + ms(200) + Duration::from_micros(40)), description: false });
    c.on_command(&command(ID, 0, &[0.0; 3]), t0 + ms(201)).unwrap();
    let s = c.status();
    assert_eq!((s.dynamics_latency_us.round(), s.command_latency_us.round()), (40.0, 960.0));
    assert_eq!((s.header.tick, s.last_applied_tick, s.states_received), (0, Some(0), 1));

    // A configuration the core cannot run with is refused at construction.
    cfg.hold_gains = Some(HoldGains { kp: vec![1.0], kd: vec![1.0] });
    let e = AgentCore::new(&cfg, Stub { feet: vec![], last_contacts: None, floating: false })
        .err()
        .unwrap();
    assert!(e.to_string().contains("posture-hold gains have 1 kp"), "{e}");
}

/// A robot that tips over goes limp for good: from the state that passes the tilt limit on,
/// each state yields joint damping only (`-K_d qdot`, clamped; written out here with the
/// posture hold's gains), no terms, commands are refused and the timer never enters safe mode;
/// the status says so, and the caller is told to leave the team, once. Standing up again does
/// not undo it.
#[test]
fn a_fallen_robot_goes_limp_refuses_commands_and_sends_no_terms() {
    let t0 = Instant::now();
    let mut cfg = AgentConfig::new("t", ID);
    cfg.deadline = CommandDeadline { ticks: 5, time: Some(ms(25)) };
    cfg.takeover = Duration::ZERO;
    let mut c =
        AgentCore::new(&cfg, Stub { feet: vec![], last_contacts: None, floating: true }).unwrap();
    c.start(t0);
    let posed = |tick: u64, q: [f64; 4], v: [f64; 3]| RobotState {
        base_pose: Pose { position: [0.0, 0.0, 0.55], orientation: q },
        ..state(tick, [0.1, 0.2, 0.3], v)
    };
    let upright = [1.0, 0.0, 0.0, 0.0];
    let tipped =
        |deg: f64| [(deg.to_radians() / 2.0).cos(), (deg.to_radians() / 2.0).sin(), 0.0, 0.0];
    assert_eq!(summary(c.on_state(&posed(0, upright, [0.0; 3]), t0).unwrap()).0, Some(0));
    c.on_command(&command(ID, 0, &[1.0, 1.0, 1.0]), t0).unwrap();
    // 55 degrees of roll: still standing (the limit is 60).
    assert_eq!(
        summary(c.on_state(&posed(1, tipped(55.0), [0.0; 3]), t0 + ms(1)).unwrap()),
        (Some(1), None, false)
    );
    assert_eq!(c.mode(), AgentMode::Commanded);
    // 65 degrees: fallen at tick 2; limp torques, no terms, the status is due.
    let v = [3.0, -40.0, 0.5];
    let kd = HoldGains::from_torque_limits(&LIMITS).kd;
    let limp: Vec<f64> = (0..3).map(|i| (-kd[i] * v[i]).clamp(-LIMITS[i], LIMITS[i])).collect();
    let out = c.on_state(&posed(2, tipped(65.0), v), t0 + ms(2)).unwrap();
    assert!(out.leave_team, "the caller is told to leave the team at the fall");
    assert_eq!(summary(out), (None, Some((2, limp.clone())), true));
    assert!(limp.iter().zip(&v).all(|(t, v)| t * v <= 0.0), "damping opposes the motion: {limp:?}");
    assert_eq!((c.mode(), c.fallen().map(|f| f.tick)), (AgentMode::Fallen, Some(2)));
    // Its commands are refused, counted, and nothing is applied.
    let r = c.on_command(&command(ID, 2, &[1.0; 3]), t0 + ms(2)).unwrap_err();
    assert_eq!(r, CommandRejection::Fallen { tick: 2, fell: 2 });
    assert_eq!(c.status().mode, AgentMode::Fallen);
    // No command for long: no safe mode (the timer yields no hold), still limp.
    assert!(c.on_timer(t0 + ms(200)).drive.is_none());
    assert_eq!((c.mode(), c.safe_mode_since()), (AgentMode::Fallen, None));
    // Upright and still: zero torque, still fallen, still no terms.
    let out = c.on_state(&posed(3, upright, [0.0; 3]), t0 + ms(201)).unwrap();
    assert!(!out.leave_team, "once");
    assert_eq!(summary(out), (None, Some((3, vec![0.0; 3])), false));
    assert_eq!(c.mode(), AgentMode::Fallen);
    assert!(c.counters().rejected >= 1);

    // A fixed base does not fall: the same states leave it commanded.
    let mut fixed = core(CommandDeadline { ticks: 5, time: Some(ms(25)) });
    fixed.start(t0);
    fixed.on_state(&posed(0, upright, [0.0; 3]), t0).unwrap();
    fixed.on_command(&command(ID, 0, &[1.0; 3]), t0).unwrap();
    assert_eq!(
        summary(fixed.on_state(&posed(1, tipped(90.0), [0.0; 3]), t0 + ms(1)).unwrap()).0,
        Some(1)
    );
    assert_eq!((fixed.mode(), fixed.fallen()), (AgentMode::Commanded, None));
}

/// Drive gains on, commands at once after a hold.
fn gains_config() -> AgentConfig {
    let mut cfg = AgentConfig::new("t", ID);
    cfg.takeover = Duration::ZERO;
    cfg.drive_gains = DriveGainsMode::Inertia;
    cfg
}

/// The stand-in without feet, fixed base.
fn stub() -> Stub {
    Stub { feet: vec![], last_contacts: None, floating: false }
}

#[test]
fn commands_carry_the_drive_gains_about_the_latest_state_and_the_hold_does_not() {
    let t0 = Instant::now();
    let mut c = AgentCore::new(&gains_config(), stub()).unwrap();
    let _ = c.start(t0);
    let (q0, q1, v1) = ([0.1, -0.2, 0.3], [0.12, -0.21, 0.35], [0.4, -0.1, 0.02]);
    let _ = c.on_state(&state(0, q0, [0.0; 3]), t0).unwrap();
    let _ = c.on_state(&state(1, q1, v1), t0 + ms(5)).unwrap();
    assert!(c.drive_gains().is_some(), "made from the first terms");
    // The command of tick 0 arrives after the state of tick 1: its reference is the trajectory
    // from tick 1's state (at its time, 5 ms) at the accelerations the command carries (not
    // the 80, -20 and 4 rad/s^2 measured from tick 0 to 1), valid for the command deadline (5
    // ticks of 5 ms, within 25 ms).
    let qdd = [3.0, -1.5, 0.5];
    let cmd = TorqueCommand { qdd: qdd.to_vec(), ..command(ID, 0, &[1.0, -0.5, 0.25]) };
    let out = c.on_command(&cmd, t0 + ms(6)).unwrap();
    let d = out.drive.unwrap().clone();
    let t1 = 0.005;
    assert_eq!(d.ref_time, Some(t1));
    assert!((d.valid_until.unwrap() - (t1 + 0.025)).abs() < 1e-12, "{:?}", d.valid_until);
    for j in 0..3 {
        let a = qdd[j];
        assert_eq!((d.q_des[j], d.qd_des[j]), (q1[j], v1[j]), "joint {j}: the state");
        assert_eq!(d.qdd_des[j], a, "joint {j}: {:?}", d.qdd_des);
        // 2.5 ms on, the drives' targets are the state carried at that acceleration.
        let s = 0.0025;
        let (q, v) = (q1[j] + v1[j] * s + 0.5 * a * s * s, v1[j] + a * s);
        let (qs, vs) = d.targets_at(j, t1 + s);
        assert!(
            (qs.unwrap() - q).abs() < 1e-12 && (vs.unwrap() - v).abs() < 1e-9,
            "joint {j}: {qs:?} {vs:?}"
        );
    }
    // Each joint a critically damped loop at the bandwidth on its inertia (stiffness and
    // damping written out), the stiffness capped where 0.05 rad would exceed the torque limit.
    let omega = 2.0 * std::f64::consts::PI * robot_agent::drive_gains::BANDWIDTH_HZ;
    for j in 0..3 {
        let kp = (omega * omega * INERTIA[j]).min(LIMITS[j] / 0.05);
        assert!((d.kp[j] - kp).abs() < 1e-9 * kp, "joint {j}: kp {} vs {kp}", d.kp[j]);
        assert!((d.kd[j] - 2.0 * omega * INERTIA[j]).abs() < 1e-12, "joint {j}: kd {}", d.kd[j]);
    }
    assert_eq!(
        d.kp[2], 40.0,
        "0.2 kg m^2 would want 197 N m/rad at 5 Hz; 2 N m at 0.05 rad caps it"
    );
    assert!(protocol::Validate::validate(&d).is_ok());
    // At the reference the law is the command's torque; away from it, it pulls back.
    let mut tau = [0.0; 3];
    d.effort(t1, &d.q_des, &d.qd_des, &mut tau);
    assert_eq!(tau, [1.0, -0.5, 0.25]);
    let pushed = [d.q_des[0] + 0.01, d.q_des[1], d.q_des[2]];
    d.effort(t1, &pushed, &d.qd_des, &mut tau);
    assert!((tau[0] - (1.0 - d.kp[0] * 0.01)).abs() < 1e-12, "{tau:?}");

    // The same state again (the lockstep bridge republishes it while it waits): the
    // reference does not change.
    let _ = c.on_state(&state(1, q1, v1), t0 + ms(7)).unwrap();
    let again = c
        .on_command(&command(ID, 1, &[1.0, -0.5, 0.25]), t0 + ms(7))
        .unwrap()
        .drive
        .unwrap()
        .clone();
    assert_eq!((again.q_des, again.qd_des), (d.q_des.clone(), d.qd_des.clone()));

    // Safe mode: the hold, answered at every state, is a torque without gains.
    let out = c.enter_safe_mode("test", t0 + ms(7));
    let hold = out.drive.unwrap();
    assert!(!hold.has_gains() && hold.q_des.is_empty() && hold.qd_des.is_empty(), "{hold:?}");

    // Without the mode, a command is its torque.
    let mut c = core(CommandDeadline { ticks: 5, time: None });
    let _ = c.on_state(&state(0, q0, [0.0; 3]), t0).unwrap();
    let d = c.on_command(&command(ID, 0, &[1.0, -0.5, 0.25]), t0).unwrap().drive.unwrap().clone();
    assert!(!d.has_gains() && d.q_des.is_empty(), "{d:?}");
    assert!(c.drive_gains().is_none());
}

/// The team answers every 4th state: the agent answers the three between alone, with the last
/// command's torque and the reference at each state; no terms go out for them; the tick
/// deadline counts the team's ticks.
#[test]
fn between_team_ticks_the_agent_answers_alone_with_the_last_torque() {
    let t0 = Instant::now();
    let mut cfg = gains_config();
    cfg.team_every = 4;
    cfg.deadline = CommandDeadline { ticks: 2, time: None };
    cfg.max_command_age = Duration::from_secs(10);
    let mut c = AgentCore::new(&cfg, stub()).unwrap();
    let _ = c.start(t0);
    let q = |k: u64| [0.1 + 0.001 * k as f64, -0.2, 0.3];
    let v = [0.2, 0.0, 0.0];
    // Tick 0, a team tick: terms, then its command.
    assert_eq!(summary(c.on_state(&state(0, q(0), v), t0).unwrap()).0, Some(0));
    let tau = [1.0, -0.5, 0.25];
    let cmd = TorqueCommand { qdd: vec![2.0, 0.0, -1.0], ..command(ID, 0, &tau) };
    assert!(c.on_command(&cmd, t0).unwrap().drive.is_some());
    // Ticks 1-3: no terms; the drive command of the tick, the last torque, the reference from
    // the state (its position and velocity at its time) at the last command's accelerations.
    for k in 1..4 {
        let out = c.on_state(&state(k, q(k), v), t0 + ms(5 * k)).unwrap();
        assert!(out.terms.is_none(), "tick {k}: no terms between team ticks");
        let d = out.drive.expect("answered alone");
        assert_eq!((d.header.tick, d.tau_ff.as_slice()), (k, &tau[..]), "tick {k}");
        assert!(d.has_gains());
        assert_eq!(
            (d.q_des[0], d.qd_des[0], d.ref_time),
            (q(k)[0], v[0], Some(k as f64 * 0.005)),
            "tick {k}"
        );
        assert_eq!(d.qdd_des, cmd.qdd, "tick {k}");
    }
    // Tick 4, a team tick: terms, and it waits for the team's command.
    let (terms, drive, _) = summary(c.on_state(&state(4, q(4), v), t0 + ms(20)).unwrap());
    assert_eq!((terms, drive), (Some(4), None));
    // No command for 8 ticks (two team ticks) is the deadline, not 2 states.
    for k in 5..8 {
        let _ = c.on_state(&state(k, q(k), v), t0 + ms(5 * k)).unwrap();
    }
    assert_eq!(
        c.mode(),
        AgentMode::Commanded,
        "no safe mode before two team ticks without a command"
    );
    for k in 8..9 {
        let _ = c.on_state(&state(k, q(k), v), t0 + ms(5 * k)).unwrap();
    }
    assert_eq!(c.mode(), AgentMode::SafeMode, "two team ticks without a command");
    // Without a command yet, a state between team ticks gets nothing.
    let mut fresh = AgentCore::new(&cfg, stub()).unwrap();
    let _ = fresh.on_state(&state(0, q(0), v), t0).unwrap();
    assert_eq!(
        summary(fresh.on_state(&state(1, q(1), v), t0 + ms(5)).unwrap()),
        (None, None, false)
    );
    cfg.team_every = 0;
    assert!(AgentCore::new(&cfg, stub()).is_err());
}

/// With a team delay of 2 ticks the command for the state of tick k applies at the state of
/// tick k + 2: the states before the first one can apply get gravity compensation with the
/// hold's damping at once (the lockstep plant waits for every tick's torques), the first
/// command follows it without the hold's blend, and commands that came early wait for their
/// state in order.
#[test]
fn a_delayed_command_applies_at_its_state_plus_the_delay() {
    let t0 = Instant::now();
    let mut cfg = AgentConfig::new("t", ID);
    cfg.team_delay = TeamDelay::Ticks(2);
    cfg.hold_gains = Some(HoldGains { kp: vec![40.0; 3], kd: vec![2.0, 3.0, 0.5] });
    cfg.deadline = CommandDeadline { ticks: 5, time: None };
    cfg.max_command_age = Duration::from_secs(10);
    let mut c = AgentCore::new(&cfg, stub()).unwrap();
    let _ = c.start(t0);
    let q = [0.1, -0.2, 0.3];
    let v = [0.4, 0.0, -0.2];
    for k in 0..2 {
        let (terms, drive, _) = summary(c.on_state(&state(k, q, v), t0 + ms(5 * k)).unwrap());
        assert_eq!(terms, Some(k), "tick {k}: terms for the team");
        let (tick, tau) = drive.expect("answered at once");
        let expected: Vec<f64> = (0..3)
            .map(|j| (GRAVITY[j] - [2.0, 3.0, 0.5][j] * v[j]).clamp(-LIMITS[j], LIMITS[j]))
            .collect();
        assert_eq!(tick, k);
        assert!(
            tau.iter().zip(&expected).all(|(a, b)| (a - b).abs() < 1e-12),
            "tick {k}: {tau:?} against {expected:?}"
        );
    }
    // The commands of ticks 0 and 1 come before the state of tick 2: both wait.
    assert!(c
        .on_command(&delayed(2, ID, 0, &[1.0, -0.5, 0.25]), t0 + ms(6))
        .unwrap()
        .drive
        .is_none());
    assert!(c
        .on_command(&delayed(2, ID, 1, &[2.0, -1.0, 0.5]), t0 + ms(7))
        .unwrap()
        .drive
        .is_none());
    // State 2 gets tick 0's command, unblended; state 3 tick 1's; state 4 waits for tick 2's.
    for (k, tau) in [(2, [1.0, -0.5, 0.25]), (3, [2.0, -1.0, 0.5])] {
        let (terms, drive, _) = summary(c.on_state(&state(k, q, v), t0 + ms(5 * k)).unwrap());
        assert_eq!((terms, drive), (Some(k), Some((k, tau.to_vec()))), "tick {k}");
    }
    assert_eq!(summary(c.on_state(&state(4, q, v), t0 + ms(20)).unwrap()), (Some(4), None, false));
    // Tick 2's command, arriving now, applies at once as the command of tick 4.
    let (_, drive, _) =
        summary(c.on_command(&delayed(2, ID, 2, &[3.0, 0.0, 0.0]), t0 + ms(21)).unwrap());
    assert_eq!(drive, Some((4, vec![3.0, 0.0, 0.0])));
    // A command for a state already answered is stale.
    assert!(matches!(
        c.on_command(&delayed(2, ID, 1, &[0.0; 3]), t0 + ms(22)),
        Err(CommandRejection::Stale { .. })
    ));
    assert_eq!(c.counters().applied, 3);
    cfg.team_delay = TeamDelay::Ticks(robot_agent::core::MAX_TEAM_DELAY + 1);
    assert!(AgentCore::new(&cfg, stub()).is_err(), "a delay over the most");
}

/// With a team delay, a coordinator that catches up (real time) may skip a tick: its command
/// never comes. A newer command waiting already says so, and the agent answers that state
/// alone with the last command's torque instead of waiting out its deadline in safe mode,
/// whether the newer command came before the state or after it.
#[test]
fn a_skipped_command_is_answered_alone_when_a_newer_one_waits() {
    let t0 = Instant::now();
    let mut cfg = AgentConfig::new("t", ID);
    cfg.team_delay = TeamDelay::Ticks(1);
    cfg.takeover = Duration::ZERO;
    cfg.deadline = CommandDeadline { ticks: 5, time: Some(ms(25)) };
    cfg.max_command_age = Duration::from_secs(10);
    let mut c = AgentCore::new(&cfg, stub()).unwrap();
    let _ = c.start(t0);
    let (q, v) = ([0.1, -0.2, 0.3], [0.0; 3]);
    let _ = c.on_state(&state(0, q, v), t0).unwrap();
    let first = [1.0, -0.5, 0.25];
    assert!(
        c.on_command(&delayed(1, ID, 0, &first), t0 + ms(1)).unwrap().drive.is_none(),
        "waits for state 1"
    );
    assert_eq!(
        summary(c.on_state(&state(1, q, v), t0 + ms(2)).unwrap()).1,
        Some((1, first.to_vec()))
    );
    // Tick 1's command is skipped: state 2 waits for it until tick 2's comes, which answers
    // state 2 with the last torque and then waits for state 3.
    assert_eq!(
        summary(c.on_state(&state(2, q, v), t0 + ms(3)).unwrap()).1,
        None,
        "its command may still come"
    );
    let second = [2.0, 0.0, -0.5];
    let (_, drive, _) = summary(c.on_command(&delayed(1, ID, 2, &second), t0 + ms(4)).unwrap());
    assert_eq!(drive, Some((2, first.to_vec())), "state 2 answered alone at once");
    assert!(
        c.on_command(&delayed(1, ID, 2, &second), t0 + ms(4)).unwrap().drive.is_none(),
        "state 2 is not answered twice"
    );
    assert_eq!(
        summary(c.on_state(&state(3, q, v), t0 + ms(5)).unwrap()).1,
        Some((3, second.to_vec()))
    );
    // Tick 3's skipped, tick 4's came first: state 4 is answered alone when it arrives.
    let third = [0.5, 0.5, 0.5];
    assert!(
        c.on_command(&delayed(1, ID, 4, &third), t0 + ms(6)).unwrap().drive.is_none(),
        "state 3 was answered; state 5 not come"
    );
    assert_eq!(
        summary(c.on_state(&state(4, q, v), t0 + ms(7)).unwrap()).1,
        Some((4, second.to_vec()))
    );
    assert_eq!(
        summary(c.on_state(&state(5, q, v), t0 + ms(8)).unwrap()).1,
        Some((5, third.to_vec()))
    );
    assert_eq!(
        (c.mode(), c.counters().safe_mode_entries),
        (AgentMode::Commanded, 0),
        "never in safe mode"
    );
}

/// `auto` ([`robot_agent::delay`]): commands that come two states after their own (the team
/// takes between two and three robot periods to answer) raise the delay a tick at a time to 3,
/// where every command waits for its state, which is then answered at once with the command
/// of three ticks before; the status says the delay, and the agent never enters safe mode.
/// Commands that come before the next state (lockstep, or a fast team) keep it at 0, unless
/// the robot's drives take an answer only within a window and they come later.
#[test]
fn auto_raises_the_delay_until_commands_come_before_their_states() {
    let t0 = Instant::now();
    let mut cfg = AgentConfig::new("t", ID);
    cfg.team_delay = TeamDelay::AUTO;
    cfg.takeover = Duration::ZERO;
    cfg.deadline = CommandDeadline { ticks: 25, time: None };
    cfg.max_command_age = Duration::from_secs(10);
    let (q, v) = ([0.1, -0.2, 0.3], [0.0; 3]);
    let tau = |k: u64| [0.001 * k as f64, 0.0, 0.0];
    let mut fast = AgentCore::new(&cfg, stub()).unwrap();
    let _ = fast.start(t0);
    for k in 0..1000 {
        let _ = fast.on_state(&state(k, q, v), t0 + ms(k)).unwrap();
        let (_, drive, _) = summary(
            fast.on_command(&delayed(fast.wanted_delay(), ID, k, &tau(k)), t0 + ms(k)).unwrap(),
        );
        assert_eq!(drive, Some((k, tau(k).to_vec())), "tick {k}: applied at its own state");
    }
    assert_eq!(fast.status().team_delay_ticks, 0, "commands on time keep the delay at 0");

    // A robot whose drives take an answer within 2 ms of its state (states 4 ms apart):
    // commands 3 ms after their state come before the next one but after the window. The
    // delay rises to 1, where each state is answered at once with the command of the one
    // before, and stays there (at 0 they would all be late again).
    let mut windowed = cfg.clone();
    windowed.answer_within = Some(ms(2));
    let mut w = AgentCore::new(&windowed, stub()).unwrap();
    let _ = w.start(t0);
    let mut answers = Vec::new();
    for k in 0..3000 {
        let (_, drive, _) = summary(w.on_state(&state(k, q, v), t0 + ms(4 * k)).unwrap());
        answers.push(drive);
        let cmd = delayed(w.wanted_delay(), ID, k, &tau(k));
        let _ = w.on_command(&cmd, t0 + ms(4 * k + 3));
    }
    assert_eq!((w.wanted_delay(), w.team_delay()), (1, 1), "raised past the window, kept");
    for (k, drive) in answers.iter().enumerate().skip(100) {
        let k = k as u64;
        assert_eq!(drive.clone(), Some((k, tau(k - 1).to_vec())), "tick {k} at its arrival");
    }

    let mut c = AgentCore::new(&cfg, stub()).unwrap();
    let _ = c.start(t0);
    let mut answered_at_arrival = Vec::new();
    for k in 0..400 {
        let (_, drive, _) = summary(c.on_state(&state(k, q, v), t0 + ms(k)).unwrap());
        answered_at_arrival.push(drive);
        if k >= 2 {
            let _ = c.on_command(&delayed(c.wanted_delay(), ID, k - 2, &tau(k - 2)), t0 + ms(k));
        }
    }
    assert_eq!(
        (c.wanted_delay(), c.team_delay(), c.status().team_delay_ticks),
        (3, 3, 3),
        "raised to the first delay the commands meet, and followed"
    );
    let settled = answered_at_arrival.len() - 100;
    for (k, drive) in answered_at_arrival.iter().enumerate().skip(settled) {
        let k = k as u64;
        assert_eq!(
            drive.clone(),
            Some((k, tau(k - 3).to_vec())),
            "tick {k}: the command of tick {} waited for it",
            k - 3
        );
    }
    assert_eq!(
        (c.mode(), c.counters().safe_mode_entries),
        (AgentMode::Commanded, 0),
        "never in safe mode"
    );
}

/// The team's delay is the newest command's: an agent configured for none follows a team delay
/// of 2 (another robot asked for it) from the command that brings it, the command applying two
/// states after its own; an older command with another delay changes nothing.
#[test]
fn the_agent_follows_the_delay_its_newest_command_brings() {
    let t0 = Instant::now();
    let mut cfg = AgentConfig::new("t", ID);
    cfg.takeover = Duration::ZERO;
    cfg.deadline = CommandDeadline { ticks: 5, time: None };
    cfg.max_command_age = Duration::from_secs(10);
    let mut c = AgentCore::new(&cfg, stub()).unwrap();
    let _ = c.start(t0);
    let (q, v) = ([0.1, -0.2, 0.3], [0.0; 3]);
    let (one, two, three) = ([1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]);
    let (terms, _, _) = summary(c.on_state(&state(0, q, v), t0).unwrap());
    assert_eq!(terms, Some(0));
    assert_eq!(
        summary(c.on_command(&delayed(0, ID, 0, &one), t0).unwrap()).1,
        Some((0, one.to_vec())),
        "no delay yet"
    );
    let _ = c.on_state(&state(1, q, v), t0 + ms(1)).unwrap();
    assert!(
        c.on_command(&delayed(2, ID, 1, &two), t0 + ms(1)).unwrap().drive.is_none(),
        "waits for state 3"
    );
    assert_eq!((c.team_delay(), c.wanted_delay(), c.status().team_delay_ticks), (2, 0, 2));
    // State 2 has no team command (the delay grew by two): answered alone with the last torque.
    assert_eq!(
        summary(c.on_state(&state(2, q, v), t0 + ms(2)).unwrap()).1,
        Some((2, one.to_vec()))
    );
    assert_eq!(
        summary(c.on_state(&state(3, q, v), t0 + ms(3)).unwrap()).1,
        Some((3, two.to_vec()))
    );
    // A late copy of tick 0's command at delay 0 is stale and leaves the delay at 2.
    assert!(c.on_command(&delayed(0, ID, 0, &three), t0 + ms(3)).is_err());
    assert_eq!(c.team_delay(), 2);
    let _ = c.on_command(&delayed(2, ID, 2, &three), t0 + ms(3));
    assert_eq!(
        summary(c.on_state(&state(4, q, v), t0 + ms(4)).unwrap()).1,
        Some((4, three.to_vec()))
    );
    assert_eq!((c.mode(), c.counters().safe_mode_entries), (AgentMode::Commanded, 0));
}
