//! The MuJoCo plant in the lockstep loop over real Zenoh (one in-process session per test,
//! `Role::Alone`, its own team name): standing under a real robot-agent for 5 s, determinism,
//! the missing robot named in the timeout error, and (on the placeholder plant) a robot whose
//! agent left alive driven by its torques until they stop.

use std::time::Duration;

use protocol::transport::{self, Role, ZenohArgs};
use robot_agent::agent::{self, AgentConfig, AgentCounters, AgentError, ModelDynamics};
use sim_bridge::ground_truth::GroundTruthLog;
use sim_bridge::lockstep::{self, BridgeError, LockstepConfig, LoopDuties};
use sim_bridge::mujoco_plant::MujocoPlant;
use sim_bridge::world::{load_robots, World, WorldSpec};
use team_tests::standing_controller::{self as standing, StandingController, StandingGains};
use tokio::sync::watch;
use tokio::task::JoinHandle;

fn cfg(team: &str, ticks: u64) -> LockstepConfig {
    LockstepConfig {
        team: team.into(),
        ticks,
        start_timeout: Duration::from_secs(10),
        command_timeout: Duration::from_secs(2),
        resend_every: Duration::from_millis(50),
        progress_every: 0,
        wait_for_coordinator: false,
        coordinator_grace_ticks: sim_bridge::lockstep::DEFAULT_COORDINATOR_GRACE_TICKS,
        agent_loss: sim_bridge::lockstep::AgentLoss::EndRun,
        drive_timeout: sim_bridge::lockstep::DEFAULT_DRIVE_TIMEOUT,
    }
}

fn controllers(world: &World, ids: &[&str]) -> Vec<(String, StandingController)> {
    world
        .robots
        .iter()
        .filter(|r| ids.contains(&r.id.as_str()))
        .map(|r| {
            (
                r.id.clone(),
                StandingController::new(r.robot.clone(), None, StandingGains::default()).unwrap(),
            )
        })
        .collect()
}

fn tilt_deg(q: [f64; 4]) -> f64 {
    (1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2])).clamp(-1.0, 1.0).acos().to_degrees()
}

/// The real agent loop with the default robot's model, on its own task until `stop`.
fn spawn_agent(
    session: &zenoh::Session,
    cfg: AgentConfig,
    mut stop: watch::Receiver<bool>,
) -> JoinHandle<Result<AgentCounters, AgentError>> {
    let robot = robot_model::Robot::load(robot_model::default_robot_path()).unwrap();
    let agent = agent::spawn(session, cfg, ModelDynamics::new(robot).unwrap());
    tokio::spawn(async move {
        let agent = agent?;
        let _ = stop.wait_for(|s| *s).await;
        let joined = tokio::task::spawn_blocking(move || agent.join()).await;
        let report = joined.map_err(|e| AgentError::Thread(e.to_string()))??;
        Ok(report.counters)
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn default_robot_stands_5_s_under_its_agent() {
    let team = "stand5";
    let session = transport::open(&ZenohArgs::default(), Role::Alone).await.unwrap();
    let spec = WorldSpec::single("r1");
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    let z0 = world.robots[0].initial_q[2];
    let mass = world.robots[0].robot.model.total_mass;
    let ctl = controllers(&world, &["r1"]);
    let mut plant = MujocoPlant::new(world).unwrap();
    let (stop_tx, stop_rx) = watch::channel(false);
    // The real agent loop with the robot's model (it publishes the dynamics terms); the
    // test-side coordinator computes the torques from the robot's own model and sends them as
    // commands, which the agent checks and forwards to the bridge.
    // A generous command deadline: lockstep ticks can be slow on a loaded machine, and safe
    // mode is not what this test is about.
    let agent = spawn_agent(
        &session,
        AgentConfig::new(team, "r1").with_deadline_time(Duration::from_secs(2)),
        stop_rx.clone(),
    );
    let s3 = session.clone();
    let rx = stop_rx.clone();
    let coord = tokio::spawn(async move { standing::serve(&s3, team, ctl, false, rx).await });
    // Settle 200 ticks, restart the scenario clock, then 5 s with tick numbers continuing.
    lockstep::run(&session, &cfg(team, 200), &mut plant, stop_rx.clone()).await.unwrap();
    plant.restart_clock();
    let mut extras = LoopDuties {
        truth_log: Some(GroundTruthLog::new(10)),
        publish_ground_truth: true,
        first_tick: 200,
        ..Default::default()
    };
    let report =
        lockstep::run_with(&session, &cfg(team, 5000), &mut plant, &mut extras, stop_rx.clone())
            .await
            .unwrap();
    stop_tx.send(true).unwrap();
    let counters = agent.await.unwrap().unwrap();
    let sent = coord.await.unwrap().unwrap();
    assert_eq!(report.ticks, 5000);
    assert!((report.sim_time - 5.0).abs() < 1e-9);
    assert!(counters.applied >= 5200 && counters.rejected == 0, "{counters:?}");
    assert!(sent >= 5200);
    let rec = extras.truth_log.unwrap();
    assert_eq!(rec.records.len(), 500);
    let (mut dz, mut tilt) = (0.0f64, 0.0f64);
    for g in &rec.records {
        let t = &g.torsos[0];
        dz = dz.max((t.pose.position[2] - z0).abs());
        tilt = tilt.max(tilt_deg(t.pose.orientation));
    }
    eprintln!("max |z - z0| = {dz:.4} m, max tilt {tilt:.3} deg, wall {:?}", report.wall_time);
    assert!(dz < 0.02, "base height moved {dz} m");
    assert!(tilt < 1.0, "trunk tilted {tilt} deg");
    // Ground truth is consistent: the feet carry the robot's weight at rest.
    let last = rec.records.last().unwrap();
    let fz: f64 = last.foot_contacts.iter().map(|c| c.wrench[2]).sum();
    assert!(last.foot_contacts.len() >= 4, "{:?}", last.foot_contacts);
    assert!(
        (fz - mass * 9.81).abs() < 0.02 * mass * 9.81,
        "foot forces {fz} N vs weight {} N",
        mass * 9.81
    );
}

/// An agent that never hears from a coordinator holds its robot up by itself: after its
/// deadline it holds the posture it found, its joints carrying the torso's weight on the four
/// feet (`robot_agent::standing`), not only the legs' own gravity. The oracle is MuJoCo's
/// torso height and the contact forces.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_agent_alone_holds_its_robot_standing() {
    let team = "alone";
    let session = transport::open(&ZenohArgs::default(), Role::Alone).await.unwrap();
    let spec = WorldSpec::single("r1");
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    let mass = world.robots[0].robot.model.total_mass;
    let mut plant = MujocoPlant::new(world).unwrap();
    let (stop_tx, stop_rx) = watch::channel(false);
    let agent = spawn_agent(&session, AgentConfig::new(team, "r1"), stop_rx.clone());
    // The first tick waits for the agent's deadline (25 ms); the hold answers every tick after.
    let mut extras = LoopDuties { truth_log: Some(GroundTruthLog::new(10)), ..Default::default() };
    lockstep::run_with(&session, &cfg(team, 2000), &mut plant, &mut extras, stop_rx.clone())
        .await
        .unwrap();
    stop_tx.send(true).unwrap();
    let counters = agent.await.unwrap().unwrap();
    assert_eq!((counters.applied, counters.safe_mode_entries), (0, 1), "{counters:?}");
    let rec = extras.truth_log.unwrap();
    // From the first recorded tick (the robot as the hold found it) to the end of 2 s.
    let z0 = rec.records[0].torsos[0].pose.position[2];
    let (mut sink, mut tilt) = (0.0f64, 0.0f64);
    for g in &rec.records {
        let t = &g.torsos[0];
        sink = sink.max(z0 - t.pose.position[2]);
        tilt = tilt.max(tilt_deg(t.pose.orientation));
    }
    eprintln!("the hold alone: torso sank {sink:.4} m, tilted {tilt:.3} deg");
    // Measured: 0.7 mm, 0.007 deg; with the legs' own gravity only (no feet carrying the torso): 29 mm, 1.2 deg.
    assert!(sink < 0.005, "the torso sank {sink} m under the hold");
    assert!(tilt < 1.0, "trunk tilted {tilt} deg");
    let last = rec.records.last().unwrap();
    let fz: f64 = last.foot_contacts.iter().map(|c| c.wrench[2]).sum();
    assert!(
        (fz - mass * 9.81).abs() < 0.02 * mass * 9.81,
        "foot forces {fz} N vs weight {} N",
        mass * 9.81
    );
}

/// One lockstep run of the pair with the object and the direct-mode test controller;
/// returns the final MuJoCo state and the recorded torso/object trajectory.
async fn pair_run(team: &str, seed: u64, ticks: u64) -> (Vec<f64>, Vec<f64>) {
    let session = transport::open(&ZenohArgs::default(), Role::Alone).await.unwrap();
    let mut spec = WorldSpec::paper_pair();
    spec.seed = seed;
    spec.initial_joint_noise = 0.01;
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    let ctl = controllers(&world, &["r1", "r2"]);
    let mut plant = MujocoPlant::new(world).unwrap();
    let (stop_tx, stop_rx) = watch::channel(false);
    let s = session.clone();
    let rx = stop_rx.clone();
    let t = team.to_string();
    let coord = tokio::spawn(async move { standing::serve(&s, &t, ctl, true, rx).await });
    let mut extras = LoopDuties { truth_log: Some(GroundTruthLog::new(1)), ..Default::default() };
    lockstep::run_with(&session, &cfg(team, ticks), &mut plant, &mut extras, stop_rx)
        .await
        .unwrap();
    stop_tx.send(true).unwrap();
    coord.await.unwrap().unwrap();
    session.close().await.unwrap();
    let mut traj = Vec::new();
    for g in extras.truth_log.unwrap().records {
        for b in g.object.iter().chain(&g.torsos) {
            traj.extend(b.pose.position);
            traj.extend(b.pose.orientation);
            traj.extend(b.twist);
        }
    }
    (plant.full_state(), traj)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lockstep_is_deterministic_for_a_seed() {
    let (a, ta) = pair_run("det-a", 7, 600).await;
    let (b, tb) = pair_run("det-b", 7, 600).await;
    let (c, _) = pair_run("det-c", 8, 600).await;
    assert_eq!(ta.len(), 600 * 3 * 13);
    // Bit-identical, not merely close.
    assert!(
        a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
        "same seed, different final state"
    );
    assert!(
        ta.iter().zip(&tb).all(|(x, y)| x.to_bits() == y.to_bits()),
        "same seed, different trajectory"
    );
    assert!(a.iter().zip(&c).any(|(x, y)| x != y), "a different seed changed nothing");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_robot_is_named_in_the_timeout() {
    let team = "silent";
    let session = transport::open(&ZenohArgs::default(), Role::Alone).await.unwrap();
    let spec = WorldSpec::paper_pair();
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    // r1 is served; r2 is a member (its token exists) that never sends torques.
    let ctl = controllers(&world, &["r1"]);
    let _r2 = transport::declare_member(&session, team, "r2").await.unwrap();
    let mut plant = MujocoPlant::new(world).unwrap();
    let (stop_tx, stop_rx) = watch::channel(false);
    let s = session.clone();
    let rx = stop_rx.clone();
    let coord = tokio::spawn(async move { standing::serve(&s, team, ctl, true, rx).await });
    let mut c = cfg(team, 100);
    c.start_timeout = Duration::from_millis(500);
    c.command_timeout = Duration::from_millis(300);
    let started = std::time::Instant::now();
    let err = lockstep::run(&session, &c, &mut plant, stop_rx).await.unwrap_err();
    stop_tx.send(true).unwrap();
    coord.await.unwrap().unwrap();
    assert!(started.elapsed() < Duration::from_secs(5), "it hung");
    match &err {
        BridgeError::TorqueTimeout { tick, missing, .. } => {
            assert_eq!(*tick, 0);
            assert_eq!(missing, &vec!["r2".to_string()]);
        }
        other => panic!("unexpected error {other}"),
    }
    assert!(err.to_string().contains("r2") && !err.to_string().contains("r1"), "{err}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn realtime_holds_and_counts_missing_torques() {
    let team = "rt";
    let session = transport::open(&ZenohArgs::default(), Role::Alone).await.unwrap();
    // 100 Hz control (physics 1 kHz, 10 substeps) so that the pace is well above timer jitter.
    let mut spec = WorldSpec::paper_pair();
    spec.object = None;
    spec.control_hz = 100.0;
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    assert_eq!(world.substeps, 10);
    let ctl = controllers(&world, &["r1"]);
    let _r2 = transport::declare_member(&session, team, "r2").await.unwrap();
    let mut plant = MujocoPlant::new(world).unwrap();
    let (stop_tx, stop_rx) = watch::channel(false);
    let s = session.clone();
    let rx = stop_rx.clone();
    let coord = tokio::spawn(async move { standing::serve(&s, team, ctl, true, rx).await });
    let started = std::time::Instant::now();
    let report = sim_bridge::realtime::run(
        &session,
        &cfg(team, 100),
        Duration::from_millis(10),
        &mut plant,
        &mut LoopDuties::default(),
        stop_rx,
    )
    .await
    .unwrap();
    let wall = started.elapsed();
    stop_tx.send(true).unwrap();
    coord.await.unwrap().unwrap();
    assert!((report.sim_time - 1.0).abs() < 1e-9);
    // Paced by the clock: 100 ticks of 10 ms take about 1 s, not the few ms of lockstep.
    assert!(wall >= Duration::from_millis(990) && wall < Duration::from_secs(3), "{wall:?}");
    assert_eq!(report.missed[1], ("r2".to_string(), 100), "r2 never sends: every tick missed");
    assert!(report.missed[0].1 < 20, "r1 is served: {:?}", report.missed);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_perturbation_from_the_key_pushes_the_object() {
    use protocol::keys;
    use protocol::transport::{Qos, TypedPublisher};
    use protocol::{Header, PerturbationRequest, PerturbationTarget};
    let team = "push";
    let session = transport::open(&ZenohArgs::default(), Role::Alone).await.unwrap();
    let mut spec = WorldSpec::paper_pair();
    spec.robots.truncate(1);
    spec.object.as_mut().unwrap().position = [0.5, 2.0, 0.3];
    let world = World::build(&spec, &load_robots(&spec).unwrap()).unwrap();
    let ctl = controllers(&world, &["r1"]);
    let mut plant = MujocoPlant::new(world).unwrap();
    let (stop_tx, stop_rx) = watch::channel(false);
    // The loop starts first (it subscribes to the perturbation key, then waits for members);
    // the request is sent while it waits; the robot joins after that.
    let s = session.clone();
    let rx = stop_rx.clone();
    let run = tokio::spawn(async move {
        let mut extras = LoopDuties {
            perturbation_key: true,
            truth_log: Some(GroundTruthLog::new(1)),
            ..Default::default()
        };
        lockstep::run_with(&s, &cfg(team, 500), &mut plant, &mut extras, rx).await.map(|_| extras)
    });
    tokio::time::sleep(Duration::from_millis(300)).await;
    let mut p = TypedPublisher::<PerturbationRequest>::declare(
        &session,
        keys::perturbation(team).unwrap(),
        Qos::HotPath,
    )
    .await
    .unwrap();
    let bad = PerturbationRequest {
        header: Header::new(team, None, 0, 0),
        target: PerturbationTarget::RobotBody { robot: "r1".into(), body: "no_such_link".into() },
        wrench: [1.0; 6],
        start: None,
        duration: 0.1,
    };
    p.put(&bad).await.unwrap();
    let r = PerturbationRequest {
        header: Header::new(team, None, 0, 0),
        target: PerturbationTarget::Object,
        wrench: [30.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        start: Some(0.0),
        duration: 0.2,
    };
    p.put(&r).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let s = session.clone();
    let rx = stop_rx.clone();
    let coord = tokio::spawn(async move { standing::serve(&s, team, ctl, true, rx).await });
    let extras = run.await.unwrap().unwrap();
    stop_tx.send(true).unwrap();
    coord.await.unwrap().unwrap();
    assert_eq!((extras.perturbations_taken, extras.perturbations_refused), (1, 1));
    let rec = extras.truth_log.unwrap();
    let x0 = rec.records.first().unwrap().object.as_ref().unwrap().pose.position[0];
    let x1 = rec.records.last().unwrap().object.as_ref().unwrap().pose.position[0];
    assert!(x1 - x0 > 0.05, "pushed object moved {} m", x1 - x0);
}

/// A robot whose agent leaves the team but keeps answering its states (a fallen robot's
/// damping, `robot_agent::fall`) is driven by those torques; once they stop, its drives are
/// lost after `LOST_DRIVE_TICKS`. On the unit-inertia placeholder plant (`v += dt tau`), with
/// both robots sent `tau = 1` on every joint: r1 answers all 80 ticks, r2 leaves at tick 20,
/// answers until tick 39 and then falls silent. Its torques are not waited for (they may drive
/// it a tick late) and the last is held for 5 ticks, so its velocity gains `dt` on 42 to 45
/// steps and none after tick 44; before, on ticks 0..=19 only (the drives were cut when its
/// agent left and its later torques ignored).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_agent_that_left_alive_drives_its_robot_until_its_torques_stop() {
    use protocol::keys::{self, RobotTopic};
    use protocol::transport::{decode_sample, Qos, TypedPublisher};
    use protocol::{DriveCommand, RobotState};
    use sim_bridge::plant::{DriveLoss, PlaceholderPlant, Plant};
    let team = "left-alive";
    let session = transport::open(&ZenohArgs::default(), Role::Alone).await.unwrap();
    let (dt, v0, ticks) = (0.001, 0.5, 80u64);
    let mut plant = PlaceholderPlant::new(vec!["r1".into(), "r2".into()], 2, v0, dt);
    let states = transport::subscribe(&session, keys::all_robots(team, RobotTopic::State).unwrap())
        .await
        .unwrap();
    let mut pubs = Vec::new();
    for id in ["r1", "r2"] {
        pubs.push(
            TypedPublisher::<DriveCommand>::declare(
                &session,
                keys::robot(team, id, RobotTopic::Torque).unwrap(),
                Qos::HotPath,
            )
            .await
            .unwrap(),
        );
    }
    let r1_token = transport::declare_member(&session, team, "r1").await.unwrap();
    let mut r2_token = Some(transport::declare_member(&session, team, "r2").await.unwrap());
    let (stop_tx, stop_rx) = watch::channel(false);
    let mut stop = stop_rx.clone();
    let responder = tokio::spawn(async move {
        let mut answered = [None::<u64>; 2];
        loop {
            let sample = tokio::select! {
                _ = stop.changed() => break,
                s = states.recv_async() => match s { Ok(s) => s, Err(_) => break },
            };
            let Ok(st) = decode_sample::<RobotState>(&sample) else { continue };
            let (tick, i) = (st.header.tick, if st.header.robot_id() == "r1" { 0 } else { 1 });
            if answered[i].is_some_and(|t| t >= tick) {
                continue; // a repeat
            }
            answered[i] = Some(tick);
            if i == 1 {
                if tick == 20 {
                    if let Some(t) = r2_token.take() {
                        t.undeclare().await.unwrap();
                    }
                }
                if tick >= 40 {
                    continue;
                }
            }
            let cmd =
                DriveCommand::torque(team, if i == 0 { "r1" } else { "r2" }, tick, vec![1.0; 2]);
            pubs[i].put(&cmd).await.unwrap();
        }
    });
    let mut c = cfg(team, ticks);
    c.agent_loss = sim_bridge::lockstep::AgentLoss::Drives(DriveLoss::Unpowered);
    let report = lockstep::run(&session, &c, &mut plant, stop_rx).await.unwrap();
    stop_tx.send(true).unwrap();
    responder.await.unwrap();
    drop(r1_token);
    assert_eq!(report.ticks, ticks);
    let gained = |i: usize| (plant.velocities(i)[0] - v0) / dt;
    println!("r1 driven for {:.1} ticks, r2 for {:.1}", gained(0), gained(1));
    assert!((gained(0) - ticks as f64).abs() < 1e-6, "r1 is driven every tick: {}", gained(0));
    let steps = gained(1).round();
    assert!(
        (gained(1) - steps).abs() < 1e-6 && (42.0..=45.0).contains(&steps),
        "r2 driven for {} steps, expected 42-45",
        gained(1)
    );
    assert!(plant.drives_lost(1) && !plant.drives_lost(0), "r2's drives lost at the end, r1's not");
}
