//! The whole robot's centre of mass (Pinocchio's `center_of_mass`), from the bodies' world
//! inertias of the last kinematics pass.

use nalgebra::Vector3;

use crate::{Data, Model};

/// Total mass and world centre of mass `c = sum m_i c_i / sum m_i` (after
/// [`crate::forward_kinematics`] or any pass that fills `data.o_inertia`).
pub fn center_of_mass(model: &Model, data: &Data) -> (f64, Vector3<f64>) {
    let mut mass = 0.0;
    let mut moment = Vector3::zeros();
    for i in &data.o_inertia[..model.bodies.len()] {
        mass += i.mass;
        moment += i.mass * i.com;
    }
    let com = if mass > 0.0 { moment / mass } else { Vector3::zeros() };
    (mass, com)
}
