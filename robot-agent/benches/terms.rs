//! The agent's real per-tick work on the project's default robot: state in, the protocol's
//! DynamicsTerms (M, h, 4 feet, hand, torso with Jacobians and Jdot*v) out.
//! Run: cargo bench -p robot-agent --bench terms
//! (the rigid-body algorithms alone: `cargo bench -p robot-model --bench dynamics`).

use criterion::{criterion_group, criterion_main, Criterion};
use robot_agent::terms::{empty_terms, ActiveContacts, TermsBuilder};
use robot_model::{default_robot_path, Robot};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let robot = Robot::load(default_robot_path()).unwrap();
    let mut builder = TermsBuilder::new(&robot).unwrap();
    let sq = robot.standing_q.as_slice();
    let state = protocol::RobotState {
        header: protocol::Header::new("bench", Some("r1"), 0, 0),
        base_pose: protocol::Pose {
            position: [sq[0], sq[1], sq[2]],
            orientation: [sq[3], sq[4], sq[5], sq[6]],
        },
        base_twist: [0.1, -0.05, 0.02, 0.1, 0.2, -0.1],
        joint_positions: sq[7..].to_vec(),
        joint_velocities: (0..18).map(|i| 0.1 * (i as f64).sin()).collect(),
        time: 0.0,
        foot_forces: Vec::new(),
        object_pose: None,
    };
    let contacts = ActiveContacts::all_stance(&robot);
    let mut terms = empty_terms("bench", "r1");
    let mut g = c.benchmark_group("default_robot");
    g.bench_function("state_to_dynamics_terms", |b| {
        b.iter(|| {
            builder.load_state(&robot, black_box(&state)).unwrap();
            builder.compute(&robot, &contacts, &mut terms).unwrap();
        })
    });
    g.finish();
    black_box(&terms);
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .warm_up_time(std::time::Duration::from_secs(1))
        .measurement_time(std::time::Duration::from_secs(3));
    targets = bench
}
criterion_main!(benches);
