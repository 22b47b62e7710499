//! Each stage of the PIDC tick, called alone, against an independent statement of what it
//! computes: the protocol's frames stacked by hand, the paper's equations written out with
//! dense matrices, Euler's equations in the body frame. The inputs come from a tick of the
//! real default robot (a moving two-robot team); the outputs are never compared with the
//! function that made them.

mod common;

use std::collections::BTreeMap;

use common::{robot_id, Fixture};
use coordinator::building_blocks::contact_jacobian::{contact_jacobian, contact_velocity};
use coordinator::building_blocks::contacts::contact_list;
use coordinator::building_blocks::grasp::{GraspTerms, GraspTracker, PlannedHand, RefitRule};
use coordinator::building_blocks::impedance::TaskStack;
use coordinator::building_blocks::limits::{torque_limits, UNBOUNDED_BASE_LIMIT};
use coordinator::building_blocks::object_load::object_load;
use coordinator::pidc::stages::acceleration::{
    commanded_accelerations, AccelerationScratch, ObjectBody,
};
use coordinator::pidc::stages::tasks::{task_torque, MotionSpaceTerms, Targets, TaskTorqueInput};
use coordinator::pidc::stages::torque::{compose, motion_torque, Clamp, MotionTorqueScratch};
use coordinator::pidc::stages::wrench::{
    contact_map, contact_wrenches, Actuation, ContactMapScratch, MapInput, WrenchInput,
};
use coordinator::pidc::TickReport;
use coordinator::qp::ContactKind;
use coordinator::team::Team;
use coordinator::{ControllerError, Pidc, PidcConfig, TeamController};
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6,
};
use protocol::{
    DynamicsTerms, FrameRole, PoseReference, RobotDescription, TaskReferences, TorsoReference,
};
use robot_agent::terms::ActiveContacts;

fn max_abs(m: &DMatrix<f64>) -> f64 {
    m.iter().fold(0.0, |a, x| a.max(x.abs()))
}

/// `|a - b|_max / max(1, |b|_max)`.
fn rel(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    max_abs(&(a - b)) / max_abs(b).max(1.0)
}

fn relv(a: &DVector<f64>, b: &DVector<f64>) -> f64 {
    (a - b).amax() / b.amax().max(1.0)
}

/// A moving two-robot team (joints perturbed, velocities in `N(J_c)`), its descriptions, and
/// the controller after a tick on it (its report holds every stage's inputs).
fn moving_team(fx: &mut Fixture, seed: u64) -> (Vec<DynamicsTerms>, Vec<RobotDescription>, Pidc) {
    let mut rng = common::rng(seed);
    let nv = fx.robot.model.nv;
    let qs: Vec<DVector<f64>> = (0..2).map(|k| fx.perturbed_q(k, 2, 0.1, &mut rng)).collect();
    let descs: Vec<_> = (0..2).map(|k| fx.description(&robot_id(k))).collect();
    let still: Vec<_> =
        (0..2).map(|k| fx.terms(&robot_id(k), &qs[k], &DVector::zeros(nv), 1)).collect();
    let mut c = Pidc::new(PidcConfig::default());
    for d in &descs {
        c.set_description(d);
    }
    c.compute(&still).expect("tick");
    let p = c.materialized().expect("tick").proj.p.clone();
    use rand::Rng;
    let v = &p * DVector::from_fn(2 * nv, |_, _| rng.random_range(-0.5..0.5));
    let terms: Vec<_> = (0..2)
        .map(|k| fx.terms(&robot_id(k), &qs[k], &v.rows(k * nv, nv).into_owned(), 2))
        .collect();
    c.compute(&terms).expect("tick");
    (terms, descs, c)
}

/// The rows of every frame of `role` (hands only when in grasp), stacked by hand from the
/// protocol's row-major Jacobians at each robot's column offset.
fn stacked(terms: &[DynamicsTerms], role: FrameRole) -> (DMatrix<f64>, DVector<f64>) {
    let n: usize = terms.iter().map(|t| t.nv()).sum();
    let mut rows: Vec<Vec<f64>> = Vec::new();
    let mut jdv = Vec::new();
    let mut off = 0;
    for t in terms {
        for f in t
            .frames
            .iter()
            .filter(|f| f.role == role && (role != FrameRole::Hand || t.hand_in_grasp))
        {
            for i in 0..f.jacobian.rows() {
                let mut row = vec![0.0; n];
                for j in 0..t.nv() {
                    row[off + j] = f.jacobian.data[i * t.nv() + j];
                }
                rows.push(row);
                jdv.push(f.jdot_v[i]);
            }
        }
        off += t.nv();
    }
    (DMatrix::from_fn(rows.len(), n, |i, j| rows[i][j]), DVector::from_vec(jdv))
}

/// The grasp matrix of eq. graspmatrix (world-aligned, `R_i = I`) for hands at `hands` and
/// the object centre at `centre`, and `G^+ = G^T (G G^T)^{-1}`.
fn grasp_matrix(hands: &[Vector3<f64>], centre: &Vector3<f64>) -> (DMatrix<f64>, DMatrix<f64>) {
    let mut g = DMatrix::zeros(6, 6 * hands.len());
    for (i, p) in hands.iter().enumerate() {
        let r = p - centre;
        let mut gi = Matrix6::identity();
        gi.fixed_view_mut::<3, 3>(3, 0).copy_from(&r.cross_matrix());
        g.fixed_view_mut::<6, 6>(0, 6 * i).copy_from(&gi);
    }
    let g_pinv = g.transpose() * (&g * g.transpose()).try_inverse().expect("G G^T regular");
    (g, g_pinv)
}

fn hand_positions(terms: &[DynamicsTerms]) -> Vec<Vector3<f64>> {
    terms
        .iter()
        .flat_map(|t| {
            t.frames
                .iter()
                .filter(|f| f.role == FrameRole::Hand && t.hand_in_grasp)
                .map(|f| Vector3::from(f.position))
        })
        .collect()
}

fn diag(v: &DVector<f64>) -> DMatrix<f64> {
    DMatrix::from_diagonal(v)
}

#[test]
fn contact_jacobian_is_the_feet_rows_then_the_grasp_projected_hand_rows() {
    let mut fx = Fixture::new();
    let (terms, _, c) = moving_team(&mut fx, 3);
    let r = c.last().expect("tick");
    // eq. jacobian_c: [J_cf; (I - G^T (G^+)^T) J_ee] (eq. jacobian_cee), from the frames.
    let (j_cf, jdv_cf) = stacked(&terms, FrameRole::StanceFoot);
    let (j_ee, _) = stacked(&terms, FrameRole::Hand);
    let grasp = r.grasp.as_ref().expect("grasp");
    let (g, g_pinv) = grasp_matrix(&hand_positions(&terms), &grasp.object.translation.vector);
    let nproj = DMatrix::identity(12, 12) - g.transpose() * g_pinv.transpose();
    let mut expect = DMatrix::zeros(j_cf.nrows() + 12, j_cf.ncols());
    expect.rows_mut(0, j_cf.nrows()).copy_from(&j_cf);
    expect.rows_mut(j_cf.nrows(), 12).copy_from(&(nproj * j_ee));

    let (mut j_c, mut jdv_c) = (DMatrix::zeros(0, 0), DVector::zeros(0));
    contact_jacobian(&r.team, Some(grasp), &mut j_c, &mut jdv_c);
    let e = rel(&j_c, &expect);
    println!("J_c ({}x{}) vs the frames stacked by hand: {e:.1e}", j_c.nrows(), j_c.ncols());
    assert_eq!(j_c.shape(), (24 + 12, 2 * fx.robot.model.nv));
    assert!(e < 1e-12);
    assert_eq!(jdv_c.rows(0, 24).into_owned(), jdv_cf, "the feet's Jdot v are the agents' own");
    assert_eq!(jdv_c.rows(24, 12).into_owned(), grasp.jdv_cee);

    // No hand in grasp: the feet's rows alone.
    let nv = fx.robot.model.nv;
    let cs = ActiveContacts { stance: vec![true; 4], hand_in_grasp: false };
    let free: Vec<_> = (0..2)
        .map(|k| fx.terms_with(&robot_id(k), &fx.standing_q(k, 2), &DVector::zeros(nv), 1, &cs))
        .collect();
    let mut team = Team::default();
    team.assemble_into(&free, None, false).expect("team");
    contact_jacobian(&team, None, &mut j_c, &mut jdv_c);
    assert_eq!(j_c, stacked(&free, FrameRole::StanceFoot).0);
}

#[test]
fn torque_limits_follow_the_descriptions() {
    let mut fx = Fixture::new();
    let (terms, descs) = fx.static_team(2);
    let by_id: BTreeMap<String, RobotDescription> =
        descs.iter().map(|d| (d.header.robot_id().to_string(), d.clone())).collect();
    let mut team = Team::default();
    team.assemble_into(&terms, None, false).expect("team");
    let (mut actuated, mut limits) = (Vec::new(), Vec::new());
    torque_limits(&team, &by_id, false, &mut actuated, &mut limits).expect("limits");
    // Robot k's joints follow its 6 base coordinates; the limits are its description's.
    let nv = fx.robot.model.nv;
    let expect: Vec<usize> = (0..2).flat_map(|k| (k * nv + 6)..((k + 1) * nv)).collect();
    assert_eq!(actuated, expect);
    assert_eq!(limits, [descs[0].torque_limits.clone(), descs[1].torque_limits.clone()].concat());
    // S = I: the base coordinates too, unbounded.
    torque_limits(&team, &by_id, true, &mut actuated, &mut limits).expect("limits");
    assert_eq!(actuated, (0..2 * nv).collect::<Vec<_>>());
    assert_eq!(limits[..6], [UNBOUNDED_BASE_LIMIT; 6]);
    assert_eq!(limits[6..nv], descs[0].torque_limits[..]);
    // A missing or disagreeing description is an error.
    let one: BTreeMap<_, _> = by_id.iter().take(1).map(|(k, v)| (k.clone(), v.clone())).collect();
    assert!(
        matches!(torque_limits(&team, &one, false, &mut actuated, &mut limits), Err(ControllerError::MissingDescription { robot }) if robot == "r2")
    );
    let mut short = by_id.clone();
    short.get_mut("r1").expect("r1").torque_limits.pop();
    assert!(matches!(
        torque_limits(&team, &short, false, &mut actuated, &mut limits),
        Err(ControllerError::Dimension { .. })
    ));
}

#[test]
fn contact_list_scales_each_robots_friction_and_patch_by_the_margins() {
    let mut fx = Fixture::new();
    let (terms, descs) = fx.static_team(2);
    let by_id: BTreeMap<String, RobotDescription> =
        descs.iter().map(|d| (d.header.robot_id().to_string(), d.clone())).collect();
    let mut team = Team::default();
    team.assemble_into(&terms, None, false).expect("team");
    let cfg = PidcConfig {
        shell: coordinator::ShellConfig {
            friction_margin: 0.5,
            patch_margin: 0.25,
            f_min_foot: 7.0,
            f_min_hand: 11.0,
            ..PidcConfig::default().shell
        },
        ..PidcConfig::default()
    };
    let mut out = Vec::new();
    contact_list(&team, &by_id, &cfg.contact_margins(), &mut out).expect("contacts");
    assert_eq!(out.len(), 8 + 2);
    let d = &descs[0];
    for (k, (row, kind)) in out.iter().take(8).enumerate() {
        assert_eq!(*row, 3 * k);
        let ContactKind::Foot { mu, f_min, .. } = kind else { panic!("foot {k} is {kind:?}") };
        assert_eq!((*mu, *f_min), (d.foot_mu * 0.5, 7.0));
    }
    // Hands: the contact frame's axes from the agent's rotation (row-major), after the feet.
    for (k, t) in terms.iter().enumerate() {
        let hand = t.frames.iter().find(|f| f.role == FrameRole::Hand).expect("hand");
        let rot = Matrix3::from_row_slice(&hand.rotation);
        let (row, kind) = &out[8 + k];
        assert_eq!(*row, 24 + 6 * k);
        let ContactKind::Hand { tx, ty, n, mu, xi, half, f_min } = kind else {
            panic!("hand {k} is {kind:?}")
        };
        for (axis, col) in [(tx, 0), (ty, 1), (n, 2)] {
            assert!((axis - rot.column(col)).amax() < 1e-15, "axis {col} of hand {k}");
        }
        assert_eq!((*mu, *xi, *f_min), (d.hand_mu * 0.5, d.hand_xi * 0.5, 11.0));
        assert_eq!(*half, [d.hand_half_size[0] * 0.25, d.hand_half_size[1] * 0.25]);
    }
    let one: BTreeMap<_, _> = by_id.into_iter().take(1).collect();
    assert!(matches!(
        contact_list(&team, &one, &cfg.contact_margins(), &mut out),
        Err(ControllerError::MissingDescription { .. })
    ));
}

#[test]
fn grasp_tracker_captures_the_object_at_the_hands_centroid_or_where_told() {
    let mut fx = Fixture::new();
    let (terms, _) = fx.static_team(2);
    let mut team = Team::default();
    team.assemble_into(&terms, None, false).expect("team");
    let hands = hand_positions(&terms);
    let centroid = (hands[0] + hands[1]) / 2.0;
    let mut terms_out: Option<GraspTerms> = None;
    let mut tracker = GraspTracker::default();
    tracker.update(&team, None, &[], &mut terms_out).expect("grasp");
    let object = terms_out.as_ref().expect("grasp terms").object;
    assert!((object.translation.vector - centroid).amax() < 1e-12);
    assert!(object.rotation.angle() < 1e-9, "world axes");
    // Told where the object is when the grasp closes.
    let at = Isometry3::from_parts(
        Translation3::new(1.1, 0.05, 0.62),
        UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
    );
    let mut told = None;
    GraspTracker::default().update(&team, Some(at), &[], &mut told).expect("grasp");
    let object = told.expect("grasp terms").object;
    assert!((object.translation.vector - at.translation.vector).amax() < 1e-12);
    assert!(object.rotation.angle_to(&at.rotation) < 1e-9);
    // Hands released: no grasp terms.
    let nv = fx.robot.model.nv;
    let cs = ActiveContacts { stance: vec![true; 4], hand_in_grasp: false };
    let free: Vec<_> = (0..2)
        .map(|k| fx.terms_with(&robot_id(k), &fx.standing_q(k, 2), &DVector::zeros(nv), 1, &cs))
        .collect();
    team.assemble_into(&free, None, false).expect("team");
    tracker.update(&team, None, &[], &mut terms_out).expect("no grasp");
    assert!(terms_out.is_none());
}

/// The robots' measured object, as `protocol::Pose`.
fn measured(at: &Isometry3<f64>) -> protocol::Pose {
    let q = at.rotation;
    protocol::Pose { position: at.translation.vector.into(), orientation: [q.w, q.i, q.j, q.k] }
}

#[test]
fn a_grasp_that_slid_on_the_measured_object_is_refitted_to_it() {
    let mut fx = Fixture::new();
    let (mut terms, _) = fx.static_team(2);
    let at = Isometry3::from_parts(
        Translation3::new(0.0, 0.02, 0.61),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.05),
    );
    let mut team = Team::default();
    let mut tracker = GraspTracker::default();
    let mut out: Option<GraspTerms> = None;
    let mut tick_at = |object: Isometry3<f64>, tracker: &mut GraspTracker| {
        terms.iter_mut().for_each(|t| t.object_pose = Some(measured(&object)));
        team.assemble_into(&terms, None, false).expect("team");
        let measured = team.object_measured.expect("the robots measure the object");
        assert!((measured.translation.vector - object.translation.vector).amax() < 1e-12);
        tracker
            .update_refitting(
                &team,
                (Some(at), &[]),
                RefitRule { at: 5e-4, min_ticks: 0 },
                &mut out,
            )
            .expect("grasp");
        out.clone().expect("grasp terms")
    };
    // The grasp closes with the object where the robots measure it.
    let g = tick_at(at, &mut tracker);
    assert_eq!(g.refits, 0);
    assert!((g.object.translation.vector - at.translation.vector).amax() < 1e-12);
    // The object sinks 0.3 mm between the palms: within the re-fit distance the model stays.
    let sunk = |m: f64| {
        Isometry3::from_parts(
            Translation3::from(at.translation.vector - Vector3::z() * m),
            at.rotation,
        )
    };
    let g = tick_at(sunk(0.3e-3), &mut tracker);
    assert_eq!(g.refits, 0);
    assert!((g.object.translation.vector - at.translation.vector).amax() < 1e-12);
    assert_eq!(g.slip_since_closed, 0.0);
    // 2 mm: the hands have slid on the object; the model follows the measured object.
    let low = sunk(2e-3);
    let g = tick_at(low, &mut tracker);
    assert_eq!(g.refits, 1);
    assert!((g.object.translation.vector - low.translation.vector).amax() < 1e-9);
    assert!(g.object.rotation.angle_to(&low.rotation) < 1e-9);
    assert!(g.fit_residual < 1e-9, "the hands agree with the re-fitted model");
    assert!((g.slip_since_closed - 2e-3).abs() < 1e-9, "{}", g.slip_since_closed);
    // Without the measurement the model stays where it was re-fitted.
    terms.iter_mut().for_each(|t| t.object_pose = None);
    team.assemble_into(&terms, None, false).expect("team");
    assert!(team.object_measured.is_none());
    tracker
        .update_refitting(&team, (Some(at), &[]), RefitRule { at: 5e-4, min_ticks: 0 }, &mut out)
        .expect("grasp");
    let g = out.expect("grasp terms");
    assert_eq!(g.refits, 1);
    assert!((g.object.translation.vector - low.translation.vector).amax() < 1e-9);
}

#[test]
fn slip_that_comes_faster_than_the_refit_interval_is_refitted_once_per_interval() {
    let mut fx = Fixture::new();
    let (mut terms, _) = fx.static_team(2);
    let at = Isometry3::translation(0.0, 0.0, 0.61);
    let rule = RefitRule { at: 5e-4, min_ticks: 3 };
    let (mut team, mut tracker) = (Team::default(), GraspTracker::default());
    let mut out: Option<GraspTerms> = None;
    // The object sinks `mm` between the palms (the hands stay): (re-fits, object height).
    let mut tick_sunk = |mm: f64| {
        let object = Isometry3::translation(0.0, 0.0, 0.61 - mm * 1e-3);
        terms.iter_mut().for_each(|t| t.object_pose = Some(measured(&object)));
        team.assemble_into(&terms, None, false).expect("team");
        tracker.update_refitting(&team, (Some(at), &[]), rule, &mut out).expect("grasp");
        let g = out.as_ref().expect("grasp terms");
        (g.refits, g.object.translation.z)
    };
    assert_eq!(tick_sunk(0.0).0, 0, "the grasp closes on the measured object");
    // Two ticks from the start: the interval has not passed, the slip is not followed yet.
    let (refits, z) = tick_sunk(2.0);
    assert_eq!(refits, 0);
    assert!((z - 0.61).abs() < 1e-12);
    // The third: followed.
    let (refits, z) = tick_sunk(2.0);
    assert_eq!(refits, 1);
    assert!((z - 0.608).abs() < 1e-9, "{z}");
    // It slides on: the model waits the interval out before it follows again.
    for _ in 0..2 {
        let (refits, z) = tick_sunk(4.0);
        assert_eq!(refits, 1);
        assert!((z - 0.608).abs() < 1e-9, "{z}");
    }
    let (refits, z) = tick_sunk(4.0);
    assert_eq!(refits, 2);
    assert!((z - 0.606).abs() < 1e-9, "{z}");
}

#[test]
fn the_team_measures_the_object_as_the_mean_of_its_robots_measurements() {
    let mut fx = Fixture::new();
    let (mut terms, _) = fx.static_team(2);
    let a = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.60),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.10),
    );
    let b = Isometry3::from_parts(
        Translation3::new(0.0, 0.002, 0.60),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.12),
    );
    terms[0].object_pose = Some(measured(&a));
    // The same rotation as the other hemisphere's quaternion.
    let mut mb = measured(&b);
    mb.orientation.iter_mut().for_each(|x| *x = -*x);
    terms[1].object_pose = Some(mb);
    let mut team = Team::default();
    team.assemble_into(&terms, None, false).expect("team");
    let m = team.object_measured.expect("measured");
    assert!((m.translation.vector - Vector3::new(0.0, 0.001, 0.60)).amax() < 1e-12);
    let (_, _, yaw) = m.rotation.euler_angles();
    assert!((yaw - 0.11).abs() < 1e-6, "yaw {yaw}");
    // A robot whose hand is not in grasp does not count.
    terms[1].hand_in_grasp = false;
    team.assemble_into(&terms, None, false).expect("team");
    let m = team.object_measured.expect("measured");
    assert!((m.translation.vector - a.translation.vector).amax() < 1e-12);
}

#[test]
fn a_tracker_started_mid_carry_fits_the_object_from_the_planned_grasp() {
    // The plan: the object at `at` with the hands where the fixture stands them.
    let mut fx = Fixture::new();
    let (mut terms, _) = fx.static_team(3);
    let at = Isometry3::from_parts(
        Translation3::new(1.1, 0.05, 0.62),
        UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
    );
    let hand_pose = |t: &DynamicsTerms| {
        let h = t.frames.iter().find(|f| f.role == FrameRole::Hand).expect("hand");
        let rot = UnitQuaternion::from_matrix(&Matrix3::from_row_slice(&h.rotation));
        (
            h.name.clone(),
            Isometry3::from_parts(
                Translation3::new(h.position[0], h.position[1], h.position[2]),
                rot,
            ),
        )
    };
    let planned: Vec<PlannedHand> = terms
        .iter()
        .map(|t| {
            let (frame, pose) = hand_pose(t);
            PlannedHand::new(t.header.robot_id(), &frame, &pose, &at)
        })
        .collect();
    // Mid-carry the team has carried the object by a rigid motion `moved`: every hand moved with it.
    let moved = Isometry3::from_parts(
        Translation3::new(0.03, -0.02, 0.04),
        UnitQuaternion::from_euler_angles(0.05, 0.02, -0.1),
    );
    for t in terms.iter_mut() {
        let h = t.frames.iter_mut().find(|f| f.role == FrameRole::Hand).expect("hand");
        let pose = Isometry3::from_parts(
            Translation3::new(h.position[0], h.position[1], h.position[2]),
            UnitQuaternion::from_matrix(&Matrix3::from_row_slice(&h.rotation)),
        );
        let p = moved * pose;
        h.position = [p.translation.x, p.translation.y, p.translation.z];
        let r = p.rotation.to_rotation_matrix();
        h.rotation = std::array::from_fn(|k| r[(k / 3, k % 3)]);
    }
    let mut team = Team::default();
    team.assemble_into(&terms, None, false).expect("team");
    // A fresh tracker (a restarted coordinator) with the plan finds the object where it is...
    let mut got = None;
    GraspTracker::default().update(&team, Some(at), &planned, &mut got).expect("grasp");
    let object = got.expect("grasp terms").object;
    let want = moved * at;
    assert!(
        (object.translation.vector - want.translation.vector).amax() < 1e-12,
        "{object} vs {want}"
    );
    assert!(object.rotation.angle_to(&want.rotation) < 1e-12);
    // ... without it, it would take the object to be where the plan put it at the start.
    let mut blind = None;
    GraspTracker::default().update(&team, Some(at), &[], &mut blind).expect("grasp");
    assert!(
        (blind.expect("grasp terms").object.translation.vector - at.translation.vector).amax()
            < 1e-12
    );
    // A plan missing one of the grasping hands is not used.
    let mut partial = None;
    GraspTracker::default().update(&team, Some(at), &planned[..2], &mut partial).expect("grasp");
    assert!(
        (partial.expect("grasp terms").object.translation.vector - at.translation.vector).amax()
            < 1e-12
    );
    // Bad plans are refused by the configuration check.
    let mut bad = planned[0].clone();
    bad.hand_to_object = [1.0, 1.0, 0.0, 0.0];
    let cfg = PidcConfig {
        shell: coordinator::ShellConfig { planned_grasp: vec![bad], ..PidcConfig::default().shell },
        ..PidcConfig::default()
    };
    assert!(cfg.check().unwrap_err().to_string().contains("planned_grasp"));
}

#[test]
fn object_load_is_eulers_equations_in_the_body_frame_rotated_to_the_world() {
    // Static: the weight, nothing else.
    let inertia = Matrix3::new(0.06, 0.001, -0.002, 0.001, 0.05, 0.003, -0.002, 0.003, 0.07);
    let w = object_load(&Isometry3::identity(), &Vector6::zeros(), &[0.0; 6], 2.0, &inertia);
    assert_eq!(w, Vector6::new(0.0, 0.0, 2.0 * 9.81, 0.0, 0.0, 0.0));
    // Moving and turning: m (a - g) and R (I alpha_b + omega_b x I omega_b), body-frame
    // quantities rotated back to the world.
    let rot = UnitQuaternion::from_euler_angles(0.4, -0.7, 1.9);
    let pose = Isometry3::from_parts(Translation3::new(0.3, -0.2, 0.8), rot);
    let omega = Vector3::new(0.7, -1.3, 0.4);
    let twist = Vector6::new(0.1, 0.2, 0.3, omega.x, omega.y, omega.z);
    let acc = [0.5, -0.4, 1.2, 2.0, -1.0, 0.5];
    let w = object_load(&pose, &twist, &acc, 2.0, &inertia);
    let (om_b, al_b) =
        (rot.inverse() * omega, rot.inverse() * Vector3::new(acc[3], acc[4], acc[5]));
    let moment = rot * (inertia * al_b + om_b.cross(&(inertia * om_b)));
    let force = 2.0 * Vector3::new(acc[0], acc[1], acc[2] + 9.81);
    let expect = Vector6::new(force.x, force.y, force.z, moment.x, moment.y, moment.z);
    println!("w_ff {:?}, vs Euler {:.1e}", w.as_slice(), (w - expect).amax());
    assert!((w - expect).amax() < 1e-12);
}

#[test]
fn targets_follow_references_and_otherwise_hold_the_first_pose_seen() {
    let a = Isometry3::translation(1.0, 2.0, 3.0);
    let b = Isometry3::translation(4.0, 5.0, 6.0);
    let mut t = Targets::default();
    assert_eq!(t.torso(None, "r1", &a), (a, [0.0; 6], [0.0; 6]));
    assert_eq!(t.torso(None, "r1", &b).0, a, "held");
    assert_eq!(t.torso(None, "r2", &b).0, b, "each robot its own");
    let reference = PoseReference {
        pose: protocol::Pose { position: [7.0, 8.0, 9.0], orientation: [1.0, 0.0, 0.0, 0.0] },
        twist: [0.1; 6],
        acceleration: [0.2; 6],
    };
    let refs = TaskReferences {
        header: protocol::Header::new("t", None, 1, 0),
        object: Some(reference.clone()),
        torsos: vec![TorsoReference { robot: "r1".into(), reference: reference.clone() }],
        swing_feet: vec![],
        foot_loads: vec![],
    };
    let (x, tw, acc) = t.torso(Some(&refs), "r1", &b);
    assert_eq!((x.translation.vector, tw, acc), (Vector3::new(7.0, 8.0, 9.0), [0.1; 6], [0.2; 6]));
    assert_eq!(t.torso(Some(&refs), "r2", &a).0, b, "a reference for r1 only");
    assert_eq!(t.object(None, &a).0, a);
    assert_eq!(t.object(None, &b).0, a);
    assert_eq!(t.object(Some(&refs), &b).0.translation.vector, Vector3::new(7.0, 8.0, 9.0));
    t.release_object();
    assert_eq!(t.object(None, &b).0, b, "captured again after a release");
    let (p, q) = (Vector3::new(0.1, 0.2, 0.0), Vector3::new(0.3, 0.2, 0.1));
    assert_eq!(t.swing_foot(None, "r1", "LF_FOOT", &p).0, p);
    assert_eq!(t.swing_foot(None, "r1", "LF_FOOT", &q).0, p);
    assert_eq!(t.swing_foot(None, "r1", "RF_FOOT", &q).0, q);
}

/// The tick's task references moved off the current poses (so that every error term acts).
fn displaced_references(r: &TickReport) -> TaskReferences {
    let to_ref = |x: &Isometry3<f64>| {
        let q = x.rotation;
        PoseReference {
            pose: protocol::Pose {
                position: x.translation.vector.into(),
                orientation: [q.w, q.i, q.j, q.k],
            },
            twist: [0.02, -0.01, 0.03, 0.05, -0.04, 0.02],
            acceleration: [0.1, 0.2, -0.1, 0.3, -0.2, 0.1],
        }
    };
    let nudge = Isometry3::from_parts(
        Translation3::new(0.01, -0.02, 0.015),
        UnitQuaternion::from_euler_angles(0.03, -0.02, 0.04),
    );
    let object = r.grasp.as_ref().expect("grasp").object;
    TaskReferences {
        header: protocol::Header::new("t", None, 2, 0),
        object: Some(to_ref(&(nudge * object))),
        torsos: r
            .team
            .torsos
            .iter()
            .map(|tf| {
                let x = Isometry3::from_parts(
                    Translation3::from(tf.position),
                    UnitQuaternion::from_rotation_matrix(&tf.rotation),
                );
                TorsoReference {
                    robot: r.team.robots[tf.robot].id.clone(),
                    reference: to_ref(&(nudge * x)),
                }
            })
            .collect(),
        swing_feet: vec![],
        foot_loads: vec![],
    }
}

/// A task written out: its Jacobian, `Jdot v`, current pose and reference.
type Task<'a> = (&'a DMatrix<f64>, &'a DVector<f64>, Isometry3<f64>, &'a PoseReference);

#[test]
fn task_torque_is_the_stacked_impedance_law_written_out() {
    let mut fx = Fixture::new();
    let (_, _, mut c) = moving_team(&mut fx, 5);
    let r = c.materialized().expect("tick");
    let cfg = PidcConfig::default();
    let refs = displaced_references(&r);
    let (team, proj, g) = (&r.team, &r.proj, r.grasp.as_ref().expect("grasp"));
    let n = team.n;

    let mut motion = MotionSpaceTerms::default();
    motion.compute_into(proj, team);
    let p_bias = &proj.p * &team.bias - &proj.pdot_v;
    assert!(relv(&motion.mcinv_bias, &(&proj.mc_inv * &p_bias)) < 1e-12);
    let inp = TaskTorqueInput {
        team,
        grasp: Some(g),
        references: Some(&refs),
        config: &cfg,
        motion: motion.view(proj),
    };
    let (mut tau_m, mut load, mut f_x) = (DVector::zeros(0), DVector::zeros(0), Vector6::zeros());
    task_torque(
        &inp,
        &mut Targets::default(),
        &mut TaskStack::default(),
        &mut tau_m,
        &mut load,
        &mut f_x,
        &mut nalgebra::Vector6::zeros(),
    )
    .expect("tau_M");
    // The same by the dense projections (formed by `materialized`), in a stack whose buffers
    // were first used by the torsos in the other order (the same shape, each task's rows on
    // other columns): nothing of that tick may be left behind.
    let mut dense = proj.clone();
    dense.by_blocks = false;
    let mut stack = TaskStack::default();
    let mut swapped = team.clone();
    swapped.torsos.reverse();
    let (mut tau_m_dense, mut load_dense, mut f_x_dense) =
        (DVector::zeros(0), DVector::zeros(0), Vector6::zeros());
    for t in [&swapped, team] {
        let inp = TaskTorqueInput {
            team: t,
            grasp: Some(g),
            references: Some(&refs),
            config: &cfg,
            motion: motion.view(&dense),
        };
        task_torque(
            &inp,
            &mut Targets::default(),
            &mut stack,
            &mut tau_m_dense,
            &mut load_dense,
            &mut f_x_dense,
            &mut nalgebra::Vector6::zeros(),
        )
        .expect("tau_M, dense");
    }

    // eq. control_law for the stacked task x = [x_o; x_t1; x_t2] (J_x = [J_o; J_t1; J_t2]):
    // F = Lambda_c (J M_c^{-1} (P h - Pdot v) - Jdot v + a_d) - K_d edot - K_p e (+ w_ff on the
    // object's rows), Lambda_c = (J M_c^{-1} P J^T)^{-1}; tau_M = J^T F (eqn. joint_space_tau_M).
    let tasks: Vec<Task> =
        std::iter::once((&g.j_o, &g.jdv_o, g.object, refs.object.as_ref().expect("object")))
            .chain(team.torsos.iter().zip(&refs.torsos).map(|(tf, t)| {
                (
                    &tf.jacobian,
                    &tf.jdot_v,
                    Isometry3::from_parts(
                        Translation3::from(tf.position),
                        UnitQuaternion::from_rotation_matrix(&tf.rotation),
                    ),
                    &t.reference,
                )
            }))
            .collect();
    let k = 6 * tasks.len();
    let mut j = DMatrix::zeros(k, n);
    let (mut jdv, mut e, mut edot, mut acc, mut kp, mut kd, mut ff) = (
        DVector::zeros(k),
        DVector::zeros(k),
        DVector::zeros(k),
        DVector::zeros(k),
        DVector::zeros(k),
        DVector::zeros(k),
        DVector::zeros(k),
    );
    for (i, (jx, jdvx, x, reference)) in tasks.iter().enumerate() {
        j.rows_mut(6 * i, 6).copy_from(*jx);
        jdv.rows_mut(6 * i, 6).copy_from(*jdvx);
        let x_d_rot = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            reference.pose.orientation[0],
            reference.pose.orientation[1],
            reference.pose.orientation[2],
            reference.pose.orientation[3],
        ));
        let dp = x.translation.vector - Vector3::from(reference.pose.position);
        let dr = (x.rotation * x_d_rot.inverse()).scaled_axis();
        e.rows_mut(6 * i, 6).copy_from(&Vector6::new(dp.x, dp.y, dp.z, dr.x, dr.y, dr.z));
        let twist = *jx * &team.velocity;
        edot.rows_mut(6 * i, 6).copy_from(&(twist - DVector::from_row_slice(&reference.twist)));
        acc.rows_mut(6 * i, 6).copy_from(&DVector::from_row_slice(&reference.acceleration));
        let gains = if i == 0 { &cfg.object_gains } else { &cfg.torso_gains };
        kp.rows_mut(6 * i, 6).copy_from(&DVector::from_row_slice(&gains.kp));
        kd.rows_mut(6 * i, 6).copy_from(&DVector::from_row_slice(&gains.kd));
    }
    let a_o = refs.object.as_ref().expect("object").acceleration;
    let w_ff = object_load(&g.object, &g.object_twist, &a_o, cfg.object_mass, &cfg.object_inertia);
    ff.rows_mut(0, 6).copy_from(&w_ff);
    let lambda = (&j * &proj.mc_inv * &proj.p * j.transpose())
        .try_inverse()
        .expect("task space spans the motion space");
    let u = &j * &proj.mc_inv * &p_bias - &jdv + &acc;
    let f = &lambda * u - kd.component_mul(&edot) - kp.component_mul(&e) + ff;
    let expect = j.transpose() * f;
    let err = relv(&tau_m, &expect);
    let err_dense = relv(&tau_m_dense, &expect);
    println!("tau_M vs eq. control_law written out: {err:.1e}, by the dense projections {err_dense:.1e} (|tau_M| {:.1})", expect.amax());
    assert!(err < 1e-8 && err_dense < 1e-8);
    // The object's load: F_x = -w_ff, J_x^T F_x with J_x = J_o.
    assert_eq!(f_x, -w_ff);
    assert!(relv(&load, &(g.j_o.transpose() * (-w_ff))) < 1e-13);

    // The motion yielding (stages::yielding): a task keeping share s of its motion commands
    // s (a_d - K_d edot - K_p e) - (1 - s) K_d v, its feed-forward s w_ff + (1 - s) w_ff(a = 0),
    // mu_c whole; the object's rows at s_o, the torsos' at s_t.
    let w_hold =
        object_load(&g.object, &g.object_twist, &[0.0; 6], cfg.object_mass, &cfg.object_inertia);
    let mut f_x_hold = Vector6::zeros();
    let inp = TaskTorqueInput {
        team,
        grasp: Some(g),
        references: Some(&refs),
        config: &cfg,
        motion: motion.view(&dense),
    };
    task_torque(
        &inp,
        &mut Targets::default(),
        &mut stack,
        &mut tau_m_dense,
        &mut load_dense,
        &mut f_x_dense,
        &mut f_x_hold,
    )
    .expect("tau_M, dense");
    assert_eq!(
        f_x_hold, -w_hold,
        "the object's load held still is its weight (and gyroscopic moment) alone"
    );
    let velocity: Vec<DVector<f64>> = tasks.iter().map(|(jx, ..)| *jx * &team.velocity).collect();
    for (s_o, s_t) in [(1.0, 1.0), (0.0, 1.0), (0.37, 1.0), (0.0, 0.0), (0.0, 0.62)] {
        let mut yielded = DVector::zeros(0);
        stack.joint_torque_yielding(
            &motion.view(&dense),
            coordinator::building_blocks::impedance::MotionScale {
                object: s_o,
                torso: s_t,
                reserve: false,
            },
            &mut yielded,
        );
        let (mut acc_s, mut e_s, mut edot_s, mut ff_s) =
            (acc.clone(), e.clone(), edot.clone(), DVector::zeros(k));
        for (i, v_i) in velocity.iter().enumerate().take(tasks.len()) {
            let share = if i == 0 { s_o } else { s_t };
            let rows = 6 * i..6 * i + 6;
            for (r, row) in rows.enumerate() {
                acc_s[row] = share * acc[row];
                e_s[row] = share * e[row];
                edot_s[row] = share * edot[row] + (1.0 - share) * v_i[r];
                if i == 0 {
                    ff_s[row] = share * w_ff[r] + (1.0 - share) * w_hold[r];
                }
            }
        }
        let u = &j * &proj.mc_inv * &p_bias - &jdv + &acc_s;
        let f = &lambda * u - kd.component_mul(&edot_s) - kp.component_mul(&e_s) + ff_s;
        let expect = j.transpose() * f;
        let err = relv(&yielded, &expect);
        println!("tau_M with the object at {s_o}, the torsos at {s_t} of their motion vs the law written out: {err:.1e}");
        assert!(err < 1e-8, "object {s_o}, torsos {s_t}: {err:.1e}");
    }
}

#[test]
fn contact_map_is_the_papers_rho_and_eta() {
    let mut fx = Fixture::new();
    let (_, _, mut c) = moving_team(&mut fx, 11);
    let r = c.materialized().expect("tick");
    let (team, proj) = (&r.team, &r.proj);
    let g = r.grasp.as_ref().expect("grasp");
    let map = MapInput {
        team,
        proj,
        j_c: &r.j_c,
        tau0: &r.tau0,
        load: &r.load,
        grasp: Some(g),
        f_x: &r.f_x,
    };
    let mut ws = ContactMapScratch::default();
    let (mut y, mut rho, mut eta, mut eta_real) =
        (DMatrix::zeros(0, 0), DMatrix::zeros(0, 0), DVector::zeros(0), DVector::zeros(0));
    contact_map(&map, &mut ws, &mut y, &mut rho, &mut eta, &mut eta_real);

    // eq. relation_between_lambda_and_Fc as printed: rho = (J_c^T)^+ (I - P)(Mbar P - I) S B J_c^T,
    // eta = (J_c^T)^+ (I - P) [eps tau_M + Mbar (-P h + Pdot v) + h + (Mbar P - I) J_x^T F_x],
    // eps = (Mbar P - I) S [P S]^+ P, with Mbar = M M_c^{-1}.
    let n = team.n;
    let id = DMatrix::<f64>::identity(n, n);
    let (p, s) = (&proj.p, diag(&team.s_diag));
    let ip = &id - p;
    let mbar = &team.mass * &proj.mc_inv;
    let k = &mbar * p - &id;
    let jct_pinv = &proj.jct_pinv;
    let rho_paper = jct_pinv * &ip * &k * &s * &proj.b * r.j_c.transpose();
    // eps tau_M = (Mbar P - I) S tau_0 with tau_0 = [P S]^+ P tau_M, saturated at the torque
    // limits when the QP failed on it (the controller then solved again with that).
    let mut tau0 = &proj.ps_pinv * p * &r.tau_m;
    if r.saturated {
        for (&j, &lim) in r.actuated.iter().zip(&r.limits) {
            tau0[j] = tau0[j].clamp(-lim, lim);
        }
    }
    println!("tau_0 saturated: {}", r.saturated);
    let eta_paper = jct_pinv
        * &ip
        * (&k * &s * &tau0
            + &mbar * (-(p * &team.bias) + &proj.pdot_v)
            + &team.bias
            + &k * &r.load);
    let (e_rho, e_eta) = (rel(&rho, &rho_paper), relv(&eta, &eta_paper));
    println!("rho vs the paper {e_rho:.1e}, eta {e_eta:.1e} (|eta| {:.1})", eta_paper.amax());
    assert!(e_rho < 1e-9 && e_eta < 1e-9);
    assert!(rel(&y, &(&proj.b * r.j_c.transpose())) < 1e-13, "Y = B J_c^T");
    // The real wrenches add the object's load share G^+ F_x on the hand rows.
    let (_, g_pinv) = grasp_matrix(
        &team.hands.iter().map(|h| h.position).collect::<Vec<_>>(),
        &g.object.translation.vector,
    );
    let mut expect = eta_paper.clone();
    let nf = team.feet.len();
    let share = &g_pinv * DVector::from_column_slice(r.f_x.as_slice());
    let mut hand_rows = expect.rows_mut(3 * nf, 12);
    hand_rows += &share;
    assert!(relv(&eta_real, &expect) < 1e-9);
    // Feet rows carry no share.
    assert_eq!(eta_real.rows(0, 3 * nf), eta.rows(0, 3 * nf));
}

#[test]
fn contact_wrenches_follow_the_map_or_eq_constraint_force() {
    let mut fx = Fixture::new();
    let (_, _, mut c) = moving_team(&mut fx, 13);
    let r = c.materialized().expect("tick");
    let (team, proj) = (&r.team, &r.proj);
    let eta_real = {
        let mut e = r.eta.clone();
        let nf = team.feet.len();
        e.rows_mut(3 * nf, 12).gemv(1.0, &r.grasp.as_ref().expect("grasp").g_pinv, &r.f_x, 1.0);
        e
    };
    let inp = WrenchInput { team, proj, load: &r.load, rho: &r.rho, eta: &r.eta };
    let mut ws = ContactMapScratch::default();
    // From F_c: lambda = rho F_c + eta.
    let (mut lambda, mut real) = (DVector::zeros(0), eta_real.clone());
    contact_wrenches(&inp, Actuation::ContactForces(&r.f_c), &mut ws, &mut lambda, &mut real);
    let expect = &r.rho * &r.f_c + &r.eta;
    assert!(relv(&lambda, &expect) < 1e-13);
    assert!(relv(&real, &(&expect + &eta_real - &r.eta)) < 1e-13);
    // From a torque (here: a quarter of the tick's): eq. constraint_force written out,
    // lambda = (J_c^T)^+ [(I - P)[Mbar (P S tau - P h + Pdot v) + h] - (I - P) S tau
    //          + (I - P)(Mbar P - I) J_x^T F_x].
    let tau = &r.tau * 0.25;
    let n = team.n;
    let id = DMatrix::<f64>::identity(n, n);
    let (p, s) = (&proj.p, diag(&team.s_diag));
    let ip = &id - p;
    let mbar = &team.mass * &proj.mc_inv;
    let s_tau = &s * &tau;
    let expect = &proj.jct_pinv
        * (&ip * (&mbar * (p * &s_tau - p * &team.bias + &proj.pdot_v) + &team.bias)
            - &ip * &s_tau
            + &ip * (&mbar * p - &id) * &r.load);
    let mut real = eta_real.clone();
    contact_wrenches(&inp, Actuation::Torque(&tau), &mut ws, &mut lambda, &mut real);
    let e = relv(&lambda, &expect);
    println!("lambda(tau) vs eq. constraint_force {e:.1e} (|lambda| {:.1})", expect.amax());
    assert!(e < 1e-9);
    assert!(relv(&real, &(&expect + &eta_real - &r.eta)) < 1e-9);
}

#[test]
fn torque_is_tau0_plus_y_f_c_clamped_after_a_fallback() {
    let mut fx = Fixture::new();
    let (_, _, mut c) = moving_team(&mut fx, 17);
    let r = c.materialized().expect("tick");
    let proj = &r.proj;
    // tau_0 = [P S]^+ P tau_M (eq. ua_solution).
    let (mut tau0, mut scratch) = (DVector::zeros(0), MotionTorqueScratch::default());
    motion_torque(proj, &r.team.s_diag, &r.tau_m, &mut tau0, &mut scratch);
    assert!(relv(&tau0, &(&proj.ps_pinv * (&proj.p * &r.tau_m))) < 1e-13);
    // tau = tau_0 + Y F_c with Y = B J_c^T, for the tick's F_c and another one.
    let y = &proj.b * r.j_c.transpose();
    let mut tau = DVector::zeros(0);
    for f_c in [r.f_c.clone(), DVector::from_fn(r.f_c.len(), |i, _| (i as f64 * 0.7).sin() * 20.0)]
    {
        compose(&r.tau0, &r.y, &f_c, None, &mut tau).expect("finite");
        let expect = &r.tau0 + &y * &f_c;
        assert!(relv(&tau, &expect) < 1e-12);
    }
    // Clamped: the actuated joints to their limits, the rest untouched.
    let f_c = r.f_c.clone() * 50.0;
    let free = &r.tau0 + &y * &f_c;
    let limits: Vec<f64> = r.limits.iter().map(|l| l * 0.05).collect();
    compose(&r.tau0, &r.y, &f_c, Some(Clamp { actuated: &r.actuated, limits: &limits }), &mut tau)
        .expect("finite");
    let mut clamped = 0;
    for i in 0..tau.len() {
        match r.actuated.iter().position(|&j| j == i) {
            Some(k) => {
                let lim = limits[k];
                assert!(tau[i].abs() <= lim);
                if free[i].abs() > lim {
                    clamped += 1;
                    assert_eq!(tau[i], lim * free[i].signum());
                } else {
                    assert!((tau[i] - free[i]).abs() < 1e-9 * free.amax());
                }
            }
            None => assert!(
                (tau[i] - free[i]).abs() < 1e-9 * free.amax(),
                "base row {i} is not clamped"
            ),
        }
    }
    assert!(clamped > 0, "the test clamps something");
    // A non-finite torque is an error, not a command.
    let mut bad = r.f_c.clone();
    bad[0] = f64::NAN;
    assert!(matches!(
        compose(&r.tau0, &r.y, &bad, None, &mut tau),
        Err(ControllerError::NonFinite { .. })
    ));
}

/// The object pose fitted to three and four hands: after a rigid motion of every hand the fit
/// is that motion applied to the object (written out here), with no residual; a hand that
/// slipped by 3 mm shows in the residual and moves the fit by less than it.
#[test]
fn object_pose_fit_follows_any_number_of_hands_and_reports_slip() {
    use coordinator::building_blocks::grasp::GraspOffsets;
    let mut fx = Fixture::new();
    for count in [3, 4] {
        let (terms, _) = fx.static_team(count);
        let mut team = Team::default();
        team.assemble_into(&terms, None, false).expect("team");
        assert_eq!(team.hands.len(), count);
        let object = Isometry3::from_parts(
            Translation3::new(0.02, -0.01, 0.6),
            UnitQuaternion::from_euler_angles(0.05, -0.02, 0.3),
        );
        let offsets = GraspOffsets::capture(&team, &object);
        let at_capture = offsets.fit(&team);
        assert!(
            (at_capture.pose.translation.vector - object.translation.vector).norm() < 1e-12,
            "{count} hands"
        );
        assert!(at_capture.pose.rotation.angle_to(&object.rotation) < 1e-12);
        assert!(at_capture.residual < 1e-12);
        // Move every hand rigidly by T: the object is at T * object.
        let t = Isometry3::from_parts(
            Translation3::new(0.03, 0.04, -0.02),
            UnitQuaternion::from_euler_angles(0.1, 0.2, -0.15),
        );
        for h in &mut team.hands {
            h.position = t.transform_point(&h.position.into()).coords;
            h.rotation = t.rotation.to_rotation_matrix() * h.rotation;
        }
        let moved = offsets.fit(&team);
        let expected = t * object;
        assert!(
            (moved.pose.translation.vector - expected.translation.vector).norm() < 1e-12,
            "{count} hands: {:?}",
            moved.pose
        );
        assert!(moved.pose.rotation.angle_to(&expected.rotation) < 1e-12);
        assert!(moved.residual < 1e-12);
        // One hand slips 3 mm along its face.
        let slip = 0.003;
        let tangent = team.hands[0].rotation * nalgebra::Vector3::x();
        team.hands[0].position += tangent * slip;
        let slipped = offsets.fit(&team);
        assert!(
            slipped.residual > 0.5 * slip && slipped.residual <= slip + 1e-12,
            "{count} hands: residual {}",
            slipped.residual
        );
        assert!(
            (slipped.pose.translation.vector - expected.translation.vector).norm() < slip,
            "the fit moves less than the slip"
        );
    }
}

/// Terms like `t` but with `k` velocities: random `M`, `h`, `v` and frame Jacobians of the
/// new size (assembly checks only shapes and finiteness), so that a team of these lays its
/// robots' blocks out differently from the default robot's at the same team size.
fn resized(t: &DynamicsTerms, k: usize, rng: &mut impl rand::Rng) -> DynamicsTerms {
    let mut out = t.clone();
    out.nv = k.try_into().expect("nv");
    let mut random =
        |r: usize, c: usize| DMatrix::from_fn(r, c, |_, _| rng.random_range(-1.0..1.0));
    out.mass_matrix = protocol::Matrix::from_dmatrix(&random(k, k));
    out.bias = random(k, 1).as_slice().to_vec();
    out.velocity = random(k, 1).as_slice().to_vec();
    for f in &mut out.frames {
        f.jacobian = protocol::Matrix::from_dmatrix(&random(f.role.dim(), k));
    }
    out
}

/// Block-diagonal `M` of the tick, written out from the protocol's row-major blocks.
fn mass_written_out(terms: &[DynamicsTerms]) -> DMatrix<f64> {
    let n: usize = terms.iter().map(|t| t.nv()).sum();
    let mut m = DMatrix::zeros(n, n);
    let mut off = 0;
    for t in terms {
        let k = t.nv();
        for i in 0..k {
            for j in 0..k {
                m[(off + i, off + j)] = t.mass_matrix.data[i * k + j];
            }
        }
        off += k;
    }
    m
}

#[test]
fn a_team_assembled_into_used_buffers_is_the_team_assembled_afresh() {
    // The team's `M`, frame Jacobians and stacked Jacobians are written on their robots'
    // columns only, into the last tick's buffers, and `J_c` row by row without clearing it
    // first: a sequence of ticks whose blocks move (a foot lifts, a hand lets go, other robot
    // sizes at the same team size, fewer robots, then the first tick again, the foot lifted
    // and set down again on the same sizes) must leave nothing behind.
    let mut fx = Fixture::new();
    let mut rng = common::rng(17);
    let nv = fx.robot.model.nv;
    let (all, _) = fx.static_team(3);
    let lifted = ActiveContacts { stance: vec![false, true, true, true], hand_in_grasp: false };
    let mut moved = all.clone();
    moved[1] = fx.terms_with(&robot_id(1), &fx.standing_q(1, 3), &DVector::zeros(nv), 1, &lifted);
    let other_sizes = vec![
        resized(&all[0], nv + 6, &mut rng),
        resized(&all[1], nv - 6, &mut rng),
        all[2].clone(),
    ];
    let resized_again = vec![
        resized(&all[0], nv - 6, &mut rng),
        resized(&all[1], nv + 6, &mut rng),
        resized(&all[2], nv, &mut rng),
    ];
    let fewer = vec![all[0].clone(), all[2].clone()];
    let ticks = [&all, &moved, &other_sizes, &resized_again, &fewer, &all, &moved, &all];

    let (mut team, mut j_c, mut jdv_c) = (Team::default(), DMatrix::zeros(0, 0), DVector::zeros(0));
    for (i, tick) in ticks.iter().enumerate() {
        team.assemble_into(tick, None, false).expect("team");
        let mut fresh = Team::default();
        fresh.assemble_into(tick, None, false).expect("team");
        assert_eq!(team.mass, mass_written_out(tick), "tick {i}: M");
        assert_eq!(team.j_cf, stacked(tick, FrameRole::StanceFoot).0, "tick {i}: J_cf");
        assert_eq!(team.j_ee, stacked(tick, FrameRole::Hand).0, "tick {i}: J_ee");
        for (used, new, what) in [
            (&team.feet, &fresh.feet, "feet"),
            (&team.hands, &fresh.hands, "hands"),
            (&team.free_hands, &fresh.free_hands, "free hands"),
            (&team.torsos, &fresh.torsos, "torsos"),
            (&team.swing_feet, &fresh.swing_feet, "swing feet"),
        ] {
            assert_eq!(used.len(), new.len(), "tick {i}: {what}");
            for (a, b) in used.iter().zip(new) {
                assert_eq!(a.jacobian, b.jacobian, "tick {i}: {what} {}", b.name);
            }
        }
        // J_c with the grasp's rows (into the used buffers and into new ones), then without a
        // grasp: the feet's rows, then zero rows for the hands in grasp.
        let mut grasp: Option<GraspTerms> = None;
        GraspTracker::default().update(&team, None, &[], &mut grasp).expect("grasp");
        let grasp = grasp.expect("grasp terms");
        let (mut new_j_c, mut new_jdv_c) = (DMatrix::zeros(0, 0), DVector::zeros(0));
        contact_jacobian(&team, Some(&grasp), &mut j_c, &mut jdv_c);
        contact_jacobian(&team, Some(&grasp), &mut new_j_c, &mut new_jdv_c);
        assert_eq!((&j_c, &jdv_c), (&new_j_c, &new_jdv_c), "tick {i}: J_c with the grasp");
        // [J_cf; N J_ee] written out (eqs. jacobian_c, jacobian_cee), and J_c v by the frames.
        let mut expect = DMatrix::zeros(team.contact_rows(), team.n);
        expect.rows_mut(0, team.j_cf.nrows()).copy_from(&stacked(tick, FrameRole::StanceFoot).0);
        expect
            .rows_mut(team.j_cf.nrows(), grasp.n.nrows())
            .copy_from(&(&grasp.n * &stacked(tick, FrameRole::Hand).0));
        assert!((&j_c - &expect).amax() <= 1e-12 * expect.amax(), "tick {i}: J_c = [J_cf; N J_ee]");
        let mut jc_v = DVector::zeros(0);
        contact_velocity(&team, Some(&grasp), &mut jc_v);
        let v_expect = &expect * &team.velocity;
        assert!((&jc_v - &v_expect).amax() <= 1e-12 * v_expect.amax().max(1.0), "tick {i}: J_c v");
        contact_jacobian(&team, None, &mut j_c, &mut jdv_c);
        let mut expect = DMatrix::zeros(team.contact_rows(), team.n);
        expect.rows_mut(0, team.j_cf.nrows()).copy_from(&stacked(tick, FrameRole::StanceFoot).0);
        assert_eq!(j_c, expect, "tick {i}: J_c without a grasp");
    }
}

/// `d/dt (J_c,ee) v` and `d/dt (J_o) v` of `GraspTerms` against central differences in time of
/// `J_c,ee(q) v` and `J_o(q) v` along `q(t) = q + v t`, on a moving team of three robots (three
/// hands, so every hand's share of the sums over the grasp counts) whose velocities keep the
/// grasp (`v = P x`): the object is fitted again from the hands at each time, with the offsets
/// captured at `t = 0`.
#[test]
fn grasp_jdot_v_is_the_time_derivative_of_j_cee_v_and_j_o_v() {
    use rand::Rng;
    let mut fx = Fixture::new();
    let (robots, nv, h) = (3, fx.robot.model.nv, 1e-6);
    let mut rng = common::rng(17);
    let qs: Vec<DVector<f64>> =
        (0..robots).map(|k| fx.perturbed_q(k, robots, 0.1, &mut rng)).collect();
    let mut c = Pidc::new(PidcConfig::default());
    for k in 0..robots {
        c.set_description(&fx.description(&robot_id(k)));
    }
    let still: Vec<_> =
        (0..robots).map(|k| fx.terms(&robot_id(k), &qs[k], &DVector::zeros(nv), 1)).collect();
    c.compute(&still).expect("tick");
    let p = c.materialized().expect("tick").proj.p.clone();
    let v = &p * DVector::from_fn(robots * nv, |_, _| rng.random_range(-0.5..0.5));
    let mut tracker = GraspTracker::default();
    let mut grasp_at = |t: f64| {
        let terms: Vec<_> = (0..robots)
            .map(|k| {
                let vk = v.rows(k * nv, nv).into_owned();
                let q = fx.robot.model.integrate(qs[k].as_slice(), vk.as_slice(), t);
                fx.terms(&robot_id(k), &q, &vk, 2)
            })
            .collect();
        let mut team = Team::default();
        team.assemble_into(&terms, None, false).expect("team");
        let mut g: Option<GraspTerms> = None;
        tracker.update(&team, None, &[], &mut g).expect("grasp");
        let g = g.expect("hands in grasp");
        // J_c,ee = N J_ee (eq. jacobian_cee), written out.
        let j_cee = &g.n * &team.j_ee;
        (g, j_cee)
    };
    let (g0, j_cee0) = grasp_at(0.0);
    let ((gp, j_cee_p), (gm, j_cee_m)) = (grasp_at(h), grasp_at(-h));
    // J_c,ee v by the hands' sums (what the constraint residual reads) is N J_ee v.
    let cee_v = &j_cee0 * &v;
    assert!((&g0.jcee_v - &cee_v).amax() <= 1e-12 * cee_v.amax().max(1.0), "J_c,ee v");
    let fd_cee = (&j_cee_p * &v - &j_cee_m * &v) / (2.0 * h);
    let fd_o = (&gp.j_o * &v - &gm.j_o * &v) / (2.0 * h);
    let rel_to = |a: &DVector<f64>, b: &DVector<f64>| (a - b).amax() / b.amax();
    let (e_cee, e_o) = (
        rel_to(&g0.jdv_cee, &fd_cee),
        rel_to(&DVector::from_column_slice(g0.jdv_o.as_slice()), &fd_o),
    );
    println!("d/dt(J_c,ee) v vs central differences: {e_cee:.1e} (|.| {:.2}); d/dt(J_o) v: {e_o:.1e} (|.| {:.2})", fd_cee.amax(), fd_o.amax());
    assert!(fd_cee.amax() > 1e-3 && fd_o.amax() > 1e-3, "a team that moves");
    assert!(e_cee < 1e-6 && e_o < 1e-6, "relative to the differences: {e_cee:.1e}, {e_o:.1e}");
}

#[test]
fn commanded_accelerations_are_the_constrained_dynamics_with_the_object_on_the_hands() {
    let mut fx = Fixture::new();
    let (terms, _, mut c) = moving_team(&mut fx, 17);
    c.keep_accelerations(true);
    c.compute(&terms).expect("tick");
    let r = c.materialized().expect("tick");
    let cfg = PidcConfig::default();
    let (team, proj, g) = (&r.team, &r.proj, r.grasp.as_ref().expect("grasp"));
    assert!(proj.by_blocks, "the tick's accelerations by the team's blocks (the default)");
    let n = team.n;
    // The object as a rigid body on the hands, written out: w_o = [m (a - g); I alpha + w x I w]
    // (world), a_o = J_o qdd + Jdot_o v; the robots M qdd + h = S tau + J_c^T lambda - J_o^T w_o,
    // so P (M qdd + h - S tau + J_o^T w_o) = 0, and the constraints J_c qdd + Jdot_c v = 0.
    let rot = g.object.rotation.to_rotation_matrix();
    let i_w = rot.matrix() * cfg.object_inertia * rot.matrix().transpose();
    let w = Vector3::new(g.object_twist[3], g.object_twist[4], g.object_twist[5]);
    let residuals = |qdd: &DVector<f64>| {
        let a_o = &g.j_o * qdd + &g.jdv_o;
        let lin = cfg.object_mass
            * (Vector3::new(a_o[0], a_o[1], a_o[2])
                - Vector3::from(protocol::conventions::GRAVITY_VECTOR));
        let ang = i_w * Vector3::new(a_o[3], a_o[4], a_o[5]) + w.cross(&(i_w * w));
        let w_o = DVector::from_column_slice(&[lin.x, lin.y, lin.z, ang.x, ang.y, ang.z]);
        let force =
            &team.mass * qdd + &team.bias - diag(&team.s_diag) * &r.tau + g.j_o.transpose() * w_o;
        let dynamics = (&proj.p * &force).amax() / (diag(&team.s_diag) * &r.tau).amax();
        let constraints = (&r.j_c * qdd + &r.jdv_c).amax() / (&r.j_c * qdd).amax().max(1.0);
        (dynamics, constraints)
    };
    let (dynamics, constraints) = residuals(&r.qdd);
    println!("qdd of the tick: dynamics residual {dynamics:.1e}, constraints {constraints:.1e} (|qdd| {:.1})", r.qdd.amax());
    assert!(dynamics < 1e-8 && constraints < 1e-8, "the controller's accelerations");
    // The same by the dense projections.
    let mut dense = proj.clone();
    dense.by_blocks = false;
    let body = ObjectBody { mass: cfg.object_mass, inertia: cfg.object_inertia };
    let mut motion = MotionSpaceTerms::default();
    motion.compute_into(&dense, team);
    let (mut qdd, mut s) = (DVector::zeros(0), AccelerationScratch::default());
    commanded_accelerations(
        team,
        &dense,
        &r.tau,
        &motion.mcinv_bias,
        Some((g, &body)),
        &mut qdd,
        &mut s,
    );
    let (dynamics, constraints) = residuals(&qdd);
    assert!(
        dynamics < 1e-8 && constraints < 1e-8,
        "by the dense projections: {dynamics:.1e} {constraints:.1e}"
    );
    assert!(relv(&qdd, &r.qdd) < 1e-8);
    // Without the object (a team that holds none) the same torque accelerates the team
    // otherwise: the written-out dynamics tell them apart.
    commanded_accelerations(team, &dense, &r.tau, &motion.mcinv_bias, None, &mut qdd, &mut s);
    let (weightless, _) = residuals(&qdd);
    println!("the object left out: dynamics residual {weightless:.1e}");
    assert!(weightless > 1e-3);
    assert_eq!(qdd.len(), n);
}
