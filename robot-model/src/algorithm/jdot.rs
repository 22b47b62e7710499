//! Time derivative of frame Jacobians, and the classical acceleration bias `Jdot v` of a frame
//! (LOCAL_WORLD_ALIGNED, rows `[linear; angular]`).
//!
//! `Jdot v` is the classical acceleration of the frame origin and the angular acceleration of
//! the frame when `qdd = 0`: with `(a_O, alpha)` the body's spatial bias acceleration (world
//! frame), `p` the frame origin and `v_p = v_O + omega x p` its velocity,
//! `Jdot v = [a_O + alpha x p + omega x v_p; alpha]` (the `omega x v` term included), which is
//! what a contact constraint `J qdd + Jdot v = 0` needs.
//! Use after [`crate::forward_kinematics`] or [`crate::compute_all_terms`].

use nalgebra::{Matrix6xX, Vector3, Vector6};

use super::jacobian::check_shape;
use super::kinematics::check_frame;
use crate::data::Data;
use crate::error::DynamicsError;
use crate::model::{FrameId, Model};

/// Classical `Jdot v` of `frame` (see the module docs).
pub fn frame_jdot_v(
    model: &Model,
    data: &Data,
    frame: FrameId,
) -> Result<Vector6<f64>, DynamicsError> {
    check_frame(model, frame)?;
    let body = model.frames[frame].body;
    let (vb, ab) = (data.ov[body], data.oa[body]);
    let p = data.o_m_f[frame].trans;
    let vp = vb.lin + vb.ang.cross(&p);
    let lin = ab.lin + ab.ang.cross(&p) + vb.ang.cross(&vp);
    Ok(Vector6::new(lin.x, lin.y, lin.z, ab.ang.x, ab.ang.y, ab.ang.z))
}

/// `d/dt J(q)` of `frame` along the current velocity into `out`. Column k:
/// `[dS.lin + dS.ang x p + S.ang x v_p; dS.ang]` with `dS = V_body(k) x S_k`.
pub fn frame_jacobian_time_variation(
    model: &Model,
    data: &Data,
    frame: FrameId,
    out: &mut Matrix6xX<f64>,
) -> Result<(), DynamicsError> {
    check_frame(model, frame)?;
    check_shape(out.nrows(), out.ncols(), 6, model.nv)?;
    out.fill(0.0);
    let body = model.frames[frame].body;
    let vb = data.ov[body];
    let p = data.o_m_f[frame].trans;
    let vp = vb.lin + vb.ang.cross(&p);
    for &k in &model.bodies[body].support {
        let s_ang: Vector3<f64> = data.j.fixed_view::<3, 1>(3, k).into();
        let ds_lin: Vector3<f64> = data.dj.fixed_view::<3, 1>(0, k).into();
        let ds_ang: Vector3<f64> = data.dj.fixed_view::<3, 1>(3, k).into();
        out.fixed_view_mut::<3, 1>(0, k).copy_from(&(ds_lin + ds_ang.cross(&p) + s_ang.cross(&vp)));
        out.fixed_view_mut::<3, 1>(3, k).copy_from(&ds_ang);
    }
    Ok(())
}
