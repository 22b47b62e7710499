//! What turns a state into dynamics terms: a [`DynamicsSource`]. [`ModelDynamics`] is the
//! robot's own model ([`crate::terms::TermsBuilder`] over a loaded [`Robot`]);
//! [`PlaceholderDynamics`] (unit mass matrix, no frames) exists only for the smoke run of the
//! runner, whose closed loop has an analytic answer.

use std::sync::Arc;

use protocol::{Matrix, RobotDescription, RobotState};
use robot_model::Robot;
use thiserror::Error;

use crate::terms::{ActiveContacts, TermsBuilder, TermsError};

/// Errors computing terms from a state.
#[derive(Debug, Error)]
pub enum SourceError {
    #[error("state has {got} joints, the robot has {expected}")]
    StateSize { expected: usize, got: usize },
    #[error(transparent)]
    Terms(#[from] TermsError),
}

/// A robot's dynamics: its size, limits, frames, and the terms at a state.
pub trait DynamicsSource: Send {
    /// Actuated joints (velocity order).
    fn joints(&self) -> usize;
    /// Whether the first 6 velocity coordinates are an unactuated floating base.
    fn floating_base(&self) -> bool;
    /// Symmetric torque limit per actuated joint (`f64::INFINITY`: none).
    fn torque_limits(&self) -> Vec<f64>;
    /// Foot frames in description order (an [`ActiveContacts`] has one entry per foot).
    fn foot_frames(&self) -> &[String];
    /// The protocol description to publish for robot `id` of team `team`, if there is a model.
    fn description(&self, team: &str, id: &str) -> Option<RobotDescription>;
    /// Fill `out` (header excepted) with the terms at `state` for `contacts`.
    fn compute(
        &mut self,
        state: &RobotState,
        contacts: &ActiveContacts,
        out: &mut protocol::DynamicsTerms,
    ) -> Result<(), SourceError>;
    /// The joint torques that balance gravity at rest, the stance feet carrying the floating
    /// base ([`crate::standing`]), at the state and contacts of the last successful
    /// [`DynamicsSource::compute`] (zeros before).
    fn actuated_gravity(&self, out: &mut [f64]);
}

/// The protocol's summary of `robot`, for robot `id` of team `team` (what the agent publishes
/// on its `description` key).
pub fn robot_description(robot: &Robot, team: &str, id: &str) -> RobotDescription {
    RobotDescription {
        header: protocol::Header::new(team, Some(id), 0, protocol::wall_clock_ns()),
        joint_names: robot.actuated_joints.clone(),
        torque_limits: robot.torque_limits.clone(),
        floating_base: robot.model.floating_base,
        nq: robot.model.nq as u32,
        nv: robot.model.nv as u32,
        foot_frames: robot.foot_frames.clone(),
        hand_frame: robot.hand_frame.clone(),
        torso_frame: robot.torso_frame.clone(),
        foot_mu: robot.feet.mu,
        hand_mu: robot.hand.mu,
        hand_xi: robot.hand.xi,
        hand_half_size: [robot.hand.half_size_x, robot.hand.half_size_y],
        total_mass: robot.model.total_mass,
    }
}

/// The robot's own model.
pub struct ModelDynamics {
    robot: Arc<Robot>,
    builder: TermsBuilder,
    gravity: Vec<f64>,
}

impl ModelDynamics {
    pub fn new(robot: Robot) -> Result<Self, SourceError> {
        Self::shared(Arc::new(robot))
    }

    /// Over a robot loaded once and shared with the rest of the process.
    pub fn shared(robot: Arc<Robot>) -> Result<Self, SourceError> {
        let builder = TermsBuilder::new(&robot)?;
        let gravity = vec![0.0; robot.joints()];
        Ok(ModelDynamics { robot, builder, gravity })
    }

    pub fn robot(&self) -> &Robot {
        &self.robot
    }
}

impl DynamicsSource for ModelDynamics {
    fn joints(&self) -> usize {
        self.robot.joints()
    }

    fn floating_base(&self) -> bool {
        self.robot.model.floating_base
    }

    fn torque_limits(&self) -> Vec<f64> {
        self.robot.torque_limits.clone()
    }

    fn foot_frames(&self) -> &[String] {
        &self.robot.foot_frames
    }

    fn description(&self, team: &str, id: &str) -> Option<RobotDescription> {
        Some(robot_description(&self.robot, team, id))
    }

    fn compute(
        &mut self,
        state: &RobotState,
        contacts: &ActiveContacts,
        out: &mut protocol::DynamicsTerms,
    ) -> Result<(), SourceError> {
        self.builder.load_state(&self.robot, state)?;
        self.builder.compute(&self.robot, contacts, out)?;
        let g = self.builder.data().g.as_slice();
        crate::standing::standing_torques(
            g,
            self.robot.model.floating_base,
            &out.frames,
            &self.robot.actuated_indices,
            &mut self.gravity,
        );
        Ok(())
    }

    fn actuated_gravity(&self, out: &mut [f64]) {
        for (o, g) in out.iter_mut().zip(&self.gravity) {
            *o = *g;
        }
    }
}

/// Smoke-run stand-in for a model: unit mass matrix, zero bias and gravity, no frames, no
/// limits. It exercises the message flow only; a real robot runs [`ModelDynamics`].
pub struct PlaceholderDynamics {
    pub joints: usize,
    pub nv: usize,
}

impl PlaceholderDynamics {
    /// A floating-base placeholder with `joints` actuated joints.
    pub fn floating(joints: usize) -> Self {
        PlaceholderDynamics { joints, nv: joints + 6 }
    }
}

impl DynamicsSource for PlaceholderDynamics {
    fn joints(&self) -> usize {
        self.joints
    }

    fn floating_base(&self) -> bool {
        self.nv > self.joints
    }

    fn torque_limits(&self) -> Vec<f64> {
        vec![f64::INFINITY; self.joints]
    }

    fn foot_frames(&self) -> &[String] {
        &[]
    }

    fn description(&self, _team: &str, _id: &str) -> Option<RobotDescription> {
        None
    }

    fn compute(
        &mut self,
        state: &RobotState,
        _contacts: &ActiveContacts,
        out: &mut protocol::DynamicsTerms,
    ) -> Result<(), SourceError> {
        if state.joint_positions.len() != self.joints {
            return Err(SourceError::StateSize {
                expected: self.joints,
                got: state.joint_positions.len(),
            });
        }
        let nv = self.nv;
        out.floating_base = self.floating_base();
        out.nv = nv as u32;
        if out.mass_matrix.rows as usize != nv || out.mass_matrix.cols as usize != nv {
            out.mass_matrix = Matrix::zeros(nv, nv);
        }
        out.mass_matrix.data.iter_mut().for_each(|x| *x = 0.0);
        for i in 0..nv {
            out.mass_matrix.data[i * nv + i] = 1.0;
        }
        out.bias.clear();
        out.bias.resize(nv, 0.0);
        out.velocity.clear();
        if nv > self.joints {
            out.velocity.extend_from_slice(&state.base_twist);
        }
        out.velocity.extend_from_slice(&state.joint_velocities);
        out.frames.clear();
        out.hand_in_grasp = false;
        Ok(())
    }

    fn actuated_gravity(&self, out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
    }
}
