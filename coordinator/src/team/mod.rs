//! Assembly of the team matrices (paper §III-A) from one tick's dynamics terms, sorted by
//! robot id: block-diagonal `M`, stacked `h` and `v`, the selection `S`, the stance-foot
//! Jacobian `J_cf`, the hand Jacobian `J_ee`, the `Jdot*v` stacks, task frames, index maps.
//!
//! Any number of robots and stance feet; the contact set may change from tick to tick (the
//! assembly is redone every tick). [`Team::assemble_into`] writes into the buffers of the
//! previous tick's team: it allocates only when the team's shape (robots, frames, contact
//! set) changes.
//!
//! Who is in the team ([`membership`]) and the gathering of one tick's terms from every member
//! ([`assembly`]) live beside it.

pub mod assembly;
pub mod membership;
pub mod prediction;

use nalgebra::{
    DMatrix, DVector, Isometry3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3,
    Vector6,
};
use protocol::{DynamicsTerms, FrameRole, FrameTerms, RobotDescription};

use protocol::conventions::rotation_from_row_major;

use crate::linalg::{zeros, zeros_v};
use crate::ControllerError;

/// One robot's block in the team vectors.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotBlock {
    pub id: String,
    /// First team velocity index of the robot and its `nv`.
    pub offset: usize,
    pub nv: usize,
    /// Team velocity indices of its actuated joints (velocity order).
    pub actuated: Vec<usize>,
    pub floating_base: bool,
}

/// A frame used as a task or a contact.
#[derive(Debug, Clone, Default)]
pub struct TeamFrame {
    pub robot: usize,
    pub name: String,
    pub position: Vector3<f64>,
    pub rotation: Rotation3<f64>,
    /// `dim x n` team Jacobian (world-aligned, rows `[linear; angular]`).
    pub jacobian: DMatrix<f64>,
    /// Its robot's team columns (first, count): `jacobian` is zero outside them.
    pub cols: (usize, usize),
    pub jdot_v: DVector<f64>,
}

impl TeamFrame {
    /// `J v`, the frame's velocity (world-aligned `[linear; angular]`; a point frame's 3 rows
    /// first, the rest zero), by its robot's columns of the team velocity `v`.
    pub fn velocity(&self, v: &DVector<f64>) -> Vector6<f64> {
        let (c0, nc) = self.cols;
        let mut out = Vector6::zeros();
        out.rows_mut(0, self.jacobian.nrows()).gemv(
            1.0,
            &self.jacobian.columns(c0, nc),
            &v.rows(c0, nc),
            0.0,
        );
        out
    }
}

/// The object's pose from the measurements of the robots whose hand is in grasp: the mean of
/// their positions and of their orientations (quaternions turned to the first one's
/// hemisphere, summed and normalised: the chordal mean, exact for equal measurements).
pub fn measured_object(tick: &[DynamicsTerms]) -> Option<Isometry3<f64>> {
    let mut seen = tick.iter().filter(|t| t.hand_in_grasp).filter_map(|t| t.object_pose);
    let first = seen.next()?;
    let q0 = Quaternion::from(nalgebra::Vector4::from(wxyz_as_xyzw(first.orientation)));
    let (mut p, mut q, mut count) = (Vector3::from(first.position), q0, 1.0);
    for m in seen {
        let qi = Quaternion::from(nalgebra::Vector4::from(wxyz_as_xyzw(m.orientation)));
        q += if qi.dot(&q0) < 0.0 { -qi } else { qi };
        p += Vector3::from(m.position);
        count += 1.0;
    }
    Some(Isometry3::from_parts(Translation3::from(p / count), UnitQuaternion::from_quaternion(q)))
}

/// `(w, x, y, z)` as nalgebra's quaternion storage order `(x, y, z, w)`.
fn wxyz_as_xyzw(q: [f64; 4]) -> [f64; 4] {
    [q[1], q[2], q[3], q[0]]
}

/// The team of one tick.
#[derive(Debug, Clone, Default)]
pub struct Team {
    pub robots: Vec<RobotBlock>,
    /// Team velocity dimension.
    pub n: usize,
    pub mass: DMatrix<f64>,
    pub bias: DVector<f64>,
    pub velocity: DVector<f64>,
    /// Diagonal of the selection matrix `S` (eq. js_dynamics): 0 on floating-base rows.
    pub s_diag: DVector<f64>,
    /// Stance feet (3 rows each) and hands in grasp (6 rows each), in robot order.
    pub feet: Vec<TeamFrame>,
    pub hands: Vec<TeamFrame>,
    /// Hands not in grasp (their robot's contact set says so, or the controller let go of the
    /// object: [`Team::hands_released`]): tasks, not contacts.
    pub free_hands: Vec<TeamFrame>,
    /// Whether the controller has let go of the object: [`Team::assemble_into`] then treats
    /// every hand as free, whatever the contact sets say.
    pub hands_released: bool,
    /// The held object's pose as the robots with a hand in grasp measured it this tick (their
    /// mean, [`measured_object`]); `None` when none of them measures it.
    pub object_measured: Option<Isometry3<f64>>,
    pub torsos: Vec<TeamFrame>,
    pub swing_feet: Vec<TeamFrame>,
    /// `J_cf` (3 nf x n) and its `Jdot*v`; `J_ee` (6 B x n) and its `Jdot*v`.
    pub j_cf: DMatrix<f64>,
    pub jdv_cf: DVector<f64>,
    pub j_ee: DMatrix<f64>,
    pub jdv_ee: DVector<f64>,
    /// The columns each row block of `j_cf` and `j_ee` was written on ([`stack`]).
    cf_cols: Vec<(usize, usize)>,
    ee_cols: Vec<(usize, usize)>,
}

/// How many frames of each role the robots assembled so far have.
#[derive(Default)]
struct FrameCounts {
    feet: usize,
    hands: usize,
    free_hands: usize,
    torsos: usize,
    swing: usize,
}

/// A tick is usable: not empty, the `expected` robots exactly (when given), every robot's
/// terms well-formed.
fn check_tick(tick: &[DynamicsTerms], expected: Option<&[String]>) -> Result<(), ControllerError> {
    if tick.is_empty() {
        return Err(ControllerError::Dimension {
            what: "tick".into(),
            detail: "no robot in the tick".into(),
        });
    }
    if let Some(exp) = expected {
        for id in exp {
            if !tick.iter().any(|t| t.header.robot_id() == id) {
                return Err(ControllerError::MissingRobot { robot: id.clone() });
            }
        }
        for t in tick {
            if !exp.iter().any(|e| e == t.header.robot_id()) {
                return Err(ControllerError::UnknownRobot {
                    robot: t.header.robot_id().to_string(),
                });
            }
        }
    }
    for t in tick {
        check_terms(t)?;
    }
    Ok(())
}

impl Team {
    /// Assemble from one tick's terms, into this team's buffers (the previous tick's).
    /// `expected` (sorted ids), when given, must match the robots of the tick.
    /// `fully_actuated` sets `S = I` (the \[Lin2018\] comparison). Every check runs before
    /// anything is written: on an error the team is unchanged.
    pub fn assemble_into(
        &mut self,
        tick: &[DynamicsTerms],
        expected: Option<&[String]>,
        fully_actuated: bool,
    ) -> Result<(), ControllerError> {
        check_tick(tick, expected)?;
        let n: usize = tick.iter().map(|t| t.nv()).sum();
        self.n = n;
        // M is written by its robots' blocks: the zeros between them are the last tick's
        // when the robots' sizes are.
        let same_blocks = self.mass.shape() == (n, n)
            && self.robots.len() == tick.len()
            && self.robots.iter().zip(tick).all(|(r, t)| r.nv == t.nv());
        if !same_blocks {
            zeros(&mut self.mass, n, n);
        }
        zeros_v(&mut self.bias, n);
        zeros_v(&mut self.velocity, n);
        zeros_v(&mut self.s_diag, n);
        self.s_diag.fill(1.0);
        self.robots.truncate(tick.len());
        let mut counts = FrameCounts::default();
        let mut off = 0;
        for (k, t) in tick.iter().enumerate() {
            self.robot_into(k, t, off, fully_actuated, &mut counts);
            off += t.nv();
        }
        self.feet.truncate(counts.feet);
        self.hands.truncate(counts.hands);
        self.free_hands.truncate(counts.free_hands);
        self.torsos.truncate(counts.torsos);
        self.swing_feet.truncate(counts.swing);
        stack(&self.feet, 3, n, &mut self.j_cf, &mut self.jdv_cf, &mut self.cf_cols);
        stack(&self.hands, 6, n, &mut self.j_ee, &mut self.jdv_ee, &mut self.ee_cols);
        self.object_measured = measured_object(tick);
        Ok(())
    }

    /// Robot `k`'s terms `t` into the team's buffers at columns `off..`: its block of `M`, its
    /// `h`, `v` and `S`, its [`RobotBlock`] and its frames (counted in `counts`).
    fn robot_into(
        &mut self,
        k: usize,
        t: &DynamicsTerms,
        off: usize,
        fully_actuated: bool,
        counts: &mut FrameCounts,
    ) {
        let n = self.n;
        let nv = t.nv();
        for j in 0..nv {
            for i in 0..nv {
                self.mass[(off + i, off + j)] = t.mass_matrix.data[i * nv + j];
            }
        }
        self.bias.rows_mut(off, nv).copy_from_slice(&t.bias);
        self.velocity.rows_mut(off, nv).copy_from_slice(&t.velocity);
        let base = if t.floating_base { 6 } else { 0 };
        if !fully_actuated {
            self.s_diag.rows_mut(off, base).fill(0.0);
        }
        if k == self.robots.len() {
            self.robots.push(RobotBlock {
                id: String::new(),
                offset: 0,
                nv: 0,
                actuated: Vec::new(),
                floating_base: false,
            });
        }
        let rb = &mut self.robots[k];
        if rb.id != t.header.robot_id() {
            rb.id.clear();
            rb.id.push_str(t.header.robot_id());
        }
        rb.offset = off;
        rb.nv = nv;
        rb.actuated.clear();
        rb.actuated.extend(off + base..off + nv);
        rb.floating_base = t.floating_base;
        for f in &t.frames {
            let (list, count) = match f.role {
                FrameRole::StanceFoot => (&mut self.feet, &mut counts.feet),
                FrameRole::SwingFoot => (&mut self.swing_feet, &mut counts.swing),
                FrameRole::Hand if t.hand_in_grasp && !self.hands_released => {
                    (&mut self.hands, &mut counts.hands)
                }
                FrameRole::Hand => (&mut self.free_hands, &mut counts.free_hands),
                FrameRole::Torso => (&mut self.torsos, &mut counts.torsos),
            };
            if *count == list.len() {
                list.push(TeamFrame::default());
            }
            team_frame_into(&mut list[*count], k, f, off, n);
            *count += 1;
        }
    }

    /// Rows of `J_c`: 3 per stance foot, 6 per hand in grasp (eq. jacobian_c).
    pub fn contact_rows(&self) -> usize {
        3 * self.feet.len() + 6 * self.hands.len()
    }

    /// Number of actuated joints of the team.
    pub fn actuated(&self) -> usize {
        self.robots.iter().map(|r| r.actuated.len()).sum()
    }
}

/// Whether a robot's terms fit what the team can use: consistent in themselves
/// ([`check_terms`]) and, once its description arrived, the size and base it describes.
pub fn terms_fit(
    t: &DynamicsTerms,
    description: Option<&RobotDescription>,
) -> Result<(), ControllerError> {
    check_terms(t)?;
    let Some(d) = description else { return Ok(()) };
    let robot = t.header.robot_id();
    if t.nv() != d.nv as usize
        || t.floating_base != d.floating_base
        || t.actuated() != d.joint_names.len()
    {
        let detail = format!(
            "nv {} ({} actuated, floating base {}) against the description's nv {} ({} joints, \
             floating base {})",
            t.nv(),
            t.actuated(),
            t.floating_base,
            d.nv,
            d.joint_names.len(),
            d.floating_base
        );
        return Err(ControllerError::Dimension { what: format!("{robot}: terms"), detail });
    }
    Ok(())
}

fn check_terms(t: &DynamicsTerms) -> Result<(), ControllerError> {
    let robot = t.header.robot_id();
    let nv = t.nv();
    let dim = |what: &str, detail: String| ControllerError::Dimension {
        what: format!("{robot}: {what}"),
        detail,
    };
    if nv == 0 || (t.floating_base && nv <= 6) {
        return Err(dim("nv", format!("{nv} leaves no actuated joint")));
    }
    if t.mass_matrix.rows() != nv
        || t.mass_matrix.cols() != nv
        || t.mass_matrix.data.len() != nv * nv
    {
        return Err(dim(
            "mass_matrix",
            format!("{}x{} for nv {nv}", t.mass_matrix.rows(), t.mass_matrix.cols()),
        ));
    }
    if t.bias.len() != nv || t.velocity.len() != nv {
        return Err(dim(
            "bias/velocity",
            format!("{}/{} for nv {nv}", t.bias.len(), t.velocity.len()),
        ));
    }
    let finite = |x: &[f64]| x.iter().all(|v| v.is_finite());
    if !finite(&t.mass_matrix.data) || !finite(&t.bias) || !finite(&t.velocity) {
        return Err(ControllerError::NonFinite {
            robot: robot.to_string(),
            what: "M, h or v".into(),
        });
    }
    check_frames(t, robot, nv)
}

/// Each frame's Jacobian and drift sized for its role and `nv` and finite; one hand frame when
/// the hand is in the grasp.
fn check_frames(t: &DynamicsTerms, robot: &str, nv: usize) -> Result<(), ControllerError> {
    let dim = |what: &str, detail: String| ControllerError::Dimension {
        what: format!("{robot}: {what}"),
        detail,
    };
    let finite = |x: &[f64]| x.iter().all(|v| v.is_finite());
    let mut hands = 0;
    for f in &t.frames {
        let d = f.role.dim();
        if f.jacobian.rows() != d
            || f.jacobian.cols() != nv
            || f.jacobian.data.len() != d * nv
            || f.jdot_v.len() != d
        {
            return Err(dim(
                &format!("frame {}", f.name),
                format!(
                    "jacobian {}x{}, jdot_v {} for a {d}-row frame and nv {nv}",
                    f.jacobian.rows(),
                    f.jacobian.cols(),
                    f.jdot_v.len()
                ),
            ));
        }
        if !finite(&f.jacobian.data)
            || !finite(&f.jdot_v)
            || !finite(&f.position)
            || !finite(&f.rotation)
        {
            return Err(ControllerError::NonFinite {
                robot: robot.to_string(),
                what: format!("frame {}", f.name),
            });
        }
        hands += (f.role == FrameRole::Hand) as usize;
    }
    if t.hand_in_grasp && hands != 1 {
        return Err(dim("hand", format!("hand in grasp with {hands} hand frames")));
    }
    Ok(())
}

/// A frame's terms into `tf`, its Jacobian on its robot's columns `off ..+ nv` of `n`: only
/// those are written when `tf` held a frame on the same columns (the rest are its zeros).
fn team_frame_into(tf: &mut TeamFrame, robot: usize, f: &FrameTerms, off: usize, n: usize) {
    let d = f.role.dim();
    let nv = f.jacobian.cols();
    if tf.jacobian.shape() != (d, n) {
        zeros(&mut tf.jacobian, d, n);
        tf.cols = (0, 0);
    }
    move_columns(&mut tf.jacobian, 0, d, &mut tf.cols, (off, nv));
    for i in 0..d {
        for j in 0..nv {
            tf.jacobian[(i, off + j)] = f.jacobian.data[i * nv + j];
        }
    }
    tf.robot = robot;
    if tf.name != f.name {
        tf.name.clone_from(&f.name);
    }
    tf.position = Vector3::from_row_slice(&f.position);
    tf.rotation = rotation_from_row_major(&f.rotation);
    zeros_v(&mut tf.jdot_v, d);
    tf.jdot_v.copy_from_slice(&f.jdot_v);
}

/// Rows `r0 ..+ d` of `a`, non-zero at most on the columns `written` (first, count), made
/// zero outside `cols`: the columns written and not `cols` are cleared, and `written`
/// becomes `cols`. The caller then writes `cols`.
fn move_columns(
    a: &mut DMatrix<f64>,
    r0: usize,
    d: usize,
    written: &mut (usize, usize),
    cols: (usize, usize),
) {
    if *written != cols {
        a.view_mut((r0, written.0), (d, written.1)).fill(0.0);
        *written = cols;
    }
}

/// Frames' Jacobians and `Jdot*v` stacked (`d` rows each) into `j` and `jdv`, each frame on
/// its robot's columns; `cols` records them for the next tick's (see [`move_columns`]).
fn stack(
    frames: &[TeamFrame],
    d: usize,
    n: usize,
    j: &mut DMatrix<f64>,
    jdv: &mut DVector<f64>,
    cols: &mut Vec<(usize, usize)>,
) {
    let rows = d * frames.len();
    if j.shape() != (rows, n) || cols.len() != frames.len() {
        zeros(j, rows, n);
        cols.clear();
        cols.resize(frames.len(), (0, 0));
    }
    zeros_v(jdv, rows);
    for (k, f) in frames.iter().enumerate() {
        let (c0, nc) = f.cols;
        move_columns(j, d * k, d, &mut cols[k], f.cols);
        j.view_mut((d * k, c0), (d, nc)).copy_from(&f.jacobian.columns(c0, nc));
        jdv.rows_mut(d * k, d).copy_from(&f.jdot_v);
    }
}
