//! The QP's constraint rows against an independent statement of each physical constraint.
//!
//! `contact_rows` and `constraints_into` write the constraints as rows `c . lambda >= lo` and
//! `A F <= b`. Here each constraint is written out again the way the physics states it, without
//! rows: for a foot the friction pyramid and the normal force in the world frame (normal +z);
//! for a hand, in its frame `(t_x, t_y, n)` with `n` the palm's outward normal, the normal force
//! `f_n = -n . f` (the object pushes the palm back), sliding and torsional friction in one
//! cone (`|t_x . f| / mu + |t_y . f| / mu + |n . m| / xi <= f_n`, one face per sign), and the
//! centre of pressure `p` in the rectangular patch,
//! found from the moment of the normal force (`m_tilt = p x (-f_n n)`, so `p = -(n x m) / f_n`);
//! for the actuated joints `|tau_0 + Y F|_j <= lim_j` (eq. real_torque_limit).
//!
//! A wrench meets the physical statement iff it meets the rows: wrenches strictly inside meet
//! every row, and a wrench that breaks exactly one physical constraint (by 2 % to 50 %) breaks
//! exactly one row, the same row every time, each constraint its own. A sign error, a wrong
//! coefficient, or the paper's pairing of the tilt rows (eqn. moment_constraint pairs
//! `delta_x` with `m_x`; the centre of pressure pairs `delta_y` with `m_x`: a moment about `t_x`
//! comes from pressure displaced along `t_y`) makes one of these fail: the inside samples reach
//! 98 % of each bound and the patch's half-sizes are drawn independently.

mod common;

use clarabel::solver::{
    DefaultSettings, DefaultSolver, IPSolver, SecondOrderConeT, SolverStatus, ZeroConeT,
};
use coordinator::qp::{
    self, constraints_into, contact_rows, ContactKind, DenseIpm, QpInput, QpPath, QpSettings,
    QpSolver, QpWorkspace, DENSE_TOL,
};
use coordinator::PidcConfig;
use nalgebra::{DMatrix, DVector, Rotation3, UnitQuaternion, Vector3, Vector4};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// A contact as the physics sees it.
#[derive(Debug, Clone)]
enum Contact {
    /// World normal +z.
    Foot { mu: f64, f_min: f64 },
    /// `rot`'s columns are the hand frame's `t_x`, `t_y`, `n` in the world; `half` =
    /// `[delta_x, delta_y]`, the patch's half-sizes along `t_x` and `t_y`.
    Hand { rot: Rotation3<f64>, mu: f64, xi: f64, half: [f64; 2], f_min: f64 },
}

fn random_rotation(rng: &mut StdRng) -> Rotation3<f64> {
    loop {
        let q = Vector4::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let norm = q.norm();
        if norm > 0.1 && norm < 1.0 {
            return UnitQuaternion::from_quaternion(nalgebra::Quaternion::from_vector(q / norm))
                .to_rotation_matrix();
        }
    }
}

impl Contact {
    fn random(rng: &mut StdRng, hand: bool) -> Self {
        let mu = rng.random_range(0.2..1.2);
        let f_min = rng.random_range(0.5..50.0);
        if hand {
            let half = [rng.random_range(0.02..0.15), rng.random_range(0.02..0.15)];
            Contact::Hand {
                rot: random_rotation(rng),
                mu,
                xi: rng.random_range(0.005..0.1),
                half,
                f_min,
            }
        } else {
            Contact::Foot { mu, f_min }
        }
    }

    /// What the controller hands the QP.
    fn kind(&self) -> ContactKind {
        match *self {
            Contact::Foot { mu, f_min } => ContactKind::Foot { mu, f_min, f_max: f64::INFINITY },
            Contact::Hand { rot, mu, xi, half, f_min } => {
                let r = rot.matrix();
                ContactKind::Hand {
                    tx: r.column(0).into(),
                    ty: r.column(1).into(),
                    n: r.column(2).into(),
                    mu,
                    xi,
                    half,
                    f_min,
                }
            }
        }
    }

    fn dim(&self) -> usize {
        match self {
            Contact::Foot { .. } => 3,
            Contact::Hand { .. } => 6,
        }
    }

    /// Each physical constraint's name and slack (`>= 0` when it holds) for the wrench `w`
    /// ON the robot (world-aligned, `[f; m]`).
    fn physics(&self, w: &[f64]) -> Vec<(&'static str, f64)> {
        match *self {
            Contact::Foot { mu, f_min } => {
                let (f_x, f_y, f_n) = (w[0], w[1], w[2]);
                vec![
                    ("f_x <= mu f_n", mu * f_n - f_x),
                    ("-f_x <= mu f_n", mu * f_n + f_x),
                    ("f_y <= mu f_n", mu * f_n - f_y),
                    ("-f_y <= mu f_n", mu * f_n + f_y),
                    ("f_n >= f_min", f_n - f_min),
                ]
            }
            Contact::Hand { rot, mu, xi, half, f_min } => {
                let (tx, ty, n) = (rot * Vector3::x(), rot * Vector3::y(), rot * Vector3::z());
                let f = Vector3::new(w[0], w[1], w[2]);
                let m = Vector3::new(w[3], w[4], w[5]);
                // The object pushes the palm back along -n.
                let f_n = -n.dot(&f);
                let f_t = f + f_n * n;
                // Centre of pressure: the tilt moment is the normal force's, applied at p in the
                // patch plane. Without a normal force there is none: outside the patch.
                let p = if f_n > 0.0 { -n.cross(&m) / f_n } else { Vector3::repeat(f64::INFINITY) };
                let (p_x, p_y) = (tx.dot(&p), ty.dot(&p));
                // Sliding and torsional friction in one cone: the cross-polytope
                // |t_x.f| / mu + |t_y.f| / mu + |n.m| / xi <= f_n, one face per sign.
                let mut out: Vec<(&'static str, f64)> = HAND_FACES
                    .iter()
                    .map(|&(name, [sx, sy, sz])| {
                        (
                            name,
                            f_n - (sx * tx.dot(&f_t) / mu
                                + sy * ty.dot(&f_t) / mu
                                + sz * n.dot(&m) / xi),
                        )
                    })
                    .collect();
                out.extend([
                    ("f_n >= f_min", f_n - f_min),
                    ("p_x <= delta_x", half[0] - p_x),
                    ("-p_x <= delta_x", half[0] + p_x),
                    ("p_y <= delta_y", half[1] - p_y),
                    ("-p_y <= delta_y", half[1] + p_y),
                ]);
                out
            }
        }
    }

    fn count(&self) -> usize {
        match self {
            Contact::Foot { .. } => 5,
            Contact::Hand { .. } => 13,
        }
    }

    /// A wrench strictly inside every physical constraint (up to 98 % of each bound), or
    /// breaking exactly constraint `violate` (by 2 % to 50 %), built from the physics: friction
    /// forces, a normal force, a torsional moment and the normal force at a centre of pressure.
    fn sample(&self, rng: &mut StdRng, violate: Option<usize>) -> Vec<f64> {
        // Ratio to a two-sided bound, constraints `plus` (coordinate <= bound) and `minus`.
        let ratio = |rng: &mut StdRng, plus: usize, minus: usize| {
            let out = rng.random_range(1.02..1.5);
            match violate {
                Some(v) if v == plus => out,
                Some(v) if v == minus => -out,
                _ => rng.random_range(-0.98..0.98),
            }
        };
        let f_n_index = match self {
            Contact::Foot { .. } => 4,
            Contact::Hand { .. } => HAND_FACES.len(),
        };
        let f_min = match *self {
            Contact::Foot { f_min, .. } | Contact::Hand { f_min, .. } => f_min,
        };
        let f_n = if violate == Some(f_n_index) {
            f_min * rng.random_range(0.3..0.98)
        } else {
            f_min * rng.random_range(1.02..20.0)
        };
        match *self {
            Contact::Foot { mu, .. } => {
                let (r0, r1) = (ratio(rng, 0, 1), ratio(rng, 2, 3));
                vec![r0 * mu * f_n, r1 * mu * f_n, f_n]
            }
            Contact::Hand { rot, mu, xi, half, .. } => {
                let [a, b, c] =
                    cross_polytope_point(rng, violate.filter(|v| *v < HAND_FACES.len()));
                let (p_x, p_y) = (
                    ratio(rng, f_n_index + 1, f_n_index + 2),
                    ratio(rng, f_n_index + 3, f_n_index + 4),
                );
                let (tx, ty, n) = (rot * Vector3::x(), rot * Vector3::y(), rot * Vector3::z());
                let f = a * mu * f_n * tx + b * mu * f_n * ty - f_n * n;
                let p = p_x * half[0] * tx + p_y * half[1] * ty;
                let m = p.cross(&(-f_n * n)) + c * xi * f_n * n;
                vec![f.x, f.y, f.z, m.x, m.y, m.z]
            }
        }
    }
}

/// A hand's friction faces: `s_x t_x.f / mu + s_y t_y.f / mu + s_z n.m / xi <= f_n`.
const HAND_FACES: [(&str, [f64; 3]); 8] = [
    ("+t_x.f/mu +t_y.f/mu +n.m/xi <= f_n", [1.0, 1.0, 1.0]),
    ("+t_x.f/mu +t_y.f/mu -n.m/xi <= f_n", [1.0, 1.0, -1.0]),
    ("+t_x.f/mu -t_y.f/mu +n.m/xi <= f_n", [1.0, -1.0, 1.0]),
    ("+t_x.f/mu -t_y.f/mu -n.m/xi <= f_n", [1.0, -1.0, -1.0]),
    ("-t_x.f/mu +t_y.f/mu +n.m/xi <= f_n", [-1.0, 1.0, 1.0]),
    ("-t_x.f/mu +t_y.f/mu -n.m/xi <= f_n", [-1.0, 1.0, -1.0]),
    ("-t_x.f/mu -t_y.f/mu +n.m/xi <= f_n", [-1.0, -1.0, 1.0]),
    ("-t_x.f/mu -t_y.f/mu -n.m/xi <= f_n", [-1.0, -1.0, -1.0]),
];

/// `(a, b, c)` (tangential forces in `mu f_n`, torsion in `xi f_n`): with `|a| + |b| + |c|`
/// up to 0.98 (`face` None), or past face `face` alone by 2 % to 50 % (every other face's
/// sum, one sign flipped, stays below 0.98).
fn cross_polytope_point(rng: &mut StdRng, face: Option<usize>) -> [f64; 3] {
    let (signs, sum) = match face {
        Some(k) => (HAND_FACES[k].1, rng.random_range(1.02..1.5)),
        None => (
            [0; 3].map(|_: i32| if rng.random_bool(0.5) { 1.0 } else { -1.0 }),
            rng.random_range(0.0..0.98),
        ),
    };
    loop {
        let w = [0; 3].map(|_: i32| rng.random_range(0.05..1.0));
        let total: f64 = w.iter().sum();
        let x = w.map(|wi| wi / total * sum);
        // Flipping component i's sign takes 2 x_i off the sum.
        if face.is_none() || x.iter().all(|xi| sum - 2.0 * xi < 0.98) {
            return [signs[0] * x[0], signs[1] * x[1], signs[2] * x[2]];
        }
    }
}

/// The rows a physical constraint maps to: one row each, the same every time, all distinct.
struct RowMap {
    names: Vec<&'static str>,
    row_of: Vec<Option<usize>>,
}

impl RowMap {
    fn new(names: Vec<&'static str>) -> Self {
        let n = names.len();
        RowMap { names, row_of: vec![None; n] }
    }

    fn record(&mut self, constraint: usize, flagged: &[usize], context: &str) {
        let name = self.names[constraint];
        assert_eq!(
            flagged.len(),
            1,
            "{context}: breaking `{name}` alone must break exactly one row, broke {flagged:?}"
        );
        match self.row_of[constraint] {
            None => self.row_of[constraint] = Some(flagged[0]),
            Some(r) => assert_eq!(
                r, flagged[0],
                "{context}: `{name}` maps to row {r} and now {}",
                flagged[0]
            ),
        }
    }

    /// Every constraint seen, each on its own row, covering all `rows`.
    fn assert_bijection(&self, rows: usize) -> Vec<usize> {
        let of: Vec<usize> = self
            .row_of
            .iter()
            .zip(&self.names)
            .map(|(r, n)| r.unwrap_or_else(|| panic!("`{n}` never sampled")))
            .collect();
        let mut sorted = of.clone();
        sorted.sort_unstable();
        assert_eq!(
            sorted,
            (0..rows).collect::<Vec<_>>(),
            "constraints -> rows {:?}",
            self.names.iter().zip(&of).collect::<Vec<_>>()
        );
        of
    }
}

/// The rows of `contact_rows` broken by the wrench `w`.
fn broken_rows(kind: &ContactKind, w: &[f64]) -> Vec<usize> {
    let rows = contact_rows(kind);
    rows.iter()
        .enumerate()
        .filter(|(_, (c, lo))| c.iter().zip(w).map(|(a, b)| a * b).sum::<f64>() < *lo)
        .map(|(i, _)| i)
        .collect()
}

/// The physical constraints a wrench breaks (to check the sampler itself).
fn broken_physics(contact: &Contact, w: &[f64]) -> Vec<usize> {
    contact.physics(w).iter().enumerate().filter(|(_, (_, s))| *s < 0.0).map(|(i, _)| i).collect()
}

fn check_contact_rows(hand: bool, seed: u64) {
    let mut rng = StdRng::seed_from_u64(seed);
    let kind_name = if hand { "hand" } else { "foot" };
    for case in 0..200 {
        let contact = Contact::random(&mut rng, hand);
        let kind = contact.kind();
        let rows = contact_rows(&kind);
        assert_eq!(rows.len(), contact.count(), "{kind_name}: one row per physical constraint");
        assert!(rows.iter().all(|(c, _)| c.len() == contact.dim()));
        let mut map = RowMap::new(
            contact.physics(&[0.0; 6][..contact.dim()]).iter().map(|(n, _)| *n).collect(),
        );
        for _ in 0..20 {
            let w = contact.sample(&mut rng, None);
            assert!(broken_physics(&contact, &w).is_empty(), "sampler");
            let broken = broken_rows(&kind, &w);
            assert!(broken.is_empty(), "{kind_name} case {case} {contact:?}: a wrench inside every physical constraint breaks rows {broken:?}: {w:?}");
            for v in 0..contact.count() {
                let w = contact.sample(&mut rng, Some(v));
                assert_eq!(broken_physics(&contact, &w), vec![v], "sampler");
                map.record(
                    v,
                    &broken_rows(&kind, &w),
                    &format!("{kind_name} case {case} {contact:?}"),
                );
            }
        }
        let row_of = map.assert_bijection(rows.len());
        if hand {
            // Each friction face is the row of its signs in FRICTION_SIGNS' order (the order
            // the capacity report names them in).
            for (k, (name, signs)) in HAND_FACES.iter().enumerate() {
                let named = qp::FRICTION_SIGNS
                    .iter()
                    .position(|&(x, y, z)| [x, y, z] == *signs)
                    .expect("a sign combination");
                assert_eq!(
                    row_of[k], named,
                    "`{name}` is row {}, FRICTION_SIGNS says {named}",
                    row_of[k]
                );
            }
        }
    }
}

#[test]
fn foot_rows_are_the_friction_pyramid_and_the_normal_force() {
    check_contact_rows(false, 1);
}

#[test]
fn hand_rows_are_friction_torsion_and_centre_of_pressure_in_the_hand_frame() {
    check_contact_rows(true, 2);
}

/// The deviation from the paper, on the default palm (`delta_x` = 0.075 m, `delta_y` = 0.05 m):
/// pressure at `p_y = 1.3 delta_y` (off the patch) gives `|m_x| = 0.065 f_n`, which the paper's
/// row `|m_x| <= delta_x f_n` lets through and ours stops.
#[test]
fn tilt_rows_pair_each_moment_with_the_half_size_across_it_not_the_papers() {
    let rot = Rotation3::from_euler_angles(0.3, -0.2, 1.1);
    let contact = Contact::Hand { rot, mu: 0.5, xi: 0.02, half: [0.075, 0.05], f_min: 10.0 };
    let kind = contact.kind();
    let (tx, ty, n) = (rot * Vector3::x(), rot * Vector3::y(), rot * Vector3::z());
    let f_n = 40.0;
    let f = -f_n * n;
    let w = |p: Vector3<f64>| {
        let m = p.cross(&f);
        vec![f.x, f.y, f.z, m.x, m.y, m.z]
    };
    // Off the patch along t_y (past delta_y, within delta_x).
    let off_y = w(1.3 * 0.05 * ty);
    let m_x = tx.dot(&Vector3::new(off_y[3], off_y[4], off_y[5]));
    assert!((m_x.abs() - 0.065 * f_n).abs() < 1e-9);
    let paper_row_holds = m_x.abs() <= 0.075 * f_n;
    assert!(paper_row_holds, "the paper's pairing accepts it");
    assert_eq!(broken_physics(&contact, &off_y), vec![11], "p_y <= delta_y");
    assert_eq!(broken_rows(&kind, &off_y).len(), 1, "our rows stop it");
    // On the patch near its t_x edge (within delta_x, past delta_y): accepted, where the
    // paper's |m_y| <= delta_y f_n would refuse it.
    let near_x = w(0.95 * 0.075 * tx);
    assert!(broken_physics(&contact, &near_x).is_empty());
    assert!(broken_rows(&kind, &near_x).is_empty(), "our rows accept it");
    let m_y = ty.dot(&Vector3::new(near_x[3], near_x[4], near_x[5]));
    assert!(m_y.abs() > 0.05 * f_n, "the paper's pairing would refuse it");
}

/// Whether four contact points at the palm's corners, each with MuJoCo's condim-6 elliptic
/// cone `f_n,i >= |(f_x,i / mu, f_y,i / mu, tau_i / xi)|` (rolling friction left at zero),
/// can carry the palm wrench `[f_x, f_y, m_x, m_y, m_z]` (palm frame, moments about its centre)
/// with a normal force of 1: a second-order cone program (Clarabel), feasible or not.
/// Independent of `contact_rows`: the physics of the simulated palm, written out.
fn corners_carry(mu: f64, xi: f64, half: [f64; 2], w: [f64; 5]) -> bool {
    let corners = [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)]
        .map(|(sx, sy)| (sx * half[0], sy * half[1]));
    // Variables per corner i: (f_n, u, v, t) with f_x = mu u, f_y = mu v, tau = xi t.
    let n = 16;
    let mut a = DMatrix::<f64>::zeros(6 + n, n);
    for (i, &(x, y)) in corners.iter().enumerate() {
        let c = 4 * i;
        a[(0, c)] = 1.0; // sum f_n = 1
        a[(1, c + 1)] = mu; // sum f_x
        a[(2, c + 2)] = mu; // sum f_y
                            // The force on the palm at (x, y, 0) is (f_x, f_y, -f_n): its moment about the centre
                            // is (-y f_n, x f_n, x f_y - y f_x), plus the point's torsion along the normal.
        a[(3, c)] = -y;
        a[(4, c)] = x;
        a[(5, c + 1)] = -y * mu;
        a[(5, c + 2)] = x * mu;
        a[(5, c + 3)] = xi;
        for k in 0..4 {
            a[(6 + c + k, c + k)] = -1.0; // s = (f_n, u, v, t) in the cone
        }
    }
    let mut b = vec![0.0; 6 + n];
    b[0] = 1.0;
    b[1..6].copy_from_slice(&w);
    let p = qp::to_csc(&DMatrix::zeros(n, n), true);
    let cones = [
        ZeroConeT(6),
        SecondOrderConeT(4),
        SecondOrderConeT(4),
        SecondOrderConeT(4),
        SecondOrderConeT(4),
    ];
    let settings = DefaultSettings::<f64> { verbose: false, ..DefaultSettings::default() };
    let mut solver =
        DefaultSolver::new(&p, &vec![0.0; n], &qp::to_csc(&a, false), &b, &cones, settings)
            .expect("the cone program");
    solver.solve();
    match solver.solution.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved => true,
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => false,
        s => panic!("the cone program ended {s:?} on {w:?}"),
    }
}

/// The vertices of a hand's rows at a normal force of 1, with friction margin `fm` and patch
/// margin `pm` (the cross-polytope of the sliding and torsional friction times the rectangle of
/// the centre of pressure: 24), each as the palm wrench `[f_x, f_y, m_x, m_y, m_z]`.
fn hand_vertices(mu: f64, xi: f64, half: [f64; 2], fm: f64, pm: f64) -> Vec<[f64; 5]> {
    let (m, x) = (mu * fm, xi * fm);
    let (px, py) = (half[0] * pm, half[1] * pm);
    let mut out = Vec::new();
    for [f_x, f_y, m_z] in [
        [m, 0.0, 0.0],
        [-m, 0.0, 0.0],
        [0.0, m, 0.0],
        [0.0, -m, 0.0],
        [0.0, 0.0, x],
        [0.0, 0.0, -x],
    ] {
        for (sx, sy) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
            // Normal force 1 along -n at (p_x, p_y): m_x = -p_y, m_y = p_x.
            out.push([f_x, f_y, -sy * py, sx * px, m_z]);
        }
    }
    out
}

/// The hand's rows with the default margins hold only wrenches that the simulated palm can
/// carry: every vertex of their polytope is carried by the palm's four corners with MuJoCo's
/// cones (the set the palm carries is convex, so the vertices are enough). So with margins up
/// to 0.8 (friction) and 0.6 (patch); not at a friction margin of 1 (the torsion about the
/// palm's centre then needs friction the corners no longer have when the centre of pressure is
/// off the centre) nor with the whole patch (all the load on one corner): the "relaxed"
/// capacities are beyond the palm. The paper's separate rows are not carried even at the
/// defaults: tangential force at the pyramid's corner with torsion at its bound, the vertex
/// three robots on the cube sat at when they dropped a 3 kg object.
#[test]
fn every_wrench_the_hand_rows_allow_is_one_the_palm_corners_carry() {
    let fx = common::Fixture::new();
    let d = fx.description(&common::robot_id(0));
    let cfg = PidcConfig::default();
    let (mu, xi, half) = (d.hand_mu, d.hand_xi, d.hand_half_size);
    let (fm, pm) = (cfg.friction_margin, cfg.patch_margin);
    let kind = ContactKind::Hand {
        tx: Vector3::x(),
        ty: Vector3::y(),
        n: Vector3::z(),
        mu: mu * fm,
        xi: xi * fm,
        half: [half[0] * pm, half[1] * pm],
        f_min: 0.0,
    };
    for w in hand_vertices(mu, xi, half, fm, pm) {
        let lambda = [w[0], w[1], -1.0, w[2], w[3], w[4]];
        let broken = broken_rows(&kind, &lambda);
        assert!(
            broken.iter().all(|&r| on_its_bound(&kind, r, &lambda)),
            "vertex {w:?} breaks rows {broken:?}"
        );
        assert!(
            corners_carry(mu, xi, half, w),
            "the rows allow {w:?}, the palm's corners cannot carry it"
        );
    }
    let carried = |fm: f64, pm: f64| {
        hand_vertices(mu, xi, half, fm, pm).into_iter().all(|w| corners_carry(mu, xi, half, w))
    };
    for (fm, pm) in [(0.8, 0.6), (0.5, 0.9), (0.9, 0.25)] {
        assert!(carried(fm, pm), "margins {fm}, {pm}");
    }
    for (fm, pm) in [(1.0, 0.25), (1.0, 1.0), (fm, 1.0)] {
        assert!(!carried(fm, pm), "margins {fm}, {pm}: beyond the palm");
    }
    // The paper's rows allowed this one (|f_x|, |f_y| <= mu' f_n, |m_z| <= xi' f_n); ours do not.
    let (m, x, px, py) = (mu * fm, xi * fm, half[0] * pm, half[1] * pm);
    let corner = [m, m, -py, px, x];
    assert!(!corners_carry(mu, xi, half, corner), "the paper's corner is beyond the palm");
    assert!(!broken_rows(&kind, &[m, m, -1.0, -py, px, x]).is_empty(), "our rows refuse it");
}

/// Row `r` of `kind` holds with equality (to round-off) at `lambda`: a vertex sits on its rows.
fn on_its_bound(kind: &ContactKind, r: usize, lambda: &[f64]) -> bool {
    let rows = contact_rows(kind);
    let (c, lo) = rows.iter().nth(r).expect("row");
    (c.iter().zip(lambda).map(|(a, b)| a * b).sum::<f64>() - lo).abs() < 1e-12
}

/// A random QP input: contacts, `rho` (well conditioned), `eta`, `Y` (n x m, n > m), actuated
/// joints and their limits. `tau0` is filled by [`Problem::place`].
struct Problem {
    contacts: Vec<Contact>,
    kinds: Vec<(usize, ContactKind)>,
    rho: DMatrix<f64>,
    eta: DVector<f64>,
    y: DMatrix<f64>,
    actuated: Vec<usize>,
    limits: Vec<f64>,
    tau0: DVector<f64>,
}

impl Problem {
    fn random(rng: &mut StdRng) -> Self {
        let nf = rng.random_range(1..=4);
        let nh = rng.random_range(0..=2);
        let contacts: Vec<Contact> = (0..nf + nh).map(|k| Contact::random(rng, k >= nf)).collect();
        let mut kinds = Vec::new();
        let mut start = 0;
        for c in &contacts {
            kinds.push((start, c.kind()));
            start += c.dim();
        }
        let m = start;
        let n = m + 6;
        let rho = DMatrix::identity(m, m) * 2.0
            + DMatrix::from_fn(m, m, |_, _| rng.random_range(-0.2..0.2));
        let eta = DVector::from_fn(m, |_, _| rng.random_range(-20.0..20.0));
        let y = DMatrix::from_fn(n, m, |_, _| rng.random_range(-0.5..0.5));
        let actuated: Vec<usize> = (0..n).filter(|_| rng.random_bool(0.75)).collect();
        let limits = actuated.iter().map(|_| rng.random_range(5.0..100.0)).collect();
        let tau0 = DVector::zeros(n);
        Problem { contacts, kinds, rho, eta, y, actuated, limits, tau0 }
    }

    fn input(&self) -> QpInput<'_> {
        QpInput {
            y: &self.y,
            rho: &self.rho,
            eta: &self.eta,
            contacts: &self.kinds,
            actuated: &self.actuated,
            limits: &self.limits,
            tau0: &self.tau0,
            regularisation: 1e-6,
        }
    }

    /// Names of every physical constraint: the contacts', then two per actuated joint.
    fn names(&self) -> Vec<&'static str> {
        let mut names: Vec<&'static str> = self
            .contacts
            .iter()
            .flat_map(|c| c.physics(&[0.0; 6][..c.dim()]).into_iter().map(|(n, _)| n))
            .collect();
        for _ in &self.actuated {
            names.extend(["tau_j <= lim_j", "-tau_j <= lim_j"]);
        }
        names
    }

    /// `F` whose `lambda = rho F + eta` and `tau = tau_0 + Y F` are inside every physical
    /// constraint, or break exactly constraint `violate` (numbered as [`Problem::names`]); sets
    /// `tau_0` to get there.
    fn place(&mut self, rng: &mut StdRng, violate: Option<usize>) -> DVector<f64> {
        let mut lambda = Vec::new();
        let mut first = 0;
        for c in &self.contacts {
            let local = violate.and_then(|v| v.checked_sub(first)).filter(|v| *v < c.count());
            lambda.extend(c.sample(rng, local));
            first += c.count();
        }
        let rhs = DVector::from_vec(lambda) - &self.eta;
        let f = self.rho.clone().lu().solve(&rhs).expect("rho invertible");
        let yf = &self.y * &f;
        self.tau0 = DVector::from_fn(self.y.nrows(), |_, _| rng.random_range(-50.0..50.0));
        for (k, (&j, &lim)) in self.actuated.iter().zip(&self.limits).enumerate() {
            let out = rng.random_range(1.02..1.5);
            let r = match violate.map(|v| v as isize - (first + 2 * k) as isize) {
                Some(0) => out,
                Some(1) => -out,
                _ => rng.random_range(-0.98..0.98),
            };
            self.tau0[j] = r * lim - yf[j];
        }
        f
    }

    /// The physical constraints `F` breaks, stated on `lambda = rho F + eta` (per contact) and
    /// `tau = tau_0 + Y F` (eq. real_torque_limit).
    fn broken_physics(&self, f: &DVector<f64>) -> Vec<usize> {
        let lambda = &self.rho * f + &self.eta;
        let tau = &self.tau0 + &self.y * f;
        let mut slacks = Vec::new();
        for (c, (start, _)) in self.contacts.iter().zip(&self.kinds) {
            slacks.extend(
                c.physics(lambda.rows(*start, c.dim()).as_slice()).into_iter().map(|(_, s)| s),
            );
        }
        for (&j, &lim) in self.actuated.iter().zip(&self.limits) {
            slacks.extend([lim - tau[j], lim + tau[j]]);
        }
        slacks.iter().enumerate().filter(|(_, s)| **s < 0.0).map(|(i, _)| i).collect()
    }
}

#[test]
fn assembled_rows_are_the_physical_constraints_of_lambda_and_tau() {
    let mut rng = StdRng::seed_from_u64(3);
    let (mut a, mut b) = (DMatrix::zeros(0, 0), DVector::zeros(0));
    for case in 0..60 {
        let mut pb = Problem::random(&mut rng);
        let names = pb.names();
        let l = pb.actuated.len();
        let mut map = RowMap::new(names.clone());
        for _ in 0..5 {
            for violate in std::iter::once(None).chain((0..names.len()).map(Some)) {
                let f = pb.place(&mut rng, violate);
                assert_eq!(
                    pb.broken_physics(&f),
                    violate.into_iter().collect::<Vec<_>>(),
                    "sampler"
                );
                constraints_into(&pb.input(), &mut a, &mut b);
                assert_eq!(
                    (a.nrows(), a.ncols(), b.len()),
                    (names.len(), f.len(), names.len()),
                    "one row per physical constraint"
                );
                let r = &a * &f - &b;
                let broken: Vec<usize> =
                    r.iter().enumerate().filter(|(_, v)| **v > 0.0).map(|(i, _)| i).collect();
                match violate {
                    None => assert!(
                        broken.is_empty(),
                        "case {case}: F inside every physical constraint breaks rows {broken:?}"
                    ),
                    Some(v) => map.record(v, &broken, &format!("case {case}")),
                }
                // The dense IPM folds rows (2k, 2k + 1) after the contacts' rows into one:
                // they must be exact negatives.
                let pairs_from = a.nrows() - 2 * l;
                for k in 0..l {
                    let (i, j) = (pairs_from + 2 * k, pairs_from + 2 * k + 1);
                    assert!(
                        (0..a.ncols()).all(|c| a[(j, c)] == -a[(i, c)]),
                        "torque rows {i}, {j} are not (a, -a)"
                    );
                }
            }
        }
        let of = map.assert_bijection(names.len());
        // Contact rows first, in contact order; then each joint's upper and lower limit.
        let nc = names.len() - 2 * l;
        assert!(of[..nc].iter().all(|r| *r < nc));
        for k in 0..l {
            assert_eq!(
                (of[nc + 2 * k], of[nc + 2 * k + 1]),
                (nc + 2 * k, nc + 2 * k + 1),
                "joint {k}: tau <= lim, then -tau <= lim"
            );
        }
    }
}

/// The dense IPM's normal matrix takes one row per `(a, -a)` torque-limit pair with the two
/// weights summed. On random feasible problems (an inside point placed as above; `tau_0` is set
/// for that point, so at the optimum, with a smaller `Y F`, some limits bind) its answer is
/// Clarabel's and the unpaired method's (every row on its own, `pairs_from = rows`).
#[test]
fn paired_torque_rows_in_the_dense_ipm_give_clarabels_solution() {
    // Tolerances on |F - F_ref|_inf / (1 + |F_ref|_inf). Dense IPM vs Clarabel: both stop at
    // relative residuals (1e-7 dense, 1e-8 Clarabel); measured worst 1.2e-6 over these 40
    // problems, bound 1e-5. Paired vs unpaired: the same iteration in exact arithmetic, so
    // only rounding differs; measured 1.7e-12, bound 1e-9.
    const TOL_CLARABEL: f64 = 1e-5;
    const TOL_UNPAIRED: f64 = 1e-9;
    // The dense method may stall at round-off (see the README's open point) and hand the
    // tick to Clarabel: 2 of these 40 problems (measured); at least 36 must converge.
    const MIN_SOLVED: usize = 36;
    let mut rng = StdRng::seed_from_u64(4);
    let mut ws = QpWorkspace::default();
    let clarabel_only = QpSettings::new(50, QpPath::Clarabel);
    let (mut worst_clarabel, mut worst_unpaired, mut binding, mut solved) = (0.0f64, 0.0f64, 0, 0);
    let cases = 40;
    for case in 0..cases {
        let mut pb = Problem::random(&mut rng);
        pb.place(&mut rng, None);
        let mut f_clarabel = DVector::zeros(0);
        let out_c = qp::solve_with(&mut ws, &pb.input(), &clarabel_only, &mut f_clarabel);
        assert_eq!(
            (out_c.solver, out_c.status),
            ("clarabel", protocol::QpStatus::Solved),
            "case {case}: feasible by construction"
        );
        let problem = ws.problem();
        let mut paired = DenseIpm::default();
        let mut f_dense = DVector::zeros(0);
        let out =
            paired.solve_problem(problem, &QpSettings::new(50, QpPath::ByBlocks), &mut f_dense);
        if out.status != protocol::QpStatus::Solved {
            println!(
                "case {case}: dense IPM {:?} after {} iterations (Clarabel finishes such ticks)",
                out.status, out.iterations
            );
            continue;
        }
        solved += 1;
        let scale = 1.0 + f_clarabel.amax();
        worst_clarabel = worst_clarabel.max((&f_dense - &f_clarabel).amax() / scale);
        let mut unpaired = DenseIpm::default();
        let it = unpaired.solve(&problem.p, &problem.a, &problem.b, problem.rows(), 50, DENSE_TOL);
        assert_eq!(
            it,
            Some((out.iterations, false)),
            "case {case}: unpaired takes the same iterations"
        );
        worst_unpaired = worst_unpaired.max((&f_dense - &unpaired.x).amax() / scale);
        let slack = &problem.b - &problem.a * &f_clarabel;
        binding += (problem.pairs_from..problem.rows())
            .filter(|&i| slack[i].abs() < 1e-6 * (1.0 + problem.b[i].abs()))
            .count();
    }
    println!("{solved} of {cases} solved by the dense IPM; relative |F| difference: vs Clarabel {worst_clarabel:.2e}, paired vs unpaired {worst_unpaired:.2e}; binding torque rows {binding}");
    assert!(solved >= MIN_SOLVED, "{solved} of {cases}");
    assert!(binding > 0, "no torque limit bound: the pairing was not exercised");
    assert!(worst_clarabel < TOL_CLARABEL, "dense vs Clarabel {worst_clarabel:.2e}");
    assert!(worst_unpaired < TOL_UNPAIRED, "paired vs unpaired {worst_unpaired:.2e}");
}

/// The least-violation fallback keeps the torque limits and the feet before the hands: a hand
/// that must squeeze 30 N through a joint limited to 10 N m cannot have both. With the default
/// prices the joint keeps its limit (within 1 %) and the squeeze gives way; with equal prices
/// (`hard_row_factor = 1`) the two split the difference. Rows written out here: the squeeze is
/// `-n . f` with `n = e_x`, the torque `tau = F_3`.
#[test]
fn least_violation_gives_up_the_grasp_before_the_joints() {
    let m = 9;
    let rho = DMatrix::<f64>::identity(m, m);
    let eta = DVector::<f64>::zeros(m);
    let mut y = DMatrix::<f64>::zeros(1, m);
    y[(0, 3)] = 1.0;
    let contacts = vec![
        (0, ContactKind::Foot { mu: 0.8, f_min: 5.0, f_max: f64::INFINITY }),
        (
            3,
            ContactKind::Hand {
                tx: Vector3::y(),
                ty: Vector3::z(),
                n: Vector3::x(),
                mu: 0.8,
                xi: 0.05,
                half: [0.05, 0.05],
                f_min: 30.0,
            },
        ),
    ];
    let tau0 = DVector::<f64>::zeros(1);
    let (actuated, limits) = (vec![0usize], vec![10.0]);
    let input = QpInput {
        y: &y,
        rho: &rho,
        eta: &eta,
        contacts: &contacts,
        actuated: &actuated,
        limits: &limits,
        tau0: &tau0,
        regularisation: 1e-6,
    };
    let solve = |hard: f64| {
        let mut ws = QpWorkspace::default();
        let mut f = DVector::zeros(m);
        let settings = QpSettings { hard_row_factor: hard, ..QpSettings::default() };
        qp::solve_least_violation_with(&mut ws, &input, &settings, &mut f)
            .expect("always solvable");
        let squeeze = -f[3];
        let torque = f[3];
        (squeeze, torque, f[2])
    };
    let (squeeze, torque, foot) = solve(qp::HARD_ROW_FACTOR);
    assert!(torque.abs() <= 10.0 * 1.01, "the joint keeps its limit: tau = {torque}");
    assert!(squeeze < 11.0, "the squeeze gives way: {squeeze} N");
    assert!(foot >= 5.0 - 0.05, "the foot keeps its least force: {foot}");
    let (squeeze, torque, _) = solve(1.0);
    assert!(
        (torque.abs() - 20.0).abs() < 0.5 && (squeeze - 20.0).abs() < 0.5,
        "equal prices split: tau {torque}, squeeze {squeeze}"
    );
}

/// A foot being unloaded before its lift-off: one more row, `f_z <= f_max`, written out again
/// here as the physics states it; below `f_min` the ramp wins (the minimum drops to `f_max`).
#[test]
fn an_unloading_foot_has_its_normal_force_bounded_above() {
    let mut rng = StdRng::seed_from_u64(7);
    for _ in 0..500 {
        let (mu, f_min) = (rng.random_range(0.2..1.2), rng.random_range(1.0..30.0));
        let f_max = rng.random_range(0.0..400.0);
        let kind = ContactKind::Foot { mu, f_min, f_max };
        assert_eq!(contact_rows(&kind).len(), 6);
        let physics_ok = |w: &[f64]| {
            w[2] <= f_max
                && w[2] >= f_min.min(f_max)
                && w[0].abs() <= mu * w[2]
                && w[1].abs() <= mu * w[2]
        };
        for _ in 0..20 {
            let f_n = rng.random_range(0.0..500.0);
            let w = [
                rng.random_range(-0.98..0.98) * mu * f_n,
                rng.random_range(-0.98..0.98) * mu * f_n,
                f_n,
            ];
            assert_eq!(
                broken_rows(&kind, &w).is_empty(),
                physics_ok(&w),
                "mu {mu} f_min {f_min} f_max {f_max}: {w:?}"
            );
        }
        // Over the bound alone: exactly the new row.
        let w = [0.0, 0.0, f_max * rng.random_range(1.02..1.5) + 1e-3];
        assert_eq!(broken_rows(&kind, &w), vec![5]);
    }
    // No ramp: the five rows of a foot.
    assert_eq!(
        contact_rows(&ContactKind::Foot { mu: 0.5, f_min: 5.0, f_max: f64::INFINITY }).len(),
        5
    );
}
