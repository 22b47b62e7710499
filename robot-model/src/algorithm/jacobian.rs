//! Frame Jacobians, LOCAL_WORLD_ALIGNED: at the frame origin, axes of the world, rows
//! `[linear; angular]` (docs/conventions.md). `[v_origin; omega] = J v`.
//! Use after [`crate::forward_kinematics`] or [`crate::compute_all_terms`].

use nalgebra::{Matrix3xX, Matrix6xX, Vector3};

use super::kinematics::check_frame;
use crate::data::Data;
use crate::error::DynamicsError;
use crate::model::{FrameId, Model};

pub(crate) fn check_shape(
    rows: usize,
    cols: usize,
    er: usize,
    ec: usize,
) -> Result<(), DynamicsError> {
    if rows != er || cols != ec {
        return Err(DynamicsError::OutputShape {
            rows,
            cols,
            expected_rows: er,
            expected_cols: ec,
        });
    }
    Ok(())
}

/// 6 x nv Jacobian of `frame` into `out`: column k is `[S_k.lin + S_k.ang x p; S_k.ang]`
/// for the joints supporting the frame's body (p = frame origin in the world), 0 elsewhere.
pub fn frame_jacobian(
    model: &Model,
    data: &Data,
    frame: FrameId,
    out: &mut Matrix6xX<f64>,
) -> Result<(), DynamicsError> {
    check_frame(model, frame)?;
    check_shape(out.nrows(), out.ncols(), 6, model.nv)?;
    out.fill(0.0);
    let p = data.o_m_f[frame].trans;
    for &k in &model.bodies[model.frames[frame].body].support {
        let lin: Vector3<f64> = data.j.fixed_view::<3, 1>(0, k).into();
        let ang: Vector3<f64> = data.j.fixed_view::<3, 1>(3, k).into();
        out.fixed_view_mut::<3, 1>(0, k).copy_from(&(lin + ang.cross(&p)));
        out.fixed_view_mut::<3, 1>(3, k).copy_from(&ang);
    }
    Ok(())
}

/// 3 x nv Jacobian of the point `point` (given in `frame`'s coordinates) rigidly attached to
/// the frame: world velocity of the point = J v.
pub fn point_jacobian(
    model: &Model,
    data: &Data,
    frame: FrameId,
    point: &Vector3<f64>,
    out: &mut Matrix3xX<f64>,
) -> Result<(), DynamicsError> {
    check_frame(model, frame)?;
    check_shape(out.nrows(), out.ncols(), 3, model.nv)?;
    out.fill(0.0);
    let p = data.o_m_f[frame].act_point(point);
    for &k in &model.bodies[model.frames[frame].body].support {
        let lin: Vector3<f64> = data.j.fixed_view::<3, 1>(0, k).into();
        let ang: Vector3<f64> = data.j.fixed_view::<3, 1>(3, k).into();
        out.fixed_view_mut::<3, 1>(0, k).copy_from(&(lin + ang.cross(&p)));
    }
    Ok(())
}
