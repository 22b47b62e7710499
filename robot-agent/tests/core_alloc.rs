//! The core's per-tick calls (state, command, timer, the posture hold) allocate nothing after
//! start-up: a counting global allocator watches this thread. The first test uses the
//! placeholder dynamics (unit mass matrix), so that only the core is measured; the second the
//! robot's own model, the agent's whole tick, with the drive gains on (each command carries
//! gains and a reference).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::time::{Duration, Instant};

use protocol::{Header, Pose, RobotState, TorqueCommand};
use robot_agent::core::{AgentConfig, AgentCore};
use robot_agent::drive_gains::DriveGainsMode;
use robot_agent::dynamics_source::{DynamicsSource, ModelDynamics, PlaceholderDynamics};
use robot_agent::safe_mode::CommandDeadline;

struct Counting;

thread_local! {
    static WATCH: Cell<bool> = const { Cell::new(false) };
    static COUNT: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = WATCH.try_with(|w| {
            if w.get() {
                COUNT.with(|c| c.set(c.get() + 1));
            }
        });
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn per_tick_calls_do_not_allocate() {
    let n = 18;
    let state = RobotState {
        header: Header::new("t", Some("r1"), 0, 0),
        base_pose: Pose::IDENTITY,
        base_twist: [0.0; 6],
        joint_positions: vec![0.1; n],
        joint_velocities: vec![0.2; n],
        time: 0.0,
        foot_forces: Vec::new(),
        object_pose: None,
    };
    let (count, applied, held) =
        ticks_allocations(PlaceholderDynamics::floating(n), state, n, DriveGainsMode::None, (1, 0));
    assert_eq!(count, 0, "the core's tick allocated {count} times");
    assert_eq!((applied, held), (180, 17), "commanded and safe-mode ticks were both exercised");
    // The counter works: an allocation while watching is seen.
    WATCH.with(|w| w.set(true));
    let v: Vec<u8> = Vec::with_capacity(16);
    WATCH.with(|w| w.set(false));
    drop(v);
    assert_eq!(COUNT.with(|c| c.get()), 1);
}

#[test]
fn the_agents_tick_on_the_robots_model_does_not_allocate() {
    let robot = robot_model::Robot::load(robot_model::default_robot_path()).unwrap();
    let q = robot.standing_q.clone();
    let n = q.len() - 7;
    let state = RobotState {
        header: Header::new("t", Some("r1"), 0, 0),
        base_pose: Pose { position: [q[0], q[1], q[2]], orientation: [q[3], q[4], q[5], q[6]] },
        base_twist: [0.0; 6],
        joint_positions: q.as_slice()[7..].to_vec(),
        joint_velocities: vec![0.01; n],
        time: 0.0,
        foot_forces: Vec::new(),
        object_pose: None,
    };
    let (count, applied, held) = ticks_allocations(
        ModelDynamics::new(robot.clone()).unwrap(),
        state.clone(),
        n,
        DriveGainsMode::Inertia,
        (1, 0),
    );
    assert_eq!(count, 0, "the agent's tick with the robot's model allocated {count} times");
    assert_eq!((applied, held), (180, 17), "commanded and safe-mode ticks were both exercised");
    // The team every 4th tick: the ticks between are answered by the agent alone.
    COUNT.with(|c| c.set(0));
    let (count, applied, held) = ticks_allocations(
        ModelDynamics::new(robot.clone()).unwrap(),
        state.clone(),
        n,
        DriveGainsMode::Inertia,
        (4, 0),
    );
    assert_eq!(count, 0, "the agent's tick between team ticks allocated {count} times");
    assert!(applied >= 180 && held >= 17, "commanded, answered alone and held: {applied} {held}");
    // The team's delay of 3 ticks: every command waits for its state among the early ones.
    COUNT.with(|c| c.set(0));
    let (count, _, answered) = ticks_allocations(
        ModelDynamics::new(robot).unwrap(),
        state,
        n,
        DriveGainsMode::Inertia,
        (1, 3),
    );
    assert_eq!(count, 0, "the agent's tick with a team delay allocated {count} times");
    assert!(
        answered >= 195,
        "every state answered from the command of three ticks before, or held: {answered}"
    );
}

/// 200 ticks of the core over `source` (10 to warm up, 20 without commands: safe mode from the
/// 5th); the allocations counted after warm-up, the ticks that applied a command and the ticks
/// that held the posture.
fn ticks_allocations(
    source: impl DynamicsSource,
    mut state: RobotState,
    n: usize,
    gains: DriveGainsMode,
    (team_every, team_delay): (u64, u64),
) -> (usize, u32, u32) {
    let mut cfg = AgentConfig::new("t", "r1");
    cfg.drive_gains = gains;
    cfg.team_every = team_every;
    cfg.team_delay = robot_agent::delay::TeamDelay::Ticks(team_delay);
    cfg.deadline = CommandDeadline { ticks: 5, time: None };
    cfg.max_command_age = Duration::from_secs(10);
    let mut core = AgentCore::new(&cfg, source).unwrap();
    let mut cmd = TorqueCommand {
        header: Header::new("t", Some("r1"), 0, 0),
        tau: vec![1.0; n],
        hold: false,
        delay_ticks: team_delay,
        qdd: vec![0.5; n],
    };
    let t0 = Instant::now();
    let _ = core.start(t0);
    let mut applied = 0;
    let mut held = 0;
    // 100 commanded ticks, then 20 without commands (safe mode from the 5th), then commanded
    // again; the first 10 ticks warm up.
    for tick in 0..200u64 {
        if tick == 10 {
            WATCH.with(|w| w.set(true));
        }
        let now = t0 + Duration::from_micros(1000 * tick);
        state.header.tick = tick;
        held += core.on_state(&state, now).unwrap().drive.is_some() as u32;
        if !(100..120).contains(&tick) {
            cmd.header.tick = tick;
            let out = core.on_command(&cmd, now).unwrap();
            if let Some(d) = out.drive {
                applied += 1;
                assert_eq!(d.has_gains(), gains == DriveGainsMode::Inertia, "tick {tick}");
            }
        }
        let _ = core.on_timer(now);
        let _ = core.status();
    }
    WATCH.with(|w| w.set(false));
    (COUNT.with(|c| c.get()), applied, held)
}
