//! Shared test helpers: the test URDFs, random states, and MuJoCo as an independent oracle.
#![allow(dead_code)]

use std::ffi::CString;

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6xX, Vector3, Vector6};
use protocol::conventions::{
    base_acceleration_to_mujoco, base_twist_to_mujoco as base_velocity_to_mujoco,
};
use rand::{rngs::StdRng, Rng, SeedableRng};
use robot_model::{FloatingBase, Model, ModelBuilder, SE3};

pub const ARM: &str = include_str!("../data/arm.urdf");
pub const QUADRUPED: &str = include_str!("../data/quadruped.urdf");

/// Where and how the arm goes onto the quadruped in the composed model.
pub const ATTACH_AT: &str = "arm_mount";
pub const ATTACH_XYZ: [f64; 3] = [0.05, 0.0, 0.02];
pub const ATTACH_RPY: [f64; 3] = [0.0, 0.0, 0.3];
pub const PREFIX: &str = "arm_";

/// The test URDFs live in robot-model/tests/data; robot-agent's tests include this module
/// too (`#[path]`), hence the path through the workspace root.
pub fn data_path(name: &str) -> String {
    format!("{}/../robot-model/tests/data/{name}", env!("CARGO_MANIFEST_DIR"))
}

pub fn arm_model() -> Model {
    Model::from_urdf_str(ARM, FloatingBase::No).unwrap()
}

pub fn quadruped_model() -> Model {
    Model::from_urdf_str(QUADRUPED, FloatingBase::Yes).unwrap()
}

/// The 24-DoF legged manipulator: quadruped + arm via the library's `attach`.
pub fn composed_model() -> Model {
    ModelBuilder::from_urdf_str(QUADRUPED)
        .unwrap()
        .attach_urdf_str(ARM, ATTACH_AT, SE3::from_xyz_rpy(ATTACH_XYZ, ATTACH_RPY), PREFIX)
        .unwrap()
        .build(FloatingBase::Yes)
        .unwrap()
}

/// Removes `<visual>...</visual>` blocks (meshes that do not exist) for MuJoCo.
pub fn strip_visuals(urdf: &str) -> String {
    let mut out = String::new();
    let mut rest = urdf;
    while let Some(a) = rest.find("<visual>") {
        out.push_str(&rest[..a]);
        let b = rest[a..].find("</visual>").expect("unterminated visual") + a + "</visual>".len();
        rest = &rest[b..];
    }
    out.push_str(rest);
    out
}

/// Inner text of `<robot ...> ... </robot>`.
fn robot_body(urdf: &str) -> &str {
    let a = urdf.find("<robot").unwrap();
    let a = a + urdf[a..].find('>').unwrap() + 1;
    let b = urdf.rfind("</robot>").unwrap();
    &urdf[a..b]
}

/// The composed robot as ONE URDF text, built by plain text editing (independent of the
/// library's `attach`): the arm's names prefixed, a fixed joint from `ATTACH_AT`.
pub fn composed_urdf_text() -> String {
    let quad = strip_visuals(QUADRUPED);
    let arm = strip_visuals(ARM);
    let arm_body = robot_body(&arm)
        .replace("name=\"", &format!("name=\"{PREFIX}"))
        .replace("link=\"", &format!("link=\"{PREFIX}"));
    let attach = format!(
        "<joint name=\"{PREFIX}attach_joint\" type=\"fixed\"><origin xyz=\"{} {} {}\" rpy=\"{} {} {}\"/><parent link=\"{ATTACH_AT}\"/><child link=\"{PREFIX}base_link\"/></joint>\n",
        ATTACH_XYZ[0], ATTACH_XYZ[1], ATTACH_XYZ[2], ATTACH_RPY[0], ATTACH_RPY[1], ATTACH_RPY[2]
    );
    let end = quad.rfind("</robot>").unwrap();
    format!("{}{}{}</robot>\n", &quad[..end], arm_body, attach)
}

pub fn rng(seed: u64) -> StdRng {
    StdRng::seed_from_u64(seed)
}

/// Random configuration within limits and random velocity in [-2, 2].
pub fn random_state(model: &Model, rng: &mut StdRng) -> (DVector<f64>, DVector<f64>) {
    let mut u = || rng.random::<f64>();
    let q = model.random_configuration(&mut u);
    let v = DVector::from_fn(model.nv, |_, _| 4.0 * rng.random::<f64>() - 2.0);
    (q, v)
}

pub fn rel_err(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    (a - b).norm() / b.norm().max(1.0)
}

pub fn rel_err_v(a: &[f64], b: &[f64]) -> f64 {
    let d: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt();
    let n: f64 = b.iter().map(|y| y * y).sum::<f64>().sqrt();
    d / n.max(1.0)
}

/// MuJoCo's view of one frame (a body's regular frame), in our conventions.
pub struct FrameTerms {
    pub pos: Vector3<f64>,
    pub rot: Matrix3<f64>,
    /// [jacp; jacr] from `mj_jacBody`.
    pub jac: Matrix6xX<f64>,
    /// Classical Jdot v [lin; ang] from `mj_jacDot`: `J_mj c + Jdot_mj qvel`.
    pub jdot_v: Vector6<f64>,
    /// The same from `mj_objectAcceleration(mjOBJ_XBODY)` after `mj_rnePostConstraint` with
    /// `qacc = c` and gravity off.
    pub acc: Vector6<f64>,
}

/// MuJoCo's terms at one state, converted into our conventions.
pub struct MjTerms {
    pub m: DMatrix<f64>,
    pub h: DVector<f64>,
    pub g: DVector<f64>,
    /// Per requested frame: position, rotation, Jacobian [jacp; jacr], Jdot v [lin; ang].
    pub frames: Vec<FrameTerms>,
}

/// The same robot loaded into MuJoCo 3.17 from the same URDF text.
///
/// Import settings that make the two models the same: `fusestatic="false"` (fixed links stay
/// bodies, so every URDF link is a MuJoCo body named like the link), `balanceinertia="false"`
/// and `inertiafromgeom="false"` (inertias exactly as written), visuals removed (no meshes),
/// armature, damping and friction loss set to 0 after compiling (asserted), gravity
/// (0, 0, -9.81). A floating base gets a free joint added to the root body with mjSpec.
/// `Jdot v` comes from `mj_jacDot`, and independently from MuJoCo's body accelerations
/// (`cacc` of `mj_rnePostConstraint`, read with `mj_objectAcceleration` on `mjOBJ_XBODY`, the
/// body's regular frame; `mjOBJ_BODY` would be its inertial frame) in a second copy with
/// gravity off; both with the free joint's `qacc` that corresponds to our zero base
/// acceleration (`base_acceleration_to_mujoco`).
pub struct MjRobot {
    pub model: mujoco_rs::prelude::MjModel,
    pub model0: mujoco_rs::prelude::MjModel,
}

pub fn mujoco_urdf(urdf: &str) -> String {
    let urdf = strip_visuals(urdf);
    let a = urdf.find("<robot").unwrap();
    let a = a + urdf[a..].find('>').unwrap() + 1;
    format!(
        "{}\n  <mujoco><compiler fusestatic=\"false\" discardvisual=\"true\" balanceinertia=\"false\" inertiafromgeom=\"false\"/></mujoco>\n{}",
        &urdf[..a],
        &urdf[a..]
    )
}

impl MjRobot {
    pub fn new(urdf: &str, floating_root: Option<&str>) -> Self {
        use mujoco_rs::prelude::*;
        let text = mujoco_urdf(urdf);
        let compile = || {
            let mut spec = MjSpec::from_xml_string(&text).expect("MuJoCo parses the URDF");
            if let Some(root) = floating_root {
                spec.world_body_mut().child_mut(root).expect("root body").add_free_joint();
            }
            spec.compile().expect("MuJoCo compiles the URDF")
        };
        let mut model = compile();
        let mut model0 = compile();
        for m in [&mut model, &mut model0] {
            let raw = unsafe { m.ffi_mut() };
            for k in 0..raw.nv as usize {
                unsafe {
                    *raw.dof_armature.add(k) = 0.0;
                    *raw.dof_damping.add(k) = 0.0;
                    *raw.dof_frictionloss.add(k) = 0.0;
                }
            }
        }
        assert_eq!(model.ffi().opt.gravity, [0.0, 0.0, -9.81]);
        unsafe { model0.ffi_mut() }.opt.gravity = [0.0; 3];
        Self { model, model0 }
    }

    /// Sum of MuJoCo's body masses, and its number of bodies (world included).
    pub fn mass_and_bodies(&self) -> (f64, usize) {
        let raw = self.model.ffi();
        let n = raw.nbody as usize;
        ((0..n).map(|b| unsafe { *raw.body_mass.add(b) }).sum(), n)
    }

    pub fn nv(&self) -> usize {
        self.model.ffi().nv as usize
    }

    fn id(&self, kind: mujoco_rs::mujoco_c::mjtObj, name: &str) -> usize {
        let c = CString::new(name).unwrap();
        let id =
            unsafe { mujoco_rs::mujoco_c::mj_name2id(self.model.ffi(), kind as i32, c.as_ptr()) };
        assert!(id >= 0, "MuJoCo has no {kind:?} named {name}");
        id as usize
    }

    /// Velocity map `qvel_mujoco = T v_ours` for base quaternion `quat` (via the library's
    /// single conversion function) and joint name matching.
    pub fn velocity_map(&self, ours: &Model, q: &DVector<f64>) -> DMatrix<f64> {
        let raw = self.model.ffi();
        let nv = self.nv();
        assert_eq!(nv, ours.nv);
        let mut t = DMatrix::zeros(nv, nv);
        if ours.floating_base {
            let quat = [q[3], q[4], q[5], q[6]];
            let free = (0..raw.njnt as usize)
                .find(|&j| unsafe { *raw.jnt_type.add(j) } == 0)
                .expect("free joint");
            let fd = unsafe { *raw.jnt_dofadr.add(free) } as usize;
            for c in 0..6 {
                let mut e = [0.0; 6];
                e[c] = 1.0;
                let col = base_velocity_to_mujoco(quat, e);
                for r in 0..6 {
                    t[(fd + r, c)] = col[r];
                }
            }
        }
        for (k, name) in ours.joint_names.iter().enumerate() {
            let j = self.id(mujoco_rs::mujoco_c::mjtObj::mjOBJ_JOINT, name);
            let d = unsafe { *raw.jnt_dofadr.add(j) } as usize;
            let col = ours.nv - ours.joint_names.len() + k;
            t[(d, col)] = 1.0;
        }
        t
    }

    fn qpos(&self, ours: &Model, q: &DVector<f64>) -> Vec<f64> {
        let raw = self.model.ffi();
        let mut qpos = vec![0.0; raw.nq as usize];
        if ours.floating_base {
            let free =
                (0..raw.njnt as usize).find(|&j| unsafe { *raw.jnt_type.add(j) } == 0).unwrap();
            let a = unsafe { *raw.jnt_qposadr.add(free) } as usize;
            qpos[a..a + 7].copy_from_slice(&q.as_slice()[0..7]);
        }
        let off = ours.nq - ours.joint_names.len();
        for (k, name) in ours.joint_names.iter().enumerate() {
            let j = self.id(mujoco_rs::mujoco_c::mjtObj::mjOBJ_JOINT, name);
            qpos[unsafe { *raw.jnt_qposadr.add(j) } as usize] = q[off + k];
        }
        qpos
    }

    pub fn eval(
        &self,
        ours: &Model,
        q: &DVector<f64>,
        v: &DVector<f64>,
        frames: &[&str],
    ) -> MjTerms {
        use mujoco_rs::mujoco_c::*;
        let nv = self.nv();
        let t = self.velocity_map(ours, q);
        let qpos = self.qpos(ours, q);
        let qvel = &t * v;
        let mut terms = MjTerms {
            m: DMatrix::zeros(nv, nv),
            h: DVector::zeros(nv),
            g: DVector::zeros(nv),
            frames: Vec::new(),
        };
        let set = |d: *mut mjData, vel: &[f64]| unsafe {
            std::ptr::copy_nonoverlapping(qpos.as_ptr(), (*d).qpos, qpos.len());
            std::ptr::copy_nonoverlapping(vel.as_ptr(), (*d).qvel, nv);
        };
        // M and h
        let mut data = self.model.make_data();
        let d = unsafe { data.ffi_mut() } as *mut mjData;
        let m = self.model.ffi() as *const mjModel;
        set(d, qvel.as_slice());
        unsafe { mj_forward(m, d) };
        let mut full = vec![0.0; nv * nv];
        unsafe { mj_fullM(m, d, full.as_mut_ptr()) };
        let m_mj = DMatrix::from_row_slice(nv, nv, &full);
        terms.m = t.transpose() * &m_mj * &t;
        let bias =
            DVector::from_column_slice(unsafe { std::slice::from_raw_parts((*d).qfrc_bias, nv) });
        // qacc in MuJoCo's coordinates for our zero acceleration (the base's world-frame linear
        // velocity turns with the base): tau_ours = T^T (M_mj c + qfrc_bias)
        let mut c = DVector::zeros(nv);
        if ours.floating_base {
            let ca = base_acceleration_to_mujoco(
                [q[3], q[4], q[5], q[6]],
                std::array::from_fn(|i| v[i]),
                [0.0; 6],
            );
            let tb = t.view((0, 0), (nv, 6));
            // the free joint's dofs are the rows where the base columns of T are non-zero
            let fd = (0..nv).find(|&r| tb.row(r).iter().any(|x| *x != 0.0)).unwrap();
            for r in 0..6 {
                c[fd + r] = ca[r];
            }
        }
        terms.h = t.transpose() * (bias + &m_mj * &c);
        // frames: placement and Jacobians at the body origin
        for name in frames {
            let b = self.id(mjtObj::mjOBJ_BODY, name);
            let (pos, rot) = unsafe {
                let p = std::slice::from_raw_parts((*d).xpos.add(3 * b), 3);
                let r = std::slice::from_raw_parts((*d).xmat.add(9 * b), 9);
                (Vector3::from_column_slice(p), Matrix3::from_row_slice(r))
            };
            let mut jp = vec![0.0; 3 * nv];
            let mut jr = vec![0.0; 3 * nv];
            unsafe { mj_jacBody(m, d, jp.as_mut_ptr(), jr.as_mut_ptr(), b as i32) };
            let mut jac = DMatrix::zeros(6, nv);
            jac.view_mut((0, 0), (3, nv)).copy_from(&DMatrix::from_row_slice(3, nv, &jp));
            jac.view_mut((3, 0), (3, nv)).copy_from(&DMatrix::from_row_slice(3, nv, &jr));
            let jac_mj = jac.clone();
            let jac = jac * &t;
            let jac6 = Matrix6xX::from_column_slice(jac.as_slice());
            // classical acceleration at our zero acceleration: J_mj c + Jdot_mj qvel
            let (mut dp, mut dr) = (vec![0.0; 3 * nv], vec![0.0; 3 * nv]);
            let point = [pos.x, pos.y, pos.z];
            unsafe { mj_jacDot(m, d, dp.as_mut_ptr(), dr.as_mut_ptr(), &point, b as i32) };
            let mut jd = DMatrix::zeros(6, nv);
            jd.view_mut((0, 0), (3, nv)).copy_from(&DMatrix::from_row_slice(3, nv, &dp));
            jd.view_mut((3, 0), (3, nv)).copy_from(&DMatrix::from_row_slice(3, nv, &dr));
            let a = &jac_mj * &c + jd * &qvel;
            terms.frames.push(FrameTerms {
                pos,
                rot,
                jac: jac6,
                jdot_v: Vector6::from_column_slice(a.as_slice()),
                acc: Vector6::zeros(),
            });
        }
        // g: zero velocity
        let zero = vec![0.0; nv];
        set(d, &zero);
        unsafe { mj_forward(m, d) };
        let bias =
            DVector::from_column_slice(unsafe { std::slice::from_raw_parts((*d).qfrc_bias, nv) });
        terms.g = t.transpose() * bias;
        // body accelerations at qacc = c without gravity
        let mut data0 = self.model0.make_data();
        let d0 = unsafe { data0.ffi_mut() } as *mut mjData;
        let m0 = self.model0.ffi() as *const mjModel;
        set(d0, qvel.as_slice());
        unsafe {
            mj_forward(m0, d0);
            std::ptr::copy_nonoverlapping(c.as_ptr(), (*d0).qacc, nv);
            mj_rnePostConstraint(m0, d0);
        }
        for (k, name) in frames.iter().enumerate() {
            let b = self.id(mjtObj::mjOBJ_BODY, name);
            let mut res = [0.0; 6];
            unsafe {
                mj_objectAcceleration(m0, d0, mjtObj::mjOBJ_XBODY as i32, b as i32, &mut res, 0)
            };
            // MuJoCo: [angular; linear] -> ours [linear; angular]
            terms.frames[k].acc = Vector6::new(res[3], res[4], res[5], res[0], res[1], res[2]);
        }
        drop(data0);
        drop(data);
        terms
    }
}
