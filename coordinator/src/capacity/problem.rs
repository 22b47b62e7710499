//! The static team problem's rows: equalities `E lambda = e0 + m e1` (robots' base rows, the
//! object's wrench balance), limit rows `A lambda <= b` each with its name
//! ([`super::limits::LimitRow`]), and
//! the objective (the torques relative to their limits, least squares).

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, Isometry3, Vector3, Vector6};
use protocol::conventions::GRAVITY_VECTOR;
use protocol::{DynamicsTerms, RobotDescription};

use super::limits::{Limit, LimitRow, Place};
use super::report::CapacityError;
use crate::building_blocks::contact_margins::ContactMargins;
use crate::building_blocks::contacts::contact_list;
use crate::building_blocks::grasp::GraspTerms;
use crate::building_blocks::limits::torque_limits;
use crate::qp::{contact_rows, ContactKind, FRICTION_SIGNS};
use crate::team::Team;

/// Largest joint speed taken as rest, rad/s or m/s: the terms' `h` is then `g(q)`.
pub const REST_SPEED: f64 = 1e-9;

/// Weight of the least-squares regularisation of `lambda` in the objective, per N^2.
const LAMBDA_REGULARISATION: f64 = 1e-9;

/// The names of [`contact_rows`]' rows, in its order.
fn contact_limits(kind: &ContactKind) -> Vec<Limit> {
    let fr = |axis, positive| Limit::Friction { axis, positive };
    match kind {
        ContactKind::Foot { f_min, .. } => vec![
            fr('x', true),
            fr('x', false),
            fr('y', true),
            fr('y', false),
            Limit::MinNormal { f_min: *f_min },
        ],
        ContactKind::Hand { f_min, .. } => {
            let cop = |axis, positive| Limit::CentreOfPressure { axis, positive };
            let mut names: Vec<Limit> = FRICTION_SIGNS
                .iter()
                .map(|&(x, y, z)| Limit::FrictionAndTorsion {
                    x: x > 0.0,
                    y: y > 0.0,
                    torsion: z > 0.0,
                })
                .collect();
            names.extend([
                Limit::MinNormal { f_min: *f_min },
                // The tilt moments (rows.rs): m_x = -p_y f_n, m_y = p_x f_n, so the row
                // `t_x . m <= delta_y f_n` keeps p_y >= -delta_y, `t_y . m <= delta_x f_n`
                // p_x <= delta_x.
                cop('y', false),
                cop('y', true),
                cop('x', true),
                cop('x', false),
            ]);
            names
        }
    }
}

/// The static problem of a team at rest, for any object mass.
#[derive(Debug, Clone)]
pub struct StaticProblem {
    /// The team at the pose (`bias` = `g(q)`).
    pub team: Team,
    pub object_centre: Vector3<f64>,
    /// `E lambda = e0 + m e1`: 6 rows per floating base, then the object's 6.
    pub e: DMatrix<f64>,
    pub e0: DVector<f64>,
    pub e1: DVector<f64>,
    /// Limit rows `A lambda <= b`: every contact's, then two per actuated joint.
    pub a: DMatrix<f64>,
    pub b: DVector<f64>,
    pub rows: Vec<LimitRow>,
    /// Objective `1/2 lambda^T P lambda + q^T lambda`.
    pub p: DMatrix<f64>,
    pub q: DVector<f64>,
    /// `J_c = [J_cf; J_ee]` (m x n), the actuated joints (team indices) and their limits.
    pub j_c: DMatrix<f64>,
    pub actuated: Vec<usize>,
    pub limits: Vec<f64>,
}

impl StaticProblem {
    /// Build from one tick's terms of the team at rest, the robots' descriptions and the
    /// controller's contact parameters (margins, minimum forces, e.g.
    /// `PidcConfig::contact_margins`), the object's centre at `centre`.
    pub fn build(
        terms: &[DynamicsTerms],
        descriptions: &[RobotDescription],
        margins: &ContactMargins,
        centre: Vector3<f64>,
    ) -> Result<Self, CapacityError> {
        if centre.iter().any(|x| !x.is_finite()) {
            return Err(CapacityError::Input(format!("object centre {centre:?} must be finite")));
        }
        margins.check()?;
        let mut team = Team::default();
        team.assemble_into(terms, None, false)?;
        if let Some(t) = terms.iter().find(|t| t.velocity.iter().any(|v| v.abs() > REST_SPEED)) {
            return Err(CapacityError::NotAtRest { robot: t.header.robot_id().to_string() });
        }
        if team.hands.is_empty() {
            return Err(CapacityError::NoHands);
        }
        let descs: BTreeMap<String, RobotDescription> =
            descriptions.iter().map(|d| (d.header.robot_id().to_string(), d.clone())).collect();
        let (mut actuated, mut limits, mut contacts) = (Vec::new(), Vec::new(), Vec::new());
        torque_limits(&team, &descs, false, &mut actuated, &mut limits)?;
        contact_list(&team, &descs, margins, &mut contacts)?;
        let mut j_c = DMatrix::zeros(team.contact_rows(), team.n);
        j_c.rows_mut(0, team.j_cf.nrows()).copy_from(&team.j_cf);
        j_c.rows_mut(team.j_cf.nrows(), team.j_ee.nrows()).copy_from(&team.j_ee);
        let (e, e0, e1) = equalities(&team, &j_c, &centre)?;
        let (a, b, rows) = limit_rows(&team, &j_c, &contacts, &actuated, &limits, &descs);
        let (p, q) = objective(&team, &j_c, &actuated, &limits);
        Ok(StaticProblem {
            team,
            object_centre: centre,
            e,
            e0,
            e1,
            a,
            b,
            rows,
            p,
            q,
            j_c,
            actuated,
            limits,
        })
    }

    /// The object moving through the pose: its six rows of `E lambda = e0 + m e1` become the
    /// Newton-Euler equations of the object, `G lambda_hands = m [g - a; -(I alpha + omega x I
    /// omega)]`, with `acceleration = [a; alpha]` (world), `omega` its angular velocity and
    /// `unit_inertia` its inertia per kilogram about its centre (world-aligned; a uniform body's
    /// inertia scales with its mass, so the rows stay linear in `m`). At rest these are the
    /// static rows.
    pub fn with_object_motion(
        mut self,
        acceleration: &Vector6<f64>,
        omega: &Vector3<f64>,
        unit_inertia: &nalgebra::Matrix3<f64>,
    ) -> Self {
        let first = self.e.nrows() - 6;
        let a = acceleration.fixed_rows::<3>(0);
        let alpha = acceleration.fixed_rows::<3>(3);
        let moment = unit_inertia * alpha + omega.cross(&(unit_inertia * omega));
        for k in 0..3 {
            self.e1[first + k] = GRAVITY_VECTOR[k] - a[k];
            self.e1[first + 3 + k] = -moment[k];
        }
        self
    }

    /// Number of unknowns (`lambda`'s rows).
    pub fn unknowns(&self) -> usize {
        self.j_c.nrows()
    }

    /// Each hand's wrench in `lambda` (`[force; moment]`, world-aligned, acting on the robot,
    /// about the hand frame's origin): `(robot id, that origin, wrench)`, in team order.
    pub fn hand_wrenches(
        &self,
        lambda: &DVector<f64>,
    ) -> Vec<(String, Vector3<f64>, Vector6<f64>)> {
        let first = 3 * self.team.feet.len();
        self.team
            .hands
            .iter()
            .enumerate()
            .filter(|(h, _)| first + 6 * h + 6 <= lambda.len())
            .map(|(h, f)| {
                (
                    self.team.robots[f.robot].id.clone(),
                    f.position,
                    lambda.fixed_rows::<6>(first + 6 * h).into_owned(),
                )
            })
            .collect()
    }

    /// The actuated joints' torques `tau = g_a - J_c,a^T lambda`.
    pub fn torques(&self, lambda: &DVector<f64>) -> DVector<f64> {
        let jt = self.j_c.tr_mul(lambda);
        DVector::from_iterator(
            self.actuated.len(),
            self.actuated.iter().map(|&j| self.team.bias[j] - jt[j]),
        )
    }
}

/// `(E, e0, e1)` of `E lambda = e0 + m e1`.
type Equalities = (DMatrix<f64>, DVector<f64>, DVector<f64>);

/// `E lambda = e0 + m e1`: each floating base's 6 rows `(J_c^T lambda)_u = g_u` (eq.
/// js_dynamics at rest), then the object's `G lambda_hands = m [g_vec; 0]` (eq. graspmatrix).
fn equalities(
    team: &Team,
    j_c: &DMatrix<f64>,
    centre: &Vector3<f64>,
) -> Result<Equalities, CapacityError> {
    let bases: Vec<usize> = team
        .robots
        .iter()
        .filter(|r| r.floating_base)
        .flat_map(|r| r.offset..r.offset + 6)
        .collect();
    let m = j_c.nrows();
    let rows = bases.len() + 6;
    let (mut e, mut e0, mut e1) =
        (DMatrix::zeros(rows, m), DVector::zeros(rows), DVector::zeros(rows));
    for (i, &u) in bases.iter().enumerate() {
        e.row_mut(i).copy_from(&j_c.column(u).transpose());
        e0[i] = team.bias[u];
    }
    let mut grasp = GraspTerms::default();
    grasp
        .compute_into(team, Isometry3::translation(centre.x, centre.y, centre.z))
        .ok_or(CapacityError::Input("singular grasp matrix".into()))?;
    let first_hand = 3 * team.feet.len();
    e.view_mut((bases.len(), first_hand), (6, grasp.g.ncols())).copy_from(&grasp.g);
    for k in 0..3 {
        e1[bases.len() + k] = GRAVITY_VECTOR[k];
    }
    Ok((e, e0, e1))
}

/// The limit rows `A lambda <= b` with their names: each contact's rows `c . lambda_k >= lo`
/// as `-c . lambda_k <= -lo`, then per actuated joint `tau <= max` and `-tau <= max` with
/// `tau = g_j - (J_c^T lambda)_j` (eq. original_torque_limit).
fn limit_rows(
    team: &Team,
    j_c: &DMatrix<f64>,
    contacts: &[(usize, ContactKind)],
    actuated: &[usize],
    limits: &[f64],
    descs: &BTreeMap<String, RobotDescription>,
) -> (DMatrix<f64>, DVector<f64>, Vec<LimitRow>) {
    let frame = |start: usize| {
        let nf3 = 3 * team.feet.len();
        let f = if start < nf3 { &team.feet[start / 3] } else { &team.hands[(start - nf3) / 6] };
        (team.robots[f.robot].id.clone(), f.name.clone())
    };
    let nc: usize = contacts.iter().map(|(_, k)| contact_rows(k).len()).sum();
    let m = j_c.nrows();
    let (mut a, mut b) =
        (DMatrix::zeros(nc + 2 * actuated.len(), m), DVector::zeros(nc + 2 * actuated.len()));
    let mut rows = Vec::with_capacity(a.nrows());
    for (start, kind) in contacts {
        let (robot, name) = frame(*start);
        for ((c, lo), limit) in contact_rows(kind).iter().zip(contact_limits(kind)) {
            let i = rows.len();
            for (r, cr) in c.iter().enumerate() {
                a[(i, start + r)] = -cr;
            }
            b[i] = -lo;
            rows.push(LimitRow {
                robot: robot.clone(),
                place: Place::Contact(name.clone()),
                limit,
            });
        }
    }
    for (&j, &max) in actuated.iter().zip(limits) {
        let (robot, joint) = actuated_joint(team, descs, j);
        for upper in [true, false] {
            // tau = g_j - a_j . lambda: tau <= max <=> -a_j . lambda <= max - g_j.
            let s = if upper { -1.0 } else { 1.0 };
            let i = rows.len();
            a.row_mut(i).copy_from(&(s * j_c.column(j).transpose()));
            b[i] = max + s * team.bias[j];
            rows.push(LimitRow {
                robot: robot.to_string(),
                place: Place::Joint(joint.clone()),
                limit: Limit::Torque { upper, max },
            });
        }
    }
    (a, b, rows)
}

/// The robot of the team's actuated joint `j` and the joint's name (from the robot's
/// description, else `joint {j}`).
fn actuated_joint<'a>(
    team: &'a Team,
    descs: &BTreeMap<String, RobotDescription>,
    j: usize,
) -> (&'a str, String) {
    let rb = team
        .robots
        .iter()
        .find(|r| r.offset <= j && j < r.offset + r.nv)
        .expect("an actuated joint belongs to a robot");
    let joint = descs
        .get(&rb.id)
        .and_then(|d| d.joint_names.get(rb.actuated.iter().position(|&x| x == j)?))
        .cloned()
        .unwrap_or_else(|| format!("joint {j}"));
    (&rb.id, joint)
}

/// `min sum_j (tau_j / max_j)^2 + eps |lambda|^2` as `1/2 lambda^T P lambda + q^T lambda`:
/// the torques the team needs, each relative to its limit, least squares.
fn objective(
    team: &Team,
    j_c: &DMatrix<f64>,
    actuated: &[usize],
    limits: &[f64],
) -> (DMatrix<f64>, DVector<f64>) {
    let m = j_c.nrows();
    let mut p = DMatrix::identity(m, m) * (2.0 * LAMBDA_REGULARISATION);
    let mut q = DVector::zeros(m);
    for (&j, &max) in actuated.iter().zip(limits) {
        let aj = j_c.column(j);
        let w = 1.0 / (max * max);
        p.ger(2.0 * w, &aj, &aj, 1.0);
        q.axpy(-2.0 * w * team.bias[j], &aj, 1.0);
    }
    (p, q)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn every_contact_row_has_a_name() {
        let foot = ContactKind::Foot { mu: 0.5, f_min: 5.0, f_max: f64::INFINITY };
        let hand = ContactKind::Hand {
            tx: Vector3::x(),
            ty: Vector3::y(),
            n: Vector3::z(),
            mu: 0.5,
            xi: 0.03,
            half: [0.05, 0.04],
            f_min: 30.0,
        };
        for k in [foot, hand] {
            assert_eq!(contact_rows(&k).len(), contact_limits(&k).len());
        }
    }
}
