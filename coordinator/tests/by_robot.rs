//! A team that holds nothing is solved robot by robot when its QP fails
//! (`coordinator::pidc::stages::by_robot`): one robot that cannot be held must not change what
//! the others are sent. The oracle is each robot alone, a one-robot team with the same terms.

mod common;

use common::{robot_id, Fixture, TEAM};
use coordinator::pidc::stages::by_robot::{decoupled, ByRobotScratch};
use coordinator::qp::{self, QpInput, QpPath, QpSettings, QpWorkspace};
use coordinator::{Pidc, PidcConfig, TeamController};
use nalgebra::{DVector, UnitQuaternion, Vector3};
use protocol::{
    DynamicsTerms, FootLoad, Header, Pose, PoseReference, QpStatus, RobotDescription,
    TaskReferences, TorqueCommand, TorsoReference,
};
use robot_agent::terms::ActiveContacts;

/// `count` robots standing, hands free, each perturbed a little (seeded), at rest.
fn free_team(
    fx: &mut Fixture,
    count: usize,
    seed: u64,
) -> (Vec<DynamicsTerms>, Vec<RobotDescription>) {
    let mut rng = common::rng(seed);
    let nv = fx.robot.model.nv;
    let free =
        ActiveContacts { stance: vec![true; fx.robot.foot_frames.len()], hand_in_grasp: false };
    let mut terms = Vec::new();
    let mut descs = Vec::new();
    for k in 0..count {
        let q = fx.perturbed_q(k, count, 0.05, &mut rng);
        terms.push(fx.terms_with(&robot_id(k), &q, &DVector::zeros(nv), 1, &free));
        descs.push(fx.description(&robot_id(k)));
    }
    (terms, descs)
}

/// References without targets (every task holds the pose it was first seen at).
fn no_references() -> TaskReferences {
    TaskReferences {
        header: Header::new(TEAM, None, 1, 0),
        object: None,
        torsos: Vec::new(),
        swing_feet: Vec::new(),
        foot_loads: Vec::new(),
    }
}

/// References that unload every foot of `robots` to `max_normal_force` (a robot that cannot
/// carry its weight: its QP is infeasible).
fn unloaded(fx: &Fixture, robots: &[String], max_normal_force: f64) -> TaskReferences {
    let mut r = no_references();
    for id in robots {
        for f in &fx.robot.foot_frames {
            r.foot_loads.push(FootLoad { robot: id.clone(), frame: f.clone(), max_normal_force });
        }
    }
    r
}

fn controller(descs: &[RobotDescription], refs: &TaskReferences) -> Pidc {
    let mut c = Pidc::new(PidcConfig::default());
    for d in descs {
        c.set_description(d);
    }
    c.set_references(refs);
    c
}

/// The torques one tick sends, by robot id.
fn torques(c: &mut Pidc, tick: &[DynamicsTerms]) -> Vec<TorqueCommand> {
    let mut out = Vec::new();
    c.solve(tick, &mut out).expect("tick");
    out
}

fn rel_err(a: &[f64], b: &[f64]) -> f64 {
    let d = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt();
    let s = b.iter().map(|y| y * y).sum::<f64>().sqrt();
    d / s.max(1.0)
}

/// Runs `refs` on the team and on each robot alone: each robot must be sent what it is sent
/// alone, and the note names exactly the robots that fall back alone. Returns the note.
fn check_against_alone(
    terms: &[DynamicsTerms],
    descs: &[RobotDescription],
    refs: &TaskReferences,
) -> String {
    let mut team = controller(descs, refs);
    let sent = torques(&mut team, terms);
    let report = team.last().expect("tick");
    assert!(decoupled(&report.team), "free hands: no grasp rows");
    let note = report.fallback.clone().expect("a robot cannot be held: a fallback");
    assert!(note.contains("robot by robot"), "{note}");
    assert!(
        !matches!(report.qp.status, QpStatus::Solved | QpStatus::AlmostSolved),
        "the worst robot's status is the team's: {:?}",
        report.qp.status
    );
    for k in 0..terms.len() {
        // The oracle: robot k alone (a one-robot team takes the team's path), same references.
        let mut alone = controller(&descs[k..k + 1], refs);
        let own = torques(&mut alone, &terms[k..k + 1]);
        let alone_fell_back = alone.last().expect("tick").fallback.is_some();
        let id = robot_id(k);
        assert_eq!(
            note.contains(&format!("{id}:")),
            alone_fell_back,
            "{id}: named in the note exactly when it falls back alone: {note}"
        );
        let err = rel_err(&sent[k].tau, &own[0].tau);
        assert!(
            err < 1e-6,
            "{id} in the team is sent what it would be sent alone: relative difference {err:.2e}"
        );
    }
    note
}

#[test]
fn one_robot_that_cannot_be_held_leaves_the_others_their_own_solution() {
    let mut fx = Fixture::new();
    let (terms, descs) = free_team(&mut fx, 3, 7);
    // r2's feet may carry at most 5 N each: it cannot stand, its block is infeasible.
    let note = check_against_alone(&terms, &descs, &unloaded(&fx, &[robot_id(1)], 5.0));
    assert!(note.contains("r2:") && !note.contains("r1:") && !note.contains("r3:"), "{note}");
}

#[test]
fn only_the_robots_that_fail_are_saturated() {
    let mut fx = Fixture::new();
    let (terms, descs) = free_team(&mut fx, 3, 8);
    // r1's torso is asked 0.4 m sideways at once: its tau_0 is over the joints' limits. r2
    // cannot stand. r3 stands as it is.
    let mut refs = unloaded(&fx, &[robot_id(1)], 5.0);
    let mut probe = controller(&descs, &no_references());
    probe.compute(&terms).expect("tick");
    let torso = &probe.last().expect("tick").team.torsos[0];
    let p = torso.position + Vector3::new(0.0, 0.4, 0.0);
    let q = UnitQuaternion::from_rotation_matrix(&torso.rotation);
    let pose = Pose { position: [p.x, p.y, p.z], orientation: [q.w, q.i, q.j, q.k] };
    refs.torsos.push(TorsoReference {
        robot: robot_id(0),
        reference: PoseReference { pose, twist: [0.0; 6], acceleration: [0.0; 6] },
    });
    let mut alone = controller(&descs[..1], &refs);
    alone.compute(&terms[..1]).expect("tick");
    assert!(alone.last().expect("tick").saturated, "the probe: r1's tau_0 is over its limits");
    let note = check_against_alone(&terms, &descs, &refs);
    assert!(note.contains("r1:") && note.contains("r2:") && !note.contains("r3:"), "{note}");
}

#[test]
fn blocks_solved_alone_give_the_team_qps_optimum() {
    // Every robot holdable: the team's QP and the blocks' have the same unique optimum
    // (the objective is strictly convex), so the blocks are checked against the team's QP.
    let mut fx = Fixture::new();
    for (count, seed) in [(2, 1), (3, 2), (4, 3)] {
        let (terms, descs) = free_team(&mut fx, count, seed);
        let mut c = controller(&descs, &no_references());
        c.compute(&terms).expect("tick");
        let r = c.materialized().expect("tick");
        assert!(r.fallback.is_none(), "{count} robots standing: the team's QP is solved");
        // Without a grasp the real wrenches' offset is eta itself (no hand carries G^+ F_x).
        let inp = QpInput {
            y: &r.y,
            rho: &r.rho,
            eta: &r.eta,
            contacts: &r.contacts,
            actuated: &r.actuated,
            limits: &r.limits,
            tau0: &r.tau0,
            regularisation: PidcConfig::default().regularisation,
        };
        let settings = QpSettings::new(200, QpPath::ByBlocks);
        let (mut f_team, mut f_blocks) = (DVector::zeros(0), DVector::zeros(0));
        let team = qp::solve_with(&mut QpWorkspace::default(), &inp, &settings, &mut f_team);
        assert_eq!(team.status, QpStatus::Solved);
        let mut blocks = ByRobotScratch::default();
        blocks.solve(&r.team, &inp, &settings, false, &mut f_blocks);
        let by = blocks.finish(&r.team, &inp, &settings, &mut f_blocks);
        assert_eq!(by.outcome.status, QpStatus::Solved, "{count} robots");
        assert!(by.fallback.is_none() && !by.saturated, "{count} robots: {:?}", by.fallback);
        let err = rel_err(f_blocks.as_slice(), f_team.as_slice());
        assert!(
            err < 1e-6,
            "{count} robots: F_c by blocks against the team's QP, relative {err:.2e}"
        );
    }
}

#[test]
fn a_team_in_grasp_is_not_split() {
    let mut fx = Fixture::new();
    let (terms, descs) = fx.static_team(2);
    let mut c = controller(&descs, &no_references());
    c.compute(&terms).expect("tick");
    let r = c.last().expect("tick");
    assert!(!r.team.hands.is_empty());
    assert!(!decoupled(&r.team), "the grasp couples the robots");
}
