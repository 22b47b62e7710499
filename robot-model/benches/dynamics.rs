//! Per-tick dynamics of the 24-DoF legged manipulator (test quadruped + 6-DoF arm via attach):
//! forward kinematics, CRBA, RNEA, all contact and task Jacobians with Jdot*v, and the whole
//! per-tick update. Run: cargo bench -p robot-model --bench dynamics
//! (the agent's state-to-terms tick is `cargo bench -p robot-agent --bench terms`).

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{DVector, Matrix6xX};
use robot_model::*;
use std::hint::black_box;

const QUADRUPED: &str = include_str!("../tests/data/quadruped.urdf");
const ARM: &str = include_str!("../tests/data/arm.urdf");
/// Contact frames (four feet) and task frames (hand, torso).
const FRAMES: [&str; 6] = ["LF_foot", "RF_foot", "LH_foot", "RH_foot", "arm_hand", "trunk"];

fn setup() -> (Model, DVector<f64>, DVector<f64>) {
    let model = ModelBuilder::from_urdf_str(QUADRUPED)
        .unwrap()
        .attach_urdf_str(
            ARM,
            "arm_mount",
            SE3::from_xyz_rpy([0.05, 0.0, 0.02], [0.0, 0.0, 0.3]),
            "arm_",
        )
        .unwrap()
        .build(FloatingBase::Yes)
        .unwrap();
    assert_eq!(model.nv, 24);
    // a fixed pseudo-random state (no rand dependency in benches)
    let mut s = 0x9E3779B97F4A7C15u64;
    let mut u = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let q = model.random_configuration(&mut u);
    let v = DVector::from_fn(model.nv, |_, _| 4.0 * u() - 2.0);
    (model, q, v)
}

fn bench(c: &mut Criterion) {
    let (model, q, v) = setup();
    let (q, v) = (q.as_slice(), v.as_slice());
    let frames: Vec<FrameId> = FRAMES.iter().map(|f| model.frame_id(f).unwrap()).collect();
    let mut data = Data::new(&model);
    let mut jacs = vec![Matrix6xX::zeros(model.nv); frames.len()];
    let mut jdvs = vec![nalgebra::Vector6::zeros(); frames.len()];

    let mut g = c.benchmark_group("legged_manipulator_24dof");
    g.bench_function("forward_kinematics", |b| {
        b.iter(|| forward_kinematics(&model, &mut data, black_box(q), black_box(v)).unwrap())
    });
    g.bench_function("crba", |b| {
        b.iter(|| crba(&model, &mut data, black_box(q)).map(|_| ()).unwrap())
    });
    g.bench_function("rnea_h", |b| {
        b.iter(|| {
            nonlinear_effects(&model, &mut data, black_box(q), black_box(v)).map(|_| ()).unwrap()
        })
    });
    forward_kinematics(&model, &mut data, q, v).unwrap();
    g.bench_function("jacobians_and_jdot_v_6_frames", |b| {
        b.iter(|| {
            for (k, &f) in frames.iter().enumerate() {
                frame_jacobian(&model, &data, f, &mut jacs[k]).unwrap();
                jdvs[k] = frame_jdot_v(&model, &data, f).unwrap();
            }
        })
    });
    g.bench_function("per_tick_update", |b| {
        b.iter(|| {
            compute_all_terms(&model, &mut data, black_box(q), black_box(v)).unwrap();
            for (k, &f) in frames.iter().enumerate() {
                frame_jacobian(&model, &data, f, &mut jacs[k]).unwrap();
                jdvs[k] = frame_jdot_v(&model, &data, f).unwrap();
            }
        })
    });
    g.finish();
    black_box((&jacs, &jdvs));
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .warm_up_time(std::time::Duration::from_secs(1))
        .measurement_time(std::time::Duration::from_secs(3));
    targets = bench
}
criterion_main!(benches);
