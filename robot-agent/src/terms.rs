//! The dynamics terms a robot publishes each tick (docs/architecture.md, one tick, step 2),
//! computed from its model: `M`, `h`, and for the frames of its current contact set (stance
//! feet, swing feet, hand, torso) the pose, the world-aligned Jacobian and `Jdot*v`.

use nalgebra::{DVector, Matrix6xX, Vector6};
use protocol::{DynamicsTerms, FrameRole, FrameTerms, Header, Matrix, RobotState};
use thiserror::Error;

use robot_model::{
    compute_all_terms, frame_jacobian, frame_jdot_v, Data, DynamicsError, FrameId, Robot,
};

/// Errors turning a state into terms.
#[derive(Debug, Error)]
pub enum TermsError {
    #[error("state has {got} joint {what}, the robot has {expected} joints")]
    StateSize { what: &'static str, expected: usize, got: usize },
    #[error("the robot has no floating base but the state is for one")]
    Base,
    #[error(transparent)]
    Dynamics(#[from] DynamicsError),
    #[error(transparent)]
    Model(#[from] robot_model::ModelError),
}

/// Which contacts are closed: per foot of the description (same order), stance or not, and
/// whether the hand holds the object. The agent's form of the wire's [`protocol::ContactSet`]
/// (feet by index rather than by frame name).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ActiveContacts {
    pub stance: Vec<bool>,
    pub hand_in_grasp: bool,
}

impl ActiveContacts {
    /// Every foot on the ground, hand in grasp: the paper's manipulation scenarios.
    pub fn all_stance(robot: &Robot) -> Self {
        ActiveContacts { stance: vec![true; robot.foot_frames.len()], hand_in_grasp: true }
    }
}

/// Preallocated workspace that fills [`DynamicsTerms`] from a robot's state.
pub struct TermsBuilder {
    data: Data,
    q: DVector<f64>,
    v: DVector<f64>,
    jac: Matrix6xX<f64>,
    feet: Vec<(String, FrameId, bool)>,
    hand: (String, FrameId),
    torso: (String, FrameId),
}

impl TermsBuilder {
    pub fn new(robot: &Robot) -> Result<Self, TermsError> {
        let m = &robot.model;
        let id = |name: &str| m.frame_id(name).map_err(TermsError::Model);
        let feet = robot
            .foot_frames
            .iter()
            .map(|f| Ok((f.clone(), id(f)?, robot.swing_foot_frames.contains(f))))
            .collect::<Result<Vec<_>, TermsError>>()?;
        Ok(TermsBuilder {
            data: Data::new(m),
            q: DVector::zeros(m.nq),
            v: DVector::zeros(m.nv),
            jac: Matrix6xX::zeros(m.nv),
            feet,
            hand: (robot.hand_frame.clone(), id(&robot.hand_frame)?),
            torso: (robot.torso_frame.clone(), id(&robot.torso_frame)?),
        })
    }

    /// The model's `(q, v)` for a protocol state (joint vectors in velocity order).
    pub fn load_state(&mut self, robot: &Robot, state: &RobotState) -> Result<(), TermsError> {
        let m = &robot.model;
        let nj = m.joint_names.len();
        if state.joint_positions.len() != nj {
            return Err(TermsError::StateSize {
                what: "positions",
                expected: nj,
                got: state.joint_positions.len(),
            });
        }
        if state.joint_velocities.len() != nj {
            return Err(TermsError::StateSize {
                what: "velocities",
                expected: nj,
                got: state.joint_velocities.len(),
            });
        }
        if m.floating_base {
            self.q.as_mut_slice()[0..3].copy_from_slice(&state.base_pose.position);
            self.q.as_mut_slice()[3..7].copy_from_slice(&state.base_pose.orientation);
            self.q.as_mut_slice()[7..].copy_from_slice(&state.joint_positions);
            self.v.as_mut_slice()[0..6].copy_from_slice(&state.base_twist);
            self.v.as_mut_slice()[6..].copy_from_slice(&state.joint_velocities);
        } else {
            self.q.as_mut_slice().copy_from_slice(&state.joint_positions);
            self.v.as_mut_slice().copy_from_slice(&state.joint_velocities);
        }
        Ok(())
    }

    /// The configuration and velocity last loaded.
    pub fn q_v(&self) -> (&DVector<f64>, &DVector<f64>) {
        (&self.q, &self.v)
    }

    /// Compute the terms at the loaded state into `out` (reusing its allocations).
    pub fn compute(
        &mut self,
        robot: &Robot,
        contacts: &ActiveContacts,
        out: &mut DynamicsTerms,
    ) -> Result<(), TermsError> {
        let m = &robot.model;
        compute_all_terms(m, &mut self.data, self.q.as_slice(), self.v.as_slice())?;
        let nv = m.nv;
        out.floating_base = m.floating_base;
        out.nv = nv as u32;
        out.mass_matrix.copy_from_dmatrix(&self.data.m);
        out.bias.clear();
        out.bias.extend_from_slice(self.data.h.as_slice());
        out.velocity.clear();
        out.velocity.extend_from_slice(self.v.as_slice());
        out.hand_in_grasp = contacts.hand_in_grasp;
        let mut used = 0;
        for (k, (name, id, can_swing)) in self.feet.iter().enumerate() {
            let role = if contacts.stance.get(k).copied().unwrap_or(true) {
                FrameRole::StanceFoot
            } else if *can_swing {
                FrameRole::SwingFoot
            } else {
                continue;
            };
            // A stance foot is a rolling sphere: its contact point, `radius` below the centre,
            // is what stays on the ground; a swing foot is tracked at its centre.
            let below = if role == FrameRole::StanceFoot { robot.feet.radius } else { 0.0 };
            fill_frame(m, &self.data, &mut self.jac, name, *id, role, below, out, used)?;
            used += 1;
        }
        // Borrowed field by field: the frame names are not copied (the tick allocates nothing).
        let (data, jac, hand, torso) = (&self.data, &mut self.jac, &self.hand, &self.torso);
        fill_frame(m, data, jac, &hand.0, hand.1, FrameRole::Hand, 0.0, out, used)?;
        fill_frame(m, data, jac, &torso.0, torso.1, FrameRole::Torso, 0.0, out, used + 1)?;
        out.frames.truncate(used + 2);
        Ok(())
    }

    /// Mass matrix, bias and gravity of the last computation.
    pub fn data(&self) -> &Data {
        &self.data
    }
}

/// Fill frame `slot` of `out`. `below > 0` (stance feet): the point `below` metres under the
/// frame origin along world z instead of the origin, the contact point of a foot sphere of that
/// radius on flat ground: `p_c = p - r e_z`, `v_c = v + omega x (-r e_z) = v + r e_z x omega`,
/// so `J_c = J_v + r [e_z]x J_omega` and `Jdot_c v = Jdot_v v + r e_z x (Jdot_omega v)`
/// (`r e_z` is constant in the world). Constraining the sphere's centre instead forbids the
/// rolling the simulator (and the real foot) allows: the team then settles off its torso
/// reference (5 mm with the paper's gains) while the controller believes the feet hold still.
#[allow(clippy::too_many_arguments)]
fn fill_frame(
    m: &robot_model::Model,
    data: &Data,
    jac: &mut Matrix6xX<f64>,
    name: &str,
    id: FrameId,
    role: FrameRole,
    below: f64,
    out: &mut DynamicsTerms,
    slot: usize,
) -> Result<(), TermsError> {
    frame_jacobian(m, data, id, jac)?;
    let mut jdv = frame_jdot_v(m, data, id)?;
    if below != 0.0 {
        shift_to_contact_point(jac, &mut jdv, below, m.nv);
    }
    let pose = &data.o_m_f[id];
    let rows = role.dim();
    if out.frames.len() <= slot {
        out.frames.push(empty_frame_terms(role, rows, m.nv));
    }
    let f = &mut out.frames[slot];
    if f.name != name {
        f.name.clear();
        f.name.push_str(name);
    }
    f.role = role;
    f.position = [pose.trans.x, pose.trans.y, pose.trans.z - below];
    for i in 0..3 {
        for j in 0..3 {
            f.rotation[3 * i + j] = pose.rot[(i, j)];
        }
    }
    copy_jacobian_rows(f, jac, &jdv, rows, m.nv);
    Ok(())
}

/// Move the frame's velocity terms from its origin to the point `below` metres under it along
/// world z: `J_c = J_v + r [e_z]x J_omega`, `Jdot_c v = Jdot_v v + r e_z x (Jdot_omega v)`.
fn shift_to_contact_point(jac: &mut Matrix6xX<f64>, jdv: &mut Vector6<f64>, below: f64, nv: usize) {
    // e_z x w = (-w_y, w_x, 0) for the angular rows 3..6.
    for j in 0..nv {
        let (wx, wy) = (jac[(3, j)], jac[(4, j)]);
        jac[(0, j)] -= below * wy;
        jac[(1, j)] += below * wx;
    }
    let (ax, ay) = (jdv[3], jdv[4]);
    jdv[0] -= below * ay;
    jdv[1] += below * ax;
}

/// A frame's terms with room for `rows` rows of `nv` columns, zero.
fn empty_frame_terms(role: FrameRole, rows: usize, nv: usize) -> FrameTerms {
    FrameTerms {
        name: String::new(),
        role,
        position: [0.0; 3],
        rotation: [0.0; 9],
        jacobian: Matrix::zeros(rows, nv),
        jdot_v: vec![0.0; rows],
    }
}

/// The first `rows` rows of the Jacobian `jac` and of `Jdot*v` into `f` (row-major).
fn copy_jacobian_rows(
    f: &mut FrameTerms,
    jac: &Matrix6xX<f64>,
    jdv: &Vector6<f64>,
    rows: usize,
    nv: usize,
) {
    f.jacobian.rows = rows as u32;
    f.jacobian.cols = nv as u32;
    f.jacobian.data.resize(rows * nv, 0.0);
    for i in 0..rows {
        for j in 0..nv {
            f.jacobian.data[i * nv + j] = jac[(i, j)];
        }
    }
    f.jdot_v.resize(rows, 0.0);
    f.jdot_v.copy_from_slice(&jdv.as_slice()[..rows]);
}

/// An empty terms message for robot `id` of team `team`, to be filled by [`TermsBuilder`].
pub fn empty_terms(team: &str, id: &str) -> DynamicsTerms {
    DynamicsTerms {
        header: Header::new(team, Some(id), 0, 0),
        floating_base: true,
        nv: 0,
        mass_matrix: Matrix::zeros(0, 0),
        bias: Vec::new(),
        velocity: Vec::new(),
        frames: Vec::new(),
        hand_in_grasp: false,
        state_tick: 0,
        team_delay_ticks: 0,
        object_pose: None,
    }
}
