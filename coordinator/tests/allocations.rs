//! The control tick allocates nothing once the team's shape is known: `Pidc::solve`
//! (assembly, projections, impedance, QP, torque slices and diagnostics) is counted by a
//! global allocator that counts per thread, so the other tests of this binary cannot disturb
//! the count.
//!
//! The one exception is inside faer's SVD and LU, whose internal products allocate packing
//! buffers (see `coordinator::linalg`): those are counted apart, through
//! `linalg::in_decomposition`, and reported.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use common::{robot_id, Fixture};
use coordinator::{Pidc, PidcConfig, TeamController};
use nalgebra::DVector;
use protocol::{DynamicsTerms, QpStatus, TorqueCommand};
use robot_agent::terms::ActiveContacts;

struct Counting;
thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    static IN_DECOMPOSITIONS: Cell<u64> = const { Cell::new(0) };
}
fn count() {
    let counter =
        if coordinator::linalg::in_decomposition() { &IN_DECOMPOSITIONS } else { &ALLOCATIONS };
    let _ = counter.try_with(|c| c.set(c.get() + 1));
}
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(p, l, new_size) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
}
#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by this thread while `f` runs: outside and inside faer's decompositions.
fn allocations(f: impl FnOnce()) -> (u64, u64) {
    let before = (ALLOCATIONS.with(Cell::get), IN_DECOMPOSITIONS.with(Cell::get));
    f();
    (ALLOCATIONS.with(Cell::get) - before.0, IN_DECOMPOSITIONS.with(Cell::get) - before.1)
}

/// A controller and its output messages, kept from tick to tick as the service keeps them.
struct Loop {
    c: Pidc,
    out: Vec<TorqueCommand>,
    inside: Vec<u64>,
}

impl Loop {
    fn new(descs: &[protocol::RobotDescription]) -> Self {
        Self::with(descs, PidcConfig::default())
    }

    fn with(descs: &[protocol::RobotDescription], cfg: PidcConfig) -> Self {
        let mut c = Pidc::new(cfg);
        for d in descs {
            c.set_description(d);
        }
        Loop { c, out: Vec::new(), inside: Vec::new() }
    }

    /// Allocations (outside the decompositions) of each of `ticks` consecutive ticks on
    /// `terms`, tick numbers advancing.
    fn run(&mut self, terms: &mut [DynamicsTerms], ticks: usize) -> Vec<u64> {
        (0..ticks)
            .map(|_| {
                for t in terms.iter_mut() {
                    t.header.tick += 1;
                }
                let (outside, inside) =
                    allocations(|| self.c.solve(terms, &mut self.out).expect("tick"));
                self.inside.push(inside);
                outside
            })
            .collect()
    }
}

#[test]
fn the_tick_allocates_nothing_once_the_team_shape_is_known() {
    let mut fx = Fixture::new();
    let (mut terms, descs) = fx.static_team(2);
    // A moving team: velocities in every joint (the grasp twist terms are then non-zero).
    let nv = fx.robot.model.nv;
    let mut rng = common::rng(7);
    let q: Vec<_> = (0..2).map(|k| fx.perturbed_q(k, 2, 0.05, &mut rng)).collect();
    for (k, t) in terms.iter_mut().enumerate() {
        let v = DVector::from_fn(nv, |i, _| 0.02 * ((i + 3 * k) as f64).sin());
        *t = fx.terms(&robot_id(k), &q[k], &v, 1);
    }
    let mut l = Loop::new(&descs);
    let first = l.run(&mut terms, 1)[0];
    let steady = l.run(&mut terms, 20);
    let r = l.c.last().expect("tick");
    println!("2 robots: first tick {first} allocations, then {steady:?}; inside faer's decompositions {:?}; QP {:?} by {}", &l.inside[1..], r.qp.status, r.qp.solver);
    assert!(first > 0, "the first tick sizes the buffers (the counter counts)");
    assert!(
        matches!(r.qp.status, QpStatus::Solved | QpStatus::AlmostSolved)
            && r.qp.solver != "clarabel"
    );
    assert_eq!(
        r.qp.solver,
        coordinator::qp::by_blocks::SOLVER,
        "the steady ticks' QP by the robots' blocks (the default)"
    );
    assert!(r.proj.by_blocks, "the projections by the team's blocks (the default)");
    assert_eq!(steady, vec![0; 20], "steady ticks allocate nothing");
    assert!(l.c.diagnostics().is_some_and(|d| d.contacts.len() == 10));
    assert_eq!(l.out.len(), 2);
    // With a team delay the tick also computes what its torque accelerates (the object on the
    // hands): sized on its first tick, nothing after.
    l.c.keep_accelerations(true);
    let first = l.run(&mut terms, 1)[0];
    let steady = l.run(&mut terms, 20);
    println!("keeping the accelerations: first tick {first} allocations, then {steady:?}");
    assert!(l
        .c
        .accelerations(&robot_id(0))
        .is_some_and(|a| a.len() == nv && a.iter().any(|x| *x != 0.0)));
    assert_eq!(steady, vec![0; 20], "steady ticks keeping the accelerations allocate nothing");
}

#[test]
fn a_new_contact_set_resizes_once_then_allocates_nothing() {
    // The contact set changes (a foot lifts): the first tick of the new shape resizes, the
    // next ones allocate nothing again; back to all stance likewise.
    let mut fx = Fixture::new();
    let (mut terms, descs) = fx.static_team(2);
    let mut l = Loop::new(&descs);
    l.run(&mut terms, 2);
    let nv = fx.robot.model.nv;
    let cs = ActiveContacts { stance: vec![false, true, true, true], hand_in_grasp: true };
    let all_stance = terms[0].clone();
    terms[0] =
        fx.terms_with("r1", &fx.standing_q(0, 2), &DVector::zeros(nv), terms[0].header.tick, &cs);
    let changed = l.run(&mut terms, 6);
    let r = l.c.last().expect("tick");
    println!("a foot lifts: {changed:?}; QP {:?} by {}", r.qp.status, r.qp.solver);
    assert_eq!((r.team.feet.len(), r.team.swing_feet.len()), (7, 1));
    assert_ne!(
        r.qp.solver, "clarabel",
        "Clarabel allocates; this test is about the active-set and dense paths"
    );
    assert!(changed[0] > 0);
    assert_eq!(&changed[1..], &[0; 5]);
    terms[0] = all_stance;
    let back = l.run(&mut terms, 6);
    println!("back to all stance: {back:?}");
    assert_eq!(&back[1..], &[0; 5]);
}

#[test]
fn four_robots_allocate_nothing_either() {
    let mut fx = Fixture::new();
    let (mut terms, descs) = fx.static_team(4);
    let mut l = Loop::new(&descs);
    l.run(&mut terms, 2);
    let steady = l.run(&mut terms, 5);
    println!("4 robots: {steady:?}; inside faer's decompositions {:?}", &l.inside[2..]);
    assert!(l.c.last().is_some_and(|r| r.proj.by_blocks));
    assert_eq!(steady, vec![0; 5]);
}

#[test]
fn the_active_set_path_allocates_nothing_either() {
    // The dual active-set method (`qp_path = QpPath::ActiveSet`): a cold first tick, hot ticks after it, and
    // a contact set that changes (cold again on the new shape).
    let mut fx = Fixture::new();
    let (mut terms, descs) = fx.static_team(2);
    let mut l = Loop::with(
        &descs,
        PidcConfig { qp_path: coordinator::qp::QpPath::ActiveSet, ..PidcConfig::default() },
    );
    l.run(&mut terms, 2);
    let steady = l.run(&mut terms, 10);
    assert_eq!(l.c.last().map(|r| r.qp.solver), Some("active-set"));
    assert_eq!(steady, vec![0; 10]);
    let nv = fx.robot.model.nv;
    let cs = ActiveContacts { stance: vec![false, true, true, true], hand_in_grasp: true };
    terms[0] =
        fx.terms_with("r1", &fx.standing_q(0, 2), &DVector::zeros(nv), terms[0].header.tick, &cs);
    let changed = l.run(&mut terms, 6);
    println!("active set: steady {steady:?}, a foot lifts {changed:?}");
    assert_eq!(l.c.last().map(|r| r.qp.solver), Some("active-set"));
    assert_eq!(&changed[1..], &[0; 5]);
}
