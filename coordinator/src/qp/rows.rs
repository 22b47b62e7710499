//! The constraint rows of one contact, `c . lambda_k >= lo` on its wrench `lambda_k` (world-
//! aligned, at the contact frame's origin, acting ON the robot): eqn.
//! unilateral_and_friction_cone_constraint and eqn. moment_constraint.
//!
//! Sign conventions (each in the contact's own frame):
//! * feet: `n = e_z` (world), `f_z >= f_min`, `|f_x|, |f_y| <= mu f_z` (ground pushes up).
//!   Feet and hands have their own `f_min` (a hand's is the squeeze it keeps at least).
//! * hands: `hand_contact` +z `n` is the palm's OUTWARD normal, pointing into the object; the
//!   object pushes the palm back, so the force on the robot has `n . f <= 0`. With the normal
//!   force `f_n = -n . f >= f_min`: sliding and torsional friction together,
//!   `|t_x . f| / mu + |t_y . f| / mu + |n . m| / xi <= f_n` (below), and the tilt moments.
//!
//! **Sliding and torsion share one cone, which DEVIATES from the paper.** Eqns.
//! unilateral_and_friction_cone_constraint and moment_constraint bound the tangential force
//! (`|t_x . f|, |t_y . f| <= mu f_n`) and the torsion (`|n . m| <= xi f_n`) each on its own.
//! A palm cannot give both at once: every point of the patch has one friction cone for its
//! sliding and its torsional friction (MuJoCo's condim-6 contact: `(f_t / mu)^2 + (m_z /
//! xi)^2 <= f_n^2`, elliptic, per contact point), so the paper's corner (tangential force at
//! the pyramid's corner, torsion at its bound) is outside what the palm can carry, and a
//! torque-optimal grasp of three or more hands sits there: three robots on the cube dropped a
//! 3 kg object in MuJoCo (palms turning on it from the first tick) that the static problem
//! with the paper's rows held up to 4.39 kg. The rows here are the cross-polytope with
//! vertices `mu f_n t_x`, `mu f_n t_y`, `xi f_n n` (and their negatives), one row per sign
//! combination, inside each point's elliptic cone (`|a| + |b| + |c| >= |(a, b, c)|`). With
//! the centre of pressure off the palm's centre the tangential force's lever arm adds torsion
//! that the points must carry too, so the margins matter: `tests/qp_rows.rs` checks the
//! vertices against four palm corners with MuJoCo's cones (a second-order cone program each),
//! carried with the default margins and up to 0.8 (friction) and 0.6 (patch), not at a
//! friction margin of 1 or with the whole patch.
//!
//! **Tilt moments: the physical pairing, which DEVIATES from the paper.** The matrix of eqn.
//! moment_constraint pairs `delta_x` with `m_x`. A centre of pressure at `(p_x, p_y)` in the
//! patch carries the normal force `-f_n n` on the palm, whose moment is `m_x = -p_y f_n`,
//! `m_y = p_x f_n`: the moment about `t_x` comes from pressure displaced along `t_y`. The
//! centre of pressure stays in the patch `|p_x| <= delta_x`, `|p_y| <= delta_y` iff
//! `|t_x . m| <= delta_y f_n` and `|t_y . m| <= delta_x f_n`. `tests/qp_rows.rs` checks every
//! row against these statements written out independently.

use nalgebra::Vector3;

/// What a contact's rows need.
#[derive(Debug, Clone, Copy)]
pub enum ContactKind {
    /// Point foot: friction coefficient, minimum normal force, and the upper bound of an
    /// unloading ramp before lift-off (`f64::INFINITY`: none).
    Foot { mu: f64, f_min: f64, f_max: f64 },
    /// Flat hand: frame axes (world), friction, torsional coefficient, patch half-sizes
    /// `[delta_x, delta_y]` (along `tx`, along `ty`), minimum normal force.
    Hand {
        tx: Vector3<f64>,
        ty: Vector3<f64>,
        n: Vector3<f64>,
        mu: f64,
        xi: f64,
        half: [f64; 2],
        f_min: f64,
    },
}

impl ContactKind {
    /// Rows of the contact's wrench in `lambda`: 3 for a foot, 6 for a hand.
    pub fn dim(&self) -> usize {
        match self {
            ContactKind::Foot { .. } => 3,
            ContactKind::Hand { .. } => 6,
        }
    }
}

/// Most constraint rows of one contact (a hand's 13).
pub const MAX_CONTACT_ROWS: usize = 13;

/// The sign combinations `(s_x, s_y, s_z)` of a hand's friction rows, in their order.
pub const FRICTION_SIGNS: [(f64, f64, f64); 8] = [
    (1.0, 1.0, 1.0),
    (-1.0, 1.0, 1.0),
    (1.0, -1.0, 1.0),
    (-1.0, -1.0, 1.0),
    (1.0, 1.0, -1.0),
    (-1.0, 1.0, -1.0),
    (1.0, -1.0, -1.0),
    (-1.0, -1.0, -1.0),
];

/// The rows `c . lambda_k >= lo` of one contact, `c` with [`ContactKind::dim`] entries.
#[derive(Debug, Clone, Copy)]
pub struct ContactRows {
    dim: usize,
    len: usize,
    rows: [([f64; 6], f64); MAX_CONTACT_ROWS],
}

impl ContactRows {
    fn new(dim: usize) -> Self {
        ContactRows { dim, len: 0, rows: [([0.0; 6], 0.0); MAX_CONTACT_ROWS] }
    }

    fn push(&mut self, c: [f64; 6], lo: f64) {
        self.rows[self.len] = (c, lo);
        self.len += 1;
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Each row's `c` (its first `dim` entries) and `lo`.
    pub fn iter(&self) -> impl Iterator<Item = (&[f64], f64)> + '_ {
        self.rows[..self.len].iter().map(move |(c, lo)| (&c[..self.dim], *lo))
    }
}

/// Rows `c . lambda_k >= lo` of one contact (3 or 6 columns): a foot's 5 (friction pyramid,
/// normal force; a 6th, `f_z <= f_max`, while it is being unloaded, with the minimum lowered
/// to `f_max` when the ramp goes below it), a hand's 13 (sliding and torsional friction, one
/// row per sign in [`FRICTION_SIGNS`]' order, normal force, tilt).
pub fn contact_rows(kind: &ContactKind) -> ContactRows {
    let mut rows = ContactRows::new(kind.dim());
    match kind {
        ContactKind::Foot { mu, f_min, f_max } => {
            // eqn. unilateral_and_friction_cone_constraint, n = e_z
            let row = |x: f64, y: f64, z: f64| [x, y, z, 0.0, 0.0, 0.0];
            rows.push(row(-1.0, 0.0, *mu), 0.0);
            rows.push(row(1.0, 0.0, *mu), 0.0);
            rows.push(row(0.0, -1.0, *mu), 0.0);
            rows.push(row(0.0, 1.0, *mu), 0.0);
            rows.push(row(0.0, 0.0, 1.0), f_min.min(*f_max));
            // The unloading ramp before a lift-off (`docs/walking.md`): f_z <= f_max.
            if f_max.is_finite() {
                rows.push(row(0.0, 0.0, -1.0), -*f_max);
            }
        }
        ContactKind::Hand { tx, ty, n, mu, xi, half, f_min } => {
            let row = |f: Vector3<f64>, m: Vector3<f64>| [f.x, f.y, f.z, m.x, m.y, m.z];
            let z = Vector3::zeros();
            // eqns. unilateral_and_friction_cone_constraint and moment_constraint (torsion),
            // in one cone (see the module's docs): s_x t_x.f + s_y t_y.f + s_z (mu / xi) n.m
            // <= mu f_n for every sign combination.
            for (sx, sy, sz) in FRICTION_SIGNS {
                rows.push(row(-*mu * n - sx * tx - sy * ty, -(sz * mu / xi) * n), 0.0);
            }
            rows.push(row(-n, z), *f_min);
            // eqn. moment_constraint, tilt: |t_x.m| <= delta_y f_n, |t_y.m| <= delta_x f_n
            // (physical pairing, see the module's docs)
            rows.push(row(-half[1] * n, -tx), 0.0);
            rows.push(row(-half[1] * n, *tx), 0.0);
            rows.push(row(-half[0] * n, -ty), 0.0);
            rows.push(row(-half[0] * n, *ty), 0.0);
        }
    }
    rows
}
