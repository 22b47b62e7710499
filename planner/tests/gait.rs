//! The crawl planner against independent statements: derivatives by finite differences, the
//! swing's boundary values, the CoM's margin in the support triangle written out again
//! (barycentric coordinates and edge distances), footholds from the final waypoint, and the
//! errors of impossible input.

use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector2, Vector3};
use planner::gait::support::centre_of_pressure;
use planner::gait::{GaitError, GaitParams, GaitPlan, HandLoad, WalkingRobot, HALT_GUARD};

/// A robot like the project's (feet 0.3 m ahead/behind, 0.2 m to each side of a torso 0.55 m
/// up, foot centres 0.03 m above the ground), in description order LF, RF, LH, RH.
fn robot(id: &str, x: f64, y: f64, yaw_deg: f64, path: &[[f64; 3]]) -> WalkingRobot {
    let start = Isometry3::from_parts(
        Translation3::new(x, y, 0.55),
        UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_deg.to_radians()),
    );
    let foot = |name: &str, fx: f64, fy: f64| {
        (name.to_string(), (start * Point3::new(fx, fy, -0.52)).coords)
    };
    let feet = vec![
        foot("LF", 0.3, 0.2),
        foot("RF", 0.3, -0.2),
        foot("LH", -0.3, 0.2),
        foot("RH", -0.3, -0.2),
    ];
    let mut waypoints = vec![start];
    waypoints.extend(path.iter().map(|w| {
        start
            * Isometry3::from_parts(
                Translation3::new(w[0], w[1], 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, w[2].to_radians()),
            )
    }));
    WalkingRobot {
        robot: id.into(),
        feet,
        com_offset: Vector3::new(0.05, 0.0, 0.0),
        mass: 55.0,
        ground_z: 0.0,
        hand: None,
        waypoints,
    }
}

/// The object's push on a hand 0.85 m ahead of the torso and 0.6 m up: a squeeze of 40 N back
/// towards the robot, 10 N of the object's weight, a small moment (world, for the start pose).
fn with_hand(mut r: WalkingRobot) -> WalkingRobot {
    let start = r.waypoints[0];
    let point = (start * Point3::new(0.85, 0.0, 0.05)).coords;
    r.hand = Some(HandLoad {
        point,
        force: start.rotation * Vector3::new(-40.0, 3.0, -10.0),
        moment: start.rotation * Vector3::new(0.5, -1.0, 0.2),
    });
    r
}

/// Statics written out again: the normal forces of three point feet on flat ground at
/// `ground_z` that carry a robot of `mass` at `com` and a hand load (the horizontal forces,
/// whatever their split, act at the ground's height), by vertical force and moment balance
/// about the world's x and y axes.
fn foot_normal_forces(
    mass: f64,
    com: &Vector3<f64>,
    hand: Option<&HandLoad>,
    ground_z: f64,
    feet: &[Vector2<f64>],
) -> Vector3<f64> {
    let g = protocol::conventions::GRAVITY;
    let (mut fz, mut mx, mut my) = (mass * g, mass * g * com.y, mass * g * com.x);
    if let Some(h) = hand {
        let pf = h.point.cross(&h.force);
        fz -= h.force.z;
        mx -= ground_z * h.force.y + pf.x + h.moment.x;
        my += -ground_z * h.force.x + pf.y + h.moment.y;
    }
    let a = Matrix3::new(
        1.0, 1.0, 1.0, feet[0].x, feet[1].x, feet[2].x, feet[0].y, feet[1].y, feet[2].y,
    );
    a.try_inverse().expect("a proper triangle") * Vector3::new(fz, my, mx)
}

const S2: [[f64; 3]; 3] = [[-0.27, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, -30.0]];

fn s2() -> (GaitPlan, Vec<WalkingRobot>) {
    let robots =
        vec![robot("r1", 0.0, 0.0, 0.0, &S2), robot("r2", 2.3, 0.0, 180.0, &[[0.0; 3]; 3])];
    (GaitPlan::new(&robots, None, &GaitParams::default(), 0.5).expect("plan"), robots)
}

/// Central differences of `f` against its returned derivative at many times.
fn check_derivative(what: &str, t_end: f64, f: impl Fn(f64) -> (Vec<f64>, Vec<f64>, Vec<f64>)) {
    let h = 1e-5;
    let mut t = 0.013;
    while t < t_end {
        let (x0, v, a) = f(t);
        let (xm, vm, _) = f(t - h);
        let (xp, vp, _) = f(t + h);
        for k in 0..x0.len() {
            let fd_v = (xp[k] - xm[k]) / (2.0 * h);
            let fd_a = (vp[k] - vm[k]) / (2.0 * h);
            assert!(
                (fd_v - v[k]).abs() < 1e-4 * (1.0 + v[k].abs()),
                "{what} t {t}: velocity[{k}] {} vs finite difference {fd_v}",
                v[k]
            );
            assert!(
                (fd_a - a[k]).abs() < 2e-3 * (1.0 + a[k].abs()),
                "{what} t {t}: acceleration[{k}] {} vs finite difference {fd_a}",
                a[k]
            );
        }
        t += 0.0371;
    }
}

#[test]
fn torso_object_and_swing_derivatives_match_finite_differences() {
    let robots = vec![
        robot("r1", 0.0, 0.0, 0.0, &[[0.3, 0.1, 20.0]]),
        robot("r2", 2.3, 0.0, 180.0, &[[-0.3, -0.1, 20.0]]),
    ];
    let object = [
        Isometry3::translation(1.15, 0.0, 0.6),
        Isometry3::from_parts(
            Translation3::new(1.45, 0.1, 0.6),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.35),
        ),
    ];
    let plan = GaitPlan::new(&robots, Some(&object), &GaitParams::default(), 0.0).unwrap();
    let pose = |x: Isometry3<f64>| {
        let r = x.rotation.scaled_axis();
        vec![x.translation.x, x.translation.y, x.translation.z, r.x, r.y, r.z]
    };
    // Rotations stay small here, so the scaled axis differentiates to the angular velocity
    // only approximately: compare the linear rows and the yaw row (a rotation about z).
    let rows = |v: Vec<f64>| vec![v[0], v[1], v[2], v[5]];
    check_derivative("torso", plan.end_time(), |t| {
        let (x, v, a) = plan.torso(0, t);
        (rows(pose(x)), rows(v.to_vec()), rows(a.to_vec()))
    });
    check_derivative("object", plan.end_time(), |t| {
        let (x, v, a) = plan.object(t).unwrap();
        (rows(pose(x)), rows(v.to_vec()), rows(a.to_vec()))
    });
    for k in 0..4 {
        check_derivative("swing foot", plan.end_time(), |t| match plan.swing_foot(1, k, t) {
            Some((p, v, a)) => (p.as_slice().to_vec(), v.to_vec(), a.to_vec()),
            None => (vec![0.0; 3], vec![0.0; 3], vec![0.0; 3]),
        });
    }
}

#[test]
fn a_swing_leaves_and_lands_at_rest_lifts_and_presses_into_the_ground() {
    let (plan, _) = s2();
    let p = plan.params().clone();
    for s in plan.steps() {
        let (at_lift, v0, _) = plan.swing_foot(s.robot, s.foot, s.liftoff).unwrap();
        assert!((at_lift - s.from).norm() < 1e-12);
        assert!(v0.iter().all(|x| x.abs() < 1e-12));
        let (land, v1, _) = plan.swing_foot(s.robot, s.foot, s.touchdown - 1e-9).unwrap();
        assert!(
            (land - (s.to - Vector3::z() * p.touchdown_depth)).norm() < 1e-6,
            "lands {} below the foothold",
            p.touchdown_depth
        );
        assert!(v1.iter().all(|x| x.abs() < 1e-6), "touchdown velocity {v1:?}");
        let (mid, _, _) =
            plan.swing_foot(s.robot, s.foot, 0.5 * (s.liftoff + s.touchdown)).unwrap();
        let line = 0.5 * (s.from.z + s.to.z - p.touchdown_depth);
        assert!(
            (mid.z - line - p.lift_height).abs() < 1e-9,
            "apex {} above the line",
            mid.z - line
        );
        assert!(
            (s.touchdown - s.liftoff - p.t_swing).abs() < 1e-12,
            "a swing lasts t_swing: {}",
            s.touchdown - s.liftoff
        );
    }
}

/// Distance of `p` inside triangle `abc`, written out again: negative when a barycentric
/// coordinate is negative, else the least distance to the edges' lines.
fn inside(p: Vector2<f64>, a: Vector2<f64>, b: Vector2<f64>, c: Vector2<f64>) -> f64 {
    let det = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
    let l1 = ((b.x - p.x) * (c.y - p.y) - (c.x - p.x) * (b.y - p.y)) / det;
    let l2 = ((c.x - p.x) * (a.y - p.y) - (a.x - p.x) * (c.y - p.y)) / det;
    let l3 = 1.0 - l1 - l2;
    let line = |u: Vector2<f64>, w: Vector2<f64>| {
        ((w.x - u.x) * (p.y - u.y) - (w.y - u.y) * (p.x - u.x)).abs() / (w - u).norm()
    };
    let d = line(a, b).min(line(b, c)).min(line(c, a));
    if l1 < 0.0 || l2 < 0.0 || l3 < 0.0 {
        -d
    } else {
        d
    }
}

#[test]
fn at_every_liftoff_the_centre_of_mass_is_the_margin_inside_the_other_three_feet() {
    use planner::gait::ShiftRule;
    for (path, shift) in [&S2[..], &[[0.0, 0.3, 0.0]][..], &[[0.25, 0.0, 45.0]][..]]
        .into_iter()
        .flat_map(|p| [(p, ShiftRule::Least), (p, ShiftRule::Incentre)])
    {
        let robots = vec![robot("r1", 0.0, 0.0, 30.0, path)];
        let params = GaitParams { shift, ..GaitParams::default() };
        let plan = GaitPlan::new(&robots, None, &params, 0.0).unwrap();
        assert!(!plan.steps().is_empty());
        // Where every foot is, replayed step by step.
        let mut feet: Vec<Vector3<f64>> = robots[0].feet.iter().map(|(_, p)| *p).collect();
        for s in plan.steps() {
            assert!((feet[s.foot] - s.from).norm() < 1e-12, "a foot lifts off where it landed");
            let (torso, _, _) = plan.torso(0, s.liftoff);
            let com = (torso * Point3::from(robots[0].com_offset)).coords.xy();
            let tri: Vec<Vector2<f64>> =
                (0..4).filter(|f| *f != s.foot).map(|f| feet[f].xy()).collect();
            let m = inside(com, tri[0], tri[1], tri[2]);
            assert!(
                m >= params.margin - 1e-9,
                "path {path:?}: margin {m} at lift-off of foot {}",
                s.foot
            );
            assert!((m - s.margin).abs() < 1e-9, "the reported margin is the real one");
            assert!(
                (s.to - s.from).xy().norm() <= params.stride + 1e-9,
                "a step of {} m",
                (s.to - s.from).xy().norm()
            );
            feet[s.foot] = s.to;
        }
    }
}

/// The centre of pressure against the statics written out again: the feet's normal forces
/// solved for three feet around it put their weighted mean at the same point, and a shift of
/// the centre of mass moves it by `gain` times as far.
#[test]
fn the_centre_of_pressure_balances_the_weight_and_the_hand_load() {
    let feet = [Vector2::new(0.31, 0.22), Vector2::new(-0.28, 0.19), Vector2::new(0.02, -0.25)];
    let loads = [
        None,
        Some(HandLoad {
            point: Vector3::new(0.9, 0.1, 0.65),
            force: Vector3::new(-35.0, 8.0, -12.0),
            moment: Vector3::new(1.0, -2.0, 0.5),
        }),
        Some(HandLoad {
            point: Vector3::new(-0.2, 0.8, 0.4),
            force: Vector3::new(5.0, -60.0, 20.0),
            moment: Vector3::zeros(),
        }),
    ];
    for (k, load) in loads.iter().enumerate() {
        for ground_z in [0.0, 0.12] {
            let com = Vector3::new(0.03, -0.01, 0.5);
            let (cop, gain) = centre_of_pressure(54.0, &com, load.as_ref(), ground_z)
                .expect("the feet carry weight");
            let n = foot_normal_forces(54.0, &com, load.as_ref(), ground_z, &feet);
            let mean = (n[0] * feet[0] + n[1] * feet[1] + n[2] * feet[2]) / n.sum();
            assert!(
                (cop - mean).norm() < 1e-9,
                "load {k}, ground {ground_z}: {cop:?} vs the statics' {mean:?}"
            );
            let d = Vector3::new(0.02, -0.015, 0.0);
            let n2 = foot_normal_forces(54.0, &(com + d), load.as_ref(), ground_z, &feet);
            let moved = (n2[0] * feet[0] + n2[1] * feet[1] + n2[2] * feet[2]) / n2.sum();
            assert!(
                (moved - mean - gain * d.xy()).norm() < 1e-9,
                "load {k}: a CoM shift moves the centre of pressure by gain {gain}"
            );
        }
    }
    assert!(
        (centre_of_pressure(54.0, &Vector3::new(0.1, 0.2, 0.5), None, 0.0).unwrap().0
            - Vector2::new(0.1, 0.2))
        .norm()
            < 1e-12,
        "without a load: under the CoM"
    );
    let lifting = HandLoad {
        point: Vector3::zeros(),
        force: Vector3::new(0.0, 0.0, 600.0),
        moment: Vector3::zeros(),
    };
    assert!(
        centre_of_pressure(54.0, &Vector3::zeros(), Some(&lifting), 0.0).is_none(),
        "a hand that lifts the robot off its feet"
    );
}

/// With a hand load (held where it is while one robot walks, or carried along with the
/// object), at every lift-off the statics' normal forces of the three stance feet are all
/// positive and their centre of pressure is the margin inside the triangle, and so is the bare
/// centre of mass. Planned with the
/// bare centre of mass, the same walks leave it short of that.
#[test]
fn with_a_hand_load_the_centre_of_pressure_is_the_margin_inside_at_every_liftoff() {
    let params = GaitParams { hand_load: true, ..GaitParams::default() };
    let object = |path: &[[f64; 3]]| {
        let start = Isometry3::translation(0.85, 0.0, 0.6);
        std::iter::once(start)
            .chain(path.iter().map(|w| {
                Isometry3::from_parts(
                    Translation3::new(0.85 + w[0], w[1], 0.6),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, w[2].to_radians()),
                )
            }))
            .collect::<Vec<_>>()
    };
    let cases: [(&[[f64; 3]], bool); 4] = [
        (&S2[..], false),
        (&[[0.3, 0.0, 0.0]][..], true),
        (&[[0.0, 0.2, 0.0]][..], true),
        (&[[0.0, 0.0, 30.0]][..], false),
    ];
    for (path, carried) in cases {
        let r = with_hand(robot("r1", 0.0, 0.0, 0.0, path));
        let waypoints = object(path);
        let moving = carried.then_some(&waypoints[..]);
        let plan = GaitPlan::new(std::slice::from_ref(&r), moving, &params, 0.0).unwrap();
        // Without the option the hand's load is not counted, as if there were none.
        let bare_plan =
            GaitPlan::new(std::slice::from_ref(&r), moving, &GaitParams::default(), 0.0).unwrap();
        let mut feet: Vec<Vector3<f64>> = r.feet.iter().map(|(_, p)| *p).collect();
        let mut bare_least = f64::INFINITY;
        for s in plan.steps() {
            let com = |t: f64, p: &GaitPlan| (p.torso(0, t).0 * Point3::from(r.com_offset)).coords;
            // The hand's load where the object is at lift-off (the plan's own object track).
            let load = r.hand.map(|h| match moving {
                Some(_) => HandLoad {
                    point: (plan.object(s.liftoff).unwrap().0
                        * waypoints[0].inverse()
                        * Point3::from(h.point))
                    .coords,
                    force: (plan.object(s.liftoff).unwrap().0.rotation
                        * waypoints[0].rotation.inverse())
                        * h.force,
                    moment: (plan.object(s.liftoff).unwrap().0.rotation
                        * waypoints[0].rotation.inverse())
                        * h.moment,
                },
                None => h,
            });
            let tri: Vec<Vector2<f64>> =
                (0..4).filter(|f| *f != s.foot).map(|f| feet[f].xy()).collect();
            let cop_of = |com: Vector3<f64>| {
                let n = foot_normal_forces(r.mass, &com, load.as_ref(), r.ground_z, &tri);
                (n, (n[0] * tri[0] + n[1] * tri[1] + n[2] * tri[2]) / n.sum())
            };
            let (n, cop) = cop_of(com(s.liftoff, &plan));
            let m = inside(cop, tri[0], tri[1], tri[2]);
            assert!(n.iter().all(|f| *f > 0.0), "path {path:?}: a stance foot pulls ({n:?})");
            assert!(
                m >= params.margin - 1e-9,
                "path {path:?}: centre of pressure {m} inside at lift-off of foot {}",
                s.foot
            );
            // The bare CoM is the margin inside too (the robot stands if the team lets go), and
            // the reported margin is the lesser of the two.
            let c = com(s.liftoff, &plan).xy();
            let m_com = inside(c, tri[0], tri[1], tri[2]);
            assert!(
                m_com >= params.margin - 1e-9,
                "path {path:?}: CoM {m_com} inside at lift-off of foot {}",
                s.foot
            );
            assert!(
                (m.min(m_com) - s.margin).abs() < 1e-9,
                "the reported margin {} is the lesser of {m} and {m_com}",
                s.margin
            );
            feet[s.foot] = s.to;
        }
        // The plan that does not count the load, replayed the same way.
        let mut feet: Vec<Vector3<f64>> = r.feet.iter().map(|(_, p)| *p).collect();
        for b in bare_plan.steps() {
            let load = r.hand.map(|h| match moving {
                Some(_) => {
                    h.moved(&(bare_plan.object(b.liftoff).unwrap().0 * waypoints[0].inverse()))
                }
                None => h,
            });
            let tri: Vec<Vector2<f64>> =
                (0..4).filter(|f| *f != b.foot).map(|f| feet[f].xy()).collect();
            let com = (bare_plan.torso(0, b.liftoff).0 * Point3::from(r.com_offset)).coords;
            let n = foot_normal_forces(r.mass, &com, load.as_ref(), r.ground_z, &tri);
            let cop = (n[0] * tri[0] + n[1] * tri[1] + n[2] * tri[2]) / n.sum();
            bare_least = bare_least.min(inside(cop, tri[0], tri[1], tri[2]));
            feet[b.foot] = b.to;
        }
        assert!(
            bare_least < params.margin - 0.005,
            "path {path:?}: planned without the load, the centre of pressure would still be \
             {bare_least} inside"
        );
    }
}

#[test]
fn never_fewer_than_three_feet_down_and_one_swing_at_a_time() {
    let (plan, _) = s2();
    let changes = plan.contact_changes();
    assert_eq!(changes.len(), 2 * plan.steps().len());
    let mut t = 0.0;
    while t < plan.end_time() + 1.0 {
        let down = plan.stance(0, t).iter().filter(|s| **s).count();
        assert!(down >= 3, "t {t}: {down} feet down");
        t += 0.001;
    }
    for w in plan.steps().windows(2) {
        assert!(w[1].liftoff > w[0].touchdown, "one swing at a time");
    }
    for (time, robot, stance) in &changes {
        assert_eq!(*robot, 0);
        assert!(stance.iter().filter(|s| **s).count() >= 3, "at {time}");
    }
}

#[test]
fn s2_walks_whole_cycles_and_ends_on_the_start_offsets_around_the_goal() {
    let (plan, robots) = s2();
    let p = GaitParams::default();
    // 0.27 m at 0.1 m per step: 3 cycles back, 3 forward; 30 deg at 15 deg per cycle: 2 cycles.
    let r1: Vec<_> = plan.steps().iter().filter(|s| s.robot == 0).collect();
    assert_eq!(r1.len(), 4 * (3 + 3 + 2));
    assert!(plan.steps().iter().all(|s| s.robot == 0), "robot 2 does not walk");
    for f in 0..4 {
        assert_eq!(r1.iter().filter(|s| s.foot == f).count(), 8, "each foot steps once a cycle");
    }
    let goal = plan.final_torso(0);
    assert_eq!(goal, *robots[0].waypoints.last().unwrap());
    let start = robots[0].waypoints[0];
    for (k, (_, p0)) in robots[0].feet.iter().enumerate() {
        let last = r1.iter().rev().find(|s| s.foot == k).unwrap();
        let want = goal * start.inverse() * Point3::from(*p0);
        assert!(
            (last.to - want.coords).norm() < 1e-9,
            "foot {k} ends {} m off",
            (last.to - want.coords).norm()
        );
    }
    let (torso, v, _) = plan.torso(0, plan.end_time() + 0.1);
    assert!(
        (torso.translation.vector - goal.translation.vector).norm() < 1e-12
            && v.iter().all(|x| *x == 0.0)
    );
    assert!((plan.end_time() - (0.5 + r1.len() as f64 * p.step_time() + p.t_shift)).abs() < 1e-9);
    // Ramps: the foot's bound falls to zero at lift-off and rises after touchdown.
    let s = r1[0];
    let bound = |t: f64| plan.max_normal_force(0, s.foot, t);
    assert_eq!(bound(s.liftoff - p.t_unload - 1e-6), None);
    assert!((bound(s.liftoff - p.t_unload).unwrap() - p.unload_force).abs() < 1e-9);
    assert!(bound(s.liftoff - 1e-6).unwrap() < 1e-2);
    assert!((bound(s.touchdown + 0.5 * p.t_load).unwrap() - 0.5 * p.unload_force).abs() < 1e-6);
}

#[test]
fn impossible_walks_are_refused_with_the_reason() {
    let ok = robot("r1", 0.0, 0.0, 0.0, &[[0.2, 0.0, 0.0]]);
    let p = GaitParams::default();
    let mut three = ok.clone();
    three.feet.pop();
    assert!(matches!(GaitPlan::new(&[three], None, &p, 0.0), Err(GaitError::Robot { .. })));
    let mut nan = ok.clone();
    nan.com_offset.x = f64::NAN;
    assert!(matches!(GaitPlan::new(&[nan], None, &p, 0.0), Err(GaitError::Robot { .. })));
    let short = robot("r2", 2.0, 0.0, 0.0, &[]);
    assert!(matches!(
        GaitPlan::new(&[ok.clone(), short], None, &p, 0.0),
        Err(GaitError::Robot { .. })
    ));
    assert!(matches!(
        GaitPlan::new(std::slice::from_ref(&ok), Some(&[Isometry3::identity()]), &p, 0.0),
        Err(GaitError::ObjectWaypoints { .. })
    ));
    for bad in [
        GaitParams { stride: 0.0, ..p.clone() },
        GaitParams { t_swing: f64::NAN, ..p.clone() },
        GaitParams { touchdown_window: 1.0, ..p.clone() },
    ] {
        assert!(matches!(
            GaitPlan::new(std::slice::from_ref(&ok), None, &bad, 0.0),
            Err(GaitError::Params(_))
        ));
    }
    let deep = GaitParams { margin: 0.5, ..p };
    let err = GaitPlan::new(&[ok], None, &deep, 0.0).unwrap_err();
    assert!(matches!(err, GaitError::Margin { .. }), "{err}");
    assert!(err.to_string().contains("inradius"));
}

#[test]
fn a_step_of_exactly_the_stride_is_one_cycle() {
    let p = GaitParams::default();
    for path in [[p.stride, 0.0, 0.0], [0.0, 0.0, p.max_turn_deg]] {
        let plan = GaitPlan::new(&[robot("r1", 0.0, 0.0, 0.0, &[path])], None, &p, 0.0).unwrap();
        assert_eq!(plan.steps().len(), 4, "{path:?}");
    }
}

/// A halted walk stops at [`GaitPlan::quiet_point`]: no robot stepping there (every foot down
/// with no unloading or loading ramp, no swing foot and no torso moving, checked with the
/// plan's own queries), and nothing quieter before it: at every sampled time between the
/// request and the quiet point some robot is stepping.
#[test]
fn a_walk_halts_at_its_first_quiet_point_never_inside_a_step() {
    let robots = vec![
        robot("r1", 0.0, 0.0, 0.0, &[[0.3, 0.1, 10.0]]),
        robot("r2", 2.3, 0.0, 180.0, &[[-0.3, -0.1, 10.0]]),
    ];
    let plan = GaitPlan::new(&robots, None, &GaitParams::default(), 0.5).expect("plan");
    let moving = |v: &[f64]| v.iter().any(|x| x.abs() > 1e-9);
    let at_rest = |t: f64| {
        (0..robots.len()).all(|i| {
            let feet = (0..4).all(|k| {
                plan.stance(i, t)[k]
                    && plan.max_normal_force(i, k, t).is_none()
                    && plan.swing_foot(i, k, t).is_none_or(|s| !moving(&s.1))
            });
            feet && !moving(&plan.torso(i, t).1)
        })
    };
    let end = plan.end_time();
    let p = plan.params();
    let mut boundaries = vec![end];
    for st in plan.steps() {
        let start = st.liftoff - p.t_unload - p.t_shift;
        boundaries.extend([
            start,
            start + p.t_shift,
            st.liftoff,
            st.touchdown - p.touchdown_window,
            st.touchdown,
            st.touchdown + p.t_load,
        ]);
    }
    let mut t = 0.0;
    let mut inside_steps = 0;
    while t < end + 1.0 {
        let q = plan.quiet_point(t);
        assert!(q >= t, "t {t}: quiet point {q} before it");
        assert!(at_rest(q), "t {t}: a robot is stepping at the quiet point {q}");
        if q > t {
            inside_steps += 1;
            // Between two steps the robots rest for an instant only: the first resting one of
            // every phase boundary of every step is the quiet point.
            let first = boundaries
                .iter()
                .copied()
                .filter(|b| *b >= t && at_rest(*b))
                .fold(f64::INFINITY, f64::min);
            assert!(
                (q - first).abs() < 1e-9,
                "t {t}: quiet point {q}, but the robots rest at {first}"
            );
            // And in between (samples at half-integer multiples of 0.1 ms, off the phase
            // boundaries, where a quintic's speed is only just zero) a robot steps.
            let mut s = t + 0.5 * 0.0113;
            while s < q {
                assert!(!at_rest(s), "t {t}: {s} is quiet, before the quiet point {q}");
                s += 0.0113;
            }
        }
        t += 0.037;
    }
    assert!(inside_steps > 100, "most times are inside a step: {inside_steps}");
    assert_eq!(plan.quiet_point(0.2), 0.2, "before the walk");
    assert_eq!(plan.quiet_point(end + 0.5), end + 0.5, "after it");
}

/// A release before a step's lift-off halts the walk at once (the step is cancelled with every
/// foot down); after its lift-off, at the quiet point, once the foot has landed and loaded.
/// After a halt inside an unloading, the foot's bound rises again from where it stood at the
/// load ramp's rate (the ramp written out again here) until it is unbounded; the other feet
/// stay unbounded.
#[test]
fn a_walk_released_before_a_lift_off_halts_at_once_and_loads_the_foot_again() {
    let robots = vec![
        robot("r1", 0.0, 0.0, 0.0, &[[0.3, 0.1, 10.0]]),
        robot("r2", 2.3, 0.0, 180.0, &[[-0.3, -0.1, 10.0]]),
    ];
    let plan = GaitPlan::new(&robots, None, &GaitParams::default(), 0.5).expect("plan");
    let p = plan.params().clone();
    assert!(!plan.steps().is_empty());
    for s in plan.steps() {
        let start = s.liftoff - p.t_unload - p.t_shift;
        for frac in [0.1, 0.5, 0.9] {
            for t in [
                start + frac * p.t_shift,
                s.liftoff - p.t_unload + frac * (p.t_unload - HALT_GUARD),
            ] {
                assert_eq!(
                    plan.halt_point(t),
                    t,
                    "robot {} foot {}: released at {t}, before the lift-off",
                    s.robot,
                    s.foot
                );
                assert!(plan.stance(s.robot, t).iter().all(|&down| down), "every foot down at {t}");
            }
            // Closer to the lift-off than the release can travel: the step goes on.
            let late = s.liftoff - frac * HALT_GUARD;
            assert_eq!(
                plan.halt_point(late),
                plan.quiet_point(late),
                "released {:.3} s before the lift-off",
                s.liftoff - late
            );
            let t = s.liftoff + frac * (s.touchdown - s.liftoff);
            assert_eq!(plan.halt_point(t), plan.quiet_point(t), "released in the swing at {t}");
            assert!(
                plan.halt_point(t) >= s.touchdown + p.t_load - 1e-9,
                "the lifted foot lands and loads first"
            );
        }
        let t_h = s.liftoff - 0.5 * p.t_unload;
        let f_h = plan.max_normal_force(s.robot, s.foot, t_h).expect("unloading at the halt");
        let back = t_h + p.t_load * (1.0 - f_h / p.unload_force);
        for tau in [0.0, 0.25, 0.5, 0.75, 0.99] {
            let t = t_h + tau * (back - t_h);
            let want = f_h + p.unload_force * (t - t_h) / p.t_load;
            let got = plan
                .max_normal_force_after_halt(s.robot, s.foot, t_h, t)
                .expect("still below full load");
            assert!((got - want).abs() < 1e-9 * p.unload_force, "t {t}: bound {got}, ramp {want}");
        }
        assert_eq!(
            plan.max_normal_force_after_halt(s.robot, s.foot, t_h, back + 1e-6),
            None,
            "full load again"
        );
        for k in (0..4).filter(|&k| k != s.foot) {
            assert_eq!(
                plan.max_normal_force_after_halt(s.robot, k, t_h, t_h + 0.01),
                None,
                "foot {k} was not unloading"
            );
        }
        // The cancelled step's foot stays where it stands, pressed, at rest: its start (the
        // last step's landing point, or where it stood before the walk).
        let (held, v, a) = plan.foot_after_halt(s.robot, s.foot, t_h).expect("the stepping foot");
        let pressed = s.from - nalgebra::Vector3::z() * p.touchdown_depth;
        assert!((held - pressed).norm() < 1e-12, "held at {held:?}, stands at {pressed:?}");
        assert!(v.iter().chain(&a).all(|x| *x == 0.0));
    }
    assert_eq!(plan.halt_point(0.2), 0.2, "before the walk");
    let end = plan.end_time();
    assert_eq!(plan.halt_point(end + 0.5), end + 0.5, "after it");
}

/// With `min_share`, every support foot carries at least that share of the weight at every
/// lift-off: the three feet's normal forces by the statics written out again
/// ([`foot_normal_forces`]), for the bare CoM and, with `hand_load`, with the hand's load.
/// The default planner (a distance margin only) leaves less on some foot of the same walks,
/// so the share is what moves the torso there. `support::shares` is the same statics.
#[test]
fn with_a_least_share_every_support_foot_carries_it_at_every_liftoff() {
    let g = protocol::conventions::GRAVITY;
    let least_share = |params: &GaitParams, r: &WalkingRobot, path: &[[f64; 3]]| -> f64 {
        let plan = GaitPlan::new(std::slice::from_ref(r), None, params, 0.0).unwrap();
        let mut feet: Vec<Vector3<f64>> = r.feet.iter().map(|(_, p)| *p).collect();
        let mut least = f64::INFINITY;
        for s in plan.steps() {
            let (torso, _, _) = plan.torso(0, s.liftoff);
            let com = (torso * Point3::from(r.com_offset)).coords;
            let tri: Vec<Vector2<f64>> =
                (0..4).filter(|f| *f != s.foot).map(|f| feet[f].xy()).collect();
            let loads: Vec<Option<&HandLoad>> =
                if params.hand_load { vec![None, r.hand.as_ref()] } else { vec![None] };
            for load in loads {
                let f = foot_normal_forces(r.mass, &com, load, r.ground_z, &tri);
                least = least.min(f.min() / f.sum());
                if load.is_none() {
                    let (cop, _) =
                        centre_of_pressure(r.mass, &com, None, r.ground_z).expect("weight");
                    let shares = planner::gait::support::shares(&cop, &[tri[0], tri[1], tri[2]]);
                    for k in 0..3 {
                        assert!(
                            (shares[k] - f[k] / (r.mass * g)).abs() < 1e-9,
                            "path {path:?}: share {k} {} vs statics {}",
                            shares[k],
                            f[k] / (r.mass * g)
                        );
                    }
                }
            }
            feet[s.foot] = s.to;
        }
        least
    };
    for (path, hand) in
        [(&S2[..], false), (&[[0.0, 0.3, 0.0]][..], false), (&[[0.25, 0.0, 45.0]][..], true)]
    {
        let r = robot("r1", 0.0, 0.0, 30.0, path);
        let r = if hand { with_hand(r) } else { r };
        let base = GaitParams { hand_load: hand, min_share: 0.0, ..GaitParams::default() };
        let plain = least_share(&base, &r, path);
        let shared = least_share(&GaitParams { min_share: 0.2, ..base.clone() }, &r, path);
        println!(
            "path {path:?}: least share {plain:.3} with the margin only, {shared:.3} asking 0.2"
        );
        assert!(plain < 0.2 - 0.01, "path {path:?}: the margin alone already leaves {plain}");
        assert!(shared >= 0.2 - 1e-9, "path {path:?}: least share {shared}");
    }
    let ok = robot("r1", 0.0, 0.0, 0.0, &[[0.1, 0.0, 0.0]]);
    for bad in [0.34, -0.01, f64::NAN] {
        let p = GaitParams { min_share: bad, ..GaitParams::default() };
        assert!(
            matches!(
                GaitPlan::new(std::slice::from_ref(&ok), None, &p, 0.0),
                Err(GaitError::Params(_))
            ),
            "min_share {bad}"
        );
    }
}

/// Barycentric coordinates of `p` in the triangle `a b c`, written out (areas).
fn barycentric(p: Vector2<f64>, a: Vector2<f64>, b: Vector2<f64>, c: Vector2<f64>) -> [f64; 3] {
    let area = |u: Vector2<f64>, v: Vector2<f64>, w: Vector2<f64>| {
        (v.x - u.x) * (w.y - u.y) - (w.x - u.x) * (v.y - u.y)
    };
    let t = area(a, b, c);
    [area(p, b, c) / t, area(a, p, c) / t, area(a, b, p) / t]
}

/// `support::least_shift` against the conditions written out again (the distance inside and
/// the barycentric shares of each point after the shift) and against a search: no shift
/// shorter than the one returned meets them, among many drawn at random in its disc. Then
/// the planner with `shift = "least"`: every lift-off meets the margin and the share.
#[test]
fn the_least_shift_is_the_shortest_that_meets_the_margin_and_the_shares() {
    use planner::gait::support::least_shift;
    use rand::{Rng, SeedableRng};
    let mut rng = rand::rngs::StdRng::seed_from_u64(17);
    let mut uniform = move || rng.random::<f64>();
    let (margin, share) = (0.03, 0.12);
    let meets =
        |pts: &[(Vector2<f64>, f64)], tri: &[Vector2<f64>; 3], d: &Vector2<f64>, tol: f64| {
            pts.iter().all(|(p, g)| {
                let q = p + *g * d;
                inside(q, tri[0], tri[1], tri[2]) >= margin - tol
                    && barycentric(q, tri[0], tri[1], tri[2]).iter().all(|l| *l >= share - tol)
            })
        };
    let mut found = 0;
    for case in 0..200 {
        // A triangle around the origin (angles about a third of a turn apart, some thin) and
        // two points anywhere near it.
        let mut corner = |k: f64| {
            let (a, r) =
                (std::f64::consts::TAU * k / 3.0 + (uniform() - 0.5) * 1.6, 0.2 + 0.3 * uniform());
            Vector2::new(r * a.cos(), r * a.sin())
        };
        let tri = [corner(0.0), corner(1.0), corner(2.0)];
        let mut v = || Vector2::new(uniform() - 0.5, uniform() - 0.5) * 0.6;
        let (p, q) = (v(), v());
        let pts = [(p, 1.0), (q, 0.5 + 0.5 * uniform())];
        match least_shift(&pts, &tri, margin, share) {
            Some(d) => {
                found += 1;
                assert!(
                    meets(&pts, &tri, &d, 1e-9),
                    "case {case}: the shift {d:?} does not meet the conditions"
                );
                let r = d.norm();
                for _ in 0..4000 {
                    let (rho, phi) = (r * uniform().sqrt(), std::f64::consts::TAU * uniform());
                    let e = Vector2::new(rho * phi.cos(), rho * phi.sin());
                    assert!(
                        !(e.norm() < r * (1.0 - 1e-6) - 1e-9 && meets(&pts, &tri, &e, 0.0)),
                        "case {case}: {e:?} is shorter than {d:?} and meets them"
                    );
                }
            }
            None => {
                // Then the conditions cannot hold: the inradius is under the margin, or a
                // share ring is empty, or no shift meets both points (searched in a wide disc).
                for _ in 0..4000 {
                    let e = Vector2::new(uniform() - 0.5, uniform() - 0.5) * 4.0;
                    assert!(
                        !meets(&pts, &tri, &e, 0.0),
                        "case {case}: no shift returned, but {e:?} meets the conditions"
                    );
                }
            }
        }
    }
    println!("{found} of 200 random cases feasible");
    assert!(found > 20, "only {found} of 200 random cases feasible");

    let params = GaitParams {
        shift: planner::gait::ShiftRule::Least,
        min_share: share,
        ..GaitParams::default()
    };
    for path in [&S2[..], &[[0.0, 0.3, 0.0]][..], &[[0.25, 0.0, 45.0]][..]] {
        let r = robot("r1", 0.0, 0.0, 30.0, path);
        let plan = GaitPlan::new(std::slice::from_ref(&r), None, &params, 0.0).unwrap();
        let mut feet: Vec<Vector3<f64>> = r.feet.iter().map(|(_, p)| *p).collect();
        for s in plan.steps() {
            let (torso, _, _) = plan.torso(0, s.liftoff);
            let com = (torso * Point3::from(r.com_offset)).coords.xy();
            let tri: Vec<Vector2<f64>> =
                (0..4).filter(|f| *f != s.foot).map(|f| feet[f].xy()).collect();
            assert!(
                inside(com, tri[0], tri[1], tri[2]) >= params.margin - 1e-9,
                "path {path:?}: margin at lift-off of foot {}",
                s.foot
            );
            assert!(
                barycentric(com, tri[0], tri[1], tri[2]).iter().all(|l| *l >= share - 1e-9),
                "path {path:?}: share at lift-off of foot {}",
                s.foot
            );
            feet[s.foot] = s.to;
        }
    }
}
